"""Reads an SVG figure of mjsafe's as a reader would and checks it, independently of the code
that drew it (xml.etree only):

    python tests/figure_check.py FIGURE.svg --legend LABEL [--legend LABEL …]
        [--axis TEXT …] [--covers VALUE] [--legends-at-most N] [--distinct]

- each --legend LABEL is a legend entry whose line sample's colour is a drawn curve (a
  polyline of that colour with at least 20 points);
- each --axis TEXT appears in some text of the figure (an axis label with its unit);
- --covers VALUE: the y axis (its tick labels fitted to their tick marks, linear or symlog as
  its label says) puts VALUE inside the axis, and the legend's curves reach it: their lowest
  point is drawn where VALUE is (within 3 px);
- --legends-at-most N: the figure has at most N legend entries (texts with a line sample
  beside them);
- --distinct: no two legend entries share their line sample's colour.

Prints "ok: …" or exits 1 with the reasons.
"""
import argparse
import math
import re
import sys
import xml.etree.ElementTree as ET

NS = "{http://www.w3.org/2000/svg}"


def points_of(element):
    pairs = element.get("points", "").split()
    return [tuple(float(v) for v in p.split(",")) for p in pairs]


def number(text):
    try:
        return float(text.replace("−", "-"))
    except ValueError:
        return None


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("svg")
    parser.add_argument("--legend", action="append", default=[])
    parser.add_argument("--axis", action="append", default=[])
    parser.add_argument("--covers", type=float)
    parser.add_argument("--legends-at-most", type=int)
    parser.add_argument("--distinct", action="store_true")
    args = parser.parse_args()
    root = ET.parse(args.svg).getroot()
    texts = [(float(t.get("x", 0)), float(t.get("y", 0)), t.get("text-anchor", "start"), "".join(t.itertext()).strip())
             for t in root.iter(NS + "text")]
    lines = [(e.get("stroke"), points_of(e)) for e in root.iter(NS + "polyline")]
    problems = []
    curves = []

    def samples_beside(x, y):
        return [c for c, p in lines if len(p) == 2 and p[0][1] == p[1][1] and abs(p[0][1] - (y + 8)) <= 6
                and p[1][0] < x <= p[1][0] + 14]

    entries = [(t[3], samples_beside(t[0], t[1])[0]) for t in texts if t[3] and samples_beside(t[0], t[1])]
    if args.legends_at_most is not None and len(entries) > args.legends_at_most:
        problems.append(f"{len(entries)} legend entries, more than {args.legends_at_most}: {[e[0] for e in entries]}")
    if args.distinct:
        colours = [c for _, c in entries]
        shared = sorted({c for c in colours if colours.count(c) > 1})
        if shared:
            problems.append(f"legend entries share colours {shared}: {entries}")
    for label in args.legend:
        found = [t for t in texts if t[3] == label]
        if not found:
            problems.append(f"no legend entry {label!r}")
            continue
        x, y = found[0][0], found[0][1]
        samples = samples_beside(x, y)
        if not samples:
            problems.append(f"legend entry {label!r} has no line sample beside it")
            continue
        drawn = [p for c, p in lines if c == samples[0] and len(p) >= 20]
        if not drawn:
            problems.append(f"legend entry {label!r}: no curve of its colour {samples[0]}")
        curves.extend(drawn)
    everything = " | ".join(t[3] for t in texts)
    for axis in args.axis:
        if axis not in everything:
            problems.append(f"no axis label with {axis!r}")
    if args.covers is not None:
        # The y axis: the longest vertical 2-point line; its ticks: short horizontal lines
        # ending on it; their labels: right-aligned numbers at their height.
        verticals = [p for c, p in lines if len(p) == 2 and p[0][0] == p[1][0]]
        axis_line = max(verticals, key=lambda p: abs(p[1][1] - p[0][1]))
        ax = axis_line[0][0]
        top, bottom = sorted([axis_line[0][1], axis_line[1][1]])
        ticks = [p[0][1] for c, p in lines if len(p) == 2 and p[0][1] == p[1][1] and p[1][0] == ax and p[0][0] < ax]
        labelled = []
        for ty in ticks:
            near = [t for t in texts if t[2] == "end" and t[0] < ax and abs(t[1] - ty) <= 10 and number(t[3]) is not None]
            if near:
                labelled.append((number(min(near, key=lambda t: abs(t[1] - ty))[3]), ty))
        match = re.search(r"symlog \(linear within ±([0-9.e+-]+)\)", everything)
        c = float(match.group(1)) if match else None
        f = (lambda v: math.copysign(math.log10(1 + abs(v) / c), v)) if c else (lambda v: v)
        if len(labelled) < 2:
            problems.append(f"fewer than two labelled y ticks ({labelled})")
        else:
            xs = [f(v) for v, _ in labelled]
            ys = [y for _, y in labelled]
            n = len(xs)
            mx, my = sum(xs) / n, sum(ys) / n
            b = sum((a - mx) * (y - my) for a, y in zip(xs, ys)) / sum((a - mx) ** 2 for a in xs)
            a0 = my - b * mx
            residual = max(abs(a0 + b * x - y) for x, y in zip(xs, ys))
            if residual > 2.0:
                problems.append(f"the y ticks do not fit a {'symlog' if c else 'linear'} axis (off by {residual:.1f} px)")
            at = a0 + b * f(args.covers)
            if not top - 0.5 <= at <= bottom + 0.5:
                problems.append(f"{args.covers} falls at y = {at:.1f} px, outside the axis [{top}, {bottom}]")
            if curves:
                lowest = max(y for p in curves for _, y in p)
                if abs(lowest - at) > 3.0:
                    problems.append(f"the curves' lowest point is at y = {lowest:.1f} px, {args.covers} at {at:.1f} px")
    if problems:
        print("\n".join(problems), file=sys.stderr)
        return 1
    print(f"ok: {len(args.legend)} curves with their legend labels, {len(args.axis)} axis labels"
          + (f", y axis covers {args.covers}" if args.covers is not None else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
