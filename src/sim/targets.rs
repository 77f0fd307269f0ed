//! Targets: the radiance each visible target adds over its background, as the projected ellipse convolved
//! with the optics PSF (default) or the paper's generalized Gaussian (eqs 11–12).
//!
//! With the PSF, a target's patch is its shape (the ellipse ⊗ the PSF at unit contrast) times its contrast
//! against the background at its centre. The shape needs neither the background nor the radiometry, so the
//! render's system draws it beside the sky render ([`TargetShapes`]), and the targets stage, once the background
//! is known, only scales it ([`draw_targets`]).

use bevy::app::{App, Plugin};
use bevy::ecs::prelude::*;
use bevy::ecs::system::SystemParam;
use bevy::prelude::FixedUpdate;
use rayon::prelude::*;

use super::{Footprint, Sensor, SensorFrame, Signature, SimSettings, TargetPatches, TargetShape, TargetsSystems};
use crate::imaging::target_psf::{render_target, render_target_shape, scale_patch};
use crate::scenario::TargetModel;

/// Draws the target patches.
pub struct TargetsPlugin;

impl Plugin for TargetsPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(FixedUpdate, draw_targets.in_set(TargetsSystems));
    }
}

/// What the targets' shapes are drawn from: each target's footprint (from the projection) and the sensor's
/// PSF. The shapes need no background, so the render's system draws them beside the render, after the
/// radiometry ([`super::render_sky`]); [`draw_targets`] then scales each by its target's contrast.
#[derive(SystemParam)]
pub struct TargetShapes<'w, 's> {
    settings: Res<'w, SimSettings>,
    sensor: Query<'w, 's, &'static Sensor>,
    targets: Query<'w, 's, (Entity, &'static Footprint)>,
    patches: ResMut<'w, TargetPatches>,
}

impl TargetShapes<'_, '_> {
    /// Draws the shape (the projected ellipse ⊗ the PSF, unit amplitude) of every target in view that the PSF
    /// model draws, each into a reused buffer, in parallel (a target drawn alone may split its patch across the
    /// threads), with the same values as [`render_target`] before its scaling.
    pub fn draw(&mut self) {
        let Self { settings, sensor, targets, patches } = self;
        patches.shapes_used = 0;
        let Ok(sensor) = sensor.single() else { return };
        let (TargetModel::Psf, Some(psf)) = (settings.blob.model, &sensor.psf) else { return };
        let patches = &mut **patches;
        for (target, fp) in targets {
            let (Some(ellipse), Some(rect)) = (fp.ellipse, fp.roi) else { continue };
            if patches.shapes.len() == patches.shapes_used {
                patches.shapes.push(TargetShape { target, rect, ellipse, values: Vec::new() });
            }
            // the entry's buffer is kept from frame to frame
            let shape = &mut patches.shapes[patches.shapes_used];
            (shape.target, shape.rect, shape.ellipse) = (target, rect, ellipse);
            shape.values.resize(rect.width() * rect.height(), 0.0);
            patches.shapes_used += 1;
        }
        let shapes = &mut patches.shapes[..patches.shapes_used];
        let spread = shapes.len() == 1;
        let spec = settings.blob.target_psf();
        shapes.par_iter_mut().with_max_len(1).for_each(|s| {
            render_target_shape(&s.ellipse, psf, &spec, s.rect, &mut s.values, spread);
        });
    }
}

/// Renders each visible target into a reused patch buffer.
///
/// The target replaces the background it covers: a pixel filled by it receives its apparent radiance
/// `L_app` instead of the sky's `L_bg` (the noise-free, blurred background at the ellipse's centre), so the
/// patch carries `ΔL = L_app − L_bg` times the fraction of the pixel's PSF-weighted footprint it covers: the
/// ellipse ⊗ PSF sampled at the pixel centres, or, in the paper model, a generalized Gaussian of the same
/// integral (`ΔL·A/∫shape`, A the ellipse's area in px²). A PSF target's shape drawn beside the render
/// ([`TargetShapes`]) becomes its patch, scaled by `ΔL`; one without (a target the render's system did not see)
/// is drawn here, with the same values.
pub fn draw_targets(
    settings: Res<SimSettings>,
    mut patches: ResMut<TargetPatches>,
    mut sensor: Query<(&Sensor, &mut SensorFrame)>,
    mut targets: Query<(Entity, &Signature, &mut Footprint)>,
) {
    let Ok((sensor, mut sf)) = sensor.single_mut() else { return };
    let sf = &mut *sf;
    if sf.handed_over {
        // the render became the frame (`SensorFrame::background`): what the labels read of it, kept before the
        // fusion changes the frame
        let (w, h) = (sf.frame.width(), sf.frame.height());
        let (frame, background) = (sf.frame.pixels(), sf.background.pixels_mut());
        for (_, _, fp) in &targets {
            let Some(r) = fp.roi.and_then(|roi| crate::labels::clutter_window(roi, w, h)) else { continue };
            for y in r.y0..r.y1 {
                let row = y * w + r.x0..y * w + r.x1;
                background[row.clone()].copy_from_slice(&frame[row]);
            }
        }
    }
    // the frame holds the render until the fusion, whichever buffer it was made in
    let sky = if sf.handed_over { &sf.frame } else { &sf.background };
    let patches = &mut *patches;
    patches.used = 0;
    let (w, h) = (sky.width(), sky.height());
    // first the targets to draw, each given the next patch buffer (in the query's order, as before) ...
    let mut jobs = Vec::new();
    let mut shapes = patches.shapes_used;
    for (entity, sig, mut fp) in &mut targets {
        let (Some(ellipse), Some(roi), Some(signal)) = (fp.ellipse, fp.roi, sig.signal) else { continue };
        let (cx, cy) = (ellipse.center.x.floor(), ellipse.center.y.floor());
        let bg = if cx >= 0.0 && cy >= 0.0 && (cx as usize) < w && (cy as usize) < h {
            f64::from(sky.get(cx as usize, cy as usize))
        } else {
            // off-frame centre: the nearest pixel of the region
            let x = (cx.max(roi.x0 as f64) as usize).min(roi.x1 - 1);
            let y = (cy.max(roi.y0 as f64) as usize).min(roi.y1 - 1);
            f64::from(sky.get(x, y))
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
        // the shape drawn beside the render, if it was: its buffer becomes the patch
        let shape = patches.shapes[..shapes].iter().position(|s| s.target == entity && s.rect == roi);
        let drawn = match shape {
            Some(k) => {
                std::mem::swap(values, &mut patches.shapes[k].values);
                // the shapes not yet taken stay in the first `shapes` entries
                shapes -= 1;
                patches.shapes.swap(k, shapes);
                true
            }
            None => {
                values.resize(roi.width() * roi.height(), 0.0);
                false
            }
        };
        jobs.push((fp, ellipse, delta, bg, 0.0f64, drawn));
        patches.used += 1;
    }
    // the shapes not taken (of targets not drawn this frame) are the only ones left
    patches.shapes_used = shapes;
    // ... then drawn (or their shapes scaled) in parallel, each into its own buffer (the same values as one after
    // the other; a target drawn alone may split its patch across the threads) ...
    let spread = jobs.len() == 1;
    jobs.par_iter_mut().zip(&mut patches.patches[..patches.used]).with_max_len(1).for_each(
        |((fp, ellipse, delta, _, peak, drawn), (roi, values))| {
            *peak = match (settings.blob.model, &sensor.psf, fp.blob) {
                (TargetModel::Psf, Some(_), _) if *drawn => f64::from(scale_patch(values, *delta as f32)),
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
    for (k, (mut fp, _, _, bg, peak, _)) in jobs.into_iter().enumerate() {
        fp.peak_radiance = peak;
        fp.patch = Some(k);
        // a target whose peak is under the set fraction of the noise is added rather than fused
        let faint =
            (peak * sensor.dn_per_radiance).abs() < settings.quality.fusion_skip_below_sigma * sensor.noise_dn(bg);
        patches.additive.push(faint);
    }
    // the frame stops being the render once the fusion writes it (and the output hands it on): from here on the
    // windows kept in the background are where the render is read (a second run of this stage reads them)
    sf.handed_over = false;
}
