//! `irsim bench report`: what every quality preset and switch costs and saves, measured in one run on fixed,
//! seeded inputs, written as `speed_vs_error.md` with PNG plots.
//!
//! Errors are against the `reference` preset on the same scenario with the noise off (so only the
//! approximations differ): the frame's rms and largest difference in DN before quantization, and the largest difference of a
//! target's intensity centroid (in its label box grown by 3 px, over the median of the box's border). Times are
//! per frame, headless, with the noise on, after two warm-up frames, on every core rayon is given. Frames are
//! compared before quantization, so a difference is the approximation's and not a rounding flip.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use plotters::prelude::*;

use super::CliError;
use super::run::{WIDE_CASE_TARGETS, bench_dir, bench_scenario, with_quality_spec};
use crate::dataset::card;
use crate::labels::FrameLabels;
use crate::record::write_atomic;
use crate::scenario::load::{load_for_frames, located};
use crate::scenario::quality::SWITCHES;
use crate::scenario::{CheckedScenario, Quality, QualityPreset, QualitySpec};
use crate::sim::{LatestFrame, RunOptions, StageTimings, headless_app, step};

/// `irsim bench report`.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Directory for speed_vs_error.md and the plots (created; a report already there is replaced only with
    /// --force).
    #[arg(long, default_value = "bench-report")]
    pub out: PathBuf,
    /// Fewer scenarios, frames and sizes: a couple of minutes on 2 cores.
    #[arg(long)]
    pub quick: bool,
    /// Replace a report already in --out.
    #[arg(long)]
    pub force: bool,
    /// Directory of the scenarios measured per preset and per skip.
    #[arg(long, default_value = "scenarios")]
    pub scenarios: PathBuf,
    /// The smallest configuration (64 × 64 synthetic cases, two points per scaling curve), for tests.
    #[arg(long, hide = true)]
    pub tiny: bool,
}

/// How much a report measures.
#[derive(Clone)]
struct Plan {
    /// Frames compared per case (noise off).
    error_frames: u64,
    /// Frames timed per case (noise on), after two warm-up frames.
    time_frames: u64,
    /// At most this many of the scenarios directory's files.
    max_scenarios: usize,
    /// Synthetic whole-pipeline cases: width, height, targets.
    cases: Vec<(u32, u32, usize)>,
    /// Target counts of the scaling curve (at `target_size`).
    targets: Vec<usize>,
    target_size: (u32, u32),
    /// Square sizes of the resolution curve (1 target).
    sizes: Vec<u32>,
    /// Switch values tried: the standard preset's, and with `all_values` the draft preset's too.
    all_values: bool,
    /// Region sides of the OpenCV comparison.
    opencv_sides: Vec<usize>,
    /// Frames per bound and pipeline run of the lower-bound section.
    limits_frames: u64,
    /// Frames of the recording against headless comparison.
    recording_frames: u64,
    /// Interleaved rounds of the timings that are compared with each other ([`interleaved`], and the
    /// lower bounds beside the pipeline).
    rounds: usize,
}

impl Plan {
    fn new(a: &ReportArgs) -> Self {
        if a.tiny {
            Plan {
                error_frames: 2,
                time_frames: 0,
                max_scenarios: 1,
                cases: vec![(64, 64, 1)],
                targets: vec![1, 2],
                target_size: (64, 64),
                sizes: vec![48, 64],
                all_values: false,
                opencv_sides: vec![17],
                limits_frames: 20,
                recording_frames: 20,
                rounds: 1,
            }
        } else if a.quick {
            Plan {
                error_frames: 3,
                time_frames: 20,
                max_scenarios: 3,
                cases: vec![(256, 256, 1), (640, 512, WIDE_CASE_TARGETS)],
                targets: vec![1, 4, 16],
                target_size: (640, 512),
                sizes: vec![128, 256, 512],
                all_values: false,
                opencv_sides: vec![17, 33, 65],
                limits_frames: 200,
                recording_frames: 300,
                rounds: 2,
            }
        } else {
            Plan {
                error_frames: 8,
                // a texture build costs tens of frames' time: a short window would show where one fell
                time_frames: 100,
                max_scenarios: usize::MAX,
                cases: vec![(256, 256, 1), (256, 256, 8), (640, 512, 1), (640, 512, WIDE_CASE_TARGETS)],
                targets: vec![1, 2, 4, 8, 16, 32, 64],
                target_size: (640, 512),
                sizes: vec![128, 256, 512, 1024, 2048],
                all_values: true,
                opencv_sides: vec![17, 33, 65, 129],
                limits_frames: 2000,
                recording_frames: 2000,
                rounds: 4,
            }
        }
    }
}

/// A timed window shorter than this, s, is timed three times ([`median_run`]).
const SHORT_WINDOW_S: f64 = 0.1;

