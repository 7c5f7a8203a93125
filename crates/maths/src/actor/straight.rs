//! The straight and polyline motions (`kind = "straight"`, `kind = "waypoints"`, docs/actors.md):
//! from a start along a direction or through waypoints, with a piecewise-linear acceleration
//! profile integrated in closed form, optionally started by the vehicle coming close.

use serde::{Deserialize, Serialize};

use super::{
    motion_error, ActorMotion, ActorState, Motion, MotionContext, MotionError, MAX_BREAKPOINTS, MAX_WAYPOINTS,
};

/// The largest jitter amplitude a motion parameter may have (as an obstacle's extent, m).
const MAX_JITTER: f64 = 1e9;

/// The parameters of `kind = "straight"` (along `direction`) and `kind = "waypoints"` (through
/// `waypoints`) (`[obstacles.motion]`, docs/actors.md): from the obstacle's `centre` with a
/// piecewise-linear acceleration profile along the path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathParams {
    /// Direction of travel (any non-zero vector; only its direction is used): `straight`'s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub direction: Option<[f64; 2]>,
    /// A polyline path: the points the actor passes after its `centre`, in order (it goes on
    /// along the last segment after the last point; at most 64): `waypoints`'.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub waypoints: Vec<[f64; 2]>,
    /// Initial speed (m/s, ≥ `min_speed`).
    #[serde(default)]
    pub speed: f64,
    /// Breakpoints [time (s), acceleration (m/s²)] of the acceleration along the direction:
    /// linear between them, 0 before the first, the last value after the last (equal times make
    /// a step; e.g. braking at 6 m/s² from t = 1 s: `[[1.0, 0.0], [1.0, -6.0]]`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub acceleration: Vec<[f64; 2]>,
    /// The speed braking stops at (m/s): the actor never goes slower or backwards.
    #[serde(default)]
    pub min_speed: f64,
    /// The profile starts when the vehicle first comes within this distance (m) of the actor's
    /// centre, its times counted from then (until then the actor keeps its initial speed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trigger_distance: Option<f64>,
    /// Seeded uniform variations (± each amplitude) of the motion's parameters.
    #[serde(default, skip_serializing_if = "MotionJitter::is_none")]
    pub jitter: MotionJitter,
}

impl crate::params::Params for PathParams {}

/// ± amplitudes of a motion's seeded uniform variations (`[obstacles.motion.jitter]`), drawn
/// from the scenario's `seed`, one draw per obstacle and parameter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionJitter {
    /// Initial speed (m/s; the result is kept ≥ `min_speed`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speed: Option<f64>,
    /// Every breakpoint time of the acceleration profile, shifted together (s; kept ≥ 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time: Option<f64>,
    /// Every acceleration of the profile, scaled together by 1 ± this fraction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acceleration: Option<f64>,
    /// The trigger distance (m; kept > 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trigger_distance: Option<f64>,
    /// The start position, along the direction of travel (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub along: Option<f64>,
}

impl MotionJitter {
    /// No variation at all.
    pub fn is_none(&self) -> bool {
        *self == MotionJitter::default()
    }
}

/// `kind = "straight"`: along `direction` (no waypoints).
pub fn build_straight(p: &PathParams, ctx: &MotionContext<'_>) -> Result<ActorMotion, MotionError> {
    if p.direction.is_none() || !p.waypoints.is_empty() {
        return Err(motion_error(
            "direction",
            "expected either a `direction` or `waypoints`, not both: kind = \"straight\" goes along a direction",
        ));
    }
    build_path(p, ctx)
}

/// `kind = "waypoints"`: through `waypoints` (no direction; a box moves along a straight line only).
pub fn build_waypoints(p: &PathParams, ctx: &MotionContext<'_>) -> Result<ActorMotion, MotionError> {
    if p.direction.is_some() || p.waypoints.is_empty() {
        return Err(motion_error(
            "waypoints",
            "expected either a `direction` or `waypoints` (a path of at least one point after the centre), not both: kind = \"waypoints\" follows a path",
        ));
    }
    if ctx.boxed {
        return Err(motion_error(
            "waypoints",
            "a box moves along a straight `direction` only (its covering circles keep the heading it starts with)",
        ));
    }
    build_path(p, ctx)
}

/// The motion of `p` from the obstacle's centre with its seeded variations.
fn build_path(p: &PathParams, ctx: &MotionContext<'_>) -> Result<ActorMotion, MotionError> {
    p.check()?;
    let (motion, trigger) = p.realised(ctx.centre, ctx.seed, ctx.index);
    // The unvaried motion must be valid too (a variation must not hide a bad parameter).
    StraightActor::new(&p.straight(ctx.centre), p.trigger_distance)?;
    Ok(ActorMotion::new(StraightActor::new(&motion, trigger)?))
}

