//! Properties of the radiometric core over random inputs, and its behaviour on extreme ones.

use glam::DVec3;
use irsim::physics::brdf::CookTorrance;
use irsim::physics::noise::{Readout, ReadoutMaps, poisson, stream_rng};
use irsim::physics::planck::{Band, band_radiance, spectral_radiance};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn band_radiance_is_finite_nonnegative_and_rises_with_temperature(
        t in 0.0f64..1e6,
        dt in 0.0f64..1e3,
        lo in 1e-3f64..1e4,
        width in 0.0f64..1e4,
    ) {
        let band = Band::try_new(lo, (lo + width).min(1e4).max(lo)).unwrap();
        let a = band_radiance(band, t, 1.0);
        let b = band_radiance(band, t + dt, 1.0);
        prop_assert!(a.is_finite() && a >= 0.0, "L({t}) = {a}");
        prop_assert!(b.is_finite() && b >= 0.0);
        // non-decreasing, allowing one part in 1e13 of rounding
        prop_assert!(b >= a * (1.0 - 1e-13), "L({t}) = {a} > L({}) = {b}", t + dt);
    }

    #[test]
    fn band_radiance_is_additive_over_adjacent_bands(t in 1.0f64..1e5, lo in 0.1f64..50.0, w1 in 0.001f64..50.0, w2 in 0.001f64..50.0) {
        let whole = band_radiance(Band::try_new(lo, lo + w1 + w2).unwrap(), t, 1.0);
        let parts = band_radiance(Band::try_new(lo, lo + w1).unwrap(), t, 1.0)
            + band_radiance(Band::try_new(lo + w1, lo + w1 + w2).unwrap(), t, 1.0);
        if whole > 1e-290 {
            prop_assert!(((whole - parts) / whole).abs() < 1e-11, "{whole} vs {parts}");
        }
    }

    #[test]
    fn spectral_radiance_is_finite(t in 0.0f64..1e6, l in 1e-3f64..1e4) {
        let b = spectral_radiance(l, t);
        prop_assert!(b.is_finite() && b >= 0.0);
    }

    #[test]
    fn brdf_is_finite_and_nonnegative(
        m in 1e-3f64..2.0, f0 in 0.0f64..1.0, kd in 0.0f64..1.0,
        tv in -10.0f64..100.0, tl in -10.0f64..100.0, phi in -360.0f64..360.0,
        nx in -1.0f64..1.0, ny in -1.0f64..1.0, nz in -1.0f64..1.0,
        vx in -1.0f64..1.0, vy in -1.0f64..1.0, vz in -1.0f64..1.0,
    ) {
        let ct = CookTorrance { kd, ks: 1.0 - kd, f0, roughness: m };
        let a = ct.evaluate_angles(tv, tl, phi);
        prop_assert!(a.f_per_sr.is_finite() && a.f_per_sr >= 0.0, "{a:?}");
        let n = DVec3::new(nx, ny, nz);
        let v = DVec3::new(vx, vy, vz);
        let b = ct.evaluate(n, v, -v);
        prop_assert!(b.f_per_sr.is_finite() && b.f_per_sr >= 0.0);
        let c = ct.evaluate(n, v, DVec3::new(vy, vz, vx));
        prop_assert!(c.f_per_sr.is_finite() && c.f_per_sr >= 0.0);
        let d = ct.evaluate_facet(v, n);
        prop_assert!(d.f_per_sr.is_finite() && d.f_per_sr >= 0.0);
    }

    #[test]
    fn brdf_is_reciprocal(m in 0.01f64..1.0, tv in 0.0f64..89.0, tl in 0.0f64..89.0, phi in 0.0f64..360.0) {
        let ct = CookTorrance { kd: 0.5, ks: 0.5, f0: 0.04, roughness: m };
        let a = ct.evaluate_angles(tv, tl, phi).f_per_sr;
        let b = ct.evaluate_angles(tl, tv, phi).f_per_sr;
        prop_assert!(((a - b) / a).abs() < 1e-9, "{a} vs {b}");
    }
}

