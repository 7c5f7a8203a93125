//! Metrics of a run, computed from its MCAP log alone.

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::Path;

use mcap::records::Record as McapRecord;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use prost::Message;
use serde::Deserialize;
use serde::Serialize;

use crate::log::{proto, TOPICS};

#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    #[error("{file}: cannot read: {reason}")]
    Io { file: String, reason: std::io::Error },
    #[error("{file}: not a readable MCAP file ({message})")]
    NotMcap { file: String, message: String },
    /// A CRC mismatch, a truncation or a framing error after some records were read.
    #[error("{file}: truncated or corrupt MCAP after {messages} messages: {message}")]
    Corrupt {
        file: String,
        messages: u64,
        message: String,
        /// The metrics of what was read from the chunks that passed their CRC before the damage
        /// (an mjsafe log only); not valid metrics of the run.
        partial: Option<Box<RunMetrics>>,
    },
    #[error("{file}: an MCAP file, but not an mjsafe log ({message})")]
    Foreign { file: String, message: String },
    #[error("{file}: message on {topic} does not decode as {schema}: {message}")]
    Decode {
        file: String,
        topic: String,
        schema: String,
        message: String,
    },
}

/// First collision of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Collision {
    /// Time of the first contact.
    pub time: f64,
    /// The obstacle first touched.
    pub with: String,
    /// Deepest penetration over all contacts of the run (MuJoCo contact distance), metres.
    pub depth: f64,
}

/// Prediction consistency of one channel: |p_i(t) − x(φ_i⁻¹(t))| over the run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PredictionStats {
    pub count: u64,
    pub max_error: f64,
    pub rms_error: f64,
    pub max_relative_error: f64,
    /// Predictions that continued the previous tick's trajectory (control.chain_tolerance).
    pub reused_chain: u64,
    /// Largest |p_1 − previous chain| seen at a tick (0 when never measured).
    pub max_chain_mismatch: f64,
    #[serde(skip)]
    sum_squares: f64,
}

/// Values at the prescribed time T (Ch. 5): barrier value(s) and the "soft landing" residuals.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PrescribedTimeMetrics {
    pub time: f64,
    /// min over barriers of h(x(T)).
    pub barrier: Option<f64>,
    /// |x_i(T)| per state component.
    pub state_residuals: Vec<f64>,
    /// |u(T)| (the command issued at T, max over channels).
    pub input_residual: Option<f64>,
}

/// Per-run metrics (see docs/log-format.md for the topics they come from).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunMetrics {
    pub file: String,
    pub scenario: String,
    /// Time of the last /state record.
    pub simulated_time: f64,
    /// Physics steps taken (step index of the last /state record).
    pub steps: u64,
    pub collision: Option<Collision>,
    /// Minimum of h over all barriers and steps (None without barriers).
    pub min_h: Option<f64>,
    /// Time spent with some barrier h < 0, seconds.
    pub time_h_negative: f64,
    /// Fraction of control ticks at which the filter changed the nominal input.
    pub filter_active_fraction: f64,
    pub filter_infeasible_ticks: u64,
    /// max |u − u_nom| per channel over the run.
    pub max_correction: BTreeMap<String, f64>,
    /// Prediction consistency (Definition 4.3) per channel, from /prediction.
    pub prediction: BTreeMap<String, PredictionStats>,
    /// Intervention and comfort: first control tick at which the filter changed the nominal,
    /// total time it did so, max |du/dt| of the issued input (over channels) overall and
    /// across ticks where the filter was overriding.
    pub first_override_time: Option<f64>,
    pub override_duration: f64,
    pub max_jerk: f64,
    pub max_jerk_overriding: f64,
    /// Safety: smallest clearance to any obstacle (metres; negative = overlap), smallest
    /// constant-velocity time to collision with a known obstacle, and time with h < 0 of an
    /// obstacle while the delays since it appeared were not yet compensated (within the
    /// longest delay after its appearance).
    pub min_clearance: Option<f64>,
    pub min_time_to_collision: Option<f64>,
    pub delay_attributed_violation_time: f64,
    /// Intervention: ∫‖u − u_nom‖ dt over the control ticks.
    pub intervention_integral: f64,
    /// Comfort: max |jerk| of the planar motion along and across the velocity (third
    /// differences of the positions at the control ticks; planar vehicles only).
    pub max_longitudinal_jerk: Option<f64>,
    pub max_lateral_jerk: Option<f64>,
    /// Prescribed-time runs (metadata `prescribed_time` = T): values at T.
    pub at_prescribed_time: Option<PrescribedTimeMetrics>,
    /// Whether the run finished (false: stopped by an error or interrupted).
    pub complete: bool,
    pub error: Option<String>,
}

/// Reads and analyses one log file.
/// Streams through the file: memory stays bounded by the largest chunk (and the read size),
/// whatever the log's length.
/// The result does not depend on where the run metadata sits in the data section (the MCAP
/// spec allows it anywhere): metadata written after the messages is found in a first pass and
/// given first in a second.
pub fn analyze_file(path: &Path) -> Result<RunMetrics, AnalyzeError> {
    let file = path.display().to_string();
    let open = || crate::files::open_input(path, "log");
    // No BufReader: the reader asks for large blocks itself.
    let mut analysis = Analysis::new(&file);
    let result = analysis.read(open()?).map(|_| ());
    let Some(metadata) = analysis.late_metadata.take() else {
        return analysis.conclude(result);
    };
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) || result.is_err() {
        // A pipe cannot be read twice; a damaged log reports its damage.
        analysis.late_metadata = Some(metadata);
        return analysis.conclude_stream(result);
    }
    let mut analysis = Analysis::new(&file);
    analysis.saw_mjsafe_metadata = true;
    apply_run_metadata(&mut analysis.acc, &metadata);
    let result = analysis.read(open()?).map(|_| ());
    analysis.conclude(result)
}

/// Longest record a log may declare, and longest chunk (compressed or decompressed): 64 times
/// the 1 MiB chunks our writer closes. A damaged length field beyond it is a clean error, and
/// below it the buffers grow only with the bytes actually present (see [`read_log`]), except
/// a chunk's decompression buffer, which is allocated at its declared size (at most this).
pub const RECORD_LIMIT: usize = 64 << 20;

/// Why streaming the records stopped.
pub(crate) enum StreamError {
    /// The bytes are not (or no longer) valid MCAP: a CRC mismatch, a truncation, a framing
    /// error; `any_record`: some record was read first.
    Read { any_record: bool, message: String },
    /// The visitor refused a record (and the rest of the file is intact).
    Visit(Box<AnalyzeError>),
}

/// Why a visitor of [`read_log`] stopped.
pub(crate) enum VisitError {
    /// The record does not parse: damage, as for a CRC mismatch.
    Malformed(String),
    /// The record parses but the visitor refuses it (not an mjsafe log, a sink error, …).
    Refused(AnalyzeError),
}

impl From<AnalyzeError> for VisitError {
    fn from(e: AnalyzeError) -> Self {
        VisitError::Refused(e)
    }
}

/// The one framing path of every log reader (`analyze`, `info`, `replay`, plots): feeds every
/// record of an MCAP stream, chunks opened, to `visit(opcode, record body)` in file order and
/// returns the number of bytes read.
///
/// Verified: the magic at both ends (nothing after the end), every chunk's CRC *before* any of
/// its records is visited (so a visitor never sees a record of a damaged chunk), the data
/// section CRC (at DataEnd) and the summary CRC (at the footer), and that no record or chunk
/// is longer than [`RECORD_LIMIT`]. The two section CRCs are known only at the end of their
/// sections: on damage they report, the visitor has seen the records before it. After a
/// visitor refuses a record, the rest is still read (not visited), so that damage (e.g. a
/// corrupt channel record, refused first for its schema) is reported as damage.
pub(crate) fn read_log(
    mut input: impl Read,
    mut visit: impl FnMut(u8, &[u8]) -> Result<(), VisitError>,
) -> Result<u64, StreamError> {
    let options = LinearReaderOptions::default()
        .with_prevalidate_chunk_crcs(true)
        .with_validate_data_section_crc(true)
        .with_validate_summary_section_crc(true)
        .with_check_finishes_after_end_magic(true)
        .with_record_length_limit(RECORD_LIMIT);
    let mut reader = LinearReader::new_with_options(options);
    let mut any_record = false;
    let mut bytes = 0u64;
    let mut refused: Option<AnalyzeError> = None;
    while let Some(event) = reader.next_event() {
        let event = event.map_err(|e| StreamError::Read {
            any_record,
            message: e.to_string(),
        })?;
        match event {
            LinearReadEvent::ReadRequest(_) => {
                // At most READ_SIZE at a time whatever the reader asks for: its buffer grows with
                // the bytes present, not with a length the file declares.
                let buffer = reader.insert(READ_SIZE);
                let read = read_some(&mut input, buffer).map_err(|e| StreamError::Read {
                    any_record,
                    message: e.to_string(),
                })?;
                // 0 is the end of the input: the reader reports a truncation itself.
                reader.notify_read(read);
                bytes += read as u64;
            }
            LinearReadEvent::Record { data, opcode } => {
                if refused.is_none() {
                    match visit(opcode, data) {
                        Ok(()) => {}
                        Err(VisitError::Malformed(message)) => return Err(StreamError::Read { any_record, message }),
                        Err(VisitError::Refused(e)) => refused = Some(e),
                    }
                }
                any_record = true;
            }
        }
    }
    match refused {
        Some(e) => Err(StreamError::Visit(Box::new(e))),
        None => Ok(bytes),
    }
}

