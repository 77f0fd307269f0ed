//! Per-pixel loops compiled for the widest vectors the CPU has.
//!
//! The crate is built for baseline x86-64 (SSE2, four f32 lanes) so that one binary runs on any x86-64 (and on
//! aarch64, where NEON is baseline). [`widest`] runs a closure inside a function compiled with AVX-512 (sixteen
//! f32 lanes, 64-bit multiplies and masked gathers) where the CPU has it, else with AVX2 (eight lanes), else as
//! the baseline, so the loops inlined into it vectorize as wide as the machine allows. Only code inlined into
//! that function is compiled with the wider set: the per-pixel functions a closure calls are
//! `#[inline(always)]`, or they run the baseline code (LLVM does not inline large functions on its own).
//! Fused multiply–add is not enabled: Rust never contracts `a·b + c`, so every lane does the same operations in
//! the same order as on the baseline path and the results are bit-identical whichever path runs.

/// The vector instruction set [`widest`] runs with on this CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// The target's baseline (SSE2 on x86-64, NEON on aarch64).
    Baseline,
    /// AVX2.
    Avx2,
    /// AVX-512 (F, DQ, BW, VL).
    Avx512,
}

impl Level {
    /// What this CPU offers, or what `IRSIM_SIMD` (`baseline`, `avx2`, `avx512`) caps it at.
    pub fn detect() -> Self {
        static LEVEL: std::sync::OnceLock<Level> = std::sync::OnceLock::new();
        *LEVEL.get_or_init(|| {
            let best = Self::supported();
            match std::env::var("IRSIM_SIMD").as_deref() {
                Ok("baseline") => Self::Baseline,
                Ok("avx2") if best != Self::Baseline => Self::Avx2,
                _ => best,
            }
        })
    }

    /// The widest level the CPU supports.
    fn supported() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512dq")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512vl")
            {
                return Self::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Self::Avx2;
            }
        }
        Self::Baseline
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Baseline => {
                if cfg!(target_arch = "aarch64") {
                    "neon"
                } else {
                    "sse2"
                }
            }
            Self::Avx2 => "avx2",
            Self::Avx512 => "avx512",
        }
    }
}

/// Plain pixels (a bilinear sample, or a noise deviate) a row-parallel pass hands each task at least. A frame's
/// workers stay awake through it, so a task of a few µs is still worth giving away: at 4096 a 160 × 120 frame's
/// readout runs as several tasks instead of one (its draft frames 21.7 k → 29.1 k frames/s on 2 threads), and
/// 256 × 256 and 640 × 512 frames are as fast as with 16 384.
pub const TASK_PIXELS: usize = 4096;

/// Rows of `width` pixels per task of a row-parallel pass whose pixels each cost `cost` plain pixels: about
/// [`TASK_PIXELS`] worth, at least one row.
pub fn rows_per_task(width: usize, cost: usize) -> usize {
    (TASK_PIXELS / width.saturating_mul(cost).max(1)).max(1)
}

/// The most items a task of a parallel pass takes when the pass's work may gather in a few of its items (the
/// tiles along a sky image's edge): `most` when the pool has other threads to hand tasks to, all of them in a
/// pool of one (which would only pay for the splitting).
pub fn split_finely(most: usize) -> usize {
    if rayon::current_num_threads() > 1 { most.max(1) } else { usize::MAX }
}

/// Runs `f`, compiled with AVX-512 or AVX2 where the CPU supports it (results identical to the baseline path).
#[inline]
pub fn widest<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        match Level::detect() {
            // SAFETY: the CPU supports the features, checked by `Level::supported`.
            Level::Avx512 => return unsafe { with_avx512(f) },
            // SAFETY: as above.
            Level::Avx2 => return unsafe { with_avx2(f) },
            Level::Baseline => {}
        }
    }
    f()
}

