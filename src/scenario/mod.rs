//! Scenarios: what a run simulates, as a serde schema (TOML or JSON) with validation.
//!
//! Pure: no Bevy. [`load()`] reads a file and returns a [`Scenario`] whose every value has been checked, or a
//! [`ScenarioError`] that names the file, line, column and field. The schema is documented field by field in
//! `docs/scenarios.md`.

pub mod edit;
pub mod load;
pub mod locate;
pub mod quality;
pub mod sensor;
pub mod trajectory;

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use serde::de::IgnoredAny;

use crate::imaging::camera::YawPitchRoll;
use crate::imaging::sky_field::SkyCalibration;
use crate::imaging::sky_gen::SkyGenSpec;
use crate::imaging::sky_plane::{MissFill, SkyError, SkyPlacement};
use crate::imaging::vibration::VibrationSpec;
use crate::physics::ParamError;
use crate::physics::atmosphere::{AirTemperature, STANDARD_T0_K};
use crate::physics::brdf::CookTorrance;
use crate::physics::lowtran::{Aerosol, AtmosphereTable, ModelAtmosphere, Weather};
use crate::physics::lowtran_paths::LowtranAtmosphere;
use crate::physics::planck::band_radiance_in;
use crate::physics::reflection::Sun;
use crate::physics::skin::StagnationModel;
use crate::physics::sky::{ClearSkyModel, DomeSpec};
use crate::physics::transmittance::Transmittance;
pub use load::{ScenarioError, load, load_str};
pub use quality::{Quality, QualityPreset, QualitySpec};
use sensor::moved_to_quality;
pub use sensor::{BlobSettings, BlobSpec, ResolvedSensor, SensorSpec, TargetModel};
use trajectory::{Exceeds, MAX_COORDINATE_M, MAX_SPEED_M_S, Trajectory, TrajectorySpec};

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
    /// The sky: the clear-sky dome, and an image or a generated cloud layer placed in the world.
    #[serde(default)]
    pub sky: SkySpec,
    /// Air temperature and transmittance.
    #[serde(default)]
    pub atmosphere: AtmosphereSpec,
    /// The sun.
    #[serde(default)]
    pub sun: Sun,
    /// Moved: `[quality] fusion_solver` and `fusion_guidance`.
    #[serde(default, skip_serializing)]
    pub fusion: Option<IgnoredAny>,
    /// The aircraft.
    #[serde(default)]
    pub targets: Vec<TargetSpec>,
    /// What the labels call detectable.
    #[serde(default)]
    pub labels: LabelsSpec,
    /// Accuracy against speed: a preset and overrides.
    #[serde(default)]
    pub quality: QualitySpec,
}

/// `[labels]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LabelsSpec {
    /// A target in the frame is `detectable` when its SNR (peak signal over the temporal noise at its
    /// background) is at least this.
    pub detectable_snr: f64,
    /// A pixel belongs to a target's mask where the target's own contribution there reaches this fraction of
    /// its peak (the contribution's magnitude: a target darker than its sky counts as well).
    pub mask_fraction: f64,
}

