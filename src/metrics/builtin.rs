//! Every metric mjsafe computes, declared once each ([`METRICS`]), with its accumulator.
//! Adding a metric: one entry here (and its accumulator beside it); its JSON, columns, table
//! cell, unit and docs/metrics.md row follow (`tests/metrics.rs` checks each of them).

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use super::{always, Accumulate, CellKind, Metric, Observed, Part, RunFacts, Shape};
use super::{Collision, PredictionStats, PrescribedTimeMetrics, Value};
use crate::log::{proto, Topic};
use crate::stall::{StallDetector, STALL_SPEED};

const SECONDS: &str = "s";
const METRES: &str = "m";
/// The barrier's own unit (m² for an obstacle's (4.81)).
const BARRIER: &str = "h-units";
/// The input channel's own unit (steering: tan δ; acceleration: m/s²).
const INPUT: &str = "u-units";
/// The units of a barrier condition a + b·u: those of ḣ + α(h) or of ḧ + l1 ḣ + l0 h.
const CONDITION: &str = "h-units/s^ρ";
const INPUT_RATE: &str = "u-units/s";
/// The norm of a state error, over components of their own units (m, rad, m/s, …).
const STATE: &str = "x-units";
const FRACTION: &str = "1";
const JERK: &str = "m/s³";
const SPEED: &str = "m/s";

/// A part of a composite metric that needs nothing beyond the metric.
const fn part(
    key: &'static str,
    column: &'static str,
    unit: &'static str,
    cell: CellKind,
    meaning: &'static str,
) -> Part {
    Part {
        key,
        column,
        unit,
        meaning,
        cell,
        reads: &[],
        metadata: &[],
    }
}

/// A metric that applies to every run and is not in the aligned table.
const fn metric(
    name: &'static str,
    unit: &'static str,
    shape: Shape,
    reads: &'static [Topic],
    accumulator: fn() -> Box<dyn Accumulate>,
    meaning: &'static str,
) -> Metric {
    Metric {
        name,
        unit,
        meaning,
        shape,
        parts: &[],
        reads,
        metadata: &[],
        applies: always,
        accumulator,
        table: None,
    }
}

fn new<A: Accumulate + Default + 'static>() -> Box<dyn Accumulate> {
    Box::<A>::default()
}

