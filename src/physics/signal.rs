//! The whole radiometric chain for one target: altitude and Mach to gray value (eqs 1–3, 9–10, 13–15).
//!
//! This is what `irsim calc signal` prints and what the simulation's radiometry stage computes per target.

use glam::{DMat3, DVec3};
use serde::Serialize;
use thiserror::Error;

use super::ParamError;
use super::atmosphere::{AirTemperature, MAX_ALTITUDE_M, MIN_ALTITUDE_M};
use super::brdf::CookTorrance;
use super::lowtran::{BinWeights, PathSpectrum};
use super::planck::{Band, Measure, PlanckMethod, band_radiance_in};
use super::reflection::{ReflectionGeometry, ReflectionInput, SphereQuadrature, Sun, reflected_radiance};
use super::sensor::{GrayMapping, Radiometer};
use super::skin::{SkinError, StagnationModel, self_radiance, skin_temperatures};
use super::transmittance::{PathTransmittance, Transmittance};

/// Any error of the radiometric chain.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SignalError {
    /// Atmosphere or stagnation model.
    #[error(transparent)]
    Skin(#[from] SkinError),
    /// A material, sensor or transmittance parameter out of range.
    #[error(transparent)]
    Param(#[from] ParamError),
    /// A geometric input.
    #[error("{0}")]
    Geometry(String),
}

/// A target's flight condition and material.
#[derive(Debug, Clone, Copy)]
pub struct TargetState {
    /// Position, m, world frame (z up: `position_m.z` is the altitude).
    pub position_m: DVec3,
    /// Mach number.
    pub mach: f64,
    /// Emissivity of the skin, [0, 1].
    pub emissivity: f64,
    /// Skin temperature above the stagnation (recovery) temperature from internal heat (motors, batteries,
    /// engine bay), K; 0 for the paper's skin.
    pub heating_k: f64,
    /// Reflectance model.
    pub brdf: CookTorrance,
    /// Ellipsoid semi-axes, m, body frame (x along the velocity).
    pub semi_axes_m: DVec3,
    /// Body-to-world rotation.
    pub attitude: DMat3,
}

/// The target's internal heating, checked: finite and in `[0, 2000]` K.
fn heating(target: &TargetState) -> Result<f64, SignalError> {
    ParamError::check_range("heating_k", target.heating_k, 0.0, 2000.0)?;
    Ok(target.heating_k)
}

/// Everything else that the chain needs: the scene and the sensor.
#[derive(Clone, Copy)]
pub struct SignalContext<'a> {
    /// Sensor band.
    pub band: Band,
    /// The air's temperature against altitude.
    pub air: AirTemperature,
    /// Stagnation constants.
    pub stagnation: StagnationModel,
    /// The sun.
    pub sun: Sun,
    /// Atmospheric transmittance model.
    pub atmosphere: &'a (dyn PathTransmittance + Sync),
    /// Facet (paper) or ellipsoid-averaged reflection.
    pub reflection: ReflectionGeometry,
    /// Quadrature for the ellipsoid average.
    pub quadrature: &'a SphereQuadrature,
    /// Optics and detector.
    pub radiometer: Radiometer,
    /// Gray mapping.
    pub gray: GrayMapping,
    /// Use the sub-pixel fill factor (DESIGN.md) rather than the paper's "target fills the pixel".
    pub fill_factor: bool,
}

/// The chain's intermediate and final values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TargetSignal {
    /// T∞ at the target's altitude, K.
    pub ambient_temp_k: f64,
    /// Skin temperature, K.
    pub skin_temp_k: f64,
    /// Self-emitted radiance, W m⁻² sr⁻¹.
    pub self_radiance_w_m2_sr: f64,
    /// Reflected sun radiance, W m⁻² sr⁻¹.
    pub reflected_radiance_w_m2_sr: f64,
    /// Total radiance, W m⁻² sr⁻¹.
    pub total_radiance_w_m2_sr: f64,
    /// Transmittance of the path target → sensor.
    pub tau: f64,
    /// Transmittance of the path target → sun.
    pub sun_tau: f64,
    /// Range, m.
    pub range_m: f64,
    /// Projected area of the ellipsoid seen from the sensor, m².
    pub projected_area_m2: f64,
    /// Fill factor of eq 13.
    pub fill_factor: f64,
    /// Power on the detector, W.
    pub power_w: f64,
    /// Sensor voltage, V.
    pub voltage_v: f64,
    /// Gray value (eq 15), before quantization.
    pub gray: f64,
    /// Quantized gray level.
    pub gray_level: u16,
}

