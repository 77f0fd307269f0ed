//! A frame's sky background: the sky plane ray cast through the camera, the dome along every ray that misses
//! it, and the optics blur, in radiance.
//!
//! Two ways to blur, selected by [`SkyBlur`] (`Auto` picks one per run, [`plan_sky_blur`]):
//! - `Frame`: ray cast the raw image, fill the misses from the dome, convolve the frame with the PSF's pixel
//!   kernel (tiles whose change would stay below a threshold are skipped, [`Convolver`]). Exact for a frame that
//!   is linear between pixel centres, it errs at edges sharper than a pixel.
//! - `Prefilter`: ray cast an image already convolved with the PSF mapped into its texels, on a grid of at most
//!   [`super::prefilter::TEXTURE_SPACING_PX`] ([`super::prefilter`]), one sample per pixel and no per-frame blur. It serves the 16 × 16 px tiles whose
//!   blur footprint (the tile widened by the PSF radius plus one pixel) lies entirely on the image, 1.5 texels
//!   in from its edges, and whose own Jacobian is within `tolerance` of the texture's; the other tiles (near the
//!   horizon where the plane ends, near the image's edges, at strongly varying perspective) are made the
//!   reference way in the same frame. When the frame's centre does not see the image, or the texture kernel
//!   would be too wide (a strongly minified image), the whole frame is. An image widened by a margin of the
//!   dome ([`super::sky_plane::DomeMargin`], `[quality] image_margin_px`) is the textures' source instead: the
//!   tiles whose blur reaches past the image's own edge into the margin are then read from a texture too, on the
//!   finest grid of the spacing (where the preset's grid is coarser, a second texture, made for the box those
//!   tiles read).
//!
//! A frame's result depends only on its own camera: the texture's Jacobian is a lattice point chosen from the
//! camera's view, and a prefiltered crop's values do not depend on its extent.

use glam::{DMat2, DVec2};
use serde::{Deserialize, Serialize};

use super::camera::Camera;
use super::frame::Frame;
use super::prefilter::{JacobianKey, PrefilterCache, PrefilterSettings};
use super::psf::{BLUR_TILE_PX, BlurStats, ConvolutionMethod, Convolver, Psf, tiles_within_reach};
use super::sky_field::render_dome;
use super::sky_plane::{MissFill, Sampling, SkyPlane};
use crate::physics::sky::Dome;

/// How the optics blur reaches a sky image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkyBlur {
    /// `prefilter` when the run's planned views make it cheaper than `frame` ([`plan_sky_blur`]).
    #[default]
    Auto,
    /// Convolve the image once with the PSF mapped into its texels, then ray cast it.
    Prefilter,
    /// Ray cast the raw image and convolve every frame (it blurs point samples of the image, so it errs more
    /// than `Prefilter` against the brute-force blur: docs/accuracy.md).
    Frame,
}

/// What blurring a run's sky each way would cost, and the choice made.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SkyBlurPlan {
    /// `prefilter` or `frame`.
    pub choice: SkyBlur,
    /// Views planned.
    pub views: usize,
    /// Views with tiles the prefiltered texture can serve.
    pub views_prefiltered: usize,
    /// Texture crops the run would prefilter.
    pub texture_builds: u64,
    /// Multiply–adds of those builds.
    pub texture_work: f64,
    /// Multiply–adds of blurring the frames of those views instead (separable kernel, every tile).
    pub frame_work: f64,
}

/// Plans the sky blur of a run whose steady views are `cameras` (every frame, or a sample of them in order):
/// simulates the prefiltered-texture cache over them and chooses `prefilter` when its builds take fewer
/// multiply–adds than blurring the frames that can use it (on the shipped scenarios this picks the faster way in
/// each of the eight, docs/accuracy.md). A function of the views alone, so every frame
/// of the run is rendered the same way whatever came before it.
pub fn plan_sky_blur(
    plane: &SkyPlane,
    psf: &Psf,
    settings: PrefilterSettings,
    (width, height): (usize, usize),
    cameras: impl IntoIterator<Item = Camera>,
) -> SkyBlurPlan {
    // as the renderer does: the tiles at an image's edge from a texture of their own where it has a margin
    let (source, inner) = texture_source(plane, false, &settings);
    let fine = PrefilterSettings { grid_error: 0.0, ..settings };
    let (mut cache, mut edge_cache) = (PrefilterCache::new(), PrefilterCache::new());
    let (mut clean, mut edge) = (Vec::new(), Vec::new());
    let (mut views, mut views_prefiltered) = (0, 0);
    for camera in cameras {
        views += 1;
        let (r_px, size) = (psf.radius_px(), (width, height));
        if let Some((key, need, need_edge)) =
            classify(source, &camera, r_px, settings.tolerance, size, inner, &mut clean, &mut edge)
        {
            let interior = clean.iter().zip(&edge).any(|(&c, &e)| c && !e);
            let edges = edge.iter().any(|&e| e);
            if (!interior || cache.plan(source, psf, key, settings, need))
                && (!edges || edge_cache.plan(source, psf, key, fine, need_edge))
            {
                views_prefiltered += 1;
            }
        }
    }
    let kernel = psf.point_kernel();
    let taps = (2 * (2 * kernel.radius() + 1) * kernel.rank()) as f64;
    let frame_work = views_prefiltered as f64 * (width * height) as f64 * taps;
    let texture_work = cache.work() + edge_cache.work();
    let choice = if views_prefiltered > 0 && texture_work < frame_work { SkyBlur::Prefilter } else { SkyBlur::Frame };
    let texture_builds = cache.builds() + edge_cache.builds();
    SkyBlurPlan { choice, views, views_prefiltered, texture_builds, texture_work, frame_work }
}