/// `f` inlined into a function compiled with AVX2. Never inlined itself: inlined into its (baseline) caller,
/// its body would lose the AVX2 code generation.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline(never)]
unsafe fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `f` inlined into a function compiled with AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512dq,avx512bw,avx512vl")]
#[inline(never)]
unsafe fn with_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `eˣ` within 1 ulp of libm's over the whole range (tested), from plain
/// multiplies and adds: written in a loop inside [`widest`] it vectorizes (libm's `exp` is a call per value),
/// and every path, scalar or vector, gives the same bits. `x = k·ln 2 + r` with `|r| ≤ ½ ln 2` (ln 2 in two
/// parts, the first exact times any `k` here), `eʳ` by its Taylor series to `r¹³` (the rest below 10⁻¹⁷ of it),
/// then times `2ᵏ` in two halves so that results down to 0 and up to ∞ come out right. NaN gives NaN.
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    // adding 1.5·2⁵² rounds to a whole number held in the mantissa's low bits
    const SHIFT: f64 = 6_755_399_441_055_744.0;
    const INV_FACT: [f64; 14] = [
        1.0,
        1.0,
        1.0 / 2.0,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5_040.0,
        1.0 / 40_320.0,
        1.0 / 362_880.0,
        1.0 / 3_628_800.0,
        1.0 / 39_916_800.0,
        1.0 / 479_001_600.0,
        1.0 / 6_227_020_800.0,
    ];
    // past these e^x is 0 or ∞ in f64 (a NaN stays NaN)
    let x = x.clamp(-746.0, 710.0);
    let t = x * std::f64::consts::LOG2_E + SHIFT;
    let kf = t - SHIFT;
    let k = (t.to_bits() as i64).wrapping_sub(SHIFT.to_bits() as i64);
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    let mut p = INV_FACT[13];
    for c in INV_FACT[..13].iter().rev() {
        p = p * r + c;
    }
    // 2^k as 2^(k/2) · 2^(k − k/2): each half a normal number for every k of the clamped range
    let k1 = k >> 1;
    let k2 = k - k1;
    let scale = |e: i64| f64::from_bits(((e + 1023) as u64) << 52);
    p * scale(k1) * scale(k2)
}

/// Sixteen bilinear samples of a row-major f32 image whose rows are `width` floats apart, with AVX-512 gathers: the texel at each lane's
/// `index` and its right, lower and lower-right neighbours, mixed by the lane's fractions the way the scalar
/// samplers do (each row `left + (right − left)·fx`, then `top + (bottom − top)·fy`, multiplies and adds
/// separate), so the values are the scalar's. Only the lanes in `mask` read the image (the others are 0).
///
/// # Safety
/// The CPU must have AVX-512F; for every lane in `mask`, `index`, `index + 1`, `index + width` and
/// `index + width + 1` must lie inside the image that `base` points at.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub unsafe fn bilinear16_avx512(
    base: *const f32,
    index: std::arch::x86_64::__m512i,
    width: usize,
    fx: std::arch::x86_64::__m512,
    fy: std::arch::x86_64::__m512,
    mask: std::arch::x86_64::__mmask16,
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    let zero = _mm512_setzero_ps();
    // SAFETY: the caller guarantees every masked lane's four texels are inside the image
    let (tl, tr, bl, br) = unsafe {
        (
            _mm512_mask_i32gather_ps::<4>(zero, mask, index, base),
            _mm512_mask_i32gather_ps::<4>(zero, mask, index, base.add(1)),
            _mm512_mask_i32gather_ps::<4>(zero, mask, index, base.add(width)),
            _mm512_mask_i32gather_ps::<4>(zero, mask, index, base.add(width + 1)),
        )
    };
    bilinear_mix16(tl, tr, bl, br, fx, fy)
}

/// [`bilinear16_avx512`]'s mix of sixteen lanes' four texels: each row `left + (right − left)·fx`, then
/// `top + (bottom − top)·fy`, multiplies and adds separate, as the scalar samplers do.
///
/// # Safety
/// Callable only on a CPU with AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
pub fn bilinear_mix16(
    tl: std::arch::x86_64::__m512,
    tr: std::arch::x86_64::__m512,
    bl: std::arch::x86_64::__m512,
    br: std::arch::x86_64::__m512,
    fx: std::arch::x86_64::__m512,
    fy: std::arch::x86_64::__m512,
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    let top = _mm512_add_ps(tl, _mm512_mul_ps(_mm512_sub_ps(tr, tl), fx));
    let bottom = _mm512_add_ps(bl, _mm512_mul_ps(_mm512_sub_ps(br, bl), fx));
    _mm512_add_ps(top, _mm512_mul_ps(_mm512_sub_ps(bottom, top), fy))
}

