//! The target's image: an ellipsoid projected to its exact image ellipse, drawn as a generalized Gaussian.
//!
//! **Projection.** The outline of an ellipsoid `(X − c)ᵀM(X − c) = 1` seen from a pinhole at `C` is the cone of
//! rays `d` tangent to it: with `e = C − c`, `dᵀ[M e eᵀ M − (eᵀMe − 1) M] d = 0`, a rays inside it meet the
//! ellipsoid. Mapping `d = R K⁻¹ p` gives a conic in pixel coordinates, whose centre, semi-axes and angle
//! are the exact image ellipse. The ellipse centre is generally not the image of the ellipsoid's centre.
//!
//! **Gray distribution** (eq 11): `g(x, y) = peak · exp(−(|x'|/α_x)^β_x − (|y'|/α_y)^β_y)` with the normalising
//! constant dropped (the peak is set by the gray value), `α` the scale in pixels and `β` the shape (2 is a
//! Gaussian, large β a flat top). **Eq 12 as printed is not a rotation**: its matrix `[[cos ρ, −sin ρ],
//! [−sin ρ, cos ρ]]` has determinant `cos 2ρ`, which collapses the target to a line at ρ = π/4. We use the proper
//! rotation `x' = (x − x₀)cos ρ + (y − y₀)sin ρ`, `y' = −(x − x₀)sin ρ + (y − y₀)cos ρ`. Angles are measured from
//! the image's +u axis toward +v (clockwise on screen, since v points down).
//!
//! **Scale from the ellipse**: `α = √(a² + b_min²)` per axis, where `a` is the ellipse semi-axis and `b_min` a
//! configurable minimum blur standing for the optics' point spread, so a sub-pixel target is as wide as the
//! blur.

use glam::{DMat2, DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::camera::Camera;
use super::frame::Frame;

/// A target's ellipsoid in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid {
    /// Centre, m.
    pub center_m: DVec3,
    /// Semi-axes along the body x (forward), y (left), z (up) axes, m.
    pub semi_axes_m: DVec3,
    /// Body-to-world rotation (columns: body axes in world coordinates).
    pub body_to_world: DMat3,
}

/// Body-to-world rotation of a target (columns: x forward, y left, z up): a fixed `attitude` (yaw, pitch, roll
/// of the body's forward axis, as a camera's), or, without one, the long axis along `velocity`.
pub fn body_to_world(attitude: Option<crate::imaging::camera::YawPitchRoll>, velocity: DVec3) -> DMat3 {
    match attitude {
        Some(a) => {
            // camera axes are (right, down, forward); the body's are (forward, left, up)
            let c = a.camera_to_world();
            DMat3::from_cols(c.z_axis, -c.x_axis, -c.y_axis)
        }
        None => attitude_from_velocity(velocity),
    }
}

/// Body attitude with x along `velocity`, z as close to world up as possible; level flight if `velocity` is 0.
pub fn attitude_from_velocity(velocity: DVec3) -> DMat3 {
    let x = velocity.try_normalize().unwrap_or(DVec3::Y);
    let mut y = DVec3::Z.cross(x);
    if y.length_squared() < 1e-24 {
        // vertical flight: pick body y along world x
        y = DVec3::X;
    }
    let y = y.normalize();
    let z = x.cross(y);
    DMat3::from_cols(x, y, z)
}

impl Ellipsoid {
    /// The quadric matrix `M = R diag(1/a²) Rᵀ`.
    pub fn quadric(&self) -> DMat3 {
        let r = self.body_to_world;
        let d = DMat3::from_diagonal(self.semi_axes_m.recip() * self.semi_axes_m.recip());
        r * d * r.transpose()
    }
}

/// An ellipse in image coordinates (px).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImageEllipse {
    /// Centre, px.
    pub center: DVec2,
    /// Semi-major axis, px.
    pub a: f64,
    /// Semi-minor axis, px.
    pub b: f64,
    /// Angle of the major axis from +u toward +v, radians in (−π/2, π/2].
    pub angle_rad: f64,
}

