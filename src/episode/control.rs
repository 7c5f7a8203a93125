//! The controller side of the loop, called by the plant at every input evaluation (inside
//! MuJoCo's control callback for the MuJoCo plant).
//!
//! One control tick (call 0 of every `steps_per_tick`-th step, at the real state x(t)):
//! predictions p_i(t) → per channel i: nominal u0 and delay-free filter at the channel's
//! evaluation state (x(t) uncompensated (2.16), p_i(t) compensated (2.26)/(4.34)) → issued
//! u_i → delay queue i. Every call: sample the queues at the call's time → applied input.

use std::collections::VecDeque;
use std::sync::Arc;

use nalgebra::DVector;

use crate::barrier::{Barrier, BarrierForm, Constraint, LieWorkspace};
use crate::delay::{DelayError, DelayQueue};
use crate::filter::linear_delays::{ConstrainedStabilizer, QpCase};
use crate::filter::prescribed_time::{EsfFilter, PrescribedTimeError, PtsfFilter, StrictFeedbackSystem};
use crate::filter::{self, ChannelOutcome};
use crate::nominal::Nominal;
use crate::plant::Controller;
use crate::predictor::{self, Prediction, PredictorContext, PredictorWorkspace, Structure};
use crate::vehicle::Dynamics;
use nalgebra::Vector2;

/// Fraction of a step below which two times are the same instant.
pub const TICK_TOLERANCE: f64 = 1e-6;

/// The safety filter a controller applies (built from the scenario's `filter` table).
#[derive(Debug, Clone, PartialEq)]
pub enum FilterRule {
    /// The nominal input is issued as it is.
    None,
    /// CBF-QP (4.9) over all channels at x(t) ((2.16)) or, `predicted`, at each channel's
    /// prediction p_i(t) ((2.26), and (4.34)–(4.37) for distinct delays).
    /// With several barriers or actuator `limits` (lower, upper) it is solved numerically
    /// ([`filter::qp`]).
    DelayFree {
        form: BarrierForm,
        predicted: bool,
        limits: Option<(Vec<f64>, Vec<f64>)>,
    },
    /// (4.44)–(4.47) at p_i(t); the first φ channels suffice everywhere (4.41).
    FixedChannel { form: BarrierForm, phi: usize },
    /// (4.60)–(4.68) at p_i(t).
    GammaM { form: BarrierForm, m: f64, gamma: f64 },
    /// Ch. 3: u_i = κ_LB,i(p_i(t)) (3.33), the γm CLF-CBF QP (3.27) at each prediction. It
    /// stabilises through its own CLF (the nominal is zero).
    LinearClfCbf(Arc<ConstrainedStabilizer>),
    /// Ch. 5: PTSf (5.27)/(5.28) or ESf (5.89) on the chain of integrators z = T(x) (the
    /// identity, or (5.83)/(5.84) for the strict-feedback system), mapped back by (5.91).
    Chain {
        filter: ChainFilter,
        transform: ChainTransform,
    },
}

/// The Ch. 5 filter on a chain of integrators.
#[derive(Debug, Clone, PartialEq)]
pub enum ChainFilter {
    Ptsf(Arc<PtsfFilter>),
    Esf(Arc<EsfFilter>),
}

/// How the plant's state and input map to a chain of integrators.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ChainTransform {
    /// The plant is the chain.
    Identity,
    /// (5.82) → (5.85) by (5.83)/(5.84), inputs by (5.86)/(5.91).
    StrictFeedback,
}

impl ChainTransform {
    pub fn to_chain(&self, x: &DVector<f64>) -> DVector<f64> {
        match self {
            ChainTransform::Identity => x.clone(),
            ChainTransform::StrictFeedback => {
                let z = StrictFeedbackSystem.to_chain(&Vector2::new(x[0], x[1]));
                DVector::from_column_slice(z.as_slice())
            }
        }
    }
    /// The chain input v for plant input u at x ((5.86)).
    pub fn chain_input(&self, x: &DVector<f64>, u: f64) -> f64 {
        match self {
            ChainTransform::Identity => u,
            ChainTransform::StrictFeedback => StrictFeedbackSystem.chain_input(&Vector2::new(x[0], x[1]), u),
        }
    }
    /// The plant input u for chain input v at x ((5.91)).
    pub fn plant_input(&self, x: &DVector<f64>, v: f64) -> f64 {
        match self {
            ChainTransform::Identity => v,
            ChainTransform::StrictFeedback => StrictFeedbackSystem.plant_input(&Vector2::new(x[0], x[1]), v),
        }
    }
}