/// The metrics, in the order of `analyze --json` and the flat columns.
pub static METRICS: &[Metric] = &[
    Metric {
        table: Some("sim_time"),
        ..metric("simulated_time", SECONDS, Shape::Number, &[Topic::State], new::<SimulatedTime>,
            "the largest `time` of the `/state` messages (the last state: the end of the run or where it stopped)")
    },
    Metric {
        table: Some("steps"),
        ..metric("steps", "steps", Shape::Count, &[Topic::State], new::<Steps>,
            "the largest `step` of the `/state` messages (physics steps taken)")
    },
    Metric {
        parts: &[
            part("time", "collision_time", SECONDS, CellKind::Num,
                "`time` of the first `/event` of kind `collision_start`; absent without one"),
            part("with", "collision_with", "", CellKind::Text,
                "that event's first participant other than `vehicle` (the obstacle's name)"),
            part("depth", "collision_depth", METRES, CellKind::Num,
                "the largest `depth` over all `collision_start` and `collision_end` events (deepest penetration of any contact; MuJoCo's contact distance, two boxes' exact penetration (docs/actors.md, \"On MuJoCo\"), or the circle overlap on the ODE plant); a contact the log leaves open gives null, reason under `missing`"),
        ],
        table: Some("collision"),
        ..metric("collision", SECONDS, Shape::Collision, &[Topic::Event], new::<FirstCollision>,
            "the run's first collision")
    },
    Metric {
        table: Some("min_h"),
        ..metric("min_h", BARRIER, Shape::Number, &[Topic::Barrier], new::<MinH>,
            "min over `/barrier` messages and their barriers of `h` (NaN ignored); h < 0: the state left the safe set; absent without barriers, and where the barriers are not in one unit (several barriers, not all obstacles: see min_h_by_barrier)")
    },
    metric("min_h_by_barrier", BARRIER, Shape::PerBarrier, &[Topic::Barrier], new::<MinHByBarrier>,
        "min over `/barrier` messages of each entry's `h` (an obstacle's entry: the least over its barriers, a footprint's pairs of covering circles, unless `[log] barrier_pairs` lists them), in that barrier's own unit (m² for an obstacle (4.81), m for a half-space (2.47)); absent without barriers"),
    Metric {
        metadata: &["timestep"],
        table: Some("t_h<0"),
        ..metric("time_h_negative", SECONDS, Shape::Number, &[Topic::Barrier], new::<TimeHNegative>,
            "Δt × (`/barrier` messages whose minimum h is < 0): time outside the safe set, sampled at the start of each step; absent without barriers")
    },
    Metric {
        table: Some("filter_active"),
        ..metric("filter_active_fraction", FRACTION, Shape::Number, &[Topic::Filter], new::<ActiveFraction>,
            "(ticks with `active`) / (ticks), 0 without ticks; `active`: the filter changed the nominal input")
    },
    Metric {
        table: Some("qp_infeasible"),
        ..metric("filter_infeasible_ticks", "ticks", Shape::Count, &[Topic::Filter], new::<InfeasibleTicks>,
            "ticks with `infeasible` (no input met every constraint within the limits; the least-violation input was applied)")
    },
    metric("filter_unmet_ticks", "ticks", Shape::Count, &[Topic::Filter], new::<UnmetTicks>,
        "ticks whose `/filter` `unmet` is not empty: some channel's decision leaves a barrier condition unmet with the real inputs it plans (an infeasible QP, or a γm constraint (4.60) met only by the fictitious inputs σ)"),
    metric("max_shortfall_by_barrier", CONDITION, Shape::PerBarrier, &[Topic::Filter], new::<MaxShortfallByBarrier>,
        "max over `/filter` messages of each barrier's `shortfall` (the filter's barriers: a footprint's pairs `<obstacle>/<i>-<j>`): how far below 0 a decision leaves a + b·u, in that barrier's constraint units (those of ḣ + α(h), or of ḧ + l1 ḣ + l0 h); absent if no condition was ever left unmet"),
    Metric {
        table: Some("max|u-u_nom|"),
        ..metric("max_correction", INPUT, Shape::PerChannel, &[Topic::Filter], new::<MaxCorrection>,
            "max over ticks of |u − u_nom| of the channel (`/filter` `correction`)")
    },
    metric("max_applied_input", INPUT, Shape::PerChannel, &[Topic::Applied], new::<MaxAppliedInput>,
        "max over `/command/applied` of |u| of the channel: the largest command that reached the actuator (the bicycle's: tan δ and m/s²), to hold against what the vehicle can do (CommonRoad's vehicle 2: |δ| ≤ 1.066 rad, tan δ ≤ 1.8098; |a| ≤ 11.5 m/s²); `[actuator_dynamics]` may limit what the plant then gets (`/command/actuated`)"),
    Metric {
        applies: |run| !run.vehicle_limits.is_empty(),
        ..metric("vehicle_limit_ratio", FRACTION, Shape::PerChannel, &[Topic::Applied, Topic::Actuated], new::<VehicleLimitRatio>,
            "runs with `[vehicle_limits]` (metadata `vehicle_limits`, the largest |u| per channel the vehicle takes, declared and not enforced): max over the inputs that reached the vehicle of |u| / limit, per declared channel — `/command/actuated` when the log has it (`[actuator_dynamics]`), else `/command/applied`; above 1: the vehicle could not have followed its commands (`run` and `analyze` warn); 0 for a channel never commanded")
    },
    Metric {
        parts: &[
            part("count", "prediction_count", "predictions", CellKind::Int,
                "`/prediction` messages of the channel (predictions whose target time was reached)"),
            part("max_error", "prediction_max_error", STATE, CellKind::Num,
                "max of `error` = ‖p_i(t) − x(φ_i⁻¹(t))‖ (prediction consistency, Definition 4.3)"),
            part("rms_error", "prediction_rms_error", STATE, CellKind::Num,
                "√(mean of `error`²) over the channel's predictions"),
            part("max_relative_error", "prediction_max_relative_error", FRACTION, CellKind::Num,
                "max of `relative_error` = error / max(1, ‖x‖)"),
            part("reused_chain", "", "predictions", CellKind::Int,
                "predictions that continued the previous tick's trajectory instead of integrating the whole window (`control.chain_tolerance`)"),
            part("max_chain_mismatch", "", STATE, CellKind::Num,
                "max of `chain_mismatch`, how far p_1(t) is from the previous chain at t + D_1: the largest of the planar position's distance and every other state component's difference (0 when never measured)"),
        ],
        applies: |run| run.predicts != Some(false),
        table: Some("prediction_err_max/rms"),
        ..metric("prediction", STATE, Shape::Prediction, &[Topic::Prediction], new::<Predictions>,
            "prediction consistency per channel")
    },
    metric("first_override_time", SECONDS, Shape::Number, &[Topic::Filter], new::<FirstOverride>,
        "`time` of the first tick with `active`; absent if the filter never acted"),
    Metric {
        metadata: &["control_period"],
        ..metric("override_duration", SECONDS, Shape::Number, &[Topic::Filter], new::<OverrideDuration>,
            "control period × (ticks with `active`)")
    },
    metric("max_input_rate", INPUT_RATE, Shape::PerChannel, &[Topic::Issued], new::<InputRate>,
        "max over consecutive `/command/issued` (t₁, u₁), (t₂, u₂), t₂ > t₁, of |u₂ − u₁| / (t₂ − t₁) of the channel: the issued input's largest rate of change (the jerk for an acceleration channel); absent with fewer than two commands"),
    metric("max_input_rate_overriding", INPUT_RATE, Shape::PerChannel, &[Topic::Issued, Topic::Filter], new::<InputRateOverriding>,
        "the same over the pairs where the filter was active at t₁ or t₂ (the rate of change interventions cause); absent when the filter never acted"),
    Metric {
        table: Some("min_clearance"),
        ..metric("min_clearance", METRES, Shape::Number, &[Topic::Barrier], new::<MinClearance>,
            "min over `/barrier` obstacle entries of `clearance`: the gap between the hull and the obstacle (negative: overlap)")
    },
    metric("min_clearance_by_obstacle", METRES, Shape::PerBarrier, &[Topic::Barrier], new::<MinClearanceByObstacle>,
        "min over `/barrier` messages of each obstacle's `clearance` (negative: overlap); absent without obstacles"),
    metric("min_time_to_collision", SECONDS, Shape::Number, &[Topic::Barrier], new::<MinTimeToCollision>,
        "min over `/barrier` entries of known obstacles of `time_to_collision` (contact if the velocity were kept; 0 while overlapping); absent if never finite"),
    metric("min_ttc_by_barrier", SECONDS, Shape::PerBarrier, &[Topic::Barrier], new::<MinTtcByBarrier>,
        "min over `/barrier` messages of each known obstacle's entry's `time_to_collision` (the least over its pairs) (relative to a moving obstacle's velocity; NaN ignored, ∞: never closing in); absent without obstacles"),
    Metric {
        // A run that made no predictions (metadata `predicts = false`) has no /prediction to lack.
        applies: |run| run.predicts != Some(false),
        ..metric("max_actor_prediction_error", METRES, Shape::Number, &[Topic::Prediction, Topic::Actors], new::<MaxActorPredictionError>,
        "max over `/prediction` messages and their moving obstacles of `actor_error` = ‖assumed − true position at the target time‖ (what `[actor_knowledge]` assumed over the delay; NaN ignored: an obstacle unknown at the prediction's tick or not existing at the controller's last observation (the tick, unless `actor_knowledge.period`), or not existing at the target time); absent without moving obstacles, and with a reason when the log has `/actors` but no actor predictions")
    },
    Metric {
        // Vehicles with a heading (a line's car following has no path to be ahead in).
        applies: |run| run.heading_index.is_some(),
        ..metric("min_time_headway", SECONDS, Shape::Number, &[Topic::State, Topic::Actors], new::<MinTimeHeadway>,
        "time headway THW as CommonRoad-CriMe defines it (measure/time/thw.py; not the numbers of CriMe 0.4.5's code: docs/studies.md, \"Against CriMe itself\"): at each `/state` time t with a lead — the nearest road user (`/actors`, present) ahead in the vehicle's path (in the frame of its heading at t, laterally within the vehicle's half width plus the road user's projected half width; CriMe: in the same lanelet), ahead of the vehicle's front (metadata `vehicle_extent`, `actor_extents`) — the time until the vehicle's front, on its logged trajectory, first reaches where the lead's rear was at t (along the heading at t; linear between `/state` samples); min over t; absent without a lead ever ahead, or when the front never reached such a point")
    },
    Metric {
        applies: |run| run.heading_index.is_some(),
        ..metric("max_brake_threat_number", FRACTION, Shape::Number, &[Topic::State, Topic::Actors], new::<MaxBrakeThreat>,
        "brake threat number BTN as CommonRoad-CriMe defines it (measure/index/btn.py, Åsljung et al. 2017, (9); accelerations signed and along the vehicle's heading, where CriMe 0.4.5's code takes magnitudes along the lanelet's world-frame direction: docs/studies.md, \"Against CriMe itself\"): at each `/state` time with a lead closing in (as for min_time_headway), a_req / (−a_max) with the required deceleration a_req = min(a_L − v_rel² / (2 HW), 0) (CriMe's a_long_req.py, constant acceleration: v_rel = v_L − v, HW the gap from the vehicle's front to the lead's rear, a_L the lead's acceleration, all along the vehicle's heading; v the state named `speed`) and a_max = A_LON_MAX = 11.5 m/s² (CriMe's default: CommonRoad's vehicle models); max over t; 0 when a lead was ahead but never closing in; absent without a lead ever ahead")
    },
    metric("impact_speed_by_actor", SPEED, Shape::PerBarrier, &[Topic::State, Topic::Actors, Topic::Event], new::<ImpactSpeedByActor>,
        "per obstacle, at its first `collision_start` at time t: the relative speed of the vehicle and the obstacle as they approached, ‖Δ(p − o)‖ / Δt for a moving one (`/actors`: the vehicle's planar position p and the obstacle's position o, both differentiated backward from their logged positions at the previous `/state` and `/actors` messages to t, so that the contact's push after t is not in it), ‖Δp‖ / Δt for a standing one (its velocity 0); absent without a collision (reason `no collision` when the log has moving obstacles), for an obstacle absent at the previous `/actors` message (a recorded road user at its first state) and for a collision at the log's first step (reasons under `impact_speed_by_actor.<name>`)"),
    metric("speed_reduction", SPEED, Shape::Number, &[Topic::State, Topic::Event], new::<SpeedReduction>,
        "planar vehicles: v(t_1) − v(t_c), t_c the first `collision_start`, or v(t_1) − min v over the run without a collision; v at a `/state` message after the first = distance from the previous `/state` position / the time between them (backward difference: the speed over the step that ends there, without the contact's push at t_c); absent for vehicles without a planar position"),
    metric("vehicle_stopped", FRACTION, Shape::Count, &[Topic::State, Topic::Event], new::<VehicleStopped>,
        "planar vehicles: 1 if the speed v (as for speed_reduction) fell below STALL_SPEED = 0.05 m/s at some `/state` message before the first `collision_start` (or the end without one), else 0"),
    Metric {
        metadata: &["timestep", "max_delay"],
        ..metric("delay_attributed_violation_time", SECONDS, Shape::Number, &[Topic::Barrier, Topic::Event], new::<DelayAttributed>,
            "Δt × (steps where an obstacle has h < 0 within [its appearance, appearance + metadata `max_delay`)): violations before the delay since it appeared could be compensated; its appearance is its `obstacle_appeared` event, or its `road_user_entered` event for a recorded road user whose recording begins later; absent without obstacles")
    },
    Metric {
        metadata: &["control_period"],
        ..metric("intervention_integral", "u-units·s", Shape::Number, &[Topic::Filter], new::<InterventionIntegral>,
            "Σ over ticks of ‖u − u_nom‖ (`/filter` `correction`) × control period: ∫‖u − u_nom‖ dt")
    },
    Metric {
        metadata: &["control_period"],
        applies: |run| run.declared_planar != Some(None),
        table: Some("stall"),
        ..metric("stall_time", SECONDS, Shape::Number, &[Topic::State, Topic::Filter], new::<Stall>,
            "planar vehicles: start of the first interval of at least STALL_DURATION = 1 s in which the vehicle moved slower than STALL_SPEED = 0.05 m/s (positions at the control ticks) while the filter overrode the nominal input (`/filter` `active`): a run held still by its filter (the CBF-QP deadlock in front of an obstacle), safe only by not moving; absent without one")
    },
    Metric {
        applies: |run| run.goal.is_some(),
        ..metric("distance_to_goal", METRES, Shape::Number, &[Topic::State], new::<DistanceToGoal>,
            "runs with a `[goal]` (metadata `goal_position` g and `goal_radius` r, or `goal_polygons`; `goal_after`, `goal_by`): min over the `/state` messages from `after` up to `by` (all without them) of the distance from p, the planar position, to the region (max(0, ‖p − g‖ − r) for a disc; 0 inside a polygon, else the distance to its edges): how far the vehicle stayed from the goal; 0: it entered it (in the window); absent, with the reason, for a goal without a region (`goal_region` = none)")
    },
    Metric {
        applies: |run| run.goal.is_some(),
        ..metric("time_to_goal", SECONDS, Shape::Number, &[Topic::State], new::<TimeToGoal>,
            "`time` of the first `/state` message from `after` on with p in the goal region (‖p − g‖ ≤ r, or inside a polygon; whether before `by` or not) and the speed and heading in the goal's intervals (`goal_speed`, `goal_heading`, if any); for a goal without a region (metadata `goal_region` = none: a CommonRoad goal without a position) the first from `after` on with the speed and heading in them (a goal of a time alone: `after`, the time a run lasting into the window reaches it, as commonroad-io's `GoalRegion.is_reached` decides); with goal states (metadata `goal_states`: a CommonRoad planning problem's that differ in more than their regions) the first state that meets one of them whole, each from its own `after` on; absent when the vehicle never enters it so, the closest approach under `missing`")
    },
    Metric {
        applies: |run| run.reference_path.is_some() && run.declared_planar != Some(None),
        ..metric("progress_along_path", METRES, Shape::Number, &[Topic::State], new::<ProgressAlongPath>,
            "planar vehicles: (p_last − p_first) · (cos ψ, sin ψ): the displacement of the planar position from the first to the last `/state` message along the nominal's straight reference path of heading ψ (metadata `reference_path`: `path_lqr`); negative: it went backwards; absent for nominals without a path")
    },
    metric("max_longitudinal_jerk", JERK, Shape::Number, &[Topic::State], new::<LongitudinalJerk>,
        "planar vehicles: max |third difference of the positions at the control ticks| / T_c³ along the velocity (central difference); needs metadata `control_period`"),
    metric("max_lateral_jerk", JERK, Shape::Number, &[Topic::State], new::<LateralJerk>,
        "the same across the velocity"),
    Metric {
        parts: &[
            part("time", "prescribed_time", SECONDS, CellKind::Num,
                "T, metadata `prescribed_time` (prescribed-time filters, Ch. 5); absent for other runs"),
            Part {
                reads: &[Topic::Barrier],
                metadata: &["timestep"],
                ..part("barrier", "prescribed_time_barrier", BARRIER, CellKind::Num,
                    "min over barriers of h in the `/barrier` message at T (within Δt/2); a run that ends at or before T has none (reason under `missing`)")
            },
            Part {
                metadata: &["timestep"],
                ..part("state_residuals", "prescribed_time_state_residual", STATE, CellKind::Num,
                    "|x_i(T)| per state component, from the `/state` message at T")
            },
            Part {
                reads: &[Topic::Issued],
                metadata: &["timestep"],
                ..part("input_residual", "prescribed_time_input_residual", INPUT, CellKind::Num,
                    "max over channels of |u(T)| of the `/command/issued` message at T")
            },
        ],
        applies: |run| run.prescribed_time.is_some(),
        ..metric("at_prescribed_time", SECONDS, Shape::AtPrescribedTime, &[Topic::State], new::<AtPrescribedTime>,
            "the values at the prescribed time T")
    },
    Metric {
        metadata: &["timestep"],
        applies: |run| !run.requirements.is_empty(),
        ..metric(REQUIREMENTS, "signal units", Shape::PerBarrier, &[Topic::State], new::<super::requirements::RequirementsAccumulator>,
            "per requirement (scenario `[[requirements]]`, `--require NAME=FORMULA`): the robustness ρ(φ, 0) of its STL formula over the run's signals, in the unit of the signals its atoms compare (docs/requirements.md); < 0: violated, > 0: satisfied; absent with its reason when a signal is unknown or has no value")
    },
    Metric {
        metadata: &["timestep"],
        applies: |run| !run.requirements.is_empty(),
        ..metric(REQUIREMENT_VIOLATED_AT, SECONDS, Shape::PerBarrier, &[Topic::State], new::<super::requirements::ViolationTimes>,
            "per violated requirement: when it first certainly failed — the time of the earliest sample after which no continuation of the run could satisfy it (for `always ψ`, the first time ψ fails; for `eventually[0, T] ψ` never met, T); absent with `not violated` for a satisfied one (docs/requirements.md)")
    },
];

