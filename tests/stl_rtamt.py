"""RTAMT's robustness of STL formulas, the independent check of mjsafe's (tests/stl_rtamt.rs).

Usage: stl_rtamt.py CASES.json OUT.json

CASES.json: {"cases": [{"formula": TEXT, "step_ns": INT, "signals": {NAME: [VALUE, ...]}}]},
values as text (Python's float() reads them, "inf" and "-inf" included). For each case RTAMT's
discrete-time offline monitor (StlDiscreteTimeSpecification, evaluate) runs with the sampling
period set to the step; OUT.json gets {"rtamt": VERSION, "results": [[VALUE, ...], ...]}: the
robustness at every sample, as repr() text.
"""

import json
import sys
from importlib.metadata import version

import rtamt


def evaluate(case):
    spec = rtamt.StlDiscreteTimeSpecification()
    spec.name = "requirement"
    signals = {name: [float(v) for v in values] for name, values in case["signals"].items()}
    for name in signals:
        spec.declare_var(name, "float")
    spec.spec = case["formula"]
    spec.set_sampling_period(case["step_ns"], "ns", 0.1)
    spec.parse()
    n = len(next(iter(signals.values())))
    step_s = case["step_ns"] * 1e-9
    dataset = {"time": [i * step_s for i in range(n)]}
    dataset.update(signals)
    rho = spec.evaluate(dataset)
    return [repr(float(v)) for _, v in rho]


def main():
    with open(sys.argv[1]) as f:
        cases = json.load(f)["cases"]
    results = []
    for case in cases:
        try:
            results.append(evaluate(case))
        except Exception as e:  # noqa: BLE001 - reported with the formula, the test fails on it
            raise SystemExit(f"rtamt failed on {case['formula']!r}: {type(e).__name__}: {e}")
    with open(sys.argv[2], "w") as f:
        json.dump({"rtamt": version("rtamt"), "results": results}, f)


if __name__ == "__main__":
    main()
