//! The egui panels: transport controls on top, the sensor image on the left (zoom, pixel read-out, ground-truth
//! boxes), display settings and the targets' ground truth on the right, the 3D view in the middle, and the
//! help overlay.

use bevy::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use bevy_egui::{EguiContexts, egui};

use super::scene::{DrawScale, ViewImage, palette};
use super::state::{ColorMap, Pace, Stretch, display_window, to_rgba};
use super::uploads::{LiveImage, LiveImages, Writes};
use super::{Viewer, edits};
use crate::cli::run::{RecordPlan, record_scenario};
use crate::record::FrameFormat;
use crate::sim::{CameraPose, Observer, Sensor, SensorFrame};

/// The Record button's settings, and the recording running in the background.
pub struct RecordUi {
    /// Output directory.
    pub out: String,
    /// First and last frame to write.
    pub first: u64,
    /// See `first`.
    pub last: u64,
    /// Frame format.
    pub format: FrameFormat,
    /// Replace an earlier run's outputs.
    pub force: bool,
    /// The job: frames written, total, stop flag, outcome.
    pub job: Option<RecordJob>,
}

/// A recording on its own thread (the window keeps running).
pub struct RecordJob {
    written: Arc<AtomicU64>,
    total: u64,
    stop: Arc<AtomicBool>,
    outcome: Arc<Mutex<Option<String>>>,
}

impl RecordUi {
    /// Frames `0 ..= last`, PNG16, into `irsim_recording`.
    pub fn new(last: u64) -> Self {
        Self { out: "irsim_recording".into(), first: 0, last, format: FrameFormat::Png16, force: false, job: None }
    }
}

/// Starts recording `scenario` as the panel says.
fn start_recording(r: &mut RecordUi, scenario: &crate::scenario::CheckedScenario, seed: Option<u64>) {
    let plan = RecordPlan {
        out: std::path::PathBuf::from(r.out.trim()),
        first_frame: r.first.min(r.last),
        frames: r.last.max(r.first) - r.first.min(r.last) + 1,
        seed,
        force: r.force,
        noise: true,
        vibration: true,
        format: r.format,
        png: crate::imaging::frame::PngCompression::Fast,
        masks: false,
        reproducible: false,
    };
    let job = RecordJob {
        written: Arc::new(AtomicU64::new(0)),
        total: plan.frames,
        stop: Arc::new(AtomicBool::new(false)),
        outcome: Arc::new(Mutex::new(None)),
    };
    let (written, stop, outcome) = (Arc::clone(&job.written), Arc::clone(&job.stop), Arc::clone(&job.outcome));
    let scenario = scenario.clone();
    std::thread::spawn(move || {
        let result = record_scenario(&scenario, &plan, &stop, &mut |n, _| written.store(n, Ordering::Relaxed));
        let text = match result {
            Ok(done) => done.summary,
            Err(e) => format!("recording failed: {e}"),
        };
        if let Ok(mut o) = outcome.lock() {
            *o = Some(text);
        }
    });
    r.job = Some(job);
}

/// The picture the sensor panel shows and what it was made from: its pixels are written straight into the same
/// GPU texture each frame (see [`super::uploads`]).
#[derive(Default)]
pub struct SensorTexture {
    image: Option<LiveImage>,
    key: Option<(u64, u64, Stretch, ColorMap)>,
    scratch: super::state::StretchScratch,
    window: (f64, f64),
}

const SHORTCUTS: [(&str, &str); 11] = [
    ("Space", "play / pause"),
    ("→ / ←", "step one frame forward / back"),
    ("Home / End", "first / last frame"),
    ("B", "ground-truth boxes on / off"),
    ("F", "3D view: focus on the first target in the frame"),
    ("H", "this help"),
    ("Esc", "close the help; cancel placing a new target"),
    ("left drag", "3D view: orbit"),
    ("right drag", "3D view: pan"),
    ("wheel", "3D view: zoom"),
    ("hover", "sensor image: pixel read-out"),
];

