//! Scenario files (TOML in `scenarios/`): parsing, `--set` overrides and validation.
//! Every error names the file, the key and what was expected.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::barrier::Shape;
use crate::delay::DelayProfile;
use crate::road::RoadSpec;
use crate::section::{Section, SectionContext};

#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    #[error("{file}: invalid TOML: {message}")]
    Syntax { file: String, message: String },
    #[error("{file}: key `{key}`: {message}")]
    Field { file: String, key: String, message: String },
    #[error("--set {spec}: {message}")]
    Override { spec: String, message: String },
    /// A `--require NAME=FORMULA` that is not one (its name or formula).
    #[error("--require {flag}: {message}")]
    Require { flag: String, message: String },
}

/// Declares [`Scenario`]: each field is `plain` (read where it is used) or a `section`, a
/// table that checks itself and sets its part of the control loop through
/// [`crate::section::Section`]. A new table is its module plus its line here.
macro_rules! scenario_tables {
    ($($(#[$attr:meta])* $role:ident $field:ident: $ty:ty,)*) => {
        /// A scenario as written in its file (after overrides).
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct Scenario {
            $($(#[$attr])* pub $field: $ty,)*
        }

        impl Scenario {
            /// The tables that are sections, with their keys, in the file's order.
            pub fn sections(&self) -> Vec<(&'static str, &dyn Section)> {
                [$(scenario_tables!(@section self, $role $field)),*].into_iter().flatten().collect()
            }
        }
    };
    (@section $self:ident, section $field:ident) => {
        Some((stringify!($field), &$self.$field as &dyn Section))
    };
    (@section $self:ident, plain $field:ident) => {
        None
    };
}

scenario_tables! {
    /// Short name, used in log file names.
    plain name: String,
    #[serde(default)]
    plain description: String,
    /// Simulated time in seconds.
    plain duration: f64,
    /// `mujoco` (default) or `ode` (the analytic model integrated by RK4).
    #[serde(default)]
    plain plant: PlantKind,
    /// Seed of every random variation (initial-state perturbation, obstacle appearance
    /// jitter, random disturbances): the same seed gives the same run, bit for bit.
    #[serde(default)]
    plain seed: u64,
    plain vehicle: VehicleSpec,
    /// Delay per input channel (channels not listed: no delay): seconds for a constant delay,
    /// or a table `{ profile = "cosine_prediction" | "rational" | "table", … }`.
    #[serde(default)]
    section delays: BTreeMap<String, DelayProfile>,
    /// The delays the controller and its predictors assume, per channel, when they differ from
    /// the actuators' true `delays` (channels not listed: the true delay). Assumptions 1–2
    /// are checked on these; the true delays only have to be physical (D(t) >= 0, finite).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    section assumed_delays: BTreeMap<String, DelayProfile>,
    /// Stochastic actuation per channel: seeded extra latency and dropped commands, unknown to
    /// the controller (which keeps assuming `assumed_delays`, or `delays`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    section actuation: BTreeMap<String, ActuationSpec>,
    /// Actuator dynamics per channel, unknown to the controller: magnitude and rate limits and
    /// a first-order lag between the delayed command and the plant.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    section actuator_dynamics: BTreeMap<String, ActuatorDynamicsSpec>,
    /// What the real vehicle can take, per input channel: the largest |u| in the channel's units
    /// (the bicycle's steering is tan δ). Declared for the analysis, which reports how far the
    /// inputs that reached the vehicle went past them (`vehicle_limit_ratio`); nothing enforces
    /// them (that is `[actuator_dynamics]`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    plain vehicle_limits: BTreeMap<String, f64>,
    /// What the controller reads instead of the true state: a late, biased, noisy measurement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    section sensing: Option<SensingSpec>,
    /// Initial input function per channel on [−D_i, 0) (constant; channels not listed: 0).
    #[serde(default)]
    plain initial_input: BTreeMap<String, f64>,
    #[serde(default)]
    section control: ControlSpec,
    /// The nominal controller: `kind` and its parameters.
    plain nominal: KindSpec,
    /// The safety filter: `kind` and its parameters (default: none).
    #[serde(default)]
    plain filter: KindSpec,
    #[serde(default)]
    section obstacles: Vec<ObstacleSpec>,
    /// State constraints h(x) >= 0 that are not physical obstacles.
    #[serde(default)]
    plain barriers: Vec<Shape>,
    /// Road edges (each a barrier with the vehicle's hull) and lane markings (drawn only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    section road: Option<RoadSpec>,
    /// An additive disturbance B_ω ω(t) on the ODE plant ((3.24), (4.12)).
    #[serde(default)]
    section disturbance: Option<DisturbanceSpec>,
    /// A place a planar vehicle should reach (the progress metrics measure against it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    section goal: Option<GoalSpec>,
    /// What the controller assumes of moving obstacles (`[actor_knowledge]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    section actor_knowledge: Option<ActorKnowledgeSpec>,
    /// `[[requirements]]`: STL formulas over the run's signals, each reported as
    /// `req.<name>` (its robustness at t = 0; docs/requirements.md).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    section requirements: Vec<RequirementSpec>,
    /// `[commonroad]`: the world of a CommonRoad scenario file, its defaults under every key the
    /// scenario does not write itself (docs/commonroad.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    plain commonroad: Option<crate::commonroad::CommonRoadSpec>,
    /// `[log]`: what the log records beyond its defaults (docs/log-format.md).
    #[serde(default, skip_serializing_if = "LogSpec::is_default")]
    plain log: LogSpec,
}

/// The `[log]` table.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogSpec {
    /// `/barrier` with one entry per barrier of the filter (each pair of a footprint's covering
    /// circle and an obstacle's, named `<obstacle>/<i>-<j>`) instead of one per obstacle.
    #[serde(default)]
    pub barrier_pairs: bool,
}

impl LogSpec {
    fn is_default(&self) -> bool {
        *self == LogSpec::default()
    }
}

/// The `[[requirements]]` section: its spec and checks are [`crate::requirement`]'s.
pub use crate::requirement::{
    check_requirement_name, parse_require_flag, RequirementSpec, MAX_REQUIREMENTS, MAX_REQUIREMENT_NAME,
};

/// The `[goal]` table: its spec and checks are [`crate::goal`]'s.
pub use crate::goal::{GoalSpec, MAX_GOAL_POINTS, MAX_GOAL_POLYGONS};

/// The `[disturbance]` table: its spec, checks and signals are [`crate::disturbance`]'s.
pub use crate::disturbance::DisturbanceSpec;

/// The `[vehicle]` table: what every vehicle has, and the keys of the kind's own (e.g. `a`, `b`
/// of `linear`), which the kind's registered parameter type checks when the episode is built
/// (`mjsafe::vehicle_registry`).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSpec {
    /// A registered vehicle kind (`mjsafe::vehicle_registry`): `bicycle`, `unicycle`, … or a
    /// user's.
    pub kind: String,
    /// MJCF file, relative to the scenario file (the kinds with an MJCF model).
    pub model: Option<PathBuf>,
    /// The kind's own keys (the table's keys other than [`VehicleSpec::KEYS`]), e.g. `a`, `b`
    /// (A and B of ẋ = A x + B u, arrays of rows) of `linear`; the kind's builder parses them
    /// into its parameter type.
    pub params: toml::Table,
    /// Initial state x(0), in the vehicle's state order.
    pub initial_state: Vec<f64>,
    /// Uniform random perturbation of x(0): component i moves by up to ± this (seeded).
    pub initial_perturbation: Option<Vec<f64>>,
    /// Overrides the model's `<option timestep>` (seconds); required without a model.
    pub timestep: Option<f64>,
    /// Overrides the model's `<option integrator>`: "euler", "rk4" or "implicit".
    pub integrator: Option<Integrator>,
    /// The vehicle's footprint, a rectangle L × W about its planar position (covering circles,
    /// docs/actors.md "Footprints"); absent: the hull circle.
    pub footprint: Option<crate::footprint::Rectangle>,
}

/// The keys every vehicle has, as [`VehicleSpec`] reads them (its other keys are the kind's).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CommonVehicleKeys {
    kind: String,
    #[serde(default)]
    model: Option<PathBuf>,
    initial_state: Vec<f64>,
    #[serde(default)]
    initial_perturbation: Option<Vec<f64>>,
    #[serde(default)]
    timestep: Option<f64>,
    #[serde(default)]
    integrator: Option<Integrator>,
    #[serde(default)]
    footprint: Option<crate::footprint::Rectangle>,
}

impl VehicleSpec {
    /// The keys every vehicle has; any other key of `[vehicle]` belongs to the kind.
    pub const KEYS: [&'static str; 7] = [
        "kind",
        "model",
        "initial_state",
        "initial_perturbation",
        "timestep",
        "integrator",
        "footprint",
    ];
}

impl<'de> Deserialize<'de> for VehicleSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let mut params = toml::Table::deserialize(deserializer)?;
        let common: toml::Table = VehicleSpec::KEYS
            .iter()
            .filter_map(|key| params.remove(*key).map(|value| (key.to_string(), value)))
            .collect();
        // An error inside names its key (`key `initial_state`: …`), which `parse` appends to
        // `vehicle`.
        let keys: CommonVehicleKeys = serde_path_to_error::deserialize(toml::Value::Table(common)).map_err(|e| {
            let inner = e.path().to_string();
            let message = e.into_inner().to_string();
            match inner.as_str() {
                "." => D::Error::custom(message),
                _ => D::Error::custom(format!("key `{inner}`: {message}")),
            }
        })?;
        Ok(VehicleSpec {
            kind: keys.kind,
            model: keys.model,
            params,
            initial_state: keys.initial_state,
            initial_perturbation: keys.initial_perturbation,
            timestep: keys.timestep,
            integrator: keys.integrator,
            footprint: keys.footprint,
        })
    }
}

