//! What the episode writes to its sinks besides events: the per-step and per-tick records
//! (kept between steps, so logging allocates nothing per step), the barrier values, the
//! predictions against the realised state, and the Foxglove 3D scene.

use nalgebra::DVector;

use super::control::{Consistency, ControlLoop, Tick};
use super::{Episode, Obstacle, Outline};
use crate::barrier::{Barrier, Shape};
use crate::log::{proto, scene, LogError, Record, Sink};

/// The records written at every step or tick, kept between steps so logging allocates
/// nothing per step: each is always the variant its field names.
pub(super) struct RecordBuffers {
    pub(super) state: Record,
    pub(super) applied: Record,
    pub(super) barrier: Record,
    pub(super) issued: Record,
    pub(super) filter: Record,
    pub(super) measured: Record,
    pub(super) actuated: Record,
    /// The moving obstacles' states (None without moving obstacles: no `/actors` topic).
    pub(super) actors: Option<Record>,
    /// One prediction record per channel (each names its channel once).
    predictions: Vec<Record>,
    /// Each obstacle's place among the controller's known moving actors.
    pub(super) actor_slots: ActorSlots,
}

/// Per obstacle, its place in the order of [`ControlLoop::moving_actors`] (the order of the
/// controller's predicted actor positions), found by its first barrier's name: one look-up
/// per obstacle when the known barriers change, instead of a search by name per obstacle at
/// every prediction and scene frame (quadratic in the number of road users).
#[derive(Default)]
pub(super) struct ActorSlots {
    /// How many barriers the controller knew when `slots` was built (None: never built).
    built_for: Option<usize>,
    slots: Vec<Option<usize>>,
}

impl ActorSlots {
    /// Rebuilds the slots if the controller's known barriers changed since they were built.
    pub(super) fn refresh(&mut self, control: &ControlLoop, obstacles: &[Obstacle]) {
        let known = control.known_barriers().len();
        if self.built_for == Some(known) {
            return;
        }
        // The first actor of each name, as a search from the front finds it.
        let mut first: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
        for (k, (name, _)) in control.moving_actors().enumerate() {
            first.entry(name).or_insert(k);
        }
        self.slots.clear();
        self.slots.extend(
            obstacles
                .iter()
                .map(|o| o.barriers.first().and_then(|b| first.get(b.name.as_str()).copied())),
        );
        self.built_for = Some(known);
    }

    /// Obstacle i's place among the first `known` moving actors, if it is one of them.
    pub(super) fn slot(&self, i: usize, known: usize) -> Option<usize> {
        self.slots.get(i).copied().flatten().filter(|&k| k < known)
    }
}

impl RecordBuffers {
    pub(super) fn new(
        state_names: &[String],
        channels: &[String],
        moving: impl Iterator<Item = String>,
    ) -> RecordBuffers {
        let names: Vec<String> = moving.collect();
        let actors: Vec<proto::ActorValue> = (names.iter())
            .map(|name| proto::ActorValue {
                name: name.clone(),
                ..Default::default()
            })
            .collect();
        RecordBuffers {
            actors: (!actors.is_empty()).then(|| Record::Actors(proto::Actors { time: 0.0, actors })),
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
            measured: Record::Measured(proto::State {
                names: state_names.to_vec(),
                ..Default::default()
            }),
            actuated: Record::Actuated(proto::AppliedCommand {
                channels: channels.to_vec(),
                ..Default::default()
            }),
            predictions: channels
                .iter()
                .map(|channel| {
                    Record::Prediction(proto::Prediction {
                        channel: channel.clone(),
                        actors: names.clone(),
                        ..Default::default()
                    })
                })
                .collect(),
            actor_slots: ActorSlots::default(),
        }
    }

