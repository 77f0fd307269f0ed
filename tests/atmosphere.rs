//! The LOWTRAN weather in scenarios: its fields and their errors, the grid checked over the whole run, and the
//! pipeline's targets seen through the table's lines of sight.

mod common;

use std::path::Path;

use common::{SMALL_SCENARIO, irsim, root};
use glam::DVec3;
use irsim::physics::lowtran::{Aerosol, AtmosphereTable, ModelAtmosphere, Weather};
use irsim::physics::planck::{band_radiance_in, brightness_temperature};
use irsim::scenario::load::{Format, load_str};
use irsim::scenario::{CheckedScenario, ScenarioError};
use irsim::sim::{RunOptions, build_app, step};

/// [`SMALL_SCENARIO`] in LOWTRAN's mid-latitude summer, rural 23 km; the sun below the horizon (no reflection).
fn base() -> String {
    format!(
        "{SMALL_SCENARIO}\n[atmosphere]\nmodel = \"midlatitude_summer\"\naerosol = \"rural\"\nvisibility_km = 23\n\n\
         [sun]\nelevation_deg = -10\n"
    )
}

fn load(text: &str) -> Result<CheckedScenario, ScenarioError> {
    load_str(text, Format::Toml, Path::new("weather.toml"), &root().join("scenarios"))
}

fn with(replace: &str, by: &str) -> String {
    let base = base();
    assert!(base.contains(replace), "{replace}");
    base.replacen(replace, by, 1)
}

fn refused(text: &str, field: &str) -> String {
    let e = load(text).expect_err("must be refused");
    assert_eq!(e.field, field, "{e}");
    assert!(e.line > 0 && e.column > 0, "no position: {e}");
    e.to_string()
}

#[test]
fn weather_fields_are_checked_with_their_path() {
    load(&base()).unwrap();
    let both = with("visibility_km = 23", "visibility_km = 23\ntransmittance = { model = \"fixed\", tau = 0.5 }");
    let e = refused(&both, "atmosphere.transmittance");
    assert!(e.contains("not both"), "{e}");
    refused(&with("model = \"midlatitude_summer\"\n", ""), "atmosphere.aerosol");
    let e = refused(&with("visibility_km = 23", "visibility_km = 80"), "atmosphere.visibility_km");
    assert!(e.contains("2, 5, 10, 23, 50"), "{e}");
    refused(&with("aerosol = \"rural\"", "aerosol = \"none\""), "atmosphere.visibility_km");
    refused(&with("aerosol = \"rural\"", "aerosol = \"urban\"").replace("= 23", "= 40"), "atmosphere.visibility_km");
    refused(&with("visibility_km = 23", "visibility_km = nan"), "atmosphere.visibility_km");
    refused(&with("model = \"midlatitude_summer\"", "model = \"martian\""), "atmosphere.model");
    let e = refused(&with("band_um = [8, 12]", "band_um = [0.5, 0.9]"), "atmosphere.model");
    assert!(e.contains("1–14 µm"), "{e}");
    // the overrides still work alone, and no aerosol needs no visibility
    load(&with("model = \"midlatitude_summer\"\naerosol = \"rural\"\nvisibility_km = 23", "t0_k = 290")).unwrap();
    load(&with("aerosol = \"rural\"\nvisibility_km = 23", "aerosol = \"none\"")).unwrap();
    load(&with("model = \"midlatitude_summer\"", "model = \"us_standard_1976\"")).unwrap();
    // the air follows the model atmosphere's profile: a sea-level temperature beside it is refused
    let e = refused(&with("visibility_km = 23", "visibility_km = 23\nt0_k = 290"), "atmosphere.t0_k");
    assert!(e.contains("294.2"), "{e}");
}

#[test]
fn the_clear_sky_source_is_checked_against_the_weather() {
    let dome = |fields: &str| base().replace("[atmosphere]", &format!("[sky.dome]\n{fields}\n\n[atmosphere]"));
    load(&dome("clear_sky = \"lowtran\"")).unwrap();
    load(&dome("clear_sky = \"parametric\"\nscale_height_km = 3")).unwrap();
    let e = refused(&dome("scale_height_km = 3"), "sky.dome.scale_height_km");
    assert!(e.contains("parametric"), "{e}");
    refused(&dome("clear_sky = \"lowtran\"\nzenith_emissivity = 0.3"), "sky.dome.zenith_emissivity");
    let override_only = dome("clear_sky = \"lowtran\"")
        .replace("model = \"midlatitude_summer\"\naerosol = \"rural\"\nvisibility_km = 23", "");
    refused(&override_only, "sky.dome.clear_sky");
    refused(&dome("clear_sky = \"modtran\""), "sky.dome.clear_sky");
}

