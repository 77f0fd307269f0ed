//! `irsim bench --limits`: lower bounds of the per-pixel work, measured on this machine in the same run as the
//! pipeline's stages, and the ratio of each stage to its bound.
//!
//! Each bound is the least a stage could do per pixel, written as a plain loop over a row and compiled for the
//! widest vectors the CPU has ([`widest`]): no planning, no tiles, no labels, no fork-join beyond one split of
//! the rows over the threads.
//! - `store`: write every pixel once (memory bandwidth; every stage pays it).
//! - `bilinear`: one bilinear sample per pixel of a 1000 × 1000 f32 texture at coordinates stepped along the
//!   row (a scaled view turned by 0.01 rad, so neighbouring pixels read neighbouring texels, as the sky's
//!   ray cast does; its texels fetched by windows where they lie close together, else gathered (AVX-512) or
//!   loaded a lane's pair at a time (AVX2), as the ray cast's are), and the store: the bound of the `render`
//!   stage.
//! - `normal`: one standard normal deviate per pixel (Box–Muller on a counter-based hash, 24-bit uniforms, a
//!   table-free logarithm and sine/cosine polynomials: the `box_muller` sampler's transform, sixteen pairs to
//!   an AVX-512 register, or eight to an AVX2 one, where the CPU has them) and the store.
//! - `readout`: the detector on a frame in place: signal, a normal deviate, shot and read noise, the ADC,
//!   rounding and clamping: the bound of the `noise` stage.
//! - `fused`: bilinear sample → signal → noise → ADC → round, in one pass: the bound of a whole frame.
//!
//! The pipeline runs `irsim bench`'s built-in case of that size (the `standard` preset) in a thread pool of the same
//! size: with one target at both sizes, and at 640 × 512 also with ten (`run::WIDE_CASE_TARGETS`), as many as the swarm
//! scenario flies (the bounds are timed again beside it). Its stages include what the bounds leave out (the sky's
//! planning, targets, labels; the render's, the targets' radiometry and shapes, which run beside it); the ratios say
//! how far each stage is from what the machine can do.

use std::time::Instant;

use rayon::prelude::*;

use super::CliError;
use super::run::{WIDE_CASE_TARGETS, bench_dir, bench_scenario, time_stages};
use crate::physics::random::{NormalSampler, SplitMix64, box_muller_fill, mix64, with_normal_fill};
use crate::physics::simd::{Level, widest};
use crate::scenario::load::load_for_frames;

/// Side of the bounds' texture, texels (not a power of two: rows 4 KiB apart would share cache sets).
const TEXTURE: usize = 1000;

/// The cases measured: width, height and targets of `irsim bench`'s built-in scenario.
const CASES: [(usize, usize, usize); 3] = [(256, 256, 1), (640, 512, 1), (640, 512, WIDE_CASE_TARGETS)];

/// How far the bounds' view is turned against the texture, rad. Along a row of a view turned by a few
/// hundredths of a radian or less, most sixteen pixels' texels lie within a window or two of 32 floats and are
/// fetched by loads and permutes ([`crate::physics::simd::texel_windows`]), and most eight pixels' within one
/// window of 16 or 24 floats (AVX2, [`crate::physics::simd::sample8_avx2`]); a view turned by 0.3 rad (as this
/// bound's was) crosses a texel row every five pixels, and its texels are gathered (AVX2: loaded a lane's pair at
/// a time).
const TURN_RAD: f32 = 0.01;

/// The bounds' parameters: the texture, its view and the detector.
struct Setup {
    texture: Vec<f32>,
    /// Texture coordinates of pixel (0, 0) and their steps along a row and down a column.
    origin: [f32; 2],
    step_u: [f32; 2],
    step_v: [f32; 2],
    /// Electrons per unit of texture value, dark electrons, read variance, well, DN per electron, offset, top.
    gain: f32,
    dark: f32,
    read_variance: f32,
    well: f32,
    dn_per_e: f32,
    offset: f32,
    top: f32,
}

