//! Render to texture: the sky plane ray cast into the sensor's frame through the vibrated camera, the dome
//! along every ray that misses it, and the optics blur; beside them, the targets' radiometry and shapes.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::components::SteadyRender;
use super::timing::StageTimings;
use super::{
    CameraPose, Observer, RenderToTextureSystems, Sensor, SensorFrame, SignatureInputs, SimSettings, Sky, TargetShapes,
};
use crate::imaging::background::{BackgroundBlur, SkyView};
use crate::imaging::camera::{Camera, Intrinsics, Jitter};
use crate::imaging::frame::{Frame, Upsampler};

/// Renders the background, and beside it computes the targets' signatures and draws their shapes.
pub struct RenderToTexturePlugin;

impl Plugin for RenderToTexturePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, render_sky.in_set(RenderToTextureSystems));
    }
}

/// Renders the blurred sky background for the vibrated camera; when the camera has not moved since the last
/// render, reuses it; on a coarse grid, reads a staring camera's shaken view from the render of its steady view
/// where `[quality] view_shift_tolerance_px` allows.
///
/// Beside the render, in a `rayon::join`, the targets' radiometry ([`SignatureInputs::update`]) and then their
/// shapes ([`TargetShapes::draw`]): neither reads what the render writes, nor the render what they write, and
/// the render's parallel rows fill the threads around their serial work (a frame of one target at 256 × 256
/// has tens of microseconds of it). Each signature and shape is computed exactly as alone, so frames are the
/// same bits as with the stages one after the other. With [`StageTimings`] present, the radiometry's own time
/// is added to its stage, and the shapes' to the targets stage.
pub fn render_sky(
    settings: Res<SimSettings>,
    observer: Query<&CameraPose, With<Observer>>,
    sky: Query<&Sky>,
    mut sensor: Query<(&Sensor, &mut SensorFrame)>,
    mut signatures: SignatureInputs,
    mut shapes: TargetShapes,
    timings: Option<ResMut<StageTimings>>,
) {
    let timed = timings.is_some();
    let ((), seconds) = rayon::join(
        || render_view(&settings, &observer, &sky, &mut sensor),
        || {
            let start = timed.then(std::time::Instant::now);
            signatures.update();
            let between = timed.then(std::time::Instant::now);
            shapes.draw();
            start.zip(between).map(|(s, b)| ((b - s).as_secs_f64(), b.elapsed().as_secs_f64()))
        },
    );
    if let (Some(mut t), Some((radiometry, shapes))) = (timings, seconds) {
        t.add_radiometry(radiometry);
        t.add_target_shapes(shapes);
    }
}

