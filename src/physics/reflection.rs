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

use super::brdf::{CookTorrance, LANES, TowardPair, sin_cos_deg};
use super::planck::{Band, band_radiance};
use super::simd::widest;

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
    /// Unit directions, by component, point by point.
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    /// Every point's solid-angle weight (the cells have equal areas; 4π over the points).
    weight: f64,
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
        let mut q = Self { x: Vec::new(), y: Vec::new(), z: Vec::new(), weight };
        for i in 0..n_z {
            let z = -1.0 + 2.0 * (i as f64 + 0.5) / n_z as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            for k in 0..n_phi {
                let (sp, cp) = (std::f64::consts::TAU * (k as f64 + 0.5) / n_phi as f64).sin_cos();
                q.x.push(r * cp);
                q.y.push(r * sp);
                q.z.push(z);
            }
        }
        q
    }

    /// Points.
    fn len(&self) -> usize {
        self.x.len()
    }
}

/// Sphere grids with at least this many points are summed with their points' terms evaluated in parallel (the
/// reference preset's 192 × 384). The standard preset's 24 × 48 is worked out on the target's own thread: the
/// targets' radiometry already runs in parallel, and with the points as vectors the split only cost time (the
/// radiometry stage of swarm 106.5 → 101.5 µs a frame, crossing_pair 19 → 18, supersonic_climb 21.5 → 20, head_on
/// 14 → 13; 10 alternating runs of `irsim bench S --frames 600`, medians, 8–10 of 10 lower, AMD EPYC Zen 5).
const PARALLEL_POINTS: usize = 4096;

/// Projected-area weighted mean of `f·(n·l)` over the visible surface of an ellipsoid, sr⁻¹.
///
/// `semi_axes_m` are the ellipsoid's semi-axes in its body frame, `body_to_world` its attitude; `v` points
/// to the viewer and `l` to the sun. Multiply by the sun's irradiance to get the reflected radiance that an
/// unresolving sensor sees. For a point `s` on the unit sphere the surface point is `A s` and
/// `(n·v) dA = det A · (A⁻ᵀ s)·v dΩ`, so the sum needs no normalisation of surface elements.
///
/// The points' terms are worked out 64 at a time, as vectors where the CPU has them, and summed in the points'
/// order, so the mean is the same bits as from one point at a time (the test
/// `lanes_are_the_points_one_at_a_time`), at any vector width and from any number of threads. On an AMD EPYC
/// (Zen 5) with the default 24 × 48 grid, one call on one thread took 9.4 µs one point at a time, 5.9 µs so.
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
    let terms = PointTerms { inv: semi_axes_m.recip(), v: v_body, l: l_body, brdf: brdf.toward(v_body, l_body) };
    let n = quadrature.len();
    let (mut weighted, mut area) = (0.0, 0.0);
    let mut add = |a: &[f64], b: &[f64]| {
        for (a, b) in a.iter().zip(b) {
            area += a;
            weighted += b;
        }
    };
    if n >= PARALLEL_POINTS {
        // a large grid's terms in parallel, each task's into its part of the buffers, then summed in order
        use rayon::prelude::*;
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        a.par_chunks_mut(LANES).zip(b.par_chunks_mut(LANES)).enumerate().with_min_len(2).for_each(|(c, (a, b))| {
            terms.fill(quadrature, c * LANES, a, b);
        });
        add(&a, &b);
    } else {
        let (mut a, mut b) = ([0.0; LANES], [0.0; LANES]);
        for start in (0..n).step_by(LANES) {
            let count = LANES.min(n - start);
            terms.fill(quadrature, start, &mut a[..count], &mut b[..count]);
            add(&a[..count], &b[..count]);
        }
    }
    if area > 0.0 { weighted / area } else { 0.0 }
}

/// What a sphere point adds to [`ellipsoid_reflectance`]'s two sums for one ellipsoid (its inverse semi-axes),
/// viewer and sun (body frame): `w·(n·v)` to the projected area and `w·(n·v)·f·(n·l)` to the reflectance.
struct PointTerms<'a> {
    inv: DVec3,
    v: DVec3,
    l: DVec3,
    brdf: TowardPair<'a>,
}

