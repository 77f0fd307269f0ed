//! Pinhole camera: intrinsics, attitude, world → pixel projection and pixel → ray.
//!
//! Conventions (DESIGN.md): world x east, y north, z up. The camera frame has x to the right of the image
//! (image `u`), y down the image (image `v`) and z along the optical axis. Pixel `(i, j)` covers
//! `[i, i+1) × [j, j+1)`, so its centre is `(i + 0.5, j + 0.5)`; the principal point is the frame centre
//! `(width/2, height/2)`. The focal length in pixels is `f / pitch`.
//!
//! Attitude is yaw (heading, degrees clockwise from north), pitch (up positive) and roll (right side down
//! positive) of the optical axis, or look-at. Vibration is a small rotation of the camera about its own axes.

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::physics::ParamError;
use crate::physics::brdf::sin_cos_deg;

/// An invalid camera parameter.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CameraError {
    /// A parameter out of range.
    #[error("camera {0}")]
    OutOfRange(#[from] ParamError),
    /// Look-at with the target at the eye.
    #[error("look-at target coincides with the camera position")]
    DegenerateLookAt,
}

/// Where a camera points, with every target resolved to a position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Aim {
    /// At a world point (a fixed point, or a tracked target's position).
    At {
        /// The point, m.
        target_m: DVec3,
        /// Roll about the optical axis, degrees.
        roll_deg: f64,
    },
    /// A fixed attitude.
    Attitude(YawPitchRoll),
    /// Along the platform's velocity (north and level when it stands still), offset in yaw and pitch, degrees.
    AlongVelocity {
        /// Added heading, degrees.
        yaw_offset_deg: f64,
        /// Added elevation, degrees.
        pitch_offset_deg: f64,
    },
}

/// Image size and the pinhole's focal length in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Focal length, m.
    pub focal_length_m: f64,
    /// Pixel pitch, m.
    pub pixel_pitch_m: f64,
}

impl Intrinsics {
    /// Intrinsics, validated.
    ///
    /// # Errors
    /// [`CameraError::OutOfRange`] for a zero or huge size (over 16384 px) or a non-positive length.
    pub fn try_new(width: u32, height: u32, focal_length_m: f64, pixel_pitch_m: f64) -> Result<Self, CameraError> {
        for (name, v) in [("width", width), ("height", height)] {
            if !(1..=16384).contains(&v) {
                return Err(ParamError { name, value: v as f64, range: "1 … 16384".into() }.into());
            }
        }
        for (name, v) in [("focal_length_m", focal_length_m), ("pixel_pitch_m", pixel_pitch_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ParamError { name, value: v, range: "(0, ∞)".into() }.into());
            }
        }
        Ok(Self { width, height, focal_length_m, pixel_pitch_m })
    }

    /// Focal length in pixels.
    pub fn focal_px(&self) -> f64 {
        self.focal_length_m / self.pixel_pitch_m
    }

    /// Principal point, px: the frame centre.
    pub fn principal_point(&self) -> DVec2 {
        DVec2::new(self.width as f64 / 2.0, self.height as f64 / 2.0)
    }
}

/// Yaw, pitch and roll of the optical axis, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct YawPitchRoll {
    /// Heading of the optical axis, degrees clockwise from north (+y) toward east (+x).
    pub yaw_deg: f64,
    /// Elevation of the optical axis, degrees, up positive.
    pub pitch_deg: f64,
    /// Rotation about the optical axis, degrees, image right side down positive.
    pub roll_deg: f64,
}

impl YawPitchRoll {
    /// Camera-to-world rotation: columns are the camera's x (right), y (down), z (forward) in world coordinates.
    pub fn camera_to_world(&self) -> DMat3 {
        let (sy, cy) = sin_cos_deg(self.yaw_deg);
        let (sp, cp) = sin_cos_deg(self.pitch_deg);
        let (sr, cr) = sin_cos_deg(self.roll_deg);
        let forward = DVec3::new(cp * sy, cp * cy, sp);
        let right0 = DVec3::new(cy, -sy, 0.0);
        let up0 = right0.cross(forward);
        let right = right0 * cr - up0 * sr;
        let up = up0 * cr + right0 * sr;
        DMat3::from_cols(right, -up, forward)
    }
}

/// Small rotation of the camera about its own axes, radians: `x` tilts the view up/down, `y` pans it
/// left/right, `z` rolls it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Jitter {
    /// About the camera's x axis (image right), rad.
    pub x_rad: f64,
    /// About the camera's y axis (image down), rad.
    pub y_rad: f64,
    /// About the optical axis, rad.
    pub z_rad: f64,
}

