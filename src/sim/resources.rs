//! The simulation's resources: clock, run settings, scene physics, per-frame scratch.

use bevy::ecs::prelude::*;

use crate::imaging::frame::Frame;
use crate::imaging::fusion::PoissonFusion;
use crate::imaging::target_blob::{ImageEllipse, PixelRect};
use crate::labels::FrameLabels;
use crate::physics::atmosphere::AirTemperature;
use crate::physics::reflection::{SphereQuadrature, Sun};
use crate::physics::skin::StagnationModel;
use crate::physics::transmittance::SceneAtmosphere;
use crate::scenario::{BlobSettings, Quality};

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
    /// Keep the whole noise-free background of the current view after each frame (a window reads any pixel of it,
    /// [`SensorFrame::background_at`](super::SensorFrame::background_at)). Without it, while the camera moves
    /// frame after frame, the render's buffer becomes the frame instead of being copied into it (see
    /// [`SensorFrame::background`](super::SensorFrame::background)).
    pub whole_background: bool,
    /// Every accuracy switch (the fusion's solver and guidance are read from it each frame).
    pub quality: Quality,
    /// How targets are drawn.
    pub blob: BlobSettings,
    /// SNR from which a target is `detectable`.
    pub detectable_snr: f64,
    /// Fraction of a target's peak that puts a pixel in its mask.
    pub mask_fraction: f64,
}

/// The scene's physics.
#[derive(Resource, Debug, Clone)]
pub struct SceneParams {
    /// The air's temperature against altitude.
    pub air: AirTemperature,
    /// Stagnation constants.
    pub stagnation: StagnationModel,
    /// The sun.
    pub sun: Sun,
    /// Transmittance and path radiance: an override, or LOWTRAN's for the scene's weather.
    pub atmosphere: SceneAtmosphere,
    /// Quadrature for ellipsoid-averaged reflection.
    pub quadrature: SphereQuadrature,
}

impl SceneParams {
    /// Air temperature at `altitude_m` (clamped to the model's range), K.
    pub fn air_temp_k(&self, altitude_m: f64) -> f64 {
        self.air.clamped_k(altitude_m)
    }
}

/// Reusable buffers of target patches for the fusion stage.
#[derive(Resource, Debug, Default)]
pub struct TargetPatches {
    /// `(rect, values)` per visible target; the vectors are reused.
    pub patches: Vec<(PixelRect, Vec<f32>)>,
    /// How many entries of `patches` are in use this frame.
    pub used: usize,
    /// Per entry: added to the frame instead of fused (a target too faint for the fusion to matter,
    /// `[quality] fusion_skip_below_sigma`).
    pub additive: Vec<bool>,
    /// The targets' shapes (unit amplitude), drawn beside the render ([`TargetShapes`](super::TargetShapes)),
    /// their buffers reused; the targets stage scales each into its patch.
    pub shapes: Vec<TargetShape>,
    /// How many entries of `shapes` hold a shape drawn this frame and not yet taken: all that were drawn until
    /// the targets stage, which takes those of the targets it draws (and leaves the others first).
    pub shapes_used: usize,
}

/// A target's shape drawn beside the render: the projected ellipse ⊗ the PSF at unit contrast on `rect`.
#[derive(Debug)]
pub struct TargetShape {
    /// The target it is of.
    pub target: Entity,
    /// Its region of interest (the footprint's).
    pub rect: PixelRect,
    /// Its image ellipse (the footprint's).
    pub ellipse: ImageEllipse,
    /// Row-major over `rect`.
    pub values: Vec<f32>,
}

/// The fusion engine (planned transforms, buffers).
#[derive(Resource, Debug, Default)]
pub struct Fusion(pub PoissonFusion);

/// The ground truth of the frame being completed, until [`FrameReady`](super::FrameReady) carries it away.
#[derive(Resource, Debug, Default, Clone)]
pub struct FrameOutput {
    /// Ground truth.
    pub labels: FrameLabels,
    /// Per-pixel target id (0 = sky), when masks are on.
    pub mask: Option<Vec<u8>>,
}

/// Frame buffers given back by a consumer of [`FrameReady`](super::FrameReady), reused for the next frames so
/// that a run that only looks at its frames allocates none.
#[derive(Resource, Debug, Default)]
pub struct FramePool(pub Vec<Frame>);

impl FramePool {
    /// A buffer of `width × height` (contents unspecified), from the pool or new.
    pub fn take(&mut self, width: usize, height: usize) -> Frame {
        match self.0.iter().position(|f| f.width() == width && f.height() == height) {
            Some(i) => self.0.swap_remove(i),
            None => Frame::new(width, height),
        }
    }

    /// Gives `frame` back for reuse (a few are kept: as many as a recorder's encoders hold at once).
    pub fn give_back(&mut self, frame: Frame) {
        if self.0.len() < 8 {
            self.0.push(frame);
        }
    }
}
