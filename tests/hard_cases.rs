//! Hard inputs: every case that once broke irsim (a panic, a hang, a NaN in an output, lost labels, an error
//! that did not name its field), each a regression test, and a property test over random valid scenarios.
//!
//! The promise: no NaN or infinity reaches a frame or a label; bad input is refused with its file, line,
//! column and full field path (exit 2); a failed or interrupted recording leaves every frame on disk with its
//! label line and a manifest that says what happened.

mod common;

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::SMALL_SCENARIO as BASE;
use common::{irsim, root, temp_dir};
use irsim::imaging::frame::Frame;
use irsim::imaging::fusion::{Guidance, Patch, PoissonFusion, Solver};
use irsim::imaging::target_blob::PixelRect;
use irsim::record::{FrameFormat, RecordError, Recorder, prepare_dir};
use irsim::scenario::load::{Format, load_str};
use irsim::scenario::{CheckedScenario, ScenarioError};
use irsim::sim::{FrameLabels, RunOptions, build_app, current_frame, step};
use proptest::prelude::*;

fn load_toml(text: &str) -> Result<CheckedScenario, ScenarioError> {
    load_str(text, Format::Toml, Path::new("hard.toml"), &root().join("scenarios"))
}

fn load_json(text: &str) -> Result<CheckedScenario, ScenarioError> {
    load_str(text, Format::Json, Path::new("hard.json"), &root().join("scenarios"))
}

fn with(replace: &str, by: &str) -> String {
    assert!(BASE.contains(replace), "{replace}");
    BASE.replacen(replace, by, 1)
}

/// Asserts the error names `field`, with a line and column.
fn refused(result: Result<CheckedScenario, ScenarioError>, field: &str) -> ScenarioError {
    let e = result.expect_err("must be refused");
    assert_eq!(e.field, field, "{e}");
    assert!(e.line > 0 && e.column > 0, "no position: {e}");
    e
}

/// Every number in the labels is finite, every box inside the image; returns the JSON.
fn check_labels(labels: &FrameLabels, width: usize, height: usize) -> serde_json::Value {
    let v = serde_json::to_value(labels).unwrap();
    fn walk(v: &serde_json::Value, path: &str) {
        match v {
            serde_json::Value::Null => panic!("{path} is null (a NaN or an infinity)"),
            serde_json::Value::Number(n) => assert!(n.as_f64().unwrap().is_finite(), "{path}"),
            serde_json::Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| walk(x, &format!("{path}[{i}]"))),
            serde_json::Value::Object(o) => o.iter().for_each(|(k, x)| walk(x, &format!("{path}.{k}"))),
            _ => {}
        }
    }
    walk(&v, "labels");
    for t in &labels.targets {
        let [x0, y0, x1, y1] = t.bbox_px;
        assert!(0.0 <= x0 && x0 <= x1 && x1 <= width as f64, "{}: {:?}", t.name, t.bbox_px);
        assert!(0.0 <= y0 && y0 <= y1 && y1 <= height as f64, "{}: {:?}", t.name, t.bbox_px);
        assert!(!t.in_frame || (x1 > x0 && y1 > y0), "{} in frame with an empty box", t.name);
    }
    v
}

/// Runs `frames` steps and checks every pixel and label number.
fn run_checked(s: &CheckedScenario, frames: u64) -> Vec<FrameLabels> {
    let mut app = build_app(s, RunOptions { keep_float: true, ..RunOptions::default() }).unwrap();
    let (w, h) = (s.sensor.intrinsics.width as usize, s.sensor.intrinsics.height as usize);
    (0..frames)
        .map(|_| {
            let labels = step(&mut app);
            check_labels(&labels, w, h);
            let frame = current_frame(&mut app);
            assert!(frame.pixels().iter().all(|p| p.is_finite()), "frame {} has a non-finite pixel", labels.frame);
            labels
        })
        .collect()
}

// ------------------------------------------------------------ panics, hangs, silent wrong output

#[test]
fn frame_rates_outside_the_range_are_refused_not_a_panic() {
    for rate in ["1e-300", "1e-320", "0", "-1", "nan", "inf", "1e6"] {
        let e =
            refused(load_toml(&with("frame_rate_hz = 30", &format!("frame_rate_hz = {rate}"))), "run.frame_rate_hz");
        assert!(!e.message.contains("000000000"), "long number in {e}");
    }
}

#[test]
fn mask_fractions_outside_zero_to_one_are_refused() {
    for fraction in ["0", "-0.1", "1.5", "nan", "inf"] {
        let text = format!("{BASE}\n[labels]\nmask_fraction = {fraction}\n");
        let e = refused(load_toml(&text), "labels.mask_fraction");
        assert!(e.message.contains("(0, 1]"), "{e}");
    }
    for fraction in ["1", "0.5", "1e-6"] {
        load_toml(&format!("{BASE}\n[labels]\nmask_fraction = {fraction}\n")).unwrap();
    }
}

