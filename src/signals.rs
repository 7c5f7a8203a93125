//! The signals of a run: a record of a table topic as a borrowed view ([`Observed`]), the
//! columns of its table row ([`table_row`]: the one definition of the columns of `mjsafe
//! export`, of the Python tables and of a requirement's signals), and a signal's name resolved
//! to its table and column ([`resolve_name`]; docs/requirements.md, "Signals of a run").

use std::collections::BTreeMap;

use crate::log::{proto, Topic};

/// A record of a table topic, borrowed: what a metric, a requirement's signals and the
/// tables of `mjsafe export` read.
#[derive(Debug, Clone, Copy)]
pub enum Observed<'a> {
    State(&'a proto::State),
    Barrier(&'a proto::Barrier),
    Filter(&'a proto::Filter),
    Issued(&'a proto::IssuedCommand),
    Prediction(&'a proto::Prediction),
    Event(&'a proto::Event),
    Actors(&'a proto::Actors),
    Applied(&'a proto::AppliedCommand),
    Measured(&'a proto::State),
    Actuated(&'a proto::AppliedCommand),
}

impl Observed<'_> {
    /// The topic the record is logged on.
    pub fn topic(&self) -> Topic {
        match self {
            Observed::State(_) => Topic::State,
            Observed::Barrier(_) => Topic::Barrier,
            Observed::Filter(_) => Topic::Filter,
            Observed::Issued(_) => Topic::Issued,
            Observed::Prediction(_) => Topic::Prediction,
            Observed::Event(_) => Topic::Event,
            Observed::Actors(_) => Topic::Actors,
            Observed::Applied(_) => Topic::Applied,
            Observed::Measured(_) => Topic::Measured,
            Observed::Actuated(_) => Topic::Actuated,
        }
    }

    /// The record's time (s).
    pub fn time(&self) -> f64 {
        match self {
            Observed::State(m) | Observed::Measured(m) => m.time,
            Observed::Barrier(m) => m.time,
            Observed::Filter(m) => m.time,
            Observed::Issued(m) => m.time,
            Observed::Prediction(m) => m.time,
            Observed::Event(m) => m.time,
            Observed::Actors(m) => m.time,
            Observed::Applied(m) | Observed::Actuated(m) => m.time,
        }
    }

    /// The record as read by metrics and tables (`None`: a view, not a table).
    pub fn of(record: &crate::log::Record) -> Option<Observed<'_>> {
        use crate::log::Record;
        Some(match record {
            Record::State(m) => Observed::State(m),
            Record::Barrier(m) => Observed::Barrier(m),
            Record::Filter(m) => Observed::Filter(m),
            Record::Issued(m) => Observed::Issued(m),
            Record::Prediction(m) => Observed::Prediction(m),
            Record::Event(m) => Observed::Event(m),
            Record::Actors(m) => Observed::Actors(m),
            Record::Applied(m) => Observed::Applied(m),
            Record::Measured(m) => Observed::Measured(m),
            Record::Actuated(m) => Observed::Actuated(m),
            Record::Scene(..) | Record::Transform(..) | Record::Log(..) => return None,
        })
    }
}

/// A table's columns: each one's name and type.
pub type Columns = Vec<(String, Kind)>;

/// A column's type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    F64,
    U64,
    Bool,
    Text,
}

/// One value of a row.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    F(f64),
    U(u64),
    B(bool),
    S(String),
}

/// The `/actors` columns: per road user its position, velocity, acceleration, heading and
/// whether it is absent ([`table_row`]).
fn actor_cells(m: &proto::Actors, c: &mut Vec<Cell>, name: &mut dyn FnMut(&dyn Fn() -> String, Kind)) {
    for a in &m.actors {
        for (field, v) in [
            ("x", a.x),
            ("y", a.y),
            ("vx", a.vx),
            ("vy", a.vy),
            ("ax", a.ax),
            ("ay", a.ay),
            ("heading", a.heading),
        ] {
            name(&|| format!("{}.{field}", a.name), Kind::F64);
            c.push(Cell::F(v));
        }
        name(&|| format!("{}.absent", a.name), Kind::Bool);
        c.push(Cell::B(a.absent));
    }
}

/// The row of a table topic's record (docs/log-format.md; the table of this module's docs):
/// its cells into `cells` (cleared first; `time` first), and with `columns` their names and
/// kinds. The one definition of the tables' columns: `mjsafe export`, the Python tables and a
/// requirement's signals (`metrics::requirements`) all read records through it. Without
/// `columns` and for a topic without text cells it does not allocate once `cells` has grown.
/// `state_names` names a prediction's components (the first `/state`'s names).
pub fn table_row(
    record: Observed<'_>,
    state_names: Option<&[String]>,
    c: &mut Vec<Cell>,
    mut columns: Option<&mut Columns>,
) {
    c.clear();
    let mut name = |text: &dyn Fn() -> String, kind: Kind| {
        if let Some(columns) = columns.as_deref_mut() {
            columns.push((text(), kind));
        }
    };
    c.push(Cell::F(record.time()));
    name(&|| "time".into(), Kind::F64);
    match record {
        Observed::State(m) | Observed::Measured(m) => {
            name(&|| "step".into(), Kind::U64);
            c.push(Cell::U(m.step));
            for (n, v) in m.names.iter().zip(&m.values) {
                name(&|| n.clone(), Kind::F64);
                c.push(Cell::F(*v));
            }
        }
        Observed::Issued(m) => {
            for (i, ch) in m.channels.iter().enumerate() {
                name(&|| format!("{ch}.nominal"), Kind::F64);
                name(&|| format!("{ch}.filtered"), Kind::F64);
                c.push(Cell::F(m.nominal.get(i).copied().unwrap_or(f64::NAN)));
                c.push(Cell::F(m.filtered.get(i).copied().unwrap_or(f64::NAN)));
            }
        }
        Observed::Applied(m) | Observed::Actuated(m) => {
            for (i, ch) in m.channels.iter().enumerate() {
                name(&|| ch.clone(), Kind::F64);
                name(&|| format!("{ch}.issued_at"), Kind::F64);
                c.push(Cell::F(m.values.get(i).copied().unwrap_or(f64::NAN)));
                c.push(Cell::F(m.issued_at.get(i).copied().unwrap_or(f64::NAN)));
            }
        }
        Observed::Barrier(m) => {
            for b in &m.barriers {
                let n = &b.name;
                for (field, v) in [
                    ("h", b.h),
                    ("constraint", b.constraint),
                    ("clearance", b.clearance),
                    ("time_to_collision", b.time_to_collision),
                ] {
                    name(&|| format!("{n}.{field}"), Kind::F64);
                    c.push(Cell::F(v));
                }
                name(&|| format!("{n}.known"), Kind::Bool);
                c.push(Cell::B(b.known));
                name(&|| format!("{n}.relative_degree"), Kind::U64);
                c.push(Cell::U(u64::from(b.relative_degree)));
                name(&|| format!("{n}.obstacle"), Kind::Bool);
                c.push(Cell::B(b.obstacle));
            }
        }
        Observed::Actors(m) => actor_cells(m, c, &mut name),
        Observed::Filter(m) => {
            name(&|| "active".into(), Kind::Bool);
            name(&|| "infeasible".into(), Kind::Bool);
            name(&|| "mu".into(), Kind::F64);
            name(&|| "left_out".into(), Kind::U64);
            c.extend([
                Cell::B(m.active),
                Cell::B(m.infeasible),
                Cell::F(m.mu),
                Cell::U(u64::from(m.left_out)),
            ]);
            for (i, ch) in m.channels.iter().enumerate() {
                name(&|| format!("{ch}.correction"), Kind::F64);
                c.push(Cell::F(m.correction.get(i).copied().unwrap_or(f64::NAN)));
            }
        }
        Observed::Prediction(m) => {
            name(&|| "channel".into(), Kind::Text);
            name(&|| "issued_at".into(), Kind::F64);
            name(&|| "horizon".into(), Kind::F64);
            c.extend([Cell::S(m.channel.clone()), Cell::F(m.issued_at), Cell::F(m.horizon)]);
            let state = |i: usize| {
                state_names
                    .filter(|n| n.len() == m.predicted.len())
                    .map_or_else(|| i.to_string(), |n| n[i].clone())
            };
            for (i, v) in m.predicted.iter().enumerate() {
                name(&|| format!("predicted.{}", state(i)), Kind::F64);
                c.push(Cell::F(*v));
            }
            for i in 0..m.predicted.len() {
                name(&|| format!("realized.{}", state(i)), Kind::F64);
                c.push(Cell::F(m.realized.get(i).copied().unwrap_or(f64::NAN)));
            }
            for (n, kind) in [
                ("error", Kind::F64),
                ("relative_error", Kind::F64),
                ("reused_chain", Kind::Bool),
                ("chain_mismatch", Kind::F64),
            ] {
                name(&|| n.into(), kind);
            }
            c.extend([
                Cell::F(m.error),
                Cell::F(m.relative_error),
                Cell::B(m.reused_chain),
                Cell::F(m.chain_mismatch),
            ]);
            // Per moving obstacle: assumed and true position at the target time, distance.
            let at = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(f64::NAN);
            for (k, a) in m.actors.iter().enumerate() {
                for (field, v) in [
                    ("predicted_x", at(&m.actor_predicted, 2 * k)),
                    ("predicted_y", at(&m.actor_predicted, 2 * k + 1)),
                    ("realized_x", at(&m.actor_realized, 2 * k)),
                    ("realized_y", at(&m.actor_realized, 2 * k + 1)),
                    ("error", at(&m.actor_error, k)),
                ] {
                    name(&|| format!("{a}.{field}"), Kind::F64);
                    c.push(Cell::F(v));
                }
            }
        }
        Observed::Event(m) => {
            for (n, kind) in [
                ("kind", Kind::Text),
                ("message", Kind::Text),
                ("participants", Kind::Text),
                ("depth", Kind::F64),
            ] {
                name(&|| n.into(), kind);
            }
            c.extend([
                Cell::S(m.kind.clone()),
                Cell::S(m.message.clone()),
                Cell::S(m.participants.join(" ")),
                Cell::F(m.depth),
            ]);
        }
    }
}

/// The topics whose columns are signals (`/prediction` and `/event` are not: off the step
/// grid, and text).
pub const SIGNAL_TOPICS: [Topic; 8] = [
    Topic::State,
    Topic::Measured,
    Topic::Issued,
    Topic::Applied,
    Topic::Actuated,
    Topic::Barrier,
    Topic::Filter,
    Topic::Actors,
];

/// Whether `topic`'s columns are signals.
pub fn is_signal_topic(topic: Topic) -> bool {
    SIGNAL_TOPICS.contains(&topic)
}

/// Where a signal's value comes from: a cell of a topic's table row.
#[derive(Debug, Clone, PartialEq)]
pub struct Source {
    pub topic: Topic,
    pub cell: usize,
}

/// The source of signal `name` among the tables' columns: a column of exactly one signal
/// topic, or a qualified `<topic>.<column>`.
pub fn resolve_name(name: &str, columns: &BTreeMap<Topic, Columns>) -> Result<Source, String> {
    let find = |topic: Topic, column: &str| {
        columns
            .get(&topic)
            .and_then(|c| c.iter().position(|(n, _)| n == column))
            .map(|cell| Source { topic, cell })
    };
    if name.starts_with('/') {
        // The longest topic name followed by `.`.
        let topic = Topic::ALL
            .iter()
            .filter(|t| name.strip_prefix(t.name()).is_some_and(|rest| rest.starts_with('.')))
            .max_by_key(|t| t.name().len());
        let Some(&topic) = topic else {
            return Err(format!(
                "signal `{name}`: no topic of the log starts it (expected <topic>.<column>, e.g. /state.speed)"
            ));
        };
        let column = &name[topic.name().len() + 1..];
        if !is_signal_topic(topic) {
            return Err(format!(
                "signal `{name}`: {topic} is not a signal (its messages are not on the step grid)"
            ));
        }
        return find(topic, column)
            .ok_or_else(|| format!("signal `{name}`: the log's {topic} has no column `{column}`"));
    }
    let found: Vec<Source> = SIGNAL_TOPICS.iter().filter_map(|&t| find(t, name)).collect();
    match found.as_slice() {
        [one] => Ok(one.clone()),
        [] => {
            let known: Vec<&str> = SIGNAL_TOPICS
                .iter()
                .filter_map(|t| columns.get(t))
                .flat_map(|c| c.iter().map(|(n, _)| n.as_str()))
                .filter(|n| *n != "time" && *n != "step")
                .collect();
            let closest = (known.iter())
                .map(|k| (strsim::jaro_winkler(name, k), *k))
                .filter(|(score, _)| *score >= 0.8)
                .max_by(|a, b| a.0.total_cmp(&b.0));
            Err(format!(
                "unknown signal `{name}`{}; the signals of this run: {}",
                closest.map_or(String::new(), |(_, k)| format!(" (did you mean `{k}`?)")),
                known.join(", ")
            ))
        }
        several => Err(format!(
            "signal `{name}` is a column of several tables: write one of {}",
            several
                .iter()
                .map(|s| format!("`{}.{name}`", s.topic.name()))
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}
