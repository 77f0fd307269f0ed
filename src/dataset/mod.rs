//! Datasets: a spec of distributions (sensors, skies, weather, target classes, trajectory families, ranges),
//! drawn into one complete scenario per sequence.
//!
//! Sequence `k` is drawn from its own random stream, keyed by the dataset's seed and `k` alone, so that it is
//! the same whatever the number of shards and the order they run in.

pub mod card;
pub mod classes;
pub mod merge;
pub mod solve;

use std::fmt::Write as _;

use glam::DVec3;
use serde::Deserialize;

use crate::imaging::frame::PngCompression;
use crate::imaging::sky_field::SkyCalibration;
use crate::physics::detector::Preset;
use crate::physics::random::{SplitMix64, mix64};
use crate::scenario::load::{ScenarioError, line_col};
use crate::scenario::locate::Nodes;
use crate::scenario::{Quality, QualityPreset, SensorSpec};
pub use classes::TargetClass;

/// A closed range `[min, max]` to draw from uniformly.
pub type Range = [f64; 2];

/// `[min, max]`: exactly two values (serde's fixed-size arrays let TOML's longer lists through).
fn pair<'de, D, T>(d: D) -> Result<[T; 2], D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de> + Copy,
{
    let v = Vec::<T>::deserialize(d)?;
    match v[..] {
        [a, b] => Ok([a, b]),
        _ => Err(serde::de::Error::invalid_length(v.len(), &"exactly 2 values, [min, max]")),
    }
}

/// [`pair`] for an optional field.
fn optional_pair<'de, D, T>(d: D) -> Result<Option<[T; 2]>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de> + Copy,
{
    pair(d).map(Some)
}

/// What a dataset is drawn from (`irsim dataset SPEC`; fields in docs/datasets.md).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSpec {
    /// The dataset's name.
    pub name: String,
    /// Every sequence's random stream derives from this.
    pub seed: u64,
    /// How many sequences.
    pub sequences: u64,
    /// Frames per sequence.
    pub frames: u64,
    /// Frame rate, Hz.
    #[serde(default = "default_frame_rate")]
    pub frame_rate_hz: f64,
    /// The quality preset every sequence is recorded with.
    #[serde(default)]
    pub quality: Option<String>,
    /// How hard the 16-bit frames are compressed.
    #[serde(default)]
    pub png_compression: PngCompression,
    /// How targets are fused into the sky (`additive` unless given; docs/datasets.md says why).
    #[serde(default = "default_guidance")]
    pub fusion_guidance: String,
    /// Cameras to draw from (preset names).
    pub sensors: Vec<String>,
    /// NETD to draw, mK (the preset's when absent).
    #[serde(default, deserialize_with = "optional_pair")]
    pub netd_mk: Option<Range>,
    /// Targets per sequence.
    #[serde(deserialize_with = "pair")]
    pub targets_per_sequence: [u64; 2],
    /// Target classes to draw from.
    pub classes: Vec<String>,
    /// Trajectory families to draw from.
    pub trajectories: Vec<String>,
    /// Place each target, where the view allows, within its class's altitudes (true unless given).
    #[serde(default = "default_true")]
    pub class_altitudes: bool,
    /// Range from the observer at the sequence's middle, m; with `snr`, the ranges the solve may use
    /// ([`DEFAULT_SNR_RANGE_M`] unless given).
    #[serde(default, deserialize_with = "optional_pair")]
    pub range_m: Option<Range>,
    /// Each target's signal-to-noise ratio at the sequence's middle frame (the label's `snr`): its range is
    /// solved for it (by simulating that frame) instead of drawn.
    #[serde(default, deserialize_with = "optional_pair")]
    pub snr: Option<Range>,
    /// How `snr` is drawn.
    #[serde(default)]
    pub snr_draw: SnrDraw,
    /// The observer.
    #[serde(default)]
    pub observer: ObserverSpec,
    /// The sky layer.
    #[serde(default)]
    pub sky: SkySpec,
    /// The atmosphere.
    #[serde(default)]
    pub atmosphere: AtmosphereSpec,
    /// Whole sequences to train, val and test.
    #[serde(default)]
    pub split: SplitSpec,
    /// Optional extra frames per sequence.
    #[serde(default)]
    pub outputs: OutputSpec,
}

/// How a target's SNR is drawn from `snr`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SnrDraw {
    /// Uniform between the ends.
    #[default]
    Uniform,
    /// Uniform in the logarithm: as many targets between 2 and 4 as between 20 and 40.
    LogUniform,
}

/// The ranges an SNR solve may use when the spec gives `snr` without `range_m`, m.
pub const DEFAULT_SNR_RANGE_M: Range = [50.0, 20_000.0];

/// Fractions of the sequences in each set (whole sequences: a set never holds frames of another's sequence).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SplitSpec {
    /// Training fraction.
    pub train: f64,
    /// Validation fraction.
    pub val: f64,
    /// Test fraction.
    pub test: f64,
}

impl Default for SplitSpec {
    fn default() -> Self {
        Self { train: 0.8, val: 0.1, test: 0.1 }
    }
}

/// Extra frames recorded beside each sequence's frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputSpec {
    /// `clean/`: each frame without targets and without noise (the same camera path, sky and weather).
    pub clean_background: bool,
    /// `noise_free/`: each frame with its targets, without temporal noise.
    pub noise_free: bool,
}

/// The set a sequence belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Set {
    /// Training.
    Train,
    /// Validation.
    Val,
    /// Test.
    Test,
}

impl Set {
    /// The three, in order.
    pub const ALL: [Set; 3] = [Set::Train, Set::Val, Set::Test];

    /// `train`, `val` or `test`.
    pub fn name(self) -> &'static str {
        match self {
            Set::Train => "train",
            Set::Val => "val",
            Set::Test => "test",
        }
    }
}

