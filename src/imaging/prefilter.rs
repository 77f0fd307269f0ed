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
//! shifted, exact at its nodes, and the grid spacing is at most [`TEXTURE_SPACING_PX`] (or the spacing set). Where
//! a budget is set ([`PrefilterSettings::grid_error`]), `m` is the smallest whose error [`BlockSpectra`] estimates
//! within it from the image's own content: a smooth sky needs fewer nodes than clouds' edges.
//!
//! Limits, and what keeps them in check:
//! - `J` varies over the frame (perspective) and from frame to frame (motion, pointing). A prefiltered texture
//!   serves one `J`, quantized by [`JacobianKey`] on a lattice of steps of `tolerance/2` (relative), so that a
//!   frame's result depends on its own camera alone, never on the frames before it; tiles of the frame whose own
//!   `J` is more than `tolerance` (relative, Frobenius) from it are blurred the reference way (see
//!   [`super::background`]).
//! - Near the image's edges the texture blur would replicate edge texels where the frame sees the dome: tiles
//!   whose blur reaches within 1.5 texels of the edge are blurred the reference way too, unless the image is
//!   widened by a margin of the dome ([`super::sky_plane::DomeMargin`]), whose texels hold what the frame sees
//!   there. The grid's estimate ([`BlockSpectra`]) then reads the margin's blocks too (the step at the image's
//!   edge among them): it takes the worst block, so the margin can only make the grid finer.
//! - The reference blur of a frame replicates the frame's edge pixels; the prefiltered texture holds the sky
//!   beyond the frame's edge, as the optics see it. The outermost `R` pixels (the PSF radius) differ by that.
//!
//! The blurred texture is made only for the texels the view needs ([`PrefilterCache`]), from the whole image
//! (its true edges replicated), block by block on a grid aligned to the image, so a crop's values do not depend
//! on where the crop ends and a panning view filters each block once. A key's blocks are written into one grid
//! of its fine nodes over the whole image (or, for an image too large, a window around the view), and a crop is
//! a view of that grid, its rows a grid's row apart: a view panning past its crop's margin takes a new view of
//! the same values, nothing copied. Wide kernels go through FFTs, two phases to an inverse transform (one as the
//! real part, one as the imaginary).
//!
//! Cost, measured with `irsim bench SCENARIO --frames 300` (two interleaved rounds, this machine's 2 cores): on
//! paper_clear_sky, whose tracking camera pans across the image, 294–295 frames/s when every crop was filtered
//! whole by one transform pair per phase, 647–662 with blocks kept and phases paired; head_on 236 → 294–299.
//! A new Jacobian's kernels (`cargo bench --bench imaging -- texture_filter`): 2.09 ms for 4 phases and
//! 5.87 ms for 16 when each phase sampled the PSF anew, 0.53 and 0.82 ms with the samples shared and the phases
//! made side by side.

use std::marker::PhantomData;
use std::ops::Range;
use std::sync::Arc;

use glam::{DMat2, DVec2};

use super::frame::Frame;
use rayon::prelude::*;
use rustfft::num_complex::Complex;

use super::psf::{ConvolutionMethod, Convolver, Kernel, Psf, fast_len, sinc};
use super::sky_plane::{SkyImage, SkyPlane};

/// Largest radius of a texture kernel, texels; a sky minified more than this allows is blurred per frame.
pub const MAX_TEXTURE_RADIUS: usize = 40;
/// Texture crops are aligned to blocks of this many texels.
const BLOCK_TEXELS: usize = 32;
/// Side of the blocks, aligned to the image's texel grid, that the FFT method of a texture build works on.
const FFT_BLOCK_TEXELS: usize = 128;
/// Prefiltered crops kept (a view whose Jacobian sits on a lattice boundary alternates between two keys).
const CACHE_ENTRIES: usize = 4;
/// Bytes of prefiltered blocks kept for later crops, counted by the pages they are written on (a panning view
/// needs the blocks it saw a moment ago and a few new ones; a run that comes back to a Jacobian, or `irsim
/// bench` running a scenario again, needs every key's blocks); the blocks of the key in use are kept whatever
/// their size. sense_and_avoid's 7 keys take 192
/// blocks of 576 KiB (24 to 28 a key, on a grid of 3 × 3 nodes a texel), 108 MiB: at 64 MiB each pass of `irsim
/// bench` made all of them again, 16–28 ms a key (docs/accuracy.md).
const BLOCK_CACHE_BYTES: usize = 256 << 20;
/// Largest grid of one key's blocks, bytes ([`Canvas`]): the whole image where its grid is no larger (its pages
/// are mapped only where blocks are written), else a window around the crops in use. sense_and_avoid's image,
/// 4096 × 1536 texels on a grid of 3 × 3 nodes a texel, takes 216 MiB.
const CANVAS_BYTES: usize = 256 << 20;
/// The pages a canvas's written blocks are counted by.
const PAGE_BYTES: usize = 4096;
/// Bytes of texture filters kept for Jacobians seen before (a camera panning back, a run looped by `irsim
/// bench`); the filter in use is kept whatever its size. A filter is a few hundred KiB at most on the shipped
/// scenarios, and takes 0.5–2.5 ms to make (docs/accuracy.md).
const FILTER_CACHE_BYTES: usize = 16 << 20;
/// Most filters kept (keys whose kernels are too wide are kept as such, and hold no bytes).
const FILTER_CACHE_ENTRIES: usize = 256;

/// The PSF mapped into texel space by the Jacobian `jacobian` (texels per sensor pixel; column 0 is the
/// change of image coordinates per pixel along the sensor's u, column 1 along v) and read `shift` texels from
/// texel centres: `k[d] = ∫ PSF(y)·Λ(shift + J·y − d) dy`, so that `Σ_d k[d]·T[n + d]` is the blurred image at
/// `n + shift`. A kernel summing to 1 (applied in 2D); `None` if its radius would exceed
/// [`MAX_TEXTURE_RADIUS`] or `jacobian` is not finite and invertible.
pub fn texture_kernel(psf: &Psf, jacobian: DMat2, shift: DVec2) -> Option<Kernel> {
    PsfSamples::new(psf, jacobian)?.kernel(shift)
}

/// Rows of the PSF's sample grid made by one task of [`PsfSamples::new`].
const SAMPLE_BAND_ROWS: usize = 32;

/// The midpoint-rule samples of the PSF that [`texture_kernel`] splats for one Jacobian, mapped into texel
/// space: the same for every shift, so a [`TextureFilter`]'s phases share them (each phase splats them with its
/// own tent).
struct PsfSamples {
    /// How far the mapped PSF reaches from its centre along each texel axis, texels.
    reach_texels: DVec2,
    /// `(J·y, PSF(y)·h²)` for each grid point `y` where the PSF is not 0, row by row.
    points: Vec<(DVec2, f64)>,
}

impl PsfSamples {
    /// `None` if `jacobian` is not finite and invertible.
    fn new(psf: &Psf, jacobian: DMat2) -> Option<Self> {
        let j = jacobian;
        if !(j.is_finite() && j.determinant().abs() > 1e-12 * frobenius2(j)) {
            return None;
        }
        // the PSF is 0 beyond R + ½ px on either axis
        let reach_px = psf.radius_px() as f64 + 0.5;
        // texels per px along each texel axis, at most
        let stretch = DVec2::new(j.x_axis.x.abs() + j.y_axis.x.abs(), j.x_axis.y.abs() + j.y_axis.y.abs());
        // sample spacing: at most 1/16 px and 1/16 texel along either texel axis
        // every phase's kernel reaches at least this far: too wide, none is made (before sampling a grid whose
        // size grows with the stretch)
        let reach_texels = reach_px * stretch;
        if reach_texels.max_element().ceil() as usize + 1 > MAX_TEXTURE_RADIUS {
            return None;
        }
        let per_px = (16.0 * stretch.x.max(stretch.y).max(1.0)).ceil();
        let n = (2.0 * reach_px * per_px).ceil() as usize;
        let h = 2.0 * reach_px / n as f64;
        let nodes: Vec<f64> = (0..n).map(|a| -reach_px + (a as f64 + 0.5) * h).collect();
        // bands of rows side by side (the grid has 10⁵ nodes and more: 0.7–1.9 ms on one thread on the shipped
        // scenarios, made for every new view Jacobian), put together in row order
        let bands: Vec<Vec<(DVec2, f64)>> = nodes
            .par_chunks(SAMPLE_BAND_ROWS)
            .map(|ys| {
                let values = psf.values_on_grid(&nodes, ys);
                let mut band = Vec::with_capacity(values.len());
                for (&y, row) in ys.iter().zip(values.chunks_exact(n)) {
                    for (&x, &v) in nodes.iter().zip(row) {
                        let w = f64::from(v) * h * h;
                        if w != 0.0 {
                            band.push((j * DVec2::new(x, y), w));
                        }
                    }
                }
                band
            })
            .collect();
        Some(Self { reach_texels, points: bands.concat() })
    }

    /// The kernel read `shift` texels from texel centres ([`texture_kernel`]).
    fn kernel(&self, shift: DVec2) -> Option<Kernel> {
        if !shift.is_finite() {
            return None;
        }
        let reach = self.reach_texels + shift.abs();
        // the tent reaches one texel further
        let radius = reach.x.max(reach.y).ceil() as usize + 1;
        if radius > MAX_TEXTURE_RADIUS {
            return None;
        }
        let side = 2 * radius + 1;
        let mut values = vec![0.0f64; side * side];
        let centre = DVec2::splat(radius as f64) + shift;
        for &(p, w) in &self.points {
            let z = p + centre;
            // z ≥ 1 on both axes (the radius reaches a texel beyond |J·y| + |shift|): truncation is the floor,
            // without a libm call
            let (x0, y0) = (z.x as usize, z.y as usize);
            let (fx, fy) = (z.x - x0 as f64, z.y - y0 as f64);
            let at = y0 * side + x0;
            values[at] += w * (1.0 - fx) * (1.0 - fy);
            values[at + 1] += w * fx * (1.0 - fy);
            values[at + side] += w * (1.0 - fx) * fy;
            values[at + side + 1] += w * fx * fy;
        }
        let total: f64 = values.iter().sum();
        if !(total > 0.0) {
            return None;
        }
        values.iter_mut().for_each(|v| *v /= total);
        Some(Kernel::from_values_2d(radius, &values))
    }
}

fn frobenius2(m: DMat2) -> f64 {
    m.to_cols_array().iter().map(|v| v * v).sum()
}

