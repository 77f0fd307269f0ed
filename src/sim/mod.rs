//! The simulation as a Bevy ECS: entities, components, system sets, plugins.
//!
//! Aircraft, the observer, the sky plane and the sensor are entities whose components hold kinematics,
//! material, geometry, sensor data and per-frame results. One fixed step is one sensor frame; its systems run
//! in this order, declared once in [`IrSimPlugins`]:
//!
//! Motion → Vibration → Radiometry → Projection → RenderToTexture → Targets → Fusion → Noise → Output.
//!
//! Systems are thin: they gather components, call one function of [`crate::physics`] or [`crate::imaging`],
//! and write the result back. [`build_app`] turns a checked scenario into a headless [`App`]; each
//! `app.update()` after the first computes one frame (the first runs Startup only).

mod camera;
mod fusion;
mod motion;
mod noise;
mod output;
mod projection;
mod radiometry;
mod render;
mod targets;

use std::sync::Arc;

use bevy::app::{App, Plugin, PluginGroup, PluginGroupBuilder};
use bevy::ecs::prelude::*;
use bevy::prelude::{FixedUpdate, MinimalPlugins};
use bevy::time::{Fixed, Time, TimeUpdateStrategy};
use glam::DVec3;

use crate::imaging::background::{BackgroundRenderer, BackgroundStats, SkyBlur, SkyBlurPlan, plan_sky_blur};
use crate::imaging::camera::{Camera, Jitter, YawPitchRoll};
use crate::imaging::frame::Frame;
use crate::imaging::fusion::PoissonFusion;
use crate::imaging::psf::{Psf, PsfOptics};
use crate::imaging::sky_field::{LayerBake, RadianceLut, bake_layer, calibrate};
use crate::imaging::sky_gen::{SkyGenSpec, generate};
use crate::imaging::sky_plane::{MissFill, Sampling, SkyImage, SkyPlane};
use crate::imaging::target_blob::{GeneralizedGaussian, ImageEllipse, PixelRect};
use crate::imaging::vibration::Vibration;
use crate::physics::atmosphere::{MAX_ALTITUDE_M, MIN_ALTITUDE_M, ambient_temperature_k};
use crate::physics::brdf::CookTorrance;
use crate::physics::noise::Readout;
use crate::physics::nonideal::{FocalPlane, NonIdeal};
use crate::physics::planck::Measure;
use crate::physics::reflection::{ReflectionGeometry, SphereQuadrature, Sun};
use crate::physics::signal::Apparent;
use crate::physics::skin::StagnationModel;
use crate::physics::sky::{Dome, DomeInputs};
use crate::physics::transmittance::Transmittance;
use crate::scenario::sensor::{PsfToml, ResolvedSensor};
use crate::scenario::trajectory::Trajectory;
use crate::scenario::{BlobSpec, CheckedScenario, FusionSpec, Pointing};

pub use output::{FrameImage, FrameLabels, MirrorFrame, TargetLabel};

/// Motion of targets and observer.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct MotionSystems;
/// Camera pointing and vibration.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct VibrationSystems;
/// Target apparent radiance.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct RadiometrySystems;
/// Ellipsoid → image ellipse.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct ProjectionSystems;
/// Sky plane ray cast into the sensor frame, the dome for the misses, the optics blur.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct RenderToTextureSystems;
/// Target patches.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct TargetsSystems;
/// Poisson fusion of the patches.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct FusionSystems;
/// The detector: electrons or volts, noise, non-idealities, ADC.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct NoiseSystems;
/// Ground truth and frame hand-off.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct OutputSystems;

// ---------------------------------------------------------------- components

/// An aircraft: its index in the scenario (the label id is `index + 1`) and name.
#[derive(Component, Debug, Clone)]
pub struct Aircraft {
    /// Label id, 1-based.
    pub id: u32,
    /// Name from the scenario.
    pub name: String,
}

