//! Scenarios: what a run simulates, as a serde schema (TOML or JSON) with validation.
//!
//! Pure: no Bevy. [`load()`] reads a file and returns a [`Scenario`] whose every value has been checked, or a
//! [`ScenarioError`] that names the file, line, column and field. The schema is documented field by field in
//! `docs/scenarios.md`.

pub mod load;
pub mod trajectory;

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::imaging::camera::{Intrinsics, YawPitchRoll};
use crate::imaging::fusion::{Guidance, Solver};
use crate::imaging::sky_plane::{MissFill, Sampling, SkyPlacement};
use crate::imaging::target_blob::BlobSampling;
use crate::imaging::vibration::VibrationSpec;
use crate::physics::brdf::CookTorrance;
use crate::physics::noise::NoiseModel;
use crate::physics::planck::Band;
use crate::physics::reflection::{ReflectionGeometry, Sun};
use crate::physics::sensor::{GrayMapping, Radiometer};
use crate::physics::skin::StagnationModel;
use crate::physics::transmittance::Transmittance;
pub use load::{ScenarioError, load, load_str};
use trajectory::{Trajectory, TrajectorySpec};

/// A whole scenario file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// A short name, used in the manifest.
    #[serde(default)]
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Frame rate, count, seed.
    #[serde(default)]
    pub run: RunSpec,
    /// The camera.
    pub sensor: SensorSpec,
    /// The camera's platform: trajectory, pointing, vibration.
    pub observer: ObserverSpec,
    /// The sky image placed in the world; without it the background is uniform at `sensor.gray.g_min`.
    #[serde(default)]
    pub sky: Option<SkySpec>,
    /// Air temperature and transmittance.
    #[serde(default)]
    pub atmosphere: AtmosphereSpec,
    /// The sun.
    #[serde(default)]
    pub sun: Sun,
    /// Poisson fusion.
    #[serde(default)]
    pub fusion: FusionSpec,
    /// The aircraft.
    #[serde(default)]
    pub targets: Vec<TargetSpec>,
}

/// Frame rate, count and seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunSpec {
    /// Sensor frames per second; one fixed step per frame.
    pub frame_rate_hz: f64,
    /// Number of frames.
    pub frames: u64,
    /// Seed of every random stream.
    pub seed: u64,
    /// Time of frame 0, s.
    pub start_time_s: f64,
}

impl Default for RunSpec {
    fn default() -> Self {
        Self { frame_rate_hz: 30.0, frames: 100, seed: 0, start_time_s: 0.0 }
    }
}

/// The camera: geometry, radiometry, electronics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSpec {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Pixel pitch, µm.
    pub pixel_pitch_um: f64,
    /// Focal length, mm.
    pub focal_length_mm: f64,
    /// Aperture diameter, mm.
    pub aperture_mm: f64,
    /// Spectral band, µm.
    pub band_um: Band,
    /// Optics transmittance.
    #[serde(default = "default_optics_transmittance")]
    pub optics_transmittance: f64,
    /// Responsivity, V/W.
    #[serde(default = "default_responsivity")]
    pub responsivity_v_per_w: f64,
    /// Photosensitive fraction of the pixel.
    #[serde(default = "one")]
    pub detector_fill: f64,
    /// Gray mapping (eqs 14–15) and bit depth.
    #[serde(default)]
    pub gray: GrayMapping,
    /// Sensor noise.
    #[serde(default)]
    pub noise: NoiseSpec,
    /// How targets are drawn.
    #[serde(default)]
    pub blob: BlobSpec,
}

fn default_optics_transmittance() -> f64 {
    0.8
}
fn default_responsivity() -> f64 {
    1e8
}
fn one() -> f64 {
    1.0
}

/// Sensor noise, with a switch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseSpec {
    /// Add noise at all.
    pub enabled: bool,
    /// Photo-electrons per gray level (shot noise); 0 turns it off.
    pub electrons_per_gray: f64,
    /// Gaussian noise, gray levels.
    pub read_noise_gray: f64,
    /// Mean electron count above which Poisson samples use the normal approximation.
    pub poisson_normal_threshold: f64,
}

