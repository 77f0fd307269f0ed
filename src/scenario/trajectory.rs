//! Trajectories of targets and observer, analytic in time: position and velocity at any `t` without stepping,
//! so frame k is computed without frames 0 … k−1 and nothing drifts.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

pub use crate::physics::trajectory::{MAX_COORDINATE_M, MAX_SPEED_M_S, Trajectory};

/// A trajectory as written in a scenario. Positions in metres (world: x east, y north, z up), times in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TrajectorySpec {
    /// Per-axis polynomials: `x(t) = Σ x_m[i]·tⁱ` (the paper's `X(t) = 0.34t + 0.5·0.01t²` km is
    /// `x_m = [0, 340, 5]`).
    Polynomial {
        /// Coefficients of x, m, m/s, m/s², …
        x_m: Vec<f64>,
        /// Coefficients of y.
        y_m: Vec<f64>,
        /// Coefficients of z.
        z_m: Vec<f64>,
    },
    /// Straight line at constant velocity: `p(t) = position_m + velocity_m_s·t`.
    ConstantVelocity {
        /// Position at t = 0, m.
        #[serde(with = "crate::physics::exact::dvec3")]
        position_m: DVec3,
        /// Velocity, m/s.
        #[serde(default, with = "crate::physics::exact::dvec3")]
        velocity_m_s: DVec3,
    },
    /// Timed waypoints joined by a C¹ cubic (Catmull–Rom tangents); constant velocity beyond the ends.
    Waypoints {
        /// `[t_s, x_m, y_m, z_m]` rows with strictly increasing times (at least two).
        #[serde(with = "crate::physics::exact::rows4")]
        points: Vec<[f64; 4]>,
    },
    /// A level (or steadily climbing) coordinated turn around a vertical axis.
    CoordinatedTurn {
        /// Centre of the circle at t = 0, m (its z is the altitude at t = 0).
        #[serde(with = "crate::physics::exact::dvec3")]
        center_m: DVec3,
        /// Radius, m.
        radius_m: f64,
        /// Ground speed along the circle, m/s.
        speed_m_s: f64,
        /// Bearing of the aircraft from the centre at t = 0, degrees clockwise from north.
        start_bearing_deg: f64,
        /// Turn direction: true for clockwise seen from above (a right turn).
        #[serde(default = "default_true")]
        clockwise: bool,
        /// Climb rate, m/s.
        #[serde(default)]
        climb_m_s: f64,
    },
    /// Samples `t, x, y, z` from a CSV file (path relative to the scenario), joined like waypoints.
    Csv {
        /// The file.
        path: String,
    },
}

fn default_true() -> bool {
    true
}

/// A trajectory error, naming the field.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryError {
    /// The field within the trajectory, e.g. `points[2]`.
    pub field: String,
    /// What is wrong.
    pub message: String,
    /// For a CSV trajectory: the file and the 1-based line at fault.
    pub csv: Option<(String, usize)>,
}

fn err(field: impl Into<String>, message: impl Into<String>) -> TrajectoryError {
    TrajectoryError { field: field.into(), message: message.into(), csv: None }
}

/// Which limit a trajectory passes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exceeds {
    /// [`MAX_COORDINATE_M`].
    Position,
    /// [`MAX_SPEED_M_S`].
    Speed,
}

impl TrajectorySpec {
    /// The field most responsible when the trajectory passes a limit over `t0 ..= t1` (`None`: the whole
    /// trajectory, or a CSV file's rows).
    pub fn culprit(&self, what: Exceeds, (t0, t1): (f64, f64)) -> Option<String> {
        let big = |v: &DVec3| !(v.is_finite() && v.abs().max_element() <= MAX_COORDINATE_M);
        let reach = t0.abs().max(t1.abs());
        match self {
            TrajectorySpec::ConstantVelocity { position_m, .. } => {
                Some(if what == Exceeds::Position && big(position_m) { "position_m" } else { "velocity_m_s" }.into())
            }
            TrajectorySpec::CoordinatedTurn { center_m, .. } => {
                Some(if what == Exceeds::Position && big(center_m) { "center_m" } else { "climb_m_s" }.into())
            }
            TrajectorySpec::Polynomial { x_m, y_m, z_m } => {
                let mut worst = (f64::NEG_INFINITY, String::new());
                for (name, c) in [("x_m", x_m), ("y_m", y_m), ("z_m", z_m)] {
                    for (i, ci) in c.iter().enumerate() {
                        let weight =
                            if what == Exceeds::Speed && i == 0 { 0.0 } else { ci.abs() * reach.powi(i as i32) };
                        let weight = if weight.is_nan() { f64::INFINITY } else { weight };
                        if weight > worst.0 {
                            worst = (weight, format!("{name}[{i}]"));
                        }
                    }
                }
                Some(worst.1)
            }
            TrajectorySpec::Waypoints { points } => {
                let size = |r: &[f64; 4]| r.iter().skip(1).fold(0.0f64, |m, v| m.max(v.abs()));
                let worst = (0..points.len()).max_by(|&a, &b| size(&points[a]).total_cmp(&size(&points[b])))?;
                Some(format!("points[{worst}]"))
            }
            TrajectorySpec::Csv { .. } => Some("path".into()),
        }
    }

