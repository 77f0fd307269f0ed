//! Pointing and vibration of the camera.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Aim, CameraPose, FlightPath, Kinematics, Observer, Shake, SimClock, SimSettings, VibrationSystems};
use crate::imaging::camera::{Aim as AimAt, Camera, Intrinsics, Jitter, YawPitchRoll};
use crate::physics::noise::{stage, standard_normal, stream_rng};
use crate::scenario::Pointing;

/// Points and shakes the camera.
pub struct VibrationPlugin;

impl Plugin for VibrationPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, shake_camera.in_set(VibrationSystems));
    }
}

/// Computes the steady camera from the pointing mode, then applies this frame's jitter.
pub fn shake_camera(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut observer: Query<(&Kinematics, &Aim, &Shake, &mut CameraPose), With<Observer>>,
    targets: Query<(&Kinematics, &FlightPath), Without<Observer>>,
) {
    let Ok((kin, aim, shake, mut pose)) = observer.single_mut() else { return };
    let intrinsics: Intrinsics = pose.steady.intrinsics;
    let t = clock.t_s();
    // the loop aims where the tracked target was `lag_s` ago
    let tracked = |_: &str, lag_s: f64| {
        let (k, path) = targets.get(aim.tracked?).ok()?;
        Some(if lag_s > 0.0 { path.0.state(t - lag_s).0 } else { k.position_m })
    };
    let steady = Camera::aimed(intrinsics, kin.position_m, kin.velocity_m_s, resolve_aim(&aim.pointing, tracked));
    let steady = match &aim.pointing {
        Pointing::Track { noise_urad, .. } if *noise_urad > 0.0 => {
            // white pointing noise per frame
            let mut rng = stream_rng(settings.seed, stage::TRACKING, clock.frame, 0);
            let s = noise_urad * 1e-6;
            let (yaw, pitch) = (standard_normal(&mut rng) * s, standard_normal(&mut rng) * s);
            steady.jittered(Jitter { x_rad: pitch, y_rad: yaw, z_rad: 0.0 })
        }
        _ => steady,
    };
    let jitter = shake.0.jitter(clock.t_s());
    *pose = CameraPose { steady, current: steady.jittered(jitter), jitter };
}

/// The core's aim for a pointing mode: `tracked(name, lag_s)` gives a tracked target's position (the loop's
/// aim point); without one the camera looks north, level.
pub fn resolve_aim(pointing: &Pointing, tracked: impl Fn(&str, f64) -> Option<glam::DVec3>) -> AimAt {
    match pointing {
        Pointing::LookAt { target_m, roll_deg } => AimAt::At { target_m: *target_m, roll_deg: *roll_deg },
        Pointing::Track { target, roll_deg, lag_s, .. } => match tracked(target, *lag_s) {
            Some(p) => AimAt::At { target_m: p, roll_deg: *roll_deg },
            None => AimAt::Attitude(YawPitchRoll { roll_deg: *roll_deg, ..YawPitchRoll::default() }),
        },
        Pointing::YawPitchRoll(a) => AimAt::Attitude(*a),
        Pointing::AlongVelocity { yaw_offset_deg, pitch_offset_deg } => {
            AimAt::AlongVelocity { yaw_offset_deg: *yaw_offset_deg, pitch_offset_deg: *pitch_offset_deg }
        }
    }
}