fn default_true() -> bool {
    true
}

fn default_frame_rate() -> f64 {
    30.0
}

/// A dataset's frames keep the sky's texture next to each target: the paper's Poisson guidance replaces it
/// with a smooth fill over the target's whole region (tens of pixels for a PSF's reach), a square a detector
/// learns to find instead of the target.
fn default_guidance() -> String {
    "additive".into()
}

/// The fusion guidances a spec may name.
pub const GUIDANCES: [&str; 3] = ["additive", "mixed", "normal"];

/// How the observer is drawn.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObserverSpec {
    /// Altitude, m.
    #[serde(deserialize_with = "pair")]
    pub altitude_m: Range,
    /// Elevation of the line of sight, degrees.
    #[serde(deserialize_with = "pair")]
    pub look_elevation_deg: Range,
    /// Line-of-sight jitter amplitude, degrees.
    #[serde(deserialize_with = "pair")]
    pub vibration_deg: Range,
    /// The platform's ground speed, m/s; absent, the observer stands still (and the fields below are refused).
    /// A moving camera looks in a fixed direction relative to its velocity.
    #[serde(deserialize_with = "optional_pair")]
    pub speed_m_s: Option<Range>,
    /// Flight heading relative to the line of sight's azimuth, degrees (0: looking ahead, 90: looking left of
    /// the track); default all round, [−180, 180].
    #[serde(deserialize_with = "optional_pair")]
    pub heading_deg: Option<Range>,
    /// Turn rate, degrees per second, positive to the right (clockwise seen from above): the view pans with the
    /// platform; default straight, [0, 0].
    #[serde(deserialize_with = "optional_pair")]
    pub turn_rate_deg_s: Option<Range>,
    /// Climb rate, m/s; default level, [0, 0].
    #[serde(deserialize_with = "optional_pair")]
    pub climb_m_s: Option<Range>,
}

impl Default for ObserverSpec {
    fn default() -> Self {
        Self {
            altitude_m: [100.0, 1000.0],
            look_elevation_deg: [2.0, 15.0],
            vibration_deg: [0.0, 0.02],
            speed_m_s: None,
            heading_deg: None,
            turn_rate_deg_s: None,
            climb_m_s: None,
        }
    }
}

/// How the sky layer is drawn.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SkySpec {
    /// Kinds to draw from: `clear`, `cumulus`, `none` (the dome alone).
    pub kinds: Vec<String>,
    /// Cumulus cover fraction.
    #[serde(deserialize_with = "pair")]
    pub cover: Range,
    /// Distance of the layer, m (at least twice the largest target range).
    #[serde(deserialize_with = "pair")]
    pub distance_m: Range,
    /// The user's sky images the kind `image` draws from.
    pub images: Option<SkyImagesSpec>,
}

impl Default for SkySpec {
    fn default() -> Self {
        Self {
            kinds: vec!["clear".into(), "cumulus".into()],
            cover: [0.2, 0.6],
            distance_m: [8000.0, 20000.0],
            images: None,
        }
    }
}

/// A folder of infrared sky images, and how they are placed in the world.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkyImagesSpec {
    /// The folder, relative to the spec file: every PNG, TIFF and PNM in it (not its subfolders), in name order.
    /// They are copied into the dataset's `skies/`, which the sequences' scenarios name.
    pub folder: String,
    /// How the images' values become radiance (as a scenario's `sky.calibration`), the same for every image.
    pub calibration: SkyCalibration,
    /// Width of the image over the width of the view at the layer's distance (1.3 or more keeps the view, its
    /// jitter and its pan inside the image); the height follows the image's aspect.
    #[serde(default = "default_span", deserialize_with = "pair")]
    pub span: Range,
    /// Rotation of the image in its plane, degrees (positive counter-clockwise as seen from the camera).
    #[serde(default, deserialize_with = "pair")]
    pub roll_deg: Range,
    /// The images hold the radiance at their plane (a cloud's own), not at the camera: each texel is seen
    /// through the air between (the scenario's `atmosphere.sky_path`). Default false: the image is what a camera
    /// near the observer saw.
    #[serde(default)]
    pub at_plane: bool,
}

fn default_span() -> Range {
    [1.5, 3.0]
}

/// One image of [`SkyImagesSpec::folder`], as the draw needs it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SkyFile {
    /// File name (in the dataset's `skies/`).
    pub name: String,
    /// Width, px.
    pub width: usize,
    /// Height, px.
    pub height: usize,
}

/// The file extensions a sky folder's images may have.
pub const SKY_IMAGE_EXTENSIONS: [&str; 6] = ["png", "tif", "tiff", "pgm", "ppm", "pnm"];

/// How the weather is drawn.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AtmosphereSpec {
    /// LOWTRAN7 model atmospheres to draw from.
    pub models: Vec<String>,
    /// Aerosol models to draw from.
    pub aerosols: Vec<String>,
    /// Visibility, km.
    #[serde(deserialize_with = "pair")]
    pub visibility_km: Range,
}

impl Default for AtmosphereSpec {
    fn default() -> Self {
        Self { models: vec!["us_standard_1976".into()], aerosols: vec!["rural".into()], visibility_km: [10.0, 50.0] }
    }
}

/// The trajectory families a target's path is drawn from.
pub const TRAJECTORIES: [&str; 5] = ["straight", "crossing", "approach", "coordinated_turn", "weave"];
/// The sky kinds.
pub const SKY_KINDS: [&str; 4] = ["clear", "cumulus", "image", "none"];
/// The model atmospheres of the LOWTRAN table.
pub const MODELS: [&str; 6] = [
    "tropical",
    "midlatitude_summer",
    "midlatitude_winter",
    "subarctic_summer",
    "subarctic_winter",
    "us_standard_1976",
];
/// The aerosol models, each with the visibilities its table holds, km.
pub const AEROSOLS: [&str; 4] = ["none", "rural", "maritime", "urban"];