/// The plane a sky's prefiltered textures are made from: the image widened by the dome where it has that margin
/// ([`SkyPlane::dome_margin`]) and is read by point samples; and, where the edge tiles take a texture of their own
/// (the preset's grid is coarser than the finest, `settings.grid_error > 0`), the image's own extent in it.
fn texture_source<'a>(
    plane: &'a SkyPlane,
    area_sampled: bool,
    settings: &PrefilterSettings,
) -> (&'a SkyPlane, Option<[f64; 4]>) {
    let Some(margin) = plane.dome_margin().filter(|_| !area_sampled) else {
        return (plane, None);
    };
    let (k, image) = (margin.texels as f64, plane.image());
    let inner = (settings.grid_error > 0.0).then(|| [k, k, k + image.width() as f64, k + image.height() as f64]);
    (&margin.plane, inner)
}

/// The sky as the renderer sees it.
#[derive(Debug, Clone, Copy)]
pub struct SkyView<'a> {
    /// The placed radiance image, if any.
    pub plane: Option<&'a SkyPlane>,
    /// The clear sky and ground.
    pub dome: &'a Dome,
    /// How the image is sampled.
    pub sampling: Sampling,
    /// What rays that miss the image get.
    pub miss: MissFill,
}

/// The optics blur of the background.
#[derive(Debug, Clone, Copy)]
pub struct BackgroundBlur<'a> {
    /// The PSF.
    pub psf: &'a Psf,
    /// How the frame kernel is applied.
    pub method: ConvolutionMethod,
    /// A tile blurred the reference way keeps its values when the blur cannot change any of them by more than
    /// this (radiance units); 0 blurs every such tile.
    pub skip_below: f32,
    /// Prefiltered texture or per-frame blur.
    pub sky_blur: SkyBlur,
    /// How the prefiltered textures are made: the largest relative (Frobenius) difference between a tile's
    /// Jacobian and its texture's, and the largest spacing of a texture's grid.
    pub prefilter: PrefilterSettings,
    /// Whether a frame that sees only the dome is blurred (false when the dome's largest curvature keeps the
    /// blur's change under `skip_below`).
    pub dome: bool,
}

/// What rendering a background did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BackgroundStats {
    /// The reference blur on the tiles made that way.
    pub blur: BlurStats,
    /// Tiles read from the prefiltered texture.
    pub tiles_prefiltered: usize,
    /// Prefiltered crops made since the renderer was created.
    pub texture_builds: u64,
}

/// Renders backgrounds; holds the buffers and the prefiltered textures between frames.
#[derive(Debug, Default)]
pub struct BackgroundRenderer {
    convolver: Convolver,
    cache: PrefilterCache,
    /// Per tile: read from the prefiltered texture.
    clean: Vec<bool>,
    /// Per tile: the negation of `clean`.
    rest: Vec<bool>,
    /// Per tile: in `rest` or within the frame kernel's reach of a tile that is.
    near: Vec<bool>,
    /// Per tile: in `clean`, not in `near`, next to a tile that is (with the FFT method, every tile in `clean`
    /// and not in `near`).
    ring: Vec<bool>,
    /// The row pass of [`tiles_within_reach`].
    along: Vec<bool>,
    /// Per tile: served by the texture, its blur reaching past the image's own edge into the margin of the dome
    /// (read from the finest grid's texture).
    edge_tiles: Vec<bool>,
    /// Per tile: served by the texture, not an edge tile.
    interior: Vec<bool>,
    /// The prefiltered textures of the edge tiles.
    edge_cache: PrefilterCache,
    /// The tiles of one texture among others (the ring's interior or edge tiles).
    pair: Vec<bool>,
}

impl BackgroundRenderer {
    /// A renderer with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders the background of `camera`'s view of `sky` into `frame`, blurred by `blur` if given.
    pub fn render(
        &mut self,
        sky: &SkyView<'_>,
        camera: &Camera,
        blur: Option<&BackgroundBlur<'_>>,
        frame: &mut Frame,
    ) -> BackgroundStats {
        let stats = self.render_frame(sky, camera, blur, frame);
        BackgroundStats { texture_builds: self.cache.builds() + self.edge_cache.builds(), ..stats }
    }

