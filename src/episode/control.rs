//! The controller side of the loop, called by the plant at every input evaluation (inside
//! MuJoCo's control callback for the MuJoCo plant).
//!
//! One control tick (call 0 of every `steps_per_tick`-th step, at the real state x(t)):
//! predictions p_i(t) → per channel i: nominal u0 and the safety filter at the channel's
//! evaluation state (x(t) uncompensated (2.16), p_i(t) compensated (2.26)/(4.34)) → issued
//! u_i → delay queue i. Every call: sample the queues at the call's time → applied input.

use std::collections::VecDeque;
use std::sync::Arc;

use nalgebra::DVector;

use super::reach::{Reach, ReachAt, SleepAt};
use crate::actor::reach::pair_rows;
use crate::actor::{
    add_headway_motion_terms, add_point_motion_terms, ActorKnowledge, ActorMotion, ActorState, AssumedWindow,
};
use crate::actuator::Actuator;
use crate::barrier::{Barrier, BarrierForm, Constraint, LieWorkspace};
use crate::delay::{DelayError, DelayQueue};
use crate::dynamics::Dynamics;
use crate::filter::{ChannelInput, ChannelOutcome, FilterError, LawInput, SafetyFilter, SeenBarriers, TICK_TOLERANCE};
use crate::nominal::{NominalController, SeenActor};
use crate::plant::Controller;
use crate::predictor::{self, Prediction, PredictorContext, PredictorWorkspace, Structure};
use crate::sensing::Sensor;

/// What one control tick computed (logged after the step).
#[derive(Debug, Clone)]
pub struct Tick {
    pub time: f64,
    /// u0 per channel (component i of the nominal at channel i's evaluation state).
    pub nominal: DVector<f64>,
    /// Issued command per channel.
    pub issued: DVector<f64>,
    /// The filter's decision per channel (None when no barrier is known or no filter is set).
    pub outcomes: Vec<Option<ChannelOutcome>>,
    /// With a sensor, the state the controller read (its late, biased, noisy measurement);
    /// without one it is not kept (the controller read the true state).
    pub measured: DVector<f64>,
    /// Barrier rows the tick's decisions left out of their QPs (docs/actors.md, "Out of
    /// reach"): each holds for every input the decision may use, so the outcomes' μ are over
    /// the others.
    pub left_out: u64,
}

impl Tick {
    /// Nothing computed yet.
    fn new(parts: &mut LoopParts) -> Tick {
        let (n, r) = parts.sizes;
        Tick {
            time: 0.0,
            nominal: DVector::zeros(r),
            issued: DVector::zeros(r),
            outcomes: vec![None; r],
            measured: DVector::zeros(n),
            left_out: 0,
        }
    }
}

/// A prediction compared with the realised state (Definition 4.3).
#[derive(Debug, Clone)]
pub struct Consistency {
    pub prediction: Prediction,
    pub realized: DVector<f64>,
    /// Per moving actor known when the prediction was made (in the order of
    /// [`ControlLoop::moving_actors`]), the position the controller assumed at the target time
    /// (x, y pairs); empty without moving actors.
    pub actors_predicted: Vec<f64>,
}

/// A prediction waiting for its target time, with where the predictor's final partial step
/// to it started (time, predicted state), when it took one, and the actors' assumed positions.
#[derive(Debug, Clone)]
struct Pending {
    prediction: Prediction,
    partial_step: Option<(f64, DVector<f64>)>,
    actors: Vec<f64>,
}

/// (time, state, the time the state is for) of a nominal input.
type NominalPoint<'a> = (f64, &'a [f64], f64);

/// Scratch space of the delay-free law and the per-channel filters.
struct LawWorkspace {
    lie: LieWorkspace,
    /// One per known barrier.
    constraints: Vec<Constraint>,
    /// u0.
    nominal: DVector<f64>,
    /// The filtered input u.
    input: DVector<f64>,
    /// Per known barrier, for a moving actor's: the barrier with its centre moved to where
    /// the controller assumes the actor at the evaluation time.
    moving: Vec<Option<Barrier>>,
    /// ẋ at zero input (the drift of the point a moving actor's barrier measures from, for
    /// the relative-degree-2 motion terms), the columns G_j of G one after another (both at the
    /// evaluation state, computed once per [`LawWorkspace::constraints_into`] for all the
    /// moving actors' barriers), and per channel ∂q/∂x G_j.
    drift: Vec<f64>,
    zero_input: Vec<f64>,
    unit_input: Vec<f64>,
    columns: Vec<f64>,
    point_input: Vec<[f64; 2]>,
    /// Per row of the last [`LawWorkspace::constraints_into`], the barrier it belongs to (rows
    /// of road users out of reach are left out: [`Reach`]).
    row_barrier: Vec<usize>,
    /// Whether the barriers' rows are out of their order 0..count (an evaluation left rows out).
    rows_moved: bool,
    /// Which road users are out of reach at an evaluation state.
    reach: Reach,
    /// The reach tests of the laws the recursive predictor evaluated at this tick (`recording`
    /// while it predicts), of the laws its present chain holds, and spares ([`Reach::record`]).
    reach_now: Vec<ReachAt>,
    reach_chain: Vec<ReachAt>,
    reach_spare: Vec<ReachAt>,
    recording: bool,
    /// Per channel, the largest |input| the filter's QPs planned, and whether it says.
    planned: Vec<f64>,
    says_planned: bool,
    /// Whether the law of the current [`LawWorkspace::issued_law`] corrected u0.
    law_corrected: bool,
    /// The moving actors as a nominal that reads them sees them (capacity: one per actor).
    seen: Vec<SeenActor>,
}

impl LawWorkspace {
    /// constraints ← the constraint data of every known barrier at z in the filter's form.
    /// Returns the number of constraints (0 for a filter without a barrier form).
    #[inline(always)]
    fn constraints_at(&mut self, laws: &Laws<'_>, z: &[f64], at: f64) -> usize {
        let Some(form) = laws.form else {
            return 0;
        };
        self.constraints_into(laws, form, z, at)
    }

    /// nominal ← u0 at (`time`, `nominal_state`), and [`LawWorkspace::constraints_at`] out of
    /// line: for the per-channel loop of a tick (the κ closure, called at every predictor
    /// step, keeps them inline).
    #[inline(always)]
    fn channel_laws(
        &mut self,
        laws: &Laws<'_>,
        time: f64,
        nominal_state: (&[f64], f64),
        (z, at): (&[f64], f64),
    ) -> Result<usize, FilterError> {
        self.nominal_into(laws, time, nominal_state)?;
        Ok(laws
            .form
            .map_or(0, |form| self.constraints_out_of_line(laws, form, z, at)))
    }

    /// u[j] ← κ_j for the channels in `free` at the predicted z = x(s) ([`SafetyFilter::issued_law`]),
    /// per group of one delay D from the longest (each group's ω holds the later groups'
    /// commands), with u0 at the tick s − D that issues it (or at s for a nominal on
    /// predictions).
    /// Made again with every row when an input it used exceeds the bound the rows it left out
    /// were checked for ([`Reach`]).
    #[inline(always)]
    fn issued_law(
        &mut self,
        laws: &Laws<'_>,
        filter: &mut dyn SafetyFilter,
        queues: &[DelayQueue],
        nominal_predicts: bool,
        point: (f64, &[f64], &[usize]),
        u: &mut [f64],
    ) -> Result<(), FilterError> {
        if !self.reach.active() {
            self.issued_law_once(laws, filter, queues, nominal_predicts, point, u)?;
            self.record_reach(laws.form, point.0);
            return Ok(());
        }
        self.reach.begin_decision(u);
        let mut attempt = 0;
        loop {
            filter.take_planned_inputs(&mut self.planned);
            self.law_corrected = false;
            self.issued_law_once(laws, filter, queues, nominal_predicts, point, u)?;
            self.note_planned(filter);
            // (A corrected u0 of a filter that does not say what it planned: made again with
            // every row, as in channel_decision.)
            let unknown = self.law_corrected && !self.says_planned;
            let commands = point.2.iter().map(|&j| (j, if unknown { f64::NAN } else { u[j] }));
            self.reach.note(commands);
            if !self.reach.again(attempt) {
                break;
            }
            self.reach.restore(u);
            attempt += 1;
        }
        self.reach.enabled = true;
        self.record_reach(laws.form, point.0);
        Ok(())
    }

    /// While the recursive predictor evaluates laws: what this law's reach test saw at `time`.
    fn record_reach(&mut self, form: Option<BarrierForm>, time: f64) {
        if !self.recording {
            return;
        }
        let mut node = self.reach_spare.pop().unwrap_or_default();
        self.reach.record(time, form, &mut node);
        self.reach_now.push(node);
    }

    /// The chain's laws after a tick: this tick's alone when the chain was formed again, else
    /// the ones still in its window (from `from` on) and this tick's.
    fn keep_chain_reach(&mut self, restarted: bool, from: f64) {
        if restarted {
            self.reach_spare.append(&mut self.reach_chain);
        } else {
            let gone = self.reach_chain.iter().take_while(|node| node.time < from).count();
            self.reach_spare.extend(self.reach_chain.drain(..gone));
        }
        self.reach_chain.append(&mut self.reach_now);
        // The next restart takes a whole chain's records before this one's come back: as many
        // spares, with their room (allocated once, when the chain first grows).
        while let (true, Some(node)) = (
            self.reach_spare.len() < self.reach_chain.len(),
            self.reach_chain.first(),
        ) {
            let copy = node.clone();
            self.reach_spare.push(copy);
        }
    }

