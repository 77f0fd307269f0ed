//! Live plots: each target's SNR, range and peak gray over the frames computed so far, with the frame on show
//! marked.
//!
//! egui_plot lays out the plot and draws its frame, axes, legend, the time on show and the hover read-out; the
//! background, the grid (at egui_plot's own grid marks, in its colours) and the targets' lines are drawn here, on the
//! CPU, into one opaque picture of the plot's size in screen pixels ([`Canvas`]), copied into the window unblended by
//! [`super::blit`]. Drawn as egui shapes, ten anti-aliased lines of 200 frames each were about 20 000 triangles a
//! displayed frame, which under software rendering (Mesa's llvmpipe) cost more than all the rest of the window's
//! widgets together; and the background, the grid and a blended image of the lines, each filling the plot, cost 5–6 ms
//! more CPU a frame together than this one picture. The picture is redrawn only when the history, the quantity, the
//! plot's size or the legend's state changes; playing on, a new frame draws its own segment and sends only the columns
//! it touched ([`super::uploads`]).

use std::collections::BTreeMap;

use bevy_egui::egui;
use egui_plot::{GridInput, Legend, Line, Plot, PlotBounds, PlotMemory, PlotPoints, VLine};

use super::scene::palette;
use super::uploads::{LiveImage, LiveImages};
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
#[derive(Default)]
pub struct History {
    frames: BTreeMap<u64, (f64, Vec<TargetValues>)>,
    names: BTreeMap<u32, String>,
    /// The quantity on show.
    pub quantity: Quantity,
    /// Counts `clear`s: the lines are drawn again from scratch after one.
    generation: u64,
    /// Frames added since the lines were last drawn.
    added: Vec<u64>,
    raster: Raster,
}

/// The lines' texture and what it was drawn from.
#[derive(Default)]
struct Raster {
    key: Option<RasterKey>,
    texture: Option<LiveImage>,
    /// The plot's frame in screen pixels, as last laid out: its size, and where its top left corner is.
    size_px: [usize; 2],
    /// See `size_px`: left, top, width and height, unrounded.
    frame_px: [f32; 4],
    canvas: Canvas,
    /// The value axis's range, which only grows while the data stay inside it (so that a new frame adds a few
    /// pixels to the picture instead of redrawing it).
    y_range: Option<(f64, f64)>,
}

/// Everything but the data that the picture depends on; a change redraws it whole.
#[derive(Debug, Clone, PartialEq)]
struct RasterKey {
    generation: u64,
    quantity: Quantity,
    size_px: [usize; 2],
    frame_px: [u32; 4],
    bounds: [u64; 4],
    hidden: Vec<u32>,
    highlighted: Option<u32>,
    pixels_per_point: u32,
    /// Background and grid colours (the theme's).
    colors: [egui::Color32; 2],
}

/// egui_plot's default grid spacing, points: marks closer than the first are not drawn, and a line's strength
/// grows from nothing there to full at the second.
const GRID_SPACING_PT: (f32, f32) = (8.0, 300.0);

/// Line width and the radius of a lone frame's dot, points.
const LINE_WIDTH_PT: f32 = 1.5;
const DOT_RADIUS_PT: f32 = 2.5;

/// A premultiplied sRGBA picture and a coverage buffer, both `width × height`, and the pixels the line being
/// drawn has covered.
#[derive(Debug, Default)]
pub struct Canvas {
    width: usize,
    height: usize,
    rgba: Vec<u8>,
    coverage: Vec<f32>,
    covered: Vec<u32>,
}

impl Canvas {
    /// Clears the picture to transparent at the given size.
    pub fn reset(&mut self, width: usize, height: usize) {
        (self.width, self.height) = (width, height);
        self.rgba.clear();
        self.rgba.resize(width * height * 4, 0);
        self.coverage.clear();
        self.coverage.resize(width * height, 0.0);
    }