/// The camera's platform.
#[derive(Component, Debug, Clone, Copy, Default)]
pub struct Observer;

/// A trajectory, evaluated analytically each frame.
#[derive(Component, Debug, Clone)]
pub struct FlightPath(pub Trajectory);

/// Position and velocity at the current frame's time.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct Kinematics {
    /// Position, m (world: x east, y north, z up).
    pub position_m: DVec3,
    /// Velocity, m/s.
    pub velocity_m_s: DVec3,
}

/// The target's ellipsoid: semi-axes along its long axis, across, up, and a fixed attitude if one is given.
#[derive(Component, Debug, Clone, Copy)]
pub struct Body {
    /// Semi-axes, m.
    pub semi_axes_m: DVec3,
    /// Fixed attitude; `None` points the long axis along the velocity.
    pub attitude: Option<YawPitchRoll>,
}

impl Body {
    /// Body-to-world rotation for velocity `velocity_m_s` (x forward, y left, z up).
    pub fn body_to_world(&self, velocity_m_s: DVec3) -> glam::DMat3 {
        match self.attitude {
            Some(a) => {
                // camera axes are (right, down, forward); the body's are (forward, left, up)
                let c = a.camera_to_world();
                glam::DMat3::from_cols(c.z_axis, -c.x_axis, -c.y_axis)
            }
            None => crate::imaging::target_blob::attitude_from_velocity(velocity_m_s),
        }
    }
}

/// Skin material and flight condition.
#[derive(Component, Debug, Clone, Copy)]
pub struct Skin {
    /// Emissivity.
    pub emissivity: f64,
    /// Reflectance.
    pub brdf: CookTorrance,
    /// Facet or ellipsoid-averaged reflection.
    pub reflection: ReflectionGeometry,
    /// Mach number if fixed; otherwise from speed and the local speed of sound.
    pub mach: Option<f64>,
    /// Skin temperature above the stagnation temperature from internal heat, K.
    pub heating_k: f64,
}

/// Radiometric result of a target, recomputed only when its inputs change.
#[derive(Component, Debug, Clone, Default)]
pub struct Signature {
    /// The chain's values, if they could be computed (the altitude may leave the model's range).
    pub signal: Option<Apparent>,
    /// Mach number used.
    pub mach: f64,
    /// Why `signal` is missing.
    pub error: Option<String>,
    /// Inputs of the last computation.
    key: Option<[f64; 10]>,
}

/// Where a target falls in the image this frame.
#[derive(Component, Debug, Clone, Default)]
pub struct Footprint {
    /// The exact image ellipse of its outline, if entirely in front of the camera.
    pub ellipse: Option<ImageEllipse>,
    /// The paper model's blob (unit peak until the targets stage scales it).
    pub blob: Option<GeneralizedGaussian>,
    /// Its region of interest, clipped to the frame; `None` if off-frame.
    pub roi: Option<PixelRect>,
    /// Range from the camera, m.
    pub range_m: f64,
    /// Radiance added at the brightest pixel (signed), in the detector's measure; set by the targets stage.
    pub peak_radiance: f64,
    /// Background radiance at the target's centre (noise-free, blurred), in the detector's measure.
    pub background_radiance: f64,
    /// Index of its patch in [`TargetPatches`] this frame.
    pub patch: Option<usize>,
}

/// Where the camera points.
#[derive(Component, Debug, Clone)]
pub struct Aim(pub Pointing);

/// The observer's vibration.
#[derive(Component, Debug, Clone)]
pub struct Shake(pub Vibration);

/// The camera this frame: before and after vibration.
#[derive(Component, Debug, Clone, Copy)]
pub struct CameraPose {
    /// Without vibration.
    pub steady: Camera,
    /// With this frame's jitter.
    pub current: Camera,
    /// The jitter.
    pub jitter: Jitter,
}

