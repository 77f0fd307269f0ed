//! Sensor noise: Poisson (shot) noise plus Gaussian (read, thermal) noise, from seeded, seekable streams.
//!
//! Randomness never comes from a global generator. Every stochastic stage draws from its own ChaCha8 stream
//! keyed by `(seed, stage, frame)` with a 64-bit sub-stream, so output is identical across runs, thread counts
//! and frame order, and any frame can be produced without the ones before it. Per-pixel sensor noise takes a
//! 64-bit key from its frame's stream and gives each row its own fast generator hashed from that key and the row
//! ([`super::random`]).
//!
//! Noise is counted in the detector's own unit, never in gray levels ([`Readout`]): a photon detector's mean
//! signal of `N` electrons becomes `Poisson(N) + σ·Z` (shot and read noise), a thermal detector's `V + σ·Z`.
//! Poisson samples are exact (sequential-search inversion, PTRS) for `N` below a threshold; above it the shot
//! noise is drawn from the normal `N(N, N)`, and since the sum of two independent normals is normal, one draw of
//! `N(0, N + σ²)` gives shot and read noise together (the rounding to whole electrons, 1/12 electron² of
//! variance, is dropped). That approximation
//! matches the mean exactly; its total-variation distance from the Poisson law (with rounding), computed
//! exactly by [`normal_approximation_tv`] (test `normal_approximation_error_table`), is 0.040 at a mean of 10,
//! 0.0126 at 100 (the default threshold), 0.0040 at 1000: about `0.126/√N`.

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::random::{NormalSampler, SplitMix64, with_normal_fill};
use super::simd::widest;

/// Identifiers of the stochastic stages; each keys its own random streams.
pub mod stage {
    /// Camera line-of-sight vibration.
    pub const VIBRATION: u64 = 1;
    /// Sensor noise.
    pub const SENSOR_NOISE: u64 = 2;
    /// Procedural sky generation.
    pub const SKY: u64 = 3;
    /// Scenario-level random choices (e.g. swarm layout).
    pub const SCENARIO: u64 = 4;
    /// The camera's fixed-pattern noise, dead pixels, drift and column noise.
    pub const FIXED_PATTERN: u64 = 5;
    /// The tracking loop's pointing noise.
    pub const TRACKING: u64 = 6;
}

/// A ChaCha8 generator for `(seed, stage, frame)`, sub-stream `substream`.
pub fn stream_rng(seed: u64, stage: u64, frame: u64, substream: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&stage.to_le_bytes());
    key[16..24].copy_from_slice(&frame.to_le_bytes());
    key[24..32].copy_from_slice(b"irsim-01");
    let mut rng = ChaCha8Rng::from_seed(key);
    rng.set_stream(substream);
    rng
}

/// The detector's readout for one frame: radiance in, digital numbers out (noise, saturation, ADC).
///
/// Per pixel: the mean signal `s = K·g(p)·L + D` (electrons or volts: `K` the signal per unit radiance on axis,
/// `g(p)` the pixel's gain map — vignetting, gain non-uniformity, dead pixels — and `D` the dark signal); with
/// noise, `s` plus Poisson shot noise (photon detectors) and Gaussian read noise; saturation at the full well;
/// then `DN = offset + o(p) + s/gain` (`o(p)` the pixel's offset map in DN), rounded and clamped to the levels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Readout {
    /// Signal (electrons or volts) per unit radiance on axis, `K`.
    pub signal_per_radiance: f32,
    /// Dark signal per frame, `D`.
    pub dark_signal: f32,
    /// Poisson shot noise on the signal (photon detectors, signal in electrons).
    pub shot_noise: bool,
    /// Read noise variance, signal units².
    pub read_variance: f32,
    /// Largest signal (the well); `f32::INFINITY` for none.
    pub full_well: f32,
    /// DN per signal unit, `1/gain`.
    pub dn_per_signal: f32,
    /// DN of zero signal this frame (the ADC offset plus any drift).
    pub offset_dn: f32,
    /// Mean electron count below which shot noise is an exact Poisson count.
    pub poisson_normal_threshold: f32,
    /// How the normal deviates are drawn.
    pub normal_sampler: NormalSampler,
}

/// What writes a block of whole rows of the frame's radiance before they are read out: `fill(first_row, block)`
/// ([`Readout::apply`]).
pub type RowFill<'a> = dyn Fn(usize, &mut [f32]) + Sync + 'a;

/// Optional per-pixel maps of the readout, row-major, the frame's size.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReadoutMaps<'a> {
    /// Gain `g(p)` multiplying the radiance (1 where absent).
    pub gain: Option<&'a [f32]>,
    /// Offset `o(p)` in DN (0 where absent).
    pub offset_dn: Option<&'a [f32]>,
    /// Per-column offset of this frame in DN, `width` long (0 where absent).
    pub column_dn: Option<&'a [f32]>,
}

impl Readout {
    /// Mean DN of a pixel of radiance `radiance` with map values `gain`, `offset_dn`, before noise and rounding.
    #[inline]
    pub fn mean_dn(&self, radiance: f32, gain: f32, offset_dn: f32) -> f32 {
        let s = (self.signal_per_radiance * gain * radiance + self.dark_signal).min(self.full_well);
        self.offset_dn + offset_dn + s * self.dn_per_signal
    }

    /// Temporal noise of a pixel of mean signal `signal`, in DN (shot and read noise).
    pub fn noise_dn(&self, signal: f64) -> f64 {
        let shot = if self.shot_noise { signal.max(0.0) } else { 0.0 };
        (shot + f64::from(self.read_variance)).sqrt() * f64::from(self.dn_per_signal)
    }

    /// Temporal noise σ in DN of a pixel whose (noise-free, on-axis) radiance is `radiance`: its signal and the
    /// dark signal, through [`Readout::noise_dn`].
    pub fn noise_dn_at_radiance(&self, radiance: f64) -> f64 {
        self.noise_dn(f64::from(self.signal_per_radiance) * radiance + f64::from(self.dark_signal))
    }

