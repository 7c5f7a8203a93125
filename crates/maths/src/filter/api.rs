//! The safety-filter extension point: the trait every filter implements (the built-ins
//! included), what it receives at a control tick, and what it is built from.
//!
//! A filter is registered under a scenario `kind` in the registry (`mjsafe::registry`) with a typed
//! parameter struct; the episode builds it once per run ([`FilterContext`]) and calls it at
//! every control tick, once per input channel ([`ChannelInput`]). See docs/writing-a-filter.md.

use std::sync::Arc;

use nalgebra::DVector;

use crate::actor::ActorState;
use crate::barrier::{Barrier, BarrierForm, Constraint};
use crate::delay::{DelayError, DelayQueue};
use crate::dynamics::Dynamics;
use crate::filter::qp::QpWorkspace;
use crate::filter::ChannelOutcome;
use crate::nominal::NominalController;
pub use crate::params::{ParamError, Params};

/// Fraction of a step below which two times are the same instant.
pub const TICK_TOLERANCE: f64 = 1e-6;

/// A safety filter: at each control tick, for each input channel i, the command u_i from the
/// nominal input and the known barriers' constraint data at the channel's evaluation state.
///
/// Called inside MuJoCo's control callback: it must not panic on any state (return an error),
/// and should not allocate once warm (size scratch space when built).
pub trait SafetyFilter: Send {
    /// The barrier condition whose constraint data a(z) + b(z)·u ≥ 0 the filter receives for
    /// every known barrier ((4.7)/(4.8) or (4.85)/(4.86)); `None`: the filter needs none (it
    /// has its own barrier, or it is no filter), and the log's `/barrier` constraint is NaN.
    fn barrier_form(&self) -> Option<BarrierForm>;

    /// Whether channel i is evaluated at its prediction p_i(t) ((2.26), (4.34)) rather than at
    /// the measured x(t) ((2.16)).
    fn uses_prediction(&self) -> bool;

    /// The decision for one channel; `None` when the filter has nothing to act on (no known
    /// barrier yet): the nominal input is issued and no decision is logged.
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError>;

    /// The law this filter issues, as the recursive predictors (4.23) assume it for the
    /// commands not yet issued inside their window: `u[j]` ← κ_j at the predicted state z for
    /// every channel j in `input.free`. On entry `u` holds, for every other channel, the
    /// command it applies at the time z is predicted for (issued before the prediction's tick,
    /// or assumed by the recursion for a later tick): the ω (4.45)/(4.62) this law reads.
    /// Entries outside `free` may be overwritten; only those in `free` are read back.
    ///
    /// By (4.25) a prediction is the state that follows only if this is the law
    /// [`SafetyFilter::filter_channel`] really issues at z. Default: the delay-free CBF-QP
    /// (4.29)/(4.9) over every known barrier — what a filter issuing component i of κ^DF at
    /// p_i(t) ((4.30)/(4.34)) issues; override it for any other law ((4.44) and (4.67) do).
    /// Allocation-free for at most one barrier; with several, override it with a
    /// [`QpWorkspace`] kept in the filter. The predictors call it at every step of their
    /// window: keep it cheap.
    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        delay_free_qp(input.constraints, input.nominal, None, None, u);
        Ok(())
    }

    /// The prescribed time T of the run's prescribed-time metrics (Ch. 5), if the filter has one.
    fn prescribed_time(&self) -> Option<f64> {
        None
    }

    /// `largest[j]` ← the largest |u_j| the QPs of this filter's decisions and laws since the
    /// last call planned on channel j — the variables of a QP as inputs, fictitious ones
    /// included (γm's u + σ (4.60)), and the real inputs whose shortfall a decision reports —
    /// and true; false (the default) when the filter does not
    /// say. A barrier condition left out of the filter's constraints (a road user out of
    /// reach, docs/actors.md) is checked against these; a decision of a filter that does not
    /// say and that corrects u0 is made again with every row.
    fn take_planned_inputs(&mut self, _largest: &mut [f64]) -> bool {
        false
    }
}

