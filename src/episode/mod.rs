//! The episode loop: builds the plant (MuJoCo or the analytic ODE) and the controller for a
//! scenario, steps the plant, and reports every step to the log sinks. See
//! docs/ARCHITECTURE.md for the data flow of one control tick.

mod control;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{DMatrix, DVector};

use crate::barrier::{self, Barrier};
use crate::delay::{DelayProfile, DelayQueue};
use crate::filter;
use crate::filter::linear_delays;
use crate::filter::prescribed_time::{
    BlowUp, ContinuityRamp, EsfFilter, PrescribedTimeError, PtsNominal, PtsfFilter, RedLightNominal,
};
use crate::log::{proto, scene, LogError, Record, RunInfo, Sink};
use crate::mujoco::{self, MjError, Model, ObjKind, Simulation};
use crate::nominal::{BicyclePathLqr, Nominal};
use crate::plant::{MujocoPlant, OdePlant, Plant, PlantKind};
use crate::random::{self, Stream};
use crate::scenario::{
    ClfCbfQpSpec, Compensation, ConstantSpec, DisturbanceSpec, FilterSpec, LoadedScenario, NominalSpec, PathLqrSpec,
    ScenarioError,
};
use crate::vehicle::{self, Dynamics, LinearModel, VehicleKind};

pub use control::{ChainFilter, ChainTransform, Consistency, ControlLoop, FilterRule, Tick, TICK_TOLERANCE};

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

/// An obstacle of the episode: its barrier, whether the controller knows it, contact state.
#[derive(Debug, Clone)]
struct Obstacle {
    barrier: Barrier,
    /// The obstacle's own radius (the barrier's r also includes the hull).
    radius: f64,
    appear_at: f64,
    known: bool,
    in_contact: bool,
    /// Deepest penetration of the current contact episode.
    contact_depth: f64,
}

/// Result of a finished (or stopped) episode.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeSummary {
    pub steps: u64,
    pub simulated_time: f64,
    pub wall_seconds: f64,
    /// The error that stopped the episode early, if any.
    pub error: Option<String>,
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
    /// The obstacles' barriers, for the plant's contact check.
    obstacle_barriers: Vec<Barrier>,
    /// Per-step scratch: penetration depth per obstacle, ẋ for the logged velocity.
    depths: Vec<Option<f64>>,
    xdot: Vec<f64>,
    /// Per-step and per-tick records, updated in place (their names keep their storage).
    records: RecordBuffers,
}

/// The records written at every step or tick, kept between steps so logging allocates
/// nothing per step: each is always the variant its field names.
struct RecordBuffers {
    state: Record,
    applied: Record,
    barrier: Record,
    issued: Record,
    filter: Record,
}

impl RecordBuffers {
    fn new(state_names: &[String], channels: &[String]) -> RecordBuffers {
        RecordBuffers {
            state: Record::State(proto::State {
                names: state_names.to_vec(),
                ..Default::default()
            }),
            applied: Record::Applied(proto::AppliedCommand {
                channels: channels.to_vec(),
                ..Default::default()
            }),
            barrier: Record::Barrier(proto::Barrier::default()),
            issued: Record::Issued(proto::IssuedCommand {
                channels: channels.to_vec(),
                ..Default::default()
            }),
            filter: Record::Filter(proto::Filter {
                channels: channels.to_vec(),
                ..Default::default()
            }),
        }
    }
}

/// What the Foxglove 3D view needs beyond the state.
struct SceneState {
    hull_radius: f64,
    /// A straight reference path (point, heading, distance the reference speed covers in the
    /// episode), drawn as a line over the stretch the vehicle can drive (so that viewers
    /// fitting their view to the scene show the episode, not a 400 m line).
    path: Option<([f64; 2], f64, f64)>,
    /// Positions at every fifth control tick since the last published trail segment (which
    /// starts with the previous segment's last point, so the segments join up).
    trail: Vec<[f64; 2]>,
    /// Trail segments published so far (entities `trail/0`, `trail/1`, …: each is
    /// published once and persists, so the log and the memory grow linearly, not
    /// quadratically, with the episode's length).
    trail_segments: u64,
}

/// Control ticks between trail points, and trail intervals per published trail segment.
const TRAIL_EVERY_TICKS: u64 = 5;
const TRAIL_PUBLISH_EVERY_POINTS: usize = 10;

/// MJCF of the model with each obstacle added as a static sphere geom `obstacle_<i>`
/// (contype 0, conaffinity 1: it collides with the vehicle hull and nothing else).
fn model_with_obstacles(xml: &str, loaded: &LoadedScenario) -> Result<String, ScenarioError> {
    let obstacles = &loaded.scenario.obstacles;
    if obstacles.is_empty() {
        return Ok(xml.to_string());
    }
    let Some(at) = xml.rfind("</worldbody>") else {
        return Err(loaded.field_error("vehicle.model", "the MJCF has no <worldbody> to place obstacles in"));
    };
    let mut geoms = String::new();
    for (i, o) in obstacles.iter().enumerate() {
        geoms.push_str(&format!(
            "    <geom name=\"{}\" type=\"sphere\" pos=\"{} {} 0\" size=\"{}\" contype=\"0\" conaffinity=\"1\" rgba=\"0.9 0.2 0.2 0.6\"/>\n",
            obstacle_geom_name(i),
            o.centre[0],
            o.centre[1],
            o.radius
        ));
    }
    Ok(format!("{}{}{}", &xml[..at], geoms, &xml[at..]))
}

fn obstacle_geom_name(index: usize) -> String {
    format!("obstacle_{index}")
}

/// The plant's pieces before it is built: model (MuJoCo kinds), analytic dynamics, hull.
struct PlantParts {
    model: Option<Model>,
    vehicle: Option<Box<dyn vehicle::MujocoVehicle>>,
    dynamics: Arc<dyn Dynamics>,
    hull_radius: f64,
    timestep: f64,
}

