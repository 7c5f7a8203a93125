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

use crate::barrier::{self, Barrier, BarrierForm};
use crate::delay::{DelayError, DelayQueue};
use crate::filter::{self, FilterOutcome};
use crate::nominal::Nominal;
use crate::plant::Controller;
use crate::predictor::{self, Prediction, PredictorContext, Structure};
use crate::scenario::Compensation;
use crate::vehicle::Dynamics;

/// Fraction of a step below which two times are the same instant.
pub const TICK_TOLERANCE: f64 = 1e-6;

/// What one control tick computed (logged after the step).
#[derive(Debug, Clone)]
pub struct Tick {
    pub time: f64,
    /// u0 per channel (component i of the nominal at channel i's evaluation state).
    pub nominal: DVector<f64>,
    /// Issued command per channel.
    pub issued: DVector<f64>,
    /// The filter outcome per channel (None when no barrier is known or no filter is set).
    pub outcomes: Vec<Option<FilterOutcome>>,
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
    /// The safety filter's barrier form, None without a filter.
    pub form: Option<BarrierForm>,
    pub compensation: Compensation,
    pub queues: Vec<DelayQueue>,
    pub structure: Structure,
    /// Barriers currently known to the controller.
    pub known_barriers: Vec<Barrier>,
    pub timestep: f64,
    pub control_period: f64,
    pub steps_per_tick: u64,
    /// Set at the tick of the current step, taken by the episode after the step.
    pub tick: Option<Tick>,
    /// Applied input at the start of the current step (value, issue time) per channel.
    pub applied: Vec<(f64, f64)>,
    applied_buffer: Vec<f64>,
    /// Predictions waiting for their target time, per channel.
    pending: Vec<VecDeque<Prediction>>,
    /// An error raised inside the callback (reported after the step).
    pub error: Option<DelayError>,
}

impl ControlLoop {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: Arc<dyn Dynamics>,
        nominal: Nominal,
        form: Option<BarrierForm>,
        compensation: Compensation,
        queues: Vec<DelayQueue>,
        structure: Structure,
        timestep: f64,
        steps_per_tick: u64,
    ) -> ControlLoop {
        let r = queues.len();
        ControlLoop {
            model,
            nominal,
            form,
            compensation,
            queues,
            structure,
            known_barriers: Vec::new(),
            timestep,
            control_period: steps_per_tick as f64 * timestep,
            steps_per_tick,
            tick: None,
            applied: vec![(0.0, 0.0); r],
            applied_buffer: Vec::with_capacity(r),
            pending: vec![VecDeque::new(); r],
            error: None,
        }
    }

    /// The delay-free safe law κ^DF (4.29): u0 + ū (4.9) at state z (nominal at time `time`).
    fn delay_free(
        &self,
        time: f64,
        nominal_state: &DVector<f64>,
        z: &DVector<f64>,
    ) -> (DVector<f64>, Option<FilterOutcome>) {
        let u0 = self.nominal.input(time, nominal_state);
        match (self.form, self.known_barriers.first()) {
            (Some(form), Some(b)) => {
                let c = barrier::constraint(b, form, self.model.as_ref(), z);
                let outcome = filter::cbf_qp(&c, &u0);
                (u0, Some(outcome))
            }
            _ => (u0, None),
        }
    }

    fn control_tick(&mut self, t: f64, x: &DVector<f64>) -> Result<(), DelayError> {
        let context = PredictorContext {
            model: self.model.as_ref(),
            queues: &self.queues,
            timestep: self.timestep,
            control_period: self.control_period,
        };
        // κ_j for commands not yet issued inside a recursive predictor's window.
        let law = |time: f64, z: &DVector<f64>| {
            let (u0, outcome) = self.delay_free(time, z, z);
            outcome.map_or(u0, |o| o.input)
        };
        // Predict only for a controller that uses predictions; otherwise every channel
        // evaluates at x(t) and nothing is pending for consistency checks.
        let uses_prediction = self.compensation == Compensation::Predictor || self.nominal.uses_prediction();
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
        // Channels sharing an evaluation point share one filter solve.
        struct Solved {
            nominal_time: f64,
            nominal_state: DVector<f64>,
            eval_state: DVector<f64>,
            u0: DVector<f64>,
            outcome: Option<FilterOutcome>,
        }
        let mut solved: Vec<Solved> = Vec::new();
        for (i, p) in predictions.iter().enumerate() {
            let eval_state = match self.compensation {
                Compensation::Predictor => &p.state,
                Compensation::None => x,
            };
            let (nominal_time, nominal_state) = if self.nominal.uses_prediction() {
                (p.target_time, &p.state)
            } else {
                (t, eval_state)
            };
            let found = solved.iter().position(|s| {
                s.nominal_time == nominal_time && &s.nominal_state == nominal_state && &s.eval_state == eval_state
            });
            let k = found.unwrap_or_else(|| {
                let (u0, outcome) = self.delay_free(nominal_time, nominal_state, eval_state);
                solved.push(Solved {
                    nominal_time,
                    nominal_state: nominal_state.clone(),
                    eval_state: eval_state.clone(),
                    u0,
                    outcome,
                });
                solved.len() - 1
            });
            let s = &solved[k];
            nominal[i] = s.u0[i];
            issued[i] = s.outcome.as_ref().map_or(s.u0[i], |o| o.input[i]);
            outcomes.push(s.outcome.clone());
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
        for (i, queue) in self.queues.iter().enumerate() {
            let applied = match queue.applied(sample_time) {
                Ok(a) => a,
                Err(e) => {
                    self.error.get_or_insert(e);
                    crate::delay::Applied {
                        value: 0.0,
                        issued_at: f64::NAN,
                    }
                }
            };
            if call_in_step == 0 {
                self.applied[i] = (applied.value, applied.issued_at);
            }
            self.applied_buffer.push(applied.value);
        }
        &self.applied_buffer
    }
}

/// Picks the predictor structure, as an error message for the scenario's `delays` key.
pub fn predictor_structure(queues: &[DelayQueue], control_period: f64) -> Result<Structure, String> {
    predictor::structure(queues, control_period)
}