/// How a [`PrefilterCache`] makes its textures (`[quality] prefilter_tolerance`, `prefilter_spacing_px` and
/// `prefilter_grid_error_dn`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PrefilterSettings {
    /// Largest relative difference between a tile's Jacobian and its texture's ([`JacobianKey`]).
    pub tolerance: f64,
    /// Largest spacing of a texture's grid, px ([`TextureFilter::with_spacing`]).
    pub spacing_px: f64,
    /// Largest estimated error of a texture's grid, in the image's units (radiance): the grid is the coarsest
    /// whose bilinear reads [`BlockSpectra::grid_errors`] estimates within this of the exact blurred image, in
    /// every block of the image, and never finer than `spacing_px` allows; 0 takes `spacing_px`'s grid
    /// (`[quality] prefilter_grid_error_dn`, in DN there).
    pub grid_error: f64,
}

/// Largest spacing of a prefiltered texture's grid, sensor pixels, in the standard preset (`[quality]
/// prefilter_spacing_px`): a magnified image is prefiltered onto a grid at least this fine. Measured against the
/// brute-force blur at sharp-edged clouds (`cargo test --lib prefiltered_sky`, image 0.65 texel/px): grids of
/// 0.77 px err up to 0.11 of a cloud's 4-unit step, 0.51 px 0.016–0.039, 0.38 px 0.021–0.024, the per-frame
/// blur 0.11–0.13. On the shipped scenarios, against the reference preset's 0.25 px (noise off, 8 frames), 0.75
/// (the 0.5 px grids of their 1 px generated texels) erred up to 0.64 DN rms and 0.45 (0.33 px grids) up to
/// 0.38. Finer grids cost memory traffic in the ray cast and work in the build (both ∝ 1/spacing²).
pub const TEXTURE_SPACING_PX: f64 = 0.45;

/// Side of the image blocks whose spectra estimate a texture grid's error ([`BlockSpectra`]), texels.
const SPECTRUM_BLOCK: usize = 64;
/// A block's spectrum is summed into this many cells of frequency a side.
const SPECTRUM_CELLS: usize = 16;

/// How an image's variance is spread over frequency, block by block, for estimating how fine a prefiltered
/// texture's grid must be. Each 64-texel square block of the image (the last of a row or column ending at the
/// image's edge, overlapping the one before) is Hann-windowed about its windowed mean and transformed; the power of its frequencies is summed into
/// 16 × 16 cells over `[−½, ½)²` cycles/texel, scaled so that a block's cells add up to its
/// variance (for a stationary field).
#[derive(Debug)]
pub struct BlockSpectra {
    /// `SPECTRUM_CELLS²` values per block, row-major by cell (cell `c` along an axis holds the frequencies
    /// `(j − S/2)/S`, `j ∈ [c·S/C, (c + 1)·S/C)`); empty for an image narrower or shorter than a block, whose
    /// estimates are then infinite (no grid coarser than the finest is chosen for it).
    cells: Vec<f32>,
}

impl BlockSpectra {
    /// The spectra of `image`'s blocks.
    pub fn new(image: &SkyImage) -> Self {
        let s = SPECTRUM_BLOCK;
        let c = SPECTRUM_CELLS;
        let (w, h) = (image.width(), image.height());
        if w < s || h < s {
            return Self { cells: Vec::new() };
        }
        let (bw, bh) = (w.div_ceil(s), h.div_ceil(s));
        // block k starts at k·S, the last S before the edge, so that every block is the image's own texels
        let hann: Vec<f64> =
            (0..s).map(|x| (std::f64::consts::PI * (x as f64 + 0.5) / s as f64).sin().powi(2)).collect();
        let (w_sum, w2_sum) = (hann.iter().sum::<f64>().powi(2), hann.iter().map(|h| h * h).sum::<f64>().powi(2));
        let plan = rustfft::FftPlanner::<f64>::new().plan_fft_forward(s);
        let per_cell = s / c;
        let cells: Vec<f32> = (0..bw * bh)
            .into_par_iter()
            .flat_map_iter(|b| {
                let (bx, by) = (b % bw, b / bw);
                let (x0, y0) = ((bx * s).min(w - s), (by * s).min(h - s));
                let region = image.region_clamped(x0 as isize, y0 as isize, s, s);
                let weight = |i: usize| hann[i % s] * hann[i / s];
                let mean = region.iter().enumerate().map(|(i, &v)| weight(i) * f64::from(v)).sum::<f64>() / w_sum;
                let mut data: Vec<Complex<f64>> = region
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| Complex::new((f64::from(v) - mean) * weight(i), 0.0))
                    .collect();
                data.chunks_exact_mut(s).for_each(|row| plan.process(row));
                let mut column = vec![Complex::new(0.0, 0.0); s];
                let mut out = vec![0.0f32; c * c];
                for kx in 0..s {
                    column.iter_mut().enumerate().for_each(|(ky, v)| *v = data[ky * s + kx]);
                    plan.process(&mut column);
                    let cx = ((kx + s / 2) % s) / per_cell;
                    for (ky, v) in column.iter().enumerate() {
                        let cy = ((ky + s / 2) % s) / per_cell;
                        out[cy * c + cx] += (v.norm_sqr() / (w2_sum * (s * s) as f64)) as f32;
                    }
                }
                out
            })
            .collect();
        Self { cells }
    }

    /// For grids `m = 1 … m_max` times finer than the image's texels: the largest over the image's blocks of
    /// the rms error of bilinear reads of the image blurred by `psf` mapped through `jacobian` (texels per px)
    /// from the grid's nodes, against the blurred image itself.
    ///
    /// The blurred field is the bilinear image convolved with the mapped PSF, so its spectrum at `ν`
    /// (cycles/texel) is the image's (periodic, period 1) times `MTF(Jᵀν)·sinc²(νx)·sinc²(νy)`. Reading it
    /// bilinearly from nodes `h = 1/m` apart at a random offset errs, per unit power at `ν`, by
    /// `(1 − T(ν))² + A(x)·A(y) − T(ν)²` with `T = sinc²(x)·sinc²(y)`, `(x, y) = h·ν` and `A(x) = Σₖ sinc⁴(x + k)
    /// = 1 − ⅔·sin²(πx)`: the passband's loss plus the aliases. The sum runs over the image's periods while
    /// the MTF and the tent pass anything.
    pub fn grid_errors(&self, psf: &Psf, jacobian: DMat2, m_max: usize) -> Vec<f64> {
        let c = SPECTRUM_CELLS;
        let mtf = psf.mtf();
        let smallest = smallest_stretch(jacobian);
        if !(smallest > 0.0) || self.cells.is_empty() {
            return vec![f64::INFINITY; m_max];
        }
        // the periods whose frequencies can reach the MTF's cut-off, cycles/texel (the tent passes about 10⁻⁴
        // of a flat spectrum's power past the third)
        let periods = ((mtf.cutoff() / smallest).ceil() + 1.0).min(3.0) as i64;
        let alias = |x: f64| 1.0 - 2.0 / 3.0 * (std::f64::consts::PI * x).sin().powi(2);
        // each cell's mean weight per grid, from 2 × 2 frequencies in it (bins 1 and 3 of its 4 along an axis: in
        // the cells next to 0, where the error grows as ν⁴, the mean is overstated, which errs toward finer grids)
        let sub = 2;
        // the frequencies along one axis (cycles/texel: a cell's sample plus a period), and at each the tent's
        // factor and, per grid, sinc² and the alias sum of the grid's own tent: the error's factors are per axis
        let axis: Vec<f64> = (0..c)
            .flat_map(|cell| (0..sub).map(move |k| -0.5 + (cell as f64 + (k as f64 + 0.5) / sub as f64) / c as f64))
            .flat_map(|nu| (-periods..=periods).map(move |n| nu + n as f64))
            .collect();
        let tent: Vec<f64> = axis.iter().map(|&f| sinc(f).powi(2)).collect();
        let grid: Vec<(f64, f64)> = (1..=m_max)
            .flat_map(|m| axis.iter().map(move |&f| f / m as f64))
            .map(|x| (sinc(x).powi(2), alias(x)))
            .collect();
        let per_sample = (2 * periods + 1) as usize;
        let mut weights = vec![0.0f64; m_max * c * c];
        for cy in 0..c {
            for cx in 0..c {
                for (sy, sx) in (0..sub).flat_map(|sy| (0..sub).map(move |sx| (sy, sx))) {
                    let (iy0, ix0) = (((cy * sub) + sy) * per_sample, ((cx * sub) + sx) * per_sample);
                    for iy in iy0..iy0 + per_sample {
                        for ix in ix0..ix0 + per_sample {
                            let f = DVec2::new(axis[ix], axis[iy]);
                            // frequency in cycles/px: ν·u with u = J·x is (Jᵀν)·x
                            let f_px = jacobian.transpose() * f;
                            let gain = mtf.at(f_px.x, f_px.y) * tent[ix] * tent[iy];
                            let power = gain * gain;
                            if power < 1e-12 {
                                continue;
                            }
                            for m in 0..m_max {
                                let ((sx_, ax), (sy_, ay)) = (grid[m * axis.len() + ix], grid[m * axis.len() + iy]);
                                let t = sx_ * sy_;
                                let e = (1.0 - t).powi(2) + ax * ay - t * t;
                                weights[m * c * c + cy * c + cx] += power * e.max(0.0) / (sub * sub) as f64;
                            }
                        }
                    }
                }
            }
        }
        (0..m_max)
            .map(|m| {
                let w = &weights[m * c * c..(m + 1) * c * c];
                self.cells
                    .chunks_exact(c * c)
                    .map(|block| block.iter().zip(w).map(|(&p, &w)| f64::from(p) * w).sum::<f64>())
                    .fold(0.0, f64::max)
                    .sqrt()
            })
            .collect()
    }
}

