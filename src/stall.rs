//! The `stall_time` definition (docs/metrics.md): a planar vehicle held still by its filter —
//! slower than [`STALL_SPEED`] for [`STALL_DURATION`] at the control ticks while the filter
//! overrides the nominal input. One observer of the records, fed them in log order: by the
//! episode as it logs them (its `stall` event) and by the `stall_time` metric after the run.
//! It reads the records as a sink does and only reports; nothing it sees feeds back into
//! control.

use std::collections::BTreeMap;

use crate::log::{proto, read};
use crate::signals::Observed;

/// Speed below which a planar vehicle counts as stopped (m/s), and how long it must stay so
/// while its filter overrides the nominal input to count as stalled (s): `stall_time`.
pub const STALL_SPEED: f64 = 0.05;
pub const STALL_DURATION: f64 = 1.0;

/// What the definition needs of the run metadata: the control period (its ticks; without it
/// there is no stall to find) and the planar position the vehicle declared.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StallFacts {
    /// Control period (metadata `control_period`).
    pub control_period: Option<f64>,
    /// The planar position the vehicle declared (None: not declared; Some(None): none).
    pub declared_planar: Option<Option<[usize; 2]>>,
}

impl StallFacts {
    /// The facts of the run metadata record.
    pub fn from_metadata(metadata: &BTreeMap<String, String>) -> StallFacts {
        StallFacts {
            control_period: metadata.get("control_period").and_then(|s| s.parse().ok()),
            declared_planar: read::declared_planar_position(metadata),
        }
    }
}

/// The planar position (time, x, y) of a `/state` message at a control tick, for what samples
/// the vehicle's motion there (the commanded input is piecewise constant on that grid, so
/// motion is resolved at the control period, not the physics step). `planar` caches the
/// position indices (None until the first state; Some(None): not a planar vehicle).
pub fn planar_at_tick(
    planar: &mut Option<Option<[usize; 2]>>,
    m: &proto::State,
    control_period: Option<f64>,
    declared_planar: Option<Option<[usize; 2]>>,
) -> Option<(f64, f64, f64)> {
    if let Some(period) = control_period {
        let ticks = m.time / period;
        if (ticks - ticks.round()).abs() > 1e-6 {
            return None;
        }
    }
    planar_of(planar, m, declared_planar)
}

/// The planar position (time, x, y) of any `/state` message (`planar` as for
/// [`planar_at_tick`]).
pub fn planar_of(
    planar: &mut Option<Option<[usize; 2]>>,
    m: &proto::State,
    declared_planar: Option<Option<[usize; 2]>>,
) -> Option<(f64, f64, f64)> {
    let [i, j] = (*planar.get_or_insert_with(|| read::planar_position_of(declared_planar, &m.names)))?;
    Some((m.time, *m.values.get(i)?, *m.values.get(j)?))
}

/// The `stall_time` definition, fed the `/state` and `/filter` records in log order.
#[derive(Default)]
pub struct StallDetector {
    /// The position indices ([`planar_at_tick`]).
    planar: Option<Option<[usize; 2]>>,
    /// The position at the last control tick (time, x, y).
    last: Option<(f64, f64, f64)>,
    /// Whether the last /filter record overrode the nominal.
    overriding: bool,
    /// Start of the current interval stopped while overridden.
    since: Option<f64>,
    first: Option<f64>,
}

impl StallDetector {
    /// Reads one record; returns the start of the first stall at the record that completes it
    /// (a `/state` message STALL_DURATION after the start), None otherwise.
    pub fn observe(&mut self, record: Observed<'_>, run: &StallFacts) -> Option<f64> {
        let m = match record {
            Observed::Filter(f) => {
                self.overriding = f.active;
                return None;
            }
            Observed::State(m) => m,
            _ => return None,
        };
        // Without the control period the metric is absent (its declared metadata).
        run.control_period?;
        let here = planar_at_tick(&mut self.planar, m, run.control_period, run.declared_planar)?;
        let (t, x, y) = self.last.replace(here)?;
        let dt = here.0 - t;
        if dt <= 0.0 {
            return None;
        }
        let speed = (here.1 - x).hypot(here.2 - y) / dt;
        if speed < STALL_SPEED && self.overriding {
            let since = *self.since.get_or_insert(t);
            if self.first.is_none() && here.0 - since >= STALL_DURATION - 1e-9 {
                self.first = Some(since);
                return self.first;
            }
        } else {
            self.since = None;
        }
        None
    }

    /// The start of the first stall so far.
    pub fn first(&self) -> Option<f64> {
        self.first
    }
}
