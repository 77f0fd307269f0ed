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
//! O(n² log n), in f64, two rows per complex FFT of the rows' length plus one.
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
#[serde(rename_all = "snake_case", tag = "method", deny_unknown_fields)]
pub enum Solver {
    /// Exact direct solve by the discrete sine transform.
    #[default]
    Direct,
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
    /// call: no allocation per frame).
    static BLOCK_BUFFERS: std::cell::RefCell<FftBuffers> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// What [`Dst1::process_rows`] applies to a row between its two transforms: `(index, row)`.
type RowStep<'a> = dyn Fn(usize, &mut [f64]) + Sync + 'a;

/// A transform buffer and an FFT scratch.
type FftBuffers = (Vec<Complex<f64>>, Vec<Complex<f64>>);

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
struct Dst1 {
    n: usize,
    /// The complex FFT of length `n + 1`.
    fft: Arc<dyn Fft<f64>>,
    /// `sin(πJ/(n+1))` for `J` = 1 … n: the weights of the rows' symmetric parts.
    sines: Vec<f64>,
    /// `2 − 2cos(π(k+1)/(n+1))`: this axis's share of the Laplacian's eigenvalues.
    eigen: Vec<f64>,
}

impl Dst1 {
    /// Plans the transform of length `n` (≥ 1) with `planner`.
    fn new(n: usize, planner: &mut FftPlanner<f64>) -> Self {
        let c = std::f64::consts::PI / (n + 1) as f64;
        Self {
            n,
            fft: planner.plan_fft_forward(n + 1),
            sines: (1..=n).map(|j| (c * j as f64).sin()).collect(),
            eigen: (0..n).map(|k| 2.0 - 2.0 * (c * (k + 1) as f64).cos()).collect(),
        }
    }

    /// The length of the transform buffer it needs.
    fn buffer_len(&self) -> usize {
        self.n + 1
    }

