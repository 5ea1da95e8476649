"""Monte Carlo machinery: typed resumable tables, executors, determinism across workers and Dask."""

from __future__ import annotations

import concurrent.futures as cf
import importlib.util
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.montecarlo import (
    InlineExecutor,
    local_executor,
    read_table,
    run_trials,
    summarise,
    trial_id,
    write_table,
)


def small_plan(seed: int, kind: str = "C") -> dict[str, Any]:
    """A real (small) plan whose numbers depend on the seed only."""
    sc = po.paper_scenario(kind, seed=seed, horizon=60)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=4, threads=1))
    return {
        "distance": res.total_distance,
        "coverage": res.coverage(),
        "per_platform": res.locales_per_platform.tolist(),
        "ok": True,
    }


def failing(seed: int) -> dict[str, Any]:
    if seed == 1:
        raise ScenarioError("seed 1 is bad")
    return {"value": float(seed)}


CALLS: list[int] = []


def counted(seed: int) -> dict[str, Any]:
    CALLS.append(seed)
    return {"square": seed * seed}


def interrupting(seed: int) -> dict[str, Any]:
    if seed == 3:
        raise KeyboardInterrupt
    return {"square": seed * seed}


TRIALS = [{"seed": s} for s in range(4)]


def test_table_round_trip_keeps_types(tmp_path: Path) -> None:
    rows = [
        {"a": 1, "b": 2.5, "c": "x,y", "d": True, "e": [1, 2], "f": None},
        {"a": 2, "b": 3, "c": "z", "d": False, "e": {"k": 1}, "f": 1.5},
        {"a": np.int64(3), "b": np.float64(0.1), "c": "", "d": np.bool_(True), "e": np.arange(2), "f": None},
    ]
    path = write_table(tmp_path / "t.csv", rows)
    back = read_table(path)
    assert back[0] == {"a": 1, "b": 2.5, "c": "x,y", "d": True, "e": [1, 2], "f": None}
    assert back[2]["c"] == ""  # an empty string stays a string
    assert back[1]["b"] == 3.0 and isinstance(back[1]["b"], float)
    assert back[1]["e"] == {"k": 1}
    assert back[2]["a"] == 3 and back[2]["b"] == 0.1 and back[2]["d"] is True and back[2]["e"] == [0, 1]


def test_malformed_table_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        read_table(tmp_path / "missing.csv")
    write_table(tmp_path / "t.csv", [{"a": 1}])
    (tmp_path / "t.schema.json").write_text("{not json")
    with pytest.raises(ConfigError, match="malformed"):
        read_table(tmp_path / "t.csv")
    write_table(tmp_path / "t.csv", [{"a": 1}])
    (tmp_path / "t.csv").write_text("a\nnot-an-int\n")
    with pytest.raises(ConfigError, match="column type"):
        read_table(tmp_path / "t.csv")


def test_trial_parameters_must_be_plain() -> None:
    assert trial_id({"b": 1, "a": "x"}) == trial_id({"a": "x", "b": 1})
    with pytest.raises(ConfigError, match="JSON"):
        trial_id({"a": object()})


def test_rows_in_trial_order_and_errors_recorded(tmp_path: Path) -> None:
    rows = run_trials(failing, TRIALS, tmp_path / "r.csv", progress=False)
    assert [r["seed"] for r in rows] == [0, 1, 2, 3]
    assert rows[1]["error"].startswith("ScenarioError: seed 1 is bad")
    assert rows[2]["value"] == 2.0 and rows[2]["error"] == ""
    assert [r["seed"] for r in read_table(tmp_path / "r.csv")] == [0, 1, 2, 3]


def test_resume_skips_finished_trials(tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    CALLS.clear()
    run_trials(counted, TRIALS[:2], out, progress=False)
    assert CALLS == [0, 1]
    rows = run_trials(counted, TRIALS, out, progress=False)
    assert CALLS == [0, 1, 2, 3]  # only the new trials ran
    assert [r["square"] for r in rows] == [0, 1, 4, 9]
    run_trials(counted, TRIALS, out, progress=False, resume=False)
    assert CALLS == [0, 1, 2, 3, 0, 1, 2, 3]


def test_interrupted_run_keeps_finished_trials_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "r.csv"
    with pytest.raises(KeyboardInterrupt):
        run_trials(interrupting, TRIALS, out, progress=False)
    assert [r["seed"] for r in read_table(out)] == [0, 1, 2]
    CALLS.clear()
    rows = run_trials(counted, TRIALS, out, progress=False)
    assert CALLS == [3]
    assert [r["square"] for r in rows] == [0, 1, 4, 9]


def test_progress_bar_is_shown(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_trials(counted, TRIALS, tmp_path / "r.csv", label="my study")
    err = capsys.readouterr().err
    assert "my study" in err and "4/4" in err


def test_bad_workers_is_a_config_error() -> None:
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="workers"):
            local_executor(bad)  # type: ignore[arg-type]
    assert isinstance(local_executor(1), InlineExecutor)


def test_summarise_ignores_non_finite() -> None:
    s = summarise([1.0, float("nan"), 3.0, 2.0, float("inf")])
    assert s == {"mean": 2.0, "median": 2.0, "max": 3.0, "n": 3}
    assert summarise([])["n"] == 0


def test_same_numbers_with_one_worker_two_workers_and_dask(tmp_path: Path) -> None:
    trials = [{"seed": s} for s in range(4)]
    one = run_trials(small_plan, trials, tmp_path / "one.csv", workers=1, progress=False)
    with cf.ProcessPoolExecutor(2) as pool:
        two = run_trials(small_plan, trials, tmp_path / "two.csv", executor=pool, progress=False)
    spawned = run_trials(small_plan, trials, tmp_path / "spawn.csv", workers=2, progress=False)
    assert all(r["error"] == "" for r in one)
    assert one == two == spawned
    assert (tmp_path / "one.csv").read_text() == (tmp_path / "two.csv").read_text()
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    from pmht_opt.montecarlo import dask_executor

    with dask_executor(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as ex:
        dask_rows = run_trials(small_plan, trials, tmp_path / "dask.csv", executor=ex, progress=False)
    assert dask_rows == one
    assert (tmp_path / "dask.csv").read_text() == (tmp_path / "one.csv").read_text()


def test_dask_bad_address_is_a_config_error() -> None:
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    from pmht_opt.montecarlo import dask_executor

    with pytest.raises(ConfigError, match="dask scheduler"), dask_executor("tcp://127.0.0.1:1"):
        pass