impl PathParams {
    /// What serde cannot check: the jitter amplitudes, a varied trigger distance's presence,
    /// the speed's size.
    fn check(&self) -> Result<(), MotionError> {
        let jitters = [
            ("jitter.speed", self.jitter.speed),
            ("jitter.time", self.jitter.time),
            ("jitter.acceleration", self.jitter.acceleration),
            ("jitter.trigger_distance", self.jitter.trigger_distance),
            ("jitter.along", self.jitter.along),
        ];
        for (key, value) in jitters {
            if let Some(v) = value {
                if !(v.is_finite() && (0.0..=MAX_JITTER).contains(&v)) {
                    return Err(motion_error(key, format!("expected an amplitude >= 0, found {v}")));
                }
            }
        }
        if self.jitter.trigger_distance.is_some() && self.trigger_distance.is_none() {
            return Err(motion_error(
                "jitter.trigger_distance",
                "expected a `trigger_distance` to vary",
            ));
        }
        if let Some(v) = self.speed.is_finite().then_some(self.speed).filter(|v| v.abs() > 1e6) {
            return Err(motion_error(
                "speed",
                format!("expected a speed within 1e6 m/s, found {v}"),
            ));
        }
        Ok(())
    }

    /// The motion of obstacle `index` from `start` with its seeded variations drawn from
    /// `seed`, and its trigger distance.
    pub fn realised(&self, start: [f64; 2], seed: u64, index: usize) -> (StraightMotion, Option<f64>) {
        use crate::random::{symmetric_unit, Stream};
        let draw = |amplitude: Option<f64>, component: u64| {
            amplitude.map_or(0.0, |a| {
                a * symmetric_unit(seed, Stream::ActorMotion, index as u64, component)
            })
        };
        let mut motion = self.straight(start);
        motion.speed = (motion.speed + draw(self.jitter.speed, 0)).max(motion.min_speed);
        let shift = draw(self.jitter.time, 1);
        let scale = 1.0 + draw(self.jitter.acceleration, 2);
        for [t, a] in &mut motion.acceleration {
            *t = (*t + shift).max(0.0);
            *a *= scale;
        }
        let along = draw(self.jitter.along, 3);
        if along != 0.0 {
            // Along the first segment's direction (the path's points move with the start).
            let d = self
                .waypoints
                .first()
                .map_or(motion.direction, |w| [w[0] - start[0], w[1] - start[1]]);
            let norm = d[0].hypot(d[1]);
            if norm > 0.0 {
                let shift = [along * d[0] / norm, along * d[1] / norm];
                motion.start = [start[0] + shift[0], start[1] + shift[1]];
                for w in &mut motion.waypoints {
                    *w = [w[0] + shift[0], w[1] + shift[1]];
                }
            }
        }
        let trigger = self
            .trigger_distance
            .map(|d| (d + draw(self.jitter.trigger_distance, 4)).max(1e-3));
        (motion, trigger)
    }

    /// The motion from `start` (without the jitter).
    pub fn straight(&self, start: [f64; 2]) -> StraightMotion {
        StraightMotion {
            start,
            direction: self.direction.unwrap_or([0.0; 2]),
            waypoints: self.waypoints.clone(),
            speed: self.speed,
            acceleration: self.acceleration.clone(),
            min_speed: self.min_speed,
        }
    }
}

/// Motion from `start` along `direction` (or through `waypoints`) at `speed`, accelerating along
/// the path by the profile a(t) through the breakpoints (t, a) (linear between them, 0 before
/// the first, the last value after the last; equal times make a step), the speed held at
/// `min_speed` where braking would take it below (no reversing).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StraightMotion {
    pub start: [f64; 2],
    /// Any non-zero vector; only its direction is used (ignored with `waypoints`).
    pub direction: [f64; 2],
    /// A polyline path instead: the points the actor passes after `start`, in order (it goes on
    /// along the last segment's direction after the last); at most [`MAX_WAYPOINTS`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub waypoints: Vec<[f64; 2]>,
    /// Initial speed ≥ 0 (m/s).
    #[serde(default)]
    pub speed: f64,
    /// Breakpoints (t, a) of the acceleration profile, t non-decreasing (s, m/s²); the last
    /// value holds after the last breakpoint.
    #[serde(default)]
    pub acceleration: Vec<[f64; 2]>,
    /// The speed braking stops at (m/s, default 0).
    #[serde(default)]
    pub min_speed: f64,
}

