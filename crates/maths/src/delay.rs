//! Actuator delays: per-channel delay profiles D(t) with delay time φ(t) = t − D(t) (2.2) and
//! prediction time φ⁻¹(t), and the delay queue that turns issued commands into the applied
//! input u(φ(t)).
//!
//! A command issued at tick time s reaches the actuator at φ⁻¹(s) (for a constant delay,
//! s + D) and is held (zero-order hold) until the next command arrives. Before any command
//! has arrived, the channel applies its initial input function on [φ(0), 0) ((4.79)/(4.80);
//! constant, zero by default).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::params::ParamError;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DelayError {
    #[error("delay of channel `{channel}` is {delay} s: it must be finite and >= 0")]
    Negative { channel: String, delay: f64 },
    #[error("delay of channel `{channel}` is {delay} s: it must be a whole multiple of the timestep {timestep} s")]
    NotMultiple { channel: String, delay: f64, timestep: f64 },
    #[error("delay profile of channel `{channel}` has a non-finite or invalid parameter: {what}")]
    BadParameter { channel: String, what: String },
    #[error("delay profile of channel `{channel}` breaks {condition} at t = {time:.6} s")]
    Assumption {
        channel: String,
        condition: &'static str,
        time: f64,
    },
    #[error("channel `{channel}`: the delay reaches {delay:.4} s, longer than the {history} s of input history kept (control.history)")]
    HistoryTooShort { channel: String, delay: f64, history: f64 },
    #[error("channel `{channel}`: command issued at t = {time} is not after the previous one at t = {previous}")]
    OutOfOrder { channel: String, time: f64, previous: f64 },
    #[error("channel `{channel}`: input at t = {time} needs history from t = {needed}, which was already discarded")]
    HistoryGone { channel: String, time: f64, needed: f64 },
}

/// How one channel's delay varies with time (scenario key `delays.<channel>`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DelayProfile {
    /// D(t) = D, written as a plain number.
    Constant(f64),
    /// A time-varying profile, written as a table with `profile = …`.
    Varying(VaryingDelay),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "profile", rename_all = "snake_case", deny_unknown_fields)]
pub enum VaryingDelay {
    /// φ⁻¹(t) = t + a + b cos(ω t), the form of (2.31) (a = 1, b = 1/2, ω = 1 there).
    CosinePrediction { a: f64, b: f64, omega: f64 },
    /// φ(t) = t − (1 + t)/(1 + 2t) (2.37), with φ' (2.38) and φ⁻¹ (2.39) in closed form.
    Rational,
    /// D(t) piecewise linear through (`times[k]`, `delays[k]`); constant beyond the ends.
    Table { times: Vec<f64>, delays: Vec<f64> },
}

/// Absolute tolerance of the root finder for φ and φ⁻¹ (seconds).
pub const ROOT_TOLERANCE: f64 = 1e-13;

impl DelayProfile {
    pub fn constant(delay: f64) -> DelayProfile {
        DelayProfile::Constant(delay)
    }

    /// Some(D) for a constant delay.
    pub fn constant_delay(&self) -> Option<f64> {
        match self {
            DelayProfile::Constant(d) => Some(*d),
            DelayProfile::Varying(_) => None,
        }
    }

    /// D(t) = t − φ(t).
    pub fn delay(&self, t: f64) -> f64 {
        t - self.delay_time(t)
    }

    /// Delay time φ(t) (2.2): when the input arriving at t was issued.
    pub fn delay_time(&self, t: f64) -> f64 {
        match self {
            DelayProfile::Constant(d) => t - d,
            DelayProfile::Varying(VaryingDelay::Rational) => t - (1.0 + t) / (1.0 + 2.0 * t),
            DelayProfile::Varying(VaryingDelay::Table { times, delays }) => t - table_delay(times, delays, t),
            // φ = (φ⁻¹)⁻¹: solve φ⁻¹(s) = t for s by Newton's method ((φ⁻¹)' = 1 − bω sin ωs
            // > 0 is checked at load time), with bisection as the fallback.
            DelayProfile::Varying(VaryingDelay::CosinePrediction { a, b, omega }) => {
                let mut s = t - a - b * (omega * (t - a)).cos();
                for _ in 0..50 {
                    let residual = s + a + b * (omega * s).cos() - t;
                    if residual.abs() < ROOT_TOLERANCE {
                        return s;
                    }
                    let slope = 1.0 - b * omega * (omega * s).sin();
                    if slope.is_nan() || slope <= 1e-3 {
                        break;
                    }
                    s -= residual / slope;
                }
                invert_increasing(|s| self.prediction_time(s), t, t - a - b.abs() - 1.0, t)
            }
        }
    }

