//! Targets: the radiance each visible target adds over its background, as the projected ellipse convolved
//! with the optics PSF (default) or the paper's generalized Gaussian (eqs 11–12).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::prelude::FixedUpdate;
use rayon::prelude::*;

use super::{Footprint, Sensor, SensorFrame, Signature, SimSettings, TargetPatches, TargetsSystems};
use crate::imaging::target_psf::render_target;
use crate::scenario::TargetModel;

/// Draws the target patches.
pub struct TargetsPlugin;

impl Plugin for TargetsPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, draw_targets.in_set(TargetsSystems));
    }
}

/// Renders each visible target into a reused patch buffer.
///
/// The target replaces the background it covers: a pixel filled by it receives its apparent radiance
/// `L_app` instead of the sky's `L_bg` (the noise-free, blurred background at the ellipse's centre), so the
/// patch carries `ΔL = L_app − L_bg` times the fraction of the pixel's PSF-weighted footprint it covers: the
/// ellipse ⊗ PSF sampled at the pixel centres, or, in the paper model, a generalized Gaussian of the same
/// integral (`ΔL·A/∫shape`, A the ellipse's area in px²).
pub fn draw_targets(
    settings: Res<SimSettings>,
    mut patches: ResMut<TargetPatches>,
    sensor: Query<(&Sensor, &SensorFrame)>,
    mut targets: Query<(&Signature, &mut Footprint)>,
) {
    let Ok((sensor, sf)) = sensor.single() else { return };
    let patches = &mut *patches;
    patches.used = 0;
    let (w, h) = (sf.background.width(), sf.background.height());
    // first the targets to draw, each given the next patch buffer (in the query's order, as before) ...
    let mut jobs = Vec::new();
    for (sig, mut fp) in &mut targets {
        let (Some(ellipse), Some(roi), Some(signal)) = (fp.ellipse, fp.roi, sig.signal) else { continue };
        let (cx, cy) = (ellipse.center.x.floor(), ellipse.center.y.floor());
        let bg = if cx >= 0.0 && cy >= 0.0 && (cx as usize) < w && (cy as usize) < h {
            f64::from(sf.background.get(cx as usize, cy as usize))
        } else {
            // off-frame centre: the nearest pixel of the region
            let x = (cx.max(roi.x0 as f64) as usize).min(roi.x1 - 1);
            let y = (cy.max(roi.y0 as f64) as usize).min(roi.y1 - 1);
            f64::from(sf.background.get(x, y))
        };
        fp.background_radiance = bg;
        fp.patch = None;
        let delta = signal.apparent_radiance - bg;
        if !(delta.is_finite() && delta != 0.0) {
            continue;
        }
        let drawable = match (settings.blob.model, &sensor.psf, fp.blob) {
            (TargetModel::Psf, Some(_), _) => true,
            (_, _, blob) => blob.is_some(),
        };
        if !drawable {
            continue;
        }
        if patches.patches.len() == patches.used {
            patches.patches.push((roi, Vec::new()));
        }
        let (rect, values) = &mut patches.patches[patches.used];
        *rect = roi;
        values.resize(roi.width() * roi.height(), 0.0);
        jobs.push((fp, ellipse, delta, bg, 0.0f64));
        patches.used += 1;
    }
    // ... then drawn in parallel, each into its own buffer (the same values as one after the other; a target
    // drawn alone may split its patch across the threads) ...
    let spread = jobs.len() == 1;
    jobs.par_iter_mut().zip(&mut patches.patches[..patches.used]).with_max_len(1).for_each(
        |((fp, ellipse, delta, _, peak), (roi, values))| {
            *peak = match (settings.blob.model, &sensor.psf, fp.blob) {
                (TargetModel::Psf, Some(psf), _) => f64::from(render_target(
                    ellipse,
                    *delta as f32,
                    psf,
                    &settings.blob.target_psf(),
                    *roi,
                    values,
                    spread,
                )),
                (_, _, Some(mut blob)) => {
                    blob.peak = *delta * ellipse.area_px2() / blob.integral();
                    blob.render_patch(*roi, settings.blob.sampling, values);
                    fp.blob = Some(blob);
                    values.iter().fold(0.0f64, |m, &v| if f64::from(v).abs() > m.abs() { f64::from(v) } else { m })
                }
                _ => unreachable!("only drawable targets are listed"),
            };
        },
    );
    // ... and their peaks and fusion mode recorded
    patches.additive.clear();
    for (k, (mut fp, _, _, bg, peak)) in jobs.into_iter().enumerate() {
        fp.peak_radiance = peak;
        fp.patch = Some(k);
        // a target whose peak is under the set fraction of the noise is added rather than fused
        let faint =
            (peak * sensor.dn_per_radiance).abs() < settings.quality.fusion_skip_below_sigma * sensor.noise_dn(bg);
        patches.additive.push(faint);
    }
}
