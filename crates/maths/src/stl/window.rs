//! Fixed-capacity buffers of the online monitor: a FIFO of values, and a sliding window that
//! aggregates its elements with an associative operation (the two-stack queue: amortised O(1)
//! per element, no allocation after [`Window::allocate`]).

use super::{max, min};

/// A FIFO of values with a fixed capacity (0 until [`Ring::allocate`]).
#[derive(Debug, Clone, Default)]
pub(super) struct Ring {
    values: Vec<f64>,
    head: usize,
    len: usize,
}

impl Ring {
    pub(super) fn allocate(&mut self, capacity: usize) {
        self.values = vec![0.0; capacity];
        self.clear();
    }

    pub(super) fn capacity(&self) -> usize {
        self.values.len()
    }

    pub(super) fn len(&self) -> usize {
        self.len
    }

    pub(super) fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Appends `v`; false (and nothing stored) when full.
    #[must_use]
    pub(super) fn push(&mut self, v: f64) -> bool {
        let cap = self.values.len();
        if self.len == cap {
            return false;
        }
        self.values[(self.head + self.len) % cap] = v;
        self.len += 1;
        true
    }

    pub(super) fn pop(&mut self) -> Option<f64> {
        if self.len == 0 {
            return None;
        }
        let v = self.values[self.head];
        self.head = (self.head + 1) % self.values.len();
        self.len -= 1;
        Some(v)
    }
}

/// An associative operation over the elements of a window, in their order.
pub(super) trait Monoid {
    type Elem: Copy + Default + std::fmt::Debug;
    type Agg: Copy + Default + std::fmt::Debug;
    fn lift(e: Self::Elem) -> Self::Agg;
    /// The aggregate of `a`'s elements followed by `b`'s.
    fn combine(a: Self::Agg, b: Self::Agg) -> Self::Agg;
}

/// Maximum (a minimum is the negated maximum of the negated values).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Max;

impl Monoid for Max {
    type Elem = f64;
    type Agg = f64;
    fn lift(e: f64) -> f64 {
        e
    }
    fn combine(a: f64, b: f64) -> f64 {
        max(a, b)
    }
}

/// A segment of `until` pairs (φ(j), ψ(j)), j = p … q: `phi` = min φ over it, `value` = max
/// over j of min(ψ(j), min φ[p, j)) — the `until` from p within the segment.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Segment {
    pub phi: f64,
    pub value: f64,
}

/// The `until` segments: [p, m] then [m+1, q] give max(value₁, min(φ₁, value₂)).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct UntilOp;

impl Monoid for UntilOp {
    type Elem = (f64, f64);
    type Agg = Segment;
    fn lift((phi, psi): (f64, f64)) -> Segment {
        Segment { phi, value: psi }
    }
    fn combine(a: Segment, b: Segment) -> Segment {
        Segment {
            phi: min(a.phi, b.phi),
            value: max(a.value, min(a.phi, b.value)),
        }
    }
}

/// The `since` segments: `value` = max over j of min(ψ(j), min φ(j, q]); [p, m] then
/// [m+1, q] give max(value₂, min(value₁, φ₂)).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SinceOp;

impl Monoid for SinceOp {
    type Elem = (f64, f64);
    type Agg = Segment;
    fn lift((phi, psi): (f64, f64)) -> Segment {
        Segment { phi, value: psi }
    }
    fn combine(a: Segment, b: Segment) -> Segment {
        Segment {
            phi: min(a.phi, b.phi),
            value: max(b.value, min(a.value, b.phi)),
        }
    }
}

/// The minimum of φ over pairs (φ, ψ).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct PhiMin;

impl Monoid for PhiMin {
    type Elem = (f64, f64);
    type Agg = f64;
    fn lift((phi, _): (f64, f64)) -> f64 {
        phi
    }
    fn combine(a: f64, b: f64) -> f64 {
        min(a, b)
    }
}

/// A sliding window of consecutive samples, oldest first, aggregated by `M`: the front part's
/// suffix aggregates and the back part's aggregate (Hirzel et al.'s two-stack queue).
#[derive(Debug, Clone, Default)]
pub(super) struct Window<M: Monoid> {
    elems: Vec<M::Elem>,
    /// For the front part (logical 0 … front−1): aggregate of elements k … front−1.
    suffix: Vec<M::Agg>,
    head: usize,
    len: usize,
    front: usize,
    /// Aggregate of the back part (logical front … len−1), when not empty.
    back: M::Agg,
    /// Sample index of the oldest element.
    first: usize,
}

impl<M: Monoid> Window<M> {
    pub(super) fn allocate(&mut self, capacity: usize) {
        self.elems = vec![M::Elem::default(); capacity];
        self.suffix = vec![M::Agg::default(); capacity];
        self.clear();
    }

    pub(super) fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.front = 0;
        self.first = 0;
    }

    pub(super) fn len(&self) -> usize {
        self.len
    }

    /// Sample index of the oldest element (when not empty).
    pub(super) fn first(&self) -> usize {
        self.first
    }

    fn slot(&self, k: usize) -> usize {
        (self.head + k) % self.elems.len()
    }

    /// Appends the element of sample `index` (the one after the newest; the first pushed into
    /// an empty window sets the count). False (nothing stored) when full.
    #[must_use]
    pub(super) fn push(&mut self, index: usize, e: M::Elem) -> bool {
        if self.len == self.elems.len() {
            return false;
        }
        if self.len == 0 {
            self.first = index;
        }
        let s = self.slot(self.len);
        self.elems[s] = e;
        self.back = if self.len == self.front {
            M::lift(e)
        } else {
            M::combine(self.back, M::lift(e))
        };
        self.len += 1;
        true
    }

    /// Removes and returns the oldest element.
    pub(super) fn pop(&mut self) -> Option<M::Elem> {
        if self.len == 0 {
            return None;
        }
        if self.front == 0 {
            // Flip: the back part becomes the front part, with its suffix aggregates.
            let mut acc = M::lift(self.elems[self.slot(self.len - 1)]);
            let last = self.slot(self.len - 1);
            self.suffix[last] = acc;
            for k in (0..self.len - 1).rev() {
                let s = self.slot(k);
                acc = M::combine(M::lift(self.elems[s]), acc);
                self.suffix[s] = acc;
            }
            self.front = self.len;
        }
        let e = self.elems[self.head];
        self.head = (self.head + 1) % self.elems.len();
        self.len -= 1;
        self.front -= 1;
        self.first += 1;
        Some(e)
    }

    /// The aggregate of every element, oldest first (`None` when empty).
    pub(super) fn query(&self) -> Option<M::Agg> {
        match (self.front > 0, self.len > self.front) {
            (true, true) => Some(M::combine(self.suffix[self.head], self.back)),
            (true, false) => Some(self.suffix[self.head]),
            (false, true) => Some(self.back),
            (false, false) => None,
        }
    }
}
