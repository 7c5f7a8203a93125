//! Scenario files (TOML in `scenarios/`): parsing, `--set` overrides and validation.
//! Every error names the file, the key and what was expected.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::vehicle::VehicleKind;

#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("{file}: cannot read the scenario: {source}")]
    Io {
        file: String,
        source: std::io::Error,
    },
    #[error("{file}: invalid TOML: {message}")]
    Syntax { file: String, message: String },
    #[error("{file}: key `{key}`: {message}")]
    Field {
        file: String,
        key: String,
        message: String,
    },
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
    pub vehicle: VehicleSpec,
    /// Constant delay per input channel in seconds (channels not listed: no delay).
    #[serde(default)]
    pub delays: BTreeMap<String, f64>,
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
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleSpec {
    pub kind: VehicleKind,
    /// MJCF file, relative to the scenario file.
    pub model: PathBuf,
    /// Initial state x(0), in the vehicle's state order.
    pub initial_state: Vec<f64>,
    /// Overrides the model's `<option timestep>` (seconds).
    #[serde(default)]
    pub timestep: Option<f64>,
    /// Overrides the model's `<option integrator>`: "euler", "rk4" or "implicit".
    #[serde(default)]
    pub integrator: Option<crate::mujoco::Integrator>,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSpec {
    /// Control period in seconds, a whole multiple of the timestep (default: the timestep).
    #[serde(default)]
    pub period: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum NominalSpec {
    /// LQR tracking of a straight path (bicycle).
    PathLqr(PathLqrSpec),
    /// A constant input, one value per channel.
    Constant(ConstantSpec),
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
    /// Delay-free CBF-QP (4.6)–(4.11) on the current state, relative-degree-2 barrier
    /// constraint (4.83).
    CbfQp(CbfQpSpec),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CbfQpSpec {
    /// Gains of ḧ + l1 ḣ + l0 h ≥ 0 (4.82).
    pub l0: f64,
    pub l1: f64,
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
    pub fn model_path(&self) -> PathBuf {
        let dir = self.path.parent().unwrap_or_else(|| Path::new("."));
        dir.join(&self.scenario.vehicle.model)
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
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io {
        file: file.clone(),
        source,
    })?;
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
    let mut table: toml::Table =
        text.parse()
            .map_err(|e: toml::de::Error| ScenarioError::Syntax {
                file: file.to_string(),
                message: e.to_string().trim().replace('\n', " "),
            })?;
    for spec in overrides {
        apply_override(&mut table, spec)?;
    }
    let whole = toml::Value::Table(table.clone());
    serde_path_to_error::deserialize(whole).map_err(|e| {
        let key = e.path().to_string();
        let (key, message) =
            refine_tagged(&table, &key).unwrap_or((key, e.into_inner().to_string()));
        ScenarioError::Field {
            file: file.to_string(),
            key: if key == "." {
                "(top level)".into()
            } else {
                key
            },
            message,
        }
    })
}

/// serde loses the field path inside internally tagged enums (`kind = …` sections): for an
/// error in such a section, deserialize the chosen variant's own struct again to find the key.
fn refine_tagged(table: &toml::Table, key: &str) -> Option<(String, String)> {
    let section = key.split('.').next()?;
    let mut body = table.get(section)?.as_table()?.clone();
    let kind = body.remove("kind")?.as_str()?.to_string();
    fn check<T: serde::de::DeserializeOwned>(
        section: &str,
        body: toml::Table,
    ) -> Option<(String, String)> {
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
                let index: usize = segment.parse().map_err(|_| {
                    err(format!(
                        "`{parent}` is an array: `{segment}` must be an index"
                    ))
                })?;
                let len = items.len();
                items.get_mut(index).ok_or_else(|| {
                    err(format!(
                        "`{parent}` has {len} entries, index {index} is out of range"
                    ))
                })?
            }
            _ => return Err(err(format!("`{parent}` is a value, not a table"))),
        };
    }
    *current = value;
    Ok(())
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
            format!(
                "expected a positive number of seconds, found {}",
                sc.duration
            ),
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
    for (channel, delay) in &sc.delays {
        if !delay.is_finite() || *delay < 0.0 {
            return Err(s.field_error(
                &format!("delays.{channel}"),
                format!("expected a delay >= 0 seconds, found {delay}"),
            ));
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
            reference_speed,
            q,
            r,
            ..
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
    }
    if let FilterSpec::CbfQp(CbfQpSpec { l0, l1 }) = sc.filter {
        // Roots of s² + l1 s + l0 negative real (below (4.83)): l0 > 0, l1 > 0, l1² ≥ 4 l0.
        if !(positive_finite(l0) && positive_finite(l1) && l1 * l1 >= 4.0 * l0) {
            return Err(s.field_error(
                "filter",
                format!("expected l0 > 0, l1 > 0 and l1² >= 4 l0 (negative real roots of s² + l1 s + l0), found l0 = {l0}, l1 = {l1}"),
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
            return Err(s.field_error(
                &format!("obstacles[{i}].centre"),
                "expected two finite coordinates",
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
        assert!(
            err.contains("duration") && err.contains("expected"),
            "{err}"
        );
    }

    #[test]
    fn overrides_reach_nested_and_array_fields() {
        let s = parse(
            MINIMAL,
            "t.toml",
            &[
                "nominal.input=[2.5]".into(),
                "delays.acceleration=0.1".into(),
            ],
        )
        .unwrap();
        assert_eq!(
            s.nominal,
            NominalSpec::Constant(ConstantSpec { input: vec![2.5] })
        );
        assert_eq!(s.delays["acceleration"], 0.1);
        let err = parse(MINIMAL, "t.toml", &["nominal.input.3=1".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("out of range"), "{err}");
    }
}
