//! Reflected sunlight (paper eq 9) and total radiance (eq 10).
//!
//! The sun is a blackbody of temperature `temp_k` subtending `solid_angle_sr`; its band irradiance at normal
//! incidence above the atmosphere is `E = Ω · L_band(T_sun)`, and `τ_sun` of it reaches the target. Since the
//! BRDF is spectrally flat, eq 9 becomes `L_re = f · (n·l) · E · τ_sun`.
//!
//! Two ways to pick the surface normal:
//! - [`ReflectionGeometry::Facet`], the paper's: one facet whose normal is the half vector of view and sun;
//! - [`ReflectionGeometry::Ellipsoid`]: the general Cook–Torrance form averaged over the visible, sunlit surface
//!   of the target's ellipsoid, weighted by projected area — what a sensor that does not resolve the target
//!   actually measures. It is bounded where the facet form diverges (sun behind the target).

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::brdf::{CookTorrance, sin_cos_deg};
use super::planck::{Band, band_radiance};

/// The sun as seen from the scene.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Sun {
    /// Blackbody temperature, K (5772 K, the solar effective temperature).
    pub temp_k: f64,
    /// Solid angle of the solar disc, sr (6.8e-5 sr at 1 AU).
    pub solid_angle_sr: f64,
    /// Azimuth of the sun, degrees clockwise from north (+y) toward east (+x).
    pub azimuth_deg: f64,
    /// Elevation of the sun above the horizon, degrees.
    pub elevation_deg: f64,
}

impl Default for Sun {
    fn default() -> Self {
        Self { temp_k: 5772.0, solid_angle_sr: 6.8e-5, azimuth_deg: 135.0, elevation_deg: 45.0 }
    }
}

impl Sun {
    /// Unit vector from the scene toward the sun, world frame (x east, y north, z up).
    pub fn direction(&self) -> DVec3 {
        direction_from_az_el(self.azimuth_deg, self.elevation_deg)
    }

    /// Band irradiance of the sun at normal incidence above the atmosphere, W m⁻².
    pub fn band_irradiance_w_m2(&self, band: Band) -> f64 {
        self.solid_angle_sr * band_radiance(band, self.temp_k, 1.0)
    }
}

/// Unit vector at `azimuth_deg` clockwise from north (+y) toward east (+x) and `elevation_deg` above horizon.
pub fn direction_from_az_el(azimuth_deg: f64, elevation_deg: f64) -> DVec3 {
    let (sin_el, cos_el) = sin_cos_deg(elevation_deg);
    let (sin_az, cos_az) = sin_cos_deg(azimuth_deg);
    DVec3::new(cos_el * sin_az, cos_el * cos_az, sin_el)
}

/// How the target's surface normal is chosen for the reflection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReflectionGeometry {
    /// The paper's facet whose normal is the half vector.
    #[default]
    Facet,
    /// The general form averaged over the ellipsoid's visible, sunlit surface.
    Ellipsoid,
}

/// A fixed quadrature over the unit sphere, planned once and reused for every ellipsoid average.
#[derive(Debug, Clone)]
pub struct SphereQuadrature {
    /// Unit directions and their solid-angle weights (sum 4π).
    points: Vec<(DVec3, f64)>,
}

impl SphereQuadrature {
    /// An equal-area grid: `n_z` equal steps in `cos θ` times `n_phi` equal steps in azimuth, cell midpoints.
    ///
    /// The integrand has a kink at the ellipsoid's terminator, so the error falls as the square of the step;
    /// the test `default_quadrature_error` measures the default grid against a 400 × 800 one (worst of four
    /// geometries for a 4:1:1 ellipsoid: 0.92%).
    pub fn new(n_z: usize, n_phi: usize) -> Self {
        let (n_z, n_phi) = (n_z.max(2), n_phi.max(4));
        let weight = 4.0 * std::f64::consts::PI / (n_z * n_phi) as f64;
        let mut points = Vec::with_capacity(n_z * n_phi);
        for i in 0..n_z {
            let z = -1.0 + 2.0 * (i as f64 + 0.5) / n_z as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            for k in 0..n_phi {
                let (sp, cp) = (std::f64::consts::TAU * (k as f64 + 0.5) / n_phi as f64).sin_cos();
                points.push((DVec3::new(r * cp, r * sp, z), weight));
            }
        }
        Self { points }
    }
}