    /// Fills the picture with `color` (premultiplied).
    pub fn fill(&mut self, color: egui::Color32) {
        for px in self.rgba.chunks_exact_mut(4) {
            px.copy_from_slice(&color.to_array());
        }
    }

    /// A grid line across the picture, one pixel wide, centred on `at_px` (a column when `vertical`, else a row;
    /// pixel edges at whole numbers), in `color` (premultiplied) over what is there, blended in linear light as
    /// the window blends egui's shapes; anti-aliased across the two pixels it straddles.
    pub fn grid_line(&mut self, vertical: bool, at_px: f32, color: egui::Color32) {
        use egui::ecolor::{gamma_u8_from_linear_f32, linear_f32_from_gamma_u8};
        let (w, h) = (self.width, self.height);
        let across = if vertical { w } else { h };
        if !at_px.is_finite() || across == 0 {
            return;
        }
        let (lo, hi) = (at_px - 0.5, at_px + 0.5);
        let first = lo.floor().max(0.0) as usize;
        let [r, g, b, a] = color.to_array();
        let src = [r, g, b].map(linear_f32_from_gamma_u8);
        for i in first..(first + 2).min(across) {
            // the part of pixel i the line covers
            let c = (hi.min(i as f32 + 1.0) - lo.max(i as f32)).clamp(0.0, 1.0);
            if c <= 0.0 {
                continue;
            }
            let keep = 1.0 - c * f32::from(a) / 255.0;
            // column i: every w-th pixel from i; row i: w pixels from i·w
            let (start, step, count) = if vertical { (i, w, h) } else { (i * w, 1, w) };
            for k in 0..count {
                let p = (start + k * step) * 4;
                for (dst, s) in self.rgba[p..p + 3].iter_mut().zip(src) {
                    *dst = gamma_u8_from_linear_f32(s * c + linear_f32_from_gamma_u8(*dst) * keep);
                }
            }
        }
    }

    /// egui_plot's grid for a plot whose frame is `frame_px` (left, top, width, height in window pixels, at
    /// `ppp` pixels per point) showing `bounds` (x0, x1, y0, y1): its marks, faded by their spacing as it fades
    /// them, in `color`, each in the window pixel egui would put it in.
    pub fn grid(&mut self, frame_px: [f32; 4], ppp: f32, bounds: [f64; 4], color: egui::Color32) {
        let [left, top, width, height] = frame_px;
        let [x0, x1, y0, y1] = bounds;
        for (vertical, (lo, hi), size_px, origin) in [(true, (x0, x1), width, left), (false, (y0, y1), height, top)] {
            let per_pt = (hi - lo) / f64::from(size_px / ppp).max(1.0);
            let marks = egui_plot::log_grid_spacer(10)(GridInput {
                bounds: (lo, hi),
                base_step_size: per_pt * f64::from(GRID_SPACING_PT.0),
            });
            let mut lines: Vec<(f32, f32)> = marks
                .iter()
                .filter_map(|m| {
                    let spacing_pt = (m.step_size / per_pt) as f32;
                    let strength =
                        ((spacing_pt - GRID_SPACING_PT.0) / (GRID_SPACING_PT.1 - GRID_SPACING_PT.0)).clamp(0.0, 1.0);
                    let frac = ((m.value - lo) / (hi - lo)) as f32;
                    let at = if vertical { frac } else { 1.0 - frac } * size_px;
                    // egui puts a one-pixel line in the window pixel it is in; the picture's pixel shown there
                    // (the blit takes the texel under each pixel's centre) gets all of it
                    let texel = ((origin + at).floor() + 0.5 - origin).floor();
                    (spacing_pt > GRID_SPACING_PT.0).then_some((texel + 0.5, strength))
                })
                .collect();
            // the stronger lines over the fainter, as egui_plot sorts them
            lines.sort_by(|a, b| a.1.total_cmp(&b.1));
            for (at, strength) in lines {
                self.grid_line(vertical, at, color.gamma_multiply(strength.sqrt()));
            }
        }
    }

