//! `irsim record` and `irsim validate` as a user runs them.

mod common;

use std::process::Command;

use common::{irsim, root, temp_dir};

#[test]
fn record_writes_frames_labels_mot_and_manifest() {
    let out = temp_dir("record");
    let scenario = root().join("scenarios/paper_clear_sky.toml");
    let out_s = out.to_str().unwrap();
    let (code, _, err) =
        irsim(&["record", scenario.to_str().unwrap(), "--out", out_s, "--frames", "6", "--masks", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let frames: Vec<_> = std::fs::read_dir(out.join("frames")).unwrap().collect();
    assert_eq!(frames.len(), 6);
    let png = image::open(out.join("frames/000005.png")).unwrap();
    assert_eq!(png.color(), image::ColorType::L16);
    assert_eq!((png.width(), png.height()), (256, 256));
    let labels = std::fs::read_to_string(out.join("labels.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = labels.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 6);
    let t = &lines[3]["targets"][0];
    for key in [
        "id",
        "name",
        "center_px",
        "bbox_px",
        "ellipse_px",
        "range_m",
        "peak_dn",
        "snr",
        "scr",
        "in_frame",
        "detectable",
    ] {
        assert!(!t[key].is_null(), "label lacks {key}: {t}");
    }
    assert_eq!(lines[3]["frame"], 3);
    let mot = std::fs::read_to_string(out.join("gt_mot.txt")).unwrap();
    assert_eq!(mot.lines().count(), 6);
    assert!(mot.starts_with("1,1,"));
    // MOTChallenge counts pixels from 1: its tools (py-motmetrics) subtract 1 from left and top to get the
    // 0-based box of labels.jsonl
    for (row, label) in mot.lines().zip(&lines) {
        let f: Vec<f64> = row.split(',').map(|x| x.parse().unwrap()).collect();
        let b: Vec<f64> =
            label["targets"][0]["bbox_px"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        for (mot, zero_based) in
            [(f[2] - 1.0, b[0]), (f[3] - 1.0, b[1]), (f[2] - 1.0 + f[4], b[2]), (f[3] - 1.0 + f[5], b[3])]
        {
            assert!((mot - zero_based).abs() < 2e-3, "{row} against {b:?}");
        }
    }
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["status"], "complete");
    assert_eq!(manifest["frames_written"], 6);
    assert_eq!(manifest["seed"], 9);
    assert!(manifest["timings"]["stage_ms_per_frame"]["render"].is_number());
    assert!(manifest["timings"]["setup_s"].as_f64().is_some_and(|s| s > 0.0));
    // where the system counts steal time, the ticks of the recording loop (a loop shorter than a tick may count
    // none, and then has no share)
    if irsim::cli::steal::CpuTicks::now().is_some() {
        let t = &manifest["timings"];
        let (total, steal) = (t["host_cpu_ticks"]["total"].as_u64(), t["host_cpu_ticks"]["steal"].as_u64());
        assert!(total.zip(steal).is_some_and(|(t, s)| s <= t), "{t:?}");
        let share = t["host_steal_share"].as_f64();
        assert!(share.is_none_or(|s| (0.0..=1.0).contains(&s)) && share.is_some() == (total > Some(0)), "{t:?}");
    }
    assert_eq!(std::fs::read_dir(out.join("masks")).unwrap().count(), 6);
    let mask = image::open(out.join("masks/000000.png")).unwrap().into_luma8();
    assert!(mask.pixels().any(|p| p.0[0] == 1));

    // a second run into the same directory is refused, and nothing is touched
    let before = std::fs::read(out.join("frames/000000.png")).unwrap();
    let (code, _, err) = irsim(&["record", scenario.to_str().unwrap(), "--out", out_s, "--frames", "2", "--quiet"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--force"), "{err}");
    assert_eq!(std::fs::read(out.join("frames/000000.png")).unwrap(), before);
    // with --force the earlier outputs are replaced
    let (code, _, err) = irsim(&[
        "record",
        scenario.to_str().unwrap(),
        "--out",
        out_s,
        "--frames",
        "2",
        "--quiet",
        "--force",
        "--format",
        "npy",
    ]);
    assert_eq!(code, 0, "{err}");
    let names: Vec<String> =
        std::fs::read_dir(out.join("frames")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert_eq!(names.len(), 2);
    assert!(names.iter().all(|n| n.ends_with(".npy")));
    assert_eq!(std::fs::read_to_string(out.join("labels.jsonl")).unwrap().lines().count(), 2);
    std::fs::remove_dir_all(&out).unwrap();
}

/// Without temporal noise and vibration a seed reproduces its frames exactly; another seed draws another
/// fixed pattern (the camera's non-uniformity is seeded per sequence).
#[test]
fn no_noise_no_vibration_records_repeat_per_seed_and_the_fixed_pattern_follows_the_seed() {
    let scenario = root().join("scenarios/paper_vibration.toml");
    let mut frames = Vec::new();
    for (run, seed) in ["1", "1", "2"].into_iter().enumerate() {
        let out = temp_dir(&format!("seed{seed}-{run}"));
        let (code, _, err) = irsim(&[
            "record",
            scenario.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--frames",
            "2",
            "--seed",
            seed,
            "--no-noise",
            "--no-vibration",
            "--quiet",
        ]);
        assert_eq!(code, 0, "{err}");
        frames.push(std::fs::read(out.join("frames/000001.png")).unwrap());
        std::fs::remove_dir_all(&out).unwrap();
    }
    assert_eq!(frames[0], frames[1]);
    assert_ne!(frames[0], frames[2]);
}

/// Writes `text` as a scenario next to the shipped ones' sky images and validates it.
fn validate_text(name: &str, text: &str) -> (i32, String) {
    let dir = temp_dir(name);
    std::fs::create_dir_all(&dir).unwrap();
    let ext = if text.trim_start().starts_with('{') { "json" } else { "toml" };
    let path = dir.join(format!("s.{ext}"));
    std::fs::write(&path, text).unwrap();
    let (code, _, err) = irsim(&["validate", path.to_str().unwrap()]);
    std::fs::remove_dir_all(&dir).unwrap();
    (code, err)
}

fn base() -> String {
    let sky = root().join("assets/skies/clear.png");
    format!(
        r#"[run]
frames = 5
[sensor]
width = 64
height = 48
pixel_pitch_um = 17
focal_length_mm = 50
aperture_mm = 50
band_um = [8, 12]
[sensor.adc]
bit_depth = 14
noise_dn = 2.0
[observer]
trajectory = {{ kind = "constant_velocity", position_m = [0, 0, 8000] }}
pointing = {{ mode = "look_at", target_m = [0, 30000, 8000] }}
[sky]
image = "{}"
calibration = {{ mode = "temperature", value_range = [0, 65535], temp_range_k = [210, 260] }}
anchor_m = [0, 30000, 6000]
width_m = 4000
height_m = 4000
[[targets]]
name = "t"
trajectory = {{ kind = "constant_velocity", position_m = [0, 5000, 8000], velocity_m_s = [100, 0, 0] }}
semi_axes_m = [6, 1.5, 1.5]
"#,
        sky.display()
    )
}

#[test]
fn the_base_scenario_is_valid() {
    let (code, err) = validate_text("base", &base());
    assert_eq!(code, 0, "{err}");
}

#[test]
fn malformed_scenarios_name_the_field_and_exit_2() {
    let b = base();
    let cases: Vec<(&str, String, &str, usize)> = vec![
        ("wrong_type", b.replace("width = 64", "width = \"wide\""), "sensor.width", 4),
        ("unknown_field", b.replace("aperture_mm = 50", "aperture_mm = 50\napperture = 1"), "sensor.apperture", 9),
        ("nan", b.replace("pixel_pitch_um = 17", "pixel_pitch_um = nan"), "sensor.pixel_pitch_um", 6),
        ("negative_range", b.replace("width_m = 4000", "width_m = -4000"), "sky.width_m", 0),
        ("bad_bit_depth", b.replace("bit_depth = 14", "bit_depth = 40"), "sensor.adc.bit_depth", 11),
        (
            "old_gray_mapping",
            b.replace("[sensor.adc]", "gray = { v_low = 0, v_high = 2 }\n[sensor.adc]"),
            "sensor.gray",
            10,
        ),
        ("uncalibrated_image", b.replace("calibration = ", "# calibration = "), "sky.calibration", 0),
        ("empty_band", b.replace("band_um = [8, 12]", "band_um = [12, 8]"), "sensor.band_um", 9),
        ("missing_image", b.replace("clear.png", "no_such_sky.png"), "sky.image", 0),
        (
            "bad_semi_axes",
            b.replace("semi_axes_m = [6, 1.5, 1.5]", "semi_axes_m = [6, 0, 1.5]"),
            "targets[0].semi_axes_m",
            0,
        ),
        (
            "unknown_track",
            b.replace(
                r#"pointing = { mode = "look_at", target_m = [0, 30000, 8000] }"#,
                r#"pointing = { mode = "track", target = "nobody" }"#,
            ),
            "observer.pointing.target",
            0,
        ),
    ];
    for (name, text, field, line) in cases {
        let (code, err) = validate_text(name, &text);
        assert_eq!(code, 2, "{name}: {err}");
        assert!(err.contains(&format!("field `{field}`")), "{name}: message does not name `{field}`: {err}");
        assert!(err.contains("s.toml:"), "{name}: message does not name the file: {err}");
        if line > 0 {
            assert!(err.contains(&format!("s.toml:{line}:")), "{name}: expected line {line}: {err}");
        }
        assert!(!err.contains("panicked"), "{name}: {err}");
    }
}

#[test]
fn json_scenarios_work_and_their_errors_are_located() {
    let sky = root().join("assets/skies/clear.png");
    let json = format!(
        r#"{{
  "sensor": {{"width": 64, "height": 48, "pixel_pitch_um": 17, "focal_length_mm": 50, "aperture_mm": 50, "band_um": [8, 12]}},
  "observer": {{
    "trajectory": {{"kind": "constant_velocity", "position_m": [0, 0, 8000]}},
    "pointing": {{"mode": "yaw_pitch_roll", "yaw_deg": 0}}
  }},
  "sky": {{"image": "{}", "calibration": {{"mode": "kelvin", "scale_k": 0.004}}, "anchor_m": [0, 30000, 6000], "width_m": 4000, "height_m": 4000}}
}}"#,
        sky.display()
    );
    assert_eq!(validate_text("json_ok", &json).0, 0);
    let (code, err) = validate_text("json_bad", &json.replace("\"height_m\": 4000", "\"height_m\": 0"));
    assert_eq!(code, 2);
    assert!(err.contains("field `sky.height_m`") && err.contains("s.json:7:"), "{err}");
}

#[test]
fn missing_scenario_file_is_reported() {
    let (code, _, err) = irsim(&["validate", "/no/such/scenario.toml"]);
    assert_eq!(code, 2);
    assert!(err.contains("/no/such/scenario.toml"), "{err}");
}

#[test]
fn out_naming_an_existing_file_is_bad_input_and_the_file_is_kept() {
    let file = std::env::temp_dir().join(format!("irsim-out-file-{}", std::process::id()));
    std::fs::write(&file, b"keep me").unwrap();
    let scenario = format!("{}/scenarios/paper_clear_sky.toml", env!("CARGO_MANIFEST_DIR"));
    for force in [false, true] {
        let mut args = vec!["record", scenario.as_str(), "--out", file.to_str().unwrap(), "--frames", "2"];
        if force {
            args.push("--force");
        }
        let (code, _, err) = irsim(&args);
        assert_eq!(code, 2, "force {force}: {err}");
        assert!(err.contains("is not a directory"), "{err}");
        assert_eq!(std::fs::read(&file).unwrap(), b"keep me");
    }
    std::fs::remove_file(&file).unwrap();
}

/// Ctrl-C (SIGINT) during a recording: the process stops with exit code 130, and what it leaves is consistent —
/// frames 0 … N−1 complete, N lines of labels, MOT rows only for those frames, no temporary files, and a
/// manifest with status "interrupted" and `frames_written` N.
#[cfg(unix)]
#[test]
fn sigint_leaves_complete_frames_matching_labels_and_a_manifest() {
    interrupt_recording(libc::SIGINT, "sigint");
}

/// SIGTERM (a batch system or `docker stop` ending the job) is handled like Ctrl-C.
#[cfg(unix)]
#[test]
fn sigterm_leaves_complete_frames_matching_labels_and_a_manifest() {
    interrupt_recording(libc::SIGTERM, "sigterm");
}

#[cfg(unix)]
/// Starts recording paper_clear_sky for as long as it takes into `out` and waits until frames are being
/// written and the manifest on disk counts at least `checkpointed` frames written.
#[cfg(unix)]
fn start_long_recording(name: &str, out: &std::path::Path, checkpointed: usize) -> std::process::Child {
    use std::time::{Duration, Instant};
    // paper_clear_sky flown for as long as it takes: past the LOWTRAN table's 100 km, so with a Beer–Lambert
    // atmosphere (a LOWTRAN scene that leaves the table is refused at load)
    let text = std::fs::read_to_string(root().join("scenarios/paper_clear_sky.toml")).unwrap();
    let start = text.find("model = \"us_standard_1976\"").expect("the LOWTRAN weather");
    let end = start + text[start..].find("visibility_km = 23").unwrap() + "visibility_km = 23".len();
    let text = format!(
        "{}transmittance = {{ model = \"beer_lambert\", extinction_per_km = 0.15 }}{}",
        &text[..start],
        &text[end..]
    );
    let scenario = std::env::temp_dir().join(format!("irsim-test-{name}-{}.toml", std::process::id()));
    std::fs::write(&scenario, text).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_irsim"))
        .args(["record", scenario.to_str().unwrap(), "--out", out.to_str().unwrap(), "--frames", "100000"])
        .arg("--quiet")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start irsim");
    // wait until frames are being written (the recorder checkpoints labels and manifest as it goes)
    let started = Instant::now();
    // the manifest is the last file a checkpoint writes, so once it counts the frames, labels and MOT do too
    let in_manifest = || {
        std::fs::read_to_string(out.join("manifest.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|m| m["frames_written"].as_u64())
            .map_or(0, |n| n as usize)
    };
    while std::fs::read_dir(out.join("frames")).map_or(0, |d| d.count()) < 5 || in_manifest() < checkpointed {
        assert!(started.elapsed() < Duration::from_secs(120), "no frames after two minutes");
        assert!(child.try_wait().unwrap().is_none(), "irsim exited before it was interrupted");
        std::thread::sleep(Duration::from_millis(20));
    }
    // read at the start: not left behind in the system's temporary directory
    let _ = std::fs::remove_file(&scenario);
    child
}

#[cfg(unix)]
fn interrupt_recording(signal: libc::c_int, name: &str) {
    let out = temp_dir(name);
    let child = start_long_recording(name, &out, 0);
    // SAFETY: kill(2) with a child's pid and a valid signal number has no memory-safety preconditions.
    let sent = unsafe { libc::kill(child.id() as libc::pid_t, signal) };
    assert_eq!(sent, 0, "could not send signal {signal}");
    let output = child.wait_with_output().expect("wait for irsim");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("interrupted"), "{stderr}");

    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["status"], "interrupted");
    let written = manifest["frames_written"].as_u64().unwrap() as usize;
    assert!((5..1_000_000).contains(&written), "{written} frames written");

    let mut names: Vec<String> =
        std::fs::read_dir(out.join("frames")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    let want: Vec<String> = (0..written).map(|i| format!("{i:06}.png")).collect();
    assert_eq!(names, want, "frame files");
    for name in &names {
        // each frame decodes completely
        let img = image::open(out.join("frames").join(name)).unwrap();
        assert_eq!((img.width(), img.height()), (256, 256));
    }

    let labels = std::fs::read_to_string(out.join("labels.jsonl")).unwrap();
    let frames: Vec<u64> = labels
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["frame"].as_u64().unwrap())
        .collect();
    assert_eq!(frames, (0..written as u64).collect::<Vec<_>>(), "label lines");
    let mot = std::fs::read_to_string(out.join("gt_mot.txt")).unwrap();
    for line in mot.lines() {
        // MOT frames count from 1
        let frame: usize = line.split(',').next().unwrap().parse().unwrap();
        assert!((1..=written).contains(&frame), "MOT row for frame {frame}: {line}");
    }
    let leftovers: Vec<_> = walk(&out).into_iter().filter(|p| p.to_string_lossy().ends_with(".tmp")).collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
#[cfg(unix)]
fn sigkill_leaves_the_checkpointed_frames_whole_and_their_labels() {
    // no chance to clean up: what the last checkpoint wrote must stand on its own
    let out = temp_dir("sigkill");
    let child = start_long_recording("sigkill", &out, 3);
    // SAFETY: kill(2) with a child's pid and a valid signal number has no memory-safety preconditions.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGKILL) }, 0);
    let output = child.wait_with_output().expect("wait for irsim");
    assert_eq!(output.status.code(), None, "killed by a signal");

    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["status"], "running");
    let written = manifest["frames_written"].as_u64().unwrap() as usize;
    let labels = std::fs::read_to_string(out.join("labels.jsonl")).unwrap();
    let frames: Vec<u64> = labels
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["frame"].as_u64().unwrap())
        .collect();
    assert!(written >= 3, "{written} frames checkpointed");
    // a kill in the middle of a checkpoint may leave the labels (written first) one checkpoint ahead of the
    // manifest (written last), never behind it; the labels list frames 0, 1, ... with no gap
    let labelled = frames.len();
    assert!(labelled >= written, "{labelled} label lines, manifest says {written} frames");
    assert_eq!(frames, (0..labelled as u64).collect::<Vec<_>>(), "label lines");
    let mot = std::fs::read_to_string(out.join("gt_mot.txt")).unwrap();
    assert!(mot.lines().all(|l| l.split(',').next().unwrap().parse::<usize>().unwrap() <= labelled), "{mot}");
    // every labelled frame is there and decodes completely; any frame file beyond them is whole too (files
    // are given their names only when whole), only temporary files may be cut short
    for entry in std::fs::read_dir(out.join("frames")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "png") {
            let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!((img.width(), img.height()), (256, 256));
        }
    }
    for i in 0..labelled {
        assert!(out.join(format!("frames/{i:06}.png")).exists(), "frame {i}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// Every file under `dir`.
#[cfg(unix)]
fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files.extend(walk(&path));
        } else {
            files.push(path);
        }
    }
    files
}

#[test]
fn bench_times_a_given_scenario() {
    let scenario = root().join("scenarios/head_on.toml");
    let (code, out, err) = irsim(&["bench", scenario.to_str().unwrap(), "--frames", "10"]);
    assert_eq!(code, 0, "{err}");
    let line = out.lines().find(|l| l.contains("head_on.toml")).expect("a line for the scenario");
    let fps: f64 = line.split_whitespace().rev().nth(1).unwrap().parse().unwrap();
    assert!(fps > 0.0, "{line}");
    assert!(err.contains("stage µs per frame: motion"), "{err}");
    let (code, _, err) = irsim(&["bench", "no/such/scenario.toml"]);
    assert_eq!(code, 2, "{err}");
}

/// The built-in cases: each a rate, and the recording's ratio to the rate without disk writes timed just before and
/// just after it.
#[test]
fn bench_s_recording_case_is_compared_with_headless_runs_beside_it() {
    let (code, out, err) = irsim(&["bench", "--frames", "10"]);
    assert_eq!(code, 0, "{err}");
    for case in ["256x256, 1 target, no disk", "640x512, 10 targets, no disk", "256x256, 1 target, png16 recording"] {
        let line = out.lines().find(|l| l.starts_with(case)).unwrap_or_else(|| panic!("no {case} in {out}"));
        let fps: f64 = line.split_whitespace().rev().nth(1).unwrap().parse().unwrap();
        assert!(fps.is_finite() && fps > 0.0, "{line}");
    }
    let line = err.lines().find(|l| l.contains("of the rate without disk writes")).expect("the ratio");
    let numbers: Vec<f64> = line
        .rsplit_once('(')
        .unwrap()
        .1
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter_map(|w| w.parse().ok())
        .collect();
    assert_eq!(numbers.len(), 3, "{line}");
    // the ratio, printed to two places, may round to 0 where ten frames wait for a busy disk
    assert!(numbers.iter().all(|n| n.is_finite() && *n >= 0.0), "{line}");
    assert!(numbers[1] > 0.0 && numbers[2] > 0.0, "{line}");
    assert!(line.contains("frames/s just before and after)"), "{line}");
}

#[test]
fn bench_replays_a_short_scenario_s_own_frames() {
    // five frames, timed over twelve after the warm-up: the scenario runs again from its first frame
    let dir = temp_dir("bench_replay");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("s.toml");
    std::fs::write(&path, base()).unwrap();
    let (code, out, err) = irsim(&["bench", path.to_str().unwrap(), "--frames", "12"]);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("frames/s"), "{out}");
    assert!(
        err.contains("12 frames timed after 10 warm-up frames: the scenario's 5 frames as written, run again"),
        "{err}"
    );
}

#[test]
fn bench_replays_a_scenario_that_could_not_run_as_long() {
    // paper_clear_sky's target would leave the atmosphere's tables at frame 3169, past the scenario's 90 frames:
    // a bench of 3200 replays the 90 as written and never refuses the frames it does not run; where the sky's blur
    // is planned (draft's `sky_blur = "auto"`), it is planned for every render, the 90 views again and again
    let scenario = root().join("scenarios/paper_clear_sky.toml");
    let (code, out, err) = irsim(&["bench", scenario.to_str().unwrap(), "--frames", "3200", "--quality", "draft"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("frames/s"), "{out}");
    assert!(err.contains("the scenario's 90 frames as written, run again from the first after the last"), "{err}");
    assert!(err.contains(" of 3210 views, "), "{err}");
    // as many frames as its own: planned for those, as `irsim record` plans them
    let (code, _, err) = irsim(&["bench", scenario.to_str().unwrap(), "--frames", "90", "--quality", "draft"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains(" of 90 views, "), "{err}");
}

#[test]
fn every_instruction_set_and_thread_count_gives_the_same_frames() {
    // the per-pixel kernels run with AVX-512, AVX2 or the baseline as the CPU allows (IRSIM_SIMD caps it), on
    // any number of threads: the frames are the same bytes
    let dir = temp_dir("simd");
    let scenario = root().join("scenarios/sense_and_avoid.toml");
    for quality in ["standard", "draft"] {
        let runs = [("native", None, "2"), ("baseline", Some("baseline"), "1"), ("avx2", Some("avx2"), "2")];
        let mut frames: Vec<Vec<u8>> = Vec::new();
        for (name, simd, threads) in runs {
            let out = dir.join(format!("{quality}-{name}"));
            let mut c = Command::new(env!("CARGO_BIN_EXE_irsim"));
            c.args(["record", scenario.to_str().unwrap(), "--out", out.to_str().unwrap(), "--frames", "2"])
                .args(["--quality", quality, "--quiet"])
                .env("RAYON_NUM_THREADS", threads);
            match simd {
                Some(level) => c.env("IRSIM_SIMD", level),
                None => c.env_remove("IRSIM_SIMD"),
            };
            let o = c.output().unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let bytes = std::fs::read(out.join("frames/000001.png")).unwrap();
            if let Some(first) = frames.first() {
                assert!(*first == bytes, "{quality}: {name} differs from the native run");
            }
            frames.push(bytes);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bench_limits_prints_each_bound_and_ratio() {
    let (code, out, err) = irsim(&["bench", "--limits", "--frames", "10"]);
    assert_eq!(code, 0, "{err}");
    // 256 x 256 with one target, 640 x 512 with one and with ten (the swarm's count), on each thread count
    for (size, targets) in [("256x256", 1.0), ("640x512", 1.0), ("640x512", 10.0)] {
        let rows: Vec<Vec<f64>> = out
            .lines()
            .filter(|l| l.starts_with(size))
            .map(|line| {
                line.split(|c: char| c.is_whitespace() || c == '|' || c == 'x').filter_map(|w| w.parse().ok()).collect()
            })
            .filter(|numbers: &Vec<f64>| numbers.get(2) == Some(&targets))
            .collect();
        assert!(!rows.is_empty(), "{size}, {targets} targets: {out}");
        for numbers in rows {
            // width and height, targets, threads, five bounds, three stages, three ratios: every one positive and
            // finite
            assert!(numbers.len() >= 15, "{numbers:?}");
            assert!(numbers.iter().all(|v| v.is_finite() && *v > 0.0), "{numbers:?}");
        }
    }
}
