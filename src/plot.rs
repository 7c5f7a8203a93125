//! Figures of a run, from its MCAP log alone (`mjsafe analyze --plot DIR [--plot-format svg]`):
//! - `<name>-barriers.png|svg`: h(t) of every barrier (of more than eight, the eight that came
//!   closest) on a symmetric-log axis (a margin of 0.02 m² and 250 m² read on one axis), the
//!   unsafe side shaded, events marked;
//! - `<name>-inputs.png|svg`: issued vs applied input per channel, events marked;
//! - `<name>-trajectory.png|svg`: the planar path with the obstacles, the road (edges solid, lane
//!   markings dashed), the half-space barriers on the plane (where h = 0), the reference path and
//!   the road users' paths (more than six: grey, one legend entry).
//!
//! With several logs, also overlays of the runs (`overlay-trajectory`, `overlay-barriers`,
//! `overlay-inputs`: one colour per run, named by its filter's equation number), and
//! [`plot_sweep`] draws a metric of a sweep summary against one swept key.
//!
//! Every figure is drawn once, as SVG; PNG is that SVG rasterised with antialiasing (resvg).
//! Text is laid out with DejaVu Sans, embedded in the binary (assets/fonts, with its licence):
//! no system font is needed, and the PNG renders with it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use plotters::coord::ranged1d::{KeyPointHint, Ranged, ValueFormatter};
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::log::read::{
    declared_planar_position, planar_position_of, read_run_file, Message, ReadError, RunVisitor, RUN_METADATA,
};
use crate::log::Record;

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error(transparent)]
    File(#[from] crate::files::FileError),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("the embedded plot font does not load")]
    Font,
    #[error("{0}")]
    Sweep(String),
    #[error("writing {file}: {message}")]
    Draw { file: String, message: String },
}

/// The font of the plots (DejaVu Sans, assets/fonts/DejaVuSans-LICENSE.txt), embedded.
pub const FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// Registers the embedded font as plotters' `sans-serif` (once per process).
pub fn register_embedded_font() -> Result<(), PlotError> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    if *REGISTERED.get_or_init(|| register_font("sans-serif", FontStyle::Normal, FONT).is_ok()) {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// A static line of the scene: its points, and whether they are dashes (pairs of points).
#[derive(Clone, PartialEq)]
struct SceneLines {
    points: Vec<(f64, f64)>,
    dashed: bool,
}

impl SceneLines {
    /// The segments to draw: the polyline, or each dash.
    fn segments(&self) -> Vec<Vec<(f64, f64)>> {
        if self.dashed {
            self.points.chunks_exact(2).map(<[_]>::to_vec).collect()
        } else {
            vec![self.points.clone()]
        }
    }

    /// Its colour and width in a trajectory plot: road edges dark grey, lane markings and
    /// half-space barriers lighter.
    fn style(id: &str) -> ShapeStyle {
        if id.starts_with("barrier/") {
            PALETTE[3].stroke_width(2)
        } else if id.starts_with("road/lane/") {
            RGBColor(150, 150, 150).stroke_width(2)
        } else {
            RGBColor(60, 60, 60).stroke_width(3)
        }
    }
}

/// Draws the scene's static lines on a trajectory chart.
fn draw_scene_lines<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    lines: &BTreeMap<String, SceneLines>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (id, line) in lines {
        for segment in line.segments() {
            chart.draw_series(LineSeries::new(segment, SceneLines::style(id)))?;
        }
    }
    Ok(())
}

/// What the plots need from a log.
#[derive(Default)]
struct Series {
    barriers: BTreeMap<String, Vec<(f64, f64)>>,
    issued: BTreeMap<String, Vec<(f64, f64)>>,
    applied: BTreeMap<String, Vec<(f64, f64)>>,
    path: Vec<(f64, f64)>,
    /// The time of each point of `path`.
    path_times: Vec<f64>,
    /// Per moving obstacle, its (t, x, y) from `/actors`.
    actors: BTreeMap<String, Vec<(f64, f64, f64)>>,
    /// (name, centre, radius) of the obstacles, from `/scene` (a moving one where it was last).
    obstacles: BTreeMap<String, ((f64, f64), f64)>,
    /// (name, centre, (length, width), heading) of the box obstacles (`/scene` cubes).
    boxes: BTreeMap<String, BoxOutline>,
    reference: Option<[(f64, f64); 2]>,
    /// The static lines of `/scene` by entity id: road edges (`road/<edge>`), lane markings
    /// (`road/lane/<marking>`, dashed: their points in pairs) and half-space barriers
    /// (`barrier/<name>`, where h = 0).
    lines: BTreeMap<String, SceneLines>,
    /// The planar position the vehicle declared in the run metadata (None: not declared).
    declared_planar: Option<Option<[usize; 2]>>,
    /// The filter by its equation number (run metadata).
    label: Option<String>,
    /// The vehicle's hull radius (from its `/scene` entity): the vehicle's share of the
    /// barrier radius r = obstacle + hull.
    hull_radius: Option<f64>,
    /// The `/barrier` entries that are obstacles' (4.81): h in m².
    obstacle_barriers: std::collections::BTreeSet<String>,
    /// Per road user (`/actors`), its (t, x, y, heading, absent).
    poses: BTreeMap<String, Vec<ActorPose>>,
    /// The vehicle's closest approach to any obstacle: (clearance, time, obstacle name), from
    /// the `/barrier` obstacle entries (the least clearance; its first time).
    closest: Option<(f64, f64, String)>,
    /// The vehicle's footprint as `/scene` draws it (a cube, no hull cylinder), with its time.
    footprints: Vec<(f64, BoxOutline)>,
    /// The events marked on time axes (`/event`): (time, what, whose appearance) of each
    /// collision, the stall and each road user's appearance.
    events: Vec<(f64, String, Option<String>)>,
    /// Per `/barrier` entry, its least clearance (m; NaN values passed over).
    least_clearance: BTreeMap<String, f64>,
}

/// At most this many barriers in one h(t) chart: with more (a CommonRoad world's road users and
/// road edges), the ones that came closest ([`Series::shown_barriers`]).
const MAX_H_LINES: usize = 8;

/// Runs with more barriers than this are drawn in an overlay of h(t) by the one that came
/// closest; up to this many, each (in the run's colour).
const OVERLAY_BARRIERS: usize = 3;

/// More road users than this are drawn in a trajectory plot as grey paths under one legend
/// entry; up to this many, each in its colour under its name.
const NAMED_ROAD_USERS: usize = 6;

impl Series {
    /// The events as marks in `colour`: collisions and the stall, and the appearances after the
    /// run's first sample of the barriers `shown` (an obstacle there from the start does not
    /// appear; one not drawn is not marked).
    fn marks(&self, colour: RGBColor, shown: &[&String]) -> Vec<Event> {
        let start = (self.barriers.values())
            .filter_map(|s| s.first().map(|p| p.0))
            .fold(f64::INFINITY, f64::min);
        let drawn = |who: &str| shown.iter().any(|name| name.split('/').next() == Some(who));
        (self.events.iter())
            .filter(|(t, _, appearance)| appearance.as_deref().is_none_or(|who| *t > start && drawn(who)))
            .map(|(t, what, _)| (*t, what.clone(), colour))
            .collect()
    }

    /// The barriers the h(t) chart draws, in name order: every one, or with more than
    /// [`MAX_H_LINES`] the ones that came closest ([`Series::closest_barriers`]).
    fn shown_barriers(&self) -> Vec<&String> {
        let names: Vec<&String> = self.barriers.keys().collect();
        if names.len() <= MAX_H_LINES {
            return names;
        }
        let closest = self.closest_barriers(MAX_H_LINES);
        names.into_iter().filter(|name| closest.contains(name)).collect()
    }

    /// The `count` barriers that came closest, closest first: by least clearance (m), then by
    /// least h (a barrier without a clearance after every one with).
    fn closest_barriers(&self, count: usize) -> Vec<&String> {
        let least = |name: &String| {
            let clearance = self.least_clearance.get(name).copied().filter(|c| c.is_finite());
            let h = (self.barriers[name].iter().map(|p| p.1))
                .filter(|h| h.is_finite())
                .fold(f64::INFINITY, f64::min);
            (clearance.unwrap_or(f64::INFINITY), h)
        };
        let mut ranked: Vec<((f64, f64), &String)> = self.barriers.keys().map(|name| (least(name), name)).collect();
        ranked.sort_by(|((ca, ha), _), ((cb, hb), _)| ca.total_cmp(cb).then(ha.total_cmp(hb)));
        ranked.into_iter().take(count).map(|(_, name)| name).collect()
    }
}

/// A road user's logged pose: time, position, heading, whether it is absent.
type ActorPose = (f64, f64, f64, f64, bool);

