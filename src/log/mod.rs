//! Log sinks. The episode emits [`Record`]s; sinks only observe them (nothing logged feeds
//! back into the simulation). The MCAP sink is the file format of record; rerun comes later
//! as a second sink.

use std::collections::BTreeMap;

pub mod info;
pub mod mcap;
pub mod mcap_writer;
pub mod read;
#[cfg(feature = "rerun")]
pub mod rerun;
pub mod scene;
mod wire;

/// The protobuf messages of the log (generated from proto/mjsafe.proto by build.rs).
pub mod proto {
    include!(concat!(env!("OUT_DIR"), "/mjsafe.rs"));
}

/// Serialized `FileDescriptorSet` of proto/mjsafe.proto, embedded as each channel's schema.
pub const DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/mjsafe_descriptor.bin"));

/// Schema version of the log contract in docs/log-format.md.
pub const LOG_FORMAT_VERSION: &str = "1";

/// The symmetric-log transform sign(v) · log10(1 + |v| / c): linear within ±c, logarithmic
/// beyond, so that a margin near 0 and a value of 250 read on one scale. The one definition
/// behind rerun's near-zero h series, the figures' axis (`plot::SymLog`) and the scorecard
/// report's.
pub fn symlog(v: f64, c: f64) -> f64 {
    v.signum() * (1.0 + v.abs() / c).log10()
}

/// One thing to log, with its topic fixed by its kind.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    State(proto::State),
    Issued(proto::IssuedCommand),
    Applied(proto::AppliedCommand),
    Barrier(proto::Barrier),
    Filter(proto::Filter),
    Event(proto::Event),
    Prediction(proto::Prediction),
    /// Foxglove 3D scene (`/scene`) and transform (`/tf`), at a time.
    Scene(f64, foxglove::messages::SceneUpdate),
    Transform(f64, foxglove::messages::FrameTransform),
    /// An `/event` as a Foxglove log line (`/log`, for Foxglove's Log panel): the MCAP sink
    /// writes one with every event ([`event_log`]).
    Log(f64, foxglove::messages::Log),
    /// What the controller read at a tick, when a sensor stands between it and the truth.
    Measured(proto::State),
    /// What the plant received over a step, when actuator dynamics follow the delayed command.
    Actuated(proto::AppliedCommand),
    /// The moving obstacles' true states at a step (scenarios with moving obstacles).
    Actors(proto::Actors),
}

/// The topic table of the log format (docs/log-format.md): topic, protobuf full name of the
/// message type, in the order of [`Topic`]. Writers, readers and decoders all use it. The
/// last three are optional: a log has them only when the scenario has a sensor, actuator
/// dynamics or moving obstacles (their channels are added with the first message).
pub const TOPICS: [(&str, &str); 13] = [
    ("/state", "mjsafe.State"),
    ("/command/issued", "mjsafe.IssuedCommand"),
    ("/command/applied", "mjsafe.AppliedCommand"),
    ("/barrier", "mjsafe.Barrier"),
    ("/filter", "mjsafe.Filter"),
    ("/event", "mjsafe.Event"),
    ("/prediction", "mjsafe.Prediction"),
    ("/scene", "foxglove.SceneUpdate"),
    ("/tf", "foxglove.FrameTransform"),
    ("/log", "foxglove.Log"),
    ("/state/measured", "mjsafe.State"),
    ("/command/actuated", "mjsafe.AppliedCommand"),
    ("/actors", "mjsafe.Actors"),
];

/// A topic of the log format, one per [`Record`] kind (its index in [`TOPICS`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Topic {
    State,
    Issued,
    Applied,
    Barrier,
    Filter,
    Event,
    Prediction,
    Scene,
    Transform,
    Log,
    Measured,
    Actuated,
    Actors,
}

impl Topic {
    /// Every topic, in the order of [`TOPICS`].
    pub const ALL: [Topic; 13] = [
        Topic::State,
        Topic::Issued,
        Topic::Applied,
        Topic::Barrier,
        Topic::Filter,
        Topic::Event,
        Topic::Prediction,
        Topic::Scene,
        Topic::Transform,
        Topic::Log,
        Topic::Measured,
        Topic::Actuated,
        Topic::Actors,
    ];

    /// Whether a log has the topic only for some scenarios (a sensor, actuator dynamics);
    /// every other topic has a channel in every log mjsafe writes.
    pub fn is_optional(self) -> bool {
        matches!(self, Topic::Measured | Topic::Actuated | Topic::Actors)
    }

