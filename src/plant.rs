//! Plants: what the episode steps. [`MujocoPlant`] steps MuJoCo with the controller inside
//! `mjcb_control`; [`OdePlant`] integrates the analytic model ẋ = f(x) + G(x) u with classical
//! RK4 and asks the controller for the input at the same four stage times RK4 uses in MuJoCo.
//! Both call the controller through [`Controller`], so the control loop is one code path.

use std::sync::Arc;

use nalgebra::DVector;

use crate::barrier::Barrier;
use crate::dynamics::Dynamics;
use crate::footprint::{boxes_penetration, OrientedBox};
use crate::mujoco::{CallbackContext, ControlHook, DataView, MjError, PhysicsWarning, Simulation};
use crate::vehicle::MujocoVehicle;

/// The control side, as a plant sees it.
pub trait Controller {
    /// The applied input at one evaluation of step `step` (call `call_in_step`, `offset`
    /// seconds after the step's start). On call 0 of a control-tick step the controller runs
    /// its tick on the state `state` writes (the real state at the start of the step).
    fn input(&mut self, step: u64, call_in_step: u32, offset: f64, state: &dyn Fn(&mut [f64])) -> &[f64];
}

pub use crate::scenario::PlantKind;

pub trait Plant: Send {
    fn timestep(&self) -> f64;
    /// The state x at the current time.
    fn state(&self) -> DVector<f64>;
    /// x ← the state at the current time (`x` has the state's dimension; no allocation).
    fn state_into(&self, x: &mut DVector<f64>);
    /// One step of size `timestep()`.
    fn step(&mut self, controller: &mut dyn Controller) -> Result<(), MjError>;
    /// What drove the last step: MuJoCo's `ctrl` (as the callback left it), or the ODE plant's
    /// input at each of its four RK4 stages (a time-varying delay switches inputs inside a
    /// step).
    fn actuation(&self) -> Vec<f64>;
    /// One step driven by `actuation` (from [`Plant::actuation`]) with no controller: replaying
    /// a run's actuation is the bare physics loop of the benchmarks (same model, same steps,
    /// same contacts).
    fn step_with_actuation(&mut self, actuation: &[f64]) -> Result<(), MjError>;
    /// Places moving obstacle `index` (its index among all obstacles) at `position` for the
    /// next step. The ODE plant reads the barriers it is given instead: nothing to do.
    /// (`turn`: its rotation since the start, rad; a box turns with it.)
    fn move_obstacle(&mut self, index: usize, position: [f64; 2], turn: f64);
    /// Penetration depth (> 0) into each obstacle, or None when not touching.
    fn penetrations(&self, obstacles: &[Barrier], depths: &mut Vec<Option<f64>>);
    /// A warning of the physics engine, raised since the last call, after which the physics
    /// is not the model's (each kind once; see [`Simulation::take_warning`]).
    /// Per channel, the [lowest, highest] input the plant applies (±∞: no limit).
    fn input_limits(&self) -> Vec<[f64; 2]>;
    fn take_warning(&mut self) -> Option<PhysicsWarning> {
        None
    }
}

/// MuJoCo plant: a simulation with a bound vehicle; obstacles are geoms of the world body (a
/// moving one's moved every step) or, for a lead, of a mocap body.
pub struct MujocoPlant {
    sim: Simulation,
    vehicle: Box<dyn MujocoVehicle>,
    obstacles: Vec<MujocoObstacle>,
    /// The vehicle's geom whose contacts count: its hull, or the box added for a footprint
    /// or a lead.
    contact_geom: usize,
    /// The contact geom's half extents if it is a box, and each obstacle's: a box-box pair's
    /// depth is [`boxes_penetration`]'s, not MuJoCo's.
    contact_box: Option<[f64; 3]>,
    obstacle_boxes: Vec<Option<[f64; 3]>>,
    /// Per obstacle, the turn its geom was last given (as a mocap body's quaternion) and its
    /// orientation in the model text (a box's layout heading).
    turns: Vec<([f64; 4], [f64; 4])>,
    input_buffer: Vec<f64>,
}