impl RunVisitor for Series {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        if name == RUN_METADATA {
            self.declared_planar = declared_planar_position(entries);
            self.label = crate::analyze::filter_label(entries);
        }
        Ok(())
    }

    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        match message.record()? {
            Record::State(m) => {
                if let Some([i, j]) = planar_position_of(self.declared_planar, &m.names) {
                    self.path.push((m.values[i], m.values[j]));
                    self.path_times.push(m.time);
                }
            }
            Record::Actors(m) => {
                for a in m.actors {
                    let pose = (m.time, a.x, a.y, a.heading, a.absent);
                    self.poses.entry(a.name.clone()).or_default().push(pose);
                    self.actors.entry(a.name).or_default().push((m.time, a.x, a.y));
                }
            }
            Record::Barrier(m) => {
                if self.barriers.is_empty() {
                    let obstacles = m.barriers.iter().filter(|b| b.obstacle);
                    self.obstacle_barriers = obstacles.map(|b| b.name.clone()).collect();
                }
                for b in m.barriers {
                    match self.least_clearance.get_mut(&b.name) {
                        Some(least) => *least = least.min(b.clearance),
                        None => {
                            self.least_clearance.insert(b.name.clone(), b.clearance);
                        }
                    }
                    // (NaN, a road user that does not exist, is never the closest.)
                    let nearer = |c: &(f64, f64, String)| b.clearance < c.0;
                    if b.obstacle && !b.clearance.is_nan() && self.closest.as_ref().is_none_or(nearer) {
                        let obstacle = b.name.split('/').next().unwrap_or_default().to_string();
                        self.closest = Some((b.clearance, m.time, obstacle));
                    }
                    self.barriers.entry(b.name).or_default().push((m.time, b.h));
                }
            }
            Record::Event(e) => {
                let with = e.participants.iter().find(|p| p.as_str() != "vehicle").cloned();
                let what = match e.kind.as_str() {
                    "collision_start" => Some((
                        format!("collision{}", with.map_or(String::new(), |w| format!(" ({w})"))),
                        None,
                    )),
                    "stall" => Some(("stall".to_string(), None)),
                    "obstacle_appeared" => {
                        let who = with.unwrap_or_else(|| "obstacle".into());
                        Some((format!("{who} appears"), Some(who)))
                    }
                    _ => None,
                };
                if let Some((what, appearance)) = what {
                    self.events.push((e.time, what, appearance));
                }
            }
            Record::Issued(m) => {
                for (c, v) in m.channels.iter().zip(&m.filtered) {
                    self.issued.entry(c.clone()).or_default().push((m.time, *v));
                }
            }
            Record::Applied(m) => {
                for (c, v) in m.channels.iter().zip(&m.values) {
                    self.applied.entry(c.clone()).or_default().push((m.time, *v));
                }
            }
            Record::Scene(time, m) => {
                for e in m.entities {
                    if e.id == "reference_path" {
                        if let Some(line) = e.lines.first() {
                            if line.points.len() >= 2 {
                                let (a, b) = (&line.points[0], &line.points[line.points.len() - 1]);
                                self.reference = Some([(a.x, a.y), (b.x, b.y)]);
                            }
                        }
                    } else if e.id.starts_with("road/") || e.id.starts_with("barrier/") {
                        for line in &e.lines {
                            let dashed = line.r#type == foxglove::messages::line_primitive::Type::LineList as i32;
                            let points = line.points.iter().map(|p| (p.x, p.y)).collect();
                            self.lines.insert(e.id.clone(), SceneLines { points, dashed });
                        }
                    } else if e.id == "vehicle" {
                        if let Some(c) = e.cylinders.first() {
                            self.hull_radius = Some(c.size.unwrap_or_default().x / 2.0);
                        } else if let Some(c) = e.cubes.first() {
                            let (pose, size) = (c.pose.unwrap_or_default(), c.size.unwrap_or_default());
                            let (p, q) = (pose.position.unwrap_or_default(), pose.orientation.unwrap_or_default());
                            let outline = ((p.x, p.y), (size.x, size.y), 2.0 * q.z.atan2(q.w));
                            self.footprints.push((time, outline));
                        }
                    } else if !e.id.starts_with("trail")
                        && !e.id.starts_with("prediction")
                        && !e.id.starts_with("actor_")
                    {
                        if let Some(c) = e.cylinders.first() {
                            let (pose, size) = (c.pose.unwrap_or_default(), c.size.unwrap_or_default());
                            let p = pose.position.unwrap_or_default();
                            self.obstacles.insert(e.id.clone(), ((p.x, p.y), size.x / 2.0));
                        } else if let Some(c) = e.cubes.first() {
                            let (pose, size) = (c.pose.unwrap_or_default(), c.size.unwrap_or_default());
                            let (p, q) = (pose.position.unwrap_or_default(), pose.orientation.unwrap_or_default());
                            // A yaw quaternion (0, 0, sin ψ/2, cos ψ/2).
                            let heading = 2.0 * q.z.atan2(q.w);
                            self.boxes.insert(e.id.clone(), ((p.x, p.y), (size.x, size.y), heading));
                        }
                    }
                }
            }
            _ => {}
        }
        Ok(())
    }
}

/// Line colours, in order (matplotlib's tab10 without its grey, which the road's lines use):
/// [`MAX_H_LINES`] and [`NAMED_ROAD_USERS`] lines each get one of their own.
const PALETTE: [RGBColor; 9] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
];

/// The road users' paths when there are more than [`NAMED_ROAD_USERS`]: light grey.
const ROAD_USER_GREY: RGBColor = RGBColor(175, 175, 175);

/// A series' runs of points with a value (a NaN, e.g. a road user's h while it does not exist,
/// is a gap in its line, not a point).
fn finite_runs(points: &[(f64, f64)]) -> impl Iterator<Item = &[(f64, f64)]> {
    points.split(|p| p.1.is_nan()).filter(|run| !run.is_empty())
}

fn bounds(points: impl Iterator<Item = (f64, f64)> + Clone) -> ((f64, f64), (f64, f64)) {
    let fold = |f: fn(&(f64, f64)) -> f64| {
        points
            .clone()
            .map(|p| f(&p))
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
    };
    let pad = |(lo, hi): (f64, f64)| {
        if !lo.is_finite() {
            return (0.0, 1.0);
        }
        // A single value (one point, a constant series) gets a range around it: ±10 % of its
        // size, or ±1 around 0, so its ticks differ and it sits inside the frame.
        let span = if hi - lo > 1e-12 * lo.abs().max(hi.abs()) {
            hi - lo
        } else {
            let half = if lo == 0.0 { 1.0 } else { 0.1 * lo.abs() };
            return (lo - half, hi + half);
        };
        (lo - 0.05 * span, hi + 0.05 * span)
    };
    (pad(fold(|p| p.0)), pad(fold(|p| p.1)))
}

type DrawResult<T> = Result<T, Box<dyn std::error::Error>>;

/// Height over width of a chart's plotting area (image size, margin, x and y label areas and
/// caption font size in pixels; the caption takes about 1.4 × its font size): the y span that
/// gives both axes the same metres per pixel is this times the x span.
fn plot_aspect((width, height): (u32, u32), margin: u32, x_label: u32, y_label: u32, caption: u32) -> f64 {
    let w = f64::from(width - 2 * margin - y_label);
    let h = f64::from(height - 2 * margin - x_label) - 1.4 * f64::from(caption);
    h / w
}

/// A trajectory figure's size (px) for data spanning (x, y) metres: 1000 wide, and as tall as
/// equal scales need (400–1000; 500 for a path with no extent).
fn trajectory_size((span_x, span_y): (f64, f64)) -> (u32, u32) {
    let width = 1000;
    if !(span_x > 0.0 && span_y.is_finite()) {
        return (width, 500);
    }
    // The plotting area: the width less the margins and the y labels; the height less the
    // margins, the x labels and the caption (as `plot_aspect` counts them).
    let plot_height = f64::from(width - 2 * 12 - 50) * span_y / span_x;
    let height = plot_height + f64::from(2 * 12 + 36) + 1.4 * 22.0;
    (width, height.round().clamp(400.0, 1000.0) as u32)
}

/// One line of a chart: legend label, (t, value) points, style.
type Line<'a> = (String, &'a [(f64, f64)], ShapeStyle);

/// A mark on a time axis: its time, what happened (a collision, a stall, a road user
/// appearing) and its colour (the run's).
type Event = (f64, String, RGBColor);

/// The legend's width for `labels` (about 8 px per character at its 15 px font), so that it
/// sits beside the plot, off the data.
fn legend_width<'a>(labels: impl Iterator<Item = &'a str>) -> u32 {
    let longest = labels.map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    (48 + 8 * longest).clamp(120, 440)
}