impl Serialize for VehicleSpec {
    /// In the order of the keys as they always were: kind, model, the kind's own keys,
    /// initial_state, initial_perturbation, timestep, integrator (absent ones left out).
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(None)?;
        map.serialize_entry("kind", &self.kind)?;
        if let Some(model) = &self.model {
            map.serialize_entry("model", model)?;
        }
        for (key, value) in &self.params {
            map.serialize_entry(key, value)?;
        }
        map.serialize_entry("initial_state", &self.initial_state)?;
        if let Some(perturbation) = &self.initial_perturbation {
            map.serialize_entry("initial_perturbation", perturbation)?;
        }
        if let Some(timestep) = &self.timestep {
            map.serialize_entry("timestep", timestep)?;
        }
        if let Some(integrator) = &self.integrator {
            map.serialize_entry("integrator", integrator)?;
        }
        if let Some(footprint) = &self.footprint {
            map.serialize_entry("footprint", footprint)?;
        }
        map.end()
    }
}

/// The `[control]` table: its spec and checks are [`crate::control_spec`]'s.
pub use crate::control_spec::{ControlSpec, DEFAULT_CHAIN_TOLERANCE};

/// A `nominal` or `filter` table: the registered `kind` it names ([`crate::registry`]) and
/// that kind's parameters (the table's other keys, checked and normalised by the kind's
/// parameter type when the scenario is parsed).
#[derive(Debug, Clone, PartialEq)]
pub struct KindSpec {
    pub kind: String,
    pub params: toml::Table,
}

