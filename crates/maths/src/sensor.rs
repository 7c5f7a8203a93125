//! A sensor between the plant and the controller (issue 16, part 3): it reports the true state
//! `latency_steps` plant steps late, offset by a constant bias and seeded Gaussian noise per
//! component:
//!
//! x̂(t_k) = x(t_k − latency) + bias + diag(σ) n_k,   n_k ~ N(0, I) drawn from (seed, step k).
//!
//! Before the first reading is `latency` old, the sensor reports x(0) (it has seen nothing
//! earlier). The scenario's `[sensing]` table builds it (`mjsafe::sensing`).

use crate::random::{standard_normal, Stream};

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