    /// Columns `columns` of the picture, row by row, premultiplied sRGBA (one transparent pixel when empty),
    /// appended to `out`, and their size.
    pub fn pixels(&self, columns: std::ops::Range<usize>, mut out: Vec<u8>) -> ([u32; 2], Vec<u8>) {
        let (w, h) = (self.width, self.height);
        let columns = columns.start.min(w)..columns.end.min(w);
        if columns.is_empty() || h == 0 {
            out.extend([0; 4]);
            return ([1, 1], out);
        }
        for y in 0..h {
            out.extend_from_slice(&self.rgba[(y * w + columns.start) * 4..(y * w + columns.end) * 4]);
        }
        ([columns.len() as u32, h as u32], out)
    }

    /// Draws one polyline (pixel coordinates, y down; each pixel's centre at +0.5) `width_px` wide, and a dot of
    /// radius `dot_px` for each lone point, in `color` over what is there. A pixel covered by two segments of the
    /// same line takes the larger coverage, so joints are not drawn twice.
    pub fn polyline(&mut self, segments: &[Vec<[f32; 2]>], width_px: f32, dot_px: f32, color: egui::Color32) {
        if self.width == 0 || self.height == 0 {
            return;
        }
        for points in segments {
            if let [p] = points.as_slice() {
                self.capsule(*p, *p, dot_px);
            }
            for pair in points.windows(2) {
                self.capsule(pair[0], pair[1], width_px / 2.0);
            }
        }
        let [r, g, b, _] = color.to_array();
        for &i in &self.covered {
            let i = i as usize;
            let c = std::mem::take(&mut self.coverage[i]);
            let px = &mut self.rgba[i * 4..i * 4 + 4];
            for (dst, src) in px.iter_mut().zip([r, g, b, 255]) {
                *dst = (f32::from(src) * c + f32::from(*dst) * (1.0 - c) + 0.5) as u8;
            }
        }
        self.covered.clear();
    }

