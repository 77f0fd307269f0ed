//! The camera as a radiometer: optics, a photon or thermal detector, and its ADC (eq 13 for extended sources).
//!
//! **Optics.** A pixel looking at a scene of radiance `L` (uniform over the pixel's footprint) receives the
//! focal-plane irradiance `E = L·τ_opt·Ω_cone`, where `Ω_cone` is the projected solid angle of the cone of light
//! converging on it. For a lens obeying the sine condition (aplanatic, as well-corrected infrared lenses are)
//! `Ω_cone = π/(4N²)` with `N = f/D`: exactly eq 13's `πD²/(4f²)`, now written for any extended source. A thin
//! paraxial lens gives `π/(1 + 4N²)`, 20 % less at F/1 ([`Cone::ThinLens`]). The power on the photosensitive area
//! `A_d = fill·pitch²` is `E·A_d`. Off axis the irradiance falls as cos⁴θ (see `nonideal`).
//!
//! **Detectors.** A *photon* detector (InSb, MCT, T2SL) counts photons: it collects
//! `N = η·t_int·A_d·Ω_cone·τ_opt·L_q` electrons, `L_q` the band photon radiance, plus `i_dark·t_int` dark
//! electrons, with Poisson (shot) noise on all of them, a Gaussian read noise `σ_r` e⁻, and saturation at the
//! well capacity. A *thermal* detector (microbolometer) responds to power: `V = R_v·A_d·Ω_cone·τ_opt·L` volts,
//! with a Gaussian noise `σ_V` (Johnson and 1/f noise) and no shot noise worth modelling. Either noise can be
//! given directly or set from a NETD at a reference scene temperature.
//!
//! **ADC.** `DN = offset + signal/gain`, rounded and clamped to `[0, 2^bits − 1]`: the paper's gray mapping
//! (eqs 14–15) with `V_L = −offset·gain`, `V_H = V_L + (2^bits − 1)·gain`, `G_min = 0`, `G_max = 2^bits − 1`,
//! in the detector's own unit (electrons or volts).
//!
//! **NETD** is the scene temperature difference that gives a signal change equal to the temporal noise:
//! `NETD = σ(T)/(dS/dT)` with `S = K·L(T)` and `dS/dT = K·dL/dT` ([`SensorModel::report`]), `K` the signal per
//! unit radiance above. Vollmer & Möllmann, *Infrared Thermal Imaging* (2nd ed., 2018), §2.4–2.5, and Rogalski,
//! *Infrared and Terahertz Detectors* (3rd ed., 2019), ch. 3 and 11, give the same forms.

use serde::{Deserialize, Serialize};

use super::ParamError;
use super::planck::{Band, Measure, band_radiance_derivative, band_radiance_in};

fn require(name: &'static str, value: f64, ok: bool, range: impl Into<String>) -> Result<(), ParamError> {
    if ok { Ok(()) } else { Err(ParamError { name, value, range: range.into() }) }
}

/// The projected solid angle of the cone of light on a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Cone {
    /// `π/(4N²)`: a lens obeying the sine condition; the form of the paper's eq 13.
    #[default]
    Aplanatic,
    /// `π/(1 + 4N²)`: a thin paraxial lens (the cone's half-angle from `tan θ = 1/(2N)`).
    ThinLens,
}

/// The optics of the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optics {
    /// Effective focal length `f`, m.
    pub focal_length_m: f64,
    /// Entrance pupil diameter `D`, m.
    pub aperture_m: f64,
    /// Transmittance of the optics `τ_opt` (eq 13's `opptrans`), [0, 1].
    pub transmittance: f64,
    /// Which cone formula.
    pub cone: Cone,
}

impl Optics {
    /// F-number `N = f/D`.
    pub fn f_number(&self) -> f64 {
        self.focal_length_m / self.aperture_m
    }

    /// Projected solid angle of the cone of light on an on-axis pixel, sr.
    pub fn cone_sr(&self) -> f64 {
        let n = self.f_number();
        match self.cone {
            Cone::Aplanatic => std::f64::consts::PI / (4.0 * n * n),
            Cone::ThinLens => std::f64::consts::PI / (1.0 + 4.0 * n * n),
        }
    }