    /// The record of a prediction against the realised state (Definition 4.3), updated in
    /// place: the prediction's channel's record. Per moving obstacle (`obstacles`, in the
    /// order of the record's `actors`): where the controller assumed it at the target time
    /// (`c.actors_predicted`, in the order of `control`'s moving actors) and where it was.
    pub(super) fn set_prediction(&mut self, c: &Consistency, control: &ControlLoop, obstacles: &[Obstacle]) -> &Record {
        let record = &mut self.predictions[c.prediction.channel];
        let Record::Prediction(m) = record else {
            unreachable!("the prediction buffers are prediction records");
        };
        let (state, realized_state) = (c.prediction.state.as_slice(), c.realized.as_slice());
        assert_eq!(state.len(), realized_state.len(), "a prediction of the whole state");
        let n = state.len();
        let norm = nalgebra_norm(n, |i| state[i] - realized_state[i]);
        // Every field, by name: a field added to the message fails to compile here.
        let proto::Prediction {
            time,
            channel: _,
            issued_at,
            horizon,
            predicted,
            realized,
            error,
            relative_error,
            reused_chain,
            chain_mismatch,
            actors: _,
            actor_predicted,
            actor_realized,
            actor_error,
        } = m;
        actor_predicted.clear();
        actor_realized.clear();
        actor_error.clear();
        let known = c.actors_predicted.len() / 2;
        let target_time = c.prediction.target_time;
        self.actor_slots.refresh(control, obstacles);
        for (i, o) in obstacles.iter().enumerate() {
            let Some(motion) = &o.motion else { continue };
            // A road user that does not exist at the target time has no true position, and one
            // that did not exist at the controller's last observation was not predicted (it
            // held it parked: NaN already, not the distance to a parking place).
            let truth = match motion.exists_at(target_time) {
                true => motion.state_at(target_time).position,
                false => [f64::NAN; 2],
            };
            let assumed = (self.actor_slots.slot(i, known)).map_or([f64::NAN; 2], |k| {
                [c.actors_predicted[2 * k], c.actors_predicted[2 * k + 1]]
            });
            actor_predicted.extend_from_slice(&assumed);
            actor_realized.extend_from_slice(&truth);
            // (sqrt, not hypot: positions are bounded by ±1e9, the squares cannot overflow.)
            let (dx, dy) = (assumed[0] - truth[0], assumed[1] - truth[1]);
            actor_error.push((dx * dx + dy * dy).sqrt());
        }
        *time = c.prediction.target_time;
        *issued_at = c.prediction.issued_at;
        *horizon = c.prediction.target_time - c.prediction.issued_at;
        predicted.clear();
        predicted.extend_from_slice(state);
        realized.clear();
        realized.extend_from_slice(realized_state);
        *error = norm;
        *relative_error = norm / nalgebra_norm(n, |i| realized_state[i]).max(1.0);
        *reused_chain = c.prediction.reused_chain;
        *chain_mismatch = c.prediction.chain_mismatch;
        record
    }
}

/// The Euclidean norm of (v(0), …, v(n − 1)), summed as nalgebra's `norm` sums a dynamic
/// vector (eight partial sums over whole blocks of eight, then the rest in order), so that the
/// logged errors keep their bits; without forming the vector.
#[inline]
fn nalgebra_norm(n: usize, v: impl Fn(usize) -> f64) -> f64 {
    let mut acc = [0.0; 8];
    let mut i = 0;
    while n - i >= 8 {
        for (k, a) in acc.iter_mut().enumerate() {
            let x = v(i + k);
            *a += x * x;
        }
        i += 8;
    }
    let mut sum = 0.0;
    sum += acc[0] + acc[4];
    sum += acc[1] + acc[5];
    sum += acc[2] + acc[6];
    sum += acc[3] + acc[7];
    for k in i..n {
        let x = v(k);
        sum += x * x;
    }
    (0.0 + sum).sqrt()
}

/// A static line of the 3D view: a road edge, a lane marking (dashed: point pairs), a planar
/// half-space barrier's h = 0.
pub(super) struct SceneLine {
    pub(super) id: String,
    pub(super) points: Vec<[f64; 2]>,
    pub(super) dashed: bool,
}

/// What the Foxglove 3D view needs beyond the state.
pub(super) struct SceneState {
    pub(super) hull_radius: f64,
    /// The vehicle's footprint (length, width) and how far its centre lies ahead of the
    /// planar position along the heading (m), drawn instead of the hull.
    footprint: Option<([f64; 2], f64)>,
    /// A straight reference path (point, heading, distance the reference speed covers in the
    /// episode), drawn as a line over the stretch the vehicle can drive (so that viewers
    /// fitting their view to the scene show the episode, not a 400 m line).
    pub(super) path: Option<([f64; 2], f64, f64)>,
    /// The road and the planar half-space barriers, drawn once at the start.
    pub(super) lines: Vec<SceneLine>,
    /// The vehicle's trail (entities `trail/0`, `trail/1`, …).
    trail: Trail,
    /// The per-frame records, updated in place: the vehicle, `/tf`, and per channel the
    /// predicted position (entity `prediction/<channel>`).
    vehicle: Record,
    transform: Record,
    predictions: Vec<(String, Record)>,
    /// Plant steps per scene frame (see [`frame_steps`]).
    frame_steps: u64,
    /// The moving obstacles' per-frame views (made at the first frame).
    actors: Vec<ActorView>,
}

/// A moving obstacle's view, updated in place: its cylinder, its trail (as the vehicle's,
/// entities `actor_trail/<name>/<n>`) and per channel where the controller assumes it at the
/// channel's prediction time (entity `actor_prediction/<name>/<channel>`).
pub(super) struct ActorView {
    obstacle: usize,
    record: Record,
    trail: Trail,
    predictions: Vec<(String, Record)>,
}

/// A trail drawn in segments: positions at every fifth scene frame since the last published
/// segment (which starts with the previous segment's last point, so the segments join up).
/// Each segment (entity `<prefix><n>`) is published once and persists, so the log and the
/// memory grow linearly, not quadratically, with the episode's length; its record and name
/// are reused.
struct Trail {
    points: Vec<[f64; 2]>,
    segments: u64,
    prefix: String,
    id: String,
    record: Record,
}

impl Trail {
    fn new(prefix: String) -> Trail {
        Trail {
            points: Vec::new(),
            segments: 0,
            prefix,
            id: String::new(),
            record: Record::Scene(0.0, Default::default()),
        }
    }

