//! Signal Temporal Logic requirements: the text users of RTAMT write, and its quantitative
//! semantics (robustness) over signals sampled on a uniform grid — pure maths, no log, no
//! scenario. docs/requirements.md is the user's page; this is the reference.
//!
//! **Syntax** (RTAMT's STL, <https://github.com/nickovic/rtamt>): a comparison of two values
//! (`speed > 2.5`, `obstacle_0.h >= 0`, `2 < x1`, `abs(x2) <= 1`, `x1 - x2 > 0.5`, with `+`,
//! `-`, `*`, unary `-` and `abs(…)` over signals and numbers), `true`, `false`, and, loosest
//! last: `not`/`!`; the prefix temporal operators `always`/`G`, `eventually`/`F`,
//! `historically`/`H`, `once`/`O`, each with an optional interval `[a, b]` (or `[a:b]`, bounds
//! in seconds, or with a unit `s`, `ms`, `us`, `ns`); `until`/`U`; `since`/`S`; `and`/`&`/`&&`;
//! `or`/`|`/`||`; `implies`/`->`; `iff`/`<->`; `xor`. Every binary operator is
//! left-associative, as in RTAMT's grammar (`a -> b -> c` is `(a -> b) -> c`). `!=` and
//! RTAMT's `!==` are both "not equal". A signal name starts with a letter, `_` or `/` and
//! goes on with letters, digits, `_`, `.` and `/` (`obstacle_0.h`, `/filter.active`,
//! `left_edge/0.h`); any other name, or one that is a keyword, is quoted in `"…"` or `` `…` ``.
//!
//! **Semantics**: RTAMT's discrete-time offline monitor (`StlDiscreteTimeSpecification`,
//! `evaluate`) with the sampling period set to the signals' step: for a trace of n samples,
//! i = 0 … n−1, and bounds a, b converted to whole numbers of steps,
//!
//! | formula | ρ(φ, i) |
//! |---|---|
//! | `l > r`, `l >= r` | l(i) − r(i) |
//! | `l < r`, `l <= r` | r(i) − l(i) |
//! | `l == r` / `l != r` | −\|l(i) − r(i)\| / \|l(i) − r(i)\| |
//! | `true` / `false` | +∞ / −∞ |
//! | `not φ` | −ρ(φ, i) |
//! | `φ and ψ` / `φ or ψ` | min / max of ρ(φ, i), ρ(ψ, i) |
//! | `φ implies ψ` | max(−ρ(φ, i), ρ(ψ, i)) |
//! | `φ iff ψ` / `φ xor ψ` | −\|ρ(φ, i) − ρ(ψ, i)\| / \|ρ(φ, i) − ρ(ψ, i)\| |
//! | `always[a,b] φ` / `eventually[a,b] φ` | min / max of ρ(φ, j), j ∈ [i+a, min(i+b, n−1)] |
//! | `historically[a,b] φ` / `once[a,b] φ` | min / max of ρ(φ, j), j ∈ [max(i−b, 0), i−a] |
//! | `φ until[a,b] ψ` | max over j ∈ [i+a, min(i+b, n−1)] of min(ρ(ψ, j), min of ρ(φ, k), k ∈ [i, j)) |
//! | `φ since[a,b] ψ` | max over j ∈ [max(i−b, 0), i−a] of min(ρ(ψ, j), min of ρ(φ, k), k ∈ (j, i]) |
//!
//! An operator without an interval ranges over the rest of the trace (future: b = ∞) or all of
//! its past (a = 0, b = ∞). **End of the trace**: windows are cut at the last sample, and an
//! empty window gives the identity of its operator — +∞ for `always`/`historically`, −∞ for
//! `eventually`/`once`/`until`/`since` — exactly what RTAMT's offline monitor computes (it pads
//! the trace with those values). So `always[0,5] φ` near the end only looks at what is left,
//! and `eventually[2,3] φ` on a trace shorter than 2 s is −∞. The requirement's value is
//! ρ(φ, 0).
//!
//! **NaN**: every min and max propagates NaN, so ρ(φ, i) is NaN exactly when a sample its
//! definition above reads is NaN (a window's samples; for `until` ψ over the window and φ over
//! [i, last j); for `since` ψ over the window and φ over (first j, i]). The arithmetic of a
//! comparison follows IEEE 754 (∞ − ∞ is NaN). RTAMT (Python's `min`/`max`) gives
//! order-dependent values there: only traces without NaN are compared with it.
//!
//! **RTAMT** (0.4.10, tests/stl_rtamt.rs: bit-identical robustness signals on every operator,
//! random formulas and a real run) differs only outside the formulas both accept and evaluate
//! the same: RTAMT lacks `&&`, `||`, `!=`, `true`, `false`, unary `-` before a signal, names
//! beginning with `/` and quoted names, and reads `a.b` as a field of `a`; it takes a bound's
//! decimal text exactly (here a bound within a relative 10⁻⁹ of a whole number of steps is
//! accepted); its `min`/`max` with a NaN depend on the operands' order; its `evaluate` fails on
//! a one-sample trace. Its `next`, `prev`, `rise`, `fall`, `unless`, division, `sqrt`, `exp`,
//! `pow`, `log`, `ln`, declarations and named constants are not supported here.
//!
//! **Online**: a [`Monitor`] takes one sample at a time with memory bounded by the bounds (a
//! sliding-window aggregate per bounded operator, a running value per unbounded past operator),
//! and unbounded future operators only where nothing but `not`/`and`/`or`/… is above them (their
//! running value over the whole run is what ρ(φ, 0) needs); see [`Formula::online`].

