//! Per-pixel kernels: sky ray casting per sampling mode, sensor noise with quantization, and Poisson fusion per
//! solver and patch size.
//!
//! Before timing, prints each solver's largest difference from the exact direct solution on the same patch.
//! Run: `cargo bench --bench imaging`.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use glam::{DVec2, DVec3};
use irsim::imaging::camera::{Camera, Intrinsics};
use irsim::imaging::frame::Frame;
use irsim::imaging::fusion::{Guidance, Patch, PoissonFusion, Solver};
use irsim::imaging::sky_plane::{MissFill, Sampling, SkyImage, SkyPlacement, SkyPlane};
use irsim::imaging::target_blob::{BlobSampling, GeneralizedGaussian, PixelRect};
use irsim::physics::noise::{Readout, ReadoutMaps};
use irsim::physics::random::NormalSampler;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn sky_setup() -> (SkyPlane, Camera) {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let n = 512;
    let px = (0..n * n).map(|_| 1000.0 + 100.0 * rng.random::<f32>()).collect();
    let image = SkyImage::from_f32(n, n, px).unwrap();
    let placement = SkyPlacement::paper_fig8();
    let cam_pos = DVec3::new(0.0, 0.0, 8000.0);
    let plane = SkyPlane::new(image, &placement, cam_pos).unwrap();
    let intr = Intrinsics::try_new(256, 256, 0.1, 17e-6).unwrap();
    let cam = Camera::look_at(intr, cam_pos, placement.anchor_m, 3.0).unwrap();
    (plane, cam)
}

fn raycast(c: &mut Criterion) {
    let (plane, cam) = sky_setup();
    let mut frame = Frame::new(256, 256);
    let mut group = c.benchmark_group("raycast_256x256");
    group.throughput(Throughput::Elements(256 * 256));
    for (name, sampling) in [
        ("nearest", Sampling::Nearest),
        ("bilinear", Sampling::Bilinear),
        ("supersample2", Sampling::Supersample { n: 2 }),
        ("supersample4", Sampling::Supersample { n: 4 }),
    ] {
        group.bench_function(name, |b| b.iter(|| plane.render(&cam, sampling, MissFill::Zero, black_box(&mut frame))));
    }
    group.finish();
}

fn noise(c: &mut Criterion) {
    let mut group = c.benchmark_group("noise_256x256");
    group.throughput(Throughput::Elements(256 * 256));
    // a photon detector: 1 electron per radiance unit, 300 e⁻ read noise, 430 e⁻ per DN, a 1000 DN offset
    let model = Readout {
        signal_per_radiance: 1.0,
        dark_signal: 0.0,
        shot_noise: true,
        read_variance: 300.0 * 300.0,
        full_well: 7e6,
        dn_per_signal: 1.0 / 430.0,
        offset_dn: 1000.0,
        poisson_normal_threshold: 100.0,
        normal_sampler: NormalSampler::Ziggurat,
    };
    // a 256-wide frame read out with noise, rounded to 14 bits
    let read_out = |model: &Readout, frame: &mut [f32], n: u64| {
        model.apply(frame, 256, ReadoutMaps::default(), true, 1, n, Some(16_383.0), None);
    };
    // 2e6 … 2.00001e6 electrons: every pixel on the normal path
    let base: Vec<f32> = (0..256 * 256).map(|i| 2e6 + (i % 11) as f32).collect();
    let mut frame = base.clone();
    let mut frame_number = 0;
    for (name, sampler) in [("normal_path", NormalSampler::Ziggurat), ("normal_path_table", NormalSampler::Table)] {
        let model = Readout { normal_sampler: sampler, ..model };
        group.bench_function(name, |b| {
            b.iter(|| {
                frame.copy_from_slice(&base);
                frame_number += 1;
                read_out(&model, black_box(&mut frame), frame_number);
            })
        });
    }
    // 40 … 80 electrons, every pixel an exact Poisson count
    let low: Vec<f32> = (0..256 * 256).map(|i| 40.0 + (i % 41) as f32).collect();
    group.bench_function("poisson_path", |b| {
        b.iter(|| {
            frame.copy_from_slice(&low);
            frame_number += 1;
            read_out(&model, black_box(&mut frame), frame_number);
        })
    });
    group.finish();
}

/// A textured background and a blob patch filling a `side × side` region.
fn fusion_case(side: usize) -> (Frame, Vec<f32>, PixelRect) {
    let mut rng = ChaCha8Rng::seed_from_u64(side as u64);
    let mut frame = Frame::new(side + 16, side + 16);
    for p in frame.pixels_mut() {
        *p = 1000.0 + 50.0 * rng.random::<f32>();
    }
    let rect = PixelRect { x0: 8, y0: 8, x1: 8 + side, y1: 8 + side };
    let blob = GeneralizedGaussian {
        center: DVec2::new(8.0 + side as f64 / 2.0 + 0.3, 8.0 + side as f64 / 2.0 - 0.2),
        alpha_x: side as f64 / 8.0,
        alpha_y: side as f64 / 12.0,
        beta_x: 2.0,
        beta_y: 2.0,
        angle_rad: 0.4,
        peak: 500.0,
    };
    let mut patch = vec![0.0; side * side];
    blob.render_patch(rect, BlobSampling::Point, &mut patch);
    (frame, patch, rect)
}

