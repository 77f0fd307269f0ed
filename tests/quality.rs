//! `[quality]`: the presets, overrides, `--quality` and the resolved settings in the manifest; the fields that
//! moved into it are refused where they were, with the new name.

mod common;

use std::path::Path;

use common::{irsim, root, temp_dir};
use irsim::scenario::load::{Format, load_str};
use irsim::scenario::{CheckedScenario, QualityPreset, ScenarioError};

fn load_toml(text: &str) -> Result<CheckedScenario, ScenarioError> {
    load_str(text, Format::Toml, Path::new("quality.toml"), &root().join("scenarios"))
}

/// A small valid scenario with a generated sky and one target in view.
const BASE: &str = r#"
[run]
frames = 3

[sensor]
width = 64
height = 48
pixel_pitch_um = 17
focal_length_mm = 50
aperture_mm = 50
band_um = [8, 12]

[observer]
trajectory = { kind = "constant_velocity", position_m = [0, 0, 1000] }
pointing = { mode = "look_at", target_m = [0, 3000, 1100] }

[sky]
generate = { kind = "cumulus", seed = 2 }
anchor_m = [0, 20000, 2000]
width_m = 20000
height_m = 8000
max_texels = 256

[[targets]]
name = "a"
trajectory = { kind = "constant_velocity", position_m = [-20, 3000, 1100], velocity_m_s = [30, 0, 0] }
semi_axes_m = [2, 1, 0.5]
"#;

#[test]
fn moved_fields_are_refused_where_they_were_with_the_new_name() {
    for (extra, field, new) in [
        ("[sensor.psf]\nsky_blur = \"frame\"\n", "sensor.psf.sky_blur", "sky_blur"),
        ("[sensor.psf]\nmethod = \"direct\"\n", "sensor.psf.method", "psf_method"),
        ("[sensor.blob]\nsampling = { mode = \"point\" }\n", "sensor.blob.sampling", "blob_sampling"),
        (
            "[sensor.noise]\npoisson_normal_threshold = 10\n",
            "sensor.noise.poisson_normal_threshold",
            "poisson_normal_threshold_e",
        ),
        ("[fusion]\nsolver = { method = \"direct\" }\n", "fusion", "fusion_solver"),
    ] {
        // sub-tables of [sensor] go before [observer]
        let text = if extra.starts_with("[sensor.") {
            BASE.replacen("[observer]", &format!("{extra}\n[observer]"), 1)
        } else {
            format!("{BASE}\n{extra}")
        };
        let e = load_toml(&text).expect_err(field);
        assert_eq!(e.field, field, "{e}");
        assert!(e.line > 0 && e.message.contains(&format!("[quality] {new}")), "{e}");
    }
    let text = BASE.replacen("max_texels = 256", "max_texels = 256\nsampling = { mode = \"nearest\" }", 1);
    assert_eq!(load_toml(&text).unwrap_err().field, "sky.sampling");
    let text = BASE.replacen("semi_axes_m = [2, 1, 0.5]", "semi_axes_m = [2, 1, 0.5]\nreflection = \"ellipsoid\"", 1);
    assert_eq!(load_toml(&text).unwrap_err().field, "targets[0].reflection");
}

#[test]
fn a_preset_and_overrides_resolve_into_the_scenario() {
    let s = load_toml(BASE).unwrap();
    assert_eq!(s.quality.preset, QualityPreset::Standard);
    let s = load_toml(&format!("{BASE}\n[quality]\npreset = \"reference\"\npsf_skip_below_dn = 0.5\n")).unwrap();
    assert_eq!(s.quality.preset, QualityPreset::Reference);
    assert_eq!(s.quality.psf_skip_below_dn, 0.5);
    // the sensor's resolved settings come from it
    let psf = s.sensor.psf.expect("psf on");
    assert_eq!((psf.skip_below_dn, psf.method), (0.5, s.quality.psf_method));
    assert_eq!(s.sensor.noise.poisson_normal_threshold, s.quality.poisson_normal_threshold_e);
    let e = load_toml(&format!("{BASE}\n[quality]\nspan_tolerance_px = 2\n")).unwrap_err();
    assert_eq!(e.field, "quality.span_tolerance_px", "{e}");
    assert!(e.line > 0, "{e}");
}