    /// Checks the parameters.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        require("focal_length_m", self.focal_length_m, positive(self.focal_length_m), "(0, ∞)")?;
        require("aperture_m", self.aperture_m, positive(self.aperture_m), "(0, ∞)")?;
        let n = self.f_number();
        require("aperture_m", self.aperture_m, (0.3..=100.0).contains(&n), "an F-number f/D in [0.3, 100]")?;
        let t = self.transmittance;
        require("optics_transmittance", t, t > 0.0 && t <= 1.0, "(0, 1]")
    }
}

/// What kind of detector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DetectorKind {
    /// Counts photo-electrons: shot noise, dark current, well capacity (InSb, MCT, T2SL).
    Photon,
    /// Responds to absorbed power: a voltage with Gaussian noise (microbolometer).
    Thermal,
}

/// How the detector's temporal noise is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoiseSpec {
    /// The read noise itself: electrons rms (photon) or volts rms (thermal).
    Read(f64),
    /// A NETD in kelvin at a reference scene temperature in kelvin: the read noise is set to match it.
    Netd {
        /// NETD, K.
        netd_k: f64,
        /// Scene temperature at which it holds, K.
        reference_temp_k: f64,
    },
}

/// The detector and its readout.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detector {
    /// Photon or thermal.
    pub kind: DetectorKind,
    /// Pixel pitch, m (square pixels).
    pub pixel_pitch_m: f64,
    /// Photosensitive fraction of the pixel's area, (0, 1].
    pub fill_factor: f64,
    /// Electrons per incident photon (photon detectors), (0, 1].
    pub quantum_efficiency: f64,
    /// Integration time, s (photon detectors).
    pub integration_time_s: f64,
    /// Well capacity, electrons (photon detectors).
    pub well_capacity_e: f64,
    /// Dark current, electrons per second (photon detectors).
    pub dark_current_e_s: f64,
    /// Responsivity, V/W (thermal detectors).
    pub responsivity_v_per_w: f64,
    /// Temporal noise.
    pub noise: NoiseSpec,
}

/// How the ADC's gain is given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AdcGain {
    /// Signal units (electrons or volts) per DN.
    PerDn(f64),
    /// The gain that puts the temporal noise of a 300 K scene at this many DN.
    NoiseDn(f64),
    /// The gain that maps the well capacity onto the levels above the offset (photon detectors).
    FullWell,
}

/// The ADC as specified; [`SensorModel::new`] resolves its gain into an [`Adc`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdcSpec {
    /// Bits per sample, 1 … 16.
    pub bit_depth: u32,
    /// The gain.
    pub gain: AdcGain,
    /// DN of zero signal.
    pub offset_dn: f64,
}

/// The analog-to-digital converter: `DN = offset + signal/gain`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Adc {
    /// Bits per sample, 1 … 16.
    pub bit_depth: u32,
    /// Signal units (electrons or volts) per DN, > 0.
    pub gain: f64,
    /// DN of zero signal.
    pub offset_dn: f64,
}

impl Adc {
    /// The highest level, `2^bits − 1`.
    pub fn max_level(&self) -> f64 {
        ((1u64 << self.bit_depth.min(32)) - 1) as f64
    }

    /// DN (not rounded) of a signal.
    pub fn dn(&self, signal: f64) -> f64 {
        self.offset_dn + signal / self.gain
    }

    /// The paper's eqs 14–15 for this ADC: `(V_L, V_H, G_min, G_max)` in signal units and DN.
    pub fn as_gray_mapping(&self) -> (f64, f64, f64, f64) {
        let v_low = -self.offset_dn * self.gain;
        (v_low, v_low + self.max_level() * self.gain, 0.0, self.max_level())
    }
}

/// A resolved camera radiometry: band, optics, detector, ADC, and what follows from them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    /// Spectral band.
    pub band: Band,
    /// Optics.
    pub optics: Optics,
    /// Detector.
    pub detector: Detector,
    /// ADC.
    pub adc: Adc,
    /// Read noise after resolving a NETD: electrons or volts rms.
    pub read_noise: f64,
}