/// [`read_log`] with every record parsed.
pub(crate) fn for_each_record(
    input: impl Read,
    mut visit: impl FnMut(McapRecord<'_>) -> Result<(), AnalyzeError>,
) -> Result<u64, StreamError> {
    read_log(input, |opcode, data| {
        let record = mcap::parse_record(opcode, data).map_err(|e| VisitError::Malformed(e.to_string()))?;
        Ok(visit(record)?)
    })
}

/// Indices of the planar position in a logged state, recognised by the state names of the
/// planar vehicles (bicycle: x1, x2, heading, speed; unicycle, 2D double integrator: x, y, …).
pub fn planar_position(names: &[String]) -> Option<[usize; 2]> {
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    match names.as_slice() {
        ["x1", "x2", ..] | ["x", "y", ..] if names.len() >= 3 => Some([0, 1]),
        _ => None,
    }
}

/// Analyses log bytes; `file` names them in errors.
pub fn analyze_bytes(bytes: &[u8], file: &str) -> Result<RunMetrics, AnalyzeError> {
    analyze_reader(bytes, file)
}

#[derive(Default)]
struct Accumulator {
    scenario: String,
    timestep: Option<f64>,
    last_time: f64,
    last_step: u64,
    states: u64,
    collision: Option<Collision>,
    min_h: Option<f64>,
    negative_steps: u64,
    ticks: u64,
    active_ticks: u64,
    infeasible_ticks: u64,
    max_correction: BTreeMap<String, f64>,
    prediction: BTreeMap<String, PredictionStats>,
    prescribed_time: Option<f64>,
    control_period: Option<f64>,
    first_override_time: Option<f64>,
    active_ticks_time: f64,
    /// Previous issued command (time, values, overriding) for du/dt.
    previous_command: Option<(f64, Vec<f64>)>,
    /// |du/dt| between the last two issued commands, waiting for the /filter record of the
    /// later tick (written right after it) to know whether the filter was overriding.
    pending_jerk: Option<(f64, f64)>,
    previous_overriding: bool,
    max_jerk: f64,
    max_jerk_overriding: f64,
    terminal: PrescribedTimeMetrics,
    max_delay: f64,
    min_clearance: Option<f64>,
    min_time_to_collision: Option<f64>,
    /// Appearance time per obstacle name.
    appeared: BTreeMap<String, f64>,
    delay_attributed_steps: u64,
    intervention_integral: f64,
    /// Last four planar positions (time, x, y) for the jerk, and the position indices.
    planar: Option<[usize; 2]>,
    recent_positions: std::collections::VecDeque<(f64, f64, f64)>,
    max_longitudinal_jerk: Option<f64>,
    max_lateral_jerk: Option<f64>,
    complete: Option<bool>,
    error: Option<String>,
}

/// Bytes asked of the input per read (256 KiB): large enough that system calls and the reader's
/// bookkeeping cost little per byte (1 MiB is no faster), small enough to add little memory.
const READ_SIZE: usize = 1 << 18;

/// Length of the fixed part of an MCAP Message record (channel id, sequence, log and
/// publish time) before the message data.
const MESSAGE_HEADER_LEN: usize = 2 + 4 + 8 + 8;

/// What to do with the messages of one channel (decided once, when the channel is seen).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Route {
    /// A topic that is not part of the log format: skipped.
    Ignore,
    /// A log topic with the expected schema; `Topic` says which metrics it feeds.
    Topic(Topic),
    /// A log topic with an unexpected schema: the first message on it is an error.
    WrongSchema(&'static str),
}

/// The log topics the metrics read.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Topic {
    State,
    Barrier,
    Filter,
    Issued,
    Prediction,
    Event,
    /// A log topic no metric reads (/command/applied, /scene, /tf).
    Unused,
}

struct ChannelRoute {
    topic: String,
    schema: String,
    route: Route,
}

impl ChannelRoute {
    fn new(topic: String, schema: String) -> Self {
        let route = match TOPICS.iter().find(|(t, _)| *t == topic) {
            None => Route::Ignore,
            Some((_, s)) if *s != schema => Route::WrongSchema(s),
            Some((t, _)) => Route::Topic(match *t {
                "/state" => Topic::State,
                "/barrier" => Topic::Barrier,
                "/filter" => Topic::Filter,
                "/command/issued" => Topic::Issued,
                "/prediction" => Topic::Prediction,
                "/event" => Topic::Event,
                _ => Topic::Unused,
            }),
        };
        ChannelRoute { topic, schema, route }
    }
}

/// The state of one analysis: the channels seen so far and the metrics.
struct Analysis<'f> {
    file: &'f str,
    schemas: HashMap<u16, String>,
    /// Indexed by channel id.
    channels: Vec<Option<ChannelRoute>>,
    acc: Accumulator,
    scratch: Scratch,
    messages: u64,
    saw_mjsafe_metadata: bool,
    /// The run metadata (`mjsafe` record), when it came after the first message: metrics
    /// that need it (timestep, control period, T) were accumulated without it, so the file
    /// is analysed again with it given first ([`analyze_file`]).
    late_metadata: Option<std::collections::BTreeMap<String, String>>,
}

/// Applies the run metadata (`mjsafe` record) to the accumulator.
fn apply_run_metadata(acc: &mut Accumulator, metadata: &std::collections::BTreeMap<String, String>) {
    acc.scenario = metadata.get("scenario_name").cloned().unwrap_or_default();
    acc.timestep = metadata.get("timestep").and_then(|s| s.parse().ok());
    acc.control_period = metadata.get("control_period").and_then(|s| s.parse().ok());
    acc.prescribed_time = metadata.get("prescribed_time").and_then(|s| s.parse().ok());
    acc.max_delay = metadata.get("max_delay").and_then(|s| s.parse().ok()).unwrap_or(0.0);
}

impl Analysis<'_> {
    fn record(&mut self, record: McapRecord<'_>) -> Result<(), AnalyzeError> {
        let acc = &mut self.acc;
        match record {
            McapRecord::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name);
            }
            McapRecord::Channel(c) => {
                let schema = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                let id = usize::from(c.id);
                if self.channels.len() <= id {
                    self.channels.resize_with(id + 1, || None);
                }
                self.channels[id] = Some(ChannelRoute::new(c.topic, schema));
            }
            McapRecord::Metadata(m) if m.name == "mjsafe" => {
                if self.saw_mjsafe_metadata {
                    // Given first by a second pass (or a repeated record): already applied.
                } else if self.messages > 0 {
                    self.late_metadata = Some(m.metadata.clone());
                }
                self.saw_mjsafe_metadata = true;
                apply_run_metadata(acc, &m.metadata);
            }
            McapRecord::Metadata(m) if m.name == "mjsafe_status" => {
                acc.complete = Some(m.metadata.get("complete").is_some_and(|v| v == "true"));
            }
            McapRecord::Message { header, data } => self.message(header.channel_id, &data)?,
            _ => {}
        }
        Ok(())
    }

    /// One message (its data) on channel `channel_id`.
    fn message(&mut self, channel_id: u16, data: &[u8]) -> Result<(), AnalyzeError> {
        self.messages += 1;
        let Some(Some(channel)) = self.channels.get(usize::from(channel_id)) else {
            return Ok(());
        };
        match channel.route {
            Route::Ignore | Route::Topic(Topic::Unused) => Ok(()),
            Route::Topic(topic) => self.acc.add(&mut self.scratch, topic, channel, data, self.file),
            Route::WrongSchema(expected) => Err(AnalyzeError::Foreign {
                file: self.file.into(),
                message: format!(
                    "topic {} has schema {}, expected {expected}",
                    channel.topic, channel.schema
                ),
            }),
        }
    }

    /// Every record of the stream, as [`read_log`] gives them, except that Message records,
    /// the bulk of a log, are taken apart here directly (no record parsing, no copy) and routed
    /// by channel id.
    fn read(&mut self, input: impl Read) -> Result<u64, StreamError> {
        read_log(input, |opcode, data| {
            if opcode == mcap::records::op::MESSAGE && data.len() >= MESSAGE_HEADER_LEN {
                Ok(self.message(u16::from_le_bytes([data[0], data[1]]), &data[MESSAGE_HEADER_LEN..])?)
            } else if opcode == mcap::records::op::MESSAGE_INDEX && message_index_parses(data) {
                // Not used by the metrics: skipped once known to parse.
                Ok(())
            } else {
                let record = mcap::parse_record(opcode, data).map_err(|e| VisitError::Malformed(e.to_string()))?;
                Ok(self.record(record)?)
            }
        })
    }
}

