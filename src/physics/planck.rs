//! Planck's law: spectral radiance and exact band radiance (paper eq 3).
//!
//! The band integral is done in the reduced variable `x = c₂/(λT)` (`c₂ = hc/k`), where
//!
//! ```text
//! ∫_{λ1}^{λ2} B_λ(λ, T) dλ = (2k⁴T⁴ / (h³c²)) · ∫_{x2}^{x1} t³/(eᵗ − 1) dt,   x_i = c₂/(λ_i T).
//! ```
//!
//! The integral of `g(t) = t³/(eᵗ − 1)` is evaluated without truncation error beyond f64 rounding:
//!
//! - for `t ≥ 2`, the upper tail `F(x) = ∫_x^∞ g = Σₙ e^{−nx}(x³/n + 3x²/n² + 6x/n³ + 6/n⁴)`, kept in the
//!   log domain (`F = e^{−x}·S(x)`) so that bands far in the Wien tail neither underflow early nor lose digits;
//! - for `t < 2`, the lower part `P(x) = ∫_0^x g = Σ_k B_k x^{k+3}/((k+3)·k!)` (Bernoulli series, radius 2π);
//! - where a difference of two such values would cancel (a narrow band), Gauss–Legendre quadrature of `g`
//!   directly, which is exact to rounding there because `g` is analytic within 2π of the real axis: 4 to 8 nodes
//!   for pieces up to 1 wide in `x` (a LOWTRAN bin is about 0.05), 20 for wider ones (`GAUSS_ORDERS`).
//!
//! A band straddling `t = 2` is split there, so every piece is a sum of positive terms. The result is assembled
//! as one `exp` of a log, which returns exactly 0 when the true radiance is below the smallest subnormal.
//!
//! Photon detectors count photons, not joules: the photon radiance `∫ B_λ λ/(hc) dλ` is the same integral with
//! `t²/(eᵗ − 1)` and the prefactor `2k³T³/(h³c²)`, evaluated by the same three methods ([`Measure::Photon`]).
//! The temperature derivative `dL/dT` (for NETD) follows from differentiating under the integral's bounds, and
//! [`brightness_temperature`] inverts the band radiance.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Planck constant, J s (CODATA 2018, exact).
pub const PLANCK_H: f64 = 6.626_070_15e-34;
/// Speed of light in vacuum, m/s (exact).
pub const SPEED_OF_LIGHT: f64 = 299_792_458.0;
/// Boltzmann constant, J/K (CODATA 2018, exact).
pub const BOLTZMANN_K: f64 = 1.380_649e-23;
/// Stefan–Boltzmann constant, W m⁻² K⁻⁴ (CODATA 2018).
pub const STEFAN_BOLTZMANN: f64 = 5.670_374_419e-8;

/// Second radiation constant c₂ = hc/k, in m·K.
pub const C2_M_K: f64 = PLANCK_H * SPEED_OF_LIGHT / BOLTZMANN_K;

/// What a band radiance counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Measure {
    /// Energy: W m⁻² sr⁻¹ (thermal detectors, and the paper's eq 3).
    #[default]
    Energy,
    /// Photons: s⁻¹ m⁻² sr⁻¹ (photon detectors).
    Photon,
}

impl Measure {
    /// The power `p` of `t` in the reduced integrand `tᵖ/(eᵗ − 1)`.
    fn power(self) -> i32 {
        match self {
            Measure::Energy => 3,
            Measure::Photon => 2,
        }
    }

    /// `ln` of the prefactor per kelvin power: `2k⁴/(h³c²)` (energy) or `2k³/(h³c²)` (photons).
    fn ln_prefactor(self) -> f64 {
        let h3c2 = PLANCK_H.powi(3) * SPEED_OF_LIGHT * SPEED_OF_LIGHT;
        match self {
            Measure::Energy => (2.0 * BOLTZMANN_K.powi(4) / h3c2).ln(),
            Measure::Photon => (2.0 * BOLTZMANN_K.powi(3) / h3c2).ln(),
        }
    }

    /// Unit of a radiance in this measure.
    pub fn unit(self) -> &'static str {
        match self {
            Measure::Energy => "W m⁻² sr⁻¹",
            Measure::Photon => "photons s⁻¹ m⁻² sr⁻¹",
        }
    }
}

/// Where the evaluation switches from the Bernoulli series to the exponential tail series.
const SPLIT_X: f64 = 2.0;
/// Above this `x` the band radiance is far below the smallest subnormal for any admissible temperature.
const X_NEGLIGIBLE: f64 = 1e15;
/// Upper pieces narrower than this go straight to the quadrature ([`upper_piece_scaled`]): `e^{−½} = 0.61`,
/// clear of the ½ where the tails' difference would be taken instead.
const NARROW_PIECE: f64 = 0.5;
/// An upper piece is the difference of its two tails where their ratio is at most this ([`upper_piece_scaled`]),
/// else the quadrature.
const TAILS_RATIO: f64 = 0.5;

