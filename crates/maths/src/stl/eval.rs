//! Offline evaluation: the robustness signal ρ(φ, i), i = 0 … n−1, of a formula over whole
//! signals, bottom-up over the syntax tree, each operator in O(n) (the windows by van Herk /
//! Gil–Werman block minima, bounded `until`/`since` by a monotone queue of candidates).

use std::collections::VecDeque;

use super::{max, min, Formula, Node, Prefix, Steps, StlError};

/// The robustness signal of `f` over signals sampled every `step` seconds: `values[k]` holds
/// the samples of `f.signals()[k]`, all of one length n ≥ 1. Element i is ρ(φ, i).
pub fn robustness_signal(f: &Formula, values: &[&[f64]], step: f64) -> Result<Vec<f64>, StlError> {
    let n = check_values(f, values)?;
    f.check_step(step)?;
    eval(f, &f.root, values, n, step)
}

/// The value of the requirement: ρ(φ, 0) (see [`robustness_signal`]).
pub fn robustness(f: &Formula, values: &[&[f64]], step: f64) -> Result<f64, StlError> {
    let rho = robustness_signal(f, values, step)?;
    rho.first()
        .copied()
        .ok_or_else(|| StlError::Signals("no samples".into()))
}

/// When `f` is first certainly violated: the time of the earliest sample k such that every
/// continuation of samples 0…k gives ρ(φ, 0) < 0 — the upper end of ρ(φ, 0)'s range with the
/// later samples unknown is negative (for `always ψ`, the first time ψ fails; for
/// `eventually[0, 5] ψ` never met, 5 s). None when ρ(φ, 0) ≥ 0 (or NaN). With more samples
/// known the range only narrows, so the earliest k is found by bisection.
pub fn violation_time(f: &Formula, values: &[&[f64]], step: f64) -> Result<Option<f64>, StlError> {
    let n = check_values(f, values)?;
    f.check_step(step)?;
    let upper = |known: usize| -> Result<f64, StlError> { Ok(bounds(f, &f.root, values, (n, known), step)?.1[0]) };
    // (NaN: no value, so no violation.)
    let rho = eval(f, &f.root, values, n, step)?[0];
    if rho.is_nan() || rho >= 0.0 {
        return Ok(None);
    }
    // The least number of known samples m with upper(m) < 0: upper(hi) < 0 ≤ upper(lo).
    let (mut lo, mut hi) = (0, n);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if upper(mid)? < 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(Some((hi - 1) as f64 * step))
}

/// Per sample, the range [lower, upper] of ρ(node, i) over every continuation of the first
/// `known` samples (the later ones unknown: an atom there is anything).
fn bounds(
    f: &Formula,
    node: &Node,
    values: &[&[f64]],
    (n, known): (usize, usize),
    step: f64,
) -> Result<(Vec<f64>, Vec<f64>), StlError> {
    let sub = |c: &Node| bounds(f, c, values, (n, known), step);
    Ok(match node {
        Node::Compare(..) if known < n => {
            let (mut lower, mut upper) = match known {
                0 => (Vec::new(), Vec::new()),
                _ => {
                    let head: Vec<&[f64]> = values.iter().map(|v| &v[..known]).collect();
                    let x = eval(f, node, &head, known, step)?;
                    (x.clone(), x)
                }
            };
            lower.resize(n, f64::NEG_INFINITY);
            upper.resize(n, f64::INFINITY);
            (lower, upper)
        }
        Node::Constant(_) | Node::Compare(..) => {
            let x = eval(f, node, values, n, step)?;
            (x.clone(), x)
        }
        Node::Not(c) => {
            let (lower, upper) = sub(c)?;
            (upper.iter().map(|v| -v).collect(), lower.iter().map(|v| -v).collect())
        }
        Node::Binary(c, l, r) => {
            let ((ll, lu), (rl, ru)) = (sub(l)?, sub(r)?);
            (0..n).map(|i| c.bounds([ll[i], lu[i]], [rl[i], ru[i]])).unzip()
        }
        Node::Temporal(p, i, c) => {
            let steps = f.steps(node, i, step)?;
            let (lower, upper) = sub(c)?;
            (temporal(*p, steps, &lower), temporal(*p, steps, &upper))
        }
        Node::Until(i, l, r) | Node::Since(i, l, r) => {
            let steps = f.steps(node, i, step)?;
            let ((ll, lu), (rl, ru)) = (sub(l)?, sub(r)?);
            let op = |phi: &[f64], psi: &[f64]| match (node, steps) {
                (Node::Until(..), None) => until_unbounded(phi, psi),
                (Node::Until(..), Some(s)) => until_bounded(phi, psi, s.a, s.b.unwrap_or(usize::MAX)),
                (_, None) => since_unbounded(phi, psi),
                (_, Some(s)) => since_bounded(phi, psi, s.a, s.b.unwrap_or(usize::MAX)),
            };
            // Both are monotone in each operand: the ends of the ranges give the range's ends.
            (op(&ll, &rl), op(&lu, &ru))
        }
    })
}

