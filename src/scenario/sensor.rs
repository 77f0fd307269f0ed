//! The `[sensor]` table: a camera preset and/or explicit optics, detector, ADC, optics blur and
//! non-idealities, resolved into one [`ResolvedSensor`].
//!
//! Every field but the geometry is optional: a `preset` supplies a whole published camera, and any field given
//! next to it overrides the preset's value. Without a preset, `width`, `height`, `pixel_pitch_um`,
//! `focal_length_mm`, `aperture_mm` and `band_um` are required and the detector defaults to an uncooled
//! microbolometer of NETD 50 mK at 300 K with a 14-bit ADC (2 DN of noise, offset 2048).

use serde::de::IgnoredAny;
use serde::{Deserialize, Serialize};

use super::{FieldError, Quality, fe};
use crate::imaging::background::SkyBlur;
use crate::imaging::camera::Intrinsics;
use crate::imaging::prefilter::PrefilterSettings;
use crate::imaging::psf::{ConvolutionMethod, PsfSpec};
use crate::imaging::target_blob::BlobSampling;
use crate::imaging::target_psf::{TargetMethod, TargetPsfSpec};
use crate::physics::ParamError;
use crate::physics::detector::{
    AdcGain, AdcSpec, Cone, Detector, DetectorKind, NoiseSpec, Optics, Preset, PresetValues, SensorModel,
};
use crate::physics::nonideal::NonIdealSpec;
use crate::physics::planck::Band;
use crate::physics::random::NormalSampler;

/// The camera: geometry, optics, detector, electronics.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSpec {
    /// A published camera supplying every value below that is not given.
    #[serde(default)]
    pub preset: Option<Preset>,
    /// Image width, px.
    #[serde(default)]
    pub width: Option<u32>,
    /// Image height, px.
    #[serde(default)]
    pub height: Option<u32>,
    /// Pixel pitch, µm.
    #[serde(default)]
    pub pixel_pitch_um: Option<f64>,
    /// Focal length, mm.
    #[serde(default)]
    pub focal_length_mm: Option<f64>,
    /// Entrance pupil diameter, mm.
    #[serde(default)]
    pub aperture_mm: Option<f64>,
    /// Spectral band, µm.
    #[serde(default)]
    pub band_um: Option<Band>,
    /// Optics transmittance, (0, 1].
    #[serde(default)]
    pub optics_transmittance: Option<f64>,
    /// Cone of light on a pixel: `aplanatic` (π/4N², eq 13) or `thin_lens` (π/(1 + 4N²)).
    #[serde(default)]
    pub cone: Option<Cone>,
    /// The detector.
    #[serde(default)]
    pub detector: DetectorToml,
    /// The ADC.
    #[serde(default)]
    pub adc: AdcToml,
    /// Temporal noise switches.
    #[serde(default)]
    pub noise: NoiseToml,
    /// Optics blur of the whole frame.
    #[serde(default)]
    pub psf: PsfToml,
    /// Fixed-pattern noise, dead pixels, drift, vignetting; absent: the detector kind's typical camera.
    #[serde(default)]
    pub nonideal: Option<NonIdealSpec>,
    /// How targets are drawn.
    #[serde(default)]
    pub blob: BlobSpec,
    /// Removed: see the migration message.
    #[serde(default, skip_serializing)]
    pub gray: Option<IgnoredAny>,
    /// Removed: now `detector.responsivity_v_per_w`.
    #[serde(default, skip_serializing)]
    pub responsivity_v_per_w: Option<IgnoredAny>,
    /// Removed: now `detector.fill_factor`.
    #[serde(default, skip_serializing)]
    pub detector_fill: Option<IgnoredAny>,
}