/// An error raised inside the control tick (reported after the step; the episode stops).
#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    #[error(transparent)]
    Delay(#[from] DelayError),
    #[error("prescribed-time filter: {0}")]
    PrescribedTime(#[from] PrescribedTimeError),
}

impl FilterRule {
    pub fn form(&self) -> Option<BarrierForm> {
        match *self {
            FilterRule::None | FilterRule::LinearClfCbf(_) | FilterRule::Chain { .. } => None,
            FilterRule::DelayFree { form, .. }
            | FilterRule::FixedChannel { form, .. }
            | FilterRule::GammaM { form, .. } => Some(form),
        }
    }

    /// Whether the filter acts on predictions p_i(t) rather than on x(t).
    pub fn uses_prediction(&self) -> bool {
        !matches!(
            self,
            FilterRule::None | FilterRule::DelayFree { predicted: false, .. } | FilterRule::Chain { .. }
        )
    }
}

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
}

/// A prediction compared with the realised state (Definition 4.3).
#[derive(Debug, Clone)]
pub struct Consistency {
    pub prediction: Prediction,
    pub realized: DVector<f64>,
}

/// Scratch space of one control tick, sized when the loop is built (and when a barrier becomes
/// known, outside the callback), so that a tick allocates nothing.
struct TickWorkspace {
    /// x(t) at the tick.
    state: DVector<f64>,
    predictions: Vec<Prediction>,
    predictor: PredictorWorkspace,
    law: LawWorkspace,
    /// ω (4.45)/(4.62): commands already issued for the later channels.
    omega: DVector<f64>,
    /// States of realised predictions, reused for new pending ones.
    spare_states: Vec<DVector<f64>>,
}

/// Scratch space of the delay-free law and the per-channel filters.
struct LawWorkspace {
    lie: LieWorkspace,
    /// One per known barrier.
    constraints: Vec<Constraint>,
    /// u0.
    nominal: DVector<f64>,
    /// The filtered input u.
    input: DVector<f64>,
}

/// What the control laws read, borrowed apart from the loop's scratch space.
struct Laws<'a> {
    model: &'a dyn Dynamics,
    nominal: &'a Nominal,
    rule: &'a FilterRule,
    barriers: &'a [Barrier],
}

