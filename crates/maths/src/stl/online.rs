//! Online evaluation: a [`Monitor`] takes one sample of every signal at a time and gives
//! ρ(φ, 0) at the end of the run — the value [`super::robustness`] gives on the whole trace.
//!
//! The formula becomes a list of operators in post-order. Each one turns the stream of its
//! operands' robustness values into its own, one value per sample: output i in round i + H,
//! H its horizon (a bounded future operator lags by its bound over its operand's horizon; past
//! operators do not lag); a binary operator's faster operand waits in a FIFO of the difference
//! of the horizons for the slower one. At the end of the run ([`Monitor::finish`]) the rounds
//! go on without samples: the lagging operators give the rest of their values with the windows
//! cut at the last sample. Unbounded future operators (only with
//! nothing but Boolean connectives above them, [`Formula::online`]) keep one running value
//! over the whole run, and the connectives above them are evaluated at the end. Every buffer
//! is sized in [`Monitor::new`]: nothing is allocated afterwards.

use super::window::{Max, Monoid, PhiMin, Ring, Segment, SinceOp, UntilOp, Window};
use super::{max, min, offline_reason, Comparison, Connective, Formula, Node, StlError, Term, MAX_MONITOR_VALUES};

/// No operand.
const NONE: usize = usize::MAX;

#[derive(Debug, Clone)]
enum Op {
    Constant(f64),
    Compare(Comparison, Term, Term),
    Not,
    Binary(Connective),
    /// `always`/`eventually` [a, b]: the window [i+a, i+b] (values negated for a minimum).
    Future {
        min: bool,
        a: usize,
        b: usize,
        window: Window<Max>,
    },
    /// `historically`/`once` [a, b]: the last a values wait in `delay`, the window is
    /// [i−b, i−a] (values negated for a minimum).
    Past {
        min: bool,
        a: usize,
        b: usize,
        delay: Ring,
        window: Window<Max>,
    },
    /// `historically`/`once` without an interval.
    PastRunning {
        min: bool,
        acc: f64,
    },
    /// `until[a, b]`: the pairs of [i+a, i+b] in `window`, −φ over [i, i+a) in `prefix`.
    Until {
        a: usize,
        b: usize,
        window: Window<UntilOp>,
        prefix: Window<Max>,
    },
    /// `since[a, b]`: the pairs of (i−a, i] in `recent`, those of [i−b, i−a] in `window`.
    Since {
        a: usize,
        b: usize,
        recent: Window<PhiMin>,
        window: Window<SinceOp>,
    },
    /// `since` without an interval.
    SinceRunning {
        acc: f64,
    },
    /// `always`/`eventually` without an interval, at the top: a running value over the run.
    Whole {
        min: bool,
        acc: f64,
    },
    /// `until` without an interval, at the top: the running `until` segment of the run.
    WholeUntil {
        acc: Segment,
    },
    /// `not` (`None`) or a connective above a whole-run operator: evaluated at the end.
    Late(Option<Connective>),
}

impl Op {
    /// Operands it consumes a value of each at a time (0: none, or read at the end).
    fn arity(&self) -> usize {
        match self {
            Op::Constant(_) | Op::Compare(..) | Op::Late(_) => 0,
            Op::Not | Op::Future { .. } | Op::Past { .. } | Op::PastRunning { .. } | Op::Whole { .. } => 1,
            Op::Binary(_) | Op::Until { .. } | Op::Since { .. } | Op::SinceRunning { .. } | Op::WholeUntil { .. } => 2,
        }
    }

    /// The values its buffers hold.
    fn buffer_sizes(&self) -> [usize; 2] {
        match self {
            Op::Future { a, b, .. } => [b.saturating_sub(*a) + 2, 0],
            Op::Past { a, b, .. } => [a + 1, b.saturating_sub(*a) + 2],
            Op::Until { a, b, .. } => [b.saturating_sub(*a) + 2, a + 2],
            Op::Since { a, b, .. } => [a + 2, b.saturating_sub(*a) + 2],
            _ => [0, 0],
        }
    }
}