    fn render_frame(
        &mut self,
        sky: &SkyView<'_>,
        camera: &Camera,
        blur: Option<&BackgroundBlur<'_>>,
        frame: &mut Frame,
    ) -> BackgroundStats {
        let mut stats = BackgroundStats::default();
        let Some(plane) = sky.plane else {
            render_dome(camera, sky.dome, frame, false, None);
            if let Some(b) = blur {
                stats.blur = self.convolver.apply_where_needed(b.psf.point_kernel(), frame, b.method, b.skip_below);
            }
            return stats;
        };
        let Some(b) = blur else {
            render_raw(plane, sky, camera, frame);
            return stats;
        };
        // a point-sampled sky needs the pixel aperture in the kernel; an area-averaged one has it already
        let area_sampled = matches!(sky.sampling, Sampling::Supersample { n } if n > 1);
        let kernel = if area_sampled { b.psf.area_kernel() } else { b.psf.point_kernel() };
        if sky.miss == MissFill::Dome && !plane.seen_by(camera) {
            // the dome alone, as a run without an image layer renders it
            render_dome(camera, sky.dome, frame, false, None);
            if b.dome {
                stats.blur = self.convolver.apply_where_needed(kernel, frame, b.method, b.skip_below);
            } else {
                let t = BLUR_TILE_PX;
                stats.blur.tiles = frame.width().div_ceil(t) * frame.height().div_ceil(t);
            }
            return stats;
        }
        // the blurred texture is read nearest where the sky is, bilinearly otherwise
        let texture_sampling = if sky.sampling == Sampling::Nearest { Sampling::Nearest } else { Sampling::Bilinear };
        // the texture's source: the image widened by the dome's texels where it has them (not for an area-sampled
        // sky, whose reference tiles are the whole frame's ray cast); tiles whose blur reaches past the image's own
        // extent in it are read from a texture on the finest grid of the spacing (the blurred edge is sharp there)
        let (source, inner) = texture_source(plane, area_sampled, &b.prefilter);
        let prefiltered = if b.sky_blur != SkyBlur::Frame {
            let size = (frame.width(), frame.height());
            let (r_px, tolerance) = (b.psf.radius_px(), b.prefilter.tolerance);
            classify(source, camera, r_px, tolerance, size, inner, &mut self.clean, &mut self.edge_tiles)
        } else {
            None
        };
        let Some((key, need, need_edge)) = prefiltered else {
            render_raw(plane, sky, camera, frame);
            stats.blur = self.convolver.apply_where_needed(kernel, frame, b.method, b.skip_below);
            return stats;
        };
        self.interior.clear();
        self.interior.extend(self.clean.iter().zip(&self.edge_tiles).map(|(&c, &e)| c && !e));
        let any = |flags: &[bool]| flags.iter().any(|&f| f);
        let (textures, fine) = (&mut self.cache, &mut self.edge_cache);
        let coarse = if any(&self.interior) { textures.plane(source, b.psf, key, b.prefilter, need) } else { None };
        let fine_settings = PrefilterSettings { grid_error: 0.0, ..b.prefilter };
        let fine = if any(&self.edge_tiles) { fine.plane(source, b.psf, key, fine_settings, need_edge) } else { None };
        if (coarse.is_none() && any(&self.interior)) || (fine.is_none() && any(&self.edge_tiles)) {
            render_raw(plane, sky, camera, frame);
            stats.blur = self.convolver.apply_where_needed(kernel, frame, b.method, b.skip_below);
            return stats;
        }
        // the served tiles (or those of them among `among`, the pair's flags made in `pair`), each from its texture
        let draw = |among: Option<&[bool]>, pair: &mut Vec<bool>, frame: &mut Frame| {
            for (texture, of) in [(coarse, &self.interior), (fine, &self.edge_tiles)] {
                let Some(texture) = texture else { continue };
                let tiles = match among {
                    None => of,
                    Some(among) => {
                        pair.clear();
                        pair.extend(among.iter().zip(of).map(|(&a, &o)| a && o));
                        &*pair
                    }
                };
                if any(tiles) {
                    texture.render_tiles(camera, texture_sampling, sky.miss, BLUR_TILE_PX, tiles, frame);
                }
            }
        };
        stats.tiles_prefiltered = self.clean.iter().filter(|&&c| c).count();
        if stats.tiles_prefiltered == self.clean.len() {
            // every ray meets the image (or its margin): no misses, nothing made the reference way
            match (coarse, fine) {
                (Some(texture), None) => texture.render(camera, texture_sampling, sky.miss, frame),
                _ => draw(None, &mut self.pair, frame),
            }
            stats.blur.tiles = self.clean.len();
            return stats;
        }
        // the reference on the other tiles, from the raw sky on them and on the tiles their blur reaches; then
        // the prefiltered tiles over everything else
        let t = BLUR_TILE_PX;
        let reach = kernel.radius().div_ceil(t);
        self.rest.clear();
        self.rest.extend(self.clean.iter().map(|c| !c));
        tiles_within_reach(&self.rest, frame.width().div_ceil(t), reach, &mut self.along, &mut self.near);
        // the tiles that may hold misses, which the dome fills: every tile where the whole image is rendered,
        // else the tiles rendered from the raw sky and the texture's ring (the other tiles are written from the
        // texture after the blur, which reads only these)
        let dome_tiles = if area_sampled {
            plane.render(camera, sky.sampling, sky.miss, frame);
            false
        } else {
            // the ring of the texture's tiles just beyond the reached ones first: the blur's skip test reads one
            // pixel into it (the curvature at the reached tiles' edge), which must be this frame's, never the
            // last frame's; an FFT blur of the whole frame reads every pixel, so for it all the texture's tiles
            // beyond the reached ones
            let tw = frame.width().div_ceil(t);
            let whole = b.method == ConvolutionMethod::Fft;
            tiles_within_reach(&self.near, tw, 1, &mut self.along, &mut self.ring);
            for ((r, &c), &n) in self.ring.iter_mut().zip(&self.clean).zip(&self.near) {
                *r = (*r || whole) && c && !n;
            }
            draw(Some(&self.ring), &mut self.pair, frame);
            plane.render_tiles(camera, sky.sampling, sky.miss, t, &self.near, frame);
            for (r, &n) in self.ring.iter_mut().zip(&self.near) {
                *r |= n;
            }
            true
        };
        if sky.miss == MissFill::Dome {
            render_dome(camera, sky.dome, frame, true, dome_tiles.then_some((t, &self.ring[..])));
        }
        stats.blur = self.convolver.apply_where_needed_in(kernel, frame, b.method, b.skip_below, Some(&self.rest));
        draw(None, &mut self.pair, frame);
        stats
    }
}

/// Rows of tiles a task of [`classify`] takes at least (40 tiles a row at 640 × 512, ~4 µs a row).
const CLASSIFY_ROWS_PER_TASK: usize = 4;

