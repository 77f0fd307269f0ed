//! Poisson fusion of target patches into the frame (paper eqs 16–20).
//!
//! On a rectangular region R, the outermost ring of pixels is the Dirichlet boundary ∂Ω (kept at the frame's
//! values, `f = f*`), and the pixels inside it are the unknowns Ω. For each `p ∈ Ω` with 4-neighbours `q`:
//!
//! ```text
//! 4 f_p − Σ_{q ∈ Ω} f_q = Σ_{q ∈ ∂Ω} f*_q + Σ_q v_pq
//! ```
//!
//! with the guidance `v_pq = u_p − u_q` ("normal", the paper's eq 17/19: the target patch `u`'s gradient),
//! or per edge whichever of `u_p − u_q` and `f*_p − f*_q` is larger in magnitude ("mixed", keeps the sky's
//! texture under the target). "Additive" is the baseline without a solve: `f = f* + u` on R.
//!
//! Solvers: Jacobi sweeps exactly as eq 20 (the paper's, kept as a reference), red-black SOR, and the default
//! exact direct solver: the 5-point Laplacian with Dirichlet boundaries is diagonalised by the type-I discrete
//! sine transform, so `f = S_y S_x (Ŝ_x Ŝ_y b / λ)` with `λ_kl = 4 − 2cos(πk/(n_x+1)) − 2cos(πl/(n_y+1))`, in
//! O(n² log n), in f64, two rows per complex FFT of the rows' length plus one. The same solve in f32
//! ([`Solver::DirectF32`]) solves for the difference from the background, `f = f* + d`, whose right-hand side
//! `Σ_q v_pq − (4 f*_p − Σ_q f*_q)` is formed in f64: `d` is the size of the target's contrast and of the sky's
//! structure the solve replaces under it, not of the gray levels, so single precision's relative error applies to
//! those alone.
//!
//! Overlapping (or touching) regions of several targets are merged into one solve. Regions are clipped to the
//! frame; a region thinner than 3 pixels has no interior and is left as it is in the solved modes. Separate
//! regions are solved in parallel, each on its own buffers. Once the largest region and the most regions at once
//! have been seen, [`PoissonFusion::fuse`] allocates nothing.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use super::frame::Frame;
use super::target_blob::PixelRect;

/// Which gradient field guides the fused region.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Guidance {
    /// The target patch's gradient (the paper).
    #[default]
    Normal,
    /// Per edge, the larger of the patch's and the background's gradient.
    Mixed,
    /// No solve: the patch is added to the background.
    Additive,
}

/// How the Poisson equation is solved.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "method", deny_unknown_fields, from = "SolverFields")]
pub enum Solver {
    /// Exact direct solve by the discrete sine transform, in f64.
    #[default]
    Direct,
    /// The direct solve in f32, of the difference from the background (its right-hand side formed in f64, the
    /// sum added back in f64): transforms of twice the values per vector register, at single precision's
    /// relative error on the target's contrast.
    DirectF32,
    /// Jacobi sweeps (eq 20) until the largest update is below `tolerance` or `max_iterations` is reached.
    Jacobi {
        /// Stop when no pixel changes by more than this, gray levels.
        tolerance: f64,
        /// Upper bound on sweeps.
        max_iterations: u32,
    },
    /// Red-black successive over-relaxation with the optimal factor for the region's size.
    Sor {
        /// Stop when no pixel changes by more than this, gray levels.
        tolerance: f64,
        /// Upper bound on sweeps.
        max_iterations: u32,
    },
}

/// [`Solver`] as a scenario writes it, every variant a table of its fields: serde reads a variant without fields
/// from the tag alone and ignores any key beside it (`{ method = "direct", tolerance = 1 }` would pass), so [`Solver`] is read through this and
/// such a key is refused as unknown.
#[derive(Deserialize)]
#[serde(
    rename_all = "snake_case",
    tag = "method",
    deny_unknown_fields,
    expecting = "a table with `method`: direct, direct_f32, jacobi or sor"
)]
enum SolverFields {
    Direct {},
    DirectF32 {},
    Jacobi { tolerance: f64, max_iterations: u32 },
    Sor { tolerance: f64, max_iterations: u32 },
}

impl From<SolverFields> for Solver {
    fn from(s: SolverFields) -> Self {
        match s {
            SolverFields::Direct {} => Self::Direct,
            SolverFields::DirectF32 {} => Self::DirectF32,
            SolverFields::Jacobi { tolerance, max_iterations } => Self::Jacobi { tolerance, max_iterations },
            SolverFields::Sor { tolerance, max_iterations } => Self::Sor { tolerance, max_iterations },
        }
    }
}

/// A target patch `u` on a pixel rectangle (row-major, `rect.width()` wide).
#[derive(Debug, Clone, Copy)]
pub struct Patch<'a> {
    /// Where the patch lies in the frame (already clipped).
    pub rect: PixelRect,
    /// Its values.
    pub values: &'a [f32],
}

/// What a call to [`PoissonFusion::fuse`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct FusionStats {
    /// Regions solved after merging.
    pub regions: usize,
    /// Unknowns over all regions.
    pub unknowns: usize,
    /// Largest number of iterations an iterative solver used (0 for the direct solver).
    pub iterations: u32,
    /// Regions whose iterative solve ended at the work budget ([`MAX_SWEEP_UPDATES`]) before its tolerance.
    pub over_budget: usize,
    /// A stop request ended a solve: the frame is incomplete.
    pub stopped: bool,
}

/// Most pixel updates one iterative solve of one region may make (sweeps × unknowns): 4·10⁹ took 26 s on a
/// loaded 2-core machine, so 10⁹ bounds a frame's solve to seconds. A solve that needs more stops there, with
/// [`FusionStats::over_budget`] counting it.
pub const MAX_SWEEP_UPDATES: u64 = 1_000_000_000;

/// Values per block of rows that [`Dst1::process_rows`] hands to a thread (rounded to whole pairs of rows): a
/// region transforms in parallel from two blocks up (a 190 × 95 region's rows in about ten blocks).
const PARALLEL_ROWS_BLOCK: usize = 4096;

thread_local! {
    /// Each thread's transform buffer and FFT scratch for the blocks of [`Dst1::process_rows`] (kept from call to
    /// call: no allocation per frame), in f64 and in f32.
    static BLOCK_BUFFERS: std::cell::RefCell<FftBuffers<f64>> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
    static BLOCK_BUFFERS_F32: std::cell::RefCell<FftBuffers<f32>> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// What [`Dst1::process_rows`] applies to a row between its two transforms: `(index, row)`.
type RowStep<'a, T> = dyn Fn(usize, &mut [T]) + Sync + 'a;

/// A transform buffer and an FFT scratch.
type FftBuffers<T> = (Vec<Complex<T>>, Vec<Complex<T>>);

/// The precisions the direct solver runs in: f64 ([`Solver::Direct`]) and f32 ([`Solver::DirectF32`]).
trait Real: rustfft::FftNum + Default + std::ops::AddAssign + std::ops::MulAssign {
    /// `v` rounded to this type.
    fn of(v: f64) -> Self;
    /// Runs `f` on this thread's [`BLOCK_BUFFERS`] of this type.
    fn with_block_buffers(f: impl FnOnce(&mut FftBuffers<Self>));
    /// [`transpose`]'s AVX2 kernel for this type.
    ///
    /// # Safety
    /// The CPU must have AVX2, and `src` and `dst` must hold `rows · cols` values.
    #[cfg(target_arch = "x86_64")]
    unsafe fn transpose_avx2(src: &[Self], dst: &mut [Self], cols: usize, rows: usize);
    /// The first blocks of [`Dst1::process_pair`]'s loop before its FFT, for two rows (`rows`: row a's low and
    /// high halves, then row b's), in explicit vector code where this type and the CPU have it: returns how many
    /// of the `low.len()` values it did, the rest being the caller's. The same operations in the same order as
    /// that loop.
    fn pair_in(_sines: &[Self], _rows: [&[Self]; 4], _low: &mut [Complex<Self>], _high: &mut [Complex<Self>]) -> usize {
        0
    }
    /// The same for the loop after the FFT, over its first `whole` values: row a's and b's `row[2k − 1]` and
    /// `row[2k]` (`a` and `b` from `row[1]`) before the running sums.
    fn pair_out(_z: [&[Complex<Self>]; 2], _whole: usize, _a: &mut [Self], _b: &mut [Self]) -> usize {
        0
    }
}

impl Real for f64 {
    fn of(v: f64) -> Self {
        v
    }
    fn with_block_buffers(f: impl FnOnce(&mut FftBuffers<Self>)) {
        BLOCK_BUFFERS.with_borrow_mut(f);
    }
    #[cfg(target_arch = "x86_64")]
    unsafe fn transpose_avx2(src: &[Self], dst: &mut [Self], cols: usize, rows: usize) {
        // SAFETY: the caller's
        unsafe { x86::transpose_avx2(src, dst, cols, rows) }
    }
}

impl Real for f32 {
    fn of(v: f64) -> Self {
        v as f32
    }
    fn with_block_buffers(f: impl FnOnce(&mut FftBuffers<Self>)) {
        BLOCK_BUFFERS_F32.with_borrow_mut(f);
    }
    #[cfg(target_arch = "x86_64")]
    unsafe fn transpose_avx2(src: &[Self], dst: &mut [Self], cols: usize, rows: usize) {
        // SAFETY: the caller's
        unsafe { x86::transpose_avx2_f32(src, dst, cols, rows) }
    }
    fn pair_in(sines: &[Self], rows: [&[Self]; 4], low: &mut [Complex<Self>], high: &mut [Complex<Self>]) -> usize {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the CPU has AVX2; the function checks the lengths
            return unsafe { x86::pair_in_f32(sines, rows, low, high) };
        }
        let _ = (sines, rows, low, high);
        0
    }
    fn pair_out(z: [&[Complex<Self>]; 2], whole: usize, a: &mut [Self], b: &mut [Self]) -> usize {
        #[cfg(target_arch = "x86_64")]
        if avx2() {
            // SAFETY: the CPU has AVX2; the function checks the lengths
            return unsafe { x86::pair_out_f32(z, whole, a, b) };
        }
        let _ = (z, whole, a, b);
        0
    }
}

