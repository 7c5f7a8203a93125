//! The one reader of mjsafe logs: record framing and CRCs ([`read_log`]), the topic table
//! ([`Topic`], [`super::TOPICS`]) and message decoding ([`Record::decode`], [`Decoder`]), and
//! the run reader ([`read_run_file`], [`read_run_stream`]) that every consumer of a log goes
//! through: `analyze`, `info` (framing only), plots and the rerun replay.
//!
//! The run reader hands a [`RunVisitor`] the run metadata (`mjsafe` record) before any message,
//! wherever it sits in the file (the MCAP spec allows metadata anywhere in the data section): a
//! file whose metadata comes after its first message is read a second time with the metadata
//! given first; a stream, which is read once, is then an error. See docs/log-format.md.

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::Path;

use mcap::records::Record as McapRecord;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::{proto, wire, Record, Topic};

/// Why a log could not be read (the same errors for every reader of logs).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    #[error("{file}: not a readable MCAP file ({message})")]
    NotMcap { file: String, message: String },
    /// A CRC mismatch, a truncation or a framing error after some records were read.
    #[error("{file}: truncated or corrupt MCAP after {messages} messages: {message}")]
    Corrupt {
        file: String,
        messages: u64,
        message: String,
    },
    #[error("{file}: an MCAP file, but not an mjsafe log ({message})")]
    Foreign { file: String, message: String },
    /// A message earlier in log time than one before it, where the reader cannot reorder them.
    #[error("{file}: messages not in log-time order (one at t = {at:.6} s after one at t = {after:.6} s): {remedy}")]
    Unordered {
        file: String,
        at: f64,
        after: f64,
        remedy: &'static str,
    },
    #[error("{file}: message on {topic} does not decode as {schema}: {message}")]
    Decode {
        file: String,
        topic: String,
        schema: String,
        message: String,
    },
}

/// Longest record a log may declare, and longest chunk (compressed or decompressed): 64 times
/// the 1 MiB chunks our writer closes. A damaged length field beyond it is a clean error, and
/// below it the buffers grow only with the bytes actually present (see [`read_log`]), except
/// a chunk's decompression buffer, which is allocated at its declared size (at most this).
pub const RECORD_LIMIT: usize = 64 << 20;

/// Bytes asked of the input per read (256 KiB): large enough that system calls and the reader's
/// bookkeeping cost little per byte (1 MiB is no faster), small enough to add little memory.
const READ_SIZE: usize = 1 << 18;

/// Length of the fixed part of an MCAP Message record (channel id, sequence, log and
/// publish time) before the message data.
pub const MESSAGE_HEADER_LEN: usize = 2 + 4 + 8 + 8;

/// (channel id, log time, data) of a record `read_log` visits, when it is a Message record
/// (taken apart directly: no record parsing, no copy).
#[inline]
pub fn message_parts(opcode: u8, record: &[u8]) -> Option<(u16, u64, &[u8])> {
    if opcode != mcap::records::op::MESSAGE || record.len() < MESSAGE_HEADER_LEN {
        return None;
    }
    let channel = u16::from_le_bytes([record[0], record[1]]);
    let log_time = u64::from_le_bytes(record[6..14].try_into().expect("8 bytes"));
    Some((channel, log_time, &record[MESSAGE_HEADER_LEN..]))
}

/// Why streaming the records stopped.
pub enum StreamError {
    /// The bytes are not (or no longer) valid MCAP: a CRC mismatch, a truncation, a framing
    /// error; `any_record`: some record was read first.
    Read { any_record: bool, message: String },
    /// The visitor refused a record (and the rest of the file is intact).
    Visit(Box<ReadError>),
    /// The visitor asked to stop ([`VisitError::Stop`]); the rest was not read.
    Stopped,
}