    #[inline(always)]
    fn issued_law_once(
        &mut self,
        laws: &Laws<'_>,
        filter: &mut dyn SafetyFilter,
        queues: &[DelayQueue],
        nominal_predicts: bool,
        (s, z, free): (f64, &[f64], &[usize]),
        u: &mut [f64],
    ) -> Result<(), FilterError> {
        let count = self.constraints_at(laws, z, s);
        let delay = |j: usize| queues[j].constant_delay().unwrap_or(0.0);
        let mut end = free.len();
        while end > 0 {
            let d = delay(free[end - 1]);
            let start = free[..end].partition_point(|&j| delay(j) < d);
            let group = &free[start..end];
            let nominal_time = if nominal_predicts { s } else { s - d };
            self.nominal_into(laws, nominal_time, (z, s))?;
            self.reach.note(self.nominal.iter().copied().enumerate());
            self.input.as_mut_slice().copy_from_slice(u);
            let assumed = |k: usize| laws.actors.assumed_circle(k, s);
            let input = LawInput {
                time: s - d,
                prediction_time: s,
                state: z,
                nominal: &self.nominal,
                constraints: &self.constraints[..count],
                free: group,
                barriers: SeenBarriers::new(laws.barriers, &self.row_barrier[..count], &assumed),
            };
            filter.issued_law(&input, &mut self.input)?;
            for &j in group {
                self.law_corrected |= self.input[j] != self.nominal[j];
                u[j] = self.input[j];
            }
            end = start;
        }
        Ok(())
    }

    /// nominal ← u0 at (`time`, x), x the state at time `at`; for a nominal that reads actors,
    /// with every known moving actor where the controller assumes it at `at` (where it is when
    /// the vehicle is at x) and the gap its (first) barrier measures at x ([`SeenActor`]).
    #[inline(always)]
    fn nominal_into(&mut self, laws: &Laws<'_>, time: f64, (x, at): (&[f64], f64)) -> Result<(), FilterError> {
        if !laws.nominal.reads_actors() {
            return laws
                .nominal
                .try_input_into(time, x, &[], self.nominal.as_mut_slice())
                .map_err(FilterError::Other);
        }
        self.seen.clear();
        for (k, motion) in laws.actors.motions.iter().enumerate() {
            let (Some(motion), true, Some(moved)) = (motion, laws.actors.primary[k], self.moving[k].as_mut()) else {
                continue;
            };
            let state = laws.actors.assumed(motion, k, at);
            moved.move_actor(state.shifted(laws.actors.offsets[k]).position);
            self.seen.push(SeenActor {
                state,
                gap: moved.clearance_at(x),
                lead: matches!(moved.shape, crate::barrier::Shape::Headway { .. }),
            });
        }
        laws.nominal
            .try_input_into(time, x, &self.seen, self.nominal.as_mut_slice())
            .map_err(FilterError::Other)
    }

    /// Channel i's decision at tick t (rows and u0 at its evaluation point unless `shared` with
    /// the previous channel's, which left `count` rows), made again with every row when an
    /// input it used exceeds the bound the rows it left out were checked for ([`Reach`]).
    fn channel_decision(
        &mut self,
        laws: &Laws<'_>,
        filter: &mut dyn SafetyFilter,
        (t, i, queues, timestep): (f64, usize, &[DelayQueue], f64),
        (nominal_point, point): (NominalPoint<'_>, (&[f64], f64)),
        (shared, count): (bool, &mut usize),
    ) -> Result<Option<ChannelOutcome>, FilterError> {
        let (nominal_time, nominal_state, state_time) = nominal_point;
        let active = self.reach.active();
        if active {
            self.reach.begin_decision(&[]);
            filter.take_planned_inputs(&mut self.planned);
            // ω (4.45): the later channels' commands come from the queues.
            for (j, queue) in queues.iter().enumerate() {
                self.reach.note(queue.issued().map(|(_, value)| (j, value)));
            }
        }
        let assumed = |k: usize| laws.actors.assumed_circle(k, point.1);
        let mut decide = |law: &mut LawWorkspace, filter: &mut dyn SafetyFilter, again: bool| {
            if !shared || again {
                *count = law.channel_laws(laws, nominal_time, (nominal_state, state_time), point)?;
            }
            filter.filter_channel(&ChannelInput {
                time: t,
                channel: i,
                state: point.0,
                nominal: &law.nominal,
                constraints: &law.constraints[..*count],
                queues,
                timestep,
                barriers: SeenBarriers::new(laws.barriers, &law.row_barrier[..*count], &assumed),
            })
        };
        if !active {
            return decide(self, filter, false);
        }
        let mut attempt = 0;
        loop {
            let outcome = decide(self, filter, attempt > 0)?;
            self.reach.note(self.nominal.iter().copied().enumerate());
            self.note_planned(filter);
            // A decision that corrects u0 plans inputs (the QP's other channels, γm's
            // fictitious σ (4.60), and the real inputs its shortfall is of) that are checked
            // when the filter says what they are; else, and for an infeasible QP's fallback, it
            // is made again with every row. One that keeps u0 is the full QP's (every left-out
            // row holds there), and so is the row a shortfall names (a left-out row holds at
            // every admissible input, the planned real ones among them).
            let corrected = outcome.is_some_and(|o| (o.active && !self.says_planned) || o.infeasible);
            let command = outcome.map_or(self.nominal[i], |o| if corrected { f64::NAN } else { o.input });
            self.reach.note(std::iter::once((i, command)));
            if !self.reach.again(attempt) {
                self.reach.enabled = true;
                return Ok(outcome);
            }
            attempt += 1;
        }
    }

    /// Notes the inputs the filter's QPs planned since `take_planned_inputs` was last called,
    /// when it says ([`SafetyFilter::take_planned_inputs`]).
    fn note_planned(&mut self, filter: &mut dyn SafetyFilter) {
        self.says_planned = filter.take_planned_inputs(&mut self.planned);
        if self.says_planned {
            self.reach.note(self.planned.iter().copied().enumerate());
        }
    }

    #[inline(never)]
    fn constraints_out_of_line(&mut self, laws: &Laws<'_>, form: BarrierForm, z: &[f64], at: f64) -> usize {
        self.constraints_into(laws, form, z, at)
    }

    /// constraints ← the constraint data of every known barrier at z, the state at time `at`,
    /// in `form`; returns their number. A moving actor's barrier is evaluated with the actor
    /// where the controller assumes it at `at` (from what it observed at the tick), with the
    /// terms of its motion ([`add_point_motion_terms`]).
    #[inline(always)]
    fn constraints_into(&mut self, laws: &Laws<'_>, form: BarrierForm, z: &[f64], at: f64) -> usize {
        let count = laws.barriers.len();
        // Rows 0..count: one per barrier; then the first-order rows of the mixed-relative-
        // degree barriers, in barrier order; then those of road users out of reach are left
        // out ([`LawWorkspace::compact_rows`]).
        let r = self.nominal.len();
        let actors = laws.actors;
        let window = |first, end, from, to| actors.assumed_window(first, end, from, to);
        let sleep = SleepAt {
            now: actors.now,
            at,
            span: actors.sleep_span,
            window: &window,
        };
        let mut culled = self
            .reach
            .mark(laws.model, form, z, r, |k| actors.assumed_centre(k, at), Some(sleep));
        let (rows, first_order_rows) = self.constraints.split_at_mut(count);
        let mut first_order = 0;
        // ẋ(z, 0) and G(z)'s columns, the same for every moving actor's barrier at z; the ego
        // points road users' circles measure from.
        let mut kinematics = false;
        let points = self.reach.measure_points(laws.model, z);
        let rates = form.real_rates().is_some();
        // (A run of barriers out of reach, a road user's, is passed over at once.)
        let mut next = 0;
        while next < count {
            let k = next;
            next += 1;
            let (b, c) = (&laws.barriers[k], &mut rows[k]);
            if culled && self.reach.out[k] {
                next = next.max(self.reach.leave_out_run(k, count, rates));
                continue;
            }
            let mixed = rates && b.mixed_relative_degree();
            match (&laws.actors.motions[k], &mut self.moving[k]) {
                (Some(motion), Some(moved)) => {
                    // The barrier's circle: the actor's centre plus its offset (a box's).
                    let actor = laws.actors.assumed(motion, k, at).shifted(laws.actors.offsets[k]);
                    // A road user's circle against an ego point: the pair's rows in closed form
                    // from the point's kinematics, measured once per state (`pair_rows`).
                    if let Some((point, radius)) = self.reach.point(k).filter(|_| points) {
                        let mixed_rate = form.real_rates().filter(|_| mixed).map(|(lambda1, _)| lambda1);
                        let first = first_order_rows.get_mut(first_order).filter(|_| mixed);
                        let has_first = first.is_some();
                        pair_rows(form, mixed_rate, &point.kinematics(r), &actor, radius, c, first);
                        let first = first_order_rows.get(first_order).filter(|_| has_first);
                        // Rows that hold for every admissible input enter no QP either.
                        if self.reach.holds_for_every_admissible_input(c, first) {
                            self.reach.leave_out(k, 1 + u64::from(has_first));
                            culled = true;
                            continue;
                        }
                        if has_first {
                            self.row_barrier[count + first_order] = k;
                            first_order += 1;
                        }
                        continue;
                    }
                    moved.move_actor(actor.position);
                    self.lie.constraint_into(moved, form, laws.model, z, c);
                    if let crate::barrier::Shape::Headway { .. } = moved.shape {
                        add_headway_motion_terms(c, form, &actor);
                        continue;
                    }
                    let body = matches!(moved.shape, crate::barrier::Shape::BodyCircle { .. });
                    let rd2 = matches!(form, BarrierForm::RelativeDegree2 { .. });
                    if rd2 && !kinematics {
                        laws.model.dynamics_into(z, &self.zero_input, &mut self.drift);
                        let n = self.drift.len();
                        for (j, column) in self.columns.chunks_exact_mut(n).enumerate() {
                            self.unit_input.fill(0.0);
                            self.unit_input[j] = 1.0;
                            column.fill(0.0);
                            laws.model.add_input_term(z, &self.unit_input, column);
                        }
                        kinematics = true;
                    }
                    // (At relative degree 1 the drift is stale and unused.)
                    let (q, q_drift) = moved.point_and_velocity(z, &self.drift).expect("a planar circle");
                    let q_drift = if rd2 { q_drift } else { [0.0; 2] };
                    // ∂q/∂x G_j: an input turns a body circle's point (docs/actors.md, "Footprints").
                    let inputs = match rd2 && body {
                        true => {
                            let n = self.drift.len();
                            for (j, column) in self.columns.chunks_exact(n).enumerate().take(self.point_input.len()) {
                                self.point_input[j] = moved.point_and_velocity(z, column).expect("a planar circle").1;
                            }
                            &self.point_input[..]
                        }
                        false => &[],
                    };
                    add_point_motion_terms(c, form, (q, q_drift, inputs), &actor);
                    // ḣ + λ1 h with ḣ's ∂h/∂t = −2 (q − o)·ȯ (the relative-degree-1 motion term).
                    if let (true, Some(row)) = (mixed, first_order_rows.get_mut(first_order)) {
                        self.lie.first_order_part_into(form, row);
                        let first = BarrierForm::RelativeDegree1 { alpha: 0.0 };
                        add_point_motion_terms(row, first, (q, q_drift, &[]), &actor);
                        self.row_barrier[count + first_order] = k;
                        first_order += 1;
                    }
                }
                _ => {
                    self.lie.constraint_into(b, form, laws.model, z, c);
                    if let (true, Some(row)) = (mixed, first_order_rows.get_mut(first_order)) {
                        self.lie.first_order_part_into(form, row);
                        self.row_barrier[count + first_order] = k;
                        first_order += 1;
                    }
                }
            }
        }
        self.compact_rows(count, first_order, culled)
    }

    /// Moves the rows of the barriers in reach to the front (each barrier's row, then the
    /// first-order rows), with row_barrier the barrier of each; returns their number.
    fn compact_rows(&mut self, count: usize, first_order: usize, culled: bool) -> usize {
        if !culled {
            // (Barrier k's row is row k again once an evaluation left rows out.)
            if std::mem::take(&mut self.rows_moved) {
                for (k, slot) in self.row_barrier[..count].iter_mut().enumerate() {
                    *slot = k;
                }
            }
            self.reach.count_rows((count + first_order) as u64, 0);
            return count + first_order;
        }
        self.rows_moved = true;
        let mut kept = 0;
        for k in 0..count {
            if !self.reach.out[k] {
                self.constraints.swap(kept, k);
                self.row_barrier[kept] = k;
                kept += 1;
            }
        }
        for row in count..count + first_order {
            self.constraints.swap(kept, row);
            self.row_barrier[kept] = self.row_barrier[row];
            kept += 1;
        }
        self.reach.count_rows(kept as u64, 0);
        kept
    }

    /// The barrier a constraint row belongs to: row k < the barriers' count is barrier k's
    /// condition, the later rows the first-order rows of the mixed-relative-degree barriers.
    fn barrier_of_row(&self, row: usize) -> usize {
        self.row_barrier.get(row).copied().unwrap_or(row)
    }
}

/// The moving actors the controller knows, per known barrier, and what it assumes of them.
struct KnownActors {
    /// Per known barrier: the actor's true motion (its truth is what the controller observes
    /// at a tick, and the oracle's future), or None for a barrier that does not move.
    motions: Vec<Option<ActorMotion>>,
    /// Per known barrier: its circle's centre relative to the actor's (a box's covering
    /// circles), and whether it is the actor's first barrier (the one that stands for it).
    offsets: Vec<[f64; 2]>,
    primary: Vec<bool>,
    /// Per known barrier k: the last primary barrier up to k (k itself when there is none),
    /// [`KnownActors::slot`].
    slots: Vec<usize>,
    /// Per known barrier that is an actor's primary: the largest distance of the actor's
    /// circles from its centre (0 for the others).
    spread: Vec<f64>,
    knowledge: ActorKnowledge,
    /// The time of the last observation and, per known barrier, the actor state observed then
    /// (the first `observed_known` barriers were known then).
    now: f64,
    observed: Vec<ActorState>,
    observed_known: usize,
    /// Observations every this many ticks (`actor_knowledge.period`), and ticks since the last.
    observe_every: u64,
    ticks_since_observation: u64,
    /// The look-ahead at − now of every evaluation until the next observation: its period, the
    /// largest delay and a tick (an epoch of sleeping road users covers it; [`SleepAt`]).
    sleep_span: f64,
    /// The observation the recursive chain's laws were first formed with (its tick time, NaN
    /// for none): [`KnownActors::assumption_change`] compares what it assumes with now.
    anchor_time: f64,
    anchor: Vec<ActorState>,
}

impl KnownActors {
    /// Where the controller assumes actor k at time `at`, from its state observed at the tick.
    #[inline]
    fn assumed(&self, motion: &ActorMotion, k: usize, at: f64) -> ActorState {
        let at = at.max(self.now);
        self.knowledge
            .predict(&self.observed[k], self.now, at, |t| motion.where_at(t, self.slot(k)))
    }