/// Marks in `clean` (row-major tiles) the tiles a prefiltered texture of `plane` (an image, or an image widened
/// by a margin of the dome) can serve, and in `edge` those of them whose footprint does not lie within the box
/// `inner` (image coordinates; an image's own extent inside its margin of the dome) inset as the image's edges
/// are; returns the texture's key and the image-coordinate boxes the tiles not in `edge` and those in `edge`
/// read, or `None` if the frame's centre does not see the image well inside its edges.
#[allow(clippy::too_many_arguments)]
fn classify(
    plane: &SkyPlane,
    camera: &Camera,
    psf_radius_px: usize,
    tolerance: f64,
    (width, height): (usize, usize),
    inner: Option<[f64; 4]>,
    clean: &mut Vec<bool>,
    edge: &mut Vec<bool>,
) -> Option<(JacobianKey, [f64; 4], [f64; 4])> {
    use rayon::prelude::*;
    let t = BLUR_TILE_PX;
    let (tw, th) = (width.div_ceil(t), height.div_ceil(t));
    let image = plane.image();
    let inset = 1.5;
    let (iw, ih) = (image.width() as f64 - inset, image.height() as f64 - inset);
    let projection = plane.projection(camera);
    // the tile widened by the PSF's reach and one pixel; its corners' image points and mean Jacobian
    let margin = (psf_radius_px + 1) as f64;
    let footprint = |x0: f64, y0: f64, x1: f64, y1: f64| -> Option<([DVec2; 4], DMat2)> {
        let (x0, y0, x1, y1) = (x0 - margin, y0 - margin, x1 + margin, y1 + margin);
        let p = [
            projection.image_point(DVec2::new(x0, y0))?,
            projection.image_point(DVec2::new(x1, y0))?,
            projection.image_point(DVec2::new(x0, y1))?,
            projection.image_point(DVec2::new(x1, y1))?,
        ];
        // the convex footprint lies in the image iff its corners do
        if !p.iter().all(|q| q.x >= inset && q.y >= inset && q.x <= iw && q.y <= ih) {
            return None;
        }
        let du = ((p[1] - p[0]) + (p[3] - p[2])) / (2.0 * (x1 - x0));
        let dv = ((p[2] - p[0]) + (p[3] - p[1])) / (2.0 * (y1 - y0));
        Some((p, DMat2::from_cols(du, dv)))
    };
    clean.clear();
    let (cx, cy) = (width as f64 / 2.0, height as f64 / 2.0);
    let half = t as f64 / 2.0;
    let (_, centre) = footprint(cx - half, cy - half, cx + half, cy + half)?;
    let key = JacobianKey::new(centre, tolerance)?;
    let reference = key.jacobian(tolerance);
    let norm = |m: DMat2| m.to_cols_array().iter().map(|v| v * v).sum::<f64>().sqrt();
    let limit = tolerance * norm(reference);
    // rows of tiles side by side (a 640 × 512 frame's 1280 tiles took ~0.14 ms on one thread, every frame); the
    // box of the image points read (finite, inside the image) is a min and max over the tiles, the same whatever
    // the order
    const EMPTY: [f64; 4] = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    let join = |a: [f64; 4], b: [f64; 4]| [a[0].min(b[0]), a[1].min(b[1]), a[2].max(b[2]), a[3].max(b[3])];
    clean.resize(tw * th, false);
    edge.clear();
    edge.resize(tw * th, false);
    let within = |q: &DVec2| {
        inner.is_none_or(|b| q.x >= b[0] + inset && q.y >= b[1] + inset && q.x <= b[2] - inset && q.y <= b[3] - inset)
    };
    let joins = |a: ([f64; 4], [f64; 4]), b: ([f64; 4], [f64; 4])| (join(a.0, b.0), join(a.1, b.1));
    let (need, need_edge) = clean
        .par_chunks_mut(tw.max(1))
        .zip(edge.par_chunks_mut(tw.max(1)))
        .enumerate()
        .with_min_len(CLASSIFY_ROWS_PER_TASK)
        .map(|(ty, (row, edge_row))| {
            let mut need = (EMPTY, EMPTY);
            for (tx, (ok, on_edge)) in row.iter_mut().zip(edge_row.iter_mut()).enumerate() {
                let (x0, y0) = ((tx * t) as f64, (ty * t) as f64);
                let (x1, y1) = (((tx + 1) * t).min(width) as f64, ((ty + 1) * t).min(height) as f64);
                *ok = match footprint(x0, y0, x1, y1) {
                    Some((corners, j)) if norm(j - reference) <= limit => {
                        *on_edge = !corners.iter().all(within);
                        let into = if *on_edge { &mut need.1 } else { &mut need.0 };
                        for q in corners {
                            *into = join(*into, [q.x, q.y, q.x, q.y]);
                        }
                        true
                    }
                    _ => false,
                };
            }
            need
        })
        .reduce(|| (EMPTY, EMPTY), joins);
    clean.iter().any(|&c| c).then_some((key, need, need_edge))
}

/// Pixel `(x, y)` of `camera`'s view of `plane` blurred by `psf`, by brute force: the PSF times the bilinear
/// image along the ray through every point of a grid of `per_px` × `per_px` points per pixel over the PSF's
/// support (midpoint rule). The reference the fast methods are measured against; `None` if a ray of the
/// support misses the image (the dome would be seen there).
pub fn exact_blurred_pixel(
    plane: &SkyPlane,
    camera: &Camera,
    psf: &Psf,
    x: usize,
    y: usize,
    per_px: usize,
) -> Option<f64> {
    let size = DVec2::new(plane.image().width() as f64, plane.image().height() as f64);
    brute_force_blur(plane, camera, psf, (x, y), per_px, |_, p| {
        p.filter(|p| p.x >= 0.0 && p.y >= 0.0 && p.x <= size.x && p.y <= size.y).map(|p| plane.value_at(p))
    })
}

/// `Σ PSF(d)·h²·value(c + d, p)` over the midpoint grid of `per_px` × `per_px` points a pixel on the PSF's support,
/// `c` pixel `(x, y)`'s centre and `p` where the ray through `c + d` meets `plane` (image coordinates, `None` if it
/// does not); `None` if `value` gives `None` at a point where the PSF is not 0.
fn brute_force_blur(
    plane: &SkyPlane,
    camera: &Camera,
    psf: &Psf,
    (x, y): (usize, usize),
    per_px: usize,
    value: impl Fn(DVec2, Option<DVec2>) -> Option<f32>,
) -> Option<f64> {
    let projection = plane.projection(camera);
    let reach = psf.radius_px() as f64 + 0.5;
    let n = (2.0 * reach * per_px as f64).ceil() as usize;
    let h = 2.0 * reach / n as f64;
    let centre = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
    let mut sum = 0.0;
    for b in 0..n {
        for a in 0..n {
            let d = DVec2::new(-reach + (a as f64 + 0.5) * h, -reach + (b as f64 + 0.5) * h);
            let w = f64::from(psf.value(d.x, d.y));
            if w != 0.0 {
                let at = centre + d;
                sum += w * h * h * f64::from(value(at, projection.image_point(at))?);
            }
        }
    }
    Some(sum)
}

