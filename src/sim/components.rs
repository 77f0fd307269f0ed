//! The components of the simulation's entities: aircraft, observer, sky and sensor.

use std::sync::Arc;

use bevy::ecs::prelude::*;
use glam::DVec3;

use crate::imaging::background::{BackgroundRenderer, BackgroundStats, SkyBlur, SkyBlurPlan};
use crate::imaging::camera::{Camera, Jitter, YawPitchRoll};
use crate::imaging::frame::{Frame, Upsampler};
use crate::imaging::psf::Psf;
use crate::imaging::sky_plane::{MissFill, Sampling, SkyPlane};
use crate::imaging::target_blob::{GeneralizedGaussian, ImageEllipse, PixelRect};
use crate::imaging::vibration::Vibration;
use crate::physics::brdf::CookTorrance;
use crate::physics::noise::Readout;
use crate::physics::nonideal::NonIdeal;
use crate::physics::planck::Measure;
use crate::physics::reflection::ReflectionGeometry;
use crate::physics::signal::Apparent;
use crate::physics::sky::Dome;
use crate::physics::trajectory::Trajectory;
use crate::scenario::Pointing;
use crate::scenario::sensor::ResolvedSensor;

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
        crate::imaging::target_blob::body_to_world(self.attitude, velocity_m_s)
    }
}

/// Skin material and flight condition.
#[derive(Component, Debug, Clone, Copy)]
pub struct Skin {
    /// Emissivity.
    pub emissivity: f64,
    /// Reflectance.
    pub brdf: CookTorrance,
    /// Facet or ellipsoid-averaged reflection (`[quality] reflection`).
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
    pub(super) key: Option<[f64; 10]>,
    /// The line of sight's LOWTRAN spectrum, when the scene has that atmosphere.
    pub(super) sight: super::radiometry::Sightline,
    /// The skin's blackbody weights over that spectrum's bins, for the next computation at the same temperature.
    pub(super) skin_weights: crate::physics::lowtran::BinWeights,
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
    /// Index of its patch in [`TargetPatches`](super::TargetPatches) this frame.
    pub patch: Option<usize>,
}

/// Where the camera points.
#[derive(Component, Debug, Clone)]
pub struct Aim {
    /// The scenario's pointing mode.
    pub pointing: Pointing,
    /// The aircraft a `track` pointing follows, resolved from its name when the scenario is spawned.
    pub tracked: Option<Entity>,
}

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
///
/// A generated layer that no planned view of the run sees (and whose misses take the dome) is made when a camera
/// first may see it ([`Sky::plane_for`]), or when something asks for its pixels ([`Sky::plane`]): until then
/// every view of it is the dome alone, so the run's frames are the same whenever it is made, and a run that never
/// sees it never spends the set-up's time on it. Clones share the plane once made (and the making): give each
/// world its own `Sky` (a world stepped on a rayon worker that waits for another world's making could deadlock).
#[derive(Component, Debug, Clone)]
pub struct Sky {
    /// The placed radiance image.
    plane: PlaneSource,
    /// Sampling.
    pub sampling: Sampling,
    /// Fill for rays that miss the plane.
    pub miss: MissFill,
    /// The clear sky and ground.
    pub dome: Arc<Dome>,
}

/// Where a [`Sky`]'s plane comes from.
#[derive(Clone)]
enum PlaneSource {
    /// No plane.
    None,
    /// Made at set-up.
    Ready(Arc<SkyPlane>),
    /// Made when first needed.
    Deferred(Arc<DeferredPlane>),
}

impl std::fmt::Debug for PlaneSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => f.write_str("None"),
            Self::Ready(plane) => f.debug_tuple("Ready").field(plane).finish(),
            Self::Deferred(d) => f.debug_struct("Deferred").field("made", &d.made.get().is_some()).finish(),
        }
    }
}

/// A plane made when first needed: its placement (an image of its size, blank) and what makes it.
struct DeferredPlane {
    geometry: SkyPlane,
    made: std::sync::OnceLock<Arc<SkyPlane>>,
    make: Box<dyn Fn(&SkyPlane) -> SkyPlane + Send + Sync>,
}

impl DeferredPlane {
    fn get(&self) -> &Arc<SkyPlane> {
        self.made.get_or_init(|| Arc::new((self.make)(&self.geometry)))
    }
}

impl Sky {
    /// A sky with `plane` (none: the dome alone).
    pub fn new(plane: Option<Arc<SkyPlane>>, sampling: Sampling, miss: MissFill, dome: Arc<Dome>) -> Self {
        let plane = plane.map_or(PlaneSource::None, PlaneSource::Ready);
        Self { plane, sampling, miss, dome }
    }

