//! Rerun sink: turns every [`Record`] into rerun data on two timelines, `sim_time` (duration)
//! and `step` (sequence), with rerun's wall-clock `log_time` and `log_tick` turned off, so the
//! recording depends on the records alone. A live run (`mjsafe run --rerun/--rrd`) and a
//! replay of its MCAP log (`mjsafe replay`) feed the same records and give the same data.
//!
//! Layout (entity paths):
//! - `world/<scene entity id>`: the Foxglove `/scene` entities drawn in 2D in the world frame:
//!   cylinders as circles, cubes as rectangles turning with their yaw (the vehicle footprint),
//!   lines as line strips (trail, reference path, road edges, a lane marking's dashes), each in
//!   its Foxglove colour (obstacles grey until known, red after).
//! - `world/prediction/<channel>`: the predicted position p_i(t) of each `/prediction`, at its
//!   issue time t.
//! - `world/collisions`: the vehicle position at every `collision_start` event.
//! - `plots/barrier/<name>`: h and the constraint a + b·u (`plots/barrier_symlog/<name>`: h on
//!   a symmetric-log scale, the margin near 0 readable); `plots/input/<channel>`: issued and
//!   applied input; `plots/command/<channel>`: nominal and filtered; `plots/filter`: active,
//!   infeasible; `plots/prediction/<channel>`: prediction error.
//! - `events`: every `/event` as a text log entry.
//!
//! A blueprint (2D view left, time series and events right) is sent when the stream opens.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use ::rerun::blueprint::components::{PanelState, PlayState};
use ::rerun::blueprint::{
    Blueprint, BlueprintPanel, Horizontal, SelectionPanel, Spatial2DView, TextLogView, TimePanel, TimeSeriesView,
    Vertical,
};
use ::rerun::{EntityPath, EntityPathPart, RecordingStream, RecordingStreamBuilder};
use foxglove::messages::{line_primitive, scene_entity_deletion, Color, Pose, SceneEntity, SceneUpdate};

use super::read::{
    declared_planar_position, planar_position_of, read_run_file, Message, ReadError, RunVisitor, RUN_METADATA,
    STATUS_METADATA,
};
use super::{proto, LogError, Record, Sink};
use crate::files::{OutputFile, Replace};

/// Application id of every mjsafe recording.
pub const APPLICATION_ID: &str = "mjsafe";

/// Where a recording goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RerunTarget {
    /// Spawn a viewer (a `rerun` binary on PATH) and stream to it.
    Spawn,
    /// Stream to a running viewer or server at this URL (`rerun+http://HOST:PORT/proxy`).
    Connect(String),
    /// Save an `.rrd` file.
    Save(PathBuf),
}

impl std::fmt::Display for RerunTarget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RerunTarget::Spawn => write!(f, "rerun viewer (spawned)"),
            RerunTarget::Connect(url) => write!(f, "rerun viewer at {url}"),
            RerunTarget::Save(path) => write!(f, "{}", path.display()),
        }
    }
}

/// What a saved recording is called in errors.
const RRD_WHAT: &str = "rerun recording";
/// The first bytes of every `.rrd` file (`RRF0`, `RRF1`, `RRF2`): an existing file that starts
/// otherwise is never replaced.
pub const RRD_MAGIC: &[u8] = b"RRF";

/// Checks that `path` may receive a saved recording, creating nothing (see
/// [`crate::files::check_output`]; an earlier recording may be replaced).
pub fn check_save_target(path: &Path, inputs: &[&Path]) -> Result<(), crate::files::FileError> {
    crate::files::check_output(path, RRD_WHAT, Replace::IfStartsWith(RRD_MAGIC), inputs)
}

/// Whether `path` holds a finished recording: the stream header's `RRF`, and the stream
/// footer (`RRF2`, `FOOT`, u32 count) that rerun writes when the stream is closed.
fn recording_is_finished(path: &Path) -> std::io::Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path)?;
    if file.metadata()?.len() < 16 {
        return Ok(false);
    }
    let mut head = [0u8; 4];
    file.read_exact(&mut head)?;
    let mut tail = [0u8; 8];
    file.seek(SeekFrom::End(-12))?;
    file.read_exact(&mut tail)?;
    Ok(head.starts_with(RRD_MAGIC) && &tail == b"RRF2FOOT")
}