impl Default for NoiseSpec {
    fn default() -> Self {
        let m = NoiseModel::default();
        Self {
            enabled: true,
            electrons_per_gray: m.electrons_per_gray,
            read_noise_gray: m.read_noise_gray,
            poisson_normal_threshold: m.poisson_normal_threshold,
        }
    }
}

impl NoiseSpec {
    /// The noise model.
    pub fn model(&self) -> NoiseModel {
        NoiseModel {
            electrons_per_gray: self.electrons_per_gray,
            read_noise_gray: self.read_noise_gray,
            poisson_normal_threshold: self.poisson_normal_threshold,
        }
    }
}

/// How targets are drawn (eq 11).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlobSpec {
    /// Minimum blur (optics point spread), px.
    pub min_blur_px: f64,
    /// Shape exponent β (2 = Gaussian).
    pub beta: f64,
    /// The region of interest ends where the blob falls below this fraction of its peak.
    pub roi_fraction: f64,
    /// Pixel sampling.
    pub sampling: BlobSampling,
}

impl Default for BlobSpec {
    fn default() -> Self {
        Self { min_blur_px: 0.7, beta: 2.0, roi_fraction: 1e-3, sampling: BlobSampling::Auto }
    }
}

impl SensorSpec {
    /// Camera intrinsics.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics {
            width: self.width,
            height: self.height,
            focal_length_m: self.focal_length_mm * 1e-3,
            pixel_pitch_m: self.pixel_pitch_um * 1e-6,
        }
    }

    /// Optics and detector for eq 13.
    pub fn radiometer(&self) -> Radiometer {
        Radiometer {
            aperture_m: self.aperture_mm * 1e-3,
            focal_length_m: self.focal_length_mm * 1e-3,
            pixel_pitch_m: self.pixel_pitch_um * 1e-6,
            detector_fill: self.detector_fill,
            optics_transmittance: self.optics_transmittance,
            responsivity_v_per_w: self.responsivity_v_per_w,
        }
    }
}

/// Where the camera points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum Pointing {
    /// At a fixed world point.
    LookAt {
        /// The point, m.
        target_m: DVec3,
        /// Roll about the optical axis, degrees.
        #[serde(default)]
        roll_deg: f64,
    },
    /// At a named target's position each frame.
    Track {
        /// The target's name.
        target: String,
        /// Roll about the optical axis, degrees.
        #[serde(default)]
        roll_deg: f64,
    },
    /// A fixed attitude.
    YawPitchRoll(YawPitchRoll),
    /// Along the observer's velocity, offset by yaw and pitch.
    AlongVelocity {
        /// Added heading, degrees.
        #[serde(default)]
        yaw_offset_deg: f64,
        /// Added elevation, degrees.
        #[serde(default)]
        pitch_offset_deg: f64,
    },
}

/// The camera's platform.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObserverSpec {
    /// Its trajectory.
    pub trajectory: TrajectorySpec,
    /// Where the camera points.
    pub pointing: Pointing,
    /// Line-of-sight vibration.
    #[serde(default)]
    pub vibration: VibrationSpec,
}

/// The sky image and its placement (paper III.B).
///
/// The placement fields repeat [`SkyPlacement`]'s ([`SkySpec::placement`] converts): serde's `flatten` cannot be
/// combined with `deny_unknown_fields`, which every scenario table uses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkySpec {
    /// Image file, relative to the scenario file.
    pub image: String,
    /// World position of the anchor point P, m.
    pub anchor_m: DVec3,
    /// Image coordinates of P, px; default the image centre.
    #[serde(default)]
    pub anchor_px: Option<DVec2>,
    /// Width of the image in the world, m.
    pub width_m: f64,
    /// Height of the image in the world, m.
    pub height_m: f64,
    /// Plane normal toward the camera; default vertical, facing the observer's start.
    #[serde(default)]
    pub normal: Option<DVec3>,
    /// World direction of the image's up; default +z.
    #[serde(default)]
    pub up: Option<DVec3>,
    /// Sampling of the image.
    #[serde(default)]
    pub sampling: Sampling,
    /// What rays that miss the image get.
    #[serde(default)]
    pub miss: MissFill,
    /// Sensor gray = `gray_offset + gray_gain · image value`.
    #[serde(default = "one")]
    pub gray_gain: f64,
    /// See `gray_gain`.
    #[serde(default)]
    pub gray_offset: f64,
}

