//! The optics blur moved into the sky texture: a sky image convolved once with the PSF mapped into its own
//! texels, then ray cast like the raw image, gives the blurred background without blurring every frame.
//!
//! A pixel of a blurred frame is `I(c) = ∫ PSF(y)·F(c + y) dy`, with `F(x) = T(H(x))` the sky image `T`
//! (bilinear between texel centres) seen through the plane-to-sensor homography `H`. Where `H` is affine over
//! the PSF's reach, `H(c + y) = H(c) + J·y` (`J` the Jacobian, texels per sensor pixel), so
//! `I(c) = ∫ PSF(y)·T(H(c) + J·y) dy`: the image convolved with the PSF mapped into texel space, read at
//! `H(c)`. At texel centres that convolution is a discrete one, `T′[n] = Σ_k T[k]·k_J[k − n]` with
//! `k_J[d] = ∫ PSF(y)·Λ(d − J·y) dy` (`Λ` the bilinear tent), exact for the bilinear image; between centres
//! `T′` is read bilinearly, which interpolates the blurred field. [`texture_kernel`] computes `k_J` by the
//! midpoint rule on a grid finer than 1/16 texel and 1/16 px, splatting each PSF sample onto the texel grid with
//! the tent's weights. Read at texel spacing, a magnified image (texels larger than pixels) would interpolate
//! the blurred field more coarsely than the frame's own pixels do, so the blurred image is computed on a grid
//! `m` times finer ([`TextureFilter`]): each of the `m²` sub-texel phases is the same integral with the tent
//! shifted, exact at its nodes, and the grid spacing is at most [`TEXTURE_SPACING_PX`].
//!
//! Limits, and what keeps them in check:
//! - `J` varies over the frame (perspective) and from frame to frame (motion, pointing). A prefiltered texture
//!   serves one `J`, quantized by [`JacobianKey`] on a lattice of steps of `tolerance/2` (relative), so that a
//!   frame's result depends on its own camera alone, never on the frames before it; tiles of the frame whose own
//!   `J` is more than `tolerance` (relative, Frobenius) from it are blurred the reference way (see
//!   [`super::background`]).
//! - Near the image's edges the texture blur would replicate edge texels where the frame sees the dome: tiles
//!   whose blur reaches within 1.5 texels of the edge are blurred the reference way too.
//! - The reference blur of a frame replicates the frame's edge pixels; the prefiltered texture holds the sky
//!   beyond the frame's edge, as the optics see it. The outermost `R` pixels (the PSF radius) differ by that.
//!
//! The blurred texture is made only for the block of texels the view needs ([`PrefilterCache`]), from the whole
//! image (its true edges replicated), so a crop's values do not depend on where the crop ends.

use glam::{DMat2, DVec2};

use super::frame::Frame;
use super::psf::{ConvolutionMethod, Convolver, Kernel, Psf};
use super::sky_plane::{SkyImage, SkyPlane};

/// Largest radius of a texture kernel, texels; a sky minified more than this allows is blurred per frame.
pub const MAX_TEXTURE_RADIUS: usize = 40;
/// Texture crops are aligned to blocks of this many texels.
const BLOCK_TEXELS: usize = 32;
/// Side of the blocks, aligned to the image's texel grid, that the FFT method of a texture build works on.
const FFT_BLOCK_TEXELS: usize = 128;
/// Prefiltered crops kept (a view whose Jacobian sits on a lattice boundary alternates between two keys).
const CACHE_ENTRIES: usize = 4;