/// The sky: the clear-sky dome and, optionally, a radiance image placed as a plane.
#[derive(Component, Debug, Clone)]
pub struct Sky {
    /// The placed radiance image.
    pub plane: Option<Arc<SkyPlane>>,
    /// Sampling.
    pub sampling: Sampling,
    /// Fill for rays that miss the plane.
    pub miss: MissFill,
    /// The clear sky and ground.
    pub dome: Arc<Dome>,
}

/// The sensor: radiometry, optics blur, readout, non-idealities.
#[derive(Component, Debug, Clone)]
pub struct Sensor {
    /// Band, optics, detector, ADC.
    pub resolved: ResolvedSensor,
    /// The readout (noise and ADC) of a frame, before drift.
    pub readout: Readout,
    /// Highest DN.
    pub max_level: f32,
    /// DN per unit radiance on axis.
    pub dn_per_radiance: f64,
    /// The optics PSF, if on.
    pub psf: Option<Arc<Psf>>,
    /// Blur the frame (false when the blur would change no pixel by more than the set DN).
    pub blur_frame: bool,
    /// How the blur reaches the sky image this run (`prefilter` or `frame`, `auto` resolved).
    pub sky_blur: SkyBlur,
    /// The plan that resolved `auto`, if one was made.
    pub sky_blur_plan: Option<SkyBlurPlan>,
    /// The non-idealities of this sequence.
    pub nonideal: Option<Arc<NonIdeal>>,
}

impl Sensor {
    /// The detector's measure.
    pub fn measure(&self) -> Measure {
        self.resolved.model.measure()
    }

    /// Temporal noise in DN of a pixel whose background radiance is `radiance`.
    pub fn noise_dn(&self, radiance: f64) -> f64 {
        let r = &self.readout;
        let signal = f64::from(r.signal_per_radiance) * radiance + f64::from(r.dark_signal);
        r.noise_dn(signal)
    }
}

/// The sensor's frame and its cached sky background.
#[derive(Component, Debug)]
pub struct SensorFrame {
    /// The frame being built: radiance until the Noise set, then DN.
    pub frame: Frame,
    /// The frame before quantization, DN (kept only when asked for).
    pub float_frame: Option<Frame>,
    /// The sky as last rendered (radiance, blurred), and the camera it was rendered for.
    pub background: Frame,
    background_camera: Option<Camera>,
    /// What the last render of the background did.
    pub background_stats: BackgroundStats,
    renderer: BackgroundRenderer,
    columns: Vec<f32>,
}

// ---------------------------------------------------------------- resources

/// Frame counter and time step.
#[derive(Resource, Debug, Clone, Copy)]
pub struct SimClock {
    /// Index of the frame the current step computes.
    pub frame: u64,
    /// Time of frame 0, s.
    pub start_s: f64,
    /// Seconds per frame.
    pub dt_s: f64,
}

impl SimClock {
    /// Time of the current frame, s (analytic: start + frame · dt).
    pub fn t_s(&self) -> f64 {
        self.start_s + self.frame as f64 * self.dt_s
    }
}

/// Run-wide settings.
#[derive(Resource, Debug, Clone, Copy)]
pub struct SimSettings {
    /// Seed of every random stream.
    pub seed: u64,
    /// Add sensor noise.
    pub noise: bool,
    /// Apply camera vibration.
    pub vibration: bool,
    /// Keep the unquantized frame.
    pub keep_float: bool,
    /// Produce per-frame target masks.
    pub masks: bool,
    /// Fusion mode and solver.
    pub fusion: FusionSpec,
    /// How targets are drawn.
    pub blob: BlobSpec,
    /// SNR from which a target is `detectable`.
    pub detectable_snr: f64,
}

/// The scene's physics.
#[derive(Resource, Debug, Clone)]
pub struct SceneParams {
    /// Sea-level temperature, K.
    pub t0_k: f64,
    /// Stagnation constants.
    pub stagnation: StagnationModel,
    /// The sun.
    pub sun: Sun,
    /// Transmittance.
    pub atmosphere: Transmittance,
    /// Quadrature for ellipsoid-averaged reflection.
    pub quadrature: SphereQuadrature,
}

