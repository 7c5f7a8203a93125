#!/usr/bin/env python3
"""PSY-TaLiRo (the PyPI package psy-taliro) on the five falsification problems of
scripts/falsify-study.sh: the same boxes, base overrides, baselines, budgets and seeds, with
`mjsafe run --json` as a black box. Runs to the first violation of PSY-TaLiRo's DualAnnealing
and UniformRandom, median over the seeds; prints Markdown table rows like falsify-study.sh's
(docs/falsification.md, "Optimiser against random search"). Run it through
scripts/psytaliro-study.sh (which makes the venv):
    scripts/psytaliro_study.py MJSAFE OUT_DIR [--seeds 1 2 ...] [--only PROBLEM]

The black box (a PSY-TaLiRo `@blackbox` model over static inputs bounded by the box) runs the
candidate, `mjsafe run SCENARIO --json --out <tmp log> --set <base overrides> --set KEY=VALUE…`,
and with a baseline the same overrides followed by the baseline's; it deletes the logs. As in
mjsafe falsify (src/falsify.rs, Evaluator::evaluate): m = min_h of the candidate, T = 0,
m_b = min_h of the baseline; the candidate is qualified iff it has no baseline or m_b >= 0; a
violation is qualified and m < 0. The model's trace is one sample of mjsafe's own score,
    score = m                                 (qualified)
    score = max(m, 0) + max(-m_b, 0) > 0      (unqualified: never a violation)
    score = f64::MAX                          (a run failed, as mjsafe's ABSENT_SCORE)
and the specification is the RTAMT formula `always (score >= 0)`, whose robustness is that
sample's score: negative exactly when the candidate is a violation. Quantised ranges
`LO..HI:STEP` take the nearest multiple of STEP from LO not above HI (integers when LO and STEP
are: the noise/jitter `seed`), formatted as mjsafe formats them; continuous ones the optimiser's
value itself.

Both optimisers are built with min_cost=0.0 (PSY-TaLiRo's falsification mode: stop at the first
negative robustness). That changes no candidate before the first violation, which is all the
count depends on; should an optimiser still ask for more, the black box returns the violation's
score again without running mjsafe (recorded as "cached"): once a (problem, seed, optimiser)
search has found a violation its later evaluations do not affect the count. The optimiser's seed
is PSY-TaLiRo's TestOptions(seed=SEED, runs=1) (the test seeds the run's optimiser from it), the
budget its `iterations`. A search that finds none within the budget is a miss, counted as more
than the budget in the median. Every evaluation (parameters, m, m_b, qualified, violation,
score) is written to OUT_DIR/<problem>-<seed>-<optimiser>.json.
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from importlib.metadata import version

import staliro
from staliro import TestOptions, Trace, blackbox
from staliro.optimizers import DualAnnealing, UniformRandom
from staliro.specifications import rtamt

SCENARIO = "scenarios/bicycle_obstacle_gamma_m.toml"
ABSENT_SCORE = sys.float_info.max  # mjsafe's score of a candidate whose run failed
BOX = ["vehicle.initial_state.0=-26..-16", "obstacles.0.centre.1=-3..3"]
BASELINE_DELAY_FREE = [
    "delays.steering=0.0",
    "delays.acceleration=0.0",
    'filter={kind="cbf_qp", l0=4.0, l1=4.0}',
]

# The problems of scripts/falsify-study.sh, in its order (keep the two in step).
PROBLEMS = [
    dict(name="gamma_m_baseline", budget=120, set=[],
         ranges=BOX + ["delays.acceleration=0.5..2.0:0.1"], baseline=BASELINE_DELAY_FREE),
    dict(name="gamma_m_underestimate", budget=120, set=[],
         ranges=BOX + ["assumed_delays.acceleration=0.3..1.5:0.05"],
         baseline=["assumed_delays.acceleration=1.5"]),
    dict(name="gamma_m_noise", budget=120, set=["sensing={noise_std=[0.0, 0.0, 0.0, 0.0]}"],
         ranges=["sensing.noise_std.0=0..0.02", "sensing.noise_std.1=0..0.02", "seed=0..1000:1"],
         baseline=[]),
    dict(name="gamma_m_jitter", budget=120,
         set=['actuation={steering={extra_latency={distribution="uniform", max=0.0}}, '
              'acceleration={extra_latency={distribution="uniform", max=0.0}}}'],
         ranges=BOX + ["actuation.steering.extra_latency.max=0..0.1",
                       "actuation.acceleration.extra_latency.max=0..0.1", "seed=0..1000:1"],
         baseline=["actuation.steering.extra_latency.max=0.0",
                   "actuation.acceleration.extra_latency.max=0.0"]),
    dict(name="gamma_m_rare", budget=600, set=[],
         ranges=["vehicle.initial_state.0=-50..-10", "obstacles.0.centre.1=-3..3",
                 "delays.acceleration=0.5..2.0:0.1"], baseline=BASELINE_DELAY_FREE),
]

OPTIMISERS = {
    "dual_annealing": lambda: DualAnnealing(min_cost=0.0),
    "uniform_random": lambda: UniformRandom(min_cost=0.0),
}


class Range:
    """`KEY=LO..HI[:STEP]` as mjsafe parses it (src/sweep.rs parse_range)."""

    def __init__(self, arg):
        self.key, spec = arg.split("=", 1)
        bounds, _, step = spec.partition(":")
        lo, hi = bounds.split("..")
        self.lo, self.hi = float(lo), float(hi)
        self.step = float(step) if step else None

    def value(self, x):
        """The override's value (TOML text) at the optimiser's x in [LO, HI]: as mjsafe's
        range_value/step_value at u = (x - LO) / (HI - LO)."""
        if self.step is None:
            return repr(float(x))
        choices = math.floor((self.hi - self.lo) / self.step + 1e-9)
        u = (x - self.lo) / (self.hi - self.lo)
        k = min(max(math.floor(u * choices + 0.5), 0), choices)  # Rust's round, half away from 0
        v = self.lo + k * self.step
        if self.lo.is_integer() and self.step.is_integer():
            return str(int(v))
        return repr(float(f"{v:.11e}"))


def min_h(mjsafe, overrides, tmp):
    """min_h of `mjsafe run --json` with the overrides, or (None, why)."""
    log = os.path.join(tmp, "run.mcap")
    cmd = [mjsafe, "run", SCENARIO, "--json", "--out", log]
    for o in overrides:
        cmd += ["--set", o]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True)
    finally:
        if os.path.exists(log):
            os.remove(log)
    if p.returncode != 0:
        return None, f"exit {p.returncode}: {p.stderr.strip()[:300]}"
    try:
        summary = json.loads(p.stdout)
    except json.JSONDecodeError as e:
        return None, f"unparseable --json output: {e}"
    if summary.get("error") or summary.get("min_h") is None:
        return None, f"run error {summary.get('error')!r}, min_h {summary.get('min_h')!r}"
    return float(summary["min_h"]), None


def evaluate(mjsafe, problem, ranges, static, tmp):
    """One candidate, scored as mjsafe falsify scores it (T = 0, T_b = 0)."""
    params = {r.key: r.value(static[r.key]) for r in ranges}
    candidate = problem["set"] + [f"{k}={v}" for k, v in params.items()]
    e = dict(params=params, raw={k: float(static[k]) for k in params}, m=None, m_b=None,
             qualified=False, violation=False, score=ABSENT_SCORE, error=None, cached=False)
    e["m"], e["error"] = min_h(mjsafe, candidate, tmp)
    if e["m"] is None:
        return e
    e["score"], e["qualified"] = e["m"], True
    if problem["baseline"]:
        e["m_b"], why = min_h(mjsafe, candidate + problem["baseline"], tmp)
        if e["m_b"] is None:
            e.update(error=f"baseline: {why}", score=ABSENT_SCORE, qualified=False)
            return e
        e["qualified"] = e["m_b"] >= 0.0
        if not e["qualified"]:
            e["score"] = max(e["m"], 0.0) + max(-e["m_b"], 0.0)
    e["violation"] = e["qualified"] and e["m"] < 0.0
    return e


def search(mjsafe, problem, seed, method, out):
    ranges = [Range(a) for a in problem["ranges"]]
    budget = problem["budget"]
    evaluations = []
    first = None  # 1-based index of the first violation
    with tempfile.TemporaryDirectory(prefix="psytaliro-") as tmp:

        @blackbox(step_size=1.0)
        def model(inputs):
            nonlocal first
            if first is not None:  # the count is decided: no more mjsafe runs
                e = dict(evaluations[first - 1], raw={k: float(v) for k, v in inputs.static.items()},
                         cached=True)
                e["params"] = {r.key: r.value(inputs.static[r.key]) for r in ranges}
            else:
                e = evaluate(mjsafe, problem, ranges, inputs.static, tmp)
            e["index"] = len(evaluations) + 1
            evaluations.append(e)
            if first is None and e["violation"]:
                first = e["index"]
            return Trace({0.0: {"score": e["score"]}})

        spec = rtamt.parse_dense("always (score >= 0)")
        options = TestOptions(runs=1, iterations=budget, seed=seed,
                              static_inputs={r.key: (r.lo, r.hi) for r in ranges})
        start = time.monotonic()
        runs = staliro.staliro(model, spec, OPTIMISERS[method](), options)
        wall = time.monotonic() - start
    # PSY-TaLiRo's own record agrees with ours (its costs are the robustness values).
    costs = [ev.cost for ev in runs[0].evaluations]
    assert costs == [e["score"] for e in evaluations], "PSY-TaLiRo's costs differ from the scores"
    n = first if first is not None and first <= budget else None
    record = dict(problem=problem["name"], seed=seed, method=method, budget=budget,
                  psy_taliro=version("psy-taliro"), scenario=SCENARIO,
                  set=problem["set"], ranges=problem["ranges"], baseline=problem["baseline"],
                  runs_to_first_violation=n, evaluations_made=len(evaluations),
                  mjsafe_candidates_run=sum(not e["cached"] for e in evaluations),
                  wall_seconds=round(wall, 2), evaluations=evaluations)
    with open(os.path.join(out, f"{problem['name']}-{seed}-{method}.json"), "w") as f:
        json.dump(record, f, indent=1)
    return n


def show(v, budget):
    if not v:
        return "–"
    m = statistics.median(v)
    misses = sum(1 for x in v if x == math.inf)
    text = f"> {budget}" if m == math.inf else f"{m:g}"
    return f"{text} ({len(v) - misses}/{len(v)} found)"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mjsafe")
    ap.add_argument("out")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--only", default=None)
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    print("| problem | budget | PSY-TaLiRo dual annealing: median runs to first violation "
          "| PSY-TaLiRo uniform random |")
    print("|---|---|---|---|", flush=True)
    for problem in PROBLEMS:
        if args.only and args.only != problem["name"]:
            continue
        found = {m: [] for m in OPTIMISERS}
        for seed in args.seeds:
            for method in OPTIMISERS:
                n = search(args.mjsafe, problem, seed, method, args.out)
                found[method].append(n if n is not None else math.inf)
                print(f"{problem['name']} seed {seed} {method}: {n}", file=sys.stderr, flush=True)
        b = problem["budget"]
        print(f"| {problem['name']} | {b} | {show(found['dual_annealing'], b)} "
              f"| {show(found['uniform_random'], b)} |", flush=True)


if __name__ == "__main__":
    main()