/// The raw image ray cast and the dome along the rays that miss it (for the dome fill).
fn render_raw(plane: &SkyPlane, sky: &SkyView<'_>, camera: &Camera, frame: &mut Frame) {
    plane.render(camera, sky.sampling, sky.miss, frame);
    if sky.miss == MissFill::Dome {
        render_dome(camera, sky.dome, frame, true, None);
    }
}

#[cfg(test)]
mod tests {
    use crate::imaging::prefilter::TEXTURE_SPACING_PX;
    use glam::DVec3;

    use super::*;
    use crate::imaging::camera::Intrinsics;
    use crate::imaging::psf::{PsfOptics, PsfSpec};
    use crate::imaging::sky_plane::{DomeMargin, SkyImage, SkyPlacement};
    use crate::physics::planck::{Band, Measure};
    use crate::physics::sky::{DomeInputs, DomeSpec};
    use crate::physics::transmittance::Transmittance;

    fn psf() -> Psf {
        let optics = PsfOptics {
            f_number: 1.0,
            pixel_pitch_m: 17e-6,
            fill_factor: 1.0,
            band: Band::LWIR_8_12,
            measure: Measure::Energy,
            reference_temp_k: 300.0,
        };
        Psf::new(&PsfSpec::default(), &optics).unwrap()
    }

    fn dome() -> Dome {
        let atmosphere = Transmittance::BeerLambert { extinction_per_km: 0.15, scale_height_km: 2.0 };
        Dome::new(&DomeInputs {
            spec: DomeSpec::default(),
            band: Band::LWIR_8_12,
            measure: Measure::Energy,
            observer_altitude_m: 8000.0,
            air: crate::physics::atmosphere::AirTemperature::default(),
            atmosphere: &atmosphere,
            zenith_emissivity: None,
            clear_sky: None,
        })
        .unwrap()
    }

    /// The paper's 4 km plane 30 km away holding 512² texels of texture at 3–40 texel periods and sharp-edged
    /// "clouds" (radiance units, about the dome's).
    fn plane() -> SkyPlane {
        plane_of(512)
    }

    /// [`plane`]'s sky on `n²` texels.
    fn plane_of(n: usize) -> SkyPlane {
        let mut px = Vec::with_capacity(n * n);
        for y in 0..n {
            for x in 0..n {
                let (xf, yf) = (x as f64, y as f64);
                let waves = 1.5 * (xf / 5.3 + 0.3 * yf / 7.0).sin() + (yf / 3.1).cos() + 2.0 * (xf / 40.0).sin();
                let cloud = if (xf - 260.0).hypot(yf - 250.0) < 60.0 + 10.0 * (xf / 9.0).sin() { 4.0 } else { 0.0 };
                px.push((20.0 + waves + cloud) as f32);
            }
        }
        let image = SkyImage::from_f32(n, n, px).unwrap();
        SkyPlane::new(image, &SkyPlacement::paper_fig8(), DVec3::new(0.0, 0.0, 8000.0)).unwrap()
    }

    fn camera(plane: &SkyPlane, look_px: DVec2, roll_deg: f64) -> Camera {
        let intrinsics = Intrinsics::try_new(128, 96, 0.1, 17e-6).unwrap();
        Camera::look_at(intrinsics, DVec3::new(0.0, 0.0, 8000.0), plane.world_point(look_px), roll_deg).unwrap()
    }

    fn render(r: &mut BackgroundRenderer, plane: &SkyPlane, dome: &Dome, cam: &Camera, how: SkyBlur) -> Frame {
        render_graded(r, plane, dome, cam, how, TEXTURE_SPACING_PX, 0.0)
    }

    /// A 128 × 96 frame of `cam`'s view, bilinear, blurred `how`, the texture's grid at most `spacing_px` and
    /// chosen within `grid_error` (0: the finest of the spacing).
    fn render_graded(
        r: &mut BackgroundRenderer,
        plane: &SkyPlane,
        dome: &Dome,
        cam: &Camera,
        how: SkyBlur,
        spacing_px: f64,
        grid_error: f64,
    ) -> Frame {
        let sky = SkyView { plane: Some(plane), dome, sampling: Sampling::Bilinear, miss: MissFill::Dome };
        let p = psf();
        let blur = BackgroundBlur {
            psf: &p,
            method: ConvolutionMethod::Separable,
            skip_below: 0.0,
            dome: true,
            sky_blur: how,
            prefilter: PrefilterSettings { tolerance: 0.05, spacing_px, grid_error },
        };
        let mut f = Frame::new(128, 96);
        r.render(&sky, cam, Some(&blur), &mut f);
        f
    }

