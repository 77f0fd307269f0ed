//! Targets: a generalized-Gaussian patch per visible target on its region of interest (eqs 11–12).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Footprint, SimSettings, TargetPatches, TargetsSystems};

/// Draws the target patches.
pub struct TargetsPlugin;

impl Plugin for TargetsPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, draw_targets.in_set(TargetsSystems));
    }
}

/// Renders each visible target's blob into a reused patch buffer.
pub fn draw_targets(settings: Res<SimSettings>, mut patches: ResMut<TargetPatches>, targets: Query<&Footprint>) {
    let patches = &mut *patches;
    patches.used = 0;
    for fp in &targets {
        let (Some(blob), Some(roi)) = (fp.blob, fp.roi) else { continue };
        if blob.peak <= 0.0 {
            continue;
        }
        if patches.patches.len() == patches.used {
            patches.patches.push((roi, Vec::new()));
        }
        let (rect, values) = &mut patches.patches[patches.used];
        *rect = roi;
        values.resize(roi.width() * roi.height(), 0.0);
        blob.render_patch(roi, settings.blob.sampling, values);
        patches.used += 1;
    }
}