/// The PSF mapped into texel space by the Jacobian `jacobian` (texels per sensor pixel; column 0 is the
/// change of image coordinates per pixel along the sensor's u, column 1 along v) and read `shift` texels from
/// texel centres: `k[d] = ∫ PSF(y)·Λ(shift + J·y − d) dy`, so that `Σ_d k[d]·T[n + d]` is the blurred image at
/// `n + shift`. A kernel summing to 1 (applied in 2D); `None` if its radius would exceed
/// [`MAX_TEXTURE_RADIUS`] or `jacobian` is not finite and invertible.
pub fn texture_kernel(psf: &Psf, jacobian: DMat2, shift: DVec2) -> Option<Kernel> {
    let j = jacobian;
    if !(j.is_finite() && shift.is_finite() && j.determinant().abs() > 1e-12 * frobenius2(j)) {
        return None;
    }
    // the PSF is 0 beyond R + ½ px on either axis
    let reach_px = psf.radius_px() as f64 + 0.5;
    let reach_x = reach_px * (j.x_axis.x.abs() + j.y_axis.x.abs()) + shift.x.abs();
    let reach_y = reach_px * (j.x_axis.y.abs() + j.y_axis.y.abs()) + shift.y.abs();
    // the tent reaches one texel further
    let radius = reach_x.max(reach_y).ceil() as usize + 1;
    if radius > MAX_TEXTURE_RADIUS {
        return None;
    }
    let side = 2 * radius + 1;
    // sample spacing: at most 1/16 px and 1/16 texel along either texel axis
    let texels_per_px = (j.x_axis.x.abs() + j.y_axis.x.abs()).max(j.x_axis.y.abs() + j.y_axis.y.abs());
    let per_px = (16.0 * texels_per_px.max(1.0)).ceil();
    let n = (2.0 * reach_px * per_px).ceil() as usize;
    let h = 2.0 * reach_px / n as f64;
    let mut values = vec![0.0f64; side * side];
    let centre = DVec2::splat(radius as f64) + shift;
    for b in 0..n {
        let y = -reach_px + (b as f64 + 0.5) * h;
        for a in 0..n {
            let x = -reach_px + (a as f64 + 0.5) * h;
            let w = f64::from(psf.value(x, y)) * h * h;
            if w == 0.0 {
                continue;
            }
            let z = j * DVec2::new(x, y) + centre;
            let (x0, y0) = (z.x.floor(), z.y.floor());
            let (fx, fy) = (z.x - x0, z.y - y0);
            let (x0, y0) = (x0 as usize, y0 as usize);
            values[y0 * side + x0] += w * (1.0 - fx) * (1.0 - fy);
            values[y0 * side + x0 + 1] += w * fx * (1.0 - fy);
            values[(y0 + 1) * side + x0] += w * (1.0 - fx) * fy;
            values[(y0 + 1) * side + x0 + 1] += w * fx * fy;
        }
    }
    let total: f64 = values.iter().sum();
    if !(total > 0.0) {
        return None;
    }
    values.iter_mut().for_each(|v| *v /= total);
    Some(Kernel::from_values_2d(radius, &values))
}

fn frobenius2(m: DMat2) -> f64 {
    m.to_cols_array().iter().map(|v| v * v).sum()
}

/// Largest spacing of a prefiltered texture's grid, sensor pixels: a magnified image is prefiltered onto a grid
/// at least this fine. Measured against the brute-force blur at sharp-edged clouds (`cargo test --lib
/// prefiltered_sky`, image 0.65 texel/px): grids of 0.77 px err up to 0.11 of a cloud's 4-unit step, 0.51 px
/// 0.016–0.039, 0.38 px 0.021–0.024, the per-frame blur 0.11–0.13; finer grids cost memory bandwidth in the
/// ray cast and work in the build (both ∝ 1/spacing²).
pub const TEXTURE_SPACING_PX: f64 = 0.75;

/// How one texture is prefiltered: onto a grid `per_texel` times finer than the image's, each of the
/// `per_texel²` sub-texel phases with its own [`texture_kernel`].
#[derive(Debug, Clone)]
pub struct TextureFilter {
    per_texel: usize,
    /// Row-major by phase `(a, b)`: `phases[b·per_texel + a]`.
    phases: Vec<Kernel>,
}

impl TextureFilter {
    /// The filter for `jacobian`; `None` as for [`texture_kernel`].
    pub fn new(psf: &Psf, jacobian: DMat2) -> Option<Self> {
        Self::with_spacing(psf, jacobian, TEXTURE_SPACING_PX)
    }