impl Jitter {
    /// The rotation, in camera coordinates.
    pub fn rotation(&self) -> DMat3 {
        DMat3::from_rotation_z(self.z_rad) * DMat3::from_rotation_y(self.y_rad) * DMat3::from_rotation_x(self.x_rad)
    }
}

/// Where a world point falls relative to the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    /// In front of the camera, at these pixel coordinates (possibly outside the frame), at this depth (m).
    InFront {
        /// Pixel coordinates.
        pixel: DVec2,
        /// Distance along the optical axis, m.
        depth_m: f64,
    },
    /// At or behind the camera's plane: not projected.
    Behind,
}

/// A posed pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Intrinsics.
    pub intrinsics: Intrinsics,
    /// Position of the projection centre, m.
    pub position_m: DVec3,
    /// Camera-to-world rotation (columns: right, down, forward).
    pub camera_to_world: DMat3,
}

impl Camera {
    /// A camera at `position_m` with attitude `attitude`.
    pub fn new(intrinsics: Intrinsics, position_m: DVec3, attitude: YawPitchRoll) -> Self {
        Self { intrinsics, position_m, camera_to_world: attitude.camera_to_world() }
    }

    /// A camera at `position_m` looking at `target_m`, with the image's up toward world +z, rolled by `roll_deg`.
    ///
    /// # Errors
    /// [`CameraError::DegenerateLookAt`] if the target is at the camera position.
    pub fn look_at(
        intrinsics: Intrinsics,
        position_m: DVec3,
        target_m: DVec3,
        roll_deg: f64,
    ) -> Result<Self, CameraError> {
        let d = target_m - position_m;
        let len = d.length();
        if !(len > 0.0) || !len.is_finite() {
            return Err(CameraError::DegenerateLookAt);
        }
        let f = d / len;
        let attitude = YawPitchRoll {
            yaw_deg: f.x.atan2(f.y).to_degrees(),
            pitch_deg: f.z.clamp(-1.0, 1.0).asin().to_degrees(),
            roll_deg,
        };
        Ok(Self::new(intrinsics, position_m, attitude))
    }

    /// The camera at `eye_m` moving at `velocity_m_s`, aimed as `aim` says; a look-at whose target is at the eye
    /// looks north, level.
    pub fn aimed(intrinsics: Intrinsics, eye_m: DVec3, velocity_m_s: DVec3, aim: Aim) -> Self {
        match aim {
            Aim::At { target_m, roll_deg } => Self::look_at(intrinsics, eye_m, target_m, roll_deg)
                .unwrap_or_else(|_| Self::new(intrinsics, eye_m, YawPitchRoll::default())),
            Aim::Attitude(attitude) => Self::new(intrinsics, eye_m, attitude),
            Aim::AlongVelocity { yaw_offset_deg, pitch_offset_deg } => {
                let v = velocity_m_s;
                let (yaw, pitch) = if v.length_squared() > 0.0 {
                    (v.x.atan2(v.y).to_degrees(), (v.z / v.length()).clamp(-1.0, 1.0).asin().to_degrees())
                } else {
                    (0.0, 0.0)
                };
                let attitude =
                    YawPitchRoll { yaw_deg: yaw + yaw_offset_deg, pitch_deg: pitch + pitch_offset_deg, roll_deg: 0.0 };
                Self::new(intrinsics, eye_m, attitude)
            }
        }
    }

    /// The same camera rotated by a small jitter about its own axes.
    pub fn jittered(&self, jitter: Jitter) -> Self {
        Self { camera_to_world: self.camera_to_world * jitter.rotation(), ..*self }
    }

    /// World-to-camera rotation.
    pub fn world_to_camera(&self) -> DMat3 {
        self.camera_to_world.transpose()
    }

    /// Unit optical axis, world frame.
    pub fn forward(&self) -> DVec3 {
        self.camera_to_world.z_axis
    }

    /// A world point in camera coordinates (x right, y down, z forward), m.
    pub fn to_camera(&self, point_m: DVec3) -> DVec3 {
        self.world_to_camera() * (point_m - self.position_m)
    }

    /// Projects a world point to pixel coordinates; points at or behind the camera plane are [`Projection::Behind`].
    pub fn project(&self, point_m: DVec3) -> Projection {
        let p = self.to_camera(point_m);
        if !(p.z > 0.0) {
            return Projection::Behind;
        }
        let f = self.intrinsics.focal_px();
        let c = self.intrinsics.principal_point();
        Projection::InFront { pixel: DVec2::new(c.x + f * p.x / p.z, c.y + f * p.y / p.z), depth_m: p.z }
    }

