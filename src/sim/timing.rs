//! Wall-clock time per pipeline stage, when asked for.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{
    FusionSystems, MotionSystems, NoiseSystems, OutputSystems, ProjectionSystems, RenderToTextureSystems,
    TargetsSystems, VibrationSystems,
};

/// Wall-clock time spent in each stage, accumulated over the run (present only when timing is asked for).
#[derive(Resource, Debug, Clone, Default)]
pub struct StageTimings {
    /// Seconds per stage, in the order of [`StageTimings::NAMES`]: each the wall-clock time between the stages
    /// before and after it, but the radiometry's, which is its own time beside the render (and within it), and
    /// the targets', to which the time of their shapes, drawn beside the render, is added.
    pub seconds: [f64; 9],
    /// Steps timed.
    pub steps: u64,
    last: Option<std::time::Instant>,
}

impl StageTimings {
    /// Stage names, in the order they are printed: the pipeline's, but for the radiometry, which runs beside
    /// the render (after the projection).
    pub const NAMES: [&'static str; 9] =
        ["motion", "vibration", "radiometry", "projection", "render", "targets", "fusion", "noise", "output"];

    /// Adds `seconds` to the radiometry's stage: the render's system times the radiometry it runs beside it.
    pub(super) fn add_radiometry(&mut self, seconds: f64) {
        self.seconds[2] += seconds;
    }

    /// Adds `seconds` to the targets' stage: the render's system times the targets' shapes it draws beside the
    /// render.
    pub(super) fn add_target_shapes(&mut self, seconds: f64) {
        self.seconds[5] += seconds;
    }

    /// Mean milliseconds per frame for each stage, by name.
    pub fn mean_ms(&self) -> Vec<(&'static str, f64)> {
        let n = self.steps.max(1) as f64;
        Self::NAMES.iter().zip(self.seconds).map(|(name, s)| (*name, 1e3 * s / n)).collect()
    }
}

/// Records the time since the previous stamp into stage `N − 1` (stamp 0 starts the step, 9 ends it; 3 is not
/// stamped: the radiometry runs beside the render, whose system adds its time to stage 2 itself, and the time of
/// the targets' shapes, also drawn beside the render, to stage 5).
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
                stamp::<2>.after(VibrationSystems).before(ProjectionSystems).run_if(on),
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
