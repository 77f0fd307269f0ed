//! Projection: each target's ellipsoid to its exact image ellipse, and the pixels its image covers.

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;

use super::{Body, CameraPose, Footprint, Kinematics, Observer, ProjectionSystems, Sensor, SimSettings};
use crate::imaging::target_blob::{Ellipsoid, EllipsoidProjection, GeneralizedGaussian, project_ellipsoid};
use crate::imaging::target_psf::psf_region;
use crate::scenario::TargetModel;

/// Projects the targets.
pub struct ProjectionPlugin;

impl Plugin for ProjectionPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, project_targets.in_set(ProjectionSystems));
    }
}

/// Image ellipse and region of interest of every target: the ellipse grown by the PSF's radius (PSF model), or
/// the paper blob's support (paper model, whose unit-peak blob is kept for the targets stage to scale).
pub fn project_targets(
    settings: Res<SimSettings>,
    sensor: Query<&Sensor>,
    observer: Query<&CameraPose, With<Observer>>,
    mut targets: Query<(&Kinematics, &Body, &mut Footprint), Without<Observer>>,
) {
    let (Ok(sensor), Ok(pose)) = (sensor.single(), observer.single()) else { return };
    let cam = pose.current;
    let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
    let blob_spec = settings.blob;
    for (kin, body, mut fp) in &mut targets {
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
        fp.peak_radiance = 0.0;
        fp.patch = None;
        let Some(ellipse) = fp.ellipse else { continue };
        let roi = match (blob_spec.model, &sensor.psf) {
            (TargetModel::Psf, Some(psf)) => psf_region(&ellipse, psf, w, h),
            _ => {
                let blob = GeneralizedGaussian::from_ellipse(&ellipse, blob_spec.min_blur_px, blob_spec.beta, 1.0);
                fp.blob = Some(blob);
                blob.region_of_interest(blob_spec.roi_fraction, w, h)
            }
        };
        if !roi.is_empty() {
            fp.roi = Some(roi);
        }
    }
}
