//! The optics' point spread function: diffraction, the pixel's aperture, aberrations and line-of-sight motion.
//!
//! The PSF is built from its optical transfer function (OTF), the product of
//! - the diffraction-limited OTF of a circular pupil, `(2/π)(acos ν − ν√(1 − ν²))` with `ν = f·λN`, averaged
//!   over the band with the weights of the detector's spectral signal at a reference scene temperature
//!   (`B_λ` for thermal detectors, `B_λ·λ/(hc)` for photon detectors): the band-averaged Airy pattern;
//! - the pixel's photosensitive aperture, a square of side `√fill · pitch`: `sinc(a f_x)·sinc(a f_y)`;
//! - a Gaussian `exp(−2π²σ²f²)` for aberrations and defocus, and another for line-of-sight motion during the
//!   integration time (their variances add).
//!
//! One inverse FFT on a 32 px periodic grid gives the PSF; its tails beyond 16 px wrap around (at F/1 in the
//! LWIR they hold about 1 % of the energy). At F/1 in the LWIR with 12 µm pixels, a 3 % cut gives a 5 px
//! radius, a 1 % cut 11 px. The PSF is cut where the energy outside a square of radius `R`
//! falls below [`PsfSpec::energy_cutoff`] and renormalised to unit integral, so a target's flux is conserved.
//!
//! Three products are kept:
//! - a fine table of the PSF (1/32 px spacing, bilinear lookups) for targets, which are rendered analytically
//!   at their sub-pixel position ([`Psf::value`]), and on demand the same split into a core and a tail
//!   ([`SplitPsf`]), for targets of many quadrature nodes;
//! - a pixel kernel for a frame of point samples (the bilinear or nearest sky): the PSF convolved with the
//!   linear interpolant's tent, sampled at integer offsets — exact for the piecewise-linear interpolant of the
//!   samples ([`Psf::point_kernel`]);
//! - a pixel kernel for a frame of pixel-area averages (the supersampled sky), without the pixel aperture
//!   (already applied by the averaging) ([`Psf::area_kernel`]).
//!
//! A [`Kernel`] is applied to a frame separably (its symmetric eigen-decomposition, cut at the rank where the
//! largest error is below 1e-4 of its peak), directly in 2D, or by FFT; edges are replicated.

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use serde::{Deserialize, Serialize};

use super::fft2d::fft2;
use super::frame::Frame;
use crate::physics::ParamError;
use crate::physics::planck::{Band, Measure, spectral_radiance};
use crate::physics::simd::{rows_per_task, split_finely, widest};

/// Period of the grid the PSF is computed on, px.
const PERIOD_PX: usize = 32;
/// Fine-table samples per pixel.
const FINE_PER_PX: usize = 32;
/// Samples per pixel of the grid the pixel kernels are computed on.
const KERNEL_GRID_PER_PX: usize = 16;
/// Largest kernel radius, px.
pub const MAX_RADIUS_PX: usize = 12;
/// The energy cut-off that sets [`Psf::region_radius_px`] in the `standard` and `reference` qualities: the finest
/// the cut-off switch may be set to, so the region holds the PSF's whole reach at any setting of the switch.
pub const REGION_ENERGY_CUTOFF: f64 = 1e-6;
/// Wavelengths averaged over the band.
const BAND_SAMPLES: usize = 24;

/// What the PSF holds, and where it is cut.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PsfSpec {
    /// Diffraction by the circular pupil (band-averaged Airy pattern).
    pub diffraction: bool,
    /// The pixel's photosensitive aperture.
    pub pixel_aperture: bool,
    /// Standard deviation of a Gaussian for aberrations and defocus, px.
    pub aberration_sigma_px: f64,
    /// Standard deviation of a Gaussian for line-of-sight motion during the integration time, px.
    pub motion_sigma_px: f64,
    /// The kernel ends where the energy outside it falls below this fraction.
    pub energy_cutoff: f64,
    /// A target's region (where it is drawn and fused) reaches where the PSF's energy outside falls below this
    /// fraction ([`Psf::region_radius_px`]); never less than the kernel's reach.
    pub region_energy_cutoff: f64,
}

impl Default for PsfSpec {
    fn default() -> Self {
        Self {
            diffraction: true,
            pixel_aperture: true,
            aberration_sigma_px: 0.3,
            motion_sigma_px: 0.0,
            energy_cutoff: 0.03,
            region_energy_cutoff: REGION_ENERGY_CUTOFF,
        }
    }
}

impl PsfSpec {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        for (name, v) in [("aberration_sigma_px", self.aberration_sigma_px), ("motion_sigma_px", self.motion_sigma_px)]
        {
            if !(v.is_finite() && (0.0..=4.0).contains(&v)) {
                return Err(ParamError { name, value: v, range: "[0, 4] px".into() });
            }
        }
        let c = self.energy_cutoff;
        if !(c.is_finite() && (1e-6..=0.2).contains(&c)) {
            return Err(ParamError { name: "energy_cutoff", value: c, range: "[1e-6, 0.2]".into() });
        }
        let c = self.region_energy_cutoff;
        if !(c.is_finite() && (1e-6..=0.2).contains(&c)) {
            return Err(ParamError { name: "region_energy_cutoff", value: c, range: "[1e-6, 0.2]".into() });
        }
        Ok(())
    }
}

/// The optical set-up the PSF depends on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsfOptics {
    /// F-number `f/D`.
    pub f_number: f64,
    /// Pixel pitch, m.
    pub pixel_pitch_m: f64,
    /// Photosensitive fraction of the pixel's area.
    pub fill_factor: f64,
    /// Spectral band.
    pub band: Band,
    /// The detector's measure (weights of the band average).
    pub measure: Measure,
    /// Scene temperature of the band-average weights, K.
    pub reference_temp_k: f64,
}

/// How a pixel kernel is applied to a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ConvolutionMethod {
    /// Sum of rank-one separable passes (the kernel's eigen-decomposition).
    #[default]
    Separable,
    /// The full 2D kernel at every pixel.
    Direct,
    /// FFT of the edge-padded frame.
    Fft,
}

/// A square pixel kernel of radius `R`, summing to 1, with its separable decomposition.
#[derive(Debug, Clone)]
pub struct Kernel {
    radius: usize,
    /// Row-major `(2R+1)²` values.
    values: Vec<f32>,
    /// `K ≈ Σ λ vvᵀ`.
    terms: Vec<(f32, Vec<f32>)>,
    /// Per term, the vertical pass's taps `λ·v`.
    vertical: Vec<Vec<f32>>,
    /// `Σ K[d]·|d|²`, px².
    second_moment_px2: f64,
}

/// The PSF of a camera.
#[derive(Debug, Clone)]
pub struct Psf {
    radius: usize,
    /// The fine table over offsets `[−R−½, R+½]²` (per px², integrating to 1; [`FINE_PER_PX`] nodes per px)
    /// stored by sub-pixel phase ([`PhaseTable`]).
    fine: PhaseTable,
    /// The PSF split into a core and a tail ([`SplitPsf`]), made when first asked for, by the core's radius.
    splits: [std::sync::OnceLock<SplitPsf>; MAX_RADIUS_PX + 1],
    point: Kernel,
    area: Kernel,
    fwhm_px: f64,
    region_radius: usize,
    mtf: Mtf,
}

/// Samples of the radial part of the MTF (the Gaussian blurs times the band's diffraction) over `[0, cutoff]`.
const MTF_SAMPLES: usize = 1024;
/// Where the MTF is taken as 0 without diffraction, cycles/px: the pixel aperture's `sinc²` is below 1/(π·4)²
/// there (0.6 %). Without the aperture a Gaussian of a fine sample's σ alone still passes 0.73 there; the
/// estimates that read the MTF ([`crate::imaging::prefilter::BlockSpectra`]) also weigh by the bilinear tent of
/// the image's texels, which passes little that far out for texels of half a pixel and more.
const MTF_CUTOFF_NO_DIFFRACTION: f64 = 4.0;

/// The PSF's modulation transfer function: the magnitude of its OTF (the optics and the pixel aperture, no
/// interpolation), tabulated along the radius, for estimates of how much of an image's detail the PSF passes.
#[derive(Debug, Clone)]
pub struct Mtf {
    /// The radial part at `f = k·cutoff/(MTF_SAMPLES − 1)`.
    radial: Vec<f64>,
    /// The pixel aperture's factor along one axis, `sinc(aperture·f)`, at the same frequencies (all 1 without
    /// the aperture).
    aperture: Vec<f64>,
    /// Frequency past which the MTF is taken as 0, cycles/px.
    cutoff: f64,
}

impl Mtf {
    fn new(otf: &Otf) -> Self {
        let cutoff = otf
            .diffraction
            .iter()
            .map(|&(_, scale)| 1.0 / scale)
            .fold(f64::NAN, f64::max)
            .min(MTF_CUTOFF_NO_DIFFRACTION);
        let cutoff = if cutoff.is_finite() && cutoff > 0.0 { cutoff } else { MTF_CUTOFF_NO_DIFFRACTION };
        let step = cutoff / (MTF_SAMPLES - 1) as f64;
        let radial = (0..MTF_SAMPLES).map(|k| otf.radial(k as f64 * step, 0.0)).collect();
        let aperture = (0..MTF_SAMPLES)
            .map(|k| if otf.aperture_px > 0.0 { sinc(otf.aperture_px * k as f64 * step) } else { 1.0 })
            .collect();
        Self { radial, aperture, cutoff }
    }

    /// `table` at `u` samples from 0, linearly between its samples; `None` past the last.
    #[inline]
    fn lerp(table: &[f64], u: f64) -> Option<f64> {
        if !(u < (MTF_SAMPLES - 1) as f64) {
            return None;
        }
        let k = u as usize;
        Some(table[k] + (u - k as f64) * (table[k + 1] - table[k]))
    }

    /// Frequency past which the MTF is taken as 0, cycles/px.
    pub fn cutoff(&self) -> f64 {
        self.cutoff
    }

    /// `|OTF|` at `(fx, fy)`, cycles/px (each factor interpolated linearly between its samples).
    pub fn at(&self, fx: f64, fy: f64) -> f64 {
        let per = (MTF_SAMPLES - 1) as f64 / self.cutoff;
        let (Some(radial), Some(ax), Some(ay)) = (
            Self::lerp(&self.radial, (fx * fx + fy * fy).sqrt() * per),
            Self::lerp(&self.aperture, fx.abs() * per),
            Self::lerp(&self.aperture, fy.abs() * per),
        ) else {
            return 0.0;
        };
        (radial * ax * ay).abs()
    }
}

impl Psf {
    /// Builds the PSF.
    ///
    /// # Errors
    /// [`ParamError`] for an invalid spec or optics.
    pub fn new(spec: &PsfSpec, optics: &PsfOptics) -> Result<Self, ParamError> {
        spec.validate()?;
        let n_f = optics.f_number;
        if !(n_f.is_finite() && n_f > 0.0) {
            return Err(ParamError { name: "f_number", value: n_f, range: "(0, ∞)".into() });
        }
        let otf = Otf::new(spec, optics);
        // pixel kernels: the PSF times the tent of linear interpolation, with and without the pixel aperture
        // the radial part once, for the fine grid and the kernels' coarser one (a subset of its frequencies)
        let half = PERIOD_PX * FINE_PER_PX.max(KERNEL_GRID_PER_PX) / 2 + 1;
        let radial = otf.radial_quadrant(half);
        let point_grid = otf.spatial(KERNEL_GRID_PER_PX, true, true, &radial, half, None);
        let area_grid = otf.spatial(KERNEL_GRID_PER_PX, false, true, &radial, half, None);
        let radius = cut_radius(&point_grid, KERNEL_GRID_PER_PX, spec.energy_cutoff);
        let region_radius = cut_radius(&point_grid, KERNEL_GRID_PER_PX, spec.region_energy_cutoff).max(radius);
        let point = Kernel::from_grid(&point_grid, KERNEL_GRID_PER_PX, radius);
        let area = Kernel::from_grid(&area_grid, KERNEL_GRID_PER_PX, radius);
        // the fine table of the PSF itself, over [−R−½, R+½]², renormalised to unit integral
        let reach = radius * FINE_PER_PX + FINE_PER_PX / 2;
        let grid = otf.spatial(FINE_PER_PX, true, false, &radial, half, Some(reach));
        let n = PERIOD_PX * FINE_PER_PX;
        let half = reach as isize;
        let side = (2 * half + 1) as usize;
        let mut fine = Vec::with_capacity(side * side);
        // a raised-cosine taper over the last pixel and a half: a hard cut would shift the centroid of a blob
        // sampled at pixel centres by up to 0.01 px (the cut's edge falls unevenly between pixels)
        let outer = radius as f64 + 0.5;
        let inner = (outer - 1.5).max(0.0);
        // in fine samples², with a margin past `hypot`'s rounding: inside the first the taper is 1, outside the
        // second 0, whatever `hypot` gives (the squares are exact integers), so only the ring between needs it
        let per = FINE_PER_PX as f64;
        let (surely_in, surely_out) = ((inner * per).powi(2) * (1.0 - 1e-9), (outer * per).powi(2) * (1.0 + 1e-9));
        for dy in -half..=half {
            for dx in -half..=half {
                let (x, y) = (dx.rem_euclid(n as isize) as usize, dy.rem_euclid(n as isize) as usize);
                let r2 = (dx * dx + dy * dy) as f64;
                let r = if r2 < surely_in {
                    0.0
                } else if r2 > surely_out {
                    f64::INFINITY
                } else {
                    (dx as f64).hypot(dy as f64) / FINE_PER_PX as f64
                };
                fine.push((f64::from(grid[y * n + x]) * raised_cosine(r, inner, outer)) as f32);
            }
        }
        let h2 = 1.0 / (FINE_PER_PX * FINE_PER_PX) as f64;
        let total: f64 = fine.iter().map(|&v| f64::from(v) * h2).sum();
        for v in &mut fine {
            *v = (f64::from(*v) / total) as f32;
        }
        let fwhm_px = fwhm(&fine, side, FINE_PER_PX);
        let fine = PhaseTable::new(&fine, side, radius);
        let mtf = Mtf::new(&otf);
        let splits = std::array::from_fn(|_| std::sync::OnceLock::new());
        Ok(Self { radius, fine, splits, point, area, fwhm_px, region_radius, mtf })
    }