    #[test]
    fn prefiltered_sky_is_closer_to_the_exact_blur_than_the_frame_blur() {
        let (plane, dome, p) = (plane(), dome(), psf());
        let r_px = p.radius_px();
        for (look, roll) in [(DVec2::new(256.0, 250.0), 0.0), (DVec2::new(200.0, 300.0), 17.0)] {
            let cam = camera(&plane, look, roll);
            let mut renderer = BackgroundRenderer::new();
            let pre = render(&mut renderer, &plane, &dome, &cam, SkyBlur::Prefilter);
            assert!(renderer.clean.iter().all(|&c| c), "every tile sees the image");
            let reference = render(&mut BackgroundRenderer::new(), &plane, &dome, &cam, SkyBlur::Frame);
            let sky = SkyView { plane: Some(&plane), dome: &dome, sampling: Sampling::Bilinear, miss: MissFill::Dome };
            let mut raw = Frame::new(128, 96);
            BackgroundRenderer::new().render(&sky, &cam, None, &mut raw);
            // pixels away from the frame's edge (the frame blur replicates it), on a coarse grid
            let (mut effect, mut err_pre, mut err_ref) = (0.0f64, 0.0f64, 0.0f64);
            for y in (r_px..96 - r_px).step_by(5) {
                for x in (r_px..128 - r_px).step_by(5) {
                    let exact = exact_blurred_pixel(&plane, &cam, &p, x, y, 8).unwrap();
                    effect = effect.max((exact - f64::from(raw.get(x, y))).abs());
                    err_pre = err_pre.max((f64::from(pre.get(x, y)) - exact).abs());
                    err_ref = err_ref.max((f64::from(reference.get(x, y)) - exact).abs());
                }
            }
            eprintln!(
                "roll {roll}: the blur changes up to {effect:.4}; error prefilter {err_pre:.4}, frame {err_ref:.4}"
            );
            assert!(effect > 0.2, "the texture must need the blur ({effect})");
            assert!(err_pre < 0.15 * effect, "prefilter error {err_pre} where the blur changes {effect}");
            assert!(err_pre < 0.5 * err_ref, "prefilter {err_pre} vs frame {err_ref}");
        }
    }

    /// The plane of [`plane`] with `m` texels of the dome around its image as its texture's source.
    fn with_dome_margin(plane: SkyPlane, dome: &Dome, m: usize) -> SkyPlane {
        let n = plane.image().width();
        let grow = |extent: f64| extent * (n + 2 * m) as f64 / n as f64;
        let base = SkyPlacement::paper_fig8();
        let wider = SkyPlacement { width_m: grow(base.width_m), height_m: grow(base.height_m), ..base };
        let eye = DVec3::new(0.0, 0.0, 8000.0);
        let image = crate::imaging::sky_field::with_dome_margin(&plane, m, eye, dome);
        let widened = SkyPlane::new(image, &wider, eye).unwrap();
        plane.with_dome_margin(DomeMargin { plane: widened, texels: m })
    }

    /// Pixel `(x, y)` of `camera`'s view blurred by `psf` by brute force (midpoint rule, `per_px` points a pixel
    /// a side): the image bilinear up to its edge, the dome along the rays beyond.
    fn exact_with_dome(
        plane: &SkyPlane,
        dome: &Dome,
        camera: &Camera,
        psf: &Psf,
        x: usize,
        y: usize,
        per_px: usize,
    ) -> f64 {
        let size = DVec2::new(plane.image().width() as f64, plane.image().height() as f64);
        let inside = |p: &DVec2| p.x >= 0.0 && p.y >= 0.0 && p.x < size.x && p.y < size.y;
        brute_force_blur(plane, camera, psf, (x, y), per_px, |at, p| {
            Some(p.filter(inside).map_or_else(|| dome.radiance_toward(camera.ray(at)), |p| plane.value_at(p)))
        })
        .expect("a value at every point")
    }