/// Analyses an MCAP stream; `file` names it in errors. On damage the error is
/// [`AnalyzeError::Corrupt`], whose `partial` metrics cover the chunks that passed their CRC.
/// A stream is read once: run metadata after the first message is an error (the metrics that
/// need it would be computed without it); [`analyze_file`] reads such a file twice instead.
pub fn analyze_reader(input: impl Read, file: &str) -> Result<RunMetrics, AnalyzeError> {
    let mut analysis = Analysis::new(file);
    let result = analysis.read(input).map(|_| ());
    analysis.conclude_stream(result)
}

impl Analysis<'_> {
    /// [`Analysis::conclude`] of a single pass: late run metadata is an error.
    fn conclude_stream(self, result: Result<(), StreamError>) -> Result<RunMetrics, AnalyzeError> {
        if self.late_metadata.is_some() && result.is_ok() {
            return Err(AnalyzeError::Foreign {
                file: self.file.into(),
                message: "the run metadata (`mjsafe`) comes after the messages, and a stream is read once: analyse the file by its path".into(),
            });
        }
        self.conclude(result)
    }
}

impl<'f> Analysis<'f> {
    fn new(file: &'f str) -> Self {
        Analysis {
            file,
            schemas: HashMap::new(),
            channels: Vec::new(),
            acc: Accumulator::default(),
            scratch: Scratch::default(),
            messages: 0,
            saw_mjsafe_metadata: false,
            late_metadata: None,
        }
    }

    /// The metrics, or the error, once the records have been read.
    fn conclude(self, result: Result<(), StreamError>) -> Result<RunMetrics, AnalyzeError> {
        let Analysis {
            file,
            acc,
            messages,
            saw_mjsafe_metadata,
            ..
        } = self;
        match result {
            Ok(()) => {}
            Err(StreamError::Visit(e)) => return Err(*e),
            Err(StreamError::Read {
                any_record: false,
                message,
            }) => {
                return Err(AnalyzeError::NotMcap {
                    file: file.into(),
                    message,
                })
            }
            Err(StreamError::Read {
                any_record: true,
                message,
            }) => {
                let partial = (saw_mjsafe_metadata && acc.states > 0).then(|| {
                    let mut m = acc.finish(file);
                    m.complete = false;
                    m.error = Some(format!("truncated or corrupt after {messages} messages: {message}"));
                    Box::new(m)
                });
                return Err(AnalyzeError::Corrupt {
                    file: file.into(),
                    messages,
                    message,
                    partial,
                });
            }
        }
        if !saw_mjsafe_metadata || acc.states == 0 {
            return Err(AnalyzeError::Foreign {
                file: file.into(),
                message: "no mjsafe metadata record or no /state messages".into(),
            });
        }
        Ok(acc.finish(file))
    }
}

/// Whether a Message Index record parses (as `mcap::parse_record` would): channel id (u16),
/// then the byte length (u32) of its 16-byte entries, all present.
fn message_index_parses(data: &[u8]) -> bool {
    match data.get(2..6) {
        Some(len) => {
            let len = u32::from_le_bytes(len.try_into().expect("4 bytes")) as usize;
            len.is_multiple_of(16) && len <= data.len() - 6
        }
        None => false,
    }
}

/// One `read` of the input, retried when interrupted (as `Read::read_exact` does).
fn read_some(input: &mut impl Read, buffer: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match input.read(buffer) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}

/// Decoding of the frequent messages into reused buffers, without allocating once the buffers
/// have their size (the channel and state names repeat from message to message).
///
/// Each `merge_*` accepts the plain encoding prost writes (known fields with their proto3 wire
/// types, packed or unpacked doubles, UTF-8 strings) and gives the message prost would decode;
/// anything else (unknown fields, other wire types, malformed bytes) makes it return `None`, and
/// the caller decodes with prost, which then gives the same message or the same error as before.
mod wire {
    use crate::log::proto;

    const VARINT: u64 = 0;
    const FIXED64: u64 = 1;
    const LEN: u64 = 2;