impl SceneParams {
    /// Air temperature at `altitude_m` (clamped to the model's range), K.
    pub fn air_temp_k(&self, altitude_m: f64) -> f64 {
        ambient_temperature_k(altitude_m.clamp(MIN_ALTITUDE_M, MAX_ALTITUDE_M), self.t0_k).unwrap_or(self.t0_k)
    }
}

/// Reusable buffers of target patches for the fusion stage.
#[derive(Resource, Debug, Default)]
pub struct TargetPatches {
    /// `(rect, values)` per visible target; the vectors are reused.
    pub patches: Vec<(PixelRect, Vec<f32>)>,
    /// How many entries of `patches` are in use this frame.
    pub used: usize,
}

/// The fusion engine (planned transforms, buffers).
#[derive(Resource, Debug, Default)]
pub struct Fusion(pub PoissonFusion);

/// What the last completed step produced.
#[derive(Resource, Debug, Default, Clone)]
pub struct FrameOutput {
    /// Ground truth.
    pub labels: FrameLabels,
    /// Per-pixel target id (0 = sky), when masks are on.
    pub mask: Option<Vec<u8>>,
    /// True once a frame has been completed since the last take.
    pub ready: bool,
}

/// Reusable target-rendering state: the tracking loop's pointing noise stream is keyed per frame, so it needs
/// no state; this holds the SCR window buffer.
#[derive(Resource, Debug, Default)]
pub struct LabelScratch(pub Vec<f32>);

// ---------------------------------------------------------------- plugins

/// Declares the pipeline order and the shared resources.
pub struct PipelinePlugin;

impl Plugin for PipelinePlugin {
    fn build(&self, app: &mut App) {
        app.configure_sets(
            FixedUpdate,
            (
                MotionSystems,
                VibrationSystems,
                RadiometrySystems,
                ProjectionSystems,
                RenderToTextureSystems,
                TargetsSystems,
                FusionSystems,
                NoiseSystems,
                OutputSystems,
            )
                .chain(),
        );
        app.init_resource::<TargetPatches>()
            .init_resource::<Fusion>()
            .init_resource::<FrameOutput>()
            .init_resource::<LabelScratch>();
    }
}

/// All of irsim's simulation plugins, in pipeline order.
pub struct IrSimPlugins;

impl PluginGroup for IrSimPlugins {
    fn build(self) -> PluginGroupBuilder {
        PluginGroupBuilder::start::<Self>()
            .add(PipelinePlugin)
            .add(motion::MotionPlugin)
            .add(camera::CameraPlugin)
            .add(radiometry::RadiometryPlugin)
            .add(projection::ProjectionPlugin)
            .add(render::RenderPlugin)
            .add(targets::TargetsPlugin)
            .add(fusion::FusionPlugin)
            .add(noise::NoisePlugin)
            .add(output::OutputPlugin)
    }
}

/// Wall-clock time spent in each stage, accumulated over the run (present only when timing is asked for).
#[derive(Resource, Debug, Clone, Default)]
pub struct StageTimings {
    /// Seconds per stage, in pipeline order.
    pub seconds: [f64; 9],
    /// Steps timed.
    pub steps: u64,
    last: Option<std::time::Instant>,
}