    /// At a trail frame: adds `position`, and returns the next segment to publish when it has
    /// enough points (or at the `last` frame, any two).
    fn advance(&mut self, time: f64, position: [f64; 2], last: bool, thickness: f64) -> Option<&Record> {
        self.points.push(position);
        let points = self.points.len();
        if !(points > TRAIL_PUBLISH_EVERY_POINTS || (last && points >= 2)) {
            return None;
        }
        use std::fmt::Write;
        self.id.clear();
        let _ = write!(self.id, "{}{}", self.prefix, self.segments);
        if let Record::Scene(t, update) = &mut self.record {
            *t = time;
            scene::polyline_into(update, time, &self.id, &self.points, scene::TRAIL, thickness);
        }
        self.segments += 1;
        self.points.drain(..points - 1);
        Some(&self.record)
    }
}

impl SceneState {
    pub(super) fn new(
        hull_radius: f64,
        footprint: Option<([f64; 2], f64)>,
        path: Option<([f64; 2], f64, f64)>,
        lines: Vec<SceneLine>,
        channels: &[String],
        frame_steps: u64,
    ) -> SceneState {
        let scene = || Record::Scene(0.0, Default::default());
        SceneState {
            hull_radius,
            footprint,
            path,
            lines,
            trail: Trail::new("trail/".into()),
            frame_steps,
            actors: Vec::new(),
            vehicle: scene(),
            transform: Record::Transform(0.0, Default::default()),
            predictions: channels
                .iter()
                .map(|name| (format!("prediction/{name}"), scene()))
                .collect(),
        }
    }
}

/// The 3D view's frame period (simulated seconds): a frame at every control tick, but at most
/// one per 10 ms (viewers draw at ~60 Hz; a 2 ms tick would otherwise encode 5 scene frames
/// per 10 ms, the largest part of the log). The data topics keep every tick.
const SCENE_FRAME_PERIOD: f64 = 0.01;
/// Scene frames between trail points, and trail intervals per published trail segment.
const TRAIL_EVERY_FRAMES: u64 = 5;
const TRAIL_PUBLISH_EVERY_POINTS: usize = 10;

/// Plant steps per 3D view frame: a whole number of control ticks, the fewest that span
/// [`SCENE_FRAME_PERIOD`].
pub(super) fn frame_steps(steps_per_tick: u64, timestep: f64) -> u64 {
    let control_period = steps_per_tick as f64 * timestep;
    let ticks_per_frame = (SCENE_FRAME_PERIOD / control_period - 1e-9).ceil().max(1.0) as u64;
    steps_per_tick * ticks_per_frame
}

impl Episode {
    pub(super) fn emit(sinks: &mut [&mut dyn Sink], record: Record) -> Result<(), LogError> {
        Self::emit_ref(sinks, &record)
    }

    pub(super) fn emit_ref(sinks: &mut [&mut dyn Sink], record: &Record) -> Result<(), LogError> {
        for sink in sinks.iter_mut() {
            sink.record(record)?;
        }
        Ok(())
    }

    pub(super) fn event(time: f64, kind: &str, message: String, participants: Vec<String>, depth: f64) -> Record {
        Record::Event(proto::Event {
            time,
            kind: kind.into(),
            message,
            participants,
            depth,
        })
    }