impl Laws<'_> {
    /// work.nominal ← u0 (nominal at `time`, evaluated at `nominal_state`) and
    /// work.constraints ← the constraint data of every known barrier at state z. Returns
    /// the number of constraints (0 without a filter).
    fn nominal_and_constraints(&self, time: f64, nominal_state: &[f64], z: &[f64], work: &mut LawWorkspace) -> usize {
        self.nominal
            .input_into(time, nominal_state, work.nominal.as_mut_slice());
        let Some(form) = self.rule.form() else {
            return 0;
        };
        for (b, c) in self.barriers.iter().zip(work.constraints.iter_mut()) {
            work.lie.constraint_into(b, form, self.model, z, c);
        }
        self.barriers.len()
    }

    /// work.input ← the delay-free CBF-QP over all channels from work.nominal and the first
    /// `count` constraints: closed form (4.9) for one barrier without limits (no allocation),
    /// otherwise the numerical QP. Returns (active, infeasible, μ).
    fn delay_free_qp(&self, work: &mut LawWorkspace, count: usize) -> (bool, bool, f64) {
        let limits = match self.rule {
            FilterRule::DelayFree { limits, .. } => limits.as_ref(),
            _ => None,
        };
        work.input.copy_from(&work.nominal);
        match (&work.constraints[..count], limits) {
            ([c], None) => filter::cbf_qp_in_place(c, &mut work.input),
            (constraints, _) => {
                let o = filter::qp::cbf_qp_multi(
                    constraints,
                    &work.nominal,
                    limits.map(|(lo, hi)| (lo.as_slice(), hi.as_slice())),
                );
                work.input.copy_from(&o.input);
                (o.active, o.infeasible, o.mu)
            }
        }
    }

    /// u ← the delay-free safe law κ^DF (4.29) at z: u0 + ū (4.9) (κ_LB (3.27) for Ch. 3).
    fn delay_free(&self, time: f64, z: &[f64], work: &mut LawWorkspace, u: &mut [f64]) {
        if let FilterRule::LinearClfCbf(stabilizer) = self.rule {
            u.copy_from_slice(stabilizer.kappa_lb(&DVector::from_column_slice(z)).input.as_slice());
            return;
        }
        let count = self.nominal_and_constraints(time, z, z, work);
        if count == 0 {
            u.copy_from_slice(work.nominal.as_slice());
            return;
        }
        self.delay_free_qp(work, count);
        u.copy_from_slice(work.input.as_slice());
    }

    /// The filter's decision for channel i at tick t, from work.constraints and work.nominal
    /// at the channel's evaluation state. The distinct-delay filters take one barrier
    /// (checked when the episode is built).
    fn filter_channel(
        &self,
        queues: &[DelayQueue],
        i: usize,
        t: f64,
        work: &mut LawWorkspace,
        count: usize,
        omega: &mut DVector<f64>,
    ) -> Result<ChannelOutcome, DelayError> {
        // ω_j: commands already issued for the later channels that reach the plant together
        // with u_i(t), i.e. u_j(t − D_{j,i}) = channel j's applied input at t + D_i.
        let mut fill_omega = |from: usize| -> Result<(), DelayError> {
            let arrival = queues[i].profile().prediction_time(t);
            omega.fill(0.0);
            for j in from..queues.len() {
                omega[j] = queues[j].applied(arrival)?.value;
            }
            Ok(())
        };
        Ok(match self.rule {
            FilterRule::None | FilterRule::LinearClfCbf(_) | FilterRule::Chain { .. } => {
                unreachable!("no constraints for these rules")
            }
            FilterRule::DelayFree { .. } => {
                let (active, infeasible, mu) = self.delay_free_qp(work, count);
                ChannelOutcome {
                    input: work.input[i],
                    active,
                    infeasible,
                    mu,
                }
            }
            FilterRule::FixedChannel { phi, .. } => {
                let s = (*phi).max(i + 1);
                fill_omega(s)?;
                filter::fixed_channel(&work.constraints[0], &work.nominal, omega, i, s)
            }
            FilterRule::GammaM { m, gamma, .. } => {
                // k (4.68): the last channel with the same delay as i.
                let delay_i = queues[i].constant_delay();
                let k = (i..queues.len())
                    .take_while(|&j| queues[j].constant_delay() == delay_i)
                    .last()
                    .unwrap_or(i);
                fill_omega(k + 1)?;
                filter::gamma_m(&work.constraints[0], &work.nominal, omega, i, k, *m, *gamma)
            }
        })
    }
}

pub struct ControlLoop {
    pub model: Arc<dyn Dynamics>,
    pub nominal: Nominal,
    /// The safety filter.
    pub rule: FilterRule,
    pub queues: Vec<DelayQueue>,
    pub structure: Structure,
    /// Barriers currently known to the controller (add with [`ControlLoop::add_barrier`]).
    known_barriers: Vec<Barrier>,
    pub timestep: f64,
    pub control_period: f64,
    pub steps_per_tick: u64,
    /// RK4 step of the predictors: by default the control period when every delay is constant
    /// and a whole multiple of it (the applied inputs are then constant on that grid, so the
    /// coarser step loses only RK4 truncation error, measured by the consistency check), else
    /// h. A scenario may set a coarser multiple of the control period (`predictor.step`).
    pub predictor_step: f64,
    /// What the last control tick computed; `tick_ready` until the episode takes it.
    tick: Tick,
    tick_ready: bool,
    /// Applied input at the start of the current step (value, issue time) per channel.
    pub applied: Vec<(f64, f64)>,
    applied_buffer: Vec<f64>,
    /// Predictions waiting for their target time, per channel.
    pending: Vec<VecDeque<Prediction>>,
    work: TickWorkspace,
    /// An error raised inside the callback (reported after the step).
    pub error: Option<ControlError>,
    /// y(t0 + T) = z1 at the prescribed time, once reached (the ramp (5.28) needs it).
    output_at_end: Option<f64>,
    /// A disturbance ω_i(t) added to channel i's applied input ((4.12) with Z = G); unknown
    /// to the predictors.
    pub input_disturbance: Option<Box<dyn Fn(f64, usize) -> f64 + Send>>,
    /// When auditing chain reuse: the whole-window recomputation next to every reused chain.
    chain_audit: Option<ChainAudit>,
}