/// Circle and ellipse outlines are drawn with this many segments.
const CIRCLE_SEGMENTS: usize = 48;
/// Half-width of outlines (scene units, metres).
const OUTLINE_RADIUS: f32 = 0.04;
/// Radius of prediction points and collision markers.
const POINT_RADIUS: f32 = 0.12;

pub struct RerunSink {
    stream: Option<RecordingStream>,
    /// The `.partial` file of a saved recording, until it is committed.
    output: Option<OutputFile>,
    target: RerunTarget,
    /// Simulation timestep: `step` = round(time / timestep).
    timestep: f64,
    /// Indices of the planar position in the state vector: as the vehicle declares it (the run
    /// metadata, or [`RerunSink::declare_planar_position`] for a live run), else recognised
    /// from the `/state` names (logs written before the declaration).
    position_index: Option<[usize; 2]>,
    declared_planar: Option<Option<[usize; 2]>>,
    /// Last vehicle position (from `/tf`), where collision markers are drawn.
    vehicle_position: Option<[f64; 2]>,
    collisions: Vec<[f32; 2]>,
    /// Entities whose static series styling has been logged.
    styled: HashSet<EntityPath>,
}

fn path(parts: &[&str]) -> EntityPath {
    EntityPath::new(parts.iter().map(|p| EntityPathPart::new(*p)).collect())
}

/// /world/<scene entity id>, with `/` in the id as path separators (`trail/3`).
fn world_path(id: &str) -> EntityPath {
    let parts: Vec<&str> = std::iter::once("world").chain(id.split('/')).collect();
    path(&parts)
}

fn rgba(c: Option<&Color>) -> ::rerun::Color {
    let c = c.cloned().unwrap_or(Color {
        r: 0.5,
        g: 0.5,
        b: 0.5,
        a: 1.0,
    });
    let byte = |v: f64| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    ::rerun::Color::from_unmultiplied_rgba(byte(c.r), byte(c.g), byte(c.b), byte(c.a))
}

