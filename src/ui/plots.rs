//! Live plots: each target's SNR, range and peak gray over the frames computed so far, with the frame on show
//! marked.

use std::collections::BTreeMap;

use bevy_egui::egui;
use egui_plot::{Legend, Line, Plot, PlotPoints, Points, VLine};

use super::scene::palette;
use crate::labels::FrameLabels;

/// What is plotted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Quantity {
    /// Signal-to-noise ratio.
    #[default]
    Snr,
    /// Range from the observer, km.
    Range,
    /// Peak gray value above the target's sky, DN.
    Peak,
}

/// One target's plotted values in one frame: id, SNR, range (km) and peak (DN).
type TargetValues = (u32, f64, f64, f64);

/// Per frame (by index), each target's id, name, time and values: a frame computed twice is stored once.
#[derive(Debug, Default)]
pub struct History {
    frames: BTreeMap<u64, (f64, Vec<TargetValues>)>,
    names: BTreeMap<u32, String>,
    /// The quantity on show.
    pub quantity: Quantity,
}

impl History {
    /// Forgets everything (the scenario changed).
    pub fn clear(&mut self) {
        self.frames.clear();
        self.names.clear();
    }

    /// Adds a frame's labels.
    pub fn add(&mut self, labels: &FrameLabels) {
        let values = labels.targets.iter().map(|t| (t.id, t.snr, t.range_m * 1e-3, t.peak_dn)).collect();
        for t in &labels.targets {
            self.names.entry(t.id).or_insert_with(|| t.name.clone());
        }
        self.frames.insert(labels.frame, (labels.t_s, values));
    }

    /// Draws the plot of the chosen quantity, `height` points high, with `t_now_s` marked.
    pub fn show(&mut self, ui: &mut egui::Ui, t_now_s: f64, height: f32) {
        ui.horizontal(|ui| {
            ui.selectable_value(&mut self.quantity, Quantity::Snr, "SNR");
            ui.selectable_value(&mut self.quantity, Quantity::Range, "range km");
            ui.selectable_value(&mut self.quantity, Quantity::Peak, "peak DN");
            ui.weak(format!("over the {} frames computed", self.frames.len()));
        });
        let quantity = self.quantity;
        Plot::new("history").height(height).legend(Legend::default()).x_axis_label("t, s").allow_scroll(false).show(
            ui,
            |plot| {
                for (&id, name) in &self.names {
                    // a line through consecutive frames only: frames skipped by a seek are a gap, not a straight
                    // line, and a lone frame is a dot
                    let mut segments: Vec<Vec<[f64; 2]>> = Vec::new();
                    let mut last: Option<u64> = None;
                    for (&k, (t, values)) in &self.frames {
                        let y = values.iter().find(|v| v.0 == id).map(|&(_, snr, range, peak)| match quantity {
                            Quantity::Snr => snr,
                            Quantity::Range => range,
                            Quantity::Peak => peak,
                        });
                        let Some(y) = y.filter(|y| y.is_finite()) else {
                            last = None;
                            continue;
                        };
                        if last.is_none_or(|l| k != l + 1) {
                            segments.push(Vec::new());
                        }
                        if let Some(segment) = segments.last_mut() {
                            segment.push([*t, y]);
                        }
                        last = Some(k);
                    }
                    let c = palette(id).to_srgba();
                    let color =
                        egui::Color32::from_rgb((c.red * 255.0) as u8, (c.green * 255.0) as u8, (c.blue * 255.0) as u8);
                    let label = format!("{id} {name}");
                    for segment in segments {
                        if segment.len() == 1 {
                            plot.points(Points::new(label.clone(), segment).radius(2.5).color(color));
                        } else {
                            plot.line(Line::new(label.clone(), PlotPoints::from(segment)).color(color));
                        }
                    }
                }
                plot.vline(VLine::new("now", t_now_s).color(egui::Color32::GRAY));
            },
        );
    }
}
