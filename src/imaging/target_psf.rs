//! A target's image as the optics form it: its projected outline (the exact image ellipse) convolved with the
//! camera's PSF, `v(p) = ΔL·∫_E PSF(p − x) dx`, evaluated at pixel centres.
//!
//! A distant target (smaller than the PSF) becomes PSF-shaped with its flux `ΔL·area`; a near one an extended
//! blob with blurred edges; in between the shape follows the ellipse's size, elongation and angle, so the
//! fitted width and shape of the blob change with range and attitude as they do in real imagery.
//!
//! The integral is a quadrature: each node a point source of its share of the area, looked up in the PSF's
//! fine table at its exact sub-pixel position and added to the pixels within the PSF's reach; or, with
//! [`TargetPsfSpec::core_px`] (the standard preset's 4 px), only the PSF's core added so, and its tail once from
//! the nodes binned to pixels ([`SplitPsf`]).
//! - An ellipse smaller than the PSF (semi-major axis up to [`TargetPsfSpec::seven_point_max_px`]) takes
//!   Radon's seven-point rule for the disk mapped onto it (the centre with weight ¼, six points at radius
//!   √(2/3) with ⅛ each; exact for polynomials to degree 5), or its centre alone when it is under a hundredth
//!   of a pixel.
//! - A larger round one takes rings of equal width, points `node_spacing_px` apart on each; an elongated one
//!   (longer than 1.25 times its width) columns across its major axis, nodes about
//!   `node_spacing_px` apart each way (rings that far apart along the major axis crowd the minor one). Pixels
//!   deeper inside than the PSF's reach get the full value directly and the nodes that reach only them are
//!   skipped, so the cost grows with the perimeter, not the area.
//!
//! [`TargetMethod::Reference`] uses rings for every size (the reference preset: at 0.05 px), against which the
//! errors of the default are measured (tests `auto_is_close_to_the_reference` and
//! `columns_are_as_close_to_the_reference_as_rings`, `docs/accuracy.md`; the draft preset's 0.6 px spacing in
//! `draft_spacing_error`). The image's intensity
//! centroid is not the ellipse centre exactly: sampling a blurred point at pixel centres biases it toward the
//! nearest pixel centre, as in a real camera; the labels give the true centre.

use serde::{Deserialize, Serialize};

use super::psf::{MAX_RADIUS_PX, PhaseTable, Psf, SplitPsf};
use super::target_blob::{ImageEllipse, PixelRect};
use crate::physics::simd::widest;

/// How the ellipse ⊗ PSF integral is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetMethod {
    /// Seven points for small ellipses, rings for larger round ones, columns for elongated ones
    /// (`column_nodes` in this module).
    #[default]
    Auto,
    /// Seven points for small ellipses, rings for every larger one.
    Rings,
    /// Rings for every size (at 0.05 px in the reference preset): the reference.
    Reference,
}

/// Settings of the target rendering.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TargetPsfSpec {
    /// The quadrature.
    pub method: TargetMethod,
    /// Spacing of the quadrature's nodes (rings, or columns and the nodes along them), px.
    pub node_spacing_px: f64,
    /// Largest semi-major axis given the seven-point rule, px.
    pub seven_point_max_px: f64,
    /// Radius of the PSF's core added at each node, px ([`SplitPsf`]: the tail beyond it added once from the
    /// nodes binned to pixels); 0, or a core as large as the kernel: the whole PSF at each node.
    pub core_px: usize,
}

impl Default for TargetPsfSpec {
    fn default() -> Self {
        Self { method: TargetMethod::Auto, node_spacing_px: NODE_SPACING_PX, seven_point_max_px: 0.6, core_px: CORE_PX }
    }
}

impl TargetPsfSpec {
    /// Checks the parameters.
    ///
    /// # Errors
    /// The name of the parameter out of range and a message.
    pub fn validate(&self) -> Result<(), crate::physics::ParamError> {
        use crate::physics::ParamError;
        ParamError::check_range("node_spacing_px", self.node_spacing_px, 0.01, 2.0)?;
        ParamError::check_range("core_px", self.core_px as f64, 0.0, MAX_RADIUS_PX as f64)?;
        ParamError::check_range("seven_point_max_px", self.seven_point_max_px, 0.0, 5.0)
    }
}

/// The default radius of the PSF's core added at each node, px (the standard preset's
/// `target_psf_core_px`; [`SplitPsf`]).
pub const CORE_PX: usize = 4;

/// The default spacing of the ring nodes, px (the standard preset's).
pub const NODE_SPACING_PX: f64 = 0.3;
/// The spacing of the ring nodes that the errors of the others are measured against, px (the reference
/// preset's).
pub const REFERENCE_NODE_SPACING_PX: f64 = 0.05;

/// Smallest elongation `a/b` given columns ([`column_nodes`]) in place of rings: rounder ellipses take fewer
/// nodes as rings (a circle of 2 px radius: 153 against 188).
const COLUMNS_MIN_ELONGATION: f64 = 1.25;

/// Most quadrature nodes of one target; beyond it the spacing grows (a very near target).
const MAX_NODES: usize = 40_000;

/// How far a node's point source reaches, px: the PSF's radius and a pixel. The nodes left out as deep are
/// those deeper than twice this: with a split PSF ([`SplitPsf`]) the tail, read bilinearly between its samples,
/// reaches up to a pixel further along a diagonal than the whole PSF, where it is under 0.75 of the PSF at its
/// kernel's radius (tapered there), so what it could leave out of a pixel that is not deep is negligible.
fn reach_px(psf: &Psf) -> f64 {
    table_reach_px(psf.points())
}

/// How far a point source of a table reaches, px: its radius and a pixel.
fn table_reach_px(table: &PhaseTable) -> f64 {
    table.radius_px() as f64 + 1.0
}

/// The pixels the target's image covers: the ellipse's box grown by the PSF's region radius
/// ([`Psf::region_radius_px`]) and a pixel, clipped to the frame, plus a one-pixel margin for the fusion
/// boundary; empty if off-frame.
pub fn psf_region(ellipse: &ImageEllipse, psf: &Psf, width: usize, height: usize) -> PixelRect {
    let [x0, y0, x1, y1] = ellipse.bbox();
    let grow = psf.region_radius_px() as f64 + 1.5;
    PixelRect::clipped(
        [(x0 - grow).floor(), (y0 - grow).floor(), (x1 + grow).ceil(), (y1 + grow).ceil()],
        width,
        height,
    )
}