/// [`bilinear_mix16`] for eight lanes with AVX2: the same operations in the same order, so the same values.
///
/// # Safety
/// Callable only on a CPU with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn bilinear_mix8(
    tl: std::arch::x86_64::__m256,
    tr: std::arch::x86_64::__m256,
    bl: std::arch::x86_64::__m256,
    br: std::arch::x86_64::__m256,
    fx: std::arch::x86_64::__m256,
    fy: std::arch::x86_64::__m256,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let top = _mm256_add_ps(tl, _mm256_mul_ps(_mm256_sub_ps(tr, tl), fx));
    let bottom = _mm256_add_ps(bl, _mm256_mul_ps(_mm256_sub_ps(br, bl), fx));
    _mm256_add_ps(top, _mm256_mul_ps(_mm256_sub_ps(bottom, top), fy))
}

/// Whether sixteen lanes' texels at `index` (those in `mask`) in a row-major f32 image whose rows are `width` floats apart
/// and `len` long lie within two windows of 32 consecutive floats (and, `bilinear`, their right neighbours too, and the
/// same floats one row down; every window inside the image): then two loads and a permute per window and row
/// fetch them, in place of a gather's sixteen loads per texel. The first window starts at the lowest index; the
/// lanes it cannot hold go to a second window, from the lowest index among them: a row of a view at up to two
/// texels a pixel fits, and so does one that crosses to the next image row at any of its sixteen pixels (a view
/// turned a little against the image). Returns the first float of each window (the same twice where one holds
/// all sixteen), each lane's index relative to its window, and the lanes of the second window.
///
/// # Safety
/// Callable only on a CPU with AVX-512 (F, DQ, BW, VL).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
#[inline]
pub fn texel_windows(
    index: std::arch::x86_64::__m512i,
    mask: std::arch::x86_64::__mmask16,
    bilinear: bool,
    width: usize,
    len: usize,
) -> Option<([usize; 2], std::arch::x86_64::__m512i, std::arch::x86_64::__mmask16)> {
    use std::arch::x86_64::*;
    // the right neighbour's index is rel + 1, and a permute reaches 32 floats
    let last = _mm512_set1_epi32(if bilinear { 30 } else { 31 });
    let rows = if bilinear { width } else { 0 };
    let inside = |first: i32| first >= 0 && first as usize + rows + 32 <= len;
    // a mask of consecutive lanes (a span's) whose indices never fall from one lane to the next (along a row of
    // a view, the usual case): the smallest index of any set of them is that of its lowest lane, read without a
    // reduction
    let run = mask >> mask.trailing_zeros().min(15);
    let pairs = mask & (mask >> 1);
    let rising = mask != 0
        && run & run.wrapping_add(1) == 0
        && _mm512_mask_cmpge_epi32_mask(pairs, _mm512_alignr_epi32::<1>(index, index), index) == pairs;
    let lowest = |lanes: __mmask16| {
        if rising {
            let lane = _mm512_set1_epi32(lanes.trailing_zeros() as i32);
            _mm_cvtsi128_si32(_mm512_castsi512_si128(_mm512_permutexvar_epi32(lane, index)))
        } else {
            _mm512_mask_reduce_min_epi32(lanes, index)
        }
    };
    let first = lowest(mask);
    let rel = _mm512_sub_epi32(index, _mm512_set1_epi32(first));
    // every lane's index is at least `first`, so `rel` ≥ 0 and the unsigned compare is the signed one
    let far = _mm512_mask_cmpgt_epu32_mask(mask, rel, last);
    if far == 0 {
        return inside(first).then_some(([first as usize; 2], rel, 0));
    }
    let second = lowest(far);
    let rel = _mm512_mask_sub_epi32(rel, far, index, _mm512_set1_epi32(second));
    let fits = _mm512_mask_cmpgt_epu32_mask(far, rel, last) == 0 && inside(first) && inside(second);
    fits.then_some(([first as usize, second as usize], rel, far))
}

/// The floats at `windows[0] + at[k]` (the lanes not in `second`) and `windows[1] + at[k]` (those in `second`)
/// from `base`: two loads and a permute per window ([`texel_windows`]'s windows, `at` its lanes' indices
/// relative to them, each in 0 … 31), one window where both are the same.
///
/// # Safety
/// The CPU must have AVX-512F; the 32 floats from `base + windows[i]` must lie inside one buffer, for both `i`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
#[inline]
pub unsafe fn window_fetch16(
    base: *const f32,
    windows: [usize; 2],
    at: std::arch::x86_64::__m512i,
    second: std::arch::x86_64::__mmask16,
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees both windows' 32 floats are inside the buffer
    let window = |first: usize| unsafe {
        let p = base.add(first);
        _mm512_permutex2var_ps(_mm512_loadu_ps(p), at, _mm512_loadu_ps(p.add(16)))
    };
    let low = window(windows[0]);
    if windows[1] == windows[0] { low } else { _mm512_mask_blend_ps(second, low, window(windows[1])) }
}

