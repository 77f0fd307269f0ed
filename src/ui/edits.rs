//! The edit panel: per-target trajectory, body and skin; the sensor's band, noise, vibration, target sampling and
//! fusion; the sun. Widgets change the [`Session`](crate::scenario::edit::Session)'s draft; the draft is validated
//! like a file and put in use when the mouse button is up (a drag changes it once, at the end), and a refused
//! draft shows the validator's message while the last good scenario stays in use.

use bevy_egui::egui;
use glam::DVec3;

use super::Viewer;
use crate::imaging::fusion::{Guidance, Solver};
use crate::imaging::sky_plane::Sampling;
use crate::imaging::target_blob::BlobSampling;
use crate::physics::planck::Band;
use crate::physics::reflection::ReflectionGeometry;
use crate::scenario::edit::shift_altitude;
use crate::scenario::trajectory::TrajectorySpec;
use crate::scenario::{FieldError, QualityPreset, QualitySpec, TargetModel};

/// Where a new target goes: the next click on the sensor image places it at `range_m` along that pixel's line
/// of sight, flying level at `speed_m_s` on `heading_deg`.
#[derive(Debug, Clone, Copy)]
pub struct NewTarget {
    /// Waiting for the click.
    pub armed: bool,
    /// Distance from the camera, m.
    pub range_m: f64,
    /// Speed, m/s.
    pub speed_m_s: f64,
    /// Heading, degrees clockwise from north.
    pub heading_deg: f64,
}

impl Default for NewTarget {
    fn default() -> Self {
        Self { armed: false, range_m: 1500.0, speed_m_s: 20.0, heading_deg: 90.0 }
    }
}

fn num(ui: &mut egui::Ui, label: &str, value: &mut f64, speed: f64, unit: &str) -> bool {
    ui.horizontal(|ui| {
        let r = ui.add(egui::DragValue::new(value).speed(speed).suffix(unit));
        ui.label(label);
        r.changed()
    })
    .inner
}

fn vec3(ui: &mut egui::Ui, label: &str, v: &mut DVec3, speed: f64, unit: &str) -> bool {
    ui.horizontal(|ui| {
        let mut changed = false;
        for c in [&mut v.x, &mut v.y, &mut v.z] {
            changed |= ui.add(egui::DragValue::new(c).speed(speed).suffix(unit)).changed();
        }
        ui.label(label);
        changed
    })
    .inner
}

/// An optional value: unticked is the preset's or default value (`None`), ticked sets it.
fn opt_num(ui: &mut egui::Ui, label: &str, value: &mut Option<f64>, fallback: f64, speed: f64, unit: &str) {
    ui.horizontal(|ui| {
        let mut set = value.is_some();
        if ui.checkbox(&mut set, "").on_hover_text("unticked: the preset's value").changed() {
            *value = set.then_some(value.unwrap_or(fallback));
        }
        match value {
            Some(v) => {
                ui.add(egui::DragValue::new(v).speed(speed).suffix(unit));
            }
            None => {
                ui.weak("preset");
            }
        }
        ui.label(label);
    });
}

