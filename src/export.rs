//! `mjsafe export`: the time series of a log as one wide, time-indexed table per topic (CSV or
//! Parquet), decoded through the one log reader ([`crate::log::read`]) and streamed: each
//! message becomes a row as it is read (CSV through a buffered writer, Parquet in batches of
//! [`BATCH_ROWS`] rows and row groups of [`ROW_GROUP_ROWS`]), so memory stays flat in the
//! log's length. Every table's first column is `time` (s); the columns follow the message
//! (docs/log-format.md):
//!
//! | topic | columns after `time` |
//! |---|---|
//! | `/state`, `/state/measured` | `step`, one per state name (`x1`, `x2`, `heading`, `speed`) |
//! | `/command/issued` | `<channel>.nominal`, `<channel>.filtered` per channel |
//! | `/command/applied`, `/command/actuated` | `<channel>`, `<channel>.issued_at` per channel |
//! | `/barrier` | per barrier `<name>.h`, `.constraint`, `.clearance`, `.time_to_collision`, `.known`, `.relative_degree`, `.obstacle` |
//! | `/filter` | `active`, `infeasible`, `mu`, `left_out`, `<channel>.correction` per channel |
//! | `/prediction` | `channel`, `issued_at`, `horizon`, `predicted.<state>`, `realized.<state>` per state component, `error`, `relative_error`, `reused_chain`, `chain_mismatch` |
//! | `/event` | `kind`, `message`, `participants` (space-separated), `depth` |
//!
//! The Foxglove topics (`/scene`, `/tf`) are views, not tables, and are not exported. Outputs
//! follow [`crate::files`]: `.partial` files renamed when the whole log was read, never over
//! the log, a non-regular file or a file that is not a table of the same format.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::builder::{BooleanBuilder, Float64Builder, StringBuilder, UInt64Builder};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::WriterProperties;

use crate::files::{FileError, OutputFile, Replace};
use crate::log::read::{read_run_file, Message, ReadError, RunVisitor};
use crate::log::{Record, Topic};
use crate::signals::{table_row, Cell, Columns, Kind, Observed};

/// Rows per Parquet batch handed to the writer.
pub const BATCH_ROWS: usize = 4096;
/// Rows per Parquet row group (the writer holds one row group's encoded pages at a time).
pub const ROW_GROUP_ROWS: usize = 16384;

/// The table formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Csv,
    Parquet,
}