    /// Replaces each radiance in `pixels` (row-major, `width` wide) by its DN: with noise if `noise`, rounded and
    /// clamped to `[0, max_level]` if `max_level` is given. Row `r` draws from sub-streams of
    /// `(seed, SENSOR_NOISE, frame)`, so the result does not depend on how rows are scheduled.
    /// Where `fill` is given, it first writes each block of rows' radiance, `fill(first_row, block)` for whole
    /// rows, just before they are read out (a frame made on a coarse grid is interpolated block by block there,
    /// while the block is in the first-level cache, instead of in a pass of its own); the result is that of
    /// filling every row first.
    ///
    /// A noisy detector whose deviates come from the `table` sampler (the `draft` preset's) takes its rows
    /// through one AVX-512 pass where the CPU has it (`fused_row_512`): the deviates are made in vector
    /// registers and used there, the signal, noise, ADC and rounding in one sweep, by the general path's f32
    /// operations in its order, so every finite radiance gives the same bits (a photon detector's block with a
    /// signal below the Poisson threshold takes its noise pixel by pixel inside that pass, as here).
    #[allow(clippy::too_many_arguments)]
    pub fn apply(
        &self,
        pixels: &mut [f32],
        width: usize,
        maps: ReadoutMaps<'_>,
        noise: bool,
        seed: u64,
        frame: u64,
        max_level: Option<f32>,
        fill: Option<&RowFill<'_>>,
    ) {
        self.apply_rows(pixels, width, maps, noise, (seed, frame), max_level, fill, true);
    }

    /// Whether a row of `width` takes the fused pass: noise on, shot or read noise, the `table` sampler, a row
    /// of at least one pixel and AVX-512.
    fn fuses(&self, width: usize, noise: bool) -> bool {
        #[cfg(target_arch = "x86_64")]
        if noise
            && (self.shot_noise || self.read_variance > 0.0)
            && self.normal_sampler == NormalSampler::Table
            && width > 0
        {
            return super::simd::Level::detect() == super::simd::Level::Avx512;
        }
        let _ = (width, noise);
        false
    }

    /// [`Readout::apply`], the fused pass allowed or not.
    #[allow(clippy::too_many_arguments)]
    fn apply_rows(
        &self,
        pixels: &mut [f32],
        width: usize,
        maps: ReadoutMaps<'_>,
        noise: bool,
        (seed, frame): (u64, u64),
        max_level: Option<f32>,
        fill: Option<&RowFill<'_>>,
        fused: bool,
    ) {
        use rayon::prelude::*;
        if width == 0 {
            return;
        }
        // whole rows and maps of the frame's size (the general path takes whatever it is given)
        let fits = |m: Option<&[f32]>, len: usize| m.is_none_or(|m| m.len() == len);
        let fused = fused
            && self.fuses(width, noise)
            && pixels.len().is_multiple_of(width)
            && fits(maps.gain, pixels.len())
            && fits(maps.offset_dn, pixels.len())
            && fits(maps.column_dn, width);
        #[cfg(not(target_arch = "x86_64"))]
        let _ = fused;
        let key = stream_rng(seed, stage::SENSOR_NOISE, frame, 0).next_u64();
        // rows in batches: one row is too little work to be worth a task
        let rows_per_task = super::simd::rows_per_task(width, 1);
        pixels.par_chunks_mut(width * rows_per_task).enumerate().for_each(|(b, block)| {
            let first = b * rows_per_task;
            if let Some(fill) = fill {
                fill(first, block);
            }
            for (r, line) in block.chunks_mut(width).enumerate() {
                let row = first + r;
                let span = row * width..(row + 1) * width;
                let gain = maps.gain.map(|g| &g[span.clone()]);
                let offset = maps.offset_dn.map(|o| &o[span]);
                #[cfg(target_arch = "x86_64")]
                if fused {
                    // the row's normal deviates are sub-stream 2·row and its uniforms 2·row + 1, as apply_row
                    // draws them
                    let mut normals = SplitMix64::substream(key, 2 * row as u64);
                    let mut uniforms = SplitMix64::substream(key, 2 * row as u64 + 1);
                    let maps = [gain, offset, maps.column_dn];
                    // whole blocks of 64, then a part block (whose run is the next one drawn, as in apply_row)
                    let whole = width - width % BLOCK;
                    let (line, part) = line.split_at_mut(whole);
                    // SAFETY: `fuses` checked for AVX-512; whole blocks and a part block, maps of their lengths
                    unsafe {
                        if whole > 0 {
                            let maps = maps.map(|m| m.map(|m| &m[..whole]));
                            x86::fused_row_512(self, line, maps, (&mut normals, &mut uniforms), max_level);
                        }
                        if !part.is_empty() {
                            let maps = maps.map(|m| m.map(|m| &m[whole..]));
                            x86::fused_part_block_512(self, part, maps, (&mut normals, &mut uniforms), max_level);
                        }
                    }
                    continue;
                }
                widest(
                    #[inline(always)]
                    || {
                        with_normal_fill!(
                            self.normal_sampler,
                            Self::apply_row,
                            (self, line, gain, offset, maps.column_dn, noise, key, row as u64, max_level)
                        )
                    },
                );
            }
        });
    }