    #[test]
    fn an_image_widened_by_the_dome_reads_its_edge_closer_to_the_exact_blur_than_the_frame_blur() {
        let (dome, p) = (dome(), psf());
        let r_px = p.radius_px();
        // the image's top edge across the middle of the frame, level (between two rows of pixel centres, or on
        // one) and turned; texels of 1.5 and 0.77 px (a pixel sees 5.1 m of the plane 30 km away)
        let cases =
            [(512, 0.0, 0.0), (512, 0.0, 0.5), (512, 11.0, 0.0), (1024, 0.0, 0.0), (1024, 0.0, 0.5), (1024, 5.0, 0.0)];
        for (n, roll, on_centres_px) in cases {
            let plane = plane_of(n);
            let widened = with_dome_margin(plane.clone(), &dome, 96);
            let texel_px = 4000.0 / n as f64 / 5.1;
            let cam = camera(&plane, DVec2::new(n as f64 / 2.0, on_centres_px / texel_px), roll);
            let frame_blur = render(&mut BackgroundRenderer::new(), &plane, &dome, &cam, SkyBlur::Frame);
            let edge_tiles = render(&mut BackgroundRenderer::new(), &plane, &dome, &cam, SkyBlur::Prefilter);
            // a grid chosen within 0.05 (a third of a percent of the step): the tiles along the edge from a
            // texture of their own on the finest grid
            let mut renderer = BackgroundRenderer::new();
            let how = SkyBlur::Prefilter;
            let texture = render_graded(&mut renderer, &widened, &dome, &cam, how, TEXTURE_SPACING_PX, 0.05);
            assert!(renderer.clean.iter().all(|&c| c), "every tile from the textures");
            assert!(renderer.edge_tiles.iter().any(|&e| e), "tiles along the edge, from the finest grid");
            assert!(renderer.interior.iter().any(|&i| i), "tiles inside, from the chosen grid");
            let (mut e_frame, mut e_tiles, mut e_texture) = (Vec::new(), Vec::new(), Vec::new());
            for y in r_px..96 - r_px {
                for x in (r_px..128 - r_px).step_by(7) {
                    let exact = exact_with_dome(&plane, &dome, &cam, &p, x, y, 16);
                    e_frame.push(f64::from(frame_blur.get(x, y)) - exact);
                    e_tiles.push(f64::from(edge_tiles.get(x, y)) - exact);
                    e_texture.push(f64::from(texture.get(x, y)) - exact);
                }
            }
            let rms = |e: &[f64]| (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
            let max = |e: &[f64]| e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let step = dome.radiance_toward(cam.ray(DVec2::new(64.0, 0.5))) - 20.0;
            eprintln!(
                "{n} texels, roll {roll}, edge {on_centres_px} px off the rows' boundary (a step of about {step:.1}): against the exact blur, rms / max: frame blur {:.4} / {:.4}, edge tiles blurred per frame {:.4} / {:.4}, widened texture {:.4} / {:.4}",
                rms(&e_frame),
                max(&e_frame),
                rms(&e_tiles),
                max(&e_tiles),
                rms(&e_texture),
                max(&e_texture)
            );
            // the frame blur reads the step at pixel centres, which puts it on the boundary between two rows of
            // them: up to half a pixel off, or stepped where the edge is turned against the rows. The widened
            // image's read ramps over a texel, which errs as the texel's square: where texels are larger than pixels
            // and the step lies between two rows, the frame blur's reads are the closer
            let bound = if n == 512 && roll == 0.0 && on_centres_px == 0.0 { 2.5 } else { 0.8 };
            assert!(rms(&e_texture) < bound * rms(&e_tiles), "{n} texels, roll {roll}, {on_centres_px} px");
        }
    }

    #[test]
    fn a_finer_texture_grid_is_closer_to_the_exact_blur_and_a_new_spacing_makes_new_textures() {
        let (plane, dome, p) = (plane(), dome(), psf());
        let r_px = p.radius_px();
        // the sharp-edged cloud in view; the image at 0.65 texels a pixel, so grids of 1.54/m px
        let cam = camera(&plane, DVec2::new(256.0, 250.0), 0.0);
        let mut renderer = BackgroundRenderer::new();
        let mut errors = Vec::new();
        for spacing in [0.75, 0.25, 0.75] {
            let frame = render_graded(&mut renderer, &plane, &dome, &cam, SkyBlur::Prefilter, spacing, 0.0);
            // a renderer that made textures at another spacing gives what a fresh one gives
            let fresh =
                render_graded(&mut BackgroundRenderer::new(), &plane, &dome, &cam, SkyBlur::Prefilter, spacing, 0.0);
            assert_eq!(frame.pixels(), fresh.pixels(), "spacing {spacing}");
            let mut worst = 0.0f64;
            for y in (r_px..96 - r_px).step_by(3) {
                for x in (r_px..128 - r_px).step_by(3) {
                    let exact = exact_blurred_pixel(&plane, &cam, &p, x, y, 8).unwrap();
                    worst = worst.max((f64::from(frame.get(x, y)) - exact).abs());
                }
            }
            errors.push(worst);
        }
        eprintln!("largest error against the exact blur: 0.75 px {:.4}, 0.25 px {:.4}", errors[0], errors[1]);
        assert!(errors[1] < 0.7 * errors[0], "{errors:?}");
    }

    #[test]
    fn the_edge_tiles_and_their_box_do_not_depend_on_the_threads() {
        let plane = plane();
        let r_px = psf().radius_px();
        // the image's own extent taken as rows 60 on: the tiles whose blur reaches row 61.5 are edge tiles
        let inner = Some([0.0, 60.0, 512.0, 512.0]);
        let intrinsics = Intrinsics::try_new(310, 250, 0.1, 17e-6).unwrap();
        let look = plane.world_point(DVec2::new(256.0, 60.0));
        let cam = Camera::look_at(intrinsics, DVec3::new(0.0, 0.0, 8000.0), look, 7.0).unwrap();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let (mut clean, mut edge) = (Vec::new(), Vec::new());
            let got = pool.install(|| classify(&plane, &cam, r_px, 0.05, (310, 250), inner, &mut clean, &mut edge));
            let bits = |b: [f64; 4]| b.map(f64::to_bits);
            (got.map(|(key, need, need_edge)| (key, bits(need), bits(need_edge))), clean, edge)
        };
        let one = run(1);
        let (clean, edge) = (&one.1, &one.2);
        let interior = clean.iter().zip(edge).filter(|&(&c, &e)| c && !e).count();
        let edges = edge.iter().filter(|&&e| e).count();
        assert!(interior > 0 && edges > 0, "both kinds ({interior} and {edges} tiles)");
        assert!(edge.iter().zip(clean).all(|(&e, &c)| c || !e), "an edge tile is a served tile");
        for threads in [2, 3] {
            assert_eq!(run(threads), one, "{threads} threads");
        }
    }

