//! MCAP sink: one file per run, protobuf messages with their schema embedded, zstd chunks
//! (written by [`McapWriter`]: messages are appended on the episode's thread, chunks compressed
//! and written in order on a writer thread), log time = simulation time, so equal runs give
//! equal bytes.
//! The file is written as `<path>.partial` (created exclusively, see [`crate::files`]) and
//! renamed when finished, so a log under its final name is always complete and readable.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use crate::files::{OutputFile, Replace};

use super::mcap_writer::{LogOutput, McapWriter};
use super::{LogError, Record, RunInfo, Sink, Topic, TOPICS};

/// The first bytes of every MCAP file: an existing file that starts otherwise is never replaced.
pub const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// Uncompressed bytes per chunk: the last chunk is compressed while the run waits to close
/// the log, so smaller chunks shorten that wait (0.5 ms at 256 KiB against 1 ms at 1 MiB, bicycle
/// log; the log grows by 0.7 %).
const CHUNK_SIZE: usize = 1 << 18;
/// zstd level: 1 is the fastest; higher levels shrink logs by ~10% at several times the cost.
const ZSTD_LEVEL: i32 = 1;

pub struct McapSink {
    writer: Option<McapWriter<BufWriter<File>>>,
    channel_ids: Vec<u16>,
    sequence: u32,
    /// The `.partial` file (and its lock) until the log is committed or abandoned.
    output: Option<OutputFile>,
    final_path: std::path::PathBuf,
    /// Time the writer thread spent compressing and writing chunks (known once finished).
    writer_busy: std::time::Duration,
    /// Whether the last message written is a scene update holding entities.
    scene_entities: bool,
}

/// Checks that `path` may receive a log, creating nothing: not an input of the run, not a
/// directory, device or other non-regular file, and not an existing file other than an MCAP
/// file (an earlier log may be replaced).
pub fn check_target(path: &Path, inputs: &[&Path]) -> Result<(), crate::files::FileError> {
    crate::files::check_output(path, "MCAP log", Replace::IfStartsWith(MCAP_MAGIC), inputs)
}

/// Nanoseconds of simulation time (log and publish time of every message).
pub fn sim_time_ns(time: f64) -> u64 {
    // `ns.round() as u64` (half away from zero, saturating) without a call into libm: below
    // 2^53 the fraction ns − ⌊ns⌋ is exact, above it every double is an integer.
    let ns = time.max(0.0) * 1e9;
    let whole = ns as u64;
    if ns - whole as f64 >= 0.5 {
        whole.saturating_add(1)
    } else {
        whole
    }
}

/// Adds `topic`'s schema and channel; returns the channel id.
fn add_channel<W: LogOutput>(writer: &mut McapWriter<W>, topic: Topic) -> std::io::Result<u16> {
    let schema = writer.add_schema(topic.schema(), "protobuf", &super::schema_data(topic as usize))?;
    writer.add_channel(schema, topic.name(), "protobuf")
}

impl McapSink {
    /// Checks `path` (see [`check_target`]) and starts the log as `<path>.partial`. `inputs`
    /// are the files the run reads (scenario, model), which the log never replaces.
    pub fn create(path: &Path, info: &RunInfo, inputs: &[&Path]) -> Result<McapSink, LogError> {
        let err = |message: String| LogError::Write {
            path: path.display().to_string(),
            message,
        };
        let output = OutputFile::create(path, "MCAP log", Replace::IfStartsWith(MCAP_MAGIC), inputs)?;
        let file = output.try_clone_file()?;
        let library = format!("mjsafe/{}", env!("CARGO_PKG_VERSION"));
        let mut writer = McapWriter::new(BufWriter::new(file), "", &library, CHUNK_SIZE, ZSTD_LEVEL, true)
            .map_err(|e| err(e.to_string()))?;
        // Every topic's channel up front, but the optional ones (added with their first message).
        let mut channel_ids = vec![0; TOPICS.len()];
        for topic in Topic::always_logged() {
            channel_ids[topic as usize] = add_channel(&mut writer, topic).map_err(|e| err(e.to_string()))?;
        }
        writer
            .write_metadata(
                super::read::RUN_METADATA,
                &info.metadata().into_iter().collect::<Vec<_>>(),
            )
            .map_err(|e| err(e.to_string()))?;
        Ok(McapSink {
            writer: Some(writer),
            channel_ids,
            sequence: 0,
            output: Some(output),
            final_path: path.to_path_buf(),
            writer_busy: std::time::Duration::ZERO,
            scene_entities: false,
        })
    }

    pub fn path(&self) -> &Path {
        &self.final_path
    }

