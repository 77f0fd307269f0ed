//! The sky as a radiance field: calibrated sky images, generated cloud layers baked over the clear-sky dome,
//! and the dome itself for every ray that meets no layer.
//!
//! Every value here is band radiance in the detector's measure (W m⁻² sr⁻¹ for thermal detectors, photons
//! s⁻¹ m⁻² sr⁻¹ for photon detectors), the same scale as the targets' apparent radiance.
//!
//! - A **user image** is calibrated ([`SkyCalibration`]): its values are brightness temperatures in the band
//!   (directly, or through a linear map of a value range onto a temperature range), or radiance per unit.
//! - A **generated layer** ([`super::sky_gen`]) of opacity `α` and temperature offset `δT` is baked once, for
//!   the observer's starting position: texel `p` at world point `P`, seen along `d = P − eye`, becomes
//!   `α·[τ·B(T∞(P_z) + ΔT_base + δT) + (1 − τ)·B(T∞(mid))] + (1 − α)·L_dome(d)`, with `τ` the scenario's
//!   transmittance over the path and `T∞(mid)` the air at the path's middle height: a cloud is a blackbody at
//!   its own height's air temperature (plus an offset), seen through the air in front of it, over the clear sky.
//! - A user image can be taken as the radiance **at its plane** (`[atmosphere] sky_path`): each texel is then seen
//!   through the path from the observer's start, `τ·L + L_path`, as a layer's clouds are.
//! - **Misses** (rays that meet no image) take the dome's radiance along their own direction, so the horizon
//!   and the ground below it appear where the view reaches them, never a black band.

use glam::DVec2;
use serde::{Deserialize, Serialize};

use super::camera::Camera;
use super::frame::Frame;
use super::sky_gen::CloudLayer;
use super::sky_plane::{SkyError, SkyImage, SkyPlane};
use crate::physics::ParamError;
use crate::physics::planck::{Band, Measure, band_radiance_in};
use crate::physics::sky::Dome;
use crate::physics::transmittance::PathTransmittance;

/// How a sky image's values become radiance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum SkyCalibration {
    /// Each value is a brightness temperature `offset_k + scale_k · value`, K (`irsim sky` writes 0.01 K per
    /// level: `scale_k = 0.01`).
    Kelvin {
        /// Kelvin per unit of the image.
        scale_k: f64,
        /// Kelvin at value 0.
        #[serde(default)]
        offset_k: f64,
    },
    /// The image's `value_range` maps linearly onto the brightness temperatures `temp_range_k`.
    Temperature {
        /// Two image values.
        #[serde(with = "crate::physics::exact::pair")]
        value_range: [f64; 2],
        /// Their brightness temperatures, K.
        #[serde(with = "crate::physics::exact::pair")]
        temp_range_k: [f64; 2],
    },
    /// Radiance in the detector's measure: `offset + gain · value`.
    Radiance {
        /// Radiance per unit of the image.
        gain: f64,
        /// Radiance at value 0.
        #[serde(default)]
        offset: f64,
    },
}

impl SkyCalibration {
    /// Brightness temperature of image value `v`, K (`None` for radiance calibrations).
    pub fn temperature_k(&self, v: f64) -> Option<f64> {
        match *self {
            SkyCalibration::Kelvin { scale_k, offset_k } => Some(offset_k + scale_k * v),
            SkyCalibration::Temperature { value_range: [v0, v1], temp_range_k: [t0, t1] } => {
                Some(t0 + (v - v0) / (v1 - v0) * (t1 - t0))
            }
            SkyCalibration::Radiance { .. } => None,
        }
    }