/// `B_{2j}/((2j+3)·(2j)!)` for j = 0, 1, …: the even-k coefficients of `P(x)/x³` as a series in `x²`.
const BERNOULLI_COEF: [f64; 22] = [
    0.333_333_333_333_333_3,
    0.016_666_666_666_666_666,
    -0.000_198_412_698_412_698_4,
    3.674_309_229_864_785_5e-6,
    -7.515_632_515_632_516e-8,
    1.605_904_383_682_161_5e-9,
    -3.522_793_425_791_662e-11,
    7.872_080_312_167_458e-13,
    -1.784_042_261_222_412e-14,
    4.088_600_979_179_926e-16,
    -9.455_950_863_295_921e-18,
    2.203_601_131_344_092e-19,
    -5.168_320_254_004_638_5e-21,
    1.218_864_496_423_954_2e-22,
    -2.888_231_428_076_628e-24,
    6.872_583_188_902_07e-26,
    -1.641_368_762_534_915e-27,
    3.932_898_582_742_878_4e-29,
    -9.451_269_078_629_001e-31,
    2.277_252_257_828_059_7e-32,
    -5.500_052_129_536_348e-34,
    1.331_260_391_662_696_6e-35,
];

/// An error in a spectral band's bounds.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BandError {
    /// A bound is zero, negative, infinite or NaN.
    #[error("band bound {name} = {} µm must be a finite number > 0", super::Num(*.value))]
    NonPositive {
        /// Which bound: `lo_um` or `hi_um`.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// The lower bound is above the upper bound.
    #[error("band lower bound {lo_um} µm is above its upper bound {hi_um} µm")]
    Reversed {
        /// Lower bound, µm.
        lo_um: f64,
        /// Upper bound, µm.
        hi_um: f64,
    },
}

/// A spectral band `[lo_um, hi_um]` in micrometres, validated: `0 < lo_um ≤ hi_um < ∞`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(into = "[f64; 2]")]
pub struct Band {
    lo_um: f64,
    hi_um: f64,
}

impl Band {
    /// The long-wave infrared band of the paper, 8–12 µm.
    pub const LWIR_8_12: Band = Band { lo_um: 8.0, hi_um: 12.0 };
    /// The mid-wave infrared window, 3–5 µm.
    pub const MWIR_3_5: Band = Band { lo_um: 3.0, hi_um: 5.0 };

    /// A band from its bounds in µm.
    ///
    /// # Errors
    /// [`BandError::NonPositive`] if a bound is not a finite number above 0; [`BandError::Reversed`] if
    /// `lo_um > hi_um`. An empty band (`lo_um == hi_um`) is allowed and has zero radiance.
    pub fn try_new(lo_um: f64, hi_um: f64) -> Result<Self, BandError> {
        for (name, value) in [("lo_um", lo_um), ("hi_um", hi_um)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(BandError::NonPositive { name, value });
            }
        }
        if lo_um > hi_um {
            return Err(BandError::Reversed { lo_um, hi_um });
        }
        Ok(Self { lo_um, hi_um })
    }

    /// Lower bound, µm.
    pub fn lo_um(&self) -> f64 {
        self.lo_um
    }

    /// Upper bound, µm.
    pub fn hi_um(&self) -> f64 {
        self.hi_um
    }

    /// Width, µm.
    pub fn width_um(&self) -> f64 {
        self.hi_um - self.lo_um
    }
}

impl<'de> Deserialize<'de> for Band {
    /// Exactly two numbers `[lo_um, hi_um]`, checked by [`Band::try_new`].
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let [lo, hi] = super::exact::array(d)?;
        Band::try_new(lo, hi).map_err(serde::de::Error::custom)
    }
}

impl TryFrom<[f64; 2]> for Band {
    type Error = BandError;
    fn try_from(v: [f64; 2]) -> Result<Self, BandError> {
        Band::try_new(v[0], v[1])
    }
}

impl From<Band> for [f64; 2] {
    fn from(b: Band) -> Self {
        [b.lo_um, b.hi_um]
    }
}

/// Blackbody spectral radiance B_λ(λ, T) in W m⁻² sr⁻¹ µm⁻¹.
///
/// Returns 0 for `temp_k ≤ 0` and where the value underflows; never NaN for finite positive inputs.
pub fn spectral_radiance(wavelength_um: f64, temp_k: f64) -> f64 {
    if !(temp_k > 0.0) || !(wavelength_um > 0.0) {
        return 0.0;
    }
    let lambda_m = wavelength_um * 1e-6;
    let x = C2_M_K / (lambda_m * temp_k);
    // 2hc²/λ⁵ may overflow for tiny λ, so combine in logs: ln(2hc²) − 5 ln λ − ln(eˣ − 1).
    let ln_denominator = if x > 30.0 { x + (-(-x).exp()).ln_1p() } else { x.exp_m1().ln() };
    let ln_b = (2.0 * PLANCK_H * SPEED_OF_LIGHT * SPEED_OF_LIGHT).ln() - 5.0 * lambda_m.ln() - ln_denominator;
    // per metre → per micrometre
    ln_b.exp() * 1e-6
}