/// What a filter receives for channel i at tick time t.
pub struct ChannelInput<'a> {
    /// t, the tick time (s).
    pub time: f64,
    /// i, the channel's index (channels in the vehicle's order).
    pub channel: usize,
    /// The evaluation state: p_i(t) if [`SafetyFilter::uses_prediction`], else x(t).
    pub state: &'a [f64],
    /// u0 (every channel) at the nominal's evaluation state.
    pub nominal: &'a DVector<f64>,
    /// The known barriers' conditions at `state` in the form of
    /// [`SafetyFilter::barrier_form`] (empty without a form): one row per barrier in reach
    /// (see `barriers.rows`).
    pub constraints: &'a [Constraint],
    /// Every channel's delay queue: delays D_j, φ_j, and the commands already issued.
    pub queues: &'a [DelayQueue],
    /// The plant step h (s).
    pub timestep: f64,
    /// The barriers behind `constraints`, as the controller sees them at the evaluation time.
    pub barriers: SeenBarriers<'a>,
}

/// What a moving barrier's actor is assumed to be at the evaluation time: None for a barrier
/// that does not move.
pub type AssumedActor<'a> = &'a dyn Fn(usize) -> Option<ActorState>;

fn no_actor(_: usize) -> Option<ActorState> {
    None
}

/// The barriers the controller knows at a decision, as it sees them at the evaluation time:
/// which barrier each constraint row belongs to, and a moving actor's barrier where the
/// controller assumes the actor then (what the rows were computed with, [`crate::actor`]'s
/// `actor_knowledge`). A barrier without a row at this decision (a road user out of reach, or
/// a filter without a barrier form) is still known.
#[derive(Clone, Copy)]
pub struct SeenBarriers<'a> {
    /// Every known barrier as built: the scenario's, the road's edges, then the obstacles'
    /// (a moving actor's centred where it was when built).
    pub known: &'a [Barrier],
    /// Per constraint row (in the order of `constraints`), the index in `known` of its barrier
    /// (a mixed-relative-degree barrier has a second, first-order row).
    pub rows: &'a [usize],
    assumed: AssumedActor<'a>,
}

impl<'a> SeenBarriers<'a> {
    /// The view of `known` with the rows' barriers and the moving actors' assumed states.
    pub fn new(known: &'a [Barrier], rows: &'a [usize], assumed: AssumedActor<'a>) -> SeenBarriers<'a> {
        SeenBarriers { known, rows, assumed }
    }

    /// No barrier (a decision made outside an episode).
    pub fn none() -> SeenBarriers<'static> {
        const NONE: AssumedActor<'static> = &no_actor;
        SeenBarriers {
            known: &[],
            rows: &[],
            assumed: NONE,
        }
    }

    /// For barrier k of a moving actor, the state the controller assumes of its circle's
    /// centre at the evaluation time (position, velocity, acceleration; a box's covering circle
    /// turned with the box); None for a barrier that does not move.
    pub fn assumed_actor(&self, k: usize) -> Option<ActorState> {
        (self.assumed)(k)
    }
}

impl ChannelInput<'_> {
    /// ω (4.45)/(4.62): `omega[j]` ← u_j(t − D_{j,i}), the command channel j ≥ `from` applies when
    /// channel i's command issued now arrives (at φ_i⁻¹(t)); 0 for j < `from`.
    pub fn later_commands(&self, from: usize, omega: &mut DVector<f64>) -> Result<(), DelayError> {
        let arrival = self.queues[self.channel].profile().prediction_time(self.time);
        omega.fill(0.0);
        for j in from..self.queues.len() {
            omega[j] = self.queues[j].applied(arrival)?.value;
        }
        Ok(())
    }
}

