//! The viewer's state and the pure logic behind its controls: which frame to compute next (play, pause, step,
//! seek, pace), and how a sensor frame is mapped to display colours. No window and no Bevy here, so it is
//! tested like the core.

use crate::imaging::frame::Frame;

/// How the simulation advances while playing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// `n` sensor frames per displayed frame (1 is the default: every frame is shown).
    PerDisplayFrame(u32),
    /// The scenario's frame rate times `speed` in wall-clock time (frames are skipped when the window is slower).
    RealTime {
        /// Multiple of real time.
        speed: f64,
    },
}

/// Play, pause, step and seek over frames `0 .. frames`.
#[derive(Debug, Clone)]
pub struct Playback {
    /// Frames in the scenario's run.
    pub frames: u64,
    /// Playing (or paused).
    pub playing: bool,
    /// Loop back to frame 0 after the last frame (or stop there).
    pub looping: bool,
    /// How playing advances.
    pub pace: Pace,
    /// The frame on show (`None` before the first is computed).
    pub shown: Option<u64>,
    /// A frame asked for by a control, computed on the next update.
    pub request: Option<u64>,
    /// Real-time pacing: frames owed but not yet computed.
    owed: f64,
}

impl Playback {
    /// Paused at frame 0 (which is computed first), `frames ≥ 1`.
    pub fn new(frames: u64, rate_hz: f64) -> Self {
        let _ = rate_hz;
        Self {
            frames: frames.max(1),
            playing: false,
            looping: true,
            pace: Pace::PerDisplayFrame(1),
            shown: None,
            request: Some(0),
            owed: 0.0,
        }
    }

    /// Asks for frame `k` (clamped to the run).
    pub fn seek(&mut self, k: u64) {
        self.request = Some(k.min(self.frames - 1));
    }

    /// Asks for the next frame (pausing).
    pub fn step_forward(&mut self) {
        self.playing = false;
        let next = self.shown.map_or(0, |k| (k + 1).min(self.frames - 1));
        self.seek(next);
    }

    /// Asks for the previous frame (pausing): frames are analytic in time, so going back is computing an
    /// earlier one.
    pub fn step_back(&mut self) {
        self.playing = false;
        let previous = self.shown.map_or(0, |k| k.saturating_sub(1));
        self.seek(previous);
    }

    /// Toggles play and pause; playing from the last frame starts again from 0.
    pub fn toggle(&mut self) {
        self.playing = !self.playing;
        if self.playing && self.shown == Some(self.frames - 1) && self.request.is_none() {
            self.seek(0);
        }
        self.owed = 0.0;
    }

    /// The frame to compute in an update that follows `elapsed_s` of wall-clock time, if any: a request first,
    /// else the next frame when playing. Reaching the end loops or pauses.
    pub fn next(&mut self, elapsed_s: f64, rate_hz: f64) -> Option<u64> {
        if let Some(k) = self.request.take() {
            return Some(k);
        }
        if !self.playing {
            return None;
        }
        let Some(shown) = self.shown else { return Some(0) };
        let advance = match self.pace {
            Pace::PerDisplayFrame(n) => u64::from(n.max(1)),
            Pace::RealTime { speed } => {
                self.owed += elapsed_s.max(0.0) * rate_hz * speed.max(0.0);
                let whole = self.owed.floor();
                self.owed -= whole;
                if whole < 1.0 {
                    return None;
                }
                whole as u64
            }
        };
        let next = shown.saturating_add(advance);
        if next < self.frames {
            Some(next)
        } else if self.looping {
            Some(next % self.frames)
        } else {
            self.playing = false;
            (shown != self.frames - 1).then_some(self.frames - 1)
        }
    }
}

/// How a frame's values are stretched over the display range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stretch {
    /// The frame's minimum to maximum.
    MinMax,
    /// Between two percentiles of the frame (as most recorded infrared video is shown).
    Percentile {
        /// Lower percentile, 0–100.
        low: f64,
        /// Upper percentile, 0–100.
        high: f64,
    },
    /// A fixed window in DN.
    Window {
        /// DN shown black.
        low: f64,
        /// DN shown white.
        high: f64,
    },
}

/// Colours for the stretched values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorMap {
    /// Black to white (white hot).
    Gray,
    /// Black through purple, red and yellow to white, as thermal cameras' "ironbow".
    Ironbow,
}

/// Buffers [`display_window`] reuses from frame to frame: a histogram of whole DN and a copy for selection.
#[derive(Debug, Default)]
pub struct StretchScratch {
    counts: Vec<u32>,
    values: Vec<f32>,
}

