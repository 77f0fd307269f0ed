//! The `irsim calc` commands: JSON output, reference values and exit codes.

use std::process::Command;

fn irsim(args: &[&str]) -> (i32, serde_json::Value, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_irsim")).args(args).output().expect("run irsim");
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    let json = serde_json::from_str(stdout.trim()).unwrap_or(serde_json::Value::Null);
    (out.status.code().unwrap_or(-1), json, String::from_utf8_lossy(&out.stderr).to_string())
}

#[test]
fn band_radiance_matches_the_reference() {
    let (code, v, _) = irsim(&["calc", "band-radiance", "--temp-k", "300", "--band-um", "8", "12"]);
    assert_eq!(code, 0);
    let l = v["radiance_w_m2_sr"].as_f64().unwrap();
    assert!(((l - 38.50042393334786) / 38.50042393334786).abs() < 1e-13, "{l}");
    let (_, v, _) = irsim(&["calc", "band-radiance", "--temp-k", "300", "--band-um", "8", "12", "--emissivity", "0.5"]);
    assert!((v["radiance_w_m2_sr"].as_f64().unwrap() - 0.5 * 38.50042393334786).abs() < 1e-12);
}

#[test]
fn skin_matches_the_stagnation_table() {
    let (code, v, _) = irsim(&["calc", "skin", "--altitude-km", "20", "--mach", "1.2"]);
    assert_eq!(code, 0);
    assert!((v["ambient_temp_k"].as_f64().unwrap() - 216.65).abs() < 1e-9);
    assert!((v["skin_temp_k"].as_f64().unwrap() - 257.362868).abs() < 1e-9);
}

#[test]
fn brdf_prints_f_and_specular() {
    let args = [
        "calc",
        "brdf",
        "--roughness",
        "0.2",
        "--f0",
        "0.04",
        "--kd",
        "0.5",
        "--ks",
        "0.5",
        "--view-zenith-deg",
        "30",
        "--light-zenith-deg",
        "30",
        "--azimuth-deg",
        "180",
    ];
    let (code, v, _) = irsim(&args);
    assert_eq!(code, 0);
    let f = v["f_per_sr"].as_f64().unwrap();
    let s = v["specular_per_sr"].as_f64().unwrap();
    assert!((f - (0.5 / std::f64::consts::PI + 0.5 * s)).abs() < 1e-15);
    // exactly opposite directions: finite
    let (code, v, _) = irsim(&[
        "calc",
        "brdf",
        "--roughness",
        "0.2",
        "--view-zenith-deg",
        "90",
        "--light-zenith-deg",
        "90",
        "--azimuth-deg",
        "180",
    ]);
    assert_eq!(code, 0);
    assert!(v["f_per_sr"].as_f64().unwrap().is_finite());
}

#[test]
fn signal_prints_the_whole_chain() {
    let (code, v, _) = irsim(&["calc", "signal"]);
    assert_eq!(code, 0);
    for key in [
        "ambient_temp_k",
        "skin_temp_k",
        "self_radiance_w_m2_sr",
        "reflected_radiance_w_m2_sr",
        "tau",
        "voltage_v",
        "gray",
    ] {
        assert!(v[key].as_f64().is_some_and(f64::is_finite), "{key} missing in {v}");
    }
    let (code, v, _) =
        irsim(&["calc", "signal", "--reflection", "ellipsoid", "--extinction-per-km", "0.1", "--range-km", "20"]);
    assert_eq!(code, 0);
    assert!(v["tau"].as_f64().unwrap() < 1.0);
}

