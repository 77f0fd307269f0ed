//! `irsim view`: fly an encounter in a window. The same ECS world and systems as `irsim record`
//! ([`IrSimPlugins`] and [`spawn_scenario`]) run inside a Bevy app with a window and egui: the sensor panel shows
//! each [`FrameReady`] frame, a 3D view shows the encounter, and the controls play, pause, step and seek.
//!
//! The viewer computes frames itself: its update runs the simulation's fixed-step schedule once per frame to
//! show (frame `k` is computed directly at `t0 + k/rate`, so seeking gives exactly the frame `irsim record`
//! writes as frame `k`); Bevy's own fixed clock never steps it.

mod blit;
mod edits;
mod meshes;
mod panels;
mod plots;
mod scene;
pub mod state;
mod uploads;

use std::path::PathBuf;

use bevy::app::AppExit;
use bevy::prelude::*;
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::window::{PresentMode, WindowResolution};
use bevy_egui::{EguiGlobalSettings, EguiPlugin, EguiPrimaryContextPass};
use clap::Args;

use crate::cli::CliError;
use crate::imaging::frame::Frame;
use crate::labels::FrameLabels;
use crate::scenario::CheckedScenario;
use crate::scenario::edit::Session;
use crate::scenario::load::located;
use crate::sim::{
    FrameReady, IrSimPlugins, RunOptions, SimClock, despawn_scenario, drain_frames_world, spawn_scenario,
};
use state::{ColorMap, Playback, Stretch};

/// Flags of `irsim view`.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// Scenario file (TOML, or JSON by extension).
    pub scenario: PathBuf,
    /// Play this many frames, then (with --screenshot) save the window and exit.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Save a screenshot of the window (PNG) after --frames frames (default 1), and beside it (`.json`) where the
    /// sensor image and the 3D view are in it; then exit.
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// Window size in logical pixels, WxH.
    #[arg(long, default_value = "1280x800")]
    pub size: String,
    /// Seed (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Accuracy against speed: draft, standard or reference, in place of the scenario's `[quality]` table.
    #[arg(long, value_name = "PRESET")]
    pub quality: Option<crate::scenario::QualityPreset>,
}

/// What the viewer shows and how.
#[derive(Resource)]
pub struct Viewer {
    /// The scenario in use and its edits.
    pub session: Session,
    /// The scenario whose world is built (the last that built: an edit that validates but cannot be built,
    /// such as a band the sky image cannot be calibrated in, goes back to it).
    pub built: CheckedScenario,
    /// `session.revision` of the world that is built.
    pub built_revision: u64,
    /// Run options (seed).
    pub options: RunOptions,
    /// The target selected in the edit panel.
    pub selected: usize,
    /// A target being added.
    pub new_target: edits::NewTarget,
    /// Plotted values of the frames computed.
    pub history: plots::History,
    /// Save: file name, overwrite, and the last outcome.
    pub save_path: String,
    /// See `save_path`.
    pub save_overwrite: bool,
    /// What the last recording or rebuild said.
    pub status: String,
    /// What the last target added or removed said (shown under the target editor).
    pub target_status: String,
    /// The last target removed and where it was, for *undo*.
    pub removed: Option<(usize, crate::scenario::TargetSpec)>,
    /// What the last save said.
    pub save_status: String,
    /// The Record button's settings and job.
    pub record: panels::RecordUi,
    /// Play, pause, step, seek.
    pub playback: Playback,
    /// The frame on show and its ground truth.
    pub frame: Option<Frame>,
    /// Its labels.
    pub labels: FrameLabels,
    /// How the frame is stretched.
    pub stretch: Stretch,
    /// Its colours.
    pub color_map: ColorMap,
    /// Draw the ground-truth boxes and ids.
    pub boxes: bool,
    /// Sensor panel zoom (image pixels per screen point); 0 fits the panel.
    pub zoom: f32,
    /// Show the help overlay.
    pub help: bool,
    /// Frames computed since start (for --frames).
    pub computed: u64,
    /// Measured display rate, frames per second (smoothed).
    pub fps: f64,
    /// Milliseconds of the last simulation step.
    pub step_ms: f64,
    /// Total milliseconds of simulation steps, and when the first frame was shown (for the run summary).
    pub step_ms_total: f64,
    /// Total milliseconds spent mapping frames to display colours and uploading them.
    pub map_ms_total: f64,
    /// Total milliseconds of the main world's updates (`First` to `Last`), and when the one under way began.
    pub update_ms_total: f64,
    /// See `update_ms_total`.
    pub update_began: Option<std::time::Instant>,
    /// Wall-clock times of the first and the latest computed frame.
    pub started: Option<std::time::Instant>,
    /// See `started`.
    pub latest: Option<std::time::Instant>,
    /// The process's CPU seconds (all threads) at `started` and at `latest`, where the system says it.
    pub cpu_s: (Option<f64>, Option<f64>),
    /// The 3D view's rectangle in the window, logical pixels (min x, min y, max x, max y).
    pub view_rect: [f32; 4],
    /// The sensor image's rectangle in the window, logical pixels, as last drawn.
    pub sensor_rect: [f32; 4],
    /// The DN window of the frame on show.
    pub display_window: (f64, f64),
}