/// Draws the edit panel and puts the draft in use when it changed and the mouse is up.
pub fn edit_panel(ui: &mut egui::Ui, v: &mut Viewer) {
    let mut local_error: Option<FieldError> = None;
    let n = v.session.draft.targets.len();
    ui.horizontal(|ui| {
        ui.label("target");
        let name = v.session.draft.targets.get(v.selected).map_or("—".to_owned(), |t| t.name.clone());
        egui::ComboBox::from_id_salt("edit_target").selected_text(name).show_ui(ui, |ui| {
            for (i, t) in v.session.draft.targets.iter().enumerate() {
                ui.selectable_value(&mut v.selected, i, format!("{} {}", i + 1, t.name));
            }
        });
        if n > 0 && ui.button("remove").clicked() {
            let i = v.selected.min(n - 1);
            let target = v.session.draft.targets[i].clone();
            v.target_status = match v.session.remove_target(i) {
                Ok(()) => {
                    v.selected = v.selected.saturating_sub(1);
                    let text = format!("removed {}", target.name);
                    v.removed = Some((i, target));
                    text
                }
                Err(e) => format!("not removed: {}: {}", e.path, e.message),
            };
        }
    });
    // the direction a speed edit keeps when the draft's velocity is zero on the way (typing 0.5 passes through 0)
    let applied_direction = match v.session.applied.spec.targets.get(v.selected).map(|t| &t.trajectory) {
        Some(TrajectorySpec::ConstantVelocity { velocity_m_s, .. }) => velocity_m_s.try_normalize(),
        _ => None,
    };
    if let Some(t) = v.session.draft.targets.get_mut(v.selected) {
        egui::CollapsingHeader::new("trajectory").default_open(true).show(ui, |ui| {
            match &mut t.trajectory {
                TrajectorySpec::ConstantVelocity { position_m, velocity_m_s } => {
                    ui.weak("constant velocity");
                    vec3(ui, "position at t = 0", position_m, 1.0, " m");
                    vec3(ui, "velocity", velocity_m_s, 0.1, " m/s");
                    let mut speed = velocity_m_s.length();
                    if num(ui, "speed", &mut speed, 0.1, " m/s") {
                        let dir = velocity_m_s.try_normalize().or(applied_direction).unwrap_or(DVec3::X);
                        // a speed is not negative: below 0 it stays 0 (the direction is the velocity's)
                        *velocity_m_s = dir * speed.max(0.0);
                    }
                }
                TrajectorySpec::CoordinatedTurn {
                    center_m,
                    radius_m,
                    speed_m_s,
                    start_bearing_deg,
                    clockwise,
                    climb_m_s,
                } => {
                    ui.weak("coordinated turn");
                    vec3(ui, "centre at t = 0", center_m, 1.0, " m");
                    num(ui, "radius", radius_m, 1.0, " m");
                    num(ui, "speed", speed_m_s, 0.1, " m/s");
                    num(ui, "start bearing", start_bearing_deg, 0.5, "°");
                    num(ui, "climb", climb_m_s, 0.1, " m/s");
                    ui.checkbox(clockwise, "clockwise");
                }
                TrajectorySpec::Polynomial { x_m, y_m, z_m } => {
                    ui.weak("polynomial coefficients (m, m/s, m/s², …)");
                    for (axis, c) in [("x", x_m), ("y", y_m), ("z", z_m)] {
                        ui.horizontal(|ui| {
                            ui.label(axis);
                            for a in c.iter_mut() {
                                ui.add(egui::DragValue::new(a).speed(0.1));
                            }
                        });
                    }
                }
                TrajectorySpec::Waypoints { points } => {
                    ui.weak("waypoints: t s, x, y, z m");
                    for p in points.iter_mut() {
                        ui.horizontal(|ui| {
                            for a in p.iter_mut() {
                                ui.add(egui::DragValue::new(a).speed(0.5));
                            }
                        });
                    }
                }
                TrajectorySpec::Csv { path } => {
                    ui.weak(format!("samples from {path} (edit the file)"));
                }
            }
            ui.horizontal(|ui| {
                ui.label("altitude");
                for dz in [-100.0, -10.0, 10.0, 100.0] {
                    if ui.button(format!("{dz:+}")).clicked() {
                        shift_altitude(&mut t.trajectory, dz);
                    }
                }
                ui.label("m");
            });
        });
        egui::CollapsingHeader::new("body and skin").default_open(false).show(ui, |ui| {
            vec3(ui, "semi-axes", &mut t.semi_axes_m, 0.01, " m");
            opt_num(ui, "Mach (unticked: from the speed)", &mut t.mach, 0.1, 0.001, "");
            num(ui, "emissivity", &mut t.emissivity, 0.005, "");
            num(ui, "internal heating", &mut t.heating_k, 0.5, " K");
            num(ui, "BRDF diffuse kd", &mut t.brdf.kd, 0.005, "");
            num(ui, "BRDF specular ks", &mut t.brdf.ks, 0.005, "");
            num(ui, "BRDF Fresnel f0", &mut t.brdf.f0, 0.005, "");
            num(ui, "BRDF roughness", &mut t.brdf.roughness, 0.005, "");
        });
    }
    egui::CollapsingHeader::new("add a target").default_open(false).show(ui, |ui| {
        let a = &mut v.new_target;
        num(ui, "range", &mut a.range_m, 10.0, " m");
        num(ui, "speed", &mut a.speed_m_s, 0.5, " m/s");
        num(ui, "heading", &mut a.heading_deg, 1.0, "°");
        let label = if a.armed { "click the sensor image … (Esc cancels)" } else { "place it with a click" };
        if ui.selectable_label(a.armed, label).clicked() {
            a.armed = !a.armed;
        }
    });
    if !v.target_status.is_empty() {
        ui.horizontal(|ui| {
            ui.label(&v.target_status);
            if v.removed.is_some() && ui.button("undo").on_hover_text("put the removed target back").clicked() {
                undo_remove(v);
            }
        });
    }
    let draft = &mut v.session.draft;
    egui::CollapsingHeader::new("sensor").default_open(false).show(ui, |ui| {
        let band = draft.sensor.band_um.unwrap_or(v.session.applied.sensor.model.band);
        let (mut lo, mut hi) = (band.lo_um(), band.hi_um());
        let changed = ui
            .horizontal(|ui| {
                let a = ui.add(egui::DragValue::new(&mut lo).speed(0.05).suffix(" µm")).changed();
                let b = ui.add(egui::DragValue::new(&mut hi).speed(0.05).suffix(" µm")).changed();
                ui.label("band");
                a || b
            })
            .inner;
        if changed {
            match Band::try_new(lo, hi) {
                Ok(b) => draft.sensor.band_um = Some(b),
                Err(e) => {
                    local_error = Some(FieldError { path: "sensor.band_um".into(), message: e.to_string(), at: None });
                }
            }
        }
        ui.checkbox(&mut draft.sensor.noise.enabled, "temporal noise");
        opt_num(ui, "NETD", &mut draft.sensor.detector.netd_mk, 40.0, 0.5, " mK");
        num(ui, "vibration amplitude", &mut draft.observer.vibration.amplitude_deg, 0.001, "°");
        num(ui, "vibration cutoff", &mut draft.observer.vibration.cutoff_hz, 0.1, " Hz");
        ui.horizontal(|ui| {
            let b = &mut draft.sensor.blob;
            ui.selectable_value(&mut b.model, TargetModel::Psf, "ellipse ⊗ PSF");
            ui.selectable_value(&mut b.model, TargetModel::Paper, "paper blob");
            ui.label("target model");
        });
    });
    egui::CollapsingHeader::new("quality").default_open(false).show(ui, |ui| quality_panel(ui, &mut draft.quality));
    egui::CollapsingHeader::new("sun").default_open(false).show(ui, |ui| {
        num(ui, "azimuth", &mut draft.sun.azimuth_deg, 1.0, "°");
        num(ui, "elevation", &mut draft.sun.elevation_deg, 0.5, "°");
    });
    // validate and use the draft once the mouse is released and no number is being typed (a half-typed value
    // is not an edit: it is taken when the field is left or Enter pressed)
    let released = !ui.ctx().input(|i| i.pointer.any_down()) && !ui.ctx().egui_wants_keyboard_input();
    if let Some(e) = local_error {
        v.session.error = Some(e);
    } else if released && v.session.draft != v.session.applied.spec {
        let _ = v.session.commit();
    }
    if let Some(e) = &v.session.error {
        ui.colored_label(egui::Color32::from_rgb(255, 110, 90), format!("refused: {}: {}", e.path, e.message));
        ui.label("the last valid scenario stays in use");
        if ui.button("revert the draft").clicked() {
            v.session.revert();
        }
    }
}