    /// Unit ray direction (world frame) through pixel coordinates `pixel` (pixel centres at `i + 0.5`).
    pub fn ray(&self, pixel: DVec2) -> DVec3 {
        (self.camera_to_world * self.ray_camera(pixel)).normalize()
    }

    /// Unnormalised ray direction in camera coordinates, z = 1.
    pub fn ray_camera(&self, pixel: DVec2) -> DVec3 {
        let f = self.intrinsics.focal_px();
        let c = self.intrinsics.principal_point();
        DVec3::new((pixel.x - c.x) / f, (pixel.y - c.y) / f, 1.0)
    }

    /// Where this camera's pixels fall in `wider`'s image, as one shift: `wider` stands at the same point and
    /// turns a little from this camera (its frame may be larger; the principal points are both frame centres).
    /// Returns the shift that takes this frame's centre to where its ray falls in `wider`'s image, px, and the
    /// largest distance between where a pixel's ray falls there and where the shift puts the pixel, over the
    /// frame's corners, edge midpoints and centre, px (for a small turn that distance is close to a quadratic in
    /// the pixel's position, largest at the frame's edges; a roll makes it grow linearly toward them). `None`
    /// if the cameras stand apart or a ray of this frame does not meet `wider`'s image plane in front.
    pub fn shift_within(&self, wider: &Camera) -> Option<(DVec2, f64)> {
        if self.position_m != wider.position_m {
            return None;
        }
        let (w, h) = (f64::from(self.intrinsics.width), f64::from(self.intrinsics.height));
        let turn = wider.world_to_camera() * self.camera_to_world;
        let (f, c) = (wider.intrinsics.focal_px(), wider.intrinsics.principal_point());
        let land = |p: DVec2| {
            let d = turn * self.ray_camera(p);
            (d.z > 0.0 && d.is_finite()).then(|| DVec2::new(c.x + f * d.x / d.z, c.y + f * d.y / d.z))
        };
        let centre = DVec2::new(w / 2.0, h / 2.0);
        let shift = land(centre)? - centre;
        let mut error: f64 = 0.0;
        for x in [0.5, w / 2.0, w - 0.5] {
            for y in [0.5, h / 2.0, h - 0.5] {
                let p = DVec2::new(x, y);
                error = error.max(land(p)?.distance(p + shift));
            }
        }
        Some((shift, error))
    }