/// What [`SafetyFilter::issued_law`] receives: one predicted state z = p_j(τ) = x(τ + D_j),
/// shared by the channels in `free` (equal delays D_j, so one issue time τ).
pub struct LawInput<'a> {
    /// τ, the tick at which the channels in `free` issue the command that reaches the plant at
    /// `prediction_time` (s).
    pub time: f64,
    /// τ + D_j, the time z is predicted for (s).
    pub prediction_time: f64,
    /// z, the predicted state.
    pub state: &'a [f64],
    /// u0 (every channel) at z, at the time the filter evaluates it at that tick.
    pub nominal: &'a DVector<f64>,
    /// The known barriers' conditions at z in the form of [`SafetyFilter::barrier_form`]:
    /// one row per barrier in reach (see `barriers.rows`).
    pub constraints: &'a [Constraint],
    /// The channels whose commands the law gives (in channel order, one delay).
    pub free: &'a [usize],
    /// The barriers behind `constraints`, as the controller sees them at `prediction_time`.
    pub barriers: SeenBarriers<'a>,
}

impl LawInput<'_> {
    /// The law of a per-channel filter: `u[j]` ← `command(constraints, ω, j)` for every j in
    /// `free` (`constraints` non-empty), with ω a copy (into `omega`) of `u` on entry — the
    /// later channels' commands — or u0_j while no barrier is known (the filter then issues
    /// the nominal).
    pub fn per_free_channel(
        &self,
        u: &mut DVector<f64>,
        omega: &mut DVector<f64>,
        mut command: impl FnMut(&[Constraint], &DVector<f64>, usize) -> f64,
    ) {
        if self.constraints.is_empty() {
            for &j in self.free {
                u[j] = self.nominal[j];
            }
            return;
        }
        omega.copy_from(u);
        for &j in self.free {
            u[j] = command(self.constraints, omega, j);
        }
    }
}

/// u ← the delay-free CBF-QP over all channels from u0 and the constraints: u0 without
/// constraints (even with limits), the closed form (4.9) for one barrier without limits, else
/// the numerical QP ([`crate::filter::qp`]) in `qp` (keep one per filter: no allocation once
/// it has seen the largest problem; `None` builds one for this call only when needed).
/// Returns (active, infeasible, μ).
#[inline(always)]
pub fn delay_free_qp(
    constraints: &[Constraint],
    nominal: &DVector<f64>,
    limits: Option<(&[f64], &[f64])>,
    qp: Option<&mut QpWorkspace>,
    u: &mut DVector<f64>,
) -> (bool, bool, f64) {
    crate::barrier::copy_small(u.as_mut_slice(), nominal.as_slice());
    match (constraints, limits) {
        // Without a known barrier the nominal passes as it is (limits included).
        ([], _) => (false, false, f64::NAN),
        ([c], None) => crate::filter::cbf_qp_in_place(c, u),
        // Out of line: the closed form above stays small enough to inline into the callers
        // (the predictors evaluate it at every step of their window).
        (constraints, _) => numerical_qp(constraints, nominal, limits, qp, u),
    }
}

/// The numerical QP of [`delay_free_qp`] (u holds u0).
#[inline(never)]
fn numerical_qp(
    constraints: &[Constraint],
    nominal: &DVector<f64>,
    limits: Option<(&[f64], &[f64])>,
    qp: Option<&mut QpWorkspace>,
    u: &mut DVector<f64>,
) -> (bool, bool, f64) {
    match qp {
        Some(qp) => qp.solve(constraints, nominal, limits, u),
        None => QpWorkspace::default().solve(constraints, nominal, limits, u),
    }
}