    /// One row: the mean signal in blocks, the normal deviates, a branch-free pass for blocks on the normal path
    /// (or without noise), the per-pixel path where some pixel needs an exact Poisson count.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn apply_row(
        &self,
        line: &mut [f32],
        gain: Option<&[f32]>,
        offset: Option<&[f32]>,
        columns: Option<&[f32]>,
        noise: bool,
        key: u64,
        row: u64,
        max_level: Option<f32>,
        fill_normals: impl Fn(&mut SplitMix64, &mut [f32]),
    ) {
        const ONES: [f32; BLOCK] = [1.0; BLOCK];
        const ZEROS: [f32; BLOCK] = [0.0; BLOCK];
        // x + (−0) is x for every x, −0 included: absent column offsets add nothing, to the bit
        const NEG_ZEROS: [f32; BLOCK] = [-0.0; BLOCK];
        let noisy = noise && (self.shot_noise || self.read_variance > 0.0);
        let mut normals = SplitMix64::substream(key, 2 * row);
        let mut uniforms = SplitMix64::substream(key, 2 * row + 1);
        let mut z = [0f32; BLOCK];
        let threshold = self.normal_threshold();
        for (b, block) in line.chunks_mut(BLOCK).enumerate() {
            let n = block.len();
            let at = b * BLOCK;
            let g = gain.map_or(&ONES[..n], |g| &g[at..at + n]);
            let o = offset.map_or(&ZEROS[..n], |o| &o[at..at + n]);
            let c = columns.map_or(&NEG_ZEROS[..n], |c| &c[at..at + n]);
            // mean signal, and whether every pixel of the block is on the normal path
            let mut normal = true;
            for (p, &g) in block.iter_mut().zip(g) {
                *p = self.signal_per_radiance * g * *p + self.dark_signal;
                normal &= *p >= threshold;
            }
            let z = &mut z[..n];
            if noisy {
                fill_normals(&mut normals, z);
            }
            // a block with a pixel below the threshold takes its noise pixel by pixel; every other noisy block
            // takes it in the pass that finishes the block
            let per_pixel = noisy && !normal;
            let shot = if self.shot_noise { 1.0 } else { 0.0 };
            if per_pixel {
                self.noise_pixel_by_pixel(block, z, &mut uniforms);
            }
            match (noisy && !per_pixel, max_level) {
                (true, Some(top)) => self.finish_block::<true, true>(block, z, o, c, shot, top),
                (true, None) => self.finish_block::<true, false>(block, z, o, c, shot, 0.0),
                (false, Some(top)) => self.finish_block::<false, true>(block, z, o, c, shot, top),
                (false, None) => self.finish_block::<false, false>(block, z, o, c, shot, 0.0),
            }
        }
    }

    /// The signal from which a pixel's shot noise is drawn from the normal law: the Poisson threshold with shot
    /// noise, every signal (−∞) without.
    fn normal_threshold(&self) -> f32 {
        if self.shot_noise { self.poisson_normal_threshold } else { f32::NEG_INFINITY }
    }

    /// The noise of a block of signals with a pixel below [`Readout::normal_threshold`] (or NaN), pixel by pixel:
    /// the normal law with deviate `z` from the threshold up, an exact Poisson count from `uniforms` plus the read
    /// noise below.
    #[inline(always)]
    fn noise_pixel_by_pixel(&self, block: &mut [f32], z: &[f32], uniforms: &mut SplitMix64) {
        let threshold = self.normal_threshold();
        let shot = if self.shot_noise { 1.0 } else { 0.0 };
        let sd_read = self.read_variance.sqrt();
        for (s, &z) in block.iter_mut().zip(z) {
            if *s >= threshold {
                // the shot noise's variance only where there is shot noise (a thermal detector's block comes here
                // only for a NaN signal, whose neighbours keep their read noise alone)
                *s += (s.max(0.0) * shot + self.read_variance).sqrt() * z;
            } else {
                // exact Poisson shot noise, and the pixel's normal deviate for the read noise
                let count = poisson(f64::from(s.max(0.0)), f64::from(self.poisson_normal_threshold), uniforms);
                *s = count as f32 + sd_read * z;
            }
        }
    }

    /// A block of signals to DN in one pass: the deviates `z` scaled by the pixel's noise (if `NOISY`: a block
    /// on the normal path), the well, the ADC with the offsets `o` and the column offsets `c`, and the rounding
    /// to `[0, top]` (if `ROUND`).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn finish_block<const NOISY: bool, const ROUND: bool>(
        &self,
        block: &mut [f32],
        z: &[f32],
        o: &[f32],
        c: &[f32],
        shot: f32,
        top: f32,
    ) {
        for (((p, &z), &o), &c) in block.iter_mut().zip(z).zip(o).zip(c) {
            let mut s = *p;
            if NOISY {
                s += (s.max(0.0) * shot + self.read_variance).sqrt() * z;
            }
            let v = self.offset_dn + o + s.min(self.full_well) * self.dn_per_signal + c;
            *p = if ROUND { quantize_level(v, top) } else { v };
        }
    }
}

