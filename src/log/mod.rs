//! Log sinks. The episode emits [`Record`]s; sinks only observe them (nothing logged feeds
//! back into the simulation). The MCAP sink is the file format of record; rerun comes later
//! as a second sink.

pub mod mcap;
pub mod mcap_writer;
#[cfg(feature = "rerun")]
pub mod rerun;
pub mod scene;

/// The protobuf messages of the log (generated from proto/mjsafe.proto by build.rs).
pub mod proto {
    include!(concat!(env!("OUT_DIR"), "/mjsafe.rs"));
}

/// Serialized `FileDescriptorSet` of proto/mjsafe.proto, embedded as each channel's schema.
pub const DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/mjsafe_descriptor.bin"));

/// Schema version of the log contract in docs/log-format.md.
pub const LOG_FORMAT_VERSION: &str = "1";

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
}

/// Topic, protobuf full name of the message type.
pub const TOPICS: [(&str, &str); 9] = [
    ("/state", "mjsafe.State"),
    ("/command/issued", "mjsafe.IssuedCommand"),
    ("/command/applied", "mjsafe.AppliedCommand"),
    ("/barrier", "mjsafe.Barrier"),
    ("/filter", "mjsafe.Filter"),
    ("/event", "mjsafe.Event"),
    ("/prediction", "mjsafe.Prediction"),
    ("/scene", "foxglove.SceneUpdate"),
    ("/tf", "foxglove.FrameTransform"),
];

/// The schema data (a serialized FileDescriptorSet) of a topic in [`TOPICS`].
pub fn schema_data(topic_index: usize) -> std::borrow::Cow<'static, [u8]> {
    use foxglove::Encode;
    match TOPICS[topic_index].0 {
        "/scene" => {
            foxglove::messages::SceneUpdate::get_schema()
                .expect("Foxglove schemas are embedded")
                .data
        }
        "/tf" => {
            foxglove::messages::FrameTransform::get_schema()
                .expect("Foxglove schemas are embedded")
                .data
        }
        _ => std::borrow::Cow::Borrowed(DESCRIPTOR_SET),
    }
}

impl Record {
    /// Index into [`TOPICS`].
    pub fn topic_index(&self) -> usize {
        match self {
            Record::State(_) => 0,
            Record::Issued(_) => 1,
            Record::Applied(_) => 2,
            Record::Barrier(_) => 3,
            Record::Filter(_) => 4,
            Record::Event(_) => 5,
            Record::Prediction(_) => 6,
            Record::Scene(..) => 7,
            Record::Transform(..) => 8,
        }
    }

    pub fn topic(&self) -> &'static str {
        TOPICS[self.topic_index()].0
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
            Record::Scene(t, _) | Record::Transform(t, _) => *t,
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut buffer = Vec::new();
        self.encode_into(&mut buffer);
        buffer
    }

    /// buffer ← the protobuf encoding (reusing the buffer's allocation).
    pub fn encode_into(&self, buffer: &mut Vec<u8>) {
        use prost::Message;
        buffer.clear();
        let result = match self {
            Record::State(m) => m.encode(buffer),
            Record::Issued(m) => m.encode(buffer),
            Record::Applied(m) => m.encode(buffer),
            Record::Barrier(m) => m.encode(buffer),
            Record::Filter(m) => m.encode(buffer),
            Record::Event(m) => m.encode(buffer),
            Record::Prediction(m) => m.encode(buffer),
            Record::Scene(_, m) => m.encode(buffer),
            Record::Transform(_, m) => m.encode(buffer),
        };
        result.expect("a Vec grows to fit any message");
    }
}

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
}

#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("log file {path}: {message}")]
    Write { path: String, message: String },
}

/// Something that observes an episode.
pub trait Sink {
    fn record(&mut self, record: &Record) -> Result<(), LogError>;
    /// Completes the output; `complete` is false when the episode stopped early.
    fn finish(&mut self, complete: bool) -> Result<(), LogError>;
}
