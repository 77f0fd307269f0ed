//! The clear sky and the ground as a radiance field over the view direction's elevation.
//!
//! With a LOWTRAN weather the sky, the limb and the paths to the ground are LOWTRAN's by default
//! ([`ClearSkyModel::Lowtran`]: every ray traced through the table, [`super::lowtran_paths::ClearSky`]); the
//! ground's emission and reflection are as below. Otherwise, or with [`ClearSkyModel::Parametric`], this module's
//! own documented model:
//!
//! **Sky** (elevation `e > 0`): a plane-parallel atmosphere whose absorber (water vapour, and CO₂ in the
//! 4.3 µm band) falls off with scale height `H` above sea level. Its zenith optical depth above the observer
//! at altitude `h` is `τ_z(h) = −ln(1 − ε_z0)·e^{−h/H}`, where `ε_z0` is the band's zenith emissivity at sea
//! level, so along elevation `e` the path's emissivity is `ε(e) = 1 − exp(−τ_z/sin e)`: small toward the
//! zenith, 1 at the horizon. The path emits at the air temperature of eq 2 at the height `h + z_e·sin e`,
//! where most of its emission comes from (`z_e` the emission height, about one absorber scale height):
//! `L(e) = ε(e)·B(T∞(h + z_e sin e))`. So the sky's radiance rises toward the horizon, where it reaches the
//! air's own temperature.
//!
//! **Limb** (`−dip < e < 0`, `dip = acos(R/(R + h))` the horizon's dip on an Earth of radius R): the ray passes
//! above the ground, down to its tangent height `(R + h)·cos e − R`, through hundreds of kilometres of air; it is
//! taken as opaque, emitting at the air temperature where the straight path to the tangent point reaches half
//! its optical depth (as ground paths below), so the sky brightens smoothly from `B(T∞(h))` at the horizontal
//! to the lower air's at the visible horizon and joins the ground's haze there.
//!
//! **Ground** (`e ≤ −dip`, flat Earth beyond that): the line of sight meets the ground after
//! `d = h/sin|e|`; the ground emits `ε_g·B(T_g)` and reflects `(1 − ε_g)` of the sky at the mirror elevation;
//! the path transmits `τ(d)` of it (the scenario's transmittance model) and adds `(1 − τ)·B(T∞(z_p))`, where
//! `z_p` is the height at which the path has reached half its optical depth: a near-horizontal path emits at
//! about the observer's height (so the ground joins the sky at the horizon without a step), a steep one lower.
//!
//! With a LOWTRAN atmosphere the ground and limb paths' transmittance and path radiance are LOWTRAN's (from the
//! observer's table of [`super::lowtran_paths`]), and `ε_z0` defaults to the band's emissivity of LOWTRAN's
//! vertical path from sea level to 20 km for the scene's weather.
//!
//! Not modelled: scattered sunlight (it matters in the MWIR by day), clouds (a sky-plane layer adds them),
//! Earth's curvature beyond the horizon's dip, and the spectral structure of absorption (a single effective emissivity per band).
//! Defaults: `ε_z0 = 0.28` for bands centred beyond 6 µm and 0.35 below (the opaque 4.3 µm CO₂ band raises the
//! MWIR value), `H = 2 km`, `z_e = 1.5 km`, ground 5 K above the sea-level air with `ε_g = 0.95`. With them a
//! sea-level observer sees an 8–12 µm zenith sky at about 225 K brightness temperature, within the 210–240 K
//! that clear mid-latitude skies show.

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use super::ParamError;
use super::atmosphere::{AirTemperature, MAX_ALTITUDE_M, MIN_ALTITUDE_M};
use super::lowtran_paths::ClearSky;
use super::planck::{Band, Measure, band_radiance_in};
use super::transmittance::PathTransmittance;

/// Mean Earth radius, m.
const EARTH_RADIUS_M: f64 = 6.371e6;

/// Samples of the radiance table over `sin e ∈ [−1, 1]`.
const TABLE_SAMPLES: usize = 8193;

/// Parameters of the clear sky and the ground.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DomeSpec {
    /// Where the clear sky above the ground comes from; `None`: LOWTRAN with an `atmosphere.model`, else the
    /// parametric model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clear_sky: Option<ClearSkyModel>,
    /// Parametric sky: zenith emissivity of the whole atmosphere seen from sea level, (0, 1); `None` takes the
    /// band's default (LOWTRAN's vertical path with an `atmosphere.model`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zenith_emissivity: Option<f64>,
    /// Parametric sky: scale height of the absorber, km, > 0; `None` is 2.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_height_km: Option<f64>,
    /// Parametric sky: height above the observer from which a zenith path's emission comes, km, ≥ 0; `None` is 1.5.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub emission_height_km: Option<f64>,
    /// Ground temperature, K; `None` is 5 K above the sea-level air temperature.
    pub ground_temp_k: Option<f64>,
    /// Ground emissivity, [0, 1].
    pub ground_emissivity: f64,
}