/// Draws every panel and records the 3D view's rectangle.
#[allow(clippy::too_many_arguments)]
pub fn draw_panels(
    mut contexts: EguiContexts,
    mut viewer: ResMut<Viewer>,
    mut texture: Local<SensorTexture>,
    mut images: ResMut<Assets<Image>>,
    writes: Res<Writes>,
    scale: Option<Res<DrawScale>>,
    view_image: Option<Res<ViewImage>>,
    sensor: Query<(&Sensor, &SensorFrame)>,
    observer: Query<&CameraPose, With<Observer>>,
) -> Result {
    let v = &mut *viewer;
    let ctx = contexts.ctx_mut()?.clone();
    let mut live = LiveImages::new(&mut images, &mut contexts, &writes);
    update_texture(&mut live, v, &mut texture);
    if ctx.global_style().visuals.panel_fill != egui::Color32::TRANSPARENT {
        // the panels paint no background: egui's camera clears the window (see `setup_egui`)
        ctx.all_styles_mut(|style| style.visuals.panel_fill = egui::Color32::TRANSPARENT);
    }
    let mut root = egui::Ui::new(
        ctx.clone(),
        "irsim_root".into(),
        egui::UiBuilder::new().layer_id(egui::LayerId::background()).max_rect(ctx.viewport_rect()),
    );
    egui::Panel::top("transport").show(&mut root, |ui| transport(ui, v));
    egui::Panel::right("details").resizable(true).default_size(320.0).show(&mut root, |ui| {
        egui::ScrollArea::vertical().show(ui, |ui| details(ui, v, scale.as_deref()));
    });
    let (sensor_w, sensor_h) = v.frame.as_ref().map_or((640.0, 512.0), |f| (f.width() as f32, f.height() as f32));
    let fit = ((ctx.viewport_rect().height() - 390.0) / sensor_h).clamp(0.25, 1.0);
    let left_default = (sensor_w * fit + 16.0).min(ctx.viewport_rect().width() * 0.5);
    egui::Panel::left("sensor").resizable(true).default_size(left_default).show(&mut root, |ui| {
        sensor_panel(ui, v, &mut live, &texture, sensor.single().ok(), observer.single().ok());
    });
    let every = view_image.as_ref().map_or(1, |image| image.every);
    let view_id = view_image.map(|image| image.handle.id());
    let central = egui::CentralPanel::default().frame(egui::Frame::NONE).show(&mut root, |ui| {
        let rect = ui.max_rect();
        if let Some(id) = view_id {
            ui.painter().add(super::blit::blit(rect, id));
        }
        ui.label(egui::RichText::new("3D view — drag to orbit, right-drag to pan, wheel to zoom, F to focus").weak());
        if every > 1 {
            ui.label(
                egui::RichText::new(format!("drawn every {every} frames while playing (software renderer)")).weak(),
            )
            .on_hover_text("without a GPU the 3D view costs as much as all the panels together; the sensor image shows every frame");
        }
        rect
    });
    let r = central.inner;
    v.view_rect = [r.min.x, r.min.y, r.max.x, r.max.y];
    if v.help {
        egui::Window::new("Help — keys and mouse").collapsible(false).show(&ctx, |ui| {
            egui::Grid::new("shortcuts").striped(true).show(ui, |ui| {
                for (key, what) in SHORTCUTS {
                    ui.monospace(key);
                    ui.label(what);
                    ui.end_row();
                }
            });
            if ui.button("Close").clicked() {
                v.help = false;
            }
        });
    }
    Ok(())
}

fn stretch_name(s: Stretch) -> String {
    match s {
        Stretch::MinMax => "min – max".into(),
        Stretch::Percentile { low, high } => format!("percentile {low}–{high}"),
        Stretch::Window { low, high } => format!("window {low:.0}–{high:.0} DN"),
    }
}