    /// As [`TextureFilter::new`] with a grid no coarser than `spacing_px` sensor pixels.
    pub fn with_spacing(psf: &Psf, jacobian: DMat2, spacing_px: f64) -> Option<Self> {
        // the smallest stretch of J: the largest texel step in sensor pixels is its inverse
        let (a, b, c, d) = (jacobian.x_axis.x, jacobian.y_axis.x, jacobian.x_axis.y, jacobian.y_axis.y);
        let (p, q) = (a * a + b * b + c * c + d * d, (a * d - b * c).abs());
        let smallest = (0.5 * (p - (p * p - 4.0 * q * q).max(0.0).sqrt())).max(0.0).sqrt();
        if !(smallest > 0.0) {
            return None;
        }
        let per_texel = (1.0 / (smallest * spacing_px) - 1e-9).ceil().clamp(1.0, 64.0) as usize;
        let m = per_texel as f64;
        let mut phases = Vec::with_capacity(per_texel * per_texel);
        for b in 0..per_texel {
            for a in 0..per_texel {
                // fine node (m·q + a) sits at coarse coordinate q + (a + ½)/m, i.e. (a + ½)/m − ½ from centre q
                let shift = DVec2::new((a as f64 + 0.5) / m - 0.5, (b as f64 + 0.5) / m - 0.5);
                phases.push(texture_kernel(psf, jacobian, shift)?);
            }
        }
        Some(Self { per_texel, phases })
    }

    /// Grid nodes per image pixel along each axis.
    pub fn per_texel(&self) -> usize {
        self.per_texel
    }

    /// Largest kernel radius, texels.
    pub fn radius(&self) -> usize {
        self.phases.iter().map(Kernel::radius).max().unwrap_or(0)
    }
}

/// A Jacobian rounded to a lattice: its scale (the RMS of its entries) to steps of `ln(1 + tolerance/2)`, the
/// entries divided by that scale to steps of `tolerance/2`. The rounded Jacobian is within about
/// `0.35·tolerance` (relative, Frobenius) of the one it was made from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct JacobianKey {
    scale_step: i32,
    entries: [i32; 4],
}

impl JacobianKey {
    /// The key of `jacobian`; `None` if it is not finite or is zero.
    pub fn new(jacobian: DMat2, tolerance: f64) -> Option<Self> {
        let cols = jacobian.to_cols_array();
        let scale = (cols.iter().map(|v| v * v).sum::<f64>() / 4.0).sqrt();
        if !(scale.is_finite() && scale > 0.0) {
            return None;
        }
        let step = 0.5 * tolerance;
        let scale_step = (scale.ln() / step.ln_1p()).round();
        let scale_q = (scale_step * step.ln_1p()).exp();
        let mut entries = [0i32; 4];
        for (e, v) in entries.iter_mut().zip(cols) {
            *e = (v / scale_q / step).round() as i32;
        }
        Some(Self { scale_step: scale_step as i32, entries })
    }

    /// The rounded Jacobian.
    pub fn jacobian(&self, tolerance: f64) -> DMat2 {
        let step = 0.5 * tolerance;
        let scale_q = (f64::from(self.scale_step) * step.ln_1p()).exp();
        DMat2::from_cols_array(&self.entries.map(|e| f64::from(e) * step * scale_q))
    }
}

/// A texel rectangle `[x0, y0, x1, y1)`.
type TexelRect = [usize; 4];

#[derive(Debug)]
struct Entry {
    key: JacobianKey,
    filter: TextureFilter,
    rect: TexelRect,
    /// `None` in a plan (nothing is built).
    plane: Option<SkyPlane>,
    last_used: u64,
}

/// Prefiltered crops of one sky plane for one PSF, by Jacobian key: a few are kept, the least recently used
/// replaced.
#[derive(Debug, Default)]
pub struct PrefilterCache {
    entries: Vec<Entry>,
    /// The source image and PSF the entries were made from (their addresses).
    source: Option<(usize, usize)>,
    convolver: Convolver,
    clock: u64,
    builds: u64,
    /// Multiply–adds the builds took (or, in a plan, would take).
    work: f64,
}

