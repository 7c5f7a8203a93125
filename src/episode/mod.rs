//! The episode loop: builds the plant (MuJoCo or the analytic ODE) and the controller for a
//! scenario, steps the plant, and reports every step to the log sinks. See
//! docs/ARCHITECTURE.md for the data flow of one control tick.

mod build;
mod control;
pub mod cost;
mod reach;
mod records;

use std::path::PathBuf;
use std::time::Instant;

use nalgebra::DVector;

use crate::barrier::{self, Barrier};
use crate::log::{LogError, Record, RunInfo, Sink, STALL_EVENT};
use crate::mujoco::{self, MjError};
use crate::plant::Plant;
use crate::scenario::{LoadedScenario, ScenarioError};
use crate::signals::Observed;
use crate::stall::{StallDetector, StallFacts, STALL_SPEED};

pub use crate::filter::TICK_TOLERANCE;
pub use control::{Consistency, ControlLoop, InputDisturbance, Tick};
use records::{obstacle_scene, RecordBuffers, SceneState};

#[derive(Debug, thiserror::Error)]
pub enum EpisodeError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Log(#[from] LogError),
    #[error("{file}: key `vehicle.model`: {reason}")]
    Model { file: String, reason: MjError },
    #[error(transparent)]
    Mujoco(#[from] MjError),
}

/// An obstacle of the episode: its barriers, whether the controller knows it, contact state.
#[derive(Debug, Clone)]
struct Obstacle {
    name: String,
    /// One barrier (4.81) per (vehicle circle, obstacle circle) pair: a circle obstacle and
    /// the hull have one, named as the obstacle (docs/actors.md, "Footprints").
    barriers: Vec<Barrier>,
    /// Per barrier, its obstacle circle's centre relative to the obstacle's (world frame).
    offsets: Vec<[f64; 2]>,
    /// The obstacle's circles: the barriers are the vehicle's circles' pairs in turn, each
    /// with these in order (barrier k pairs vehicle circle k / circles with circle k % circles).
    circles: usize,
    /// The obstacle's true centre now.
    centre: [f64; 2],
    outline: Outline,
    appear_at: f64,
    known: bool,
    in_contact: bool,
    /// Deepest penetration of the current contact episode.
    contact_depth: f64,
    /// A recorded road user outside its recorded span (its barriers parked, `/actors` absent).
    absent: bool,
    /// A moving obstacle's true motion (its barrier's centre follows it at every step).
    motion: Option<crate::actor::ActorMotion>,
    /// Its true state at the current step (set by `move_actors`, read by the `/barrier` record).
    state: crate::actor::ActorState,
}

/// An obstacle's own shape (its barriers' r also include the vehicle's circles).
#[derive(Debug, Clone, Copy)]
enum Outline {
    Circle { radius: f64 },
    Box { length: f64, width: f64, heading: f64 },
}

/// The vehicle's extent about its planar position [front, rear, half width] and each moving
/// road user's [length, width] (`RunInfo::extents`); None without moving road users, unless the
/// vehicle has a footprint and there are obstacles (its contacts with them can then be checked
/// from the log alone, as tests/commonroad_check.py does).
fn extents(loaded: &LoadedScenario, hull_radius: f64, obstacles: &[Obstacle]) -> Option<crate::log::Extents> {
    let actors: std::collections::BTreeMap<String, [f64; 2]> = (obstacles.iter())
        .filter(|o| o.motion.is_some())
        .map(|o| {
            let size = match o.outline {
                Outline::Circle { radius } => [2.0 * radius, 2.0 * radius],
                Outline::Box { length, width, .. } => [length, width],
            };
            (o.name.clone(), size)
        })
        .collect();
    if actors.is_empty() && (obstacles.is_empty() || loaded.scenario.vehicle.footprint.is_none()) {
        return None;
    }
    let vehicle = match &loaded.scenario.vehicle.footprint {
        Some(f) => [f.offset + 0.5 * f.length, 0.5 * f.length - f.offset, 0.5 * f.width],
        None => [hull_radius; 3],
    };
    Some(crate::log::Extents { vehicle, actors })
}

/// Result of a finished (or stopped) episode.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeSummary {
    pub steps: u64,
    pub simulated_time: f64,
    pub wall_seconds: f64,
    /// Why the episode stopped before its end, if it did.
    pub error: Option<StopReason>,
    /// The barrier rows the controller formed and left out (road users out of reach).
    pub barrier_rows: BarrierRows,
}

/// Over a run: the barrier rows the controller formed for its filter's decisions and laws,
/// the rows of road users out of reach it left out of them without forming them
/// (docs/actors.md, "Out of reach"), and the decisions it made again (an input above the
/// bound the left-out rows were checked for; the rows of the first attempt are not counted).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct BarrierRows {
    pub formed: u64,
    pub left_out: u64,
    pub redone: u64,
}

/// Why an episode stopped before its last step (logged as an `/event`).
#[derive(Debug, Clone, PartialEq)]
pub enum StopReason {
    /// A stop was requested ([`request_stop`]: Ctrl-C, SIGTERM).
    Interrupted,
    /// An error inside the run: a non-finite state, a filter or delay-queue error, a
    /// MuJoCo warning, a panic in the control callback.
    Error(String),
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopReason::Interrupted => f.write_str(INTERRUPTED),
            StopReason::Error(message) => f.write_str(message),
        }
    }
}