/// An obstacle as the MuJoCo plant sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MujocoObstacle {
    /// Its geom (sphere or box).
    pub geom: usize,
    /// The mocap index of its body if it moves in one (a lead), None if it is in the world body.
    pub mocap: Option<usize>,
    /// A geom of the world body that moves ([`Simulation::place_world_geom`]).
    pub moves_in_world: bool,
    /// How many barriers the episode keeps for it (one per pair of covering circles): its
    /// depth goes to the first, the others get none.
    pub barriers: usize,
}

impl MujocoPlant {
    /// The vehicle's contacts are its hull geom's until [`MujocoPlant::with_contact_geom`].
    pub fn new(
        sim: Simulation,
        vehicle: Box<dyn MujocoVehicle>,
        obstacles: Vec<MujocoObstacle>,
        x0: &DVector<f64>,
    ) -> MujocoPlant {
        let obstacle_boxes = (obstacles.iter())
            .map(|o| sim.model().box_half_extents(o.geom))
            .collect();
        let turns = (obstacles.iter())
            .map(|o| ([1.0, 0.0, 0.0, 0.0], sim.model().geom_quat(o.geom)))
            .collect();
        let mut plant = MujocoPlant {
            turns,
            contact_box: sim.model().box_half_extents(vehicle.hull_geom()),
            sim,
            contact_geom: vehicle.hull_geom(),
            obstacle_boxes,
            vehicle,
            obstacles,
            input_buffer: Vec::new(),
        };
        plant.vehicle.write_state(&mut plant.sim, x0);
        plant
    }

    /// The vehicle's contacts are those of `geom` (a geom of its body) instead of the hull's.
    pub fn with_contact_geom(mut self, geom: usize) -> MujocoPlant {
        self.contact_geom = geom;
        self.contact_box = self.sim.model().box_half_extents(geom);
        self
    }

    /// A box geom where the last kinematics put it (the state the last step started from).
    fn placed_box(&self, geom: usize, half: [f64; 3]) -> OrientedBox {
        let m = self.sim.geom_xmat(geom);
        OrientedBox {
            centre: self.sim.geom_xpos(geom),
            axes: [[m[0], m[3], m[6]], [m[1], m[4], m[7]], [m[2], m[5], m[8]]],
            half,
        }
    }
}

/// Routes MuJoCo's control callback to a [`Controller`] and maps its input to `ctrl`.
struct CallbackAdapter<'a> {
    controller: &'a mut dyn Controller,
    vehicle: &'a dyn MujocoVehicle,
    input: &'a mut Vec<f64>,
}

impl ControlHook for CallbackAdapter<'_> {
    fn on_control(&mut self, ctx: CallbackContext, data: &mut DataView<'_>) {
        {
            let view: &DataView<'_> = data;
            let read = |x: &mut [f64]| self.vehicle.read_state_into(view.qpos(), view.qvel(), view.act(), x);
            let input = self
                .controller
                .input(ctx.step, ctx.call_in_step, ctx.time - ctx.step_start_time, &read);
            self.input.clear();
            self.input.extend_from_slice(input);
        }
        self.vehicle.write_ctrl(data, self.input);
    }
}