/// The name of the requirements' metric (`req.<name>` columns).
pub const REQUIREMENTS: &str = "req";

/// The name of the requirements' violation-time metric (`req_violated_at.<name>` columns).
pub const REQUIREMENT_VIOLATED_AT: &str = "req_violated_at";

/// The maximum longitudinal deceleration the brake threat number divides by (m/s²):
/// CommonRoad-CriMe's default `a_lon_max`, the a_max of CommonRoad's vehicle parameter sets.
pub const A_LON_MAX: f64 = 11.5;

/// The vehicle at a `/state` time: position, unit heading vector, speed, front point.
#[derive(Debug, Clone, Copy)]
struct Ego {
    time: f64,
    heading: [f64; 2],
    speed: f64,
    front: [f64; 2],
}

/// The lead at a time: the gap from the vehicle's front to its rear HW (m), and its velocity
/// and acceleration along the vehicle's heading.
#[derive(Debug, Clone, Copy)]
struct Lead {
    headway: f64,
    velocity: f64,
    acceleration: f64,
}

/// A present road user of known extent: [length, width], position, velocity, acceleration,
/// heading.
type RoadUser = ([f64; 2], [f64; 2], [f64; 2], [f64; 2], f64);

/// Pairs each `/state` with the `/actors` message of its time and finds the lead then (the
/// headway metrics, after CommonRoad-CriMe's HW): the nearest present road user ahead of the
/// vehicle's front and laterally within the vehicle's half width plus its own projected half
/// width, in the frame of the vehicle's heading.
#[derive(Default)]
struct LeadTracker {
    /// Position, heading and `speed` indices of `/state` (None: not yet seen; Some(None): none).
    indices: Option<Option<([usize; 2], usize, usize)>>,
    state: Option<(f64, [f64; 2], f64, f64)>,
    /// The latest `/actors` time and its present road users of known extent: [length, width],
    /// position, velocity, acceleration, heading (reused: no allocation per message).
    actors_time: Option<f64>,
    present: Vec<RoadUser>,
    /// Each road user's extent, by its place in the last `/actors` message.
    extents: ByPosition<Option<[f64; 2]>>,
    done: f64,
    /// Whether any road user was ever ahead in the path.
    saw_lead: bool,
}

impl LeadTracker {
    /// The vehicle and its lead at a time both `/state` and `/actors` have reached (once per time).
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) -> Option<(Ego, Option<Lead>)> {
        match record {
            Observed::State(m) => {
                let indices = *self.indices.get_or_insert_with(|| {
                    let position = run.declared_planar.flatten()?;
                    let speed = m.names.iter().position(|n| n == "speed")?;
                    Some((position, run.heading_index?, speed))
                });
                let ([i, j], h, v) = indices?;
                let value = |k: usize| m.values.get(k).copied();
                self.state = Some((m.time, [value(i)?, value(j)?], value(h)?, value(v)?));
            }
            Observed::Actors(m) => {
                self.actors_time = Some(m.time);
                self.present.clear();
                for (k, a) in m.actors.iter().enumerate() {
                    let known = (self.extents).get(k, &a.name, |name| run.actor_extents.get(name).copied());
                    let Some(extent) = known.filter(|_| !a.absent) else {
                        continue;
                    };
                    self.present
                        .push((extent, [a.x, a.y], [a.vx, a.vy], [a.ax, a.ay], a.heading));
                }
            }
            _ => return None,
        }
        let ((time, p, heading, speed), actors_time) = (self.state?, self.actors_time?);
        if !same_time(time, actors_time) || (self.done > 0.0 && time <= self.done) {
            return None;
        }
        self.done = time.max(f64::MIN_POSITIVE);
        let [front, _, half_width] = run.vehicle_extent?;
        let e = [heading.cos(), heading.sin()];
        let ego = Ego {
            time,
            heading: e,
            speed,
            front: [p[0] + front * e[0], p[1] + front * e[1]],
        };
        let lead = (self.present.iter())
            .filter_map(|&([length, width], o, v, a, actor_heading)| {
                let d = [o[0] - p[0], o[1] - p[1]];
                let (along, across) = (d[0] * e[0] + d[1] * e[1], -d[0] * e[1] + d[1] * e[0]);
                let (s, c) = (actor_heading - heading).sin_cos();
                let half_along = 0.5 * (length * c.abs() + width * s.abs());
                let half_across = 0.5 * (length * s.abs() + width * c.abs());
                let headway = along - half_along - front;
                (across.abs() < half_width + half_across && headway > 0.0).then_some(Lead {
                    headway,
                    velocity: v[0] * e[0] + v[1] * e[1],
                    acceleration: a[0] * e[0] + a[1] * e[1],
                })
            })
            .min_by(|a, b| a.headway.total_cmp(&b.headway));
        self.saw_lead |= lead.is_some();
        Some((ego, lead))
    }

    /// Why a headway metric of a log with road users has no value.
    fn reason(&self, run: &RunFacts) -> &'static str {
        match (run.vehicle_extent, self.indices) {
            (None, _) => {
                "the log has no metadata `vehicle_extent` and `actor_extents` (logs written before the headway metrics)"
            }
            (_, Some(None)) => "needs a planar vehicle with a heading and a state named `speed`",
            _ => "no road user was ever ahead in the vehicle's path",
        }
    }
}

