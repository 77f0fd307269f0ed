//! Automatic gain control: the 8-bit display mapping most real infrared datasets were recorded with.
//!
//! Per frame, the DN histogram's `low_percentile` and `high_percentile` points are found; a first-order
//! temporal filter smooths them over frames (`smoothing` = weight of the new frame, 1 for none), as camera AGCs
//! do to avoid flicker; then `out = round(255·(DN − lo)/(hi − lo))`, clamped to 0–255. The map is linear with a
//! positive slope in every frame, so the output is monotone (non-decreasing) in the raw value.

/// Settings of the AGC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgcSpec {
    /// Percentile mapped to 0, [0, 50).
    pub low_percentile: f64,
    /// Percentile mapped to 255, (50, 100].
    pub high_percentile: f64,
    /// Weight of the new frame's percentiles in the running ones, (0, 1].
    pub smoothing: f64,
    /// Smallest span `hi − lo`, DN (a flat frame is not stretched beyond it).
    pub min_span_dn: f64,
}

impl Default for AgcSpec {
    fn default() -> Self {
        Self { low_percentile: 0.5, high_percentile: 99.5, smoothing: 0.1, min_span_dn: 32.0 }
    }
}

/// The AGC's state over a sequence.
#[derive(Debug, Clone)]
pub struct Agc {
    spec: AgcSpec,
    state: Option<(f64, f64)>,
    histogram: Vec<u32>,
}

impl Agc {
    /// A fresh AGC (its first frame sets the levels without smoothing).
    pub fn new(spec: AgcSpec) -> Self {
        Self { spec, state: None, histogram: Vec::new() }
    }

    /// The current `(lo, hi)` in DN, once a frame has been seen.
    pub fn levels(&self) -> Option<(f64, f64)> {
        self.state
    }

    /// Maps a frame of DN (whole numbers in `[0, max_level]`) to 0–255 in place and updates the levels.
    pub fn apply(&mut self, pixels: &mut [f32], max_level: u32) {
        if pixels.is_empty() {
            return;
        }
        let (lo, hi) = self.percentiles(pixels, max_level);
        let (lo, hi) = match self.state {
            None => (lo, hi),
            Some((l, h)) => {
                let a = self.spec.smoothing;
                (l + a * (lo - l), h + a * (hi - h))
            }
        };
        let (lo, hi) = widen(lo, hi, self.spec.min_span_dn);
        self.state = Some((lo, hi));
        let scale = (255.0 / (hi - lo)) as f32;
        let lo = lo as f32;
        for p in pixels {
            let v = if p.is_nan() { 0.0 } else { (*p - lo) * scale };
            *p = (v.clamp(0.0, 255.0) + 0.5).floor();
        }
    }

    fn percentiles(&mut self, pixels: &[f32], max_level: u32) -> (f64, f64) {
        let n = max_level as usize + 1;
        self.histogram.clear();
        self.histogram.resize(n, 0);
        for &p in pixels {
            let i = if p.is_nan() { 0 } else { (p.max(0.0) as usize).min(n - 1) };
            self.histogram[i] += 1;
        }
        let total = pixels.len() as f64;
        let find = |q: f64| -> f64 {
            let target = (q / 100.0 * total).max(1.0);
            let mut acc = 0.0;
            for (i, &c) in self.histogram.iter().enumerate() {
                acc += f64::from(c);
                if acc >= target {
                    return i as f64;
                }
            }
            (n - 1) as f64
        };
        (find(self.spec.low_percentile), find(self.spec.high_percentile))
    }
}

/// `(lo, hi)` widened symmetrically to at least `min_span`.
fn widen(lo: f64, hi: f64, min_span: f64) -> (f64, f64) {
    let span = (hi - lo).max(min_span.max(1e-6));
    let mid = 0.5 * (lo + hi);
    (mid - span / 2.0, mid + span / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_is_monotone_in_the_raw_value() {
        let mut agc = Agc::new(AgcSpec::default());
        for frame in 0..5u32 {
            // a ramp of every level plus an outlier, drifting from frame to frame
            let raw: Vec<f32> = (0..4096u32).map(|i| (1000 + i + 37 * frame) as f32).chain([16_000.0]).collect();
            let mut out = raw.clone();
            agc.apply(&mut out, 16_383);
            let mut pairs: Vec<(f32, f32)> = raw.iter().copied().zip(out.iter().copied()).collect();
            pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            for w in pairs.windows(2) {
                assert!(w[1].1 >= w[0].1, "frame {frame}: {:?} then {:?}", w[0], w[1]);
            }
            assert!(out.iter().all(|&v| (0.0..=255.0).contains(&v) && v.fract() == 0.0));
            if frame == 0 {
                // the first frame sets the levels: its percentiles map to 0 and 255
                assert_eq!(out.iter().copied().fold(f32::MIN, f32::max), 255.0);
                assert_eq!(out.iter().copied().fold(f32::MAX, f32::min), 0.0);
            }
        }
    }

    #[test]
    fn a_flat_frame_is_not_stretched_into_noise() {
        let mut agc = Agc::new(AgcSpec::default());
        let mut px = vec![5000.0f32; 100];
        px[0] = 5001.0;
        agc.apply(&mut px, 16_383);
        // a span of 32 DN at least: one DN is 8 gray levels, not 255
        assert!(px[0] - px[1] <= 8.0 + 1e-6, "{} {}", px[0], px[1]);
    }
}