impl Default for DomeSpec {
    fn default() -> Self {
        Self {
            clear_sky: None,
            zenith_emissivity: None,
            scale_height_km: None,
            emission_height_km: None,
            ground_temp_k: None,
            ground_emissivity: 0.95,
        }
    }
}

impl DomeSpec {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let bad = |name, value, range: &str| Err(ParamError { name, value, range: range.into() });
        if let Some(e) = self.zenith_emissivity
            && !(e > 0.0 && e < 1.0)
        {
            return bad("zenith_emissivity", e, "(0, 1)");
        }
        let scale = self.scale_height();
        if !(scale.is_finite() && (0.1..=100.0).contains(&scale)) {
            return bad("scale_height_km", scale, "[0.1, 100] km");
        }
        let emission = self.emission_height();
        if !(emission.is_finite() && (0.0..=20.0).contains(&emission)) {
            return bad("emission_height_km", emission, "[0, 20] km");
        }
        if let Some(t) = self.ground_temp_k
            && !(t.is_finite() && (150.0..=400.0).contains(&t))
        {
            return bad("ground_temp_k", t, "[150, 400] K");
        }
        if !(0.0..=1.0).contains(&self.ground_emissivity) {
            return bad("ground_emissivity", self.ground_emissivity, "[0, 1]");
        }
        Ok(())
    }
}

/// Where the clear sky's radiance comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClearSkyModel {
    /// LOWTRAN7's paths from the observer up through the whole atmosphere (needs `atmosphere.model`).
    Lowtran,
    /// The plane-parallel model of this module (zenith emissivity, scale height, emission height).
    Parametric,
}

impl DomeSpec {
    /// Scale height of the parametric sky's absorber, km.
    pub fn scale_height(&self) -> f64 {
        self.scale_height_km.unwrap_or(2.0)
    }

    /// Emission height of the parametric sky, km.
    pub fn emission_height(&self) -> f64 {
        self.emission_height_km.unwrap_or(1.5)
    }

    /// The parametric sky's fields that the scenario gives, by name.
    pub fn parametric_fields_given(&self) -> Vec<&'static str> {
        [
            ("zenith_emissivity", self.zenith_emissivity.is_some()),
            ("scale_height_km", self.scale_height_km.is_some()),
            ("emission_height_km", self.emission_height_km.is_some()),
        ]
        .into_iter()
        .filter_map(|(n, given)| given.then_some(n))
        .collect()
    }
}

/// Default sea-level zenith emissivity of a band.
pub fn default_zenith_emissivity(band: Band) -> f64 {
    if 0.5 * (band.lo_um() + band.hi_um()) > 6.0 { 0.28 } else { 0.35 }
}

/// The clear sky and ground as seen from one altitude: radiance as a function of the sine of the elevation.
#[derive(Debug, Clone)]
pub struct Dome {
    /// Radiance at `sin e = −1 + 2i/(n − 1)`, in the detector's measure.
    table: Vec<f32>,
    /// Largest `|d²L/de²|`, radiance per rad².
    max_curvature_per_rad2: f64,
    /// Radiance at the horizon, from above.
    horizon_sky: f64,
}

/// Everything a dome depends on.
pub struct DomeInputs<'a> {
    /// The parameters.
    pub spec: DomeSpec,
    /// The detector's band and measure.
    pub band: Band,
    /// Energy or photons.
    pub measure: Measure,
    /// Observer altitude, m.
    pub observer_altitude_m: f64,
    /// Sea-level temperature of eq 2, K.
    pub air: AirTemperature,
    /// Transmittance of ground paths (and their path radiance, where the model has its own).
    pub atmosphere: &'a (dyn PathTransmittance + Sync),
    /// The sea-level zenith emissivity the atmosphere model gives the band (LOWTRAN's vertical path to 20 km),
    /// used where `spec` gives none; `None` takes the band's default.
    pub zenith_emissivity: Option<f64>,
    /// LOWTRAN's clear sky from the observer: with it, every ray that misses the ground (the sky, and the limb
    /// down to the horizon's dip) takes its radiance, and the ground reflects it; the parametric model otherwise.
    pub clear_sky: Option<&'a ClearSky>,
}