    /// The modulation transfer function of the PSF the fine table holds (optics and pixel aperture).
    pub fn mtf(&self) -> &Mtf {
        &self.mtf
    }

    /// Kernel radius `R`, px: the PSF is taken as 0 beyond `R + ½` px on either axis.
    pub fn radius_px(&self) -> usize {
        self.radius
    }

    /// Radius of a target's region, px: the PSF's reach at [`PsfSpec::region_energy_cutoff`] (default
    /// [`REGION_ENERGY_CUTOFF`]), whatever the kernel's cut-off. The region is where Poisson fusion solves, and
    /// with the paper's guidance the solution inside it depends on its size (the sky's curvature there is
    /// replaced by the harmonic fill of its border), so it has its own switch: a coarser kernel cut-off changes
    /// only the target's far tail, a smaller region changes the fused sky around the target.
    pub fn region_radius_px(&self) -> usize {
        self.region_radius
    }

    /// Full width at half maximum along the image x axis, px.
    pub fn fwhm_px(&self) -> f64 {
        self.fwhm_px
    }

    /// The PSF at offset `(dx, dy)` px from a point source, per px² (bilinear in the fine table; 0 outside).
    #[inline]
    pub fn value(&self, dx: f64, dy: f64) -> f32 {
        match (self.fine_node(dx), self.fine_node(dy)) {
            (Some(column), Some(row)) => self.fine_mix(column, row),
            _ => 0.0,
        }
    }

    /// [`Psf::value`] at every `(xs[a], ys[b])`, row-major (`b` the row), with each axis's node and
    /// fraction found once: the same values.
    pub fn values_on_grid(&self, xs: &[f64], ys: &[f64]) -> Vec<f32> {
        let columns: Vec<_> = xs.iter().map(|&d| self.fine_node(d)).collect();
        let mut out = Vec::with_capacity(xs.len() * ys.len());
        for row in ys.iter().map(|&d| self.fine_node(d)) {
            match row {
                None => out.extend(std::iter::repeat_n(0.0, xs.len())),
                Some(row) => out.extend(columns.iter().map(|c| c.map_or(0.0, |column| self.fine_mix(column, row)))),
            }
        }
        out
    }

    /// The fine table's node at or below offset `d` px on one axis and the fraction beyond it; `None` outside
    /// the table (the PSF is 0 there).
    #[inline]
    fn fine_node(&self, d: f64) -> Option<(usize, f32)> {
        let f = d * FINE_PER_PX as f64 + (self.fine.side / 2) as f64;
        if !(f >= 0.0 && f < (self.fine.side - 1) as f64) {
            return None;
        }
        let node = f as usize;
        Some((node, (f - node as f64) as f32))
    }

    /// The fine table between the nodes `(x0, y0)` and `(x0 + 1, y0 + 1)`, bilinear at fractions `(tx, ty)`.
    #[inline]
    fn fine_mix(&self, (x0, tx): (usize, f32), (y0, ty): (usize, f32)) -> f32 {
        let f = |x: usize, y: usize| self.fine.at(x, y);
        let top = f(x0, y0) + (f(x0 + 1, y0) - f(x0, y0)) * tx;
        let bottom = f(x0, y0 + 1) + (f(x0 + 1, y0 + 1) - f(x0, y0 + 1)) * tx;
        top + (bottom - top) * ty
    }

    /// Adds `weight ×` the PSF of a point source at `(x, y)` (px) to the pixels `x0..x1 × y0..y1` of `out`, a
    /// row-major buffer `width` wide whose first element is pixel `(x0, y0)`: the same values as
    /// [`Psf::value`] at each pixel centre, with the interpolation weights computed once (every pixel centre
    /// has the same sub-pixel offset from the source, so it falls at the same place between the fine table's
    /// nodes).
    #[allow(clippy::too_many_arguments)]
    pub fn add_point(&self, x: f64, y: f64, weight: f32, [x0, y0, x1, y1]: [usize; 4], out: &mut [f32], width: usize) {
        self.fine.add_point_rows(x, y, weight, [x0, y0, x1, y1], y0..y1, out, width);
    }

    /// The fine table as a [`PhaseTable`]: the whole PSF added at each point source.
    pub fn points(&self) -> &PhaseTable {
        &self.fine
    }

    /// The PSF split at a core of `core_radius_px` ([`SplitPsf`]); `None` for 0, or where the core would be as
    /// large as the kernel itself (its radius [`Psf::radius_px`] or more). Made once per core radius.
    pub fn split(&self, core_radius_px: usize) -> Option<&SplitPsf> {
        if core_radius_px == 0 || core_radius_px >= self.radius {
            return None;
        }
        Some(self.splits[core_radius_px].get_or_init(|| SplitPsf::new(self, core_radius_px)))
    }

    /// Kernel for a frame of point samples (nearest or bilinear sky).
    pub fn point_kernel(&self) -> &Kernel {
        &self.point
    }

    /// Kernel for a frame of pixel-area averages (supersampled sky).
    pub fn area_kernel(&self) -> &Kernel {
        &self.area
    }

    /// Integral of the fine table, px² (1 up to f32 rounding).
    pub fn integral(&self) -> f64 {
        let h2 = 1.0 / (FINE_PER_PX * FINE_PER_PX) as f64;
        let side = self.fine.side;
        (0..side).flat_map(|y| (0..side).map(move |x| (x, y))).map(|(x, y)| f64::from(self.fine.at(x, y)) * h2).sum()
    }
}

/// A raised cosine at `r`: 1 up to `inner`, 0 from `outer` on, `½(1 + cos(π(r − inner)/(outer − inner)))` between.
fn raised_cosine(r: f64, inner: f64, outer: f64) -> f64 {
    if r <= inner {
        1.0
    } else if r >= outer {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * (r - inner) / (outer - inner)).cos())
    }
}

/// Phases stored per axis: the [`FINE_PER_PX`] sub-pixel phases and one more, the first again one pixel on.
const PHASES: usize = FINE_PER_PX + 1;

/// A fine table stored by sub-pixel phase: for each phase `(qy, qx)` in `0..=FINE_PER_PX` a block of the nodes
/// `(qy + FINE_PER_PX·j, qx + FINE_PER_PX·i)`, one per whole pixel `(j, i)`, row-major (0 beyond the table).
/// Every pixel centre sees a point source at the same sub-pixel offset, so a point's pixels read one phase's
/// block (and its neighbours' for the interpolation) at consecutive addresses: a node's right neighbour is
/// the next phase's block at the same step (phase `FINE_PER_PX` is phase 0 one pixel on).
#[derive(Debug, Clone)]
pub struct PhaseTable {
    values: Vec<f32>,
    /// Pixel steps per block side.
    steps: usize,
    /// Nodes a side of the table it was made from, centred on the point source (`2·(R·FINE_PER_PX + FINE_PER_PX/2)
    /// + 1`).
    side: usize,
    /// Its radius `R`, px: the table is 0 beyond `R + ½` px on either axis.
    radius: usize,
}

impl PhaseTable {
    /// From a row-major table `side` nodes wide, of radius `radius` px.
    fn new(fine: &[f32], side: usize, radius: usize) -> Self {
        let steps = side.div_ceil(FINE_PER_PX) + 1;
        let mut values = vec![0f32; PHASES * PHASES * steps * steps];
        for qy in 0..PHASES {
            for qx in 0..PHASES {
                for j in 0..steps {
                    let y = qy + FINE_PER_PX * j;
                    for i in 0..steps {
                        let x = qx + FINE_PER_PX * i;
                        if x < side && y < side {
                            values[((qy * PHASES + qx) * steps + j) * steps + i] = fine[y * side + x];
                        }
                    }
                }
            }
        }
        Self { values, steps, side, radius }
    }

    /// Its radius `R`, px: a point source reaches the pixels within `R + ½` px of it on either axis.
    pub fn radius_px(&self) -> usize {
        self.radius
    }

    /// Node `(x, y)` of the table.
    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        let (qx, i) = (x % FINE_PER_PX, x / FINE_PER_PX);
        let (qy, j) = (y % FINE_PER_PX, y / FINE_PER_PX);
        self.values[((qy * PHASES + qx) * self.steps + j) * self.steps + i]
    }

    /// Row `j` of phase `(qy, qx)`'s block: nodes `(qy + FINE_PER_PX·j, qx + FINE_PER_PX·i)` for every `i`.
    #[inline(always)]
    fn row(&self, qy: usize, qx: usize, j: usize) -> &[f32] {
        let start = self.row_start(qy, qx, j);
        &self.values[start..start + self.steps]
    }

    /// [`Psf::add_point`] for this table on the pixel rows `rows` of the box alone (`rows.start ≥ y0`), into `out`
    /// whose first element is pixel `(x0, rows.start)`: each of those pixels gets the same value, to the bit, as
    /// from the whole box (the interpolation weights are the box's), so a box may be split into bands of rows
    /// filled side by side.
    #[allow(clippy::too_many_arguments)]
    pub fn add_point_rows(
        &self,
        x: f64,
        y: f64,
        weight: f32,
        [x0, y0, x1, y1]: [usize; 4],
        rows: std::ops::Range<usize>,
        out: &mut [f32],
        width: usize,
    ) {
        debug_assert!(rows.start >= y0, "the rows start inside the box");
        let per = FINE_PER_PX as f64;
        let half = (self.side / 2) as f64;
        let limit = (self.side - 1) as f64;
        // fine coordinates of pixel (x0, y0), and of each further pixel by steps of FINE_PER_PX nodes
        let fx0 = (x0 as f64 + 0.5 - x) * per + half;
        let fy0 = (y0 as f64 + 0.5 - y) * per + half;
        let first = |f0: f64| if f0 >= 0.0 { 0 } else { ((-f0) / per).ceil() as usize };
        let count = |f0: f64, n: usize| {
            if f0 >= limit { 0 } else { (((limit - f0) / per).ceil() as usize).min(n) }
        };
        let (kx0, kx1) = (first(fx0), count(fx0, x1.saturating_sub(x0)));
        let (ky0, ky1) = (first(fy0), count(fy0, y1.saturating_sub(y0)));
        // the rows written, from the box's first row, and the first of them (out's first row)
        let (r0, r1) = (rows.start.saturating_sub(y0), rows.end.min(y1).saturating_sub(y0));
        let (ky_lo, ky_hi) = (ky0.max(r0), ky1.min(r1));
        if kx0 >= kx1 || ky_lo >= ky_hi {
            return;
        }
        let fx = fx0 + per * kx0 as f64;
        let fy = fy0 + per * ky0 as f64;
        let (ix, iy) = (fx.floor(), fy.floor());
        let (tx, ty) = ((fx - ix) as f32, (fy - iy) as f32);
        let (ix, iy) = (ix as usize, iy as usize);
        // the nodes pixel after pixel are one phase's block, contiguous: the loop over a row vectorizes
        let (px, i0) = (ix % FINE_PER_PX, ix / FINE_PER_PX);
        let (py, j0) = (iy % FINE_PER_PX, iy / FINE_PER_PX);
        let n = kx1 - kx0;
        #[cfg(target_arch = "x86_64")]
        {
            use crate::physics::simd::Level;
            if let level @ (Level::Avx512 | Level::Avx2) = Level::detect() {
                let (steps, table) = (self.steps, &self.values);
                let start = |qy: usize, qx: usize| self.row_start(qy, qx, j0 + ky_lo - ky0) + i0;
                let starts = [start(py, px), start(py, px + 1), start(py + 1, px), start(py + 1, px + 1)];
                let (count, at) = (ky_hi - ky_lo, (ky_lo - r0) * width + kx0);
                // every row read and written lies inside its buffer (the same rows as the loop below would slice)
                assert!(i0 + n <= steps && starts.iter().all(|&s| s + (count - 1) * steps + n <= table.len()));
                assert!(at + (count - 1) * width + n <= out.len());
                let (out, weights) = (&mut out[at..], [tx, ty, weight]);
                // SAFETY: the CPU has AVX-512 or AVX2 (checked above); the reads and writes are inside the buffers
                // (asserted)
                unsafe {
                    if level == Level::Avx512 {
                        x86::add_rows_512(table, starts, steps, out, width, n, count, weights)
                    } else {
                        x86::add_rows_256(table, starts, steps, out, width, n, count, weights)
                    }
                }
                return;
            }
        }
        widest(
            #[inline(always)]
            || {
                for ky in ky_lo..ky_hi {
                    let j = j0 + ky - ky0;
                    let row = |qy: usize, qx: usize| &self.row(qy, qx, j)[i0..i0 + n];
                    let (a, b) = (row(py, px), row(py, px + 1));
                    let (c, d) = (row(py + 1, px), row(py + 1, px + 1));
                    let at = (ky - r0) * width;
                    let out = &mut out[at + kx0..at + kx1];
                    for k in 0..n {
                        let t = a[k] + (b[k] - a[k]) * tx;
                        let bottom = c[k] + (d[k] - c[k]) * tx;
                        out[k] += weight * (t + (bottom - t) * ty);
                    }
                }
            },
        );
    }

    /// Where [`PhaseTable::row`]`(qy, qx, j)` starts in `values` (row `j + 1` starts `steps` further on).
    #[inline(always)]
    fn row_start(&self, qy: usize, qx: usize, j: usize) -> usize {
        ((qy * PHASES + qx) * self.steps + j) * self.steps
    }
}

/// The width of the taper between a [`SplitPsf`]'s core and its tail, px.
pub const SPLIT_TAPER_PX: f64 = 2.0;