/// Blackbody radiance integrated over `band`, W m⁻² sr⁻¹, times `emissivity` (paper eq 3).
///
/// Exact to about `4·(x+4)` ulp, `x = c₂/(λ_hi T)`; 0 for `temp_k ≤ 0`, for an empty band and where the true
/// value is below the smallest subnormal. Never NaN, infinite or negative for `temp_k` in [0, 1e6] K.
///
/// # Examples
/// ```
/// use irsim::physics::planck::{band_radiance, Band};
/// let l = band_radiance(Band::LWIR_8_12, 300.0, 1.0);
/// assert!((l - 38.500_423_933_347_86).abs() < 1e-12);
/// ```
pub fn band_radiance(band: Band, temp_k: f64, emissivity: f64) -> f64 {
    band_radiance_in(Measure::Energy, band, temp_k, emissivity)
}

/// Blackbody photon radiance integrated over `band`, photons s⁻¹ m⁻² sr⁻¹, times `emissivity`.
///
/// The photon counterpart of [`band_radiance`], exact to the same accuracy.
pub fn photon_band_radiance(band: Band, temp_k: f64, emissivity: f64) -> f64 {
    band_radiance_in(Measure::Photon, band, temp_k, emissivity)
}

/// Band radiance in `measure` (energy or photons), times `emissivity`; see [`band_radiance`].
pub fn band_radiance_in(measure: Measure, band: Band, temp_k: f64, emissivity: f64) -> f64 {
    if !(temp_k > 0.0) || !(emissivity > 0.0) || band.lo_um == band.hi_um {
        return 0.0;
    }
    let p = measure.power();
    // x is largest at the short-wave edge.
    let x_hi = C2_M_K / (band.lo_um * 1e-6 * temp_k);
    let x_lo = C2_M_K / (band.hi_um * 1e-6 * temp_k);
    let Some(ln_integral) = ln_reduced_integral(x_lo, x_hi, p) else {
        return 0.0;
    };
    // the prefactor, in logs so that extreme temperatures cannot overflow an intermediate
    let ln_prefactor = measure.ln_prefactor() + f64::from(p + 1) * temp_k.ln();
    (ln_prefactor + ln_integral + emissivity.ln()).exp()
}

/// Temperature derivative of the blackbody band radiance, `dL/dT` in `measure` per kelvin (emissivity 1).
///
/// With `L = A·T^{p+1}·∫_{x_lo}^{x_hi} tᵖ/(eᵗ − 1) dt` and `x = c₂/(λT)`, differentiating the bounds gives
/// `dL/dT = (p + 1)·L/T − A·Tᵖ·[x_hi^{p+1}/(e^{x_hi} − 1) − x_lo^{p+1}/(e^{x_lo} − 1)]`. Exact to about 1e-11
/// relative except for bands narrower than 1e-4 of their wavelength, where the bracket cancels. 0 where `L` is 0.
pub fn band_radiance_derivative(measure: Measure, band: Band, temp_k: f64) -> f64 {
    derivative_at(measure, band, temp_k, band_radiance_in(measure, band, temp_k, 1.0))
}

/// [`band_radiance_derivative`] given the band radiance `l` at `temp_k` ([`band_radiance_in`], emissivity 1).
fn derivative_at(measure: Measure, band: Band, temp_k: f64, l: f64) -> f64 {
    if l == 0.0 {
        return 0.0;
    }
    let p = measure.power();
    let x_hi = C2_M_K / (band.lo_um * 1e-6 * temp_k);
    let x_lo = C2_M_K / (band.hi_um * 1e-6 * temp_k);
    // x^{p+1}/(eˣ − 1), in logs: no overflow for large x
    let edge = |x: f64| -> f64 {
        let ln_den = if x > 30.0 { x + (-(-x).exp()).ln_1p() } else { x.exp_m1().ln() };
        (f64::from(p + 1) * x.ln() - ln_den).exp()
    };
    let ln_a_tp = measure.ln_prefactor() + f64::from(p) * temp_k.ln();
    let bracket = (edge(x_hi) - edge(x_lo)) * ln_a_tp.exp();
    (f64::from(p + 1) * l / temp_k - bracket).max(0.0)
}