    /// The topics every log has a channel for (from its start, messages or not).
    pub fn always_logged() -> impl Iterator<Item = Topic> {
        Topic::ALL.into_iter().filter(|t| !t.is_optional())
    }

    /// The topic name (`/state`, …).
    pub fn name(self) -> &'static str {
        TOPICS[self as usize].0
    }

    /// The protobuf full name of its message type.
    pub fn schema(self) -> &'static str {
        TOPICS[self as usize].1
    }

    /// The topic named `name`, if it is one of the log format.
    pub fn from_name(name: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.name() == name)
    }
}

impl std::fmt::Display for Topic {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The schema data (a serialized FileDescriptorSet) of a topic in [`TOPICS`].
pub fn schema_data(topic_index: usize) -> std::borrow::Cow<'static, [u8]> {
    use foxglove::Encode;
    match Topic::ALL[topic_index] {
        Topic::Scene => {
            foxglove::messages::SceneUpdate::get_schema()
                .expect("Foxglove schemas are embedded")
                .data
        }
        Topic::Transform => {
            foxglove::messages::FrameTransform::get_schema()
                .expect("Foxglove schemas are embedded")
                .data
        }
        Topic::Log => {
            foxglove::messages::Log::get_schema()
                .expect("Foxglove schemas are embedded")
                .data
        }
        _ => std::borrow::Cow::Borrowed(DESCRIPTOR_SET),
    }
}

impl Record {
    /// The topic of the record.
    pub fn kind(&self) -> Topic {
        match self {
            Record::State(_) => Topic::State,
            Record::Issued(_) => Topic::Issued,
            Record::Applied(_) => Topic::Applied,
            Record::Barrier(_) => Topic::Barrier,
            Record::Filter(_) => Topic::Filter,
            Record::Event(_) => Topic::Event,
            Record::Prediction(_) => Topic::Prediction,
            Record::Scene(..) => Topic::Scene,
            Record::Transform(..) => Topic::Transform,
            Record::Log(..) => Topic::Log,
            Record::Measured(_) => Topic::Measured,
            Record::Actuated(_) => Topic::Actuated,
            Record::Actors(_) => Topic::Actors,
        }
    }

    /// Index into [`TOPICS`].
    pub fn topic_index(&self) -> usize {
        self.kind() as usize
    }

    pub fn topic(&self) -> &'static str {
        self.kind().name()
    }

    /// Decodes one message of `topic` (the inverse of [`Record::encode`]); `log_time` (ns) is the
    /// time of the Foxglove records, which carry none of their own.
    pub fn decode(topic: Topic, data: &[u8], log_time: u64) -> Result<Record, prost::DecodeError> {
        use prost::Message;
        let time = log_time as f64 / 1e9;
        Ok(match topic {
            Topic::State => Record::State(proto::State::decode(data)?),
            Topic::Issued => Record::Issued(proto::IssuedCommand::decode(data)?),
            Topic::Applied => Record::Applied(proto::AppliedCommand::decode(data)?),
            Topic::Barrier => Record::Barrier(proto::Barrier::decode(data)?),
            Topic::Filter => Record::Filter(proto::Filter::decode(data)?),
            Topic::Event => Record::Event(proto::Event::decode(data)?),
            Topic::Prediction => Record::Prediction(proto::Prediction::decode(data)?),
            Topic::Scene => Record::Scene(time, foxglove::messages::SceneUpdate::decode(data)?),
            Topic::Transform => Record::Transform(time, foxglove::messages::FrameTransform::decode(data)?),
            Topic::Log => Record::Log(time, foxglove::messages::Log::decode(data)?),
            Topic::Measured => Record::Measured(proto::State::decode(data)?),
            Topic::Actuated => Record::Actuated(proto::AppliedCommand::decode(data)?),
            Topic::Actors => Record::Actors(proto::Actors::decode(data)?),
        })
    }

    /// Simulation time of the record, seconds.
    pub fn time(&self) -> f64 {
        match self {
            Record::State(m) => m.time,
            Record::Issued(m) => m.time,
            Record::Applied(m) => m.time,
            Record::Barrier(m) => m.time,
            Record::Filter(m) => m.time,
            Record::Event(m) => m.time,
            Record::Prediction(m) => m.time,
            Record::Measured(m) => m.time,
            Record::Actuated(m) => m.time,
            Record::Actors(m) => m.time,
            Record::Scene(t, _) | Record::Transform(t, _) | Record::Log(t, _) => *t,
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut buffer = Vec::new();
        self.encode_into(&mut buffer);
        buffer
    }

    /// buffer ← the protobuf encoding (reusing the buffer's allocation).
    pub fn encode_into(&self, buffer: &mut Vec<u8>) {
        buffer.clear();
        self.encode_append(buffer);
    }

    /// Appends the protobuf encoding to `buffer` (the MCAP sink encodes into its open chunk).
    pub fn encode_append(&self, buffer: &mut Vec<u8>) {
        use prost::Message;
        // The per-step and per-frame messages through `wire` (prost's bytes, cheaper); the
        // rare events through prost.
        const FITS: &str = "a Vec grows to fit any message";
        match self {
            Record::State(m) | Record::Measured(m) => wire::encode_state(m, buffer),
            Record::Issued(m) => wire::encode_issued(m, buffer),
            Record::Applied(m) | Record::Actuated(m) => wire::encode_applied(m, buffer),
            Record::Barrier(m) => wire::encode_barrier(m, buffer),
            Record::Filter(m) => wire::encode_filter(m, buffer),
            Record::Prediction(m) => wire::encode_prediction(m, buffer),
            Record::Scene(_, m) => wire::encode_scene_update(m, buffer),
            Record::Transform(_, m) => wire::encode_frame_transform(m, buffer),
            Record::Event(m) => m.encode(buffer).expect(FITS),
            Record::Actors(m) => wire::encode_actors(m, buffer),
            Record::Log(_, m) => m.encode(buffer).expect(FITS),
        }
    }
}