fn load_plant_parts(loaded: &LoadedScenario) -> Result<PlantParts, EpisodeError> {
    let sc = &loaded.scenario;
    let file = loaded.path.display().to_string();
    if let Some(model_path) = loaded.model_path() {
        let xml = crate::files::read_text_limited(&model_path, "MJCF model", crate::files::MODEL_LIMIT)
            .map_err(|e| loaded.field_error("vehicle.model", e.to_string()))?;
        let xml = model_with_obstacles(&xml, loaded)?;
        let mut model =
            Model::from_xml_string(&xml, &model_path.display().to_string()).map_err(|source| EpisodeError::Model {
                file: file.clone(),
                reason: source,
            })?;
        if let Some(h) = sc.vehicle.timestep {
            model.set_timestep(h);
        }
        if let Some(integrator) = sc.vehicle.integrator {
            model.set_integrator(integrator);
        }
        let bound = vehicle::bind(sc.vehicle.kind, &model).map_err(|reason| EpisodeError::Model { file, reason })?;
        return Ok(PlantParts {
            dynamics: bound.dynamics(),
            hull_radius: bound.hull_radius(),
            timestep: model.timestep(),
            model: Some(model),
            vehicle: Some(bound),
        });
    }
    // Validation guarantees a timestep, and A and B for kind linear.
    let dynamics: Arc<dyn Dynamics> = match sc.vehicle.kind {
        VehicleKind::NonlinearExample1 => Arc::new(vehicle::NonlinearExample1::default()),
        VehicleKind::StrictFeedback => Arc::new(vehicle::StrictFeedbackModel::default()),
        _ => {
            let (a, b) = (
                sc.vehicle.a.as_ref().expect("validated"),
                sc.vehicle.b.as_ref().expect("validated"),
            );
            Arc::new(LinearModel::new(matrix_from_rows(a), matrix_from_rows(b)))
        }
    };
    Ok(PlantParts {
        model: None,
        vehicle: None,
        dynamics,
        hull_radius: 0.0,
        timestep: sc.vehicle.timestep.expect("validated"),
    })
}

