//! The adapter of [`crate::actor::reach`] to the control loop: at each evaluation state, which
//! road users' barrier rows the controller leaves out (docs/actors.md, "Out of reach").
//!
//! The ego's points (a footprint's covering circles, or the planar position) are measured once
//! per evaluation from two probe barriers each (h = ‖q − o‖² with o = q − e_x and o = q − e_y,
//! whose Lie derivatives give q̇₀, q̈₀ and the rows of K and J exactly); a road user's bounds then
//! cost one distance per ego point (and, for one in reach as a whole, one test per circle). The
//! admissible inputs are, per channel j, |u_j| ≤ U_j = 1.1 M_j with M_j the largest |u_j| of the
//! channel's recent commands, nominal inputs and planned inputs (M_j forgets within a few ticks); a decision
//! that used an input above U_j on some channel is made again, with the bound grown to it and
//! then with every row (control.rs), so every left-out row is met by every input a decision
//! plans: the decision is the one with every row.

use crate::actor::reach::{rows_hold_given, ReachBounds};
use crate::actor::{ActorState, AssumedWindow};
use crate::barrier::{Barrier, BarrierForm, Constraint, LieWorkspace, Shape};
use crate::delay::DelayQueue;
use crate::dynamics::Dynamics;

/// The factor M_j keeps of itself at each decision ([`Reach::begin_decision`]): halving over
/// about 14 decisions, two or three ticks of a recursive predictor. 0.95 took the fewest
/// instructions of 0.9, 0.95, 0.99 and 0.999 on the committed CommonRoad files (US101-5 −18 %,
/// Flensburg −25 % against 0.999; docs/performance.md, "Stop 82").
const FORGET: f64 = 0.95;
/// U_j = BOUND_FACTOR · M_j, the admissible inputs' bound per channel (module docs). A wider box
/// certifies fewer rows out of reach, a narrower one makes more decisions again; 1.1 took the
/// fewest instructions on every CommonRoad file measured (docs/performance.md, "Stop 72").
const BOUND_FACTOR: f64 = 1.1;

/// One road user: its barriers (consecutive known barriers from its primary), the largest
/// distance of its circles from its centre, and whether its rows may be left out at all.
#[derive(Clone, Copy)]
struct Group {
    first: usize,
    end: usize,
    spread: f64,
    cullable: bool,
    /// Its range of [`Reach::gap_terms`].
    terms: [usize; 2],
    /// The largest radius of its barriers that measure from an ego point (the far test's).
    largest_radius: f64,
    /// Whether the last evaluation left it out whole: the far test is tried first only then
    /// (a road user near the ego would fail it at every evaluation).
    was_out: bool,
    /// Asleep for the current [`Epoch`] (tested with one distance), and whether it was tried.
    asleep: Option<Asleep>,
    sleep_tried: bool,
}

/// A road user asleep for the current [`Epoch`] (docs/actors.md, "Asleep through an epoch"): wherever the
/// assumption puts it over the epoch's look-aheads it is within `reach` of `centre` (its
/// assumed centre at the window's middle, plus its displacement over the window, its circles'
/// spread and largest radius), and its rows hold for every admissible input at any gap of at
/// least `threshold` with the epoch's speed, acceleration and input bounds. At an evaluation
/// within the epoch's bounds it is left out when the ego envelope is far enough from `centre`:
/// then the far test would leave it out too ([`Asleep::sleeps`]).
#[derive(Clone, Copy)]
struct Asleep {
    centre: [f64; 2],
    reach: f64,
    threshold: f64,
}

/// The bounds one observation epoch (from one observation of the road users to the next) holds
/// its evaluations to, so that a road user asleep in it needs one distance per evaluation: the
/// observation time, the look-ahead at − now its windows cover, the barrier form, the ego
/// envelope's mean velocity v̄ and acceleration ā at its first evaluation with bounds on how far
/// any ego point's q̇₀ and q̈₀ are from them at its evaluations, and bounds on W and B (those
/// of its first evaluation grown by [`EPOCH_GROWTH`]). An evaluation outside them tests every
/// road user as before, and one of another observation or beyond the ego bounds begins a new
/// epoch.
#[derive(Clone, Copy)]
struct Epoch {
    now: f64,
    span: f64,
    form: BarrierForm,
    velocity: [f64; 2],
    velocity_deviation: f64,
    acceleration: [f64; 2],
    acceleration_deviation: f64,
    input_reach: [f64; 2],
}

/// How an epoch's ego bounds grow from its first evaluation's: (factor, added) for the points'
/// velocity deviation from the mean (m/s), their acceleration deviation (m/s²), and W, B. Wider
/// bounds let fewer road users sleep, narrower ones begin more epochs (docs/performance.md,
/// "Stop 83").
const EPOCH_GROWTH: [(f64, f64); 3] = [(1.0, 1.0), (1.0, 1.0), (1.5, 0.5)];

/// The largest gap (m) a road user may need to sleep: beyond it, it stays awake.
const MOST_SLEEP_GAP: f64 = 1e6;

/// What [`Reach::mark`] needs to let road users sleep through an epoch: the observation time
/// the assumptions start from, the evaluation's time, the look-ahead an epoch covers, and the
/// bounds of a road user's assumed states over look-aheads [from, to] (its barriers
/// `first..end`; None when they are not bounded or its barriers see different states).
pub(super) struct SleepAt<'a> {
    pub(super) now: f64,
    pub(super) at: f64,
    pub(super) span: f64,
    pub(super) window: &'a dyn Fn(usize, usize, f64, f64) -> Option<AssumedWindow>,
}

/// What one ego point does at the evaluation state (module docs).
#[derive(Clone, Copy, Default)]
pub(super) struct PointMotion {
    /// q, q̇₀ and q̈₀ (the drift's velocity and acceleration of the point).
    pub(super) position: [f64; 2],
    pub(super) velocity: [f64; 2],
    pub(super) acceleration: [f64; 2],
    /// K_j = ∂q̇/∂u_j and J_j (the input's part of q̈ at relative degree 2) per input channel
    /// (up to four), and their norms.
    pub(super) velocity_columns: [[f64; 2]; 4],
    pub(super) acceleration_columns: [[f64; 2]; 4],
    velocity_gains: [f64; 4],
    acceleration_gains: [f64; 4],
}

impl PointMotion {
    /// The point's kinematics for r ≤ 4 input channels.
    pub(super) fn kinematics(&self, r: usize) -> crate::actor::reach::PointKinematics<'_> {
        crate::actor::reach::PointKinematics {
            position: self.position,
            velocity: self.velocity,
            acceleration: self.acceleration,
            velocity_columns: &self.velocity_columns[..r],
            acceleration_columns: &self.acceleration_columns[..r],
        }
    }
}

/// The ego's points (a footprint's covering circles, or the planar position) that barriers
/// around road users measure from, and what each does at the last state measured: two probe
/// barriers each (module docs).
pub(super) struct EgoPoints {
    /// One probe barrier per ego point (radius 0, centre set per measurement).
    probes: Vec<Barrier>,
    points: Vec<PointMotion>,
    /// The state `points` were measured at (NaN: none; NaN equals nothing).
    measured_at: Vec<f64>,
    lie: LieWorkspace,
}

/// Which road users are out of reach, per evaluation.
pub(super) struct Reach {
    groups: Vec<Group>,
    /// Per known barrier: its ego point (an index into `ego`), None for barriers never left
    /// out (not a moving road user's circle).
    point_of: Vec<Option<usize>>,
    radius: Vec<f64>,
    /// Per known barrier: its circle's offset from its road user's centre.
    offsets: Vec<[f64; 2]>,
    /// Per road user, per ego point its barriers measure from: the largest radius of those
    /// barriers (the group's gap bound takes one distance per point).
    gap_terms: Vec<(usize, f64)>,
    ego: EgoPoints,
    /// Per ego point, W and B for the current bound.
    input_reach: Vec<[f64; 2]>,
    /// Per known barrier: left out at the last evaluation.
    pub(super) out: Vec<bool>,
    /// Per known barrier k: how many barriers before k have a mixed relative degree (and so a
    /// first-order row in a form with real rates), and the count over all at the end.
    mixed_before: Vec<u64>,
    /// Scratch space of [`Reach::still_out`].
    scratch_out: Vec<bool>,
    /// M_j per channel: the largest recent |u_j| of a command or nominal input.
    largest_input: Vec<f64>,
    /// M_j when the current decision began.
    bound: Vec<f64>,
    /// Whether rows may be left out (false while a decision is made again with every row).
    pub(super) enabled: bool,
    /// Rows formed and left out over the run by the decisions that stand (the run's summary
    /// reports them), and by the current decision's attempt.
    pub(super) rows_left_out: u64,
    pub(super) rows_formed: u64,
    attempt_rows: [u64; 2],
    /// Decisions made again (an input above the bound U, or one not said).
    pub(super) redone: u64,
    /// Whether the last [`Reach::mark`] left rows out, and whether some group may.
    culled_last: bool,
    /// Whether the last [`Reach::mark`] kept the nearest road user because every row would
    /// have gone.
    kept_nearest: bool,
    active: bool,
    /// Whether some known barrier is never left out (its rows stay in every QP).
    keeps_a_row: bool,
    allowed: bool,
    /// Whether an input of the current decision exceeded its channel's admissible U_j (the
    /// bound its left-out rows were checked for), and the commands it started from.
    exceeded: bool,
    /// Whether the current decision used an input it does not say (noted as NaN).
    unknown: bool,
    saved: Vec<f64>,
    /// The current epoch, if one has begun ([`Epoch`]), and how many have.
    epoch: Option<Epoch>,
    epochs: u64,
    /// Road-user tests an asleep road user's one distance stood for.
    slept: u64,
}

