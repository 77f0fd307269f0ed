//! Fusion: the target patches Poisson-fused into the frame (eqs 16–20).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Fusion, FusionSystems, SensorFrame, SimSettings, TargetPatches};
use crate::imaging::fusion::Patch;

/// Fuses the targets.
pub struct FusionPlugin;

impl Plugin for FusionPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, fuse_targets.in_set(FusionSystems));
    }
}

/// One fusion call for all patches (overlapping ones are solved together).
pub fn fuse_targets(
    settings: Res<SimSettings>,
    patches: Res<TargetPatches>,
    mut fusion: ResMut<Fusion>,
    mut sensor: Query<&mut SensorFrame>,
) {
    let Ok(mut sf) = sensor.single_mut() else { return };
    if patches.used == 0 {
        return;
    }
    let list: Vec<Patch<'_>> =
        patches.patches[..patches.used].iter().map(|(rect, values)| Patch { rect: *rect, values }).collect();
    fusion.0.fuse(&mut sf.frame, &list, settings.quality.fusion_guidance, settings.quality.fusion_solver);
}