/// The pending time headways: (t, heading at t, the lead's rear along it, the front's last
/// distance to it and its time).
#[derive(Default)]
struct MinTimeHeadway {
    leads: LeadTracker,
    pending: Vec<(f64, [f64; 2], f64, f64, f64)>,
    best: Option<f64>,
}

impl Accumulate for MinTimeHeadway {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        let Some((ego, lead)) = self.leads.observe(record, run) else {
            return;
        };
        let best = &mut self.best;
        self.pending.retain_mut(|(t0, e0, rear, last_gap, last_time)| {
            let gap = ego.front[0] * e0[0] + ego.front[1] * e0[1] - *rear;
            if gap >= 0.0 {
                // Linear between the samples on either side of the crossing.
                let crossed = *last_time + (ego.time - *last_time) * (-*last_gap) / (gap - *last_gap);
                *best = lower(*best, crossed - *t0);
                return false;
            }
            (*last_gap, *last_time) = (gap, ego.time);
            best.is_none_or(|b| ego.time - *t0 < b)
        });
        if let Some(lead) = lead {
            let e = ego.heading;
            let front = ego.front[0] * e[0] + ego.front[1] * e[1];
            self.pending
                .push((ego.time, e, front + lead.headway, -lead.headway, ego.time));
        }
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if self.best.is_none() && self.leads.actors_time.is_some() && run.heading_index.is_some() {
            let reason = match self.leads.saw_lead {
                true => "the vehicle's front never reached where a lead had been",
                false => self.leads.reason(run),
            };
            missing.insert("min_time_headway".into(), reason.into());
        }
        Value::Number(self.best)
    }
}

#[derive(Default)]
struct MaxBrakeThreat {
    leads: LeadTracker,
    best: Option<f64>,
}

impl Accumulate for MaxBrakeThreat {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        let Some((ego, Some(lead))) = self.leads.observe(record, run) else {
            return;
        };
        let relative = lead.velocity - ego.speed;
        // Closing in only (CriMe's formula also charges a lead moving away).
        let required = match relative < 0.0 {
            true => (lead.acceleration - relative * relative / (2.0 * lead.headway)).min(0.0),
            false => 0.0,
        };
        self.best = Some(self.best.map_or(0.0, |b: f64| b.max(0.0)).max(required / -A_LON_MAX));
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if self.best.is_none() && self.leads.actors_time.is_some() && run.heading_index.is_some() {
            missing.insert("max_brake_threat_number".into(), self.leads.reason(run).into());
        }
        Value::Number(self.best)
    }
}

/// `Some(min(current, x))`; a NaN (no value) leaves `current`.
fn lower(current: Option<f64>, x: f64) -> Option<f64> {
    match x.is_nan() {
        true => current,
        false => Some(current.map_or(x, |c| c.min(x))),
    }
}

/// `Some(max(current, x))`.
fn raise(current: Option<f64>, x: f64) -> Option<f64> {
    Some(current.map_or(x, |c| c.max(x)))
}

/// min over a `/barrier` message's barriers of h (NaN ignored; +∞ without any).
fn step_min(m: &proto::Barrier) -> f64 {
    m.barriers.iter().map(|b| b.h).fold(f64::INFINITY, f64::min)
}

#[derive(Default)]
struct SimulatedTime(f64);

impl Accumulate for SimulatedTime {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::State(m) = record {
            self.0 = self.0.max(m.time);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(Some(self.0))
    }
}

#[derive(Default)]
struct Steps(u64);

impl Accumulate for Steps {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::State(m) = record {
            self.0 = self.0.max(m.step);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Count(Some(self.0))
    }
}

#[derive(Default)]
struct FirstCollision {
    first: Option<Collision>,
    /// Obstacles with a `collision_start` and no `collision_end` yet.
    open: BTreeSet<String>,
}

impl Accumulate for FirstCollision {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        let Observed::Event(m) = record else { return };
        let start = m.kind == "collision_start";
        if !start && m.kind != "collision_end" {
            return;
        }
        let with = m
            .participants
            .iter()
            .find(|p| *p != "vehicle")
            .cloned()
            .unwrap_or_default();
        if start {
            self.open.insert(with.clone());
        } else {
            self.open.remove(&with);
        }
        match self.first.as_mut() {
            Some(c) => c.depth = c.depth.max(m.depth),
            None if start => {
                self.first = Some(Collision {
                    time: m.time,
                    with,
                    depth: m.depth,
                })
            }
            None => {}
        }
    }

    fn value(&mut self, _: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        // A contact the log never closes (cut short, or written before episodes closed their
        // contacts at the end): its deepest penetration is not in the log.
        if let (Some(c), Some(open)) = (self.first.as_mut(), self.open.first()) {
            missing.insert(
                "collision.depth".into(),
                format!(
                    "the contact with {open} is still going on where the log ends: only its depth at first contact ({:.4} m) is in the log",
                    c.depth
                ),
            );
            c.depth = f64::NAN;
        }
        Value::Collision(self.first.take())
    }
}

#[derive(Default)]
struct MinH {
    min: Option<f64>,
    /// The first barrier that is not an obstacle, and whether the log has any other barrier:
    /// h of obstacles is in m² (4.81), of another barrier in its own unit.
    not_obstacle: Option<String>,
    names: BTreeSet<String>,
    /// The last message's barriers by place: a name in its place is in `names` already.
    by_position: ByPosition<()>,
}

/// The names of the last message's entries by their place in it, each with what a look-up by
/// name gave: an entry whose name is the one in its place costs one comparison instead of a
/// look-up per entry and message.
#[derive(Default)]
struct ByPosition<T>(Vec<(String, T)>);

impl<T: Copy> ByPosition<T> {
    /// The value for the entry `name` at `position`: the remembered one, or `look_up(name)`.
    fn get(&mut self, position: usize, name: &str, look_up: impl FnOnce(&str) -> T) -> T {
        match self.0.get_mut(position) {
            Some((known, value)) if known == name => *value,
            slot => {
                let value = look_up(name);
                match slot {
                    Some(entry) => *entry = (name.to_string(), value),
                    None => self.0.push((name.to_string(), value)),
                }
                value
            }
        }
    }
}

impl Accumulate for MinH {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            let h = step_min(m);
            if h.is_finite() {
                self.min = lower(self.min, h);
            }
            for (k, b) in m.barriers.iter().enumerate() {
                let names = &mut self.names;
                self.by_position.get(k, &b.name, |name| {
                    if !names.contains(name) {
                        names.insert(name.to_string());
                    }
                });
                if !b.obstacle && self.not_obstacle.is_none() {
                    self.not_obstacle = Some(b.name.clone());
                }
            }
        }
    }
    fn value(&mut self, _: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        // One minimum over barriers only where they share a unit: all obstacles, or one barrier.
        if let (Some(other), true) = (&self.not_obstacle, self.names.len() > 1) {
            missing.insert(
                "min_h".into(),
                format!(
                    "the run's {} barriers are not all obstacles, so their h are not in one unit ({other} is in its own): see min_h_by_barrier and min_clearance",
                    self.names.len()
                ),
            );
            return Value::Number(None);
        }
        Value::Number(self.min)
    }
}

#[derive(Default)]
struct TimeHNegative {
    barriers: bool,
    negative_steps: u64,
}

impl Accumulate for TimeHNegative {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            let h = step_min(m);
            if h.is_finite() {
                self.barriers = true;
                self.negative_steps += u64::from(h < 0.0);
            }
        }
    }
    fn value(&mut self, run: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        // Only for a run with barriers (as min_h): 0 s would claim a safe set was kept.
        let timestep = run.timestep.unwrap_or(0.0);
        Value::Number(self.barriers.then_some(self.negative_steps as f64 * timestep))
    }
}

#[derive(Default)]
struct ActiveFraction {
    ticks: u64,
    active: u64,
}

impl Accumulate for ActiveFraction {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            self.ticks += 1;
            self.active += u64::from(m.active);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(Some(if self.ticks > 0 {
            self.active as f64 / self.ticks as f64
        } else {
            0.0
        }))
    }
}