/// Renders `amplitude·∫_E PSF(p − x) dx` at the centres of the pixels of `rect` into `out` (row-major,
/// `rect.width()` wide, overwritten); returns the largest value written. `spread`: no other patch is drawn
/// beside this one, so a patch of a few hundred nodes is worth splitting across the pool's threads (the values
/// are the same either way; two patches drawn side by side and split as well were slower). The same values as
/// [`render_target_shape`] and then [`scale_patch`], which the pipeline calls apart: the shape needs no
/// background, so it is drawn beside the render.
///
/// # Panics
/// If `out` is shorter than the rectangle.
pub fn render_target(
    ellipse: &ImageEllipse,
    amplitude: f32,
    psf: &Psf,
    spec: &TargetPsfSpec,
    rect: PixelRect,
    out: &mut [f32],
    spread: bool,
) -> f32 {
    render_target_shape(ellipse, psf, spec, rect, out, spread);
    scale_patch(&mut out[..rect.width() * rect.height()], amplitude)
}

/// The target's shape: `∫_E PSF(p − x) dx` (unit amplitude) at the centres of the pixels of `rect`, into `out`
/// (row-major, `rect.width()` wide, overwritten); `spread` as in [`render_target`].
///
/// # Panics
/// If `out` is shorter than the rectangle.
pub fn render_target_shape(
    ellipse: &ImageEllipse,
    psf: &Psf,
    spec: &TargetPsfSpec,
    rect: PixelRect,
    out: &mut [f32],
    spread: bool,
) {
    let w = rect.width();
    assert!(out.len() >= w * rect.height(), "patch buffer too short");
    let out = &mut out[..w * rect.height()];
    out.fill(0.0);
    if rect.is_empty() {
        return;
    }
    // the thread's buffer is taken out while the bands run: a thread waiting for a band may run another target
    // (rayon runs queued work while it waits), which must not find the buffer borrowed
    let mut nodes = NODES.take();
    nodes.clear();
    let push = |x, y, weight| nodes.push((x, y, weight));
    let rings = match spec.method {
        TargetMethod::Auto => column_nodes(ellipse, psf, spec.node_spacing_px, spec.seven_point_max_px, push),
        TargetMethod::Rings => quadrature_nodes(ellipse, psf, spec.node_spacing_px, spec.seven_point_max_px, push),
        TargetMethod::Reference => quadrature_nodes(ellipse, psf, spec.node_spacing_px, 0.0, push),
    };
    scatter_nodes(psf, psf.split(spec.core_px), &nodes, rect, out, spread);
    NODES.set(nodes);
    if rings {
        fill_deep_pixels(ellipse, psf, rect, out);
    }
}

/// Multiplies a shape from [`render_target_shape`] by `amplitude` in place; returns the value of largest
/// magnitude (the first of equal ones; 0 for an empty patch).
pub fn scale_patch(values: &mut [f32], amplitude: f32) -> f32 {
    let mut peak = 0.0f32;
    for v in values.iter_mut() {
        *v *= amplitude;
        if v.abs() > peak.abs() {
            peak = *v;
        }
    }
    peak
}

/// Gives `node(x, y, weight)` each of the quadrature's nodes in turn (px, px, share of the area in px²; unit
/// amplitude); returns whether they were rings (which leave out the nodes that reach only the deep pixels, see
/// [`fill_deep_pixels`]).
fn quadrature_nodes(
    e: &ImageEllipse,
    psf: &Psf,
    spacing: f64,
    seven_point_max: f64,
    mut node: impl FnMut(f64, f64, f32),
) -> bool {
    let area = e.area_px2();
    let (s, c) = e.angle_rad.sin_cos();
    let at = |u: f64, v: f64| (e.center.x + u * e.a * c - v * e.b * s, e.center.y + u * e.a * s + v * e.b * c);
    if e.a < 0.01 {
        node(e.center.x, e.center.y, area as f32);
        return false;
    }
    if e.a <= seven_point_max {
        node(e.center.x, e.center.y, (0.25 * area) as f32);
        let r = (2.0f64 / 3.0).sqrt();
        for k in 0..6 {
            let phi = std::f64::consts::FRAC_PI_3 * k as f64;
            let (x, y) = at(r * phi.cos(), r * phi.sin());
            node(x, y, (0.125 * area) as f32);
        }
        return false;
    }
    // rings of width `spacing` along the major axis; on ring i (unit radii r0..r1) points `spacing` apart at the
    // ring's area-weighted mean radius
    let ring = |i: usize, rings: usize| -> (f64, f64, f64) {
        let (r0, r1) = (i as f64 / rings as f64, (i + 1) as f64 / rings as f64);
        (2.0 / 3.0 * (r1.powi(3) - r0.powi(3)) / (r1 * r1 - r0 * r0), r1 * r1 - r0 * r0, r0)
    };
    // a pixel deeper than `reach` inside receives the whole PSF; nodes deeper than 2·reach reach only such pixels
    let reach = reach_px(psf);
    let needed = |r0: f64| (1.0 - r0) * e.b <= 2.0 * reach + 0.5;
    let count = |h: f64| -> (usize, usize) {
        let rings = (e.a / h).ceil().max(1.0) as usize;
        let total = (0..rings)
            .filter(|&i| needed(ring(i, rings).2))
            .map(|i| (std::f64::consts::TAU * ring(i, rings).0 * e.a / h).ceil().max(1.0) as usize)
            .sum();
        (rings, total)
    };
    let mut spacing = spacing;
    while count(spacing).1 > MAX_NODES {
        spacing *= 1.5;
    }
    let rings = count(spacing).0;
    for i in 0..rings {
        let (r, fraction, r0) = ring(i, rings);
        if !needed(r0) {
            continue;
        }
        let n = (std::f64::consts::TAU * r * e.a / spacing).ceil().max(1.0) as usize;
        let weight = (area * fraction / n as f64) as f32;
        // alternate rings are offset by half a step
        let offset = if i % 2 == 1 { 0.5 } else { 0.0 };
        for k in 0..n {
            let phi = std::f64::consts::TAU * (k as f64 + offset) / n as f64;
            let (x, y) = at(r * phi.cos(), r * phi.sin());
            node(x, y, weight);
        }
    }
    true
}