#[test]
fn any_accepted_frame_rate_puts_frame_k_at_t0_plus_k_over_rate() {
    // Bevy clamps a step to 250 ms; the simulation clock must not care
    for (rate, start) in [(1.0, 0.0), (0.01, 5.0), (1e-3, -100.0), (4.0, 0.0), (1e5, 0.0)] {
        let text = with("frame_rate_hz = 30", &format!("frame_rate_hz = {rate}\nstart_time_s = {start}"))
            .replace("velocity_m_s = [100, 0, 0]", "velocity_m_s = [0.001, 0, 0]")
            .replace("velocity_m_s = [-80, 0, 0]", "velocity_m_s = [-0.001, 0, 0]");
        let s = load_toml(&text).unwrap();
        let labels = run_checked(&s, 3);
        for (k, l) in labels.iter().enumerate() {
            assert_eq!(l.frame, k as u64);
            let want = start + k as f64 / rate;
            assert!((l.t_s - want).abs() <= 1e-9 * want.abs().max(1.0), "{rate} Hz frame {k}: t = {}", l.t_s);
            assert_eq!(l.targets.len(), 2);
        }
        assert!(labels[0].targets[0].in_frame, "{rate} Hz: the target should be seen");
    }
}

#[test]
fn edge_fill_with_far_image_coordinates_is_no_panic() {
    let sky = r#"
[sky]
generate = { kind = "clear", seed = 1 }
anchor_m = [0, 20000, 2000]
width_m = 4000
height_m = 2000
max_texels = 64
miss = { mode = "edge" }
"#;
    // refused beyond the documented range
    for px in ["[1e19, 1024]", "[nan, 3]", "[inf, 0]"] {
        refused(load_toml(&format!("{BASE}{sky}anchor_px = {px}\n")), "sky.anchor_px");
    }
    refused(load_toml(&format!("{BASE}{}", sky.replace("[0, 20000, 2000]", "[0, 20000, 1e308]"))), "sky.anchor_m");
    // the largest accepted anchor puts every ray far beyond the image: the edge value, no index overflow
    let s = load_toml(&format!("{BASE}{sky}anchor_px = [1e9, -1e9]\n")).unwrap();
    run_checked(&s, 2);
}

#[test]
fn a_key_beside_a_tag_that_takes_no_fields_is_refused_where_it_stands() {
    // serde reads such a variant from its tag alone and would ignore the key; every tagged table with such
    // variants is read so that it is refused, with the line, column and whole path of the key
    for (table, key) in [
        ("fusion_solver = { method = \"direct\", tolerance = 1 }", "quality.fusion_solver.tolerance"),
        ("fusion_solver = { method = \"direct_f32\", max_iterations = 10 }", "quality.fusion_solver.max_iterations"),
        (
            "fusion_solver = { method = \"sor\", tolerance = 1e-3, max_iterations = 10, omega = 1 }",
            "quality.fusion_solver.omega",
        ),
        ("planck = { method = \"series\", points = 4 }", "quality.planck.points"),
        ("sky_sampling = { mode = \"bilinear\", n = 3 }", "quality.sky_sampling.n"),
        ("sky_sampling = { mode = \"nearest\", n = 3 }", "quality.sky_sampling.n"),
        ("blob_sampling = { mode = \"point\", n = 4 }", "quality.blob_sampling.n"),
        ("blob_sampling = { mode = \"auto\", n = 4 }", "quality.blob_sampling.n"),
    ] {
        let e = refused(load_toml(&format!("{BASE}[quality]\n{table}\n")), key);
        assert!(e.to_string().contains("unknown field"), "{e}");
    }
    let sky = "\n[sky]\ngenerate = { kind = \"clear\", seed = 1 }\nanchor_m = [0, 20000, 2000]\nwidth_m = 4000\nheight_m = 2000\n";
    refused(load_toml(&format!("{BASE}{sky}miss = {{ mode = \"zero\", value = 3 }}\n")), "sky.miss.value");
    load_toml(&format!("{BASE}{sky}miss = {{ mode = \"constant\", value = 3 }}\n")).unwrap();
    // a value that is not a table says what it should be, not the name of the type that reads it
    let e = refused(load_toml(&format!("{BASE}[quality]\nfusion_solver = \"direct_f32\"\n")), "quality.fusion_solver");
    assert!(e.to_string().contains("expected a table with `method`: direct, direct_f32, jacobi or sor"), "{e}");
    // the same tables without the key are read
    for table in [
        "fusion_solver = { method = \"direct_f32\" }",
        "planck = { method = \"series\" }",
        "blob_sampling = { mode = \"point\" }",
    ] {
        load_toml(&format!("{BASE}[quality]\n{table}\n")).unwrap();
    }
}