/// `--frames` (and `--screenshot`): after `frames` computed frames, save the window to `path` if given, and exit.
#[derive(Resource, Debug, Clone)]
struct ScreenshotPlan {
    frames: u64,
    path: Option<PathBuf>,
    /// Display frames waited since the asked frames were computed.
    waited: u32,
    /// The display frame at which to capture (again).
    capture_at: u32,
    /// Captures made; one is in flight.
    tries: u32,
    in_flight: bool,
    /// The file is written.
    saved: bool,
}

impl ScreenshotPlan {
    fn new(frames: u64, path: Option<PathBuf>) -> Self {
        // a few display frames for the renderer to show the last frame (pipelined rendering lags by one)
        Self { frames, path, waited: 0, capture_at: 5, tries: 0, in_flight: false, saved: false }
    }
}

/// Captures until the sensor image and the 3D view both show something, at most this many times.
const SCREENSHOT_TRIES: u32 = 40;
/// Display frames between captures: pipelines still compiling draw nothing, more so in a debug build.
const SCREENSHOT_RETRY_FRAMES: u32 = 10;

/// Opens the viewer on `a.scenario`.
///
/// # Errors
/// [`CliError::Invalid`] for a bad scenario, sky image or flag (exit 2); [`CliError::Failed`] when no window can
/// be opened or the screenshot cannot be written.
pub fn view(a: &ViewArgs) -> Result<(), CliError> {
    let (width, height) = parse_size(&a.size)?;
    if let Some(n) = a.frames
        && !(1..=100_000_000).contains(&n)
    {
        return Err(CliError::Invalid(format!("--frames {n} must be in 1 … 100000000")));
    }
    // a screenshot goes into an existing directory: said now, not after the frames have played
    if let Some(path) = &a.screenshot {
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
        if !dir.is_dir() {
            return Err(CliError::Invalid(format!(
                "--screenshot {}: the directory {} does not exist",
                path.display(),
                dir.display()
            )));
        }
    }
    // checked over the frames that will be shown, as `record --frames` checks them
    let file_frames = crate::scenario::load(&a.scenario).map_err(|e| CliError::Invalid(e.to_string()))?.spec.run.frames;
    let scenario = crate::scenario::load::load_for_frames(&a.scenario, a.frames.map(|n| n.max(file_frames)))
        .map_err(|e| CliError::Invalid(e.to_string()))?;
    let scenario = crate::cli::run::with_quality(scenario, a.quality)?;
    // the panel reads the sky behind the pixel under the pointer: the whole background is kept
    let options = RunOptions { seed: a.seed, whole_background: true, ..RunOptions::default() };
    let rate = scenario.spec.run.frame_rate_hz;
    let title = window_title(&scenario.spec.name, None, 0.0);
    // the scenario's world first: a bad sky image or PSF is reported before any window opens
    let mut app = App::new();
    spawn_scenario(app.world_mut(), &scenario, options)
        .map_err(|e| CliError::Invalid(located(&scenario.source, &e.field, &e.message).to_string()))?;
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return Err(CliError::Failed(
            "no display to open a window on (DISPLAY is not set); run it in a desktop session, or under `xvfb-run`"
                .into(),
        ));
    }
    app.add_plugins(
        DefaultPlugins
            .set(WindowPlugin {
                primary_window: Some(Window {
                    title,
                    resolution: WindowResolution::new(width, height),
                    present_mode: PresentMode::AutoNoVsync,
                    ..default()
                }),
                ..default()
            })
            .set(bevy::log::LogPlugin { level: bevy::log::Level::WARN, ..default() }),
    );
    app.add_plugins((EguiPlugin::default(), meshes::ViewMeshesPlugin, blit::ViewBlitPlugin, uploads::LiveImagesPlugin));
    // the viewer steps the simulation itself (see the module docs): Bevy's fixed clock must never do it
    app.insert_resource(Time::<Fixed>::from_seconds(1e9));
    app.add_plugins(IrSimPlugins);
    // the simulation's chain on one thread, as `irsim record` runs it (see `run_systems_in_order`)
    app.edit_schedule(FixedUpdate, |s| {
        s.set_executor(bevy::ecs::schedule::SingleThreadedExecutor::new());
    });
    let mut playback = Playback::new(scenario.spec.run.frames, rate);
    if a.frames.is_some() || a.screenshot.is_some() {
        playback.playing = true;
        playback.looping = false;
    }
    let save_path =
        format!("{}_edited.toml", if scenario.spec.name.is_empty() { "scenario" } else { &scenario.spec.name });
    let last = playback.frames - 1;
    app.insert_resource(Viewer {
        built: scenario.clone(),
        built_revision: 0,
        session: Session::new(scenario),
        options,
        selected: 0,
        new_target: edits::NewTarget::default(),
        history: plots::History::default(),
        save_path,
        save_overwrite: false,
        status: String::new(),
        target_status: String::new(),
        removed: None,
        save_status: String::new(),
        record: panels::RecordUi::new(last),
        playback,
        frame: None,
        labels: FrameLabels::default(),
        stretch: Stretch::Percentile { low: 0.5, high: 99.5 },
        color_map: ColorMap::Gray,
        boxes: true,
        zoom: 0.0,
        help: false,
        computed: 0,
        fps: 0.0,
        step_ms: 0.0,
        step_ms_total: 0.0,
        map_ms_total: 0.0,
        update_ms_total: 0.0,
        update_began: None,
        started: None,
        latest: None,
        cpu_s: (None, None),
        view_rect: [0.0; 4],
        sensor_rect: [0.0; 4],
        display_window: (0.0, 1.0),
    });
    if a.frames.is_some() || a.screenshot.is_some() {
        // --frames alone: play them, then exit
        app.insert_resource(ScreenshotPlan::new(a.frames.unwrap_or(1), a.screenshot.clone()));
    }
    app.add_systems(Startup, (setup_egui, scene::spawn_view_camera));
    app.add_systems(First, update_began);
    app.add_systems(Last, update_ended);
    app.add_systems(
        Update,
        (
            keyboard,
            drive_simulation,
            update_title,
            pace_window,
            scene::orbit_camera,
            scene::draw_encounter,
            scene::pace_view,
            meshes::sync_sky_quad,
            meshes::sync_ellipsoids,
            finish_screenshot_run.run_if(resource_exists::<ScreenshotPlan>),
        )
            .chain(),
    );
    app.add_systems(EguiPrimaryContextPass, panels::draw_panels);
    match app.run() {
        AppExit::Success => Ok(()),
        AppExit::Error(code) => Err(CliError::Failed(format!("the window closed with error {code}"))),
    }
}

