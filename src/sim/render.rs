//! Render to texture: the sky plane ray cast into the sensor's frame through the vibrated camera, the dome
//! along every ray that misses it, and the optics blur.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{CameraPose, Observer, RenderToTextureSystems, Sensor, SensorFrame, Sky};
use crate::imaging::background::{BackgroundBlur, SkyView};
use crate::imaging::camera::Camera;

/// Renders the background.
pub struct RenderToTexturePlugin;

impl Plugin for RenderToTexturePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, render_sky.in_set(RenderToTextureSystems));
    }
}

/// Renders the blurred sky background for the vibrated camera; when the camera has not moved since the last
/// render, reuses it.
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
        let in_frame = render_background(sensor, sky, &pose.current, sf);
        sf.background_camera = Some(pose.current);
        if in_frame {
            return;
        }
    }
    if sf.coarse_only {
        // the readout interpolates the frame from the coarse grid, which holds this view still
        return;
    }
    // the frame starts as the background: copied in parallel (one thread's memcpy of a 640 × 512 frame took a
    // tenth of a draft frame)
    use rayon::prelude::*;
    let chunk = 16_384;
    sf.frame
        .pixels_mut()
        .par_chunks_mut(chunk)
        .zip(sf.background.pixels().par_chunks(chunk))
        .for_each(|(dst, src)| dst.copy_from_slice(src));
}

/// `camera` with pixels `step` times larger each way: what sees the background's coarse grid.
pub(super) fn coarse_camera(camera: &Camera, step: usize) -> Camera {
    let mut camera = *camera;
    camera.intrinsics.width /= step as u32;
    camera.intrinsics.height /= step as u32;
    camera.intrinsics.pixel_pitch_m *= step as f64;
    camera
}

/// Renders the background `camera` sees into `sf.background` (on a sensor with a coarse grid: into the coarse
/// frame, upsampled into both `sf.background` and `sf.frame` unless the readout does it, and returns true: the
/// frame holds it already, or will).
pub(super) fn render_background(sensor: &Sensor, sky: &Sky, camera: &Camera, sf: &mut SensorFrame) -> bool {
    let step = sensor.background_step;
    // on the coarse grid: the optics seen from pixels `step` times larger
    let blur = match (sensor.background_psf(), sensor.resolved.psf, sensor.blur_frame) {
        (Some(psf), Some(cfg), true) => Some(BackgroundBlur {
            psf,
            method: cfg.method,
            // tiles where the blur changes no pixel by more than the set DN keep their values
            skip_below: (cfg.skip_below_dn / sensor.dn_per_radiance) as f32,
            sky_blur: sensor.sky_blur,
            prefilter: cfg.prefilter(sensor.dn_per_radiance),
            dome: sensor.blur_dome,
        }),
        _ => None,
    };
    // a plane still to be made is made now if this view may see it
    let view = |camera: &Camera| SkyView {
        plane: sky.plane_for(camera),
        dome: &sky.dome,
        sampling: sky.sampling,
        miss: sky.miss,
    };
    match sf.coarse.as_mut() {
        Some(coarse) => {
            let camera = coarse_camera(camera, step);
            let view = view(&camera);
            sf.background_stats = sf.renderer.render(&view, &camera, blur.as_ref(), coarse);
            // the frame gets each row as it is made, or (nothing reading it before) from the readout
            if !sf.coarse_only {
                sf.background.upsample_bilinear(coarse, step, Some(&mut sf.frame));
            }
            true
        }
        None => {
            let view = view(camera);
            sf.background_stats = sf.renderer.render(&view, camera, blur.as_ref(), &mut sf.background);
            false
        }
    }
}
