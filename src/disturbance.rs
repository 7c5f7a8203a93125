//! The `[disturbance]` section: an additive disturbance the controller does not know — a
//! deterministic one of the dissertation's examples ((3.49)/(3.50)) or a bounded random one,
//! piecewise constant and seeded, on the states of the ODE plant (B_ω = I in (3.24)) or with the
//! inputs on either plant (Z = G in (4.12)). The section's spec, its checks at load and the
//! disturbance signals the plant and the control loop are built with.

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::random::{self, Stream};
use crate::section::{ControlSettings, Section, SectionContext};

/// `[disturbance]`: which disturbance, by `kind`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DisturbanceSpec {
    /// (3.49)/(3.50): ω1 = sin(0.4πt)/√2, ω2 = sgn(ω1)/√2, entering every state (B_ω = I).
    Example349,
    /// A bounded random disturbance ‖ω‖ ≤ `bound` entering with the inputs (Z = G in (4.12)),
    /// piecewise constant over `hold` seconds, seeded. Both plants.
    RandomInput { bound: f64, hold: f64 },
    /// A bounded random disturbance ‖ω‖ ≤ `bound` on every state (B_ω = I in (3.24)),
    /// piecewise constant over `hold` seconds, seeded. ODE plant.
    RandomState { bound: f64, hold: f64 },
}

/// ω(t) on every state of the ODE plant.
pub type StateDisturbance = Box<dyn Fn(f64) -> DVector<f64> + Send>;

/// ω_i(t) added to channel i's applied input.
pub use crate::section::InputDisturbance;

impl DisturbanceSpec {
    /// The checks of the section when the scenario loads: a bound ≥ 0 and a hold > 0; a
    /// disturbance of the state only on the ODE plant (`ode_plant`). Key: `disturbance`.
    pub fn validate(&self, ode_plant: bool) -> Result<(), ParamError> {
        match self {
            DisturbanceSpec::RandomInput { bound, hold } | DisturbanceSpec::RandomState { bound, hold }
                if !(bound.is_finite() && *bound >= 0.0 && hold.is_finite() && *hold > 0.0) =>
            {
                Err(ParamError::new(
                    "disturbance",
                    format!("expected bound >= 0 and hold > 0, found bound = {bound}, hold = {hold}"),
                ))
            }
            DisturbanceSpec::Example349 | DisturbanceSpec::RandomState { .. } if !ode_plant => Err(ParamError::new(
                "disturbance",
                "this disturbance acts on the state of the ODE plant: expected plant = \"ode\" (or kind = \"random_input\")",
            )),
            _ => Ok(()),
        }
    }

    /// The disturbance of the `n` states of the ODE plant, if this one acts on the state.
    pub fn state_disturbance(&self, seed: u64, n: usize) -> Option<StateDisturbance> {
        match *self {
            DisturbanceSpec::Example349 => Some(Box::new(crate::filter::linear_delays::disturbance_3_49)),
            DisturbanceSpec::RandomState { bound, hold } => Some(Box::new(move |t| {
                random_vector(seed, Stream::StateDisturbance, bound, hold, t, n)
            })),
            DisturbanceSpec::RandomInput { .. } => None,
        }
    }

    /// The disturbance of the `r` input channels, if this one enters with the inputs.
    pub fn input_disturbance(&self, seed: u64, r: usize) -> Option<InputDisturbance> {
        match *self {
            DisturbanceSpec::RandomInput { bound, hold } => Some(Box::new(move |t, channel| {
                random_component(seed, Stream::InputDisturbance, bound, hold, t, r, channel)
            })),
            DisturbanceSpec::Example349 | DisturbanceSpec::RandomState { .. } => None,
        }
    }
}

/// A random vector with ‖ω‖ ≤ `bound`, constant on each interval [k·hold, (k+1)·hold).
fn random_vector(seed: u64, stream: Stream, bound: f64, hold: f64, t: f64, dim: usize) -> DVector<f64> {
    DVector::from_iterator(
        dim,
        (0..dim).map(|i| random_component(seed, stream, bound, hold, t, dim, i)),
    )
}

/// Component i of [`random_vector`] (no allocation: the input disturbance is sampled in the
/// control callback).
fn random_component(seed: u64, stream: Stream, bound: f64, hold: f64, t: f64, dim: usize, i: usize) -> f64 {
    let interval = (t / hold + 1e-9).floor().max(0.0) as u64;
    bound / (dim as f64).sqrt() * random::symmetric_unit(seed, stream, interval, i as u64)
}

/// `[disturbance]`: an input disturbance is added in the control loop; a state disturbance is
/// the ODE plant's (built with the plant).
impl Section for DisturbanceSpec {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        DisturbanceSpec::validate(self, cx.ode_plant)
    }

    fn configure(&self, cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        if let Some(disturbance) = self.input_disturbance(cx.seed, control.channel_names().len()) {
            control.set_input_disturbance(disturbance);
        }
        Ok(())
    }
}
