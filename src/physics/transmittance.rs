//! Atmospheric transmittance of a path, τ in eq 13 and on the way to the sun in eq 9.
//!
//! Two simple models for now, both band-averaged:
//! - [`Transmittance::Fixed`]: one τ for every path (what the paper does once it has picked the weather);
//! - [`Transmittance::BeerLambert`]: `τ = exp(−∫β ds)` with an extinction coefficient `β(z) = β₀·e^{−z/H}`
//!   falling with altitude over the scale height `H` (flat Earth). `H = ∞` is a homogeneous atmosphere.
//!
//! Every model implements [`PathTransmittance`], the seam where the table-driven model
//! ([`super::lowtran_paths::LowtranAtmosphere`]) plugs in; a scene holds one of them as a [`SceneAtmosphere`].

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Transmittance of straight paths through the atmosphere.
pub trait PathTransmittance {
    /// τ of the segment between two points (m, world frame, z up), in [0, 1].
    fn along_segment(&self, a_m: DVec3, b_m: DVec3) -> f64;
    /// τ from `from_m` to the top of the atmosphere along `direction` (unit, toward the sun), in [0, 1].
    fn to_space(&self, from_m: DVec3, direction: DVec3) -> f64;
    /// The band radiance the segment's air itself emits toward `a_m`, in the detector's measure, where the model
    /// knows it; `None` leaves it to the caller (`(1 − τ)·B(T)` at a temperature it picks).
    fn path_radiance(&self, _a_m: DVec3, _b_m: DVec3) -> Option<f64> {
        None
    }
    /// [`PathTransmittance::along_segment`] and [`PathTransmittance::path_radiance`] together (one lookup where
    /// the model shares it).
    fn transmittance_and_path(&self, a_m: DVec3, b_m: DVec3) -> (f64, Option<f64>) {
        (self.along_segment(a_m, b_m), self.path_radiance(a_m, b_m))
    }
}

/// A scene's atmosphere: a band-averaged override, or the LOWTRAN weather.
#[derive(Debug, Clone)]
pub enum SceneAtmosphere {
    /// [`Transmittance`]: fixed τ or Beer–Lambert.
    Override(Transmittance),
    /// LOWTRAN7's tables for the scene's weather, band and observer.
    Lowtran(std::sync::Arc<super::lowtran_paths::LowtranAtmosphere>),
}

impl Default for SceneAtmosphere {
    fn default() -> Self {
        SceneAtmosphere::Override(Transmittance::default())
    }
}

impl SceneAtmosphere {
    /// The LOWTRAN model, if the scene uses it.
    pub fn lowtran(&self) -> Option<&super::lowtran_paths::LowtranAtmosphere> {
        match self {
            SceneAtmosphere::Lowtran(l) => Some(l),
            SceneAtmosphere::Override(_) => None,
        }
    }
}

impl PathTransmittance for SceneAtmosphere {
    fn along_segment(&self, a_m: DVec3, b_m: DVec3) -> f64 {
        match self {
            SceneAtmosphere::Override(t) => t.along_segment(a_m, b_m),
            SceneAtmosphere::Lowtran(l) => l.along_segment(a_m, b_m),
        }
    }

    fn to_space(&self, from_m: DVec3, direction: DVec3) -> f64 {
        match self {
            SceneAtmosphere::Override(t) => t.to_space(from_m, direction),
            SceneAtmosphere::Lowtran(l) => l.to_space(from_m, direction),
        }
    }

    fn path_radiance(&self, a_m: DVec3, b_m: DVec3) -> Option<f64> {
        match self {
            SceneAtmosphere::Override(t) => t.path_radiance(a_m, b_m),
            SceneAtmosphere::Lowtran(l) => l.path_radiance(a_m, b_m),
        }
    }

    fn transmittance_and_path(&self, a_m: DVec3, b_m: DVec3) -> (f64, Option<f64>) {
        match self {
            SceneAtmosphere::Override(t) => t.transmittance_and_path(a_m, b_m),
            SceneAtmosphere::Lowtran(l) => l.transmittance_and_path(a_m, b_m),
        }
    }
}

/// An invalid transmittance parameter: its name, value and allowed range.
pub type TransmittanceError = super::ParamError;

/// A band-averaged transmittance model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum Transmittance {
    /// The same τ for every path, sun path included.
    Fixed {
        /// τ, [0, 1].
        tau: f64,
    },
    /// Exponential extinction, falling with altitude.
    BeerLambert {
        /// Extinction coefficient at sea level, km⁻¹, ≥ 0.
        extinction_per_km: f64,
        /// Scale height of the extinction, km, > 0 (`inf` for a homogeneous atmosphere).
        #[serde(default = "default_scale_height_km")]
        scale_height_km: f64,
    },
}

fn default_scale_height_km() -> f64 {
    // Water vapour, the main absorber in the 8–12 µm window, falls off over about 2 km.
    2.0
}

