//! PNG plots of a run, from its MCAP log alone (`mjsafe analyze --plot DIR`):
//! - `<name>-barriers.png`: h(t) of every barrier, with the zero line;
//! - `<name>-inputs.png`: issued vs applied input per channel;
//! - `<name>-trajectory.png`: the planar path with the obstacles and the reference path.
//!
//! Text is drawn with DejaVu Sans (Debian's `fonts-dejavu-core`, installed by
//! scripts/setup.sh), loaded at run time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
    #[error("no font for the plot text: {path} is missing (Debian package fonts-dejavu-core)")]
    Font { path: String },
    #[error("writing {file}: {message}")]
    Draw { file: String, message: String },
}

/// The font the plots use.
pub const FONT_PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

/// What the plots need from a log.
#[derive(Default)]
struct Series {
    barriers: BTreeMap<String, Vec<(f64, f64)>>,
    issued: BTreeMap<String, Vec<(f64, f64)>>,
    applied: BTreeMap<String, Vec<(f64, f64)>>,
    path: Vec<(f64, f64)>,
    /// (name, centre, radius) of the obstacles, from `/scene`.
    obstacles: BTreeMap<String, ((f64, f64), f64)>,
    reference: Option<[(f64, f64); 2]>,
    /// The planar position the vehicle declared in the run metadata (None: not declared).
    declared_planar: Option<Option<[usize; 2]>>,
}

impl RunVisitor for Series {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        if name == RUN_METADATA {
            self.declared_planar = declared_planar_position(entries);
        }
        Ok(())
    }

    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        match message.record()? {
            Record::State(m) => {
                if let Some([i, j]) = planar_position_of(self.declared_planar, &m.names) {
                    self.path.push((m.values[i], m.values[j]));
                }
            }
            Record::Barrier(m) => {
                for b in m.barriers {
                    self.barriers.entry(b.name).or_default().push((m.time, b.h));
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
            Record::Scene(_, m) => {
                for e in m.entities {
                    if e.id == "reference_path" {
                        if let Some(line) = e.lines.first() {
                            if line.points.len() >= 2 {
                                let (a, b) = (&line.points[0], &line.points[line.points.len() - 1]);
                                self.reference = Some([(a.x, a.y), (b.x, b.y)]);
                            }
                        }
                    } else if e.id != "vehicle" && !e.id.starts_with("trail") {
                        if let Some(c) = e.cylinders.first() {
                            let (pose, size) = (c.pose.unwrap_or_default(), c.size.unwrap_or_default());
                            let p = pose.position.unwrap_or_default();
                            self.obstacles.insert(e.id.clone(), ((p.x, p.y), size.x / 2.0));
                        }
                    }
                }
            }
            _ => {}
        }
        Ok(())
    }
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

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
        let span = (hi - lo).max(1e-9);
        (lo - 0.05 * span, hi + 0.05 * span)
    };
    (pad(fold(|p| p.0)), pad(fold(|p| p.1)))
}

type DrawResult<T> = Result<T, Box<dyn std::error::Error>>;

/// One line of a chart: legend label, (t, value) points, style.
type Line<'a> = (String, &'a [(f64, f64)], ShapeStyle);