impl EpisodeSummary {
    pub fn real_time_factor(&self) -> f64 {
        if self.wall_seconds > 0.0 {
            self.simulated_time / self.wall_seconds
        } else {
            f64::INFINITY
        }
    }
}

/// An episode ready to run.
pub struct Episode {
    plant: Box<dyn Plant>,
    control: ControlLoop,
    obstacles: Vec<Obstacle>,
    /// State constraints that are not obstacles (always known).
    barriers: Vec<Barrier>,
    steps: u64,
    info: RunInfo,
    scene: SceneState,
    /// The plant's actuation after every step, when recording (benchmarks).
    actuation: Option<Vec<Vec<f64>>>,
    /// Scratch space of the logged barrier constraints (one evaluation per barrier and step).
    lie: barrier::LieWorkspace,
    constraint: barrier::Constraint,
    /// The obstacles' barriers, for the plant's contact check (each obstacle's in a row).
    obstacle_barriers: Vec<Barrier>,
    /// Per-step scratch: penetration depth per obstacle, ẋ with the applied input (the
    /// velocities of time to collision).
    depths: Vec<Option<f64>>,
    xdot: Vec<f64>,
    /// The ego points road users' barriers measure from, for their logged conditions, and
    /// each logged barrier's point (None: not a road user's circle), found once.
    ego_points: reach::EgoPoints,
    logged_points: Vec<Option<usize>>,
    /// `[log] barrier_pairs`: `/barrier` lists each pair of an obstacle, not one entry.
    log_barrier_pairs: bool,
    /// Per-step and per-tick records, updated in place (their names keep their storage).
    records: RecordBuffers,
    /// The run's estimated cost, and the error of a log over the log budget (taken by
    /// [`Episode::check_log_budget`]).
    cost: cost::Cost,
    log_budget: Option<ScenarioError>,
    /// Predictions realised at a time inside the current step, logged after its records.
    inside_step: Vec<control::Consistency>,
    /// The predictions realised at a step (their room kept between steps).
    realized: Vec<control::Consistency>,
    /// The margin added to a moving obstacle's radius in the controller's barrier (m).
    actor_margin: f64,
    /// The `stall_time` definition applied to the records as they are logged, for the `stall`
    /// event (it reads the records and only adds an event: nothing feeds back into control).
    stall: (StallDetector, StallFacts),
    /// Where the step loop stands ([`Episode::advance`]).
    cursor: Cursor,
}

/// The step loop's state between steps: the next step k, x(t_k) and the input of the step
/// (allocated once), and how the episode ended once it has.
struct Cursor {
    step: u64,
    x: DVector<f64>,
    applied: DVector<f64>,
    end: Option<Ended>,
    /// The steps the episode was to take, when its caller ended it early ([`Episode::end_here`]).
    planned: Option<u64>,
}

/// A barrier at a state ([`Episode::barriers_now`]): the fields of the log's `BarrierValue`.
#[derive(Debug, Clone, PartialEq)]
pub struct BarrierNow {
    pub name: String,
    /// h(x), in the barrier's own unit.
    pub h: f64,
    /// Signed distance to the boundary (m for obstacles and road edges).
    pub clearance: f64,
    /// Whether the controller knows it yet.
    pub known: bool,
    /// Whether it is an obstacle's (vs a state constraint or road edge).
    pub obstacle: bool,
}

impl BarrierNow {
    fn of(b: &Barrier, x: &DVector<f64>, known: bool, obstacle: bool) -> BarrierNow {
        BarrierNow {
            name: b.name.clone(),
            h: b.h(x),
            clearance: b.clearance(x),
            known,
            obstacle,
        }
    }
}

/// How an episode ended: the steps it took and why it stopped early, if it did.
pub type Ended = (u64, Option<StopReason>);