/// Sixteen samples of a row-major f32 image whose rows are `width` floats apart, bilinear ([`bilinear16_avx512`]'s) or nearest (the
/// texel at `index`): the texels fetched by [`texel_windows`] where they lie close together, as along a row of
/// a view that is not turned much against the image, else gathered. The same values either way; the lanes
/// outside `mask` are unspecified.
///
/// # Safety
/// The CPU must have AVX-512 (F, DQ, BW, VL); for every lane in `mask`, `index` (and, bilinear, `index + 1`,
/// `index + width` and `index + width + 1`) must lie inside `px`, whose length must fit an `i32`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vl")]
#[inline]
pub unsafe fn sample16_avx512(
    px: &[f32],
    index: std::arch::x86_64::__m512i,
    width: usize,
    fx: std::arch::x86_64::__m512,
    fy: std::arch::x86_64::__m512,
    mask: std::arch::x86_64::__mmask16,
    bilinear: bool,
) -> std::arch::x86_64::__m512 {
    use std::arch::x86_64::*;
    let base = px.as_ptr();
    match texel_windows(index, mask, bilinear, width, px.len()) {
        Some((windows, rel, second)) => {
            // the lanes' texels `offset` floats on from their index (the lanes in `second` from the second window)
            // SAFETY: `texel_windows` checked that every window (one row down included) ends inside `px`
            let fetch = |offset: usize, at: __m512i| unsafe { window_fetch16(base.add(offset), windows, at, second) };
            if bilinear {
                let right = _mm512_add_epi32(rel, _mm512_set1_epi32(1));
                let (tl, tr) = (fetch(0, rel), fetch(0, right));
                let (bl, br) = (fetch(width, rel), fetch(width, right));
                bilinear_mix16(tl, tr, bl, br, fx, fy)
            } else {
                fetch(0, rel)
            }
        }
        // SAFETY: the caller guarantees the masked lanes' texels are inside `px`
        None if bilinear => unsafe { bilinear16_avx512(base, index, width, fx, fy, mask) },
        // SAFETY: as above
        None => unsafe { _mm512_mask_i32gather_ps::<4>(_mm512_setzero_ps(), mask, index, base) },
    }
}

/// The first float of a window of 16 or 24 consecutive floats that holds eight lanes' floats at `index` (and,
/// `right`, each one's right neighbour), each lane's index relative to it, and whether it takes 24: where the
/// window, and the same floats `below` floats on, lie inside the `len` floats of a buffer; `None` where the lanes
/// spread wider or the window would end past it. Along a row of a view, 16 floats hold eight pixels' texels at up
/// to about two texels a pixel, 24 at up to about three (a prefiltered texture's grid at 2.6–3.1 nodes a pixel on
/// six of the eight shipped scenarios).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn window8(
    index: std::arch::x86_64::__m256i,
    right: bool,
    below: usize,
    len: usize,
) -> Option<(usize, std::arch::x86_64::__m256i, bool)> {
    use std::arch::x86_64::*;
    // the lowest index: the window's first float
    let m = _mm256_min_epi32(index, _mm256_permute2x128_si256::<1>(index, index));
    let m = _mm256_min_epi32(m, _mm256_shuffle_epi32::<0b01_00_11_10>(m));
    let m = _mm256_min_epi32(m, _mm256_shuffle_epi32::<0b10_11_00_01>(m));
    let first = _mm256_cvtsi256_si32(m);
    let rel = _mm256_sub_epi32(index, _mm256_set1_epi32(first));
    // every index is at least `first`, so `rel` ≥ 0; the window's last float is its right neighbour's
    let within = |floats: i32| {
        let last = _mm256_set1_epi32(floats - 1 - i32::from(right));
        _mm256_movemask_epi8(_mm256_cmpgt_epi32(rel, last)) == 0
            && first >= 0
            && first as usize + below + floats as usize <= len
    };
    if within(16) {
        Some((first as usize, rel, false))
    } else if within(24) {
        Some((first as usize, rel, true))
    } else {
        None
    }
}