/// The visibilities LOWTRAN's table holds for `aerosol`, km: a drawn one is brought within them.
fn visibility_range_km(aerosol: &str) -> Range {
    match aerosol {
        "maritime" => [5.0, 50.0],
        "urban" => [2.0, 23.0],
        _ => [2.0, 50.0],
    }
}

/// A spec that cannot be used: where and why (file, line, column, field).
pub type SpecError = ScenarioError;

impl DatasetSpec {
    /// Reads and checks a spec's text; `file` names it in errors.
    ///
    /// # Errors
    /// A [`SpecError`] naming file, line, column and field for unreadable text, an unknown field or name, a
    /// range whose ends are not finite or out of order, and counts out of bounds.
    pub fn from_str(text: &str, file: &str) -> Result<Self, SpecError> {
        let nodes = Nodes::toml(text);
        let at = |field: &str, message: String, offset: Option<usize>| {
            let offset = offset.or_else(|| nodes.nearest(field).map(|n| n.key_start)).unwrap_or(0);
            let (line, column) = line_col(text, offset);
            SpecError { file: file.to_owned(), line, column, field: field.to_owned(), message }
        };
        let spec: Self = toml::from_str(text).map_err(|e| {
            let span = e.span().map(|s| (s.start, s.end));
            let node = span.and_then(|s| nodes.at_span(s));
            let message = e.message().trim().to_owned();
            let (field, located) = match node {
                Some(n) => nodes.refine(n, &message),
                None => (String::new(), None),
            };
            let offset = located.map(|n| n.key_start).or(span.map(|s| s.0));
            at(&field, message, offset)
        })?;
        spec.check().map_err(|(field, message)| at(&field, message, None))?;
        Ok(spec)
    }

    /// An error at `field` of the spec `text` (read from `file`): for what only the run can see (a sky folder).
    pub fn error_at(text: &str, file: &str, field: &str, message: String) -> SpecError {
        let offset = Nodes::toml(text).nearest(field).map_or(0, |n| n.key_start);
        let (line, column) = line_col(text, offset);
        SpecError { file: file.to_owned(), line, column, field: field.to_owned(), message }
    }

    /// `(field, message)` for the first value out of bounds.
    fn check(&self) -> Result<(), (String, String)> {
        let err = |f: &str, m: String| Err((f.to_owned(), m));
        let range = |f: &str, r: Range, lo: f64, hi: f64| -> Result<(), (String, String)> {
            if !(r[0].is_finite() && r[1].is_finite()) {
                return err(f, format!("both ends must be finite numbers, not [{}, {}]", r[0], r[1]));
            }
            if r[0] > r[1] {
                return err(f, format!("min {} is above max {}", r[0], r[1]));
            }
            if r[0] < lo || r[1] > hi {
                return err(f, format!("[{}, {}] must lie within [{lo}, {hi}]", r[0], r[1]));
            }
            Ok(())
        };
        let names = |f: &str, given: &[String], allowed: &[&str]| -> Result<(), (String, String)> {
            if given.is_empty() {
                return err(f, format!("give at least one of {}", allowed.join(", ")));
            }
            for (i, g) in given.iter().enumerate() {
                if !allowed.contains(&g.as_str()) {
                    return err(&format!("{f}[{i}]"), format!("`{g}` is not one of {}", allowed.join(", ")));
                }
            }
            Ok(())
        };
        if self.name.trim().is_empty() || self.name.contains(['/', '\\']) {
            return err("name", "a non-empty name without path separators".into());
        }
        if !(1..=10_000_000).contains(&self.sequences) {
            return err("sequences", format!("{} must be in 1 … 10000000", self.sequences));
        }
        if !(1..=1_000_000).contains(&self.frames) {
            return err("frames", format!("{} must be in 1 … 1000000", self.frames));
        }
        if !(0.1..=10_000.0).contains(&self.frame_rate_hz) {
            return err("frame_rate_hz", format!("{} must be a number in [0.1, 10000]", self.frame_rate_hz));
        }
        if let Some(q) = &self.quality {
            q.parse::<QualityPreset>().map_err(|e| ("quality".to_owned(), e.to_string()))?;
        }
        if !GUIDANCES.contains(&self.fusion_guidance.as_str()) {
            return err(
                "fusion_guidance",
                format!("`{}` is not one of {}", self.fusion_guidance, GUIDANCES.join(", ")),
            );
        }
        let presets: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
        names("sensors", &self.sensors, &presets)?;
        if let Some(n) = self.netd_mk {
            range("netd_mk", n, 1.0, 10_000.0)?;
        }
        let [t0, t1] = self.targets_per_sequence;
        if t0 > t1 {
            return err("targets_per_sequence", format!("min {t0} is above max {t1}"));
        }
        if t1 > 64 {
            return err("targets_per_sequence", format!("at most 64 targets, not {t1}"));
        }
        let class_names: Vec<&str> = TargetClass::ALL.iter().map(|c| c.name).collect();
        names("classes", &self.classes, &class_names)?;
        names("trajectories", &self.trajectories, &TRAJECTORIES)?;
        match (self.range_m, self.snr) {
            (None, None) => return err("range_m", "give range_m ([min, max] m), or snr to solve ranges for".into()),
            (Some(r), _) => range("range_m", r, 10.0, 200_000.0)?,
            (None, Some(_)) => {}
        }
        if let Some(r) = self.snr {
            range("snr", r, 0.01, 1e6)?;
        }
        let o = &self.observer;
        range("observer.altitude_m", o.altitude_m, 0.0, 20_000.0)?;
        range("observer.look_elevation_deg", o.look_elevation_deg, -30.0, 89.0)?;
        range("observer.vibration_deg", o.vibration_deg, 0.0, 5.0)?;
        if let Some(r) = o.speed_m_s {
            range("observer.speed_m_s", r, 0.0, 1000.0)?;
        }
        let moving = [
            ("observer.heading_deg", o.heading_deg, -360.0, 360.0),
            ("observer.turn_rate_deg_s", o.turn_rate_deg_s, -30.0, 30.0),
            ("observer.climb_m_s", o.climb_m_s, -100.0, 100.0),
        ];
        for (f, r, lo, hi) in moving {
            if let Some(r) = r {
                if o.speed_m_s.is_none() {
                    return err(f, "the observer stands still without observer.speed_m_s: give it too".into());
                }
                range(f, r, lo, hi)?;
            }
        }
        names("sky.kinds", &self.sky.kinds, &SKY_KINDS)?;
        range("sky.cover", self.sky.cover, 0.0, 1.0)?;
        range("sky.distance_m", self.sky.distance_m, 100.0, 1e6)?;
        let wants_images = self.sky.kinds.iter().any(|k| k == "image");
        match &self.sky.images {
            None if wants_images => {
                return err("sky.kinds", "`image` needs a [sky.images] table (folder and calibration)".into());
            }
            Some(_) if !wants_images => {
                return err("sky.images", "no `image` in sky.kinds: add it, or remove [sky.images]".into());
            }
            Some(images) => {
                if images.folder.trim().is_empty() {
                    return err("sky.images.folder", "give the folder of sky images".into());
                }
                images.calibration.validate().map_err(|e| {
                    (format!("sky.images.calibration.{}", e.name), format!("{} is outside {}", e.value, e.range))
                })?;
                range("sky.images.span", images.span, 0.1, 100.0)?;
                range("sky.images.roll_deg", images.roll_deg, -180.0, 180.0)?;
            }
            None => {}
        }
        names("atmosphere.models", &self.atmosphere.models, &MODELS)?;
        names("atmosphere.aerosols", &self.atmosphere.aerosols, &AEROSOLS)?;
        range("atmosphere.visibility_km", self.atmosphere.visibility_km, 2.0, 200.0)?;
        let s = self.split;
        for (f, v) in [("split.train", s.train), ("split.val", s.val), ("split.test", s.test)] {
            if !(0.0..=1.0).contains(&v) {
                return err(f, format!("{v} must be a fraction in [0, 1]"));
            }
        }
        let sum = s.train + s.val + s.test;
        if (sum - 1.0).abs() > 1e-6 {
            return err("split", format!("train + val + test = {sum}, not 1"));
        }
        Ok(())
    }

