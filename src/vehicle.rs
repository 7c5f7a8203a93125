//! Vehicles bound to MuJoCo ([`MujocoVehicle`]): where each built-in vehicle's state and inputs
//! live in `mjData`, and the analytic model ([`crate::dynamics`]) read from its MJCF. Each is
//! registered as a `vehicle.kind` by one closure in `vehicle_registry`, as a user's is.

use std::sync::Arc;

use nalgebra::DVector;

use crate::dynamics::{BicycleModel, DoubleIntegratorModel, Dynamics, LongitudinalModel, UnicycleModel};
use crate::mujoco::{DataView, MjError, Model, ObjKind, Simulation};

/// A vehicle bound to a MuJoCo model: how its state and inputs live in `mjData`.
pub trait MujocoVehicle: Send {
    /// The analytic model of this vehicle (parameters read from the MJCF).
    fn dynamics(&self) -> Arc<dyn Dynamics>;
    /// Radius of the collision geom `hull` (the vehicle's share of r in (4.81)).
    fn hull_radius(&self) -> f64;
    /// Id of the `hull` geom, for contact detection.
    fn hull_geom(&self) -> usize;
    /// x ← the state read from MuJoCo data (no allocation: called in the control callback).
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], act: &[f64], x: &mut [f64]);
    /// State x read from MuJoCo data.
    fn read_state(&self, qpos: &[f64], qvel: &[f64], act: &[f64]) -> DVector<f64> {
        let mut x = DVector::zeros(self.dynamics().state_dim());
        self.read_state_into(qpos, qvel, act, x.as_mut_slice());
        x
    }
    /// Sets MuJoCo's state (time 0) to x.
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>);
    /// Maps the applied input u (one value per channel) to MuJoCo's `ctrl`, given the data at
    /// the current (possibly RK4 trial) state. Writes only ctrl.
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]);
    /// Per channel, the [lowest, highest] input the vehicle can apply (what it clamps an
    /// applied input to); ±∞ where it has no limit (the default: none).
    fn input_limits(&self) -> Vec<[f64; 2]> {
        vec![[f64::NEG_INFINITY, f64::INFINITY]; self.dynamics().input_dim()]
    }
}

fn hull(model: &Model) -> Result<(usize, f64), MjError> {
    let geom = model.require(ObjKind::Geom, "hull")?;
    Ok((geom, model.geom_size(geom)[0]))
}

fn wheelbase(model: &Model) -> Result<f64, MjError> {
    model
        .numeric("wheelbase")
        .and_then(|v| v.first().copied())
        .ok_or_else(|| MjError::MissingName {
            kind: "custom numeric",
            name: "wheelbase".into(),
        })
}

fn activation(model: &Model, actuator: usize, name: &str) -> Result<usize, MjError> {
    model.actuator_act_addr(actuator).ok_or_else(|| MjError::MissingName {
        kind: "stateful actuator (with dyntype)",
        name: name.into(),
    })
}

/// The bicycle on `models/bicycle.xml` (body at the rear axle; see the model's comments).
pub struct MujocoBicycle {
    model: Arc<BicycleModel>,
    qpos: [usize; 3],
    dof: [usize; 3],
    ctrl_yaw_rate: usize,
    ctrl_speed: usize,
    act_speed: usize,
    /// A model with a `speed_lead` actuator (models/commonroad_car.xml) moves each step as
    /// (4.78) does, to second order ([`MidStep`]).
    mid_step: Option<MidStep>,
    hull_geom: usize,
    hull_radius: f64,
}