#[derive(Default)]
struct InfeasibleTicks(u64);

impl Accumulate for InfeasibleTicks {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            self.0 += u64::from(m.infeasible);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Count(Some(self.0))
    }
}

/// `map[channel] = max(map[channel], x)`; the channel's key is allocated at its first value.
fn raise_channel(map: &mut BTreeMap<String, f64>, channel: &str, x: f64) {
    match map.get_mut(channel) {
        Some(entry) => *entry = entry.max(x),
        None => {
            map.insert(channel.to_string(), 0.0f64.max(x));
        }
    }
}

/// [`raise_channel`] with |value| of each (channel, value) pair of a per-channel record.
fn raise_channels_abs(map: &mut BTreeMap<String, f64>, channels: &[String], values: &[f64]) {
    for (channel, value) in channels.iter().zip(values) {
        raise_channel(map, channel, value.abs());
    }
}

#[derive(Default)]
struct MaxCorrection(BTreeMap<String, f64>);

impl Accumulate for MaxCorrection {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            raise_channels_abs(&mut self.0, &m.channels, &m.correction);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(Some(std::mem::take(&mut self.0)))
    }
}

#[derive(Default)]
struct MaxAppliedInput(BTreeMap<String, f64>);

impl Accumulate for MaxAppliedInput {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Applied(m) = record {
            raise_channels_abs(&mut self.0, &m.channels, &m.values);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(Some(std::mem::take(&mut self.0)))
    }
}

/// The largest |u| that reached the vehicle per channel: actuated (a channel `/command/actuated`
/// has), else applied, each against the declared limits.
#[derive(Default)]
struct VehicleLimitRatio {
    applied: BTreeMap<String, f64>,
    actuated: BTreeMap<String, f64>,
}

impl Accumulate for VehicleLimitRatio {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        match record {
            Observed::Applied(m) => raise_channels_abs(&mut self.applied, &m.channels, &m.values),
            Observed::Actuated(m) => raise_channels_abs(&mut self.actuated, &m.channels, &m.values),
            _ => {}
        }
    }
    fn value(&mut self, run: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        if run.vehicle_limits.is_empty() {
            return Value::PerChannel(None);
        }
        let reached = |channel: &str| self.actuated.get(channel).or(self.applied.get(channel)).copied();
        let ratios = run
            .vehicle_limits
            .iter()
            .map(|(channel, limit)| (channel.clone(), reached(channel).unwrap_or(0.0) / limit))
            .collect();
        Value::PerChannel(Some(ratios))
    }
}

#[derive(Default)]
struct Predictions(BTreeMap<String, PredictionStats>);

impl Accumulate for Predictions {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        let Observed::Prediction(m) = record else { return };
        let add = |stats: &mut PredictionStats| {
            stats.count += 1;
            stats.max_error = stats.max_error.max(m.error);
            stats.max_relative_error = stats.max_relative_error.max(m.relative_error);
            stats.sum_squares += m.error * m.error;
            stats.reused_chain += u64::from(m.reused_chain);
            if m.chain_mismatch.is_finite() {
                stats.max_chain_mismatch = stats.max_chain_mismatch.max(m.chain_mismatch);
            }
        };
        // The channel's key is allocated once, at its first prediction.
        match self.0.get_mut(&m.channel) {
            Some(stats) => add(stats),
            None => add(self.0.entry(m.channel.clone()).or_default()),
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        let mut stats = std::mem::take(&mut self.0);
        for s in stats.values_mut() {
            s.rms_error = (s.sum_squares / s.count.max(1) as f64).sqrt();
        }
        Value::Prediction(Some(stats))
    }
}

#[derive(Default)]
struct FirstOverride(Option<f64>);

impl Accumulate for FirstOverride {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            if m.active {
                self.0.get_or_insert(m.time);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(self.0)
    }
}

#[derive(Default)]
struct OverrideDuration(f64);

impl Accumulate for OverrideDuration {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        if let Observed::Filter(m) = record {
            if m.active {
                self.0 += run.control_period.unwrap_or(0.0);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(Some(self.0))
    }
}

/// |du/dt| per channel between consecutive issued commands; with `overriding`, only over the
/// pairs where the filter was active at either tick.
#[derive(Default)]
struct InputRates {
    /// Previous issued command (time, values).
    previous: Option<(f64, Vec<f64>)>,
    /// The rates between the last two commands (reused), and the time of the later one while
    /// they wait for the `/filter` record of its tick (written right after it) to know whether
    /// the filter was overriding.
    rates: Vec<f64>,
    pending: Option<f64>,
    /// The last /filter record (time, active), and whether the one before it was active. A
    /// /filter written before its tick's /command/issued (a log rewritten with the ties of one
    /// log time in another order) settles the rates when the command comes.
    last_filter: Option<(f64, bool)>,
    previous_overriding: bool,
    channels: Vec<String>,
    all: Option<BTreeMap<String, f64>>,
    overriding: Option<BTreeMap<String, f64>>,
}

impl InputRates {
    /// The rates of the tick at `time` count as overriding when the filter of that tick (the
    /// last /filter, if it is that tick's) or of the tick before was active.
    fn settle(&mut self, time: f64) {
        if let Some((filter_time, active)) = self.last_filter {
            if (filter_time - time).abs() < 1e-9 && (active || self.previous_overriding) {
                let map = self.overriding.get_or_insert_with(BTreeMap::new);
                for (channel, rate) in self.channels.iter().zip(&self.rates) {
                    raise_channel(map, channel, *rate);
                }
            }
        }
    }

    fn observe(&mut self, record: Observed<'_>) {
        match record {
            Observed::Filter(m) => {
                self.previous_overriding = self.last_filter.is_some_and(|(_, active)| active);
                self.last_filter = Some((m.time, m.active));
                if let Some(time) = self.pending.take() {
                    self.settle(time);
                }
            }
            Observed::Issued(m) => {
                if self.channels != m.channels {
                    self.channels.clone_from(&m.channels);
                }
                if let Some((previous_time, previous)) = &self.previous {
                    let dt = m.time - previous_time;
                    if dt > 0.0 {
                        self.rates.clear();
                        let rates = m.filtered.iter().zip(previous).map(|(u, p)| ((u - p) / dt).abs());
                        self.rates.extend(rates);
                        let all = self.all.get_or_insert_with(BTreeMap::new);
                        for (channel, rate) in self.channels.iter().zip(&self.rates) {
                            raise_channel(all, channel, *rate);
                        }
                        if self.last_filter.is_some_and(|(time, _)| (time - m.time).abs() < 1e-9) {
                            self.settle(m.time);
                        } else {
                            self.pending = Some(m.time);
                        }
                    }
                }
                match &mut self.previous {
                    Some((time, previous)) => {
                        *time = m.time;
                        previous.clear();
                        previous.extend_from_slice(&m.filtered);
                    }
                    None => self.previous = Some((m.time, m.filtered.clone())),
                }
            }
            _ => {}
        }
    }
}

#[derive(Default)]
struct InputRate(InputRates);

impl Accumulate for InputRate {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        self.0.observe(record);
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(self.0.all.take())
    }
}

#[derive(Default)]
struct InputRateOverriding(InputRates);

impl Accumulate for InputRateOverriding {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        self.0.observe(record);
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(self.0.overriding.take())
    }
}

#[derive(Default)]
struct MinClearance(Option<f64>);

impl Accumulate for MinClearance {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            for b in m.barriers.iter().filter(|b| b.obstacle) {
                self.0 = lower(self.0, b.clearance);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(self.0)
    }
}

/// `map[key] = min(map[key], x)`; the key is allocated at its first value.
/// The least value per name of a `/barrier` entry, found by the entry's position among those a
/// metric reads: every message lists the barriers in one order, so the name there is one
/// comparison (a look-up by name only when it is not: hundreds of road users' barriers at
/// every step; docs/performance.md).
#[derive(Default)]
struct LeastByName {
    slots: Vec<(String, f64)>,
    index: BTreeMap<String, usize>,
}

impl LeastByName {
    /// The entry `key` at `position` of a message's entries has `x`.
    fn observe(&mut self, position: usize, key: &str, x: f64) {
        let slot = match self.slots.get(position) {
            Some((name, _)) if name == key => position,
            _ => match self.index.get(key) {
                Some(&slot) => slot,
                None => {
                    self.index.insert(key.to_string(), self.slots.len());
                    self.slots.push((key.to_string(), x));
                    self.slots.len() - 1
                }
            },
        };
        let least = &mut self.slots[slot].1;
        *least = least.min(x);
    }

