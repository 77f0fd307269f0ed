//! A checked scenario turned into entities and resources: the sensor (readout, PSF, non-idealities, the sky
//! blur's plan), the observer, the sky (calibrated image or baked layer over the dome) and the aircraft.

use std::sync::Arc;

use bevy::ecs::prelude::*;
use glam::{DVec2, DVec3};

use super::camera::resolve_aim;
use super::render::{coarse_camera, render_background, render_steady, steady_margin};
use super::{
    Aim, Aircraft, Body, CameraPose, FlightPath, Footprint, Kinematics, Observer, SceneParams, Sensor, SensorFrame,
    Shake, Signature, SimClock, SimSettings, Skin, Sky,
};
use crate::imaging::background::{BackgroundRenderer, BackgroundStats, SkyBlur, plan_sky_blur};
use crate::imaging::camera::{Camera, Jitter};
use crate::imaging::frame::Frame;
use crate::imaging::psf::{Psf, PsfOptics, PsfSpec};
use crate::imaging::sky_field::{LayerBake, RadianceLut, bake_layer, calibrate, through_air, with_dome_margin};
use crate::imaging::sky_gen::{CloudLayer, SkyGenSpec, generate};
use crate::imaging::sky_plane::{DomeMargin, MissFill, Sampling, SkyImage, SkyPlacement, SkyPlane};
use crate::imaging::vibration::Vibration;
use crate::physics::atmosphere::AirTemperature;
use crate::physics::lowtran::{AtmosphereError, PathSteps, Weather};
use crate::physics::lowtran_paths::{ClearSky, LowtranAtmosphere};
use crate::physics::nonideal::{FocalPlane, NonIdeal};
use crate::physics::planck::{Band, Measure};
use crate::physics::random::SplitMix64;
use crate::physics::reflection::SphereQuadrature;
use crate::physics::sky::{ClearSkyModel, Dome, DomeInputs};
use crate::physics::transmittance::SceneAtmosphere;
use crate::scenario::sensor::{PsfSettings, ResolvedSensor};
use crate::scenario::{CheckedScenario, Pointing};

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
    /// Keep the whole background after each frame ([`SimSettings::whole_background`]): a window's readout of
    /// the sky behind any pixel needs it; a run that reads only frames and labels does not.
    pub whole_background: bool,
    /// Time each stage ([`StageTimings`](super::StageTimings)).
    pub timings: bool,
    /// Where the run's own frames are replayed, from the first after the last, until this many are rendered
    /// (`irsim bench` timing more frames than a scenario has): the renders the sky's blur is planned for, where
    /// it is planned (`[quality] sky_blur = "auto"`); `None`: the run's own frames.
    pub replayed_to: Option<u64>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            seed: None,
            noise: true,
            vibration: true,
            keep_float: false,
            masks: false,
            whole_background: false,
            timings: false,
            replayed_to: None,
        }
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