/// The `[quality]` preset and the switches worth trying in the window; a choice becomes an override of the
/// preset's value (picking the preset again drops every override).
fn quality_panel(ui: &mut egui::Ui, q: &mut QualitySpec) {
    let resolved = q.resolve().unwrap_or_default();
    ui.horizontal(|ui| {
        for p in [QualityPreset::Draft, QualityPreset::Standard, QualityPreset::Reference] {
            if ui.selectable_label(q.preset == p && q.overrides().is_empty(), p.name()).clicked() {
                *q = QualitySpec::of(p);
            }
        }
        ui.label("preset");
    });
    let overrides = q.overrides();
    if !overrides.is_empty() {
        ui.weak(format!("{} with overrides: {}", q.preset.name(), overrides.join(", ")));
    }
    let samplings =
        [(Sampling::Nearest, "nearest"), (Sampling::Bilinear, "bilinear"), (Sampling::Supersample { n: 4 }, "4×4")];
    pick(ui, "sky sampling", resolved.sky_sampling, &samplings, &mut q.sky_sampling);
    let blob =
        [(BlobSampling::Auto, "auto"), (BlobSampling::Point, "point"), (BlobSampling::Integrated { n: 4 }, "4×4")];
    pick(ui, "paper blob sampling", resolved.blob_sampling, &blob, &mut q.blob_sampling);
    let reflection = [(ReflectionGeometry::Facet, "facet"), (ReflectionGeometry::Ellipsoid, "ellipsoid")];
    pick(ui, "sun reflection", resolved.reflection, &reflection, &mut q.reflection);
    let guidance = [(Guidance::Normal, "normal"), (Guidance::Mixed, "mixed"), (Guidance::Additive, "additive")];
    pick(ui, "fusion guidance", resolved.fusion_guidance, &guidance, &mut q.fusion_guidance);
    let mut s = resolved.fusion_solver;
    ui.horizontal(|ui| {
        if ui.selectable_label(s == Solver::Direct, "direct").clicked() {
            s = Solver::Direct;
        }
        if ui.selectable_label(s == Solver::DirectF32, "direct f32").clicked() {
            s = Solver::DirectF32;
        }
        if ui.selectable_label(matches!(s, Solver::Sor { .. }), "SOR").clicked() && !matches!(s, Solver::Sor { .. }) {
            s = Solver::Sor { tolerance: ITERATIVE_TOLERANCE_DN, max_iterations: 2000 };
        }
        if ui.selectable_label(matches!(s, Solver::Jacobi { .. }), "Jacobi").clicked()
            && !matches!(s, Solver::Jacobi { .. })
        {
            s = Solver::Jacobi { tolerance: ITERATIVE_TOLERANCE_DN, max_iterations: 5000 };
        }
        ui.label("fusion solver");
    });
    if let Solver::Sor { tolerance, .. } | Solver::Jacobi { tolerance, .. } = &mut s {
        num(ui, "solver tolerance", tolerance, 1e-4, " DN");
    }
    if s != resolved.fusion_solver {
        q.fusion_solver = Some(s);
    }
}