/// Why a visitor of [`read_log`] stopped.
pub enum VisitError {
    /// The record does not parse: damage, as for a CRC mismatch.
    Malformed(String),
    /// The record parses but the visitor refuses it (not an mjsafe log, a sink error, …).
    Refused(ReadError),
    /// The visitor has what it needs: stop reading at once.
    Stop,
}

impl From<ReadError> for VisitError {
    fn from(e: ReadError) -> Self {
        VisitError::Refused(e)
    }
}

/// The framing path of every log reader (`analyze`, `info`, `replay`, plots): feeds every
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
pub fn read_log(
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
    let mut refused: Option<ReadError> = None;
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
                        Err(VisitError::Stop) => return Err(StreamError::Stopped),
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

/// Whether a Message Index record parses (as `mcap::parse_record` would): channel id (u16),
/// then the byte length (u32) of its 16-byte entries, all present.
pub fn message_index_parses(data: &[u8]) -> bool {
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

/// The planar position the vehicle declared in the run metadata (`planar_position`: "i j", or
/// empty for a vehicle that does not move in a plane): `None` when the log has no declaration
/// (written before vehicles declared it), `Some(None)` for a declared non-planar vehicle.
pub fn declared_planar_position(metadata: &BTreeMap<String, String>) -> Option<Option<[usize; 2]>> {
    let text = metadata.get("planar_position")?;
    let indices: Vec<usize> = text.split_whitespace().filter_map(|i| i.parse().ok()).collect();
    Some(match indices.as_slice() {
        [i, j] => Some([*i, *j]),
        _ => None,
    })
}

/// The planar position of a logged state: as declared (`declared`, from
/// [`declared_planar_position`]), else, for logs without the declaration, recognised by the
/// state names of the built-in planar vehicles.
pub fn planar_position_of(declared: Option<Option<[usize; 2]>>, names: &[String]) -> Option<[usize; 2]> {
    declared
        .unwrap_or_else(|| planar_position(names))
        .filter(|[i, j]| *i < names.len() && *j < names.len())
}

/// Indices of the planar position in a logged state, recognised by the state names of the
/// planar vehicles (bicycle: x1, x2, heading, speed; unicycle, 2D double integrator: x, y, …):
/// the fallback for logs written before vehicles declared it.
pub fn planar_position(names: &[String]) -> Option<[usize; 2]> {
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    match names.as_slice() {
        ["x1", "x2", ..] | ["x", "y", ..] if names.len() >= 3 => Some([0, 1]),
        _ => None,
    }
}

/// The name of the run metadata record, and of the record written when the log is finished.
pub const RUN_METADATA: &str = "mjsafe";
pub const STATUS_METADATA: &str = "mjsafe_status";

/// What a consumer of a run's log does with what the run reader finds.
pub trait RunVisitor {
    /// A metadata record. The run metadata ([`RUN_METADATA`]) comes first, before any message,
    /// and once (a repeated record is not given again).
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError>;
    /// A message on a topic of the log format, with the schema the format gives it.
    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError>;
}

/// One message of a log topic, as the run reader hands it on.
pub struct Message<'a> {
    pub topic: Topic,
    /// Log time, nanoseconds of simulation time.
    pub log_time: u64,
    /// The protobuf encoding.
    pub data: &'a [u8],
    file: &'a str,
}

impl<'a> Message<'a> {
    /// A message handed on without a file (an in-memory analysis of a running episode);
    /// `file` names its source in errors.
    pub(crate) fn new(topic: Topic, log_time: u64, data: &'a [u8], file: &'a str) -> Message<'a> {
        Message {
            topic,
            log_time,
            data,
            file,
        }
    }

    /// The decoding error of this message as a [`ReadError`].
    fn decode_error(&self, e: prost::DecodeError) -> ReadError {
        ReadError::Decode {
            file: self.file.into(),
            topic: self.topic.name().into(),
            schema: self.topic.schema().into(),
            message: e.to_string(),
        }
    }

    /// The message as the [`Record`] the episode emitted.
    pub fn record(&self) -> Result<Record, ReadError> {
        Record::decode(self.topic, self.data, self.log_time).map_err(|e| self.decode_error(e))
    }

    /// The message decoded as `M` (prost).
    pub fn decode<M: prost::Message + Default>(&self) -> Result<M, ReadError> {
        M::decode(self.data).map_err(|e| self.decode_error(e))
    }

    /// Decodes into `m`: the allocation-free path, or prost when that declines.
    fn decode_into<M: prost::Message + Default>(
        &self,
        m: &mut M,
        fast: fn(&[u8], &mut M) -> Option<()>,
    ) -> Result<(), ReadError> {
        if fast(self.data, m).is_none() {
            *m = self.decode()?;
        }
        Ok(())
    }
}