impl ImageEllipse {
    /// Area, px².
    pub fn area_px2(&self) -> f64 {
        std::f64::consts::PI * self.a * self.b
    }

    /// Fill factor of one pixel (eq 13 with DESIGN.md's correction): `min(1, area)` for a pixel of area 1.
    pub fn fill_factor(&self) -> f64 {
        self.area_px2().min(1.0)
    }

    /// Axis-aligned bounding box `[x0, y0, x1, y1]`, px.
    pub fn bbox(&self) -> [f64; 4] {
        let (s, c) = self.angle_rad.sin_cos();
        let hx = ((self.a * c).powi(2) + (self.b * s).powi(2)).sqrt();
        let hy = ((self.a * s).powi(2) + (self.b * c).powi(2)).sqrt();
        [self.center.x - hx, self.center.y - hy, self.center.x + hx, self.center.y + hy]
    }
}

/// Result of projecting an ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EllipsoidProjection {
    /// Entirely in front of the camera: its outline.
    Visible(ImageEllipse),
    /// Some part at or behind the camera plane: the outline is not an ellipse; not drawn.
    Behind,
    /// The camera is inside the ellipsoid.
    Inside,
}

/// Projects `ellipsoid` through `camera` to its exact image ellipse.
pub fn project_ellipsoid(ellipsoid: &Ellipsoid, camera: &Camera) -> EllipsoidProjection {
    let m = ellipsoid.quadric();
    let e = camera.position_m - ellipsoid.center_m;
    let eme = e.dot(m * e);
    if eme <= 1.0 {
        return EllipsoidProjection::Inside;
    }
    // Nearest point along the optical axis: depth of centre minus the support half-width.
    let fwd = camera.forward();
    let m_inv = {
        let r = ellipsoid.body_to_world;
        r * DMat3::from_diagonal(ellipsoid.semi_axes_m * ellipsoid.semi_axes_m) * r.transpose()
    };
    let depth = (ellipsoid.center_m - camera.position_m).dot(fwd);
    if depth - fwd.dot(m_inv * fwd).sqrt() <= 0.0 {
        return EllipsoidProjection::Behind;
    }
    let me = m * e;
    let cone = outer(me, me) - m * (eme - 1.0);
    // pixel homogeneous p → world direction d = R K⁻¹ p
    let k_inv = camera.k_matrix().inverse();
    let t = camera.camera_to_world * k_inv;
    let conic = t.transpose() * cone * t;
    match ellipse_from_conic(&conic) {
        Some(el) => EllipsoidProjection::Visible(el),
        None => EllipsoidProjection::Behind,
    }
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The ellipse `pᵀ C p = 0` (inside where `pᵀ C p > 0`), or `None` if the conic is not a real ellipse.
pub fn ellipse_from_conic(c: &DMat3) -> Option<ImageEllipse> {
    // C symmetric: [[Q, b], [bᵀ, f]]
    let q = DMat2::from_cols(c.x_axis.truncate(), c.y_axis.truncate());
    let b = DVec2::new(c.z_axis.x, c.z_axis.y);
    let f = c.z_axis.z;
    let det = q.determinant();
    if det.abs() < f64::MIN_POSITIVE {
        return None;
    }
    let center = -(q.inverse() * b);
    let k = f + b.dot(center);
    // (x − x0)ᵀ S (x − x0) = 1 with S = −Q/k
    let s = q * (-1.0 / k);
    let (p, r, qq) = (s.x_axis.x, s.y_axis.y, 0.5 * (s.x_axis.y + s.y_axis.x));
    let mean = 0.5 * (p + r);
    let diff = (0.25 * (p - r) * (p - r) + qq * qq).sqrt();
    let (l_small, l_large) = (mean - diff, mean + diff);
    if !(l_small > 0.0) || !center.is_finite() {
        return None;
    }
    // major axis along the eigenvector of the smaller eigenvalue
    let angle = 0.5 * (2.0 * qq).atan2(p - r) + std::f64::consts::FRAC_PI_2;
    let angle = wrap_half_pi(angle);
    Some(ImageEllipse { center, a: 1.0 / l_small.sqrt(), b: 1.0 / l_large.sqrt(), angle_rad: angle })
}

fn wrap_half_pi(mut a: f64) -> f64 {
    use std::f64::consts::PI;
    while a > PI / 2.0 {
        a -= PI;
    }
    while a <= -PI / 2.0 {
        a += PI;
    }
    a
}

/// Parameters of the generalized Gaussian (eq 11) with a proper rotation (eq 12 corrected).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeneralizedGaussian {
    /// Centre, px.
    pub center: DVec2,
    /// Scale along the blob's own x axis, px (`ρ_αx`).
    pub alpha_x: f64,
    /// Scale along its y axis, px (`ρ_αy`).
    pub alpha_y: f64,
    /// Shape exponent along x (`ρ_βx`), > 0.
    pub beta_x: f64,
    /// Shape exponent along y (`ρ_βy`), > 0.
    pub beta_y: f64,
    /// Rotation from +u toward +v, radians (`ρ_a`).
    pub angle_rad: f64,
    /// Peak value, gray levels.
    pub peak: f64,
}

