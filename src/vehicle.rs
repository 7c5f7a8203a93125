//! Vehicles: the analytic control-affine model ẋ = f(x) + G(x) u that filters use, and the
//! binding of that state and input to a MuJoCo model in `models/`.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::mujoco::{DataView, MjError, Model, ObjKind, Simulation};

/// The vehicle kinds mjsafe knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleKind {
    /// Kinematic bicycle (4.78): x = (x1, x2, heading, speed), u = (tan δ, acceleration).
    Bicycle,
    /// ẍ = u on a line: x = (position, velocity).
    #[serde(rename = "double_integrator_1d")]
    DoubleIntegrator1d,
    /// ẍ = u in the plane: x = (x, y, vx, vy).
    #[serde(rename = "double_integrator_2d")]
    DoubleIntegrator2d,
}

/// A vehicle: its analytic model plus how its state and inputs live in MuJoCo.
pub trait Vehicle: Send {
    fn kind(&self) -> VehicleKind;
    /// Names of the state components, in order.
    fn state_names(&self) -> &'static [&'static str];
    /// Names of the input channels, in order.
    fn channel_names(&self) -> &'static [&'static str];
    /// Drift f(x).
    fn drift(&self, x: &DVector<f64>) -> DVector<f64>;
    /// Jacobian ∂f/∂x, used for Lie derivatives of relative-degree-2 barriers.
    fn drift_jacobian(&self, x: &DVector<f64>) -> DMatrix<f64>;
    /// Input matrix G(x).
    fn input_matrix(&self, x: &DVector<f64>) -> DMatrix<f64>;
    /// Indices of the planar position (x, y) in the state, if the vehicle moves in a plane.
    fn planar_position(&self) -> Option<[usize; 2]>;
    /// Radius of the collision geom `hull` (the vehicle's share of r in (4.81)).
    fn hull_radius(&self) -> f64;
    /// Id of the `hull` geom, for contact detection.
    fn hull_geom(&self) -> usize;
    /// State x read from MuJoCo data.
    fn read_state(&self, qpos: &[f64], qvel: &[f64], act: &[f64]) -> DVector<f64>;
    /// Sets MuJoCo's state (time 0) to x.
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>);
    /// Maps the applied input u (one value per channel) to MuJoCo's `ctrl`, given the data
    /// at the current (possibly RK4 trial) state. Writes only ctrl.
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]);

    /// ẋ = f(x) + G(x) u.
    fn dynamics(&self, x: &DVector<f64>, u: &DVector<f64>) -> DVector<f64> {
        self.drift(x) + self.input_matrix(x) * u
    }
    fn state_dim(&self) -> usize {
        self.state_names().len()
    }
    fn input_dim(&self) -> usize {
        self.channel_names().len()
    }
}

/// Builds the vehicle of `kind` on `model`, resolving joints and actuators by name.
pub fn bind(kind: VehicleKind, model: &Model) -> Result<Box<dyn Vehicle>, MjError> {
    Ok(match kind {
        VehicleKind::Bicycle => Box::new(Bicycle::bind(model)?),
        VehicleKind::DoubleIntegrator1d => Box::new(DoubleIntegrator1d::bind(model)?),
        VehicleKind::DoubleIntegrator2d => Box::new(DoubleIntegrator2d::bind(model)?),
    })
}

fn hull(model: &Model) -> Result<(usize, f64), MjError> {
    let geom = model.require(ObjKind::Geom, "hull")?;
    Ok((geom, model.geom_size(geom)[0]))
}

/// Kinematic bicycle (4.78) with wheelbase L from the model's custom numeric `wheelbase`.
pub struct Bicycle {
    pub wheelbase: f64,
    qpos_x: usize,
    qpos_y: usize,
    qpos_yaw: usize,
    dof_x: usize,
    dof_y: usize,
    dof_yaw: usize,
    ctrl_yaw_rate: usize,
    ctrl_speed: usize,
    act_speed: usize,
    hull_geom: usize,
    hull_radius: f64,
}

