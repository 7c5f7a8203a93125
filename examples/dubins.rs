//! A user-defined vehicle in one file: a Dubins car (constant speed v, the turn rate ω is the
//! only input) with its own MJCF (`examples/dubins/dubins.xml`) and analytic model
//!
//!   ẋ = v cos θ,  ẏ = v sin θ,  θ̇ = ω,
//!
//! registered as `vehicle.kind = "dubins"` and driven at an obstacle with a 0.3 s turn-rate
//! delay (`examples/dubins/dubins_obstacle.toml`), by the delay-free CBF-QP (4.9) at x(t) and
//! at the prediction p(t) (2.26). The obstacle barrier (4.81) has relative degree 2 in ω.
//!
//! Run: `cargo run --example dubins -- OUT_DIR [KEY=VALUE …]` (overrides for every run).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use mjsafe::dynamics::Dynamics;
use mjsafe::embed;
use mjsafe::mujoco::{DataView, MjError, Model, ObjKind, Simulation};
use mjsafe::vehicle::MujocoVehicle;
use nalgebra::{DMatrix, DVector};

/// The analytic model the filters and predictors use.
struct DubinsModel {
    speed: f64,
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl Dynamics for DubinsModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        let (s, c) = x[2].sin_cos();
        f.copy_from_slice(&[self.speed * c, self.speed * s, 0.0]);
    }
    fn add_input_term(&self, _: &[f64], u: &[f64], xdot: &mut [f64]) {
        xdot[2] += u[0];
    }
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
        let (s, c) = x[2].sin_cos();
        j[(0, 2)] = -self.speed * s;
        j[(1, 2)] = self.speed * c;
    }
    fn input_matrix_into(&self, _: &[f64], g: &mut DMatrix<f64>) {
        g[(2, 0)] = 1.0;
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        Some([0, 1])
    }
    fn heading_index(&self) -> Option<usize> {
        Some(2)
    }
}

/// The binding to the MJCF: joints x, y, yaw; actuators speed (held at v) and turn_rate.
struct MujocoDubins {
    model: Arc<DubinsModel>,
    qpos: [usize; 3],
    dof: [usize; 3],
    ctrl_speed: usize,
    ctrl_turn_rate: usize,
    hull_geom: usize,
    hull_radius: f64,
}

fn bind(model: &Model) -> Result<Box<dyn MujocoVehicle>, MjError> {
    let joint = |name| model.require(ObjKind::Joint, name);
    let joints = [joint("x")?, joint("y")?, joint("yaw")?];
    let speed = model
        .numeric("speed")
        .and_then(|v| v.first().copied())
        .ok_or_else(|| MjError::MissingName {
            kind: "custom numeric",
            name: "speed".into(),
        })?;
    let hull_geom = model.require(ObjKind::Geom, "hull")?;
    Ok(Box::new(MujocoDubins {
        model: Arc::new(DubinsModel {
            speed,
            state_names: ["x", "y", "heading"].map(String::from).to_vec(),
            channel_names: vec!["turn_rate".to_string()],
        }),
        qpos: joints.map(|j| model.joint_qpos_addr(j)),
        dof: joints.map(|j| model.joint_dof_addr(j)),
        ctrl_speed: model.require(ObjKind::Actuator, "speed")?,
        ctrl_turn_rate: model.require(ObjKind::Actuator, "turn_rate")?,
        hull_radius: model.geom_size(hull_geom)[0],
        hull_geom,
    }))
}

impl MujocoVehicle for MujocoDubins {
    fn dynamics(&self) -> Arc<dyn Dynamics> {
        self.model.clone()
    }
    fn hull_radius(&self) -> f64 {
        self.hull_radius
    }
    fn hull_geom(&self) -> usize {
        self.hull_geom
    }
    fn read_state_into(&self, qpos: &[f64], _: &[f64], _: &[f64], x: &mut [f64]) {
        x.copy_from_slice(&self.qpos.map(|i| qpos[i]));
    }
    fn write_state(&self, sim: &mut Simulation, x: &DVector<f64>) {
        let model = sim.model();
        let (mut qpos, mut qvel, act) = (vec![0.0; model.nq()], vec![0.0; model.nv()], vec![0.0; model.na()]);
        for (k, &i) in self.qpos.iter().enumerate() {
            qpos[i] = x[k];
        }
        // Already moving at v along the heading.
        let (s, c) = x[2].sin_cos();
        qvel[self.dof[0]] = self.model.speed * c;
        qvel[self.dof[1]] = self.model.speed * s;
        sim.set_state(0.0, &qpos, &qvel, &act);
    }
    fn write_ctrl(&self, data: &mut DataView<'_>, applied_input: &[f64]) {
        let ctrl = data.ctrl_mut();
        ctrl[self.ctrl_speed] = self.model.speed;
        ctrl[self.ctrl_turn_rate] = applied_input[0];
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "dubins_logs".into()));
    std::fs::create_dir_all(&out)?;
    // Its label and description go into every run's metadata (`vehicle_label`, …).
    mjsafe::vehicle_registry::register(|r| {
        r.add_mjcf_vehicle("dubins", bind)
            .label("Dubins car")
            .description("constant speed, steered by its turn rate");
    })?;

    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/dubins/dubins_obstacle.toml");
    let runs: [(&str, &[&str]); 3] = [
        ("no filter", &["filter={kind='none'}"]),
        ("(4.9) at x(t)", &[]),
        ("(4.9) at p(t) (2.26)", &["filter.compensation='predictor'"]),
    ];
    // Further arguments: `--set`-style overrides for every run (e.g. delays.turn_rate=0.6).
    let extra: Vec<String> = std::env::args().skip(2).collect();
    println!("filter | collision | min h | min clearance (m)");
    for (i, (label, overrides)) in runs.iter().enumerate() {
        let overrides: Vec<String> = extra
            .iter()
            .cloned()
            .chain(overrides.iter().map(|s| s.to_string()))
            .collect();
        let loaded = embed::load_scenario(&scenario, &overrides)?;
        let outcome = embed::run_logged(&loaded, &out.join(format!("dubins{i}.mcap")), &mut [])?;
        let m = outcome.metrics.as_ref().expect("a logged run is analysed");
        println!(
            "{label} | {} | {:.2} | {:.3}",
            if m.collision().is_some() { "yes" } else { "no" },
            m.min_h().unwrap_or(f64::NAN),
            m.min_clearance().unwrap_or(f64::NAN),
        );
    }
    Ok(())
}