impl Plant for MujocoPlant {
    fn input_limits(&self) -> Vec<[f64; 2]> {
        self.vehicle.input_limits()
    }
    fn timestep(&self) -> f64 {
        self.sim.model().timestep()
    }
    fn state(&self) -> DVector<f64> {
        let d = self.sim.data();
        self.vehicle.read_state(d.qpos(), d.qvel(), d.act())
    }
    fn state_into(&self, x: &mut DVector<f64>) {
        let d = self.sim.data();
        self.vehicle
            .read_state_into(d.qpos(), d.qvel(), d.act(), x.as_mut_slice());
    }
    fn step(&mut self, controller: &mut dyn Controller) -> Result<(), MjError> {
        let mut adapter = CallbackAdapter {
            controller,
            vehicle: self.vehicle.as_ref(),
            input: &mut self.input_buffer,
        };
        self.sim.step(&mut adapter)
    }
    fn actuation(&self) -> Vec<f64> {
        self.sim.data().ctrl().to_vec()
    }
    fn take_warning(&mut self) -> Option<PhysicsWarning> {
        self.sim.take_warning()
    }
    fn step_with_actuation(&mut self, actuation: &[f64]) -> Result<(), MjError> {
        self.sim.set_ctrl(actuation);
        self.sim.step_without_hook()
    }
    /// Sets the obstacle's mocap body (at z = 0): the next `mj_step`'s collision sees it there.
    fn move_obstacle(&mut self, index: usize, position: [f64; 2], turn: f64) {
        let Some(&obstacle) = self.obstacles.get(index) else {
            return;
        };
        if let Some(mocap) = obstacle.mocap {
            self.sim.set_mocap_pos(mocap, [position[0], position[1], 0.0]);
            if turn != 0.0 {
                self.sim.set_mocap_yaw(mocap, turn);
            }
        } else if obstacle.moves_in_world {
            let (body, local) = &mut self.turns[index];
            if turn != 0.0 {
                let (s, c) = (0.5 * turn).sin_cos();
                *body = [c, 0.0, 0.0, s];
            }
            self.sim
                .place_world_geom(obstacle.geom, [position[0], position[1], 0.0], *body, *local);
        }
    }
    /// From MuJoCo's contacts between the vehicle's contact geom (the hull, or the footprint's
    /// or lead's box) and each obstacle's geom, deepest first in the obstacle's first barrier
    /// slot. The contacts after `mj_step` are those of the step's first collision phase (the
    /// state at its start). MuJoCo says which pairs touch; two boxes' depth is their exact
    /// penetration ([`boxes_penetration`]): MuJoCo 2.2.2's box-box collider reports half of it,
    /// and at a grazing corner up to a metre in one frame and 27 µm in another
    /// (docs/actors.md, "On MuJoCo").
    fn penetrations(&self, obstacles: &[Barrier], depths: &mut Vec<Option<f64>>) {
        let vehicle = self.contact_geom;
        let contacts = self.sim.data().contacts();
        depths.clear();
        for (o, obstacle_box) in self.obstacles.iter().zip(&self.obstacle_boxes) {
            let geom = o.geom;
            let mut touching = (contacts.iter())
                .filter(|c| (c.geom1 == vehicle && c.geom2 == geom) || (c.geom2 == vehicle && c.geom1 == geom))
                .map(|c| -c.dist)
                .peekable();
            let depth = match (self.contact_box, obstacle_box) {
                (Some(car), Some(other)) if touching.peek().is_some() => Some(boxes_penetration(
                    &self.placed_box(vehicle, car),
                    &self.placed_box(geom, *other),
                )),
                _ => touching.fold(None, |acc: Option<f64>, d| Some(acc.map_or(d, |a| a.max(d)))),
            }
            .filter(|d| *d > 0.0);
            depths.push(depth);
            depths.extend(std::iter::repeat_n(None, o.barriers.saturating_sub(1)));
        }
        depths.truncate(obstacles.len());
    }
}

/// Reference plant: RK4 on the analytic model, input sampled at the stage times.
pub struct OdePlant {
    dynamics: Arc<dyn Dynamics>,
    x: DVector<f64>,
    /// The state at the start of the last step: contacts are reported for it, as MuJoCo's
    /// are (its collision phase runs on the state a step starts from).
    step_start: DVector<f64>,
    timestep: f64,
    step: u64,
    disturbance: Option<Disturbance>,
    /// The inputs at the four RK4 stages of the last step (its actuation).
    last_input: Vec<f64>,
}

/// An additive disturbance w(t) on ẋ (e.g. B_ω ω(t) of (3.24); [`crate::disturbance`]).
pub type Disturbance = crate::disturbance::StateDisturbance;

impl OdePlant {
    pub fn new(dynamics: Arc<dyn Dynamics>, x0: DVector<f64>, timestep: f64) -> OdePlant {
        OdePlant {
            dynamics,
            step_start: x0.clone(),
            x: x0,
            timestep,
            step: 0,
            disturbance: None,
            last_input: Vec::new(),
        }
    }

    /// Adds w(t) to ẋ at every RK4 stage.
    pub fn with_disturbance(mut self, disturbance: Disturbance) -> OdePlant {
        self.disturbance = Some(disturbance);
        self
    }
}

