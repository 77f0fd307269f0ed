//! Per-pixel loops compiled for the widest vectors the CPU has.
//!
//! The crate is built for baseline x86-64 (SSE2, four f32 lanes). [`widest`] runs a closure inside a function
//! compiled with AVX2 (eight lanes) when the CPU has it, so the loops inlined into it vectorize twice as wide.
//! Only code inlined into that function is compiled with AVX2: the per-pixel functions a closure calls are
//! `#[inline(always)]`, or they run the baseline code (LLVM does not inline large functions on its own).
//! Fused multiply–add is not enabled: Rust never contracts `a·b + c`, so every lane does the same operations in
//! the same order as on the baseline path and the results are bit-identical whichever path runs.

/// Runs `f`, compiled with AVX2 where the CPU supports it (results identical to the baseline path).
#[inline]
pub fn widest<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { with_avx2(f) };
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
    }
}