/// True where explicit AVX2 code may run: the CPU has it (every level above the baseline includes it), and
/// `IRSIM_SIMD` does not hold the crate to the baseline.
fn avx2() -> bool {
    cfg!(target_arch = "x86_64") && crate::physics::simd::Level::detect() != crate::physics::simd::Level::Baseline
}

/// The symmetric part `s·(f + mirror)` and the antisymmetric part `½(f − mirror)` of a row's value `f` and its
/// mirror image, weighted by the sine `s`: what [`Dst1::process_pair`] adds and subtracts.
#[inline(always)]
fn parts<T: Real>(s: T, f: T, mirror: T) -> (T, T) {
    (s * (f + mirror), T::of(0.5) * (f - mirror))
}

/// `buf` grown with zeros to `len` values where it is shorter.
fn fit<V: Clone + Default>(buf: &mut Vec<V>, len: usize) {
    if buf.len() < len {
        buf.resize(len, V::default());
    }
}

/// A planned type-I discrete sine transform of length `n`, two real rows per complex FFT of length `n + 1`.
///
/// `X_k = Σ_j x_j sin(π(j+1)(k+1)/(n+1))` (unnormalised; applying it twice multiplies by `(n+1)/2`). Written with
/// `N = n + 1`, `f_J = x_{J−1}` (`f_0 = f_N = 0`) and `F_K = X_{K−1}`, the sequence
/// `y_J = sin(πJ/N)(f_J + f_{N−J}) + ½(f_J − f_{N−J})` has the discrete Fourier transform `Y_k = R_k − i·I_k` (the
/// FFT's sign), whose imaginary parts are minus the even outputs, `F_{2k} = I_k`, and whose real parts are
/// differences of the odd ones, `R_k = F_{2k+1} − F_{2k−1}` (with `F_{−1} = −F_1`), summed from `F_1 = R_0/2`:
/// the sine part of `y` is even about `N/2` and meets only the cosines, the rest is odd and meets only the sines.
/// Two rows go in as the real and imaginary parts of one complex FFT of length `N`, and are told apart by the
/// symmetry of real sequences' transforms. The odd extension of length `2N` that this replaced took an FFT twice
/// as long: a direct solve ([`PoissonFusion::solve_dirichlet`], one thread, an AMD EPYC, three interleaved rounds)
/// of a 254 × 71 interior took 268–270 µs with it and 175–176 µs with this, of 143 × 71 102–103 and 74–75 µs, of
/// 31 × 31 8.0–8.2 and 6.2–6.3 µs.
struct Dst1<T: Real> {
    n: usize,
    /// The complex FFT of length `n + 1`.
    fft: Arc<dyn Fft<T>>,
    /// `sin(πJ/(n+1))` for `J` = 1 … n: the weights of the rows' symmetric parts.
    sines: Vec<T>,
    /// `2 − 2cos(π(k+1)/(n+1))`: this axis's share of the Laplacian's eigenvalues.
    eigen: Vec<T>,
}

impl<T: Real> Dst1<T> {
    /// Plans the transform of length `n` (≥ 1) with `planner` (its weights computed in f64, then rounded).
    fn new(n: usize, planner: &mut FftPlanner<T>) -> Self {
        let c = std::f64::consts::PI / (n + 1) as f64;
        Self {
            n,
            fft: planner.plan_fft_forward(n + 1),
            sines: (1..=n).map(|j| T::of((c * j as f64).sin())).collect(),
            eigen: (0..n).map(|k| T::of(2.0 - 2.0 * (c * (k + 1) as f64).cos())).collect(),
        }
    }

    /// The length of the transform buffer it needs.
    fn buffer_len(&self) -> usize {
        self.n + 1
    }

    /// Transforms `a` and, if given, `b` in place; `buf` holds `n + 1` values, `scratch` the FFT's scratch. The
    /// loops before and after the FFT run over slices of known length, a mirrored half indexed from its end; for
    /// a pair of f32 rows on a CPU with AVX2 their blocks of eight are explicit vector code ([`Real::pair_in`],
    /// [`Real::pair_out`]). The odd outputs' running sums are the one serial part.
    #[inline(always)]
    fn process_pair(&self, a: &mut [T], b: Option<&mut [T]>, buf: &mut [Complex<T>], scratch: &mut [Complex<T>]) {
        let n = self.n;
        let (zero, half) = (T::zero(), T::of(0.5));
        let buf = &mut buf[..n + 1];
        let a = &mut a[..n];
        let b = b.map(|b| &mut b[..n]);
        // y_J and y_{N−J} from f_J (row[J − 1]) and f_{N−J} (row[n − J]), J = 1 … m = ⌊n/2⌋, rows a and b as real
        // and imaginary parts: buf[J] is low[J − 1], buf[N − J] is high[m − J]; n odd, the middle one, y_{N/2},
        // from f_{N/2} alone
        let m = n / 2;
        buf[0] = Complex::new(zero, zero);
        let (head, high) = buf.split_at_mut(n + 1 - m);
        let low = &mut head[1..=m];
        let sines = &self.sines[..m];
        let (a_low, a_high) = (&a[..m], &a[n - m..]);
        match b.as_deref() {
            Some(b) => {
                let rows = [a_low, a_high, &b[..m], &b[n - m..]];
                let done = T::pair_in(sines, rows, low, high);
                pair_in_from(done, sines, rows, low, high);
            }
            None => {
                for k in 0..m {
                    let r = m - 1 - k;
                    let (sa, da) = parts(sines[k], a_low[k], a_high[r]);
                    low[k] = Complex::new(sa + da, zero);
                    high[r] = Complex::new(sa - da, zero);
                }
            }
        }
        if n % 2 == 1 {
            let s = self.sines[m];
            let (sa, da) = parts(s, a[m], a[m]);
            let im = b.as_deref().map_or(zero, |b| {
                let (sb, db) = parts(s, b[m], b[m]);
                sb + db
            });
            head[m + 1] = Complex::new(sa + da, im);
        }
        self.fft.process_with_scratch(buf, scratch);
        // the FFT of row a's y is (Z_k + conj Z_{N−k})/2, of row b's (Z_k − conj Z_{N−k})/(2i), k = 1 … m:
        // F_{2k} (row[2k − 1]) from their imaginary parts, and row[2k] first the real part R_k, which is
        // F_{2k+1} − F_{2k−1}, then (below) their running sum from F_1 = R_0/2
        let (z_low, z_high) = (&buf[1..=m], &buf[n + 1 - m..]);
        // the k whose row[2k] exists: all m with n odd, the last one without with n even
        let whole = if n % 2 == 1 { m } else { m.saturating_sub(1) };
        // n even: the last k's F_{2k} alone
        let last = (whole < m).then(|| (z_low[m - 1], z_high[0]));
        a[0] = half * buf[0].re;
        if let Some((zk, zm)) = last {
            a[2 * m - 1] = half * (zm.im - zk.im);
        }
        match b {
            Some(b) => {
                b[0] = half * buf[0].im;
                if let Some((zk, zm)) = last {
                    b[2 * m - 1] = half * (zk.re - zm.re);
                }
                let (z, outs_a, outs_b) = ([z_low, z_high], &mut a[1..1 + 2 * whole], &mut b[1..1 + 2 * whole]);
                let done = T::pair_out(z, whole, outs_a, outs_b);
                pair_out_from(done, z, outs_a, outs_b);
                // the sums kept in registers: loaded back from the rows, each would wait for its own store
                let (mut odd_a, mut odd_b) = (a[0], b[0]);
                for i in (2..n).step_by(2) {
                    odd_a += a[i];
                    odd_b += b[i];
                    (a[i], b[i]) = (odd_a, odd_b);
                }
            }
            None => {
                for (k, out) in a[1..1 + 2 * whole].chunks_exact_mut(2).enumerate() {
                    let (zk, zm) = (z_low[k], z_high[m - 1 - k]);
                    out[0] = half * (zm.im - zk.im);
                    out[1] = half * (zk.re + zm.re);
                }
                let mut odd_a = a[0];
                for v in a.iter_mut().skip(2).step_by(2) {
                    odd_a += *v;
                    *v = odd_a;
                }
            }
        }
    }

    /// Transforms every row of length `n` in `rows`, two at a time; a large region's rows in parallel, in
    /// blocks of whole pairs (each row is paired as in one pass, so the result is the same), each block on its
    /// thread's own buffers ([`BLOCK_BUFFERS`]). With `between`, each pair is transformed, `between(i, row)` is
    /// applied to its rows (`i` the row's index in `rows`), and the pair is transformed again, while it is in the
    /// cache and on the same thread.
    fn process_rows(
        &self,
        rows: &mut [T],
        buf: &mut [Complex<T>],
        scratch: &mut [Complex<T>],
        between: Option<&RowStep<'_, T>>,
    ) {
        use rayon::prelude::*;
        let pair = 2 * self.n;
        let block = pair * (PARALLEL_ROWS_BLOCK / pair).max(1);
        if rows.len() < 2 * block || rayon::current_num_threads() < 2 {
            return self.process_rows_serial(rows, 0, buf, scratch, between);
        }
        let (buf_len, scratch_len) = (buf.len(), scratch.len());
        rows.par_chunks_mut(block).enumerate().for_each(|(k, rows)| {
            T::with_block_buffers(|(buf, scratch)| {
                fit(buf, buf_len);
                fit(scratch, scratch_len);
                let first = k * block / self.n;
                self.process_rows_serial(rows, first, &mut buf[..buf_len], &mut scratch[..scratch_len], between);
            });
        });
    }