    struct Fields<'a> {
        buf: &'a [u8],
        pos: usize,
    }

    impl<'a> Fields<'a> {
        fn new(buf: &'a [u8]) -> Self {
            Fields { buf, pos: 0 }
        }

        fn done(&self) -> bool {
            self.pos >= self.buf.len()
        }

        /// A varint as prost reads it (at most 10 bytes, the 10th at most 1).
        fn varint(&mut self) -> Option<u64> {
            let mut value = 0u64;
            for i in 0..10 {
                let b = *self.buf.get(self.pos)?;
                self.pos += 1;
                if i == 9 && b > 1 {
                    return None;
                }
                value |= u64::from(b & 0x7f) << (7 * i);
                if b < 0x80 {
                    return Some(value);
                }
            }
            None
        }

        /// (field number, wire type) of the next field.
        fn key(&mut self) -> Option<(u64, u64)> {
            let key = self.varint()?;
            Some((key >> 3, key & 7))
        }

        fn f64(&mut self) -> Option<f64> {
            let bytes = self.buf.get(self.pos..self.pos + 8)?;
            self.pos += 8;
            Some(f64::from_le_bytes(bytes.try_into().ok()?))
        }

        fn bytes(&mut self) -> Option<&'a [u8]> {
            let len = usize::try_from(self.varint()?).ok()?;
            let end = self.pos.checked_add(len)?;
            let bytes = self.buf.get(self.pos..end)?;
            self.pos = end;
            Some(bytes)
        }

        /// Packed doubles, appended to `out`.
        fn packed_f64(&mut self, out: &mut Vec<f64>) -> Option<()> {
            let bytes = self.bytes()?;
            if bytes.len() % 8 != 0 {
                return None;
            }
            out.extend(
                bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
            );
            Some(())
        }

        /// A repeated double field (packed or not), appended to `out`.
        fn repeated_f64(&mut self, wire: u64, out: &mut Vec<f64>) -> Option<()> {
            match wire {
                LEN => self.packed_f64(out),
                FIXED64 => {
                    out.push(self.f64()?);
                    Some(())
                }
                _ => None,
            }
        }
    }

    /// Element `k` of a repeated string field := `bytes` (UTF-8, else `None`), reusing the
    /// element's buffer; an unchanged string (the usual case) is only compared.
    fn set_string(list: &mut Vec<String>, k: usize, bytes: &[u8]) -> Option<()> {
        match list.get_mut(k) {
            Some(old) => set_str(old, bytes)?,
            None => list.push(std::str::from_utf8(bytes).ok()?.to_owned()),
        }
        Some(())
    }

    fn set_str(old: &mut String, bytes: &[u8]) -> Option<()> {
        if old.as_bytes() != bytes {
            let s = std::str::from_utf8(bytes).ok()?;
            old.clear();
            old.push_str(s);
        }
        Some(())
    }

    pub(super) fn merge_state(buf: &[u8], m: &mut proto::State) -> Option<()> {
        let mut r = Fields::new(buf);
        let mut names = 0;
        m.time = 0.0;
        m.step = 0;
        m.values.clear();
        while !r.done() {
            match r.key()? {
                (1, FIXED64) => m.time = r.f64()?,
                (2, VARINT) => m.step = r.varint()?,
                (3, LEN) => {
                    set_string(&mut m.names, names, r.bytes()?)?;
                    names += 1;
                }
                (4, wire) => r.repeated_f64(wire, &mut m.values)?,
                _ => return None,
            }
        }
        m.names.truncate(names);
        Some(())
    }

    pub(super) fn merge_issued(buf: &[u8], m: &mut proto::IssuedCommand) -> Option<()> {
        let mut r = Fields::new(buf);
        let mut channels = 0;
        m.time = 0.0;
        m.nominal.clear();
        m.filtered.clear();
        while !r.done() {
            match r.key()? {
                (1, FIXED64) => m.time = r.f64()?,
                (2, LEN) => {
                    set_string(&mut m.channels, channels, r.bytes()?)?;
                    channels += 1;
                }
                (3, wire) => r.repeated_f64(wire, &mut m.nominal)?,
                (4, wire) => r.repeated_f64(wire, &mut m.filtered)?,
                _ => return None,
            }
        }
        m.channels.truncate(channels);
        Some(())
    }

    pub(super) fn merge_filter(buf: &[u8], m: &mut proto::Filter) -> Option<()> {
        let mut r = Fields::new(buf);
        let mut channels = 0;
        m.time = 0.0;
        m.active = false;
        m.correction.clear();
        m.infeasible = false;
        m.mu = 0.0;
        while !r.done() {
            match r.key()? {
                (1, FIXED64) => m.time = r.f64()?,
                (2, VARINT) => m.active = r.varint()? != 0,
                (3, LEN) => {
                    set_string(&mut m.channels, channels, r.bytes()?)?;
                    channels += 1;
                }
                (4, wire) => r.repeated_f64(wire, &mut m.correction)?,
                (5, VARINT) => m.infeasible = r.varint()? != 0,
                (6, FIXED64) => m.mu = r.f64()?,
                _ => return None,
            }
        }
        m.channels.truncate(channels);
        Some(())
    }

    pub(super) fn merge_barrier(buf: &[u8], m: &mut proto::Barrier) -> Option<()> {
        let mut r = Fields::new(buf);
        let mut barriers = 0;
        m.time = 0.0;
        while !r.done() {
            match r.key()? {
                (1, FIXED64) => m.time = r.f64()?,
                (2, LEN) => {
                    let bytes = r.bytes()?;
                    if barriers == m.barriers.len() {
                        m.barriers.push(proto::BarrierValue::default());
                    }
                    merge_barrier_value(bytes, &mut m.barriers[barriers])?;
                    barriers += 1;
                }
                _ => return None,
            }
        }
        m.barriers.truncate(barriers);
        Some(())
    }

    fn merge_barrier_value(buf: &[u8], m: &mut proto::BarrierValue) -> Option<()> {
        let mut r = Fields::new(buf);
        let mut name = None;
        m.h = 0.0;
        m.constraint = 0.0;
        m.known = false;
        m.relative_degree = 0;
        m.clearance = 0.0;
        m.time_to_collision = 0.0;
        m.obstacle = false;
        while !r.done() {
            match r.key()? {
                (1, LEN) if name.is_none() => name = Some(r.bytes()?),
                (2, FIXED64) => m.h = r.f64()?,
                (3, FIXED64) => m.constraint = r.f64()?,
                (4, VARINT) => m.known = r.varint()? != 0,
                (5, VARINT) => m.relative_degree = r.varint()? as u32,
                (6, FIXED64) => m.clearance = r.f64()?,
                (7, FIXED64) => m.time_to_collision = r.f64()?,
                (8, VARINT) => m.obstacle = r.varint()? != 0,
                _ => return None,
            }
        }
        set_str(&mut m.name, name.unwrap_or(b""))?;
        Some(())
    }
}

/// Reused decoding buffers for the frequent messages (see [`wire`]).
#[derive(Default)]
struct Scratch {
    state: proto::State,
    barrier: proto::Barrier,
    filter: proto::Filter,
    issued: proto::IssuedCommand,
}

/// Decodes `data` into `m`: the allocation-free path, or prost when that declines.
fn decode_into<M: Message + Default>(
    data: &[u8],
    m: &mut M,
    fast: fn(&[u8], &mut M) -> Option<()>,
) -> Result<(), prost::DecodeError> {
    if fast(data, m).is_none() {
        *m = M::decode(data)?;
    }
    Ok(())
}

impl Accumulator {
    fn add(
        &mut self,
        scratch: &mut Scratch,
        topic: Topic,
        channel: &ChannelRoute,
        data: &[u8],
        file: &str,
    ) -> Result<(), AnalyzeError> {
        let decode_error = |e: prost::DecodeError| AnalyzeError::Decode {
            file: file.into(),
            topic: channel.topic.clone(),
            schema: channel.schema.clone(),
            message: e.to_string(),
        };
        match topic {
            Topic::State => {
                decode_into(data, &mut scratch.state, wire::merge_state).map_err(decode_error)?;
                self.add_state(&scratch.state);
            }
            Topic::Barrier => {
                decode_into(data, &mut scratch.barrier, wire::merge_barrier).map_err(decode_error)?;
                self.add_barrier(&scratch.barrier);
            }
            Topic::Filter => {
                decode_into(data, &mut scratch.filter, wire::merge_filter).map_err(decode_error)?;
                self.add_filter(&scratch.filter);
            }
            Topic::Issued => {
                decode_into(data, &mut scratch.issued, wire::merge_issued).map_err(decode_error)?;
                self.add_issued(&scratch.issued);
            }
            Topic::Prediction => self.add_prediction(proto::Prediction::decode(data).map_err(decode_error)?),
            Topic::Event => self.add_event(proto::Event::decode(data).map_err(decode_error)?),
            Topic::Unused => {}
        }
        Ok(())
    }

    fn add_state(&mut self, m: &proto::State) {
        if self.is_prescribed_time(m.time) {
            self.terminal.state_residuals = m.values.iter().map(|v| v.abs()).collect();
        }
        self.track_jerk(m);
        self.states += 1;
        self.last_time = self.last_time.max(m.time);
        self.last_step = self.last_step.max(m.step);
    }

    fn add_barrier(&mut self, m: &proto::Barrier) {
        let step_min = m.barriers.iter().map(|b| b.h).fold(f64::INFINITY, f64::min);
        if self.is_prescribed_time(m.time) && step_min.is_finite() {
            self.terminal.barrier = Some(step_min);
        }
        for b in m.barriers.iter().filter(|b| b.obstacle) {
            self.min_clearance = Some(self.min_clearance.map_or(b.clearance, |c| c.min(b.clearance)));
            if b.known && !b.time_to_collision.is_nan() {
                let ttc = b.time_to_collision;
                self.min_time_to_collision = Some(self.min_time_to_collision.map_or(ttc, |c| c.min(ttc)));
            }
        }
        let uncompensated_violation = m.barriers.iter().any(|b| {
            b.h < 0.0
                && self
                    .appeared
                    .get(&b.name)
                    .is_some_and(|t| m.time >= *t && m.time < t + self.max_delay)
        });
        self.delay_attributed_steps += u64::from(uncompensated_violation);
        if step_min.is_finite() {
            self.min_h = Some(self.min_h.map_or(step_min, |h| h.min(step_min)));
            if step_min < 0.0 {
                self.negative_steps += 1;
            }
        }
    }

    fn add_filter(&mut self, m: &proto::Filter) {
        self.ticks += 1;
        self.active_ticks += u64::from(m.active);
        if m.active {
            self.first_override_time.get_or_insert(m.time);
            self.active_ticks_time += self.control_period.unwrap_or(0.0);
        }
        if let Some((time, jerk)) = self.pending_jerk.take() {
            if (time - m.time).abs() < 1e-9 && (m.active || self.previous_overriding) {
                self.max_jerk_overriding = self.max_jerk_overriding.max(jerk);
            }
        }
        self.previous_overriding = m.active;
        self.infeasible_ticks += u64::from(m.infeasible);
        let correction = m.correction.iter().map(|c| c * c).sum::<f64>().sqrt();
        self.intervention_integral += correction * self.control_period.unwrap_or(0.0);
        for (channel, c) in m.channels.iter().zip(&m.correction) {
            match self.max_correction.get_mut(channel) {
                Some(entry) => *entry = entry.max(c.abs()),
                None => {
                    self.max_correction.insert(channel.clone(), 0.0f64.max(c.abs()));
                }
            }
        }
    }