impl Episode {
    /// Loads the model, builds plant and controller, and checks everything that depends on
    /// the model (state size, channel names, delays against the timestep and Assumptions 1–2).
    pub fn new(loaded: &LoadedScenario) -> Result<Episode, EpisodeError> {
        mujoco::check_version()?;
        let sc = &loaded.scenario;
        let parts = load_plant_parts(loaded)?;
        let model = parts.dynamics.clone();
        let timestep = parts.timestep;

        check_step_budget(loaded, timestep)?;
        let n = model.state_dim();
        if sc.vehicle.initial_state.len() != n {
            return Err(loaded
                .field_error(
                    "vehicle.initial_state",
                    format!(
                        "expected {n} values ({}), found {}",
                        model.state_names().join(", "),
                        sc.vehicle.initial_state.len()
                    ),
                )
                .into());
        }
        let channels: Vec<String> = model.channel_names().to_vec();
        for (section, keys) in [
            ("delays", sc.delays.keys().collect::<Vec<_>>()),
            ("initial_input", sc.initial_input.keys().collect()),
        ] {
            for key in keys {
                if !channels.contains(key) {
                    return Err(loaded
                        .field_error(
                            &format!("{section}.{key}"),
                            format!("unknown input channel; this vehicle has: {}", channels.join(", ")),
                        )
                        .into());
                }
            }
        }

        let period = sc.control.period.unwrap_or(timestep);
        let ratio = period / timestep;
        if (ratio - ratio.round()).abs() > 1e-6 || ratio.round() < 1.0 {
            return Err(loaded
                .field_error(
                    "control.period",
                    format!("expected a whole multiple of the timestep {timestep} s, found {period}"),
                )
                .into());
        }
        let steps_per_tick = ratio.round() as u64;

        let mut queues = Vec::with_capacity(channels.len());
        for channel in &channels {
            let profile = sc.delays.get(channel).cloned().unwrap_or(DelayProfile::Constant(0.0));
            let key = format!("delays.{channel}");
            profile
                .check(channel, sc.duration, timestep, sc.control.history)
                .map_err(|e| loaded.field_error(&key, e.to_string()))?;
            let initial = sc.initial_input.get(channel).copied().unwrap_or(0.0);
            let queue = DelayQueue::with_profile(channel, profile, initial, timestep)
                .map_err(|e| loaded.field_error(&key, e.to_string()))?;
            queues.push(queue);
        }
        let structure = control::predictor_structure(&queues, period).map_err(|e| loaded.field_error("delays", e))?;

        let nominal = match &sc.nominal {
            NominalSpec::PathLqr(PathLqrSpec {
                reference_speed,
                path_point,
                path_heading,
                q,
                r,
            }) => {
                if sc.vehicle.kind != VehicleKind::Bicycle {
                    return Err(loaded
                        .field_error("nominal.kind", "path_lqr needs vehicle.kind = \"bicycle\"")
                        .into());
                }
                let wheelbase = model.input_matrix(&DVector::from_element(n, 1.0))[(2, 0)].recip();
                let lqr = BicyclePathLqr::new(*path_point, *path_heading, *reference_speed, wheelbase, *q, *r)
                    .map_err(|e| loaded.field_error("nominal", e.to_string()))?;
                Nominal::PathLqr(lqr)
            }
            NominalSpec::Constant(ConstantSpec { input }) => {
                if input.len() != channels.len() {
                    return Err(loaded
                        .field_error(
                            "nominal.input",
                            format!("expected {} values ({})", channels.len(), channels.join(", ")),
                        )
                        .into());
                }
                Nominal::Constant(DVector::from_column_slice(input))
            }
            NominalSpec::UnicycleStabilizer => Nominal::UnicycleStabilizer,
            NominalSpec::QuarticClf => {
                if n != 2 {
                    return Err(loaded
                        .field_error("nominal.kind", "quartic_clf (4.57)/(4.58) needs a two-state system")
                        .into());
                }
                Nominal::QuarticClf(model.clone())
            }
            NominalSpec::RedLight(spec) => {
                if sc.vehicle.kind != VehicleKind::DoubleIntegrator1d && n != 2 {
                    return Err(loaded
                        .field_error("nominal.kind", "red_light (5.20) needs a double integrator")
                        .into());
                }
                Nominal::RedLight(RedLightNominal {
                    position_gain: spec.k1,
                    velocity_gain: spec.k2,
                    amplitude: spec.a,
                    offset: spec.b,
                    frequency: spec.omega,
                })
            }
            NominalSpec::Pts(spec) => {
                if sc.vehicle.kind != VehicleKind::StrictFeedback {
                    return Err(loaded
                        .field_error("nominal.kind", "pts (5.87) needs vehicle.kind = \"strict_feedback\"")
                        .into());
                }
                let clip = spec.clip.ok_or_else(|| {
                    loaded.field_error(
                        "nominal.clip",
                        "the nominal (5.87) blows up at T: expected a clip of mu_2 (e.g. 1000)",
                    )
                })?;
                let blow_up = BlowUp::new(0.0, spec.horizon)
                    .and_then(|b| b.with_mu2_clip(clip))
                    .map_err(|e| loaded.field_error("nominal", e.to_string()))?;
                Nominal::Pts(PtsNominal {
                    natural_frequency: spec.omega,
                    damping_ratio: spec.zeta,
                    blow_up,
                })
            }
        };

        let rule = filter_rule(
            loaded,
            model.as_ref(),
            &queues,
            &DVector::from_column_slice(&sc.vehicle.initial_state),
        )?;
        let distinct_delay_filter = matches!(rule, FilterRule::FixedChannel { .. } | FilterRule::GammaM { .. });
        if distinct_delay_filter && sc.obstacles.len() + sc.barriers.len() > 1 {
            return Err(loaded
                .field_error(
                    "obstacles",
                    "the distinct-delay filters (4.44) and (4.67) take one barrier; for several, use kind = \"cbf_qp\" (solved as a QP)",
                )
                .into());
        }

        let mut x0 = DVector::from_column_slice(&sc.vehicle.initial_state);
        if let Some(bounds) = &sc.vehicle.initial_perturbation {
            for (i, bound) in bounds.iter().enumerate() {
                x0[i] += bound * random::symmetric_unit(sc.seed, Stream::InitialState, 0, i as u64);
            }
        }
        let mut barriers = Vec::with_capacity(sc.barriers.len());
        for (i, shape) in sc.barriers.iter().enumerate() {
            let b = Barrier {
                name: format!("barrier_{i}"),
                shape: shape.clone(),
            };
            if b.max_index() >= n {
                return Err(loaded
                    .field_error(
                        &format!("barriers[{i}]"),
                        format!("refers to state index {}, the state has {n} components", b.max_index()),
                    )
                    .into());
            }
            barriers.push(b);
        }
        let mut obstacles = Vec::with_capacity(sc.obstacles.len());
        for (i, o) in sc.obstacles.iter().enumerate() {
            let Some(position) = model.planar_position() else {
                return Err(loaded
                    .field_error("obstacles", "this vehicle does not move in a plane")
                    .into());
            };
            let name = o.name.clone().unwrap_or_else(|| obstacle_geom_name(i));
            let barrier = Barrier::circular_obstacle(&name, position, o.centre, parts.hull_radius + o.radius);
            if barrier.h(&x0) < 0.0 {
                return Err(loaded
                    .field_error(
                        &format!("obstacles[{i}]"),
                        format!(
                            "the obstacle overlaps the vehicle at the start (clearance {:.3} m)",
                            barrier.clearance(&x0)
                        ),
                    )
                    .into());
            }
            obstacles.push(Obstacle {
                barrier,
                radius: o.radius,
                appear_at: (o.appear_at
                    + o.appear_jitter * random::symmetric_unit(sc.seed, Stream::ObstacleAppearance, i as u64, 0))
                .max(0.0),
                known: false,
                in_contact: false,
                contact_depth: 0.0,
            });
        }

        let file = loaded.path.display().to_string();
        let plant: Box<dyn Plant> = match sc.plant {
            PlantKind::Mujoco => {
                let model = parts.model.expect("MuJoCo kinds have a model (validated)");
                let geoms = (0..obstacles.len())
                    .map(|i| model.require(ObjKind::Geom, &obstacle_geom_name(i)))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|source| EpisodeError::Model {
                        file: file.clone(),
                        reason: source,
                    })?;
                let sim = Simulation::new(model)?;
                Box::new(MujocoPlant::new(
                    sim,
                    parts.vehicle.expect("bound with the model"),
                    geoms,
                    &x0,
                ))
            }
            PlantKind::Ode => {
                let plant = OdePlant::new(model.clone(), x0.clone(), timestep);
                Box::new(match &sc.disturbance {
                    Some(DisturbanceSpec::Example349) => {
                        plant.with_disturbance(Box::new(linear_delays::disturbance_3_49))
                    }
                    Some(DisturbanceSpec::RandomState { bound, hold }) => {
                        let (seed, bound, hold) = (sc.seed, *bound, *hold);
                        plant.with_disturbance(Box::new(move |t| {
                            random_vector(seed, Stream::StateDisturbance, bound, hold, t, n)
                        }))
                    }
                    Some(DisturbanceSpec::RandomInput { .. }) | None => plant,
                })
            }
        };

        let mut control = ControlLoop::new(model, nominal, rule, queues, structure, timestep, steps_per_tick);
        if let Some(step) = sc.control.predictor_step {
            let steps = step / timestep;
            if !(steps >= 0.5 && (steps - steps.round()).abs() < 1e-6) {
                return Err(loaded
                    .field_error(
                        "control.predictor_step",
                        format!("expected a whole multiple of the timestep {timestep} s, got {step}"),
                    )
                    .into());
            }
            control
                .set_predictor_step(steps.round() as u32)
                .map_err(|e| loaded.field_error("control.predictor_step", e))?;
        }
        let tolerance = sc.control.chain_tolerance;
        if !(tolerance >= 0.0 && tolerance.is_finite()) {
            return Err(loaded
                .field_error(
                    "control.chain_tolerance",
                    format!("expected a finite distance >= 0, got {tolerance}"),
                )
                .into());
        }
        control.set_chain_tolerance(tolerance);
        if let Some(DisturbanceSpec::RandomInput { bound, hold }) = &sc.disturbance {
            let (seed, bound, hold) = (sc.seed, *bound, *hold);
            let r = channels.len();
            control.input_disturbance = Some(Box::new(move |t, channel| {
                random_component(seed, Stream::InputDisturbance, bound, hold, t, r, channel)
            }));
        }
        // Non-obstacle barriers are known from the start.
        for barrier in &barriers {
            control.add_barrier(barrier.clone());
        }

