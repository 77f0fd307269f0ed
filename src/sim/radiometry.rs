//! Radiometry: skin temperature, radiance, reflection, transmittance and path radiance per target, in the
//! detector's measure.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Body, CameraPose, Kinematics, Observer, RadiometrySystems, SceneParams, Sensor, Signature, Skin};
use crate::physics::signal::{ApparentContext, TargetState, apparent_radiance};
use crate::physics::skin::mach_number;

/// Computes each target's signature.
pub struct RadiometryPlugin;

impl Plugin for RadiometryPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, update_signatures.in_set(RadiometrySystems));
    }
}

/// Runs the radiometric chain for every target whose inputs changed since its last computation.
pub fn update_signatures(
    scene: Res<SceneParams>,
    sensor: Query<&Sensor>,
    observer: Query<&CameraPose, With<Observer>>,
    mut targets: Query<(&Kinematics, &Body, &Skin, &mut Signature), Without<Observer>>,
) {
    let (Ok(sensor), Ok(pose)) = (sensor.single(), observer.single()) else { return };
    let eye = pose.steady.position_m;
    let ctx = ApparentContext {
        band: sensor.resolved.model.band,
        measure: sensor.measure(),
        t0_k: scene.t0_k,
        stagnation: scene.stagnation,
        sun: scene.sun,
        atmosphere: &scene.atmosphere,
        reflection: Default::default(),
        quadrature: &scene.quadrature,
    };
    for (kin, body, skin, mut sig) in &mut targets {
        let p = kin.position_m;
        let dir = kin.velocity_m_s.normalize_or_zero();
        let key = [p.x, p.y, p.z, dir.x, dir.y, dir.z, kin.velocity_m_s.length(), eye.x, eye.y, eye.z];
        if sig.key == Some(key) {
            continue;
        }
        let mach = match skin.mach {
            Some(m) => m,
            None => mach_number(kin.velocity_m_s.length(), scene.air_temp_k(p.z)),
        };
        let state = TargetState {
            position_m: p,
            mach,
            emissivity: skin.emissivity,
            heating_k: skin.heating_k,
            brdf: skin.brdf,
            semi_axes_m: body.semi_axes_m,
            attitude: body.body_to_world(kin.velocity_m_s),
        };
        let ctx = ApparentContext { reflection: skin.reflection, ..ctx };
        match apparent_radiance(&state, eye, &ctx) {
            Ok(signal) => {
                sig.signal = Some(signal);
                sig.error = None;
            }
            Err(e) => {
                sig.signal = None;
                sig.error = Some(e.to_string());
            }
        }
        sig.mach = mach;
        sig.key = Some(key);
    }
}