/// The `/event` kind of a MuJoCo warning after which the physics is not the model's (the run
/// goes on; its metrics list the warning).
pub const MUJOCO_WARNING: &str = "mujoco_warning";

/// The `/event` kind of the run's first stall (the `stall_time` metric's definition), logged
/// when the stall has lasted STALL_DURATION; its message names the start.
pub const STALL_EVENT: &str = "stall";

/// The Foxglove log line of an `/event` (`/log`): level ERROR for `error`, WARNING for
/// `collision_start`, `interrupted`, `mujoco_warning` and `stall`, INFO otherwise; the message is `kind: message` (with
/// the participants and, for collisions, the depth), `name` = "mjsafe".
pub fn event_log(event: &proto::Event) -> foxglove::messages::Log {
    use foxglove::messages::log::Level;
    let level = match event.kind.as_str() {
        "error" => Level::Error,
        "collision_start" | "interrupted" | MUJOCO_WARNING | STALL_EVENT => Level::Warning,
        _ => Level::Info,
    };
    let mut message = format!("{}: {}", event.kind, event.message);
    if !event.participants.is_empty() {
        message.push_str(&format!(" [{}]", event.participants.join(", ")));
    }
    if event.kind.starts_with("collision") {
        message.push_str(&format!(" (depth {:.3} m)", event.depth));
    }
    let ns = mcap::sim_time_ns(event.time);
    foxglove::messages::Log {
        timestamp: Some(foxglove::messages::Timestamp::new(
            (ns / 1_000_000_000) as u32,
            (ns % 1_000_000_000) as u32,
        )),
        level: level as i32,
        message,
        name: "mjsafe".into(),
        file: String::new(),
        line: 0,
    }
}

/// The run metadata key of a requirement's formula: `requirement.<name>`.
pub const REQUIREMENT_METADATA_PREFIX: &str = "requirement.";