        let steps = (sc.duration / timestep - TICK_TOLERANCE).ceil() as u64;
        let info = RunInfo {
            scenario_name: sc.name.clone(),
            scenario_path: loaded.path.display().to_string(),
            scenario_text: loaded.source_text.clone(),
            scenario_resolved: loaded.resolved_toml(),
            overrides: loaded.overrides.clone(),
            mujoco_version: mujoco::version_string(),
            timestep,
            control_period: period,
            max_delay: control
                .queues
                .iter()
                .flat_map(|q| {
                    // Sampled over the run for a time-varying delay; a constant one is itself.
                    let samples = match q.constant_delay() {
                        Some(_) => 0,
                        None => (sc.duration / timestep).ceil() as usize,
                    };
                    (0..=samples).map(move |k| q.profile().delay((k as f64 * timestep).min(sc.duration)))
                })
                .fold(0.0, f64::max),
            prescribed_time: match &sc.filter {
                FilterSpec::Ptsf(spec) => Some(spec.horizon),
                FilterSpec::Esf(spec) => spec.horizon,
                _ => None,
            },
        };
        let path = match &sc.nominal {
            NominalSpec::PathLqr(p) => Some((p.path_point, p.path_heading, p.reference_speed.abs() * sc.duration)),
            _ => None,
        };
        let control_model = control.model.clone();
        Ok(Episode {
            plant,
            control,
            obstacle_barriers: obstacles.iter().map(|o| o.barrier.clone()).collect(),
            obstacles,
            barriers,
            steps,
            info,
            actuation: None,
            lie: barrier::LieWorkspace::new(control_model.as_ref()),
            constraint: barrier::Constraint::zeros(control_model.input_dim()),
            depths: Vec::new(),
            xdot: vec![0.0; control_model.state_dim()],
            records: RecordBuffers::new(control_model.state_names(), control_model.channel_names()),
            scene: SceneState {
                hull_radius: parts.hull_radius,
                path,
                trail: Vec::new(),
                trail_segments: 0,
            },
        })
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
        self.control.predictor_step
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
    pub fn replay_actuation(&mut self, actuation: &[Vec<f64>]) {
        for a in actuation {
            self.plant.step_with_actuation(a);
        }
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
            simulated_time: steps as f64 * self.control.timestep,
            wall_seconds: started.elapsed().as_secs_f64(),
            error,
        })
    }

    fn emit(sinks: &mut [&mut dyn Sink], record: Record) -> Result<(), LogError> {
        Self::emit_ref(sinks, &record)
    }

    fn emit_ref(sinks: &mut [&mut dyn Sink], record: &Record) -> Result<(), LogError> {
        for sink in sinks.iter_mut() {
            sink.record(record)?;
        }
        Ok(())
    }

    fn event(time: f64, kind: &str, message: String, participants: Vec<String>, depth: f64) -> Record {
        Record::Event(proto::Event {
            time,
            kind: kind.into(),
            message,
            participants,
            depth,
        })
    }

    /// Makes the obstacles that appear by `time` known to the controller; returns their indices.
    fn reveal_obstacles(&mut self, time: f64) -> Vec<usize> {
        let tolerance = TICK_TOLERANCE * self.control.timestep;
        let mut revealed = Vec::new();
        for (i, o) in self.obstacles.iter_mut().enumerate() {
            if !o.known && o.appear_at <= time + tolerance {
                o.known = true;
                self.control.add_barrier(o.barrier.clone());
                revealed.push(i);
            }
        }
        revealed
    }

    /// The step loop. Returns the steps taken and the in-run error that stopped it, if any.
    fn run_steps(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<(u64, Option<String>), EpisodeError> {
        let h = self.control.timestep;
        let channels = self.control.model.channel_names().to_vec();

        for k in 0..=self.steps {
            let time = k as f64 * h;
            for i in self.reveal_obstacles(time) {
                let o = &self.obstacles[i];
                let message = format!("{} becomes known to the controller", o.barrier.name);
                Self::emit(
                    sinks,
                    Self::event(time, "obstacle_appeared", message, vec![o.barrier.name.clone()], 0.0),
                )?;
                Self::emit(sinks, obstacle_scene(time, o))?;
            }

            let x = self.plant.state();
            self.emit_scene(sinks, k, time, &x)?;
            if let Record::State(m) = &mut self.records.state {
                (m.time, m.step) = (time, k);
                m.values.clear();
                m.values.extend(x.iter());
            }
            Self::emit_ref(sinks, &self.records.state)?;
            // Checked after the state is logged, so even a run stopped before its first step
            // leaves a log with its initial state.
            if stop_requested() {
                Self::emit(sinks, Self::event(time, "interrupted", INTERRUPTED.into(), vec![], 0.0))?;
                return Ok((k, Some(INTERRUPTED.into())));
            }
            if x.iter().any(|v| !v.is_finite()) {
                return self.stop_with_error(
                    sinks,
                    time,
                    k,
                    format!("non-finite state {:?} at t = {time}", x.as_slice()),
                );
            }
            match self.control.realize(time, &x) {
                Ok(done) => {
                    for c in done {
                        Self::emit(sinks, prediction_record(&c, &channels))?;
                        self.control.recycle(c);
                    }
                }
                Err(e) => return self.stop_with_error(sinks, time, k, e.to_string()),
            }
            if k == self.steps {
                break;
            }

            if let Err(e) = self.plant.step(&mut self.control) {
                return self.stop_with_error(sinks, time, k, e.to_string());
            }
            if let Some(e) = self.control.error.take() {
                return self.stop_with_error(sinks, time, k, e.to_string());
            }
            if let Some(actuation) = &mut self.actuation {
                actuation.push(self.plant.actuation());
            }

            // What happened during step k: tick, applied input, barriers, contacts.
            if let Some(tick) = self.control.take_tick() {
                Self::emit_tick(sinks, tick, &mut self.records)?;
            }
            let applied = DVector::from_iterator(channels.len(), self.control.applied.iter().map(|a| a.0));
            if let Record::Applied(m) = &mut self.records.applied {
                m.time = time;
                m.values.clear();
                m.values.extend(applied.iter());
                m.issued_at.clear();
                m.issued_at.extend(self.control.applied.iter().map(|a| a.1));
            }
            Self::emit_ref(sinks, &self.records.applied)?;
            self.emit_barriers(sinks, time, &x, &applied)?;
            self.check_contacts(sinks, time)?;
        }
        let end = self.steps as f64 * h;
        Self::emit(
            sinks,
            Self::event(
                end,
                "episode_end",
                format!("completed {} steps", self.steps),
                vec![],
                0.0,
            ),
        )?;
        Ok((self.steps, None))
    }

    /// Foxglove view: static entities at the start, then the vehicle and `/tf` at every
    /// control tick and the trail every few ticks (planar vehicles only).
    fn emit_scene(&mut self, sinks: &mut [&mut dyn Sink], k: u64, time: f64, x: &DVector<f64>) -> Result<(), LogError> {
        let model = self.control.model.clone();
        let Some([i, j]) = model.planar_position() else {
            return Ok(());
        };
        let position = [x[i], x[j]];
        if k == 0 {
            if let Some((point, heading, reach)) = self.scene.path {
                let (s, c) = heading.sin_cos();
                // From 10 m behind the start to 10 m beyond where the reference speed leads.
                let start = (position[0] - point[0]) * c + (position[1] - point[1]) * s;
                let (from, to) = (start - 10.0, start + reach + 10.0);
                let ends = [
                    [point[0] + from * c, point[1] + from * s],
                    [point[0] + to * c, point[1] + to * s],
                ];
                Self::emit(
                    sinks,
                    Record::Scene(time, scene::polyline(time, "reference_path", &ends, scene::PATH, 0.1)),
                )?;
            }
            for o in &self.obstacles {
                Self::emit(sinks, obstacle_scene(time, o))?;
            }
        }
        let tick = k / self.control.steps_per_tick;
        if !k.is_multiple_of(self.control.steps_per_tick) {
            return Ok(());
        }
        let heading = model.heading_index().map_or(0.0, |h| x[h]);
        Self::emit(
            sinks,
            Record::Scene(time, scene::vehicle(time, position, heading, self.scene.hull_radius)),
        )?;
        Self::emit(
            sinks,
            Record::Transform(time, scene::transform(time, position, heading)),
        )?;
        if tick.is_multiple_of(TRAIL_EVERY_TICKS) {
            self.scene.trail.push(position);
            let last_tick = k + self.control.steps_per_tick > self.steps;
            let points = self.scene.trail.len();
            if points > TRAIL_PUBLISH_EVERY_POINTS || (last_tick && points >= 2) {
                let id = format!("trail/{}", self.scene.trail_segments);
                let trail = scene::polyline(time, &id, &self.scene.trail, scene::TRAIL, 0.15);
                Self::emit(sinks, Record::Scene(time, trail))?;
                self.scene.trail_segments += 1;
                self.scene.trail.drain(..points - 1);
            }
        }
        Ok(())
    }

    fn emit_tick(sinks: &mut [&mut dyn Sink], tick: &Tick, records: &mut RecordBuffers) -> Result<(), LogError> {
        if let Record::Issued(m) = &mut records.issued {
            m.time = tick.time;
            m.nominal.clear();
            m.nominal.extend(tick.nominal.iter());
            m.filtered.clear();
            m.filtered.extend(tick.issued.iter());
        }
        Self::emit_ref(sinks, &records.issued)?;
        let solved = tick.outcomes.iter().flatten();
        if let Record::Filter(m) = &mut records.filter {
            m.time = tick.time;
            m.active = solved.clone().any(|o| o.active);
            m.infeasible = solved.clone().any(|o| o.infeasible);
            m.mu = solved.map(|o| o.mu).fold(f64::NAN, f64::min);
            m.correction.clear();
            m.correction
                .extend(tick.issued.iter().zip(&tick.nominal).map(|(u, u0)| u - u0));
        }
        Self::emit_ref(sinks, &records.filter)
    }

    /// Every barrier at x(t_k), with its constraint evaluated at the applied input (without a
    /// filter there is no barrier constraint: only h is meaningful).
    fn emit_barriers(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        time: f64,
        x: &DVector<f64>,
        applied: &DVector<f64>,
    ) -> Result<(), LogError> {
        let form = self.control.rule.form();
        let model = self.control.model.as_ref();
        let entries = self
            .obstacles
            .iter()
            .map(|o| (&o.barrier, o.known, true))
            .chain(self.barriers.iter().map(|b| (b, true, false)));
        // World velocity of the planar position (for time-to-collision): ṗ from the model.
        let velocity = model.planar_position().map(|[i, j]| {
            model.dynamics_into(x.as_slice(), applied.as_slice(), &mut self.xdot);
            [self.xdot[i], self.xdot[j]]
        });
        let Record::Barrier(record) = &mut self.records.barrier else {
            unreachable!("records.barrier holds a barrier record")
        };
        record.time = time;
        let count = self.obstacles.len() + self.barriers.len();
        if record.barriers.len() != count {
            record.barriers = entries
                .clone()
                .map(|(b, ..)| proto::BarrierValue {
                    name: b.name.clone(),
                    ..Default::default()
                })
                .collect();
        }
        let (lie, constraint_data) = (&mut self.lie, &mut self.constraint);
        for ((b, known, obstacle), value) in entries.zip(record.barriers.iter_mut()) {
            let (constraint, relative_degree) = form.map_or((f64::NAN, 0), |form| {
                lie.constraint_into(b, form, model, x.as_slice(), constraint_data);
                (constraint_data.value(applied), form.relative_degree())
            });
            let time_to_collision = match (obstacle, velocity, &b.shape) {
                (
                    true,
                    Some(v),
                    crate::barrier::Shape::Ball {
                        indices,
                        centre,
                        radius,
                        ..
                    },
                ) => time_to_contact([x[indices[0]] - centre[0], x[indices[1]] - centre[1]], v, *radius),
                _ => f64::NAN,
            };
            *value = proto::BarrierValue {
                name: std::mem::take(&mut value.name),
                h: b.h(x),
                constraint,
                known,
                relative_degree,
                clearance: b.clearance(x),
                time_to_collision,
                obstacle,
            };
        }
        if count == 0 {
            return Ok(());
        }
        Self::emit_ref(sinks, &self.records.barrier)
    }

    /// Collision start/end events from the plant's penetrations of the obstacles.
    fn check_contacts(&mut self, sinks: &mut [&mut dyn Sink], time: f64) -> Result<(), LogError> {
        if self.obstacles.is_empty() {
            return Ok(());
        }
        self.plant.penetrations(&self.obstacle_barriers, &mut self.depths);
        for (o, &depth) in self.obstacles.iter_mut().zip(&self.depths) {
            let touching = depth.is_some();
            if let Some(d) = depth {
                o.contact_depth = o.contact_depth.max(d);
            }
            if touching == o.in_contact {
                continue;
            }
            o.in_contact = touching;
            let participants = vec!["vehicle".to_string(), o.barrier.name.clone()];
            // collision_start carries the depth at first contact, collision_end the deepest
            // penetration of the whole contact.
            let record = if touching {
                Self::event(
                    time,
                    "collision_start",
                    format!("vehicle hull touches {}", o.barrier.name),
                    participants,
                    o.contact_depth,
                )
            } else {
                let deepest = std::mem::take(&mut o.contact_depth);
                let message = format!(
                    "vehicle hull clear of {} (deepest penetration {deepest:.4} m)",
                    o.barrier.name
                );
                Self::event(time, "collision_end", message, participants, deepest)
            };
            Self::emit(sinks, record)?;
        }
        Ok(())
    }

    fn stop_with_error(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        time: f64,
        steps: u64,
        message: String,
    ) -> Result<(u64, Option<String>), EpisodeError> {
        Self::emit(sinks, Self::event(time, "error", message.clone(), vec![], 0.0))?;
        Ok((steps, Some(message)))
    }
}