impl Reach {
    /// For `model`, with M starting at the largest initial input in `queues`.
    pub(super) fn new(model: &dyn Dynamics, queues: &[DelayQueue]) -> Reach {
        let largest_input: Vec<f64> = queues
            .iter()
            .map(|q| q.issued().map(|(_, value)| value.abs()).fold(0.0, f64::max))
            .collect();
        Reach {
            groups: Vec::new(),
            point_of: Vec::new(),
            radius: Vec::new(),
            offsets: Vec::new(),
            gap_terms: Vec::new(),
            ego: EgoPoints::new(model),
            input_reach: Vec::new(),
            out: Vec::new(),
            mixed_before: vec![0],
            scratch_out: Vec::new(),
            bound: largest_input.clone(),
            largest_input,
            enabled: true,
            culled_last: false,
            kept_nearest: false,
            active: false,
            keeps_a_row: false,
            allowed: true,
            exceeded: false,
            unknown: false,
            saved: vec![0.0; queues.len()],
            epoch: None,
            epochs: 0,
            slept: 0,
            rows_left_out: 0,
            rows_formed: 0,
            attempt_rows: [0; 2],
            redone: 0,
        }
    }

    /// Registers the next known barrier: a moving road user's (`offset` from its centre,
    /// `primary` for its first) or not (`None`).
    pub(super) fn add(&mut self, barrier: &Barrier, road_user: Option<([f64; 2], bool)>) {
        let index = self.point_of.len();
        self.epoch = None;
        self.out.push(false);
        let mixed = self.mixed_before[index] + u64::from(barrier.mixed_relative_degree());
        self.mixed_before.push(mixed);
        let point = road_user.and_then(|_| self.ego.index_of(barrier));
        self.input_reach.resize(self.ego.len(), [0.0; 2]);
        self.point_of.push(point);
        self.radius.push(match &barrier.shape {
            Shape::Ball { radius, .. } | Shape::BodyCircle { radius, .. } => *radius,
            _ => f64::NAN,
        });
        self.offsets.push(road_user.map_or([0.0; 2], |(offset, _)| offset));
        let Some((offset, primary)) = road_user else {
            self.refresh_active();
            return;
        };
        let spread = offset[0].hypot(offset[1]);
        match (primary, self.groups.last_mut()) {
            (false, Some(group)) if group.end == index => {
                group.end += 1;
                group.spread = group.spread.max(spread);
                group.cullable &= point.is_some();
            }
            _ => self.groups.push(Group {
                first: index,
                end: index + 1,
                spread,
                cullable: point.is_some(),
                terms: [self.gap_terms.len(); 2],
                largest_radius: 0.0,
                was_out: false,
                asleep: None,
                sleep_tried: false,
            }),
        }
        let (Some(group), Some(i)) = (self.groups.last_mut(), point) else {
            self.refresh_active();
            return;
        };
        let radius = self.radius[index];
        group.largest_radius = group.largest_radius.max(radius);
        match (self.gap_terms[group.terms[0]..group.terms[1]].iter_mut()).find(|(point, _)| *point == i) {
            Some((_, largest)) => *largest = largest.max(radius),
            None => {
                self.gap_terms.push((i, radius));
                group.terms[1] += 1;
            }
        }
        self.refresh_active();
    }

    /// active ← whether a decision could ever leave rows out: a road user that may be, and
    /// some other row to keep (the nearest road user is kept when every row would go).
    fn refresh_active(&mut self) {
        let cullable = self.groups.iter().filter(|g| g.cullable).count();
        let in_cullable: usize = self.groups.iter().filter(|g| g.cullable).map(|g| g.end - g.first).sum();
        self.keeps_a_row = in_cullable < self.point_of.len();
        self.active = self.allowed && (cullable >= 2 || (cullable == 1 && self.keeps_a_row));
    }

    /// Whether a formed row (and its first-order row) holds for every admissible input,
    /// a − Σ_j |b_j| U_j > 0 with U_j = 1.1 M_j, the box [`Reach::mark`]'s certificate is for (a
    /// margin of 1e-9 of its terms for the rounding): then it may be left out of the QP as a
    /// row out of reach is ([`Reach::leave_out`]). Only where some other barrier's row always
    /// stays (the road's edges), so that a decision never has no row.
    pub(super) fn holds_for_every_admissible_input(&self, row: &Constraint, first_order: Option<&Constraint>) -> bool {
        if !(self.enabled && self.active && self.keeps_a_row) {
            return false;
        }
        // (Over slices: an iterator chain over the rows and nalgebra's iterators cost several
        // times the arithmetic, for every pair row formed.)
        let holds = |row: &Constraint| {
            let b = row.b.as_slice();
            let mut spread = 0.0;
            for (b, m) in b.iter().zip(&self.bound) {
                spread += (b * BOUND_FACTOR * m).abs();
            }
            b.len() <= self.bound.len() && row.a - spread > 1e-9 * (row.a.abs() + spread)
        };
        holds(row) && first_order.is_none_or(holds)
    }

    /// Leaves barrier k's formed rows (`rows`: its row, and its first-order row if it has one)
    /// out of the QP: they hold for every admissible input.
    pub(super) fn leave_out(&mut self, k: usize, rows: u64) {
        self.out[k] = true;
        self.culled_last = true;
        self.count_rows(0, rows);
    }

    /// Counts the rows of the run of barriers left out by the last [`Reach::mark`] that
    /// starts at barrier k (up to `count`) as left out, each with its first-order row when the
    /// form has real rates (`rates`); returns the barrier after the run.
    pub(super) fn leave_out_run(&mut self, k: usize, count: usize, rates: bool) -> usize {
        let end = (self.out[k..count].iter().position(|&out| !out)).map_or(count, |n| k + n);
        let first_order = if rates {
            self.mixed_before[end] - self.mixed_before[k]
        } else {
            0
        };
        self.count_rows(0, (end - k) as u64 + first_order);
        end
    }

    /// Whether rows may be left out at all (`control.leave_out_of_reach`).
    pub(super) fn set_allowed(&mut self, allowed: bool) {
        self.allowed = allowed;
        self.refresh_active();
    }

    /// Rows formed and left out by the current attempt (counted for the run when the decision
    /// stands; at once when no decision is ever made again).
    pub(super) fn count_rows(&mut self, formed: u64, left_out: u64) {
        if self.active {
            self.attempt_rows[0] += formed;
            self.attempt_rows[1] += left_out;
        } else {
            self.rows_formed += formed;
            self.rows_left_out += left_out;
        }
    }

    /// Whether some road user's rows may be left out (else decisions need no bookkeeping).
    pub(super) fn active(&self) -> bool {
        self.active
    }

    /// out ← which barriers are out of reach at z (the state at time `at`), in `form`, with each
    /// road user where `assumed(k)` puts the centre of the one whose primary barrier is k; `r`
    /// input channels. Returns whether any is.
    pub(super) fn mark(
        &mut self,
        model: &dyn Dynamics,
        form: BarrierForm,
        z: &[f64],
        r: usize,
        assumed: impl Fn(usize) -> ActorState,
        sleep: Option<SleepAt<'_>>,
    ) -> bool {
        self.out.fill(false);
        self.culled_last = false;
        // (Up to four input channels: the probes keep their rows on the stack.)
        if !self.enabled || r > 4 || !self.active {
            return self.leave_out_parked(&assumed);
        }
        self.ego.measure(model, z);
        // W and B of each ego point for |u_j| ≤ U_j.
        let admissible = |gains: &[f64; 4]| {
            gains
                .iter()
                .zip(&self.bound)
                .map(|(g, m)| BOUND_FACTOR * g * m)
                .sum::<f64>()
        };
        for (reach, p) in self.input_reach.iter_mut().zip(&self.ego.points) {
            *reach = [admissible(&p.velocity_gains), admissible(&p.acceleration_gains)];
        }
        let envelope = EgoEnvelope::of(&self.ego.points, &self.input_reach);
        let rates = form.real_rates();
        // Whether this evaluation keeps within an epoch's bounds: then asleep road users are
        // tested with one distance, and road users the far test leaves out may fall asleep.
        let epoch = self.enter_epoch(envelope.as_ref(), form, sleep.as_ref());
        let mut any = false;
        // The nearest road user left out: kept when every row would be (a filter with known
        // barriers always decides).
        let mut nearest: Option<(f64, usize, usize)> = None;
        let Reach {
            groups,
            point_of,
            radius,
            offsets,
            gap_terms,
            ego,
            input_reach,
            out,
            ..
        } = self;
        let geometry = BarrierGeometry {
            point_of,
            radius,
            offsets,
            gap_terms,
        };
        // Road users that do not exist where assumed (parked) are out without a test; only when
        // every row is out and no road user that exists is, their gaps name the nearest (the
        // one every road user's group test gave: parked ones are farther than any other).
        let mut parked_any = false;
        // Whether a road user left out by the far test (its gap not measured) is all out.
        let mut far_out = false;
        for skip_parked in [true, false] {
            for group in groups.iter_mut().filter(|g| g.cullable) {
                if let (Some(asleep), Some(envelope)) = (group.asleep.filter(|_| epoch.is_some()), &envelope) {
                    // (Asleep: not parked, so the second pass passes it over too.)
                    if !skip_parked || asleep.sleeps(envelope) {
                        if skip_parked {
                            self.slept += 1;
                            out[group.first..group.end].fill(true);
                            (far_out, any, group.was_out) = (true, any || group.end > group.first, true);
                        }
                        continue;
                    }
                }
                let actor = assumed(group.first);
                if !skip_parked && !actor.is_parked() {
                    continue;
                }
                let parts = (&ego.points[..], &input_reach[..]);
                let far = envelope.as_ref().filter(|_| skip_parked && group.was_out);
                let gap = match mark_group(
                    group,
                    geometry,
                    parts,
                    (form, rates, far),
                    (actor, &assumed, skip_parked),
                    out,
                ) {
                    GroupGap::Parked => {
                        (parked_any, any) = (true, any || group.end > group.first);
                        continue;
                    }
                    GroupGap::Far => {
                        (far_out, any) = (true, any || group.end > group.first);
                        fall_asleep(group, epoch.as_ref(), sleep.as_ref(), rates);
                        continue;
                    }
                    GroupGap::Measured(gap) => gap,
                };
                any |= out[group.first..group.end].iter().any(|&out| out);
                let all_out = out[group.first..group.end].iter().all(|&out| out);
                group.was_out = all_out;
                if all_out && nearest.is_none_or(|(nearest, ..)| gap < nearest) {
                    nearest = Some((gap, group.first, group.end));
                }
            }
            if !(parked_any && nearest.is_none() && !far_out && out.iter().all(|&out| out)) {
                break;
            }
        }
        self.kept_nearest = false;
        if far_out && self.out.iter().all(|&out| out) {
            // (Rare: every row out. The nearest as the loop above would have named it, every
            // road user that exists measured.)
            nearest = self.nearest_of_all(&assumed);
        }
        if let (true, Some((_, first, end))) = (self.out.iter().all(|&out| out), nearest) {
            self.out[first..end].fill(false);
            any = self.out.iter().any(|&out| out);
            self.kept_nearest = true;
        }
        self.culled_last = any;
        any
    }