impl Setup {
    fn new(width: usize, height: usize) -> Self {
        let mut rng = SplitMix64::new(7);
        let texture = (0..TEXTURE * TEXTURE).map(|_| 1000.0 + (rng.next_bits() >> 54) as f32).collect();
        // a view turned by 0.01 rad (the shipped scenarios' cameras are about level), 0.7 texels per pixel,
        // inside the texture
        let scale = 0.7f32;
        let (s, c) = TURN_RAD.sin_cos();
        let step_u = [scale * c, scale * s];
        let step_v = [-scale * s, scale * c];
        let centre = TEXTURE as f32 / 2.0;
        let (hw, hh) = (width as f32 / 2.0, height as f32 / 2.0);
        let origin = [centre - hw * step_u[0] - hh * step_v[0], centre - hw * step_u[1] - hh * step_v[1]];
        Self {
            texture,
            origin,
            step_u,
            step_v,
            gain: 20.0,
            dark: 500.0,
            read_variance: 400.0,
            well: 3.0e6,
            dn_per_e: 0.05,
            offset: 100.0,
            top: 65_535.0,
        }
    }

    /// Row `j`'s bilinear samples: with AVX2 or AVX-512, 8 or 16 pixels at a time, their texels fetched the way
    /// the sky's ray cast fetches them, by windows, else by gathers (AVX-512) or a 64-bit load of each lane's pair
    /// (AVX2) (LLVM does not vectorize the loop below with gathers on its own); else one pixel after another.
    #[inline(always)]
    fn sample_row(&self, j: usize, row: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        {
            let level = Level::detect();
            if level != Level::Baseline {
                // SAFETY: the CPU supports `level`
                unsafe { x86::bilinear_row(level, self, j, row) };
                return;
            }
        }
        for (i, o) in row.iter_mut().enumerate() {
            let (k, [fx, fy]) = self.texel(i, j);
            let t = &self.texture;
            let top = t[k] + (t[k + 1] - t[k]) * fx;
            let bottom = t[k + TEXTURE] + (t[k + TEXTURE + 1] - t[k + TEXTURE]) * fx;
            *o = top + (bottom - top) * fy;
        }
    }

    /// The index of the top-left texel of pixel `i` of row `j`'s bilinear sample, and its weights.
    #[inline(always)]
    fn texel(&self, i: usize, j: usize) -> (usize, [f32; 2]) {
        let (fi, fj) = (i as f32, j as f32);
        let x = self.origin[0] + self.step_u[0] * fi + self.step_v[0] * fj;
        let y = self.origin[1] + self.step_u[1] * fi + self.step_v[1] * fj;
        // inside the texture by construction; the clamps keep every read in bounds whatever the view
        let limit = (TEXTURE - 2) as f32;
        let (x, y) = (x.max(0.0).min(limit), y.max(0.0).min(limit));
        // i32 conversions: one instruction per vector (a float-to-usize conversion is a sequence)
        let (ix, iy) = (x as i32, y as i32);
        ((iy * TEXTURE as i32 + ix) as usize, [x - ix as f32, y - iy as f32])
    }

    /// The detector on the signal `electrons` with the deviate `z`: noise, well, ADC, rounding.
    #[inline(always)]
    fn read(&self, electrons: f32, z: f32) -> f32 {
        let s = electrons + (electrons.max(0.0) + self.read_variance).sqrt() * z;
        crate::physics::noise::quantize_level(self.offset + s.min(self.well) * self.dn_per_e, self.top)
    }
}

/// The bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Bound {
    Store,
    Bilinear,
    Normal,
    Readout,
    Fused,
}

impl Bound {
    const ALL: [Self; 5] = [Self::Store, Self::Bilinear, Self::Normal, Self::Readout, Self::Fused];