impl Default for LabelsSpec {
    fn default() -> Self {
        Self { detectable_snr: 3.0, mask_fraction: 0.1 }
    }
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

/// Where the camera points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum Pointing {
    /// At a fixed world point.
    LookAt {
        /// The point, m.
        #[serde(with = "crate::physics::exact::dvec3")]
        target_m: DVec3,
        /// Roll about the optical axis, degrees.
        #[serde(default)]
        roll_deg: f64,
    },
    /// At a named target, through a tracking loop: aimed at where the target was `lag_s` ago, plus seeded
    /// pointing noise.
    Track {
        /// The target's name.
        target: String,
        /// Roll about the optical axis, degrees.
        #[serde(default)]
        roll_deg: f64,
        /// Delay of the tracking loop, s.
        #[serde(default = "default_track_lag")]
        lag_s: f64,
        /// Rms pointing noise per axis, µrad (white from frame to frame).
        #[serde(default = "default_track_noise")]
        noise_urad: f64,
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

fn default_track_lag() -> f64 {
    0.05
}
fn default_track_noise() -> f64 {
    30.0
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

/// The sky (paper III.B, as radiance): the clear-sky dome, and optionally an image or a generated cloud layer
/// placed as a plane in the world.
///
/// The placement fields repeat [`SkyPlacement`]'s ([`SkySpec::placement`] converts): serde's `flatten` cannot be
/// combined with `deny_unknown_fields`, which every scenario table uses.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkySpec {
    /// Image file, relative to the scenario file (needs `calibration`).
    #[serde(default)]
    pub image: Option<String>,
    /// How the image's values become radiance.
    #[serde(default)]
    pub calibration: Option<SkyCalibration>,
    /// A generated cloud or haze layer instead of an image.
    #[serde(default)]
    pub generate: Option<SkyGenSpec>,
    /// Cloud-base temperature of a generated layer relative to the air at its height, K.
    #[serde(default)]
    pub cloud_offset_k: f64,
    /// Cloud-base altitude of a generated layer, m: below it the layer holds no cloud (it fades out over the
    /// 100 m above); default none, clouds wherever the layer is.
    #[serde(default)]
    pub cloud_base_m: Option<f64>,
    /// Largest side of a generated layer, texels (its resolution follows the sensor's footprint up to this). A
    /// smaller layer is the same clouds without their finest detail ([`crate::imaging::sky_gen::gaussian_field`]).
    #[serde(default = "default_max_texels")]
    pub max_texels: usize,
    /// World position of the anchor point P, m.
    #[serde(default, with = "crate::physics::exact::opt_dvec3")]
    pub anchor_m: Option<DVec3>,
    /// Image coordinates of P, px; default the image centre.
    #[serde(default, with = "crate::physics::exact::opt_dvec2")]
    pub anchor_px: Option<DVec2>,
    /// Width of the image in the world, m.
    #[serde(default)]
    pub width_m: Option<f64>,
    /// Height of the image in the world, m.
    #[serde(default)]
    pub height_m: Option<f64>,
    /// Plane normal toward the camera; default vertical, facing the observer's start.
    #[serde(default, with = "crate::physics::exact::opt_dvec3")]
    pub normal: Option<DVec3>,
    /// World direction of the image's up; default +z.
    #[serde(default, with = "crate::physics::exact::opt_dvec3")]
    pub up: Option<DVec3>,
    /// Moved: `[quality] sky_sampling`.
    #[serde(default, skip_serializing)]
    pub sampling: Option<IgnoredAny>,
    /// What rays that miss the image get (default: the dome along the ray).
    #[serde(default)]
    pub miss: MissFill,
    /// The clear sky and the ground.
    #[serde(default)]
    pub dome: DomeSpec,
    /// Removed: see `calibration`.
    #[serde(default, skip_serializing)]
    pub gray_gain: Option<IgnoredAny>,
    /// Removed: see `calibration`.
    #[serde(default, skip_serializing)]
    pub gray_offset: Option<IgnoredAny>,
}

fn default_max_texels() -> usize {
    4096
}

impl SkySpec {
    /// The placement part, if the anchor and size are given.
    pub fn placement(&self) -> Option<SkyPlacement> {
        Some(SkyPlacement {
            anchor_m: self.anchor_m?,
            anchor_px: self.anchor_px,
            width_m: self.width_m?,
            height_m: self.height_m?,
            normal: self.normal,
            up: self.up,
        })
    }

    /// True if an image or a generated layer is placed in the world.
    pub fn has_layer(&self) -> bool {
        self.image.is_some() || self.generate.is_some()
    }
}

/// Air temperature profile, skin heating, and the atmosphere's transmittance and path radiance: the LOWTRAN7
/// weather (`model`, `aerosol`, `visibility_km`) or a band-averaged override (`transmittance`), not both.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AtmosphereSpec {
    /// Sea-level temperature for eq 2, K (default 288.15); refused with `model`, whose own profile the air follows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub t0_k: Option<f64>,
    /// LOWTRAN model atmosphere: with it, LOWTRAN7's tables give every path's transmittance and path radiance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<ModelAtmosphere>,
    /// LOWTRAN aerosol model (default `rural`; `none` for a clear, aerosol-free path).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aerosol: Option<Aerosol>,
    /// Meteorological range at sea level of the aerosol, km (default 23).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub visibility_km: Option<f64>,
    /// Band-averaged transmittance override: a fixed τ or Beer–Lambert (without `model`; neither: τ = 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transmittance: Option<Transmittance>,
    /// The sky image holds the radiance at its plane, not at the sensor: each texel is seen through the path from
    /// the observer's start to it (transmitted, plus that path's own radiance). Generated layers always are.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub sky_path: bool,
    /// Stagnation constants of eq 1.
    pub stagnation: StagnationModel,
}

/// Visibility of the LOWTRAN weather when the scenario gives none, km.
pub const DEFAULT_VISIBILITY_KM: f64 = 23.0;

impl AtmosphereSpec {
    /// The LOWTRAN weather, if the scenario names a model atmosphere.
    pub fn weather(&self) -> Option<Weather> {
        let aerosol = self.aerosol.unwrap_or(Aerosol::Rural);
        Some(Weather {
            model: self.model?,
            aerosol,
            visibility_km: self.visibility_km.unwrap_or(DEFAULT_VISIBILITY_KM),
        })
    }