    /// The values by name (emptied).
    fn take(&mut self) -> Option<BTreeMap<String, f64>> {
        self.index.clear();
        // A name whose every value was NaN (a road user that never existed in the run) has none.
        let values: BTreeMap<_, _> = std::mem::take(&mut self.slots)
            .into_iter()
            .filter(|(_, least)| !least.is_nan())
            .collect();
        (!values.is_empty()).then_some(values)
    }
}

#[derive(Default)]
struct MinHByBarrier(LeastByName);

impl Accumulate for MinHByBarrier {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            for (k, b) in m.barriers.iter().filter(|b| b.h.is_finite()).enumerate() {
                self.0.observe(k, &b.name, b.h);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(self.0.take())
    }
}

#[derive(Default)]
struct UnmetTicks(u64);

impl Accumulate for UnmetTicks {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            self.0 += u64::from(!m.unmet.is_empty());
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Count(Some(self.0))
    }
}

#[derive(Default)]
struct MaxShortfallByBarrier(BTreeMap<String, f64>);

impl Accumulate for MaxShortfallByBarrier {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Filter(m) = record {
            for (name, shortfall) in m.unmet.iter().zip(&m.shortfall) {
                raise_channel(&mut self.0, name, *shortfall);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel((!self.0.is_empty()).then(|| std::mem::take(&mut self.0)))
    }
}

#[derive(Default)]
struct MinClearanceByObstacle(LeastByName);

impl Accumulate for MinClearanceByObstacle {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            for (k, b) in m.barriers.iter().filter(|b| b.obstacle).enumerate() {
                self.0.observe(k, &b.name, b.clearance);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(self.0.take())
    }
}

#[derive(Default)]
struct MinTimeToCollision(Option<f64>);

impl Accumulate for MinTimeToCollision {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            for b in m
                .barriers
                .iter()
                .filter(|b| b.obstacle && b.known && !b.time_to_collision.is_nan())
            {
                self.0 = lower(self.0, b.time_to_collision);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(self.0)
    }
}

/// The value kept for an entry's obstacle: the entry's name itself, or the obstacle of a pair
/// `<obstacle>/<i>-<j>` (`[log] barrier_pairs`).
fn obstacle_of<'a, T>(name: &str, by_obstacle: &'a BTreeMap<String, T>) -> Option<&'a T> {
    let is_pair = |pair: &str| {
        pair.split_once('-').is_some_and(|(i, j)| {
            [i, j]
                .iter()
                .all(|n| !n.is_empty() && n.bytes().all(|c| c.is_ascii_digit()))
        })
    };
    by_obstacle.get(name).or_else(|| {
        let (obstacle, pair) = name.rsplit_once('/')?;
        is_pair(pair).then(|| by_obstacle.get(obstacle)).flatten()
    })
}

#[derive(Default)]
struct DelayAttributed {
    /// Appearance time per obstacle name.
    appeared: BTreeMap<String, f64>,
    obstacles: bool,
    steps: u64,
}

impl Accumulate for DelayAttributed {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        match record {
            Observed::Event(m) if m.kind == "obstacle_appeared" => {
                for name in &m.participants {
                    self.appeared.entry(name.clone()).or_insert(m.time);
                }
            }
            // A recorded road user known from the start appears when its recording begins.
            Observed::Event(m) if m.kind == "road_user_entered" => {
                for name in &m.participants {
                    self.appeared.insert(name.clone(), m.time);
                }
            }
            Observed::Barrier(m) => {
                self.obstacles |= m.barriers.iter().any(|b| b.obstacle);
                let max_delay = run.max_delay.unwrap_or(0.0);
                let uncompensated = m.barriers.iter().any(|b| {
                    b.h < 0.0
                        && obstacle_of(&b.name, &self.appeared).is_some_and(|t| m.time >= *t && m.time < t + max_delay)
                });
                self.steps += u64::from(uncompensated);
            }
            _ => {}
        }
    }
    fn value(&mut self, run: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        // Only for a run with obstacles (whose appearance it measures from).
        let timestep = run.timestep.unwrap_or(0.0);
        Value::Number(self.obstacles.then_some(self.steps as f64 * timestep))
    }
}

#[derive(Default)]
struct InterventionIntegral(f64);

impl Accumulate for InterventionIntegral {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        if let Observed::Filter(m) = record {
            let correction = m.correction.iter().map(|c| c * c).sum::<f64>().sqrt();
            self.0 += correction * run.control_period.unwrap_or(0.0);
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(Some(self.0))
    }
}

/// [`planar_at_tick`](crate::stall::planar_at_tick) with the run's facts.
fn planar_at_tick(
    planar: &mut Option<Option<[usize; 2]>>,
    m: &proto::State,
    run: &RunFacts,
) -> Option<(f64, f64, f64)> {
    crate::stall::planar_at_tick(planar, m, run.control_period, run.declared_planar)
}

/// [`planar_of`](crate::stall::planar_of) with the run's facts.
fn planar_of(planar: &mut Option<Option<[usize; 2]>>, m: &proto::State, run: &RunFacts) -> Option<(f64, f64, f64)> {
    crate::stall::planar_of(planar, m, run.declared_planar)
}

/// Why a progress metric of a vehicle without a planar position is absent.
const NOT_PLANAR: &str = "the log's /state has no planar position (x, y) to measure it on";

/// How close a run's planar position came to the goal's centre: (distance, time), over the
/// whole run and over the states up to the goal's `by`; and when it first entered the disc.
#[derive(Default)]
struct GoalApproach {
    planar: Option<Option<[usize; 2]>>,
    /// The goal's point lies ahead along a heading the log's state does not have.
    no_heading: bool,
    /// Why the goal's speed or heading interval could not be checked.
    unchecked: Option<&'static str>,
    closest: Option<(f64, f64)>,
    closest_by: Option<(f64, f64)>,
    reached: Option<f64>,
}

impl GoalApproach {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        let (Observed::State(m), Some(goal)) = (record, &run.goal) else {
            return;
        };
        let Some((t, mut x, mut y)) = planar_of(&mut self.planar, m, run) else {
            return;
        };
        // Before the window opens a state does not count.
        if goal.after.is_some_and(|after| t < after - 1e-9) {
            return;
        }
        // The point that must enter a region: `offset` ahead along the heading (no heading:
        // absent).
        let regions = goal.has_region() || goal.states.iter().any(|s| s.has_region());
        if let (true, Some((offset, heading))) = (regions, goal.offset) {
            let Some(theta) = heading.and_then(|h| m.values.get(h)) else {
                self.no_heading = true;
                return;
            };
            (x, y) = (x + offset * theta.cos(), y + offset * theta.sin());
        }
        // Reached when the state meets the goal whole, or one of its goal states whole.
        if self.reached.is_none() {
            let reached = match goal.states.is_empty() {
                true => self.meets(goal, t, [x, y], m),
                false => goal.states.iter().any(|s| self.meets(s, t, [x, y], m)),
            };
            if reached {
                self.reached = Some(t);
            }
        }
        // (A goal of conditions alone has no distance.)
        if !goal.has_region() {
            return;
        }
        let d = goal.distance([x, y]);
        let closer = |c: Option<(f64, f64)>| c.is_none_or(|(closest, _)| d < closest);
        if closer(self.closest) {
            self.closest = Some((d, t));
        }
        if goal.by.is_none_or(|by| t <= by + 1e-9) && closer(self.closest_by) {
            self.closest_by = Some((d, t));
        }
    }

    /// Whether the state at time t, its point at `point`, meets `goal` (or one goal state):
    /// from its `after` on, in its region (if it has one), speed and heading in its intervals.
    fn meets(&mut self, goal: &crate::metrics::Goal, t: f64, point: [f64; 2], m: &proto::State) -> bool {
        goal.after.is_none_or(|after| t >= after - 1e-9)
            && (!goal.has_region() || goal.distance(point) <= 0.0)
            && self.state_within(goal, m)
    }

    /// Whether the state's speed and heading lie in the goal's intervals (no interval: yes; a
    /// state without a `speed` or a heading to check: no, and the metric says why).
    fn state_within(&mut self, goal: &crate::metrics::Goal, m: &proto::State) -> bool {
        if let Some([lo, hi]) = goal.speed {
            let speed = m.names.iter().position(|n| n == "speed").and_then(|i| m.values.get(i));
            match speed {
                Some(v) if (lo - 1e-12..=hi + 1e-12).contains(v) => {}
                Some(_) => return false,
                None => {
                    self.unchecked = Some("the goal's speed interval needs a state named `speed`");
                    return false;
                }
            }
        }
        if let Some((interval, index)) = goal.heading {
            match index.and_then(|i| m.values.get(i)) {
                Some(theta) if crate::metrics::Goal::heading_within(interval, *theta) => {}
                Some(_) => return false,
                None => {
                    self.unchecked = Some("the goal's heading interval needs the log's heading (`heading_index`)");
                    return false;
                }
            }
        }
        true
    }

    /// Whether the run has the metric: a goal and a planar position (absent without one, with
    /// the reason under `name`; `value` is called whether the metric applies or not).
    fn planar(&self, name: &str, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> bool {
        if run.goal.is_none() {
            return false;
        }
        if self.planar == Some(None) {
            missing.insert(name.into(), NOT_PLANAR.into());
            return false;
        }
        if self.no_heading {
            missing.insert(
                name.into(),
                "the goal's point lies `goal_offset` ahead along the heading, and the log declares no heading (`heading_index`)".into(),
            );
            return false;
        }
        true
    }
}