/// The nodes of [`TargetMethod::Auto`]: the seven-point rule for a small ellipse, rings ([`quadrature_nodes`])
/// for a round one (`a` under [`COLUMNS_MIN_ELONGATION`]·`b`), else columns across the major axis `spacing` wide
/// at most. Each column holds its exact share of the area (the slice of the ellipse between its edges): the part
/// as wide as the column (under the chord at its outer edge) on two-point Gauss–Legendre nodes along the column's
/// middle, on segments of the chord two `spacing`s long at most; the two thin parts where the ellipse's edge
/// crosses the column on nodes `spacing` apart at most, each at the middle of the column's width at its height,
/// sharing the rest of the slice's area in proportion to those widths. So the nodes lie about `spacing` apart
/// each way in pixels whatever the ellipse's elongation, where rings `spacing` apart along the major axis crowd
/// the minor one `a/b` times more: supersonic_climb's 5.8 × 1.25 px target takes 368 nodes against 1228, with
/// errors against the reference of the same size (`columns_are_as_close_to_the_reference_as_rings`). Nodes
/// deeper than twice the PSF's reach are left out, as for rings; returns whether any could have been (whether
/// [`fill_deep_pixels`] applies).
fn column_nodes(
    e: &ImageEllipse,
    psf: &Psf,
    spacing: f64,
    seven_point_max: f64,
    mut node: impl FnMut(f64, f64, f32),
) -> bool {
    if e.a <= seven_point_max || e.a < 0.01 || e.a < COLUMNS_MIN_ELONGATION * e.b {
        return quadrature_nodes(e, psf, spacing, seven_point_max, node);
    }
    let reach = reach_px(psf);
    // the spacing grows, as the rings' does, until the nodes kept fit the cap; they are counted only where a
    // bound on them does not fit already (a column holds at most 2·⌈b/spacing⌉ nodes on its full part and as many
    // on its thin parts)
    let mut spacing = spacing;
    loop {
        let columns_at = (2.0 * e.a / spacing).ceil().max(1.0);
        if columns_at * 4.0 * ((e.b / spacing).ceil() + 1.0) <= MAX_NODES as f64 {
            break;
        }
        let mut count = 0;
        columns(e, reach, spacing, &mut |_, _, _| count += 1);
        if count <= MAX_NODES {
            break;
        }
        spacing *= 1.5;
    }
    columns(e, reach, spacing, &mut node);
    true
}

/// The nodes of [`column_nodes`] at `spacing`, those deeper than `2·reach + ½` inside the ellipse left out
/// (whole runs of them in a column's middle are never visited, so a large ellipse costs its rim alone).
fn columns(e: &ImageEllipse, reach: f64, spacing: f64, node: &mut impl FnMut(f64, f64, f32)) {
    let (s, c) = e.angle_rad.sin_cos();
    let at = |u: f64, v: f64| (e.center.x + u * c - v * s, e.center.y + u * s + v * c);
    let depth = 2.0 * reach + 0.5;
    let kept = |u: f64, v: f64| (1.0 - ((u / e.a).powi(2) + (v / e.b).powi(2)).sqrt()) * e.b <= depth;
    let count = (2.0 * e.a / spacing).ceil().max(1.0) as usize;
    // ∫ 2·√(1 − t²) dt from −1 to t: the slice's area in units of a·b
    let area_to = |t: f64| t * (1.0 - t * t).max(0.0).sqrt() + t.clamp(-1.0, 1.0).asin();
    let chord = |u: f64| e.b * (1.0 - (u / e.a).powi(2)).max(0.0).sqrt();
    let g = 0.5 / 3f64.sqrt();
    for k in 0..count {
        let (t0, t1) = (-1.0 + 2.0 * k as f64 / count as f64, -1.0 + 2.0 * (k + 1) as f64 / count as f64);
        let area = e.a * e.b * (area_to(t1) - area_to(t0));
        if !(area > 0.0) {
            continue;
        }
        let (u0, u1) = (t0 * e.a, t1 * e.a);
        let middle_u = 0.5 * (u0 + u1);
        // the part of the slice as wide as the column (|v| under the chord at its outer edge), and the two thin
        // parts above and below it, where the ellipse's edge crosses the column
        let (outer, inner) = (chord(u0).min(chord(u1)), chord(0f64.clamp(u0, u1)));
        let full = (u1 - u0) * 2.0 * outer;
        // two-point Gauss–Legendre on segments of the chord two spacings long at most; the segments between
        // ±`deep` hold deep nodes alone (the range visited is one segment wider each way than that, and each node
        // is tested, so rounding at the bounds leaves out no node that is kept)
        let segments = (outer / spacing).ceil() as usize;
        let length = 2.0 * outer / segments.max(1) as f64;
        let shrunk = 1.0 - depth / e.b;
        let deep = if shrunk > 0.0 { e.b * (shrunk * shrunk - (middle_u / e.a).powi(2)).max(0.0).sqrt() } else { 0.0 };
        let below = (((outer - deep) / length).ceil() as usize + 1).min(segments);
        let above = (((outer + deep) / length).floor() as usize).saturating_sub(1).clamp(below, segments);
        for j in (0..below).chain(above..segments) {
            let middle = -outer + (j as f64 + 0.5) * length;
            for side in [-g, g] {
                let v = middle + side * length;
                if kept(middle_u, v) {
                    let (x, y) = at(middle_u, v);
                    node(x, y, (0.5 * full / segments as f64) as f32);
                }
            }
        }
        let thin = (area - full).max(0.0);
        if thin > 0.0 && inner > outer {
            let rows = ((inner - outer) / spacing).ceil().max(1.0) as usize;
            // row j's cell: the middle of the column's width at its height, the height, and that width
            let cell = |j: usize| {
                let v = outer + (j as f64 + 0.5) * (inner - outer) / rows as f64;
                let width = e.a * (1.0 - (v / e.b).powi(2)).max(0.0).sqrt();
                let (lo, hi) = (u0.max(-width), u1.min(width));
                (hi > lo).then_some((0.5 * (lo + hi), v, hi - lo))
            };
            // the upper thin part's cells take half the thin area in proportion to their widths; the lower are
            // their mirror images
            let widths: f64 = (0..rows).filter_map(cell).map(|c| c.2).sum();
            for sign in [1.0, -1.0] {
                for (u, v, width) in (0..rows).filter_map(cell) {
                    if kept(u, sign * v) {
                        let (x, y) = at(u, sign * v);
                        node(x, y, (0.5 * thin * width / widths) as f32);
                    }
                }
            }
        }
    }
}

/// Sets the pixels of `rect` deeper inside the ellipse than the PSF's reach to 1: the whole (unit-integral)
/// PSF lies inside it there (the ring nodes that would reach only such pixels are left out).
fn fill_deep_pixels(e: &ImageEllipse, psf: &Psf, rect: PixelRect, out: &mut [f32]) {
    let reach = reach_px(psf);
    if (e.b - reach) <= 0.0 {
        return;
    }
    let (s, c) = e.angle_rad.sin_cos();
    let w = rect.width();
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            let (dx, dy) = (x as f64 + 0.5 - e.center.x, y as f64 + 0.5 - e.center.y);
            let (u, v) = ((dx * c + dy * s) / e.a, (-dx * s + dy * c) / e.b);
            let rho = u.hypot(v);
            if (1.0 - rho) * e.b > reach {
                out[(y - rect.y0) * w + x - rect.x0] = 1.0;
            }
        }
    }
}

