//! Road users that move (pure maths; docs/actors.md): an actor's planar motion along a
//! straight line with a piecewise-linear acceleration profile, what a controller assumes of it
//! over a channel's delay, and the terms its motion adds to the constraint of a barrier around it,
//! h(x, t) = ‖p − o(t)‖² − r² ((4.81) with a moving centre o(t)).

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::barrier::{BarrierForm, Constraint};

pub mod recorded;

pub use recorded::{RecordedMotion, RecordedState};

/// Most breakpoints of an acceleration profile.
pub const MAX_BREAKPOINTS: usize = 64;
/// Most waypoints of a path.
pub const MAX_WAYPOINTS: usize = 64;

/// An actor's planar state at one time: position o (m), velocity ȯ (m/s), acceleration ö (m/s²),
/// heading θ (rad), its turn since the heading its covering circles were laid out at (rad), yaw
/// rate θ̇ (rad/s) and yaw acceleration θ̈ (rad/s²). A motion along a line keeps its heading
/// (turn, rate and yaw acceleration 0); a recorded one turns.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ActorState {
    pub position: [f64; 2],
    pub velocity: [f64; 2],
    pub acceleration: [f64; 2],
    pub heading: f64,
    pub turn: f64,
    pub yaw_rate: f64,
    pub yaw_acceleration: f64,
}