/// A case run twice: noise off for its frames, noise on for its time.
struct Measured {
    ms_per_frame: f64,
    /// Mean ms per frame of each pipeline stage in the timed run (empty without one).
    stage_ms: Vec<(&'static str, f64)>,
    frames: Vec<Vec<f32>>,
    labels: Vec<FrameLabels>,
    width: usize,
}

/// Differences from the reference.
#[derive(Clone, Copy)]
struct Errors {
    rms_dn: f64,
    max_dn: f64,
    /// Largest centroid difference, px; `None` when no target was in a frame.
    centroid_px: Option<f64>,
}

/// Runs `run`, which returns how long its timed window took (s) and its result, once, or three times where the
/// first window took under [`SHORT_WINDOW_S`] (one pause of the shared machine is a large part of a few
/// milliseconds); the result of the median window.
fn median_run<T>(mut run: impl FnMut() -> Result<(f64, T), CliError>) -> Result<T, CliError> {
    let mut runs = vec![run()?];
    if runs[0].0 < SHORT_WINDOW_S {
        for _ in 0..2 {
            runs.push(run()?);
        }
    }
    runs.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(runs.swap_remove(runs.len() / 2).1)
}

/// `s`'s headless app, its set-up's error located in its file.
fn app(s: &CheckedScenario, options: RunOptions) -> Result<bevy::app::App, CliError> {
    headless_app(s, options).map_err(|e| CliError::Invalid(located(&s.source, &e.field, &e.message).to_string()))
}

/// A scenario's whole run headless: its set-up with nothing kept from earlier runs and every one of its own
/// frames, noise on; the window's length, s, and it in ms.
fn whole_run(s: &CheckedScenario) -> Result<(f64, f64), CliError> {
    crate::sim::forget_kept_results();
    let started = Instant::now();
    let mut app = app(s, RunOptions::default())?;
    for _ in 0..s.spec.run.frames {
        step(&mut app);
    }
    let elapsed_s = started.elapsed().as_secs_f64();
    Ok((elapsed_s, elapsed_s * 1e3))
}

/// The whole runs of `runs` ([`whole_run`]), ms ([`interleaved`]).
fn whole_runs_ms(runs: &[CheckedScenario], rounds: usize) -> Result<Vec<f64>, CliError> {
    interleaved(runs, rounds, whole_run)
}

/// `window` of every case in `rounds` rounds, round k running each case once in order, so that a slow minute of
/// a shared machine falls on all of them alike; per case, the result of its fastest window, the least disturbed
/// by the host's other work, which can only add time (`window` returns its length, s, and its result). With one
/// round, each case as [`median_run`] times it.
fn interleaved<C, T>(
    cases: &[C],
    rounds: usize,
    mut window: impl FnMut(&C) -> Result<(f64, T), CliError>,
) -> Result<Vec<T>, CliError> {
    if rounds <= 1 {
        return cases.iter().map(|c| median_run(|| window(c))).collect();
    }
    let mut windows: Vec<Vec<(f64, T)>> = cases.iter().map(|_| Vec::new()).collect();
    for _ in 0..rounds {
        for (c, w) in cases.iter().zip(&mut windows) {
            w.push(window(c)?);
        }
    }
    // the fastest (the first of equals): what the host's other work does is add time
    Ok(windows
        .into_iter()
        .filter_map(|w| w.into_iter().reduce(|a, b| if b.0.total_cmp(&a.0).is_lt() { b } else { a }))
        .map(|(_, result)| result)
        .collect())
}

fn failed(e: impl std::fmt::Display) -> CliError {
    CliError::Failed(e.to_string())
}

fn preset(scenario: &CheckedScenario, p: QualityPreset) -> Result<CheckedScenario, CliError> {
    with_quality_spec(scenario, QualitySpec::of(p))
}

/// Preset `base` with one switch set to `value` (TOML); an error if the value does not parse for the switch.
fn one_switch(
    scenario: &CheckedScenario,
    base: QualityPreset,
    name: &str,
    value: &str,
) -> Result<CheckedScenario, CliError> {
    let text = format!("preset = \"{}\"\n{name} = {value}\n", base.name());
    let spec: QualitySpec = toml::from_str(&text).map_err(|e| failed(format!("switch {name} = {value}: {e}")))?;
    with_quality_spec(scenario, spec)
}

/// `s`'s frames and labels with the noise off (`plan.error_frames`; `ms_per_frame` their time, noise off, and no
/// stages), untimed.
fn compare_frames(s: &CheckedScenario, plan: &Plan) -> Result<Measured, CliError> {
    let (mut frames, mut labels) = (Vec::new(), Vec::new());
    let mut width = 0;
    let mut ms_per_frame = f64::NAN;
    if plan.error_frames > 0 {
        let mut app = app(s, RunOptions { noise: false, keep_float: true, ..RunOptions::default() })?;
        let t = Instant::now();
        for _ in 0..plan.error_frames {
            labels.push(step(&mut app));
            // the frame before quantization, so that a difference is not a rounding flip
            let latest = app.world().get_resource::<LatestFrame>().and_then(|l| l.0.as_ref());
            let f = latest.and_then(|r| r.float_frame.as_ref()).ok_or_else(|| failed("no unquantized frame"))?;
            width = f.width();
            frames.push(f.pixels().to_vec());
        }
        ms_per_frame = t.elapsed().as_secs_f64() * 1e3 / plan.error_frames as f64;
    }
    Ok(Measured { ms_per_frame, stage_ms: Vec::new(), frames, labels, width })
}

/// A timed window of `s` from a fresh start: two warm-up frames, then `plan.time_frames` frames, noise on; the
/// window's length, s, with ms per frame and each stage's mean ms.
fn time_window(s: &CheckedScenario, plan: &Plan) -> Result<(f64, Timed), CliError> {
    let mut app = app(s, RunOptions { timings: true, ..RunOptions::default() })?;
    for _ in 0..2 {
        step(&mut app);
    }
    app.world_mut().insert_resource(StageTimings::default());
    let t = Instant::now();
    for _ in 0..plan.time_frames {
        step(&mut app);
    }
    let window_s = t.elapsed().as_secs_f64();
    let ms = window_s * 1e3 / plan.time_frames.max(1) as f64;
    let stages = app.world().get_resource::<StageTimings>().map(StageTimings::mean_ms).unwrap_or_default();
    Ok((window_s, (ms, stages)))
}

/// Ms per frame and each stage's mean ms.
type Timed = (f64, Vec<(&'static str, f64)>);

/// One case compared ([`compare_frames`]) and timed: its window of median time among one, or three where the
/// first is short ([`median_run`]). Without timed frames (the smallest configuration) the compared frames' own
/// time, noise off.
fn measure(s: &CheckedScenario, plan: &Plan) -> Result<Measured, CliError> {
    let mut m = compare_frames(s, plan)?;
    if plan.time_frames > 0 {
        (m.ms_per_frame, m.stage_ms) = median_run(|| time_window(s, plan))?;
    }
    Ok(m)
}

/// Cases whose times are compared with each other (presets, skips, points of a curve): each compared
/// ([`compare_frames`]), then timed in `plan.rounds` interleaved rounds ([`interleaved`]).
fn measure_together(cases: &[CheckedScenario], plan: &Plan) -> Result<Vec<Measured>, CliError> {
    let mut all = cases.iter().map(|s| compare_frames(s, plan)).collect::<Result<Vec<_>, _>>()?;
    if plan.time_frames > 0 {
        let times = interleaved(cases, plan.rounds, |s| time_window(s, plan))?;
        for (m, (ms, stages)) in all.iter_mut().zip(times) {
            (m.ms_per_frame, m.stage_ms) = (ms, stages);
        }
    }
    Ok(all)
}

/// How the report's times were taken, as its header says it.
fn timing_text(plan: &Plan) -> String {
    // a time alone (the reference's, a switch's) or every time of a one-round plan
    let alone = "one run, or the median of three where its timed frames take under 0.1 s";
    if plan.time_frames == 0 {
        "Times are those of the compared frames, noise off (no frames are timed apart).".into()
    } else if plan.rounds <= 1 {
        format!("Times are per frame, headless, noise on, after two warm-up frames: each {alone}.")
    } else {
        format!(
            "Times are per frame, headless, noise on, after two warm-up frames. Times that are compared with each \
             other (standard's, draft's and the skips' on a scenario or case, a scenario's whole runs, the points of \
             the scaling curves, the lower bounds and the pipeline beside them) are taken in {} interleaved rounds, \
             each the fastest of its rounds (the host's other work can only add time), so that a slow minute of a \
             shared machine falls on all of them alike; a time alone (the reference's, a switch's) is {alone}.",
            plan.rounds
        )
    }
}

/// The intensity centroid of `frame` in `bbox` grown by 3 px, over the median of the region's border.
fn centroid(frame: &[f32], width: usize, bbox: [f64; 4]) -> Option<[f64; 2]> {
    let height = frame.len() / width.max(1);
    let grow = 3.0;
    let x0 = (bbox[0].floor() - grow).max(0.0) as usize;
    let y0 = (bbox[1].floor() - grow).max(0.0) as usize;
    let x1 = ((bbox[2].ceil() + grow) as usize).min(width.checked_sub(1)?);
    let y1 = ((bbox[3].ceil() + grow) as usize).min(height.checked_sub(1)?);
    if x1 < x0 + 3 || y1 < y0 + 3 {
        return None;
    }
    let at = |x: usize, y: usize| f64::from(frame[y * width + x]);
    let mut ring: Vec<f64> = (x0..=x1).flat_map(|x| [at(x, y0), at(x, y1)]).collect();
    ring.extend((y0 + 1..y1).flat_map(|y| [at(x0, y), at(x1, y)]));
    let floor = median(&mut ring);
    let (mut sum, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let v = (at(x, y) - floor).max(0.0);
            sum += v;
            sx += v * x as f64;
            sy += v * y as f64;
        }
    }
    (sum > 0.0).then(|| [sx / sum, sy / sum])
}

fn errors(run: &Measured, reference: &Measured) -> Errors {
    let (mut sq, mut max, mut n) = (0.0f64, 0.0f64, 0usize);
    for (a, b) in run.frames.iter().zip(&reference.frames) {
        for (&x, &y) in a.iter().zip(b) {
            let d = f64::from(x) - f64::from(y);
            sq += d * d;
            max = max.max(d.abs());
            n += 1;
        }
    }
    let mut centroid_px: Option<f64> = None;
    for (k, (la, lr)) in run.labels.iter().zip(&reference.labels).enumerate() {
        for (ta, tr) in la.targets.iter().zip(&lr.targets) {
            if !(ta.in_frame && tr.in_frame) {
                continue;
            }
            let a = centroid(&run.frames[k], run.width, tr.bbox_px);
            let r = centroid(&reference.frames[k], reference.width, tr.bbox_px);
            if let (Some(a), Some(r)) = (a, r) {
                let d = (a[0] - r[0]).abs().max((a[1] - r[1]).abs());
                centroid_px = Some(centroid_px.map_or(d, |c| c.max(d)));
            }
        }
    }
    Errors { rms_dn: (sq / n.max(1) as f64).sqrt(), max_dn: max, centroid_px }
}

fn centroid_cell(e: &Errors) -> String {
    e.centroid_px.map_or("–".to_string(), |c| format!("{c:.4}"))
}

/// The slope of `ln y` against `ln x` by least squares.
fn exponent(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (lx, ly): (Vec<f64>, Vec<f64>) = points.iter().map(|&(x, y)| (x.ln(), y.ln())).unzip();
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = lx.iter().map(|x| (x - mx) * (x - mx)).sum();
    if sxx > 0.0 { sxy / sxx } else { f64::NAN }
}

const SERIES_COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// Errors below this are drawn at it on the log axes, DN.
const FLOOR: f64 = 1e-4;

/// One plot's points: a series name and its labelled points.
type Series = (String, Vec<(f64, f64, String)>);

/// The median (the upper one of an even count) of `v`, sorting it; NaN for none.
pub(super) fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { f64::NAN } else { v[v.len() / 2] }
}

/// A text box: left, top, right, bottom, px.
type TextBox = (i32, i32, i32, i32);

/// Where each point's label goes, as the offset of the text's top-left corner from the point (px): the first of
/// eight places around the point whose box stays inside `area` and clears the labels placed before and every
/// point's marker; where none does, the place that overlaps least. `points` are pixel positions, `widths` the
/// labels' estimated widths, `height` their height.
fn place_labels(
    points: &[(i32, i32)],
    widths: &[i32],
    height: i32,
    area: TextBox,
    blocked: &[TextBox],
) -> Vec<(i32, i32)> {
    let overlap = |a: TextBox, b: TextBox| {
        let w = (a.2.min(b.2) - a.0.max(b.0)).max(0);
        let h = (a.3.min(b.3) - a.1.max(b.1)).max(0);
        i64::from(w) * i64::from(h)
    };
    const R: i32 = 6; // a marker's radius and a gap
    let markers: Vec<TextBox> = points.iter().map(|&(x, y)| (x - R, y - R, x + R, y + R)).collect();
    let mut placed: Vec<TextBox> = blocked.to_vec();
    let mut offsets = Vec::new();
    for (&(x, y), &w) in points.iter().zip(widths) {
        let candidates = [
            (R, -height - 2),
            (R, 2),
            (-R - w, -height - 2),
            (-R - w, 2),
            (-w / 2, -height - R - 2),
            (-w / 2, R + 2),
            (R, -2 * height - 4),
            (R, height + 4),
        ];
        let cost = |&(dx, dy): &(i32, i32)| {
            let b = (x + dx, y + dy, x + dx + w, y + dy + height);
            let outside = i64::from(w) * i64::from(height) - overlap(b, area);
            let hits: i64 = placed.iter().chain(&markers).map(|&o| overlap(b, o)).sum();
            // leaving the plot is worse than covering another label
            4 * outside + hits
        };
        let best = candidates.iter().copied().min_by_key(cost).unwrap_or((R, -height - 2));
        placed.push((x + best.0, y + best.1, x + best.0 + w, y + best.1 + height));
        offsets.push(best);
    }
    offsets
}

/// The corner of `area` for a legend box of `size` (px) that covers the fewest `points`, and that box.
fn legend_corner(points: &[(i32, i32)], size: (i32, i32), area: TextBox) -> (SeriesLabelPosition, TextBox) {
    const GAP: i32 = 12; // the legend's distance from the corner, and room around the markers
    let (w, h) = size;
    let corners = [
        (SeriesLabelPosition::UpperLeft, (area.0, area.1, area.0 + w + GAP, area.1 + h + GAP)),
        (SeriesLabelPosition::UpperRight, (area.2 - w - GAP, area.1, area.2, area.1 + h + GAP)),
        (SeriesLabelPosition::LowerLeft, (area.0, area.3 - h - GAP, area.0 + w + GAP, area.3)),
        (SeriesLabelPosition::LowerRight, (area.2 - w - GAP, area.3 - h - GAP, area.2, area.3)),
    ];
    let covered = |b: &TextBox| {
        points.iter().filter(|&&(x, y)| x + GAP > b.0 && x - GAP < b.2 && y + GAP > b.1 && y - GAP < b.3).count()
    };
    let mut best = corners[0].clone();
    for c in corners {
        if covered(&c.1) < covered(&best.1) {
            best = c;
        }
    }
    best
}

/// A log–log plot of labelled points (`lines`: joined in order) written as a PNG.
fn plot(path: &Path, title: &str, x_desc: &str, y_desc: &str, series: &[Series], lines: bool) -> Result<(), CliError> {
    let (w, h) = (900u32, 600u32);
    let all: Vec<(f64, f64)> =
        series.iter().flat_map(|s| s.1.iter().map(|p| (p.0, p.1))).filter(|p| p.0 > 0.0 && p.1 > 0.0).collect();
    if all.is_empty() {
        return Ok(());
    }
    let range = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::INFINITY, 0.0f64), |(lo, hi), x| (lo.min(x), hi.max(x)));
        // at least a decade and a half, so that the log axis has labelled ticks
        let widen = (30.0 / (hi / lo)).sqrt().max(1.6);
        (lo / widen, hi * widen)
    };
    let (x0, x1) = range(&mut all.iter().map(|p| p.0));
    let (y0, y1) = range(&mut all.iter().map(|p| p.1));
    let floor = all.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(failed)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d(
                (x0..x1).log_scale().with_key_points(card::log_ticks(x0, x1)),
                (y0..y1).log_scale().with_key_points(card::log_ticks(y0, y1)),
            )
            .map_err(failed)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .x_label_formatter(&|v| format!("{v}"))
            .y_label_formatter(&|v| format!("{v}"))
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()
            .map_err(failed)?;
        // every label placed together, clear of the others and of every marker
        let shown: Vec<Vec<(f64, f64, String)>> = series
            .iter()
            .map(|(_, points)| {
                points
                    .iter()
                    .filter(|p| p.0 > 0.0 && p.1 > 0.0)
                    .map(|(x, y, label)| {
                        // points on the error floor crowd together: their names are in the report's table
                        let label = if !lines && *y <= floor && floor <= FLOOR { String::new() } else { label.clone() };
                        (*x, *y, label)
                    })
                    .collect()
            })
            .collect();
        let flat: Vec<&(f64, f64, String)> = shown.iter().flatten().collect();
        let pixels: Vec<(i32, i32)> = flat.iter().map(|p| chart.backend_coord(&(p.0, p.1))).collect();
        let widths: Vec<i32> = flat.iter().map(|p| (7 * p.2.chars().count()) as i32).collect();
        let (xr, yr) = chart.plotting_area().get_pixel_range();
        let area = (xr.start, yr.start, xr.end, yr.end);
        let legend_size = (
            10 + 7 * series.iter().map(|s| s.0.chars().count()).max().unwrap_or(0) as i32 + 40,
            20 * series.len() as i32 + 12,
        );
        let (legend_at, legend_box) = legend_corner(&pixels, legend_size, area);
        let mut offsets = place_labels(&pixels, &widths, 14, area, &[legend_box]).into_iter();
        for (i, ((name, _), points)) in series.iter().zip(&shown).enumerate() {
            let color = SERIES_COLORS[i % SERIES_COLORS.len()];
            let placed: Vec<(i32, i32)> = offsets.by_ref().take(points.len()).collect();
            if lines {
                chart
                    .draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.1)), color.stroke_width(2)))
                    .map_err(failed)?;
            }
            chart
                .draw_series(points.iter().zip(placed).map(|((x, y, label), offset)| {
                    EmptyElement::at((*x, *y))
                        + Circle::new((0, 0), 5, color.filled())
                        + Text::new(label.clone(), offset, ("sans-serif", 13))
                }))
                .map_err(failed)?
                .label(name.as_str())
                .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 15))
            .position(legend_at)
            .draw()
            .map_err(failed)?;
        root.present().map_err(failed)?;
    }
    write_png(path, w, h, buf)
}

