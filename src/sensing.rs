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
use crate::random::{standard_normal, Stream};

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

/// The sensor of one episode: a ring of the last `latency_steps + 1` true states.
#[derive(Debug, Clone)]
pub struct Sensor {
    state_dim: usize,
    latency_steps: usize,
    noise_std: Vec<f64>,
    bias: Vec<f64>,
    seed: u64,
    /// True states at the starts of the last `latency_steps + 1` steps, step k in slot
    /// k mod (latency_steps + 1), flattened.
    history: Vec<f64>,
}

impl Sensor {
    /// A sensor for `state_dim` components, `latency_steps` plant steps late; `noise_std` and
    /// `bias` have one entry per component (checked by the scenario).
    pub fn new(state_dim: usize, latency_steps: usize, noise_std: Vec<f64>, bias: Vec<f64>, seed: u64) -> Sensor {
        debug_assert!(noise_std.len() == state_dim && bias.len() == state_dim);
        Sensor {
            state_dim,
            latency_steps,
            noise_std,
            bias,
            seed,
            history: vec![0.0; (latency_steps + 1) * state_dim],
        }
    }

    /// Plant steps between the true state and its report.
    pub fn latency_steps(&self) -> usize {
        self.latency_steps
    }

    fn slot(&self, step: u64) -> std::ops::Range<usize> {
        let start = (step % (self.latency_steps as u64 + 1)) as usize * self.state_dim;
        start..start + self.state_dim
    }

    /// Records the true state at the start of `step`. Every step must be recorded, in order,
    /// when the sensor has a latency; otherwise only the steps that are measured.
    pub fn record(&mut self, step: u64, true_state: &[f64]) {
        let slot = self.slot(step);
        self.history[slot].copy_from_slice(true_state);
    }

    /// measured ← x̂ at the start of `step` (after [`Sensor::record`] of that step).
    pub fn measure_into(&self, step: u64, measured: &mut [f64]) {
        let source = step.saturating_sub(self.latency_steps as u64);
        let truth = &self.history[self.slot(source)];
        for (j, (m, &x)) in measured.iter_mut().zip(truth).enumerate() {
            let noise = if self.noise_std[j] > 0.0 {
                self.noise_std[j] * standard_normal(self.seed, Stream::SensorNoise, step, j as u64)
            } else {
                0.0
            };
            *m = x + self.bias[j] + noise;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_late_reading_is_the_state_latency_steps_earlier_plus_the_bias() {
        let mut sensor = Sensor::new(2, 3, vec![0.0, 0.0], vec![0.5, -1.0], 1);
        let mut measured = [0.0; 2];
        for step in 0..10u64 {
            sensor.record(step, &[step as f64, 10.0 * step as f64]);
            sensor.measure_into(step, &mut measured);
            let source = step.saturating_sub(3) as f64;
            assert_eq!(measured, [source + 0.5, 10.0 * source - 1.0], "step {step}");
        }
    }

    #[test]
    fn noise_is_seeded_per_step_and_component_with_the_given_deviation() {
        let sensor_with = |seed| {
            let mut s = Sensor::new(2, 0, vec![0.2, 0.0], vec![0.0, 0.0], seed);
            (0..4000u64)
                .map(|step| {
                    s.record(step, &[1.0, 2.0]);
                    let mut m = [0.0; 2];
                    s.measure_into(step, &mut m);
                    m
                })
                .collect::<Vec<_>>()
        };
        let a = sensor_with(5);
        assert_eq!(a, sensor_with(5));
        assert_ne!(a, sensor_with(6));
        assert!(a.iter().all(|m| m[1] == 2.0), "a zero deviation adds no noise");
        let errors: Vec<f64> = a.iter().map(|m| m[0] - 1.0).collect();
        let std = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        assert!((std - 0.2).abs() < 0.01, "std {std}");
    }
}
