//! The `[control]` table: the control loop's timing — its period, the issued-input history
//! kept, the predictors' step and chain reuse, and whether road users out of reach form rows —
//! with its checks at load ([`ControlSpec::validate`]). The loop it configures is
//! `episode::control`.

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{ControlSettings, Section, SectionContext};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSpec {
    /// Control period in seconds, a whole multiple of the timestep (default: the timestep).
    #[serde(default)]
    pub period: Option<f64>,
    /// Seconds of issued-input history kept; a delay longer than this is an error.
    #[serde(default = "default_history")]
    pub history: f64,
    /// RK4 step of the predictors in seconds, a whole multiple of the period (default: the
    /// period when every delay is constant and a whole multiple of it, else the timestep).
    /// Coarser is faster; the log's /prediction records measure what it costs in accuracy.
    #[serde(default)]
    pub predictor_step: Option<f64>,
    /// Predictors: continue the previous tick's prediction trajectory when the fresh p_1 (x(t)
    /// for one shared delay profile) lands within this distance of it (state units: the largest
    /// of the planar position's distance and every other component's difference), else
    /// integrate the whole window.
    /// 0 reuses only an exact match; the log's /prediction records say which ticks reused.
    #[serde(default = "default_chain_tolerance")]
    pub chain_tolerance: f64,
    /// Road users out of reach form no barrier row (docs/actors.md, "Out of reach"); `false`
    /// forms every row of the road users that exist at every evaluation (the same commands, at
    /// their full cost).
    #[serde(default = "default_leave_out_of_reach", skip_serializing_if = "is_true")]
    pub leave_out_of_reach: bool,
}

impl Default for ControlSpec {
    fn default() -> Self {
        ControlSpec {
            period: None,
            predictor_step: None,
            history: default_history(),
            chain_tolerance: default_chain_tolerance(),
            leave_out_of_reach: default_leave_out_of_reach(),
        }
    }
}

fn default_leave_out_of_reach() -> bool {
    true
}

fn is_true(value: &bool) -> bool {
    *value
}

fn default_history() -> f64 {
    30.0
}

/// See docs/performance.md (predictor chain reuse) for the measurement behind it.
pub const DEFAULT_CHAIN_TOLERANCE: f64 = 1e-4;

fn default_chain_tolerance() -> f64 {
    DEFAULT_CHAIN_TOLERANCE
}

impl ControlSpec {
    /// The period and the history are positive durations (s); the period's fit to the timestep
    /// and the predictor step's to the period are checked with the model (`episode::build`).
    pub fn validate(&self) -> Result<(), ParamError> {
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.history) {
            return Err(ParamError::new(
                "control.history",
                format!("expected a positive number of seconds, found {}", self.history),
            ));
        }
        if let Some(period) = self.period.filter(|p| !positive(*p)) {
            return Err(ParamError::new(
                "control.period",
                format!("expected a positive number of seconds, found {period}"),
            ));
        }
        let tolerance = self.chain_tolerance;
        if !(tolerance >= 0.0 && tolerance.is_finite()) {
            return Err(ParamError::new(
                "control.chain_tolerance",
                format!("expected a finite distance >= 0, got {tolerance}"),
            ));
        }
        Ok(())
    }
}

/// `[control]`: the predictor step, the chain reuse and the rows left out of reach are set in
/// the loop; the period and the history are read where the loop and its queues are built.
impl Section for ControlSpec {
    fn validate(&self, _key: &str, _cx: &SectionContext<'_>) -> Result<(), ParamError> {
        ControlSpec::validate(self)
    }

    fn configure(&self, _cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        if let Some(step) = self.predictor_step {
            let timestep = control.timestep();
            let steps = step / timestep;
            if !(steps >= 0.5 && (steps - steps.round()).abs() < 1e-6) {
                return Err(ParamError::new(
                    "control.predictor_step",
                    format!("expected a whole multiple of the timestep {timestep} s, got {step}"),
                ));
            }
            control
                .set_predictor_step(steps.round() as u32)
                .map_err(|e| ParamError::new("control.predictor_step", e))?;
        }
        control.set_chain_tolerance(self.chain_tolerance);
        control.set_leave_out_of_reach(self.leave_out_of_reach);
        Ok(())
    }
}
