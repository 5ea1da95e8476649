"""The study commands: table1 end to end on a small budget, resume, anneal study summary."""

from __future__ import annotations

from pathlib import Path

import pytest

from pmht_opt.cli import main
from pmht_opt.montecarlo import read_table
from pmht_opt.studies import anneal, table1


def test_table1_writes_table_and_figures_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["study", "table1", "--trials", "1", "--methods", "ga", "pmht", "--out", str(tmp_path)]
    assert main([*args, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "| A | GA-TSP | 1 |" in out and "117.8" in out  # the paper's figure next to ours
    rows = read_table(tmp_path / "table1.csv")
    assert [(r["kind"], r["method"]) for r in rows] == [(k, m) for k in "ABC" for m in ("ga", "pmht")]
    assert all(r["error"] == "" for r in rows)
    assert all(r["coverage"] == 1.0 for r in rows if r["method"] == "ga")
    assert all(0.0 < r["coverage"] < 1.0 for r in rows if r["method"] == "pmht")
    for name in (
        "table1.md",
        "table1_summary.json",
        "figure1_iterations.png",
        "figure5_locales_per_platform.png",
    ):
        assert (tmp_path / name).stat().st_size > 0
    for n, kind in ((2, "A"), (3, "B"), (4, "C")):
        assert (tmp_path / f"figure{n}_scenario_{kind}.png").stat().st_size > 0
    # A second run with one more trial reuses the finished ones (their timings are unchanged).
    assert main([*args[:3], "2", *args[4:], "--no-figures"]) == 0
    assert "(resumed)" in capsys.readouterr().err
    again = read_table(tmp_path / "table1.csv")
    assert len(again) == 12
    first = {(r["kind"], r["method"]): r["wall"] for r in rows}
    assert all(first[(r["kind"], r["method"])] == r["wall"] for r in again if r["seed"] == 0)


def test_table1_rejects_bad_trials(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", "table1", "--trials", "0", "--out", str(tmp_path)]) == 2
    assert "--trials" in capsys.readouterr().err


def test_table1_summary_and_paper_columns() -> None:
    rows = [
        {"kind": "B", "seed": s, "method": "pmht", "distance": d, "cpu": 1.0, "coverage": 0.7, "excursion": e}
        for s, (d, e) in enumerate([(70.0, 1.0), (80.0, 3.0), (90.0, 0.0)])
    ]
    rows.append({"kind": "B", "seed": 3, "method": "pmht", "error": "SolverError: x"})
    (s,) = table1.summary(rows)
    assert s["trials"] == 3 and s["failed"] == 1
    assert s["mean_distance"] == 80.0 and s["median_distance"] == 80.0 and s["max_distance"] == 90.0
    assert s["paper_distance"] == 77.8 and s["paper_cpu"] == 16.7
    assert s["left_area"] == 1  # B's starts are exactly 1 outside: only the 3-unit excursion counts
    assert "(1 failed)" in table1.markdown([s])


def test_anneal_summary_counts() -> None:
    rows = [
        {
            "kind": "A",
            "seed": s,
            "config": "annealed",
            "distance": 80.0 + s,
            "coverage": 0.7,
            "left_area": s == 0,
            "time": 1.0,
            "error": "",
        }
        for s in range(3)
    ]
    (s,) = anneal.summary(rows)
    assert s["trials"] == 3 and s["left_area"] == 1 and s["median_distance"] == 81.0
    assert "| A | annealed | 3 |" in anneal.markdown([s])