    /// The set of every sequence: the spec's fractions of the sequences, rounded (test and val first, train the
    /// rest), dealt by a shuffle drawn from the dataset's seed, so that it depends on the seed and the count alone.
    pub fn splits(&self) -> Vec<Set> {
        let n = self.sequences as usize;
        let n_test = ((self.split.test * n as f64).round() as usize).min(n);
        let n_val = ((self.split.val * n as f64).round() as usize).min(n - n_test);
        let mut order: Vec<usize> = (0..n).collect();
        let mut rng = Draw(SplitMix64::substream(mix64(self.seed ^ 0x7370_6c69_7473), 0));
        for i in (1..n).rev() {
            let j = (rng.bits() % (i as u64 + 1)) as usize;
            order.swap(i, j);
        }
        let mut sets = vec![Set::Train; n];
        for (rank, &k) in order.iter().enumerate() {
            if rank < n_test {
                sets[k] = Set::Test;
            } else if rank < n_test + n_val {
                sets[k] = Set::Val;
            }
        }
        sets
    }

    /// The range `[min, max]` targets are placed at, m (`range_m`, or the SNR solve's default).
    pub fn range_m(&self) -> Range {
        self.range_m.unwrap_or(DEFAULT_SNR_RANGE_M)
    }

    /// The scenario of sequence `k` as TOML text: everything drawn from the sequence's own stream (without an
    /// SNR solve: with `snr`, each target at its drawn range; [`Self::draw`] places them again).
    ///
    /// # Errors
    /// A message when the drawn camera cannot be resolved (a preset the crate no longer knows), or the sky image
    /// drawn is not among `skies`.
    pub fn sequence_scenario(&self, k: u64, skies: &[SkyFile]) -> Result<String, String> {
        self.draw(k, None, skies).map(|d| d.scenario())
    }