/// The filter rule of the scenario, with the checks that need the model and the queues:
/// distinct-delay filters need constant delays in non-decreasing channel order (D_1 ≤ … ≤ D_r),
/// and φ (4.41) declared (verified on `phi_box` if given) or found on `phi_box`.
fn filter_rule(
    loaded: &LoadedScenario,
    model: &dyn Dynamics,
    queues: &[DelayQueue],
    x0: &DVector<f64>,
) -> Result<FilterRule, EpisodeError> {
    let sc = &loaded.scenario;
    if let FilterSpec::Ptsf(_) | FilterSpec::Esf(_) = &sc.filter {
        return chain_rule(loaded, model, queues, x0);
    }
    let Some(form) = sc.filter.form() else {
        return Ok(FilterRule::None);
    };
    let ordered_delays = || -> Result<(), EpisodeError> {
        let mut previous: Option<(&str, f64)> = None;
        for q in queues {
            let Some(d) = q.constant_delay() else {
                return Err(loaded
                    .field_error(
                        &format!("delays.{}", q.channel()),
                        "the distinct-delay filters need constant delays",
                    )
                    .into());
            };
            if let Some((name, p)) = previous {
                if d < p {
                    return Err(loaded
                        .field_error(
                            &format!("delays.{}", q.channel()),
                            format!("the filter assumes D_1 <= ... <= D_r in channel order, but `{}` ({d} s) comes after `{name}` ({p} s)", q.channel()),
                        )
                        .into());
                }
            }
            previous = Some((q.channel(), d));
        }
        Ok(())
    };
    Ok(match &sc.filter {
        FilterSpec::None | FilterSpec::Ptsf(_) | FilterSpec::Esf(_) => FilterRule::None,
        FilterSpec::CbfQp(spec) => {
            let limits = match &spec.input_limits {
                Some(l) => {
                    let r = queues.len();
                    if l.lower.len() != r
                        || l.upper.len() != r
                        || l.lower
                            .iter()
                            .zip(&l.upper)
                            .any(|(lo, hi)| lo.is_nan() || hi.is_nan() || lo > hi)
                    {
                        return Err(loaded
                            .field_error(
                                "filter.input_limits",
                                format!("expected lower <= upper, {r} values each (one per channel)"),
                            )
                            .into());
                    }
                    Some((l.lower.clone(), l.upper.clone()))
                }
                None => None,
            };
            FilterRule::DelayFree {
                form,
                predicted: spec.compensation == Compensation::Predictor,
                limits,
            }
        }
        FilterSpec::ClfCbfQp(spec) => FilterRule::LinearClfCbf(Arc::new(linear_stabilizer(loaded, spec, queues)?)),
        FilterSpec::GammaM(spec) => {
            ordered_delays()?;
            FilterRule::GammaM {
                form,
                m: spec.m,
                gamma: spec.gamma.unwrap_or((spec.m + 1.0) / spec.m),
            }
        }
        FilterSpec::FixedChannel(spec) => {
            ordered_delays()?;
            let r = queues.len();
            let barrier = first_barrier(loaded, model)?;
            let phi = match (&spec.phi_box, spec.phi) {
                (Some(b), declared) => {
                    if b.lower.len() != model.state_dim() {
                        return Err(loaded
                            .field_error(
                                "filter.phi_box",
                                format!("expected {} bounds per side", model.state_dim()),
                            )
                            .into());
                    }
                    let b_at = |x: &DVector<f64>| barrier::constraint(&barrier, form, model, x).b;
                    let found = filter::minimal_channels(filter::box_grid(&b.lower, &b.upper, b.points), b_at);
                    match declared {
                        Some(phi) if phi < found => {
                            return Err(loaded
                                .field_error("filter.phi", format!("phi = {phi} is too small: on phi_box the first {phi} channels cannot act on the barrier everywhere (the box needs {found})"))
                                .into())
                        }
                        Some(phi) => phi,
                        None => found,
                    }
                }
                (None, Some(phi)) => phi,
                (None, None) => unreachable!("validated"),
            };
            if phi > r {
                return Err(loaded
                    .field_error("filter.phi", format!("expected at most {r} channels, found {phi}"))
                    .into());
            }
            FilterRule::FixedChannel { form, phi }
        }
    })
}

