//! Every row of the independent reference tables (mpmath, 25+ digits) in `tests/data/`.

use irsim::physics::atmosphere::AirTemperature;
use irsim::physics::brdf::CookTorrance;
use irsim::physics::planck::{Band, C2_M_K, band_radiance};
use irsim::physics::skin::{StagnationModel, self_radiance, skin_temperatures};

/// Rows of a CSV file with a header line, split on commas (the fields we read contain none).
fn rows(name: &str) -> Vec<Vec<String>> {
    let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines().skip(1).filter(|l| !l.trim().is_empty()).map(|l| l.split(',').map(str::to_owned).collect()).collect()
}

fn num(s: &str) -> f64 {
    // Rust parses values below the smallest subnormal as 0, as the table's README asks of us.
    s.trim().parse().unwrap_or_else(|_| panic!("not a number: {s}"))
}

#[test]
fn planck_table_every_row() {
    let table = rows("planck_table.csv");
    assert!(table.len() >= 120);
    let mut worst: f64 = 0.0;
    for r in &table {
        let (t, lo, hi, want) = (num(&r[0]), num(&r[1]), num(&r[2]), num(&r[3]));
        let got = band_radiance(Band::try_new(lo, hi).unwrap(), t, 1.0);
        assert!(got.is_finite() && got >= 0.0);
        if want == 0.0 {
            assert_eq!(got, 0.0, "T={t} [{lo}, {hi}]: expected exactly 0 (underflow or empty band), got {got:e}");
            continue;
        }
        let x = C2_M_K / (hi * 1e-6 * t);
        let mut tol = f64::max(1e-13, 4.0 * (x + 4.0) * 2.2e-16);
        if hi - lo < 1e-3 {
            tol = 1e-10; // decimal band edges limit a 1e-4 µm wide band
        }
        let rel = ((got - want) / want).abs();
        worst = worst.max(rel / tol);
        assert!(rel <= tol, "T={t} [{lo}, {hi}]: got {got:e}, want {want:e}, rel {rel:e} > tol {tol:e}");
    }
    eprintln!("planck: worst error / tolerance = {worst:.3}");
}

#[test]
fn stagnation_table_every_row() {
    let model = StagnationModel::default();
    for r in rows("stagnation_table.csv") {
        let (h_km, mach) = (num(&r[0]), num(&r[1]));
        let t = skin_temperatures(&model, h_km * 1000.0, mach, &AirTemperature::default()).unwrap();
        let close = |got: f64, want: f64, tol: f64| ((got - want) / want).abs() <= tol;
        assert!(close(t.ambient_temp_k, num(&r[2]), 1e-14), "H={h_km}: T∞ {} vs {}", t.ambient_temp_k, r[2]);
        assert!(close(t.skin_temp_k, num(&r[3]), 1e-14), "H={h_km} M={mach}: Ts {} vs {}", t.skin_temp_k, r[3]);
        let lw = self_radiance(Band::LWIR_8_12, t.skin_temp_k, 0.8).unwrap();
        let mw = self_radiance(Band::MWIR_3_5, t.skin_temp_k, 0.8).unwrap();
        assert!(close(lw, num(&r[4]), 1e-12), "H={h_km} M={mach}: L 8-12 {lw} vs {}", r[4]);
        assert!(close(mw, num(&r[5]), 1e-12), "H={h_km} M={mach}: L 3-5 {mw} vs {}", r[5]);
    }
}

#[test]
fn cook_torrance_table_every_finite_row() {
    let table = rows("cook_torrance_table.csv");
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for r in &table {
        let (m, tv, tl, phi) = (num(&r[0]), num(&r[1]), num(&r[2]), num(&r[3]));
        let ct = CookTorrance { kd: 0.5, ks: 0.5, f0: 0.04, roughness: m };
        let got = ct.evaluate_angles(tv, tl, phi);
        assert!(got.f_per_sr.is_finite() && got.f_per_sr >= 0.0, "{r:?}");
        let (spec, total) = (r[11].trim(), r[12].trim());
        if spec == "inf" || spec == "nan" {
            continue; // v = −l: no finite value to match
        }
        let (want_spec, want_total) = (num(spec), num(total));
        let tol = 1e-10;
        if want_spec == 0.0 {
            // the true value is below the smallest subnormal or exactly 0
            assert!(got.specular_per_sr < 1e-300, "{r:?}: spec {:e}", got.specular_per_sr);
        } else {
            let rel = ((got.specular_per_sr - want_spec) / want_spec).abs();
            worst = worst.max(rel);
            assert!(
                rel <= tol,
                "m={m} θv={tv} θl={tl} φ={phi}: spec {:e} vs {want_spec:e} (rel {rel:e})",
                got.specular_per_sr
            );
        }
        let rel = ((got.f_per_sr - want_total) / want_total).abs();
        worst = worst.max(rel);
        assert!(rel <= tol, "m={m} θv={tv} θl={tl} φ={phi}: f {:e} vs {want_total:e} (rel {rel:e})", got.f_per_sr);
        checked += 1;
    }
    eprintln!("cook-torrance: {checked} finite rows, worst relative error {worst:.2e}");
    assert!(checked >= 960, "checked {checked}");
}

#[test]
fn photon_radiance_and_derivatives_every_row() {
    use irsim::physics::planck::{Measure, band_radiance_derivative, photon_band_radiance};
    let table = rows("planck_photon_table.csv");
    assert!(table.len() >= 60);
    let mut worst = [0f64; 3];
    for r in &table {
        let (t, lo, hi) = (num(&r[0]), num(&r[1]), num(&r[2]));
        let band = Band::try_new(lo, hi).unwrap();
        let got = [
            photon_band_radiance(band, t, 1.0),
            band_radiance_derivative(Measure::Energy, band, t),
            band_radiance_derivative(Measure::Photon, band, t),
        ];
        for (i, (g, w)) in got.iter().zip([num(&r[3]), num(&r[4]), num(&r[5])]).enumerate() {
            let rel = ((g - w) / w).abs();
            worst[i] = worst[i].max(rel);
            // the radiance is exact like the energy series; the derivative loses a few digits in the bracket
            let tol = if i == 0 { 1e-12 } else { 1e-10 };
            assert!(rel <= tol, "column {} at T={t} [{lo}, {hi}]: got {g:e}, want {w:e}, rel {rel:e}", i + 3);
        }
    }
    eprintln!("photon table: worst relative errors {worst:?}");
}