/// A sensor's figures of merit at one scene temperature, as `irsim calc sensor` prints them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SensorReport {
    /// Scene temperature, K.
    pub scene_temp_k: f64,
    /// `electrons` or `volts`.
    pub signal_unit: &'static str,
    /// F-number.
    pub f_number: f64,
    /// Projected solid angle of the cone of light, sr.
    pub cone_sr: f64,
    /// Photosensitive area of a pixel, m².
    pub detector_area_m2: f64,
    /// Band radiance of the scene in the detector's measure (photons s⁻¹ m⁻² sr⁻¹ or W m⁻² sr⁻¹).
    pub scene_radiance: f64,
    /// Its derivative per kelvin.
    pub scene_radiance_per_k: f64,
    /// Signal per unit radiance (on axis): electrons or volts per radiance unit.
    pub signal_per_radiance: f64,
    /// Mean signal of the scene: electrons or volts.
    pub signal: f64,
    /// Dark signal per frame.
    pub dark_signal: f64,
    /// Signal change per kelvin of scene temperature.
    pub signal_per_k: f64,
    /// Shot noise, rms (0 for thermal detectors).
    pub shot_noise: f64,
    /// Read noise, rms.
    pub read_noise: f64,
    /// Temporal noise without quantization, rms.
    pub temporal_noise: f64,
    /// NETD from the temporal noise, mK.
    pub netd_mk: f64,
    /// NETD with the ADC's quantization noise (`gain²/12`) added, mK.
    pub netd_with_quantization_mk: f64,
    /// Noise-equivalent radiance, in the detector's measure.
    pub noise_equivalent_radiance: f64,
    /// Noise-equivalent energy radiance `NETD·dL/dT` in the band, W m⁻² sr⁻¹.
    pub noise_equivalent_radiance_w_m2_sr: f64,
    /// Signal units per DN (electrons per DN for photon detectors).
    pub signal_per_dn: f64,
    /// Mean DN of the scene.
    pub scene_dn: f64,
    /// DN per kelvin of scene temperature.
    pub dn_per_k: f64,
    /// Temporal noise in DN.
    pub noise_dn: f64,
    /// Fraction of the well the scene fills (photon detectors; 0 for thermal).
    pub well_fill: f64,
    /// Hottest scene temperature before the well or the ADC saturates, K (None if above 2000 K).
    pub saturation_temp_k: Option<f64>,
}

impl SensorModel {
    /// Checks the parts and resolves a NETD into a read noise.
    ///
    /// # Errors
    /// [`ParamError`] naming the first parameter out of range, or `netd_mk` if the NETD asked for is below what
    /// the shot noise alone allows.
    pub fn new(band: Band, optics: Optics, detector: Detector, adc: AdcSpec) -> Result<Self, ParamError> {
        optics.validate()?;
        let d = &detector;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        require("pixel_pitch_m", d.pixel_pitch_m, positive(d.pixel_pitch_m), "(0, ∞)")?;
        require("fill_factor", d.fill_factor, d.fill_factor > 0.0 && d.fill_factor <= 1.0, "(0, 1]")?;
        match d.kind {
            DetectorKind::Photon => {
                let q = d.quantum_efficiency;
                require("quantum_efficiency", q, q > 0.0 && q <= 1.0, "(0, 1]")?;
                let t = d.integration_time_s;
                require("integration_time_s", t, t > 0.0 && t <= 10.0, "(0, 10] s")?;
                let w = d.well_capacity_e;
                require("well_capacity_e", w, (1.0..=1e12).contains(&w), "[1, 1e12]")?;
                let i = d.dark_current_e_s;
                require("dark_current_e_s", i, (0.0..=1e15).contains(&i), "[0, 1e15]")?;
            }
            DetectorKind::Thermal => {
                let r = d.responsivity_v_per_w;
                require("responsivity_v_per_w", r, r > 0.0 && r <= 1e12, "(0, 1e12]")?;
            }
        }
        let bits = adc.bit_depth;
        require("bit_depth", f64::from(bits), (1..=16).contains(&bits), "1 … 16")?;
        let mut resolved = Adc { bit_depth: bits, gain: 1.0, offset_dn: adc.offset_dn };
        let top = resolved.max_level();
        let offset_ok = adc.offset_dn.is_finite() && (0.0..top).contains(&adc.offset_dn);
        require("offset_dn", adc.offset_dn, offset_ok, format!("[0, {top})"))?;
        let mut model = Self { band, optics, detector, adc: resolved, read_noise: 0.0 };
        model.read_noise = match detector.noise {
            NoiseSpec::Read(s) => {
                require("read_noise", s, (0.0..1e15).contains(&s), "[0, 1e15)")?;
                s
            }
            NoiseSpec::Netd { netd_k, reference_temp_k: t } => {
                require("netd_mk", netd_k * 1e3, netd_k > 0.0 && netd_k <= 100.0, "(0, 100000] mK")?;
                require("reference_temp_k", t, (100.0..=2000.0).contains(&t), "[100, 2000] K")?;
                let want = netd_k * model.signal_per_radiance() * band_radiance_derivative(model.measure(), band, t);
                let shot2 =
                    model.shot_variance(model.signal_per_radiance() * band_radiance_in(model.measure(), band, t, 1.0));
                if !(want * want > shot2) {
                    let floor = shot2.sqrt() / (want / netd_k);
                    return Err(ParamError {
                        name: "netd_mk",
                        value: netd_k * 1e3,
                        range: format!("(shot-noise limit {:.2} mK at {t} K, ∞)", floor * 1e3),
                    });
                }
                (want * want - shot2).sqrt()
            }
        };
        resolved.gain = match adc.gain {
            AdcGain::PerDn(g) => g,
            AdcGain::NoiseDn(n) => {
                require("noise_dn", n, n.is_finite() && n > 0.0 && n <= 1e6, "(0, 1e6]")?;
                let signal = model.signal_per_radiance() * band_radiance_in(model.measure(), band, 300.0, 1.0);
                model.temporal_noise(signal) / n
            }
            AdcGain::FullWell => {
                if detector.kind != DetectorKind::Photon {
                    return Err(ParamError {
                        name: "gain",
                        value: f64::NAN,
                        range: "a number: a thermal detector has no well".into(),
                    });
                }
                detector.well_capacity_e / (top - adc.offset_dn)
            }
        };
        require("gain", resolved.gain, positive(resolved.gain) && resolved.gain < 1e15, "(0, 1e15)")?;
        model.adc = resolved;
        Ok(model)
    }