/// Run-level facts stored once in the log's metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct RunInfo {
    pub scenario_name: String,
    pub scenario_path: String,
    /// The scenario file as written.
    pub scenario_text: String,
    /// The effective scenario after overrides, as TOML.
    pub scenario_resolved: String,
    pub overrides: Vec<String>,
    pub mujoco_version: String,
    pub timestep: f64,
    pub control_period: f64,
    /// T of a prescribed-time scenario (for the metrics at T).
    pub prescribed_time: Option<f64>,
    /// The longest input delay over the run (for delay-attributed violations).
    pub max_delay: f64,
    /// Where the state holds the planar position and the heading, as the vehicle declares
    /// them (`Dynamics::planar_position`, `heading_index`); None for non-planar systems.
    pub planar_position: Option<[usize; 2]>,
    pub heading_index: Option<usize>,
    /// Whether the controller predicts (a predictor runs at its ticks): without, the log's
    /// `/prediction` topic is empty, and a copy that drops the empty channel lost nothing.
    pub predicts: bool,
    /// The kinds the run is made of (filter, nominal, vehicle) as their registrations describe
    /// them: metadata `<role>_kind`, `<role>_label`, `<role>_description`.
    pub kinds: Vec<KindInfo>,
    /// The scenario's `[goal]`: metadata `goal_position` ("x y") and `goal_radius`, or
    /// `goal_polygons` (JSON), or `goal_region` = "none" (a goal of conditions alone), and
    /// `goal_after`, `goal_by`, `goal_offset`, `goal_speed`, `goal_heading` ("lo hi"), and
    /// `goal_states` (JSON: the goal states, any one of which reaches it).
    pub goal: Option<crate::scenario::GoalSpec>,
    /// The scenario's `[vehicle_limits]`, the largest |u| per channel the vehicle takes:
    /// metadata `vehicle_limits` (JSON, absent when none is declared).
    pub vehicle_limits: BTreeMap<String, f64>,
    /// The scenario's `[[requirements]]` (name, formula): metadata `requirement.<name>`.
    pub requirements: Vec<(String, String)>,
    /// The nominal's straight reference path (point, heading): metadata `reference_path`
    /// ("x y heading").
    pub reference_path: Option<([f64; 2], f64)>,
    /// With road users (`/actors`), or a footprint among static obstacles: the vehicle's extent about its planar position along its
    /// heading, [front, rear, half width] (m; metadata `vehicle_extent` "front rear half_width"),
    /// and each road user's [length, width] (m; a circle's: its diameter twice; metadata
    /// `actor_extents`, JSON), for the headway metrics.
    pub extents: Option<Extents>,
}

/// The extents the headway metrics need ([`RunInfo::extents`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Extents {
    /// The vehicle's [front, rear, half width] about its planar position along its heading (m).
    pub vehicle: [f64; 3],
    /// Each road user's [length, width] (m).
    pub actors: BTreeMap<String, [f64; 2]>,
}

/// A kind of the run as its registration describes it (`registry::Description`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KindInfo {
    /// `filter`, `nominal` or `vehicle`.
    pub role: String,
    pub kind: String,
    /// The label legends and tables show, with its equation number.
    pub label: String,
    pub description: String,
}