/// One switch as a row of choices: picking one other than the value in use makes it the switch's override.
fn pick<T: Copy + PartialEq>(ui: &mut egui::Ui, label: &str, in_use: T, choices: &[(T, &str)], slot: &mut Option<T>) {
    ui.horizontal(|ui| {
        let mut v = in_use;
        for &(choice, name) in choices {
            ui.selectable_value(&mut v, choice, name);
        }
        ui.label(label);
        if v != in_use {
            *slot = Some(v);
        }
    });
}

/// The tolerance an iterative fusion solver starts from when picked in the window, DN: the value
/// docs/accuracy.md measures the solvers at.
const ITERATIVE_TOLERANCE_DN: f64 = 1e-4;

/// Puts the last removed target back where it was; a refusal (another target took its name since) is said and
/// the scenario in use stays.
fn undo_remove(v: &mut Viewer) {
    let Some((i, target)) = v.removed.take() else { return };
    let name = target.name.clone();
    let at = i.min(v.session.draft.targets.len());
    v.target_status = match v.session.edit(|s| s.targets.insert(at, target)) {
        Ok(_) => {
            v.selected = at;
            format!("restored {name}")
        }
        Err(e) => {
            v.session.revert();
            format!("not restored: {}: {}", e.path, e.message)
        }
    };
}
