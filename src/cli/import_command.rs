//! `mjsafe import commonroad FILE.xml --out X.toml`: the scenario a CommonRoad file runs as, with
//! every default written out for a user to edit (docs/commonroad.md).

use super::*;

/// What `import` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ImportFormat {
    /// A CommonRoad XML scenario (2018b or 2020a).
    Commonroad,
}

/// `mjsafe import`: a scenario from another format.
#[derive(Debug, clap::Args)]
pub struct ImportCommand {
    /// The format of FILE.
    #[arg(value_enum)]
    format: ImportFormat,
    /// The file to import.
    file: PathBuf,
    /// The planning problem (its id; default the file's first).
    #[arg(long, value_name = "ID")]
    planning_problem: Option<u64>,
    /// Where to write the scenario (a new TOML file, or one this command wrote).
    #[arg(long, value_name = "X.toml")]
    out: PathBuf,
}

/// The first line of every scenario `import` writes: an existing file without it is kept.
const IMPORT_START: &[u8] = b"# Imported by `mjsafe import commonroad`";

impl ImportCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let ImportCommand {
            format: ImportFormat::Commonroad,
            file,
            planning_problem,
            out,
        } = self;
        // The XML by its absolute path, so the scenario runs from wherever it is written.
        let xml = std::fs::canonicalize(&file).with_context(|| format!("{}: cannot read", file.display()))?;
        let text = crate::commonroad::scenario_text(&xml, planning_problem);
        let loaded = scenario::from_text(&xml, text, &[])?;
        let mut resolved = loaded.scenario.clone();
        if let Some(spec) = &mut resolved.commonroad {
            spec.file = xml.clone();
        }
        let body = toml::to_string(&resolved).context("the scenario as TOML")?;
        let mut text = String::from_utf8_lossy(IMPORT_START).into_owned();
        text.push_str(&format!(
            " from {}: the world of its planning problem with every default written out.\n# `[commonroad]` still names the file: its road users' recorded states are read from it.\n",
            xml.display()
        ));
        text.push_str(&body);
        // The car's limits, commented out: the defaults' car steers and accelerates without limit.
        let vehicle = &crate::commonroad::VEHICLE;
        text.push_str(&format!(
            "\n# The car is a kinematic bicycle that steers and accelerates without limit, and the filters use\n\
             # that (docs/studies.md, \"Real traffic\"). {} steers to {} rad at {} rad/s and\n\
             # accelerates at up to {} m/s²: [vehicle_limits] above declares that, and the analysis warns\n\
             # when the commands went past it (vehicle_limit_ratio). To run on a car with those limits,\n\
             # which the filter does not know of, remove the \"# \" before the lines below.\n",
            vehicle.name, vehicle.steering_lock, vehicle.steering_rate, vehicle.max_acceleration
        ));
        for line in crate::commonroad::limits_toml(vehicle).lines() {
            text.push_str(if line.is_empty() { "#" } else { "# " });
            text.push_str(line);
            text.push('\n');
        }
        // Checked as a scenario before it is written: it loads and gives the same scenario.
        let reread = scenario::from_text(&out, text.clone(), &[])?;
        if reread.scenario != resolved {
            bail!(
                "{}: the written scenario would not read back as the imported one",
                out.display()
            );
        }
        use crate::files::{write_atomically, Replace};
        write_atomically(
            &out,
            "scenario",
            Replace::IfStartsWith(IMPORT_START),
            &[&xml],
            text.as_bytes(),
        )?;
        if let Some(cr) = &loaded.commonroad {
            for line in cr.remarks() {
                eprintln!("{}: {line}", file.display());
            }
        }
        eprintln!("{} written", out.display());
        Ok(ExitCode::from(exit::DONE))
    }
}