/// Spawns `scenario`'s entities into `world` and inserts the resources its systems read ([`SimClock`],
/// [`SimSettings`], [`SceneParams`]); the plugins of [`IrSimPlugins`](super::IrSimPlugins) must be added to its
/// app. Every front end (headless runs, the recorder, a window) builds its world this way.
///
/// # Errors
/// [`SetupError`] if the sky image cannot be loaded, calibrated or placed, or the optics PSF cannot be built.
pub fn spawn_scenario(world: &mut World, scenario: &CheckedScenario, options: RunOptions) -> Result<(), SetupError> {
    let spec = &scenario.spec;
    let seed = options.seed.unwrap_or(spec.run.seed);
    let dt = 1.0 / spec.run.frame_rate_hz;
    let sensor_spec = scenario.sensor;
    world.insert_resource(SimClock { frame: 0, start_s: spec.run.start_time_s, dt_s: dt });
    world.insert_resource(SimSettings {
        seed,
        noise: options.noise && sensor_spec.noise.enabled,
        vibration: options.vibration,
        keep_float: options.keep_float,
        masks: options.masks,
        whole_background: options.whole_background,
        quality: scenario.quality,
        blob: sensor_spec.blob,
        detectable_snr: spec.labels.detectable_snr,
        mask_fraction: spec.labels.mask_fraction,
    });
    let (p0, v0) = scenario.observer_trajectory.state(spec.run.start_time_s);
    // a generated layer no planned view sees is made when a view first may see it (its placement now)
    let layer_plan = plan_layer(scenario, p0);
    // independent parts side by side (each has stretches on one thread: the generated layer's noise, the
    // table's logarithms, the image's decoding): the atmosphere's tables and the clear sky from them, the
    // generated cloud layer, the optics' PSFs and the detector's fixed pattern, and the radiance table with the
    // sky image calibrated by it
    let ((atmosphere, layer), ((psfs, nonideal), (lut, image))) = rayon::join(
        || {
            rayon::join(
                || atmosphere_and_clear_sky(scenario, p0),
                || {
                    layer_plan
                        .as_ref()
                        .filter(|plan| !plan.unseen && plan.geometry.is_ok())
                        .and_then(|plan| generated_layer(scenario, plan, seed))
                },
            )
        },
        || {
            rayon::join(
                || (sensor_psfs(&sensor_spec, !spec.targets.is_empty()), nonideal(&sensor_spec, seed)),
                || {
                    let model = &sensor_spec.model;
                    let lut = RadianceLut::new(model.band, model.measure(), scenario.quality.radiance_table_step_k);
                    let image = calibrated_image(scenario, &lut);
                    (lut, image)
                },
            )
        },
    );
    // the errors in the order the parts were made in before: the atmosphere's, the sky's, the sensor's
    let (atmosphere, clear_sky) = atmosphere?;
    let scene = SceneParams {
        air: spec.atmosphere.air_temperature().map_err(|e| setup("atmosphere.model")(e.to_string()))?,
        stagnation: spec.atmosphere.stagnation,
        sun: spec.sun,
        atmosphere,
        quadrature: SphereQuadrature::new(scenario.quality.reflection_grid[0], scenario.quality.reflection_grid[1]),
    };

    let intrinsics = sensor_spec.intrinsics;
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let sky = build_sky(scenario, &scene, p0, SkyParts { layer, layer_plan, clear_sky, lut, image, seed })?;
    let mut sensor = build_sensor(&sensor_spec, &sky, psfs?, nonideal)?;
    if let (Some(plane), Some(psf), Some(cfg), true) =
        (sky.plane_geometry(), sensor.background_psf(), sensor_spec.psf, sensor.blur_frame)
        && cfg.sky_blur == SkyBlur::Auto
    {
        // planned for what is rendered: on a coarse grid, its cameras with its PSF
        let step = sensor.background_step;
        let views = replayed_views(scenario, options.replayed_to).map(|c| coarse_camera(&c, step));
        let plan = plan_sky_blur(plane, psf, cfg.prefilter(sensor.dn_per_radiance), (w / step, h / step), views);
        sensor.sky_blur = plan.choice;
        sensor.sky_blur_plan = Some(plan);
    }
    world.insert_resource(scene);
    let step = sensor.background_step;
    let vibration = if options.vibration { spec.observer.vibration.plan(seed) } else { Vibration::still() };
    // a staring camera (the same steady view at every frame) may read its shaken views from one render
    let mut views = planned_views(scenario);
    let first = views.next();
    let noisy_track = matches!(spec.observer.pointing, Pointing::Track { noise_urad, .. } if noise_urad > 0.0);
    let staring = !noisy_track && first.is_some_and(|first| views.all(|v| v == first));
    let tolerance_px = if staring { scenario.quality.view_shift_tolerance_px } else { 0.0 };
    let mut sensor_frame = SensorFrame {
        frame: Frame::new(w, h),
        float_frame: None,
        background: Frame::new(w, h),
        background_camera: None,
        last_camera: None,
        moving: false,
        handed_over: false,
        background_stats: BackgroundStats::default(),
        renderer: BackgroundRenderer::new(),
        columns: Vec::new(),
        coarse: (step > 1).then(|| Frame::new(w / step, h / step)),
        coarse_only: step > 1 && spec.targets.is_empty(),
        steady_render: None,
        steady_margin: steady_margin(vibration.peak(), &intrinsics, step, tolerance_px),
        view_offset: None,
    };
    // the prefiltered textures the first view reads are built now, with the rest of the set-up, rather than in
    // the first frame: the first view's background is rendered here (the first frame renders its own over it,
    // the same values: a texel does not depend on when or in which crop it was built, nor a frame on what its
    // buffers held)
    if sensor_frame.steady_margin > 0
        && let Some(first) = first
    {
        // a staring camera's frames read the steady view's render: that is the first view's render
        render_steady(&sensor, &sky, &first, &mut sensor_frame);
    } else if sensor.blur_frame
        && sensor.sky_blur == SkyBlur::Prefilter
        && sky.has_plane()
        && let Some(first) = first
    {
        render_background(&sensor, &sky, &first, &mut sensor_frame);
    }
    world.spawn((sensor, sensor_frame));
    let placeholder = Camera::new(intrinsics, p0, Default::default());
    let observer = world
        .spawn((
            Observer,
            FlightPath(scenario.observer_trajectory.clone()),
            Kinematics { position_m: p0, velocity_m_s: v0 },
            Aim { pointing: spec.observer.pointing.clone(), tracked: None },
            Shake(vibration),
            CameraPose { steady: placeholder, current: placeholder, jitter: Jitter::default() },
        ))
        .id();
    world.spawn(sky);
    let mut tracked = None;
    for (i, (t, tr)) in spec.targets.iter().zip(&scenario.target_trajectories).enumerate() {
        let (p, v) = tr.state(spec.run.start_time_s);
        let entity = world
            .spawn((
                Aircraft { id: i as u32 + 1, name: t.name.clone() },
                FlightPath(tr.clone()),
                Kinematics { position_m: p, velocity_m_s: v },
                Body { semi_axes_m: t.semi_axes_m, attitude: t.attitude },
                Skin {
                    emissivity: t.emissivity,
                    brdf: t.brdf,
                    reflection: scenario.quality.reflection,
                    mach: t.mach,
                    heating_k: t.heating_k,
                },
                Signature::default(),
                Footprint::default(),
            ))
            .id();
        if matches!(&spec.observer.pointing, Pointing::Track { target, .. } if *target == t.name) && tracked.is_none() {
            tracked = Some(entity);
        }
    }
    if let Some(mut aim) = world.get_mut::<Aim>(observer) {
        aim.tracked = tracked;
    }
    Ok(())
}

/// Removes what [`spawn_scenario`] spawned (the sensor, observer, sky and aircraft entities), so that a changed
/// scenario can be spawned into the same world; the resources are replaced by the next [`spawn_scenario`].
pub fn despawn_scenario(world: &mut World) {
    let mut entities: Vec<Entity> = Vec::new();
    entities.extend(world.query_filtered::<Entity, With<Sensor>>().iter(world));
    entities.extend(world.query_filtered::<Entity, With<Observer>>().iter(world));
    entities.extend(world.query_filtered::<Entity, With<Sky>>().iter(world));
    entities.extend(world.query_filtered::<Entity, With<Aircraft>>().iter(world));
    for e in entities {
        world.despawn(e);
    }
}