/// How the blob is evaluated on pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "mode", deny_unknown_fields, from = "BlobSamplingFields")]
pub enum BlobSampling {
    /// The value at each pixel centre.
    Point,
    /// The mean of `n × n` point samples over the pixel's area.
    Integrated {
        /// Samples per side, 1 … 16.
        n: u32,
    },
    /// Adaptive default: integrated with 4 × 4 where the blob is narrower than 2 px, point otherwise.
    #[default]
    Auto,
}

/// [`BlobSampling`] as a scenario writes it, every variant a table of its fields: serde reads a variant without fields
/// from the tag alone and ignores any key beside it (`{ mode = "point", n = 4 }` would pass), so [`BlobSampling`] is read through this and
/// such a key is refused as unknown.
#[derive(Deserialize)]
#[serde(
    rename_all = "snake_case",
    tag = "mode",
    deny_unknown_fields,
    expecting = "a table with `mode`: point, integrated or auto"
)]
enum BlobSamplingFields {
    Point {},
    Integrated { n: u32 },
    Auto {},
}

impl From<BlobSamplingFields> for BlobSampling {
    fn from(s: BlobSamplingFields) -> Self {
        match s {
            BlobSamplingFields::Point {} => Self::Point,
            BlobSamplingFields::Integrated { n } => Self::Integrated { n },
            BlobSamplingFields::Auto {} => Self::Auto,
        }
    }
}

/// An axis-aligned pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct PixelRect {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// One past the last column.
    pub x1: usize,
    /// One past the last row.
    pub y1: usize,
}

impl PixelRect {
    /// The rectangle `[x0, y0, x1, y1]` (whole numbers of pixels, any sign, NaN as 0) clipped to a
    /// `width × height` frame.
    pub fn clipped(bounds: [f64; 4], width: usize, height: usize) -> Self {
        let clip = |v: f64, max: usize| -> usize {
            if v.is_nan() || v <= 0.0 {
                0
            } else if v >= max as f64 {
                max
            } else {
                v as usize
            }
        };
        let [x0, y0, x1, y1] = bounds;
        PixelRect { x0: clip(x0, width), y0: clip(y0, height), x1: clip(x1, width), y1: clip(y1, height) }
    }

    /// Width, px.
    pub fn width(&self) -> usize {
        self.x1 - self.x0
    }

    /// Height, px.
    pub fn height(&self) -> usize {
        self.y1 - self.y0
    }