    fn add_issued(&mut self, m: &proto::IssuedCommand) {
        if let Some((previous_time, previous)) = &self.previous_command {
            let dt = m.time - previous_time;
            if dt > 0.0 {
                let jerk = m
                    .filtered
                    .iter()
                    .zip(previous)
                    .map(|(u, p)| ((u - p) / dt).abs())
                    .fold(0.0, f64::max);
                self.max_jerk = self.max_jerk.max(jerk);
                self.pending_jerk = Some((m.time, jerk));
            }
        }
        if self.is_prescribed_time(m.time) {
            self.terminal.input_residual = m.filtered.iter().map(|u| u.abs()).reduce(f64::max);
        }
        match &mut self.previous_command {
            Some((time, previous)) => {
                *time = m.time;
                previous.clear();
                previous.extend_from_slice(&m.filtered);
            }
            None => self.previous_command = Some((m.time, m.filtered.clone())),
        }
    }

    fn add_prediction(&mut self, m: proto::Prediction) {
        let stats = self.prediction.entry(m.channel).or_default();
        stats.count += 1;
        stats.max_error = stats.max_error.max(m.error);
        stats.max_relative_error = stats.max_relative_error.max(m.relative_error);
        stats.sum_squares += m.error * m.error;
        stats.reused_chain += u64::from(m.reused_chain);
        if m.chain_mismatch.is_finite() {
            stats.max_chain_mismatch = stats.max_chain_mismatch.max(m.chain_mismatch);
        }
    }

    fn add_event(&mut self, m: proto::Event) {
        match m.kind.as_str() {
            "obstacle_appeared" => {
                for name in &m.participants {
                    self.appeared.entry(name.clone()).or_insert(m.time);
                }
            }
            "collision_start" | "collision_end" => {
                let with = m
                    .participants
                    .iter()
                    .find(|p| *p != "vehicle")
                    .cloned()
                    .unwrap_or_default();
                match self.collision.as_mut() {
                    Some(c) => c.depth = c.depth.max(m.depth),
                    None if m.kind == "collision_start" => {
                        self.collision = Some(Collision {
                            time: m.time,
                            with,
                            depth: m.depth,
                        })
                    }
                    None => {}
                }
            }
            "error" | "interrupted" if self.error.is_none() => self.error = Some(m.message),
            _ => {}
        }
    }

    /// Longitudinal and lateral jerk from the last four planar positions (x1, x2 or x, y).
    fn track_jerk(&mut self, m: &proto::State) {
        if self.planar.is_none() {
            self.planar = planar_position(&m.names);
            if self.planar.is_none() {
                return;
            }
        }
        // Sample on the control-tick grid: the commanded acceleration is piecewise constant on
        // it, so the jerk is resolved at the control period (not at the physics step).
        if let Some(period) = self.control_period {
            let ticks = m.time / period;
            if (ticks - ticks.round()).abs() > 1e-6 {
                return;
            }
        }
        let [i, j] = self.planar.expect("set above");
        self.recent_positions.push_back((m.time, m.values[i], m.values[j]));
        if self.recent_positions.len() > 4 {
            self.recent_positions.pop_front();
        }
        if self.recent_positions.len() < 4 {
            return;
        }
        let q = &self.recent_positions;
        let p = [q[0], q[1], q[2], q[3]];
        let dt = (p[3].0 - p[0].0) / 3.0;
        if dt <= 0.0 {
            return;
        }
        // Third differences → jerk; the velocity direction (central difference) splits it.
        let third = |f: fn(&(f64, f64, f64)) -> f64| f(&p[3]) - 3.0 * f(&p[2]) + 3.0 * f(&p[1]) - f(&p[0]);
        let (jx, jy) = (third(|q| q.1) / dt.powi(3), third(|q| q.2) / dt.powi(3));
        let (vx, vy) = (p[2].1 - p[1].1, p[2].2 - p[1].2);
        let speed = vx.hypot(vy);
        if speed <= 1e-12 {
            return;
        }
        let (ux, uy) = (vx / speed, vy / speed);
        let longitudinal = (jx * ux + jy * uy).abs();
        let lateral = (-jx * uy + jy * ux).abs();
        self.max_longitudinal_jerk = Some(self.max_longitudinal_jerk.map_or(longitudinal, |v| v.max(longitudinal)));
        self.max_lateral_jerk = Some(self.max_lateral_jerk.map_or(lateral, |v| v.max(lateral)));
    }

    /// Whether `time` is the prescribed time T (within half a timestep).
    fn is_prescribed_time(&self, time: f64) -> bool {
        match (self.prescribed_time, self.timestep) {
            (Some(t), Some(h)) => (time - t).abs() < 0.5 * h,
            _ => false,
        }
    }

    fn finish(self, file: &str) -> RunMetrics {
        let (max_jerk, max_jerk_overriding) = (self.max_jerk, self.max_jerk_overriding);
        let at_prescribed_time = self.prescribed_time.map(|time| PrescribedTimeMetrics {
            time,
            ..self.terminal.clone()
        });
        RunMetrics {
            file: file.into(),
            scenario: self.scenario,
            simulated_time: self.last_time,
            steps: self.last_step,
            collision: self.collision,
            min_h: self.min_h,
            time_h_negative: self.negative_steps as f64 * self.timestep.unwrap_or(0.0),
            filter_active_fraction: if self.ticks > 0 {
                self.active_ticks as f64 / self.ticks as f64
            } else {
                0.0
            },
            filter_infeasible_ticks: self.infeasible_ticks,
            max_correction: self.max_correction,
            first_override_time: self.first_override_time,
            override_duration: self.active_ticks_time,
            max_jerk,
            max_jerk_overriding,
            min_clearance: self.min_clearance,
            min_time_to_collision: self.min_time_to_collision,
            delay_attributed_violation_time: self.delay_attributed_steps as f64 * self.timestep.unwrap_or(0.0),
            intervention_integral: self.intervention_integral,
            max_longitudinal_jerk: self.max_longitudinal_jerk,
            max_lateral_jerk: self.max_lateral_jerk,
            at_prescribed_time,
            prediction: self
                .prediction
                .into_iter()
                .map(|(channel, mut stats)| {
                    stats.rms_error = (stats.sum_squares / stats.count.max(1) as f64).sqrt();
                    (channel, stats)
                })
                .collect(),
            complete: self.complete.unwrap_or(false) && self.error.is_none(),
            error: self.error,
        }
    }
}

/// Header and one row per run, as aligned text.
pub fn table(runs: &[RunMetrics]) -> String {
    let header = [
        "file",
        "scenario",
        "sim_time_s",
        "steps",
        "collision",
        "min_h",
        "t_h<0_s",
        "filter_active",
        "qp_infeasible",
        "max|u-u_nom|",
        "prediction_err_max/rms",
        "status",
    ];
    let mut rows: Vec<Vec<String>> = vec![header.iter().map(|s| s.to_string()).collect()];
    for r in runs {
        rows.push(vec![
            r.file.clone(),
            r.scenario.clone(),
            format!("{:.3}", r.simulated_time),
            r.steps.to_string(),
            r.collision
                .as_ref()
                .map_or("none".into(), |c| format!("t={:.3} {}", c.time, c.with)),
            r.min_h.map_or("-".into(), |h| format!("{h:.3}")),
            format!("{:.3}", r.time_h_negative),
            format!("{:.1}%", 100.0 * r.filter_active_fraction),
            r.filter_infeasible_ticks.to_string(),
            r.max_correction
                .iter()
                .map(|(c, v)| format!("{c}={v:.3}"))
                .collect::<Vec<_>>()
                .join(" "),
            if r.prediction.is_empty() {
                "-".to_string()
            } else {
                r.prediction
                    .iter()
                    .map(|(c, p)| format!("{c}={:.1e}/{:.1e}", p.max_error, p.rms_error))
                    .collect::<Vec<_>>()
                    .join(" ")
            },
            match (&r.error, r.complete) {
                (Some(e), _) => format!("error: {e}"),
                (None, true) => "complete".into(),
                (None, false) => "incomplete".into(),
            },
        ]);
    }
    align_columns(&rows)
}

