//! A road user that follows recorded, time-stamped states (a CommonRoad trajectory: docs/commonroad.md):
//! its position and heading interpolated between the recording's steps by natural cubic splines
//! through the recorded values, so that its velocity, acceleration, yaw rate and yaw acceleration
//! are the exact derivatives of the positions and headings it is at (the time-varying barrier
//! terms ∂h/∂t and ö of (4.85) read them). It exists from its first recorded time to its last.

use std::sync::Arc;

use super::{motion_error, ActorState, Motion, MotionError};

/// Most states of one recording.
pub const MAX_RECORDED_STATES: usize = 100_000;

/// One recorded state: time (s), position (m), orientation (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedState {
    pub time: f64,
    pub position: [f64; 2],
    pub orientation: f64,
}

/// A natural cubic spline through (t_k, y_k) ([`crate::planar::natural_spline`]).
#[derive(Debug, Clone, PartialEq)]
struct Spline {
    /// Per piece (y, b, c, d).
    pieces: Vec<[f64; 4]>,
}

impl Spline {
    fn new(times: &[f64], values: &[f64]) -> Spline {
        Spline {
            pieces: crate::planar::natural_spline(times, values),
        }
    }

    /// Value, first and second derivative on piece `k` at u = t − t_k.
    fn at(&self, k: usize, u: f64) -> [f64; 3] {
        crate::planar::cubic_at(&self.pieces[k], u)
    }
}

/// A recording checked and interpolated: the state at any time of its span.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMotion {
    times: Vec<f64>,
    x: Spline,
    y: Spline,
    /// The unwrapped heading (consecutive orientations differ by at most π).
    heading: Spline,
    /// The heading the covering circles' offsets are laid out at: the first recorded one.
    reference_heading: f64,
}

impl RecordedMotion {
    /// Checks `states` (2 to [`MAX_RECORDED_STATES`], finite, times strictly increasing) and
    /// fits the splines.
    pub fn new(states: &[RecordedState]) -> Result<RecordedMotion, MotionError> {
        if states.len() < 2 || states.len() > MAX_RECORDED_STATES {
            return Err(motion_error(
                "states",
                format!(
                    "expected 2 to {MAX_RECORDED_STATES} recorded states, found {}",
                    states.len()
                ),
            ));
        }
        for (k, s) in states.iter().enumerate() {
            let finite = s.time.is_finite() && s.orientation.is_finite() && s.position.iter().all(|v| v.is_finite());
            if !finite || (k > 0 && s.time <= states[k - 1].time) {
                return Err(motion_error(
                    "states",
                    format!("expected finite states with increasing times (state {k} is not)"),
                ));
            }
        }
        let times: Vec<f64> = states.iter().map(|s| s.time).collect();
        let coordinate = |i: usize| states.iter().map(|s| s.position[i]).collect::<Vec<_>>();
        let mut headings: Vec<f64> = Vec::with_capacity(states.len());
        for s in states {
            let heading = match headings.last() {
                None => s.orientation,
                // The turn from the last orientation taken in [−π, π].
                Some(&last) => {
                    let d = s.orientation - last;
                    last + (d - std::f64::consts::TAU * (d / std::f64::consts::TAU).round())
                }
            };
            headings.push(heading);
        }
        Ok(RecordedMotion {
            x: Spline::new(&times, &coordinate(0)),
            y: Spline::new(&times, &coordinate(1)),
            heading: Spline::new(&times, &headings),
            reference_heading: states[0].orientation,
            times,
        })
    }

    /// The first and last recorded times (s): the road user exists in between.
    pub fn span(&self) -> (f64, f64) {
        (self.times[0], self.times[self.times.len() - 1])
    }

    /// Whether the road user exists at t (within 1e-9 s of its span).
    pub fn exists_at(&self, t: f64) -> bool {
        let (first, last) = self.span();
        t >= first - 1e-9 && t <= last + 1e-9
    }

    /// The heading its covering circles' offsets are laid out at (the first recorded one).
    pub fn reference_heading(&self) -> f64 {
        self.reference_heading
    }

    /// The state at t (clamped to the span: outside it, where it was first or last seen, at rest).
    pub fn state_at(&self, t: f64) -> ActorState {
        let (first, last) = self.span();
        let inside = (first..=last).contains(&t);
        let t = t.clamp(first, last);
        let k = self
            .times
            .partition_point(|&tk| tk <= t)
            .saturating_sub(1)
            .min(self.times.len() - 2);
        let u = t - self.times[k];
        let ([x, vx, ax], [y, vy, ay], [heading, rate, yaw_acceleration]) =
            (self.x.at(k, u), self.y.at(k, u), self.heading.at(k, u));
        let moving = if inside { 1.0 } else { 0.0 };
        ActorState {
            position: [x, y],
            velocity: [moving * vx, moving * vy],
            acceleration: [moving * ax, moving * ay],
            heading,
            turn: heading - self.reference_heading,
            yaw_rate: moving * rate,
            yaw_acceleration: moving * yaw_acceleration,
        }
    }

    /// The largest speed (m/s) the interpolated motion reaches: on each piece the speed's square
    /// is a quartic in u; bounded by the speeds at the piece's ends plus the largest |ẍ|, |ÿ|
    /// times its length (a bound, not an estimate: ‖v(u)‖ ≤ ‖v(0)‖ + u max‖a‖).
    pub fn speed_bound(&self) -> f64 {
        let mut bound: f64 = 0.0;
        for k in 0..self.times.len() - 1 {
            let h = self.times[k + 1] - self.times[k];
            let [_, vx, ax0] = self.x.at(k, 0.0);
            let [_, vy, ay0] = self.y.at(k, 0.0);
            let [_, _, ax1] = self.x.at(k, h);
            let [_, _, ay1] = self.y.at(k, h);
            // The acceleration is linear on a piece: its largest norm is at an end.
            let a = ax0.hypot(ay0).max(ax1.hypot(ay1));
            bound = bound.max(vx.hypot(vy) + h * a);
        }
        bound
    }
}