/// The fused readout with AVX-512.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{BLOCK, Readout};
    use crate::physics::random::{Quantiles, SplitMix64};

    /// One row (`line`, whole blocks of 64) read out with deviates of the `table` sampler: per block of 64, the
    /// run's deviates as four vectors ([`Quantiles::next_run_512`]), then per vector of sixteen the general
    /// path's f32 operations in its order: the signal `(K·g)·L + D`, plus `√(max(s, 0)·1 + σ²)·z` with shot
    /// noise or `√(0 + σ²)·z` without (a thermal detector: `max(s, 0)·0` is 0 for every finite `s`), the well
    /// (`min`, which like `f32::min` gives the well for NaN), the ADC `((offset + o) + s·(1/gain)) + c`, and
    /// [`super::quantize_level`]'s rounding if `top` is given. With shot noise, a block with a signal below the
    /// readout's Poisson threshold (or NaN) takes its noise pixel by pixel as the general path does (the same
    /// deviates, exact counts from `uniforms`), and then the same ADC. `maps` are the row's gain, offset and
    /// column offsets, each `line`'s length where given; an absent one is 1, 0 or −0 as in the general path.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL).
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn fused_row_512(
        r: &Readout,
        line: &mut [f32],
        maps: [Option<&[f32]>; 3],
        (normals, uniforms): (&mut SplitMix64, &mut SplitMix64),
        top: Option<f32>,
    ) {
        let n = line.len();
        assert!(
            n.is_multiple_of(64) && maps.iter().flatten().all(|m| m.len() == n),
            "whole blocks, maps of the row's length"
        );
        let quantiles = Quantiles::get();
        let ps = _mm512_set1_ps;
        let k = ps(r.signal_per_radiance);
        let dark = ps(r.dark_signal);
        let read_variance = ps(r.read_variance);
        let sigma = ps((0.0 + r.read_variance).sqrt());
        let threshold = ps(r.normal_threshold());
        let (well, dn, offset) = (ps(r.full_well), ps(r.dn_per_signal), ps(r.offset_dn));
        // sixteen map values from pixel i, or the absent map's constant
        let [gain, offsets, columns] = maps;
        let at_or = |map: Option<&[f32]>, i: usize, absent: __m512| match map {
            // SAFETY: i + 16 ≤ n, the map's length
            Some(m) => unsafe { _mm512_loadu_ps(m.as_ptr().add(i)) },
            None => absent,
        };
        let (zero, half, one, neg_zeros) = (ps(0.0), ps(0.5), ps(1.0), ps(-0.0));
        let shift = ps(super::QUANTIZE_SHIFT);
        let top_v = ps(top.unwrap_or(0.0));
        // the mean signal of sixteen radiances from pixel i
        let signal = |p: __m512, i: usize| _mm512_add_ps(_mm512_mul_ps(_mm512_mul_ps(k, at_or(gain, i, one)), p), dark);
        // the ADC and rounding of sixteen signals (noise added) from pixel i
        let adc = |s: __m512, i: usize| {
            let v = _mm512_add_ps(offset, at_or(offsets, i, zero));
            let v = _mm512_add_ps(v, _mm512_mul_ps(_mm512_min_ps(s, well), dn));
            let mut v = _mm512_add_ps(v, at_or(columns, i, neg_zeros));
            if top.is_some() {
                // max first, whose second operand (0) is what a NaN gives, as f32::max does
                let y = _mm512_add_ps(_mm512_min_ps(_mm512_max_ps(v, zero), top_v), half);
                let t = _mm512_sub_ps(_mm512_add_ps(y, shift), shift);
                v = _mm512_mask_sub_ps(t, _mm512_cmp_ps_mask::<_CMP_GT_OQ>(t, y), t, one);
            }
            v
        };
        // the deviates one block ahead: the next block's polynomials are independent of this block's readout, and
        // written before it they overlap it instead of waiting in the same dependency chain
        // (a row of n > 0 pixels draws n/64 runs, one a block, so a part block read after it takes the next run;
        // an empty row draws one it does not use)
        let blocks = n / 64;
        // SAFETY: the CPU has AVX-512 (the caller's promise)
        let mut next = unsafe { quantiles.next_run_512(normals) };
        for (b, block) in line.chunks_exact_mut(64).enumerate() {
            let z = next;
            if b + 1 < blocks {
                // SAFETY: as above
                next = unsafe { quantiles.next_run_512(normals) };
            }
            // sixteen floats at 16·j, inside the block of 64
            let at = |block: &mut [f32], j: usize| block[16 * j..].as_mut_ptr();
            // SAFETY: sixteen floats at `at`
            let s: [__m512; 4] =
                std::array::from_fn(|j| signal(unsafe { _mm512_loadu_ps(at(block, j)) }, 64 * b + 16 * j));
            // (a thermal detector's threshold is −∞: its NaN signals stay in the vector path)
            let normal = !r.shot_noise || s.iter().all(|&s| _mm512_cmp_ps_mask::<_CMP_GE_OQ>(s, threshold) == 0xffff);
            if normal {
                for (j, (s, z)) in s.into_iter().zip(z).enumerate() {
                    let sd = if r.shot_noise {
                        _mm512_sqrt_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_max_ps(s, zero), one), read_variance))
                    } else {
                        sigma
                    };
                    let s = _mm512_add_ps(s, _mm512_mul_ps(sd, z));
                    // SAFETY: sixteen floats at `at`
                    unsafe { _mm512_storeu_ps(at(block, j), adc(s, 64 * b + 16 * j)) };
                }
                continue;
            }
            let mut zs = [0f32; 64];
            for (j, (s, z)) in s.into_iter().zip(z).enumerate() {
                // SAFETY: sixteen floats at 16·j, inside `zs`, and at `at`
                unsafe {
                    _mm512_storeu_ps(zs.as_mut_ptr().add(16 * j), z);
                    _mm512_storeu_ps(at(block, j), s);
                }
            }
            r.noise_pixel_by_pixel(block, &zs, uniforms);
            for j in 0..4 {
                // SAFETY: sixteen floats at `at`
                unsafe { _mm512_storeu_ps(at(block, j), adc(_mm512_loadu_ps(at(block, j)), 64 * b + 16 * j)) };
            }
        }
    }

    /// A part block (`block`, fewer than 64 pixels, the end of a row whose whole blocks [`fused_row_512`] read out
    /// with the same generators) read out the same way: in a block of 64 whose other lanes repeat its last pixel
    /// and are dropped. Its deviates are the first of the next run, which are those the general path draws for a
    /// part block ([`Quantiles::fill`]). The copies come after its pixels, so its pixels draw their exact counts'
    /// uniforms first, and a pixel's value does not depend on the path its block takes (above the Poisson
    /// threshold the per-pixel and the vector noise are the same operations): what the copies hold changes none
    /// of its bits (repeating the last pixel keeps the block's path that of its own pixels). `maps` are the
    /// block's gain, offset and column offsets, each `block`'s length where given.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL).
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn fused_part_block_512(
        r: &Readout,
        block: &mut [f32],
        maps: [Option<&[f32]>; 3],
        rngs: (&mut SplitMix64, &mut SplitMix64),
        top: Option<f32>,
    ) {
        let n = block.len();
        assert!(n > 0 && n < BLOCK && maps.iter().flatten().all(|m| m.len() == n), "a part block, maps of its length");
        // the values in a block of 64, the last repeated
        fn pad<'a>(values: &[f32], to: &'a mut [f32; BLOCK]) -> &'a mut [f32] {
            to.fill(values[values.len() - 1]);
            to[..values.len()].copy_from_slice(values);
            to
        }
        let mut padded = [[0f32; BLOCK]; 4];
        let [whole, g, o, c] = &mut padded;
        let whole = pad(block, whole);
        let [gain, offsets, columns] = maps;
        let maps = [gain.map(|m| &*pad(m, g)), offsets.map(|m| &*pad(m, o)), columns.map(|m| &*pad(m, c))];
        // SAFETY: the CPU has AVX-512 (the caller's promise); a whole block, maps of its length
        unsafe { fused_row_512(r, whole, maps, rngs, top) };
        block.copy_from_slice(&whole[..n]);
    }
}