impl Plant for OdePlant {
    /// The analytic model applies any input.
    fn input_limits(&self) -> Vec<[f64; 2]> {
        vec![[f64::NEG_INFINITY, f64::INFINITY]; self.dynamics.input_dim()]
    }
    fn timestep(&self) -> f64 {
        self.timestep
    }
    fn state(&self) -> DVector<f64> {
        self.x.clone()
    }
    fn state_into(&self, x: &mut DVector<f64>) {
        x.copy_from(&self.x);
    }
    fn step(&mut self, controller: &mut dyn Controller) -> Result<(), MjError> {
        let h = self.timestep;
        let x = self.x.clone();
        let model = self.dynamics.as_ref();
        let step_time = self.step as f64 * h;
        let disturbance = self.disturbance.as_ref();
        let last_input = &mut self.last_input;
        let step = self.step;
        let mut derivative = |call: u32, offset: f64, stage: &DVector<f64>| {
            let input = controller.input(step, call, offset, &|out: &mut [f64]| out.copy_from_slice(x.as_slice()));
            if call == 0 {
                last_input.clear();
            }
            last_input.extend_from_slice(input);
            ode_rhs(model, disturbance, stage, input, step_time + offset)
        };
        let k1 = derivative(0, 0.0, &x);
        let k2 = derivative(1, h / 2.0, &(&x + &k1 * (h / 2.0)));
        let k3 = derivative(2, h / 2.0, &(&x + &k2 * (h / 2.0)));
        let k4 = derivative(3, h, &(&x + &k3 * h));
        self.x = &x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
        self.step_start = x;
        self.step += 1;
        Ok(())
    }
    fn actuation(&self) -> Vec<f64> {
        self.last_input.clone()
    }
    fn step_with_actuation(&mut self, actuation: &[f64]) -> Result<(), MjError> {
        let (h, x) = (self.timestep, &self.x);
        let (model, disturbance) = (self.dynamics.as_ref(), self.disturbance.as_ref());
        let step_time = self.step as f64 * h;
        let stages: Vec<&[f64]> = actuation.chunks(actuation.len() / 4).collect();
        let derivative = |stage: usize, offset: f64, state: &DVector<f64>| {
            ode_rhs(model, disturbance, state, stages[stage], step_time + offset)
        };
        let k1 = derivative(0, 0.0, x);
        let k2 = derivative(1, h / 2.0, &(x + &k1 * (h / 2.0)));
        let k3 = derivative(2, h / 2.0, &(x + &k2 * (h / 2.0)));
        let k4 = derivative(3, h, &(x + &k3 * h));
        let next = x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
        self.step_start = std::mem::replace(&mut self.x, next);
        self.step += 1;
        Ok(())
    }
    fn move_obstacle(&mut self, _index: usize, _position: [f64; 2], _turn: f64) {}
    /// Geometric: the overlap of the vehicle's hull circle with each obstacle, at the state
    /// the last step started from (the state the episode logs with this step's barriers).
    fn penetrations(&self, obstacles: &[Barrier], depths: &mut Vec<Option<f64>>) {
        depths.clear();
        depths.extend(obstacles.iter().map(|o| {
            let depth = -o.clearance(&self.step_start);
            (depth > 0.0).then_some(depth)
        }));
    }
}

/// ẋ = f(x) + G(x) u + w(t) at one RK4 stage of the ODE plant.
fn ode_rhs(
    model: &dyn Dynamics,
    disturbance: Option<&Disturbance>,
    state: &DVector<f64>,
    input: &[f64],
    time: f64,
) -> DVector<f64> {
    let dx = model.dynamics(state, &DVector::from_column_slice(input));
    match disturbance {
        Some(w) => dx + w(time),
        None => dx,
    }
}

/// One classical RK4 step of ẋ = f(x) + G(x) u with u held constant over the step.
pub fn rk4_step(model: &dyn Dynamics, x: &DVector<f64>, u: &DVector<f64>, h: f64) -> DVector<f64> {
    let k1 = model.dynamics(x, u);
    let k2 = model.dynamics(&(x + &k1 * (h / 2.0)), u);
    let k3 = model.dynamics(&(x + &k2 * (h / 2.0)), u);
    let k4 = model.dynamics(&(x + &k3 * h), u);
    x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0)
}

/// Integrates from x0 over `inputs.len()` steps of size h, input k held on [k h, (k+1) h),
/// with `substeps` RK4 steps per input step. Returns the states at the step boundaries.
pub fn integrate(
    model: &dyn Dynamics,
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
            x = rk4_step(model, &x, u, dt);
        }
        states.push(x.clone());
    }
    states
}
