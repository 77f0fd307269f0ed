//! Procedural cloud and haze layers: opacity and temperature fields whose power spectrum has a set slope.
//!
//! A layer is two fields on a periodic grid (so it tiles without seams): the opacity `α ∈ [0, 1]` of cloud or
//! haze, and a temperature offset `δT` (K) for the cloud's own texture. The sky plane turns them into radiance
//! over the clear-sky dome: `L = α·L_cloud + (1 − α)·L_dome` (see [`super::sky_plane`]).
//!
//! Both start from Gaussian random fields made by spectral synthesis: white complex noise shaped by
//! `|A(f)| ∝ max(f, f₀)^{β/2}` and transformed back, so the field's radially averaged power spectrum falls as
//! `f^β` above the outer scale `f₀ = 1/scale_px` and is flat below it.
//! - **Cumulus**: the field is thresholded at the quantile that leaves `cover` of the sky above it, with a
//!   smooth step `edge` field-standard-deviations wide: broken cloud with sharp edges. Thresholding flattens the
//!   spectrum (a sharp-edged region alone gives about −3 whatever its field), so the field's slope is chosen,
//!   from a measured table, so that the layer's comes out as asked; the reachable slopes span −3.06 to −2.39.
//!   Inside the clouds a second field (slope −3, a quarter of the scale) varies the
//!   cloud-base temperature by `texture_k` rms.
//! - **Clear**: a faint haze whose opacity is linear in the field, `α = haze·clip(0.5 + 0.25·g, 0, 1)`, so its
//!   spectrum has the asked slope directly: the weak large-scale texture of a clear sky.
//!
//! The radially averaged power spectrum of real infrared cloud clutter has a slope near −3 (sharp-edged
//! cumulus), the default.

use rustfft::num_complex::Complex;
use rustfft::{FftDirection, FftPlanner};
use serde::{Deserialize, Serialize};

use super::fft2d::fft_columns;
use crate::physics::ParamError;
use crate::physics::noise::{stage, standard_normal, stream_rng};

/// What kind of layer to make.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkyKind {
    /// A faint haze over the clear sky.
    Clear,
    /// Broken cumulus.
    Cumulus,
}

/// Parameters of a generated layer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkyGenSpec {
    /// Kind of layer.
    pub kind: SkyKind,
    /// Seed (combined with the scenario's).
    #[serde(default)]
    pub seed: u64,
    /// Slope of the layer's radially averaged power spectrum: [−3.06, −2.39] for cumulus, [−4.5, −1.5] for haze.
    #[serde(default = "default_slope")]
    pub psd_slope: f64,
    /// Fraction of the sky covered by cloud, [0, 1] (cumulus).
    #[serde(default = "default_cover")]
    pub cover: f64,
    /// Size of the largest features (the outer scale), as a fraction of the layer's width, (0, 1].
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Width of the cloud edge, in standard deviations of the cloud field, (0, 2].
    #[serde(default = "default_edge")]
    pub edge: f64,
    /// Rms of the cloud-base temperature texture, K, [0, 20].
    #[serde(default = "default_texture")]
    pub texture_k: f64,
    /// Largest opacity of the haze, [0, 1] (clear).
    #[serde(default = "default_haze")]
    pub haze: f64,
}

fn default_slope() -> f64 {
    -3.0
}
fn default_cover() -> f64 {
    0.4
}
fn default_scale() -> f64 {
    0.25
}
fn default_edge() -> f64 {
    0.05
}
fn default_texture() -> f64 {
    1.5
}
fn default_haze() -> f64 {
    0.1
}

impl SkyGenSpec {
    /// The defaults for `kind`.
    pub fn new(kind: SkyKind) -> Self {
        Self {
            kind,
            seed: 0,
            psd_slope: default_slope(),
            cover: default_cover(),
            scale: default_scale(),
            edge: default_edge(),
            texture_k: default_texture(),
            haze: default_haze(),
        }
    }

