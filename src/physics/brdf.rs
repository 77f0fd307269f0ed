//! Cook–Torrance BRDF (paper eqs 4–8), in the general form and in the paper's facet form.
//!
//! `f = k_d/π + k_s · F·D·G / (π (n·v)(n·l))` with Schlick's Fresnel term (eq 5), the Beckmann distribution
//! `D = exp(−tan²α/m²)/(π m² cos⁴α)` (eqs 6–7) and the geometric attenuation
//! `G = min(1, 2(n·h)(n·v)/(v·h), 2(n·h)(n·l)/(v·h))` (eq 8).
//!
//! Robustness, where the printed formulas divide by zero or overflow:
//! - `G/((n·v)(n·l))` is evaluated as `min(1/((n·v)(n·l)), 2(n·h)/((v·h)(n·l)), 2(n·h)/((v·h)(n·v)))`, whose
//!   value at `n·v = 0` or `n·l = 0` is the finite grazing limit;
//! - `D` is evaluated in logs with `tan²α = |n×h|²/(n·h)²`, so it goes smoothly to 0 as `h` tilts away from `n`
//!   and never forms `0·∞` (the per-normal form of an ellipsoid's sphere grid, [`TowardPair::f_unit`], takes
//!   `exp(−tan²α/m²)/(π m² cos⁴α)` and 0 where the exponential nears underflow);
//! - directions strictly below the surface's horizon reflect nothing (`f = 0`);
//! - `v = −l` leaves the half vector undefined; the specular limit there depends on the path of approach (the
//!   reference table notes `+∞` along `θ_v = θ_l → 90°`) and no light arrives (`n·l = 0`), so the specular
//!   term is reported as 0 with [`BrdfRegime::BackScatterUndefined`].
//!
//! The facet form is the paper's simplification: the target is a facet whose normal is the half vector, so
//! `D = 1/(π m²)`, `G = 1` and `(n·v)(n·l) = (v·h)²`; it diverges as `1/(v·h)²` as the sun moves behind the
//! target. [`crate::physics::reflection`] also offers the general form averaged over an ellipsoid's visible
//! surface, which stays bounded.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use std::f64::consts::PI;

/// Below this length of `v + l` the half vector is treated as undefined.
const HALF_VECTOR_MIN: f64 = 1e-12;
/// Most normals [`TowardPair::f_unit_lanes`] takes at once.
pub const LANES: usize = 64;

/// An invalid BRDF parameter: its name, value and allowed range.
pub type BrdfError = super::ParamError;

/// Material parameters of the Cook–Torrance model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CookTorrance {
    /// Diffuse coefficient `k_d`, [0, 1].
    pub kd: f64,
    /// Specular coefficient `k_s`, [0, 1]; the paper takes `k_d + k_s = 1`.
    pub ks: f64,
    /// Reflectance at normal incidence `f0`, [0, 1].
    pub f0: f64,
    /// Beckmann roughness `m` (RMS slope), [1e-4, 10].
    pub roughness: f64,
}

impl Default for CookTorrance {
    /// Painted aluminium skin as a moderate specular reflector: `k_d = k_s = 0.5`, `f0 = 0.04`, `m = 0.3`.
    fn default() -> Self {
        Self { kd: 0.5, ks: 0.5, f0: 0.04, roughness: 0.3 }
    }
}

/// Which case of the model produced a value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BrdfRegime {
    /// Both directions strictly above the horizon: the formula as printed.
    Regular,
    /// `n·v = 0` or `n·l = 0`: the finite limit of the specular term.
    GrazingLimit,
    /// A direction strictly below the horizon: no reflection.
    BelowHorizon,
    /// `v = −l`: half vector undefined, specular term reported as 0.
    BackScatterUndefined,
}

/// [`CookTorrance::evaluate`]'s `f` for one pair of directions and any normal ([`CookTorrance::toward`]).
#[derive(Debug, Clone, Copy)]
pub struct TowardPair<'a> {
    brdf: &'a CookTorrance,
    /// The unit viewer and light directions (zero for a zero input).
    v: DVec3,
    l: DVec3,
    /// [`CookTorrance::half`] of `v + l`.
    half: Option<(DVec3, f64, f64)>,
    /// `ln(π m²)`.
    ln_pi_m2: f64,
    /// `m²` and `π m²`.
    m2: f64,
    pi_m2: f64,
}