/// The floats at `p + at[k]` (0 ≤ `at[k]` ≤ 23): each third's permute of three loads, bits 3 and 4 of `at` pick
/// the third.
///
/// # Safety
/// The CPU must have AVX2; the 24 floats from `p` must lie inside one buffer.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn window_fetch24(p: *const f32, at: std::arch::x86_64::__m256i) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees the 24 floats from `p` are inside the buffer
    let (a, b, c) = unsafe { (_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8)), _mm256_loadu_ps(p.add(16))) };
    let (upper, last) =
        (_mm256_castsi256_ps(_mm256_slli_epi32::<28>(at)), _mm256_castsi256_ps(_mm256_slli_epi32::<27>(at)));
    let first16 = _mm256_blendv_ps(_mm256_permutevar8x32_ps(a, at), _mm256_permutevar8x32_ps(b, at), upper);
    _mm256_blendv_ps(first16, _mm256_permutevar8x32_ps(c, at), last)
}

/// The floats at `p + at[k]` (0 ≤ `at[k]` ≤ 15): each half's permute, and bit 3 of `at` picks the half.
///
/// # Safety
/// The CPU must have AVX2; the 16 floats from `p` must lie inside one buffer.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn window_fetch8(p: *const f32, at: std::arch::x86_64::__m256i) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees the 16 floats from `p` are inside the buffer
    let (low, high) = unsafe { (_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8))) };
    let upper = _mm256_castsi256_ps(_mm256_slli_epi32::<28>(at));
    _mm256_blendv_ps(_mm256_permutevar8x32_ps(low, at), _mm256_permutevar8x32_ps(high, at), upper)
}

/// The low 32 bits of eight 64-bit lanes held in two vectors (four in `a`, then four in `b`), as eight 32-bit
/// lanes in that order.
///
/// # Safety
/// Called from code not compiled with AVX2, the CPU must have it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn low_halves_256(a: std::arch::x86_64::__m256i, b: std::arch::x86_64::__m256i) -> std::arch::x86_64::__m256i {
    use std::arch::x86_64::*;
    let pairs = _mm256_shuffle_ps::<0b10_00_10_00>(_mm256_castsi256_ps(a), _mm256_castsi256_ps(b));
    _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_castps_si256(pairs))
}

/// Each of eight lanes' float at `index` and its right neighbour, in every row `rows[r]` floats on, with AVX2:
/// where all of them lie within one window of 16 floats a row (`window8`), as along a row of a view at up to
/// about two texels a pixel, two loads, two permutes and a blend per row and neighbour; within one of 24, at up
/// to about three, three loads and permutes and two blends; else one 64-bit load of each lane's pair per row, two
/// lanes to a 128-bit half (hardware gathers, of pairs or of single floats, were slower than a scalar loop on an
/// AMD EPYC with AVX2).
///
/// # Safety
/// The CPU must have AVX2; for every lane and row, `index + rows[r]` and the float after it must lie inside
/// `px`, whose length must fit an `i32`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub unsafe fn pairs8_avx2<const ROWS: usize>(
    px: &[f32],
    index: std::arch::x86_64::__m256i,
    rows: [usize; ROWS],
) -> [(std::arch::x86_64::__m256, std::arch::x86_64::__m256); ROWS] {
    use std::arch::x86_64::*;
    let base = px.as_ptr();
    let below = rows.iter().copied().max().unwrap_or(0);
    if let Some((first, rel, wide)) = window8(index, true, below, px.len()) {
        let right = _mm256_add_epi32(rel, _mm256_set1_epi32(1));
        // a loop, not a closure mapped over the rows: with the 24-float fetch that closure was not inlined, and its
        // fetches went through memory
        let mut pairs = [(_mm256_setzero_ps(), _mm256_setzero_ps()); ROWS];
        for (pair, &r) in pairs.iter_mut().zip(&rows) {
            // SAFETY: `window8` checked that the window's 16 or 24 floats from `first + r` lie inside `px`
            unsafe {
                let p = base.add(first + r);
                *pair = if wide {
                    (window_fetch24(p, rel), window_fetch24(p, right))
                } else {
                    (window_fetch8(p, rel), window_fetch8(p, right))
                };
            }
        }
        return pairs;
    }
    let mut at = [0i32; 8];
    // SAFETY: eight i32 into an array of eight
    unsafe { _mm256_storeu_si256(at.as_mut_ptr().cast(), index) };
    rows.map(|r| {
        // SAFETY: the caller guarantees every lane's pair in this row is inside `px`
        let two = |j: usize| unsafe {
            let row = base.add(r);
            let first = _mm_load_sd(row.offset(at[j] as isize).cast());
            _mm_castpd_ps(_mm_loadh_pd(first, row.offset(at[j + 1] as isize).cast()))
        };
        let (a, b) = (_mm256_set_m128(two(2), two(0)), _mm256_set_m128(two(6), two(4)));
        // in lane order after the shuffles' (0, 2, 1, 3) interleave of 64-bit quarters
        let order = |v: __m256| _mm256_castsi256_ps(_mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_castps_si256(v)));
        (order(_mm256_shuffle_ps::<0b10_00_10_00>(a, b)), order(_mm256_shuffle_ps::<0b11_01_11_01>(a, b)))
    })
}