/// `[sensor.detector]`: every field optional (the preset's or the default's value otherwise).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorToml {
    /// `photon` (InSb, MCT: electrons, shot noise, a well) or `thermal` (microbolometer: volts).
    pub kind: Option<DetectorKind>,
    /// Photosensitive fraction of the pixel, (0, 1].
    pub fill_factor: Option<f64>,
    /// Quantum efficiency, (0, 1] (photon).
    pub quantum_efficiency: Option<f64>,
    /// Integration time, s (photon).
    pub integration_time_s: Option<f64>,
    /// Well capacity, electrons (photon).
    pub well_capacity_e: Option<f64>,
    /// Dark current, electrons/s (photon).
    pub dark_current_e_s: Option<f64>,
    /// Responsivity, V/W (thermal).
    pub responsivity_v_per_w: Option<f64>,
    /// Read noise, electrons (photon) or volts (thermal) rms; exclusive with `netd_mk`.
    pub read_noise: Option<f64>,
    /// NETD the noise is set to match, mK; exclusive with `read_noise`.
    pub netd_mk: Option<f64>,
    /// Scene temperature at which `netd_mk` holds, K (default 300).
    pub netd_reference_k: Option<f64>,
}

/// `[sensor.adc]`: bit depth, offset, and one way of giving the gain.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdcToml {
    /// Bits per sample, 1 … 16.
    pub bit_depth: Option<u32>,
    /// DN of zero signal.
    pub offset_dn: Option<f64>,
    /// Electrons per DN (photon detectors).
    pub gain_e_per_dn: Option<f64>,
    /// Microvolts per DN (thermal detectors).
    pub gain_uv_per_dn: Option<f64>,
    /// The gain that puts a 300 K scene's temporal noise at this many DN.
    pub noise_dn: Option<f64>,
    /// The gain that maps the well onto the levels above the offset (photon detectors).
    pub full_well: Option<bool>,
}

/// `[sensor.noise]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseToml {
    /// Add temporal noise at all.
    pub enabled: bool,
    /// Moved: `[quality] poisson_normal_threshold_e`.
    #[serde(skip_serializing)]
    pub poisson_normal_threshold: Option<IgnoredAny>,
    /// Removed: noise is now in electrons (see `sensor.detector`).
    #[serde(skip_serializing)]
    pub electrons_per_gray: Option<IgnoredAny>,
    /// Removed: see `sensor.detector.read_noise`.
    #[serde(skip_serializing)]
    pub read_noise_gray: Option<IgnoredAny>,
}

impl Default for NoiseToml {
    fn default() -> Self {
        Self { enabled: true, poisson_normal_threshold: None, electrons_per_gray: None, read_noise_gray: None }
    }
}

/// Temporal noise, resolved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseSettings {
    /// Add temporal noise at all.
    pub enabled: bool,
    /// Mean electron count below which shot noise is an exact Poisson count (`[quality]`).
    pub poisson_normal_threshold: f64,
    /// How the normal deviates are drawn (`[quality]`).
    pub normal_sampler: NormalSampler,
}

/// `[sensor.psf]`: the optics blur of the whole frame (and of the targets).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PsfToml {
    /// Blur at all.
    pub enabled: bool,
    /// Diffraction by the circular pupil.
    pub diffraction: bool,
    /// The pixel's photosensitive aperture.
    pub pixel_aperture: bool,
    /// Gaussian for aberrations and defocus, px rms.
    pub aberration_sigma_px: f64,
    /// Gaussian for line-of-sight motion during the integration time, px rms.
    pub motion_sigma_px: f64,
    /// Moved: `[quality] psf_energy_cutoff`.
    #[serde(skip_serializing)]
    pub energy_cutoff: Option<IgnoredAny>,
    /// Moved: `[quality] psf_method`.
    #[serde(skip_serializing)]
    pub method: Option<IgnoredAny>,
    /// Moved: `[quality] psf_skip_below_dn`.
    #[serde(skip_serializing)]
    pub skip_below_dn: Option<IgnoredAny>,
    /// Moved: `[quality] sky_blur`.
    #[serde(skip_serializing)]
    pub sky_blur: Option<IgnoredAny>,
    /// Moved: `[quality] prefilter_tolerance`.
    #[serde(skip_serializing)]
    pub prefilter_tolerance: Option<IgnoredAny>,
}