/// The legend in its own area beside the plot: a line sample and the label per entry.
fn draw_legend(area: &Area<'_>, entries: &[(String, ShapeStyle)], top: i32) -> DrawResult<()> {
    let font = ("sans-serif", 15).into_font();
    for (k, (label, style)) in entries.iter().enumerate() {
        let y = top + 22 * k as i32;
        area.draw(&PathElement::new(vec![(6, y), (32, y)], *style))?;
        area.draw(&Text::new(label.clone(), (38, y - 8), font.clone()))?;
    }
    Ok(())
}

/// Splits `area` into the plot and, at its right, the legend of `entries`; draws the legend.
fn with_legend<'a>(area: &Area<'a>, entries: &[(String, ShapeStyle)]) -> DrawResult<Area<'a>> {
    if entries.is_empty() {
        return Ok(area.clone());
    }
    let width = area.dim_in_pixel().0;
    let legend = legend_width(entries.iter().map(|e| e.0.as_str())).min(width / 2);
    let (plot, side) = area.split_horizontally(width - legend);
    draw_legend(&side, entries, 48)?;
    Ok(plot)
}

/// Time-series chart of named series into `area`, the events marked.
fn time_chart(area: &Area<'_>, title: &str, y_desc: &str, series: &[Line<'_>], events: &[Event]) -> DrawResult<()> {
    let entries: Vec<(String, ShapeStyle)> = series.iter().map(|(n, _, s)| (n.clone(), *s)).collect();
    let plot = with_legend(area, &entries)?;
    let all = series.iter().flat_map(|(_, s, _)| s.iter().copied());
    let ((x0, x1), (y0, y1)) = bounds(all);
    let mut chart = ChartBuilder::on(&plot)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .x_desc("t [s]")
        .y_desc(y_desc)
        .y_label_formatter(&|v| tick_label(*v))
        .light_line_style(WHITE.mix(0.0))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()?;
    for (_, points, style) in series {
        for run in finite_runs(points) {
            chart.draw_series(LineSeries::new(run.iter().copied(), *style))?;
        }
    }
    mark_events(&mut chart, events, (y0, y1), (x0, x1))?;
    Ok(())
}

/// Vertical dashed lines at the events' times, labelled at the top (staggered so that close
/// events do not print over each other).
fn mark_events<X, DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, X>>,
    events: &[Event],
    (y0, y1): (f64, f64),
    (x0, x1): (f64, f64),
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    X: Ranged<ValueType = f64>,
{
    let mut last_right = f64::NEG_INFINITY;
    let mut row = 0;
    for (t, what, colour) in events.iter().filter(|e| (x0..=x1).contains(&e.0)) {
        let style = colour.stroke_width(1);
        chart.draw_series(DashedLineSeries::new([(*t, y0), (*t, y1)], 5, 4, style))?;
        // Roughly 7 px per character of the 13 px label over a plot about 800 px wide.
        let width = (x1 - x0) * 7.0 * what.chars().count() as f64 / 800.0;
        row = if *t < last_right { (row + 1) % 5 } else { 0 };
        last_right = last_right.max(t + width);
        let font = ("sans-serif", 13).into_font().color(colour);
        let label = EmptyElement::at((*t, y1)) + Text::new(what.clone(), (4, 4 + 15 * row), font);
        chart.draw_series(std::iter::once(label))?;
    }
    Ok(())
}

/// h(t) of named series on a symmetric-log axis ([`symlog_chart`]).
fn h_chart(area: &Area<'_>, title: &str, y_desc: &str, series: &[Line<'_>], events: &[Event]) -> DrawResult<()> {
    symlog_chart(area, title, ("t [s]", y_desc), series, events)
}

/// Named series on a symmetric-log y axis ([`SymLog`]): a margin of 0.02 m² and 250 m² read
/// on one axis; the unsafe side (y < 0) shaded, the zero line drawn, the events marked, the
/// legend beside the plot.
fn symlog_chart(
    area: &Area<'_>,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    series: &[Line<'_>],
    events: &[Event],
) -> DrawResult<()> {
    let entries: Vec<(String, ShapeStyle)> = series.iter().map(|(n, _, s)| (n.clone(), *s)).collect();
    let plot = with_legend(area, &entries)?;
    let all = series.iter().flat_map(|(_, s, _)| s.iter().copied());
    let ((x0, x1), _) = bounds(all.clone());
    // The data's own extremes (bounds pads linearly), with 0 always in view.
    let lowest = all.clone().map(|p| p.1).filter(|v| v.is_finite()).fold(0.0, f64::min);
    let highest = all.map(|p| p.1).filter(|v| v.is_finite()).fold(0.0, f64::max);
    let axis = SymLog::over(lowest, highest).padded(0.05);
    let (lo, hi) = (axis.lo, axis.hi);
    let mut chart = ChartBuilder::on(&plot)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, axis)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(format!("{y_desc}, symlog (linear within ±{})", tick_label(axis.c)))
        .light_line_style(WHITE.mix(0.0))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()?;
    if lo < 0.0 {
        chart.draw_series(std::iter::once(Rectangle::new(
            [(x0, lo), (x1, 0.0)],
            RED.mix(0.08).filled(),
        )))?;
    }
    chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.stroke_width(2)))?;
    for (_, points, style) in series {
        for run in finite_runs(points) {
            chart.draw_series(LineSeries::new(run.iter().copied(), *style))?;
        }
    }
    mark_events(&mut chart, events, (lo, hi), (x0, x1))?;
    Ok(())
}

pub use crate::log::symlog;

/// A tick label: round values plainly, tiny and huge ones in scientific notation.
pub fn tick_label(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e5 || v.abs() < 1e-3 {
        format!("{v:.0e}")
    } else {
        let text = format!("{:.4}", v);
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// A symmetric-log axis (`symlog`): linear within ±`c`, logarithmic beyond, so that a margin
/// of 0.02 m² and a value of 250 m² both read on one axis. Ticks: 0 and ±1, 2, 5 × 10^k from
/// `c` on (fewer when crowded).
#[derive(Debug, Clone, Copy)]
pub(crate) struct SymLog {
    pub(crate) lo: f64,
    pub(crate) hi: f64,
    /// The linear half-width about 0.
    pub(crate) c: f64,
}

impl SymLog {
    /// The axis over [lo, hi], its linear part 10⁻⁴ of the largest magnitude rounded down to a
    /// power of ten.
    pub(crate) fn over(lo: f64, hi: f64) -> SymLog {
        let largest = lo.abs().max(hi.abs());
        let c = if largest > 0.0 {
            10f64.powf((largest * 1e-4).log10().floor())
        } else {
            1.0
        };
        SymLog { lo, hi, c }
    }

    /// sign(v) · log10(1 + |v| / c).
    pub(crate) fn forward(&self, v: f64) -> f64 {
        symlog(v, self.c)
    }

    /// The value whose [`SymLog::forward`] is `t`.
    pub(crate) fn inverse(&self, t: f64) -> f64 {
        t.signum() * self.c * (10f64.powf(t.abs()) - 1.0)
    }

    /// The axis widened by `fraction` of its transformed span at each end.
    fn padded(self, fraction: f64) -> SymLog {
        let (a, b) = (self.forward(self.lo), self.forward(self.hi));
        let pad = fraction * (b - a).max(0.1);
        SymLog {
            lo: self.inverse(a - pad),
            hi: self.inverse(b + pad),
            c: self.c,
        }
    }
}

impl Ranged for SymLog {
    type FormatOption = plotters::coord::ranged1d::NoDefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let (a, b) = (self.forward(self.lo), self.forward(self.hi));
        let f = (self.forward(*value) - a) / (b - a);
        limit.0 + (f * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        let most = hint.max_num_points().max(3);
        let decades = |mantissas: &[f64], every: i32| -> Vec<f64> {
            let mut points = vec![0.0];
            let first = self.c.log10().floor() as i32;
            for e in (first..=first + 40).filter(|e| (e - first) % every == 0) {
                for m in mantissas {
                    let v = m * 10f64.powi(e);
                    points.push(v);
                    points.push(-v);
                }
            }
            points.retain(|v| (self.lo..=self.hi).contains(v));
            points.sort_by(f64::total_cmp);
            points
        };
        let mut every = 1;
        loop {
            for mantissas in [&[1.0, 2.0, 5.0][..], &[1.0][..]] {
                let points = decades(mantissas, every);
                if points.len() <= most || every > 40 {
                    return points;
                }
            }
            every += 1;
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.lo..self.hi
    }
}

impl ValueFormatter<f64> for SymLog {
    fn format(value: &f64) -> String {
        tick_label(*value)
    }
}

/// The start of every PNG file: an existing file that does not start so is never replaced.
pub(crate) const PNG_MAGIC: &[u8] = b"\x89PNG";
/// The start of every SVG file mjsafe draws.
pub(crate) const SVG_MAGIC: &[u8] = b"<svg";

/// What every figure is drawn on: an SVG document, rasterised for PNG ([`draw_figure`]).
type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// The file formats of figures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Antialiased PNG (the SVG rasterised by resvg, text in the embedded DejaVu Sans).
    Png,
    /// SVG: vector, text as text (DejaVu Sans, falling back to the reader's sans-serif).
    Svg,
}

impl Format {
    /// The file extension.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Png => "png",
            Format::Svg => "svg",
        }
    }

    /// The format a file name's extension names (`.png`, `.svg`).
    pub fn of(path: &Path) -> Option<Format> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "png" => Some(Format::Png),
            "svg" => Some(Format::Svg),
            _ => None,
        }
    }

    fn magic(self) -> &'static [u8] {
        match self {
            Format::Png => PNG_MAGIC,
            Format::Svg => SVG_MAGIC,
        }
    }
}