/// The temperature of the blackbody whose band radiance in `measure` is `radiance` (the brightness temperature),
/// K; `None` if `radiance` is not a finite number > 0 or the temperature would leave [1e-3, 1e6] K.
///
/// Newton's method on `ln L(T)` (which is increasing and concave in `ln T`), safeguarded by bisection; converges
/// to about 1e-12 relative.
pub fn brightness_temperature(measure: Measure, band: Band, radiance: f64) -> Option<f64> {
    if !(radiance.is_finite() && radiance > 0.0) || band.lo_um == band.hi_um {
        return None;
    }
    let target = radiance.ln();
    let (mut lo, mut hi) = (1e-3f64, 1e6f64);
    // `ln L(t) − ln radiance`, and `L(t)` for Newton's step
    let f = |t: f64| {
        let l = band_radiance_in(measure, band, t, 1.0);
        (if l > 0.0 { l.ln() - target } else { f64::NEG_INFINITY }, l)
    };
    if f(hi).0 < 0.0 || f(lo).0 > 0.0 {
        return None;
    }
    let mut t = 300.0f64.clamp(lo, hi);
    for _ in 0..200 {
        let (ft, l) = f(t);
        if ft == 0.0 {
            return Some(t);
        }
        if ft < 0.0 {
            lo = t;
        } else {
            hi = t;
        }
        let d = derivative_at(measure, band, t, l);
        let newton = if l > 0.0 && d > 0.0 { t - ft * l / d } else { f64::NAN };
        let next = if newton > lo && newton < hi { newton } else { (lo * hi).sqrt() };
        if (next - t).abs() <= 1e-13 * t {
            return Some(next);
        }
        t = next;
    }
    Some(t)
}

/// Total (all-wavelength) blackbody radiance σT⁴/π, W m⁻² sr⁻¹.
pub fn total_radiance(temp_k: f64) -> f64 {
    if temp_k > 0.0 { STEFAN_BOLTZMANN * temp_k.powi(4) / std::f64::consts::PI } else { 0.0 }
}

/// `ln ∫_a^b tᵖ/(eᵗ−1) dt` (`p` 2 or 3) for `0 < a ≤ b`, or `None` when the integral is zero or negligible.
fn ln_reduced_integral(a: f64, b: f64, p: i32) -> Option<f64> {
    if !(a < b) || a >= X_NEGLIGIBLE {
        return None;
    }
    let b = b.min(X_NEGLIGIBLE);
    if b <= SPLIT_X {
        return Some(ln_lower_piece(a, b, p));
    }
    if a >= SPLIT_X {
        return Some(ln_upper_piece(a, b, p));
    }
    // Straddles the split: both pieces positive, add them without cancellation.
    let lower = ln_lower_piece(a, SPLIT_X, p).exp();
    let (s, ln_scale) = upper_piece_scaled(SPLIT_X, b, p);
    Some((lower + s * ln_scale.exp()).ln())
}

/// `ln ∫_a^b g` for `0 < a < b ≤ 2`, from the Bernoulli series or, if that would cancel, quadrature.
fn ln_lower_piece(a: f64, b: f64, p: i32) -> f64 {
    let pa = lower_cumulative(a, p);
    let pb = lower_cumulative(b, p);
    if pa <= 0.5 * pb {
        (pb - pa).ln()
    } else {
        let (m, ln_scale) = gauss_legendre_scaled(a, b, p);
        m.ln() + ln_scale
    }
}

/// `ln ∫_a^b g` for `2 ≤ a < b`.
fn ln_upper_piece(a: f64, b: f64, p: i32) -> f64 {
    let (m, ln_scale) = upper_piece_scaled(a, b, p);
    m.ln() + ln_scale
}

/// `∫_a^b g = m·e^{ln_scale}` for `2 ≤ a < b`, with `ln_scale = −a`.
///
/// The difference of the two tails is taken where `e^{−(b−a)}·S(b)/S(a) ≤ ½` (no cancellation), else the
/// quadrature. `S` rises on `[2, ∞)` (`S′ = S − xᵖ/(1 − e^{−x})`, which is at least 0.26·S for `p = 3` and
/// 0.18·S for `p = 2` up to `x = 10`, falling as about `p/x` beyond, 0.004·S at 700: 30-digit quadrature), so the
/// ratio is at least `e^{−(b−a)}`, above ½ for `b − a` under `ln 2`; a piece narrower than [`NARROW_PIECE`] (a
/// LOWTRAN bin is `b − a ≈ 0.05` at 10 µm and 290 K) goes to the quadrature without the two series, the branch
/// they would have chosen.
fn upper_piece_scaled(a: f64, b: f64, p: i32) -> (f64, f64) {
    if b - a < NARROW_PIECE {
        return gauss_legendre_scaled(a, b, p);
    }
    let sa = tail_scaled(a, p);
    let ratio = (-(b - a)).exp() * tail_scaled(b, p) / sa;
    if ratio <= TAILS_RATIO { (sa * (1.0 - ratio), -a) } else { gauss_legendre_scaled(a, b, p) }
}

