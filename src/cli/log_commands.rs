//! `mjsafe export` and `mjsafe info`: a log's tables and description.

use super::*;

pub(super) fn export(
    files: &[PathBuf],
    format: crate::export::Format,
    topics: &[String],
    out: Option<&Path>,
) -> Result<ExitCode> {
    let explicit = !topics.is_empty();
    let topics = crate::export::parse_topics(topics)?;
    // Two logs whose tables would have the same names (the same stem into one directory)
    // would overwrite each other's tables: refused before any is written.
    let dir = |file: &Path| {
        out.map_or_else(
            || file.parent().unwrap_or(Path::new("")).to_path_buf(),
            Path::to_path_buf,
        )
    };
    let tables = |file: &Path| dir(file).join(crate::export::table_stem(file));
    if let Some((a, b)) = same_output_names(files, tables) {
        let shown = match dir(b).display().to_string() {
            d if d.is_empty() => ".".to_string(),
            d => d,
        };
        bail!(
            "{} and {}: both would write {}-*.{} in {shown}; export them into different --out directories",
            a.display(),
            b.display(),
            crate::export::table_stem(b),
            format.extension()
        );
    }
    let mut failed = false;
    for file in files {
        match crate::export::export_log(file, out, &topics, format) {
            Ok(exported) => {
                for (topic, path, rows) in &exported.tables {
                    outln!("{topic}: {rows} rows -> {}", path.display());
                }
                for topic in exported.empty.iter().filter(|_| explicit) {
                    eprintln!("note: {}: no messages on {topic}, no table written", file.display());
                }
                if !exported.complete {
                    eprintln!(
                        "note: {}: the run did not complete (interrupted or stopped on an error): its tables end where its log does",
                        file.display()
                    );
                }
            }
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    Ok(if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS })
}

pub(super) fn info(file: &Path, resolved: bool, json: bool, recover: bool) -> Result<ExitCode> {
    let info = if recover {
        crate::log::info::log_info_recover(file)?
    } else {
        crate::log::info::log_info(file)?
    };
    let code = match &info.error {
        Some(e) => {
            eprintln!("error: {e} (--recover: showing what was read before)");
            ExitCode::FAILURE
        }
        None => ExitCode::SUCCESS,
    };
    if json {
        outln!("{}", serde_json::to_string_pretty(&info).expect("info serialises"));
        return Ok(code);
    }
    outln!("file:      {} ({} bytes)", info.file, info.bytes);
    if info.error.is_some() {
        outln!("messages:  {} read before the damage", info.messages);
    } else {
        match info.chunks {
            Some(chunks) => outln!("messages:  {} in {chunks} chunks", info.messages),
            None => outln!("messages:  {} (counted: no statistics record)", info.messages),
        }
    }
    outln!(
        "time:      {:.3} .. {:.3} s ({:.3} s of simulation time)",
        info.start,
        info.end,
        info.end - info.start
    );
    outln!("channels:");
    let topic_width = info.channels.iter().map(|c| c.topic.len()).max().unwrap_or(0);
    let count_width = info
        .channels
        .iter()
        .map(|c| c.messages.to_string().len())
        .max()
        .unwrap_or(0);
    for c in &info.channels {
        outln!(
            "  ({}) {:<topic_width$}  {:>count_width$} msgs  {} [{}]",
            c.id,
            c.topic,
            c.messages,
            c.schema,
            c.schema_encoding
        );
    }
    let mut scenario_text = None;
    let mut resolved_text = None;
    for (name, entries) in &info.metadata {
        outln!("metadata {name}:");
        let width = entries.keys().map(|k| k.len()).max().unwrap_or(0);
        for (key, value) in entries {
            match key.as_str() {
                "scenario" if name == "mjsafe" => scenario_text = Some(value.clone()),
                "scenario_resolved" if name == "mjsafe" => resolved_text = Some(value.clone()),
                _ => {
                    let mut lines = value.lines();
                    let first = lines.next().unwrap_or(if key == "overrides" { "(none)" } else { "" });
                    outln!("  {key:<width$}  {first}");
                    for line in lines {
                        outln!("  {:<width$}  {line}", "");
                    }
                }
            }
        }
    }
    if let Some(text) = scenario_text {
        outln!("scenario (as written):");
        for line in text.lines() {
            outln!("  | {line}");
        }
    }
    if resolved {
        match resolved_text {
            Some(text) => {
                outln!("scenario (resolved, after overrides):");
                for line in text.lines() {
                    outln!("  | {line}");
                }
            }
            None => eprintln!("warning: the log holds no resolved scenario"),
        }
    }
    Ok(code)
}

/// `mjsafe export`: The time series of logs as tables: one wide, time-indexed CSV or Parquet file per topic
#[derive(Debug, clap::Args)]
pub struct ExportCommand {
    /// Logs (.mcap).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Table format.
    #[arg(long, value_enum, default_value = "csv")]
    format: crate::export::Format,
    /// Topics to export, comma-separated (default: every table topic the log has:
    /// /state, /command/issued, /command/applied, /barrier, /filter, /event, /prediction,
    /// /state/measured, /command/actuated).
    #[arg(long, value_name = "T1,T2,…", value_delimiter = ',')]
    topics: Vec<String>,
    /// Directory of the tables (default: each log's directory).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

impl ExportCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let ExportCommand {
            files,
            format,
            topics,
            out,
        } = self;
        export(&files, format, &topics, out.as_deref())
    }
}

/// `mjsafe info`: Topics, message counts, schemas, time span, mjsafe metadata and scenario of a log.
#[derive(Debug, clap::Args)]
pub struct InfoCommand {
    /// The MCAP log written by `mjsafe run`, `sweep` or `falsify`.
    file: PathBuf,
    /// Also print the effective scenario (after --set overrides).
    #[arg(long)]
    resolved: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// On a damaged log, still show what was read before the damage (counted from the
    /// messages read); the exit status is still non-zero.
    #[arg(long)]
    recover: bool,
}

impl InfoCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let InfoCommand {
            file,
            resolved,
            json,
            recover,
        } = self;
        info(&file, resolved, json, recover)
    }
}