/// Reused decoding buffers for the frequent messages: decoding allocates nothing once the
/// buffers have their size (the channel and state names repeat from message to message).
#[derive(Default)]
pub struct Decoder {
    state: proto::State,
    barrier: proto::Barrier,
    filter: proto::Filter,
    issued: proto::IssuedCommand,
    prediction: proto::Prediction,
}

impl Decoder {
    pub fn state(&mut self, m: &Message<'_>) -> Result<&proto::State, ReadError> {
        m.decode_into(&mut self.state, wire::merge_state)?;
        Ok(&self.state)
    }

    pub fn barrier(&mut self, m: &Message<'_>) -> Result<&proto::Barrier, ReadError> {
        m.decode_into(&mut self.barrier, wire::merge_barrier)?;
        Ok(&self.barrier)
    }

    pub fn filter(&mut self, m: &Message<'_>) -> Result<&proto::Filter, ReadError> {
        m.decode_into(&mut self.filter, wire::merge_filter)?;
        Ok(&self.filter)
    }

    pub fn issued(&mut self, m: &Message<'_>) -> Result<&proto::IssuedCommand, ReadError> {
        m.decode_into(&mut self.issued, wire::merge_issued)?;
        Ok(&self.issued)
    }

    pub fn prediction(&mut self, m: &Message<'_>) -> Result<&proto::Prediction, ReadError> {
        m.decode_into(&mut self.prediction, wire::merge_prediction)?;
        Ok(&self.prediction)
    }
}

/// What the run reader read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunRead {
    /// Messages of the file (on any channel).
    pub messages: u64,
    /// The log topics the file has a channel for (with the expected schema), in [`Topic`] order.
    pub topics: Vec<Topic>,
}

impl RunRead {
    /// The log topics the file has no channel for (e.g. filtered out of a copy): mjsafe writes
    /// a channel for every topic but the optional ones when the log starts, also for those a
    /// run never uses.
    pub fn missing_topics(&self) -> Vec<Topic> {
        Topic::ALL
            .into_iter()
            .filter(|t| !t.is_optional() && !self.topics.contains(t))
            .collect()
    }
}

/// What a run read gave: what was read, or why it stopped (on damage, the visitor has seen the
/// messages before it; `messages` of [`ReadError::Corrupt`] counts them).
pub type RunResult = Result<RunRead, ReadError>;

/// How one channel's messages are handed on (decided once, when the channel is seen).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Route {
    /// A topic that is not part of the log format: skipped.
    Ignore,
    /// A log topic with the expected schema.
    Topic(Topic),
    /// A log topic with an unexpected schema: the first message on it is an error.
    WrongSchema(Topic),
}

struct Channel {
    topic: String,
    schema: String,
    route: Route,
}

