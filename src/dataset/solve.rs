//! Targets placed by signal-to-noise ratio: each target of a sequence moved along its line of sight until its
//! SNR at the middle frame (the label's `snr`, the simulation's own) is the one the spec drew for it.
//!
//! The SNR of a target against range has no closed form worth trusting here: it holds the target's size against
//! the PSF, the atmosphere's transmittance and path radiance along the slant path, the sky behind it (cloud or
//! clear) and the detector's shot noise. So the middle frame is simulated: the sequence's scene is built once,
//! and each iteration moves the targets (their trajectories, drawn again with the new ranges) and computes that
//! frame again. Ranges are found in `ln R` against `ln SNR` by the secant method, kept inside a bracket once
//! the SNR has been seen on both sides of the asked value (bisection where the secant leaves it), and within the
//! spec's `range_m`.

use std::path::Path;

use bevy::app::App;
use bevy::ecs::prelude::*;

use super::{DatasetSpec, Drawn, SkyFile};
use crate::scenario::load::{Format, load_str};
use crate::sim::{Aircraft, FlightPath, RunOptions, frame_at, headless_app};

/// A solve stops when every target's SNR is within this relative tolerance of the asked one.
pub const SNR_TOLERANCE: f64 = 0.01;
/// Most frames simulated per sequence.
pub const MAX_ITERATIONS: usize = 16;

/// What the solve found, per target.
#[derive(Debug, Clone, PartialEq)]
pub struct SolvedTarget {
    /// The SNR drawn for it.
    pub asked: f64,
    /// Its SNR at the middle frame at `range_m` (0 when it is not in view there).
    pub reached: f64,
    /// The range it is placed at, m.
    pub range_m: f64,
    /// Why `reached` differs from `asked` by more than the tolerance, if it does.
    pub limit: Option<&'static str>,
}

/// A sequence with its targets placed by SNR.
#[derive(Debug, Clone)]
pub struct Solved {
    /// The sequence, drawn at the solved ranges.
    pub drawn: Drawn,
    /// Per target.
    pub targets: Vec<SolvedTarget>,
    /// Frames simulated.
    pub iterations: usize,
}

/// One target's search in `x = ln R`, `y = ln SNR`.
#[derive(Debug, Clone)]
struct Search {
    goal: f64,
    lo: f64,
    hi: f64,
    /// Largest x seen with y above the goal, smallest seen with y below it.
    above: Option<f64>,
    below: Option<f64>,
    last: Option<(f64, f64)>,
    best: Option<(f64, f64)>,
    done: bool,
    limit: Option<&'static str>,
}

impl Search {
    /// Takes the SNR `y` found at `x` and gives the next x, or `None` when done.
    fn next(&mut self, x: f64, y: f64) -> Option<f64> {
        if !y.is_finite() {
            // not in view, or no contrast at all: nothing to solve for
            self.done = true;
            self.limit = Some("not in view at the middle frame, or no contrast");
            self.best.get_or_insert((x, y));
            return None;
        }
        let error = y - self.goal;
        if self.best.is_none_or(|(_, by)| error.abs() < (by - self.goal).abs()) {
            self.best = Some((x, y));
        }
        if error.abs() <= SNR_TOLERANCE.ln_1p() {
            self.done = true;
            return None;
        }
        if error > 0.0 {
            self.above = Some(self.above.map_or(x, |a: f64| a.max(x)));
        } else {
            self.below = Some(self.below.map_or(x, |b: f64| b.min(x)));
        }
        // the SNR falls with range: too high → farther
        if error > 0.0 && x >= self.hi {
            self.done = true;
            self.limit = Some("above the asked SNR even at the largest range");
            return None;
        }
        if error < 0.0 && x <= self.lo {
            self.done = true;
            self.limit = Some("below the asked SNR even at the smallest range");
            return None;
        }
        let slope = match self.last {
            Some((px, py)) if (x - px).abs() > 1e-9 && py.is_finite() => {
                let m = (y - py) / (x - px);
                if m < -0.05 { m } else { -2.0 }
            }
            // a point source's SNR falls as 1/R² before the air takes its share
            _ => -2.0,
        };
        self.last = Some((x, y));
        let step = (-error / slope).clamp(-8f64.ln(), 8f64.ln());
        let mut nx = (x + step).clamp(self.lo, self.hi);
        if let (Some(a), Some(b)) = (self.above, self.below) {
            if !(nx > a.min(b) && nx < a.max(b)) {
                nx = 0.5 * (a + b);
            }
            if (a - b).abs() < 1e-6 {
                self.done = true;
                self.limit = Some("the SNR jumps across the asked value (an edge of a cloud, or the ground)");
                return None;
            }
        }
        Some(nx)
    }
}

