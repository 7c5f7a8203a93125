//! Road users that move (pure maths; docs/actors.md): an actor's planar motion along a
//! straight line with a piecewise-linear acceleration profile, what a controller assumes of it
//! over a channel's delay, and the terms its motion adds to the constraint of a barrier around it,
//! h(x, t) = ‖p − o(t)‖² − r² ((4.81) with a moving centre o(t)).

use serde::{Deserialize, Serialize};

use crate::barrier::{BarrierForm, Constraint};

pub mod reach;
pub mod recorded;
pub mod straight;

pub use recorded::{RecordedMotion, RecordedState};
pub use straight::{MotionJitter, PathParams, StraightActor, StraightMotion, Trajectory};

/// Most breakpoints of an acceleration profile.
pub const MAX_BREAKPOINTS: usize = 64;
/// Most waypoints of a path.
pub const MAX_WAYPOINTS: usize = 64;

thread_local! {
    /// The turn of [`ActorState::shifted`] (each of a road user's covering circles in turn).
    static TURN: crate::footprint::SinCosMemo = const { crate::footprint::SinCosMemo::new() };
}

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
    /// Whether this is the place a road user that does not exist is parked at
    /// ([`ActorMotion::where_at`]): at rest on the line y = [`PARKED`], which no world reaches
    /// (a state predicted from a real observation that comes to rest there started there).
    #[inline]
    pub fn is_parked(&self) -> bool {
        self.position[1] == PARKED && self.velocity == [0.0; 2] && self.acceleration == [0.0; 2]
    }

    /// The state of the point at `offset` from the actor's centre (the world-frame offset at the
    /// reference heading, e.g. a box's covering circle), turned with the actor: position
    /// o + R(turn) c, velocity ȯ + θ̇ J R c, acceleration ö + θ̈ J R c − θ̇² R c (J: a quarter turn).
    /// An actor that has not turned carries the offset unchanged.
    #[inline]
    pub fn shifted(&self, offset: [f64; 2]) -> ActorState {
        if self.turn == 0.0 && self.yaw_rate == 0.0 && self.yaw_acceleration == 0.0 {
            return ActorState {
                position: [self.position[0] + offset[0], self.position[1] + offset[1]],
                ..*self
            };
        }
        let (s, c) = TURN.with(|memo| memo.sin_cos(self.turn));
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
    #[inline]
    fn without_turning(self) -> ActorState {
        ActorState {
            yaw_rate: 0.0,
            yaw_acceleration: 0.0,
            ..self
        }
    }
}

/// A motion whose parameters cannot be used: the key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct MotionError {
    pub key: &'static str,
    pub message: String,
}

/// A motion's parameter error at `key` (relative to its `motion` table).
pub fn motion_error(key: &'static str, message: impl Into<String>) -> MotionError {
    MotionError {
        key,
        message: message.into(),
    }
}

/// Where an actor that does not exist is parked (m, both coordinates): beyond every coordinate
/// a world may hold (obstacles and states within ±1e9 m, `scenario::OBSTACLE_EXTENT` and
/// `STATE_EXTENT`; CommonRoad's within ±1e7 m), so a parked road user is never near anything.
/// (Until stop 77 it was 1e7 m, which a CommonRoad file's largest coordinates reach.) Its
/// squares stay far from overflow and MuJoCo's geoms take it (a world geom's position).
pub const PARKED: f64 = 4e9;

/// A kind of actor motion (`[obstacles.motion] kind = …`, docs/actors.md): the actor's true
/// state at any time of the run. Each kind is its own module, registered as filters are
/// (`Registry::add_motion` in `mjsafe::registry`): `straight` and `waypoints` ([`straight`]),
/// `recorded` (a CommonRoad recording, [`recorded`]).
pub trait Motion: Send + Sync + std::fmt::Debug {
    /// The actor's true state at time t, as far as the run has decided it.
    fn state_at(&self, t: f64) -> ActorState;

    /// Whether the actor exists at t (default: always).
    fn exists_at(&self, _t: f64) -> bool {
        true
    }

    /// The heading (rad) a box's covering circles are laid out at when the motion decides it (a
    /// box moving along a line faces its direction); None: the shape's own `heading`.
    fn layout_heading(&self) -> Option<f64> {
        None
    }