    /// Checks the parameters.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let check = ParamError::check_range;
        match self.kind {
            SkyKind::Cumulus => check("psd_slope", self.psd_slope, CUMULUS_SLOPES[0].0, CUMULUS_SLOPES[5].0)?,
            SkyKind::Clear => check("psd_slope", self.psd_slope, -4.5, -1.5)?,
        }
        check("cover", self.cover, 0.0, 1.0)?;
        check("scale", self.scale, 1e-3, 1.0)?;
        check("edge", self.edge, 1e-3, 2.0)?;
        check("texture_k", self.texture_k, 0.0, 20.0)?;
        check("haze", self.haze, 0.0, 1.0)
    }
}

/// A generated layer: opacity and temperature offset, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudLayer {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Opacity `α`, [0, 1].
    pub opacity: Vec<f32>,
    /// Temperature offset of the cloud, K.
    pub temp_offset_k: Vec<f32>,
}

/// Generates a `width × height` layer (periodic in both directions).
///
/// # Panics
/// If a size is 0.
pub fn generate(spec: &SkyGenSpec, width: usize, height: usize) -> CloudLayer {
    assert!(width > 0 && height > 0, "empty layer");
    let outer_px = (spec.scale * width as f64).max(2.0);
    match spec.kind {
        SkyKind::Cumulus => {
            let field_slope = cumulus_field_slope(spec.psd_slope);
            // the two fields side by side: each draws its noise on one thread (its own stream)
            let (opacity, temp_offset_k) = rayon::join(
                || {
                    let g = gaussian_field(width, height, field_slope, outer_px, spec.seed, 0);
                    let threshold = quantile(&g, 1.0 - spec.cover.clamp(0.0, 1.0));
                    let edge = spec.edge as f32;
                    g.iter()
                        .map(|&v| {
                            if spec.cover <= 0.0 {
                                0.0
                            } else if spec.cover >= 1.0 {
                                1.0
                            } else {
                                smoothstep((v - threshold) / edge)
                            }
                        })
                        .collect::<Vec<f32>>()
                },
                || {
                    let t = gaussian_field(width, height, -3.0, outer_px / 4.0, spec.seed, 1);
                    let k = spec.texture_k as f32;
                    t.iter().map(|&v| k * v).collect::<Vec<f32>>()
                },
            );
            CloudLayer { width, height, opacity, temp_offset_k }
        }
        SkyKind::Clear => {
            let g = gaussian_field(width, height, spec.psd_slope, outer_px, spec.seed, 0);
            let haze = spec.haze as f32;
            let opacity = g.iter().map(|&v| haze * (0.5 + 0.25 * v).clamp(0.0, 1.0)).collect();
            CloudLayer { width, height, opacity, temp_offset_k: vec![0.0; width * height] }
        }
    }
}

/// `(layer slope, field slope)`: the radially averaged spectrum of a thresholded layer (edge 0.05, outer scale
/// a quarter of the width, fitted over `[8/n, 0.25]` cycles/px) against the slope of the field thresholded,
/// measured on 1024² layers (three seeds × covers 0.2, 0.45, 0.7 each). Sharp edges hold the layer near −3
/// however steep the field, so the reachable range is narrow.
const CUMULUS_SLOPES: [(f64, f64); 6] =
    [(-3.06, -4.6), (-2.99, -4.3), (-2.90, -4.0), (-2.82, -3.8), (-2.67, -3.5), (-2.39, -3.0)];

/// The field slope that gives a cumulus layer of spectral slope `layer_slope` (piecewise-linear inverse of
/// [`CUMULUS_SLOPES`], clamped to its ends).
fn cumulus_field_slope(layer_slope: f64) -> f64 {
    let t = &CUMULUS_SLOPES;
    if layer_slope <= t[0].0 {
        return t[0].1;
    }
    for w in t.windows(2) {
        let ((l0, f0), (l1, f1)) = (w[0], w[1]);
        if layer_slope <= l1 {
            return f0 + (f1 - f0) * (layer_slope - l0) / (l1 - l0);
        }
    }
    t[t.len() - 1].1
}

