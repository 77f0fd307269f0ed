//! Output: ground truth of the frame, masks, and the clock's advance to the next frame.

use bevy::app::{App, Plugin};
use bevy::asset::RenderAssetUsages;
use bevy::ecs::prelude::*;
use bevy::image::Image;
use bevy::prelude::FixedUpdate;
use serde::Serialize;
use wgpu_types::{Extent3d, TextureDimension, TextureFormat};

use super::{Aircraft, Footprint, FrameOutput, OutputSystems, Sensor, SensorFrame, Signature, SimClock, SimSettings};

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

/// The sensor frame as a Bevy [`Image`] (`R32Float`, gray levels), on the sensor entity.
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
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct TargetLabel {
    /// 1-based id.
    pub id: u32,
    /// Name.
    pub name: String,
    /// Centre of the image ellipse (u, v), px; pixel (i, j) covers [i, i+1) × [j, j+1).
    pub center_px: [f64; 2],
    /// Box `[x0, y0, x1, y1]` of the drawn blob to its 1/e level (ellipse grown by the blur), px, unclipped.
    pub bbox_px: [f64; 4],
    /// Exact image ellipse of the outline.
    pub ellipse_px: EllipseLabel,
    /// Distance from the camera, m.
    pub range_m: f64,
    /// Peak gray added by the target.
    pub peak_gray: f64,
    /// Peak over the noise standard deviation at the target's background.
    pub snr: f64,
    /// Peak over the background gray at the target's centre.
    pub local_contrast: f64,
    /// Fraction of a pixel the outline covers, min(1, area) (eq 13's fill factor).
    pub fill_factor: f64,
    /// Mach number used for the skin temperature.
    pub mach: f64,
    /// Skin temperature, K.
    pub skin_temp_k: f64,
    /// In front of the camera and overlapping the frame.
    pub visible: bool,
}

/// Fills [`FrameOutput`] with this frame's labels (and mask).
pub fn collect_labels(
    clock: Res<SimClock>,
    settings: Res<SimSettings>,
    mut output: ResMut<FrameOutput>,
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
    for (aircraft, fp, sig) in &sorted {
        let mut label = TargetLabel {
            id: aircraft.id,
            name: aircraft.name.clone(),
            range_m: fp.range_m,
            mach: sig.mach,
            skin_temp_k: sig.signal.map_or(f64::NAN, |s| s.skin_temp_k),
            ..TargetLabel::default()
        };
        if let (Some(e), Some(blob)) = (fp.ellipse, fp.blob) {
            label.center_px = [e.center.x, e.center.y];
            let grown = crate::imaging::target_blob::ImageEllipse { a: blob.alpha_x, b: blob.alpha_y, ..e };
            label.bbox_px = grown.bbox();
            label.ellipse_px = EllipseLabel { a: e.a, b: e.b, angle_rad: e.angle_rad };
            label.peak_gray = blob.peak;
            label.fill_factor = e.fill_factor();
            label.visible = fp.roi.is_some() && sig.signal.is_some();
            let (cx, cy) = (e.center.x.floor(), e.center.y.floor());
            let bg = if cx >= 0.0 && cy >= 0.0 && (cx as usize) < w && (cy as usize) < h {
                f64::from(sf.background.get(cx as usize, cy as usize))
            } else {
                sensor.gray.g_min
            };
            let n = sensor.noise;
            let shot =
                if n.electrons_per_gray > 0.0 { (bg - sensor.gray.g_min).max(0.0) / n.electrons_per_gray } else { 0.0 };
            let sigma = (shot + n.read_noise_gray * n.read_noise_gray).sqrt();
            label.snr = if sigma > 0.0 { blob.peak / sigma } else { f64::INFINITY };
            label.local_contrast = if bg > 0.0 { blob.peak / bg } else { f64::INFINITY };
        }
        out.labels.targets.push(label);
    }
    if settings.masks {
        let mask = out.mask.get_or_insert_with(Vec::new);
        mask.clear();
        mask.resize(w * h, 0);
        // nearer targets drawn last win
        let mut order: Vec<_> = sorted.iter().filter(|(_, fp, _)| fp.roi.is_some()).collect();
        order.sort_by(|a, b| b.1.range_m.total_cmp(&a.1.range_m));
        for (aircraft, fp, _) in order {
            let (Some(blob), Some(roi)) = (fp.blob, fp.roi) else { continue };
            let threshold = 0.1 * blob.peak;
            for y in roi.y0..roi.y1 {
                for x in roi.x0..roi.x1 {
                    let v = blob.value(glam::DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                    if v >= threshold && blob.peak > 0.0 {
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

/// Moves the clock to the next frame.
pub fn advance_clock(mut clock: ResMut<SimClock>) {
    clock.frame += 1;
}