impl TowardPair<'_> {
    /// `f`, sr⁻¹, for the normal `n` (any length; zero gives 0): the operations of [`CookTorrance::evaluate`]
    /// that depend on `n`, in its order.
    #[inline]
    pub fn f_per_sr(&self, n: DVec3) -> f64 {
        let n = n.normalize_or_zero();
        if n == DVec3::ZERO || self.v == DVec3::ZERO || self.l == DVec3::ZERO {
            return 0.0;
        }
        self.f_with(n, n.dot(self.v), n.dot(self.l), |nh, sin| beckmann_in_logs(nh, sin(), self.m2, self.ln_pi_m2))
    }

    /// `f`, sr⁻¹, for a unit normal `n` with `nv = n·v` and `nl = n·l` already in hand (0 where either is
    /// negative, as [`TowardPair::f_per_sr`] gives): `f_per_sr` without normalising `n` again, and Beckmann's `D`
    /// as `exp(−tan²α/m²)/(π m² cos⁴α)` instead of through logarithms (one `exp` and no `ln`). It agrees with
    /// `f_per_sr` within 1e-13 relative (test `unit_normal_form_matches_the_general_form`; the log form's own
    /// rounding grows with the exponent); where `exp(−tan²α/m²)` is at or below e⁻⁷⁰⁸ (3.3e-308), so far in the
    /// lobe's tail that it nears underflow, the specular part is 0.
    /// The ellipsoid's reflectance takes it for many normals at once ([`TowardPair::f_unit_lanes`]).
    #[inline]
    pub fn f_unit(&self, n: DVec3, nv: f64, nl: f64) -> f64 {
        self.f_with(n, nv, nl, |nh, sin| {
            if !(nh > 0.0) {
                return 0.0;
            }
            let t = sin() / nh;
            let exponent = -(t * t) / self.m2;
            // exp underflows below about −708 (normal) and −745 (subnormal): 0 there, and no 0/0 from cos⁴α
            if !(exponent > -708.0) {
                return 0.0;
            }
            let c2 = nh * nh;
            exponent.exp() / (self.pi_m2 * (c2 * c2))
        })
    }

    /// [`TowardPair::f_unit`] of many normals: lane `k` of `f` is `f_unit(n[k], nv[k], nl[k])` to the bit, the
    /// normals given by component (all slices of one length, at most [`LANES`]). The operations of `f_unit`, in
    /// its order, run as one loop of selects that the caller's vector width compiles (inside
    /// [`crate::physics::simd::widest`]), all but the exponential; a second loop takes each lane's exponential, the
    /// one call, where its lobe needs it, and finishes the lane.
    #[inline(always)]
    pub fn f_unit_lanes(&self, [nx, ny, nz]: [&[f64]; 3], nv: &[f64], nl: &[f64], f: &mut [f64]) {
        let count = f.len();
        assert!(count <= LANES && [nx.len(), ny.len(), nz.len(), nv.len(), nl.len()].iter().all(|&n| n == count));
        let diffuse = self.brdf.kd / PI;
        let Some((h, vh, fresnel)) = self.half else {
            for k in 0..count {
                let (nv, nl) = (nv[k] + 0.0, nl[k] + 0.0);
                f[k] = if nv >= 0.0 && nl >= 0.0 { diffuse } else { 0.0 };
            }
            return;
        };
        // per lane: whether f is not 0, the exponent, the distribution's denominator, G/((n·v)(n·l)), and
        // whether the exponential is taken (else D is 0)
        let (mut ok, mut need) = ([false; LANES], [false; LANES]);
        let (mut exponent, mut below, mut g_over) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        for k in 0..count {
            let (nv, nl) = (nv[k] + 0.0, nl[k] + 0.0);
            let (x, y, z) = (nx[k], ny[k], nz[k]);
            let nh = (x * h.x + y * h.y) + z * h.z;
            // |n × h|
            let (cx, cy, cz) = (y * h.z - h.y * z, z * h.x - h.z * x, x * h.y - h.x * y);
            let t = ((cx * cx + cy * cy) + cz * cz).sqrt() / nh;
            let e = -(t * t) / self.m2;
            let c2 = nh * nh;
            ok[k] = nv >= 0.0 && nl >= 0.0;
            need[k] = ok[k] && nh > 0.0 && e > -708.0;
            exponent[k] = e;
            below[k] = self.pi_m2 * (c2 * c2);
            g_over[k] = (1.0 / (nv * nl)).min(2.0 * nh / (vh * nl)).min(2.0 * nh / (vh * nv));
        }
        let ks = self.brdf.ks;
        for k in 0..count {
            // D ≠ 0 only where n·h > 0, so specular_term's own test of n·h passes wherever D is not 0
            let d = if need[k] { exponent[k].exp() / below[k] } else { 0.0 };
            let specular = if d == 0.0 { 0.0 } else { fresnel * d * g_over[k] / PI };
            f[k] = if ok[k] { diffuse + ks * specular } else { 0.0 };
        }
    }

    /// `f` for the unit normal `n` with `nv = n·v` and `nl = n·l` (0 where either is negative), Beckmann's `D`
    /// from `distribution(n·h, || |n×h|)`: the diffuse part, and the specular part where `h` is defined and `D`
    /// is not 0.
    #[inline(always)]
    fn f_with(&self, n: DVec3, nv: f64, nl: f64, distribution: impl Fn(f64, &dyn Fn() -> f64) -> f64) -> f64 {
        // as in `evaluate_unit`: −0.0 to +0.0, so that 1/(n·v) at grazing is +∞
        let (nv, nl) = (nv + 0.0, nl + 0.0);
        if !(nv >= 0.0 && nl >= 0.0) {
            return 0.0;
        }
        let brdf = self.brdf;
        let diffuse = brdf.kd / PI;
        let Some((h, vh, fresnel)) = self.half else {
            return diffuse;
        };
        let nh = n.dot(h);
        let d = distribution(nh, &|| n.cross(h).length());
        diffuse + brdf.ks * specular_term(fresnel, d, nh, nv, nl, vh)
    }
}

