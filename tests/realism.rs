//! The physical camera and the sky: noise against NETD, electrons against a hand calculation, no black band.

use std::path::PathBuf;

use irsim::physics::detector::Preset;
use irsim::physics::noise::{Readout, ReadoutMaps};
use irsim::physics::planck::{Measure, band_radiance_in};
use irsim::scenario::{SensorSpec, load};
use irsim::sim::{RunOptions, build_app, current_frame, step};

fn readout(preset: Preset) -> (irsim::scenario::ResolvedSensor, Readout) {
    let s = SensorSpec { preset: Some(preset), ..Default::default() }.resolve(&Default::default()).unwrap();
    let r = s.model.readout(100.0, irsim::physics::random::NormalSampler::Ziggurat);
    (s, r)
}

/// A uniform 300 K scene through the readout, unrounded: the pixels' standard deviation is the NETD-derived σ
/// (NETD × DN per kelvin) within 2 %.
#[test]
fn temporal_noise_of_a_uniform_scene_matches_the_netd() {
    for preset in Preset::ALL {
        let (s, r) = readout(preset);
        let m = &s.model;
        let report = m.report(300.0);
        let want = report.netd_mk * 1e-3 * report.dn_per_k;
        let l = band_radiance_in(m.measure(), m.band, 300.0, 1.0) as f32;
        let (w, h) = (512, 512);
        let mut px = vec![l; w * h];
        r.apply(&mut px, w, ReadoutMaps::default(), true, 3, 0, None, None);
        let n = px.len() as f64;
        let mean = px.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let sd = (px.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!((sd / want - 1.0).abs() < 0.02, "{}: σ {sd:.4} DN, NETD-derived {want:.4} DN", preset.name());
        // the NETD the preset promises
        let promised = match preset {
            Preset::CooledMwirInsb => (15.0, 25.0),
            Preset::UncooledLwirMicrobolometer => (39.9, 40.1),
            Preset::PaperLwir256 => (49.9, 50.1),
        };
        assert!((promised.0..promised.1).contains(&report.netd_mk), "{}: {} mK", preset.name(), report.netd_mk);
    }
}

/// The cooled InSb preset looking at a uniform 300 K blackbody: electrons by hand from the photon radiance,
/// and back from the DN the readout gives.
#[test]
fn electrons_of_a_300_k_blackbody_are_conserved() {
    let (s, r) = readout(Preset::CooledMwirInsb);
    let m = &s.model;
    // by hand: η · t · A_d · π/(4N²) · τ_opt · L_photon(3–5 µm, 300 K)
    let l_photon = band_radiance_in(Measure::Photon, m.band, 300.0, 1.0);
    let n_f: f64 = 0.1 / 0.025;
    let area = 15e-6f64 * 15e-6;
    let hand = 0.8 * 7e-3 * area * std::f64::consts::PI / (4.0 * n_f * n_f) * 0.85 * l_photon;
    let model = m.signal_per_radiance() * l_photon;
    assert!((model / hand - 1.0).abs() < 1e-12, "model {model} e⁻, hand {hand} e⁻");
    // about 2 million electrons, 30 % of the 7 Me⁻ well
    assert!((1.5e6..3e6).contains(&hand), "{hand}");
    let mut px = vec![l_photon as f32; 64];
    r.apply(&mut px, 64, ReadoutMaps::default(), false, 1, 0, None, None);
    let back = (f64::from(px[0]) - m.adc.offset_dn) * m.adc.gain - m.dark_signal();
    assert!((back / hand - 1.0).abs() < 1e-6, "through the ADC and back: {back} e⁻ vs {hand} e⁻");
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// No shipped scenario has a band of constant rows (rays that met nothing) or pixels at 0.
#[test]
fn no_black_band_in_any_shipped_scenario() {
    for entry in std::fs::read_dir(root().join("scenarios")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        let s = load(&path).unwrap_or_else(|e| panic!("{e}"));
        let mut app = build_app(&s, RunOptions::default()).unwrap();
        step(&mut app);
        let f = current_frame(&mut app);
        let (w, h) = (f.width(), f.height());
        let offset = s.sensor.model.adc.offset_dn as f32;
        let mut constant_rows = 0;
        for y in 0..h {
            let row = &f.pixels()[y * w..(y + 1) * w];
            if row.iter().all(|&v| v == row[0]) {
                constant_rows += 1;
            }
        }
        assert_eq!(constant_rows, 0, "{}: {constant_rows} constant rows", path.display());
        // dead pixels read the offset; nothing reads far below it
        let low = f.pixels().iter().filter(|&&v| v < offset - 50.0).count();
        assert_eq!(low, 0, "{}: {low} pixels below the ADC offset", path.display());
    }
}
