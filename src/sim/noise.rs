//! The detector stage: radiance to electrons or volts, temporal noise, non-idealities, ADC.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::components::coarse_upsampler;
use super::{NoiseSystems, Sensor, SensorFrame, SimClock, SimSettings};
use crate::physics::noise::{Readout, ReadoutMaps, RowFill};

/// Reads the detector out.
pub struct NoisePlugin;

impl Plugin for NoisePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, read_out.in_set(NoiseSystems));
    }
}

/// Replaces the frame's radiance by DN: the pixel's gain map (vignetting, FPN gain, dead pixels), shot and read
/// noise from the `(seed, SENSOR_NOISE, frame)` streams, the well, the ADC with the offset map, this frame's
/// drift and column offsets, and rounding to the bit depth.
pub fn read_out(clock: Res<SimClock>, settings: Res<SimSettings>, mut sensor: Query<(&Sensor, &mut SensorFrame)>) {
    let Ok((sensor, mut sf)) = sensor.single_mut() else { return };
    let sf = &mut *sf;
    let width = sf.frame.width();
    let (seed, frame) = (settings.seed, clock.frame);
    let mut readout: Readout = sensor.readout;
    let mut maps = ReadoutMaps::default();
    if let Some(ni) = &sensor.nonideal {
        readout.offset_dn += ni.drift_dn(clock.t_s()) as f32;
        maps.gain = ni.gain();
        maps.offset_dn = ni.offset_dn();
        if ni.column_offsets(frame, &mut sf.columns) {
            maps.column_dn = Some(&sf.columns);
        }
    }
    let top = sensor.max_level;
    // a frame made on a coarse grid with nothing drawn on it: interpolated block by block as it is read out
    let size = (width, sf.frame.height());
    let upsampler = match sf.coarse_only {
        true => coarse_upsampler(
            sf.steady_render.as_ref(),
            sf.view_offset,
            sf.coarse.as_ref(),
            size,
            sensor.background_step,
        ),
        false => None,
    };
    let fill = upsampler.as_ref().map(|u| move |first: usize, block: &mut [f32]| u.rows(first, block));
    let fill = fill.as_ref().map(|f| f as &RowFill<'_>);
    let frame_pixels = sf.frame.pixels_mut();
    if settings.keep_float {
        readout.apply(frame_pixels, width, maps, settings.noise, seed, frame, None, fill);
        match &mut sf.float_frame {
            Some(f) => f.pixels_mut().copy_from_slice(sf.frame.pixels()),
            None => sf.float_frame = Some(sf.frame.clone()),
        }
        crate::physics::noise::quantize_row(sf.frame.pixels_mut(), top);
    } else {
        readout.apply(frame_pixels, width, maps, settings.noise, seed, frame, Some(top), fill);
    }
}