impl KindSpec {
    /// A kind with its parameters as a TOML table (not yet checked).
    pub fn new(kind: &str, params: toml::Table) -> KindSpec {
        KindSpec {
            kind: kind.to_string(),
            params,
        }
    }
}

impl Default for KindSpec {
    /// No safety filter.
    fn default() -> Self {
        KindSpec::new("none", toml::Table::new())
    }
}

impl<'de> Deserialize<'de> for KindSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let mut params = toml::Table::deserialize(deserializer)?;
        match params.remove("kind") {
            Some(toml::Value::String(kind)) => Ok(KindSpec { kind, params }),
            Some(other) => Err(D::Error::custom(format!(
                "key `kind`: expected a string, found {}",
                other.type_str()
            ))),
            None => Err(D::Error::missing_field("kind")),
        }
    }
}

impl Serialize for KindSpec {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        crate::params::serialize_kind_table(&self.kind, &self.params, serializer)
    }
}

/// The `[[obstacles]]` section and `[actor_knowledge]`: their specs and checks are
/// [`crate::obstacles`]'.
pub use crate::obstacles::{ActorKnowledgeSpec, FollowingSpec, MotionSpec, ObstacleShape, ObstacleSpec};

/// Which plant a scenario runs on (scenario key `plant`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlantKind {
    /// MuJoCo 2.2.2 stepping the vehicle's MJCF model.
    #[default]
    Mujoco,
    /// Pure-Rust RK4 of the analytic model (the reference).
    Ode,
}

/// One channel's stochastic actuation (`[actuation.<channel>]`): its spec, checks and build
/// are [`crate::delay`]'s.
pub use crate::delay::{ActuationSpec, ExtraLatencySpec};

/// One channel's actuator dynamics (`[actuator_dynamics.<channel>]`): its spec, checks and
/// build are [`crate::actuator`]'s.
pub use crate::actuator::ActuatorDynamicsSpec;

/// The sensor the controller reads (`[sensing]`): its spec, checks and build are
/// [`crate::sensing`]'s.
pub use crate::sensing::SensingSpec;

/// MuJoCo's numerical integrator (`vehicle.integrator`, the model's `<option integrator>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    Euler,
    Rk4,
    Implicit,
}

/// A scenario with where it came from: what the episode and the log need.
#[derive(Debug, Clone)]
pub struct LoadedScenario {
    pub scenario: Scenario,
    /// The file it was read from.
    pub path: PathBuf,
    /// The file's text as written (stored in the log).
    pub source_text: String,
    /// `--set` overrides applied, in order.
    pub overrides: Vec<String>,
    /// The CommonRoad file of `[commonroad]`, as read.
    pub commonroad: Option<std::sync::Arc<mjsafe_commonroad::CommonRoad>>,
}

impl LoadedScenario {
    /// What the scenario's tables see of the rest of it ([`Section`]).
    pub fn section_context(&self) -> SectionContext<'_> {
        let sc = &self.scenario;
        SectionContext {
            duration: sc.duration,
            seed: sc.seed,
            ode_plant: sc.plant == PlantKind::Ode,
            state_dim: sc.vehicle.initial_state.len(),
            extent: OBSTACLE_EXTENT,
            state_extent: STATE_EXTENT,
            initial_input: &sc.initial_input,
            commonroad: self.commonroad.as_deref(),
        }
    }

    /// The model path resolved against the scenario file's directory.
    /// A built-in model (`mjsafe:<name>`, [`crate::models`]) is its name.
    pub fn model_path(&self) -> Option<PathBuf> {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        self.scenario
            .vehicle
            .model
            .as_ref()
            .map(|m| match crate::models::is_builtin(m) {
                true => m.clone(),
                false => dir.join(m),
            })
    }

    /// The CommonRoad file of `[commonroad]`, resolved against the scenario file's directory.
    pub fn commonroad_path(&self) -> Option<PathBuf> {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        self.scenario.commonroad.as_ref().map(|c| dir.join(&c.file))
    }

    /// The files a run of this scenario reads (the scenario, its model, its CommonRoad file):
    /// outputs never replace them.
    pub fn inputs(&self) -> Vec<PathBuf> {
        let model = self.model_path().filter(|m| !crate::models::is_builtin(m));
        std::iter::once(self.path.clone())
            .chain(model)
            .chain(self.commonroad_path())
            .collect()
    }

    /// The error for a field of this scenario.
    pub fn field_error(&self, key: &str, message: impl Into<String>) -> ScenarioError {
        ScenarioError::Field {
            file: self.path.display().to_string(),
            key: key.to_string(),
            message: message.into(),
        }
    }

    /// The effective scenario (after overrides) as TOML.
    pub fn resolved_toml(&self) -> String {
        toml::to_string(&self.scenario).unwrap_or_default()
    }
}