    /// The air's temperature against altitude: the model atmosphere's profile, or eq 2 from `t0_k`.
    ///
    /// # Errors
    /// [`crate::physics::lowtran::AtmosphereError`] if the built-in LOWTRAN table cannot be read.
    pub fn air_temperature(&self) -> Result<AirTemperature, crate::physics::lowtran::AtmosphereError> {
        Ok(match self.model {
            Some(model) => AirTemperature::of_model(model, AtmosphereTable::shipped()?),
            None => AirTemperature::Standard { t0_k: self.t0_k.unwrap_or(STANDARD_T0_K) },
        })
    }

    /// The band-averaged override (τ = 1 when none is given).
    pub fn override_transmittance(&self) -> Transmittance {
        self.transmittance.unwrap_or_default()
    }
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
    #[serde(with = "crate::physics::exact::dvec3")]
    pub semi_axes_m: DVec3,
    /// Mach number; default from the speed and the speed of sound at the altitude.
    #[serde(default)]
    pub mach: Option<f64>,
    /// Skin emissivity.
    #[serde(default = "default_emissivity")]
    pub emissivity: f64,
    /// Skin temperature above the stagnation temperature from internal heat (a drone's motors and batteries,
    /// an engine bay), K; default 0, the paper's skin.
    #[serde(default)]
    pub heating_k: f64,
    /// Reflectance.
    #[serde(default)]
    pub brdf: CookTorrance,
    /// Moved: `[quality] reflection`.
    #[serde(default, skip_serializing)]
    pub reflection: Option<IgnoredAny>,
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
    /// Where in another file the fault lies (a trajectory CSV's line), if not in the scenario itself.
    pub at: Option<TextPosition>,
}

/// A position in a file other than the scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct TextPosition {
    /// The file.
    pub file: String,
    /// 1-based line.
    pub line: usize,
    /// 1-based column.
    pub column: usize,
}

fn num(v: f64) -> crate::physics::Num {
    crate::physics::Num(v)
}

/// Maps a [`ParamError`] of a table at `prefix` to the field error naming `prefix.name`: the one conversion of
/// every physics and imaging `validate` into a located error.
pub fn at(prefix: &str) -> impl Fn(ParamError) -> FieldError + '_ {
    move |e| fe(format!("{prefix}.{}", e.name), format!("{} is outside {}", num(e.value), e.range))
}

fn fe(path: impl Into<String>, message: impl std::fmt::Display) -> FieldError {
    FieldError { path: path.into(), message: message.to_string(), at: None }
}

/// Lowest frame rate, Hz (one frame every 1000 s).
pub const MIN_FRAME_RATE_HZ: f64 = 1e-3;
/// Highest frame rate, Hz.
pub const MAX_FRAME_RATE_HZ: f64 = 1e5;
/// Most sweeps an iterative fusion solver may be asked for (a solve also stops at
/// [`crate::imaging::fusion::MAX_SWEEP_UPDATES`] pixel updates).
pub const MAX_SOLVER_ITERATIONS: u32 = 100_000;
/// Largest |time| of frame 0, s (about 32 years).
pub const MAX_ABS_TIME_S: f64 = 1e9;

