//! A chunked MCAP writer (spec: <https://mcap.dev/spec>) for the one layout mjsafe writes.
//!
//! Messages are appended to an uncompressed chunk buffer (one memcpy per message) and each
//! chunk is compressed with zstd in one call when it is full. The `mcap` crate's writer feeds
//! every record field to a streaming zstd encoder, one call per field, which cost more than
//! the compression itself (docs/performance.md). The file is the same kind: magic, header,
//! schemas and channels, metadata, zstd chunks each followed by their message indexes, data
//! end with the data-section CRC, then a summary (schemas, channels, statistics, chunk and
//! metadata indexes, summary offsets) and the footer with the summary CRC. No seeking: offsets
//! are counted as bytes are written. Written bytes are made durable every 256 KiB between
//! chunks ([`LogOutput`]), so the one sync at commit has at most that and the last chunk left.

use std::io::{self, Write};
use std::sync::mpsc;

/// "\x89MCAP0\r\n".
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// Written bytes made durable part-way once this many accumulate (checked when the next chunk
/// arrives, on the writer thread): the final flush at commit then has little left to wait for.
const SYNC_EVERY: u64 = 256 << 10;

/// Chunks that may wait for the writer thread before the episode waits for it. The writer
/// compresses a 256 KiB chunk in ≈ 1.5 ms and syncs every 256 KiB written, while an episode
/// fills a chunk every 2–3 ms; with one slot the episode waited 0.25–0.6 ms per run, and for
/// 6–25 ms when a sync stalled on a busy disk. Sixteen (4 MiB of records at most) absorb such
/// stalls and still bound the memory of a log on a disk slower than the run.
const QUEUED_CHUNKS: usize = 16;

/// Where a log goes. A file makes the bytes written so far durable in [`LogOutput::sync_written`]
/// (called between chunks, off the episode thread); an in-memory output has nothing to do.
pub trait LogOutput: Write + Send + 'static {
    /// Makes every byte written so far durable (a file: flush, then `fdatasync`).
    fn sync_written(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl LogOutput for Vec<u8> {}

impl LogOutput for io::BufWriter<std::fs::File> {
    fn sync_written(&mut self) -> io::Result<()> {
        self.flush()?;
        self.get_ref().sync_data()
    }
}

/// Message record bytes before the payload: opcode, length, channel, sequence, two times.
const MESSAGE_PREFIX: usize = 1 + 8 + 2 + 4 + 8 + 8;

/// Little-endian field encoders into a byte buffer.
struct Fields<'a>(&'a mut Vec<u8>);

impl Fields<'_> {
    fn u16(&mut self, v: u16) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn string(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32);
        self.0.extend_from_slice(s.as_bytes());
        self
    }
    fn bytes_u32(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.0.extend_from_slice(b);
        self
    }
    /// Map<string, string>: byte length, then (key, value) pairs in the given order.
    fn string_map(&mut self, entries: &[(String, String)]) -> &mut Self {
        let length: usize = entries.iter().map(|(k, v)| 8 + k.len() + v.len()).sum();
        self.u32(length as u32);
        for (k, v) in entries {
            self.string(k).string(v);
        }
        self
    }
    /// Map<uint16, uint64>.
    fn id_map(&mut self, entries: &[(u16, u64)]) -> &mut Self {
        self.u32((entries.len() * 10) as u32);
        for &(k, v) in entries {
            self.u16(k).u64(v);
        }
        self
    }
}

struct ChannelInfo {
    id: u16,
    schema_id: u16,
    topic: String,
    message_encoding: String,
    message_count: u64,
    /// (log time, offset in the open chunk's records) of its messages in the open chunk.
    index: Vec<(u64, u64)>,
}

struct SchemaInfo {
    id: u16,
    name: String,
    encoding: String,
    data: Vec<u8>,
}

struct ChunkIndex {
    start_time: u64,
    end_time: u64,
    offset: u64,
    length: u64,
    message_index_offsets: Vec<(u16, u64)>,
    message_index_length: u64,
    compressed_size: u64,
    uncompressed_size: u64,
}

struct MetadataIndex {
    offset: u64,
    length: u64,
    name: String,
}

/// A chunk's buffers once written, emptied for the next chunk: its records and its per-channel
/// message indexes (so that a warm log allocates nothing per chunk).
struct Spare {
    records: Vec<u8>,
    indexes: Vec<(u16, Vec<(u64, u64)>)>,
}