    /// [`Dst1::process_rows`] on this thread, `rows` starting at row `first`.
    fn process_rows_serial(
        &self,
        rows: &mut [T],
        first: usize,
        buf: &mut [Complex<T>],
        scratch: &mut [Complex<T>],
        between: Option<&RowStep<'_, T>>,
    ) {
        // the loop inlined into `widest`, so that process_pair's loops are compiled for the CPU's vectors
        crate::physics::simd::widest(
            #[inline(always)]
            || {
                let mut chunks = rows.chunks_exact_mut(self.n);
                let mut i = first;
                while let Some(a) = chunks.next() {
                    let mut b = chunks.next();
                    self.process_pair(a, b.as_deref_mut(), buf, scratch);
                    if let Some(between) = between {
                        between(i, a);
                        if let Some(b) = b.as_deref_mut() {
                            between(i + 1, b);
                        }
                        self.process_pair(a, b, buf, scratch);
                    }
                    i += 2;
                }
            },
        );
    }
}

/// [`Dst1::process_pair`]'s loop before the FFT for two rows, from the `from`-th of the `m = low.len()` values:
/// `low[k]` and `high[m − 1 − k]` from `rows` (row a's first and last `m` values, then row b's).
#[inline(always)]
fn pair_in_from<T: Real>(from: usize, sines: &[T], rows: [&[T]; 4], low: &mut [Complex<T>], high: &mut [Complex<T>]) {
    let m = low.len();
    let [a_low, a_high, b_low, b_high] = rows.map(|r| &r[..m]);
    let (sines, high) = (&sines[..m], &mut high[..m]);
    for k in from..m {
        let r = m - 1 - k;
        let ((sa, da), (sb, db)) = (parts(sines[k], a_low[k], a_high[r]), parts(sines[k], b_low[k], b_high[r]));
        low[k] = Complex::new(sa + da, sb + db);
        high[r] = Complex::new(sa - da, sb - db);
    }
}

/// [`Dst1::process_pair`]'s loop after the FFT for two rows, from the `from`-th of the `whole = a.len() / 2`
/// values: `a[2k]`, `a[2k + 1]` (and b's) from `z` (the FFT's values 1 … m and N − m … N − 1).
#[inline(always)]
fn pair_out_from<T: Real>(from: usize, z: [&[Complex<T>]; 2], a: &mut [T], b: &mut [T]) {
    let half = T::of(0.5);
    let [z_low, z_high] = z;
    let m = z_low.len();
    let outs = a.chunks_exact_mut(2).zip(b.chunks_exact_mut(2));
    for (k, (oa, ob)) in (from..).zip(outs.skip(from)) {
        let (zk, zm) = (z_low[k], z_high[m - 1 - k]);
        oa[0] = half * (zm.im - zk.im);
        oa[1] = half * (zk.re + zm.re);
        ob[0] = half * (zk.re - zm.re);
        ob[1] = half * (zk.im + zm.im);
    }
}

/// Poisson fusion with planned transforms and reusable buffers.
pub struct PoissonFusion {
    /// The transforms of [`Solver::Direct`].
    plans: Plans<f64>,
    /// The transforms of [`Solver::DirectF32`].
    plans_f32: Plans<f32>,
    rects: Vec<PixelRect>,
    /// One set of buffers per region: the regions are solved in parallel.
    scratch: Vec<Scratch>,
    /// The largest region's area so far: what every set of buffers is sized for.
    sized_for_area: usize,
    /// Looked at between sweeps of the iterative solvers: when set, they stop at once.
    stop: Option<Arc<AtomicBool>>,
}

/// Planned sine transforms of one precision by length, and the longest transform buffer and FFT scratch they
/// need.
struct Plans<T: Real> {
    planner: FftPlanner<T>,
    dst: HashMap<usize, Arc<Dst1<T>>>,
    buf_len: usize,
    scratch_len: usize,
}

impl<T: Real> Plans<T> {
    fn new() -> Self {
        Self { planner: FftPlanner::new(), dst: HashMap::new(), buf_len: 0, scratch_len: 0 }
    }

    /// The transform of length `n`, planned when first asked for.
    fn get(&mut self, n: usize) -> Arc<Dst1<T>> {
        if let Some(d) = self.dst.get(&n) {
            return Arc::clone(d);
        }
        let d = Arc::new(Dst1::new(n, &mut self.planner));
        self.buf_len = self.buf_len.max(d.buffer_len());
        self.scratch_len = self.scratch_len.max(d.fft.get_inplace_scratch_len());
        self.dst.insert(n, Arc::clone(&d));
        d
    }

    /// Plans the transforms of the interior of every region of `rects` that has one.
    fn plan_regions(&mut self, rects: &[PixelRect]) {
        for r in rects {
            if r.width() >= 3 && r.height() >= 3 {
                self.get(r.width() - 2);
                self.get(r.height() - 2);
            }
        }
    }
}

/// A direct solve's buffers in one precision: the right-hand side and then the solution (interior layout), its
/// transpose, the transform buffer and the FFT scratch.
#[derive(Default)]
struct Spectral<T> {
    work: Vec<T>,
    tmp: Vec<T>,
    buf: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
}

impl<T: Real> Spectral<T> {
    /// Sizes the buffers for an interior of `area` values and the transforms of `plans` (allocating only where
    /// one falls short).
    fn reserve(&mut self, area: usize, plans: &Plans<T>) {
        fit(&mut self.work, area);
        fit(&mut self.tmp, area);
        fit(&mut self.buf, plans.buf_len);
        fit(&mut self.scratch, plans.scratch_len);
    }

    /// [`solve_sine`] on these buffers.
    fn solve(&mut self, dst_x: &Dst1<T>, dst_y: &Dst1<T>) {
        solve_sine(&mut self.work, &mut self.tmp, &mut self.buf, &mut self.scratch, dst_x, dst_y);
    }
}

/// The buffers of one region's solve.
#[derive(Default)]
struct Scratch {
    /// Guidance patch u on the region.
    u: Vec<f64>,
    /// Background f* on the region.
    bg: Vec<f64>,
    /// Right-hand side / solution on the interior (or the whole region for the iterative solvers).
    work: Vec<f64>,
    work2: Vec<f64>,
    /// Second buffer of the Jacobi sweeps.
    next: Vec<f64>,
    /// The direct solve's (f64: `work` and `work2` are its right-hand side and transpose).
    fft_buf: Vec<Complex<f64>>,
    fft_scratch: Vec<Complex<f64>>,
    /// The f32 direct solve's.
    single: Spectral<f32>,
    /// What the last solve on these buffers did.
    stats: FusionStats,
}

impl std::fmt::Debug for PoissonFusion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoissonFusion")
            .field("planned_sizes", &self.plans.dst.keys().collect::<Vec<_>>())
            .field("planned_sizes_f32", &self.plans_f32.dst.keys().collect::<Vec<_>>())
            .finish()
    }
}

impl Default for PoissonFusion {
    fn default() -> Self {
        Self::new()
    }
}

impl PoissonFusion {
    /// A fusion engine with nothing planned yet.
    pub fn new() -> Self {
        Self {
            plans: Plans::new(),
            plans_f32: Plans::new(),
            rects: Vec::new(),
            scratch: vec![Scratch::default()],
            sized_for_area: 0,
            stop: None,
        }
    }

    /// The regions the last [`PoissonFusion::fuse`] solved: the patches' rectangles clipped to the frame,
    /// merged where they touch, and grown by a few pixels where that gives a faster transform size.
    pub fn regions(&self) -> &[PixelRect] {
        &self.rects
    }

    /// Plans transforms and sizes buffers for regions up to `max_side × max_side` solved by
    /// [`Solver::Direct`], so later calls with one region do not allocate (each further region at once gets
    /// buffers of the same size when first needed).
    pub fn with_capacity(max_side: usize) -> Self {
        let mut s = Self::new();
        for n in 1..=max_side.saturating_sub(2) {
            s.plans.get(n);
        }
        s.sized_for_area = max_side * max_side;
        s.size_buffers(1);
        s.rects.reserve(64);
        s
    }

    /// Gives the first `sets` sets of buffers the size of the largest region so far and of the planned
    /// transforms (the f32 solve's only once it has been used), allocating only where one falls short.
    fn size_buffers(&mut self, sets: usize) {
        if self.scratch.len() < sets {
            self.scratch.resize_with(sets, Scratch::default);
        }
        let area = self.sized_for_area;
        for sc in &mut self.scratch[..sets] {
            sc.reserve(area);
            fit(&mut sc.fft_buf, self.plans.buf_len);
            fit(&mut sc.fft_scratch, self.plans.scratch_len);
            if !self.plans_f32.dst.is_empty() {
                sc.single.reserve(area, &self.plans_f32);
            }
        }
    }

    /// A flag the iterative solvers look at between sweeps: once it is set they return at once (the frame is
    /// then incomplete, and [`FusionStats::stopped`] says so).
    pub fn set_stop(&mut self, flag: Arc<AtomicBool>) {
        self.stop = Some(flag);
    }