impl Episode {
    /// Loads the model, builds plant and controller, and checks everything that depends on
    /// the model (state size, channel names, delays against the timestep and Assumptions 1–2,
    /// each kind's own checks): the blocks of the control diagram, assembled in `build`.
    pub fn new(loaded: &LoadedScenario) -> Result<Episode, EpisodeError> {
        mujoco::check_version()?;
        let mut parts = build::plant_parts(loaded)?;
        let model = parts.dynamics.clone();
        let timestep = parts.timestep;
        check_step_budget(loaded, timestep)?;
        build::check_state_and_channels(loaded, model.as_ref())?;
        let (period, steps_per_tick) = build::control_period(loaded, timestep)?;
        let queues = build::queues(loaded, model.channel_names(), timestep, period)?;
        let nominal = build::nominal(loaded, &model)?;
        let x0 = build::initial_state(loaded);
        let mut barriers = build::barriers(loaded, model.state_dim())?;
        let obstacles = build::obstacles(loaded, model.as_ref(), parts.hull_radius, &x0)?;
        // The road's edges are barriers known from the start, after the scenario's own.
        let own_barriers = barriers.len();
        barriers.extend(build::road_edges(loaded, model.as_ref(), parts.hull_radius, &x0)?);
        let every_barrier: Vec<Barrier> = barriers
            .iter()
            .chain(obstacles.iter().flat_map(|o| &o.barriers))
            .cloned()
            .collect();
        let filter = build::filter(
            loaded,
            &model,
            &queues.assumed,
            &every_barrier,
            nominal.as_ref(),
            (timestep, parts.hull_radius),
        )?;
        build::check_mixed_relative_degree(loaded, filter.barrier_form(), &every_barrier)?;
        let reference_path = nominal.reference_path();
        let path = reference_path.map(|p| (p.point, p.heading, p.speed.abs() * loaded.scenario.duration));
        let hull_radius = parts.hull_radius;
        // The 3D view's static lines, drawn near the start, the reference path's far end and
        // the obstacles: the road, and the scenario's own half-spaces on the plane.
        let start = model.planar_position().map(|[i, j]| [x0[i], x0[j]]);
        let far_end = path.zip(start).map(|((point, heading, reach), p)| {
            let (s, c) = heading.sin_cos();
            let along = (p[0] - point[0]) * c + (p[1] - point[1]) * s + reach;
            [point[0] + along * c, point[1] + along * s]
        });
        let around: Vec<[f64; 2]> = start
            .into_iter()
            .chain(far_end)
            .chain(loaded.scenario.obstacles.iter().map(|o| o.centre))
            .collect();
        let scene_lines = build::scene_lines(loaded, model.planar_position(), &barriers[..own_barriers], &around);
        let vehicle_params = std::mem::take(&mut parts.vehicle_params);
        let barrier_counts: Vec<usize> = obstacles.iter().map(|o| o.barriers.len()).collect();
        let plant = build::plant(loaded, parts, &barrier_counts, &x0)?;
        let mut control = ControlLoop::new(
            model.clone(),
            nominal,
            filter,
            queues.assumed,
            queues.structure,
            timestep,
            steps_per_tick,
        );
        if let Some(actuators) = queues.actuators {
            control.set_actuators(actuators);
        }
        build::configure_control(loaded, &mut control, &barriers)?;
        let mut info = build::run_info(loaded, vehicle_params, &control, period)?;
        info.reference_path = reference_path.map(|p| (p.point, p.heading));
        info.extents = extents(loaded, hull_radius, &obstacles);
        // `/barrier`'s entries: one per obstacle with barriers, or per pair.
        let log_barrier_pairs = loaded.scenario.log.barrier_pairs;
        let logged_barriers = barriers.len()
            + match log_barrier_pairs {
                true => every_barrier.len() - barriers.len(),
                false => obstacles.iter().filter(|o| !o.barriers.is_empty()).count(),
            };
        let (cost, log_budget) = build::check_cost(loaded, &control, build::steps(loaded, timestep), logged_barriers)?;
        let moving_names: Vec<String> = (obstacles.iter())
            .filter(|o| o.motion.is_some())
            .map(|o| o.name.clone())
            .collect();
        Ok(Episode {
            plant,
            control,
            obstacle_barriers: obstacles.iter().flat_map(|o| o.barriers.iter().cloned()).collect(),
            obstacles,
            barriers,
            steps: build::steps(loaded, timestep),
            actuation: None,
            lie: barrier::LieWorkspace::new(model.as_ref()),
            constraint: barrier::Constraint::zeros(model.input_dim()),
            depths: Vec::new(),
            xdot: vec![0.0; model.state_dim()],
            ego_points: reach::EgoPoints::new(model.as_ref()),
            logged_points: Vec::new(),
            log_barrier_pairs,
            records: RecordBuffers::new(model.state_names(), model.channel_names(), moving_names.into_iter()),
            actor_margin: loaded.scenario.actor_knowledge.map_or(0.0, |k| k.margin),
            scene: SceneState::new(
                hull_radius,
                loaded
                    .scenario
                    .vehicle
                    .footprint
                    .map(|r| ([r.length, r.width], r.offset)),
                path,
                scene_lines,
                model.channel_names(),
                records::frame_steps(steps_per_tick, timestep),
            ),
            cost,
            log_budget,
            inside_step: Vec::new(),
            realized: Vec::new(),
            stall: (StallDetector::default(), StallFacts::from_metadata(&info.metadata())),
            info,
            cursor: Cursor {
                step: 0,
                x: DVector::zeros(model.state_dim()),
                applied: DVector::zeros(model.input_dim()),
                end: None,
                planned: None,
            },
        })
    }

    /// The run's estimated cost (integration steps, log bytes), checked against the work
    /// budget when the episode was built.
    pub fn cost(&self) -> cost::Cost {
        self.cost
    }

    /// Refuses a log the estimate puts over the log-size budget (`--max-log-size`): call it
    /// before opening the log (an episode analysed in memory writes none).
    pub fn check_log_budget(&mut self) -> Result<(), EpisodeError> {
        self.log_budget.take().map_or(Ok(()), |e| Err(e.into()))
    }

    pub fn info(&self) -> &RunInfo {
        &self.info
    }

    /// Steps the episode will take.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Ends the episode after at most `steps` steps (a preview, or a fuzz case that only
    /// needs to show the episode runs).
    pub fn limit_steps(&mut self, steps: u64) {
        self.steps = self.steps.min(steps);
    }

    /// The RK4 step the predictors use (seconds).
    pub fn predictor_step(&self) -> f64 {
        self.control.predictor_step()
    }

    /// Recomputes every reused recursive-predictor chain too (see
    /// [`ControlLoop::audit_chain_reuse`]); read the result with [`Episode::chain_audit`].
    pub fn audit_chain_reuse(&mut self) {
        self.control.audit_chain_reuse();
    }

    /// (largest difference between a reused and a recomputed prediction, reused predictions).
    pub fn chain_audit(&self) -> Option<(f64, u64)> {
        self.control.chain_audit()
    }

    /// The barrier rows formed and left out so far ([`BarrierRows`]).
    pub fn barrier_rows(&self) -> BarrierRows {
        self.control.barrier_rows()
    }