    /// Foxglove view: static entities at the start, then the vehicle, predictions and `/tf`
    /// every frame (each control tick, at most every [`SCENE_FRAME_PERIOD`]) and the trail
    /// every few frames (planar vehicles only).
    pub(super) fn emit_scene(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        k: u64,
        time: f64,
        x: &DVector<f64>,
    ) -> Result<(), LogError> {
        // Every frame step (step 0 among them, which also draws the static entities).
        let frame_steps = self.scene.frame_steps;
        if !k.is_multiple_of(frame_steps) {
            return Ok(());
        }
        let model = self.control.model();
        let planar = model.planar_position();
        // Planar vehicles in the plane; a vehicle on a line along the world x axis.
        let (position, heading) = match (planar, model.line_position()) {
            (Some([i, j]), _) => ([x[i], x[j]], model.heading_index().map_or(0.0, |h| x[h])),
            (None, Some(i)) => ([x[i], 0.0], 0.0),
            (None, None) => return Ok(()),
        };
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
            for line in &self.scene.lines {
                let (color, thickness) = if line.id.starts_with("barrier/") {
                    (scene::BARRIER, 0.15)
                } else if line.dashed {
                    (scene::LANE, 0.15)
                } else {
                    (scene::ROAD_EDGE, 0.3)
                };
                let update = scene::lines(time, &line.id, &line.points, color, thickness, line.dashed);
                Self::emit(sinks, Record::Scene(time, update))?;
            }
        }
        let frame = k / frame_steps;
        let hull_radius = self.scene.hull_radius;
        if let Record::Scene(t, update) = &mut self.scene.vehicle {
            *t = time;
            match self.scene.footprint {
                Some((size, 0.0)) => scene::footprint_vehicle_into(update, time, position, heading, size),
                Some((size, offset)) => {
                    let centre = [
                        position[0] + offset * heading.cos(),
                        position[1] + offset * heading.sin(),
                    ];
                    scene::footprint_vehicle_into(update, time, centre, heading, size)
                }
                None => scene::vehicle_into(update, time, position, heading, hull_radius),
            }
        }
        Self::emit_ref(sinks, &self.scene.vehicle)?;
        self.emit_actors(sinks, k, time)?;
        // Where the controller predicts the vehicle at t + D_i (the latest prediction of each
        // channel, made at the previous tick), with a line from where it is now.
        if let Some([i, j]) = planar {
            for p in self.control.latest_predictions() {
                let Some((id, record)) = self.scene.predictions.get_mut(p.channel) else {
                    continue;
                };
                if let Record::Scene(t, update) = record {
                    *t = time;
                    scene::prediction_into(update, time, id, position, [p.state[i], p.state[j]], hull_radius);
                }
                Self::emit_ref(sinks, record)?;
            }
        }
        if let Record::Transform(t, transform) = &mut self.scene.transform {
            *t = time;
            scene::transform_into(transform, time, position, heading);
        }
        Self::emit_ref(sinks, &self.scene.transform)?;
        if frame.is_multiple_of(TRAIL_EVERY_FRAMES) {
            let last_tick = k + frame_steps > self.steps;
            if let Some(segment) = self.scene.trail.advance(time, position, last_tick, 0.15) {
                Self::emit_ref(sinks, segment)?;
            }
        }
        Ok(())
    }

    /// The moving obstacles in a scene frame: each where it is now (step 0 drew them with the
    /// static entities), where the controller assumes it at each channel's prediction time
    /// (the latest pending prediction; a ring of its radius with a line from it), and its trail.
    fn emit_actors(&mut self, sinks: &mut [&mut dyn Sink], k: u64, time: f64) -> Result<(), LogError> {
        if k == 0 && self.scene.actors.is_empty() {
            let channels = self.control.model().channel_names();
            let moving = self.obstacles.iter().enumerate().filter(|(_, o)| o.motion.is_some());
            self.scene.actors = moving
                .map(|(i, o)| ActorView {
                    obstacle: i,
                    record: Record::Scene(time, Default::default()),
                    trail: Trail::new(format!("actor_trail/{}/", o.name)),
                    predictions: (channels.iter())
                        .map(|c| {
                            let id = format!("actor_prediction/{}/{c}", o.name);
                            (id, Record::Scene(time, Default::default()))
                        })
                        .collect(),
                })
                .collect();
        }
        let frame = k / self.scene.frame_steps;
        let last_frame = k + self.scene.frame_steps > self.steps;
        self.records.actor_slots.refresh(&self.control, &self.obstacles);
        for view in &mut self.scene.actors {
            let o = &self.obstacles[view.obstacle];
            let centre = o.centre;
            // A box's predicted position is drawn as the ring around it.
            let radius = match o.outline {
                Outline::Circle { radius } => radius,
                Outline::Box { length, width, .. } => 0.5 * (length * length + width * width).sqrt(),
            };
            if k > 0 {
                if let Record::Scene(t, update) = &mut view.record {
                    *t = time;
                    let known = o.known && !o.absent;
                    match o.outline {
                        Outline::Circle { radius } => {
                            scene::obstacle_into(update, time, &o.name, centre, radius, known)
                        }
                        Outline::Box { length, width, heading } => {
                            let turned = heading + o.state.turn;
                            scene::box_obstacle_into(update, time, &o.name, centre, turned, [length, width], known);
                        }
                    }
                }
                Self::emit_ref(sinks, &view.record)?;
            }
            for (channel, assumed) in self.control.latest_actor_predictions() {
                let Some(a) = self.records.actor_slots.slot(view.obstacle, assumed.len() / 2) else {
                    continue;
                };
                let Some((id, record)) = view.predictions.get_mut(channel) else {
                    continue;
                };
                if let Record::Scene(t, update) = record {
                    *t = time;
                    let to = [assumed[2 * a], assumed[2 * a + 1]];
                    scene::prediction_into(update, time, id, centre, to, radius);
                }
                Self::emit_ref(sinks, record)?;
            }
            if frame.is_multiple_of(TRAIL_EVERY_FRAMES) {
                if let Some(segment) = view.trail.advance(time, centre, last_frame, 0.1) {
                    Self::emit_ref(sinks, segment)?;
                }
            }
        }
        Ok(())
    }

    /// The tick's issued commands and filter decision, and with a sensor what it measured
    /// (`step`: the tick's plant step; `barriers`: the known barriers, whose indices the
    /// decisions' `unmet` are).
    pub(super) fn emit_tick(
        sinks: &mut [&mut dyn Sink],
        tick: &Tick,
        barriers: &[Barrier],
        step: u64,
        sensor: bool,
        records: &mut RecordBuffers,
    ) -> Result<(), LogError> {
        if sensor {
            if let Record::Measured(m) = &mut records.measured {
                (m.time, m.step) = (tick.time, step);
                m.values.clear();
                m.values.extend_from_slice(tick.measured.as_slice());
            }
            Self::emit_ref(sinks, &records.measured)?;
        }
        if let Record::Issued(m) = &mut records.issued {
            m.time = tick.time;
            m.nominal.clear();
            m.nominal.extend_from_slice(tick.nominal.as_slice());
            m.filtered.clear();
            m.filtered.extend_from_slice(tick.issued.as_slice());
        }
        Self::emit_ref(sinks, &records.issued)?;
        let solved = tick.outcomes.iter().flatten();
        if let Record::Filter(m) = &mut records.filter {
            m.time = tick.time;
            m.active = solved.clone().any(|o| o.active);
            m.infeasible = solved.clone().any(|o| o.infeasible);
            m.mu = solved.clone().map(|o| o.mu).fold(f64::NAN, f64::min);
            m.left_out = u32::try_from(tick.left_out).unwrap_or(u32::MAX);
            // Per barrier left unmet by some channel's decision: its largest shortfall (names
            // written into the message's reused strings).
            m.shortfall.clear();
            let mut unmet = 0;
            if solved.clone().any(|o| o.unmet.is_some()) {
                for (k, barrier) in barriers.iter().enumerate() {
                    let Some(shortfall) = solved
                        .clone()
                        .filter(|o| o.unmet == Some(k))
                        .map(|o| o.shortfall)
                        .reduce(f64::max)
                    else {
                        continue;
                    };
                    match m.unmet.get_mut(unmet) {
                        Some(name) => {
                            name.clear();
                            name.push_str(&barrier.name);
                        }
                        None => m.unmet.push(barrier.name.clone()),
                    }
                    m.shortfall.push(shortfall);
                    unmet += 1;
                }
            }
            m.unmet.truncate(unmet);
            m.correction.clear();
            let (issued, nominal) = (tick.issued.as_slice(), tick.nominal.as_slice());
            m.correction.extend(issued.iter().zip(nominal).map(|(u, u0)| u - u0));
        }
        Self::emit_ref(sinks, &records.filter)
    }

    /// Every barrier at x(t_k), with its constraint evaluated at the applied input (without a
    /// filter there is no barrier constraint: only h is meaningful). An obstacle is one entry,
    /// named as the obstacle, from its pairs (a footprint's covering circles against the
    /// obstacle's, each pair a barrier of the filter; [`BarrierSample::nearer`]), or, with
    /// `[log] barrier_pairs`, one entry per pair.
    pub(super) fn emit_barriers(
        &mut self,
        sinks: &mut [&mut dyn Sink],
        time: f64,
        x: &DVector<f64>,
        applied: &DVector<f64>,
    ) -> Result<(), LogError> {
        let form = self.control.filter().barrier_form();
        let model = self.control.model().as_ref();
        // World velocity of the planar position (for time-to-collision): ṗ from the model, ẋ
        // formed once per step (a body circle's point velocity reads it too).
        let velocity = model.planar_position().map(|[i, j]| {
            model.dynamics_into(x.as_slice(), applied.as_slice(), &mut self.xdot);
            [self.xdot[i], self.xdot[j]]
        });
        let Record::Barrier(record) = &mut self.records.barrier else {
            unreachable!("records.barrier holds a barrier record")
        };
        record.time = time;
        let logged = self.obstacles.iter().filter(|o| !o.barriers.is_empty());
        let pairs = self.log_barrier_pairs;
        let obstacle_entries = match pairs {
            true => self.obstacle_barriers.len(),
            false => logged.clone().count(),
        };
        let count = obstacle_entries + self.barriers.len();
        let ego = &mut self.ego_points;
        if record.barriers.len() != count {
            let entry = |name: &String| proto::BarrierValue {
                name: name.clone(),
                ..Default::default()
            };
            record.barriers.clear();
            for o in logged.clone() {
                match pairs {
                    true => record.barriers.extend(o.barriers.iter().map(|b| entry(&b.name))),
                    false => record.barriers.push(entry(&o.name)),
                }
            }
            record.barriers.extend(self.barriers.iter().map(|b| entry(&b.name)));
            // A road user's circle measures from its ego point (when conditions are logged).
            self.logged_points = logged
                .clone()
                .flat_map(|o| o.barriers.iter().map(move |b| (b, o.motion.is_some())))
                .map(|(b, moving)| (moving && form.is_some()).then(|| ego.index_of(b)).flatten())
                .collect();
        }
        // (The points are those of the logged road users' circles.)
        if ego.len() > 0 {
            ego.measure(model, x.as_slice());
        }
        let mut sampler = BarrierSampler {
            form,
            model,
            x,
            applied,
            xdot: &self.xdot,
            velocity,
            ego,
            lie: &mut self.lie,
            constraint: &mut self.constraint,
            points: Default::default(),
            known_points: 0,
        };
        let (obstacle_values, other_values) = record.barriers.split_at_mut(obstacle_entries);
        let (mut first, mut values) = (0, obstacle_values.iter_mut());
        for o in logged {
            // Each barrier's circle moves with the actor at its offset (a box's circles).
            let actor = o.motion.as_ref().map(|_| o.state);
            let circle = |k: usize| actor.map(|a| a.shifted(o.offsets[k]));
            let points = &self.logged_points[first..first + o.barriers.len()];
            first += o.barriers.len();
            if o.absent {
                // A recorded road user that does not exist now has no values (`/actors` says
                // why), not those of where it is parked.
                for value in values.by_ref().take(if pairs { o.barriers.len() } else { 1 }) {
                    BarrierSample::ABSENT.write(value, o.known, true);
                }
                continue;
            }
            if pairs {
                for ((k, b), value) in o.barriers.iter().enumerate().zip(&mut values) {
                    sampler
                        .sample(b, true, circle(k), points[k])
                        .write(value, o.known, true);
                }
                continue;
            }
            // The pairs' geometry, then the condition of the nearest pair alone.
            let pairs = actor.and_then(|actor| sampler.road_user_pairs(&o.barriers, &o.offsets[..o.circles], actor));
            let nearest = pairs.or_else(|| {
                (o.barriers.iter().enumerate())
                    .map(|(k, b)| (k, sampler.geometry(b, true, circle(k))))
                    .reduce(nearer_pair)
            });
            if let (Some((k, mut sample)), Some(value)) = (nearest, values.next()) {
                (sample.constraint, sample.relative_degree) = sampler.condition(&o.barriers[k], circle(k), points[k]);
                sample.write(value, o.known, true);
            }
        }
        for (b, value) in self.barriers.iter().zip(other_values) {
            sampler.sample(b, false, None, None).write(value, true, false);
        }
        if count == 0 {
            return Ok(());
        }
        Self::emit_ref(sinks, &self.records.barrier)
    }
}