/// Time-series chart of named series into `area`.
fn time_chart(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    title: &str,
    series: &[Line<'_>],
    zero_line: bool,
) -> DrawResult<()> {
    let all = series.iter().flat_map(|(_, s, _)| s.iter().copied());
    let ((x0, x1), (mut y0, mut y1)) = bounds(all);
    if zero_line {
        y0 = y0.min(0.0);
        y1 = y1.max(0.0);
    }
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .x_desc("t [s]")
        .light_line_style(WHITE.mix(0.0))
        .draw()?;
    if zero_line {
        chart.draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.stroke_width(2)))?;
    }
    for (name, points, style) in series {
        let style = *style;
        chart
            .draw_series(LineSeries::new(points.iter().copied(), style))?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// The start of every PNG file: an existing file that does not start so is never replaced.
const PNG_MAGIC: &[u8] = b"\x89PNG";

/// Draws a PNG into a hidden `.partial.png` sibling (plotters picks the format by extension)
/// and renames it to `path` when complete: never a half-drawn plot under the final name, never
/// over a non-regular file, the log itself or a file that is not a PNG.
fn draw_png(
    path: &Path,
    log: &Path,
    draw: impl FnOnce(&Path) -> DrawResult<()>,
) -> Result<(), Box<dyn std::error::Error>> {
    crate::files::check_output(path, "PNG plot", crate::files::Replace::IfStartsWith(PNG_MAGIC), &[log])?;
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("plot.png");
    let partial = path.with_file_name(format!(".{}.partial.png", name.trim_end_matches(".png")));
    let drawn = draw(&partial).and_then(|()| std::fs::rename(&partial, path).map_err(|e| e.into()));
    if drawn.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    drawn
}

/// Makes the plot font plotters' `sans-serif` (read once per process).
pub fn register_plot_font() -> Result<(), PlotError> {
    static FONT: std::sync::OnceLock<Option<&'static [u8]>> = std::sync::OnceLock::new();
    let font = FONT.get_or_init(|| std::fs::read(FONT_PATH).ok().map(|f| &*Box::leak(f.into_boxed_slice())));
    let font = font.ok_or_else(|| PlotError::Font { path: FONT_PATH.into() })?;
    register_font("sans-serif", FontStyle::Normal, font).map_err(|_| PlotError::Font { path: FONT_PATH.into() })
}

/// Writes the plots of `log` into `dir`; returns the files written.
pub fn plot_log(log: &Path, dir: &Path) -> Result<Vec<PathBuf>, PlotError> {
    register_plot_font()?;
    // No plot of part of a run shown as if it were the run: damage is an error.
    let mut series = Series::default();
    read_run_file(log, &mut series)?;
    std::fs::create_dir_all(dir).map_err(|e| PlotError::Draw {
        file: dir.display().to_string(),
        message: e.to_string(),
    })?;
    let stem = log.file_stem().and_then(|s| s.to_str()).unwrap_or("run").to_string();
    let mut written = Vec::new();
    let draw_error = |path: &Path, e: Box<dyn std::error::Error>| {
        let file = path.display().to_string();
        // A refused target's message already starts with the path.
        let message = e.to_string();
        let message = message
            .strip_prefix(&format!("{file}: "))
            .unwrap_or(&message)
            .to_string();
        PlotError::Draw { file, message }
    };

    if !series.barriers.is_empty() {
        let path = dir.join(format!("{stem}-barriers.png"));
        let lines: Vec<Line<'_>> = series
            .barriers
            .iter()
            .enumerate()
            .map(|(i, (name, s))| {
                (
                    format!("h {name}"),
                    s.as_slice(),
                    PALETTE[i % PALETTE.len()].stroke_width(2),
                )
            })
            .collect();
        let result = draw_png(&path, log, |partial: &Path| -> DrawResult<()> {
            let root = BitMapBackend::new(partial, (1000, 500)).into_drawing_area();
            root.fill(&WHITE)?;
            time_chart(&root, "barrier functions h(t) (safe: h >= 0)", &lines, true)?;
            root.present()?;
            Ok(())
        });
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }

    if !series.issued.is_empty() {
        let path = dir.join(format!("{stem}-inputs.png"));
        let channels: Vec<&String> = series.issued.keys().collect();
        let result = draw_png(&path, log, |partial: &Path| -> DrawResult<()> {
            let root = BitMapBackend::new(partial, (1000, 320 * channels.len() as u32)).into_drawing_area();
            root.fill(&WHITE)?;
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
                time_chart(area, &format!("{channel}: issued vs applied (delayed)"), &lines, false)?;
            }
            root.present()?;
            Ok(())
        });
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }

    if !series.path.is_empty() {
        let path = dir.join(format!("{stem}-trajectory.png"));
        let circles = series
            .obstacles
            .values()
            .flat_map(|((x, y), r)| [(x - r, y - r), (x + r, y + r)]);
        let ((x0, x1), (y0, y1)) = bounds(series.path.iter().copied().chain(circles));
        // Equal axis scales: widen the shorter span.
        let (cx, cy, half) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0, ((x1 - x0).max((y1 - y0) * 2.0)) / 2.0);
        let result = draw_png(&path, log, |partial: &Path| -> DrawResult<()> {
            let root = BitMapBackend::new(partial, (1000, 500)).into_drawing_area();
            root.fill(&WHITE)?;
            let mut chart = ChartBuilder::on(&root)
                .caption("trajectory, obstacles and reference path", ("sans-serif", 22))
                .margin(12)
                .x_label_area_size(36)
                .y_label_area_size(50)
                .build_cartesian_2d((cx - half)..(cx + half), (cy - half / 2.0)..(cy + half / 2.0))?;
            chart.configure_mesh().x_desc("x [m]").y_desc("y [m]").draw()?;
            if let Some(reference) = series.reference {
                chart.draw_series(LineSeries::new(reference, PALETTE[2].stroke_width(2)))?;
            }
            for ((x, y), r) in series.obstacles.values() {
                let outline = (0..=72).map(|k| {
                    let a = k as f64 * std::f64::consts::TAU / 72.0;
                    (x + r * a.cos(), y + r * a.sin())
                });
                chart.draw_series(LineSeries::new(outline, PALETTE[1].stroke_width(3)))?;
            }
            chart.draw_series(LineSeries::new(series.path.iter().copied(), PALETTE[0].stroke_width(2)))?;
            root.present()?;
            Ok(())
        });
        result.map_err(|e| draw_error(&path, e))?;
        written.push(path);
    }
    Ok(written)
}