/// What goes to the data section, in file order.
enum Job {
    /// A record outside chunks (header, schema, channel): opcode and content.
    Record(u8, Vec<u8>),
    /// A metadata record (its index entry is kept for the summary).
    Metadata { name: String, content: Vec<u8> },
    /// A full chunk of message records and, per channel, its message index entries.
    Chunk {
        start_time: u64,
        end_time: u64,
        records: Vec<u8>,
        indexes: Vec<(u16, Vec<(u64, u64)>)>,
    },
}

/// The data section: owns the output, counts offsets and the CRC, compresses and writes
/// chunks with their message indexes, and keeps the chunk and metadata indexes.
struct DataSection<W: LogOutput> {
    out: W,
    /// Bytes written so far (the offset of the next record).
    position: u64,
    /// `position` at the last [`LogOutput::sync_written`].
    synced: u64,
    /// CRC of the data section (magic included), until the data end record.
    data_crc: crc32fast::Hasher,
    compressor: zstd::bulk::Compressor<'static>,
    compressed: Vec<u8>,
    record: Vec<u8>,
    chunk_indexes: Vec<ChunkIndex>,
    metadata_indexes: Vec<MetadataIndex>,
    /// Time spent writing jobs (compressing and writing chunks), wherever they ran.
    busy: std::time::Duration,
}

impl<W: LogOutput> DataSection<W> {
    fn write_data(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.out.write_all(bytes)?;
        self.data_crc.update(bytes);
        self.position += bytes.len() as u64;
        Ok(())
    }

    fn write_record(&mut self, opcode: u8, content: &[u8]) -> io::Result<()> {
        let mut prefix = [0u8; 9];
        prefix[0] = opcode;
        prefix[1..].copy_from_slice(&(content.len() as u64).to_le_bytes());
        self.write_data(&prefix)?;
        self.write_data(content)
    }

    /// Writes one job; a chunk's record buffer is handed back (emptied) for reuse.
    fn write(&mut self, job: Job) -> io::Result<Option<Spare>> {
        let started = std::time::Instant::now();
        let result = self.write_untimed(job);
        self.busy += started.elapsed();
        result
    }

    fn write_untimed(&mut self, job: Job) -> io::Result<Option<Spare>> {
        match job {
            Job::Record(opcode, content) => self.write_record(opcode, &content)?,
            Job::Metadata { name, content } => {
                let offset = self.position;
                self.write_record(op::METADATA, &content)?;
                self.metadata_indexes.push(MetadataIndex {
                    offset,
                    length: self.position - offset,
                    name,
                });
            }
            Job::Chunk {
                start_time,
                end_time,
                mut records,
                mut indexes,
            } => {
                // The bytes before this chunk, once enough accumulate: never after the last
                // chunk, whose bytes the commit's own sync makes durable (one wait, not two).
                if self.position - self.synced >= SYNC_EVERY {
                    self.out.sync_written()?;
                    self.synced = self.position;
                }
                self.write_chunk(start_time, end_time, &records, &indexes)?;
                records.clear();
                for (_, entries) in &mut indexes {
                    entries.clear();
                }
                return Ok(Some(Spare { records, indexes }));
            }
        }
        Ok(None)
    }