impl RunInfo {
    /// The run metadata record's entries ([`read::RUN_METADATA`]): what every reader of a run
    /// learns before its first message (the MCAP log's record, and what an in-memory analysis
    /// is given the same way).
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let indices = |list: &[usize]| list.iter().map(usize::to_string).collect::<Vec<_>>().join(" ");
        let mut metadata = BTreeMap::from([
            ("mjsafe_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("log_format_version".to_string(), LOG_FORMAT_VERSION.to_string()),
            ("mujoco_version".to_string(), self.mujoco_version.clone()),
            ("scenario_name".to_string(), self.scenario_name.clone()),
            ("scenario_path".to_string(), self.scenario_path.clone()),
            ("scenario".to_string(), self.scenario_text.clone()),
            ("scenario_resolved".to_string(), self.scenario_resolved.clone()),
            ("overrides".to_string(), self.overrides.join("\n")),
            ("timestep".to_string(), format!("{}", self.timestep)),
            ("control_period".to_string(), format!("{}", self.control_period)),
            ("max_delay".to_string(), format!("{}", self.max_delay)),
            ("predicts".to_string(), self.predicts.to_string()),
            (
                "planar_position".to_string(),
                self.planar_position.map_or(String::new(), |p| indices(&p)),
            ),
            (
                "heading_index".to_string(),
                self.heading_index.map_or(String::new(), |h| indices(&[h])),
            ),
        ]);
        if let Some(t) = self.prescribed_time {
            metadata.insert("prescribed_time".to_string(), format!("{t}"));
        }
        if let Some(goal) = &self.goal {
            if let (Some([x, y]), Some(radius)) = (goal.position, goal.radius) {
                metadata.insert("goal_position".to_string(), format!("{x} {y}"));
                metadata.insert("goal_radius".to_string(), format!("{radius}"));
            }
            if !goal.polygons.is_empty() {
                let polygons = serde_json::to_string(&goal.polygons).unwrap_or_default();
                metadata.insert("goal_polygons".to_string(), polygons);
            }
            if goal.position.is_none() && goal.polygons.is_empty() {
                metadata.insert("goal_region".to_string(), "none".to_string());
            }
            if let Some(after) = goal.after {
                metadata.insert("goal_after".to_string(), format!("{after}"));
            }
            if let Some(offset) = goal.offset {
                metadata.insert("goal_offset".to_string(), format!("{offset}"));
            }
            if let Some([lo, hi]) = goal.speed {
                metadata.insert("goal_speed".to_string(), format!("{lo} {hi}"));
            }
            if let Some([lo, hi]) = goal.heading {
                metadata.insert("goal_heading".to_string(), format!("{lo} {hi}"));
            }
            if let Some(by) = goal.by {
                metadata.insert("goal_by".to_string(), format!("{by}"));
            }
            if !goal.states.is_empty() {
                let states = serde_json::to_string(&goal.states).unwrap_or_default();
                metadata.insert("goal_states".to_string(), states);
            }
        }
        if !self.vehicle_limits.is_empty() {
            let limits = serde_json::to_string(&self.vehicle_limits).unwrap_or_default();
            metadata.insert("vehicle_limits".to_string(), limits);
        }
        if let Some(([x, y], heading)) = self.reference_path {
            metadata.insert("reference_path".to_string(), format!("{x} {y} {heading}"));
        }
        if let Some(Extents {
            vehicle: [front, rear, half_width],
            actors,
        }) = &self.extents
        {
            metadata.insert("vehicle_extent".to_string(), format!("{front} {rear} {half_width}"));
            let actors = serde_json::to_string(actors).unwrap_or_default();
            metadata.insert("actor_extents".to_string(), actors);
        }
        for (name, formula) in &self.requirements {
            metadata.insert(format!("{REQUIREMENT_METADATA_PREFIX}{name}"), formula.clone());
        }
        for k in &self.kinds {
            metadata.insert(format!("{}_kind", k.role), k.kind.clone());
            metadata.insert(format!("{}_label", k.role), k.label.clone());
            metadata.insert(format!("{}_description", k.role), k.description.clone());
        }
        metadata
    }
}

/// The status metadata record's entries ([`read::STATUS_METADATA`]), written when a run ends.
pub fn status_metadata(complete: bool) -> BTreeMap<String, String> {
    BTreeMap::from([("complete".to_string(), complete.to_string())])
}

#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("{path}: {message}")]
    Write { path: String, message: String },
    #[error(transparent)]
    Output(#[from] crate::files::FileError),
}

/// Something that observes an episode.
pub trait Sink {
    fn record(&mut self, record: &Record) -> Result<(), LogError>;
    /// Completes the output; `complete` is false when the episode stopped early.
    fn finish(&mut self, complete: bool) -> Result<(), LogError>;
}

/// A borrowed sink is a sink (a caller's sinks joining a run: `Prepared::run` of the run path).
impl<S: Sink + ?Sized> Sink for &mut S {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        (**self).record(record)
    }
    fn finish(&mut self, complete: bool) -> Result<(), LogError> {
        (**self).finish(complete)
    }
}

/// The outputs of a run: the log of record (the MCAP sink) and further sinks (rerun). A
/// further sink that fails stops the run: the log gets an `/event` error naming the failure
/// and is finished as incomplete. The further sinks are finished first, so a failure at their
/// end also marks the log incomplete. A failed sink is dropped unfinished (a saved recording
/// is then deleted, see [`Sink`] implementations).
pub struct Tee<'l, 'a> {
    log: &'l mut dyn Sink,
    others: Vec<Box<dyn Sink + 'a>>,
    /// Time of the last record (of the error event).
    time: f64,
    failed: bool,
}

impl<'l, 'a> Tee<'l, 'a> {
    pub fn new(log: &'l mut dyn Sink, others: Vec<Box<dyn Sink + 'a>>) -> Tee<'l, 'a> {
        Tee {
            log,
            others,
            time: 0.0,
            failed: false,
        }
    }

    /// Whether a further sink failed (and the log was marked incomplete because of it).
    pub fn other_failed(&self) -> bool {
        self.failed
    }

    /// The further sinks still running (a failed one was dropped) and the time of the last
    /// record, to go on with a later `Tee` ([`Tee::resume`]).
    pub fn into_parts(self) -> (Vec<Box<dyn Sink + 'a>>, f64) {
        (self.others, self.time)
    }