/// The PSF split in two for drawing many point sources at once (a target's quadrature nodes): the core, the PSF
/// within `r + ½` px of the source (times a raised cosine falling from 1 to 0 over its last [`SPLIT_TAPER_PX`]),
/// added at each source's exact sub-pixel position like the whole table ([`PhaseTable`]); and the tail, the rest (the PSF times one minus that taper), sampled at whole-pixel offsets, added from the sources' weights
/// binned to the pixel grid (each shared bilinearly among the four pixel centres around it) — the tail between
/// its whole-pixel samples taken as bilinear. The two add up to the PSF; the tail is smooth on the pixel scale
/// (the Airy rings there are mostly averaged away by the pixel's aperture), so its interpolation errs little
/// (`split_psf_error` in the tests: at `r` = 4 within 6.5e-4 of a point's peak on an F/4 MWIR PSF cut at 12 px,
/// 4.5e-4 on an F/1 LWIR one cut at 11 px, the flux within 3.5e-4; at `r` = 3 within 2.4e-3).
/// A node then costs the core's `(2r + 2)²` pixels instead of the kernel's `(2R + 2)²`, and the tail a kernel's
/// worth per binned pixel.
#[derive(Debug, Clone)]
pub struct SplitPsf {
    core: PhaseTable,
    /// `(2R + 1)²` values, row-major, at whole-pixel offsets `−R..=R`.
    tail: Vec<f32>,
    tail_radius: usize,
}

impl SplitPsf {
    fn new(psf: &Psf, core_radius: usize) -> Self {
        let per = FINE_PER_PX as f64;
        let centre = (psf.fine.side / 2) as isize;
        let outer = core_radius as f64 + 0.5;
        let inner = (outer - SPLIT_TAPER_PX).max(0.0);
        let taper = |r: f64| raised_cosine(r, inner, outer);
        let at = |dx: isize, dy: isize| f64::from(psf.fine.at((centre + dx) as usize, (centre + dy) as usize));
        let half = (core_radius * FINE_PER_PX + FINE_PER_PX / 2) as isize;
        let side = (2 * half + 1) as usize;
        let mut core = Vec::with_capacity(side * side);
        for dy in -half..=half {
            for dx in -half..=half {
                core.push((at(dx, dy) * taper((dx as f64).hypot(dy as f64) / per)) as f32);
            }
        }
        let r = psf.radius as isize;
        let step = FINE_PER_PX as isize;
        let mut tail = Vec::with_capacity(((2 * r + 1) * (2 * r + 1)) as usize);
        for dy in -r..=r {
            for dx in -r..=r {
                tail.push((at(dx * step, dy * step) * (1.0 - taper((dx as f64).hypot(dy as f64)))) as f32);
            }
        }
        Self { core: PhaseTable::new(&core, side, core_radius), tail, tail_radius: psf.radius }
    }

    /// The core, added at each point source's position.
    pub fn core(&self) -> &PhaseTable {
        &self.core
    }

    /// The tail's radius `R`, px (the whole kernel's).
    pub fn tail_radius_px(&self) -> usize {
        self.tail_radius
    }

    /// The tail at whole-pixel offsets `(dx, dy)` in `−R..=R`, row-major: `(2R + 1)²` values.
    pub fn tail(&self) -> &[f32] {
        &self.tail
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// [`Psf::add_point`](super::Psf::add_point)'s loop, sixteen pixels at a time with the row's last
    /// pixels under a mask: for `count` rows `r`, `out[r·width + k] += weight·bilinear(a, b, c, d; tx, ty)` for
    /// `k < n`, where `a`… are the table's values at `starts[0..4] + r·steps + k`. The operations are the scalar
    /// loop's in its order (no fused multiply–add), so every value is the same.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL); `starts[i] + (count − 1)·steps + n ≤ table.len()` for each
    /// `i`, and `(count − 1)·width + n ≤ out.len()`.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn add_rows_512(
        table: &[f32],
        starts: [usize; 4],
        steps: usize,
        out: &mut [f32],
        width: usize,
        n: usize,
        count: usize,
        [tx, ty, weight]: [f32; 3],
    ) {
        let (tx, ty, weight) = (_mm512_set1_ps(tx), _mm512_set1_ps(ty), _mm512_set1_ps(weight));
        let base = table.as_ptr();
        let dst = out.as_mut_ptr();
        for r in 0..count {
            let mut k = 0;
            while k < n {
                let mask: __mmask16 = if n - k >= 16 { 0xffff } else { (1u16 << (n - k)) - 1 };
                // SAFETY: lanes under the mask lie inside the rows the caller vouches for; the others are not
                // touched (masked loads and stores do not fault)
                unsafe {
                    let load = |s: usize| _mm512_maskz_loadu_ps(mask, base.add(s + r * steps + k));
                    let (a, b, c, d) = (load(starts[0]), load(starts[1]), load(starts[2]), load(starts[3]));
                    let v = crate::physics::simd::bilinear_mix16(a, b, c, d, tx, ty);
                    let o = dst.add(r * width + k);
                    let sum = _mm512_add_ps(_mm512_maskz_loadu_ps(mask, o), _mm512_mul_ps(weight, v));
                    _mm512_mask_storeu_ps(o, mask, sum);
                }
                k += 16;
            }
        }
    }

    /// [`add_rows_512`] with AVX2, eight pixels at a time; the row's last pixels read under a mask and written
    /// one by one (a masked store, `vmaskmovps`, made the `targets` stage slower than the scalar loop it replaced
    /// on an AMD EPYC).
    ///
    /// # Safety
    /// The CPU must have AVX2; otherwise as [`add_rows_512`]'s.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2")]
    pub unsafe fn add_rows_256(
        table: &[f32],
        starts: [usize; 4],
        steps: usize,
        out: &mut [f32],
        width: usize,
        n: usize,
        count: usize,
        [tx, ty, weight]: [f32; 3],
    ) {
        let (tx, ty, weight) = (_mm256_set1_ps(tx), _mm256_set1_ps(ty), _mm256_set1_ps(weight));
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let base = table.as_ptr();
        let dst = out.as_mut_ptr();
        // `out + weight·bilinear` of eight pixels, the lanes outside `mask` (if any) read as 0
        let block = |s: [*const f32; 4], o: *const f32, mask: Option<__m256i>| {
            // SAFETY: the lanes read (all, or those under the mask) lie inside the rows the caller vouches for;
            // masked loads do not fault on the others
            let load = |p: *const f32| unsafe {
                match mask {
                    Some(m) => _mm256_maskload_ps(p, m),
                    None => _mm256_loadu_ps(p),
                }
            };
            let (a, b, c, d) = (load(s[0]), load(s[1]), load(s[2]), load(s[3]));
            let v = crate::physics::simd::bilinear_mix8(a, b, c, d, tx, ty);
            _mm256_add_ps(load(o), _mm256_mul_ps(weight, v))
        };
        for r in 0..count {
            let mut k = 0;
            while k < n {
                // SAFETY: the rows' pixels k… lie inside the buffers (the caller's promise)
                let (s, o) = unsafe { (starts.map(|s| base.add(s + r * steps + k)), dst.add(r * width + k)) };
                if n - k >= 8 {
                    // SAFETY: eight pixels inside the row
                    unsafe { _mm256_storeu_ps(o, block(s, o, None)) };
                } else {
                    let mask = _mm256_cmpgt_epi32(_mm256_set1_epi32((n - k) as i32), lanes);
                    let mut tail = [0f32; 8];
                    // SAFETY: eight floats into `tail`, then the row's last n − k pixels from it
                    unsafe {
                        _mm256_storeu_ps(tail.as_mut_ptr(), block(s, o, Some(mask)));
                        std::ptr::copy_nonoverlapping(tail.as_ptr(), o, n - k);
                    }
                }
                k += 8;
            }
        }
    }
}

/// The OTF as a function of spatial frequency (cycles/px).
struct Otf {
    /// `(weight, λN/pitch)` per wavelength; empty without diffraction.
    diffraction: Vec<(f64, f64)>,
    /// Side of the pixel aperture, px; 0 without it.
    aperture_px: f64,
    /// Total Gaussian variance, px² (at least a fine sample's, which keeps a bare box free of ringing).
    sigma2: f64,
}

impl Otf {
    fn new(spec: &PsfSpec, o: &PsfOptics) -> Self {
        let mut diffraction = Vec::new();
        if spec.diffraction {
            let (lo, hi) = (o.band.lo_um(), o.band.hi_um());
            let mut total = 0.0;
            for i in 0..BAND_SAMPLES {
                let lambda_um = lo + (hi - lo) * (i as f64 + 0.5) / BAND_SAMPLES as f64;
                let mut w = spectral_radiance(lambda_um, o.reference_temp_k);
                if o.measure == Measure::Photon {
                    w *= lambda_um;
                }
                total += w;
                diffraction.push((w, lambda_um * 1e-6 * o.f_number / o.pixel_pitch_m));
            }
            if total > 0.0 {
                for d in &mut diffraction {
                    d.0 /= total;
                }
            } else {
                // no signal weights (a band far in the Wien tail): weigh wavelengths equally
                for d in &mut diffraction {
                    d.0 = 1.0 / BAND_SAMPLES as f64;
                }
            }
        }
        let fine = 1.0 / FINE_PER_PX as f64;
        let sigma2 = (spec.aberration_sigma_px.powi(2) + spec.motion_sigma_px.powi(2)).max(fine * fine);
        Self { diffraction, aperture_px: if spec.pixel_aperture { o.fill_factor.sqrt() } else { 0.0 }, sigma2 }
    }

    /// The OTF's radial part at `(fx, fy)`: the Gaussian blur times the band's diffraction.
    fn radial(&self, fx: f64, fy: f64) -> f64 {
        let f = fx.hypot(fy);
        let mut v = (-2.0 * std::f64::consts::PI.powi(2) * self.sigma2 * f * f).exp();
        if !self.diffraction.is_empty() {
            let mut d = 0.0;
            for &(w, scale) in &self.diffraction {
                let nu = f * scale;
                if nu < 1.0 {
                    d += w * (2.0 / std::f64::consts::PI) * (nu.acos() - nu * (1.0 - nu * nu).sqrt());
                }
            }
            v *= d;
        }
        v
    }

    /// The OTF at `(fx, fy)` from its radial part `v` there; `aperture` includes the pixel aperture, `tent`
    /// the linear interpolant's `sinc²`.
    /// (The tests' direct form; the grids use [`Otf::with_factors`], the same operations.)
    #[cfg(test)]
    fn with_apertures(&self, mut v: f64, fx: f64, fy: f64, aperture: bool, tent: bool) -> f64 {
        if aperture && self.aperture_px > 0.0 {
            v *= sinc(self.aperture_px * fx) * sinc(self.aperture_px * fy);
        }
        if tent {
            v *= (sinc(fx) * sinc(fy)).powi(2);
        }
        v
    }

    /// The apertures' factors along one axis at frequency `f`: the pixel aperture's `sinc`, the tent's `sinc`.
    fn factors(&self, f: f64) -> (f64, f64) {
        (sinc(self.aperture_px * f), sinc(f))
    }

    /// [`Otf::with_apertures`] from each axis's [`Otf::factors`] (the OTF's apertures are separable, so a grid
    /// needs them once per row and once per column, not per frequency).
    #[inline]
    fn with_factors(&self, mut v: f64, (ax, tx): (f64, f64), (ay, ty): (f64, f64), aperture: bool, tent: bool) -> f64 {
        if aperture && self.aperture_px > 0.0 {
            v *= ax * ay;
        }
        if tent {
            v *= (tx * ty).powi(2);
        }
        v
    }

    /// The radial part over the frequencies `(mx, my) / PERIOD_PX`, `mx, my ∈ [0, half)`, row-major: every
    /// value a grid of `per_px ≤ 2·(half − 1) / PERIOD_PX` samples per pixel needs (the OTF is even in each
    /// frequency, and the grids' frequencies are all multiples of `1/PERIOD_PX`).
    fn radial_quadrant(&self, half: usize) -> Vec<f64> {
        // past every wavelength's cut-off the diffraction term is 0, and so is the value: such frequencies
        // (most of the quadrant) need no `hypot` or `exp`. `f² > (cut-off·(1 + 10⁻⁹))²` puts `hypot` (within an
        // ulp of the exact `f`) past the cut-off for certain, so each value is the bits `radial` gives.
        let beyond = self.diffraction.iter().map(|&(_, scale)| 1.0 / scale).fold(0.0, f64::max) * (1.0 + 1e-9);
        let zero_past = (!self.diffraction.is_empty() && beyond.is_finite()).then_some(beyond * beyond);
        let mut out = vec![0.0; half * half];
        out.par_chunks_mut(half).enumerate().for_each(|(my, row)| {
            let fy = my as f64 / PERIOD_PX as f64;
            for (mx, v) in row.iter_mut().enumerate() {
                let fx = mx as f64 / PERIOD_PX as f64;
                *v = match zero_past {
                    Some(f2) if fx * fx + fy * fy > f2 => 0.0,
                    _ => self.radial(fx, fy),
                };
            }
        });
        out
    }