    /// Row `j` of the bound, for frame `frame` (its random stream).
    #[inline(always)]
    fn row(self, s: &Setup, frame: u64, j: usize, row: &mut [f32]) {
        // pair p's draw is mix64(key + (p + 1)·GAMMA), the deviates made 64 at a time (as the readout does)
        const BLOCK: usize = 64;
        let key = mix64(frame ^ ((j as u64) << 32));
        let state = |at: usize| key.wrapping_add((at as u64 / 2).wrapping_mul(SplitMix64::GAMMA));
        let mut z = [0f32; BLOCK];
        match self {
            Self::Store => row.fill(frame as f32),
            Self::Bilinear => s.sample_row(j, row),
            Self::Normal => box_muller_fill(key, row),
            Self::Readout | Self::Fused => {
                if self == Self::Fused {
                    s.sample_row(j, row);
                }
                for (b, block) in row.chunks_mut(BLOCK).enumerate() {
                    let z = &mut z[..block.len()];
                    box_muller_fill(state(b * BLOCK), z);
                    for (p, &z) in block.iter_mut().zip(z.iter()) {
                        *p = s.read(s.gain * *p + s.dark, z);
                    }
                }
            }
        }
    }

    /// One frame of the bound, rows split over the current pool.
    fn frame(self, s: &Setup, frame: u64, pixels: &mut [f32], width: usize) {
        let per_task = crate::physics::simd::rows_per_task(width, 1);
        pixels.par_chunks_mut(width).enumerate().with_min_len(per_task).for_each(|(j, row)| {
            widest(
                #[inline(always)]
                || self.row(s, frame, j, row),
            )
        });
    }
}

/// Median µs per frame of `bound` over `frames` frames (after a few to warm up).
fn time_bound(bound: Bound, s: &Setup, width: usize, height: usize, frames: u64) -> f64 {
    let mut pixels = vec![1000.0f32; width * height];
    for k in 0..5 {
        bound.frame(s, k, &mut pixels, width);
    }
    // the other workers kept awake, as the pipeline keeps them through a frame
    let mut times: Vec<f64> = crate::sim::with_workers_awake(|| {
        (0..frames)
            .map(|k| {
                if bound == Bound::Readout {
                    pixels.fill(1000.0);
                }
                let t = Instant::now();
                bound.frame(s, k, &mut pixels, width);
                t.elapsed().as_secs_f64() * 1e6
            })
            .collect()
    });
    super::report::median(&mut times)
}

/// `row` filled with normal deviates by `fill`, in blocks of 64 (as the readout draws them).
#[inline(always)]
fn fill_blocks(row: &mut [f32], rng: &mut SplitMix64, fill: impl Fn(&mut SplitMix64, &mut [f32])) {
    for block in row.chunks_mut(64) {
        fill(rng, block);
    }
}

/// Median µs per frame of the pipeline's normal generator (`sampler`) alone: one deviate per pixel, a stream
/// per row as the readout draws them.
fn time_sampler(sampler: NormalSampler, width: usize, height: usize, frames: u64) -> f64 {
    let mut pixels = vec![0f32; width * height];
    let per_task = crate::physics::simd::rows_per_task(width, 1);
    let mut times: Vec<f64> = crate::sim::with_workers_awake(|| {
        (0..frames + 5)
            .map(|k| {
                let t = Instant::now();
                pixels.par_chunks_mut(width).enumerate().with_min_len(per_task).for_each(|(j, row)| {
                    let mut rng = SplitMix64::substream(k, j as u64);
                    widest(
                        #[inline(always)]
                        || with_normal_fill!(sampler, fill_blocks, (row, &mut rng)),
                    );
                });
                t.elapsed().as_secs_f64() * 1e6
            })
            .skip(5)
            .collect()
    });
    super::report::median(&mut times)
}

/// One size and thread count of [`measure_limits`]: each bound and the pipeline's stages, µs per frame.
pub(super) struct LimitsRow {
    pub width: usize,
    pub height: usize,
    /// Targets of the pipeline's scenario.
    pub targets: usize,
    pub threads: usize,
    /// Per [`Bound::ALL`]: store, bilinear, normal, readout, fused.
    pub bounds: Vec<f64>,
    pub render_us: f64,
    pub noise_us: f64,
    pub frame_us: f64,
    /// The pipeline's normal samplers alone, `name µs`.
    pub samplers: Vec<String>,
}