/// Beckmann's `D` for the angle between `n` and `h` given by its cosine and sine, with `m²` and `ln(π m²)`.
#[inline]
fn beckmann_in_logs(cos_a: f64, sin_a: f64, m2: f64, ln_pi_m2: f64) -> f64 {
    if !(cos_a > 0.0) {
        return 0.0;
    }
    let tan2 = (sin_a / cos_a) * (sin_a / cos_a);
    (-tan2 / m2 - ln_pi_m2 - 4.0 * cos_a.ln()).exp()
}

/// The specular term `F·D·G/(π (n·v)(n·l))` (0 where `D` is 0 or `n·h ≤ 0`), with `G/((n·v)(n·l))` formed
/// without 0/0 at grazing incidence.
#[inline]
fn specular_term(fresnel: f64, distribution: f64, nh: f64, nv: f64, nl: f64, vh: f64) -> f64 {
    if distribution == 0.0 || nh <= 0.0 {
        return 0.0;
    }
    let g_over = (1.0 / (nv * nl)).min(2.0 * nh / (vh * nl)).min(2.0 * nh / (vh * nv));
    fresnel * distribution * g_over / PI
}

/// The value of the BRDF for one pair of directions, with its parts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BrdfValue {
    /// `f`, sr⁻¹.
    pub f_per_sr: f64,
    /// The specular term `F·D·G/(π (n·v)(n·l))` before the factor `k_s`, sr⁻¹.
    pub specular_per_sr: f64,
    /// Fresnel term F.
    pub fresnel: f64,
    /// Beckmann distribution D.
    pub distribution: f64,
    /// Geometric attenuation G.
    pub geometry: f64,
    /// Which case applied.
    pub regime: BrdfRegime,
}

