"""The pmht-opt command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.cli import main


def test_demo_writes_figure_and_prints_metrics(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo.png"
    assert main(["demo", "--iterations", "5", "--out", str(out), "--quiet"]) == 0
    assert out.stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "total distance" in text and "coverage within 0.3" in text


def test_scenario_then_plan_with_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scen = tmp_path / "b.toml"
    assert main(["scenario", "B", "--seed", "3", "--out", str(scen)]) == 0
    js = tmp_path / "m.json"
    code = main(["plan", str(scen), "--solver", "osqp", "--iterations", "3", "--json", str(js)])
    assert code == 0
    payload = json.loads(js.read_text())
    assert payload["metrics"]["solver"] == "osqp" and payload["metrics"]["iterations"] == 3
    assert len(payload["positions"]) == 3
    assert "coverage (osqp)" in capsys.readouterr().err  # the progress bar of the default planner


def test_bad_file_is_a_clean_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"locales": [[1, 2]], "starts": [[0, 0]], "horizon": -4}')
    assert main(["plan", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "horizon" in err and "Traceback" not in err


def test_solvers_lists_backends(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["solvers"]) == 0
    text = capsys.readouterr().out
    for name in ("clarabel", "osqp", "kalman", "cvxpy"):
        assert name in text


def test_warnings_reach_the_command_line_as_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    import warnings

    from pmht_opt.cli import one_line_warnings

    with one_line_warnings():
        warnings.warn(po.PlanWarning("the plan was fitted at r = 0.1"), stacklevel=1)
        np.log(np.zeros(1))  # numpy's own RuntimeWarning, in the same form
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "pmht-opt: warning: the plan was fitted at r = 0.1",
        "pmht-opt: warning: divide by zero encountered in log",
    ]