impl Format {
    pub fn extension(self) -> &'static str {
        match self {
            Format::Csv => "csv",
            Format::Parquet => "parquet",
        }
    }

    /// How every file of this format that mjsafe writes starts: an existing file that does not
    /// is never replaced (CSV: the header's first column).
    fn magic(self) -> &'static [u8] {
        match self {
            Format::Csv => b"time,",
            Format::Parquet => b"PAR1",
        }
    }

    fn what(self) -> &'static str {
        match self {
            Format::Csv => "CSV table",
            Format::Parquet => "Parquet table",
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    File(#[from] FileError),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("{file}: {message}")]
    Write { file: String, message: String },
    #[error("{file}: {topic} at t = {time}: {message}")]
    Layout {
        file: String,
        topic: Topic,
        time: f64,
        message: String,
    },
    #[error("--topics: {0}")]
    Topics(String),
}

/// The topics that are tables, in [`Topic`] order.
pub fn table_topics() -> Vec<Topic> {
    Topic::ALL
        .into_iter()
        .filter(|t| !matches!(t, Topic::Scene | Topic::Transform | Topic::Log))
        .collect()
}

/// Parses `--topics` (comma-separated topic names); empty: every table topic.
pub fn parse_topics(list: &[String]) -> Result<Vec<Topic>, ExportError> {
    if list.is_empty() {
        return Ok(table_topics());
    }
    let mut topics = Vec::new();
    for name in list
        .iter()
        .flat_map(|s| s.split(','))
        .map(str::trim)
        .filter(|s| !s.is_empty())
    {
        let topic = Topic::from_name(name).ok_or_else(|| {
            let known: Vec<&str> = table_topics().iter().map(|t| t.name()).collect();
            ExportError::Topics(format!("unknown topic `{name}` (tables: {})", known.join(", ")))
        })?;
        if !table_topics().contains(&topic) {
            return Err(ExportError::Topics(format!(
                "{name} is a Foxglove view, not a table (open the log in Foxglove)"
            )));
        }
        if !topics.contains(&topic) {
            topics.push(topic);
        }
    }
    if topics.is_empty() {
        let known: Vec<&str> = table_topics().iter().map(|t| t.name()).collect();
        return Err(ExportError::Topics(format!(
            "no topic named (expected comma-separated topics among {}; leave --topics out for every table)",
            known.join(", ")
        )));
    }
    topics.sort();
    Ok(topics)
}

/// The file a topic of `log` is exported to in `dir`: `<log stem>-<topic>.<ext>` with the
/// topic's slashes as underscores (`run-state.csv`, `run-command_issued.parquet`).
pub fn table_path(log: &Path, dir: &Path, topic: Topic, format: Format) -> PathBuf {
    let stem = table_stem(log);
    let slug = topic.name().trim_start_matches('/').replace('/', "_");
    dir.join(format!("{stem}-{slug}.{}", format.extension()))
}

/// The name a log's tables start with: its file name without `.mcap` (a `run.mcap.partial`,
/// a copy of a log not yet renamed, has the tables of `run.mcap`).
pub fn table_stem(log: &Path) -> String {
    let name = log.file_name().and_then(|s| s.to_str()).unwrap_or("run");
    let name = name.strip_suffix(".partial").unwrap_or(name);
    Path::new(name)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("run")
        .to_string()
}

/// What one log's export wrote.
#[derive(Debug)]
pub struct Exported {
    /// (topic, file, rows) of each table written.
    pub tables: Vec<(Topic, PathBuf, u64)>,
    /// Topics asked for that the log has no message on (no file written).
    pub empty: Vec<Topic>,
    /// The log says its run completed (`mjsafe_status`): else the tables end where the run
    /// stopped (an interruption, an error, a log still being written).
    pub complete: bool,
}

/// Exports `topics` of `log` into `dir` (default: the log's directory). Nothing is renamed to
/// its final name unless the whole log was read and every table written.
pub fn export_log(log: &Path, dir: Option<&Path>, topics: &[Topic], format: Format) -> Result<Exported, ExportError> {
    let dir = match dir {
        Some(d) => d.to_path_buf(),
        None => log.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf),
    };
    // Every target is checked before the log is read.
    for &topic in topics {
        crate::files::check_output(
            &table_path(log, &dir, topic, format),
            format.what(),
            Replace::IfStartsWith(format.magic()),
            &[log],
        )?;
    }
    let mut export = Export::new(
        &log.display().to_string(),
        topics,
        FileTables {
            log,
            dir: &dir,
            format,
            tables: BTreeMap::new(),
        },
    );
    let result = read_run_file(log, &mut export);
    if let Some(failure) = export.failure.take() {
        return Err(failure);
    }
    result?;
    // A table of a topic this log has no message on, left by an earlier export under the same
    // name (another log of that name), would pass for this log's: refused before any table is
    // renamed into place (the new tables' `.partial` files are removed).
    let empty: Vec<Topic> = topics
        .iter()
        .copied()
        .filter(|t| !export.out.tables.contains_key(t))
        .collect();
    for &topic in &empty {
        let path = table_path(log, &dir, topic, format);
        if std::fs::symlink_metadata(&path).is_ok() {
            return Err(ExportError::Write {
                file: path.display().to_string(),
                message: format!(
                    "{} has no {topic} messages, and a file under the name of that table (an earlier export of another log of this name?) would pass for it; remove it or export into another directory",
                    log.display()
                ),
            });
        }
    }
    let mut written = Vec::new();
    for (topic, table) in std::mem::take(&mut export.out.tables) {
        let rows = table.rows;
        written.push((topic, table.finish()?, rows));
    }
    Ok(Exported {
        tables: written,
        empty,
        complete: export.rows.complete,
    })
}

