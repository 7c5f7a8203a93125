//! State predictors: the state at the time a command issued now reaches the plant.
//!
//! - One delay profile shared by all channels: p(t) = x(φ⁻¹(t)) ((2.19)/(2.20)), computed by
//!   integrating the analytic model forward over [t, φ⁻¹(t)] from x(t) with the inputs already
//!   issued (u(φ(s)) for s in that window was issued in [φ(t), t]).
//! - Distinct constant delays D_1 ≤ … ≤ D_r: the recursive predictors (4.23)/(4.24),
//!   p_i(t) = x(t + D_i), integrated from p_{i−1}(t) over [t + D_{i−1}, t + D_i]; channels
//!   j with D_j < D_i arrive with commands not yet issued, predicted by channel j's own
//!   control law κ_j at the predicted state; the others use their issued history.
//!
//! Integration is classical RK4 on the plant's step grid, with the input sampled at the stage
//! times exactly as the plant samples it, so on the ODE plant a prediction equals the realised
//! state up to integration round-off; where the inputs are held over each step and the model
//! has a closed-form flow (the bicycle (4.78), the unicycle (2.36)), the step is exact. Consecutive ticks share most of their window: a tick
//! continues the previous tick's trajectory when the fresh measurement agrees with it
//! (`control.chain_tolerance`, [`PredictorWorkspace::set_chain_reuse`]).

use nalgebra::DVector;

use crate::delay::{DelayError, DelayProfile, DelayQueue};
use crate::dynamics::{Dynamics, LinearModel};

/// Tolerance, as a fraction of the step, for grid comparisons.
const GRID_TOLERANCE: f64 = 1e-6;

/// p_i(t) for one channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    pub channel: usize,
    /// When the prediction was made (t).
    pub issued_at: f64,
    /// The time it predicts (φ_i⁻¹(t)).
    pub target_time: f64,
    pub state: DVector<f64>,
    /// Whether this tick continued the previous tick's trajectory instead of integrating its
    /// whole window (see [`PredictorWorkspace::set_chain_reuse`]).
    pub reused_chain: bool,
    /// How far p_1(t) is from the previous trajectory at the same time (x(t) for the shared
    /// predictor): the largest of the planar position's distance and every other component's
    /// difference; how far the measurement moved off it; NaN without a previous one.
    pub chain_mismatch: f64,
}

/// How far `fresh` is from `node`: the largest of the planar position's distance (`planar`, its
/// two components; a distance turns with the world's frame, where the largest coordinate
/// difference would not) and every other component's difference.
fn mismatch(node: &[f64], fresh: &[f64], planar: Option<[usize; 2]>) -> f64 {
    let position = planar.map_or(0.0, |[i, j]| (node[i] - fresh[i]).hypot(node[j] - fresh[j]));
    let others = (0..fresh.len()).filter(|k| planar.is_none_or(|p| !p.contains(k)));
    others.fold(position, |m, k| m.max((node[k] - fresh[k]).abs()))
}

/// How the predictor treats the channels (fixed by the scenario's delays).
#[derive(Debug, Clone, PartialEq)]
pub enum Structure {
    /// No delays: p = x.
    None,
    /// All channels share one delay profile: one prediction p(t) = x(φ⁻¹(t)).
    Shared,
    /// Distinct constant delays: channel indices sorted by delay, and the delays.
    Recursive { order: Vec<usize>, delays: Vec<f64> },
}

/// Picks the predictor structure for these queues, or explains why none applies.
pub fn structure(queues: &[DelayQueue], control_period: f64) -> Result<Structure, String> {
    let first = queues[0].profile();
    if queues.iter().all(|q| q.profile() == first) {
        return Ok(if first.constant_delay() == Some(0.0) {
            Structure::None
        } else {
            Structure::Shared
        });
    }
    let delays: Option<Vec<f64>> = queues.iter().map(|q| q.constant_delay()).collect();
    let Some(delays) = delays else {
        return Err("channels with different time-varying delay profiles: predictors need one shared profile or constant delays".into());
    };
    for (q, d) in queues.iter().zip(&delays) {
        let ticks = d / control_period;
        if (ticks - ticks.round()).abs() > 1e-6 {
            return Err(format!(
                "delay of channel `{}` ({d} s) is not a whole multiple of the control period {control_period} s, which the recursive predictor (4.23) needs",
                q.channel()
            ));
        }
    }
    let mut order: Vec<usize> = (0..queues.len()).collect();
    order.sort_by(|&a, &b| delays[a].total_cmp(&delays[b]));
    Ok(Structure::Recursive { order, delays })
}

/// Everything a prediction reads.
pub struct PredictorContext<'a> {
    pub model: &'a dyn Dynamics,
    pub queues: &'a [DelayQueue],
    /// Plant step h (the integration grid).
    pub timestep: f64,
    pub control_period: f64,
}

/// One integration step [start, end) of the predictor; `first_stage` marks its first RK4 stage.
#[derive(Debug, Clone, Copy)]
struct Step {
    start: f64,
    end: f64,
    first_stage: bool,
}

/// u ← the input of every channel at one RK4 stage: (state at the step's start, the step,
/// stage time, u).
type StageInput<'a> = dyn FnMut(&[f64], Step, f64, &mut [f64]) -> Result<(), DelayError> + 'a;

/// κ(s, z, free, u): the control law used for commands not yet issued (recursive predictor
/// only). z is the predicted x(s); `free` the channels whose command reaching the plant at s is
/// not yet issued (in increasing delay, ties in channel order); `u[j]` ← κ_j for j in `free`.
/// On entry `u` holds every other channel's command applied at s (issued before the tick),
/// and for those in `free` the value the recursion held for them since their last command.
pub type ControlLaw<'a> = dyn FnMut(f64, &[f64], &[usize], &mut [f64]) + 'a;

/// RK4 buffers: the integrated state, the stage state, the four slopes and the stage input.
#[derive(Debug, Clone)]
struct Rk4Buffers {
    state: Vec<f64>,
    stage: Vec<f64>,
    slopes: [Vec<f64>; 4],
    input: Vec<f64>,
}

/// The last history sample of one channel: its value holds while φ(s) ∈ [from, until), so the
/// RK4 stages that follow skip the queue search (a prediction samples at increasing times).
#[derive(Debug, Clone, Copy)]
struct HistoryCursor {
    from: f64,
    until: f64,
    value: f64,
    /// Position of that command in the queue (where the next search starts).
    index: usize,
}

impl HistoryCursor {
    const EMPTY: HistoryCursor = HistoryCursor {
        from: f64::INFINITY,
        until: f64::NEG_INFINITY,
        value: 0.0,
        index: 0,
    };
}

/// The last tick's prediction trajectory on the predictor's step grid: the recursive chain
/// (4.23) on [t + D_1, t + D_r], or the shared predictor's (2.19) on [t, φ⁻¹(t)]; each node with
/// the input held on the step that reached it, in a ring so the next tick drops one control
/// period at the front and appends at the back.
#[derive(Debug, Clone)]
struct Chain {
    /// Tick time of the chain; NaN when there is none.
    tick: f64,
    states: usize,
    channels: usize,
    len: usize,
    /// Slot of node 0.
    head: usize,
    /// Slots of (state, input of the step into the node).
    slots: Vec<f64>,
    /// Nodes the slots hold (`slots.len() / stride`).
    capacity: usize,
    /// The chain's states are `frame` applied to the stored ones (see [`Chain::transport_to`]).
    frame: PlanarMotion,
    /// Whether `frame` is not the identity (stored states are then not the chain's).
    moved: bool,
    /// A transformed node.
    scratch: Vec<f64>,
}

/// A rigid motion of the plane acting on a state's position (p ↦ R(φ) p + b) and heading
/// (θ ↦ θ + φ), the symmetry of models that do not depend on where they are or face
/// ([`Dynamics::planar_motion_invariant`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct PlanarMotion {
    cos: f64,
    sin: f64,
    angle: f64,
    shift: [f64; 2],
}