/// Every recursive prediction recomputed over its whole window next to the reused chain, and
/// the largest difference seen (what `control.chain_tolerance` costs; benchmarks report it).
struct ChainAudit {
    workspace: PredictorWorkspace,
    predictions: Vec<Prediction>,
    max_difference: f64,
    reused: u64,
}

impl ControlLoop {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: Arc<dyn Dynamics>,
        nominal: Nominal,
        rule: FilterRule,
        queues: Vec<DelayQueue>,
        structure: Structure,
        timestep: f64,
        steps_per_tick: u64,
    ) -> ControlLoop {
        let r = queues.len();
        let n = model.state_dim();
        let control_period = steps_per_tick as f64 * timestep;
        let predictor_step = if queues.iter().all(|q| on_tick_grid(q, control_period)) {
            control_period
        } else {
            timestep
        };
        let predictor = PredictorWorkspace::new(n, r);
        let work = TickWorkspace {
            state: DVector::zeros(n),
            predictions: predictor.predictions(),
            predictor,
            law: LawWorkspace {
                lie: LieWorkspace::new(model.as_ref()),
                constraints: Vec::new(),
                nominal: DVector::zeros(r),
                input: DVector::zeros(r),
            },
            omega: DVector::zeros(r),
            spare_states: Vec::new(),
        };
        ControlLoop {
            predictor_step,
            model,
            nominal,
            rule,
            queues,
            structure,
            known_barriers: Vec::new(),
            timestep,
            control_period,
            steps_per_tick,
            tick: Tick {
                time: 0.0,
                nominal: DVector::zeros(r),
                issued: DVector::zeros(r),
                outcomes: vec![None; r],
            },
            tick_ready: false,
            applied: vec![(0.0, 0.0); r],
            applied_buffer: Vec::with_capacity(r),
            pending: vec![VecDeque::new(); r],
            work,
            error: None,
            output_at_end: None,
            input_disturbance: None,
            chain_audit: None,
        }
    }

    /// Makes a barrier known to the controller (outside the callback: sizes the scratch space).
    pub fn add_barrier(&mut self, barrier: Barrier) {
        self.known_barriers.push(barrier);
        self.work.law.constraints.push(Constraint::zeros(self.queues.len()));
        // κ_j changed: the recursive chain computed with the old law no longer holds.
        self.work.predictor.invalidate_chain();
    }

    pub fn known_barriers(&self) -> &[Barrier] {
        &self.known_barriers
    }

    /// Sets the predictors' RK4 step to `steps` plant steps. The plant step h is always valid;
    /// anything else needs every delay constant and a whole multiple of the control period
    /// (the applied inputs are then constant on the control grid, so a step of one period is
    /// exact up to RK4 truncation; a coarser one switches inputs inside its RK4 steps and holds
    /// κ_j's commands over several periods, an approximation the /prediction records measure).
    pub fn set_predictor_step(&mut self, steps: u32) -> Result<(), String> {
        if steps != 1 && !self.queues.iter().all(|q| on_tick_grid(q, self.control_period)) {
            return Err("a predictor step other than the timestep needs constant delays that are whole multiples of the control period".into());
        }
        self.predictor_step = steps as f64 * self.timestep;
        Ok(())
    }

    /// Reuse of the recursive chain between ticks (see [`PredictorWorkspace::set_chain_reuse`]).
    pub fn set_chain_tolerance(&mut self, tolerance: f64) {
        self.work.predictor.set_chain_reuse(Some(tolerance));
    }

    /// Recomputes every reused recursive chain over its whole window too, and keeps the
    /// largest difference (doubles the predictor cost: for measurements, not for runs).
    pub fn audit_chain_reuse(&mut self) {
        let workspace = PredictorWorkspace::new(self.model.state_dim(), self.queues.len());
        self.chain_audit = Some(ChainAudit {
            predictions: workspace.predictions(),
            workspace,
            max_difference: 0.0,
            reused: 0,
        });
    }

    /// (largest max-norm difference between a reused and a recomputed prediction, predictions
    /// made from a reused chain) since [`ControlLoop::audit_chain_reuse`].
    pub fn chain_audit(&self) -> Option<(f64, u64)> {
        self.chain_audit.as_ref().map(|a| (a.max_difference, a.reused))
    }

    /// The last tick's record, once (after the step in which it ran).
    pub fn take_tick(&mut self) -> Option<&Tick> {
        std::mem::take(&mut self.tick_ready).then_some(&self.tick)
    }

    /// Ch. 5 tick: u = T⁻¹(filter(t, z, v_nom)) for a scalar-input chain (no delays).
    fn chain_tick(&mut self, t: f64, filter: &ChainFilter, transform: ChainTransform) -> Result<(), ControlError> {
        let x = &self.work.state;
        let u_nom = self.nominal.input(t, x)[0];
        let z = transform.to_chain(x);
        let v_nom = transform.chain_input(x, u_nom);
        let decision = match filter {
            ChainFilter::Ptsf(ptsf) => {
                if t >= ptsf.blow_up().end_time() - TICK_TOLERANCE * self.timestep && self.output_at_end.is_none() {
                    self.output_at_end = Some(z[0]);
                }
                ptsf.control(t, &z, v_nom, self.output_at_end)?
            }
            ChainFilter::Esf(esf) => esf.control(&z, v_nom)?,
        };
        let u = transform.plant_input(x, decision.input);
        self.queues[0].push(t, u)?;
        self.queues[0].discard_before(t);
        self.tick.time = t;
        self.tick.nominal[0] = u_nom;
        self.tick.issued[0] = u;
        self.tick.outcomes[0] = Some(ChannelOutcome {
            input: u,
            active: decision.overriding,
            infeasible: false,
            mu: f64::NAN,
        });
        self.tick_ready = true;
        Ok(())
    }

    /// One control tick at time t from the state in `work.state`.
    fn control_tick(&mut self, t: f64) -> Result<(), ControlError> {
        if let FilterRule::Chain { filter, transform } = &self.rule {
            let (filter, transform) = (filter.clone(), *transform);
            return self.chain_tick(t, &filter, transform);
        }
        let ControlLoop {
            model,
            nominal,
            rule,
            queues,
            structure,
            known_barriers,
            timestep,
            control_period,
            predictor_step,
            tick,
            tick_ready,
            pending,
            work,
            chain_audit,
            ..
        } = self;
        let TickWorkspace {
            state,
            predictions,
            predictor,
            law: law_work,
            omega,
            spare_states,
        } = work;
        let (model, nominal, rule, known_barriers) = (&*model, &*nominal, &*rule, &*known_barriers);
        let laws = Laws {
            model: model.as_ref(),
            nominal,
            rule,
            barriers: known_barriers,
        };
        // Predict only for a controller that uses predictions; otherwise every channel
        // evaluates at x(t) and nothing is pending for consistency checks.
        let uses_prediction = rule.uses_prediction() || nominal.uses_prediction();
        let structure = if uses_prediction { &*structure } else { &Structure::None };
        {
            let context = PredictorContext {
                model: model.as_ref(),
                queues,
                timestep: *predictor_step,
                control_period: *control_period,
            };
            // κ_j for commands not yet issued inside a recursive predictor's window: the
            // delay-free law (4.29) (exact for (4.30); for (4.44) and (4.67) the commands equal
            // it once predictions are consistent, Lemma 4.7).
            let mut kappa = |time: f64, z: &[f64], u: &mut [f64]| laws.delay_free(time, z, law_work, u);
            context.predict_into(structure, t, state.as_slice(), &mut kappa, predictor, predictions)?;
            if let Some(audit) = chain_audit {
                let ChainAudit {
                    workspace,
                    predictions: recomputed,
                    ..
                } = audit;
                context.predict_into(structure, t, state.as_slice(), &mut kappa, workspace, recomputed)?;
                for (p, q) in predictions.iter().zip(recomputed.iter()) {
                    if p.reused_chain {
                        audit.reused += 1;
                        let difference = (&p.state - &q.state).amax();
                        audit.max_difference = audit.max_difference.max(difference);
                    }
                }
            }
        }

        for (i, p) in predictions.iter().enumerate() {
            if let FilterRule::LinearClfCbf(stabilizer) = rule {
                // (3.33): channel i takes component i of QP-LB solved at p_i(t).
                let outcome = stabilizer.kappa_lb(&p.state);
                tick.nominal[i] = 0.0;
                tick.issued[i] = outcome.input[i];
                tick.outcomes[i] = Some(ChannelOutcome {
                    input: outcome.input[i],
                    active: outcome.case != QpCase::A,
                    infeasible: outcome.infeasible,
                    mu: f64::NAN,
                });
                continue;
            }
            let eval_state = if rule.uses_prediction() { &p.state } else { &*state };
            let (nominal_time, nominal_state) = if nominal.uses_prediction() {
                (p.target_time, &p.state)
            } else {
                (t, eval_state)
            };
            let count =
                laws.nominal_and_constraints(nominal_time, nominal_state.as_slice(), eval_state.as_slice(), law_work);
            let outcome = if count == 0 {
                None
            } else {
                Some(laws.filter_channel(queues, i, t, law_work, count, omega)?)
            };
            tick.nominal[i] = law_work.nominal[i];
            tick.issued[i] = outcome.map_or(law_work.nominal[i], |o| o.input);
            tick.outcomes[i] = outcome;
        }
        for (i, queue) in queues.iter_mut().enumerate() {
            queue.push(t, tick.issued[i])?;
            queue.discard_before(t);
        }
        for p in predictions.iter() {
            if p.target_time > t + TICK_TOLERANCE * *timestep {
                let mut state = spare_states.pop().unwrap_or_else(|| p.state.clone());
                state.copy_from(&p.state);
                pending[p.channel].push_back(Prediction {
                    channel: p.channel,
                    issued_at: p.issued_at,
                    target_time: p.target_time,
                    state,
                    reused_chain: p.reused_chain,
                    chain_mismatch: p.chain_mismatch,
                });
            }
        }
        tick.time = t;
        *tick_ready = true;
        Ok(())
    }

    /// Predictions whose target time falls in [t_k, t_k + h), compared with the realised state:
    /// x(t_k) itself, or x(t_k) advanced to an off-grid target with the applied inputs.
    /// Hand them back with [`ControlLoop::recycle`] once logged.
    pub fn realize(&mut self, t_k: f64, x_k: &DVector<f64>) -> Result<Vec<Consistency>, DelayError> {
        let h = self.timestep;
        let mut out = Vec::new();
        for channel in 0..self.pending.len() {
            while let Some(p) = self.pending[channel].front() {
                if p.target_time >= t_k + h * (1.0 - TICK_TOLERANCE) {
                    break;
                }
                let p = self.pending[channel].pop_front().expect("front exists");
                let realized = if (p.target_time - t_k).abs() <= h * TICK_TOLERANCE {
                    x_k.clone()
                } else {
                    let context = PredictorContext {
                        model: self.model.as_ref(),
                        queues: &self.queues,
                        timestep: h,
                        control_period: self.control_period,
                    };
                    context.advance_with_history(x_k, t_k, p.target_time)?
                };
                out.push(Consistency {
                    prediction: p,
                    realized,
                });
            }
        }
        Ok(out)
    }

    /// Returns a realised prediction's storage for reuse by later ticks.
    pub fn recycle(&mut self, consistency: Consistency) {
        self.work.spare_states.push(consistency.prediction.state);
    }
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
        let step_time = step as f64 * self.timestep;
        if call_in_step == 0 && step.is_multiple_of(self.steps_per_tick) && self.error.is_none() {
            state(self.work.state.as_mut_slice());
            if let Err(e) = self.control_tick(step_time) {
                self.error = Some(e);
            }
        }
        // Sample at the call's offset inside this step, kept in [t_k, t_k + h): RK4's last
        // stage (at t_k + h) takes the left limit, so a constant-delay input is constant over
        // the step.
        let offset = offset.clamp(0.0, self.timestep * (1.0 - TICK_TOLERANCE));
        let sample_time = step_time + offset;
        self.applied_buffer.clear();
        for (i, queue) in self.queues.iter().enumerate() {
            let applied = match queue.applied(sample_time) {
                Ok(a) => a,
                Err(e) => {
                    self.error.get_or_insert(e.into());
                    crate::delay::Applied {
                        value: 0.0,
                        issued_at: f64::NAN,
                    }
                }
            };
            let value = applied.value + self.input_disturbance.as_ref().map_or(0.0, |w| w(sample_time, i));
            if call_in_step == 0 {
                self.applied[i] = (value, applied.issued_at);
            }
            self.applied_buffer.push(value);
        }
        &self.applied_buffer
    }
}

/// Picks the predictor structure, as an error message for the scenario's `delays` key.
pub fn predictor_structure(queues: &[DelayQueue], control_period: f64) -> Result<Structure, String> {
    predictor::structure(queues, control_period)
}