    /// Where known barrier k's road user is parked while it does not exist
    /// ([`ActorMotion::where_at`]): its primary barrier's place, so that all its barriers see one
    /// state and a reach test takes it whole.
    #[inline]
    fn slot(&self, k: usize) -> usize {
        self.slots[k]
    }

    /// slots ← for the last known barrier, the last primary barrier up to it.
    fn place_last(&mut self) {
        let k = self.primary.len() - 1;
        let slot = (0..=k).rev().find(|&j| self.primary[j]).unwrap_or(k);
        self.slots.resize(k + 1, k);
        self.slots[k] = slot;
    }

    /// For known barrier k of a moving actor, the state of its circle's centre where the
    /// controller assumes it at `at` (what its constraint rows are computed with).
    fn assumed_circle(&self, k: usize, at: f64) -> Option<ActorState> {
        let motion = self.motions.get(k)?.as_ref()?;
        Some(self.assumed(motion, k, at).shifted(self.offsets[k]))
    }

    /// Keeps the present observation as the one the recursive chain's laws are formed with.
    fn anchor_here(&mut self) {
        self.anchor_time = self.now;
        self.anchor.clone_from(&self.observed);
    }

    /// Whether what the controller assumes of every road user is the anchor's: the road users
    /// are known exactly (the oracle), or the anchor is the present observation (taken by
    /// [`KnownActors::anchor_here`], and no observation and no new barrier since). Every
    /// [`KnownActors::assumption_change`] is then 0.
    fn assumes_the_anchor(&self) -> bool {
        self.knowledge == ActorKnowledge::Oracle
            || (self.anchor_time.to_bits() == self.now.to_bits() && self.anchor.len() == self.observed.len())
    }

    /// The moving road users, by their primary barrier.
    fn road_users(&self) -> impl Iterator<Item = usize> + '_ {
        (self.motions.iter().zip(&self.primary).enumerate()).filter_map(|(k, (m, &p))| (m.is_some() && p).then_some(k))
    }

    /// The largest change, over the times `window` (none before either observation), of what the
    /// controller assumes of the road user whose primary barrier is k between the anchor's
    /// observation and the present one: of a circle's position (the centre's, plus the road
    /// user's spread times its change of heading), velocity and acceleration, each the largest
    /// coordinate (m, m/s, m/s²). Each coordinate's change is constant or affine in time but
    /// constant acceleration's position, a parabola: largest at an end of the window or at
    /// its vertex. Infinite without an anchor; 0 for the oracle, whose assumption is the truth
    /// whenever observed.
    fn assumption_change(&self, k: usize, (from, to): (f64, f64)) -> f64 {
        if self.knowledge == ActorKnowledge::Oracle {
            return 0.0;
        }
        if self.anchor_time.is_nan() || self.anchor.len() != self.observed.len() {
            return f64::INFINITY;
        }
        let largest = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs().max((a[1] - b[1]).abs());
        // The road user's barriers: k and the ones after it up to the next primary.
        let spread = self.spread[k];
        let (now, then) = (&self.observed[k], &self.anchor[k]);
        let turned = spread * (now.turn - then.turn).abs();
        let mut times = [from, to, f64::NAN, f64::NAN];
        if self.knowledge == ActorKnowledge::ConstantAcceleration {
            // Where d/ds of the difference of o + v (s − t_o) + a (s − t_o)²/2 vanishes.
            for c in 0..2 {
                let curvature = now.acceleration[c] - then.acceleration[c];
                let slope_at_zero = now.velocity[c] - now.acceleration[c] * self.now - then.velocity[c]
                    + then.acceleration[c] * self.anchor_time;
                times[2 + c] = (-slope_at_zero / curvature).clamp(from, to);
            }
        }
        let mut change = 0.0_f64;
        for s in times.into_iter().filter(|s| s.is_finite()) {
            let truth = |_: f64| *now;
            let a = self.knowledge.predict(now, self.now, s.max(self.now), truth);
            let b = self
                .knowledge
                .predict(then, self.anchor_time, s.max(self.anchor_time), truth);
            change = change
                .max(largest(a.position, b.position) + turned)
                .max(largest(a.velocity, b.velocity))
                .max(largest(a.acceleration, b.acceleration));
        }
        change
    }