    /// Prediction time φ⁻¹(t): when a command issued at t arrives.
    pub fn prediction_time(&self, t: f64) -> f64 {
        match self {
            DelayProfile::Constant(d) => t + d,
            DelayProfile::Varying(VaryingDelay::CosinePrediction { a, b, omega }) => t + a + b * (omega * t).cos(),
            DelayProfile::Varying(VaryingDelay::Rational) => (t + (1.0 + (1.0 + t) * (1.0 + t)).sqrt()) / 2.0,
            DelayProfile::Varying(VaryingDelay::Table { delays, .. }) => {
                let longest = delays.iter().cloned().fold(0.0, f64::max);
                invert_increasing(|s| self.delay_time(s), t, t, t + longest + 1.0)
            }
        }
    }

    /// φ'(t).
    pub fn delay_time_derivative(&self, t: f64) -> f64 {
        match self {
            DelayProfile::Constant(_) => 1.0,
            DelayProfile::Varying(VaryingDelay::Rational) => 1.0 + 1.0 / ((1.0 + 2.0 * t) * (1.0 + 2.0 * t)),
            DelayProfile::Varying(VaryingDelay::Table { times, delays }) => 1.0 - table_slope(times, delays, t),
            DelayProfile::Varying(VaryingDelay::CosinePrediction { b, omega, .. }) => {
                // φ' = 1 / (φ⁻¹)'(φ(t)), (φ⁻¹)'(s) = 1 − b ω sin(ω s).
                let s = self.delay_time(t);
                1.0 / (1.0 - b * omega * (omega * s).sin())
            }
        }
    }

    /// The profile's parameters: finite, a constant delay >= 0, a table's times increasing.
    fn check_parameters(&self, channel: &str) -> Result<(), DelayError> {
        let bad = |what: String| DelayError::BadParameter {
            channel: channel.into(),
            what,
        };
        match self {
            DelayProfile::Constant(d) => {
                if !d.is_finite() || *d < 0.0 {
                    return Err(DelayError::Negative {
                        channel: channel.into(),
                        delay: *d,
                    });
                }
            }
            DelayProfile::Varying(VaryingDelay::CosinePrediction { a, b, omega }) => {
                if !(a.is_finite() && b.is_finite() && omega.is_finite()) {
                    return Err(bad(format!("a = {a}, b = {b}, omega = {omega}")));
                }
            }
            DelayProfile::Varying(VaryingDelay::Rational) => {}
            DelayProfile::Varying(VaryingDelay::Table { times, delays }) => {
                if times.is_empty() || times.len() != delays.len() {
                    return Err(bad(format!(
                        "times and delays need the same, non-zero length ({} and {})",
                        times.len(),
                        delays.len()
                    )));
                }
                if times.iter().chain(delays).any(|v| !v.is_finite()) {
                    return Err(bad("times and delays must be finite numbers".into()));
                }
                if times.windows(2).any(|w| w[1] <= w[0]) {
                    return Err(bad("times must be strictly increasing".into()));
                }
            }
        }
        Ok(())
    }

    /// What a true (actuator) delay needs: valid parameters, and D(t) finite, >= 0 and within
    /// the kept history over the horizon. Assumptions 1–2 ([`DelayProfile::check`]) are what
    /// the controller assumes; the actuators need not satisfy them.
    pub fn check_physical(&self, channel: &str, horizon: f64, step: f64, history: f64) -> Result<(), DelayError> {
        self.check_parameters(channel)?;
        let step = sampling_step(horizon, step);
        let samples = if self.constant_delay().is_none() {
            (horizon / step).ceil() as usize
        } else {
            0
        };
        for k in 0..=samples {
            let t = (k as f64 * step).min(horizon);
            let d = self.delay(t);
            if !(d.is_finite() && d >= 0.0) {
                return Err(DelayError::Assumption {
                    channel: channel.into(),
                    condition: "a physical delay: D(t) finite and >= 0",
                    time: t,
                });
            }
            if d > history {
                return Err(DelayError::HistoryTooShort {
                    channel: channel.into(),
                    delay: d,
                    history,
                });
            }
        }
        Ok(())
    }