    /// Transforms `a` and, if given, `b` in place; `buf` holds `n + 1` values, `scratch` the FFT's scratch.
    fn process_pair(
        &self,
        a: &mut [f64],
        b: Option<&mut [f64]>,
        buf: &mut [Complex<f64>],
        scratch: &mut [Complex<f64>],
    ) {
        let n = self.n;
        let big_n = n + 1;
        let buf = &mut buf[..big_n];
        let a = &mut a[..n];
        let b = b.map(|b| &mut b[..n]);
        // y_J and y_{N−J} from f_J (row[J − 1]) and f_{N−J} (row[n − J]), J = 1 … ⌈n/2⌉ (the middle one, n odd,
        // from itself): buf[J] and buf[N − J] hold rows a and b as real and imaginary parts
        buf[0] = Complex::new(0.0, 0.0);
        let half = n.div_ceil(2);
        let (low, high) = buf[1..].split_at_mut(half);
        fn mirrored(row: &[f64], half: usize) -> impl Iterator<Item = (&f64, &f64)> {
            row[..half].iter().zip(row[row.len() - half..].iter().rev())
        }
        // the middle value's mirror image, n odd: written and not read
        let mut unused = Complex::new(0.0, 0.0);
        let ends = low.iter_mut().zip(high.iter_mut().rev().chain(std::iter::once(&mut unused)));
        let weights = self.sines[..half].iter();
        match &b {
            Some(b) => {
                for (((lo, hi), &s), ((&fa, &ma), (&fb, &mb))) in
                    ends.zip(weights).zip(mirrored(a, half).zip(mirrored(b, half)))
                {
                    let (sa, da, sb, db) = (s * (fa + ma), 0.5 * (fa - ma), s * (fb + mb), 0.5 * (fb - mb));
                    *lo = Complex::new(sa + da, sb + db);
                    *hi = Complex::new(sa - da, sb - db);
                }
            }
            None => {
                for (((lo, hi), &s), (&fa, &ma)) in ends.zip(weights).zip(mirrored(a, half)) {
                    let (sa, da) = (s * (fa + ma), 0.5 * (fa - ma));
                    *lo = Complex::new(sa + da, 0.0);
                    *hi = Complex::new(sa - da, 0.0);
                }
            }
        }
        self.fft.process_with_scratch(buf, scratch);
        // the FFT of row a's y is (Z_k + conj Z_{N−k})/2, of row b's (Z_k − conj Z_{N−k})/(2i), k = 1 … ⌊n/2⌋:
        // F_{2k} (row[2k − 1]) from their imaginary parts, F_{2k+1} (row[2k]) the running sum of their real parts
        let pairs = buf[1..=n / 2].iter().zip(buf[big_n - n / 2..].iter().rev());
        let (mut odd_a, mut odd_b) = (0.5 * buf[0].re, 0.5 * buf[0].im);
        a[0] = odd_a;
        match b {
            Some(b) => {
                b[0] = odd_b;
                for ((zk, zm), (oa, ob)) in pairs.zip(a[1..].chunks_mut(2).zip(b[1..].chunks_mut(2))) {
                    oa[0] = 0.5 * (zm.im - zk.im);
                    ob[0] = 0.5 * (zk.re - zm.re);
                    if let (Some(na), Some(nb)) = (oa.get_mut(1), ob.get_mut(1)) {
                        odd_a += 0.5 * (zk.re + zm.re);
                        odd_b += 0.5 * (zk.im + zm.im);
                        *na = odd_a;
                        *nb = odd_b;
                    }
                }
            }
            None => {
                for ((zk, zm), oa) in pairs.zip(a[1..].chunks_mut(2)) {
                    oa[0] = 0.5 * (zm.im - zk.im);
                    if let Some(na) = oa.get_mut(1) {
                        odd_a += 0.5 * (zk.re + zm.re);
                        *na = odd_a;
                    }
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
        rows: &mut [f64],
        buf: &mut [Complex<f64>],
        scratch: &mut [Complex<f64>],
        between: Option<&RowStep<'_>>,
    ) {
        use rayon::prelude::*;
        let pair = 2 * self.n;
        let block = pair * (PARALLEL_ROWS_BLOCK / pair).max(1);
        if rows.len() < 2 * block || rayon::current_num_threads() < 2 {
            return self.process_rows_serial(rows, 0, buf, scratch, between);
        }
        let (buf_len, scratch_len) = (buf.len(), scratch.len());
        rows.par_chunks_mut(block).enumerate().for_each(|(k, rows)| {
            BLOCK_BUFFERS.with_borrow_mut(|(buf, scratch)| {
                let zero = Complex::new(0.0, 0.0);
                buf.resize(buf_len.max(buf.len()), zero);
                scratch.resize(scratch_len.max(scratch.len()), zero);
                let first = k * block / self.n;
                self.process_rows_serial(rows, first, &mut buf[..buf_len], &mut scratch[..scratch_len], between);
            });
        });
    }

    /// [`Dst1::process_rows`] on this thread, `rows` starting at row `first`.
    fn process_rows_serial(
        &self,
        rows: &mut [f64],
        first: usize,
        buf: &mut [Complex<f64>],
        scratch: &mut [Complex<f64>],
        between: Option<&RowStep<'_>>,
    ) {
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
    }
}

/// Poisson fusion with planned transforms and reusable buffers.
pub struct PoissonFusion {
    planner: FftPlanner<f64>,
    dst: HashMap<usize, Arc<Dst1>>,
    rects: Vec<PixelRect>,
    /// One set of buffers per region: the regions are solved in parallel.
    scratch: Vec<Scratch>,
    /// What every set of buffers is sized for.
    sized_for: BufferSizes,
    /// Looked at between sweeps of the iterative solvers: when set, they stop at once.
    stop: Option<Arc<AtomicBool>>,
}

/// The largest region's area, and the longest transform buffer and scratch of the planned sizes.
#[derive(Debug, Clone, Copy, Default)]
struct BufferSizes {
    area: usize,
    fft_buf: usize,
    fft_scratch: usize,
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
    fft_buf: Vec<Complex<f64>>,
    fft_scratch: Vec<Complex<f64>>,
    /// What the last solve on these buffers did.
    stats: FusionStats,
}

impl std::fmt::Debug for PoissonFusion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoissonFusion").field("planned_sizes", &self.dst.keys().collect::<Vec<_>>()).finish()
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
            planner: FftPlanner::new(),
            dst: HashMap::new(),
            rects: Vec::new(),
            scratch: vec![Scratch::default()],
            sized_for: BufferSizes::default(),
            stop: None,
        }
    }

    /// The regions the last [`PoissonFusion::fuse`] solved: the patches' rectangles clipped to the frame,
    /// merged where they touch, and grown by a few pixels where that gives a faster transform size.
    pub fn regions(&self) -> &[PixelRect] {
        &self.rects
    }

    /// Plans transforms and sizes buffers for regions up to `max_side × max_side`, so later calls with one
    /// region do not allocate (each further region at once gets buffers of the same size when first needed).
    pub fn with_capacity(max_side: usize) -> Self {
        let mut s = Self::new();
        for n in 1..=max_side.saturating_sub(2) {
            s.plan(n);
        }
        s.sized_for.area = max_side * max_side;
        s.size_buffers(1);
        s.rects.reserve(64);
        s
    }

