//! Ambient air temperature against altitude (paper eq 2, continued by the US Standard Atmosphere 1976).
//!
//! Eq 2 is the 1976 standard atmosphere's temperature profile below 32 km with the sea-level temperature `T0`
//! as a parameter: a 6.5 K/km lapse to 11 km, isothermal to 20 km, warming by 1 K/km to 32 km. Above 32 km we
//! continue with the 1976 layers — +2.8 K/km to 47 km, isothermal to 51 km, −2.8 K/km to 71 km, −2.0 K/km to
//! 84.852 km — shifted by `T0 − 288.15 K` so the profile is continuous for any `T0`. As in the paper, the
//! altitude goes into the formula as given; in the 1976 standard the layer altitudes are geopotential, which
//! differs from geometric altitude by `z²/r₀` (63 m at 20 km, 0.12 K of T∞ at 11 km). 84.852 km geopotential is
//! the 86 km geometric top of the 1976 lower atmosphere; from there to 86 km we hold 186.946 K, within 0.08 K
//! of the standard's 186.87 K kinetic temperature in its 86–91 km isothermal layer.
//!
//! The supported range is −5 km to 86 km (the 1976 tables start at −5 km).
//!
//! With a LOWTRAN weather the air follows the model atmosphere's own profile ([`AirTemperature`]), so that the
//! skin heating, the speed of sound and the air's emission agree with the transmittance: mid-latitude summer is
//! 294.2 K at sea level, sub-arctic winter 257.2 K.

use thiserror::Error;

use super::lowtran::{AtmosphereTable, ModelAtmosphere, Profile};

/// Sea-level temperature of the standard atmosphere, K.
pub const STANDARD_T0_K: f64 = 288.15;
/// Lowest supported altitude, m.
pub const MIN_ALTITUDE_M: f64 = -5_000.0;
/// Highest sea-level temperature the profile is evaluated for, K.
pub const MAX_T0_K: f64 = 1000.0;
/// Highest supported altitude, m.
pub const MAX_ALTITUDE_M: f64 = 86_000.0;

/// Layer bases (km) and lapse rates (K/km) of the standard atmosphere, from the tropopause of eq 2 upward.
const LAYERS: [(f64, f64); 8] =
    [(-5.0, -6.5), (11.0, 0.0), (20.0, 1.0), (32.0, 2.8), (47.0, 0.0), (51.0, -2.8), (71.0, -2.0), (84.852, 0.0)];

/// An altitude or sea-level temperature outside what the model supports.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum AtmosphereError {
    /// Altitude outside [−5, 86] km or not finite.
    #[error("altitude {} m is outside the supported range [-5000, 86000] m", super::Num(*.altitude_m))]
    AltitudeOutOfRange {
        /// The altitude given, m.
        altitude_m: f64,
    },
    /// Sea-level temperature not finite, or so low that the profile drops to 0 K.
    #[error("sea-level temperature {} K must be finite, above 71.5 + 1 K so that T∞ stays positive, and at most 1000 K", super::Num(*.t0_k))]
    BadSeaLevelTemperature {
        /// The temperature given, K.
        t0_k: f64,
    },
}

/// The air's temperature against altitude: eq 2 from a sea-level temperature, or a LOWTRAN model atmosphere's
/// profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AirTemperature {
    /// Eq 2 (the 1976 standard's lapse rates) from sea level at `t0_k`, K.
    Standard {
        /// Sea-level temperature, K.
        t0_k: f64,
    },
    /// A LOWTRAN model atmosphere's levels, linear between them (constant beyond its lowest and highest).
    Profile(&'static Profile),
}

impl Default for AirTemperature {
    fn default() -> Self {
        Self::Standard { t0_k: STANDARD_T0_K }
    }
}

impl AirTemperature {
    /// The air temperature of a LOWTRAN model atmosphere. US Standard 1976 is eq 2 itself from 288.15 K (LOWTRAN
    /// lists its levels rounded to 0.1 K); the others follow their profiles.
    pub fn of_model(model: ModelAtmosphere, table: &'static AtmosphereTable) -> Self {
        match model {
            ModelAtmosphere::UsStandard1976 => Self::Standard { t0_k: STANDARD_T0_K },
            other => Self::Profile(table.profile(other)),
        }
    }

    /// Temperature at `altitude_m`, K.
    ///
    /// # Errors
    /// As [`ambient_temperature_k`].
    pub fn at_k(&self, altitude_m: f64) -> Result<f64, AtmosphereError> {
        match self {
            Self::Standard { t0_k } => ambient_temperature_k(altitude_m, *t0_k),
            Self::Profile(p) => {
                if !(altitude_m.is_finite() && (MIN_ALTITUDE_M..=MAX_ALTITUDE_M).contains(&altitude_m)) {
                    return Err(AtmosphereError::AltitudeOutOfRange { altitude_m });
                }
                Ok(p.temperature_at(altitude_m / 1000.0))
            }
        }
    }

