//! The episode loop: builds the MuJoCo plant for a scenario, steps it with the controller in
//! MuJoCo's control callback, and reports every step to the log sinks.
//!
//! One control tick (every `control_period`, decided by the step counter, at the callback call
//! that sees the real state): read x → nominal u0(x) → safety filter → push the issued command
//! into each channel's delay queue. At every callback call (RK4 fires four per step, at trial
//! states): sample the queues at the call's time and write `ctrl`. Nothing else happens inside
//! the callback.

use std::path::PathBuf;
use std::time::Instant;

use nalgebra::DVector;

use crate::barrier::{self, BarrierForm, CircularObstacle};
use crate::delay::{DelayError, DelayQueue};
use crate::filter::{self, FilterOutcome};
use crate::log::{proto, LogError, Record, RunInfo, Sink};
use crate::mujoco::{self, CallbackContext, ControlHook, DataView, MjError, Model, Simulation};
use crate::nominal::{BicyclePathLqr, Nominal};
use crate::scenario::{
    CbfQpSpec, ConstantSpec, FilterSpec, LoadedScenario, NominalSpec, PathLqrSpec, ScenarioError,
};
use crate::vehicle::{self, Vehicle, VehicleKind};

#[derive(Debug, thiserror::Error)]
pub enum EpisodeError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Log(#[from] LogError),
    #[error("{file}: key `vehicle.model`: {source}")]
    Model { file: String, source: MjError },
    #[error(transparent)]
    Mujoco(#[from] MjError),
}

/// Fraction of a step below which two times are the same tick.
const TICK_TOLERANCE: f64 = 1e-6;

/// An obstacle of the episode: its barrier, its MuJoCo geom, whether the controller knows it.
#[derive(Debug, Clone)]
struct Obstacle {
    barrier: CircularObstacle,
    geom: usize,
    appear_at: f64,
    known: bool,
    in_contact: bool,
    /// Deepest penetration of the current contact episode.
    contact_depth: f64,
}

/// What one control tick computed (logged after the step).
#[derive(Debug, Clone)]
struct Tick {
    time: f64,
    nominal: DVector<f64>,
    outcome: Option<FilterOutcome>,
    issued: DVector<f64>,
}

/// The controller side of the loop: runs inside MuJoCo's control callback.
struct ControlLoop {
    vehicle: Box<dyn Vehicle>,
    nominal: Nominal,
    form: Option<BarrierForm>,
    queues: Vec<DelayQueue>,
    /// Barriers of obstacles currently known to the controller.
    known_barriers: Vec<CircularObstacle>,
    timestep: f64,
    steps_per_tick: u64,
    /// Set at the tick of the current step, taken by the episode after the step.
    tick: Option<Tick>,
    /// Applied input at the start of the current step (value, issue time) per channel.
    applied: Vec<(f64, f64)>,
    applied_buffer: Vec<f64>,
    /// A queue error raised inside the callback (reported after the step).
    error: Option<DelayError>,
}

impl ControlLoop {
    fn control_tick(&mut self, time: f64, data: &DataView<'_>) {
        let x = self
            .vehicle
            .read_state(data.qpos(), data.qvel(), data.act());
        let nominal = self.nominal.input(&x);
        let outcome = match (self.form, self.known_barriers.first()) {
            (Some(form), Some(b)) => {
                let c = barrier::constraint(b, form, self.vehicle.as_ref(), &x);
                Some(filter::cbf_qp(&c, &nominal))
            }
            _ => None,
        };
        let issued = outcome
            .as_ref()
            .map_or_else(|| nominal.clone(), |o| o.input.clone());
        for (queue, &value) in self.queues.iter_mut().zip(issued.iter()) {
            if let Err(e) = queue.push(time, value) {
                self.error.get_or_insert(e);
            }
            queue.discard_before(time);
        }
        self.tick = Some(Tick {
            time,
            nominal,
            outcome,
            issued,
        });
    }
}

impl ControlHook for ControlLoop {
    fn on_control(&mut self, ctx: CallbackContext, data: &mut DataView<'_>) {
        let step_time = ctx.step as f64 * self.timestep;
        if ctx.call_in_step == 0 && ctx.step % self.steps_per_tick == 0 {
            self.control_tick(step_time, data);
        }
        // Sample at the call's offset inside this step, kept in [t_k, t_k + h): RK4's last
        // stage (at t_k + h) takes the left limit, so ctrl is constant over the step.
        let offset =
            (ctx.time - ctx.step_start_time).clamp(0.0, self.timestep * (1.0 - TICK_TOLERANCE));
        let sample_time = step_time + offset;
        self.applied_buffer.clear();
        for (i, queue) in self.queues.iter().enumerate() {
            let applied = match queue.applied(sample_time) {
                Ok(a) => a,
                Err(e) => {
                    self.error.get_or_insert(e);
                    crate::delay::Applied {
                        value: 0.0,
                        issued_at: f64::NAN,
                    }
                }
            };
            if ctx.call_in_step == 0 {
                self.applied[i] = (applied.value, applied.issued_at);
            }
            self.applied_buffer.push(applied.value);
        }
        self.vehicle.write_ctrl(data, &self.applied_buffer);
    }
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
    sim: Simulation,
    control: ControlLoop,
    obstacles: Vec<Obstacle>,
    steps: u64,
    info: RunInfo,
}

/// MJCF of the model with each obstacle added as a static sphere geom `obstacle_<i>`
/// (contype 0, conaffinity 1: it collides with the vehicle hull and nothing else).
fn model_with_obstacles(xml: &str, loaded: &LoadedScenario) -> Result<String, ScenarioError> {
    let obstacles = &loaded.scenario.obstacles;
    if obstacles.is_empty() {
        return Ok(xml.to_string());
    }
    let Some(at) = xml.rfind("</worldbody>") else {
        return Err(loaded.field_error(
            "vehicle.model",
            "the MJCF has no <worldbody> to place obstacles in",
        ));
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

impl Episode {
    /// Loads the model, binds the vehicle and checks everything that depends on the model.
    pub fn new(loaded: &LoadedScenario) -> Result<Episode, EpisodeError> {
        mujoco::check_version()?;
        let sc = &loaded.scenario;
        let file = loaded.path.display().to_string();
        let model_path = loaded.model_path();
        let xml = std::fs::read_to_string(&model_path).map_err(|e| {
            loaded.field_error(
                "vehicle.model",
                format!("cannot read MJCF file {}: {e}", model_path.display()),
            )
        })?;
        let xml = model_with_obstacles(&xml, loaded)?;
        let mut model =
            Model::from_xml_string(&xml, &model_path.display().to_string()).map_err(|source| {
                EpisodeError::Model {
                    file: file.clone(),
                    source,
                }
            })?;
        if let Some(h) = sc.vehicle.timestep {
            model.set_timestep(h);
        }
        if let Some(integrator) = sc.vehicle.integrator {
            model.set_integrator(integrator);
        }
        let timestep = model.timestep();
        let vehicle =
            vehicle::bind(sc.vehicle.kind, &model).map_err(|source| EpisodeError::Model {
                file: file.clone(),
                source,
            })?;

        let n = vehicle.state_dim();
        if sc.vehicle.initial_state.len() != n {
            return Err(loaded
                .field_error(
                    "vehicle.initial_state",
                    format!(
                        "expected {n} values ({}), found {}",
                        vehicle.state_names().join(", "),
                        sc.vehicle.initial_state.len()
                    ),
                )
                .into());
        }
        let channels = vehicle.channel_names();
        for key in sc.delays.keys().chain(sc.initial_input.keys()) {
            if !channels.contains(&key.as_str()) {
                return Err(loaded
                    .field_error(
                        key,
                        format!(
                            "unknown input channel; this vehicle has: {}",
                            channels.join(", ")
                        ),
                    )
                    .into());
            }
        }
        let mut queues = Vec::with_capacity(channels.len());
        for channel in channels {
            let delay = sc.delays.get(*channel).copied().unwrap_or(0.0);
            let initial = sc.initial_input.get(*channel).copied().unwrap_or(0.0);
            let queue = DelayQueue::new(channel, delay, initial, timestep)
                .map_err(|e| loaded.field_error(&format!("delays.{channel}"), e.to_string()))?;
            queues.push(queue);
        }

        let period = sc.control.period.unwrap_or(timestep);
        let ratio = period / timestep;
        if (ratio - ratio.round()).abs() > 1e-6 || ratio.round() < 1.0 {
            return Err(loaded
                .field_error(
                    "control.period",
                    format!(
                        "expected a whole multiple of the timestep {timestep} s, found {period}"
                    ),
                )
                .into());
        }
        let steps_per_tick = ratio.round() as u64;

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
                let wheelbase =
                    vehicle.input_matrix(&DVector::from_element(n, 1.0))[(2, 0)].recip();
                let lqr = BicyclePathLqr::new(
                    *path_point,
                    *path_heading,
                    *reference_speed,
                    wheelbase,
                    *q,
                    *r,
                )
                .map_err(|e| loaded.field_error("nominal", e.to_string()))?;
                Nominal::PathLqr(lqr)
            }
            NominalSpec::Constant(ConstantSpec { input }) => {
                if input.len() != channels.len() {
                    return Err(loaded
                        .field_error(
                            "nominal.input",
                            format!(
                                "expected {} values ({})",
                                channels.len(),
                                channels.join(", ")
                            ),
                        )
                        .into());
                }
                Nominal::Constant(DVector::from_column_slice(input))
            }
        };

        let form = match sc.filter {
            FilterSpec::None => None,
            FilterSpec::CbfQp(CbfQpSpec { l0, l1 }) => {
                if sc.obstacles.len() > 1 {
                    return Err(loaded
                        .field_error("obstacles", "the closed-form CBF-QP (4.9) handles one obstacle; several need the QP solver of the distinct-delay filters")
                        .into());
                }
                Some(BarrierForm::RelativeDegree2 { l0, l1 })
            }
        };

        let x0 = DVector::from_column_slice(&sc.vehicle.initial_state);
        let mut obstacles = Vec::with_capacity(sc.obstacles.len());
        for (i, o) in sc.obstacles.iter().enumerate() {
            let Some(position) = vehicle.planar_position() else {
                return Err(loaded
                    .field_error("obstacles", "this vehicle does not move in a plane")
                    .into());
            };
            let name = o.name.clone().unwrap_or_else(|| obstacle_geom_name(i));
            let barrier = CircularObstacle {
                name,
                centre: o.centre,
                radius_sum: vehicle.hull_radius() + o.radius,
                position,
            };
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
            let geom = model
                .require(crate::mujoco::ObjKind::Geom, &obstacle_geom_name(i))
                .map_err(|source| EpisodeError::Model {
                    file: file.clone(),
                    source,
                })?;
            obstacles.push(Obstacle {
                barrier,
                geom,
                appear_at: o.appear_at,
                known: false,
                in_contact: false,
                contact_depth: 0.0,
            });
        }

        let mut sim = Simulation::new(model)?;
        vehicle.write_state(&mut sim, &x0);
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
        };
        let n_channels = channels.len();
        Ok(Episode {
            sim,
            control: ControlLoop {
                vehicle,
                nominal,
                form,
                queues,
                known_barriers: Vec::new(),
                timestep,
                steps_per_tick,
                tick: None,
                applied: vec![(0.0, 0.0); n_channels],
                applied_buffer: Vec::with_capacity(n_channels),
                error: None,
            },
            obstacles,
            steps,
            info,
        })
    }

    pub fn info(&self) -> &RunInfo {
        &self.info
    }

    /// Steps the episode will take.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Runs to the end (or to the first error inside the run, which is logged as an `/event`
    /// error and returned in the summary) and finishes every sink.
    pub fn run(&mut self, sinks: &mut [&mut dyn Sink]) -> Result<EpisodeSummary, EpisodeError> {
        let started = Instant::now();
        let result = self.run_steps(sinks);
        let (steps, error) = match result {
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
        for sink in sinks.iter_mut() {
            sink.record(&record)?;
        }
        Ok(())
    }

    /// The step loop. Returns the steps taken and the in-run error that stopped it, if any.
    fn run_steps(
        &mut self,
        sinks: &mut [&mut dyn Sink],
    ) -> Result<(u64, Option<String>), EpisodeError> {
        let h = self.control.timestep;
        let state_names: Vec<String> = self
            .control
            .vehicle
            .state_names()
            .iter()
            .map(|s| s.to_string())
            .collect();
        let channels: Vec<String> = self
            .control
            .vehicle
            .channel_names()
            .iter()
            .map(|s| s.to_string())
            .collect();
        let hull = self.control.vehicle.hull_geom();

        for k in 0..=self.steps {
            let time = k as f64 * h;
            // Obstacles become known to the controller at their appearance time.
            for o in self
                .obstacles
                .iter_mut()
                .filter(|o| !o.known && o.appear_at <= time + TICK_TOLERANCE * h)
            {
                o.known = true;
                self.control.known_barriers.push(o.barrier.clone());
                Self::emit(
                    sinks,
                    Record::Event(proto::Event {
                        time,
                        kind: "obstacle_appeared".into(),
                        message: format!(
                            "{} at ({}, {}) becomes known to the controller",
                            o.barrier.name, o.barrier.centre[0], o.barrier.centre[1]
                        ),
                        participants: vec![o.barrier.name.clone()],
                        depth: 0.0,
                    }),
                )?;
            }

            let data = self.sim.data();
            let x = self
                .control
                .vehicle
                .read_state(data.qpos(), data.qvel(), data.act());
            Self::emit(
                sinks,
                Record::State(proto::State {
                    time,
                    step: k,
                    names: state_names.clone(),
                    values: x.iter().copied().collect(),
                }),
            )?;
            if x.iter().any(|v| !v.is_finite()) {
                let message = format!("non-finite state {:?} at t = {time}", x.as_slice());
                return self.stop_with_error(sinks, time, k, message);
            }
            if k == self.steps {
                break;
            }

            if let Err(e) = self.sim.step(&mut self.control) {
                return self.stop_with_error(sinks, time, k, e.to_string());
            }
            if let Some(e) = self.control.error.take() {
                return self.stop_with_error(sinks, time, k, e.to_string());
            }

            // What happened during step k: tick, applied input, barriers, contacts.
            if let Some(tick) = self.control.tick.take() {
                Self::emit(
                    sinks,
                    Record::Issued(proto::IssuedCommand {
                        time: tick.time,
                        channels: channels.clone(),
                        nominal: tick.nominal.iter().copied().collect(),
                        filtered: tick.issued.iter().copied().collect(),
                    }),
                )?;
                let (active, infeasible, mu) = tick
                    .outcome
                    .as_ref()
                    .map_or((false, false, f64::NAN), |o| (o.active, o.infeasible, o.mu));
                Self::emit(
                    sinks,
                    Record::Filter(proto::Filter {
                        time: tick.time,
                        active,
                        channels: channels.clone(),
                        correction: (&tick.issued - &tick.nominal).iter().copied().collect(),
                        infeasible,
                        mu,
                    }),
                )?;
            }
            let applied =
                DVector::from_iterator(channels.len(), self.control.applied.iter().map(|a| a.0));
            Self::emit(
                sinks,
                Record::Applied(proto::AppliedCommand {
                    time,
                    channels: channels.clone(),
                    values: applied.iter().copied().collect(),
                    issued_at: self.control.applied.iter().map(|a| a.1).collect(),
                }),
            )?;
            // Without a filter there is no barrier constraint: only h is meaningful.
            let form = self.control.form;
            let barriers = self
                .obstacles
                .iter()
                .map(|o| {
                    let vehicle = self.control.vehicle.as_ref();
                    let (constraint, relative_degree) = form.map_or((f64::NAN, 0), |form| {
                        let c = barrier::constraint(&o.barrier, form, vehicle, &x);
                        (c.value(&applied), form.relative_degree())
                    });
                    proto::BarrierValue {
                        name: o.barrier.name.clone(),
                        h: o.barrier.h(&x),
                        constraint,
                        known: o.known,
                        relative_degree,
                    }
                })
                .collect::<Vec<_>>();
            if !barriers.is_empty() {
                Self::emit(sinks, Record::Barrier(proto::Barrier { time, barriers }))?;
            }
            self.check_contacts(sinks, time, hull)?;
        }
        Self::emit(
            sinks,
            Record::Event(proto::Event {
                time: self.steps as f64 * h,
                kind: "episode_end".into(),
                message: format!("completed {} steps", self.steps),
                participants: vec![],
                depth: 0.0,
            }),
        )?;
        Ok((self.steps, None))
    }

    /// Collision start/end events from MuJoCo's contacts between the hull and obstacles.
    /// The contacts after `mj_step` are those of the step's first collision phase, i.e. of
    /// the state at the start of the step (Euler/implicit), so they carry that time.
    fn check_contacts(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        time: f64,
        hull: usize,
    ) -> Result<(), LogError> {
        if self.obstacles.is_empty() {
            return Ok(());
        }
        let contacts = self.sim.data().contacts();
        for o in self.obstacles.iter_mut() {
            let depth = contacts
                .iter()
                .filter(|c| {
                    (c.geom1 == hull && c.geom2 == o.geom) || (c.geom2 == hull && c.geom1 == o.geom)
                })
                .map(|c| -c.dist)
                .fold(None, |acc: Option<f64>, d| {
                    Some(acc.map_or(d, |a| a.max(d)))
                });
            let touching = depth.is_some_and(|d| d > 0.0);
            if touching {
                o.contact_depth = o.contact_depth.max(depth.unwrap_or(0.0));
            }
            if touching != o.in_contact {
                o.in_contact = touching;
                // collision_start carries the depth at first contact, collision_end the
                // deepest penetration of the whole contact.
                let (kind, message, depth) = if touching {
                    (
                        "collision_start",
                        format!("vehicle hull touches {}", o.barrier.name),
                        o.contact_depth,
                    )
                } else {
                    let deepest = std::mem::take(&mut o.contact_depth);
                    (
                        "collision_end",
                        format!(
                            "vehicle hull clear of {} (deepest penetration {deepest:.4} m)",
                            o.barrier.name
                        ),
                        deepest,
                    )
                };
                Self::emit(
                    sinks,
                    Record::Event(proto::Event {
                        time,
                        kind: kind.into(),
                        message,
                        participants: vec!["vehicle".into(), o.barrier.name.clone()],
                        depth,
                    }),
                )?;
            }
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
        Self::emit(
            sinks,
            Record::Event(proto::Event {
                time,
                kind: "error".into(),
                message: message.clone(),
                participants: vec![],
                depth: 0.0,
            }),
        )?;
        Ok((steps, Some(message)))
    }
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
mod tests {
    #[test]
    fn utc_stamp_matches_known_dates() {
        assert_eq!(super::utc_stamp(0), "19700101T000000");
        assert_eq!(super::utc_stamp(1_700_000_000), "20231114T221320");
        assert_eq!(super::utc_stamp(951_782_400), "20000229T000000");
    }
}