/// The scene's atmosphere (its tables for a LOWTRAN weather) and, where the dome takes it from them, the clear
/// sky's radiance from the observer's start `eye` (its error for the field `sky.dome.clear_sky`).
fn atmosphere_and_clear_sky(
    scenario: &CheckedScenario,
    eye: DVec3,
) -> Result<(SceneAtmosphere, Result<Option<ClearSky>, SetupError>), SetupError> {
    let spec = &scenario.spec;
    let Some(weather) = spec.atmosphere.weather() else {
        return Ok((SceneAtmosphere::Override(spec.atmosphere.override_transmittance()), Ok(None)));
    };
    let model = &scenario.sensor.model;
    let steps = scenario.quality.path_steps();
    let key = (weather, model.band, model.measure(), eye.z.to_bits(), spec.sun.temp_k.to_bits(), steps);
    let lowtran = shared_lowtran(key).map_err(|e| setup("atmosphere.model")(e.to_string()))?;
    let clear_sky = match spec.sky.dome.clear_sky {
        Some(ClearSkyModel::Parametric) => Ok(None),
        _ => shared_clear_sky(key, &lowtran).map(Some).map_err(|e| setup("sky.dome.clear_sky")(e.to_string())),
    };
    Ok((SceneAtmosphere::Lowtran(lowtran), clear_sky))
}

/// A scenario's sky image loaded and calibrated to radiance by `lut` (none for a generated sky or no plane).
fn calibrated_image(scenario: &CheckedScenario, lut: &RadianceLut) -> Option<Result<SkyImage, SetupError>> {
    let sky = &scenario.spec.sky;
    let (Some(path), Some(_)) = (&scenario.sky_image, sky.placement()) else { return None };
    let raw = match SkyImage::load(path) {
        Ok(raw) => raw,
        Err(e) => return Some(Err(setup("sky.image")(e.to_string()))),
    };
    let Some(calibration) = sky.calibration else { return Some(Err(setup("sky.calibration")("is required".into()))) };
    Some(
        calibrate(&raw, &calibration, lut, &path.display().to_string())
            .map_err(|e| setup("sky.calibration")(e.to_string())),
    )
}

/// What the sky is built from, made beside the atmosphere ([`spawn_scenario`]).
struct SkyParts {
    /// The generated cloud layer, for a generated sky a planned view sees.
    layer: Option<Arc<CloudLayer>>,
    /// A generated layer's size and placement, and whether no planned view sees it.
    layer_plan: Option<LayerPlan>,
    /// The run's seed (a deferred layer's).
    seed: u64,
    /// The clear sky from the LOWTRAN tables, where the dome takes it from them.
    clear_sky: Result<Option<ClearSky>, SetupError>,
    /// Band radiance by temperature.
    lut: RadianceLut,
    /// The calibrated sky image, for a sky image.
    image: Option<Result<SkyImage, SetupError>>,
}

/// The dome for the observer's start, and the sky image (calibrated) or generated layer (baked) on its plane.
fn build_sky(scenario: &CheckedScenario, scene: &SceneParams, eye: DVec3, parts: SkyParts) -> Result<Sky, SetupError> {
    let SkyParts { layer, layer_plan, seed, clear_sky, lut, image } = parts;
    let sky = &scenario.spec.sky;
    let model = &scenario.sensor.model;
    let (band, measure) = (model.band, model.measure());
    // none without LOWTRAN tables; its error where they could not give it
    let clear_sky = clear_sky?;
    let dome = Dome::new(&DomeInputs {
        spec: sky.dome,
        band,
        measure,
        observer_altitude_m: eye.z,
        air: scene.air,
        atmosphere: &scene.atmosphere,
        zenith_emissivity: scene.atmosphere.lowtran().map(|l| 1.0 - l.zenith_transmittance()),
        clear_sky: clear_sky.as_ref(),
    })
    .map_err(|e| SetupError { field: format!("sky.dome.{}", e.name), message: e.to_string() })?;
    let dome = Arc::new(dome);
    let placement = sky.placement();
    let plane = match (&sky.generate, image, placement) {
        (_, Some(image), Some(placement)) => {
            let image = image?;
            let image = if scenario.spec.atmosphere.sky_path {
                let geometry =
                    SkyPlane::new(image.clone(), &placement, eye).map_err(|e| setup("sky")(e.to_string()))?;
                let air = |z: f64| scene.air_temp_k(z);
                through_air(&image, &geometry, eye, &scene.atmosphere, &air, &lut)
                    .map_err(|e| setup("atmosphere.sky_path")(e.to_string()))?
            } else {
                image
            };
            let plane = SkyPlane::new(image, &placement, eye).map_err(|e| setup("sky")(e.to_string()))?;
            Some(image_margin(scenario, plane, &placement, eye, &dome)?)
        }
        (Some(gen_spec), None, Some(placement)) => {
            let plan = layer_plan.ok_or_else(|| setup("sky.generate")("no layer was planned".into()))?;
            let geometry = plan.geometry?;
            let maker = LayerMaker {
                spec: layer_spec(gen_spec, seed),
                size: plan.size,
                margin: plan.margin,
                placement: with_margin(&placement, plan.size, plan.margin),
                eye_m: eye,
                dome: Arc::clone(&dome),
                air: scene.air,
                atmosphere: scene.atmosphere.clone(),
                lut,
                cloud_offset_k: sky.cloud_offset_k,
                cloud_base_m: sky.cloud_base_m,
            };
            match layer {
                Some(layer) => Some(maker.plane(&layer, &geometry)?),
                None => {
                    let tolerance = scenario.quality.span_tolerance_px;
                    let mut geometry = geometry;
                    geometry.set_span_tolerance(tolerance);
                    // its pixels: the layer generated and baked as at set-up (a pure function of these inputs).
                    // The placement was checked here; the bake fails only on a texel that is not finite, which the
                    // finite dome and the radiance table (clamped to its temperatures) never give
                    let make = move |geometry: &SkyPlane| {
                        let layer = shared_layer(&maker.spec, maker.size.0, maker.size.1);
                        let mut plane = maker.plane(&layer, geometry).expect("a layer checked at set-up bakes");
                        plane.set_span_tolerance(tolerance);
                        plane
                    };
                    return Ok(Sky::deferred(geometry, make, scenario.quality.sky_sampling, dome));
                }
            }
        }
        _ => None,
    };
    let plane = plane.map(|mut p| {
        p.set_span_tolerance(scenario.quality.span_tolerance_px);
        Arc::new(p)
    });
    Ok(Sky::new(plane, scenario.quality.sky_sampling, sky.miss, dome))
}