    /// Sequence `k`, drawn from its own stream; with `ranges`, target `i` placed at `ranges[i]` m along the same
    /// line of sight instead of its drawn range (every other draw the same).
    ///
    /// # Errors
    /// As [`Self::sequence_scenario`].
    pub fn draw(&self, k: u64, ranges: Option<&[f64]>, skies: &[SkyFile]) -> Result<Drawn, String> {
        let mut rng = Draw(SplitMix64::substream(mix64(self.seed ^ 0x6461_7461_7365_7473), k));
        let duration_s = self.frames as f64 / self.frame_rate_hz;
        // the middle frame's time: every target is in view then, and the observer where it was drawn
        let t_mid = (self.frames / 2) as f64 / self.frame_rate_hz;
        let mut s = String::new();
        let _ = writeln!(s, "# sequence {k} of dataset `{}` (seed {}), drawn by irsim dataset", self.name, self.seed);
        let _ = writeln!(s, "name = \"{}_{k:06}\"\n", self.name);
        let seed = rng.bits() >> 11;
        let _ = writeln!(s, "[run]\nframe_rate_hz = {}\nframes = {}\nseed = {seed}\n", self.frame_rate_hz, self.frames);

        // the camera
        let sensor_name = rng.pick(&self.sensors);
        let preset = Preset::ALL.iter().copied().find(|p| p.name() == sensor_name).ok_or("unknown sensor")?;
        let resolved = SensorSpec { preset: Some(preset), ..Default::default() }
            .resolve(&Quality::default())
            .map_err(|e| format!("sensor `{sensor_name}`: {}", e.message))?;
        let ifov = resolved.intrinsics.pixel_pitch_m / resolved.intrinsics.focal_length_m;
        let half_w = (0.5 * f64::from(resolved.intrinsics.width) * ifov).atan();
        let half_h = (0.5 * f64::from(resolved.intrinsics.height) * ifov).atan();
        let _ = writeln!(s, "[sensor]\npreset = \"{sensor_name}\"");
        if let Some(n) = self.netd_mk {
            let _ = writeln!(s, "detector = {{ netd_mk = {} }}", num(rng.uniform(n)));
        }
        s.push('\n');

        // the observer: where it is and looks at the middle frame, and how it moves
        let alt = rng.uniform(self.observer.altitude_m);
        let yaw = rng.uniform([0.0, 360.0]).to_radians();
        let elevation = rng.uniform(self.observer.look_elevation_deg).to_radians();
        let eye = DVec3::new(0.0, 0.0, alt);
        let dir = |yaw: f64, el: f64| DVec3::new(yaw.sin() * el.cos(), yaw.cos() * el.cos(), el.sin());
        let look = eye + dir(yaw, elevation) * 10_000.0;
        let vibration = rng.uniform(self.observer.vibration_deg);
        let motion = self.observer.speed_m_s.map(|speed| {
            let speed = rng.uniform(speed);
            let heading = yaw + rng.uniform(self.observer.heading_deg.unwrap_or([-180.0, 180.0])).to_radians();
            let turn = rng.uniform(self.observer.turn_rate_deg_s.unwrap_or([0.0, 0.0]));
            let climb = rng.uniform(self.observer.climb_m_s.unwrap_or([0.0, 0.0]));
            (speed, heading, turn, climb)
        });
        // how far the view pans either side of the middle one, rad
        let mut pan = 0.0;
        let (trajectory, pointing) = match motion {
            Some((speed, heading, turn, climb)) if speed >= 0.1 => {
                // looking at a fixed angle from the velocity; at the middle frame, at (yaw, elevation) from `eye`
                let path = climb.atan2(speed);
                let pointing = format!(
                    "{{ mode = \"along_velocity\", yaw_offset_deg = {}, pitch_offset_deg = {} }}",
                    num(wrap_deg((yaw - heading).to_degrees())),
                    num((elevation - path).to_degrees())
                );
                let trajectory = if turn.abs() >= 0.01 {
                    let rate = turn.abs().to_radians();
                    pan = rate * t_mid.max(duration_s - t_mid);
                    let radius = speed / rate;
                    let clockwise = turn > 0.0;
                    // the centre lies on the turn's side of the track; the platform's bearing from it at the
                    // middle is the heading ∓ 90°, and it turns by the rate times the time before that
                    let right = DVec3::new(heading.cos(), -heading.sin(), 0.0);
                    let side = if clockwise { 1.0 } else { -1.0 };
                    let centre = eye + right * side * radius - DVec3::Z * climb * t_mid;
                    let bearing_mid = heading.to_degrees() - side * 90.0;
                    let bearing_0 = bearing_mid - side * turn.abs() * t_mid;
                    format!(
                        "{{ kind = \"coordinated_turn\", center_m = {}, radius_m = {}, speed_m_s = {}, start_bearing_deg = {}, clockwise = {clockwise}, climb_m_s = {} }}",
                        vec3(centre),
                        num(radius),
                        num(speed),
                        num(wrap_deg(bearing_0)),
                        num(climb)
                    )
                } else {
                    let velocity = DVec3::new(heading.sin() * speed, heading.cos() * speed, climb);
                    format!(
                        "{{ kind = \"constant_velocity\", position_m = {}, velocity_m_s = {} }}",
                        vec3(eye - velocity * t_mid),
                        vec3(velocity)
                    )
                };
                (trajectory, pointing)
            }
            _ => (
                format!("{{ kind = \"constant_velocity\", position_m = [0, 0, {}] }}", num(alt)),
                format!("{{ mode = \"look_at\", target_m = {} }}", vec3(look)),
            ),
        };
        let _ = writeln!(
            s,
            "[observer]\ntrajectory = {trajectory}\npointing = {pointing}\nvibration = {{ amplitude_deg = {}, cutoff_hz = 10 }}\n",
            num(vibration)
        );

        // the sky layer, far behind every target, wide enough for the view, its jitter and its pan
        let sky_kind = rng.pick(&self.sky.kinds);
        let cover = rng.uniform(self.sky.cover);
        let range_m = self.range_m();
        let distance = rng.uniform(self.sky.distance_m).max(2.0 * range_m[1]);
        let sky_seed = rng.bits() >> 11;
        if sky_kind != "none" {
            // 30 % beyond the field of view, and twice the jitter's amplitude more (a plane covers up to ±80°)
            let reach = 2.0 * vibration.to_radians();
            let limit = 80f64.to_radians();
            let view_w = 2.0 * distance * (1.3 * half_w + reach + pan).min(limit).tan();
            let view_h = 2.0 * distance * (1.3 * half_h + reach).min(limit).tan();
            let anchor = eye + DVec3::new(yaw.sin(), yaw.cos(), elevation.tan()) * distance;
            if sky_kind == "image" {
                let images = self.sky.images.as_ref().ok_or("`image` without [sky.images]")?;
                if skies.is_empty() {
                    return Err(format!("no sky images in {}", images.folder));
                }
                let image = &skies[(rng.bits() % skies.len() as u64) as usize];
                let span = rng.uniform(images.span);
                let roll = rng.uniform(images.roll_deg).to_radians();
                let (w_px, h_px) = (image.width as f64, image.height as f64);
                let width = span * view_w;
                let height = width * h_px / w_px;
                // the view's middle on a point of the image that keeps the view inside it where it fits
                let free = |view: f64, size: f64| (0.5 * (1.0 - view / size)).max(0.0);
                let (fu, fv) = (free(view_w, width), free(view_h, height));
                let u = w_px * (0.5 + rng.uniform([-fu, fu]));
                let v = h_px * (0.5 + rng.uniform([-fv, fv]));
                // the plane faces the camera; its up turned by the roll about the line of sight
                let toward = DVec3::new(-yaw.sin(), -yaw.cos(), 0.0);
                let right = DVec3::new(yaw.cos(), -yaw.sin(), 0.0);
                let up = DVec3::Z * roll.cos() - right * roll.sin();
                let _ = writeln!(
                    s,
                    "[sky]\nimage = \"../../skies/{}\"\ncalibration = {}\nanchor_m = {}\nanchor_px = [{}, {}]\nwidth_m = {}\nheight_m = {}\nnormal = {}\nup = {}\n",
                    image.name,
                    calibration_toml(&images.calibration),
                    vec3(anchor),
                    num(u),
                    num(v),
                    num(width),
                    num(height),
                    vec3(toward),
                    vec3(up)
                );
            } else {
                let generate = if sky_kind == "cumulus" {
                    format!("{{ kind = \"cumulus\", cover = {}, seed = {sky_seed} }}", num(cover))
                } else {
                    format!("{{ kind = \"clear\", haze = 0.3, seed = {sky_seed} }}")
                };
                let _ = writeln!(
                    s,
                    "[sky]\ngenerate = {generate}\nanchor_m = {}\nwidth_m = {}\nheight_m = {}\nmax_texels = 2048\n",
                    vec3(anchor),
                    num(view_w),
                    num(view_h)
                );
            }
        }

        // the weather
        let model = rng.pick(&self.atmosphere.models);
        let aerosol = rng.pick(&self.atmosphere.aerosols);
        let visibility = rng.uniform(self.atmosphere.visibility_km);
        let _ = write!(s, "[atmosphere]\nmodel = \"{model}\"\naerosol = \"{aerosol}\"\n");
        if aerosol != "none" {
            let [lo, hi] = visibility_range_km(aerosol);
            let _ = writeln!(s, "visibility_km = {}", num(visibility.clamp(lo, hi)));
        }
        if sky_kind == "image" && self.sky.images.as_ref().is_some_and(|i| i.at_plane) {
            s.push_str("sky_path = true\n");
        }
        s.push('\n');

        // the targets, each in view at the sequence's middle
        let scene = std::mem::take(&mut s);
        let [n0, n1] = self.targets_per_sequence;
        let n = n0 + rng.bits() % (n1 - n0 + 1);
        let mut asked_snr = Vec::new();
        let mut drawn_ranges = Vec::new();
        for i in 0..n {
            let class = TargetClass::named(rng.pick(&self.classes)).ok_or("unknown class")?;
            let family = rng.pick(&self.trajectories);
            let mut range = rng.uniform(range_m);
            if let Some(r) = self.snr {
                asked_snr.push(match self.snr_draw {
                    SnrDraw::Uniform => rng.uniform(r),
                    SnrDraw::LogUniform => rng.uniform([r[0].ln(), r[1].ln()]).exp(),
                });
            }
            drawn_ranges.push(range);
            if let Some(&r) = ranges.and_then(|r| r.get(i as usize)) {
                range = r;
            }
            let az = yaw + rng.uniform([-0.7, 0.7]) * half_w;
            // within 70 % of the half view, and where the view reaches them, the class's altitudes
            let view = [elevation - 0.7 * half_h, elevation + 0.7 * half_h];
            let band = if self.class_altitudes { class.altitude_m } else { [f64::NEG_INFINITY, f64::INFINITY] };
            let el = rng.uniform(elevations_at_altitudes(view, alt, range, band));
            let mut mid = eye + dir(az, el) * range;
            // above the ground by at least 20 m
            mid.z = mid.z.max(20.0);
            let speed = rng.uniform(class.speed_m_s);
            let scale = rng.uniform([0.8, 1.2]);
            let heading = rng.uniform([0.0, std::f64::consts::TAU]);
            let climb = rng.uniform([-0.05, 0.05]) * speed;
            let los = DVec3::new(mid.x - eye.x, mid.y - eye.y, 0.0).normalize_or(DVec3::Y);
            let side = if rng.bits() & 1 == 0 { 1.0 } else { -1.0 };
            let horizontal = |h: f64| DVec3::new(h.sin(), h.cos(), 0.0);
            let velocity = match family {
                "crossing" => DVec3::new(los.y, -los.x, 0.0) * speed * side + DVec3::Z * climb,
                "approach" => -los * speed + DVec3::Z * climb,
                _ => horizontal(heading) * speed + DVec3::Z * climb,
            };
            let trajectory = match family {
                "coordinated_turn" => {
                    // a turn at 3–12 °/s through the middle point at the middle frame
                    let rate_deg = rng.uniform([3.0, 12.0]);
                    let rate = rate_deg.to_radians();
                    let radius = (speed / rate).max(1.0);
                    let bearing = rng.uniform([0.0, 360.0]);
                    let b = bearing.to_radians();
                    let centre = DVec3::new(mid.x - radius * b.sin(), mid.y - radius * b.cos(), mid.z);
                    // the bearing grows with time in a clockwise turn
                    let turned = speed / radius * t_mid;
                    let start = bearing - side * turned.to_degrees();
                    format!(
                        "{{ kind = \"coordinated_turn\", center_m = {}, radius_m = {}, speed_m_s = {}, start_bearing_deg = {}, clockwise = {} }}",
                        vec3(centre),
                        num(radius),
                        num(speed),
                        num(wrap_deg(start)),
                        side > 0.0
                    )
                }
                "weave" => {
                    // a sine across the heading, period 4–10 s, amplitude up to a tenth of the distance flown in it
                    let period = rng.uniform([4.0, 10.0]);
                    let amplitude = rng.uniform([0.02, 0.1]) * speed * period;
                    let across = DVec3::new(velocity.y, -velocity.x, 0.0).normalize_or(DVec3::X);
                    let steps = ((duration_s / 0.5).ceil() as usize).max(1);
                    let mut points = Vec::new();
                    for j in 0..=steps + 2 {
                        let t = j as f64 * 0.5 - 0.5;
                        let p = mid
                            + velocity * (t - t_mid)
                            + across * amplitude * (std::f64::consts::TAU * (t - t_mid) / period).sin();
                        points.push(format!("[{}, {}, {}, {}]", num(t), num(p.x), num(p.y), num(p.z)));
                    }
                    format!("{{ kind = \"waypoints\", points = [{}] }}", points.join(", "))
                }
                _ => format!(
                    "{{ kind = \"constant_velocity\", position_m = {}, velocity_m_s = {} }}",
                    vec3(mid - velocity * t_mid),
                    vec3(velocity)
                ),
            };
            let [a, b, c] = class.semi_axes_m.map(|v| v * scale);
            let snr_note = asked_snr.last().map(|v| format!(", SNR {} asked", num(*v))).unwrap_or_default();
            let _ = writeln!(
                s,
                "[[targets]]\nname = \"{}_{i}\"\n# class {}, {family}, {} m away and {} m up at the middle{snr_note}\ntrajectory = {trajectory}\nsemi_axes_m = [{}, {}, {}]\nemissivity = {}\nheating_k = {}\nbrdf = {{ kd = {}, ks = {}, f0 = {}, roughness = {} }}\n",
                class.name,
                class.name,
                num(range),
                num(mid.z.round()),
                num(a),
                num(b),
                num(c),
                num(class.emissivity),
                num(rng.uniform(class.heating_k)),
                num(class.brdf.kd),
                num(class.brdf.ks),
                num(class.brdf.f0),
                num(class.brdf.roughness),
            );
        }
        let mut tail = String::from("[quality]\n");
        if let Some(q) = &self.quality {
            let _ = writeln!(tail, "preset = \"{q}\"");
        }
        let _ = writeln!(tail, "fusion_guidance = \"{}\"", self.fusion_guidance);
        Ok(Drawn { scene, targets: s, tail, asked_snr, drawn_ranges, middle_frame: self.frames / 2 })
    }
}

