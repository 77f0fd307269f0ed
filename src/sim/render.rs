//! Render to texture: the sky plane ray cast into the sensor's frame through the vibrated camera.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{CameraPose, Observer, RenderToTextureSystems, Sensor, SensorFrame, Sky};

/// Renders the background.
pub struct RenderPlugin;

impl Plugin for RenderPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, render_sky.in_set(RenderToTextureSystems));
    }
}

/// Ray casts the sky into the frame; when the camera has not moved since the last render, reuses it.
pub fn render_sky(
    observer: Query<&CameraPose, With<Observer>>,
    sky: Query<&Sky>,
    mut sensor: Query<(&Sensor, &mut SensorFrame)>,
) {
    let (Ok(pose), Ok((sensor, mut sf))) = (observer.single(), sensor.single_mut()) else { return };
    let sf = &mut *sf;
    if sf.background_camera != Some(pose.current) {
        match sky.single() {
            Ok(sky) => {
                sky.plane.render_mapped(
                    &pose.current,
                    sky.sampling,
                    sky.miss,
                    sky.gain,
                    sky.offset,
                    &mut sf.background,
                );
            }
            Err(_) => sf.background.fill(sensor.gray.g_min as f32),
        }
        sf.background_camera = Some(pose.current);
    }
    sf.frame.pixels_mut().copy_from_slice(sf.background.pixels());
}