fn update_texture(live: &mut LiveImages, v: &mut Viewer, t: &mut SensorTexture) {
    let Some(frame) = &v.frame else { return };
    let key = (v.computed, v.playback.shown.unwrap_or(0), v.stretch, v.color_map);
    if t.key.as_ref() == Some(&key) && t.image.is_some() {
        return;
    }
    let started = std::time::Instant::now();
    t.window = display_window(frame, v.stretch, &mut t.scratch);
    let mut rgba = live.buffer(frame.pixels().len() * 4);
    to_rgba(frame, t.window, v.color_map, &mut rgba);
    let size = [frame.width() as u32, frame.height() as u32];
    match &t.image {
        Some(image) if image.size == size => live.write(image, [0, 0], size, rgba),
        _ => t.image = Some(live.create(size, rgba, t.image.take())),
    }
    t.key = Some(key);
    v.map_ms_total += started.elapsed().as_secs_f64() * 1e3;
}

fn transport(ui: &mut egui::Ui, v: &mut Viewer) {
    ui.horizontal(|ui| {
        let last = v.playback.frames - 1;
        if ui.button("⏮").on_hover_text("first frame (Home)").clicked() {
            v.playback.seek(0);
        }
        if ui.button("◀").on_hover_text("one frame back (←)").clicked() {
            v.playback.step_back();
        }
        let play = if v.playback.playing { "⏸ pause" } else { "▶ play" };
        if ui.button(play).on_hover_text("Space").clicked() {
            v.playback.toggle();
        }
        if ui.button("▶|").on_hover_text("one frame forward (→)").clicked() {
            v.playback.step_forward();
        }
        if ui.button("⏭").on_hover_text("last frame (End)").clicked() {
            v.playback.seek(last);
        }
        let mut k = v.playback.shown.unwrap_or(0);
        let slider = egui::Slider::new(&mut k, 0..=last).text("frame");
        if ui.add(slider).changed() {
            v.playback.seek(k);
        }
        ui.label(format!("t = {:.3} s", v.labels.t_s));
        egui::ComboBox::from_id_salt("pace").selected_text(pace_name(v.playback.pace)).show_ui(ui, |ui| {
            for pace in [
                Pace::PerDisplayFrame(1),
                Pace::PerDisplayFrame(2),
                Pace::PerDisplayFrame(5),
                Pace::RealTime { speed: 1.0 },
                Pace::RealTime { speed: 0.25 },
            ] {
                ui.selectable_value(&mut v.playback.pace, pace, pace_name(pace));
            }
        });
        ui.checkbox(&mut v.playback.looping, "loop");
        ui.separator();
        ui.label(format!("{:.0} fps, step {:.1} ms", v.fps, v.step_ms));
        if ui.button("Help (H)").clicked() {
            v.help = !v.help;
        }
    });
}

fn pace_name(p: Pace) -> String {
    match p {
        Pace::PerDisplayFrame(1) => "1 frame per display frame".into(),
        Pace::PerDisplayFrame(n) => format!("{n} frames per display frame"),
        Pace::RealTime { speed } => format!("real time × {speed}"),
    }
}