/// The actuators that make a step of models/commonroad_car.xml move the car as (4.78) does
/// under a held input, to second order in the timestep h: the Euler and implicit integrators
/// apply the speed activation x4 of the step's start and move the body along its heading at the
/// step's start, where (4.78) moves at the mean speed x4 + h u2 / 2 along the mean heading
/// θ + h ω / 2. `speed_lead` adds K h u2 / 2 to the speed servo's force (its target becomes the
/// mean speed), `rear_no_slip` turns the rear axle's velocity by h ω / 2 (its target lateral
/// speed), the yaw-rate servo runs at the mean speed, and x4 is read from the activation.
struct MidStep {
    speed_lead: usize,
    rear_no_slip: usize,
    /// h under the Euler and implicit integrators; 0 under RK4, which integrates the
    /// activation with the forces.
    late: f64,
}

/// qpos and dof addresses of the planar joints x, y, yaw.
fn planar_joints(model: &Model) -> Result<([usize; 3], [usize; 3]), MjError> {
    let joint = |name| model.require(ObjKind::Joint, name);
    let ids = [joint("x")?, joint("y")?, joint("yaw")?];
    Ok((
        ids.map(|j| model.joint_qpos_addr(j)),
        ids.map(|j| model.joint_dof_addr(j)),
    ))
}

impl MujocoBicycle {
    pub fn bind(model: &Model) -> Result<MujocoBicycle, MjError> {
        let (qpos, dof) = planar_joints(model)?;
        let yaw_rate = model.require(ObjKind::Actuator, "yaw_rate")?;
        let speed = model.require(ObjKind::Actuator, "speed")?;
        let act_speed = activation(model, speed, "speed")?;
        let mid_step = match model.id(ObjKind::Actuator, "speed_lead") {
            Some(speed_lead) => Some(MidStep {
                speed_lead,
                rear_no_slip: model.require(ObjKind::Actuator, "rear_no_slip")?,
                late: match model.integrator() {
                    crate::mujoco::Integrator::Rk4 => 0.0,
                    _ => model.timestep(),
                },
            }),
            None => None,
        };
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoBicycle {
            model: Arc::new(BicycleModel::new(wheelbase(model)?)),
            qpos,
            dof,
            ctrl_yaw_rate: yaw_rate,
            ctrl_speed: speed,
            act_speed,
            mid_step,
            hull_geom,
            hull_radius,
        })
    }
}

impl MujocoVehicle for MujocoBicycle {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], act: &[f64], x: &mut [f64]) {
        let heading = qpos[self.qpos[2]];
        let speed = match self.mid_step {
            // x4 of (4.78) itself: the integrator of u2 (the body moves at the step's mean
            // speed, [`MidStep`]).
            Some(_) => act[self.act_speed],
            None => {
                // Longitudinal velocity of the rear axle, measured from the body's motion.
                let (s, c) = heading.sin_cos();
                qvel[self.dof[0]] * c + qvel[self.dof[1]] * s
            }
        };
        x.copy_from_slice(&[qpos[self.qpos[0]], qpos[self.qpos[1]], heading, speed]);
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, mut qvel, mut act) = (vec![0.0; model.nq()], vec![0.0; model.nv()], vec![0.0; model.na()]);
        qpos[self.qpos[0]] = x[0];
        qpos[self.qpos[1]] = x[1];
        qpos[self.qpos[2]] = x[2];
        qvel[self.dof[0]] = x[3] * x[2].cos();
        qvel[self.dof[1]] = x[3] * x[2].sin();
        act[self.act_speed] = x[3];
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        // (4.78): heading rate = x4 u1 / L, with x4 the commanded speed (the integrator state
        // the body's velocity follows); speed rate = u2.
        let mut commanded_speed = data.act()[self.act_speed];
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl_speed] = applied_input[1];
        if let Some(mid) = &self.mid_step {
            // The step's mean speed x4 + h u2 / 2, and its velocity turned by half the step's
            // turn h ω (tan: the lateral speed in the frame of the step's start).
            ctrl[mid.speed_lead] = 0.5 * mid.late * applied_input[1];
            commanded_speed += 0.5 * mid.late * applied_input[1];
            let turn = mid.late * commanded_speed * applied_input[0] / self.model.wheelbase;
            ctrl[mid.rear_no_slip] = commanded_speed * (0.5 * turn).tan();
        }
        ctrl[self.ctrl_yaw_rate] = commanded_speed * applied_input[0] / self.model.wheelbase;
    }
}