/// Reads a scenario file and applies `--set key.path=VALUE` overrides (VALUE in TOML syntax).
/// A CommonRoad file (`.xml`) is the scenario `[commonroad] file = …` beside it: its world with
/// every default (docs/commonroad.md).
pub fn load(path: &Path, overrides: &[String]) -> Result<LoadedScenario, ScenarioError> {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xml")) {
        // `commonroad.file=…` on a CommonRoad file (a sweep over files sets it per run) runs
        // that file as if it were given: its errors and its log name it.
        let (file, rest) = commonroad_file_override(path, overrides)?;
        return from_text(&file, crate::commonroad::scenario_text(&file, None), &rest);
    }
    let text = crate::files::read_text_limited(path, "scenario", crate::files::SCENARIO_LIMIT)?;
    from_text(path, text, overrides)
}

/// The CommonRoad file a run of the CommonRoad file `path` reads (`path`, or the one a
/// `commonroad.file` override names, relative to `path`'s directory) and the other overrides.
fn commonroad_file_override(path: &Path, overrides: &[String]) -> Result<(PathBuf, Vec<String>), ScenarioError> {
    let is_file = |spec: &String| {
        spec.split_once('=')
            .is_some_and(|(key, _)| canonical_key(key) == "commonroad.file")
    };
    let name = path
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let mut probe = toml::Table::new();
    let mut commonroad = toml::Table::new();
    commonroad.insert("file".into(), toml::Value::String(name.clone()));
    probe.insert("commonroad".into(), toml::Value::Table(commonroad));
    for spec in overrides.iter().filter(|s| is_file(s)) {
        apply_override(&mut probe, spec)?;
    }
    let file = match probe["commonroad"].get("file").and_then(toml::Value::as_str) {
        Some(file) if file != name => path.parent().unwrap_or_else(|| Path::new(".")).join(file),
        _ => return Ok((path.to_path_buf(), overrides.to_vec())),
    };
    Ok((file, overrides.iter().filter(|s| !is_file(s)).cloned().collect()))
}

/// The comment that names a file to load for a kind that is not built in (written into a
/// counterexample, read back when the kind is unknown).
const LOAD_COMMENT: &str = "# mjsafe-load: ";

/// Comment lines for a scenario file: for each of `scenario`'s filter and nominal kinds that a
/// Python module registered, which file to load and how (`python -m mjsafe --load FILE …`).
pub fn load_lines(scenario: &Scenario) -> String {
    let registry = crate::registry::registry();
    let origins = [
        (
            "filter",
            &scenario.filter.kind,
            registry.filter_origin(&scenario.filter.kind),
        ),
        (
            "nominal",
            &scenario.nominal.kind,
            registry.nominal_origin(&scenario.nominal.kind),
        ),
    ];
    let mut lines = String::new();
    for (section, kind, origin) in origins {
        if let Some(file) = origin {
            lines.push_str(&format!(
                "# {section} kind `{kind}` is written in Python: run this file with `python -m mjsafe --load {file} run <this file>`\n{LOAD_COMMENT}{file}\n"
            ));
        }
    }
    lines
}

/// An unknown kind in a file that names the Python files of its kinds says what to load.
fn with_load_hint(error: ScenarioError, text: &str) -> ScenarioError {
    let files: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix(LOAD_COMMENT)).collect();
    match error {
        ScenarioError::Field { file, key, message } if message.contains("unknown kind") && !files.is_empty() => {
            let loads: Vec<String> = files.iter().map(|f| format!("--load {f}")).collect();
            ScenarioError::Field {
                file,
                key,
                message: format!(
                    "{message}; the file says the kind is written in Python: run it with `python -m mjsafe {} run …`",
                    loads.join(" ")
                ),
            }
        }
        other => other,
    }
}

/// A scenario from its text, as if read from `path` (which names it in errors and anchors the
/// relative model path), with overrides applied and validated.
pub fn from_text(path: &Path, text: String, overrides: &[String]) -> Result<LoadedScenario, ScenarioError> {
    let file = path.display().to_string();
    let (scenario, commonroad) = parse_with_world(&text, &file, overrides).map_err(|e| with_load_hint(e, &text))?;
    let loaded = LoadedScenario {
        scenario,
        path: path.to_path_buf(),
        source_text: text,
        overrides: overrides.to_vec(),
        commonroad,
    };
    validate(&loaded).map_err(|e| with_load_hint(e, &loaded.source_text))?;
    Ok(loaded)
}

/// Parses scenario text; `file` names it in errors.
pub fn parse(text: &str, file: &str, overrides: &[String]) -> Result<Scenario, ScenarioError> {
    parse_with_world(text, file, overrides).map(|(scenario, _)| scenario)
}