/// The readout's block of pixels: the general path's unit of work, and one run of the `table` sampler's deviates.
const BLOCK: usize = 64;

/// Rounds to the nearest level in `[0, top]` (`top` a whole number ≤ 2²²), halves up; NaN becomes 0.
///
/// `⌊y⌋` for `y = x + ½` in `[0, 2²²]`: adding and subtracting 2²³ rounds `y` to a whole number `t` (f32
/// arithmetic, exact here), and `t − [t > y]` is the floor. Written this way the loop vectorizes on the
/// baseline x86-64 target, which has neither a rounding instruction nor a vector float-to-int conversion with
/// Rust's saturating semantics.
#[inline]
pub fn quantize_row(line: &mut [f32], top: f32) {
    for p in line {
        *p = quantize_level(*p, top);
    }
}

/// 2²³: adding and subtracting it rounds an f32 in [0, 2²²] to a whole number ([`quantize_level`]).
const QUANTIZE_SHIFT: f32 = 8_388_608.0;

/// [`quantize_row`] of one value.
#[inline(always)]
pub fn quantize_level(v: f32, top: f32) -> f32 {
    // max first: NaN.max(0) is 0
    let y = v.max(0.0).min(top) + 0.5;
    let t = (y + QUANTIZE_SHIFT) - QUANTIZE_SHIFT;
    if t > y { t - 1.0 } else { t }
}

/// A Poisson sample of mean `mean`: exact below `threshold`, rounded normal above.
///
/// Exact samples come from sequential-search inversion for means below 10 and from Hörmann's transformed
/// rejection with squeeze, PTRS ("The transformed rejection method for generating Poisson random variables",
/// Insurance: Mathematics and Economics 12, 1993) from 10 up: about 1.1 tries per sample, most of them accepted
/// by the squeeze without a logarithm, where inversion would take `mean` steps.
pub fn poisson<R: Rng + ?Sized>(mean: f64, threshold: f64, rng: &mut R) -> f64 {
    if !(mean > 0.0) {
        return 0.0;
    }
    if mean >= threshold {
        return (mean + mean.sqrt() * standard_normal(rng)).round().max(0.0);
    }
    if mean >= 10.0 {
        return poisson_ptrs(mean, rng);
    }
    // Sequential-search inversion.
    let u: f64 = rng.random();
    let mut k = 0.0;
    let mut p = (-mean).exp();
    let mut cdf = p;
    while u > cdf && p > 0.0 {
        k += 1.0;
        p *= mean / k;
        cdf += p;
    }
    k
}

/// Hörmann's PTRS for `mean ≥ 10` (the constants are his, tuned for that range).
fn poisson_ptrs<R: Rng + ?Sized>(mean: f64, rng: &mut R) -> f64 {
    let b = 0.931 + 2.53 * mean.sqrt();
    let a = -0.059 + 0.024_83 * b;
    let v_r = 0.927_7 - 3.622_4 / (b - 2.0);
    // the logarithms are needed only when the squeeze fails (about one try in seven)
    let mut logs: Option<(f64, f64)> = None;
    loop {
        let u = rng.random::<f64>() - 0.5;
        let v: f64 = rng.random();
        let us = 0.5 - u.abs();
        let x = (2.0 * a / us + b) * u + mean + 0.43;
        // k = ⌊x⌋; for x ≥ 0 truncation is the floor (no libm call); x < 0 (or NaN, us = 0) is a rejection.
        // For mean ≥ 10 the squeeze region (us ≥ 0.07) always has x > 0, so testing the sign first changes
        // nothing.
        if !(x >= 0.0) {
            continue;
        }
        let k = (x as u64) as f64;
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if us < 0.013 && v > us {
            continue;
        }
        let (ln_inv_alpha, ln_mean) = *logs.get_or_insert_with(|| ((1.123_9 + 1.132_8 / (b - 3.4)).ln(), mean.ln()));
        // the exact acceptance test, in logarithms
        if v.ln() + ln_inv_alpha - (a / (us * us) + b).ln() <= -mean + k * ln_mean - ln_factorial(k) {
            return k;
        }
    }
}

/// `ln k!` for a whole `k ≥ 0`: a table to 1023, Stirling's series beyond (relative error below 1e-16 there).
fn ln_factorial(k: f64) -> f64 {
    static TABLE: std::sync::LazyLock<Vec<f64>> = std::sync::LazyLock::new(|| {
        let mut t = vec![0.0; 1024];
        for i in 1..t.len() {
            t[i] = t[i - 1] + (i as f64).ln();
        }
        t
    });
    if k < 1024.0 {
        return TABLE[k as usize];
    }
    // ln k! = (k + ½) ln(k + 1) − (k + 1) + ½ ln 2π + 1/(12(k+1)) − 1/(360(k+1)³)
    let n = k + 1.0;
    (n - 0.5) * n.ln() - n + 0.5 * (2.0 * std::f64::consts::PI).ln() + 1.0 / (12.0 * n) - 1.0 / (360.0 * n * n * n)
}