/// Wheels in the order rear left, rear right, front left, front right.
const WHEELS: [&str; 4] = ["rl", "rr", "fl", "fr"];

/// Gain of the steering-rate loop (1/s): the steering actuators' ctrl (a rate, clamped by their
/// ctrlrange) is this times the distance from the commanded angle to the Ackermann target, so the
/// commanded angle reaches the target as a first-order lag of 1/50 s when the rate limit is not
/// active.
pub const CAR_STEERING_RATE_GAIN: f64 = 50.0;

/// The car on `models/car.xml` (docs/car.md): a chassis on a free joint, four wheels on tyre
/// contacts, Ackermann-steered front wheels (rate-limited steering servos) and a lagged drive/brake
/// torque at every wheel. Its analytic model is the kinematic bicycle (4.78) with the MJCF's
/// wheelbase; the state is read from the chassis at the rear-axle midpoint.
pub struct MujocoCar {
    model: Arc<BicycleModel>,
    /// qpos address of the chassis' free joint (position, then quaternion w x y z).
    qpos_free: usize,
    /// dof address of the free joint (world linear velocity, then local angular velocity).
    dof_free: usize,
    /// The model's qpos0 (wheel and steering angles at rest, the chassis' rest height).
    qpos0: Vec<f64>,
    /// dof addresses of the wheel spin hinges (rl, rr, fl, fr).
    dof_wheels: [usize; 4],
    /// Steering actuators (front left, front right) and their activations (commanded angles).
    ctrl_steer: [usize; 2],
    act_steer: [usize; 2],
    /// Drive/brake torque actuators (rl, rr, fl, fr).
    ctrl_torque: [usize; 4],
    /// Half the front track (kingpin to the centre line), for Ackermann steering.
    half_track: f64,
    /// Largest road-wheel angle (the steering hinges' range).
    max_steer: f64,
    wheel_radius: f64,
    /// Wheel torque per unit of commanded acceleration at each of the four wheels:
    /// (total mass + Σ wheel spin inertia / r²) · r / 4.
    torque_per_acceleration: f64,
    hull_geom: usize,
    hull_radius: f64,
}

impl MujocoCar {
    pub fn bind(model: &Model) -> Result<MujocoCar, MjError> {
        let free = model.require(ObjKind::Joint, "chassis")?;
        let mut dof_wheels = [0; 4];
        let mut ctrl_torque = [0; 4];
        let mut spin_inertia = 0.0;
        for (i, w) in WHEELS.iter().enumerate() {
            dof_wheels[i] = model.joint_dof_addr(model.require(ObjKind::Joint, &format!("wheel_{w}"))?);
            ctrl_torque[i] = model.require(ObjKind::Actuator, &format!("torque_{w}"))?;
            spin_inertia += model.body_inertia(model.require(ObjKind::Body, &format!("wheel_{w}"))?)[1];
        }
        let mut ctrl_steer = [0; 2];
        let mut act_steer = [0; 2];
        for (i, side) in ["fl", "fr"].iter().enumerate() {
            let name = format!("steer_{side}");
            ctrl_steer[i] = model.require(ObjKind::Actuator, &name)?;
            act_steer[i] = activation(model, ctrl_steer[i], &name)?;
        }
        let steer = model.require(ObjKind::Joint, "steer_fl")?;
        let max_steer = model
            .joint_range(steer)
            .map_or(std::f64::consts::FRAC_PI_2, |[lo, hi]| hi.min(-lo));
        let half_track = model.body_pos(model.require(ObjKind::Body, "knuckle_fl")?)[1].abs();
        let wheel_radius = model.geom_size(model.require(ObjKind::Geom, "tyre_rl")?)[0];
        let mass: f64 = (1..model.nbody()).map(|b| model.body_mass(b)).sum();
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoCar {
            model: Arc::new(BicycleModel::new(wheelbase(model)?)),
            qpos_free: model.joint_qpos_addr(free),
            dof_free: model.joint_dof_addr(free),
            qpos0: model.qpos0().to_vec(),
            dof_wheels,
            ctrl_steer,
            act_steer,
            ctrl_torque,
            half_track,
            max_steer,
            wheel_radius,
            torque_per_acceleration: (mass + spin_inertia / wheel_radius.powi(2)) * wheel_radius / 4.0,
            hull_geom,
            hull_radius,
        })
    }

    /// Road-wheel angles (left, right) for u1 = tan δ of the bicycle: Ackermann steering, both
    /// wheels pointing at the turn centre on the rear-axle line, tan δ_l,r = L u1 / (L ∓ w u1)
    /// with w half the track. u1 is first limited to ±tan(max angle); the inner wheel then
    /// stops at the hinge's range.
    pub fn steering_targets(&self, u1: f64) -> [f64; 2] {
        let limit = self.max_steer.tan();
        let u1 = if u1.is_nan() { 0.0 } else { u1.clamp(-limit, limit) };
        let l = self.model.wheelbase;
        let w = self.half_track;
        [
            (l * u1).atan2(l - w * u1).clamp(-self.max_steer, self.max_steer),
            (l * u1).atan2(l + w * u1).clamp(-self.max_steer, self.max_steer),
        ]
    }

    /// Wheel torque (N m, at each wheel) the binding commands per m/s² of u2.
    pub fn torque_per_acceleration(&self) -> f64 {
        self.torque_per_acceleration
    }
}