#[test]
fn iterative_solvers_are_bounded_and_stop_on_request() {
    let text = |it: &str| {
        format!(
            "{BASE}[quality]\nfusion_solver = {{ method = \"jacobi\", tolerance = 1e-300, max_iterations = {it} }}\n"
        )
    };
    refused(load_toml(&text("4000000000")), "quality.fusion_solver.max_iterations");
    refused(load_toml(&text("0")), "quality.fusion_solver.max_iterations");
    load_toml(&text("100000")).unwrap();

    // a large patch and a tolerance no solve reaches: the stop flag ends it between sweeps
    let mut frame = Frame::new(400, 400);
    let values = vec![1.0f32; 300 * 300];
    let patch = Patch { rect: PixelRect { x0: 50, y0: 50, x1: 350, y1: 350 }, values: &values };
    let mut fusion = PoissonFusion::new();
    let stop = Arc::new(AtomicBool::new(false));
    fusion.set_stop(Arc::clone(&stop));
    let setter = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(300));
            stop.store(true, Ordering::SeqCst);
        })
    };
    let started = Instant::now();
    let stats = fusion.fuse(
        &mut frame,
        &[patch],
        Guidance::Normal,
        Solver::Jacobi { tolerance: 1e-300, max_iterations: 100_000 },
    );
    setter.join().unwrap();
    assert!(stats.stopped, "{stats:?}");
    assert!(stats.iterations < 100_000, "{stats:?}");
    // generous: the point is that it returns, not how fast
    assert!(started.elapsed() < Duration::from_secs(60), "{:?}", started.elapsed());
}

// ------------------------------------------------------------ data loss

fn labels(frame: u64) -> FrameLabels {
    FrameLabels { frame, t_s: frame as f64, targets: Vec::new() }
}