fn details(ui: &mut egui::Ui, v: &mut Viewer, scale: Option<&DrawScale>) {
    let spec = &v.built.spec;
    let sensor = &v.built.sensor;
    ui.heading(&spec.name);
    ui.label(format!(
        "{} × {} px, {:.1} µm pitch, {:.0} mm, band {:.1}–{:.1} µm, {} Hz, {} frames",
        sensor.intrinsics.width,
        sensor.intrinsics.height,
        sensor.intrinsics.pixel_pitch_m * 1e6,
        sensor.intrinsics.focal_length_m * 1e3,
        sensor.model.band.lo_um(),
        sensor.model.band.hi_um(),
        spec.run.frame_rate_hz,
        v.playback.frames
    ));
    ui.separator();
    ui.strong("Display");
    egui::ComboBox::from_label("stretch").selected_text(stretch_name(v.stretch)).show_ui(ui, |ui| {
        for s in [
            Stretch::Percentile { low: 0.5, high: 99.5 },
            Stretch::Percentile { low: 2.0, high: 98.0 },
            Stretch::MinMax,
        ] {
            ui.selectable_value(&mut v.stretch, s, stretch_name(s));
        }
    });
    egui::ComboBox::from_label("colours").selected_text(format!("{:?}", v.color_map)).show_ui(ui, |ui| {
        ui.selectable_value(&mut v.color_map, ColorMap::Gray, "Gray");
        ui.selectable_value(&mut v.color_map, ColorMap::Ironbow, "Ironbow");
    });
    ui.checkbox(&mut v.boxes, "ground-truth boxes (B)");
    ui.horizontal(|ui| {
        ui.label("zoom");
        ui.selectable_value(&mut v.zoom, 0.0, "fit");
        for z in [1.0, 2.0, 4.0, 8.0] {
            ui.selectable_value(&mut v.zoom, z, format!("{z}×"));
        }
    });
    ui.separator();
    ui.strong("Targets (ground truth of this frame)");
    egui::Grid::new("targets").striped(true).num_columns(7).show(ui, |ui| {
        for (h, hint) in [
            ("id", "the target's id in the labels"),
            ("name", "its name in the scenario"),
            ("range km", "distance from the observer"),
            ("SNR", "|peak ΔDN| over the temporal noise σ at its sky"),
            ("SCR", "|peak ΔDN| over the σ of the noise-free sky around it"),
            ("peak ΔDN", "peak gray value above its sky, DN: negative where the target is darker than the sky"),
            ("drawn ×", "enlargement of its ellipsoid in the 3D view"),
        ] {
            ui.strong(h).on_hover_text(hint);
        }
        ui.end_row();
        for t in &v.labels.targets {
            let c = palette(t.id).to_srgba();
            let color = egui::Color32::from_rgb((c.red * 255.0) as u8, (c.green * 255.0) as u8, (c.blue * 255.0) as u8);
            ui.colored_label(color, t.id.to_string());
            let state = if t.detectable {
                "detectable"
            } else if t.in_frame {
                "in frame"
            } else {
                "out of frame"
            };
            ui.label(&t.name).on_hover_text(state);
            ui.label(format!("{:.2}", t.range_m * 1e-3));
            ui.label(format!("{:.1}", t.snr));
            ui.label(format!("{:.1}", t.scr));
            ui.label(format!("{:.1}", t.peak_dn));
            let factor = scale.and_then(|s| s.get(t.id)).map_or(1.0, |d| d.factor);
            ui.label(if factor > 1.0 { format!("{factor:.0}") } else { "1".into() });
            ui.end_row();
        }
    });
    ui.separator();
    egui::CollapsingHeader::new(egui::RichText::new("Edit").strong()).default_open(true).show(ui, |ui| {
        edits::edit_panel(ui, v);
    });
    ui.separator();
    save_and_record(ui, v);
}