/// Builds a trajectory and checks that it stays within [`MAX_COORDINATE_M`] and [`MAX_SPEED_M_S`] over the
/// run's times `t0 ..= t1`.
fn build_trajectory(
    spec: &TrajectorySpec,
    path: &str,
    base_dir: &Path,
    (t0, t1): (f64, f64),
) -> Result<Trajectory, FieldError> {
    let tr = spec.build(base_dir).map_err(|e| FieldError {
        path: format!("{path}.{}", e.field),
        message: e.message,
        at: e.csv.map(|(file, line)| TextPosition { file, line, column: 1 }),
    })?;
    let (reach_m, speed_m_s) = tr.bounds(t0, t1);
    let culprit = |what| match spec.culprit(what, (t0, t1)) {
        Some(field) => format!("{path}.{field}"),
        None => path.to_owned(),
    };
    if !(reach_m <= MAX_COORDINATE_M) {
        return Err(fe(
            culprit(Exceeds::Position),
            format!(
                "leaves the modelled world during the run (t = {} … {} s): a coordinate may reach {reach_m:e} m, \
                 more than {MAX_COORDINATE_M:e} m",
                num(t0),
                num(t1)
            ),
        ));
    }
    if !(speed_m_s <= MAX_SPEED_M_S) {
        return Err(fe(
            culprit(Exceeds::Speed),
            format!(
                "is too fast during the run (t = {} … {} s): its speed may reach {speed_m_s:e} m/s, more than \
                 {MAX_SPEED_M_S:e} m/s",
                num(t0),
                num(t1)
            ),
        ));
    }
    Ok(tr)
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
    /// The sensor with the preset and overrides resolved.
    pub sensor: ResolvedSensor,
    /// Every accuracy switch, resolved.
    pub quality: Quality,
}

/// What [`Scenario::check`] builds.
#[derive(Debug, Clone)]
pub struct Checked {
    /// Observer trajectory.
    pub observer: Trajectory,
    /// Target trajectories, in order.
    pub targets: Vec<Trajectory>,
    /// Resolved sky image path.
    pub sky_image: Option<PathBuf>,
    /// The resolved sensor.
    pub sensor: ResolvedSensor,
    /// The resolved accuracy switches.
    pub quality: Quality,
}

impl Scenario {
    /// [`Scenario::check`] in the directory of `source` (the file it came from, or will be saved as), keeping
    /// what it built: the one way from a scenario value to a [`CheckedScenario`], for files and for edits alike.
    ///
    /// # Errors
    /// The first [`FieldError`] found.
    pub fn checked(self, source: &Path) -> Result<CheckedScenario, FieldError> {
        let base = source.parent().map(Path::to_path_buf).unwrap_or_default();
        self.checked_in(source, &base)
    }

    /// [`Scenario::checked`] with relative paths resolved in `base_dir`.
    ///
    /// # Errors
    /// The first [`FieldError`] found.
    pub fn checked_in(self, source: &Path, base_dir: &Path) -> Result<CheckedScenario, FieldError> {
        let checked = self.check(base_dir)?;
        Ok(CheckedScenario {
            spec: self,
            source: PathBuf::from(source),
            observer_trajectory: checked.observer,
            target_trajectories: checked.targets,
            sky_image: checked.sky_image,
            sensor: checked.sensor,
            quality: checked.quality,
        })
    }

    /// Rewrites the relative file paths (the sky image, CSV trajectories) that resolve in `from_dir` so that
    /// they resolve the same from `to_dir`: unchanged when the directories are the same, absolute otherwise.
    pub fn rebase_paths(&mut self, from_dir: &Path, to_dir: &Path) {
        let same = |a: &Path, b: &Path| {
            let canon =
                |p: &Path| std::fs::canonicalize(if p.as_os_str().is_empty() { Path::new(".") } else { p }).ok();
            canon(a).is_some_and(|a| Some(a) == canon(b))
        };
        if same(from_dir, to_dir) {
            return;
        }
        let rebase = |p: &mut String| {
            if Path::new(p.as_str()).is_relative() {
                let joined = from_dir.join(p.as_str());
                let absolute =
                    std::fs::canonicalize(&joined).or_else(|_| std::path::absolute(&joined)).unwrap_or(joined);
                *p = absolute.display().to_string();
            }
        };
        if let Some(image) = &mut self.sky.image {
            rebase(image);
        }
        let trajectories =
            std::iter::once(&mut self.observer.trajectory).chain(self.targets.iter_mut().map(|t| &mut t.trajectory));
        for tr in trajectories {
            if let TrajectorySpec::Csv { path } = tr {
                rebase(path);
            }
        }
    }