/// The most bytes the tables of one log may take in memory ([`read_tables`], [`TableSink`]):
/// 8 per number or flag, a text's length plus 24. Beyond it the tables are files
/// ([`export_log`], which streams).
pub const MEMORY_LIMIT: usize = 1 << 30;

/// One column of a table held in memory.
#[derive(Debug, Clone, PartialEq)]
pub enum Values {
    F64(Vec<f64>),
    U64(Vec<u64>),
    Bool(Vec<bool>),
    Text(Vec<String>),
}

impl Values {
    fn of(kind: Kind) -> Values {
        match kind {
            Kind::F64 => Values::F64(Vec::new()),
            Kind::U64 => Values::U64(Vec::new()),
            Kind::Bool => Values::Bool(Vec::new()),
            Kind::Text => Values::Text(Vec::new()),
        }
    }

    /// Appends `cell`; the bytes it takes.
    fn push(&mut self, cell: &Cell) -> usize {
        match (self, cell) {
            (Values::F64(v), Cell::F(x)) => v.push(*x),
            (Values::U64(v), Cell::U(x)) => v.push(*x),
            (Values::Bool(v), Cell::B(x)) => v.push(*x),
            (Values::Text(v), Cell::S(x)) => {
                v.push(x.clone());
                return x.len() + 24;
            }
            _ => unreachable!("cells follow the columns"),
        }
        8
    }
}

/// A topic's table held in memory: the columns of its file ([`export_log`]), in order, each
/// with its name.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryTable {
    pub columns: Vec<(String, Values)>,
    kinds: Vec<(String, Kind)>,
}

impl MemoryTable {
    /// Rows in the table.
    pub fn rows(&self) -> usize {
        match self.columns.first().map(|(_, v)| v) {
            Some(Values::F64(v)) => v.len(),
            Some(Values::U64(v)) => v.len(),
            Some(Values::Bool(v)) => v.len(),
            Some(Values::Text(v)) => v.len(),
            None => 0,
        }
    }
}

/// The tables of one log in memory: one per topic with messages, as [`export_log`] would
/// write them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MemoryTables {
    pub tables: BTreeMap<Topic, MemoryTable>,
    /// The log says its run completed (see [`Exported::complete`]).
    pub complete: bool,
    /// Bytes taken so far (at most [`MEMORY_LIMIT`]).
    bytes: usize,
}

/// The rows of a log into [`MemoryTables`], within [`MEMORY_LIMIT`].
struct InMemory {
    file: String,
    tables: MemoryTables,
}

impl Tables for InMemory {
    fn push(
        &mut self,
        topic: Topic,
        time: f64,
        columns: Vec<(String, Kind)>,
        cells: &[Cell],
    ) -> Result<(), ExportError> {
        let table = self.tables.tables.entry(topic).or_insert_with(|| MemoryTable {
            columns: columns.iter().map(|(n, k)| (n.clone(), Values::of(*k))).collect(),
            kinds: columns.clone(),
        });
        check_layout(&self.file, (topic, time), &table.kinds, &columns)?;
        let bytes: usize = table
            .columns
            .iter_mut()
            .zip(cells)
            .map(|((_, values), cell)| values.push(cell))
            .sum();
        self.tables.bytes = self.tables.bytes.saturating_add(bytes);
        if self.tables.bytes > MEMORY_LIMIT {
            return Err(ExportError::Write {
                file: self.file.clone(),
                message: format!(
                    "its tables take more than {MEMORY_LIMIT} bytes in memory (at {topic}, t = {time}); write them to files with `mjsafe export`, which streams"
                ),
            });
        }
        Ok(())
    }
}