#[derive(Debug, Clone)]
struct Slot {
    op: Op,
    children: [usize; 2],
    /// Samples ahead of an output its inputs reach (`None`: evaluated at the end).
    horizon: Option<usize>,
    /// Outputs waiting for the parent (capacity 0: the parent reads only the first).
    queue: Ring,
    /// Inputs consumed.
    received: usize,
    /// Outputs produced.
    emitted: usize,
    /// The first output, ρ(·, 0) (NaN until known).
    value0: f64,
}

/// An online monitor of one formula: [`Monitor::push`] one sample of every signal at a time,
/// then [`Monitor::finish`]. Memory is fixed at [`Monitor::new`] (sized by the bounds over the
/// step): `push` does not allocate.
#[derive(Debug, Clone)]
pub struct Monitor {
    slots: Vec<Slot>,
    signals: usize,
    /// Samples pushed.
    time: usize,
    /// Rounds run (one per sample, then those of the end of the run).
    clock: usize,
    /// The largest horizon of an operator: the rounds after the last sample that complete
    /// every output.
    longest: usize,
    /// The run's length, once finished.
    end: Option<usize>,
    result: Option<f64>,
    /// A buffer overflowed (a bug): the result is NaN.
    broken: bool,
}

impl Monitor {
    /// A monitor of `f` over signals sampled every `step` seconds. Refused when the bounds are
    /// not whole numbers of steps, when [`Formula::online`] is false, when the formula reads no
    /// signal, or when its buffers would hold more than [`MAX_MONITOR_VALUES`] values.
    pub fn new(f: &Formula, step: f64) -> Result<Monitor, StlError> {
        f.check_step(step)?;
        if let Some(message) = offline_reason(&f.root, true) {
            return Err(StlError::Offline {
                formula: f.to_string(),
                message: message.into(),
            });
        }
        if f.signals.is_empty() {
            return Err(StlError::Signals("the formula reads no signal".into()));
        }
        let mut slots = Vec::new();
        build(f, &f.root, step, true, &mut slots)?;
        // The queues: a parent consumes a value of each operand together, so the faster one's
        // wait at most (slowest operand's horizon − its horizon) samples; one more for the order
        // of the operators within a sample, one of slack.
        let mut queues = vec![0usize; slots.len()];
        for s in &slots {
            if s.op.arity() == 0 {
                continue;
            }
            let kids = &s.children[..s.op.arity()];
            let align = kids.iter().filter_map(|&c| slots[c].horizon).max().unwrap_or(0);
            for &c in kids {
                queues[c] = align - slots[c].horizon.unwrap_or(align) + 2;
            }
        }
        let total = slots
            .iter()
            .zip(&queues)
            .map(|(s, q)| s.op.buffer_sizes().iter().sum::<usize>().saturating_add(*q))
            .fold(0usize, usize::saturating_add);
        if total > MAX_MONITOR_VALUES {
            return Err(StlError::Offline {
                formula: f.to_string(),
                message: format!(
                    "its windows need {total} values at a step of {step} s, more than the {MAX_MONITOR_VALUES} allowed"
                ),
            });
        }
        for (s, q) in slots.iter_mut().zip(queues) {
            s.queue.allocate(q);
            let [x, y] = s.op.buffer_sizes();
            match &mut s.op {
                Op::Future { window, .. } => window.allocate(x),
                Op::Past { delay, window, .. } => {
                    delay.allocate(x);
                    window.allocate(y);
                }
                Op::Until { window, prefix, .. } => {
                    window.allocate(x);
                    prefix.allocate(y);
                }
                Op::Since { recent, window, .. } => {
                    recent.allocate(x);
                    window.allocate(y);
                }
                _ => {}
            }
        }
        let longest = slots.iter().filter_map(|s| s.horizon).max().unwrap_or(0);
        let mut m = Monitor {
            slots,
            signals: f.signals.len(),
            time: 0,
            clock: 0,
            longest,
            end: None,
            result: None,
            broken: false,
        };
        m.reset();
        Ok(m)
    }