/// Position (x, y) and yaw of a Foxglove pose.
fn planar_pose(pose: Option<&Pose>) -> ([f64; 2], f64) {
    let Some(pose) = pose else {
        return ([0.0, 0.0], 0.0);
    };
    let p = pose.position.as_ref().map_or([0.0, 0.0], |v| [v.x, v.y]);
    let yaw = pose.orientation.as_ref().map_or(0.0, |q| {
        (2.0 * (q.w * q.z + q.x * q.y)).atan2(1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    });
    (p, yaw)
}

/// A local point (x, y) of a pose's frame in world coordinates.
fn place(origin: [f64; 2], yaw: f64, local: [f64; 2]) -> [f32; 2] {
    let (s, c) = yaw.sin_cos();
    [
        (origin[0] + c * local[0] - s * local[1]) as f32,
        (origin[1] + s * local[0] + c * local[1]) as f32,
    ]
}

/// The closed outlines and polylines of one Foxglove scene entity, with their colours and radii.
fn entity_strips(entity: &SceneEntity) -> (Vec<Vec<[f32; 2]>>, Vec<::rerun::Color>, Vec<f32>) {
    let mut strips = Vec::new();
    let mut colors = Vec::new();
    let mut radii = Vec::new();
    for cylinder in &entity.cylinders {
        let (origin, yaw) = planar_pose(cylinder.pose.as_ref());
        let (a, b) = cylinder.size.as_ref().map_or((0.5, 0.5), |s| (s.x / 2.0, s.y / 2.0));
        let outline = (0..=CIRCLE_SEGMENTS)
            .map(|k| {
                let theta = std::f64::consts::TAU * k as f64 / CIRCLE_SEGMENTS as f64;
                place(origin, yaw, [a * theta.cos(), b * theta.sin()])
            })
            .collect();
        strips.push(outline);
        colors.push(rgba(cylinder.color.as_ref()));
        radii.push(OUTLINE_RADIUS);
    }
    for cube in &entity.cubes {
        let (origin, yaw) = planar_pose(cube.pose.as_ref());
        let (a, b) = cube.size.as_ref().map_or((0.5, 0.5), |s| (s.x / 2.0, s.y / 2.0));
        let corners = [[a, b], [-a, b], [-a, -b], [a, -b], [a, b]];
        strips.push(corners.iter().map(|&c| place(origin, yaw, c)).collect());
        colors.push(rgba(cube.color.as_ref()));
        radii.push(OUTLINE_RADIUS);
    }
    for line in &entity.lines {
        let (origin, yaw) = planar_pose(line.pose.as_ref());
        let points: Vec<[f32; 2]> = line.points.iter().map(|p| place(origin, yaw, [p.x, p.y])).collect();
        let radius = (line.thickness / 2.0).max(0.01) as f32;
        let color = rgba(line.color.as_ref());
        match line_primitive::Type::try_from(line.r#type).unwrap_or(line_primitive::Type::LineStrip) {
            line_primitive::Type::LineStrip => strips.push(points),
            line_primitive::Type::LineLoop => {
                let mut closed = points;
                if let Some(&first) = closed.first() {
                    closed.push(first);
                }
                strips.push(closed);
            }
            line_primitive::Type::LineList => {
                for pair in points.chunks_exact(2) {
                    strips.push(pair.to_vec());
                    colors.push(color);
                    radii.push(radius);
                }
                continue;
            }
        }
        colors.push(color);
        radii.push(radius);
    }
    (strips, colors, radii)
}

/// The linear half-width of the `plots/barrier_symlog` series (h's unit): a margin of 0.02 m²
/// reads as 0.48 there, 250 m² as 4.4, a violation of −0.01 m² as −0.30.
pub const SYMLOG_C: f64 = 0.01;

/// h on the symmetric-log scale of `plots/barrier_symlog` (the figures' axis, [`SYMLOG_C`]).
fn symlog(h: f64) -> f64 {
    crate::log::symlog(h, SYMLOG_C)
}

/// The blueprint: the 2D world view on the left, the time series and the events on the right.
pub fn blueprint() -> Blueprint {
    let plots = Vertical::new([
        TimeSeriesView::new("barriers: h, constraint")
            .with_origin("plots/barrier")
            .into(),
        TimeSeriesView::new(format!("h near 0: sign(h)·log10(1 + |h|/{SYMLOG_C}) (unsafe below 0)"))
            .with_origin("plots/barrier_symlog")
            .into(),
        TimeSeriesView::new("input: issued vs applied")
            .with_origin("plots/input")
            .into(),
        TimeSeriesView::new("command: nominal vs filtered")
            .with_origin("plots/command")
            .into(),
        TimeSeriesView::new("filter").with_origin("plots/filter").into(),
        TimeSeriesView::new("prediction error")
            .with_origin("plots/prediction")
            .into(),
        TextLogView::new("events").with_origin("events").into(),
    ]);
    // Side panels collapsed; the time panel follows the data, so a loaded recording opens at
    // its end with the whole trail drawn.
    Blueprint::new(
        Horizontal::new([Spatial2DView::new("world").with_origin("world").into(), plots.into()])
            .with_column_shares([1.2, 1.0]),
    )
    .with_blueprint_panel(BlueprintPanel::new().with_state(PanelState::Collapsed))
    .with_selection_panel(SelectionPanel::new().with_state(PanelState::Collapsed))
    .with_time_panel(
        TimePanel::new()
            .with_state(PanelState::Collapsed)
            .with_timeline("sim_time")
            .with_play_state(PlayState::Following),
    )
}

impl RerunSink {
    /// Opens a recording. `recording_id` names it (the same for a run and the replay of its
    /// log, e.g. the log's file stem); `timestep` is the simulation timestep (for `step`).
    /// A saved recording is written as `<file>.partial` (see [`crate::files::OutputFile`]) and
    /// renamed by [`Sink::finish`]; dropped unfinished, nothing is left.
    /// The vehicle's planar position in the state (`None`: not planar), as it declares it.
    pub fn declare_planar_position(&mut self, position: Option<[usize; 2]>) {
        self.declared_planar = Some(position);
    }

    pub fn create(target: RerunTarget, recording_id: &str, timestep: f64) -> Result<RerunSink, LogError> {
        Self::create_with_inputs(target, recording_id, timestep, &[])
    }

    /// [`RerunSink::create`] for a run that reads `inputs`: a saved recording never replaces them.
    pub fn create_with_inputs(
        target: RerunTarget,
        recording_id: &str,
        timestep: f64,
        inputs: &[&Path],
    ) -> Result<RerunSink, LogError> {
        let builder = RecordingStreamBuilder::new(APPLICATION_ID)
            .recording_id(recording_id)
            .enabled(true)
            .with_blueprint(blueprint());
        let mut output = None;
        let stream = match &target {
            RerunTarget::Spawn => builder.spawn(),
            RerunTarget::Connect(url) => builder.connect_grpc_opts(url.clone()),
            RerunTarget::Save(file) => {
                let out = OutputFile::create(file, RRD_WHAT, Replace::IfStartsWith(RRD_MAGIC), inputs)?;
                // Chunks cut by row count only (never by elapsed wall-clock time): a run and the
                // replay of its log write the same chunks.
                let builder = builder.batcher_config(::rerun::log::ChunkBatcherConfig {
                    flush_tick: std::time::Duration::from_secs(365 * 24 * 3600),
                    flush_num_bytes: u64::MAX,
                    flush_num_rows: 4096,
                    ..::rerun::log::ChunkBatcherConfig::DEFAULT
                });
                // rerun writes the file itself (a second handle); `out` holds the lock.
                let stream = builder.save(out.partial_path());
                output = Some(out);
                stream
            }
        }
        .map_err(|e| LogError::Write {
            path: target.to_string(),
            message: e.to_string(),
        })?;
        stream.set_log_time_enabled(false);
        stream.set_log_tick_enabled(false);
        Ok(RerunSink {
            stream: Some(stream),
            output,
            target,
            timestep,
            position_index: None,
            declared_planar: None,
            vehicle_position: None,
            collisions: Vec::new(),
            styled: HashSet::new(),
        })
    }

    pub fn target(&self) -> &RerunTarget {
        &self.target
    }

    fn error(&self, message: String) -> LogError {
        LogError::Write {
            path: self.target.to_string(),
            message,
        }
    }

    fn set_time(&self, stream: &RecordingStream, time: f64) {
        let ns = super::mcap::sim_time_ns(time);
        stream.set_time("sim_time", std::time::Duration::from_nanos(ns));
        let step = if self.timestep > 0.0 {
            (time.max(0.0) / self.timestep).round() as i64
        } else {
            0
        };
        stream.set_time_sequence("step", step);
    }

    /// Logs `values` on a time series entity, naming its lines once (static).
    fn series(
        &mut self,
        stream: &RecordingStream,
        entity: EntityPath,
        names: &[&str],
        values: &[f64],
    ) -> Result<(), ::rerun::RecordingStreamError> {
        if !self.styled.contains(&entity) {
            stream.log_static(
                entity.clone(),
                &::rerun::SeriesLines::new().with_names(names.iter().map(|n| n.to_string())),
            )?;
            self.styled.insert(entity.clone());
        }
        stream.log(entity, &::rerun::Scalars::new(values.iter().copied()))
    }

    fn scene(&mut self, stream: &RecordingStream, update: &SceneUpdate) -> Result<(), ::rerun::RecordingStreamError> {
        for deletion in &update.deletions {
            match scene_entity_deletion::Type::try_from(deletion.r#type) {
                Ok(scene_entity_deletion::Type::All) => stream.log(path(&["world"]), &::rerun::Clear::recursive())?,
                _ => stream.log(world_path(&deletion.id), &::rerun::Clear::flat())?,
            }
        }
        // The predicted positions are drawn from `/prediction` (at their issue time) already.
        for entity in update.entities.iter().filter(|e| !e.id.starts_with("prediction/")) {
            let (strips, colors, radii) = entity_strips(entity);
            let mut archetype = ::rerun::LineStrips2D::new(strips).with_colors(colors).with_radii(radii);
            if entity.lines.is_empty() && entity.cubes.is_empty() && entity.cylinders.len() == 1 {
                archetype = archetype.with_labels([entity.id.clone()]);
            }
            stream.log(world_path(&entity.id), &archetype)?;
        }
        Ok(())
    }

    fn log(&mut self, stream: &RecordingStream, record: &Record) -> Result<(), ::rerun::RecordingStreamError> {
        self.set_time(stream, record.time());
        match record {
            Record::State(m) => {
                if self.position_index.is_none() {
                    self.position_index = planar_position_of(self.declared_planar, &m.names);
                }
            }
            Record::Issued(m) => {
                for (i, channel) in m.channels.iter().enumerate() {
                    let (nominal, filtered) = (value(&m.nominal, i), value(&m.filtered, i));
                    self.series(
                        stream,
                        path(&["plots", "command", channel]),
                        &["nominal", "filtered"],
                        &[nominal, filtered],
                    )?;
                    self.series(
                        stream,
                        path(&["plots", "input", channel, "issued"]),
                        &["issued"],
                        &[filtered],
                    )?;
                }
            }
            Record::Applied(m) => {
                for (i, channel) in m.channels.iter().enumerate() {
                    self.series(
                        stream,
                        path(&["plots", "input", channel, "applied"]),
                        &["applied"],
                        &[value(&m.values, i)],
                    )?;
                }
            }
            Record::Actuated(m) => {
                for (i, channel) in m.channels.iter().enumerate() {
                    self.series(
                        stream,
                        path(&["plots", "input", channel, "actuated"]),
                        &["actuated"],
                        &[value(&m.values, i)],
                    )?;
                }
            }
            Record::Actors(m) => {
                for a in &m.actors {
                    let speed = a.vx.hypot(a.vy);
                    self.series(
                        stream,
                        path(&["plots", "actors", &a.name, "speed"]),
                        &["speed"],
                        &[speed],
                    )?;
                }
            }
            Record::Measured(m) => {
                for (name, v) in m.names.iter().zip(&m.values) {
                    self.series(stream, path(&["plots", "measured", name]), &["measured"], &[*v])?;
                }
                if let Some([i, j]) = self.position_index {
                    if let (Some(x), Some(y)) = (m.values.get(i), m.values.get(j)) {
                        stream.log(
                            path(&["world", "measured"]),
                            &::rerun::Points2D::new([[*x as f32, *y as f32]])
                                .with_radii([POINT_RADIUS])
                                .with_labels(["measured"]),
                        )?;
                    }
                }
            }
            Record::Barrier(m) => {
                for b in &m.barriers {
                    self.series(
                        stream,
                        path(&["plots", "barrier", &b.name]),
                        &["h", "constraint"],
                        &[b.h, b.constraint],
                    )?;
                    // The margin near 0 readable beside h = 250 m² (the raw view runs 0–1000).
                    self.series(
                        stream,
                        path(&["plots", "barrier_symlog", &b.name]),
                        &["h (symlog)"],
                        &[symlog(b.h)],
                    )?;
                }
            }
            Record::Filter(m) => {
                self.series(
                    stream,
                    path(&["plots", "filter"]),
                    &["active", "infeasible"],
                    &[f64::from(u8::from(m.active)), f64::from(u8::from(m.infeasible))],
                )?;
            }
            Record::Prediction(m) => {
                self.series(
                    stream,
                    path(&["plots", "prediction", &m.channel]),
                    &["error"],
                    &[m.error],
                )?;
                if let Some([i, j]) = self.position_index {
                    if let (Some(x), Some(y)) = (m.predicted.get(i), m.predicted.get(j)) {
                        // The prediction made at `issued_at`, shown at that time.
                        self.set_time(stream, m.issued_at);
                        // No text label: the channels' predictions sit within centimetres of
                        // each other and their labels printed over each other; each channel
                        // has its own colour and its entity path names it on hover.
                        stream.log(
                            path(&["world", "prediction", &m.channel]),
                            &::rerun::Points2D::new([[*x as f32, *y as f32]]).with_radii([POINT_RADIUS]),
                        )?;
                    }
                }
            }
            Record::Event(m) => self.event(stream, m)?,
            Record::Scene(_, update) => self.scene(stream, update)?,
            Record::Transform(_, transform) => {
                if let Some(t) = &transform.translation {
                    self.vehicle_position = Some([t.x, t.y]);
                }
            }
            // The `/event` it repeats for Foxglove is logged as the event.
            Record::Log(..) => {}
        }
        Ok(())
    }

    fn event(&mut self, stream: &RecordingStream, m: &proto::Event) -> Result<(), ::rerun::RecordingStreamError> {
        let level = match m.kind.as_str() {
            "error" => ::rerun::TextLogLevel::ERROR,
            "collision_start" | "collision_end" | crate::log::MUJOCO_WARNING => ::rerun::TextLogLevel::WARN,
            _ => ::rerun::TextLogLevel::INFO,
        };
        let mut text = m.kind.clone();
        if !m.participants.is_empty() {
            text.push_str(&format!(" [{}]", m.participants.join(", ")));
        }
        if m.depth != 0.0 {
            text.push_str(&format!(" depth {:.4} m", m.depth));
        }
        if !m.message.is_empty() {
            text.push_str(&format!(": {}", m.message));
        }
        stream.log(path(&["events"]), &::rerun::TextLog::new(text).with_level(level))?;
        if m.kind == "collision_start" {
            if let Some(p) = self.vehicle_position {
                self.collisions.push([p[0] as f32, p[1] as f32]);
                stream.log(
                    path(&["world", "collisions"]),
                    &::rerun::Points2D::new(self.collisions.clone())
                        .with_radii([2.0 * POINT_RADIUS])
                        .with_colors([::rerun::Color::from_rgb(255, 140, 0)]),
                )?;
            }
        }
        Ok(())
    }
}

fn value(values: &[f64], i: usize) -> f64 {
    values.get(i).copied().unwrap_or(f64::NAN)
}

impl Sink for RerunSink {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        let Some(stream) = self.stream.take() else {
            return Err(self.error("record after finish".into()));
        };
        let result = self.log(&stream, record);
        self.stream = Some(stream);
        result.map_err(|e| self.error(e.to_string()))
    }

    /// Flushes the stream and closes it; a saved recording is checked to be complete and
    /// renamed to its final name (also for a run stopped early: it holds the run up to there).
    fn finish(&mut self, _complete: bool) -> Result<(), LogError> {
        let output = self.output.take();
        let Some(stream) = self.stream.take() else {
            return Ok(());
        };
        let flushed = stream.flush_blocking();
        // Dropping the last handle closes the sink (an .rrd file is completed and closed).
        drop(stream);
        flushed.map_err(|e| self.error(format!("flushing the recording: {e}")))?;
        if let Some(output) = output {
            match recording_is_finished(output.partial_path()) {
                Ok(true) => {}
                Ok(false) => return Err(output.error("rerun did not finish writing it".into()).into()),
                Err(e) => return Err(output.error(format!("cannot read it back: {e}")).into()),
            }
            output.commit()?;
        }
        Ok(())
    }
}