impl BrdfValue {
    fn zero(regime: BrdfRegime) -> Self {
        Self { f_per_sr: 0.0, specular_per_sr: 0.0, fresnel: 0.0, distribution: 0.0, geometry: 0.0, regime }
    }
}

impl CookTorrance {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`BrdfError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), BrdfError> {
        let unit = |name, value: f64| {
            if (0.0..=1.0).contains(&value) { Ok(()) } else { Err(BrdfError { name, value, range: "[0, 1]".into() }) }
        };
        unit("kd", self.kd)?;
        unit("ks", self.ks)?;
        unit("f0", self.f0)?;
        if !(1e-4..=10.0).contains(&self.roughness) {
            return Err(BrdfError { name: "roughness", value: self.roughness, range: "[1e-4, 10]".into() });
        }
        Ok(())
    }

    /// Schlick's Fresnel term (eq 5) for `v·h = cos_vh`.
    pub fn fresnel(&self, cos_vh: f64) -> f64 {
        let c = cos_vh.clamp(0.0, 1.0);
        self.f0 + (1.0 - self.f0) * (1.0 - c).powi(5)
    }

    /// An upper bound on `f·(n·l)` over every normal `n` that sees both unit directions `v` and `l`, sr⁻¹: the
    /// most a surface element (or the paper's facet, or an average over a body) can reflect per unit of
    /// irradiance. `k_d/π` bounds the diffuse part; the specular part is `k_s·F·D·G/(π (n·v))`, where `F`
    /// depends on `v·h` alone, `G/(n·v) ≤ 2(n·h)/(v·h) ≤ 2/(v·h)`, and Beckmann's `D` is largest at `tan²α =
    /// 2m² − 1` when `m² > ½` (else at `α = 0`). Infinite when `v = −l`.
    pub fn max_reflectance(&self, v: DVec3, l: DVec3) -> f64 {
        let vh = 0.5 * (v.normalize_or_zero() + l.normalize_or_zero()).length();
        let m2 = self.roughness * self.roughness;
        let d_max = if m2 > 0.5 { 4.0 * m2 * (1.0 / m2 - 2.0).exp() / PI } else { 1.0 / (PI * m2) };
        let specular = self.ks * self.fresnel(vh) * d_max * 2.0 / (PI * vh);
        let bound = self.kd / PI + specular;
        if bound.is_nan() { f64::INFINITY } else { bound }
    }

    /// Beckmann distribution (eq 6) for the angle between `n` and `h` given by its cosine and sine.
    fn beckmann(&self, cos_a: f64, sin_a: f64) -> f64 {
        let m2 = self.roughness * self.roughness;
        beckmann_in_logs(cos_a, sin_a, m2, (PI * m2).ln())
    }

    /// The general form (eq 4) for unit normal `n`, unit direction to the viewer `v` and to the light `l`.
    ///
    /// Inputs need not be normalised; zero vectors give [`BrdfRegime::BelowHorizon`].
    pub fn evaluate(&self, n: DVec3, v: DVec3, l: DVec3) -> BrdfValue {
        let (n, v, l) = (n.normalize_or_zero(), v.normalize_or_zero(), l.normalize_or_zero());
        if n == DVec3::ZERO || v == DVec3::ZERO || l == DVec3::ZERO {
            return BrdfValue::zero(BrdfRegime::BelowHorizon);
        }
        self.evaluate_unit(n.dot(v), n.dot(l), n, v + l)
    }