    /// Energy (thermal detector) or photons (photon detector).
    pub fn measure(&self) -> Measure {
        match self.detector.kind {
            DetectorKind::Photon => Measure::Photon,
            DetectorKind::Thermal => Measure::Energy,
        }
    }

    /// Photosensitive area of a pixel `A_d`, m².
    pub fn detector_area_m2(&self) -> f64 {
        self.detector.fill_factor * self.detector.pixel_pitch_m * self.detector.pixel_pitch_m
    }

    /// Mean signal (electrons or volts) per unit band radiance in [`SensorModel::measure`], on axis: eq 13 for
    /// an extended source, `η·t·A_d·Ω·τ_opt` or `R_v·A_d·Ω·τ_opt`.
    pub fn signal_per_radiance(&self) -> f64 {
        let geometric = self.detector_area_m2() * self.optics.cone_sr() * self.optics.transmittance;
        let d = &self.detector;
        match d.kind {
            DetectorKind::Photon => d.quantum_efficiency * d.integration_time_s * geometric,
            DetectorKind::Thermal => d.responsivity_v_per_w * geometric,
        }
    }

    /// Dark signal per frame: `i_dark·t_int` electrons (0 for thermal detectors).
    pub fn dark_signal(&self) -> f64 {
        match self.detector.kind {
            DetectorKind::Photon => self.detector.dark_current_e_s * self.detector.integration_time_s,
            DetectorKind::Thermal => 0.0,
        }
    }

    /// Whether the signal carries Poisson shot noise (photon detectors).
    pub fn shot_noise(&self) -> bool {
        self.detector.kind == DetectorKind::Photon
    }

    /// The largest signal the pixel holds: the well (photon detectors) or unbounded (thermal: the ADC clips).
    pub fn full_well(&self) -> f64 {
        match self.detector.kind {
            DetectorKind::Photon => self.detector.well_capacity_e,
            DetectorKind::Thermal => f64::INFINITY,
        }
    }

    /// Shot-noise variance of a mean scene signal, dark current included.
    fn shot_variance(&self, scene_signal: f64) -> f64 {
        if self.shot_noise() { scene_signal + self.dark_signal() } else { 0.0 }
    }

    /// Temporal noise (rms, signal units) at a mean scene signal: `√(shot + σ_r²)`.
    pub fn temporal_noise(&self, scene_signal: f64) -> f64 {
        (self.shot_variance(scene_signal) + self.read_noise * self.read_noise).sqrt()
    }