    /// The intrinsic matrix K (pixels from camera coordinates).
    pub fn k_matrix(&self) -> DMat3 {
        let f = self.intrinsics.focal_px();
        let c = self.intrinsics.principal_point();
        DMat3::from_cols(DVec3::new(f, 0.0, 0.0), DVec3::new(0.0, f, 0.0), DVec3::new(c.x, c.y, 1.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn intr() -> Intrinsics {
        Intrinsics::try_new(256, 256, 0.1, 17e-6).unwrap()
    }

    #[test]
    fn yaw_zero_looks_north_with_east_to_the_right() {
        let m = YawPitchRoll::default().camera_to_world();
        assert!((m.z_axis - DVec3::Y).length() < 1e-15);
        assert!((m.x_axis - DVec3::X).length() < 1e-15);
        assert!((m.y_axis + DVec3::Z).length() < 1e-15);
    }

    #[test]
    fn projects_known_points() {
        let cam = Camera::new(intr(), DVec3::new(0.0, 0.0, 8000.0), YawPitchRoll::default());
        // on the axis → principal point
        let Projection::InFront { pixel, depth_m } = cam.project(DVec3::new(0.0, 10_000.0, 8000.0)) else { panic!() };
        assert!((pixel - DVec2::new(128.0, 128.0)).length() < 1e-12);
        assert!((depth_m - 10_000.0).abs() < 1e-9);
        // 17 m east at 10 km = 17e-6·... : u offset = f/pitch · 17/10000 = 5882.35 · 0.0017 = 10 px
        let Projection::InFront { pixel, .. } = cam.project(DVec3::new(17.0, 10_000.0, 8000.0)) else { panic!() };
        assert!((pixel.x - 138.0).abs() < 1e-9 && (pixel.y - 128.0).abs() < 1e-9);
        // above the axis → smaller v
        let Projection::InFront { pixel, .. } = cam.project(DVec3::new(0.0, 10_000.0, 8017.0)) else { panic!() };
        assert!((pixel.y - 118.0).abs() < 1e-9);
        assert_eq!(cam.project(DVec3::new(0.0, -5.0, 8000.0)), Projection::Behind);
        assert_eq!(cam.project(DVec3::new(100.0, 0.0, 8000.0)), Projection::Behind);
    }

    #[test]
    fn ray_projection_round_trip() {
        let attitudes = [
            YawPitchRoll { yaw_deg: 37.0, pitch_deg: 12.0, roll_deg: -23.0 },
            YawPitchRoll { yaw_deg: -170.0, pitch_deg: -60.0, roll_deg: 90.0 },
        ];
        for att in attitudes {
            let cam = Camera::new(intr(), DVec3::new(100.0, -50.0, 3000.0), att).jittered(Jitter {
                x_rad: 0.003,
                y_rad: -0.002,
                z_rad: 0.01,
            });
            for (u, v) in [(0.0, 0.0), (0.5, 0.5), (255.99, 3.25), (128.0, 128.0), (17.3, 240.8)] {
                let px = DVec2::new(u, v);
                let p = cam.position_m + cam.ray(px) * 12_345.0;
                let Projection::InFront { pixel, .. } = cam.project(p) else { panic!() };
                assert!((pixel - px).length() <= 1e-9, "{px} → {pixel}");
            }
        }
    }

    #[test]
    fn look_at_centres_the_target() {
        let target = DVec3::new(3000.0, 20_000.0, 6000.0);
        let cam = Camera::look_at(intr(), DVec3::new(0.0, 0.0, 8000.0), target, 15.0).unwrap();
        let Projection::InFront { pixel, .. } = cam.project(target) else { panic!() };
        assert!((pixel - DVec2::splat(128.0)).length() < 1e-9);
        assert!(Camera::look_at(intr(), target, target, 0.0).is_err());
    }

    #[test]
    fn a_small_turn_is_a_shift_up_to_its_quadratic_term() {
        let inner = Intrinsics::try_new(256, 200, 0.05, 17e-6).unwrap();
        let outer = Intrinsics::try_new(296, 240, 0.05, 17e-6).unwrap();
        let eye = DVec3::new(10.0, -20.0, 3000.0);
        let attitude = YawPitchRoll { yaw_deg: 30.0, pitch_deg: 10.0, roll_deg: 5.0 };
        let wider = Camera::new(outer, eye, attitude);
        let f = inner.focal_px();
        // unturned: the margin, exactly
        let (shift, error) = Camera::new(inner, eye, attitude).shift_within(&wider).unwrap();
        assert!((shift - DVec2::new(20.0, 20.0)).length() < 1e-9 && error < 1e-9, "{shift} {error}");
        for (pan, tilt) in [(3e-3, 0.0), (0.0, -4e-3), (2e-3, 2e-3)] {
            let view = Camera::new(inner, eye, attitude).jittered(Jitter { x_rad: tilt, y_rad: pan, z_rad: 0.0 });
            let (shift, error) = view.shift_within(&wider).unwrap();
            // a pan to the right moves the view right in the wider image, a tilt about x the other way down
            assert!((shift.x - 20.0 - f * pan.tan()).abs() < 0.02 && (shift.y - 20.0 + f * tilt.tan()).abs() < 0.02);
            // every pixel of the view, not just the nine points, lies within the error of the shift
            let mut worst: f64 = 0.0;
            for y in (0..200).step_by(7).chain([199]) {
                for x in (0..256).step_by(5).chain([255]) {
                    let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let Projection::InFront { pixel, .. } = wider.project(eye + 1e4 * view.ray(p)) else { panic!() };
                    worst = worst.max(pixel.distance(p + shift));
                }
            }
            assert!(worst <= error + 1e-6 && error < 0.1 && error > 0.2 * worst, "{pan} {tilt}: {worst} {error}");
            // the quadratic term: θ·x²/f at the edge, a few hundredths of a pixel here
            let edge = pan.abs().max(tilt.abs()) * 128f64.powi(2) / f;
            assert!(error > 0.5 * edge && error < 4.0 * edge, "{error} against {edge}");
        }
        // a roll moves the corners: a milliradian is 0.16 px at the corner
        let rolled = Camera::new(inner, eye, attitude).jittered(Jitter { x_rad: 0.0, y_rad: 0.0, z_rad: 1e-3 });
        let (_, error) = rolled.shift_within(&wider).unwrap();
        assert!((error - 1e-3 * DVec2::new(127.5, 99.5).length()).abs() < 2e-3, "{error}");
        // elsewhere: no shift
        let moved = Camera::new(inner, eye + DVec3::X, attitude);
        assert!(moved.shift_within(&wider).is_none());
    }

    #[test]
    fn rejects_bad_intrinsics() {
        assert!(Intrinsics::try_new(0, 10, 0.1, 1e-5).is_err());
        assert!(Intrinsics::try_new(10, 10, -0.1, 1e-5).is_err());
        assert!(Intrinsics::try_new(10, 10, 0.1, f64::NAN).is_err());
    }
}