impl PointTerms<'_> {
    /// The terms of one point `s` of weight `w`, 0 where it adds nothing (`x + 0 = x` for the sums'
    /// non-negative `x`).
    #[cfg(test)]
    fn one(&self, s: DVec3, w: f64) -> (f64, f64) {
        let normal_scaled = s * self.inv; // A⁻ᵀ s for a diagonal A (det A cancels in the ratio)
        let projected = normal_scaled.dot(self.v);
        if projected <= 0.0 {
            return (0.0, 0.0);
        }
        let length = normal_scaled.length();
        let n = normal_scaled / length;
        let nl = n.dot(self.l);
        let weighted = if nl > 0.0 { w * projected * self.brdf.f_unit(n, projected / length, nl) * nl } else { 0.0 };
        (w * projected, weighted)
    }

    /// The terms of the points from `start` on, as many as `area` holds (at most [`LANES`]), into `area` and
    /// `weighted`: the operations of `PointTerms::one` (the tests' one point at a time) lane by lane, compiled
    /// for the widest vectors ([`widest`]).
    fn fill(&self, q: &SphereQuadrature, start: usize, area: &mut [f64], weighted: &mut [f64]) {
        let count = area.len();
        assert!(count <= LANES && weighted.len() == count);
        let range = start..start + count;
        let (sx, sy, sz, w) = (&q.x[range.clone()], &q.y[range.clone()], &q.z[range], q.weight);
        // moved in, so that no store through `area` or `weighted` could change where the loops read (they
        // vectorize)
        widest(
            #[inline(always)]
            move || {
                let (inv, v, l) = (self.inv, self.v, self.l);
                // every slice exactly `count` long, so that the loops index them without a bounds test
                let (sx, sy, sz) = (&sx[..count], &sy[..count], &sz[..count]);
                let (area, weighted) = (&mut area[..count], &mut weighted[..count]);
                let (mut nx, mut ny, mut nz) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
                let (mut nv, mut nl, mut wp, mut lit) = ([0.0; LANES], [0.0; LANES], [0.0; LANES], [false; LANES]);
                for k in 0..count {
                    let (x, y, z) = (sx[k] * inv.x, sy[k] * inv.y, sz[k] * inv.z);
                    let projected = (x * v.x + y * v.y) + z * v.z;
                    let length = ((x * x + y * y) + z * z).sqrt();
                    (nx[k], ny[k], nz[k]) = (x / length, y / length, z / length);
                    nl[k] = (nx[k] * l.x + ny[k] * l.y) + nz[k] * l.z;
                    let seen = !(projected <= 0.0);
                    lit[k] = seen && nl[k] > 0.0;
                    wp[k] = w * projected;
                    area[k] = if seen { wp[k] } else { 0.0 };
                    // a point that is not lit takes no BRDF (n·v < 0 makes it 0 without its exponential)
                    nv[k] = if lit[k] { projected / length } else { -1.0 };
                }
                let mut f = [0.0; LANES];
                self.brdf.f_unit_lanes(
                    [&nx[..count], &ny[..count], &nz[..count]],
                    &nv[..count],
                    &nl[..count],
                    &mut f[..count],
                );
                for k in 0..count {
                    weighted[k] = if lit[k] { wp[k] * f[k] * nl[k] } else { 0.0 };
                }
            },
        );
    }
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
    fn lanes_are_the_points_one_at_a_time() {
        // the mean against the two sums taken one point at a time in the points' order, bit for bit: one block,
        // several blocks with a partial last one (77 and 713 points; draft's 128, standard's 1152), the parallel
        // path with and without a short last chunk (4221, 4480 points), materials from a mirror to a rough
        // dielectric, and the light from anywhere, on the viewer's side (v = l) and opposite it (v = −l, no half
        // vector)
        let dir = |t: f64, p: f64| DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        let materials = [
            CookTorrance::default(),
            CookTorrance { kd: 0.1, ks: 0.9, f0: 0.5, roughness: 1e-4 },
            CookTorrance { kd: 0.0, ks: 1.0, f0: 0.04, roughness: 5.0 },
        ];
        let (mut compared, mut lit) = (0, 0);
        const { assert!(67 * 63 >= PARALLEL_POINTS && 67 * 63 % LANES != 0 && 70 * 64 % LANES == 0) };
        for (n_z, n_phi) in [(3, 5), (7, 11), (8, 16), (23, 31), (24, 48), (67, 63), (70, 64)] {
            let q = SphereQuadrature::new(n_z, n_phi);
            for brdf in &materials {
                for k in 0..12 {
                    let t = k as f64;
                    let v = dir(0.3 * t, 0.9 * t);
                    for l in [dir(3.0 - 0.25 * t, 1.7 * t), -v, v] {
                        let axes = DVec3::new(6.0, 1.5, 1.5 + 0.2 * t);
                        let attitude = DMat3::from_rotation_z(0.4 * t) * DMat3::from_rotation_x(0.3 * t);
                        let got = ellipsoid_reflectance(brdf, axes, attitude, v, l, &q);
                        let (vb, lb) = (attitude.transpose() * v.normalize(), attitude.transpose() * l.normalize());
                        let terms = PointTerms { inv: axes.recip(), v: vb, l: lb, brdf: brdf.toward(vb, lb) };
                        let (mut area, mut weighted) = (0.0, 0.0);
                        for i in 0..q.len() {
                            let (a, b) = terms.one(DVec3::new(q.x[i], q.y[i], q.z[i]), q.weight);
                            area += a;
                            weighted += b;
                        }
                        let want = if area > 0.0 { weighted / area } else { 0.0 };
                        assert_eq!(
                            got.to_bits(),
                            want.to_bits(),
                            "{n_z}×{n_phi}, {brdf:?}, v {v}, l {l}: {got} {want}"
                        );
                        compared += 1;
                        lit += usize::from(weighted > 0.0);
                    }
                }
            }
        }
        assert!(compared == 756 && lit > 450, "{compared} compared, {lit} lit");
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