/// An RGB buffer written as a PNG, atomically.
fn write_png(path: &Path, w: u32, h: u32, buf: Vec<u8>) -> Result<(), CliError> {
    let png = card::rgb_png(w, h, buf).map_err(failed)?;
    write_atomic(path, &png).map_err(failed)
}

/// One Pareto chart per switch, in a grid: each setting's time per frame against its rms error (log, errors
/// below [`FLOOR`] drawn at it), labelled with its value; the settings no other beats on both axes joined.
fn pareto_panels(path: &Path, title: &str, panels: &[Series]) -> Result<(), CliError> {
    if panels.is_empty() {
        return Ok(());
    }
    let columns = 4usize;
    let rows = panels.len().div_ceil(columns);
    let (pw, ph) = (400u32, 290u32);
    let (w, h) = (pw * columns as u32, ph * rows as u32 + 50);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(failed)?;
        let root = root.titled(title, ("sans-serif", 24)).map_err(failed)?;
        let areas = root.split_evenly((rows, columns));
        for ((name, points), area) in panels.iter().zip(areas) {
            let (lo, hi) = points.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| (lo.min(p.0), hi.max(p.0)));
            let pad = ((hi - lo) * 0.25).max(hi * 0.05);
            let top = points.iter().map(|p| p.1).fold(FLOOR, f64::max);
            let mut chart = ChartBuilder::on(&area)
                .caption(name, ("sans-serif", 16))
                .margin(10)
                .x_label_area_size(34)
                .y_label_area_size(56)
                .build_cartesian_2d((lo - pad).max(0.0)..hi + pad, (FLOOR / 2.0..top * 20.0).log_scale())
                .map_err(failed)?;
            chart
                .configure_mesh()
                .x_desc("ms per frame")
                .y_desc("rms DN")
                .x_labels(4)
                .y_labels(5)
                .x_label_formatter(&|v| format!("{v:.2}"))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .label_style(("sans-serif", 12))
                .axis_desc_style(("sans-serif", 13))
                .draw()
                .map_err(failed)?;
            // the front: by time, each point that is more accurate than every faster one
            let mut by_time: Vec<_> = points.clone();
            by_time.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut front = Vec::new();
            let mut best = f64::INFINITY;
            for p in by_time.iter().rev() {
                if p.1 < best {
                    best = p.1;
                    front.push((p.0, p.1));
                }
            }
            chart.draw_series(LineSeries::new(front, SERIES_COLORS[0].stroke_width(2))).map_err(failed)?;
            let labels: Vec<String> = points
                .iter()
                .map(|p| {
                    if p.2.chars().count() > 22 {
                        p.2.chars().take(21).collect::<String>() + "…"
                    } else {
                        p.2.clone()
                    }
                })
                .collect();
            // placed clear of each other and of the markers, as in the single plots (settings whose points fall
            // together otherwise write over each other)
            let pixels: Vec<(i32, i32)> = points.iter().map(|p| chart.backend_coord(&(p.0, p.1))).collect();
            let widths: Vec<i32> = labels.iter().map(|l| (7 * l.chars().count()) as i32).collect();
            let (xr, yr) = chart.plotting_area().get_pixel_range();
            let offsets = place_labels(&pixels, &widths, 12, (xr.start, yr.start, xr.end, yr.end), &[]);
            chart
                .draw_series(points.iter().zip(labels).zip(offsets).enumerate().map(|(k, (((x, y, _), label), at))| {
                    let color = if k == 0 { RGBColor(120, 120, 120) } else { SERIES_COLORS[k % SERIES_COLORS.len()] };
                    // the label in its point's colour, so that a label set beside another point still names its own
                    let style = ("sans-serif", 12).into_font().color(&color);
                    EmptyElement::at((*x, *y)) + Circle::new((0, 0), 5, color.filled()) + Text::new(label, at, style)
                }))
                .map_err(failed)?;
        }
        root.present().map_err(failed)?;
    }
    write_png(path, w, h, buf)
}