/// Sphere grids with at least this many points are summed with their points' terms evaluated in parallel.
const PARALLEL_POINTS: usize = 512;

/// Projected-area weighted mean of `f·(n·l)` over the visible surface of an ellipsoid, sr⁻¹.
///
/// `semi_axes_m` are the ellipsoid's semi-axes in its body frame, `body_to_world` its attitude; `v` points
/// to the viewer and `l` to the sun. Multiply by the sun's irradiance to get the reflected radiance that an
/// unresolving sensor sees. For a point `s` on the unit sphere the surface point is `A s` and
/// `(n·v) dA = det A · (A⁻ᵀ s)·v dΩ`, so the sum needs no normalisation of surface elements.
pub fn ellipsoid_reflectance(
    brdf: &CookTorrance,
    semi_axes_m: DVec3,
    body_to_world: DMat3,
    v: DVec3,
    l: DVec3,
    quadrature: &SphereQuadrature,
) -> f64 {
    let v_body = body_to_world.transpose() * v.normalize_or_zero();
    let l_body = body_to_world.transpose() * l.normalize_or_zero();
    let inv = semi_axes_m.recip();
    let brdf = brdf.toward(v_body, l_body);
    // each point's terms of the two sums (0 where it adds nothing: x + 0 = x for the sums' non-negative x)
    let terms = |&(s, w): &(DVec3, f64)| -> (f64, f64) {
        let normal_scaled = s * inv; // A⁻ᵀ s for a diagonal A (det A cancels in the ratio)
        let projected = normal_scaled.dot(v_body);
        if projected <= 0.0 {
            return (0.0, 0.0);
        }
        let length = normal_scaled.length();
        let n = normal_scaled / length;
        let nl = n.dot(l_body);
        let weighted = if nl > 0.0 { w * projected * brdf.f_unit(n, projected / length, nl) * nl } else { 0.0 };
        (w * projected, weighted)
    };
    // a large grid's terms are evaluated in parallel and summed in the points' order, as one thread would
    let (mut weighted, mut area) = (0.0, 0.0);
    if quadrature.points.len() >= PARALLEL_POINTS {
        use rayon::prelude::*;
        let all: Vec<(f64, f64)> = quadrature.points.par_iter().with_min_len(PARALLEL_POINTS / 4).map(terms).collect();
        for (a, b) in all {
            area += a;
            weighted += b;
        }
    } else {
        for p in &quadrature.points {
            let (a, b) = terms(p);
            area += a;
            weighted += b;
        }
    }
    if area > 0.0 { weighted / area } else { 0.0 }
}

/// Inputs of the reflected-radiance computation (eq 9).
#[derive(Debug, Clone, Copy)]
pub struct ReflectionInput<'a> {
    /// Material.
    pub brdf: &'a CookTorrance,
    /// The sun.
    pub sun: &'a Sun,
    /// Sensor band.
    pub band: Band,
    /// Transmittance of the path from the target to the sun, [0, 1].
    pub sun_transmittance: f64,
    /// Unit vector from the target toward the viewer.
    pub to_viewer: DVec3,
}

/// Reflected band radiance `L_re` of a target, W m⁻² sr⁻¹ (eq 9).
///
/// `ellipsoid` is `(semi_axes_m, body_to_world, quadrature)` for [`ReflectionGeometry::Ellipsoid`] and ignored
/// for the facet form. A sun at or below the horizon gives 0.
pub fn reflected_radiance(
    input: &ReflectionInput<'_>,
    geometry: ReflectionGeometry,
    ellipsoid: Option<(DVec3, DMat3, &SphereQuadrature)>,
) -> f64 {
    if input.sun.elevation_deg <= 0.0 || input.sun_transmittance <= 0.0 {
        return 0.0;
    }
    let l = input.sun.direction();
    let v = input.to_viewer;
    let irradiance = input.sun.band_irradiance_w_m2(input.band) * input.sun_transmittance;
    let factor = match (geometry, ellipsoid) {
        (ReflectionGeometry::Ellipsoid, Some((axes, attitude, quad))) => {
            ellipsoid_reflectance(input.brdf, axes, attitude, v, l, quad)
        }
        _ => {
            let value = input.brdf.evaluate_facet(v, l);
            // n = h, so n·l = v·h
            let h = (v.normalize_or_zero() + l).normalize_or_zero();
            value.f_per_sr * h.dot(l).max(0.0)
        }
    };
    factor * irradiance
}