    /// The epoch this evaluation (at `sleep.at`, with the ego `envelope`, in `form`) keeps
    /// within: the current one, or a new one begun here (every road user awake) when the
    /// observation changed or the ego left the current one's bounds; None (no road user
    /// sleeps at this evaluation) without an envelope or `sleep`, or beyond the look-ahead.
    fn enter_epoch(
        &mut self,
        envelope: Option<&EgoEnvelope>,
        form: BarrierForm,
        sleep: Option<&SleepAt<'_>>,
    ) -> Option<Epoch> {
        let (Some(e), Some(sleep)) = (envelope, sleep) else {
            return None;
        };
        let ahead = (sleep.at - sleep.now).max(0.0);
        if ahead > sleep.span || sleep.span.is_nan() {
            return None;
        }
        let off = |a: [f64; 2], b: [f64; 2]| norm([a[0] - b[0], a[1] - b[1]]);
        let within = |epoch: &Epoch| {
            epoch.now == sleep.now
                && ahead <= epoch.span
                && epoch.form == form
                && off(e.velocity, epoch.velocity) + e.velocity_spread <= epoch.velocity_deviation
                && off(e.mean_acceleration, epoch.acceleration) + e.acceleration_spread <= epoch.acceleration_deviation
                && e.input_reach[0] <= epoch.input_reach[0]
                && e.input_reach[1] <= epoch.input_reach[1]
        };
        if let Some(epoch) = self.epoch.filter(within) {
            return Some(epoch);
        }
        // The ego left the bounds of an epoch of this observation: the next holds it to what
        // its accelerations allow over the look-ahead (braking by (4.67) moves v̄ by metres per
        // second), so that it does not begin again at every evaluation.
        let widen = self.epoch.is_some_and(|epoch| epoch.now == sleep.now);
        let change = (norm(e.mean_acceleration) + e.acceleration_spread + e.input_reach[1]) * sleep.span;
        let grow = |value: f64, (factor, added): (f64, f64), wide: f64| match widen {
            true => 2.0 * value * factor + added.max(wide),
            false => value * factor + added,
        };
        let epoch = Epoch {
            now: sleep.now,
            span: sleep.span,
            form,
            velocity: e.velocity,
            velocity_deviation: grow(e.velocity_spread, EPOCH_GROWTH[0], change),
            acceleration: e.mean_acceleration,
            acceleration_deviation: grow(e.acceleration_spread, EPOCH_GROWTH[1], e.input_reach[1]),
            input_reach: e.input_reach.map(|w| grow(w, EPOCH_GROWTH[2], w)),
        };
        for group in &mut self.groups {
            (group.asleep, group.sleep_tried) = (None, false);
        }
        self.epochs += 1;
        self.epoch = Some(epoch);
        self.epoch
    }

    /// The nearest road user that exists, as [`Reach::mark`]'s loop names it when every row is
    /// out: the first cullable group of the least gap (its measured gap, [`group_gap`]).
    fn nearest_of_all(&self, assumed: &impl Fn(usize) -> ActorState) -> Option<(f64, usize, usize)> {
        let mut nearest: Option<(f64, usize, usize)> = None;
        for group in self.groups.iter().filter(|g| g.cullable) {
            let actor = assumed(group.first);
            if actor.is_parked() {
                continue;
            }
            let gap = group_gap(group, &self.gap_terms, &self.ego.points, &actor);
            if nearest.is_none_or(|(nearest, ..)| gap < nearest) {
                nearest = Some((gap, group.first, group.end));
            }
        }
        nearest
    }

    /// Where no row may be left out for being out of reach (a decision made again with every
    /// row, `control.leave_out_of_reach = false`, more than four inputs): the road users that do
    /// not exist where assumed (parked) are still out, without a test, since a barrier around a
    /// road user that does not exist is no constraint (its rows, of h ≈ 3·10¹⁹ m², moved the QP's
    /// fallback by 7e-5 m/s² on Peach); unless every row would be. They hold for every input, so
    /// they never call for a decision to be made again (`culled_last` stays false). Returns
    /// whether any is out.
    fn leave_out_parked(&mut self, assumed: &impl Fn(usize) -> ActorState) -> bool {
        let mut any = false;
        for group in &self.groups {
            if assumed(group.first).is_parked() {
                self.out[group.first..group.end].fill(true);
                any |= group.end > group.first;
            }
        }
        if any && self.out.iter().all(|&out| out) {
            self.out.fill(false);
            return false;
        }
        any
    }

    /// Measures the ego points at z (once per state) when the model has at most four inputs
    /// (the points keep four columns); returns whether it did: then [`Reach::point`] holds.
    pub(super) fn measure_points(&mut self, model: &dyn Dynamics, z: &[f64]) -> bool {
        let measurable = model.input_dim() <= 4 && self.ego.len() > 0;
        if measurable {
            self.ego.measure(model, z);
        }
        measurable
    }

    /// Barrier k's ego point as last measured ([`Reach::measure_points`]), and the barrier's
    /// radius, when k is a road user's circle against an ego point; None otherwise.
    pub(super) fn point(&self, k: usize) -> Option<(&PointMotion, f64)> {
        self.point_of[k].map(|i| (&self.ego.points[i], self.radius[k]))
    }

    /// A decision begins: its left-out rows are checked for the M_j of now; keeps `inputs` (the
    /// commands it starts from) for [`Reach::restore`].
    pub(super) fn begin_decision(&mut self, inputs: &[f64]) {
        (self.exceeded, self.unknown) = (false, false);
        self.attempt_rows = [0; 2];
        self.bound.copy_from_slice(&self.largest_input);
        self.saved[..inputs.len()].copy_from_slice(inputs);
        self.note(inputs.iter().copied().enumerate());
        // M_j forgets ([`FORGET`]): the bound follows the inputs now, and a decision above it
        // is made again.
        for m in &mut self.largest_input {
            *m *= FORGET;
        }
    }

    /// The decision used these inputs, (channel, value): u0 and its commands.
    pub(super) fn note(&mut self, inputs: impl Iterator<Item = (usize, f64)>) {
        for (j, value) in inputs {
            let magnitude = value.abs();
            self.unknown |= magnitude.is_nan();
            // (The left-out rows hold for every |u_j| ≤ U_j: `mark`'s W and B.)
            self.exceeded |= magnitude.is_nan() || magnitude > BOUND_FACTOR * self.bound[j];
            self.largest_input[j] = self.largest_input[j].max(magnitude);
        }
    }

    /// Whether the decision, which used the inputs noted since [`Reach::begin_decision`], must
    /// be made again (it left rows out and an input exceeded its channel's bound): with the
    /// bound grown to those inputs (`attempt` 0 and 1, finite inputs), else with every row
    /// (culling disabled until the caller sets `enabled` again).
    pub(super) fn again(&mut self, attempt: usize) -> bool {
        let again = self.culled_last && self.exceeded;
        let [formed, left_out] = std::mem::take(&mut self.attempt_rows);
        if again {
            self.redone += 1;
            self.exceeded = false;
            if attempt < 2 && !std::mem::take(&mut self.unknown) {
                self.bound.copy_from_slice(&self.largest_input);
            } else {
                self.enabled = false;
            }
        } else {
            self.rows_formed += formed;
            self.rows_left_out += left_out;
        }
        again
    }

    /// inputs ← what [`Reach::begin_decision`] kept.
    pub(super) fn restore(&self, inputs: &mut [f64]) {
        inputs.copy_from_slice(&self.saved[..inputs.len()]);
    }
}

/// What the reach test of one law saw at its evaluation state: the time, the ego points and
/// their input bounds, the barrier form, and per barrier whether the law formed its rows (all,
/// when it left none out or kept the nearest road user): [`Reach::still_out`] tests a road user
/// again there under another assumption.
#[derive(Default, Clone)]
pub(super) struct ReachAt {
    pub(super) time: f64,
    points: Vec<PointMotion>,
    input_reach: Vec<[f64; 2]>,
    form: Option<(BarrierForm, Option<(f64, f64)>)>,
    formed: Vec<bool>,
}

impl ReachAt {
    /// Room for this many barriers and ego points (so that recording allocates nothing).
    pub(super) fn reserve(&mut self, (barriers, points): (usize, usize)) {
        self.formed.reserve(barriers.saturating_sub(self.formed.len()));
        self.points.reserve(points.saturating_sub(self.points.len()));
        self.input_reach.reserve(points.saturating_sub(self.input_reach.len()));
    }
}

impl Reach {
    /// (known barriers, ego points): what a [`ReachAt`] records.
    pub(super) fn sizes(&self) -> (usize, usize) {
        (self.out.len(), self.ego.len())
    }

    /// `node` ← what the last [`Reach::mark`] (made at `time`, in `form`) saw and left out.
    pub(super) fn record(&self, time: f64, form: Option<BarrierForm>, node: &mut ReachAt) {
        let culled = self.culled_last && !self.kept_nearest;
        node.time = time;
        node.points.clone_from(&self.ego.points);
        node.input_reach.clone_from(&self.input_reach);
        node.form = form.map(|form| (form, form.real_rates()));
        node.formed.clear();
        node.formed.extend(self.out.iter().map(|&out| !(culled && out)));
    }

    /// The road user whose primary barrier is `first` (the groups are in barrier order).
    fn group_of(&self, first: usize) -> Option<Group> {
        let i = self.groups.partition_point(|g| g.first < first);
        self.groups.get(i).filter(|g| g.first == first).copied()
    }

    /// Whether the law `node` records may have formed a row of the road user whose primary
    /// barrier is `first` (it did, or its rows are never left out, or the law has no form):
    /// then [`Reach::still_out`] is false without a test.
    pub(super) fn formed_in(&self, node: &ReachAt, first: usize) -> bool {
        let Some(group) = self.group_of(first) else {
            return true;
        };
        !group.cullable
            || node.form.is_none()
            || (node.formed.get(group.first..group.end)).is_none_or(|formed| formed.iter().any(|&f| f))
    }