/// Runs the whole chain for one target seen from `sensor_m`.
///
/// # Errors
/// [`SignalError`] for an out-of-range altitude, Mach number, material, sensor or transmittance parameter, or a
/// target at the sensor's position.
pub fn target_signal(
    target: &TargetState,
    sensor_m: DVec3,
    ctx: &SignalContext<'_>,
) -> Result<TargetSignal, SignalError> {
    target.brdf.validate()?;
    ctx.radiometer.validate()?;
    ctx.gray.validate()?;
    let mut temps = skin_temperatures(&ctx.stagnation, target.position_m.z, target.mach, &ctx.air)?;
    temps.skin_temp_k += heating(target)?;
    let l_self = self_radiance(ctx.band, temps.skin_temp_k, target.emissivity)?;
    let Sunlit { range_m, to_viewer, sun_tau, reflected: l_re } =
        sunlit(target, sensor_m, ctx.band, &ctx.sun, ctx.atmosphere, ctx.reflection, ctx.quadrature, 0.0)?;
    let l_sum = l_self + l_re;
    let tau = ctx.atmosphere.along_segment(target.position_m, sensor_m);
    let projected_area_m2 = ellipsoid_projected_area(target.semi_axes_m, target.attitude, to_viewer);
    let area = if ctx.fill_factor { projected_area_m2 } else { f64::INFINITY };
    let s = ctx.radiometer.signal(l_sum, tau, area, range_m);
    let gray = ctx.gray.gray(s.voltage_v);
    Ok(TargetSignal {
        ambient_temp_k: temps.ambient_temp_k,
        skin_temp_k: temps.skin_temp_k,
        self_radiance_w_m2_sr: l_self,
        reflected_radiance_w_m2_sr: l_re,
        total_radiance_w_m2_sr: l_sum,
        tau,
        sun_tau,
        range_m,
        projected_area_m2,
        fill_factor: s.fill_factor,
        power_w: s.power_w,
        voltage_v: s.voltage_v,
        gray,
        gray_level: ctx.gray.quantize(gray),
    })
}

/// The viewing geometry and the sunlight a target reflects toward the sensor (eq 9, energy radiance).
struct Sunlit {
    range_m: f64,
    to_viewer: DVec3,
    sun_tau: f64,
    reflected: f64,
}

/// Range, direction, sun transmittance and reflected sun radiance, shared by [`target_signal`] and
/// [`apparent_radiance`]; the reflection is taken as 0, not computed, where a bound on it is below `skip_below`
/// (energy radiance at the target; 0: never).
#[allow(clippy::too_many_arguments)]
fn sunlit(
    target: &TargetState,
    sensor_m: DVec3,
    band: Band,
    sun: &Sun,
    atmosphere: &(dyn PathTransmittance + Sync),
    reflection: ReflectionGeometry,
    quadrature: &SphereQuadrature,
    skip_below: f64,
) -> Result<Sunlit, SignalError> {
    let line = sensor_m - target.position_m;
    let range_m = line.length();
    if !(range_m > 0.0) || !range_m.is_finite() {
        return Err(SignalError::Geometry(format!("range {range_m} m between sensor and target must be > 0")));
    }
    let to_viewer = line / range_m;
    let sun_tau = atmosphere.to_space(target.position_m, sun.direction());
    let input = ReflectionInput { brdf: &target.brdf, sun, band, sun_transmittance: sun_tau, to_viewer };
    let bound = || target.brdf.max_reflectance(to_viewer, sun.direction()) * sun.band_irradiance_w_m2(band) * sun_tau;
    let reflected = if skip_below > 0.0 && bound() < skip_below {
        0.0
    } else {
        reflected_radiance(&input, reflection, Some((target.semi_axes_m, target.attitude, quadrature)))
    };
    Ok(Sunlit { range_m, to_viewer, sun_tau, reflected })
}

/// Area of an ellipsoid's orthographic projection along unit direction `d`, m².
///
/// For semi-axes `a, b, c` in the body frame and `d` in body coordinates, the area is
/// `π·√((bc·d_x)² + (ac·d_y)² + (ab·d_z)²)`.
pub fn ellipsoid_projected_area(semi_axes_m: DVec3, body_to_world: DMat3, d: DVec3) -> f64 {
    let d = body_to_world.transpose() * d.normalize_or_zero();
    let (a, b, c) = (semi_axes_m.x, semi_axes_m.y, semi_axes_m.z);
    std::f64::consts::PI * ((b * c * d.x).powi(2) + (a * c * d.y).powi(2) + (a * b * d.z).powi(2)).sqrt()
}