/// One pass of the run reader over a file or stream.
struct Pass<'f> {
    file: &'f str,
    schemas: HashMap<u16, String>,
    /// Indexed by channel id.
    channels: Vec<Option<Channel>>,
    messages: u64,
    /// The run metadata was handed on (given first by a second pass, or met in file order).
    run_metadata: bool,
    /// A message came before the run metadata: messages are no longer handed on, the pass
    /// only looks for the run metadata (and stops when it finds it).
    looking_for_metadata: bool,
    /// The run metadata, found after the first message.
    late_metadata: Option<BTreeMap<String, String>>,
    /// Other metadata records met before the run metadata, handed on right after it (and
    /// dropped when a message comes first: the second pass hands them on in file order).
    held: Vec<(String, BTreeMap<String, String>)>,
    /// Messages are handed on in file order, which must be log-time order: a message earlier
    /// than the last one handed on is an error with this remedy (None: not checked, as when
    /// the messages are collected to be sorted).
    order_remedy: Option<&'static str>,
    /// Log time of the last message handed on.
    last_time: u64,
}

impl<'f> Pass<'f> {
    fn new(file: &'f str) -> Self {
        Pass {
            file,
            schemas: HashMap::new(),
            channels: Vec::new(),
            messages: 0,
            run_metadata: false,
            looking_for_metadata: false,
            late_metadata: None,
            held: Vec::new(),
            order_remedy: Some(STREAM_ORDER_REMEDY),
            last_time: 0,
        }
    }

    fn foreign(&self, message: String) -> ReadError {
        ReadError::Foreign {
            file: self.file.into(),
            message,
        }
    }

    /// Every record of the stream in file order. Message records, the bulk of a log, are taken
    /// apart here directly (no record parsing, no copy) and routed by channel id.
    fn read(&mut self, input: impl Read, visitor: &mut impl RunVisitor) -> Result<u64, StreamError> {
        read_log(input, |opcode, data| {
            if let Some((channel, log_time, body)) = message_parts(opcode, data) {
                Ok(self.message(channel, log_time, body, visitor)?)
            } else if opcode == mcap::records::op::MESSAGE_INDEX && message_index_parses(data) {
                // Not used: skipped once known to parse.
                Ok(())
            } else {
                let record = mcap::parse_record(opcode, data).map_err(|e| VisitError::Malformed(e.to_string()))?;
                self.record(record, visitor)
            }
        })
    }