#[derive(Default)]
struct DistanceToGoal(GoalApproach);

impl Accumulate for DistanceToGoal {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if !self.0.planar("distance_to_goal", run, missing) {
            return Value::Number(None);
        }
        if run.goal.as_ref().is_some_and(|g| !g.has_region()) {
            missing.insert(
                "distance_to_goal".into(),
                "the goal has no region (a time window, speed or heading alone): see time_to_goal".into(),
            );
            return Value::Number(None);
        }
        Value::Number(self.0.closest_by.map(|(d, _)| d))
    }
}

#[derive(Default)]
struct TimeToGoal(GoalApproach);

impl Accumulate for TimeToGoal {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if !self.0.planar("time_to_goal", run, missing) {
            return Value::Number(None);
        }
        if let (None, Some(why)) = (self.0.reached, self.0.unchecked) {
            missing.insert("time_to_goal".into(), why.into());
            return Value::Number(None);
        }
        if let (None, Some(goal)) = (self.0.reached, run.goal.as_ref().filter(|g| !g.has_region())) {
            let window = match (goal.after, goal.by) {
                (Some(after), Some(by)) => format!(" in [{after}, {by}] s"),
                (Some(after), None) => format!(" from {after} s on"),
                (None, Some(by)) => format!(" by {by} s"),
                (None, None) => String::new(),
            };
            missing.insert(
                "time_to_goal".into(),
                format!("the vehicle's state never met the goal ({}){window}", goal.describe()),
            );
        }
        if let (None, Some(goal), Some((d, t))) = (self.0.reached, &run.goal, self.0.closest) {
            missing.insert(
                "time_to_goal".into(),
                format!(
                    "the vehicle never reached the goal ({}): closest {d:.3} m from it, at t = {t:.3} s",
                    goal.describe()
                ),
            );
        }
        Value::Number(self.0.reached)
    }
}

#[derive(Default)]
struct ProgressAlongPath {
    planar: Option<Option<[usize; 2]>>,
    /// The planar positions of the earliest and the latest state (time, x, y).
    first: Option<(f64, f64, f64)>,
    last: Option<(f64, f64, f64)>,
}

impl Accumulate for ProgressAlongPath {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        let Observed::State(m) = record else { return };
        let Some(here) = planar_of(&mut self.planar, m, run) else {
            return;
        };
        if self.first.is_none_or(|f| here.0 < f.0) {
            self.first = Some(here);
        }
        if self.last.is_none_or(|l| here.0 >= l.0) {
            self.last = Some(here);
        }
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if run.reference_path.is_none() {
            return Value::Number(None);
        }
        if self.planar == Some(None) {
            missing.insert("progress_along_path".into(), NOT_PLANAR.into());
            return Value::Number(None);
        }
        let progress = match (run.reference_path, self.first, self.last) {
            (Some((_, heading)), Some(first), Some(last)) => {
                let (sin, cos) = heading.sin_cos();
                Some((last.1 - first.1) * cos + (last.2 - first.2) * sin)
            }
            _ => None,
        };
        Value::Number(progress)
    }
}

/// The largest longitudinal and lateral jerk of a planar vehicle, from the third differences
/// of its positions at the control ticks.
#[derive(Default)]
struct PlanarJerk {
    /// The position indices ([`planar_at_tick`]).
    planar: Option<Option<[usize; 2]>>,
    /// Last four planar positions (time, x, y).
    recent: VecDeque<(f64, f64, f64)>,
    longitudinal: Option<f64>,
    lateral: Option<f64>,
}

impl PlanarJerk {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        let Observed::State(m) = record else { return };
        let Some(here) = planar_at_tick(&mut self.planar, m, run) else {
            return;
        };
        self.recent.push_back(here);
        if self.recent.len() > 4 {
            self.recent.pop_front();
        }
        if self.recent.len() < 4 {
            return;
        }
        let q = &self.recent;
        let p = [q[0], q[1], q[2], q[3]];
        let dt = (p[3].0 - p[0].0) / 3.0;
        if dt <= 0.0 {
            return;
        }
        // Third differences → jerk; the velocity direction (central difference) splits it.
        let third = |f: fn(&(f64, f64, f64)) -> f64| f(&p[3]) - 3.0 * f(&p[2]) + 3.0 * f(&p[1]) - f(&p[0]);
        let (jx, jy) = (third(|q| q.1) / dt.powi(3), third(|q| q.2) / dt.powi(3));
        let (vx, vy) = (p[2].1 - p[1].1, p[2].2 - p[1].2);
        let speed = vx.hypot(vy);
        if speed <= 1e-12 {
            return;
        }
        let (ux, uy) = (vx / speed, vy / speed);
        self.longitudinal = raise(self.longitudinal, (jx * ux + jy * uy).abs());
        self.lateral = raise(self.lateral, (-jx * uy + jy * ux).abs());
    }

    /// `value`, or absent (with the reason under `name`) for a planar vehicle whose log lacks
    /// the control period the jerk is sampled at.
    fn value(&self, value: Option<f64>, name: &str, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if self.planar.flatten().is_some() && run.control_period.is_none() {
            missing.insert(name.into(), "no `control_period` in the run metadata".into());
            return Value::Number(None);
        }
        Value::Number(value)
    }
}

#[derive(Default)]
struct Stall(StallDetector);

impl Accumulate for Stall {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, &run.stall_facts());
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Number(self.0.first())
    }
}

#[derive(Default)]
struct LongitudinalJerk(PlanarJerk);

impl Accumulate for LongitudinalJerk {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        self.0.value(self.0.longitudinal, "max_longitudinal_jerk", run, missing)
    }
}

#[derive(Default)]
struct LateralJerk(PlanarJerk);

impl Accumulate for LateralJerk {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        self.0.value(self.0.lateral, "max_lateral_jerk", run, missing)
    }
}

#[derive(Default)]
struct AtPrescribedTime {
    terminal: PrescribedTimeMetrics,
    last_time: f64,
}

impl Accumulate for AtPrescribedTime {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        match record {
            Observed::State(m) => {
                self.last_time = self.last_time.max(m.time);
                if run.is_prescribed_time(m.time) {
                    self.terminal.state_residuals = m.values.iter().map(|v| v.abs()).collect();
                }
            }
            Observed::Barrier(m) => {
                let h = step_min(m);
                if run.is_prescribed_time(m.time) && h.is_finite() {
                    self.terminal.barrier = Some(h);
                }
            }
            Observed::Issued(m) if run.is_prescribed_time(m.time) => {
                self.terminal.input_residual = m.filtered.iter().map(|u| u.abs()).reduce(f64::max);
            }
            _ => {}
        }
    }

    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        let Some(t) = run.prescribed_time else {
            return Value::AtPrescribedTime(None);
        };
        // The values at T come from the messages logged at T: none when the run ended at or
        // before T (the barriers and commands of a step are logged at its start, so the final
        // state has none).
        let end = self.last_time;
        let half_step = 0.5 * run.timestep.unwrap_or(0.0);
        let reason = |topic: &str| {
            if end < t - half_step {
                format!("no {topic} message at T = {t} s: the run ends before T, at t = {end} s")
            } else if end < t + half_step && topic != "/state" {
                format!("no {topic} message at T = {t} s: the run ends at T, and {topic} is logged at the start of each step, not at the final state")
            } else {
                format!("no {topic} message at T = {t} s")
            }
        };
        let terminal = &self.terminal;
        let absent_values = [
            ("at_prescribed_time.barrier", terminal.barrier.is_none(), "/barrier"),
            (
                "at_prescribed_time.state_residuals",
                terminal.state_residuals.is_empty(),
                "/state",
            ),
            (
                "at_prescribed_time.input_residual",
                terminal.input_residual.is_none(),
                "/command/issued",
            ),
        ];
        for (part, absent, topic) in absent_values {
            if absent && !missing.contains_key(part) {
                missing.insert(part.to_string(), reason(topic));
            }
        }
        let given = |part: &str| !missing.contains_key(part);
        Value::AtPrescribedTime(Some(PrescribedTimeMetrics {
            time: t,
            barrier: terminal.barrier.filter(|_| given("at_prescribed_time.barrier")),
            state_residuals: if given("at_prescribed_time.state_residuals") {
                terminal.state_residuals.clone()
            } else {
                Vec::new()
            },
            input_residual: terminal
                .input_residual
                .filter(|_| given("at_prescribed_time.input_residual")),
        }))
    }
}

