//! `report.html`: the scorecard as one self-contained page (no script, no network: the styles
//! and the SVG figures inline, the system's sans-serif font). The summary table with the
//! Euro NCAP colour bands, failing items first; then each item with its figures and the
//! commands that reproduce it. One colour per filter throughout (Okabe–Ito, readable with
//! colour blindness).

use std::fmt::Write;

use super::{ItemCard, Scorecard, Scoring, Status};
use crate::ncap::Colour;
use crate::plot::{symlog, tick_label};

/// One colour per filter column (Okabe–Ito), repeated past eight.
const FILTER_COLOURS: [&str; 8] = [
    "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442",
];

/// Euro NCAP's band colours, as its rating sheets draw them.
fn band(c: Colour) -> &'static str {
    match c {
        Colour::Green => "#38a800",
        Colour::Yellow => "#ffd700",
        Colour::Orange => "#ff9100",
        Colour::Brown => "#8b5a2b",
        Colour::Red => "#e00000",
    }
}

fn filter_colour(column: usize) -> &'static str {
    FILTER_COLOURS[column % FILTER_COLOURS.len()]
}

/// Escapes text for HTML and SVG.
fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Whether an item fails for some filter: a fail or an error, or Euro NCAP points lost.
fn failing(item: &ItemCard) -> bool {
    item.cells.iter().any(|c| {
        matches!(c.status, Status::Fail | Status::Error)
            || (c.status == Status::Scored && c.score.zip(c.max).is_some_and(|(s, m)| s < m))
    })
}

fn status_class(status: Status) -> &'static str {
    match status {
        Status::Pass => "pass",
        Status::Fail => "fail",
        Status::Scored => "scored",
        Status::NotApplicable => "na",
        Status::Error => "error",
        Status::NotRun => "notrun",
    }
}