impl Drop for RerunSink {
    /// Unfinished (an error path): a viewer stream is flushed; a saved recording is deleted.
    fn drop(&mut self) {
        if self.output.is_some() {
            drop(self.stream.take());
            self.output = None;
        } else {
            let _ = self.finish(false);
        }
    }
}

#[cfg(test)]
mod tests {

    /// The symlog view separates the 0.024 m² margin of (4.67) from 0 and from a violation of
    /// −0.01 m², while 250 m² stays on the same scale.
    #[test]
    fn the_symlog_series_reads_the_margin_near_zero() {
        use super::symlog;
        assert_eq!(symlog(0.0), 0.0);
        assert!(
            symlog(0.024) > 0.5 && symlog(-0.01) < -0.3,
            "{} {}",
            symlog(0.024),
            symlog(-0.01)
        );
        assert!(symlog(250.0) < 4.5 && symlog(1000.0) < 5.1);
        assert_eq!(symlog(-3.0), -symlog(3.0));
    }

    use super::*;

    #[test]
    fn cube_outline_turns_with_the_yaw() {
        let update = crate::log::scene::vehicle(0.0, [1.0, 2.0], std::f64::consts::FRAC_PI_2, 1.0);
        let (strips, colors, radii) = entity_strips(&update.entities[0]);
        assert_eq!((strips.len(), colors.len(), radii.len()), (2, 2, 2));
        // Body box: 1.6 r long along the heading (here +y), 0.7 r wide, centred 0.5 r ahead.
        let body = &strips[1];
        assert_eq!(body.first(), body.last());
        let (xs, ys): (Vec<f32>, Vec<f32>) = body.iter().map(|p| (p[0], p[1])).unzip();
        let span = |v: &[f32]| v.iter().cloned().fold(f32::MIN, f32::max) - v.iter().cloned().fold(f32::MAX, f32::min);
        assert!((span(&ys) - 1.6).abs() < 1e-5 && (span(&xs) - 0.7).abs() < 1e-5);
        let cy = ys.iter().take(4).sum::<f32>() / 4.0;
        assert!((cy - 2.5).abs() < 1e-5);
        // Hull: a circle of radius r around the position.
        assert!(strips[0]
            .iter()
            .all(|p| ((p[0] - 1.0).hypot(p[1] - 2.0) - 1.0).abs() < 1e-5));
    }
}