impl StageTimings {
    /// Stage names, in pipeline order.
    pub const NAMES: [&'static str; 9] =
        ["motion", "vibration", "radiometry", "projection", "render", "targets", "fusion", "noise", "output"];

    /// Mean milliseconds per frame for each stage, by name.
    pub fn mean_ms(&self) -> Vec<(&'static str, f64)> {
        let n = self.steps.max(1) as f64;
        Self::NAMES.iter().zip(self.seconds).map(|(name, s)| (*name, 1e3 * s / n)).collect()
    }
}

/// Records the time since the previous stamp into stage `N − 1` (stamp 0 starts the step).
fn stamp<const N: usize>(mut timings: ResMut<StageTimings>) {
    let now = std::time::Instant::now();
    if N > 0
        && let Some(last) = timings.last
    {
        timings.seconds[N - 1] += (now - last).as_secs_f64();
    }
    if N == 9 {
        timings.steps += 1;
    }
    timings.last = Some(now);
}

/// Adds [`StageTimings`] and the systems that fill it, between the stages.
pub struct TimingPlugin;

impl Plugin for TimingPlugin {
    fn build(&self, app: &mut App) {
        let on = resource_exists::<StageTimings>;
        app.init_resource::<StageTimings>().add_systems(
            FixedUpdate,
            (
                stamp::<0>.before(MotionSystems).run_if(on),
                stamp::<1>.after(MotionSystems).before(VibrationSystems).run_if(on),
                stamp::<2>.after(VibrationSystems).before(RadiometrySystems).run_if(on),
                stamp::<3>.after(RadiometrySystems).before(ProjectionSystems).run_if(on),
                stamp::<4>.after(ProjectionSystems).before(RenderToTextureSystems).run_if(on),
                stamp::<5>.after(RenderToTextureSystems).before(TargetsSystems).run_if(on),
                stamp::<6>.after(TargetsSystems).before(FusionSystems).run_if(on),
                stamp::<7>.after(FusionSystems).before(NoiseSystems).run_if(on),
                stamp::<8>.after(NoiseSystems).before(OutputSystems).run_if(on),
                stamp::<9>.after(OutputSystems).run_if(on),
            ),
        );
    }
}

/// Switches for a run.
#[derive(Debug, Clone, Copy)]
pub struct RunOptions {
    /// Seed override.
    pub seed: Option<u64>,
    /// Add sensor noise (if the scenario enables it).
    pub noise: bool,
    /// Apply vibration.
    pub vibration: bool,
    /// Keep the unquantized frame.
    pub keep_float: bool,
    /// Produce masks.
    pub masks: bool,
    /// Time each stage ([`StageTimings`]).
    pub timings: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self { seed: None, noise: true, vibration: true, keep_float: false, masks: false, timings: false }
    }
}

/// An error building the simulation from a checked scenario (the sky image cannot be read, calibrated or
/// placed; the optics PSF cannot be built).
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct SetupError {
    /// The scenario field at fault, as a dotted path (`sky.calibration`).
    pub field: String,
    /// What is wrong.
    pub message: String,
}

fn setup(field: &str) -> impl Fn(String) -> SetupError + '_ {
    move |message| SetupError { field: field.to_owned(), message }
}

/// Bevy's fixed timestep in every app: one step per `update()` whatever the sensor's frame rate (the
/// simulation's own time is [`SimClock`]).
pub const BEVY_STEP: std::time::Duration = std::time::Duration::from_millis(10);

