//! The viewer's state logic without a window: seeking to frame k gives the frame a run writes as frame k, an
//! edit changes the frames exactly as the same change in a scenario file does, and save → validate → record
//! round-trips.

mod common;

use std::path::Path;

use common::{irsim, root, temp_dir};
use irsim::imaging::frame::Frame;
use irsim::scenario::edit::Session;
use irsim::scenario::load::{Format, load_str};
use irsim::scenario::{CheckedScenario, load};
use irsim::sim::{RunOptions, drain_frames, frame_at, headless_app};

fn frames_in_order(s: &CheckedScenario, n: usize) -> Vec<Frame> {
    let mut app = headless_app(s, RunOptions::default()).expect("builds");
    (0..n)
        .map(|_| {
            app.update();
            drain_frames(&mut app).pop().expect("one frame per update").frame
        })
        .collect()
}

fn frame_alone(s: &CheckedScenario, k: u64) -> Frame {
    let mut app = headless_app(s, RunOptions::default()).expect("builds");
    frame_at(&mut app, k).expect("a frame").frame
}

/// A small scene with a generated sky, vibration, noise and two targets (one the observer tracks).
const SCENE: &str = r#"
name = "edit_test"
[run]
frame_rate_hz = 30
frames = 12
seed = 5
[sensor]
preset = "uncooled_lwir_microbolometer"
width = 160
height = 128
[observer]
trajectory = { kind = "constant_velocity", position_m = [0, 0, 1500], velocity_m_s = [0, 50, 0] }
pointing = { mode = "track", target = "a", roll_deg = 0 }
vibration = { amplitude_deg = 0.05, cutoff_hz = 8.0 }
[sky]
generate = { kind = "cumulus", cover = 0.45, psd_slope = -3.0, scale = 0.15, texture_k = 1.5, seed = 3 }
anchor_m = [0, 25000, 2500]
normal = [0, -1, 0]
width_m = 16000
height_m = 6000
max_texels = 512
[[targets]]
name = "a"
trajectory = { kind = "constant_velocity", position_m = [0, 1600, 1500], velocity_m_s = [0, -30, 0] }
semi_axes_m = [0.6, 0.6, 0.2]
emissivity = 0.9
[[targets]]
name = "b"
trajectory = { kind = "constant_velocity", position_m = [30, 1000, 1520], velocity_m_s = [-6, 0, -1] }
semi_axes_m = [0.6, 0.6, 0.2]
emissivity = 0.9
"#;

fn scene(text: &str) -> CheckedScenario {
    load_str(text, Format::Toml, Path::new("edit_test.toml"), &root().join("scenarios")).expect("valid")
}

#[test]
fn seeking_to_frame_k_gives_the_frame_a_run_writes_as_frame_k() {
    let s = scene(SCENE);
    let run = frames_in_order(&s, 8);
    let mut app = headless_app(&s, RunOptions::default()).expect("builds");
    // in any order, as a slider jumps
    for k in [7_u64, 2, 5, 0, 5] {
        let f = frame_at(&mut app, k).expect("a frame");
        assert_eq!(f.labels.frame, k);
        assert_eq!(f.frame.pixels(), run[k as usize].pixels(), "frame {k}");
    }
}

#[test]
fn an_edit_changes_the_frames_as_the_same_change_in_the_file_does() {
    let mut session = Session::new(scene(SCENE));
    let unedited = frame_alone(&session.applied, 4);
    // the target's skin, the sun, the observer's vibration and the fusion solver, in one edit
    session
        .edit(|d| {
            d.targets[1].emissivity = 0.5;
            d.targets[1].heating_k = 25.0;
            d.sun.elevation_deg = 12.0;
            d.observer.vibration.amplitude_deg = 0.2;
        })
        .expect("a valid edit");
    let edited_text = SCENE
        .replace(
            "[[targets]]\nname = \"b\"",
            "[sun]\nelevation_deg = 12.0\n[[targets]]\nname = \"b\"\nheating_k = 25.0",
        )
        .replace("amplitude_deg = 0.05", "amplitude_deg = 0.2");
    let edited_text = {
        // the second target's emissivity is the last `emissivity = 0.9` in the file
        let i = edited_text.rfind("emissivity = 0.9").expect("present");
        format!("{}emissivity = 0.5{}", &edited_text[..i], &edited_text[i + "emissivity = 0.9".len()..])
    };
    let from_file = scene(&edited_text);
    assert_eq!(from_file.spec, session.applied.spec, "the same scenario, edited or written");
    let edited = frame_alone(&session.applied, 4);
    assert_eq!(edited.pixels(), frame_alone(&from_file, 4).pixels());
    assert_ne!(edited.pixels(), unedited.pixels(), "the edit shows in the frame");
}