    #[test]
    fn the_tile_classes_and_the_box_they_read_do_not_depend_on_the_threads() {
        let plane = plane();
        let r_px = psf().radius_px();
        // a view across the image's top edge, rolled: tiles of both kinds, in rows split among tasks; at 320 × 256
        // whole tiles, at 310 × 250 a last column 6 px wide and a last row 10 px high
        for (width, height) in [(320, 256), (310, 250)] {
            let intrinsics = Intrinsics::try_new(width as u32, height as u32, 0.1, 17e-6).unwrap();
            let look = plane.world_point(DVec2::new(256.0, 40.0));
            let cam = Camera::look_at(intrinsics, DVec3::new(0.0, 0.0, 8000.0), look, 7.0).unwrap();
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut clean = vec![true; 3];
                let mut edge = Vec::new();
                let got =
                    pool.install(|| classify(&plane, &cam, r_px, 0.05, (width, height), None, &mut clean, &mut edge));
                (got.map(|(key, need, _)| (key, need.map(f64::to_bits))), clean)
            };
            let (one, clean) = run(1);
            let t = BLUR_TILE_PX;
            let tw = width.div_ceil(t);
            assert_eq!(clean.len(), tw * height.div_ceil(t));
            let served = clean.iter().filter(|&&c| c).count();
            assert!(served > 0 && served < clean.len(), "a mixed frame ({served} of {} tiles)", clean.len());
            for threads in [2, 3] {
                assert_eq!(run(threads), (one, clean.clone()), "{width} × {height}, {threads} threads");
            }
            // the box holds every served tile's footprint corners (a tile cut by the frame's edge ends there),
            // and each of its sides is one of them
            let need = one.unwrap().1.map(f64::from_bits);
            let projection = plane.projection(&cam);
            let m = (r_px + 1) as f64;
            let mut sides = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
            let mut cut = 0;
            for (i, _) in clean.iter().enumerate().filter(|(_, c)| **c) {
                let (tx, ty) = (i % tw, i / tw);
                let (x0, y0) = ((tx * t) as f64 - m, (ty * t) as f64 - m);
                let (x1, y1) = (((tx + 1) * t).min(width) as f64 + m, ((ty + 1) * t).min(height) as f64 + m);
                cut += usize::from((tx + 1) * t > width || (ty + 1) * t > height);
                for (x, y) in [(x0, y0), (x1, y0), (x0, y1), (x1, y1)] {
                    let q = projection.image_point(DVec2::new(x, y)).unwrap();
                    let inside = need[0] <= q.x && need[1] <= q.y && q.x <= need[2] && q.y <= need[3];
                    assert!(inside, "{width} × {height}: {q} outside {need:?}");
                    sides = [sides[0].min(q.x), sides[1].min(q.y), sides[2].max(q.x), sides[3].max(q.y)];
                }
            }
            assert_eq!(need, sides, "{width} × {height}");
            if width % t != 0 {
                assert!(cut > 0, "{width} × {height}: served tiles cut by the frame's edge");
            }
        }
    }

    #[test]
    fn the_dome_in_marked_tiles_is_the_whole_frame_s_dome_there() {
        let (d, p) = (dome(), plane());
        // 120 × 90: the last column and row of 16 px tiles are cut short; the misses are placed by hand
        let intrinsics = Intrinsics::try_new(120, 90, 0.05, 17e-6).unwrap();
        let cam =
            Camera::look_at(intrinsics, DVec3::new(0.0, 0.0, 8000.0), p.world_point(DVec2::new(256.0, 900.0)), 3.0)
                .unwrap();
        let mut before = Frame::new(120, 90);
        for (i, v) in before.pixels_mut().iter_mut().enumerate() {
            *v = if i % 7 < 3 { f32::NAN } else { i as f32 };
        }
        let (tw, th) = (120usize.div_ceil(16), 90usize.div_ceil(16));
        // single tiles, runs of tiles, the cut-short ones
        let marks: Vec<bool> = (0..tw * th).map(|i| (i % tw + i / tw) % 3 == 0 || i % tw >= 5).collect();
        for only_nan in [true, false] {
            let mut whole = before.clone();
            render_dome(&cam, &d, &mut whole, only_nan, None);
            let mut part = before.clone();
            render_dome(&cam, &d, &mut part, only_nan, Some((16, &marks)));
            for (i, ((&w, &q), &b)) in whole.pixels().iter().zip(part.pixels()).zip(before.pixels()).enumerate() {
                let (x, y) = (i % 120, i / 120);
                let want = if marks[(y / 16) * tw + x / 16] { w } else { b };
                assert_eq!(q.to_bits(), want.to_bits(), "pixel ({x}, {y}), only_nan {only_nan}");
            }
            // the dome was written where the marks and NaN say
            assert!(part.pixels().iter().zip(before.pixels()).any(|(a, b)| a.to_bits() != b.to_bits()));
        }
    }

    #[test]
    fn tiles_near_the_image_edge_get_the_reference() {
        let (plane, dome) = (plane(), dome());
        // the image's top edge crosses the frame: the dome above it
        let cam = camera(&plane, DVec2::new(256.0, 28.0), 5.0);
        let mut renderer = BackgroundRenderer::new();
        let pre = render(&mut renderer, &plane, &dome, &cam, SkyBlur::Prefilter);
        let clean = renderer.clean.clone();
        let (some, all) = (clean.iter().any(|&c| c), clean.iter().all(|&c| c));
        assert!(some && !all, "a mixed frame");
        let reference = render(&mut BackgroundRenderer::new(), &plane, &dome, &cam, SkyBlur::Frame);
        let tw = 128usize.div_ceil(BLUR_TILE_PX);
        for y in 0..96 {
            for x in 0..128 {
                let (a, b) = (pre.get(x, y), reference.get(x, y));
                assert!(a.is_finite());
                if !clean[(y / BLUR_TILE_PX) * tw + x / BLUR_TILE_PX] {
                    assert!((a - b).abs() <= 1e-4 * b.abs(), "({x}, {y}): {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn a_frame_does_not_depend_on_the_frames_before_it() {
        let (plane, dome) = (plane(), dome());
        // a view, another turned far away, one over the image's edge, the first panned (its crops share blocks),
        // and the first rolled: more Jacobians than the cache keeps crops of, so that a view seen again finds its
        // crop gone and its filter kept
        let views = [
            (DVec2::new(256.0, 250.0), 0.0),
            (DVec2::new(100.0, 400.0), 30.0),
            (DVec2::new(256.0, 28.0), 5.0),
            (DVec2::new(296.0, 250.0), 0.0),
            (DVec2::new(336.0, 290.0), 0.0),
            (DVec2::new(256.0, 250.0), 12.0),
            (DVec2::new(256.0, 250.0), 20.0),
        ];
        let fresh: Vec<Frame> = views
            .iter()
            .map(|&(l, r)| {
                render(&mut BackgroundRenderer::new(), &plane, &dome, &camera(&plane, l, r), SkyBlur::Prefilter)
            })
            .collect();
        let mut renderer = BackgroundRenderer::new();
        for (pass, order) in [[0, 1, 2, 3, 4, 5, 6], [4, 2, 6, 3, 1, 5, 0], [1, 5, 0, 3, 6, 2, 4]].iter().enumerate() {
            let builds = renderer.cache.builds();
            for &i in order {
                let (l, r) = views[i];
                let f = render(&mut renderer, &plane, &dome, &camera(&plane, l, r), SkyBlur::Prefilter);
                assert_eq!(f.pixels(), fresh[i].pixels(), "view {i}");
            }
            // crops made again after theirs were dropped (their filters and blocks kept)
            assert!(pass == 0 || renderer.cache.builds() > builds, "pass {pass} made no crop");
        }
    }
}