#[test]
fn labels_that_cannot_be_written_take_their_frames_with_them() {
    let dir = temp_dir("nolabels");
    let _lock = prepare_dir(&dir, false).unwrap();
    let mut rec = Recorder::new(
        &dir,
        (FrameFormat::Png16, irsim::imaging::frame::PngCompression::Fast),
        false,
        65535,
        2,
        serde_json::json!({}),
        20,
    )
    .unwrap();
    // the labels file's temporary name is taken: every write of the labels fails, as on a full disk
    std::fs::create_dir_all(dir.join("labels.jsonl.tmp")).unwrap();
    for k in 0..5 {
        rec.push(Frame::new(16, 16), None, labels(k));
    }
    let err = rec.finish(false).unwrap_err().to_string();
    assert!(err.contains("labels.jsonl"), "{err}");
    let frames = std::fs::read_dir(dir.join("frames")).unwrap().count();
    let lines = std::fs::read_to_string(dir.join("labels.jsonl")).map_or(0, |t| t.lines().count());
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["status"], "failed");
    assert!(m["error"].as_str().unwrap().contains("labels.jsonl"), "{m}");
    assert_eq!(frames, lines, "every frame on disk has its label line");
    assert_eq!(m["frames_written"].as_u64().unwrap() as usize, frames);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_second_recording_into_the_same_directory_is_refused() {
    let dir = temp_dir("lock");
    let lock = prepare_dir(&dir, false).unwrap();
    assert!(matches!(prepare_dir(&dir, true), Err(RecordError::Locked(..))));
    // and by the binary, with exit 2
    let scenario = root().join("scenarios/paper_clear_sky.toml");
    let (code, _, err) =
        irsim(&["record", scenario.to_str().unwrap(), "--out", dir.to_str().unwrap(), "--frames", "1", "--force"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("in use by another recording"), "{err}");
    drop(lock);
    // a lock left by a process that no longer runs is taken over
    std::fs::write(dir.join(irsim::record::LOCK_FILE), "4000000000\n").unwrap();
    let _again = prepare_dir(&dir, true).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn out_naming_a_file_is_bad_input() {
    let dir = temp_dir("outfile");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("not_a_dir");
    std::fs::write(&file, "keep").unwrap();
    let scenario = root().join("scenarios/paper_clear_sky.toml");
    let (code, _, err) =
        irsim(&["record", scenario.to_str().unwrap(), "--out", file.to_str().unwrap(), "--frames", "1"]);
    assert_eq!(code, 2, "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep");
    std::fs::remove_dir_all(&dir).unwrap();
}

// ------------------------------------------------------------ no NaN or infinity in an output

#[test]
fn shipped_scenarios_write_finite_labels() {
    for name in ["crossing_pair", "sense_and_avoid", "swarm", "head_on"] {
        let s = irsim::scenario::load(&root().join(format!("scenarios/{name}.toml"))).unwrap();
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        let l = step(&mut app);
        check_labels(&l, s.sensor.intrinsics.width as usize, s.sensor.intrinsics.height as usize);
    }
}

#[test]
fn extreme_accepted_geometry_gives_finite_labels() {
    let cases = [
        // above and below the atmosphere profile (−5 … 86 km)
        "position_m = [-20, 3000, 90000], velocity_m_s = [100, 0, 0]",
        "position_m = [-20, 3000, -6000], velocity_m_s = [100, 0, 0]",
        // at the observer's own position
        "position_m = [0, 0, 1000], velocity_m_s = [100, 0, 0]",
        // far away and very fast, within the limits
        "position_m = [-9e8, 9e8, 9e8], velocity_m_s = [9e4, 0, 0]",
    ];
    for c in cases {
        let text = with("position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0]", c);
        run_checked(&load_toml(&text).unwrap(), 2);
    }
    // zero noise: the SNR is still a number
    run_checked(&load_toml(&format!("{BASE}[sensor.noise]\nenabled = false\n")).unwrap(), 1);
    // a turn of the smallest radius, frame 0 at the latest start
    let turn = with(
        "trajectory = { kind = \"constant_velocity\", position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0] }",
        "trajectory = { kind = \"coordinated_turn\", center_m = [0, 3000, 1005], radius_m = 0.001, speed_m_s = 10, start_bearing_deg = 0 }",
    )
    .replace("seed = 3", "seed = 3\nstart_time_s = 1e9");
    let s = load_toml(&turn.replace("velocity_m_s = [-80, 0, 0]", "velocity_m_s = [0, 0, 0]")).unwrap();
    run_checked(&s, 2);
}

#[test]
fn inputs_whose_results_would_overflow_are_refused() {
    let traj = "position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0]";
    for (c, field) in [
        ("position_m = [1e308, 3000, 1005], velocity_m_s = [100, 0, 0]", "targets[0].trajectory.position_m"),
        ("position_m = [0, 3000, 1005], velocity_m_s = [1e308, 0, 0]", "targets[0].trajectory.velocity_m_s"),
        ("position_m = [0, 3000, 1005], velocity_m_s = [2e5, 0, 0]", "targets[0].trajectory.velocity_m_s"),
    ] {
        refused(load_toml(&with(traj, c)), field);
    }
    refused(load_toml(&with("seed = 3", "seed = 3\nstart_time_s = 1e300")), "run.start_time_s");
    let turn = with(
        &format!("trajectory = {{ kind = \"constant_velocity\", {traj} }}"),
        "trajectory = { kind = \"coordinated_turn\", center_m = [0, 3000, 1005], radius_m = 1e-320, speed_m_s = 10, start_bearing_deg = 0 }",
    );
    refused(load_toml(&turn), "targets[0].trajectory.radius_m");
    // a number or a boolean where a name belongs ("wanted string or table" in TOML), beside numbers that fit
    for bad in ["sky_blur = 3", "psf_method = true"] {
        let quality = format!("{BASE}[quality]\npsf_energy_cutoff = 0.03\n{bad}\n");
        refused(load_toml(&quality), &format!("quality.{}", bad.split(' ').next().unwrap()));
    }
    // a polynomial that grows past the world within the run
    let poly = with(
        &format!("trajectory = {{ kind = \"constant_velocity\", {traj} }}"),
        "trajectory = { kind = \"polynomial\", x_m = [0, 0, 0, 0, 0, 0, 0, 0, 1e3], y_m = [3000], z_m = [1005] }",
    )
    .replace("frames = 4", "frames = 10000");
    refused(load_toml(&poly), "targets[0].trajectory.x_m[8]");
    let (code, out, err) = irsim(&["calc", "skin", "--mach", "1e308", "--altitude-km", "5"]);
    assert_eq!(code, 2, "{out}{err}");
    assert!(!out.contains("null"), "{out}");
}

#[test]
fn values_that_would_overflow_a_frame_are_refused() {
    let sky = "\n[sky]\ngenerate = { kind = \"clear\", seed = 1 }\nanchor_m = [0, 20000, 2000]\nwidth_m = 4000\nheight_m = 2000\nmax_texels = 64\n";
    for v in ["inf", "1e39", "-1", "nan", "1e30"] {
        refused(load_toml(&format!("{BASE}{sky}miss = {{ mode = \"constant\", value = {v} }}\n")), "sky.miss.value");
    }
    // the largest accepted value saturates, finitely
    let s = load_toml(&format!("{BASE}{sky}miss = {{ mode = \"constant\", value = 1e4 }}\n")).unwrap();
    run_checked(&s, 1);
}

#[test]
fn mot_file_holds_only_targets_with_pixels_in_the_image() {
    let dir = temp_dir("mot");
    let scenario = root().join("scenarios/swarm.toml");
    let (code, _, err) =
        irsim(&["record", scenario.to_str().unwrap(), "--out", dir.to_str().unwrap(), "--frames", "2", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let labels = std::fs::read_to_string(dir.join("labels.jsonl")).unwrap();
    let mut in_frame = 0;
    for line in labels.lines() {
        let l: serde_json::Value = serde_json::from_str(line).unwrap();
        for t in l["targets"].as_array().unwrap() {
            let b: Vec<f64> = t["bbox_px"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            assert!(b[0] >= 0.0 && b[2] <= 640.0 && b[1] >= 0.0 && b[3] <= 512.0, "{t}");
            if t["in_frame"].as_bool().unwrap() {
                in_frame += 1;
                assert!(b[2] > b[0] && b[3] > b[1], "{t}");
            }
        }
    }
    let mot = std::fs::read_to_string(dir.join("gt_mot.txt")).unwrap();
    assert_eq!(mot.lines().count(), in_frame);
    for line in mot.lines() {
        let f: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        // MOTChallenge pixels count from 1
        assert!(f[2] >= 1.0 && f[3] >= 1.0 && f[2] + f[4] <= 641.0 + 1e-3 && f[3] + f[5] <= 513.0 + 1e-3, "{line}");
        assert!(f[4] > 0.0 && f[5] > 0.0, "{line}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

// ------------------------------------------------------------ bad values accepted

#[test]
fn non_finite_values_are_refused_with_their_field() {
    let sky = "\n[sky]\ngenerate = { kind = \"clear\", seed = 1 }\nanchor_m = [0, 20000, 2000]\nwidth_m = 4000\nheight_m = 2000\nmax_texels = 64\n";
    refused(load_toml(&format!("{BASE}{sky}anchor_px = [nan, 1]\n")), "sky.anchor_px");
    refused(load_toml(&format!("{BASE}{sky}miss = {{ mode = \"constant\", value = nan }}\n")), "sky.miss.value");
    for a in ["yaw_deg", "pitch_deg", "roll_deg"] {
        let text = with("semi_axes_m = [4, 2, 1]\n", &format!("semi_axes_m = [4, 2, 1]\nattitude = {{ {a} = nan }}\n"));
        refused(load_toml(&text), &format!("targets[0].attitude.{a}"));
    }
    refused(load_toml(&format!("{BASE}{sky}up = [nan, 0, 1]\n")), "sky.up");
    refused(load_toml(&format!("{BASE}{sky}normal = [0, 0, 1]\n")), "sky.normal");
}

#[test]
fn fixed_length_arrays_take_exactly_their_length() {
    let sky = "\n[sky]\ngenerate = { kind = \"clear\", seed = 1 }\nanchor_m = [0, 20000, 2000]\nwidth_m = 4000\nheight_m = 2000\nmax_texels = 64\n";
    refused(load_toml(&with("band_um = [8, 12]", "band_um = [8, 12, 3, 5]")), "sensor.band_um");
    refused(load_toml(&with("band_um = [8, 12]", "band_um = [8]")), "sensor.band_um");
    refused(load_toml(&with("semi_axes_m = [4, 2, 1]\n", "semi_axes_m = [4, 2, 1, 1]\n")), "targets[0].semi_axes_m");
    refused(
        load_toml(&with("position_m = [0, 0, 1000]", "position_m = [0, 0, 1000, 1]")),
        "observer.trajectory.position_m",
    );
    refused(load_toml(&(BASE.to_owned() + &sky.replace("[0, 20000, 2000]", "[0, 20000, 2000, 1]"))), "sky.anchor_m");
    for (field, value) in [("anchor_px", "[1, 2, 3]"), ("normal", "[0, -1, 0, 0]"), ("up", "[0, 0, 1, 0]")] {
        refused(load_toml(&format!("{BASE}{sky}{field} = {value}\n")), &format!("sky.{field}"));
    }
    let points = with(
        "trajectory = { kind = \"constant_velocity\", position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0] }",
        "trajectory = { kind = \"waypoints\", points = [[0, 0, 3000, 1000], [1, 10, 3000, 1000, 7]] }",
    );
    refused(load_toml(&points), "targets[0].trajectory.points[1]");
}

#[test]
fn sky_command_refuses_nan_elevations() {
    let dir = temp_dir("skynan");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("sky.png");
    for flag in ["--elevation-top-deg", "--elevation-bottom-deg"] {
        let (code, _, err) = irsim(&["sky", "--kind", "clear", "--out", out.to_str().unwrap(), flag, "nan"]);
        assert_eq!(code, 2, "{flag}: {err}");
        assert!(!out.exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn float_grayscale_tiff_is_a_sky_image() {
    use tiff::encoder::{TiffEncoder, colortype::Gray32Float};
    let dir = temp_dir("tiff");
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h) = (32u32, 16u32);
    let data: Vec<f32> = (0..w * h).map(|i| 250.0 + (i % w) as f32 * 0.5).collect();
    let path = dir.join("sky.tif");
    let mut enc = TiffEncoder::new(std::fs::File::create(&path).unwrap()).unwrap();
    enc.write_image::<Gray32Float>(w, h, &data).unwrap();
    let img = irsim::imaging::sky_plane::SkyImage::load(&path).unwrap();
    assert_eq!((img.width(), img.height()), (32, 16));
    assert_eq!(img.pixels()[5], 252.5);
    std::fs::remove_dir_all(&dir).unwrap();
}

// ------------------------------------------------------------ errors name their field

#[test]
fn type_errors_name_the_full_path() {
    let adc = format!("{BASE}\n[sensor.adc]\nbit_depth = \"x\"\n");
    // `[sensor.adc]` after `[[targets]]` is valid TOML
    refused(load_toml(&adc), "sensor.adc.bit_depth");
    refused(load_toml(&with("roughness = 0.3 }", "roughness = \"x\" }")), "targets[1].brdf.roughness");
    refused(
        load_toml(&with("kind = \"constant_velocity\", position_m = [0, 0, 1000]", "position_m = [0, 0, 1000]")),
        "observer.trajectory.kind",
    );
    refused(
        load_toml(&with("position_m = [0, 0, 1000]", "position_m = [0, \"x\", 1000]")),
        "observer.trajectory.position_m[1]",
    );
    let missing = BASE
        .replace("[sensor]\nwidth = 64\nheight = 48\npixel_pitch_um = 17\nfocal_length_mm = 100\naperture_mm = 100\nband_um = [8, 12]\n", "");
    refused(load_toml(&missing), "sensor");
    // header tables
    let header = BASE.replace(
        "trajectory = { kind = \"constant_velocity\", position_m = [0, 0, 1000] }\npointing = { mode = \"yaw_pitch_roll\", yaw_deg = 0 }",
        "pointing = { mode = \"yaw_pitch_roll\", yaw_deg = 0 }\n[observer.trajectory]\nkind = \"constant_velocity\"\nposition_m = [0, 0, true]",
    );
    refused(load_toml(&header), "observer.trajectory.position_m[2]");
    // two `true`s in a buffered (internally tagged) table: the one where a number belongs is named
    let turn = with(
        "trajectory = { kind = \"constant_velocity\", position_m = [-20, 3000, 1005], velocity_m_s = [100, 0, 0] }",
        "trajectory = { kind = \"coordinated_turn\", center_m = [0, 3000, 1005], radius_m = true, speed_m_s = 10, start_bearing_deg = 0, clockwise = true }",
    );
    refused(load_toml(&turn), "targets[0].trajectory.radius_m");
    // JSON
    let json = r#"{
  "sensor": {"width": 64, "height": 48, "pixel_pitch_um": 17, "focal_length_mm": 100, "aperture_mm": 100, "band_um": [8, 12]},
  "observer": {"trajectory": {"kind": "constant_velocity", "position_m": [0, 0, 1000]}, "pointing": {"mode": "yaw_pitch_roll"}},
  "targets": [{"name": "a", "trajectory": {"kind": "constant_velocity", "position_m": [0, 3000, 1000]}, "semi_axes_m": [1, 1, 1]},
              {"name": "b", "trajectory": {"kind": "constant_velocity", "position_m": [0, 3000, 1000]}, "semi_axes_m": [1, 1, 1], "brdf": {"roughness": "x"}}]
}"#;
    // a list or a table where a number belongs is refused on sight: the position is its first byte
    let e =
        load_json(&json.replacen("\"semi_axes_m\": [1, 1, 1]}", "\"semi_axes_m\": [1, 1, 1], \"emissivity\": []}", 1))
            .unwrap_err();
    assert_eq!(e.field, "targets[0].emissivity", "{e}");
    let e = load_json(&json.replace("\"width\": 64", "\"width\": {}")).unwrap_err();
    assert_eq!(e.field, "sensor.width", "{e}");
    // a number where a name belongs ("expected value" in JSON)
    let e = load_json(&json.replacen('{', "{\"quality\": {\"reflection\": 1.5}, ", 1)).unwrap_err();
    assert_eq!(e.field, "quality.reflection", "{e}");
    let e = load_json(json).unwrap_err();
    assert_eq!(e.field, "targets[1].brdf.roughness", "{e}");
    assert_eq!(e.line, 5, "{e}");
    let e = load_json(
        &json.replace("\"kind\": \"constant_velocity\", \"position_m\": [0, 0, 1000]", "\"position_m\": [0, 0, 1000]"),
    )
    .unwrap_err();
    assert_eq!(e.field, "observer.trajectory.kind", "{e}");
}

#[test]
fn csv_trajectory_errors_name_the_csv_file_and_its_line() {
    let dir = temp_dir("csv");
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("path.csv");
    std::fs::write(&csv, "t,x,y,z\n0,0,3000,1000\n# a comment\n1,10,3000,1000\n1,20,3000,1000\n").unwrap();
    let text = with(
        "trajectory = { kind = \"constant_velocity\", position_m = [10, 4000, 1010], velocity_m_s = [-80, 0, 0] }",
        "trajectory = { kind = \"csv\", path = \"path.csv\" }",
    );
    let e = load_str(&text, Format::Toml, &dir.join("s.toml"), &dir).unwrap_err();
    assert_eq!(e.file, csv.display().to_string(), "{e}");
    assert_eq!(e.line, 5, "{e}");
    assert_eq!(e.field, "targets[1].trajectory.path", "{e}");
    std::fs::write(&csv, "0,0,3000,1000\n1,10,3000\n").unwrap();
    let e = load_str(&text, Format::Toml, &dir.join("s.toml"), &dir).unwrap_err();
    assert_eq!((e.line, e.file.as_str()), (2, csv.to_str().unwrap()), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

// ------------------------------------------------------------ random valid scenarios

/// A scenario drawn over the whole schema, extreme but accepted values included.
fn scenario_text() -> impl Strategy<Value = String> {
    let number = prop_oneof![-1e4..1e4f64, Just(0.0), Just(1e-300), Just(-1e-300)];
    let position = (number.clone(), 10.0..1e5f64, -4000.0..9e4f64);
    let velocity = (-1e3..1e3f64, -1e3..1e3f64, -100.0..100.0f64);
    let trajectory = prop_oneof![
        (position.clone(), velocity.clone()).prop_map(|((x, y, z), (vx, vy, vz))| format!(
            "{{ kind = \"constant_velocity\", position_m = [{x:e}, {y:e}, {z:e}], velocity_m_s = [{vx:e}, {vy:e}, {vz:e}] }}"
        )),
        (position.clone(), 1e-3..1e4f64, 0.0..500.0f64, -360.0..360.0f64, any::<bool>()).prop_map(
            |((x, y, z), r, v, b, cw)| format!(
                "{{ kind = \"coordinated_turn\", center_m = [{x:e}, {y:e}, {z:e}], radius_m = {r:e}, speed_m_s = {v:e}, start_bearing_deg = {b:e}, clockwise = {cw} }}"
            )
        ),
        (position.clone(), position.clone(), 1e-3..100.0f64).prop_map(|((x, y, z), (x2, y2, z2), dt)| format!(
            "{{ kind = \"waypoints\", points = [[0, {x:e}, {y:e}, {z:e}], [{dt:e}, {x2:e}, {y2:e}, {z2:e}]] }}"
        )),
        (position, -10.0..10.0f64).prop_map(|((x, y, z), a)| format!(
            "{{ kind = \"polynomial\", x_m = [{x:e}, 1, {a:e}], y_m = [{y:e}], z_m = [{z:e}, 0, 0, 1e-3] }}"
        )),
    ];
    let target = (trajectory, 1e-4..1e4f64, 0.0..1.0f64, 0.0..2000.0f64, 1e-4..10.0f64, prop::option::of(0.0..30.0f64))
        .prop_map(|(tr, size, e, heat, rough, mach)| {
            let mach = mach.map_or(String::new(), |m| format!("mach = {m:e}\n"));
            format!(
                "trajectory = {tr}\nsemi_axes_m = [{size:e}, {:e}, {:e}]\nemissivity = {e:e}\nheating_k = {heat:e}\n{mach}brdf = {{ kd = 0.5, ks = 0.5, f0 = 0.05, roughness = {rough:e} }}\n",
                size * 0.5,
                size * 0.25
            )
        });
    let sky = prop_oneof![
        Just(String::new()),
        (any::<u32>(), prop_oneof![Just("dome"), Just("zero"), Just("edge")], -1e9..1e9f64).prop_map(|(seed, miss, px)| format!(
            "[sky]\ngenerate = {{ kind = \"cumulus\", seed = {seed} }}\nanchor_m = [0, 30000, 3000]\nwidth_m = 20000\nheight_m = 8000\nmax_texels = 64\nmiss = {{ mode = \"{miss}\" }}\nanchor_px = [{px:e}, 10]\n"
        )),
    ];
    let solver = prop_oneof![
        Just("{ method = \"direct\" }".to_owned()),
        (1e-300..1.0f64, 1u32..200)
            .prop_map(|(t, n)| format!("{{ method = \"jacobi\", tolerance = {t:e}, max_iterations = {n} }}")),
        (1e-300..1.0f64, 1u32..200)
            .prop_map(|(t, n)| format!("{{ method = \"sor\", tolerance = {t:e}, max_iterations = {n} }}")),
    ];
    let guidance = prop_oneof![Just("normal"), Just("mixed"), Just("additive")];
    (
        prop_oneof![Just(1e-3), Just(1.0), Just(30.0), Just(1e5), 1e-3..1e5f64],
        prop_oneof![Just(0.0), Just(1e9), Just(-1e9), -1e3..1e3f64],
        (1u32..48, 1u32..40),
        prop::collection::vec(target, 0..4),
        sky,
        solver,
        guidance,
        (0.0..1.0f64, any::<bool>()),
    )
        .prop_map(|(rate, start, (w, h), targets, sky, solver, guidance, (vib, noise))| {
            let mut s = format!(
                "[run]\nframe_rate_hz = {rate:e}\nstart_time_s = {start:e}\nframes = 3\nseed = 1\n\n\
                 [sensor]\nwidth = {w}\nheight = {h}\npixel_pitch_um = 17\nfocal_length_mm = 50\naperture_mm = 50\nband_um = [8, 12]\n\
                 noise = {{ enabled = {noise} }}\n\n\
                 [observer]\ntrajectory = {{ kind = \"constant_velocity\", position_m = [0, 0, 1000] }}\n\
                 pointing = {{ mode = \"look_at\", target_m = [0, 3000, 1100] }}\nvibration = {{ amplitude_deg = {vib:e} }}\n\n\
                 [quality]\nfusion_guidance = \"{guidance}\"\nfusion_solver = {solver}\n\n{sky}\n"
            );
            for (i, t) in targets.iter().enumerate() {
                s.push_str(&format!("[[targets]]\nname = \"t{i}\"\n{t}\n"));
            }
            s
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    /// Loads (refusal is fine: exit 2), builds and runs three frames: never a panic, every pixel and label
    /// number finite, every box inside the image.
    #[test]
    fn random_valid_scenarios_give_finite_outputs(text in scenario_text()) {
        match load_toml(&text) {
            // a refusal is exit 2: it must say where
            Err(e) => prop_assert!(e.line > 0 && !e.field.is_empty(), "{e}"),
            Ok(s) => {
                if build_app(&s, RunOptions::default()).is_ok() {
                    run_checked(&s, 3);
                }
            }
        }
    }
}

/// The strategy draws mostly accepted scenarios, so the property above exercises the pipeline.
#[test]
fn random_scenarios_are_mostly_accepted() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    let mut runner = TestRunner::deterministic();
    let strategy = scenario_text();
    let accepted = (0..40)
        .filter(|_| {
            let text = strategy.new_tree(&mut runner).unwrap().current();
            load_toml(&text).is_ok_and(|s| build_app(&s, RunOptions::default()).is_ok())
        })
        .count();
    assert!(accepted >= 20, "only {accepted} of 40 accepted");
}

#[test]
fn calc_refuses_what_would_print_null() {
    for args in [
        &["calc", "skin", "--altitude-km", "5", "--mach", "1e308"][..],
        &["calc", "skin", "--altitude-km", "5", "--mach", "2", "--t0-k", "1e308"],
        &["calc", "signal", "--heading-deg", "nan"],
        &["calc", "signal", "--aperture-mm", "1e308"],
        &["calc", "signal", "--focal-mm", "1e-320"],
        &["calc", "signal", "--pitch-um", "1e308"],
        &["calc", "signal", "--v-low", "-1e308"],
    ] {
        let (code, out, err) = irsim(args);
        assert_eq!(code, 2, "{args:?}: {out}{err}");
        assert!(err.contains("error:") && !err.contains("000000000"), "{args:?}: {err}");
    }
    // and in range, a number
    let (code, out, _) = irsim(&["calc", "skin", "--altitude-km", "500", "--mach", "2"]);
    assert!(code == 2 || !out.contains("null"), "{out}");
}