impl Dome {
    /// Tabulates the sky and ground radiance for an observer.
    ///
    /// # Errors
    /// [`ParamError`] for invalid parameters, or an observer altitude outside [−5, 86] km.
    pub fn new(inputs: &DomeInputs<'_>) -> Result<Self, ParamError> {
        let s = &inputs.spec;
        s.validate()?;
        let h = inputs.observer_altitude_m;
        if !(MIN_ALTITUDE_M..=MAX_ALTITUDE_M).contains(&h) {
            return Err(ParamError { name: "observer_altitude_m", value: h, range: "[−5000, 86000] m".into() });
        }
        let t_air = |z: f64| {
            inputs.air.at_k(z.clamp(MIN_ALTITUDE_M, MAX_ALTITUDE_M)).map_err(|e| ParamError {
                name: "t0_k",
                value: inputs.air.sea_level_k(),
                range: e.to_string(),
            })
        };
        let planck = |t: f64| band_radiance_in(inputs.measure, inputs.band, t, 1.0);
        let eps_z0 = s
            .zenith_emissivity
            .or(inputs.zenith_emissivity.filter(|e| *e > 0.0 && *e < 1.0))
            .unwrap_or_else(|| default_zenith_emissivity(inputs.band));
        let scale_m = s.scale_height() * 1000.0;
        let tau_z = -(1.0 - eps_z0).ln() * (-h.max(0.0) / scale_m).exp();
        let z_e = s.emission_height() * 1000.0;
        let mut sky_at = Vec::with_capacity(TABLE_SAMPLES);
        // the sky for every positive sin e (also the reflection of the sky in the ground)
        let sky = |sin_e: f64| -> Result<f64, ParamError> {
            if let Some(clear) = inputs.clear_sky {
                return Ok(clear.radiance(sin_e.max(0.0)));
            }
            let eps = if sin_e <= 0.0 { 1.0 } else { -(-tau_z / sin_e).exp_m1() };
            Ok(eps * planck(t_air(h + z_e * sin_e.max(0.0))?))
        };
        let ground_k = match s.ground_temp_k {
            Some(t) => t,
            None => t_air(0.0)? + 5.0,
        };
        let ground = s.ground_emissivity * planck(ground_k);
        let path_air = planck(t_air(h)?);
        // the horizon's dip below the horizontal, from the Earth's curvature
        let dip = (EARTH_RADIUS_M / (EARTH_RADIUS_M + h.max(0.0))).acos();
        for i in 0..TABLE_SAMPLES {
            let sin_e = -1.0 + 2.0 * i as f64 / (TABLE_SAMPLES - 1) as f64;
            let lowtran_sky = inputs.clear_sky.filter(|c| sin_e >= c.lowest_sin_e() && (h > 0.0 || sin_e >= 0.0));
            let value = if let Some(clear) = lowtran_sky {
                clear.radiance(sin_e)
            } else if sin_e > 0.0 || (sin_e == 0.0 && h <= 0.0) {
                sky(sin_e)?
            } else if h <= 0.0 {
                // an observer on the ground sees the ground below the horizon at once
                ground + (1.0 - s.ground_emissivity) * sky(-sin_e)?
            } else if sin_e == 0.0 {
                path_air
            } else if sin_e.asin() > -dip {
                // a grazing ray above the curved Earth's horizon: a long path through the air down to its tangent
                // height (opaque at these lengths), emitting where it reaches half its optical depth on the way
                let cos_e = (1.0 - sin_e * sin_e).max(0.0).sqrt();
                let h_t = ((EARTH_RADIUS_M + h) * cos_e - EARTH_RADIUS_M).max(0.0);
                let reach = ((EARTH_RADIUS_M + h).powi(2) - (EARTH_RADIUS_M + h_t).powi(2)).max(0.0).sqrt();
                let from = DVec3::new(0.0, 0.0, h);
                let tangent = DVec3::new(0.0, reach, h_t);
                let tau = inputs.atmosphere.along_segment(from, tangent).clamp(0.0, 1.0);
                let path = match inputs.atmosphere.path_radiance(from, tangent) {
                    Some(l) => l,
                    None => (1.0 - tau) * planck(t_air(emission_altitude(inputs.atmosphere, from, tangent, tau))?),
                };
                // what passes the tangent point is the horizontal sky seen from its height
                tau * planck(t_air(h_t)?) + path
            } else {
                // the ray meets the curved ground after t = −(R+h)·sin e − √((R+h)²·sin²e − (2Rh + h²)); the path
                // is taken, like the grazing one, as a straight descent over that horizontal distance, so the two
                // agree at the horizon
                if let Some(clear) = inputs.clear_sky {
                    let (tau, path) = clear.ground(sin_e);
                    sky_at.push(tau * (ground + (1.0 - s.ground_emissivity) * sky(-sin_e)?) + path);
                    continue;
                }
                let r_h = EARTH_RADIUS_M + h;
                let t = -r_h * sin_e - (r_h * r_h * sin_e * sin_e - (2.0 * EARTH_RADIUS_M * h + h * h)).max(0.0).sqrt();
                let from = DVec3::new(0.0, 0.0, h);
                let hit = DVec3::new(0.0, t.max(0.0), 0.0);
                let tau = inputs.atmosphere.along_segment(from, hit).clamp(0.0, 1.0);
                let path = match inputs.atmosphere.path_radiance(from, hit) {
                    Some(l) => l,
                    None => (1.0 - tau) * planck(t_air(emission_altitude(inputs.atmosphere, from, hit, tau))?),
                };
                tau * (ground + (1.0 - s.ground_emissivity) * sky(-sin_e)?) + path
            };
            sky_at.push(value);
        }
        // |d²L/de²| by finite differences in e over the table (e = asin(sin e))
        let mut max_curvature_per_rad2: f64 = 0.0;
        for i in 1..TABLE_SAMPLES - 1 {
            let e = |j: usize| (-1.0 + 2.0 * j as f64 / (TABLE_SAMPLES - 1) as f64).asin();
            let (e0, e1, e2) = (e(i - 1), e(i), e(i + 1));
            let (l0, l1, l2) = (sky_at[i - 1], sky_at[i], sky_at[i + 1]);
            let d1 = (l1 - l0) / (e1 - e0);
            let d2 = (l2 - l1) / (e2 - e1);
            let c = 2.0 * (d2 - d1) / (e2 - e0);
            if c.is_finite() {
                max_curvature_per_rad2 = max_curvature_per_rad2.max(c.abs());
            }
        }
        let horizon_sky = sky(1e-9)?;
        Ok(Self { table: sky_at.iter().map(|&v| v as f32).collect(), max_curvature_per_rad2, horizon_sky })
    }