    /// Checks the parameters and Assumptions 1 and 2 of Ch. 2 ((2.4)–(2.7)) on [0, horizon]
    /// (sampled every `step`, at most [`MAX_PROFILE_SAMPLES`] times: a finer step samples
    /// more coarsely), and that the delay never exceeds `history`. A constant delay
    /// may be 0 (the delay-free case); a time-varying one must stay > 0.
    pub fn check(&self, channel: &str, horizon: f64, step: f64, history: f64) -> Result<(), DelayError> {
        self.check_parameters(channel)?;
        let step = sampling_step(horizon + history, step);
        let varying = self.constant_delay().is_none();
        if let DelayProfile::Varying(VaryingDelay::CosinePrediction { a, b, omega }) = self {
            // φ is defined through φ⁻¹, so (2.6) is (φ⁻¹)'(s) = 1 − b ω sin(ω s) > 0 for every
            // issue time s in [φ(0), horizon] (φ(0) >= −a − |b|).
            let first = -a - b.abs();
            if -first > history {
                return Err(DelayError::HistoryTooShort {
                    channel: channel.into(),
                    delay: -first,
                    history,
                });
            }
            let samples = ((horizon - first) / step).ceil().max(0.0) as usize;
            for k in 0..=samples {
                let s = first + k as f64 * step;
                if 1.0 - b * omega * (omega * s).sin() <= 0.0 {
                    return Err(DelayError::Assumption {
                        channel: channel.into(),
                        condition: "(2.6) phi'(t) > 0 (here: d/ds phi^-1(s) = 1 - b omega sin(omega s) > 0)",
                        time: s,
                    });
                }
            }
        }
        // A constant delay satisfies (2.4)-(2.7) everywhere: only its length needs checking
        // (sampling would make the start-up linear in the episode's length).
        let samples = if varying { (horizon / step).ceil() as usize } else { 0 };
        for k in 0..=samples {
            let t = (k as f64 * step).min(horizon);
            let d = self.delay(t);
            let fail = |condition| {
                Err(DelayError::Assumption {
                    channel: channel.into(),
                    condition,
                    time: t,
                })
            };
            if !d.is_finite() {
                return fail("finiteness of D(t)");
            }
            if varying && d <= 0.0 {
                return fail("(2.4) phi(t) < t, i.e. D(t) > 0");
            }
            if d > history {
                return Err(DelayError::HistoryTooShort {
                    channel: channel.into(),
                    delay: d,
                    history,
                });
            }
            let dphi = self.delay_time_derivative(t);
            if dphi.is_nan() || dphi <= 0.0 {
                return fail("(2.6) phi'(t) > 0, i.e. dD/dt < 1");
            }
            if !dphi.is_finite() || dphi > 1e6 {
                return fail("(2.7) phi'(t) bounded");
            }
        }
        Ok(())
    }
}

/// D(t) of a piecewise-linear table, constant beyond its ends.
fn table_delay(times: &[f64], delays: &[f64], t: f64) -> f64 {
    let k = times.partition_point(|&s| s <= t);
    if k == 0 {
        return delays[0];
    }
    if k == times.len() {
        return delays[times.len() - 1];
    }
    let w = (t - times[k - 1]) / (times[k] - times[k - 1]);
    delays[k - 1] + w * (delays[k] - delays[k - 1])
}

/// dD/dt of the table (right derivative at knots; 0 beyond the ends).
fn table_slope(times: &[f64], delays: &[f64], t: f64) -> f64 {
    let k = times.partition_point(|&s| s <= t);
    if k == 0 || k == times.len() {
        return 0.0;
    }
    (delays[k] - delays[k - 1]) / (times[k] - times[k - 1])
}

/// Solves g(s) = target for an increasing g by bisection on [lo, hi] (expanded if needed).
fn invert_increasing(g: impl Fn(f64) -> f64, target: f64, mut lo: f64, mut hi: f64) -> f64 {
    let mut span = (hi - lo).max(1.0);
    while g(lo) > target {
        lo -= span;
        span *= 2.0;
    }
    while g(hi) < target {
        hi += span;
        span *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < ROOT_TOLERANCE {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// Tolerance, as a fraction of the timestep, for comparing issue times: far below the margin
/// (1e-6 h) by which the plant keeps its last RK4 stage inside the step, so a command issued
/// exactly at the step's end is never picked up by that stage.
const TIME_TOLERANCE: f64 = 1e-9;

/// A value that reached (or will reach) an actuator, with when it was issued.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Applied {
    pub value: f64,
    /// Issue time; φ(0) (= −D for a constant delay) for the initial input function.
    pub issued_at: f64,
}

/// The delay line of one input channel.
#[derive(Debug, Clone)]
pub struct DelayQueue {
    channel: String,
    profile: DelayProfile,
    initial_input: f64,
    /// Issued commands (issue time, value), oldest first.
    history: VecDeque<(f64, f64)>,
    /// Tolerance for time comparisons (a small fraction of the timestep).
    eps: f64,
    /// Whether old commands were discarded (then "nothing older" no longer means the
    /// initial input applies).
    pruned: bool,
    /// Stochastic actuation: each command's own arrival time (see [`Actuation`]).
    actuation: Option<ActuationLine>,
}

/// Seeded per-command randomness of an actuator: an extra latency ε_k ≥ 0 added to the true
/// delay, and a probability of dropping the command (it never arrives; the actuator holds the
/// last command that did).
#[derive(Debug, Clone, PartialEq)]
pub struct Actuation {
    pub extra_latency: ExtraLatency,
    pub drop_probability: f64,
    /// Seed and channel index of the draws (draw k of channel i depends on nothing else).
    pub seed: u64,
    pub channel_index: u64,
}

/// The distribution of the extra latency ε_k (seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ExtraLatency {
    None,
    /// Uniform on [0, max].
    Uniform {
        max: f64,
    },
    /// Normal(mean, std) truncated to [0, max] (by rejection, deterministic per draw).
    TruncatedNormal {
        mean: f64,
        std: f64,
        max: f64,
    },
}

/// One channel's stochastic actuation (`[actuation.<channel>]`): the section's spec, checks
/// and build.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuationSpec {
    /// Extra latency ε_k ≥ 0 of each command (seconds), seeded by `seed`.
    #[serde(default)]
    pub extra_latency: Option<ExtraLatencySpec>,
    /// Probability that a command is dropped (never arrives; the actuator holds the last one
    /// that did), in [0, 1).
    #[serde(default)]
    pub drop_probability: f64,
}

