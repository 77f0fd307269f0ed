//! Trajectories as the simulation evaluates them: analytic position and velocity at any time (polynomial,
//! constant velocity, cubic Hermite spline through timed points, coordinated turn), and conservative bounds over
//! an interval. Built and validated from the scenario schema by `scenario::trajectory`.

use glam::DVec3;

/// A validated trajectory, ready to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub enum Trajectory {
    /// Per-axis polynomials.
    Polynomial([Vec<f64>; 3]),
    /// Constant velocity.
    ConstantVelocity {
        /// Position at t = 0.
        p0: DVec3,
        /// Velocity.
        v: DVec3,
    },
    /// Piecewise cubic Hermite through timed points.
    Spline {
        /// Times, strictly increasing.
        t: Vec<f64>,
        /// Positions.
        p: Vec<DVec3>,
        /// Tangents (velocities).
        m: Vec<DVec3>,
    },
    /// Coordinated turn.
    Turn {
        /// Centre at t = 0.
        center: DVec3,
        /// Radius.
        radius: f64,
        /// Signed angular rate, rad/s (positive counter-clockwise in the x-y plane).
        omega: f64,
        /// Angle at t = 0 from +x, rad.
        phase: f64,
        /// Climb rate.
        climb: f64,
    },
}

/// Largest coordinate a trajectory may reach during a run, m (|x|, |y| and |z|): six times the Moon's
/// distance, far beyond anything a sensor resolves, and small enough that every derived quantity stays finite.
pub const MAX_COORDINATE_M: f64 = 1e9;
/// Largest speed a trajectory may reach during a run, m/s (about Mach 300).
pub const MAX_SPEED_M_S: f64 = 1e5;

impl Trajectory {
    /// Upper bounds of |position| (per axis, m) and |velocity| (m/s) over `t0_s ..= t1_s`: conservative
    /// (from the coefficients, the knots and the tangents), infinite if they overflow.
    pub fn bounds(&self, t0_s: f64, t1_s: f64) -> (f64, f64) {
        let reach = t0_s.abs().max(t1_s.abs());
        match self {
            Trajectory::Polynomial(axes) => {
                let (mut p, mut v) = (0.0f64, 0.0f64);
                for c in axes {
                    let (mut pa, mut va, mut power) = (0.0, 0.0, 1.0);
                    for (i, ci) in c.iter().enumerate() {
                        pa += ci.abs() * power;
                        if i + 1 < c.len() {
                            va += (i + 1) as f64 * c[i + 1].abs() * power;
                        }
                        power *= reach;
                    }
                    p = p.max(pa);
                    v += va * va;
                }
                (p, v.sqrt())
            }
            Trajectory::ConstantVelocity { p0, v } => {
                ((*p0).abs().max_element() + v.abs().max_element() * reach, v.length())
            }
            Trajectory::Spline { t, p, m } => {
                let (first, last) = (t[0], t[t.len() - 1]);
                let p_max = p.iter().map(|q| q.abs().max_element()).fold(0.0, f64::max);
                let m_max = m.iter().map(|q| q.abs().max_element()).fold(0.0, f64::max);
                let h_max = t.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
                let h_min = t.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
                let step_max = p.windows(2).map(|w| (w[1] - w[0]).abs().max_element()).fold(0.0, f64::max);
                // Hermite basis: |h00|, |h01| ≤ 1 and |h10|, |h11| ≤ 4/27; beyond the ends a straight line
                let beyond = (first - t0_s.min(t1_s)).max(t0_s.max(t1_s) - last).max(0.0);
                let pos = p_max + m_max * (8.0 / 27.0 * h_max).max(beyond);
                let vel = (1.5 * step_max / h_min + 2.0 * m_max) * 3f64.sqrt();
                (pos, vel)
            }
            Trajectory::Turn { center, radius, omega, climb, .. } => {
                let pos = center.abs().max_element() + radius + climb.abs() * reach;
                (pos, (radius * omega).hypot(*climb))
            }
        }
    }

    /// Position (m) and velocity (m/s) at time `t_s`.
    pub fn state(&self, t_s: f64) -> (DVec3, DVec3) {
        match self {
            Trajectory::Polynomial(axes) => {
                let eval = |c: &[f64]| {
                    let (mut p, mut v) = (0.0, 0.0);
                    for (i, &ci) in c.iter().enumerate().rev() {
                        p = p * t_s + ci;
                        if i > 0 {
                            v = v * t_s + ci * i as f64;
                        }
                    }
                    (p, v)
                };
                let (x, vx) = eval(&axes[0]);
                let (y, vy) = eval(&axes[1]);
                let (z, vz) = eval(&axes[2]);
                (DVec3::new(x, y, z), DVec3::new(vx, vy, vz))
            }
            Trajectory::ConstantVelocity { p0, v } => (*p0 + *v * t_s, *v),
            Trajectory::Spline { t, p, m } => {
                let n = t.len();
                if t_s <= t[0] {
                    return (p[0] + m[0] * (t_s - t[0]), m[0]);
                }
                if t_s >= t[n - 1] {
                    return (p[n - 1] + m[n - 1] * (t_s - t[n - 1]), m[n - 1]);
                }
                let i = t.partition_point(|&ti| ti <= t_s) - 1;
                let h = t[i + 1] - t[i];
                let s = (t_s - t[i]) / h;
                let (s2, s3) = (s * s, s * s * s);
                let pos = p[i] * (2.0 * s3 - 3.0 * s2 + 1.0)
                    + m[i] * h * (s3 - 2.0 * s2 + s)
                    + p[i + 1] * (-2.0 * s3 + 3.0 * s2)
                    + m[i + 1] * h * (s3 - s2);
                let vel = (p[i] * (6.0 * s2 - 6.0 * s)
                    + m[i] * h * (3.0 * s2 - 4.0 * s + 1.0)
                    + p[i + 1] * (-6.0 * s2 + 6.0 * s)
                    + m[i + 1] * h * (3.0 * s2 - 2.0 * s))
                    / h;
                (pos, vel)
            }
            Trajectory::Turn { center, radius, omega, phase, climb } => {
                let a = phase + omega * t_s;
                let (s, c) = a.sin_cos();
                let pos = *center + DVec3::new(radius * c, radius * s, climb * t_s);
                let vel = DVec3::new(-radius * omega * s, radius * omega * c, *climb);
                (pos, vel)
            }
        }
    }
}