    /// Whether the road user whose primary barrier is `first` had no row in the law `node`
    /// records and is out of reach there as a whole when barrier k's road user is at
    /// `assumed(k)` ([`Reach::mark`]'s test, with the law's own ego points and input bounds):
    /// then its rows are in that law under neither assumption.
    pub(super) fn still_out(&mut self, node: &ReachAt, first: usize, assumed: impl Fn(usize) -> ActorState) -> bool {
        if self.formed_in(node, first) {
            return false;
        }
        let (Some(group), Some((form, rates))) = (self.group_of(first), node.form) else {
            return false;
        };
        let range = group.first..group.end;
        self.scratch_out.clear();
        self.scratch_out.resize(self.out.len(), false);
        mark_group(
            &group,
            BarrierGeometry {
                point_of: &self.point_of,
                radius: &self.radius,
                offsets: &self.offsets,
                gap_terms: &self.gap_terms,
            },
            (&node.points, &node.input_reach),
            (form, rates, None),
            (assumed(group.first), &assumed, true),
            &mut self.scratch_out,
        );
        self.scratch_out[range].iter().all(|&out| out)
    }
}

/// What [`mark_group`] reads of the known barriers ([`Reach`]'s fields of the same names).
#[derive(Clone, Copy)]
struct BarrierGeometry<'a> {
    point_of: &'a [Option<usize>],
    radius: &'a [f64],
    offsets: &'a [[f64; 2]],
    gap_terms: &'a [(usize, f64)],
}

/// ‖v‖ (sqrt, not hypot: the states are bounded by ±1e9, so the squares cannot overflow).
#[inline]
fn norm(v: [f64; 2]) -> f64 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

/// The least gap at which a road user's rows hold with no closing term, speed V, acceleration
/// A and the epoch's W and B (the bracket conditions of [`rows_hold_given`]: l0 D ≥ 2K and
/// l0 D² − 2K D ≥ 2VW with K = A + |l1| V + B + λ1 W, and λ1 D ≥ 2(V + W) for a first-order
/// row; α D ≥ 2(V + W) at relative degree 1), grown by a relative 1e-12 so that it passes;
/// None when the form gives no margin.
fn least_far_gap(epoch: &Epoch, speed: f64, acceleration: f64, rates: Option<(f64, f64)>) -> Option<f64> {
    let [w, b] = epoch.input_reach;
    let first_order = |rate: f64| (rate > 0.0).then(|| 2.0 * (speed + w) / rate);
    let gap = match epoch.form {
        BarrierForm::RelativeDegree1 { alpha } => first_order(alpha)?,
        BarrierForm::RelativeDegree2 { l0, l1 } => {
            let lambda1 = rates.map_or(0.0, |(lambda1, _)| lambda1);
            let k = acceleration + l1.abs() * speed + b + lambda1 * w;
            if l0 <= 0.0 || l0.is_nan() {
                return None;
            }
            let quadratic = (k + (k * k + 2.0 * l0 * speed * w).sqrt()) / l0;
            match rates {
                Some((lambda1, _)) => quadratic.max(first_order(lambda1)?),
                None => quadratic,
            }
        }
    };
    (gap.is_finite() && gap <= MOST_SLEEP_GAP).then(|| gap.max(f64::MIN_POSITIVE) * (1.0 + 1e-12) + 1e-12)
}

/// The least gap for which `holds` (monotone in the gap) does, to a relative 2⁻¹⁶ on the
/// passing side: doubled from 1 m up to a passing gap, then the interval halved; None above
/// [`MOST_SLEEP_GAP`].
fn least_gap_by_halving(holds: impl Fn(f64) -> bool) -> Option<f64> {
    let mut high = 1.0;
    while !holds(high) {
        high *= 2.0;
        if high > MOST_SLEEP_GAP {
            return None;
        }
    }
    let mut low = 0.0;
    for _ in 0..16 {
        let middle = 0.5 * (low + high);
        match holds(middle) {
            true => high = middle,
            false => low = middle,
        }
    }
    Some(high)
}

/// A road user the far test left out may fall asleep for the rest of `epoch`: tried once per
/// epoch ([`Asleep::of`]; after the group test, a road user only just out would be tried too
/// early: fewer slept on the CommonRoad files).
fn fall_asleep(group: &mut Group, epoch: Option<&Epoch>, sleep: Option<&SleepAt<'_>>, rates: Option<(f64, f64)>) {
    if let (Some(epoch), Some(sleep)) = (epoch, sleep) {
        if !std::mem::replace(&mut group.sleep_tried, true) {
            let window = (sleep.window)(group.first, group.end, 0.0, epoch.span);
            group.asleep = window.and_then(|w| Asleep::of(group, epoch, &w, rates));
        }
    }
}

impl Asleep {
    /// `group` asleep for `epoch`, its assumed states over the epoch's look-aheads bounded by
    /// `window`: the least gap (to a relative 2⁻¹⁶, on the passing side) at which its rows hold
    /// with V = ‖v̄ − ȯ‖ + its velocity change over the window + the epoch's velocity deviation,
    /// and A likewise (v̄, ā the epoch's, ȯ, ö the road user's at the window's middle; each
    /// grown by twice the far test's slack), and the epoch's W and B; None when parked or when
    /// no gap up to [`MOST_SLEEP_GAP`] does.
    fn of(group: &Group, epoch: &Epoch, window: &AssumedWindow, rates: Option<(f64, f64)>) -> Option<Asleep> {
        let actor = &window.middle;
        if actor.is_parked() || !(window.displacement.is_finite() && window.velocity_change.is_finite()) {
            return None;
        }
        let rho = group.spread;
        let (w, dw) = (actor.yaw_rate.abs(), actor.yaw_acceleration.abs());
        let up = 1.0 + 2.0 * FAR_SLACK;
        let off = |a: [f64; 2], b: [f64; 2]| norm([a[0] - b[0], a[1] - b[1]]);
        let speed = off(epoch.velocity, actor.velocity) + window.velocity_change + epoch.velocity_deviation;
        let acceleration = off(epoch.acceleration, actor.acceleration) + epoch.acceleration_deviation;
        let (speed, acceleration) = ((speed + w * rho) * up, (acceleration + (dw + w * w) * rho) * up);
        let holds = |gap: f64| {
            let bounds = ReachBounds {
                gap,
                speed,
                acceleration,
                closing: f64::MIN,
                input_speed: epoch.input_reach[0],
                input_acceleration: epoch.input_reach[1],
            };
            rows_hold_given(&bounds, epoch.form, rates)
        };
        // With no closing term only the bracket rows can hold ((4.85)–(4.86) with every bound
        // at its worst): the least gap in closed form, checked; else (rounding at the root) by
        // halving, rows_hold_given being monotone in the gap.
        let threshold = least_far_gap(epoch, speed, acceleration, rates)
            .filter(|&gap| holds(gap))
            .or_else(|| least_gap_by_halving(holds))?;
        Some(Asleep {
            centre: actor.position,
            reach: window.displacement + rho + group.largest_radius,
            threshold,
        })
    }

    /// Whether it sleeps through an evaluation of its epoch with the ego `envelope`: the far
    /// test's gap there, at least m − reach − s − ε(m + reach + s + 1) (m the distance from the
    /// envelope's centre to `centre`, s its spread, ε the far test's slack), is above the
    /// threshold with a margin of ε(m + reach + s + 1), and its other bounds are within those
    /// the threshold was found for (‖v̄_now − ȯ(at)‖ + the spread ≤ ‖v̄ − ȯ_middle‖ + the
    /// velocity change + the deviation, and likewise A): the far test leaves it out.
    #[inline]
    fn sleeps(&self, envelope: &EgoEnvelope) -> bool {
        let m = norm([envelope.centre[0] - self.centre[0], envelope.centre[1] - self.centre[1]]);
        let reduce = self.reach + envelope.spread;
        m - reduce - 2.0 * FAR_SLACK * (m + reduce + 1.0) >= self.threshold
    }
}

/// What [`mark_group`] found of a road user's gap.
enum GroupGap {
    /// Parked where it does not exist (skipped: no rows, no bounds formed).
    Parked,
    /// Out as a whole by the far test ([`EgoEnvelope`]); its gap not measured.
    Far,
    /// The group's gap bound D (module docs).
    Measured(f64),
}

/// Bounds of every ego point at one evaluation, for a test of a road user against all of them
/// at once (the far test of [`mark_group`]): the points' centroid c and the largest ‖q_i − c‖,
/// the largest ‖q̇₀_i‖ and ‖q̈₀_i‖, the mean q̇₀ and q̈₀ with the largest distance of a point's
/// from them, and the largest W and B.
struct EgoEnvelope {
    centre: [f64; 2],
    spread: f64,
    speed: f64,
    acceleration: f64,
    velocity: [f64; 2],
    velocity_spread: f64,
    mean_acceleration: [f64; 2],
    acceleration_spread: f64,
    input_reach: [f64; 2],
}

/// Relative slack of the far test's bounds, far above the rounding of the sums they bound:
/// what it leaves out the pair and group tests leave out too, bit for bit.
const FAR_SLACK: f64 = 1e-9;