impl MujocoVehicle for MujocoCar {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    /// u1 = tan δ within ±tan(the steering hinges' range), as [`MujocoCar`] clamps it; the
    /// acceleration is bounded only through the wheels' torque limits and the tyres (no
    /// single number: unbounded here).
    fn input_limits(&self) -> Vec<[f64; 2]> {
        let steer = self.max_steer.tan();
        vec![[-steer, steer], [f64::NEG_INFINITY, f64::INFINITY]]
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], _act: &[f64], x: &mut [f64]) {
        let p = &qpos[self.qpos_free..self.qpos_free + 7];
        let (w, qx, qy, qz) = (p[3], p[4], p[5], p[6]);
        // Yaw of the chassis (z-y-x Euler angles), in (−π, π].
        let heading = (2.0 * (w * qz + qx * qy)).atan2(1.0 - 2.0 * (qy * qy + qz * qz));
        let (s, c) = heading.sin_cos();
        // The free joint's linear velocity is the world velocity of the chassis origin, the
        // rear-axle midpoint: its component along the heading is the speed.
        let speed = qvel[self.dof_free] * c + qvel[self.dof_free + 1] * s;
        x.copy_from_slice(&[p[0], p[1], heading, speed]);
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, mut qvel, act) = (self.qpos0.clone(), vec![0.0; model.nv()], vec![0.0; model.na()]);
        let (s, c) = (0.5 * x[2]).sin_cos();
        // Rest height and straight wheels from qpos0; heading as a rotation about z.
        qpos[self.qpos_free] = x[0];
        qpos[self.qpos_free + 1] = x[1];
        qpos[self.qpos_free + 3..self.qpos_free + 7].copy_from_slice(&[c, 0.0, 0.0, s]);
        qvel[self.dof_free] = x[3] * x[2].cos();
        qvel[self.dof_free + 1] = x[3] * x[2].sin();
        // Rolling without slip: spin = v / r on every wheel (straight ahead, no yaw rate).
        for &d in &self.dof_wheels {
            qvel[d] = x[3] / self.wheel_radius;
        }
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        let targets = self.steering_targets(applied_input[0]);
        let commanded = [data.act()[self.act_steer[0]], data.act()[self.act_steer[1]]];
        let ctrl = data.ctrl_mut();
        for i in 0..2 {
            // Steering rate toward the target; MuJoCo clamps it to the rate limit (ctrlrange).
            ctrl[self.ctrl_steer[i]] = CAR_STEERING_RATE_GAIN * (targets[i] - commanded[i]);
        }
        // Feed-forward torque for the commanded acceleration, shared by the four wheels;
        // MuJoCo clamps it to the torque limit and lags it (dyntype filter).
        let torque = self.torque_per_acceleration * applied_input[1];
        for &c in &self.ctrl_torque {
            ctrl[c] = torque;
        }
    }
}