impl PlanarMotion {
    const IDENTITY: PlanarMotion = PlanarMotion {
        cos: 1.0,
        sin: 0.0,
        angle: 0.0,
        shift: [0.0, 0.0],
    };

    fn apply(&self, [px, py, heading]: [usize; 3], x: &mut [f64]) {
        let (a, b) = (x[px], x[py]);
        x[px] = self.cos * a - self.sin * b + self.shift[0];
        x[py] = self.sin * a + self.cos * b + self.shift[1];
        x[heading] += self.angle;
    }

    fn apply_inverse(&self, [px, py, heading]: [usize; 3], x: &mut [f64]) {
        let (a, b) = (x[px] - self.shift[0], x[py] - self.shift[1]);
        x[px] = self.cos * a + self.sin * b;
        x[py] = -self.sin * a + self.cos * b;
        x[heading] -= self.angle;
    }

    /// The motion that takes state `from` to state `to` (position and heading).
    fn between([px, py, heading]: [usize; 3], from: &[f64], to: &[f64]) -> PlanarMotion {
        let angle = to[heading] - from[heading];
        let (sin, cos) = angle.sin_cos();
        PlanarMotion {
            cos,
            sin,
            angle,
            shift: [
                to[px] - (cos * from[px] - sin * from[py]),
                to[py] - (sin * from[px] + cos * from[py]),
            ],
        }
    }

    /// `next` after `self`.
    fn then(&self, next: &PlanarMotion) -> PlanarMotion {
        let (cos, sin) = (
            next.cos * self.cos - next.sin * self.sin,
            next.sin * self.cos + next.cos * self.sin,
        );
        // Renormalised, so thousands of compositions stay a rotation.
        let norm = cos.hypot(sin);
        PlanarMotion {
            cos: cos / norm,
            sin: sin / norm,
            angle: self.angle + next.angle,
            shift: [
                next.cos * self.shift[0] - next.sin * self.shift[1] + next.shift[0],
                next.sin * self.shift[0] + next.cos * self.shift[1] + next.shift[1],
            ],
        }
    }
}

impl Chain {
    fn new(states: usize, channels: usize) -> Chain {
        Chain {
            tick: f64::NAN,
            states,
            channels,
            len: 0,
            head: 0,
            slots: Vec::new(),
            capacity: 0,
            frame: PlanarMotion::IDENTITY,
            moved: false,
            scratch: vec![0.0; states],
        }
    }

    fn stride(&self) -> usize {
        self.states + self.channels
    }

    fn capacity(&self) -> usize {
        self.capacity
    }

    /// Empties the chain for tick t, sized for `nodes` (allocates only the first time).
    fn restart(&mut self, tick: f64, nodes: usize) {
        if self.capacity < nodes {
            self.slots.resize(nodes * self.stride(), 0.0);
            self.capacity = nodes;
        }
        self.tick = tick;
        self.len = 0;
        self.head = 0;
        self.frame = PlanarMotion::IDENTITY;
        self.moved = false;
    }

    fn offset(&self, node: usize) -> usize {
        debug_assert!(node < self.capacity && self.head < self.capacity);
        // node < capacity and head < capacity: one wrap at most.
        let slot = self.head + node;
        let slot = if slot >= self.capacity {
            slot - self.capacity
        } else {
            slot
        };
        slot * self.stride()
    }

    /// The stored state of `node` (the chain's state unless it was transported).
    fn state(&self, node: usize) -> &[f64] {
        let o = self.offset(node);
        &self.slots[o..o + self.states]
    }

    /// out ← the chain's state at `node`.
    fn state_into(&self, axes: Option<[usize; 3]>, node: usize, out: &mut [f64]) {
        out.copy_from_slice(self.state(node));
        if let (Some(axes), true) = (axes, self.moved) {
            self.frame.apply(axes, out);
        }
    }

    /// Moves the whole chain by the rigid motion that takes its node 0 to `fresh` (O(1): only
    /// the frame changes). For a model invariant under planar motions, whose inputs here are
    /// all issued history, this is the trajectory integrated from `fresh` (RK4 commutes with
    /// the affine action, so up to round-off).
    fn transport_to(&mut self, axes: [usize; 3], fresh: &[f64]) {
        let mut node0 = std::mem::take(&mut self.scratch);
        self.state_into(Some(axes), 0, &mut node0);
        self.frame = self.frame.then(&PlanarMotion::between(axes, &node0, fresh));
        self.moved = self.frame != PlanarMotion::IDENTITY;
        self.scratch = node0;
    }

    /// max |node 0 − `fresh`| over the components a planar motion leaves alone.
    fn mismatch_off_motion(&mut self, axes: [usize; 3], fresh: &[f64]) -> f64 {
        if fresh.len() == axes.len() {
            return 0.0;
        }
        let mut node0 = std::mem::take(&mut self.scratch);
        self.state_into(Some(axes), 0, &mut node0);
        let mismatch = (0..fresh.len())
            .filter(|i| !axes.contains(i))
            .fold(0.0_f64, |m, i| m.max((node0[i] - fresh[i]).abs()));
        self.scratch = node0;
        mismatch
    }

    fn input(&self, node: usize) -> &[f64] {
        let o = self.offset(node) + self.states;
        &self.slots[o..o + self.channels]
    }

    /// Appends a node; with `axes`, `state` is in the chain's frame and stored without it.
    fn push(&mut self, axes: Option<[usize; 3]>, state: &[f64], input: &[f64]) {
        assert!(self.len < self.capacity(), "chain ring sized for the window");
        let (o, states, stride) = (self.offset(self.len), self.states, self.stride());
        self.slots[o..o + states].copy_from_slice(state);
        if let (Some(axes), true) = (axes, self.moved) {
            self.frame.apply_inverse(axes, &mut self.slots[o..o + states]);
        }
        self.slots[o + states..o + stride].copy_from_slice(input);
        self.len += 1;
    }

    fn drop_front(&mut self, nodes: usize) {
        self.head = (self.head + nodes) % self.capacity;
        self.len -= nodes;
    }

    /// At tick t, if this chain is the previous tick's (t − T, `period_steps` nodes per T)
    /// and `usable`, drops that period from the front and returns the mismatch of the fresh
    /// prediction ([`mismatch`] of node 0 and `fresh`, `planar` the position's components);
    /// NaN otherwise.
    fn advance_to(
        &mut self,
        (axes, planar): (Option<[usize; 3]>, Option<[usize; 2]>),
        (t, period, period_steps): (f64, f64, usize),
        usable: bool,
        fresh: &[f64],
    ) -> f64 {
        let step = period / period_steps as f64;
        if !(usable && (self.tick + period - t).abs() < step * GRID_TOLERANCE && self.len > period_steps) {
            return f64::NAN;
        }
        self.drop_front(period_steps);
        let mut node0 = std::mem::take(&mut self.scratch);
        self.state_into(axes, 0, &mut node0);
        let mismatch = mismatch(&node0, fresh, planar);
        self.scratch = node0;
        mismatch
    }
}

/// Scratch space of the predictors, sized once for a model (a prediction then allocates
/// nothing: it runs inside the control callback).
#[derive(Debug, Clone)]
pub struct PredictorWorkspace {
    rk4: Rk4Buffers,
    cursors: Vec<HistoryCursor>,
    /// Per channel: the command κ_j holds inside a recursive predictor's window.
    held: Vec<Option<f64>>,
    law_input: Vec<f64>,
    chain: Chain,
    /// The recursive predictors' trajectory on [t, t + D_1] (issued history only), moved
    /// from tick to tick like the shared predictor's.
    lead: Chain,
    /// p_1 of the last recursive prediction made through the chain.
    first_prediction: Vec<f64>,
    /// (start time, state) of the last prediction's final partial step, NaN time when it
    /// took none (see [`PredictorWorkspace::partial_step`]).
    partial_start: f64,
    partial_state: Vec<f64>,
    /// Reuse the previous tick's recursive chain when p_1 lands within this distance of it.
    chain_tolerance: Option<f64>,
}