fn solvers() -> [(&'static str, Solver); 3] {
    [
        ("direct_dst", Solver::Direct),
        ("sor", Solver::Sor { tolerance: 1e-4, max_iterations: 10_000 }),
        ("jacobi_eq20", Solver::Jacobi { tolerance: 1e-4, max_iterations: 2_000 }),
    ]
}

fn fusion(c: &mut Criterion) {
    let sides = [16usize, 32, 64, 127, 128];
    eprintln!("{:>5} {:>12} {:>11} {:>22}", "side", "solver", "iterations", "max |f − f_direct| gray");
    for side in sides {
        let (frame, patch, rect) = fusion_case(side);
        let patches = [Patch { rect, values: &patch }];
        let mut engine = PoissonFusion::new();
        let mut exact = frame.clone();
        engine.fuse(&mut exact, &patches, Guidance::Normal, Solver::Direct);
        for (name, solver) in solvers() {
            let mut f = frame.clone();
            let stats = engine.fuse(&mut f, &patches, Guidance::Normal, solver);
            let err = exact.pixels().iter().zip(f.pixels()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            eprintln!("{side:>5} {name:>12} {:>11} {err:>22.3e}", stats.iterations);
        }
    }
    let mut group = c.benchmark_group("fusion");
    group.sample_size(20);
    for side in sides {
        let (frame, patch, rect) = fusion_case(side);
        let mut engine = PoissonFusion::with_capacity(side);
        for (name, solver) in solvers() {
            if name == "jacobi_eq20" && side > 64 {
                continue; // seconds per call; its error above shows why it is only a reference
            }
            let mut work = frame.clone();
            group.bench_with_input(BenchmarkId::new(name, side), &side, |b, _| {
                b.iter(|| {
                    work.pixels_mut().copy_from_slice(frame.pixels());
                    engine.fuse(&mut work, &[Patch { rect, values: &patch }], Guidance::Normal, solver)
                })
            });
        }
    }
    group.finish();
}

/// The optics PSF of an F/1 LWIR camera with 17 µm pixels (radius 4 px, rank 3) on a textured 256² frame, per
/// application method.
/// 16-bit PNG encoding of a noisy sky frame: this crate's Huffman-only encoder (`fast`), the `png` crate's
/// fast deflate it replaced, and stored (no deflate).
fn png16(c: &mut Criterion) {
    use irsim::imaging::frame::PngCompression;
    use irsim::imaging::png16::Png16Encoder;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (w, h) in [(256, 256), (640, 512)] {
        let px = (0..w * h).map(|i| 3000.0 + (i / w) as f32 * 0.8 + 12.0 * rng.random::<f32>()).collect();
        let frame = Frame::from_pixels(w, h, px);
        let mut group = c.benchmark_group(format!("png16_{w}x{h}"));
        group.throughput(Throughput::Bytes((w * h * 2) as u64));
        let (mut enc, mut out, mut samples) = (Png16Encoder::new(), Vec::new(), Vec::new());
        group.bench_function("fast", |b| b.iter(|| enc.encode(black_box(frame.pixels()), w, h, 16383, &mut out)));
        for (name, level) in [("png_crate_fast", PngCompression::Fast), ("stored", PngCompression::None)] {
            group.bench_function(name, |b| {
                b.iter(|| {
                    out.clear();
                    frame.png16_samples(16383, &mut samples);
                    frame.write_png16_samples(black_box(&samples), level, &mut out).unwrap();
                })
            });
        }
        group.finish();
    }
}

fn psf(c: &mut Criterion) {
    use irsim::imaging::prefilter::TextureFilter;
    use irsim::imaging::psf::{ConvolutionMethod, Convolver, Psf, PsfOptics, PsfSpec};
    use irsim::physics::planck::{Band, Measure};
    let optics = PsfOptics {
        f_number: 1.0,
        pixel_pitch_m: 17e-6,
        fill_factor: 1.0,
        band: Band::LWIR_8_12,
        measure: Measure::Energy,
        reference_temp_k: 300.0,
    };
    let psf = Psf::new(&PsfSpec::default(), &optics).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let base: Vec<f32> = (0..256 * 256).map(|_| 1000.0 + 100.0 * rng.random::<f32>()).collect();
    let mut frame = Frame::new(256, 256);
    let mut convolver = Convolver::new();
    let mut group = c.benchmark_group("psf_256x256");
    group.throughput(Throughput::Elements(256 * 256));
    for (name, method) in [
        ("separable", ConvolutionMethod::Separable),
        ("direct", ConvolutionMethod::Direct),
        ("fft", ConvolutionMethod::Fft),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                frame.pixels_mut().copy_from_slice(&base);
                convolver.apply(psf.point_kernel(), black_box(&mut frame), method);
            })
        });
    }
    group.finish();
    // the kernels of a prefiltered sky texture, made for every new view Jacobian: a sky about as fine as the
    // sensor (one texel a pixel, 4 phases), and a magnified one (0.4 texel a pixel, 16 phases)
    let mut group = c.benchmark_group("texture_filter");
    for (name, scale) in [("texel_per_px_1.09", 1.09), ("texel_per_px_0.4", 0.4)] {
        let (s, c) = (0.1f64.sin(), 0.1f64.cos());
        let jacobian = glam::DMat2::from_cols_array(&[scale * c, scale * s, -scale * s * 0.9, scale * c * 0.9]);
        group.bench_function(name, |b| b.iter(|| TextureFilter::new(&psf, black_box(jacobian))));
    }
    group.finish();
}

criterion_group!(benches, raycast, noise, fusion, psf, png16);
criterion_main!(benches);