/// The DN window `(low, high)` that `stretch` gives for `frame` (`high > low`).
pub fn display_window(frame: &Frame, stretch: Stretch, scratch: &mut StretchScratch) -> (f64, f64) {
    let (low, high) = match stretch {
        Stretch::Window { low, high } => (low, high),
        Stretch::MinMax => {
            let (lo, hi) = frame.pixels().iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                if v.is_finite() { (lo.min(v), hi.max(v)) } else { (lo, hi) }
            });
            (f64::from(lo), f64::from(hi))
        }
        Stretch::Percentile { low, high } => percentiles(frame.pixels(), low.min(high), low.max(high), scratch),
    };
    if !(low.is_finite() && high.is_finite()) {
        (0.0, 1.0)
    } else if high > low {
        (low, high)
    } else {
        (low - 0.5, low + 0.5)
    }
}

/// The values at percentiles `low ≤ high` of the finite `pixels` (nearest rank). Whole-number DN below 2¹⁶, as
/// every recorded gray frame has, are counted in a histogram (one pass); any other value falls back to selection.
fn percentiles(pixels: &[f32], low: f64, high: f64, scratch: &mut StretchScratch) -> (f64, f64) {
    const BINS: usize = 1 << 16;
    let rank = |p: f64, n: usize| ((p.clamp(0.0, 100.0) / 100.0 * (n - 1) as f64).round() as usize).min(n - 1);
    let counts = &mut scratch.counts;
    counts.clear();
    counts.resize(BINS, 0);
    let mut whole = true;
    for &v in pixels {
        // whole numbers in range: the conversion is exact (and, unlike `trunc`, not a call on x86-64 without SSE4.1)
        if v >= 0.0 && v < BINS as f32 && (v as u32) as f32 == v {
            counts[v as usize] += 1;
        } else if v.is_finite() {
            whole = false;
            break;
        }
    }
    if whole {
        let n = counts.iter().map(|&c| c as usize).sum::<usize>();
        if n == 0 {
            return (0.0, 1.0);
        }
        let (i, j) = (rank(low, n), rank(high, n));
        let (mut below, mut lo) = (0_usize, None);
        for (value, &c) in counts.iter().enumerate() {
            below += c as usize;
            if lo.is_none() && below > i {
                lo = Some(value as f64);
            }
            if below > j {
                return (lo.unwrap_or(value as f64), value as f64);
            }
        }
    }
    let values = &mut scratch.values;
    values.clear();
    values.extend(pixels.iter().copied().filter(|v| v.is_finite()));
    if values.is_empty() {
        return (0.0, 1.0);
    }
    let n = values.len();
    let (i, j) = (rank(low, n), rank(high, n));
    let lo = *values.select_nth_unstable_by(i, f32::total_cmp).1;
    let hi = *values.select_nth_unstable_by(j, f32::total_cmp).1;
    (f64::from(lo), f64::from(hi))
}

/// The colour of `t` in [0, 1] (clamped).
pub fn color(map: ColorMap, t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    match map {
        ColorMap::Gray => {
            let g = (t * 255.0).round() as u8;
            [g, g, g]
        }
        ColorMap::Ironbow => {
            // piecewise-linear through black, indigo, purple-red, orange, yellow, white
            const STOPS: [(f64, [f64; 3]); 6] = [
                (0.0, [0.0, 0.0, 0.0]),
                (0.2, [30.0, 0.0, 100.0]),
                (0.45, [190.0, 30.0, 110.0]),
                (0.7, [245.0, 120.0, 20.0]),
                (0.9, [255.0, 220.0, 60.0]),
                (1.0, [255.0, 255.0, 255.0]),
            ];
            let i = STOPS.iter().position(|(s, _)| *s >= t).unwrap_or(STOPS.len() - 1).max(1);
            let ((s0, c0), (s1, c1)) = (STOPS[i - 1], STOPS[i]);
            let u = ((t - s0) / (s1 - s0)).clamp(0.0, 1.0);
            let mix = |k: usize| (c0[k] + (c1[k] - c0[k]) * u).round() as u8;
            [mix(0), mix(1), mix(2)]
        }
    }
}