impl SkySpec {
    /// The placement part.
    pub fn placement(&self) -> SkyPlacement {
        SkyPlacement {
            anchor_m: self.anchor_m,
            anchor_px: self.anchor_px,
            width_m: self.width_m,
            height_m: self.height_m,
            normal: self.normal,
            up: self.up,
        }
    }
}

/// Air temperature profile, skin heating and transmittance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AtmosphereSpec {
    /// Sea-level temperature for eq 2, K.
    pub t0_k: f64,
    /// Transmittance model.
    pub transmittance: Transmittance,
    /// Stagnation constants of eq 1.
    pub stagnation: StagnationModel,
}

impl Default for AtmosphereSpec {
    fn default() -> Self {
        Self { t0_k: 288.15, transmittance: Transmittance::default(), stagnation: StagnationModel::default() }
    }
}

/// Poisson fusion settings.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionSpec {
    /// Guidance field.
    pub guidance: Guidance,
    /// Solver.
    pub solver: Solver,
}

/// One aircraft.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSpec {
    /// Name, unique in the scenario.
    pub name: String,
    /// Trajectory.
    pub trajectory: TrajectorySpec,
    /// Ellipsoid semi-axes: along the velocity, across, up, m.
    pub semi_axes_m: DVec3,
    /// Mach number; default from the speed and the speed of sound at the altitude.
    #[serde(default)]
    pub mach: Option<f64>,
    /// Skin emissivity.
    #[serde(default = "default_emissivity")]
    pub emissivity: f64,
    /// Reflectance.
    #[serde(default)]
    pub brdf: CookTorrance,
    /// Facet (paper) or ellipsoid-averaged reflection.
    #[serde(default)]
    pub reflection: ReflectionGeometry,
    /// Fixed attitude of the ellipsoid's long axis (yaw, pitch, roll); default along the velocity.
    #[serde(default)]
    pub attitude: Option<YawPitchRoll>,
}

fn default_emissivity() -> f64 {
    0.8
}

/// A validation failure: the dotted path of the field and what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldError {
    /// E.g. `sensor.gray.v_high` or `targets[1].trajectory.points[2]`.
    pub path: String,
    /// What is wrong, with the allowed range.
    pub message: String,
}

fn fe(path: impl Into<String>, message: impl std::fmt::Display) -> FieldError {
    FieldError { path: path.into(), message: message.to_string() }
}

/// A checked scenario with its trajectories built and paths resolved.
#[derive(Debug, Clone)]
pub struct CheckedScenario {
    /// What was read.
    pub spec: Scenario,
    /// The file it came from (for relative paths and messages).
    pub source: PathBuf,
    /// Observer trajectory.
    pub observer_trajectory: Trajectory,
    /// Target trajectories, in order.
    pub target_trajectories: Vec<Trajectory>,
    /// Resolved sky image path.
    pub sky_image: Option<PathBuf>,
}