fn parse_size(text: &str) -> Result<(u32, u32), CliError> {
    let bad = || CliError::Invalid(format!("--size {text}: expected WIDTHxHEIGHT, each 320 … 8192 (e.g. 1280x800)"));
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if !(320..=8192).contains(&w) || !(240..=8192).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

fn window_title(name: &str, frame: Option<u64>, t_s: f64) -> String {
    match frame {
        Some(k) => format!("irsim view — {name} — frame {k}, t = {t_s:.3} s"),
        None => format!("irsim view — {name}"),
    }
}

/// egui on the window's one camera: it clears the window to the panels' colour (the panels themselves paint no
/// background, which saves a window-sized fill under software rendering); the 3D camera's picture
/// (`scene::ViewImage`) is copied into its pass by `blit`.
fn setup_egui(mut commands: Commands, mut settings: ResMut<EguiGlobalSettings>) {
    settings.auto_create_primary_context = false;
    commands.spawn((
        bevy_egui::PrimaryEguiContext,
        Camera2d,
        Msaa::Off,
        bevy::core_pipeline::tonemapping::Tonemapping::None,
        bevy::camera::visibility::RenderLayers::none(),
        Camera { order: 1, clear_color: ClearColorConfig::Custom(scene::BACKGROUND), ..default() },
    ));
}

/// Space play/pause, arrows step, Home/End first/last frame, B boxes, H help, Escape closes help.
fn keyboard(keys: Res<ButtonInput<KeyCode>>, egui: Res<bevy_egui::input::EguiWantsInput>, mut viewer: ResMut<Viewer>) {
    if egui.wants_keyboard_input() {
        return;
    }
    let v = &mut *viewer;
    if keys.just_pressed(KeyCode::Space) {
        v.playback.toggle();
    }
    if keys.just_pressed(KeyCode::ArrowRight) {
        v.playback.step_forward();
    }
    if keys.just_pressed(KeyCode::ArrowLeft) {
        v.playback.step_back();
    }
    if keys.just_pressed(KeyCode::Home) {
        v.playback.seek(0);
    }
    if keys.just_pressed(KeyCode::End) {
        let last = v.playback.frames - 1;
        v.playback.seek(last);
    }
    if keys.just_pressed(KeyCode::KeyB) {
        v.boxes = !v.boxes;
    }
    if keys.just_pressed(KeyCode::KeyH) {
        v.help = !v.help;
    }
    if keys.just_pressed(KeyCode::Escape) {
        v.help = false;
        v.new_target.armed = false;
    }
}

/// Computes the frame the playback asks for: sets the clock to it and runs the simulation's fixed-step schedule
/// once, then takes the [`FrameReady`] it wrote.
fn drive_simulation(world: &mut World) {
    rebuild_if_edited(world);
    let elapsed = world.resource::<Time<Real>>().delta_secs_f64();
    let rate = world.resource::<Viewer>().built.spec.run.frame_rate_hz;
    let wanted = {
        let mut viewer = world.resource_mut::<Viewer>();
        if elapsed > 0.0 {
            viewer.fps = 0.9 * viewer.fps + 0.1 / elapsed;
        }
        viewer.playback.next(elapsed, rate)
    };
    let Some(k) = wanted else { return };
    world.resource_mut::<SimClock>().frame = k;
    let started = std::time::Instant::now();
    world.run_schedule(FixedUpdate);
    let step_ms = started.elapsed().as_secs_f64() * 1e3;
    let ready: Option<FrameReady> = drain_frames_world(world).pop();
    let mut viewer = world.resource_mut::<Viewer>();
    viewer.step_ms = step_ms;
    viewer.step_ms_total += step_ms;
    let now = std::time::Instant::now();
    let cpu = process_cpu_s();
    if viewer.started.is_none() {
        viewer.started = Some(now);
        viewer.cpu_s.0 = cpu;
    }
    viewer.latest = Some(now);
    viewer.cpu_s.1 = cpu;
    if let Some(ready) = ready {
        viewer.history.add(&ready.labels);
        viewer.playback.shown = Some(ready.labels.frame);
        viewer.labels = ready.labels;
        viewer.frame = Some(ready.frame);
        viewer.computed += 1;
    }
}

/// Notes when the main world's update begins (see [`Viewer::update_ms_total`]).
fn update_began(mut viewer: ResMut<Viewer>) {
    viewer.update_began = Some(std::time::Instant::now());
}

/// Adds the main world's update to [`Viewer::update_ms_total`] once frames are being counted.
fn update_ended(mut viewer: ResMut<Viewer>) {
    if let (Some(began), Some(_)) = (viewer.update_began, viewer.started) {
        viewer.update_ms_total += began.elapsed().as_secs_f64() * 1e3;
    }
}

/// Updates as fast as the window can while playing (Bevy's default caps an unfocused window, as one under Xvfb
/// always is, at 60 Hz by sleeping); paused, it redraws on input and at 30 Hz, to spare the CPU.
fn pace_window(viewer: Res<Viewer>, mut settings: ResMut<bevy::winit::WinitSettings>) {
    let busy = viewer.playback.playing || viewer.playback.request.is_some();
    let wanted = if busy {
        bevy::winit::WinitSettings::continuous()
    } else {
        let wait = std::time::Duration::from_secs_f64(1.0 / 30.0);
        bevy::winit::WinitSettings {
            focused_mode: bevy::winit::UpdateMode::reactive(wait),
            unfocused_mode: bevy::winit::UpdateMode::reactive(wait),
        }
    };
    if settings.focused_mode != wanted.focused_mode || settings.unfocused_mode != wanted.unfocused_mode {
        *settings = wanted;
    }
}

/// After an edit was put in use: the world is rebuilt from it and the frame on show computed again. One that
/// cannot be built (a sky image that cannot be calibrated in a new band, say) is refused like an invalid edit:
/// its message is shown and the last built scenario stays.
fn rebuild_if_edited(world: &mut World) {
    let (revision, built_revision) = {
        let v = world.resource::<Viewer>();
        (v.session.revision, v.built_revision)
    };
    if revision == built_revision {
        return;
    }
    let (next, options) = {
        let v = world.resource::<Viewer>();
        (v.session.applied.clone(), v.options)
    };
    despawn_scenario(world);
    let result = spawn_scenario(world, &next, options);
    match result {
        Ok(()) => world.resource_mut::<Viewer>().built = next,
        Err(e) => {
            let good = {
                let mut v = world.resource_mut::<Viewer>();
                let good = v.built.clone();
                v.session.applied = good.clone();
                v.session.draft = good.spec.clone();
                v.session.error =
                    Some(crate::scenario::FieldError { path: e.field.clone(), message: e.message.clone(), at: None });
                good
            };
            despawn_scenario(world);
            // it built before; if it no longer does, the world stays empty and the panel says why
            if let Err(e) = spawn_scenario(world, &good, options) {
                world.resource_mut::<Viewer>().status =
                    format!("the scenario no longer builds: {}: {}", e.field, e.message);
            }
        }
    }
    let mut v = world.resource_mut::<Viewer>();
    v.built_revision = revision;
    v.history.clear();
    let frames = v.built.spec.run.frames.max(1);
    v.playback.frames = frames;
    let k = v.playback.shown.unwrap_or(0).min(frames - 1);
    v.playback.seek(k);
}

fn update_title(viewer: Res<Viewer>, mut window: Single<&mut Window, With<bevy::window::PrimaryWindow>>) {
    if !viewer.is_changed() {
        return;
    }
    let title = window_title(&viewer.built.spec.name, viewer.playback.shown, viewer.labels.t_s);
    if window.title != title {
        window.title = title;
    }
}

/// After `--frames`: exits, or with `--screenshot` captures the window until the sensor image and the 3D view
/// both show something (a pipeline still compiling draws nothing), saves it with its layout beside it, and exits
/// when the file is written.
fn finish_screenshot_run(
    mut commands: Commands,
    mut plan: ResMut<ScreenshotPlan>,
    mut viewer: ResMut<Viewer>,
    window: Single<&Window, With<bevy::window::PrimaryWindow>>,
    mut exit: MessageWriter<AppExit>,
) {
    let done = viewer.computed >= plan.frames || (!viewer.playback.playing && viewer.playback.shown.is_some());
    if !done {
        return;
    }
    // hold the last of the asked frames on screen
    viewer.playback.playing = false;
    let Some(path) = plan.path.clone() else {
        summary(&viewer);
        exit.write(AppExit::Success);
        return;
    };
    plan.waited += 1;
    if plan.saved {
        summary(&viewer);
        exit.write(AppExit::Success);
        return;
    }
    if !plan.in_flight && plan.waited >= plan.capture_at {
        plan.in_flight = true;
        plan.tries += 1;
        let s = window.scale_factor();
        let physical = |r: [f32; 4]| r.map(|v| (v * s).round());
        let (sensor, view) = (physical(viewer.sensor_rect), physical(viewer.view_rect));
        // where things are in the picture, for whoever checks it
        let layout = serde_json::json!({
            "frame": viewer.playback.shown,
            "scale_factor": s,
            "sensor_rect_px": sensor,
            "view_rect_px": view,
            "display_window_dn": [viewer.display_window.0, viewer.display_window.1],
            "stretch": format!("{:?}", viewer.stretch),
        });
        let last_try = plan.tries >= SCREENSHOT_TRIES;
        let path = path.clone();
        commands.spawn(Screenshot::primary_window()).observe(
            move |captured: On<ScreenshotCaptured>,
                  mut plan: ResMut<ScreenshotPlan>,
                  mut exit: MessageWriter<AppExit>| {
                plan.in_flight = false;
                let picture = match captured.image.clone().try_into_dynamic() {
                    Ok(p) => p.to_rgb8(),
                    Err(e) => {
                        eprintln!("error: the screenshot cannot be read: {e}");
                        exit.write(AppExit::error());
                        return;
                    }
                };
                let ready = shows_something(&picture, sensor) && shows_something(&picture, view);
                if !(ready || last_try) {
                    plan.capture_at = plan.waited + SCREENSHOT_RETRY_FRAMES;
                    return;
                }
                let sidecar = path.with_extension("json");
                let written = picture.save(&path).map_err(|e| format!("{}: {e}", path.display())).and_then(|()| {
                    std::fs::write(&sidecar, format!("{layout:#}\n")).map_err(|e| format!("{}: {e}", sidecar.display()))
                });
                match written {
                    Ok(()) => plan.saved = true,
                    Err(e) => {
                        eprintln!("error: writing the screenshot: {e}");
                        exit.write(AppExit::error());
                    }
                }
            },
        );
    }
    if plan.waited > SCREENSHOT_TRIES * SCREENSHOT_RETRY_FRAMES + 600 {
        eprintln!("error: the screenshot {} was not written", path.display());
        exit.write(AppExit::error());
    }
}

/// Whether the rectangle `r` (physical px: min x, min y, max x, max y) of `picture` is more than one flat colour.
fn shows_something(picture: &image::RgbImage, r: [f32; 4]) -> bool {
    let (w, h) = (picture.width() as f32, picture.height() as f32);
    let (x0, y0) = (r[0].clamp(0.0, w) as u32, r[1].clamp(0.0, h) as u32);
    let (x1, y1) = (r[2].clamp(0.0, w) as u32, r[3].clamp(0.0, h) as u32);
    let mut first = None;
    for y in y0..y1 {
        for x in x0..x1 {
            let p = picture.get_pixel(x, y).0;
            match first {
                None => first = Some(p),
                Some(q) if p.iter().zip(q).any(|(a, b)| a.abs_diff(b) > 8) => return true,
                Some(_) => {}
            }
        }
    }
    false
}

/// Prints how fast the window ran: frames shown per second since the first, and the simulation's share.
fn summary(viewer: &Viewer) {
    let (Some(started), Some(latest)) = (viewer.started, viewer.latest) else { return };
    let seconds = (latest - started).as_secs_f64();
    let n = viewer.computed;
    if n > 1 && seconds > 0.0 {
        let per_frame_ms = seconds * 1e3 / (n - 1) as f64;
        let (sim, map) = (viewer.step_ms_total / n as f64, viewer.map_ms_total / n as f64);
        let update = viewer.update_ms_total / n as f64;
        let cpu = match viewer.cpu_s {
            (Some(a), Some(b)) => format!(
                "; CPU {:.1} ms per frame ({:.2} cores busy)",
                (b - a) * 1e3 / (n - 1) as f64,
                (b - a) / seconds
            ),
            _ => String::new(),
        };
        eprintln!(
            "{n} frames shown in {seconds:.2} s: {:.1} frames/s, {per_frame_ms:.1} ms per frame: the main world's \
             update {update:.1} ms (simulation {sim:.1} ms, display mapping {map:.1} ms, egui and the rest {:.1} ms), \
             then {:.1} ms handing over to the renderer and waiting for it{cpu}",
            (n - 1) as f64 / seconds,
            update - sim - map,
            per_frame_ms - update
        );
    }
}

/// CPU seconds this process has used, all threads (Linux: /proc/self/stat; None elsewhere).
fn process_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // the fields after the command name, which ends at the last ')': utime and stime are the 12th and 13th
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    // the kernel's USER_HZ, 100 on every Linux this runs on
    Some(ticks / 100.0)
}