/// [`parse`], and the CommonRoad file of `[commonroad]` (read relative to `file`'s directory),
/// whose world fills every key the scenario and its overrides leave out.
fn parse_with_world(
    text: &str,
    file: &str,
    overrides: &[String],
) -> Result<(Scenario, Option<std::sync::Arc<mjsafe_commonroad::CommonRoad>>), ScenarioError> {
    let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| ScenarioError::Syntax {
        file: file.to_string(),
        message: e
            .to_string()
            .trim()
            .replace('\n', " ")
            // toml reads an integer beyond 64 bits as serde's i128 and names that type.
            .replace("invalid type: integer ", "invalid value: integer ")
            .replace(
                "` as i128, expected any valid TOML value",
                "`, beyond TOML's 64-bit integers (expected a float such as 1e20, or a smaller integer)",
            )
            .replace("` as i128", "`"),
    })?;
    // A sweep file names its scenario and sweeps it: it is `mjsafe sweep`'s, not a scenario.
    if ["scenario", "scenarios"].iter().any(|k| table.contains_key(*k))
        && ["grid", "range", "random"].iter().any(|k| table.contains_key(*k))
    {
        return Err(ScenarioError::Field {
            file: file.to_string(),
            key: "scenario".into(),
            message: format!(
                "this is a sweep file (it names a scenario and sweeps it), not a scenario: run it with `mjsafe sweep --sweep {file}`"
            ),
        });
    }
    let world = commonroad_world(&mut table, file, overrides)?;
    for spec in overrides {
        apply_override(&mut table, spec)?;
    }
    // Scenarios imported before motions had kinds name a recording as `recorded = ID`.
    let obstacles = table
        .get("obstacles")
        .and_then(|o| o.as_array())
        .map_or(&[][..], |o| o.as_slice());
    if let Some((i, id)) = (obstacles.iter().enumerate()).find_map(|(i, o)| Some((i, o.get("recorded")?))) {
        return Err(ScenarioError::Field {
            file: file.to_string(),
            key: format!("obstacles.{i}.recorded"),
            message: format!(
                "a recorded road user is now a motion kind: expected `motion = {{ kind = \"recorded\", id = {id} }}`"
            ),
        });
    }
    let whole = toml::Value::Table(table);
    let mut scenario: Scenario = serde_path_to_error::deserialize(whole).map_err(|e| {
        let key = e.path().to_string();
        let message = plain_serde_message(&e.into_inner().to_string());
        // A message about an inner key of a table names it (`key `kind`: …`).
        let (key, message) = match message.strip_prefix("key `").and_then(|m| m.split_once("`: ")) {
            Some((inner, rest)) if key != "." => (format!("{key}.{inner}"), rest.to_string()),
            _ => (key, message),
        };
        ScenarioError::Field {
            file: file.to_string(),
            key: if key == "." { "(top level)".into() } else { key },
            message,
        }
    })?;
    // Each kind's parameters, checked and normalised (defaults filled in) by its own type.
    let field = |e: crate::params::ParamError| ScenarioError::Field {
        file: file.to_string(),
        key: e.key,
        message: e.message,
    };
    let registry = crate::registry::registry();
    scenario.nominal.params = registry
        .check_nominal(&scenario.nominal.kind, &scenario.nominal.params)
        .map_err(field)?;
    scenario.filter.params = registry
        .check_filter(&scenario.filter.kind, &scenario.filter.params)
        .map_err(field)?;
    for (i, o) in scenario.obstacles.iter_mut().enumerate() {
        if let Some(m) = &mut o.motion {
            m.params = registry
                .check_motion(&format!("obstacles.{i}.motion"), &m.kind, &m.params)
                .map_err(field)?;
        }
    }
    Ok((scenario, world))
}

pub use crate::message::plain_serde_message;

/// The world of `table`'s `[commonroad]` (as the `overrides` leave it) filled in where the table
/// is silent (docs/commonroad.md); the file as read. `file` names the scenario.
fn commonroad_world(
    table: &mut toml::Table,
    file: &str,
    overrides: &[String],
) -> Result<Option<std::sync::Arc<mjsafe_commonroad::CommonRoad>>, ScenarioError> {
    let field = |key: String, message: String| ScenarioError::Field {
        file: file.to_string(),
        key,
        message,
    };
    let mut probe = toml::Table::new();
    if let Some(c) = table.get("commonroad") {
        probe.insert("commonroad".into(), c.clone());
    }
    for spec in overrides.iter().filter(|s| s.trim_start().starts_with("commonroad.")) {
        apply_override(&mut probe, spec)?;
    }
    let Some(value) = probe.remove("commonroad") else {
        return Ok(None);
    };
    let spec: crate::commonroad::CommonRoadSpec = serde_path_to_error::deserialize(value).map_err(|e| {
        let inner = e.path().to_string();
        let key = if inner == "." {
            "commonroad".to_string()
        } else {
            format!("commonroad.{inner}")
        };
        field(key, plain_serde_message(&e.into_inner().to_string()))
    })?;
    let dir = Path::new(file).parent().unwrap_or_else(|| Path::new("."));
    let (cr, defaults) = crate::commonroad::defaults(&spec, dir).map_err(|(key, message)| field(key, message))?;
    crate::commonroad::fill(table, defaults, overrides);
    Ok(Some(cr))
}

/// The field a dotted override key names, spelled one way: array indices as numbers
/// (`obstacles.00.radius` and `obstacles.+0.radius` are `obstacles.0.radius`, as an override
/// applies them), so two spellings of one field are seen to be one.
pub fn canonical_key(key: &str) -> String {
    key.trim()
        .split('.')
        .map(|segment| match segment.parse::<usize>() {
            Ok(index) => index.to_string(),
            Err(_) => segment.to_string(),
        })
        .collect::<Vec<_>>()
        .join(".")
}