/// The tables of `topics` of `log`, in memory: the rows and columns [`export_log`] writes
/// (the same reader and decoding), at most [`MEMORY_LIMIT`] bytes of them.
pub fn read_tables(log: &Path, topics: &[Topic]) -> Result<MemoryTables, ExportError> {
    let file = log.display().to_string();
    let mut export = Export::new(
        &file,
        topics,
        InMemory {
            file: file.clone(),
            tables: MemoryTables::default(),
        },
    );
    let result = read_run_file(log, &mut export);
    if let Some(failure) = export.failure.take() {
        return Err(failure);
    }
    result?;
    let mut tables = export.out.tables;
    tables.complete = export.rows.complete;
    Ok(tables)
}

/// A sink that keeps a running episode's tables in memory: each record encoded as the log
/// encodes it and read back through the one decoder into the rows [`read_tables`] gives of
/// its log, every table topic, at most [`MEMORY_LIMIT`] bytes (beyond it the sink fails, and
/// the run stops: [`crate::run`]).
pub struct TableSink {
    export: Export<'static, InMemory>,
    /// What stands for the log.
    name: String,
    buffer: Vec<u8>,
}

impl TableSink {
    /// A sink whose tables and errors name `name` as their log.
    pub fn new(name: &str) -> TableSink {
        static TOPICS: std::sync::OnceLock<Vec<Topic>> = std::sync::OnceLock::new();
        let topics = TOPICS.get_or_init(table_topics);
        TableSink {
            export: Export::new(
                name,
                topics,
                InMemory {
                    file: name.to_string(),
                    tables: MemoryTables::default(),
                },
            ),
            name: name.to_string(),
            buffer: Vec::new(),
        }
    }

    /// The tables of the run (after the episode finished the sink: `complete` as its log's).
    pub fn tables(self) -> MemoryTables {
        let mut tables = self.export.out.tables;
        tables.complete = self.export.rows.complete;
        tables
    }
}

impl crate::log::Sink for TableSink {
    fn record(&mut self, record: &Record) -> Result<(), crate::log::LogError> {
        let topic = record.kind();
        if !self.export.rows.topics.contains(&topic) {
            return Ok(());
        }
        record.encode_into(&mut self.buffer);
        let message = Message::new(
            topic,
            crate::log::mcap::sim_time_ns(record.time()),
            &self.buffer,
            &self.name,
        );
        self.export.message(&message).map_err(|e| crate::log::LogError::Write {
            path: self.name.clone(),
            message: match self.export.failure.take() {
                Some(failure) => failure.to_string(),
                None => e.to_string(),
            },
        })
    }

    fn finish(&mut self, complete: bool) -> Result<(), crate::log::LogError> {
        self.export.rows.complete = complete;
        Ok(())
    }
}

/// Where an export's rows go: the table files ([`export_log`]) or tables in memory
/// ([`read_tables`], [`TableSink`]).
trait Tables {
    /// Appends a row of `topic` with `columns`, its values `cells`.
    fn push(
        &mut self,
        topic: Topic,
        time: f64,
        columns: Vec<(String, Kind)>,
        cells: &[Cell],
    ) -> Result<(), ExportError>;
}

/// The error of a row whose columns are not its table's: a table has the same columns in
/// every row.
fn check_layout(
    file: &str,
    (topic, time): (Topic, f64),
    table: &[(String, Kind)],
    row: &[(String, Kind)],
) -> Result<(), ExportError> {
    if table == row {
        return Ok(());
    }
    let names = |c: &[(String, Kind)]| c.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(",");
    Err(ExportError::Layout {
        file: file.to_string(),
        topic,
        time,
        message: format!(
            "the columns change from [{}] to [{}]; a table needs the same columns in every row",
            names(table),
            names(row)
        ),
    })
}

/// The table files of one log's export.
struct FileTables<'a> {
    log: &'a Path,
    dir: &'a Path,
    format: Format,
    tables: BTreeMap<Topic, Table>,
}