/// The common length of the signals, checked against the formula.
fn check_values(f: &Formula, values: &[&[f64]]) -> Result<usize, StlError> {
    if f.signals.is_empty() {
        return Err(StlError::Signals(
            "the formula reads no signal, so its trace has no length".into(),
        ));
    }
    if values.len() != f.signals.len() {
        return Err(StlError::Signals(format!(
            "the formula reads {} signals ({}), given {}",
            f.signals.len(),
            f.signals.join(", "),
            values.len()
        )));
    }
    let n = values[0].len();
    if n == 0 {
        return Err(StlError::Signals("the signals have no samples".into()));
    }
    if let Some(k) = values.iter().position(|v| v.len() != n) {
        return Err(StlError::Signals(format!(
            "signal `{}` has {} samples, `{}` has {n}: every signal needs the same length",
            f.signals[k],
            values[k].len(),
            f.signals[0]
        )));
    }
    Ok(n)
}

fn eval(f: &Formula, node: &Node, values: &[&[f64]], n: usize, step: f64) -> Result<Vec<f64>, StlError> {
    let sub = |c: &Node| eval(f, c, values, n, step);
    Ok(match node {
        Node::Constant(b) => vec![if *b { f64::INFINITY } else { f64::NEG_INFINITY }; n],
        Node::Compare(c, l, r) => (0..n)
            .map(|i| {
                let at = |k: usize| values.get(k).and_then(|v| v.get(i)).copied().unwrap_or(f64::NAN);
                c.robustness(l.value(&at), r.value(&at))
            })
            .collect(),
        Node::Not(c) => sub(c)?.into_iter().map(|v| -v).collect(),
        Node::Binary(c, l, r) => {
            let (x, y) = (sub(l)?, sub(r)?);
            x.iter().zip(&y).map(|(&a, &b)| c.robustness(a, b)).collect()
        }
        Node::Temporal(p, i, c) => {
            let steps = f.steps(node, i, step)?;
            let x = sub(c)?;
            temporal(*p, steps, &x)
        }
        Node::Until(i, l, r) => {
            let steps = f.steps(node, i, step)?;
            let (phi, psi) = (sub(l)?, sub(r)?);
            match steps {
                None => until_unbounded(&phi, &psi),
                Some(s) => until_bounded(&phi, &psi, s.a, s.b.unwrap_or(usize::MAX)),
            }
        }
        Node::Since(i, l, r) => {
            let steps = f.steps(node, i, step)?;
            let (phi, psi) = (sub(l)?, sub(r)?);
            match steps {
                None => since_unbounded(&phi, &psi),
                Some(s) => since_bounded(&phi, &psi, s.a, s.b.unwrap_or(usize::MAX)),
            }
        }
    })
}

