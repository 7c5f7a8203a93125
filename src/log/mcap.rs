//! MCAP sink: one file per run, protobuf messages with their schema embedded, zstd chunks
//! (written by [`McapWriter`]), log time = simulation time, written single-threaded so equal
//! runs give equal bytes.
//! The file is written as `<path>.partial` and renamed when finished, so a log under its
//! final name is always complete and readable.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::mcap_writer::McapWriter;
use super::{LogError, Record, RunInfo, Sink, LOG_FORMAT_VERSION, TOPICS};

/// Uncompressed bytes per chunk.
const CHUNK_SIZE: usize = 1 << 20;
/// zstd level: 1 is the fastest; higher levels shrink logs by ~10% at several times the cost.
const ZSTD_LEVEL: i32 = 1;

pub struct McapSink {
    writer: Option<McapWriter<BufWriter<File>>>,
    channel_ids: Vec<u16>,
    sequence: u32,
    /// Encoding buffer reused by every record.
    buffer: Vec<u8>,
    partial_path: PathBuf,
    final_path: PathBuf,
}

/// Nanoseconds of simulation time (log and publish time of every message).
pub fn sim_time_ns(time: f64) -> u64 {
    (time.max(0.0) * 1e9).round() as u64
}

impl McapSink {
    pub fn create(path: &Path, info: &RunInfo) -> Result<McapSink, LogError> {
        let err = |message: String| LogError::Write {
            path: path.display().to_string(),
            message,
        };
        if let Some(dir) = path.parent() {
            if !dir.as_os_str().is_empty() {
                std::fs::create_dir_all(dir).map_err(|e| err(format!("cannot create directory: {e}")))?;
            }
        }
        let mut partial = path.as_os_str().to_owned();
        partial.push(".partial");
        let partial_path = PathBuf::from(partial);
        let file = File::create(&partial_path).map_err(|e| err(e.to_string()))?;
        let library = format!("mjsafe/{}", env!("CARGO_PKG_VERSION"));
        let mut writer = McapWriter::new(BufWriter::new(file), "", &library, CHUNK_SIZE, ZSTD_LEVEL)
            .map_err(|e| err(e.to_string()))?;
        let mut channel_ids = Vec::with_capacity(TOPICS.len());
        for (index, (topic, schema_name)) in TOPICS.into_iter().enumerate() {
            let schema = writer
                .add_schema(schema_name, "protobuf", &super::schema_data(index))
                .map_err(|e| err(e.to_string()))?;
            let id = writer
                .add_channel(schema, topic, "protobuf")
                .map_err(|e| err(e.to_string()))?;
            channel_ids.push(id);
        }
        let metadata = BTreeMap::from([
            ("mjsafe_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
            ("log_format_version".to_string(), LOG_FORMAT_VERSION.to_string()),
            ("mujoco_version".to_string(), info.mujoco_version.clone()),
            ("scenario_name".to_string(), info.scenario_name.clone()),
            ("scenario_path".to_string(), info.scenario_path.clone()),
            ("scenario".to_string(), info.scenario_text.clone()),
            ("scenario_resolved".to_string(), info.scenario_resolved.clone()),
            ("overrides".to_string(), info.overrides.join("\n")),
            ("timestep".to_string(), format!("{}", info.timestep)),
            ("control_period".to_string(), format!("{}", info.control_period)),
        ]);
        let mut metadata = metadata;
        metadata.insert("max_delay".to_string(), format!("{}", info.max_delay));
        if let Some(t) = info.prescribed_time {
            metadata.insert("prescribed_time".to_string(), format!("{t}"));
        }
        writer
            .write_metadata("mjsafe", &metadata.into_iter().collect::<Vec<_>>())
            .map_err(|e| err(e.to_string()))?;
        Ok(McapSink {
            writer: Some(writer),
            channel_ids,
            sequence: 0,
            buffer: Vec::new(),
            partial_path,
            final_path: path.to_path_buf(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.final_path
    }

    fn error(&self, message: String) -> LogError {
        LogError::Write {
            path: self.final_path.display().to_string(),
            message,
        }
    }
}

impl Sink for McapSink {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        let Some(writer) = self.writer.as_mut() else {
            return Err(self.error("record after finish".into()));
        };
        let time = sim_time_ns(record.time());
        self.sequence += 1;
        record.encode_into(&mut self.buffer);
        let channel = self.channel_ids[record.topic_index()];
        let result = writer.write_message(channel, self.sequence, time, &self.buffer);
        result.map_err(|e| self.error(e.to_string()))
    }

    fn finish(&mut self, complete: bool) -> Result<(), LogError> {
        let Some(mut writer) = self.writer.take() else {
            return Ok(());
        };
        let status = [(
            "complete".to_string(),
            if complete { "true" } else { "false" }.to_string(),
        )];
        writer
            .write_metadata("mjsafe_status", &status)
            .map_err(|e| self.error(e.to_string()))?;
        let out = writer.finish().map_err(|e| self.error(e.to_string()))?;
        drop(out.into_inner().map_err(|e| self.error(e.error().to_string()))?);
        std::fs::rename(&self.partial_path, &self.final_path)
            .map_err(|e| self.error(format!("cannot move the finished log into place: {e}")))
    }
}

impl Drop for McapSink {
    fn drop(&mut self) {
        // An episode that returned without finishing (a bug path) still leaves a valid file.
        if self.writer.is_some() {
            let _ = self.finish(false);
        }
    }
}