    /// The per-frame readout: signal per radiance, dark signal, shot and read noise, well, ADC gain and offset;
    /// shot noise is an exact Poisson count below `poisson_normal_threshold` electrons, and the normal deviates
    /// come from `normal_sampler`.
    pub fn readout(
        &self,
        poisson_normal_threshold: f64,
        normal_sampler: super::random::NormalSampler,
    ) -> super::noise::Readout {
        super::noise::Readout {
            signal_per_radiance: self.signal_per_radiance() as f32,
            dark_signal: self.dark_signal() as f32,
            shot_noise: self.shot_noise(),
            read_variance: (self.read_noise * self.read_noise) as f32,
            full_well: self.full_well() as f32,
            dn_per_signal: (1.0 / self.adc.gain) as f32,
            offset_dn: self.adc.offset_dn as f32,
            poisson_normal_threshold: poisson_normal_threshold as f32,
            normal_sampler,
        }
    }

    /// Figures of merit at scene temperature `temp_k` (a blackbody filling the field of view, on axis).
    pub fn report(&self, temp_k: f64) -> SensorReport {
        let m = self.measure();
        let k = self.signal_per_radiance();
        let l = band_radiance_in(m, self.band, temp_k, 1.0);
        let dl = band_radiance_derivative(m, self.band, temp_k);
        let signal = k * l;
        let per_k = k * dl;
        let shot = self.shot_variance(signal).sqrt();
        let temporal = self.temporal_noise(signal);
        let with_q = (temporal * temporal + self.adc.gain * self.adc.gain / 12.0).sqrt();
        let netd = temporal / per_k;
        let top = self.adc.max_level();
        let limit = self.full_well().min((top - self.adc.offset_dn) * self.adc.gain) - self.dark_signal();
        let saturation_temp_k = if k * band_radiance_in(m, self.band, 2000.0, 1.0) <= limit {
            None
        } else {
            // bisection on the monotonic signal
            let (mut lo, mut hi) = (1.0f64, 2000.0f64);
            for _ in 0..100 {
                let mid = 0.5 * (lo + hi);
                if k * band_radiance_in(m, self.band, mid, 1.0) > limit { hi = mid } else { lo = mid }
            }
            Some(lo)
        };
        SensorReport {
            scene_temp_k: temp_k,
            signal_unit: if self.shot_noise() { "electrons" } else { "volts" },
            f_number: self.optics.f_number(),
            cone_sr: self.optics.cone_sr(),
            detector_area_m2: self.detector_area_m2(),
            scene_radiance: l,
            scene_radiance_per_k: dl,
            signal_per_radiance: k,
            signal,
            dark_signal: self.dark_signal(),
            signal_per_k: per_k,
            shot_noise: shot,
            read_noise: self.read_noise,
            temporal_noise: temporal,
            netd_mk: netd * 1e3,
            netd_with_quantization_mk: with_q / per_k * 1e3,
            noise_equivalent_radiance: temporal / k,
            noise_equivalent_radiance_w_m2_sr: netd * band_radiance_derivative(Measure::Energy, self.band, temp_k),
            signal_per_dn: self.adc.gain,
            scene_dn: self.adc.dn(signal + self.dark_signal()),
            dn_per_k: per_k / self.adc.gain,
            noise_dn: temporal / self.adc.gain,
            well_fill: if self.shot_noise() { (signal + self.dark_signal()) / self.full_well() } else { 0.0 },
            saturation_temp_k,
        }
    }
}

/// Cameras whose parameters are published, as starting points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// A cooled MWIR InSb camera: 640×512, 15 µm, F/4, 3–5 µm, NETD ≈ 20 mK at 300 K.
    CooledMwirInsb,
    /// An uncooled LWIR VOx microbolometer core: 640×512, 12 µm, F/1, 7.5–13.5 µm, NETD 40 mK at 300 K.
    UncooledLwirMicrobolometer,
    /// The paper's set-up: 256×256, 17 µm, a 50 mm F/1 lens, 8–12 µm, with an uncooled detector (NETD 50 mK).
    #[serde(rename = "paper_lwir_256")]
    PaperLwir256,
}

/// Every value a preset sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PresetValues {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Band.
    pub band: Band,
    /// Optics.
    pub optics: Optics,
    /// Detector.
    pub detector: Detector,
    /// ADC.
    pub adc: AdcSpec,
    /// Frames per second the camera runs at.
    pub frame_rate_hz: f64,
}

