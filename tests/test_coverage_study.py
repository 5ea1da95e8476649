"""The coverage study on a tiny budget: rows, summary with the ratio, figures, verify; its Pareto front;
plan seeds and the comparison with an earlier run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pmht_opt.cli import main
from pmht_opt.exceptions import ConfigError
from studies import coverage_study as coverage
from studies.coverage_figures import pareto_front
from studies.store import read_rows


def test_coverage_study_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # An earlier run's file: one coverage row of the same trial, 1.0 shorter than any plan of it.
    earlier = tmp_path / "earlier.jsonl"
    row = {"record": "row", "kind": "C", "seed": 0, "method": "coverage", "radius": 0.3, "horizon": 80}
    earlier.write_text(json.dumps({**row, "error_class": "", "distance": 1.0}) + "\n")
    args = ["study", "coverage", "--trials", "1", "--radii", "0.3", "--kinds", "C", "--horizon", "80"]
    args += ["--methods", "coverage", "pmht", "--plan-seeds", "0", "1", "--out", str(tmp_path / "run")]
    assert main([*args, "--quiet", "--previous", str(earlier)]) == 0
    out = capsys.readouterr().out
    assert f"wrote: {tmp_path / 'run' / 'coverage_C.png'}" in out
    rows = read_rows(tmp_path / "run" / "coverage.jsonl", coverage.TABLE.schema, "coverage")
    assert sorted((r["method"], r["radius"], r["plan_seed"]) for r in rows) == [
        ("coverage", 0.3, 0),
        ("coverage", 0.3, 1),
        ("pmht", 0.0, 0),
    ]
    assert all(r["error_class"] == "" for r in rows)
    full = [r for r in rows if r["method"] != "pmht"]
    assert all(r["coverage"] == 1.0 and r["coverage_at"]["0.3"] == 1.0 for r in full)
    assert all(r["covered"] == 1.0 and r["worst_gap"] <= 1e-6 for r in full)
    assert all(r["distance"] >= r["tour_length"] > 0 for r in full)
    (partial,) = [r for r in rows if r["method"] == "pmht"]
    assert partial["coverage"] is None and set(partial["coverage_at"]) == {"0.05", "0.1", "0.2", "0.3", "0.5"}
    assert partial["tour_length"] is None and partial["covered"] is None
    summary = json.loads((tmp_path / "run" / "coverage_summary.json").read_text())["summary"]
    assert {s["method"] for s in summary} == {"coverage", "pmht"}
    (cov,) = [s for s in summary if s["method"] == "coverage"]
    assert cov["trials"] == 1 and cov["spread_trials"] == 1 and cov["seed_spread_max"] >= 0.0
    assert cov["mean_smooth_over_straight"] >= 1.0 and cov["fully_covered"] == 1
    assert cov["previous"]["trials"] == 1 and cov["previous"]["longer"] == 1
    assert "| C | 0.3 | coverage | 1 (0) |" in (tmp_path / "run" / "coverage.md").read_text()
    assert main([*args, "--verify", "1"]) == 0
    assert "agrees" in capsys.readouterr().out


def test_ratio_against_the_best_baseline() -> None:
    rows = []
    for method, dist in (("coverage", 9.0), ("ortools-smoothed", 10.0), ("pyvrp-smoothed", 12.0)):
        rows.append(
            {
                "kind": "A",
                "seed": 0,
                "method": method,
                "radius": 0.3,
                "distance": dist,
                "coverage_at": {"0.3": 1.0},
                "wall": 1.0,
            }
        )
    table = coverage.summary(rows, [0.3])
    (cov,) = [s for s in table if s["method"] == "coverage"]
    assert cov["ratio"] == pytest.approx(0.9) and cov["baseline"] == "ortools-smoothed"


def test_pareto_front() -> None:
    pts = [(1.0, 10.0), (0.8, 8.0), (0.7, 9.0), (1.0, 12.0), (0.5, 5.0)]
    assert pareto_front(pts) == [(0.5, 5.0), (0.8, 8.0), (1.0, 10.0)]


def test_bad_options_name_the_option() -> None:
    with pytest.raises(ConfigError, match="--radii"):
        coverage.Options(radii=(0.3, -1.0))
    with pytest.raises(ConfigError, match="--methods"):
        coverage.Options(methods=("lkh-smoothed",))


def test_trials_of_a_run() -> None:
    opts = coverage.Options(
        trials=2, radii=(0.1, 0.3), methods=("coverage", "pmht"), kinds=("A",), spread_trials=1
    )
    trials = coverage.params(opts)
    # coverage: seed 0 with plan seeds 0, 1, 2 and seed 1 with plan seed 0, at two radii; pmht once each.
    assert len(trials) == 2 * 4 + 2
    assert {t["radius"] for t in trials if t["method"] == "pmht"} == {0.0}
    assert {t["plan_seed"] for t in trials if t["method"] == "pmht"} == {0}
    assert sorted(t["plan_seed"] for t in trials if t["method"] == "coverage" and t["radius"] == 0.1) == [
        0,
        0,
        1,
        2,
    ]


def test_previous_distances_read_the_coverage_rows_of_any_schema(tmp_path: Path) -> None:
    lines = [
        {"record": "header", "schema": {}},
        {
            "record": "row",
            "kind": "A",
            "seed": 3,
            "method": "coverage",
            "radius": 0.1,
            "horizon": 500,
            "error_class": "",
            "distance": 90.0,
        },
        {
            "record": "row",
            "kind": "A",
            "seed": 4,
            "method": "coverage",
            "radius": 0.1,
            "horizon": 500,
            "error_class": "SolverError",
        },
        {
            "record": "row",
            "kind": "A",
            "seed": 3,
            "method": "pmht",
            "radius": 0.0,
            "horizon": 500,
            "error_class": "",
            "distance": 80.0,
        },
    ]
    path = tmp_path / "old.jsonl"
    path.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    assert coverage.previous_distances(path) == {("A", 3, 0.1, 500): 90.0}
    with pytest.raises(ConfigError, match="--previous"):
        coverage.previous_distances(tmp_path / "missing.jsonl")


def test_previous_run_cannot_be_the_results_file(tmp_path: Path) -> None:
    (tmp_path / "coverage.jsonl").write_text("")
    args = ["study", "coverage", "--trials", "1", "--kinds", "A", "--methods", "pmht", "--out", str(tmp_path)]
    assert main([*args, "--previous", str(tmp_path / "coverage.jsonl"), "--quiet"]) == 2
