//! Sensor noise and quantization.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{NoiseSystems, Sensor, SensorFrame, SimClock, SimSettings};
use crate::physics::noise::quantize_row;

/// Adds noise and quantizes.
pub struct NoisePlugin;

impl Plugin for NoisePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, add_noise_and_quantize.in_set(NoiseSystems));
    }
}

/// Poisson + Gaussian noise from the `(seed, SENSOR_NOISE, frame)` streams, then rounding to the bit depth.
pub fn add_noise_and_quantize(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut sensor: Query<(&Sensor, &mut SensorFrame)>,
) {
    let Ok((sensor, mut sf)) = sensor.single_mut() else { return };
    let sf = &mut *sf;
    let width = sf.frame.width();
    let top = sensor.gray.max_level() as f32;
    let (seed, frame) = (settings.seed, clock.frame);
    if settings.keep_float {
        if settings.noise {
            sensor.noise.apply(sf.frame.pixels_mut(), width, sensor.gray.g_min, seed, frame);
        }
        match &mut sf.float_frame {
            Some(f) => f.pixels_mut().copy_from_slice(sf.frame.pixels()),
            None => sf.float_frame = Some(sf.frame.clone()),
        }
        quantize_row(sf.frame.pixels_mut(), top);
    } else if settings.noise {
        sensor.noise.apply_and_quantize(sf.frame.pixels_mut(), width, sensor.gray.g_min, seed, frame, Some(top));
    } else {
        quantize_row(sf.frame.pixels_mut(), top);
    }
}