impl PrefilterCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// How many crops have been prefiltered (or, in a plan, would have been) so far.
    pub fn builds(&self) -> u64 {
        self.builds
    }

    /// Multiply–adds of those builds (an FFT counted as 200 per texel and phase).
    pub fn work(&self) -> f64 {
        self.work
    }

    /// The plane of `source`'s image prefiltered for the Jacobian of `key`, over at least the texels within 2
    /// of the image-coordinate box `need` (`[x0, y0, x1, y1]`, px); `None` when the texture kernel is too wide
    /// ([`MAX_TEXTURE_RADIUS`]).
    pub fn plane(
        &mut self,
        source: &SkyPlane,
        psf: &Psf,
        key: JacobianKey,
        tolerance: f64,
        need: [f64; 4],
    ) -> Option<&SkyPlane> {
        let slot = self.slot(source, psf, key, tolerance, need, true)?;
        self.entries[slot].plane.as_ref()
    }

    /// What [`PrefilterCache::plane`] would do, without building anything: counts the builds and their work.
    /// Returns false when the texture kernel is too wide. A cache used for planning must not be used to render.
    pub fn plan(&mut self, source: &SkyPlane, psf: &Psf, key: JacobianKey, tolerance: f64, need: [f64; 4]) -> bool {
        self.slot(source, psf, key, tolerance, need, false).is_some()
    }

    fn slot(
        &mut self,
        source: &SkyPlane,
        psf: &Psf,
        key: JacobianKey,
        tolerance: f64,
        need: [f64; 4],
        build: bool,
    ) -> Option<usize> {
        let id = (source.image().pixels().as_ptr() as usize, psf as *const Psf as usize);
        if self.source != Some(id) {
            self.entries.clear();
            self.source = Some(id);
        }
        self.clock += 1;
        let image = source.image();
        let (w, h) = (image.width(), image.height());
        // texels whose values the bilinear samples inside `need` read
        let lo = |v: f64| (v - 2.0).floor().max(0.0) as usize;
        let hi = |v: f64, n: usize| ((v + 2.0).ceil().max(0.0) as usize).min(n);
        let want = [lo(need[0]).min(w), lo(need[1]).min(h), hi(need[2], w), hi(need[3], h)];
        let covers = |r: &TexelRect| r[0] <= want[0] && r[1] <= want[1] && r[2] >= want[2] && r[3] >= want[3];
        if let Some(i) = self.entries.iter().position(|e| e.key == key && covers(&e.rect)) {
            self.entries[i].last_used = self.clock;
            return Some(i);
        }
        let filter = match self.entries.iter().find(|e| e.key == key) {
            Some(e) => e.filter.clone(),
            None => TextureFilter::new(psf, key.jacobian(tolerance))?,
        };
        // the block-aligned box around what is needed, one block wider on every side so that a panning view
        // rebuilds it now and then rather than every frame
        let down = |v: usize| (v / BLOCK_TEXELS).saturating_sub(1) * BLOCK_TEXELS;
        let up = |v: usize, n: usize| ((v.div_ceil(BLOCK_TEXELS) + 1) * BLOCK_TEXELS).min(n);
        let rect = [down(want[0]), down(want[1]), up(want[2], w), up(want[3], h)];
        let r = filter.radius();
        let texels = ((rect[2] - rect[0] + 2 * r) * (rect[3] - rect[1] + 2 * r)) as f64;
        self.work += texels * filter.phases.iter().map(build_taps).sum::<f64>();
        let plane = build.then(|| self.build(source, &filter, rect));
        let entry = Entry { key, filter, rect, plane, last_used: self.clock };
        self.builds += 1;
        let slot = if self.entries.len() < CACHE_ENTRIES {
            self.entries.push(entry);
            self.entries.len() - 1
        } else {
            let i = (0..self.entries.len()).min_by_key(|&i| self.entries[i].last_used).expect("entries");
            self.entries[i] = entry;
            i
        };
        Some(slot)
    }

    /// `rect` of `source`'s image prefiltered by `filter`, read from the whole image (its edges replicated).
    ///
    /// A texel's value must not depend on the crop it is built in (a frame's result depends on its own camera
    /// alone, whichever crop the cache holds): the direct method computes every texel from its own
    /// neighbourhood, and the FFT method works on blocks of [`FFT_BLOCK_TEXELS`] aligned to the image's own
    /// grid, each read with the kernel's reach around it, so a texel is always computed in the same block at the
    /// same transform size (one transform of the whole crop would round differently for crops of other sizes).
    fn build(&mut self, source: &SkyPlane, filter: &TextureFilter, rect: TexelRect) -> SkyPlane {
        let r = filter.radius();
        let m = filter.per_texel;
        let (cw, ch) = (rect[2] - rect[0], rect[3] - rect[1]);
        let (fw, fh) = (cw * m, ch * m);
        let mut pixels = vec![0.0f32; fw * fh];
        let image = source.image();
        for (phase, kernel) in filter.phases.iter().enumerate() {
            let (a, b) = (phase % m, phase / m);
            let mut place = |blurred: &Frame, [x0, y0, bw, bh]: [usize; 4]| {
                // `blurred` holds texels x0.., y0.. of the image at offset (r, r); copy its part inside `rect`
                let pw = blurred.width();
                for y in y0.max(rect[1])..(y0 + bh).min(rect[3]) {
                    let row = &mut pixels[((y - rect[1]) * m + b) * fw..((y - rect[1]) * m + b + 1) * fw];
                    for x in x0.max(rect[0])..(x0 + bw).min(rect[2]) {
                        row[(x - rect[0]) * m + a] = blurred.pixels()[(y - y0 + r) * pw + x - x0 + r];
                    }
                }
            };
            let read = |x0: usize, y0: usize, w: usize, h: usize| {
                let region =
                    image.region_clamped(x0 as isize - r as isize, y0 as isize - r as isize, w + 2 * r, h + 2 * r);
                Frame::from_pixels(w + 2 * r, h + 2 * r, region)
            };
            let method = build_method(kernel);
            if method == ConvolutionMethod::Direct {
                let mut frame = read(rect[0], rect[1], cw, ch);
                self.convolver.apply(kernel, &mut frame, method);
                place(&frame, [rect[0], rect[1], cw, ch]);
                continue;
            }
            let s = FFT_BLOCK_TEXELS;
            for by in (rect[1] / s..rect[3].div_ceil(s)).map(|k| k * s) {
                for bx in (rect[0] / s..rect[2].div_ceil(s)).map(|k| k * s) {
                    let mut frame = read(bx, by, s, s);
                    self.convolver.apply(kernel, &mut frame, method);
                    place(&frame, [bx, by, s, s]);
                }
            }
        }
        let image = SkyImage::from_f32(fw.max(1), fh.max(1), pixels).expect("a blur of finite values is finite");
        source.with_region(image, [rect[0], rect[1]], m)
    }
}

