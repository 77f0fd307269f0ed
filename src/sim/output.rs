//! Output: ground truth of the frame, masks, and the clock's advance to the next frame.

use bevy::app::{App, Plugin};
use bevy::asset::RenderAssetUsages;
use bevy::ecs::prelude::*;
use bevy::image::Image;
use bevy::prelude::FixedUpdate;
use serde::Serialize;
use wgpu_types::{Extent3d, TextureDimension, TextureFormat};

use super::{
    Aircraft, Footprint, FrameOutput, LabelScratch, OutputSystems, Sensor, SensorFrame, Signature, SimClock,
    SimSettings, TargetPatches,
};
use crate::imaging::frame::Frame;
use crate::imaging::target_blob::{ImageEllipse, PixelRect};
use crate::physics::planck::brightness_temperature;

/// Collects labels.
pub struct OutputPlugin;

impl Plugin for OutputPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(
            FixedUpdate,
            (collect_labels, mirror_frame.run_if(resource_exists::<MirrorFrame>), advance_clock)
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

/// Ground truth of one frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FrameLabels {
    /// Frame index, from 0.
    pub frame: u64,
    /// Time, s.
    pub t_s: f64,
    /// One entry per target, in scenario order.
    pub targets: Vec<TargetLabel>,
}

/// The image ellipse of a target's outline, px.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EllipseLabel {
    /// Semi-major axis, px.
    pub a: f64,
    /// Semi-minor axis, px.
    pub b: f64,
    /// Angle of the major axis from +u toward +v, rad.
    pub angle_rad: f64,
}

/// Ground truth of one target in one frame.
///
/// Signals are in DN above the target's background (on axis, before non-uniformity); `snr`, `scr` and
/// `local_contrast` are 0 for a target not in the frame.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TargetLabel {
    /// 1-based id.
    pub id: u32,
    /// Name.
    pub name: String,
    /// Centre of the image ellipse (u, v), px; pixel (i, j) covers [i, i+1) × [j, j+1).
    pub center_px: [f64; 2],
    /// Box `[x0, y0, x1, y1]` of the drawn target to its 1/e level (the outline grown by the blur), px,
    /// clipped to the frame.
    pub bbox_px: [f64; 4],
    /// Exact image ellipse of the outline.
    pub ellipse_px: EllipseLabel,
    /// Distance from the camera, m.
    pub range_m: f64,
    /// Largest signal the target adds over its background, DN (signed: a target colder than the sky is
    /// negative).
    pub peak_dn: f64,
    /// `|peak_dn|` over the temporal noise σ (DN) at the target's background.
    pub snr: f64,
    /// Signal-to-clutter ratio: `|peak_dn|` over the standard deviation of the noise-free background (DN) in a
    /// window around the target (its own region left out), with σ floored at 0.001 DN.
    pub scr: f64,
    /// Radiance contrast `ΔL / L_background` at the target's centre.
    pub local_contrast: f64,
    /// Apparent brightness temperature of a pixel filled by the target (with the path), K.
    pub apparent_temp_k: f64,
    /// Fraction of a pixel the outline covers, min(1, area) (eq 13's fill factor).
    pub fill_factor: f64,
    /// Mach number used for the skin temperature.
    pub mach: f64,
    /// Skin temperature, K.
    pub skin_temp_k: f64,
    /// In front of the camera, drawn, and its box (the 1/e outline) covering part of the frame (geometric only;
    /// called `visible` before 0.2). Only these targets are in the MOT file.
    pub in_frame: bool,
    /// In the frame with `snr` at least the scenario's `labels.detectable_snr`.
    pub detectable: bool,
}

