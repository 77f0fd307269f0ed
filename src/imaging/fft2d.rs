//! Two-dimensional FFTs of row-major arrays: every row, then every column through a tiled transpose, on every
//! thread. Each row and column is transformed by the same plan whatever the thread count, so the result is the
//! same bit for bit as one thread transforming the rows and then the columns one by one.

use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{FftDirection, FftNum, FftPlanner};

/// In-place 2D FFT of a `w × h` row-major array (unnormalised, as rustfft's).
pub fn fft2<T: FftNum>(data: &mut [Complex<T>], w: usize, h: usize, direction: FftDirection) {
    assert_eq!(data.len(), w * h, "a {w}x{h} array");
    let rows = FftPlanner::new().plan_fft(w, direction);
    data.par_chunks_mut(w.max(1)).for_each(|row| rows.process(row));
    fft_columns(data, w, h, direction);
}

/// In-place FFT of every column of a `w × h` row-major array: transposed (so that each column is a row),
/// transformed, transposed back.
pub fn fft_columns<T: FftNum>(data: &mut [Complex<T>], w: usize, h: usize, direction: FftDirection) {
    assert_eq!(data.len(), w * h, "a {w}x{h} array");
    let columns = FftPlanner::new().plan_fft(h, direction);
    let mut t = vec![Complex::new(T::zero(), T::zero()); w * h];
    transpose_into(data, &mut t, w, h);
    t.par_chunks_mut(h.max(1)).for_each(|col| columns.process(col));
    transpose_into(&t, data, h, w);
}

/// `out` (`h × w`, row-major) = the transpose of `data` (`w × h`, row-major), in bands of output rows on every
/// thread, each read from `data` in tiles (a tile's columns are a few cache lines, not one line per value).
pub fn transpose_into<T: Copy + Send + Sync>(data: &[T], out: &mut [T], w: usize, h: usize) {
    const TILE: usize = 16;
    assert!(data.len() == w * h && out.len() == w * h, "a {w}x{h} array and its transpose");
    if w == 0 || h == 0 {
        return;
    }
    out.par_chunks_mut(TILE * h).enumerate().for_each(|(b, band)| {
        let x0 = b * TILE;
        let rows = band.len() / h;
        for y0 in (0..h).step_by(TILE) {
            for y in y0..(y0 + TILE).min(h) {
                for (j, &v) in data[y * w + x0..][..rows].iter().enumerate() {
                    band[j * h + y] = v;
                }
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tiled_transpose_is_the_transpose() {
        for (w, h) in [(1, 1), (5, 5), (16, 16), (17, 3), (3, 40), (40, 33)] {
            let data: Vec<u32> = (0..(w * h) as u32).collect();
            let mut out = vec![0; w * h];
            transpose_into(&data, &mut out, w, h);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(out[x * h + y], data[y * w + x], "{w}x{h}");
                }
            }
        }
    }

    #[test]
    fn the_2d_fft_is_rows_then_columns_one_by_one_bit_for_bit() {
        for (w, h) in [(1, 1), (7, 5), (24, 17), (3, 64)] {
            let data: Vec<Complex<f32>> =
                (0..w * h).map(|i| Complex::new((i as f32 * 0.37).sin(), (i as f32 * 0.11).cos())).collect();
            let mut got = data.clone();
            fft2(&mut got, w, h, FftDirection::Forward);
            let mut want = data;
            let mut planner = FftPlanner::new();
            let (rows, cols) = (planner.plan_fft_forward(w), planner.plan_fft_forward(h));
            want.chunks_mut(w).for_each(|row| rows.process(row));
            let mut col = vec![Complex::new(0.0f32, 0.0); h];
            for x in 0..w {
                for y in 0..h {
                    col[y] = want[y * w + x];
                }
                cols.process(&mut col);
                for y in 0..h {
                    want[y * w + x] = col[y];
                }
            }
            assert!(
                got.iter()
                    .zip(&want)
                    .all(|(a, b)| a.re.to_bits() == b.re.to_bits() && a.im.to_bits() == b.im.to_bits()),
                "{w}x{h}"
            );
        }
    }
}
