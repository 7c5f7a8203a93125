//! A metric's value and what follows from its shape: its JSON, its flat columns, its cell.

use std::collections::BTreeMap;

use serde::ser::SerializeMap;
use serde::{Deserialize, Serialize};

use super::{builtin, CellKind, Metric, Shape};

/// First collision of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Collision {
    /// Time of the first contact, s.
    pub time: f64,
    /// The obstacle first touched.
    pub with: String,
    /// Deepest penetration over all contacts of the run (MuJoCo contact distance), m; NaN
    /// (null in JSON, reason under `missing`) when a contact is still going on where the log
    /// ends without closing it.
    pub depth: f64,
}

/// Prediction consistency of one channel: |p_i(t) − x(φ_i⁻¹(t))| over the run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PredictionStats {
    pub count: u64,
    pub max_error: f64,
    pub rms_error: f64,
    pub max_relative_error: f64,
    /// Predictions that continued the previous tick's trajectory (control.chain_tolerance).
    pub reused_chain: u64,
    /// Largest |p_1 − previous chain| seen at a tick (0 when never measured).
    pub max_chain_mismatch: f64,
    #[serde(skip)]
    pub(crate) sum_squares: f64,
}

/// Values at the prescribed time T (Ch. 5): barrier value(s) and the "soft landing" residuals.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PrescribedTimeMetrics {
    pub time: f64,
    /// min over barriers of h(x(T)).
    pub barrier: Option<f64>,
    /// |x_i(T)| per state component.
    pub state_residuals: Vec<f64>,
    /// |u(T)| (the command issued at T, max over channels).
    pub input_residual: Option<f64>,
}

/// The value of one metric (`None`: the run does not have it, or its log cannot give it).
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Number(Option<f64>),
    Count(Option<u64>),
    /// A number per input channel or per barrier ([`Shape::PerChannel`], [`Shape::PerBarrier`]).
    PerChannel(Option<BTreeMap<String, f64>>),
    Collision(Option<Collision>),
    Prediction(Option<BTreeMap<String, PredictionStats>>),
    AtPrescribedTime(Option<PrescribedTimeMetrics>),
}