    /// The PSF on the periodic grid of `per_px` samples per pixel (`PERIOD_PX·per_px` square, row-major, index 0
    /// at offset 0), per px², from the radial part's quadrant ([`Otf::radial_quadrant`] of side `half`).
    ///
    /// The OTF is even in `fx` and in `fy` (sines are odd, `hypot` and the squares even, bit for bit), so each
    /// frequency's value is that of its magnitudes, computed once; so is each row's transform (rows `ky` and
    /// `n − ky` are the same). With `reach`, only the columns within `reach` samples of offset 0 (either way,
    /// periodically) are transformed, and only their rows within it kept, the others left 0: the fine table
    /// reads no further.
    ///
    /// Each row and column is transformed by the same plan as [`fft2`]'s, so every value is the same bits as
    /// those of the whole grid's 2D transform.
    fn spatial(
        &self,
        per_px: usize,
        aperture: bool,
        tent: bool,
        radial: &[f64],
        half: usize,
        reach: Option<usize>,
    ) -> Vec<f32> {
        let n = PERIOD_PX * per_px;
        assert!(n / 2 < half, "the radial quadrant covers the grid");
        let fold = |k: usize| if k < n / 2 { k } else { n - k };
        // the quadrant's values with the apertures, then the grid filled from it
        let q = n / 2 + 1;
        let factors: Vec<(f64, f64)> = (0..q).map(|m| self.factors(m as f64 / PERIOD_PX as f64)).collect();
        let mut quadrant = vec![0.0; q * q];
        quadrant.par_chunks_mut(q).enumerate().for_each(|(my, row)| {
            for (mx, v) in row.iter_mut().enumerate() {
                *v = self.with_factors(radial[my * half + mx], factors[mx], factors[my], aperture, tent);
            }
        });
        let mut planner = rustfft::FftPlanner::new();
        let plan = planner.plan_fft(n, rustfft::FftDirection::Inverse);
        // past the diffraction cut-off whole rows of the quadrant are 0 (most of them): their transforms are 0
        // (up to the sign of zero, which no sum of the columns' transforms can show), so only the rows before
        // the last with a value are transformed
        let live = quadrant.chunks_exact(q).rposition(|row| row.iter().any(|&v| v != 0.0)).map_or(0, |k| k + 1);
        let mut rows = vec![Complex::new(0.0, 0.0); live * n];
        rows.par_chunks_mut(n).enumerate().for_each(|(ky, row)| {
            let source = &quadrant[ky * q..][..q];
            for (kx, c) in row.iter_mut().enumerate() {
                c.re = source[fold(kx)];
            }
            plan.process(row);
        });
        // the columns asked for, each gathered from its rows and transformed; with `reach`, the rows kept are
        // the same offsets as the columns
        let columns: Vec<usize> = match reach {
            Some(r) if 2 * r + 1 < n => (0..=r).chain(n - r..n).collect(),
            _ => (0..n).collect(),
        };
        let scale = 1.0 / (PERIOD_PX * PERIOD_PX) as f64;
        let zero = Complex::new(0.0, 0.0);
        let values: Vec<Vec<f32>> = columns
            .par_iter()
            .map(|&x| {
                let mut column: Vec<Complex<f64>> =
                    (0..n).map(|ky| if fold(ky) < live { rows[fold(ky) * n + x] } else { zero }).collect();
                plan.process(&mut column);
                columns.iter().map(|&y| (column[y].re * scale) as f32).collect()
            })
            .collect();
        let mut grid = vec![0.0f32; n * n];
        // the kept rows in order, as the columns are (the same offsets)
        let mut kept: Vec<&mut [f32]> = grid
            .chunks_exact_mut(n)
            .enumerate()
            .filter_map(|(y, row)| columns.binary_search(&y).is_ok().then_some(row))
            .collect();
        kept.par_iter_mut().enumerate().for_each(|(k, row)| {
            for (&x, column) in columns.iter().zip(&values) {
                row[x] = column[k];
            }
        });
        grid
    }
}

/// `sin(πx)/(πx)`, 1 at 0.
pub(crate) fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-8 {
        1.0
    } else {
        let px = std::f64::consts::PI * x;
        px.sin() / px
    }
}

/// The smallest radius (px) whose square of integer offsets holds `1 − cutoff` of the grid's energy.
fn cut_radius(grid: &[f32], per_px: usize, cutoff: f64) -> usize {
    let n = PERIOD_PX * per_px;
    let at = |dx: isize, dy: isize| {
        let (x, y) = ((dx * per_px as isize).rem_euclid(n as isize), (dy * per_px as isize).rem_euclid(n as isize));
        f64::from(grid[y as usize * n + x as usize])
    };
    let total: f64 = (-(PERIOD_PX as isize) / 2..PERIOD_PX as isize / 2)
        .flat_map(|dy| (-(PERIOD_PX as isize) / 2..PERIOD_PX as isize / 2).map(move |dx| (dx, dy)))
        .map(|(dx, dy)| at(dx, dy))
        .sum();
    for r in 0..=MAX_RADIUS_PX as isize {
        let inside: f64 = (-r..=r).flat_map(|dy| (-r..=r).map(move |dx| (dx, dy))).map(|(dx, dy)| at(dx, dy)).sum();
        if inside >= (1.0 - cutoff) * total {
            return r as usize;
        }
    }
    MAX_RADIUS_PX
}

/// Full width at half maximum along x through the centre of a fine table.
fn fwhm(fine: &[f32], side: usize, per_px: usize) -> f64 {
    let c = side / 2;
    let row = &fine[c * side..(c + 1) * side];
    let half = row[c] * 0.5;
    let mut x = c;
    while x + 1 < side && row[x + 1] > half {
        x += 1;
    }
    if x + 1 >= side {
        return (side / per_px) as f64;
    }
    // linear interpolation of the crossing between x and x + 1
    let t = f64::from((row[x] - half) / (row[x] - row[x + 1]));
    2.0 * ((x - c) as f64 + t) / per_px as f64
}

impl Kernel {
    /// Integer-offset samples of a periodic grid, normalised to sum 1, with the separable decomposition.
    fn from_grid(grid: &[f32], per_px: usize, radius: usize) -> Self {
        let n = PERIOD_PX * per_px;
        let r = radius as isize;
        let side = 2 * radius + 1;
        let mut values = Vec::with_capacity(side * side);
        for dy in -r..=r {
            for dx in -r..=r {
                let (x, y) =
                    ((dx * per_px as isize).rem_euclid(n as isize), (dy * per_px as isize).rem_euclid(n as isize));
                values.push(f64::from(grid[y as usize * n + x as usize]));
            }
        }
        let sum: f64 = values.iter().sum();
        let values: Vec<f64> = values.iter().map(|v| v / sum).collect();
        Self::from_values(radius, &values)
    }

    /// A kernel from row-major `(2R+1)²` values (symmetric under transposition for the decomposition to be
    /// exact at full rank).
    ///
    /// # Panics
    /// If `values.len()` is not `(2·radius + 1)²`.
    pub fn from_values(radius: usize, values: &[f64]) -> Self {
        let side = 2 * radius + 1;
        assert_eq!(values.len(), side * side, "kernel size");
        let second_moment_px2 = second_moment(radius, values);
        // symmetric part, eigen-decomposed; keep the largest terms until the worst error is 1e-4 of the peak
        let sym: Vec<f64> =
            (0..side * side).map(|i| 0.5 * (values[i] + values[(i % side) * side + i / side])).collect();
        let (eigenvalues, vectors) = jacobi_eigen(&sym, side);
        let mut order: Vec<usize> = (0..side).collect();
        order.sort_by(|&a, &b| eigenvalues[b].abs().total_cmp(&eigenvalues[a].abs()));
        let peak = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut approx = vec![0.0; side * side];
        let mut terms: Vec<(f32, Vec<f32>)> = Vec::new();
        for &k in &order {
            let v: Vec<f64> = (0..side).map(|i| vectors[i * side + k]).collect();
            for y in 0..side {
                for x in 0..side {
                    approx[y * side + x] += eigenvalues[k] * v[y] * v[x];
                }
            }
            terms.push((eigenvalues[k] as f32, v.iter().map(|&x| x as f32).collect()));
            let worst = approx.iter().zip(values).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            if worst <= 1e-4 * peak {
                break;
            }
        }
        // the truncated sum keeps the kernel's total exactly, so flat regions stay flat
        let (want, got): (f64, f64) = (values.iter().sum(), approx.iter().sum());
        if got != 0.0 {
            for t in &mut terms {
                t.0 = (f64::from(t.0) * want / got) as f32;
            }
        }
        let vertical = terms.iter().map(|(lambda, v)| v.iter().map(|c| c * lambda).collect()).collect();
        Self { radius, values: values.iter().map(|&v| v as f32).collect(), terms, vertical, second_moment_px2 }
    }

    /// A kernel from row-major `(2R+1)²` values, applied in 2D only (no separable decomposition: the separable
    /// method applies it directly).
    ///
    /// # Panics
    /// If `values.len()` is not `(2·radius + 1)²`.
    pub fn from_values_2d(radius: usize, values: &[f64]) -> Self {
        let side = 2 * radius + 1;
        assert_eq!(values.len(), side * side, "kernel size");
        let second_moment_px2 = second_moment(radius, values);
        let values = values.iter().map(|&v| v as f32).collect();
        Self { radius, values, terms: Vec::new(), vertical: Vec::new(), second_moment_px2 }
    }

    /// Radius, px.
    pub fn radius(&self) -> usize {
        self.radius
    }

    /// Row-major values.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Rank of the separable decomposition.
    pub fn rank(&self) -> usize {
        self.terms.len()
    }

    /// `Σ K[d]·|d|²`, px²: a frame `S` changes by at most `½·M₂·max|∂²S|` under the kernel (second-order Taylor
    /// bound for a symmetric kernel), which is how a smooth sky is recognised as not needing it.
    pub fn second_moment_px2(&self) -> f64 {
        self.second_moment_px2
    }
}

/// `Σ K[d]·|d|²` of row-major `(2R+1)²` kernel values, px².
fn second_moment(radius: usize, values: &[f64]) -> f64 {
    let (side, r) = (2 * radius + 1, radius as f64);
    values
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (x, y) = ((i % side) as f64 - r, (i / side) as f64 - r);
            v * (x * x + y * y)
        })
        .sum()
}

/// Eigen-decomposition of a symmetric `n × n` matrix by cyclic Jacobi rotations: eigenvalues and the
/// eigenvectors as the columns of a row-major matrix.
fn jacobi_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut a = a.to_vec();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .filter(|(i, j)| i != j)
            .map(|(i, j)| a[i * n + j].powi(2))
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                let t = sign / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k * n + p], a[k * n + q]);
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p * n + k], a[q * n + k]);
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

/// Per [`BLUR_TILE_PX`] tile of `frame`, the largest `|F_xx| + |F_yy| + 2·|F_xy|` (central second differences
/// along the axes, the forward mixed difference of the pixel's 2 × 2 cell; edges replicated) into `out`; NaN
/// where a pixel or a neighbour is NaN. Tiles whose entry in `wanted` (row-major) is false are left at 0.
fn tile_curvature(frame: &Frame, wanted: &[bool], out: &mut Vec<f32>) {
    let (w, h) = (frame.width(), frame.height());
    let t = BLUR_TILE_PX;
    let (tw, th) = (w.div_ceil(t), h.div_ceil(t));
    out.clear();
    out.resize(tw * th, 0.0);
    let px = frame.pixels();
    // a band of tiles a task: the wanted tiles are often a few bands
    out.par_chunks_mut(tw).enumerate().with_max_len(split_finely(1)).for_each(|(ty, tiles)| {
        CURVATURE_COLUMNS.with_borrow_mut(|most| {
            // each column's largest value so far in the band (NaN sticking)
            most.clear();
            most.resize(w, 0.0);
            let wanted = &wanted[ty * tw..(ty + 1) * tw];
            widest(
                #[inline(always)]
                || {
                    for y in ty * t..((ty + 1) * t).min(h) {
                        let row = |y: usize| &px[y * w..(y + 1) * w];
                        let (up, mid, down) = (row(y.saturating_sub(1)), row(y), row((y + 1).min(h - 1)));
                        for run in true_runs(wanted) {
                            curvature_max_row(up, mid, down, run.start * t..(run.end * t).min(w), most);
                        }
                    }
                },
            );
            // the values are ≥ 0 and NaN sticks, so their largest is the same in any order (here down each column
            // in vector registers, then across a tile's sixteen columns by halves)
            for (k, tile) in tiles.iter_mut().enumerate() {
                if wanted[k] {
                    // a partial tile's missing columns as 0, which changes no largest value
                    let columns = &most[k * t..((k + 1) * t).min(w)];
                    let mut v = [0.0; BLUR_TILE_PX];
                    v[..columns.len()].copy_from_slice(columns);
                    *tile = halving_max(v);
                }
            }
        });
    });
}

/// The largest of sixteen values (`≥ 0`, or NaN) by [`sticky_max`], the first half against the second until one
/// is left (four vector steps, where a fold is sixteen dependent ones).
#[inline(always)]
fn halving_max(mut v: [f32; BLUR_TILE_PX]) -> f32 {
    let mut n = BLUR_TILE_PX;
    while n > 1 {
        n /= 2;
        for j in 0..n {
            v[j] = sticky_max(v[j], v[j + n]);
        }
    }
    v[0]
}

/// The larger of `m` and `v` (values `≥ 0`), NaN if either is NaN: a tile's curvature is NaN once a pixel's is.
#[inline(always)]
fn sticky_max(m: f32, v: f32) -> f32 {
    if v > m {
        v
    } else if v <= m {
        m
    } else {
        f32::NAN
    }
}