/// `always`, `eventually`, `historically`, `once` over the signal `x`.
fn temporal(p: Prefix, steps: Option<Steps>, x: &[f64]) -> Vec<f64> {
    let n = x.len();
    let (op, identity): (fn(f64, f64) -> f64, f64) = if p.is_min() {
        (min, f64::INFINITY)
    } else {
        (max, f64::NEG_INFINITY)
    };
    let mut out = x.to_vec();
    match (p.future(), steps) {
        (true, None) => {
            for i in (0..n.saturating_sub(1)).rev() {
                out[i] = op(x[i], out[i + 1]);
            }
        }
        (false, None) => {
            for i in 1..n {
                out[i] = op(out[i - 1], x[i]);
            }
        }
        (true, Some(Steps { a, b })) => {
            // ρ(i) = op over [i+a, min(i+b, n−1)]: the window of length b−a+1 from i+a.
            let b = b.unwrap_or(usize::MAX);
            let y = sliding(x, b.saturating_sub(a).saturating_add(1), op);
            for (i, o) in out.iter_mut().enumerate() {
                *o = y.get(i.saturating_add(a)).copied().unwrap_or(identity);
            }
        }
        (false, Some(Steps { a, b })) => {
            // ρ(i) = op over [max(i−b, 0), i−a].
            let b = b.unwrap_or(usize::MAX);
            let y = sliding(x, b.saturating_sub(a).saturating_add(1), op);
            let mut prefix = x.to_vec();
            for i in 1..n {
                prefix[i] = op(prefix[i - 1], x[i]);
            }
            for (i, o) in out.iter_mut().enumerate() {
                *o = match (i.checked_sub(a), i.checked_sub(b)) {
                    (None, _) => identity,
                    (Some(_), Some(lo)) => y[lo],
                    (Some(hi), None) => prefix[hi],
                };
            }
        }
    }
    out
}

/// y[s] = op over x[s ..= min(s+len−1, n−1)] (van Herk / Gil–Werman: running values from each
/// block's start and to each block's end, blocks of `len`).
fn sliding(x: &[f64], len: usize, op: fn(f64, f64) -> f64) -> Vec<f64> {
    let n = x.len();
    let len = len.clamp(1, n.max(1));
    let mut from_start = x.to_vec();
    let mut to_end = x.to_vec();
    for k in 1..n {
        if k % len != 0 {
            from_start[k] = op(from_start[k - 1], x[k]);
        }
    }
    for k in (0..n.saturating_sub(1)).rev() {
        if (k + 1) % len != 0 {
            to_end[k] = op(x[k], to_end[k + 1]);
        }
    }
    (0..n)
        .map(|s| {
            let e = s.saturating_add(len - 1).min(n - 1);
            if e / len == s / len {
                to_end[s]
            } else {
                op(to_end[s], from_start[e])
            }
        })
        .collect()
}

/// Counts of NaN before each index: `c[k]` = NaN among x[0..k].
fn nan_counts(x: &[f64]) -> Vec<usize> {
    let mut c = Vec::with_capacity(x.len() + 1);
    c.push(0);
    for v in x {
        c.push(c[c.len() - 1] + usize::from(v.is_nan()));
    }
    c
}

/// Whether x[lo..hi] (half-open; empty when lo ≥ hi) holds a NaN, from [`nan_counts`].
fn nan_in(c: &[usize], lo: usize, hi: usize) -> bool {
    lo < hi && c[hi] > c[lo]
}

fn sanitized(x: &[f64]) -> Vec<f64> {
    x.iter().map(|&v| if v.is_nan() { 0.0 } else { v }).collect()
}

/// Unbounded `until`: U(n−1) = ψ(n−1), U(i) = max(ψ(i), min(φ(i), U(i+1))).
fn until_unbounded(phi: &[f64], psi: &[f64]) -> Vec<f64> {
    let n = psi.len();
    let mut out = psi.to_vec();
    for i in (0..n.saturating_sub(1)).rev() {
        out[i] = max(psi[i], min(phi[i], out[i + 1]));
    }
    out
}

/// Unbounded `since`: S(0) = ψ(0), S(i) = max(ψ(i), min(φ(i), S(i−1))).
fn since_unbounded(phi: &[f64], psi: &[f64]) -> Vec<f64> {
    let mut out = psi.to_vec();
    for i in 1..psi.len() {
        out[i] = max(psi[i], min(phi[i], out[i - 1]));
    }
    out
}

/// Candidates (index, value) of a windowed `until`/`since`: values strictly decreasing from
/// the front (the first to leave the window) to the back.
struct Candidates(VecDeque<(usize, f64)>);

