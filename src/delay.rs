//! Actuator delay queues: one per input channel, each with its own constant delay D_i.
//!
//! A command issued at tick time t reaches the actuator at exactly t + D_i and is held
//! (zero-order hold) until the next command arrives. Before any command has arrived, the
//! channel applies its initial input function on [−D_i, 0) ((4.79)/(4.80); constant,
//! zero by default).

use std::collections::VecDeque;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DelayError {
    #[error("delay of channel `{channel}` is {delay} s: it must be finite and >= 0")]
    Negative { channel: String, delay: f64 },
    #[error("delay of channel `{channel}` is {delay} s: it must be a whole multiple of the timestep {timestep} s")]
    NotMultiple {
        channel: String,
        delay: f64,
        timestep: f64,
    },
    #[error("channel `{channel}`: command issued at t = {time} is not after the previous one at t = {previous}")]
    OutOfOrder {
        channel: String,
        time: f64,
        previous: f64,
    },
    #[error("channel `{channel}`: input at t = {time} needs history from t = {needed}, which was already discarded")]
    HistoryGone {
        channel: String,
        time: f64,
        needed: f64,
    },
}

/// Relative tolerance, in timesteps, for "is a whole multiple" and for comparing tick times.
const TIME_TOLERANCE: f64 = 1e-9;

/// A value that reached (or will reach) an actuator, with when it was issued.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Applied {
    pub value: f64,
    /// Issue time; −D_i for the initial input function.
    pub issued_at: f64,
}

/// The delay line of one input channel.
#[derive(Debug, Clone)]
pub struct DelayQueue {
    channel: String,
    delay: f64,
    initial_input: f64,
    /// Issued commands (issue time, value), oldest first.
    history: VecDeque<(f64, f64)>,
    /// Tolerance for time comparisons (a small fraction of the timestep).
    eps: f64,
    /// Whether old commands were discarded (then "nothing older" no longer means the
    /// initial input applies).
    pruned: bool,
}

impl DelayQueue {
    /// A queue with constant delay `delay`, which must be a whole multiple of `timestep`.
    pub fn new(
        channel: &str,
        delay: f64,
        initial_input: f64,
        timestep: f64,
    ) -> Result<DelayQueue, DelayError> {
        if !delay.is_finite() || delay < 0.0 {
            return Err(DelayError::Negative {
                channel: channel.into(),
                delay,
            });
        }
        let steps = delay / timestep;
        if (steps - steps.round()).abs() > 1e-6 {
            return Err(DelayError::NotMultiple {
                channel: channel.into(),
                delay,
                timestep,
            });
        }
        Ok(DelayQueue {
            channel: channel.into(),
            delay,
            initial_input,
            history: VecDeque::new(),
            eps: TIME_TOLERANCE.max(1e-6 * timestep),
            pruned: false,
        })
    }

    pub fn channel(&self) -> &str {
        &self.channel
    }
    pub fn delay(&self) -> f64 {
        self.delay
    }

    /// Records a command issued at `time` (control ticks, increasing).
    pub fn push(&mut self, time: f64, value: f64) -> Result<(), DelayError> {
        if let Some(&(previous, _)) = self.history.back() {
            if time <= previous + self.eps {
                return Err(DelayError::OutOfOrder {
                    channel: self.channel.clone(),
                    time,
                    previous,
                });
            }
        }
        self.history.push_back((time, value));
        Ok(())
    }

    /// The applied input u_i(t − D_i): the latest command issued at or before t − D_i
    /// (within a tolerance), or the initial input if none.
    pub fn applied(&self, time: f64) -> Result<Applied, DelayError> {
        let source_time = time - self.delay;
        // Latest entry with issue time <= source_time (+eps). History is sorted.
        let idx = self
            .history
            .partition_point(|&(t, _)| t <= source_time + self.eps);
        if idx == 0 {
            if self.pruned {
                return Err(DelayError::HistoryGone {
                    channel: self.channel.clone(),
                    time,
                    needed: source_time,
                });
            }
            return Ok(Applied {
                value: self.initial_input,
                issued_at: -self.delay,
            });
        }
        let (issued_at, value) = self.history[idx - 1];
        Ok(Applied { value, issued_at })
    }

    /// Discards commands no longer needed to answer `applied(t)` for any t >= `time`.
    pub fn discard_before(&mut self, time: f64) {
        let source_time = time - self.delay;
        while self.history.len() >= 2 && self.history[1].0 <= source_time + self.eps {
            self.history.pop_front();
            self.pruned = true;
        }
    }

    /// The latest command issued, if any.
    pub fn last_issued(&self) -> Option<(f64, f64)> {
        self.history.back().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_issued_at_t_arrives_at_exactly_t_plus_delay() {
        let h = 0.002;
        let mut q = DelayQueue::new("u", 0.2, 0.0, h).unwrap();
        for k in 0..500 {
            let t = k as f64 * h;
            q.push(t, if k >= 100 { 1.0 } else { 0.0 }).unwrap();
        }
        // Issued at 0.2, arrives at 0.4: zero just before, one from 0.4 on.
        assert_eq!(q.applied(0.4 - h).unwrap().value, 0.0);
        let a = q.applied(0.4).unwrap();
        assert_eq!(a.value, 1.0);
        assert!((a.issued_at - 0.2).abs() < 1e-12);
    }

    #[test]
    fn initial_input_applies_on_the_first_delay_interval() {
        let mut q = DelayQueue::new("u", 1.5, -0.7, 0.01).unwrap();
        q.push(0.0, 2.0).unwrap();
        let a = q.applied(1.49).unwrap();
        assert_eq!(a.value, -0.7);
        assert_eq!(a.issued_at, -1.5);
        assert_eq!(q.applied(1.5).unwrap().value, 2.0);
    }

    #[test]
    fn bad_delays_are_rejected() {
        assert!(matches!(
            DelayQueue::new("u", -0.1, 0.0, 0.01),
            Err(DelayError::Negative { .. })
        ));
        assert!(matches!(
            DelayQueue::new("u", 0.015, 0.0, 0.01),
            Err(DelayError::NotMultiple { .. })
        ));
    }

    #[test]
    fn discarded_history_is_an_error_not_a_silent_zero() {
        let mut q = DelayQueue::new("u", 0.1, 0.0, 0.1).unwrap();
        for k in 0..10 {
            q.push(k as f64 * 0.1, k as f64).unwrap();
        }
        q.discard_before(0.9);
        assert_eq!(q.applied(0.9).unwrap().value, 8.0);
        assert!(matches!(
            q.applied(0.3),
            Err(DelayError::HistoryGone { .. })
        ));
    }
}