    /// A `Tee` going on from [`Tee::into_parts`] of an earlier one.
    pub fn resume(log: &'l mut dyn Sink, (others, time): (Vec<Box<dyn Sink + 'a>>, f64)) -> Tee<'l, 'a> {
        Tee {
            time,
            ..Tee::new(log, others)
        }
    }

    /// Logs the failure of a further sink as an error event (the log's own failure, if any,
    /// surfaces when it is finished).
    fn log_failure(&mut self, error: &LogError) {
        self.failed = true;
        let _ = self.log.record(&Record::Event(proto::Event {
            time: self.time,
            kind: "error".into(),
            message: format!("{error}; the run stopped"),
            participants: Vec::new(),
            depth: 0.0,
        }));
    }
}

impl Sink for Tee<'_, '_> {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        self.log.record(record)?;
        self.time = record.time();
        for i in 0..self.others.len() {
            if let Err(e) = self.others[i].record(record) {
                drop(self.others.remove(i));
                self.log_failure(&e);
                return Err(e);
            }
        }
        Ok(())
    }

    fn finish(&mut self, complete: bool) -> Result<(), LogError> {
        let mut failure = None;
        for mut other in std::mem::take(&mut self.others) {
            if let Err(e) = other.finish(complete) {
                failure.get_or_insert(e);
            }
        }
        match failure {
            None => self.log.finish(complete),
            Some(e) => {
                self.log_failure(&e);
                let _ = self.log.finish(false);
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keeps what it is given; fails its `fail_at`-th record (1-based) or its finish.
    #[derive(Default)]
    struct Probe {
        records: Vec<Record>,
        finished: Option<bool>,
        fail_at: Option<usize>,
        fail_finish: bool,
    }

    impl Sink for Probe {
        fn record(&mut self, record: &Record) -> Result<(), LogError> {
            self.records.push(record.clone());
            if self.fail_at == Some(self.records.len()) {
                return Err(LogError::Write {
                    path: "x.rrd".into(),
                    message: "disk full".into(),
                });
            }
            Ok(())
        }

        fn finish(&mut self, complete: bool) -> Result<(), LogError> {
            self.finished = Some(complete);
            if self.fail_finish {
                return Err(LogError::Write {
                    path: "x.rrd".into(),
                    message: "cannot close".into(),
                });
            }
            Ok(())
        }
    }

    fn state(time: f64) -> Record {
        Record::State(proto::State {
            time,
            ..Default::default()
        })
    }

    fn error_events(records: &[Record]) -> Vec<String> {
        records
            .iter()
            .filter_map(|r| match r {
                Record::Event(e) if e.kind == "error" => Some(e.message.clone()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn tee_passes_records_through_and_finishes_the_log_last() {
        let mut log = Probe::default();
        let mut tee = Tee::new(&mut log, vec![Box::new(Probe::default())]);
        tee.record(&state(0.0)).unwrap();
        tee.finish(true).unwrap();
        assert!(!tee.other_failed());
        drop(tee);
        assert_eq!((log.records.len(), log.finished), (1, Some(true)));
    }

    #[test]
    fn a_failing_other_sink_marks_the_log_incomplete_with_an_error_event() {
        // Fails at its second record: the run stops, the log holds the error at that time.
        let mut log = Probe::default();
        let other = Probe {
            fail_at: Some(2),
            ..Default::default()
        };
        let mut tee = Tee::new(&mut log, vec![Box::new(other)]);
        tee.record(&state(0.0)).unwrap();
        let e = tee.record(&state(0.5)).unwrap_err();
        assert!(e.to_string().contains("disk full"));
        tee.finish(false).unwrap();
        assert!(tee.other_failed());
        drop(tee);
        assert_eq!(log.finished, Some(false));
        assert_eq!(error_events(&log.records), ["x.rrd: disk full; the run stopped"]);
        assert_eq!(log.records.last().unwrap().time(), 0.5);

        // Fails when finished: the log of a complete run is still marked incomplete.
        let mut log = Probe::default();
        let other = Probe {
            fail_finish: true,
            ..Default::default()
        };
        let mut tee = Tee::new(&mut log, vec![Box::new(other)]);
        tee.record(&state(0.0)).unwrap();
        assert!(tee.finish(true).unwrap_err().to_string().contains("cannot close"));
        drop(tee);
        assert_eq!(log.finished, Some(false));
        assert_eq!(error_events(&log.records).len(), 1);
    }
}