/// Rows of cells as text with every column left-aligned to its widest cell.
pub fn align_columns<Row: AsRef<[String]>>(rows: &[Row]) -> String {
    let columns = rows.iter().map(|r| r.as_ref().len()).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.as_ref().get(c))
                .map(|cell| cell.chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    rows.iter()
        .map(|r| {
            r.as_ref()
                .iter()
                .enumerate()
                .map(|(c, cell)| format!("{cell:<width$}", width = widths[c]))
                .collect::<Vec<_>>()
                .join("  ")
                .trim_end()
                .to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// `Some(x)` for a finite x (JSON has no NaN or infinity: those are `null`, CSV leaves them empty).
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// A run's metrics as one flat record (no nesting beyond per-channel maps): the rows of
/// `analyze --csv`, `analyze --compare` and the sweep summaries. Floats that are not finite
/// are `None`. Definitions: docs/metrics.md.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatMetrics {
    pub scenario: String,
    pub simulated_time: Option<f64>,
    pub steps: u64,
    pub collision_time: Option<f64>,
    pub collision_with: Option<String>,
    pub collision_depth: Option<f64>,
    pub min_h: Option<f64>,
    pub time_h_negative: Option<f64>,
    pub filter_active_fraction: Option<f64>,
    pub filter_infeasible_ticks: u64,
    pub max_correction: BTreeMap<String, Option<f64>>,
    pub prediction_count: BTreeMap<String, u64>,
    pub prediction_max_error: BTreeMap<String, Option<f64>>,
    pub prediction_rms_error: BTreeMap<String, Option<f64>>,
    pub prediction_max_relative_error: BTreeMap<String, Option<f64>>,
    pub first_override_time: Option<f64>,
    pub override_duration: Option<f64>,
    pub max_jerk: Option<f64>,
    pub max_jerk_overriding: Option<f64>,
    pub min_clearance: Option<f64>,
    pub min_time_to_collision: Option<f64>,
    pub delay_attributed_violation_time: Option<f64>,
    pub intervention_integral: Option<f64>,
    pub max_longitudinal_jerk: Option<f64>,
    pub max_lateral_jerk: Option<f64>,
    /// The prescribed time T (Ch. 5 runs only) and the values at T.
    pub prescribed_time: Option<f64>,
    pub prescribed_time_barrier: Option<f64>,
    pub prescribed_time_input_residual: Option<f64>,
    pub prescribed_time_state_residual: Vec<Option<f64>>,
    pub complete: bool,
    pub error: Option<String>,
}

/// One value of a [`FlatMetrics`] column.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    Num(Option<f64>),
    Int(Option<u64>),
    Text(Option<String>),
    Bool(Option<bool>),
}

/// The fixed scalar columns of [`FlatMetrics`] before the per-channel groups.
const SCALAR_COLUMNS: [&str; 23] = [
    "scenario",
    "simulated_time",
    "steps",
    "collision_time",
    "collision_with",
    "collision_depth",
    "min_h",
    "time_h_negative",
    "filter_active_fraction",
    "filter_infeasible_ticks",
    "first_override_time",
    "override_duration",
    "max_jerk",
    "max_jerk_overriding",
    "min_clearance",
    "min_time_to_collision",
    "delay_attributed_violation_time",
    "intervention_integral",
    "max_longitudinal_jerk",
    "max_lateral_jerk",
    "prescribed_time",
    "prescribed_time_barrier",
    "prescribed_time_input_residual",
];

/// Per-channel column groups: a column is `<group>.<channel>` (`<group>.<state index>` for
/// the state residuals at the prescribed time).
const CHANNEL_GROUPS: [&str; 6] = [
    "max_correction",
    "prediction_count",
    "prediction_max_error",
    "prediction_rms_error",
    "prediction_max_relative_error",
    "prescribed_time_state_residual",
];

impl From<&RunMetrics> for FlatMetrics {
    fn from(m: &RunMetrics) -> FlatMetrics {
        let per_channel = |f: &dyn Fn(&PredictionStats) -> f64| {
            m.prediction
                .iter()
                .map(|(c, p)| (c.clone(), finite(f(p))))
                .collect::<BTreeMap<_, _>>()
        };
        FlatMetrics {
            scenario: m.scenario.clone(),
            simulated_time: finite(m.simulated_time),
            steps: m.steps,
            collision_time: m.collision.as_ref().and_then(|c| finite(c.time)),
            collision_with: m.collision.as_ref().map(|c| c.with.clone()),
            collision_depth: m.collision.as_ref().and_then(|c| finite(c.depth)),
            min_h: m.min_h.and_then(finite),
            time_h_negative: finite(m.time_h_negative),
            filter_active_fraction: finite(m.filter_active_fraction),
            filter_infeasible_ticks: m.filter_infeasible_ticks,
            max_correction: m.max_correction.iter().map(|(c, v)| (c.clone(), finite(*v))).collect(),
            prediction_count: m.prediction.iter().map(|(c, p)| (c.clone(), p.count)).collect(),
            prediction_max_error: per_channel(&|p| p.max_error),
            prediction_rms_error: per_channel(&|p| p.rms_error),
            prediction_max_relative_error: per_channel(&|p| p.max_relative_error),
            first_override_time: m.first_override_time.and_then(finite),
            override_duration: finite(m.override_duration),
            max_jerk: finite(m.max_jerk),
            max_jerk_overriding: finite(m.max_jerk_overriding),
            min_clearance: m.min_clearance.and_then(finite),
            min_time_to_collision: m.min_time_to_collision.and_then(finite),
            delay_attributed_violation_time: finite(m.delay_attributed_violation_time),
            intervention_integral: finite(m.intervention_integral),
            max_longitudinal_jerk: m.max_longitudinal_jerk.and_then(finite),
            max_lateral_jerk: m.max_lateral_jerk.and_then(finite),
            prescribed_time: m.at_prescribed_time.as_ref().and_then(|p| finite(p.time)),
            prescribed_time_barrier: m.at_prescribed_time.as_ref().and_then(|p| p.barrier.and_then(finite)),
            prescribed_time_input_residual: m
                .at_prescribed_time
                .as_ref()
                .and_then(|p| p.input_residual.and_then(finite)),
            prescribed_time_state_residual: m
                .at_prescribed_time
                .as_ref()
                .map_or(Vec::new(), |p| p.state_residuals.iter().map(|v| finite(*v)).collect()),
            complete: m.complete,
            error: m.error.clone(),
        }
    }
}

impl FlatMetrics {
    /// Column names covering `rows`: the scalar columns, then per group the union of the
    /// channels (sorted), then `complete` and `error`.
    pub fn columns<'a>(rows: impl IntoIterator<Item = &'a FlatMetrics> + Clone) -> Vec<String> {
        let mut names: Vec<String> = SCALAR_COLUMNS.iter().map(|s| s.to_string()).collect();
        for group in CHANNEL_GROUPS {
            if group == "prescribed_time_state_residual" {
                let n = rows
                    .clone()
                    .into_iter()
                    .map(|r| r.prescribed_time_state_residual.len())
                    .max();
                names.extend((0..n.unwrap_or(0)).map(|i| format!("{group}.{i}")));
                continue;
            }
            let channels: std::collections::BTreeSet<&String> =
                rows.clone().into_iter().flat_map(|r| r.channels(group)).collect();
            names.extend(channels.into_iter().map(|c| format!("{group}.{c}")));
        }
        names.push("complete".into());
        names.push("error".into());
        names
    }

    fn channels(&self, group: &str) -> Vec<&String> {
        match group {
            "max_correction" => self.max_correction.keys().collect(),
            "prediction_count" => self.prediction_count.keys().collect(),
            "prediction_max_error" => self.prediction_max_error.keys().collect(),
            "prediction_rms_error" => self.prediction_rms_error.keys().collect(),
            "prediction_max_relative_error" => self.prediction_max_relative_error.keys().collect(),
            _ => Vec::new(),
        }
    }

    /// The value of one column (as named by [`FlatMetrics::columns`]); a channel this run
    /// does not have is an empty cell.
    pub fn cell(&self, column: &str) -> Cell {
        match column {
            "scenario" => Cell::Text(Some(self.scenario.clone())),
            "simulated_time" => Cell::Num(self.simulated_time),
            "steps" => Cell::Int(Some(self.steps)),
            "collision_time" => Cell::Num(self.collision_time),
            "collision_with" => Cell::Text(self.collision_with.clone()),
            "collision_depth" => Cell::Num(self.collision_depth),
            "min_h" => Cell::Num(self.min_h),
            "time_h_negative" => Cell::Num(self.time_h_negative),
            "filter_active_fraction" => Cell::Num(self.filter_active_fraction),
            "filter_infeasible_ticks" => Cell::Int(Some(self.filter_infeasible_ticks)),
            "first_override_time" => Cell::Num(self.first_override_time),
            "override_duration" => Cell::Num(self.override_duration),
            "max_jerk" => Cell::Num(self.max_jerk),
            "max_jerk_overriding" => Cell::Num(self.max_jerk_overriding),
            "min_clearance" => Cell::Num(self.min_clearance),
            "min_time_to_collision" => Cell::Num(self.min_time_to_collision),
            "delay_attributed_violation_time" => Cell::Num(self.delay_attributed_violation_time),
            "intervention_integral" => Cell::Num(self.intervention_integral),
            "max_longitudinal_jerk" => Cell::Num(self.max_longitudinal_jerk),
            "max_lateral_jerk" => Cell::Num(self.max_lateral_jerk),
            "prescribed_time" => Cell::Num(self.prescribed_time),
            "prescribed_time_barrier" => Cell::Num(self.prescribed_time_barrier),
            "prescribed_time_input_residual" => Cell::Num(self.prescribed_time_input_residual),
            "complete" => Cell::Bool(Some(self.complete)),
            "error" => Cell::Text(self.error.clone()),
            _ => {
                let Some((group, channel)) = column.split_once('.') else {
                    return Cell::Text(None);
                };
                let num = |m: &BTreeMap<String, Option<f64>>| Cell::Num(m.get(channel).copied().flatten());
                match group {
                    "max_correction" => num(&self.max_correction),
                    "prediction_count" => Cell::Int(self.prediction_count.get(channel).copied()),
                    "prediction_max_error" => num(&self.prediction_max_error),
                    "prediction_rms_error" => num(&self.prediction_rms_error),
                    "prediction_max_relative_error" => num(&self.prediction_max_relative_error),
                    "prescribed_time_state_residual" => Cell::Num(
                        channel
                            .parse::<usize>()
                            .ok()
                            .and_then(|i| self.prescribed_time_state_residual.get(i).copied().flatten()),
                    ),
                    _ => Cell::Text(None),
                }
            }
        }
    }
}