    /// Fires the motion's trigger at t if the vehicle at `vehicle` sets it off; returns whether
    /// it fired now (default: no trigger).
    fn check_trigger(&mut self, _t: f64, _vehicle: [f64; 2]) -> bool {
        false
    }

    /// When the trigger fired, if it has.
    fn triggered_at(&self) -> Option<f64> {
        None
    }

    /// Marks the trigger fired at `t` (a copy of the motion following the run's own).
    fn set_triggered_at(&mut self, _t: f64) {}

    /// A copy (the controller keeps its own, which follows the run's triggers).
    fn clone_motion(&self) -> Box<dyn Motion>;
}

/// What a motion kind is built from besides its parameters: the obstacle it moves.
#[derive(Debug, Clone, Copy)]
pub struct MotionContext<'a> {
    /// The obstacle's `centre` (m): where a motion along a path starts.
    pub centre: [f64; 2],
    /// The scenario's seed and the obstacle's index: the seeded variations' draws.
    pub seed: u64,
    pub index: usize,
    /// Whether the obstacle is a box (`shape`), not a circle.
    pub boxed: bool,
    /// The scenario's CommonRoad file, if it names one (recorded road users).
    pub commonroad: Option<&'a mjsafe_commonroad::CommonRoad>,
}

/// An actor's true motion over a run: one registered [`Motion`] kind.
#[derive(Debug)]
pub struct ActorMotion(Box<dyn Motion>);

impl Clone for ActorMotion {
    fn clone(&self) -> Self {
        ActorMotion(self.0.clone_motion())
    }
}

impl ActorMotion {
    /// The run's motion of one kind.
    pub fn new(motion: impl Motion + 'static) -> ActorMotion {
        ActorMotion(Box::new(motion))
    }

    /// The actor's true state at time t, as far as the run has decided it.
    #[inline]
    pub fn state_at(&self, t: f64) -> ActorState {
        self.0.state_at(t)
    }

    /// Whether the actor exists at t (a recorded one: from its first recorded state to its last).
    #[inline]
    pub fn exists_at(&self, t: f64) -> bool {
        self.0.exists_at(t)
    }

    /// The heading a box's covering circles are laid out at, if the motion decides it.
    pub fn layout_heading(&self) -> Option<f64> {
        self.0.layout_heading()
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

    /// Fires the motion's trigger ([`Motion::check_trigger`]).
    pub fn check_trigger(&mut self, t: f64, vehicle: [f64; 2]) -> bool {
        self.0.check_trigger(t, vehicle)
    }

    /// When the trigger fired, if it has.
    pub fn triggered_at(&self) -> Option<f64> {
        self.0.triggered_at()
    }

    /// Marks the trigger fired at `t` (a copy of the motion following the run's own).
    pub fn set_triggered_at(&mut self, t: f64) {
        self.0.set_triggered_at(t)
    }
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

    /// Bounds on every state [`ActorKnowledge::predict`] gives from `observed` for the look-ahead
    /// times d = at − now in [from, to] (0 ≤ from ≤ to): the state at the middle time, and
    /// the largest distance of the position, the velocity and the acceleration from its (the
    /// assumed heading and turning do not change). Each bound is grown by a relative 1e-9 (and
    /// the displacement by 1e-9 of the position's size) above the rounding of the predictions.
    /// None for the oracle (the recording's future is not bounded here) and for an empty or
    /// negative window.
    pub fn window(self, observed: &ActorState, from: f64, to: f64) -> Option<AssumedWindow> {
        if !(0.0 <= from && from <= to && to.is_finite()) || self == ActorKnowledge::Oracle {
            return None;
        }
        let middle = self.predict(observed, 0.0, 0.5 * (from + to), |_| *observed);
        let half = 0.5 * (to - from);
        let norm = |v: [f64; 2]| v[0].hypot(v[1]);
        let (v, a) = (norm(observed.velocity), norm(observed.acceleration));
        // o(d) − o(m) = (d − m)(v + a (d + m)/2) and ȯ(d) − ȯ(m) = a (d − m) for a constant
        // acceleration (v alone at constant velocity), with |d − m| ≤ half and d + m ≤ 2 to.
        let (displacement, velocity_change) = match self {
            ActorKnowledge::Static => (0.0, 0.0),
            ActorKnowledge::ConstantVelocity => (half * v, 0.0),
            ActorKnowledge::ConstantAcceleration => (half * (v + a * to), half * a),
            ActorKnowledge::Oracle => return None,
        };
        let grow = 1.0 + 1e-9;
        let size = |v: [f64; 2]| 1e-9 * (norm(v) + 1.0);
        Some(AssumedWindow {
            middle,
            displacement: displacement * grow + size(middle.position),
            velocity_change: velocity_change * grow + size(middle.velocity),
        })
    }
}

/// What [`ActorKnowledge::window`] bounds: every state an assumption gives over a window of
/// look-ahead times.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AssumedWindow {
    /// The assumed state at the window's middle time.
    pub middle: ActorState,
    /// The largest distance (m) of the assumed position from `middle`'s.
    pub displacement: f64,
    /// The largest ‖ȯ − ȯ_middle‖ (m/s); the assumed acceleration does not change.
    pub velocity_change: f64,
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