/// `P(x) = ∫_0^x tᵖ/(eᵗ−1) dt` for `0 ≤ x ≤ 2` (Bernoulli series `Σ_k B_k x^{k+p}/((k+p)·k!)`).
///
/// The even-`k` coefficients for `p = 2` are those of `p = 3` times `(2j+3)/(2j+2)`; the one odd term is
/// `B₁ = −½`.
fn lower_cumulative(x: f64, p: i32) -> f64 {
    let x2 = x * x;
    let mut sum = 0.0;
    if p == 3 {
        for &c in BERNOULLI_COEF.iter().rev() {
            sum = sum * x2 + c;
        }
        x * x2 * (sum - x / 8.0)
    } else {
        for (j, &c) in BERNOULLI_COEF.iter().enumerate().rev() {
            let j = j as f64;
            sum = sum * x2 + c * (2.0 * j + 3.0) / (2.0 * j + 2.0);
        }
        x2 * (sum - x / 6.0)
    }
}

/// `S(x) = eˣ·∫_x^∞ tᵖ/(eᵗ−1) dt` for `x ≥ 2`: for `p = 3`, `Σₙ e^{−(n−1)x}(x³/n + 3x²/n² + 6x/n³ + 6/n⁴)`;
/// for `p = 2`, `Σₙ e^{−(n−1)x}(x²/n + 2x/n² + 2/n³)`.
fn tail_scaled(x: f64, p: i32) -> f64 {
    let q = (-x).exp();
    let mut sum = 0.0;
    let mut qn = 1.0; // e^{-(n-1)x}
    for n in 1..=64 {
        let nf = f64::from(n);
        let inv = 1.0 / nf;
        let term = if p == 3 {
            qn * inv * (x * x * x + 3.0 * inv * (x * x + 2.0 * inv * (x + inv)))
        } else {
            qn * inv * (x * x + 2.0 * inv * (x + inv))
        };
        sum += term;
        if term <= sum * 1e-18 {
            break;
        }
        qn *= q;
    }
    sum
}

/// Gauss–Legendre orders for pieces of `g` up to each width in `x` ([`gauss_legendre_scaled`]), then 20 for
/// wider ones. `g` is analytic but for poles at `±2πik` (`k ≠ 0`), at least 2π from the real axis, so the
/// error falls as the `2n`-th power of the width (about `(width/8π)^{2n}`). Measured in 40-digit arithmetic with
/// the double-precision nodes and weights, over `a` from 0.001 to 400 and `p` 2 and 3, the largest relative error
/// at each width: 2.3·10⁻¹⁶ (4 points at 0.06), 9·10⁻¹⁷ (5 at 0.2), 3.5·10⁻¹⁷ (6 at 0.4), 2.7·10⁻¹⁶ (8 at 1),
/// where 20 points erred by up to 1.1·10⁻¹⁵ on the same pieces: the nodes' rounding, not the order, sets it. A
/// LOWTRAN bin of 0.1 µm at 10 µm and 290 K is 0.05 wide.
const GAUSS_ORDERS: [(f64, usize); 4] = [(0.06, 4), (0.2, 5), (0.4, 6), (1.0, 8)];

/// `∫_a^b g` by Gauss–Legendre of the order [`GAUSS_ORDERS`] gives its width, as `m·e^{ln_scale}` with the
/// factor `e^{−a}` taken out for `a ≥ 2` (there `1 − e^{−x}` is formed as `1 − e^{−a}·e^{−(x−a)}`, at least
/// 0.86 and free of cancellation, one exponential a node).
fn gauss_legendre_scaled(a: f64, b: f64, p: i32) -> (f64, f64) {
    let width = b - a;
    let order = GAUSS_ORDERS.iter().find(|&&(w, _)| width <= w).map_or(20, |&(_, n)| n);
    let (nodes, weights) = gauss_legendre_table(order);
    let half = 0.5 * width;
    let mid = 0.5 * (a + b);
    let scaled = a >= SPLIT_X;
    let below_a = if scaled { (-a).exp() } else { 0.0 };
    let mut sum = 0.0;
    for (&t, &w) in nodes.iter().zip(weights) {
        let x = mid + half * t;
        let xp = if p == 3 { x * x * x } else { x * x };
        let value = if scaled {
            // xᵖ e^{−(x−a)} / (1 − e^{−x})
            let e = (-(x - a)).exp();
            xp * e / (1.0 - below_a * e)
        } else {
            xp / x.exp_m1()
        };
        sum += w * value;
    }
    (sum * half, if scaled { -a } else { 0.0 })
}

/// Gauss–Legendre nodes and weights of order `n ≥ 1` on [−1, 1], by Newton iteration on `P_n`.
fn gauss_legendre_nodes(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    let nf = n as f64;
    for i in 0..n {
        // Chebyshev-like first guess, then Newton on P_n.
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, d) = legendre_and_derivative(n, x);
            dp = d;
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre_and_derivative(n, x);
        dp = if d != 0.0 { d } else { dp };
        nodes[i] = x;
        weights[i] = 2.0 / ((1.0 - x * x) * dp * dp);
    }
    (nodes, weights)
}