/// The smallest stretch of `jacobian` (its smallest singular value): the largest texel step in sensor pixels
/// is its inverse.
fn smallest_stretch(jacobian: DMat2) -> f64 {
    let (a, b, c, d) = (jacobian.x_axis.x, jacobian.y_axis.x, jacobian.x_axis.y, jacobian.y_axis.y);
    let (p, q) = (a * a + b * b + c * c + d * d, (a * d - b * c).abs());
    (0.5 * (p - (p * p - 4.0 * q * q).max(0.0).sqrt())).max(0.0).sqrt()
}

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
        Self::with_per_texel(psf, jacobian, finest_per_texel(jacobian, spacing_px)?)
    }

    /// As [`TextureFilter::new`] on a grid `per_texel` times finer than the image's texels.
    pub fn with_per_texel(psf: &Psf, jacobian: DMat2, per_texel: usize) -> Option<Self> {
        let per_texel = per_texel.clamp(1, MAX_PER_TEXEL);
        let m = per_texel as f64;
        let samples = PsfSamples::new(psf, jacobian)?;
        // the phases side by side, in order
        let phases = (0..per_texel * per_texel)
            .into_par_iter()
            .map(|phase| {
                let (a, b) = (phase % per_texel, phase / per_texel);
                // fine node (m·q + a) sits at coarse coordinate q + (a + ½)/m, i.e. (a + ½)/m − ½ from centre q
                let shift = DVec2::new((a as f64 + 0.5) / m - 0.5, (b as f64 + 0.5) / m - 0.5);
                samples.kernel(shift)
            })
            .collect::<Option<Vec<_>>>()?;
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

    /// Bytes its kernels hold.
    fn bytes(&self) -> usize {
        self.phases.iter().map(|k| size_of_val(k.values())).sum()
    }
}

/// Most grid nodes per texel along an axis.
const MAX_PER_TEXEL: usize = 64;