/// Two pairs' samples reduced to their obstacle's entry: the nearer pair's index (the first on
/// a tie) with [`BarrierSample::nearer`].
#[inline]
fn nearer_pair((i, a): (usize, BarrierSample), (j, b): (usize, BarrierSample)) -> (usize, BarrierSample) {
    (if b.h < a.h { j } else { i }, a.nearer(b))
}

/// One barrier's logged values at a step (an obstacle's entry: the least over its pairs).
#[derive(Clone, Copy)]
struct BarrierSample {
    h: f64,
    constraint: f64,
    relative_degree: u32,
    clearance: f64,
    time_to_collision: f64,
}

impl BarrierSample {
    /// The entry of a road user that does not exist at the step: no values, no condition.
    const ABSENT: BarrierSample = BarrierSample {
        h: f64::NAN,
        constraint: f64::NAN,
        relative_degree: 0,
        clearance: f64::NAN,
        time_to_collision: f64::NAN,
    };

    /// An obstacle's entry from two of its pairs: the nearer pair's h and condition (the first
    /// on a tie), the least clearance and the least time to collision (NaN only where both are).
    fn nearer(self, other: BarrierSample) -> BarrierSample {
        let nearer = if other.h < self.h { other } else { self };
        BarrierSample {
            clearance: self.clearance.min(other.clearance),
            time_to_collision: self.time_to_collision.min(other.time_to_collision),
            ..nearer
        }
    }