/// How a texture kernel is applied: directly up to 11 × 11 taps, by FFT above.
fn build_method(kernel: &Kernel) -> ConvolutionMethod {
    let side = 2 * kernel.radius() + 1;
    if side * side <= 121 { ConvolutionMethod::Direct } else { ConvolutionMethod::Fft }
}

/// Multiply–adds per texel of applying `kernel` by [`build_method`].
fn build_taps(kernel: &Kernel) -> f64 {
    match build_method(kernel) {
        ConvolutionMethod::Direct => ((2 * kernel.radius() + 1).pow(2)) as f64,
        // the transform of a block and its reach, per texel of the block
        _ => {
            let side = (FFT_BLOCK_TEXELS + 4 * kernel.radius()) as f64;
            200.0 * side * side / (FFT_BLOCK_TEXELS * FFT_BLOCK_TEXELS) as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::psf::{PsfOptics, PsfSpec};
    use crate::physics::planck::{Band, Measure};

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

    #[test]
    fn identity_jacobian_gives_the_point_kernel() {
        // at one texel per pixel the texture kernel is the PSF ⊗ tent at integer offsets: the point kernel
        let p = psf();
        let k = texture_kernel(&p, DMat2::IDENTITY, DVec2::ZERO).unwrap();
        let point = p.point_kernel();
        let (r, rp) = (k.radius() as isize, point.radius() as isize);
        let (side, side_p) = (2 * r + 1, 2 * rp + 1);
        let mut worst = 0.0f32;
        for dy in -r..=r {
            for dx in -r..=r {
                let got = k.values()[((dy + r) * side + dx + r) as usize];
                let want = if dx.abs() <= rp && dy.abs() <= rp {
                    point.values()[((dy + rp) * side_p + dx + rp) as usize]
                } else {
                    0.0
                };
                worst = worst.max((got - want).abs());
            }
        }
        // the point kernel is cut at its radius and renormalised; the texture kernel holds the PSF to R + ½
        assert!(worst < 0.01 * point.values().iter().fold(0.0f32, |m, &v| m.max(v)), "worst {worst}");
    }

    #[test]
    fn texture_kernel_is_normalised_symmetric_and_scales_with_the_jacobian() {
        let p = psf();
        for j in [
            DMat2::from_diagonal(DVec2::splat(0.5)),
            DMat2::from_diagonal(DVec2::new(2.0, 1.2)),
            DMat2::from_angle(0.4) * 1.5,
        ] {
            let k = texture_kernel(&p, j, DVec2::ZERO).unwrap();
            let v = k.values();
            let sum: f64 = v.iter().map(|&x| f64::from(x)).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{sum}");
            // point symmetry (the PSF is even)
            for (a, b) in v.iter().zip(v.iter().rev()) {
                assert!((a - b).abs() < 1e-6);
            }
            // second moment: the trace of J·Σ·Jᵀ (Σ the PSF's, isotropic) plus the tent's f(1 − f) per axis,
            // 1/6 on average where the PSF spans several texels (not for J = 0.5, where it spans about one)
            if j.x_axis.x.abs() < 1.0 {
                continue;
            }
            let m2_psf = texture_kernel(&p, DMat2::IDENTITY, DVec2::ZERO).unwrap().second_moment_px2() - 2.0 / 6.0;
            let want = 0.5 * m2_psf * (j.x_axis.length_squared() + j.y_axis.length_squared()) + 2.0 / 6.0;
            let got = k.second_moment_px2();
            assert!((got - want).abs() < 0.03 * want, "J {j:?}: second moment {got} vs {want}");
        }
        assert!(texture_kernel(&p, DMat2::ZERO, DVec2::ZERO).is_none());
        assert!(texture_kernel(&p, DMat2::IDENTITY * 50.0, DVec2::ZERO).is_none());
    }

    #[test]
    fn keys_round_within_the_tolerance() {
        for tol in [0.01, 0.05] {
            for j in
                [DMat2::IDENTITY * 0.37, DMat2::from_angle(1.0) * 3.3, DMat2::from_cols_array(&[1.0, 0.2, -0.1, 0.4])]
            {
                let key = JacobianKey::new(j, tol).unwrap();
                let q = key.jacobian(tol);
                let rel = (q - j).to_cols_array().iter().map(|v| v * v).sum::<f64>().sqrt()
                    / j.to_cols_array().iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!(rel <= 0.36 * tol, "{rel} for tolerance {tol}");
                // a nearby Jacobian in the same cell gives the same key; the key is a function of J alone
                assert_eq!(JacobianKey::new(j, tol), Some(key));
            }
        }
        assert!(JacobianKey::new(DMat2::ZERO, 0.02).is_none());
        assert!(JacobianKey::new(DMat2::IDENTITY * f64::NAN, 0.02).is_none());
    }
}
