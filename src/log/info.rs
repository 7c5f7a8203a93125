//! `mjsafe info`: the summary section and metadata records of any MCAP file (an mjsafe log or
//! not), read through the framing path of every log reader ([`read_log`]).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use mcap::records::Record as McapRecord;
use serde::Serialize;

use super::read::{message_index_parses, message_parts, read_log, ReadError, StreamError, VisitError};

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
    /// From the summary's statistics record; None without one (a damaged log, or a writer
    /// that writes no statistics), whose counts are those of the messages read.
    pub chunks: Option<u32>,
    /// Log time of the first and last message, seconds (simulation time in mjsafe logs).
    pub start: f64,
    pub end: f64,
    pub channels: Vec<ChannelInfo>,
    /// Metadata records by name (`mjsafe`, `mjsafe_status`), in file order.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Only from [`log_info_recover`] on a damaged log: the damage. The counts, times and
    /// channels are then those of the messages read before it (`chunks`: None, as the chunk
    /// count is in the summary).
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
        if let Some((channel, time, _)) = message_parts(opcode, data) {
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

    /// The info: from the statistics record when `counted` is false and the file has one,
    /// else counted from the messages read.
    fn info(self, file: String, bytes: u64, counted: bool) -> Result<LogInfo, ReadError> {
        let (messages, chunks, (start, end), per_channel) = match self.statistics {
            Some(stats) if !counted => (
                stats.message_count,
                Some(stats.chunk_count),
                (stats.message_start_time, stats.message_end_time),
                stats.channel_message_counts,
            ),
            _ => (self.messages, None, self.times.unwrap_or((0, 0)), self.counts),
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
fn read_info(path: &Path) -> Result<(LogInfo, Option<ReadError>), ReadError> {
    let file = path.display().to_string();
    let input = crate::files::open_input(path, "log")?;
    let mut records = InfoRecords::default();
    match read_log(input, |opcode, data| records.visit(opcode, data)) {
        Ok(bytes) => Ok((records.info(file, bytes, false)?, None)),
        Err(StreamError::Visit(e)) => Err(*e),
        Err(StreamError::Stopped) => unreachable!("the info visitor never stops"),
        Err(StreamError::Read {
            any_record: false,
            message,
        }) => Err(ReadError::NotMcap { file, message }),
        Err(StreamError::Read {
            any_record: true,
            message,
        }) => {
            let damage = ReadError::Corrupt {
                file: file.clone(),
                messages: records.messages,
                message,
            };
            let bytes = std::fs::metadata(path).map_or(0, |m| m.len());
            Ok((records.info(file, bytes, true)?, Some(damage)))
        }
    }
}

/// The channels, statistics and metadata records of a log, streamed (flat memory) with every
/// CRC of the file verified ([`read_log`]); any damage is an error.
pub fn log_info(path: &Path) -> Result<LogInfo, ReadError> {
    match read_info(path)? {
        (info, None) => Ok(info),
        (_, Some(damage)) => Err(damage),
    }
}

/// [`log_info`] that reports a damaged log as what was read before the damage, with
/// [`LogInfo::error`] set (other errors, e.g. not an MCAP file at all, are still errors).
pub fn log_info_recover(path: &Path) -> Result<LogInfo, ReadError> {
    let (mut info, damage) = read_info(path)?;
    info.error = damage.map(|e| e.to_string());
    Ok(info)
}