/// Sequence `k` of `spec` with every target at the range that gives it its asked SNR at the middle frame, or as
/// near as `range_m` allows; a spec without `snr` is drawn as it is. `base_dir` is where the scenario's
/// relative paths (the sky image) resolve.
///
/// # Errors
/// A message when the drawn scenario cannot be loaded or simulated (a bug, or a sky image gone).
pub fn solve(spec: &DatasetSpec, k: u64, skies: &[SkyFile], base_dir: &Path) -> Result<Solved, String> {
    let first = spec.draw(k, None, skies)?;
    if first.asked_snr.is_empty() {
        return Ok(Solved { drawn: first, targets: Vec::new(), iterations: 0 });
    }
    let [lo, hi] = spec.range_m();
    let mut searches: Vec<Search> = first
        .asked_snr
        .iter()
        .map(|&a| Search {
            goal: a.ln(),
            lo: lo.ln(),
            hi: hi.ln(),
            above: None,
            below: None,
            last: None,
            best: None,
            done: false,
            limit: None,
        })
        .collect();
    let load = |text: &str| {
        load_str(text, Format::Toml, Path::new("scenario.toml"), base_dir)
            .map_err(|e| format!("the drawn scenario is refused: {e}"))
    };
    let options = RunOptions { noise: false, ..RunOptions::default() };
    let mut app = headless_app(&load(&first.scenario())?, options).map_err(|e| e.to_string())?;
    let mut xs: Vec<f64> = first.drawn_ranges.iter().map(|r| r.clamp(lo, hi).ln()).collect();
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS && searches.iter().any(|s| !s.done) {
        let ranges: Vec<f64> = xs.iter().map(|x| x.exp()).collect();
        let snr = middle_snr(&mut app, spec, k, &ranges, skies, &load, first.middle_frame)?;
        iterations += 1;
        for (i, s) in searches.iter_mut().enumerate() {
            if s.done {
                continue;
            }
            if let Some(nx) = s.next(xs[i], snr.get(i).copied().unwrap_or(0.0).ln()) {
                xs[i] = nx;
            }
        }
    }
    let mut targets = Vec::new();
    let mut ranges = Vec::new();
    for s in &searches {
        let (x, y) = s.best.expect("every search saw one frame");
        let reached = if y.is_finite() { y.exp() } else { 0.0 };
        let limit = match s.limit {
            Some(l) => Some(l),
            None if ((y - s.goal).abs()) > SNR_TOLERANCE.ln_1p() => Some("not converged"),
            None => None,
        };
        targets.push(SolvedTarget { asked: s.goal.exp(), reached, range_m: x.exp(), limit });
        ranges.push(x.exp());
    }
    let drawn = spec.draw(k, Some(&ranges), skies)?;
    Ok(Solved { drawn, targets, iterations })
}