impl EgoEnvelope {
    /// The envelope of `points` with their input bounds (the same maxima as [`mark_group`]'s);
    /// None without points or with any value not finite (then no far test).
    fn of(points: &[PointMotion], input_reach: &[[f64; 2]]) -> Option<EgoEnvelope> {
        let n = points.len() as f64;
        let mean = |of: fn(&PointMotion) -> [f64; 2]| {
            let sum = points.iter().map(of).fold([0.0; 2], |s, v| [s[0] + v[0], s[1] + v[1]]);
            [sum[0] / n, sum[1] / n]
        };
        let (centre, velocity) = (mean(|p| p.position), mean(|p| p.velocity));
        let mut envelope = EgoEnvelope {
            centre,
            spread: 0.0,
            speed: 0.0,
            acceleration: 0.0,
            velocity,
            velocity_spread: 0.0,
            mean_acceleration: mean(|p| p.acceleration),
            acceleration_spread: 0.0,
            input_reach: [f64::NEG_INFINITY; 2],
        };
        let mut finite = !points.is_empty();
        let from = |v: [f64; 2], mean: [f64; 2]| norm([v[0] - mean[0], v[1] - mean[1]]);
        for (p, reach) in points.iter().zip(input_reach) {
            let values = [
                from(p.position, centre),
                norm(p.velocity),
                norm(p.acceleration),
                from(p.velocity, velocity),
                from(p.acceleration, envelope.mean_acceleration),
            ];
            finite &= values.iter().chain(reach).all(|v| v.is_finite());
            envelope.spread = envelope.spread.max(values[0]);
            envelope.speed = envelope.speed.max(values[1]);
            envelope.acceleration = envelope.acceleration.max(values[2]);
            envelope.velocity_spread = envelope.velocity_spread.max(values[3]);
            envelope.acceleration_spread = envelope.acceleration_spread.max(values[4]);
            envelope.input_reach[0] = envelope.input_reach[0].max(reach[0]);
            envelope.input_reach[1] = envelope.input_reach[1].max(reach[1]);
        }
        finite.then_some(envelope)
    }

    /// Bounds of a road user (at `actor`, its circles within `rho` of its centre turning at
    /// `turning` = (speed, acceleration) terms, radii up to `largest_radius`) against every ego
    /// point: D from the centroid; V and A by the triangle inequality, the lesser of
    /// ‖q̇₀_i‖ + ‖ȯ‖ and ‖v̄ − ȯ‖ + ‖q̇₀_i − v̄‖ (v̄ the points' mean; the second is the
    /// smaller for a road user moving with the ego); no closing term. Each is on the safe side
    /// of the group test's by the slack, so that a pass here is a pass there.
    fn bounds(&self, actor: &ActorState, rho: f64, turning: (f64, f64), largest_radius: f64) -> ReachBounds {
        let distance = norm([self.centre[0] - actor.position[0], self.centre[1] - actor.position[1]]);
        let reduce = self.spread + rho + largest_radius;
        let up = 1.0 + FAR_SLACK;
        let relative = |mean: [f64; 2], of: [f64; 2]| norm([mean[0] - of[0], mean[1] - of[1]]);
        let speed =
            (self.speed + norm(actor.velocity)).min(relative(self.velocity, actor.velocity) + self.velocity_spread);
        let acceleration = (self.acceleration + norm(actor.acceleration))
            .min(relative(self.mean_acceleration, actor.acceleration) + self.acceleration_spread);
        ReachBounds {
            gap: distance - reduce - FAR_SLACK * (distance + reduce + 1.0),
            speed: (speed + turning.0) * up,
            acceleration: (acceleration + turning.1) * up,
            closing: f64::MIN,
            input_speed: self.input_reach[0],
            input_acceleration: self.input_reach[1],
        }
    }
}

/// The group's gap bound D: the least ‖q_i − o‖ − ρ − r_k over its barriers, one term per ego
/// point (`actor` its centre), as [`mark_group`] measures it.
fn group_gap(group: &Group, gap_terms: &[(usize, f64)], points: &[PointMotion], actor: &ActorState) -> f64 {
    let mut gap = f64::INFINITY;
    for &(i, largest_radius) in &gap_terms[group.terms[0]..group.terms[1]] {
        let p = &points[i];
        let d = [p.position[0] - actor.position[0], p.position[1] - actor.position[1]];
        gap = gap.min(norm(d) - group.spread - largest_radius);
    }
    gap
}

/// Which of `group`'s barriers are out of reach, written into `out` (indexed by barrier): the
/// road user as a whole against every ego point at once (`far`, when given), else from its
/// centre and spread, else pair by pair (module docs), for the ego points `points` and their
/// input bounds `input_reach` (W and B), with barrier k's road user at `assumed(k)` (`actor` =
/// `assumed(group.first)`). Parked, with every barrier out, for a road user parked at `actor`
/// when `skip_parked` (it does not exist).
fn mark_group(
    group: &Group,
    geometry: BarrierGeometry<'_>,
    (points, input_reach): (&[PointMotion], &[[f64; 2]]),
    (form, rates, far): (BarrierForm, Option<(f64, f64)>, Option<&EgoEnvelope>),
    (actor, assumed, skip_parked): (ActorState, &impl Fn(usize) -> ActorState, bool),
    out: &mut [bool],
) -> GroupGap {
    let BarrierGeometry {
        point_of,
        radius,
        offsets,
        gap_terms,
    } = geometry;
    if skip_parked && actor.is_parked() {
        out[group.first..group.end].fill(true);
        return GroupGap::Parked;
    }
    // A road user whose barriers see one state (a parked one: its primary's place) is tested
    // whole first; otherwise pair by pair only.
    let shared = group.end - group.first == 1 || assumed(group.end - 1) == actor;
    let rho = group.spread;
    let (w, dw) = (actor.yaw_rate.abs(), actor.yaw_acceleration.abs());
    // A circle at c from the centre: ȯ + θ̇ J R c and ö + θ̈ J R c − θ̇² R c (‖R c‖ ≤ ρ).
    let (turning_speed, turning_acceleration) = (w * rho, (dw + w * w) * rho);
    // Far: every bound below is within the envelope's (rows_hold_given is monotone in each).
    if let (true, Some(envelope)) = (shared, far) {
        let bounds = envelope.bounds(&actor, rho, (turning_speed, turning_acceleration), group.largest_radius);
        if rows_hold_given(&bounds, form, rates) {
            out[group.first..group.end].fill(true);
            return GroupGap::Far;
        }
    }
    let relative = |a: [f64; 2], b: [f64; 2]| norm([a[0] - b[0], a[1] - b[1]]);
    let mut bounds = ReachBounds {
        gap: f64::INFINITY,
        closing: f64::INFINITY,
        ..Default::default()
    };
    // Per ego point (every one: a superset of the group's, so the bounds still hold).
    for (i, p) in points.iter().enumerate() {
        let d = [p.position[0] - actor.position[0], p.position[1] - actor.position[1]];
        let w = [p.velocity[0] - actor.velocity[0], p.velocity[1] - actor.velocity[1]];
        let distance = norm(d);
        // d·w for a circle at c: (d_c − Rc)·(w_c − θ̇ J R c) ≥ d_c·w_c − ‖d_c‖ θ̇ρ − ρ‖w_c‖ − θ̇ρ².
        let closing = d[0] * w[0] + d[1] * w[1] - (distance + rho) * turning_speed - rho * norm(w);
        bounds.closing = bounds.closing.min(closing);
        bounds.speed = bounds.speed.max(norm(w) + turning_speed);
        let acceleration = relative(p.acceleration, actor.acceleration) + turning_acceleration;
        bounds.acceleration = bounds.acceleration.max(acceleration);
        bounds.input_speed = bounds.input_speed.max(input_reach[i][0]);
        bounds.input_acceleration = bounds.input_acceleration.max(input_reach[i][1]);
    }
    // (The least of ‖q_i − o‖ − ρ − r_k over the barriers, one term per ego point.)
    bounds.gap = group_gap(group, gap_terms, points, &actor);
    if shared && rows_hold_given(&bounds, form, rates) {
        out[group.first..group.end].fill(true);
    } else {
        // Pair by pair: each circle where the road user's state puts it, exactly.
        for k in group.first..group.end {
            let Some(p) = point_of[k].map(|i| &points[i]) else {
                continue;
            };
            let circle = match shared {
                true => actor.shifted(offsets[k]),
                false => assumed(k).shifted(offsets[k]),
            };
            let d = [p.position[0] - circle.position[0], p.position[1] - circle.position[1]];
            let w = [p.velocity[0] - circle.velocity[0], p.velocity[1] - circle.velocity[1]];
            let [input_speed, input_acceleration] = input_reach[point_of[k].unwrap_or(0)];
            let pair = ReachBounds {
                gap: norm(d) - radius[k],
                speed: norm(w),
                acceleration: relative(p.acceleration, circle.acceleration),
                closing: d[0] * w[0] + d[1] * w[1],
                input_speed,
                input_acceleration,
            };
            out[k] = rows_hold_given(&pair, form, rates);
        }
    }
    GroupGap::Measured(bounds.gap)
}

impl EgoPoints {
    pub(super) fn new(model: &dyn Dynamics) -> EgoPoints {
        EgoPoints {
            probes: Vec::new(),
            points: Vec::new(),
            measured_at: vec![f64::NAN; model.state_dim()],
            lie: LieWorkspace::new(model),
        }
    }

    /// How many points there are.
    pub(super) fn len(&self) -> usize {
        self.points.len()
    }

    /// Point i as last measured.
    pub(super) fn point(&self, i: usize) -> &PointMotion {
        &self.points[i]
    }