    /// Fuses `patches` into `frame` with `guidance`, solving with `solver`.
    pub fn fuse(
        &mut self,
        frame: &mut Frame,
        patches: &[Patch<'_>],
        guidance: Guidance,
        solver: Solver,
    ) -> FusionStats {
        use rayon::prelude::*;
        self.merge_regions(patches, frame.width(), frame.height());
        let solved = guidance != Guidance::Additive;
        // the transforms are planned first (the planner is not shared); then each region is loaded and solved
        // on its own buffers, in parallel (regions do not touch, and each reads only its own pixels), and the
        // solutions are written into the frame one region after the other
        match solver {
            Solver::Direct if solved => self.plans.plan_regions(&self.rects),
            Solver::DirectF32 if solved => self.plans_f32.plan_regions(&self.rects),
            _ => {}
        }
        let regions = self.rects.len();
        // every set of buffers sized for the largest region and transform so far: which region a set gets
        // changes from frame to frame, and none then allocates again
        let largest = self.rects.iter().map(|r| r.width() * r.height()).max().unwrap_or(0);
        self.sized_for_area = self.sized_for_area.max(largest);
        self.size_buffers(regions);
        let (stop, rects) = (self.stop.as_deref(), &self.rects);
        let (dst, dst_f32) = (&self.plans.dst, &self.plans_f32.dst);
        let frame_in: &Frame = frame;
        self.scratch[..regions].par_iter_mut().zip(rects.par_iter()).with_max_len(1).for_each(|(sc, &rect)| {
            let mut stats = FusionStats::default();
            // the loading and the right-hand sides' loops compiled for the CPU's widest vectors (f64 adds and
            // subtracts: the same results on every path)
            crate::physics::simd::widest(
                #[inline(always)]
                || sc.load_region(frame_in, rect, patches),
            );
            let (w, h) = (rect.width(), rect.height());
            if !solved || w < 3 || h < 3 {
                sc.stats = stats;
                return;
            }
            stats.unknowns = (w - 2) * (h - 2);
            match solver {
                Solver::Direct => {
                    crate::physics::simd::widest(
                        #[inline(always)]
                        || sc.build_rhs(w, h, guidance),
                    );
                    sc.solve_direct(&dst[&(w - 2)], &dst[&(h - 2)]);
                }
                Solver::DirectF32 => {
                    crate::physics::simd::widest(
                        #[inline(always)]
                        || sc.build_difference_rhs(w, h, guidance),
                    );
                    sc.single.solve(&dst_f32[&(w - 2)], &dst_f32[&(h - 2)]);
                }
                Solver::Jacobi { tolerance, max_iterations } => {
                    sc.build_rhs(w, h, guidance);
                    stats.iterations = sc.solve_iterative(w, h, tolerance, max_iterations, None, stop, &mut stats);
                }
                Solver::Sor { tolerance, max_iterations } => {
                    sc.build_rhs(w, h, guidance);
                    let n = (w - 2).max(h - 2) as f64;
                    let omega = 2.0 / (1.0 + (std::f64::consts::PI / (n + 1.0)).sin());
                    let it = sc.solve_iterative(w, h, tolerance, max_iterations, Some(omega), stop, &mut stats);
                    stats.iterations = it;
                }
            }
            sc.stats = stats;
        });
        let mut stats = FusionStats { regions, ..FusionStats::default() };
        for (rect, sc) in self.rects.iter().zip(&self.scratch) {
            let (w, h) = (rect.width(), rect.height());
            let r = &sc.stats;
            stats.unknowns += r.unknowns;
            stats.iterations = stats.iterations.max(r.iterations);
            stats.over_budget += r.over_budget;
            stats.stopped |= r.stopped;
            // each row of the region (its interior's, in the solved modes) from the buffers' row y
            let (nx, bg) = (w.saturating_sub(2), &sc.bg);
            if !solved {
                store(frame, *rect, 0, |y, out| {
                    for ((o, &b), &u) in out.iter_mut().zip(&bg[y * w..][..w]).zip(&sc.u[y * w..][..w]) {
                        *o = (b + u) as f32;
                    }
                });
            } else if w >= 3 && h >= 3 {
                match solver {
                    Solver::DirectF32 => store(frame, *rect, 1, |y, out| {
                        let d = &sc.single.work[(y - 1) * nx..][..nx];
                        for ((o, &b), &d) in out.iter_mut().zip(&bg[y * w + 1..][..nx]).zip(d) {
                            *o = (b + f64::from(d)) as f32;
                        }
                    }),
                    // the solution: the direct solve's on the interior's layout, the iterative ones' on the region's
                    _ => store(frame, *rect, 1, |y, out| {
                        let start = if solver == Solver::Direct { (y - 1) * nx } else { y * w + 1 };
                        for (o, &v) in out.iter_mut().zip(&sc.work[start..][..nx]) {
                            *o = v as f32;
                        }
                    }),
                }
            }
        }
        stats
    }

    /// Clips the patches' rectangles to the frame and merges touching ones until none touch.
    fn merge_regions(&mut self, patches: &[Patch<'_>], width: usize, height: usize) {
        self.rects.clear();
        for p in patches {
            let r = PixelRect { x0: p.rect.x0, y0: p.rect.y0, x1: p.rect.x1.min(width), y1: p.rect.y1.min(height) };
            if !r.is_empty() {
                self.rects.push(r);
            }
        }
        // Merge touching regions, then grow each so that its DST length n has a smooth n + 1 (fast FFT sizes);
        // growing can make regions touch again, so repeat until nothing changes.
        loop {
            let mut merged = true;
            while merged {
                merged = false;
                'outer: for i in 0..self.rects.len() {
                    for j in i + 1..self.rects.len() {
                        if self.rects[i].touches(&self.rects[j]) {
                            self.rects[i] = self.rects[i].union(&self.rects[j]);
                            self.rects.swap_remove(j);
                            merged = true;
                            break 'outer;
                        }
                    }
                }
            }
            let mut grown = false;
            for r in &mut self.rects {
                let g = grow_to_fast_size(*r, width, height);
                grown |= g != *r;
                *r = g;
            }
            if !grown {
                break;
            }
        }
    }

    /// Solves `(4I − adjacency) x = rhs` on an `nx × ny` grid with zero Dirichlet boundary, in place, in f64: the
    /// direct solver that [`PoissonFusion::fuse`] uses, exposed for checks and other drivers.
    ///
    /// # Panics
    /// If `rhs.len() != nx·ny`.
    pub fn solve_dirichlet(&mut self, nx: usize, ny: usize, rhs: &mut [f64]) {
        assert_eq!(rhs.len(), nx * ny, "right-hand side length");
        if rhs.is_empty() {
            return;
        }
        let (dst_x, dst_y) = (self.plans.get(nx), self.plans.get(ny));
        let sc = &mut self.scratch[0];
        sc.reserve(rhs.len());
        sc.work[..rhs.len()].copy_from_slice(rhs);
        sc.solve_direct(&dst_x, &dst_y);
        rhs.copy_from_slice(&sc.work[..rhs.len()]);
    }
}

impl Scratch {
    fn reserve(&mut self, area: usize) {
        for b in [&mut self.u, &mut self.bg, &mut self.work, &mut self.work2] {
            fit(b, area);
        }
    }

    /// Loads the background and the summed guidance patch on `rect`.
    #[inline(always)]
    fn load_region(&mut self, frame: &Frame, rect: PixelRect, patches: &[Patch<'_>]) {
        let (w, h) = (rect.width(), rect.height());
        self.reserve(w * h);
        let fw = frame.width();
        let px = frame.pixels();
        for (y, bg) in self.bg[..w * h].chunks_exact_mut(w).enumerate() {
            let start = (rect.y0 + y) * fw + rect.x0;
            for (b, &p) in bg.iter_mut().zip(&px[start..start + w]) {
                *b = f64::from(p);
            }
        }
        self.u[..w * h].fill(0.0);
        for p in patches {
            let pr = p.rect;
            let (x0, x1) = (pr.x0.max(rect.x0), pr.x1.min(rect.x1));
            if x0 >= x1 {
                continue;
            }
            // the patch's part of each row, added as a slice (the same sums, pixel by pixel)
            for y in pr.y0.max(rect.y0)..pr.y1.min(rect.y1) {
                let to = &mut self.u[(y - rect.y0) * w..][x0 - rect.x0..x1 - rect.x0];
                let from = &p.values[(y - pr.y0) * pr.width()..][x0 - pr.x0..x1 - pr.x0];
                for (u, &v) in to.iter_mut().zip(from) {
                    *u += f64::from(v);
                }
            }
        }
    }

    /// Right-hand side on the interior: guidance divergence plus the Dirichlet ring, into `work`
    /// (interior layout `(w−2) × (h−2)`), and the guidance part alone into `work2` (region layout).
    #[inline(always)]
    fn build_rhs(&mut self, w: usize, h: usize, guidance: Guidance) {
        if guidance == Guidance::Mixed {
            return self.build_rhs_per_pixel(w, h, true);
        }
        for y in 1..h - 1 {
            let (top, bottom) = (y == 1, y == h - 2);
            match (top, bottom) {
                (false, false) => self.rhs_row::<false, false>(w, y),
                (true, false) => self.rhs_row::<true, false>(w, y),
                (false, true) => self.rhs_row::<false, true>(w, y),
                (true, true) => self.rhs_row::<true, true>(w, y),
            }
        }
    }

    /// [`Scratch::build_rhs`] pixel by pixel through [`guidance_sum`]: the mixed guidance's (`mixed`), and the
    /// normal one's as [`Scratch::rhs_row`] gives it row by row.
    fn build_rhs_per_pixel(&mut self, w: usize, h: usize, mixed: bool) {
        let nx = w - 2;
        let (u, bg) = (&self.u, &self.bg);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let p = y * w + x;
                let b = guidance_sum(u, bg, p, w, mixed);
                // known boundary neighbours move to the right-hand side
                let mut ring = 0.0;
                if x == 1 {
                    ring += bg[p - 1];
                }
                if x == w - 2 {
                    ring += bg[p + 1];
                }
                if y == 1 {
                    ring += bg[p - w];
                }
                if y == h - 2 {
                    ring += bg[p + w];
                }
                self.work2[p] = b;
                self.work[(y - 1) * nx + (x - 1)] = b + ring;
            }
        }
    }