/// The Ch. 5 filters: one input channel without delay, a model that is a chain of integrators
/// of order n (or the strict-feedback system (5.82), mapped to one), gains from x(0).
fn chain_rule(
    loaded: &LoadedScenario,
    model: &dyn Dynamics,
    queues: &[DelayQueue],
    x0: &DVector<f64>,
) -> Result<FilterRule, EpisodeError> {
    let sc = &loaded.scenario;
    if queues.len() != 1 || queues[0].constant_delay() != Some(0.0) {
        return Err(loaded
            .field_error("filter.kind", "the Ch. 5 filters need one input channel without delay")
            .into());
    }
    let n = model.state_dim();
    let transform = if sc.vehicle.kind == VehicleKind::StrictFeedback {
        ChainTransform::StrictFeedback
    } else {
        // ẋ_i = x_{i+1}, ẋ_n = u: check f and G at a generic state.
        let probe = DVector::from_iterator(n, (0..n).map(|i| 0.37 * (i as f64 + 1.0)));
        let f = model.drift(&probe);
        let g = model.input_matrix(&probe);
        let is_chain = (0..n).all(|i| {
            let expected_f = if i + 1 < n { probe[i + 1] } else { 0.0 };
            let expected_g = if i + 1 == n { 1.0 } else { 0.0 };
            (f[i] - expected_f).abs() < 1e-12 && (g[(i, 0)] - expected_g).abs() < 1e-12
        });
        if !is_chain {
            return Err(loaded.field_error("vehicle", "the Ch. 5 filters need a chain of integrators (x_i' = x_{i+1}, x_n' = u) or kind = \"strict_feedback\"").into());
        }
        ChainTransform::Identity
    };
    let filter_error = |e: PrescribedTimeError| EpisodeError::from(loaded.field_error("filter", e.to_string()));
    let filter = match &sc.filter {
        FilterSpec::Ptsf(spec) => {
            if let Some(order) = spec.order {
                if order != n {
                    return Err(loaded
                        .field_error(
                            "filter.order",
                            format!("the model is a chain of order {n}, not {order}"),
                        )
                        .into());
                }
            }
            let mut blow_up = BlowUp::new(0.0, spec.horizon).map_err(filter_error)?;
            if let Some(clip) = spec.clip {
                blow_up = blow_up.with_mu2_clip(clip).map_err(filter_error)?;
            }
            let ramp = ContinuityRamp::new(spec.ramp_exponent, spec.ramp_duration, spec.ramp_tolerance)
                .map_err(filter_error)?;
            let z0 = transform.to_chain(x0);
            ChainFilter::Ptsf(Arc::new(
                PtsfFilter::from_initial_state(blow_up, &z0, spec.margin, ramp).map_err(filter_error)?,
            ))
        }
        FilterSpec::Esf(spec) => ChainFilter::Esf(Arc::new(EsfFilter::new(n, spec.rate).map_err(filter_error)?)),
        _ => unreachable!("called for the chain filters only"),
    };
    Ok(FilterRule::Chain { filter, transform })
}