#[test]
fn every_preset_records_and_the_manifest_says_what_it_resolved_to() {
    let dir = temp_dir("quality");
    std::fs::create_dir_all(&dir).unwrap();
    let scenario = dir.join("s.toml");
    std::fs::write(&scenario, format!("{BASE}\n[quality]\npreset = \"draft\"\nreflection = \"facet\"\n")).unwrap();
    let scenario = scenario.to_str().unwrap();
    for preset in ["draft", "standard", "reference"] {
        let out = dir.join(preset);
        let out = out.to_str().unwrap();
        let (code, _, err) = irsim(&["record", scenario, "--out", out, "--quality", preset, "--quiet"]);
        assert_eq!(code, 0, "{err}");
        // the file's override is dropped, and said to be
        assert!(err.contains("reflection") && err.contains("not used"), "{err}");
        let manifest: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(Path::new(out).join("manifest.json")).unwrap()).unwrap();
        let q = &manifest["resolved"]["quality"];
        assert_eq!(q["preset"], preset);
        assert_eq!(q["reflection"], "ellipsoid", "{manifest:#}");
        assert_eq!(manifest["scenario"]["quality"]["preset"], preset);
        assert!(manifest["resolved"]["sky_blur_used"].is_string(), "{manifest:#}");
    }
    // without the flag the file's table holds, and `validate` prints it, overrides starred
    let (code, out, err) = irsim(&["validate", scenario]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("   preset = \"draft\"") && out.contains("  *reflection = \"facet\""), "{out}");
    let (code, _, err) = irsim(&["record", scenario, "--out", "x", "--quality", "best"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("draft, standard or reference"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `irsim bench report` on the smallest configuration writes the report and its plots, every number in it is
/// finite, and it refuses to overwrite a report without --force.
#[test]
fn bench_report_writes_finite_tables_and_plots() {
    let dir = temp_dir("report");
    let scenarios = dir.join("scenarios");
    std::fs::create_dir_all(&scenarios).unwrap();
    // the dome alone (no sky image to prefilter), which keeps the reference runs of a debug build short
    let (sky, targets) = (BASE.find("[sky]").unwrap(), BASE.find("[[targets]]").unwrap());
    std::fs::write(scenarios.join("small.toml"), format!("{}{}", &BASE[..sky], &BASE[targets..])).unwrap();
    let out = dir.join("out");
    let args =
        ["bench", "report", "--tiny", "--out", out.to_str().unwrap(), "--scenarios", scenarios.to_str().unwrap()];
    let (code, stdout, err) = irsim(&args);
    assert_eq!(code, 0, "{stdout}{err}");
    let md = std::fs::read_to_string(out.join("speed_vs_error.md")).unwrap();
    for png in [
        "presets_scenarios.png",
        "presets_pipeline.png",
        "presets_pipeline_centroid.png",
        "switches.png",
        "scaling.png",
    ] {
        let image = image::open(out.join(png)).unwrap_or_else(|e| panic!("{png}: {e}"));
        assert_eq!((image.width(), image.height()), (900, 600), "{png}");
        assert!(md.contains(&format!("({png})")), "{png} is linked");
    }
    // every table cell that is a number is finite, and the error columns are there
    let mut numbers = 0;
    for line in md.lines().filter(|l| l.starts_with('|') && !l.starts_with("|---")) {
        for cell in line.split('|').map(str::trim) {
            let lower = cell.to_lowercase();
            assert!(!lower.contains("nan") && !lower.contains("inf"), "{line}");
            for part in cell.split(" / ") {
                if let Ok(v) = part.trim_end_matches('×').parse::<f64>() {
                    assert!(v.is_finite(), "{line}");
                    numbers += 1;
                }
            }
        }
    }
    assert!(numbers > 40, "{numbers} numbers in\n{md}");
    assert!(md.contains("| small |") && md.contains("`psf_energy_cutoff`"), "{md}");
    // the presets' speed-up per frame and over the scenario's whole run, both numbers
    let small = md.lines().find(|l| l.starts_with("| small |")).unwrap();
    assert!(md.contains("per frame / whole run |") && small.ends_with("× |") && small.contains("× / "), "{small}");
    assert!(md.contains("| `ziggurat` |") && md.contains("| `table` |"), "the normal samplers' rows: {md}");
    assert!(md.contains("## OpenCV's seamlessClone"), "{md}");
    // each stage beside its bound, and recording against headless
    assert!(
        md.contains("| 256 × 256 | 1 | 1 |")
            && md.contains("| 640 × 512 | 1 | 1 |")
            && md.contains("| 640 × 512 | 10 | 1 |"),
        "the bounds' rows: {md}"
    );
    assert!(md.contains("| 256 × 256, 1 target |") && md.contains("| 640 × 512, 10 targets |"), "recording: {md}");
    let opencv = std::process::Command::new("python3").args(["-c", "import cv2, numpy"]).status();
    if std::env::var_os("IRSIM_REQUIRE_OPENCV").is_some() || opencv.is_ok_and(|s| s.success()) {
        assert!(md.contains("| 17×17 | 225 |"), "OpenCV's row: {md}");
    }
    assert!(md.contains("## Atmosphere: the LOWTRAN7 table"), "{md}");
    assert!(md.contains("| 8–12 µm | ") && !md.contains("Not measured: the off-grid"), "the LOWTRAN rows: {md}");
    let (code, _, err) = irsim(&args);
    assert_eq!(code, 2, "a second report needs --force: {err}");
    assert!(err.contains("--force"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `fusion_skip_below_sigma`: a target under the threshold is added to the frame exactly as the `additive`
/// guidance adds it, and at 0 every target is fused as before.
#[test]
fn a_target_below_the_fusion_threshold_is_added_not_fused() {
    let dir = temp_dir("fusion_skip");
    std::fs::create_dir_all(&dir).unwrap();
    let record = |name: &str, quality: &str| -> Vec<Vec<u8>> {
        let scenario = dir.join(format!("{name}.toml"));
        std::fs::write(&scenario, format!("{BASE}\n[quality]\n{quality}\n")).unwrap();
        let out = dir.join(name);
        let args = ["record", scenario.to_str().unwrap(), "--out", out.to_str().unwrap(), "--no-noise", "--quiet"];
        let (code, _, err) = irsim(&args);
        assert_eq!(code, 0, "{err}");
        let mut files: Vec<_> = std::fs::read_dir(out.join("frames")).unwrap().map(|e| e.unwrap().path()).collect();
        files.sort();
        assert_eq!(files.len(), 3, "{files:?}");
        files.iter().map(|f| std::fs::read(f).unwrap()).collect()
    };
    let skipped = record("skipped", "fusion_skip_below_sigma = 100");
    let additive = record("additive", "fusion_guidance = \"additive\"");
    let fused = record("fused", "fusion_skip_below_sigma = 0");
    assert_eq!(skipped, additive);
    assert_ne!(skipped, fused, "the target's fusion must change the frames");
    let e = load_toml(&format!("{BASE}\n[quality]\nfusion_skip_below_sigma = -1\n")).unwrap_err();
    assert_eq!(e.field, "quality.fusion_skip_below_sigma", "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