fn smoothstep(x: f32) -> f32 {
    let t = x.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The value below which a fraction `q` of the field lies.
fn quantile(values: &[f32], q: f64) -> f32 {
    let mut scratch = values.to_vec();
    let i = ((scratch.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    *scratch.select_nth_unstable_by(i, f32::total_cmp).1
}

/// A periodic Gaussian random field, mean 0 and standard deviation 1, whose power spectrum falls as
/// `max(f, 1/outer_px)^slope`.
///
/// The spectrum's white noise is a function of the seed and of each frequency alone, in cycles per layer: the
/// row of vertical frequency `k_y` is drawn from its own stream (keyed by the place of `k_y` in the order
/// `0, 1, −1, 2, −2, …`), two normals per frequency, its horizontal frequencies in that order. A layer of any size
/// therefore holds the same coefficients at the frequencies it has, and each texel the field at its centre:
/// generated at half the size (and half the outer scale in texels) it is the same clouds, in the same place,
/// without their finest detail, not other clouds. The rows are
/// drawn and transformed on every thread without changing a bit (each row's stream is its own); then the
/// columns ([`fft_columns`]).
pub fn gaussian_field(width: usize, height: usize, slope: f64, outer_px: f64, seed: u64, substream: u64) -> Vec<f32> {
    use rayon::prelude::*;
    let f0 = 1.0 / outer_px.max(1.0);
    let (half_w, half_h) = (width / 2 + 1, height / 2 + 1);
    // |f| depends on |k_x| and |k_y| alone: the amplitude once per quadrant's texel
    let amplitude: Vec<f64> = (0..half_w * half_h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % half_w, i / half_w);
            let f = (x as f64 / width as f64).hypot(y as f64 / height as f64);
            if x == 0 && y == 0 { 0.0 } else { f.max(f0).powf(0.5 * slope) }
        })
        .collect();
    // texel i holds the field at its centre, (i + ½)/n of the layer: each coefficient turned by e^{iπk/n} on
    // both axes, so that every size samples the same field at its own texels' centres
    let turn = |k: i64, n: usize| Complex::from_polar(1.0, std::f64::consts::PI * k as f64 / n as f64);
    let column_turn: Vec<Complex<f64>> = (0..width).map(|x| turn(signed_frequency(x, width), width)).collect();
    let rows = FftPlanner::<f32>::new().plan_fft_inverse(width);
    let mut data = vec![Complex::new(0.0f32, 0.0); width * height];
    data.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let ky = signed_frequency(y, height);
        let amp_row = &amplitude[ky.unsigned_abs() as usize * half_w..][..half_w];
        let row_turn = turn(ky, height);
        let mut rng = stream_rng(seed, stage::SKY, frequency_order(ky), substream);
        for p in 0..width as u64 {
            // the p-th horizontal frequency of the order 0, 1, −1, 2, −2, …, at its index in the row
            let kx = if p % 2 == 1 { p.div_ceil(2) as i64 } else { -((p / 2) as i64) };
            let x = kx.rem_euclid(width as i64) as usize;
            let amp = amp_row[kx.unsigned_abs() as usize];
            let (re, im) = (standard_normal(&mut rng), standard_normal(&mut rng));
            let c = Complex::new(amp * re, amp * im) * row_turn * column_turn[x];
            row[x] = Complex::new(c.re as f32, c.im as f32);
        }
        rows.process(row);
    });
    fft_columns(&mut data, width, height, FftDirection::Inverse);
    // the real part of the transform of white complex noise is a real Gaussian field with the same spectrum;
    // standardized (the sums in row order, as the field is laid out)
    let mut real: Vec<f32> = data.par_iter().map(|c| c.re).collect();
    drop(data);
    let n = real.len() as f64;
    let mean = real.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let sd = (real.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / n).sqrt();
    let sd = if sd > 0.0 { sd } else { 1.0 };
    real.par_iter_mut().for_each(|v| *v = ((f64::from(*v) - mean) / sd) as f32);
    real
}

/// The frequency, in cycles per side, of index `k` of an `n`-point transform: `k` up to `n/2`, `k − n` above.
fn signed_frequency(k: usize, n: usize) -> i64 {
    if k <= n / 2 { k as i64 } else { k as i64 - n as i64 }
}