    /// Compresses and writes a chunk and its message indexes.
    fn write_chunk(
        &mut self,
        start_time: u64,
        end_time: u64,
        records: &[u8],
        indexes: &[(u16, Vec<(u64, u64)>)],
    ) -> io::Result<()> {
        self.compressed.clear();
        self.compressed.reserve(zstd::zstd_safe::compress_bound(records.len()));
        self.compressor.compress_to_buffer(records, &mut self.compressed)?;
        let offset = self.position;
        self.record.clear();
        Fields(&mut self.record)
            .u64(start_time)
            .u64(end_time)
            .u64(records.len() as u64)
            .u32(crc32fast::hash(records))
            .string("zstd")
            .u64(self.compressed.len() as u64);
        let mut prefix = [0u8; 9];
        prefix[0] = op::CHUNK;
        prefix[1..].copy_from_slice(&((self.record.len() + self.compressed.len()) as u64).to_le_bytes());
        self.write_data(&prefix)?;
        let (header, compressed) = (std::mem::take(&mut self.record), std::mem::take(&mut self.compressed));
        let result = self.write_data(&header).and_then(|()| self.write_data(&compressed));
        (self.record, self.compressed) = (header, compressed);
        result?;
        let length = self.position - offset;

        let index_start = self.position;
        let mut message_index_offsets = Vec::new();
        for (channel, entries) in indexes.iter().filter(|(_, entries)| !entries.is_empty()) {
            message_index_offsets.push((*channel, self.position));
            let mut record = std::mem::take(&mut self.record);
            record.clear();
            let mut fields = Fields(&mut record);
            fields.u16(*channel).u32((entries.len() * 16) as u32);
            for &(time, at) in entries {
                fields.u64(time).u64(at);
            }
            let result = self.write_record(op::MESSAGE_INDEX, &record);
            self.record = record;
            result?;
        }
        self.chunk_indexes.push(ChunkIndex {
            start_time,
            end_time,
            offset,
            length,
            message_index_offsets,
            message_index_length: self.position - index_start,
            compressed_size: self.compressed.len() as u64,
            uncompressed_size: records.len() as u64,
        });
        Ok(())
    }
}

/// Where the data section is written: on the caller's thread, or on a writer thread that
/// compresses and writes chunks while the caller fills the next one. Jobs keep their order,
/// so both give the same bytes.
enum Back<W: LogOutput> {
    Inline(DataSection<W>),
    /// Inline until the first chunk, then a writer thread (the header, schemas, channels and
    /// the run metadata are written without waking a thread for each).
    Deferred(Option<DataSection<W>>),
    Thread(WriterThread<W>),
}

struct WriterThread<W: LogOutput> {
    jobs: Option<mpsc::SyncSender<Job>>,
    /// Chunk buffers handed back by the thread.
    spare: mpsc::Receiver<Spare>,
    thread: Option<std::thread::JoinHandle<io::Result<DataSection<W>>>>,
}

impl<W: LogOutput> WriterThread<W> {
    /// Waits for every submitted job and returns the data section (or the first write error).
    fn join(&mut self) -> io::Result<DataSection<W>> {
        self.jobs.take();
        let thread = self
            .thread
            .take()
            .ok_or_else(|| io::Error::other("the MCAP writer thread already stopped"))?;
        thread
            .join()
            .map_err(|_| io::Error::other("the MCAP writer thread panicked"))?
    }
}

impl<W: LogOutput> Drop for WriterThread<W> {
    fn drop(&mut self) {
        // An abandoned writer: the thread finishes what it has before the file goes.
        if self.thread.is_some() {
            let _ = self.join();
        }
    }
}

impl<W: LogOutput> Back<W> {
    fn new(section: DataSection<W>, background: bool) -> io::Result<Self> {
        Ok(if background {
            Back::Deferred(Some(section))
        } else {
            Back::Inline(section)
        })
    }

    fn spawn(section: DataSection<W>) -> io::Result<Self> {
        let (jobs, queued) = mpsc::sync_channel::<Job>(QUEUED_CHUNKS);
        let (give_back, spare) = mpsc::channel();
        let thread = std::thread::Builder::new().name("mcap-writer".into()).spawn(move || {
            let mut section = section;
            for job in queued {
                if let Some(buffer) = section.write(job)? {
                    // The caller may no longer take buffers back; nothing is lost.
                    let _ = give_back.send(buffer);
                }
            }
            Ok(section)
        })?;
        Ok(Back::Thread(WriterThread {
            jobs: Some(jobs),
            spare,
            thread: Some(thread),
        }))
    }

    /// Writes `job` (or queues it for the thread); returns a chunk buffer free for reuse.
    fn submit(&mut self, job: Job) -> io::Result<Option<Spare>> {
        match self {
            Back::Inline(section) => section.write(job),
            Back::Deferred(section) if matches!(job, Job::Chunk { .. }) => {
                let section = section.take().expect("a deferred back holds its section");
                *self = Back::spawn(section)?;
                self.submit(job)
            }
            Back::Deferred(section) => section.as_mut().expect("a deferred back holds its section").write(job),
            Back::Thread(writer) => {
                let sent = writer.jobs.as_ref().is_some_and(|jobs| jobs.send(job).is_ok());
                if !sent {
                    // The thread stopped at a write error: report that error.
                    let stopped = writer.join().err();
                    return Err(stopped.unwrap_or_else(|| io::Error::other("the MCAP writer thread stopped")));
                }
                Ok(writer.spare.try_recv().ok())
            }
        }
    }