impl Default for PsfToml {
    fn default() -> Self {
        let p = PsfSpec::default();
        Self {
            enabled: true,
            diffraction: p.diffraction,
            pixel_aperture: p.pixel_aperture,
            aberration_sigma_px: p.aberration_sigma_px,
            motion_sigma_px: p.motion_sigma_px,
            energy_cutoff: None,
            method: None,
            skip_below_dn: None,
            sky_blur: None,
            prefilter_tolerance: None,
        }
    }
}

/// The optics blur, resolved: the physics from `[sensor.psf]`, the numerics from `[quality]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsfSettings {
    /// The PSF's parameters: what it holds from `[sensor.psf]`, where it and a target's region are cut from
    /// `[quality]`.
    pub spec: PsfSpec,
    /// How the kernel is applied to the frame.
    pub method: ConvolutionMethod,
    /// A 16 × 16 px tile of the frame is not blurred when the blur cannot change any of its pixels by more than
    /// this many DN (bounded from the background's second differences); 0 always blurs.
    pub skip_below_dn: f64,
    /// How the blur reaches a sky image.
    pub sky_blur: SkyBlur,
    /// How the prefiltered textures are made: the largest relative difference between a tile's plane-to-sensor
    /// Jacobian and its texture's, and the largest spacing of a texture's grid (px of the background's grid).
    /// Its `grid_error` is in DN here; [`PsfSettings::prefilter`] gives it in radiance.
    pub prefilter_dn: PrefilterSettings,
}

impl PsfSettings {
    /// How the prefiltered textures are made, with the grid's error budget in radiance: the settings' DN
    /// divided by `dn_per_radiance` (0, the finest grid, where either is not positive).
    pub fn prefilter(&self, dn_per_radiance: f64) -> PrefilterSettings {
        let grid_error = if self.prefilter_dn.grid_error > 0.0 && dn_per_radiance > 0.0 {
            self.prefilter_dn.grid_error / dn_per_radiance
        } else {
            0.0
        };
        PrefilterSettings { grid_error, ..self.prefilter_dn }
    }
}

/// The target model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetModel {
    /// The projected ellipse convolved with the optics PSF (default).
    #[default]
    Psf,
    /// The paper's generalized Gaussian (eqs 11–12) with `min_blur_px` and `beta`.
    Paper,
}

/// `[sensor.blob]`: how targets are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlobSpec {
    /// `psf` (ellipse ⊗ PSF) or `paper` (generalized Gaussian).
    pub model: TargetModel,
    /// Paper model: minimum blur, px.
    pub min_blur_px: f64,
    /// Paper model: shape exponent β (2 = Gaussian).
    pub beta: f64,
    /// Moved: `[quality] target_method`.
    #[serde(skip_serializing)]
    pub method: Option<IgnoredAny>,
    /// Moved: `[quality] blob_roi_fraction`.
    #[serde(skip_serializing)]
    pub roi_fraction: Option<IgnoredAny>,
    /// Moved: `[quality] blob_sampling`.
    #[serde(skip_serializing)]
    pub sampling: Option<IgnoredAny>,
}

impl Default for BlobSpec {
    fn default() -> Self {
        Self { model: TargetModel::Psf, min_blur_px: 0.7, beta: 2.0, method: None, roi_fraction: None, sampling: None }
    }
}