    /// Forgets every sample: the monitor starts a new run (its buffers kept).
    pub fn reset(&mut self) {
        self.time = 0;
        self.clock = 0;
        self.end = None;
        self.result = None;
        self.broken = false;
        for s in &mut self.slots {
            s.queue.clear();
            s.received = 0;
            s.emitted = 0;
            s.value0 = f64::NAN;
            match &mut s.op {
                Op::Future { window, .. } => window.clear(),
                Op::Past { delay, window, .. } => {
                    delay.clear();
                    window.clear();
                }
                Op::Until { window, prefix, .. } => {
                    window.clear();
                    prefix.clear();
                }
                Op::Since { recent, window, .. } => {
                    recent.clear();
                    window.clear();
                }
                Op::PastRunning { acc, .. } | Op::SinceRunning { acc } | Op::Whole { acc, .. } => *acc = f64::NAN,
                Op::WholeUntil { acc } => *acc = Segment::default(),
                _ => {}
            }
        }
    }

    /// The signals it reads, in the order of [`Formula::signals`].
    pub fn signal_count(&self) -> usize {
        self.signals
    }

    /// The next sample: `sample[k]` is the value of signal k (a missing value reads NaN, extra
    /// ones are ignored). Ignored after [`Monitor::finish`] until [`Monitor::reset`].
    pub fn push(&mut self, sample: &[f64]) {
        if self.end.is_some() {
            return;
        }
        self.time += 1;
        self.round(Some(sample));
    }

    /// ρ(φ, 0), once no sample to come can change it: from the sample that completes the
    /// formula's horizon on (never before [`Monitor::finish`] when an unbounded future
    /// operator is in it).
    pub fn value(&self) -> Option<f64> {
        if let Some(r) = self.result {
            return Some(r);
        }
        let root = self.slots.last()?;
        (root.horizon.is_some() && root.emitted > 0 && !self.broken).then_some(root.value0)
    }

    /// Ends the run: ρ(φ, 0) over the samples pushed (windows cut at the last one), NaN when
    /// none was pushed. Calling it again returns the same value.
    pub fn finish(&mut self) -> f64 {
        if let Some(r) = self.result {
            return r;
        }
        let n = self.time;
        self.end = Some(n);
        if n == 0 {
            self.result = Some(f64::NAN);
            return f64::NAN;
        }
        // Every output is due by round n − 1 + its operator's horizon.
        while !self.drained(n) {
            if self.clock > n.saturating_add(self.longest) {
                self.broken = true;
                break;
            }
            self.round(None);
        }
        for k in 0..self.slots.len() {
            let [c0, c1] = self.slots[k].children;
            let v = |c: usize| self.slots.get(c).map_or(f64::NAN, |s| s.value0);
            let (x, y) = (v(c0), v(c1));
            let s = &mut self.slots[k];
            let complete = s.received == n;
            match &s.op {
                Op::Whole { acc, .. } if complete => s.value0 = *acc,
                Op::WholeUntil { acc } if complete => s.value0 = acc.value,
                Op::Late(None) => s.value0 = -x,
                Op::Late(Some(c)) => s.value0 = c.robustness(x, y),
                _ => {}
            }
        }
        let r = match self.slots.last() {
            Some(root) if !self.broken => root.value0,
            _ => f64::NAN,
        };
        self.result = Some(r);
        r
    }

    /// Whether every operator has all the outputs the result needs (after the run's end).
    fn drained(&self, n: usize) -> bool {
        if let Some(root) = self.slots.last() {
            if root.horizon.is_some() && root.emitted > 0 {
                return true;
            }
        }
        self.slots.iter().all(|s| match s.op {
            Op::Whole { .. } | Op::WholeUntil { .. } => s.received == n,
            Op::Late(_) => true,
            _ => s.emitted == n,
        })
    }