    /// Radiance toward a direction whose elevation has sine `sin_e` (clamped to [−1, 1]), linear in the table.
    #[inline]
    pub fn radiance(&self, sin_e: f64) -> f32 {
        let x = (sin_e.clamp(-1.0, 1.0) + 1.0) * 0.5 * (TABLE_SAMPLES - 1) as f64;
        let i = (x as usize).min(TABLE_SAMPLES - 2);
        let t = (x - i as f64) as f32;
        self.table[i] + (self.table[i + 1] - self.table[i]) * t
    }

    /// Radiance toward world direction `d` (any length).
    #[inline]
    pub fn radiance_toward(&self, d: DVec3) -> f32 {
        let len = d.length();
        if len > 0.0 { self.radiance(d.z / len) } else { self.horizon_sky as f32 }
    }

    /// [`Dome::radiance_toward`] `base + step·i` into `out[i]` (with `only_nan`, only where `out[i]` is NaN), in
    /// f32: the ray `base + step·i` from `base` and `step` rounded to f32, its length's correctly rounded
    /// square root and the division by it, the table's index and fraction, and the interpolation, in that
    /// order. Sixteen pixels go in one AVX-512 register where the CPU has it, with the same operations, so the
    /// values are the same bits on every path. Against [`Dome::radiance_toward`] (f64) the elevation's sine
    /// differs by about 1e-7 and the table's fraction, in f32, is resolved to 5e-4 of a step; the radiance is
    /// within 4.0e-7 of the sky's range (measured by `a_row_of_rays_gives_each_ray_s_radiance`). A zero ray,
    /// which no camera casts, gets the horizon's sky only where it is zero in f32 too.
    #[inline(always)]
    pub fn radiance_along(&self, base: DVec3, step: DVec3, out: &mut [f32], only_nan: bool) {
        self.radiance_along_from(base, step, 0, out, only_nan);
    }

