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

use crate::barrier::{self, Barrier, BarrierForm, Constraint};
use crate::delay::{DelayError, DelayQueue};
use crate::filter::linear_delays::{ConstrainedStabilizer, QpCase};
use crate::filter::prescribed_time::{EsfFilter, PrescribedTimeError, PtsfFilter, StrictFeedbackSystem};
use crate::filter::{self, ChannelOutcome};
use crate::nominal::Nominal;
use crate::plant::Controller;
use crate::predictor::{self, Prediction, PredictorContext, Structure};
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

pub struct ControlLoop {
    pub model: Arc<dyn Dynamics>,
    pub nominal: Nominal,
    /// The safety filter.
    pub rule: FilterRule,
    pub queues: Vec<DelayQueue>,
    pub structure: Structure,
    /// Barriers currently known to the controller.
    pub known_barriers: Vec<Barrier>,
    pub timestep: f64,
    pub control_period: f64,
    pub steps_per_tick: u64,
    /// RK4 step of the predictors: the control period when every delay is constant and a
    /// whole multiple of it (the applied inputs are then constant on that grid, so the coarser
    /// step loses only RK4 truncation error, measured by the consistency check), else h.
    pub predictor_step: f64,
    /// Set at the tick of the current step, taken by the episode after the step.
    pub tick: Option<Tick>,
    /// Applied input at the start of the current step (value, issue time) per channel.
    pub applied: Vec<(f64, f64)>,
    applied_buffer: Vec<f64>,
    /// Predictions waiting for their target time, per channel.
    pending: Vec<VecDeque<Prediction>>,
    /// An error raised inside the callback (reported after the step).
    pub error: Option<ControlError>,
    /// y(t0 + T) = z1 at the prescribed time, once reached (the ramp (5.28) needs it).
    output_at_end: Option<f64>,
    /// A disturbance ω(t) added to the applied input ((4.12) with Z = G); unknown to the
    /// predictors.
    pub input_disturbance: Option<Box<dyn Fn(f64) -> DVector<f64> + Send>>,
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
        let control_period = steps_per_tick as f64 * timestep;
        let on_tick_grid = |q: &DelayQueue| {
            q.constant_delay().is_some_and(|d| {
                let ticks = d / control_period;
                (ticks - ticks.round()).abs() < 1e-6
            })
        };
        let predictor_step = if queues.iter().all(on_tick_grid) {
            control_period
        } else {
            timestep
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
            tick: None,
            applied: vec![(0.0, 0.0); r],
            applied_buffer: Vec::with_capacity(r),
            pending: vec![VecDeque::new(); r],
            error: None,
            output_at_end: None,
            input_disturbance: None,
        }
    }

    /// u0 (nominal at `time`, evaluated at `nominal_state`) and the constraint data of every
    /// known barrier at state z (empty without a filter).
    fn nominal_and_constraints(
        &self,
        time: f64,
        nominal_state: &DVector<f64>,
        z: &DVector<f64>,
    ) -> (DVector<f64>, Vec<Constraint>) {
        let u0 = self.nominal.input(time, nominal_state);
        let constraints = match self.rule.form() {
            Some(form) => self
                .known_barriers
                .iter()
                .map(|b| barrier::constraint(b, form, self.model.as_ref(), z))
                .collect(),
            None => Vec::new(),
        };
        (u0, constraints)
    }

    /// The delay-free CBF-QP over all channels: closed form (4.9) for one barrier without
    /// limits, otherwise the numerical QP.
    fn delay_free_qp(&self, constraints: &[Constraint], u0: &DVector<f64>) -> (DVector<f64>, bool, bool, f64) {
        let limits = match &self.rule {
            FilterRule::DelayFree { limits, .. } => limits.as_ref(),
            _ => None,
        };
        match (constraints, limits) {
            ([c], None) => {
                let o = filter::cbf_qp(c, u0);
                (o.input, o.active, o.infeasible, o.mu)
            }
            _ => {
                let o =
                    filter::qp::cbf_qp_multi(constraints, u0, limits.map(|(lo, hi)| (lo.as_slice(), hi.as_slice())));
                (o.input, o.active, o.infeasible, o.mu)
            }
        }
    }

    /// The delay-free safe law κ^DF (4.29) at z: u0 + ū (4.9) (κ_LB (3.27) for Ch. 3).
    fn delay_free(&self, time: f64, z: &DVector<f64>) -> DVector<f64> {
        if let FilterRule::LinearClfCbf(stabilizer) = &self.rule {
            return stabilizer.kappa_lb(z).input;
        }
        let (u0, constraints) = self.nominal_and_constraints(time, z, z);
        if constraints.is_empty() {
            return u0;
        }
        self.delay_free_qp(&constraints, &u0).0
    }

    /// Ch. 5 tick: u = T⁻¹(filter(t, z, v_nom)) for a scalar-input chain (no delays).
    fn chain_tick(
        &mut self,
        t: f64,
        x: &DVector<f64>,
        filter: &ChainFilter,
        transform: ChainTransform,
    ) -> Result<(), ControlError> {
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
        let outcome = ChannelOutcome {
            input: u,
            active: decision.overriding,
            infeasible: false,
            mu: f64::NAN,
        };
        self.tick = Some(Tick {
            time: t,
            nominal: DVector::from_element(1, u_nom),
            issued: DVector::from_element(1, u),
            outcomes: vec![Some(outcome)],
        });
        Ok(())
    }

    fn control_tick(&mut self, t: f64, x: &DVector<f64>) -> Result<(), ControlError> {
        if let FilterRule::Chain { filter, transform } = &self.rule {
            let (filter, transform) = (filter.clone(), *transform);
            return self.chain_tick(t, x, &filter, transform);
        }
        let context = PredictorContext {
            model: self.model.as_ref(),
            queues: &self.queues,
            timestep: self.predictor_step,
            control_period: self.control_period,
        };
        // κ_j for commands not yet issued inside a recursive predictor's window: the
        // delay-free law (4.29) (exact for (4.30); for (4.44) and (4.67) the commands equal it
        // once predictions are consistent, Lemma 4.7).
        let law = |time: f64, z: &DVector<f64>| self.delay_free(time, z);
        // Predict only for a controller that uses predictions; otherwise every channel
        // evaluates at x(t) and nothing is pending for consistency checks.
        let uses_prediction = self.rule.uses_prediction() || self.nominal.uses_prediction();
        let structure = if uses_prediction {
            &self.structure
        } else {
            &Structure::None
        };
        let predictions = context.predict(structure, t, x, &law)?;

        let r = self.queues.len();
        let mut nominal = DVector::zeros(r);
        let mut issued = DVector::zeros(r);
        let mut outcomes = Vec::with_capacity(r);
        for (i, p) in predictions.iter().enumerate() {
            if let FilterRule::LinearClfCbf(stabilizer) = &self.rule {
                // (3.33): channel i takes component i of QP-LB solved at p_i(t).
                let outcome = stabilizer.kappa_lb(&p.state);
                issued[i] = outcome.input[i];
                outcomes.push(Some(ChannelOutcome {
                    input: issued[i],
                    active: outcome.case != QpCase::A,
                    infeasible: outcome.infeasible,
                    mu: f64::NAN,
                }));
                continue;
            }
            let eval_state = if self.rule.uses_prediction() { &p.state } else { x };
            let (nominal_time, nominal_state) = if self.nominal.uses_prediction() {
                (p.target_time, &p.state)
            } else {
                (t, eval_state)
            };
            let (u0, constraints) = self.nominal_and_constraints(nominal_time, nominal_state, eval_state);
            let outcome = if constraints.is_empty() {
                None
            } else {
                Some(self.filter_channel(i, t, &constraints, &u0)?)
            };
            nominal[i] = u0[i];
            issued[i] = outcome.map_or(u0[i], |o| o.input);
            outcomes.push(outcome);
        }
        for (i, queue) in self.queues.iter_mut().enumerate() {
            queue.push(t, issued[i])?;
            queue.discard_before(t);
        }
        for p in predictions {
            if p.target_time > t + TICK_TOLERANCE * self.timestep {
                self.pending[p.channel].push_back(p);
            }
        }
        self.tick = Some(Tick {
            time: t,
            nominal,
            issued,
            outcomes,
        });
        Ok(())
    }

    /// The filter's decision for channel i at tick t, from the constraints at the channel's
    /// evaluation state and u0 there. The distinct-delay filters take one barrier (checked
    /// when the episode is built).
    fn filter_channel(
        &self,
        i: usize,
        t: f64,
        constraints: &[Constraint],
        u0: &DVector<f64>,
    ) -> Result<ChannelOutcome, DelayError> {
        // ω_j: commands already issued for the later channels that reach the plant together
        // with u_i(t), i.e. u_j(t − D_{j,i}) = channel j's applied input at t + D_i.
        let omega = |from: usize| -> Result<DVector<f64>, DelayError> {
            let arrival = self.queues[i].profile().prediction_time(t);
            let mut omega = DVector::zeros(u0.len());
            for j in from..u0.len() {
                omega[j] = self.queues[j].applied(arrival)?.value;
            }
            Ok(omega)
        };
        Ok(match &self.rule {
            FilterRule::None | FilterRule::LinearClfCbf(_) | FilterRule::Chain { .. } => {
                unreachable!("no constraints for these rules")
            }
            FilterRule::DelayFree { .. } => {
                let (input, active, infeasible, mu) = self.delay_free_qp(constraints, u0);
                ChannelOutcome {
                    input: input[i],
                    active,
                    infeasible,
                    mu,
                }
            }
            FilterRule::FixedChannel { phi, .. } => {
                let s = (*phi).max(i + 1);
                filter::fixed_channel(&constraints[0], u0, &omega(s)?, i, s)
            }
            FilterRule::GammaM { m, gamma, .. } => {
                // k (4.68): the last channel with the same delay as i.
                let delay_i = self.queues[i].constant_delay();
                let k = (i..u0.len())
                    .take_while(|&j| self.queues[j].constant_delay() == delay_i)
                    .last()
                    .unwrap_or(i);
                filter::gamma_m(&constraints[0], u0, &omega(k + 1)?, i, k, *m, *gamma)
            }
        })
    }

    /// Predictions whose target time falls in [t_k, t_k + h), compared with the realised state:
    /// x(t_k) itself, or x(t_k) advanced to an off-grid target with the applied inputs.
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
}

impl Controller for ControlLoop {
    fn input(&mut self, step: u64, call_in_step: u32, offset: f64, state: &dyn Fn() -> DVector<f64>) -> &[f64] {
        let step_time = step as f64 * self.timestep;
        if call_in_step == 0 && step % self.steps_per_tick == 0 && self.error.is_none() {
            let x = state();
            if let Err(e) = self.control_tick(step_time, &x) {
                self.error = Some(e);
            }
        }
        // Sample at the call's offset inside this step, kept in [t_k, t_k + h): RK4's last
        // stage (at t_k + h) takes the left limit, so a constant-delay input is constant over
        // the step.
        let offset = offset.clamp(0.0, self.timestep * (1.0 - TICK_TOLERANCE));
        let sample_time = step_time + offset;
        self.applied_buffer.clear();
        let disturbance = self.input_disturbance.as_ref().map(|w| w(sample_time));
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
            let value = applied.value + disturbance.as_ref().map_or(0.0, |w| w[i]);
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
