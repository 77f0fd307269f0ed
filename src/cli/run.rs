//! `irsim record`, `irsim validate`, `irsim sky` and `irsim bench`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use clap::{Args, ValueEnum};
use serde_json::json;

use super::CliError;
use crate::imaging::frame::{Frame, PngCompression};
use crate::imaging::sky_gen::{SkyGenSpec, SkyKind, generate};
use crate::record::{FrameFormat, Recorder, prepare_dir, write_atomic};
use crate::scenario::load::{load_for_frames, located};
use crate::scenario::{CheckedScenario, QualityPreset, QualitySpec, load};
use crate::sim::{
    FrameReady, RunOptions, SensorFrame, SimClock, StageTimings, drain_frames, headless_app, set_stop_flag, step,
    with_workers_awake_and,
};

/// Flags of `irsim record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Scenario file (TOML, or JSON by extension).
    pub scenario: PathBuf,
    /// Output directory; refused if not empty unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Number of frames (default: the scenario's).
    #[arg(long)]
    pub frames: Option<u64>,
    /// Seed (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Replace the outputs of an earlier run in --out.
    #[arg(long)]
    pub force: bool,
    /// No sensor noise.
    #[arg(long)]
    pub no_noise: bool,
    /// No camera vibration.
    #[arg(long)]
    pub no_vibration: bool,
    /// Frame file format.
    #[arg(long, value_enum, default_value = "png16")]
    pub format: FrameFormat,
    /// How hard 16-bit PNG frames are compressed: the same pixels at every level (the README measures size
    /// against speed).
    #[arg(long, value_enum, default_value = "fast")]
    pub png_compression: PngCompression,
    /// Also write per-frame target masks (8-bit PNG, pixel = target id, 0 = sky).
    #[arg(long)]
    pub masks: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Accuracy against speed: draft, standard or reference, in place of the scenario's `[quality]` table.
    #[arg(long, value_name = "PRESET")]
    pub quality: Option<QualityPreset>,
}

/// Flags of `irsim validate`.
#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Scenario file.
    pub scenario: PathBuf,
}

/// Kind of generated sky.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum SkyKindArg {
    /// A clear sky with a faint haze texture.
    Clear,
    /// Broken cumulus.
    Cumulus,
}

/// Flags of `irsim sky`.
#[derive(Debug, Args)]
pub struct SkyArgs {
    /// Kind of sky.
    #[arg(long, value_enum)]
    pub kind: SkyKindArg,
    /// Output PNG (16-bit, brightness temperature at 0.01 K per level).
    #[arg(long)]
    pub out: PathBuf,
    /// Width, px.
    #[arg(long, default_value_t = 1024)]
    pub width: usize,
    /// Height, px.
    #[arg(long, default_value_t = 1024)]
    pub height: usize,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Cloud cover, [0, 1] (cumulus).
    #[arg(long, default_value_t = 0.45)]
    pub cover: f64,
    /// Slope of the layer's power spectrum ([−3.06, −2.39] cumulus, [−4.5, −1.5] clear).
    #[arg(long, default_value_t = -3.0, allow_negative_numbers = true)]
    pub psd_slope: f64,
    /// Largest features as a fraction of the width, (0, 1].
    #[arg(long, default_value_t = 0.25)]
    pub scale: f64,
    /// Elevation of the top row, degrees.
    #[arg(long, default_value_t = 12.0, allow_negative_numbers = true)]
    pub elevation_top_deg: f64,
    /// Elevation of the bottom row, degrees.
    #[arg(long, default_value_t = -2.0, allow_negative_numbers = true)]
    pub elevation_bottom_deg: f64,
    /// Spectral band, µm: LO HI.
    #[arg(long, num_args = 2, value_names = ["LO", "HI"], default_values_t = [8.0, 12.0])]
    pub band_um: Vec<f64>,
    /// Observer altitude, m.
    #[arg(long, default_value_t = 1000.0, allow_negative_numbers = true)]
    pub altitude_m: f64,
    /// Distance to the clouds, km.
    #[arg(long, default_value_t = 8.0)]
    pub cloud_range_km: f64,
    /// Sea-level air temperature, K.
    #[arg(long, default_value_t = 288.15)]
    pub t0_k: f64,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
}

/// Flags of `irsim bench`.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct BenchArgs {
    /// `report`: speed against error of every preset and switch, as Markdown and plots.
    #[command(subcommand)]
    pub command: Option<BenchCommand>,
    /// Scenario files to time (headless, no disk) instead of the built-in cases.
    pub scenarios: Vec<PathBuf>,
    /// Frames timed per case. A scenario file's own frames are run, and run again from its first frame until
    /// this many are timed, so that the rate is that of the scenario as written (its targets in view, and its
    /// sky, as they are when it is recorded), not of a run stretched past its end; where the sky's blur is
    /// planned (`[quality] sky_blur = "auto"`, the draft preset's: textures made once, or a blur every frame),
    /// it is planned for every frame rendered, the first pass's textures serving the passes after it.
    #[arg(long, default_value_t = 2000)]
    pub frames: u64,
    /// Accuracy against speed: draft, standard or reference, in place of each scenario's `[quality]` table.
    #[arg(long, value_name = "PRESET")]
    pub quality: Option<QualityPreset>,
    /// Per-pixel lower bounds (store, bilinear sample, normal deviate, readout, all fused) measured beside the
    /// pipeline's stages at 256×256 (one target) and 640×512 (one target, and ten) on 1 and 2 threads, with the
    /// ratios.
    #[arg(long, conflicts_with_all = ["scenarios", "quality"])]
    pub limits: bool,
}