/// The distribution of the extra latency.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "distribution", rename_all = "snake_case", deny_unknown_fields)]
pub enum ExtraLatencySpec {
    /// Uniform on [0, max].
    Uniform { max: f64 },
    /// Normal(mean, std) truncated to [0, max].
    TruncatedNormal { mean: f64, std: f64, max: f64 },
}

impl ActuationSpec {
    /// The checks of channel `channel`'s table when the scenario loads: a drop probability in
    /// [0, 1), an extra latency of at most the run's `duration` (a command that late never
    /// arrives). Keys are the scenario's (`actuation.<channel>.drop_probability`).
    pub fn validate(&self, channel: &str, duration: f64) -> Result<(), ParamError> {
        let (a, key) = (self, format!("actuation.{channel}"));
        if !(a.drop_probability.is_finite() && (0.0..1.0).contains(&a.drop_probability)) {
            return Err(ParamError::new(
                format!("{key}.drop_probability"),
                format!("expected a probability in [0, 1), found {}", a.drop_probability),
            ));
        }
        let ok = match a.extra_latency {
            None => true,
            Some(ExtraLatencySpec::Uniform { max }) => max.is_finite() && max >= 0.0,
            Some(ExtraLatencySpec::TruncatedNormal { mean, std, max }) => {
                mean.is_finite() && (std.is_finite() && std > 0.0) && max.is_finite() && max >= 0.0
            }
        };
        if !ok {
            return Err(ParamError::new(
                format!("{key}.extra_latency"),
                "expected max >= 0 seconds (and for truncated_normal a finite mean and std > 0)",
            ));
        }
        let bound = match a.extra_latency {
            Some(ExtraLatencySpec::Uniform { max }) | Some(ExtraLatencySpec::TruncatedNormal { max, .. }) => max,
            None => 0.0,
        };
        if bound > duration {
            return Err(ParamError::new(
                format!("{key}.extra_latency.max"),
                format!(
                    "expected at most the run's duration {} s (a command that late never arrives), found {bound}",
                    duration
                ),
            ));
        }
        Ok(())
    }

    /// The channel's seeded actuation (`seed`, its index among the channels).
    pub fn build(&self, seed: u64, channel_index: usize) -> Actuation {
        Actuation {
            extra_latency: match self.extra_latency {
                None => ExtraLatency::None,
                Some(ExtraLatencySpec::Uniform { max }) => ExtraLatency::Uniform { max },
                Some(ExtraLatencySpec::TruncatedNormal { mean, std, max }) => {
                    ExtraLatency::TruncatedNormal { mean, std, max }
                }
            },
            drop_probability: self.drop_probability,
            seed,
            channel_index: channel_index as u64,
        }
    }
}

impl Actuation {
    /// Arrival offset of command k beyond the true delay: ε_k, or +∞ when dropped.
    fn offset(&self, k: u64) -> f64 {
        use crate::random::{symmetric_unit, Stream};
        let unit = |stream, component| 0.5 * (symmetric_unit(self.seed, stream, k, component) + 1.0);
        if unit(Stream::ActuationDrop, self.channel_index) < self.drop_probability {
            return f64::INFINITY;
        }
        let c = self.channel_index << 8;
        match self.extra_latency {
            ExtraLatency::None => 0.0,
            ExtraLatency::Uniform { max } => max * unit(Stream::ActuationLatency, c),
            ExtraLatency::TruncatedNormal { mean, std, max } => (0..64)
                .map(|j| {
                    // Box–Muller from two draws; the first in [0, max] is taken.
                    let (u1, u2) = (
                        unit(Stream::ActuationLatency, c + 2 * j).max(1e-300),
                        unit(Stream::ActuationLatency, c + 2 * j + 1),
                    );
                    mean + std * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                })
                .find(|e| (0.0..=max).contains(e))
                .unwrap_or(mean.clamp(0.0, max)),
        }
    }
}