/// One sequence as drawn: its scenario in three parts, and what an SNR solve needs.
#[derive(Debug, Clone, PartialEq)]
pub struct Drawn {
    /// Everything before the targets.
    pub scene: String,
    /// The `[[targets]]` tables.
    pub targets: String,
    /// What follows the targets.
    pub tail: String,
    /// Each target's asked SNR (empty without `snr`).
    pub asked_snr: Vec<f64>,
    /// Each target's drawn range, m.
    pub drawn_ranges: Vec<f64>,
    /// The frame at which every target is in view and the SNR is asked.
    pub middle_frame: u64,
}

impl Drawn {
    /// The whole scenario.
    pub fn scenario(&self) -> String {
        format!("{}{}{}", self.scene, self.targets, self.tail)
    }

    /// The scenario without its targets: the background its frames are drawn on.
    pub fn background(&self) -> String {
        format!("{}{}", self.scene, self.tail)
    }
}

/// An angle brought into (−180°, 180°].
/// The elevations of `view` (rad) at which a point `range` m from an eye `eye_alt` m up is within `band` m up:
/// the part of `view` whose altitude `eye_alt + range·sin(el)` lies in `band`, or, where none does, the end of
/// `view` nearest the band (the target stays in view).
fn elevations_at_altitudes(view: Range, eye_alt: f64, range: f64, band: Range) -> Range {
    let el = |alt: f64| ((alt - eye_alt) / range).clamp(-1.0, 1.0).asin();
    let (lo, hi) = (view[0].max(el(band[0])), view[1].min(el(band[1])));
    if lo <= hi {
        [lo, hi]
    } else if lo > view[1] {
        // the band lies above the view
        [view[1], view[1]]
    } else {
        [view[0], view[0]]
    }
}

