//! Vehicles bound to MuJoCo ([`MujocoVehicle`]): where each built-in vehicle's state and inputs
//! live in `mjData`, and the analytic model ([`crate::dynamics`]) read from its MJCF.

use std::sync::Arc;

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::dynamics::{BicycleModel, DoubleIntegratorModel, Dynamics, UnicycleModel};
use crate::mujoco::{DataView, MjError, Model, ObjKind, Simulation};

/// The systems mjsafe knows (scenario key `vehicle.kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleKind {
    /// Kinematic bicycle (4.78): x = (x1, x2, heading, speed), u = (tan δ, acceleration).
    Bicycle,
    /// Nonholonomic unicycle (2.36): x = (x, y, θ), u = (v, ω).
    Unicycle,
    /// ẍ = u on a line: x = (position, velocity).
    #[serde(rename = "double_integrator_1d")]
    DoubleIntegrator1d,
    /// ẍ = u in the plane: x = (x, y, vx, vy).
    #[serde(rename = "double_integrator_2d")]
    DoubleIntegrator2d,
    /// ẋ = A x + B u with A, B from the scenario (ODE plant only), e.g. (2.30), (3.34).
    Linear,
    /// Example 1 of Ch. 4 (4.52): ẋ1 = −x1 − x2 + u1, ẋ2 = x1³ + x2 u2 (ODE plant only).
    NonlinearExample1,
    /// The strict-feedback system (5.82): ẋ1 = x1² + x2, ẋ2 = u (ODE plant only).
    StrictFeedback,
}

impl VehicleKind {
    /// Whether the kind has an MJCF model (and so can run on the MuJoCo plant).
    pub fn has_mjcf(self) -> bool {
        !matches!(
            self,
            VehicleKind::Linear | VehicleKind::NonlinearExample1 | VehicleKind::StrictFeedback
        )
    }
}

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
}

/// Builds the vehicle of `kind` on `model`, resolving joints and actuators by name.
pub fn bind(kind: VehicleKind, model: &Model) -> Result<Box<dyn MujocoVehicle>, MjError> {
    Ok(match kind {
        VehicleKind::Bicycle => Box::new(MujocoBicycle::bind(model)?),
        VehicleKind::Unicycle => Box::new(MujocoUnicycle::bind(model)?),
        VehicleKind::DoubleIntegrator1d => Box::new(MujocoDoubleIntegrator::bind(model, 1)?),
        VehicleKind::DoubleIntegrator2d => Box::new(MujocoDoubleIntegrator::bind(model, 2)?),
        VehicleKind::Linear | VehicleKind::NonlinearExample1 | VehicleKind::StrictFeedback => {
            return Err(MjError::MissingName {
                kind: "MJCF binding for vehicle kind",
                name: format!("{kind:?}"),
            })
        }
    })
}

fn hull(model: &Model) -> Result<(usize, f64), MjError> {
    let geom = model.require(ObjKind::Geom, "hull")?;
    Ok((geom, model.geom_size(geom)[0]))
}

/// The bicycle on `models/bicycle.xml` (body at the rear axle; see the model's comments).
pub struct MujocoBicycle {
    model: Arc<BicycleModel>,
    qpos: [usize; 3],
    dof: [usize; 3],
    ctrl_yaw_rate: usize,
    ctrl_speed: usize,
    act_speed: usize,
    hull_geom: usize,
    hull_radius: f64,
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
        let act_speed = model.actuator_act_addr(speed).ok_or_else(|| MjError::MissingName {
            kind: "stateful actuator (dyntype=\"integrator\")",
            name: "speed".into(),
        })?;
        let wheelbase = model
            .numeric("wheelbase")
            .and_then(|v| v.first().copied())
            .ok_or_else(|| MjError::MissingName {
                kind: "custom numeric",
                name: "wheelbase".into(),
            })?;
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(MujocoBicycle {
            model: Arc::new(BicycleModel::new(wheelbase)),
            qpos,
            dof,
            ctrl_yaw_rate: yaw_rate,
            ctrl_speed: speed,
            act_speed,
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
    fn read_state_into(&self, qpos: &[f64], qvel: &[f64], _act: &[f64], x: &mut [f64]) {
        let heading = qpos[self.qpos[2]];
        let (s, c) = heading.sin_cos();
        // Longitudinal velocity of the rear axle, measured from the body's motion.
        let speed = qvel[self.dof[0]] * c + qvel[self.dof[1]] * s;
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
        let commanded_speed = data.act()[self.act_speed];
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl_yaw_rate] = commanded_speed * applied_input[0] / self.model.wheelbase;
        ctrl[self.ctrl_speed] = applied_input[1];
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