    /// The data section once every submitted job is written.
    fn into_section(self) -> io::Result<DataSection<W>> {
        match self {
            Back::Inline(section) | Back::Deferred(Some(section)) => Ok(section),
            Back::Deferred(None) => Err(io::Error::other("the MCAP writer thread did not start")),
            Back::Thread(mut writer) => writer.join(),
        }
    }
}

pub struct McapWriter<W: LogOutput> {
    back: Back<W>,
    schemas: Vec<SchemaInfo>,
    channels: Vec<ChannelInfo>,
    chunk: Vec<u8>,
    /// The message indexes of a written chunk, emptied, for the next ones.
    spare_indexes: Vec<(u16, Vec<(u64, u64)>)>,
    /// (earliest, latest) log time of the open chunk's messages.
    chunk_bounds: Option<(u64, u64)>,
    chunk_size: usize,
    /// (earliest, latest) log time of the chunks handed on so far.
    bounds: Option<(u64, u64)>,
    /// The open chunk's last message: channel, log time and where its record starts.
    last: Option<(u16, u64, usize)>,
}

impl<W: LogOutput> McapWriter<W> {
    /// Writes the magic and the header; chunks close once their records reach `chunk_size`
    /// bytes and are compressed with zstd at `level` — on a writer thread when `background`
    /// (the bytes are the same either way).
    pub fn new(
        out: W,
        profile: &str,
        library: &str,
        chunk_size: usize,
        level: i32,
        background: bool,
    ) -> io::Result<Self> {
        let mut section = DataSection {
            out,
            position: 0,
            synced: 0,
            data_crc: crc32fast::Hasher::new(),
            compressor: zstd::bulk::Compressor::new(level)?,
            compressed: Vec::new(),
            record: Vec::new(),
            chunk_indexes: Vec::new(),
            metadata_indexes: Vec::new(),
            busy: std::time::Duration::ZERO,
        };
        section.write_data(MAGIC)?;
        let mut header = Vec::new();
        Fields(&mut header).string(profile).string(library);
        section.write_record(op::HEADER, &header)?;
        Ok(McapWriter {
            back: Back::new(section, background)?,
            schemas: Vec::new(),
            channels: Vec::new(),
            chunk: Vec::with_capacity(chunk_size + chunk_size / 8),
            spare_indexes: Vec::new(),
            chunk_bounds: None,
            chunk_size,
            bounds: None,
            last: None,
        })
    }

    /// Adds a schema (written at once, outside chunks); returns its id (from 1).
    pub fn add_schema(&mut self, name: &str, encoding: &str, data: &[u8]) -> io::Result<u16> {
        let id = self.schemas.len() as u16 + 1;
        let mut record = Vec::new();
        Fields(&mut record)
            .u16(id)
            .string(name)
            .string(encoding)
            .bytes_u32(data);
        self.back.submit(Job::Record(op::SCHEMA, record))?;
        self.schemas.push(SchemaInfo {
            id,
            name: name.into(),
            encoding: encoding.into(),
            data: data.to_vec(),
        });
        Ok(id)
    }

    /// Adds a channel without metadata (written before the open chunk); returns its id (from 1).
    pub fn add_channel(&mut self, schema_id: u16, topic: &str, message_encoding: &str) -> io::Result<u16> {
        let id = self.channels.len() as u16 + 1;
        let mut record = Vec::new();
        encode_channel(&mut record, id, schema_id, topic, message_encoding);
        self.back.submit(Job::Record(op::CHANNEL, record))?;
        self.channels.push(ChannelInfo {
            id,
            schema_id,
            topic: topic.into(),
            message_encoding: message_encoding.into(),
            message_count: 0,
            // Room for a share of a chunk of small messages (later chunks start with the room
            // the previous one needed).
            index: Vec::with_capacity(self.chunk_size / 256),
        });
        Ok(id)
    }

    /// Writes a metadata record (closing the open chunk first, so it sits between chunks).
    pub fn write_metadata(&mut self, name: &str, entries: &[(String, String)]) -> io::Result<()> {
        self.finish_chunk()?;
        let mut content = Vec::new();
        Fields(&mut content).string(name).string_map(entries);
        self.back.submit(Job::Metadata {
            name: name.into(),
            content,
        })?;
        Ok(())
    }

