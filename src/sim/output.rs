//! Output: ground truth of the frame, masks, and the clock's advance to the next frame.

use bevy::app::{App, Plugin};
use bevy::asset::RenderAssetUsages;
use bevy::ecs::prelude::*;
use bevy::image::Image;
use bevy::prelude::FixedUpdate;
use rayon::prelude::*;
use wgpu_types::{Extent3d, TextureDimension, TextureFormat};

use super::{
    Aircraft, Footprint, FrameOutput, FramePool, Kinematics, OutputSystems, Sensor, SensorFrame, Signature, SimClock,
    SimSettings, TargetPatches,
};
use crate::imaging::frame::Frame;
use crate::imaging::target_blob::ImageEllipse;
use crate::labels::{EllipseLabel, FrameLabels, MaskPatch, TargetLabel, clutter_sigma, paint_mask, snr};
use crate::physics::planck::brightness_temperature;

/// Collects the labels and the mask, and sends each completed frame as [`FrameReady`].
pub struct OutputPlugin;

/// A completed sensor frame with its ground truth: written once per fixed step in [`OutputSystems`], read by
/// whatever front end runs the simulation (the recorder drains them; a window reads them).
#[derive(Message, Debug, Clone)]
pub struct FrameReady {
    /// The frame, DN (quantized, as f32).
    pub frame: Frame,
    /// The frame before quantization, DN, when the run keeps it.
    pub float_frame: Option<Frame>,
    /// Per-pixel target id (0 = sky), when masks are on.
    pub mask: Option<Vec<u8>>,
    /// Ground truth.
    pub labels: FrameLabels,
}

impl Plugin for OutputPlugin {
    fn build(&self, app: &mut App) {
        app.add_message::<FrameReady>().init_resource::<FramePool>().add_systems(
            FixedUpdate,
            (collect_labels, mirror_frame.run_if(resource_exists::<MirrorFrame>), emit_frame, advance_clock)
                .chain()
                .in_set(OutputSystems),
        );
    }
}

/// Present when the frame should be mirrored into a Bevy [`Image`] each step (the viewer inserts it; headless
/// runs skip the copy).
#[derive(Resource, Debug, Clone, Copy, Default)]
pub struct MirrorFrame;

/// The sensor frame as a Bevy [`Image`] (`R32Float`, DN), on the sensor entity.
#[derive(Component, Debug, Clone)]
pub struct FrameImage(pub Image);

/// Copies the quantized frame into the sensor's [`FrameImage`], creating it on first use.
pub fn mirror_frame(mut commands: Commands, mut sensor: Query<(Entity, &SensorFrame, Option<&mut FrameImage>)>) {
    let Ok((entity, sf, image)) = sensor.single_mut() else { return };
    let bytes: &[u8] = bytemuck::cast_slice(sf.frame.pixels());
    match image {
        Some(mut img) => match &mut img.0.data {
            Some(data) if data.len() == bytes.len() => data.copy_from_slice(bytes),
            _ => img.0.data = Some(bytes.to_vec()),
        },
        None => {
            let size =
                Extent3d { width: sf.frame.width() as u32, height: sf.frame.height() as u32, depth_or_array_layers: 1 };
            let image = Image::new(
                size,
                TextureDimension::D2,
                bytes.to_vec(),
                TextureFormat::R32Float,
                RenderAssetUsages::default(),
            );
            commands.entity(entity).insert(FrameImage(image));
        }
    }
}