/// The Ch. 3 design from the scenario: the linear model, the channel delays, V = p xᵀx,
/// the disk barrier (the scenario's only barrier: a ball, outside, over the whole state) and η
/// (given, or the bound (3.25) for ω̄ with B_ω = I).
fn linear_stabilizer(
    loaded: &LoadedScenario,
    spec: &ClfCbfQpSpec,
    queues: &[DelayQueue],
) -> Result<linear_delays::ConstrainedStabilizer, EpisodeError> {
    let sc = &loaded.scenario;
    let err =
        |key: &str, e: linear_delays::LinearDelaysError| EpisodeError::from(loaded.field_error(key, e.to_string()));
    let (a, b) = (
        matrix_from_rows(sc.vehicle.a.as_ref().expect("validated")),
        matrix_from_rows(sc.vehicle.b.as_ref().expect("validated")),
    );
    let n = a.nrows();
    let system = linear_delays::LinearSystem::new(a, b).map_err(|e| err("vehicle.a", e))?;
    let delays: Vec<f64> = queues.iter().map(|q| q.constant_delay().unwrap_or(f64::NAN)).collect();
    let clf = linear_delays::QuadraticClf::new(DMatrix::identity(n, n) * spec.p, DMatrix::identity(n, n) * spec.q)
        .map_err(|e| err("filter.p", e))?;
    let disk = match sc.barriers.as_slice() {
        [crate::barrier::Shape::Ball {
            indices,
            centre,
            radius,
            inside: false,
        }] if indices.iter().copied().eq(0..n) => {
            linear_delays::DiskBarrier::new(DVector::from_column_slice(centre), *radius)
                .map_err(|e| err("barriers[0]", e))?
        }
        _ => {
            return Err(loaded
                .field_error(
                    "barriers",
                    "clf_cbf_qp needs exactly one barrier: kind = \"ball\", inside = false, over every state index",
                )
                .into())
        }
    };
    let qp = linear_delays::GammaM::new(spec.m, spec.gamma).map_err(|e| err("filter.m", e))?;
    let build = |eta: f64| {
        linear_delays::ConstrainedStabilizer::new(
            system.clone(),
            delays.clone(),
            clf.clone(),
            disk.clone(),
            spec.l0,
            eta,
            qp,
        )
        .map_err(|e| err("filter", e))
    };
    let eta = match spec.eta {
        Some(eta) => eta,
        None => build(0.0)?
            .robust_buffer_bound(&DMatrix::identity(n, n), spec.omega_bar)
            .map_err(|e| err("filter.omega_bar", e))?,
    };
    build(eta)
}

