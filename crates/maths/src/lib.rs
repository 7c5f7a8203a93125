//! mjsafe's pure maths, the blocks of the control diagram that need neither MuJoCo nor I/O:
//! the vehicles' dynamics, barrier functions, safety filters, predictors over the delay, the
//! delays themselves, the sensor and the actuators between the plant and the controller, the
//! road users' motions and what the controller assumes of them, roads, nominal controllers and
//! signal temporal logic. The simulation library (`mjsafe`) re-exports
//! every module under the same name (`mjsafe::barrier`, …); this crate cannot reach MuJoCo or
//! the log because it does not depend on them (docs/ARCHITECTURE.md).

#![forbid(unsafe_code)]

pub mod actor;
pub mod actuation;
pub mod barrier;
pub mod delay;
pub mod dynamics;
pub mod filter;
pub mod footprint;
pub mod nominal;
pub mod params;
pub mod planar;
pub mod predictor;
pub mod prescribed_time;
pub mod random;
pub mod road;
pub mod sensor;
pub mod stl;
