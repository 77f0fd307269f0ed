//! Projection: each target's ellipsoid to its exact image ellipse, and the blob drawn for it.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Body, CameraPose, Footprint, Kinematics, Observer, ProjectionSystems, Sensor, Signature, SimSettings};
use crate::imaging::target_blob::{Ellipsoid, EllipsoidProjection, GeneralizedGaussian, project_ellipsoid};

/// Projects the targets.
pub struct ProjectionPlugin;

impl Plugin for ProjectionPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, project_targets.in_set(ProjectionSystems));
    }
}

/// Image ellipse, blob (energy-conserving peak) and region of interest of every target.
///
/// The blob's peak is set so that its integral equals the target's signal: `peak = C · A / ∫shape`, where
/// `C` is the gray a pixel filled by the target would show and `A` the ellipse's area in px². A resolved
/// target (blob ≈ ellipse) peaks at `C`; a sub-pixel one spreads `C·A` over the blur, which is eq 13 with the
/// fill factor of DESIGN.md applied through the optics' point spread. The peak is capped at the gray range.
pub fn project_targets(
    settings: Res<SimSettings>,
    sensor: Query<&Sensor>,
    observer: Query<&CameraPose, With<Observer>>,
    mut targets: Query<(&Kinematics, &Body, &Signature, &mut Footprint), Without<Observer>>,
) {
    let (Ok(sensor), Ok(pose)) = (sensor.single(), observer.single()) else { return };
    let cam = pose.current;
    let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
    let blob_spec = settings.blob;
    let range_cap = sensor.gray.g_max - sensor.gray.g_min;
    for (kin, body, sig, mut fp) in &mut targets {
        let ellipsoid = Ellipsoid {
            center_m: kin.position_m,
            semi_axes_m: body.semi_axes_m,
            body_to_world: body.body_to_world(kin.velocity_m_s),
        };
        fp.range_m = kin.position_m.distance(cam.position_m);
        fp.ellipse = match project_ellipsoid(&ellipsoid, &cam) {
            EllipsoidProjection::Visible(e) => Some(e),
            _ => None,
        };
        fp.blob = None;
        fp.roi = None;
        let Some(ellipse) = fp.ellipse else { continue };
        let mut blob = GeneralizedGaussian::from_ellipse(&ellipse, blob_spec.min_blur_px, blob_spec.beta, 1.0);
        let peak = sig.full_contrast_gray * ellipse.area_px2() / blob.integral();
        blob.peak = if peak.is_finite() { peak.clamp(0.0, range_cap) } else { 0.0 };
        let roi = blob.region_of_interest(blob_spec.roi_fraction, w, h);
        fp.blob = Some(blob);
        if !roi.is_empty() {
            fp.roi = Some(roi);
        }
    }
}