/// Arrival times of the issued commands, kept beside the history.
#[derive(Debug, Clone)]
struct ActuationLine {
    actuation: Actuation,
    /// Effective arrival per command, parallel to `history`: the earliest arrival of it or
    /// any later-issued command (non-decreasing, so "the latest-issued command that has
    /// arrived by t" is a binary search; a command overtaken by a later one never applies).
    arrivals: VecDeque<f64>,
    /// Commands pushed so far (the draw index).
    pushed: u64,
}

impl DelayQueue {
    /// A queue with constant delay `delay`, which must be a whole multiple of `timestep`.
    pub fn new(channel: &str, delay: f64, initial_input: f64, timestep: f64) -> Result<DelayQueue, DelayError> {
        if !delay.is_finite() || delay < 0.0 {
            return Err(DelayError::Negative {
                channel: channel.into(),
                delay,
            });
        }
        Self::with_profile(channel, DelayProfile::constant(delay), initial_input, timestep)
    }

    /// A queue with any delay profile. Constant delays must be whole multiples of `timestep`
    /// (so the input is constant over each physics step and RK4 keeps its order).
    pub fn with_profile(
        channel: &str,
        profile: DelayProfile,
        initial_input: f64,
        timestep: f64,
    ) -> Result<DelayQueue, DelayError> {
        if let Some(delay) = profile.constant_delay() {
            let steps = delay / timestep;
            if (steps - steps.round()).abs() > 1e-6 {
                return Err(DelayError::NotMultiple {
                    channel: channel.into(),
                    delay,
                    timestep,
                });
            }
        }
        Ok(Self::line(channel, profile, initial_input, timestep))
    }

    /// An actuator's delay line: command k, issued at t_k, arrives at t_k + D(t_k) + ε_k (or
    /// never, when dropped), and the input at time t is the latest-issued command that has
    /// arrived by t (the initial input before any). D may be any physical delay, not only a
    /// multiple of the timestep: the plant samples the line at each input evaluation, so under
    /// Euler/implicit integration a command takes effect from the first step starting at or
    /// after its arrival, under RK4 from the first stage at or after it.
    pub fn actuator(
        channel: &str,
        profile: DelayProfile,
        initial_input: f64,
        timestep: f64,
        actuation: Actuation,
    ) -> DelayQueue {
        DelayQueue {
            actuation: Some(ActuationLine {
                actuation,
                arrivals: VecDeque::new(),
                pushed: 0,
            }),
            ..Self::line(channel, profile, initial_input, timestep)
        }
    }

    /// A queue without the grid check.
    fn line(channel: &str, profile: DelayProfile, initial_input: f64, timestep: f64) -> DelayQueue {
        DelayQueue {
            channel: channel.into(),
            profile,
            initial_input,
            history: VecDeque::new(),
            eps: TIME_TOLERANCE * timestep,
            pruned: false,
            actuation: None,
        }
    }

    /// The largest extra latency a stochastic actuator adds to the delay (0 without one).
    pub fn extra_latency_bound(&self) -> f64 {
        match self.actuation.as_ref().map(|line| line.actuation.extra_latency) {
            Some(ExtraLatency::Uniform { max }) | Some(ExtraLatency::TruncatedNormal { max, .. }) => max,
            Some(ExtraLatency::None) | None => 0.0,
        }
    }