/// Most texels of an image widened by a margin of the dome (256 MiB of radiance); a larger image gets no margin.
const MAX_WIDENED_TEXELS: usize = 1 << 26;

/// `plane` (a sky image's) with the image widened by the dome as its texture's source (`[quality]
/// image_margin_px`, [`DomeMargin`]) where misses take the dome, the sky is read by point samples, and a planned
/// view comes within the margin of the image's edge; else `plane` as it is.
fn image_margin(
    scenario: &CheckedScenario,
    plane: SkyPlane,
    placement: &SkyPlacement,
    eye: DVec3,
    dome: &Dome,
) -> Result<SkyPlane, SetupError> {
    let margin_px = scenario.quality.image_margin_px;
    let point_sampled = !matches!(scenario.quality.sky_sampling, Sampling::Supersample { n } if n > 1);
    if !(scenario.spec.sky.miss == MissFill::Dome
        && margin_px > 0.0
        && point_sampled
        && views_near_the_edge(scenario, &plane, margin_px))
    {
        return Ok(plane);
    }
    let size = (plane.image().width(), plane.image().height());
    // the smaller of the texel's sides, so that the margin is at least as wide as asked along both
    let texel_m = (placement.width_m / size.0 as f64).min(placement.height_m / size.1 as f64);
    let texels = margin_texels(&scenario.sensor, placement, eye, texel_m, margin_px);
    let (w, h) = (size.0 + 2 * texels, size.1 + 2 * texels);
    if w.saturating_mul(h) > MAX_WIDENED_TEXELS {
        // the widened copy would be too large to hold beside the image: its edge is blurred per frame instead
        return Ok(plane);
    }
    let wider = with_margin(placement, size, texels);
    let widened = SkyPlane::new(with_dome_margin(&plane, texels, eye, dome), &wider, eye)
        .map_err(|e| setup("sky")(e.to_string()))?;
    Ok(plane.with_dome_margin(DomeMargin { plane: widened, texels }))
}

/// What makes a generated layer's plane: the layer's parameters (its seed the run's) and size, and what its bake
/// reads, owned (a deferred plane is made during the run).
struct LayerMaker {
    spec: SkyGenSpec,
    size: (usize, usize),
    /// Texels of clear sky baked around the layer ([`LayerPlan::margin`]).
    margin: usize,
    /// The placement of the layer with its margin.
    placement: SkyPlacement,
    eye_m: DVec3,
    dome: Arc<Dome>,
    air: AirTemperature,
    atmosphere: SceneAtmosphere,
    lut: RadianceLut,
    cloud_offset_k: f64,
    cloud_base_m: Option<f64>,
}

impl LayerMaker {
    /// `layer` baked into radiance over the dome with its margin, placed as `geometry` (the same plane holding
    /// any image of the layer's size with the margin), at the default span tolerance.
    fn plane(&self, layer: &CloudLayer, geometry: &SkyPlane) -> Result<SkyPlane, SetupError> {
        let air = |z: f64| self.air.clamped_k(z);
        let image = bake_layer(&LayerBake {
            layer,
            plane: geometry,
            margin: self.margin,
            eye_m: self.eye_m,
            dome: &self.dome,
            air_temp_k: &air,
            atmosphere: &self.atmosphere,
            lut: &self.lut,
            cloud_offset_k: self.cloud_offset_k,
            cloud_base_m: self.cloud_base_m,
        })
        .map_err(|e| setup("sky.generate")(e.to_string()))?;
        SkyPlane::new(image, &self.placement, self.eye_m).map_err(|e| setup("sky")(e.to_string()))
    }
}

/// A generated layer's size, the margin of clear sky baked around it, its placement (the plane holding a blank
/// image of that size with the margin, or the placement's error), and whether no planned view may see it, its
/// misses taking the dome: such a layer is made when a view first may ([`Sky::deferred`]).
struct LayerPlan {
    size: (usize, usize),
    /// Texels of the dome baked around the layer on every side (`[quality] layer_margin_px` at the plane's
    /// distance from the observer's start; 0 where the switch is 0, misses do not take the dome, or no planned
    /// view comes within the margin of the layer's edge).
    margin: usize,
    geometry: Result<SkyPlane, SetupError>,
    unseen: bool,
}