/// The largest |coordinate| and radius of an obstacle, metres.
const OBSTACLE_EXTENT: f64 = 1e9;

/// The largest |component| of an initial state, its perturbation bound, and a sensor's bias
/// or noise (state units).
const STATE_EXTENT: f64 = 1e9;

/// Checks the form of one `a.b.c=VALUE` override (a dotted key, `=`, a TOML value) without a
/// scenario to apply it to: what `--set` rejects whatever the scenario.
pub fn check_override(spec: &str) -> Result<(), ScenarioError> {
    apply_override(&mut toml::Table::new(), spec)
}

/// Applies one `a.b.c=VALUE` override; numeric segments index arrays (`obstacles.0.radius`).
/// The value of `--set KEY=VALUE` (and of a `--grid` value): a TOML literal (`0.4`, `'text'`,
/// `[1, 2]`, `{ kind = 'none' }`, `true`), or a bare word taken as a string (`gamma_m`, `ode`,
/// `../models/car.xml`: a letter, `_`, `.` or `/` first, then letters, digits and `_-./:`), so
/// a string needs no shell quotes around TOML quotes. The schema then checks its type as for
/// any value.
pub fn override_value(raw: &str) -> Result<toml::Value, String> {
    let raw = raw.trim();
    if let Ok(table) = format!("value = {raw}").parse::<toml::Table>() {
        return Ok(table.get("value").cloned().expect("parsed above"));
    }
    let bare = raw.starts_with(|c: char| c.is_ascii_alphabetic() || "_./".contains(c))
        && raw.chars().all(|c| c.is_ascii_alphanumeric() || "_-./:".contains(c));
    if bare {
        return Ok(toml::Value::String(raw.to_string()));
    }
    let digits = raw.strip_prefix(['-', '+']).unwrap_or(raw);
    if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!(
            "`{raw}` is outside TOML's integers (`{}` to `{}`); a float is written with a decimal point",
            i64::MIN,
            i64::MAX
        ));
    }
    Err(format!(
        "`{raw}` is not a TOML value or a bare word (numbers as 0.4, strings as gamma_m or quoted as '\"text\"', arrays as [1, 2])"
    ))
}

fn apply_override(table: &mut toml::Table, spec: &str) -> Result<(), ScenarioError> {
    let err = |message: String| ScenarioError::Override {
        spec: spec.to_string(),
        message,
    };
    let (key, raw) = spec
        .split_once('=')
        .ok_or_else(|| err("expected KEY=VALUE, e.g. delays.steering=0.4".into()))?;
    // `KEY+=VALUE` appends VALUE to the array at KEY (made when absent): `--require`.
    let (key, append) = match key.trim().strip_suffix('+') {
        Some(key) => (key.trim(), true),
        None => (key.trim(), false),
    };
    let value = override_value(raw).map_err(err)?;
    let segments: Vec<&str> = key.split('.').collect();
    if segments.iter().any(|s| s.is_empty()) {
        return Err(err(format!("`{key}` is not a dotted key")));
    }
    let mut current = table
        .entry(segments[0].to_string())
        .or_insert_with(|| toml::Value::Table(Default::default()));
    for (depth, segment) in segments.iter().enumerate().skip(1) {
        let parent = segments[..depth].join(".");
        current = match current {
            toml::Value::Table(t) => t
                .entry(segment.to_string())
                .or_insert_with(|| toml::Value::Table(Default::default())),
            toml::Value::Array(items) => {
                let index: usize = segment
                    .parse()
                    .map_err(|_| err(format!("`{parent}` is an array: `{segment}` must be an index")))?;
                let len = items.len();
                items
                    .get_mut(index)
                    .ok_or_else(|| err(format!("`{parent}` has {len} entries, index {index} is out of range")))?
            }
            _ => return Err(err(format!("`{parent}` is a value, not a table"))),
        };
    }
    if append {
        match current {
            toml::Value::Array(items) => items.push(value),
            // Made just now by the walk above: the key was absent.
            toml::Value::Table(t) if t.is_empty() => *current = toml::Value::Array(vec![value]),
            _ => {
                return Err(err(format!(
                    "`{key}` is not an array: `{key}+=VALUE` appends to an array"
                )))
            }
        }
        return Ok(());
    }
    *current = value;
    Ok(())
}

/// The `--set` override of `--require NAME=FORMULA`: `requirements+={name = …, formula = …}`
/// (the name and the formula checked first: one error line naming the flag).
pub fn require_override(flag: &str) -> Result<String, ScenarioError> {
    let (name, formula) = parse_require_flag(flag).map_err(|message| ScenarioError::Require {
        flag: flag.to_string(),
        message,
    })?;
    let quote = |text: &str| toml::Value::String(text.to_string()).to_string();
    Ok(format!(
        "requirements+={{name = {}, formula = {}}}",
        quote(&name),
        quote(&formula)
    ))
}

