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

/// Sixteen bilinear samples of a row-major f32 image `width` wide with AVX-512 gathers: the texel at each lane's
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
    let top = _mm512_add_ps(tl, _mm512_mul_ps(_mm512_sub_ps(tr, tl), fx));
    let bottom = _mm512_add_ps(bl, _mm512_mul_ps(_mm512_sub_ps(br, bl), fx));
    _mm512_add_ps(top, _mm512_mul_ps(_mm512_sub_ps(bottom, top), fy))
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
}