    /// Row `y` of [`Scratch::build_rhs`] with the normal guidance (`TOP`: `y` is the first interior row,
    /// `BOTTOM` the last): the same f64 operations in the same order, written over the row's slices so that they
    /// vectorize.
    #[inline(always)]
    fn rhs_row<const TOP: bool, const BOTTOM: bool>(&mut self, w: usize, y: usize) {
        let nx = w - 2;
        let (u, bg) = (&self.u, &self.bg);
        let row = y * w;
        // the interior's pixels p = row + 1 ..= row + nx, and their neighbours as slices of the same length
        let (up, left, centre) = (&u[row + 1 - w..][..nx], &u[row..][..nx], &u[row + 1..][..nx]);
        let (right, down) = (&u[row + 2..][..nx], &u[row + 1 + w..][..nx]);
        let (bg_up, bg_down) = (&bg[row + 1 - w..][..nx], &bg[row + 1 + w..][..nx]);
        let out = &mut self.work[(y - 1) * nx..y * nx];
        let guide = &mut self.work2[row + 1..row + 1 + nx];
        // pixel k's guidance sum and right-hand side; `first` and `last`: k is the row's first or last pixel
        let at = |k: usize, first: bool, last: bool| {
            let p = centre[k];
            // guidance_sum's order: left, right, up, down neighbours
            let b = 0.0 + (p - left[k]) + (p - right[k]) + (p - up[k]) + (p - down[k]);
            // the ring's order: left, right, top, bottom
            let mut ring = 0.0;
            if first {
                ring += bg[row];
            }
            if last {
                ring += bg[row + w - 1];
            }
            if TOP {
                ring += bg_up[k];
            }
            if BOTTOM {
                ring += bg_down[k];
            }
            (b, b + ring)
        };
        // the two ends, then the pixels between them in a loop without their tests (so that it vectorizes)
        (guide[0], out[0]) = at(0, true, nx == 1);
        if nx > 1 {
            (guide[nx - 1], out[nx - 1]) = at(nx - 1, false, true);
        }
        for k in 1..nx.saturating_sub(1) {
            (guide[k], out[k]) = at(k, false, false);
        }
    }

    /// The right-hand side of [`Solver::DirectF32`]'s difference `d = f − f*` on the interior, into
    /// `single.work` (interior layout): the guidance sum less the background's own, `Σ_q v_pq − Σ_q (f*_p − f*_q)`,
    /// formed in f64 and then rounded (the ring's values drop out: `d` is zero on it). The buffers are sized for
    /// the region ([`PoissonFusion::size_buffers`]).
    #[inline(always)]
    fn build_difference_rhs(&mut self, w: usize, h: usize, guidance: Guidance) {
        let nx = w - 2;
        let (u, bg) = (&self.u, &self.bg);
        for (y, out) in (1..h - 1).zip(self.single.work[..nx * (h - 2)].chunks_exact_mut(nx)) {
            let row = y * w;
            if guidance == Guidance::Mixed {
                for (k, o) in out.iter_mut().enumerate() {
                    let p = row + 1 + k;
                    *o = (guidance_sum(u, bg, p, w, true) - guidance_sum(bg, bg, p, w, false)) as f32;
                }
                continue;
            }
            // the normal guidance's less the background's, over the difference e = u − f*: Σ_q (e_p − e_q), over
            // the row's slices so that it vectorizes
            fn window(v: &[f64], start: usize, n: usize) -> &[f64] {
                &v[start..][..n]
            }
            let at = |v, start| window(v, start, nx);
            let (uc, ul, ur, uu, ud) =
                (at(u, row + 1), at(u, row), at(u, row + 2), at(u, row + 1 - w), at(u, row + 1 + w));
            let (bc, bl, br, bu, bd) =
                (at(bg, row + 1), at(bg, row), at(bg, row + 2), at(bg, row + 1 - w), at(bg, row + 1 + w));
            for (k, o) in out.iter_mut().enumerate() {
                let e = uc[k] - bc[k];
                let sum = (e - (ul[k] - bl[k])) + (e - (ur[k] - br[k])) + (e - (uu[k] - bu[k])) + (e - (ud[k] - bd[k]));
                *o = sum as f32;
            }
        }
    }

    /// [`solve_sine`] on `work`, with `work2` as its transpose.
    fn solve_direct(&mut self, dst_x: &Dst1<f64>, dst_y: &Dst1<f64>) {
        solve_sine(&mut self.work, &mut self.work2, &mut self.fft_buf, &mut self.fft_scratch, dst_x, dst_y);
    }

    /// Jacobi (eq 20, `omega = None`) or red-black SOR on the whole region layout, starting from the
    /// background; the solution is left in `work` (region layout). Returns the sweeps used.
    #[allow(clippy::too_many_arguments)]
    fn solve_iterative(
        &mut self,
        w: usize,
        h: usize,
        tolerance: f64,
        max_iterations: u32,
        omega: Option<f64>,
        stop: Option<&AtomicBool>,
        stats: &mut FusionStats,
    ) -> u32 {
        let area = w * h;
        let unknowns = ((w - 2) * (h - 2)).max(1) as u64;
        let budget = (MAX_SWEEP_UPDATES / unknowns).clamp(1, u64::from(u32::MAX)) as u32;
        let max_iterations = if max_iterations > budget {
            stats.over_budget += 1;
            budget
        } else {
            max_iterations
        };
        let (f, next, bg, guide) = (&mut self.work, &mut self.next, &self.bg, &self.work2);
        if next.len() < area {
            next.resize(area, 0.0);
        }
        f[..area].copy_from_slice(&bg[..area]);
        next[..area].copy_from_slice(&bg[..area]);
        for it in 1..=max_iterations {
            if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
                stats.stopped = true;
                return it - 1;
            }
            let mut max_change: f64 = 0.0;
            match omega {
                None => {
                    for y in 1..h - 1 {
                        for x in 1..w - 1 {
                            let p = y * w + x;
                            // eq 20: f = ¼(Σ neighbours − Δu); here −Δu is the guidance sum
                            let v = 0.25 * (f[p - 1] + f[p + 1] + f[p - w] + f[p + w] + guide[p]);
                            max_change = max_change.max((v - f[p]).abs());
                            next[p] = v;
                        }
                    }
                    std::mem::swap(f, next);
                }
                Some(omega) => {
                    for colour in 0..2 {
                        for y in 1..h - 1 {
                            let start = 1 + (y + 1 + colour) % 2;
                            for x in (start..w - 1).step_by(2) {
                                let p = y * w + x;
                                let gs = 0.25 * (f[p - 1] + f[p + 1] + f[p - w] + f[p + w] + guide[p]);
                                let v = f[p] + omega * (gs - f[p]);
                                max_change = max_change.max((v - f[p]).abs());
                                f[p] = v;
                            }
                        }
                    }
                }
            }
            if max_change < tolerance {
                return it;
            }
        }
        max_iterations
    }
}

/// Solves `(4I − adjacency) x = work` on an `nx × ny` grid with zero Dirichlet boundary (`nx`, `ny` the lengths
/// of `dst_x` and `dst_y`), in place in `work`'s first `nx·ny` values, with `tmp` as the transpose and `buf`
/// and `scratch` grown to the transforms' needs.
fn solve_sine<T: Real>(
    work: &mut [T],
    tmp: &mut [T],
    buf: &mut Vec<Complex<T>>,
    scratch: &mut Vec<Complex<T>>,
    dst_x: &Dst1<T>,
    dst_y: &Dst1<T>,
) {
    let (nx, ny) = (dst_x.n, dst_y.n);
    for d in [dst_x, dst_y] {
        fit(buf, d.buffer_len());
        fit(scratch, d.fft.get_inplace_scratch_len());
    }
    let n = nx * ny;
    let (work, tmp) = (&mut work[..n], &mut tmp[..n]);
    let (sx, sy) = (dst_x.fft.get_inplace_scratch_len(), dst_y.fft.get_inplace_scratch_len());
    // rows: DST along x
    dst_x.process_rows(work, buf, &mut scratch[..sx], None);
    transpose(work, tmp, nx, ny);
    // along y, dividing between the two transforms by the eigenvalues λ = (2 − 2cos θx) + (2 − 2cos θy); tmp is
    // ny-fast: row kx, index ky
    let scale = T::of(4.0 / ((nx + 1) * (ny + 1)) as f64);
    let divide = |kx: usize, row: &mut [T]| {
        let lx = dst_x.eigen[kx];
        for (v, &ly) in row.iter_mut().zip(&dst_y.eigen) {
            *v *= scale / (lx + ly);
        }
    };
    dst_y.process_rows(tmp, buf, &mut scratch[..sy], Some(&divide));
    transpose(tmp, work, ny, nx);
    dst_x.process_rows(work, buf, &mut scratch[..sx], None);
}

/// True if `n` is `2^a·3^b`: FFT lengths `2n` that rustfft runs fastest.
fn is_smooth(mut n: usize) -> bool {
    if n == 0 {
        return false;
    }
    for p in [2, 3] {
        while n.is_multiple_of(p) {
            n /= p;
        }
    }
    n == 1
}

/// Grows `rect` (within the frame) until each side's interior length `n = side − 2` has `n + 1 = 2^a·3^b`,
/// adding columns alternately right and left (rows down and up). A side that cannot grow stays as it is.
fn grow_to_fast_size(rect: PixelRect, width: usize, height: usize) -> PixelRect {
    let grow = |mut lo: usize, mut hi: usize, max: usize| {
        let mut right = true;
        while hi - lo >= 3 && !is_smooth(hi - lo - 1) {
            if right && hi < max {
                hi += 1;
            } else if lo > 0 {
                lo -= 1;
            } else if hi < max {
                hi += 1;
            } else {
                break;
            }
            right = !right;
        }
        (lo, hi)
    };
    let (x0, x1) = grow(rect.x0, rect.x1, width);
    let (y0, y1) = grow(rect.y0, rect.y1, height);
    PixelRect { x0, y0, x1, y1 }
}