    /// Appends one message to the open chunk.
    pub fn write_message(&mut self, channel_id: u16, sequence: u32, log_time: u64, data: &[u8]) -> io::Result<()> {
        self.write_message_with(channel_id, sequence, log_time, |chunk| chunk.extend_from_slice(data))
    }

    /// Appends one message whose payload `encode` appends to the buffer it is given: the open
    /// chunk itself, so the payload is encoded in place rather than encoded and then copied.
    #[inline]
    pub fn write_message_with(
        &mut self,
        channel_id: u16,
        sequence: u32,
        log_time: u64,
        encode: impl FnOnce(&mut Vec<u8>),
    ) -> io::Result<()> {
        let channel = &mut self.channels[usize::from(channel_id) - 1];
        let start = self.chunk.len();
        channel.index.push((log_time, start as u64));
        let mut prefix = [0u8; MESSAGE_PREFIX];
        prefix[0] = op::MESSAGE;
        prefix[9..11].copy_from_slice(&channel_id.to_le_bytes());
        prefix[11..15].copy_from_slice(&sequence.to_le_bytes());
        prefix[15..23].copy_from_slice(&log_time.to_le_bytes());
        prefix[23..31].copy_from_slice(&log_time.to_le_bytes());
        self.chunk.extend_from_slice(&prefix);
        encode(&mut self.chunk);
        // The record's length (all but the opcode and the length itself), now that it is known.
        let length = (self.chunk.len() - start - 9) as u64;
        let at: &mut [u8; 8] = (&mut self.chunk[start + 1..start + 9])
            .try_into()
            .expect("a message record starts with its opcode and its 8-byte length");
        *at = length.to_le_bytes();
        let (lo, hi) = self.chunk_bounds.unwrap_or((log_time, log_time));
        self.chunk_bounds = Some((lo.min(log_time), hi.max(log_time)));
        self.last = Some((channel_id, log_time, start));
        if self.chunk.len() >= self.chunk_size {
            self.finish_chunk()?;
        }
        Ok(())
    }

    /// Appends what `encode` appends to the payload of the open chunk's last message, when that
    /// message is on `channel_id` at `log_time`; returns whether it did (else nothing happens).
    /// For protobuf, the bytes of two messages one after the other are one message holding
    /// both (the repeated fields' elements joined, in order).
    pub fn extend_last_message(
        &mut self,
        channel_id: u16,
        log_time: u64,
        encode: impl FnOnce(&mut Vec<u8>),
    ) -> io::Result<bool> {
        let Some((channel, time, start)) = self.last else {
            return Ok(false);
        };
        if channel != channel_id || time != log_time {
            return Ok(false);
        }
        encode(&mut self.chunk);
        let length = (self.chunk.len() - start - 9) as u64;
        self.chunk[start + 1..start + 9].copy_from_slice(&length.to_le_bytes());
        if self.chunk.len() >= self.chunk_size {
            self.finish_chunk()?;
        }
        Ok(true)
    }

    /// Hands the open chunk and its message indexes to the data section (nothing if empty).
    fn finish_chunk(&mut self) -> io::Result<()> {
        self.last = None;
        let Some((start_time, end_time)) = self.chunk_bounds.take() else {
            return Ok(());
        };
        let widen = |(lo, hi): (u64, u64)| (lo.min(start_time), hi.max(end_time));
        self.bounds = Some(self.bounds.map_or((start_time, end_time), widen));
        let capacity = self.chunk.capacity();
        let records = std::mem::take(&mut self.chunk);
        // Each channel's next index is a written chunk's (emptied), with at least the room this
        // one needed (no regrowing).
        let mut indexes = std::mem::take(&mut self.spare_indexes);
        for (i, c) in self.channels.iter_mut().enumerate() {
            // A channel's messages are counted by chunk, from its index entries.
            let room = c.index.len();
            c.message_count += room as u64;
            let mut next = indexes
                .get_mut(i)
                .map(|(_, entries)| std::mem::take(entries))
                .unwrap_or_default();
            next.reserve(room);
            let full = (c.id, std::mem::replace(&mut c.index, next));
            match indexes.get_mut(i) {
                Some(slot) => *slot = full,
                None => indexes.push(full),
            }
        }
        indexes.truncate(self.channels.len());
        let spare = self.back.submit(Job::Chunk {
            start_time,
            end_time,
            records,
            indexes,
        })?;
        match spare {
            Some(Spare { records, indexes }) => (self.chunk, self.spare_indexes) = (records, indexes),
            None => self.chunk = Vec::with_capacity(capacity),
        }
        Ok(())
    }