    /// Checks every value and builds the trajectories; `base_dir` resolves relative paths.
    ///
    /// # Errors
    /// The first [`FieldError`] found.
    pub fn check(&self, base_dir: &Path) -> Result<Checked, FieldError> {
        let r = &self.run;
        if !(r.frame_rate_hz.is_finite() && (MIN_FRAME_RATE_HZ..=MAX_FRAME_RATE_HZ).contains(&r.frame_rate_hz)) {
            return Err(fe(
                "run.frame_rate_hz",
                format!("{} must be in [{MIN_FRAME_RATE_HZ}, {MAX_FRAME_RATE_HZ}] Hz", num(r.frame_rate_hz)),
            ));
        }
        if !(r.start_time_s.is_finite() && r.start_time_s.abs() <= MAX_ABS_TIME_S) {
            return Err(fe("run.start_time_s", format!("{} must be in [−1e9, 1e9] s", num(r.start_time_s))));
        }
        if r.frames == 0 || r.frames > 100_000_000 {
            return Err(fe("run.frames", format!("{} must be in 1 … 100000000", r.frames)));
        }
        if self.fusion.is_some() {
            return Err(fe("fusion", moved_to_quality("fusion_solver` / `fusion_guidance")));
        }
        if self.sky.sampling.is_some() {
            return Err(fe("sky.sampling", moved_to_quality("sky_sampling")));
        }
        if let Some(i) = self.targets.iter().position(|t| t.reflection.is_some()) {
            return Err(fe(format!("targets[{i}].reflection"), moved_to_quality("reflection")));
        }
        let quality = self.quality.resolve()?;
        let sensor = self.sensor.resolve(&quality)?;
        if !(self.labels.detectable_snr.is_finite() && self.labels.detectable_snr >= 0.0) {
            return Err(fe(
                "labels.detectable_snr",
                format!("{} must be a finite number ≥ 0", num(self.labels.detectable_snr)),
            ));
        }
        let fraction = self.labels.mask_fraction;
        if !(fraction > 0.0 && fraction <= 1.0) {
            return Err(fe(
                "labels.mask_fraction",
                format!(
                    "{} must be in (0, 1]: the fraction of a target's peak that puts a pixel in its mask",
                    num(fraction)
                ),
            ));
        }

        let (t0, t1) = (r.start_time_s, r.start_time_s + (r.frames - 1) as f64 / r.frame_rate_hz);
        let observer = build_trajectory(&self.observer.trajectory, "observer.trajectory", base_dir, (t0, t1))?;
        self.observer.vibration.validate().map_err(at("observer.vibration"))?;
        match &self.observer.pointing {
            Pointing::LookAt { target_m, roll_deg } => {
                if !(target_m.is_finite() && target_m.abs().max_element() <= MAX_COORDINATE_M) {
                    return Err(fe(
                        "observer.pointing.target_m",
                        format!("each coordinate must be in [−{MAX_COORDINATE_M:e}, {MAX_COORDINATE_M:e}] m"),
                    ));
                }
                if !roll_deg.is_finite() {
                    return Err(fe("observer.pointing.roll_deg", "must be finite"));
                }
            }
            Pointing::Track { target, roll_deg, lag_s, noise_urad } => {
                if !self.targets.iter().any(|t| &t.name == target) {
                    return Err(fe("observer.pointing.target", format!("no target named `{target}`")));
                }
                if !roll_deg.is_finite() {
                    return Err(fe("observer.pointing.roll_deg", "must be finite"));
                }
                if !(lag_s.is_finite() && (0.0..=10.0).contains(lag_s)) {
                    return Err(fe("observer.pointing.lag_s", format!("{} must be in [0, 10] s", num(*lag_s))));
                }
                if !(noise_urad.is_finite() && (0.0..=1e5).contains(noise_urad)) {
                    return Err(fe(
                        "observer.pointing.noise_urad",
                        format!("{} must be in [0, 1e5] µrad", num(*noise_urad)),
                    ));
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
                for (n, v) in [("yaw_offset_deg", yaw_offset_deg), ("pitch_offset_deg", pitch_offset_deg)] {
                    if !(v.is_finite() && v.abs() <= 1e6) {
                        return Err(fe(
                            format!("observer.pointing.{n}"),
                            format!("{} must be in [−1e6, 1e6]°", num(*v)),
                        ));
                    }
                }
            }
        }

        let sky = &self.sky;
        if sky.gray_gain.is_some() || sky.gray_offset.is_some() {
            let which = if sky.gray_gain.is_some() { "gray_gain" } else { "gray_offset" };
            return Err(fe(
                format!("sky.{which}"),
                "was removed: the sky is now radiance; give `calibration = { mode = \"temperature\", \
                 value_range = [lo, hi], temp_range_k = [t_lo, t_hi] }` (the image values' brightness \
                 temperatures in the band) or `{ mode = \"kelvin\", scale_k = … }` (docs/scenarios.md, \"Migrating\")",
            ));
        }
        sky.dome.validate().map_err(at("sky.dome"))?;
        if sky.image.is_some() && sky.generate.is_some() {
            return Err(fe("sky.generate", "give either `image` or `generate`, not both"));
        }
        if let Some(g) = &sky.generate {
            g.validate().map_err(at("sky.generate"))?;
        }
        if !(sky.cloud_offset_k.is_finite() && (-100.0..=100.0).contains(&sky.cloud_offset_k)) {
            return Err(fe("sky.cloud_offset_k", format!("{} must be in [−100, 100] K", num(sky.cloud_offset_k))));
        }
        if let Some(b) = sky.cloud_base_m
            && !(b.is_finite() && (-5000.0..=86000.0).contains(&b))
        {
            return Err(fe("sky.cloud_base_m", format!("{} must be in [−5000, 86000] m", num(b))));
        }
        if sky.generate.is_some() && !(16..=8192).contains(&sky.max_texels) {
            return Err(fe("sky.max_texels", format!("{} must be in 16 … 8192", sky.max_texels)));
        }
        if let Some(c) = &sky.calibration {
            c.validate().map_err(at("sky.calibration"))?;
        }
        let sky_image = if sky.has_layer() {
            let Some(anchor) = sky.anchor_m else {
                return Err(fe("sky.anchor_m", "is required with `image` or `generate`"));
            };
            if !(anchor.is_finite() && anchor.abs().max_element() <= MAX_COORDINATE_M) {
                return Err(fe(
                    "sky.anchor_m",
                    format!("each coordinate must be in [−{MAX_COORDINATE_M:e}, {MAX_COORDINATE_M:e}] m"),
                ));
            }
            if let Some(px) = sky.anchor_px
                && !(px.is_finite() && px.abs().max_element() <= 1e9)
            {
                return Err(fe("sky.anchor_px", "each coordinate must be in [−1e9, 1e9] px"));
            }
            for (n, v) in [("width_m", sky.width_m), ("height_m", sky.height_m)] {
                match v {
                    None => return Err(fe(format!("sky.{n}"), "is required with `image` or `generate`")),
                    Some(v) if !(v.is_finite() && v > 0.0 && v <= MAX_COORDINATE_M) => {
                        return Err(fe(
                            format!("sky.{n}"),
                            format!("{} must be in (0, {MAX_COORDINATE_M:e}] m", num(v)),
                        ));
                    }
                    _ => {}
                }
            }
            if let Some(placement) = sky.placement() {
                placement.axes(observer.state(r.start_time_s).0).map_err(|e| match e {
                    SkyError::Placement { name, message } => fe(format!("sky.{name}"), message),
                    other => fe("sky", other),
                })?;
            }
            let largest = band_radiance_in(sensor.model.measure(), sensor.model.band, 6000.0, 1.0) as f32;
            if let MissFill::Constant { value } = sky.miss
                && !(value.is_finite() && (0.0..=largest).contains(&value))
            {
                return Err(fe(
                    "sky.miss.value",
                    format!(
                        "{} must be a radiance in [0, {largest:e}] (0 K … a 6000 K black body in the band)",
                        num(f64::from(value))
                    ),
                ));
            }
            match &sky.image {
                Some(image) => {
                    if sky.calibration.is_none() {
                        return Err(fe(
                            "sky.calibration",
                            "is required with `image`: say what the values mean, e.g. `{ mode = \"temperature\", \
                             value_range = [0, 65535], temp_range_k = [220, 290] }`",
                        ));
                    }
                    let path = base_dir.join(image);
                    if !path.is_file() {
                        return Err(fe("sky.image", format!("file not found: {}", path.display())));
                    }
                    Some(path)
                }
                None => None,
            }
        } else {
            None
        };

        let a = &self.atmosphere;
        if let Some(t0) = a.t0_k {
            if !(t0.is_finite() && t0 > 100.0 && t0 < 400.0) {
                return Err(fe("atmosphere.t0_k", format!("{} must be in (100, 400) K", num(t0))));
            }
            if let Some(model) = a.model {
                let sea = AtmosphereTable::shipped()
                    .map(|t| AirTemperature::of_model(model, t).sea_level_k())
                    .map_err(|e| fe("atmosphere.model", e))?;
                return Err(fe(
                    "atmosphere.t0_k",
                    format!(
                        "the air follows the model atmosphere's own temperature profile (`model = \"{}\"`, {sea:.2} K \
                         at sea level): leave t0_k out, or give `atmosphere.transmittance` instead of `model`",
                        model.name()
                    ),
                ));
            }
        }
        if let Some(t) = &a.transmittance {
            t.validate().map_err(at("atmosphere.transmittance"))?;
        }
        a.stagnation.validate().map_err(|e| fe("atmosphere.stagnation", e))?;
        let lowtran = check_weather(a, &sensor)?;
        check_clear_sky(&self.sky.dome, a)?;
        let sun = &self.sun;
        for (n, v, ok) in [
            ("temp_k", sun.temp_k, sun.temp_k >= 0.0 && sun.temp_k <= 1e5),
            ("solid_angle_sr", sun.solid_angle_sr, sun.solid_angle_sr >= 0.0 && sun.solid_angle_sr < 1.0),
            ("azimuth_deg", sun.azimuth_deg, true),
            ("elevation_deg", sun.elevation_deg, (-90.0..=90.0).contains(&sun.elevation_deg)),
        ] {
            if !(v.is_finite() && ok) {
                return Err(fe(format!("sun.{n}"), format!("{} is outside its allowed range", num(v))));
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
            trajectories.push(build_trajectory(&t.trajectory, &format!("{p}.trajectory"), base_dir, (t0, t1))?);
            if !(t.semi_axes_m.is_finite() && t.semi_axes_m.min_element() >= 1e-4 && t.semi_axes_m.max_element() <= 1e4)
            {
                return Err(fe(format!("{p}.semi_axes_m"), "each semi-axis must be in [1e-4, 1e4] m"));
            }
            if let Some(m) = t.mach
                && !(m.is_finite() && (0.0..=30.0).contains(&m))
            {
                return Err(fe(format!("{p}.mach"), format!("{} must be in [0, 30]", num(m))));
            }
            if !(0.0..=1.0).contains(&t.emissivity) {
                return Err(fe(format!("{p}.emissivity"), format!("{} must be in [0, 1]", t.emissivity)));
            }
            if !(t.heating_k.is_finite() && (0.0..=2000.0).contains(&t.heating_k)) {
                return Err(fe(format!("{p}.heating_k"), format!("{} must be in [0, 2000]", t.heating_k)));
            }
            if let Some(a) = &t.attitude {
                for (n, v) in [("yaw_deg", a.yaw_deg), ("pitch_deg", a.pitch_deg), ("roll_deg", a.roll_deg)] {
                    if !(v.is_finite() && v.abs() <= 1e6) {
                        return Err(fe(format!("{p}.attitude.{n}"), format!("{} must be in [−1e6, 1e6]°", num(v))));
                    }
                }
            }
            t.brdf.validate().map_err(at(&format!("{p}.brdf")))?;
        }
        if let Some(table) = lowtran {
            check_lines_of_sight(self, table, &observer, &trajectories)?;
        }
        Ok(Checked { observer, targets: trajectories, sky_image, sensor, quality })
    }
}

/// Checks the LOWTRAN weather's fields; the table when the scenario uses it.
fn check_weather(a: &AtmosphereSpec, sensor: &ResolvedSensor) -> Result<Option<&'static AtmosphereTable>, FieldError> {
    let Some(model) = a.model else {
        for (name, given) in [("aerosol", a.aerosol.is_some()), ("visibility_km", a.visibility_km.is_some())] {
            if given {
                return Err(fe(
                    format!("atmosphere.{name}"),
                    "is part of the LOWTRAN weather: give `atmosphere.model` too (e.g. \"midlatitude_summer\")",
                ));
            }
        }
        return Ok(None);
    };
    if a.transmittance.is_some() {
        return Err(fe(
            "atmosphere.transmittance",
            format!(
                "overrides the LOWTRAN weather (`model = \"{}\"`): give one of `atmosphere.model` and \
                 `atmosphere.transmittance`, not both",
                model.name()
            ),
        ));
    }
    let table = AtmosphereTable::shipped().map_err(|e| fe("atmosphere.model", e))?;
    let aerosol = a.aerosol.unwrap_or(Aerosol::Rural);
    if let Some(v) = a.visibility_km {
        if aerosol == Aerosol::None {
            return Err(fe("atmosphere.visibility_km", "has no effect with `aerosol = \"none\"`: leave it out"));
        }
        let tabulated = table.visibilities_km(aerosol);
        let (lo, hi) = (tabulated[0], tabulated[tabulated.len() - 1]);
        if !(v.is_finite() && v >= lo && v <= hi) {
            return Err(fe(
                "atmosphere.visibility_km",
                format!(
                    "{} is outside the {lo}–{hi} km that LOWTRAN's {} aerosol is tabulated for ({})",
                    num(v),
                    aerosol.name(),
                    tabulated.iter().map(|x| format!("{x}")).collect::<Vec<_>>().join(", ")
                ),
            ));
        }
    }
    let band = sensor.model.band;
    let (lo, hi) = (table.edges_um()[0], table.edges_um()[table.edges_um().len() - 1]);
    if band.lo_um() < lo || band.hi_um() > hi {
        return Err(fe(
            "atmosphere.model",
            format!(
                "the sensor's band {}–{} µm is not inside the {lo}–{hi} µm that the LOWTRAN table covers; use \
                 `atmosphere.transmittance` for this band",
                num(band.lo_um()),
                num(band.hi_um())
            ),
        ));
    }
    Ok(Some(table))
}

/// The clear sky's source against the weather: LOWTRAN's needs a model atmosphere, and the parametric sky's
/// fields are refused where LOWTRAN's sky would leave them unused.
fn check_clear_sky(dome: &DomeSpec, a: &AtmosphereSpec) -> Result<(), FieldError> {
    match (dome.clear_sky, a.model) {
        (Some(ClearSkyModel::Lowtran), None) => Err(fe(
            "sky.dome.clear_sky",
            "\"lowtran\" needs the LOWTRAN weather: give `atmosphere.model` (e.g. \"midlatitude_summer\"), or use \
             \"parametric\"",
        )),
        (None | Some(ClearSkyModel::Lowtran), Some(model)) => match dome.parametric_fields_given().first() {
            Some(name) => Err(fe(
                format!("sky.dome.{name}"),
                format!(
                    "belongs to the parametric clear sky, but with `atmosphere.model = \"{}\"` the clear sky is \
                     LOWTRAN's: leave it out, or set `sky.dome.clear_sky = \"parametric\"`",
                    model.name()
                ),
            )),
            None => Ok(()),
        },
        _ => Ok(()),
    }
}

/// Frames at most sampled by [`check_lines_of_sight`] (every frame up to this many).
const SIGHT_CHECK_FRAMES: u64 = 20_000;

/// Checks that every target's line of sight stays inside the LOWTRAN table's grid over the run (0–20 km,
/// ranges to 100 km, above the ground): a path outside it is an error, never an extrapolation.
fn check_lines_of_sight(
    spec: &Scenario,
    table: &AtmosphereTable,
    observer: &Trajectory,
    targets: &[Trajectory],
) -> Result<(), FieldError> {
    let r = &spec.run;
    let stride = r.frames.div_ceil(SIGHT_CHECK_FRAMES).max(1);
    let mut frames: Vec<u64> = (0..r.frames).step_by(stride as usize).collect();
    if frames.last() != Some(&(r.frames - 1)) {
        frames.push(r.frames - 1);
    }
    let top_m = table.max_altitude_km() * 1000.0;
    for &k in &frames {
        let t = r.start_time_s + k as f64 / r.frame_rate_hz;
        let eye = observer.state(t).0;
        if !(eye.z >= 0.0 && eye.z <= top_m) {
            return Err(fe(
                "observer.trajectory",
                format!(
                    "at frame {k} (t = {} s) the observer is at {} m, outside the 0–{} m that the LOWTRAN table \
                     covers; use `atmosphere.transmittance` for this scene",
                    num(t),
                    num(eye.z),
                    num(top_m)
                ),
            ));
        }
        for (i, tr) in targets.iter().enumerate() {
            let p = tr.state(t).0;
            if let Err(e) = LowtranAtmosphere::check_sight(table, eye, p) {
                return Err(fe(
                    format!("targets[{i}].trajectory"),
                    format!(
                        "at frame {k} (t = {} s) the line of sight from the observer ({} m up) to `{}` ({} m up, \
                         {} m away) leaves the LOWTRAN table: {e}; keep the scene within 0–20 km altitude and \
                         100 km range, or use `atmosphere.transmittance`",
                        num(t),
                        num(eye.z),
                        spec.targets[i].name,
                        num(p.z),
                        num(eye.distance(p))
                    ),
                ));
            }
        }
    }
    Ok(())
}