impl LimitsRow {
    /// The time of bound `b`, µs per frame.
    fn bound(&self, b: Bound) -> f64 {
        self.bounds[Bound::ALL.iter().position(|&x| x == b).expect("a bound")]
    }

    /// The bilinear, readout and fused bounds, µs per frame.
    pub fn bilinear_readout_fused(&self) -> [f64; 3] {
        [self.bound(Bound::Bilinear), self.bound(Bound::Readout), self.bound(Bound::Fused)]
    }

    /// Render / bilinear bound, noise / readout bound, frame / fused bound.
    pub fn ratios(&self) -> [f64; 3] {
        let [bilinear, readout, fused] = self.bilinear_readout_fused();
        [self.render_us / bilinear, self.noise_us / readout, self.frame_us / fused]
    }
}

/// `rounds` (at least 1, at most one a frame) and the frames each takes of `frames`.
fn rounds_of(frames: u64, rounds: usize) -> (usize, u64) {
    let rounds = rounds.clamp(1, frames.max(1) as usize);
    (rounds, frames.div_ceil(rounds as u64))
}

/// Times the per-pixel lower bounds beside `irsim bench`'s built-in case (`standard`) at 256×256 with one target
/// and at 640×512 with one and with [`WIDE_CASE_TARGETS`] ([`CASES`]), on 1 and 2 threads (as many as the machine
/// has), `frames` frames each, split over `rounds` rounds that
/// take the bounds and the pipeline in turn (each number that of its fastest round: a bound's median frame, the
/// pipeline's mean); `each` sees every row as it is measured (its error stops the measurement).
///
/// # Errors
/// [`CliError`] if the scenario cannot be written or run, or from `each`.
pub(super) fn measure_limits(
    frames: u64,
    rounds: usize,
    each: &mut dyn FnMut(&LimitsRow) -> Result<(), CliError>,
) -> Result<Vec<LimitsRow>, CliError> {
    let failed = |e: String| CliError::Failed(e);
    let dir = bench_dir("limits")?;
    let threads_max = std::thread::available_parallelism().map_or(1, |n| n.get()).min(2);
    let (rounds, per_round) = rounds_of(frames, rounds);
    let mut rows = Vec::new();
    for (w, h, targets) in CASES {
        let setup = Setup::new(w, h);
        let path = dir.join(format!("limits_{w}x{h}_{targets}.toml"));
        std::fs::write(&path, bench_scenario(w as u32, h as u32, targets)).map_err(|e| failed(e.to_string()))?;
        let scenario = load_for_frames(&path, Some(frames)).map_err(|e| CliError::Invalid(e.to_string()))?;
        for threads in 1..=threads_max {
            let pool =
                rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| failed(e.to_string()))?;
            // the bounds and the pipeline in turn, `rounds` times, so that a slow minute of a shared machine
            // falls on both
            let (mut bounds, mut render, mut noise, mut frame) =
                (vec![Vec::new(); Bound::ALL.len()], Vec::new(), Vec::new(), Vec::new());
            for _ in 0..rounds {
                let split = pool.install(|| {
                    for (b, times) in Bound::ALL.iter().zip(&mut bounds) {
                        times.push(time_bound(*b, &setup, w, h, per_round));
                    }
                    time_stages(&scenario, per_round)
                })?;
                render.push(split.stage_us("render"));
                noise.push(split.stage_us("noise"));
                frame.push(split.frame_us);
            }
            // the fastest round: what the host's other work does is add time
            let fastest = |t: &[f64]| t.iter().copied().fold(f64::INFINITY, f64::min);
            let samplers: Vec<String> = [NormalSampler::Ziggurat, NormalSampler::BoxMuller, NormalSampler::Table]
                .into_iter()
                .map(|n| {
                    let name = serde_json::to_value(n).ok().and_then(|v| v.as_str().map(str::to_owned));
                    format!("{} {:.0}", name.unwrap_or_default(), pool.install(|| time_sampler(n, w, h, frames)))
                })
                .collect();
            let row = LimitsRow {
                width: w,
                height: h,
                targets,
                threads,
                bounds: bounds.iter().map(|t| fastest(t)).collect(),
                render_us: fastest(&render),
                noise_us: fastest(&noise),
                frame_us: fastest(&frame),
                samplers,
            };
            each(&row)?;
            rows.push(row);
        }
    }
    Ok(rows)
}

