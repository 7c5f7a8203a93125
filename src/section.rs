//! A scenario table as one block: its spec checks itself when the scenario loads and sets its
//! part of the control loop when the episode is assembled. A table is registered by one
//! declaration, its field in `scenario::Scenario` marked `section` (the `scenario_tables!`
//! list); `scenario::validate` and `episode::build` go through [`Section`] for every one
//! (docs/ARCHITECTURE.md, "Extension costs").
//!
//! This module names no other module of the library (the tables import it, not the reverse):
//! what a table may set in the loop is [`ControlSettings`], which the episode's loop
//! implements.

use std::collections::BTreeMap;

use crate::actor::ActorKnowledge;
use crate::actuation::Actuator;
use crate::params::ParamError;
use crate::road::RoadSpec;
use crate::sensor::Sensor;

/// ω_i(t) added to channel i's applied input.
pub type InputDisturbance = Box<dyn Fn(f64, usize) -> f64 + Send>;

/// What a table's checks and build see of the rest of the scenario.
#[derive(Clone, Copy)]
pub struct SectionContext<'a> {
    /// The run's duration (s).
    pub duration: f64,
    /// The scenario's seed (every seeded variation).
    pub seed: u64,
    /// Whether the plant is the ODE (`plant = "ode"`) rather than MuJoCo.
    pub ode_plant: bool,
    /// The vehicle's state size (`vehicle.initial_state`'s length).
    pub state_dim: usize,
    /// Largest coordinate or radius accepted in the plane (m).
    pub extent: f64,
    /// Largest magnitude of a state component accepted.
    pub state_extent: f64,
    /// The initial input per channel (`initial_input`; channels not listed: 0).
    pub initial_input: &'a BTreeMap<String, f64>,
    /// The parsed `[commonroad]` file, if the scenario names one.
    pub commonroad: Option<&'a mjsafe_commonroad::CommonRoad>,
}

/// What a table may set in the control loop (implemented by `episode::ControlLoop`).
pub trait ControlSettings {
    /// The plant step h (s).
    fn timestep(&self) -> f64;
    /// The model's state size n.
    fn state_dim(&self) -> usize;
    /// The input channels, in the model's order.
    fn channel_names(&self) -> Vec<String>;
    /// The controller reads `sensor`'s measurement instead of the true state.
    fn set_sensor(&mut self, sensor: Sensor);
    /// Puts `actuator` between channel `channel`'s delayed command and the plant.
    fn set_actuator(&mut self, channel: usize, actuator: Actuator);
    /// Adds ω_i(t) to every channel's applied input.
    fn set_input_disturbance(&mut self, disturbance: InputDisturbance);
    /// What the controller assumes of the road users over the delay, observing them every
    /// `period` seconds (0: every control tick; an error says why the period is not allowed).
    fn set_actor_knowledge(&mut self, knowledge: ActorKnowledge, period: f64) -> Result<(), String>;
    /// The predictors step every `steps` plant steps (an error says why the delays forbid it).
    fn set_predictor_step(&mut self, steps: u32) -> Result<(), String>;
    /// Reuse the previous tick's recursive chain within this distance.
    fn set_chain_tolerance(&mut self, tolerance: f64);
    /// Whether the rows of road users out of reach are left out of the filter.
    fn set_leave_out_of_reach(&mut self, leave_out: bool);
}

/// A scenario table: its checks at load and its part of the control loop.
pub trait Section {
    /// The table's checks when the scenario loads, against what `cx` says of the rest; `key` is
    /// its name in the scenario (errors name the key under it, e.g. `sensing.latency`).
    fn validate(&self, key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError>;

    /// Sets the table's part of the control loop (default: none; a table that only describes
    /// the run, such as `[goal]`, is read where it is described).
    fn configure(&self, _cx: &SectionContext<'_>, _control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        Ok(())
    }
}

/// An optional table: absent, it checks and sets nothing.
impl<T: Section> Section for Option<T> {
    fn validate(&self, key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        self.as_ref().map_or(Ok(()), |table| table.validate(key, cx))
    }

    fn configure(&self, cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        self.as_ref().map_or(Ok(()), |table| table.configure(cx, control))
    }
}

/// `[delays]` and `[assumed_delays]`: the maths crate's profiles and checks
/// ([`crate::delay::validate_profiles`]); the episode builds the queues from both at once.
impl Section for BTreeMap<String, crate::delay::DelayProfile> {
    fn validate(&self, key: &str, _cx: &SectionContext<'_>) -> Result<(), ParamError> {
        crate::delay::validate_profiles(key, self)
    }
}

/// `[actuation.<channel>]`: seeded extra latency and drops, checked per channel
/// ([`crate::delay::ActuationSpec::validate`]); the episode builds them into the queues.
impl Section for BTreeMap<String, crate::delay::ActuationSpec> {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        self.iter()
            .try_for_each(|(channel, a)| a.validate(channel, cx.duration))
    }
}

/// `[road]`: the maths crate's spec and checks ([`crate::road::RoadSpec::validate`]); its
/// edges are barriers the episode builds with the vehicle's hull.
impl Section for crate::road::RoadSpec {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        RoadSpec::validate(self, cx.extent)
    }
}