    /// Into the record's entry (its name kept).
    fn write(self, value: &mut proto::BarrierValue, known: bool, obstacle: bool) {
        *value = proto::BarrierValue {
            name: std::mem::take(&mut value.name),
            h: self.h,
            constraint: self.constraint,
            known,
            relative_degree: self.relative_degree,
            clearance: self.clearance,
            time_to_collision: self.time_to_collision,
            obstacle,
        };
    }
}

/// What one step's barrier values are measured from (x, the applied input, ẋ formed once).
struct BarrierSampler<'a> {
    form: Option<crate::barrier::BarrierForm>,
    model: &'a dyn crate::dynamics::Dynamics,
    x: &'a DVector<f64>,
    applied: &'a DVector<f64>,
    xdot: &'a [f64],
    velocity: Option<[f64; 2]>,
    ego: &'a super::reach::EgoPoints,
    lie: &'a mut crate::barrier::LieWorkspace,
    constraint: &'a mut crate::barrier::Constraint,
    /// The footprint circles' (point, q, q̇) at this step, as formed, and how many
    /// ([`BarrierSampler::body_point`]; room for four, on the stack).
    points: [BodyPoint; 4],
    known_points: usize,
}

/// A body circle's point (position and heading indices, offset) with its q and q̇.
type BodyPoint = (([usize; 2], usize, [f64; 2]), [f64; 2], [f64; 2]);