/// What `irsim bench` can do besides timing.
#[derive(Debug, clap::Subcommand)]
pub enum BenchCommand {
    /// Measure every quality preset and switch against `reference` and write speed_vs_error.md with PNG plots.
    Report(super::report::ReportArgs),
}

fn load_scenario(path: &Path) -> Result<CheckedScenario, CliError> {
    load(path).map_err(|e| CliError::Invalid(e.to_string()))
}

/// `--quality PRESET`: `scenario` with its `[quality]` table replaced by the preset alone (a note on stderr
/// names the file's overrides that are dropped); unchanged without the flag.
///
/// # Errors
/// [`CliError::Invalid`] if the scenario does not check with the preset.
pub fn with_quality(scenario: CheckedScenario, preset: Option<QualityPreset>) -> Result<CheckedScenario, CliError> {
    let Some(preset) = preset else { return Ok(scenario) };
    let dropped = scenario.spec.quality.overrides();
    if !dropped.is_empty() {
        eprintln!(
            "note: --quality {}: the [quality] overrides of {} are not used: {}",
            preset.name(),
            scenario.source.display(),
            dropped.join(", ")
        );
    }
    with_quality_spec(&scenario, QualitySpec::of(preset))
}

/// `scenario` with its `[quality]` table replaced by `quality`, checked again.
///
/// # Errors
/// [`CliError::Invalid`] if the scenario does not check with it.
pub fn with_quality_spec(scenario: &CheckedScenario, quality: QualitySpec) -> Result<CheckedScenario, CliError> {
    let mut spec = scenario.spec.clone();
    spec.quality = quality;
    let base = scenario.source.parent().map(Path::to_path_buf).unwrap_or_default();
    spec.checked_in(&scenario.source, &base)
        .map_err(|e| CliError::Invalid(located(&scenario.source, &e.path, &e.message).to_string()))
}

/// `irsim validate`: loads and checks the scenario and builds its simulation without running it.
///
/// # Errors
/// [`CliError::Invalid`] with the located error.
pub fn validate(a: &ValidateArgs) -> Result<(), CliError> {
    let s = load_scenario(&a.scenario)?;
    let mut app = headless_app(&s, RunOptions::default())
        .map_err(|e| CliError::Invalid(located(&a.scenario, &e.field, &e.message).to_string()))?;
    let mut text = format!(
        "{}: ok ({} targets, {} frames of {}×{} at {} Hz)\n",
        a.scenario.display(),
        s.spec.targets.len(),
        s.spec.run.frames,
        s.sensor.intrinsics.width,
        s.sensor.intrinsics.height,
        s.spec.run.frame_rate_hz
    );
    text.push_str(&format!("atmosphere: {}\n", describe_atmosphere(&s.spec.atmosphere)));
    let resolved = resolved_settings(&mut app, &s);
    let given = s.spec.quality.overrides();
    text.push_str("[quality] as resolved (* = given in the file):");
    for (name, value, _) in s.quality.describe() {
        text.push_str(&format!("\n  {}{name} = {value}", if given.contains(&name) { "*" } else { " " }));
    }
    if let Some(choice) =
        resolved["sky_blur_used"].as_str().filter(|_| s.spec.sky.has_layer() && s.sensor.psf.is_some())
    {
        text.push_str(&format!("\n  sky blur used: {choice}"));
    }
    super::say(&text)
}

/// The scenario's atmosphere in a line: the LOWTRAN weather or the override.
pub fn describe_atmosphere(a: &crate::scenario::AtmosphereSpec) -> String {
    use crate::physics::lowtran::Aerosol;
    use crate::physics::transmittance::Transmittance;
    match (a.weather(), a.override_transmittance()) {
        (Some(w), _) if w.aerosol == Aerosol::None => {
            format!("LOWTRAN7, {} model atmosphere, no aerosol", w.model.name())
        }
        (Some(w), _) => format!(
            "LOWTRAN7, {} model atmosphere, {} aerosol at {} km visibility",
            w.model.name(),
            w.aerosol.name(),
            crate::physics::Num(w.visibility_km)
        ),
        (None, Transmittance::Fixed { tau }) => format!("fixed transmittance {}", crate::physics::Num(tau)),
        (None, Transmittance::BeerLambert { extinction_per_km, scale_height_km }) => format!(
            "Beer–Lambert, {} per km at sea level, scale height {} km",
            crate::physics::Num(extinction_per_km),
            crate::physics::Num(scale_height_km)
        ),
    }
}