thread_local! {
    /// Each thread's quadrature nodes `(x, y, weight)` of the target it renders (kept from call to call).
    static NODES: std::cell::RefCell<Vec<(f64, f64, f32)>> = const { std::cell::RefCell::new(Vec::new()) };
    /// Each thread's nodes binned to pixels for a split PSF's tail (kept from call to call).
    static BINS: std::cell::RefCell<Bins> = const { std::cell::RefCell::new(Bins::new()) };
}

/// Rows of the bands a large patch is split into, filled side by side.
const BAND_ROWS: usize = 32;
/// Fewest nodes worth splitting a patch for.
const BAND_MIN_NODES: usize = 2_000;
/// Least work worth splitting a patch drawn alone across the pool's threads, in pixels written: the nodes times
/// the `(2r + 2)²` pixels each writes from a table of radius `r` ([`worth_spreading`]). Each band goes through every
/// node that reaches it, so a band of few rows repeats most nodes' set-up. Measured with the whole PSF at each node
/// (a 12 px kernel, 676 pixels a node): with rings, supersonic_climb's 1233-node target went from 331–332 to
/// 251–257 µs a frame on two threads, while two targets of 800–1200 nodes drawn side by side (crossing_pair) lost
/// 278–304 → 336–347 µs when split as well; its 368 nodes from columns still paid, targets stage 121–123 µs split
/// against 138–144 not split (`irsim bench --frames 1000`, three interleaved rounds, one of them too noisy to count;
/// paper_clear_sky's target the same either way). With the PSF split at a core of 4 px (100 pixels a node) the same
/// 368 nodes no longer paid: 120–130 µs split against 85–91 not split, and 971–1003 against 992–1046 frames/s
/// (`irsim bench S --frames 1500`, four alternating rounds). So the bound is in work, 300 nodes of the whole 12 px
/// kernel.
const SPREAD_MIN_WORK: usize = 300 * 26 * 26;
/// Fewest rows of a band of a patch split across the threads.
const SPREAD_MIN_ROWS: usize = 8;

/// Adds every node's point source to the patch `rect` (`out`): the whole PSF at each node ([`scatter`]), or with
/// `split` its core at each node and its tail once from the nodes binned to pixels ([`add_tail`]). A patch of many
/// nodes and rows is split into bands of [`BAND_ROWS`] rows, filled in parallel, each from the nodes that reach it
/// in their order, where one large target had filled its patch on one thread; with `spread`, a patch of fewer (at
/// least [`SPREAD_MIN_WORK`] and twice [`SPREAD_MIN_ROWS`] rows) into bands of one thread's share of the
/// rows, [`SPREAD_MIN_ROWS`] at least. Every pixel gets the same sums, to the bit, as from one pass, however the
/// rows are split.
fn scatter_nodes(
    psf: &Psf,
    split: Option<&SplitPsf>,
    nodes: &[(f64, f64, f32)],
    rect: PixelRect,
    out: &mut [f32],
    spread: bool,
) {
    use rayon::prelude::*;
    let rows = rect.height();
    let w = rect.width();
    let table = split.map_or(psf.points(), SplitPsf::core);
    // the nodes binned for the tail, taken out of the thread's buffer while the bands run (as the nodes are)
    let mut bins = BINS.take();
    if let Some(split) = split {
        bins.bin(nodes, rect, split.tail_radius_px());
    }
    let tail = split.map(|s| (s, &bins));
    let threads = rayon::current_num_threads();
    let band_rows = if nodes.len() >= BAND_MIN_NODES && rows >= 2 * BAND_ROWS {
        BAND_ROWS
    } else if spread && threads > 1 && worth_spreading(table, nodes.len(), rows) {
        rows.div_ceil(threads).max(SPREAD_MIN_ROWS)
    } else {
        for &(x, y, weight) in nodes {
            scatter(table, x, y, weight, rect, rect.y0..rect.y1, out);
        }
        if let Some((split, bins)) = tail {
            add_tail(split, bins, rect, rect.y0..rect.y1, out);
        }
        BINS.set(bins);
        return;
    };
    out[..rows * w].par_chunks_mut(band_rows * w).enumerate().for_each(|(b, band)| {
        let (y0, y1) = (rect.y0 + b * band_rows, (rect.y0 + (b + 1) * band_rows).min(rect.y1));
        // a node reaches the rows within the table's reach of it (as scatter clips them)
        let reach = table_reach_px(table);
        for &(x, y, weight) in nodes {
            if y + reach > y0 as f64 - 1.0 && y - reach < y1 as f64 + 1.0 {
                scatter(table, x, y, weight, rect, y0..y1, band);
            }
        }
        if let Some((split, bins)) = tail {
            add_tail(split, bins, rect, y0..y1, band);
        }
    });
    BINS.set(bins);
}

/// Whether a patch of `nodes` nodes of `table` and `rows` rows, drawn alone, is worth splitting across the pool's
/// threads ([`SPREAD_MIN_WORK`], [`SPREAD_MIN_ROWS`]).
fn worth_spreading(table: &PhaseTable, nodes: usize, rows: usize) -> bool {
    let per_node = (2 * table.radius_px() + 2).pow(2);
    nodes * per_node >= SPREAD_MIN_WORK && rows >= 2 * SPREAD_MIN_ROWS
}

/// Adds a point source of `weight` px² at `(x, y)` to the pixels of `rect` within the table's reach, on the rows
/// `rows` of the patch alone, into `out`, whose first element is pixel `(rect.x0, rows.start)`.
#[inline]
fn scatter(
    table: &PhaseTable,
    x: f64,
    y: f64,
    weight: f32,
    rect: PixelRect,
    rows: std::ops::Range<usize>,
    out: &mut [f32],
) {
    let reach = table_reach_px(table);
    let lo = |v: f64, min: usize| ((v - reach).floor().max(min as f64)) as usize;
    let hi = |v: f64, max: usize| ((v + reach).ceil().max(0.0) as usize).min(max);
    let (px0, px1) = (lo(x, rect.x0), hi(x, rect.x1));
    let (py0, py1) = (lo(y, rect.y0), hi(y, rect.y1));
    let (r0, r1) = (py0.max(rows.start), py1.min(rows.end));
    if px0 >= px1 || r0 >= r1 {
        return;
    }
    let w = rect.width();
    let start = (r0 - rows.start) * w + px0 - rect.x0;
    table.add_point_rows(x, y, weight, [px0, py0, px1, py1], r0..r1, &mut out[start..], w);
}