    /// The commands issued and still held (issue time, value), oldest first: those that may
    /// still apply (older ones are discarded as the run goes, [`DelayQueue::discard_before`]).
    pub fn issued(&self) -> impl ExactSizeIterator<Item = (f64, f64)> + '_ {
        self.history.iter().copied()
    }

    /// The input applied before the first issued command arrives ((4.79)/(4.80)).
    pub fn initial_input(&self) -> f64 {
        self.initial_input
    }

    pub fn channel(&self) -> &str {
        &self.channel
    }
    pub fn profile(&self) -> &DelayProfile {
        &self.profile
    }
    /// The constant delay, if the profile is constant.
    pub fn constant_delay(&self) -> Option<f64> {
        self.profile.constant_delay()
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
        if let Some(line) = &mut self.actuation {
            let arrival = time + self.profile.delay(time) + line.actuation.offset(line.pushed);
            line.pushed += 1;
            for earlier in line.arrivals.iter_mut().rev() {
                if *earlier <= arrival {
                    break;
                }
                *earlier = arrival;
            }
            line.arrivals.push_back(arrival);
        }
        Ok(())
    }

    /// The applied input u_i(φ(t)): the latest command issued at or before φ(t) (within a
    /// tolerance), or the initial input if none.
    pub fn applied(&self, time: f64) -> Result<Applied, DelayError> {
        if let Some(line) = &self.actuation {
            let idx = line.arrivals.partition_point(|&a| a <= time + self.eps);
            return self.applied_at_index(idx, time, time);
        }
        self.issued_at_or_before(self.profile.delay_time(time), time)
    }

    /// [`DelayQueue::applied`] at `time`, whose φ(time) the caller has computed as
    /// `source_time`, with the interval [from, until) of source times φ(s) over which that
    /// command stays in force (while no command is pushed), so that a caller sampling at
    /// increasing times can skip the search while φ(s) stays inside it. The search tries
    /// first the command after the one at index `hint` (what such a caller needs next); the
    /// index found is returned as the next hint.
    pub fn applied_span_near(
        &self,
        time: f64,
        source_time: f64,
        hint: usize,
    ) -> Result<(Applied, f64, f64, usize), DelayError> {
        let in_force = |idx: usize| {
            idx <= self.history.len()
                && (idx == 0 || self.history[idx - 1].0 <= source_time + self.eps)
                && (idx == self.history.len() || self.history[idx].0 > source_time + self.eps)
        };
        let idx = [hint + 1, hint]
            .into_iter()
            .find(|&idx| in_force(idx))
            .unwrap_or_else(|| self.in_force_index(source_time));
        let applied = self.applied_at_index(idx, source_time, time)?;
        let from = if idx == 0 {
            f64::NEG_INFINITY
        } else {
            self.history[idx - 1].0 - self.eps
        };
        let until = self.history.get(idx).map_or(f64::INFINITY, |&(t, _)| t - self.eps);
        Ok((applied, from, until, idx))
    }

    /// Number of commands issued at or before `source_time` (within the tolerance).
    fn in_force_index(&self, source_time: f64) -> usize {
        self.history.partition_point(|&(t, _)| t <= source_time + self.eps)
    }

    /// The command in force at issue time `source_time` (ZOH), `time` only names the request.
    fn issued_at_or_before(&self, source_time: f64, time: f64) -> Result<Applied, DelayError> {
        self.applied_at_index(self.in_force_index(source_time), source_time, time)
    }

    /// The command in force when `idx` commands were issued at or before `source_time`.
    fn applied_at_index(&self, idx: usize, source_time: f64, time: f64) -> Result<Applied, DelayError> {
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
                issued_at: self.profile.delay_time(0.0),
            });
        }
        let (issued_at, value) = self.history[idx - 1];
        Ok(Applied { value, issued_at })
    }

    /// Discards commands no longer needed to answer `applied(t)` for any t >= `time`
    /// (φ is increasing, so nothing issued before φ(time) is needed but the one in force).
    pub fn discard_before(&mut self, time: f64) {
        if let Some(line) = &mut self.actuation {
            while line.arrivals.len() >= 2 && line.arrivals[1] <= time + self.eps {
                line.arrivals.pop_front();
                self.history.pop_front();
                self.pruned = true;
            }
            return;
        }
        let source_time = self.profile.delay_time(time);
        while self.history.len() >= 2 && self.history[1].0 <= source_time + self.eps {
            self.history.pop_front();
            self.pruned = true;
        }
    }
}

/// Most samples of a time-varying delay profile a check takes over a run (start-up stays
/// bounded whatever the timestep).
pub const MAX_PROFILE_SAMPLES: f64 = 1e6;

/// The sampling step of a profile check over `horizon`: `step`, or coarser so that at most
/// [`MAX_PROFILE_SAMPLES`] samples are taken.
fn sampling_step(horizon: f64, step: f64) -> f64 {
    step.max(horizon / MAX_PROFILE_SAMPLES)
}

/// The `[delays]`, `[assumed_delays]`, `[actuation]` and `[initial_input]` tables of a run, for
/// building its queues ([`DelaySections::queues`]).
pub struct DelaySections<'a> {
    pub delays: &'a std::collections::BTreeMap<String, DelayProfile>,
    pub assumed_delays: &'a std::collections::BTreeMap<String, DelayProfile>,
    pub actuation: &'a std::collections::BTreeMap<String, ActuationSpec>,
    pub initial_input: &'a std::collections::BTreeMap<String, f64>,
    /// The scenario's seed (the stochastic actuation's draws).
    pub seed: u64,
    /// The run's duration and the issued-input history kept (s): Assumptions 1–2 are checked
    /// over the run.
    pub duration: f64,
    pub history: f64,
}

