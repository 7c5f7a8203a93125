//! `mjsafe scorecard --compare A B`: what changed between two scorecards, item by item (a
//! regression report). Reads `scorecard.json` as JSON values, so that scorecards of other
//! mjsafe versions compare as long as they have the fields used here.

use serde_json::Value;

/// How a cell changed from A to B.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    Better,
    Worse,
    /// The same score (the figure behind it may differ: `detail`).
    Same,
    /// Only in A, only in B, or without a comparable score on one side.
    Incomparable,
}

/// One compared cell.
#[derive(Debug, Clone)]
pub struct Row {
    pub section: String,
    pub item: String,
    /// "gamma_m" when both columns have the filter's name, else "A-name → B-name".
    pub filter: String,
    pub a: Option<String>,
    pub b: Option<String>,
    pub change: Change,
}

/// The comparison of two scorecards.
#[derive(Debug, Clone)]
pub struct Comparison {
    pub rows: Vec<Row>,
    /// Things that make the two less comparable (another suite file, another mjsafe).
    pub notes: Vec<String>,
    /// Per column pair: (label, A's overall, B's overall) as fractions.
    pub overall: Vec<(String, Option<f64>, Option<f64>)>,
}

/// A cell's score as a fraction of its maximum (pass 1, fail 0; a margin its value, higher
/// better), as [`super::Cell::fraction`] computes it, and for margins the value itself.
fn comparable(cell: &Value) -> Option<f64> {
    let score = cell.get("score").and_then(Value::as_f64);
    let max = cell.get("max").and_then(Value::as_f64);
    match cell.get("status").and_then(Value::as_str)? {
        "pass" => Some(1.0),
        "fail" => Some(score.zip(max).map_or(0.0, |(s, m)| s / m)),
        // A margin without a value (not clear even at its safe end) ranks below every value:
        // only the order is used, never the number.
        "scored" => match max {
            Some(m) => score.map(|s| s / m),
            None => Some(score.unwrap_or(f64::NEG_INFINITY)),
        },
        _ => None,
    }
}

fn text(cell: &Value) -> String {
    let detail = cell.get("detail").and_then(Value::as_str).unwrap_or("-");
    match cell.get("reason").and_then(Value::as_str) {
        Some(r) if cell.get("status").and_then(Value::as_str) != Some("pass") && !detail.contains(r) => {
            format!("{detail} ({})", r.lines().next().unwrap_or_default())
        }
        _ => detail.to_string(),
    }
}

fn field<'a>(v: &'a Value, key: &str, which: &str) -> Result<&'a Value, String> {
    v.get(key)
        .ok_or_else(|| format!("{which}: key `{key}`: expected a scorecard.json (mjsafe scorecard --out DIR)"))
}

/// The filter columns of a scorecard: their names.
fn filter_names(card: &Value, which: &str) -> Result<Vec<String>, String> {
    let filters = field(card, "filters", which)?
        .as_array()
        .ok_or_else(|| format!("{which}: key `filters`: expected an array"))?;
    Ok(filters
        .iter()
        .map(|f| f.get("name").and_then(Value::as_str).unwrap_or("?").to_string())
        .collect())
}