    fn record(&mut self, record: McapRecord<'_>, visitor: &mut impl RunVisitor) -> Result<(), VisitError> {
        match record {
            McapRecord::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name);
            }
            McapRecord::Channel(c) => {
                let schema = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                let route = match Topic::from_name(&c.topic) {
                    None => Route::Ignore,
                    Some(t) if t.schema() != schema => Route::WrongSchema(t),
                    Some(t) => Route::Topic(t),
                };
                let id = usize::from(c.id);
                if self.channels.len() <= id {
                    self.channels.resize_with(id + 1, || None);
                }
                self.channels[id] = Some(Channel {
                    topic: c.topic,
                    schema,
                    route,
                });
            }
            McapRecord::Metadata(m) if m.name == RUN_METADATA => {
                if self.looking_for_metadata {
                    self.late_metadata = Some(m.metadata);
                    return Err(VisitError::Stop);
                }
                if !self.run_metadata {
                    self.run_metadata = true;
                    visitor.metadata(&m.name, &m.metadata)?;
                    for (name, entries) in std::mem::take(&mut self.held) {
                        visitor.metadata(&name, &entries)?;
                    }
                }
            }
            McapRecord::Metadata(m) if self.run_metadata => visitor.metadata(&m.name, &m.metadata)?,
            McapRecord::Metadata(m) if !self.looking_for_metadata => self.held.push((m.name, m.metadata)),
            _ => {}
        }
        Ok(())
    }

    /// One message (its data) on channel `channel_id`.
    fn message(
        &mut self,
        channel_id: u16,
        log_time: u64,
        data: &[u8],
        visitor: &mut impl RunVisitor,
    ) -> Result<(), ReadError> {
        self.messages += 1;
        if !self.run_metadata {
            self.looking_for_metadata = true;
            self.held.clear();
        }
        if self.looking_for_metadata {
            return Ok(());
        }
        let Some(Some(channel)) = self.channels.get(usize::from(channel_id)) else {
            return Ok(());
        };
        match channel.route {
            Route::Ignore => Ok(()),
            Route::Topic(_) if log_time < self.last_time && self.order_remedy.is_some() => Err(ReadError::Unordered {
                file: self.file.into(),
                at: log_time as f64 * 1e-9,
                after: self.last_time as f64 * 1e-9,
                remedy: self.order_remedy.unwrap_or_default(),
            }),
            Route::Topic(topic) => {
                self.last_time = log_time;
                visitor.message(&Message {
                    topic,
                    log_time,
                    data,
                    file: self.file,
                })
            }
            Route::WrongSchema(expected) => Err(self.foreign(format!(
                "topic {} has schema {}, expected {}",
                channel.topic,
                channel.schema,
                expected.schema()
            ))),
        }
    }

    /// The result of the pass once its records have been read (`Ok(None)`: it stopped at run
    /// metadata that came after the first message, now in `late_metadata`).
    fn conclude(&self, result: Result<u64, StreamError>) -> Result<Option<RunRead>, ReadError> {
        match result {
            Ok(_) => {}
            Err(StreamError::Stopped) => return Ok(None),
            Err(StreamError::Visit(e)) => return Err(*e),
            Err(StreamError::Read {
                any_record: false,
                message,
            }) => {
                return Err(ReadError::NotMcap {
                    file: self.file.into(),
                    message,
                })
            }
            Err(StreamError::Read {
                any_record: true,
                message,
            }) => {
                return Err(ReadError::Corrupt {
                    file: self.file.into(),
                    messages: self.messages,
                    message,
                })
            }
        }
        if !self.run_metadata {
            return Err(self.foreign(format!("no {RUN_METADATA} metadata record (the run metadata)")));
        }
        let mut topics: Vec<Topic> = self
            .channels
            .iter()
            .flatten()
            .filter_map(|c| match c.route {
                Route::Topic(t) => Some(t),
                _ => None,
            })
            .collect();
        topics.sort();
        topics.dedup();
        Ok(Some(RunRead {
            messages: self.messages,
            topics,
        }))
    }
}

/// Reads the log at `path` through `visitor`: the run metadata first, then every message of a
/// log topic in file order. Streams through the file: memory stays bounded by the largest chunk
/// (and the read size), whatever the log's length. A file whose run metadata comes after its
/// first message is read twice (the metadata is looked for, then given first); a pipe or device,
/// which cannot be read twice, is then an error (as for [`read_run_stream`]).
pub fn read_run_file(path: &Path, visitor: &mut impl RunVisitor) -> RunResult {
    let file = path.display().to_string();
    let regular = std::fs::metadata(path).is_ok_and(|m| m.is_file());
    if regular && !in_log_time_order(path) {
        // Handed on sorted by log time (ties in file order), as a reader in log-time order
        // gives them: the same run whatever the layout.
        let mut sorting = Sorting {
            visitor,
            arena: Vec::new(),
            messages: Vec::new(),
        };
        let result = read_run_passes(path, &file, &mut sorting, None);
        return sorting.finish(result, &file);
    }
    // A pipe or device is read once, as a stream.
    let remedy = if regular {
        INDEX_ORDER_REMEDY
    } else {
        STREAM_ORDER_REMEDY
    };
    read_run_passes(path, &file, visitor, Some(remedy))
}

/// The remedies of [`ReadError::Unordered`].
const STREAM_ORDER_REMEDY: &str = "a stream is read once and cannot be reordered: read the file by its path";
const INDEX_ORDER_REMEDY: &str = "its index says they are in order; the file is damaged";