/// A headless app for `scenario`: `MinimalPlugins`, [`IrSimPlugins`], one fixed step per `update()`.
///
/// # Errors
/// [`SetupError`] if the sky image cannot be loaded or placed.
pub fn build_app(scenario: &CheckedScenario, options: RunOptions) -> Result<App, SetupError> {
    let spec = &scenario.spec;
    let seed = options.seed.unwrap_or(spec.run.seed);
    let dt = 1.0 / spec.run.frame_rate_hz;
    let mut app = App::new();
    app.add_plugins(MinimalPlugins);
    // Simulated time is `SimClock`'s (t0 + k/rate, exact at any rate); Bevy's clock only has to run one fixed
    // step per update, which a nominal step below its 250 ms maximum delta does at every frame rate.
    app.insert_resource(Time::<Fixed>::from_duration(BEVY_STEP));
    app.insert_resource(TimeUpdateStrategy::FixedTimesteps(1));
    app.add_plugins(IrSimPlugins);
    if options.timings {
        app.add_plugins(TimingPlugin);
    }
    let sensor_spec = scenario.sensor;
    app.insert_resource(SimClock { frame: 0, start_s: spec.run.start_time_s, dt_s: dt });
    app.insert_resource(SimSettings {
        seed,
        noise: options.noise && sensor_spec.noise.enabled,
        vibration: options.vibration,
        keep_float: options.keep_float,
        masks: options.masks,
        fusion: spec.fusion,
        blob: sensor_spec.blob,
        detectable_snr: spec.labels.detectable_snr,
    });
    let scene = SceneParams {
        t0_k: spec.atmosphere.t0_k,
        stagnation: spec.atmosphere.stagnation,
        sun: spec.sun,
        atmosphere: spec.atmosphere.transmittance,
        quadrature: SphereQuadrature::default(),
    };

    let intrinsics = sensor_spec.intrinsics;
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let (p0, v0) = scenario.observer_trajectory.state(spec.run.start_time_s);
    let sky = build_sky(scenario, &scene, p0, seed)?;
    let mut sensor = build_sensor(&sensor_spec, &sky, seed)?;
    if let (Some(plane), Some(psf), Some(cfg), true) = (&sky.plane, &sensor.psf, sensor_spec.psf, sensor.blur_frame)
        && cfg.sky_blur == SkyBlur::Auto
    {
        let plan = plan_sky_blur(plane, psf, cfg.prefilter_tolerance, (w, h), planned_views(scenario));
        sensor.sky_blur = plan.choice;
        sensor.sky_blur_plan = Some(plan);
    }
    app.insert_resource(scene);
    let world = app.world_mut();
    world.spawn((
        sensor,
        SensorFrame {
            frame: Frame::new(w, h),
            float_frame: None,
            background: Frame::new(w, h),
            background_camera: None,
            background_stats: BackgroundStats::default(),
            renderer: BackgroundRenderer::new(),
            columns: Vec::new(),
        },
    ));
    let vibration = if options.vibration { spec.observer.vibration.plan(seed) } else { Vibration::still() };
    let placeholder = Camera::new(intrinsics, p0, Default::default());
    world.spawn((
        Observer,
        FlightPath(scenario.observer_trajectory.clone()),
        Kinematics { position_m: p0, velocity_m_s: v0 },
        Aim(spec.observer.pointing.clone()),
        Shake(vibration),
        CameraPose { steady: placeholder, current: placeholder, jitter: Jitter::default() },
    ));
    world.spawn(sky);
    for (i, (t, tr)) in spec.targets.iter().zip(&scenario.target_trajectories).enumerate() {
        let (p, v) = tr.state(spec.run.start_time_s);
        world.spawn((
            Aircraft { id: i as u32 + 1, name: t.name.clone() },
            FlightPath(tr.clone()),
            Kinematics { position_m: p, velocity_m_s: v },
            Body { semi_axes_m: t.semi_axes_m, attitude: t.attitude },
            Skin {
                emissivity: t.emissivity,
                brdf: t.brdf,
                reflection: t.reflection,
                mach: t.mach,
                heating_k: t.heating_k,
            },
            Signature::default(),
            Footprint::default(),
        ));
    }
    // The first update runs Startup and no fixed step.
    app.update();
    Ok(app)
}