impl BarrierSampler<'_> {
    /// Barrier b's h, condition a + b·u at the applied input, clearance and time to collision;
    /// `actor`: where its circle is when it moves; `point`: its ego point when it is measured.
    fn sample(
        &mut self,
        b: &Barrier,
        obstacle: bool,
        actor: Option<crate::actor::ActorState>,
        point: Option<usize>,
    ) -> BarrierSample {
        let mut sample = self.geometry(b, obstacle, actor);
        (sample.constraint, sample.relative_degree) = self.condition(b, actor, point);
        sample
    }

    /// The nearest pair of a moving road user's body-circle pairs (`barriers`, each vehicle
    /// circle with the road user's `circles` in turn) and their entry, as [`Self::geometry`]
    /// and [`nearer_pair`] give them pair by pair, bit for bit, with each circle's state and
    /// each vehicle point formed once; None for any other layout (then pair by pair).
    fn road_user_pairs(
        &mut self,
        barriers: &[Barrier],
        circles: &[[f64; 2]],
        actor: crate::actor::ActorState,
    ) -> Option<(usize, BarrierSample)> {
        const MOST_CIRCLES: usize = 8;
        let n = circles.len();
        if self.velocity.is_none() || n == 0 || n > MOST_CIRCLES || !barriers.len().is_multiple_of(n) {
            return None;
        }
        let mut states = [crate::actor::ActorState::default(); MOST_CIRCLES];
        for (state, offset) in states.iter_mut().zip(circles) {
            *state = actor.shifted(*offset);
        }
        let mut nearest: Option<(usize, BarrierSample)> = None;
        for (vehicle, pairs) in barriers.chunks_exact(n).enumerate() {
            let key = pairs[0].body_point_of()?;
            let (q, q_dot) = self.body_point(key, &pairs[0]);
            for (j, (b, circle)) in pairs.iter().zip(&states).enumerate() {
                let (&Shape::BodyCircle { centre, radius, .. }, Some((h, clearance, ..)), true) =
                    (&b.shape, b.circle_values_at(q, q_dot), b.body_point_of() == Some(key))
                else {
                    return None;
                };
                // (The body-circle case of time_to_collision.)
                let relative = [q_dot[0] - circle.velocity[0], q_dot[1] - circle.velocity[1]];
                let sample = BarrierSample {
                    h,
                    constraint: f64::NAN,
                    relative_degree: 0,
                    clearance,
                    time_to_collision: time_to_contact([q[0] - centre[0], q[1] - centre[1]], relative, radius),
                };
                let pair = (vehicle * n + j, sample);
                nearest = Some(nearest.map_or(pair, |best| nearer_pair(best, pair)));
            }
        }
        nearest
    }

    /// Barrier b's h, clearance and time to collision (its condition NaN, to be formed).
    fn geometry(&mut self, b: &Barrier, obstacle: bool, actor: Option<crate::actor::ActorState>) -> BarrierSample {
        let x = self.x;
        // An outside circle: h, the clearance, q and q̇ (with the applied input) from one q,
        // a footprint circle's formed once per step for all its barriers.
        let circle_values = match b.body_point_of() {
            Some(key) => {
                let (q, q_dot) = self.body_point(key, b);
                b.circle_values_at(q, q_dot)
            }
            None => b.circle_values(x.as_slice(), self.xdot),
        };
        BarrierSample {
            h: circle_values.map_or_else(|| b.h(x), |(h, ..)| h),
            constraint: f64::NAN,
            relative_degree: 0,
            clearance: circle_values.map_or_else(|| b.clearance(x), |(_, c, ..)| c),
            time_to_collision: self.time_to_collision(b, obstacle, actor, circle_values),
        }
    }

    /// The point q and its velocity q̇ of body circle `key` (b one of its barriers), formed once
    /// per step ([`Barrier::point_and_velocity`]) for up to four footprint circles.
    fn body_point(&mut self, key: ([usize; 2], usize, [f64; 2]), b: &Barrier) -> ([f64; 2], [f64; 2]) {
        let same = |known: &([usize; 2], usize, [f64; 2])| {
            known.0 == key.0 && known.1 == key.1 && known.2.map(f64::to_bits) == key.2.map(f64::to_bits)
        };
        if let Some((_, q, q_dot)) = self.points[..self.known_points].iter().find(|(known, ..)| same(known)) {
            return (*q, *q_dot);
        }
        let (q, q_dot) = b
            .point_and_velocity(self.x.as_slice(), self.xdot)
            .expect("a body circle has a point");
        if let Some(room) = self.points.get_mut(self.known_points) {
            (*room, self.known_points) = ((key, q, q_dot), self.known_points + 1);
        }
        (q, q_dot)
    }

    /// Barrier b's condition a + b·u at the applied input and its relative degree (NaN and 0
    /// without a filter).
    fn condition(&mut self, b: &Barrier, actor: Option<crate::actor::ActorState>, point: Option<usize>) -> (f64, u32) {
        let (x, applied) = (self.x, self.applied);
        let Some(form) = self.form else {
            return (f64::NAN, 0);
        };
        // A road user's circle against an ego point: the closed form of the pair's condition
        // from the point's kinematics, measured once per step.
        if let (Some(circle), Some(i)) = (&actor, point) {
            let value = pair_condition_at(self.ego.point(i), form, b, circle, applied.as_slice());
            return (value, form.relative_degree());
        }
        let data = &mut *self.constraint;
        self.lie.constraint_into(b, form, self.model, x.as_slice(), data);
        // A moving actor: h(x, t) gains the terms of its true motion.
        if let (Some(actor), crate::barrier::Shape::Headway { .. }) = (&actor, &b.shape) {
            crate::actor::add_headway_motion_terms(data, form, actor);
        }
        // (ṗ: at relative degree 2 no input reaches the position, so the velocity with the
        // applied input is the drift.)
        if let (Some(actor), Some([i, j]), Some(p_dot)) = (&actor, self.model.planar_position(), self.velocity) {
            crate::actor::add_motion_terms(data, form, [x[i], x[j]], p_dot, actor);
        }
        (data.value(applied), form.relative_degree())
    }

    /// Time until the clearance reaches 0 with the velocity held (NaN where it has none).
    fn time_to_collision(
        &self,
        b: &Barrier,
        obstacle: bool,
        actor: Option<crate::actor::ActorState>,
        circle_values: Option<(f64, f64, [f64; 2], [f64; 2])>,
    ) -> f64 {
        let x = self.x;
        // Relative to a moving actor's velocity.
        let relative_velocity = match (self.velocity, &actor) {
            (Some(v), Some(a)) => Some([v[0] - a.velocity[0], v[1] - a.velocity[1]]),
            (v, _) => v,
        };
        match (obstacle, relative_velocity, &b.shape) {
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
            // A body circle's point q, moving at q̇ (with the applied input).
            (true, Some(_), crate::barrier::Shape::BodyCircle { centre, radius, .. }) => {
                let point = circle_values.map(|(_, _, q, q_dot)| (q, q_dot));
                match point.or_else(|| b.point_and_velocity(x.as_slice(), self.xdot)) {
                    Some((q, q_dot)) => {
                        let relative = actor.map_or(q_dot, |a| [q_dot[0] - a.velocity[0], q_dot[1] - a.velocity[1]]);
                        time_to_contact([q[0] - centre[0], q[1] - centre[1]], relative, *radius)
                    }
                    None => f64::NAN,
                }
            }
            // A lead: the gap over the closing speed v − v_L (the lead's velocity held).
            (true, _, &crate::barrier::Shape::Headway { speed, .. }) => {
                let closing = x[speed] - actor.map_or(0.0, |a| a.velocity[0]);
                let gap = b.clearance(x);
                match (gap <= 0.0, closing > 0.0) {
                    (true, _) => 0.0,
                    (false, true) => gap / closing,
                    (false, false) => f64::INFINITY,
                }
            }
            _ => f64::NAN,
        }
    }
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