/// What a filter is built from (once per run, before the first step).
pub struct FilterContext<'a> {
    /// The analytic model the controller assumes (f, G, ∂f/∂x).
    pub model: &'a Arc<dyn Dynamics>,
    /// The scenario's `vehicle.kind`.
    pub vehicle_kind: &'a str,
    /// One queue per channel, with its delay profile.
    pub queues: &'a [DelayQueue],
    /// x(0) as the scenario writes it.
    pub initial_state: &'a DVector<f64>,
    /// The scenario's barriers, then its obstacles' barriers (hull radius included).
    pub barriers: &'a [Barrier],
    /// The radius of the vehicle's hull (m), what the circle barriers add to an obstacle's.
    pub hull_radius: f64,
    /// The vehicle's footprint, if the scenario gives one (its covering circles are then the
    /// vehicle's side of the circle barriers, [`crate::footprint`]).
    pub footprint: Option<crate::footprint::Rectangle>,
    /// The nominal controller.
    pub nominal: &'a dyn NominalController,
    /// The plant step h (s).
    pub timestep: f64,
}

impl FilterContext<'_> {
    /// The most constraint rows a decision in `form` can have: one per barrier, and the
    /// first-order row ḣ + λ1 h of each mixed-relative-degree barrier when the form has real
    /// rates (what a filter's QP workspace is sized for: solving then never allocates).
    pub fn most_rows(&self, form: BarrierForm) -> usize {
        let first_order = match form.real_rates() {
            Some(_) => self.barriers.iter().filter(|b| b.mixed_relative_degree()).count(),
            None => 0,
        };
        self.barriers.len() + first_order
    }

    /// The error of a check that failed: the distinct-delay filters need constant delays in
    /// non-decreasing channel order D_1 ≤ … ≤ D_r.
    pub fn ordered_constant_delays(&self) -> Result<(), ParamError> {
        let mut previous: Option<(&str, f64)> = None;
        for q in self.queues {
            let key = format!("delays.{}", q.channel());
            let Some(d) = q.constant_delay() else {
                return Err(ParamError::new(key, "the distinct-delay filters need constant delays"));
            };
            if let Some((name, p)) = previous {
                if d < p {
                    return Err(ParamError::new(
                        key,
                        format!(
                            "the filter assumes D_1 <= ... <= D_r in channel order, but `{}` ({d} s) comes after `{name}` ({p} s)",
                            q.channel()
                        ),
                    ));
                }
            }
            previous = Some((q.channel(), d));
        }
        Ok(())
    }
}

/// An error inside a control tick (the episode logs it and stops).
#[derive(Debug, thiserror::Error)]
pub enum FilterError {
    #[error(transparent)]
    Delay(#[from] DelayError),
    #[error("{0}")]
    Other(String),
}

/// The barrier form from a filter's gains: relative degree 1 with α(h) = alpha·h, or 2 with
/// l0, l1 of (4.82) (roots of s² + l1 s + l0 negative real, below (4.83)).
pub fn barrier_form(alpha: Option<f64>, l0: Option<f64>, l1: Option<f64>) -> Result<BarrierForm, ParamError> {
    let positive = |x: f64| x.is_finite() && x > 0.0;
    match (alpha, l0, l1) {
        (Some(alpha), None, None) if !positive(alpha) => Err(ParamError::new(
            "filter.alpha",
            format!("expected alpha > 0, found {alpha}"),
        )),
        (Some(alpha), None, None) => Ok(BarrierForm::RelativeDegree1 { alpha }),
        (None, Some(l0), Some(l1)) if !(positive(l0) && positive(l1) && l1 * l1 >= 4.0 * l0) => Err(ParamError::new(
            "filter",
            format!("expected l0 > 0, l1 > 0 and l1² >= 4 l0 (negative real roots of s² + l1 s + l0), found l0 = {l0}, l1 = {l1}"),
        )),
        (None, Some(l0), Some(l1)) => Ok(BarrierForm::RelativeDegree2 { l0, l1 }),
        _ => Err(ParamError::new(
            "filter",
            "expected either alpha (relative degree 1) or both l0 and l1 (relative degree 2)",
        )),
    }
}