    /// Every operator in post-order takes what its operands have and produces what is due.
    fn round(&mut self, sample: Option<&[f64]>) {
        let now = self.clock;
        for k in 0..self.slots.len() {
            self.step(k, sample, now);
        }
        self.clock += 1;
    }

    /// One operator's turn in round `now`. Output i of an operator of horizon H is due in round
    /// i + H: its inputs are there by then (by induction, each operand's output j comes in
    /// round j + its horizon), and the operators that could produce it earlier at the end of
    /// the run (cut windows) wait for it, so that a FIFO never holds more than the difference
    /// of its operands' horizons.
    fn step(&mut self, k: usize, sample: Option<&[f64]>, now: usize) {
        let [c0, c1] = self.slots[k].children;
        let ready = |m: &Monitor, c: usize| m.slots.get(c).is_some_and(|s| s.queue.len() > 0);
        let input = match self.slots[k].op.arity() {
            1 if ready(self, c0) => self.slots[c0].queue.pop().map(|v| (v, f64::NAN)),
            2 if ready(self, c0) && ready(self, c1) => {
                let l = self.slots[c0].queue.pop().unwrap_or(f64::NAN);
                let r = self.slots[c1].queue.pop().unwrap_or(f64::NAN);
                Some((l, r))
            }
            _ => None,
        };
        let end = self.end;
        let s = &mut self.slots[k];
        let mut ok = true;
        let first = s.received == 0;
        if input.is_some() {
            s.received += 1;
        }
        let j = s.received.wrapping_sub(1);
        let i = s.emitted;
        // The operand has given all its values (the run has ended).
        let done = end == Some(s.received);
        let due = s.horizon.is_some_and(|h| i.saturating_add(h) <= now);
        let out = match &mut s.op {
            Op::Constant(v) => sample.map(|_| *v),
            Op::Compare(c, l, r) => sample.map(|x| {
                let at = |k: usize| x.get(k).copied().unwrap_or(f64::NAN);
                c.robustness(l.value(&at), r.value(&at))
            }),
            Op::Not => input.map(|(v, _)| -v),
            Op::Binary(c) => input.map(|(l, r)| c.robustness(l, r)),
            Op::Future { min, a, b, window } => {
                let turn = Turn {
                    i,
                    j,
                    received: s.received,
                    due,
                    done,
                };
                future_turn((*min, *a, *b), window, input, &turn, &mut ok)
            }
            Op::Past {
                min,
                a,
                b,
                delay,
                window,
            } => {
                let sign = if *min { -1.0 } else { 1.0 };
                input.map(|(v, _)| {
                    ok &= delay.push(sign * v);
                    if delay.len() > *a {
                        let x = delay.pop().unwrap_or(f64::NAN);
                        ok &= window.push(j - *a, x);
                    }
                    while window.len() > 0 && window.first() + *b < j {
                        window.pop();
                    }
                    match window.query() {
                        Some(m) if j >= *a => sign * m,
                        _ => -sign * f64::INFINITY,
                    }
                })
            }
            Op::PastRunning { min: is_min, acc } => input.map(|(v, _)| {
                *acc = match (first, *is_min) {
                    (true, _) => v,
                    (false, true) => min(*acc, v),
                    (false, false) => max(*acc, v),
                };
                *acc
            }),
            Op::Until { a, b, window, prefix } => {
                let turn = Turn {
                    i,
                    j,
                    received: s.received,
                    due,
                    done,
                };
                until_turn((*a, *b), (window, prefix), input, &turn, &mut ok)
            }
            Op::Since { a, b, recent, window } => input.map(|pair| {
                ok &= recent.push(j, pair);
                if recent.len() > *a {
                    if let Some(e) = recent.pop() {
                        ok &= window.push(j - *a, e);
                    }
                }
                while window.len() > 0 && window.first() + *b < j {
                    window.pop();
                }
                match window.query() {
                    Some(v) if j >= *a && *a == 0 => v.value,
                    Some(v) if j >= *a => min(recent.query().unwrap_or(f64::INFINITY), v.value),
                    _ => f64::NEG_INFINITY,
                }
            }),
            Op::SinceRunning { acc } => input.map(|(phi, psi)| {
                *acc = if first { psi } else { max(psi, min(phi, *acc)) };
                *acc
            }),
            Op::Whole { min: is_min, acc } => {
                if let Some((v, _)) = input {
                    *acc = match (first, *is_min) {
                        (true, _) => v,
                        (false, true) => min(*acc, v),
                        (false, false) => max(*acc, v),
                    };
                }
                None
            }
            Op::WholeUntil { acc } => {
                if let Some(pair) = input {
                    let g = UntilOp::lift(pair);
                    *acc = if first { g } else { UntilOp::combine(*acc, g) };
                }
                None
            }
            Op::Late(_) => None,
        };
        if let Some(v) = out {
            if s.emitted == 0 {
                s.value0 = v;
            }
            s.emitted += 1;
            if s.queue.capacity() > 0 {
                ok &= s.queue.push(v);
            }
        }
        self.broken |= !ok;
    }
}

