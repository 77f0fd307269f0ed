//! The sensor's optics and electronics (paper eq 13) and gray mapping (eqs 14–15).
//!
//! Eq 13: `V_s = R_v · L_sum · (R²A_d/f²) · π(D/2)²/R² · τ · τ_opt`. The factor `R²A_d/f²` is the area of the
//! pixel's footprint at range `R`, which assumes the target fills it. A distant target smaller than the
//! footprint only contributes its projected area `A_proj`, so we multiply by the fill factor
//! `min(1, A_proj·f²/(R²·A_d))` (see DESIGN.md). With it, `V_s = R_v·L·τ·τ_opt·A_d·πD²/(4f²)·fill`.
//!
//! Gray mapping: the voltage is clamped to `[V_L, V_H]` (eq 14) and mapped linearly onto `[G_min, G_max]`
//! (eq 15); [`GrayMapping::quantize`] rounds to the sensor's integer levels.

use serde::{Deserialize, Serialize};

/// An invalid sensor parameter: its name, value and allowed range.
pub type SensorError = super::ParamError;

fn require(name: &'static str, value: f64, ok: bool, range: impl Into<String>) -> Result<(), SensorError> {
    if ok { Ok(()) } else { Err(SensorError { name, value, range: range.into() }) }
}

/// Optics and detector of an infrared camera, as they enter eq 13.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Radiometer {
    /// Entrance aperture diameter `D`, m.
    pub aperture_m: f64,
    /// Effective focal length `f`, m.
    pub focal_length_m: f64,
    /// Pixel pitch, m; the pixel is square.
    pub pixel_pitch_m: f64,
    /// Fraction of the pixel that is photosensitive, (0, 1]; `A_d = fill · pitch²`.
    pub detector_fill: f64,
    /// Optical transmittance `opptrans`, [0, 1].
    pub optics_transmittance: f64,
    /// Responsivity `R_v`, V/W.
    pub responsivity_v_per_w: f64,
}

impl Default for Radiometer {
    /// An uncooled LWIR camera: 100 mm f/1 lens, 17 µm pixels, τ_opt 0.8, R_v 1e8 V/W.
    fn default() -> Self {
        Self {
            aperture_m: 0.1,
            focal_length_m: 0.1,
            pixel_pitch_m: 17e-6,
            detector_fill: 1.0,
            optics_transmittance: 0.8,
            responsivity_v_per_w: 1e8,
        }
    }
}

/// The parts of eq 13 for one target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DetectorSignal {
    /// Fraction of the pixel footprint the target covers, [0, 1].
    pub fill_factor: f64,
    /// Power on the detector, W.
    pub power_w: f64,
    /// Output voltage `V_s`, V.
    pub voltage_v: f64,
}