    /// True if it holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.x1 <= self.x0 || self.y1 <= self.y0
    }

    /// True if the two rectangles share a pixel or touch along an edge.
    pub fn touches(&self, other: &PixelRect) -> bool {
        self.x0 <= other.x1 && other.x0 <= self.x1 && self.y0 <= other.y1 && other.y0 <= self.y1
    }

    /// The smallest rectangle holding both.
    pub fn union(&self, other: &PixelRect) -> PixelRect {
        PixelRect {
            x0: self.x0.min(other.x0),
            y0: self.y0.min(other.y0),
            x1: self.x1.max(other.x1),
            y1: self.y1.max(other.y1),
        }
    }
}

impl GeneralizedGaussian {
    /// The blob for an image ellipse: scales `√(a² + blur²)` and `√(b² + blur²)`, the ellipse's angle.
    pub fn from_ellipse(ellipse: &ImageEllipse, min_blur_px: f64, beta: f64, peak: f64) -> Self {
        Self {
            center: ellipse.center,
            alpha_x: (ellipse.a * ellipse.a + min_blur_px * min_blur_px).sqrt(),
            alpha_y: (ellipse.b * ellipse.b + min_blur_px * min_blur_px).sqrt(),
            beta_x: beta,
            beta_y: beta,
            angle_rad: ellipse.angle_rad,
            peak,
        }
    }

    /// Integral of the blob over the plane divided by its peak, px²: `4 α_x α_y Γ(1+1/β_x) Γ(1+1/β_y)`
    /// (π α_x α_y for a Gaussian).
    pub fn integral(&self) -> f64 {
        4.0 * self.alpha_x * self.alpha_y * gamma(1.0 + 1.0 / self.beta_x) * gamma(1.0 + 1.0 / self.beta_y)
    }

    /// Value at image point `p` (px). Uses a proper rotation, not eq 12 as printed.
    #[inline]
    pub fn value(&self, p: DVec2) -> f64 {
        let (s, c) = self.angle_rad.sin_cos();
        self.value_rotated(p, s, c)
    }

    #[inline]
    fn value_rotated(&self, p: DVec2, s: f64, c: f64) -> f64 {
        let d = p - self.center;
        let xr = d.x * c + d.y * s;
        let yr = -d.x * s + d.y * c;
        let (sx, sy) = (xr / self.alpha_x, yr / self.alpha_y);
        // β = 2 (a Gaussian, the default) needs no powf
        let ex = if self.beta_x == 2.0 { sx * sx } else { sx.abs().powf(self.beta_x) };
        let ey = if self.beta_y == 2.0 { sy * sy } else { sy.abs().powf(self.beta_y) };
        self.peak * (-(ex + ey)).exp()
    }

    /// Half-widths along the blob's own axes beyond which the value is below `fraction` of the peak.
    pub fn support_half_widths(&self, fraction: f64) -> DVec2 {
        let l = (1.0 / fraction.clamp(1e-300, 1.0)).ln();
        DVec2::new(self.alpha_x * l.powf(1.0 / self.beta_x), self.alpha_y * l.powf(1.0 / self.beta_y))
    }

    /// Pixel region where the blob exceeds `fraction` of its peak (a box around the rotated support), clipped
    /// to a `width × height` frame, plus a one-pixel margin for the fusion boundary. Empty if it is off-frame.
    pub fn region_of_interest(&self, fraction: f64, width: usize, height: usize) -> PixelRect {
        let h = self.support_half_widths(fraction);
        let (s, c) = self.angle_rad.sin_cos();
        let hx = (h.x * c).abs() + (h.y * s).abs();
        let hy = (h.x * s).abs() + (h.y * c).abs();
        PixelRect::clipped(
            [
                (self.center.x - hx).floor() - 1.0,
                (self.center.y - hy).floor() - 1.0,
                (self.center.x + hx).ceil() + 1.0,
                (self.center.y + hy).ceil() + 1.0,
            ],
            width,
            height,
        )
    }