/// One piece of the speed profile: from time `t` at arc length `s` and speed `v`, with
/// acceleration a + j (τ − t) (or held at the minimum speed: a = j = 0).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Piece {
    t: f64,
    s: f64,
    v: f64,
    a: f64,
    j: f64,
}

impl Piece {
    fn at(&self, t: f64) -> (f64, f64, f64) {
        let d = t - self.t;
        let a = self.a + self.j * d;
        let v = self.v + self.a * d + 0.5 * self.j * d * d;
        let s = self.s + self.v * d + 0.5 * self.a * d * d + self.j * d * d * d / 6.0;
        (s, v, a)
    }
}

/// A [`StraightMotion`] checked and integrated in closed form: its state at any time exactly.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    start: [f64; 2],
    unit: [f64; 2],
    /// The path's segments after the first (from `start` along `unit`): (arc length where it
    /// starts, its start point, its unit direction); the last extends to +∞.
    bends: Vec<(f64, [f64; 2], [f64; 2])>,
    min_speed: f64,
    /// In time order; the last extends to +∞.
    pieces: Vec<Piece>,
}

impl Trajectory {
    /// Checks `motion` (finite values, a non-zero direction, speeds ≥ 0 with the initial one
    /// at least `min_speed`, at most [`MAX_BREAKPOINTS`] breakpoints in time order from t ≥ 0)
    /// and integrates its speed profile.
    pub fn new(motion: &StraightMotion) -> Result<Trajectory, MotionError> {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !finite(&motion.start) {
            return Err(motion_error("start", "expected two finite coordinates (m)"));
        }
        if motion.waypoints.len() > MAX_WAYPOINTS {
            return Err(motion_error(
                "waypoints",
                format!(
                    "expected at most {MAX_WAYPOINTS} points, found {}",
                    motion.waypoints.len()
                ),
            ));
        }
        // The path's segments: each from the previous point, non-zero and finite.
        let mut segments = Vec::with_capacity(motion.waypoints.len());
        let mut from = motion.start;
        for (k, w) in motion.waypoints.iter().enumerate() {
            let d = [w[0] - from[0], w[1] - from[1]];
            let length = d[0].hypot(d[1]);
            if !(finite(w) && length.is_finite() && length > 1e-9) {
                return Err(motion_error(
                    "waypoints",
                    format!("expected finite points, each apart from the one before it (point {k} is not)"),
                ));
            }
            segments.push((from, [d[0] / length, d[1] / length], length));
            from = *w;
        }
        let (direction, norm) = match segments.first() {
            Some((_, unit, _)) => (*unit, 1.0),
            None => (motion.direction, motion.direction[0].hypot(motion.direction[1])),
        };
        if !(norm.is_finite() && norm > 0.0) {
            return Err(motion_error("direction", "expected a finite, non-zero vector"));
        }
        let mut bends = Vec::with_capacity(segments.len().saturating_sub(1));
        let mut arc = 0.0;
        for pair in segments.windows(2) {
            arc += pair[0].2;
            bends.push((arc, pair[1].0, pair[1].1));
        }
        if !(motion.min_speed.is_finite() && motion.min_speed >= 0.0) {
            return Err(motion_error(
                "min_speed",
                format!("expected a speed >= 0 (m/s), found {}", motion.min_speed),
            ));
        }
        if !(motion.speed.is_finite() && motion.speed >= motion.min_speed) {
            return Err(motion_error(
                "speed",
                format!(
                    "expected a speed >= min_speed = {} (m/s), found {}",
                    motion.min_speed, motion.speed
                ),
            ));
        }
        if motion.acceleration.len() > MAX_BREAKPOINTS {
            return Err(motion_error(
                "acceleration",
                format!(
                    "expected at most {MAX_BREAKPOINTS} breakpoints, found {}",
                    motion.acceleration.len()
                ),
            ));
        }
        let mut previous = 0.0;
        for [t, a] in &motion.acceleration {
            if !(t.is_finite() && a.is_finite() && *t >= previous) {
                return Err(motion_error(
                    "acceleration",
                    "expected [time, acceleration] pairs, finite, with times >= 0 in non-decreasing order",
                ));
            }
            previous = *t;
        }
        let unit = [direction[0] / norm, direction[1] / norm];
        let mut trajectory = Trajectory {
            start: motion.start,
            unit,
            bends,
            min_speed: motion.min_speed,
            pieces: Vec::with_capacity(3 * motion.acceleration.len() + 2),
        };
        // The profile's linear segments: 0 before the first breakpoint, the last value after
        // the last.
        let mut segments: Vec<(f64, f64, f64)> = Vec::with_capacity(motion.acceleration.len() + 1);
        segments.push((0.0, 0.0, 0.0));
        for pair in motion.acceleration.windows(2) {
            let ([t0, a0], [t1, a1]) = (pair[0], pair[1]);
            if t1 > t0 {
                segments.push((t0, a0, (a1 - a0) / (t1 - t0)));
            }
        }
        if let Some([t, a]) = motion.acceleration.last() {
            segments.push((*t, *a, 0.0));
        }
        // Segment ends: the next segment's start.
        let ends: Vec<f64> = segments
            .iter()
            .skip(1)
            .map(|s| s.0)
            .chain(std::iter::once(f64::INFINITY))
            .collect();
        let (mut s, mut v) = (0.0, motion.speed);
        for (&(t0, a0, j), &t1) in segments.iter().zip(&ends) {
            trajectory.integrate_segment(t0, t1, a0, j, &mut s, &mut v);
        }
        Ok(trajectory)
    }