/// Writes `frame` on `rect`, skipping a ring of `margin` pixels: `fill(y, row)` fills the part of the region's
/// row `y` inside the ring. Run inside [`crate::physics::simd::widest`], so that `fill`'s loops (inlined)
/// vectorize as wide as the CPU allows.
fn store(frame: &mut Frame, rect: PixelRect, margin: usize, fill: impl Fn(usize, &mut [f32])) {
    let (w, h) = (rect.width(), rect.height());
    let fw = frame.width();
    let px = frame.pixels_mut();
    crate::physics::simd::widest(
        #[inline(always)]
        || {
            for y in margin..h - margin {
                let start = (rect.y0 + y) * fw + rect.x0;
                fill(y, &mut px[start + margin..start + w - margin]);
            }
        },
    );
}

/// `dst` (`cols × rows`, row-major) = the transpose of `src` (`rows × cols`), in tiles of 8 × 8 (with AVX2, of
/// 4 × 4 blocks moved through vector registers: the fusion stage of the 256 × 256 bench case with 8 targets took
/// 78–81 µs a frame against 89–92 value by value, `draft`, four interleaved rounds on an AMD EPYC), on this thread:
/// regions are solved side by side in the pool, and the parallel [`super::fft2d::transpose_into`] in its place
/// was no faster (the fusion stage 16–21 against 12–17 µs a frame for one 33 × 33 region, three interleaved
/// rounds on an AMD EPYC). Nor was a large region cut into bands of rows transposed in parallel: the fusion stage
/// of the 256 × 256 bench case with 8 targets (one region of up to 256 × 73) took 109–112 against 94–96 µs a
/// frame.
fn transpose<T: Real>(src: &[T], dst: &mut [T], cols: usize, rows: usize) {
    assert!(src.len() >= rows * cols && dst.len() >= rows * cols, "buffers of the region's size");
    #[cfg(target_arch = "x86_64")]
    if avx2() {
        // SAFETY: the CPU has AVX2; the lengths are checked above
        return unsafe { T::transpose_avx2(src, dst, cols, rows) };
    }
    transpose_tiles(src, dst, cols, rows, (0..rows, 0..cols));
}

/// [`transpose`] of the part of `src` in rows `part.0` and columns `part.1`, in 8 × 8 tiles, one value at a time.
fn transpose_tiles<T: Copy>(src: &[T], dst: &mut [T], cols: usize, rows: usize, part: (Range<usize>, Range<usize>)) {
    const TILE: usize = 8;
    let (row_part, col_part) = part;
    for r0 in row_part.clone().step_by(TILE) {
        for c0 in col_part.clone().step_by(TILE) {
            for r in r0..(r0 + TILE).min(row_part.end) {
                for c in c0..(c0 + TILE).min(col_part.end) {
                    dst[c * rows + r] = src[r * cols + c];
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    /// [`super::transpose`] in 4 × 4 blocks of AVX2 registers (two unpacks and two lane permutes a block), in
    /// 8 × 8 tiles; the rows and columns past the last whole block one value at a time.
    ///
    /// # Safety
    /// The CPU must have AVX2, and `src` and `dst` must hold `rows · cols` values.
    #[target_feature(enable = "avx2")]
    pub unsafe fn transpose_avx2(src: &[f64], dst: &mut [f64], cols: usize, rows: usize) {
        let (rows4, cols4) = (rows / 4 * 4, cols / 4 * 4);
        let (s, d) = (src.as_ptr(), dst.as_mut_ptr());
        for r0 in (0..rows4).step_by(8) {
            for c0 in (0..cols4).step_by(8) {
                for r in (r0..(r0 + 8).min(rows4)).step_by(4) {
                    for c in (c0..(c0 + 8).min(cols4)).step_by(4) {
                        // SAFETY: rows r … r + 3 and columns c … c + 3 are inside both buffers (r + 3 < rows,
                        // c + 3 < cols, and the caller's lengths)
                        unsafe {
                            let at = |k: usize| _mm256_loadu_pd(s.add((r + k) * cols + c));
                            let (a, b, e, f) = (at(0), at(1), at(2), at(3));
                            let (lo_ab, hi_ab) = (_mm256_unpacklo_pd(a, b), _mm256_unpackhi_pd(a, b));
                            let (lo_ef, hi_ef) = (_mm256_unpacklo_pd(e, f), _mm256_unpackhi_pd(e, f));
                            _mm256_storeu_pd(d.add(c * rows + r), _mm256_permute2f128_pd::<0x20>(lo_ab, lo_ef));
                            _mm256_storeu_pd(d.add((c + 1) * rows + r), _mm256_permute2f128_pd::<0x20>(hi_ab, hi_ef));
                            _mm256_storeu_pd(d.add((c + 2) * rows + r), _mm256_permute2f128_pd::<0x31>(lo_ab, lo_ef));
                            _mm256_storeu_pd(d.add((c + 3) * rows + r), _mm256_permute2f128_pd::<0x31>(hi_ab, hi_ef));
                        }
                    }
                }
            }
        }
        // the columns past the last block, in the rows of whole blocks; then the rows past them, every column
        super::transpose_tiles(src, dst, cols, rows, (0..rows4, cols4..cols));
        super::transpose_tiles(src, dst, cols, rows, (rows4..rows, 0..cols));
    }

    /// [`super::transpose`] of f32 values in 8 × 8 blocks of AVX2 registers (unpacks, shuffles and lane
    /// permutes); the rows and columns past the last whole block one value at a time.
    ///
    /// # Safety
    /// The CPU must have AVX2, and `src` and `dst` must hold `rows · cols` values.
    #[target_feature(enable = "avx2")]
    pub unsafe fn transpose_avx2_f32(src: &[f32], dst: &mut [f32], cols: usize, rows: usize) {
        let (rows8, cols8) = (rows / 8 * 8, cols / 8 * 8);
        let (s, d) = (src.as_ptr(), dst.as_mut_ptr());
        for r in (0..rows8).step_by(8) {
            for c in (0..cols8).step_by(8) {
                // SAFETY: rows r … r + 7 and columns c … c + 7 are inside both buffers (r + 7 < rows,
                // c + 7 < cols, and the caller's lengths)
                unsafe {
                    let at = |k: usize| _mm256_loadu_ps(s.add((r + k) * cols + c));
                    // pairs of rows interleaved, then quarters of columns gathered: column j's first four rows in
                    // q[j % 4], its last four in q[j % 4 + 4], in their 128-bit half j / 4
                    let t = [0, 2, 4, 6]
                        .map(|k| (_mm256_unpacklo_ps(at(k), at(k + 1)), _mm256_unpackhi_ps(at(k), at(k + 1))));
                    let q = [
                        _mm256_shuffle_ps::<0x44>(t[0].0, t[1].0),
                        _mm256_shuffle_ps::<0xEE>(t[0].0, t[1].0),
                        _mm256_shuffle_ps::<0x44>(t[0].1, t[1].1),
                        _mm256_shuffle_ps::<0xEE>(t[0].1, t[1].1),
                        _mm256_shuffle_ps::<0x44>(t[2].0, t[3].0),
                        _mm256_shuffle_ps::<0xEE>(t[2].0, t[3].0),
                        _mm256_shuffle_ps::<0x44>(t[2].1, t[3].1),
                        _mm256_shuffle_ps::<0xEE>(t[2].1, t[3].1),
                    ];
                    for j in 0..4 {
                        _mm256_storeu_ps(d.add((c + j) * rows + r), _mm256_permute2f128_ps::<0x20>(q[j], q[j + 4]));
                        _mm256_storeu_ps(d.add((c + j + 4) * rows + r), _mm256_permute2f128_ps::<0x31>(q[j], q[j + 4]));
                    }
                }
            }
        }
        super::transpose_tiles(src, dst, cols, rows, (0..rows8, cols8..cols));
        super::transpose_tiles(src, dst, cols, rows, (rows8..rows, 0..cols));
    }

    /// Eight complex values at `p` as their real and imaginary parts.
    ///
    /// # Safety
    /// AVX2, and 16 f32 values readable at `p`.
    #[target_feature(enable = "avx2")]
    unsafe fn load_complex(p: *const f32) -> (__m256, __m256) {
        // SAFETY: the caller's
        let (x0, x1) = unsafe { (_mm256_loadu_ps(p), _mm256_loadu_ps(p.add(8))) };
        // per lane: re 0 1 4 5 | 2 3 6 7, then the 64-bit pairs put in order
        let order = |v: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0xD8>(_mm256_castps_pd(v)));
        (order(_mm256_shuffle_ps::<0x88>(x0, x1)), order(_mm256_shuffle_ps::<0xDD>(x0, x1)))
    }

    /// `first` and `second` interleaved, `first[0], second[0], first[1], …`, into the 16 f32 values at `p`.
    ///
    /// # Safety
    /// AVX2, and 16 f32 values writable at `p`.
    #[target_feature(enable = "avx2")]
    unsafe fn store_interleaved(p: *mut f32, first: __m256, second: __m256) {
        let (lo, hi) = (_mm256_unpacklo_ps(first, second), _mm256_unpackhi_ps(first, second));
        // SAFETY: the caller's
        unsafe {
            _mm256_storeu_ps(p, _mm256_permute2f128_ps::<0x20>(lo, hi));
            _mm256_storeu_ps(p.add(8), _mm256_permute2f128_ps::<0x31>(lo, hi));
        }
    }

    /// `v`'s eight values in reverse order.
    #[target_feature(enable = "avx2")]
    fn reversed(v: __m256) -> __m256 {
        _mm256_permutevar8x32_ps(v, _mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0))
    }

    /// [`super::Real::pair_in`] for f32 in blocks of eight.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn pair_in_f32(
        sines: &[f32],
        rows: [&[f32]; 4],
        low: &mut [super::Complex<f32>],
        high: &mut [super::Complex<f32>],
    ) -> usize {
        let m = low.len();
        assert!(high.len() == m && sines.len() >= m && rows.iter().all(|r| r.len() == m), "halves of m values");
        let [al, ah, bl, bh] = rows.map(<[f32]>::as_ptr);
        let (lo, hi) = (low.as_mut_ptr().cast::<f32>(), high.as_mut_ptr().cast::<f32>());
        let half = _mm256_set1_ps(0.5);
        for c in 0..m / 8 {
            // values k0 … k0 + 7 of the low halves, and their mirror images r = m − 1 − k: the high halves'
            // r0 … r0 + 7, reversed
            let (k0, r0) = (8 * c, m - 8 * (c + 1));
            // SAFETY: k0 + 7 and r0 + 7 are below m, the length of every slice (a complex value is two f32)
            unsafe {
                let s = _mm256_loadu_ps(sines.as_ptr().add(k0));
                let y = |low: *const f32, high: *const f32| {
                    let (f, mirror) = (_mm256_loadu_ps(low.add(k0)), reversed(_mm256_loadu_ps(high.add(r0))));
                    (_mm256_mul_ps(s, _mm256_add_ps(f, mirror)), _mm256_mul_ps(half, _mm256_sub_ps(f, mirror)))
                };
                let ((sa, da), (sb, db)) = (y(al, ah), y(bl, bh));
                store_interleaved(lo.add(2 * k0), _mm256_add_ps(sa, da), _mm256_add_ps(sb, db));
                store_interleaved(hi.add(2 * r0), reversed(_mm256_sub_ps(sa, da)), reversed(_mm256_sub_ps(sb, db)));
            }
        }
        m / 8 * 8
    }

    /// [`super::Real::pair_out`] for f32 in blocks of eight.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn pair_out_f32(z: [&[super::Complex<f32>]; 2], whole: usize, a: &mut [f32], b: &mut [f32]) -> usize {
        let [z_low, z_high] = z;
        let m = z_low.len();
        assert!(z_high.len() == m && whole <= m && a.len().min(b.len()) >= 2 * whole, "halves of m values");
        let (zl, zh) = (z_low.as_ptr().cast::<f32>(), z_high.as_ptr().cast::<f32>());
        let (pa, pb) = (a.as_mut_ptr(), b.as_mut_ptr());
        let half = _mm256_set1_ps(0.5);
        for c in 0..whole / 8 {
            // Z_k for k0 … k0 + 7, and Z_{N−k}: z_high's m − 8 − k0 … m − 1 − k0, reversed
            let k0 = 8 * c;
            // SAFETY: k0 + 7 < whole ≤ m, so both blocks of z are inside it, and a and b hold 2·whole values
            unsafe {
                let (zkr, zki) = load_complex(zl.add(2 * k0));
                let (zmr, zmi) = load_complex(zh.add(2 * (m - 8 - k0)));
                let (zmr, zmi) = (reversed(zmr), reversed(zmi));
                let (even_a, step_a) = (_mm256_sub_ps(zmi, zki), _mm256_add_ps(zkr, zmr));
                let (even_b, step_b) = (_mm256_sub_ps(zkr, zmr), _mm256_add_ps(zki, zmi));
                let h = |v| _mm256_mul_ps(half, v);
                store_interleaved(pa.add(2 * k0), h(even_a), h(step_a));
                store_interleaved(pb.add(2 * k0), h(even_b), h(step_b));
            }
        }
        whole / 8 * 8
    }
}