fn legendre_and_derivative(n: usize, x: f64) -> (f64, f64) {
    let mut p0 = 1.0;
    let mut p1 = x;
    for k in 2..=n {
        let kf = k as f64;
        let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
        p0 = p1;
        p1 = p2;
    }
    let nf = n as f64;
    (p1, nf * (x * p1 - p0) / (x * x - 1.0))
}

/// How a band radiance is evaluated: the exact series, or a quadrature of Planck's law in wavelength (cheaper
/// for few nodes, with an error that `irsim bench report` measures).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields, from = "PlanckMethodFields")]
pub enum PlanckMethod {
    /// [`band_radiance_in`]: exact to rounding.
    #[default]
    Series,
    /// Composite Simpson with `intervals` (even, 2 to [`MAX_QUADRATURE_NODES`]) sub-intervals.
    Simpson {
        /// Sub-intervals of the band.
        intervals: usize,
    },
    /// Gauss–Legendre with `points` (1 to [`MAX_GAUSS_POINTS`]) nodes.
    GaussLegendre {
        /// Nodes over the band.
        points: usize,
    },
}

/// [`PlanckMethod`] as a scenario writes it, every variant a table of its fields: serde reads a variant without
/// fields from the tag alone and ignores any key beside it (`{ method = "series", points = 4 }` would pass), so
/// [`PlanckMethod`] is read through this and such a key is refused as unknown.
#[derive(Deserialize)]
#[serde(
    tag = "method",
    rename_all = "snake_case",
    deny_unknown_fields,
    expecting = "a table with `method`: series, simpson or gauss_legendre"
)]
enum PlanckMethodFields {
    Series {},
    Simpson { intervals: usize },
    GaussLegendre { points: usize },
}

impl From<PlanckMethodFields> for PlanckMethod {
    fn from(m: PlanckMethodFields) -> Self {
        match m {
            PlanckMethodFields::Series {} => Self::Series,
            PlanckMethodFields::Simpson { intervals } => Self::Simpson { intervals },
            PlanckMethodFields::GaussLegendre { points } => Self::GaussLegendre { points },
        }
    }
}

/// The most nodes (Gauss–Legendre) or sub-intervals (Simpson) a [`PlanckMethod`] may ask for.
pub const MAX_QUADRATURE_NODES: usize = 4096;

impl PlanckMethod {
    /// Whether the node count is allowed: Simpson's even and in [2, 4096], Gauss–Legendre's in [1, 64].
    pub fn check(self) -> Result<(), String> {
        match self {
            Self::Series => Ok(()),
            Self::Simpson { intervals }
                if intervals >= 2 && intervals % 2 == 0 && intervals <= MAX_QUADRATURE_NODES =>
            {
                Ok(())
            }
            Self::Simpson { intervals } => {
                Err(format!("Simpson's intervals must be even, from 2 to {MAX_QUADRATURE_NODES}: got {intervals}"))
            }
            Self::GaussLegendre { points } if (1..=MAX_GAUSS_POINTS).contains(&points) => Ok(()),
            Self::GaussLegendre { points } => {
                Err(format!("Gauss–Legendre points must be from 1 to {MAX_GAUSS_POINTS}: got {points}"))
            }
        }
    }

    /// Band radiance in `measure` times `emissivity`, by this method; 0 for `temp_k ≤ 0`, `emissivity ≤ 0` or
    /// an empty band, never NaN.
    pub fn band_radiance(self, measure: Measure, band: Band, temp_k: f64, emissivity: f64) -> f64 {
        if !(temp_k > 0.0) || !(emissivity > 0.0) || band.lo_um == band.hi_um {
            return 0.0;
        }
        // the integrand in the measure, per µm of wavelength
        let integrand = |lambda_um: f64| {
            let b = spectral_radiance(lambda_um, temp_k);
            match measure {
                Measure::Energy => b,
                Measure::Photon => b * lambda_um * 1e-6 / (PLANCK_H * SPEED_OF_LIGHT),
            }
        };
        let sum = match self {
            Self::Series => return band_radiance_in(measure, band, temp_k, emissivity),
            Self::Simpson { intervals } => {
                let n = intervals.clamp(2, MAX_QUADRATURE_NODES) & !1;
                let h = band.width_um() / n as f64;
                let mut sum = integrand(band.lo_um) + integrand(band.hi_um);
                for i in 1..n {
                    let w = if i % 2 == 1 { 4.0 } else { 2.0 };
                    sum += w * integrand(band.lo_um + h * i as f64);
                }
                sum * h / 3.0
            }
            Self::GaussLegendre { points } => {
                let (nodes, weights) = gauss_legendre_table(points.clamp(1, MAX_GAUSS_POINTS));
                let (half, mid) = (0.5 * band.width_um(), 0.5 * (band.lo_um + band.hi_um));
                nodes.iter().zip(weights).map(|(&t, &w)| w * integrand(mid + half * t)).sum::<f64>() * half
            }
        };
        let value = emissivity * sum;
        if value.is_finite() { value.max(0.0) } else { 0.0 }
    }
}