/// Eight samples of a row-major f32 image whose rows are `width` floats apart, with AVX2, bilinear (the texel at each lane's `index` and
/// its right, lower and lower-right neighbours by [`pairs8_avx2`], mixed by [`bilinear_mix8`] as
/// [`bilinear_mix16`] mixes them, so the values are the scalar samplers') or nearest (the texel at `index`, by a
/// window of 16 or 24 floats where the lanes' texels fit one, else gathered).
///
/// # Safety
/// The CPU must have AVX2; for every lane, `index` (and, bilinear, `index + 1`, `index + width` and
/// `index + width + 1`) must lie inside `px`, whose length must fit an `i32`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub unsafe fn sample8_avx2(
    px: &[f32],
    index: std::arch::x86_64::__m256i,
    width: usize,
    fx: std::arch::x86_64::__m256,
    fy: std::arch::x86_64::__m256,
    bilinear: bool,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let base = px.as_ptr();
    if !bilinear {
        return match window8(index, false, 0, px.len()) {
            // SAFETY (both): `window8` checked that the window lies inside `px`
            Some((first, rel, false)) => unsafe { window_fetch8(base.add(first), rel) },
            Some((first, rel, true)) => unsafe { window_fetch24(base.add(first), rel) },
            // SAFETY: the caller guarantees every lane's texel is inside `px`
            None => unsafe { _mm256_i32gather_ps::<4>(base, index) },
        };
    }
    // SAFETY: the caller guarantees the four texels of every lane are inside `px`
    let [(tl, tr), (bl, br)] = unsafe { pairs8_avx2(px, index, [0, width]) };
    bilinear_mix8(tl, tr, bl, br, fx, fy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn widest_gives_the_baseline_result() {
        let data: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin() * 100.0).collect();
        let kernel = [0.1f32, 0.2, 0.4, 0.2, 0.1];
        let run = || -> Vec<f32> {
            (0..data.len() - 4).map(|i| kernel.iter().zip(&data[i..i + 5]).map(|(k, d)| k * d).sum()).collect()
        };
        assert_eq!(widest(run), run());
        #[cfg(target_arch = "x86_64")]
        {
            if Level::supported() == Level::Avx512 {
                // SAFETY: checked just above
                assert_eq!(unsafe { with_avx2(run) }, run());
            }
        }
    }

    /// Distance in units in the last place between two finite positive floats (or 0 for equal ones).
    fn ulps(a: f64, b: f64) -> u64 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    #[test]
    fn exp_is_within_one_ulp_and_the_same_bits_vectorized() {
        // every binade of the range, densely near 0 where the physics lives, and the awkward points
        let mut xs: Vec<f64> = (0..200_001).map(|i| -745.0 + 1455.0 * i as f64 / 200_000.0).collect();
        xs.extend((0..100_001).map(|i| -20.0 + 40.0 * i as f64 / 100_000.0));
        xs.extend((0..1000).map(|i| (i as f64 - 500.0) * std::f64::consts::LN_2 * 0.5));
        xs.extend([0.0, -0.0, 1e-300, -1e-300, 1e-17, 709.78, 709.79, -708.39, -708.40, -744.4, -745.2]);
        let mut worst = 0;
        for &x in &xs {
            let (got, want) = (exp(x), x.exp());
            if want >= f64::MIN_POSITIVE && want.is_finite() {
                worst = worst.max(ulps(got, want));
            } else {
                // subnormal or out of range: within a few subnormal steps of libm's, or its 0 / ∞
                assert!((got - want).abs() <= 4.0 * 5e-324 || got == want, "{x}: {got} vs {want}");
            }
        }
        assert!(worst <= 1, "{worst} ulp");
        for (x, want) in [(f64::NEG_INFINITY, 0.0), (f64::INFINITY, f64::INFINITY), (-1e6, 0.0), (1e6, f64::INFINITY)] {
            assert_eq!(exp(x), want, "{x}");
        }
        assert!(exp(f64::NAN).is_nan());
        let vector = widest(|| xs.iter().map(|&x| exp(x)).collect::<Vec<f64>>());
        let scalar: Vec<f64> = xs.iter().map(|&x| std::hint::black_box(exp(std::hint::black_box(x)))).collect();
        assert!(vector.iter().zip(&scalar).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_windows_are_used_only_where_they_fit() {
        use std::arch::x86_64::*;
        if !is_x86_feature_detected!("avx2") {
            return;
        }
        let (w, len) = (300usize, 60_000usize);
        // the route for eight lanes at `lanes(k)`: the window's first float and whether it takes 24 floats
        let route = |lanes: &dyn Fn(i32) -> i32, right: bool, below: usize, len: usize| {
            let v: [i32; 8] = std::array::from_fn(|k| lanes(k as i32));
            // SAFETY: AVX2 checked above; 32 bytes read from, and written to, eight-lane arrays
            unsafe {
                let found = window8(_mm256_loadu_si256(v.as_ptr().cast()), right, below, len);
                found.map(|(first, rel, wide)| {
                    let mut out = [0i32; 8];
                    _mm256_storeu_si256(out.as_mut_ptr().cast(), rel);
                    // each lane's index is the first float plus its relative index, inside the window
                    let floats = if wide { 24 } else { 16 };
                    for k in 0..8 {
                        assert_eq!(first as i32 + out[k], v[k], "lane {k}");
                        assert!((0..floats - i32::from(right)).contains(&out[k]), "lane {k}");
                    }
                    (first, wide)
                })
            }
        };
        // every lane reads its float from a window of 24, at every place in it
        let floats: Vec<f32> = (0..24).map(|i| i as f32 * 1.5 - 7.0).collect();
        for shift in 0..24 {
            let at: [i32; 8] = std::array::from_fn(|k| (shift + 5 * k as i32) % 24);
            let mut got = [0f32; 8];
            // SAFETY: AVX2 checked above; 24 floats from the start of `floats`; eight lanes read and written
            unsafe {
                let v = window_fetch24(floats.as_ptr(), _mm256_loadu_si256(at.as_ptr().cast()));
                _mm256_storeu_ps(got.as_mut_ptr(), v);
            }
            assert_eq!(got, at.map(|i| floats[i as usize]), "lanes at {at:?}");
        }
        // 2 texels a pixel: 16 floats (the last lane's right neighbour is the 16th); one float more: 24
        assert_eq!(route(&|k| 100 + 2 * k, true, w, len), Some((100, false)));
        let past = |k: i32| 100 + 2 * k + i32::from(k == 7);
        assert_eq!(route(&past, true, w, len), Some((100, true)));
        assert_eq!(route(&past, false, 0, len), Some((100, false)));
        // 3 texels a pixel: 24 (the last lane's right neighbour is the 23rd float), and one float more (the 24th);
        // two more: gathered, bilinear (nearest samples still fit)
        assert_eq!(route(&|k| 100 + 3 * k, true, w, len), Some((100, true)));
        assert_eq!(route(&|k| 100 + 3 * k + i32::from(k == 7), true, w, len), Some((100, true)));
        let wider = |k: i32| 100 + 3 * k + 2 * i32::from(k == 7);
        assert_eq!(route(&wider, true, w, len), None);
        assert_eq!(route(&wider, false, 0, len), Some((100, true)));
        // backwards along a row: the window starts at the last lane's texel
        assert_eq!(route(&|k| 200 - 3 * k, true, w, len), Some((179, true)));
        // across a row of the image: gathered
        assert_eq!(route(&|k| if k < 4 { 100 + k } else { 400 + k }, false, 0, len), None);
        // the window (one row down, bilinear) must end inside the buffer
        assert_eq!(route(&|k| 100 + 3 * k, true, w, 100 + w + 24), Some((100, true)));
        assert_eq!(route(&|k| 100 + 3 * k, true, w, 100 + w + 23), None);
        assert_eq!(route(&|k| 100 + 2 * k, true, w, 100 + w + 16), Some((100, false)));
        assert_eq!(route(&|k| 100 + 2 * k, true, w, 100 + w + 15), None);
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn texel_windows_are_used_only_where_they_fit() {
        use std::arch::x86_64::*;
        if Level::supported() != Level::Avx512 {
            return;
        }
        let (w, len) = (300usize, 60_000usize);
        let near = |lanes: &dyn Fn(i32) -> i32, mask: u16, bilinear: bool, len: usize| {
            let v: [i32; 16] = std::array::from_fn(|k| lanes(k as i32));
            // SAFETY: AVX-512 checked above; 64 bytes read from a 16-lane array
            let (route, rel, second) = unsafe {
                let i = _mm512_loadu_si512(v.as_ptr().cast());
                match texel_windows(i, mask, bilinear, w, len) {
                    Some((first, rel, second)) => {
                        let mut out = [0i32; 16];
                        _mm512_storeu_si512(out.as_mut_ptr().cast(), rel);
                        (Some(first), out, second)
                    }
                    None => (None, [0; 16], 0),
                }
            };
            // each lane's index is its window's first float plus its relative index, which the window (with the
            // right neighbour, bilinear) holds; only lanes in the mask are in the second window
            if let Some(windows) = route {
                assert_eq!(second & !mask, 0);
                for k in (0..16).filter(|k| mask >> k & 1 == 1) {
                    let first = windows[usize::from(second >> k & 1 == 1)];
                    assert_eq!(first as i32 + rel[k], v[k], "lane {k}");
                    assert!((0..=if bilinear { 30 } else { 31 }).contains(&rel[k]), "lane {k}");
                }
            }
            route
        };
        // 2 texels a pixel: one window (the last lane's right neighbour is its 32nd float)
        assert_eq!(near(&|k| 100 + 2 * k, 0xffff, true, len), Some([100, 100]));
        // one float wider: one window for nearest samples, two for bilinear ones (the last lane's its own)
        let wide = |k: i32| 100 + 2 * k + i32::from(k == 15);
        assert_eq!(near(&wide, 0xffff, false, len), Some([100, 100]));
        assert_eq!(near(&wide, 0xffff, true, len), Some([100, 131]));
        // two windows, each on its own row, the row changing at the middle lane or at any other
        assert_eq!(near(&|k| if k < 8 { 100 + k } else { 400 + k }, 0xffff, true, len), Some([100, 408]));
        assert_eq!(near(&|k| if k < 3 { 100 + 2 * k } else { 400 + 2 * k }, 0xffff, true, len), Some([100, 406]));
        assert_eq!(near(&|k| if k < 13 { 100 + k } else { 400 + k }, 0xffff, false, len), Some([100, 413]));
        // 5 texels a pixel, or three rows: gathered
        assert_eq!(near(&|k| 100 + 5 * k, 0xffff, true, len), None);
        assert_eq!(near(&|k| [100, 400, 700][k as usize / 6] + k, 0xffff, false, len), None);
        // lanes outside the mask do not count
        assert_eq!(near(&|k| if k < 10 { 100 + k } else { 50_000 }, 0x03ff, true, len), Some([100, 100]));
        // the windows (one row down, bilinear) must end inside the image
        assert_eq!(near(&|k| 100 + k, 0xffff, true, 100 + w + 32), Some([100, 100]));
        assert_eq!(near(&|k| 100 + k, 0xffff, true, 100 + w + 31), None);
        assert_eq!(near(&|k| 100 + k, 0xffff, false, 100 + 31), None);
        // along a row backwards: the first window starts at the last lane's texel, the second at the lowest of
        // the lanes the first cannot hold
        assert_eq!(near(&|k| 200 - 2 * k, 0xffff, true, len), Some([170, 170]));
        assert_eq!(near(&|k| 200 - 3 * k, 0xffff, true, len), Some([155, 188]));
        // one lane below the first lane's texel (lanes that do not rise all along): the windows start at the
        // lowest index, as by a reduction over every lane
        assert_eq!(near(&|k| if k == 9 { 90 } else { 100 + 2 * k }, 0xffff, true, len), Some([90, 122]));
        // lanes outside the mask do not count, nor does their place between lanes inside it
        assert_eq!(near(&|k| if k == 0 { 50_000 } else { 100 + k }, 0xfffe, true, len), Some([101, 101]));
        assert_eq!(near(&|k| [100, 101, 50_000, 90][k as usize % 4], 0b1011, true, len), Some([90, 90]));
        // no lane at all: nothing to fetch
        assert_eq!(near(&|k| 100 + k, 0, true, len), None);
        // the second window ending past the image is enough to gather
        assert_eq!(near(&|k| 100 + 3 * k, 0xffff, false, 133 + 31), None);
        assert_eq!(near(&|k| 100 + 3 * k, 0xffff, false, 133 + 32), Some([100, 133]));
    }
}