/// `Σ_q v_pq` over the 4-neighbours `q` of region-layout index `p` (row width `w`): the patch's differences
/// `u_p − u_q`, or with `mixed` per edge whichever of those and the background's is larger in magnitude.
#[inline]
fn guidance_sum(u: &[f64], bg: &[f64], p: usize, w: usize, mixed: bool) -> f64 {
    let mut sum = 0.0;
    for q in [p - 1, p + 1, p - w, p + w] {
        let gu = u[p] - u[q];
        let gb = bg[p] - bg[q];
        sum += if mixed && gb.abs() > gu.abs() { gb } else { gu };
    }
    sum
}

/// Largest residual `|4f_p − Σ_q f_q − Σ_q v_pq|` of the fused equation on the interior of `rect`, for
/// `guidance` (not additive), with patch `u` and the background `bg` (both region layout, f64).
pub fn max_residual(fused: &Frame, rect: PixelRect, u: &[f64], bg: &[f64], guidance: Guidance) -> f64 {
    let w = rect.width();
    let at = |x: usize, y: usize| f64::from(fused.get(rect.x0 + x, rect.y0 + y));
    let mut worst: f64 = 0.0;
    for y in 1..rect.height() - 1 {
        for x in 1..w - 1 {
            let p = y * w + x;
            let v = guidance_sum(u, bg, p, w, guidance == Guidance::Mixed);
            let lap = 4.0 * at(x, y) - at(x - 1, y) - at(x + 1, y) - at(x, y - 1) - at(x, y + 1);
            worst = worst.max((lap - v).abs());
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The transform by its definition, summed in f64.
    fn dst1_by_definition(x: &[f64]) -> Vec<f64> {
        let n = x.len();
        let c = std::f64::consts::PI / (n + 1) as f64;
        // the sine's argument reduced to [0, 2π) first, so that the sum is accurate to a few ulps
        let angle = |j: usize, k: usize| c * (((j + 1) * (k + 1)) % (2 * (n + 1))) as f64;
        (0..n).map(|k| x.iter().enumerate().map(|(j, &v)| v * angle(j, k).sin()).sum()).collect()
    }

    #[test]
    fn the_transpose_is_the_transpose_at_every_simd_level_and_shape() {
        for (rows, cols) in [(1, 1), (1, 9), (9, 1), (3, 7), (4, 4), (5, 4), (4, 5), (9, 17), (71, 254), (254, 71)] {
            let src: Vec<f64> = (0..rows * cols).map(|i| i as f64 + 0.5).collect();
            let check = |dst: &[f64], what: &str| {
                for r in 0..rows {
                    for c in 0..cols {
                        assert_eq!(dst[c * rows + r], src[r * cols + c], "{what}: {rows} × {cols}, ({r}, {c})");
                    }
                }
            };
            let mut dst = vec![-1.0; rows * cols];
            transpose(&src, &mut dst, cols, rows);
            check(&dst, "dispatched");
            let mut dst = vec![-1.0; rows * cols];
            transpose_tiles(&src, &mut dst, cols, rows, (0..rows, 0..cols));
            check(&dst, "tiles");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut dst = vec![-1.0; rows * cols];
                // SAFETY: the CPU has AVX2; both buffers hold rows · cols values
                unsafe { x86::transpose_avx2(&src, &mut dst, cols, rows) };
                check(&dst, "avx2");
            }
            // f32, whose vector transpose moves 8 × 8 blocks
            let src32: Vec<f32> = src.iter().map(|&v| v as f32).collect();
            let check32 = |dst: &[f32], what: &str| {
                let wide: Vec<f64> = dst.iter().map(|&v| f64::from(v)).collect();
                check(&wide, what);
            };
            let mut dst = vec![-1.0; rows * cols];
            transpose(&src32, &mut dst, cols, rows);
            check32(&dst, "f32, dispatched");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut dst = vec![-1.0; rows * cols];
                // SAFETY: the CPU has AVX2; both buffers hold rows · cols values
                unsafe { x86::transpose_avx2_f32(&src32, &mut dst, cols, rows) };
                check32(&dst, "f32, avx2");
            }
        }
    }

    /// [`Real::pair_in`] for f32, or its AVX2 kernel.
    type PairIn = fn(&[f32], [&[f32]; 4], &mut [Complex<f32>], &mut [Complex<f32>]) -> usize;
    /// [`Real::pair_out`] for f32, or its AVX2 kernel.
    type PairOut = fn([&[Complex<f32>]; 2], usize, &mut [f32], &mut [f32]) -> usize;

    #[test]
    fn the_vector_loops_around_the_f32_transform_are_the_scalar_ones_bit_for_bit() {
        let zero = Complex::new(0.0f32, 0.0);
        for m in [1usize, 7, 8, 9, 15, 16, 17, 35, 71, 127] {
            // four rows unlike each other and their mirror images, of mixed signs and magnitudes
            let rows: Vec<Vec<f32>> = (0..4)
                .map(|r| {
                    (0..m).map(|j| (((j * 37 + r * 11) % 17) as f32 - 8.3) * (1.0 + (j % 5) as f32 * 0.71)).collect()
                })
                .collect();
            let rows = [&rows[0][..], &rows[1][..], &rows[2][..], &rows[3][..]];
            let sines: Vec<f32> = (0..m).map(|k| ((k + 1) as f32 * 0.093).sin()).collect();
            let bits = |v: &[Complex<f32>]| v.iter().map(|z| (z.re.to_bits(), z.im.to_bits())).collect::<Vec<_>>();
            let (mut low, mut high) = (vec![zero; m], vec![zero; m]);
            pair_in_from(0, &sines, rows, &mut low, &mut high);
            // the dispatched loop (AVX2 where IRSIM_SIMD allows it), and the AVX2 one where the CPU has it
            let mut vector_ins: Vec<(&str, PairIn)> = vec![("dispatched", <f32 as Real>::pair_in)];
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2
                vector_ins.push(("avx2", |s, r, l, h| unsafe { x86::pair_in_f32(s, r, l, h) }));
            }
            for (what, pair_in) in vector_ins {
                let (mut vlow, mut vhigh) = (vec![zero; m], vec![zero; m]);
                let done = pair_in(&sines, rows, &mut vlow, &mut vhigh);
                pair_in_from(done, &sines, rows, &mut vlow, &mut vhigh);
                assert_eq!((bits(&vlow), bits(&vhigh)), (bits(&low), bits(&high)), "{what}, before the FFT, m = {m}");
                if what == "avx2" {
                    assert_eq!(done, m / 8 * 8, "the vector loop ran");
                }
            }
            // the same values standing in for an FFT's, with either count of whole outputs
            for whole in [m, m - 1] {
                let z = [&low[..], &high[..]];
                let (mut a, mut b) = (vec![0.0f32; 2 * whole], vec![0.0f32; 2 * whole]);
                pair_out_from(0, z, &mut a, &mut b);
                let mut vector_outs: Vec<(&str, PairOut)> = vec![("dispatched", <f32 as Real>::pair_out)];
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU has AVX2
                    vector_outs.push(("avx2", |z, w, a, b| unsafe { x86::pair_out_f32(z, w, a, b) }));
                }
                for (what, pair_out) in vector_outs {
                    let (mut va, mut vb) = (vec![0.0f32; 2 * whole], vec![0.0f32; 2 * whole]);
                    let done = pair_out(z, whole, &mut va, &mut vb);
                    pair_out_from(done, z, &mut va, &mut vb);
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!((bits(&va), bits(&vb)), (bits(&a), bits(&b)), "{what}, after the FFT, m = {m}, {whole}");
                    if what == "avx2" {
                        assert_eq!(done, whole / 8 * 8, "the vector loop ran");
                    }
                }
            }
        }
    }

    #[test]
    fn the_f32_solve_of_the_difference_is_the_f64_solve_within_four_hundredths_of_a_gray_level() {
        // a bright, steep, textured sky (15 000 … 60 000 DN) and a target 20 000 DN above it; a region 193 × 97
        // (transform lengths 191 and 95, neither smooth) and one as wide as the frame
        let (w, h) = (240, 140);
        let bg: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                15_000.0 + 180.0 * x + 12.0 * y + ((i as u32).wrapping_mul(2_654_435_761) >> 24) as f32
            })
            .collect();
        for rect in [PixelRect { x0: 20, y0: 20, x1: 213, y1: 117 }, PixelRect { x0: 0, y0: 30, x1: w, y1: 101 }] {
            let (pw, ph) = (rect.width(), rect.height());
            let vals: Vec<f32> = (0..pw * ph)
                .map(|i| {
                    let (x, y) = ((i % pw) as f32 - pw as f32 / 2.0, (i / pw) as f32 - ph as f32 / 2.0);
                    20_000.0 * (-(x * x + 4.0 * y * y) / 200.0).exp()
                })
                .collect();
            for guidance in [Guidance::Normal, Guidance::Mixed] {
                let fuse = |solver| {
                    let mut frame = Frame::from_pixels(w, h, bg.clone());
                    PoissonFusion::new().fuse(&mut frame, &[Patch { rect, values: &vals }], guidance, solver);
                    frame
                };
                let (double, single) = (fuse(Solver::Direct), fuse(Solver::DirectF32));
                let worst = double.pixels().iter().zip(single.pixels()).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                // measured 0.0117 (normal) and 0.0156 DN (mixed), 3 and 4 steps of f32 at these levels (2⁻⁸ DN
                // below 65 536); the bound leaves room for another FFT plan's rounding (rustfft picks its code
                // by the CPU)
                assert!(worst <= 0.04, "{guidance:?} on {rect:?}: {worst} DN apart");
                assert!(double.pixels().iter().zip(&bg).any(|(a, b)| (a - b).abs() > 100.0), "the target is there");
            }
        }
    }

    #[test]
    fn the_sine_transform_is_its_definition_on_rows_of_every_length() {
        let mut planner = FftPlanner::new();
        let lengths = (1..=40).chain([71, 142, 242, 254, 255]);
        let mut planner32 = FftPlanner::new();
        for n in lengths {
            let d = Dst1::new(n, &mut planner);
            let mut buf = vec![Complex::new(0.0, 0.0); d.buffer_len()];
            let mut scratch = vec![Complex::new(0.0, 0.0); d.fft.get_inplace_scratch_len()];
            // two rows unlike each other and unlike their mirror images, and a third on its own
            let rows: Vec<Vec<f64>> = (0..3)
                .map(|r| {
                    (0..n).map(|j| ((j * 37 + r * 11) % 17) as f64 - 8.0 + 0.25 * (j * j) as f64 / n as f64).collect()
                })
                .collect();
            let (mut a, mut b, mut single) = (rows[0].clone(), rows[1].clone(), rows[2].clone());
            d.process_pair(&mut a, Some(&mut b), &mut buf, &mut scratch);
            d.process_pair(&mut single, None, &mut buf, &mut scratch);
            for (got, row) in [(&a, &rows[0]), (&b, &rows[1]), (&single, &rows[2])] {
                let want = dst1_by_definition(row);
                let scale = want.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert!((g - w).abs() <= 1e-14 * scale * n as f64, "n = {n}, output {k}: {g} against {w}");
                }
            }
            // in f32 (the vector loops around its FFT run from n = 16 before it and n = 17 after), to single
            // precision's rounding
            let d = Dst1::<f32>::new(n, &mut planner32);
            let mut buf = vec![Complex::new(0.0, 0.0); d.buffer_len()];
            let mut scratch = vec![Complex::new(0.0, 0.0); d.fft.get_inplace_scratch_len()];
            let rows32: Vec<Vec<f32>> = rows.iter().map(|r| r.iter().map(|&v| v as f32).collect()).collect();
            let (mut a, mut b, mut single) = (rows32[0].clone(), rows32[1].clone(), rows32[2].clone());
            d.process_pair(&mut a, Some(&mut b), &mut buf, &mut scratch);
            d.process_pair(&mut single, None, &mut buf, &mut scratch);
            for (got, row) in [(&a, &rows32[0]), (&b, &rows32[1]), (&single, &rows32[2])] {
                let want = dst1_by_definition(&row.iter().map(|&v| f64::from(v)).collect::<Vec<_>>());
                let scale = want.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                for (k, (&g, w)) in got.iter().zip(&want).enumerate() {
                    let err = (f64::from(g) - w).abs() / scale;
                    assert!(err <= 2e-7 * n as f64, "f32, n = {n}, output {k}: {g} against {w}");
                }
            }
        }
    }

    #[test]
    fn the_right_hand_side_row_by_row_is_the_per_pixel_one_bit_for_bit() {
        // thin and square regions (one interior row or column included), values of both signs and −0
        for (w, h) in [(3, 3), (3, 7), (7, 3), (4, 5), (11, 9)] {
            let value = |i: usize, k: usize| match (i * k + 3 * i) % 11 {
                0 => -0.0,
                m => (m as f64 - 5.0) * 0.37 + (i as f64) * 1e-3,
            };
            let mut a = Scratch::default();
            a.reserve(w * h);
            for i in 0..w * h {
                a.u[i] = value(i, 7);
                a.bg[i] = value(i, 13);
            }
            let mut b = Scratch::default();
            b.reserve(w * h);
            b.u.clone_from(&a.u);
            b.bg.clone_from(&a.bg);
            a.build_rhs(w, h, Guidance::Normal);
            b.build_rhs_per_pixel(w, h, false);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let n = (w - 2) * (h - 2);
            assert_eq!(bits(&a.work[..n]), bits(&b.work[..n]), "{w}×{h}: right-hand side");
            assert_eq!(bits(&a.work2[..w * h]), bits(&b.work2[..w * h]), "{w}×{h}: guidance");
        }
    }

    #[test]
    fn merges_touching_regions() {
        let mut f = PoissonFusion::new();
        let vals = vec![0.0f32; 100];
        let a = Patch { rect: PixelRect { x0: 0, y0: 0, x1: 10, y1: 10 }, values: &vals };
        let b = Patch { rect: PixelRect { x0: 5, y0: 5, x1: 15, y1: 15 }, values: &vals };
        let c = Patch { rect: PixelRect { x0: 40, y0: 40, x1: 50, y1: 50 }, values: &vals };
        f.merge_regions(&[a, b, c], 64, 64);
        assert_eq!(f.rects.len(), 2);
        // 0..15 merged, then grown so that interior length + 1 is 2^a·3^b
        assert!(f.rects.iter().any(|r| r.x0 == 0 && r.y0 == 0 && r.x1 >= 15 && r.y1 >= 15), "{:?}", f.rects);
    }

    #[test]
    fn large_regions_solve_the_same_on_any_number_of_threads() {
        // a 193 × 97 region: its row transforms are shared out in blocks, which must pair rows as one pass does
        let (w, h) = (240, 140);
        let bg: Vec<f32> = (0..w * h).map(|i| 1000.0 + ((i as u32).wrapping_mul(2_654_435_761) >> 22) as f32).collect();
        let rect = PixelRect { x0: 20, y0: 20, x1: 213, y1: 117 };
        let vals: Vec<f32> =
            (0..rect.width() * rect.height()).map(|i| ((i as u32).wrapping_mul(40_503) >> 20) as f32).collect();
        for solver in [Solver::Direct, Solver::DirectF32] {
            let solve = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                pool.install(|| {
                    let mut frame = Frame::from_pixels(w, h, bg.clone());
                    let mut f = PoissonFusion::new();
                    f.fuse(&mut frame, &[Patch { rect, values: &vals }], Guidance::Normal, solver);
                    frame
                })
            };
            let one = solve(1);
            assert_ne!(one.pixels(), &bg[..]);
            for threads in [2, 3] {
                let same = one.pixels().iter().zip(solve(threads).pixels()).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{solver:?} on {threads} threads");
            }
        }
    }

    #[test]
    fn regions_grow_to_fast_transform_sizes() {
        // side 128: interior 126, 126 + 1 = 127 is prime → grows to 129 (interior 127, 128 = 2⁷)
        let r = grow_to_fast_size(PixelRect { x0: 10, y0: 10, x1: 138, y1: 138 }, 300, 300);
        assert_eq!((r.width(), r.height()), (129, 129));
        // at the frame edge it grows the other way, or not at all
        let r = grow_to_fast_size(PixelRect { x0: 0, y0: 0, x1: 128, y1: 128 }, 128, 128);
        assert_eq!((r.width(), r.height()), (128, 128));
        assert!(is_smooth(64) && is_smooth(54) && !is_smooth(63) && !is_smooth(127) && !is_smooth(0));
    }
}