/// Draws a figure of `size` pixels as SVG and writes it to `path` as its extension says (SVG,
/// or PNG rasterised with antialiasing), atomically: never a half-drawn figure under the final
/// name, never over a non-regular file, an input or a file of another kind.
fn draw_figure(
    path: &Path,
    size: (u32, u32),
    inputs: &[&Path],
    draw: impl FnOnce(&Area<'_>) -> DrawResult<()>,
) -> Result<(), Box<dyn std::error::Error>> {
    let format = Format::of(path).ok_or_else(|| format!("{}: expected a .png or .svg file name", path.display()))?;
    let replace = crate::files::Replace::IfStartsWith(format.magic());
    crate::files::check_output(path, "plot", replace, inputs)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: cannot create its directory: {e}", path.display()))?;
    }
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    let svg = with_font_family(&svg);
    let bytes = match format {
        Format::Svg => svg.into_bytes(),
        Format::Png => rasterise(&svg)?,
    };
    crate::files::write_atomically(path, "plot", replace, inputs, &bytes)?;
    Ok(())
}

/// plotters names the registered font `sans-serif`: the SVG asks for DejaVu Sans first (the
/// font the text was measured with), the reader's sans-serif after it.
fn with_font_family(svg: &str) -> String {
    svg.replace("font-family=\"sans-serif\"", "font-family=\"DejaVu Sans, sans-serif\"")
}

/// The SVG as an antialiased PNG of the same pixel size, its text in the embedded font.
fn rasterise(svg: &str) -> Result<Vec<u8>, Box<dyn std::error::Error>> {
    use resvg::{tiny_skia, usvg};
    let mut fonts = usvg::fontdb::Database::new();
    fonts.load_font_data(FONT.to_vec());
    fonts.set_sans_serif_family("DejaVu Sans");
    let options = usvg::Options {
        fontdb: std::sync::Arc::new(fonts),
        ..usvg::Options::default()
    };
    let tree = usvg::Tree::from_str(svg, &options)?;
    let size = tree.size().to_int_size();
    let mut pixmap = tiny_skia::Pixmap::new(size.width(), size.height()).ok_or("the figure has no area")?;
    pixmap.fill(tiny_skia::Color::WHITE);
    resvg::render(&tree, tiny_skia::Transform::default(), &mut pixmap.as_mut());
    Ok(pixmap.encode_png()?)
}

/// The error of a failed drawing of `path`.
fn draw_error(path: &Path, e: Box<dyn std::error::Error>) -> PlotError {
    let file = path.display().to_string();
    // A refused target's message already starts with the path.
    let message = e.to_string();
    let message = message
        .strip_prefix(&format!("{file}: "))
        .unwrap_or(&message)
        .to_string();
    PlotError::Draw { file, message }
}

/// One chart (PNG or SVG, by `path`'s extension) on a symmetric-log y axis of named (x, y) series with the zero line (e.g. a search's best score
/// against runs): written as the other plots are (never half-drawn under its final name).
pub fn line_chart_figure(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), PlotError> {
    register_embedded_font()?;
    let lines: Vec<Line<'_>> = series
        .iter()
        .enumerate()
        .map(|(i, (name, points))| {
            (
                name.clone(),
                points.as_slice(),
                PALETTE[i % PALETTE.len()].stroke_width(2),
            )
        })
        .collect();
    draw_figure(path, (900, 560), &[], |root: &Area<'_>| -> DrawResult<()> {
        symlog_chart(root, title, axes, &lines, &[])?;
        Ok(())
    })
    .map_err(|e| draw_error(path, e))
}

/// Writes the plots of `log` into `dir`; returns the files written.
pub fn plot_log(log: &Path, dir: &Path, format: Format) -> Result<Vec<PathBuf>, PlotError> {
    let ext = format.extension();
    register_embedded_font()?;
    // No plot of part of a run shown as if it were the run: damage is an error.
    let mut series = Series::default();
    read_run_file(log, &mut series)?;
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Draw {
        file: dir.display().to_string(),
        message: e.to_string(),
    })?;
    let stem = log.file_stem().and_then(|s| s.to_str()).unwrap_or("run").to_string();
    let mut written = Vec::new();
    let shown = series.shown_barriers();
    let marks = series.marks(BLACK, &shown);

    if !series.barriers.is_empty() {
        let path = dir.join(format!("{stem}-barriers.{ext}"));
        let lines: Vec<Line<'_>> = (shown.iter().enumerate())
            .map(|(i, name)| {
                (
                    format!("h {name}"),
                    series.barriers[*name].as_slice(),
                    PALETTE[i % PALETTE.len()].stroke_width(2),
                )
            })
            .collect();
        let title = match shown.len() < series.barriers.len() {
            true => format!(
                "barrier functions h(t) (safe: h ≥ 0): the {} of {} that came closest",
                shown.len(),
                series.barriers.len()
            ),
            false => "barrier functions h(t) (safe: h ≥ 0)".to_string(),
        };
        let result = draw_figure(&path, (1000, 500), &[log], |root: &Area<'_>| -> DrawResult<()> {
            let unit = h_unit(!shown.is_empty() && shown.iter().all(|n| series.obstacle_barriers.contains(*n)));
            h_chart(root, &title, &unit, &lines, &marks)?;
            Ok(())
        });
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }

    if !series.issued.is_empty() {
        let path = dir.join(format!("{stem}-inputs.{ext}"));
        let channels: Vec<&String> = series.issued.keys().collect();
        let result = draw_figure(
            &path,
            (1000, 320 * channels.len() as u32),
            &[log],
            |root: &Area<'_>| -> DrawResult<()> {
                for (area, channel) in root.split_evenly((channels.len(), 1)).iter().zip(&channels) {
                    let mut lines = vec![(
                        format!("issued {channel}"),
                        series.issued[*channel].as_slice(),
                        PALETTE[0].stroke_width(2),
                    )];
                    if let Some(applied) = series.applied.get(*channel) {
                        lines.push((
                            format!("applied {channel}"),
                            applied.as_slice(),
                            PALETTE[1].stroke_width(2),
                        ));
                    }
                    time_chart(
                        area,
                        &format!("{channel}: issued vs applied (delayed)"),
                        &channel_unit(channel),
                        &lines,
                        &marks,
                    )?;
                }
                Ok(())
            },
        );
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }

    if !series.path.is_empty() {
        let path = dir.join(format!("{stem}-trajectory.{ext}"));
        plot_trajectory(&series, log, &path)?;
        written.push(path);
    }
    if let Some(path) = plot_closest_approach(&series, log, &dir.join(format!("{stem}-closest.{ext}")))? {
        written.push(path);
    }
    Ok(written)
}