    /// Time the writer thread spent compressing, writing and syncing chunks, once finished
    /// (work the episode's thread did not wait for; the syncs wait for the disk, not the CPU;
    /// `mjsafe bench` reports it).
    pub fn writer_busy(&self) -> std::time::Duration {
        self.writer_busy
    }

    /// Stops without finishing: the `.partial` file is deleted, nothing is left under the
    /// final name (for a run that fails before it starts, e.g. another output cannot be opened).
    pub fn abandon(mut self) {
        self.writer = None;
        self.output = None;
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
        let topic = record.topic_index();
        // The scene updates of one frame (one time, in a row) go into one message, which
        // Foxglove applies at once: its deletions first, then its entities. So a deletion
        // after an entity starts a new message (it could delete that entity).
        if let Record::Scene(_, update) = record {
            let channel = self.channel_ids[topic];
            let joinable = update.deletions.is_empty() || !self.scene_entities;
            let joined = joinable
                && writer
                    .extend_last_message(channel, time, |chunk| record.encode_append(chunk))
                    .map_err(|e| LogError::Write {
                        path: self.final_path.display().to_string(),
                        message: e.to_string(),
                    })?;
            if joined {
                self.scene_entities |= !update.entities.is_empty();
                return Ok(());
            }
            self.scene_entities = !update.entities.is_empty();
        }
        self.sequence += 1;
        let mut channel = self.channel_ids[topic];
        if channel == 0 {
            channel = add_channel(writer, record.kind()).map_err(|e| LogError::Write {
                path: self.final_path.display().to_string(),
                message: e.to_string(),
            })?;
            self.channel_ids[topic] = channel;
        }
        // Encoded straight into the writer's open chunk.
        let result = writer.write_message_with(channel, self.sequence, time, |chunk| record.encode_append(chunk));
        result.map_err(|e| self.error(e.to_string()))?;
        // Every event also as a Foxglove log line, for Foxglove's Log panel.
        if let Record::Event(event) = record {
            self.record(&Record::Log(record.time(), super::event_log(event)))?;
        }
        Ok(())
    }