    /// Validates and builds the trajectory; `base_dir` resolves a CSV path.
    ///
    /// # Errors
    /// [`TrajectoryError`] naming the field: non-finite numbers, empty polynomials, fewer than two waypoints,
    /// times not strictly increasing, a non-positive radius, an unreadable or malformed CSV file (with its line).
    pub fn build(&self, base_dir: &Path) -> Result<Trajectory, TrajectoryError> {
        match self {
            TrajectorySpec::Polynomial { x_m, y_m, z_m } => {
                for (name, c) in [("x_m", x_m), ("y_m", y_m), ("z_m", z_m)] {
                    if c.is_empty() {
                        return Err(err(name, "needs at least one coefficient"));
                    }
                    if let Some(i) = c.iter().position(|v| !v.is_finite()) {
                        return Err(err(format!("{name}[{i}]"), "must be a finite number"));
                    }
                }
                Ok(Trajectory::Polynomial([x_m.clone(), y_m.clone(), z_m.clone()]))
            }
            TrajectorySpec::ConstantVelocity { position_m, velocity_m_s } => {
                if !position_m.is_finite() {
                    return Err(err("position_m", "must be finite"));
                }
                if !velocity_m_s.is_finite() {
                    return Err(err("velocity_m_s", "must be finite"));
                }
                Ok(Trajectory::ConstantVelocity { p0: *position_m, v: *velocity_m_s })
            }
            TrajectorySpec::Waypoints { points } => spline(points.iter().copied(), "points"),
            TrajectorySpec::CoordinatedTurn {
                center_m,
                radius_m,
                speed_m_s,
                start_bearing_deg,
                clockwise,
                climb_m_s,
            } => {
                if !center_m.is_finite() {
                    return Err(err("center_m", "must be finite"));
                }
                if !(radius_m.is_finite() && (1e-3..=MAX_COORDINATE_M).contains(radius_m)) {
                    return Err(err(
                        "radius_m",
                        format!("{} must be in [0.001, {MAX_COORDINATE_M:e}] m", crate::physics::Num(*radius_m)),
                    ));
                }
                if !(speed_m_s.is_finite() && (0.0..=MAX_SPEED_M_S).contains(speed_m_s)) {
                    return Err(err(
                        "speed_m_s",
                        format!("{} must be in [0, {MAX_SPEED_M_S:e}] m/s", crate::physics::Num(*speed_m_s)),
                    ));
                }
                if !start_bearing_deg.is_finite() {
                    return Err(err("start_bearing_deg", "must be finite"));
                }
                if !climb_m_s.is_finite() {
                    return Err(err("climb_m_s", "must be finite"));
                }
                // bearing (clockwise from north) → math angle from +x
                let phase = (90.0 - start_bearing_deg).to_radians();
                let rate = speed_m_s / radius_m;
                Ok(Trajectory::Turn {
                    center: *center_m,
                    radius: *radius_m,
                    omega: if *clockwise { -rate } else { rate },
                    phase,
                    climb: *climb_m_s,
                })
            }
            TrajectorySpec::Csv { path } => {
                let full = base_dir.join(path);
                let file = full.display().to_string();
                let at = |line: usize, message: String| TrajectoryError {
                    field: "path".into(),
                    message,
                    csv: Some((file.clone(), line)),
                };
                let text = std::fs::read_to_string(&full)
                    .map_err(|e| err("path", format!("cannot read {}: {e}", full.display())))?;
                let mut rows = Vec::new();
                let mut lines = Vec::new();
                for (i, line) in text.lines().enumerate() {
                    let line = line.trim();
                    if line.is_empty() || line.starts_with('#') {
                        continue;
                    }
                    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
                    let parsed: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
                    match parsed {
                        Ok(v) if v.len() == 4 => {
                            rows.push([v[0], v[1], v[2], v[3]]);
                            lines.push(i + 1);
                        }
                        // a header line names the columns
                        Err(_) if rows.is_empty() && i == 0 => continue,
                        Ok(v) => return Err(at(i + 1, format!("expected 4 numbers t, x, y, z, found {}", v.len()))),
                        Err(_) => return Err(at(i + 1, "expected 4 numbers t, x, y, z".into())),
                    }
                }
                if rows.len() < 2 {
                    return Err(at(lines.last().copied().unwrap_or(1), "needs at least two rows t, x, y, z".into()));
                }
                spline(rows.into_iter(), "path").map_err(|e| {
                    let row: usize = e.field.trim_start_matches("path[").trim_end_matches(']').parse().unwrap_or(0);
                    at(lines.get(row).copied().unwrap_or(1), e.message)
                })
            }
        }
    }
}