const STYLE: &str = "body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif;margin:2em;color:#222;max-width:1400px}
table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;padding:4px 8px;text-align:left;vertical-align:top;font-size:14px}
th{background:#eee}td.pass{background:#dff0d8}td.fail{background:#f8d7da}td.error{background:#fce5cd}td.na,td.notrun{background:#eee;color:#666}
td.scored{background:#fff}.chip{display:inline-block;width:10px;height:10px;margin:0 2px 0 6px;border:1px solid #555}
code{font-size:12px;background:#f4f4f4;padding:2px 4px;word-break:break-all}figure{display:inline-block;margin:0.5em 1em 0.5em 0}
figcaption{font-size:13px;color:#444;max-width:640px}.key{display:inline-block;width:14px;height:4px;margin:0 4px 3px 10px}
h2{margin-top:2em;border-bottom:1px solid #ccc}.reason{color:#555;font-size:12px}";

/// The whole page.
pub fn html(card: &Scorecard) -> String {
    let mut page = String::new();
    let title = format!("mjsafe scorecard: {}", card.suite.name);
    let _ = write!(
        page,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style></head><body>\n",
        esc(&title)
    );
    let _ = writeln!(page, "<h1>{}</h1>", esc(&title));
    let _ = writeln!(
        page,
        "<p>Suite <code>{}</code> (FNV-1a {}), mjsafe {}, {} runs in {:.1} s{}.</p>",
        esc(&card.suite.file),
        esc(&card.suite.fnv1a),
        esc(&card.mjsafe_version),
        card.runs,
        card.wall_seconds,
        if card.complete {
            ""
        } else {
            " &mdash; <b>incomplete: interrupted</b>"
        }
    );
    page.push_str("<p>Filters:");
    for (column, f) in card.filters.iter().enumerate() {
        let _ = write!(
            page,
            "<span class=\"key\" style=\"background:{}\"></span><b>{}</b>{} <code>{}</code>",
            filter_colour(column),
            esc(&f.name),
            f.label.as_ref().map_or(String::new(), |l| format!(" ({})", esc(l))),
            esc(&f.spec)
        );
    }
    page.push_str("</p>\n");
    summary(&mut page, card);
    for item in card
        .items
        .iter()
        .filter(|i| failing(i))
        .chain(card.items.iter().filter(|i| !failing(i)))
    {
        item_section(&mut page, card, item);
    }
    page.push_str("</body></html>\n");
    page
}

/// The summary table: one row per item (failing first), one column per filter.
fn summary(page: &mut String, card: &Scorecard) {
    page.push_str(
        "<h2 id=\"summary\">Summary</h2>\n<table id=\"summary-table\"><thead><tr><th>item</th><th>section</th>",
    );
    for (column, f) in card.filters.iter().enumerate() {
        let _ = write!(
            page,
            "<th class=\"filter\"><span class=\"key\" style=\"background:{}\"></span>{}</th>",
            filter_colour(column),
            esc(&f.name)
        );
    }
    page.push_str("</tr></thead><tbody>\n");
    let ordered = card
        .items
        .iter()
        .filter(|i| failing(i))
        .chain(card.items.iter().filter(|i| !failing(i)));
    for item in ordered {
        let _ = write!(
            page,
            "<tr><td><a href=\"#item-{}\">{}</a></td><td>{}</td>",
            esc(&item.name),
            esc(&item.name),
            esc(&item.section)
        );
        for cell in &item.cells {
            let _ = write!(
                page,
                "<td class=\"{}\">{}",
                status_class(cell.status),
                esc(&cell.detail)
            );
            if !cell.points.is_empty() {
                page.push_str("<br>");
                for colour in [
                    Colour::Green,
                    Colour::Yellow,
                    Colour::Orange,
                    Colour::Brown,
                    Colour::Red,
                ] {
                    let n = cell.points.iter().filter(|p| p.colour == Some(colour)).count();
                    let _ = write!(
                        page,
                        "<span class=\"chip\" style=\"background:{}\" title=\"{colour}\"></span>{n}",
                        band(colour)
                    );
                }
            }
            let shown = cell
                .reason
                .as_ref()
                .filter(|r| cell.status != Status::Pass && !cell.detail.contains(r.as_str()));
            if let Some(r) = shown {
                let _ = write!(
                    page,
                    "<div class=\"reason\">{}</div>",
                    esc(r.lines().next().unwrap_or_default())
                );
            }
            page.push_str("</td>");
        }
        page.push_str("</tr>\n");
    }
    if card.ncap.iter().any(Option::is_some) {
        page.push_str("<tr><td><b>Euro NCAP total</b></td><td></td>");
        for total in &card.ncap {
            match total {
                Some(t) => {
                    let _ = write!(
                        page,
                        "<td>{:.3} / {:.3} points, gate {}{}</td>",
                        t.score,
                        t.max,
                        match t.gate_passed {
                            Some(true) => "passed",
                            Some(false) => "<b>failed</b>",
                            None => "not evaluated",
                        },
                        t.gate_reason
                            .as_ref()
                            .map_or(String::new(), |r| format!("<div class=\"reason\">{}</div>", esc(r)))
                    );
                }
                None => page.push_str("<td>-</td>"),
            }
        }
        page.push_str("</tr>\n");
    }
    page.push_str("<tr><td><b>overall</b></td><td></td>");
    for o in &card.overall {
        let _ = write!(
            page,
            "<td>{}</td>",
            o.map_or("-".into(), |o| format!("{:.1} %", 100.0 * o))
        );
    }
    page.push_str("</tr>\n</tbody></table>\n<p class=\"reason\">Overall: the mean over items of the score as a fraction of its maximum (pass 1, fail 0, a Euro NCAP test its points over its weight); margins without a threshold are left out.</p>\n");
}

fn item_section(page: &mut String, card: &Scorecard, item: &ItemCard) {
    let _ = writeln!(
        page,
        "<h2 id=\"item-{}\">{} <small>({})</small></h2>",
        esc(&item.name),
        esc(&item.name),
        esc(&item.section)
    );
    if let Some(claim) = &item.claim {
        let _ = writeln!(page, "<p><i>{}</i></p>", esc(claim));
    }
    let _ = writeln!(page, "<p>Scenario <code>{}</code></p>", esc(&item.scenario));
    let figure = match &item.scoring {
        Scoring::Ncap { .. } => ncap_figures(card, item),
        Scoring::Margin { key, unit, .. } => vec![margin_figure(card, item, key, unit)],
        Scoring::Falsify {
            objective, threshold, ..
        } => vec![search_figure(card, item, objective, *threshold)],
        Scoring::Clear | Scoring::Progress { .. } => vec![figure_bars(card, item)],
    };
    for f in figure.into_iter().flatten() {
        page.push_str(&f);
    }
    page.push_str("<table><tr><th>filter</th><th>result</th><th>reproduce</th></tr>\n");
    for (column, cell) in item.cells.iter().enumerate() {
        let _ = writeln!(
            page,
            "<tr><td><span class=\"key\" style=\"background:{}\"></span>{}</td><td class=\"{}\">{}{}</td><td><code>{}</code>{}</td></tr>",
            filter_colour(column),
            esc(&card.filters[column].name),
            status_class(cell.status),
            esc(&cell.detail),
            cell.reason
                .as_ref()
                .filter(|r| !cell.detail.contains(r.as_str()))
                .map_or(String::new(), |r| format!("<div class=\"reason\">{}</div>", esc(r))),
            esc(&cell.command),
            cell.log
                .as_ref()
                .map_or(String::new(), |l| format!("<br>log: <a href=\"{}\">{}</a>", esc(l), esc(l)))
        );
    }
    page.push_str("</table>\n");
}

/// An SVG figure with its caption.
fn figure(svg: String, caption: &str) -> String {
    format!("<figure>{svg}<figcaption>{}</figcaption></figure>\n", esc(caption))
}

fn svg_open(width: f64, height: f64, label: &str) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" viewBox=\"0 0 {width} {height}\" role=\"img\" aria-label=\"{}\" font-family=\"system-ui,'DejaVu Sans',sans-serif\" font-size=\"12\">",
        esc(label)
    )
}

/// A Euro NCAP test's grid per filter: the car's speed down, the impact location across, each
/// point in its colour band with its relative impact speed (km/h).
fn ncap_figures(card: &Scorecard, item: &ItemCard) -> Vec<Option<String>> {
    (item.cells.iter().enumerate())
        .map(|(column, cell)| {
            if cell.points.is_empty() {
                return None;
            }
            let mut speeds: Vec<f64> = cell.points.iter().map(|p| p.car_speed_kmh).collect();
            let mut locations: Vec<f64> = cell.points.iter().map(|p| p.impact_location_percent).collect();
            for v in [&mut speeds, &mut locations] {
                v.sort_by(f64::total_cmp);
                v.dedup();
            }
            let (cw, ch, left, top) = (64.0, 24.0, 90.0, 40.0);
            let width = (left + cw * locations.len() as f64 + 10.0).max(340.0);
            let height = top + ch * speeds.len() as f64 + 30.0;
            let name = &card.filters[column].name;
            let mut svg = svg_open(width, height, &format!("{} {}", item.name, name));
            let _ = write!(
                svg,
                "<text x=\"{left}\" y=\"14\">impact location (% of the car's width)</text>"
            );
            let _ = write!(
                svg,
                "<text x=\"12\" y=\"{}\" transform=\"rotate(-90 12 {})\" text-anchor=\"middle\">car speed (km/h)</text>",
                top + ch * speeds.len() as f64 / 2.0,
                top + ch * speeds.len() as f64 / 2.0
            );
            for (j, l) in locations.iter().enumerate() {
                let _ = write!(
                    svg,
                    "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{l}</text>",
                    left + cw * (j as f64 + 0.5),
                    top - 6.0
                );
            }
            for (i, s) in speeds.iter().enumerate() {
                let _ = write!(
                    svg,
                    "<text x=\"{}\" y=\"{}\" text-anchor=\"end\">{s}</text>",
                    left - 6.0,
                    top + ch * (i as f64 + 0.7)
                );
            }
            for p in &cell.points {
                let (Some(i), Some(j)) = (
                    speeds.iter().position(|s| *s == p.car_speed_kmh),
                    locations.iter().position(|l| *l == p.impact_location_percent),
                ) else {
                    continue;
                };
                let fill = p.colour.map_or("#bbbbbb", band);
                let text_colour = if matches!(p.colour, Some(Colour::Brown | Colour::Red)) {
                    "#fff"
                } else {
                    "#000"
                };
                let (x, y) = (left + cw * j as f64, top + ch * i as f64);
                let _ = write!(
                    svg,
                    "<rect x=\"{x}\" y=\"{y}\" width=\"{cw}\" height=\"{ch}\" fill=\"{fill}\" stroke=\"#fff\"><title>{}</title></rect>",
                    esc(&p.command)
                );
                let _ = write!(
                    svg,
                    "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\" fill=\"{text_colour}\">{}</text>",
                    x + cw / 2.0,
                    y + ch * 0.7,
                    p.relative_impact_kmh.map_or("n/a".into(), |v| format!("{v:.1}"))
                );
            }
            svg.push_str("</svg>");
            Some(figure(
                svg,
                &format!(
                    "{}: {} — each test point's relative impact speed (km/h) in its Euro NCAP colour band (grey: no colour, the table says why).",
                    item.name, name
                ),
            ))
        })
        .collect()
}

/// Ticks of a linear axis over [lo, hi]: about five round values.
fn linear_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-12);
    let raw = span / 5.0;
    let magnitude = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * magnitude)
        .find(|s| span / s <= 6.0)
        .unwrap_or(10.0 * magnitude);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Horizontal bars, one per filter, of the figure behind each cell (min clearance, time to the
/// goal), zero marked; a filter without the figure is named with its reason.
fn figure_bars(card: &Scorecard, item: &ItemCard) -> Option<String> {
    let first = item.cells.iter().find_map(|c| c.figure.as_ref())?;
    let values: Vec<Option<f64>> = item
        .cells
        .iter()
        .map(|c| c.figure.as_ref().and_then(|f| f.value))
        .collect();
    let known: Vec<f64> = values.iter().flatten().copied().collect();
    let lo = known.iter().copied().fold(0.0, f64::min);
    let hi = known.iter().copied().fold(0.0, f64::max);
    let (lo, hi) = if hi - lo < 1e-9 { (lo - 1.0, hi + 1.0) } else { (lo, hi) };
    // Room for the value printed beside each bar's end.
    let pad = 0.18 * (hi - lo);
    let (lo, hi) = (
        if lo < 0.0 { lo - pad } else { lo },
        if hi > 0.0 { hi + pad } else { hi },
    );
    bars(
        card,
        item,
        &values,
        (lo, hi),
        &format!("{} ({})", first.name, first.unit),
        &[],
    )
    .map(|svg| {
        figure(
            svg,
            &format!(
                "{}: {} per filter ({}); the line at 0.",
                item.name, first.name, first.unit
            ),
        )
    })
}

/// Bars of `values` (one per filter) on the axis `range`, with optional dots per filter
/// (value, filled: clear).
fn bars(
    card: &Scorecard,
    item: &ItemCard,
    values: &[Option<f64>],
    (lo, hi): (f64, f64),
    axis: &str,
    dots: &[Vec<(f64, bool)>],
) -> Option<String> {
    let (left, right, top, row) = (150.0, 30.0, 10.0, 26.0);
    let plot = 420.0;
    let width = left + plot + right;
    let height = top + row * values.len() as f64 + 44.0;
    let x = |v: f64| left + (v - lo) / (hi - lo) * plot;
    let mut svg = svg_open(width, height, &item.name);
    let bottom = top + row * values.len() as f64;
    for t in linear_ticks(lo, hi) {
        let _ = write!(
            svg,
            "<line x1=\"{0}\" x2=\"{0}\" y1=\"{top}\" y2=\"{bottom}\" stroke=\"#ddd\"/><text x=\"{0}\" y=\"{1}\" text-anchor=\"middle\">{2}</text>",
            x(t),
            bottom + 14.0,
            tick_label(t)
        );
    }
    let _ = write!(
        svg,
        "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>",
        left + plot / 2.0,
        bottom + 32.0,
        esc(axis)
    );
    for (column, value) in values.iter().enumerate() {
        let y = top + row * column as f64;
        let _ = write!(
            svg,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"end\">{}</text>",
            left - 6.0,
            y + row * 0.65,
            esc(&truncate(&card.filters[column].name, 22))
        );
        match value {
            Some(v) => {
                let (a, b) = (x(0.0_f64.clamp(lo, hi)), x(*v));
                let _ = write!(
                    svg,
                    "<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"{}\" fill-opacity=\"0.8\"><title>{v}</title></rect>",
                    a.min(b),
                    y + 5.0,
                    (a - b).abs().max(1.0),
                    row - 10.0,
                    filter_colour(column)
                );
                // The value beside the bar's end, so that a value near zero reads too.
                let (anchor, at) = if b >= a { ("start", b + 4.0) } else { ("end", b - 4.0) };
                let _ = write!(
                    svg,
                    "<text x=\"{at}\" y=\"{}\" text-anchor=\"{anchor}\" fill=\"#333\">{}</text>",
                    y + row * 0.65,
                    format_value(*v)
                );
            }
            None => {
                let reason = item.cells[column].reason.clone().unwrap_or_else(|| "absent".into());
                let _ = write!(
                    svg,
                    "<text x=\"{}\" y=\"{}\" fill=\"#666\">no value: {}</text>",
                    left + 4.0,
                    y + row * 0.65,
                    esc(&truncate(&reason, 60))
                );
            }
        }
        for (v, clear) in dots.get(column).into_iter().flatten() {
            let _ = write!(
                svg,
                "<circle cx=\"{}\" cy=\"{}\" r=\"3.5\" fill=\"{}\" stroke=\"{}\"/>",
                x(*v),
                y + row / 2.0,
                if *clear { filter_colour(column) } else { "#fff" },
                filter_colour(column)
            );
        }
    }
    if (lo..=hi).contains(&0.0) {
        let _ = write!(
            svg,
            "<line x1=\"{0}\" x2=\"{0}\" y1=\"{top}\" y2=\"{bottom}\" stroke=\"#000\"/>",
            x(0.0)
        );
    }
    svg.push_str("</svg>");
    Some(svg)
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        s.chars().take(n - 1).collect::<String>() + "…"
    }
}

/// A value to four significant digits.
fn format_value(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    format!("{v:.digits$}")
}

/// A margin per filter: the bar is the margin, the dots the bisection's runs (filled: clear,
/// open: collided), by their distance from the safe end.
fn margin_figure(card: &Scorecard, item: &ItemCard, key: &str, unit: &str) -> Option<String> {
    let Scoring::Margin { safe, toward, .. } = &item.scoring else {
        return None;
    };
    let span = (toward - safe).abs();
    let values: Vec<Option<f64>> = item.cells.iter().map(|c| c.score).collect();
    let dots: Vec<Vec<(f64, bool)>> = (item.cells.iter())
        .map(|c| {
            (c.steps.iter())
                .filter_map(|s| s.clear.map(|clear| ((s.value - safe).abs(), clear)))
                .collect()
        })
        .collect();
    let svg = bars(
        card,
        item,
        &values,
        (0.0, span),
        &format!("distance of {key} from {safe} towards {toward} ({unit})"),
        &dots,
    )?;
    Some(figure(
        svg,
        &format!(
            "{}: the margin per filter (bar) and the bisection's runs (filled: clear, open: collided).",
            item.name
        ),
    ))
}

/// A falsification item's convergence per filter: the lowest qualified objective after each
/// run, on a symmetric-log axis, the threshold dashed and the violating side shaded.
fn search_figure(card: &Scorecard, item: &ItemCard, objective: &str, threshold: f64) -> Option<String> {
    let series: Vec<&Vec<Option<f64>>> = item
        .cells
        .iter()
        .filter_map(|c| c.search.as_ref().map(|s| &s.best_so_far))
        .collect();
    let values: Vec<f64> = series.iter().flat_map(|s| s.iter().flatten().copied()).collect();
    if values.is_empty() {
        return None;
    }
    let runs = series.iter().map(|s| s.len()).max().unwrap_or(1).max(2);
    let c = 0.01;
    let lo = values.iter().copied().fold(threshold, f64::min);
    let hi = values.iter().copied().fold(threshold, f64::max);
    let (ylo, yhi) = (symlog(lo, c) - 0.2, symlog(hi, c) + 0.2);
    let (left, top, pw, ph) = (70.0, 14.0, 460.0, 240.0);
    let width = left + pw + 180.0;
    let height = top + ph + 46.0;
    let x = |k: f64| left + k / (runs - 1) as f64 * pw;
    let y = |v: f64| top + (yhi - symlog(v, c)) / (yhi - ylo) * ph;
    let mut svg = svg_open(width, height, &item.name);
    // The violating side (below the threshold), shaded.
    let _ = write!(
        svg,
        "<rect x=\"{left}\" y=\"{}\" width=\"{pw}\" height=\"{}\" fill=\"#e00000\" fill-opacity=\"0.07\"/>",
        y(threshold),
        (top + ph - y(threshold)).max(0.0)
    );
    let decades: Vec<f64> = (-2..=4).map(|e| 10f64.powi(e)).collect();
    let ticks = std::iter::once(0.0)
        .chain(decades.iter().flat_map(|d| [*d, -*d]))
        .filter(|t| (ylo..=yhi).contains(&symlog(*t, c)));
    for t in ticks {
        let _ = write!(
            svg,
            "<line x1=\"{left}\" x2=\"{}\" y1=\"{1}\" y2=\"{1}\" stroke=\"#e4e4e4\"/><text x=\"{2}\" y=\"{3}\" text-anchor=\"end\">{4}</text>",
            left + pw,
            y(t),
            left - 6.0,
            y(t) + 4.0,
            tick_label(t)
        );
    }
    let _ = write!(
        svg,
        "<line x1=\"{left}\" x2=\"{}\" y1=\"{1}\" y2=\"{1}\" stroke=\"#000\" stroke-dasharray=\"5 3\"/>",
        left + pw,
        y(threshold)
    );
    for t in linear_ticks(1.0, runs as f64) {
        let _ = write!(
            svg,
            "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{t}</text>",
            x(t - 1.0),
            top + ph + 14.0
        );
    }
    let _ = write!(
        svg,
        "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">run</text><text x=\"14\" y=\"{}\" transform=\"rotate(-90 14 {})\" text-anchor=\"middle\">lowest qualified {} (symlog)</text>",
        left + pw / 2.0,
        top + ph + 32.0,
        top + ph / 2.0,
        top + ph / 2.0,
        esc(objective)
    );
    let mut legend_y = top + 10.0;
    for (column, cell) in item.cells.iter().enumerate() {
        let Some(search) = &cell.search else { continue };
        let points: Vec<String> = (search.best_so_far.iter().enumerate())
            .filter_map(|(k, v)| v.map(|v| format!("{:.1},{:.1}", x(k as f64), y(v))))
            .collect();
        if !points.is_empty() {
            let _ = write!(
                svg,
                "<polyline class=\"series\" fill=\"none\" stroke=\"{}\" stroke-width=\"2\" points=\"{}\"/>",
                filter_colour(column),
                points.join(" ")
            );
        }
        let _ = write!(
            svg,
            "<line x1=\"{0}\" x2=\"{1}\" y1=\"{2}\" y2=\"{2}\" stroke=\"{3}\" stroke-width=\"2\"/><text x=\"{4}\" y=\"{5}\">{6}</text>",
            left + pw + 12.0,
            left + pw + 32.0,
            legend_y,
            filter_colour(column),
            left + pw + 36.0,
            legend_y + 4.0,
            esc(&truncate(&card.filters[column].name, 20))
        );
        legend_y += 18.0;
    }
    let _ = write!(
        svg,
        "<line x1=\"{0}\" x2=\"{1}\" y1=\"{2}\" y2=\"{2}\" stroke=\"#000\" stroke-dasharray=\"5 3\"/><text x=\"{3}\" y=\"{4}\">threshold {5}</text>",
        left + pw + 12.0,
        left + pw + 32.0,
        legend_y,
        left + pw + 36.0,
        legend_y + 4.0,
        threshold
    );
    svg.push_str("</svg>");
    Some(figure(
        svg,
        &format!(
            "{}: the lowest {objective} of a qualified candidate after each run; below the dashed threshold (shaded) a violation. Symmetric-log axis, linear within ±{c}.",
            item.name
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symlog_is_odd_monotone_and_linear_near_zero() {
        assert_eq!(symlog(0.0, 0.01), 0.0);
        assert_eq!(symlog(-5.0, 0.01), -symlog(5.0, 0.01));
        assert!(symlog(0.024, 0.01) > symlog(0.0, 0.01) + 0.3);
        assert!(symlog(250.0, 0.01) < 5.0);
        let ticks = linear_ticks(0.0, 0.8);
        assert_eq!(ticks.first(), Some(&0.0));
        assert!(ticks.len() >= 4 && ticks.len() <= 9, "{ticks:?}");
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(esc("<a href='x'>&\""), "&lt;a href=&#39;x&#39;&gt;&amp;&quot;");
    }
}