/// The unicycle on `models/unicycle.xml`: speed and yaw-rate velocity servos plus a lateral
/// no-slip damper on a body with planar joints.
pub struct MujocoUnicycle {
    model: Arc<UnicycleModel>,
    qpos: [usize; 3],
    dof: [usize; 3],
    ctrl_speed: usize,
    ctrl_turn_rate: usize,
    hull_geom: usize,
    hull_radius: f64,
}

impl MujocoUnicycle {
    pub fn bind(model: &Model) -> Result<MujocoUnicycle, MjError> {
        let (qpos, dof) = planar_joints(model)?;
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoUnicycle {
            model: Arc::new(UnicycleModel::default()),
            qpos,
            dof,
            ctrl_speed: model.require(ObjKind::Actuator, "speed")?,
            ctrl_turn_rate: model.require(ObjKind::Actuator, "turn_rate")?,
            hull_geom,
            hull_radius,
        })
    }
}

impl MujocoVehicle for MujocoUnicycle {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], _qvel: &[f64], _act: &[f64], x: &mut [f64]) {
        x.copy_from_slice(&[qpos[self.qpos[0]], qpos[self.qpos[1]], qpos[self.qpos[2]]]);
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, qvel, act) = (vec![0.0; model.nq()], vec![0.0; model.nv()], vec![0.0; model.na()]);
        qpos[self.qpos[0]] = x[0];
        qpos[self.qpos[1]] = x[1];
        qpos[self.qpos[2]] = x[2];
        let _ = self.dof;
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl_speed] = applied_input[0];
        ctrl[self.ctrl_turn_rate] = applied_input[1];
    }
}

/// Double integrator on `models/double_integrator_{1d,2d}.xml`: slide joints and motors.
pub struct MujocoDoubleIntegrator {
    model: Arc<DoubleIntegratorModel>,
    qpos: Vec<usize>,
    dof: Vec<usize>,
    ctrl: Vec<usize>,
    hull_geom: usize,
    hull_radius: f64,
}

impl MujocoDoubleIntegrator {
    pub fn bind(model: &Model, dim: usize) -> Result<MujocoDoubleIntegrator, MjError> {
        let axes: &[(&str, &str)] = if dim == 1 {
            &[("x", "acceleration")]
        } else {
            &[("x", "acceleration_x"), ("y", "acceleration_y")]
        };
        let mut qpos = Vec::new();
        let mut dof = Vec::new();
        let mut ctrl = Vec::new();
        for (joint, actuator) in axes {
            let j = model.require(ObjKind::Joint, joint)?;
            qpos.push(model.joint_qpos_addr(j));
            dof.push(model.joint_dof_addr(j));
            ctrl.push(model.require(ObjKind::Actuator, actuator)?);
        }
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoDoubleIntegrator {
            model: Arc::new(DoubleIntegratorModel::new(dim)),
            qpos,
            dof,
            ctrl,
            hull_geom,
            hull_radius,
        })
    }
}

impl MujocoVehicle for MujocoDoubleIntegrator {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], _act: &[f64], x: &mut [f64]) {
        let positions = self.qpos.iter().map(|&i| qpos[i]);
        let velocities = self.dof.iter().map(|&i| qvel[i]);
        for (x, v) in x.iter_mut().zip(positions.chain(velocities)) {
            *x = v;
        }
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, mut qvel, act) = (vec![0.0; model.nq()], vec![0.0; model.nv()], vec![0.0; model.na()]);
        let dim = self.qpos.len();
        for i in 0..dim {
            qpos[self.qpos[i]] = x[i];
            qvel[self.dof[i]] = x[dim + i];
        }
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        let ctrl = data.ctrl_mut();
        for (&c, &u) in self.ctrl.iter().zip(applied_input) {
            ctrl[c] = u;
        }
    }
}