impl Preset {
    /// Every preset.
    pub const ALL: [Preset; 3] = [Preset::CooledMwirInsb, Preset::UncooledLwirMicrobolometer, Preset::PaperLwir256];

    /// Its name in scenarios and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Preset::CooledMwirInsb => "cooled_mwir_insb",
            Preset::UncooledLwirMicrobolometer => "uncooled_lwir_microbolometer",
            Preset::PaperLwir256 => "paper_lwir_256",
        }
    }

    /// The values.
    ///
    /// Sources. *Cooled MWIR InSb*: 640×512 arrays of 15 µm InSb pixels reach NETD 10–20 mK at 77 K
    /// (Ivanov et al., "Mesa structures and focal plane arrays based on epitaxially grown InSb layers", 2020;
    /// Rogalski 2019, ch. 11); InSb's quantum efficiency with an anti-reflection coating is 0.8–0.9 (Rogalski
    /// 2019, ch. 11); 15 µm ROICs hold a few million electrons. We take η = 0.8, a 7 Me⁻ well, 300 e⁻ read
    /// noise, 50 e⁻/s dark current (negligible at 77 K), a 100 mm F/4 lens with τ_opt = 0.85 and a 3–5 µm cold
    /// filter, and choose the integration time, 7 ms, so that a 300 K scene fills about 30 % of the well; the
    /// model then gives NETD ≈ 19 mK at 300 K (`irsim calc sensor --preset cooled_mwir_insb`). *Uncooled LWIR
    /// microbolometer*: Teledyne FLIR Boson 640 datasheet (doc. 102-2013-40, rel. 340, 2021): 640×512 VOx, 12 µm
    /// pitch, 7.5–13.5 µm, NETD "as low as < 40 mK at f/1.0", 60 Hz; we take 40 mK at 300 K, a 25 mm F/1.0
    /// lens with τ_opt = 0.9 and a 14-bit output with 2 DN of noise. *Paper*: the sensor of its Fig. 9
    /// example (256×256) with 17 µm pixels and a 50 mm F/1 lens, as the paper's scenario here uses, and an
    /// uncooled detector of NETD 50 mK.
    pub fn values(self) -> PresetValues {
        match self {
            Preset::CooledMwirInsb => PresetValues {
                width: 640,
                height: 512,
                band: Band::MWIR_3_5,
                optics: Optics { focal_length_m: 0.1, aperture_m: 0.025, transmittance: 0.85, cone: Cone::Aplanatic },
                detector: Detector {
                    kind: DetectorKind::Photon,
                    pixel_pitch_m: 15e-6,
                    fill_factor: 1.0,
                    quantum_efficiency: 0.8,
                    integration_time_s: 7e-3,
                    well_capacity_e: 7e6,
                    dark_current_e_s: 50.0,
                    responsivity_v_per_w: 0.0,
                    noise: NoiseSpec::Read(300.0),
                },
                // the well spans the 14-bit range above a 1000 DN offset
                adc: AdcSpec { bit_depth: 14, gain: AdcGain::FullWell, offset_dn: 1000.0 },
                frame_rate_hz: 100.0,
            },
            Preset::UncooledLwirMicrobolometer => PresetValues {
                width: 640,
                height: 512,
                band: Band::try_new(7.5, 13.5).expect("valid band"),
                optics: Optics { focal_length_m: 0.025, aperture_m: 0.025, transmittance: 0.9, cone: Cone::Aplanatic },
                detector: thermal_detector(12e-6, 0.04),
                adc: thermal_adc(),
                frame_rate_hz: 60.0,
            },
            Preset::PaperLwir256 => PresetValues {
                width: 256,
                height: 256,
                band: Band::LWIR_8_12,
                optics: Optics { focal_length_m: 0.05, aperture_m: 0.05, transmittance: 0.8, cone: Cone::Aplanatic },
                detector: thermal_detector(17e-6, 0.05),
                adc: thermal_adc(),
                frame_rate_hz: 30.0,
            },
        }
    }
}

/// A microbolometer of `pitch_m` whose noise is set by a NETD (K) at 300 K; responsivity 1e6 V/W (the value
/// only sets the voltage scale, which the ADC gain undoes).
fn thermal_detector(pitch_m: f64, netd_k: f64) -> Detector {
    Detector {
        kind: DetectorKind::Thermal,
        pixel_pitch_m: pitch_m,
        fill_factor: 1.0,
        quantum_efficiency: 1.0,
        integration_time_s: 0.0,
        well_capacity_e: 0.0,
        dark_current_e_s: 0.0,
        responsivity_v_per_w: 1e6,
        noise: NoiseSpec::Netd { netd_k, reference_temp_k: 300.0 },
    }
}