impl Cell {
    /// The CSV text: floats in Rust's shortest round-trip form (`0.1`, `1e-15`), empty for none.
    pub fn csv(&self) -> String {
        match self {
            Cell::Num(v) => v.map_or(String::new(), |x| format!("{x:?}")),
            Cell::Int(v) => v.map_or(String::new(), |x| x.to_string()),
            Cell::Text(v) => v.clone().unwrap_or_default(),
            Cell::Bool(v) => v.map_or(String::new(), |b| b.to_string()),
        }
    }

    /// Short human-readable text for aligned tables (`-` for none).
    pub fn display(&self) -> String {
        match self {
            Cell::Num(Some(x)) => short_number(*x),
            Cell::Num(None) | Cell::Int(None) | Cell::Text(None) | Cell::Bool(None) => "-".into(),
            _ => self.csv(),
        }
    }

    /// The value as JSON (`null` for none).
    pub fn json(&self) -> serde_json::Value {
        match self {
            Cell::Num(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Int(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Text(v) => v.clone().map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Bool(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
        }
    }

    /// `other − self` for numbers; for text and flags `same` or `differs`; `None` when
    /// either side is missing.
    pub fn difference(&self, other: &Cell) -> Option<Cell> {
        match (self, other) {
            (Cell::Num(Some(a)), Cell::Num(Some(b))) => Some(Cell::Num(finite(b - a))),
            (Cell::Int(Some(a)), Cell::Int(Some(b))) => Some(Cell::Num(Some(*b as f64 - *a as f64))),
            (Cell::Num(None), Cell::Num(None))
            | (Cell::Int(None), Cell::Int(None))
            | (Cell::Text(None), Cell::Text(None))
            | (Cell::Bool(None), Cell::Bool(None)) => Some(Cell::Text(Some("same".into()))),
            (Cell::Text(a), Cell::Text(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            (Cell::Bool(a), Cell::Bool(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            _ => None,
        }
    }
}

/// A number in at most 6 significant digits, without trailing zeros.
fn short_number(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        let decimals = (5 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{x:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{x:.3e}")
    }
}

/// One CSV field, quoted when it holds a comma, quote or line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// Lines of CSV fields joined, ending with a newline.
pub fn csv_lines(rows: &[Vec<String>]) -> String {
    rows.iter()
        .map(|r| r.iter().map(|f| csv_field(f)).collect::<Vec<_>>().join(",") + "\n")
        .collect()
}

/// `analyze --csv`: one row per run, `file` then every [`FlatMetrics`] column.
pub fn csv(runs: &[RunMetrics]) -> String {
    let flat: Vec<FlatMetrics> = runs.iter().map(FlatMetrics::from).collect();
    let columns = FlatMetrics::columns(&flat);
    let mut rows = vec![std::iter::once("file".to_string())
        .chain(columns.iter().cloned())
        .collect()];
    for (run, f) in runs.iter().zip(&flat) {
        rows.push(
            std::iter::once(run.file.clone())
                .chain(columns.iter().map(|c| f.cell(c).csv()))
                .collect(),
        );
    }
    csv_lines(&rows)
}

/// One line of a comparison: a metric and its values in runs A and B.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub metric: String,
    pub a: Cell,
    pub b: Cell,
    /// B − A for numbers, `same`/`differs` otherwise; `None` when one side lacks the metric.
    pub difference: Option<Cell>,
}

/// `analyze --compare A B`: every metric of either run, side by side.
pub fn compare(a: &RunMetrics, b: &RunMetrics) -> Vec<Comparison> {
    let (fa, fb) = (FlatMetrics::from(a), FlatMetrics::from(b));
    FlatMetrics::columns([&fa, &fb])
        .into_iter()
        .map(|metric| {
            let (ca, cb) = (fa.cell(&metric), fb.cell(&metric));
            let difference = ca.difference(&cb);
            Comparison {
                metric,
                a: ca,
                b: cb,
                difference,
            }
        })
        .collect()
}

/// A comparison as aligned text: header `metric  A  B  B-A`.
pub fn comparison_table(rows: &[Comparison]) -> String {
    let mut cells: Vec<[String; 4]> = vec![["metric".into(), "A".into(), "B".into(), "B-A".into()]];
    for r in rows {
        cells.push([
            r.metric.clone(),
            r.a.display(),
            r.b.display(),
            r.difference.as_ref().map_or("-".into(), Cell::display),
        ]);
    }
    align_columns(&cells)
}

/// A comparison as CSV: `metric,a,b,difference`.
pub fn comparison_csv(rows: &[Comparison]) -> String {
    let mut lines = vec![vec!["metric".to_string(), "a".into(), "b".into(), "difference".into()]];
    for r in rows {
        lines.push(vec![
            r.metric.clone(),
            r.a.csv(),
            r.b.csv(),
            r.difference.as_ref().map_or(String::new(), Cell::csv),
        ]);
    }
    csv_lines(&lines)
}

/// A comparison as JSON: `[{metric, a, b, difference}, …]`.
pub fn comparison_json(rows: &[Comparison]) -> serde_json::Value {
    serde_json::Value::Array(
        rows.iter()
            .map(|r| {
                serde_json::json!({
                    "metric": r.metric,
                    "a": r.a.json(),
                    "b": r.b.json(),
                    "difference": r.difference.as_ref().map_or(serde_json::Value::Null, Cell::json),
                })
            })
            .collect(),
    )
}

/// One channel of a log, from its summary section.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelInfo {
    pub id: u16,
    pub topic: String,
    pub schema: String,
    pub schema_encoding: String,
    pub message_encoding: String,
    pub messages: u64,
}

/// What `mjsafe info` shows: the summary section of a log and its metadata records.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogInfo {
    pub file: String,
    pub bytes: u64,
    pub messages: u64,
    pub chunks: u32,
    /// Log time of the first and last message, seconds (simulation time in mjsafe logs).
    pub start: f64,
    pub end: f64,
    pub channels: Vec<ChannelInfo>,
    /// Metadata records by name (`mjsafe`, `mjsafe_status`), in file order.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Only from [`log_info_recover`] on a damaged log: the damage. The counts, times and
    /// channels are then those of the messages read before it (`chunks`: 0, as the chunk count
    /// is in the summary).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The records of a log [`log_info`] keeps, as they stream past.
#[derive(Default)]
struct InfoRecords {
    schemas: HashMap<u16, (String, String)>,
    channels: BTreeMap<u16, mcap::records::Channel>,
    statistics: Option<mcap::records::Statistics>,
    metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Counted from the messages read (for a damaged log, which has no usable statistics).
    counts: BTreeMap<u16, u64>,
    messages: u64,
    times: Option<(u64, u64)>,
}

impl InfoRecords {
    fn visit(&mut self, opcode: u8, data: &[u8]) -> Result<(), VisitError> {
        if opcode == mcap::records::op::MESSAGE && data.len() >= MESSAGE_HEADER_LEN {
            let channel = u16::from_le_bytes([data[0], data[1]]);
            let time = u64::from_le_bytes(data[6..14].try_into().expect("8 bytes"));
            *self.counts.entry(channel).or_default() += 1;
            self.messages += 1;
            self.times = Some(self.times.map_or((time, time), |(a, b)| (a.min(time), b.max(time))));
            return Ok(());
        }
        if opcode == mcap::records::op::MESSAGE_INDEX && message_index_parses(data) {
            return Ok(());
        }
        match mcap::parse_record(opcode, data).map_err(|e| VisitError::Malformed(e.to_string()))? {
            McapRecord::Schema { header, .. } => {
                self.schemas.insert(header.id, (header.name, header.encoding));
            }
            McapRecord::Channel(c) => {
                self.channels.insert(c.id, c);
            }
            McapRecord::Statistics(s) => self.statistics = Some(s),
            McapRecord::Metadata(m) => self.metadata.push((m.name, m.metadata)),
            _ => {}
        }
        Ok(())
    }

    /// The info; from the statistics record when `counted` is false.
    fn info(self, file: String, bytes: u64, counted: bool) -> Result<LogInfo, AnalyzeError> {
        let (messages, chunks, (start, end), per_channel) = if counted {
            (self.messages, 0, self.times.unwrap_or((0, 0)), self.counts)
        } else {
            let stats = self.statistics.ok_or_else(|| AnalyzeError::Foreign {
                file: file.clone(),
                message: "the summary has no statistics record".into(),
            })?;
            let times = (stats.message_start_time, stats.message_end_time);
            (
                stats.message_count,
                stats.chunk_count,
                times,
                stats.channel_message_counts,
            )
        };
        let schemas = &self.schemas;
        let channels = self
            .channels
            .into_values()
            .map(|c| {
                let (schema, schema_encoding) = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                ChannelInfo {
                    id: c.id,
                    messages: per_channel.get(&c.id).copied().unwrap_or(0),
                    topic: c.topic,
                    schema,
                    schema_encoding,
                    message_encoding: c.message_encoding,
                }
            })
            .collect();
        Ok(LogInfo {
            file,
            bytes,
            messages,
            chunks,
            start: start as f64 * 1e-9,
            end: end as f64 * 1e-9,
            channels,
            metadata: self.metadata,
            error: None,
        })
    }
}

/// Reads a log for `info`: the info, and the damage if any (`None` for an intact log).
fn read_info(path: &Path) -> Result<(LogInfo, Option<AnalyzeError>), AnalyzeError> {
    let file = path.display().to_string();
    let input = crate::files::open_input(path, "log")?;
    let mut records = InfoRecords::default();
    match read_log(input, |opcode, data| records.visit(opcode, data)) {
        Ok(bytes) => Ok((records.info(file, bytes, false)?, None)),
        Err(StreamError::Visit(e)) => Err(*e),
        Err(StreamError::Read {
            any_record: false,
            message,
        }) => Err(AnalyzeError::NotMcap { file, message }),
        Err(StreamError::Read {
            any_record: true,
            message,
        }) => {
            let damage = AnalyzeError::Corrupt {
                file: file.clone(),
                messages: records.messages,
                message,
                partial: None,
            };
            let bytes = std::fs::metadata(path).map_or(0, |m| m.len());
            Ok((records.info(file, bytes, true)?, Some(damage)))
        }
    }
}

/// The channels, statistics and metadata records of a log, streamed (flat memory) with every
/// CRC of the file verified ([`read_log`]); any damage is an error.
pub fn log_info(path: &Path) -> Result<LogInfo, AnalyzeError> {
    match read_info(path)? {
        (info, None) => Ok(info),
        (_, Some(damage)) => Err(damage),
    }
}

/// [`log_info`] that reports a damaged log as what was read before the damage, with
/// [`LogInfo::error`] set (other errors, e.g. not an MCAP file at all, are still errors).
pub fn log_info_recover(path: &Path) -> Result<LogInfo, AnalyzeError> {
    let (mut info, damage) = read_info(path)?;
    info.error = damage.map(|e| e.to_string());
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::{proto, wire};
    use prost::Message;

    /// Messages of varied shape: empty and non-empty lists, zeros (omitted by proto3), NaN,
    /// infinities, negative zero, changing names.
    fn states() -> Vec<proto::State> {
        vec![
            proto::State {
                time: 0.5,
                step: 250,
                names: vec!["x1".into(), "x2".into(), "heading".into(), "speed".into()],
                values: vec![-20.0, 0.0, -0.0, 3.0],
            },
            proto::State::default(),
            proto::State {
                time: f64::NAN,
                step: u64::MAX,
                names: vec!["é".into()],
                values: vec![f64::INFINITY, f64::NEG_INFINITY, 1e-300],
            },
            proto::State {
                time: 1.0,
                step: 1,
                names: vec!["x1".into(), "x2".into(), "heading".into(), "speed".into()],
                values: vec![1.0, 2.0],
            },
        ]
    }

    fn same_bits(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
    }

    #[test]
    fn fast_state_decoding_matches_prost_also_when_the_message_is_reused() {
        let mut reused = proto::State::default();
        for m in states() {
            let bytes = m.encode_to_vec();
            let expected = proto::State::decode(&bytes[..]).unwrap();
            assert!(wire::merge_state(&bytes, &mut reused).is_some(), "{m:?}");
            assert_eq!(
                (reused.step, &reused.names, reused.time.to_bits()),
                (expected.step, &expected.names, expected.time.to_bits())
            );
            assert!(
                same_bits(&reused.values, &expected.values),
                "{reused:?} vs {expected:?}"
            );
        }
    }

    #[test]
    fn fast_decoding_of_the_other_per_step_messages_matches_prost() {
        let channels = vec!["steering".to_string(), "acceleration".to_string()];
        let issued = [
            proto::IssuedCommand {
                time: 2.75,
                channels: channels.clone(),
                nominal: vec![0.1, -0.2],
                filtered: vec![0.3, 0.0],
            },
            proto::IssuedCommand::default(),
        ];
        let mut reused = proto::IssuedCommand::default();
        for m in issued {
            let bytes = m.encode_to_vec();
            assert!(wire::merge_issued(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::IssuedCommand::decode(&bytes[..]).unwrap());
        }
        let filters = [
            proto::Filter {
                time: 3.0,
                active: true,
                channels: channels.clone(),
                correction: vec![0.5, -1.5],
                infeasible: true,
                mu: -0.25,
            },
            proto::Filter::default(),
        ];
        let mut reused = proto::Filter::default();
        for m in filters {
            let bytes = m.encode_to_vec();
            assert!(wire::merge_filter(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::Filter::decode(&bytes[..]).unwrap());
        }
        let barriers = [
            proto::Barrier {
                time: 4.0,
                barriers: vec![
                    proto::BarrierValue {
                        name: "obstacle_0".into(),
                        h: 12.5,
                        constraint: -3.0,
                        known: true,
                        relative_degree: 2,
                        clearance: 1.25,
                        time_to_collision: f64::INFINITY,
                        obstacle: true,
                    },
                    proto::BarrierValue {
                        name: "wall".into(),
                        ..Default::default()
                    },
                ],
            },
            proto::Barrier {
                time: 4.002,
                barriers: vec![proto::BarrierValue {
                    name: "obstacle_0".into(),
                    h: 12.0,
                    ..Default::default()
                }],
            },
        ];
        let mut reused = proto::Barrier::default();
        for m in barriers {
            let bytes = m.encode_to_vec();
            assert!(wire::merge_barrier(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::Barrier::decode(&bytes[..]).unwrap());
        }
    }

    #[test]
    fn unknown_fields_and_truncation_fall_back_to_prost() {
        let mut bytes = states()[0].encode_to_vec();
        let mut reused = proto::State::default();
        // Field 15, varint 1: not in the schema.
        bytes.extend_from_slice(&[15 << 3, 1]);
        assert!(wire::merge_state(&bytes, &mut reused).is_none());
        let bytes = states()[0].encode_to_vec();
        assert!(wire::merge_state(&bytes[..bytes.len() - 3], &mut reused).is_none());
    }
}