impl Scenario {
    /// Checks every value and builds the trajectories; `base_dir` resolves relative paths.
    ///
    /// # Errors
    /// The first [`FieldError`] found.
    pub fn check(&self, base_dir: &Path) -> Result<(Trajectory, Vec<Trajectory>, Option<PathBuf>), FieldError> {
        let r = &self.run;
        if !(r.frame_rate_hz.is_finite() && r.frame_rate_hz > 0.0 && r.frame_rate_hz <= 100_000.0) {
            return Err(fe("run.frame_rate_hz", format!("{} must be in (0, 100000]", r.frame_rate_hz)));
        }
        if !r.start_time_s.is_finite() {
            return Err(fe("run.start_time_s", "must be finite"));
        }
        if r.frames == 0 || r.frames > 100_000_000 {
            return Err(fe("run.frames", format!("{} must be in 1 … 100000000", r.frames)));
        }
        let s = &self.sensor;
        Intrinsics::try_new(s.width, s.height, s.focal_length_mm * 1e-3, s.pixel_pitch_um * 1e-6).map_err(|e| {
            let name = match &e {
                crate::imaging::camera::CameraError::OutOfRange { name, .. } => match *name {
                    "focal_length_m" => "focal_length_mm",
                    "pixel_pitch_m" => "pixel_pitch_um",
                    other => other,
                },
                _ => "width",
            };
            fe(format!("sensor.{name}"), e)
        })?;
        s.radiometer().validate().map_err(|e| {
            let name = match e.name {
                "aperture_m" => "aperture_mm",
                "focal_length_m" => "focal_length_mm",
                "pixel_pitch_m" => "pixel_pitch_um",
                other => other,
            };
            fe(format!("sensor.{name}"), format!("{} is outside its allowed range {}", e.value, e.range))
        })?;
        s.gray
            .validate()
            .map_err(|e| fe(format!("sensor.gray.{}", e.name), format!("{} is outside {}", e.value, e.range)))?;
        s.noise
            .model()
            .validate()
            .map_err(|e| fe(format!("sensor.noise.{}", e.name), format!("{} is outside {}", e.value, e.range)))?;
        let b = &s.blob;
        if !(b.min_blur_px.is_finite() && (0.0..=100.0).contains(&b.min_blur_px)) {
            return Err(fe("sensor.blob.min_blur_px", format!("{} must be in [0, 100]", b.min_blur_px)));
        }
        if !(b.beta.is_finite() && (0.1..=1000.0).contains(&b.beta)) {
            return Err(fe("sensor.blob.beta", format!("{} must be in [0.1, 1000]", b.beta)));
        }
        if !(b.roi_fraction > 0.0 && b.roi_fraction < 1.0) {
            return Err(fe("sensor.blob.roi_fraction", format!("{} must be in (0, 1)", b.roi_fraction)));
        }
        if let BlobSampling::Integrated { n } = b.sampling
            && !(1..=16).contains(&n)
        {
            return Err(fe("sensor.blob.sampling.n", format!("{n} must be in 1 … 16")));
        }

        let observer = self
            .observer
            .trajectory
            .build(base_dir)
            .map_err(|e| fe(format!("observer.trajectory.{}", e.field), e.message))?;
        self.observer.vibration.validate().map_err(|(f, m)| fe(format!("observer.vibration.{f}"), m))?;
        match &self.observer.pointing {
            Pointing::LookAt { target_m, roll_deg } => {
                if !target_m.is_finite() {
                    return Err(fe("observer.pointing.target_m", "must be finite"));
                }
                if !roll_deg.is_finite() {
                    return Err(fe("observer.pointing.roll_deg", "must be finite"));
                }
            }
            Pointing::Track { target, roll_deg } => {
                if !self.targets.iter().any(|t| &t.name == target) {
                    return Err(fe("observer.pointing.target", format!("no target named `{target}`")));
                }
                if !roll_deg.is_finite() {
                    return Err(fe("observer.pointing.roll_deg", "must be finite"));
                }
            }
            Pointing::YawPitchRoll(a) => {
                for (n, v) in [("yaw_deg", a.yaw_deg), ("pitch_deg", a.pitch_deg), ("roll_deg", a.roll_deg)] {
                    if !v.is_finite() {
                        return Err(fe(format!("observer.pointing.{n}"), "must be finite"));
                    }
                }
            }
            Pointing::AlongVelocity { yaw_offset_deg, pitch_offset_deg } => {
                if !(yaw_offset_deg.is_finite() && pitch_offset_deg.is_finite()) {
                    return Err(fe("observer.pointing", "offsets must be finite"));
                }
            }
        }

        let sky_image = match &self.sky {
            None => None,
            Some(sky) => {
                if !sky.anchor_m.is_finite() {
                    return Err(fe("sky.anchor_m", "must be finite"));
                }
                for (n, v) in [("width_m", sky.width_m), ("height_m", sky.height_m)] {
                    if !(v.is_finite() && v > 0.0) {
                        return Err(fe(format!("sky.{n}"), format!("{v} must be a finite number > 0")));
                    }
                }
                if !(sky.gray_gain.is_finite() && sky.gray_offset.is_finite()) {
                    return Err(fe("sky.gray_gain", "gain and offset must be finite"));
                }
                if let Sampling::Supersample { n } = sky.sampling
                    && !(1..=16).contains(&n)
                {
                    return Err(fe("sky.sampling.n", format!("{n} must be in 1 … 16")));
                }
                if let Some(n) = sky.normal
                    && (!n.is_finite() || n.length() == 0.0)
                {
                    return Err(fe("sky.normal", "must be a finite, non-zero vector"));
                }
                let path = base_dir.join(&sky.image);
                if !path.is_file() {
                    return Err(fe("sky.image", format!("file not found: {}", path.display())));
                }
                Some(path)
            }
        };

        let a = &self.atmosphere;
        if !(a.t0_k.is_finite() && a.t0_k > 100.0 && a.t0_k < 400.0) {
            return Err(fe("atmosphere.t0_k", format!("{} must be in (100, 400) K", a.t0_k)));
        }
        a.transmittance.validate().map_err(|e| {
            fe(format!("atmosphere.transmittance.{}", e.name), format!("{} is outside {}", e.value, e.range))
        })?;
        a.stagnation.validate().map_err(|e| fe("atmosphere.stagnation", e))?;
        let sun = &self.sun;
        for (n, v, ok) in [
            ("temp_k", sun.temp_k, sun.temp_k >= 0.0 && sun.temp_k <= 1e5),
            ("solid_angle_sr", sun.solid_angle_sr, sun.solid_angle_sr >= 0.0 && sun.solid_angle_sr < 1.0),
            ("azimuth_deg", sun.azimuth_deg, true),
            ("elevation_deg", sun.elevation_deg, (-90.0..=90.0).contains(&sun.elevation_deg)),
        ] {
            if !(v.is_finite() && ok) {
                return Err(fe(format!("sun.{n}"), format!("{v} is outside its allowed range")));
            }
        }
        match self.fusion.solver {
            Solver::Direct => {}
            Solver::Jacobi { tolerance, max_iterations } | Solver::Sor { tolerance, max_iterations } => {
                if !(tolerance > 0.0 && tolerance.is_finite()) {
                    return Err(fe("fusion.solver.tolerance", format!("{tolerance} must be a finite number > 0")));
                }
                if max_iterations == 0 {
                    return Err(fe("fusion.solver.max_iterations", "must be ≥ 1"));
                }
            }
        }

        let mut trajectories = Vec::with_capacity(self.targets.len());
        for (i, t) in self.targets.iter().enumerate() {
            let p = format!("targets[{i}]");
            if t.name.trim().is_empty() {
                return Err(fe(format!("{p}.name"), "must not be empty"));
            }
            if self.targets[..i].iter().any(|o| o.name == t.name) {
                return Err(fe(format!("{p}.name"), format!("`{}` is used by an earlier target", t.name)));
            }
            trajectories
                .push(t.trajectory.build(base_dir).map_err(|e| fe(format!("{p}.trajectory.{}", e.field), e.message))?);
            if !(t.semi_axes_m.is_finite() && t.semi_axes_m.min_element() > 0.0) {
                return Err(fe(format!("{p}.semi_axes_m"), "each semi-axis must be a finite number > 0"));
            }
            if let Some(m) = t.mach
                && !(m.is_finite() && (0.0..=30.0).contains(&m))
            {
                return Err(fe(format!("{p}.mach"), format!("{m} must be in [0, 30]")));
            }
            if !(0.0..=1.0).contains(&t.emissivity) {
                return Err(fe(format!("{p}.emissivity"), format!("{} must be in [0, 1]", t.emissivity)));
            }
            t.brdf
                .validate()
                .map_err(|e| fe(format!("{p}.brdf.{}", e.name), format!("{} is outside {}", e.value, e.range)))?;
        }
        Ok((observer, trajectories, sky_image))
    }
}