/// A 14-bit ADC for thermal detectors with 2 DN of noise at 300 K (such cores show a few DN of noise).
fn thermal_adc() -> AdcSpec {
    AdcSpec { bit_depth: 14, gain: AdcGain::NoiseDn(2.0), offset_dn: 2048.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::planck::{PLANCK_H, SPEED_OF_LIGHT, photon_band_radiance};

    fn resolve(p: Preset) -> SensorModel {
        let v = p.values();
        SensorModel::new(v.band, v.optics, v.detector, v.adc).unwrap()
    }

    #[test]
    fn electrons_of_a_300_k_blackbody_by_hand() {
        let m = resolve(Preset::CooledMwirInsb);
        // η t A_d π/(4N²) τ_opt ∫ L_λ λ/(hc) dλ, N = 4
        let lq = photon_band_radiance(Band::MWIR_3_5, 300.0, 1.0);
        let want = 0.8 * 7e-3 * (15e-6f64).powi(2) * std::f64::consts::PI / 64.0 * 0.85 * lq;
        let r = m.report(300.0);
        assert!(((r.signal - want) / want).abs() < 1e-14, "{} vs {want}", r.signal);
        // a photon at 4 µm carries hc/λ ≈ 5e-20 J: the photon count is energy/(hc/λ̄) within the band's spread
        let energy = crate::physics::planck::band_radiance(Band::MWIR_3_5, 300.0, 1.0);
        let mean_lambda_m = energy / lq * 1.0 / (PLANCK_H * SPEED_OF_LIGHT);
        assert!((1.0 / mean_lambda_m * 1e6 - 4.2).abs() < 0.4);
    }

    #[test]
    fn presets_give_their_published_netd() {
        let mw = resolve(Preset::CooledMwirInsb).report(300.0);
        assert!(mw.netd_mk > 14.0 && mw.netd_mk < 22.0, "{mw:?}");
        assert!(mw.well_fill > 0.2 && mw.well_fill < 0.6, "{mw:?}");
        let lw = resolve(Preset::UncooledLwirMicrobolometer).report(300.0);
        assert!((lw.netd_mk - 40.0).abs() < 1e-9, "{lw:?}");
        assert!((lw.noise_dn - 2.0).abs() < 1e-9);
    }

    #[test]
    fn netd_as_input_sets_the_read_noise() {
        let v = Preset::CooledMwirInsb.values();
        let det = Detector { noise: NoiseSpec::Netd { netd_k: 0.025, reference_temp_k: 300.0 }, ..v.detector };
        let m = SensorModel::new(v.band, v.optics, det, v.adc).unwrap();
        assert!((m.report(300.0).netd_mk - 25.0).abs() < 1e-9);
        // below the shot-noise limit
        let det = Detector { noise: NoiseSpec::Netd { netd_k: 0.001, reference_temp_k: 300.0 }, ..v.detector };
        let e = SensorModel::new(v.band, v.optics, det, v.adc).unwrap_err();
        assert_eq!(e.name, "netd_mk");
        assert!(e.range.contains("shot-noise limit"), "{e}");
    }

    #[test]
    fn thin_lens_cone_is_smaller() {
        let o = Optics { focal_length_m: 0.1, aperture_m: 0.1, transmittance: 1.0, cone: Cone::Aplanatic };
        let t = Optics { cone: Cone::ThinLens, ..o };
        assert!((o.cone_sr() - std::f64::consts::PI / 4.0).abs() < 1e-15);
        assert!((t.cone_sr() / o.cone_sr() - 0.8).abs() < 1e-15);
    }

    #[test]
    fn adc_is_the_papers_gray_mapping() {
        let adc = Adc { bit_depth: 14, gain: 430.0, offset_dn: 1000.0 };
        let (v_l, v_h, g_min, g_max) = adc.as_gray_mapping();
        for s in [0.0, 1e5, 3e6] {
            let eq15 = g_min + (s - v_l) * (g_max - g_min) / (v_h - v_l);
            assert!((eq15 - adc.dn(s)).abs() < 1e-9);
        }
    }
}
