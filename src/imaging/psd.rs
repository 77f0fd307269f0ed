//! The radially averaged power spectrum of an image and the slope of its log–log fit.
//!
//! Clutter in infrared sky imagery is summarised by this slope: the power at spatial frequency `f` falls as
//! `f^slope`, with `slope ≈ −3` for real cloud scenes (sharp-edged regions give −3, smooth fields steeper).
//! The estimate removes the mean and a fitted plane, applies a Hann window, and fits `ln P` against `ln f` by
//! least squares over `[f_min, f_max]` cycles/px on bins `1/min(w, h)` wide.

use super::fft2d::fft2;
use rustfft::num_complex::Complex;

/// The radially averaged power spectrum: `(frequency cycles/px, mean power)` per bin from the first non-zero.
pub fn radial_power_spectrum(pixels: &[f32], width: usize, height: usize) -> Vec<(f64, f64)> {
    assert_eq!(pixels.len(), width * height, "image size");
    let (w, h) = (width, height);
    // remove the least-squares plane a + b·x + c·y (centred coordinates make the fit separable)
    let n = (w * h) as f64;
    let mean = pixels.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
    let (mut sxv, mut sxx, mut syv, mut syy) = (0.0, 0.0, 0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            let v = f64::from(pixels[y * w + x]) - mean;
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            sxv += dx * v;
            sxx += dx * dx;
            syv += dy * v;
            syy += dy * dy;
        }
    }
    let (bx, by) = (if sxx > 0.0 { sxv / sxx } else { 0.0 }, if syy > 0.0 { syv / syy } else { 0.0 });
    let hann = |i: usize, len: usize| {
        if len < 2 { 1.0 } else { 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / (len - 1) as f64).cos() }
    };
    let mut data: Vec<Complex<f64>> = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let v = f64::from(pixels[y * w + x]) - mean - bx * (x as f64 - cx) - by * (y as f64 - cy);
            data.push(Complex::new(v * hann(x, w) * hann(y, h), 0.0));
        }
    }
    fft2(&mut data, w, h, rustfft::FftDirection::Forward);
    let bin = 1.0 / w.min(h) as f64;
    let nbins = (0.5f64.hypot(0.5) / bin).ceil() as usize + 1;
    let (mut power, mut count) = (vec![0.0; nbins], vec![0usize; nbins]);
    let freq = |k: usize, len: usize| if k <= len / 2 { k as f64 } else { k as f64 - len as f64 } / len as f64;
    for y in 0..h {
        for x in 0..w {
            let f = freq(x, w).hypot(freq(y, h));
            let b = (f / bin).round() as usize;
            power[b] += data[y * w + x].norm_sqr();
            count[b] += 1;
        }
    }
    (1..nbins).filter(|&b| count[b] > 0).map(|b| (b as f64 * bin, power[b] / count[b] as f64)).collect()
}

/// Slope of `ln P` against `ln f` over `[f_min, f_max]` cycles/px; `None` with fewer than three bins there or
/// no power.
pub fn psd_slope(pixels: &[f32], width: usize, height: usize, f_min: f64, f_max: f64) -> Option<f64> {
    let spectrum = radial_power_spectrum(pixels, width, height);
    let pts: Vec<(f64, f64)> = spectrum
        .iter()
        .filter(|(f, p)| *f >= f_min && *f <= f_max && *p > 0.0)
        .map(|(f, p)| (f.ln(), p.ln()))
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_noise_is_flat_and_a_step_is_minus_two() {
        let (w, h) = (128, 128);
        let mut z = 1u64;
        let noise: Vec<f32> = (0..w * h)
            .map(|_| {
                z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (z >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        let s = psd_slope(&noise, w, h, 0.03, 0.45).unwrap();
        assert!(s.abs() < 0.15, "white noise slope {s}");
        // a vertical edge: all power on one axis, falling as f⁻²
        let step: Vec<f32> = (0..w * h).map(|i| if (i % w) < w / 2 { 0.0 } else { 1.0 }).collect();
        let s = psd_slope(&step, w, h, 0.03, 0.3).unwrap();
        assert!(s < -1.5, "step slope {s}");
    }
}