fn render_view(
    settings: &SimSettings,
    observer: &Query<&CameraPose, With<Observer>>,
    sky: &Query<&Sky>,
    sensor: &mut Query<(&Sensor, &mut SensorFrame)>,
) {
    let (Ok(pose), Ok((sensor, mut sf)), Ok(sky)) = (observer.single(), sensor.single_mut(), sky.single()) else {
        return;
    };
    let sf = &mut *sf;
    sf.handed_over = false;
    let moved = sf.last_camera != Some(pose.current);
    let moved_before = std::mem::replace(&mut sf.moving, moved);
    sf.last_camera = Some(pose.current);
    if sf.background_camera != Some(pose.current) {
        let tolerance_px = settings.quality.view_shift_tolerance_px;
        let in_frame = if read_shifted(sensor, sky, pose, tolerance_px, sf) {
            true
        } else {
            sf.view_offset = None;
            render_background(sensor, sky, &pose.current, sf)
        };
        sf.background_camera = Some(pose.current);
        if in_frame {
            return;
        }
        if moved && moved_before && !settings.whole_background {
            // a camera that moved in the last two frames will most likely move again before this render could
            // be reused: the render becomes the frame, and the targets stage keeps what the labels read of it
            // (`SensorFrame::background`)
            std::mem::swap(&mut sf.frame, &mut sf.background);
            sf.background_camera = None;
            sf.handed_over = true;
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

/// The margin, coarse pixels, that a steady view is rendered with so that every view a shake of `peak` turns it
/// to lies inside, where a shaken view may be read from it (a grid of `step` > 1 pixels, `tolerance_px` > 0):
/// the shift of the frame's centre under the largest pan or tilt, the tolerance and a pixel for the
/// interpolation, and a coarse pixel more. 0 where views are rendered each: without those, without a pan or tilt,
/// where the peak roll alone would move the frame's corners by more than the tolerance (a roll is not a shift),
/// or where the render would have more than 2.25 times a view's pixels.
pub(super) fn steady_margin(peak: Jitter, intrinsics: &Intrinsics, step: usize, tolerance_px: f64) -> usize {
    let turn = peak.x_rad.abs().max(peak.y_rad.abs());
    let (w, h) = (f64::from(intrinsics.width), f64::from(intrinsics.height));
    let corner_px = 0.5 * w.hypot(h);
    if step < 2 || !(tolerance_px > 0.0) || !(turn > 0.0 && turn < 0.5) || peak.z_rad.abs() * corner_px > tolerance_px {
        return 0;
    }
    let shift_px = intrinsics.focal_px() * turn.tan() + tolerance_px + 1.0;
    let margin = (shift_px / step as f64).ceil() as usize + 1;
    let m = (2 * margin * step) as f64;
    if (w + m) * (h + m) > 2.25 * w * h { 0 } else { margin }
}

/// `camera` with pixels `step` times larger each way: what sees the background's coarse grid.
pub(super) fn coarse_camera(camera: &Camera, step: usize) -> Camera {
    let mut camera = *camera;
    camera.intrinsics.width /= step as u32;
    camera.intrinsics.height /= step as u32;
    camera.intrinsics.pixel_pitch_m *= step as f64;
    camera
}

/// Reads this frame's view from the render of the steady view, shifted (upsampled into both `sf.background`
/// and `sf.frame` unless the readout does it), where the sensor has a coarse grid, the shake a margin (a
/// staring camera), and the shift puts the frame's corners, edge midpoints and centre within `tolerance_px` of
/// where their rays fall in that render ([`Camera::shift_within`]); renders the steady view first where it has not been (a frame's values depend on
/// its own pose alone, not on the frames before it: a render does not depend on when it is made). Returns false
/// where the view is to be rendered instead.
fn read_shifted(sensor: &Sensor, sky: &Sky, pose: &CameraPose, tolerance_px: f64, sf: &mut SensorFrame) -> bool {
    let (step, margin) = (sensor.background_step, sf.steady_margin);
    if step < 2 || margin == 0 || !(tolerance_px > 0.0) {
        return false;
    }
    if !sf.steady_render.as_ref().is_some_and(|r| r.steady == pose.steady) {
        render_steady(sensor, sky, &pose.steady, sf);
    }
    let Some(r) = &sf.steady_render else { return false };
    let Some((shift, error_px)) = pose.current.shift_within(&r.wider) else { return false };
    if !(error_px <= tolerance_px) {
        return false;
    }
    let offset = [shift.x / step as f64, shift.y / step as f64];
    let size = (sf.background.width(), sf.background.height());
    let Some(up) = Upsampler::shifted(&r.coarse, step, size, offset) else { return false };
    if !sf.coarse_only {
        sf.background.upsample_with(&up, Some(&mut sf.frame));
    }
    // what the render the frame is read from did
    sf.background_stats = r.stats;
    sf.view_offset = Some(offset);
    true
}

/// Renders `steady` on the coarse grid with `sf.steady_margin` coarse pixels more on every side, into
/// `sf.steady_render`.
pub(super) fn render_steady(sensor: &Sensor, sky: &Sky, steady: &Camera, sf: &mut SensorFrame) {
    let (step, margin) = (sensor.background_step, sf.steady_margin);
    // the principal point stays the centre
    let mut wider = *steady;
    let m = (2 * margin * step) as u32;
    wider.intrinsics.width += m;
    wider.intrinsics.height += m;
    let camera = coarse_camera(&wider, step);
    let (cw, ch) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
    let mut coarse = match sf.steady_render.take() {
        Some(r) if (r.coarse.width(), r.coarse.height()) == (cw, ch) => r.coarse,
        _ => Frame::new(cw, ch),
    };
    let stats = sf.renderer.render(&sky_view(sky, &camera), &camera, background_blur(sensor).as_ref(), &mut coarse);
    sf.steady_render = Some(SteadyRender { steady: *steady, wider, coarse, stats });
}

/// The sky as `camera` sees it: a plane still to be made is made now if this view may see it.
fn sky_view<'a>(sky: &'a Sky, camera: &Camera) -> SkyView<'a> {
    SkyView { plane: sky.plane_for(camera), dome: &sky.dome, sampling: sky.sampling, miss: sky.miss }
}

/// How the background is blurred: on the coarse grid, the optics seen from pixels `background_step` times
/// larger.
fn background_blur(sensor: &Sensor) -> Option<BackgroundBlur<'_>> {
    match (sensor.background_psf(), sensor.resolved.psf, sensor.blur_frame) {
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
    }
}