impl Candidates {
    /// Every candidate's value becomes min(value, x): those at or above x merge into the one
    /// that stays longest.
    fn clamp(&mut self, x: f64) {
        while self.0.len() >= 2 && self.0[1].1 >= x {
            self.0.pop_front();
        }
        if let Some(front) = self.0.front_mut() {
            if front.1 > x {
                front.1 = x;
            }
        }
    }

    /// A new candidate, staying longer than every other.
    fn push(&mut self, index: usize, value: f64) {
        while self.0.back().is_some_and(|c| c.1 <= value) {
            self.0.pop_back();
        }
        self.0.push_back((index, value));
    }

    fn expire(&mut self, gone: impl Fn(usize) -> bool) {
        while self.0.front().is_some_and(|c| gone(c.0)) {
            self.0.pop_front();
        }
    }

    fn best(&self) -> f64 {
        self.0.front().map_or(f64::NEG_INFINITY, |c| c.1)
    }
}

/// `φ until[a,b] ψ`: ρ(i) = min(min φ[i, i+a), V(i+a)) with V(s) = max over
/// j ∈ [s, min(s+b−a, n−1)] of min(ψ(j), min φ[s, j)), swept backwards; −∞ when i+a > n−1;
/// NaN when ψ over the window or φ over [i, last j) holds a NaN.
fn until_bounded(phi: &[f64], psi: &[f64], a: usize, b: usize) -> Vec<f64> {
    let n = psi.len();
    let w = b.saturating_sub(a);
    let (nan_phi, nan_psi) = (nan_counts(phi), nan_counts(psi));
    let (sphi, spsi) = (sanitized(phi), sanitized(psi));
    let mut v = vec![f64::NEG_INFINITY; n];
    let mut c = Candidates(VecDeque::with_capacity(n.min(w.saturating_add(2))));
    for s in (0..n).rev() {
        c.clamp(sphi[s]);
        c.push(s, spsi[s]);
        c.expire(|j| j - s > w);
        v[s] = c.best();
    }
    let prefix = (a > 0).then(|| sliding(phi, a, min));
    (0..n)
        .map(|i| {
            let first = i.saturating_add(a);
            if first >= n {
                return f64::NEG_INFINITY;
            }
            let last = i.saturating_add(b).min(n - 1);
            if nan_in(&nan_psi, first, last + 1) || nan_in(&nan_phi, i, last) {
                return f64::NAN;
            }
            match &prefix {
                Some(m) => min(m[i], v[first]),
                None => v[first],
            }
        })
        .collect()
}

/// `φ since[a,b] ψ`: ρ(i) = min(min φ(i−a, i], V(i−a)) with V(s) = max over
/// j ∈ [max(s−(b−a), 0), s] of min(ψ(j), min φ(j, s]), swept forwards; −∞ when i < a; NaN
/// when ψ over the window or φ over (first j, i] holds a NaN.
fn since_bounded(phi: &[f64], psi: &[f64], a: usize, b: usize) -> Vec<f64> {
    let n = psi.len();
    let w = b.saturating_sub(a);
    let (nan_phi, nan_psi) = (nan_counts(phi), nan_counts(psi));
    let (sphi, spsi) = (sanitized(phi), sanitized(psi));
    let mut v = vec![f64::NEG_INFINITY; n];
    let mut c = Candidates(VecDeque::with_capacity(n.min(w.saturating_add(2))));
    for s in 0..n {
        c.clamp(sphi[s]);
        c.push(s, spsi[s]);
        c.expire(|j| s - j > w);
        v[s] = c.best();
    }
    let recent = (a > 0).then(|| sliding(phi, a, min));
    (0..n)
        .map(|i| {
            let Some(last) = i.checked_sub(a) else {
                return f64::NEG_INFINITY;
            };
            let first = i.saturating_sub(b);
            if nan_in(&nan_psi, first, last + 1) || nan_in(&nan_phi, first + 1, i + 1) {
                return f64::NAN;
            }
            match &recent {
                // φ over (i−a, i]: the window of length a from i−a+1.
                Some(m) => min(m[last + 1], v[last]),
                None => v[last],
            }
        })
        .collect()
}