/// Grid nodes per texel along each axis for a grid no coarser than `spacing_px` sensor pixels through
/// `jacobian`; `None` where it is not finite and invertible.
pub fn finest_per_texel(jacobian: DMat2, spacing_px: f64) -> Option<usize> {
    let smallest = smallest_stretch(jacobian);
    if !(smallest > 0.0) {
        return None;
    }
    Some((1.0 / (smallest * spacing_px) - 1e-9).ceil().clamp(1.0, MAX_PER_TEXEL as f64) as usize)
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

/// A crop handed out: a texel rectangle of a key's [`Canvas`].
#[derive(Debug)]
struct Entry {
    key: JacobianKey,
    rect: TexelRect,
    last_used: u64,
}

/// A key's texture filter, or `None` where its kernels are too wide ([`MAX_TEXTURE_RADIUS`]).
#[derive(Debug)]
struct KeptFilter {
    key: JacobianKey,
    filter: Option<Arc<TextureFilter>>,
    last_used: u64,
}

/// One key's prefiltered image: its [`FFT_BLOCK_TEXELS`]-square blocks, aligned to the image's texel grid, each
/// prefiltered once (every phase, on the fine grid of `per_texel` nodes a texel along each axis), held in one
/// row-major grid of fine nodes over a window of the image, so that a crop is a view of it, never a copy.
#[derive(Debug)]
struct Canvas {
    key: JacobianKey,
    /// Grid nodes per texel along each axis: a block holds `(FFT_BLOCK_TEXELS · per_texel)²` values.
    per_texel: usize,
    /// The texels it covers, aligned to [`FFT_BLOCK_TEXELS`] (its last blocks may reach past the image's edge).
    window: TexelRect,
    /// Which of its blocks hold their values, row-major.
    present: Vec<bool>,
    /// Which of the grid's 4 KiB pages a block's rows were written on since it was made (they stay mapped).
    pages: Vec<bool>,
    /// How many: the grid's pages count against [`BLOCK_CACHE_BYTES`], not its blocks' bytes (a block's rows
    /// of 512 bytes, one node a texel, lie a grid's row apart, each on a page of its own).
    touched: usize,
    /// The grid (`None` in a plan, and until a block is written): `stride()` floats a row.
    values: Option<Arc<Vec<f32>>>,
    last_used: u64,
}

impl Canvas {
    fn new(key: JacobianKey, per_texel: usize, window: TexelRect, last_used: u64) -> Self {
        let s = FFT_BLOCK_TEXELS;
        let blocks = (window[2] - window[0]) / s * ((window[3] - window[1]) / s);
        let floats = (window[2] - window[0]) * (window[3] - window[1]) * per_texel * per_texel;
        let pages = (floats * size_of::<f32>()).div_ceil(PAGE_BYTES);
        Self {
            key,
            per_texel,
            window,
            present: vec![false; blocks],
            pages: vec![false; pages],
            touched: 0,
            values: None,
            last_used,
        }
    }

    /// Floats a row of the grid.
    fn stride(&self) -> usize {
        (self.window[2] - self.window[0]) * self.per_texel
    }

    /// Index in `present` of the block whose first texel is `at`, if inside the window.
    fn block(&self, [bx, by]: [usize; 2]) -> Option<usize> {
        let s = FFT_BLOCK_TEXELS;
        let w = self.window;
        let inside = bx >= w[0] && by >= w[1] && bx < w[2] && by < w[3];
        inside.then(|| (by - w[1]) / s * ((w[2] - w[0]) / s) + (bx - w[0]) / s)
    }

    /// The bytes of the grid's pages its blocks were written on.
    fn bytes(&self) -> usize {
        self.touched * PAGE_BYTES
    }

    /// Its grid, made (of pages the system maps as they are first written) where it had none, for writing. The
    /// crops handed out are dropped before a grid is written, so it is never shared here (were it, it would be
    /// copied first, the views keeping the old values).
    fn values_mut(&mut self) -> &mut [f32] {
        let len = self.stride() * (self.window[3] - self.window[1]) * self.per_texel;
        let values: &mut Vec<f32> = Arc::make_mut(self.values.get_or_insert_with(|| Arc::new(vec![0.0; len])));
        values
    }

    /// The grid's column and row of texel `at`'s first node (`at` inside the window).
    fn node(&self, at: [usize; 2]) -> [usize; 2] {
        let m = self.per_texel;
        [(at[0] - self.window[0]) * m, (at[1] - self.window[1]) * m]
    }

    /// Where texel `at` (inside the window) starts in the grid.
    fn offset(&self, at: [usize; 2]) -> usize {
        let [x, y] = self.node(at);
        y * self.stride() + x
    }

    /// Marks the block whose first texel is `at` present, and the pages its rows lie on touched (in a plan, as
    /// though its values were written).
    fn mark(&mut self, at: [usize; 2]) {
        let i = self.block(at).expect("a block inside the window");
        let (first, stride) = (self.offset(at), self.stride());
        let bs = FFT_BLOCK_TEXELS * self.per_texel;
        for y in 0..bs {
            let start = first + y * stride;
            let bytes = start * size_of::<f32>()..(start + bs) * size_of::<f32>();
            for page in &mut self.pages[bytes.start / PAGE_BYTES..=(bytes.end - 1) / PAGE_BYTES] {
                self.touched += usize::from(!*page);
                *page = true;
            }
        }
        self.present[i] = true;
    }

    /// Writes the values of the blocks whose first texels are `blocks` (each `(FFT_BLOCK_TEXELS · per_texel)²`,
    /// row-major) into the grid, its rows in parallel (megabytes a key, on pages the system maps and zeroes as
    /// they are first written), and marks them.
    fn write(&mut self, blocks: &[[usize; 2]], values: &[Vec<f32>]) {
        let stride = self.stride();
        let bs = FFT_BLOCK_TEXELS * self.per_texel;
        // each block's first node: its column and row in the grid
        let places: Vec<[usize; 2]> = blocks.iter().map(|&at| self.node(at)).collect();
        if let (Some(top), Some(bottom)) = (places.iter().map(|p| p[1]).min(), places.iter().map(|p| p[1] + bs).max()) {
            let grid = self.values_mut();
            grid[top * stride..bottom * stride].par_chunks_mut(stride).enumerate().for_each(|(k, row)| {
                let y = top + k;
                for (&[x0, y0], block) in places.iter().zip(values) {
                    if (y0..y0 + bs).contains(&y) {
                        row[x0..x0 + bs].copy_from_slice(&block[(y - y0) * bs..(y - y0 + 1) * bs]);
                    }
                }
            });
        }
        for &at in blocks {
            self.mark(at);
        }
    }

    /// Writes the blocks whose first texels are `blocks` in place, each by `fill` given its first texel and its
    /// rows in the grid, the blocks in parallel, and marks them if every `fill` returned true (else returns
    /// false, none marked).
    ///
    /// # Panics
    /// If a block is outside the window, off its grid of blocks, or given twice.
    fn fill(&mut self, blocks: &[[usize; 2]], fill: impl Fn([usize; 2], &mut BlockRows<'_>) -> bool + Sync) -> bool {
        let (s, w) = (FFT_BLOCK_TEXELS, self.window);
        let mut seen = vec![false; self.present.len()];
        // each block's first node in the grid
        let firsts: Vec<usize> = blocks
            .iter()
            .map(|&at| {
                let i = self.block(at).expect("a block inside the window");
                assert!((at[0] - w[0]) % s == 0 && (at[1] - w[1]) % s == 0, "a block on the window's grid of blocks");
                assert!(!std::mem::replace(&mut seen[i], true), "each block once");
                self.offset(at)
            })
            .collect();
        let (stride, bs) = (self.stride(), s * self.per_texel);
        let grid = SharedGrid::new(self.values_mut());
        let finite = blocks.par_iter().zip(&firsts).map(|(&at, &first)| {
            // SAFETY: distinct blocks of the window's grid of blocks (checked above) own disjoint rectangles of
            // the grid: side by side they share rows, never a value
            let mut rows = unsafe { grid.block(first, stride, bs) };
            fill(at, &mut rows)
        });
        if !finite.reduce(|| true, |a, b| a && b) {
            return false;
        }
        for &at in blocks {
            self.mark(at);
        }
        true
    }

    /// The block whose first texel is `at`, copied out of the grid.
    fn read(&self, at: [usize; 2]) -> Option<Vec<f32>> {
        let values = self.values.as_ref()?;
        let (first, stride) = (self.offset(at), self.stride());
        let bs = FFT_BLOCK_TEXELS * self.per_texel;
        Some((0..bs).flat_map(|y| &values[first + y * stride..first + y * stride + bs]).copied().collect())
    }
}

/// Whether texel rectangle `outer` holds `inner`.
fn holds(outer: &TexelRect, inner: &TexelRect) -> bool {
    outer[0] <= inner[0] && outer[1] <= inner[1] && outer[2] >= inner[2] && outer[3] >= inner[3]
}

/// Prefiltered crops of one sky plane for one PSF, by Jacobian key: a few are kept, the least recently used
/// replaced. A crop is a view of its key's grid of prefiltered blocks, which are kept (up to 256 MiB of them) for the
/// next crops of the same key, so a view panning across the image filters each block once and copies nothing.
#[derive(Debug, Default)]
pub struct PrefilterCache {
    entries: Vec<Entry>,
    canvases: Vec<Canvas>,
    /// The crop last handed out.
    view: Option<SkyPlane>,
    /// The largest canvas, bytes ([`CANVAS_BYTES`] where `None`).
    canvas_bytes: Option<usize>,
    /// The filters of the keys seen (and the keys whose kernels are too wide), up to [`FILTER_CACHE_BYTES`].
    filters: Vec<KeptFilter>,
    /// The transforms of the last key's kernels.
    spectra: Option<PhaseSpectra>,
    /// The source image's block spectra, made when a grid is first chosen by its error.
    image_spectra: Option<BlockSpectra>,
    /// The source image and PSF the entries were made from (their addresses), and the settings (their bits).
    source: Option<(usize, usize, [u64; 3])>,
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
        settings: PrefilterSettings,
        need: [f64; 4],
    ) -> Option<&SkyPlane> {
        let slot = self.slot(source, psf, key, settings, need, true)?;
        let Entry { key, rect, .. } = self.entries[slot];
        let canvas = self.canvases.iter().find(|c| c.key == key).expect("a crop's key has its canvas");
        let values = canvas.values.clone().expect("a built crop's canvas holds values");
        let m = canvas.per_texel;
        let offset = canvas.offset([rect[0], rect[1]]);
        let image = SkyImage::view(values, offset, (rect[2] - rect[0]) * m, (rect[3] - rect[1]) * m, canvas.stride());
        self.view = Some(source.with_region(image, [rect[0], rect[1]], m));
        self.view.as_ref()
    }

    /// What [`PrefilterCache::plane`] would do, without building anything: counts the builds and their work.
    /// Returns false when the texture kernel is too wide. A cache used for planning must not be used to render.
    pub fn plan(
        &mut self,
        source: &SkyPlane,
        psf: &Psf,
        key: JacobianKey,
        settings: PrefilterSettings,
        need: [f64; 4],
    ) -> bool {
        self.slot(source, psf, key, settings, need, false).is_some()
    }

    fn slot(
        &mut self,
        source: &SkyPlane,
        psf: &Psf,
        key: JacobianKey,
        settings: PrefilterSettings,
        need: [f64; 4],
        build: bool,
    ) -> Option<usize> {
        let PrefilterSettings { tolerance, spacing_px, .. } = settings;
        let id = (
            source.image().pixels().as_ptr() as usize,
            psf as *const Psf as usize,
            [tolerance.to_bits(), spacing_px.to_bits(), settings.grid_error.to_bits()],
        );
        if self.source != Some(id) {
            self.entries.clear();
            self.canvases.clear();
            self.view = None;
            self.filters.clear();
            self.image_spectra = None;
            self.source = Some(id);
        }
        self.clock += 1;
        let image = source.image();
        let (w, h) = (image.width(), image.height());
        // texels whose values the bilinear samples inside `need` read
        let lo = |v: f64| (v - 2.0).floor().max(0.0) as usize;
        let hi = |v: f64, n: usize| ((v + 2.0).ceil().max(0.0) as usize).min(n);
        let want = [lo(need[0]).min(w), lo(need[1]).min(h), hi(need[2], w), hi(need[3], h)];
        if let Some(i) = self.entries.iter().position(|e| e.key == key && holds(&e.rect, &want)) {
            self.entries[i].last_used = self.clock;
            // the key's canvas and filter are in use too: not the first to go when they are dropped
            if let Some(c) = self.canvases.iter_mut().find(|c| c.key == key) {
                c.last_used = self.clock;
            }
            self.touch_filter(key);
            return Some(i);
        }
        let filter = self.filter(image, psf, key, settings)?;
        // the block-aligned box around what is needed, one block wider on every side so that a panning view
        // rebuilds it now and then rather than every frame
        let down = |v: usize| (v / BLOCK_TEXELS).saturating_sub(1) * BLOCK_TEXELS;
        let up = |v: usize, n: usize| ((v.div_ceil(BLOCK_TEXELS) + 1) * BLOCK_TEXELS).min(n);
        let rect = [down(want[0]), down(want[1]), up(want[2], w), up(want[3], h)];
        let c = self.canvas(key, filter.per_texel, rect, (w, h));
        let missing = self.mark_blocks(c, rect);
        let s = FFT_BLOCK_TEXELS;
        self.work += (missing.len() * s * s) as f64 * build_taps(&filter);
        if build && !missing.is_empty() {
            self.build(source, &filter, c, &missing);
        } else if !build {
            for &at in &missing {
                self.canvases[c].mark(at);
            }
        }
        self.evict_canvases();
        let entry = Entry { key, rect, last_used: self.clock };
        self.builds += 1;
        let slot = if self.entries.len() < CACHE_ENTRIES {
            self.entries.push(entry);
            self.entries.len() - 1
        } else {
            let (i, _) = least_recent(&self.entries, |e| e.last_used);
            self.entries[i] = entry;
            i
        };
        Some(slot)
    }

    /// The texture filter of `key`, made or kept from before; the least recently used filters beyond
    /// [`FILTER_CACHE_BYTES`] or [`FILTER_CACHE_ENTRIES`] are dropped.
    fn filter(
        &mut self,
        image: &SkyImage,
        psf: &Psf,
        key: JacobianKey,
        settings: PrefilterSettings,
    ) -> Option<Arc<TextureFilter>> {
        if let Some(kept) = self.touch_filter(key) {
            return kept.filter.clone();
        }
        let jacobian = key.jacobian(settings.tolerance);
        let filter = finest_per_texel(jacobian, settings.spacing_px)
            .map(|finest| {
                if settings.grid_error > 0.0 && finest > 1 {
                    let spectra = self.image_spectra.get_or_insert_with(|| BlockSpectra::new(image));
                    let errors = spectra.grid_errors(psf, jacobian, finest);
                    errors.iter().position(|&e| e <= settings.grid_error).map_or(finest, |k| k + 1)
                } else {
                    finest
                }
            })
            .and_then(|per_texel| TextureFilter::with_per_texel(psf, jacobian, per_texel))
            .map(Arc::new);
        self.filters.push(KeptFilter { key, filter: filter.clone(), last_used: self.clock });
        let bytes = |f: &KeptFilter| f.filter.as_ref().map_or(0, |f| f.bytes());
        let mut total: usize = self.filters.iter().map(bytes).sum();
        while total > FILTER_CACHE_BYTES || self.filters.len() > FILTER_CACHE_ENTRIES {
            let (i, oldest) = least_recent(&self.filters, |f| f.last_used);
            if oldest == self.clock {
                break;
            }
            total -= bytes(&self.filters[i]);
            self.filters.swap_remove(i);
        }
        filter
    }

    /// The kept filter of `key`, marked used now.
    fn touch_filter(&mut self, key: JacobianKey) -> Option<&KeptFilter> {
        let kept = self.filters.iter_mut().find(|f| f.key == key)?;
        kept.last_used = self.clock;
        Some(kept)
    }

    /// The index of `key`'s canvas, marked used, made where there is none, or moved where its window does not
    /// hold `rect` (keeping the blocks the old and new windows share; the crops outside the new one are
    /// dropped). Its window is [`window_around`] `rect`: the whole image (`w × h` texels) where that grid fits the
    /// canvas budget.
    fn canvas(&mut self, key: JacobianKey, per_texel: usize, rect: TexelRect, (w, h): (usize, usize)) -> usize {
        let s = FFT_BLOCK_TEXELS;
        let found = self.canvases.iter().position(|c| c.key == key);
        if let Some(i) =
            found.filter(|&i| self.canvases[i].per_texel == per_texel && holds(&self.canvases[i].window, &rect))
        {
            self.canvases[i].last_used = self.clock;
            return i;
        }
        let window = window_around(rect, per_texel, (w, h), self.canvas_bytes.unwrap_or(CANVAS_BYTES));
        let mut canvas = Canvas::new(key, per_texel, window, self.clock);
        if let Some(old) = found.map(|i| self.canvases.swap_remove(i)) {
            self.view = None;
            // the blocks both windows hold, carried over (a copy, as rare as a view leaving its window)
            if old.per_texel == per_texel {
                let bw = (old.window[2] - old.window[0]) / s;
                let kept: Vec<[usize; 2]> = (old.present.iter().enumerate().filter(|&(_, &p)| p))
                    .map(|(i, _)| [old.window[0] + i % bw * s, old.window[1] + i / bw * s])
                    .filter(|&at| canvas.block(at).is_some())
                    .collect();
                // a plan's canvas holds no values: its blocks are marked alone
                match kept.iter().map(|&at| old.read(at)).collect::<Option<Vec<_>>>() {
                    Some(values) => canvas.write(&kept, &values),
                    None => kept.iter().for_each(|&at| canvas.mark(at)),
                }
            }
            self.entries.retain(|e| e.key != key || (old.per_texel == per_texel && holds(&window, &e.rect)));
        }
        self.canvases.push(canvas);
        self.canvases.len() - 1
    }

    /// The first texels of the blocks of canvas `c` that cover `rect` and are not yet prefiltered.
    fn mark_blocks(&self, c: usize, rect: TexelRect) -> Vec<[usize; 2]> {
        let s = FFT_BLOCK_TEXELS;
        let canvas = &self.canvases[c];
        let mut missing = Vec::new();
        for by in (rect[1] / s..rect[3].div_ceil(s)).map(|k| k * s) {
            for bx in (rect[0] / s..rect[2].div_ceil(s)).map(|k| k * s) {
                let i = canvas.block([bx, by]).expect("the window holds the crop");
                if !canvas.present[i] {
                    missing.push([bx, by]);
                }
            }
        }
        missing
    }

    /// Drops the least recently used canvases (and their crops) while the pages their blocks were written on
    /// take more than [`BLOCK_CACHE_BYTES`], never the one in use.
    fn evict_canvases(&mut self) {
        let mut total: usize = self.canvases.iter().map(Canvas::bytes).sum();
        while total > BLOCK_CACHE_BYTES {
            let (i, oldest) = least_recent(&self.canvases, |c| c.last_used);
            if oldest == self.clock {
                break;
            }
            let old = self.canvases.swap_remove(i);
            total -= old.bytes();
            self.entries.retain(|e| e.key != old.key);
        }
    }

    /// Prefilters the blocks `missing` (from [`PrefilterCache::mark_blocks`]) of canvas `c` by `filter` (the
    /// Jacobian of its key), read from `source`'s whole image (its edges replicated), and writes them into it.
    ///
    /// A texel's value must not depend on the crop it is read in (a frame's result depends on its own camera
    /// alone, whichever crop the cache holds): every texel is computed in its block of [`FFT_BLOCK_TEXELS`],
    /// aligned to the image's own grid and read with the kernel's reach around it, at the same transform size
    /// (one transform of the whole crop would round differently for crops of other sizes), and the direct
    /// method computes it from its own neighbourhood.
    fn build(&mut self, source: &SkyPlane, filter: &TextureFilter, c: usize, missing: &[[usize; 2]]) {
        let key = self.canvases[c].key;
        let r = filter.radius();
        let m = filter.per_texel;
        let s = FFT_BLOCK_TEXELS;
        let bs = s * m;
        let image = source.image();
        // the crop last handed out shares the grid: dropped, so that it is written in place
        self.view = None;
        if filter_method(filter) == ConvolutionMethod::Fft {
            let spectra = match self.spectra.take() {
                Some(sp) if sp.key == key && sp.radius == r && sp.per_texel == m => sp,
                _ => PhaseSpectra::new(key, filter),
            };
            // each block's phases written straight into the grid, the blocks side by side
            let finite = self.canvases[c].fill(missing, |at, rows| spectra.block_into(image, at, rows));
            self.spectra = Some(spectra);
            // a blur of finite values is finite; checked once per block, not again for every crop read from it
            assert!(finite, "a blur of finite values is finite");
            return;
        }
        let mut fresh: Vec<Vec<f32>> = missing.iter().map(|_| vec![0.0f32; bs * bs]).collect();
        // phase by phase, so that the convolver prepares each kernel once
        for (phase, kernel) in filter.phases.iter().enumerate() {
            let (a, b) = (phase % m, phase / m);
            for (&[bx, by], values) in missing.iter().zip(&mut fresh) {
                let region =
                    image.region_clamped(bx as isize - r as isize, by as isize - r as isize, s + 2 * r, s + 2 * r);
                let mut frame = Frame::from_pixels(s + 2 * r, s + 2 * r, region);
                self.convolver.apply(kernel, &mut frame, ConvolutionMethod::Direct);
                let pw = frame.width();
                for y in 0..s {
                    let from = &frame.pixels()[(y + r) * pw + r..(y + r) * pw + r + s];
                    let row = &mut values[(y * m + b) * bs..(y * m + b + 1) * bs];
                    for (x, &v) in from.iter().enumerate() {
                        row[x * m + a] = v;
                    }
                }
            }
        }
        // a blur of finite values is finite; checked once per block, not again for every crop read from it
        assert!(fresh.iter().all(|values| values.iter().all(|v| v.is_finite())), "a blur of finite values is finite");
        self.canvases[c].write(missing, &fresh);
    }
}

/// The blocks of a canvas for `rect` (texels) of a `w × h` image at `per_texel` nodes a texel: the whole image
/// where its grid takes at most `limit` bytes, else the box of blocks centred on `rect`'s, grown by as many
/// blocks on every side as keep it within `limit` (never smaller than `rect`'s blocks) and shifted inside the
/// image, so that a view panning across a large image moves its window (copying the blocks the two share) only
/// when it has crossed most of it.
fn window_around(rect: TexelRect, per_texel: usize, (w, h): (usize, usize), limit: usize) -> TexelRect {
    let s = FFT_BLOCK_TEXELS;
    let block_bytes = (s * per_texel).pow(2) * size_of::<f32>();
    let (wb, hb) = (w.div_ceil(s), h.div_ceil(s));
    let (rx, ry) = (rect[0] / s, rect[1] / s);
    let (rw, rh) = (rect[2].div_ceil(s) - rx, rect[3].div_ceil(s) - ry);
    let most = (limit / block_bytes).max(rw * rh);
    let size = |k: usize| ((rw + 2 * k).min(wb), (rh + 2 * k).min(hb));
    let mut k = 0;
    while size(k) != (wb, hb) && size(k + 1).0 * size(k + 1).1 <= most {
        k += 1;
    }
    let (nx, ny) = size(k);
    if (nx, ny) == (wb, hb) && nx * ny <= most {
        return [0, 0, wb * s, hb * s];
    }
    let x0 = rx.saturating_sub((nx - rw) / 2).min(wb - nx);
    let y0 = ry.saturating_sub((ny - rh) / 2).min(hb - ny);
    [x0 * s, y0 * s, (x0 + nx) * s, (y0 + ny) * s]
}

/// The index of the least recently used of `items` (not empty), and when it was last used.
fn least_recent<T>(items: &[T], last_used: impl Fn(&T) -> u64) -> (usize, u64) {
    items.iter().map(last_used).enumerate().min_by_key(|&(_, t)| t).expect("a cache with an entry to drop")
}

/// How a texture filter is applied: directly while its widest kernel has up to 11 × 11 taps, by FFT above.
fn filter_method(filter: &TextureFilter) -> ConvolutionMethod {
    let side = 2 * filter.radius() + 1;
    if side * side <= 121 { ConvolutionMethod::Direct } else { ConvolutionMethod::Fft }
}

/// Multiply–adds per texel of prefiltering a block with `filter` (every phase), an FFT counted as
/// `5·log₂(size)` per point.
fn build_taps(filter: &TextureFilter) -> f64 {
    let r = filter.radius();
    match filter_method(filter) {
        ConvolutionMethod::Fft => {
            let n = PhaseSpectra::side(r) as f64;
            // a forward transform of the block and an inverse one per pair of phases
            let transforms = 1 + filter.phases.len().div_ceil(2);
            transforms as f64 * 2.0 * 5.0 * n.log2() * n * n / (FFT_BLOCK_TEXELS * FFT_BLOCK_TEXELS) as f64
        }
        _ => filter.phases.iter().map(|k| ((2 * k.radius() + 1).pow(2)) as f64).sum(),
    }
}

/// The transforms of a [`TextureFilter`]'s phase kernels on the grid of one block and its reach
/// (`FFT_BLOCK_TEXELS + 2R` padded to a fast size), two phases to a transform: the kernel of phase `a` as the
/// real part and of phase `b` as the imaginary part, so that one inverse transform of the block's spectrum times
/// it gives both phases (the block is real) in its real and imaginary parts.
///
/// A 2D transform is the rows' transforms, a transpose, and the rows' transforms again; spectra stay
/// transposed, and the inverse undoes the steps in the same order, so two transposes serve a block.
struct PhaseSpectra {
    key: JacobianKey,
    radius: usize,
    per_texel: usize,
    side: usize,
    forward: Arc<dyn rustfft::Fft<f32>>,
    inverse: Arc<dyn rustfft::Fft<f32>>,
    /// Per pair of phases `(2p, 2p + 1)`, transposed.
    pairs: Vec<Vec<Complex<f32>>>,
}

impl std::fmt::Debug for PhaseSpectra {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PhaseSpectra({} pairs, side {})", self.pairs.len(), self.side)
    }
}