/// How targets are drawn, resolved: the model from `[sensor.blob]`, the numerics from `[quality]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobSettings {
    /// `psf` (ellipse ⊗ PSF) or `paper` (generalized Gaussian).
    pub model: TargetModel,
    /// Quadrature of the ellipse ⊗ PSF.
    pub method: TargetMethod,
    /// Spacing of its ring nodes, px.
    pub node_spacing_px: f64,
    /// Radius of the PSF's core drawn at each node, px (0: the whole PSF).
    pub core_px: usize,
    /// Paper model: minimum blur, px.
    pub min_blur_px: f64,
    /// Paper model: shape exponent β (2 = Gaussian).
    pub beta: f64,
    /// Paper model: the region of interest ends where the blob falls below this fraction of its peak.
    pub roi_fraction: f64,
    /// Paper model: pixel sampling.
    pub sampling: BlobSampling,
}

impl BlobSettings {
    /// The PSF-model quadrature settings.
    pub fn target_psf(&self) -> TargetPsfSpec {
        TargetPsfSpec {
            method: self.method,
            node_spacing_px: self.node_spacing_px,
            core_px: self.core_px,
            ..TargetPsfSpec::default()
        }
    }
}

/// The sensor with every value decided and checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResolvedSensor {
    /// Geometry.
    pub intrinsics: Intrinsics,
    /// Radiometry: band, optics, detector, ADC.
    pub model: SensorModel,
    /// Temporal noise switches.
    pub noise: NoiseSettings,
    /// Optics blur; `None` when off.
    pub psf: Option<PsfSettings>,
    /// Non-idealities.
    pub nonideal: NonIdealSpec,
    /// Target drawing.
    pub blob: BlobSettings,
    /// Frame rate the preset's camera runs at, if a preset was named.
    pub preset_frame_rate_hz: Option<f64>,
    /// `[quality] background_step_px`.
    pub background_step_px: usize,
}

const MIGRATION: &str = "was removed: the sensor is now a physical camera (optics, detector in electrons or volts, \
     ADC in DN); use `preset = \"paper_lwir_256\"` (or `cooled_mwir_insb`, `uncooled_lwir_microbolometer`) and \
     override `[sensor.detector]` / `[sensor.adc]` fields (docs/scenarios.md, \"Migrating\")";

/// The message for a field that moved to `[quality]`.
pub(crate) fn moved_to_quality(new: &str) -> String {
    format!(
        "moved: accuracy settings are now in `[quality]` (a preset, `draft`, `standard` or `reference`, and \
         overrides); write `[quality] {new} = …` (docs/scenarios.md, \"Quality\")"
    )
}