    /// Checks the parameters: the name of the bad field and why.
    ///
    /// # Errors
    /// The field and the message.
    pub fn validate(&self) -> Result<(), ParamError> {
        let bad = |name, value, range: &str| Err(ParamError { name, value, range: range.into() });
        match *self {
            SkyCalibration::Kelvin { scale_k, offset_k } => {
                if !(scale_k.is_finite() && scale_k != 0.0 && scale_k.abs() <= 1e6) {
                    return bad("scale_k", scale_k, "[−1e6, 1e6] K per unit, not 0");
                }
                ParamError::check_range("offset_k", offset_k, -1e6, 1e6)?;
            }
            SkyCalibration::Temperature { value_range, temp_range_k } => {
                for v in value_range {
                    ParamError::check_range("value_range", v, -1e30, 1e30)?;
                }
                if value_range[0] == value_range[1] {
                    return bad("value_range", value_range[1], "two different values");
                }
                for t in temp_range_k {
                    ParamError::check_range("temp_range_k", t, RadianceLut::LO_K, RadianceLut::HI_K)?;
                }
            }
            SkyCalibration::Radiance { gain, offset } => {
                ParamError::check_range("gain", gain, -1e30, 1e30)?;
                ParamError::check_range("offset", offset, -1e30, 1e30)?;
            }
        }
        Ok(())
    }
}

/// Band radiance against temperature from 40 to 700 K: tabulated every `step_k` and interpolated linearly, or
/// (step 0) the Planck series for every value.
///
/// The table is exact (the series of [`band_radiance_in`]) at its nodes; between them the error of linear
/// interpolation is `h²/8·L''`: at the `standard` step of 0.02 K below 2e-7 of `L` for 3–14 µm bands above
/// 150 K (test `lut_matches_the_exact_radiance`).
#[derive(Debug, Clone)]
pub struct RadianceLut {
    values: Vec<f64>,
    step_k: f64,
    band: Band,
    measure: Measure,
}

impl RadianceLut {
    /// Lowest temperature of the table, K.
    pub const LO_K: f64 = 40.0;
    /// Highest temperature of the table, K.
    pub const HI_K: f64 = 700.0;

    /// The table for a band and measure, every `step_k` (clamped to 0.001 … 5 K); 0 (or less) makes no table.
    pub fn new(band: Band, measure: Measure, step_k: f64) -> Self {
        if !(step_k > 0.0) {
            return Self { values: Vec::new(), step_k: 0.0, band, measure };
        }
        let step_k = step_k.clamp(1e-3, 5.0);
        let n = ((Self::HI_K - Self::LO_K) / step_k).ceil() as usize + 1;
        use rayon::prelude::*;
        let values = (0..n)
            .into_par_iter()
            .with_min_len(1024)
            .map(|i| band_radiance_in(measure, band, Self::LO_K + i as f64 * step_k, 1.0))
            .collect();
        Self { values, step_k, band, measure }
    }

    /// Radiance at `temp_k` (clamped to the table's range; NaN gives the lowest).
    #[inline]
    pub fn radiance(&self, temp_k: f64) -> f64 {
        if self.values.len() < 2 {
            let t = if temp_k.is_nan() { Self::LO_K } else { temp_k.clamp(Self::LO_K, Self::HI_K) };
            return band_radiance_in(self.measure, self.band, t, 1.0);
        }
        let x = ((temp_k - Self::LO_K) / self.step_k).clamp(0.0, (self.values.len() - 1) as f64);
        let x = if x.is_nan() { 0.0 } else { x };
        let i = (x as usize).min(self.values.len() - 2);
        let t = x - i as f64;
        self.values[i] + (self.values[i + 1] - self.values[i]) * t
    }
}