impl PhaseSpectra {
    /// The transform size for a block read with reach `radius`: no output a block keeps wraps around.
    fn side(radius: usize) -> usize {
        fast_len(FFT_BLOCK_TEXELS + 2 * radius)
    }

    fn new(key: JacobianKey, filter: &TextureFilter) -> Self {
        let radius = filter.radius();
        let side = Self::side(radius);
        let mut planner = rustfft::FftPlanner::new();
        let (forward, inverse) = (planner.plan_fft_forward(side), planner.plan_fft_inverse(side));
        let mut this = Self { key, radius, per_texel: filter.per_texel, side, forward, inverse, pairs: Vec::new() };
        // each kernel mirrored about the grid's origin, so that the product of transforms gives the correlation
        // `Σ_d K[d]·T[n + d]` (the convolution's convention in [`Convolver`](super::psf::Convolver))
        let n = side as isize;
        this.pairs = filter
            .phases
            .chunks(2)
            .map(|pair| {
                let mut grid = vec![Complex::new(0.0f32, 0.0); side * side];
                for (part, kernel) in pair.iter().enumerate() {
                    let rk = kernel.radius() as isize;
                    let width = 2 * rk + 1;
                    for (i, &v) in kernel.values().iter().enumerate() {
                        let (dx, dy) = (i as isize % width - rk, i as isize / width - rk);
                        let cell = &mut grid[((-dy).rem_euclid(n) * n + (-dx).rem_euclid(n)) as usize];
                        if part == 0 {
                            cell.re = v;
                        } else {
                            cell.im = v;
                        }
                    }
                }
                this.transform(&mut grid, true, &mut Vec::new(), 0..side);
                grid
            })
            .collect();
        this
    }

    /// In place, `side²` values: forward (rows, transpose, rows: the result transposed) or inverse (the
    /// same steps undoing a forward one); `scratch` is grown as the transforms need. The last pass transforms
    /// the rows `last` alone (the others are left half done): each row is transformed on its own, so those rows
    /// hold, bit for bit, what the whole transform gives them.
    fn transform(&self, grid: &mut [Complex<f32>], forward: bool, scratch: &mut Vec<Complex<f32>>, last: Range<usize>) {
        let fft = if forward { &self.forward } else { &self.inverse };
        let need = fft.get_inplace_scratch_len();
        if scratch.len() < need {
            scratch.resize(need, Complex::new(0.0, 0.0));
        }
        let n = self.side;
        fft.process_with_scratch(grid, &mut scratch[..need]);
        transpose_square(grid, n);
        fft.process_with_scratch(&mut grid[last.start * n..last.end * n], &mut scratch[..need]);
    }

    /// The block of `image` whose first texel is `at`, prefiltered: every phase on the fine grid, row-major (as a
    /// [`Canvas`] holds it).
    #[cfg(test)]
    fn block(&self, image: &SkyImage, at: [usize; 2]) -> Vec<f32> {
        let bs = FFT_BLOCK_TEXELS * self.per_texel;
        let mut values = vec![0.0f32; bs * bs];
        let grid = SharedGrid::new(&mut values);
        // SAFETY: the only rows of the grid handed out
        self.block_into(image, at, &mut unsafe { grid.block(0, bs, bs) });
        values
    }