/// A recording shared between the run's copies of the motion (the truth and the controller's).
impl Motion for Arc<RecordedMotion> {
    fn state_at(&self, t: f64) -> ActorState {
        RecordedMotion::state_at(self, t)
    }

    fn exists_at(&self, t: f64) -> bool {
        RecordedMotion::exists_at(self, t)
    }

    fn clone_motion(&self) -> Box<dyn Motion> {
        Box::new(Arc::clone(self))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn states(f: impl Fn(f64) -> ([f64; 2], f64), n: usize, dt: f64) -> Vec<RecordedState> {
        (0..n)
            .map(|k| {
                let t = k as f64 * dt;
                let (position, orientation) = f(t);
                RecordedState {
                    time: t,
                    position,
                    orientation,
                }
            })
            .collect()
    }

    /// The recorded states are reproduced at their times, and a motion the spline can represent
    /// (quadratic in t with zero second derivative at the ends is not one; a straight line at
    /// constant speed is) is exact in between.
    #[test]
    fn knots_are_exact_and_a_line_is_exact_between() {
        let line = states(|t| ([3.0 + 2.0 * t, -1.0 - 0.5 * t], 0.3), 11, 0.1);
        let m = RecordedMotion::new(&line).unwrap();
        for s in &line {
            let at = m.state_at(s.time);
            assert_eq!(at.position, s.position);
            assert_eq!(at.heading, 0.3);
        }
        let at = m.state_at(0.437);
        assert!((at.position[0] - (3.0 + 2.0 * 0.437)).abs() < 1e-12);
        assert!((at.velocity[0] - 2.0).abs() < 1e-12 && (at.velocity[1] + 0.5).abs() < 1e-12);
        assert!(at.acceleration[0].abs() < 1e-9 && at.yaw_rate.abs() < 1e-12);
    }

    /// Independent: velocity and acceleration are the derivatives of the interpolated position
    /// (central differences of state_at), the spline is C² at the knots, and a smooth motion
    /// (a circle) is matched to O(h⁴) inside.
    #[test]
    fn derivatives_are_those_of_the_positions() {
        let circle = |t: f64| {
            (
                [10.0 * (0.5 * t).cos(), 10.0 * (0.5 * t).sin()],
                0.5 * t + std::f64::consts::FRAC_PI_2,
            )
        };
        let m = RecordedMotion::new(&states(circle, 81, 0.1)).unwrap();
        let e = 1e-5;
        for t in [0.35, 1.0, 2.05, 4.0, 6.3] {
            let (a, b, c) = (m.state_at(t - e), m.state_at(t), m.state_at(t + e));
            for i in 0..2 {
                let v = (c.position[i] - a.position[i]) / (2.0 * e);
                let acc = (c.velocity[i] - a.velocity[i]) / (2.0 * e);
                assert!((v - b.velocity[i]).abs() < 1e-6, "t {t}: v {v} vs {}", b.velocity[i]);
                assert!(
                    (acc - b.acceleration[i]).abs() < 1e-5,
                    "t {t}: a {acc} vs {}",
                    b.acceleration[i]
                );
            }
            let rate = (c.heading - a.heading) / (2.0 * e);
            assert!((rate - b.yaw_rate).abs() < 1e-6);
            // Inside, far from the free ends: the true circle to 1e-4 m, 1e-3 m/s.
            if (1.0..=6.0).contains(&t) {
                let (p, _) = circle(t);
                assert!((b.position[0] - p[0]).abs() < 1e-4 && (b.position[1] - p[1]).abs() < 1e-4);
                assert!((b.velocity[0] + 5.0 * (0.5 * t).sin()).abs() < 1e-3);
            }
        }
        // Continuity of the acceleration at a knot (C²).
        let (l, r) = (m.state_at(2.0 - 1e-9), m.state_at(2.0 + 1e-9));
        assert!((l.acceleration[0] - r.acceleration[0]).abs() < 1e-6);
    }

    /// Orientations that wrap at ±π give a continuous heading; the turn is relative to the first.
    #[test]
    fn headings_are_unwrapped() {
        let tau = std::f64::consts::TAU;
        let wrapped = |t: f64| {
            (
                [t, 0.0],
                if 3.0 + t > std::f64::consts::PI {
                    3.0 + t - tau
                } else {
                    3.0 + t
                },
            )
        };
        let m = RecordedMotion::new(&states(wrapped, 11, 0.1)).unwrap();
        let at = m.state_at(0.55);
        assert!((at.heading - 3.55).abs() < 1e-9, "{}", at.heading);
        assert!((at.turn - 0.55).abs() < 1e-9);
        assert!((at.yaw_rate - 1.0).abs() < 1e-9);
    }

    #[test]
    fn existence_and_bounds() {
        let m = RecordedMotion::new(&states(|t| ([t, 0.0], 0.0), 5, 0.2)).unwrap();
        assert!(m.exists_at(0.0) && m.exists_at(0.8) && !m.exists_at(0.81));
        assert_eq!(m.state_at(2.0).velocity, [0.0, 0.0]);
        assert!((m.speed_bound() - 1.0).abs() < 1e-9);
        let bad = [
            states(|t| ([t, 0.0], 0.0), 1, 0.1),
            states(|t| ([t, f64::NAN], 0.0), 3, 0.1),
            states(|t| ([t, 0.0], 0.0), 3, 0.0),
        ];
        for s in bad {
            assert_eq!(RecordedMotion::new(&s).unwrap_err().key, "states");
        }
    }
}