/// A sky image's values turned into radiance.
///
/// # Errors
/// [`SkyError::Image`] (`path` names the image) if a value maps outside the table's temperatures or to a
/// non-finite radiance.
pub fn calibrate(
    image: &SkyImage,
    calibration: &SkyCalibration,
    lut: &RadianceLut,
    path: &str,
) -> Result<SkyImage, SkyError> {
    let mut out = Vec::with_capacity(image.pixels().len());
    // the radiance a calibration may give: that of the hottest temperature the calibrations take
    let highest = lut.radiance(RadianceLut::HI_K);
    // an 8- or 16-bit image holds at most 65 536 values: each whole value's radiance is worked out once, at its
    // first pixel (NaN: not yet), the same value a pixel of its own would get
    let mut known = vec![f32::NAN; 1 << 16];
    for (i, &v) in image.pixels().iter().enumerate() {
        // the value's slot if it is whole (by its bits: −0 is not 0, which a radiance offset of −0 would tell apart)
        let slot =
            ((0.0..=65_535.0).contains(&v) && f32::from(v as u16).to_bits() == v.to_bits()).then_some(v as usize);
        if let Some(k) = slot
            && !known[k].is_nan()
        {
            out.push(known[k]);
            continue;
        }
        let l = match calibration.temperature_k(f64::from(v)) {
            Some(t) => {
                if !(RadianceLut::LO_K..=RadianceLut::HI_K).contains(&t) {
                    return Err(SkyError::Image {
                        path: path.to_owned(),
                        message: format!(
                            "pixel ({}, {}) = {v} calibrates to {t:.2} K, outside [{}, {}] K",
                            i % image.width(),
                            i / image.width(),
                            RadianceLut::LO_K,
                            RadianceLut::HI_K
                        ),
                    });
                }
                lut.radiance(t)
            }
            None => match *calibration {
                SkyCalibration::Radiance { gain, offset } => offset + gain * f64::from(v),
                _ => unreachable!("temperature calibrations return Some"),
            },
        };
        if !(l.is_finite() && l >= 0.0 && l <= highest) {
            return Err(SkyError::Image {
                path: path.to_owned(),
                message: format!(
                    "pixel ({}, {}) = {v} calibrates to radiance {}, outside [0, {}] (0 K … a {} K black body)",
                    i % image.width(),
                    i / image.width(),
                    crate::physics::Num(l),
                    crate::physics::Num(highest),
                    RadianceLut::HI_K
                ),
            });
        }
        if let Some(k) = slot {
            known[k] = l as f32;
        }
        out.push(l as f32);
    }
    SkyImage::from_f32(image.width(), image.height(), out)
}

/// What baking a generated layer needs.
pub struct LayerBake<'a> {
    /// The layer.
    pub layer: &'a CloudLayer,
    /// Where it sits (any image of the baked size, the layer's with the margin, placed as the scenario says
    /// with the margin around it).
    pub plane: &'a SkyPlane,
    /// Texels of clear sky baked around the layer on every side (`[quality] layer_margin_px`).
    pub margin: usize,
    /// The observer's starting position, m.
    pub eye_m: glam::DVec3,
    /// The clear sky behind it.
    pub dome: &'a Dome,
    /// Air temperature at an altitude, K.
    pub air_temp_k: &'a (dyn Fn(f64) -> f64 + Sync),
    /// Transmittance of the path eye → cloud.
    pub atmosphere: &'a (dyn PathTransmittance + Sync),
    /// Radiance of a temperature.
    pub lut: &'a RadianceLut,
    /// Cloud-base temperature relative to the air at its height, K.
    pub cloud_offset_k: f64,
    /// Cloud-base altitude, m: no cloud below it, fading in over [`CLOUD_BASE_FADE_M`] above it.
    pub cloud_base_m: Option<f64>,
}

/// Height over which a layer's clouds fade in above the cloud base, m.
pub const CLOUD_BASE_FADE_M: f64 = 100.0;