/// The dome for the observer's start, and the sky image (calibrated) or generated layer (baked) on its plane.
fn build_sky(scenario: &CheckedScenario, scene: &SceneParams, eye: DVec3, seed: u64) -> Result<Sky, SetupError> {
    let sky = &scenario.spec.sky;
    let model = &scenario.sensor.model;
    let (band, measure) = (model.band, model.measure());
    let dome = Dome::new(&DomeInputs {
        spec: sky.dome,
        band,
        measure,
        observer_altitude_m: eye.z,
        t0_k: scene.t0_k,
        atmosphere: &scene.atmosphere,
    })
    .map_err(|e| SetupError { field: format!("sky.dome.{}", e.name), message: e.to_string() })?;
    let dome = Arc::new(dome);
    let lut = RadianceLut::new(band, measure);
    let placement = sky.placement();
    let plane = match (&sky.generate, &scenario.sky_image, placement) {
        (_, Some(path), Some(placement)) => {
            let raw = SkyImage::load(path).map_err(|e| setup("sky.image")(e.to_string()))?;
            let calibration = sky.calibration.ok_or_else(|| setup("sky.calibration")("is required".into()))?;
            let image = calibrate(&raw, &calibration, &lut, &path.display().to_string())
                .map_err(|e| setup("sky.calibration")(e.to_string()))?;
            Some(SkyPlane::new(image, &placement, eye).map_err(|e| setup("sky")(e.to_string()))?)
        }
        (Some(gen_spec), None, Some(placement)) => {
            let (tw, th) = layer_size(&scenario.sensor, &placement, eye, sky.max_texels);
            let gen_spec = SkyGenSpec { seed: gen_spec.seed ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15), ..*gen_spec };
            let layer = generate(&gen_spec, tw, th);
            let blank = SkyImage::from_f32(tw, th, vec![0.0; tw * th]).map_err(|e| setup("sky")(e.to_string()))?;
            let geometry = SkyPlane::new(blank, &placement, eye).map_err(|e| setup("sky")(e.to_string()))?;
            let air = |z: f64| scene.air_temp_k(z);
            let image = bake_layer(&LayerBake {
                layer: &layer,
                plane: &geometry,
                eye_m: eye,
                dome: &dome,
                air_temp_k: &air,
                atmosphere: &scene.atmosphere,
                lut: &lut,
                cloud_offset_k: sky.cloud_offset_k,
                cloud_base_m: sky.cloud_base_m,
            })
            .map_err(|e| setup("sky.generate")(e.to_string()))?;
            Some(SkyPlane::new(image, &placement, eye).map_err(|e| setup("sky")(e.to_string()))?)
        }
        _ => None,
    };
    Ok(Sky { plane: plane.map(Arc::new), sampling: sky.sampling, miss: sky.miss, dome })
}

/// The steady cameras (no vibration, no pointing noise) of the run's frames, for planning: every frame up to
/// 4096 of them, an even sample of 4096 beyond.
fn planned_views(scenario: &CheckedScenario) -> impl Iterator<Item = Camera> + '_ {
    let spec = &scenario.spec;
    let frames = spec.run.frames.max(1);
    let stride = frames.div_ceil(4096).max(1);
    let intrinsics = scenario.sensor.intrinsics;
    (0..frames).step_by(stride as usize).map(move |k| {
        let t = spec.run.start_time_s + k as f64 / spec.run.frame_rate_hz;
        let (eye, velocity) = scenario.observer_trajectory.state(t);
        let tracked = |name: &str, lag_s: f64| {
            let i = spec.targets.iter().position(|target| target.name == name)?;
            Some(scenario.target_trajectories[i].state(t - lag_s).0)
        };
        Camera::aimed(intrinsics, eye, velocity, camera::resolve_aim(&spec.observer.pointing, tracked))
    })
}

/// Texels of a generated layer: at least one per sensor pixel at the plane's distance from the observer's
/// start (its nearest point), up to `max_texels` per side.
fn layer_size(
    sensor: &ResolvedSensor,
    placement: &crate::imaging::sky_plane::SkyPlacement,
    eye: DVec3,
    max_texels: usize,
) -> (usize, usize) {
    let ifov = sensor.intrinsics.pixel_pitch_m / sensor.intrinsics.focal_length_m;
    let normal = placement.normal.map_or_else(
        || {
            let d = eye - placement.anchor_m;
            DVec3::new(d.x, d.y, 0.0).normalize_or(DVec3::Y)
        },
        |n| n.normalize_or(DVec3::Y),
    );
    let distance = (eye - placement.anchor_m).dot(normal).abs().max(1.0);
    let texel_m = ifov * distance;
    let side = |extent_m: f64| ((extent_m / texel_m).ceil() as usize).clamp(16, max_texels);
    (side(placement.width_m), side(placement.height_m))
}