/// Everything the apparent radiance of a target needs besides the target.
#[derive(Clone, Copy)]
pub struct ApparentContext<'a> {
    /// Sensor band.
    pub band: Band,
    /// The detector's measure (energy or photons).
    pub measure: Measure,
    /// The air's temperature against altitude.
    pub air: AirTemperature,
    /// Stagnation constants.
    pub stagnation: StagnationModel,
    /// The sun.
    pub sun: Sun,
    /// Atmospheric transmittance model.
    pub atmosphere: &'a (dyn PathTransmittance + Sync),
    /// Facet (paper) or ellipsoid-averaged reflection.
    pub reflection: ReflectionGeometry,
    /// Quadrature for the ellipsoid average.
    pub quadrature: &'a SphereQuadrature,
    /// How the target's own and the path's band radiances are integrated.
    pub planck: PlanckMethod,
    /// The reflection is not computed where a bound on what it adds at the aperture (in the measure, after the
    /// path's transmittance) is below this (0: always computed).
    pub reflection_skip_below: f64,
    /// The line of sight's spectrum (LOWTRAN), when the scene has one: then the target's own emission is
    /// transmitted with τ weighted by its spectrum at the skin temperature, the reflected sunlight with τ weighted
    /// by the sun's, and the path radiance is the spectrum's; without it, `atmosphere`'s band τ for both and
    /// `(1 − τ)·B(T∞(mid-path))`.
    pub sight: Option<Sight<'a>>,
}

/// A target's line of sight through a LOWTRAN atmosphere.
#[derive(Clone, Copy)]
pub struct Sight<'a> {
    /// The path's spectral transmittance and path radiance.
    pub spectrum: &'a PathSpectrum,
    /// The sun's spectrum per bin in the detector's measure ([`PathSpectrum::blackbody_weights`] at the sun's
    /// temperature).
    pub sun_weights: &'a [f64],
    /// Each bin's ratio from energy radiance to the detector's measure ([`PathSpectrum::measure_ratios`] for the
    /// band).
    pub measure_ratios: &'a [f64],
    /// The target's own blackbody weights over the bins, kept from its last computation.
    pub skin_weights: &'a BinWeights,
}

/// A target's radiance at the sensor's aperture, in the detector's measure.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Apparent {
    /// T∞ at the target's altitude, K.
    pub ambient_temp_k: f64,
    /// Skin temperature, K.
    pub skin_temp_k: f64,
    /// Self-emitted band radiance `ε·L(T_skin)`, in the measure.
    pub self_radiance: f64,
    /// Reflected sun radiance, in the measure.
    pub reflected_radiance: f64,
    /// Transmittance of the path target → sensor for the target's own emission.
    pub tau: f64,
    /// Transmittance of the path target → sensor for the reflected sunlight (equal to `tau` without a LOWTRAN
    /// line of sight).
    pub reflected_tau: f64,
    /// Radiance the path itself adds, in the measure: the LOWTRAN spectrum's, or `(1 − τ)·L(T∞(mid-path))`.
    pub path_radiance: f64,
    /// `τ·self + τ_reflected·reflected + path`: what a pixel filled by the target receives, in the measure.
    pub apparent_radiance: f64,
    /// Range, m.
    pub range_m: f64,
}