impl Bicycle {
    pub fn bind(model: &Model) -> Result<Bicycle, MjError> {
        let joint = |name| model.require(ObjKind::Joint, name);
        let (jx, jy, jyaw) = (joint("x")?, joint("y")?, joint("yaw")?);
        let yaw_rate = model.require(ObjKind::Actuator, "yaw_rate")?;
        let speed = model.require(ObjKind::Actuator, "speed")?;
        let act_speed = model
            .actuator_act_addr(speed)
            .ok_or_else(|| MjError::MissingName {
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
        Ok(Bicycle {
            wheelbase,
            qpos_x: model.joint_qpos_addr(jx),
            qpos_y: model.joint_qpos_addr(jy),
            qpos_yaw: model.joint_qpos_addr(jyaw),
            dof_x: model.joint_dof_addr(jx),
            dof_y: model.joint_dof_addr(jy),
            dof_yaw: model.joint_dof_addr(jyaw),
            ctrl_yaw_rate: yaw_rate,
            ctrl_speed: speed,
            act_speed,
            hull_geom,
            hull_radius,
        })
    }
}

impl Vehicle for Bicycle {
    fn kind(&self) -> VehicleKind {
        VehicleKind::Bicycle
    }
    fn state_names(&self) -> &'static [&'static str] {
        &["x1", "x2", "heading", "speed"]
    }
    fn channel_names(&self) -> &'static [&'static str] {
        &["steering", "acceleration"]
    }
    fn drift(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_column_slice(&[x[3] * x[2].cos(), x[3] * x[2].sin(), 0.0, 0.0])
    }
    fn drift_jacobian(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let (s, c) = x[2].sin_cos();
        let mut j = DMatrix::zeros(4, 4);
        j[(0, 2)] = -x[3] * s;
        j[(0, 3)] = c;
        j[(1, 2)] = x[3] * c;
        j[(1, 3)] = s;
        j
    }
    fn input_matrix(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let mut g = DMatrix::zeros(4, 2);
        g[(2, 0)] = x[3] / self.wheelbase;
        g[(3, 1)] = 1.0;
        g
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        Some([0, 1])
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state(&self, qpos: &[f64], qvel: &[f64], _act: &[f64]) -> DVector<f64> {
        let heading = qpos[self.qpos_yaw];
        let (s, c) = heading.sin_cos();
        // Longitudinal velocity of the rear axle, measured from the body's motion.
        let speed = qvel[self.dof_x] * c + qvel[self.dof_y] * s;
        DVector::from_column_slice(&[qpos[self.qpos_x], qpos[self.qpos_y], heading, speed])
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let mut qpos = vec![0.0; model.nq()];
        let mut qvel = vec![0.0; model.nv()];
        let mut act = vec![0.0; model.na()];
        qpos[self.qpos_x] = x[0];
        qpos[self.qpos_y] = x[1];
        qpos[self.qpos_yaw] = x[2];
        qvel[self.dof_x] = x[3] * x[2].cos();
        qvel[self.dof_y] = x[3] * x[2].sin();
        qvel[self.dof_yaw] = 0.0;
        act[self.act_speed] = x[3];
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        // (4.78): heading rate = x4 u1 / L, with x4 the commanded speed (the integrator state
        // the body's velocity follows); speed rate = u2.
        let commanded_speed = data.act()[self.act_speed];
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl_yaw_rate] = commanded_speed * applied_input[0] / self.wheelbase;
        ctrl[self.ctrl_speed] = applied_input[1];
    }
}

/// ẍ = u on a line.
pub struct DoubleIntegrator1d {
    qpos_x: usize,
    dof_x: usize,
    ctrl: usize,
    hull_geom: usize,
    hull_radius: f64,
}

impl DoubleIntegrator1d {
    pub fn bind(model: &Model) -> Result<DoubleIntegrator1d, MjError> {
        let jx = model.require(ObjKind::Joint, "x")?;
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(DoubleIntegrator1d {
            qpos_x: model.joint_qpos_addr(jx),
            dof_x: model.joint_dof_addr(jx),
            ctrl: model.require(ObjKind::Actuator, "acceleration")?,
            hull_geom,
            hull_radius,
        })
    }
}