/// The barrier the filter acts on (the scenario's only one), for checks before the run.
fn first_barrier(loaded: &LoadedScenario, model: &dyn Dynamics) -> Result<Barrier, EpisodeError> {
    let sc = &loaded.scenario;
    if let Some(shape) = sc.barriers.first() {
        return Ok(Barrier {
            name: "barrier_0".into(),
            shape: shape.clone(),
        });
    }
    match (sc.obstacles.first(), model.planar_position()) {
        (Some(o), Some(position)) => Ok(Barrier::circular_obstacle("obstacle_0", position, o.centre, o.radius)),
        _ => Err(loaded
            .field_error("filter", "a filter needs a barrier or an obstacle")
            .into()),
    }
}

/// A matrix from a scenario's array of rows (validated rectangular and non-empty).
fn matrix_from_rows(rows: &[Vec<f64>]) -> DMatrix<f64> {
    DMatrix::from_row_iterator(rows.len(), rows[0].len(), rows.iter().flatten().copied())
}

/// Smallest τ ≥ 0 with |d + v τ| = r (relative position d, velocity v held): 0 when already
/// within r, +inf when never.
fn time_to_contact(d: [f64; 2], v: [f64; 2], r: f64) -> f64 {
    let c = d[0] * d[0] + d[1] * d[1] - r * r;
    if c <= 0.0 {
        return 0.0;
    }
    let a = v[0] * v[0] + v[1] * v[1];
    let b = 2.0 * (d[0] * v[0] + d[1] * v[1]);
    let discriminant = b * b - 4.0 * a * c;
    if a == 0.0 || b >= 0.0 || discriminant < 0.0 {
        return f64::INFINITY;
    }
    (-b - discriminant.sqrt()) / (2.0 * a)
}

/// A random vector with ‖ω‖ ≤ `bound`, constant on each interval [k·hold, (k+1)·hold).
fn random_vector(seed: u64, stream: Stream, bound: f64, hold: f64, t: f64, dim: usize) -> DVector<f64> {
    DVector::from_iterator(
        dim,
        (0..dim).map(|i| random_component(seed, stream, bound, hold, t, dim, i)),
    )
}

/// Component i of [`random_vector`] (no allocation: the input disturbance is sampled in the
/// control callback).
fn random_component(seed: u64, stream: Stream, bound: f64, hold: f64, t: f64, dim: usize, i: usize) -> f64 {
    let interval = (t / hold + 1e-9).floor().max(0.0) as u64;
    bound / (dim as f64).sqrt() * random::symmetric_unit(seed, stream, interval, i as u64)
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
        return Err(loaded.field_error(
            "vehicle.timestep",
            format!("expected a positive number of seconds, found {timestep:e}"),
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
    let longest = [
        sc.control.period.unwrap_or(0.0),
        sc.control.predictor_step.unwrap_or(0.0),
    ]
    .into_iter()
    .chain(sc.delays.values().filter_map(DelayProfile::constant_delay))
    .fold(0.0, f64::max);
    if too_many(longest) {
        return Err(loaded.field_error(
            "vehicle.timestep",
            format!(
                "a delay or control period of {} s is {} steps of {} s, more than the limit of {budget} steps",
                longest,
                steps(longest).ceil(),
                timestep
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

/// Whether a stop was requested.
pub fn stop_requested() -> bool {
    STOP_REQUESTED.load(std::sync::atomic::Ordering::SeqCst)
}

/// The message of an episode stopped by [`request_stop`].
pub const INTERRUPTED: &str = "interrupted by a signal";

/// An obstacle as a Foxglove entity (grey until known, red after).
fn obstacle_scene(time: f64, o: &Obstacle) -> Record {
    let (centre, radius) = match &o.barrier.shape {
        crate::barrier::Shape::Ball { centre, .. } => ([centre[0], centre[1]], o.radius),
        _ => ([0.0, 0.0], o.radius),
    };
    Record::Scene(time, scene::obstacle(time, &o.barrier.name, centre, radius, o.known))
}

fn prediction_record(c: &Consistency, channels: &[String]) -> Record {
    let error = (&c.prediction.state - &c.realized).norm();
    Record::Prediction(proto::Prediction {
        time: c.prediction.target_time,
        channel: channels[c.prediction.channel].clone(),
        issued_at: c.prediction.issued_at,
        horizon: c.prediction.target_time - c.prediction.issued_at,
        predicted: c.prediction.state.iter().copied().collect(),
        realized: c.realized.iter().copied().collect(),
        error,
        relative_error: error / c.realized.norm().max(1.0),
        reused_chain: c.prediction.reused_chain,
        chain_mismatch: c.prediction.chain_mismatch,
    })
}

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
mod alloc_tests;

#[cfg(test)]
mod tests {
    #[test]
    fn time_to_contact_solves_the_constant_velocity_geometry() {
        // 10 m away head-on at 2 m/s, r = 6: contact after (10 − 6)/2 = 2 s.
        assert!((super::time_to_contact([-10.0, 0.0], [2.0, 0.0], 6.0) - 2.0).abs() < 1e-12);
        assert_eq!(super::time_to_contact([-10.0, 0.0], [-2.0, 0.0], 6.0), f64::INFINITY);
        assert_eq!(super::time_to_contact([-10.0, 7.0], [2.0, 0.0], 6.0), f64::INFINITY);
        assert_eq!(super::time_to_contact([-1.0, 0.0], [0.0, 0.0], 6.0), 0.0);
    }

    #[test]
    fn utc_stamp_matches_known_dates() {
        assert_eq!(super::utc_stamp(0), "19700101T000000");
        assert_eq!(super::utc_stamp(1_700_000_000), "20231114T221320");
        assert_eq!(super::utc_stamp(951_782_400), "20000229T000000");
    }
}