/// The calendar date (UTC) of the current time.
fn today() -> String {
    let days = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs() / 86_400);
    // days since 1970-01-01 to a civil date (proleptic Gregorian)
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {cores} threads")
}

fn progress(what: &str) {
    eprintln!("report: {what}");
}

/// The skips measured on every scenario, with the pipeline stage whose time each saves.
const SKIPS: [(&str, &str); 4] = [
    ("psf_skip_below_dn", "render"),
    ("fusion_skip_below_sigma", "fusion"),
    ("reflection_skip_below_dn", "radiometry"),
    ("radiometry_tolerance", "radiometry"),
];

/// A switch's value in a preset, as TOML.
fn skip_value_in(p: QualityPreset, switch: &str) -> String {
    Quality::preset(p).describe().into_iter().find(|d| d.0 == switch).map(|d| d.1).unwrap_or_default()
}

/// Whether a skip's value (TOML) turns it on.
fn skips(value: &str) -> bool {
    value.parse::<f64>().is_ok_and(|v| v > 0.0)
}

/// The value that turns a skip on: standard's where standard skips, else draft's.
fn skip_value(switch: &str) -> String {
    let standard = skip_value_in(QualityPreset::Standard, switch);
    if skips(&standard) { standard } else { skip_value_in(QualityPreset::Draft, switch) }
}