    /// [`CookTorrance::evaluate`] for one viewer direction `v` and light direction `l` and many normals: what
    /// depends on `v` and `l` alone (their normalisation, the half vector, `v·h`, the Fresnel term) is worked
    /// out once here, and [`TowardPair::f_per_sr`] gives `evaluate(n, v, l).f_per_sr`, the same bits, per normal.
    pub fn toward(&self, v: DVec3, l: DVec3) -> TowardPair<'_> {
        let (v, l) = (v.normalize_or_zero(), l.normalize_or_zero());
        let m2 = self.roughness * self.roughness;
        TowardPair { brdf: self, v, l, half: self.half(v + l), ln_pi_m2: (PI * m2).ln(), m2, pi_m2: PI * m2 }
    }

    /// The half vector `h`, `v·h` and the Fresnel term for `sum = v + l` (unit `v`, `l`); `None` where `v + l` is
    /// shorter than [`HALF_VECTOR_MIN`] and `h` is undefined.
    fn half(&self, sum: DVec3) -> Option<(DVec3, f64, f64)> {
        let len = sum.length();
        if len < HALF_VECTOR_MIN {
            return None;
        }
        // |v + l|² = 2 + 2 v·l, so v·h = (1 + v·l)/|v + l| = |v + l|/2, without cancellation near v = −l.
        let vh = (0.5 * len).min(1.0);
        Some((sum / len, vh, self.fresnel(vh)))
    }

    /// The general form with the normal along +z, from zenith angles of view and light and the azimuth between
    /// them (180° = the mirror side), all in degrees.
    ///
    /// The half vector is formed from sum-to-product identities rather than by adding the two direction
    /// vectors, which keeps full precision near the mirror direction at grazing angles.
    pub fn evaluate_angles(&self, view_zenith_deg: f64, light_zenith_deg: f64, azimuth_deg: f64) -> BrdfValue {
        let (_, cos_v) = sin_cos_deg(view_zenith_deg);
        let (sin_l, cos_l) = sin_cos_deg(light_zenith_deg);
        let (sin_p, _) = sin_cos_deg(azimuth_deg);
        let (_, cos_half_p) = sin_cos_deg(0.5 * azimuth_deg);
        let (_, cos_mean) = sin_cos_deg(0.5 * (view_zenith_deg + light_zenith_deg));
        let (sin_half_diff, _) = sin_cos_deg(0.5 * (view_zenith_deg - light_zenith_deg));
        // v = (sin θv, 0, cos θv), l = (sin θl cos φ, sin θl sin φ, cos θl);
        // sin θv + sin θl cos φ = (sin θv − sin θl) + sin θl (1 + cos φ)
        let sum = DVec3::new(
            2.0 * cos_mean * sin_half_diff + 2.0 * sin_l * cos_half_p * cos_half_p,
            sin_l * sin_p,
            cos_v + cos_l,
        );
        self.evaluate_unit(cos_v, cos_l, DVec3::Z, sum)
    }

    /// The general form from `n·v`, `n·l`, the unit normal and `v + l` (all for unit `v`, `l`).
    fn evaluate_unit(&self, nv: f64, nl: f64, n: DVec3, sum: DVec3) -> BrdfValue {
        // `+ 0.0` turns −0.0 into +0.0, so that 1/(n·v) at grazing is +∞, never −∞.
        let (nv, nl) = (nv + 0.0, nl + 0.0);
        if !(nv >= 0.0 && nl >= 0.0) {
            return BrdfValue::zero(BrdfRegime::BelowHorizon);
        }
        let diffuse = self.kd / PI;
        let Some((h, vh, fresnel)) = self.half(sum) else {
            let mut value = BrdfValue::zero(BrdfRegime::BackScatterUndefined);
            value.f_per_sr = diffuse;
            return value;
        };
        let nh = n.dot(h);
        let distribution = self.beckmann(nh, n.cross(h).length());
        let geometry = (2.0 * nh * nv / vh).min(2.0 * nh * nl / vh).clamp(0.0, 1.0);
        let regime = if nv > 0.0 && nl > 0.0 { BrdfRegime::Regular } else { BrdfRegime::GrazingLimit };
        let specular = specular_term(fresnel, distribution, nh, nv, nl, vh);
        BrdfValue {
            f_per_sr: diffuse + self.ks * specular,
            specular_per_sr: specular,
            fresnel,
            distribution,
            geometry,
            regime,
        }
    }

    /// The paper's facet form: the facet normal is the half vector of `v` and `l`.
    pub fn evaluate_facet(&self, v: DVec3, l: DVec3) -> BrdfValue {
        let (v, l) = (v.normalize_or_zero(), l.normalize_or_zero());
        if v == DVec3::ZERO || l == DVec3::ZERO {
            return BrdfValue::zero(BrdfRegime::BelowHorizon);
        }
        let diffuse = self.kd / PI;
        let sum = v + l;
        let len = sum.length();
        if len < HALF_VECTOR_MIN {
            let mut value = BrdfValue::zero(BrdfRegime::BackScatterUndefined);
            value.f_per_sr = diffuse;
            return value;
        }
        let vh = (0.5 * len).min(1.0);
        let fresnel = self.fresnel(vh);
        let distribution = 1.0 / (PI * self.roughness * self.roughness);
        let specular = fresnel * distribution / (PI * vh * vh);
        BrdfValue {
            f_per_sr: diffuse + self.ks * specular,
            specular_per_sr: specular,
            fresnel,
            distribution,
            geometry: 1.0,
            regime: BrdfRegime::Regular,
        }
    }
}

