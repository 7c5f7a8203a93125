//! mjsafe: a MuJoCo-backed vehicle safety testbed with delayed actuators and CBF safety
//! filters. Modules mirror the blocks of the control diagram; see docs/ARCHITECTURE.md.

// `unsafe` only in `mujoco` (the FFI and the test binary's counting allocator).
#![deny(unsafe_code)]

pub mod actor;
pub mod actuator;
pub mod analyze;
pub mod barrier;
pub mod bench;
pub mod cli;
pub mod commonroad;
pub mod delay;
pub mod disturbance;
pub mod dynamics;
pub mod embed;
pub mod episode;
pub mod export;
pub mod falsify;
pub mod files;
pub mod filter;
pub mod footprint;
pub mod goal;
pub mod log;
pub mod message;
pub mod metrics;
pub mod models;
#[allow(unsafe_code)]
pub mod mujoco;
pub mod ncap;
pub mod nominal;
pub mod params;
pub mod planar;
pub mod plant;
pub mod plot;
pub mod predictor;
pub mod prescribed_time;
pub mod random;
pub mod registry;
pub mod requirement;
pub mod road;
pub mod run;
pub mod scenario;
pub mod scorecard;
pub mod sensing;
pub mod signals;
pub mod stl;
pub mod sweep;
pub mod table;
pub mod vehicle;
pub mod vehicle_registry;