/// A run's delay queues: the controller's, with the delays it assumes, and the actuators' own
/// when the true delays or the actuation differ from them (every channel then actuates through
/// its own or a copy of the controller's).
pub struct BuiltQueues {
    pub assumed: Vec<DelayQueue>,
    pub actuators: Option<Vec<DelayQueue>>,
}

impl DelaySections<'_> {
    /// One queue per channel (`channels`, in the model's order) on the plant step `timestep`:
    /// the assumed profile checked against Assumptions 1–2, the true one only for being
    /// physical where it differs; errors at the key they concern (`delays.<channel>`,
    /// `assumed_delays.<channel>`, `actuation.<channel>`).
    pub fn queues(&self, channels: &[String], timestep: f64) -> Result<BuiltQueues, crate::params::ParamError> {
        use crate::params::ParamError;
        let (mut assumed, mut actuators) = (Vec::with_capacity(channels.len()), Vec::with_capacity(channels.len()));
        for (index, channel) in channels.iter().enumerate() {
            let initial = self.initial_input.get(channel).copied().unwrap_or(0.0);
            let truth = self.delays.get(channel).cloned().unwrap_or(DelayProfile::Constant(0.0));
            let true_key = format!("delays.{channel}");
            let (key, profile) = match self.assumed_delays.get(channel) {
                Some(profile) => (format!("assumed_delays.{channel}"), profile.clone()),
                None => (true_key.clone(), truth.clone()),
            };
            // The actuator's own line when it is not the controller's: another true delay
            // (only physical), or a stochastic actuation (which needs a constant assumption).
            let stochastic = self.actuation.get(channel);
            if stochastic.is_some() || self.assumed_delays.contains_key(channel) {
                truth
                    .check_physical(channel, self.duration, timestep, self.history)
                    .map_err(|e| ParamError::new(&true_key, e.to_string()))?;
            }
            actuators.push(match stochastic {
                Some(_) if profile.constant_delay().is_none() => {
                    return Err(ParamError::new(
                        format!("actuation.{channel}"),
                        "stochastic actuation needs a constant assumed delay on its channel (the consistency check of time-varying predictions is not defined for it)",
                    ));
                }
                Some(spec) => Some(DelayQueue::actuator(
                    channel,
                    truth,
                    initial,
                    timestep,
                    spec.build(self.seed, index),
                )),
                None if self.assumed_delays.contains_key(channel) => {
                    Some(DelayQueue::with_profile(channel, truth, initial, timestep).map_err(|e| ParamError::new(&true_key, e.to_string()))?)
                }
                None => None,
            });
            profile
                .check(channel, self.duration, timestep, self.history)
                .map_err(|e| ParamError::new(&key, e.to_string()))?;
            assumed.push(
                DelayQueue::with_profile(channel, profile, initial, timestep)
                    .map_err(|e| ParamError::new(&key, e.to_string()))?,
            );
        }
        // Channels without their own assumption actuate through a copy of the assumed queue.
        let actuators = actuators.iter().any(Option::is_some).then(|| {
            actuators
                .into_iter()
                .zip(&assumed)
                .map(|(own, same)| own.unwrap_or_else(|| same.clone()))
                .collect()
        });
        Ok(BuiltQueues { assumed, actuators })
    }
}