    /// The block of `image` whose first texel is `at`, prefiltered (every phase on the fine grid, as a [`Canvas`]
    /// holds it), written into `rows`; whether every value written is finite. Of each inverse transform's last
    /// pass only the rows the block keeps are made.
    fn block_into(&self, image: &SkyImage, [bx, by]: [usize; 2], rows: &mut BlockRows<'_>) -> bool {
        let (n, r, m, s) = (self.side, self.radius, self.per_texel, FFT_BLOCK_TEXELS);
        let read = s + 2 * r;
        let region = image.region_clamped(bx as isize - r as isize, by as isize - r as isize, read, read);
        let mut spectrum = vec![Complex::new(0.0f32, 0.0); n * n];
        for (row, values) in spectrum.chunks_exact_mut(n).zip(region.chunks_exact(read)) {
            for (c, &v) in row.iter_mut().zip(values) {
                c.re = v;
            }
        }
        let mut scratch = Vec::new();
        self.transform(&mut spectrum, true, &mut scratch, 0..n);
        let scale = 1.0 / (n * n) as f32;
        let mut product = vec![Complex::new(0.0f32, 0.0); n * n];
        let mut finite = true;
        for (p, kernel) in self.pairs.iter().enumerate() {
            for ((o, &a), &k) in product.iter_mut().zip(&spectrum).zip(kernel) {
                *o = a * k;
            }
            self.transform(&mut product, false, &mut scratch, r..r + s);
            for (part, phase) in [2 * p, 2 * p + 1].into_iter().enumerate() {
                if phase >= m * m {
                    break;
                }
                let (a, b) = (phase % m, phase / m);
                for y in 0..s {
                    let from = &product[(y + r) * n + r..(y + r) * n + r + s];
                    let row = rows.row(y * m + b);
                    for (x, c) in from.iter().enumerate() {
                        let v = scale * if part == 0 { c.re } else { c.im };
                        finite &= v.is_finite();
                        row[x * m + a] = v;
                    }
                }
            }
        }
        finite
    }
}

/// A grid, borrowed for `'g`, whose blocks several tasks write at once, each its own ([`Canvas::fill`]).
struct SharedGrid<'g> {
    base: *mut f32,
    len: usize,
    _grid: PhantomData<&'g mut [f32]>,
}

// SAFETY: the grid is borrowed mutably for as long as this lives, and its blocks' rows, the only way to it, are
// handed out by `SharedGrid::block`, whose callers promise that no two alive at once share a value
unsafe impl Sync for SharedGrid<'_> {}

impl<'g> SharedGrid<'g> {
    fn new(grid: &'g mut [f32]) -> Self {
        Self { base: grid.as_mut_ptr(), len: grid.len(), _grid: PhantomData }
    }

    /// The rows of one block: `bs` values a row, rows `stride` apart from `first`.
    ///
    /// # Safety
    /// No value of these rows may be one of another block's rows handed out and alive at the same time.
    unsafe fn block(&self, first: usize, stride: usize, bs: usize) -> BlockRows<'_> {
        BlockRows { grid: self, first, stride, bs }
    }
}

/// One block's rows in a [`SharedGrid`].
struct BlockRows<'a> {
    grid: &'a SharedGrid<'a>,
    first: usize,
    stride: usize,
    bs: usize,
}

impl BlockRows<'_> {
    /// The block's row `yy` (`yy < bs`).
    fn row(&mut self, yy: usize) -> &mut [f32] {
        assert!(yy < self.bs, "a row of the block");
        let start = self.first + yy * self.stride;
        assert!(start + self.bs <= self.grid.len, "the block inside the grid");
        // SAFETY: inside the grid (checked above), which is borrowed mutably for as long as `self.grid` lives; no
        // other block's rows handed out share a value with these (`SharedGrid::block`), and the slice borrows
        // `self` mutably, so this block's rows are not handed out twice at once
        unsafe { std::slice::from_raw_parts_mut(self.grid.base.add(start), self.bs) }
    }
}