/// A standard normal sample (rand_distr's 64-bit ziggurat).
#[inline]
pub fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    use rand_distr::Distribution;
    rand_distr::StandardNormal.sample(rng)
}

/// Total-variation distance between Poisson(`mean`) and the rounded, clamped normal `N(mean, mean)`.
///
/// Exact up to the normal CDF, which is evaluated to about 1e-15 absolute.
pub fn normal_approximation_tv(mean: f64) -> f64 {
    let sd = mean.sqrt();
    let top = (mean + 40.0 * sd + 50.0).ceil() as u64;
    let mut total = 0.0;
    let mut ln_p = -mean; // ln Poisson pmf at k
    for k in 0..=top {
        let kf = k as f64;
        if k > 0 {
            ln_p += mean.ln() - kf.ln();
        }
        let upper = normal_cdf((kf + 0.5 - mean) / sd);
        let lower = if k == 0 { 0.0 } else { normal_cdf((kf - 0.5 - mean) / sd) };
        total += (ln_p.exp() - (upper - lower)).abs();
    }
    total / 2.0
}

/// Standard normal CDF via `erfc`, accurate to about 1e-15 absolute.
pub fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// Kolmogorov–Smirnov distance between the sample `sorted` (ascending) and the standard normal law: the largest
/// gap between its empirical CDF and `Φ`, on either side of each step. At the 1 % level a sample of the law
/// stays below `1.63/√n`.
pub fn ks_distance_normal(sorted: &[f32]) -> f64 {
    let n = sorted.len() as f64;
    sorted
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let c = normal_cdf(f64::from(s));
            (c - i as f64 / n).abs().max(((i + 1) as f64 / n - c).abs())
        })
        .fold(0.0, f64::max)
}

