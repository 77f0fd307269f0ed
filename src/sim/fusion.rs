//! Fusion: the target patches Poisson-fused into the frame (eqs 16–20).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Fusion, FusionSystems, SensorFrame, SimSettings, TargetPatches};
use crate::imaging::fusion::{Guidance, Patch};

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
    let q = &settings.quality;
    let list = |additive: bool| -> Vec<Patch<'_>> {
        let used = patches.patches[..patches.used].iter().zip(&patches.additive);
        used.filter(|(_, a)| **a == additive).map(|((rect, values), _)| Patch { rect: *rect, values }).collect()
    };
    let faint = list(true);
    if !faint.is_empty() {
        fusion.0.fuse(&mut sf.frame, &faint, Guidance::Additive, q.fusion_solver);
    }
    let fused = list(false);
    if !fused.is_empty() {
        fusion.0.fuse(&mut sf.frame, &fused, q.fusion_guidance, q.fusion_solver);
    }
}