/// `irsim bench report`.
///
/// # Errors
/// [`CliError::Invalid`] for a bad scenario or an output directory that holds a report (without --force);
/// [`CliError::Failed`] if a file cannot be written.
pub fn report(a: &ReportArgs) -> Result<(), CliError> {
    let plan = Plan::new(a);
    if a.out.exists() && !a.out.is_dir() {
        return Err(CliError::Invalid(format!("{}: is not a directory", a.out.display())));
    }
    let md_path = a.out.join("speed_vs_error.md");
    if md_path.exists() && !a.force {
        return Err(CliError::Invalid(format!("{}: holds a report already (--force replaces it)", a.out.display())));
    }
    card::register_plot_font();
    let started = Instant::now();
    let steal_since = super::steal::CpuTicks::now();
    let mut scenario_paths: Vec<PathBuf> = std::fs::read_dir(&a.scenarios)
        .map_err(|e| CliError::Invalid(format!("{}: {e}", a.scenarios.display())))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    scenario_paths.sort();
    // with fewer than all, those that exercise the most: cloud edges, several targets, a sky image
    let rank = |p: &PathBuf| {
        let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        ["sense_and_avoid", "swarm", "paper_cloudy_sky"].iter().position(|n| *n == stem).unwrap_or(usize::MAX)
    };
    if scenario_paths.len() > plan.max_scenarios {
        scenario_paths.sort_by_key(|p| rank(p));
        scenario_paths.truncate(plan.max_scenarios);
        scenario_paths.sort();
    }
    if scenario_paths.is_empty() {
        return Err(CliError::Invalid(format!("{}: no scenario (.toml) files", a.scenarios.display())));
    }
    let load = |p: &Path| {
        load_for_frames(p, Some(plan.error_frames.max(plan.time_frames + 2)))
            .map_err(|e| CliError::Invalid(e.to_string()))
    };
    let scenarios = scenario_paths.iter().map(|p| load(p)).collect::<Result<Vec<_>, _>>()?;
    // and as written, for their whole runs
    let whole = |p: &Path| load_for_frames(p, None).map_err(|e| CliError::Invalid(e.to_string()));
    let as_written = scenario_paths.iter().map(|p| whole(p)).collect::<Result<Vec<_>, _>>()?;
    // the directory only once the input is known to be good
    std::fs::create_dir_all(&a.out).map_err(|e| failed(format!("{}: {e}", a.out.display())))?;
    let mut md = String::new();
    let mode = if a.tiny {
        " --tiny"
    } else if a.quick {
        " --quick"
    } else {
        ""
    };
    let _ = writeln!(md, "# Speed against error\n");
    let _ = writeln!(
        md,
        "Made by `irsim bench report --out {}{mode}` (irsim {}) on {} ({}), {} frames compared and {} timed per \
         case. Errors are against the `reference` preset on the same input with the noise off: the frame's rms and \
         largest difference in DN before quantization, and the largest difference of a target's intensity centroid in px (\"–\": no \
         target in the frames). {} The machine may be shared, so compare times within one report. \
         Each run is planned for the frames compared and timed ({} here). A scenario's whole run is timed apart: its set-up \
         with nothing kept from earlier runs (the shipped LOWTRAN table, decoded once per process, aside) and all of its own \
         frames, headless, noise on, planned for them (timed as the frames of a scenario are); a preset plans for the frames \
         it runs (draft's sky blur builds a prefiltered texture only where enough frames use it), so on a short scenario the \
         speed-ups per frame and over the whole run can differ.\n",
        a.out.display(),
        env!("CARGO_PKG_VERSION"),
        machine(),
        today(),
        plan.error_frames,
        plan.time_frames,
        timing_text(&plan),
        plan.error_frames.max(plan.time_frames + 2),
    );

    // 1. presets on the shipped scenarios
    progress("presets on the scenarios");
    let _ = writeln!(md, "## Presets on the scenarios\n");
    let _ = writeln!(
        md,
        "| scenario | reference ms | standard ms | draft ms | standard rms / max DN | standard centroid px | draft \
         rms / max DN | draft centroid px | draft speed-up over standard: per frame / whole run |\n\
         |---|---|---|---|---|---|---|---|---|"
    );
    let mut preset_points: Vec<Series> = vec![("standard".into(), Vec::new()), ("draft".into(), Vec::new())];
    let mut skip_rows = Vec::new();
    for ((path, s), written) in scenario_paths.iter().zip(&scenarios).zip(&as_written) {
        let name = path.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        progress(&format!("  {name}"));
        let r = measure(&preset(s, QualityPreset::Reference)?, &plan)?;
        // standard, draft and each skip's other setting over standard, timed in the same rounds: the speed-up and
        // the savings are differences of these times
        let mut cases = vec![preset(s, QualityPreset::Standard)?, preset(s, QualityPreset::Draft)?];
        for &(switch, _) in &SKIPS {
            let value =
                if skips(&skip_value_in(QualityPreset::Standard, switch)) { "0".into() } else { skip_value(switch) };
            cases.push(one_switch(s, QualityPreset::Standard, switch, &value)?);
        }
        let measured = measure_together(&cases, &plan)?;
        let (st, dr) = (&measured[0], &measured[1]);
        let (es, ed) = (errors(st, &r), errors(dr, &r));
        let whole = whole_runs_ms(
            &[preset(written, QualityPreset::Standard)?, preset(written, QualityPreset::Draft)?],
            plan.rounds,
        )?;
        let _ = writeln!(
            md,
            "| {name} | {:.2} | {:.2} | {:.2} | {:.3} / {:.2} | {} | {:.3} / {:.2} | {} | {:.2}× / {:.2}× |",
            r.ms_per_frame,
            st.ms_per_frame,
            dr.ms_per_frame,
            es.rms_dn,
            es.max_dn,
            centroid_cell(&es),
            ed.rms_dn,
            ed.max_dn,
            centroid_cell(&ed),
            st.ms_per_frame / dr.ms_per_frame,
            whole[0] / whole[1]
        );
        // the skips of the last section against the same standard run
        for (&(switch, stage), other) in SKIPS.iter().zip(&measured[2..]) {
            let on = skip_value(switch);
            let standard_skips = skips(&skip_value_in(QualityPreset::Standard, switch));
            let (skipping, full) = if standard_skips { (st, other) } else { (other, st) };
            let changed = errors(skipping, full);
            let stage_of = |m: &Measured| m.stage_ms.iter().find(|x| x.0 == stage).map_or(f64::NAN, |x| x.1);
            let stage_saved = 1e3 * (stage_of(full) - stage_of(skipping));
            let stage_cell =
                if stage_saved.is_finite() { format!("{stage} {stage_saved:.1}") } else { "–".to_string() };
            skip_rows.push(format!(
                "| {name} | `{switch} = {on}` | {:.3} | {stage_cell} | {:.3} |",
                full.ms_per_frame - skipping.ms_per_frame,
                changed.max_dn
            ));
        }
        preset_points[0].1.push((st.ms_per_frame, es.rms_dn.max(FLOOR), name.clone()));
        preset_points[1].1.push((dr.ms_per_frame, ed.rms_dn.max(FLOOR), name));
    }
    plot(
        &a.out.join("presets_scenarios.png"),
        "Presets on the scenarios",
        "ms per frame",
        "rms error against reference, DN",
        &preset_points,
        false,
    )?;
    let _ = writeln!(md, "\n![presets on the scenarios](presets_scenarios.png)\n");

    // 2. the whole pipeline on synthetic cases
    progress("presets on synthetic cases");
    let dir = bench_dir("report")?;
    let synthetic = |w: u32, h: u32, n: usize| -> Result<CheckedScenario, CliError> {
        let path = dir.join(format!("case_{w}x{h}_{n}.toml"));
        std::fs::write(&path, bench_scenario(w, h, n)).map_err(failed)?;
        load(&path)
    };
    let _ = writeln!(md, "## The whole pipeline\n");
    let _ = writeln!(
        md,
        "A paper camera (`paper_lwir_256` optics at the size given) looking at a generated clear sky, with targets \
         circling in view (the cases of `irsim bench`).\n\n| case | preset | frames/s | rms / max DN | centroid px |\n|---|---|---|---|---|"
    );
    let mut pipeline_points: Vec<Series> = vec![("standard".into(), Vec::new()), ("draft".into(), Vec::new())];
    let mut centroid_points: Vec<Series> = pipeline_points.clone();
    for &(w, h, n) in &plan.cases {
        progress(&format!("  {w}x{h}, {n} targets"));
        let s = synthetic(w, h, n)?;
        let r = measure(&preset(&s, QualityPreset::Reference)?, &plan)?;
        let _ = writeln!(md, "| {w}×{h}, {n} | reference | {:.1} | 0 / 0 | 0 |", 1e3 / r.ms_per_frame);
        let presets = [QualityPreset::Standard, QualityPreset::Draft];
        let cases = presets.iter().map(|&p| preset(&s, p)).collect::<Result<Vec<_>, _>>()?;
        for (k, (p, m)) in presets.into_iter().zip(measure_together(&cases, &plan)?).enumerate() {
            let e = errors(&m, &r);
            let _ = writeln!(
                md,
                "| {w}×{h}, {n} | {} | {:.1} | {:.3} / {:.2} | {} |",
                p.name(),
                1e3 / m.ms_per_frame,
                e.rms_dn,
                e.max_dn,
                centroid_cell(&e)
            );
            pipeline_points[k].1.push((1e3 / m.ms_per_frame, e.rms_dn.max(FLOOR), format!("{w}×{h}, {n}")));
            if let Some(c) = e.centroid_px {
                centroid_points[k].1.push((1e3 / m.ms_per_frame, c.max(FLOOR), format!("{w}×{h}, {n}")));
            }
        }
    }
    plot(
        &a.out.join("presets_pipeline.png"),
        "The whole pipeline",
        "frames per second",
        "rms error against reference, DN",
        &pipeline_points,
        false,
    )?;
    plot(
        &a.out.join("presets_pipeline_centroid.png"),
        "The whole pipeline: where the targets are",
        "frames per second",
        "largest centroid error against reference, px",
        &centroid_points,
        false,
    )?;
    let _ = writeln!(
        md,
        "\n![the whole pipeline](presets_pipeline.png)\n\n![the whole pipeline, centroid error](presets_pipeline_centroid.png)\n"
    );

    // 3. every switch against the reference, one at a time
    let base = scenarios
        .iter()
        .find(|s| s.source.file_stem().is_some_and(|n| n == "sense_and_avoid"))
        .unwrap_or(&scenarios[0]);
    let base_name = base.source.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    progress(&format!("each switch on {base_name}"));
    let _ = writeln!(md, "## Each switch\n");
    let _ = writeln!(
        md,
        "`{base_name}` with the `reference` preset and one switch set to the value another preset gives it; the \
         rest stay at the reference. Rows where the value is the reference's are left out.\n\n| switch | value | \
         ms per frame | rms / max DN | centroid px |\n|---|---|---|---|---|"
    );
    let reference = measure(&preset(base, QualityPreset::Reference)?, &plan)?;
    let _ = writeln!(md, "| (reference) | | {:.2} | 0 / 0 | 0 |", reference.ms_per_frame);
    let describe = |p: QualityPreset| Quality::preset(p).describe();
    let (refs, stds, drafts) =
        (describe(QualityPreset::Reference), describe(QualityPreset::Standard), describe(QualityPreset::Draft));
    let mut switch_points: Vec<Series> =
        vec![("standard's value".into(), Vec::new()), ("draft's value".into(), Vec::new())];
    let mut panels: Vec<Series> = Vec::new();
    for name in SWITCHES.iter().skip(1) {
        let value =
            |d: &[(&str, String, bool)]| d.iter().find(|x| x.0 == *name).map(|x| x.1.clone()).unwrap_or_default();
        let reference_value = value(&refs);
        let mut tried: Vec<String> = Vec::new();
        for (k, v) in [value(&stds), value(&drafts)].into_iter().enumerate() {
            if (k == 1 && !plan.all_values) || v == reference_value || tried.contains(&v) {
                continue;
            }
            tried.push(v.clone());
            let m = measure(&one_switch(base, QualityPreset::Reference, name, &v)?, &plan)?;
            let e = errors(&m, &reference);
            let _ = writeln!(
                md,
                "| `{name}` | `{v}` | {:.2} | {:.3} / {:.2} | {} |",
                m.ms_per_frame,
                e.rms_dn,
                e.max_dn,
                centroid_cell(&e)
            );
            switch_points[k].1.push((m.ms_per_frame, e.rms_dn.max(FLOOR), (*name).to_string()));
            if tried.len() == 1 {
                panels.push(((*name).to_string(), vec![(reference.ms_per_frame, FLOOR, reference_value.clone())]));
            }
            if let Some(panel) = panels.last_mut() {
                panel.1.push((m.ms_per_frame, e.rms_dn.max(FLOOR), v.clone()));
            }
        }
    }
    plot(
        &a.out.join("switches.png"),
        &format!("Each switch against the reference ({base_name})"),
        "ms per frame",
        "rms error against reference, DN (floor 1e-4)",
        &switch_points,
        false,
    )?;
    let _ = writeln!(md, "\n![each switch](switches.png)\n");
    pareto_panels(
        &a.out.join("switch_pareto.png"),
        &format!("Per switch: time against error ({base_name}; grey: the reference value)"),
        &panels,
    )?;
    let _ = writeln!(
        md,
        "Per switch, its settings' time against error, the reference's in grey at the error floor; the line joins \
         the settings no other beats on both.\n\n![per switch](switch_pareto.png)\n"
    );

    // 4. scaling
    progress("scaling");
    let _ = writeln!(md, "## Scaling (standard preset)\n");
    // timing alone, unless there is no timing run (then the compared frames are the timed ones)
    let plan_timing = Plan { error_frames: if plan.time_frames > 0 { 0 } else { plan.error_frames }, ..plan.clone() };
    // every point of both curves in the same rounds, so that a slow minute bends neither
    let mut cases = Vec::new();
    for &n in &plan.targets {
        cases.push(preset(&synthetic(plan.target_size.0, plan.target_size.1, n)?, QualityPreset::Standard)?);
    }
    for &side in &plan.sizes {
        cases.push(preset(&synthetic(side, side, 1)?, QualityPreset::Standard)?);
    }
    let times: Vec<f64> = measure_together(&cases, &plan_timing)?.iter().map(|m| m.ms_per_frame).collect();
    let (target_times, size_times) = times.split_at(plan.targets.len());
    let by_targets: Vec<_> =
        plan.targets.iter().zip(target_times).map(|(&n, &ms)| (n as f64, ms, format!("{n}"))).collect();
    let by_size: Vec<_> = plan
        .sizes
        .iter()
        .zip(size_times)
        .map(|(&side, &ms)| (f64::from(side * side), ms, format!("{side}²")))
        .collect();
    drop(dir);
    // the marginal cost of targets: time above the fewest-target case, fitted where it is measurable
    let t1 = by_targets.first().map_or(0.0, |p| p.1);
    let marginal: Vec<(f64, f64)> = by_targets.iter().skip(1).map(|p| (p.0, p.1 - t1)).filter(|p| p.1 > 0.0).collect();
    let k_targets = exponent(&by_targets.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>());
    let k_marginal = if marginal.len() >= 2 { exponent(&marginal) } else { f64::NAN };
    let k_size = exponent(&by_size.iter().map(|p| (p.0, p.1)).collect::<Vec<_>>());
    let _ = writeln!(md, "| targets ({}×{}) | ms per frame |\n|---|---|", plan.target_size.0, plan.target_size.1);
    for p in &by_targets {
        let _ = writeln!(md, "| {} | {:.2} |", p.2, p.1);
    }
    let _ = writeln!(md, "\n| size (1 target) | ms per frame | ns per pixel |\n|---|---|---|");
    for p in &by_size {
        let _ = writeln!(md, "| {} | {:.2} | {:.1} |", p.2, p.1, p.1 * 1e6 / p.0);
    }
    let marginal_text = if k_marginal.is_finite() {
        format!("{k_marginal:.2}")
    } else {
        "not measurable (below the timing noise)".into()
    };
    let _ = writeln!(
        md,
        "\nFitted exponents (least squares on log–log): time against targets {k_targets:.2}, the time above one \
         target against targets {marginal_text}; time against pixels {k_size:.2}. Each target's work (its \
         radiometry, patch and fusion region) is independent of the others', so the time above one target should \
         grow linearly (exponent 1) once it is measurable, and the whole frame sublinearly while the per-pixel \
         work dominates. Every per-pixel stage (ray cast, blur, noise, quantization) is linear in the pixels, so \
         the exponent against pixels should approach 1 as the size grows past the fixed per-frame cost.\n"
    );
    plot(
        &a.out.join("scaling.png"),
        "Time per frame (standard)",
        "targets, or pixels / 1000",
        "ms per frame",
        &[
            ("targets".into(), by_targets.clone()),
            ("pixels / 1000 (1 target)".into(), by_size.iter().map(|p| (p.0 / 1e3, p.1, p.2.clone())).collect()),
        ],
        true,
    )?;
    let _ = writeln!(md, "![scaling](scaling.png)\n");

    // 5. per-call kernels whose error the noise-free frames cannot show
    progress("kernels");
    kernel_section(&mut md, if plan.all_values { 1 << 22 } else { 1 << 18 });

    // 6. what the skips save (measured with the presets, section 1)
    let _ = writeln!(md, "## Model only what a scene needs\n");
    let _ = writeln!(
        md,
        "Each skip on (the value standard or draft gives it) against off (0), over the `standard` preset, on each \
         scenario: the time saved per frame (whole frame, and in the stage the skip is in; timing noise is a few \
         per cent of a frame, so a small saving can show as negative), and the largest change of a pixel, noise off. \
         `psf_skip_below_dn`: tiles of the per-frame blur that it cannot change by more than this many DN keep \
         their values. `fusion_skip_below_sigma`: a target whose peak is below this many noise σ is added, not \
         fused. `reflection_skip_below_dn`: the sun's reflection is not computed where a bound on what it adds \
         to a pixel is below this (below the horizon it is zero and never computed). `radiometry_tolerance`: a \
         target's radiometry is computed again only when range, heading or speed change by more than this \
         fraction. The radiometry runs beside the sky render: its stage's time is its own, not the \
         frame's; so do the targets' shapes, whose time is part of the targets stage's.\n\n| scenario | skip | ms saved per frame | µs saved in stage | max DN changed |\n|---|---|---|---|---|"
    );
    for row in &skip_rows {
        let _ = writeln!(md, "{row}");
    }
    let _ = writeln!(md);

    progress("against the machine");
    machine_section(&mut md, &plan)?;
    guards_section(&mut md);
    progress("OpenCV");
    super::opencv::section(&mut md, &plan.opencv_sides);
    progress("atmosphere");
    super::atmosphere::section(&mut md);
    // said only where the host took some of the time (a machine that is not virtual has no steal time)
    let steal = super::steal::CpuTicks::since(steal_since).and_then(|c| c.share()).filter(|&s| s > 0.0);
    let _ = writeln!(
        md,
        "The report took {:.0} s{}.",
        started.elapsed().as_secs_f64(),
        steal.map_or_else(String::new, |s| format!(
            ", and this machine's host took {:.1} % of its CPU time meanwhile (steal time, /proc/stat; the more it \
             took, the less the times above are this machine's own)",
            100.0 * s
        ))
    );
    write_atomic(&md_path, md.as_bytes()).map_err(failed)?;
    super::say(&format!("wrote {}", md_path.display()))?;
    Ok(())
}