    /// Closes the data section and writes the summary, the footer and the closing magic.
    /// Returns the output.
    pub fn finish(self) -> io::Result<W> {
        self.finish_timed().map(|(out, _)| out)
    }

    /// [`McapWriter::finish`], also returning the time spent compressing, writing and syncing chunks
    /// (on the writer thread when there is one: work the caller did not wait for).
    pub fn finish_timed(mut self) -> io::Result<(W, std::time::Duration)> {
        self.finish_chunk()?;
        let McapWriter {
            back,
            schemas,
            channels,
            bounds,
            ..
        } = self;
        let mut section = back.into_section()?;
        let data_crc = std::mem::take(&mut section.data_crc).finalize();
        section.write_record(op::DATA_END, &data_crc.to_le_bytes())?;
        let DataSection {
            mut out,
            position: summary_start,
            chunk_indexes,
            metadata_indexes,
            busy,
            ..
        } = section;

        let mut summary = Vec::new();
        let mut offsets: Vec<(u8, u64, u64)> = Vec::new();
        let mut group = |summary: &mut Vec<u8>, opcode: u8, records: &mut dyn FnMut(&mut Vec<u8>)| {
            let start = summary.len();
            records(summary);
            if summary.len() > start {
                offsets.push((opcode, summary_start + start as u64, (summary.len() - start) as u64));
            }
        };
        group(&mut summary, op::SCHEMA, &mut |s| {
            for schema in &schemas {
                record(s, op::SCHEMA, |f| {
                    f.u16(schema.id)
                        .string(&schema.name)
                        .string(&schema.encoding)
                        .bytes_u32(&schema.data);
                });
            }
        });
        group(&mut summary, op::CHANNEL, &mut |s| {
            for c in &channels {
                record(s, op::CHANNEL, |f| {
                    encode_channel(f.0, c.id, c.schema_id, &c.topic, &c.message_encoding);
                });
            }
        });
        group(&mut summary, op::STATISTICS, &mut |s| {
            let (start, end) = bounds.unwrap_or((0, 0));
            let counts: Vec<(u16, u64)> = channels
                .iter()
                .filter(|c| c.message_count > 0)
                .map(|c| (c.id, c.message_count))
                .collect();
            record(s, op::STATISTICS, |f| {
                f.u64(counts.iter().map(|&(_, n)| n).sum())
                    .u16(schemas.len() as u16)
                    .u32(channels.len() as u32)
                    .u32(0)
                    .u32(metadata_indexes.len() as u32)
                    .u32(chunk_indexes.len() as u32)
                    .u64(start)
                    .u64(end)
                    .id_map(&counts);
            });
        });
        group(&mut summary, op::CHUNK_INDEX, &mut |s| {
            for c in &chunk_indexes {
                record(s, op::CHUNK_INDEX, |f| {
                    f.u64(c.start_time)
                        .u64(c.end_time)
                        .u64(c.offset)
                        .u64(c.length)
                        .id_map(&c.message_index_offsets)
                        .u64(c.message_index_length)
                        .string("zstd")
                        .u64(c.compressed_size)
                        .u64(c.uncompressed_size);
                });
            }
        });
        group(&mut summary, op::METADATA_INDEX, &mut |s| {
            for m in &metadata_indexes {
                record(s, op::METADATA_INDEX, |f| {
                    f.u64(m.offset).u64(m.length).string(&m.name);
                });
            }
        });
        let summary_offset_start = summary_start + summary.len() as u64;
        for (opcode, start, length) in offsets {
            record(&mut summary, op::SUMMARY_OFFSET, |f| {
                f.0.push(opcode);
                f.u64(start).u64(length);
            });
        }
        // The footer's CRC covers the summary and the footer up to the CRC itself.
        summary.push(op::FOOTER);
        Fields(&mut summary)
            .u64(20)
            .u64(summary_start)
            .u64(summary_offset_start);
        let summary_crc = crc32fast::hash(&summary);
        Fields(&mut summary).u32(summary_crc);
        summary.extend_from_slice(MAGIC);
        out.write_all(&summary)?;
        out.flush()?;
        Ok((out, busy))
    }
}

