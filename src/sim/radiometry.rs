//! Radiometry: skin temperature, radiance, reflection, transmittance and path radiance per target, in the
//! detector's measure. It reads the targets, the observer and the scene and writes only the targets'
//! [`Signature`]s, which neither the projection nor the sky render touch: the render's system runs it beside the
//! render (see [`super::render_sky`]), on whichever of the pool's threads is free, followed there by the targets'
//! shapes ([`super::TargetShapes`]).

use bevy::ecs::prelude::*;

use super::{Body, CameraPose, Kinematics, Observer, SceneParams, Sensor, Signature, SimSettings, Skin};
use crate::physics::lowtran::{ALTITUDE_TOLERANCE_SCALE_KM, AtmosphereError, PathSpectrum};
use crate::physics::lowtran_paths::LowtranAtmosphere;
use crate::physics::signal::{ApparentContext, Sight, TargetState, apparent_radiance};
use crate::physics::skin::mach_number;
use glam::DVec3;
use rayon::prelude::*;

/// What the radiometry reads and writes: the scene, the sensor, the observer's pose, and each target's state
/// and [`Signature`].
#[derive(bevy::ecs::system::SystemParam)]
pub struct SignatureInputs<'w, 's> {
    scene: Res<'w, SceneParams>,
    settings: Res<'w, SimSettings>,
    sensor: Query<'w, 's, &'static Sensor>,
    observer: Query<'w, 's, &'static CameraPose, With<Observer>>,
    targets:
        Query<'w, 's, (&'static Kinematics, &'static Body, &'static Skin, &'static mut Signature), Without<Observer>>,
}

impl SignatureInputs<'_, '_> {
    /// Runs the radiometric chain for every target whose inputs changed since its last computation (by more
    /// than `[quality] radiometry_tolerance`, see `unchanged` in this module).
    pub fn update(&mut self) {
        let Self { scene, settings, sensor, observer, targets } = self;
        let (scene, settings): (&SceneParams, &SimSettings) = (scene, settings);
        let (Ok(sensor), Ok(pose)) = (sensor.single(), observer.single()) else { return };
        let eye = pose.steady.position_m;
        let ctx = ApparentContext {
            band: sensor.resolved.model.band,
            measure: sensor.measure(),
            air: scene.air,
            stagnation: scene.stagnation,
            sun: scene.sun,
            atmosphere: &scene.atmosphere,
            reflection: Default::default(),
            quadrature: &scene.quadrature,
            planck: settings.quality.planck,
            // in radiance at the aperture (infinite, so always skipped, where no radiance gives a DN)
            reflection_skip_below: match settings.quality.reflection_skip_below_dn {
                dn if dn > 0.0 => dn / sensor.dn_per_radiance,
                _ => 0.0,
            },
            sight: None,
        };
        let tolerance = settings.quality.radiometry_tolerance;
        // each target's chain reads only its own components and the scene: the targets run in parallel (rayon's
        // pool, whose workers the frame keeps awake), each computed exactly as alone
        let mut all: Vec<_> = targets.iter_mut().collect();
        all.par_iter_mut().with_max_len(1).for_each(|(kin, body, skin, sig)| {
            let p = kin.position_m;
            let dir = kin.velocity_m_s.normalize_or_zero();
            let key = [p.x, p.y, p.z, dir.x, dir.y, dir.z, kin.velocity_m_s.length(), eye.x, eye.y, eye.z];
            if sig.key.is_some_and(|old| unchanged(&old, &key, tolerance)) {
                return;
            }
            let mach = match skin.mach {
                Some(m) => m,
                None => mach_number(kin.velocity_m_s.length(), scene.air_temp_k(p.z)),
            };
            let state = TargetState {
                position_m: p,
                mach,
                emissivity: skin.emissivity,
                heating_k: skin.heating_k,
                brdf: skin.brdf,
                semi_axes_m: body.semi_axes_m,
                attitude: body.body_to_world(kin.velocity_m_s),
            };
            let sig = &mut **sig;
            let sight = match scene.atmosphere.lowtran() {
                Some(lowtran) => sig
                    .sight
                    .update(lowtran, eye, p, settings.quality.atmosphere_tolerance)
                    .map(|spectrum| {
                        let (sun_weights, measure_ratios) = (lowtran.sun_weights(), lowtran.measure_ratios());
                        Some(Sight { spectrum, sun_weights, measure_ratios, skin_weights: &sig.skin_weights })
                    })
                    .map_err(|e| e.to_string()),
                None => Ok(None),
            };
            let result = sight.and_then(|sight| {
                let ctx = ApparentContext { reflection: skin.reflection, sight, ..ctx };
                apparent_radiance(&state, eye, &ctx).map_err(|e| e.to_string())
            });
            (sig.signal, sig.error) = match result {
                Ok(signal) => (Some(signal), None),
                Err(e) => (None, Some(e)),
            };
            sig.mach = mach;
            sig.key = Some(key);
        });
    }
}