/// Fills [`FrameOutput`] with this frame's labels (and mask).
#[allow(clippy::too_many_arguments)]
pub fn collect_labels(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut output: ResMut<FrameOutput>,
    patches: Res<TargetPatches>,
    sensor: Query<(&Sensor, &SensorFrame)>,
    targets: Query<(&Aircraft, &Footprint, &Signature, &Kinematics)>,
) {
    let Ok((sensor, sf)) = sensor.single() else { return };
    let out = &mut *output;
    out.labels.frame = clock.frame;
    out.labels.t_s = clock.t_s();
    out.labels.targets.clear();
    let (w, h) = (sf.frame.width(), sf.frame.height());
    let mut sorted: Vec<_> = targets.iter().collect();
    sorted.sort_by_key(|(a, _, _, _)| a.id);
    let blur_1e = sensor.psf.as_ref().map_or(0.0, |p| 0.6006 * p.fwhm_px());
    let model = &sensor.resolved.model;
    let label_of = |(aircraft, fp, sig, kin): &(&Aircraft, &Footprint, &Signature, &Kinematics)| {
        let mut label = TargetLabel {
            id: aircraft.id,
            name: aircraft.name.clone(),
            range_m: fp.range_m,
            altitude_m: kin.position_m.z,
            mach: sig.mach,
            skin_temp_k: sig.signal.map_or(0.0, |s| s.skin_temp_k),
            apparent_temp_k: sig.signal.map_or(0.0, |s| {
                brightness_temperature(model.measure(), model.band, s.apparent_radiance).unwrap_or(0.0)
            }),
            ..TargetLabel::default()
        };
        if let Some(e) = fp.ellipse {
            label.center_px = [e.center.x, e.center.y];
            let (ga, gb) = match fp.blob {
                Some(blob) => (blob.alpha_x, blob.alpha_y),
                None => (e.a.hypot(blur_1e), e.b.hypot(blur_1e)),
            };
            let [x0, y0, x1, y1] = ImageEllipse { a: ga, b: gb, ..e }.bbox();
            let (wf, hf) = (w as f64, h as f64);
            let clipped = [x0.clamp(0.0, wf), y0.clamp(0.0, hf), x1.clamp(0.0, wf), y1.clamp(0.0, hf)];
            label.bbox_px = clipped;
            label.ellipse_px = EllipseLabel { a: e.a, b: e.b, angle_rad: e.angle_rad };
            label.fill_factor = e.fill_factor();
            // in the frame: drawn, and its 1/e box covers part of the image (a blur tail alone is not a target)
            let has_area = clipped[2] > clipped[0] && clipped[3] > clipped[1];
            label.in_frame = fp.roi.is_some() && sig.signal.is_some() && has_area;
        }
        if label.in_frame
            && let Some(roi) = fp.roi
        {
            let peak_dn = fp.peak_radiance * sensor.dn_per_radiance;
            label.peak_dn = peak_dn;
            label.snr = snr(peak_dn, sensor.noise_dn(fp.background_radiance));
            let clutter = clutter_sigma(&sf.background, roi) * sensor.dn_per_radiance;
            label.scr = peak_dn.abs() / clutter.max(1e-3);
            label.local_contrast =
                if fp.background_radiance > 0.0 { fp.peak_radiance / fp.background_radiance } else { 0.0 };
            label.detectable = label.snr >= settings.detectable_snr;
        }
        label
    };
    // each label is its target's alone (its brightness temperature's Newton steps, the clutter around it), so the
    // labels are made side by side, kept in the order of their ids (a single one is not split off). The output
    // stage of `irsim bench`'s 640 × 512 case against all on one thread, medians of alternating runs, µs a frame
    // (two sets of 8–10 runs, an AMD EPYC with 2 vCPUs): 1 target 3 → 3, 2 targets 5 → 4 and 6 → 6, 4 targets
    // 8 → 6, 10 targets 23.5 → 14 and 23 → 20; swarm (10 targets) 30.5 → 24.5 and 32.5 → 22
    out.labels.targets.par_extend(sorted.par_iter().map(label_of));
    if settings.masks {
        let mut drawn: Vec<MaskPatch<'_>> = sorted
            .iter()
            .filter_map(|(aircraft, fp, _, _)| {
                let (rect, values) = &patches.patches[fp.patch?];
                Some(MaskPatch { id: aircraft.id, range_m: fp.range_m, rect: *rect, values, peak: fp.peak_radiance })
            })
            .collect();
        paint_mask(out.mask.get_or_insert_with(Vec::new), w, h, settings.mask_fraction, &mut drawn);
    } else {
        out.mask = None;
    }
}

/// Sends the completed frame out of the schedule as [`FrameReady`]: the frame's buffer is handed over (the
/// sensor takes another from the [`FramePool`]), with the float frame, the mask and the labels.
pub fn emit_frame(
    mut output: ResMut<FrameOutput>,
    mut pool: ResMut<FramePool>,
    mut sensor: Query<&mut SensorFrame>,
    mut ready: MessageWriter<FrameReady>,
) {
    let Ok(mut sf) = sensor.single_mut() else { return };
    let (w, h) = (sf.frame.width(), sf.frame.height());
    let frame = std::mem::replace(&mut sf.frame, pool.take(w, h));
    ready.write(FrameReady {
        frame,
        float_frame: sf.float_frame.take(),
        mask: output.mask.take(),
        labels: std::mem::take(&mut output.labels),
    });
}

/// Moves the clock to the next frame.
pub fn advance_clock(mut clock: ResMut<SimClock>) {
    clock.frame += 1;
}
