"""The coverage study on a tiny budget: rows, summary with the ratio, figures, verify; its Pareto front."""

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
    args = ["study", "coverage", "--trials", "1", "--radii", "0.3", "--kinds", "C", "--horizon", "80"]
    args += ["--methods", "coverage", "pmht", "--out", str(tmp_path)]
    assert main([*args, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert f"wrote: {tmp_path / 'coverage_C.png'}" in out
    rows = read_rows(tmp_path / "coverage.jsonl", coverage.TABLE.schema, "coverage")
    assert sorted((r["method"], r["radius"]) for r in rows) == [("coverage", 0.3), ("pmht", 0.0)]
    assert all(r["error_class"] == "" for r in rows)
    full = [r for r in rows if r["method"] != "pmht"]
    assert all(r["coverage"] == 1.0 and r["coverage_at"]["0.3"] == 1.0 for r in full)
    (partial,) = [r for r in rows if r["method"] == "pmht"]
    assert partial["coverage"] is None and set(partial["coverage_at"]) == {"0.05", "0.1", "0.2", "0.3", "0.5"}
    summary = json.loads((tmp_path / "coverage_summary.json").read_text())["summary"]
    assert {s["method"] for s in summary} == {"coverage", "pmht"}
    assert "| C | 0.3 | coverage | 1 (0) |" in (tmp_path / "coverage.md").read_text()
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
    opts = coverage.Options(trials=2, radii=(0.1, 0.3), methods=("coverage", "pmht"), kinds=("A",))
    trials = coverage.params(opts)
    assert len(trials) == 2 * 2 + 2
    assert {t["radius"] for t in trials if t["method"] == "pmht"} == {0.0}