/// Nodes' weights binned to the pixel grid: each node's shared among the four pixel centres around it with
/// bilinear weights, on the pixels from `(x0, y0)` (which may lie off the frame), `w × h` of them.
#[derive(Debug, Default)]
struct Bins {
    x0: isize,
    y0: isize,
    w: usize,
    h: usize,
    values: Vec<f32>,
}

impl Bins {
    const fn new() -> Self {
        Self { x0: 0, y0: 0, w: 0, h: 0, values: Vec::new() }
    }

    /// Bins `nodes` on the pixels whose tail, `radius` px wide, may reach `rect` (the others are left out: they
    /// add nothing to it).
    fn bin(&mut self, nodes: &[(f64, f64, f32)], rect: PixelRect, radius: usize) {
        let r = radius as f64;
        let (lo_x, hi_x) = (rect.x0 as f64 - r, rect.x1 as f64 + r);
        let (lo_y, hi_y) = (rect.y0 as f64 - r, rect.y1 as f64 + r);
        // the pixel whose centre is at or before a coordinate, and the fraction of a pixel past it; a node whose
        // four pixels all lie outside the bins' reach (or a coordinate that is not finite) is left out, before the
        // coordinate is made an integer
        let cell = |v: f64, lo: f64, hi: f64| {
            let f = (v - 0.5).floor();
            (f >= lo - 1.0 && f <= hi).then_some((f as isize, (v - 0.5 - f) as f32))
        };
        let at = |&(x, y, _): &(f64, f64, f32)| cell(x, lo_x, hi_x).zip(cell(y, lo_y, hi_y));
        let (mut x0, mut y0, mut x1, mut y1) = (isize::MAX, isize::MAX, isize::MIN, isize::MIN);
        for ((i, _), (j, _)) in nodes.iter().filter_map(at) {
            (x0, y0, x1, y1) = (x0.min(i), y0.min(j), x1.max(i + 1), y1.max(j + 1));
        }
        (x0, y0) = (x0.max(lo_x as isize), y0.max(lo_y as isize));
        (x1, y1) = (x1.min(hi_x as isize), y1.min(hi_y as isize));
        self.values.clear();
        if x0 > x1 || y0 > y1 {
            (self.w, self.h) = (0, 0);
            return;
        }
        (self.x0, self.y0, self.w, self.h) = (x0, y0, (x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
        self.values.resize(self.w * self.h, 0.0);
        for (node, ((i, tx), (j, ty))) in nodes.iter().filter_map(|n| at(n).map(|c| (n, c))) {
            let weight = node.2;
            for (di, dj, share) in
                [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
            {
                let (u, v) = (i + di - x0, j + dj - y0);
                if u >= 0 && v >= 0 && (u as usize) < self.w && (v as usize) < self.h {
                    self.values[v as usize * self.w + u as usize] += weight * share;
                }
            }
        }
    }
}

/// Adds `split`'s tail from the binned nodes `bins` to the pixels of `rect` on its rows `rows`, into `out`, whose
/// first element is pixel `(rect.x0, rows.start)`: each pixel takes the bins in the same order whatever the rows.
fn add_tail(split: &SplitPsf, bins: &Bins, rect: PixelRect, rows: std::ops::Range<usize>, out: &mut [f32]) {
    let r = split.tail_radius_px() as isize;
    let side = (2 * r + 1) as usize;
    let tail = split.tail();
    let w = rect.width();
    let (rows_lo, rows_hi) = (rows.start as isize, rows.end as isize);
    widest(
        #[inline(always)]
        || {
            for v in 0..bins.h {
                let cy = bins.y0 + v as isize;
                let (ya, yb) = ((cy - r).max(rows_lo), (cy + r + 1).min(rows_hi));
                if ya >= yb {
                    continue;
                }
                for u in 0..bins.w {
                    let weight = bins.values[v * bins.w + u];
                    if weight == 0.0 {
                        continue;
                    }
                    let cx = bins.x0 + u as isize;
                    let (xa, xb) = ((cx - r).max(rect.x0 as isize), (cx + r + 1).min(rect.x1 as isize));
                    if xa >= xb {
                        continue;
                    }
                    let n = (xb - xa) as usize;
                    for y in ya..yb {
                        let t = ((y - cy + r) as usize) * side + (xa - cx + r) as usize;
                        let o = (y - rows_lo) as usize * w + (xa as usize - rect.x0);
                        for (o, t) in out[o..o + n].iter_mut().zip(&tail[t..t + n]) {
                            *o += weight * t;
                        }
                    }
                }
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::psf::{PsfOptics, PsfSpec};
    use crate::physics::planck::{Band, Measure};
    use glam::DVec2;

    /// A fast LWIR lens: F/1, 12 µm pixels, 7.5–13.5 µm.
    fn lwir() -> PsfOptics {
        PsfOptics {
            f_number: 1.0,
            pixel_pitch_m: 12e-6,
            fill_factor: 1.0,
            band: Band::try_new(7.5, 13.5).unwrap(),
            measure: Measure::Energy,
            reference_temp_k: 300.0,
        }
    }

    /// A slow MWIR lens: F/4, 15 µm pixels, 3–5 µm.
    fn mwir() -> PsfOptics {
        PsfOptics { f_number: 4.0, pixel_pitch_m: 15e-6, band: Band::MWIR_3_5, ..lwir() }
    }

    fn psf() -> Psf {
        Psf::new(&PsfSpec::default(), &lwir()).unwrap()
    }

    /// The target `e` drawn at unit amplitude with `spec` into `rect`, on one pass.
    fn draw(e: &ImageEllipse, psf: &Psf, spec: &TargetPsfSpec, rect: PixelRect) -> Vec<f32> {
        let mut out = vec![0.0; rect.width() * rect.height()];
        render_target(e, 1.0, psf, spec, rect, &mut out, false);
        out
    }

    fn render(e: &ImageEllipse, psf: &Psf, method: TargetMethod) -> (PixelRect, Vec<f32>) {
        let rect = psf_region(e, psf, 200, 200);
        // the reference at the reference preset's spacing
        let node_spacing_px =
            if method == TargetMethod::Reference { REFERENCE_NODE_SPACING_PX } else { NODE_SPACING_PX };
        // the whole PSF at every node: the quadrature's own error (the split's is measured apart)
        let spec = TargetPsfSpec { method, node_spacing_px, core_px: 0, ..TargetPsfSpec::default() };
        (rect, draw(e, psf, &spec, rect))
    }

    fn centroid(rect: PixelRect, v: &[f32]) -> (DVec2, f64) {
        let (mut sum, mut m) = (0.0, DVec2::ZERO);
        for (i, &x) in v.iter().enumerate() {
            let p = DVec2::new((rect.x0 + i % rect.width()) as f64 + 0.5, (rect.y0 + i / rect.width()) as f64 + 0.5);
            sum += f64::from(x);
            m += p * f64::from(x);
        }
        (m / sum, sum)
    }

    #[test]
    fn flux_and_centroid_are_kept() {
        let psf = psf();
        for (a, b, angle, cx, cy) in [
            (0.05, 0.02, 0.3, 100.27, 80.61),
            (0.6, 0.2, -0.7, 50.5, 50.0),
            (3.0, 2.2, 1.1, 120.13, 40.9),
            (12.0, 5.0, 0.4, 90.3, 90.7),
        ] {
            let e = ImageEllipse { center: DVec2::new(cx, cy), a, b, angle_rad: angle };
            let (rect, reference) = render(&e, &psf, TargetMethod::Reference);
            let (want, _) = centroid(rect, &reference);
            let (rect, v) = render(&e, &psf, TargetMethod::Auto);
            let (c, flux) = centroid(rect, &v);
            let area = e.area_px2();
            // the pixel aperture's sinc vanishes at every non-zero integer frequency: the sampled flux is exact
            assert!(((flux - area) / area).abs() < 2e-3, "a={a}: flux {flux} vs area {area}");
            assert!((c - want).length() < 2e-3, "a={a}: centroid {c} vs the reference's {want}");
            // the sampling bias toward pixel centres is a fraction of a pixel at most
            assert!((c - e.center).length() < 0.05, "a={a}: centroid {c} vs the centre {}", e.center);
        }
    }

    #[test]
    fn auto_is_close_to_the_reference() {
        let psf = psf();
        let mut worst: f64 = 0.0;
        for (a, b) in
            [(0.1, 0.05), (0.5, 0.3), (0.6, 0.6), (0.61, 0.6), (1.2, 0.6), (2.0, 2.0), (6.0, 3.0), (15.0, 9.0)]
        {
            let e = ImageEllipse { center: DVec2::new(60.37, 61.81), a, b, angle_rad: 0.5 };
            let (_, got) = render(&e, &psf, TargetMethod::Auto);
            let (_, want) = render(&e, &psf, TargetMethod::Reference);
            let peak = want.iter().fold(0.0f32, |m, v| m.max(*v));
            let err = got.iter().zip(&want).map(|(g, w)| (g - w).abs()).fold(0.0f32, f32::max) / peak;
            worst = worst.max(f64::from(err));
            assert!(err < 0.01, "a={a} b={b}: max error {err} of the peak");
        }
        eprintln!("worst error of auto against the reference: {worst:.4} of the peak");
    }

    #[test]
    fn draft_spacing_error() {
        // the auto quadrature 0.6 px apart (the draft preset's: rings or columns) against the reference, on
        // ellipses large enough to have more than seven points
        let psf = psf();
        let mut worst: f64 = 0.0;
        for (a, b) in [(0.61, 0.6), (1.2, 0.6), (2.0, 2.0), (5.8, 1.25), (6.0, 3.0), (15.0, 9.0)] {
            let e = ImageEllipse { center: DVec2::new(60.37, 61.81), a, b, angle_rad: 0.5 };
            let rect = psf_region(&e, &psf, 200, 200);
            let mut got = vec![0.0; rect.width() * rect.height()];
            let spec = TargetPsfSpec { node_spacing_px: 0.6, core_px: 0, ..TargetPsfSpec::default() };
            render_target(&e, 1.0, &psf, &spec, rect, &mut got, false);
            let (_, want) = render(&e, &psf, TargetMethod::Reference);
            let peak = want.iter().fold(0.0f32, |m, v| m.max(*v));
            let err = got.iter().zip(&want).map(|(g, w)| (g - w).abs()).fold(0.0f32, f32::max) / peak;
            let flux: f64 = got.iter().map(|&v| f64::from(v)).sum();
            worst = worst.max(f64::from(err));
            assert!(((flux - e.area_px2()) / e.area_px2()).abs() < 2e-3, "a={a} b={b}: flux {flux}");
            assert!(err < DRAFT_SPACING_MAX_ERROR, "a={a} b={b}: max error {err} of the peak");
        }
        eprintln!("worst error of the auto quadrature at 0.6 px against the reference: {worst:.4} of the peak");
    }

    /// Largest error of the auto quadrature 0.6 px apart against the reference, as a fraction of the target's peak.
    const DRAFT_SPACING_MAX_ERROR: f32 = 0.03;

    #[test]
    fn a_banded_patch_is_the_one_pass_patch_bit_for_bit() {
        let psf = psf();
        let e = ImageEllipse { center: DVec2::new(100.3, 90.7), a: 45.0, b: 30.0, angle_rad: 0.4 };
        let rect = psf_region(&e, &psf, 200, 200);
        let mut nodes = Vec::new();
        quadrature_nodes(&e, &psf, NODE_SPACING_PX, 0.6, |x, y, w| nodes.push((x, y, w)));
        assert!(nodes.len() >= BAND_MIN_NODES && rect.height() >= 2 * BAND_ROWS, "the patch is split");
        // the whole PSF at each node, and split
        assert!(psf.split(CORE_PX).is_some());
        for split in [None, psf.split(CORE_PX)] {
            let mut banded = vec![0f32; rect.width() * rect.height()];
            scatter_nodes(&psf, split, &nodes, rect, &mut banded, false);
            let mut one = vec![0f32; rect.width() * rect.height()];
            for &(x, y, w) in &nodes {
                scatter(split.map_or(psf.points(), SplitPsf::core), x, y, w, rect, rect.y0..rect.y1, &mut one);
            }
            if let Some(split) = split {
                let mut bins = Bins::default();
                bins.bin(&nodes, rect, split.tail_radius_px());
                add_tail(split, &bins, rect, rect.y0..rect.y1, &mut one);
            }
            assert!(one.iter().any(|&v| v > 0.5));
            for (i, (a, b)) in banded.iter().zip(&one).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "pixel {i}");
            }
        }
    }

    #[test]
    fn large_targets_render_side_by_side() {
        // several split patches at once on a pool of two (a thread waiting for one target's band may run another
        // target's work, which must find its node buffer free): each patch is what it is alone
        let psf = psf();
        let ellipses: Vec<ImageEllipse> = (0..12)
            .map(|k| {
                let a = 30.0 + 5.0 * (k % 4) as f64;
                ImageEllipse { center: DVec2::new(100.3 + k as f64, 90.7), a, b: 0.7 * a, angle_rad: 0.4 }
            })
            .collect();
        let alone: Vec<Vec<f32>> = ellipses.iter().map(|e| render(e, &psf, TargetMethod::Auto).1).collect();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        for _ in 0..10 {
            let together: Vec<Vec<f32>> = pool.install(|| {
                use rayon::prelude::*;
                ellipses.par_iter().with_max_len(1).map(|e| render(e, &psf, TargetMethod::Auto).1).collect()
            });
            assert_eq!(together, alone);
        }
    }

    #[test]
    fn a_patch_spread_across_threads_is_the_patch_drawn_on_one() {
        // supersonic_climb's target (some 370 nodes, 30 rows) and a smaller one on its F/4 MWIR PSF (a 12 px
        // kernel, drawn whole at each node), split into bands on pools of two and three threads: every pixel the
        // same, to the bit, as drawn in one pass
        let psf = &standard_cut_psfs()[1].1;
        for (a, b) in [(5.83, 1.25), (4.0, 2.5)] {
            let e = ImageEllipse { center: DVec2::new(60.37, 61.81), a, b, angle_rad: 0.3 };
            let (rect, alone) = render(&e, psf, TargetMethod::Auto);
            let mut nodes = 0;
            column_nodes(&e, psf, NODE_SPACING_PX, 0.6, |_, _, _| nodes += 1);
            assert!(worth_spreading(psf.points(), nodes, rect.height()), "{nodes} nodes");
            for threads in [2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut got = vec![0.0; rect.width() * rect.height()];
                // the whole PSF at each node, as `render` draws it (the split's own test follows)
                let spec = TargetPsfSpec { core_px: 0, ..TargetPsfSpec::default() };
                pool.install(|| render_target(&e, 1.0, psf, &spec, rect, &mut got, true));
                assert!(got.iter().zip(&alone).all(|(g, w)| g.to_bits() == w.to_bits()), "{a} × {b}, {threads}");
            }
        }
    }

    #[test]
    fn columns_are_as_close_to_the_reference_as_rings() {
        // elongated ellipses, on a fast LWIR PSF (F/1, 12 µm) and a slow MWIR one (F/4, 15 µm)
        let mut worst = [0.0f32; 2];
        for psf in [psf(), Psf::new(&PsfSpec::default(), &mwir()).unwrap()] {
            for (a, b) in [(1.2, 0.6), (3.0, 0.4), (5.8, 1.25), (6.0, 3.0), (15.0, 9.0), (20.0, 2.0)] {
                let e = ImageEllipse { center: DVec2::new(60.37, 61.81), a, b, angle_rad: 0.5 };
                let rect = psf_region(&e, &psf, 200, 200);
                let draw = |method: TargetMethod, node_spacing_px: f64| {
                    let spec = TargetPsfSpec { method, node_spacing_px, core_px: 0, ..TargetPsfSpec::default() };
                    draw(&e, &psf, &spec, rect)
                };
                let want = draw(TargetMethod::Reference, REFERENCE_NODE_SPACING_PX);
                let peak = want.iter().fold(0.0f32, |m, v| m.max(*v));
                let error = |got: &[f32]| got.iter().zip(&want).map(|(g, w)| (g - w).abs()).fold(0.0, f32::max) / peak;
                let columns = draw(TargetMethod::Auto, NODE_SPACING_PX);
                let rings = draw(TargetMethod::Reference, NODE_SPACING_PX);
                let (mut by_columns, mut by_rings) = (0, 0);
                column_nodes(&e, &psf, NODE_SPACING_PX, 0.6, |_, _, _| by_columns += 1);
                quadrature_nodes(&e, &psf, NODE_SPACING_PX, 0.6, |_, _, _| by_rings += 1);
                let flux: f64 = columns.iter().map(|&v| f64::from(v)).sum();
                eprintln!(
                    "{a} × {b}: columns {by_columns} nodes, error {:.4}; rings {by_rings}, {:.4}",
                    error(&columns),
                    error(&rings)
                );
                assert!(by_columns < by_rings, "{a} × {b}: {by_columns} against {by_rings} nodes");
                assert!(((flux - e.area_px2()) / e.area_px2()).abs() < 1e-3, "{a} × {b}: flux {flux}");
                worst = [worst[0].max(error(&columns)), worst[1].max(error(&rings))];
            }
        }
        // measured: columns 0.0051 of the peak at worst, rings at the same spacing 0.0044
        assert!(worst[0] < 0.006 && worst[0] < 1.5 * worst[1], "columns {} against rings {}", worst[0], worst[1]);
    }

    #[test]
    fn columns_leave_out_only_deep_nodes_and_keep_to_the_cap() {
        let psf = psf();
        let reach = reach_px(&psf);
        // a target deep enough for many of its nodes to be left out: the same image as rings within 1 % of its
        // peak (measured 0.72 %; each differs from drawing every node by about 0.5 %: the deep pixels' whole PSF
        // is 1, the sum of its table a little less), and the same flux
        let e = ImageEllipse { center: DVec2::new(100.37, 100.81), a: 60.0, b: 40.0, angle_rad: 0.5 };
        let rect = psf_region(&e, &psf, 200, 200);
        let draw = |method: TargetMethod| draw(&e, &psf, &TargetPsfSpec { method, ..TargetPsfSpec::default() }, rect);
        let (by_columns, by_rings) = (draw(TargetMethod::Auto), draw(TargetMethod::Rings));
        let error = by_columns.iter().zip(&by_rings).map(|(c, r)| (c - r).abs()).fold(0.0, f32::max);
        let flux: f64 = by_columns.iter().map(|&v| f64::from(v)).sum();
        assert!(error < 0.01, "columns against rings: {error} of the peak (1)");
        assert!(((flux - e.area_px2()) / e.area_px2()).abs() < 1e-3, "flux {flux}");
        let (mut kept, mut all) = (0, 0);
        columns(&e, reach, NODE_SPACING_PX, &mut |_, _, _| kept += 1);
        columns(&e, 1e9, NODE_SPACING_PX, &mut |_, _, _| all += 1);
        assert!(kept < all * 9 / 10, "{kept} of {all} nodes kept");
        // the cap counts the nodes kept: a large target keeps its spacing while they fit, a long thin one
        // grows it until they do
        for (a, b) in [(200.0, 100.0), (1000.0, 1.0), (3000.0, 1.0)] {
            let e = ImageEllipse { center: DVec2::new(0.0, 0.0), a, b, angle_rad: 0.2 };
            let (mut got, mut at_spacing) = (0, 0);
            column_nodes(&e, &psf, NODE_SPACING_PX, 0.6, |_, _, _| got += 1);
            columns(&e, reach, NODE_SPACING_PX, &mut |_, _, _| at_spacing += 1);
            assert!(got <= MAX_NODES, "{a} × {b}: {got} nodes");
            if at_spacing <= MAX_NODES {
                assert_eq!(got, at_spacing, "{a} × {b}: the spacing grew though the nodes fitted");
            }
        }
    }

    #[test]
    fn a_point_target_is_the_psf() {
        let psf = psf();
        let e = ImageEllipse { center: DVec2::new(30.5, 30.5), a: 0.005, b: 0.004, angle_rad: 0.0 };
        let (rect, v) = render(&e, &psf, TargetMethod::Auto);
        let i = (30 - rect.y0) * rect.width() + (30 - rect.x0);
        let want = e.area_px2() as f32 * psf.value(0.0, 0.0);
        assert!((v[i] - want).abs() < 1e-6 * want.abs().max(1e-12) + 1e-12, "{} vs {want}", v[i]);
    }

    /// The PSFs the split is measured on: a fast LWIR one (F/1, 12 µm) and a slow MWIR one (F/4, 15 µm), each cut
    /// at 1 % of the energy (the standard preset's: 11 and 12 px).
    fn standard_cut_psfs() -> Vec<(&'static str, Psf)> {
        let spec = PsfSpec { energy_cutoff: 0.01, ..PsfSpec::default() };
        vec![("LWIR F/1", Psf::new(&spec, &lwir()).unwrap()), ("MWIR F/4", Psf::new(&spec, &mwir()).unwrap())]
    }

    #[test]
    fn split_psf_error() {
        // a point source at sub-pixel positions across a pixel, drawn with the whole PSF and split at a core of
        // 3 and 4 px; the largest difference against the point's peak, and of the flux. Measured: at 4 px 4.5e-4
        // (LWIR) and 6.5e-4 (MWIR) of the peak, the flux within 3.5e-4; at 3 px 1.5e-3 and 2.4e-3 of the peak,
        // the flux within 1.4e-3
        for (name, psf) in standard_cut_psfs() {
            for (core, bound) in [(3, 2.5e-3), (4, 7e-4)] {
                let split = psf.split(core).expect("a core smaller than the kernel");
                let (mut worst, mut flux_worst) = (0.0f32, 0.0f64);
                for k in 0..49 {
                    let (x, y) = (40.0 + (k % 7) as f64 / 7.0 + 0.03, 41.0 + (k / 7) as f64 / 7.0 + 0.05);
                    let rect = PixelRect::clipped([20.0, 20.0, 62.0, 62.0], 200, 200);
                    let mut whole = vec![0.0; rect.width() * rect.height()];
                    let mut parts = whole.clone();
                    scatter_nodes(&psf, None, &[(x, y, 1.0)], rect, &mut whole, false);
                    scatter_nodes(&psf, Some(split), &[(x, y, 1.0)], rect, &mut parts, false);
                    let peak = whole.iter().fold(0.0f32, |m, v| m.max(*v));
                    let error = whole.iter().zip(&parts).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max) / peak;
                    let flux = |v: &[f32]| v.iter().map(|&v| f64::from(v)).sum::<f64>();
                    flux_worst = flux_worst.max((flux(&whole) - flux(&parts)).abs());
                    worst = worst.max(error);
                }
                eprintln!(
                    "{name} (R = {} px), core {core} px: {worst:.2e} of the peak, flux {flux_worst:.2e}",
                    psf.radius_px()
                );
                assert!(
                    worst < bound && flux_worst < 2e-3,
                    "{name}, core {core}: {worst} of the peak, flux {flux_worst}"
                );
            }
        }
    }

    #[test]
    fn split_targets_are_close_to_the_whole_psf() {
        // ellipses of every quadrature drawn with the whole PSF at each node and split at the standard core, one
        // deep enough for nodes to be left out (60 × 40), and one cut by the frame's edge (its centre 2 px
        // inside)
        for (name, psf) in standard_cut_psfs() {
            let mut worst = 0.0f32;
            let centre = DVec2::new(100.37, 100.81);
            for (a, b, center) in [
                (0.3, 0.2, centre),
                (1.2, 0.6, centre),
                (2.0, 1.9, centre),
                (5.8, 1.25, centre),
                (15.0, 9.0, centre),
                (20.0, 2.0, centre),
                (60.0, 40.0, centre),
                (5.8, 1.25, DVec2::new(2.3, 197.6)),
            ] {
                let e = ImageEllipse { center, a, b, angle_rad: 0.5 };
                let rect = psf_region(&e, &psf, 200, 200);
                let draw =
                    |core_px: usize| draw(&e, &psf, &TargetPsfSpec { core_px, ..TargetPsfSpec::default() }, rect);
                let (whole, split) = (draw(0), draw(CORE_PX));
                let peak = whole.iter().fold(0.0f32, |m, v| m.max(*v));
                let error = whole.iter().zip(&split).map(|(w, s)| (w - s).abs()).fold(0.0, f32::max) / peak;
                eprintln!("{name}, {a} × {b}: {error:.2e} of the peak");
                worst = worst.max(error);
            }
            // measured: 2.9e-4 (LWIR) and 3.7e-4 (MWIR) of the peak at worst
            assert!(worst < 5e-4, "{name}: {worst} of the peak");
        }
    }

    #[test]
    fn a_split_patch_spread_across_threads_is_the_patch_drawn_on_one() {
        // a target of enough nodes to be split across the threads with the split PSF's core (100 pixels a node)
        let psf = &standard_cut_psfs()[1].1;
        let e = ImageEllipse { center: DVec2::new(60.37, 61.81), a: 30.0, b: 10.0, angle_rad: 0.5 };
        let rect = psf_region(&e, psf, 200, 200);
        let spec = TargetPsfSpec::default();
        let mut nodes = 0;
        column_nodes(&e, psf, NODE_SPACING_PX, 0.6, |_, _, _| nodes += 1);
        let core = psf.split(spec.core_px).expect("split").core();
        assert!(nodes < BAND_MIN_NODES || rect.height() < 2 * BAND_ROWS, "{nodes} nodes: banded anyway");
        assert!(worth_spreading(core, nodes, rect.height()), "{nodes} nodes");
        let draw = |threads: usize, spread: bool| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut out = vec![0.0; rect.width() * rect.height()];
            pool.install(|| render_target(&e, 1.0, psf, &spec, rect, &mut out, spread));
            out
        };
        let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
        let one = bits(draw(1, false));
        assert_eq!(bits(draw(2, true)), one);
        assert_eq!(bits(draw(3, true)), one);
    }
}