/// The `[delays]` or `[assumed_delays]` table (`section`): every constant delay is a finite
/// number of seconds >= 0 (a time-varying profile is checked against Assumptions 1–2 when the
/// queues are built: [`DelayProfile::check`]).
pub fn validate_profiles(
    section: &str,
    profiles: &std::collections::BTreeMap<String, DelayProfile>,
) -> Result<(), crate::params::ParamError> {
    for (channel, profile) in profiles {
        if let DelayProfile::Constant(delay) = profile {
            if !delay.is_finite() || *delay < 0.0 {
                return Err(crate::params::ParamError::new(
                    format!("{section}.{channel}"),
                    format!("expected a delay >= 0 seconds, found {delay}"),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn applied_span_near_agrees_with_applied_for_any_hint() {
        let profile = DelayProfile::Varying(VaryingDelay::Rational);
        let mut q = DelayQueue::with_profile("u", profile, 0.5, 0.01).unwrap();
        for k in 0..300 {
            q.push(k as f64 * 0.01, (k as f64).sin()).unwrap();
        }
        for i in 0..700 {
            let time = i as f64 * 0.0037;
            let source_time = q.profile().delay_time(time);
            let expected = q.applied(time).unwrap();
            for hint in [0, 3, 150, 299, 300, 1000] {
                let (applied, from, until, index) = q.applied_span_near(time, source_time, hint).unwrap();
                assert_eq!(applied, expected, "t = {time}, hint {hint}");
                assert!(
                    from <= source_time && source_time < until,
                    "{from} {source_time} {until}"
                );
                let (again, ..) = q.applied_span_near(time, source_time, index).unwrap();
                assert_eq!(again, expected);
            }
        }
    }

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
        assert!(matches!(q.applied(0.3), Err(DelayError::HistoryGone { .. })));
    }

    fn assert_inverse_pair(profile: &DelayProfile) {
        for k in 0..200 {
            let t = k as f64 * 0.05;
            let back = profile.delay_time(profile.prediction_time(t));
            assert!((back - t).abs() < 1e-10, "{profile:?}: phi(phi^-1({t})) = {back}");
            // φ' against a central difference.
            let e = 1e-6;
            let numeric = (profile.delay_time(t + e) - profile.delay_time(t - e)) / (2.0 * e);
            if let DelayProfile::Varying(VaryingDelay::Table { .. }) = profile {
                continue; // kinks at the knots
            }
            assert!(
                (numeric - profile.delay_time_derivative(t)).abs() < 1e-6,
                "{profile:?} phi'({t})"
            );
        }
    }

    #[test]
    fn prediction_time_inverts_delay_time_for_every_profile() {
        assert_inverse_pair(&DelayProfile::Constant(0.3));
        assert_inverse_pair(&DelayProfile::Varying(VaryingDelay::CosinePrediction {
            a: 1.0,
            b: 0.5,
            omega: 1.0,
        }));
        assert_inverse_pair(&DelayProfile::Varying(VaryingDelay::Rational));
        assert_inverse_pair(&DelayProfile::Varying(VaryingDelay::Table {
            times: vec![0.0, 2.0, 5.0],
            delays: vec![0.5, 1.2, 0.8],
        }));
    }

    #[test]
    fn closed_forms_match_the_reference() {
        let r = DelayProfile::Varying(VaryingDelay::Rational);
        // (2.37) at t = 0: phi = -1; (2.39): phi^-1(0) = (0 + sqrt 2) / 2.
        assert!((r.delay_time(0.0) + 1.0).abs() < 1e-15);
        assert!((r.prediction_time(0.0) - 2f64.sqrt() / 2.0).abs() < 1e-15);
        // (2.31): phi^-1(0) = 1.5 ("the controller kicks in at 1.5").
        let c = DelayProfile::Varying(VaryingDelay::CosinePrediction {
            a: 1.0,
            b: 0.5,
            omega: 1.0,
        });
        assert!((c.prediction_time(0.0) - 1.5).abs() < 1e-15);
    }

    #[test]
    fn time_varying_queue_applies_u_at_phi_t() {
        let profile = DelayProfile::Varying(VaryingDelay::Rational);
        let mut q = DelayQueue::with_profile("u", profile.clone(), 7.0, 0.01).unwrap();
        for k in 0..1000 {
            q.push(k as f64 * 0.01, k as f64).unwrap();
        }
        assert_eq!(q.applied(0.5).unwrap().value, 7.0); // φ(0.5) < 0: initial input
        let t = 4.0;
        let issued = profile.delay_time(t);
        assert_eq!(q.applied(t).unwrap().value, (issued / 0.01 + 1e-9).floor());
    }

    #[test]
    fn assumption_violations_name_the_condition_and_time() {
        // dD/dt = 1.5 > 1 between t = 1 and 2: (2.6) fails at t = 1.
        let p = DelayProfile::Varying(VaryingDelay::Table {
            times: vec![1.0, 2.0],
            delays: vec![0.5, 2.0],
        });
        match p.check("u", 5.0, 0.01, 10.0) {
            Err(DelayError::Assumption { condition, time, .. }) => {
                assert!(condition.contains("(2.6)"));
                assert!((time - 1.0).abs() < 0.011, "{time}");
            }
            other => panic!("{other:?}"),
        }
        // |b ω| > 1 makes φ⁻¹ non-monotone.
        let p = DelayProfile::Varying(VaryingDelay::CosinePrediction {
            a: 3.0,
            b: 2.0,
            omega: 1.0,
        });
        assert!(p.check("u", 10.0, 0.01, 10.0).is_err());
        // D reaches 0.
        let p = DelayProfile::Varying(VaryingDelay::Table {
            times: vec![0.0, 1.0],
            delays: vec![0.5, 0.0],
        });
        assert!(
            matches!(p.check("u", 2.0, 0.01, 10.0), Err(DelayError::Assumption { condition, .. }) if condition.contains("(2.4)"))
        );
        // Longer than the history kept.
        assert!(matches!(
            DelayProfile::Constant(3.0).check("u", 2.0, 0.01, 2.0),
            Err(DelayError::HistoryTooShort { .. })
        ));
        assert!(DelayProfile::Constant(0.0).check("u", 2.0, 0.01, 2.0).is_ok());
    }
}