/// The plan of a scenario's generated layer (none for a sky image or no plane), from the observer's start `eye`.
fn plan_layer(scenario: &CheckedScenario, eye: DVec3) -> Option<LayerPlan> {
    let sky = &scenario.spec.sky;
    let (Some(_), None, Some(placement)) = (&sky.generate, &scenario.sky_image, sky.placement()) else {
        return None;
    };
    let size = layer_size(&scenario.sensor, &placement, eye, sky.max_texels, scenario.quality.sky_texel_px);
    // zeros from the allocator: a blank image's pages are not touched unless read
    let blank = |(w, h): (usize, usize)| SkyImage::from_finite(w, h, vec![0.0; w * h]);
    // a margin only where misses take the dome and a planned view comes within it of the layer's edge
    let margin_px = scenario.quality.layer_margin_px;
    let near_the_edge = || {
        SkyPlane::new(blank(size), &placement, eye).is_ok_and(|bare| views_near_the_edge(scenario, &bare, margin_px))
    };
    let margin = if sky.miss == MissFill::Dome && margin_px > 0.0 && near_the_edge() {
        // the texels along the width (square, but for a side that `layer_size` raised to its 16-texel floor, whose
        // texels are smaller and whose margin is then narrower than asked)
        margin_texels(&scenario.sensor, &placement, eye, placement.width_m / size.0 as f64, margin_px)
    } else {
        0
    };
    let blank = blank((size.0 + 2 * margin, size.1 + 2 * margin));
    let geometry =
        SkyPlane::new(blank, &with_margin(&placement, size, margin), eye).map_err(|e| setup("sky")(e.to_string()));
    let unseen = sky.miss == MissFill::Dome
        && geometry.as_ref().is_ok_and(|g| planned_views(scenario).all(|camera| !g.seen_by(&camera)));
    Some(LayerPlan { size, margin, geometry, unseen })
}

/// A layer's parameters with its seed mixed with the run's `seed`.
fn layer_spec(spec: &SkyGenSpec, seed: u64) -> SkyGenSpec {
    SkyGenSpec { seed: spec.seed ^ seed.wrapping_mul(SplitMix64::GAMMA), ..*spec }
}

/// The steady cameras (no vibration, no pointing noise) of the run's frames, for planning: every frame up to
/// 4096 of them, an even sample of 4096 beyond.
pub(crate) fn planned_views(scenario: &CheckedScenario) -> impl Iterator<Item = Camera> + '_ {
    replayed_views(scenario, None)
}

/// [`planned_views`] of a run whose own frames are replayed, from the first after the last, until `renders` are
/// rendered (`None`, or no more than its own: its own frames): the views of every render up to 4096 of them, an
/// even sample of 4096 beyond.
fn replayed_views(scenario: &CheckedScenario, renders: Option<u64>) -> impl Iterator<Item = Camera> + '_ {
    let spec = &scenario.spec;
    let own = spec.run.frames.max(1);
    let renders = renders.map_or(own, |n| n.max(own));
    let stride = renders.div_ceil(4096).max(1);
    let intrinsics = scenario.sensor.intrinsics;
    (0..renders).step_by(stride as usize).map(move |k| {
        let k = k % own;
        let t = spec.run.start_time_s + k as f64 / spec.run.frame_rate_hz;
        let (eye, velocity) = scenario.observer_trajectory.state(t);
        let tracked = |name: &str, lag_s: f64| {
            let i = spec.targets.iter().position(|target| target.name == name)?;
            Some(scenario.target_trajectories[i].state(t - lag_s).0)
        };
        Camera::aimed(intrinsics, eye, velocity, resolve_aim(&spec.observer.pointing, tracked))
    })
}

/// The generated cloud layer of `plan` (a scenario's generated sky), its seed the layer's own mixed with the
/// run's.
fn generated_layer(scenario: &CheckedScenario, plan: &LayerPlan, seed: u64) -> Option<Arc<CloudLayer>> {
    let gen_spec = scenario.spec.sky.generate.as_ref()?;
    Some(shared_layer(&layer_spec(gen_spec, seed), plan.size.0, plan.size.1))
}

/// Whether a planned view of `scenario`, widened by `margin_px` pixels on every side, reaches past the edge of
/// `plane`'s image (or sees beyond the plane): a view whose widened corners all meet the image reads none of a
/// margin (the image and the view's footprint on it are convex).
fn views_near_the_edge(scenario: &CheckedScenario, plane: &SkyPlane, margin_px: f64) -> bool {
    let (iw, ih) = (plane.image().width() as f64, plane.image().height() as f64);
    planned_views(scenario).any(|camera| {
        let projection = plane.projection(&camera);
        let (w, h) = (f64::from(camera.intrinsics.width), f64::from(camera.intrinsics.height));
        let (lo_x, lo_y, hi_x, hi_y) = (-margin_px, -margin_px, w + margin_px, h + margin_px);
        [(lo_x, lo_y), (hi_x, lo_y), (lo_x, hi_y), (hi_x, hi_y)].into_iter().any(|(x, y)| {
            projection
                .image_point(DVec2::new(x, y))
                .is_none_or(|p| !(p.x >= 0.0 && p.y >= 0.0 && p.x <= iw && p.y <= ih))
        })
    })
}

/// `placement` of an image of `size` texels widened by `margin` texels on every side, each texel where it was.
fn with_margin(placement: &SkyPlacement, (w, h): (usize, usize), margin: usize) -> SkyPlacement {
    if margin == 0 {
        return *placement;
    }
    let grow = |extent_m: f64, texels: usize| extent_m * (texels + 2 * margin) as f64 / texels as f64;
    SkyPlacement {
        width_m: grow(placement.width_m, w),
        height_m: grow(placement.height_m, h),
        anchor_px: placement.anchor_px.map(|a| a + DVec2::splat(margin as f64)),
        ..*placement
    }
}