/// The planar path with the obstacles, the road, the reference path and the road users' paths
/// (each named, or with more than [`NAMED_ROAD_USERS`] grey under one entry), on equal scales.
fn plot_trajectory(series: &Series, log: &Path, path: &Path) -> Result<(), PlotError> {
    // A road user is drawn by its path; with many, not also where it was last.
    let named = series.actors.len() <= NAMED_ROAD_USERS;
    let drawn_last = |name: &String| named || !series.actors.contains_key(name);
    let obstacles: Vec<_> = (series.obstacles.iter()).filter(|(n, _)| drawn_last(n)).collect();
    let boxes: Vec<_> = (series.boxes.iter()).filter(|(n, _)| drawn_last(n)).collect();
    let circles = obstacles
        .iter()
        .flat_map(|(_, ((x, y), r))| [(x - r, y - r), (x + r, y + r)]);
    let lines = series.lines.values().flat_map(|l| l.points.iter().copied());
    let actor_paths = series.actors.values().flatten().map(|&(_, x, y)| (x, y));
    let corners = boxes.iter().flat_map(|(_, b)| box_corners(**b));
    let ((x0, x1), (y0, y1)) = bounds(
        (series.path.iter().copied())
            .chain(circles)
            .chain(lines)
            .chain(actor_paths.clone())
            .chain(corners),
    );
    // Equal axis scales: a figure of the data's shape, the shorter span widened to fit.
    let size = trajectory_size((x1 - x0, y1 - y0));
    let aspect = plot_aspect(size, 12, 36, 50, 22);
    let (cx, cy, half) = (
        (x0 + x1) / 2.0,
        (y0 + y1) / 2.0,
        ((x1 - x0).max((y1 - y0) / aspect)) / 2.0,
    );
    let (xs, ys) = ((cx - half, cx + half), (cy - half * aspect, cy + half * aspect));
    let legend_corner = emptiest_corner(series.path.iter().copied().chain(actor_paths), xs, ys);
    let result = draw_figure(path, size, &[log], |root: &Area<'_>| -> DrawResult<()> {
        let mut chart = ChartBuilder::on(root)
            .caption("trajectory, obstacles, road and reference path", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(xs.0..xs.1, ys.0..ys.1)?;
        chart.configure_mesh().x_desc("x [m]").y_desc("y [m]").draw()?;
        draw_scene_lines(&mut chart, &series.lines)?;
        if let Some(reference) = series.reference {
            chart.draw_series(LineSeries::new(reference, PALETTE[2].stroke_width(2)))?;
        }
        // The vehicle's path first in the legend (and again over many road users' grey paths;
        // a few named ones, each in its colour, are drawn over it).
        let path_style = PALETTE[0].stroke_width(2);
        let vehicle_path = || LineSeries::new(series.path.iter().copied(), path_style);
        chart
            .draw_series(vehicle_path())?
            .label("vehicle's path")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], path_style));
        for (_, (centre, r)) in &obstacles {
            chart.draw_series(LineSeries::new(circle(*centre, *r), PALETTE[1].stroke_width(3)))?;
        }
        for (_, b) in &boxes {
            chart.draw_series(LineSeries::new(closed_box(**b), PALETTE[1].stroke_width(3)))?;
        }
        draw_actor_paths(&mut chart, series)?;
        if !named {
            chart.draw_series(vehicle_path())?;
        }
        if !series.actors.is_empty() {
            (chart.configure_series_labels())
                .position(legend_corner.clone())
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }
        Ok(())
    });
    result.map_err(|e| draw_error(path, e))
}

/// Half the side of the closest-approach plot's square window about the vehicle (m).
const CLOSEUP: f64 = 30.0;

/// The scene at the vehicle's closest approach to any obstacle, for a log with road users
/// (`/actors`): the road and lane lines, the vehicle's path and where it was then (its hull), and
/// every road user present then in its outline (a box at its logged heading, or a circle),
/// within ±[`CLOSEUP`] m of the vehicle; the closest one labelled with its clearance. None
/// without road users or a closest approach.
fn plot_closest_approach(series: &Series, log: &Path, path: &Path) -> Result<Option<PathBuf>, PlotError> {
    let (Some((clearance, time, name)), false) = (&series.closest, series.poses.is_empty()) else {
        return Ok(None);
    };
    let at = series.path_times.partition_point(|&s| s < time - 1e-9);
    let Some(&(px, py)) = series.path.get(at) else {
        return Ok(None);
    };
    // Each road user present at `time`: its outline there.
    let mut outlines: Vec<(&str, Vec<(f64, f64)>)> = Vec::new();
    for (actor, poses) in &series.poses {
        let k = poses.partition_point(|p| p.0 < time - 1e-9);
        let Some(&(_, x, y, heading, absent)) = poses.get(k).filter(|p| (p.0 - time).abs() < 1e-6) else {
            continue;
        };
        if absent || (x - px).abs() > 2.0 * CLOSEUP || (y - py).abs() > 2.0 * CLOSEUP {
            continue;
        }
        let outline = match (series.boxes.get(actor), series.obstacles.get(actor)) {
            (Some(&(_, size, _)), _) => closed_box(((x, y), size, heading)).collect(),
            (None, Some(&(_, r))) => circle((x, y), r).collect(),
            (None, None) => continue,
        };
        outlines.push((actor, outline));
    }
    let result = draw_figure(path, (800, 800), &[log], |root: &Area<'_>| -> DrawResult<()> {
        let caption = format!("closest approach: t = {time:.2} s, {name} at {clearance:.2} m");
        let mut chart = ChartBuilder::on(root)
            .caption(caption, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d((px - CLOSEUP)..(px + CLOSEUP), (py - CLOSEUP)..(py + CLOSEUP))?;
        chart.configure_mesh().x_desc("x [m]").y_desc("y [m]").draw()?;
        draw_scene_lines(&mut chart, &series.lines)?;
        let path_style = PALETTE[0].stroke_width(2);
        chart
            .draw_series(LineSeries::new(series.path.iter().copied(), path_style))?
            .label("vehicle's path")
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], path_style));
        if let Some(r) = series.hull_radius {
            chart.draw_series(LineSeries::new(circle((px, py), r), PALETTE[0].stroke_width(3)))?;
        }
        // The footprint as last drawn at or before `time` (the scene is drawn at the frame rate).
        let drawn = series.footprints.partition_point(|f| f.0 <= time + 1e-9);
        if let Some((_, outline)) = drawn.checked_sub(1).and_then(|k| series.footprints.get(k)) {
            chart.draw_series(LineSeries::new(closed_box(*outline), PALETTE[0].stroke_width(3)))?;
        }
        chart.draw_series([Cross::new((px, py), 6, PALETTE[0].stroke_width(3))])?;
        let user_style = PALETTE[1].stroke_width(2);
        for (k, (actor, outline)) in outlines.iter().enumerate() {
            let style = match *actor == name.as_str() {
                true => PALETTE[1].stroke_width(4),
                false => user_style,
            };
            let drawn = chart.draw_series(LineSeries::new(outline.iter().copied(), style))?;
            if k == 0 {
                drawn
                    .label("road users at that time")
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], user_style));
            }
            if *actor == name.as_str() {
                let (x, y) = outline[0];
                chart.draw_series([Text::new(actor.to_string(), (x, y), ("sans-serif", 16))])?;
            }
        }
        (chart.configure_series_labels())
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    });
    result.map_err(|e| draw_error(path, e))?;
    Ok(Some(path.to_path_buf()))
}

/// A box obstacle's outline: centre, (length, width), heading.
type BoxOutline = ((f64, f64), (f64, f64), f64);

/// A box's outline as a closed line: its corners and the first again.
fn closed_box(outline: BoxOutline) -> impl Iterator<Item = (f64, f64)> + Clone {
    let corners = box_corners(outline);
    (0..=4).map(move |k| corners[k % 4])
}

/// The corners of a box obstacle, in order around it.
fn box_corners(((x, y), (length, width), heading): BoxOutline) -> [(f64, f64); 4] {
    let (s, c) = heading.sin_cos();
    [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)].map(|(a, b)| {
        let (u, v) = (a * length / 2.0, b * width / 2.0);
        (x + u * c - v * s, y + u * s + v * c)
    })
}

/// Each moving obstacle's path from `/actors` (a line named in the legend) and the actor at
/// the vehicle's closest approach to it (its outline, dashed, and the vehicle's position then).
fn draw_actor_paths<DB: DrawingBackend>(
    chart: &mut ChartContext<
        '_,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    series: &Series,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    if series.actors.len() > NAMED_ROAD_USERS {
        // Many (a CommonRoad world's traffic): grey under one legend entry, the vehicle's path
        // over them.
        let style = ROAD_USER_GREY.stroke_width(1);
        for (k, samples) in series.actors.values().enumerate() {
            let drawn = chart.draw_series(LineSeries::new(samples.iter().map(|&(_, x, y)| (x, y)), style))?;
            if k == 0 {
                drawn
                    .label(format!("road users' paths ({})", series.actors.len()))
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], style));
            }
        }
        return Ok(());
    }
    for (k, (name, samples)) in series.actors.iter().enumerate() {
        let style = PALETTE[(3 + k) % PALETTE.len()].stroke_width(2);
        chart
            .draw_series(LineSeries::new(samples.iter().map(|&(_, x, y)| (x, y)), style))?
            .label(format!("{name} (moving obstacle)"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], style));
        // The closest approach: the vehicle's state at the actor's sample time.
        let closest = (samples.iter())
            .filter_map(|&(t, x, y)| {
                let i = series.path_times.partition_point(|&s| s < t - 1e-9);
                let &(px, py) = series.path.get(i).filter(|_| (series.path_times[i] - t).abs() < 1e-9)?;
                Some(((px - x).hypot(py - y), (x, y), (px, py)))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let (Some((_, (x, y), vehicle)), Some((_, r))) = (closest, series.obstacles.get(name)) else {
            continue;
        };
        let r = *r;
        let outline: Vec<(f64, f64)> = (0..=72)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 72.0;
                (x + r * a.cos(), y + r * a.sin())
            })
            .collect();
        for dash in outline.chunks(4).step_by(2) {
            chart.draw_series(LineSeries::new(dash.iter().copied(), style))?;
        }
        chart.draw_series([Cross::new(vehicle, 5, style)])?;
    }
    Ok(())
}

