//! Fast seeded randomness for per-pixel work: SplitMix64 streams and a 32-bit ziggurat for normal deviates.
//!
//! Sensor noise draws one normal deviate per pixel, tens of millions a second; a cryptographic generator and a
//! 64-bit ziggurat cost more there than the rest of the frame. This module gives the per-pixel stages:
//!
//! - [`SplitMix64`] (Steele, Lea & Flood, "Fast splittable pseudorandom number generators", OOPSLA 2014): a
//!   Weyl sequence through a 64-bit mixing function, one multiply-xorshift chain per output, period 2⁶⁴; it
//!   passes BigCrush. A row of pixels gets its own generator whose start is a hash of the frame's key and the
//!   row, so the result does not depend on how rows are scheduled.
//! - [`Ziggurat`]: Marsaglia & Tsang's ziggurat ("The Ziggurat Method for Generating Random Variables", J.
//!   Stat. Softw. 5(8), 2000) with 256 layers, on 32 random bits per deviate, two deviates per 64-bit draw. The
//!   layer index (bits 0–7) and the signed magnitude (bits 8–31) come from disjoint bits (the original takes the
//!   index from bits of the magnitude, a correlation Doornik pointed out in "An Improved Ziggurat Method to
//!   Generate Normal Random Samples", 2005). Layers are exact; the magnitude is quantized to 2⁻²³ of its layer's
//!   width, so the deviates take about 2²⁴ distinct values per layer — far finer than any gray level. The tail
//!   beyond r = 3.6542 is sampled exactly (Marsaglia's exponential rejection).
//! - [`box_muller`]: Box–Muller on two 24-bit uniforms per draw, with a logarithm and a sine/cosine of our own
//!   (polynomials, no table, no libm): the `standard` preset's sampler ([`NormalSampler::BoxMuller`]). Without a
//!   table or a rejection step its fill vectorizes (64-bit multiplies for the draws, square roots and
//!   polynomials for the transform), where the ziggurat's table lookups and rare second tries keep it scalar.
//! - [`Quantiles`]: a deviate is a quantile of the normal law picked by 16 random bits, four deviates per 64-bit
//!   draw: the `draft` preset's sampler ([`NormalSampler::Table`]). A draw and four short polynomials per four
//!   deviates, with no branch (and with AVX-512 no memory read), against the ziggurat's two deviates per draw with a
//!   comparison each; the price is that the deviates take the 2¹⁶ quantiles' values (each within 8e-5 σ) and
//!   none lies beyond 4.32 σ (the law puts 1.5·10⁻⁵ of its mass there).

use std::convert::Infallible;
use std::sync::LazyLock;

use rand::TryRng;
use serde::{Deserialize, Serialize};

/// How the sensor noise draws its standard normal deviates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NormalSampler {
    /// The ziggurat: exact to f32, the tail included.
    #[default]
    Ziggurat,
    /// A quantile per deviate, picked by 16 bits ([`Quantiles`]: a polynomial per octave of the bits'
    /// distance from the nearer end): cheaper, the tail cut at 4.32 σ.
    Table,
    /// Box–Muller on two 24-bit uniforms per draw ([`box_muller`]): no table and no rejection, so the fill
    /// vectorizes; deviates within 1e-6 of the exact transform, none beyond 5.77 σ (the law puts 8·10⁻⁹ of its
    /// mass there).
    BoxMuller,
}

/// Calls `$f($args…, fill)` with `fill` the fill of `$sampler` ([`NormalSampler::fill`] of that one variant, as
/// an `#[inline(always)]` closure), choosing the variant once: a per-pixel loop over blocks that calls `$f` gets
/// one copy per sampler, each with its fill inlined, where a loop that matched on the sampler block by block had
/// compiled the table's fill to code twice as slow (the readout of the `draft` preset on paper_vibration, 31–34
/// against 64–74 µs a frame). Inside [`crate::physics::simd::widest`], `$f` must be `#[inline(always)]` too.
macro_rules! with_normal_fill {
    ($sampler:expr, $f:path, ($($arg:expr),* $(,)?)) => {{
        use $crate::physics::random::{NormalSampler, SplitMix64};
        match $sampler {
            NormalSampler::Ziggurat => $f($($arg,)* #[inline(always)] |r: &mut SplitMix64, z: &mut [f32]| {
                NormalSampler::Ziggurat.fill(r, z)
            }),
            NormalSampler::Table => $f($($arg,)* #[inline(always)] |r: &mut SplitMix64, z: &mut [f32]| {
                NormalSampler::Table.fill(r, z)
            }),
            NormalSampler::BoxMuller => $f($($arg,)* #[inline(always)] |r: &mut SplitMix64, z: &mut [f32]| {
                NormalSampler::BoxMuller.fill(r, z)
            }),
        }
    }};
}
pub(crate) use with_normal_fill;

impl NormalSampler {
    /// Fills `out` with standard normal deviates from `rng`.
    #[inline(always)]
    pub fn fill(self, rng: &mut SplitMix64, out: &mut [f32]) {
        match self {
            Self::Ziggurat => Ziggurat::get().fill(rng, out),
            Self::Table => Quantiles::get().fill(rng, out),
            Self::BoxMuller => {
                // draw p of the pairs is the generator's (p + 1)-th
                box_muller_fill(rng.state, out);
                let draws = out.len().div_ceil(2) as u64;
                rng.state = rng.state.wrapping_add(draws.wrapping_mul(SplitMix64::GAMMA));
            }
        }
    }
}

/// 2⁻²⁴.
const U24: f32 = 1.0 / 16_777_216.0;

/// Two standard normal deviates from 64 random bits: Box–Muller, `√(−2 ln u₁)·(cos 2πu₂, sin 2πu₂)`, with
/// `u₁ = (bits 40–63 + 1)/2²⁴` in (0, 1] and `u₂ = (bits 0–23)/2²⁴` in [0, 1), in f32 with [`ln_f32`] and
/// [`sin_cos_turns`] (no libm call, no table: every operation has a vector form, and rounds the same in every
/// lane on every instruction set).
#[inline(always)]
pub fn box_muller(bits: u64) -> (f32, f32) {
    // through i32, whose conversion to f32 is one vector instruction on every x86-64 (exact below 2²⁴ + 1)
    let u1 = (((bits >> 40) as u32 + 1) as i32) as f32 * U24;
    let u2 = ((bits & 0xff_ffff) as u32 as i32) as f32 * U24;
    let r = (-2.0 * ln_f32(u1)).sqrt();
    let (s, c) = sin_cos_turns(u2);
    (r * c, r * s)
}