/// Texels of `texel_m` metres in a margin of the dome around a generated layer or an image: `margin_px` sensor
/// pixels at the plane's distance from the observer's start `eye` (its nearest point), rounded up (`margin_px` >
/// 0: the callers make no margin otherwise).
fn margin_texels(sensor: &ResolvedSensor, placement: &SkyPlacement, eye: DVec3, texel_m: f64, margin_px: f64) -> usize {
    let px_m = pixel_at_plane_m(sensor, placement, eye);
    let texels = (margin_px * px_m / texel_m).ceil();
    // a generated layer's texels are at least half a pixel wide (`sky_texel_px`) unless a side is at its floor; an
    // image's may be smaller, and then the cap makes its margin narrower than asked. The cap bounds the image
    if texels.is_finite() { texels.clamp(1.0, 1024.0) as usize } else { 0 }
}

/// A sensor pixel's width at the plane's distance from `eye` (its nearest point), m.
fn pixel_at_plane_m(sensor: &ResolvedSensor, placement: &SkyPlacement, eye: DVec3) -> f64 {
    let ifov = sensor.intrinsics.pixel_pitch_m / sensor.intrinsics.focal_length_m;
    let normal = placement.normal.map_or_else(
        || {
            let d = eye - placement.anchor_m;
            DVec3::new(d.x, d.y, 0.0).normalize_or(DVec3::Y)
        },
        |n| n.normalize_or(DVec3::Y),
    );
    let distance = (eye - placement.anchor_m).dot(normal).abs().max(1.0);
    ifov * distance
}

/// Texels of a generated layer: one per `texel_px` sensor pixels at the plane's distance from the observer's
/// start (its nearest point), square, and larger where a side would pass `max_texels`.
fn layer_size(
    sensor: &ResolvedSensor,
    placement: &SkyPlacement,
    eye: DVec3,
    max_texels: usize,
    texel_px: f64,
) -> (usize, usize) {
    // square texels: where a side would pass `max_texels`, both grow (a layer's spectrum is isotropic in texels)
    let max = max_texels as f64;
    let texel_m = (pixel_at_plane_m(sensor, placement, eye) * texel_px)
        .max(placement.width_m / max)
        .max(placement.height_m / max);
    let side = |extent_m: f64| ((extent_m / texel_m).ceil() as usize).clamp(16, max_texels);
    (side(placement.width_m), side(placement.height_m))
}

/// The last few results of a pure function, kept for the process by their inputs. The same inputs come back
/// often: a dataset spawns each sequence up to four times (its SNR solve, its frames, the noise-free and the
/// clean extras) and draws its cameras from a few presets, and the viewer respawns the scenario at every edit.
/// A kept result is the one a new call gives, so keeping it changes no output.
struct Kept<K, V> {
    room: usize,
    /// The entries, and the [`forget_kept_results`] count they were kept under.
    entries: std::sync::Mutex<(u64, Vec<(K, V)>)>,
}

/// How many times [`forget_kept_results`] has been called.
static FORGOTTEN: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Lets go of every result kept from earlier set-ups (LOWTRAN tables, clear skies, PSFs, generated layers), so
/// that the next set-up makes its own, as a new process would (the shipped atmosphere table, decoded once per
/// process, stays): what a timing of a whole run needs. No output changes.
pub fn forget_kept_results() {
    FORGOTTEN.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
}

impl<K: PartialEq, V: Clone> Kept<K, V> {
    const fn new(room: usize) -> Self {
        Self { room, entries: std::sync::Mutex::new((0, Vec::new())) }
    }

    /// The kept result for `key`, or `make`'s, kept (the oldest let go beyond the room); errors are not kept.
    fn get_or<E>(&self, key: K, make: impl FnOnce() -> Result<V, E>) -> Result<V, E> {
        let lock = || {
            let mut kept = self.entries.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            let now = FORGOTTEN.load(std::sync::atomic::Ordering::SeqCst);
            if kept.0 != now {
                *kept = (now, Vec::new());
            }
            kept
        };
        if let Some((_, v)) = lock().1.iter().find(|(k, _)| *k == key) {
            return Ok(v.clone());
        }
        // made without the lock: two runs asking at once both make it, and keep the same value
        let v = make()?;
        let mut kept = lock();
        let kept = &mut kept.1;
        if !kept.iter().any(|(k, _)| *k == key) {
            if kept.len() >= self.room {
                kept.remove(0);
            }
            kept.push((key, v.clone()));
        }
        Ok(v)
    }
}

/// The PSF of `spec` and `optics`, built once per process for each (the last 8 kept): building one (its OTF
/// sampled on fine grids) takes a good part of a scenario's set-up.
fn shared_psf(spec: &PsfSpec, optics: &PsfOptics) -> Result<Arc<Psf>, crate::physics::ParamError> {
    static KEPT: Kept<(PsfSpec, PsfOptics), Arc<Psf>> = Kept::new(8);
    KEPT.get_or((*spec, *optics), || Psf::new(spec, optics).map(Arc::new))
}

/// What an observer's LOWTRAN tables are a function of: the weather, the band and measure, the observer's
/// starting altitude and the sun's temperature (the floats by their bits), and the paths' steps.
type AtmosphereKey = (Weather, Band, Measure, u64, u64, PathSteps);

/// The observer's LOWTRAN tables for `key`'s inputs, made once per process for each (the last 4 kept: they
/// take most of a scenario's set-up).
fn shared_lowtran(key: AtmosphereKey) -> Result<Arc<LowtranAtmosphere>, AtmosphereError> {
    static KEPT: Kept<AtmosphereKey, Arc<LowtranAtmosphere>> = Kept::new(4);
    let (weather, band, measure, eye_z, sun_k, steps) = key;
    KEPT.get_or(key, || {
        LowtranAtmosphere::new(weather, band, measure, f64::from_bits(eye_z), f64::from_bits(sun_k), steps)
            .map(Arc::new)
    })
}

