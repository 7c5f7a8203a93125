//! mjsafe: a MuJoCo-backed vehicle safety testbed with delayed actuators and CBF safety
//! filters. Modules mirror the blocks of the control diagram; see docs/ARCHITECTURE.md.

// `unsafe` only in `mujoco` (the FFI and the test binary's counting allocator).
#![deny(unsafe_code)]

pub use mjsafe_maths::actor;
pub use mjsafe_maths::actuation;
pub mod actuator;
pub mod analyze;
pub use mjsafe_maths::barrier;
pub mod bench;
pub mod cli;
pub mod commonroad;
pub mod control_spec;
pub use mjsafe_maths::delay;
pub mod disturbance;
pub use mjsafe_maths::dynamics;
pub mod embed;
pub mod episode;
pub mod export;
pub mod falsify;
pub mod files;
pub use mjsafe_maths::filter;
pub use mjsafe_maths::footprint;
pub mod goal;
pub mod log;
pub mod message;
pub mod metrics;
pub mod models;
#[allow(unsafe_code)]
pub mod mujoco;
pub mod ncap;
pub mod obstacles;
pub use mjsafe_maths::nominal;
pub use mjsafe_maths::params;
pub use mjsafe_maths::planar;
pub mod plant;
pub mod plot;
pub use mjsafe_maths::predictor;
pub use mjsafe_maths::prescribed_time;
pub use mjsafe_maths::random;
pub mod registry;
pub mod requirement;
pub use mjsafe_maths::road;
pub mod run;
pub mod scenario;
pub mod scorecard;
pub mod section;
pub mod sensing;
pub use mjsafe_maths::sensor;
pub mod signals;
pub mod stall;
pub use mjsafe_maths::stl;
pub mod sweep;
pub mod table;
pub mod vehicle;
pub mod vehicle_registry;