impl SensorSpec {
    /// Resolves the preset and the overrides, and checks every value; the numerical settings come from `quality`.
    ///
    /// # Errors
    /// A [`FieldError`] under `sensor.`.
    pub fn resolve(&self, quality: &Quality) -> Result<ResolvedSensor, FieldError> {
        for (given, path, new) in [
            (
                self.noise.poisson_normal_threshold.is_some(),
                "noise.poisson_normal_threshold",
                "poisson_normal_threshold_e",
            ),
            (self.psf.energy_cutoff.is_some(), "psf.energy_cutoff", "psf_energy_cutoff"),
            (self.psf.method.is_some(), "psf.method", "psf_method"),
            (self.psf.skip_below_dn.is_some(), "psf.skip_below_dn", "psf_skip_below_dn"),
            (self.psf.sky_blur.is_some(), "psf.sky_blur", "sky_blur"),
            (self.psf.prefilter_tolerance.is_some(), "psf.prefilter_tolerance", "prefilter_tolerance"),
            (self.blob.method.is_some(), "blob.method", "target_method"),
            (self.blob.roi_fraction.is_some(), "blob.roi_fraction", "blob_roi_fraction"),
            (self.blob.sampling.is_some(), "blob.sampling", "blob_sampling"),
        ] {
            if given {
                return Err(fe(format!("sensor.{path}"), moved_to_quality(new)));
            }
        }
        if self.gray.is_some() {
            return Err(fe(
                "sensor.gray",
                format!("the gray mapping {MIGRATION}; the ADC's `bit_depth`, `offset_dn` and gain replace it"),
            ));
        }
        if self.responsivity_v_per_w.is_some() {
            return Err(fe(
                "sensor.responsivity_v_per_w",
                "moved: write it as `[sensor.detector] responsivity_v_per_w = …` (with `kind = \"thermal\"`)",
            ));
        }
        if self.detector_fill.is_some() {
            return Err(fe("sensor.detector_fill", "moved: write it as `[sensor.detector] fill_factor = …`"));
        }
        if self.noise.electrons_per_gray.is_some() {
            return Err(fe("sensor.noise.electrons_per_gray", format!("the gray-level noise model {MIGRATION}")));
        }
        if self.noise.read_noise_gray.is_some() {
            return Err(fe(
                "sensor.noise.read_noise_gray",
                "was removed: give `[sensor.detector] read_noise` (electrons or volts) or `netd_mk`",
            ));
        }
        let base: Option<PresetValues> = self.preset.map(Preset::values);
        let need = |name: &str| fe(format!("sensor.{name}"), "is required when no `preset` is given");
        let width = self.width.or(base.map(|b| b.width)).ok_or_else(|| need("width"))?;
        let height = self.height.or(base.map(|b| b.height)).ok_or_else(|| need("height"))?;
        let pitch_m = match self.pixel_pitch_um {
            Some(p) => p * 1e-6,
            None => base.map(|b| b.detector.pixel_pitch_m).ok_or_else(|| need("pixel_pitch_um"))?,
        };
        let focal_m = match self.focal_length_mm {
            Some(f) => f * 1e-3,
            None => base.map(|b| b.optics.focal_length_m).ok_or_else(|| need("focal_length_mm"))?,
        };
        let aperture_m = match self.aperture_mm {
            Some(a) => a * 1e-3,
            None => base.map(|b| b.optics.aperture_m).ok_or_else(|| need("aperture_mm"))?,
        };
        let band = self.band_um.or(base.map(|b| b.band)).ok_or_else(|| need("band_um"))?;
        for (name, given, lo, hi, unit) in [
            ("focal_length_mm", self.focal_length_mm, 0.1, 1e5, "mm"),
            ("aperture_mm", self.aperture_mm, 0.1, 1e4, "mm"),
            ("pixel_pitch_um", self.pixel_pitch_um, 0.1, 1e3, "µm"),
        ] {
            if let Some(v) = given
                && !(v.is_finite() && (lo..=hi).contains(&v))
            {
                return Err(fe(
                    format!("sensor.{name}"),
                    format!("{} must be in [{lo}, {hi}] {unit}", crate::physics::Num(v)),
                ));
            }
        }
        let intrinsics = Intrinsics::try_new(width, height, focal_m, pitch_m).map_err(|e| {
            let name = match &e {
                crate::imaging::camera::CameraError::OutOfRange(p) => match p.name {
                    "focal_length_m" => "focal_length_mm",
                    "pixel_pitch_m" => "pixel_pitch_um",
                    other => other,
                },
                _ => "width",
            };
            fe(format!("sensor.{name}"), e)
        })?;
        let optics = Optics {
            focal_length_m: focal_m,
            aperture_m,
            transmittance: self.optics_transmittance.or(base.map(|b| b.optics.transmittance)).unwrap_or(0.8),
            cone: self.cone.or(base.map(|b| b.optics.cone)).unwrap_or_default(),
        };
        let d = &self.detector;
        let mut det = base.map_or_else(default_detector, |b| b.detector);
        det.pixel_pitch_m = pitch_m;
        if let Some(k) = d.kind
            && k != det.kind
        {
            // switching the kind starts from that kind's defaults
            det = match k {
                DetectorKind::Thermal => default_detector(),
                DetectorKind::Photon => Preset::CooledMwirInsb.values().detector,
            };
            det.pixel_pitch_m = pitch_m;
        }
        macro_rules! set {
            ($field:ident) => {
                if let Some(v) = d.$field {
                    det.$field = v;
                }
            };
        }
        set!(fill_factor);
        set!(quantum_efficiency);
        set!(integration_time_s);
        set!(well_capacity_e);
        set!(dark_current_e_s);
        set!(responsivity_v_per_w);
        match (d.read_noise, d.netd_mk) {
            (Some(_), Some(_)) => {
                return Err(fe("sensor.detector.netd_mk", "give either `read_noise` or `netd_mk`, not both"));
            }
            (Some(r), None) => det.noise = NoiseSpec::Read(r),
            (None, Some(n)) => {
                det.noise = NoiseSpec::Netd { netd_k: n * 1e-3, reference_temp_k: d.netd_reference_k.unwrap_or(300.0) }
            }
            (None, None) => {
                if let (Some(t), NoiseSpec::Netd { netd_k, .. }) = (d.netd_reference_k, det.noise) {
                    det.noise = NoiseSpec::Netd { netd_k, reference_temp_k: t };
                }
            }
        }
        let a = &self.adc;
        let mut adc = match base {
            Some(b) if b.detector.kind == det.kind => b.adc,
            _ => default_adc(det.kind),
        };
        if let Some(b) = a.bit_depth {
            adc.bit_depth = b;
        }
        if let Some(o) = a.offset_dn {
            adc.offset_dn = o;
        }
        let gains =
            [a.gain_e_per_dn.is_some(), a.gain_uv_per_dn.is_some(), a.noise_dn.is_some(), a.full_well == Some(true)];
        if gains.iter().filter(|&&g| g).count() > 1 {
            return Err(fe(
                "sensor.adc",
                "give at most one of `gain_e_per_dn`, `gain_uv_per_dn`, `noise_dn`, `full_well`",
            ));
        }
        if let Some(g) = a.gain_e_per_dn {
            if det.kind != DetectorKind::Photon {
                return Err(fe(
                    "sensor.adc.gain_e_per_dn",
                    "is for photon detectors; a thermal one takes `gain_uv_per_dn`",
                ));
            }
            adc.gain = AdcGain::PerDn(g);
        }
        if let Some(g) = a.gain_uv_per_dn {
            if det.kind != DetectorKind::Thermal {
                return Err(fe(
                    "sensor.adc.gain_uv_per_dn",
                    "is for thermal detectors; a photon one takes `gain_e_per_dn`",
                ));
            }
            adc.gain = AdcGain::PerDn(g * 1e-6);
        }
        if let Some(n) = a.noise_dn {
            adc.gain = AdcGain::NoiseDn(n);
        }
        if a.full_well == Some(true) {
            adc.gain = AdcGain::FullWell;
        }
        let model = SensorModel::new(band, optics, det, adc).map_err(|e| sensor_param_error(&e, self))?;
        let psf = if self.psf.enabled {
            let p = &self.psf;
            let settings = PsfSettings {
                spec: PsfSpec {
                    diffraction: p.diffraction,
                    pixel_aperture: p.pixel_aperture,
                    aberration_sigma_px: p.aberration_sigma_px,
                    motion_sigma_px: p.motion_sigma_px,
                    energy_cutoff: quality.psf_energy_cutoff,
                    region_energy_cutoff: quality.region_energy_cutoff,
                },
                method: quality.psf_method,
                skip_below_dn: quality.psf_skip_below_dn,
                sky_blur: quality.sky_blur,
                prefilter_dn: PrefilterSettings {
                    tolerance: quality.prefilter_tolerance,
                    spacing_px: quality.prefilter_spacing_px,
                    grid_error: quality.prefilter_grid_error_dn,
                },
            };
            settings.spec.validate().map_err(|e| {
                // the cuts come from [quality]
                let switch = match e.name {
                    "energy_cutoff" => Some("psf_energy_cutoff"),
                    "region_energy_cutoff" => Some("region_energy_cutoff"),
                    _ => None,
                };
                match switch {
                    Some(s) => fe(format!("quality.{s}"), format!("{} is outside {}", super::num(e.value), e.range)),
                    None => super::at("sensor.psf")(e),
                }
            })?;
            Some(settings)
        } else {
            None
        };
        let nonideal = match self.nonideal {
            Some(s) => s,
            None => match det.kind {
                DetectorKind::Photon => NonIdealSpec::cooled(),
                DetectorKind::Thermal => NonIdealSpec::uncooled(),
            },
        };
        nonideal.validate().map_err(super::at("sensor.nonideal"))?;
        let b = &self.blob;
        if !(b.min_blur_px.is_finite() && (0.0..=100.0).contains(&b.min_blur_px)) {
            return Err(fe("sensor.blob.min_blur_px", format!("{} must be in [0, 100]", b.min_blur_px)));
        }
        if !(b.beta.is_finite() && (0.1..=1000.0).contains(&b.beta)) {
            return Err(fe("sensor.blob.beta", format!("{} must be in [0.1, 1000]", b.beta)));
        }
        Ok(ResolvedSensor {
            intrinsics,
            model,
            noise: NoiseSettings {
                enabled: self.noise.enabled,
                poisson_normal_threshold: quality.poisson_normal_threshold_e,
                normal_sampler: quality.normal_sampler,
            },
            psf,
            nonideal,
            blob: BlobSettings {
                model: b.model,
                method: quality.target_method,
                node_spacing_px: quality.target_node_spacing_px,
                core_px: quality.target_psf_core_px,
                min_blur_px: b.min_blur_px,
                beta: b.beta,
                roi_fraction: quality.blob_roi_fraction,
                sampling: quality.blob_sampling,
            },
            preset_frame_rate_hz: base.map(|b| b.frame_rate_hz),
            background_step_px: quality.background_step_px,
        })
    }
}