    /// A sky whose plane `make` makes from `geometry` when first needed; `geometry` is the same plane holding a
    /// blank image of the size `make` gives (its placement, to tell whether a camera may see it). Its misses take
    /// the dome (the views that do not see the plane are the dome alone whatever its pixels).
    pub fn deferred(
        geometry: SkyPlane,
        make: impl Fn(&SkyPlane) -> SkyPlane + Send + Sync + 'static,
        sampling: Sampling,
        dome: Arc<Dome>,
    ) -> Self {
        let deferred = DeferredPlane { geometry, made: std::sync::OnceLock::new(), make: Box::new(make) };
        Self { plane: PlaneSource::Deferred(Arc::new(deferred)), sampling, miss: MissFill::Dome, dome }
    }

    /// Whether the sky has a plane (made or not).
    pub fn has_plane(&self) -> bool {
        !matches!(self.plane, PlaneSource::None)
    }

    /// Whether the plane is still to be made.
    pub fn plane_pending(&self) -> bool {
        matches!(&self.plane, PlaneSource::Deferred(d) if d.made.get().is_none())
    }

    /// The plane with its pixels, made now if it was deferred.
    pub fn plane(&self) -> Option<&Arc<SkyPlane>> {
        match &self.plane {
            PlaneSource::None => None,
            PlaneSource::Ready(plane) => Some(plane),
            PlaneSource::Deferred(d) => Some(d.get()),
        }
    }

    /// The plane's placement: the plane itself, or before a deferred one is made the same plane with a blank
    /// image of its size (its pixels must not be read).
    pub fn plane_geometry(&self) -> Option<&SkyPlane> {
        match &self.plane {
            PlaneSource::None => None,
            PlaneSource::Ready(plane) => Some(plane),
            PlaneSource::Deferred(d) => Some(d.made.get().map_or(&d.geometry, |p| &**p)),
        }
    }

    /// The plane for rendering `camera`'s view: made now if this camera may see it; before then, the blank
    /// placement, which the renderer only asks whether the camera sees it (it does not: the view is the dome).
    pub fn plane_for(&self, camera: &Camera) -> Option<&SkyPlane> {
        match &self.plane {
            PlaneSource::Deferred(d)
                if self.miss == MissFill::Dome && d.made.get().is_none() && !d.geometry.seen_by(camera) =>
            {
                Some(&d.geometry)
            }
            _ => self.plane().map(|p| &**p),
        }
    }
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
    /// The optics PSF at the sensor's pixels, if on: the targets' (and the background's where it is made at
    /// every pixel); not made where the background is made on a coarse grid in a scene without targets.
    pub psf: Option<Arc<Psf>>,
    /// Blur the frame (false when the blur would change no pixel by more than the set DN).
    pub blur_frame: bool,
    /// Blur a frame that sees only the dome (false when the dome's curvature bounds the blur's change below
    /// the set DN).
    pub blur_dome: bool,
    /// How the blur reaches the sky image this run (`prefilter` or `frame`, `auto` resolved).
    pub sky_blur: SkyBlur,
    /// The plan that resolved `auto`, if one was made.
    pub sky_blur_plan: Option<SkyBlurPlan>,
    /// The non-idealities of this sequence.
    pub nonideal: Option<Arc<NonIdeal>>,
    /// The background is made on a grid this many pixels apart (`[quality] background_step_px`, 1 where the
    /// frame's size is not a multiple of it).
    pub background_step: usize,
    /// The PSF the coarse grid blurs with: the optics seen from pixels `background_step` times larger, over
    /// the detector's own photosensitive area (`None` at step 1 or without optics blur).
    pub coarse_psf: Option<Arc<Psf>>,
}

impl Sensor {
    /// The detector's measure.
    pub fn measure(&self) -> Measure {
        self.resolved.model.measure()
    }

    /// Temporal noise in DN of a pixel whose background radiance is `radiance`.
    pub fn noise_dn(&self, radiance: f64) -> f64 {
        self.readout.noise_dn_at_radiance(radiance)
    }

    /// The PSF the background is blurred with: the coarse grid's where it is made on one.
    pub fn background_psf(&self) -> Option<&Arc<Psf>> {
        if self.background_step > 1 { self.coarse_psf.as_ref() } else { self.psf.as_ref() }
    }
}