thread_local! {
    /// Each thread's largest curvature so far down each column of a band of tiles, for [`tile_curvature`] (kept
    /// from frame to frame).
    static CURVATURE_COLUMNS: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    /// Each thread's tile columns that a padded row's horizontal pass covers, and the run of the row it pads
    /// ([`pad_span`]), for [`Convolver::apply_where_needed_in`] (kept from frame to frame).
    static BLURRED_COLUMNS: std::cell::RefCell<(Vec<bool>, Vec<f32>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
    /// Each thread's padded row and band of horizontal passes for [`Convolver::apply`]'s separable method (kept
    /// from frame to frame).
    static SEPARABLE_BAND: std::cell::RefCell<(Vec<f32>, Vec<f32>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// The curvature measure `|f_xx| + |f_yy| + 2·|f_xy|` of row `mid` (rows `up` and `down` around it, edges
/// replicated) at the columns `xs`, taken into `most` at the same columns by [`sticky_max`]. The interior is one
/// pass over slices (it vectorizes); the first and last columns use the replicated neighbours.
#[inline(always)]
fn curvature_max_row(up: &[f32], mid: &[f32], down: &[f32], xs: std::ops::Range<usize>, most: &mut [f32]) {
    let w = mid.len();
    let at = |x: usize| {
        let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
        let fxx = mid[l] - 2.0 * mid[x] + mid[r];
        let fyy = up[x] - 2.0 * mid[x] + down[x];
        let fxy = down[r] - down[x] - mid[r] + mid[x];
        fxx.abs() + fyy.abs() + 2.0 * fxy.abs()
    };
    // the interior columns a..b have both neighbours
    let (a, b) = (xs.start.max(1), xs.end.min(w.saturating_sub(1)));
    for (x, m) in most.iter_mut().enumerate().take(a.min(xs.end)).skip(xs.start) {
        *m = sticky_max(*m, at(x));
    }
    if a < b {
        let n = b - a;
        let (ml, mc, mr) = (&mid[a - 1..b - 1], &mid[a..b], &mid[a + 1..b + 1]);
        let (uc, dc, dr) = (&up[a..b], &down[a..b], &down[a + 1..b + 1]);
        let out = &mut most[a..b];
        for i in 0..n {
            let fxx = ml[i] - 2.0 * mc[i] + mr[i];
            let fyy = uc[i] - 2.0 * mc[i] + dc[i];
            let fxy = dr[i] - dc[i] - mr[i] + mc[i];
            out[i] = sticky_max(out[i], fxx.abs() + fyy.abs() + 2.0 * fxy.abs());
        }
    }
    for (x, m) in most.iter_mut().enumerate().take(xs.end).skip(b.max(a)) {
        *m = sticky_max(*m, at(x));
    }
}

/// Reusable buffers for applying kernels to frames of one size.
#[derive(Debug, Default)]
pub struct Convolver {
    /// Per padded row, per term: the horizontal pass of the tiles blurred where needed (frame columns).
    horizontal: Vec<f32>,
    acc: Vec<f32>,
    padded: Vec<f32>,
    fft: Option<FftConvolution>,
    /// Per tile: the curvature measure (infinite for NaN).
    rough: Vec<f32>,
    /// Per tile: the largest measure within the kernel's reach along its row of tiles.
    along: Vec<f32>,
    /// Per tile: the largest measure within the kernel's reach.
    worst: Vec<f32>,
    /// Per tile: whether a candidate tile is within the kernel's reach along its row of tiles.
    along_flags: Vec<bool>,
    /// Per tile: whether the tile is blurred.
    needed: Vec<bool>,
    /// Per tile: whether its curvature is needed (a candidate tile reaches it).
    wanted: Vec<bool>,
    /// The vertical pass's pieces of blurred tiles: (band, first column, columns), in band order.
    pieces: Vec<(usize, usize, usize)>,
}

/// Per tile of a row-major grid `tiles_x` wide (`flags`): whether a tile within `reach` tiles of it (on either
/// axis) is flagged, into `out`; `along` is the buffer of its pass along the rows (each row's windows, then the
/// columns' windows of those).
pub fn tiles_within_reach(flags: &[bool], tiles_x: usize, reach: usize, along: &mut Vec<bool>, out: &mut Vec<bool>) {
    join_within_reach(flags, tiles_x, reach, (false, |a, b| a | b), along, out);
}

/// Per tile of a row-major grid `tiles_x` wide (`values`; its last row may be short): `join` of the values of the
/// tiles within `reach` tiles of it on either axis (a square, cut at the grid's edges), into `out`. `join` is
/// associative and commutative with `none` its identity (`|` with `false`, or the larger of two values `≥ 0` with
/// 0), so the square's value is that of each row's windows (into `along`) taken down the column's window: twice
/// `2·reach + 1` joins a tile where the square takes its square. Rows and columns go in nested loops (no division
/// of a tile's index into them).
fn join_within_reach<T: Copy>(
    values: &[T],
    tiles_x: usize,
    reach: usize,
    (none, join): (T, impl Fn(T, T) -> T),
    along: &mut Vec<T>,
    out: &mut Vec<T>,
) {
    debug_assert!(tiles_x > 0 || values.is_empty(), "tiles in rows of none");
    let window = |v: &[T]| v.iter().fold(none, |m, &x| join(m, x));
    along.clear();
    for row in values.chunks(tiles_x.max(1)) {
        // every column of the grid, past a short last row's end too: their windows may reach into the row
        along.extend((0..tiles_x).map(|tx| {
            let end = (tx + reach + 1).min(row.len());
            window(&row[tx.saturating_sub(reach).min(end)..end])
        }));
    }
    let tiles_y = values.len().div_ceil(tiles_x.max(1));
    out.clear();
    for ty in 0..tiles_y {
        let rows = ty.saturating_sub(reach)..=(ty + reach).min(tiles_y - 1);
        let row_len = tiles_x.min(values.len() - ty * tiles_x);
        out.extend((0..row_len).map(|tx| rows.clone().fold(none, |m, y| join(m, along[y * tiles_x + tx]))));
    }
}

/// The runs of consecutive `true` entries of `flags`, as index ranges, in order.
pub fn true_runs(flags: &[bool]) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
    let mut i = 0;
    std::iter::from_fn(move || {
        while i < flags.len() && !flags[i] {
            i += 1;
        }
        let start = i;
        while i < flags.len() && flags[i] {
            i += 1;
        }
        (start < i).then_some(start..i)
    })
}

/// Side of the tiles a selective blur ([`Convolver::apply_where_needed`]) decides on, px.
pub const BLUR_TILE_PX: usize = 16;

/// What a selective blur did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BlurStats {
    /// Tiles where the blur can change a pixel by more than the threshold.
    pub tiles_needed: usize,
    /// Tiles blurred (all of them when the whole-frame method was cheaper).
    pub tiles_blurred: usize,
    /// Tiles in the frame.
    pub tiles: usize,
}

/// Four sums of sixteen lanes, `acc.b[j] += c·p[16b + j]`: the blur passes' step over four blocks of outputs
/// side by side (four independent sums, where one block's sum waited on each add).
#[inline(always)]
fn add_four_blocks(acc: &mut ([f32; 16], [f32; 16], [f32; 16], [f32; 16]), c: f32, p: &[f32; 64]) {
    for j in 0..16 {
        acc.0[j] += c * p[j];
        acc.1[j] += c * p[16 + j];
        acc.2[j] += c * p[32 + j];
        acc.3[j] += c * p[48 + j];
    }
}

/// `out[x] += Σ_k v[k]·src[k][x]` for every `x` of `out`, the sum from 0 in `k`'s order: one term's vertical
/// pass as the tests spell it out, output by output, which [`vertical_terms`] must match to the bit.
#[cfg(test)]
fn accumulate_rows(rows: &[&[f32]], v: &[f32], out: &mut [f32]) {
    for (x, o) in out.iter_mut().enumerate() {
        let mut sum = 0.0f32;
        for (row, &c) in rows.iter().zip(v) {
            sum += c * row[x];
        }
        *o += sum;
    }
}

/// Fills `out` with columns `x0 − r .. x0 − r + out.len()` of `line` (`x0` a column of it), the columns beyond
/// its ends replicating its first and last values: a row padded by `r` on each side, or a run of one.
fn pad_span(line: &[f32], x0: usize, r: usize, out: &mut [f32]) {
    let (w, n) = (line.len() as isize, out.len() as isize);
    let lo = x0 as isize - r as isize;
    let (a, b) = (lo.clamp(0, w), (lo + n).clamp(0, w));
    let left = ((a - lo) as usize).min(out.len());
    let inside = (b - a) as usize;
    out[..left].fill(line[0]);
    out[left..left + inside].copy_from_slice(&line[a as usize..b as usize]);
    out[left + inside..].fill(line[line.len() - 1]);
}

/// Columns of a vertical pass taken down all of a piece's rows before the next (a multiple of the passes'
/// 64-output step): every term's taps of one output row, 64 columns wide, fit the first-level cache.
const VERTICAL_COLUMNS: usize = 64;

/// The vertical pass of every term at once: `out[x] = Σ_t (Σ_k v_t[k]·h[first + k·row_stride + t·term_stride + x])`
/// with each term's sum taken from 0 in `k`'s order and the terms added to 0 in their order — the sums, to the
/// bit, of clearing `out` and then adding each term's vertical pass in turn (`accumulate_rows`, as the tests
/// spell it), without storing and reloading `out` between terms or gathering the rows' slices for each (four
/// blocks of sixteen outputs in registers).
#[inline(always)]
fn vertical_terms(
    h: &[f32],
    first: usize,
    [row_stride, term_stride]: [usize; 2],
    verticals: &[Vec<f32>],
    out: &mut [f32],
) {
    const LANES: usize = 16;
    const WIDE: usize = 4 * LANES;
    let cols = out.len();
    let mut x = 0;
    while x + WIDE <= cols {
        let mut total = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        for (t, v) in verticals.iter().enumerate() {
            let mut acc = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
            for (k, &c) in v.iter().enumerate() {
                let at = first + k * row_stride + t * term_stride + x;
                add_four_blocks(&mut acc, c, h[at..at + WIDE].try_into().expect("four blocks of LANES"));
            }
            for j in 0..LANES {
                total.0[j] += acc.0[j];
                total.1[j] += acc.1[j];
                total.2[j] += acc.2[j];
                total.3[j] += acc.3[j];
            }
        }
        for (b, sums) in [total.0, total.1, total.2, total.3].iter().enumerate() {
            out[x + b * LANES..x + (b + 1) * LANES].copy_from_slice(sums);
        }
        x += WIDE;
    }
    while x + LANES <= cols {
        let mut total = [0.0f32; LANES];
        for (t, v) in verticals.iter().enumerate() {
            let mut acc = [0.0f32; LANES];
            for (k, &c) in v.iter().enumerate() {
                let at = first + k * row_stride + t * term_stride + x;
                let p: &[f32; LANES] = h[at..at + LANES].try_into().expect("a block of LANES");
                for j in 0..LANES {
                    acc[j] += c * p[j];
                }
            }
            for j in 0..LANES {
                total[j] += acc[j];
            }
        }
        out[x..x + LANES].copy_from_slice(&total);
        x += LANES;
    }
    for (i, o) in out.iter_mut().enumerate().skip(x) {
        let mut total = 0.0f32;
        for (t, v) in verticals.iter().enumerate() {
            total +=
                v.iter().enumerate().map(|(k, &c)| c * h[first + k * row_stride + t * term_stride + i]).sum::<f32>();
        }
        *o = total;
    }
}

/// `out[x] = Σ_k v[k]·src[x + k]`, sixteen outputs at a time in registers, four such blocks side by side
/// (`src` holds `out.len() + v.len() − 1` values). Every output's sum runs over `k` in order, whatever the
/// blocking.
#[inline(always)]
fn correlate_row(src: &[f32], v: &[f32], out: &mut [f32]) {
    const LANES: usize = 16;
    const WIDE: usize = 4 * LANES;
    let w = out.len();
    let taps = v.len();
    let mut x = 0;
    while x + WIDE <= w {
        let window = &src[x..x + WIDE + taps - 1];
        let mut acc = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        for (k, &c) in v.iter().enumerate() {
            add_four_blocks(&mut acc, c, window[k..k + WIDE].try_into().expect("four blocks of LANES"));
        }
        for (b, acc) in [acc.0, acc.1, acc.2, acc.3].iter().enumerate() {
            out[x + b * LANES..x + (b + 1) * LANES].copy_from_slice(acc);
        }
        x += WIDE;
    }
    while x + LANES <= w {
        let mut acc = [0.0f32; LANES];
        for (k, &c) in v.iter().enumerate() {
            let p: &[f32; LANES] = src[x + k..x + k + LANES].try_into().expect("a block of LANES");
            for j in 0..LANES {
                acc[j] += c * p[j];
            }
        }
        out[x..x + LANES].copy_from_slice(&acc);
        x += LANES;
    }
    for (i, o) in out.iter_mut().enumerate().skip(x) {
        *o = v.iter().enumerate().map(|(k, &c)| c * src[i + k]).sum();
    }
}

struct FftConvolution {
    width: usize,
    height: usize,
    radius: usize,
    /// The kernel's transform on the padded grid.
    kernel: Vec<Complex<f32>>,
    kernel_values: Vec<f32>,
    buf: Vec<Complex<f32>>,
}

impl std::fmt::Debug for FftConvolution {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FftConvolution({}×{}, radius {})", self.width, self.height, self.radius)
    }
}

impl Convolver {
    /// A convolver with no buffers yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Replaces `frame` by its convolution with `kernel` (edges replicated); strictly, the correlation
    /// `Σ_d K[d]·F(x + d)`, which is the convolution for an even kernel.
    pub fn apply(&mut self, kernel: &Kernel, frame: &mut Frame, method: ConvolutionMethod) {
        if kernel.radius == 0 {
            let k = kernel.values[0];
            if k != 1.0 {
                frame.pixels_mut().iter_mut().for_each(|p| *p *= k);
            }
            return;
        }
        match method {
            ConvolutionMethod::Separable if kernel.terms.is_empty() => self.direct(kernel, frame),
            ConvolutionMethod::Separable => self.separable(kernel, frame),
            ConvolutionMethod::Direct => self.direct(kernel, frame),
            ConvolutionMethod::Fft => self.fft(kernel, frame),
        }
    }

    /// The separable terms, in one parallel pass over bands of output rows: each band makes the horizontal
    /// pass of the rows it reads (its own rows and `r` more on each side, made again by the neighbouring band)
    /// and then the vertical pass of every term ([`vertical_terms`]). Every output is the same sum in the same
    /// order as a whole frame's horizontal pass followed by its vertical pass (one fork-join per frame instead
    /// of two per term, which on a small frame cost more than the arithmetic).
    fn separable(&mut self, kernel: &Kernel, frame: &mut Frame) {
        let (w, h) = (frame.width(), frame.height());
        if w == 0 || h == 0 {
            return;
        }
        let r = kernel.radius;
        // bands of several times the halo, a few per thread
        let band = h.div_ceil(4 * rayon::current_num_threads()).max(4 * r).max(1);
        // every output is written (not added to): the buffer's old values do not matter
        self.acc.resize(w * h, 0.0);
        let src = frame.pixels();
        let terms = kernel.terms.len();
        self.acc.par_chunks_mut(w * band).enumerate().for_each(|(b, out)| {
            SEPARABLE_BAND.with_borrow_mut(|(pad, tmp)| {
                pad.resize(w + 2 * r, 0.0);
                let (y0, rows) = (b * band, out.len() / w);
                // band row k of `tmp` holds every term's horizontal pass of frame row y0 + k − r (clamped to the
                // frame), term after term
                tmp.resize((rows + 2 * r) * terms * w, 0.0);
                for (k, line) in tmp.chunks_exact_mut(terms * w).enumerate() {
                    let sy = (y0 + k).saturating_sub(r).min(h - 1);
                    pad_span(&src[sy * w..(sy + 1) * w], 0, r, pad);
                    for ((_, v), out) in kernel.terms.iter().zip(line.chunks_exact_mut(w)) {
                        widest(
                            #[inline(always)]
                            || correlate_row(pad, v, out),
                        );
                    }
                }
                // vertical pass, scaled by λ, the terms added in turn; 64 columns down the band at a time, so that
                // an output row's taps stay in the first-level cache
                widest(
                    #[inline(always)]
                    || {
                        for c0 in (0..w).step_by(VERTICAL_COLUMNS) {
                            let c1 = (c0 + VERTICAL_COLUMNS).min(w);
                            for (y, line) in out.chunks_exact_mut(w).enumerate() {
                                let first = y * terms * w + c0;
                                vertical_terms(tmp, first, [terms * w, w], &kernel.vertical, &mut line[c0..c1]);
                            }
                        }
                    },
                );
            });
        });
        // the sums are the frame now; its old pixels are the next blur's buffer
        frame.swap_pixels(&mut self.acc);
    }