/// The sensor component: readout, PSF (and whether the frame needs it), non-idealities.
fn build_sensor(resolved: &ResolvedSensor, sky: &Sky, seed: u64) -> Result<Sensor, SetupError> {
    let model = &resolved.model;
    let k = model.signal_per_radiance();
    let readout = model.readout(resolved.noise.poisson_normal_threshold);
    let dn_per_radiance = k / model.adc.gain;
    let psf = match resolved.psf {
        Some(p) => Some(Arc::new(
            Psf::new(
                &p.spec(),
                &PsfOptics {
                    f_number: model.optics.f_number(),
                    pixel_pitch_m: model.detector.pixel_pitch_m,
                    fill_factor: model.detector.fill_factor,
                    band: model.band,
                    measure: model.measure(),
                    reference_temp_k: 300.0,
                },
            )
            .map_err(|e| SetupError { field: format!("sensor.psf.{}", e.name), message: e.to_string() })?,
        )),
        None => None,
    };
    let blur_frame = match (&psf, resolved.psf) {
        (Some(psf), Some(cfg)) => frame_needs_blur(psf, &cfg, sky, resolved, dn_per_radiance),
        _ => false,
    };
    let report = model.report(300.0);
    let nonideal = if resolved.nonideal.is_ideal() {
        None
    } else {
        let plane = FocalPlane {
            width: resolved.intrinsics.width as usize,
            height: resolved.intrinsics.height as usize,
            focal_px: resolved.intrinsics.focal_px(),
        };
        Some(Arc::new(NonIdeal::new(&resolved.nonideal, plane, report.noise_dn, seed)))
    };
    Ok(Sensor {
        resolved: *resolved,
        readout,
        max_level: model.adc.max_level() as f32,
        dn_per_radiance,
        psf,
        blur_frame,
        sky_blur: resolved.psf.map_or(SkyBlur::Frame, |p| p.sky_blur),
        sky_blur_plan: None,
        nonideal,
    })
}

/// Whether blurring the background can change a pixel by more than `skip_below_dn`: always for an image
/// layer; for the dome alone, the blur of a smooth field changes it by `½·M₂·|L''|` (M₂ the kernel's second
/// moment in px², L'' the largest curvature per px²), which is compared with the threshold.
fn frame_needs_blur(psf: &Psf, cfg: &PsfToml, sky: &Sky, sensor: &ResolvedSensor, dn_per_radiance: f64) -> bool {
    if sky.plane.is_some() || cfg.skip_below_dn <= 0.0 {
        return true;
    }
    let ifov = sensor.intrinsics.pixel_pitch_m / sensor.intrinsics.focal_length_m;
    let curvature_per_px2 = sky.dome.max_curvature_per_rad2() * ifov * ifov;
    let change_dn = 0.5 * psf.point_kernel().second_moment_px2() * curvature_per_px2 * dn_per_radiance;
    change_dn > cfg.skip_below_dn
}

/// Lets `flag` stop the run inside a frame: long iterative fusion solves look at it between sweeps. A frame
/// computed while it was set is incomplete; the caller must not write it.
pub fn set_stop_flag(app: &mut App, flag: std::sync::Arc<std::sync::atomic::AtomicBool>) {
    app.world_mut().resource_mut::<Fusion>().0.set_stop(flag);
}

/// Runs one step (one frame) and returns its labels.
pub fn step(app: &mut App) -> FrameLabels {
    app.update();
    let mut out = app.world_mut().resource_mut::<FrameOutput>();
    out.ready = false;
    out.labels.clone()
}

/// The sensor frame of the last completed step (quantized DN as f32).
pub fn current_frame(app: &mut App) -> &Frame {
    let world = app.world_mut();
    let mut q = world.query::<&SensorFrame>();
    &q.single(world).expect("one sensor").frame
}