fn positive_finite(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// Checks what serde cannot: signs, ranges and consistency. Model-dependent checks (state
/// size, channel names, timestep multiples) happen when the episode binds the model.
/// Why `name` cannot name output files (`<name>-….mcap` inside the output directory), if it
/// cannot: it must be one path component, so it never leaves the directory.
pub fn file_name_problem(name: &str) -> Option<String> {
    if name.trim().is_empty() {
        return Some("expected a non-empty name".into());
    }
    if name == "." || name == ".." || name.contains(['/', '\\', '\0']) {
        return Some(format!(
            "expected one path component, without `/` or `\\` and other than `.` and `..` (it names the log files inside the output directory), found {name:?}"
        ));
    }
    None
}

fn validate(s: &LoadedScenario) -> Result<(), ScenarioError> {
    let sc = &s.scenario;
    if let Some(problem) = file_name_problem(&sc.name) {
        return Err(s.field_error("name", problem));
    }
    if !positive_finite(sc.duration) {
        return Err(s.field_error(
            "duration",
            format!("expected a positive number of seconds, found {}", sc.duration),
        ));
    }
    if let Some(h) = sc.vehicle.timestep {
        if !positive_finite(h) {
            return Err(s.field_error(
                "vehicle.timestep",
                format!("expected a positive number of seconds, found {h}"),
            ));
        }
    }
    if sc.vehicle.initial_state.iter().any(|v| !v.is_finite()) {
        return Err(s.field_error("vehicle.initial_state", "expected finite numbers"));
    }
    if let Some(v) = sc.vehicle.initial_state.iter().find(|v| v.abs() > STATE_EXTENT) {
        return Err(s.field_error(
            "vehicle.initial_state",
            format!("expected components within ±{STATE_EXTENT:e} (the models and barriers lose their precision or overflow beyond), found {v:e}"),
        ));
    }
    let cx = s.section_context();
    for (key, section) in sc.sections() {
        section
            .validate(key, &cx)
            .map_err(|e| s.field_error(&e.key, e.message))?;
    }
    validate_inputs(s)?;
    validate_barriers_and_names(s)
}

/// `initial_input`, `vehicle_limits` and the initial perturbation.
fn validate_inputs(s: &LoadedScenario) -> Result<(), ScenarioError> {
    let sc = &s.scenario;
    for (channel, value) in &sc.initial_input {
        if !value.is_finite() {
            return Err(s.field_error(
                &format!("initial_input.{channel}"),
                format!("expected a finite number, found {value}"),
            ));
        }
    }
    for (channel, limit) in &sc.vehicle_limits {
        if !(limit.is_finite() && *limit > 0.0 && *limit <= STATE_EXTENT) {
            return Err(s.field_error(
                &format!("vehicle_limits.{channel}"),
                format!("expected the largest |u| the vehicle takes, a number > 0 and at most {STATE_EXTENT:e}, found {limit}"),
            ));
        }
    }
    if let Some(p) = &sc.vehicle.initial_perturbation {
        if p.len() != sc.vehicle.initial_state.len()
            || p.iter().any(|v| !v.is_finite() || *v < 0.0 || *v > STATE_EXTENT)
        {
            return Err(s.field_error(
                "vehicle.initial_perturbation",
                format!("expected one bound >= 0 per initial_state component, each at most {STATE_EXTENT:e}"),
            ));
        }
    }
    Ok(())
}

/// Obstacle `i`'s motion built by its registered kind (None for an obstacle that stands), with
/// its seeded variations; errors name the scenario key.
pub fn motion_of(s: &LoadedScenario, i: usize) -> Result<Option<crate::actor::ActorMotion>, crate::params::ParamError> {
    s.scenario.obstacles[i].motion(i, &(&s.section_context()).into())
}

/// `barriers` and the footprint: shapes and extents; one name for each barrier, obstacle and
/// road edge.
fn validate_barriers_and_names(s: &LoadedScenario) -> Result<(), ScenarioError> {
    let sc = &s.scenario;
    for (i, b) in sc.barriers.iter().enumerate() {
        let ok = match b {
            Shape::Ball {
                indices,
                centre,
                radius,
                ..
            } => {
                !indices.is_empty()
                    && indices.len() == centre.len()
                    && centre.iter().all(|c| c.is_finite())
                    && positive_finite(*radius)
            }
            Shape::HalfSpace { coefficients, offset } => {
                !coefficients.is_empty() && coefficients.iter().all(|c| c.is_finite()) && offset.is_finite()
            }
            Shape::Quadratic { q, c, d } => {
                q.iter().all(|row| row.len() == q.len())
                    && q.iter().flatten().chain(c).all(|v| v.is_finite())
                    && d.is_finite()
            }
            // Not a scenario key (`#[serde(skip)]`): built by the episode.
            Shape::BodyCircle { .. }
            | Shape::BodyHalfSpace { .. }
            | Shape::BodyCurve { .. }
            | Shape::Headway { .. } => false,
        };
        if !ok {
            return Err(s.field_error(
                &format!("barriers.{i}"),
                "expected a ball (indices and centre of equal length, radius > 0) or a half-space (finite coefficients and offset)",
            ));
        }
    }
    if let Some(footprint) = &sc.vehicle.footprint {
        footprint
            .check(OBSTACLE_EXTENT)
            .map_err(|e| s.field_error(&format!("vehicle.footprint.{}", e.key), e.message))?;
    }
    // Names key the obstacles' barrier values, events and table columns: one each. A name
    // left out is `obstacle_<index>`; the barriers are `barrier_<index>`.
    let mut names: std::collections::BTreeMap<String, String> = (0..sc.barriers.len())
        .map(|j| (format!("barrier_{j}"), format!("barriers.{j}")))
        .collect();
    for (i, o) in sc.obstacles.iter().enumerate() {
        let key = format!("obstacles.{i}.name");
        let name = o.name.clone().unwrap_or_else(|| format!("obstacle_{i}"));
        if name.trim().is_empty() {
            return Err(s.field_error(&key, "expected a name that is not empty"));
        }
        if let Some(other) = names.insert(name.clone(), format!("obstacles.{i}")) {
            return Err(s.field_error(
                &key,
                format!("`{name}` is already the name of {other}; names must be unique (they key the logged barriers and table columns)"),
            ));
        }
    }
    // Road edges are barriers too (`road_edge_<index>` unless named).
    let edges = sc.road.as_ref().map_or(&[][..], |r| &r.edges[..]);
    for (i, edge) in edges.iter().enumerate() {
        let key = format!("road.edges.{i}.name");
        let name = edge.name(i);
        if name.trim().is_empty() {
            return Err(s.field_error(&key, "expected a name that is not empty"));
        }
        if let Some(other) = names.insert(name.clone(), format!("road.edges.{i}")) {
            return Err(s.field_error(
                &key,
                format!("`{name}` is already the name of {other}; names must be unique (they key the logged barriers and table columns)"),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
name = "t"
duration = 1.0
[vehicle]
kind = "double_integrator_1d"
model = "m.xml"
initial_state = [0.0, 0.0]
[nominal]
kind = "constant"
input = [1.0]
"#;

    #[test]
    fn minimal_scenario_parses_with_defaults() {
        let s = parse(MINIMAL, "t.toml", &[]).unwrap();
        assert_eq!(s.filter, KindSpec::default());
        assert!(s.obstacles.is_empty());
    }

    #[test]
    fn unknown_key_is_named() {
        let text = format!("{MINIMAL}\n[control]\nperiod = 0.1\nrate = 3\n");
        let err = parse(&text, "t.toml", &[]).unwrap_err().to_string();
        assert!(
            err.contains("t.toml") && err.contains("control") && err.contains("rate"),
            "{err}"
        );
    }

    #[test]
    fn wrong_type_names_key_and_expectation() {
        let err = parse(MINIMAL, "t.toml", &["duration='long'".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("duration") && err.contains("expected"), "{err}");
    }

    #[test]
    fn serde_messages_name_no_rust_types() {
        assert_eq!(
            plain_serde_message("invalid type: integer `3`, expected struct VehicleSpec"),
            "invalid type: integer `3`, expected a table"
        );
        assert!(
            plain_serde_message("data did not match any variant of untagged enum DelayProfile")
                .starts_with("expected a delay in seconds")
        );
        assert_eq!(
            plain_serde_message("invalid type: string \"x\", expected a sequence"),
            "invalid type: string \"x\", expected an array"
        );
        assert_eq!(
            plain_serde_message("invalid value: integer `18446744073709551616` as i128, expected usize"),
            "invalid value: integer `18446744073709551616`, expected a whole number >= 0"
        );
        let err = parse(MINIMAL, "t.toml", &["vehicle=3".into()]).unwrap_err().to_string();
        assert!(
            !err.contains("VehicleSpec") && err.contains("expected a table"),
            "{err}"
        );
        let err = parse(MINIMAL, "t.toml", &["delays.acceleration='slow'".into()])
            .unwrap_err()
            .to_string();
        assert!(
            !err.contains("DelayProfile") && err.contains("delays.acceleration"),
            "{err}"
        );
    }

    #[test]
    fn vehicle_keys_are_every_vehicles_or_the_kinds() {
        // The common keys are read (and their errors named) here; the others are the kind's,
        // kept for its parameter type and written back in their place.
        let s = parse(MINIMAL, "t.toml", &["vehicle.a=[[1.0]]".into()]).unwrap();
        assert_eq!(s.vehicle.params.keys().collect::<Vec<_>>(), ["a"]);
        let text = toml::to_string(&s).unwrap();
        let at = |key: &str| text.find(key).unwrap();
        assert!(at("kind = \"double_integrator_1d\"") < at("a = [[1.0]]"), "{text}");
        assert!(at("a = [[1.0]]") < at("initial_state"), "{text}");
        for (set, key, expected) in [
            (
                "vehicle.initial_state='x'",
                "key `vehicle.initial_state`",
                "expected an array",
            ),
            ("vehicle.kind=3", "key `vehicle.kind`", "expected a string"),
        ] {
            let err = parse(MINIMAL, "t.toml", &[set.into()]).unwrap_err().to_string();
            assert!(err.contains(key) && err.contains(expected), "{err}");
        }
    }

    #[test]
    fn overrides_reach_nested_and_array_fields() {
        let s = parse(
            MINIMAL,
            "t.toml",
            &["nominal.input=[2.5]".into(), "delays.acceleration=0.1".into()],
        )
        .unwrap();
        assert_eq!(s.nominal.kind, "constant");
        assert_eq!(
            s.nominal.params.get("input"),
            Some(&toml::Value::Array(vec![toml::Value::Float(2.5)]))
        );
        assert_eq!(s.delays["acceleration"], DelayProfile::Constant(0.1));
        let err = parse(MINIMAL, "t.toml", &["nominal.input.3=1".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("out of range"), "{err}");
    }
}
