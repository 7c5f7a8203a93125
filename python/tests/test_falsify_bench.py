"""scripts/falsify_bench.py, the falsification benchmark of issue 53: its problems run and are
what docs/falsification.md says (ten rare boxes, six or more in the moving world, two halves,
and a fresh half), the score it gives pycma's candidates is `mjsafe falsify`'s, bit for bit, and
a cached result is reused only for the box it was computed for."""

import importlib.util
import json
import itertools
import math
import random

import pytest

from conftest import ROOT, cli

spec = importlib.util.spec_from_file_location("falsify_bench", ROOT / "scripts" / "falsify_bench.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

CH4_WORLD = ("scenarios/bicycle_obstacle_gamma_m.toml", "scenarios/car_obstacle_gamma_m.toml")


def test_the_benchmark_is_the_one_the_docs_describe():
    problems = bench.PROBLEMS
    assert len(problems) >= 10
    halves = {h: [p for p in problems if p["half"] == h] for h in ("tuning", "test", "fresh")}
    assert len(halves["tuning"]) == len(halves["test"]) == 5
    assert len(halves["fresh"]) == len(problems) - 10 >= 3
    assert sum(p["scenario"] not in CH4_WORLD for p in problems) >= 6
    assert all(4 <= len(p["ranges"]) <= 8 for p in problems)
    assert any(":" in r for p in problems for r in p["ranges"]), "some ranges are quantised"
    assert any(r.startswith("seed=") for p in problems for r in p["ranges"]), "some boxes have seeded noise"
    names = [p["name"] for p in problems]
    assert len(set(names)) == len(names)
    docs = (ROOT / "docs" / "falsification.md").read_text()
    for p in problems:
        assert f"| {p['name']} | {p['half']} |" in docs, f"{p['name']} is not in the docs' table"


def test_a_cached_result_serves_only_the_box_it_was_computed_for(tmp_path):
    problem = dict(next(p for p in bench.PROBLEMS if p["name"] == "ccrs_noise"))
    where = tmp_path / "ccrs_noise-guided-1"
    assert not bench.reusable(str(where), problem)
    bench.remember(str(where), problem)
    (where / "evaluations.json").write_text("{}")
    assert bench.reusable(str(where), problem)
    assert bench.reusable(str(where), dict(problem, half="test")), "the half is only a label"
    edited = dict(problem, ranges=problem["ranges"][:-1] + ["seed=0..10:1"])
    assert not bench.reusable(str(where), edited)
    assert not where.exists(), "the stale result is removed"
    # A result cached without its definition (an older cache) is not trusted either.
    where.mkdir()
    (where / "evaluations.json").write_text("{}")
    assert not bench.reusable(str(where), problem) and not where.exists()



def exact_two_sided_p(a, b):
    """Mann–Whitney's exact two-sided p-value by enumerating every split of the pooled runs
    (no ties): the share of splits whose U is at least as far from its mean as the observed."""
    pooled = a + b
    def u(first):
        return sum(1 for x in first for y in pooled if y not in first and x > y)
    mean = len(a) * len(b) / 2
    observed = abs(u(a) - mean)
    splits = [list(c) for c in itertools.combinations(pooled, len(a))]
    return sum(1 for s in splits if abs(u(s) - mean) >= observed - 1e-12) / len(splits)


def test_the_separation_of_two_methods_is_mann_whitney_s_with_a_miss_beyond_the_budget():
    budget = 600
    # Wholly separated (a miss ranks last): 2 of the C(8, 4) = 70 splits are as extreme.
    assert bench.separation([1, 2, 3, 4], [5, 6, 7, None], budget) == pytest.approx(2 / 70)
    assert exact_two_sided_p([1, 2, 3, 4], [5, 6, 7, budget + 1]) == pytest.approx(2 / 70)
    rng = random.Random(53)
    for _ in range(20):
        runs = rng.sample(range(1, budget + 1), 10)
        a, b = runs[:5], runs[5:]
        assert bench.separation(a, b, budget) == pytest.approx(exact_two_sided_p(a, b), abs=1e-12)
    row = bench.separations({"guided": [1, 2, 3, 4], "random": [5, 6, 7, None], "pycma": [1, 2, 3, 4]},
                            budget)
    assert row.startswith("random 0.029, pycma ") and float(row.split()[-1]) > 0.9

def test_quantised_values_are_multiples_of_the_step_within_the_box():
    r = bench.Range("delays.acceleration=0.3..0.8:0.01")
    values = [float(r.value(u / 97)) for u in range(98)]
    assert min(values) == 0.3 and max(values) == 0.8
    assert all(abs(round((v - 0.3) / 0.01) * 0.01 + 0.3 - v) < 1e-12 for v in values)
    assert bench.Range("seed=0..1000:1").value(0.5) == "500"
    assert float(bench.Range("x=-6..-2").value(0.25)) == -5.0


@pytest.mark.parametrize("name", ["ccrb_brake", "ccrm_noise", "truck_jitter"])
def test_the_score_of_a_candidate_is_mjsafe_falsify_s(name, tmp_path):
    problem = next(p for p in bench.PROBLEMS if p["name"] == name)
    out = tmp_path / "search"
    cli(*bench.falsify_args("mjsafe", problem)[1:], "--method", "random", "--worst", "--budget", "8",
        "--seed", "5", "--out", str(out))
    evaluations = json.loads((out / "evaluations.json").read_text())["searches"][0]["evaluations"]
    assert len(evaluations) == 8
    py = bench.MjsafePy()
    for e in evaluations:
        assert e["error"] is None, e["error"]
        score, violation = bench.score(py, problem, [f"{k}={v}" for k, v in e["parameters"]])
        assert math.isfinite(score)
        assert (score, violation) == (e["score"], e["violation"]), e["parameters"]


def test_every_problem_runs(tmp_path):
    for problem in bench.PROBLEMS:
        out = tmp_path / problem["name"]
        cli(*bench.falsify_args("mjsafe", problem)[1:], "--method", "random", "--worst", "--budget", "2",
            "--seed", "1", "--out", str(out))
        evaluations = json.loads((out / "evaluations.json").read_text())["searches"][0]["evaluations"]
        assert [e["error"] for e in evaluations] == [None, None], problem["name"]