/// [`read_run_file`] in file order: one pass, or two when the run metadata comes late.
fn read_run_passes(
    path: &Path,
    file: &str,
    visitor: &mut impl RunVisitor,
    order_remedy: Option<&'static str>,
) -> RunResult {
    let open = || crate::files::open_input(path, "log");
    // No BufReader: the reader asks for large blocks itself.
    let mut pass = Pass::new(file);
    pass.order_remedy = order_remedy;
    let result = pass.read(open()?, visitor);
    if let Some(read) = pass.conclude(result)? {
        return Ok(read);
    }
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return Err(late_in_stream(file));
    }
    let metadata = pass.late_metadata.take().expect("the pass stopped at it");
    let mut pass = Pass::new(file);
    pass.order_remedy = order_remedy;
    pass.run_metadata = true;
    visitor.metadata(RUN_METADATA, &metadata)?;
    let result = pass.read(open()?, visitor);
    Ok(pass.conclude(result)?.expect("the run metadata was given first"))
}

/// [`read_run_file`] of a stream, read once: run metadata after the first message is an error.
/// `file` names the stream in errors.
pub fn read_run_stream(input: impl Read, file: &str, visitor: &mut impl RunVisitor) -> RunResult {
    let mut pass = Pass::new(file);
    let result = pass.read(input, visitor);
    pass.conclude(result)?.ok_or_else(|| late_in_stream(file))
}

/// Collects a pass's messages and hands them on sorted by log time, the run metadata (and
/// other metadata) as they come.
struct Sorting<'v, V> {
    visitor: &'v mut V,
    /// The messages' bytes, one after the other.
    arena: Vec<u8>,
    /// (log time, topic, start in `arena`, length), in file order.
    messages: Vec<(u64, Topic, usize, usize)>,
}

impl<V: RunVisitor> RunVisitor for Sorting<'_, V> {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        self.visitor.metadata(name, entries)
    }
    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        self.messages
            .push((message.log_time, message.topic, self.arena.len(), message.data.len()));
        self.arena.extend_from_slice(message.data);
        Ok(())
    }
}

impl<V: RunVisitor> Sorting<'_, V> {
    /// Hands on the collected messages in log-time order (stable: ties keep file order), then
    /// the pass's result. Before damage the messages read are handed on, as a read in file
    /// order hands them.
    fn finish(mut self, result: RunResult, file: &str) -> RunResult {
        if matches!(result, Ok(_) | Err(ReadError::Corrupt { .. })) {
            self.messages.sort_by_key(|m| m.0);
            for &(log_time, topic, start, len) in &self.messages {
                let data = &self.arena[start..start + len];
                self.visitor.message(&Message::new(topic, log_time, data, file))?;
            }
        }
        result
    }
}

/// Whether the messages of the regular file at `path` are in log-time order in file order:
/// told by the file's index (its summary's chunk indexes and each chunk's message indexes)
/// when it has a complete one, else by reading every message's log time. A file that cannot
/// be read here counts as in order (the read in file order reports why it cannot be read).
fn in_log_time_order(path: &Path) -> bool {
    let Ok(mut file) = std::fs::File::open(path) else {
        return true;
    };
    if let Some(ordered) = indexed_log_time_order(&mut file) {
        return ordered;
    }
    let mut last = 0u64;
    let mut ordered = true;
    let _ = read_log(file, |opcode, data| {
        if let Some((_, log_time, _)) = message_parts(opcode, data) {
            if log_time < last {
                ordered = false;
                return Err(VisitError::Stop);
            }
            last = log_time;
        }
        Ok(())
    });
    ordered
}

/// `len` bytes of `file` at `offset` (None past its end or beyond [`RECORD_LIMIT`]).
fn read_at(file: &std::fs::File, offset: u64, len: u64) -> Option<Vec<u8>> {
    use std::os::unix::fs::FileExt;
    let mut bytes = vec![0; usize::try_from(len).ok().filter(|&n| n <= RECORD_LIMIT)?];
    file.read_exact_at(&mut bytes, offset).ok()?;
    Some(bytes)
}

