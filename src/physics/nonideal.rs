//! A real camera's departures from an ideal one, after its non-uniformity correction (NUC).
//!
//! Each is switchable and seeded per sequence (stage [`stage::FIXED_PATTERN`] of the scenario's seed), so it is
//! constant over a sequence and changes with the seed:
//! - **fixed-pattern noise**: a per-pixel gain error (relative rms) and offset (rms), and a per-column offset
//!   (the column structure of microbolometer readouts), as a NUC leaves them;
//! - **dead and hot pixels**: a fraction with no response (they read the offset) and a fraction stuck bright;
//! - **drift**: a slow frame offset that wanders with a 1/f spectrum between `drift_min_hz` and `drift_max_hz`
//!   (twelve sinusoids at log-spaced frequencies with equal amplitudes and seeded phases, so frame k is computed
//!   without the frames before it);
//! - **temporal column noise**: a fresh per-column offset every frame (microbolometers);
//! - **vignetting**: the `cos⁴θ` fall-off of irradiance with the angle θ from the optical axis, of which a NUC
//!   removes most; `cos4_residual` is the fraction left; and **narcissus**, the cooled detector seeing its own
//!   cold reflection: a Gaussian offset centred on the image.
//!
//! Offsets are given in multiples of the camera's temporal noise at a 300 K scene (`_netd`: one NETD of signal),
//! so one set of values suits any ADC; [`NonIdeal::new`] converts them to DN.

use rand::RngExt;
use serde::{Deserialize, Serialize};

use super::ParamError;
use super::noise::{stage, standard_normal, stream_rng};

/// The non-idealities and their sizes; all zero is an ideal camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NonIdealSpec {
    /// Relative rms of the per-pixel gain after NUC (e.g. 2e-4).
    pub gain_rms: f64,
    /// Rms per-pixel offset, in NETDs.
    pub offset_netd: f64,
    /// Rms per-column offset, in NETDs.
    pub column_netd: f64,
    /// Rms per-column offset drawn anew each frame, in NETDs.
    pub column_temporal_netd: f64,
    /// Fraction of dead pixels (no response), [0, 0.1].
    pub dead_fraction: f64,
    /// Fraction of hot pixels (stuck 50 NETDs bright), [0, 0.1].
    pub hot_fraction: f64,
    /// Rms of the slow 1/f frame-offset drift, in NETDs.
    pub drift_netd: f64,
    /// Lowest frequency of the drift, Hz.
    pub drift_min_hz: f64,
    /// Highest frequency of the drift, Hz.
    pub drift_max_hz: f64,
    /// Fraction of the `cos⁴θ` fall-off left after NUC, [0, 1].
    pub cos4_residual: f64,
    /// Narcissus: offset at the image centre, in NETDs (negative: a dark centre).
    pub narcissus_netd: f64,
    /// Narcissus: Gaussian width as a fraction of the half-diagonal, (0, 2].
    pub narcissus_width: f64,
}

impl Default for NonIdealSpec {
    /// An ideal camera.
    fn default() -> Self {
        Self {
            gain_rms: 0.0,
            offset_netd: 0.0,
            column_netd: 0.0,
            column_temporal_netd: 0.0,
            dead_fraction: 0.0,
            hot_fraction: 0.0,
            drift_netd: 0.0,
            drift_min_hz: 0.01,
            drift_max_hz: 1.0,
            cos4_residual: 0.0,
            narcissus_netd: 0.0,
            narcissus_width: 0.5,
        }
    }
}

impl NonIdealSpec {
    /// A cooled photon-detector camera after a two-point NUC: 0.02 % gain and 0.3 NETD offset residuals, one
    /// dead pixel in 10⁴, 0.5 NETD of drift, 1 % of the cos⁴ fall-off and a faint −1 NETD narcissus.
    pub fn cooled() -> Self {
        Self {
            gain_rms: 2e-4,
            offset_netd: 0.3,
            dead_fraction: 1e-4,
            hot_fraction: 2e-5,
            drift_netd: 0.5,
            cos4_residual: 0.01,
            narcissus_netd: -1.0,
            ..Self::default()
        }
    }

    /// An uncooled microbolometer after shutter NUC: 0.05 % gain, 0.4 NETD offset, 0.3 NETD fixed and 0.2 NETD
    /// per-frame column offsets, dead pixels 2 in 10⁴, 1.5 NETD of drift between shutter events, 2 % of the cos⁴
    /// fall-off.
    pub fn uncooled() -> Self {
        Self {
            gain_rms: 5e-4,
            offset_netd: 0.4,
            column_netd: 0.3,
            column_temporal_netd: 0.2,
            dead_fraction: 2e-4,
            hot_fraction: 5e-5,
            drift_netd: 1.5,
            cos4_residual: 0.02,
            ..Self::default()
        }
    }

