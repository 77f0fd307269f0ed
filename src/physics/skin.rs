//! Aircraft skin temperature by the stagnation-point method (paper eq 1) and its self-emitted radiance (eq 3).
//!
//! `T_s = T∞ · (1 + r·(k − 1)/2 · M²)`, with the recovery factor `r` (paper: 0.87) and the ratio of specific
//! heats `k` (paper: 1.3). The skin is a grey body of emissivity ε over the sensor band. The model has no
//! engine plume, no solar heating of the skin and no radiative cooling: it is the paper's empirical model.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use super::ParamError;
use super::atmosphere::{AirTemperature, AtmosphereError};
use super::planck::{Band, band_radiance};

/// Ratio of specific heats of dry air used for the speed of sound (not eq 1's `k`).
pub const AIR_GAMMA: f64 = 1.4;
/// Largest Mach number eq 1 is evaluated for (far beyond its validity; it keeps every result finite).
pub const MAX_MACH: f64 = 1000.0;

/// Specific gas constant of dry air, J kg⁻¹ K⁻¹.
pub const AIR_GAS_CONSTANT: f64 = 287.052_87;

/// An invalid stagnation-model parameter or flight condition.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SkinError {
    /// A parameter is outside its allowed range.
    #[error(transparent)]
    OutOfRange(#[from] ParamError),
    /// The ambient temperature could not be computed.
    #[error(transparent)]
    Atmosphere(#[from] AtmosphereError),
}

/// Constants of the stagnation-temperature formula (paper eq 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StagnationModel {
    /// Recovery factor `r` (the paper's γ), 0 … 1.
    pub recovery: f64,
    /// Ratio of specific heats `k`, > 1.
    pub gamma: f64,
}

impl Default for StagnationModel {
    fn default() -> Self {
        Self { recovery: 0.87, gamma: 1.3 }
    }
}

impl StagnationModel {
    /// Checks the constants.
    ///
    /// # Errors
    /// [`SkinError::OutOfRange`] if `recovery` is not in [0, 1] or `gamma` not in (1, 3].
    pub fn validate(&self) -> Result<(), SkinError> {
        check("recovery", self.recovery, (0.0..=1.0).contains(&self.recovery), "[0, 1]")?;
        check("gamma", self.gamma, self.gamma > 1.0 && self.gamma <= 3.0, "(1, 3]")
    }

    /// Skin temperature T_s in K for ambient temperature `ambient_k` and Mach number `mach` (eq 1).
    ///
    /// # Errors
    /// [`SkinError::OutOfRange`] for a non-finite or negative Mach number or ambient temperature.
    pub fn skin_temperature_k(&self, ambient_k: f64, mach: f64) -> Result<f64, SkinError> {
        self.validate()?;
        check("mach", mach, mach.is_finite() && (0.0..=MAX_MACH).contains(&mach), "[0, 1000]")?;
        check("ambient_temp_k", ambient_k, ambient_k.is_finite() && ambient_k > 0.0, "(0, ∞)")?;
        Ok(ambient_k * (1.0 + self.recovery * (self.gamma - 1.0) / 2.0 * mach * mach))
    }
}

/// Ambient and skin temperature of an aircraft at `altitude_m` flying at `mach` (eqs 2 and 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SkinTemperatures {
    /// T∞, K.
    pub ambient_temp_k: f64,
    /// T_s, K.
    pub skin_temp_k: f64,
}

/// T∞ (eq 2, or the model atmosphere's profile) and T_s (eq 1) for an aircraft at `altitude_m` flying at `mach`.
///
/// # Errors
/// Those of [`AirTemperature::at_k`] and [`StagnationModel::skin_temperature_k`].
pub fn skin_temperatures(
    model: &StagnationModel,
    altitude_m: f64,
    mach: f64,
    air: &AirTemperature,
) -> Result<SkinTemperatures, SkinError> {
    let ambient_temp_k = air.at_k(altitude_m)?;
    let skin_temp_k = model.skin_temperature_k(ambient_temp_k, mach)?;
    Ok(SkinTemperatures { ambient_temp_k, skin_temp_k })
}

/// Speed of sound in m/s in air at `temp_k`.
pub fn speed_of_sound_m_s(temp_k: f64) -> f64 {
    (AIR_GAMMA * AIR_GAS_CONSTANT * temp_k.max(0.0)).sqrt()
}

/// Mach number of a flight at `speed_m_s` through air at `air_temp_k`.
pub fn mach_number(speed_m_s: f64, air_temp_k: f64) -> f64 {
    speed_m_s / speed_of_sound_m_s(air_temp_k)
}

/// Self-emitted band radiance of a grey skin, W m⁻² sr⁻¹ (eq 3).
///
/// # Errors
/// [`SkinError::OutOfRange`] if `emissivity` is not in [0, 1].
pub fn self_radiance(band: Band, skin_temp_k: f64, emissivity: f64) -> Result<f64, SkinError> {
    check("emissivity", emissivity, (0.0..=1.0).contains(&emissivity), "[0, 1]")?;
    Ok(band_radiance(band, skin_temp_k, emissivity))
}

fn check(name: &'static str, value: f64, ok: bool, range: &'static str) -> Result<(), SkinError> {
    if ok { Ok(()) } else { Err(ParamError { name, value, range: range.into() }.into()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_defaults() {
        let m = StagnationModel::default();
        // r(k-1)/2 = 0.87 * 0.15 = 0.1305
        let ts = m.skin_temperature_k(216.65, 1.2).unwrap();
        assert!((ts - 216.65 * (1.0 + 0.1305 * 1.44)).abs() < 1e-12);
        assert_eq!(m.skin_temperature_k(250.0, 0.0).unwrap(), 250.0);
    }

    #[test]
    fn rejects_bad_inputs() {
        let m = StagnationModel::default();
        assert!(m.skin_temperature_k(250.0, -0.1).is_err());
        assert!(m.skin_temperature_k(250.0, f64::NAN).is_err());
        assert!(StagnationModel { recovery: 1.2, gamma: 1.3 }.validate().is_err());
        assert!(StagnationModel { recovery: 0.8, gamma: 1.0 }.validate().is_err());
        assert!(self_radiance(Band::LWIR_8_12, 300.0, 1.5).is_err());
    }

    #[test]
    fn sound_speed_at_sea_level() {
        assert!((speed_of_sound_m_s(288.15) - 340.294).abs() < 1e-3);
    }
}