/// Each per-pixel stage beside its lower bound on this CPU (`irsim bench --limits`), and what recording 16-bit
/// PNG keeps of the headless rate on `irsim bench`'s cases.
fn machine_section(md: &mut String, plan: &Plan) -> Result<(), CliError> {
    let _ = writeln!(md, "## Against the machine\n");
    let rows = super::limits::measure_limits(plan.limits_frames, plan.rounds, &mut |_| Ok(()))?;
    let _ = writeln!(
        md,
        "`irsim bench --limits` in this run ({} frames each in {} interleaved rounds, each number its fastest round's: a \
         bound's median frame, the pipeline's mean; {} vectors): simple kernels that bound each \
         per-pixel stage from below (one bilinear sample of a texture per pixel; the detector's readout in place; \
         sample, noise and ADC fused in one pass), beside `irsim bench`'s built-in case (`standard`, one target, \
         and at 640 × 512 also with {WIDE_CASE_TARGETS} targets, the bounds timed again beside it) in a pool of the \
         same size. µs per frame; a frame includes every stage and the schedule's own.\n\n\
         | size | targets | threads | bilinear | readout | fused | render | noise | frame | render / bilinear \
         | noise / readout | frame / fused |\n|---|---|---|---|---|---|---|---|---|---|---|---|",
        plan.limits_frames,
        plan.rounds,
        crate::physics::simd::Level::detect().name(),
    );
    for r in &rows {
        let [render, noise, frame] = r.ratios();
        let [bilinear, readout, fused] = r.bilinear_readout_fused();
        let _ = writeln!(
            md,
            "| {} × {} | {} | {} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {render:.1}× | {noise:.1}× \
             | {frame:.1}× |",
            r.width, r.height, r.targets, r.threads, bilinear, readout, fused, r.render_us, r.noise_us, r.frame_us,
        );
    }
    let _ = writeln!(
        md,
        "\nRecording (`irsim record`'s loop, 16-bit PNG, `fast` compression, {} frames) against the same case \
         headless, timed just before and just after the recording in this run (the ratio is to their mean):\n\n\
         | case | headless frames/s, before and after | recording frames/s | ratio |\n|---|---|---|---|",
        plan.recording_frames
    );
    let dir = super::run::bench_dir("report-recording")?;
    for (w, h, n) in [(256u32, 256u32, 1usize), (640, 512, WIDE_CASE_TARGETS)] {
        let path = dir.join(format!("bench_{w}x{h}_{n}.toml"));
        std::fs::write(&path, super::run::bench_scenario(w, h, n)).map_err(failed)?;
        let scenario =
            load_for_frames(&path, Some(plan.recording_frames)).map_err(|e| CliError::Invalid(e.to_string()))?;
        let before = 1e6 / super::run::time_stages(&scenario, plan.recording_frames)?.frame_us;
        // a directory per case: recording over the last case's frames would first delete them, and on ext4
        // files made just after many deletions are slow to create (docs/accuracy.md)
        let out = dir.join(format!("out-{w}x{h}"));
        let done = super::run::time_recording(&path, &scenario, plan.recording_frames, None, &out)?;
        let after = 1e6 / super::run::time_stages(&scenario, plan.recording_frames)?.frame_us;
        let _ = writeln!(
            md,
            "| {w} × {h}, {n} target{} | {before:.0}, {after:.0} | {:.0} | {:.2} |",
            if n > 1 { "s" } else { "" },
            done.frames_per_s,
            done.frames_per_s / (0.5 * (before + after))
        );
    }
    drop(dir);
    let _ = writeln!(
        md,
        "\nThe frames are encoded by the simulation's own pool, on the cores the frame's stages leave idle; on a \
         machine with few cores the recording is bound by the CPU it shares with the simulation (encoding, \
         writing the files): README, \"Recording labelled sequences\".\n"
    );
    Ok(())
}