    /// Checks the parameters.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let check = ParamError::check_range;
        check("gain_rms", self.gain_rms, 0.0, 0.1)?;
        check("offset_netd", self.offset_netd, 0.0, 1000.0)?;
        check("column_netd", self.column_netd, 0.0, 1000.0)?;
        check("column_temporal_netd", self.column_temporal_netd, 0.0, 1000.0)?;
        check("dead_fraction", self.dead_fraction, 0.0, 0.1)?;
        check("hot_fraction", self.hot_fraction, 0.0, 0.1)?;
        check("drift_netd", self.drift_netd, 0.0, 1000.0)?;
        check("drift_min_hz", self.drift_min_hz, 1e-6, 1e4)?;
        check("drift_max_hz", self.drift_max_hz, self.drift_min_hz, 1e4)?;
        check("cos4_residual", self.cos4_residual, 0.0, 1.0)?;
        check("narcissus_netd", self.narcissus_netd, -1000.0, 1000.0)?;
        check("narcissus_width", self.narcissus_width, 1e-3, 2.0)
    }

    /// True if every non-ideality is off.
    pub fn is_ideal(&self) -> bool {
        self.gain_rms == 0.0
            && self.offset_netd == 0.0
            && self.column_netd == 0.0
            && self.column_temporal_netd == 0.0
            && self.dead_fraction == 0.0
            && self.hot_fraction == 0.0
            && self.drift_netd == 0.0
            && self.cos4_residual == 0.0
            && self.narcissus_netd == 0.0
    }
}

/// The geometry the maps depend on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FocalPlane {
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
    /// Focal length in pixels.
    pub focal_px: f64,
}

/// The non-idealities of one sequence, ready to apply.
#[derive(Debug, Clone)]
pub struct NonIdeal {
    spec: NonIdealSpec,
    /// One NETD of signal, DN.
    netd_dn: f64,
    width: usize,
    /// Per-pixel gain (vignetting × FPN gain × dead pixels); `None` if all 1.
    gain: Option<Vec<f32>>,
    /// Per-pixel offset, DN; `None` if all 0.
    offset_dn: Option<Vec<f32>>,
    /// Drift components: (frequency Hz, phase rad); amplitude each.
    drift: Vec<(f64, f64)>,
    drift_amplitude_dn: f64,
    seed: u64,
}

impl NonIdeal {
    /// Draws the sequence's maps. `netd_dn` is one NETD of signal in DN (the temporal noise at 300 K).
    pub fn new(spec: &NonIdealSpec, plane: FocalPlane, netd_dn: f64, seed: u64) -> Self {
        let (w, h) = (plane.width, plane.height);
        let n = w * h;
        let mut rng = stream_rng(seed, stage::FIXED_PATTERN, 0, 0);
        let mut gain = vec![1.0f32; n];
        let mut offset = vec![0.0f32; n];
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let half_diag = cx.hypot(cy).max(1e-9);
        let narcissus_sigma = spec.narcissus_width * half_diag;
        let columns: Vec<f64> = (0..w).map(|_| standard_normal(&mut rng) * spec.column_netd * netd_dn).collect();
        for y in 0..h {
            for (x, column) in columns.iter().enumerate() {
                let i = y * w + x;
                let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                let r2 = dx * dx + dy * dy;
                let cos2 = plane.focal_px * plane.focal_px / (plane.focal_px * plane.focal_px + r2);
                let vignette = 1.0 - spec.cos4_residual * (1.0 - cos2 * cos2);
                let g = 1.0 + spec.gain_rms * standard_normal(&mut rng);
                gain[i] = (vignette * g) as f32;
                let mut o = spec.offset_netd * netd_dn * standard_normal(&mut rng) + column;
                if spec.narcissus_netd != 0.0 {
                    o += spec.narcissus_netd * netd_dn * (-0.5 * r2 / (narcissus_sigma * narcissus_sigma)).exp();
                }
                offset[i] = o as f32;
                let u: f64 = rng.random();
                if u < spec.dead_fraction {
                    gain[i] = 0.0;
                } else if u < spec.dead_fraction + spec.hot_fraction {
                    offset[i] += (50.0 * netd_dn) as f32;
                }
            }
        }
        let mut drift = Vec::new();
        const DRIFT_COMPONENTS: usize = 12;
        if spec.drift_netd > 0.0 {
            let (lo, hi) = (spec.drift_min_hz.ln(), spec.drift_max_hz.ln());
            for k in 0..DRIFT_COMPONENTS {
                let f = (lo + (hi - lo) * (k as f64 + rng.random::<f64>()) / DRIFT_COMPONENTS as f64).exp();
                drift.push((f, std::f64::consts::TAU * rng.random::<f64>()));
            }
        }
        // each of the components a·sin(…) has variance a²/2: rms of the sum = a·√(K/2)
        let drift_amplitude_dn = spec.drift_netd * netd_dn / (DRIFT_COMPONENTS as f64 / 2.0).sqrt();
        let any_gain = spec.gain_rms > 0.0 || spec.cos4_residual > 0.0 || spec.dead_fraction > 0.0;
        let any_offset =
            spec.offset_netd > 0.0 || spec.column_netd > 0.0 || spec.narcissus_netd != 0.0 || spec.hot_fraction > 0.0;
        Self {
            spec: *spec,
            netd_dn,
            width: w,
            gain: any_gain.then_some(gain),
            offset_dn: any_offset.then_some(offset),
            drift,
            drift_amplitude_dn,
            seed,
        }
    }