/// Each target's SNR at the middle frame with the targets at `ranges` (the scene stays; the targets' paths are
/// replaced by the ones drawn for these ranges).
fn middle_snr(
    app: &mut App,
    spec: &DatasetSpec,
    k: u64,
    ranges: &[f64],
    skies: &[SkyFile],
    load: &dyn Fn(&str) -> Result<crate::scenario::CheckedScenario, String>,
    middle: u64,
) -> Result<Vec<f64>, String> {
    let scenario = load(&spec.draw(k, Some(ranges), skies)?.scenario())?;
    let world = app.world_mut();
    let mut paths = world.query::<(&Aircraft, &mut FlightPath)>();
    for (aircraft, mut path) in paths.iter_mut(world) {
        if let Some(t) = scenario.target_trajectories.get(aircraft.id as usize - 1) {
            path.0 = t.clone();
        }
    }
    let ready = frame_at(app, middle).ok_or("the middle frame was not computed")?;
    let mut snr = vec![0.0; ranges.len()];
    for t in &ready.labels.targets {
        if t.in_frame
            && let Some(s) = snr.get_mut(t.id as usize - 1)
        {
            *s = t.snr;
        }
    }
    Ok(snr)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::headless_app;

    /// A spec with `extra` lines after its ranges: short sequences, a moving camera, every trajectory family.
    fn spec(extra: &str, observer: &str) -> DatasetSpec {
        let text = format!(
            "name = \"t\"\nseed = 9\nsequences = 40\nframes = 20\nquality = \"draft\"\nsensors = [\"paper_lwir_256\", \"cooled_mwir_insb\"]\ntargets_per_sequence = [1, 3]\nclasses = [\"small_multirotor\", \"fixed_wing_uav\", \"light_aircraft\", \"fighter\"]\ntrajectories = [\"straight\", \"crossing\", \"approach\", \"coordinated_turn\", \"weave\"]\n{extra}\n[observer]\n{observer}\n[sky]\nkinds = [\"none\"]\n"
        );
        DatasetSpec::from_str(&text, "t.toml").unwrap()
    }

    fn middle_labels(text: &str, middle: u64) -> crate::labels::FrameLabels {
        let scenario = load_str(text, Format::Toml, Path::new("s.toml"), Path::new(".")).unwrap();
        let mut app = headless_app(&scenario, RunOptions { noise: false, ..RunOptions::default() }).unwrap();
        frame_at(&mut app, middle).unwrap().labels
    }

    #[test]
    fn every_target_is_in_view_at_the_middle_frame_whatever_the_motion() {
        // a still camera, a straight flight and a turning, climbing one; fast targets turning hard
        for observer in [
            "",
            "speed_m_s = [20, 80]\nheading_deg = [-180, 180]",
            "speed_m_s = [20, 80]\nturn_rate_deg_s = [-12, 12]\nclimb_m_s = [-3, 3]",
        ] {
            let s = spec("range_m = [300, 3000]", observer);
            for k in 0..12 {
                let d = s.draw(k, None, &[]).unwrap();
                let labels = middle_labels(&d.scenario(), d.middle_frame);
                for t in &labels.targets {
                    assert!(t.in_frame, "{observer:?}, sequence {k}, target {}: not in view at the middle", t.id);
                    let [x, y] = t.center_px;
                    assert!(x > 0.0 && y > 0.0, "{observer:?}, sequence {k}: {x}, {y}");
                }
            }
        }
    }

    #[test]
    fn a_moving_camera_is_where_it_was_drawn_at_the_middle_frame_and_pans_with_its_turn() {
        let s = spec("range_m = [300, 3000]", "speed_m_s = [30, 30]\nturn_rate_deg_s = [10, 10]");
        for k in 0..6 {
            let d = s.draw(k, None, &[]).unwrap();
            let scenario = load_str(&d.scenario(), Format::Toml, Path::new("s.toml"), Path::new(".")).unwrap();
            let t_mid = d.middle_frame as f64 / 30.0;
            let (p, v) = scenario.observer_trajectory.state(t_mid);
            // drawn at the origin, at its altitude, flying at the drawn speed
            assert!(p.x.abs() < 1e-3 && p.y.abs() < 1e-3, "sequence {k}: {p}");
            assert!((v.length() - 30.0).abs() < 1e-3, "{v}");
            // a right turn at 10 °/s: the heading grows by 10° a second
            let (_, v1) = scenario.observer_trajectory.state(t_mid + 1.0);
            let turned = (v1.x.atan2(v1.y) - v.x.atan2(v.y)).to_degrees().rem_euclid(360.0);
            assert!((turned - 10.0).abs() < 1e-3, "sequence {k}: turned {turned}°");
        }
    }

    #[test]
    fn targets_are_placed_at_the_asked_snr() {
        let s = spec("snr = [3, 60]\nsnr_draw = \"log_uniform\"\nrange_m = [100, 30000]", "speed_m_s = [10, 40]");
        let mut solved_targets = 0;
        for k in 0..4 {
            let solved = solve(&s, k, &[], Path::new(".")).unwrap();
            assert!(solved.iterations <= MAX_ITERATIONS);
            // the scenario recorded gives each target its SNR at the middle frame (a new run of that frame: the
            // draft preset's radiometry tolerance of 0.1 % aside)
            let labels = middle_labels(&solved.drawn.scenario(), solved.drawn.middle_frame);
            for (t, l) in solved.targets.iter().zip(&labels.targets) {
                assert!((3.0..=60.0).contains(&t.asked), "{t:?}");
                assert!((100.0..=30000.0).contains(&t.range_m), "{t:?}");
                match t.limit {
                    None => {
                        solved_targets += 1;
                        assert!((t.reached / t.asked - 1.0).abs() <= SNR_TOLERANCE + 1e-9, "{t:?}");
                        assert!((l.snr / t.asked - 1.0).abs() < 0.02, "sequence {k}: {t:?}, frame says {}", l.snr);
                    }
                    // at an end of range_m, on the side the asked SNR lies beyond
                    Some(_) => assert!(
                        (t.range_m - 100.0).abs() < 1e-6 && t.reached < t.asked
                            || (t.range_m - 30000.0).abs() < 1e-3 && t.reached > t.asked,
                        "sequence {k}: {t:?}"
                    ),
                }
            }
        }
        assert!(solved_targets >= 4, "only {solved_targets} targets solved");
    }
}