/// Where an operator stands in its turn ([`Monitor::step`]): output i is next, its operand's
/// value j the latest, `received` of them so far; the output is `due` by its horizon; the
/// operand is `done` (the run has ended).
struct Turn {
    i: usize,
    j: usize,
    received: usize,
    due: bool,
    done: bool,
}

impl Turn {
    /// Whether output i can be given now: its window [i + a, i + b] is complete, or cut by the
    /// end of the run.
    fn window_complete(&self, b: usize) -> bool {
        self.due && (self.received > self.i + b || (self.done && self.i < self.received))
    }
}

/// F_[a,b] (max) or G_[a,b] (min: `sign` −1) over the operand's values in the window of output i.
fn future_turn(
    (is_min, a, b): (bool, usize, usize),
    window: &mut Window<Max>,
    input: Option<(f64, f64)>,
    t: &Turn,
    ok: &mut bool,
) -> Option<f64> {
    let sign = if is_min { -1.0 } else { 1.0 };
    if let Some((v, _)) = input {
        // Values before the next output's window reach no window.
        while window.len() > 0 && window.first() < t.i + a {
            window.pop();
        }
        if t.j >= t.i + a {
            *ok &= window.push(t.j, sign * v);
        }
    }
    if !t.window_complete(b) {
        return None;
    }
    while window.len() > 0 && window.first() < t.i + a {
        window.pop();
    }
    Some(window.query().map_or(-sign * f64::INFINITY, |m| sign * m))
}

/// φ U_[a,b] ψ at output i: the pairs (φ, ψ) in its window, and the running prefix of φ before it.
fn until_turn(
    (a, b): (usize, usize),
    (window, prefix): (&mut Window<UntilOp>, &mut Window<Max>),
    input: Option<(f64, f64)>,
    t: &Turn,
    ok: &mut bool,
) -> Option<f64> {
    let maintain = |window: &mut Window<UntilOp>, prefix: &mut Window<Max>| -> bool {
        let mut ok = true;
        while window.len() > 0 && window.first() < t.i + a {
            let index = window.first();
            if let Some((phi, _)) = window.pop() {
                ok &= prefix.push(index, -phi);
            }
        }
        while prefix.len() > 0 && prefix.first() < t.i {
            prefix.pop();
        }
        ok
    };
    if let Some(pair) = input {
        *ok &= window.push(t.j, pair);
        *ok &= maintain(window, prefix);
    }
    if !t.window_complete(b) {
        return None;
    }
    *ok &= maintain(window, prefix);
    Some(match window.query() {
        None => f64::NEG_INFINITY,
        Some(v) if a == 0 => v.value,
        Some(v) => min(-prefix.query().unwrap_or(f64::NEG_INFINITY), v.value),
    })
}