    /// Where the controller now assumes the road user of known barrier k at `at` (its centre;
    /// the default state for a barrier that does not move), as its reach tests read it.
    /// Bounds on where the controller assumes the road user of barriers `first..end` over the
    /// look-aheads [from, to] from its observation ([`ActorKnowledge::window`]); None unless
    /// it moves, its barriers were all observed in one state, and the assumption is bounded.
    fn assumed_window(&self, first: usize, end: usize, from: f64, to: f64) -> Option<AssumedWindow> {
        self.motions.get(first)?.as_ref()?;
        let observed = self.observed.get(first)?;
        if self.observed.get(first..end)?.iter().any(|o| o != observed) {
            return None;
        }
        self.knowledge.window(observed, from, to)
    }

    fn assumed_centre(&self, k: usize, at: f64) -> ActorState {
        match &self.motions[k] {
            Some(motion) => self.assumed(motion, k, at),
            None => ActorState::default(),
        }
    }

    /// observed ← every actor's state at the tick time t when an observation is due (every
    /// `observe_every` ticks from the first); else the barriers that became known since the
    /// last one are given their state then (a road user that did not exist then is parked out
    /// of the way, `ActorMotion::where_at`: it is seen from the next observation on).
    fn observe(&mut self, t: f64) {
        let due = self.observed_known == 0 || self.ticks_since_observation + 1 >= self.observe_every;
        let from = match due {
            true => {
                (self.now, self.ticks_since_observation) = (t, 0);
                0
            }
            false => {
                self.ticks_since_observation += 1;
                self.observed_known
            }
        };
        let now = self.now;
        for k in from..self.observed.len() {
            if let Some(m) = &self.motions[k] {
                self.observed[k] = m.where_at(now, self.slot(k));
            }
        }
        self.observed_known = self.observed.len();
    }
}

/// What the control laws read, borrowed apart from the loop's scratch space and the filter.
struct Laws<'a> {
    model: &'a dyn Dynamics,
    nominal: &'a dyn NominalController,
    form: Option<BarrierForm>,
    barriers: &'a [Barrier],
    actors: &'a KnownActors,
}