/// The most Gauss–Legendre nodes a [`PlanckMethod`] may ask for.
pub const MAX_GAUSS_POINTS: usize = 64;

/// Gauss–Legendre nodes and weights of order `n` (1 to [`MAX_GAUSS_POINTS`]), computed once per order.
fn gauss_legendre_table(n: usize) -> &'static (Vec<f64>, Vec<f64>) {
    static TABLES: [OnceLock<(Vec<f64>, Vec<f64>)>; MAX_GAUSS_POINTS + 1] =
        [const { OnceLock::new() }; MAX_GAUSS_POINTS + 1];
    TABLES[n].get_or_init(|| gauss_legendre_nodes(n))
}

/// Band radiance by composite Simpson quadrature in wavelength with `intervals` (even) sub-intervals.
///
/// The baseline the exact method is benchmarked against; not used by the simulation.
pub fn band_radiance_simpson(band: Band, temp_k: f64, emissivity: f64, intervals: usize) -> f64 {
    let n = intervals.max(2) & !1;
    let h = band.width_um() / n as f64;
    let mut sum = spectral_radiance(band.lo_um, temp_k) + spectral_radiance(band.hi_um, temp_k);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        sum += w * spectral_radiance(band.lo_um + h * i as f64, temp_k);
    }
    emissivity * sum * h / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadrature_methods_converge_to_the_series() {
        for band in [Band::try_new(3.0, 5.0).unwrap(), Band::LWIR_8_12] {
            for measure in [Measure::Energy, Measure::Photon] {
                for t in [200.0, 300.0, 800.0, 1500.0] {
                    let exact = band_radiance_in(measure, band, t, 0.9);
                    assert_eq!(PlanckMethod::Series.band_radiance(measure, band, t, 0.9), exact);
                    let rel = |m: PlanckMethod| (m.band_radiance(measure, band, t, 0.9) / exact - 1.0).abs();
                    assert!(rel(PlanckMethod::GaussLegendre { points: 8 }) < 1e-10, "{band:?} {t}");
                    assert!(rel(PlanckMethod::GaussLegendre { points: 4 }) < 1e-4, "{band:?} {t}");
                    assert!(rel(PlanckMethod::Simpson { intervals: 32 }) < 1e-5, "{band:?} {t}");
                }
            }
        }
        assert_eq!(
            PlanckMethod::GaussLegendre { points: 4 }.band_radiance(Measure::Energy, Band::LWIR_8_12, 0.0, 1.0),
            0.0
        );
        assert!(PlanckMethod::Simpson { intervals: 3 }.check().is_err());
        assert!(PlanckMethod::GaussLegendre { points: 65 }.check().is_err());
        assert!(PlanckMethod::GaussLegendre { points: 1 }.check().is_ok());
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        let (x, w) = gauss_legendre_table(20);
        // ∫_{-1}^{1} t^38 dt = 2/39
        let s: f64 = x.iter().zip(w).map(|(t, w)| w * t.powi(38)).sum();
        assert!((s - 2.0 / 39.0).abs() < 1e-15);
        let total: f64 = w.iter().sum();
        assert!((total - 2.0).abs() < 1e-14);
        // and every order the series' pieces use: t^(2n − 2) exactly
        for &(_, n) in &GAUSS_ORDERS {
            let (x, w) = gauss_legendre_table(n);
            let k = 2 * n as i32 - 2;
            let s: f64 = x.iter().zip(w).map(|(t, w)| w * t.powi(k)).sum();
            assert!((s - 2.0 / f64::from(k + 1)).abs() < 1e-15, "{n}");
        }
    }

    #[test]
    fn series_pieces_agree_at_the_split() {
        // P(2) + F(2) = π⁴/15
        let p = lower_cumulative(SPLIT_X, 3);
        let f = tail_scaled(SPLIT_X, 3) * (-SPLIT_X).exp();
        let want = std::f64::consts::PI.powi(4) / 15.0;
        assert!(((p + f) - want).abs() / want < 1e-15, "{p} + {f} vs {want}");
        // p = 2: P(2) + F(2) = 2ζ(3)
        let p = lower_cumulative(SPLIT_X, 2);
        let f = tail_scaled(SPLIT_X, 2) * (-SPLIT_X).exp();
        let want = 2.0 * 1.202_056_903_159_594_2;
        assert!(((p + f) - want).abs() / want < 1e-15, "{p} + {f} vs {want}");
    }

    #[test]
    fn narrow_upper_pieces_are_those_the_tails_send_to_the_quadrature() {
        // S rises on [2, ∞), so the tails' ratio over a piece of width w is at least e^{−w}, above TAILS_RATIO
        // for every piece narrower than NARROW_PIECE: the shortcut takes the branch the two series would have
        assert!((-NARROW_PIECE).exp() > TAILS_RATIO);
        for p in [2, 3] {
            let mut a = SPLIT_X;
            while a < 800.0 {
                let sa = tail_scaled(a, p);
                for width in [1e-9, 1e-4, 0.01, 0.05, 0.2, 0.45, NARROW_PIECE * (1.0 - 1e-12)] {
                    let b = a + width;
                    let ratio = (-(b - a)).exp() * tail_scaled(b, p) / sa;
                    assert!(ratio >= (-width).exp() * (1.0 - 1e-12), "p {p}, a {a}, b {b}: {ratio}");
                }
                a = a * 1.01 + 1e-3;
            }
        }
    }

    #[test]
    fn whole_spectrum_is_sigma_t4_over_pi() {
        for t in [50.0, 300.0, 1000.0, 5772.0] {
            let band = Band::try_new(1e-4, 1e6).unwrap();
            let l = band_radiance(band, t, 1.0);
            let want = total_radiance(t);
            assert!(((l - want) / want).abs() < 1e-9, "T={t}: {l} vs {want}");
        }
    }

    #[test]
    fn whole_spectrum_photon_radiance() {
        // ∫ B_λ λ/(hc) dλ over all λ = 4ζ(3)k³T³/(h³c²)
        let zeta3 = 1.202_056_903_159_594_2;
        for t in [50.0, 300.0, 5772.0] {
            // photons keep coming far into the long-wave tail (∫₀ˣ t²/(eᵗ−1) ≈ x²/2): go to 1e9 µm
            let band = Band::try_new(1e-4, 1e9).unwrap();
            let l = photon_band_radiance(band, t, 1.0);
            let want = 4.0 * zeta3 * (BOLTZMANN_K * t).powi(3) / (PLANCK_H.powi(3) * SPEED_OF_LIGHT.powi(2));
            assert!(((l - want) / want).abs() < 1e-9, "T={t}: {l} vs {want}");
        }
    }

    #[test]
    fn derivative_matches_a_central_difference() {
        for measure in [Measure::Energy, Measure::Photon] {
            for (band, t) in [(Band::LWIR_8_12, 300.0), (Band::MWIR_3_5, 250.0), (Band::MWIR_3_5, 1200.0)] {
                let h = 1e-5 * t;
                let fd = (band_radiance_in(measure, band, t + h, 1.0) - band_radiance_in(measure, band, t - h, 1.0))
                    / (2.0 * h);
                let d = band_radiance_derivative(measure, band, t);
                assert!(((d - fd) / d).abs() < 1e-6, "{measure:?} {band:?} {t}: {d} vs {fd}");
            }
        }
    }

    #[test]
    fn brightness_temperature_inverts_band_radiance() {
        for measure in [Measure::Energy, Measure::Photon] {
            for band in [Band::LWIR_8_12, Band::MWIR_3_5, Band::try_new(10.0, 10.5).unwrap()] {
                for t in [20.0, 180.0, 300.0, 5772.0] {
                    let l = band_radiance_in(measure, band, t, 1.0);
                    let back = brightness_temperature(measure, band, l).unwrap();
                    assert!(((back - t) / t).abs() < 1e-10, "{measure:?} {band:?}: {t} → {back}");
                }
            }
        }
        assert_eq!(brightness_temperature(Measure::Energy, Band::LWIR_8_12, 0.0), None);
        assert_eq!(brightness_temperature(Measure::Energy, Band::LWIR_8_12, f64::NAN), None);
    }

    #[test]
    fn wien_peak() {
        // λ_max T = 2897.771955 µm K
        let t = 300.0;
        let peak = 2_897.771_955 / t;
        let at = |l| spectral_radiance(l, t);
        assert!(at(peak) > at(peak * (1.0 + 1e-4)));
        assert!(at(peak) > at(peak * (1.0 - 1e-4)));
    }

    #[test]
    fn band_rejects_bad_bounds() {
        assert!(matches!(Band::try_new(12.0, 8.0), Err(BandError::Reversed { .. })));
        assert!(matches!(Band::try_new(0.0, 8.0), Err(BandError::NonPositive { .. })));
        assert!(matches!(Band::try_new(-1.0, 8.0), Err(BandError::NonPositive { .. })));
        assert!(matches!(Band::try_new(1.0, f64::NAN), Err(BandError::NonPositive { .. })));
        assert!(matches!(Band::try_new(1.0, f64::INFINITY), Err(BandError::NonPositive { .. })));
        assert_eq!(band_radiance(Band::try_new(8.0, 8.0).unwrap(), 300.0, 1.0), 0.0);
    }

    #[test]
    fn simpson_converges_to_the_exact_value() {
        let exact = band_radiance(Band::LWIR_8_12, 300.0, 1.0);
        let s = band_radiance_simpson(Band::LWIR_8_12, 300.0, 1.0, 1024);
        assert!(((s - exact) / exact).abs() < 1e-10);
    }
}