/// Compares scorecard `a` with `b` (both parsed `scorecard.json`); `names` are how the two are
/// called in errors. Columns pair by filter name; two scorecards of one filter each pair their
/// only columns (two filters on one suite).
pub fn compare(a: &Value, b: &Value, names: (&str, &str)) -> Result<Comparison, String> {
    let (fa, fb) = (filter_names(a, names.0)?, filter_names(b, names.1)?);
    let pairs: Vec<(usize, usize, String)> = if fa.len() == 1 && fb.len() == 1 {
        let label = if fa[0] == fb[0] {
            fa[0].clone()
        } else {
            format!("{} -> {}", fa[0], fb[0])
        };
        vec![(0, 0, label)]
    } else {
        (fa.iter().enumerate())
            .filter_map(|(i, n)| fb.iter().position(|m| m == n).map(|j| (i, j, n.clone())))
            .collect()
    };
    if pairs.is_empty() {
        return Err(format!(
            "{} and {}: no filter in common (A: {}; B: {}); compare scorecards of one filter each, or of the same filters",
            names.0,
            names.1,
            fa.join(", "),
            fb.join(", ")
        ));
    }
    let items = |card: &Value, which: &str| -> Result<Vec<Value>, String> {
        field(card, "items", which)?
            .as_array()
            .cloned()
            .ok_or_else(|| format!("{which}: key `items`: expected an array"))
    };
    let (ia, ib) = (items(a, names.0)?, items(b, names.1)?);
    let name_of = |v: &Value| v.get("name").and_then(Value::as_str).unwrap_or("?").to_string();
    let mut order: Vec<(String, String)> = Vec::new();
    for v in ia.iter().chain(&ib) {
        let key = (
            v.get("section").and_then(Value::as_str).unwrap_or("").to_string(),
            name_of(v),
        );
        if !order.contains(&key) {
            order.push(key);
        }
    }
    let find = |list: &[Value], name: &str| list.iter().find(|v| name_of(v) == name).cloned();
    let mut rows = Vec::new();
    for (section, name) in &order {
        let (va, vb) = (find(&ia, name), find(&ib, name));
        for (ca, cb, label) in &pairs {
            let cell = |v: &Option<Value>, c: usize| v.as_ref().and_then(|v| v.get("cells")?.get(c).cloned());
            let (x, y) = (cell(&va, *ca), cell(&vb, *cb));
            let change = match (x.as_ref().and_then(comparable), y.as_ref().and_then(comparable)) {
                (Some(p), Some(q)) if p == q || (q - p).abs() <= 1e-9 * p.abs().max(1.0) => Change::Same,
                (Some(p), Some(q)) if q > p => Change::Better,
                (Some(_), Some(_)) => Change::Worse,
                _ => Change::Incomparable,
            };
            rows.push(Row {
                section: section.clone(),
                item: name.clone(),
                filter: label.clone(),
                a: x.as_ref().map(text),
                b: y.as_ref().map(text),
                change,
            });
        }
    }
    let mut notes = Vec::new();
    let hash = |v: &Value| v.pointer("/suite/fnv1a").and_then(Value::as_str).map(str::to_string);
    if hash(a) != hash(b) {
        notes.push(format!(
            "the suites differ ({} against {}): items may have changed",
            a.pointer("/suite/file").and_then(Value::as_str).unwrap_or("?"),
            b.pointer("/suite/file").and_then(Value::as_str).unwrap_or("?")
        ));
    }
    let version = |v: &Value| {
        v.get("mjsafe_version")
            .and_then(Value::as_str)
            .unwrap_or("?")
            .to_string()
    };
    if version(a) != version(b) {
        notes.push(format!("mjsafe {} against {}", version(a), version(b)));
    }
    for (card, name) in [(a, names.0), (b, names.1)] {
        if card.get("complete").and_then(Value::as_bool) == Some(false) {
            notes.push(format!("{name} is incomplete (interrupted)"));
        }
    }
    let overall_of = |v: &Value, c: usize| v.get("overall")?.get(c)?.as_f64();
    let overall = (pairs.iter())
        .map(|(ca, cb, label)| (label.clone(), overall_of(a, *ca), overall_of(b, *cb)))
        .collect();
    Ok(Comparison { rows, notes, overall })
}

impl Comparison {
    /// How many cells got worse.
    pub fn worse(&self) -> usize {
        self.rows.iter().filter(|r| r.change == Change::Worse).count()
    }