/// Why a replay failed: the log could not be read as an mjsafe log (the reader's errors, as
/// for `analyze`), or the recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Log(#[from] LogError),
    #[error(transparent)]
    Output(#[from] crate::files::FileError),
}

/// What a replay fed to the sink.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplaySummary {
    pub messages: u64,
    pub complete: bool,
    /// With `recover`: the damage that ended the replay of a corrupt log (what was read from
    /// the chunks before it is in the recording).
    pub damage: Option<String>,
}

/// The recording id of a log: its file stem (a run and the replay of its log share it).
pub fn recording_id(log: &Path) -> String {
    log.file_stem()
        .map_or_else(|| "mjsafe".to_string(), |s| s.to_string_lossy().into_owned())
}

/// Rebuilds the rerun recording of a run from its MCAP log alone (no re-simulation): every
/// message is decoded into its [`Record`] and fed to a [`RerunSink`] in log order, through the
/// run reader ([`read_run_file`]: the run metadata first, wherever it sits in the file). Only
/// the records of chunks that passed their CRC reach the sink. A damaged log is an error and
/// its `.rrd` is not written, unless `recover`: then the recording of what was read before the
/// damage is finished and kept, and the summary names the damage.
pub fn replay(log: &Path, target: RerunTarget, recover: bool) -> Result<ReplaySummary, ReplayError> {
    let file = log.display().to_string();
    // A saved recording is checked before anything is read; the sink writes it as `.partial`
    // and renames it only when finished (a sink dropped unfinished deletes it).
    if let RerunTarget::Save(out) = &target {
        check_save_target(out, &[log])?;
    }
    let mut replay = Replay {
        log,
        file: &file,
        sink: None,
        target: Some(target),
        complete: false,
        failure: None,
    };
    let result = read_run_file(log, &mut replay);
    let Replay {
        sink,
        complete,
        failure,
        ..
    } = replay;
    // A recording error of the visitor was carried out through `failure`.
    if let Some(failure) = failure {
        return Err(failure);
    }
    let read = match result {
        Ok(read) => read,
        Err(damage @ ReadError::Corrupt { messages, .. }) => match sink {
            // Keep what was read (the recording is finished), report the damage.
            Some(mut sink) if recover => {
                sink.finish(false)?;
                return Ok(ReplaySummary {
                    messages,
                    complete: false,
                    damage: Some(damage.to_string()),
                });
            }
            // Dropped unfinished, the sink deletes its `.partial` recording.
            _ => {
                drop(sink);
                return Err(damage.into());
            }
        },
        Err(e) => return Err(e.into()),
    };
    let mut sink = sink.expect("the run reader gave the run metadata");
    sink.finish(complete)?;
    Ok(ReplaySummary {
        messages: read.messages,
        complete,
        damage: None,
    })
}