/// The y axis of h(t): obstacle barriers (4.81) are in m² (the label of a chart whose every
/// line is an obstacle's).
fn h_unit(obstacle_barriers: bool) -> String {
    if obstacle_barriers {
        "h = ‖p − c‖² − r²  [m²]".into()
    } else {
        "h".into()
    }
}

/// The y axis of an input channel, with its unit for the built-in vehicles' channels.
fn channel_unit(channel: &str) -> String {
    match channel {
        "steering" => "steering: tan δ  [–]".into(),
        "acceleration" => "acceleration  [m/s²]".into(),
        // The unicycle (2.36).
        "speed" => "speed  [m/s]".into(),
        "turn_rate" => "turn_rate  [rad/s]".into(),
        "force" | "u" => format!("{channel}  [N per kg = m/s²]"),
        other => other.to_string(),
    }
}

/// A closed circle as points.
fn circle(centre: (f64, f64), r: f64) -> impl Iterator<Item = (f64, f64)> + Clone {
    (0..=96).map(move |k| {
        let a = k as f64 * std::f64::consts::TAU / 96.0;
        (centre.0 + r * a.cos(), centre.1 + r * a.sin())
    })
}

/// One run of an overlay: its legend label and series.
struct Run {
    label: String,
    series: Series,
}

/// Overlays of several runs in `dir` (`overlay-trajectory.png`, `overlay-barriers.png`,
/// `overlay-inputs.png`): one line per run, named by its filter (run metadata; the file stem
/// is added when two runs would share a label), the obstacles with the barrier radius
/// r = obstacle + hull radius drawn around them, units on the axes. Returns the files written.
pub fn plot_overlay(logs: &[PathBuf], dir: &Path, format: Format) -> Result<Vec<PathBuf>, PlotError> {
    let ext = format.extension();
    register_embedded_font()?;
    let mut runs = Vec::new();
    for log in logs {
        let mut series = Series::default();
        read_run_file(log, &mut series)?;
        let stem = log.file_stem().and_then(|s| s.to_str()).unwrap_or("run").to_string();
        let label = series.label.clone().unwrap_or_else(|| stem.clone());
        runs.push((stem, Run { label, series }));
    }
    let labels: Vec<String> = runs.iter().map(|(_, r)| r.label.clone()).collect();
    let runs: Vec<Run> = runs
        .into_iter()
        .map(|(stem, mut run)| {
            if labels.iter().filter(|l| **l == run.label).count() > 1 {
                run.label = format!("{} ({stem})", run.label);
            }
            run
        })
        .collect();
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Draw {
        file: dir.display().to_string(),
        message: e.to_string(),
    })?;
    let inputs: Vec<&Path> = logs.iter().map(PathBuf::as_path).collect();
    let color = |i: usize| PALETTE[i % PALETTE.len()];
    let mut written = Vec::new();

    // Every run's events in its colour (the legend's); one every run shares, once in black.
    let mut events: Vec<Event> = Vec::new();
    let marks: Vec<Vec<Event>> = (runs.iter())
        .map(|r| r.series.marks(BLACK, &r.series.shown_barriers()))
        .collect();
    for (i, run_marks) in marks.iter().enumerate() {
        for (t, what, _) in run_marks {
            let shared = (marks.iter()).all(|m| m.iter().any(|e| e.0 == *t && &e.1 == what));
            match (shared, events.iter().any(|e| e.0 == *t && &e.1 == what)) {
                (true, true) => {}
                (true, false) => events.push((*t, what.clone(), BLACK)),
                (false, _) => events.push((*t, what.clone(), color(i))),
            }
        }
    }
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Trajectories, obstacles and the barrier radius around them.
    if runs.iter().any(|r| !r.series.path.is_empty()) {
        let path = dir.join(format!("overlay-trajectory.{ext}"));
        overlay_trajectories(&runs, &path, &inputs)?;
        written.push(path);
    }

    // h(t) of every run.
    if runs.iter().any(|r| !r.series.barriers.is_empty()) {
        let path = dir.join(format!("overlay-barriers.{ext}"));
        let mut lines: Vec<Line<'_>> = Vec::new();
        let mut all_obstacles = true;
        for (i, run) in runs.iter().enumerate() {
            let count = run.series.barriers.len();
            // A run of many barriers (road users) by the one that came closest.
            let drawn = match count > OVERLAY_BARRIERS {
                true => run.series.closest_barriers(1),
                false => run.series.barriers.keys().collect(),
            };
            for name in drawn {
                all_obstacles &= run.series.obstacle_barriers.contains(name);
                let label = match count {
                    1 => run.label.clone(),
                    2..=OVERLAY_BARRIERS => format!("{}: {name}", run.label),
                    _ => format!("{}: {name} (closest of {count})", run.label),
                };
                let points = run.series.barriers[name].as_slice();
                lines.push((label, points, color(i).stroke_width(3)));
            }
        }
        let unit = h_unit(all_obstacles && !lines.is_empty());
        let result = draw_figure(&path, (1200, 600), &inputs, |root: &Area<'_>| -> DrawResult<()> {
            h_chart(root, "barrier function h(t) (safe: h ≥ 0)", &unit, &lines, &events)?;
            Ok(())
        });
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }

    // The issued (filtered) input of every run, one panel per channel.
    let mut channels: Vec<String> = runs.iter().flat_map(|r| r.series.issued.keys().cloned()).collect();
    channels.sort();
    channels.dedup();
    if !channels.is_empty() {
        let path = dir.join(format!("overlay-inputs.{ext}"));
        let result = draw_figure(
            &path,
            (1200, 380 * channels.len() as u32),
            &inputs,
            |root: &Area<'_>| -> DrawResult<()> {
                for (area, channel) in root.split_evenly((channels.len(), 1)).iter().zip(&channels) {
                    let lines: Vec<Line<'_>> = runs
                        .iter()
                        .enumerate()
                        .filter_map(|(i, run)| {
                            let points = run.series.issued.get(channel)?;
                            Some((run.label.clone(), points.as_slice(), color(i).stroke_width(3)))
                        })
                        .collect();
                    time_chart(
                        area,
                        &format!("input {channel}, as issued by the filter (applied after its delay)"),
                        &channel_unit(channel),
                        &lines,
                        &events,
                    )?;
                }
                Ok(())
            },
        );
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }
    Ok(written)
}