impl Tables for FileTables<'_> {
    fn push(
        &mut self,
        topic: Topic,
        time: f64,
        columns: Vec<(String, Kind)>,
        cells: &[Cell],
    ) -> Result<(), ExportError> {
        let table = match self.tables.entry(topic) {
            std::collections::btree_map::Entry::Occupied(entry) => {
                let table = entry.into_mut();
                check_layout(&self.log.display().to_string(), (topic, time), &table.columns, &columns)?;
                table
            }
            std::collections::btree_map::Entry::Vacant(entry) => {
                let path = table_path(self.log, self.dir, topic, self.format);
                entry.insert(Table::create(&path, self.log, self.format, columns)?)
            }
        };
        table.push(cells)
    }
}

/// What an export reads of a log besides its rows, and the row being made.
struct Rows<'a> {
    topics: &'a [Topic],
    /// The state names of the first `/state` message (the prediction columns).
    state_names: Option<Vec<String>>,
    cells: Vec<Cell>,
    /// `mjsafe_status` says the run completed.
    complete: bool,
}

/// The export as a visitor of the run reader: each message of a topic asked for becomes a row
/// of `out`.
struct Export<'a, T> {
    /// The log, as errors name it.
    file: String,
    rows: Rows<'a>,
    out: T,
    /// A write error, carried out of the reader.
    failure: Option<ExportError>,
}

impl<'a, T: Tables> Export<'a, T> {
    fn new(file: &str, topics: &'a [Topic], out: T) -> Export<'a, T> {
        Export {
            file: file.to_string(),
            rows: Rows {
                topics,
                state_names: None,
                cells: Vec::new(),
                complete: false,
            },
            out,
            failure: None,
        }
    }

    fn fail(&mut self, e: ExportError) -> ReadError {
        self.failure = Some(e);
        ReadError::Foreign {
            file: self.file.clone(),
            message: "export stopped".into(),
        }
    }
}

impl<T: Tables> RunVisitor for Export<'_, T> {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        if name == crate::log::read::STATUS_METADATA {
            self.rows.complete = entries.get("complete").is_some_and(|c| c == "true");
        }
        Ok(())
    }

    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        let Some((time, columns)) = self.rows.row(message)? else {
            return Ok(());
        };
        let cells = std::mem::take(&mut self.rows.cells);
        let result = self.out.push(message.topic, time, columns, &cells);
        self.rows.cells = cells;
        result.map_err(|e| self.fail(e))
    }
}

impl Rows<'_> {
    /// The row `message` makes, if its topic is asked for: its time and columns (its cells
    /// in `self.cells`).
    fn row(&mut self, message: &Message<'_>) -> Result<Option<(f64, Columns)>, ReadError> {
        let topic = message.topic;
        let wanted = self.topics.contains(&topic);
        if !(wanted || topic == Topic::State && self.state_names.is_none()) {
            return Ok(None);
        }
        let record = message.record()?;
        if let Record::State(m) = &record {
            if self.state_names.is_none() {
                self.state_names = Some(m.names.clone());
            }
        }
        let Some(observed) = Observed::of(&record).filter(|_| wanted) else {
            return Ok(None);
        };
        let mut columns = Vec::new();
        table_row(
            observed,
            self.state_names.as_deref(),
            &mut self.cells,
            Some(&mut columns),
        );
        Ok(Some((observed.time(), columns)))
    }
}

/// One table being written.
struct Table {
    output: OutputFile,
    columns: Vec<(String, Kind)>,
    rows: u64,
    sink: Sink,
}

enum Sink {
    Csv(BufWriter<File>),
    Parquet(Box<ParquetTable>),
}

struct ParquetTable {
    schema: SchemaRef,
    builders: Vec<Builder>,
    buffered: usize,
    writer: ArrowWriter<File>,
}

enum Builder {
    F(Float64Builder),
    U(UInt64Builder),
    B(BooleanBuilder),
    S(StringBuilder),
}

/// At most 80 characters of `text` (an ellipsis marks the cut).
fn clipped(text: &str) -> String {
    match text.char_indices().nth(80) {
        Some((at, _)) => format!("{}…", &text[..at]),
        None => text.to_string(),
    }
}