/// `irsim record`.
///
/// # Errors
/// [`CliError::Invalid`] for a bad scenario or a non-empty output directory; [`CliError::Failed`] for a write
/// error during the run.
pub fn record(a: &RecordArgs) -> Result<(), CliError> {
    if let Some(n) = a.frames
        && !(1..=100_000_000).contains(&n)
    {
        return Err(CliError::Invalid(format!("--frames {n} must be in 1 … 100000000")));
    }
    let scenario = load_for_frames(&a.scenario, a.frames).map_err(|e| CliError::Invalid(e.to_string()))?;
    let scenario = with_quality(scenario, a.quality)?;
    let plan = record_plan(a, scenario.spec.run.frames);
    let (stop, bar) = stop_flag_and_bar(a.quiet, plan.frames);
    let done = record_scenario(&scenario, &plan, &stop, &mut |written, _| bar.set_position(written));
    bar.finish_and_clear();
    let done = done?;
    eprintln!("{}", done.summary);
    if let Some(note) = done.steal_share.and_then(super::steal::note_for_share) {
        eprintln!("{note}");
    }
    if done.interrupted {
        return Err(CliError::Interrupted);
    }
    Ok(())
}

/// A flag that Ctrl-C sets, and a progress bar over `frames` frames (hidden with `quiet`; it shows its message
/// after the rate).
pub(super) fn stop_flag_and_bar(quiet: bool, frames: u64) -> (Arc<AtomicBool>, indicatif::ProgressBar) {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        // a second handler cannot be installed in the same process (tests run record twice); ignore that
        let _ = ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst));
    }
    let bar = if quiet {
        indicatif::ProgressBar::hidden()
    } else {
        let b = indicatif::ProgressBar::new(frames);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} frames, {per_sec}, eta {eta} {msg}")
                .expect("valid template"),
        );
        b
    };
    (stop, bar)
}

/// What [`record_scenario`] writes: the flags of `irsim record`, and the frames `first_frame ..
/// first_frame + frames` (written as 000000, 000001, … with their true frame index in the labels).
#[derive(Debug, Clone)]
pub struct RecordPlan {
    /// Output directory; refused if not empty unless `force`.
    pub out: PathBuf,
    /// The first frame's index.
    pub first_frame: u64,
    /// How many frames.
    pub frames: u64,
    /// Seed (default: the scenario's).
    pub seed: Option<u64>,
    /// Replace the outputs of an earlier run.
    pub force: bool,
    /// Sensor noise.
    pub noise: bool,
    /// Camera vibration.
    pub vibration: bool,
    /// Frame file format.
    pub format: FrameFormat,
    /// 16-bit PNG compression.
    pub png: PngCompression,
    /// Per-frame target masks.
    pub masks: bool,
    /// A manifest with nothing that depends on the machine or the moment (no timings), so that the same
    /// scenario gives the same bytes anywhere: what a dataset's sequences are recorded with.
    pub reproducible: bool,
}

/// How a recording ended.
#[derive(Debug, Clone)]
pub struct RecordDone {
    /// `complete: 10 of 10 frames written to DIR (41.3 frames/s)` or the like.
    pub summary: String,
    /// Stopped by the flag before the last frame.
    pub interrupted: bool,
    /// Frames written per second of the recording loop (from the first frame to the last file in place; the
    /// scenario's set-up not counted, as `irsim bench` does not count it for a run without disk writes).
    pub frames_per_s: f64,
    /// The share of the machine's CPU time its host took during the recording loop (steal time, 0 to 1), where
    /// the system counts it.
    pub steal_share: Option<f64>,
}

/// What `irsim record` with `a` writes, for a run of `frames` frames.
fn record_plan(a: &RecordArgs, frames: u64) -> RecordPlan {
    RecordPlan {
        out: a.out.clone(),
        first_frame: 0,
        frames,
        seed: a.seed,
        force: a.force,
        noise: !a.no_noise,
        vibration: !a.no_vibration,
        format: a.format,
        png: a.png_compression,
        masks: a.masks,
        reproducible: false,
    }
}