/// The clear sky of `lowtran`, whose inputs are `key`, made once per process for each (the last 4 kept).
fn shared_clear_sky(key: AtmosphereKey, lowtran: &LowtranAtmosphere) -> Result<ClearSky, AtmosphereError> {
    static KEPT: Kept<AtmosphereKey, ClearSky> = Kept::new(4);
    KEPT.get_or(key, || lowtran.clear_sky())
}

/// Texels of the largest generated layer kept for the process (2048², 32 MiB): a larger one is generated for
/// each use rather than held for the run.
const KEPT_LAYER_TEXELS: usize = 2048 * 2048;

/// The layer of `spec` at `width × height` ([`generate`]), generated once per process for each (the last 2
/// up to [`KEPT_LAYER_TEXELS`] kept).
fn shared_layer(spec: &SkyGenSpec, width: usize, height: usize) -> Arc<CloudLayer> {
    static KEPT: Kept<(SkyGenSpec, usize, usize), Arc<CloudLayer>> = Kept::new(2);
    let make = || Arc::new(generate(spec, width, height));
    if width * height > KEPT_LAYER_TEXELS {
        return make();
    }
    match KEPT.get_or((*spec, width, height), || Ok::<_, std::convert::Infallible>(make())) {
        Ok(layer) => layer,
        Err(never) => match never {},
    }
}

/// A sensor's PSFs: at its pixels (for the background and targets, or where the background is made on a coarse
/// grid, for targets alone: none in a scene without targets), and at the coarse background's (`background_step`
/// pixels a side, where that is more than 1).
struct SensorPsfs {
    psf: Option<Arc<Psf>>,
    coarse_psf: Option<Arc<Psf>>,
    background_step: usize,
}

/// The PSFs of a sensor ([`SensorPsfs`]) in a scene with or without `targets`.
fn sensor_psfs(resolved: &ResolvedSensor, targets: bool) -> Result<SensorPsfs, SetupError> {
    let model = &resolved.model;
    let (w, h) = (resolved.intrinsics.width as usize, resolved.intrinsics.height as usize);
    let step = resolved.background_step_px.max(1);
    let background_step = if w % step == 0 && h % step == 0 { step } else { 1 };
    // the PSF seen from pixels `scale` times larger over the detector's own photosensitive area
    let psf_at = |scale: usize| -> Result<Option<Arc<Psf>>, SetupError> {
        let Some(p) = resolved.psf else { return Ok(None) };
        let scale = scale as f64;
        let optics = PsfOptics {
            f_number: model.optics.f_number(),
            pixel_pitch_m: model.detector.pixel_pitch_m * scale,
            fill_factor: model.detector.fill_factor / (scale * scale),
            band: model.band,
            measure: model.measure(),
            reference_temp_k: 300.0,
        };
        shared_psf(&p.spec, &optics)
            .map(Some)
            .map_err(|e| SetupError { field: format!("sensor.psf.{}", e.name), message: e.to_string() })
    };
    // (a scene without targets still has its PSF's settings checked: the coarse one is built from the same spec
    // and f-number, all that Psf::new refuses)
    let psf = if background_step == 1 || targets { psf_at(1)? } else { None };
    let coarse_psf = if background_step > 1 { psf_at(background_step)? } else { None };
    Ok(SensorPsfs { psf, coarse_psf, background_step })
}

/// The detector's fixed pattern and drifts ([`NonIdeal`]), where it has any.
fn nonideal(resolved: &ResolvedSensor, seed: u64) -> Option<Arc<NonIdeal>> {
    if resolved.nonideal.is_ideal() {
        return None;
    }
    let plane = FocalPlane {
        width: resolved.intrinsics.width as usize,
        height: resolved.intrinsics.height as usize,
        focal_px: resolved.intrinsics.focal_px(),
    };
    Some(Arc::new(NonIdeal::new(&resolved.nonideal, plane, resolved.model.report(300.0).noise_dn, seed)))
}

/// The sensor component: readout, PSF (and whether the frame needs it), non-idealities.
fn build_sensor(
    resolved: &ResolvedSensor,
    sky: &Sky,
    psfs: SensorPsfs,
    nonideal: Option<Arc<NonIdeal>>,
) -> Result<Sensor, SetupError> {
    let model = &resolved.model;
    let k = model.signal_per_radiance();
    let readout = model.readout(resolved.noise.poisson_normal_threshold, resolved.noise.normal_sampler);
    let dn_per_radiance = k / model.adc.gain;
    let SensorPsfs { psf, coarse_psf, background_step } = psfs;
    let mut sensor = Sensor {
        resolved: *resolved,
        readout,
        max_level: model.adc.max_level() as f32,
        dn_per_radiance,
        psf,
        blur_frame: false,
        blur_dome: false,
        sky_blur: resolved.psf.map_or(SkyBlur::Frame, |p| p.sky_blur),
        sky_blur_plan: None,
        nonideal,
        background_step,
        coarse_psf,
    };
    // the background's PSF and pixels: the coarse grid's where it is made on one
    let ifov = resolved.intrinsics.pixel_pitch_m * background_step as f64 / resolved.intrinsics.focal_length_m;
    sensor.blur_dome = match (sensor.background_psf(), resolved.psf) {
        (Some(psf), Some(cfg)) => dome_needs_blur(psf, &cfg, sky, ifov, dn_per_radiance),
        _ => false,
    };
    // an image layer may be seen in any frame
    sensor.blur_frame = sensor.background_psf().is_some() && (sensor.blur_dome || sky.has_plane());
    Ok(sensor)
}