    /// Temperature at `altitude_m` clamped to the supported altitudes, K.
    pub fn clamped_k(&self, altitude_m: f64) -> f64 {
        let z = if altitude_m.is_nan() { 0.0 } else { altitude_m.clamp(MIN_ALTITUDE_M, MAX_ALTITUDE_M) };
        self.at_k(z).unwrap_or(self.sea_level_k())
    }

    /// Temperature at sea level, K.
    pub fn sea_level_k(&self) -> f64 {
        match self {
            Self::Standard { t0_k } => *t0_k,
            Self::Profile(p) => p.temperature_at(0.0),
        }
    }
}

/// Ambient temperature T∞(H) in K at `altitude_m`, for sea-level temperature `t0_k` (paper eq 2, 1976 above).
///
/// # Errors
/// [`AtmosphereError::AltitudeOutOfRange`] outside [−5, 86] km; [`AtmosphereError::BadSeaLevelTemperature`]
/// if `t0_k` is not finite or leaves a temperature at or below 1 K somewhere in the profile.
///
/// # Examples
/// ```
/// use irsim::physics::atmosphere::{ambient_temperature_k, STANDARD_T0_K};
/// let t = ambient_temperature_k(15_000.0, STANDARD_T0_K).unwrap();
/// assert!((t - 216.65).abs() < 1e-12);
/// ```
pub fn ambient_temperature_k(altitude_m: f64, t0_k: f64) -> Result<f64, AtmosphereError> {
    if !(altitude_m.is_finite() && (MIN_ALTITUDE_M..=MAX_ALTITUDE_M).contains(&altitude_m)) {
        return Err(AtmosphereError::AltitudeOutOfRange { altitude_m });
    }
    // The coldest point of the profile is T0 − 288.15 + 186.946 K; keep it above 1 K.
    if !(t0_k.is_finite() && t0_k - STANDARD_T0_K + 186.946 > 1.0 && t0_k <= MAX_T0_K) {
        return Err(AtmosphereError::BadSeaLevelTemperature { t0_k });
    }
    let h_km = altitude_m / 1000.0;
    // Temperature at 0 km is T0; walk the layers from there (the first layer runs down to −5 km too).
    let mut temp = t0_k;
    let mut base = 0.0;
    for (i, &(_, lapse)) in LAYERS.iter().enumerate() {
        let top = LAYERS.get(i + 1).map_or(f64::INFINITY, |l| l.0);
        if h_km <= top {
            return Ok(temp + lapse * (h_km - base));
        }
        temp += lapse * (top - base);
        base = top;
    }
    unreachable!("the last layer is open-ended")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn follows_eq_2_below_32_km() {
        let t0 = STANDARD_T0_K;
        for h_km in [0.0, 5.0, 10.999, 11.0, 15.0, 20.0, 25.0, 32.0] {
            let want = if h_km <= 11.0 {
                t0 - 6.5 * h_km
            } else if h_km <= 20.0 {
                t0 - 71.5
            } else {
                t0 - 71.5 + (h_km - 20.0)
            };
            let got = ambient_temperature_k(h_km * 1000.0, t0).unwrap();
            assert!((got - want).abs() < 1e-12, "{h_km} km: {got} vs {want}");
        }
    }

    #[test]
    fn matches_1976_layer_temperatures() {
        for (h_km, want) in [(47.0, 270.65), (51.0, 270.65), (71.0, 214.65), (84.852, 186.946), (86.0, 186.946)] {
            let got = ambient_temperature_k(h_km * 1000.0, STANDARD_T0_K).unwrap();
            assert!((got - want).abs() < 1e-9, "{h_km} km: {got} vs {want}");
        }
        // below sea level the tropospheric lapse continues
        let got = ambient_temperature_k(-5000.0, STANDARD_T0_K).unwrap();
        assert!((got - 320.65).abs() < 1e-12);
    }

    #[test]
    fn continuous_for_a_custom_sea_level_temperature() {
        let t0 = 300.0;
        for h_km in [11.0, 20.0, 32.0, 47.0, 51.0, 71.0, 84.852] {
            let below = ambient_temperature_k(h_km * 1000.0 - 1e-6, t0).unwrap();
            let above = ambient_temperature_k(h_km * 1000.0 + 1e-6, t0).unwrap();
            assert!((below - above).abs() < 1e-6, "jump at {h_km} km");
        }
    }

    #[test]
    fn rejects_out_of_range() {
        for h in [-5000.1, 86000.1, f64::NAN, f64::INFINITY] {
            assert!(matches!(ambient_temperature_k(h, STANDARD_T0_K), Err(AtmosphereError::AltitudeOutOfRange { .. })));
        }
        assert!(ambient_temperature_k(0.0, 50.0).is_err());
        assert!(ambient_temperature_k(0.0, f64::NAN).is_err());
    }
}