    /// Appends the pieces of one profile segment [t0, t1) with a(t) = a0 + j (t − t0), from
    /// arc length `s` and speed `v` (updated to the segment's end), holding the speed at the
    /// minimum while the profile would take it lower.
    fn integrate_segment(&mut self, t0: f64, t1: f64, a0: f64, j: f64, s: &mut f64, v: &mut f64) {
        let mut t = t0;
        while t < t1 {
            let a_now = a0 + j * (t - t0);
            let held = *v <= self.min_speed && (a_now < 0.0 || (a_now == 0.0 && j < 0.0));
            if held {
                // Held until a(t) turns positive (never within the segment unless j > 0).
                let release = if j > 0.0 { t0 - a0 / j } else { f64::INFINITY };
                let end = release.min(t1);
                self.pieces.push(Piece {
                    t,
                    s: *s,
                    v: self.min_speed,
                    a: 0.0,
                    j: 0.0,
                });
                if end.is_infinite() {
                    return;
                }
                (*s, *v) = (*s + self.min_speed * (end - t), self.min_speed);
                t = end;
            } else {
                let piece = Piece {
                    t,
                    s: *s,
                    v: *v,
                    a: a_now,
                    j,
                };
                let stop = first_time_at_speed(&piece, self.min_speed);
                let end = stop.min(t1);
                self.pieces.push(piece);
                if end.is_infinite() {
                    return;
                }
                let (s_end, v_end, _) = piece.at(end);
                (*s, *v) = (
                    s_end,
                    if end == stop {
                        self.min_speed
                    } else {
                        v_end.max(self.min_speed)
                    },
                );
                t = end;
            }
        }
    }

    /// The actor's true state at time t ≥ 0 (before 0: at the start, moving as at 0).
    pub fn state_at(&self, t: f64) -> ActorState {
        let (s, v, a) = self.profile_at(t);
        self.at_arc(s, v, a)
    }

    /// Arc length, speed and acceleration along the path at time t.
    fn profile_at(&self, t: f64) -> (f64, f64, f64) {
        let index = self.pieces.partition_point(|p| p.t <= t).saturating_sub(1);
        self.pieces[index].at(t)
    }

    /// The state at arc length s with speed v and acceleration a along the path (along a
    /// polyline, the segment's tangent: the turn at a waypoint is instantaneous).
    fn at_arc(&self, s: f64, v: f64, a: f64) -> ActorState {
        let bend = self.bends.partition_point(|b| b.0 <= s);
        let (s0, from, [ux, uy]) = match bend {
            0 => (0.0, self.start, self.unit),
            k => self.bends[k - 1],
        };
        let s = s - s0;
        ActorState {
            position: [from[0] + s * ux, from[1] + s * uy],
            velocity: [v * ux, v * uy],
            acceleration: [a * ux, a * uy],
            heading: uy.atan2(ux),
            ..ActorState::default()
        }
    }
}

/// An actor's true motion over a run: its [`Trajectory`], started at t = 0 or, with a trigger
/// distance, when the vehicle first comes that close to the actor's centre (the profile's
/// times then count from that moment; until it, the actor keeps its initial speed).
#[derive(Debug, Clone, PartialEq)]
pub struct StraightActor {
    trajectory: Trajectory,
    trigger_distance: Option<f64>,
    /// When the trigger fired (None: not yet, or no trigger).
    triggered_at: Option<f64>,
    /// Initial speed along the unit direction, for the state before the trigger.
    speed: f64,
    /// Along a line (no waypoints): the direction's angle, which a box faces.
    heading: Option<f64>,
}

