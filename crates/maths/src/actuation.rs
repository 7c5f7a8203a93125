//! Actuator dynamics unknown to the controller (issue 16, part 5): per channel, the input the
//! plant receives, a, follows the delayed command u through a magnitude limit, a rate limit R
//! and a first-order lag τ:
//!
//! ȧ = clamp((sat(u) − a) / τ, −R, R),   sat(u) = clamp(u, min, max)
//!
//! (τ = 0: a moves to sat(u) at rate R; no rate limit: R = ∞). The command is held over a
//! plant step, so the step is solved exactly and the plant receives a's mean over the step
//! (one value for every RK4 stage of it). The scenario's `[actuator_dynamics]` table builds it
//! (`mjsafe::actuator`).

/// Limits and lag of one channel's actuator (`[actuator_dynamics.<channel>]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActuatorLimits {
    /// τ ≥ 0 (s).
    pub time_constant: f64,
    /// R > 0 (input units per second); infinite for none.
    pub rate_limit: f64,
    pub min: f64,
    pub max: f64,
}

/// One channel's actuator: its limits and its output a.
#[derive(Debug, Clone)]
pub struct Actuator {
    limits: ActuatorLimits,
    output: f64,
}

impl Actuator {
    /// An actuator at rest at `initial` (the channel's initial input, within the limits).
    pub fn new(limits: ActuatorLimits, initial: f64) -> Actuator {
        Actuator {
            output: initial.clamp(limits.min, limits.max),
            limits,
        }
    }

    /// a at the current time.
    pub fn output(&self) -> f64 {
        self.output
    }

    /// Advances a over a step of `h` seconds with the command `u` held; returns a's mean over
    /// the step (exact: a rate-limited ramp, then the lag's exponential approach).
    pub fn step(&mut self, u: f64, h: f64) -> f64 {
        let ActuatorLimits {
            time_constant: tau,
            rate_limit: rate,
            min,
            max,
        } = self.limits;
        let target = u.clamp(min, max);
        let a0 = self.output;
        let gap = target - a0;
        let direction = gap.signum();
        // Phase 1: the rate limit binds while |target − a| > τ R.
        let ramp = if rate.is_finite() {
            ((gap.abs() - tau * rate) / rate).max(0.0)
        } else {
            0.0
        };
        let t1 = ramp.min(h);
        if t1 == 0.0 && tau == 0.0 {
            // Neither lag nor a binding rate limit: the (limited) command itself, exactly.
            self.output = target;
            return target;
        }
        let (a1, mut integral) = if t1 > 0.0 {
            (a0 + direction * rate * t1, a0 * t1 + 0.5 * direction * rate * t1 * t1)
        } else {
            (a0, 0.0)
        };
        // Phase 2: the lag (or, with τ = 0, a at the target).
        let rest = h - t1;
        let end = if rest <= 0.0 {
            a1
        } else if tau > 0.0 {
            let e1 = target - a1;
            let decay = (-rest / tau).exp();
            integral += target * rest - e1 * tau * (1.0 - decay);
            target - e1 * decay
        } else {
            integral += target * rest;
            target
        };
        self.output = end;
        if h > 0.0 {
            integral / h
        } else {
            end
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(time_constant: f64, rate_limit: f64, min: f64, max: f64) -> ActuatorLimits {
        ActuatorLimits {
            time_constant,
            rate_limit,
            min,
            max,
        }
    }

    /// a(t) and its integral by fine explicit Euler of ȧ = clamp((sat(u) − a)/τ, ±R).
    fn reference(l: ActuatorLimits, a0: f64, u: f64, h: f64) -> (f64, f64) {
        let n = 200_000;
        let dt = h / n as f64;
        let (mut a, mut integral) = (a0, 0.0);
        let target = u.clamp(l.min, l.max);
        for _ in 0..n {
            let rate = if l.time_constant > 0.0 {
                (target - a) / l.time_constant
            } else {
                (target - a).signum() * f64::INFINITY
            };
            let next = a + rate.clamp(-l.rate_limit, l.rate_limit) * dt;
            // τ = 0: the ramp stops at the target.
            let next = if l.time_constant == 0.0 && (next - target).signum() != (a - target).signum() {
                target
            } else {
                next
            };
            integral += 0.5 * (a + next) * dt;
            a = next;
        }
        (a, integral / h)
    }

    #[test]
    fn the_exact_step_matches_a_fine_integration() {
        for (l, a0, u, h) in [
            (limits(0.1, f64::INFINITY, -1.0, 1.0), 0.0, 0.8, 0.05),
            (limits(0.1, 2.0, -1.0, 1.0), 0.0, 0.8, 0.05),
            (limits(0.1, 2.0, -1.0, 1.0), 0.0, 5.0, 0.5),
            (limits(0.0, 2.0, -1.0, 1.0), 0.3, -0.9, 0.2),
            (limits(0.0, 2.0, -1.0, 1.0), 0.3, -0.9, 1.0),
            (limits(0.05, 0.5, -3.0, 3.0), -1.0, 2.0, 0.01),
        ] {
            let mut actuator = Actuator::new(l, a0);
            let mean = actuator.step(u, h);
            let (end, reference_mean) = reference(l, a0, u, h);
            assert!(
                (actuator.output() - end).abs() < 1e-4,
                "{l:?} {u}: {} vs {end}",
                actuator.output()
            );
            assert!(
                (mean - reference_mean).abs() < 1e-4,
                "{l:?} {u}: mean {mean} vs {reference_mean}"
            );
        }
    }

    #[test]
    fn without_lag_or_rate_limit_only_the_magnitude_limit_remains() {
        let mut actuator = Actuator::new(limits(0.0, f64::INFINITY, -0.5, 0.5), 0.0);
        assert_eq!(actuator.step(0.3, 0.01), 0.3);
        assert_eq!(actuator.step(2.0, 0.01), 0.5);
        assert_eq!(actuator.output(), 0.5);
        assert_eq!(actuator.step(-7.0, 0.01), -0.5);
    }

    #[test]
    fn a_lag_reaches_63_percent_after_one_time_constant() {
        let mut actuator = Actuator::new(limits(0.2, f64::INFINITY, -10.0, 10.0), 0.0);
        for _ in 0..100 {
            actuator.step(1.0, 0.002);
        }
        assert!((actuator.output() - (1.0 - (-1.0f64).exp())).abs() < 1e-12);
    }
}
