//! Pointing and vibration of the camera.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{
    Aim, Aircraft, CameraPose, FlightPath, Kinematics, Observer, Shake, SimClock, SimSettings, VibrationSystems,
};
use crate::imaging::camera::{Camera, Intrinsics, Jitter, YawPitchRoll};
use crate::physics::noise::{stage, standard_normal, stream_rng};
use crate::scenario::Pointing;

/// Points and shakes the camera.
pub struct CameraPlugin;

impl Plugin for CameraPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, shake_camera.in_set(VibrationSystems));
    }
}

/// Computes the steady camera from the pointing mode, then applies this frame's jitter.
pub fn shake_camera(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut observer: Query<(&Kinematics, &Aim, &Shake, &mut CameraPose), With<Observer>>,
    targets: Query<(&Aircraft, &Kinematics, &FlightPath), Without<Observer>>,
) {
    let Ok((kin, aim, shake, mut pose)) = observer.single_mut() else { return };
    let intrinsics: Intrinsics = pose.steady.intrinsics;
    let eye = kin.position_m;
    let look_at = |target: glam::DVec3, roll: f64| {
        Camera::look_at(intrinsics, eye, target, roll)
            .unwrap_or_else(|_| Camera::new(intrinsics, eye, YawPitchRoll::default()))
    };
    let steady = match &aim.0 {
        Pointing::LookAt { target_m, roll_deg } => look_at(*target_m, *roll_deg),
        Pointing::Track { target, roll_deg, lag_s, noise_urad } => {
            // the loop aims where the target was `lag_s` ago, plus white pointing noise per frame
            let t = clock.t_s();
            let p = targets.iter().find(|(a, _, _)| &a.name == target).map_or(eye + glam::DVec3::Y, |(_, k, path)| {
                if *lag_s > 0.0 { path.0.state(t - lag_s).0 } else { k.position_m }
            });
            let cam = look_at(p, *roll_deg);
            if *noise_urad > 0.0 {
                let mut rng = stream_rng(settings.seed, stage::TRACKING, clock.frame, 0);
                let s = noise_urad * 1e-6;
                let (yaw, pitch) = (standard_normal(&mut rng) * s, standard_normal(&mut rng) * s);
                cam.jittered(Jitter { x_rad: pitch, y_rad: yaw, z_rad: 0.0 })
            } else {
                cam
            }
        }
        Pointing::YawPitchRoll(a) => Camera::new(intrinsics, eye, *a),
        Pointing::AlongVelocity { yaw_offset_deg, pitch_offset_deg } => {
            let v = kin.velocity_m_s;
            let (yaw, pitch) = if v.length_squared() > 0.0 {
                (v.x.atan2(v.y).to_degrees(), (v.z / v.length()).asin().to_degrees())
            } else {
                (0.0, 0.0)
            };
            let att =
                YawPitchRoll { yaw_deg: yaw + yaw_offset_deg, pitch_deg: pitch + pitch_offset_deg, roll_deg: 0.0 };
            Camera::new(intrinsics, eye, att)
        }
    };
    let jitter = shake.0.jitter(clock.t_s());
    *pose = CameraPose { steady, current: steady.jittered(jitter), jitter };
}