/// The runs' trajectories over their obstacles, each ring of barrier radius r (obstacle plus
/// the run's hull) drawn once, into `path`.
fn overlay_trajectories(runs: &[Run], path: &Path, inputs: &[&Path]) -> Result<(), PlotError> {
    let color = |i: usize| PALETTE[i % PALETTE.len()];
    // Every run's obstacles with that run's hull (runs may move or resize an obstacle of
    // one name, or drive vehicles of other hulls): each distinct ring drawn once.
    let mut rings: Vec<((f64, f64), f64, f64)> = Vec::new();
    for r in runs.iter().filter(|r| !r.series.path.is_empty()) {
        let hull = r.series.hull_radius.unwrap_or(0.0);
        for &(centre, radius) in r.series.obstacles.values() {
            if !rings.contains(&(centre, radius, hull)) {
                rings.push((centre, radius, hull));
            }
        }
    }
    let same_ring = rings.windows(2).all(|w| (w[0].1, w[0].2) == (w[1].1, w[1].2));
    let extent = rings
        .iter()
        .flat_map(|&((x, y), r, hull)| [(x - r - hull, y - r - hull), (x + r + hull, y + r + hull)]);
    // Every run's road and half-space lines, each distinct one drawn once.
    let mut lines: BTreeMap<String, SceneLines> = BTreeMap::new();
    for (k, r) in runs.iter().enumerate().filter(|(_, r)| !r.series.path.is_empty()) {
        for (id, line) in &r.series.lines {
            if lines.get(id).is_some_and(|l| l != line) {
                lines.insert(format!("{id} ({k})"), line.clone());
            } else {
                lines.insert(id.clone(), line.clone());
            }
        }
    }
    let points = runs
        .iter()
        .flat_map(|r| r.series.path.iter().copied())
        .chain(extent)
        .chain(lines.values().flat_map(|l| l.points.iter().copied()));
    let ((x0, x1), (y0, y1)) = bounds(points);
    let aspect = plot_aspect((1200, 600), 14, 44, 60, 24);
    let (cx, cy, half) = (
        (x0 + x1) / 2.0,
        (y0 + y1) / 2.0,
        ((x1 - x0).max((y1 - y0) / aspect)) / 2.0,
    );
    let result = draw_figure(path, (1200, 600), inputs, |root: &Area<'_>| -> DrawResult<()> {
        let mut chart = ChartBuilder::on(root)
            .caption("trajectories", ("sans-serif", 24))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(60)
            .build_cartesian_2d((cx - half)..(cx + half), (cy - half * aspect)..(cy + half * aspect))?;
        chart
            .configure_mesh()
            .x_desc("x [m]")
            .y_desc("y [m]")
            .label_style(("sans-serif", 16))
            .draw()?;
        draw_scene_lines(&mut chart, &lines)?;
        let obstacle_color = RGBColor(120, 120, 120);
        for (k, &((x, y), r, hull)) in rings.iter().enumerate() {
            let drawn = chart.draw_series(std::iter::once(Polygon::new(
                circle((x, y), r).collect::<Vec<_>>(),
                obstacle_color.mix(0.35).filled(),
            )))?;
            if k == 0 {
                drawn.label("obstacle").legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 18, y + 5)], obstacle_color.mix(0.35).filled())
                });
            }
            if hull > 0.0 {
                let drawn = chart.draw_series(DashedLineSeries::new(
                    circle((x, y), r + hull),
                    8,
                    6,
                    BLACK.stroke_width(2),
                ))?;
                if k == 0 {
                    let label = if same_ring {
                        format!(
                            "barrier radius r = obstacle {r:.2} m + hull {hull:.2} m = {:.2} m",
                            r + hull
                        )
                    } else {
                        "barrier radius r = obstacle + the run's hull radius".to_string()
                    };
                    drawn
                        .label(label)
                        .legend(|(x, y)| PathElement::new([(x, y), (x + 8, y), (x + 12, y), (x + 18, y)], BLACK));
                }
            }
        }
        // Runs that do not move in a plane have no path: not in this plot's legend.
        for (i, run) in runs.iter().enumerate().filter(|(_, r)| !r.series.path.is_empty()) {
            let style = color(i).stroke_width(3);
            chart
                .draw_series(LineSeries::new(run.series.path.iter().copied(), style))?
                .label(run.label.clone())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], style));
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 16))
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    });
    result.map_err(|e| draw_error(path, e))
}

/// One run of a sweep as the sweep plot reads it: its swept values and its metrics.
pub struct SweepPoint<'a> {
    pub parameters: &'a BTreeMap<String, String>,
    pub metrics: Option<&'a crate::analyze::FlatMetrics>,
}

struct SweepRows<'a> {
    name: &'a str,
    parameters: &'a [String],
    runs: &'a [SweepPoint<'a>],
}