    /// [`Dome::radiance_along`] for the pixels `first..first + out.len()` of the row alone: `out[i]` gets the
    /// ray `base + step·(first + i)`, the same bits as pixel `first + i` of the whole row (the pixel's index
    /// enters as the same f32).
    ///
    /// # Panics
    /// If the pixels reach 2²⁴ (their indices would not be exact in f32).
    #[inline(always)]
    pub fn radiance_along_from(&self, base: DVec3, step: DVec3, first: usize, out: &mut [f32], only_nan: bool) {
        assert!(first + out.len() <= 1 << 24, "pixel indices exact in f32");
        let (base, step) = (base.as_vec3(), step.as_vec3());
        #[cfg(target_arch = "x86_64")]
        let done = {
            use crate::physics::simd::Level;
            let (table, horizon) = (&self.table[..], self.horizon_sky as f32);
            match Level::detect() {
                // SAFETY: the CPU has AVX-512
                Level::Avx512 if table.len() == TABLE_SAMPLES => unsafe {
                    x86::radiance_along_512(table, horizon, base, step, first, out, only_nan)
                },
                // SAFETY: the CPU has AVX2
                Level::Avx2 if table.len() == TABLE_SAMPLES => unsafe {
                    x86::radiance_along_256(table, horizon, base, step, first, out, only_nan)
                },
                _ => 0,
            }
        };
        #[cfg(not(target_arch = "x86_64"))]
        let done = 0;
        for (i, o) in out.iter_mut().enumerate().skip(done) {
            if only_nan && !o.is_nan() {
                continue;
            }
            *o = self.radiance_f32(base, step, first + i);
        }
    }

    /// Pixel `i` of [`Dome::radiance_along`], by the scalar f32 operations its vector blocks repeat.
    #[inline(always)]
    fn radiance_f32(&self, base: Vec3, step: Vec3, i: usize) -> f32 {
        let k = i as f32;
        let (x, y, z) = (base.x + step.x * k, base.y + step.y * k, base.z + step.z * k);
        let len = (x * x + y * y + z * z).sqrt();
        if !(len > 0.0) {
            return self.horizon_sky as f32;
        }
        // max, then min, as the vector path does: a NaN sine (an infinite ray) reads sample 0 on both
        #[allow(clippy::manual_clamp)]
        let sin_e = (z / len).max(-1.0).min(1.0);
        let at = (sin_e + 1.0) * 0.5 * (TABLE_SAMPLES - 1) as f32;
        let j = (at as i32).min(TABLE_SAMPLES as i32 - 2) as usize;
        let frac = at - j as f32;
        let (lo, hi) = (self.table[j], self.table[j + 1]);
        lo + (hi - lo) * frac
    }

    /// Largest `|d²L/de²|` over the sky and ground, radiance per rad² (for the PSF's skip bound).
    pub fn max_curvature_per_rad2(&self) -> f64 {
        self.max_curvature_per_rad2
    }

    /// The sky's radiance just above the horizon.
    pub fn horizon_sky(&self) -> f64 {
        self.horizon_sky
    }
}