/// Renders the background `camera` sees into `sf.background` (on a sensor with a coarse grid: into the coarse
/// frame, upsampled into both `sf.background` and `sf.frame` unless the readout does it, and returns true: the
/// frame holds it already, or will).
pub(super) fn render_background(sensor: &Sensor, sky: &Sky, camera: &Camera, sf: &mut SensorFrame) -> bool {
    let step = sensor.background_step;
    let blur = background_blur(sensor);
    match sf.coarse.as_mut() {
        Some(coarse) => {
            let camera = coarse_camera(camera, step);
            let view = sky_view(sky, &camera);
            sf.background_stats = sf.renderer.render(&view, &camera, blur.as_ref(), coarse);
            // the frame gets each row as it is made, or (nothing reading it before) from the readout
            if !sf.coarse_only {
                sf.background.upsample_bilinear(coarse, step, Some(&mut sf.frame));
            }
            true
        }
        None => {
            let view = sky_view(sky, camera);
            sf.background_stats = sf.renderer.render(&view, camera, blur.as_ref(), &mut sf.background);
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_margin_holds_the_shake_or_there_is_none() {
        // the paper's 256 × 256 sensor, f = 2941 px
        let i = Intrinsics::try_new(256, 256, 0.05, 17e-6).unwrap();
        let shake = |turn: f64, roll: f64| Jitter { x_rad: turn, y_rad: turn / 2.0, z_rad: roll };
        let a = 0.3f64.to_radians();
        // 0.3°: 15.4 px, the tolerance and a pixel, 8.25 coarse pixels: 9, and one more
        assert_eq!(steady_margin(shake(a, 0.0), &i, 2, 0.1), 10);
        assert_eq!(steady_margin(shake(a, 0.0), &i, 4, 0.1), 6);
        // no coarse grid, no tolerance, no turn
        assert_eq!(steady_margin(shake(a, 0.0), &i, 1, 0.1), 0);
        assert_eq!(steady_margin(shake(a, 0.0), &i, 2, 0.0), 0);
        assert_eq!(steady_margin(shake(0.0, 1e-5), &i, 2, 0.1), 0);
        // a peak roll of 0.1 mrad moves the corners 0.018 px, of 1 mrad 0.18 px
        assert_eq!(steady_margin(shake(a, 1e-4), &i, 2, 0.1), 10);
        assert_eq!(steady_margin(shake(a, 1e-3), &i, 2, 0.1), 0);
        // 1.1°: 30 coarse pixels a side, a render of 2.16 times the view's pixels; 1.2°: 33, 2.30 times
        assert_eq!(steady_margin(shake(1.1f64.to_radians(), 0.0), &i, 2, 0.1), 30);
        assert_eq!(steady_margin(shake(1.2f64.to_radians(), 0.0), &i, 2, 0.1), 0);
    }
}