/// Standard normal deviates into `out`: pair `p` (deviates `2p` and `2p + 1`) is [`box_muller`] of the draw
/// `mix64(state + (p + 1)·GAMMA)`, the `(p + 1)`-th of a [`SplitMix64`] that starts after `state`; an odd
/// length's last deviate is the first of its pair's. Each draw's state is in closed form, so no pair waits for
/// the one before: where the CPU has AVX-512, sixteen pairs at a time in vector registers, with AVX2 eight (its
/// 64-bit multiplies made of 32-bit ones), by the same f32 operations in the same order as [`box_muller`] (so the
/// same bits), else a scalar loop.
#[inline(always)]
pub fn box_muller_fill(state: u64, out: &mut [f32]) {
    let draw = |p: usize| mix64(state.wrapping_add((p as u64 + 1).wrapping_mul(SplitMix64::GAMMA)));
    #[cfg(target_arch = "x86_64")]
    let done = match crate::physics::simd::Level::detect() {
        // SAFETY: the CPU has AVX-512
        crate::physics::simd::Level::Avx512 => unsafe { x86::box_muller_512(state, out) },
        // SAFETY: the CPU has AVX2
        crate::physics::simd::Level::Avx2 => unsafe { x86::box_muller_256(state, out) },
        crate::physics::simd::Level::Baseline => 0,
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    let last_pair = out.len() / 2;
    let mut pairs = out[2 * done..].chunks_exact_mut(2);
    for (k, pair) in (&mut pairs).enumerate() {
        let (a, b) = box_muller(draw(done + k));
        pair[0] = a;
        pair[1] = b;
    }
    if let [last] = pairs.into_remainder() {
        *last = box_muller(draw(last_pair)).0;
    }
}

/// `ln x` for a positive normal f32 `x`, within 2e-7 relative (`ln 1 = 0` exactly): the exponent, and
/// `2·atanh((m − 1)/(m + 1))` as its series to `s⁹` for the mantissa `m` brought into [√½, √2) (the next term is
/// below 1e-9).
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x7f_ffff) | 0x3f80_0000);
    let high = m > std::f32::consts::SQRT_2;
    let (m, e) = if high { (m * 0.5, e + 1) } else { (m, e) };
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = 1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0))));
    e as f32 * std::f32::consts::LN_2 + 2.0 * s * series
}

/// `(sin 2πt, cos 2πt)` for `t` in [0, 1), within 4e-7: the nearest quarter turn, and Taylor polynomials to
/// the 7th and 8th power on the rest, in [−π/4, π/4].
#[inline(always)]
pub fn sin_cos_turns(t: f32) -> (f32, f32) {
    let q = (t * 4.0 + 0.5) as i32; // 0 ..= 4
    let r = (t - q as f32 * 0.25) * std::f32::consts::TAU;
    let r2 = r * r;
    let s = r * (1.0 - r2 * (1.0 / 6.0 - r2 * (1.0 / 120.0 - r2 * (1.0 / 5040.0))));
    let c = 1.0 - r2 * (0.5 - r2 * (1.0 / 24.0 - r2 * (1.0 / 720.0 - r2 * (1.0 / 40320.0))));
    let (s, c) = if q & 1 == 1 { (c, -s) } else { (s, c) };
    if q & 2 == 2 { (-s, -c) } else { (s, c) }
}