#[test]
fn extreme_inputs_give_no_nan() {
    let bands = [
        Band::try_new(1e-3, 1e-3 + 1e-9).unwrap(),
        Band::try_new(0.01, 1e4).unwrap(),
        Band::try_new(1e-3, 1e4).unwrap(),
        Band::try_new(10.0, 10.0).unwrap(),
    ];
    for band in bands {
        for t in [0.0, 1e-300, 1e-3, 1.0, 5772.0, 1e6] {
            let l = band_radiance(band, t, 1.0);
            assert!(l.is_finite() && l >= 0.0, "{band:?} T={t}: {l}");
        }
    }
    assert_eq!(band_radiance(Band::LWIR_8_12, 0.0, 1.0), 0.0);
    // 1e-3…1e4 µm holds all but ~1e-50 of the spectrum at 1e5 K: σT⁴/π (σ known to 10 digits)
    let l = band_radiance(Band::try_new(1e-3, 1e4).unwrap(), 1e5, 1.0);
    let want = irsim::physics::planck::total_radiance(1e5);
    assert!(((l - want) / want).abs() < 1e-9, "{l} vs {want}");
}

#[test]
fn poisson_sampler_mean_and_variance() {
    for (mean, threshold) in [(0.5, 100.0), (7.0, 100.0), (60.0, 100.0), (400.0, 100.0), (400.0, 500.0)] {
        let mut rng = stream_rng(42, 99, 0, 0);
        let n = 100_000;
        let samples: Vec<f64> = (0..n).map(|_| poisson(mean, threshold, &mut rng)).collect();
        let m = samples.iter().sum::<f64>() / n as f64;
        let v = samples.iter().map(|s| (s - m).powi(2)).sum::<f64>() / (n - 1) as f64;
        // standard error of the mean is sqrt(mean/n); of the variance about mean·sqrt(2/n)
        assert!((m - mean).abs() < 5.0 * (mean / n as f64).sqrt(), "mean {mean}: sample mean {m}");
        let var_tol = 5.0 * mean * (2.0 / n as f64).sqrt() + 0.1;
        assert!((v - mean).abs() < var_tol, "mean {mean}: sample variance {v}");
    }
}

/// A readout with unit radiance-to-signal and DN scales, no offset.
fn readout(shot_noise: bool, read_sigma: f32, dn_per_signal: f32) -> Readout {
    Readout {
        signal_per_radiance: 1.0,
        dark_signal: 0.0,
        shot_noise,
        read_variance: read_sigma * read_sigma,
        full_well: f32::INFINITY,
        dn_per_signal,
        offset_dn: 0.0,
        poisson_normal_threshold: 100.0,
        normal_sampler: irsim::physics::random::NormalSampler::Ziggurat,
    }
}

#[test]
fn gaussian_noise_mean_and_variance() {
    // a thermal detector: read noise only
    let model = readout(false, 3.0, 1.0);
    let mut frame = vec![1000.0f32; 256 * 256];
    model.apply(&mut frame, 256, ReadoutMaps::default(), true, 1, 0, None, None);
    let n = frame.len() as f64;
    let m = frame.iter().map(|&p| p as f64).sum::<f64>() / n;
    let v = frame.iter().map(|&p| (p as f64 - m).powi(2)).sum::<f64>() / (n - 1.0);
    assert!((m - 1000.0).abs() < 5.0 * 3.0 / n.sqrt(), "{m}");
    assert!((v - 9.0).abs() < 5.0 * 9.0 * (2.0 / n).sqrt(), "{v}");
}

#[test]
fn shot_noise_variance_follows_the_conversion_gain() {
    // 2000 electrons at 4 electrons per DN: 500 DN, variance 2000/16 = 125 DN²
    let model = readout(true, 0.0, 0.25);
    let mut frame = vec![2000.0f32; 256 * 256];
    model.apply(&mut frame, 256, ReadoutMaps::default(), true, 2, 0, None, None);
    let n = frame.len() as f64;
    let m = frame.iter().map(|&p| p as f64).sum::<f64>() / n;
    let v = frame.iter().map(|&p| (p as f64 - m).powi(2)).sum::<f64>() / (n - 1.0);
    assert!((m - 500.0).abs() < 0.3, "{m}");
    assert!((v - 125.0).abs() < 4.0, "{v}");
}
