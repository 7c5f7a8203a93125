//! What the controller sees (issue 16, part 3): a sensor that reports the true state `latency`
//! seconds late, offset by a constant bias and seeded Gaussian noise per component:
//!
//! x̂(t_k) = x(t_k − latency) + bias + diag(σ) n_k,   n_k ~ N(0, I) drawn from (seed, step k).
//!
//! The predictors, the nominal controller and the filter work from x̂; the plant, the barriers
//! in the log and the prediction-consistency check keep the true state. Before the first
//! reading is `latency` old, the sensor reports x(0) (it has seen nothing earlier).

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{ControlSettings, Section, SectionContext};

/// Most values the sensor's ring of past true states may hold ((latency/h + 1) × state size):
/// 10⁷ doubles, 80 MB.
pub const MAX_SENSOR_HISTORY: usize = 10_000_000;

/// The sensor the controller reads (`[sensing]`): the section's spec, checks and build.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensingSpec {
    /// Age of every reading (seconds, a whole multiple of the timestep; default 0).
    #[serde(default)]
    pub latency: f64,
    /// Standard deviation of the seeded Gaussian noise per state component (default: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_std: Option<Vec<f64>>,
    /// Constant offset per state component (default: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bias: Option<Vec<f64>>,
}

impl SensingSpec {
    /// The checks of the section's own values when the scenario loads: a latency of 0 to the
    /// run's `duration` (a reading older than the run is x(0) throughout); noise and bias one
    /// finite value per state component (`state_dim`, as `vehicle.initial_state`) within
    /// ±`extent`, the noise ≥ 0. Keys are the scenario's (`sensing.latency`).
    pub fn validate(&self, state_dim: usize, duration: f64, extent: f64) -> Result<(), ParamError> {
        if !(self.latency.is_finite() && self.latency >= 0.0) {
            return Err(ParamError::new(
                "sensing.latency",
                format!("expected a latency >= 0 seconds, found {}", self.latency),
            ));
        }
        // The sensor keeps a ring of latency/h + 1 past true states: bounded by the run first.
        if self.latency > duration {
            return Err(ParamError::new(
                "sensing.latency",
                format!(
                    "expected at most the run's duration {duration} s (a reading older than the run is x(0) throughout), found {}",
                    self.latency
                ),
            ));
        }
        let n = state_dim;
        for (name, values, non_negative) in [("noise_std", &self.noise_std, true), ("bias", &self.bias, false)] {
            let Some(values) = values else { continue };
            if values.len() != n {
                return Err(ParamError::new(
                    format!("sensing.{name}"),
                    format!(
                        "expected one value per state component ({n}, as vehicle.initial_state), found {}",
                        values.len()
                    ),
                ));
            }
            if values
                .iter()
                .any(|v| !v.is_finite() || (non_negative && *v < 0.0) || v.abs() > extent)
            {
                let expected = if non_negative {
                    "finite numbers >= 0"
                } else {
                    "finite numbers"
                };
                return Err(ParamError::new(
                    format!("sensing.{name}"),
                    format!("expected {expected} within ±{extent:e}"),
                ));
            }
        }
        Ok(())
    }

    /// The sensor of a run at plant step `timestep` for a model of `state_dim` components (the
    /// checks that need them: a latency of whole steps, a ring of at most
    /// [`MAX_SENSOR_HISTORY`] values).
    pub fn build(&self, state_dim: usize, timestep: f64, seed: u64) -> Result<Sensor, ParamError> {
        let steps = self.latency / timestep;
        if (steps - steps.round()).abs() > 1e-6 {
            return Err(ParamError::new(
                "sensing.latency",
                format!(
                    "expected a whole multiple of the timestep {timestep} s, found {}",
                    self.latency
                ),
            ));
        }
        let n = state_dim;
        if (steps + 1.0) * n as f64 > MAX_SENSOR_HISTORY as f64 {
            return Err(ParamError::new(
                "sensing.latency",
                format!(
                    "{} s is {} steps of {timestep} s: the sensor's ring of past states would hold {:.4e} values, more than the limit of {MAX_SENSOR_HISTORY:e} (expected a latency of at most {} steps)",
                    self.latency,
                    steps.round(),
                    (steps.round() + 1.0) * n as f64,
                    MAX_SENSOR_HISTORY / n.max(1) - 1
                ),
            ));
        }
        let or_zeros = |v: &Option<Vec<f64>>| v.clone().unwrap_or_else(|| vec![0.0; n]);
        Ok(Sensor::new(
            n,
            steps.round() as usize,
            or_zeros(&self.noise_std),
            or_zeros(&self.bias),
            seed,
        ))
    }
}

/// The sensor of one episode (the maths crate's).
pub use mjsafe_maths::sensor::Sensor;

/// `[sensing]`: the controller reads the sensor's measurement.
impl Section for SensingSpec {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        SensingSpec::validate(self, cx.state_dim, cx.duration, cx.state_extent)
    }

    fn configure(&self, cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        control.set_sensor(self.build(control.state_dim(), control.timestep(), cx.seed)?);
        Ok(())
    }
}