    fn finish(&mut self, complete: bool) -> Result<(), LogError> {
        let Some(mut writer) = self.writer.take() else {
            return Ok(());
        };
        let status: Vec<_> = super::status_metadata(complete).into_iter().collect();
        writer
            .write_metadata(super::read::STATUS_METADATA, &status)
            .map_err(|e| self.error(e.to_string()))?;
        let (out, busy) = writer.finish_timed().map_err(|e| self.error(e.to_string()))?;
        self.writer_busy = busy;
        drop(out.into_inner().map_err(|e| self.error(e.error().to_string()))?);
        let output = self.output.take().expect("the output lives until the log is finished");
        output.commit()?;
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    fn info() -> RunInfo {
        RunInfo {
            scenario_name: "t".into(),
            scenario_path: "t.toml".into(),
            scenario_text: String::new(),
            scenario_resolved: String::new(),
            overrides: Vec::new(),
            mujoco_version: "2.2.2".into(),
            timestep: 0.01,
            control_period: 0.01,
            prescribed_time: None,
            max_delay: 0.0,
            planar_position: None,
            heading_index: None,
            predicts: false,
            kinds: Vec::new(),
            goal: None,
            vehicle_limits: std::collections::BTreeMap::new(),
            requirements: Vec::new(),
            reference_path: None,
            extents: None,
        }
    }

    #[test]
    fn sim_time_ns_rounds_as_f64_round_does() {
        let mut times = vec![
            0.0,
            -0.0,
            -1.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN_POSITIVE,
            0.5e-9,
            1.5e-9,
            2.5e-9,
        ];
        // Just below a half; around 2^52 ns (the last halves), 2^53 (the last odd integers),
        // 2^63 and 2^64 (saturation).
        let below_half = f64::from_bits(0.5f64.to_bits() - 1);
        for ns in [
            below_half,
            2f64.powi(52) - 0.5,
            2f64.powi(53) + 2.0,
            2f64.powi(63),
            2f64.powi(64),
            1e29,
        ] {
            let t = ns / 1e9;
            times.extend([t, f64::from_bits(t.to_bits() + 1), f64::from_bits(t.to_bits() - 1)]);
        }
        // Every step time of long runs at common timesteps, and values near halves.
        for h in [0.001, 0.002, 0.005, 0.01, 1.0 / 3.0] {
            times.extend((0..200_000).map(|k| k as f64 * h));
        }
        let mut x = 1e-12_f64;
        while x < 1e12 {
            for t in [x, x * 1.000_000_000_1, (x * 1e9).floor() / 1e9 + 0.5e-9] {
                times.extend([t, f64::from_bits(t.to_bits() + 1), f64::from_bits(t.to_bits() - 1)]);
            }
            x *= 1.37;
        }
        for t in times {
            assert_eq!(sim_time_ns(t), (t.max(0.0) * 1e9).round() as u64, "{t:e}");
        }
    }

    /// A frame's scene updates (one time, in a row) are one message holding their entities and
    /// deletions in order; a deletion after an entity (which Foxglove would apply first), another
    /// topic or another time starts a new message. The `mcap` crate reads every message.
    #[test]
    fn a_frames_scene_updates_are_one_message_where_foxglove_applies_them_alike() {
        use crate::log::scene;
        use foxglove::messages::SceneUpdate;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scene.mcap");
        let mut sink = McapSink::create(&path, &info(), &[]).unwrap();
        let entity =
            |t: f64, id: &str| Record::Scene(t, scene::polyline(t, id, &[[0.0, 0.0], [1.0, 1.0]], scene::TRAIL, 0.1));
        let mut deletion = SceneUpdate::default();
        scene::prediction_into(&mut deletion, 1.0, "prediction/a", [0.0; 2], [f64::NAN; 2], 1.0);
        let deletion = Record::Scene(1.0, deletion);
        let state = Record::State(crate::log::proto::State {
            time: 1.0,
            ..Default::default()
        });
        let sent = [
            deletion.clone(),
            entity(1.0, "a"),
            entity(1.0, "b"),
            deletion.clone(),
            entity(1.0, "c"),
            state,
            entity(1.0, "d"),
            entity(2.0, "e"),
        ];
        for record in &sent {
            sink.record(record).unwrap();
        }
        sink.finish(true).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let messages: Vec<_> = mcap::MessageStream::new(&bytes).unwrap().map(|m| m.unwrap()).collect();
        let scenes: Vec<(u64, Vec<String>, Vec<String>)> = (messages.iter())
            .filter(|m| m.channel.topic == "/scene")
            .map(|m| {
                let update = <SceneUpdate as prost::Message>::decode(&m.data[..]).unwrap();
                let ids = |e: &[foxglove::messages::SceneEntity]| e.iter().map(|e| e.id.clone()).collect();
                let deleted = update.deletions.iter().map(|d| d.id.clone()).collect();
                (m.log_time, deleted, ids(&update.entities))
            })
            .collect();
        let names = |ids: &[&str]| ids.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let expected = vec![
            (1_000_000_000, names(&["prediction/a"]), names(&["a", "b"])),
            (1_000_000_000, names(&["prediction/a"]), names(&["c"])),
            (1_000_000_000, names(&[]), names(&["d"])),
            (2_000_000_000, names(&[]), names(&["e"])),
        ];
        assert_eq!(scenes, expected);
        // The sequence numbers count messages.
        let sequences: Vec<u32> = messages.iter().map(|m| m.sequence).collect();
        assert_eq!(sequences, (1..=sequences.len() as u32).collect::<Vec<_>>());
    }

    #[test]
    fn a_log_is_exclusive_until_finished_and_abandoning_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let mut sink = McapSink::create(&path, &info(), &[]).unwrap();
        let e = McapSink::create(&path, &info(), &[]).err().unwrap();
        assert!(e.to_string().contains("another process is writing it"), "{e}");
        assert!(!path.exists());
        sink.finish(false).unwrap();
        assert!(std::fs::read(&path).unwrap().starts_with(MCAP_MAGIC));
        // An earlier log may be replaced; an abandoned one leaves the earlier one as it was.
        let before = std::fs::read(&path).unwrap();
        McapSink::create(&path, &info(), &[]).unwrap().abandon();
        assert_eq!(std::fs::read(&path).unwrap(), before);
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["run.mcap"]);
    }

    #[test]
    fn inputs_and_foreign_files_are_refused_before_anything_is_created() {
        let dir = tempfile::tempdir().unwrap();
        let scenario = dir.path().join("s.toml");
        std::fs::write(&scenario, "name = 's'\n").unwrap();
        let e = McapSink::create(&scenario, &info(), &[&scenario]).err().unwrap();
        assert!(e.to_string().contains("is an input of this run"), "{e}");
        let e = McapSink::create(&scenario, &info(), &[]).err().unwrap();
        assert!(e.to_string().contains("not an mjsafe MCAP log"), "{e}");
        let e = McapSink::create(dir.path(), &info(), &[]).err().unwrap();
        assert!(e.to_string().contains("a directory"), "{e}");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["s.toml"]);
        assert_eq!(std::fs::read_to_string(&scenario).unwrap(), "name = 's'\n");
    }
}