impl Radiometer {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`SensorError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), SensorError> {
        let within = |v: f64, lo: f64, hi: f64| v.is_finite() && (lo..=hi).contains(&v);
        require("aperture_m", self.aperture_m, within(self.aperture_m, 1e-4, 10.0), "[1e-4, 10]")?;
        require("focal_length_m", self.focal_length_m, within(self.focal_length_m, 1e-4, 100.0), "[1e-4, 100]")?;
        require("pixel_pitch_m", self.pixel_pitch_m, within(self.pixel_pitch_m, 1e-7, 1e-3), "[1e-7, 1e-3]")?;
        require("detector_fill", self.detector_fill, self.detector_fill > 0.0 && self.detector_fill <= 1.0, "(0, 1]")?;
        let t = self.optics_transmittance;
        require("optics_transmittance", t, (0.0..=1.0).contains(&t), "[0, 1]")?;
        let r = self.responsivity_v_per_w;
        require("responsivity_v_per_w", r, r.is_finite() && (0.0..=1e15).contains(&r), "[0, 1e15]")
    }

    /// Photosensitive area of one pixel `A_d`, m².
    pub fn detector_area_m2(&self) -> f64 {
        self.detector_fill * self.pixel_pitch_m * self.pixel_pitch_m
    }

    /// Fill factor `min(1, A_proj·f²/(R²·A_d))` of a target of projected area `projected_area_m2` at `range_m`.
    pub fn fill_factor(&self, projected_area_m2: f64, range_m: f64) -> f64 {
        let footprint = range_m * range_m * self.detector_area_m2() / (self.focal_length_m * self.focal_length_m);
        if footprint > 0.0 { (projected_area_m2 / footprint).clamp(0.0, 1.0) } else { 1.0 }
    }

    /// Eq 13 with the fill factor: the signal of a target of radiance `radiance_w_m2_sr` seen through a path
    /// of transmittance `tau`, with projected area `projected_area_m2` at `range_m`.
    ///
    /// `projected_area_m2 = ∞` reproduces the paper (target fills the pixel).
    pub fn signal(&self, radiance_w_m2_sr: f64, tau: f64, projected_area_m2: f64, range_m: f64) -> DetectorSignal {
        let fill_factor = self.fill_factor(projected_area_m2, range_m);
        let aperture_area = std::f64::consts::PI * self.aperture_m * self.aperture_m / 4.0;
        // L · (R²A_d/f²) · (πD²/4)/R² — the R² cancel.
        let etendue = self.detector_area_m2() * aperture_area / (self.focal_length_m * self.focal_length_m);
        let power_w = radiance_w_m2_sr * etendue * tau * self.optics_transmittance * fill_factor;
        DetectorSignal { fill_factor, power_w, voltage_v: self.responsivity_v_per_w * power_w }
    }
}

/// Gray mapping of eqs 14–15 and the sensor's bit depth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GrayMapping {
    /// Voltage mapped to `g_min`, V.
    pub v_low: f64,
    /// Voltage mapped to `g_max`, V.
    pub v_high: f64,
    /// Lowest gray level.
    pub g_min: f64,
    /// Highest gray level, at most `2^bit_depth − 1`.
    pub g_max: f64,
    /// Bits per pixel, 1 … 16.
    pub bit_depth: u32,
}

impl Default for GrayMapping {
    fn default() -> Self {
        Self { v_low: 0.0, v_high: 2.0, g_min: 0.0, g_max: 65535.0, bit_depth: 16 }
    }
}

impl GrayMapping {
    /// Checks the parameters.
    ///
    /// # Errors
    /// [`SensorError`] if `v_high ≤ v_low`, `g_max ≤ g_min`, the levels leave `[0, 2^bit_depth − 1]` or the bit
    /// depth is not 1 … 16.
    pub fn validate(&self) -> Result<(), SensorError> {
        let bits = self.bit_depth;
        require("bit_depth", bits as f64, (1..=16).contains(&bits), "1 … 16")?;
        require("v_low", self.v_low, self.v_low.is_finite() && self.v_low.abs() <= 1e6, "[−1e6, 1e6]")?;
        let v_high_ok = self.v_high.is_finite() && self.v_high > self.v_low && self.v_high <= 1e6;
        require("v_high", self.v_high, v_high_ok, "(v_low, 1e6]")?;
        let top = self.max_level();
        require("g_min", self.g_min, (0.0..top).contains(&self.g_min), format!("[0, {top})"))?;
        require("g_max", self.g_max, self.g_max > self.g_min && self.g_max <= top, format!("(g_min, {top}]"))
    }

    /// The highest level the bit depth can hold, `2^bit_depth − 1`.
    pub fn max_level(&self) -> f64 {
        ((1u64 << self.bit_depth.min(32)) - 1) as f64
    }

    /// Gray value of voltage `voltage_v` (eqs 14–15), not yet quantized.
    pub fn gray(&self, voltage_v: f64) -> f64 {
        let v = voltage_v.clamp(self.v_low, self.v_high);
        self.g_min + (v - self.v_low) * (self.g_max - self.g_min) / (self.v_high - self.v_low)
    }

    /// Gray per volt of the linear part of the mapping.
    pub fn gain_per_v(&self) -> f64 {
        (self.g_max - self.g_min) / (self.v_high - self.v_low)
    }

    /// Rounds a gray value to the nearest level and clamps it to `[0, 2^bit_depth − 1]`; NaN maps to 0.
    pub fn quantize(&self, gray: f64) -> u16 {
        let g = gray.round();
        if g.is_nan() { 0 } else { g.clamp(0.0, self.max_level()) as u16 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq_13_when_target_fills_the_footprint() {
        let r = Radiometer::default();
        let s = r.signal(10.0, 0.5, f64::INFINITY, 5000.0);
        let ad = 17e-6f64.powi(2);
        let want = 1e8 * 10.0 * (5000.0f64.powi(2) * ad / 0.01) * (std::f64::consts::PI * 0.0025) / 25e6 * 0.5 * 0.8;
        assert_eq!(s.fill_factor, 1.0);
        assert!((s.voltage_v - want).abs() / want < 1e-14);
    }

    #[test]
    fn fill_factor_scales_with_projected_area() {
        let r = Radiometer::default();
        // footprint at 10 km: (10e3 * 17e-6 / 0.1)² = 1.7² = 2.89 m²
        let f = r.fill_factor(1.0, 10_000.0);
        assert!((f - 1.0 / 2.89).abs() < 1e-12);
        assert_eq!(r.fill_factor(10.0, 10_000.0), 1.0);
    }

    #[test]
    fn gray_mapping_clamps_and_maps() {
        let g = GrayMapping { v_low: 1.0, v_high: 3.0, g_min: 10.0, g_max: 250.0, bit_depth: 8 };
        g.validate().unwrap();
        assert_eq!(g.gray(0.0), 10.0);
        assert_eq!(g.gray(5.0), 250.0);
        assert_eq!(g.gray(2.0), 130.0);
        assert_eq!(g.quantize(300.0), 255);
        assert_eq!(g.quantize(-3.0), 0);
        assert_eq!(g.quantize(f64::NAN), 0);
        assert!(GrayMapping { v_high: 1.0, ..g }.validate().is_err());
        assert!(GrayMapping { g_max: 256.0, ..g }.validate().is_err());
    }
}