#[test]
fn lines_of_sight_outside_the_table_are_refused_at_load() {
    // a target climbing through 20 km during the run
    let climb = with(
        "position_m = [10, 4000, 1010], velocity_m_s = [-80, 0, 0]",
        "position_m = [10, 4000, 19990], velocity_m_s = [0, 0, 400]",
    );
    let e = refused(&climb, "targets[1].trajectory");
    assert!(e.contains("frame 1") && e.contains("target_alt_km"), "{e}");
    // beyond 100 km
    let far = with("position_m = [10, 4000, 1010]", "position_m = [10, 120000, 1010]");
    let e = refused(&far, "targets[1].trajectory");
    assert!(e.contains("range_km"), "{e}");
    // through the ground: a target far below the horizon
    let low = with("position_m = [10, 4000, 1010]", "position_m = [10, 80000, 0]")
        .replace("position_m = [0, 0, 1000] }", "position_m = [0, 0, 200] }");
    let e = refused(&low, "targets[1].trajectory");
    assert!(e.contains("below the ground"), "{e}");
    // an observer above the table
    let high = with("position_m = [0, 0, 1000] }", "position_m = [0, 0, 21000] }");
    refused(&high, "observer.trajectory");
    // the same scenes are fine with an override
    let over = "model = \"midlatitude_summer\"\naerosol = \"rural\"\nvisibility_km = 23";
    load(&climb.replace(over, "transmittance = { model = \"fixed\", tau = 0.8 }")).unwrap();
}

#[test]
fn the_cli_names_file_line_and_field() {
    let dir = common::temp_dir("weather_cli");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    std::fs::write(&path, with("visibility_km = 23", "visibility_km = 1")).unwrap();
    let (code, _, err) = irsim(&["validate", path.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("bad.toml:") && err.contains("atmosphere.visibility_km"), "{err}");
    let good = dir.join("good.toml");
    std::fs::write(&good, base()).unwrap();
    let (code, out, err) = irsim(&["validate", good.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("LOWTRAN7, midlatitude_summer model atmosphere, rural aerosol at 23 km visibility"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_target_is_seen_through_the_tables_line_of_sight() {
    let s = load(&base()).unwrap();
    let mut app = build_app(&s, RunOptions::default()).unwrap();
    let labels = step(&mut app);
    let table = AtmosphereTable::shipped().unwrap();
    let weather = Weather { model: ModelAtmosphere::MidlatitudeSummer, aerosol: Aerosol::Rural, visibility_km: 23.0 };
    let (band, measure) = (s.sensor.model.band, s.sensor.model.measure());
    let eye = DVec3::new(0.0, 0.0, 1000.0);
    for (t, start) in labels.targets.iter().zip([DVec3::new(-20.0, 3000.0, 1005.0), DVec3::new(10.0, 4000.0, 1010.0)]) {
        let path = table.path(&weather, 1.0, start.z / 1000.0, eye.distance(start) / 1000.0).unwrap();
        let tau = path.spectrum_weighted_in(measure, band, t.skin_temp_k);
        let l_app =
            tau * band_radiance_in(measure, band, t.skin_temp_k, 0.8) + path.band_path_radiance_in(measure, band);
        let expected = brightness_temperature(measure, band, l_app).unwrap();
        assert!((t.apparent_temp_k - expected).abs() < 1e-6, "{}: {} against {expected}", t.name, t.apparent_temp_k);
        // the target is warmer than the air it is seen through, so the path lowers its apparent temperature
        assert!(t.apparent_temp_k < t.skin_temp_k && tau < 0.95 && tau > 0.3, "{tau}");
    }
}

#[test]
fn haze_lowers_the_contrast() {
    let peak = |text: &str| {
        let s = load(text).unwrap();
        let mut app = build_app(&s, RunOptions { noise: false, ..RunOptions::default() }).unwrap();
        let l = step(&mut app);
        (l.targets[0].local_contrast, l.targets[0].apparent_temp_k)
    };
    // a target 20 K warmer than the air it flies in, seen through the model atmosphere that matches t0_k
    let warm = with("semi_axes_m = [4, 2, 1]\n", "semi_axes_m = [4, 2, 1]\nheating_k = 20\n")
        .replace("midlatitude_summer", "us_standard_1976");
    let clear = peak(&warm.replace("visibility_km = 23", "visibility_km = 50"));
    let hazy = peak(&warm.replace("visibility_km = 23", "visibility_km = 2"));
    assert!(hazy.0 < clear.0 && hazy.0 > 0.0 && hazy.1 < clear.1, "clear {clear:?}, hazy {hazy:?}");
}

#[test]
fn a_sky_image_seen_through_the_air_is_attenuated_toward_the_air() {
    let scenario = root().join("scenarios/paper_vibration.toml");
    let text = std::fs::read_to_string(&scenario).unwrap();
    // the texture: mean absolute difference of neighbouring pixels
    let texture = |text: &str| {
        let s = load_str(text, Format::Toml, &scenario, &root().join("scenarios")).unwrap();
        let options = RunOptions { noise: false, vibration: false, keep_float: true, ..RunOptions::default() };
        let mut app = build_app(&s, options).unwrap();
        step(&mut app);
        let f = irsim::sim::current_frame(&mut app);
        let (w, p) = (f.width(), f.pixels());
        assert!(p.iter().all(|v| v.is_finite()));
        let d: Vec<f64> =
            (0..p.len() - 1).filter(|i| (i + 1) % w != 0).map(|i| f64::from((p[i + 1] - p[i]).abs())).collect();
        d.iter().sum::<f64>() / d.len() as f64
    };
    let plain = texture(&text);
    let through = texture(&text.replace("visibility_km = 50\n", "visibility_km = 50\nsky_path = true\n"));
    // the clouds 30 km away are seen through air that transmits part of them: less contrast, not none
    assert!(through < plain && through > 0.3 * plain, "{plain} {through}");
}