/// A kernel that runs with the CPU's vectors (chosen at run time), the tests that hold it to the scalar code or to
/// its law, and what they check: `(kernel, source, [(test file, test)], what)`.
type Guard = (&'static str, &'static str, &'static [(&'static str, &'static str)], &'static str);

/// Every per-pixel kernel written for the CPU's vectors, with the tests that guard it ([`guards_section`]; a test
/// checks that each test named here exists).
const GUARDS: &[Guard] = &[
    (
        "sky ray cast (nearest and bilinear spans, texel windows)",
        "imaging::sky_plane, physics::simd",
        &[
            ("src/imaging/sky_plane.rs", "the_vector_span_is_the_scalar_recurrence_bit_for_bit"),
            ("src/imaging/sky_plane.rs", "a_span_that_turns_beyond_the_image_is_not_stepped_in_fixed_point"),
            ("src/imaging/sky_plane.rs", "interpolated_coordinates_stay_within_the_tolerance"),
        ],
        "AVX-512 and AVX2 spans (where the CPU has them) the scalar recurrence bit for bit, forwards and backwards, \
         1 to 100 pixels, windowed and gathered; a span that would turn beyond the image refused, nothing written; \
         the quadratic through each span within the tolerance of the exact coordinates",
    ),
    (
        "normal deviates (Box–Muller sixteen pairs an AVX-512 register, eight an AVX2 one; ziggurat; table)",
        "physics::random",
        &[
            ("src/physics/random.rs", "the_box_muller_fill_is_the_scalar_transform_bit_for_bit"),
            ("src/physics/random.rs", "box_muller_s_functions_are_accurate"),
            ("src/physics/random.rs", "normal_deviates_follow_the_normal_law"),
            ("src/physics/random.rs", "every_16_bit_field_gives_the_scalar_deviate_in_a_run"),
        ],
        "the vector fills (AVX-512 and AVX2, where the CPU has them) the scalar transform bit for bit; its \
         logarithm, sine and cosine against f64's; the table fill the scalar deviate for all 2¹⁶ fields in every \
         lane; mean, variance, Kolmogorov–Smirnov distance and the tails beyond 2, 3, 3.5 and 4 σ on 2²¹ deviates \
         of each sampler",
    ),
    (
        "detector readout (electrons, noise, gain, ADC, rounding, clamp)",
        "physics::noise",
        &[
            ("src/physics/noise.rs", "the_fused_pass_is_the_general_path_bit_for_bit"),
            ("src/physics/noise.rs", "exact_poisson_samples_fit_the_law"),
            ("src/physics/noise.rs", "a_block_with_a_pixel_under_the_threshold_draws_exact_counts_there_alone"),
            ("src/physics/noise.rs", "row_parallel_noise_does_not_depend_on_thread_count"),
            ("src/physics/noise.rs", "quantization_rounds_halves_up_and_clamps"),
        ],
        "the fused AVX-512 pass the general path bit for bit (where the CPU has AVX-512); χ² of the exact Poisson \
         counts, drawn only at the pixels under the threshold; the same frame on one thread as on the pool; \
         rounding half up and clamping",
    ),
    (
        "optics: the blur's rows and columns, a target's PSF rows",
        "imaging::psf",
        &[
            ("src/imaging/psf.rs", "tiles_blurred_where_needed_are_the_separable_sums_bit_for_bit"),
            ("src/imaging/psf.rs", "blurs_where_needed_of_random_sizes_and_tiles_are_the_separable_sums_bit_for_bit"),
            (
                "src/imaging/psf.rs",
                "the_banded_separable_pass_is_the_whole_frame_passes_bit_for_bit_on_any_number_of_threads",
            ),
            ("src/imaging/psf.rs", "separable_direct_and_fft_agree"),
            ("src/imaging/psf.rs", "add_point_matches_value_at_every_pixel_centre"),
        ],
        "the blur where needed and the banded pass the separable sums bit for bit, on any number of threads; \
         direct against FFT; a point source's rows the PSF's value at every pixel centre",
    ),
    (
        "the dome along sixteen rays at a time (f32)",
        "physics::sky",
        &[("src/physics/sky.rs", "a_row_of_rays_gives_each_ray_s_radiance")],
        "sixteen rays at a time the scalar f32 loop bit for bit, windowed and gathered, and within 2·10⁻⁶ of the \
         sky's range of the f64 ray",
    ),
    (
        "Poisson fusion: transposes and the loops around the f32 sine transform",
        "imaging::fusion",
        &[
            ("src/imaging/fusion.rs", "the_transpose_is_the_transpose_at_every_simd_level_and_shape"),
            ("src/imaging/fusion.rs", "the_vector_loops_around_the_f32_transform_are_the_scalar_ones_bit_for_bit"),
            (
                "src/imaging/fusion.rs",
                "the_f32_solve_of_the_difference_is_the_f64_solve_within_four_hundredths_of_a_gray_level",
            ),
        ],
        "the dispatched and the AVX2 transposes (f64 and f32) the transpose by its definition on ten shapes from \
         1 × 1 to 254 × 71; the vector loops the scalar ones bit for bit; the f32 solve within 0.04 DN of the f64 \
         one",
    ),
    (
        "16-bit PNG: Huffman codes joined in vector registers (VBMI or BW)",
        "imaging::png16",
        &[
            ("src/imaging/png16.rs", "frames_read_back_exactly_through_other_decoders"),
            ("src/imaging/png16.rs", "eight_codes_to_a_store_write_the_stream_one_code_at_a_time_writes"),
        ],
        "the frames decoded by other decoders exactly; the vector coder's stream the one-code-at-a-time stream",
    ),
    (
        "ellipsoid reflectance, 64 points at a time",
        "physics::reflection, physics::brdf",
        &[
            ("src/physics/reflection.rs", "lanes_are_the_points_one_at_a_time"),
            ("src/physics/brdf.rs", "lanes_are_f_unit_bit_for_bit"),
        ],
        "the lanes the point-by-point sums and the BRDF bit for bit, every block length 1–64, grazing 0 and −0",
    ),
    (
        "the whole pipeline",
        "every stage",
        &[
            ("tests/cli_record.rs", "every_instruction_set_and_thread_count_gives_the_same_frames"),
            ("tests/sim.rs", "golden_frame_hashes"),
        ],
        "the same frame bytes with AVX-512, AVX2 and the baseline, on 1 and 2 threads; the golden frame hashes",
    ),
];

/// The tests that guard each vector kernel ([`GUARDS`]), as a table.
fn guards_section(md: &mut String) {
    let _ = writeln!(
        md,
        "### The tests that guard the vector kernels\n\nThe per-pixel kernels run with the widest vectors the CPU has \
         (AVX-512, AVX2 or the baseline, chosen at run time; `IRSIM_SIMD` caps it). These tests hold each to the \
         scalar code (bit for bit) or to its law, and run in CI; a comparison with an instruction set the CPU \
         running them lacks is skipped there.\n\n| kernel | module | tests | what they check \
         |\n|---|---|---|---|"
    );
    for (kernel, module, tests, what) in GUARDS {
        let names: Vec<String> = tests.iter().map(|(file, test)| format!("`{test}` ({file})")).collect();
        // module paths as code, a plain word as it is
        let modules: Vec<String> =
            module.split(", ").map(|m| if m.contains("::") { format!("`{m}`") } else { m.to_owned() }).collect();
        let _ = writeln!(md, "| {kernel} | {} | {} | {what} |", modules.join(", "), names.join("<br>"));
    }
    let _ = writeln!(md);
}