/// Fills [`FrameOutput`] with this frame's labels (and mask).
#[allow(clippy::too_many_arguments)]
pub fn collect_labels(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut output: ResMut<FrameOutput>,
    patches: Res<TargetPatches>,
    mut scratch: ResMut<LabelScratch>,
    sensor: Query<(&Sensor, &SensorFrame)>,
    targets: Query<(&Aircraft, &Footprint, &Signature)>,
) {
    let Ok((sensor, sf)) = sensor.single() else { return };
    let out = &mut *output;
    out.labels.frame = clock.frame;
    out.labels.t_s = clock.t_s();
    out.labels.targets.clear();
    let (w, h) = (sf.frame.width(), sf.frame.height());
    let mut sorted: Vec<_> = targets.iter().collect();
    sorted.sort_by_key(|(a, _, _)| a.id);
    let blur_1e = sensor.psf.as_ref().map_or(0.0, |p| 0.6006 * p.fwhm_px());
    let model = &sensor.resolved.model;
    for (aircraft, fp, sig) in &sorted {
        let mut label = TargetLabel {
            id: aircraft.id,
            name: aircraft.name.clone(),
            range_m: fp.range_m,
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
            let sigma = sensor.noise_dn(fp.background_radiance);
            label.snr = if sigma > 0.0 { peak_dn.abs() / sigma } else { peak_dn.abs() / 1e-3 };
            let clutter = clutter_sigma_dn(&sf.background, roi, sensor.dn_per_radiance, &mut scratch.0);
            label.scr = peak_dn.abs() / clutter.max(1e-3);
            label.local_contrast =
                if fp.background_radiance > 0.0 { fp.peak_radiance / fp.background_radiance } else { 0.0 };
            label.detectable = label.snr >= settings.detectable_snr;
        }
        out.labels.targets.push(label);
    }
    if settings.masks {
        let mask = out.mask.get_or_insert_with(Vec::new);
        mask.clear();
        mask.resize(w * h, 0);
        // nearer targets drawn last win
        let mut order: Vec<_> = sorted.iter().filter(|(_, fp, _)| fp.patch.is_some()).collect();
        order.sort_by(|a, b| b.1.range_m.total_cmp(&a.1.range_m));
        for (aircraft, fp, _) in order {
            let Some(i) = fp.patch else { continue };
            let (rect, values) = &patches.patches[i];
            let peak = fp.peak_radiance.abs() as f32;
            if !(peak > 0.0) {
                continue;
            }
            let threshold = 0.1 * peak;
            let rw = rect.width();
            for y in rect.y0..rect.y1 {
                for x in rect.x0..rect.x1 {
                    if values[(y - rect.y0) * rw + x - rect.x0].abs() >= threshold {
                        mask[y * w + x] = aircraft.id.min(255) as u8;
                    }
                }
            }
        }
    } else {
        out.mask = None;
    }
    out.ready = true;
}

/// Standard deviation (DN) of the background in a window around `roi` (the region grown by 10 px on each side,
/// at least 31 px wide), the region itself left out.
fn clutter_sigma_dn(background: &Frame, roi: PixelRect, dn_per_radiance: f64, buf: &mut Vec<f32>) -> f64 {
    let (w, h) = (background.width(), background.height());
    let grow_x = 10 + 15usize.saturating_sub(roi.width() / 2);
    let grow_y = 10 + 15usize.saturating_sub(roi.height() / 2);
    let (x0, y0) = (roi.x0.saturating_sub(grow_x), roi.y0.saturating_sub(grow_y));
    let (x1, y1) = ((roi.x1 + grow_x).min(w), (roi.y1 + grow_y).min(h));
    buf.clear();
    for y in y0..y1 {
        for x in x0..x1 {
            if !(roi.x0..roi.x1).contains(&x) || !(roi.y0..roi.y1).contains(&y) {
                buf.push(background.get(x, y));
            }
        }
    }
    if buf.len() < 2 {
        return 0.0;
    }
    let n = buf.len() as f64;
    let mean = buf.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let var = buf.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / (n - 1.0);
    var.sqrt() * dn_per_radiance
}
/// Moves the clock to the next frame.
pub fn advance_clock(mut clock: ResMut<SimClock>) {
    clock.frame += 1;
}