/// A target's line of sight through a LOWTRAN atmosphere: the spectrum last interpolated from the table and the
/// geometry it was interpolated for, and the spectrum in use now (stretched from it, see
/// [`crate::scenario::Quality::atmosphere_tolerance`]).
#[derive(Debug, Clone, Default)]
pub struct Sightline {
    base: Option<(DVec3, DVec3, PathSpectrum)>,
    current: Option<PathSpectrum>,
}

impl Sightline {
    /// The spectrum of the line of sight from `eye_m` to `target_m`: interpolated from the table again when the
    /// range has moved by more than `tolerance` of itself or either altitude by more than `tolerance` times
    /// [`ALTITUDE_TOLERANCE_SCALE_KM`] since the last interpolation (0: whenever either end moved), else the last
    /// interpolation stretched to the new range.
    ///
    /// # Errors
    /// [`AtmosphereError`] for a line of sight outside the table.
    pub fn update(
        &mut self,
        atmosphere: &LowtranAtmosphere,
        eye_m: DVec3,
        target_m: DVec3,
        tolerance: f64,
    ) -> Result<&PathSpectrum, AtmosphereError> {
        let range = eye_m.distance(target_m);
        let reuse = match &self.base {
            Some((e0, t0, _)) if tolerance > 0.0 => {
                let r0 = e0.distance(*t0);
                let dh_m = tolerance * ALTITUDE_TOLERANCE_SCALE_KM * 1000.0;
                r0 > 0.0
                    && (range - r0).abs() <= tolerance * r0
                    && (eye_m.z - e0.z).abs() <= dh_m
                    && (target_m.z - t0.z).abs() <= dh_m
            }
            Some((e0, t0, _)) => *e0 == eye_m && *t0 == target_m,
            None => false,
        };
        if let (true, Some((e0, t0, base)), Some(current)) = (reuse, &self.base, &mut self.current) {
            if *e0 == eye_m && *t0 == target_m {
                current.clone_from(base);
            } else {
                base.stretched(range / e0.distance(*t0), current);
            }
        } else {
            let spectrum = atmosphere.sight(eye_m, target_m)?;
            self.current = Some(spectrum.clone());
            self.base = Some((eye_m, target_m, spectrum));
        }
        self.current.as_ref().ok_or_else(|| AtmosphereError::Table("no line of sight was interpolated".into()))
    }
}

/// Whether a target's radiometry inputs `new` (position, unit heading, speed, observer position) are within
/// `tolerance` of `old`, those of its last computation: each position within `tolerance` of the old range, the
/// heading within `tolerance` rad, the speed within `tolerance` of the old speed. With 0, only equal inputs are.
pub fn unchanged(old: &[f64; 10], new: &[f64; 10], tolerance: f64) -> bool {
    if tolerance <= 0.0 {
        return old == new;
    }
    let v = |k: &[f64; 10], i: usize| glam::DVec3::new(k[i], k[i + 1], k[i + 2]);
    let range = v(old, 0).distance(v(old, 7));
    v(old, 0).distance(v(new, 0)) <= tolerance * range
        && v(old, 7).distance(v(new, 7)) <= tolerance * range
        && v(old, 3).distance(v(new, 3)) <= tolerance
        && (old[6] - new[6]).abs() <= tolerance * old[6]
}

#[cfg(test)]
mod tests {
    use super::unchanged;

    #[test]
    fn tolerance_bounds_each_input() {
        // target 1000 m east of the observer, heading north at 100 m/s
        let old = [1000.0, 0.0, 0.0, 0.0, 1.0, 0.0, 100.0, 0.0, 0.0, 0.0];
        assert!(unchanged(&old, &old, 0.0));
        let mut moved = old;
        moved[1] = 0.9; // 0.9 m: within 1e-3 of the range
        assert!(!unchanged(&old, &moved, 0.0));
        assert!(unchanged(&old, &moved, 1e-3));
        moved[1] = 1.1;
        assert!(!unchanged(&old, &moved, 1e-3));
        let mut eye = old;
        eye[9] = 1.1; // the observer climbed 1.1 m
        assert!(!unchanged(&old, &eye, 1e-3));
        let mut faster = old;
        faster[6] = 100.2;
        assert!(!unchanged(&old, &faster, 1e-3));
        faster[6] = 100.05;
        assert!(unchanged(&old, &faster, 1e-3));
        let mut turned = old;
        let a: f64 = 2e-3; // 2 mrad
        (turned[3], turned[4]) = (a.sin(), a.cos());
        assert!(!unchanged(&old, &turned, 1e-3));
        assert!(unchanged(&old, &turned, 3e-3));
    }
}