/// Maps a [`SensorModel::new`] error to the scenario field that set the value.
fn sensor_param_error(e: &ParamError, spec: &SensorSpec) -> FieldError {
    let path = match e.name {
        "focal_length_m" => "sensor.focal_length_mm".to_owned(),
        "aperture_m" => "sensor.aperture_mm".to_owned(),
        "pixel_pitch_m" => "sensor.pixel_pitch_um".to_owned(),
        "optics_transmittance" => "sensor.optics_transmittance".to_owned(),
        "bit_depth" | "offset_dn" | "noise_dn" => format!("sensor.adc.{}", e.name),
        "gain" => {
            if spec.adc.gain_e_per_dn.is_some() {
                "sensor.adc.gain_e_per_dn".to_owned()
            } else if spec.adc.gain_uv_per_dn.is_some() {
                "sensor.adc.gain_uv_per_dn".to_owned()
            } else {
                "sensor.adc".to_owned()
            }
        }
        "reference_temp_k" => "sensor.detector.netd_reference_k".to_owned(),
        other => format!("sensor.detector.{other}"),
    };
    // the thermal-detector `full_well` gain has no value to show
    let value =
        if e.name == "gain" && e.value.is_nan() { String::new() } else { format!("{} ", crate::physics::Num(e.value)) };
    fe(path, format!("{value}is outside its allowed range {}", e.range))
}

/// Without a preset: an uncooled microbolometer with NETD 50 mK at 300 K.
fn default_detector() -> Detector {
    let mut d = Preset::PaperLwir256.values().detector;
    d.noise = NoiseSpec::Netd { netd_k: 0.05, reference_temp_k: 300.0 };
    d
}

/// A 14-bit ADC: thermal detectors get 2 DN of noise above a 2048 offset, photon detectors the well over the
/// levels above 1000.
fn default_adc(kind: DetectorKind) -> AdcSpec {
    match kind {
        DetectorKind::Thermal => AdcSpec { bit_depth: 14, gain: AdcGain::NoiseDn(2.0), offset_dn: 2048.0 },
        DetectorKind::Photon => AdcSpec { bit_depth: 14, gain: AdcGain::FullWell, offset_dn: 1000.0 },
    }
}