/// Total radiance `L_sum = L_self + L_re` (eq 10).
pub fn total_radiance(self_radiance: f64, reflected_radiance: f64) -> f64 {
    self_radiance + reflected_radiance
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sun_direction_convention() {
        let east = direction_from_az_el(90.0, 0.0);
        assert!((east - DVec3::X).length() < 1e-15);
        let zenith = direction_from_az_el(0.0, 90.0);
        assert!((zenith - DVec3::Z).length() < 1e-15);
    }

    #[test]
    fn solar_constant_order_of_magnitude() {
        // Whole-spectrum irradiance of a 5772 K sun of 6.8e-5 sr is about 1361 W/m².
        let sun = Sun::default();
        let e = sun.band_irradiance_w_m2(Band::try_new(0.01, 1e4).unwrap());
        assert!((e - 1361.0).abs() < 15.0, "{e}");
    }

    #[test]
    fn lambertian_sphere_average_matches_closed_form() {
        // A Lambertian sphere (k_s = 0) seen with the sun behind the viewer: <f (n·l)> = (kd/π)·(2/3)·... the
        // projected-area mean of (n·v) over the visible hemisphere with l = v is 2/3.
        let brdf = CookTorrance { kd: 1.0, ks: 0.0, f0: 0.0, roughness: 0.3 };
        let quad = SphereQuadrature::new(64, 128);
        let r = ellipsoid_reflectance(&brdf, DVec3::splat(2.0), DMat3::IDENTITY, DVec3::Y, DVec3::Y, &quad);
        let want = (1.0 / std::f64::consts::PI) * 2.0 / 3.0;
        assert!((r - want).abs() / want < 2e-3, "{r} vs {want}");
    }

    #[test]
    fn default_quadrature_error() {
        let brdf = CookTorrance::default();
        let fine = SphereQuadrature::new(400, 800);
        let coarse = SphereQuadrature::new(24, 48);
        let axes = DVec3::new(6.0, 1.5, 1.5);
        let mut worst: f64 = 0.0;
        for (v, l) in [
            (DVec3::Y, DVec3::new(0.3, -0.5, 0.8)),
            (DVec3::new(0.2, 1.0, 0.1), DVec3::new(-0.7, 0.1, 0.7)),
            (DVec3::X, DVec3::new(0.0, 0.6, 0.8)),
            (DVec3::new(0.0, 1.0, -0.3), DVec3::Z),
        ] {
            let a = ellipsoid_reflectance(&brdf, axes, DMat3::IDENTITY, v, l, &coarse);
            let b = ellipsoid_reflectance(&brdf, axes, DMat3::IDENTITY, v, l, &fine);
            worst = worst.max(((a - b) / b).abs());
        }
        eprintln!("ellipsoid reflectance, default grid vs 400x800: worst relative error {worst:.2e}");
        assert!(worst < 0.02, "{worst}");
    }

    #[test]
    fn ellipsoid_form_is_bounded_with_the_sun_behind() {
        let brdf = CookTorrance::default();
        let quad = SphereQuadrature::new(24, 48);
        let axes = DVec3::new(6.0, 1.5, 1.5);
        let v = DVec3::Y;
        let l = -DVec3::Y + DVec3::Z * 1e-9;
        let r = ellipsoid_reflectance(&brdf, axes, DMat3::IDENTITY, v, l, &quad);
        assert!((0.0..1.0).contains(&r));
    }
}