/// Rounds of `irsim bench --limits` ([`measure_limits`]).
const LIMITS_ROUNDS: usize = 4;

/// `irsim bench --limits`: the per-pixel lower bounds beside the pipeline's stages, printed as a table.
///
/// # Errors
/// [`CliError`] if the scenario cannot be written or run, or the output cannot be written.
pub fn limits(frames: u64) -> Result<(), CliError> {
    let (rounds, per_round) = rounds_of(frames, LIMITS_ROUNDS);
    super::say(&format!(
        "per-pixel lower bounds beside the pipeline ({} vectors, {rounds} interleaved rounds of {per_round} frames, \
         each number its fastest round's: a bound's median frame, the pipeline's mean; pipeline: irsim bench's case \
         with the targets given, standard)",
        Level::detect().name()
    ))?;
    super::say(
        "size      targets threads | store bilinear normal readout  fused | render  noise  frame | render/bilinear noise/readout frame/fused",
    )?;
    // each row's share of steal time, from the end of the row before
    let mut since = super::steal::CpuTicks::now();
    measure_limits(frames, rounds, &mut |row| {
        eprintln!("  the pipeline's normal samplers alone, µs per frame: {}", row.samplers.join(", "));
        let cols: Vec<String> = row.bounds.iter().map(|b| format!("{b:.0}")).collect();
        let [render, noise, frame] = row.ratios();
        let line = format!(
            "{:<9} {:>7} {:>7} | {:>5} {:>8} {:>6} {:>7} {:>6} | {:>6.0} {:>6.0} {:>6.0} | {render:>15.1}x {noise:>12.1}x {frame:>10.1}x",
            format!("{}x{}", row.width, row.height),
            row.targets,
            row.threads,
            cols[0],
            cols[1],
            cols[2],
            cols[3],
            cols[4],
            row.render_us,
            row.noise_us,
            row.frame_us,
        );
        super::say(&line)?;
        if let Some(note) = super::steal::steal_note(since) {
            eprintln!("{note}");
        }
        since = super::steal::CpuTicks::now();
        Ok(())
    })?;
    super::say(
        "(µs per frame; a frame's time includes every stage and the schedule's own; the render's includes the \
         targets' radiometry and shapes, which run beside it)",
    )
}