/// An obstacle as a Foxglove entity (grey until known, red after): a cylinder, or a box's cube.
pub(super) fn obstacle_scene(time: f64, o: &Obstacle) -> Record {
    // Grey while unknown to the controller or absent (a recorded road user outside its span,
    // drawn where it was last seen); a box turned as its motion turned it.
    let known = o.known && !o.absent;
    let update = match o.outline {
        Outline::Circle { radius } => scene::obstacle(time, &o.name, o.centre, radius, known),
        Outline::Box { length, width, heading } => {
            scene::box_obstacle(time, &o.name, o.centre, heading + o.state.turn, [length, width], known)
        }
    };
    Record::Scene(time, update)
}

/// a + b·u of a road user's circle (its state `circle`) against the ego point of `b` (`point`,
/// measured at the state), in `form`, at the input `u` ([`crate::actor::reach::pair_condition`]).
fn pair_condition_at(
    point: &super::reach::PointMotion,
    form: crate::barrier::BarrierForm,
    b: &Barrier,
    circle: &crate::actor::ActorState,
    u: &[f64],
) -> f64 {
    let kinematics = point.kinematics(u.len().min(4));
    let mixed_rate = match b.mixed_relative_degree() {
        true => form.real_rates().map(|(lambda1, _)| lambda1),
        false => None,
    };
    let radius = match &b.shape {
        crate::barrier::Shape::Ball { radius, .. } | crate::barrier::Shape::BodyCircle { radius, .. } => *radius,
        _ => 0.0,
    };
    crate::actor::reach::pair_condition(form, mixed_rate, &kinematics, circle, radius, u)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_norm_has_the_bits_of_nalgebras() {
        let special = [0.0, -0.0, 1e-300, -3.5, 1e200, f64::NAN, f64::INFINITY, 1.0 / 3.0];
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        for n in 0..=40 {
            for trial in 0..50 {
                let v: Vec<f64> = (0..n)
                    .map(|i| {
                        seed ^= seed << 13;
                        seed ^= seed >> 7;
                        seed ^= seed << 17;
                        let x = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                        if trial % 10 == 9 && i % 7 == 3 {
                            special[(seed % 8) as usize]
                        } else {
                            x * 10f64.powi((seed % 13) as i32 - 6)
                        }
                    })
                    .collect();
                let expected = nalgebra::DVector::from_vec(v.clone()).norm();
                assert_eq!(super::nalgebra_norm(n, |i| v[i]).to_bits(), expected.to_bits(), "{v:?}");
            }
        }
    }

    #[test]
    fn time_to_contact_solves_the_constant_velocity_geometry() {
        // 10 m away head-on at 2 m/s, r = 6: contact after (10 − 6)/2 = 2 s.
        assert!((super::time_to_contact([-10.0, 0.0], [2.0, 0.0], 6.0) - 2.0).abs() < 1e-12);
        assert_eq!(super::time_to_contact([-10.0, 0.0], [-2.0, 0.0], 6.0), f64::INFINITY);
        assert_eq!(super::time_to_contact([-10.0, 7.0], [2.0, 0.0], 6.0), f64::INFINITY);
        assert_eq!(super::time_to_contact([-1.0, 0.0], [0.0, 0.0], 6.0), 0.0);
    }
}