/// `Some(x)` for a finite x (JSON has no NaN or infinity: those are `null`, CSV leaves them empty).
pub(crate) fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl Value {
    /// The absent value of a metric of `shape`.
    pub fn absent(shape: Shape) -> Value {
        match shape {
            Shape::Number => Value::Number(None),
            Shape::Count => Value::Count(None),
            Shape::PerChannel | Shape::PerBarrier => Value::PerChannel(None),
            Shape::Collision => Value::Collision(None),
            Shape::Prediction => Value::Prediction(None),
            Shape::AtPrescribedTime => Value::AtPrescribedTime(None),
        }
    }

    /// The value in `analyze --json` (a float that is not finite is `null`).
    pub fn json(&self) -> serde_json::Value {
        let json = |v: serde_json::Result<serde_json::Value>| v.unwrap_or(serde_json::Value::Null);
        match self {
            Value::Number(v) => json(serde_json::to_value(v)),
            Value::Count(v) => json(serde_json::to_value(v)),
            Value::PerChannel(v) => json(serde_json::to_value(v)),
            Value::Collision(v) => json(serde_json::to_value(v)),
            Value::Prediction(v) => json(serde_json::to_value(v)),
            Value::AtPrescribedTime(v) => json(serde_json::to_value(v)),
        }
    }

    /// The flat columns of the value of `metric` (what [`FlatMetrics`] holds).
    fn cells(&self, metric: &Metric, cells: &mut BTreeMap<String, Cell>) {
        let part = |key: &str| metric.parts.iter().find(|p| p.key == key).map_or("", |p| p.column);
        let mut put = |column: String, cell: Cell| {
            cells.insert(column, cell);
        };
        match self {
            Value::Number(v) => put(metric.name.into(), Cell::Num(v.and_then(finite))),
            Value::Count(v) => put(metric.name.into(), Cell::Int(*v)),
            Value::PerChannel(v) => {
                for (channel, x) in v.iter().flatten() {
                    put(format!("{}.{channel}", metric.name), Cell::Num(finite(*x)));
                }
            }
            Value::Collision(c) => {
                put(part("time").into(), Cell::Num(c.as_ref().and_then(|c| finite(c.time))));
                put(part("with").into(), Cell::Text(c.as_ref().map(|c| c.with.clone())));
                put(
                    part("depth").into(),
                    Cell::Num(c.as_ref().and_then(|c| finite(c.depth))),
                );
            }
            Value::Prediction(p) => {
                for (channel, s) in p.iter().flatten() {
                    put(format!("{}.{channel}", part("count")), Cell::Int(Some(s.count)));
                    for (key, x) in [
                        ("max_error", s.max_error),
                        ("rms_error", s.rms_error),
                        ("max_relative_error", s.max_relative_error),
                    ] {
                        put(format!("{}.{channel}", part(key)), Cell::Num(finite(x)));
                    }
                }
            }
            Value::AtPrescribedTime(p) => {
                let Some(p) = p else { return };
                put(part("time").into(), Cell::Num(finite(p.time)));
                put(part("barrier").into(), Cell::Num(p.barrier.and_then(finite)));
                put(
                    part("input_residual").into(),
                    Cell::Num(p.input_residual.and_then(finite)),
                );
                for (i, r) in p.state_residuals.iter().enumerate() {
                    put(format!("{}.{i}", part("state_residuals")), Cell::Num(finite(*r)));
                }
            }
        }
    }

    /// Short text for the aligned table (`-` when absent).
    pub fn display(&self) -> String {
        let channels = |m: &BTreeMap<String, f64>| {
            m.iter()
                .map(|(c, v)| format!("{c}={v:.3}"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        match self {
            Value::Number(Some(x)) => Cell::Num(Some(*x)).display(),
            Value::Count(Some(n)) => n.to_string(),
            Value::PerChannel(Some(m)) if !m.is_empty() => channels(m),
            Value::Collision(Some(c)) => format!("t={:.3} {}", c.time, c.with),
            Value::Prediction(Some(p)) if !p.is_empty() => p
                .iter()
                .map(|(c, p)| format!("{c}={:.1e}/{:.1e}", p.max_error, p.rms_error))
                .collect::<Vec<_>>()
                .join(" "),
            Value::AtPrescribedTime(Some(p)) => p.barrier.map_or("-".into(), |h| format!("h(T)={h:.3}")),
            _ => "-".into(),
        }
    }
}

/// One value of a [`FlatMetrics`] column.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    Num(Option<f64>),
    Int(Option<u64>),
    Text(Option<String>),
    Bool(Option<bool>),
}

impl Cell {
    /// An empty cell of `kind`.
    fn none(kind: CellKind) -> Cell {
        match kind {
            CellKind::Num => Cell::Num(None),
            CellKind::Int => Cell::Int(None),
            CellKind::Text => Cell::Text(None),
        }
    }

    /// The cell of a column of `kind` from its JSON value (a sweep summary's row).
    fn from_json(kind: CellKind, value: &serde_json::Value) -> Option<Cell> {
        Some(match (kind, value) {
            (_, serde_json::Value::Null) => Cell::none(kind),
            (CellKind::Num, v) => Cell::Num(Some(v.as_f64()?)),
            (CellKind::Int, v) => Cell::Int(Some(v.as_u64()?)),
            (CellKind::Text, v) => Cell::Text(Some(v.as_str()?.to_string())),
        })
    }

    /// The CSV text: floats in Rust's shortest round-trip form (`0.1`, `1e-15`), empty for none.
    pub fn csv(&self) -> String {
        match self {
            Cell::Num(v) => v.map_or(String::new(), |x| format!("{x:?}")),
            Cell::Int(v) => v.map_or(String::new(), |x| x.to_string()),
            Cell::Text(v) => v.clone().unwrap_or_default(),
            Cell::Bool(v) => v.map_or(String::new(), |b| b.to_string()),
        }
    }

    /// Short human-readable text for aligned tables (`-` for none).
    pub fn display(&self) -> String {
        match self {
            Cell::Num(Some(x)) => short_number(*x),
            Cell::Num(None) | Cell::Int(None) | Cell::Text(None) | Cell::Bool(None) => "-".into(),
            _ => self.csv(),
        }
    }

    /// The value as JSON (`null` for none).
    pub fn json(&self) -> serde_json::Value {
        match self {
            Cell::Num(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Int(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Text(v) => v.clone().map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Bool(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
        }
    }

    /// `other − self` for numbers; for text and flags `same` or `differs`; `None` when
    /// either side is missing.
    pub fn difference(&self, other: &Cell) -> Option<Cell> {
        match (self, other) {
            (Cell::Num(Some(a)), Cell::Num(Some(b))) => Some(Cell::Num(finite(b - a))),
            (Cell::Int(Some(a)), Cell::Int(Some(b))) => Some(Cell::Num(Some(*b as f64 - *a as f64))),
            (Cell::Num(None), Cell::Num(None))
            | (Cell::Int(None), Cell::Int(None))
            | (Cell::Text(None), Cell::Text(None))
            | (Cell::Bool(None), Cell::Bool(None)) => Some(Cell::Text(Some("same".into()))),
            (Cell::Text(a), Cell::Text(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            (Cell::Bool(a), Cell::Bool(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            _ => None,
        }
    }
}

/// A number in at most 6 significant digits, without trailing zeros.
pub(crate) fn short_number(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        let decimals = (5 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{x:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{x:.3e}")
    }
}

/// A run's metrics as one flat record, one cell per column: the rows of `analyze --csv`,
/// `analyze --compare` and the sweep summaries (columns: docs/metrics.md). Floats that are not
/// finite are empty.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlatMetrics {
    pub scenario: String,
    /// The metrics' columns this run has (a channel it does not have is not there).
    cells: BTreeMap<String, Cell>,
    pub complete: bool,
    pub error: Option<String>,
}

impl From<&super::RunMetrics> for FlatMetrics {
    fn from(m: &super::RunMetrics) -> FlatMetrics {
        let mut cells = BTreeMap::new();
        for (metric, value) in builtin::METRICS.iter().zip(&m.values) {
            value.cells(metric, &mut cells);
        }
        FlatMetrics {
            scenario: m.scenario.clone(),
            cells,
            complete: m.complete,
            error: m.error.clone(),
        }
    }
}

/// The kind of a metric column's cells (`None`: not a metric column).
fn column_kind(column: &str) -> Option<CellKind> {
    Metric::of_column(column).map(|(metric, part)| match part {
        Some(part) => part.cell,
        None if metric.shape == Shape::Count => CellKind::Int,
        None => CellKind::Num,
    })
}

impl FlatMetrics {
    /// Whether a column of [`FlatMetrics::columns`] holds numbers (what `falsify --objective`
    /// and `plot-sweep --y` accept).
    pub fn is_numeric_column(name: &str) -> bool {
        matches!(column_kind(name), Some(CellKind::Num | CellKind::Int))
    }

    /// A metric's column as a number, if this run has it.
    pub fn number(&self, column: &str) -> Option<f64> {
        match self.cell(column) {
            Cell::Num(v) => v,
            Cell::Int(v) => v.map(|v| v as f64),
            Cell::Text(_) | Cell::Bool(_) => None,
        }
    }

    /// Column names covering `rows`: `scenario`, then every metric's columns in declaration
    /// order (a per-channel group: the union of the rows' channels, sorted; a list: its
    /// indices), then `complete` and `error`.
    pub fn columns<'a>(rows: impl IntoIterator<Item = &'a FlatMetrics> + Clone) -> Vec<String> {
        let mut names = vec!["scenario".to_string()];
        for metric in builtin::METRICS {
            let bases: Vec<&str> = if metric.parts.is_empty() {
                vec![metric.name]
            } else {
                metric
                    .parts
                    .iter()
                    .map(|p| p.column)
                    .filter(|c| !c.is_empty())
                    .collect()
            };
            for base in bases {
                let keyed = matches!(metric.shape, Shape::PerChannel | Shape::PerBarrier | Shape::Prediction)
                    || (metric.shape == Shape::AtPrescribedTime && base.ends_with("state_residual"));
                if !keyed {
                    names.push(base.to_string());
                    continue;
                }
                let prefix = format!("{base}.");
                let mut keys: Vec<String> = rows
                    .clone()
                    .into_iter()
                    .flat_map(|r| {
                        r.cells
                            .range(prefix.clone()..)
                            .take_while(|(c, _)| c.starts_with(&prefix))
                            .map(|(c, _)| c[prefix.len()..].to_string())
                            .collect::<Vec<_>>()
                    })
                    .collect();
                // State indices in numeric order (2 before 10), channels by name.
                keys.sort_by_key(|k| (k.parse::<usize>().unwrap_or(usize::MAX), k.clone()));
                keys.dedup();
                names.extend(keys.into_iter().map(|k| format!("{prefix}{k}")));
            }
        }
        names.push("complete".into());
        names.push("error".into());
        names
    }

    /// The value of one column (as named by [`FlatMetrics::columns`]); a channel this run
    /// does not have is an empty cell of the column's kind.
    pub fn cell(&self, column: &str) -> Cell {
        match column {
            "scenario" => Cell::Text(Some(self.scenario.clone())),
            "complete" => Cell::Bool(Some(self.complete)),
            "error" => Cell::Text(self.error.clone()),
            _ => self
                .cells
                .get(column)
                .cloned()
                .unwrap_or_else(|| Cell::none(column_kind(column).unwrap_or(CellKind::Text))),
        }
    }

    /// Sets one metric column (a test's or a plot's made-up run).
    pub fn set(&mut self, column: &str, cell: Cell) {
        self.cells.insert(column.to_string(), cell);
    }
}

/// A sweep summary's row: `scenario`, every column this run has, `complete`, `error`.
impl Serialize for FlatMetrics {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(None)?;
        for column in FlatMetrics::columns([self]) {
            map.serialize_entry(&column, &self.cell(&column).json())?;
        }
        map.end()
    }
}

impl<'de> Deserialize<'de> for FlatMetrics {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let entries = BTreeMap::<String, serde_json::Value>::deserialize(deserializer)?;
        let mut flat = FlatMetrics::default();
        for (column, value) in entries {
            let wrong = || D::Error::custom(format!("metric column `{column}`: unexpected value {value}"));
            match column.as_str() {
                "scenario" => flat.scenario = value.as_str().ok_or_else(wrong)?.to_string(),
                "complete" => flat.complete = value.as_bool().ok_or_else(wrong)?,
                "error" => flat.error = value.as_str().map(str::to_string),
                _ => {
                    let kind = column_kind(&column)
                        .ok_or_else(|| D::Error::custom(format!("`{column}` is not a metric column")))?;
                    let cell = Cell::from_json(kind, &value).ok_or_else(wrong)?;
                    flat.cells.insert(column, cell);
                }
            }
        }
        Ok(flat)
    }
}