/// `frame` mapped linearly from `window` to colours, as RGBA bytes (row-major), into `out`.
pub fn to_rgba(frame: &Frame, window: (f64, f64), map: ColorMap, out: &mut Vec<u8>) {
    let (low, high) = window;
    let scale = 1.0 / (high - low);
    // a table of 256 colours: the stretched value is quantized to 8 bits first, as a display does
    let table: Vec<[u8; 4]> = (0..256)
        .map(|i| {
            let [r, g, b] = color(map, f64::from(i) / 255.0);
            [r, g, b, 255]
        })
        .collect();
    // levels as f32 (exact to well under a level for any window) without a call per pixel: +0.5 and truncation
    // round the clamped, non-negative value
    let (offset, gain) = (low as f32, (255.0 * scale) as f32);
    out.resize(frame.pixels().len() * 4, 0);
    for (px, &v) in out.chunks_exact_mut(4).zip(frame.pixels()) {
        let level = ((v - offset) * gain).clamp(0.0, 255.0) + 0.5;
        // NaN clamps to NaN, and NaN as usize is 0: black
        px.copy_from_slice(&table[level as usize]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn playing_advances_one_frame_per_update_and_loops() {
        let mut p = Playback::new(3, 25.0);
        assert_eq!(p.next(0.0, 25.0), Some(0));
        p.shown = Some(0);
        assert_eq!(p.next(0.0, 25.0), None, "paused");
        p.toggle();
        for want in [1, 2, 0, 1] {
            let k = p.next(0.016, 25.0).unwrap();
            assert_eq!(k, want);
            p.shown = Some(k);
        }
        p.looping = false;
        p.shown = Some(2);
        assert_eq!(p.next(0.016, 25.0), None);
        assert!(!p.playing, "stops at the end");
    }

    #[test]
    fn real_time_pace_follows_the_clock() {
        let mut p = Playback::new(1000, 30.0);
        p.shown = Some(0);
        p.request = None;
        p.toggle();
        p.pace = Pace::RealTime { speed: 1.0 };
        // 10 ms at 30 Hz is a third of a frame: nothing yet; 100 ms more owes 3.3 frames: three are advanced
        assert_eq!(p.next(0.010, 30.0), None);
        assert_eq!(p.next(0.100, 30.0), Some(3));
    }

    #[test]
    fn steps_and_seeks_stay_in_the_run() {
        let mut p = Playback::new(5, 25.0);
        p.request = None;
        p.step_back();
        assert_eq!(p.next(0.0, 25.0), Some(0));
        p.shown = Some(4);
        p.step_forward();
        assert_eq!(p.next(0.0, 25.0), Some(4));
        p.seek(99);
        assert_eq!(p.next(0.0, 25.0), Some(4));
    }

    #[test]
    fn stretches_and_colours_are_monotone() {
        let frame = Frame::from_pixels(4, 1, vec![10.0, 20.0, 30.0, 1000.0]);
        let mut scratch = StretchScratch::default();
        assert_eq!(display_window(&frame, Stretch::MinMax, &mut scratch), (10.0, 1000.0));
        let (lo, hi) = display_window(&frame, Stretch::Percentile { low: 0.0, high: 67.0 }, &mut scratch);
        assert_eq!((lo, hi), (10.0, 30.0));
        // the histogram (whole DN) and the selection (fractional values) agree
        let whole: Vec<f32> = (0..1000).map(|i| ((i * 7919) % 1000) as f32).collect();
        let fractional: Vec<f32> = whole.iter().map(|v| v + 0.25).collect();
        let p = Stretch::Percentile { low: 0.5, high: 99.5 };
        let a = display_window(&Frame::from_pixels(1000, 1, whole), p, &mut scratch);
        let b = display_window(&Frame::from_pixels(1000, 1, fractional), p, &mut scratch);
        assert_eq!(a, (5.0, 994.0));
        assert_eq!((a.0 + 0.25, a.1 + 0.25), b);
        let flat = Frame::from_pixels(2, 1, vec![7.0, 7.0]);
        assert_eq!(display_window(&flat, Stretch::MinMax, &mut scratch), (6.5, 7.5));
        for map in [ColorMap::Gray, ColorMap::Ironbow] {
            let lum = |c: [u8; 3]| u32::from(c[0]) * 3 + u32::from(c[1]) * 6 + u32::from(c[2]);
            let mut last = 0;
            for i in 0..=100 {
                let l = lum(color(map, f64::from(i) / 100.0));
                assert!(l >= last, "{map:?} at {i}");
                last = l;
            }
        }
        let mut rgba = Vec::new();
        to_rgba(&frame, (10.0, 30.0), ColorMap::Gray, &mut rgba);
        assert_eq!(rgba, vec![0, 0, 0, 255, 128, 128, 128, 255, 255, 255, 255, 255, 255, 255, 255, 255]);
    }
}