#[derive(Default)]
struct MinTtcByBarrier(LeastByName);

impl Accumulate for MinTtcByBarrier {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        if let Observed::Barrier(m) = record {
            let known = (m.barriers.iter()).filter(|b| b.obstacle && b.known && !b.time_to_collision.is_nan());
            for (k, b) in known.enumerate() {
                self.0.observe(k, &b.name, b.time_to_collision);
            }
        }
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::PerChannel(self.0.take())
    }
}

#[derive(Default)]
struct MaxActorPredictionError {
    max: Option<f64>,
    /// Whether the log has moving obstacles (an `/actors` message).
    actors: bool,
}

impl Accumulate for MaxActorPredictionError {
    fn observe(&mut self, record: Observed<'_>, _: &RunFacts) {
        match record {
            Observed::Prediction(m) => {
                for e in m.actor_error.iter().filter(|e| !e.is_nan()) {
                    self.max = raise(self.max, *e);
                }
            }
            Observed::Actors(_) => self.actors = true,
            _ => {}
        }
    }
    fn value(&mut self, _: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        if self.max.is_none() && self.actors {
            missing.insert(
                "max_actor_prediction_error".into(),
                "no actor predictions in the log (the controller does not predict, or no prediction reached its target time while a moving obstacle was known)".into(),
            );
        }
        Value::Number(self.max)
    }
}

/// The vehicle's planar velocity at each `/state` message but the first: the backward
/// difference from the previous one (the mean over the step that ends there). What happens at
/// that state, such as a contact's push, is not in it.
#[derive(Default)]
struct StepVelocity {
    planar: Option<Option<[usize; 2]>>,
    last: Option<(f64, f64, f64)>,
}

impl StepVelocity {
    /// Reads a `/state` message at time t; returns (t, vx, vy) over the step that ends at t.
    fn observe(&mut self, m: &proto::State, run: &RunFacts) -> Option<(f64, f64, f64)> {
        let here = planar_of(&mut self.planar, m, run)?;
        let (t, x, y) = self.last.replace(here)?;
        let dt = here.0 - t;
        (dt > 0.0).then(|| (here.0, (here.1 - x) / dt, (here.2 - y) / dt))
    }
}

/// Whether two log times are the same step's.
fn same_time(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(1.0)
}

/// The first collision and the vehicle's speed up to it, for speed_reduction and
/// vehicle_stopped.
#[derive(Default)]
struct SpeedBeforeCollision {
    velocity: StepVelocity,
    initial: Option<f64>,
    collision: Option<f64>,
    /// The speed over the step that ends at the latest `/state` message, and that message's time.
    latest: Option<(f64, f64)>,
    at_collision: Option<f64>,
    /// The least speed up to the first collision (the whole run without one).
    min: Option<f64>,
}

impl SpeedBeforeCollision {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        match record {
            Observed::Event(m) if m.kind == "collision_start" && self.collision.is_none() => {
                self.collision = Some(m.time);
                // (The collision's own `/state` may come before its event.)
                if let Some((_, v)) = self.latest.filter(|(t, _)| same_time(*t, m.time)) {
                    self.at_collision = Some(v);
                }
            }
            Observed::State(m) => {
                let Some((t, vx, vy)) = self.velocity.observe(m, run) else {
                    return;
                };
                let v = vx.hypot(vy);
                self.initial.get_or_insert(v);
                match self.collision {
                    Some(c) if same_time(t, c) => self.at_collision = Some(v),
                    Some(c) if t > c => return,
                    _ => {}
                }
                self.latest = Some((t, v));
                self.min = lower(self.min, v);
            }
            _ => {}
        }
    }
}

#[derive(Default)]
struct SpeedReduction(SpeedBeforeCollision);

impl Accumulate for SpeedReduction {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        let s = &self.0;
        let end = if s.collision.is_some() { s.at_collision } else { s.min };
        Value::Number(s.initial.zip(end).map(|(v0, v)| v0 - v))
    }
}

#[derive(Default)]
struct VehicleStopped(SpeedBeforeCollision);

impl Accumulate for VehicleStopped {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }
    fn value(&mut self, _: &RunFacts, _: &mut BTreeMap<String, String>) -> Value {
        Value::Count(self.0.min.map(|v| u64::from(v < STALL_SPEED)))
    }
}

/// A first collision with an obstacle, waiting for the velocities over the step that ends at
/// it.
struct Impact {
    actor: String,
    time: f64,
    actor_velocity: Option<(f64, f64)>,
    vehicle_velocity: Option<(f64, f64)>,
    /// The obstacle did not exist at the step before the collision (a recorded road user at its
    /// first recorded state): no backward difference.
    appeared: bool,
}

/// A moving obstacle's last two logged positions (t, x, y, absent).
type Track = [Option<(f64, f64, f64, bool)>; 2];

#[derive(Default)]
struct ImpactSpeedByActor {
    velocity: StepVelocity,
    /// The vehicle's velocity over the step that ends at the latest `/state` message (t, vx, vy).
    vehicle: Option<(f64, f64, f64)>,
    /// Each moving obstacle's track.
    tracks: BTreeMap<String, Track>,
    impacts: Vec<Impact>,
}

impl ImpactSpeedByActor {
    /// Impact i's obstacle velocity over the step that ends at its collision, once its track
    /// reaches the collision's time.
    fn actor_velocity(i: &mut Impact, track: &Track) {
        let [Some((t0, x0, y0, absent)), Some((t1, x1, y1, _))] = *track else {
            return;
        };
        if i.actor_velocity.is_some() || i.appeared || !same_time(t1, i.time) {
            return;
        }
        match absent || t1 <= t0 {
            true => i.appeared = true,
            false => i.actor_velocity = Some(((x1 - x0) / (t1 - t0), (y1 - y0) / (t1 - t0))),
        }
    }
}

impl Accumulate for ImpactSpeedByActor {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        match record {
            Observed::Actors(m) => {
                for a in &m.actors {
                    let track = self.tracks.entry(a.name.clone()).or_default();
                    *track = [track[1], Some((m.time, a.x, a.y, a.absent))];
                    for i in self.impacts.iter_mut().filter(|i| i.actor == a.name) {
                        Self::actor_velocity(i, track);
                    }
                }
            }
            Observed::Event(m) if m.kind == "collision_start" => {
                for p in m.participants.iter().filter(|p| *p != "vehicle") {
                    if self.impacts.iter().any(|i| &i.actor == p) {
                        continue;
                    }
                    let vehicle = self.vehicle.filter(|(t, ..)| same_time(*t, m.time));
                    let mut impact = Impact {
                        actor: p.clone(),
                        time: m.time,
                        // A standing obstacle (never in `/actors`): its velocity is 0.
                        actor_velocity: (!self.tracks.contains_key(p)).then_some((0.0, 0.0)),
                        vehicle_velocity: vehicle.map(|(_, vx, vy)| (vx, vy)),
                        appeared: false,
                    };
                    if let Some(track) = self.tracks.get(p) {
                        Self::actor_velocity(&mut impact, track);
                    }
                    self.impacts.push(impact);
                }
            }
            Observed::State(m) => {
                if let Some((t, vx, vy)) = self.velocity.observe(m, run) {
                    self.vehicle = Some((t, vx, vy));
                    for i in self.impacts.iter_mut().filter(|i| same_time(i.time, t)) {
                        i.vehicle_velocity.get_or_insert((vx, vy));
                    }
                }
            }
            _ => {}
        }
    }
    fn value(&mut self, _: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        let speeds: BTreeMap<String, f64> = (self.impacts.iter())
            .filter_map(|i| {
                let ((vx, vy), (ox, oy)) = i.vehicle_velocity.zip(i.actor_velocity)?;
                Some((i.actor.clone(), (vx - ox).hypot(vy - oy)))
            })
            .collect();
        for i in self.impacts.iter().filter(|i| !speeds.contains_key(&i.actor)) {
            let why = match i.appeared {
                true => "it did not exist at the step before its collision (its first recorded state): no backward difference",
                false => "the collision is at the log's first step: no step before it to difference over",
            };
            missing.insert(format!("impact_speed_by_actor.{}", i.actor), why.into());
        }
        if self.impacts.is_empty() && !self.tracks.is_empty() {
            missing.insert("impact_speed_by_actor".into(), "no collision".into());
        }
        Value::PerChannel((!speeds.is_empty()).then_some(speeds))
    }
}