/// The sensor's frame and its cached sky background.
#[derive(Component, Debug)]
pub struct SensorFrame {
    /// The frame being built: radiance until the Noise set, then DN.
    pub frame: Frame,
    /// The frame before quantization, DN (kept only when asked for).
    pub float_frame: Option<Frame>,
    /// The sky as last rendered (radiance, blurred), and the camera it was rendered for (`None` where the buffer
    /// does not hold it). While the camera moves frame after frame, and unless
    /// [`SimSettings::whole_background`](super::SimSettings::whole_background) is set, the render is handed to
    /// `frame` whole (the two buffers swapped, where a copy of 1.3 MB a frame at 640 × 512 was 3–4 % of a run's
    /// CPU) and this buffer then holds the render only in the windows its targets' labels read
    /// ([`crate::labels::clutter_window`]): a frame's own render is needed again only by a camera that holds still
    /// (one that stops after moving renders its first still view once more).
    pub background: Frame,
    pub(super) background_camera: Option<Camera>,
    /// The camera of the last frame's view, whether that view was rendered or reused.
    pub(super) last_camera: Option<Camera>,
    /// Whether the last frame's camera differed from the frame's before it.
    pub(super) moving: bool,
    /// Whether this frame's render was handed to `frame` (see `background`).
    pub(super) handed_over: bool,
    /// What the last render of the background did.
    pub background_stats: BackgroundStats,
    pub(super) renderer: BackgroundRenderer,
    pub(super) columns: Vec<f32>,
    /// The background on the coarse grid, where `background_step` > 1.
    pub(super) coarse: Option<Frame>,
    /// The background is made on the coarse grid in a scene without targets: nothing reads it at the sensor's
    /// pixels before the readout, so `background` is not made and the readout interpolates each block of the
    /// frame from `coarse` as it reads it out ([`SensorFrame::background_at`] for a pixel).
    pub(super) coarse_only: bool,
    /// A staring camera's steady view rendered on the coarse grid with a margin around it, from which its shaken
    /// views are read shifted (`[quality] view_shift_tolerance_px`).
    pub(super) steady_render: Option<SteadyRender>,
    /// The margin `steady_render` is made with, coarse pixels (0: shaken views are rendered each; so in a run
    /// whose steady view moves).
    pub(super) steady_margin: usize,
    /// This frame's view read from `steady_render` at this offset, coarse pixels ([`Upsampler::shifted`]).
    pub(super) view_offset: Option<[f64; 2]>,
}

/// A steady view on the coarse grid with a margin (see [`SensorFrame`]).
#[derive(Debug)]
pub(super) struct SteadyRender {
    /// The steady camera it was made for (at the sensor's pixels, without the margin).
    pub(super) steady: Camera,
    /// The camera that sees it at the sensor's pixels: the steady one with the margin on every side.
    pub(super) wider: Camera,
    /// The coarse frame, margin included.
    pub(super) coarse: Frame,
    /// What its render did.
    pub(super) stats: BackgroundStats,
}

/// What interpolates a frame of `size` from the coarse grid (`step`): the view at `offset` in the steady render
/// where it is read from one ([`Upsampler::shifted`]), else the coarse frame itself (`None` without a coarse
/// grid).
pub(super) fn coarse_upsampler<'a>(
    steady: Option<&'a SteadyRender>,
    offset: Option<[f64; 2]>,
    coarse: Option<&'a Frame>,
    size: (usize, usize),
    step: usize,
) -> Option<Upsampler<'a>> {
    match (steady, offset, coarse) {
        // `read_shifted` set the offset only where this fits
        (Some(r), Some(offset), _) => {
            Some(Upsampler::shifted(&r.coarse, step, size, offset).expect("a shifted view inside its render"))
        }
        (_, _, Some(coarse)) => Some(Upsampler::new(coarse, step)),
        _ => None,
    }
}

impl SensorFrame {
    /// Where this frame's view was read from the render of the camera's steady view, shifted (`[quality]
    /// view_shift_tolerance_px`): the offset in that render's coarse pixels ([`Upsampler::shifted`]); `None`
    /// where the view was rendered.
    pub fn shifted_view(&self) -> Option<[f64; 2]> {
        self.view_offset
    }

    /// The noise-free, blurred background at pixel `(x, y)` (radiance; 0 outside the frame): of the current
    /// view where the run keeps the whole background ([`SimSettings::whole_background`](super::SimSettings)),
    /// else only within the windows the labels read while the camera moves.
    pub fn background_at(&self, x: usize, y: usize) -> f32 {
        let (w, h) = (self.background.width(), self.background.height());
        if x >= w || y >= h {
            return 0.0;
        }
        let step = self.coarse.as_ref().map_or(1, |c| w / c.width().max(1));
        let up = coarse_upsampler(self.steady_render.as_ref(), self.view_offset, self.coarse.as_ref(), (w, h), step);
        match (self.coarse_only, up) {
            (true, Some(up)) => {
                let mut row = vec![0.0; w];
                up.rows(y, &mut row);
                row[x]
            }
            _ => self.background.get(x, y),
        }
    }
}