/// The radiance a pixel filled by the target receives (eqs 1–3, 9–10 and the path), in the detector's measure.
///
/// The reflected sun term is computed in energy (eq 9) and converted with the sun's photon-to-energy ratio in
/// the band, exact because the BRDF is grey. The path emits at the air temperature of its middle height.
///
/// # Errors
/// [`SignalError`] for an out-of-range altitude, Mach number, material or transmittance parameter, or a target
/// at the sensor's position.
pub fn apparent_radiance(
    target: &TargetState,
    sensor_m: DVec3,
    ctx: &ApparentContext<'_>,
) -> Result<Apparent, SignalError> {
    target.brdf.validate()?;
    // a scene may fly above or below the profile's range: the air there is taken at the nearest end
    let altitude_m = target.position_m.z.clamp(MIN_ALTITUDE_M, MAX_ALTITUDE_M);
    let mut temps = skin_temperatures(&ctx.stagnation, altitude_m, target.mach, &ctx.air)?;
    temps.skin_temp_k += heating(target)?;
    self_radiance(ctx.band, temps.skin_temp_k, target.emissivity)?;
    let l_self = ctx.planck.band_radiance(ctx.measure, ctx.band, temps.skin_temp_k, target.emissivity);
    let (tau, reflected_tau) = match ctx.sight {
        Some(Sight { spectrum: p, sun_weights, skin_weights, .. }) => (
            skin_weights
                .spectrum_weighted_with(p, ctx.measure, ctx.band, temps.skin_temp_k, ctx.planck)
                .clamp(0.0, 1.0),
            p.weighted(sun_weights).clamp(0.0, 1.0),
        ),
        None => {
            let tau = ctx.atmosphere.along_segment(target.position_m, sensor_m).clamp(0.0, 1.0);
            (tau, tau)
        }
    };
    // the sun's band radiance in energy and in the measure: their ratio converts the grey reflection
    let sun_energy = band_radiance_in(Measure::Energy, ctx.band, ctx.sun.temp_k, 1.0);
    let sun_measure = band_radiance_in(ctx.measure, ctx.band, ctx.sun.temp_k, 1.0);
    let in_measure = |energy: f64| match ctx.measure {
        Measure::Energy => energy,
        Measure::Photon if sun_energy > 0.0 => energy * sun_measure / sun_energy,
        Measure::Photon => 0.0,
    };
    // the skip threshold at the target, in energy (infinite, so always skipped, where nothing would arrive)
    let skip_below = if ctx.reflection_skip_below > 0.0 {
        ctx.reflection_skip_below / (reflected_tau * in_measure(1.0))
    } else {
        0.0
    };
    let Sunlit { range_m, reflected: l_re_energy, .. } =
        sunlit(target, sensor_m, ctx.band, &ctx.sun, ctx.atmosphere, ctx.reflection, ctx.quadrature, skip_below)?;
    let l_re = in_measure(l_re_energy);
    let path_radiance = match ctx.sight {
        Some(Sight { spectrum: p, measure_ratios, .. }) => p.band_path_radiance_by(ctx.band, measure_ratios),
        None => {
            let mid_z = 0.5 * (target.position_m.z + sensor_m.z);
            let t_mid = ctx
                .air
                .at_k(mid_z.clamp(MIN_ALTITUDE_M, MAX_ALTITUDE_M))
                .map_err(|e| SignalError::Skin(SkinError::from(e)))?;
            (1.0 - tau) * ctx.planck.band_radiance(ctx.measure, ctx.band, t_mid, 1.0)
        }
    };
    Ok(Apparent {
        ambient_temp_k: temps.ambient_temp_k,
        skin_temp_k: temps.skin_temp_k,
        self_radiance: l_self,
        reflected_radiance: l_re,
        tau,
        reflected_tau,
        path_radiance,
        apparent_radiance: tau * l_self + reflected_tau * l_re + path_radiance,
        range_m,
    })
}

/// A convenience context holder with owned parts, for callers that build one from flags or a scenario.
#[derive(Debug, Clone)]
pub struct OwnedSignalContext {
    /// Sensor band.
    pub band: Band,
    /// The air's temperature against altitude.
    pub air: AirTemperature,
    /// Stagnation constants.
    pub stagnation: StagnationModel,
    /// The sun.
    pub sun: Sun,
    /// Transmittance model.
    pub atmosphere: Transmittance,
    /// Reflection geometry.
    pub reflection: ReflectionGeometry,
    /// Quadrature for the ellipsoid average.
    pub quadrature: SphereQuadrature,
    /// Optics and detector.
    pub radiometer: Radiometer,
    /// Gray mapping.
    pub gray: GrayMapping,
    /// Apply the fill factor.
    pub fill_factor: bool,
}

impl OwnedSignalContext {
    /// Borrows it as a [`SignalContext`].
    pub fn as_context(&self) -> SignalContext<'_> {
        SignalContext {
            band: self.band,
            air: self.air,
            stagnation: self.stagnation,
            sun: self.sun,
            atmosphere: &self.atmosphere,
            reflection: self.reflection,
            quadrature: &self.quadrature,
            radiometer: self.radiometer,
            gray: self.gray,
            fill_factor: self.fill_factor,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projected_area_of_a_spheroid() {
        let axes = DVec3::new(3.0, 1.0, 1.0);
        let pi = std::f64::consts::PI;
        assert!((ellipsoid_projected_area(axes, DMat3::IDENTITY, DVec3::X) - pi).abs() < 1e-12);
        assert!((ellipsoid_projected_area(axes, DMat3::IDENTITY, DVec3::Y) - 3.0 * pi).abs() < 1e-12);
    }
}