/// Transposes a `side × side` row-major grid in place, by tiles.
fn transpose_square(grid: &mut [Complex<f32>], side: usize) {
    const TILE: usize = 16;
    for ty in (0..side).step_by(TILE) {
        for tx in (ty..side).step_by(TILE) {
            for y in ty..(ty + TILE).min(side) {
                let x0 = if tx == ty { y + 1 } else { tx };
                for x in x0..(tx + TILE).min(side) {
                    grid.swap(y * side + x, x * side + y);
                }
            }
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

    /// A field with detail down to the texel: white noise (a fixed xorshift) smoothed by two passes of a 3-texel
    /// box along each axis, 256 texels a side, placed as the paper's Fig. 8 plane.
    fn noise_plane() -> SkyPlane {
        let n = 256;
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut px: Vec<f64> = (0..n * n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        for _ in 0..2 {
            let at = |v: &[f64], x: usize, y: usize| v[y.min(n - 1) * n + x.min(n - 1)];
            let blurred: Vec<f64> = (0..n * n)
                .map(|i| {
                    let (x, y) = (i % n, i / n);
                    let mut sum = 0.0;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            sum += at(&px, (x + dx).saturating_sub(1), (y + dy).saturating_sub(1));
                        }
                    }
                    sum / 9.0
                })
                .collect();
            px = blurred;
        }
        let image = SkyImage::from_f32(n, n, px.iter().map(|&v| (20.0 + 10.0 * v) as f32).collect()).unwrap();
        SkyPlane::new(image, &crate::imaging::sky_plane::SkyPlacement::paper_fig8(), glam::DVec3::new(0.0, 0.0, 8000.0))
            .unwrap()
    }

    /// The crop [`PrefilterCache::plane`] hands out, and its texels.
    fn crop(
        cache: &mut PrefilterCache,
        plane: &SkyPlane,
        p: &Psf,
        key: JacobianKey,
        settings: PrefilterSettings,
        need: [f64; 4],
    ) -> (TexelRect, SkyPlane) {
        let crop = cache.plane(plane, p, key, settings, need).expect("a texture").clone();
        let entry = cache.entries.iter().max_by_key(|e| e.last_used).expect("the crop's entry");
        (entry.rect, crop)
    }

    /// Settings whose spacing allows a grid of `m` nodes a texel for `key` (at its smallest stretch).
    fn settings_for(key: JacobianKey, tol: f64, m: usize, grid_error: f64) -> PrefilterSettings {
        let spacing_px = 1.0 / (m as f64 * smallest_stretch(key.jacobian(tol)));
        PrefilterSettings { tolerance: tol, spacing_px, grid_error }
    }

    /// The texture of `plane` prefiltered for `key` on a grid `m` nodes a texel, read at image coordinates `u`.
    fn texture_reads(plane: &SkyPlane, p: &Psf, key: JacobianKey, tol: f64, m: usize, us: &[DVec2]) -> Vec<f64> {
        let settings = settings_for(key, tol, m, 0.0);
        let mut cache = PrefilterCache::new();
        let (rect, crop) = crop(&mut cache, plane, p, key, settings, [40.0, 40.0, 216.0, 216.0]);
        let origin = DVec2::new(rect[0] as f64, rect[1] as f64);
        assert_eq!(crop.image().width(), (rect[2] - rect[0]) * m, "{m} nodes a texel");
        // fine node m·q + a has its centre at texel coordinate q + (a + ½)/m: a texel coordinate u is m·u on the
        // fine grid
        us.iter().map(|&u| f64::from(crop.value_at((u - origin) * m as f64))).collect()
    }

    #[test]
    fn the_grid_error_estimate_follows_the_error_of_coarser_grids() {
        let plane = noise_plane();
        let p = psf();
        let tol = 0.01;
        let spectra = BlockSpectra::new(plane.image());
        // reads at scattered points against a grid of 8 nodes a texel
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let us: Vec<DVec2> = (0..4000).map(|_| DVec2::new(48.0 + 160.0 * next(), 48.0 + 160.0 * next())).collect();
        // texels 2 px wide (the image magnified twice), turned; and a sheared view, its texels 0.45 and 0.9 of a
        // pixel along the axes (J and its transpose differ)
        let views = [DMat2::from_angle(0.3) * 0.5, DMat2::from_cols_array(&[0.45, 0.1, 0.3, 0.9])];
        for (v, j) in views.into_iter().enumerate() {
            let key = JacobianKey::new(j, tol).unwrap();
            let started = std::time::Instant::now();
            let estimate = spectra.grid_errors(&p, key.jacobian(tol), 4);
            let took = started.elapsed();
            let fine = texture_reads(&plane, &p, key, tol, 8, &us);
            for m in [1, 2, 4] {
                let reads = texture_reads(&plane, &p, key, tol, m, &us);
                let rms = (reads.iter().zip(&fine).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / us.len() as f64).sqrt();
                let ratio = estimate[m - 1] / rms;
                eprintln!(
                    "view {v}, {m} nodes a texel: measured {rms:.5}, estimated {:.5} ({ratio:.2}x; estimate {took:?})",
                    estimate[m - 1]
                );
                assert!((0.8..2.0).contains(&ratio), "view {v}, {m} nodes a texel: {ratio}");
            }
            // a finer grid errs less
            assert!(estimate.windows(2).all(|w| w[1] < w[0]), "{estimate:?}");
        }
    }

    #[test]
    fn a_new_grid_budget_makes_new_textures() {
        // the same cache asked for the same key with another budget: the grid of a fresh cache, never the one
        // kept from before
        let (plane, p, tol) = (noise_plane(), psf(), 0.01);
        let key = JacobianKey::new(DMat2::IDENTITY * 0.5, tol).unwrap();
        let estimate = BlockSpectra::new(plane.image()).grid_errors(&p, key.jacobian(tol), 4);
        let mut cache = PrefilterCache::new();
        let need = [60.0, 60.0, 190.0, 190.0];
        let per_texel = |cache: &mut PrefilterCache, grid_error: f64| {
            let settings = settings_for(key, tol, 4, grid_error);
            let (rect, crop) = crop(cache, &plane, &p, key, settings, need);
            crop.image().width() / (rect[2] - rect[0])
        };
        assert_eq!(per_texel(&mut cache, 0.0), 4);
        let budget = 0.5 * (estimate[0] + estimate[1]);
        assert_eq!(per_texel(&mut cache, budget), 2);
        assert_eq!(per_texel(&mut PrefilterCache::new(), budget), 2);
        assert_eq!(per_texel(&mut cache, 0.0), 4);
    }

    #[test]
    fn a_run_coming_back_to_its_keys_finds_their_blocks() {
        // seven keys, each needing 28 blocks on a grid of 3 × 3 nodes a texel (110 MiB, about sense_and_avoid's
        // working set), asked for in turn twice over, as `irsim bench` runs a scenario again: the second round
        // prefilters nothing
        let (p, tol) = (psf(), 0.05);
        let (w, h) = (7 * FFT_BLOCK_TEXELS, 4 * FFT_BLOCK_TEXELS);
        let image = SkyImage::from_f32(w, h, vec![20.0; w * h]).unwrap();
        let placement = crate::imaging::sky_plane::SkyPlacement::paper_fig8();
        let plane = SkyPlane::new(image, &placement, glam::DVec3::new(0.0, 0.0, 8000.0)).unwrap();
        let keys: Vec<JacobianKey> =
            (0..7).map(|i| JacobianKey::new(DMat2::IDENTITY * (0.5 * 1.05f64.powi(i)), tol).unwrap()).collect();
        let mut cache = PrefilterCache::new();
        let need = [0.0, 0.0, w as f64, h as f64];
        // one spacing for every key (a cache is for one set of settings): 3 nodes a texel at each of these scales
        let settings = PrefilterSettings { tolerance: tol, spacing_px: 0.7, grid_error: 0.0 };
        let round = |cache: &mut PrefilterCache| {
            for &key in &keys {
                assert_eq!(finest_per_texel(key.jacobian(tol), settings.spacing_px), Some(3));
                assert!(cache.plan(&plane, &p, key, settings, need), "a texture");
            }
            cache.work()
        };
        let first = round(&mut cache);
        assert_eq!(cache.canvases.iter().map(|c| c.present.iter().filter(|&&p| p).count()).sum::<usize>(), 7 * 28);
        let bytes: usize = cache.canvases.iter().map(Canvas::bytes).sum();
        assert!(bytes > 64 << 20, "{bytes} bytes of blocks: more than the budget these were made again under");
        assert_eq!(round(&mut cache), first, "a block was prefiltered again");
    }

    #[test]
    fn canvases_are_dropped_by_their_bytes_oldest_first() {
        // 4000 keys' canvases of one block of one node a texel (64 KiB each, 250 MiB) made first, then one of
        // 100 blocks of 3 × 3 nodes (576 KiB each) in use: the oldest small ones go, with their crops, until the
        // pages fit the budget; the one in use never does
        let key = |i: usize| JacobianKey { scale_step: i as i32, entries: [1, 0, 0, 1] };
        let s = FFT_BLOCK_TEXELS;
        let mut cache = PrefilterCache::new();
        for i in 0..4000 {
            let mut canvas = Canvas::new(key(i), 1, [0, 0, s, s], i as u64);
            canvas.mark([0, 0]);
            assert_eq!(canvas.bytes(), 64 << 10);
            cache.canvases.push(canvas);
            cache.entries.push(Entry { key: key(i), rect: [0, 0, s, s], last_used: i as u64 });
        }
        cache.clock = 5000;
        let mut in_use = Canvas::new(key(4000), 3, [0, 0, 100 * s, s], 5000);
        for b in 0..100 {
            in_use.mark([b * s, 0]);
        }
        assert_eq!(in_use.bytes(), 100 * (576 << 10));
        cache.canvases.push(in_use);
        cache.evict_canvases();
        let total: usize = cache.canvases.iter().map(Canvas::bytes).sum();
        assert!(total <= BLOCK_CACHE_BYTES && total + (64 << 10) > BLOCK_CACHE_BYTES, "{total} bytes kept");
        assert!(cache.canvases.iter().any(|c| c.key == key(4000)), "the canvas in use");
        let small: Vec<u64> = cache.canvases.iter().filter(|c| c.per_texel == 1).map(|c| c.last_used).collect();
        let oldest_kept = *small.iter().min().unwrap();
        assert_eq!(oldest_kept, 4000 - small.len() as u64, "the oldest went first");
        // a dropped canvas's crops went with it
        assert!(cache.entries.iter().all(|e| cache.canvases.iter().any(|c| c.key == e.key)));
        assert_eq!(cache.entries.len(), small.len());
        // a block of one node a texel in a grid 32 blocks (16 KiB) a row: its 128 rows of 512 bytes are on a page
        // each, and count so
        let mut wide = Canvas::new(key(0), 1, [0, 0, 32 * s, 2 * s], 0);
        wide.mark([5 * s, s]);
        assert_eq!(wide.bytes(), 128 * PAGE_BYTES);
        // its neighbour along the row shares them
        wide.mark([6 * s, s]);
        assert_eq!(wide.bytes(), 128 * PAGE_BYTES);
    }

    #[test]
    fn a_window_is_the_whole_image_where_it_fits_else_the_most_blocks_around_the_crop() {
        let s = FFT_BLOCK_TEXELS;
        let block = s * s * size_of::<f32>();
        // 40 × 20 blocks: whole where they fit
        let (w, h) = (40 * s - 7, 20 * s);
        assert_eq!(window_around([s, s, 2 * s, 2 * s], 1, (w, h), 800 * block), [0, 0, 40 * s, 20 * s]);
        // 100 blocks: a crop of 2 × 2 grown by 4 on every side (10 × 10), centred
        let rect = [20 * s + 5, 10 * s, 22 * s - 3, 12 * s];
        assert_eq!(window_around(rect, 1, (w, h), 100 * block), [16 * s, 6 * s, 26 * s, 16 * s]);
        // near the corner: shifted inside the image, still 10 × 10
        assert_eq!(window_around([s, 0, 3 * s, 2 * s], 1, (w, h), 100 * block), [0, 0, 10 * s, 10 * s]);
        // 3 × 3 nodes a texel: a block takes 9 blocks' bytes, so 100 blocks' bytes hold 11 of them (a 3 × 3 box)
        assert_eq!(window_around(rect, 3, (w, h), 100 * block), [20 * s, 10 * s, 22 * s, 12 * s]);
        assert_eq!(window_around(rect, 3, (w, h), 9 * 16 * block), [19 * s, 9 * s, 23 * s, 13 * s]);
        // never smaller than the crop's blocks
        assert_eq!(window_around(rect, 1, (w, h), 0), [20 * s, 10 * s, 22 * s, 12 * s]);
        // a strip of an image 3 blocks tall grows along the other axis
        let strip = window_around([20 * s, 0, 22 * s, 3 * s], 1, (40 * s, 3 * s), 30 * block);
        assert_eq!(strip, [16 * s, 0, 26 * s, 3 * s]);
    }

    /// A `w × h` sky image on the paper's plane: a ripple of frequencies `f` (radians a texel along x and y) and a
    /// hash.
    fn ripple_plane(w: usize, h: usize, f: [f32; 2]) -> SkyPlane {
        let values = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let hash = (i as u32).wrapping_mul(2_654_435_761) >> 24;
                20.0 + (f[0] * x).sin() * (f[1] * y).cos() + hash as f32 / 256.0
            })
            .collect();
        let image = SkyImage::from_f32(w, h, values).unwrap();
        let placement = crate::imaging::sky_plane::SkyPlacement::paper_fig8();
        SkyPlane::new(image, &placement, glam::DVec3::new(0.0, 0.0, 8000.0)).unwrap()
    }

    #[test]
    fn blocks_written_in_place_are_each_block_s_own_transform_bit_for_bit() {
        // the transform route writes each block's phases straight into the key's grid, the blocks side by side:
        // every block built, copied back out of the grid, is what the block's transforms give it alone
        let (p, tol) = (psf(), 0.01);
        let (w, h) = (6 * FFT_BLOCK_TEXELS, 3 * FFT_BLOCK_TEXELS);
        let plane = ripple_plane(w, h, [0.07, 0.05]);
        // texels larger than pixels: kernels wide enough for the transform route
        let key = JacobianKey::new(DMat2::IDENTITY * 1.2, tol).unwrap();
        let settings = settings_for(key, tol, 3, 0.0);
        let mut cache = PrefilterCache::new();
        // two crops: blocks built together, then more beside them in a grid that already holds some
        let mut built = Vec::new();
        for need in [[150.0, 100.0, 400.0, 250.0], [300.0, 40.0, 600.0, 300.0]] {
            crop(&mut cache, &plane, &p, key, settings, need);
            built.push(cache.canvases[0].present.iter().filter(|&&b| b).count());
        }
        assert!(built[0] >= 8 && built[1] > built[0], "blocks built: {built:?}");
        let canvas = &cache.canvases[0];
        assert_eq!(canvas.per_texel, 3);
        let spectra = cache.spectra.as_ref().expect("the transform route");
        let s = FFT_BLOCK_TEXELS;
        let blocks = (0..h / s).flat_map(|by| (0..w / s).map(move |bx| [bx * s, by * s]));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for at in blocks.filter(|&at| canvas.present[canvas.block(at).unwrap()]) {
            let want = spectra.block(plane.image(), at);
            assert_eq!(bits(&canvas.read(at).unwrap()), bits(&want), "block {at:?}");
        }
    }

    #[test]
    fn an_inverse_transform_s_kept_rows_are_the_whole_transform_s_bit_for_bit() {
        // a block keeps rows r..r + s of each inverse transform, and only those rows of its last pass are made
        let p = psf();
        let j = DMat2::from_cols_array(&[1.2, 0.1, -0.05, 0.5]);
        let filter = TextureFilter::with_spacing(&p, j, 0.75).unwrap();
        let spectra = PhaseSpectra::new(JacobianKey::new(j, 0.05).unwrap(), &filter);
        let (n, r, s) = (spectra.side, spectra.radius, FFT_BLOCK_TEXELS);
        assert!(n > s + r, "rows left out: side {n}, radius {r}");
        let grid: Vec<Complex<f32>> =
            (0..n * n).map(|i| Complex::new((i as f32 * 0.37).sin(), (i as f32 * 0.11).cos())).collect();
        let (mut whole, mut kept) = (grid.clone(), grid);
        spectra.transform(&mut whole, false, &mut Vec::new(), 0..n);
        spectra.transform(&mut kept, false, &mut Vec::new(), r..r + s);
        let bits = |v: &[Complex<f32>]| v.iter().map(|c| (c.re.to_bits(), c.im.to_bits())).collect::<Vec<_>>();
        assert_eq!(bits(&kept[r * n..(r + s) * n]), bits(&whole[r * n..(r + s) * n]));
    }

    #[test]
    fn crops_read_from_a_moving_window_are_those_of_the_whole_image() {
        // a view panning across the image, its crops read from a canvas of the whole image and from one whose
        // window (limited to two blocks of 3 × 3 nodes a texel, so the blocks around the crop) has to move
        // along: the same values; and a moved window keeps the blocks it shares, which are not prefiltered again
        let (p, tol) = (psf(), 0.01);
        // 8 × 2 blocks of texels: a ripple and a hash
        let (w, h) = (8 * FFT_BLOCK_TEXELS, 2 * FFT_BLOCK_TEXELS);
        let plane = ripple_plane(w, h, [0.05, 0.08]);
        let key = JacobianKey::new(DMat2::IDENTITY * 0.5, tol).unwrap();
        let settings = settings_for(key, tol, 3, 0.0);
        let mut whole = PrefilterCache::new();
        let block_bytes = (3 * FFT_BLOCK_TEXELS).pow(2) * size_of::<f32>();
        let mut windowed = PrefilterCache { canvas_bytes: Some(2 * block_bytes), ..Default::default() };
        let mut moves = 0;
        for step in 0..16 {
            let x = 4.0 + 60.0 * step as f64;
            let need = [x, 100.0 - 0.05 * x, x + 50.0, 140.0 - 0.05 * x];
            let (rect, a) = crop(&mut whole, &plane, &p, key, settings, need);
            let before = windowed.canvases.first().map(|c| c.window);
            let (rect_w, b) = crop(&mut windowed, &plane, &p, key, settings, need);
            assert_eq!(rect, rect_w);
            assert_eq!(a.image(), b.image(), "step {step}");
            assert_eq!(whole.canvases[0].window, [0, 0, w, h], "the whole image");
            let window = windowed.canvases[0].window;
            assert!(window[2] - window[0] < w, "a window: {window:?}");
            moves += usize::from(before.is_some_and(|w| w != window));
        }
        assert!(moves >= 2, "the window moved {moves} times");
        assert_eq!(whole.work(), windowed.work(), "a block prefiltered again");
    }

    #[test]
    fn a_smooth_image_gets_a_coarser_grid_than_a_detailed_one() {
        let (p, tol) = (psf(), 0.01);
        // texels 2 px wide, a spacing that allows up to 4 nodes a texel
        let key = JacobianKey::new(DMat2::IDENTITY * 0.5, tol).unwrap();
        let detailed = noise_plane();
        let n = 256;
        let smooth: Vec<f32> =
            (0..n * n).map(|i| (20.0 + (i % n) as f64 / 40.0 + ((i / n) as f64 / 30.0).sin()) as f32).collect();
        let smooth = SkyImage::from_f32(n, n, smooth).unwrap();
        let per_texel = |image: &SkyImage, grid_error: f64| {
            let mut cache = PrefilterCache::new();
            cache.clock += 1;
            let settings = settings_for(key, tol, 4, grid_error);
            cache.filter(image, &p, key, settings).expect("a filter").per_texel()
        };
        // no budget: the finest grid the spacing allows, whatever the image
        assert_eq!(per_texel(detailed.image(), 0.0), 4);
        assert_eq!(per_texel(&smooth, 0.0), 4);
        // a budget between the detailed image's estimates for 2 and 3 nodes a texel gives it 3, and the smooth
        // image 1
        let estimate = BlockSpectra::new(detailed.image()).grid_errors(&p, key.jacobian(tol), 4);
        let budget = 0.5 * (estimate[1] + estimate[2]);
        assert_eq!(per_texel(detailed.image(), budget), 3, "{estimate:?}");
        assert_eq!(per_texel(&smooth, budget), 1);
        // a budget under every estimate keeps the finest grid
        assert_eq!(per_texel(detailed.image(), 0.5 * estimate[3]), 4);
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

    /// The kernel as first written: the PSF sampled and splatted anew for each phase.
    fn texture_kernel_alone(psf: &Psf, j: DMat2, shift: DVec2) -> Option<Vec<f32>> {
        let reach_px = psf.radius_px() as f64 + 0.5;
        let reach_x = reach_px * (j.x_axis.x.abs() + j.y_axis.x.abs()) + shift.x.abs();
        let reach_y = reach_px * (j.x_axis.y.abs() + j.y_axis.y.abs()) + shift.y.abs();
        let radius = reach_x.max(reach_y).ceil() as usize + 1;
        if radius > MAX_TEXTURE_RADIUS {
            return None;
        }
        let side = 2 * radius + 1;
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
        values.iter_mut().for_each(|v| *v /= total);
        Some(Kernel::from_values_2d(radius, &values).values().to_vec())
    }

    #[test]
    fn the_phases_from_shared_samples_are_each_made_alone_bit_for_bit() {
        let p = psf();
        for (scale, angle, squash) in [(1.09, 0.1, 0.9), (0.4, -0.3, 1.0), (2.5, 0.7, 0.6), (0.23, 0.0, 1.0)] {
            let (s, c) = (f64::sin(angle), f64::cos(angle));
            let j = DMat2::from_cols_array(&[scale * c, scale * s, -scale * s * squash, scale * c * squash]);
            let filter = TextureFilter::new(&p, j).unwrap();
            let m = filter.per_texel();
            assert_eq!(filter.phases.len(), m * m);
            for (phase, kernel) in filter.phases.iter().enumerate() {
                let (a, b) = ((phase % m) as f64, (phase / m) as f64);
                let shift = DVec2::new((a + 0.5) / m as f64 - 0.5, (b + 0.5) / m as f64 - 0.5);
                let alone = texture_kernel_alone(&p, j, shift).unwrap();
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(kernel.values()), bits(&alone), "scale {scale}, phase {phase}");
            }
        }
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
    fn filters_are_kept_by_key_and_the_least_recently_used_dropped() {
        let p = psf();
        let tol = 0.05;
        let bits = |f: &TextureFilter| -> Vec<Vec<u32>> {
            f.phases.iter().map(|k| k.values().iter().map(|v| v.to_bits()).collect()).collect()
        };
        // more keys than are kept: 37 turns of the same magnified view at 7 scales, all distinct
        let keys: Vec<JacobianKey> = (0..FILTER_CACHE_ENTRIES + 3)
            .map(|i| {
                let j = DMat2::from_angle(0.15 * (i % 37) as f64) * (0.6 * 1.04f64.powi((i / 37) as i32));
                JacobianKey::new(j, tol).unwrap()
            })
            .collect();
        let distinct: std::collections::HashSet<_> = keys.iter().collect();
        assert_eq!(distinct.len(), keys.len());
        let mut cache = PrefilterCache::new();
        let img = SkyImage::from_finite(1, 1, vec![0.0]);
        let get = |cache: &mut PrefilterCache, key: JacobianKey| {
            cache.clock += 1;
            cache
                .filter(
                    &img,
                    &p,
                    key,
                    PrefilterSettings { tolerance: tol, spacing_px: TEXTURE_SPACING_PX, grid_error: 0.0 },
                )
                .expect("a filter")
        };
        let first = get(&mut cache, keys[0]);
        assert_eq!(bits(&first), bits(&TextureFilter::new(&p, keys[0].jacobian(tol)).unwrap()));
        for (n, &key) in keys.iter().enumerate().skip(1) {
            let f = get(&mut cache, key);
            // each key gets its own filter, the one made for it alone
            if n % 50 == 0 {
                assert_eq!(bits(&f), bits(&TextureFilter::new(&p, key.jacobian(tol)).unwrap()), "key {n}");
            }
            // the first key, asked for now and then, is kept
            if n % 10 == 0 {
                assert!(Arc::ptr_eq(&get(&mut cache, keys[0]), &first), "key 0 made again after key {n}");
            }
        }
        assert_eq!(cache.filters.len(), FILTER_CACHE_ENTRIES);
        let kept = |cache: &PrefilterCache, key: JacobianKey| cache.filters.iter().any(|f| f.key == key);
        // the first key, used recently, and the newest are kept; the least recently used went
        assert!(kept(&cache, keys[0]) && kept(&cache, keys[keys.len() - 1]));
        assert!(!kept(&cache, keys[1]) && !kept(&cache, keys[2]));
        // a key dropped is made again, the same
        let again = get(&mut cache, keys[1]);
        assert_eq!(bits(&again), bits(&TextureFilter::new(&p, keys[1].jacobian(tol)).unwrap()));
        // a kernel too wide is known as such without sampling the PSF on a grid as fine as the texels
        let wide = JacobianKey::new(DMat2::IDENTITY * 60.0, tol).unwrap();
        cache.clock += 1;
        assert!(
            cache
                .filter(
                    &img,
                    &p,
                    wide,
                    PrefilterSettings { tolerance: tol, spacing_px: TEXTURE_SPACING_PX, grid_error: 0.0 }
                )
                .is_none()
                && kept(&cache, wide)
        );
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

    #[test]
    fn paired_phase_transforms_give_each_phase_s_direct_convolution() {
        // a stretched, magnified view: 3 × 3 phases (an odd count, so one transform holds a phase alone) and
        // kernels wide enough for the transform method
        let p = psf();
        let j = DMat2::from_cols_array(&[1.2, 0.1, -0.05, 0.5]);
        let filter = TextureFilter::with_spacing(&p, j, 0.75).unwrap();
        let m = filter.per_texel;
        assert_eq!(m, 3);
        assert_eq!(filter_method(&filter), ConvolutionMethod::Fft);
        let (w, h) = (300, 200);
        let px: Vec<f32> =
            (0..w * h).map(|i| ((i % w) as f32 / 7.0).sin() * 3.0 + ((i / w) as f32 / 3.0).cos() + 20.0).collect();
        let image = SkyImage::from_f32(w, h, px).unwrap();
        let key = JacobianKey::new(j, 0.05).unwrap();
        let spectra = PhaseSpectra::new(key, &filter);
        let (s, r) = (FFT_BLOCK_TEXELS, filter.radius());
        // a block inside the image and one over its edge (read with the edge replicated)
        for at in [[128, 0], [256, 128]] {
            let got = spectra.block(&image, at);
            let mut worst = 0.0f32;
            for (phase, kernel) in filter.phases.iter().enumerate() {
                let region = image.region_clamped(
                    at[0] as isize - r as isize,
                    at[1] as isize - r as isize,
                    s + 2 * r,
                    s + 2 * r,
                );
                let mut frame = Frame::from_pixels(s + 2 * r, s + 2 * r, region);
                Convolver::new().apply(kernel, &mut frame, ConvolutionMethod::Direct);
                let (a, b) = (phase % m, phase / m);
                for y in 0..s {
                    for x in 0..s {
                        let want = frame.pixels()[(y + r) * (s + 2 * r) + x + r];
                        let have = got[(y * m + b) * s * m + x * m + a];
                        worst = worst.max((have - want).abs() / want.abs());
                    }
                }
            }
            assert!(worst < 1e-5, "block {at:?}: worst relative difference {worst}");
        }
    }
}