fn spline(points: impl Iterator<Item = [f64; 4]>, field: &str) -> Result<Trajectory, TrajectoryError> {
    let rows: Vec<[f64; 4]> = points.collect();
    if rows.len() < 2 {
        return Err(err(field, "needs at least two points"));
    }
    for (i, r) in rows.iter().enumerate() {
        if r.iter().any(|v| !v.is_finite()) {
            return Err(err(format!("{field}[{i}]"), "must be finite numbers"));
        }
        if i > 0 && !(r[0] > rows[i - 1][0]) {
            return Err(err(
                format!("{field}[{i}]"),
                format!("time {} must be after {}", crate::physics::Num(r[0]), crate::physics::Num(rows[i - 1][0])),
            ));
        }
    }
    let t: Vec<f64> = rows.iter().map(|r| r[0]).collect();
    let p: Vec<DVec3> = rows.iter().map(|r| DVec3::new(r[1], r[2], r[3])).collect();
    let n = t.len();
    let m = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            (p[b] - p[a]) / (t[b] - t[a])
        })
        .collect();
    Ok(Trajectory::Spline { t, p, m })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_polynomial() {
        let spec = TrajectorySpec::Polynomial {
            x_m: vec![0.0, 340.0, 5.0],
            y_m: vec![4000.0, 340.0],
            z_m: vec![8000.0, 10.0],
        };
        let tr = spec.build(Path::new(".")).unwrap();
        let (p, v) = tr.state(2.0);
        assert!((p - DVec3::new(700.0, 4680.0, 8020.0)).length() < 1e-9);
        assert!((v - DVec3::new(360.0, 340.0, 10.0)).length() < 1e-9);
    }

    #[test]
    fn spline_passes_through_waypoints_with_matching_velocity() {
        let pts = vec![[0.0, 0.0, 0.0, 1000.0], [10.0, 1000.0, 0.0, 1000.0], [20.0, 1000.0, 1000.0, 1200.0]];
        let tr = TrajectorySpec::Waypoints { points: pts.clone() }.build(Path::new(".")).unwrap();
        for r in &pts {
            assert!((tr.state(r[0]).0 - DVec3::new(r[1], r[2], r[3])).length() < 1e-9);
        }
        // velocity is the derivative of position
        let (p1, v) = tr.state(7.3);
        let (p2, _) = tr.state(7.3 + 1e-6);
        assert!(((p2 - p1) / 1e-6 - v).length() < 1e-3);
    }

    #[test]
    fn turn_keeps_radius_and_speed() {
        let spec = TrajectorySpec::CoordinatedTurn {
            center_m: DVec3::new(0.0, 0.0, 3000.0),
            radius_m: 2000.0,
            speed_m_s: 100.0,
            start_bearing_deg: 0.0,
            clockwise: true,
            climb_m_s: 5.0,
        };
        let tr = spec.build(Path::new(".")).unwrap();
        let (p0, v0) = tr.state(0.0);
        assert!((p0 - DVec3::new(0.0, 2000.0, 3000.0)).length() < 1e-9);
        // clockwise from north: heading east
        assert!(v0.x > 99.0);
        let (p, v) = tr.state(37.0);
        assert!(((p.truncate()).length() - 2000.0).abs() < 1e-9);
        assert!((v.truncate().length() - 100.0).abs() < 1e-9);
        assert!((p.z - 3185.0).abs() < 1e-9);
    }

    #[test]
    fn rejects_bad_waypoints() {
        let e = TrajectorySpec::Waypoints { points: vec![[0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 1.0, 1.0]] }
            .build(Path::new("."))
            .unwrap_err();
        assert_eq!(e.field, "points[1]");
        assert!(TrajectorySpec::Waypoints { points: vec![[0.0; 4]] }.build(Path::new(".")).is_err());
    }
}