/// The first line of an existing regular file (at most 1 MiB of it), if there is one.
fn existing_first_line(path: &Path) -> Option<String> {
    use std::io::{BufRead, Read};
    let meta = std::fs::symlink_metadata(path).ok()?;
    if !meta.file_type().is_file() {
        return None;
    }
    let file = File::open(path).ok()?;
    let mut line = String::new();
    std::io::BufReader::new(file.take(1 << 20)).read_line(&mut line).ok()?;
    Some(line.trim_end_matches(['\n', '\r']).to_string())
}

impl Table {
    fn create(path: &Path, log: &Path, format: Format, columns: Vec<(String, Kind)>) -> Result<Table, ExportError> {
        if format == Format::Csv {
            // A CSV is replaced only if it is this table: its header line is the one this log
            // gives the topic (a user's CSV that merely starts with `time,` is kept).
            let header: Vec<String> = columns.iter().map(|(n, _)| csv_field(n)).collect();
            if let Some(found) = existing_first_line(path) {
                if found != header.join(",") {
                    return Err(ExportError::Write {
                        file: path.display().to_string(),
                        message: format!(
                            "it exists and is not this log's table (its header `{}` is not `{}`); remove it or choose another --out",
                            clipped(&found),
                            clipped(&header.join(","))
                        ),
                    });
                }
            }
        }
        let output = OutputFile::create(path, format.what(), Replace::IfStartsWith(format.magic()), &[log])?;
        let file = output.try_clone_file()?;
        let write_error = |message: String| ExportError::Write {
            file: path.display().to_string(),
            message,
        };
        let sink = match format {
            Format::Csv => {
                let mut w = BufWriter::with_capacity(1 << 16, file);
                let header: Vec<String> = columns.iter().map(|(n, _)| csv_field(n)).collect();
                writeln!(w, "{}", header.join(",")).map_err(|e| write_error(e.to_string()))?;
                Sink::Csv(w)
            }
            Format::Parquet => {
                let fields: Vec<Field> = columns
                    .iter()
                    .map(|(n, k)| {
                        let t = match k {
                            Kind::F64 => DataType::Float64,
                            Kind::U64 => DataType::UInt64,
                            Kind::Bool => DataType::Boolean,
                            Kind::Text => DataType::Utf8,
                        };
                        Field::new(n, t, false)
                    })
                    .collect();
                let schema = Arc::new(Schema::new(fields));
                let props = WriterProperties::builder()
                    .set_compression(Compression::ZSTD(ZstdLevel::default()))
                    .set_max_row_group_row_count(Some(ROW_GROUP_ROWS))
                    .build();
                let writer =
                    ArrowWriter::try_new(file, schema.clone(), Some(props)).map_err(|e| write_error(e.to_string()))?;
                let builders = columns
                    .iter()
                    .map(|(_, k)| match k {
                        Kind::F64 => Builder::F(Float64Builder::with_capacity(BATCH_ROWS)),
                        Kind::U64 => Builder::U(UInt64Builder::with_capacity(BATCH_ROWS)),
                        Kind::Bool => Builder::B(BooleanBuilder::with_capacity(BATCH_ROWS)),
                        Kind::Text => Builder::S(StringBuilder::new()),
                    })
                    .collect();
                Sink::Parquet(Box::new(ParquetTable {
                    schema,
                    builders,
                    buffered: 0,
                    writer,
                }))
            }
        };
        Ok(Table {
            output,
            columns,
            rows: 0,
            sink,
        })
    }

    fn error(&self, message: String) -> ExportError {
        ExportError::Write {
            file: self.output.target().display().to_string(),
            message,
        }
    }

    fn push(&mut self, cells: &[Cell]) -> Result<(), ExportError> {
        self.rows += 1;
        let result = match &mut self.sink {
            Sink::Csv(w) => write_csv_row(w, cells).map_err(|e| e.to_string()),
            Sink::Parquet(p) => p.push(cells),
        };
        result.map_err(|e| self.error(e))
    }