    /// Per channel, the [lowest, highest] input the plant applies (±∞: no limit; the car's
    /// steering is bounded by its hinges).
    pub fn input_limits(&self) -> Vec<[f64; 2]> {
        self.plant.input_limits()
    }

    /// The plant's current state x.
    pub fn plant_state(&self) -> DVector<f64> {
        self.plant.state()
    }

    /// Records the plant's actuation after every step of the next run (for
    /// [`Episode::replay_actuation`]).
    pub fn record_actuation(&mut self) {
        self.actuation = Some(Vec::with_capacity(self.steps as usize));
    }

    /// The actuation recorded by the last run, one entry per step.
    pub fn take_actuation(&mut self) -> Vec<Vec<f64>> {
        self.actuation.take().unwrap_or_default()
    }

    /// Steps the plant through a recorded actuation with no controller, sink or check: the
    /// bare physics loop over this episode's model, on the same trajectory (and contacts) as
    /// the recorded run (benchmarks compare the pipeline against it).
    pub fn replay_actuation(&mut self, actuation: &[Vec<f64>]) -> Result<(), EpisodeError> {
        let h = self.control.timestep();
        let position = self.control.model().planar_position();
        let moving = self.obstacles.iter().any(|o| o.motion.is_some());
        for (k, a) in actuation.iter().enumerate() {
            // Moving obstacles go where the run put them (triggered by the same states; a lead
            // on the line has no trigger).
            if moving {
                let (time, x) = (k as f64 * h, self.plant.state());
                for (index, o) in self.obstacles.iter_mut().enumerate() {
                    if let Some(motion) = &mut o.motion {
                        if let Some([i, j]) = position {
                            motion.check_trigger(time, [x[i], x[j]]);
                        }
                        let state = motion.where_at(time, index);
                        self.plant.move_obstacle(index, state.position, state.turn);
                    }
                }
            }
            self.plant.step_with_actuation(a)?;
        }
        Ok(())
    }