impl ActorState {
    /// The state of the point at `offset` from the actor's centre (the world-frame offset at the
    /// reference heading, e.g. a box's covering circle), turned with the actor: position
    /// o + R(turn) c, velocity ȯ + θ̇ J R c, acceleration ö + θ̈ J R c − θ̇² R c (J: a quarter turn).
    /// An actor that has not turned carries the offset unchanged.
    pub fn shifted(&self, offset: [f64; 2]) -> ActorState {
        if self.turn == 0.0 && self.yaw_rate == 0.0 && self.yaw_acceleration == 0.0 {
            return ActorState {
                position: [self.position[0] + offset[0], self.position[1] + offset[1]],
                ..*self
            };
        }
        let (s, c) = self.turn.sin_cos();
        let r = [c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]];
        let jr = [-r[1], r[0]];
        let (w, dw) = (self.yaw_rate, self.yaw_acceleration);
        ActorState {
            position: [self.position[0] + r[0], self.position[1] + r[1]],
            velocity: [self.velocity[0] + w * jr[0], self.velocity[1] + w * jr[1]],
            acceleration: [
                self.acceleration[0] + dw * jr[0] - w * w * r[0],
                self.acceleration[1] + dw * jr[1] - w * w * r[1],
            ],
            ..*self
        }
    }

    /// The same state without its turning (rates 0), keeping its heading: what a prediction that
    /// holds the heading assumes.
    fn without_turning(self) -> ActorState {
        ActorState {
            yaw_rate: 0.0,
            yaw_acceleration: 0.0,
            ..self
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

/// A motion whose parameters cannot be used: the key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct MotionError {
    pub key: &'static str,
    pub message: String,
}

fn motion_error(key: &'static str, message: impl Into<String>) -> MotionError {
    MotionError {
        key,
        message: message.into(),
    }
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

/// How far away an actor that does not exist is parked (m).
pub const PARKED: f64 = 1e7;

/// An actor's true motion over a run: along a line or polyline ([`StraightActor`]) or through
/// recorded states ([`RecordedMotion`], shared between the run's copies).
#[derive(Debug, Clone, PartialEq)]
pub enum ActorMotion {
    Straight(StraightActor),
    Recorded(Arc<RecordedMotion>),
}

impl ActorMotion {
    /// The motion along a line of `motion` ([`StraightActor::new`]).
    pub fn new(motion: &StraightMotion, trigger_distance: Option<f64>) -> Result<ActorMotion, MotionError> {
        Ok(ActorMotion::Straight(StraightActor::new(motion, trigger_distance)?))
    }

    /// The actor's true state at time t, as far as the run has decided it.
    pub fn state_at(&self, t: f64) -> ActorState {
        match self {
            ActorMotion::Straight(m) => m.state_at(t),
            ActorMotion::Recorded(m) => m.state_at(t),
        }
    }

    /// Whether the actor exists at t (a recorded one: from its first recorded state to its last).
    pub fn exists_at(&self, t: f64) -> bool {
        match self {
            ActorMotion::Straight(_) => true,
            ActorMotion::Recorded(m) => m.exists_at(t),
        }
    }

    /// Where the actor is at t for the barriers, the plant and the controller: its true state, or
    /// — while it does not exist (a recorded road user before its first or after its last
    /// recorded state) — parked at rest [`PARKED`] metres away (`slot` its own place), where no
    /// barrier is active and no contact can happen.
    pub fn where_at(&self, t: f64, slot: usize) -> ActorState {
        if self.exists_at(t) {
            return self.state_at(t);
        }
        ActorState {
            position: [PARKED + 100.0 * slot as f64, PARKED],
            ..ActorState::default()
        }
    }

    /// Fires a trigger ([`StraightActor::check_trigger`]; a recording has none).
    pub fn check_trigger(&mut self, t: f64, vehicle: [f64; 2]) -> bool {
        match self {
            ActorMotion::Straight(m) => m.check_trigger(t, vehicle),
            ActorMotion::Recorded(_) => false,
        }
    }

    /// When the trigger fired, if it has.
    pub fn triggered_at(&self) -> Option<f64> {
        match self {
            ActorMotion::Straight(m) => m.triggered_at(),
            ActorMotion::Recorded(_) => None,
        }
    }

    /// Marks the trigger fired at `t` (a copy of the motion following the run's own).
    pub fn set_triggered_at(&mut self, t: f64) {
        if let ActorMotion::Straight(m) = self {
            m.set_triggered_at(t);
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

/// What the controller assumes of an actor's motion over a channel's delay (a scenario section
/// next to `assumed_delays`). Every assumption but the oracle holds the actor's heading (a
/// recorded road user's box does not turn over the delay).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ActorKnowledge {
    /// Standing still where it is now.
    Static,
    /// Its current velocity held (the default).
    #[default]
    ConstantVelocity,
    /// Its current acceleration held (may predict it reversing after it stops).
    ConstantAcceleration,
    /// Its true future (an oracle: an upper bound on what prediction can achieve).
    Oracle,
}

impl ActorKnowledge {
    /// The state the controller assumes at time `at` ≥ `now`, from the state `observed` at `now`
    /// (`truth` gives the true state, for the oracle).
    pub fn predict(self, observed: &ActorState, now: f64, at: f64, truth: impl Fn(f64) -> ActorState) -> ActorState {
        let d = at - now;
        let [o, v, a] = [observed.position, observed.velocity, observed.acceleration];
        match self {
            ActorKnowledge::Static => ActorState {
                position: o,
                velocity: [0.0; 2],
                acceleration: [0.0; 2],
                ..observed.without_turning()
            },
            ActorKnowledge::ConstantVelocity => ActorState {
                position: [o[0] + v[0] * d, o[1] + v[1] * d],
                velocity: v,
                acceleration: [0.0; 2],
                ..observed.without_turning()
            },
            ActorKnowledge::ConstantAcceleration => ActorState {
                position: [
                    o[0] + v[0] * d + 0.5 * a[0] * d * d,
                    o[1] + v[1] * d + 0.5 * a[1] * d * d,
                ],
                velocity: [v[0] + a[0] * d, v[1] + a[1] * d],
                acceleration: a,
                ..observed.without_turning()
            },
            ActorKnowledge::Oracle => truth(at),
        }
    }
}

/// Adds to `c` — the constraint of the ball h = ‖p − o‖² − r² frozen at the actor's position o,
/// at a state whose planar position is p with drift velocity ṗ (the position's derivative
/// without input: the relative-degree-2 case has no input in ṗ) — the terms of the actor's
/// motion:
/// - ∂h/∂t = −2 (p − o)·ȯ, added to ḣ: a += ∂h/∂t (relative degree 1, (4.7));
/// - relative degree 2 ((4.85)): ḧ gains ∂/∂t(L_f h) + L_f(∂h/∂t) + ∂²h/∂t²
///   = −4 ṗ·ȯ + 2‖ȯ‖² − 2 (p − o)·ö, and l1 ḣ gains l1 ∂h/∂t.
///
/// b is unchanged: ∂h/∂t depends on the position alone.
pub fn add_motion_terms(c: &mut Constraint, form: BarrierForm, p: [f64; 2], p_dot: [f64; 2], actor: &ActorState) {
    add_point_motion_terms(c, form, (p, p_dot, &[]), actor);
}

/// [`add_motion_terms`] for h = ‖q − o‖² − r² measured from a point q(x) that an input may
/// move (a footprint's body circle, q = p + R(θ) c: docs/actors.md, "Footprints"), given
/// (q, q_drift = ∂q/∂x f, `q_input[j]` = ∂q/∂x G_j; an empty `q_input`: no input reaches q):
/// - ∂h/∂t = −2 (q − o)·ȯ, added to a (relative degree 1, (4.7); ∂h/∂t has no input);
/// - relative degree 2 ((4.85)/(4.86)), on ψ = L_f h + ∂h/∂t: a gains −4 q_drift·ȯ + 2‖ȯ‖²
///   − 2 (q − o)·ö + l1 ∂h/∂t, and b_j gains L_{G_j}(∂h/∂t) = −2 ȯ·`q_input[j]`.
pub fn add_point_motion_terms(
    c: &mut Constraint,
    form: BarrierForm,
    (q, q_drift, q_input): ([f64; 2], [f64; 2], &[[f64; 2]]),
    actor: &ActorState,
) {
    let (o, ov, oa) = (actor.position, actor.velocity, actor.acceleration);
    let rel = [q[0] - o[0], q[1] - o[1]];
    let dh_dt = -2.0 * (rel[0] * ov[0] + rel[1] * ov[1]);
    match form {
        BarrierForm::RelativeDegree1 { .. } => c.a += dh_dt,
        BarrierForm::RelativeDegree2 { l1, .. } => {
            let second = -4.0 * (q_drift[0] * ov[0] + q_drift[1] * ov[1]) + 2.0 * (ov[0] * ov[0] + ov[1] * ov[1])
                - 2.0 * (rel[0] * oa[0] + rel[1] * oa[1]);
            c.a += second + l1 * dh_dt;
            for (b, g) in c.b.iter_mut().zip(q_input) {
                *b += -2.0 * (ov[0] * g[0] + ov[1] * g[1]);
            }
        }
    }
}

/// Adds to `c` — the constraint of a headway barrier h = (o_x − rear) − p − D_sf − T v with
/// the lead frozen at o — the terms of the lead's motion along x: ∂h/∂t = ȯ_x (relative
/// degree 1: a += ȯ_x); at relative degree 2, ḧ gains ∂²h/∂t² = ö_x (∂h/∂t does not depend on
/// the state) and l1 ḣ gains l1 ȯ_x.
pub fn add_headway_motion_terms(c: &mut Constraint, form: BarrierForm, actor: &ActorState) {
    let (ov, oa) = (actor.velocity[0], actor.acceleration[0]);
    match form {
        BarrierForm::RelativeDegree1 { .. } => c.a += ov,
        BarrierForm::RelativeDegree2 { l1, .. } => c.a += oa + l1 * ov,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::DVector;

    use super::*;
    use crate::barrier::{self, Barrier};
    use crate::dynamics::{BicycleModel, Dynamics, UnicycleModel};

    fn motion(speed: f64, acceleration: &[[f64; 2]]) -> StraightMotion {
        StraightMotion {
            waypoints: Vec::new(),
            start: [30.0, 1.0],
            direction: [3.0, 4.0],
            speed,
            acceleration: acceleration.to_vec(),
            min_speed: 0.0,
        }
    }

    /// Independent: the speed profile integrated by explicit Euler in 1e-5 s steps.
    fn euler(m: &StraightMotion, t: f64) -> (f64, f64) {
        let a_at = |tau: f64| {
            let b = &m.acceleration;
            if b.is_empty() || tau < b[0][0] {
                return 0.0;
            }
            if tau >= b[b.len() - 1][0] {
                return b[b.len() - 1][1];
            }
            for w in b.windows(2) {
                if tau >= w[0][0] && tau < w[1][0] {
                    return w[0][1] + (w[1][1] - w[0][1]) * (tau - w[0][0]) / (w[1][0] - w[0][0]);
                }
            }
            0.0
        };
        let (mut s, mut v, dt) = (0.0, m.speed, 1e-5);
        let steps = (t / dt).round() as usize;
        for k in 0..steps {
            let tau = k as f64 * dt;
            let a = a_at(tau + 0.5 * dt);
            let v_next = (v + a * dt).max(m.min_speed);
            s += 0.5 * (v + v_next) * dt;
            v = v_next;
        }
        (s, v)
    }

    #[test]
    fn constant_velocity_is_exact_and_along_the_direction() {
        let m = motion(5.0, &[]);
        let tr = Trajectory::new(&m).unwrap();
        let st = tr.state_at(2.0);
        assert_eq!(st.position, [30.0 + 10.0 * 0.6, 1.0 + 10.0 * 0.8]);
        assert_eq!(st.velocity, [3.0, 4.0]);
        assert_eq!(st.acceleration, [0.0, 0.0]);
    }

    #[test]
    fn braking_profiles_match_an_independent_integration() {
        // Molnar et al.'s lead: 0 → −10 m/s² over 3–4 s, held to 4.5 s, back to 0 by 5.5 s.
        let ramp = motion(15.0, &[[3.0, 0.0], [4.0, -10.0], [4.5, -10.0], [5.5, 0.0]]);
        // CCRb: brake at 6 m/s² from t = 1 s, to a stop (speed held at 0).
        let step = motion(13.89, &[[1.0, 0.0], [1.0, -6.0]]);
        // A pedestrian starting to walk: 0 → 1.39 m/s at 1 m/s².
        let walk = motion(0.0, &[[0.5, 1.0], [1.89, 1.0], [1.89, 0.0]]);
        for m in [ramp, step, walk] {
            let tr = Trajectory::new(&m).unwrap();
            for t in [0.0, 0.7, 2.9, 3.5, 4.2, 4.9, 5.6, 8.0] {
                let (s, v) = euler(&m, t);
                let st = tr.state_at(t);
                let s_here = (st.position[0] - 30.0) / 0.6;
                let v_here = st.velocity[0] / 0.6;
                assert!((s_here - s).abs() < 1e-3, "{m:?} t {t}: s {s_here} vs {s}");
                assert!((v_here - v).abs() < 1e-3, "{m:?} t {t}: v {v_here} vs {v}");
                assert!(v_here >= -1e-12);
            }
        }
        // The step brake stops at 13.89/6 + 1 s and stays there.
        let tr = Trajectory::new(&motion(13.89, &[[1.0, 0.0], [1.0, -6.0]])).unwrap();
        let stop = 1.0 + 13.89 / 6.0;
        assert!(tr.state_at(stop + 0.01).velocity[0].abs() < 1e-9);
        let d = 13.89 + 13.89 * 13.89 / 12.0;
        assert!(((tr.state_at(20.0).position[0] - 30.0) / 0.6 - d).abs() < 1e-9);
    }

    /// A polyline path: the arc length of the speed profile laid along the segments (by hand:
    /// 1 m/s² from rest, s = t²/2; the corner at s = 3 m).
    #[test]
    fn a_path_is_followed_segment_by_segment() {
        let tr = Trajectory::new(&StraightMotion {
            start: [0.0, 0.0],
            direction: [9.0, 9.0],
            waypoints: vec![[3.0, 0.0], [3.0, 4.0]],
            speed: 0.0,
            acceleration: vec![[0.0, 1.0]],
            min_speed: 0.0,
        })
        .unwrap();
        let at = |t: f64| tr.state_at(t);
        let s = |t: f64| 0.5 * t * t;
        let t = 2.0; // s = 2: on the first segment
        assert!((at(t).position[0] - s(t)).abs() < 1e-12 && at(t).position[1] == 0.0);
        assert_eq!(at(t).velocity, [t, 0.0]);
        let t = 3.0; // s = 4.5: 1.5 m up the second
        assert!((at(t).position[0] - 3.0).abs() < 1e-12 && (at(t).position[1] - 1.5).abs() < 1e-12);
        assert!((at(t).velocity[1] - t).abs() < 1e-12 && at(t).velocity[0].abs() < 1e-12);
        let t = 4.0; // s = 8: past the last point, on along its direction
        assert!((at(t).position[1] - 5.0).abs() < 1e-12, "{:?}", at(t));
    }

    /// A triggered profile starts where the vehicle comes within the distance; before, the
    /// actor keeps its initial speed; the profile's times count from the trigger.
    #[test]
    fn a_trigger_starts_the_profile_when_the_vehicle_is_close() {
        let m = StraightMotion {
            waypoints: Vec::new(),
            start: [10.0, 0.0],
            direction: [0.0, 1.0],
            speed: 1.0,
            acceleration: vec![[0.5, -2.0]],
            min_speed: 0.0,
        };
        let mut motion = ActorMotion::new(&m, Some(5.0)).unwrap();
        assert_eq!(motion.state_at(3.0).position, [10.0, 3.0]);
        assert!(!motion.check_trigger(1.0, [0.0, 0.0]), "10 m away");
        assert!(motion.check_trigger(2.0, [10.0, -2.0]), "4 m away");
        assert!(!motion.check_trigger(2.5, [10.0, 2.0]), "fires once");
        assert_eq!(motion.triggered_at(), Some(2.0));
        // Until 2.5 s at 1 m/s (y = 2.5), then braking at 2 m/s² to a stop after 0.5 s.
        assert_eq!(motion.state_at(1.0).position, [10.0, 1.0]);
        assert!((motion.state_at(2.5).position[1] - 2.5).abs() < 1e-12);
        let stopped = motion.state_at(10.0);
        assert!((stopped.position[1] - 2.75).abs() < 1e-12, "{stopped:?}");
        assert_eq!(stopped.velocity, [0.0, 0.0]);
        assert!(ActorMotion::new(&m, Some(0.0)).is_err() && ActorMotion::new(&m, Some(f64::NAN)).is_err());
    }

    #[test]
    fn hostile_motions_are_refused_with_the_key() {
        let bad = [
            (
                StraightMotion {
                    direction: [0.0, 0.0],
                    ..motion(1.0, &[])
                },
                "direction",
            ),
            (motion(-1.0, &[]), "speed"),
            (motion(f64::NAN, &[]), "speed"),
            (motion(1.0, &[[2.0, 0.0], [1.0, -1.0]]), "acceleration"),
            (motion(1.0, &[[-1.0, 0.0]]), "acceleration"),
            (motion(1.0, &vec![[0.0, 0.0]; MAX_BREAKPOINTS + 1]), "acceleration"),
            (
                StraightMotion {
                    waypoints: vec![[30.0, 1.0]],
                    ..motion(1.0, &[])
                },
                "waypoints",
            ),
            (
                StraightMotion {
                    waypoints: vec![[31.0, 1.0], [f64::NAN, 0.0]],
                    ..motion(1.0, &[])
                },
                "waypoints",
            ),
            (
                StraightMotion {
                    waypoints: vec![[31.0, 1.0]; MAX_WAYPOINTS + 1],
                    ..motion(1.0, &[])
                },
                "waypoints",
            ),
        ];
        for (m, key) in bad {
            assert_eq!(Trajectory::new(&m).unwrap_err().key, key, "{m:?}");
        }
    }

    #[test]
    fn what_the_controller_assumes_over_the_delay() {
        let tr = Trajectory::new(&motion(10.0, &[[0.0, -2.0], [10.0, -2.0]])).unwrap();
        let now = tr.state_at(1.0);
        let truth = |t: f64| tr.state_at(t);
        let at = 1.5;
        let stat = ActorKnowledge::Static.predict(&now, 1.0, at, truth);
        assert_eq!(stat.position, now.position);
        let cv = ActorKnowledge::ConstantVelocity.predict(&now, 1.0, at, truth);
        assert!((cv.position[0] - (now.position[0] + now.velocity[0] * 0.5)).abs() < 1e-12);
        // Under constant deceleration the constant-acceleration prediction is exact.
        let ca = ActorKnowledge::ConstantAcceleration.predict(&now, 1.0, at, truth);
        let real = tr.state_at(at);
        for k in 0..2 {
            assert!((ca.position[k] - real.position[k]).abs() < 1e-9);
            assert!((ca.velocity[k] - real.velocity[k]).abs() < 1e-9);
        }
        assert_eq!(ActorKnowledge::Oracle.predict(&now, 1.0, at, truth), real);
    }

    /// Classic RK4 for ẋ = f(x) + G(x) u with u held.
    fn rk4(model: &dyn Dynamics, x: &[f64], u: &[f64], h: f64) -> Vec<f64> {
        let f = |x: &[f64]| {
            let mut d = vec![0.0; x.len()];
            model.dynamics_into(x, u, &mut d);
            d
        };
        let add = |x: &[f64], k: &[f64], s: f64| x.iter().zip(k).map(|(a, b)| a + s * b).collect::<Vec<_>>();
        let k1 = f(x);
        let k2 = f(&add(x, &k1, h / 2.0));
        let k3 = f(&add(x, &k2, h / 2.0));
        let k4 = f(&add(x, &k3, h));
        (0..x.len())
            .map(|i| x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
            .collect()
    }

    /// h(x(t), o(t)) along the closed loop with u held, t = t0 + k·step, k = −2…2.
    fn h_series(model: &dyn Dynamics, x0: &[f64], u: &[f64], tr: &Trajectory, t0: f64, step: f64, r: f64) -> [f64; 5] {
        let mut out = [0.0; 5];
        for (k, out) in out.iter_mut().enumerate() {
            let offset = k as f64 - 2.0;
            let mut x = x0.to_vec();
            let n = 200;
            for _ in 0..n {
                x = rk4(model, &x, u, offset * step / n as f64);
            }
            let o = tr.state_at(t0 + offset * step).position;
            *out = (x[0] - o[0]).powi(2) + (x[1] - o[1]).powi(2) - r * r;
        }
        out
    }

    /// a + b·u of the moving ball against finite differences of h along the motion: ḣ + α h
    /// (relative degree 1, the unicycle) and ḧ + l1 ḣ + l0 h (relative degree 2, the bicycle
    /// (4.78)), with an actor that accelerates (ö ≠ 0).
    #[test]
    fn motion_terms_match_finite_differences() {
        let tr = Trajectory::new(&StraightMotion {
            waypoints: Vec::new(),
            start: [6.0, 3.0],
            direction: [-1.0, 0.2],
            speed: 2.0,
            acceleration: vec![[0.0, 1.5], [10.0, 1.5]],
            min_speed: 0.0,
        })
        .unwrap();
        let (t0, r, step) = (0.8, 2.5, 1e-3);
        let actor = tr.state_at(t0);
        let ball = Barrier::circular_obstacle("actor", [0, 1], actor.position, r);

        let unicycle = UnicycleModel::default();
        let (x, u) = ([0.5, -0.4, 0.3], [1.2, 0.4]);
        let alpha = 0.7;
        let form = BarrierForm::RelativeDegree1 { alpha };
        let mut c = barrier::constraint(&ball, form, &unicycle, &DVector::from_column_slice(&x));
        let mut f = [0.0; 3];
        unicycle.drift_into(&x, &mut f);
        add_motion_terms(&mut c, form, [x[0], x[1]], [f[0], f[1]], &actor);
        let hs = h_series(&unicycle, &x, &u, &tr, t0, step, r);
        let dh = (hs[3] - hs[1]) / (2.0 * step);
        let expected = dh + alpha * hs[2];
        let got = c.value(&DVector::from_column_slice(&u));
        assert!(
            (got - expected).abs() < 1e-5 * (1.0 + expected.abs()),
            "RD1: {got} vs {expected}"
        );

        let bicycle = BicycleModel::new(6.0);
        let (x, u) = ([0.5, -0.4, 0.3, 2.5], [0.1, -0.8]);
        let (l0, l1) = (4.0, 4.0);
        let form = BarrierForm::RelativeDegree2 { l0, l1 };
        let mut c = barrier::constraint(&ball, form, &bicycle, &DVector::from_column_slice(&x));
        let mut f = [0.0; 4];
        bicycle.drift_into(&x, &mut f);
        add_motion_terms(&mut c, form, [x[0], x[1]], [f[0], f[1]], &actor);
        let hs = h_series(&bicycle, &x, &u, &tr, t0, step, r);
        let dh = (hs[3] - hs[1]) / (2.0 * step);
        let ddh = (hs[3] - 2.0 * hs[2] + hs[1]) / (step * step);
        let expected = ddh + l1 * dh + l0 * hs[2];
        let got = c.value(&DVector::from_column_slice(&u));
        assert!(
            (got - expected).abs() < 1e-4 * (1.0 + expected.abs()),
            "RD2: {got} vs {expected}"
        );
        // Without the motion terms the constraint is off by more than the tolerance: the test
        // can fail.
        let frozen = barrier::constraint(&ball, form, &bicycle, &DVector::from_column_slice(&x));
        assert!((frozen.value(&DVector::from_column_slice(&u)) - expected).abs() > 1e-2);
    }

    /// f(x(t), t) along the closed loop with u held, t = t0 + k·step, k = −2…2.
    fn series(
        model: &dyn Dynamics,
        x0: &[f64],
        u: &[f64],
        t0: f64,
        step: f64,
        f: impl Fn(&[f64], f64) -> f64,
    ) -> [f64; 5] {
        let mut out = [0.0; 5];
        for (k, out) in out.iter_mut().enumerate() {
            let offset = k as f64 - 2.0;
            let mut x = x0.to_vec();
            for _ in 0..200 {
                x = rk4(model, &x, u, offset * step / 200.0);
            }
            *out = f(&x, t0 + offset * step);
        }
        out
    }

    /// A footprint's body circle q = p + R(θ) c around an accelerating actor, along the bicycle
    /// (4.78): ḣ + α h is a + b·u exactly (relative degree 1); at relative degree 2 the row of
    /// the mixed-relative-degree condition, ψ̇ + λ2 ψ for ψ = L_f h + ∂h/∂t + λ1 h, is
    /// ḧ + l1 ḣ + l0 h minus the steering's first-order terms λ2 g + ġ, g = L_G h·u (exactly
    /// ḧ + l1 ḣ + l0 h when the steering is 0).
    #[test]
    fn body_circle_motion_terms_match_finite_differences() {
        let tr = Trajectory::new(&StraightMotion {
            waypoints: Vec::new(),
            start: [6.0, 3.0],
            direction: [-1.0, 0.2],
            speed: 2.0,
            acceleration: vec![[0.0, 1.5], [10.0, 1.5]],
            min_speed: 0.0,
        })
        .unwrap();
        let (t0, r, step, offset) = (0.8, 2.5, 1e-3, [1.6, 0.3]);
        let actor = tr.state_at(t0);
        let circle = |centre: [f64; 2]| Barrier::body_circle("actor/0-0", ([0, 1], 2), offset, centre, r);
        let h_at = |x: &[f64], t: f64| circle(tr.state_at(t).position).h_at(x);
        let bicycle = BicycleModel::new(6.0);
        let x = [0.5, -0.4, 0.3, 2.5];
        let b0 = circle(actor.position);
        let point_terms = |c: &mut Constraint, form: BarrierForm, with_input: bool| {
            let (mut f, mut g0, mut g1) = ([0.0; 4], [0.0; 4], [0.0; 4]);
            bicycle.drift_into(&x, &mut f);
            bicycle.add_input_term(&x, &[1.0, 0.0], &mut g0);
            bicycle.add_input_term(&x, &[0.0, 1.0], &mut g1);
            let (q, q_drift) = b0.point_and_velocity(&x, &f).unwrap();
            let q_input = [
                b0.point_and_velocity(&x, &g0).unwrap().1,
                b0.point_and_velocity(&x, &g1).unwrap().1,
            ];
            let inputs: &[[f64; 2]] = if with_input { &q_input } else { &[] };
            add_point_motion_terms(c, form, (q, q_drift, inputs), &actor);
        };

        let alpha = 0.7;
        let form = BarrierForm::RelativeDegree1 { alpha };
        let u = [0.1, -0.8];
        let mut c = barrier::constraint(&b0, form, &bicycle, &DVector::from_column_slice(&x));
        point_terms(&mut c, form, true);
        let hs = series(&bicycle, &x, &u, t0, step, h_at);
        let expected = (hs[3] - hs[1]) / (2.0 * step) + alpha * hs[2];
        let got = c.value(&DVector::from_column_slice(&u));
        assert!(
            (got - expected).abs() < 1e-5 * (1.0 + expected.abs()),
            "RD1: {got} vs {expected}"
        );

        let (l0, l1) = (4.0, 4.0);
        let form = BarrierForm::RelativeDegree2 { l0, l1 };
        let (_, lambda2) = form.real_rates().unwrap();
        // g(t) = ∇_x h(x(t), t)·G(x(t)) u.
        let lg_h_u = |x: &[f64], t: f64| {
            let mut grad = [0.0; 4];
            circle(tr.state_at(t).position).gradient_into(x, &mut grad);
            let mut gu = [0.0; 4];
            bicycle.add_input_term(x, &u, &mut gu);
            grad.iter().zip(gu).map(|(a, b)| a * b).sum::<f64>()
        };
        for (u, steering_terms) in [([0.0, -0.8], false), ([0.1, -0.8], true)] {
            let hs = series(&bicycle, &x, &u, t0, step, h_at);
            let dh = (hs[3] - hs[1]) / (2.0 * step);
            let ddh = (hs[3] - 2.0 * hs[2] + hs[1]) / (step * step);
            let mut expected = ddh + l1 * dh + l0 * hs[2];
            if steering_terms {
                let g = series(&bicycle, &x, &u, t0, step, lg_h_u);
                expected -= lambda2 * g[2] + (g[3] - g[1]) / (2.0 * step);
            }
            let value = |with_input: bool| {
                let mut c = barrier::constraint(&b0, form, &bicycle, &DVector::from_column_slice(&x));
                point_terms(&mut c, form, with_input);
                c.value(&DVector::from_column_slice(&u))
            };
            let got = value(true);
            assert!(
                (got - expected).abs() < 1e-4 * (1.0 + expected.abs()),
                "RD2 {u:?}: {got} vs {expected}"
            );
            if steering_terms {
                // L_G(∂h/∂t) matters: without it the constraint misses.
                assert!((value(false) - expected).abs() > 1e-2, "{} vs {expected}", value(false));
            }
        }
    }
}