    fn finish(self) -> Result<PathBuf, ExportError> {
        let error = |message: String| ExportError::Write {
            file: self.output.target().display().to_string(),
            message,
        };
        match self.sink {
            Sink::Csv(mut w) => w.flush().map_err(|e| error(e.to_string()))?,
            Sink::Parquet(mut p) => {
                p.flush_batch().map_err(error)?;
                p.writer.close().map_err(|e| error(e.to_string()))?;
            }
        }
        Ok(self.output.commit()?)
    }
}

impl ParquetTable {
    fn push(&mut self, cells: &[Cell]) -> Result<(), String> {
        for (b, cell) in self.builders.iter_mut().zip(cells) {
            match (b, cell) {
                (Builder::F(b), Cell::F(v)) => b.append_value(*v),
                (Builder::U(b), Cell::U(v)) => b.append_value(*v),
                (Builder::B(b), Cell::B(v)) => b.append_value(*v),
                (Builder::S(b), Cell::S(v)) => b.append_value(v),
                _ => unreachable!("cells follow the columns"),
            }
        }
        self.buffered += 1;
        if self.buffered >= BATCH_ROWS {
            self.flush_batch()?;
        }
        Ok(())
    }

    fn flush_batch(&mut self) -> Result<(), String> {
        if self.buffered == 0 {
            return Ok(());
        }
        let arrays: Vec<ArrayRef> = self
            .builders
            .iter_mut()
            .map(|b| -> ArrayRef {
                match b {
                    Builder::F(b) => Arc::new(b.finish()),
                    Builder::U(b) => Arc::new(b.finish()),
                    Builder::B(b) => Arc::new(b.finish()),
                    Builder::S(b) => Arc::new(b.finish()),
                }
            })
            .collect();
        self.buffered = 0;
        let batch = RecordBatch::try_new(self.schema.clone(), arrays).map_err(|e| e.to_string())?;
        self.writer.write(&batch).map_err(|e| e.to_string())
    }
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// One CSV row. Floats are written in Rust's shortest round-trip form (`NaN`, `inf`, `-inf`
/// for the non-finite values), so a reader parsing them exactly gets the logged bits back.
fn write_csv_row(w: &mut impl Write, cells: &[Cell]) -> std::io::Result<()> {
    for (i, cell) in cells.iter().enumerate() {
        if i > 0 {
            w.write_all(b",")?;
        }
        match cell {
            Cell::F(v) => write!(w, "{v:?}")?,
            Cell::U(v) => write!(w, "{v}")?,
            Cell::B(v) => w.write_all(if *v { b"true" } else { b"false" })?,
            Cell::S(s) => w.write_all(csv_field(s).as_bytes())?,
        }
    }
    w.write_all(b"\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_rows_round_trip_floats_and_quote_text() {
        let mut out = Vec::new();
        let cells = [
            Cell::F(0.1),
            Cell::F(f64::NAN),
            Cell::F(f64::NEG_INFINITY),
            Cell::F(1e-300),
            Cell::U(7),
            Cell::B(true),
            Cell::S("a, \"b\"".into()),
        ];
        write_csv_row(&mut out, &cells).unwrap();
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "0.1,NaN,-inf,1e-300,7,true,\"a, \"\"b\"\"\"\n"
        );
    }

    #[test]
    fn topics_parse_and_views_are_refused() {
        assert_eq!(parse_topics(&[]).unwrap(), table_topics());
        let t = parse_topics(&["/barrier,/state".into(), "/state".into()]).unwrap();
        assert_eq!(t, [Topic::State, Topic::Barrier]);
        assert!(parse_topics(&["/scene".into()])
            .unwrap_err()
            .to_string()
            .contains("not a table"));
        assert!(parse_topics(&["/nope".into()])
            .unwrap_err()
            .to_string()
            .contains("unknown topic"));
    }
}