/// Complementary error function: series for |x| < 2, continued fraction (Lentz) beyond.
fn erfc(x: f64) -> f64 {
    if x < 0.0 {
        return 2.0 - erfc(-x);
    }
    if x < 2.0 {
        // erf(x) = 2/√π Σ (−1)ⁿ x^{2n+1}/(n!(2n+1))
        let mut term = x;
        let mut sum = x;
        let x2 = x * x;
        for n in 1..80 {
            term *= -x2 / n as f64;
            let add = term / (2 * n + 1) as f64;
            sum += add;
            if add.abs() < 1e-17 * sum.abs() {
                break;
            }
        }
        return 1.0 - sum * std::f64::consts::FRAC_2_SQRT_PI;
    }
    // erfc(x) = e^{−x²}/√π · 1/(x + 1/2/(x + 1/(x + 3/2/(x + …))))
    let tiny = 1e-300;
    let mut f = x;
    let mut c = x;
    let mut d = 0.0;
    for n in 1..200 {
        let a = n as f64 / 2.0;
        d = x + a * d;
        d = if d.abs() < tiny { tiny } else { d };
        c = x + a / c;
        c = if c.abs() < tiny { tiny } else { c };
        d = 1.0 / d;
        let delta = c * d;
        f *= delta;
        if (delta - 1.0).abs() < 1e-16 {
            break;
        }
    }
    (-x * x).exp() / (f * std::f64::consts::PI.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfc_reference_values() {
        // values from the series definition, independent of this implementation
        assert!((erfc(0.5) - 0.479_500_122_186_953_5).abs() < 1e-15);
        assert!((erfc(2.5) - 4.069_520_174_449_59e-4).abs() < 1e-18);
        assert!((erfc(-1.0) - 1.842_700_792_949_715).abs() < 1e-15);
    }

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: u64 = stream_rng(7, stage::SENSOR_NOISE, 3, 0).random();
        let b: u64 = stream_rng(7, stage::SENSOR_NOISE, 3, 0).random();
        let c: u64 = stream_rng(7, stage::SENSOR_NOISE, 4, 0).random();
        let d: u64 = stream_rng(7, stage::VIBRATION, 3, 0).random();
        let e: u64 = stream_rng(7, stage::SENSOR_NOISE, 3, 1).random();
        assert_eq!(a, b);
        assert!(a != c && a != d && a != e && c != d);
    }

    #[test]
    fn quantization_rounds_halves_up_and_clamps() {
        let top = 65_535.0f32;
        let mut values = vec![f32::NAN, f32::NEG_INFINITY, f32::INFINITY, -0.7, 0.0, 0.49, 0.5, 1.5, 2.5, 65_534.5];
        values.extend([65_535.4, 65_535.6, 1e9, 4_194_303.5, 12_345.499, 12_345.5]);
        // every representable value between 1000 and 1003, and a spread of others
        let mut x = 1000.0f32;
        while x < 1003.0 {
            values.push(x);
            x = f32::from_bits(x.to_bits() + 1);
        }
        values.extend((0..10_000).map(|i| i as f32 * 6.553_7 - 10.0));
        let mut out = values.clone();
        quantize_row(&mut out, top);
        for (&v, &q) in values.iter().zip(&out) {
            let want = if v.is_nan() { 0.0 } else { (f64::from(v).clamp(0.0, f64::from(top)) + 0.5).floor() };
            assert_eq!(f64::from(q), want, "{v}");
        }
    }

    #[test]
    fn exact_poisson_samples_fit_the_law() {
        // χ² goodness of fit on 200 000 samples per mean, classes merged until each expects ≥ 20
        for mean in [0.3f64, 3.0, 9.99, 10.0, 12.0, 60.0, 250.0, 499.0] {
            let mut rng = crate::physics::random::SplitMix64::substream(5, mean.to_bits());
            let n = 200_000usize;
            let top = (mean + 12.0 * mean.sqrt() + 20.0) as usize;
            let mut counts = vec![0f64; top + 1];
            for _ in 0..n {
                let k = poisson(mean, 500.0, &mut rng);
                counts[(k as usize).min(top)] += 1.0;
            }
            let mut ln_p = -mean;
            let mut pmf = Vec::with_capacity(top + 1);
            for k in 0..=top {
                if k > 0 {
                    ln_p += mean.ln() - (k as f64).ln();
                }
                pmf.push(ln_p.exp());
            }
            let (mut chi2, mut classes, mut expected, mut observed) = (0.0, 0usize, 0.0, 0.0);
            for k in 0..=top {
                expected += pmf[k] * n as f64;
                observed += counts[k];
                if expected >= 20.0 {
                    chi2 += (observed - expected).powi(2) / expected;
                    classes += 1;
                    (expected, observed) = (0.0, 0.0);
                }
            }
            let df = classes as f64 - 1.0;
            // far beyond the 1e-6 tail of χ²(df)
            let limit = df + 7.0 * (2.0 * df).sqrt() + 10.0;
            assert!(chi2 < limit, "mean {mean}: χ² = {chi2} with {df} degrees of freedom");
        }
    }

    #[test]
    fn ln_factorial_matches_the_direct_sum() {
        let mut direct = 0.0;
        for k in 1..3000u32 {
            direct += f64::from(k).ln();
            let got = ln_factorial(f64::from(k));
            assert!((got - direct).abs() <= 1e-12 * direct.max(1.0), "{k}: {got} vs {direct}");
        }
    }

    #[test]
    fn normal_approximation_error_table() {
        for (mean, want) in [(10.0, 0.0402), (100.0, 0.0126), (1000.0, 0.0040)] {
            let tv = normal_approximation_tv(mean);
            assert!((tv - want).abs() < 5e-4, "mean {mean}: tv {tv}");
        }
    }

    fn readout() -> Readout {
        Readout {
            signal_per_radiance: 2.0,
            dark_signal: 0.0,
            shot_noise: true,
            read_variance: 4.0,
            full_well: f32::INFINITY,
            dn_per_signal: 0.25,
            offset_dn: 100.0,
            poisson_normal_threshold: 100.0,
            normal_sampler: NormalSampler::Ziggurat,
        }
    }

    #[test]
    fn row_parallel_noise_does_not_depend_on_thread_count() {
        let r = readout();
        let base: Vec<f32> = (0..64 * 48).map(|i| (i % 700) as f32).collect();
        let mut a = base.clone();
        r.apply(&mut a, 64, ReadoutMaps::default(), true, 11, 5, None, None);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut b = base.clone();
        pool.install(|| r.apply(&mut b, 64, ReadoutMaps::default(), true, 11, 5, None, None));
        assert_eq!(a, b);
        let mut c = base.clone();
        r.apply(&mut c, 64, ReadoutMaps::default(), false, 11, 5, None, None);
        for (i, (&v, &l)) in c.iter().zip(&base).enumerate() {
            assert_eq!(v, r.mean_dn(l, 1.0, 0.0), "pixel {i}");
        }
        assert_ne!(a, c);
    }

    #[test]
    fn the_fused_pass_is_the_general_path_bit_for_bit() {
        // thermal and photon detectors with the table sampler: radiances below zero, across the range and past
        // the well and the top level, widths of 4 and 10 blocks and widths that end in a part block (160, 650)
        // or are less than one (17), rounded and not; for the photon detector, rows whose blocks are all above
        // the Poisson threshold and rows where most blocks have a pixel below it
        let thermal = Readout {
            shot_noise: false,
            read_variance: 9.0,
            dark_signal: 3.5,
            full_well: 5000.0,
            normal_sampler: NormalSampler::Table,
            ..readout()
        };
        let avx512 = crate::physics::simd::Level::detect() == crate::physics::simd::Level::Avx512;
        if !avx512 {
            eprintln!("no AVX-512 here (or IRSIM_SIMD caps it): the fused pass is not compared");
        }
        for r in [thermal, Readout { shot_noise: true, ..thermal }] {
            for (w, h) in [(256, 9), (640, 5), (160, 7), (650, 5), (17, 6)] {
                let mut base: Vec<f32> = (0..w * h)
                    .map(|i| {
                        let v = ((i * 7919) % 11_000) as f32 * 0.37;
                        if (i / w) % 2 == 0 { v + 60.0 } else { v - 500.0 }
                    })
                    .collect();
                // for the photon detector, a NaN (whose block takes the per-pixel path in both; a thermal
                // detector's NaN is outside the promise) and a signal exactly at the Poisson threshold without the
                // maps ((2·1)·48.25 + 3.5 = 100), in odd rows; and a NaN as the last pixel of row 4 (in a part
                // block where the width has one)
                if r.shot_noise {
                    base[w + 5] = f32::NAN;
                    base[3 * w + 7] = 48.25;
                    base[5 * w - 1] = f32::NAN;
                }
                assert_eq!(r.fuses(w, true), avx512);
                let gain: Vec<f32> = (0..w * h).map(|i| 0.9 + 0.2 * ((i * 37) % 101) as f32 / 101.0).collect();
                let offset: Vec<f32> = (0..w * h).map(|i| ((i * 53) % 17) as f32 - 8.0).collect();
                let columns: Vec<f32> = (0..w).map(|x| (x % 5) as f32 * 0.75 - 1.5).collect();
                let with_maps = ReadoutMaps { gain: Some(&gain), offset_dn: Some(&offset), column_dn: Some(&columns) };
                for maps in [ReadoutMaps::default(), with_maps] {
                    for top in [Some(1023.0), None] {
                        let mut fused = base.clone();
                        r.apply_rows(&mut fused, w, maps, true, (7, 3), top, None, true);
                        let mut general = base.clone();
                        r.apply_rows(&mut general, w, maps, true, (7, 3), top, None, false);
                        for (i, (a, b)) in fused.iter().zip(&general).enumerate() {
                            let shot = r.shot_noise;
                            assert_eq!(
                                a.to_bits(),
                                b.to_bits(),
                                "shot {shot}, {w}×{h}, top {top:?}, pixel {i}: {a}, {b}"
                            );
                        }
                        // (a photon detector's count is never below 0: with an offset of 100 DN, read noise of
                        // 3 electrons at 4 per DN and maps of at most −9.5 DN, its lowest level stays above 0)
                        if let Some(top) = top {
                            assert!(fused.contains(&top), "the top level was reached");
                            assert!(r.shot_noise || fused.contains(&0.0), "the bottom level was reached");
                        }
                    }
                }
            }
        }
        let r = thermal;
        // levels exactly halfway (noise far below an ulp: 1e-15 against signals of 1–1000) round up in both
        let halves = Readout {
            read_variance: 1e-30,
            dark_signal: 0.0,
            signal_per_radiance: 1.0,
            dn_per_signal: 1.0,
            offset_dn: 0.5,
            ..r
        };
        let base: Vec<f32> = (0..256 * 4).map(|i| (i % 1000) as f32).collect();
        let (mut fused, mut general) = (base.clone(), base.clone());
        halves.apply_rows(&mut fused, 256, ReadoutMaps::default(), true, (1, 1), Some(4095.0), None, true);
        halves.apply_rows(&mut general, 256, ReadoutMaps::default(), true, (1, 1), Some(4095.0), None, false);
        assert_eq!(fused, general);
        assert!(fused.iter().zip(&base).all(|(&v, &l)| v == l + 1.0), "x + ½ rounds to x + 1");
        // another sampler, an empty row, no noise or a detector without noise take the general path
        assert!(!Readout { normal_sampler: NormalSampler::BoxMuller, ..r }.fuses(256, true));
        assert!(!Readout { read_variance: 0.0, ..r }.fuses(256, true));
        // a photon detector without read noise fuses, and gives the general path's bits
        let photons = Readout { shot_noise: true, read_variance: 0.0, ..r };
        assert_eq!(photons.fuses(256, true), avx512);
        let base: Vec<f32> = (0..256 * 4).map(|i| ((i * 7919) % 3000) as f32 * 0.5 - 20.0).collect();
        let (mut fused, mut general) = (base.clone(), base.clone());
        photons.apply_rows(&mut fused, 256, ReadoutMaps::default(), true, (5, 2), Some(4095.0), None, true);
        photons.apply_rows(&mut general, 256, ReadoutMaps::default(), true, (5, 2), Some(4095.0), None, false);
        assert_eq!(fused, general);
        assert!(!r.fuses(0, true) && !r.fuses(256, false));
    }

    #[test]
    fn a_filled_readout_is_the_readout_of_the_filled_frame() {
        // rows filled block by block as they are read out, against the whole frame filled first (a width whose
        // blocks do not divide the frame's rows)
        let r = readout();
        let (w, h) = (200, 45);
        let value = |row: usize, x: usize| ((row * 31 + x * 7) % 900) as f32;
        let mut first = vec![0f32; w * h];
        for (row, line) in first.chunks_mut(w).enumerate() {
            for (x, v) in line.iter_mut().enumerate() {
                *v = value(row, x);
            }
        }
        r.apply(&mut first, w, ReadoutMaps::default(), true, 3, 9, Some(16383.0), None);
        let fill = |start: usize, block: &mut [f32]| {
            for (k, line) in block.chunks_mut(w).enumerate() {
                for (x, v) in line.iter_mut().enumerate() {
                    *v = value(start + k, x);
                }
            }
        };
        let mut filled = vec![f32::NAN; w * h];
        r.apply(&mut filled, w, ReadoutMaps::default(), true, 3, 9, Some(16383.0), Some(&fill));
        assert!(first.iter().zip(&filled).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn a_block_with_a_pixel_under_the_threshold_draws_exact_counts_there_alone() {
        // no read noise and 1 DN an electron: an exact Poisson count is a whole number of DN, a normal draw is not
        let r =
            Readout { read_variance: 0.0, dn_per_signal: 1.0, offset_dn: 0.0, signal_per_radiance: 1.0, ..readout() };
        // one row of two blocks: the first with dim pixels (5 e⁻) among bright ones, the second all bright
        let mut p: Vec<f32> = (0..128).map(|i| if i < 64 && i % 8 == 0 { 5.0 } else { 5000.0 }).collect();
        r.apply(&mut p, 128, ReadoutMaps::default(), true, 7, 3, None, None);
        let whole = |v: f32| v == v.round();
        for (i, &v) in p.iter().enumerate() {
            if i < 64 && i % 8 == 0 {
                assert!(whole(v) && (0.0..40.0).contains(&v), "dim pixel {i}: {v}");
            }
        }
        // the bright pixels of both blocks take the normal law: hardly any lands on a whole number
        let bright_whole = p.iter().enumerate().filter(|&(i, &v)| !(i < 64 && i % 8 == 0) && whole(v)).count();
        assert!(bright_whole < 10, "{bright_whole} of 120 bright pixels whole");
    }

    #[test]
    fn maps_and_saturation() {
        let r = Readout { full_well: 1000.0, ..readout() };
        let gain = vec![0.5f32; 8];
        let offset = vec![3.0f32; 8];
        let mut p = vec![100.0f32, 100.0, 100.0, 100.0, 1e6, 1e6, 0.0, 0.0];
        let maps = ReadoutMaps { gain: Some(&gain), offset_dn: Some(&offset), column_dn: None };
        r.apply(&mut p, 8, maps, false, 1, 1, Some(16_383.0), None);
        // 2·0.5·100 = 100 e⁻ → 100 + 3 + 25 = 128 DN; saturated: 100 + 3 + 250 = 353 DN
        assert_eq!(&p[..4], &[128.0; 4]);
        assert_eq!(&p[4..6], &[353.0; 2]);
        assert_eq!(&p[6..], &[103.0; 2]);
    }
}
