"""Recomputes every Euro NCAP score of a scorecard.json from its test points' car speeds and
relative impact speeds, sharing no code with mjsafe's scorer (src/ncap.rs, src/scorecard/).

The rule, as Euro NCAP's 2026 rating calculator (Euro-NCAP/euroncap_rating_2026 at 94b1035)
implements it: the relative impact speed rounded half up to 2 decimals (Decimal, as its
numeric.round_half_up); bands (lower, upper] per car-speed row (10, 20, 30, 40, >= 50 km/h);
points green 1, yellow 0.75, orange 0.5, brown 0.25, red 0 (no colour counts 0); a test's score
the mean of its points times its weight (data_model.TOTAL_SCORES), shown to 3 decimals; the gate
zeroes every test unless every CCRs point at <= 20 km/h and the CPNA point at 75 % / 10 km/h are
green.

Usage: python ncap_check.py scorecard.json  (prints "ok N points" or raises)
"""
import json
import math
import sys
from decimal import Decimal, ROUND_HALF_UP

WEIGHTS = {"CCRs": 1.2, "CCRm": 2.4, "CCRb": 1.6, "CPNA": 0.5, "CPFA": 0.5}
ROWS = {
    10: [("green", 0.0), ("red", math.inf)],
    20: [("green", 0.0), ("red", math.inf)],
    30: [("green", 0.0), ("brown", 10.0), ("red", math.inf)],
    40: [("green", 0.0), ("orange", 10.0), ("brown", 20.0), ("red", math.inf)],
    50: [("green", 0.0), ("yellow", 10.0), ("orange", 20.0), ("brown", 30.0), ("red", math.inf)],
}
POINTS = {"green": 1.0, "yellow": 0.75, "orange": 0.5, "brown": 0.25, "red": 0.0}


def half_up(x, digits):
    d = Decimal(float(x)).quantize(Decimal(1).scaleb(-max(9, digits + 4)), rounding=ROUND_HALF_UP)
    return float(d.quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))


def colour(car_kmh, v_rel):
    row = ROWS.get(50 if car_kmh >= 50 else car_kmh)
    if row is None or v_rel is None:
        return None
    v = half_up(v_rel, 2)
    lower = -math.inf
    for name, upper in row:
        if lower < v <= upper:
            return name
        lower = upper
    raise AssertionError("no band")


def main(path):
    card = json.load(open(path))
    checked = 0
    for column in range(len(card["filters"])):
        tests = {}
        for item in card["items"]:
            score = item["scoring"]
            if score["kind"] != "ncap":
                continue
            cell = item["cells"][column]
            if cell["status"] != "scored":
                continue
            points = []
            for p in cell["points"]:
                c = colour(p["car_speed_kmh"], p["relative_impact_kmh"])
                assert c == p["colour"], (item["name"], p, c)
                got = POINTS[c] if c else 0.0
                assert got == p["points"], (item["name"], p, got)
                points.append(got)
                checked += 1
            tests[item["name"]] = (score["test"], points, cell)
        if not tests:
            continue
        ccrs = [p for _, (t, _, cell) in tests.items() if t == "CCRs" for p in cell["points"] if p["car_speed_kmh"] <= 20]
        cpna = [p for _, (t, _, cell) in tests.items() if t == "CPNA" for p in cell["points"]
                if p["car_speed_kmh"] == 10 and p["impact_location_percent"] == 75]
        gate = None
        if ccrs and cpna:
            gate = all(colour(p["car_speed_kmh"], p["relative_impact_kmh"]) == "green" for p in ccrs + cpna[:1])
        total = 0.0
        for name, (test, points, cell) in tests.items():
            expected = half_up(sum(points) / len(points) * WEIGHTS[test], 3) if points else 0.0
            if gate is False:
                expected = 0.0
            assert abs(cell["score"] - expected) < 1e-12, (name, cell["score"], expected)
            assert cell["max"] == WEIGHTS[test], (name, cell["max"])
            total += expected
        ncap = card["ncap"][column]
        assert ncap["gate_passed"] == gate, (ncap, gate)
        assert abs(ncap["score"] - half_up(total, 3)) < 1e-9, (ncap["score"], total)
        assert abs(ncap["max"] - sum(WEIGHTS[t] for t, _, _ in tests.values())) < 1e-9
    print(f"ok {checked} points")


if __name__ == "__main__":
    main(sys.argv[1])