/// The records (opcode, body) laid out one after the other in `bytes`; None when they do not
/// split into whole records.
fn records_in(mut bytes: &[u8]) -> Option<Vec<(u8, &[u8])>> {
    let mut records = Vec::new();
    while let Some(&opcode) = bytes.first() {
        let len = usize::try_from(u64::from_le_bytes(bytes.get(1..9)?.try_into().ok()?)).ok()?;
        let end = 9usize.checked_add(len)?;
        records.push((opcode, bytes.get(9..end)?));
        bytes = &bytes[end..];
    }
    Some(records)
}

/// [`in_log_time_order`] from the file's index: every chunk's message index entries, in the
/// chunks' file order and by offset within a chunk. None when the file has no summary with
/// chunk indexes, a chunk has no message indexes, or any of it does not parse.
fn indexed_log_time_order(file: &mut std::fs::File) -> Option<bool> {
    use mcap::records::{op, Record as R};
    // Footer: opcode, length, summary start, summary offset start, summary CRC; then the magic.
    const TAIL: u64 = 1 + 8 + 8 + 8 + 4 + 8;
    let len = file.metadata().ok()?.len();
    let tail = read_at(file, len.checked_sub(TAIL)?, TAIL)?;
    if tail[0] != op::FOOTER || tail[29..] != *mcap::MAGIC {
        return None;
    }
    let summary_start = u64::from_le_bytes(tail[9..17].try_into().ok()?);
    if summary_start == 0 {
        return None;
    }
    let summary = read_at(file, summary_start, (len - TAIL).checked_sub(summary_start)?)?;
    let mut chunks = Vec::new();
    for (opcode, body) in records_in(&summary)? {
        if opcode == op::CHUNK_INDEX {
            match mcap::parse_record(opcode, body).ok()? {
                R::ChunkIndex(chunk) => chunks.push(chunk),
                _ => return None,
            }
        }
    }
    if chunks.is_empty() {
        return None;
    }
    chunks.sort_by_key(|c| c.chunk_start_offset);
    let mut last = 0u64;
    let mut entries = Vec::new();
    for chunk in &chunks {
        let start = *chunk.message_index_offsets.values().min()?;
        let indexes = read_at(file, start, chunk.message_index_length)?;
        entries.clear();
        for (opcode, body) in records_in(&indexes)? {
            match mcap::parse_record(opcode, body).ok()? {
                R::MessageIndex(index) => entries.extend(index.records.iter().map(|e| (e.offset, e.log_time))),
                _ => return None,
            }
        }
        entries.sort_unstable();
        for &(_, log_time) in &entries {
            if log_time < last {
                return Some(false);
            }
            last = log_time;
        }
    }
    Some(true)
}

