//! Scenario files (TOML in `scenarios/`): parsing, `--set` overrides and validation.
//! Every error names the file, the key and what was expected.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::barrier::{BarrierForm, Shape};
use crate::delay::DelayProfile;
use crate::plant::PlantKind;
use crate::vehicle::VehicleKind;

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
}

/// A scenario as written in its file (after overrides).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name, used in log file names.
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Simulated time in seconds.
    pub duration: f64,
    /// `mujoco` (default) or `ode` (the analytic model integrated by RK4).
    #[serde(default)]
    pub plant: PlantKind,
    /// Seed of every random variation (initial-state perturbation, obstacle appearance
    /// jitter, random disturbances): the same seed gives the same run, bit for bit.
    #[serde(default)]
    pub seed: u64,
    pub vehicle: VehicleSpec,
    /// Delay per input channel (channels not listed: no delay): seconds for a constant delay,
    /// or a table `{ profile = "cosine_prediction" | "rational" | "table", … }`.
    #[serde(default)]
    pub delays: BTreeMap<String, DelayProfile>,
    /// Initial input function per channel on [−D_i, 0) (constant; channels not listed: 0).
    #[serde(default)]
    pub initial_input: BTreeMap<String, f64>,
    #[serde(default)]
    pub control: ControlSpec,
    pub nominal: NominalSpec,
    #[serde(default)]
    pub filter: FilterSpec,
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    /// State constraints h(x) >= 0 that are not physical obstacles.
    #[serde(default)]
    pub barriers: Vec<Shape>,
    /// An additive disturbance B_ω ω(t) on the ODE plant ((3.24), (4.12)).
    #[serde(default)]
    pub disturbance: Option<DisturbanceSpec>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DisturbanceSpec {
    /// (3.49)/(3.50): ω1 = sin(0.4πt)/√2, ω2 = sgn(ω1)/√2, entering every state (B_ω = I).
    Example349,
    /// A bounded random disturbance ‖ω‖ ≤ `bound` entering with the inputs (Z = G in (4.12)),
    /// piecewise constant over `hold` seconds, seeded. Both plants.
    RandomInput { bound: f64, hold: f64 },
    /// A bounded random disturbance ‖ω‖ ≤ `bound` on every state (B_ω = I in (3.24)),
    /// piecewise constant over `hold` seconds, seeded. ODE plant.
    RandomState { bound: f64, hold: f64 },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSpec {
    pub kind: VehicleKind,
    /// MJCF file, relative to the scenario file (all kinds but `linear`).
    #[serde(default)]
    pub model: Option<PathBuf>,
    /// A and B of ẋ = A x + B u (kind `linear`), as arrays of rows.
    #[serde(default)]
    pub a: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    pub b: Option<Vec<Vec<f64>>>,
    /// Initial state x(0), in the vehicle's state order.
    pub initial_state: Vec<f64>,
    /// Uniform random perturbation of x(0): component i moves by up to ± this (seeded).
    #[serde(default)]
    pub initial_perturbation: Option<Vec<f64>>,
    /// Overrides the model's `<option timestep>` (seconds); required for `linear`.
    #[serde(default)]
    pub timestep: Option<f64>,
    /// Overrides the model's `<option integrator>`: "euler", "rk4" or "implicit".
    #[serde(default)]
    pub integrator: Option<crate::mujoco::Integrator>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSpec {
    /// Control period in seconds, a whole multiple of the timestep (default: the timestep).
    #[serde(default)]
    pub period: Option<f64>,
    /// Seconds of issued-input history kept; a delay longer than this is an error.
    #[serde(default = "default_history")]
    pub history: f64,
    /// RK4 step of the predictors in seconds, a whole multiple of the period (default: the
    /// period when every delay is constant and a whole multiple of it, else the timestep).
    /// Coarser is faster; the log's /prediction records measure what it costs in accuracy.
    #[serde(default)]
    pub predictor_step: Option<f64>,
    /// Predictors: continue the previous tick's prediction trajectory when the fresh p_1 (x(t)
    /// for one shared delay profile) lands within this max-norm distance of it (state units),
    /// else integrate the whole window.
    /// 0 reuses only an exact match; the log's /prediction records say which ticks reused.
    #[serde(default = "default_chain_tolerance")]
    pub chain_tolerance: f64,
}

impl Default for ControlSpec {
    fn default() -> Self {
        ControlSpec {
            period: None,
            predictor_step: None,
            history: default_history(),
            chain_tolerance: default_chain_tolerance(),
        }
    }
}

fn default_history() -> f64 {
    30.0
}

/// See docs/performance.md (predictor chain reuse) for the measurement behind it.
pub const DEFAULT_CHAIN_TOLERANCE: f64 = 1e-4;

fn default_chain_tolerance() -> f64 {
    DEFAULT_CHAIN_TOLERANCE
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum NominalSpec {
    /// LQR tracking of a straight path (bicycle).
    PathLqr(PathLqrSpec),
    /// A constant input, one value per channel.
    Constant(ConstantSpec),
    /// The unicycle's predictor-feedback stabiliser (2.40)–(2.46).
    UnicycleStabilizer,
    /// CLF controller (4.58) with V = x1⁴/4 + x2²/2 (4.57) (two-state systems).
    QuarticClf,
    /// Red-light tracking controller (5.20)–(5.22) for the double integrator.
    RedLight(RedLightSpec),
    /// Prescribed-time stabiliser (5.87)/(5.88) of the strict-feedback system (5.82), in
    /// z-coordinates and mapped back by (5.91).
    Pts(PtsSpec),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RedLightSpec {
    /// u = −k1 z1 − k2 z2, z1 = x1 + a sin(ωt) + b, z2 = x2 + aω cos(ωt).
    pub k1: f64,
    pub k2: f64,
    pub a: f64,
    pub b: f64,
    pub omega: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtsSpec {
    /// v = −μ2(t)[ω², 2ζω] z on [0, T).
    pub omega: f64,
    pub zeta: f64,
    pub horizon: f64,
    /// Clip of μ2 (default: none).
    #[serde(default)]
    pub clip: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathLqrSpec {
    pub reference_speed: f64,
    /// A point of the straight path.
    #[serde(default)]
    pub path_point: [f64; 2],
    /// Direction of the path (radians).
    #[serde(default)]
    pub path_heading: f64,
    /// Diagonal of Q for (cross-track, heading, speed) errors.
    #[serde(default = "default_q")]
    pub q: [f64; 3],
    /// Diagonal of R for (steering, acceleration).
    #[serde(default = "default_r")]
    pub r: [f64; 2],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantSpec {
    pub input: Vec<f64>,
}

fn default_q() -> [f64; 3] {
    [1.0, 1.0, 1.0]
}
fn default_r() -> [f64; 2] {
    [1.0, 1.0]
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FilterSpec {
    /// No safety filter: the nominal input is issued as it is.
    #[default]
    None,
    /// CBF-QP (4.6)–(4.11) over all channels, at x(t) or at each channel's prediction.
    CbfQp(CbfQpSpec),
    /// Fixed-channel robust filter (4.39)–(4.47), at the predictions.
    FixedChannel(FixedChannelSpec),
    /// Variable-channel γm filter (4.60)–(4.68), at the predictions.
    GammaM(GammaMSpec),
    /// Ch. 3 constrained stabiliser for linear systems: the γm CLF-CBF QP (3.27)–(3.33) at
    /// the recursive predictions (3.3)/(3.4), with buffer η (3.25) and a disk barrier.
    ClfCbfQp(ClfCbfQpSpec),
    /// Ch. 5 prescribed-time safety filter (5.23)–(5.29) keeping y = x1 < 0 on [0, T).
    Ptsf(PtsfSpec),
    /// Ch. 5 exponential safety filter u = min{u_nom, −k x} (5.89), poles −ρ, …, −nρ.
    Esf(EsfSpec),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtsfSpec {
    /// T: the prescribed time (the filter starts at t0 = 0).
    pub horizon: f64,
    /// Margin added to the lower bounds (5.32)–(5.34) of the gains c_i (computed from x(0)).
    pub margin: f64,
    /// Clip of μ2 (§5.4 uses 1000); none if absent.
    #[serde(default)]
    pub clip: Option<f64>,
    /// Order n of the chain; checked against the model if given.
    #[serde(default)]
    pub order: Option<usize>,
    /// Ramp g (5.28) after T: exponent m, duration T̄, and |y(T)| tolerance for "y(T) = 0".
    #[serde(default = "default_ramp_exponent")]
    pub ramp_exponent: u32,
    #[serde(default = "default_ramp_duration")]
    pub ramp_duration: f64,
    #[serde(default = "default_ramp_tolerance")]
    pub ramp_tolerance: f64,
}

fn default_ramp_exponent() -> u32 {
    2
}
fn default_ramp_duration() -> f64 {
    0.5
}
fn default_ramp_tolerance() -> f64 {
    1e-9
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EsfSpec {
    /// ρ.
    pub rate: f64,
    /// T for the prescribed-time metrics (barrier and residuals at T); optional.
    #[serde(default)]
    pub horizon: Option<f64>,
}

impl FilterSpec {
    /// The barrier form the gains describe (None without a filter or with invalid gains).
    pub fn form(&self) -> Option<BarrierForm> {
        match self {
            FilterSpec::None => None,
            FilterSpec::CbfQp(s) => barrier_form(s.alpha, s.l0, s.l1),
            FilterSpec::FixedChannel(s) => barrier_form(s.alpha, s.l0, s.l1),
            FilterSpec::GammaM(s) => barrier_form(s.alpha, s.l0, s.l1),
            FilterSpec::ClfCbfQp(s) => Some(BarrierForm::RelativeDegree1 { alpha: s.l0 }),
            // The chain filters have their own barrier chains ((5.24), (5.15)/(5.16)).
            FilterSpec::Ptsf(_) | FilterSpec::Esf(_) => None,
        }
    }
}

/// Relative degree 1 with α(h) = alpha·h, or 2 with gains l0, l1 of (4.82).
fn barrier_form(alpha: Option<f64>, l0: Option<f64>, l1: Option<f64>) -> Option<BarrierForm> {
    match (alpha, l0, l1) {
        (Some(alpha), None, None) => Some(BarrierForm::RelativeDegree1 { alpha }),
        (None, Some(l0), Some(l1)) => Some(BarrierForm::RelativeDegree2 { l0, l1 }),
        _ => None,
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CbfQpSpec {
    /// Relative degree 1: α(h) = alpha·h in ḣ + α(h) ≥ 0.
    #[serde(default)]
    pub alpha: Option<f64>,
    /// Relative degree 2: gains of ḧ + l1 ḣ + l0 h ≥ 0 (4.82).
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// `none`: the filter acts on the current state ((2.16)); `predictor`: on the predicted
    /// state of each channel ((2.26), and (4.34) for distinct delays).
    #[serde(default)]
    pub compensation: Compensation,
    /// Actuator limits per channel; with them (or several barriers) the QP is solved
    /// numerically (`filter::qp`).
    #[serde(default)]
    pub input_limits: Option<InputLimits>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLimits {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Compensation {
    #[default]
    None,
    Predictor,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedChannelSpec {
    #[serde(default)]
    pub alpha: Option<f64>,
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// φ (4.41): how many of the shortest-delayed channels suffice everywhere. Declared here
    /// (verified on `phi_box` if given) or, if absent, found on `phi_box`.
    #[serde(default)]
    pub phi: Option<usize>,
    #[serde(default)]
    pub phi_box: Option<StateBox>,
}

/// An axis-aligned box of states, sampled on a grid to verify or find φ (4.40).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateBox {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// Grid points per axis (default 9).
    #[serde(default = "default_box_points")]
    pub points: usize,
}

fn default_box_points() -> usize {
    9
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClfCbfQpSpec {
    /// CLF V = xᵀPx with P = p·I, decay rate Q = q·I (Definition 3.1).
    pub p: f64,
    pub q: f64,
    /// α_h(H) = l0·H (3.40).
    pub l0: f64,
    /// Buffer η: a number, or absent to use the bound (3.25) for `omega_bar`.
    #[serde(default)]
    pub eta: Option<f64>,
    /// ω̄ of (3.24) for the bound (3.25) (default 0: no disturbance).
    #[serde(default)]
    pub omega_bar: f64,
    /// QP-LB penalty m and γ of γ_f (3.28).
    pub m: f64,
    pub gamma: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GammaMSpec {
    #[serde(default)]
    pub alpha: Option<f64>,
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// Slack penalty m ≥ 1 (4.60).
    pub m: f64,
    /// γ ≥ 1 of γ_f (4.61); default (m + 1)/m (Remark 4.5).
    #[serde(default)]
    pub gamma: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// Name in logs (default obstacle_<index>).
    #[serde(default)]
    pub name: Option<String>,
    pub centre: [f64; 2],
    pub radius: f64,
    /// When the obstacle becomes known to the controller (seconds).
    #[serde(default)]
    pub appear_at: f64,
    /// Uniform random jitter of `appear_at` (± seconds, seeded; the result is kept >= 0).
    #[serde(default)]
    pub appear_jitter: f64,
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
}

impl LoadedScenario {
    /// The model path resolved against the scenario file's directory.
    pub fn model_path(&self) -> Option<PathBuf> {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        self.scenario.vehicle.model.as_ref().map(|m| dir.join(m))
    }

    /// The files a run of this scenario reads (the scenario, its model): outputs never replace them.
    pub fn inputs(&self) -> Vec<PathBuf> {
        std::iter::once(self.path.clone()).chain(self.model_path()).collect()
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
pub fn load(path: &Path, overrides: &[String]) -> Result<LoadedScenario, ScenarioError> {
    let text = crate::files::read_text_limited(path, "scenario", crate::files::SCENARIO_LIMIT)?;
    from_text(path, text, overrides)
}

/// A scenario from its text, as if read from `path` (which names it in errors and anchors the
/// relative model path), with overrides applied and validated.
pub fn from_text(path: &Path, text: String, overrides: &[String]) -> Result<LoadedScenario, ScenarioError> {
    let file = path.display().to_string();
    let scenario = parse(&text, &file, overrides)?;
    let loaded = LoadedScenario {
        scenario,
        path: path.to_path_buf(),
        source_text: text,
        overrides: overrides.to_vec(),
    };
    validate(&loaded)?;
    Ok(loaded)
}

/// Parses scenario text; `file` names it in errors.
pub fn parse(text: &str, file: &str, overrides: &[String]) -> Result<Scenario, ScenarioError> {
    let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| ScenarioError::Syntax {
        file: file.to_string(),
        message: e.to_string().trim().replace('\n', " "),
    })?;
    for spec in overrides {
        apply_override(&mut table, spec)?;
    }
    let whole = toml::Value::Table(table.clone());
    serde_path_to_error::deserialize(whole).map_err(|e| {
        let key = e.path().to_string();
        let (key, message) = refine_tagged(&table, &key).unwrap_or((key, e.into_inner().to_string()));
        let message = plain_serde_message(&message);
        ScenarioError::Field {
            file: file.to_string(),
            key: if key == "." { "(top level)".into() } else { key },
            message,
        }
    })
}

/// A serde message in the scenario's terms instead of Rust's: no type names
/// ("untagged enum DelayProfile", "struct VehicleSpec"), TOML words for sequences and maps.
pub fn plain_serde_message(message: &str) -> String {
    let message = message.trim().replace('\n', " ");
    let message = message.as_str();
    if message.contains("untagged enum DelayProfile") {
        return "expected a delay in seconds (a number >= 0) or a table { profile = \"cosine_prediction\" | \"rational\" | \"table\", … }".into();
    }
    let mut out = String::with_capacity(message.len());
    let mut words = message.split(' ').peekable();
    while let Some(word) = words.next() {
        let next_is_type = words.peek().is_some_and(|w| {
            w.starts_with(|c: char| c.is_ascii_uppercase()) && w.chars().all(|c| c.is_alphanumeric() || c == ',')
        });
        let replacement = match word {
            "struct" | "map" if next_is_type => Some("a table"),
            "enum" if next_is_type => Some("one of the documented names"),
            "untagged" | "internally" | "tagged" if words.peek().is_some_and(|w| *w == "enum" || *w == "tagged") => {
                continue;
            }
            _ => None,
        };
        if !out.is_empty() {
            out.push(' ');
        }
        match replacement {
            Some(text) => {
                out.push_str(text);
                // The type name, keeping trailing punctuation.
                let name = words.next().unwrap_or_default();
                out.extend(name.chars().filter(|c| !c.is_alphanumeric()));
            }
            None => out.push_str(word),
        }
    }
    let mut out = out
        .replace("a sequence", "an array")
        .replace("a map", "a table")
        .replace("type: map", "type: table")
        .replace("type: sequence", "type: array")
        .replace("expected f64", "expected a number")
        .replace("expected f32", "expected a number");
    for int in ["u8", "u16", "u32", "u64", "usize"] {
        out = out.replace(&format!("expected {int}"), "expected a whole number >= 0");
    }
    for int in ["i8", "i16", "i32", "i64", "isize"] {
        out = out.replace(&format!("expected {int}"), "expected a whole number");
    }
    // toml repeats the key the message is already prefixed with.
    if let Some(at) = out.rfind(" in `") {
        if out.ends_with('`') {
            out.truncate(at);
        }
    }
    out
}

/// serde loses the field path inside internally tagged enums (`kind = …` sections): for an
/// error in such a section, deserialize the chosen variant's own struct again to find the key.
fn refine_tagged(table: &toml::Table, key: &str) -> Option<(String, String)> {
    let section = key.split('.').next()?;
    let mut body = table.get(section)?.as_table()?.clone();
    let kind = body.remove("kind")?.as_str()?.to_string();
    fn check<T: serde::de::DeserializeOwned>(section: &str, body: toml::Table) -> Option<(String, String)> {
        serde_path_to_error::deserialize::<_, T>(toml::Value::Table(body))
            .err()
            .map(|e| {
                let inner = e.path().to_string();
                let key = if inner == "." {
                    section.to_string()
                } else {
                    format!("{section}.{inner}")
                };
                (key, e.into_inner().to_string())
            })
    }
    match (section, kind.as_str()) {
        ("nominal", "path_lqr") => check::<PathLqrSpec>(section, body),
        ("nominal", "constant") => check::<ConstantSpec>(section, body),
        ("filter", "cbf_qp") => check::<CbfQpSpec>(section, body),
        ("filter", "fixed_channel") => check::<FixedChannelSpec>(section, body),
        ("filter", "gamma_m") => check::<GammaMSpec>(section, body),
        ("filter", "clf_cbf_qp") => check::<ClfCbfQpSpec>(section, body),
        ("filter", "ptsf") => check::<PtsfSpec>(section, body),
        ("filter", "esf") => check::<EsfSpec>(section, body),
        ("nominal", "red_light") => check::<RedLightSpec>(section, body),
        ("nominal", "pts") => check::<PtsSpec>(section, body),
        _ => None,
    }
}

/// Applies one `a.b.c=VALUE` override; numeric segments index arrays (`obstacles.0.radius`).
fn apply_override(table: &mut toml::Table, spec: &str) -> Result<(), ScenarioError> {
    let err = |message: String| ScenarioError::Override {
        spec: spec.to_string(),
        message,
    };
    let (key, raw) = spec
        .split_once('=')
        .ok_or_else(|| err("expected KEY=VALUE, e.g. delays.steering=0.4".into()))?;
    let key = key.trim();
    let value: toml::Table = format!("value = {}", raw.trim()).parse().map_err(|_| {
        err(format!(
            "`{}` is not a TOML value (numbers as 0.4, strings quoted as '\"text\"', arrays as [1, 2])",
            raw.trim()
        ))
    })?;
    let value = value.get("value").cloned().expect("parsed above");
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
    *current = value;
    Ok(())
}

/// The kind as a scenario writes it (`kind = "bicycle"`).
fn vehicle_kind_name(kind: VehicleKind) -> String {
    toml::Value::try_from(kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| format!("{kind:?}"))
}

fn positive_finite(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// Checks what serde cannot: signs, ranges and consistency. Model-dependent checks (state
/// size, channel names, timestep multiples) happen when the episode binds the model.
fn validate(s: &LoadedScenario) -> Result<(), ScenarioError> {
    let sc = &s.scenario;
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
    for (channel, profile) in &sc.delays {
        if let DelayProfile::Constant(delay) = profile {
            if !delay.is_finite() || *delay < 0.0 {
                return Err(s.field_error(
                    &format!("delays.{channel}"),
                    format!("expected a delay >= 0 seconds, found {delay}"),
                ));
            }
        }
    }
    if !positive_finite(sc.control.history) {
        return Err(s.field_error(
            "control.history",
            format!("expected a positive number of seconds, found {}", sc.control.history),
        ));
    }
    if sc.vehicle.kind.has_mjcf() && sc.vehicle.model.is_none() {
        return Err(s.field_error(
            "vehicle.model",
            format!(
                "expected the MJCF file of the {} model",
                vehicle_kind_name(sc.vehicle.kind)
            ),
        ));
    }
    if !sc.vehicle.kind.has_mjcf() {
        let kind = vehicle_kind_name(sc.vehicle.kind);
        if sc.plant != PlantKind::Ode {
            return Err(s.field_error(
                "plant",
                format!("vehicle.kind = \"{kind}\" has no MJCF model: expected plant = \"ode\""),
            ));
        }
        if sc.vehicle.model.is_some() {
            return Err(s.field_error(
                "vehicle.model",
                format!("vehicle.kind = \"{kind}\" is an analytic model: expected no MJCF file"),
            ));
        }
        if sc.vehicle.timestep.is_none() {
            return Err(s.field_error(
                "vehicle.timestep",
                format!("vehicle.kind = \"{kind}\" has no model file: expected the integration step in seconds"),
            ));
        }
    }
    if sc.vehicle.kind == VehicleKind::Linear {
        let (Some(a), Some(b)) = (&sc.vehicle.a, &sc.vehicle.b) else {
            return Err(s.field_error(
                "vehicle.a",
                "kind = \"linear\" needs both vehicle.a and vehicle.b (arrays of rows)",
            ));
        };
        let n = a.len();
        if n == 0 || a.iter().any(|row| row.len() != n) {
            return Err(s.field_error("vehicle.a", "expected a square matrix (array of equal-length rows)"));
        }
        if b.len() != n || b.iter().any(|row| row.len() != b[0].len()) || b[0].is_empty() {
            return Err(s.field_error("vehicle.b", format!("expected {n} rows of equal, non-zero length")));
        }
        if a.iter().chain(b).flatten().any(|v| !v.is_finite()) {
            return Err(s.field_error("vehicle.a", "matrix entries must be finite"));
        }
    }
    for (channel, value) in &sc.initial_input {
        if !value.is_finite() {
            return Err(s.field_error(
                &format!("initial_input.{channel}"),
                format!("expected a finite number, found {value}"),
            ));
        }
    }
    if let Some(period) = sc.control.period {
        if !positive_finite(period) {
            return Err(s.field_error(
                "control.period",
                format!("expected a positive number of seconds, found {period}"),
            ));
        }
    }
    match &sc.nominal {
        NominalSpec::PathLqr(PathLqrSpec {
            reference_speed, q, r, ..
        }) => {
            if !positive_finite(*reference_speed) {
                return Err(s.field_error(
                    "nominal.reference_speed",
                    format!("expected a positive speed, found {reference_speed}"),
                ));
            }
            if q.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return Err(s.field_error("nominal.q", "expected three weights >= 0"));
            }
            if r.iter().any(|v| !positive_finite(*v)) {
                return Err(s.field_error("nominal.r", "expected two weights > 0"));
            }
        }
        NominalSpec::Constant(ConstantSpec { input }) => {
            if input.iter().any(|v| !v.is_finite()) {
                return Err(s.field_error("nominal.input", "expected finite numbers"));
            }
        }
        NominalSpec::QuarticClf | NominalSpec::RedLight(_) | NominalSpec::Pts(_) => {}
        NominalSpec::UnicycleStabilizer => {
            if sc.vehicle.kind != VehicleKind::Unicycle {
                return Err(s.field_error("nominal.kind", "unicycle_stabilizer needs vehicle.kind = \"unicycle\""));
            }
        }
    }
    let has_gains = !matches!(sc.filter, FilterSpec::None | FilterSpec::Ptsf(_) | FilterSpec::Esf(_));
    if has_gains {
        match sc.filter.form() {
            None => {
                return Err(s.field_error(
                    "filter",
                    "expected either alpha (relative degree 1) or both l0 and l1 (relative degree 2)",
                ))
            }
            Some(BarrierForm::RelativeDegree1 { alpha }) if !positive_finite(alpha) => {
                return Err(s.field_error("filter.alpha", format!("expected alpha > 0, found {alpha}")))
            }
            // Roots of s² + l1 s + l0 negative real (below (4.83)): l0 > 0, l1 > 0, l1² ≥ 4 l0.
            Some(BarrierForm::RelativeDegree2 { l0, l1 })
                if !(positive_finite(l0) && positive_finite(l1) && l1 * l1 >= 4.0 * l0) =>
            {
                return Err(s.field_error(
                    "filter",
                    format!("expected l0 > 0, l1 > 0 and l1² >= 4 l0 (negative real roots of s² + l1 s + l0), found l0 = {l0}, l1 = {l1}"),
                ));
            }
            Some(_) => {}
        }
    }
    if let FilterSpec::GammaM(spec) = &sc.filter {
        if !(spec.m.is_finite() && spec.m >= 1.0) {
            return Err(s.field_error("filter.m", format!("expected m >= 1 (4.60), found {}", spec.m)));
        }
        if let Some(gamma) = spec.gamma {
            if !(gamma.is_finite() && gamma >= 1.0) {
                return Err(s.field_error("filter.gamma", format!("expected gamma >= 1 (4.61), found {gamma}")));
            }
        }
    }
    if let FilterSpec::Ptsf(spec) = &sc.filter {
        if !positive_finite(spec.horizon) {
            return Err(s.field_error("filter.horizon", format!("expected T > 0, found {}", spec.horizon)));
        }
        if !positive_finite(spec.margin) {
            return Err(s.field_error("filter.margin", format!("expected a margin > 0, found {}", spec.margin)));
        }
        if let Some(clip) = spec.clip {
            if !(clip.is_finite() && clip > 1.0) {
                return Err(s.field_error("filter.clip", format!("expected a clip > 1 for mu_2, found {clip}")));
            }
        }
    }
    if let FilterSpec::Esf(spec) = &sc.filter {
        if !positive_finite(spec.rate) {
            return Err(s.field_error("filter.rate", format!("expected rho > 0, found {}", spec.rate)));
        }
    }
    if let FilterSpec::ClfCbfQp(spec) = &sc.filter {
        if !(spec.m.is_finite() && spec.m >= 1.0) {
            return Err(s.field_error("filter.m", format!("expected m >= 1, found {}", spec.m)));
        }
        if !(spec.gamma.is_finite() && spec.gamma >= 1.0) {
            return Err(s.field_error("filter.gamma", format!("expected gamma >= 1, found {}", spec.gamma)));
        }
        if sc.vehicle.kind != VehicleKind::Linear {
            return Err(s.field_error("filter.kind", "clf_cbf_qp (Ch. 3) needs vehicle.kind = \"linear\""));
        }
        if !matches!(&sc.nominal, NominalSpec::Constant(c) if c.input.iter().all(|v| *v == 0.0)) {
            return Err(s.field_error(
                "nominal",
                "clf_cbf_qp stabilises through its CLF (3.27): expected a zero constant nominal",
            ));
        }
    }
    match &sc.disturbance {
        Some(DisturbanceSpec::RandomInput { bound, hold }) | Some(DisturbanceSpec::RandomState { bound, hold })
            if !(bound.is_finite() && *bound >= 0.0 && positive_finite(*hold)) =>
        {
            return Err(s.field_error(
                "disturbance",
                format!("expected bound >= 0 and hold > 0, found bound = {bound}, hold = {hold}"),
            ));
        }
        Some(DisturbanceSpec::Example349) | Some(DisturbanceSpec::RandomState { .. }) if sc.plant != PlantKind::Ode => {
            return Err(s.field_error("disturbance", "this disturbance acts on the state of the ODE plant: expected plant = \"ode\" (or kind = \"random_input\")"));
        }
        _ => {}
    }
    if let Some(p) = &sc.vehicle.initial_perturbation {
        if p.len() != sc.vehicle.initial_state.len() || p.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(s.field_error(
                "vehicle.initial_perturbation",
                "expected one bound >= 0 per initial_state component",
            ));
        }
    }
    if let FilterSpec::FixedChannel(spec) = &sc.filter {
        if spec.phi == Some(0) {
            return Err(s.field_error("filter.phi", "expected phi >= 1 (a number of input channels, (4.41))"));
        }
        if spec.phi.is_none() && spec.phi_box.is_none() {
            return Err(s.field_error("filter.phi", "declare phi (4.41) or give filter.phi_box to find it"));
        }
        if let Some(b) = &spec.phi_box {
            let ok = b.lower.len() == b.upper.len()
                && b.points >= 2
                && b.lower
                    .iter()
                    .zip(&b.upper)
                    .all(|(l, u)| l.is_finite() && u.is_finite() && l <= u);
            if !ok {
                return Err(s.field_error(
                    "filter.phi_box",
                    "expected lower <= upper of equal lengths, finite, and points >= 2",
                ));
            }
        }
    }
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
        };
        if !ok {
            return Err(s.field_error(
                &format!("barriers[{i}]"),
                "expected a ball (indices and centre of equal length, radius > 0) or a half-space (finite coefficients and offset)",
            ));
        }
    }
    for (i, o) in sc.obstacles.iter().enumerate() {
        if !positive_finite(o.radius) {
            return Err(s.field_error(
                &format!("obstacles[{i}].radius"),
                format!("expected a positive radius, found {}", o.radius),
            ));
        }
        if o.centre.iter().any(|v| !v.is_finite()) {
            return Err(s.field_error(&format!("obstacles[{i}].centre"), "expected two finite coordinates"));
        }
        if !o.appear_jitter.is_finite() || o.appear_jitter < 0.0 {
            return Err(s.field_error(
                &format!("obstacles[{i}].appear_jitter"),
                format!("expected a jitter >= 0, found {}", o.appear_jitter),
            ));
        }
        if !o.appear_at.is_finite() || o.appear_at < 0.0 {
            return Err(s.field_error(
                &format!("obstacles[{i}].appear_at"),
                format!("expected a time >= 0, found {}", o.appear_at),
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
        assert_eq!(s.filter, FilterSpec::None);
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
    fn overrides_reach_nested_and_array_fields() {
        let s = parse(
            MINIMAL,
            "t.toml",
            &["nominal.input=[2.5]".into(), "delays.acceleration=0.1".into()],
        )
        .unwrap();
        assert_eq!(s.nominal, NominalSpec::Constant(ConstantSpec { input: vec![2.5] }));
        assert_eq!(s.delays["acceleration"], DelayProfile::Constant(0.1));
        let err = parse(MINIMAL, "t.toml", &["nominal.input.3=1".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("out of range"), "{err}");
    }
}