/// The dome along a row with AVX-512 or AVX2.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use glam::Vec3;

    use super::TABLE_SAMPLES;

    /// [`Dome::radiance_along_from`](super::Dome::radiance_along_from) for the whole blocks of sixteen pixels
    /// in `out`; returns how many it wrote. Each value is the scalar loop's: the same f32 operations in the same
    /// order (`base + step·i` for the row's pixel `i = first + ` the index in `out`, the squared length summed
    /// x, y, z, a correctly rounded square root and division, the clamp, the index and fraction, the table's
    /// interpolation).
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL); `table` must hold [`TABLE_SAMPLES`] values; `first +
    /// out.len()` must not pass 2²⁴.
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn radiance_along_512(
        table: &[f32],
        horizon: f32,
        base: Vec3,
        step: Vec3,
        first: usize,
        out: &mut [f32],
        only_nan: bool,
    ) -> usize {
        let blocks = out.len() / 16;
        let lanes = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let (zero, one, half) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0), _mm512_set1_ps(0.5));
        let last = _mm512_set1_ps((TABLE_SAMPLES - 1) as f32);
        let top = _mm512_set1_epi32(TABLE_SAMPLES as i32 - 2);
        let horizon = _mm512_set1_ps(horizon);
        let t = table.as_ptr();
        for b in 0..blocks {
            // i as f32, exact (i < 2²⁴)
            let k = _mm512_cvtepi32_ps(_mm512_add_epi32(_mm512_set1_epi32((first + 16 * b) as i32), lanes));
            let axis = |o: f32, s: f32| _mm512_add_ps(_mm512_set1_ps(o), _mm512_mul_ps(_mm512_set1_ps(s), k));
            let (x, y, z) = (axis(base.x, step.x), axis(base.y, step.y), axis(base.z, step.z));
            let dot = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(x, x), _mm512_mul_ps(y, y)), _mm512_mul_ps(z, z));
            let len = _mm512_sqrt_ps(dot);
            let seen = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(len, zero);
            let sin_e = _mm512_min_ps(_mm512_max_ps(_mm512_div_ps(z, len), _mm512_set1_ps(-1.0)), one);
            // zero rays read sample 0, then take the horizon's value
            let sin_e = _mm512_mask_blend_ps(seen, zero, sin_e);
            let at = _mm512_mul_ps(_mm512_mul_ps(_mm512_add_ps(sin_e, one), half), last);
            let i = _mm512_min_epi32(_mm512_cvttps_epi32(at), top);
            let frac = _mm512_sub_ps(at, _mm512_cvtepi32_ps(i));
            // the samples by loads and permutes where the sixteen rays' lie close together (along a row that is
            // about level, as a camera's rows mostly are), else gathered: the same values either way
            let (lo, hi) = match crate::physics::simd::texel_windows(i, 0xffff, true, 0, table.len()) {
                Some((windows, rel, second)) => {
                    use crate::physics::simd::window_fetch16;
                    // SAFETY: `texel_windows` checked that both 32-float windows end inside the table (and that
                    // every lane's index + 1 is inside its window)
                    unsafe {
                        let next = _mm512_add_epi32(rel, _mm512_set1_epi32(1));
                        (window_fetch16(t, windows, rel, second), window_fetch16(t, windows, next, second))
                    }
                }
                // SAFETY: 0 ≤ i ≤ TABLE_SAMPLES − 2, so i and i + 1 are inside the table
                None => unsafe { (_mm512_i32gather_ps::<4>(i, t), _mm512_i32gather_ps::<4>(i, t.add(1))) },
            };
            let v = _mm512_add_ps(lo, _mm512_mul_ps(_mm512_sub_ps(hi, lo), frac));
            let v = _mm512_mask_blend_ps(seen, horizon, v);
            let p = out[16 * b..16 * b + 16].as_mut_ptr();
            // SAFETY: sixteen floats at `p`, inside `out`
            unsafe {
                let v = if only_nan {
                    let old = _mm512_loadu_ps(p);
                    _mm512_mask_blend_ps(_mm512_cmp_ps_mask::<_CMP_UNORD_Q>(old, old), old, v)
                } else {
                    v
                };
                _mm512_storeu_ps(p, v);
            }
        }
        16 * blocks
    }

    /// [`radiance_along_512`] with AVX2, eight pixels a block, the table's two samples of each by
    /// [`pairs8_avx2`](crate::physics::simd::pairs8_avx2): the same operations, so the same values.
    ///
    /// # Safety
    /// The CPU must have AVX2; `table` must hold [`TABLE_SAMPLES`] values; `first + out.len()` must not pass
    /// 2²⁴.
    #[target_feature(enable = "avx2")]
    pub unsafe fn radiance_along_256(
        table: &[f32],
        horizon: f32,
        base: Vec3,
        step: Vec3,
        first: usize,
        out: &mut [f32],
        only_nan: bool,
    ) -> usize {
        let blocks = out.len() / 8;
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let (zero, one, half) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0), _mm256_set1_ps(0.5));
        let last = _mm256_set1_ps((TABLE_SAMPLES - 1) as f32);
        let top = _mm256_set1_epi32(TABLE_SAMPLES as i32 - 2);
        let horizon = _mm256_set1_ps(horizon);
        for b in 0..blocks {
            // i as f32, exact (i < 2²⁴)
            let k = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32((first + 8 * b) as i32), lanes));
            let axis = |o: f32, s: f32| _mm256_add_ps(_mm256_set1_ps(o), _mm256_mul_ps(_mm256_set1_ps(s), k));
            let (x, y, z) = (axis(base.x, step.x), axis(base.y, step.y), axis(base.z, step.z));
            let dot = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(x, x), _mm256_mul_ps(y, y)), _mm256_mul_ps(z, z));
            let len = _mm256_sqrt_ps(dot);
            let seen = _mm256_cmp_ps::<_CMP_GT_OQ>(len, zero);
            let sin_e = _mm256_min_ps(_mm256_max_ps(_mm256_div_ps(z, len), _mm256_set1_ps(-1.0)), one);
            // zero rays read sample 0, then take the horizon's value
            let sin_e = _mm256_blendv_ps(zero, sin_e, seen);
            let at = _mm256_mul_ps(_mm256_mul_ps(_mm256_add_ps(sin_e, one), half), last);
            let i = _mm256_min_epi32(_mm256_cvttps_epi32(at), top);
            let frac = _mm256_sub_ps(at, _mm256_cvtepi32_ps(i));
            // SAFETY: 0 ≤ i ≤ TABLE_SAMPLES − 2, so i and i + 1 are inside the table
            let [(lo, hi)] = unsafe { crate::physics::simd::pairs8_avx2(table, i, [0]) };
            let v = _mm256_add_ps(lo, _mm256_mul_ps(_mm256_sub_ps(hi, lo), frac));
            let v = _mm256_blendv_ps(horizon, v, seen);
            let p = out[8 * b..8 * b + 8].as_mut_ptr();
            // SAFETY: eight floats at `p`, inside `out`
            unsafe {
                let v = if only_nan {
                    let old = _mm256_loadu_ps(p);
                    _mm256_blendv_ps(old, v, _mm256_cmp_ps::<_CMP_UNORD_Q>(old, old))
                } else {
                    v
                };
                _mm256_storeu_ps(p, v);
            }
        }
        8 * blocks
    }
}