    /// As [`Convolver::apply`], only on the tiles of [`BLUR_TILE_PX`] px where the blur can change a pixel by
    /// more than `skip_below` (the frame's units); the other tiles keep their values.
    ///
    /// For a symmetric kernel `K` the blur changes a pixel by `½·Σ_d K(d)·(F(x+d) + F(x−d) − 2·F(x))`. For
    /// `d = (a, b)` that sum splits exactly into second differences along the axes (`a²` and `b²` of them, with
    /// weights summing to those) and `2·|a·b|` mixed differences of 2 × 2 cells, so the change is at most
    /// `½·Σ K·(a²·D_xx + b²·D_yy + 2·|a·b|·D_xy) ≤ ¼·M₂·D`, with `M₂ = Σ K·|d|²` and `D` the largest
    /// `|F_xx| + |F_yy| + 2·|F_xy|` within the kernel's reach. A tile is blurred when that bound, with `D` taken
    /// over the tile and its neighbours within the kernel radius, exceeds `skip_below`. Mostly blurred frames take
    /// the whole-frame method.
    pub fn apply_where_needed(
        &mut self,
        kernel: &Kernel,
        frame: &mut Frame,
        method: ConvolutionMethod,
        skip_below: f32,
    ) -> BlurStats {
        self.apply_where_needed_in(kernel, frame, method, skip_below, None)
    }

    /// As [`Convolver::apply_where_needed`], deciding only on the tiles whose entry in `candidates` (row-major,
    /// `⌈width/BLUR_TILE_PX⌉` per row) is true: the others are not counted and may keep their values or be
    /// blurred (when the whole-frame method is cheaper), so the caller overwrites them afterwards.
    pub fn apply_where_needed_in(
        &mut self,
        kernel: &Kernel,
        frame: &mut Frame,
        method: ConvolutionMethod,
        skip_below: f32,
        candidates: Option<&[bool]>,
    ) -> BlurStats {
        let (w, h) = (frame.width(), frame.height());
        let t = BLUR_TILE_PX;
        let (tw, th) = (w.div_ceil(t), h.div_ceil(t));
        let tiles = tw * th;
        let candidate = |i: usize| candidates.is_none_or(|c| c[i]);
        let considered = (0..tiles).filter(|&i| candidate(i)).count();
        if considered == 0 {
            return BlurStats { tiles_needed: 0, tiles_blurred: 0, tiles };
        }
        if kernel.radius == 0 || !(skip_below > 0.0) {
            self.apply(kernel, frame, method);
            return BlurStats { tiles_needed: considered, tiles_blurred: considered, tiles };
        }
        let reach = kernel.radius.div_ceil(t);
        // curvature only on the tiles a candidate's reach covers
        match candidates {
            Some(c) => tiles_within_reach(c, tw, reach, &mut self.along_flags, &mut self.wanted),
            None => {
                self.wanted.clear();
                self.wanted.resize(tiles, true);
            }
        }
        tile_curvature(frame, &self.wanted, &mut self.rough);
        // NaN counts as rough; then each tile's largest within `reach` tiles on either axis: along each row of
        // tiles, then down the columns (a max is the same in either order)
        for r in &mut self.rough {
            if r.is_nan() {
                *r = f32::INFINITY;
            }
        }
        join_within_reach(&self.rough, tw, reach, (0.0, f32::max), &mut self.along, &mut self.worst);
        let factor = (0.25 * kernel.second_moment_px2) as f32;
        self.needed.clear();
        self.needed
            .extend(self.worst.iter().enumerate().map(|(i, &worst)| candidate(i) && !(worst * factor <= skip_below)));
        let blurred = self.needed.iter().filter(|&&n| n).count();
        if blurred == 0 {
            return BlurStats { tiles_needed: 0, tiles_blurred: 0, tiles };
        }
        if 2 * blurred > tiles {
            self.apply(kernel, frame, method);
            return BlurStats { tiles_needed: blurred, tiles_blurred: considered, tiles };
        }
        let r = kernel.radius;
        // only the padded rows the blurred tiles' bands read
        let needed_tiles = std::mem::take(&mut self.needed);
        let needed = &needed_tiles;
        let band_needed = |ty: usize| needed[ty * tw..(ty + 1) * tw].iter().any(|&n| n);
        // the first and last bands blurred (there is one: `blurred > 0`), and the padded rows they read
        let (first_band, last_band) =
            ((0..th).find(|&ty| band_needed(ty)).unwrap_or(0), (0..th).rfind(|&ty| band_needed(ty)).unwrap_or(0));
        let padded_rows = first_band * t..(last_band * t + t + 2 * r).min(h + 2 * r);
        // padded row py is read by the bands ty with ty·t ≤ py < ty·t + t + 2r
        let bands_reading = |py: usize| py.saturating_sub(t + 2 * r - 1) / t..=(py / t).min(th - 1);
        let src = frame.pixels();
        // each padded row's horizontal pass, every term, once: on the tiles' columns that any band reading the
        // row blurs (rows shared by the bands of a horizontal edge are not made again for each band); the same
        // sums, pixel by pixel, as a band's own pass (a run starts on a tile's edge, a multiple of the rows' 16
        // lanes)
        let terms = kernel.terms.len();
        self.horizontal.resize((h + 2 * r) * terms * w, 0.0);
        // a few rows a task: the rows to blur are often one strip of the frame, which in a handful of large tasks
        // fell to one thread
        let rows_made = &mut self.horizontal[padded_rows.start * terms * w..padded_rows.end * terms * w];
        rows_made.par_chunks_mut(terms * w).enumerate().with_max_len(split_finely(BLUR_TILE_PX / 2)).for_each(
            |(k, row)| {
                let py = padded_rows.start + k;
                BLURRED_COLUMNS.with_borrow_mut(|(columns, pad)| {
                    columns.clear();
                    columns.resize(tw, false);
                    for ty in bands_reading(py) {
                        for (c, &n) in columns.iter_mut().zip(&needed[ty * tw..(ty + 1) * tw]) {
                            *c |= n;
                        }
                    }
                    // frame row py − r (the edge rows replicated beyond the frame), padded here on the run's
                    // columns alone: the values a padded copy of the frame would hold
                    let line = &src[py.saturating_sub(r).min(h - 1) * w..][..w];
                    for run in true_runs(columns) {
                        let x0 = run.start * t;
                        let cols = (run.end * t).min(w) - x0;
                        pad.resize(cols + 2 * r, 0.0);
                        pad_span(line, x0, r, pad);
                        for ((_, v), out) in kernel.terms.iter().zip(row.chunks_exact_mut(w)) {
                            widest(
                                #[inline(always)]
                                || correlate_row(pad, v, &mut out[x0..x0 + cols]),
                            );
                        }
                    }
                });
            },
        );
        // the vertical pass in pieces of at most 4 tiles of a band's runs, each its own task: the tiles to blur
        // (the sky image's edges) often lie in a few bands, which as whole tasks left one thread doing most of the
        // pass (a pool of one sweeps each run whole)
        let piece_tiles = split_finely(4);
        self.pieces.clear();
        for ty in 0..th {
            for run in true_runs(&needed[ty * tw..(ty + 1) * tw]) {
                for first in run.clone().step_by(piece_tiles) {
                    let x0 = first * t;
                    let cols = (first.saturating_add(piece_tiles).min(run.end) * t).min(w) - x0;
                    self.pieces.push((ty, x0, cols));
                }
            }
        }
        // each piece's rows of the frame (the pieces of a band are consecutive, left to right), written by the
        // piece's own task: the sums go straight into the frame, not through a buffer copied in afterwards (which
        // another core had written)
        let pieces = &self.pieces;
        debug_assert!(pieces.windows(2).all(|p| (p[0].0, p[0].1 + p[0].2) <= (p[1].0, p[1].1)), "pieces in order");
        // piece p's row y of the frame at p·t + y (a partial last band leaves its pieces' last entries empty)
        let mut segments: Vec<Option<&mut [f32]>> = Vec::new();
        segments.resize_with(pieces.len() * t, || None);
        let bands = &mut frame.pixels_mut()[first_band * t * w..((last_band + 1) * t * w).min(w * h)];
        let mut next = 0;
        for (k, band) in bands.chunks_mut(t * w).enumerate() {
            let first = next;
            while next < pieces.len() && pieces[next].0 == first_band + k {
                next += 1;
            }
            for (y, row) in band.chunks_mut(w).enumerate() {
                let (mut rest, mut at) = (row, 0);
                for (p, &(_, x0, cols)) in pieces.iter().enumerate().take(next).skip(first) {
                    let (segment, after) = std::mem::take(&mut rest)[x0 - at..].split_at_mut(cols);
                    segments[p * t + y] = Some(segment);
                    (rest, at) = (after, x0 + cols);
                }
            }
        }
        let horizontal = &self.horizontal;
        segments.par_chunks_mut(t).zip(pieces.par_iter()).with_max_len(split_finely(1)).for_each(
            |(rows, &(ty, x0, cols))| {
                widest(
                    #[inline(always)]
                    || {
                        // a few tiles' columns down all the rows, then the next few: the rows one output row
                        // reads (every term's taps) stay in the first-level cache (a pool of one takes whole runs)
                        for c0 in (0..cols).step_by(VERTICAL_COLUMNS) {
                            let c1 = (c0 + VERTICAL_COLUMNS).min(cols);
                            for (y, out) in rows.iter_mut().flatten().enumerate() {
                                let first = (ty * t + y) * terms * w + x0 + c0;
                                vertical_terms(horizontal, first, [terms * w, w], &kernel.vertical, &mut out[c0..c1]);
                            }
                        }
                    },
                );
            },
        );
        self.needed = needed_tiles;
        BlurStats { tiles_needed: blurred, tiles_blurred: blurred, tiles }
    }

    /// Copies `frame` into `self.padded` with `r` replicated pixels on every side; returns the padded width.
    fn pad(&mut self, frame: &Frame, r: usize) -> usize {
        let (w, h) = (frame.width(), frame.height());
        let pw = w + 2 * r;
        self.padded.resize(pw * (h + 2 * r), 0.0);
        let src = frame.pixels();
        self.padded.par_chunks_mut(pw).enumerate().with_max_len(split_finely(BLUR_TILE_PX)).for_each(|(py, out)| {
            let y = py.saturating_sub(r).min(h - 1);
            pad_span(&src[y * w..(y + 1) * w], 0, r, out);
        });
        pw
    }

    fn direct(&mut self, kernel: &Kernel, frame: &mut Frame) {
        let (w, r) = (frame.width(), kernel.radius);
        let pw = self.pad(frame, r);
        let side = 2 * r + 1;
        let padded = &self.padded;
        let rows_per_task = rows_per_task(w, side * side);
        frame.pixels_mut().par_chunks_mut(w).enumerate().with_min_len(rows_per_task).for_each(|(y, out)| {
            out.fill(0.0);
            for dy in 0..side {
                let row = &padded[(y + dy) * pw..(y + dy + 1) * pw];
                for dx in 0..side {
                    let c = kernel.values[dy * side + dx];
                    for (o, &p) in out.iter_mut().zip(&row[dx..dx + w]) {
                        *o += c * p;
                    }
                }
            }
        });
    }

    fn fft(&mut self, kernel: &Kernel, frame: &mut Frame) {
        let (w, h, r) = (frame.width(), frame.height(), kernel.radius);
        let (pw, ph) = (fast_len(w + 2 * r), fast_len(h + 2 * r));
        let stale = match &self.fft {
            Some(f) => f.width != w || f.height != h || f.radius != r || f.kernel_values != kernel.values,
            None => true,
        };
        if stale {
            // the kernel, centred at the origin of the padded grid and mirrored, so that the product of the
            // transforms gives the correlation `Σ K[d]·F(x + d)` as the direct and separable methods do (the
            // same as the convolution for the PSF's even kernels)
            let mut k = vec![Complex::new(0.0f32, 0.0); pw * ph];
            let side = 2 * r + 1;
            for dy in 0..side {
                for dx in 0..side {
                    let x = (r as isize - dx as isize).rem_euclid(pw as isize) as usize;
                    let y = (r as isize - dy as isize).rem_euclid(ph as isize) as usize;
                    k[y * pw + x] = Complex::new(kernel.values[dy * side + dx], 0.0);
                }
            }
            fft2(&mut k, pw, ph, rustfft::FftDirection::Forward);
            self.fft = Some(FftConvolution {
                width: w,
                height: h,
                radius: r,
                kernel: k,
                kernel_values: kernel.values.clone(),
                buf: vec![Complex::new(0.0, 0.0); pw * ph],
            });
        }
        let f = self.fft.as_mut().expect("set above");
        // the frame padded by replication to the transform size (the extra columns and rows replicate too)
        let src = frame.pixels();
        for py in 0..ph {
            let y = py.saturating_sub(r).min(h - 1);
            for px in 0..pw {
                let x = px.saturating_sub(r).min(w - 1);
                f.buf[py * pw + px] = Complex::new(src[y * w + x], 0.0);
            }
        }
        fft2(&mut f.buf, pw, ph, rustfft::FftDirection::Forward);
        for (b, k) in f.buf.iter_mut().zip(&f.kernel) {
            *b *= k;
        }
        fft2(&mut f.buf, pw, ph, rustfft::FftDirection::Inverse);
        let scale = 1.0 / (pw * ph) as f32;
        let out = frame.pixels_mut();
        for y in 0..h {
            for x in 0..w {
                out[y * w + x] = f.buf[(y + r) * pw + x + r].re * scale;
            }
        }
    }
}