/// Unit vector at `zenith_deg` from +z and `azimuth_deg` from +x toward +y.
///
/// Near the horizon the cosine is taken as the sine of the complement, which keeps full relative precision.
pub fn direction_from_zenith(zenith_deg: f64, azimuth_deg: f64) -> DVec3 {
    let (sin_z, cos_z) = sin_cos_deg(zenith_deg);
    let (sin_a, cos_a) = sin_cos_deg(azimuth_deg);
    DVec3::new(sin_z * cos_a, sin_z * sin_a, cos_z)
}

/// `(sin, cos)` of an angle in degrees, exact at multiples of 90° and precise next to them.
pub fn sin_cos_deg(deg: f64) -> (f64, f64) {
    let r = deg.rem_euclid(360.0);
    // reduce to [-45, 45] around the nearest multiple of 90
    let quadrant = (r / 90.0).round();
    let rest = (r - quadrant * 90.0).to_radians();
    let (s, c) = rest.sin_cos();
    match quadrant as i64 % 4 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_deg_is_exact_at_right_angles() {
        assert_eq!(sin_cos_deg(90.0), (1.0, 0.0));
        assert_eq!(sin_cos_deg(180.0).1, -1.0);
        assert_eq!(sin_cos_deg(-90.0).0, -1.0);
        let (s, c) = sin_cos_deg(30.0);
        assert!((s - 0.5).abs() < 2e-16 && (c - 0.75f64.sqrt()).abs() < 2e-16);
    }

    #[test]
    fn max_reflectance_bounds_every_normal() {
        let dir = |th: f64, ph: f64| DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
        for m in [0.05, 0.3, 0.8, 2.0] {
            let brdf = CookTorrance { kd: 0.4, ks: 0.6, f0: 0.04, roughness: m };
            for (v, l) in
                [(dir(0.3, 0.0), dir(0.9, 2.5)), (dir(1.2, 0.0), dir(1.1, 3.0)), (dir(0.0, 0.0), dir(0.5, 1.0))]
            {
                let bound = brdf.max_reflectance(v, l);
                for i in 0..60 {
                    for j in 0..120 {
                        let n = dir(std::f64::consts::FRAC_PI_2 * (i as f64 + 0.5) / 60.0, 0.0523 * j as f64);
                        let f = brdf.evaluate(n, v, l).f_per_sr * n.dot(l).max(0.0);
                        assert!(f <= bound * (1.0 + 1e-12), "m {m}: {f} > {bound}");
                    }
                }
                assert!(brdf.evaluate_facet(v, l).f_per_sr * 0.5 * (v + l).length() <= bound);
            }
        }
    }

    #[test]
    fn a_pair_s_value_is_evaluate_s_bit_for_bit() {
        // unnormalised, grazing, below the horizon, opposite and nearly opposite (|v + l| under the half
        // vector's threshold, not 0), mirrored, equal and zero directions, several materials
        let dir = |th: f64, ph: f64, r: f64| r * DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
        let mut pairs = vec![
            (DVec3::Z, -DVec3::Z),
            (DVec3::X, -DVec3::X),
            (DVec3::X, -DVec3::X + 1e-14 * DVec3::Z),
            (2.0 * DVec3::Z, -DVec3::Z + 3e-13 * DVec3::Y),
            (DVec3::Z, DVec3::Z),
            (DVec3::ZERO, DVec3::Z),
            (DVec3::X, DVec3::ZERO),
            (dir(1.0, 0.2, 3.0), dir(1.0, 0.2 + std::f64::consts::PI, 0.5)),
        ];
        // the nearly opposite pairs take the undefined half vector's branch without |v + l| being 0
        for &(v, l) in &pairs[2..4] {
            let len = (v.normalize() + l.normalize()).length();
            assert!(len > 0.0 && len < HALF_VECTOR_MIN, "{len}");
        }
        for k in 0..40 {
            let t = k as f64;
            pairs.push((dir(0.08 * t, 0.7 * t, 1.0 + 0.1 * t), dir(3.1 - 0.077 * t, 1.3 * t, 0.3 + 0.05 * t)));
        }
        let mut normals = vec![DVec3::ZERO, DVec3::X, DVec3::Z, -DVec3::Z];
        for i in 0..24 {
            for j in 0..48 {
                normals.push(dir(
                    std::f64::consts::PI * (i as f64 + 0.5) / 24.0,
                    0.1309 * j as f64,
                    0.5 + 0.01 * j as f64,
                ));
            }
        }
        for m in [1e-4, 0.05, 0.3, 2.0] {
            let brdf = CookTorrance { kd: 0.3, ks: 0.7, f0: 0.04, roughness: m };
            for &(v, l) in &pairs {
                let pair = brdf.toward(v, l);
                for &n in &normals {
                    let (want, got) = (brdf.evaluate(n, v, l).f_per_sr, pair.f_per_sr(n));
                    assert_eq!(want.to_bits(), got.to_bits(), "m {m}, n {n}, v {v}, l {l}: {want} against {got}");
                }
            }
        }
    }

    #[test]
    fn lanes_are_f_unit_bit_for_bit() {
        // normals all round the sphere (n·v and n·l of either sign, the lobe's centre and its far tail, and
        // grazing: n·v or n·l exactly 0 or −0), in blocks of every length from 1 to LANES, against f_unit one at
        // a time, both at the baseline's width and inside `widest` (the CPU's)
        let dir = |theta: f64, phi: f64| DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let mut specular = 0;
        for m in [1e-4, 0.05, 0.3, 2.0, 10.0] {
            let brdf = CookTorrance { kd: 0.3, ks: 0.7, f0: 0.04, roughness: m };
            for (v, l) in [
                (DVec3::Z, DVec3::Z),
                (dir(0.4, 0.3), dir(1.2, 2.9)),
                (dir(1.5, 0.0), dir(1.5, 3.0)),
                (DVec3::X, -DVec3::X),
            ] {
                let pair = brdf.toward(v, l);
                let normals: Vec<DVec3> = (0..2100)
                    .map(|i| dir(std::f64::consts::PI * (i as f64 + 0.5) / 2100.0, 2.399_963 * i as f64))
                    .collect();
                let mut start = 0;
                for count in (1..=LANES).cycle() {
                    if start + count > normals.len() {
                        break;
                    }
                    let block = &normals[start..start + count];
                    let component = |c: usize| block.iter().map(|n| n[c]).collect::<Vec<f64>>();
                    // every few lanes n·v or n·l set to 0 or −0 (f_unit takes them as given)
                    let grazing = |k: usize, x: f64, y: f64| match (start + k) % 13 {
                        3 => (0.0, y),
                        5 => (-0.0, y),
                        7 => (x, 0.0),
                        9 => (x, -0.0),
                        _ => (x, y),
                    };
                    let (nv, nl): (Vec<f64>, Vec<f64>) =
                        block.iter().enumerate().map(|(k, n)| grazing(k, n.dot(v), n.dot(l))).unzip();
                    let (x, y, z) = (component(0), component(1), component(2));
                    let (mut f, mut wide) = (vec![0.0; count], vec![0.0; count]);
                    pair.f_unit_lanes([&x, &y, &z], &nv, &nl, &mut f);
                    crate::physics::simd::widest(
                        #[inline(always)]
                        || pair.f_unit_lanes([&x, &y, &z], &nv, &nl, &mut wide),
                    );
                    for (k, n) in block.iter().enumerate() {
                        let want = pair.f_unit(*n, nv[k], nl[k]);
                        assert_eq!(f[k].to_bits(), want.to_bits(), "m {m}, n {n}, v {v}, l {l}: {} {want}", f[k]);
                        assert_eq!(wide[k].to_bits(), want.to_bits(), "widest: m {m}, n {n}, v {v}, l {l}");
                        specular += usize::from(want > brdf.kd / PI * (1.0 + 1e-9));
                    }
                    start += count;
                }
            }
        }
        assert!(specular > 1000, "{specular}");
    }

    #[test]
    fn unit_normal_form_matches_the_general_form() {
        // direction pairs like the bit-for-bit test's, and a finer grid of unit normals, every one that sees both
        let dir = |theta: f64, phi: f64| DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let mut pairs = vec![(DVec3::Z, DVec3::Z), (DVec3::Y, DVec3::new(0.3, -0.5, 0.8).normalize())];
        for k in 1..12 {
            let t = k as f64;
            pairs.push((dir(0.08 * t, 0.7 * t), dir(3.1 - 0.077 * t, 1.3 * t)));
        }
        let (mut compared, mut specular) = (0, 0);
        for m in [1e-4, 0.05, 0.3, 2.0, 10.0] {
            let brdf = CookTorrance { kd: 0.3, ks: 0.7, f0: 0.04, roughness: m };
            for &(v, l) in &pairs {
                let pair = brdf.toward(v, l);
                for i in 0..96 {
                    for j in 0..192 {
                        let n = dir(std::f64::consts::PI * (i as f64 + 0.5) / 96.0, 0.0327 * j as f64);
                        let (nv, nl) = (n.dot(v), n.dot(l));
                        if !(nv > 0.0 && nl > 0.0) {
                            continue;
                        }
                        let (want, got) = (pair.f_per_sr(n), pair.f_unit(n, nv, nl));
                        let tolerance = 1e-13 * want.abs().max(brdf.kd / PI);
                        assert!((want - got).abs() <= tolerance, "m {m}, n {n}, v {v}, l {l}: {want} against {got}");
                        compared += 1;
                        specular += usize::from(want > brdf.kd / PI * (1.0 + 1e-9));
                    }
                }
            }
        }
        // the comparison reached the specular lobe, not only the diffuse floor
        assert!(compared > 50_000 && specular > 5_000, "{compared} compared, {specular} with a specular part");
    }

    #[test]
    fn below_horizon_is_zero() {
        let ct = CookTorrance::default();
        let v = ct.evaluate(DVec3::Z, DVec3::new(0.0, 1.0, -0.1), DVec3::Z);
        assert_eq!(v.f_per_sr, 0.0);
        assert_eq!(v.regime, BrdfRegime::BelowHorizon);
    }

    #[test]
    fn opposite_directions_are_finite() {
        let ct = CookTorrance::default();
        let v = ct.evaluate_angles(90.0, 90.0, 180.0);
        assert!(v.f_per_sr.is_finite());
        assert_eq!(v.regime, BrdfRegime::BackScatterUndefined);
        let f = ct.evaluate_facet(DVec3::X, -DVec3::X);
        assert!(f.f_per_sr.is_finite());
    }

    #[test]
    fn facet_form_at_normal_incidence() {
        let ct = CookTorrance { kd: 0.5, ks: 0.5, f0: 0.04, roughness: 0.2 };
        let f = ct.evaluate_facet(DVec3::Z, DVec3::Z);
        let want = 0.5 / PI + 0.5 * 0.04 / (PI * 0.04) / PI;
        assert!((f.f_per_sr - want).abs() < 1e-15);
        // At normal incidence the general form with n = v = l agrees.
        let g = ct.evaluate(DVec3::Z, DVec3::Z, DVec3::Z);
        assert!((g.f_per_sr - want).abs() < 1e-15);
    }
}