    /// Coverage of the points within `radius` of the segment a–b (anti-aliased over one pixel), kept as the larger
    /// of it and what the pixel has; a pixel covered for the first time is listed in `covered`.
    fn capsule(&mut self, a: [f32; 2], b: [f32; 2], radius: f32) {
        if !(a.iter().chain(&b).all(|v| v.is_finite())) {
            return;
        }
        let (w, h) = (self.width as i64, self.height as i64);
        let reach = radius + 0.5;
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len2 = dx * dx + dy * dy;
        let y0 = ((a[1].min(b[1]) - reach).floor() as i64).max(0);
        let y1 = ((a[1].max(b[1]) + reach).ceil() as i64).min(h - 1);
        for y in y0..=y1 {
            let yc = y as f32 + 0.5;
            // the part of the segment within `reach` of this row sets the columns to visit
            let (mut xa, mut xb) = (a[0].min(b[0]), a[0].max(b[0]));
            if dy.abs() > 1e-6 {
                let t0 = ((yc - reach - a[1]) / dy).clamp(0.0, 1.0);
                let t1 = ((yc + reach - a[1]) / dy).clamp(0.0, 1.0);
                let (u, v) = (a[0] + dx * t0, a[0] + dx * t1);
                (xa, xb) = (u.min(v), u.max(v));
            }
            let x0 = ((xa - reach).floor() as i64).max(0);
            let x1 = ((xb + reach).ceil() as i64).min(w - 1);
            for x in x0..=x1 {
                let xc = x as f32 + 0.5;
                let t = if len2 > 0.0 { (((xc - a[0]) * dx + (yc - a[1]) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
                let (ex, ey) = (a[0] + dx * t - xc, a[1] + dy * t - yc);
                let c = (reach - (ex * ex + ey * ey).sqrt()).clamp(0.0, 1.0);
                let i = (y * w + x) as usize;
                let cell = &mut self.coverage[i];
                if c > *cell {
                    if *cell == 0.0 {
                        self.covered.push(i as u32);
                    }
                    *cell = c;
                }
            }
        }
    }
}

impl History {
    /// Forgets everything (the scenario changed).
    pub fn clear(&mut self) {
        self.frames.clear();
        self.names.clear();
        self.added.clear();
        self.generation += 1;
    }

    /// Adds a frame's labels.
    pub fn add(&mut self, labels: &FrameLabels) {
        let values = labels.targets.iter().map(|t| (t.id, t.snr, t.range_m * 1e-3, t.peak_dn)).collect();
        for t in &labels.targets {
            self.names.entry(t.id).or_insert_with(|| t.name.clone());
        }
        if self.frames.insert(labels.frame, (labels.t_s, values)).is_none() {
            self.added.push(labels.frame);
        }
    }

    /// Each target's runs of consecutive frames (a seek leaves a gap, not a line across frames never computed)
    /// as (t, value) points, by target id.
    fn series(&self, quantity: Quantity, frames: std::ops::RangeInclusive<u64>) -> Vec<(u32, Vec<Vec<[f64; 2]>>)> {
        self.names
            .keys()
            .map(|&id| {
                let mut segments: Vec<Vec<[f64; 2]>> = Vec::new();
                let mut last: Option<u64> = None;
                for (&k, (t, values)) in self.frames.range(frames.clone()) {
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
                (id, segments)
            })
            .collect()
    }

    /// Draws the plot of the chosen quantity, `height` points high, over the run's time span `run_s`, with
    /// `t_now_s` marked.
    pub fn show(
        &mut self,
        ui: &mut egui::Ui,
        live: &mut LiveImages<'_, '_, '_>,
        t_now_s: f64,
        run_s: (f64, f64),
        height: f32,
    ) {
        ui.horizontal(|ui| {
            ui.selectable_value(&mut self.quantity, Quantity::Snr, "SNR");
            ui.selectable_value(&mut self.quantity, Quantity::Range, "range km");
            ui.selectable_value(&mut self.quantity, Quantity::Peak, "peak ΔDN")
                .on_hover_text("peak gray value above the target's sky, DN (negative: darker than the sky)");
            ui.weak(format!("over the {} frames computed", self.frames.len()));
        });
        let quantity = self.quantity;
        let series = self.series(quantity, 0..=u64::MAX);
        let label = |id: u32| format!("{id} {}", self.names.get(&id).map_or("", String::as_str));
        // the legend's state (entries clicked off, the entry under the pointer) from the plot's memory
        let plot_id = egui::Id::new("irsim_history_plot");
        let memory = PlotMemory::load(ui.ctx(), plot_id);
        let item = |id: u32| egui::Id::new(label(id));
        let hidden: Vec<u32> = series
            .iter()
            .map(|s| s.0)
            .filter(|&id| memory.as_ref().is_some_and(|m| m.hidden_items.contains(&item(id))))
            .collect();
        let highlighted = memory
            .as_ref()
            .and_then(|m| m.hovered_legend_item)
            .and_then(|h| series.iter().map(|s| s.0).find(|&id| item(id) == h));
        // time over the whole run; values over what is shown, the range kept while they stay inside it
        let values = value_range(&series, &hidden);
        let same_view = self
            .raster
            .key
            .as_ref()
            .is_some_and(|k| k.generation == self.generation && k.quantity == quantity && k.hidden == hidden);
        let (y0, y1) = match (self.raster.y_range, values) {
            (Some((a, b)), Some((lo, hi))) if same_view && a <= lo && hi <= b => (a, b),
            (_, Some((lo, hi))) => padded(lo, hi),
            (_, None) => (0.0, 1.0),
        };
        self.raster.y_range = Some((y0, y1));
        let t_last = series.iter().flat_map(|s| s.1.iter().flatten()).fold(t_now_s, |t, p| t.max(p[0]));
        let (x0, x1) = time_axis(run_s, t_now_s, t_last);
        let bounds = [x0, x1, y0, y1];
        let ppp = ui.ctx().pixels_per_point();
        let (background, grid) = (ui.visuals().extreme_bg_color, ui.visuals().text_color());
        let key = RasterKey {
            generation: self.generation,
            quantity,
            size_px: self.raster.size_px,
            frame_px: self.raster.frame_px.map(f32::to_bits),
            bounds: bounds.map(f64::to_bits),
            hidden: hidden.clone(),
            highlighted,
            pixels_per_point: ppp.to_bits(),
            colors: [background, grid],
        };
        let [w, h] = self.raster.size_px;
        let to_px =
            |p: &[f64; 2]| [((p[0] - x0) / (x1 - x0) * w as f64) as f32, ((y1 - p[1]) / (y1 - y0) * h as f64) as f32];
        let draw = |canvas: &mut Canvas, series: &[(u32, Vec<Vec<[f64; 2]>>)]| {
            // the highlighted line last, on top and wider
            let mut order: Vec<_> = series.iter().filter(|s| !hidden.contains(&s.0)).collect();
            order.sort_by_key(|s| Some(s.0) == highlighted);
            for (id, segments) in order {
                let px: Vec<Vec<[f32; 2]>> = segments.iter().map(|s| s.iter().map(to_px).collect()).collect();
                let wide = if Some(*id) == highlighted { 2.0 } else { 1.0 };
                canvas.polyline(&px, LINE_WIDTH_PT * wide * ppp, DOT_RADIUS_PT * ppp, color32(*id));
            }
        };
        // playing on: the frames added follow the last one drawn, which was not a lone dot; draw only the new
        // part and send only the columns it touched
        let added = std::mem::take(&mut self.added);
        let appended = appended_run(&self.frames, &added);
        if self.raster.key.as_ref() != Some(&key)
            || self.raster.texture.is_none()
            || (appended.is_none() && !added.is_empty())
        {
            let canvas = &mut self.raster.canvas;
            canvas.reset(w, h);
            canvas.fill(background);
            canvas.grid(self.raster.frame_px, ppp, [x0, x1, y0, y1], grid);
            draw(canvas, &series);
            let (size, rgba) = canvas.pixels(0..w, live.buffer(w * h * 4));
            match &self.raster.texture {
                Some(t) if t.size == size => live.write(t, [0, 0], size, rgba),
                _ => self.raster.texture = Some(live.create(size, rgba, self.raster.texture.take())),
            }
            self.raster.key = Some(key);
        } else if let Some((from, to)) = appended {
            let new = self.series(quantity, from..=to);
            let canvas = &mut self.raster.canvas;
            draw(canvas, &new);
            let column = |k: u64| to_px(&[self.frames.get(&k).map_or(x0, |f| f.0), y0])[0];
            let reach = (LINE_WIDTH_PT * 2.0 * ppp).max(DOT_RADIUS_PT * ppp) + 2.0;
            let a = ((column(from) - reach).floor().max(0.0) as usize).min(w);
            let b = ((column(to) + reach).ceil().max(0.0) as usize).min(w);
            if b > a
                && let Some(texture) = &self.raster.texture
            {
                let (size, rgba) = canvas.pixels(a..b, live.buffer((b - a) * h * 4));
                live.write(texture, [a as u32, 0], size, rgba);
            }
        }
        // the picture goes under everything egui_plot draws: its place among the shapes is kept now, and filled
        // in once the plot has said where its frame is
        let slot = ui.painter().add(egui::Shape::Noop);
        let response = Plot::new("history")
            .id(plot_id)
            .height(height)
            .legend(Legend::default())
            // time labels closer together than egui_plot's default (60 points), which leaves a 10 s axis with
            // no second marked
            .custom_x_axes(vec![egui_plot::AxisHints::new_x().label("t, s").label_spacing(22.0..=32.0)])
            .allow_scroll(false)
            .allow_zoom(false)
            .allow_drag(false)
            .allow_boxed_zoom(false)
            .allow_double_click_reset(false)
            .show_background(false)
            .show_grid(false)
            .show(ui, |plot| {
                plot.set_plot_bounds(PlotBounds::from_min_max([x0, y0], [x1, y1]));
                // legend entries: each target's colour and name (its line is in the image): a line of one point,
                // its latest, which egui_plot lists and hovers but does not draw
                for (id, segments) in &series {
                    let last = segments.iter().flatten().last().copied().unwrap_or([t_now_s, (y0 + y1) / 2.0]);
                    plot.line(Line::new(label(*id), PlotPoints::new(vec![last])).color(color32(*id)));
                }
                plot.vline(VLine::new("now", t_now_s).color(egui::Color32::GRAY));
            });
        let frame = *response.transform.frame();
        if let Some(texture) = &self.raster.texture {
            let picture = if super::blit::fits(ui.ctx(), frame) {
                egui::Shape::Callback(super::blit::blit(frame, texture.asset()))
            } else {
                let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
                egui::Shape::image(texture.id, frame, uv, egui::Color32::WHITE)
            };
            ui.painter().set(slot, picture);
        }
        // egui_plot's frame line, which it draws with the background
        ui.painter().with_clip_rect(frame).rect_stroke(
            frame,
            2.0,
            ui.visuals().widgets.noninteractive.bg_stroke,
            egui::StrokeKind::Inside,
        );
        let size = frame.size() * ppp;
        self.raster.size_px = [size.x.round().max(0.0) as usize, size.y.round().max(0.0) as usize];
        self.raster.frame_px = [frame.min.x * ppp, frame.min.y * ppp, size.x, size.y];
    }
}

/// Playing on: when the frames `added` (in the order added) follow the last frame already in `frames` one by one,
/// and the frame before them was joined to its own predecessor (drawn as a line, not a lone dot), the frames from
/// that one to the last added: only they need drawing. Otherwise (a seek, a frame filled in before others) None.
fn appended_run<T>(frames: &BTreeMap<u64, T>, added: &[u64]) -> Option<(u64, u64)> {
    let (&first, &last) = (added.first()?, added.last()?);
    let prior = first.checked_sub(1)?;
    let consecutive = added.windows(2).all(|p| p[1] == p[0] + 1);
    let at_end = frames.range(prior..).count() == added.len() + 1 && frames.contains_key(&prior);
    let joined = prior.checked_sub(1).is_some_and(|k| frames.contains_key(&k));
    (consecutive && at_end && joined).then_some((prior, last))
}

/// The time axis: from the run's start to the first of 1/8, 1/4, 1/2 or all of the run that holds the frames
/// computed so far (with 2 % to spare); a change of step redraws the lines, so they are redrawn at most four
/// times as a run plays through, and fill the plot from the start.
fn time_axis(run_s: (f64, f64), t_first: f64, t_last: f64) -> (f64, f64) {
    let (t0, t1) = (run_s.0.min(t_first), run_s.1.max(t_last));
    let span = (t1 - t0).max(1e-3);
    let needed = (t_last - t0) / span * 1.02;
    let fraction = [0.125, 0.25, 0.5].into_iter().find(|&f| needed <= f).unwrap_or(1.0);
    (t0, t0 + span * fraction)
}

/// The lowest and highest value shown, if any.
fn value_range(series: &[(u32, Vec<Vec<[f64; 2]>>)], hidden: &[u32]) -> Option<(f64, f64)> {
    series
        .iter()
        .filter(|s| !hidden.contains(&s.0))
        .flat_map(|s| s.1.iter().flatten())
        .fold(None, |r, p| Some(r.map_or((p[1], p[1]), |(lo, hi): (f64, f64)| (lo.min(p[1]), hi.max(p[1])))))
}

/// A value range with room: 5 % below, 25 % above (values rise as targets close in), never empty.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    // one value (or a flat line): a tenth of its size around it, not a sliver that labels the fourth decimal
    let span = (hi - lo).max(0.1 * hi.abs().max(lo.abs())).max(1e-9);
    (lo - 0.05 * span, hi + 0.25 * span)
}

/// A target's colour as egui's.
fn color32(id: u32) -> egui::Color32 {
    let c = palette(id).to_srgba();
    egui::Color32::from_rgb((c.red * 255.0) as u8, (c.green * 255.0) as u8, (c.blue * 255.0) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alpha(c: &Canvas, x: usize, y: usize) -> u8 {
        c.rgba[(y * c.width + x) * 4 + 3]
    }

    #[test]
    fn a_line_covers_its_pixels_once_and_nothing_far_from_it() {
        let mut c = Canvas::default();
        c.reset(40, 20);
        // a horizontal line along row 10's centre, 2 px wide, drawn as three overlapping pieces of one polyline
        let line = vec![vec![[5.0, 10.5], [20.0, 10.5], [12.0, 10.5], [30.0, 10.5]]];
        c.polyline(&line, 2.0, 2.5, egui::Color32::from_rgb(255, 0, 0));
        assert_eq!(alpha(&c, 15, 10), 255, "on the line");
        assert_eq!(c.rgba[(10 * 40 + 15) * 4..(10 * 40 + 15) * 4 + 4], [255, 0, 0, 255]);
        // overlapping pieces of one line are not blended twice: the edge row is as covered everywhere
        let edge: Vec<u8> = (8..28).map(|x| alpha(&c, x, 9)).collect();
        assert!(edge.iter().all(|&a| a == edge[0] && a > 0 && a < 255), "{edge:?}");
        assert_eq!(alpha(&c, 15, 5), 0, "far above");
        assert_eq!(alpha(&c, 36, 10), 0, "beyond the end");
        assert!(c.coverage.iter().all(|&v| v == 0.0) && c.covered.is_empty(), "scratch left clean");
    }

    #[test]
    fn a_lone_point_is_a_dot_and_points_off_the_canvas_are_clipped() {
        let mut c = Canvas::default();
        c.reset(20, 20);
        c.polyline(&[vec![[10.0, 10.0]], vec![[-50.0, 3.0], [-40.0, 90.0]]], 1.5, 3.0, egui::Color32::WHITE);
        assert_eq!(alpha(&c, 10, 10), 255);
        assert_eq!(alpha(&c, 9, 9), 255);
        assert_eq!(alpha(&c, 10, 15), 0);
        let covered = c.rgba.chunks_exact(4).filter(|p| p[3] > 0).count();
        // a disc of radius 3 (+ half a pixel of edge): about π 3.5² ≈ 38 pixels
        assert!((28..=48).contains(&covered), "{covered}");
        // NaN points draw nothing and do not panic
        c.polyline(&[vec![[f32::NAN, 1.0], [5.0, 5.0]]], 1.5, 3.0, egui::Color32::WHITE);
        assert_eq!(c.rgba.chunks_exact(4).filter(|p| p[3] > 0).count(), covered);
    }

    #[test]
    fn a_drawing_in_two_steps_matches_one_away_from_the_joint() {
        let points: Vec<[f32; 2]> =
            (0..40).map(|i| [i as f32 * 2.0 + 0.5, 10.0 + 6.0 * (i as f32 * 0.7).sin()]).collect();
        let mut whole = Canvas::default();
        whole.reset(90, 24);
        whole.polyline(std::slice::from_ref(&points), 1.5, 2.5, egui::Color32::GREEN);
        let mut steps = Canvas::default();
        steps.reset(90, 24);
        steps.polyline(&[points[..20].to_vec()], 1.5, 2.5, egui::Color32::GREEN);
        steps.polyline(&[points[19..].to_vec()], 1.5, 2.5, egui::Color32::GREEN);
        // only pixels within reach of the joint (point 19, x ≈ 38.5) may differ, and only by a blend
        for y in 0..24 {
            for x in 0..90 {
                let (a, b) = (alpha(&whole, x, y), alpha(&steps, x, y));
                if (x as f32 - 38.5).abs() > 3.0 {
                    assert_eq!(a, b, "at ({x}, {y})");
                } else {
                    assert!(b >= a, "at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn a_grid_line_fills_the_pixel_it_is_centred_in_and_blends_in_linear_light() {
        use egui::ecolor::{gamma_u8_from_linear_f32, linear_f32_from_gamma_u8};
        let gray = |c: &Canvas, x: usize, y: usize| c.rgba[(y * c.width + x) * 4];
        let mut c = Canvas::default();
        c.reset(8, 4);
        c.fill(egui::Color32::from_gray(10));
        c.grid_line(true, 3.5, egui::Color32::from_gray(140));
        for y in 0..4 {
            for x in 0..8 {
                assert_eq!(gray(&c, x, y), if x == 3 { 140 } else { 10 }, "({x}, {y})");
                assert_eq!(c.rgba[(y * 8 + x) * 4 + 3], 255, "the picture stays opaque");
            }
        }
        // straddling rows 0 and 1, half over each: half the light, not half the gray level
        c.fill(egui::Color32::BLACK);
        c.grid_line(false, 1.0, egui::Color32::from_gray(140));
        let half = gamma_u8_from_linear_f32(0.5 * linear_f32_from_gamma_u8(140));
        assert!(half > 70, "{half}");
        for x in 0..8 {
            assert_eq!([gray(&c, x, 0), gray(&c, x, 1), gray(&c, x, 2)], [half, half, 0]);
        }
        // off the picture, or not a number: nothing
        c.fill(egui::Color32::BLACK);
        c.grid_line(true, -3.0, egui::Color32::WHITE);
        c.grid_line(true, f32::NAN, egui::Color32::WHITE);
        c.grid_line(false, 99.0, egui::Color32::WHITE);
        assert!(c.rgba.chunks_exact(4).all(|p| p == [0, 0, 0, 255]));
    }

    #[test]
    fn the_time_axis_grows_in_four_steps_to_the_whole_run() {
        let run = (0.0, 16.0);
        assert_eq!(time_axis(run, 0.0, 0.5), (0.0, 2.0));
        assert_eq!(time_axis(run, 0.0, 1.9), (0.0, 2.0));
        assert_eq!(time_axis(run, 0.0, 2.0), (0.0, 4.0));
        assert_eq!(time_axis(run, 0.0, 7.0), (0.0, 8.0));
        assert_eq!(time_axis(run, 0.0, 9.0), (0.0, 16.0));
        // frames beyond the run, or before it, widen it
        assert_eq!(time_axis(run, -1.0, 20.0), (-1.0, 20.0));
    }

    #[test]
    fn only_frames_that_continue_the_run_are_drawn_alone() {
        let frames = |ks: &[u64]| ks.iter().map(|&k| (k, ())).collect::<BTreeMap<u64, ()>>();
        // playing: 0..=5 drawn, 6 and 7 added
        assert_eq!(appended_run(&frames(&[0, 1, 2, 3, 4, 5, 6, 7]), &[6, 7]), Some((5, 7)));
        // nothing new
        assert_eq!(appended_run(&frames(&[0, 1, 2]), &[]), None);
        // a frame filled in before frames already drawn
        assert_eq!(appended_run(&frames(&[0, 1, 2, 5, 6]), &[2]), None);
        // after a seek: the frame before the new one was a lone dot
        assert_eq!(appended_run(&frames(&[0, 1, 2, 10, 11]), &[11]), None);
        // the first frames of all
        assert_eq!(appended_run(&frames(&[0, 1]), &[0, 1]), None);
        // not one after the other
        assert_eq!(appended_run(&frames(&[0, 1, 2, 3, 5]), &[3, 5]), None);
    }
}