/// The altitude a path's emission comes from: where its transmittance from the observer has fallen to
/// `√τ_total` (half its optical depth), found by bisection. A near-horizontal path reaches it close to the
/// observer's altitude, so the ground's haze joins the sky's at the horizon without a step; a steep one lower.
fn emission_altitude(atmosphere: &(dyn PathTransmittance + Sync), from: DVec3, to: DVec3, tau_total: f64) -> f64 {
    let half = tau_total.max(1e-300).sqrt();
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if atmosphere.along_segment(from, from.lerp(to, mid)) > half {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    from.lerp(to, 0.5 * (lo + hi)).z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::planck::brightness_temperature;
    use crate::physics::transmittance::Transmittance;

    fn dome(h: f64, band: Band) -> Dome {
        let atm = Transmittance::BeerLambert { extinction_per_km: 0.15, scale_height_km: 2.0 };
        Dome::new(&DomeInputs {
            spec: DomeSpec::default(),
            band,
            measure: Measure::Energy,
            observer_altitude_m: h,
            air: AirTemperature::default(),
            atmosphere: &atm,
            zenith_emissivity: None,
            clear_sky: None,
        })
        .unwrap()
    }

    #[test]
    fn a_row_of_rays_gives_each_ray_s_radiance() {
        let d = dome(1500.0, Band::LWIR_8_12);
        // the f32 row against the f64 ray: within 2e-6 of the sky's range (4.0e-7 measured: see the eprintln)
        let range = d.table.iter().fold(0.0f32, |m, &v| m.max(v)) - d.table.iter().fold(f32::MAX, |m, &v| m.min(v));
        let mut worst = 0.0f32;
        // rows across the sky, the limb and the ground, one through the zero ray (in f64); with AVX-512 the
        // fourth row's sixteen rays read one window of the table, the first row's two, the second's are gathered
        for (base, step) in [
            (DVec3::new(-0.3, 1.0, 0.2), DVec3::new(0.003, 0.0, -0.0007)),
            (DVec3::new(-0.5, 1.0, -0.9), DVec3::new(0.01, 0.0, 0.011)),
            (DVec3::new(-0.05, 0.0, 0.0), DVec3::new(0.001, 0.0, 0.0)),
            (DVec3::new(-0.4, 1.0, 0.0002), DVec3::new(1.3e-4, 1e-6, -2e-7)),
        ] {
            for n in [1, 15, 16, 17, 100, 2048] {
                let mut row: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { f32::NAN } else { -1.0 }).collect();
                let before = row.clone();
                d.radiance_along(base, step, &mut row, true);
                for (i, (&v, &was)) in row.iter().zip(&before).enumerate() {
                    // (the zero ray of the third row is one only in f64)
                    if was.is_nan() && (base + step * i as f64).length() > 1e-6 {
                        worst = worst.max((v - d.radiance_toward(base + step * i as f64)).abs());
                    } else {
                        assert_eq!(v.to_bits(), was.to_bits(), "pixel {i} of {n} is not NaN: left as it was");
                    }
                }
                d.radiance_along(base, step, &mut row, false);
                for (i, &v) in row.iter().enumerate() {
                    if (base + step * i as f64).length() > 1e-6 {
                        worst = worst.max((v - d.radiance_toward(base + step * i as f64)).abs());
                    }
                }
                // the vector blocks (where the CPU has them) and the scalar loop give the same bits
                let (b, s) = (base.as_vec3(), step.as_vec3());
                for (i, &v) in row.iter().enumerate() {
                    assert_eq!(v.to_bits(), d.radiance_f32(b, s, i).to_bits(), "pixel {i} of {n}");
                }
                // and a part of the row its pixels' bits, its blocks starting anywhere
                for first in [1, 3, 16, 21].into_iter().filter(|&f| f < n) {
                    let mut part = vec![f32::NAN; n - first];
                    d.radiance_along_from(base, step, first, &mut part, true);
                    for (i, (&v, &w)) in part.iter().zip(&row[first..]).enumerate() {
                        assert_eq!(v.to_bits(), w.to_bits(), "pixel {} of {n} from {first}", first + i);
                    }
                }
            }
        }
        eprintln!("worst f32 row against the f64 ray: {:.2e} of the sky's range", worst / range);
        assert!(worst <= 2e-6 * range, "{worst} of {range}");
        assert_eq!(d.radiance_toward(DVec3::ZERO), d.horizon_sky() as f32);
        let mut zero = [0f32];
        d.radiance_along(DVec3::ZERO, DVec3::X, &mut zero, false);
        assert_eq!(zero[0], d.horizon_sky() as f32);
    }

    #[test]
    fn grazing_and_ground_paths_meet_at_the_curved_horizon() {
        for h in [500.0, 8000.0] {
            let d = dome(h, Band::LWIR_8_12);
            let dip = (EARTH_RADIUS_M / (EARTH_RADIUS_M + h)).acos();
            // one table step either side of the limb
            let step = 2.0 / (TABLE_SAMPLES - 1) as f64;
            let limb = -dip.sin();
            let at = |k: f64| f64::from(d.radiance(limb + k * step));
            // the limb is a kink (the radiance climbs steeply above it), not a step: the change across it is
            // no larger than the neighbouring changes
            let across = (at(1.0) - at(-1.0)).abs();
            let beside = (at(2.0) - at(1.0)).abs().max((at(-1.0) - at(-2.0)).abs());
            assert!(across <= 2.0 * beside + 1e-4 * at(0.0), "h {h}: {across} across the limb, {beside} beside it");
            // and no dip below the limb: the warmer, nearer ground only brightens the view downward
            let mut last = f64::from(d.radiance(limb));
            for k in 1..40 {
                let v = f64::from(d.radiance(limb - k as f64 * step));
                assert!(v >= last - 1e-6 * last, "h {h}: radiance falls {k} steps below the limb: {v} < {last}");
                last = v;
            }
        }
    }

    #[test]
    fn sky_brightens_toward_the_horizon_and_reaches_air_temperature() {
        let d = dome(0.0, Band::LWIR_8_12);
        let tb = |s: f64| brightness_temperature(Measure::Energy, Band::LWIR_8_12, f64::from(d.radiance(s))).unwrap();
        let zenith = tb(1.0);
        assert!(zenith > 210.0 && zenith < 240.0, "zenith {zenith} K");
        let mut last = zenith;
        for s in [0.5, 0.2, 0.1, 0.05, 0.01] {
            let t = tb(s);
            assert!(t > last, "{s}: {t} after {last}");
            last = t;
        }
        assert!((tb(1e-4) - 288.15).abs() < 0.5, "horizon {}", tb(1e-4));
    }

    #[test]
    fn ground_is_continuous_with_the_haze_and_warm_below() {
        let d = dome(1500.0, Band::LWIR_8_12);
        let below = |s: f64| f64::from(d.radiance(s));
        // looking down steeply sees the warm ground, near the horizon the lower air
        assert!(below(-1.0) > below(0.3));
        // just below the horizontal the limb emits at about the observer's height, as the sky just above does
        let near = below(-1e-3);
        let air = band_radiance_in(
            Measure::Energy,
            Band::LWIR_8_12,
            crate::physics::atmosphere::ambient_temperature_k(1500.0, 288.15).unwrap(),
            1.0,
        );
        assert!(((near - air) / air).abs() < 0.02, "{near} vs {air}");
        assert!(((below(1e-3) - near) / air).abs() < 0.02, "step at the horizon: {} vs {near}", below(1e-3));
        // and brightens smoothly down to the visible horizon (dip 1.24° at 1.5 km) and the ground beyond
        let mut last = near;
        for k in 1..=40 {
            let v = below(-(k as f64 * 0.001));
            assert!(v >= last - 1e-6 * air, "not monotone at sin e = {}", -(k as f64 * 0.001));
            assert!((v - last) / air < 0.02, "a step of {} at sin e = {}", (v - last) / air, -(k as f64 * 0.001));
            last = v;
        }
    }

    #[test]
    fn table_matches_direct_evaluation() {
        let d = dome(8000.0, Band::MWIR_3_5);
        // a value between table nodes vs. the nodes' neighbourhood: linear interpolation error is tiny
        for s in [0.0371, 0.4123, -0.3001] {
            let a = f64::from(d.radiance(s));
            let b = f64::from(d.radiance(s + 1e-6));
            assert!(((a - b) / a).abs() < 1e-4);
        }
        assert!(d.max_curvature_per_rad2().is_finite() && d.max_curvature_per_rad2() > 0.0);
    }
}