    /// Samples per pixel side for `sampling`.
    pub fn samples_per_side(&self, sampling: BlobSampling) -> usize {
        match sampling {
            BlobSampling::Point => 1,
            BlobSampling::Integrated { n } => n.clamp(1, 16) as usize,
            BlobSampling::Auto => {
                if self.alpha_x.min(self.alpha_y) < 2.0 {
                    4
                } else {
                    1
                }
            }
        }
    }

    /// Evaluates the blob on the pixels of `rect` into `out` (row-major, `rect.width()` wide).
    ///
    /// # Panics
    /// If `out` is shorter than the rectangle.
    pub fn render_patch(&self, rect: PixelRect, sampling: BlobSampling, out: &mut [f32]) {
        let n = self.samples_per_side(sampling);
        let (s, c) = self.angle_rad.sin_cos();
        let w = rect.width();
        assert!(out.len() >= w * rect.height(), "patch buffer too short");
        let inv = 1.0 / (n * n) as f64;
        for (row, y) in (rect.y0..rect.y1).enumerate() {
            for (col, x) in (rect.x0..rect.x1).enumerate() {
                let mut sum = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let p = DVec2::new(
                            x as f64 + (sx as f64 + 0.5) / n as f64,
                            y as f64 + (sy as f64 + 0.5) / n as f64,
                        );
                        sum += self.value_rotated(p, s, c);
                    }
                }
                out[row * w + col] = (sum * inv) as f32;
            }
        }
    }

    /// Adds the blob to `frame` on its region of interest (the paper's "additive" placement, no fusion).
    pub fn add_to(&self, frame: &mut Frame, fraction: f64, sampling: BlobSampling) {
        let rect = self.region_of_interest(fraction, frame.width(), frame.height());
        if rect.is_empty() {
            return;
        }
        let mut patch = vec![0.0f32; rect.width() * rect.height()];
        self.render_patch(rect, sampling, &mut patch);
        let w = frame.width();
        let px = frame.pixels_mut();
        for (row, y) in (rect.y0..rect.y1).enumerate() {
            for (col, x) in (rect.x0..rect.x1).enumerate() {
                px[y * w + x] += patch[row * rect.width() + col];
            }
        }
    }
}