fn wrap_deg(a: f64) -> f64 {
    let r = a.rem_euclid(360.0);
    if r > 180.0 { r - 360.0 } else { r }
}

/// A sky calibration as a TOML inline table.
fn calibration_toml(c: &SkyCalibration) -> String {
    match *c {
        SkyCalibration::Kelvin { scale_k, offset_k } => {
            format!("{{ mode = \"kelvin\", scale_k = {scale_k:?}, offset_k = {offset_k:?} }}")
        }
        SkyCalibration::Temperature { value_range, temp_range_k } => format!(
            "{{ mode = \"temperature\", value_range = [{:?}, {:?}], temp_range_k = [{:?}, {:?}] }}",
            value_range[0], value_range[1], temp_range_k[0], temp_range_k[1]
        ),
        SkyCalibration::Radiance { gain, offset } => {
            format!("{{ mode = \"radiance\", gain = {gain:?}, offset = {offset:?} }}")
        }
    }
}

/// A number as TOML writes it, rounded to 1e-6 (the scenario is the record; a sequence is its file).
fn num(v: f64) -> String {
    let r = (v * 1e6).round() / 1e6;
    let r = if r == 0.0 { 0.0 } else { r };
    format!("{r}")
}

fn vec3(v: DVec3) -> String {
    format!("[{}, {}, {}]", num(v.x), num(v.y), num(v.z))
}

/// Draws from one sequence's stream.
struct Draw(SplitMix64);

impl Draw {
    fn bits(&mut self) -> u64 {
        self.0.next_bits()
    }

    /// Uniform on `[r[0], r[1]]`.
    fn uniform(&mut self, r: Range) -> f64 {
        let u = (self.bits() >> 11) as f64 / (1u64 << 53) as f64;
        r[0] + (r[1] - r[0]) * u
    }