    /// Gives the first `sets` sets of buffers the size in `sized_for` (allocating only where one falls short).
    fn size_buffers(&mut self, sets: usize) {
        if self.scratch.len() < sets {
            self.scratch.resize_with(sets, Scratch::default);
        }
        let size = self.sized_for;
        for sc in &mut self.scratch[..sets] {
            sc.reserve(size.area);
            sc.fit(size.fft_buf, size.fft_scratch);
        }
    }

    fn plan(&mut self, n: usize) -> Arc<Dst1> {
        if let Some(d) = self.dst.get(&n) {
            return Arc::clone(d);
        }
        let d = Arc::new(Dst1::new(n, &mut self.planner));
        self.sized_for.fft_buf = self.sized_for.fft_buf.max(d.buffer_len());
        self.sized_for.fft_scratch = self.sized_for.fft_scratch.max(d.fft.get_inplace_scratch_len());
        self.dst.insert(n, Arc::clone(&d));
        d
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
        if solved && solver == Solver::Direct {
            for k in 0..self.rects.len() {
                let (w, h) = (self.rects[k].width(), self.rects[k].height());
                if w >= 3 && h >= 3 {
                    self.plan(w - 2);
                    self.plan(h - 2);
                }
            }
        }
        let regions = self.rects.len();
        // every set of buffers sized for the largest region and transform so far: which region a set gets
        // changes from frame to frame, and none then allocates again
        let largest = self.rects.iter().map(|r| r.width() * r.height()).max().unwrap_or(0);
        self.sized_for.area = self.sized_for.area.max(largest);
        self.size_buffers(regions);
        let (dst, stop, rects) = (&self.dst, self.stop.as_deref(), &self.rects);
        let frame_in: &Frame = frame;
        self.scratch[..regions].par_iter_mut().zip(rects.par_iter()).with_max_len(1).for_each(|(sc, &rect)| {
            let mut stats = FusionStats::default();
            sc.load_region(frame_in, rect, patches);
            let (w, h) = (rect.width(), rect.height());
            if !solved || w < 3 || h < 3 {
                sc.stats = stats;
                return;
            }
            stats.unknowns = (w - 2) * (h - 2);
            sc.build_rhs(w, h, guidance);
            match solver {
                Solver::Direct => sc.solve_direct(&dst[&(w - 2)], &dst[&(h - 2)]),
                Solver::Jacobi { tolerance, max_iterations } => {
                    stats.iterations = sc.solve_iterative(w, h, tolerance, max_iterations, None, stop, &mut stats);
                }
                Solver::Sor { tolerance, max_iterations } => {
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
            if !solved {
                store(frame, *rect, |y, x| sc.bg[y * w + x] + sc.u[y * w + x], 0);
            } else if w >= 3 && h >= 3 {
                match solver {
                    Solver::Direct => {
                        let (nx, work) = (w - 2, &sc.work);
                        store(frame, *rect, |y, x| work[(y - 1) * nx + (x - 1)], 1);
                    }
                    Solver::Jacobi { .. } | Solver::Sor { .. } => store(frame, *rect, |y, x| sc.work[y * w + x], 1),
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
        let (dst_x, dst_y) = (self.plan(nx), self.plan(ny));
        let sc = &mut self.scratch[0];
        sc.reserve(rhs.len());
        sc.work[..rhs.len()].copy_from_slice(rhs);
        sc.solve_direct(&dst_x, &dst_y);
        rhs.copy_from_slice(&sc.work[..rhs.len()]);
    }
}

impl Scratch {
    /// Sizes the transforms' buffers: `buf` and `scratch` complex values at least.
    fn fit(&mut self, buf: usize, scratch: usize) {
        let zero = Complex::new(0.0, 0.0);
        if self.fft_scratch.len() < scratch {
            self.fft_scratch.resize(scratch, zero);
        }
        if self.fft_buf.len() < buf {
            self.fft_buf.resize(buf, zero);
        }
    }

    fn reserve(&mut self, area: usize) {
        for b in [&mut self.u, &mut self.bg, &mut self.work, &mut self.work2] {
            if b.len() < area {
                b.resize(area, 0.0);
            }
        }
    }

    /// Loads the background and the summed guidance patch on `rect`.
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

    /// Solves `(4I − adjacency) x = work` on an `nx × ny` grid with zero Dirichlet boundary, in place.
    fn solve_direct(&mut self, dst_x: &Dst1, dst_y: &Dst1) {
        let (nx, ny) = (dst_x.n, dst_y.n);
        for d in [dst_x, dst_y] {
            self.fit(d.buffer_len(), d.fft.get_inplace_scratch_len());
        }
        let n = nx * ny;
        let (work, tmp) = (&mut self.work[..n], &mut self.work2[..n]);
        let (buf, scratch) = (&mut self.fft_buf, &mut self.fft_scratch);
        let (sx, sy) = (dst_x.fft.get_inplace_scratch_len(), dst_y.fft.get_inplace_scratch_len());
        // rows: DST along x
        dst_x.process_rows(work, buf, &mut scratch[..sx], None);
        transpose(work, tmp, nx, ny);
        // along y, dividing between the two transforms by the eigenvalues λ = (2 − 2cos θx) + (2 − 2cos θy); tmp is
        // ny-fast: row kx, index ky
        let scale = 4.0 / ((nx + 1) * (ny + 1)) as f64;
        let divide = |kx: usize, row: &mut [f64]| {
            let lx = dst_x.eigen[kx];
            for (v, &ly) in row.iter_mut().zip(&dst_y.eigen) {
                *v *= scale / (lx + ly);
            }
        };
        dst_y.process_rows(tmp, buf, &mut scratch[..sy], Some(&divide));
        transpose(tmp, work, ny, nx);
        dst_x.process_rows(work, buf, &mut scratch[..sx], None);
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

/// Writes `value(y, x)` (region coordinates) into `frame` on `rect`, skipping a ring of `margin` pixels.
fn store(frame: &mut Frame, rect: PixelRect, value: impl Fn(usize, usize) -> f64, margin: usize) {
    let (w, h) = (rect.width(), rect.height());
    let fw = frame.width();
    let px = frame.pixels_mut();
    for y in margin..h - margin {
        let start = (rect.y0 + y) * fw + rect.x0;
        for (x, p) in px[start + margin..start + w - margin].iter_mut().enumerate() {
            *p = value(y, x + margin) as f32;
        }
    }
}

/// `dst` (`cols × rows`, row-major) = the transpose of `src` (`rows × cols`), in tiles of 8 × 8 (with AVX2, of
/// 4 × 4 blocks moved through vector registers: the fusion stage of the 256 × 256 bench case with 8 targets took
/// 78–81 µs a frame against 89–92 value by value, `draft`, four interleaved rounds on an AMD EPYC), on this thread:
/// regions are solved side by side in the pool, and the parallel [`super::fft2d::transpose_into`] in its place
/// was no faster (the fusion stage 16–21 against 12–17 µs a frame for one 33 × 33 region, three interleaved
/// rounds on an AMD EPYC). Nor was a large region cut into bands of rows transposed in parallel: the fusion stage
/// of the 256 × 256 bench case with 8 targets (one region of up to 256 × 73) took 109–112 against 94–96 µs a
/// frame.
fn transpose(src: &[f64], dst: &mut [f64], cols: usize, rows: usize) {
    assert!(src.len() >= rows * cols && dst.len() >= rows * cols, "buffers of the region's size");
    #[cfg(target_arch = "x86_64")]
    if crate::physics::simd::Level::detect() != crate::physics::simd::Level::Baseline {
        // SAFETY: the CPU has AVX2 (every level above the baseline includes it); the lengths are checked above
        return unsafe { x86::transpose_avx2(src, dst, cols, rows) };
    }
    transpose_tiles(src, dst, cols, rows, (0..rows, 0..cols));
}

/// [`transpose`] of the part of `src` in rows `part.0` and columns `part.1`, in 8 × 8 tiles, one value at a time.
fn transpose_tiles(src: &[f64], dst: &mut [f64], cols: usize, rows: usize, part: (Range<usize>, Range<usize>)) {
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
        }
    }

    #[test]
    fn the_sine_transform_is_its_definition_on_rows_of_every_length() {
        let mut planner = FftPlanner::new();
        let lengths = (1..=40).chain([71, 142, 242, 254, 255]);
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
        let solve = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut frame = Frame::from_pixels(w, h, bg.clone());
                let mut f = PoissonFusion::new();
                f.fuse(&mut frame, &[Patch { rect, values: &vals }], Guidance::Normal, Solver::Direct);
                frame
            })
        };
        let one = solve(1);
        assert_ne!(one.pixels(), &bg[..]);
        for threads in [2, 3] {
            assert!(one.pixels().iter().zip(solve(threads).pixels()).all(|(a, b)| a.to_bits() == b.to_bits()));
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
