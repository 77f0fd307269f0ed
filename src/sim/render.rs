//! Render to texture: the sky plane ray cast into the sensor's frame through the vibrated camera, the dome
//! along every ray that misses it, and the optics blur.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{CameraPose, Observer, RenderToTextureSystems, Sensor, SensorFrame, Sky};
use crate::imaging::sky_field::render_dome;
use crate::imaging::sky_plane::Sampling;

/// Renders the background.
pub struct RenderPlugin;

impl Plugin for RenderPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, render_sky.in_set(RenderToTextureSystems));
    }
}

/// Ray casts the sky into the frame and blurs it; when the camera has not moved since the last render, reuses
/// it.
pub fn render_sky(
    observer: Query<&CameraPose, With<Observer>>,
    sky: Query<&Sky>,
    mut sensor: Query<(&Sensor, &mut SensorFrame)>,
) {
    let (Ok(pose), Ok((sensor, mut sf)), Ok(sky)) = (observer.single(), sensor.single_mut(), sky.single()) else {
        return;
    };
    let sf = &mut *sf;
    if sf.background_camera != Some(pose.current) {
        match &sky.plane {
            Some(plane) => {
                plane.render(&pose.current, sky.sampling, sky.miss, &mut sf.background);
                render_dome(&pose.current, &sky.dome, &mut sf.background, true);
            }
            None => render_dome(&pose.current, &sky.dome, &mut sf.background, false),
        }
        if let (Some(psf), Some(cfg), true) = (&sensor.psf, sensor.resolved.psf, sensor.blur_frame) {
            // a point-sampled sky needs the pixel aperture in the kernel; an area-averaged one has it already
            let area_sampled = sky.plane.is_some() && matches!(sky.sampling, Sampling::Supersample { n } if n > 1);
            let kernel = if area_sampled { psf.area_kernel() } else { psf.point_kernel() };
            // tiles where the blur changes no pixel by more than the set DN keep their values
            let skip = (cfg.skip_below_dn / sensor.dn_per_radiance) as f32;
            sf.blur = sf.convolver.apply_where_needed(kernel, &mut sf.background, cfg.method, skip);
        }
        sf.background_camera = Some(pose.current);
    }
    sf.frame.pixels_mut().copy_from_slice(sf.background.pixels());
}