    fn pick<'a>(&mut self, from: &'a [String]) -> &'a str {
        &from[(self.bits() % from.len() as u64) as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(sequences: u64, split: [f64; 3]) -> DatasetSpec {
        let text = format!(
            "name = \"t\"\nseed = 5\nsequences = {sequences}\nframes = 2\nsensors = [\"paper_lwir_256\"]\ntargets_per_sequence = [1, 1]\nclasses = [\"bird\"]\ntrajectories = [\"straight\"]\nrange_m = [300, 900]\n[split]\ntrain = {}\nval = {}\ntest = {}\n",
            split[0], split[1], split[2]
        );
        DatasetSpec::from_str(&text, "t.toml").unwrap()
    }

    #[test]
    fn the_split_deals_whole_sequences_in_the_asked_proportions() {
        for (n, split) in [(1, [0.8, 0.1, 0.1]), (8, [0.8, 0.1, 0.1]), (97, [0.7, 0.2, 0.1]), (10, [0.0, 0.5, 0.5])] {
            let s = spec(n, split);
            let sets = s.splits();
            // one set per sequence, by construction of the vector; the counts are the rounded fractions
            assert_eq!(sets.len() as u64, n);
            let count = |x: Set| sets.iter().filter(|&&v| v == x).count();
            let n_test = (split[2] * n as f64).round() as usize;
            assert_eq!(count(Set::Test), n_test.min(n as usize));
            assert_eq!(count(Set::Val), ((split[1] * n as f64).round() as usize).min(n as usize - n_test));
            assert_eq!(count(Set::Train) + count(Set::Val) + count(Set::Test), n as usize);
            // the same for the same seed and count, whoever computes it
            assert_eq!(sets, s.splits());
        }
        // another seed deals differently
        let a = spec(50, [0.6, 0.2, 0.2]);
        let mut b = a.clone();
        b.seed = 6;
        assert_ne!(a.splits(), b.splits());
    }

    #[test]
    fn split_fractions_must_be_fractions_summing_to_one() {
        for (split, field) in
            [([0.8, 0.3, 0.1], "split"), ([1.2, -0.1, -0.1], "split.train"), ([0.5, f64::NAN, 0.5], "split.val")]
        {
            let text = format!(
                "name = \"t\"\nseed = 5\nsequences = 3\nframes = 2\nsensors = [\"paper_lwir_256\"]\ntargets_per_sequence = [1, 1]\nclasses = [\"bird\"]\ntrajectories = [\"straight\"]\nrange_m = [300, 900]\n[split]\ntrain = {}\nval = {}\ntest = {}\n",
                split[0], split[1], split[2]
            )
            .replace("NaN", "nan");
            let e = DatasetSpec::from_str(&text, "t.toml").unwrap_err();
            assert_eq!(e.field, field, "{e}");
            assert!(e.line >= 10, "{e}");
        }
    }

    #[test]
    fn targets_fly_within_their_class_s_altitudes_where_the_view_reaches_them() {
        // the elevations of the view at which the band is reached
        let view = [-0.05, 0.05];
        let [lo, hi] = elevations_at_altitudes(view, 100.0, 1000.0, [90.0, 120.0]);
        assert!(lo >= view[0] && hi <= view[1] && lo < hi);
        for el in [lo, hi, 0.5 * (lo + hi)] {
            let z = 100.0 + 1000.0 * el.sin();
            assert!((90.0 - 1e-9..=120.0 + 1e-9).contains(&z), "{z}");
        }
        // a band above or below the view: its nearest edge
        assert_eq!(elevations_at_altitudes(view, 100.0, 1000.0, [500.0, 900.0]), [0.05, 0.05]);
        assert_eq!(elevations_at_altitudes(view, 100.0, 1000.0, [0.0, 10.0]), [-0.05, -0.05]);
        // drawn sequences from low cameras with a wide view (±7° up and down): every multirotor between 5 and 500 m
        // at the middle frame, and the same spec without the bands puts some above
        let text = "name = \"t\"\nseed = 5\nsequences = 40\nframes = 2\nsensors = [\"uncooled_lwir_microbolometer\"]\ntargets_per_sequence = [3, 3]\nclasses = [\"small_multirotor\"]\ntrajectories = [\"straight\", \"coordinated_turn\", \"weave\"]\nrange_m = [1000, 6000]\n[observer]\naltitude_m = [100, 300]\nlook_elevation_deg = [0, 2]\n";
        let heights = |text: &str| -> Vec<f64> {
            let s = DatasetSpec::from_str(text, "t.toml").unwrap();
            (0..s.sequences)
                .flat_map(|k| {
                    let drawn = s.draw(k, None, &[]).unwrap();
                    drawn
                        .targets
                        .lines()
                        .filter_map(|l| l.split(" m away and ").nth(1)?.split(" m up").next()?.parse().ok())
                        .collect::<Vec<f64>>()
                })
                .collect()
        };
        let banded = heights(text);
        assert_eq!(banded.len(), 120);
        assert!(banded.iter().all(|z| (5.0..=500.0).contains(z)), "{banded:?}");
        let free = heights(&text.replace("range_m", "class_altitudes = false\nrange_m"));
        assert!(free.iter().any(|&z| z > 500.0), "{free:?}");
    }

    #[test]
    fn the_background_scenario_is_the_sequence_without_its_targets() {
        let s = spec(3, [0.8, 0.1, 0.1]);
        let drawn = s.draw(2, None, &[]).unwrap();
        let (full, bg) = (drawn.scenario(), drawn.background());
        assert!(full.contains("[[targets]]") && !bg.contains("[[targets]]"));
        assert!(full.starts_with(&bg[..bg.find("[quality]").unwrap()]));
        assert!(bg.contains("fusion_guidance = \"additive\""));
    }
}