/// The replay as a visitor of the run reader.
struct Replay<'a> {
    log: &'a Path,
    file: &'a str,
    /// Opened at the run metadata (it holds the timestep).
    sink: Option<RerunSink>,
    target: Option<RerunTarget>,
    complete: bool,
    failure: Option<ReplayError>,
}

impl Replay<'_> {
    /// Keeps a recording error, and stops the reader with a stand-in error.
    fn fail(&mut self, e: LogError) -> ReadError {
        self.failure = Some(e.into());
        ReadError::Foreign {
            file: self.file.into(),
            message: "replay stopped".into(),
        }
    }
}

impl RunVisitor for Replay<'_> {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        match name {
            RUN_METADATA => {
                let timestep = entries.get("timestep").and_then(|s| s.parse::<f64>().ok());
                let Some(timestep) = timestep else {
                    return Err(ReadError::Foreign {
                        file: self.file.into(),
                        message: "the mjsafe metadata has no timestep".into(),
                    });
                };
                if let Some(target) = self.target.take() {
                    match RerunSink::create_with_inputs(target, &recording_id(self.log), timestep, &[self.log]) {
                        Ok(mut s) => {
                            s.declared_planar = declared_planar_position(entries);
                            self.sink = Some(s);
                        }
                        Err(e) => return Err(self.fail(e)),
                    }
                }
            }
            STATUS_METADATA => self.complete = entries.get("complete").is_some_and(|v| v == "true"),
            _ => {}
        }
        Ok(())
    }

    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        let record = message.record()?;
        let sink = self.sink.as_mut().expect("opened at the run metadata, given first");
        match sink.record(&record) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.fail(e)),
        }
    }
}

