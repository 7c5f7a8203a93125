//! The metrics of runs for people and tools: the aligned table, the brief comparison, CSV,
//! and the comparison of two runs (`mjsafe analyze`), all from the declarations.

use super::{builtin, Cell, FlatMetrics, Metric, RunMetrics, Value};
use crate::table::{align_columns, csv_lines};

/// Header and one row per run, as aligned text: the file, the scenario, the metrics declared
/// for the table (header: name and unit), the status.
pub fn table(runs: &[RunMetrics]) -> String {
    let shown: Vec<(usize, &Metric)> = builtin::METRICS
        .iter()
        .enumerate()
        .filter(|(_, m)| m.table.is_some())
        .collect();
    let mut header = vec!["file".to_string(), "scenario".to_string()];
    header.extend(shown.iter().map(|(_, m)| match m.unit {
        "" | "steps" | "ticks" => m.table.unwrap_or(m.name).to_string(),
        unit => format!("{} [{unit}]", m.table.unwrap_or(m.name)),
    }));
    // Each requirement's robustness (`req.NAME`, `--require`): its own column.
    let flat: Vec<FlatMetrics> = runs.iter().map(FlatMetrics::from).collect();
    let requirements: Vec<String> = (FlatMetrics::columns(&flat).into_iter())
        .filter(|c| c.starts_with("req."))
        .collect();
    header.extend(requirements.iter().cloned());
    header.push("status".into());
    let mut rows = vec![header];
    for (r, f) in runs.iter().zip(&flat) {
        let mut row = vec![r.file.clone(), r.scenario.clone()];
        for (i, m) in &shown {
            row.push(match &r.values[*i] {
                Value::Collision(None) if !r.missing.contains_key(m.name) => "none".into(),
                value => value.display(),
            });
        }
        for c in &requirements {
            let at = format!(
                "{}{}",
                builtin::REQUIREMENT_VIOLATED_AT,
                &c[builtin::REQUIREMENTS.len()..]
            );
            row.push(match (f.cell(c), f.cell(&at)) {
                (Cell::Num(Some(v)), Cell::Num(Some(t))) if v < 0.0 => format!("{v:.4} VIOLATED at {t:.3} s"),
                (Cell::Num(Some(v)), _) if v < 0.0 => format!("{v:.4} VIOLATED"),
                (Cell::Num(Some(v)), _) => format!("{v:.4}"),
                _ => "-".into(),
            });
        }
        row.push(match (&r.error, r.complete, r.warnings.len()) {
            (Some(e), _, _) => format!("error: {e}"),
            (None, true, 0) => "complete".into(),
            (None, true, n) => format!("complete, {n} MuJoCo warning(s)"),
            (None, false, _) => "incomplete".into(),
        });
        rows.push(row);
    }
    align_columns(&rows)
}

/// A compact comparison of runs, one row per run: filter, collision, min h, min clearance
/// (`analyze --brief`, the table scripts/run.sh prints).
pub fn brief_table(runs: &[RunMetrics]) -> String {
    let mut rows = vec![["filter", "collision", "min_h", "min_clearance_m", "file"]
        .map(String::from)
        .to_vec()];
    for r in runs {
        rows.push(vec![
            r.filter_label.clone().unwrap_or_else(|| r.scenario.clone()),
            match r.collision() {
                Some(c) => format!("YES at t={:.2} s", c.time),
                None if r.missing.contains_key("collision") => "-".into(),
                None => "no".into(),
            },
            r.min_h().map_or("-".into(), |h| format!("{h:.3}")),
            r.min_clearance().map_or("-".into(), |c| format!("{c:.3}")),
            r.file.clone(),
        ]);
    }
    align_columns(&rows)
}

/// `analyze --csv`: one row per run, `file` then every [`FlatMetrics`] column.
pub fn csv(runs: &[RunMetrics]) -> String {
    let flat: Vec<FlatMetrics> = runs.iter().map(FlatMetrics::from).collect();
    let columns = FlatMetrics::columns(&flat);
    let mut rows = vec![std::iter::once("file".to_string())
        .chain(columns.iter().cloned())
        .collect()];
    for (run, f) in runs.iter().zip(&flat) {
        rows.push(
            std::iter::once(run.file.clone())
                .chain(columns.iter().map(|c| f.cell(c).csv()))
                .collect(),
        );
    }
    csv_lines(&rows)
}

/// One line of a comparison: a metric and its values in runs A and B.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub metric: String,
    /// The metric's unit (empty for text, flags and the run's description).
    pub unit: &'static str,
    pub a: Cell,
    pub b: Cell,
    /// B − A for numbers, `same`/`differs` otherwise; `None` when one side lacks the metric.
    pub difference: Option<Cell>,
}

/// `analyze --compare A B`: every metric of either run, side by side.
pub fn compare(a: &RunMetrics, b: &RunMetrics) -> Vec<Comparison> {
    let (fa, fb) = (FlatMetrics::from(a), FlatMetrics::from(b));
    FlatMetrics::columns([&fa, &fb])
        .into_iter()
        .map(|metric| {
            let (ca, cb) = (fa.cell(&metric), fb.cell(&metric));
            let difference = ca.difference(&cb);
            Comparison {
                unit: Metric::unit_of_column(&metric).unwrap_or(""),
                metric,
                a: ca,
                b: cb,
                difference,
            }
        })
        .collect()
}

/// A comparison as aligned text: header `metric  unit  A  B  B-A`.
pub fn comparison_table(rows: &[Comparison]) -> String {
    let mut cells: Vec<[String; 5]> = vec![["metric".into(), "unit".into(), "A".into(), "B".into(), "B-A".into()]];
    for r in rows {
        cells.push([
            r.metric.clone(),
            r.unit.to_string(),
            r.a.display(),
            r.b.display(),
            r.difference.as_ref().map_or("-".into(), Cell::display),
        ]);
    }
    align_columns(&cells)
}

/// A comparison as CSV: `metric,unit,a,b,difference`.
pub fn comparison_csv(rows: &[Comparison]) -> String {
    let mut lines = vec![vec![
        "metric".to_string(),
        "unit".into(),
        "a".into(),
        "b".into(),
        "difference".into(),
    ]];
    for r in rows {
        lines.push(vec![
            r.metric.clone(),
            r.unit.to_string(),
            r.a.csv(),
            r.b.csv(),
            r.difference.as_ref().map_or(String::new(), Cell::csv),
        ]);
    }
    csv_lines(&lines)
}

/// A comparison as JSON: `[{metric, unit, a, b, difference}, …]`.
pub fn comparison_json(rows: &[Comparison]) -> serde_json::Value {
    serde_json::Value::Array(
        rows.iter()
            .map(|r| {
                serde_json::json!({
                    "metric": r.metric,
                    "unit": r.unit,
                    "a": r.a.json(),
                    "b": r.b.json(),
                    "difference": r.difference.as_ref().map_or(serde_json::Value::Null, Cell::json),
                })
            })
            .collect(),
    )
}

/// A Markdown table as aligned text (cells unquoted from their backticks).
pub fn markdown_as_text(markdown: &str) -> String {
    let rows: Vec<Vec<String>> = markdown
        .lines()
        .filter(|l| l.starts_with('|') && !l.starts_with("|---"))
        .map(|l| {
            l.trim_matches('|')
                .split(" | ")
                .map(|c| c.trim().replace('`', "").replace("\\|", "|"))
                .collect()
        })
        .collect();
    align_columns(&rows)
}