/// The corner of the plot area (x and y ranges) with the fewest points within a third of the
/// width and height of it: where the legend hides the least.
fn emptiest_corner(
    points: impl Iterator<Item = (f64, f64)>,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> SeriesLabelPosition {
    // Lower left, lower right, upper left, upper right.
    let mut counts = [0usize; 4];
    for (x, y) in points {
        let (u, v) = ((x - x0) / (x1 - x0), (y - y0) / (y1 - y0));
        let (left, right, low, high) = (u < 0.4, u > 0.6, v < 0.4, v > 0.6);
        counts[0] += usize::from(left && low);
        counts[1] += usize::from(right && low);
        counts[2] += usize::from(left && high);
        counts[3] += usize::from(right && high);
    }
    let corners = [
        SeriesLabelPosition::LowerLeft,
        SeriesLabelPosition::LowerRight,
        SeriesLabelPosition::UpperLeft,
        SeriesLabelPosition::UpperRight,
    ];
    let best = (0..4).min_by_key(|&i| counts[i]).unwrap_or(0);
    corners[best].clone()
}

/// The label a swept `filter` table's kind registers (with its equation number, completed by
/// its parameters), if the value is such a table of a registered kind.
fn swept_filter_label(value: &str) -> Option<String> {
    let document: toml::Table = format!("filter = {value}").parse().ok()?;
    let mut params = document.get("filter")?.as_table()?.clone();
    let kind = params.remove("kind")?.as_str()?.to_string();
    let registry = crate::registry::registry();
    let params = registry.check_filter(&kind, &params).ok()?;
    registry.describe_filter(&kind, &params).ok().map(|d| d.label)
}

/// (x, y, collided) of one line of a sweep plot.
type SweepLine = Vec<(f64, f64, bool)>;

/// The lines of a sweep plot of `metric` against `key`: one per combination of the other swept
/// values, named by them (a swept filter table by its equation number; two lines whose names
/// agree, such as two gains of one filter, by their values).
fn sweep_lines(parameters: &[String], runs: &[SweepPoint<'_>], key: &str, metric: &str) -> BTreeMap<String, SweepLine> {
    use crate::analyze::Cell;
    let mut lines: BTreeMap<String, (String, SweepLine)> = BTreeMap::new();
    for run in runs {
        let Some(metrics) = run.metrics else { continue };
        let x = run.parameters.get(key).and_then(|v| v.trim().parse::<f64>().ok());
        let y = match metrics.cell(metric) {
            Cell::Num(v) => v,
            Cell::Int(v) => v.map(|n| n as f64),
            Cell::Text(_) | Cell::Bool(_) => None,
        };
        let (Some(x), Some(y)) = (x, y) else { continue };
        let (mut values, mut names) = (Vec::new(), Vec::new());
        for p in parameters.iter().filter(|p| *p != key) {
            let value = run.parameters.get(p).map_or("", String::as_str);
            names.push(match swept_filter_label(value) {
                Some(label) if p == "filter" => label,
                _ => format!("{p} = {value}"),
            });
            values.push(format!("{p} = {value}"));
        }
        let line = lines
            .entry(values.join(", "))
            .or_insert_with(|| (names.join(", "), Vec::new()));
        line.1.push((x, y, metrics.number("collision_time").is_some()));
    }
    let mut named = BTreeMap::<String, usize>::new();
    for (name, _) in lines.values() {
        *named.entry(name.clone()).or_default() += 1;
    }
    lines
        .into_iter()
        .map(|(values, (name, points))| {
            let label = if named[&name] > 1 { values } else { name };
            (label, points)
        })
        .collect()
}

/// A metric of a sweep's summary (`summary.json`, or a sweep directory holding one) against
/// one swept key, into `out` (PNG): one line per combination of the other swept keys, runs that
/// collided marked with a cross. The metric is a numeric field of the summary's metrics
/// (`min_h`, `min_clearance`, `max_input_rate.steering`, … docs/metrics.md).
///
/// `file` names the summary in messages, `name` is the sweep's name; `swept` are its swept keys and `runs` its rows (the
/// caller reads the summary: plotting never reaches the code that runs sweeps).
pub fn plot_sweep(
    file: &Path,
    name: &str,
    swept: &[String],
    runs: &[SweepPoint<'_>],
    key: &str,
    metric: &str,
    out: &Path,
) -> Result<PathBuf, PlotError> {
    register_embedded_font()?;
    let s = SweepRows {
        name,
        parameters: swept,
        runs,
    };
    if !s.parameters.iter().any(|p| p == key) {
        return Err(PlotError::Sweep(format!(
            "{}: `{key}` is not a swept key (swept: {})",
            file.display(),
            s.parameters.join(", ")
        )));
    }
    use crate::analyze::FlatMetrics;
    // The numeric columns of the summary's metrics, per-channel ones included.
    let numeric: Vec<String> = FlatMetrics::columns(s.runs.iter().filter_map(|r| r.metrics))
        .into_iter()
        .filter(|c| FlatMetrics::is_numeric_column(c))
        .collect();
    let known_metric = numeric.iter().any(|c| c == metric);
    let mut groups = sweep_lines(s.parameters, s.runs, key, metric);
    if !known_metric {
        return Err(PlotError::Sweep(format!(
            "{}: no metric `{metric}` in the summary (numeric metrics: {})",
            file.display(),
            numeric.join(", ")
        )));
    }
    if groups.is_empty() {
        return Err(PlotError::Sweep(format!(
            "{}: no run has both a numeric `{key}` and a value of `{metric}`",
            file.display()
        )));
    }
    for points in groups.values_mut() {
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    let ((x0, x1), (mut y0, mut y1)) = bounds(groups.values().flatten().map(|p| (p.0, p.1)));
    let zero = y0 < 0.0 && y1 > 0.0 || metric.contains("min_h") || metric.contains("clearance");
    if zero {
        y0 = y0.min(0.0);
        y1 = y1.max(0.0);
    }
    let unit = if key.starts_with("delays.") || key.starts_with("assumed_delays.") {
        format!("{key}  [s]")
    } else {
        key.to_string()
    };
    let legend_corner = emptiest_corner(groups.values().flatten().map(|p| (p.0, p.1)), (x0, x1), (y0, y1));
    // The declared unit (docs/metrics.md); a count's unit is its name.
    let y_desc = match crate::metrics::Metric::unit_of_column(metric) {
        Some("" | "1" | "steps" | "ticks" | "predictions") | None => metric.to_string(),
        Some(unit) => format!("{metric}  [{unit}]"),
    };
    let result = draw_figure(out, (1000, 560), &[file], |root: &Area<'_>| -> DrawResult<()> {
        let mut chart = ChartBuilder::on(root)
            .caption(format!("{metric} against {key} ({})", s.name), ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(unit.as_str())
            .y_desc(y_desc.as_str())
            .draw()?;
        if zero {
            chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.stroke_width(1)))?;
        }
        for (i, (group, points)) in groups.iter().enumerate() {
            let c = PALETTE[i % PALETTE.len()];
            let style = c.stroke_width(3);
            let line = chart.draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.1)), style))?;
            if !group.is_empty() {
                line.label(group.clone())
                    .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], style));
            }
            chart.draw_series(
                points
                    .iter()
                    .filter(|p| !p.2)
                    .map(|p| Circle::new((p.0, p.1), 5, c.filled())),
            )?;
            chart.draw_series(
                points
                    .iter()
                    .filter(|p| p.2)
                    .map(|p| Cross::new((p.0, p.1), 7, RED.stroke_width(3))),
            )?;
        }
        chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
            .label("collision")
            .legend(|(x, y)| Cross::new((x + 9, y), 6, RED.stroke_width(3)));
        chart
            .configure_series_labels()
            .position(legend_corner)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    });
    result.map_err(|e| draw_error(out, e))?;
    Ok(out.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run's log as the plots read it: barrier `name{k}` with h = 100 k + 1 (m²) and
    /// clearance 30 − k (m) at t = 0 and 1, and one appearance event per barrier at `appear`.
    fn many_barriers(count: usize, appear: f64) -> Series {
        let mut series = Series::default();
        for k in 0..count {
            let name = format!("cr_{k:02}");
            let h = 100.0 * k as f64 + 1.0;
            series.barriers.insert(name.clone(), vec![(0.0, h), (1.0, h)]);
            series.least_clearance.insert(name.clone(), 30.0 - k as f64);
            series.events.push((appear, format!("{name} appears"), Some(name)));
        }
        series
    }

    /// Up to eight barriers are all drawn; of more, the eight of least clearance (not of least
    /// h: m² and m do not compare), in name order, and only their appearances are marked.
    #[test]
    fn an_h_chart_of_many_barriers_draws_the_eight_that_came_closest() {
        let few = many_barriers(MAX_H_LINES, 0.5);
        assert_eq!(few.shown_barriers().len(), MAX_H_LINES);
        let many = many_barriers(28, 0.5);
        let shown = many.shown_barriers();
        let names: Vec<&str> = shown.iter().map(|s| s.as_str()).collect();
        assert_eq!(
            names,
            ["cr_20", "cr_21", "cr_22", "cr_23", "cr_24", "cr_25", "cr_26", "cr_27"]
        );
        assert_eq!(many.closest_barriers(1), [&"cr_27".to_string()]);
        let marks = many.marks(BLACK, &shown);
        assert_eq!(marks.len(), MAX_H_LINES, "{marks:?}");
        assert!(marks
            .iter()
            .all(|m| names.iter().any(|n| m.1 == format!("{n} appears"))));
        // A barrier with no clearance (NaN throughout) comes after every one with.
        let mut without = many_barriers(9, 0.5);
        without.least_clearance.insert("cr_08".into(), f64::NAN);
        let shown = without.shown_barriers();
        assert!(!shown.iter().any(|s| s.as_str() == "cr_08"), "{shown:?}");
    }

    /// Road users there from the first sample do not appear; a collision is marked whoever it
    /// is with.
    #[test]
    fn appearances_at_the_start_are_not_marked() {
        let mut series = many_barriers(3, 0.0);
        series.events.push((0.7, "collision (cr_01)".into(), None));
        let shown = series.shown_barriers();
        let marks = series.marks(BLACK, &shown);
        assert_eq!(marks.len(), 1, "{marks:?}");
        assert_eq!((marks[0].0, marks[0].1.as_str()), (0.7, "collision (cr_01)"));
    }

    /// A trajectory figure takes the data's shape (its plotting area that of the data, within
    /// its least and largest height), a long scene the least height, one without extent the
    /// default.
    #[test]
    fn a_trajectory_figure_is_as_tall_as_its_data_needs() {
        let (w, h) = trajectory_size((100.0, 80.0));
        assert_eq!(w, 1000);
        let aspect = plot_aspect((w, h), 12, 36, 50, 22);
        assert!((aspect - 0.8).abs() < 0.002, "{aspect}");
        assert_eq!(trajectory_size((400.0, 10.0)), (1000, 400));
        assert_eq!(trajectory_size((10.0, 400.0)), (1000, 1000));
        assert_eq!(trajectory_size((0.0, 0.0)), (1000, 500));
    }

    /// A NaN is a gap: the runs around it are drawn, no point of it.
    #[test]
    fn a_series_is_drawn_in_its_runs_of_values() {
        let nan = f64::NAN;
        let points = [(0.0, nan), (1.0, 1.0), (2.0, 2.0), (3.0, nan), (4.0, nan), (5.0, 5.0)];
        let runs: Vec<Vec<f64>> = super::finite_runs(&points)
            .map(|r| r.iter().map(|p| p.0).collect())
            .collect();
        assert_eq!(runs, [vec![1.0, 2.0], vec![5.0]]);
    }

    /// A 4 × 2 box turned by 90° spans 2 in x and 4 in y about its centre.
    #[test]
    fn box_corners_turn_with_the_heading() {
        let corners = super::box_corners(((10.0, 5.0), (4.0, 2.0), std::f64::consts::FRAC_PI_2));
        let xs: Vec<f64> = corners.iter().map(|c| c.0).collect();
        let ys: Vec<f64> = corners.iter().map(|c| c.1).collect();
        let span = |v: &[f64]| v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min);
        assert!(
            (span(&xs) - 2.0).abs() < 1e-12 && (span(&ys) - 4.0).abs() < 1e-12,
            "{corners:?}"
        );
        assert!((xs.iter().sum::<f64>() / 4.0 - 10.0).abs() < 1e-12);
    }

    #[test]
    fn the_legend_goes_where_the_points_are_not() {
        use plotters::chart::SeriesLabelPosition as P;
        // A line from the upper left to the lower right leaves the other two corners free.
        let falling = (0..=10).map(|i| (f64::from(i), 10.0 - f64::from(i)));
        let corner = super::emptiest_corner(falling, (0.0, 10.0), (0.0, 10.0));
        assert!(matches!(corner, P::LowerLeft | P::UpperRight), "{corner:?}");
        let rising = (0..=10).map(|i| (f64::from(i), f64::from(i)));
        let corner = super::emptiest_corner(rising, (0.0, 10.0), (0.0, 10.0));
        assert!(matches!(corner, P::LowerRight | P::UpperLeft), "{corner:?}");
    }

    #[test]
    fn two_gains_of_one_filter_are_two_lines_named_by_their_values() {
        use crate::analyze::FlatMetrics;
        let filters = ["{kind='cbf_qp', l0=1.0, l1=3.0}", "{kind='cbf_qp', l0=4.0, l1=4.0}"];
        let swept = vec!["delays.steering".to_string(), "filter".to_string()];
        let mut rows = Vec::new();
        for (i, filter) in filters.iter().enumerate() {
            for delay in ["0.0", "0.2"] {
                let parameters = std::collections::BTreeMap::from([
                    ("delays.steering".to_string(), delay.to_string()),
                    ("filter".to_string(), filter.to_string()),
                ]);
                let mut metrics = FlatMetrics::default();
                metrics.set("min_h", crate::analyze::Cell::Num(Some(i as f64)));
                rows.push((parameters, metrics));
            }
        }
        let points: Vec<super::SweepPoint> = rows
            .iter()
            .map(|(parameters, metrics)| super::SweepPoint {
                parameters,
                metrics: Some(metrics),
            })
            .collect();
        let lines = super::sweep_lines(&swept, &points, "delays.steering", "min_h");
        assert_eq!(lines.len(), 2, "{lines:?}");
        for (filter, (label, points)) in filters.iter().zip(&lines) {
            assert!(label.contains(filter), "{label}");
            assert_eq!(points.len(), 2, "{label}");
        }
        // One gain per filter kind: the line is named by the filter's equation numbers.
        let one = super::sweep_lines(&swept, &points[..2], "delays.steering", "min_h");
        assert_eq!(one.keys().collect::<Vec<_>>(), ["delay-free CBF-QP (4.9)–(4.11)"]);
    }
}