    /// Every state an assumption predicts over a window lies within the window's bounds
    /// (sampled densely, each assumption, moving and turning observations); the bounds are
    /// tight to within their slack at the window's ends (constant velocity).
    #[test]
    fn an_assumption_stays_within_its_window() {
        let observed = ActorState {
            position: [1.0e4, -3.0e3],
            velocity: [7.0, -2.0],
            acceleration: [-1.5, 0.8],
            heading: 0.3,
            turn: 0.2,
            yaw_rate: 0.4,
            yaw_acceleration: -0.1,
        };
        let mut checked = 0;
        for knowledge in [
            ActorKnowledge::Static,
            ActorKnowledge::ConstantVelocity,
            ActorKnowledge::ConstantAcceleration,
        ] {
            for (from, to) in [(0.0, 0.6), (0.2, 0.5), (0.0, 0.0), (1.0, 7.0)] {
                let w = knowledge.window(&observed, from, to).unwrap();
                for k in 0..=1000 {
                    let d = from + (to - from) * k as f64 / 1000.0;
                    let s = knowledge.predict(&observed, 100.0, 100.0 + d, |_| unreachable!());
                    let moved = (s.position[0] - w.middle.position[0]).hypot(s.position[1] - w.middle.position[1]);
                    assert!(
                        moved <= w.displacement,
                        "{knowledge:?} d {d}: {moved} > {}",
                        w.displacement
                    );
                    let changed = (s.velocity[0] - w.middle.velocity[0]).hypot(s.velocity[1] - w.middle.velocity[1]);
                    assert!(
                        changed <= w.velocity_change,
                        "{knowledge:?} d {d}: {changed} > {}",
                        w.velocity_change
                    );
                    assert_eq!(s.acceleration, w.middle.acceleration);
                    assert_eq!((s.yaw_rate, s.yaw_acceleration, s.turn), (0.0, 0.0, observed.turn));
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 3 * 4 * 1001);
        let w = ActorKnowledge::ConstantVelocity.window(&observed, 0.0, 0.6).unwrap();
        let end = ActorKnowledge::ConstantVelocity.predict(&observed, 0.0, 0.6, |_| unreachable!());
        let moved = (end.position[0] - w.middle.position[0]).hypot(end.position[1] - w.middle.position[1]);
        assert!(w.displacement - moved < 1e-4, "{} against {moved}", w.displacement);
        assert!(ActorKnowledge::Oracle.window(&observed, 0.0, 0.6).is_none());
        assert!(ActorKnowledge::ConstantVelocity.window(&observed, 0.5, 0.2).is_none());
        assert!(ActorKnowledge::ConstantVelocity.window(&observed, -0.1, 0.2).is_none());
    }

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
        let mut motion = ActorMotion::new(StraightActor::new(&m, Some(5.0)).unwrap());
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
        assert!(StraightActor::new(&m, Some(0.0)).is_err() && StraightActor::new(&m, Some(f64::NAN)).is_err());
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