/// The layer as radiance texels over the dome (see the module's documentation), with `margin` texels of the
/// dome alone (no cloud) on every side: `(width + 2·margin) × (height + 2·margin)` texels.
///
/// # Errors
/// Only if the layer is empty.
pub fn bake_layer(b: &LayerBake<'_>) -> Result<SkyImage, SkyError> {
    use rayon::prelude::*;
    let (w, h) = (b.layer.width, b.layer.height);
    let m = b.margin;
    let (bw, bh) = (w + 2 * m, h + 2 * m);
    let mut out = vec![0f32; bw * bh];
    out.par_chunks_mut(bw).enumerate().for_each(|(y, row)| {
        for (x, texel) in row.iter_mut().enumerate() {
            let p = b.plane.world_point(DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
            let d = p - b.eye_m;
            let dome = f64::from(b.dome.radiance_toward(d));
            // the layer's own texel, if this one is not in the margin
            let inside = (x.checked_sub(m).filter(|&lx| lx < w)).zip(y.checked_sub(m).filter(|&ly| ly < h));
            let Some((lx, ly)) = inside else {
                *texel = dome as f32;
                continue;
            };
            let i = ly * w + lx;
            let base = b.cloud_base_m.map_or(1.0, |base| ((p.z - base) / CLOUD_BASE_FADE_M).clamp(0.0, 1.0));
            let alpha = f64::from(b.layer.opacity[i]) * base;
            *texel = if alpha > 0.0 {
                let t_cloud = (b.air_temp_k)(p.z) + b.cloud_offset_k + f64::from(b.layer.temp_offset_k[i]);
                let cloud = through_path(b.atmosphere, b.air_temp_k, b.lut, b.eye_m, p, b.lut.radiance(t_cloud));
                (alpha * cloud + (1.0 - alpha) * dome) as f32
            } else {
                dome as f32
            };
        }
    });
    SkyImage::from_f32(bw, bh, out)
}

/// `plane`'s image with `margin` texels of the dome on every side, each of the image's texels where it was (texel
/// `i` of the image is texel `i + margin` of the result): each margin texel is the dome's radiance toward its world
/// point from `eye_m`, what a ray from there past the image's edge sees.
pub fn with_dome_margin(plane: &SkyPlane, margin: usize, eye_m: glam::DVec3, dome: &Dome) -> SkyImage {
    use rayon::prelude::*;
    let image = plane.image();
    let (w, h, stride) = (image.width(), image.height(), image.stride());
    let (bw, bh) = (w + 2 * margin, h + 2 * margin);
    let source = image.pixels();
    let m = margin as f64;
    let mut out = vec![0f32; bw * bh];
    out.par_chunks_mut(bw).enumerate().for_each(|(y, row)| {
        let iy = y.checked_sub(margin).filter(|&iy| iy < h);
        for (x, texel) in row.iter_mut().enumerate() {
            *texel = match (x.checked_sub(margin).filter(|&ix| ix < w), iy) {
                (Some(ix), Some(iy)) => source[iy * stride + ix],
                _ => {
                    let p = plane.world_point(DVec2::new(x as f64 + 0.5 - m, y as f64 + 0.5 - m));
                    dome.radiance_toward(p - eye_m)
                }
            };
        }
    });
    SkyImage::from_finite(bw, bh, out)
}

/// Radiance `at` a world point `p` as seen from `eye_m`: `τ·at` plus the path's own radiance (the atmosphere's,
/// or `(1 − τ)·B(T∞)` at the path's middle height).
fn through_path(
    atmosphere: &(dyn PathTransmittance + Sync),
    air_temp_k: &(dyn Fn(f64) -> f64 + Sync),
    lut: &RadianceLut,
    eye_m: glam::DVec3,
    p: glam::DVec3,
    at: f64,
) -> f64 {
    let (tau, path) = atmosphere.transmittance_and_path(eye_m, p);
    let tau = tau.clamp(0.0, 1.0);
    let path = match path {
        Some(l) => l,
        None => (1.0 - tau) * lut.radiance(air_temp_k(0.5 * (p.z + eye_m.z))),
    };
    tau * at + path
}

/// A calibrated sky image taken as the radiance at its plane, seen through the air from `eye_m`: each texel
/// becomes `τ·L + L_path` over the path from the eye to the texel's world point.
pub fn through_air(
    image: &SkyImage,
    plane: &SkyPlane,
    eye_m: glam::DVec3,
    atmosphere: &(dyn PathTransmittance + Sync),
    air_temp_k: &(dyn Fn(f64) -> f64 + Sync),
    lut: &RadianceLut,
) -> Result<SkyImage, SkyError> {
    use rayon::prelude::*;
    let (w, h) = (image.width(), image.height());
    let source = image.pixels();
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, texel) in row.iter_mut().enumerate() {
            let p = plane.world_point(DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
            let at = f64::from(source[y * w + x]);
            *texel = through_path(atmosphere, air_temp_k, lut, eye_m, p, at) as f32;
        }
    });
    SkyImage::from_f32(w, h, out)
}