#[test]
fn a_refused_edit_leaves_the_frames_unchanged() {
    let mut session = Session::new(scene(SCENE));
    let before = frame_alone(&session.applied, 3);
    let e = session.edit(|d| d.sun.elevation_deg = 120.0).unwrap_err();
    assert!(e.path.starts_with("sun"), "{e:?}");
    let e2 = session.remove_target(0).unwrap_err();
    assert!(e2.path.starts_with("observer.pointing"), "the tracked target cannot go: {e2:?}");
    assert_eq!(session.applied.spec.targets.len(), 2);
    assert_eq!(frame_alone(&session.applied, 3).pixels(), before.pixels());
}

#[test]
fn save_validate_record_round_trips() {
    let dir = temp_dir("edit-save");
    std::fs::create_dir_all(&dir).unwrap();
    // a shipped scenario with a sky image given by a relative path, saved elsewhere
    let mut session = Session::new(load(&root().join("scenarios/paper_vibration.toml")).expect("shipped"));
    session.edit(|d| d.sun.azimuth_deg = 200.0).expect("valid");
    let path = dir.join("edited.toml");
    session.save(&path, false).expect("saved");
    assert!(session.save(&path, false).is_err(), "no silent overwrite");
    session.save(&path, true).expect("overwrite when asked");
    let loaded = load(&path).expect("the saved file loads");
    let mut rebased = session.applied.spec.clone();
    rebased.rebase_paths(&root().join("scenarios"), &dir);
    assert_eq!(loaded.spec, rebased, "the saved file is the scenario in use, paths rebased");
    assert_eq!(loaded.spec.sun, session.applied.spec.sun);
    let (code, out, err) = irsim(&["validate", path.to_str().unwrap()]);
    assert_eq!(code, 0, "{out}{err}");
    let out_dir = dir.join("rec");
    let (code, _, err) =
        irsim(&["record", path.to_str().unwrap(), "--out", out_dir.to_str().unwrap(), "--frames", "3", "--quiet"]);
    assert_eq!(code, 0, "{err}");
    let recorded = image::open(out_dir.join("frames/000002.png")).expect("png").into_luma16();
    // `record --frames 3` runs the scenario for 3 frames (which the sky-blur planner takes into account)
    let mut three = loaded.spec.clone();
    three.run.frames = 3;
    let computed = frame_alone(&three.checked(&path).expect("valid"), 2);
    assert_eq!((recorded.width() as usize, recorded.height() as usize), (computed.width(), computed.height()));
    let same = recorded.pixels().zip(computed.pixels()).all(|(r, &c)| f32::from(r.0[0]) == c);
    assert!(same, "the recorded frame 2 is the edited scenario's frame 2");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The Record button writes frames a … b of the run on show; its manifest's scenario, recorded whole, gives those
/// same frames as its frames a … b (the run's length, which the sky is planned over, is the run's, not the part's).
#[test]
fn a_recorded_part_of_the_run_is_reproduced_from_its_manifest() {
    use irsim::cli::run::{RecordPlan, record_scenario};
    let dir = temp_dir("edit_part");
    let s = scene(SCENE);
    let part = dir.join("part");
    let plan = RecordPlan {
        out: part.clone(),
        first_frame: 4,
        frames: 3,
        seed: None,
        force: false,
        noise: true,
        vibration: true,
        format: irsim::record::FrameFormat::Png16,
        png: irsim::imaging::frame::PngCompression::Fast,
        masks: false,
        reproducible: false,
    };
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    record_scenario(&s, &plan, &stop, &mut |_, _| {}).expect("recorded");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(part.join("manifest.json")).unwrap()).unwrap();
    assert_eq!((manifest["first_frame"].as_u64(), manifest["frames"].as_u64()), (Some(4), Some(3)));
    assert_eq!(manifest["scenario"]["run"]["frames"].as_u64(), Some(12), "the run as built");
    let again = dir.join("again.json");
    std::fs::write(&again, serde_json::to_string(&manifest["scenario"]).unwrap()).unwrap();
    let whole = dir.join("whole");
    let (code, _, err) = irsim(&["record", again.to_str().unwrap(), "--out", whole.to_str().unwrap(), "--quiet"]);
    assert_eq!(code, 0, "{err}");
    for i in 0..3 {
        let a = image::open(part.join(format!("frames/{i:06}.png"))).expect("png").into_luma16();
        let b = image::open(whole.join(format!("frames/{:06}.png", i + 4))).expect("png").into_luma16();
        assert!(a == b, "part frame {i} is the whole run's frame {}", i + 4);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
