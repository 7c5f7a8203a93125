//! What a run will cost, estimated before its first step: the integration steps of the plant
//! and the predictors, and the bytes of its log. Refused above budgets that flags move
//! (`--max-work`, `--max-log-size`, next to `--max-steps`), so a mistyped timestep is an error
//! line, not hours of work or a disk filled (docs/hardening.md).

use std::sync::atomic::{AtomicU64, Ordering};

/// Most RK4 steps one prediction may integrate (its window over the predictor step): the
/// chain the predictor keeps holds about twice as many states.
pub const MAX_PREDICTION_STEPS: f64 = 1e6;

/// Default budget of integration steps of one episode (plant steps plus predictor steps).
pub const DEFAULT_MAX_WORK: u64 = 2_000_000_000;

/// Default budget of one log's size (bytes): 4 GiB.
pub const DEFAULT_MAX_LOG_BYTES: u64 = 4 << 30;

static MAX_WORK: AtomicU64 = AtomicU64::new(DEFAULT_MAX_WORK);
static MAX_LOG_BYTES: AtomicU64 = AtomicU64::new(DEFAULT_MAX_LOG_BYTES);

/// Sets the work budget of every episode built from now on (at least 1).
pub fn set_max_work(steps: u64) {
    MAX_WORK.store(steps.max(1), Ordering::SeqCst);
}

/// Sets the log-size budget of every log opened from now on (at least 1 byte).
pub fn set_max_log_bytes(bytes: u64) {
    MAX_LOG_BYTES.store(bytes.max(1), Ordering::SeqCst);
}

/// The work budget (integration steps).
pub fn max_work() -> u64 {
    MAX_WORK.load(Ordering::SeqCst)
}

/// The log-size budget (bytes).
pub fn max_log_bytes() -> u64 {
    MAX_LOG_BYTES.load(Ordering::SeqCst)
}

/// What sizes a run's cost.
#[derive(Debug, Clone, Copy)]
pub struct RunShape {
    pub steps: u64,
    pub steps_per_tick: u64,
    pub timestep: f64,
    pub states: usize,
    pub channels: usize,
    /// Barriers and obstacles.
    pub barriers: usize,
    /// The predictor's window (the longest assumed delay, s) and step (s), if it predicts.
    pub prediction: Option<(f64, f64)>,
    pub sensor: bool,
}

/// The estimate of one run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cost {
    /// Plant steps.
    pub steps: u64,
    /// RK4 steps of one whole prediction window (0 without predictions).
    pub prediction_steps: f64,
    /// Predictor steps over the run: one whole window, then per tick the control period
    /// (consecutive ticks continue the previous trajectory, `control.chain_tolerance`).
    pub predictor_steps: f64,
    /// Log bytes (records as encoded, before compression: an upper bound of the file).
    pub log_bytes: f64,
}

impl Cost {
    /// The estimate for a run of this shape.
    pub fn of(shape: &RunShape) -> Cost {
        let (n, r, k) = (shape.states as f64, shape.channels as f64, shape.barriers as f64);
        let ticks = (shape.steps / shape.steps_per_tick.max(1) + 1) as f64;
        let (prediction_steps, per_tick) = match shape.prediction {
            Some((window, step)) => {
                let whole = (window / step).ceil();
                let period = shape.steps_per_tick as f64 * shape.timestep / step;
                (whole, whole.min(period.ceil().max(1.0)))
            }
            None => (0.0, 0.0),
        };
        // Encoded sizes (protobuf: 9 bytes a double, names and framing ~16 bytes a message or
        // a per-channel entry; MCAP adds 31 bytes a message): per step /state, /command/applied,
        // /barrier (k barriers), /tf; per tick /command/issued, /filter, /prediction (r
        // predictions of 2n values) and, with a sensor, /state/measured.
        let message = 31.0 + 16.0;
        let per_step = 4.0 * message + 9.0 * n + r * (16.0 + 18.0) + k * (16.0 + 9.0 * (6.0 + r));
        let per_tick_bytes = 2.0 * message
            + r * (16.0 + 36.0)
            + if shape.prediction.is_some() {
                r * (message + 18.0 * n + 60.0)
            } else {
                0.0
            }
            + if shape.sensor { message + 9.0 * n } else { 0.0 };
        Cost {
            steps: shape.steps,
            prediction_steps,
            predictor_steps: prediction_steps + ticks * per_tick,
            log_bytes: shape.steps as f64 * per_step + ticks * per_tick_bytes,
        }
    }

    /// Plant steps plus predictor steps.
    pub fn work(&self) -> f64 {
        self.steps as f64 + self.predictor_steps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(steps: u64, prediction: Option<(f64, f64)>) -> RunShape {
        RunShape {
            steps,
            steps_per_tick: 5,
            timestep: 0.002,
            states: 4,
            channels: 2,
            barriers: 1,
            prediction,
            sensor: false,
        }
    }

    #[test]
    fn the_estimate_grows_linearly_in_steps_and_the_window_counts_once() {
        let a = Cost::of(&shape(6000, Some((1.5, 0.01))));
        let b = Cost::of(&shape(12000, Some((1.5, 0.01))));
        assert_eq!(a.prediction_steps, 150.0);
        // One period (one predictor step of 0.01 s) per tick after the first window.
        assert_eq!(a.predictor_steps, 150.0 + 1201.0);
        assert!((b.log_bytes / a.log_bytes - 2.0).abs() < 1e-3);
        assert_eq!(Cost::of(&shape(6000, None)).predictor_steps, 0.0);
    }
}