#[cfg(test)]
mod save_tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn a_saved_recording_appears_when_finished_and_never_when_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("run.rrd");
        let mut sink = RerunSink::create(RerunTarget::Save(file.clone()), "run", 0.01).unwrap();
        assert_eq!(names(dir.path()), ["run.rrd.partial"]);
        let e = RerunSink::create(RerunTarget::Save(file.clone()), "run", 0.01)
            .err()
            .unwrap();
        assert!(e.to_string().contains("another process is writing it"), "{e}");
        let state = Record::State(proto::State {
            time: 0.0,
            names: vec!["x".into()],
            values: vec![1.0],
            ..Default::default()
        });
        sink.record(&state).unwrap();
        sink.finish(true).unwrap();
        assert_eq!(names(dir.path()), ["run.rrd"]);
        assert!(recording_is_finished(&file).unwrap());
        // Dropped unfinished: the earlier recording stays as it was.
        let before = std::fs::read(&file).unwrap();
        let mut sink = RerunSink::create(RerunTarget::Save(file.clone()), "run", 0.01).unwrap();
        sink.record(&state).unwrap();
        drop(sink);
        assert_eq!(names(dir.path()), ["run.rrd"]);
        assert_eq!(std::fs::read(&file).unwrap(), before);
        // A file that is not a recording is never replaced.
        let notes = dir.path().join("notes.rrd");
        std::fs::write(&notes, "notes").unwrap();
        let e = RerunSink::create(RerunTarget::Save(notes.clone()), "run", 0.01)
            .err()
            .unwrap();
        assert!(e.to_string().contains("not an mjsafe rerun recording"), "{e}");
    }
}