impl StraightActor {
    /// The motion of `motion`, started at once (`trigger_distance` None) or by the vehicle
    /// coming within `trigger_distance` metres (> 0, finite) of the actor's centre.
    pub fn new(motion: &StraightMotion, trigger_distance: Option<f64>) -> Result<StraightActor, MotionError> {
        if let Some(d) = trigger_distance {
            if !(d.is_finite() && d > 0.0) {
                return Err(motion_error(
                    "trigger_distance",
                    format!("expected a distance > 0 (m), found {d}"),
                ));
            }
        }
        Ok(StraightActor {
            trajectory: Trajectory::new(motion)?,
            trigger_distance,
            triggered_at: None,
            speed: motion.speed,
            heading: (motion.waypoints.is_empty()).then(|| motion.direction[1].atan2(motion.direction[0])),
        })
    }

    /// The actor's true state at time t, as far as the run has decided it (an actor waiting
    /// for its trigger moves on at its initial speed).
    pub fn state_at(&self, t: f64) -> ActorState {
        match (self.trigger_distance, self.triggered_at) {
            (None, _) => self.trajectory.state_at(t),
            (Some(_), None) => self.cruising(t),
            (Some(_), Some(at)) if t < at => self.cruising(t),
            (Some(_), Some(at)) => {
                let (s, v, a) = self.trajectory.profile_at(t - at);
                self.trajectory.at_arc(self.speed * at + s, v, a)
            }
        }
    }

    /// Before the trigger: the initial speed held from the start.
    fn cruising(&self, t: f64) -> ActorState {
        self.trajectory.at_arc(self.speed * t, self.speed, 0.0)
    }

    /// Fires the trigger at time t if the vehicle at `vehicle` is within its distance of the
    /// actor's centre and it has not fired yet; returns whether it fired now.
    pub fn check_trigger(&mut self, t: f64, vehicle: [f64; 2]) -> bool {
        let Some(distance) = self.trigger_distance else {
            return false;
        };
        if self.triggered_at.is_some() {
            return false;
        }
        let o = self.cruising(t).position;
        if (vehicle[0] - o[0]).hypot(vehicle[1] - o[1]) <= distance {
            self.triggered_at = Some(t);
            return true;
        }
        false
    }

    /// When the trigger fired, if it has.
    pub fn triggered_at(&self) -> Option<f64> {
        self.triggered_at
    }

    /// Marks the trigger fired at `t` (a copy of the motion following the run's own).
    pub fn set_triggered_at(&mut self, t: f64) {
        if self.trigger_distance.is_some() {
            self.triggered_at = Some(t);
        }
    }
}

/// The first time ≥ piece.t at which the piece's speed falls to `v_min` while decreasing; +∞ if
/// never.
fn first_time_at_speed(p: &Piece, v_min: f64) -> f64 {
    // v(d) = v + a d + ½ j d² = v_min, smallest d > 0 with v'(d) < 0.
    let (c, b, a2) = (p.v - v_min, p.a, 0.5 * p.j);
    let mut roots = [f64::INFINITY; 2];
    if a2.abs() < 1e-15 {
        if b < 0.0 {
            roots[0] = -c / b;
        }
    } else {
        let disc = b * b - 4.0 * a2 * c;
        if disc >= 0.0 {
            let q = disc.sqrt();
            roots = [(-b - q) / (2.0 * a2), (-b + q) / (2.0 * a2)];
        }
    }
    roots
        .iter()
        .filter(|d| d.is_finite() && **d > 1e-12 && p.a + p.j * **d <= 0.0)
        .fold(f64::INFINITY, |m, d| m.min(*d))
        + p.t
}

impl Motion for StraightActor {
    fn state_at(&self, t: f64) -> ActorState {
        StraightActor::state_at(self, t)
    }

    fn layout_heading(&self) -> Option<f64> {
        self.heading
    }

    fn check_trigger(&mut self, t: f64, vehicle: [f64; 2]) -> bool {
        StraightActor::check_trigger(self, t, vehicle)
    }

    fn triggered_at(&self) -> Option<f64> {
        StraightActor::triggered_at(self)
    }

    fn set_triggered_at(&mut self, t: f64) {
        StraightActor::set_triggered_at(self, t)
    }

    fn clone_motion(&self) -> Box<dyn Motion> {
        Box::new(self.clone())
    }
}