mod eval;
mod online;
mod parse;
#[cfg(test)]
mod tests;
mod window;

pub use eval::{robustness, robustness_signal};
pub use online::Monitor;
pub use parse::parse;

/// Longest formula text, bytes.
pub const MAX_TEXT: usize = 65_536;
/// Deepest nesting of operators in a formula (the evaluators recurse over it).
pub const MAX_DEPTH: usize = 100;
/// Largest interval bound, in steps (a bounded operator's window is at most this long).
pub const MAX_STEPS: u64 = 10_000_000;
/// Most values a [`Monitor`]'s buffers may hold together.
pub const MAX_MONITOR_VALUES: usize = 1 << 25;

/// Relative tolerance of a bound's conversion to a whole number of steps.
const STEP_TOLERANCE: f64 = 1e-9;

/// Why a formula cannot be read or evaluated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StlError {
    /// The text is not a formula: where (1-based character column) and what was expected.
    #[error("column {column}: {message}")]
    Parse { column: usize, message: String },
    /// The step is not a positive finite number of seconds.
    #[error("the step must be a positive finite number of seconds, found {0}")]
    Step(f64),
    /// A bound of `formula` (a temporal operator of the requirement) that is not a whole number
    /// of steps, or is more than [`MAX_STEPS`] steps.
    #[error("`{formula}`: {message}")]
    Bound { formula: String, message: String },
    /// The signal values do not fit the formula.
    #[error("{0}")]
    Signals(String),
    /// The formula needs memory that grows with the run (or more than [`MAX_MONITOR_VALUES`])
    /// to be monitored online.
    #[error("`{formula}` cannot be monitored online: {message}; evaluate it offline")]
    Offline { formula: String, message: String },
}

/// A comparison operator of an atom.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Comparison {
    Less,
    LessEqual,
    Greater,
    GreaterEqual,
    Equal,
    NotEqual,
}

impl Comparison {
    /// The operator's text.
    fn symbol(self) -> &'static str {
        match self {
            Comparison::Less => "<",
            Comparison::LessEqual => "<=",
            Comparison::Greater => ">",
            Comparison::GreaterEqual => ">=",
            Comparison::Equal => "==",
            Comparison::NotEqual => "!=",
        }
    }

    /// The robustness of `l op r`: the signed distance from the comparison's boundary.
    #[inline]
    fn robustness(self, l: f64, r: f64) -> f64 {
        match self {
            Comparison::Greater | Comparison::GreaterEqual => l - r,
            Comparison::Less | Comparison::LessEqual => r - l,
            Comparison::Equal => -(l - r).abs(),
            Comparison::NotEqual => (l - r).abs(),
        }
    }
}

/// A value of a comparison: arithmetic over signals (indices into [`Formula::signals`]) and
/// numbers.
#[derive(Debug, Clone, PartialEq)]
enum Term {
    Signal(usize),
    Number(f64),
    Negate(Box<Term>),
    Abs(Box<Term>),
    Add(Box<Term>, Box<Term>),
    Subtract(Box<Term>, Box<Term>),
    Multiply(Box<Term>, Box<Term>),
}