/// The gamma function for `x > 0` (Lanczos, g = 7, 9 terms; relative error below 1e-14 on [1, 2]).
pub fn gamma(x: f64) -> f64 {
    const G: f64 = 7.0;
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return std::f64::consts::PI / ((std::f64::consts::PI * x).sin() * gamma(1.0 - x));
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + G + 0.5;
    for (i, &c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    (2.0 * std::f64::consts::PI).sqrt() * t.powf(x + 0.5) * (-t).exp() * a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::camera::{Intrinsics, YawPitchRoll};

    #[test]
    fn gamma_values() {
        assert!((gamma(1.5) - std::f64::consts::PI.sqrt() / 2.0).abs() < 1e-14);
        assert!((gamma(1.0) - 1.0).abs() < 1e-14);
        assert!((gamma(5.0) - 24.0).abs() < 1e-11);
        let g = GeneralizedGaussian {
            center: DVec2::ZERO,
            alpha_x: 2.0,
            alpha_y: 3.0,
            beta_x: 2.0,
            beta_y: 2.0,
            angle_rad: 0.3,
            peak: 1.0,
        };
        assert!((g.integral() - std::f64::consts::PI * 6.0).abs() < 1e-12);
    }

    fn camera() -> Camera {
        Camera::new(Intrinsics::try_new(256, 256, 0.1, 17e-6).unwrap(), DVec3::ZERO, YawPitchRoll::default())
    }

    #[test]
    fn sphere_on_axis_projects_to_a_centred_circle() {
        let cam = camera();
        let f = cam.intrinsics.focal_px();
        let (r, d) = (10.0, 5000.0);
        let e = Ellipsoid {
            center_m: DVec3::new(0.0, d, 0.0),
            semi_axes_m: DVec3::splat(r),
            body_to_world: DMat3::IDENTITY,
        };
        let EllipsoidProjection::Visible(el) = project_ellipsoid(&e, &cam) else { panic!() };
        // tangent cone half-angle asin(r/d): image radius f·tan(asin(r/d))
        let want = f * (r / d).asin().tan();
        assert!((el.a - want).abs() < 1e-9 && (el.b - want).abs() < 1e-9, "{el:?} vs {want}");
        assert!((el.center - DVec2::splat(128.0)).length() < 1e-9);
    }

    #[test]
    fn ellipse_from_axis_aligned_conic() {
        // (x−10)²/9 + (y−20)²/4 = 1, inside positive: −(…) + 1 > 0
        let c = DMat3::from_cols(
            DVec3::new(-1.0 / 9.0, 0.0, 10.0 / 9.0),
            DVec3::new(0.0, -1.0 / 4.0, 20.0 / 4.0),
            DVec3::new(10.0 / 9.0, 20.0 / 4.0, 1.0 - 100.0 / 9.0 - 400.0 / 4.0),
        );
        let el = ellipse_from_conic(&c).unwrap();
        assert!((el.center - DVec2::new(10.0, 20.0)).length() < 1e-12);
        assert!((el.a - 3.0).abs() < 1e-12 && (el.b - 2.0).abs() < 1e-12);
        assert!(el.angle_rad.abs() < 1e-12);
    }

    #[test]
    fn behind_and_inside_are_reported() {
        let cam = camera();
        let behind = Ellipsoid {
            center_m: DVec3::new(0.0, -100.0, 0.0),
            semi_axes_m: DVec3::splat(5.0),
            body_to_world: DMat3::IDENTITY,
        };
        assert_eq!(project_ellipsoid(&behind, &cam), EllipsoidProjection::Behind);
        let straddling = Ellipsoid {
            center_m: DVec3::new(0.0, 2.0, 0.0),
            semi_axes_m: DVec3::new(1.0, 5.0, 1.0),
            body_to_world: DMat3::IDENTITY,
        };
        assert!(matches!(
            project_ellipsoid(&straddling, &cam),
            EllipsoidProjection::Behind | EllipsoidProjection::Inside
        ));
        let around =
            Ellipsoid { center_m: DVec3::ZERO, semi_axes_m: DVec3::splat(5.0), body_to_world: DMat3::IDENTITY };
        assert_eq!(project_ellipsoid(&around, &cam), EllipsoidProjection::Inside);
    }

    #[test]
    fn rotation_is_proper_at_quarter_pi() {
        let g = GeneralizedGaussian {
            center: DVec2::ZERO,
            alpha_x: 3.0,
            alpha_y: 1.0,
            beta_x: 2.0,
            beta_y: 2.0,
            angle_rad: std::f64::consts::FRAC_PI_4,
            peak: 1.0,
        };
        // along the rotated major axis the value falls as exp(−(t/3)²), along the minor as exp(−t²)
        let major = DVec2::new(1.0, 1.0).normalize();
        let minor = DVec2::new(-1.0, 1.0).normalize();
        assert!((g.value(major * 3.0) - (-1.0f64).exp()).abs() < 1e-12);
        assert!((g.value(minor * 1.0) - (-1.0f64).exp()).abs() < 1e-12);
    }

    #[test]
    fn attitude_follows_velocity() {
        let r = attitude_from_velocity(DVec3::new(1.0, 1.0, 0.0));
        assert!((r.x_axis - DVec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-15);
        assert!((r.z_axis - DVec3::Z).length() < 1e-15);
        let up = attitude_from_velocity(DVec3::Z);
        assert!((up.determinant() - 1.0).abs() < 1e-12);
    }
}