    /// Runs to the end (or to the first error inside the run, which is logged as an `/event`
    /// error and returned in the summary) and finishes every sink.
    pub fn run(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<EpisodeSummary, EpisodeError> {
        let _graceful = GracefulStop::begin();
        let started = Instant::now();
        let (steps, error) = match self.run_steps(sinks) {
            Ok(outcome) => outcome,
            Err(e) => {
                for sink in sinks.iter_mut() {
                    let _ = sink.finish(false);
                }
                return Err(e);
            }
        };
        let complete = error.is_none();
        for sink in sinks.iter_mut() {
            sink.finish(complete)?;
        }
        Ok(EpisodeSummary {
            steps,
            simulated_time: steps as f64 * self.control.timestep(),
            wall_seconds: started.elapsed().as_secs_f64(),
            error,
            barrier_rows: self.control.barrier_rows(),
        })
    }

    /// Makes the obstacles that appear by `time` known to the controller; returns their indices.
    fn reveal_obstacles(&mut self, time: f64) -> Vec<usize> {
        let tolerance = TICK_TOLERANCE * self.control.timestep();
        let mut revealed = Vec::new();
        for (i, o) in self.obstacles.iter_mut().enumerate() {
            if !o.known && o.appear_at <= time + tolerance {
                o.known = true;
                for (k, (b, &offset)) in o.barriers.iter().zip(&o.offsets).enumerate() {
                    match &o.motion {
                        Some(motion) => {
                            // The controller's barrier is widened by the margin on the actor's
                            // predicted position (`actor_knowledge.margin`).
                            let mut barrier = b.clone();
                            if let Some(radius) = barrier.radius_mut() {
                                *radius += self.actor_margin;
                            }
                            if let crate::barrier::Shape::Headway { rear, .. } = &mut barrier.shape {
                                *rear += self.actor_margin;
                            }
                            self.control.add_moving_barrier(barrier, motion.clone(), offset, k == 0);
                        }
                        None => self.control.add_barrier(b.clone()),
                    }
                }
                revealed.push(i);
            }
        }
        revealed
    }

    /// The moving obstacles at `time`: triggers fired by the vehicle's position in `x` (an
    /// `actor_triggered` event; the controller's copy follows), each barrier's centre and the
    /// plant's obstacle (`Plant::move_obstacle`) moved to the actor's true position, and their
    /// true states as an `/actors` record.
    fn move_actors(&mut self, sinks: &mut [&mut dyn Sink], time: f64, x: &DVector<f64>) -> Result<(), LogError> {
        let Some(record) = &mut self.records.actors else {
            return Ok(());
        };
        let Record::Actors(m) = record else {
            unreachable!("records.actors holds an actors record")
        };
        let position = self.control.model().planar_position();
        m.time = time;
        let mut entries = m.actors.iter_mut();
        let mut first = 0;
        for (index, o) in self.obstacles.iter_mut().enumerate() {
            let pairs = first..first + o.barriers.len();
            first = pairs.end;
            let Some(motion) = &mut o.motion else {
                continue;
            };
            if let Some([i, j]) = position {
                if motion.check_trigger(time, [x[i], x[j]]) {
                    self.control.actor_triggered(&o.name, time);
                    let message = format!(
                        "{} starts its motion profile (the vehicle came within its trigger distance)",
                        o.name
                    );
                    let event = Self::event(time, "actor_triggered", message, vec![o.name.clone()], 0.0);
                    for sink in sinks.iter_mut() {
                        sink.record(&event)?;
                    }
                }
            }
            let state = motion.where_at(time, index);
            o.state = state;
            self.plant.move_obstacle(index, state.position, state.turn);
            // Drawn where it was last (or will be first) seen while it does not exist.
            let was_absent = std::mem::replace(&mut o.absent, !motion.exists_at(time));
            if time > 0.0 && was_absent != o.absent {
                let (kind, what) = match o.absent {
                    false => ("road_user_entered", "enters: its first recorded state"),
                    true => ("road_user_left", "has left: past its last recorded state"),
                };
                let event = Self::event(time, kind, format!("{} {what}", o.name), vec![o.name.clone()], 0.0);
                for sink in sinks.iter_mut() {
                    sink.record(&event)?;
                }
            }
            o.centre = match o.absent {
                true => motion.state_at(time).position,
                false => state.position,
            };
            let copies = &mut self.obstacle_barriers[pairs];
            for ((b, copy), offset) in o.barriers.iter_mut().zip(copies).zip(&o.offsets) {
                let at = state.shifted(*offset).position;
                for b in [&mut *b, copy] {
                    b.move_actor(at);
                }
            }
            if let Some(entry) = entries.next() {
                // An actor that does not exist now: where it was last (or will be first) seen.
                let absent = o.absent;
                let seen = if absent { motion.state_at(time) } else { state };
                (entry.x, entry.y) = (seen.position[0], seen.position[1]);
                (entry.vx, entry.vy) = (state.velocity[0], state.velocity[1]);
                (entry.ax, entry.ay) = (state.acceleration[0], state.acceleration[1]);
                entry.heading = seen.heading;
                entry.absent = absent;
            }
        }
        for sink in sinks.iter_mut() {
            sink.record(record)?;
        }
        Ok(())
    }

    /// The step loop. Returns the steps taken and the in-run error that stopped it, if any.
    fn run_steps(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<Ended, EpisodeError> {
        PROGRESS.store(0, std::sync::atomic::Ordering::Relaxed);
        loop {
            if let Some(end) = self.advance(sinks)? {
                return Ok(end);
            }
        }
    }

    /// Takes the loop's next step k — x(t_k) logged, the plant stepped to t_{k+1} (with the
    /// control tick when t_k is on the tick grid), what happened during the step logged — or,
    /// after the last step, logs the episode's end. Returns how the episode ended once it has
    /// (then again at every call, doing nothing). [`Episode::run`] is this in a loop; stepping
    /// it from outside (the Python `Env`) runs the same loop, the sinks finished by the caller.
    pub fn advance(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<Option<Ended>, EpisodeError> {
        if let Some(end) = &self.cursor.end {
            return Ok(Some(end.clone()));
        }
        let k = self.cursor.step;
        let mut x = std::mem::replace(&mut self.cursor.x, DVector::zeros(0));
        let mut applied = std::mem::replace(&mut self.cursor.applied, DVector::zeros(0));
        let result = self.step_at(sinks, k, &mut x, &mut applied);
        (self.cursor.x, self.cursor.applied) = (x, applied);
        let end = match result {
            Ok(end) => end,
            Err(e) => {
                // A sink failed: the episode cannot go on.
                self.cursor.end = Some((k, Some(StopReason::Error(e.to_string()))));
                return Err(e);
            }
        };
        // The next step, or where the episode ended.
        if end.is_none() {
            self.cursor.step = k + 1;
        }
        self.cursor.end.clone_from(&end);
        Ok(end)
    }

    /// Ends the episode before its last step, at its current step k, as its caller decided (a
    /// learning environment's episode that terminated): x(t_k) is logged, open contacts are
    /// closed and an `episode_end` event says where it stopped. The log is complete up to there.
    pub fn end_here(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<Ended, EpisodeError> {
        if self.cursor.end.is_none() {
            self.cursor.planned = Some(self.steps);
            self.steps = self.cursor.step;
        }
        loop {
            if let Some(end) = self.advance(sinks)? {
                return Ok(end);
            }
        }
    }

    /// The next step k of the loop ([`Episode::advance`]), or the step it ended at; t_k = k h.
    pub fn step_index(&self) -> u64 {
        self.cursor.step
    }

    /// Sets the input of a nominal commanded from outside (`nominal.kind = "external"`), used
    /// from the next control tick on; an error names what was expected.
    pub fn set_external_input(&mut self, input: &[f64]) -> Result<(), String> {
        // The channel names only for an error: a learning loop sets the input at every tick.
        let channels = |model: &dyn crate::dynamics::Dynamics| model.channel_names().join(", ");
        let expected = self.control.model().input_dim();
        if input.len() != expected {
            let names = channels(self.control.model().as_ref());
            return Err(format!("expected {expected} values ({names}), found {}", input.len()));
        }
        if let Some(v) = input.iter().find(|v| !v.is_finite()) {
            let names = channels(self.control.model().as_ref());
            return Err(format!("expected finite numbers ({names}), found {v}"));
        }
        let Some(held) = self.control.nominal_mut().external_input_mut() else {
            return Err("the scenario's nominal is not `external`: its nominal computes its own input".into());
        };
        held.copy_from_slice(input);
        Ok(())
    }

    /// The controller's delay queues (delays, commands issued), one per channel.
    pub fn queues(&self) -> &[crate::delay::DelayQueue] {
        self.control.queues()
    }

    /// Every barrier at the plant's current state x(t_k) (the obstacles' pairs first, as in the
    /// `/barrier` record; a moving obstacle where its motion puts it at t_k): what a caller
    /// stepping the episode observes between steps.
    pub fn barriers_now(&self) -> Vec<BarrierNow> {
        let time = self.cursor.step as f64 * self.control.timestep();
        let x = self.plant.state();
        let mut out = Vec::new();
        for (index, o) in self.obstacles.iter().enumerate() {
            let state = o.motion.as_ref().map(|m| m.where_at(time, index));
            for (b, offset) in o.barriers.iter().zip(&o.offsets) {
                let mut b = b.clone();
                if let Some(state) = state {
                    b.move_actor(state.shifted(*offset).position);
                }
                out.push(BarrierNow::of(&b, &x, o.known, true));
            }
        }
        out.extend(self.barriers.iter().map(|b| BarrierNow::of(b, &x, true, false)));
        out
    }

    /// The names of the state's components, in order.
    pub fn state_names(&self) -> &[String] {
        self.control.model().state_names()
    }

    /// The input channels, in order.
    pub fn channel_names(&self) -> &[String] {
        self.control.model().channel_names()
    }

    /// Control ticks happen every this many steps.
    pub fn steps_per_tick(&self) -> u64 {
        self.control.steps_per_tick()
    }

    /// The plant step h (s).
    pub fn timestep(&self) -> f64 {
        self.control.timestep()
    }

    /// Step k of the loop: returns how the episode ended if it did at this step.
    fn step_at(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        k: u64,
        x: &mut DVector<f64>,
        applied: &mut DVector<f64>,
    ) -> Result<Option<Ended>, EpisodeError> {
        let h = self.control.timestep();
        let time = k as f64 * h;
        PROGRESS.store(k, std::sync::atomic::Ordering::Relaxed);
        self.plant.state_into(x);
        self.move_actors(sinks, time, x)?;
        for i in self.reveal_obstacles(time) {
            let o = &self.obstacles[i];
            let message = format!("{} becomes known to the controller", o.name);
            Self::emit(
                sinks,
                Self::event(time, "obstacle_appeared", message, vec![o.name.clone()], 0.0),
            )?;
            Self::emit(sinks, obstacle_scene(time, o))?;
        }

        self.emit_scene(sinks, k, time, x)?;
        if let Record::State(m) = &mut self.records.state {
            (m.time, m.step) = (time, k);
            m.values.clear();
            m.values.extend_from_slice(x.as_slice());
        }
        Self::emit_ref(sinks, &self.records.state)?;
        self.check_stall(sinks, time)?;
        // Checked after the state is logged, so even a run stopped before its first step
        // leaves a log with its initial state.
        if stop_requested() {
            self.close_contacts(sinks, time)?;
            Self::emit(sinks, Self::event(time, "interrupted", INTERRUPTED.into(), vec![], 0.0))?;
            return Ok(Some((k, Some(StopReason::Interrupted))));
        }
        if x.iter().any(|v| !v.is_finite()) {
            return self.stop_with_error(
                sinks,
                time,
                k,
                format!("non-finite state {:?} at t = {time}", x.as_slice()),
            );
        }
        let mut done = std::mem::take(&mut self.realized);
        match self.control.realize_into(time, x, k == self.steps, &mut done) {
            Ok(()) => {
                for c in done.drain(..) {
                    // A target inside the step (off the grid: a time-varying delay) is
                    // logged after the step's records of t_k, so the log stays in
                    // log-time order (a reader streams it instead of sorting it).
                    if c.prediction.target_time > time + TICK_TOLERANCE * h {
                        self.inside_step.push(c);
                        continue;
                    }
                    Self::emit_ref(sinks, self.records.set_prediction(&c, &self.control, &self.obstacles))?;
                    self.control.recycle(c);
                }
                self.realized = done;
            }
            Err(e) => return self.stop_with_error(sinks, time, k, e.to_string()),
        }
        if k == self.steps {
            return self.end_of_episode(sinks).map(Some);
        }

        if let Err(e) = self.plant.step(&mut self.control) {
            return self.stop_with_error(sinks, time, k, e.to_string());
        }
        if let Some(e) = self.control.take_error() {
            return self.stop_with_error(sinks, time, k, e.to_string());
        }
        while let Some(w) = self.plant.take_warning() {
            Self::emit(
                sinks,
                Self::event(
                    time,
                    crate::log::MUJOCO_WARNING,
                    w.message,
                    vec![w.name.to_string()],
                    0.0,
                ),
            )?;
        }
        if let Some(actuation) = &mut self.actuation {
            actuation.push(self.plant.actuation());
        }

        // What happened during step k: tick, applied input, barriers, contacts.
        let sensor = self.control.has_sensor();
        if let Some((tick, barriers)) = self.control.take_tick() {
            Self::emit_tick(sinks, tick, barriers, k, sensor, &mut self.records)?;
            if let Record::Filter(m) = &self.records.filter {
                self.stall.0.observe(Observed::Filter(m), &self.stall.1);
            }
        }
        let applied_now = self.control.applied();
        debug_assert_eq!(applied_now.len(), applied.len(), "one applied input per channel");
        for (a, &(value, _)) in applied.iter_mut().zip(applied_now) {
            *a = value;
        }
        if let Record::Applied(m) = &mut self.records.applied {
            m.time = time;
            m.values.clear();
            m.values.extend_from_slice(applied.as_slice());
            m.issued_at.clear();
            m.issued_at.extend(applied_now.iter().map(|a| a.1));
        }
        Self::emit_ref(sinks, &self.records.applied)?;
        // With actuator dynamics the plant received the actuators' output, not the command.
        if let Some(actuated) = self.control.actuated() {
            applied.copy_from_slice(actuated);
            if let Record::Actuated(m) = &mut self.records.actuated {
                m.time = time;
                m.values.clear();
                m.values.extend_from_slice(actuated);
                m.issued_at.clear();
                m.issued_at.extend(self.control.applied().iter().map(|a| a.1));
            }
            Self::emit_ref(sinks, &self.records.actuated)?;
        }
        self.emit_barriers(sinks, time, x, applied)?;
        self.check_contacts(sinks, time)?;
        let mut inside_step = std::mem::take(&mut self.inside_step);
        for c in inside_step.drain(..) {
            Self::emit_ref(sinks, self.records.set_prediction(&c, &self.control, &self.obstacles))?;
            self.control.recycle(c);
        }
        self.inside_step = inside_step;
        Ok(None)
    }

    /// The end of the last step: open contacts closed, an `episode_end` event.
    fn end_of_episode(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<Ended, EpisodeError> {
        let end = self.steps as f64 * self.control.timestep();
        self.close_contacts(sinks, end)?;
        let message = match self.cursor.planned {
            Some(planned) => format!("stopped by its caller after {} of {planned} steps", self.steps),
            None => format!("completed {} steps", self.steps),
        };
        Self::emit(sinks, Self::event(end, "episode_end", message, vec![], 0.0))?;
        Ok((self.steps, None))
    }

    /// A `stall` event when the state just logged completes the run's first stall
    /// ([`StallDetector`], the `stall_time` metric's definition): logged at `time`, the moment
    /// the definition is met (STALL_DURATION after the stall's start, which the message names:
    /// the log stays in log-time order).
    fn check_stall(&mut self, sinks: &mut [&mut dyn Sink], time: f64) -> Result<(), LogError> {
        let Record::State(m) = &self.records.state else {
            return Ok(());
        };
        let Some(since) = self.stall.0.observe(Observed::State(m), &self.stall.1) else {
            return Ok(());
        };
        let message = format!(
            "the vehicle has moved slower than {STALL_SPEED} m/s since t = {since} s while the filter overrides the nominal input (stall_time = {since})"
        );
        Self::emit(
            sinks,
            Self::event(time, STALL_EVENT, message, vec!["vehicle".into()], 0.0),
        )
    }

    /// Collision start/end events from the plant's penetrations of the obstacles (an
    /// obstacle's: its pairs' deepest; a collision is any pair with negative clearance).
    fn check_contacts(&mut self, sinks: &mut [&mut dyn Sink], time: f64) -> Result<(), LogError> {
        if self.obstacles.is_empty() {
            return Ok(());
        }
        self.plant.penetrations(&self.obstacle_barriers, &mut self.depths);
        let mut pairs = self.depths.iter();
        for o in self.obstacles.iter_mut() {
            let depth = (pairs.by_ref().take(o.barriers.len()).flatten())
                .fold(None, |deepest: Option<f64>, &d| Some(deepest.map_or(d, |m| m.max(d))));
            let touching = depth.is_some();
            if let Some(d) = depth {
                o.contact_depth = o.contact_depth.max(d);
            }
            if touching == o.in_contact {
                continue;
            }
            o.in_contact = touching;
            let participants = vec!["vehicle".to_string(), o.name.clone()];
            // collision_start carries the depth at first contact, collision_end the deepest
            // penetration of the whole contact.
            let record = if touching {
                Self::event(
                    time,
                    "collision_start",
                    format!("vehicle hull touches {}", o.name),
                    participants,
                    o.contact_depth,
                )
            } else {
                let deepest = std::mem::take(&mut o.contact_depth);
                let message = format!("vehicle hull clear of {} (deepest penetration {deepest:.4} m)", o.name);
                Self::event(time, "collision_end", message, participants, deepest)
            };
            Self::emit(sinks, record)?;
        }
        Ok(())
    }

    /// A `collision_end` for every contact still going on when the episode stops (its end,
    /// an interruption, an error): it carries the deepest penetration so far, so a run that
    /// ends in contact does not report only the depth at first contact.
    fn close_contacts(&mut self, sinks: &mut [&mut dyn Sink], time: f64) -> Result<(), LogError> {
        for o in self.obstacles.iter_mut().filter(|o| o.in_contact) {
            o.in_contact = false;
            let deepest = std::mem::take(&mut o.contact_depth);
            let message = format!(
                "the episode ended with the vehicle hull still touching {} (deepest penetration {deepest:.4} m)",
                o.name
            );
            let participants = vec!["vehicle".to_string(), o.name.clone()];
            Self::emit(
                sinks,
                Self::event(time, "collision_end", message, participants, deepest),
            )?;
        }
        Ok(())
    }

    fn stop_with_error(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        time: f64,
        steps: u64,
        message: String,
    ) -> Result<Option<Ended>, EpisodeError> {
        self.close_contacts(sinks, time)?;
        Self::emit(sinks, Self::event(time, "error", message.clone(), vec![], 0.0))?;
        Ok(Some((steps, Some(StopReason::Error(message)))))
    }
}

/// Default of the most steps one episode may take: 10⁸ (55 hours of simulated time at
/// h = 2 ms; docs/hardening.md has the log size per step). `--max-steps` raises or lowers it.
pub const DEFAULT_MAX_STEPS: u64 = 100_000_000;
static MAX_STEPS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(DEFAULT_MAX_STEPS);

/// Sets the step budget of every episode built from now on (at least 1).
pub fn set_max_steps(steps: u64) {
    MAX_STEPS.store(steps.max(1), std::sync::atomic::Ordering::SeqCst);
}

/// The step budget of an episode (see [`set_max_steps`]).
pub fn max_steps() -> u64 {
    MAX_STEPS.load(std::sync::atomic::Ordering::SeqCst)
}

/// Refuses an episode whose duration, or whose longest constant delay or control period, is
/// more steps than the budget, before anything is sampled or allocated per step.
fn check_step_budget(loaded: &LoadedScenario, timestep: f64) -> Result<(), ScenarioError> {
    let sc = &loaded.scenario;
    let budget = max_steps();
    let steps = |seconds: f64| seconds / timestep;
    let too_many = |seconds: f64| steps(seconds).is_nan() || steps(seconds) > budget as f64;
    if !(timestep.is_finite() && timestep > 0.0) {
        // The scenario's own timestep is checked on load: this one is the model's.
        let (key, what) = match sc.vehicle.timestep {
            Some(_) => ("vehicle.timestep", "the timestep"),
            None => ("vehicle.model", "the model's <option timestep>"),
        };
        return Err(loaded.field_error(
            key,
            format!("{what} must be a positive number of seconds, found {timestep:e}"),
        ));
    }
    if sc.duration / timestep < 1.0 - TICK_TOLERANCE {
        return Err(loaded.field_error(
            "duration",
            format!(
                "{} s is less than one step of {timestep} s: expected at least one step",
                sc.duration
            ),
        ));
    }
    if too_many(sc.duration) {
        return Err(loaded.field_error(
            "duration",
            format!(
                "{} s at a timestep of {} s is {} steps, more than the limit of {budget} steps (raise it with --max-steps)",
                sc.duration,
                timestep,
                steps(sc.duration).ceil()
            ),
        ));
    }
    let periods = [
        ("period", sc.control.period),
        ("predictor_step", sc.control.predictor_step),
    ]
    .map(|(name, seconds)| (("control", name), seconds));
    let delays = (sc.delays.iter()).map(|(channel, profile)| (("delays", channel.as_str()), profile.constant_delay()));
    let too_long = (periods.into_iter().chain(delays))
        .filter_map(|(key, seconds)| Some((key, seconds?)))
        .find(|&(_, seconds)| too_many(seconds));
    if let Some(((section, name), seconds)) = too_long {
        return Err(loaded.field_error(
            &format!("{section}.{name}"),
            format!(
                "{seconds} s is {} steps of {timestep} s, more than the limit of {budget} steps (raise it with --max-steps)",
                steps(seconds).ceil(),
            ),
        ));
    }
    Ok(())
}

/// Phases in which a stop request is honoured by the code itself (episodes stepping, a sweep
/// executing), counted: outside them a signal handler ends the process at once.
static GRACEFUL: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// While a value lives, [`graceful_stop_active`] is true.
pub struct GracefulStop(());

impl GracefulStop {
    pub fn begin() -> GracefulStop {
        GRACEFUL.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        GracefulStop(())
    }
}

impl Drop for GracefulStop {
    fn drop(&mut self) {
        GRACEFUL.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

/// Whether some code of this process is polling [`stop_requested`] now.
pub fn graceful_stop_active() -> bool {
    GRACEFUL.load(std::sync::atomic::Ordering::SeqCst) > 0
}

/// Set by a signal handler: every running episode stops at its next step, logs an
/// `interrupted` event and finishes its log as incomplete.
static STOP_REQUESTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Asks every running episode to stop (Ctrl-C, SIGTERM).
pub fn request_stop() {
    STOP_REQUESTED.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Withdraws a stop request once every run it stopped has returned: for a process that goes on
/// after a stop (the Python package, whose user interrupted one call with Ctrl-C).
pub fn clear_stop_request() {
    STOP_REQUESTED.store(false, std::sync::atomic::Ordering::SeqCst);
}

/// Whether a stop was requested.
pub fn stop_requested() -> bool {
    STOP_REQUESTED.load(std::sync::atomic::Ordering::SeqCst)
}

/// The step the episode stepping last reached (what `mjsafe run` shows as its progress).
static PROGRESS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// The step the episode stepping last (in this process) has reached.
pub fn progress() -> u64 {
    PROGRESS.load(std::sync::atomic::Ordering::Relaxed)
}

/// The message of an episode stopped by [`request_stop`].
pub const INTERRUPTED: &str = "interrupted by a signal";

/// Default log path: `logs/<scenario name>-<UTC timestamp>.mcap`, never overwriting a file.
pub fn default_log_path(dir: &std::path::Path, name: &str) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let stamp = utc_stamp(secs);
    let mut path = dir.join(format!("{name}-{stamp}.mcap"));
    let mut n = 2;
    while path.exists() {
        path = dir.join(format!("{name}-{stamp}-{n}.mcap"));
        n += 1;
    }
    path
}

/// `YYYYmmddTHHMMSS` for seconds since the Unix epoch (UTC).
fn utc_stamp(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod conformance;

#[cfg(test)]
mod tests {
    #[test]
    fn utc_stamp_matches_known_dates() {
        assert_eq!(super::utc_stamp(0), "19700101T000000");
        assert_eq!(super::utc_stamp(1_700_000_000), "20231114T221320");
        assert_eq!(super::utc_stamp(951_782_400), "20000229T000000");
    }
}
