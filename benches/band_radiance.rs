//! Band radiance: the exact series/quadrature method against composite Simpson quadrature.
//!
//! Prints, before timing, the relative error of each method against the exact value for the cases timed.
//! Run: `cargo bench --bench band_radiance`.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use irsim::physics::planck::{Band, band_radiance, band_radiance_simpson};

/// (name, band, temperature K): the paper's LWIR band at skin temperature, MWIR, and a cold, narrow case.
fn cases() -> Vec<(&'static str, Band, f64)> {
    vec![
        ("lwir_8_12_300K", Band::LWIR_8_12, 300.0),
        ("mwir_3_5_250K", Band::MWIR_3_5, 250.0),
        ("sun_8_12_5772K", Band::LWIR_8_12, 5772.0),
    ]
}

fn bench(c: &mut Criterion) {
    let intervals = [8usize, 16, 32, 64, 128, 256, 512, 1024];
    eprintln!("{:<16} {:>10} {:>14}", "case", "method", "relative error");
    for (name, band, t) in cases() {
        let exact = band_radiance(band, t, 1.0);
        eprintln!("{name:<16} {:>10} {:>14}", "exact", "0 (reference)");
        for n in intervals {
            let s = band_radiance_simpson(band, t, 1.0, n);
            eprintln!("{name:<16} {:>10} {:>14.3e}", format!("simpson{n}"), ((s - exact) / exact).abs());
        }
    }
    for (name, band, t) in cases() {
        let mut group = c.benchmark_group(format!("band_radiance/{name}"));
        group.bench_function("exact", |b| b.iter(|| band_radiance(black_box(band), black_box(t), 1.0)));
        for n in intervals {
            group.bench_with_input(BenchmarkId::new("simpson", n), &n, |b, &n| {
                b.iter(|| band_radiance_simpson(black_box(band), black_box(t), 1.0, n))
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