    /// The report: changed items first (worse, then better), then a count of the rest.
    pub fn table(&self) -> String {
        let mut rows = vec![vec![
            "item".to_string(),
            "filter".into(),
            "change".into(),
            "A".into(),
            "B".into(),
        ]];
        let mut shown: Vec<&Row> = self.rows.iter().filter(|r| r.change != Change::Same).collect();
        shown.sort_by_key(|r| match r.change {
            Change::Worse => 0,
            Change::Better => 1,
            _ => 2,
        });
        for r in &shown {
            rows.push(vec![
                format!("[{}] {}", r.section, r.item),
                r.filter.clone(),
                match r.change {
                    Change::Worse => "WORSE".into(),
                    Change::Better => "better".into(),
                    Change::Same => "same".into(),
                    Change::Incomparable => "not comparable".into(),
                },
                r.a.clone().unwrap_or_else(|| "(absent)".into()),
                r.b.clone().unwrap_or_else(|| "(absent)".into()),
            ]);
        }
        let mut out = crate::table::align_columns(&rows);
        let count = |c: Change| self.rows.iter().filter(|r| r.change == c).count();
        out.push_str(&format!(
            "\n{} worse, {} better, {} the same, {} not comparable",
            count(Change::Worse),
            count(Change::Better),
            count(Change::Same),
            count(Change::Incomparable)
        ));
        for (label, a, b) in &self.overall {
            let pct = |v: &Option<f64>| v.map_or("-".into(), |v| format!("{:.1} %", 100.0 * v));
            out.push_str(&format!("\noverall {label}: {} -> {}", pct(a), pct(b)));
        }
        for n in &self.notes {
            out.push_str(&format!("\nnote: {n}"));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn card(filter: &str, cells: &[(&str, Value)]) -> Value {
        json!({
            "mjsafe_version": "1", "suite": {"name": "s", "file": "s.toml", "fnv1a": "00"},
            "filters": [{"name": filter}], "complete": true, "overall": [0.5],
            "items": cells.iter().map(|(n, c)| json!({"name": n, "section": "S", "cells": [c]})).collect::<Vec<_>>(),
        })
    }

    #[test]
    fn a_pass_that_fails_is_worse_and_a_higher_margin_better() {
        let a = card(
            "f",
            &[
                (
                    "x",
                    json!({"status": "pass", "score": 1.0, "max": 1.0, "detail": "pass"}),
                ),
                (
                    "m",
                    json!({"status": "scored", "score": 0.1, "max": null, "detail": "0.1 s"}),
                ),
                (
                    "n",
                    json!({"status": "scored", "score": 1.0, "max": 1.2, "detail": "1.0/1.2"}),
                ),
            ],
        );
        let b = card(
            "f",
            &[
                (
                    "x",
                    json!({"status": "fail", "score": 0.0, "max": 1.0, "detail": "FAIL"}),
                ),
                (
                    "m",
                    json!({"status": "scored", "score": 0.2, "max": null, "detail": "0.2 s"}),
                ),
                (
                    "n",
                    json!({"status": "scored", "score": 1.0, "max": 1.2, "detail": "1.0/1.2"}),
                ),
            ],
        );
        let c = compare(&a, &b, ("a", "b")).unwrap();
        let change = |item: &str| c.rows.iter().find(|r| r.item == item).unwrap().change;
        assert_eq!(change("x"), Change::Worse);
        assert_eq!(change("m"), Change::Better);
        assert_eq!(change("n"), Change::Same);
        assert_eq!(c.worse(), 1);
        assert!(c.table().contains("1 worse, 1 better, 1 the same"), "{}", c.table());
    }

    #[test]
    fn an_item_only_in_one_is_not_comparable_and_foreign_json_is_refused() {
        let a = card("f", &[("x", json!({"status": "pass"}))]);
        let b = card("g", &[("y", json!({"status": "pass"}))]);
        let c = compare(&a, &b, ("a", "b")).unwrap();
        assert!(c.rows.iter().all(|r| r.change == Change::Incomparable));
        assert_eq!(c.rows[0].filter, "f -> g");
        let e = compare(&json!({"x": 1}), &b, ("a.json", "b.json")).unwrap_err();
        assert!(e.starts_with("a.json: key `filters`"), "{e}");
    }
}