impl Term {
    /// The value at one sample (`sample[k]` is signal k; a missing one reads NaN).
    fn value(&self, sample: &dyn Fn(usize) -> f64) -> f64 {
        match self {
            Term::Signal(k) => sample(*k),
            Term::Number(c) => *c,
            Term::Negate(t) => -t.value(sample),
            Term::Abs(t) => t.value(sample).abs(),
            Term::Add(l, r) => l.value(sample) + r.value(sample),
            Term::Subtract(l, r) => l.value(sample) - r.value(sample),
            Term::Multiply(l, r) => l.value(sample) * r.value(sample),
        }
    }
}

/// A binary Boolean connective.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Connective {
    And,
    Or,
    Implies,
    Iff,
    Xor,
}

impl Connective {
    #[inline]
    fn robustness(self, l: f64, r: f64) -> f64 {
        match self {
            Connective::And => min(l, r),
            Connective::Or => max(l, r),
            Connective::Implies => max(-l, r),
            Connective::Iff => -(l - r).abs(),
            Connective::Xor => (l - r).abs(),
        }
    }
}

/// A prefix temporal operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Prefix {
    Always,
    Eventually,
    Historically,
    Once,
}

impl Prefix {
    /// Whether it looks at the future (else the past).
    fn future(self) -> bool {
        matches!(self, Prefix::Always | Prefix::Eventually)
    }

    /// Whether it is a minimum (else a maximum).
    fn is_min(self) -> bool {
        matches!(self, Prefix::Always | Prefix::Historically)
    }
}

/// A time interval [start, end] of a temporal operator, seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Interval {
    start: f64,
    end: f64,
}

/// A formula's syntax tree (signals by index into [`Formula::signals`]).
#[derive(Debug, Clone, PartialEq)]
enum Node {
    Constant(bool),
    Compare(Comparison, Term, Term),
    Not(Box<Node>),
    Binary(Connective, Box<Node>, Box<Node>),
    Temporal(Prefix, Option<Interval>, Box<Node>),
    Until(Option<Interval>, Box<Node>, Box<Node>),
    Since(Option<Interval>, Box<Node>, Box<Node>),
}

/// An interval in steps: [a, b] (b = `None`: unbounded).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Steps {
    a: usize,
    b: Option<usize>,
}

/// A parsed STL formula: its syntax tree and the signals it reads.
#[derive(Debug, Clone, PartialEq)]
pub struct Formula {
    root: Node,
    signals: Vec<String>,
}

impl Formula {
    /// The distinct signal names, in order of first appearance in the text; the evaluators take
    /// the signals' values in this order.
    pub fn signals(&self) -> &[String] {
        &self.signals
    }

    /// The same formula over signals of other names: `names[k]` replaces `signals()[k]` (one
    /// distinct, non-empty name each).
    pub fn rename(&self, names: &[&str]) -> Result<Formula, StlError> {
        let distinct = names.iter().enumerate().all(|(k, n)| !names[..k].contains(n));
        if names.len() != self.signals.len() || !distinct || names.iter().any(|n| n.is_empty()) {
            return Err(StlError::Signals(format!(
                "renaming the {} signals ({}) needs as many distinct names, given {}",
                self.signals.len(),
                self.signals.join(", "),
                names.join(", ")
            )));
        }
        Ok(Formula {
            root: self.root.clone(),
            signals: names.iter().map(|n| n.to_string()).collect(),
        })
    }

    /// Whether a [`Monitor`] can evaluate it with memory bounded independently of the run's
    /// length: every unbounded future operator (`always`, `eventually`, `until` without an
    /// interval) has only Boolean connectives above it.
    pub fn online(&self) -> bool {
        offline_reason(&self.root, true).is_none()
    }

    /// How far into the future ρ(φ, 0) looks, seconds (`None`: to the end of the run).
    pub fn horizon(&self) -> Option<f64> {
        fn h(n: &Node) -> Option<f64> {
            match n {
                Node::Constant(_) | Node::Compare(..) => Some(0.0),
                Node::Not(c) => h(c),
                Node::Binary(_, l, r) | Node::Since(_, l, r) => Some(h(l)?.max(h(r)?)),
                Node::Temporal(p, i, c) if p.future() => Some(h(c)? + i.as_ref()?.end),
                Node::Temporal(_, _, c) => h(c),
                Node::Until(i, l, r) => Some(h(l)?.max(h(r)?) + i.as_ref()?.end),
            }
        }
        h(&self.root)
    }