    /// The probe of the ego point a road user's barrier measures from (a new one for a new
    /// point); None for a barrier whose rows are never left out (a headway, an inner circle).
    pub(super) fn index_of(&mut self, barrier: &Barrier) -> Option<usize> {
        let probe = match &barrier.shape {
            Shape::Ball {
                indices, inside: false, ..
            } if indices.len() == 2 => Shape::Ball {
                indices: indices.clone(),
                centre: vec![0.0; 2],
                radius: 0.0,
                inside: false,
            },
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                inside: false,
                ..
            } => Shape::BodyCircle {
                position,
                heading,
                offset,
                centre: [0.0; 2],
                radius: 0.0,
                inside: false,
            },
            _ => return None,
        };
        let same = |b: &Barrier| match (&b.shape, &probe) {
            (Shape::Ball { indices: i, .. }, Shape::Ball { indices: j, .. }) => i == j,
            (
                Shape::BodyCircle {
                    position: p,
                    heading: h,
                    offset: o,
                    ..
                },
                Shape::BodyCircle {
                    position: q,
                    heading: g,
                    offset: c,
                    ..
                },
            ) => (p, h, o) == (q, g, c),
            _ => false,
        };
        if let Some(i) = self.probes.iter().position(same) {
            return Some(i);
        }
        let mut probe_barrier = barrier.clone();
        probe_barrier.shape = probe;
        self.probes.push(probe_barrier);
        self.points.push(PointMotion::default());
        self.measured_at.fill(f64::NAN);
        Some(self.probes.len() - 1)
    }

    /// points ← each ego point's position, |q̇₀|, |q̈₀|, ‖K‖ and ‖J‖ (Frobenius norms) at z, from
    /// its probe's Lie derivatives with the centre one metre behind q along x, then along y:
    /// L_f h = 2 d·q̇₀, L_f²h = 2‖q̇₀‖² + 2 d·q̈₀, L_G h = 2 dᵀK, L_G L_f h = 2 q̇₀ᵀK + 2 dᵀJ.
    pub(super) fn measure(&mut self, model: &dyn Dynamics, z: &[f64]) {
        // (A decision made again, or the next channel's at the same point, asks again.)
        if self.measured_at == z {
            return;
        }
        self.measured_at.clear();
        self.measured_at.extend_from_slice(z);
        let r = model.input_dim();
        for (probe, point) in self.probes.iter_mut().zip(&mut self.points) {
            // (q alone: the velocity along z is not used.)
            let Some((q, _)) = probe.point_and_velocity(z, z) else {
                continue;
            };
            let mut axis = [([0.0; 2], 0.0, [0.0; 4], [0.0; 4]); 2];
            for (e, out) in axis.iter_mut().enumerate() {
                let mut centre = q;
                centre[e] -= 1.0;
                probe.move_actor(centre);
                self.lie.evaluate(probe, model, z);
                let lie = &self.lie.lie;
                out.1 = lie.lf2_h;
                out.0[e] = lie.lf_h;
                for j in 0..r.min(4) {
                    out.2[j] = lie.lg_h[j] / 2.0;
                    out.3[j] = lie.lg_lf_h[j] / 2.0;
                }
            }
            let velocity = [axis[0].0[0] / 2.0, axis[1].0[1] / 2.0];
            let speed_squared = velocity[0] * velocity[0] + velocity[1] * velocity[1];
            // (L_G L_f h along e: 2 q̇₀ᵀK_j + 2 J_ej, so J_ej = that / 2 − q̇₀·K_j.)
            let acceleration = [axis[0].1 / 2.0 - speed_squared, axis[1].1 / 2.0 - speed_squared];
            let mut point_motion = PointMotion {
                position: q,
                velocity,
                acceleration,
                ..PointMotion::default()
            };
            for j in 0..r.min(4) {
                let (kx, ky) = (axis[0].2[j], axis[1].2[j]);
                let v_k = velocity[0] * kx + velocity[1] * ky;
                let (jx, jy) = (axis[0].3[j] - v_k, axis[1].3[j] - v_k);
                point_motion.velocity_columns[j] = [kx, ky];
                point_motion.acceleration_columns[j] = [jx, jy];
                // (sqrt, not hypot: Lie derivatives of bounded states cannot overflow squared.)
                point_motion.velocity_gains[j] = (kx * kx + ky * ky).sqrt();
                point_motion.acceleration_gains[j] = (jx * jx + jy * jy).sqrt();
            }
            *point = point_motion;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::actor::{add_point_motion_terms, ActorKnowledge};
    use crate::barrier::Constraint;
    use crate::dynamics::BicycleModel;
    use crate::random::SplitMix64;

    /// The row the Lie path forms for `barrier` (a body circle or a planar ball) against a
    /// road user's circle in `circle`'s state: the Lie derivatives with the circle frozen plus
    /// its motion terms (at relative degree 1 with q alone: ∂h/∂t has no input).
    fn controller_row(
        model: &BicycleModel,
        barrier: &mut Barrier,
        form: BarrierForm,
        x: &[f64],
        circle: &ActorState,
    ) -> Constraint {
        let mut lie = LieWorkspace::new(model);
        barrier.move_actor(circle.position);
        let mut row = Constraint::zeros(2);
        lie.constraint_into(barrier, form, model, x, &mut row);
        let mut drift = [0.0; 4];
        model.dynamics_into(x, &[0.0, 0.0], &mut drift);
        let (q, q_drift) = barrier.point_and_velocity(x, &drift).expect("a planar circle");
        let mut inputs = [[0.0; 2]; 2];
        for (j, input) in inputs.iter_mut().enumerate() {
            let (mut unit, mut column) = ([0.0; 2], [0.0; 4]);
            unit[j] = 1.0;
            model.add_input_term(x, &unit, &mut column);
            *input = barrier.point_and_velocity(x, &column).expect("a planar circle").1;
        }
        match form {
            BarrierForm::RelativeDegree2 { .. } => {
                add_point_motion_terms(&mut row, form, (q, q_drift, &inputs), circle)
            }
            BarrierForm::RelativeDegree1 { .. } => add_point_motion_terms(&mut row, form, (q, [0.0; 2], &[]), circle),
        }
        row
    }

    /// The bicycle of wheelbase 2.6 m with its steering delayed 0.2 s and its acceleration 0.5 s.
    fn bicycle_with_delays() -> (BicycleModel, [DelayQueue; 2]) {
        let queues = [
            DelayQueue::new("steering", 0.2, 0.3, 0.002).expect("a queue"),
            DelayQueue::new("acceleration", 0.5, 2.0, 0.002).expect("a queue"),
        ];
        (BicycleModel::new(2.6), queues)
    }

    /// Every row [`Reach::mark`] leaves out is met by every input [`Reach::note`] lets a
    /// decision keep without being made again: random bicycle states against two road users of
    /// three circles each, the inputs at the corners of the largest box `note` accepts (found by
    /// probing it), and that box within the one `mark`'s certificate assumed (W and B): with
    /// `note`'s bound 5 % above U_j this fails (tried).
    #[test]
    fn every_row_left_out_holds_for_every_input_a_decision_may_keep() {
        let (model, queues) = bicycle_with_delays();
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        let offsets = [[-1.5, 0.0], [0.0, 0.0], [1.5, 0.0]];
        let mut rng = SplitMix64(5);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let (mut left_out, mut checked) = (0, 0);
        for _ in 0..300 {
            let mut reach = Reach::new(&model, &queues);
            let mut barriers = Vec::new();
            for user in 0..2 {
                for (c, offset) in offsets.iter().enumerate() {
                    let barrier = Barrier::body_circle(&format!("u{user}c{c}"), ([0, 1], 2), [1.3, 0.0], [0.0; 2], 2.0);
                    reach.add(&barrier, Some((*offset, c == 0)));
                    barriers.push(barrier);
                }
            }
            // M_j: recent commands of up to 0.3 rad and 2 m/s².
            reach.largest_input = vec![uniform(0.0, 0.3), uniform(0.0, 2.0)];
            reach.bound.clone_from(&reach.largest_input);
            let x = [0.0, 0.0, uniform(-3.0, 3.0), uniform(0.0, 30.0)];
            let users: Vec<ActorState> = (0..2)
                .map(|_| ActorState {
                    position: [uniform(-40.0, 40.0), uniform(-40.0, 40.0)],
                    velocity: [uniform(-20.0, 20.0), uniform(-20.0, 20.0)],
                    acceleration: [uniform(-5.0, 5.0), uniform(-5.0, 5.0)],
                    ..ActorState::default()
                })
                .collect();
            if !reach.mark(&model, form, &x, 2, |k| users[k / 3], None) {
                continue;
            }
            // The largest |u_j| `note` accepts on each channel (bisection on its flag; each
            // probe from the M_j `mark` saw, which `note` grows).
            let seen = reach.largest_input.clone();
            let accepted: Vec<f64> = (0..2)
                .map(|j| {
                    let exceeds = |reach: &mut Reach, value: f64| {
                        reach.largest_input.copy_from_slice(&seen);
                        reach.begin_decision(&[0.0, 0.0]);
                        reach.note(std::iter::once((j, value)));
                        reach.exceeded
                    };
                    let (mut lo, mut hi) = (0.0, 1e3 * seen[j]);
                    for _ in 0..60 {
                        let mid = 0.5 * (lo + hi);
                        (lo, hi) = if exceeds(&mut reach, mid) { (lo, mid) } else { (mid, hi) };
                    }
                    lo
                })
                .collect();
            // The certificate's W and B (`input_reach`) cover that box.
            for (point, covered) in reach.ego.points.iter().zip(&reach.input_reach) {
                let needed = |gains: &[f64; 4]| gains.iter().zip(&accepted).map(|(g, u)| g * u).sum::<f64>();
                let needed = [needed(&point.velocity_gains), needed(&point.acceleration_gains)];
                for (n, c) in needed.iter().zip(covered) {
                    assert!(
                        *n <= c * (1.0 + 1e-9),
                        "note accepts inputs the certificate did not cover: {n} > {c}"
                    );
                }
            }
            for k in (0..barriers.len()).filter(|&k| reach.out[k]) {
                left_out += 1;
                let circle = users[k / 3].shifted(offsets[k % 3]);
                let row = controller_row(&model, &mut barriers[k], form, &x, &circle);
                for corner in [[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]] {
                    let u = nalgebra::DVector::from_column_slice(&[corner[0] * accepted[0], corner[1] * accepted[1]]);
                    let value = row.value(&u);
                    assert!(
                        value >= -1e-9 * (1.0 + row.a.abs()),
                        "row {k} left out but {value} < 0 at {u:?}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(left_out > 50, "only {left_out} rows left out");
        assert!(checked > 200);
    }

    /// A [`Reach`] of `users` road users of three circles along their length (the first the
    /// primary), each against three ego circles along the car: barriers 9u + 3c + e.
    fn road_users_of_three_circles(model: &BicycleModel, queues: &[DelayQueue], users: usize) -> Reach {
        let ego_offsets = [[-1.0, 0.0], [0.5, 0.0], [2.0, 0.0]];
        let circle_offsets = [[-1.5, 0.0], [0.0, 0.0], [1.5, 0.0]];
        let mut reach = Reach::new(model, queues);
        for user in 0..users {
            for (c, offset) in circle_offsets.iter().enumerate() {
                for (e, ego) in ego_offsets.iter().enumerate() {
                    let barrier = Barrier::body_circle(&format!("u{user}c{c}e{e}"), ([0, 1], 2), *ego, [0.0; 2], 1.0);
                    reach.add(&barrier, Some((*offset, c == 0 && e == 0)));
                }
            }
        }
        reach
    }

    /// The far test (a road user against every ego point at once, [`EgoEnvelope`]) leaves a
    /// road user out only where the group and pair tests leave every one of its barriers out:
    /// random bicycle states against two turning road users of three circles, each against
    /// three ego circles, spread across the edge of reach, standing, turning or moving. And [`Reach::mark`] with the far
    /// test (its second call, after a road user was out) decides as without it (its first),
    /// the nearest road user kept included. Fails with the road user's turning, or the ego
    /// points' spread about their centroid, left out of the far test's bounds (tried).
    #[test]
    fn the_far_test_leaves_out_only_what_the_group_and_pair_tests_leave_out() {
        let (model, queues) = bicycle_with_delays();
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        let rates = form.real_rates();
        let mut rng = SplitMix64(23);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let (mut far, mut out_not_far, mut in_reach, mut kept) = (0, 0, 0, 0);
        for _ in 0..20000 {
            let mut reach = road_users_of_three_circles(&model, &queues, 2);
            reach.largest_input = vec![uniform(0.0, 0.3), uniform(0.0, 2.0)];
            reach.bound.clone_from(&reach.largest_input);
            let x = [0.0, 0.0, uniform(-3.0, 3.0), uniform(0.0, 30.0)];
            // A third standing, a third turning where they stand (the far test's V and A then as
            // tight as the group test's), a third moving and turning.
            let kind = uniform(0.0, 3.0);
            let (moving, turning) = (f64::from(u8::from(kind >= 2.0)), f64::from(u8::from(kind >= 1.0)));
            let users: Vec<ActorState> = (0..2)
                .map(|_| ActorState {
                    position: [uniform(-80.0, 80.0), uniform(-80.0, 80.0)],
                    velocity: [uniform(-20.0, 20.0) * moving, uniform(-20.0, 20.0) * moving],
                    acceleration: [uniform(-5.0, 5.0) * moving, uniform(-5.0, 5.0) * moving],
                    turn: uniform(-1.0, 1.0),
                    yaw_rate: uniform(-2.0, 2.0) * turning,
                    yaw_acceleration: uniform(-4.0, 4.0) * turning,
                    ..ActorState::default()
                })
                .collect();
            let assumed = |k: usize| users[k / 9];
            // Without the far test: no road user was out before.
            reach.mark(&model, form, &x, 2, assumed, None);
            let (out, nearest_kept) = (reach.out.clone(), reach.kept_nearest);
            kept += usize::from(nearest_kept);
            let envelope = EgoEnvelope::of(&reach.ego.points, &reach.input_reach).expect("finite points");
            let parts = (&reach.ego.points[..], &reach.input_reach[..]);
            for group in &reach.groups {
                let geometry = BarrierGeometry {
                    point_of: &reach.point_of,
                    radius: &reach.radius,
                    offsets: &reach.offsets,
                    gap_terms: &reach.gap_terms,
                };
                let (mut with, mut without) = (vec![false; out.len()], vec![false; out.len()]);
                let actor = (assumed(group.first), &assumed, true);
                let tested = mark_group(group, geometry, parts, (form, rates, Some(&envelope)), actor, &mut with);
                mark_group(group, geometry, parts, (form, rates, None), actor, &mut without);
                let range = group.first..group.end;
                let all_out = without[range.clone()].iter().all(|&o| o);
                match tested {
                    GroupGap::Far => {
                        far += 1;
                        assert!(
                            all_out,
                            "far, but the pair tests keep {without:?} of {:?}",
                            users[group.first / 9]
                        );
                    }
                    _ => {
                        assert_eq!(with[range.clone()], without[range.clone()]);
                        out_not_far += usize::from(all_out);
                        in_reach += usize::from(!all_out);
                    }
                }
            }
            // With the far test first where the first call left a road user out.
            reach.mark(&model, form, &x, 2, assumed, None);
            assert_eq!((&reach.out, reach.kept_nearest), (&out, nearest_kept), "{users:?}");
        }
        assert!(
            far > 500 && out_not_far > 300 && in_reach > 300,
            "{far} far, {out_not_far} out, {in_reach} in reach"
        );
        assert!(kept > 100, "{kept} decisions kept the nearest");
    }

    /// Road users asleep through an epoch ([`Asleep`]) are left out only where the far test
    /// leaves them out (so exactly as the group and pair tests do): at every evaluation, each
    /// road user that sleeps through it passes the far test there; and two [`Reach`]es seeing
    /// the same evaluations, one letting road users sleep and one not, leave the same barriers
    /// out and keep the same nearest road user. Random epochs: four road users of three circles
    /// against three ego circles, 10–80 m away, observed moving with the ego, crossing or
    /// braking, assumed static, at constant velocity or at constant acceleration; 40 evaluations
    /// each at look-aheads across the window along the ego's path, its heading and speed
    /// perturbed (some beyond the epoch's bounds, which begins another). Fails with a sleeping
    /// road user's displacement over the window, or the epoch's velocity deviation, left out
    /// of its bounds (tried).
    #[test]
    fn asleep_road_users_pass_the_far_test_wherever_they_sleep() {
        let (model, queues) = bicycle_with_delays();
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        let rates = form.real_rates();
        let mut rng = SplitMix64(41);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let build = || road_users_of_three_circles(&model, &queues, 4);
        let (mut sleeping, mut awake) = (build(), build());
        let (mut evaluations, mut slept_checked) = (0, 0);
        let span = 0.6;
        for epoch in 0..1500 {
            let now = epoch as f64;
            let knowledge = [
                ActorKnowledge::Static,
                ActorKnowledge::ConstantVelocity,
                ActorKnowledge::ConstantAcceleration,
            ][(uniform(0.0, 3.0) as usize).min(2)];
            let (heading, speed) = (uniform(-3.0, 3.0), uniform(0.0, 30.0));
            let ahead = [heading.cos(), heading.sin()];
            let observed: Vec<ActorState> = (0..4)
                .map(|_| {
                    let (distance, bearing) = (uniform(10.0, 80.0), uniform(-3.2, 3.2));
                    let velocity = match uniform(0.0, 1.0) < 0.5 {
                        true => [
                            ahead[0] * speed + uniform(-3.0, 3.0),
                            ahead[1] * speed + uniform(-3.0, 3.0),
                        ],
                        false => [uniform(-20.0, 20.0), uniform(-20.0, 20.0)],
                    };
                    ActorState {
                        position: [distance * bearing.cos(), distance * bearing.sin()],
                        velocity,
                        acceleration: [uniform(-6.0, 6.0), uniform(-6.0, 6.0)],
                        turn: uniform(-1.0, 1.0),
                        ..ActorState::default()
                    }
                })
                .collect();
            let window =
                |first: usize, _end: usize, from: f64, to: f64| knowledge.window(&observed[first / 9], from, to);
            let bound = vec![uniform(0.0, 0.3), uniform(0.0, 2.0)];
            for k in 0..40 {
                let at = now + span * (k as f64 + uniform(-2.0, 2.0)) / 40.0;
                let d = (at - now).max(0.0);
                // The first evaluation at the epoch's heading and speed, the others 0.3–0.95 m/s
                // faster (within the epoch's velocity deviation), one in 20 far beyond.
                let scale = [0.0, 1.0, 10.0][usize::from(k > 0) + usize::from(k > 0 && uniform(0.0, 1.0) < 0.05)];
                let (h, v) = (
                    heading + scale * uniform(-0.002, 0.002),
                    speed + scale * uniform(0.3, 0.95),
                );
                let x = [ahead[0] * speed * d, ahead[1] * speed * d, h, v];
                let assumed = |k: usize| knowledge.predict(&observed[k / 9], now, at.max(now), |_| unreachable!());
                for reach in [&mut sleeping, &mut awake] {
                    reach.largest_input.clone_from(&bound);
                    reach.bound.clone_from(&bound);
                }
                let sleep = SleepAt {
                    now,
                    at,
                    span,
                    window: &window,
                };
                sleeping.mark(&model, form, &x, 2, assumed, Some(sleep));
                awake.mark(&model, form, &x, 2, assumed, None);
                assert_eq!(
                    (&sleeping.out, sleeping.kept_nearest),
                    (&awake.out, awake.kept_nearest),
                    "epoch {epoch}, {knowledge:?}, at {at}: {observed:?}"
                );
                evaluations += 1;
                // Each road user that slept through this evaluation (one within the epoch's
                // look-ahead) passes the far test here.
                if d > span {
                    continue;
                }
                let envelope = EgoEnvelope::of(&sleeping.ego.points, &sleeping.input_reach).expect("finite");
                let geometry = BarrierGeometry {
                    point_of: &sleeping.point_of,
                    radius: &sleeping.radius,
                    offsets: &sleeping.offsets,
                    gap_terms: &sleeping.gap_terms,
                };
                let parts = (&sleeping.ego.points[..], &sleeping.input_reach[..]);
                let asleep = sleeping
                    .groups
                    .iter()
                    .filter(|g| g.asleep.is_some_and(|a| a.sleeps(&envelope)));
                for group in asleep {
                    let mut out = vec![false; sleeping.out.len()];
                    let actor = (assumed(group.first), &assumed, true);
                    let tested = mark_group(group, geometry, parts, (form, rates, Some(&envelope)), actor, &mut out);
                    assert!(
                        matches!(tested, GroupGap::Far),
                        "asleep but not far: epoch {epoch}, {knowledge:?}, look-ahead {d}, {:?}",
                        observed[group.first / 9]
                    );
                    slept_checked += 1;
                }
            }
        }
        assert_eq!(evaluations, 60000);
        assert!(
            slept_checked > 20000 && sleeping.slept > 20000 && sleeping.epochs > 1800,
            "{slept_checked} checked, {} slept, {} epochs",
            sleeping.slept,
            sleeping.epochs
        );
    }

    /// A road user parked where it does not exist is left out without a test; the one kept when
    /// every row would go is the nearest that exists, and a parked one only when none exists
    /// (the nearest of them, as their group tests name it). Moving on the parking line, it is
    /// no longer parked and is tested.
    #[test]
    fn parked_road_users_are_out_and_kept_only_when_no_road_user_exists() {
        use crate::actor::PARKED;
        let (model, mut reach) = three_road_users();
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        reach.largest_input = vec![0.1, 1.0];
        reach.bound.clone_from(&reach.largest_input);
        let x = [0.0, 0.0, 0.0, 10.0];
        let parked = |slot: f64| ActorState {
            position: [PARKED + 100.0 * slot, PARKED],
            ..ActorState::default()
        };
        let at = |d: f64| ActorState {
            position: [d, 0.0],
            ..ActorState::default()
        };
        let cases: [([ActorState; 3], [bool; 3], bool); 4] = [
            // Two far road users: the nearer kept.
            ([parked(0.0), at(1000.0), at(500.0)], [true, true, false], true),
            // One in reach: nothing kept.
            ([parked(0.0), at(1000.0), at(5.0)], [true, true, false], false),
            // None exists: the nearest parked one kept.
            ([parked(2.0), parked(0.0), parked(1.0)], [true, false, true], true),
            // Moving on the parking line: tested (far, so out), and nearer than the parked.
            (
                [
                    parked(0.0),
                    ActorState {
                        velocity: [1.0, 0.0],
                        ..parked(-1e3)
                    },
                    parked(1.0),
                ],
                [true, false, true],
                true,
            ),
        ];
        for (users, out, kept) in cases {
            assert!(reach.mark(&model, form, &x, 2, |k| users[k], None));
            assert_eq!(
                (reach.out.as_slice(), reach.kept_nearest),
                (&out[..], kept),
                "{users:?}"
            );
        }
        assert!(parked(3.0).is_parked() && !at(PARKED).is_parked());
    }

    /// A decision made with every row (after an input above its bound, or with
    /// `leave_out_of_reach = false`) still has no row of a road user that does not exist, and
    /// calls for no decision to be made again for it; when every road user is parked and no
    /// other barrier keeps a row, every row stays (a filter with barriers always decides).
    #[test]
    fn a_decision_with_every_row_has_none_of_a_road_user_that_does_not_exist() {
        use crate::actor::PARKED;
        let (model, mut reach) = three_road_users();
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        let x = [0.0, 0.0, 0.0, 10.0];
        let parked = ActorState {
            position: [PARKED, PARKED],
            ..ActorState::default()
        };
        let near = ActorState {
            position: [5.0, 0.0],
            ..ActorState::default()
        };
        for every_row in [Every::Again, Every::NotAllowed] {
            match every_row {
                Every::Again => reach.enabled = false,
                Every::NotAllowed => {
                    reach.enabled = true;
                    reach.set_allowed(false);
                }
            }
            let users = [parked, near, parked];
            assert!(reach.mark(&model, form, &x, 2, |k| users[k], None), "{every_row:?}");
            assert_eq!(reach.out, [true, false, true], "{every_row:?}");
            assert!(!reach.culled_last, "{every_row:?}: nothing to make again");
            assert!(!reach.mark(&model, form, &x, 2, |_| parked, None), "{every_row:?}");
            assert_eq!(reach.out, [false; 3], "{every_row:?}");
        }
    }

    /// The bicycle's reach test with three road users of one circle each (their primaries).
    fn three_road_users() -> (BicycleModel, Reach) {
        let (model, queues) = bicycle_with_delays();
        let mut reach = Reach::new(&model, &queues);
        for user in 0..3 {
            let barrier = Barrier::body_circle(&format!("u{user}"), ([0, 1], 2), [1.3, 0.0], [0.0; 2], 2.0);
            reach.add(&barrier, Some(([0.0; 2], true)));
        }
        (model, reach)
    }

    #[derive(Debug, Clone, Copy)]
    enum Every {
        Again,
        NotAllowed,
    }

    /// A formed row is left out only when it holds at every corner of the box of inputs
    /// `note` accepts without making the decision again (|u_j| ≤ U_j), and only where
    /// another barrier's row always stays (it fails with U_j / 1.1 = M_j for U_j, or with the
    /// margin's sign turned).
    #[test]
    fn a_formed_row_left_out_holds_for_every_input_a_decision_may_keep() {
        let (model, queues) = bicycle_with_delays();
        let user = |c: usize| Barrier::body_circle(&format!("u{c}"), ([0, 1], 2), [1.3, 0.0], [0.0; 2], 2.0);
        let mut alone = Reach::new(&model, &queues);
        for c in 0..2 {
            alone.add(&user(c), Some(([0.0; 2], true)));
        }
        let mut reach = Reach::new(&model, &queues);
        reach.add(&Barrier::circular_obstacle("fixed", [0, 1], [100.0, 0.0], 1.0), None);
        for c in 0..2 {
            reach.add(&user(c), Some(([0.0; 2], true)));
        }
        let mut rng = SplitMix64(11);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let (mut kept, mut left_out) = (0, 0);
        for _ in 0..2000 {
            let bound = [uniform(0.0, 0.3), uniform(0.0, 2.0)];
            for r in [&mut reach, &mut alone] {
                r.bound.copy_from_slice(&bound);
            }
            let mut row = Constraint::zeros(2);
            (row.a, row.b[0], row.b[1]) = (uniform(-5.0, 40.0), uniform(-60.0, 60.0), uniform(-8.0, 8.0));
            assert!(
                !alone.holds_for_every_admissible_input(&row, None),
                "no other row stays"
            );
            if !reach.holds_for_every_admissible_input(&row, None) {
                kept += 1;
                continue;
            }
            left_out += 1;
            for corner in [[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]] {
                let u = nalgebra::DVector::from_column_slice(&[
                    BOUND_FACTOR * corner[0] * bound[0],
                    BOUND_FACTOR * corner[1] * bound[1],
                ]);
                assert!(
                    row.value(&u) >= 0.0,
                    "{row:?} left out, but {} < 0 at {u:?}",
                    row.value(&u)
                );
            }
        }
        assert!(kept > 200 && left_out > 200, "kept {kept}, left out {left_out}");
    }

    /// The rows the controller forms for a road user's circle in closed form
    /// ([`crate::actor::reach::pair_rows`] from the measured ego point) against the Lie path
    /// (h, ∇h, ∇²h with f, G and ∂f/∂x, plus the motion terms), a and every b_j, and the
    /// first-order row ḣ + λ1 h of the mixed-relative-degree pair, and the condition a + b·u
    /// `/barrier` logs ([`crate::actor::reach::pair_condition`]), on random bicycle states,
    /// circles off the rear axle and balls about the planar position, road users and forms.
    #[test]
    fn the_pairs_rows_from_the_point_equal_the_lie_path() {
        let model = BicycleModel::new(2.6);
        let mut rng = SplitMix64(23);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let mut ego = EgoPoints::new(&model);
        let mut lie = LieWorkspace::new(&model);
        let (mut worst, mut first_rows) = (0.0_f64, 0);
        let relative = |x: f64, y: f64| (x - y).abs() / (1.0 + x.abs().max(y.abs()));
        for trial in 0..400 {
            let offset = [uniform(-1.0, 4.0), uniform(-0.9, 0.9)];
            let radius = uniform(0.5, 3.0);
            // (Every fourth a ball about the planar position, the ego point of a vehicle
            // without a footprint.)
            let mut barrier = match trial % 4 {
                3 => Barrier::circular_obstacle("pair", [0, 1], [0.0; 2], radius),
                _ => Barrier::body_circle("pair", ([0, 1], 2), offset, [0.0; 2], radius),
            };
            let i = ego.index_of(&barrier).expect("a planar circle");
            let x = [
                uniform(-50.0, 50.0),
                uniform(-50.0, 50.0),
                uniform(-3.0, 3.0),
                uniform(-5.0, 30.0),
            ];
            let circle = ActorState {
                position: [x[0] + uniform(-30.0, 30.0), x[1] + uniform(-30.0, 30.0)],
                velocity: [uniform(-20.0, 20.0), uniform(-20.0, 20.0)],
                acceleration: [uniform(-5.0, 5.0), uniform(-5.0, 5.0)],
                ..ActorState::default()
            };
            let form = match trial % 3 {
                0 => BarrierForm::RelativeDegree1 { alpha: 2.0 },
                1 => BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 },
                _ => BarrierForm::RelativeDegree2 { l0: 1.0, l1: 3.0 },
            };
            // The Lie path, as the controller formed it before.
            let expected = controller_row(&model, &mut barrier, form, &x, &circle);
            let mixed = barrier
                .mixed_relative_degree()
                .then(|| form.real_rates().map(|r| r.0))
                .flatten();
            let mut expected_first = Constraint::zeros(2);
            if mixed.is_some() {
                barrier.move_actor(circle.position);
                let mut scratch = Constraint::zeros(2);
                lie.constraint_into(&barrier, form, &model, &x, &mut scratch);
                assert!(lie.first_order_part_into(form, &mut expected_first));
                let q = barrier.point_and_velocity(&x, &x).expect("a planar circle").0;
                add_point_motion_terms(
                    &mut expected_first,
                    BarrierForm::RelativeDegree1 { alpha: 0.0 },
                    (q, [0.0; 2], &[]),
                    &circle,
                );
            }
            ego.measure(&model, &x);
            let (mut row, mut first) = (Constraint::zeros(2), Constraint::zeros(2));
            crate::actor::reach::pair_rows(
                form,
                mixed,
                &ego.points[i].kinematics(2),
                &circle,
                radius,
                &mut row,
                Some(&mut first),
            );
            worst = worst.max(relative(row.h, expected.h)).max(relative(row.a, expected.a));
            // The condition at an input, as `/barrier` logs it.
            let u = [uniform(-0.5, 0.5), uniform(-6.0, 6.0)];
            let condition =
                crate::actor::reach::pair_condition(form, mixed, &ego.points[i].kinematics(2), &circle, radius, &u);
            worst = worst.max(relative(
                condition,
                expected.value(&nalgebra::DVector::from_column_slice(&u)),
            ));
            for j in 0..2 {
                worst = worst.max(relative(row.b[j], expected.b[j]));
            }
            if mixed.is_some() {
                first_rows += 1;
                worst = worst.max(relative(first.a, expected_first.a));
                for j in 0..2 {
                    worst = worst.max(relative(first.b[j], expected_first.b[j]));
                }
            }
        }
        assert!(
            first_rows > 100 && worst < 1e-10,
            "worst relative difference {worst:e} ({first_rows} first-order rows)"
        );
    }
}