#[test]
fn bad_flags_exit_2_with_a_message() {
    for args in [
        &["calc", "band-radiance", "--temp-k", "300", "--band-um", "12", "8"][..],
        &["calc", "band-radiance", "--temp-k", "300", "--band-um", "-1", "8"],
        &["calc", "band-radiance", "--temp-k", "-5", "--band-um", "8", "12"],
        &["calc", "band-radiance", "--temp-k", "abc", "--band-um", "8", "12"],
        &["calc", "skin", "--altitude-km", "90", "--mach", "1"],
        &["calc", "skin", "--altitude-km", "-6", "--mach", "1"],
        &["calc", "skin", "--altitude-km", "10", "--mach", "-1"],
        &["calc", "brdf", "--roughness", "0", "--view-zenith-deg", "0", "--light-zenith-deg", "0"],
        &["calc", "signal", "--v-low", "2", "--v-high", "1"],
        &["calc", "signal", "--tau", "1.5"],
        &["calc", "nonsense"],
    ] {
        let (code, _, stderr) = irsim(args);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert!(!stderr.trim().is_empty(), "{args:?}: no message");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
}

#[test]
fn transmittance_prints_both_taus_path_radiance_and_the_cell() {
    let base = [
        "calc",
        "transmittance",
        "--model",
        "midlatitude-summer",
        "--aerosol",
        "rural",
        "--visibility-km",
        "23",
        "--observer-alt-km",
        "8",
        "--target-alt-km",
        "8",
        "--range-km",
        "4",
        "--band-um",
        "8",
        "12",
    ];
    let (code, v, err) = irsim(&base);
    assert_eq!(code, 0, "{err}");
    let avg = v["transmittance_band_average"].as_f64().unwrap();
    let weighted = v["transmittance_spectrum_weighted"].as_f64().unwrap();
    assert!(avg > 0.8 && avg < 1.0 && weighted > 0.8 && weighted < 1.0, "{v}");
    assert!(v["path_radiance_w_m2_sr"].as_f64().unwrap() > 0.0);
    assert_eq!(v["grid_cell"]["lower_alt_km"], serde_json::json!([8.0, 9.0]));
    // a hotter target weights the band differently
    let mut hot = base.to_vec();
    hot.extend(["--temp-k", "900"]);
    let (_, v2, _) = irsim(&hot);
    assert_ne!(v2["transmittance_spectrum_weighted"], v["transmittance_spectrum_weighted"]);
    assert_eq!(v2["transmittance_band_average"], v["transmittance_band_average"]);
}

#[test]
fn transmittance_refuses_paths_off_the_table() {
    for (flag, value, says) in [
        ("--observer-alt-km", "30", "--observer-alt-km: 30 is outside"),
        ("--range-km", "1", "--range-km"),
        ("--range-km", "500", "--range-km"),
        ("--visibility-km", "0.1", "--visibility-km"),
        ("--range-km", "nan", "--range-km"),
    ] {
        let mut args =
            vec!["calc", "transmittance", "--observer-alt-km", "1", "--target-alt-km", "3", "--range-km", "10"];
        let i = args.iter().position(|a| *a == flag);
        match i {
            Some(i) => args[i + 1] = value,
            None => args.extend([flag, value]),
        }
        let (code, _, err) = irsim(&args);
        assert_eq!(code, 2, "{flag} {value}: {err}");
        assert!(err.contains(says), "{flag} {value}: {err}");
    }
    let (code, _, err) =
        irsim(&["calc", "transmittance", "--observer-alt-km", "0.05", "--target-alt-km", "0.05", "--range-km", "80"]);
    assert_eq!(code, 2);
    assert!(err.contains("below the ground"), "{err}");
    let (code, _, err) = irsim(&[
        "calc",
        "transmittance",
        "--model",
        "martian",
        "--observer-alt-km",
        "1",
        "--target-alt-km",
        "1",
        "--range-km",
        "1",
    ]);
    assert_eq!(code, 2, "{err}");
}

#[test]
fn sky_prints_the_clear_sky_and_refuses_the_ground() {
    let sky = |alt: &str, elevation: &str| {
        irsim(&[
            "calc",
            "sky",
            "--model",
            "us-standard-1976",
            "--aerosol",
            "none",
            "--observer-alt-km",
            alt,
            "--elevation-deg",
            elevation,
        ])
    };
    let (code, zenith, err) = sky("0", "90");
    assert_eq!(code, 0, "{err}");
    let bt = |v: &serde_json::Value| v["brightness_temp_k"].as_f64().unwrap();
    // a clear 8–12 µm zenith sky from sea level: about 210 K, colder than the air, warmer than space
    assert!(bt(&zenith) > 190.0 && bt(&zenith) < 240.0, "{zenith}");
    let tau = zenith["transmittance_band_average"].as_f64().unwrap();
    assert!(tau > 0.6 && tau < 0.9, "{zenith}");
    // toward the horizon the path thickens: warmer, up to the air's own temperature
    let (_, low, _) = sky("0", "2");
    assert!(bt(&low) > bt(&zenith) + 30.0 && bt(&low) < 290.0, "{low}");
    // from 10 km the sky is far colder, and the limb below the horizontal is still sky
    let (_, high, _) = sky("10", "90");
    assert!(bt(&high) < bt(&zenith) - 30.0, "{high}");
    let (code, _, err) = sky("10", "-1");
    assert_eq!(code, 0, "{err}");
    for (alt, elevation, says) in
        [("10", "-5", "looks at the ground"), ("30", "10", "--observer-alt-km"), ("1", "nan", "--elevation-deg")]
    {
        let (code, _, err) = sky(alt, elevation);
        assert_eq!(code, 2, "{alt} {elevation}: {err}");
        assert!(err.contains(says), "{alt} {elevation}: {err}");
    }
}