/// Appends the slots of `node` (post-order); its index. `top`: only connectives above it.
fn build(f: &Formula, node: &Node, step: f64, top: bool, slots: &mut Vec<Slot>) -> Result<usize, StlError> {
    let mut children = [NONE; 2];
    let mut child = |k: usize, n: &Node, top: bool, slots: &mut Vec<Slot>| -> Result<Option<usize>, StlError> {
        let c = build(f, n, step, top, slots)?;
        children[k] = c;
        Ok(slots[c].horizon)
    };
    let (op, horizon) = match node {
        Node::Constant(b) => (
            Op::Constant(if *b { f64::INFINITY } else { f64::NEG_INFINITY }),
            Some(0),
        ),
        Node::Compare(c, l, r) => (Op::Compare(*c, l.clone(), r.clone()), Some(0)),
        Node::Not(c) => match child(0, c, top, slots)? {
            Some(h) => (Op::Not, Some(h)),
            None => (Op::Late(None), None),
        },
        Node::Binary(c, l, r) => match (child(0, l, top, slots)?, child(1, r, top, slots)?) {
            (Some(x), Some(y)) => (Op::Binary(*c), Some(x.max(y))),
            _ => (Op::Late(Some(*c)), None),
        },
        Node::Temporal(p, i, c) => {
            let steps = f.steps(node, i, step)?;
            let h = child(0, c, false, slots)?.unwrap_or(0);
            let is_min = p.is_min();
            match (p.future(), steps) {
                (true, None) => (
                    Op::Whole {
                        min: is_min,
                        acc: f64::NAN,
                    },
                    None,
                ),
                (true, Some(s)) => {
                    let b = s.b.unwrap_or(0);
                    let op = Op::Future {
                        min: is_min,
                        a: s.a,
                        b,
                        window: Window::default(),
                    };
                    (op, Some(h.saturating_add(b)))
                }
                (false, None) => (
                    Op::PastRunning {
                        min: is_min,
                        acc: f64::NAN,
                    },
                    Some(h),
                ),
                (false, Some(s)) => {
                    let op = Op::Past {
                        min: is_min,
                        a: s.a,
                        b: s.b.unwrap_or(0),
                        delay: Ring::default(),
                        window: Window::default(),
                    };
                    (op, Some(h))
                }
            }
        }
        Node::Until(i, l, r) => {
            let steps = f.steps(node, i, step)?;
            let h = child(0, l, false, slots)?.max(child(1, r, false, slots)?).unwrap_or(0);
            match steps {
                None => (
                    Op::WholeUntil {
                        acc: Segment::default(),
                    },
                    None,
                ),
                Some(s) => {
                    let b = s.b.unwrap_or(0);
                    let op = Op::Until {
                        a: s.a,
                        b,
                        window: Window::default(),
                        prefix: Window::default(),
                    };
                    (op, Some(h.saturating_add(b)))
                }
            }
        }
        Node::Since(i, l, r) => {
            let steps = f.steps(node, i, step)?;
            let h = child(0, l, false, slots)?.max(child(1, r, false, slots)?).unwrap_or(0);
            match steps {
                None => (Op::SinceRunning { acc: f64::NAN }, Some(h)),
                Some(s) => {
                    let op = Op::Since {
                        a: s.a,
                        b: s.b.unwrap_or(0),
                        recent: Window::default(),
                        window: Window::default(),
                    };
                    (op, Some(h))
                }
            }
        }
    };
    slots.push(Slot {
        op,
        children,
        horizon,
        queue: Ring::default(),
        received: 0,
        emitted: 0,
        value0: f64::NAN,
    });
    Ok(slots.len() - 1)
}