    /// Checks that `step` (s) is positive and finite and that every bound is a whole number of
    /// steps (within a relative 10⁻⁹) of at most [`MAX_STEPS`].
    pub fn check_step(&self, step: f64) -> Result<(), StlError> {
        self.visit_steps(step, &mut |_| {})
    }

    /// Calls `f` with the interval in steps of every temporal operator, in post-order.
    fn visit_steps(&self, step: f64, f: &mut dyn FnMut(Option<Steps>)) -> Result<(), StlError> {
        if !(step.is_finite() && step > 0.0) {
            return Err(StlError::Step(step));
        }
        fn walk(formula: &Formula, n: &Node, step: f64, f: &mut dyn FnMut(Option<Steps>)) -> Result<(), StlError> {
            match n {
                Node::Constant(_) | Node::Compare(..) => Ok(()),
                Node::Not(c) => walk(formula, c, step, f),
                Node::Binary(_, l, r) => {
                    walk(formula, l, step, f)?;
                    walk(formula, r, step, f)
                }
                Node::Temporal(_, i, c) => {
                    walk(formula, c, step, f)?;
                    f(formula.steps(n, i, step)?);
                    Ok(())
                }
                Node::Until(i, l, r) | Node::Since(i, l, r) => {
                    walk(formula, l, step, f)?;
                    walk(formula, r, step, f)?;
                    f(formula.steps(n, i, step)?);
                    Ok(())
                }
            }
        }
        walk(self, &self.root, step, f)
    }

    /// A temporal operator's interval in steps (no interval: [0, ∞)).
    fn steps(&self, node: &Node, interval: &Option<Interval>, step: f64) -> Result<Option<Steps>, StlError> {
        let Some(i) = interval else { return Ok(None) };
        let count = |bound: f64| -> Result<usize, StlError> {
            let k = bound / step;
            let m = k.round();
            let fail = |message: String| StlError::Bound {
                formula: self.node_text(node),
                message,
            };
            if (k - m).abs() > STEP_TOLERANCE * k.abs().max(1.0) {
                return Err(fail(format!(
                    "the bound {bound} s is not a whole number of steps of {step} s ({k} steps)"
                )));
            }
            if !(m >= 0.0 && m <= MAX_STEPS as f64) {
                return Err(fail(format!(
                    "the bound {bound} s is {m} steps of {step} s, more than the {MAX_STEPS} allowed"
                )));
            }
            Ok(m as usize)
        };
        Ok(Some(Steps {
            a: count(i.start)?,
            b: Some(count(i.end)?),
        }))
    }

    /// The canonical text of a subformula.
    fn node_text(&self, node: &Node) -> String {
        let mut s = String::new();
        let _ = parse::write_node(&mut s, node, &self.signals);
        s
    }
}

/// Why a subformula needs unbounded memory online (`top`: only Boolean connectives above it).
fn offline_reason(n: &Node, top: bool) -> Option<&'static str> {
    match n {
        Node::Constant(_) | Node::Compare(..) => None,
        Node::Not(c) => offline_reason(c, top),
        Node::Binary(_, l, r) => offline_reason(l, top).or_else(|| offline_reason(r, top)),
        Node::Temporal(p, i, c) => {
            if p.future() && i.is_none() && !top {
                return Some(match p {
                    Prefix::Always => "an unbounded `always` inside a temporal operator",
                    _ => "an unbounded `eventually` inside a temporal operator",
                });
            }
            offline_reason(c, false)
        }
        Node::Until(i, l, r) => {
            if i.is_none() && !top {
                return Some("an unbounded `until` inside a temporal operator");
            }
            offline_reason(l, false).or_else(|| offline_reason(r, false))
        }
        Node::Since(_, l, r) => offline_reason(l, false).or_else(|| offline_reason(r, false)),
    }
}

/// The minimum of two robustness values, NaN if either is NaN.
#[inline]
fn min(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else if b <= a {
        b
    } else {
        f64::NAN
    }
}

/// The maximum of two robustness values, NaN if either is NaN.
#[inline]
fn max(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else if b >= a {
        b
    } else {
        f64::NAN
    }
}