impl PredictorWorkspace {
    pub fn new(states: usize, channels: usize) -> PredictorWorkspace {
        PredictorWorkspace {
            rk4: Rk4Buffers {
                state: vec![0.0; states],
                stage: vec![0.0; states],
                slopes: std::array::from_fn(|_| vec![0.0; states]),
                input: vec![0.0; channels],
            },
            cursors: vec![HistoryCursor::EMPTY; channels],
            held: vec![None; channels],
            law_input: vec![0.0; channels],
            chain: Chain::new(states, channels),
            lead: Chain::new(states, channels),
            first_prediction: vec![0.0; states],
            partial_start: f64::NAN,
            partial_state: vec![0.0; states],
            chain_tolerance: None,
        }
    }

    /// Lets consecutive ticks reuse the previous prediction trajectory. Recursive predictors
    /// (4.23), chain on [t + D_1, t + D_r]: tick t + T computes p_1 afresh from x(t + T) (the
    /// feedback), and if
    /// it is within `tolerance` of the previous chain's state at t + T + D_1 (the planar
    /// position's distance and every other component's difference: a norm the world's frame
    /// does not change), and
    /// the commands issued at t equal the κ_j values that chain assumed for them, the overlap
    /// [t + T + D_1, t + D_r] is the previous chain and only [t + D_r, t + T + D_r] is
    /// integrated. Otherwise the whole window is. On a plant that follows the model exactly the
    /// reused chain is the recomputed one up to round-off; on MuJoCo the model mismatch moves
    /// p_1 off the chain, and the tolerance bounds how far before a full recomputation.
    /// The shared predictor (2.19) compares x(t + T) itself with its previous trajectory and
    /// then integrates from that trajectory's last full step to φ⁻¹(t + T).
    /// `None` always integrates the whole window. Applies when the predictor step divides the
    /// control period (and, for the recursive chain, the inputs are constant on every step).
    pub fn set_chain_reuse(&mut self, tolerance: Option<f64>) {
        self.chain_tolerance = tolerance;
        self.invalidate_chain();
        self.lead.tick = f64::NAN;
    }

    /// The tolerance of chain reuse ([`PredictorWorkspace::set_chain_reuse`]), None without.
    pub fn chain_tolerance(&self) -> Option<f64> {
        self.chain_tolerance
    }

    /// Where the last shared prediction's final partial step (from its last grid node to
    /// φ⁻¹(t), off the grid) started: (time, predicted state); `None` when it took none.
    pub fn partial_step(&self) -> Option<(f64, &[f64])> {
        (!self.partial_start.is_nan()).then_some((self.partial_start, self.partial_state.as_slice()))
    }

    /// Forgets the last chain (the control law changed, e.g. a barrier became known).
    pub fn invalidate_chain(&mut self) {
        self.chain.tick = f64::NAN;
    }

    /// One prediction per channel, ready for [`PredictorContext::predict_into`].
    pub fn predictions(&self) -> Vec<Prediction> {
        (0..self.held.len())
            .map(|channel| Prediction {
                channel,
                issued_at: 0.0,
                target_time: 0.0,
                state: DVector::zeros(self.rk4.state.len()),
                reused_chain: false,
                chain_mismatch: f64::NAN,
            })
            .collect()
    }
}