/// The longitudinal car of Ames et al. (CDC 2014, Table 1) on `models/longitudinal.xml`: the car
/// and the lead on slide joints `x` and `lead_x`, the `force` motor; m is the car body's mass,
/// f0, f1, f2 and v_L the `<numeric>`s of those names (`lead_speed`).
pub struct MujocoLongitudinal {
    model: Arc<LongitudinalModel>,
    /// qpos and dof addresses of the car's and the lead's slide joints.
    qpos: [usize; 2],
    dof: [usize; 2],
    ctrl_force: usize,
    hull_geom: usize,
    hull_radius: f64,
}

/// The first value of the `<numeric>` `name`, checked by `valid`.
fn numeric_value(
    model: &Model,
    name: &'static str,
    expected: &'static str,
    valid: impl Fn(f64) -> bool,
) -> Result<f64, MjError> {
    let value = model
        .numeric(name)
        .and_then(|v| v.first().copied())
        .ok_or_else(|| MjError::MissingName {
            kind: "custom numeric",
            name: name.into(),
        })?;
    if valid(value) {
        Ok(value)
    } else {
        Err(MjError::InvalidValue { name, value, expected })
    }
}

impl MujocoLongitudinal {
    pub fn bind(model: &Model) -> Result<MujocoLongitudinal, MjError> {
        let car = model.require(ObjKind::Joint, "x")?;
        let lead = model.require(ObjKind::Joint, "lead_x")?;
        let body = model.require(ObjKind::Body, "vehicle")?;
        let mass = model.body_mass(body);
        if !(mass.is_finite() && mass > 0.0) {
            return Err(MjError::InvalidValue {
                name: "mass of body `vehicle`",
                value: mass,
                expected: "a finite mass > 0 (kg)",
            });
        }
        let coefficient = |name| {
            numeric_value(model, name, "a finite resistance coefficient >= 0", |v| {
                v.is_finite() && v >= 0.0
            })
        };
        let resistance = [coefficient("f0")?, coefficient("f1")?, coefficient("f2")?];
        let lead_speed = numeric_value(model, "lead_speed", "a finite speed (m/s)", f64::is_finite)?;
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoLongitudinal {
            model: Arc::new(LongitudinalModel::new(mass, resistance, lead_speed)),
            qpos: [car, lead].map(|j| model.joint_qpos_addr(j)),
            dof: [car, lead].map(|j| model.joint_dof_addr(j)),
            ctrl_force: model.require(ObjKind::Actuator, "force")?,
            hull_geom,
            hull_radius,
        })
    }
}

impl MujocoVehicle for MujocoLongitudinal {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], _act: &[f64], x: &mut [f64]) {
        let [car, lead] = self.qpos;
        // x = (p, v, z), z = q_lead − q_car.
        x.copy_from_slice(&[qpos[car], qvel[self.dof[0]], qpos[lead] - qpos[car]]);
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, mut qvel, act) = (vec![0.0; model.nq()], vec![0.0; model.nv()], vec![0.0; model.na()]);
        qpos[self.qpos[0]] = x[0];
        qpos[self.qpos[1]] = x[0] + x[2];
        qvel[self.dof[0]] = x[1];
        // No force acts on the lead: it keeps v_L.
        qvel[self.dof[1]] = self.model.lead_speed;
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        // m v̇ = u − F_r(v) with v this (RK4 trial) state's speed: exact under RK4.
        let resistance = self.model.resistance_force(data.qvel()[self.dof[0]]);
        data.ctrl_mut()[self.ctrl_force] = applied_input[0] - resistance;
    }
}