/// SplitMix64: a Weyl sequence with increment [`SplitMix64::GAMMA`] through the [`mix64`] finalizer.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// The Weyl increment, ⌊2⁶⁴/φ⌋ made odd.
    pub const GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

    /// A generator starting after state `state`.
    pub fn new(state: u64) -> Self {
        Self { state }
    }

    /// The generator for sub-stream `substream` of `key`: the start is a hash of both, so sub-streams begin at
    /// unrelated points of the 2⁶⁴ cycle.
    pub fn substream(key: u64, substream: u64) -> Self {
        Self::new(mix64(key ^ mix64(substream.wrapping_mul(Self::GAMMA).wrapping_add(0x6A09_E667_F3BC_C909))))
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_bits(&mut self) -> u64 {
        self.state = self.state.wrapping_add(Self::GAMMA);
        mix64(self.state)
    }

    /// A uniform deviate in (0, 1], 53 bits.
    #[inline]
    pub fn uniform_open0(&mut self) -> f64 {
        ((self.next_bits() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// The SplitMix64 output function (Stafford's "Mix13" variant of the MurmurHash3 finalizer): a bijection of
/// u64 with full avalanche.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl TryRng for SplitMix64 {
    type Error = Infallible;

    #[inline]
    fn try_next_u32(&mut self) -> Result<u32, Infallible> {
        Ok((self.next_bits() >> 32) as u32)
    }

    #[inline]
    fn try_next_u64(&mut self) -> Result<u64, Infallible> {
        Ok(self.next_bits())
    }

    fn try_fill_bytes(&mut self, dst: &mut [u8]) -> Result<(), Infallible> {
        for chunk in dst.chunks_mut(8) {
            let bytes = self.next_bits().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
        Ok(())
    }
}

/// Number of ziggurat layers.
const LAYERS: usize = 256;
/// Magnitudes are 23-bit.
const MAGNITUDE_SCALE: f64 = (1u32 << 23) as f64;
/// Right edge of the base layer (Marsaglia & Tsang, 256 layers).
const R: f64 = 3.654_152_885_361_009;
/// Largest difference between a deviate of [`Quantiles`] and the exact quantile it stands for, in σ
/// (`quantiles_match_the_exact_inverse`; measured 6.4e-5). The error is smooth within an octave and every jump
/// between octaves goes up, so the deviates keep the quantiles' order (checked for all 2¹⁶).
pub const QUANTILE_MAX_ERROR: f64 = 8e-5;

/// Random bits per deviate of [`Quantiles`].
const QUANTILE_BITS: u32 = 16;
/// Coefficients of [`Quantiles`]'s polynomials, constant term first.
const QUANTILE_TERMS: usize = 5;
/// Octaves of [`Quantiles`]: `d + 1` in `[2^e, 2^(e+1))` for `e` in 0 … 15 (`d` below 2¹⁵).
const OCTAVES: usize = 16;

/// The deviates of [`NormalSampler::Table`]. For 16 random bits `i` in the lower half (`i < 2¹⁵`), the deviate
/// is `i`'s quantile `Φ⁻¹((i + ½)/2¹⁶)` of the standard normal law; the upper half is the mirror image (`i`
/// gives minus the deviate of `2¹⁶ − 1 − i`). So the deviates take the 2¹⁶ values of the 2¹⁶ quantiles, out to
/// 4.32 σ in the tails.
///
/// The quantiles are not read from a table: `n = d + 1` (`d` the distance from the nearer end, 0 … 2¹⁵ − 1, so
/// `n` in 1 … 2¹⁵) is written as `2^e·m` with `m` in [1, 2) (the exponent and mantissa of `n` as an f32), and the
/// quantile is a polynomial of degree 4 in `m − 1.5` whose five coefficients are those of octave `e`, fitted by least squares
/// to that octave's exact quantiles (octaves of five points or fewer are interpolated). Sixteen octaves make each
/// coefficient a row of sixteen floats, one vector register with AVX-512, so a vector of sixteen deviates takes
/// five in-register permutes and eight multiplies and adds, where a table of the quantiles took a gather from
/// memory (the gathers were 45 % of the `draft` preset's readout on paper_vibration). Each deviate is within
/// [`QUANTILE_MAX_ERROR`] of its exact quantile; degree 5 came within 9e-6 σ and degree 3 within 4e-4 σ (out of
/// order at the middle), the readout 1–3 µs a frame slower and faster on paper_vibration.
#[derive(Debug)]
pub struct Quantiles {
    /// `coefficients[k][e]`: the coefficient of `(m − 1.5)^k` in octave `e`.
    coefficients: [[f32; OCTAVES]; QUANTILE_TERMS],
}

static QUANTILES: LazyLock<Quantiles> = LazyLock::new(Quantiles::fit);

impl Quantiles {
    /// The shared polynomials.
    pub fn get() -> &'static Self {
        &QUANTILES
    }

    /// Fits each octave's polynomial to its quantiles (in f64; rounded to f32 once fitted).
    fn fit() -> Self {
        let half = 1u32 << (QUANTILE_BITS - 1);
        let octaves: Vec<Vec<f64>> = (0..OCTAVES as u32)
            .map(|e| {
                let first = 1u32 << e;
                let points: Vec<(f64, f64)> = (first..(2 * first).min(half + 1))
                    .map(|n| {
                        let x = f64::from(n) / f64::from(first) - 1.5;
                        (x, inverse_normal_cdf((f64::from(n) - 0.5) / f64::from(2 * half)))
                    })
                    .collect();
                least_squares(&points, points.len().min(QUANTILE_TERMS))
            })
            .collect();
        let coefficients =
            std::array::from_fn(|k| std::array::from_fn(|e| octaves[e].get(k).map_or(0.0, |&c| c as f32)));
        Self { coefficients }
    }

    /// The deviate of the 16 random bits `i`: the same f32 operations, in the same order, as the vector code
    /// (so the same bits).
    #[inline(always)]
    pub fn value(&self, i: u16) -> f32 {
        let upper = i >= 0x8000;
        let d = if upper { i ^ 0xffff } else { i };
        let bits = (u32::from(d) + 1) as f32;
        let bits = bits.to_bits();
        let e = ((bits >> 23) - 127) as usize & (OCTAVES - 1);
        let x = f32::from_bits((bits & 0x7f_ffff) | 0x3f80_0000) - 1.5;
        let c = &self.coefficients;
        let mut z = c[QUANTILE_TERMS - 1][e];
        for k in (0..QUANTILE_TERMS - 1).rev() {
            z = z * x + c[k][e];
        }
        if upper { -z } else { z }
    }

    /// Fills `out` with standard normal deviates, four per 64-bit draw: `out[k]` is the deviate of bits
    /// `16·(k mod 4)` to `16·(k mod 4) + 15` of draw `⌊k/4⌋` ([`Quantiles::value`]).
    ///
    /// Runs of 64 deviates take their 16 draws in closed form (draw `i` after state `s` is `mix64(s + i·γ)`), so
    /// the draws have no carried dependence: with AVX-512 a run is four vectors of sixteen deviates, else a
    /// loop of [`Quantiles::value`].
    #[inline(always)]
    pub fn fill(&self, rng: &mut SplitMix64, out: &mut [f32]) {
        const RUN: usize = 64;
        const DRAWS: usize = RUN / 4;
        let mut runs = out.chunks_exact_mut(RUN);
        #[cfg(target_arch = "x86_64")]
        let wide = crate::physics::simd::Level::detect() == crate::physics::simd::Level::Avx512;
        for run in &mut runs {
            let start = rng.state;
            rng.state = start.wrapping_add((DRAWS as u64).wrapping_mul(SplitMix64::GAMMA));
            #[cfg(target_arch = "x86_64")]
            if wide {
                // SAFETY: the CPU has AVX-512
                unsafe { x86::quantile_run_512(&self.coefficients, start, run) };
                continue;
            }
            let mut draws = [0u64; DRAWS];
            for (i, d) in draws.iter_mut().enumerate() {
                // little-endian in memory whatever the target, so that index k below is bits 16·(k mod 4) up of
                // draw ⌊k/4⌋
                *d = mix64(start.wrapping_add((i as u64 + 1).wrapping_mul(SplitMix64::GAMMA))).to_le();
            }
            let index: [u16; RUN] = bytemuck::cast(draws);
            for (o, &i) in run.iter_mut().zip(&index) {
                // each field read back little-endian too: on a big-endian target the cast's u16s are byte-swapped
                *o = self.value(u16::from_le(i));
            }
        }
        // the rest four at a time, a draw each (the last group may be shorter)
        for quad in runs.into_remainder().chunks_mut(4) {
            let b = rng.next_bits();
            for (k, o) in quad.iter_mut().enumerate() {
                *o = self.value((b >> (16 * k)) as u16);
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl Quantiles {
    /// The next run of 64 deviates of `rng` as [`Quantiles::fill`] draws them into a slice of 64, as four vectors
    /// of sixteen (for a kernel that uses them where they are made).
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL).
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    #[inline]
    pub(crate) unsafe fn next_run_512(&self, rng: &mut SplitMix64) -> [std::arch::x86_64::__m512; 4] {
        let start = rng.state;
        rng.state = start.wrapping_add(16u64.wrapping_mul(SplitMix64::GAMMA));
        x86::quantile_vectors_512(&self.coefficients, start)
    }
}

/// The least-squares polynomial with `terms` coefficients (constant first) through the points `(x, y)`: the
/// normal equations solved by Gaussian elimination with partial pivoting (`x` within ±½ here, so they are well
/// conditioned in f64 at six terms).
fn least_squares(points: &[(f64, f64)], terms: usize) -> Vec<f64> {
    let mut a = vec![vec![0.0; terms + 1]; terms];
    for &(x, y) in points {
        let powers: Vec<f64> = (0..terms).scan(1.0, |p, _| Some(std::mem::replace(p, *p * x))).collect();
        for (r, row) in a.iter_mut().enumerate() {
            for c in 0..terms {
                row[c] += powers[r] * powers[c];
            }
            row[terms] += powers[r] * y;
        }
    }
    for col in 0..terms {
        let pivot = (col..terms).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs())).unwrap_or(col);
        a.swap(col, pivot);
        let (upper, lower) = a.split_at_mut(col + 1);
        let pivot_row = &upper[col];
        for row in lower {
            let f = row[col] / pivot_row[col];
            for (v, &p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                *v -= f * p;
            }
        }
    }
    let mut solution = vec![0.0; terms];
    for r in (0..terms).rev() {
        let rest: f64 = (r + 1..terms).map(|c| a[r][c] * solution[c]).sum();
        solution[r] = (a[r][terms] - rest) / a[r][r];
    }
    solution
}

/// `Φ⁻¹(u)` for `u` in (0, 1), within 1e-6 (the fit's points): `√2·erf⁻¹(2u − 1)` with Giles's approximation of
/// `erf⁻¹` ("Approximating the erfinv function", GPU Computing Gems Jade, 2011), a polynomial in
/// `w = −ln(1 − x²)` (one for `w < 5`, one in `√w` beyond); `1 − x² = 4u(1 − u)` is computed from `u`, so it
/// keeps its precision however close `u` is to 0 or 1.
fn inverse_normal_cdf(u: f64) -> f64 {
    let x = 2.0 * u - 1.0;
    let w = -(4.0 * u * (1.0 - u)).ln();
    let erfinv = if w < 5.0 {
        let c = w - 2.5;
        [
            3.432_739_39e-7,
            -3.523_387_7e-6,
            -4.391_506_54e-6,
            2.185_808_7e-4,
            -1.253_725_03e-3,
            -4.177_681_64e-3,
            0.246_640_727,
            1.501_409_41,
        ]
        .iter()
        .fold(2.810_226_36e-8, |p, k| k + p * c)
    } else {
        let t = w.sqrt() - 3.0;
        [
            1.009_505_58e-4,
            1.349_343_22e-3,
            -3.673_428_44e-3,
            5.739_507_73e-3,
            -7.622_461_3e-3,
            9.438_870_47e-3,
            1.001_674_06,
            2.832_976_82,
        ]
        .iter()
        .fold(-2.002_142_57e-4, |p, k| k + p * t)
    };
    std::f64::consts::SQRT_2 * erfinv * x
}

/// Area of each layer, tail included.
const V: f64 = 4.928_673_233_99e-3;

/// Tables of the 256-layer ziggurat for the half-normal density `f(x) = exp(−x²/2)`.
#[derive(Debug)]
pub struct Ziggurat {
    /// A magnitude index below `k[i]` lies under the density in layer `i` for sure: `(m + ½)·w[i] ≤ x[i−1]`.
    k: [u32; LAYERS],
    /// Deviate per unit of magnitude in layer `i` (its right edge / 2²³).
    w: [f32; LAYERS],
    /// Density at layer `i`'s right edge.
    f: [f64; LAYERS],
}

static ZIGGURAT: LazyLock<Ziggurat> = LazyLock::new(Ziggurat::build);

impl Ziggurat {
    /// The shared tables.
    pub fn get() -> &'static Self {
        &ZIGGURAT
    }

    /// Marsaglia & Tsang's table set-up: layer 0 is the base strip with the tail, layer 255 the widest
    /// rectangle (right edge r), layer 1 the top one.
    fn build() -> Self {
        let mut k = [0u32; LAYERS];
        let mut w = [0f32; LAYERS];
        let mut f = [0f64; LAYERS];
        let density = |x: f64| (-0.5 * x * x).exp();
        let q = V / density(R);
        // k = ⌊ratio·2²³ + ½⌋, so m < k implies m + ½ ≤ ratio·2²³
        let k_of = |ratio: f64| (ratio * MAGNITUDE_SCALE + 0.5) as u32;
        k[0] = k_of(R / q);
        w[0] = (q / MAGNITUDE_SCALE) as f32;
        w[LAYERS - 1] = (R / MAGNITUDE_SCALE) as f32;
        f[0] = 1.0;
        f[LAYERS - 1] = density(R);
        let (mut x, mut previous) = (R, R);
        for i in (1..LAYERS - 1).rev() {
            x = (-2.0 * (V / x + density(x)).ln()).sqrt();
            k[i + 1] = k_of(x / previous);
            previous = x;
            f[i] = density(x);
            w[i] = (x / MAGNITUDE_SCALE) as f32;
        }
        k[1] = 0;
        Self { k, w, f }
    }

    /// A standard normal deviate from the 32 random bits `bits`; `rng` supplies more bits in the rare case
    /// (1.5 % of draws: `few_draws_take_the_slow_path`) that the first draw is rejected.
    #[inline(always)]
    pub fn sample(&self, bits: u32, rng: &mut SplitMix64) -> f32 {
        let layer = (bits & 255) as usize;
        // Bits 8…31 as a signed 24-bit value m; the deviate is (m + ½)·w, symmetric about 0, with magnitude
        // index ⌊|m + ½|⌋ = m ^ (m >> 31). Nothing branches on the sign (a branch on a random bit mispredicts
        // half the time).
        let signed = (bits as i32) >> 8;
        let magnitude = (signed ^ (signed >> 31)) as u32;
        if magnitude < self.k[layer] {
            (signed as f32 + 0.5) * self.w[layer]
        } else {
            let x = self.reject(layer, magnitude, rng);
            if signed < 0 { -x } else { x }
        }
    }

    /// Fills `out` with standard normal deviates, two per 64-bit draw.
    #[inline(always)]
    pub fn fill(&self, rng: &mut SplitMix64, out: &mut [f32]) {
        let mut pairs = out.chunks_exact_mut(2);
        for pair in &mut pairs {
            let bits = rng.next_bits();
            pair[0] = self.sample(bits as u32, rng);
            pair[1] = self.sample((bits >> 32) as u32, rng);
        }
        if let [last] = pairs.into_remainder() {
            let bits = rng.next_bits();
            *last = self.sample(bits as u32, rng);
        }
    }

    /// The slow path: the wedge test, the tail, or a fresh draw; returns a half-normal magnitude.
    #[cold]
    fn reject(&self, mut layer: usize, mut magnitude: u32, rng: &mut SplitMix64) -> f32 {
        loop {
            let x = (f64::from(magnitude) + 0.5) * f64::from(self.w[layer]);
            if layer == 0 {
                // the tail beyond R (Marsaglia 1964)
                loop {
                    let t = -rng.uniform_open0().ln() / R;
                    let y = -rng.uniform_open0().ln();
                    if y + y >= t * t {
                        return (R + t) as f32;
                    }
                }
            }
            let u = rng.uniform_open0();
            if self.f[layer] + u * (self.f[layer - 1] - self.f[layer]) < (-0.5 * x * x).exp() {
                return x as f32;
            }
            let bits = rng.next_bits() as u32;
            layer = (bits & 255) as usize;
            magnitude = bits >> 9;
            if magnitude < self.k[layer] {
                return (magnitude as f32 + 0.5) * self.w[layer];
            }
        }
    }
}

/// Box–Muller with AVX-512 and AVX2, and the quantile polynomials with AVX-512.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{OCTAVES, QUANTILE_TERMS, SplitMix64, U24};

    /// The eight SplitMix64 states `state + (first + k)·GAMMA`, `k` = 0 … 7.
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    #[inline]
    fn states_512(state: u64, first: i64) -> __m512i {
        let lanes =
            _mm512_setr_epi64(first, first + 1, first + 2, first + 3, first + 4, first + 5, first + 6, first + 7);
        let gamma = _mm512_set1_epi64(SplitMix64::GAMMA as i64);
        _mm512_add_epi64(_mm512_set1_epi64(state as i64), _mm512_mullo_epi64(lanes, gamma))
    }

    /// [`mix64`](super::mix64) in each of eight 64-bit lanes.
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    #[inline]
    fn mix64_512(z: __m512i) -> __m512i {
        let (m1, m2) =
            (_mm512_set1_epi64(0xBF58_476D_1CE4_E5B9u64 as i64), _mm512_set1_epi64(0x94D0_49BB_1331_11EBu64 as i64));
        let z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)), m1);
        let z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)), m2);
        _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z))
    }

    /// One run of 64 deviates of [`Quantiles::fill`](super::Quantiles::fill) into `out` (64 long): the 16 draws
    /// `mix64(start + (i + 1)·GAMMA)` in two vectors, their 64 16-bit fields in memory order as four vectors of
    /// sixteen, and [`Quantiles::value`](super::Quantiles::value)'s f32 operations in its order (the octave's
    /// coefficients permuted out of one register each, no fused multiply–add), so every deviate has the
    /// scalar's bits.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL).
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn quantile_run_512(coefficients: &[[f32; OCTAVES]; QUANTILE_TERMS], start: u64, out: &mut [f32]) {
        assert_eq!(out.len(), 64, "a run of 64");
        for (q, z) in quantile_vectors_512(coefficients, start).into_iter().enumerate() {
            // SAFETY: sixteen floats at 16·q, inside `out` (64 long)
            unsafe { _mm512_storeu_ps(out.as_mut_ptr().add(16 * q), z) };
        }
    }

    /// The 64 deviates of [`quantile_run_512`] as four vectors of sixteen, in order.
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    #[inline]
    pub fn quantile_vectors_512(coefficients: &[[f32; OCTAVES]; QUANTILE_TERMS], start: u64) -> [__m512; 4] {
        let (low, high) = (mix64_512(states_512(start, 1)), mix64_512(states_512(start, 9)));
        // SAFETY: each row is sixteen floats
        let c: [__m512; QUANTILE_TERMS] = std::array::from_fn(|k| unsafe { _mm512_loadu_ps(coefficients[k].as_ptr()) });
        let epi = _mm512_set1_epi32;
        let sign = _mm512_set1_ps(-0.0);
        let quarters = [
            _mm512_castsi512_si256(low),
            _mm512_extracti64x4_epi64::<1>(low),
            _mm512_castsi512_si256(high),
            _mm512_extracti64x4_epi64::<1>(high),
        ];
        // a loop, not `quarters.map`: the closure was compiled as a function of its own, called four times a run
        let mut deviates = [_mm512_setzero_ps(); 4];
        for (q, fields) in quarters.into_iter().enumerate() {
            let i = _mm512_cvtepu16_epi32(fields);
            let upper = _mm512_cmpge_epi32_mask(i, epi(0x8000));
            let d = _mm512_mask_xor_epi32(i, upper, i, epi(0xffff));
            let bits = _mm512_castps_si512(_mm512_cvtepi32_ps(_mm512_add_epi32(d, epi(1))));
            let e = _mm512_sub_epi32(_mm512_srli_epi32::<23>(bits), epi(127));
            let m = _mm512_castsi512_ps(_mm512_or_si512(_mm512_and_si512(bits, epi(0x7f_ffff)), epi(0x3f80_0000)));
            let x = _mm512_sub_ps(m, _mm512_set1_ps(1.5));
            let mut z = _mm512_permutexvar_ps(e, c[QUANTILE_TERMS - 1]);
            for k in (0..QUANTILE_TERMS - 1).rev() {
                z = _mm512_add_ps(_mm512_mul_ps(z, x), _mm512_permutexvar_ps(e, c[k]));
            }
            deviates[q] = _mm512_mask_xor_ps(z, upper, z, sign);
        }
        deviates
    }

    /// [`box_muller_fill`](super::box_muller_fill) for the whole blocks of sixteen pairs in `out`; returns how
    /// many pairs it wrote. Every lane does [`mix64`](super::mix64), then
    /// [`box_muller`](super::box_muller)'s f32 operations ([`ln_f32`](super::ln_f32),
    /// [`sin_cos_turns`](super::sin_cos_turns)) in their order, each correctly rounded as the scalar's are
    /// (no fused multiply–add), so every deviate has the scalar's bits.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, DQ, BW, VL).
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
    pub unsafe fn box_muller_512(state: u64, out: &mut [f32]) -> usize {
        let blocks = out.len() / 32;
        // the states of pairs 0–7 and 8–15 of the block: state + (p + 1)·GAMMA
        let (mut lo, mut hi) = (states_512(state, 1), states_512(state, 9));
        let step = _mm512_set1_epi64(SplitMix64::GAMMA.wrapping_mul(16) as i64);
        // sixteen 64-bit lanes' low 32 bits as sixteen i32 lanes, in order
        let join = |a: __m512i, b: __m512i| {
            _mm512_inserti64x4::<1>(_mm512_castsi256_si512(_mm512_cvtepi64_epi32(a)), _mm512_cvtepi64_epi32(b))
        };
        let ps = _mm512_set1_ps;
        let epi = _mm512_set1_epi32;
        let (u24, one, half) = (ps(U24), ps(1.0), ps(0.5));
        let sign = ps(-0.0);
        // deviates (a₀, b₀, a₁, b₁, …): pairs 0–7 from the first index vector, 8–15 from the second
        let first = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let second = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
        for b in 0..blocks {
            let (zl, zh) = (mix64_512(lo), mix64_512(hi));
            lo = _mm512_add_epi64(lo, step);
            hi = _mm512_add_epi64(hi, step);
            // u₁ from bits 40–63 (+ 1), u₂ from bits 0–23
            let top = join(_mm512_srli_epi64::<40>(zl), _mm512_srli_epi64::<40>(zh));
            let mask = _mm512_set1_epi64(0xff_ffff);
            let bottom = join(_mm512_and_si512(zl, mask), _mm512_and_si512(zh, mask));
            let u1 = _mm512_mul_ps(_mm512_cvtepi32_ps(_mm512_add_epi32(top, epi(1))), u24);
            let u2 = _mm512_mul_ps(_mm512_cvtepi32_ps(bottom), u24);
            // ln_f32(u₁)
            let bits = _mm512_castps_si512(u1);
            let e = _mm512_sub_epi32(_mm512_and_si512(_mm512_srli_epi32::<23>(bits), epi(0xff)), epi(127));
            let m = _mm512_castsi512_ps(_mm512_or_si512(_mm512_and_si512(bits, epi(0x7f_ffff)), epi(0x3f80_0000)));
            let high = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(m, ps(std::f32::consts::SQRT_2));
            let m = _mm512_mask_mul_ps(m, high, m, half);
            let e = _mm512_mask_add_epi32(e, high, e, epi(1));
            let s = _mm512_div_ps(_mm512_sub_ps(m, one), _mm512_add_ps(m, one));
            let s2 = _mm512_mul_ps(s, s);
            let mut t = _mm512_mul_ps(s2, ps(1.0 / 9.0));
            t = _mm512_mul_ps(s2, _mm512_add_ps(ps(1.0 / 7.0), t));
            t = _mm512_mul_ps(s2, _mm512_add_ps(ps(1.0 / 5.0), t));
            t = _mm512_mul_ps(s2, _mm512_add_ps(ps(1.0 / 3.0), t));
            let series = _mm512_add_ps(one, t);
            let ln = _mm512_add_ps(
                _mm512_mul_ps(_mm512_cvtepi32_ps(e), ps(std::f32::consts::LN_2)),
                _mm512_mul_ps(_mm512_mul_ps(ps(2.0), s), series),
            );
            let r = _mm512_sqrt_ps(_mm512_mul_ps(ps(-2.0), ln));
            // sin_cos_turns(u₂)
            let q = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(u2, ps(4.0)), half));
            let x = _mm512_mul_ps(
                _mm512_sub_ps(u2, _mm512_mul_ps(_mm512_cvtepi32_ps(q), ps(0.25))),
                ps(std::f32::consts::TAU),
            );
            let x2 = _mm512_mul_ps(x, x);
            let mut p = _mm512_mul_ps(x2, ps(1.0 / 5040.0));
            p = _mm512_mul_ps(x2, _mm512_sub_ps(ps(1.0 / 120.0), p));
            p = _mm512_mul_ps(x2, _mm512_sub_ps(ps(1.0 / 6.0), p));
            let sin = _mm512_mul_ps(x, _mm512_sub_ps(one, p));
            let mut p = _mm512_mul_ps(x2, ps(1.0 / 40320.0));
            p = _mm512_mul_ps(x2, _mm512_sub_ps(ps(1.0 / 720.0), p));
            p = _mm512_mul_ps(x2, _mm512_sub_ps(ps(1.0 / 24.0), p));
            p = _mm512_mul_ps(x2, _mm512_sub_ps(half, p));
            let cos = _mm512_sub_ps(one, p);
            // the quarter turns: (s, c) → (c, −s) for odd q, → (−s, −c) for q & 2
            let odd = _mm512_test_epi32_mask(q, epi(1));
            let (sin, cos) =
                (_mm512_mask_blend_ps(odd, sin, cos), _mm512_mask_blend_ps(odd, cos, _mm512_xor_ps(sin, sign)));
            let turn = _mm512_test_epi32_mask(q, epi(2));
            let (sin, cos) = (_mm512_mask_xor_ps(sin, turn, sin, sign), _mm512_mask_xor_ps(cos, turn, cos, sign));
            let (a, b_) = (_mm512_mul_ps(r, cos), _mm512_mul_ps(r, sin));
            let o = out[32 * b..32 * b + 32].as_mut_ptr();
            // SAFETY: 32 floats at `o`, inside `out`
            unsafe {
                _mm512_storeu_ps(o, _mm512_permutex2var_ps(a, first, b_));
                _mm512_storeu_ps(o.add(16), _mm512_permutex2var_ps(a, second, b_));
            }
        }
        16 * blocks
    }

    /// `a·b` modulo 2⁶⁴ in each of four 64-bit lanes, `b` given as its low and high 32 bits in every lane (AVX2 has
    /// no 64-bit multiply): `aₗbₗ + ((aₕbₗ + aₗbₕ) << 32)`.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn mullo64_256(a: __m256i, b_low: __m256i, b_high: __m256i) -> __m256i {
        let low = _mm256_mul_epu32(a, b_low);
        let cross = _mm256_add_epi64(_mm256_mul_epu32(_mm256_srli_epi64::<32>(a), b_low), _mm256_mul_epu32(a, b_high));
        _mm256_add_epi64(low, _mm256_slli_epi64::<32>(cross))
    }

    /// [`mix64`](super::mix64) in each of four 64-bit lanes, with AVX2.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn mix64_256(z: __m256i) -> __m256i {
        let halves = |m: u64| (_mm256_set1_epi64x((m & 0xffff_ffff) as i64), _mm256_set1_epi64x((m >> 32) as i64));
        let ((l1, h1), (l2, h2)) = (halves(0xBF58_476D_1CE4_E5B9), halves(0x94D0_49BB_1331_11EB));
        let z = mullo64_256(_mm256_xor_si256(z, _mm256_srli_epi64::<30>(z)), l1, h1);
        let z = mullo64_256(_mm256_xor_si256(z, _mm256_srli_epi64::<27>(z)), l2, h2);
        _mm256_xor_si256(z, _mm256_srli_epi64::<31>(z))
    }

    /// [`box_muller_512`] with AVX2: the whole blocks of eight pairs in `out`; returns how many pairs it wrote.
    /// The same f32 operations in the same order (no fused multiply–add), so every deviate has the scalar's bits.
    /// The draws (two 64-bit multiplies each, of three 32-bit ones each) take most of its time: on an AMD EPYC
    /// with AVX2, 1.1–1.4 of the 1.7 ns a deviate.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn box_muller_256(state: u64, out: &mut [f32]) -> usize {
        let blocks = out.len() / 16;
        // the states of pairs 0–3 and 4–7 of the block: state + (p + 1)·GAMMA
        let at = |p: u64| state.wrapping_add(p.wrapping_mul(SplitMix64::GAMMA)) as i64;
        let (mut lo, mut hi) =
            (_mm256_setr_epi64x(at(1), at(2), at(3), at(4)), _mm256_setr_epi64x(at(5), at(6), at(7), at(8)));
        let step = _mm256_set1_epi64x(SplitMix64::GAMMA.wrapping_mul(8) as i64);
        let join = crate::physics::simd::low_halves_256;
        let ps = _mm256_set1_ps;
        let epi = _mm256_set1_epi32;
        let (u24, one, half) = (ps(U24), ps(1.0), ps(0.5));
        let sign = ps(-0.0);
        for b in 0..blocks {
            let (zl, zh) = (mix64_256(lo), mix64_256(hi));
            lo = _mm256_add_epi64(lo, step);
            hi = _mm256_add_epi64(hi, step);
            // u₁ from bits 40–63 (+ 1), u₂ from bits 0–23
            let top = join(_mm256_srli_epi64::<40>(zl), _mm256_srli_epi64::<40>(zh));
            let bottom = _mm256_and_si256(join(zl, zh), epi(0xff_ffff));
            let u1 = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_add_epi32(top, epi(1))), u24);
            let u2 = _mm256_mul_ps(_mm256_cvtepi32_ps(bottom), u24);
            // ln_f32(u₁)
            let bits = _mm256_castps_si256(u1);
            let e = _mm256_sub_epi32(_mm256_and_si256(_mm256_srli_epi32::<23>(bits), epi(0xff)), epi(127));
            let m = _mm256_castsi256_ps(_mm256_or_si256(_mm256_and_si256(bits, epi(0x7f_ffff)), epi(0x3f80_0000)));
            let high = _mm256_cmp_ps::<_CMP_GT_OQ>(m, ps(std::f32::consts::SQRT_2));
            let m = _mm256_blendv_ps(m, _mm256_mul_ps(m, half), high);
            // e + 1 where high: the mask's lanes are −1
            let e = _mm256_sub_epi32(e, _mm256_castps_si256(high));
            let s = _mm256_div_ps(_mm256_sub_ps(m, one), _mm256_add_ps(m, one));
            let s2 = _mm256_mul_ps(s, s);
            let mut t = _mm256_mul_ps(s2, ps(1.0 / 9.0));
            t = _mm256_mul_ps(s2, _mm256_add_ps(ps(1.0 / 7.0), t));
            t = _mm256_mul_ps(s2, _mm256_add_ps(ps(1.0 / 5.0), t));
            t = _mm256_mul_ps(s2, _mm256_add_ps(ps(1.0 / 3.0), t));
            let series = _mm256_add_ps(one, t);
            let ln = _mm256_add_ps(
                _mm256_mul_ps(_mm256_cvtepi32_ps(e), ps(std::f32::consts::LN_2)),
                _mm256_mul_ps(_mm256_mul_ps(ps(2.0), s), series),
            );
            let r = _mm256_sqrt_ps(_mm256_mul_ps(ps(-2.0), ln));
            // sin_cos_turns(u₂)
            let q = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(u2, ps(4.0)), half));
            let x = _mm256_mul_ps(
                _mm256_sub_ps(u2, _mm256_mul_ps(_mm256_cvtepi32_ps(q), ps(0.25))),
                ps(std::f32::consts::TAU),
            );
            let x2 = _mm256_mul_ps(x, x);
            let mut p = _mm256_mul_ps(x2, ps(1.0 / 5040.0));
            p = _mm256_mul_ps(x2, _mm256_sub_ps(ps(1.0 / 120.0), p));
            p = _mm256_mul_ps(x2, _mm256_sub_ps(ps(1.0 / 6.0), p));
            let sin = _mm256_mul_ps(x, _mm256_sub_ps(one, p));
            let mut p = _mm256_mul_ps(x2, ps(1.0 / 40320.0));
            p = _mm256_mul_ps(x2, _mm256_sub_ps(ps(1.0 / 720.0), p));
            p = _mm256_mul_ps(x2, _mm256_sub_ps(ps(1.0 / 24.0), p));
            p = _mm256_mul_ps(x2, _mm256_sub_ps(half, p));
            let cos = _mm256_sub_ps(one, p);
            // the quarter turns: (s, c) → (c, −s) for odd q, → (−s, −c) for q & 2
            let lanes = |bit: i32| _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(q, epi(bit)), epi(bit)));
            let odd = lanes(1);
            let (sin, cos) = (_mm256_blendv_ps(sin, cos, odd), _mm256_blendv_ps(cos, _mm256_xor_ps(sin, sign), odd));
            let turn = _mm256_and_ps(lanes(2), sign);
            let (a, b_) = (_mm256_mul_ps(r, _mm256_xor_ps(cos, turn)), _mm256_mul_ps(r, _mm256_xor_ps(sin, turn)));
            // (a₀ b₀ a₁ b₁ | a₄ b₄ a₅ b₅) and (a₂ b₂ a₃ b₃ | a₆ b₆ a₇ b₇), then their halves in order
            let (first, second) = (_mm256_unpacklo_ps(a, b_), _mm256_unpackhi_ps(a, b_));
            let o = out[16 * b..16 * b + 16].as_mut_ptr();
            // SAFETY: 16 floats at `o`, inside `out`
            unsafe {
                _mm256_storeu_ps(o, _mm256_permute2f128_ps::<0x20>(first, second));
                _mm256_storeu_ps(o.add(8), _mm256_permute2f128_ps::<0x31>(first, second));
            }
        }
        8 * blocks
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::noise::{ks_distance_normal, normal_cdf};

    #[test]
    fn splitmix_matches_the_published_sequence() {
        // first outputs of SplitMix64 seeded with 1234567 (the reference implementation by Vigna)
        let mut rng = SplitMix64::new(1_234_567);
        let want = [6_457_827_717_110_365_317u64, 3_203_168_211_198_807_973, 9_817_491_932_198_370_423];
        for w in want {
            assert_eq!(rng.next_bits(), w);
        }
    }

    #[test]
    fn few_draws_take_the_slow_path() {
        // the share of (layer, magnitude) draws at or above the layer's sure-accept bound
        let z = Ziggurat::get();
        let slow = z.k.iter().map(|&k| 1.0 - f64::from(k) / MAGNITUDE_SCALE).sum::<f64>() / LAYERS as f64;
        eprintln!("slow path: {:.3} %", 100.0 * slow);
        // measured 1.49 % (the 128-layer table: 2.76 %)
        assert!(slow < 0.016, "{slow}");
    }

    #[test]
    fn layers_have_equal_area() {
        let z = Ziggurat::get();
        // layer i (1 ≤ i < 256) spans density f[i] … f[i-1] over [0, x_i]: area x_i·(f[i-1] − f[i]) = V
        for i in 1..LAYERS {
            let x = f64::from(z.w[i]) * MAGNITUDE_SCALE;
            let area = x * (z.f[i - 1] - z.f[i]);
            assert!((area - V).abs() < 1e-6 * V, "layer {i}: {area}");
        }
    }

    /// `Φ⁻¹(u)` by bisection on the f64 CDF.
    fn exact_inverse(u: f64) -> f64 {
        if u > 0.5 {
            return -exact_inverse(1.0 - u);
        }
        let (mut lo, mut hi) = (-9.0, 0.0);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if normal_cdf(mid) < u { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn quantiles_match_the_exact_inverse() {
        let q = Quantiles::get();
        let n = 65_536.0;
        // each deviate against the exact quantile it stands for: every third, and the ends of each octave
        let octave_ends = (0..16u32).flat_map(|e| [(1 << e) - 1, ((2 << e) - 2).min(0x7fff)]).map(|d: u32| d as u16);
        let mut worst = (0.0, 0);
        for i in (0..=u16::MAX).step_by(3).chain(octave_ends.flat_map(|d| [d, !d])) {
            let error = (f64::from(q.value(i)) - exact_inverse((f64::from(i) + 0.5) / n)).abs();
            if error > worst.0 {
                worst = (error, i);
            }
        }
        eprintln!("largest error {:.2e} σ at {}", worst.0, worst.1);
        assert!(worst.0 < QUANTILE_MAX_ERROR, "largest error {} σ at {}", worst.0, worst.1);
        // symmetric, cut at 4.32 σ, and increasing: all 2¹⁶ values different, in order
        assert!((0..=u16::MAX).all(|i| q.value(i) == -q.value(!i)));
        assert!((f64::from(q.value(0)) + 4.3249).abs() < 1e-4, "{}", q.value(0));
        assert!((0..u16::MAX).all(|i| q.value(i) < q.value(i + 1)));
    }

    #[test]
    fn quantile_deviates_take_their_bits_in_order() {
        let mut a = SplitMix64::substream(5, 1);
        let mut b = a.clone();
        let mut out = vec![0f32; 131];
        Quantiles::get().fill(&mut a, &mut out);
        for quad in out.chunks(4) {
            let bits = b.next_bits();
            for (k, &z) in quad.iter().enumerate() {
                assert_eq!(z.to_bits(), Quantiles::get().value((bits >> (16 * k)) as u16).to_bits());
            }
        }
        assert_eq!(a.next_bits(), b.next_bits());
    }

    #[test]
    fn every_16_bit_field_gives_the_scalar_deviate_in_a_run() {
        // runs of 64 whose first draw holds four chosen fields (the state before it inverted from them), so that
        // the runs' first deviates go through all 2¹⁶ fields in every lane position; each of the 64 against
        // `Quantiles::value` of its field, whichever path `fill` takes
        let q = Quantiles::get();
        let mut out = [0f32; 64];
        for r in 0..1u64 << 14 {
            let bits = (0..4).fold(0u64, |b, k| b | ((4 * r + k) << (16 * k)));
            let start = unmix64(bits).wrapping_sub(SplitMix64::GAMMA);
            q.fill(&mut SplitMix64::new(start), &mut out);
            for (k, &z) in out.iter().enumerate() {
                let draw = mix64(start.wrapping_add((k as u64 / 4 + 1).wrapping_mul(SplitMix64::GAMMA)));
                let field = (draw >> (16 * (k % 4))) as u16;
                assert_eq!(z.to_bits(), q.value(field).to_bits(), "run {r}, deviate {k}");
            }
            assert_eq!(mix64(start.wrapping_add(SplitMix64::GAMMA)), bits);
        }
    }

    #[test]
    fn box_muller_s_functions_are_accurate() {
        for i in 1..20_000 {
            let x = i as f32 * 0.000_073_1;
            assert!(
                (f64::from(ln_f32(x)) - f64::from(x).ln()).abs() <= 2e-7 * f64::from(x).ln().abs().max(1.0),
                "ln {x}"
            );
            let t = (i as f32 - 0.5) / 20_000.0;
            let (s, c) = sin_cos_turns(t);
            let a = f64::from(t) * std::f64::consts::TAU;
            assert!((f64::from(s) - a.sin()).abs() < 4e-7 && (f64::from(c) - a.cos()).abs() < 4e-7, "{t}");
        }
        assert_eq!(ln_f32(1.0), 0.0);
        // the deviates against the exact transform, at the ends of u₁ and around the circle
        for bits in [0u64, u64::MAX, 1 << 40, 0xff_ffff, 0x8000_0000_0080_0000, 0x1234_5678_9abc_def0] {
            let (a, b) = box_muller(bits);
            let u1 = (((bits >> 40) + 1) as f64) / 16_777_216.0;
            let u2 = ((bits & 0xff_ffff) as f64) / 16_777_216.0;
            let r = (-2.0 * u1.ln()).sqrt();
            let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
            assert!((f64::from(a) - r * c).abs() < 2e-6 && (f64::from(b) - r * s).abs() < 2e-6, "{bits:x}");
        }
        // the fill is the pairs of draws in order, an odd length's last deviate from a draw of its own
        let mut out = [0f32; 7];
        let mut rng = SplitMix64::substream(4, 4);
        let mut check = rng.clone();
        NormalSampler::BoxMuller.fill(&mut rng, &mut out);
        for p in 0..3 {
            let (a, b) = box_muller(check.next_bits());
            assert_eq!((out[2 * p].to_bits(), out[2 * p + 1].to_bits()), (a.to_bits(), b.to_bits()));
        }
        assert_eq!(out[6].to_bits(), box_muller(check.next_bits()).0.to_bits());
        assert_eq!(rng.next_bits(), check.next_bits());
    }

    #[test]
    fn the_box_muller_fill_is_the_scalar_transform_bit_for_bit() {
        // every length around the vector blocks, and many states (the vector path where the CPU has it)
        let mut states = SplitMix64::new(11);
        for len in (0..70).chain([255, 640, 1001]) {
            for _ in 0..20 {
                let state = states.next_bits();
                let mut out = vec![f32::NAN; len];
                box_muller_fill(state, &mut out);
                let mut rng = SplitMix64::new(state);
                for (p, pair) in out.chunks(2).enumerate() {
                    let (a, b) = box_muller(rng.next_bits());
                    assert_eq!(pair[0].to_bits(), a.to_bits(), "len {len} pair {p}");
                    if let [_, second] = pair {
                        assert_eq!(second.to_bits(), b.to_bits(), "len {len} pair {p}");
                    }
                }
                // the AVX2 kernel on a CPU whose widest is AVX-512 too: its whole blocks, the rest left as they were
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    let mut narrow = vec![f32::NAN; len];
                    // SAFETY: the CPU has AVX2
                    let pairs = unsafe { x86::box_muller_256(state, &mut narrow) };
                    assert_eq!(pairs, len / 16 * 8);
                    let same = |x: &[f32], y: &[f32]| x.iter().zip(y).all(|(x, y)| x.to_bits() == y.to_bits());
                    assert!(same(&narrow[..2 * pairs], &out[..2 * pairs]), "len {len}");
                    assert!(narrow[2 * pairs..].iter().all(|v| v.is_nan()));
                }
            }
        }
        // u₁ and u₂ at their ends and at the quarter turns, where the branches of ln and sin/cos meet
        let edges = [0u64, 0xff_ffff, 0x40_0000, 0x80_0000, 0xc0_0000, 0x20_0000, 0x60_0000, 0x3f_ffff];
        for (k, &low) in edges.iter().enumerate() {
            for top in [0u64, 0xff_ffff, 0xb5_04f3, 0xb5_04f2, 0x7f_ffff, 0x80_0000, 1, 2] {
                let bits = (top << 40) | ((k as u64) << 24) | low;
                // the draw that mix64 maps to `bits`, as the first pair of a fill
                assert_eq!(mix64(unmix64(bits)), bits);
                let state = unmix64(bits).wrapping_sub(SplitMix64::GAMMA);
                let mut out = [0f32; 32];
                box_muller_fill(state, &mut out);
                let (a, b) = box_muller(bits);
                assert_eq!((out[0].to_bits(), out[1].to_bits()), (a.to_bits(), b.to_bits()), "{bits:x}");
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    out.fill(f32::NAN);
                    // SAFETY: the CPU has AVX2
                    let pairs = unsafe { x86::box_muller_256(state, &mut out) };
                    assert_eq!(pairs, 16);
                    assert_eq!((out[0].to_bits(), out[1].to_bits()), (a.to_bits(), b.to_bits()), "{bits:x} AVX2");
                }
            }
        }
    }

    /// The inverse of [`mix64`].
    fn unmix64(mut z: u64) -> u64 {
        let unshift = |z: u64, s: u32| {
            let mut x = z;
            for _ in 0..=64 / s {
                x = z ^ (x >> s);
            }
            x
        };
        // the multipliers' inverses modulo 2⁶⁴, by Newton's iteration
        let inverse = |m: u64| {
            let mut x = m;
            for _ in 0..6 {
                x = x.wrapping_mul(2u64.wrapping_sub(m.wrapping_mul(x)));
            }
            x
        };
        z = unshift(z, 31);
        z = unshift(z.wrapping_mul(inverse(0x94D0_49BB_1331_11EB)), 27);
        unshift(z.wrapping_mul(inverse(0xBF58_476D_1CE4_E5B9)), 30)
    }

    #[test]
    fn normal_deviates_follow_the_normal_law() {
        for sampler in [NormalSampler::Ziggurat, NormalSampler::Table, NormalSampler::BoxMuller] {
            let mut rng = SplitMix64::substream(99, 0);
            let mut samples = vec![0f32; 1 << 21];
            sampler.fill(&mut rng, &mut samples);
            let n = samples.len() as f64;
            let mean = samples.iter().map(|&s| f64::from(s)).sum::<f64>() / n;
            let var = samples.iter().map(|&s| (f64::from(s) - mean).powi(2)).sum::<f64>() / n;
            assert!(mean.abs() < 5.0 / n.sqrt(), "{sampler:?}: mean {mean}");
            assert!((var - 1.0).abs() < 5.0 * (2.0 / n).sqrt(), "{sampler:?}: variance {var}");
            // Kolmogorov–Smirnov distance; 1.63/√n is the 1 % critical value
            samples.sort_by(f32::total_cmp);
            let ks = ks_distance_normal(&samples);
            assert!(ks < 1.63 / n.sqrt(), "{sampler:?}: KS distance {ks}");
            // tails, including the ziggurat's exact sampling beyond R = 3.44: counts within 5 standard errors
            for t in [2.0, 3.0, 3.5, 4.0] {
                let p = 2.0 * normal_cdf(-t);
                let count = samples.iter().filter(|s| f64::from(s.abs()) > t).count() as f64;
                assert!(
                    (count - n * p).abs() < 5.0 * (n * p).sqrt() + 1.0,
                    "{sampler:?}: |z| > {t}: {count} vs {}",
                    n * p
                );
            }
        }
    }
}
