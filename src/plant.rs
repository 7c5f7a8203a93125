//! Plants. The MuJoCo plant is [`crate::mujoco::Simulation`] with a vehicle bound to it
//! (see [`crate::episode`]); this module holds the analytic reference: RK4 integration of a
//! vehicle's control-affine model ẋ = f(x) + G(x) u, used to measure MuJoCo's fidelity.

use nalgebra::DVector;

use crate::vehicle::Vehicle;

/// One classical RK4 step of ẋ = f(x) + G(x) u with u held constant over the step.
pub fn rk4_step(vehicle: &dyn Vehicle, x: &DVector<f64>, u: &DVector<f64>, h: f64) -> DVector<f64> {
    let k1 = vehicle.dynamics(x, u);
    let k2 = vehicle.dynamics(&(x + &k1 * (h / 2.0)), u);
    let k3 = vehicle.dynamics(&(x + &k2 * (h / 2.0)), u);
    let k4 = vehicle.dynamics(&(x + &k3 * h), u);
    x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0)
}

/// Integrates from x0 over `inputs.len()` steps of size h, input k held on [k h, (k+1) h),
/// with `substeps` RK4 steps per input step. Returns the states at the step boundaries.
pub fn integrate(
    vehicle: &dyn Vehicle,
    x0: &DVector<f64>,
    inputs: &[DVector<f64>],
    h: f64,
    substeps: usize,
) -> Vec<DVector<f64>> {
    let mut states = Vec::with_capacity(inputs.len() + 1);
    let mut x = x0.clone();
    states.push(x.clone());
    let dt = h / substeps as f64;
    for u in inputs {
        for _ in 0..substeps {
            x = rk4_step(vehicle, &x, u, dt);
        }
        states.push(x.clone());
    }
    states
}