/// Appends a record (opcode, length, content written by `content`) to `buffer`.
fn record(buffer: &mut Vec<u8>, opcode: u8, content: impl FnOnce(&mut Fields)) {
    buffer.push(opcode);
    let length_at = buffer.len();
    buffer.extend_from_slice(&[0; 8]);
    content(&mut Fields(buffer));
    let length = (buffer.len() - length_at - 8) as u64;
    buffer[length_at..length_at + 8].copy_from_slice(&length.to_le_bytes());
}

fn encode_channel(buffer: &mut Vec<u8>, id: u16, schema_id: u16, topic: &str, message_encoding: &str) {
    Fields(buffer)
        .u16(id)
        .u16(schema_id)
        .string(topic)
        .string(message_encoding)
        .string_map(&[]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes a small file with several chunks and metadata.
    fn sample(chunk_size: usize) -> Vec<u8> {
        sample_written(chunk_size, false)
    }

    fn sample_written(chunk_size: usize, background: bool) -> Vec<u8> {
        let mut w = McapWriter::new(Vec::new(), "", "test", chunk_size, 1, background).unwrap();
        let schema = w.add_schema("pkg.A", "protobuf", b"schema bytes").unwrap();
        let a = w.add_channel(schema, "/a", "protobuf").unwrap();
        let b = w.add_channel(schema, "/b", "protobuf").unwrap();
        w.write_metadata("first", &[("k".into(), "v".into()), ("x".into(), "y".into())])
            .unwrap();
        for i in 0..1000u32 {
            let payload = format!("message {i}").into_bytes();
            w.write_message(if i % 3 == 0 { b } else { a }, i + 1, u64::from(i) * 1000, &payload)
                .unwrap();
        }
        w.write_metadata("last", &[("complete".into(), "true".into())]).unwrap();
        w.finish().unwrap()
    }

    #[test]
    fn the_mcap_crate_reads_back_every_message_summary_and_metadata() {
        for chunk_size in [1 << 20, 512] {
            let bytes = sample(chunk_size);
            let messages: Vec<_> = mcap::MessageStream::new(&bytes).unwrap().map(|m| m.unwrap()).collect();
            assert_eq!(messages.len(), 1000);
            for (i, m) in messages.iter().enumerate() {
                assert_eq!(m.data.as_ref(), format!("message {i}").as_bytes());
                assert_eq!(m.log_time, i as u64 * 1000);
                assert_eq!(m.sequence, i as u32 + 1);
                assert_eq!(m.channel.topic, if i % 3 == 0 { "/b" } else { "/a" });
                assert_eq!(m.channel.schema.as_ref().unwrap().name, "pkg.A");
            }
            let summary = mcap::read::Summary::read(&bytes).unwrap().expect("a summary");
            let stats = summary.stats.as_ref().unwrap();
            assert_eq!(
                (stats.message_count, stats.channel_count, stats.metadata_count),
                (1000, 2, 2)
            );
            assert_eq!(stats.message_end_time, 999_000);
            assert_eq!(stats.chunk_count as usize, summary.chunk_indexes.len());
            assert!(chunk_size > 1000 || summary.chunk_indexes.len() > 10);
            // Indexed reads through the chunk indexes and message indexes.
            let mut indexed = 0;
            for chunk in &summary.chunk_indexes {
                let index = summary.read_message_indexes(&bytes, chunk).unwrap();
                for (channel, entries) in index {
                    for entry in entries {
                        let m = summary.seek_message(&bytes, chunk, &entry).unwrap();
                        assert_eq!(m.channel.id, channel.id);
                        assert_eq!(m.log_time, entry.log_time);
                        indexed += 1;
                    }
                }
            }
            assert_eq!(indexed, 1000);
            let last = summary.metadata_indexes.iter().find(|m| m.name == "last").unwrap();
            let metadata = mcap::read::metadata(&bytes, last).unwrap();
            assert_eq!(metadata.metadata.get("complete").map(String::as_str), Some("true"));
        }
    }

    #[test]
    fn the_data_and_summary_crcs_check_out() {
        let bytes = sample(4096);
        // Footer: opcode, length, summary_start, summary_offset_start, summary_crc, magic.
        let footer = bytes.len() - 8 - 29;
        assert_eq!(bytes[footer], op::FOOTER);
        let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
        let summary_start = u64_at(footer + 9) as usize;
        let summary_crc = u32::from_le_bytes(bytes[footer + 25..footer + 29].try_into().unwrap());
        assert_eq!(crc32fast::hash(&bytes[summary_start..footer + 25]), summary_crc);
        // Data end is the record right before the summary: opcode, length 4, CRC.
        let data_end = summary_start - 13;
        assert_eq!(bytes[data_end], op::DATA_END);
        let data_crc = u32::from_le_bytes(bytes[data_end + 9..data_end + 13].try_into().unwrap());
        assert_eq!(crc32fast::hash(&bytes[..data_end]), data_crc);
    }

    #[test]
    fn equal_input_gives_equal_bytes() {
        assert_eq!(sample(4096), sample(4096));
    }

    #[test]
    fn the_writer_thread_writes_the_same_bytes() {
        for chunk_size in [1 << 20, 4096, 512] {
            assert_eq!(
                sample_written(chunk_size, true),
                sample(chunk_size),
                "chunks of {chunk_size}"
            );
        }
    }

    /// Fails every write after the first `budget` bytes.
    struct FailingAfter {
        budget: usize,
    }

    impl Write for FailingAfter {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if buf.len() > self.budget {
                return Err(io::Error::other("disk full"));
            }
            self.budget -= buf.len();
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl LogOutput for FailingAfter {}

    /// An in-memory output that records how many bytes it held at each sync.
    #[derive(Default)]
    struct SyncRecording {
        bytes: Vec<u8>,
        synced_at: std::sync::Arc<std::sync::Mutex<Vec<usize>>>,
    }

    impl Write for SyncRecording {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.bytes.write(buf)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl LogOutput for SyncRecording {
        fn sync_written(&mut self) -> io::Result<()> {
            self.synced_at.lock().unwrap().push(self.bytes.len());
            Ok(())
        }
    }

    #[test]
    fn written_bytes_are_synced_between_chunks_about_every_sync_every_bytes() {
        for background in [false, true] {
            let output = SyncRecording::default();
            let synced_at = output.synced_at.clone();
            // Incompressible payloads: the file grows by about a chunk per chunk.
            let mut w = McapWriter::new(output, "", "test", 64 << 10, 1, background).unwrap();
            let schema = w.add_schema("pkg.A", "protobuf", b"schema").unwrap();
            let a = w.add_channel(schema, "/a", "protobuf").unwrap();
            let mut state = 0x9E37_79B9_7F4A_7C15u64;
            for i in 0..4000u32 {
                let payload: Vec<u8> = (0..300)
                    .map(|_| {
                        state ^= state << 13;
                        state ^= state >> 7;
                        state ^= state << 17;
                        state as u8
                    })
                    .collect();
                w.write_message(a, i, u64::from(i), &payload).unwrap();
            }
            let written = w.finish().unwrap().bytes.len();
            let synced_at = synced_at.lock().unwrap().clone();
            // 1.3 MB written: a sync once 256 KiB accumulate (at most a chunk more), before the
            // next chunk; the last chunk and the summary are left to the commit's sync.
            assert!(synced_at.len() >= 3, "{synced_at:?}");
            let mut last = 0;
            for at in synced_at {
                assert!(at - last >= SYNC_EVERY as usize && at - last < SYNC_EVERY as usize + (80 << 10));
                last = at;
            }
            assert!(written - last < SYNC_EVERY as usize + (96 << 10), "{}", written - last);
        }
    }

    #[test]
    fn a_write_error_on_the_writer_thread_reaches_the_caller() {
        for background in [false, true] {
            let mut w = McapWriter::new(FailingAfter { budget: 600 }, "", "test", 512, 1, background).unwrap();
            let schema = w.add_schema("pkg.A", "protobuf", b"schema").unwrap();
            let a = w.add_channel(schema, "/a", "protobuf").unwrap();
            let mut failed = None;
            for i in 0..10_000u32 {
                if let Err(e) = w.write_message(a, i, u64::from(i), b"payload of some length") {
                    failed = Some(e);
                    break;
                }
            }
            let error = match failed {
                Some(e) => e,
                None => w.finish().err().expect("the writes cannot all succeed"),
            };
            assert!(error.to_string().contains("disk full"), "{background}: {error}");
        }
    }
}