/// Records `scenario` as `plan` says: what `irsim record` does, for any front end. `progress(written, total)` is
/// called after each frame; setting `stop` ends the run after the frame in hand (the directory says so).
///
/// # Errors
/// [`CliError::Invalid`] for a simulation that cannot be built or a non-empty output directory;
/// [`CliError::Failed`] for a write error during the run.
pub fn record_scenario(
    scenario: &CheckedScenario,
    plan: &RecordPlan,
    stop: &Arc<AtomicBool>,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<RecordDone, CliError> {
    let frames = plan.frames;
    let options = RunOptions {
        seed: plan.seed,
        noise: plan.noise,
        vibration: plan.vibration,
        keep_float: plan.format == FrameFormat::Npy,
        masks: plan.masks,
        whole_background: false,
        timings: true,
        replayed_to: None,
    };
    let setting_up = Instant::now();
    let mut app = headless_app(scenario, options)
        .map_err(|e| CliError::Invalid(located(&scenario.source, &e.field, &e.message).to_string()))?;
    // the world's set-up (atmosphere tables, sky, PSFs): a short run's wall time is mostly this
    let setup_s = setting_up.elapsed().as_secs_f64();
    let _lock = prepare_dir(&plan.out, plan.force).map_err(|e| match e {
        crate::record::RecordError::NotEmpty(_)
        | crate::record::RecordError::NotADirectory(_)
        | crate::record::RecordError::Locked(..) => CliError::Invalid(e.to_string()),
        other => CliError::Failed(other.to_string()),
    })?;
    let seed = plan.seed.unwrap_or(scenario.spec.run.seed);
    // the scenario as the world was built from it: its run's length stays (the sky is planned over the whole
    // run), and frames written from a part of it are said by `first_frame` and `frames` below
    let mut spec_as_run = scenario.spec.clone();
    spec_as_run.run.seed = seed;
    let mut manifest = json!({
        "program": "irsim",
        "version": env!("CARGO_PKG_VERSION"),
        "scenario_file": scenario.source.display().to_string(),
        "scenario": spec_as_run,
        "seed": seed,
        "options": {
            "noise": plan.noise,
            "vibration": plan.vibration,
            "format": plan.format,
            "png_compression": plan.png,
            "masks": plan.masks,
        },
        "resolved": resolved_settings(&mut app, scenario),
    });
    if plan.first_frame > 0 || frames != scenario.spec.run.frames {
        manifest["first_frame"] = json!(plan.first_frame);
        manifest["frames"] = json!(frames);
        app.world_mut().resource_mut::<SimClock>().frame = plan.first_frame;
    }
    let max_level = scenario.sensor.model.adc.max_level() as u16;
    // at most twice the pool's size of frames out at once (not the machine's cores: a smaller pool holds fewer)
    let threads = rayon::current_num_threads().max(2);
    let mut rec = Recorder::new(&plan.out, (plan.format, plan.png), plan.masks, max_level, threads, manifest, frames)
        .map_err(|e| CliError::Failed(e.to_string()))?;
    set_stop_flag(&mut app, Arc::clone(stop));
    // the pool's workers encode waiting frames when the frame's stages leave them idle; they are kept awake for
    // the whole loop, not frame by frame: woken for each frame, a worker went to sleep in the gaps between
    // frames (the recorder's own work, a frame this thread encodes when too many wait) about once every four
    // frames at 256 × 256 (930 sleeps in 4000 frames) and stayed idle until the next frame woke it
    let idle = rec.idle_work();
    let started = Instant::now();
    let steal_since = super::steal::CpuTicks::now();
    let interrupted = with_workers_awake_and(idle.as_ref(), || {
        record_frames(&mut app, &mut rec, (plan.format, frames), stop, progress)
    });
    let elapsed = started.elapsed().as_secs_f64();
    // the CPU time the machine's host took meanwhile (steal time; absent where not counted)
    let counted = super::steal::CpuTicks::since(steal_since);
    let steal = counted.and_then(|c| c.share());
    if let Some(t) = app.world().get_resource::<StageTimings>().filter(|_| !plan.reproducible) {
        let stages: serde_json::Map<String, serde_json::Value> =
            t.mean_ms().into_iter().map(|(k, v)| (k.to_owned(), json!(v))).collect();
        let mut timings = json!({ "setup_s": setup_s, "wall_s": elapsed, "stage_ms_per_frame": stages });
        if let Some(c) = counted {
            timings["host_cpu_ticks"] = json!({ "total": c.total, "steal": c.steal });
        }
        if let Some(share) = steal {
            timings["host_steal_share"] = json!(share);
        }
        rec.set_manifest("timings", timings);
    }
    let progress = rec.finish(interrupted).map_err(|e| CliError::Failed(format!("recording stopped: {e}")))?;
    // the rate counts the files still in the encoders' hands and the last sync
    let elapsed = started.elapsed().as_secs_f64();
    let frames_per_s = progress.frames_written as f64 / elapsed.max(1e-9);
    let summary = format!(
        "{}: {} of {} frames written to {} ({frames_per_s:.1} frames/s, after {setup_s:.2} s of set-up)",
        progress.status,
        progress.frames_written,
        progress.frames_requested,
        plan.out.display(),
    );
    Ok(RecordDone { summary, interrupted, frames_per_s, steal_share: steal })
}

/// `irsim sky`: writes a generated 16-bit sky.
///
/// # Errors
/// [`CliError::Invalid`] for bad sizes or an existing file without --force; [`CliError::Failed`] on a write
/// error.
pub fn sky(a: &SkyArgs) -> Result<(), CliError> {
    write_sky(a)?;
    super::say(&format!("{}\ncalibration = {{ mode = \"kelvin\", scale_k = 0.01 }}", a.out.display()))
}

/// Generates the sky `a` describes and writes it to `a.out`.
fn write_sky(a: &SkyArgs) -> Result<(), CliError> {
    use crate::imaging::sky_field::RadianceLut;
    use crate::physics::planck::{Band, Measure, brightness_temperature};
    use crate::physics::sky::{Dome, DomeInputs, DomeSpec};
    use crate::physics::transmittance::{PathTransmittance, Transmittance};
    if !(1..=16384).contains(&a.width) || !(1..=16384).contains(&a.height) {
        return Err(CliError::Invalid("--width and --height must be in 1 … 16384".into()));
    }
    let kind = match a.kind {
        SkyKindArg::Clear => SkyKind::Clear,
        SkyKindArg::Cumulus => SkyKind::Cumulus,
    };
    let spec =
        SkyGenSpec { seed: a.seed, cover: a.cover, psd_slope: a.psd_slope, scale: a.scale, ..SkyGenSpec::new(kind) };
    spec.validate().map_err(|e| {
        CliError::Invalid(format!("--{}: {} is outside {}", e.name.replace('_', "-"), e.value, e.range))
    })?;
    let (top, bottom) = (a.elevation_top_deg, a.elevation_bottom_deg);
    if !(top.is_finite()
        && bottom.is_finite()
        && (-90.0..=90.0).contains(&top)
        && (-90.0..=90.0).contains(&bottom)
        && top > bottom)
    {
        return Err(CliError::Invalid(
            "--elevation-top-deg must exceed --elevation-bottom-deg, both in [−90, 90]".into(),
        ));
    }
    let band = match a.band_um.as_slice() {
        [lo, hi] => Band::try_new(*lo, *hi).map_err(|e| CliError::Invalid(format!("--band-um: {e}")))?,
        _ => return Err(CliError::Invalid("--band-um takes two values".into())),
    };
    if !(a.altitude_m.is_finite() && (0.0..=20_000.0).contains(&a.altitude_m)) {
        return Err(CliError::Invalid(format!("--altitude-m {} must be in [0, 20000]", a.altitude_m)));
    }
    if !(a.cloud_range_km.is_finite() && a.cloud_range_km > 0.0 && a.cloud_range_km <= 200.0) {
        return Err(CliError::Invalid(format!("--cloud-range-km {} must be in (0, 200]", a.cloud_range_km)));
    }
    if !(a.t0_k.is_finite() && a.t0_k > 200.0 && a.t0_k < 330.0) {
        return Err(CliError::Invalid(format!("--t0-k {} must be in (200, 330)", a.t0_k)));
    }
    if a.out.exists() && !a.force {
        return Err(CliError::Invalid(format!("{} exists; use --force to replace it", a.out.display())));
    }
    let atmosphere = Transmittance::default();
    let dome = Dome::new(&DomeInputs {
        spec: DomeSpec::default(),
        band,
        measure: Measure::Energy,
        observer_altitude_m: a.altitude_m,
        air: crate::physics::atmosphere::AirTemperature::Standard { t0_k: a.t0_k },
        atmosphere: &atmosphere,
        zenith_emissivity: None,
        clear_sky: None,
    })
    .map_err(|e| CliError::Invalid(format!("{}: {}", e.name, e.range)))?;
    let lut = RadianceLut::new(band, Measure::Energy, crate::scenario::Quality::default().radiance_table_step_k);
    let layer = generate(&spec, a.width, a.height);
    let air =
        |z: f64| crate::physics::atmosphere::ambient_temperature_k(z.clamp(0.0, 80_000.0), a.t0_k).unwrap_or(a.t0_k);
    let range_m = a.cloud_range_km * 1000.0;
    let eye = glam::DVec3::new(0.0, 0.0, a.altitude_m);
    // rows side by side; a row's cloudless pixels are its clear sky, whose temperature (the inversion of the
    // band radiance, most of the time) is found once
    use rayon::prelude::*;
    let mut pixels = vec![0.0f32; a.width * a.height];
    pixels.par_chunks_mut(a.width).enumerate().for_each(|(y, row)| {
        let e = (top + (bottom - top) * (y as f64 + 0.5) / a.height as f64).to_radians();
        let dir = glam::DVec3::new(0.0, e.cos(), e.sin());
        let clear = f64::from(dome.radiance_toward(dir));
        let cloud_at = eye + dir * range_m;
        let tau = atmosphere.along_segment(eye, cloud_at);
        let path = (1.0 - tau) * lut.radiance(air(0.5 * (eye.z + cloud_at.z)));
        let level = |l: f64| (brightness_temperature(Measure::Energy, band, l).unwrap_or(0.0) * 100.0).round() as f32;
        let clear_level = level(clear);
        for (x, p) in row.iter_mut().enumerate() {
            let i = y * a.width + x;
            let alpha = f64::from(layer.opacity[i]);
            *p = if alpha == 0.0 {
                clear_level
            } else {
                let cloud = tau * lut.radiance(air(cloud_at.z) + f64::from(layer.temp_offset_k[i])) + path;
                level(alpha * cloud + (1.0 - alpha) * clear)
            };
        }
    });
    let frame = Frame::from_pixels(a.width, a.height, pixels);
    let mut bytes = Vec::new();
    frame.write_png16(u16::MAX, &mut bytes).map_err(|e| CliError::Failed(e.to_string()))?;
    write_atomic(&a.out, &bytes).map_err(|e| CliError::Failed(e.to_string()))
}

/// A temporary directory, removed with what it holds when dropped (also when a measurement in it fails).
pub(super) struct BenchDir(PathBuf);

impl std::ops::Deref for BenchDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for BenchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A fresh temporary directory holding the sky image `clear.png` that [`bench_scenario`] files refer to,
/// removed when the returned guard is dropped.
///
/// # Errors
/// [`CliError::Failed`] if it cannot be written.
pub(super) fn bench_dir(name: &str) -> Result<BenchDir, CliError> {
    let dir = std::env::temp_dir().join(format!("irsim-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| CliError::Failed(e.to_string()))?;
    // removed from here on, whatever happens
    let dir = BenchDir(dir);
    write_sky(&SkyArgs {
        kind: SkyKindArg::Clear,
        out: dir.join("clear.png"),
        width: 512,
        height: 512,
        seed: 1,
        cover: 0.45,
        psd_slope: -3.0,
        scale: 0.25,
        elevation_top_deg: 12.0,
        elevation_bottom_deg: -2.0,
        band_um: vec![8.0, 12.0],
        altitude_m: 8000.0,
        cloud_range_km: 30.0,
        t0_k: 288.15,
        force: true,
    })?;
    Ok(dir)
}

/// Targets of `irsim bench`'s built-in 640 × 512 case: as many as the swarm scenario flies.
pub(super) const WIDE_CASE_TARGETS: usize = 10;

/// A scenario of `targets` targets circling in the view of a `width` × `height` paper camera, against the sky
/// of [`bench_dir`].
pub(super) fn bench_scenario(width: u32, height: u32, targets: usize) -> String {
    let mut s = format!(
        r#"
name = "bench_{width}x{height}_{targets}"
[run]
frame_rate_hz = 30
frames = 1000
seed = 1
[sensor]
width = {width}
height = {height}
preset = "paper_lwir_256"
pixel_pitch_um = 17
focal_length_mm = 100
aperture_mm = 100
band_um = [8, 12]
[observer]
trajectory = {{ kind = "constant_velocity", position_m = [0, 0, 8000] }}
pointing = {{ mode = "look_at", target_m = [0, 30000, 7000] }}
vibration = {{ amplitude_deg = 0.05, cutoff_hz = 5 }}
[sky]
image = "clear.png"
calibration = {{ mode = "kelvin", scale_k = 0.01 }}
anchor_m = [0, 30000, 6000]
width_m = 4000
height_m = 4000
"#
    );
    for i in 0..targets {
        // each target circles a point in the field of view, so it stays visible however long the run
        let dx = (i as f64 - (targets as f64 - 1.0) / 2.0) * 120.0;
        s.push_str(&format!(
            "[[targets]]\nname = \"t{i}\"\ntrajectory = {{ kind = \"coordinated_turn\", center_m = [{dx}, 20000, {}], radius_m = 40, speed_m_s = 60, start_bearing_deg = {} }}\nsemi_axes_m = [6, 1.5, 1.5]\n",
            7330.0 + 15.0 * i as f64,
            45 * i
        ));
    }
    s
}

/// Where a headless run's time went: the mean wall time of a frame and of each stage, µs.
#[derive(Debug, Clone)]
pub(super) struct StageSplit {
    /// Wall time per frame, the schedule's own time included.
    pub frame_us: f64,
    /// Per stage, in [`crate::sim::StageTimings::NAMES`]' order (the radiometry's is its own time, within the
    /// render's; the targets' includes their shapes' time, within the render's too).
    pub stages_us: Vec<(&'static str, f64)>,
}

impl StageSplit {
    /// The mean µs of stage `name` (0 for an unknown name).
    pub fn stage_us(&self, name: &str) -> f64 {
        self.stages_us.iter().find(|(n, _)| *n == name).map_or(0.0, |s| s.1)
    }
}

/// Frames [`run_timed`] runs before it starts the clock.
const WARM_UP_FRAMES: u64 = 10;

/// Runs `scenario` headless without disk writes for `frames` frames after [`WARM_UP_FRAMES`]; `each` sees the
/// app after every timed frame. After frame `period − 1` the run starts again from its first frame (every
/// stage's state is a function of the frame's index and time), so that a scenario is timed on its own `period`
/// frames however many are timed; where more are timed than it has, its sky's blur, where it is planned, is
/// planned for every render ([`RunOptions::replayed_to`]), the textures a prefiltered sky makes on its first pass
/// serving the passes after it.
fn run_timed(
    scenario: &CheckedScenario,
    frames: u64,
    period: u64,
    mut each: impl FnMut(&mut bevy::app::App),
) -> Result<(StageSplit, bevy::app::App), CliError> {
    // a run replayed past its own frames: the sky's blur, where it is planned, planned for every render
    let replayed_to = (frames > period).then_some(frames.saturating_add(WARM_UP_FRAMES));
    let options = RunOptions { timings: true, replayed_to, ..RunOptions::default() };
    let mut app = headless_app(scenario, options)
        .map_err(|e| CliError::Invalid(located(&scenario.source, &e.field, &e.message).to_string()))?;
    let period = period.max(1);
    let replay = |app: &mut bevy::app::App| {
        let mut clock = app.world_mut().resource_mut::<SimClock>();
        if clock.frame >= period {
            clock.frame = 0;
        }
    };
    for _ in 0..WARM_UP_FRAMES {
        replay(&mut app);
        step(&mut app);
    }
    app.world_mut().insert_resource(StageTimings::default());
    let t = Instant::now();
    for _ in 0..frames {
        replay(&mut app);
        step(&mut app);
        each(&mut app);
    }
    let frame_us = t.elapsed().as_secs_f64() * 1e6 / frames.max(1) as f64;
    let stages_us = app
        .world()
        .get_resource::<StageTimings>()
        .map(|t| t.mean_ms().into_iter().map(|(n, ms)| (n, ms * 1e3)).collect())
        .unwrap_or_default();
    Ok((StageSplit { frame_us, stages_us }, app))
}

/// [`run_timed`] without looking at the frames.
pub(super) fn time_stages(scenario: &CheckedScenario, frames: u64) -> Result<StageSplit, CliError> {
    run_timed(scenario, frames, scenario.spec.run.frames, |_| {}).map(|(split, _)| split)
}

/// Frames per second of `scenario` run headless without disk writes, over `frames` frames after 10 warm-up
/// frames, its first `period` replayed ([`run_timed`]), and lines on where the time went (per stage, the sky
/// blur).
fn time_headless(scenario: &CheckedScenario, frames: u64, period: u64) -> Result<(f64, Vec<String>), CliError> {
    let (mut needed, mut blurred, mut prefiltered, mut builds, mut shifted) = (0.0, 0.0, 0.0, 0, 0u64);
    let mut plan = None;
    // the query made once: making it is ~0.6 µs, which the timed loop would count every frame
    let mut query = None;
    let (split, _) = run_timed(scenario, frames, period, |app| {
        let q = query.get_or_insert_with(|| app.world_mut().query::<(&crate::sim::Sensor, &SensorFrame)>());
        if let Some((sensor, sf)) = q.iter(app.world()).next() {
            plan = Some((sensor.sky_blur, sensor.sky_blur_plan));
            let b = &sf.background_stats.blur;
            needed += b.tiles_needed as f64 / b.tiles.max(1) as f64;
            blurred += b.tiles_blurred as f64 / b.tiles.max(1) as f64;
            prefiltered += sf.background_stats.tiles_prefiltered as f64 / b.tiles.max(1) as f64;
            builds = sf.background_stats.texture_builds;
            shifted += u64::from(sf.shifted_view().is_some());
        }
    })?;
    let fps = 1e6 / split.frame_us;
    let mut details = Vec::new();
    // the radiometry runs beside the render: its time is its own, inside the render's; so do the targets'
    // shapes, whose time is part of the targets'
    let stages: Vec<String> = split
        .stages_us
        .iter()
        .map(|(name, us)| match *name {
            "radiometry" => format!("{name} {us:.0} (beside the render)"),
            "targets" => format!("{name} {us:.0} (shapes beside the render)"),
            _ => format!("{name} {us:.0}"),
        })
        .collect();
    details.push(format!(
        "  stage µs per frame: {}; background: {:.0} % of the frame from the prefiltered sky ({builds} \
         textures made), per-frame blur needed on {:.0} %, applied on {:.0} %",
        stages.join(", "),
        100.0 * prefiltered / frames as f64,
        100.0 * needed / frames as f64,
        100.0 * blurred / frames as f64
    ));
    if shifted > 0 {
        details.push(format!(
            "  views read shifted from one render of the steady view ([quality] view_shift_tolerance_px): {:.0} %",
            100.0 * shifted as f64 / frames as f64
        ));
    }
    if let Some((choice, plan)) = plan {
        let why = plan.map_or_else(String::new, |p| {
            format!(
                " (planned: {} texture builds for {} of {} views, {:.2e} multiply–adds against {:.2e} for frame blurs)",
                p.texture_builds, p.views_prefiltered, p.views, p.texture_work, p.frame_work
            )
        });
        let name = serde_json::to_value(choice).ok().and_then(|v| v.as_str().map(str::to_owned)).unwrap_or_default();
        details.push(format!("  sky blur: {name}{why}"));
    }
    Ok((fps, details))
}

/// `irsim bench`: frames per second of the whole pipeline without disk writes, and with 16-bit PNG recording,
/// on built-in cases or on the scenarios given.
///
/// # Errors
/// [`CliError::Failed`] if the temporary scenario cannot be written or run.
pub fn bench(a: &BenchArgs) -> Result<(), CliError> {
    if let Some(BenchCommand::Report(r)) = &a.command {
        return super::report::report(r);
    }
    let frames = a.frames.max(10);
    if a.limits {
        return super::limits::limits(frames.min(2000));
    }
    if !a.scenarios.is_empty() {
        for path in &a.scenarios {
            // as written, its own frames replayed until `frames` are timed: what is planned for the run from its
            // views (the sky layer's margin, a staring camera's one render) is the scenario's own, and the sky's
            // blur, where it is planned (a texture made once, or a blur every frame), for every render (`run_timed`)
            let scenario = load_scenario(path)?;
            let own = scenario.spec.run.frames;
            let scenario = with_quality(scenario, a.quality)?;
            let before = super::steal::CpuTicks::now();
            let (fps, mut details) = time_headless(&scenario, frames, own)?;
            details.extend(super::steal::steal_note(before));
            super::say(&format!("{:<40} {fps:>9.1} frames/s", path.display()))?;
            if own < frames.saturating_add(WARM_UP_FRAMES) {
                details.insert(
                    0,
                    format!(
                        "  {frames} frames timed after {WARM_UP_FRAMES} warm-up frames: the scenario's {own} frames as written, \
                         run again from the first after the last"
                    ),
                );
            }
            details.iter().for_each(|d| eprintln!("{d}"));
        }
        return Ok(());
    }
    let dir = bench_dir("bench")?;
    for (w, h, n, recording) in [(256, 256, 1, false), (640, 512, WIDE_CASE_TARGETS, false), (256, 256, 1, true)] {
        let path = dir.join(format!("bench_{w}x{h}_{n}.toml"));
        std::fs::write(&path, bench_scenario(w, h, n)).map_err(|e| CliError::Failed(e.to_string()))?;
        let scenario = load_for_frames(&path, Some(frames)).map_err(|e| CliError::Invalid(e.to_string()))?;
        let scenario = with_quality(scenario, a.quality)?;
        let before = super::steal::CpuTicks::now();
        let (fps, mut details) = if recording {
            // the rate without disk writes timed again just before and just after the recording, so that the
            // ratio compares runs seconds apart, not the first case's run, two cases earlier, on a machine whose
            // speed drifts
            let before = time_headless(&scenario, frames, frames)?.0;
            let done = time_recording(&path, &scenario, frames, a.quality, &dir.join("out"))?;
            let after = time_headless(&scenario, frames, frames)?.0;
            let ratio = format!(
                "  ({:.2} of the rate without disk writes, {before:.1} and {after:.1} frames/s just before and after)",
                done.frames_per_s / (0.5 * (before + after))
            );
            (done.frames_per_s, vec![format!("  {}{ratio}", done.summary)])
        } else {
            time_headless(&scenario, frames, frames)?
        };
        let case = format!(
            "{w}x{h}, {n} target{}{}",
            if n > 1 { "s" } else { "" },
            if recording { ", png16 recording" } else { ", no disk" }
        );
        details.extend(super::steal::steal_note(before));
        super::say(&format!("{case:<40} {fps:>9.1} frames/s"))?;
        details.iter().for_each(|d| eprintln!("{d}"));
    }
    Ok(())
}

/// Records `scenario` (loaded from `path`) as `irsim record` does, 16-bit PNG at the default compression, into
/// `out` (replaced), and reports the recorder's own loop rate: set-up is not counted, the last files and their
/// sync are.
///
/// # Errors
/// [`CliError`] from the recording.
pub(super) fn time_recording(
    path: &Path,
    scenario: &CheckedScenario,
    frames: u64,
    quality: Option<QualityPreset>,
    out: &Path,
) -> Result<RecordDone, CliError> {
    let args = RecordArgs {
        scenario: path.to_path_buf(),
        out: out.to_path_buf(),
        frames: Some(frames),
        seed: None,
        force: true,
        no_noise: false,
        no_vibration: false,
        format: FrameFormat::Png16,
        png_compression: PngCompression::Fast,
        masks: false,
        quiet: true,
        quality,
    };
    let plan = record_plan(&args, frames);
    record_scenario(scenario, &plan, &Arc::new(AtomicBool::new(false)), &mut |_, _| {})
}

/// The recording loop: `frames` frames simulated and handed to `rec`, each reported to `progress`; returns
/// whether `stop` ended it early. A failure (a write error, a frame that panicked) ends it and is left in `rec`.
fn record_frames(
    app: &mut bevy::app::App,
    rec: &mut Recorder,
    (format, frames): (FrameFormat, u64),
    stop: &AtomicBool,
    progress: &mut dyn FnMut(u64, u64),
) -> bool {
    for _ in 0..frames {
        if stop.load(Ordering::SeqCst) {
            return true;
        }
        if rec.failed() {
            break;
        }
        // A bug must not leave the directory claiming to run: record it as the failure and stop there.
        let ready = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            app.update();
            drain_frames(app).pop()
        })) {
            Ok(Some(ready)) => ready,
            Ok(None) => {
                rec.fail(format!("internal error: frame {} was not completed (please report it)", rec.frames_sent()));
                break;
            }
            Err(panic) => {
                let what = crate::record::panic_text(panic.as_ref());
                rec.fail(format!("internal error computing frame {}: {what} (please report it)", rec.frames_sent()));
                break;
            }
        };
        if stop.load(Ordering::SeqCst) {
            // the frame may have been cut short inside a solve: it is not written
            return true;
        }
        let FrameReady { frame, float_frame, mask, labels } = ready;
        let frame: Frame = match (format, float_frame) {
            (FrameFormat::Npy, Some(f)) => f,
            _ => frame,
        };
        rec.push(frame, mask, labels);
        // buffers the encoders are done with go back to the simulation's pool (no allocation per frame)
        while let Some(spare) = rec.take_spare() {
            app.world_mut().resource_mut::<crate::sim::FramePool>().give_back(spare);
        }
        progress(rec.frames_sent(), frames);
    }
    false
}

/// What a run's settings resolved to, for the manifest: every `[quality]` switch, and the sky blur route the
/// planner chose where the switch says `auto`.
fn resolved_settings(app: &mut bevy::app::App, scenario: &CheckedScenario) -> serde_json::Value {
    let mut sensors = app.world_mut().query::<&crate::sim::Sensor>();
    let sky_blur = sensors.iter(app.world()).next().map(|s| (s.sky_blur, s.sky_blur_plan));
    json!({
        "quality": scenario.quality,
        "sky_blur_used": sky_blur.map(|(choice, _)| choice),
        "sky_blur_plan": sky_blur.and_then(|(_, plan)| plan),
    })
}
