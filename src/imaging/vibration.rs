//! Camera line-of-sight vibration: band-limited, seeded and seekable jitter.
//!
//! Each axis is a sum of `components` sinusoids with frequencies drawn uniformly from
//! `[cutoff/10, cutoff]`, random phases, and amplitudes drawn from [0.5, 1] and scaled so they add up to the
//! configured amplitude. The jitter is therefore band-limited to the cut-off, never exceeds the amplitude
//! (the paper's "camera shake amplitude", e.g. 0.3°), and is an analytic function of time: frame k needs no
//! earlier frame. The random draws come from the `(seed, VIBRATION, 0)` stream. Zero amplitude gives an
//! exact still camera.

use rand::RngExt;
use serde::{Deserialize, Serialize};

use super::camera::Jitter;
use crate::physics::ParamError;
use crate::physics::noise::{stage, stream_rng};

/// Vibration parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VibrationSpec {
    /// Peak angular deviation of the line of sight on each of the pan and tilt axes, degrees.
    pub amplitude_deg: f64,
    /// Highest frequency in the jitter, Hz.
    pub cutoff_hz: f64,
    /// Sinusoids per axis, 1 … 64.
    pub components: u32,
    /// Roll amplitude as a fraction of `amplitude_deg`.
    pub roll_fraction: f64,
}

impl Default for VibrationSpec {
    fn default() -> Self {
        Self { amplitude_deg: 0.0, cutoff_hz: 5.0, components: 8, roll_fraction: 0.0 }
    }
}

/// One sinusoid: amplitude (rad), angular frequency (rad/s), phase (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tone {
    amplitude: f64,
    omega: f64,
    phase: f64,
}

/// A planned vibration: the sinusoids of each axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Vibration {
    axes: [Vec<Tone>; 3],
}

impl VibrationSpec {
    /// Checks the parameters.
    ///
    /// # Errors
    /// A message naming the field out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        ParamError::check_range("amplitude_deg", self.amplitude_deg, 0.0, 45.0)?;
        ParamError::check_range("cutoff_hz", self.cutoff_hz, 1e-6, 1e6)?;
        ParamError::check_range("components", self.components as f64, 1.0, 64.0)?;
        ParamError::check_range("roll_fraction", self.roll_fraction, 0.0, 1.0)
    }

    /// Draws the sinusoids for `seed`.
    pub fn plan(&self, seed: u64) -> Vibration {
        let mut rng = stream_rng(seed, stage::VIBRATION, 0, 0);
        let amp = self.amplitude_deg.to_radians();
        let mut axis = |scale: f64| {
            let mut tones: Vec<Tone> = (0..self.components)
                .map(|_| Tone {
                    amplitude: 0.5 + 0.5 * rng.random::<f64>(),
                    omega: std::f64::consts::TAU * self.cutoff_hz * (0.1 + 0.9 * rng.random::<f64>()),
                    phase: std::f64::consts::TAU * rng.random::<f64>(),
                })
                .collect();
            let total: f64 = tones.iter().map(|t| t.amplitude).sum();
            for t in &mut tones {
                t.amplitude *= scale / total;
            }
            if scale == 0.0 {
                tones.clear();
            }
            tones
        };
        let x = axis(amp);
        let y = axis(amp);
        let z = axis(amp * self.roll_fraction);
        Vibration { axes: [x, y, z] }
    }
}

impl Vibration {
    /// No vibration.
    pub fn still() -> Self {
        Self { axes: [Vec::new(), Vec::new(), Vec::new()] }
    }

    /// The largest jitter on each axis: the sum of its sinusoids' amplitudes, rad (none is ever exceeded).
    pub fn peak(&self) -> Jitter {
        let sum = |tones: &[Tone]| tones.iter().map(|t| t.amplitude.abs()).sum::<f64>();
        Jitter { x_rad: sum(&self.axes[0]), y_rad: sum(&self.axes[1]), z_rad: sum(&self.axes[2]) }
    }

    /// The jitter at time `t_s`.
    pub fn jitter(&self, t_s: f64) -> Jitter {
        let eval = |tones: &[Tone]| tones.iter().map(|t| t.amplitude * (t.omega * t_s + t.phase).sin()).sum::<f64>();
        Jitter { x_rad: eval(&self.axes[0]), y_rad: eval(&self.axes[1]), z_rad: eval(&self.axes[2]) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounded_seeded_and_still_at_zero() {
        let spec = VibrationSpec { amplitude_deg: 0.3, ..VibrationSpec::default() };
        let a = spec.plan(7);
        let b = spec.plan(7);
        let c = spec.plan(8);
        let mut peak: f64 = 0.0;
        for k in 0..3000 {
            let t = k as f64 / 100.0;
            let j = a.jitter(t);
            assert_eq!(j, b.jitter(t));
            peak = peak.max(j.x_rad.abs()).max(j.y_rad.abs());
        }
        assert!(peak <= 0.3f64.to_radians() + 1e-15);
        // the bound `peak` gives is the amplitude on each turning axis, none on the roll without a roll fraction
        let bound = a.peak();
        assert!((bound.x_rad - 0.3f64.to_radians()).abs() < 1e-15 && (bound.y_rad - bound.x_rad).abs() < 1e-15);
        assert!(bound.z_rad == 0.0 && peak <= bound.x_rad + 1e-15);
        let rolled = VibrationSpec { roll_fraction: 0.5, ..spec }.plan(7).peak();
        assert!((rolled.z_rad - 0.15f64.to_radians()).abs() < 1e-15);
        assert!(peak > 0.1f64.to_radians(), "peak {peak}");
        assert_ne!(a.jitter(1.0), c.jitter(1.0));
        let still = VibrationSpec::default().plan(7);
        assert_eq!(still.jitter(3.0), Jitter::default());
        assert_eq!(still.peak(), Jitter::default());
    }
}