/// Declares [`ControlLoop`]: each field with the function that builds it from the loop's
/// parts ([`LoopParts`]), in the order they are built. A new stage is its struct, its line here
/// and its call in `control_tick` (docs/ARCHITECTURE.md, "What an extension costs").
macro_rules! control_loop {
    ($(#[$meta:meta])* pub struct ControlLoop { $($(#[$field_meta:meta])* $field:ident: $ty:ty = $build:expr,)* }) => {
        $(#[$meta])*
        pub struct ControlLoop {
            $($(#[$field_meta])* $field: $ty,)*
        }

        impl ControlLoop {
            /// Builds every field from the parts, in declaration order.
            fn from_parts(parts: &mut LoopParts) -> ControlLoop {
                ControlLoop { $($field: ($build)(parts),)* }
            }
        }
    };
}

control_loop! {
    /// The controller: the tick's stages — sense, predict, the laws (nominal and filter), the
    /// delay queues — running at the control period, and the actuate stage sampling the queues
    /// at every input evaluation ([`Controller`]). Each stage owns its state; a tick hands each
    /// the previous stage's output (`control_tick`).
    pub struct ControlLoop {
        /// What the controller reads at a tick: the true state or a sensor's measurement.
        sense: SenseStage = SenseStage::new,
        /// The model, the nominal and the filter with what they read (the known barriers and
        /// road users) and their scratch space.
        laws: LawStage = LawStage::new,
        /// Every channel's prediction p_i(t) on the predictor structure.
        predict: PredictStage = PredictStage::new,
        /// The delay queues of the issued commands.
        queues: QueueStage = QueueStage::new,
        /// The plant's input at each evaluation, from the queues.
        actuate: ActuateStage = ActuateStage::new,
        /// Predictions waiting for their target time, for the consistency checks.
        pending: PendingStage = PendingStage::new,
        timing: Timing = |parts: &mut LoopParts| parts.timing,
        /// What the last control tick computed; `tick_ready` until the episode takes it.
        tick: Tick = Tick::new,
        tick_ready: bool = |_: &mut LoopParts| false,
        /// An error raised inside the callback (reported after the step).
        error: Option<FilterError> = |_: &mut LoopParts| None,
    }
}

/// What the loop is built from ([`ControlLoop::new`]); each stage takes its part.
struct LoopParts {
    model: Arc<dyn Dynamics>,
    nominal: Option<Box<dyn NominalController>>,
    filter: Option<Box<dyn SafetyFilter>>,
    queues: Vec<DelayQueue>,
    structure: Structure,
    timing: Timing,
    /// (n, r): the state size and the number of input channels (one queue each).
    sizes: (usize, usize),
}

/// The plant step, the control period and the steps per tick.
#[derive(Debug, Clone, Copy)]
struct Timing {
    timestep: f64,
    control_period: f64,
    steps_per_tick: u64,
}

/// The tables' part of the loop ([`crate::section::Section::configure`]).
impl crate::section::ControlSettings for ControlLoop {
    fn timestep(&self) -> f64 {
        self.timing.timestep
    }

    fn state_dim(&self) -> usize {
        self.laws.model.state_dim()
    }

    fn channel_names(&self) -> Vec<String> {
        self.laws.model.channel_names().to_vec()
    }

    /// The controller reads `sensor`'s measurement instead of the true state (predictions are
    /// still compared with the truth).
    fn set_sensor(&mut self, sensor: Sensor) {
        self.sense.sensor = Some(sensor);
    }

    /// Puts `actuator` (lag, rate and magnitude limits) between channel `channel`'s delayed
    /// command and the plant.
    fn set_actuator(&mut self, channel: usize, actuator: Actuator) {
        let r = self.queues().len();
        if self.actuate.dynamics.len() != r {
            self.actuate.actuated = Some(vec![0.0; r]);
            self.actuate.dynamics = vec![None; r];
        }
        self.actuate.dynamics[channel] = Some(actuator);
    }

    /// Adds ω_i(t) to channel i's applied input, unknown to the predictors.
    fn set_input_disturbance(&mut self, disturbance: InputDisturbance) {
        self.actuate.disturbance = Some(disturbance);
    }

    /// What the controller assumes of moving actors over the delays.
    fn set_actor_knowledge(&mut self, knowledge: ActorKnowledge, period: f64) -> Result<(), String> {
        let control_period = self.timing.control_period;
        let ticks = period / control_period;
        if !(period == 0.0 || ((0.5..=1e9).contains(&ticks) && (ticks - ticks.round()).abs() < 1e-6)) {
            return Err(format!(
                "expected 0 (every tick) or a whole multiple of the control period {control_period} s, found {period}"
            ));
        }
        let actors = &mut self.laws.actors;
        actors.knowledge = knowledge;
        actors.observe_every = (ticks.round() as u64).max(1);
        Ok(())
    }

    /// Sets the predictors' RK4 step to `steps` plant steps. The plant step h is always valid;
    /// anything else needs every delay constant and a whole multiple of the control period
    /// (the applied inputs are then constant on the control grid, so a step of one period is
    /// exact up to RK4 truncation; a coarser one switches inputs inside its RK4 steps and holds
    /// κ_j's commands over several periods, an approximation the /prediction records measure).
    fn set_predictor_step(&mut self, steps: u32) -> Result<(), String> {
        let period = self.timing.control_period;
        if steps != 1 && !self.queues.assumed.iter().all(|q| on_tick_grid(q, period)) {
            return Err("a predictor step other than the timestep needs constant delays that are whole multiples of the control period".into());
        }
        self.predict.step = steps as f64 * self.timing.timestep;
        Ok(())
    }

    /// Reuse of the recursive chain between ticks (see [`PredictorWorkspace::set_chain_reuse`]).
    fn set_chain_tolerance(&mut self, tolerance: f64) {
        self.predict.workspace.set_chain_reuse(Some(tolerance));
    }

    /// Whether road users out of reach form no barrier row (`control.leave_out_of_reach`).
    fn set_leave_out_of_reach(&mut self, leave_out: bool) {
        self.laws.work.reach.set_allowed(leave_out);
    }
}

/// Sense: x(t) at the tick — the true state, or what a sensor reports of it (late, biased,
/// noisy), which needs the true state of every step.
struct SenseStage {
    sensor: Option<Sensor>,
    /// x(t) as the controller reads it at the tick (allocated once).
    state: DVector<f64>,
}

impl SenseStage {
    /// The true state until a sensor is set.
    fn new(parts: &mut LoopParts) -> SenseStage {
        SenseStage {
            sensor: None,
            state: DVector::zeros(parts.sizes.0),
        }
    }

    /// Records the true state for a late sensor (every step's first call) and, at a tick,
    /// reads the state the controller uses (a sensor's measurement is also kept in `measured`).
    fn read(
        &mut self,
        step: u64,
        call_in_step: u32,
        tick: bool,
        truth: &dyn Fn(&mut [f64]),
        measured: &mut DVector<f64>,
    ) {
        if let Some(sensor) = &mut self.sensor {
            // A late sensor needs the true state of every step; otherwise only at ticks.
            if call_in_step == 0 && (tick || sensor.latency_steps() > 0) {
                truth(self.state.as_mut_slice());
                sensor.record(step, self.state.as_slice());
            }
        }
        if tick {
            match &self.sensor {
                Some(sensor) => {
                    sensor.measure_into(step, self.state.as_mut_slice());
                    measured.copy_from(&self.state);
                }
                None => truth(self.state.as_mut_slice()),
            }
        }
    }
}

/// The laws: the model the controller assumes, the nominal, the filter, the barriers and road
/// users it knows, and the scratch space of u0 and the filters' decisions.
struct LawStage {
    model: Arc<dyn Dynamics>,
    nominal: Box<dyn NominalController>,
    filter: Box<dyn SafetyFilter>,
    /// Barriers currently known to the controller (add with [`ControlLoop::add_barrier`]).
    known_barriers: Vec<Barrier>,
    /// The moving actors among them.
    actors: KnownActors,
    work: LawWorkspace,
}

impl LawStage {
    /// The parts' model, nominal and filter, with no barrier or road user known yet.
    fn new(parts: &mut LoopParts) -> LawStage {
        let (n, r) = parts.sizes;
        let model = parts.model.clone();
        let work = LawWorkspace {
            lie: LieWorkspace::new(model.as_ref()),
            constraints: Vec::new(),
            nominal: DVector::zeros(r),
            input: DVector::zeros(r),
            moving: Vec::new(),
            drift: vec![0.0; n],
            zero_input: vec![0.0; r],
            unit_input: vec![0.0; r],
            columns: vec![0.0; n * r],
            point_input: vec![[0.0; 2]; r],
            row_barrier: Vec::new(),
            rows_moved: true,
            reach: Reach::new(model.as_ref(), &parts.queues),
            planned: vec![0.0; r],
            says_planned: false,
            law_corrected: false,
            seen: Vec::new(),
            reach_now: Vec::new(),
            reach_chain: Vec::new(),
            reach_spare: Vec::new(),
            recording: false,
        };
        LawStage {
            model,
            nominal: parts.nominal.take().expect("the law stage is built once"),
            filter: parts.filter.take().expect("the law stage is built once"),
            known_barriers: Vec::new(),
            actors: KnownActors {
                motions: Vec::new(),
                offsets: Vec::new(),
                spread: Vec::new(),
                primary: Vec::new(),
                slots: Vec::new(),
                knowledge: ActorKnowledge::default(),
                now: 0.0,
                observed: Vec::new(),
                observed_known: 0,
                observe_every: 1,
                ticks_since_observation: 0,
                sleep_span: 0.0,
                anchor_time: f64::NAN,
                anchor: Vec::new(),
            },
            work,
        }
    }

    /// (the filter uses predictions, the nominal does).
    fn predicts(&self) -> (bool, bool) {
        (self.filter.uses_prediction(), self.nominal.uses_prediction())
    }

    /// What the laws read, the filter and the scratch space, borrowed apart.
    fn parts(&mut self) -> (Laws<'_>, &mut dyn SafetyFilter, &mut LawWorkspace) {
        let laws = Laws {
            model: self.model.as_ref(),
            nominal: self.nominal.as_ref(),
            form: self.filter.barrier_form(),
            barriers: &self.known_barriers,
            actors: &self.actors,
        };
        (laws, self.filter.as_mut(), &mut self.work)
    }
}

/// Predict: the predictor structure and step, its workspace and the predictions of the last
/// tick, and an optional audit of chain reuse.
struct PredictStage {
    structure: Structure,
    /// RK4 step of the predictors: by default the control period when every delay is constant
    /// and a whole multiple of it (the applied inputs are then constant on that grid, so the
    /// coarser step loses only RK4 truncation error, measured by the consistency check), else
    /// h. A scenario may set a coarser multiple of the control period (`predictor.step`).
    step: f64,
    workspace: PredictorWorkspace,
    predictions: Vec<Prediction>,
    /// When auditing chain reuse: the whole-window recomputation next to every reused chain.
    audit: Option<ChainAudit>,
    /// The chain's laws [`PredictStage::keep_chain_for`] has already tested each road user at.
    tested: TestedLaws,
}

/// Per road user (by its primary barrier), the time of the chain's last law at which the
/// reach test, made again with the present assumption, left it out, for one pair of
/// observations (the anchor's and the present one, with as many known barriers). The test's
/// outcome at a law does not change while that pair stays (the law's state and input bounds are
/// kept with it, and the assumption is the same), so each tick tests only the laws added since
/// (one, at the chain's new end) instead of every law of the chain again.
#[derive(Default)]
struct TestedLaws {
    observations: (u64, u64, usize),
    until: Vec<f64>,
    /// Scratch: the changed road users no law of the chain formed rows of.
    changed: Vec<usize>,
}

impl TestedLaws {
    /// Forgets every road user's tested laws when the observations compared are not the last
    /// call's.
    fn compare(&mut self, actors: &KnownActors) {
        let observations = (
            actors.anchor_time.to_bits(),
            actors.now.to_bits(),
            actors.observed.len(),
        );
        if self.observations != observations {
            self.observations = observations;
            self.until.clear();
        }
        self.until.resize(actors.observed.len(), f64::NEG_INFINITY);
    }
}

impl PredictStage {
    /// The parts' structure, stepping at the control period when every queue's delays stay on
    /// its grid, else at the plant step.
    fn new(parts: &mut LoopParts) -> PredictStage {
        let (n, r) = parts.sizes;
        let Timing {
            timestep,
            control_period,
            ..
        } = parts.timing;
        let workspace = PredictorWorkspace::new(n, r);
        PredictStage {
            structure: parts.structure.clone(),
            step: match parts.queues.iter().all(|q| on_tick_grid(q, control_period)) {
                true => control_period,
                false => timestep,
            },
            predictions: workspace.predictions(),
            workspace,
            audit: None,
            tested: TestedLaws::default(),
        }
    }

    /// Forgets the recursive chain when what the controller assumes of the road users has
    /// changed by more than the chain tolerance since the chain's laws were formed, at any
    /// time they are evaluated at ([t + D_1, t + D_r] on the control grid): those laws are then
    /// no longer the filter's (as when a barrier becomes known), and reusing them would
    /// predict with a stale assumption (constant velocity re-anchored at every tick).
    /// A road user whose assumption changed is let be when no law of the chain formed its rows
    /// and the reach test, made again at each law's state with the new assumption, still
    /// leaves it out: its rows are then in those laws under neither assumption.
    fn keep_chain_for(&mut self, actors: &KnownActors, work: &mut LawWorkspace, t: f64, period: f64) {
        let (Some(tolerance), Structure::Recursive { delays, .. }) =
            (self.workspace.chain_tolerance(), &self.structure)
        else {
            return;
        };
        if actors.assumes_the_anchor() {
            return;
        }
        let first = delays.iter().copied().fold(f64::INFINITY, f64::min);
        let last = delays.iter().copied().fold(0.0, f64::max);
        let nodes = ((last - first) / period).round().max(0.0) as usize;
        let window = (t + first, t + first + nodes as f64 * period);
        let LawWorkspace { reach, reach_chain, .. } = work;
        self.tested.compare(actors);
        let TestedLaws { until, changed, .. } = &mut self.tested;
        // A changed road user some law of the chain formed rows of ends it (no reach test to
        // make again); the other changed ones are then tested again at every law's state with
        // the new assumption (but at the laws already tested, [`TestedLaws`]).
        changed.clear();
        for k in actors.road_users() {
            if actors.assumption_change(k, window) <= tolerance {
                continue;
            }
            if reach_chain.is_empty() || reach_chain.iter().any(|node| reach.formed_in(node, k)) {
                self.workspace.invalidate_chain();
                return;
            }
            changed.push(k);
        }
        for &k in changed.iter() {
            let tested = until[k];
            let left_out = |reach: &mut Reach, node: &ReachAt| {
                node.time <= tested || reach.still_out(node, k, |j| actors.assumed_centre(j, node.time))
            };
            if !reach_chain.iter().all(|node| left_out(reach, node)) {
                self.workspace.invalidate_chain();
                return;
            }
            until[k] = reach_chain.last().map_or(tested, |node| node.time);
        }
    }

    /// Every channel's prediction from x(t) = `state` ([`predict_stage`]); only for a
    /// controller that uses predictions: otherwise every channel evaluates at x(t) and nothing
    /// is pending for consistency checks.
    fn run(
        &mut self,
        laws: &mut LawStage,
        (queues, timing): (&[DelayQueue], Timing),
        (t, state): (f64, &DVector<f64>),
        predicts: (bool, bool),
    ) -> Result<(), FilterError> {
        let structure = if predicts.0 || predicts.1 {
            &self.structure
        } else {
            &Structure::None
        };
        let (laws, filter, law) = laws.parts();
        let context = PredictorContext {
            model: laws.model,
            queues,
            timestep: self.step,
            control_period: timing.control_period,
        };
        predict_stage(
            (&laws, filter, law),
            (&context, structure, predicts.1),
            (t, state),
            (&mut self.workspace, &mut self.predictions),
            self.audit.as_mut(),
        )
    }
}

/// The delay queues: the controller's (the delays it assumes) and, when the true delays or the
/// actuation differ, the actuators' own; every issued command goes to both.
struct QueueStage {
    assumed: Vec<DelayQueue>,
    actuators: Option<Vec<DelayQueue>>,
}

impl QueueStage {
    /// The parts' queues (what the controller assumes; the actuators' own are set apart).
    fn new(parts: &mut LoopParts) -> QueueStage {
        QueueStage {
            assumed: std::mem::take(&mut parts.queues),
            actuators: None,
        }
    }

    /// The tick's commands issued at t onto every queue.
    fn push(&mut self, t: f64, issued: &DVector<f64>) -> Result<(), DelayError> {
        for queues in std::iter::once(&mut self.assumed).chain(self.actuators.as_mut()) {
            for (queue, &u) in queues.iter_mut().zip(issued.iter()) {
                queue.push(t, u)?;
                queue.discard_before(t);
            }
        }
        Ok(())
    }

    /// The queues the plant's inputs come from: the true delays.
    fn true_delays(&self) -> &[DelayQueue] {
        self.actuators.as_deref().unwrap_or(&self.assumed)
    }
}

/// Actuate: each channel's queue sampled at the evaluation time, plus the input disturbance,
/// through the actuator dynamics.
struct ActuateStage {
    /// A disturbance ω_i(t) added to channel i's applied input ((4.12) with Z = G); unknown
    /// to the predictors.
    disturbance: Option<InputDisturbance>,
    /// Per channel, the actuator between the delayed command and the plant, if any; and the
    /// plant's input over the current step (every channel) when some channel has one.
    dynamics: Vec<Option<Actuator>>,
    actuated: Option<Vec<f64>>,
    /// Applied input at the start of the current step (value, issue time) per channel.
    applied: Vec<(f64, f64)>,
    /// The plant's input at the current evaluation (allocated once).
    buffer: Vec<f64>,
}

impl ActuateStage {
    /// No disturbance or actuator dynamics until set; every channel applies 0 issued at 0.
    fn new(parts: &mut LoopParts) -> ActuateStage {
        let r = parts.sizes.1;
        ActuateStage {
            disturbance: None,
            dynamics: Vec::new(),
            actuated: None,
            applied: vec![(0.0, 0.0); r],
            buffer: Vec::with_capacity(r),
        }
    }

    /// The plant's input at `sample_time`, from `queues`; a queue's error is kept in `error`
    /// (that channel then reads 0).
    fn sample(
        &mut self,
        queues: &[DelayQueue],
        (sample_time, call_in_step, timestep): (f64, u32, f64),
        error: &mut Option<FilterError>,
    ) -> &[f64] {
        self.buffer.clear();
        for (i, queue) in queues.iter().enumerate() {
            let applied = match queue.applied(sample_time) {
                Ok(a) => a,
                Err(e) => {
                    error.get_or_insert(e.into());
                    crate::delay::Applied {
                        value: 0.0,
                        issued_at: f64::NAN,
                    }
                }
            };
            let value = applied.value + self.disturbance.as_ref().map_or(0.0, |w| w(sample_time, i));
            if call_in_step == 0 {
                self.applied[i] = (value, applied.issued_at);
            }
            self.buffer.push(value);
        }
        // Actuator dynamics: the step's command (at its start) drives the actuator, whose mean
        // output over the step is the input of every evaluation of the step.
        if let Some(actuated) = &mut self.actuated {
            if call_in_step == 0 {
                for ((out, &command), actuator) in actuated.iter_mut().zip(&self.buffer).zip(&mut self.dynamics) {
                    *out = match actuator {
                        Some(actuator) => actuator.step(command, timestep),
                        None => command,
                    };
                }
            }
            for (value, (&out, actuator)) in self.buffer.iter_mut().zip(actuated.iter().zip(&self.dynamics)) {
                if actuator.is_some() {
                    *value = out;
                }
            }
        }
        &self.buffer
    }
}

/// The predictions waiting for their target time, per channel, with the storage realised ones
/// return (no allocation once warm) and the workspace that advances a state to a target time.
struct PendingStage {
    channels: Vec<VecDeque<Pending>>,
    /// States of realised predictions, reused for new pending ones and realised states.
    spare_states: Vec<DVector<f64>>,
    /// Storage of realised predictions' actor positions, reused.
    spare_actor_positions: Vec<Vec<f64>>,
    /// Advances the state to a prediction's target time between steps.
    realize: PredictorWorkspace,
}

impl PendingStage {
    /// Nothing pending, one queue per channel.
    fn new(parts: &mut LoopParts) -> PendingStage {
        let (n, r) = parts.sizes;
        PendingStage {
            channels: vec![VecDeque::new(); r],
            spare_states: Vec::new(),
            spare_actor_positions: Vec::new(),
            realize: PredictorWorkspace::new(n, r),
        }
    }

    /// Keeps the tick's predictions whose target time is still ahead ([`keep_pending`]).
    fn keep(&mut self, (t, timestep, actors): (f64, f64, &KnownActors), predict: &PredictStage) {
        keep_pending(
            (t, timestep, actors),
            (&predict.predictions, &predict.workspace),
            (&mut self.spare_states, &mut self.spare_actor_positions),
            &mut self.channels,
        );
    }
}

/// ω_i(t) added to channel i's applied input ([`crate::disturbance`]).
pub use crate::disturbance::InputDisturbance;

/// Every recursive prediction recomputed over its whole window next to the reused chain, and
/// the largest difference seen (what `control.chain_tolerance` costs; benchmarks report it).
struct ChainAudit {
    workspace: PredictorWorkspace,
    predictions: Vec<Prediction>,
    max_difference: f64,
    reused: u64,
}

impl ControlLoop {
    /// The loop for a model, its nominal and filter, one delay queue per channel, the
    /// predictor structure, the plant step h and the control period in steps.
    pub fn new(
        model: Arc<dyn Dynamics>,
        nominal: Box<dyn NominalController>,
        filter: Box<dyn SafetyFilter>,
        queues: Vec<DelayQueue>,
        structure: Structure,
        timestep: f64,
        steps_per_tick: u64,
    ) -> ControlLoop {
        let sizes = (model.state_dim(), queues.len());
        let mut parts = LoopParts {
            sizes,
            model,
            nominal: Some(nominal),
            filter: Some(filter),
            queues,
            structure,
            timing: Timing {
                timestep,
                control_period: steps_per_tick as f64 * timestep,
                steps_per_tick,
            },
        };
        ControlLoop::from_parts(&mut parts)
    }

    /// What the plant received over the last step per channel, when some channel has actuator
    /// dynamics (else the plant received [`ControlLoop::applied`]).
    pub fn actuated(&self) -> Option<&[f64]> {
        self.actuate.actuated.as_deref()
    }

    /// Whether the controller reads a sensor rather than the true state.
    pub fn has_sensor(&self) -> bool {
        self.sense.sensor.is_some()
    }

    /// Actuates through queues of the true delays, one per channel (the controller keeps
    /// predicting and filtering with the delays of [`ControlLoop::queues`]).
    pub fn set_actuators(&mut self, actuators: Vec<DelayQueue>) {
        self.queues.actuators = Some(actuators);
    }

    /// The queues the plant's inputs come from: the true delays.
    pub fn actuators(&self) -> &[DelayQueue] {
        self.queues.true_delays()
    }

    /// The analytic model the controller assumes.
    pub fn model(&self) -> &Arc<dyn Dynamics> {
        &self.laws.model
    }

    /// Whether a predictor runs at the ticks (the filter or the nominal uses predictions, and
    /// some channel is delayed).
    pub fn predicts(&self) -> bool {
        let (filter, nominal) = self.laws.predicts();
        (filter || nominal) && self.predict.structure != Structure::None
    }

    /// The nominal controller (to set an external one's input between steps).
    pub fn nominal_mut(&mut self) -> &mut dyn NominalController {
        self.laws.nominal.as_mut()
    }

    /// The safety filter.
    pub fn filter(&self) -> &dyn SafetyFilter {
        self.laws.filter.as_ref()
    }

    /// The delay queue of every channel, with the delays the controller assumes.
    pub fn queues(&self) -> &[DelayQueue] {
        &self.queues.assumed
    }

    /// The plant step h (s).
    pub fn timestep(&self) -> f64 {
        self.timing.timestep
    }

    /// Plant steps per control tick.
    pub fn steps_per_tick(&self) -> u64 {
        self.timing.steps_per_tick
    }

    /// The predictors' RK4 step (s).
    pub fn predictor_step(&self) -> f64 {
        self.predict.step
    }

    /// (value, issue time) of each channel's input applied at the start of the last step.
    pub fn applied(&self) -> &[(f64, f64)] {
        &self.actuate.applied
    }

    /// The error raised inside the last step's callbacks, if any (taken once).
    pub fn take_error(&mut self) -> Option<FilterError> {
        self.error.take()
    }

    /// The barrier rows formed and left out so far.
    pub fn barrier_rows(&self) -> super::BarrierRows {
        let reach = &self.laws.work.reach;
        super::BarrierRows {
            formed: reach.rows_formed,
            left_out: reach.rows_left_out,
            redone: reach.redone,
        }
    }

    /// Makes a barrier known to the controller (outside the callback: sizes the scratch space).
    pub fn add_barrier(&mut self, barrier: Barrier) {
        self.add_known(barrier, None, None);
    }

    /// Makes a moving actor's barrier known (a planar circle about the actor's centre plus
    /// `offset`, where the actor is at t = 0; outside the callback): the filters evaluate it
    /// with the actor where the controller assumes it at each channel's prediction time. An
    /// actor with several barriers (a box's covering circles, a footprint's) has one `primary`.
    pub fn add_moving_barrier(&mut self, barrier: Barrier, motion: ActorMotion, offset: [f64; 2], primary: bool) {
        assert!(
            barrier.clone().move_actor([0.0; 2]),
            "a moving actor's barrier is a planar circle or a headway"
        );
        self.add_known(barrier, Some(motion), Some((offset, primary)));
        let actors = &mut self.laws.actors;
        *actors.offsets.last_mut().expect("just added") = offset;
        *actors.primary.last_mut().expect("just added") = primary;
        actors.place_last();
        // The actor's spread, at its primary barrier (this one, or the last before it).
        let at = actors.slot(actors.primary.len() - 1);
        actors.spread[at] = actors.spread[at].max(offset[0].hypot(offset[1]));
        // (len stays 0 outside a tick: reserve for every primary actor.)
        let primaries = actors.primary.iter().filter(|&&p| p).count();
        self.laws.work.seen.reserve(primaries);
    }

    fn add_known(&mut self, barrier: Barrier, motion: Option<ActorMotion>, road_user: Option<([f64; 2], bool)>) {
        let channels = self.queues.assumed.len();
        let laws = &mut self.laws;
        laws.work.reach.add(&barrier, road_user);
        laws.work.moving.push(motion.as_ref().map(|_| barrier.clone()));
        laws.actors.motions.push(motion);
        laws.actors.offsets.push([0.0; 2]);
        laws.actors.primary.push(false);
        laws.actors.place_last();
        laws.actors.spread.push(0.0);
        laws.actors.observed.push(ActorState::default());
        // A mixed-relative-degree barrier has a second row, ḣ + λ1 h ≥ 0.
        let form = laws.filter.barrier_form();
        if barrier.mixed_relative_degree() && form.is_some_and(|f| f.real_rates().is_some()) {
            laws.work.constraints.push(Constraint::zeros(channels));
            laws.work.row_barrier.push(0);
        }
        laws.known_barriers.push(barrier);
        laws.work.constraints.push(Constraint::zeros(channels));
        laws.work.row_barrier.push(0);
        laws.work.rows_moved = true;
        let sizes = laws.work.reach.sizes();
        let LawWorkspace {
            reach_now,
            reach_chain,
            reach_spare,
            ..
        } = &mut laws.work;
        for node in reach_now
            .iter_mut()
            .chain(reach_chain.iter_mut())
            .chain(reach_spare.iter_mut())
        {
            node.reserve(sizes);
        }
        // κ_j changed: the recursive chain computed with the old law no longer holds.
        self.predict.workspace.invalidate_chain();
    }

    /// An actor's trigger fired at `time`: the controller's copy of its motion follows (from
    /// the next tick on, the actor is observed braking, walking, …). `name` is the obstacle's:
    /// its barriers are named as it or `<name>/<i>-<j>`.
    pub fn actor_triggered(&mut self, name: &str, time: f64) {
        let laws = &mut self.laws;
        for (b, m) in laws.known_barriers.iter().zip(&mut laws.actors.motions) {
            let ours = b.name == name || b.name.strip_prefix(name).is_some_and(|rest| rest.starts_with('/'));
            if let (true, Some(m)) = (ours, m) {
                m.set_triggered_at(time);
            }
        }
    }

    /// The known moving actors: (barrier name, true motion), in the order of
    /// [`Consistency::actors_predicted`].
    pub fn moving_actors(&self) -> impl Iterator<Item = (&str, &ActorMotion)> {
        let laws = &self.laws;
        (laws
            .known_barriers
            .iter()
            .zip(&laws.actors.motions)
            .zip(&laws.actors.primary))
        .filter_map(|((b, m), &primary)| m.as_ref().filter(|_| primary).map(|m| (b.name.as_str(), m)))
    }

    pub fn known_barriers(&self) -> &[Barrier] {
        &self.laws.known_barriers
    }

    /// Recomputes every reused recursive chain over its whole window too, and keeps the
    /// largest difference (doubles the predictor cost: for measurements, not for runs).
    pub fn audit_chain_reuse(&mut self) {
        let workspace = PredictorWorkspace::new(self.laws.model.state_dim(), self.queues.assumed.len());
        self.predict.audit = Some(ChainAudit {
            predictions: workspace.predictions(),
            workspace,
            max_difference: 0.0,
            reused: 0,
        });
    }

    /// (largest max-norm difference between a reused and a recomputed prediction, predictions
    /// made from a reused chain) since [`ControlLoop::audit_chain_reuse`].
    pub fn chain_audit(&self) -> Option<(f64, u64)> {
        self.predict.audit.as_ref().map(|a| (a.max_difference, a.reused))
    }

    /// The last tick's record, once (after the step in which it ran).
    pub fn take_tick(&mut self) -> Option<(&Tick, &[Barrier])> {
        std::mem::take(&mut self.tick_ready).then_some((&self.tick, &self.laws.known_barriers))
    }

    /// One control tick at time t from the state the sense stage read: the road users as
    /// observed at t → predict (if the filter or the nominal uses predictions) → the laws: per
    /// channel u0 and the filter's decision at the channel's evaluation state → the delay
    /// queues → the predictions kept for their consistency checks.
    fn control_tick(&mut self, t: f64) -> Result<(), FilterError> {
        let ControlLoop {
            sense,
            laws,
            predict,
            queues,
            pending,
            timing,
            tick,
            tick_ready,
            ..
        } = self;
        laws.actors.observe(t);
        let largest_delay = (queues.assumed.iter()).fold(0.0, |d: f64, q| d.max(q.constant_delay().unwrap_or(0.0)));
        laws.actors.sleep_span = (laws.actors.observe_every + 1) as f64 * timing.control_period + largest_delay;
        let predicts = laws.predicts();
        predict.keep_chain_for(&laws.actors, &mut laws.work, t, timing.control_period);
        laws.work.recording = true;
        let predicted = predict.run(laws, (&queues.assumed, *timing), (t, &sense.state), predicts);
        laws.work.recording = false;
        predicted?;
        let restarted = predict.predictions.iter().any(|p| !p.reused_chain);
        let window_start = predict
            .predictions
            .iter()
            .map(|p| p.target_time)
            .fold(f64::INFINITY, f64::min);
        laws.work
            .keep_chain_reach(restarted, window_start - 0.5 * timing.control_period);
        if restarted {
            laws.actors.anchor_here();
        }
        let left_out_before = laws.work.reach.rows_left_out;
        let (laws_read, filter, law) = laws.parts();
        decide_stage(
            (&laws_read, filter, law),
            (t, &sense.state, &predict.predictions),
            (&queues.assumed, timing.timestep, predicts),
            tick,
        )?;
        tick.left_out = laws.work.reach.rows_left_out - left_out_before;
        queues.push(t, &tick.issued)?;
        pending.keep((t, timing.timestep, &laws.actors), predict);
        tick.time = t;
        *tick_ready = true;
        Ok(())
    }

    /// The latest prediction of each channel still waiting for its target time (the one the
    /// last tick made): what the Foxglove scene draws.
    pub fn latest_predictions(&self) -> impl Iterator<Item = &Prediction> {
        self.pending
            .channels
            .iter()
            .filter_map(|q| q.back().map(|p| &p.prediction))
    }

    /// Per channel, the actors' assumed positions at the target time of its latest pending
    /// prediction (x, y pairs in the order of [`ControlLoop::moving_actors`], for the actors
    /// known at its tick): what the Foxglove scene draws.
    pub fn latest_actor_predictions(&self) -> impl Iterator<Item = (usize, &[f64])> {
        (self.pending.channels.iter()).filter_map(|q| q.back().map(|p| (p.prediction.channel, p.actors.as_slice())))
    }

    /// Predictions whose target time falls in [t_k, t_k + h), compared with the realised state:
    /// x(t_k) itself, or x(t_k) advanced to an off-grid target with the applied inputs (for a
    /// model invariant under planar motions, the predictor's own final partial step from t_k
    /// moved onto x(t_k), when it ran on this grid with these inputs).
    /// Hand them back with [`ControlLoop::recycle`] once logged.
    ///
    /// `last`: x_k is the run's final state, so only predictions of that time are realised (a
    /// target later than the run's end has no realised state: not extrapolated past it).
    /// They are written into `out` (cleared first; its room kept between steps).
    pub fn realize_into(
        &mut self,
        t_k: f64,
        x_k: &DVector<f64>,
        last: bool,
        out: &mut Vec<Consistency>,
    ) -> Result<(), DelayError> {
        out.clear();
        let h = self.timing.timestep;
        let ControlLoop {
            laws,
            predict,
            queues,
            pending,
            timing,
            ..
        } = self;
        let reach = if last {
            h * TICK_TOLERANCE
        } else {
            h * (1.0 - TICK_TOLERANCE)
        };
        // The predictor's final partial step ran on this grid with these inputs.
        let same_step = queues.actuators.is_none() && (predict.step - h).abs() <= h * TICK_TOLERANCE;
        for channel in 0..pending.channels.len() {
            while let Some(p) = pending.channels[channel].front() {
                if p.prediction.target_time >= t_k + reach {
                    break;
                }
                let Pending {
                    prediction: p,
                    partial_step,
                    actors,
                } = pending.channels[channel].pop_front().expect("front exists");
                let mut realized = pending.spare_states.pop().unwrap_or_else(|| x_k.clone());
                let context = PredictorContext {
                    model: laws.model.as_ref(),
                    queues: queues.true_delays(),
                    timestep: h,
                    control_period: timing.control_period,
                };
                // Channels sharing a prediction time (one shared delay) share the realised state.
                let same_time = out
                    .iter()
                    .find(|c: &&Consistency| c.prediction.target_time == p.target_time);
                let moved = |realized: &mut DVector<f64>| match &partial_step {
                    Some((start, from)) if same_step && (start - t_k).abs() <= h * TICK_TOLERANCE => context
                        .move_partial_step(
                            from.as_slice(),
                            p.state.as_slice(),
                            x_k.as_slice(),
                            realized.as_mut_slice(),
                        ),
                    _ => false,
                };
                if let Some(earlier) = same_time {
                    realized.copy_from(&earlier.realized);
                } else if (p.target_time - t_k).abs() <= h * TICK_TOLERANCE {
                    realized.copy_from(x_k);
                } else if !moved(&mut realized) {
                    context.advance_with_history_into(
                        x_k.as_slice(),
                        (t_k, p.target_time),
                        &mut pending.realize,
                        realized.as_mut_slice(),
                    )?;
                }
                if let Some((_, state)) = partial_step {
                    pending.spare_states.push(state);
                }
                out.push(Consistency {
                    prediction: p,
                    realized,
                    actors_predicted: actors,
                });
            }
        }
        Ok(())
    }

    /// Returns a realised prediction's storage for reuse by later ticks.
    pub fn recycle(&mut self, consistency: Consistency) {
        let pending = &mut self.pending;
        pending.spare_states.push(consistency.prediction.state);
        pending.spare_states.push(consistency.realized);
        pending.spare_actor_positions.push(consistency.actors_predicted);
    }
}

/// The predict stage: every channel's prediction p_i(t) from x(t) on `structure`, the
/// recursive windows assuming for the commands not yet issued the law the filter issues
/// ((4.25) needs it: κ_j at the predicted z = x(s), per group of one delay D from the longest,
/// each group's ω holding the later groups' commands, with u0 at the tick s − D that issues it,
/// or at s for a nominal on predictions); with an audit, each reused chain against its
/// whole-window recomputation.
fn predict_stage(
    (laws, filter, law): (&Laws<'_>, &mut dyn SafetyFilter, &mut LawWorkspace),
    (context, structure, nominal_predicts): (&PredictorContext<'_>, &Structure, bool),
    (t, state): (f64, &DVector<f64>),
    (predictor, predictions): (&mut PredictorWorkspace, &mut Vec<Prediction>),
    chain_audit: Option<&mut ChainAudit>,
) -> Result<(), FilterError> {
    let mut law_error = None;
    // (The audit's laws are not the chain's: only the prediction's own are recorded.)
    let recording = std::cell::Cell::new(law.recording);
    let mut kappa = |s: f64, z: &[f64], free: &[usize], u: &mut [f64]| {
        law.recording = recording.get();
        if let Err(e) = law.issued_law(laws, filter, context.queues, nominal_predicts, (s, z, free), u) {
            law_error.get_or_insert(e);
        }
    };
    context.predict_into(structure, t, state.as_slice(), &mut kappa, predictor, predictions)?;
    if let Some(audit) = chain_audit {
        let ChainAudit {
            workspace,
            predictions: recomputed,
            ..
        } = audit;
        recording.set(false);
        context.predict_into(structure, t, state.as_slice(), &mut kappa, workspace, recomputed)?;
        for (p, q) in predictions.iter().zip(recomputed.iter()) {
            if p.reused_chain {
                audit.reused += 1;
                let difference = (&p.state - &q.state).amax();
                audit.max_difference = audit.max_difference.max(difference);
            }
        }
    }
    law_error.map_or(Ok(()), Err)
}

/// The laws stage: per channel, u0 and the filter's decision at the channel's evaluation point
/// (its prediction if the filter predicts, else x(t)), into `tick`; a non-finite command never
/// reaches a queue (the tick stops with an error).
fn decide_stage(
    (laws, filter, law): (&Laws<'_>, &mut dyn SafetyFilter, &mut LawWorkspace),
    (t, state, predictions): (f64, &DVector<f64>, &[Prediction]),
    (queues, timestep, (filter_predicts, nominal_predicts)): (&[DelayQueue], f64, (bool, bool)),
    tick: &mut Tick,
) -> Result<(), FilterError> {
    let mut count = 0;
    for (i, p) in predictions.iter().enumerate() {
        let (eval_state, eval_time) = if filter_predicts {
            (&p.state, p.target_time)
        } else {
            (state, t)
        };
        // (u0's time, and its state with the time that state is for.)
        let (nominal_time, nominal_state, state_time) = if nominal_predicts {
            (p.target_time, &p.state, p.target_time)
        } else {
            (t, eval_state, eval_time)
        };
        // Channels at one point (one shared prediction (2.19), or none) share u0 and (a, b).
        let shared = i > 0 && (!(filter_predicts || nominal_predicts) || same_point(&predictions[i - 1], p));
        let outcome = law.channel_decision(
            laws,
            filter,
            (t, i, queues, timestep),
            (
                (nominal_time, nominal_state.as_slice(), state_time),
                (eval_state.as_slice(), eval_time),
            ),
            (shared, &mut count),
        )?;
        tick.nominal[i] = law.nominal[i];
        tick.issued[i] = outcome.map_or(law.nominal[i], |o| o.input);
        tick.outcomes[i] = outcome.map(|mut o| {
            o.unmet = o.unmet.map(|row| law.barrier_of_row(row));
            o
        });
        // A non-finite command (from a state at NaN or ±1e300) never reaches a queue.
        if !tick.issued[i].is_finite() {
            return Err(FilterError::Other(format!(
                "the command of channel `{}` at t = {t} s is not finite ({}), at the state {:?}",
                laws.model.channel_names()[i],
                tick.issued[i],
                eval_state.as_slice()
            )));
        }
    }
    Ok(())
}

/// Keeps each prediction whose target time is still ahead, with where the controller assumes
/// the moving actors then, for its consistency check when the plant gets there (storage from
/// the spares: no allocation once warm).
fn keep_pending(
    (t, timestep, actors): (f64, f64, &KnownActors),
    (predictions, predictor): (&[Prediction], &PredictorWorkspace),
    (spare_states, spare_actor_positions): (&mut Vec<DVector<f64>>, &mut Vec<Vec<f64>>),
    pending: &mut [VecDeque<Pending>],
) {
    for p in predictions.iter() {
        if p.target_time > t + TICK_TOLERANCE * timestep {
            let mut copy = |from: &[f64]| {
                let mut state = spare_states.pop().unwrap_or_else(|| p.state.clone());
                state.copy_from_slice(from);
                state
            };
            let partial_step = predictor.partial_step().map(|(start, state)| (start, copy(state)));
            // Where the controller assumes each moving actor at the target time.
            let mut assumed = spare_actor_positions.pop().unwrap_or_default();
            assumed.clear();
            // (NaN for a road user that did not exist at the last observation: the controller
            // held it parked, it assumed nothing of it.)
            for (k, m) in actors.motions.iter().enumerate() {
                if let (Some(m), true) = (m, actors.primary[k]) {
                    let position = match m.exists_at(actors.now) {
                        true => actors.assumed(m, k, p.target_time).position,
                        false => [f64::NAN; 2],
                    };
                    assumed.extend_from_slice(&position);
                }
            }
            pending[p.channel].push_back(Pending {
                actors: assumed,
                prediction: Prediction {
                    channel: p.channel,
                    issued_at: p.issued_at,
                    target_time: p.target_time,
                    state: copy(p.state.as_slice()),
                    reused_chain: p.reused_chain,
                    chain_mismatch: p.chain_mismatch,
                },
                partial_step,
            });
        }
    }
}

/// Whether two predictions have the same target time and state, bit for bit.
#[inline]
fn same_point(a: &Prediction, b: &Prediction) -> bool {
    let same_bits =
        |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(a, b)| a.to_bits() == b.to_bits());
    a.target_time.to_bits() == b.target_time.to_bits() && same_bits(a.state.as_slice(), b.state.as_slice())
}

/// Whether the queue's delay is constant and a whole multiple of the control period.
fn on_tick_grid(queue: &DelayQueue, control_period: f64) -> bool {
    queue.constant_delay().is_some_and(|d| {
        let ticks = d / control_period;
        (ticks - ticks.round()).abs() < 1e-6
    })
}

impl Controller for ControlLoop {
    fn input(&mut self, step: u64, call_in_step: u32, offset: f64, state: &dyn Fn(&mut [f64])) -> &[f64] {
        let Timing {
            timestep,
            steps_per_tick,
            ..
        } = self.timing;
        let step_time = step as f64 * timestep;
        let tick = call_in_step == 0 && step.is_multiple_of(steps_per_tick) && self.error.is_none();
        self.sense
            .read(step, call_in_step, tick, state, &mut self.tick.measured);
        if tick {
            if let Err(e) = self.control_tick(step_time) {
                self.error = Some(e);
            }
        }
        // Sample at the call's offset inside this step, kept in [t_k, t_k + h): RK4's last
        // stage (at t_k + h) takes the left limit, so a constant-delay input is constant over
        // the step.
        let offset = offset.clamp(0.0, timestep * (1.0 - TICK_TOLERANCE));
        let sample_time = step_time + offset;
        self.actuate.sample(
            self.queues.true_delays(),
            (sample_time, call_in_step, timestep),
            &mut self.error,
        )
    }
}

/// Picks the predictor structure, as an error message for the scenario's `delays` key.
pub fn predictor_structure(queues: &[DelayQueue], control_period: f64) -> Result<Structure, String> {
    predictor::structure(queues, control_period)
}