fn save_and_record(ui: &mut egui::Ui, v: &mut Viewer) {
    ui.strong("Save the scenario (TOML)");
    ui.horizontal(|ui| {
        ui.text_edit_singleline(&mut v.save_path);
        ui.checkbox(&mut v.save_overwrite, "overwrite");
    });
    if ui.button("Save").clicked() {
        v.save_status = match v.session.save(std::path::Path::new(v.save_path.trim()), v.save_overwrite) {
            Ok(p) => format!("saved {}", std::fs::canonicalize(&p).unwrap_or(p).display()),
            Err(e) => format!("not saved: {e}"),
        };
    }
    if !v.save_status.is_empty() {
        ui.label(&v.save_status);
    }
    ui.separator();
    ui.strong("Record (as irsim record)");
    let last = v.playback.frames - 1;
    let r = &mut v.record;
    ui.horizontal(|ui| {
        ui.label("frames");
        ui.add(egui::DragValue::new(&mut r.first).range(0..=last));
        ui.label("to");
        ui.add(egui::DragValue::new(&mut r.last).range(0..=last));
    });
    ui.horizontal(|ui| {
        ui.text_edit_singleline(&mut r.out);
        ui.label("directory");
    });
    ui.horizontal(|ui| {
        for (f, name) in [
            (FrameFormat::Png16, "png16"),
            (FrameFormat::Png8, "png8"),
            (FrameFormat::Png8Agc, "png8-agc"),
            (FrameFormat::Npy, "npy"),
        ] {
            ui.selectable_value(&mut r.format, f, name);
        }
        ui.checkbox(&mut r.force, "replace an earlier run");
    });
    let running = r.job.as_ref().is_some_and(|j| !matches!(j.outcome.lock().as_deref(), Ok(Some(_))));
    if let Some(job) = &r.job {
        let n = job.written.load(Ordering::Relaxed);
        if running {
            ui.add(
                egui::ProgressBar::new(n as f32 / job.total.max(1) as f32).text(format!("{n} / {} frames", job.total)),
            );
            if ui.button("Stop").clicked() {
                job.stop.store(true, Ordering::SeqCst);
            }
            ui.ctx().request_repaint();
        } else if let Some(text) = job.outcome.lock().ok().and_then(|o| o.clone()) {
            v.status = text;
            r.job = None;
        }
    }
    if !running && ui.button("Record").clicked() {
        start_recording(r, &v.session.applied, v.options.seed);
    }
    if !v.status.is_empty() {
        ui.label(&v.status);
    }
}