/// The bilinear bound with the CPU's vectors.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{Level, Setup, TEXTURE};

    /// Row `j` of the bilinear bound.
    ///
    /// # Safety
    /// The CPU must support `level` (not [`Level::Baseline`]).
    pub unsafe fn bilinear_row(level: Level, s: &Setup, j: usize, row: &mut [f32]) {
        // SAFETY: the caller checked the CPU's features
        unsafe {
            match level {
                Level::Avx512 => row_512(s, j, row),
                _ => row_256(s, j, row),
            }
        }
    }

    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    unsafe fn row_512(s: &Setup, j: usize, row: &mut [f32]) {
        let fj = j as f32;
        let x0 = _mm512_set1_ps(s.origin[0] + s.step_v[0] * fj);
        let y0 = _mm512_set1_ps(s.origin[1] + s.step_v[1] * fj);
        let (su, sv) = (_mm512_set1_ps(s.step_u[0]), _mm512_set1_ps(s.step_u[1]));
        let limit = _mm512_set1_ps((TEXTURE - 2) as f32);
        let lanes = _mm512_setr_ps(0., 1., 2., 3., 4., 5., 6., 7., 8., 9., 10., 11., 12., 13., 14., 15.);
        let mut i = 0;
        let mut tail = [0f32; 16];
        while i < row.len() {
            let fi = _mm512_add_ps(_mm512_set1_ps(i as f32), lanes);
            let x = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(x0, _mm512_mul_ps(su, fi)), _mm512_setzero_ps()), limit);
            let y = _mm512_min_ps(_mm512_max_ps(_mm512_add_ps(y0, _mm512_mul_ps(sv, fi)), _mm512_setzero_ps()), limit);
            let (ix, iy) = (_mm512_cvttps_epi32(x), _mm512_cvttps_epi32(y));
            let (fx, fy) = (_mm512_sub_ps(x, _mm512_cvtepi32_ps(ix)), _mm512_sub_ps(y, _mm512_cvtepi32_ps(iy)));
            let k = _mm512_add_epi32(_mm512_mullo_epi32(iy, _mm512_set1_epi32(TEXTURE as i32)), ix);
            // SAFETY: 0 ≤ ix, iy ≤ TEXTURE − 2 (clamped), so every index is inside the texture
            let v = unsafe { crate::physics::simd::sample16_avx512(&s.texture, k, TEXTURE, fx, fy, 0xffff, true) };
            let n = (row.len() - i).min(16);
            // SAFETY: 16 floats into `tail`, then n ≤ 16 into the row at i
            unsafe {
                if n == 16 {
                    _mm512_storeu_ps(row.as_mut_ptr().add(i), v);
                } else {
                    _mm512_storeu_ps(tail.as_mut_ptr(), v);
                    row[i..].copy_from_slice(&tail[..n]);
                }
            }
            i += 16;
        }
    }

    #[target_feature(enable = "avx2")]
    unsafe fn row_256(s: &Setup, j: usize, row: &mut [f32]) {
        let fj = j as f32;
        let x0 = _mm256_set1_ps(s.origin[0] + s.step_v[0] * fj);
        let y0 = _mm256_set1_ps(s.origin[1] + s.step_v[1] * fj);
        let (su, sv) = (_mm256_set1_ps(s.step_u[0]), _mm256_set1_ps(s.step_u[1]));
        let limit = _mm256_set1_ps((TEXTURE - 2) as f32);
        let lanes = _mm256_setr_ps(0., 1., 2., 3., 4., 5., 6., 7.);
        let mut i = 0;
        let mut tail = [0f32; 8];
        while i < row.len() {
            let fi = _mm256_add_ps(_mm256_set1_ps(i as f32), lanes);
            let x = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(x0, _mm256_mul_ps(su, fi)), _mm256_setzero_ps()), limit);
            let y = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(y0, _mm256_mul_ps(sv, fi)), _mm256_setzero_ps()), limit);
            let (ix, iy) = (_mm256_cvttps_epi32(x), _mm256_cvttps_epi32(y));
            let (fx, fy) = (_mm256_sub_ps(x, _mm256_cvtepi32_ps(ix)), _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy)));
            let k = _mm256_add_epi32(_mm256_mullo_epi32(iy, _mm256_set1_epi32(TEXTURE as i32)), ix);
            // SAFETY: 0 ≤ ix, iy ≤ TEXTURE − 2 (clamped), so every index is inside the texture
            let v = unsafe { crate::physics::simd::sample8_avx2(&s.texture, k, TEXTURE, fx, fy, true) };
            let n = (row.len() - i).min(8);
            // SAFETY: 8 floats into `tail`, then n ≤ 8 into the row at i
            unsafe {
                if n == 8 {
                    _mm256_storeu_ps(row.as_mut_ptr().add(i), v);
                } else {
                    _mm256_storeu_ps(tail.as_mut_ptr(), v);
                    row[i..].copy_from_slice(&tail[..n]);
                }
            }
            i += 8;
        }
    }
}