/// The normal samplers (`normal_sampler`): time per deviate, and their law against the normal one on `n`
/// deviates (Kolmogorov–Smirnov distance, the largest deviate, the mass beyond 4 σ).
fn kernel_section(md: &mut String, n: usize) {
    use crate::physics::noise::{ks_distance_normal, normal_cdf};
    use crate::physics::random::{NormalSampler, SplitMix64};
    let _ = writeln!(
        md,
        "## Kernels\n\nThe error of `normal_sampler` is in the noise, which the frames above leave out: here the \
         deviates themselves, {n} of them, against the normal law (the Kolmogorov–Smirnov distance, whose 1 % \
         critical value at this count is {:.1e}; the largest deviate; the share beyond 4 σ over the law's \
         {:.2e}). Time per deviate on one thread, best of five fills of the same buffer.\n\n| `normal_sampler` | \
         ns per deviate | KS distance | largest |z| | mass beyond 4 σ |\n|---|---|---|---|---|",
        1.63 / (n as f64).sqrt(),
        2.0 * normal_cdf(-4.0)
    );
    let mut z = vec![0f32; n];
    for sampler in [NormalSampler::Ziggurat, NormalSampler::BoxMuller, NormalSampler::Table] {
        let mut best = f64::INFINITY;
        for round in 0..5 {
            let mut rng = SplitMix64::substream(0x5EED, round);
            let t = Instant::now();
            sampler.fill(&mut rng, &mut z);
            best = best.min(t.elapsed().as_secs_f64());
        }
        let beyond = z.iter().filter(|v| v.abs() > 4.0).count() as f64 / n as f64;
        let largest = z.iter().fold(0f32, |m, v| m.max(v.abs()));
        z.sort_by(f32::total_cmp);
        let ks = ks_distance_normal(&z);
        let name = serde_json::to_value(sampler).ok().and_then(|v| v.as_str().map(str::to_owned)).unwrap_or_default();
        let _ = writeln!(md, "| `{name}` | {:.2} | {ks:.1e} | {largest:.2} | {beyond:.2e} |", best * 1e9 / n as f64);
    }
    let _ = writeln!(md);
    planck_rows(md);
}

/// The `planck` methods: time per band radiance and the largest relative error against the exact series, over
/// 200–1500 K in 10 K steps, in the 3–5 and 8–12 µm bands, in energy and photons.
fn planck_rows(md: &mut String) {
    use crate::physics::planck::{Band, Measure, PlanckMethod};
    let _ = writeln!(
        md,
        "The `planck` switch integrates a target's band radiance (its own, and the path's) over the band. Each \
         method against the exact series over 200–1500 K in 10 K steps, in the 3–5 and 8–12 µm bands, energy \
         and photons; time per evaluation on one thread (mean over those 528 calls, best of five). It is \
         evaluated a few times per target per frame, so even the series costs microseconds a frame.\n\n| \
         `planck` | ns per evaluation | largest relative error, 3–5 µm | largest relative error, 8–12 µm \
         |\n|---|---|---|---|"
    );
    let bands = [Band::try_new(3.0, 5.0), Band::try_new(8.0, 12.0)];
    let [Ok(mwir), Ok(lwir)] = bands else { return };
    let temps: Vec<f64> = (0..=130).map(|k| 200.0 + 10.0 * f64::from(k)).collect();
    let methods = [
        PlanckMethod::Series,
        PlanckMethod::GaussLegendre { points: 2 },
        PlanckMethod::GaussLegendre { points: 4 },
        PlanckMethod::GaussLegendre { points: 8 },
        PlanckMethod::Simpson { intervals: 8 },
        PlanckMethod::Simpson { intervals: 32 },
    ];
    for method in methods {
        let mut best = f64::INFINITY;
        let mut sink = 0.0;
        for _ in 0..5 {
            let t = Instant::now();
            for band in [mwir, lwir] {
                for measure in [Measure::Energy, Measure::Photon] {
                    for &k in &temps {
                        sink += method.band_radiance(measure, band, k, 1.0);
                    }
                }
            }
            best = best.min(t.elapsed().as_secs_f64());
        }
        std::hint::black_box(sink);
        let worst = |band: Band| {
            let mut e = 0.0f64;
            for measure in [Measure::Energy, Measure::Photon] {
                for &k in &temps {
                    let exact = PlanckMethod::Series.band_radiance(measure, band, k, 1.0);
                    e = e.max((method.band_radiance(measure, band, k, 1.0) / exact - 1.0).abs());
                }
            }
            e
        };
        let text = toml_text(&method);
        let _ = writeln!(
            md,
            "| `{text}` | {:.0} | {:.1e} | {:.1e} |",
            best * 1e9 / (4 * temps.len()) as f64,
            worst(mwir),
            worst(lwir)
        );
    }
    let _ = writeln!(md);
}

/// A switch value as the `[quality]` table writes it.
fn toml_text<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_value(v).map(|j| crate::scenario::quality::toml_value(&j)).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_guarding_test_named_exists() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        for (kernel, _, tests, _) in GUARDS {
            for (file, test) in *tests {
                let source = std::fs::read_to_string(root.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
                // the function, and a test attribute within the few lines above it
                let at =
                    source.find(&format!("fn {test}()")).unwrap_or_else(|| panic!("{kernel}: no {test} in {file}"));
                let before = &source[..at];
                let lines: Vec<&str> = before.lines().rev().take(4).collect();
                assert!(lines.iter().any(|l| l.trim() == "#[test]"), "{kernel}: {test} in {file} is not a test");
            }
        }
        let mut md = String::new();
        guards_section(&mut md);
        assert_eq!(md.lines().filter(|l| l.starts_with("| ")).count(), GUARDS.len() + 1, "{md}");
    }

    #[test]
    fn rounds_take_every_case_in_turn_and_keep_each_fastest() {
        // window lengths by call: case a 3, 1, 2; case b 5, 9, 7 (a slow second round for b)
        let lengths = [3.0, 5.0, 1.0, 9.0, 2.0, 7.0];
        let mut calls = Vec::new();
        let got = interleaved(&["a", "b"], 3, |c| {
            calls.push(*c);
            Ok((lengths[calls.len() - 1], (*c, calls.len())))
        })
        .unwrap();
        assert_eq!(calls, ["a", "b", "a", "b", "a", "b"]);
        // the fastest windows: a's second call (length 1), b's first (length 5)
        assert_eq!(got, [("a", 3), ("b", 2)]);
        let errs = interleaved(&[0, 1], 2, |&c| if c == 1 { Err(failed("boom")) } else { Ok((1.0, c)) });
        assert!(errs.is_err());
    }

    #[test]
    fn exponent_of_a_power_law() {
        let pts: Vec<(f64, f64)> = [1.0, 2.0, 4.0, 8.0].iter().map(|&x: &f64| (x, 3.0 * x.powf(1.5))).collect();
        assert!((exponent(&pts) - 1.5).abs() < 1e-12);
    }

    #[test]
    fn centroid_of_a_symmetric_spot() {
        let w = 20;
        let mut f = vec![10.0f32; w * w];
        for (dx, dy, v) in [(0, 0, 100.0), (1, 0, 50.0), (-1, 0, 50.0), (0, 1, 50.0), (0, -1, 50.0)] {
            f[((9 + dy) * w as i32 + 7 + dx) as usize] = 10.0 + v;
        }
        let c = centroid(&f, w, [6.0, 8.0, 8.0, 10.0]).unwrap();
        assert!((c[0] - 7.0).abs() < 1e-12 && (c[1] - 9.0).abs() < 1e-12, "{c:?}");
    }

    #[test]
    fn labels_of_crowded_points_do_not_overlap() {
        // three names at nearly one spot, as crossing_pair, paper_clear_sky and sense_and_avoid sit in the
        // scenarios' plot, and one far off
        let points = [(400, 300), (404, 302), (410, 300), (100, 100)];
        let widths = [84, 105, 105, 60];
        let offsets = place_labels(&points, &widths, 14, (0, 0, 800, 600), &[]);
        let boxes: Vec<TextBox> = points
            .iter()
            .zip(&offsets)
            .zip(&widths)
            .map(|((p, o), w)| (p.0 + o.0, p.1 + o.1, p.0 + o.0 + w, p.1 + o.1 + 14))
            .collect();
        for (i, a) in boxes.iter().enumerate() {
            assert!(a.0 >= 0 && a.1 >= 0 && a.2 <= 800 && a.3 <= 600, "label {i} leaves the plot: {a:?}");
            for b in &boxes[i + 1..] {
                let apart = a.2 <= b.0 || b.2 <= a.0 || a.3 <= b.1 || b.3 <= a.1;
                assert!(apart, "{a:?} and {b:?} overlap");
            }
        }
        // a label at the plot's right edge goes to the left of its point
        let o = place_labels(&[(790, 300)], &[80], 14, (0, 0, 800, 600), &[]);
        assert!(o[0].0 < 0, "{o:?}");
    }

    #[test]
    fn the_legend_goes_where_no_point_is() {
        let area = (0, 0, 800, 600);
        // points in the upper left and lower right: the legend takes an empty corner
        let (at, b) = legend_corner(&[(30, 20), (60, 40), (780, 590)], (120, 50), area);
        assert!(matches!(at, SeriesLabelPosition::UpperRight | SeriesLabelPosition::LowerLeft), "{at:?}");
        assert!(b.0 >= 0 && b.2 <= 800 && b.1 >= 0 && b.3 <= 600);
    }

    #[test]
    fn dates() {
        assert_eq!(today().len(), 10);
    }
}