fn sensor_panel(
    ui: &mut egui::Ui,
    v: &mut Viewer,
    live: &mut LiveImages,
    t: &SensorTexture,
    sensor: Option<(&Sensor, &SensorFrame)>,
    pose: Option<&CameraPose>,
) {
    let (Some(frame), Some(image)) = (&v.frame, &t.image) else {
        ui.label("computing the first frame …");
        return;
    };
    let (w, h) = (frame.width() as f32, frame.height() as f32);
    let avail = ui.available_width().max(64.0);
    // the image, its read-out below, and the plots under that
    let image_height = (ui.available_height() - 330.0).max(160.0);
    let zoom = if v.zoom > 0.0 { v.zoom } else { (avail / w).min(image_height / h) };
    let size = egui::vec2(w * zoom, h * zoom);
    let mut hovered = None;
    let mut clicked = None;
    // solid scroll bars, shown whenever the zoomed image is larger than its area (egui's default floating bars
    // appear only under the pointer, so a zoomed image gave no sign that it scrolls)
    ui.spacing_mut().scroll = egui::style::ScrollStyle::solid();
    egui::ScrollArea::both().max_height(image_height).show(ui, |ui| {
        let sense = if v.new_target.armed { egui::Sense::click() } else { egui::Sense::hover() };
        let (rect, response) = ui.allocate_exact_size(size, sense);
        if super::blit::fits(ui.ctx(), rect) {
            ui.painter().add(super::blit::blit(rect, image.asset()));
        } else {
            // zoomed beyond the window: egui's own image (a paint callback's viewport cannot leave the window)
            let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
            ui.painter().image(image.id, rect, uv, egui::Color32::WHITE);
        }
        if v.new_target.armed {
            response.clone().on_hover_cursor(egui::CursorIcon::Crosshair);
        }
        let rect = response.rect;
        v.sensor_rect = [rect.min.x, rect.min.y, rect.max.x, rect.max.y];
        let painter = ui.painter_at(rect);
        if v.boxes {
            for l in v.labels.targets.iter().filter(|l| l.in_frame) {
                let [x0, y0, x1, y1] = l.bbox_px;
                let r = egui::Rect::from_min_max(
                    rect.min + egui::vec2(x0 as f32, y0 as f32) * zoom,
                    rect.min + egui::vec2(x1 as f32, y1 as f32) * zoom,
                )
                .expand(2.0);
                let c = palette(l.id).to_srgba();
                let color =
                    egui::Color32::from_rgb((c.red * 255.0) as u8, (c.green * 255.0) as u8, (c.blue * 255.0) as u8);
                painter.rect_stroke(r, 0.0, egui::Stroke::new(1.5, color), egui::StrokeKind::Outside);
                painter.text(
                    r.left_top() - egui::vec2(0.0, 2.0),
                    egui::Align2::LEFT_BOTTOM,
                    format!("{} {}", l.id, l.name),
                    egui::FontId::monospace(11.0),
                    color,
                );
            }
        }
        if let Some(p) = response.hover_pos() {
            let q = (p - rect.min) / zoom;
            if q.x >= 0.0 && q.y >= 0.0 && q.x < w && q.y < h {
                hovered = Some((q.x as usize, q.y as usize));
                if response.clicked() {
                    clicked = Some((f64::from(q.x), f64::from(q.y)));
                }
            }
        }
    });

    v.display_window = t.window;
    ui.label(format!("display window {:.0} – {:.0} DN", t.window.0, t.window.1));
    match hovered {
        Some((x, y)) => {
            ui.monospace(format!("pixel ({x}, {y}): {:.0} DN", frame.get(x, y)));
            if let Some((s, sf)) = sensor
                && x < sf.background.width()
                && y < sf.background.height()
            {
                let l = f64::from(sf.background_at(x, y));
                ui.monospace(format!(
                    "sky behind it (noise-free, blurred): {l:.4e} W m⁻² sr⁻¹ ≈ {:.1} DN above offset",
                    l * s.dn_per_radiance
                ));
            }
            for l in v.labels.targets.iter().filter(|l| l.in_frame) {
                let [x0, y0, x1, y1] = l.bbox_px;
                let (xf, yf) = (x as f64 + 0.5, y as f64 + 0.5);
                if xf >= x0 && xf <= x1 && yf >= y0 && yf <= y1 {
                    ui.monospace(format!(
                        "target {} {}: peak {:.1} DN over its sky, {:.1} K apparent",
                        l.id, l.name, l.peak_dn, l.apparent_temp_k
                    ));
                }
            }
        }
        None => {
            ui.label("hover the image for a pixel read-out");
        }
    }
    ui.separator();
    let t_now = v.labels.t_s;
    let height = (ui.available_height() - 40.0).max(80.0);
    let run = &v.built.spec.run;
    let run_s = (run.start_time_s, run.start_time_s + (v.playback.frames.max(2) - 1) as f64 / run.frame_rate_hz);
    v.history.show(ui, live, t_now, run_s, height);
    if let (Some((x, y)), Some(pose)) = (clicked, pose) {
        add_target_at(v, pose, x, y);
    }
}

/// Adds a target through the clicked pixel `(x, y)` (image coordinates, px) at the panel's range, flying level
/// at its speed and heading, with the selected target's body and skin.
fn add_target_at(v: &mut Viewer, pose: &CameraPose, x: f64, y: f64) {
    let cam = pose.current;
    let (w, h) = (f64::from(cam.intrinsics.width), f64::from(cam.intrinsics.height));
    let f = cam.intrinsics.focal_px();
    let ray = (cam.camera_to_world * glam::DVec3::new((x - w / 2.0) / f, (y - h / 2.0) / f, 1.0)).normalize();
    let a = v.new_target;
    let point = cam.position_m + ray * a.range_m;
    let heading = a.heading_deg.to_radians();
    let velocity = glam::DVec3::new(heading.sin(), heading.cos(), 0.0) * a.speed_m_s;
    let template = v.session.draft.targets.get(v.selected).cloned();
    match v.session.add_target(point, v.labels.t_s, velocity, template.as_ref()) {
        Ok(i) => {
            v.selected = i;
            v.new_target.armed = false;
            v.target_status = format!("added {} at {:.0} m range", v.session.applied.spec.targets[i].name, a.range_m);
        }
        Err(e) => v.target_status = format!("not added: {}: {}", e.path, e.message),
    }
}
