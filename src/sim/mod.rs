//! The simulation as a Bevy ECS: entities, components, system sets, plugins.
//!
//! Aircraft, the observer, the sky plane and the sensor are entities whose components hold kinematics,
//! material, geometry, sensor data and per-frame results. One fixed step is one sensor frame; its systems run
//! in this order, declared once in [`PipelinePlugin`]:
//!
//! Motion → Vibration → Projection → RenderToTexture (with the targets' radiometry and shapes beside the sky
//! render) → Targets → Fusion → Noise → Output.
//!
//! Systems are thin: they gather components, call into [`crate::physics`], [`crate::imaging`] or
//! [`crate::labels`] (most one function, the render's two side by side), and write the result back. Each
//! completed frame leaves the schedule as a [`FrameReady`] message. A front end adds [`IrSimPlugins`] to its
//! app and [`spawn_scenario`]s a checked scenario into its world; [`headless_app`] is the front end of
//! `irsim record`, `irsim bench` and the tests (each `update()` computes one frame).

mod camera;
mod components;
mod fusion;
mod headless;
mod motion;
mod noise;
mod output;
mod projection;
mod radiometry;
mod render;
mod resources;
mod spawn;
mod targets;
mod timing;

use bevy::app::{App, Plugin, PluginGroup, PluginGroupBuilder};
use bevy::ecs::schedule::{IntoScheduleConfigs, SystemSet};
use bevy::prelude::FixedUpdate;

pub use camera::{VibrationPlugin, resolve_aim, shake_camera};
pub use components::{
    Aim, Aircraft, Body, CameraPose, FlightPath, Footprint, Kinematics, Observer, Sensor, SensorFrame, Shake,
    Signature, Skin, Sky,
};
pub use fusion::{FusionPlugin, fuse_targets};
pub use headless::{
    BEVY_STEP, IdleWork, LatestFrame, build_app, current_frame, drain_frames, drain_frames_world, frame_at,
    headless_app, run_systems_in_order, set_stop_flag, step, with_workers_awake, with_workers_awake_and,
};
pub use motion::{MotionPlugin, advance_trajectories};
pub use noise::{NoisePlugin, read_out};
pub use output::{
    FrameImage, FrameReady, MirrorFrame, OutputPlugin, advance_clock, collect_labels, emit_frame, mirror_frame,
};
pub use projection::{ProjectionPlugin, project_targets};
pub use radiometry::SignatureInputs;
pub use render::{RenderToTexturePlugin, render_sky};
pub use resources::{FrameOutput, FramePool, Fusion, SceneParams, SimClock, SimSettings, TargetPatches, TargetShape};
pub use spawn::{RunOptions, SetupError, despawn_scenario, forget_kept_results, spawn_scenario};
pub use targets::{TargetShapes, TargetsPlugin, draw_targets};
pub use timing::{StageTimings, TimingPlugin};

pub use crate::labels::{EllipseLabel, FrameLabels, TargetLabel};

/// Motion of targets and observer.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct MotionSystems;
/// Camera pointing and vibration.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct VibrationSystems;
/// Ellipsoid → image ellipse.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct ProjectionSystems;
/// Sky plane ray cast into the sensor frame, the dome for the misses, the optics blur; beside them, the
/// targets' apparent radiance and their shapes (the PSF model's).
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

/// Declares the pipeline order and the shared resources.
pub struct PipelinePlugin;

impl Plugin for PipelinePlugin {
    fn build(&self, app: &mut App) {
        app.configure_sets(
            FixedUpdate,
            (
                MotionSystems,
                VibrationSystems,
                ProjectionSystems,
                RenderToTextureSystems,
                TargetsSystems,
                FusionSystems,
                NoiseSystems,
                OutputSystems,
            )
                .chain(),
        );
        app.init_resource::<TargetPatches>().init_resource::<Fusion>().init_resource::<FrameOutput>();
    }
}

/// All of irsim's simulation plugins, in pipeline order.
pub struct IrSimPlugins;

impl PluginGroup for IrSimPlugins {
    fn build(self) -> PluginGroupBuilder {
        PluginGroupBuilder::start::<Self>()
            .add(PipelinePlugin)
            .add(MotionPlugin)
            .add(VibrationPlugin)
            .add(ProjectionPlugin)
            .add(RenderToTexturePlugin)
            .add(TargetsPlugin)
            .add(FusionPlugin)
            .add(NoisePlugin)
            .add(OutputPlugin)
    }
}
