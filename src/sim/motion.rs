//! Motion: every trajectory evaluated at the frame's time (analytic, no integration drift).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{FlightPath, Kinematics, MotionSystems, SimClock};

/// Moves targets and observer.
pub struct MotionPlugin;

impl Plugin for MotionPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, advance_trajectories.in_set(MotionSystems));
    }
}

/// Sets each entity's position and velocity to its trajectory's value at t = start + frame · dt.
pub fn advance_trajectories(clock: Res<SimClock>, mut movers: Query<(&FlightPath, &mut Kinematics)>) {
    let t = clock.t_s();
    for (path, mut kin) in &mut movers {
        let (position_m, velocity_m_s) = path.0.state(t);
        kin.set_if_neq(Kinematics { position_m, velocity_m_s });
    }
}