/// The place of frequency `k` in the order `0, 1, −1, 2, −2, …`: the first `n` places are an `n`-point
/// transform's frequencies, whatever `n`.
fn frequency_order(k: i64) -> u64 {
    if k > 0 { 2 * k as u64 - 1 } else { 2 * k.unsigned_abs() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::fft2d::fft2;
    use crate::imaging::psd::psd_slope;

    /// [`gaussian_field`] from its definition, on one thread: each frequency's coefficient is the pair of
    /// normals at its place in its row's stream, then the 2D FFT.
    fn gaussian_field_serial(
        width: usize,
        height: usize,
        slope: f64,
        outer_px: f64,
        seed: u64,
        substream: u64,
    ) -> Vec<f32> {
        let f0 = 1.0 / outer_px.max(1.0);
        let mut data: Vec<Complex<f32>> = Vec::with_capacity(width * height);
        for y in 0..height {
            let ky = signed_frequency(y, height);
            let mut rng = stream_rng(seed, stage::SKY, frequency_order(ky), substream);
            let draws: Vec<(f64, f64)> =
                (0..width).map(|_| (standard_normal(&mut rng), standard_normal(&mut rng))).collect();
            for x in 0..width {
                let kx = signed_frequency(x, width);
                let f = (kx.abs() as f64 / width as f64).hypot(ky.abs() as f64 / height as f64);
                let amp = if x == 0 && y == 0 { 0.0 } else { f.max(f0).powf(0.5 * slope) };
                let (re, im) = draws[frequency_order(kx) as usize];
                let turn = |k: i64, n: usize| Complex::from_polar(1.0, std::f64::consts::PI * k as f64 / n as f64);
                let c = Complex::new(amp * re, amp * im) * turn(ky, height) * turn(kx, width);
                data.push(Complex::new(c.re as f32, c.im as f32));
            }
        }
        fft2(&mut data, width, height, FftDirection::Inverse);
        let values: Vec<f64> = data.iter().map(|c| f64::from(c.re)).collect();
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        let sd = if sd > 0.0 { sd } else { 1.0 };
        values.iter().map(|v| ((v - mean) / sd) as f32).collect()
    }

    #[test]
    fn a_smaller_field_holds_the_same_coefficients() {
        use crate::imaging::fft2d::fft2;
        // odd and even sides; half the size and half the outer scale in texels: the same frequencies in cycles
        // per side have the same coefficient up to one factor (the amplitudes' common scale and the
        // standardization), the Nyquist row and column of the smaller aside (they alias ±n/2)
        for ((w, h), (sw, sh)) in [((64, 48), (32, 24)), ((90, 66), (45, 33)), ((96, 60), (32, 20))] {
            let spectrum = |w: usize, h: usize| {
                let g = gaussian_field(w, h, -3.0, 0.5 * w as f64, 9, 1);
                let mut c: Vec<Complex<f32>> = g.iter().map(|&v| Complex::new(v, 0.0)).collect();
                fft2(&mut c, w, h, FftDirection::Forward);
                c
            };
            let (big, small) = (spectrum(w, h), spectrum(sw, sh));
            let at = |c: &[Complex<f32>], n: (usize, usize), kx: i64, ky: i64| {
                c[ky.rem_euclid(n.1 as i64) as usize * n.0 + kx.rem_euclid(n.0 as i64) as usize]
            };
            let (mut ratios, mut peak) = (Vec::new(), 0.0f32);
            for ky in -(sh as i64 - 1) / 2..=(sh as i64 - 1) / 2 {
                for kx in -(sw as i64 - 1) / 2..=(sw as i64 - 1) / 2 {
                    // less each size's turn to its texels' centres (the same field, sampled at other points)
                    let untwist = |n: (usize, usize)| {
                        let a = -std::f32::consts::PI * (kx as f32 / n.0 as f32 + ky as f32 / n.1 as f32);
                        Complex::from_polar(1.0, a)
                    };
                    let b = at(&big, (w, h), kx, ky) * untwist((w, h));
                    let s = at(&small, (sw, sh), kx, ky) * untwist((sw, sh));
                    peak = peak.max(s.norm());
                    if (kx, ky) != (0, 0) {
                        ratios.push((b, s));
                    }
                }
            }
            // one real factor: b = c·s at every frequency
            let c = ratios.iter().map(|(b, s)| (b * s.conj()).re).sum::<f32>()
                / ratios.iter().map(|(_, s)| s.norm_sqr()).sum::<f32>();
            let worst = ratios.iter().map(|(b, s)| (b - s * c).norm()).fold(0.0f32, f32::max);
            assert!(worst <= 1e-3 * c.abs() * peak, "{w}x{h} against {sw}x{sh}: off by {worst}, factor {c}");
        }
    }

    #[test]
    fn the_parallel_field_is_the_serial_one_bit_for_bit() {
        // odd and even sides, a side under a block and one over a band, sides that are not powers of two
        for (w, h, slope, outer) in
            [(1, 1, -3.0, 4.0), (7, 5, -3.0, 2.0), (64, 48, -2.5, 30.0), (300, 17, -4.0, 90.0), (9000, 3, -3.0, 1e4)]
        {
            for substream in [0, 1] {
                let got = gaussian_field(w, h, slope, outer, 11, substream);
                let want = gaussian_field_serial(w, h, slope, outer, 11, substream);
                assert!(
                    got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()) && got.len() == want.len(),
                    "{w}x{h} substream {substream}"
                );
            }
        }
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let three = pool.install(|| gaussian_field(129, 70, -3.0, 40.0, 5, 0));
        let want = gaussian_field_serial(129, 70, -3.0, 40.0, 5, 0);
        assert!(three.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn the_quantile_is_that_of_the_sorted_values() {
        let values: Vec<f32> = gaussian_field(40, 30, -3.0, 10.0, 3, 0);
        let mut sorted = values.clone();
        sorted.sort_by(f32::total_cmp);
        for q in [0.0, 0.1, 0.35, 0.5, 0.99, 1.0] {
            let i = ((sorted.len() - 1) as f64 * q).round() as usize;
            assert_eq!(quantile(&values, q).to_bits(), sorted[i].to_bits(), "q {q}");
        }
    }

    /// The layer as a radiance image over a uniform background (cloud 1 + texture, background 0).
    fn radiance(layer: &CloudLayer) -> Vec<f32> {
        layer.opacity.iter().zip(&layer.temp_offset_k).map(|(&a, &t)| a * (1.0 + 0.02 * t)).collect()
    }

    #[test]
    fn generated_skies_have_the_configured_slope() {
        let n = 512;
        for (kind, slope) in [
            (SkyKind::Cumulus, -3.0),
            (SkyKind::Cumulus, -2.7),
            (SkyKind::Cumulus, -2.45),
            (SkyKind::Clear, -3.0),
            (SkyKind::Clear, -2.0),
            (SkyKind::Clear, -4.0),
        ] {
            for seed in [1, 2] {
                let spec = SkyGenSpec { psd_slope: slope, seed, ..SkyGenSpec::new(kind) };
                let layer = generate(&spec, n, n);
                let got = psd_slope(&radiance(&layer), n, n, 8.0 / n as f64, 0.25).unwrap();
                assert!((got - slope).abs() <= 0.3, "{kind:?} seed {seed}: slope {got:.2}, configured {slope}");
            }
        }
    }

    #[test]
    fn cumulus_cover_is_as_asked_and_edges_are_sharp() {
        let spec = SkyGenSpec { cover: 0.35, ..SkyGenSpec::new(SkyKind::Cumulus) };
        let layer = generate(&spec, 256, 256);
        let covered = layer.opacity.iter().filter(|&&a| a >= 0.5).count() as f64 / 65536.0;
        assert!((covered - 0.35).abs() < 0.03, "cover {covered}");
        // most pixels are clear or fully cloud: the transition band is narrow
        let partial = layer.opacity.iter().filter(|&&a| a > 0.05 && a < 0.95).count() as f64 / 65536.0;
        assert!(partial < 0.05, "partial {partial}");
        assert_eq!(layer, generate(&spec, 256, 256));
    }
}