/// The smallest `2^a·3^b·5^c` not below `n`.
pub(crate) fn fast_len(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustfft::FftPlanner;

    #[test]
    fn the_banded_separable_pass_is_the_whole_frame_passes_bit_for_bit_on_any_number_of_threads() {
        // a kernel of several separable terms (an asymmetric blob), frames narrower and shorter than the halo
        let r = 4;
        let side = 2 * r + 1;
        let values: Vec<f64> = (0..side * side)
            .map(|i| {
                let (x, y) = ((i % side) as f64 - 4.0, (i / side) as f64 - 4.0);
                (-(x * x) / 5.0 - (y * y) / 3.0 - 0.3 * x * y).exp() + 0.01 * ((i * 7) % 5) as f64
            })
            .collect();
        let kernel = Kernel::from_values(r, &values);
        assert!(kernel.terms.len() >= 3, "{} terms", kernel.terms.len());
        for (w, h) in [(37, 53), (130, 9), (5, 3), (64, 1)] {
            let frame: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 101) as f32 * 0.5 + (i / w) as f32).collect();
            // the whole frame's horizontal pass, term by term, then its vertical pass, accumulated from 0
            let mut want = vec![0.0f32; w * h];
            for ((_, v), scaled) in kernel.terms.iter().zip(&kernel.vertical) {
                let horizontal: Vec<f32> = (0..h)
                    .flat_map(|y| {
                        let row = &frame[y * w..(y + 1) * w];
                        let mut pad = vec![row[0]; r];
                        pad.extend_from_slice(row);
                        pad.extend(std::iter::repeat_n(row[w - 1], r));
                        let mut out = vec![0.0f32; w];
                        correlate_row(&pad, v, &mut out);
                        out
                    })
                    .collect();
                for (y, out) in want.chunks_exact_mut(w).enumerate() {
                    let rows: Vec<&[f32]> = (0..side)
                        .map(|k| {
                            let sy = (y + k).saturating_sub(r).min(h - 1);
                            &horizontal[sy * w..(sy + 1) * w]
                        })
                        .collect();
                    accumulate_rows(&rows, scaled, out);
                }
            }
            for threads in [1, 2, 5] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut f = Frame::from_pixels(w, h, frame.clone());
                pool.install(|| Convolver::default().apply(&kernel, &mut f, ConvolutionMethod::Separable));
                let same = f.pixels().iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{w} × {h} on {threads} threads");
            }
        }
    }

    #[test]
    fn runs_and_reach_of_flagged_tiles() {
        let f = [false, true, true, false, true, false, false, true];
        assert_eq!(true_runs(&f).collect::<Vec<_>>(), vec![1..3, 4..5, 7..8]);
        assert_eq!(true_runs(&[]).count(), 0);
        // a 4 × 2 grid with one flagged tile: reach 1 covers its neighbours on either axis and diagonally
        let grid = [false, false, false, false, false, false, true, false];
        let (mut along, mut out) = (Vec::new(), Vec::new());
        tiles_within_reach(&grid, 4, 1, &mut along, &mut out);
        assert_eq!(out, vec![false, true, true, true, false, true, true, true]);
        tiles_within_reach(&grid, 4, 0, &mut along, &mut out);
        assert_eq!(out, grid.to_vec());
    }

    #[test]
    fn rows_then_columns_give_the_square_window() {
        // grids of several widths (the last row whole or short), sparse and dense flags and measures (NaN as ∞,
        // as the blur's decision takes it), against each tile's square of tiles within reach
        let mut rng = crate::physics::random::SplitMix64::new(17);
        let (mut along, mut out, mut along_f, mut out_f) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (tiles_x, len) in [(1, 5), (4, 8), (7, 35), (7, 33), (40, 32 * 40), (9, 1)] {
            for reach in 0..4 {
                for density in [0.05, 0.5] {
                    let flags: Vec<bool> = (0..len).map(|_| rng.uniform_open0() < density).collect();
                    let values: Vec<f32> = (0..len)
                        .map(|_| if rng.uniform_open0() < 0.02 { f32::INFINITY } else { rng.uniform_open0() as f32 })
                        .collect();
                    tiles_within_reach(&flags, tiles_x, reach, &mut along, &mut out);
                    join_within_reach(&values, tiles_x, reach, (0.0, f32::max), &mut along_f, &mut out_f);
                    for i in 0..len {
                        let (ty, tx) = (i / tiles_x, i % tiles_x);
                        let square = (0..len).filter(|&j| {
                            let (y, x) = (j / tiles_x, j % tiles_x);
                            y.abs_diff(ty) <= reach && x.abs_diff(tx) <= reach
                        });
                        let what = format!("{tiles_x} wide, {len} tiles, reach {reach}, tile {i}");
                        assert_eq!(out[i], square.clone().any(|j| flags[j]), "{what}");
                        assert_eq!(out_f[i], square.fold(0.0f32, |m, j| m.max(values[j])), "{what}");
                    }
                    assert_eq!((out.len(), out_f.len()), (len, len));
                }
            }
        }
    }

    #[test]
    fn values_on_a_grid_are_the_values_one_by_one() {
        let psf = Psf::new(&PsfSpec::default(), &optics(1.0, Band::LWIR_8_12)).unwrap();
        let reach = psf.radius_px() as f64 + 0.5;
        // inside, on the table's edges and beyond them, at odd steps
        let xs: Vec<f64> = (0..97).map(|a| -reach - 0.3 + a as f64 * (2.0 * reach + 0.6) / 96.0).collect();
        let ys: Vec<f64> = (0..61).map(|b| -reach - 0.2 + b as f64 * (2.0 * reach + 0.5) / 60.0).collect();
        let grid = psf.values_on_grid(&xs, &ys);
        assert_eq!(grid.len(), xs.len() * ys.len());
        let mut inside = 0;
        for (b, &y) in ys.iter().enumerate() {
            for (a, &x) in xs.iter().enumerate() {
                let one = psf.value(x, y);
                assert_eq!(grid[b * xs.len() + a].to_bits(), one.to_bits(), "({x}, {y})");
                inside += usize::from(one != 0.0);
            }
        }
        assert!(inside > xs.len() * ys.len() / 2 && inside < xs.len() * ys.len(), "{inside} inside");
    }

    fn optics(f_number: f64, band: Band) -> PsfOptics {
        PsfOptics {
            f_number,
            pixel_pitch_m: 12e-6,
            fill_factor: 1.0,
            band,
            measure: Measure::Energy,
            reference_temp_k: 300.0,
        }
    }

    /// The PSF's grid as first written: the OTF at every frequency, negative ones included, and a 2D FFT whose
    /// transposes swap in place.
    fn spatial_direct(otf: &Otf, per_px: usize, aperture: bool, tent: bool) -> Vec<f32> {
        let n = PERIOD_PX * per_px;
        let freq = |k: usize| if k < n / 2 { k as f64 } else { k as f64 - n as f64 } / PERIOD_PX as f64;
        let mut data: Vec<Complex<f64>> = Vec::with_capacity(n * n);
        for ky in 0..n {
            for kx in 0..n {
                let (fx, fy) = (freq(kx), freq(ky));
                data.push(Complex::new(otf.with_apertures(otf.radial(fx, fy), fx, fy, aperture, tent), 0.0));
            }
        }
        let fft = FftPlanner::new().plan_fft(n, rustfft::FftDirection::Inverse);
        for _ in 0..2 {
            data.chunks_mut(n).for_each(|row| fft.process(row));
            for y in 0..n {
                for x in y + 1..n {
                    data.swap(y * n + x, x * n + y);
                }
            }
        }
        let scale = 1.0 / (PERIOD_PX * PERIOD_PX) as f64;
        data.iter().map(|c| (c.re * scale) as f32).collect()
    }

    #[test]
    fn the_grids_from_the_folded_otf_are_the_direct_ones_bit_for_bit() {
        let spec = PsfSpec { aberration_sigma_px: 0.3, ..PsfSpec::default() };
        let mut o = optics(2.0, Band::LWIR_8_12);
        o.fill_factor = 0.8;
        let otf = Otf::new(&spec, &o);
        assert!(!otf.diffraction.is_empty() && otf.aperture_px > 0.0);
        let half = PERIOD_PX * 3 / 2 + 1;
        let radial = otf.radial_quadrant(half);
        for (per_px, aperture, tent) in [(1, true, true), (2, false, true), (3, true, false), (2, false, false)] {
            let got = otf.spatial(per_px, aperture, tent, &radial, half, None);
            let want = spatial_direct(&otf, per_px, aperture, tent);
            assert_eq!(got.len(), want.len());
            let same = got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "{per_px} per px, aperture {aperture}, tent {tent}");
            // the offsets within a reach alone: theirs the same bits, the others 0
            let n = PERIOD_PX * per_px;
            let reach = n / 5;
            let part = otf.spatial(per_px, aperture, tent, &radial, half, Some(reach));
            let within = |k: usize| k <= reach || k >= n - reach;
            for (i, (a, b)) in part.iter().zip(&want).enumerate() {
                let (x, y) = (i % n, i / n);
                let want = if within(x) && within(y) { b.to_bits() } else { 0 };
                assert_eq!(a.to_bits(), want, "{per_px} per px, column {x}, row {y}");
            }
        }
    }

    #[test]
    fn psf_integrates_to_one() {
        let psf = Psf::new(&PsfSpec::default(), &optics(1.0, Band::LWIR_8_12)).unwrap();
        assert!((psf.integral() - 1.0).abs() < 1e-5, "{}", psf.integral());
        for k in [psf.point_kernel(), psf.area_kernel()] {
            let s: f64 = k.values().iter().map(|&v| f64::from(v)).sum();
            assert!((s - 1.0).abs() < 1e-6, "{s}");
        }
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_vector_rows_of_a_point_are_the_scalar_loop_bit_for_bit() {
        let avx512 = is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512dq")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512vl");
        let avx2 = is_x86_feature_detected!("avx2");
        let table: Vec<f32> = (0..4000).map(|i| (i as f32 * 0.731).sin() * 3.0 + 4.0).collect();
        let (steps, width, starts, weights) = (50, 37, [3, 1007, 2011, 2999], [0.3125f32, 0.71, 1.7]);
        // rows of every length up to 20 pixels (whole blocks and masked tails), one to three rows
        for n in 1..=20 {
            for count in 1..=3 {
                let before: Vec<f32> = (0..width * count).map(|i| i as f32 * 0.01).collect();
                let mut scalar = before.clone();
                for r in 0..count {
                    for k in 0..n {
                        let at = |s: usize| table[s + r * steps + k];
                        let (a, b, c, d) = (at(starts[0]), at(starts[1]), at(starts[2]), at(starts[3]));
                        let t = a + (b - a) * weights[0];
                        let bottom = c + (d - c) * weights[0];
                        scalar[r * width + k] += weights[2] * (t + (bottom - t) * weights[1]);
                    }
                }
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                if avx512 {
                    let mut vector = before.clone();
                    // SAFETY: AVX-512 checked above; every row read and written lies inside its buffer
                    unsafe { x86::add_rows_512(&table, starts, steps, &mut vector, width, n, count, weights) };
                    assert_eq!(bits(&vector), bits(&scalar), "avx512, {n} px, {count} rows");
                }
                if avx2 {
                    let mut vector = before.clone();
                    // SAFETY: AVX2 checked above; as above
                    unsafe { x86::add_rows_256(&table, starts, steps, &mut vector, width, n, count, weights) };
                    assert_eq!(bits(&vector), bits(&scalar), "avx2, {n} px, {count} rows");
                }
            }
        }
    }

    #[test]
    fn add_point_matches_value_at_every_pixel_centre() {
        let psf = Psf::new(&PsfSpec::default(), &optics(1.0, Band::LWIR_8_12)).unwrap();
        let (w, h) = (23, 19);
        for (x, y) in [(11.3, 9.7), (0.02, 18.99), (-3.4, 4.5), (25.0, -2.2), (11.5, 9.5), (4.0, 3.0)] {
            let mut out = vec![0.0f32; w * h];
            psf.add_point(x, y, 2.0, [0, 0, w, h], &mut out, w);
            for py in 0..h {
                for px in 0..w {
                    let want = 2.0 * psf.value(px as f64 + 0.5 - x, py as f64 + 0.5 - y);
                    let got = out[py * w + px];
                    assert!(
                        (got - want).abs() <= 1e-6 * want.abs().max(1e-3),
                        "({x}, {y}) px ({px}, {py}): {got} vs {want}"
                    );
                }
            }
            // a sub-rectangle at an offset in a wider buffer
            let mut sub = vec![0.0f32; 40 * 10];
            psf.add_point(x, y, 2.0, [5, 4, 15, 12], &mut sub, 40);
            for py in 4..12 {
                for px in 5..15 {
                    assert_eq!(sub[(py - 4) * 40 + px - 5], out[py * w + px]);
                }
            }
        }
    }

    #[test]
    fn airy_fwhm_matches_the_formula() {
        // diffraction only, a narrow band at 10 µm: FWHM = 1.029 λN
        let spec = PsfSpec { pixel_aperture: false, aberration_sigma_px: 0.0, ..PsfSpec::default() };
        for n in [2.0, 4.0] {
            let band = Band::try_new(10.0, 10.001).unwrap();
            let psf = Psf::new(&spec, &optics(n, band)).unwrap();
            let want = 1.029 * 10e-6 * n / 12e-6;
            let got = psf.fwhm_px();
            assert!(((got - want) / want).abs() < 0.01, "F/{n}: FWHM {got} px, Airy {want} px");
        }
    }

    #[test]
    fn separable_direct_and_fft_agree() {
        let psf = Psf::new(&PsfSpec::default(), &optics(1.5, Band::LWIR_8_12)).unwrap();
        let (w, h) = (70, 45);
        let base = Frame::from_pixels(
            w,
            h,
            (0..w * h).map(|i| ((i * 7919) % 1000) as f32 + if (i % w) > 30 { 500.0 } else { 0.0 }).collect(),
        );
        let mut c = Convolver::new();
        let mut out = Vec::new();
        for m in [ConvolutionMethod::Direct, ConvolutionMethod::Separable, ConvolutionMethod::Fft] {
            let mut f = base.clone();
            c.apply(psf.point_kernel(), &mut f, m);
            out.push(f);
        }
        for f in &out[1..] {
            let worst = f.pixels().iter().zip(out[0].pixels()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(worst < 0.2, "worst difference {worst} on values up to 1500");
        }
        // a constant frame stays constant (edges replicated, kernel sums to 1)
        let mut flat = Frame::from_pixels(w, h, vec![123.0; w * h]);
        c.apply(psf.point_kernel(), &mut flat, ConvolutionMethod::Separable);
        assert!(flat.pixels().iter().all(|v| (v - 123.0).abs() < 1e-3));
    }

    #[test]
    fn tiles_blurred_where_needed_are_the_separable_sums_bit_for_bit() {
        // candidate tiles alone, in a row, in a column, in a block, at the right and bottom edges (partial
        // tiles), in a run wider than the vertical pass's column steps: every pixel of a blurred tile is the
        // kernel's sums in their order (horizontal per term, then vertical, terms added in turn), whichever band
        // shares its rows and however many threads split the pieces; the other tiles are untouched
        let psf = Psf::new(&PsfSpec::default(), &optics(4.0, Band::MWIR_3_5)).unwrap();
        let kernel = psf.point_kernel();
        assert!(
            kernel.rank() > 1 && kernel.radius() >= BLUR_TILE_PX / 2,
            "rank {}, radius {}",
            kernel.rank(),
            kernel.radius()
        );
        let (w, h) = (150usize, 133usize);
        let t = BLUR_TILE_PX;
        let (tw, th) = (w.div_ceil(t), h.div_ceil(t));
        let base =
            Frame::from_pixels(w, h, (0..w * h).map(|i| 1000.0 + ((i * 7919 + 13) % 997) as f32 * 0.1).collect());
        let mut everywhere = vec![false; tw * th];
        for (tx, ty) in [(1, 1), (3, 2), (4, 2), (5, 2), (7, 3), (7, 4), (7, 5), (1, 6), (2, 6), (1, 7), (2, 7)] {
            everywhere[ty * tw + tx] = true;
        }
        everywhere[(th - 1) * tw + tw - 1] = true;
        everywhere[tw - 1] = true;
        // the bottom band's partial tiles, seven of them: 102 columns, more than one step of the vertical pass
        for tx in 3..tw - 1 {
            everywhere[(th - 1) * tw + tx] = true;
        }
        assert!((tw - 3) * t > VERTICAL_COLUMNS);
        // and two bands alone, neither the first nor the last, with bands between them that blur nothing: a
        // whole band (150 columns, more than two steps) and a tile
        let mut two_bands = vec![false; tw * th];
        two_bands[2 * tw..3 * tw].fill(true);
        two_bands[5 * tw + 4] = true;
        for candidates in [everywhere, two_bands] {
            let mut frames = Vec::new();
            for threads in [1, 2, 3] {
                let (frame, stats) = blur_candidates_on(threads, kernel, &base, &candidates);
                assert_eq!(stats.tiles_blurred, candidates.iter().filter(|&&c| c).count());
                frames.push(frame);
            }
            for f in &frames[1..] {
                assert!(f.pixels().iter().zip(frames[0].pixels()).all(|(a, b)| a.to_bits() == b.to_bits()));
            }
            assert_blurred_where_needed(kernel, &base, &frames[0], &candidates, true);
        }
    }

    /// `base` blurred where needed on the `candidates` tiles (every one of them rough enough at a threshold of
    /// 1e-6), by a fresh convolver on a pool of `threads`.
    fn blur_candidates_on(threads: usize, kernel: &Kernel, base: &Frame, candidates: &[bool]) -> (Frame, BlurStats) {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let mut frame = base.clone();
        let stats = pool.install(|| {
            Convolver::new().apply_where_needed_in(
                kernel,
                &mut frame,
                ConvolutionMethod::Separable,
                1e-6,
                Some(candidates),
            )
        });
        (frame, stats)
    }

    /// The separable sums at pixel `(x, y)` of `base`, spelled out (horizontal per term from 0, then vertical
    /// from 0, the terms added to 0 in turn; the frame's edges replicated).
    fn separable_sum_at(kernel: &Kernel, base: &Frame, x: usize, y: usize) -> f32 {
        let (w, h, r) = (base.width() as isize, base.height() as isize, kernel.radius() as isize);
        let at = |x: isize, y: isize| base.get(x.clamp(0, w - 1) as usize, y.clamp(0, h - 1) as usize);
        let mut want = 0.0f32;
        for ((_, v), scaled) in kernel.terms.iter().zip(&kernel.vertical) {
            let mut term = 0.0f32;
            for (k, &c) in scaled.iter().enumerate() {
                let row = y as isize + k as isize - r;
                let mut across = 0.0f32;
                for (j, &cj) in v.iter().enumerate() {
                    across += cj * at(x as isize + j as isize - r, row);
                }
                term += c * across;
            }
            want += term;
        }
        want
    }

    /// Every pixel of a candidate tile of `blurred` is [`separable_sum_at`] of `base`, to the bit; with
    /// `others_kept`, every other pixel is `base`'s.
    fn assert_blurred_where_needed(
        kernel: &Kernel,
        base: &Frame,
        blurred: &Frame,
        candidates: &[bool],
        others_kept: bool,
    ) {
        let (w, h, t) = (base.width(), base.height(), BLUR_TILE_PX);
        let tw = w.div_ceil(t);
        for y in 0..h {
            for x in 0..w {
                let got = blurred.get(x, y);
                if !candidates[(y / t) * tw + x / t] {
                    if others_kept {
                        assert_eq!(got.to_bits(), base.get(x, y).to_bits(), "{w} × {h}: ({x}, {y}) changed");
                    }
                    continue;
                }
                let want = separable_sum_at(kernel, base, x, y);
                assert_eq!(got.to_bits(), want.to_bits(), "{w} × {h}: ({x}, {y}): {got} vs {want}");
            }
        }
    }

    #[test]
    fn blurs_where_needed_of_random_sizes_and_tiles_are_the_separable_sums_bit_for_bit() {
        // 300 frames 1–90 px a side (many narrower or shorter than the kernel's reach, partial tiles), a random
        // third of their tiles candidates, on 1–3 threads: the blurred tiles are the sums to the bit, whether the
        // tiles alone are blurred or (most of the frame a candidate) the whole frame
        let psf = Psf::new(&PsfSpec::default(), &optics(4.0, Band::MWIR_3_5)).unwrap();
        let kernel = psf.point_kernel();
        let mut state = 12_345u64;
        let mut draw = |n: usize| {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            ((state >> 33) as usize) % n
        };
        let t = BLUR_TILE_PX;
        for case in 0..300 {
            let (w, h) = (1 + draw(90), 1 + draw(90));
            let pixels = (0..w * h).map(|i| 1000.0 + ((i * 7919 + case) % 997) as f32 * 0.1).collect();
            let base = Frame::from_pixels(w, h, pixels);
            let candidates: Vec<bool> = (0..w.div_ceil(t) * h.div_ceil(t)).map(|_| draw(3) == 0).collect();
            let (frame, stats) = blur_candidates_on(1 + draw(3), kernel, &base, &candidates);
            // the whole-frame method blurs the other tiles too
            let whole = 2 * stats.tiles_needed > stats.tiles;
            assert_blurred_where_needed(kernel, &base, &frame, &candidates, !whole);
        }
    }

    #[test]
    fn selective_blur_changes_skipped_tiles_by_less_than_the_threshold() {
        let psf = Psf::new(&PsfSpec::default(), &optics(1.0, Band::LWIR_8_12)).unwrap();
        let kernel = psf.point_kernel();
        let (w, h) = (100, 84);
        // a smooth ramp with weak texture, a bilinear-like kinked band, and a sharp cloud edge at the bottom right
        let field = |x: usize, y: usize| {
            let (fx, fy) = (x as f32, y as f32);
            let mut v = 1000.0 + 0.5 * fx + 0.002 * fy * fy + 0.3 * (0.05 * fx).sin();
            v += 0.4 * ((fx / 3.7).fract() - 0.5).abs();
            // pixel-scale texture in the top rows
            if y < 20 {
                v += 0.05 * ((x * 7919 + y * 104_729) % 1000) as f32 / 1000.0;
            }
            if x > 80 && y > 60 {
                v += 300.0;
            }
            v
        };
        let base = Frame::from_pixels(w, h, (0..w * h).map(|i| field(i % w, i / w)).collect());
        let mut full = base.clone();
        let mut c = Convolver::new();
        c.apply(kernel, &mut full, ConvolutionMethod::Separable);
        for skip in [0.05f32, 0.5, 2.0] {
            let mut sel = base.clone();
            let stats = c.apply_where_needed(kernel, &mut sel, ConvolutionMethod::Separable, skip);
            assert!(stats.tiles_blurred > 0 && stats.tiles_blurred <= stats.tiles, "{stats:?}");
            for i in 0..w * h {
                let (kept, blurred) = (sel.pixels()[i], full.pixels()[i]);
                if kept == base.pixels()[i] {
                    // a skipped pixel: the blur would have moved it by less than the threshold
                    assert!((blurred - kept).abs() <= skip, "skip {skip}: pixel {i} moves {}", blurred - kept);
                } else {
                    assert!((kept - blurred).abs() < 1e-3, "skip {skip}: pixel {i}: {kept} vs {blurred}");
                }
            }
        }
        // a ramp under a threshold above what the replicated edges' kinks give (0.3·1.1): nothing to do
        let smooth = Frame::from_pixels(w, h, (0..w * h).map(|i| 1000.0 + 0.3 * (i % w) as f32).collect());
        let mut f = smooth.clone();
        assert_eq!(c.apply_where_needed(kernel, &mut f, ConvolutionMethod::Separable, 0.5).tiles_blurred, 0);
        assert_eq!(f, smooth);
    }

    #[test]
    fn a_rough_or_nan_pixel_marks_the_tiles_it_reaches_and_the_blur_takes_those_within_reach() {
        // a ramp (no curvature) 100 × 84 px: 7 × 6 tiles of 16 px, the last column and row of tiles partial
        let (w, h) = (100, 84);
        let ramp = Frame::from_pixels(w, h, (0..w * h).map(|i| 1000.0 + 0.25 * (i % w) as f32).collect());
        let t = BLUR_TILE_PX;
        let tile = |x: usize, y: usize| (y / t) * w.div_ceil(t) + x / t;
        let psf = Psf::new(&PsfSpec::default(), &optics(1.0, Band::LWIR_8_12)).unwrap();
        let (kernel, mut convolver) = (psf.point_kernel(), Convolver::new());
        // a tile's first and last column and row, a partial tile's last pixel, two of the frame's corners
        for (x, y) in [(0, 0), (15, 20), (16, 31), (47, 47), (99, 83), (96, 70), (31, 64)] {
            for bad in [f32::NAN, 1100.0] {
                let mut f = ramp.clone();
                f.pixels_mut()[y * w + x] = bad;
                let mut rough = Vec::new();
                tile_curvature(&f, &[true; 42], &mut rough);
                // the pixel's own tile, and those whose pixels are its neighbours in the stencil
                let mut want = [false; 42];
                for (dx, dy) in [(0, 0), (-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1)] {
                    let (nx, ny) = (x as isize + dx, y as isize + dy);
                    if (0..w as isize).contains(&nx) && (0..h as isize).contains(&ny) {
                        want[tile(nx as usize, ny as usize)] = true;
                    }
                }
                for (i, &r) in rough.iter().enumerate() {
                    if !want[i] {
                        // the replicated edges' kinks give 0.25
                        assert!(r <= 0.25, "({x}, {y}) = {bad}: tile {i} {r}");
                    } else if bad.is_nan() {
                        assert!(r.is_nan(), "({x}, {y}): tile {i} {r}");
                    } else {
                        // a neighbour's second difference alone is over 75; the pixel's own, over 150
                        let least = if i == tile(x, y) { 150.0 } else { 70.0 };
                        assert!(r >= least, "({x}, {y}): tile {i} {r}");
                    }
                }
                // the blur's decision: every tile within the kernel's reach of those tiles, and no other
                let (mut along, mut reached) = (Vec::new(), Vec::new());
                tiles_within_reach(&want, w.div_ceil(t), kernel.radius().div_ceil(t), &mut along, &mut reached);
                convolver.apply_where_needed(kernel, &mut f.clone(), ConvolutionMethod::Separable, 0.5);
                assert_eq!(convolver.needed, reached, "({x}, {y}) = {bad}");
                // a tile that is not wanted stays at 0
                let mut some = [true; 42];
                some[tile(x, y)] = false;
                tile_curvature(&f, &some, &mut rough);
                assert_eq!(rough[tile(x, y)], 0.0);
            }
        }
    }

    #[test]
    fn photon_weights_shift_toward_long_waves() {
        let mut o = optics(2.0, Band::MWIR_3_5);
        let spec = PsfSpec { pixel_aperture: false, aberration_sigma_px: 0.0, ..PsfSpec::default() };
        let energy = Psf::new(&spec, &o).unwrap().fwhm_px();
        o.measure = Measure::Photon;
        let photon = Psf::new(&spec, &o).unwrap().fwhm_px();
        assert!(photon > energy, "{photon} vs {energy}");
    }

    #[test]
    fn jacobi_diagonalises() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 1.0];
        let (l, v) = jacobi_eigen(&a, 3);
        for k in 0..3 {
            for i in 0..3 {
                let av: f64 = (0..3).map(|j| a[i * 3 + j] * v[j * 3 + k]).sum();
                assert!((av - l[k] * v[i * 3 + k]).abs() < 1e-12);
            }
        }
    }
}