impl PredictorContext<'_> {
    /// The applied input of channel j at stage time `time` of the step [step_start, step_end),
    /// sampled like the plant: clamped into the half-open step, so the last stage takes the
    /// left limit (for a final partial step, the left limit at the target time).
    fn history_input(
        &self,
        j: usize,
        cursor: &mut HistoryCursor,
        step_start: f64,
        step_end: f64,
        time: f64,
    ) -> Result<f64, DelayError> {
        let margin = self.timestep * GRID_TOLERANCE;
        let sample = time.clamp(step_start, step_end - margin);
        let queue = &self.queues[j];
        let source_time = queue.profile().delay_time(sample);
        if cursor.from <= source_time && source_time < cursor.until {
            return Ok(cursor.value);
        }
        let (applied, from, until, index) = queue.applied_span_near(sample, source_time, cursor.index)?;
        *cursor = HistoryCursor {
            from,
            until,
            value: applied.value,
            index,
        };
        Ok(applied.value)
    }

    /// Predictions for every channel, made at tick time t from state x (allocating form of
    /// [`PredictorContext::predict_into`]).
    pub fn predict(
        &self,
        structure: &Structure,
        t: f64,
        x: &DVector<f64>,
        law: &mut ControlLaw<'_>,
    ) -> Result<Vec<Prediction>, DelayError> {
        let mut workspace = PredictorWorkspace::new(x.len(), self.queues.len());
        let mut out = workspace.predictions();
        self.predict_into(structure, t, x.as_slice(), law, &mut workspace, &mut out)?;
        Ok(out)
    }

    /// `out[i]` ← p_i(t), made at tick time t from state x; `out` holds one prediction per
    /// channel (from [`PredictorWorkspace::predictions`]). Allocates nothing once the
    /// workspace has served one tick.
    pub fn predict_into(
        &self,
        structure: &Structure,
        t: f64,
        x: &[f64],
        law: &mut ControlLaw<'_>,
        workspace: &mut PredictorWorkspace,
        out: &mut [Prediction],
    ) -> Result<(), DelayError> {
        workspace.cursors.fill(HistoryCursor::EMPTY);
        workspace.partial_start = f64::NAN;
        let constant_input = self.inputs_constant_per_step(structure);
        let set = |p: &mut Prediction, channel: usize, target_time: f64, state: &[f64]| {
            p.channel = channel;
            p.issued_at = t;
            p.target_time = target_time;
            p.state.copy_from_slice(state);
            p.reused_chain = false;
            p.chain_mismatch = f64::NAN;
        };
        match structure {
            Structure::None => {
                for (channel, p) in out.iter_mut().enumerate() {
                    set(p, channel, t, x);
                }
            }
            Structure::Shared => {
                let target = self.queues[0].profile().prediction_time(t);
                let (reused, mismatch) = match (workspace.chain_tolerance, self.period_steps()) {
                    (Some(tolerance), Some(period_steps)) => {
                        let PredictorWorkspace {
                            rk4, cursors, chain, ..
                        } = workspace;
                        let outcome = self.history_trajectory(
                            t,
                            target,
                            x,
                            (rk4, cursors, chain),
                            (period_steps, tolerance),
                            constant_input,
                        )?;
                        // The chain ends at the last grid node before the target.
                        let last_node = t + (chain.len - 1) as f64 * self.timestep;
                        if target - last_node > self.timestep * GRID_TOLERANCE {
                            workspace.partial_start = last_node;
                            chain.state_into(self.motion_axes(), chain.len - 1, &mut workspace.partial_state);
                        }
                        outcome
                    }
                    _ => {
                        let PredictorWorkspace { rk4, cursors, .. } = workspace;
                        rk4.state.copy_from_slice(x);
                        self.integrate(rk4, t, target, constant_input, None, &mut |_, step, stage_time, u| {
                            self.history_inputs(cursors, step, stage_time, u)
                        })?;
                        (false, f64::NAN)
                    }
                };
                for (channel, p) in out.iter_mut().enumerate() {
                    set(p, channel, target, &workspace.rk4.state);
                    p.reused_chain = reused;
                    p.chain_mismatch = mismatch;
                }
            }
            Structure::Recursive { order, delays } => {
                let chain_window = self.chain_window(order, delays, constant_input);
                match (workspace.chain_tolerance, chain_window) {
                    (Some(tolerance), Some((period_steps, nodes))) => {
                        let (reused, lead_moved, mismatch) = self.recursive_with_chain(
                            (order, delays),
                            t,
                            x,
                            law,
                            workspace,
                            (period_steps, nodes, tolerance),
                        )?;
                        let first = delays[order[0]];
                        for &i in order {
                            let node = ((delays[i] - first) / self.timestep).round() as usize;
                            let state = if node == 0 {
                                // p_1 from x(t) (node 0 of a reused chain is only within tolerance).
                                &workspace.first_prediction
                            } else {
                                workspace.chain.state(node)
                            };
                            set(&mut out[i], i, t + delays[i], state);
                            out[i].reused_chain = reused || (node == 0 && lead_moved);
                            out[i].chain_mismatch = mismatch;
                        }
                    }
                    _ => {
                        let PredictorWorkspace { rk4, .. } = workspace;
                        rk4.state.copy_from_slice(x);
                        let mut reached = 0.0;
                        workspace.held.fill(None);
                        for &i in order {
                            let d_i = delays[i];
                            if d_i > reached {
                                self.recursive_segment(order, delays, t, (reached, d_i), law, workspace, false)?;
                                reached = d_i;
                            }
                            set(&mut out[i], i, t + d_i, &workspace.rk4.state);
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// (position x, position y, heading) when the model is invariant under planar rigid
    /// motions, so a trajectory under the same inputs can be moved instead of re-integrated.
    fn motion_axes(&self) -> Option<[usize; 3]> {
        if !self.model.planar_motion_invariant() {
            return None;
        }
        let [px, py] = self.model.planar_position()?;
        Some([px, py, self.model.heading_index()?])
    }

    /// Predictor steps per control period, when the step divides the period (consecutive
    /// ticks then share the integration grid, so a prediction's trajectory can be reused).
    fn period_steps(&self) -> Option<usize> {
        let period_steps = self.control_period / self.timestep;
        let whole = period_steps >= 0.5 && (period_steps - period_steps.round()).abs() < GRID_TOLERANCE;
        whole.then(|| period_steps.round() as usize)
    }

    /// (predictor steps per control period, chain nodes on [t + D_1, t + D_r]) when the
    /// recursive chain can be reused between ticks: the step divides the control period (so
    /// it divides every delay) and the inputs are constant on each step.
    fn chain_window(&self, order: &[usize], delays: &[f64], constant_input: bool) -> Option<(usize, usize)> {
        let window = delays[order[order.len() - 1]] - delays[order[0]];
        let period_steps = self.period_steps()?;
        constant_input.then(|| (period_steps, (window / self.timestep).round() as usize + 1))
    }

    /// x(`target`) from x(t) under issued history only, through `chain`, which keeps the
    /// trajectory's states on the step grid from t: the shared prediction p(t) = x(φ⁻¹(t))
    /// (2.19), and the recursive predictors' p_1. Tick t + T reuses the previous trajectory on
    /// [t + T, t + K h] (its last full step before the previous target: every input there was
    /// issued before t, so it is the same history) when x(t + T) is within `tolerance` of it,
    /// or moved onto x(t + T) for a model invariant under planar motions, and integrates only
    /// from t + K h to the target. Leaves x(target) in `rk4.state`. Returns (reused, mismatch).
    fn history_trajectory(
        &self,
        t: f64,
        target: f64,
        x: &[f64],
        (rk4, cursors, chain): (&mut Rk4Buffers, &mut [HistoryCursor], &mut Chain),
        (period_steps, tolerance): (usize, f64),
        constant_input: bool,
    ) -> Result<(bool, f64), DelayError> {
        let step = self.timestep;
        // Nodes t + k h, k = 0..=K, with t + K h the last grid point not after the target
        // (the rule `integrate` uses: a remainder within the grid tolerance of h is a step).
        let full_steps = ((target - t) / step + GRID_TOLERANCE).floor().max(0.0) as usize;
        let last_full = t + full_steps as f64 * step;
        let axes = self.motion_axes();
        let mismatch = chain.advance_to(
            (axes, self.model.planar_position()),
            (t, self.control_period, period_steps),
            chain.capacity() > full_steps,
            x,
        );
        let mut reusable = mismatch <= tolerance;
        if let (Some(axes), false) = (axes, mismatch.is_nan()) {
            // Inputs here are all issued history: the previous trajectory moved onto x(t) is
            // this tick's whatever its position and heading, if the rest of the state (the
            // bicycle's speed) agrees; exactly when there is no rest (the unicycle).
            if chain.mismatch_off_motion(axes, x) <= tolerance {
                chain.transport_to(axes, x);
                reusable = true;
            }
        }
        let from = if reusable {
            chain.tick = t;
            let end = chain.len - 1;
            chain.state_into(axes, end, &mut rk4.state);
            t + end as f64 * step
        } else {
            // Room for the horizon growing to twice this one before the ring must grow.
            chain.restart(t, 2 * (full_steps + 1).max(period_steps + 1));
            rk4.state.copy_from_slice(x);
            chain.push(None, x, &rk4.input);
            t
        };
        let mut history =
            |_: &[f64], step: Step, stage_time: f64, u: &mut [f64]| self.history_inputs(cursors, step, stage_time, u);
        self.integrate(rk4, from, last_full, constant_input, Some(chain), &mut history)?;
        self.integrate(rk4, last_full, target, constant_input, None, &mut history)?;
        Ok((reusable, mismatch))
    }

    /// The recursive predictions through `workspace.chain`, reusing the previous tick's chain
    /// when it still holds (see [`PredictorWorkspace::set_chain_reuse`]). Leaves p_1 in
    /// `workspace.first_prediction`. Returns (chain reused, p_1 moved, mismatch).
    fn recursive_with_chain(
        &self,
        (order, delays): (&[usize], &[f64]),
        t: f64,
        x: &[f64],
        law: &mut ControlLaw<'_>,
        workspace: &mut PredictorWorkspace,
        (period_steps, nodes, tolerance): (usize, usize, f64),
    ) -> Result<(bool, bool, f64), DelayError> {
        let (first, last) = (delays[order[0]], delays[order[order.len() - 1]]);
        let step = self.timestep;
        // p_1 (4.23) from x(t): every channel's history over [t, t + D_1]. For a model
        // invariant under planar motions that trajectory is the previous tick's moved onto
        // x(t) when the rest of the state agrees within the tolerance (see
        // `history_trajectory`): one new step instead of D_1 / h.
        workspace.held.fill(None);
        let mut lead_moved = false;
        if self.motion_axes().is_some() {
            let PredictorWorkspace { rk4, cursors, lead, .. } = workspace;
            (lead_moved, _) =
                self.history_trajectory(t, t + first, x, (rk4, cursors, lead), (period_steps, tolerance), true)?;
        } else {
            workspace.rk4.state.copy_from_slice(x);
            self.recursive_segment(order, delays, t, (0.0, first), law, workspace, false)?;
        }
        workspace.first_prediction.copy_from_slice(&workspace.rk4.state);

        let chain = &mut workspace.chain;
        let usable = chain.len == nodes;
        let mismatch = chain.advance_to(
            (None, self.model.planar_position()),
            (t, self.control_period, period_steps),
            usable,
            &workspace.rk4.state,
        );
        let mut reusable = mismatch <= tolerance;
        if !mismatch.is_nan() {
            // Channels strictly between D_1 and D_r: the previous chain held κ_j on the steps
            // starting in [t − T + D_j, t + D_j); this tick's chain takes channel j's history
            // there (the command issued at t − T), so they must agree.
            for &j in order.iter().filter(|&&j| delays[j] > first && delays[j] < last) {
                let node_j = ((delays[j] - first) / step).round() as usize;
                for node in node_j + 1 - period_steps..=node_j {
                    let start = t + first + (node - 1) as f64 * step;
                    let mut cursor = HistoryCursor::EMPTY;
                    let history = self.history_input(j, &mut cursor, start, start + step, start)?;
                    reusable &= (chain.input(node)[j] - history).abs() <= tolerance;
                }
            }
        }
        workspace.held.fill(None);
        if reusable {
            // Continue from the chain's end at t − T + D_r over the last control period.
            let end = chain.len - 1;
            workspace.rk4.state.copy_from_slice(chain.state(end));
            chain.tick = t;
            self.recursive_segment(
                order,
                delays,
                t,
                (last - self.control_period, last),
                law,
                workspace,
                true,
            )?;
        } else {
            chain.restart(t, nodes);
            chain.push(None, &workspace.rk4.state, &workspace.rk4.input);
            let mut reached = first;
            for &i in order {
                if delays[i] > reached {
                    self.recursive_segment(order, delays, t, (reached, delays[i]), law, workspace, true)?;
                    reached = delays[i];
                }
            }
        }
        debug_assert_eq!(workspace.chain.len, nodes);
        Ok((reusable, lead_moved, mismatch))
    }

    /// Integrates `workspace.rk4.state` over [t + from, t + to] inside the segment that ends at
    /// t + to = t + D_i of the recursive chain: channels j with D_j < D_i take κ_j at the
    /// predicted state (ticking on the control grid shifted by D_j), the others their history.
    /// `record` appends every step to the chain.
    #[allow(clippy::too_many_arguments)]
    fn recursive_segment(
        &self,
        order: &[usize],
        delays: &[f64],
        t: f64,
        (from, to): (f64, f64),
        law: &mut ControlLaw<'_>,
        workspace: &mut PredictorWorkspace,
        record: bool,
    ) -> Result<(), DelayError> {
        let PredictorWorkspace {
            rk4,
            cursors,
            held,
            law_input,
            chain,
            ..
        } = workspace;
        let r = self.queues.len();
        let d_i = to;
        let mut input = |step_state: &[f64], step: Step, stage_time: f64, u: &mut [f64]| {
            // κ_j ticks when the command reaching the plant now was issued at a tick:
            // (s − D_j) on the control-period grid.
            if step.first_stage {
                let free = &order[..order.partition_point(|&j| delays[j] < d_i)];
                let period = self.control_period;
                let due = |j: usize, held: &[Option<f64>]| {
                    let ticks = (step.start - t - delays[j]) / period;
                    (ticks - ticks.round()).abs() < GRID_TOLERANCE || held[j].is_none()
                };
                if free.iter().any(|&j| due(j, held)) {
                    // ω for the law: what every channel applies at s — the issued history, or
                    // for a free channel the command the recursion holds for it (before its
                    // first in the window: the history, as the filter's queue reads it).
                    for (j, u_j) in law_input.iter_mut().enumerate().take(r) {
                        *u_j = match held[j] {
                            Some(v) if delays[j] < d_i => v,
                            _ => self.history_input(j, &mut cursors[j], step.start, step.end, step.start)?,
                        };
                    }
                    law(step.start, step_state, free, law_input);
                    for &j in free {
                        if due(j, held) {
                            held[j] = Some(law_input[j]);
                        }
                    }
                }
            }
            for (j, u_j) in u.iter_mut().enumerate().take(r) {
                *u_j = match held[j] {
                    Some(v) if delays[j] < d_i => v,
                    _ => self.history_input(j, &mut cursors[j], step.start, step.end, stage_time)?,
                };
            }
            Ok(())
        };
        let constant_input = self.inputs_constant_per_step(&Structure::Recursive {
            order: Vec::new(),
            delays: Vec::new(),
        });
        let record = if record { Some(chain) } else { None };
        self.integrate(rk4, t + from, t + to, constant_input, record, &mut input)
    }

    /// u ← every channel's issued history at one RK4 stage.
    fn history_inputs(
        &self,
        cursors: &mut [HistoryCursor],
        step: Step,
        stage_time: f64,
        u: &mut [f64],
    ) -> Result<(), DelayError> {
        for (j, (u_j, cursor)) in u.iter_mut().zip(cursors.iter_mut()).enumerate() {
            *u_j = self.history_input(j, cursor, step.start, step.end, stage_time)?;
        }
        Ok(())
    }

    /// `out` ← x(t_k + δ) from the measured `x_k`, given a prediction's final partial step
    /// [t_k, t_k + δ] from `from` to `to` under the same issued history and step grid: that
    /// step moved by the planar motion taking `from` onto `x_k` (exact up to round-off for a
    /// model invariant under planar motions, as RK4 commutes with it). False, `out`
    /// untouched, for other models.
    pub fn move_partial_step(&self, from: &[f64], to: &[f64], x_k: &[f64], out: &mut [f64]) -> bool {
        let Some(axes) = self.motion_axes() else {
            return false;
        };
        out.copy_from_slice(to);
        PlanarMotion::between(axes, from, x_k).apply(axes, out);
        true
    }

    /// x advanced from `from` to `to` with every channel's issued history (no new commands).
    pub fn advance_with_history(&self, x: &DVector<f64>, from: f64, to: f64) -> Result<DVector<f64>, DelayError> {
        let mut workspace = PredictorWorkspace::new(x.len(), self.queues.len());
        let mut out = x.clone();
        self.advance_with_history_into(x.as_slice(), (from, to), &mut workspace, out.as_mut_slice())?;
        Ok(out)
    }

    /// out ← x advanced from `from` to `to` with every channel's issued history, in
    /// `workspace` (allocation-free form of [`PredictorContext::advance_with_history`]).
    pub fn advance_with_history_into(
        &self,
        x: &[f64],
        (from, to): (f64, f64),
        workspace: &mut PredictorWorkspace,
        out: &mut [f64],
    ) -> Result<(), DelayError> {
        let PredictorWorkspace { rk4, cursors, .. } = workspace;
        cursors.fill(HistoryCursor::EMPTY);
        rk4.state.copy_from_slice(x);
        self.integrate(rk4, from, to, false, None, &mut |_, step, stage_time, u| {
            self.history_inputs(cursors, step, stage_time, u)
        })?;
        out.copy_from_slice(&rk4.state);
        Ok(())
    }

    /// Whether every input is constant on each integration step of a prediction made on the
    /// control grid: constant delays that are whole multiples of the control period, which is
    /// itself a whole multiple of the step (commands then switch only at step boundaries).
    fn inputs_constant_per_step(&self, structure: &Structure) -> bool {
        let whole = |ratio: f64| ratio >= 0.5 && (ratio - ratio.round()).abs() < GRID_TOLERANCE;
        whole(self.control_period / self.timestep)
            && match structure {
                Structure::None => false,
                // Checked by `structure`.
                Structure::Recursive { .. } => true,
                Structure::Shared => self.queues[0]
                    .constant_delay()
                    .is_some_and(|d| d == 0.0 || whole(d / self.control_period)),
            }
    }

    /// RK4 of `rk4.state` from `from` to `to` on the grid of step h (a final partial step if
    /// `to` is off the grid). `input(step_start_state, step, stage_time, u)` writes u; with
    /// `constant_input` it is asked once per step (at the first stage) and held, and a model
    /// with a closed-form flow ([`Dynamics::flow_into`]) takes the step exactly instead.
    fn integrate(
        &self,
        rk4: &mut Rk4Buffers,
        from: f64,
        to: f64,
        constant_input: bool,
        mut record: Option<&mut Chain>,
        input: &mut StageInput<'_>,
    ) -> Result<(), DelayError> {
        let h = self.timestep;
        let axes = self.motion_axes();
        let Rk4Buffers {
            state,
            stage,
            slopes,
            input: u,
        } = rk4;
        let [k1, k2, k3, k4] = slopes;
        let mut s = from;
        while s < to - h * GRID_TOLERANCE {
            let dt = (to - s).min(h);
            let dt = if (h - dt) < h * GRID_TOLERANCE { h } else { dt };
            let end = if dt < h { to } else { s + h };
            let step = |first_stage| Step {
                start: s,
                end,
                first_stage,
            };
            input(state, step(true), s, u)?;
            // Inputs held over the step: the model's exact flow when it has one.
            if constant_input && self.model.flow_into(state, u, dt) {
                if let Some(chain) = record.as_deref_mut() {
                    chain.push(axes, state, u);
                }
                s += dt;
                continue;
            }
            self.model.dynamics_into(state, u, k1);
            for (stage, (x, k)) in stage.iter_mut().zip(state.iter().zip(k1.iter())) {
                *stage = x + k * (dt / 2.0);
            }
            if !constant_input {
                input(state, step(false), s + dt / 2.0, u)?;
            }
            self.model.dynamics_into(stage, u, k2);
            for (stage, (x, k)) in stage.iter_mut().zip(state.iter().zip(k2.iter())) {
                *stage = x + k * (dt / 2.0);
            }
            // Stage 3 samples the input at the same time as stage 2: u holds it.
            self.model.dynamics_into(stage, u, k3);
            for (stage, (x, k)) in stage.iter_mut().zip(state.iter().zip(k3.iter())) {
                *stage = x + k * dt;
            }
            if !constant_input {
                input(state, step(false), s + dt, u)?;
            }
            self.model.dynamics_into(stage, u, k4);
            for (i, x) in state.iter_mut().enumerate() {
                *x += (k1[i] + k2[i] * 2.0 + k3[i] * 2.0 + k4[i]) * (dt / 6.0);
            }
            if let Some(chain) = record.as_deref_mut() {
                chain.push(axes, state, u);
            }
            s += dt;
        }
        Ok(())
    }
}

/// Explicit predictor (2.21) for ẋ = A x + B u with one delay profile:
/// p(t) = e^{A(φ⁻¹(t)−t)} x(t) + ∫_{φ(t)}^{t} e^{A(φ⁻¹(t)−φ⁻¹(σ))} B u(σ) / φ'(φ⁻¹(σ)) dσ.
/// The issued input is piecewise constant: `breakpoints` are its switch times, and the integral
/// is composite Simpson with `per_piece` (even) subintervals on each constant piece.
pub fn linear_explicit(
    model: &LinearModel,
    x: &DVector<f64>,
    t: f64,
    profile: &DelayProfile,
    input: &dyn Fn(f64) -> DVector<f64>,
    breakpoints: &[f64],
    per_piece: usize,
) -> DVector<f64> {
    let (a, b) = (&model.a, &model.b);
    let target = profile.prediction_time(t);
    let lo = profile.delay_time(t);
    let integrand = |sigma: f64, u: &DVector<f64>| {
        let arrival = profile.prediction_time(sigma);
        let dphi = profile.delay_time_derivative(arrival);
        (a * (target - arrival)).exp() * b * u / dphi
    };
    let mut edges: Vec<f64> = std::iter::once(lo)
        .chain(breakpoints.iter().copied().filter(|&s| s > lo && s < t))
        .chain(std::iter::once(t))
        .collect();
    edges.dedup();
    let n = per_piece + per_piece % 2;
    let mut p = (a * (target - t)).exp() * x;
    for piece in edges.windows(2) {
        let (start, end) = (piece[0], piece[1]);
        // The input is constant on [start, end): evaluate it inside the piece.
        let u = input(0.5 * (start + end));
        let w = (end - start) / n as f64;
        let mut sum = integrand(start, &u) + integrand(end, &u);
        for k in 1..n {
            sum += integrand(start + k as f64 * w, &u) * if k % 2 == 1 { 4.0 } else { 2.0 };
        }
        p += sum * (w / 3.0);
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The predictor context of a test whose control period is the step h.
    fn on_grid<'a>(model: &'a dyn Dynamics, queues: &'a [DelayQueue], h: f64) -> PredictorContext<'a> {
        PredictorContext {
            model,
            queues,
            timestep: h,
            control_period: h,
        }
    }
    use crate::delay::VaryingDelay;
    use nalgebra::DMatrix;

    /// Queue with commands u(s) = sin(s) + 0.3 issued every `period` on [0, t].
    fn queue_with_history(profile: DelayProfile, t: f64, period: f64) -> DelayQueue {
        let mut q = DelayQueue::with_profile("u1", profile, 0.2, period).unwrap();
        let mut k = 0;
        while k as f64 * period <= t + 1e-12 {
            let s = k as f64 * period;
            q.push(s, s.sin() + 0.3).unwrap();
            k += 1;
        }
        q
    }

    /// |numerical (2.19) − explicit (2.21)| for (2.30) with (2.31) at t = 4, plant step h.
    /// A workspace reusing trajectories at chain tolerance `tolerance` and one integrating
    /// every window, with their predictions: (reusing, full, reused predictions, full ones).
    fn twin(
        states: usize,
        channels: usize,
        tolerance: f64,
    ) -> (PredictorWorkspace, PredictorWorkspace, Vec<Prediction>, Vec<Prediction>) {
        let mut reusing = PredictorWorkspace::new(states, channels);
        reusing.set_chain_reuse(Some(tolerance));
        let full = PredictorWorkspace::new(states, channels);
        let (p_reused, p_full) = (reusing.predictions(), full.predictions());
        (reusing, full, p_reused, p_full)
    }

    /// The same tick predicted in each (workspace, predictions) pair.
    fn predict_both(
        context: &PredictorContext<'_>,
        structure: &Structure,
        t: f64,
        x: &DVector<f64>,
        law: &mut ControlLaw<'_>,
        pairs: [(&mut PredictorWorkspace, &mut Vec<Prediction>); 2],
    ) {
        for (workspace, predictions) in pairs {
            context
                .predict_into(structure, t, x.as_slice(), law, workspace, predictions)
                .unwrap();
        }
    }

    fn explicit_vs_numerical(h: f64) -> (f64, f64) {
        let profile = DelayProfile::Varying(VaryingDelay::CosinePrediction {
            a: 1.0,
            b: 0.5,
            omega: 1.0,
        });
        let t = 4.0;
        // Commands issued before t only (the tick at t has not pushed yet).
        let queue = queue_with_history(profile.clone(), t - h, h);
        let (a, b) = (DMatrix::from_element(1, 1, 1.0), DMatrix::from_element(1, 1, 1.0));
        let model = LinearModel::new(a, b);
        let x = DVector::from_element(1, 0.7);
        let queues = [queue];
        let context = on_grid(&model, &queues, h);
        let mut law = |_: f64, _: &[f64], _: &[usize], u: &mut [f64]| u.fill(0.0);
        let numerical = context.predict(&Structure::Shared, t, &x, &mut law).unwrap();
        assert!((numerical[0].target_time - profile.prediction_time(t)).abs() < 1e-12);
        let issued = |s: f64| {
            let tick = ((s / h) + 1e-9).floor() * h;
            DVector::from_element(1, if s < 0.0 { 0.2 } else { tick.sin() + 0.3 })
        };
        let breakpoints: Vec<f64> = (0..=(t / h).round() as usize).map(|k| k as f64 * h).collect();
        let explicit = linear_explicit(&model, &x, t, &profile, &issued, &breakpoints, 8);
        ((numerical[0].state[0] - explicit[0]).abs(), explicit[0])
    }

    #[test]
    fn numerical_predictor_converges_to_the_explicit_form_2_21() {
        // (2.30) with (2.31), whose explicit predictor is (2.35). The issued input switches
        // inside RK4 steps (φ(s) crosses issue ticks off the step grid), so the numerical
        // predictor, which integrates exactly as the plant does, is first order in h there:
        // check the size at small h and the convergence from coarse steps.
        let (coarse, _) = explicit_vs_numerical(0.004);
        let (fine, p) = explicit_vs_numerical(0.00025);
        println!("predictor (2.19) vs explicit (2.21) at t = 4 (p = {p:.9}): |difference| = {coarse:.2e} (h = 4 ms), {fine:.2e} (h = 0.25 ms)");
        assert!(fine < 1e-6 * p.abs(), "difference {fine}");
        assert!(fine < coarse / 20.0, "no convergence: {coarse} -> {fine}");
    }

    #[test]
    fn constant_delay_recursive_predictor_reaches_t_plus_d_i() {
        // Two channels of a double integrator with D1 = 0.1 < D2 = 0.3: p_2 integrates channel 1
        // with the law κ, channel 2 with its history.
        let h = 0.01;
        let model = LinearModel::new(
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.0, 1.0]),
        );
        let mut q1 = DelayQueue::new("u1", 0.1, 0.0, h).unwrap();
        let mut q2 = DelayQueue::new("u2", 0.3, 0.0, h).unwrap();
        for k in 0..100 {
            q1.push(k as f64 * h, 1.0).unwrap();
            q2.push(k as f64 * h, 2.0).unwrap();
        }
        let queues = [q1, q2];
        let s = structure(&queues, h).unwrap();
        assert_eq!(
            s,
            Structure::Recursive {
                order: vec![0, 1],
                delays: vec![0.1, 0.3]
            }
        );
        let context = on_grid(&model, &queues, h);
        // κ_1 = −1 (a known constant law): p_2 velocity = 0 + 2·0.3 (channel 2 history), position
        // = 0.1·1 (history) + 0.2·(−1) (law) + ∫ velocity.
        let mut law = |_: f64, _: &[f64], _: &[usize], u: &mut [f64]| u.copy_from_slice(&[-1.0, 99.0]);
        let t = 1.0;
        let p = context.predict(&s, t, &DVector::zeros(2), &mut law).unwrap();
        assert!((p[0].target_time - 1.1).abs() < 1e-12 && (p[1].target_time - 1.3).abs() < 1e-12);
        let v = 2.0 * 0.3;
        let position = 0.1 - 0.2 + 0.5 * 2.0 * 0.3 * 0.3;
        assert!((p[1].state[1] - v).abs() < 1e-12, "{}", p[1].state);
        assert!((p[1].state[0] - position).abs() < 1e-12, "{}", p[1].state);
        assert!(
            (p[0].state[0] - (0.1 + 0.5 * 2.0 * 0.1 * 0.1)).abs() < 1e-12,
            "{}",
            p[0].state
        );
    }

    #[test]
    fn a_transported_shared_chain_equals_the_recomputed_one() {
        // The unicycle (2.36) with the delay (2.37) on both channels, ticking every step; the
        // "measured" state drifts off the model each tick (as on MuJoCo) by far more than
        // any tolerance, so only moving the chain can reuse it.
        use crate::delay::VaryingDelay;
        use crate::dynamics::UnicycleModel;
        let h = 0.002;
        let model = UnicycleModel::default();
        let profile = DelayProfile::Varying(VaryingDelay::Rational);
        let mut queues: Vec<DelayQueue> = ["speed", "turn_rate"]
            .iter()
            .map(|name| DelayQueue::with_profile(name, profile.clone(), 0.0, h).unwrap())
            .collect();
        let structure = structure(&queues, h).unwrap();
        assert_eq!(structure, Structure::Shared);
        let (mut reusing, mut full, mut p_reused, mut p_full) = twin(3, 2, 0.0);
        let mut x = DVector::from_vec(vec![1.0, 1.0, 1.0]);
        let (mut reused, mut worst, mut worst_mismatch) = (0, 0.0_f64, 0.0_f64);
        let (mut partial_steps, mut worst_partial) = (0, 0.0_f64);
        let mut never = |_: f64, _: &[f64], _: &[usize], _: &mut [f64]| unreachable!("no control law in (2.19)");
        for k in 0..400 {
            let t = k as f64 * h;
            let context = on_grid(&model, &queues, h);
            predict_both(
                &context,
                &structure,
                t,
                &x,
                &mut never,
                [(&mut reusing, &mut p_reused), (&mut full, &mut p_full)],
            );
            assert!(!p_full[0].reused_chain);
            // The realised state at the target from any state at the partial step's start
            // (the consistency check's x(t_k)) is that step moved.
            if let Some((start, from)) = reusing.partial_step() {
                partial_steps += 1;
                let from = DVector::from_column_slice(from);
                let x_k = &from + DVector::from_vec(vec![2e-3, -1e-3, 3e-3]);
                let mut moved = DVector::zeros(3);
                let target = p_reused[0].target_time;
                assert!(context.move_partial_step(
                    from.as_slice(),
                    p_reused[0].state.as_slice(),
                    x_k.as_slice(),
                    moved.as_mut_slice()
                ));
                let advanced = context.advance_with_history(&x_k, start, target).unwrap();
                worst_partial = worst_partial.max((moved - advanced).amax());
            }
            if p_reused[0].reused_chain {
                reused += 1;
                worst = worst.max((&p_reused[0].state - &p_full[0].state).amax());
                worst_mismatch = worst_mismatch.max(p_reused[0].chain_mismatch);
            }
            for (j, queue) in queues.iter_mut().enumerate() {
                let u = if j == 0 {
                    1.0 + 0.5 * (3.0 * t).sin()
                } else {
                    (2.0 * t).cos()
                };
                queue.push(t, u).unwrap();
            }
            let context = on_grid(&model, &queues, h);
            x = context.advance_with_history(&x, t, t + h).unwrap();
            // Model mismatch: a slip of a millimetre and a milliradian per step.
            x[0] += 1e-3 * (0.7 * t).cos();
            x[1] -= 1e-3;
            x[2] += 1e-3 * (1.3 * t).sin();
        }
        assert_eq!(reused, 399, "every tick after the first moves the previous trajectory");
        assert!(
            worst_mismatch > 1e-3,
            "the measurement left the trajectory: {worst_mismatch}"
        );
        assert!(
            worst < 1e-11,
            "a moved chain differs from the recomputed one by {worst:e}"
        );
        assert!(partial_steps > 390, "{partial_steps}");
        assert!(
            worst_partial < 1e-13,
            "a moved partial step differs by {worst_partial:e}"
        );
    }

    /// The bicycle (4.78), D = (0.2, 0.5) s, ticking every 0.01 s, chain tolerance 1e-4; after
    /// every tick the measured state slips off the model by 1 mm and 1 mrad, and its speed by
    /// `speed_slip`. Returns (ticks whose p_1 moved the previous trajectory, largest
    /// |p_1 − recomputed p_1| among them, largest among the others).
    fn lead_run(speed_slip: f64) -> (usize, f64, f64) {
        use crate::dynamics::BicycleModel;
        let h = 0.01;
        let model = BicycleModel::new(6.0);
        let mut queues: Vec<DelayQueue> = [("steering", 0.2), ("acceleration", 0.5)]
            .iter()
            .map(|&(name, d)| DelayQueue::new(name, d, 0.0, h).unwrap())
            .collect();
        let structure = structure(&queues, h).unwrap();
        let kappa = |_: f64, z: &[f64], _: &[usize], u: &mut [f64]| {
            u[0] = -0.1 * z[1] - 0.3 * z[2];
            u[1] = 3.0 - z[3];
        };
        let (mut reusing, mut full, mut p_reused, mut p_full) = twin(4, 2, 1e-4);
        let mut x = DVector::from_vec(vec![-20.0, 1.0, 0.1, 2.0]);
        let (mut moved, mut worst_moved, mut worst_fresh) = (0, 0.0_f64, 0.0_f64);
        for k in 0..200 {
            let t = k as f64 * h;
            let context = on_grid(&model, &queues, h);
            let mut law = kappa;
            predict_both(
                &context,
                &structure,
                t,
                &x,
                &mut law,
                [(&mut reusing, &mut p_reused), (&mut full, &mut p_full)],
            );
            let difference = (&p_reused[0].state - &p_full[0].state).amax();
            if reusing.lead.tick == t && reusing.lead.frame != PlanarMotion::IDENTITY {
                moved += 1;
                worst_moved = worst_moved.max(difference);
                assert!(p_reused[0].reused_chain, "a moved p_1 is flagged for the audit");
            } else {
                worst_fresh = worst_fresh.max(difference);
            }
            let mut u = [0.0; 2];
            for (j, queue) in queues.iter_mut().enumerate() {
                kappa(t, p_full[j].state.as_slice(), &[], &mut u);
                queue.push(t, u[j] + 0.05 * (7.0 * t).sin()).unwrap();
            }
            let context = on_grid(&model, &queues, h);
            x = context.advance_with_history(&x, t, t + h).unwrap();
            x[0] += 1e-3;
            x[2] -= 1e-3 * (0.9 * t).cos();
            x[3] += speed_slip;
        }
        (moved, worst_moved, worst_fresh)
    }

    #[test]
    fn a_moved_recursive_lead_equals_the_recomputed_p_1() {
        // Position and heading off the model: p_1 (history only over [t, t + D_1]) is the
        // previous tick's trajectory moved, every tick, exactly.
        let (moved, worst, _) = lead_run(0.0);
        assert_eq!(
            moved, 199,
            "every tick after the first moves the previous p_1 trajectory"
        );
        assert!(
            worst < 1e-11,
            "a moved p_1 differs from the recomputed one by {worst:e}"
        );
        // The speed is not moved by a planar motion: off by more than the tolerance, p_1 is
        // integrated afresh (exact); within it, moved, off by about the slip times D_1.
        let (moved, _, fresh) = lead_run(1e-3);
        assert_eq!(moved, 0);
        assert!(fresh < 1e-12, "{fresh:e}");
        let (moved, worst, _) = lead_run(2e-6);
        assert!(moved > 20, "{moved}");
        assert!(worst > 1e-9 && worst < 1e-4, "{worst:e}");
    }

    #[test]
    fn a_shared_bicycle_prediction_is_moved_only_when_its_speed_agrees() {
        // Equal delays make the bicycle's predictor shared (2.19). A planar motion moves
        // position and heading, not speed: with the measured speed off the trajectory by more
        // than the tolerance, the prediction must be integrated afresh (it was moved before).
        use crate::dynamics::BicycleModel;
        let h = 0.01;
        let model = BicycleModel::new(6.0);
        for (speed_slip, expect_moved) in [(0.0, true), (1e-3, false)] {
            let mut queues: Vec<DelayQueue> = ["steering", "acceleration"]
                .iter()
                .map(|name| DelayQueue::new(name, 0.3, 0.0, h).unwrap())
                .collect();
            let structure = structure(&queues, h).unwrap();
            assert_eq!(structure, Structure::Shared);
            let (mut reusing, mut full, mut p_reused, mut p_full) = twin(4, 2, 1e-4);
            let mut x = DVector::from_vec(vec![-20.0, 1.0, 0.1, 2.0]);
            let (mut reused, mut worst) = (0, 0.0_f64);
            let mut never = |_: f64, _: &[f64], _: &[usize], _: &mut [f64]| unreachable!("no control law in (2.19)");
            for k in 0..100 {
                let t = k as f64 * h;
                let context = on_grid(&model, &queues, h);
                predict_both(
                    &context,
                    &structure,
                    t,
                    &x,
                    &mut never,
                    [(&mut reusing, &mut p_reused), (&mut full, &mut p_full)],
                );
                reused += usize::from(p_reused[0].reused_chain);
                worst = worst.max((&p_reused[0].state - &p_full[0].state).amax());
                for (j, queue) in queues.iter_mut().enumerate() {
                    queue.push(t, [0.02 * (3.0 * t).sin(), 0.5][j]).unwrap();
                }
                let context = on_grid(&model, &queues, h);
                x = context.advance_with_history(&x, t, t + h).unwrap();
                x[0] += 1e-3;
                x[3] += speed_slip;
            }
            assert_eq!(reused, if expect_moved { 99 } else { 0 }, "slip {speed_slip}");
            assert!(
                worst < 1e-11,
                "slip {speed_slip}: off the recomputed prediction by {worst:e}"
            );
        }
    }

    /// Closed loop of a double integrator with three channels (D = 0.1, 0.2, 0.3 s) whose
    /// commands are κ_j at their own predictions, except at tick `off_law_tick` where channel 2
    /// (the middle delay) issues κ_2 + 0.5, and at tick `kick_tick` where the state is
    /// perturbed. Returns, per tick from the second: (reused, max |reused − recomputed|).
    fn chain_reuse_run(tolerance: f64, off_law_tick: usize, kick_tick: usize) -> Vec<(bool, f64)> {
        let h = 0.01;
        let model = LinearModel::new(
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::from_row_slice(2, 3, &[0.3, 0.0, 0.0, 1.0, 1.0, 1.0]),
        );
        let kappa = |_: f64, z: &[f64], _: &[usize], u: &mut [f64]| {
            u[0] = -z[0] - z[1];
            u[1] = 0.5 * z[0].sin() - 0.2;
            u[2] = -0.2 * z[1] + 0.1;
        };
        let mut queues: Vec<DelayQueue> = [("u1", 0.1), ("u2", 0.2), ("u3", 0.3)]
            .iter()
            .map(|&(name, d)| DelayQueue::new(name, d, 0.05, h).unwrap())
            .collect();
        let structure = structure(&queues, h).unwrap();
        let (mut reusing, mut full, mut p_reused, mut p_full) = twin(2, 3, tolerance);
        let mut x = DVector::from_vec(vec![1.0, -0.5]);
        let mut out = Vec::new();
        for k in 0..60 {
            let t = k as f64 * h;
            if k == kick_tick {
                x[0] += 1e-3;
            }
            let context = on_grid(&model, &queues, h);
            let mut law = kappa;
            predict_both(
                &context,
                &structure,
                t,
                &x,
                &mut law,
                [(&mut reusing, &mut p_reused), (&mut full, &mut p_full)],
            );
            let difference = p_reused
                .iter()
                .zip(&p_full)
                .map(|(a, b)| (&a.state - &b.state).amax())
                .fold(0.0, f64::max);
            if k > 0 {
                out.push((p_reused[0].reused_chain, difference));
            }
            let mut u = [0.0; 3];
            for (j, queue) in queues.iter_mut().enumerate() {
                kappa(t, p_full[j].state.as_slice(), &[], &mut u);
                let off_law = if k == off_law_tick && j == 1 { 0.5 } else { 0.0 };
                queue.push(t, u[j] + off_law).unwrap();
            }
            let context = on_grid(&model, &queues, h);
            x = context.advance_with_history(&x, t, t + h).unwrap();
        }
        out
    }

    #[test]
    fn a_reused_chain_equals_the_recomputed_one_and_is_dropped_when_it_no_longer_holds() {
        // Exact model and commands from κ: every tick after the first reuses the chain, and the
        // reused predictions are the recomputed ones.
        let clean = chain_reuse_run(0.0, usize::MAX, usize::MAX);
        assert!(clean.iter().all(|&(reused, d)| reused && d < 1e-12), "{clean:?}");
        // Channel 2 issues something other than the κ_2 the chain assumed at tick 20: tick 21
        // must recompute (and stays exact); later ticks reuse again.
        let off_law = chain_reuse_run(0.0, 20, usize::MAX);
        assert!(!off_law[20].0, "tick 21 reused a chain built on the wrong command");
        assert!(off_law.iter().all(|&(_, d)| d < 1e-12), "{off_law:?}");
        assert!(off_law[25].0);
        // A state kick of 1e-3 puts p_1 off the chain: recomputed below the tolerance, reused
        // (with a bounded difference) above it.
        let strict = chain_reuse_run(1e-4, usize::MAX, 30);
        assert!(!strict[29].0 && strict.iter().all(|&(_, d)| d < 1e-12), "{strict:?}");
        let loose = chain_reuse_run(1e-2, usize::MAX, 30);
        let worst = loose.iter().map(|&(_, d)| d).fold(0.0, f64::max);
        assert!(loose[29].0 && worst > 1e-6 && worst < 1e-2, "{loose:?}");
    }
}
