//! Actuator dynamics unknown to the controller (issue 16, part 5): per channel, the input the
//! plant receives, a, follows the delayed command u through a magnitude limit, a rate limit R
//! and a first-order lag τ:
//!
//! ȧ = clamp((sat(u) − a) / τ, −R, R),   sat(u) = clamp(u, min, max)
//!
//! (τ = 0: a moves to sat(u) at rate R; no rate limit: R = ∞). The command is held over a
//! plant step, so the step is solved exactly and the plant receives a's mean over the step
//! (one value for every RK4 stage of it).

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{ControlSettings, Section, SectionContext};

/// One channel's actuator dynamics (`[actuator_dynamics.<channel>]`): the section's spec,
/// checks and build.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorDynamicsSpec {
    /// First-order lag τ (seconds, >= 0; 0: none).
    #[serde(default)]
    pub time_constant: f64,
    /// Largest |da/dt| (input units per second, > 0; absent: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_limit: Option<f64>,
    /// Smallest input the actuator produces (absent: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
    /// Largest input the actuator produces (absent: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
}

impl ActuatorDynamicsSpec {
    /// The checks of channel `channel`'s table when the scenario loads: τ ≥ 0, a positive
    /// rate limit, finite bounds with min ≤ max. Keys are the scenario's
    /// (`actuator_dynamics.<channel>.rate_limit`).
    pub fn validate(&self, channel: &str) -> Result<(), ParamError> {
        let key = format!("actuator_dynamics.{channel}");
        if !(self.time_constant.is_finite() && self.time_constant >= 0.0) {
            return Err(ParamError::new(
                format!("{key}.time_constant"),
                format!("expected a lag >= 0 seconds, found {}", self.time_constant),
            ));
        }
        if let Some(rate) = self.rate_limit {
            if !(rate.is_finite() && rate > 0.0) {
                return Err(ParamError::new(
                    format!("{key}.rate_limit"),
                    format!("expected a positive rate (input units per second), found {rate}"),
                ));
            }
        }
        for (name, bound) in [("min", self.min), ("max", self.max)] {
            if bound.is_some_and(|b| !b.is_finite()) {
                return Err(ParamError::new(format!("{key}.{name}"), "expected a finite number"));
            }
        }
        if let (Some(lo), Some(hi)) = (self.min, self.max) {
            if lo > hi {
                return Err(ParamError::new(
                    format!("{key}.max"),
                    format!("expected max >= min ({lo}), found {hi}"),
                ));
            }
        }
        Ok(())
    }

    /// The channel's actuator, at rest at its initial input.
    pub fn build(&self, initial: f64) -> Actuator {
        let limits = ActuatorLimits {
            time_constant: self.time_constant,
            rate_limit: self.rate_limit.unwrap_or(f64::INFINITY),
            min: self.min.unwrap_or(f64::NEG_INFINITY),
            max: self.max.unwrap_or(f64::INFINITY),
        };
        Actuator::new(limits, initial)
    }
}

/// One channel's actuator and its limits (the maths crate's).
pub use mjsafe_maths::actuation::{Actuator, ActuatorLimits};

/// `[actuator_dynamics.<channel>]`: each channel's actuator, at rest at its initial input.
impl Section for std::collections::BTreeMap<String, ActuatorDynamicsSpec> {
    fn validate(&self, _key: &str, _cx: &SectionContext<'_>) -> Result<(), ParamError> {
        self.iter().try_for_each(|(channel, a)| a.validate(channel))
    }

    fn configure(&self, cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        for (i, channel) in control.channel_names().iter().enumerate() {
            if let Some(spec) = self.get(channel) {
                control.set_actuator(i, spec.build(cx.initial_input.get(channel).copied().unwrap_or(0.0)));
            }
        }
        Ok(())
    }
}