    /// The per-pixel gain map, if any pixel's gain differs from 1.
    pub fn gain(&self) -> Option<&[f32]> {
        self.gain.as_deref()
    }

    /// The per-pixel offset map in DN, if any offset differs from 0.
    pub fn offset_dn(&self) -> Option<&[f32]> {
        self.offset_dn.as_deref()
    }

    /// The frame offset drift at time `t_s`, DN.
    pub fn drift_dn(&self, t_s: f64) -> f64 {
        self.drift.iter().map(|&(f, phase)| (std::f64::consts::TAU * f * t_s + phase).sin()).sum::<f64>()
            * self.drift_amplitude_dn
    }

    /// Writes frame `frame`'s temporal column offsets (DN) into `out` (resized to the width); returns false,
    /// writing nothing, if there are none.
    pub fn column_offsets(&self, frame: u64, out: &mut Vec<f32>) -> bool {
        if self.spec.column_temporal_netd <= 0.0 {
            return false;
        }
        let mut rng = stream_rng(self.seed, stage::FIXED_PATTERN, frame.wrapping_add(1), 1);
        let sigma = self.spec.column_temporal_netd * self.netd_dn;
        out.clear();
        out.extend((0..self.width).map(|_| (standard_normal(&mut rng) * sigma) as f32));
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane() -> FocalPlane {
        FocalPlane { width: 64, height: 48, focal_px: 100.0 }
    }

    #[test]
    fn fixed_pattern_is_constant_over_a_sequence_and_changes_with_the_seed() {
        let spec = NonIdealSpec::uncooled();
        let a = NonIdeal::new(&spec, plane(), 2.0, 7);
        let b = NonIdeal::new(&spec, plane(), 2.0, 7);
        let c = NonIdeal::new(&spec, plane(), 2.0, 8);
        assert_eq!(a.gain(), b.gain());
        assert_eq!(a.offset_dn(), b.offset_dn());
        assert_ne!(a.offset_dn(), c.offset_dn());
        assert_ne!(a.gain(), c.gain());
    }

    #[test]
    fn sizes_are_as_asked() {
        let spec = NonIdealSpec { offset_netd: 0.5, ..NonIdealSpec::default() };
        let big = FocalPlane { width: 256, height: 256, focal_px: 1e9 };
        let n = NonIdeal::new(&spec, big, 4.0, 3);
        let o = n.offset_dn().unwrap();
        let rms = (o.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>() / o.len() as f64).sqrt();
        assert!((rms - 2.0).abs() < 0.05, "{rms}");
        assert!(n.gain().is_none());
        // drift: rms over a long stretch near the asked value, smooth from frame to frame
        let d = NonIdeal::new(&NonIdealSpec { drift_netd: 1.0, ..NonIdealSpec::default() }, big, 4.0, 3);
        let samples: Vec<f64> = (0..20_000).map(|k| d.drift_dn(k as f64 * 0.05)).collect();
        let rms = (samples.iter().map(|v| v * v).sum::<f64>() / samples.len() as f64).sqrt();
        assert!(rms > 2.0 && rms < 6.0, "{rms}");
        assert!((d.drift_dn(10.0) - d.drift_dn(10.01)).abs() < 0.5);
    }

    #[test]
    fn vignetting_darkens_the_corners() {
        let spec = NonIdealSpec { cos4_residual: 1.0, ..NonIdealSpec::default() };
        let n = NonIdeal::new(&spec, plane(), 1.0, 1);
        let g = n.gain().unwrap();
        let centre = g[24 * 64 + 32];
        let corner = g[0];
        // θ at the corner: r ≈ 39.4 px at f = 100 px → cos⁴θ ≈ 0.75
        assert!(centre > 0.999 && corner < 0.76 && corner > 0.74, "{centre} {corner}");
    }

    #[test]
    fn dead_pixels_have_no_gain() {
        let spec = NonIdealSpec { dead_fraction: 0.05, ..NonIdealSpec::default() };
        let n = NonIdeal::new(&spec, FocalPlane { width: 200, height: 200, focal_px: 1e9 }, 1.0, 5);
        let dead = n.gain().unwrap().iter().filter(|&&g| g == 0.0).count();
        assert!((dead as f64 / 40_000.0 - 0.05).abs() < 0.01, "{dead}");
    }
}