impl Default for Transmittance {
    fn default() -> Self {
        Transmittance::Fixed { tau: 1.0 }
    }
}

impl Transmittance {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`TransmittanceError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), TransmittanceError> {
        match *self {
            Transmittance::Fixed { tau } if !(0.0..=1.0).contains(&tau) => {
                Err(TransmittanceError { name: "tau", value: tau, range: "[0, 1]".into() })
            }
            Transmittance::BeerLambert { extinction_per_km, .. }
                if !(extinction_per_km.is_finite() && extinction_per_km >= 0.0) =>
            {
                Err(TransmittanceError {
                    name: "extinction_per_km", value: extinction_per_km, range: "[0, ∞)".into()
                })
            }
            Transmittance::BeerLambert { scale_height_km, .. } if !(scale_height_km > 0.0) => {
                Err(TransmittanceError { name: "scale_height_km", value: scale_height_km, range: "(0, ∞]".into() })
            }
            _ => Ok(()),
        }
    }

    /// Optical depth `∫β ds` between altitudes `z_a` and `z_b` (m) along a path of length `length_m`.
    fn optical_depth(beta0_per_m: f64, scale_m: f64, z_a: f64, z_b: f64, length_m: f64) -> f64 {
        if scale_m.is_infinite() {
            return beta0_per_m * length_m;
        }
        // mean of e^{−z/H} over z from z_a to z_b, exact, stable when z_a ≈ z_b
        let (lo, hi) = if z_a <= z_b { (z_a, z_b) } else { (z_b, z_a) };
        let d = (hi - lo) / scale_m;
        let mean = (-lo / scale_m).exp() * if d < 1e-8 { 1.0 - 0.5 * d } else { -(-d).exp_m1() / d };
        beta0_per_m * length_m * mean
    }
}

impl PathTransmittance for Transmittance {
    fn along_segment(&self, a_m: DVec3, b_m: DVec3) -> f64 {
        match *self {
            Transmittance::Fixed { tau } => tau,
            Transmittance::BeerLambert { extinction_per_km, scale_height_km } => {
                let depth = Self::optical_depth(
                    extinction_per_km / 1000.0,
                    scale_height_km * 1000.0,
                    a_m.z,
                    b_m.z,
                    a_m.distance(b_m),
                );
                (-depth).exp()
            }
        }
    }

    fn to_space(&self, from_m: DVec3, direction: DVec3) -> f64 {
        match *self {
            Transmittance::Fixed { tau } => tau,
            Transmittance::BeerLambert { extinction_per_km, scale_height_km } => {
                let sin_el = direction.normalize_or_zero().z;
                if extinction_per_km == 0.0 {
                    return 1.0;
                }
                if sin_el <= 0.0 || scale_height_km.is_infinite() {
                    return 0.0;
                }
                // ∫_z^∞ β₀ e^{−z'/H} dz' / sin(el)
                let scale_m = scale_height_km * 1000.0;
                let depth = extinction_per_km / 1000.0 * scale_m * (-from_m.z / scale_m).exp() / sin_el;
                (-depth).exp()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unity_at_zero_range() {
        let t = Transmittance::BeerLambert { extinction_per_km: 0.3, scale_height_km: 2.0 };
        let p = DVec3::new(0.0, 0.0, 5000.0);
        assert_eq!(t.along_segment(p, p), 1.0);
    }

    #[test]
    fn homogeneous_is_beer_lambert() {
        let t = Transmittance::BeerLambert { extinction_per_km: 0.2, scale_height_km: f64::INFINITY };
        let tau = t.along_segment(DVec3::ZERO, DVec3::new(0.0, 10_000.0, 0.0));
        assert!((tau - (-2.0f64).exp()).abs() < 1e-15);
    }

    #[test]
    fn slant_path_matches_numerical_integral() {
        let t = Transmittance::BeerLambert { extinction_per_km: 0.5, scale_height_km: 2.0 };
        let a = DVec3::new(0.0, 0.0, 1000.0);
        let b = DVec3::new(0.0, 20_000.0, 8000.0);
        let n = 100_000;
        let mut depth = 0.0;
        for i in 0..n {
            let p = a.lerp(b, (i as f64 + 0.5) / n as f64);
            depth += 0.5e-3 * (-p.z / 2000.0).exp() * a.distance(b) / n as f64;
        }
        assert!((t.along_segment(a, b) - (-depth).exp()).abs() < 1e-9);
    }

    #[test]
    fn validation() {
        assert!(Transmittance::Fixed { tau: 1.1 }.validate().is_err());
        assert!(Transmittance::BeerLambert { extinction_per_km: -1.0, scale_height_km: 2.0 }.validate().is_err());
        assert!(Transmittance::BeerLambert { extinction_per_km: 0.1, scale_height_km: 0.0 }.validate().is_err());
    }
}