/// Writes the dome's radiance along each pixel's ray into `frame`; with `only_nan`, only into pixels that are
/// NaN (the misses of a sky-plane render); with `tiles` (a tile's side in pixels and a row-major mark for each
/// tile), only into the marked tiles' pixels, and only those are read: each value is the one a whole frame's
/// render gives its pixel.
///
/// # Panics
/// If `tiles` gives a side of 0 or not one mark for each tile of the frame.
pub fn render_dome(camera: &Camera, dome: &Dome, frame: &mut Frame, only_nan: bool, tiles: Option<(usize, &[bool])>) {
    use rayon::prelude::*;
    let width = frame.width();
    let r = camera.camera_to_world;
    let f = camera.intrinsics.focal_px();
    let c = camera.intrinsics.principal_point();
    if let Some((t, marks)) = tiles {
        assert!(t > 0 && marks.len() == width.div_ceil(t) * frame.height().div_ceil(t), "a mark for each tile");
    }
    // rows in batches: one row is too little work to be worth a task
    let rows_per_task = crate::physics::simd::rows_per_task(width, 2);
    frame.pixels_mut().par_chunks_mut(width).enumerate().with_min_len(rows_per_task).for_each(|(j, row)| {
        let y = (j as f64 + 0.5 - c.y) / f;
        // the unnormalised ray is linear in the column
        let base = r * glam::DVec3::new((0.5 - c.x) / f, y, 1.0);
        let step = r.x_axis / f;
        // the pixels `x0..x1` of the row
        let mut span = |x0: usize, x1: usize| {
            let part = &mut row[x0..x1];
            // a scan of the whole span (no early exit) is one vector compare per sixteen pixels
            let any_nan = || {
                crate::physics::simd::widest(
                    #[inline(always)]
                    || part.iter().fold(false, |any, v| any | v.is_nan()),
                )
            };
            if only_nan && !any_nan() {
                return;
            }
            crate::physics::simd::widest(
                #[inline(always)]
                || dome.radiance_along_from(base, step, x0, part, only_nan),
            );
        };
        let Some((t, marks)) = tiles else {
            span(0, width);
            return;
        };
        // each run of marked tiles along the row's band of tiles
        let tw = width.div_ceil(t);
        let band = &marks[(j / t) * tw..(j / t + 1) * tw];
        let mut tx = 0;
        while tx < tw {
            if !band[tx] {
                tx += 1;
                continue;
            }
            let start = tx;
            while tx < tw && band[tx] {
                tx += 1;
            }
            span(start * t, (tx * t).min(width));
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_gives_each_pixel_its_own_value_and_names_the_first_bad_pixel() {
        let lut = RadianceLut::new(Band::LWIR_8_12, Measure::Energy, 0.02);
        let cal = SkyCalibration::Temperature { value_range: [0.0, 1000.0], temp_range_k: [205.0, 265.0] };
        // repeated whole values (worked out once), values between them, and one below 0
        let pixels = vec![0.0, 700.0, 700.0, 0.5, 999.75, 700.0, 65_535.0 / 100.0, -0.0, 12.0, 0.5];
        let image = SkyImage::from_f32(5, 2, pixels.clone()).unwrap();
        let got = calibrate(&image, &cal, &lut, "sky").unwrap();
        for (&v, &l) in pixels.iter().zip(got.pixels()) {
            let want = lut.radiance(cal.temperature_k(f64::from(v)).unwrap()) as f32;
            assert_eq!(l.to_bits(), want.to_bits(), "{v}");
        }
        // a value past 700 K, at pixels (2, 0) and (1, 1): the error names the first
        let hot = SkyImage::from_f32(3, 2, vec![10.0, 20.0, 60_000.0, 10.0, 60_000.0, 5.0]).unwrap();
        match calibrate(&hot, &cal, &lut, "sky") {
            Err(SkyError::Image { message, .. }) => assert!(message.starts_with("pixel (2, 0) = 60000"), "{message}"),
            other => panic!("{other:?}"),
        }
    }
}