impl Vehicle for DoubleIntegrator1d {
    fn kind(&self) -> VehicleKind {
        VehicleKind::DoubleIntegrator1d
    }
    fn state_names(&self) -> &'static [&'static str] {
        &["position", "velocity"]
    }
    fn channel_names(&self) -> &'static [&'static str] {
        &["acceleration"]
    }
    fn drift(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_column_slice(&[x[1], 0.0])
    }
    fn drift_jacobian(&self, _x: &DVector<f64>) -> DMatrix<f64> {
        DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0])
    }
    fn input_matrix(&self, _x: &DVector<f64>) -> DMatrix<f64> {
        DMatrix::from_column_slice(2, 1, &[0.0, 1.0])
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        None
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state(&self, qpos: &[f64], qvel: &[f64], _act: &[f64]) -> DVector<f64> {
        DVector::from_column_slice(&[qpos[self.qpos_x], qvel[self.dof_x]])
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let mut qpos = vec![0.0; model.nq()];
        let mut qvel = vec![0.0; model.nv()];
        let act = vec![0.0; model.na()];
        qpos[self.qpos_x] = x[0];
        qvel[self.dof_x] = x[1];
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        data.ctrl_mut()[self.ctrl] = applied_input[0];
    }
}

/// ẍ = u in the plane.
pub struct DoubleIntegrator2d {
    qpos: [usize; 2],
    dof: [usize; 2],
    ctrl: [usize; 2],
    hull_geom: usize,
    hull_radius: f64,
}

impl DoubleIntegrator2d {
    pub fn bind(model: &Model) -> Result<DoubleIntegrator2d, MjError> {
        let jx = model.require(ObjKind::Joint, "x")?;
        let jy = model.require(ObjKind::Joint, "y")?;
        let (hull_geom, hull_radius) = hull(model)?;
        Ok(DoubleIntegrator2d {
            qpos: [model.joint_qpos_addr(jx), model.joint_qpos_addr(jy)],
            dof: [model.joint_dof_addr(jx), model.joint_dof_addr(jy)],
            ctrl: [
                model.require(ObjKind::Actuator, "acceleration_x")?,
                model.require(ObjKind::Actuator, "acceleration_y")?,
            ],
            hull_geom,
            hull_radius,
        })
    }
}

impl Vehicle for DoubleIntegrator2d {
    fn kind(&self) -> VehicleKind {
        VehicleKind::DoubleIntegrator2d
    }
    fn state_names(&self) -> &'static [&'static str] {
        &["x", "y", "vx", "vy"]
    }
    fn channel_names(&self) -> &'static [&'static str] {
        &["acceleration_x", "acceleration_y"]
    }
    fn drift(&self, x: &DVector<f64>) -> DVector<f64> {
        DVector::from_column_slice(&[x[2], x[3], 0.0, 0.0])
    }
    fn drift_jacobian(&self, _x: &DVector<f64>) -> DMatrix<f64> {
        let mut j = DMatrix::zeros(4, 4);
        j[(0, 2)] = 1.0;
        j[(1, 3)] = 1.0;
        j
    }
    fn input_matrix(&self, _x: &DVector<f64>) -> DMatrix<f64> {
        let mut g = DMatrix::zeros(4, 2);
        g[(2, 0)] = 1.0;
        g[(3, 1)] = 1.0;
        g
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        Some([0, 1])
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state(&self, qpos: &[f64], qvel: &[f64], _act: &[f64]) -> DVector<f64> {
        DVector::from_column_slice(&[
            qpos[self.qpos[0]],
            qpos[self.qpos[1]],
            qvel[self.dof[0]],
            qvel[self.dof[1]],
        ])
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let mut qpos = vec![0.0; model.nq()];
        let mut qvel = vec![0.0; model.nv()];
        let act = vec![0.0; model.na()];
        qpos[self.qpos[0]] = x[0];
        qpos[self.qpos[1]] = x[1];
        qvel[self.dof[0]] = x[2];
        qvel[self.dof[1]] = x[3];
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl[0]] = applied_input[0];
        ctrl[self.ctrl[1]] = applied_input[1];
    }
}