fn late_in_stream(file: &str) -> ReadError {
    ReadError::Foreign {
        file: file.into(),
        message: format!(
            "the run metadata (`{RUN_METADATA}`) comes after the messages, and a stream is read once: analyse the file by its path"
        ),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_declared_planar_position_rules_and_old_logs_fall_back_to_names() {
        let names = |list: &[&str]| list.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let meta = |value: &str| BTreeMap::from([("planar_position".to_string(), value.to_string())]);
        // Declared: a two-state linear system is planar, a bicycle declared otherwise is not.
        let declared = super::declared_planar_position(&meta("0 1"));
        assert_eq!(declared, Some(Some([0, 1])));
        assert_eq!(super::planar_position_of(declared, &names(&["x1", "x2"])), Some([0, 1]));
        let not_planar = super::declared_planar_position(&meta(""));
        assert_eq!(not_planar, Some(None));
        assert_eq!(
            super::planar_position_of(not_planar, &names(&["x1", "x2", "heading"])),
            None
        );
        // Indices beyond the state are ignored rather than trusted.
        assert_eq!(super::planar_position_of(Some(Some([0, 5])), &names(&["x", "y"])), None);
        // Not declared (logs written before): recognised by the names.
        let old = super::declared_planar_position(&BTreeMap::new());
        assert_eq!(old, None);
        assert_eq!(
            super::planar_position_of(old, &names(&["x", "y", "theta"])),
            Some([0, 1])
        );
        assert_eq!(super::planar_position_of(old, &names(&["position", "velocity"])), None);
    }

    use super::*;
    use crate::log::mcap_writer::McapWriter;
    use prost::Message as _;

    /// What a visitor was given, in order.
    #[derive(Default)]
    struct Seen(Vec<String>);

    impl RunVisitor for Seen {
        fn metadata(&mut self, name: &str, _: &BTreeMap<String, String>) -> Result<(), ReadError> {
            self.0.push(format!("metadata {name}"));
            Ok(())
        }

        fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
            let Record::State(m) = message.record()? else {
                panic!("only /state is logged here");
            };
            self.0.push(format!("{} {}", message.topic, m.step));
            Ok(())
        }
    }

    /// A log with one /state channel (and a foreign topic) holding `items` in order: a metadata
    /// record by name, or a /state message by step.
    fn log(items: &[&str]) -> Vec<u8> {
        let mut w = McapWriter::new(Vec::new(), "", "test", 1 << 20, 1, false).unwrap();
        let schema = w.add_schema("mjsafe.State", "protobuf", b"").unwrap();
        let state = w.add_channel(schema, "/state", "protobuf").unwrap();
        let other = w.add_channel(schema, "/elsewhere", "protobuf").unwrap();
        for (i, item) in items.iter().enumerate() {
            match item.parse::<u64>() {
                Ok(step) => {
                    let m = proto::State {
                        step,
                        ..Default::default()
                    };
                    w.write_message(state, i as u32, step, &m.encode_to_vec()).unwrap();
                    w.write_message(other, i as u32, step, b"not read").unwrap();
                }
                Err(_) => w.write_metadata(item, &[("timestep".into(), "0.01".into())]).unwrap(),
            }
        }
        w.finish().unwrap()
    }

    fn read_file(bytes: &[u8]) -> (RunResult, Vec<String>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        std::fs::write(&path, bytes).unwrap();
        let mut seen = Seen::default();
        let result = read_run_file(&path, &mut seen);
        (result, seen.0)
    }

    #[test]
    fn the_run_metadata_comes_first_wherever_it_sits_in_a_file() {
        let expected = ["metadata mjsafe", "/state 1", "/state 2", "metadata mjsafe_status"];
        for items in [
            &["mjsafe", "1", "2", "mjsafe_status"][..],
            &["1", "2", "mjsafe", "mjsafe_status"][..],
            &["1", "mjsafe", "2", "mjsafe_status"][..],
        ] {
            let (result, seen) = read_file(&log(items));
            let read = result.unwrap();
            assert_eq!(seen, expected, "{items:?}");
            assert_eq!(read.messages, 4, "every message of the file is counted");
            assert_eq!(read.topics, [Topic::State]);
            assert_eq!(
                read.missing_topics().len(),
                Topic::ALL.iter().filter(|t| !t.is_optional()).count() - 1
            );
        }
        // Metadata before the run metadata is given right after it.
        let (result, seen) = read_file(&log(&["mjsafe_status", "mjsafe", "1"]));
        result.unwrap();
        assert_eq!(seen, ["metadata mjsafe", "metadata mjsafe_status", "/state 1"]);
    }

    #[test]
    fn late_run_metadata_in_a_stream_and_no_run_metadata_are_errors() {
        let bytes = log(&["1", "mjsafe"]);
        let mut seen = Seen::default();
        let e = read_run_stream(&bytes[..], "pipe", &mut seen).unwrap_err();
        assert!(e.to_string().contains("comes after the messages"), "{e}");
        assert!(seen.0.is_empty(), "{:?}", seen.0);
        for items in [&["1", "mjsafe_status"][..], &["mjsafe_status"][..]] {
            let (result, seen) = read_file(&log(items));
            let e = result.unwrap_err();
            assert!(e.to_string().contains("no mjsafe metadata record"), "{e}");
            assert!(seen.is_empty(), "{seen:?}");
        }
    }
}