/// Whether blurring a view of the dome alone can change a pixel by more than `skip_below_dn`: the blur of a
/// smooth field changes it by `½·M₂·|L''|` (M₂ the kernel's second moment in px², L'' the largest curvature per
/// px², for pixels of `ifov` rad), which is compared with the threshold.
fn dome_needs_blur(psf: &Psf, cfg: &PsfSettings, sky: &Sky, ifov: f64, dn_per_radiance: f64) -> bool {
    if cfg.skip_below_dn <= 0.0 {
        return true;
    }
    let curvature_per_px2 = sky.dome.max_curvature_per_rad2() * ifov * ifov;
    let change_dn = 0.5 * psf.point_kernel().second_moment_px2() * curvature_per_px2 * dn_per_radiance;
    change_dn > cfg.skip_below_dn
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_margin_keeps_every_texel_where_it_was_with_or_without_an_anchor() {
        let eye = DVec3::new(0.0, 0.0, 8000.0);
        let blank = |w: usize, h: usize| SkyImage::from_finite(w, h, vec![0.0; w * h]);
        let (w, h, m) = (300, 120, 17);
        for anchor_px in [None, Some(DVec2::new(40.0, 110.0))] {
            // texels 4000/300 m wide and 1500/120 m high: not square
            let placement = SkyPlacement { anchor_px, height_m: 1500.0, ..SkyPlacement::paper_fig8() };
            let plane = SkyPlane::new(blank(w, h), &placement, eye).unwrap();
            let wider = SkyPlane::new(blank(w + 2 * m, h + 2 * m), &with_margin(&placement, (w, h), m), eye).unwrap();
            for (x, y) in [(0.5, 0.5), (0.0, 0.0), (299.5, 119.5), (300.0, 120.0), (150.25, 60.75)] {
                let p = DVec2::new(x, y);
                let moved = wider.world_point(p + DVec2::splat(m as f64)) - plane.world_point(p);
                assert!(moved.length() < 1e-6, "{anchor_px:?} ({x}, {y}): {moved}");
            }
        }
    }

    #[test]
    fn a_replayed_run_plans_its_own_views_again_for_every_render() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/paper_clear_sky.toml");
        let scenario = crate::scenario::load::load(&path).unwrap();
        let own: Vec<Camera> = planned_views(&scenario).collect();
        assert_eq!(own.len(), 90);
        // no more renders than its own frames: its own views
        assert_eq!(replayed_views(&scenario, None).collect::<Vec<_>>(), own);
        assert_eq!(replayed_views(&scenario, Some(40)).collect::<Vec<_>>(), own);
        // 200 renders: its 90 views, the 90 again, then the first 20
        let replayed: Vec<Camera> = replayed_views(&scenario, Some(200)).collect();
        assert_eq!(replayed.len(), 200);
        assert!(replayed.iter().enumerate().all(|(k, v)| *v == own[k % 90]));
        assert_ne!(own[0], own[89], "a tracking camera's views differ");
        // beyond 4096, an even sample of them: every third render's of 10 000
        let sampled: Vec<Camera> = replayed_views(&scenario, Some(10_000)).collect();
        assert_eq!(sampled.len(), 3334);
        assert!(sampled.iter().enumerate().all(|(k, v)| *v == own[(3 * k) % 90]));
    }

    #[test]
    fn kept_results_are_returned_until_the_oldest_is_let_go() {
        let kept: Kept<u32, Arc<u32>> = Kept::new(2);
        let made = std::cell::Cell::new(0);
        let get = |k: u32| {
            kept.get_or(k, || {
                made.set(made.get() + 1);
                Ok::<_, ()>(Arc::new(k * 10))
            })
            .unwrap()
        };
        let first = get(1);
        assert!(Arc::ptr_eq(&first, &get(1)), "kept");
        get(2);
        get(3); // lets 1 go
        assert_eq!(*get(1), 10);
        assert_eq!(made.get(), 4, "1, 2, 3, then 1 again");
        // an error is returned and not kept
        assert_eq!(kept.get_or(7, || Err::<Arc<u32>, _>("no")), Err("no"));
        assert_eq!(*kept.get_or(7, || Ok::<_, ()>(Arc::new(70))).unwrap(), 70);
        // once forgotten, a result is made again, and kept again (no other test forgets: this one's `ptr_eq`s
        // would not hold if one did meanwhile)
        let before = get(1);
        forget_kept_results();
        let again = get(1);
        assert!(!Arc::ptr_eq(&before, &again) && *again == 10, "made again");
        assert!(Arc::ptr_eq(&again, &get(1)), "and kept again");
    }

    #[test]
    fn a_kept_layer_is_the_one_a_new_generation_gives() {
        let spec = SkyGenSpec {
            kind: crate::imaging::sky_gen::SkyKind::Cumulus,
            seed: 5,
            psd_slope: -3.0,
            cover: 0.4,
            scale: 0.25,
            edge: 0.05,
            texture_k: 1.5,
            haze: 0.3,
        };
        // (other tests share the process's kept layers, so this one may have been let go since)
        let kept = shared_layer(&spec, 96, 64);
        assert_eq!(*kept, generate(&spec, 96, 64));
        assert_eq!(*shared_layer(&spec, 96, 64), *kept);
        let other = shared_layer(&SkyGenSpec { seed: 6, ..spec }, 96, 64);
        assert_ne!(*other, *kept);
    }
}
