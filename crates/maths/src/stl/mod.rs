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
mod window;

pub use eval::{robustness, robustness_signal, violation_time};
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

    /// The range of [`Connective::robustness`] over l in `l` = [lower, upper] and r in `r`.
    fn bounds(self, l: [f64; 2], r: [f64; 2]) -> (f64, f64) {
        match self {
            Connective::And => (min(l[0], r[0]), min(l[1], r[1])),
            Connective::Or => (max(l[0], r[0]), max(l[1], r[1])),
            Connective::Implies => (max(-l[1], r[0]), max(-l[0], r[1])),
            // Known operands: the value itself (∞ − ∞ included).
            Connective::Iff | Connective::Xor if l[0] == l[1] && r[0] == r[1] => {
                let v = self.robustness(l[0], r[0]);
                (v, v)
            }
            Connective::Iff | Connective::Xor => {
                // |l − r| over l − r in [l0 − r1, l1 − r0] (unknown where ∞ − ∞).
                let (a, b) = (l[0] - r[1], l[1] - r[0]);
                let (low, high) = if a.is_nan() || b.is_nan() {
                    (0.0, f64::INFINITY)
                } else if a <= 0.0 && b >= 0.0 {
                    (0.0, a.abs().max(b.abs()))
                } else {
                    (a.abs().min(b.abs()), a.abs().max(b.abs()))
                };
                match self {
                    Connective::Iff => (-high, -low),
                    _ => (low, high),
                }
            }
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

#[cfg(test)]
mod tests {
    //! The parser, the offline evaluator against hand-computed traces and a direct evaluation of
    //! the definitions (module documentation), and the online monitor against the offline one.

    use super::*;
    use crate::random::SplitMix64;

    const INF: f64 = f64::INFINITY;

    fn p(text: &str) -> Formula {
        parse(text).unwrap_or_else(|e| panic!("{text}: {e}"))
    }

    /// Equal as numbers (−0 = +0), or both NaN.
    fn same(a: f64, b: f64) -> bool {
        a == b || (a.is_nan() && b.is_nan())
    }

    fn assert_signal(text: &str, values: &[&[f64]], step: f64, want: &[f64]) {
        let f = p(text);
        let got = robustness_signal(&f, values, step).unwrap();
        assert!(
            got.len() == want.len() && got.iter().zip(want).all(|(a, b)| same(*a, *b)),
            "{text}: got {got:?}, want {want:?}"
        );
        let reference = direct(&f, values, step);
        assert!(
            got.iter().zip(&reference).all(|(a, b)| same(*a, *b)),
            "{text}: direct evaluation {reference:?}"
        );
        if f.online() {
            let mut m = Monitor::new(&f, step).unwrap();
            for i in 0..want.len() {
                let sample: Vec<f64> = values.iter().map(|v| v[i]).collect();
                m.push(&sample);
            }
            assert!(
                same(m.finish(), want[0]),
                "{text}: online {} vs {}",
                m.finish(),
                want[0]
            );
        }
    }

    // ---------------------------------------------------------------------------------------
    // The definitions, evaluated directly (O(n·window)): the reference of the random tests.

    fn direct(f: &Formula, values: &[&[f64]], step: f64) -> Vec<f64> {
        direct_node(f, &f.root, values, values[0].len(), step)
    }

    fn direct_node(f: &Formula, node: &Node, values: &[&[f64]], n: usize, step: f64) -> Vec<f64> {
        let sub = |c: &Node| direct_node(f, c, values, n, step);
        let steps = |i: &Option<Interval>| f.steps(node, i, step).unwrap();
        // [lo, hi] ∩ [0, n−1] of the future window [i+a, i+b] / past window [i−b, i−a].
        let future = |i: usize, s: Option<Steps>| {
            let (a, b) = s.map_or((0, usize::MAX), |s| (s.a, s.b.unwrap()));
            (i + a, i.saturating_add(b).min(n - 1))
        };
        let past = |i: usize, s: Option<Steps>| -> (usize, isize) {
            let (a, b) = s.map_or((0, usize::MAX), |s| (s.a, s.b.unwrap()));
            (i.saturating_sub(b), i as isize - a as isize)
        };
        match node {
            Node::Constant(b) => vec![if *b { INF } else { -INF }; n],
            Node::Compare(c, l, r) => (0..n)
                .map(|i| {
                    let at = |k: usize| values[k][i];
                    c.robustness(l.value(&at), r.value(&at))
                })
                .collect(),
            Node::Not(c) => sub(c).iter().map(|v| -v).collect(),
            Node::Binary(c, l, r) => sub(l).iter().zip(sub(r)).map(|(a, b)| c.robustness(*a, b)).collect(),
            Node::Temporal(p, i, c) => {
                let x = sub(c);
                let s = steps(i);
                (0..n)
                    .map(|t| {
                        let range: Vec<usize> = if p.future() {
                            let (lo, hi) = future(t, s);
                            (lo..=hi).collect()
                        } else {
                            let (lo, hi) = past(t, s);
                            (lo as isize..=hi).map(|k| k as usize).collect()
                        };
                        let mut acc = if p.is_min() { INF } else { -INF };
                        for k in range {
                            acc = if p.is_min() { min(acc, x[k]) } else { max(acc, x[k]) };
                        }
                        acc
                    })
                    .collect()
            }
            Node::Until(i, l, r) => {
                let (phi, psi, s) = (sub(l), sub(r), steps(i));
                (0..n)
                    .map(|t| {
                        let (lo, hi) = future(t, s);
                        let mut acc = -INF;
                        for j in lo..=hi {
                            let mut held = INF;
                            for &v in &phi[t..j] {
                                held = min(held, v);
                            }
                            acc = max(acc, min(psi[j], held));
                        }
                        acc
                    })
                    .collect()
            }
            Node::Since(i, l, r) => {
                let (phi, psi, s) = (sub(l), sub(r), steps(i));
                (0..n)
                    .map(|t| {
                        let (lo, hi) = past(t, s);
                        let mut acc = -INF;
                        for j in lo as isize..=hi {
                            let j = j as usize;
                            let mut held = INF;
                            for &v in &phi[j + 1..=t] {
                                held = min(held, v);
                            }
                            acc = max(acc, min(psi[j], held));
                        }
                        acc
                    })
                    .collect()
            }
        }
    }

    // ---------------------------------------------------------------------------------------
    // Parser.

    #[test]
    fn every_operator_parses_and_short_forms_are_the_same() {
        for (long, short) in [
            ("always[0, 1] x > 0", "G[0:1] x > 0"),
            ("eventually[0, 1] x > 0", "F[0,1] x>0"),
            ("historically[0, 1] x > 0", "H [0 , 1] x > 0"),
            ("once[0, 1] x > 0", "O[0,1](x > 0)"),
            ("x > 0 until[0, 1] y < 1", "x > 0 U[0,1] y < 1"),
            ("x > 0 since[0, 1] y < 1", "x>0 S[0,1] y<1"),
            ("always x > 0", "G x > 0"),
            ("x > 0 until y < 1", "(x > 0) U (y < 1)"),
            ("not x > 0", "!x > 0"),
            ("x > 0 and y < 1", "x > 0 && y < 1"),
            ("x > 0 and y < 1", "x > 0 & y < 1"),
            ("x > 0 or y < 1", "x > 0 || y < 1"),
            ("x > 0 or y < 1", "x > 0 | y < 1"),
            ("x > 0 implies y < 1", "x > 0 -> y < 1"),
            ("x > 0 iff y < 1", "x > 0 <-> y < 1"),
            ("x != 1", "x !== 1"),
            ("always[0, 0.5] x > 0", "always[0 ms, 500 ms] x > 0"),
            ("always[0.5, 1] x > 0", "always[500, 1000ms] x > 0"),
            ("always[0, 0.000001] x > 0", "always[0, 1 us] x > 0"),
            ("true and x > 0", "TRUE & x > 0"),
        ] {
            assert_eq!(p(long), p(short), "{long} / {short}");
            assert_eq!(p(short).to_string(), long);
        }
        for text in [
            "x < 1",
            "x <= 1",
            "x > 1",
            "x >= 1",
            "x == 1",
            "x != 1",
            "2 < x",
            "abs(x) <= 1",
            "x - y > 0.5",
            "x + 2 * y >= -3",
            "-x > 0",
            "x > 0 xor y > 0",
            "false or x > 0",
        ] {
            let f = p(text);
            assert_eq!(parse(&f.to_string()).unwrap(), f, "{text}");
        }
    }

    #[test]
    fn precedence_follows_rtamt() {
        for (text, explicit) in [
            ("not x > 0 and y > 0", "(not (x > 0)) and (y > 0)"),
            ("x > 0 or y > 0 and z > 0", "(x > 0) or ((y > 0) and (z > 0))"),
            ("x > 0 and y > 0 or z > 0", "((x > 0) and (y > 0)) or (z > 0)"),
            ("x > 0 -> y > 0 -> z > 0", "((x > 0) -> (y > 0)) -> (z > 0)"),
            ("x > 0 or y > 0 -> z > 0", "((x > 0) or (y > 0)) -> (z > 0)"),
            ("always x > 0 and y > 0", "(always (x > 0)) and (y > 0)"),
            ("x > 0 until y > 0 and z > 0", "((x > 0) until (y > 0)) and (z > 0)"),
            ("x > 0 since y > 0 until z > 0", "(x > 0) since ((y > 0) until (z > 0))"),
            ("x > 0 until y > 0 until z > 0", "((x > 0) until (y > 0)) until (z > 0)"),
            ("not x > 0 until y > 0", "(not (x > 0)) until (y > 0)"),
            ("always not x > 0 or y > 0", "(always (not (x > 0))) or (y > 0)"),
            (
                "x > 0 and always y > 0 or z > 0",
                "((x > 0) and (always (y > 0))) or (z > 0)",
            ),
            ("x > 0 iff y > 0 xor z > 0", "((x > 0) iff (y > 0)) xor (z > 0)"),
            ("x > 0 implies y > 0 iff z > 0", "((x > 0) implies (y > 0)) iff (z > 0)"),
            ("-x * 2 + y - 1 > 0", "(((-x) * 2) + y) - 1 > 0"),
            ("x - y - z > 0", "(x - y) - z > 0"),
            ("x - (y - z) > 0", "x - (y - z) > 0"),
        ] {
            assert_eq!(p(text), p(explicit), "{text}");
            assert_eq!(p(&p(text).to_string()), p(text), "{text}");
        }
        assert_eq!(
            p("x > 0 -> y > 0 -> z > 0").to_string(),
            "x > 0 implies y > 0 implies z > 0"
        );
        assert_eq!(
            p("x > 0 -> (y > 0 -> z > 0)").to_string(),
            "x > 0 implies (y > 0 implies z > 0)"
        );
        assert_eq!(p("x - (y - z) > -1").to_string(), "x - (y - z) > -1");
        assert_eq!(
            p("always (x > 0 until y > 0)").to_string(),
            "always (x > 0 until y > 0)"
        );
    }

    #[test]
    fn names() {
        let f = p("obstacle_0.h >= 0 and /filter.active < 0.5 and left_edge/0.h > 0 and obstacle_0.h < 9");
        assert_eq!(f.signals(), ["obstacle_0.h", "/filter.active", "left_edge/0.h"]);
        let f = p("\"always\" > 0 and `a \"b\"` < 1 and \"x y\" > 2 and `G` > 0 and \"s\" > 1 and s > 2");
        assert_eq!(f.signals(), ["always", "a \"b\"", "x y", "G", "s"]);
        assert_eq!(
            f.to_string(),
            "\"always\" > 0 and `a \"b\"` < 1 and \"x y\" > 2 and \"G\" > 0 and s > 1 and s > 2"
        );
        assert_eq!(parse(&f.to_string()).unwrap(), f);
        assert_eq!(p("x1 > 0 and x2 < 0 or x1 == 1").signals(), ["x1", "x2"]);
    }

    #[test]
    fn parse_errors_name_the_column_and_what_was_expected() {
        for (text, column, needle) in [
            ("", 1, "expected a condition or a value, found the end"),
            ("x >", 4, "expected a condition or a value, found the end"),
            ("x > 0 and", 10, "found the end"),
            ("(x > 0", 7, "expected `)` or an operator, found the end"),
            (
                "x > 0 )",
                7,
                "expected an operator or the end of the formula, found `)`",
            ),
            ("x = 1", 3, "expected `==`"),
            ("x # 1", 3, "unexpected character `#`"),
            ("\"abc > 0", 1, "not closed"),
            ("\"\" > 0", 1, "inside the quotes"),
            ("x > 1e999", 5, "out of range"),
            (
                "always x",
                8,
                "`always` (column 1) needs a condition here, found a value",
            ),
            ("x > 0 and y", 11, "`and` (column 7) needs a condition here"),
            ("x", 1, "the formula is a value, not a condition"),
            ("x + (y > 0) > 1", 3, "`+` needs a value"),
            ("always[1, 0] x > 0", 7, "starts after it ends"),
            ("always[-1, 0] x > 0", 8, "expected a bound"),
            ("always[0 1] x > 0", 10, "expected `,` or `:`"),
            ("always[0, 1 x > 0", 13, "expected `]`"),
            ("next x > 0", 1, "RTAMT's `next` is not supported"),
            ("x > 0 unless y > 0", 7, "RTAMT's `unless` is not supported"),
            ("and > 0", 1, "expected a condition or a value, found `and`"),
            ("abs x > 0", 5, "expected `(` after `abs`"),
        ] {
            match parse(text) {
                Err(StlError::Parse { column: c, message }) => {
                    assert_eq!(c, column, "{text}: {message}");
                    assert!(message.contains(needle), "{text}: {message}");
                }
                other => panic!("{text}: {other:?}"),
            }
        }
        let deep = format!("{}x > 0{}", "(".repeat(300), ")".repeat(300));
        assert!(matches!(parse(&deep), Err(StlError::Parse { .. })));
        let long = vec!["x > 0"; 200].join(" and ");
        let e = parse(&long).unwrap_err().to_string();
        assert!(e.contains("nested more than 100 deep"), "{e}");
        let nots = format!("{}x > 0", "not ".repeat(150));
        assert!(parse(&nots).is_err());
        assert!(parse(&"x".repeat(MAX_TEXT + 1)).is_err());
        // One line.
        assert!(!parse("x >\n\n").unwrap_err().to_string().contains('\n'));
    }

    #[test]
    fn online_and_steps() {
        for (text, online) in [
            ("always x > 0", true),
            ("eventually x > 0 and always[0, 2] y > 0", true),
            ("not (x > 0 until y > 0)", true),
            ("historically x > 0 since y > 0", true),
            ("always (historically[0, 1] x > 0 or once y > 0)", true),
            ("eventually[0, 5] always x > 0", false),
            ("historically eventually x > 0", false),
            ("always (x > 0 until y > 0)", false),
            ("(eventually x > 0) until[0, 1] y > 0", false),
        ] {
            assert_eq!(p(text).online(), online, "{text}");
            assert_eq!(Monitor::new(&p(text), 1.0).is_ok(), online, "{text}");
        }
        let e = Monitor::new(&p("eventually[0, 5] always x > 0"), 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("unbounded `always` inside a temporal operator"), "{e}");
        assert!(e.contains("evaluate it offline"), "{e}");

        let f = p("x > 0 and always[0, 0.005] y > 0");
        assert!(f.check_step(0.001).is_ok());
        let e = f.check_step(0.002).unwrap_err().to_string();
        assert!(e.contains("`always[0, 0.005] y > 0`"), "{e}");
        assert!(e.contains("0.005 s is not a whole number of steps of 0.002 s"), "{e}");
        assert!(p("always[0.1, 0.3] x > 0").check_step(0.002).is_ok());
        assert!(p("always[0, 1] x > 0").check_step(0.3).is_err());
        for bad in [0.0, -1.0, f64::NAN, INF] {
            assert!(matches!(p("x > 0").check_step(bad), Err(StlError::Step(_))));
        }
        let e = p("always[0, 100] x > 0").check_step(1e-6).unwrap_err().to_string();
        assert!(e.contains("more than the 10000000 allowed"), "{e}");
        assert_eq!(p("always[0, 2] x > 0 and eventually[1, 4] y > 0").horizon(), Some(4.0));
        assert_eq!(p("x > 0 until[0, 2] always[1, 3] y > 0").horizon(), Some(5.0));
        assert_eq!(p("historically[0, 9] x > 0").horizon(), Some(0.0));
        assert_eq!(p("always x > 0").horizon(), None);
    }

    // ---------------------------------------------------------------------------------------
    // Hand-computed robustness.

    const X: [f64; 5] = [1.0, -2.0, 3.0, 0.0, 5.0];
    const Y: [f64; 5] = [-1.0, -1.0, 2.0, -3.0, 4.0];

    #[test]
    fn atoms_and_connectives() {
        let x: &[f64] = &X;
        assert_signal("x > 0.5", &[x], 1.0, &[0.5, -2.5, 2.5, -0.5, 4.5]);
        assert_signal("x >= 0.5", &[x], 1.0, &[0.5, -2.5, 2.5, -0.5, 4.5]);
        assert_signal("x < 1", &[x], 1.0, &[0.0, 3.0, -2.0, 1.0, -4.0]);
        assert_signal("x <= 1", &[x], 1.0, &[0.0, 3.0, -2.0, 1.0, -4.0]);
        assert_signal("1 > x", &[x], 1.0, &[0.0, 3.0, -2.0, 1.0, -4.0]);
        assert_signal("x == 3", &[x], 1.0, &[-2.0, -5.0, 0.0, -3.0, -2.0]);
        assert_signal("x != 3", &[x], 1.0, &[2.0, 5.0, 0.0, 3.0, 2.0]);
        assert_signal("abs(x) - 1 > 0", &[x], 1.0, &[0.0, 1.0, 2.0, -1.0, 4.0]);
        assert_signal("not x > 0", &[x], 1.0, &[-1.0, 2.0, -3.0, 0.0, -5.0]);
        assert_signal("true and x > 0", &[x], 1.0, &X);
        assert_signal("false or x > 0", &[x], 1.0, &X);
        let xy: &[&[f64]] = &[&X, &Y];
        assert_signal("x > 0 and y > 0", xy, 1.0, &[-1.0, -2.0, 2.0, -3.0, 4.0]);
        assert_signal("x > 0 or y > 0", xy, 1.0, &[1.0, -1.0, 3.0, 0.0, 5.0]);
        assert_signal("x > 0 implies y > 0", xy, 1.0, &[-1.0, 2.0, 2.0, 0.0, 4.0]);
        assert_signal("x > 0 iff y > 0", xy, 1.0, &[-2.0, -1.0, -1.0, -3.0, -1.0]);
        assert_signal("x > 0 xor y > 0", xy, 1.0, &[2.0, 1.0, 1.0, 3.0, 1.0]);
        assert_signal("x - y > 0", xy, 1.0, &[2.0, -1.0, 1.0, 3.0, 1.0]);
        assert_signal("x * y + 1 < 0", xy, 1.0, &[0.0, -3.0, -7.0, -1.0, -21.0]);
    }

    #[test]
    fn temporal_operators_with_the_end_of_the_trace() {
        let x: &[f64] = &X;
        assert_signal("always[1, 2] x > 0", &[x], 1.0, &[-2.0, 0.0, 0.0, 5.0, INF]);
        assert_signal("eventually[1, 2] x > 0", &[x], 1.0, &[3.0, 3.0, 5.0, 5.0, -INF]);
        assert_signal("always[0, 0] x > 0", &[x], 1.0, &X);
        assert_signal("eventually[0, 10] x > 0", &[x], 1.0, &[5.0; 5]);
        assert_signal("always[5, 7] x > 0", &[x], 1.0, &[INF; 5]);
        assert_signal("always x > 0", &[x], 1.0, &[-2.0, -2.0, 0.0, 0.0, 5.0]);
        assert_signal("eventually x > 0", &[x], 1.0, &[5.0; 5]);
        assert_signal("historically[1, 2] x > 0", &[x], 1.0, &[INF, 1.0, -2.0, -2.0, 0.0]);
        assert_signal("once[1, 2] x > 0", &[x], 1.0, &[-INF, 1.0, 1.0, 3.0, 3.0]);
        assert_signal("historically x > 0", &[x], 1.0, &[1.0, -2.0, -2.0, -2.0, -2.0]);
        assert_signal("once x > 0", &[x], 1.0, &[1.0, 1.0, 3.0, 3.0, 5.0]);
        // Bounds in seconds over a step of 0.5 s: [0.5, 1] s is [1, 2] steps.
        assert_signal("always[0.5, 1] x > 0", &[x], 0.5, &[-2.0, 0.0, 0.0, 5.0, INF]);
        let xy: &[&[f64]] = &[&X, &Y];
        assert_signal("x > 0 until[1, 2] y > 0", xy, 1.0, &[-1.0, -2.0, 0.0, 0.0, -INF]);
        assert_signal("x > 0 until y > 0", xy, 1.0, &[-1.0, -1.0, 2.0, 0.0, 4.0]);
        assert_signal("x > 0 until[0, 0] y > 0", xy, 1.0, &Y);
        assert_signal("x > 0 since[1, 2] y > 0", xy, 1.0, &[-INF, -2.0, -1.0, 0.0, 0.0]);
        assert_signal("x > 0 since y > 0", xy, 1.0, &[-1.0, -1.0, 2.0, 0.0, 4.0]);
        assert_signal("x > 0 since[0, 0] y > 0", xy, 1.0, &Y);
        // One sample.
        assert_signal("eventually[1, 2] x > 0", &[&[3.0]], 1.0, &[-INF]);
        assert_signal("x > 0 until y > 0", &[&[3.0], &[-1.0]], 1.0, &[-1.0]);
    }

    #[test]
    fn nan_propagates_to_what_reads_it() {
        let nan = f64::NAN;
        let x: &[f64] = &[1.0, nan, 3.0, 0.0, 5.0];
        assert_signal("x > 0", &[x], 1.0, &[1.0, nan, 3.0, 0.0, 5.0]);
        assert_signal("always[0, 1] x > 0", &[x], 1.0, &[nan, nan, 0.0, 0.0, 5.0]);
        assert_signal("eventually[2, 3] x > 0", &[x], 1.0, &[3.0, 5.0, 5.0, -INF, -INF]);
        assert_signal("historically x > 0", &[x], 1.0, &[1.0, nan, nan, nan, nan]);
        let y: &[f64] = &[-1.0, -1.0, 2.0, -3.0, 4.0];
        // φ at the window's last sample is not read.
        assert_signal("x > 0 until[0, 1] y > 0", &[x, y], 1.0, &[-1.0, nan, 2.0, 0.0, 4.0]);
        assert_signal(
            "x > 0 until y > 0",
            &[&[1.0, 2.0, nan], &[-1.0, 3.0, 0.0]],
            1.0,
            &[1.0, 3.0, 0.0],
        );
        assert_signal(
            "x > 0 since y > 0",
            &[&[nan, 2.0, 1.0], &[3.0, -1.0, 0.0]],
            1.0,
            &[3.0, 2.0, 1.0],
        );
    }

    #[test]
    fn evaluation_errors() {
        let f = p("x > 0 and y > 0");
        let x: &[f64] = &[1.0, 2.0];
        assert!(robustness(&f, &[x], 1.0)
            .unwrap_err()
            .to_string()
            .contains("reads 2 signals (x, y), given 1"));
        let e = robustness(&f, &[x, &[1.0]], 1.0).unwrap_err().to_string();
        assert!(e.contains("signal `y` has 1 samples, `x` has 2"), "{e}");
        assert!(robustness(&f, &[&[], &[]], 1.0).is_err());
        assert!(robustness(&f, &[x, x], 0.0).is_err());
        assert!(robustness(&p("true"), &[], 1.0).is_err());
        assert!(Monitor::new(&p("true"), 1.0).is_err());
        let mut m = Monitor::new(&f, 1.0).unwrap();
        assert!(m.finish().is_nan(), "no sample");
        m.reset();
        m.push(&[1.0]);
        assert!(m.finish().is_nan(), "a missing value reads NaN");
        m.reset();
        m.push(&[1.0, 2.0, 3.0]);
        assert_eq!(m.finish(), 1.0);
        m.push(&[-1.0, -1.0]);
        assert_eq!(m.finish(), 1.0, "pushes after finish are ignored");
    }

    #[test]
    fn monitor_value_settles_once_the_horizon_is_seen() {
        let f = p("always[0, 2] x > 0");
        let mut m = Monitor::new(&f, 1.0).unwrap();
        m.push(&[1.0]);
        m.push(&[2.0]);
        assert_eq!(m.value(), None);
        m.push(&[0.5]);
        assert_eq!(m.value(), Some(0.5));
        m.push(&[-9.0]);
        assert_eq!(m.finish(), 0.5);
        let mut m = Monitor::new(&p("always x > 0"), 1.0).unwrap();
        m.push(&[1.0]);
        assert_eq!(m.value(), None);
        assert_eq!(m.finish(), 1.0);
        assert_eq!(m.value(), Some(1.0));
    }

    // ---------------------------------------------------------------------------------------
    // Random formulas and traces.

    const NAMES: [&str; 3] = ["x", "y", "obstacle_0.h"];

    fn pick<'a>(rng: &mut SplitMix64, options: &[&'a str]) -> &'a str {
        options[rng.below(options.len())]
    }

    fn atom(rng: &mut SplitMix64) -> String {
        let name = pick(rng, &NAMES);
        let other = pick(rng, &NAMES);
        let op = pick(rng, &["<", "<=", ">", ">=", "==", "!=", "!=="]);
        let c = pick(rng, &["0", "0.5", "-1", "1", "2"]);
        match rng.below(6) {
            0 => format!("{c} {op} {name}"),
            1 => format!("abs({name}) {op} {c}"),
            2 => format!("{name} - {other} {op} {c}"),
            3 => format!("{name} + 2 * {other} {op} {c}"),
            _ => format!("{name} {op} {c}"),
        }
    }

    /// A random formula, bounds in whole steps of `step`; unbounded future operators only where
    /// `top` (nothing but connectives above) unless `anywhere`.
    fn formula(rng: &mut SplitMix64, depth: usize, top: bool, anywhere: bool, step: f64, max_bound: usize) -> String {
        if depth == 0 || rng.below(5) == 0 {
            return atom(rng);
        }
        let interval = |rng: &mut SplitMix64| {
            let a = rng.below(max_bound + 1);
            let b = a + rng.below(max_bound + 1);
            format!("[{}, {}]", a as f64 * step, b as f64 * step)
        };
        let k = rng.below(10);
        let bounded = rng.below(3) != 0;
        let future_ok = top || anywhere;
        let sub =
            |rng: &mut SplitMix64, top: bool| format!("({})", formula(rng, depth - 1, top, anywhere, step, max_bound));
        match k {
            0 => format!("{} {}", pick(rng, &["not", "!"]), sub(rng, top)),
            1 | 2 => {
                let op = pick(rng, &["and", "or", "implies", "&&", "|", "->", "iff", "xor"]);
                format!("{} {op} {}", sub(rng, top), sub(rng, top))
            }
            3..=6 => {
                let op = pick(
                    rng,
                    &["always", "eventually", "historically", "once", "G", "F", "H", "O"],
                );
                let future = matches!(op, "always" | "eventually" | "G" | "F");
                let i = if bounded || (future && !future_ok) {
                    interval(rng)
                } else {
                    String::new()
                };
                format!("{op}{i} {}", sub(rng, false))
            }
            _ => {
                let op = pick(rng, &["until", "since", "U", "S"]);
                let future = matches!(op, "until" | "U");
                let i = if bounded || (future && !future_ok) {
                    interval(rng)
                } else {
                    String::new()
                };
                format!("{} {op}{i} {}", sub(rng, false), sub(rng, false))
            }
        }
    }

    fn trace(rng: &mut SplitMix64, n: usize, special: bool) -> Vec<Vec<f64>> {
        (0..NAMES.len())
            .map(|_| {
                (0..n)
                    .map(|_| match rng.below(if special { 40 } else { 1000 }) {
                        0 => f64::NAN,
                        1 => INF,
                        2 => -INF,
                        3..=14 => pick(rng, &["0", "1", "-1", "2", "0.5"]).parse().unwrap(),
                        _ => (rng.next_f64() - 0.5) * 6.0,
                    })
                    .collect()
            })
            .collect()
    }

    /// The signal values of the names `f` reads.
    fn columns<'a>(f: &Formula, t: &'a [Vec<f64>]) -> Vec<&'a [f64]> {
        f.signals()
            .iter()
            .map(|s| t[NAMES.iter().position(|n| n == s).unwrap()].as_slice())
            .collect()
    }

    #[test]
    fn random_formulas_offline_equals_the_definitions_and_the_text_round_trips() {
        let mut rng = SplitMix64(7);
        let step = 0.25;
        for case in 0..3000 {
            let text = formula(&mut rng, 4, true, true, step, 3);
            let f = p(&text);
            let canonical = f.to_string();
            assert_eq!(parse(&canonical).unwrap(), f, "{text} → {canonical}");
            assert_eq!(parse(&canonical).unwrap().to_string(), canonical);
            let n = 1 + rng.below(25);
            let t = trace(&mut rng, n, case % 2 == 0);
            let values = columns(&f, &t);
            let got = robustness_signal(&f, &values, step).unwrap();
            let want = direct(&f, &values, step);
            for i in 0..n {
                assert!(
                    same(got[i], want[i]),
                    "{text} at {i}: {} vs {}; trace {t:?}",
                    got[i],
                    want[i]
                );
            }
        }
    }

    /// The trace with every sample from `from` on replaced by `fill(rng)`.
    fn continued(t: &[Vec<f64>], from: usize, rng: &mut SplitMix64, fill: fn(&mut SplitMix64) -> f64) -> Vec<Vec<f64>> {
        t.iter()
            .map(|s| {
                s.iter()
                    .enumerate()
                    .map(|(i, &v)| if i < from { v } else { fill(rng) })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn a_violation_time_is_certain_and_the_earliest_for_monotone_formulas() {
        // Sound on any formula: at the time found, no continuation of the samples up to it
        // (random ones, extremes included) satisfies the formula. Earliest on formulas that
        // only grow with their signals (atoms `name > c` under and/or/always/eventually/
        // until): continued by +10⁹ from the sample found, the run satisfies it.
        let mut rng = SplitMix64(23);
        let step = 0.5;
        let mut violated = 0;
        for case in 0..3000 {
            let monotone = case % 2 == 0;
            let text = if monotone {
                fn grow(rng: &mut SplitMix64, depth: usize) -> String {
                    let w = |rng: &mut SplitMix64| {
                        let a = rng.below(4);
                        [
                            format!("[{}, {}]", a as f64 * 0.5, (a + rng.below(4)) as f64 * 0.5),
                            String::new(),
                        ][rng.below(2)]
                        .clone()
                    };
                    match if depth == 0 { 0 } else { rng.below(6) } {
                        0 => format!("{} > {}", pick(rng, &NAMES), pick(rng, &["0", "0.5", "-1", "1"])),
                        1 => format!("({} and {})", grow(rng, depth - 1), grow(rng, depth - 1)),
                        2 => format!("({} or {})", grow(rng, depth - 1), grow(rng, depth - 1)),
                        3 => format!("always{} ({})", w(rng), grow(rng, depth - 1)),
                        4 => format!("eventually{} ({})", w(rng), grow(rng, depth - 1)),
                        _ => format!("({} until{} {})", grow(rng, depth - 1), w(rng), grow(rng, depth - 1)),
                    }
                }
                grow(&mut rng, 3)
            } else {
                formula(&mut rng, 3, true, true, step, 3)
            };
            let f = p(&text);
            let n = 1 + rng.below(20);
            let t = continued(&trace(&mut rng, n, false), n, &mut rng, |_| 0.0);
            let values = columns(&f, &t);
            let Some(at) = violation_time(&f, &values, step).unwrap() else {
                let rho = robustness(&f, &values, step).unwrap();
                assert!(rho.is_nan() || rho >= 0.0, "{text}: violated without a time");
                continue;
            };
            violated += 1;
            let k = (at / step).round() as usize;
            assert!(k < n && robustness(&f, &values, step).unwrap() < 0.0, "{text}: {at}");
            for _ in 0..20 {
                let other = continued(&t, k + 1, &mut rng, |rng| match rng.below(10) {
                    0 => INF,
                    1 => -INF,
                    _ => (rng.next_f64() - 0.5) * 8.0,
                });
                let rho = robustness(&f, &columns(&f, &other), step).unwrap();
                assert!(
                    rho < 0.0 || rho.is_nan(),
                    "{text}: certain at {at} s, yet {rho} on {other:?}"
                );
            }
            // (At the first sample there is nothing earlier: a formula no run of n samples
            // satisfies is certain from it.)
            if monotone && k > 0 {
                let best = continued(&t, k, &mut rng, |_| 1e9);
                let rho = robustness(&f, &columns(&f, &best), step).unwrap();
                assert!(
                    rho >= 0.0,
                    "{text}: not yet certain before {at} s, yet {rho} on {best:?}"
                );
            }
        }
        assert!(violated > 500, "{violated}");
    }

    fn online_value(f: &Formula, values: &[&[f64]], step: f64) -> f64 {
        let mut m = Monitor::new(f, step).unwrap();
        let mut sample = vec![0.0; values.len()];
        for i in 0..values[0].len() {
            for (s, v) in sample.iter_mut().zip(values) {
                *s = v[i];
            }
            m.push(&sample);
        }
        m.finish()
    }

    #[test]
    fn random_formulas_online_equals_offline() {
        let mut rng = SplitMix64(11);
        let step = 0.5;
        let mut checked = 0;
        for case in 0..4000 {
            // Long windows and traces (the window aggregates flip many times) one case in 40.
            let (depth, max_bound, n) = match case % 40 {
                0 => (3, 80, 1 + rng.below(1500)),
                k if k % 4 == 1 => (3, 12, 1 + rng.below(120)),
                _ => (4, 3, 1 + rng.below(20)),
            };
            let text = formula(&mut rng, depth, true, false, step, max_bound);
            let f = p(&text);
            assert!(f.online(), "{text}");
            let t = trace(&mut rng, n, case % 3 == 0);
            let values = columns(&f, &t);
            let want = robustness(&f, &values, step).unwrap();
            let got = online_value(&f, &values, step);
            assert!(
                same(got, want),
                "{text}: online {got} vs offline {want}; n = {n}, trace {t:?}"
            );
            checked += 1;
        }
        assert_eq!(checked, 4000);
    }

    #[test]
    fn monitor_reset_reuses_the_buffers() {
        let mut rng = SplitMix64(3);
        let f = p("always[0, 2] (x > 0 until[1, 3] y < 1) and eventually (historically[0, 2] x > -1)");
        let mut m = Monitor::new(&f, 1.0).unwrap();
        for _ in 0..50 {
            let n = 1 + rng.below(30);
            let t = trace(&mut rng, n, false);
            let values = columns(&f, &t);
            m.reset();
            for (x, y) in values[0].iter().zip(values[1]) {
                m.push(&[*x, *y]);
            }
            assert!(same(m.finish(), robustness(&f, &values, 1.0).unwrap()));
        }
    }

    #[test]
    fn push_and_finish_do_not_allocate() {
        let f = p(
            "always[0, 20] (x > 0 until[2, 30] y < 1 or once[1, 5] x > 2) and eventually (y > 0 since[0, 9] x > 1) \
               and historically (x > -5) and always (abs(x - y) < 9)",
        );
        let mut m = Monitor::new(&f, 0.5).unwrap();
        let mut rng = SplitMix64(5);
        let samples: Vec<[f64; 2]> = (0..2000)
            .map(|_| [rng.next_f64() * 4.0 - 2.0, rng.next_f64() * 4.0 - 2.0])
            .collect();
        let mut v = 0.0;
        let counted = allocation_counter::measure(|| {
            for s in &samples {
                m.push(s);
            }
            v = m.finish();
        });
        assert_eq!(counted.count_total, 0, "push or finish allocated");
        let x: Vec<f64> = samples.iter().map(|s| s[0]).collect();
        let y: Vec<f64> = samples.iter().map(|s| s[1]).collect();
        assert!(same(v, robustness(&f, &[&x, &y], 0.5).unwrap()));
    }

    #[test]
    fn any_text_parses_or_fails_without_panicking() {
        const PIECES: [&str; 40] = [
            "x",
            "y",
            "obstacle_0.h",
            "\"G\"",
            "`a`",
            "0",
            "1.5",
            "-",
            "+",
            "*",
            "(",
            ")",
            "[",
            "]",
            ",",
            ":",
            "<",
            ">=",
            "==",
            "!=",
            "!",
            "&&",
            "|",
            "->",
            "<->",
            "not",
            "and",
            "or",
            "always",
            "F",
            "until",
            "S",
            "once",
            "abs",
            "true",
            "ms",
            " ",
            "1e3",
            "next",
            "#",
        ];
        let mut rng = SplitMix64(13);
        let mut parsed = 0;
        for _ in 0..20_000 {
            let len = 1 + rng.below(14);
            let text: String = (0..len)
                .map(|_| PIECES[rng.below(PIECES.len())])
                .collect::<Vec<_>>()
                .join(" ");
            if let Ok(f) = parse(&text) {
                parsed += 1;
                assert_eq!(parse(&f.to_string()).as_ref(), Ok(&f), "{text}");
                if !f.signals().is_empty() && f.check_step(1.0).is_ok() {
                    let n = 1 + rng.below(6);
                    let t = trace(&mut rng, n, true);
                    let values: Vec<&[f64]> = f.signals().iter().map(|_| t[0].as_slice()).collect();
                    let offline = robustness(&f, &values, 1.0).unwrap();
                    if f.online() {
                        assert!(same(online_value(&f, &values, 1.0), offline), "{text}");
                    }
                }
            }
        }
        assert!(parsed > 20, "{parsed} parsed");
    }
}
