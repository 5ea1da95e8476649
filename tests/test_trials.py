"""The trial machinery: typed append-only results, resume, damage, interrupts, crashed workers, Dask.

Real processes and real files throughout: workers are spawned, killed with real signals, and results
files are damaged the way a crash or a power cut leaves them.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import pytest

import pmht_opt as po
from pmht_opt.exceptions import ConfigError, ScenarioError
from studies.pool import WorkerPool
from studies.store import (
    DamagedRowWarning,
    NaNResultWarning,
    ResultsFile,
    Schema,
    load,
    read_rows,
    trial_id,
)
from studies.stored import pick_evenly, verify
from studies.trials import (
    Check,
    InlineExecutor,
    TrialTable,
    check_dask_address,
    local_executor,
    run_trials,
)

HERE = Path(__file__).resolve().parent
CALLS: list[int] = []


def counted(seed: int) -> dict[str, Any]:
    CALLS.append(seed)
    return {"square": seed * seed, "root": math.sqrt(seed)}


def failing(seed: int) -> dict[str, Any]:
    if seed == 1:
        raise ScenarioError("seed 1 is bad")
    return {"square": seed * seed, "root": math.sqrt(seed)}


def interrupting(seed: int) -> dict[str, Any]:
    if seed == 3:
        raise KeyboardInterrupt
    return counted(seed)


def crash_once(seed: int, marker: str) -> dict[str, Any]:
    """SIGKILL this worker the first time seed 2 runs (the marker file remembers)."""
    if seed == 2 and not os.path.exists(marker):
        Path(marker).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.05)
    return {"square": seed * seed, "root": math.sqrt(seed)}


def crash_always(seed: int, marker: str) -> dict[str, Any]:
    if seed == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return {"square": seed * seed, "root": math.sqrt(seed)}


def small_plan(seed: int) -> dict[str, Any]:
    """A real (small) plan whose numbers depend on the seed only."""
    sc = po.paper_scenario("C", seed=seed, horizon=40)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=3, threads=1))
    return {"distance": res.total_distance, "per_platform": res.locales_per_platform.tolist()}


SCHEMA = Schema(params={"seed": "int"}, values={"square": "int", "root": "float"})
COUNTED = TrialTable("squares", counted, SCHEMA)
TRIALS = [{"seed": s} for s in range(4)]


def lines(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def test_round_trip_keeps_types_and_provenance(tmp_path: Path) -> None:
    schema = Schema(
        params={"kind": "str", "seed": "int"},
        values={"x": "float", "n": "int", "ok": "bool", "xs": "list", "d": "dict", "note": "str?"},
    )
    with ResultsFile(tmp_path / "t.jsonl", schema, "t", {"commit": "abc"}) as store:
        store.append({"kind": "A", "seed": 1}, {"x": 3, "n": 2, "ok": True, "xs": (1, 2), "d": {"k": 1}})
        with pytest.warns(
            NaNResultWarning, match=r'trial \{"kind":"B","seed":2\}: column x: the trial returned'
        ):
            store.append(
                {"kind": "B", "seed": 2}, {"x": math.nan, "n": 0, "ok": False, "xs": [], "d": {}, "note": ""}
            )
        store.append({"kind": "C", "seed": 3}, error_class="SolverError", error="no")
    with pytest.warns(
        NaNResultWarning, match=r't\.jsonl:4: trial \{"kind":"B","seed":2\}: column x: NaN result'
    ):
        loaded = load(tmp_path / "t.jsonl", schema, "t")
    assert loaded.nan == [('{"kind":"B","seed":2}', "x")]
    a, b, c = loaded.rows.values()
    assert a["x"] == 3.0 and isinstance(a["x"], float) and a["xs"] == [1, 2] and a["ok"] is True
    assert math.isnan(b["x"]) and b["note"] == "" and b["d"] == {}
    assert c["error_class"] == "SolverError" and "x" not in c
    assert loaded.runs[0]["provenance"] == {"commit": "abc"} and not loaded.damaged and loaded.clean
    header = json.loads(lines(tmp_path / "t.jsonl")[0])
    assert header["schema"]["values"]["note"] == "str?"


@pytest.mark.parametrize(
    ("values", "field"),
    [
        ({"square": 1}, "root"),  # missing
        ({"square": 1, "root": 1.0, "extra": 1}, "extra"),
        ({"square": "1", "root": 1.0}, "square"),
        ({"square": True, "root": 1.0}, "square"),
    ],
)
def test_results_that_do_not_fit_the_schema_stop_the_run(values: dict[str, Any], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        SCHEMA.normalise(values)


def test_trial_parameters_must_be_plain_and_fit_the_schema() -> None:
    assert trial_id({"b": 1, "a": "x"}) == trial_id({"a": "x", "b": 1})
    with pytest.raises(ConfigError, match="JSON"):
        trial_id({"a": object()})
    with pytest.raises(ConfigError, match="seed"):
        SCHEMA.check_params({"seed": "0"})


def test_rows_in_trial_order_with_error_classes(tmp_path: Path) -> None:
    table = TrialTable("squares", failing, SCHEMA)
    rows = run_trials(table, TRIALS, tmp_path, progress=False)
    assert [r["seed"] for r in rows] == [0, 1, 2, 3]
    assert rows[1]["error_class"] == "ScenarioError" and rows[1]["error"] == "seed 1 is bad"
    assert rows[2]["square"] == 4 and rows[2]["error_class"] == ""
    # A real error is a result: a resume keeps it.
    CALLS.clear()
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == []


def test_resume_retries_only_retryable_error_rows(tmp_path: Path) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    path = COUNTED.path(tmp_path)
    with ResultsFile(path, SCHEMA, "squares", {}) as store:
        store.append({"seed": 1}, error_class="WorkerCrashed", error="worker died")
        store.append({"seed": 2}, error_class="KeyboardInterrupt", error="interrupted")
        store.append({"seed": 3}, error_class="InfeasibleError", error="no plan")
    CALLS.clear()
    rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == [1, 2]
    assert [r["error_class"] for r in rows] == ["", "", "", "InfeasibleError"]
    # Superseded rows were dropped when the run opened the file: 4 rows, then the 2 retried ones.
    assert sum(b'"record":"row"' in line for line in lines(path)) == 6
    assert [r["error_class"] for r in read_rows(path, SCHEMA, "squares")] == ["", "", "", "InfeasibleError"]


def test_resume_skips_finished_trials_and_fresh_starts_over(tmp_path: Path) -> None:
    CALLS.clear()
    run_trials(COUNTED, TRIALS[:2], tmp_path, progress=False)
    rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == [0, 1, 2, 3] and [r["square"] for r in rows] == [0, 1, 4, 9]
    run_trials(COUNTED, TRIALS, tmp_path, progress=False, resume=False)
    assert CALLS == [0, 1, 2, 3, 0, 1, 2, 3]
    assert len(load(COUNTED.path(tmp_path), SCHEMA, "squares").runs) == 1


def test_interrupted_run_keeps_finished_rows_and_writes_no_error_row(tmp_path: Path) -> None:
    table = TrialTable("squares", interrupting, SCHEMA)
    with pytest.raises(KeyboardInterrupt):
        run_trials(table, TRIALS, tmp_path, progress=False)
    rows = read_rows(COUNTED.path(tmp_path), SCHEMA, "squares")
    assert [r["seed"] for r in rows] == [0, 1, 2] and all(r["error_class"] == "" for r in rows)
    CALLS.clear()
    assert [r["square"] for r in run_trials(COUNTED, TRIALS, tmp_path, progress=False)] == [0, 1, 4, 9]
    assert CALLS == [3]


def test_truncated_file_resumes_with_only_the_cut_row_recomputed(tmp_path: Path) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    path = COUNTED.path(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 12])  # the last row cut inside its value
    with pytest.warns(DamagedRowWarning, match=r'squares\.jsonl:6: trial \{"seed":3\}: line: truncated'):
        loaded = load(path, SCHEMA, "squares")
    assert sorted(r["seed"] for r in loaded.rows.values()) == [0, 1, 2]
    CALLS.clear()
    with pytest.warns(DamagedRowWarning):
        rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == [3] and rows[3]["square"] == 9
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load(path, SCHEMA, "squares").clean  # rewritten once: no damage left


def test_nul_damaged_file_resumes_with_only_the_damaged_row_recomputed(tmp_path: Path) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    path = COUNTED.path(tmp_path)
    raw = lines(path)
    raw[3] = b"\x00" * (len(raw[3]) - 1) + b"\n"  # the row of seed 1 zeroed, as after a power cut
    raw.append(b"\x00" * 64)  # and a zeroed tail
    path.write_bytes(b"".join(raw))
    CALLS.clear()
    with pytest.warns(DamagedRowWarning, match="NUL bytes") as caught:
        rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == [1]
    assert [r["square"] for r in rows] == [0, 1, 4, 9]
    assert {str(w.message).split(": ")[0].rsplit(":", 1)[1] for w in caught} == {"4", "7"}
    assert b"\x00" not in path.read_bytes()


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda r: r.pop("root"), "root: missing column"),
        (lambda r: r.update(extra=1), "extra: column not in the schema"),
        (lambda r: r.update(square="4"), "square: expected int"),
        (lambda r: r.update(root=None), "root: missing value"),
        (lambda r: r.update(trial='{"seed":9'), "trial: id does not match"),
        (lambda r: r.update(error_class="SolverError"), "error: empty value"),
    ],
)
def test_rows_failing_their_schema_are_reported_and_recomputed(tmp_path: Path, edit: Any, field: str) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    path = COUNTED.path(tmp_path)
    raw = lines(path)
    row = json.loads(raw[4])  # seed 2
    edit(row)
    raw[4] = (json.dumps(row) + "\n").encode()
    path.write_bytes(b"".join(raw))
    CALLS.clear()
    with pytest.warns(DamagedRowWarning, match=rf"jsonl:5: trial .*: {field}"):
        rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert CALLS == [2] and rows[2]["square"] == 4


def _lose_header(raw: list[bytes]) -> list[bytes]:
    return raw[1:]


def _cut_header(raw: list[bytes]) -> list[bytes]:
    return [raw[0][:30] + b"\n", *raw[1:]]


def _zero_header(raw: list[bytes]) -> list[bytes]:
    return [b"\x00" * (len(raw[0]) - 1) + b"\n", *raw[1:]]


def _other_json_header(raw: list[bytes]) -> list[bytes]:
    return [b'{"record":"header","version":1}\n', *raw[1:]]


@pytest.mark.parametrize(
    ("damage", "problem"),
    [
        (_lose_header, "missing"),
        (_cut_header, "truncated or not JSON"),
        (_zero_header, "NUL bytes"),
        (_other_json_header, "incomplete"),
    ],
)
def test_a_damaged_header_is_recovered_keeping_every_row(tmp_path: Path, damage: Any, problem: str) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    path = COUNTED.path(tmp_path)
    path.write_bytes(b"".join(damage(lines(path))))
    CALLS.clear()
    with pytest.warns(DamagedRowWarning, match=rf"squares\.jsonl:1: header: {problem}") as caught:
        rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert len(caught) == 1  # only the header: no row was dropped
    assert CALLS == [] and [r["square"] for r in rows] == [0, 1, 4, 9]
    header = json.loads(lines(path)[0])
    assert header["format"] == "pmht-opt-trials" and header["study"] == "squares"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = load(path, SCHEMA, "squares")
    assert loaded.clean and len(loaded.rows) == 4 and len(loaded.runs) == 2


@pytest.mark.parametrize(
    "content",
    [
        b"name,value\nalpha,1\n",
        b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR",
        b'{"some": "json"}\n{"other": 1}\n',
        b'{"record":"header","format":"another-format","study":"squares"}\n',
    ],
)
def test_a_foreign_file_is_refused_by_name_and_never_overwritten(tmp_path: Path, content: bytes) -> None:
    path = COUNTED.path(tmp_path)
    path.write_bytes(content)
    CALLS.clear()
    for resume in (True, False):  # not even when asked to start afresh
        with pytest.raises(ConfigError, match=rf"{path}: not a results file of this project"):
            run_trials(COUNTED, TRIALS, tmp_path, progress=False, resume=resume)
        with pytest.raises(ConfigError, match="not a results file"):
            read_rows(path, SCHEMA, "squares")
    assert path.read_bytes() == content and CALLS == []


@pytest.mark.parametrize("content", [b"", b"\x00" * 200])
def test_an_empty_or_zeroed_results_file_is_started_again(tmp_path: Path, content: bytes) -> None:
    """What a power cut leaves of a new file holds nothing to lose: it gets a header and the rows."""
    path = COUNTED.path(tmp_path)
    path.write_bytes(content)
    with pytest.warns(DamagedRowWarning, match="header"):
        rows = run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    assert [r["square"] for r in rows] == [0, 1, 4, 9]
    assert json.loads(lines(path)[0])["record"] == "header" and b"\x00" not in path.read_bytes()


def test_nan_where_the_schema_means_not_measured_is_not_flagged(tmp_path: Path) -> None:
    schema = Schema(
        {"seed": "int"}, {"t": "float", "x": "float"}, not_measured={"t": "a failed run has no time"}
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with ResultsFile(tmp_path / "n.jsonl", schema, "n", {}) as store:
            store.append({"seed": 0}, {"t": math.nan, "x": 1.0})
        assert load(tmp_path / "n.jsonl", schema, "n").nan == []
    with pytest.raises(ConfigError, match="not_measured"):
        Schema({"seed": "int"}, {"t": "float"}, not_measured={"t": ""})


def test_a_file_of_another_study_is_refused(tmp_path: Path) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, progress=False)
    with pytest.raises(ConfigError, match="holds study 'squares'"):
        load(COUNTED.path(tmp_path), SCHEMA, "other")


def test_a_killed_worker_costs_only_its_trial(tmp_path: Path) -> None:
    trials = [{"seed": s, "marker": str(tmp_path / "crashed")} for s in range(6)]
    table = TrialTable("squares", crash_once, Schema({"seed": "int", "marker": "str"}, SCHEMA.values))
    rows = run_trials(table, trials, tmp_path, workers=2, progress=False)
    assert (tmp_path / "crashed").exists()  # the worker really was killed once
    assert [r["square"] for r in rows] == [s * s for s in range(6)]
    assert all(r["error_class"] == "" for r in rows)


def test_a_trial_that_always_kills_its_worker_is_recorded_as_a_crash(tmp_path: Path) -> None:
    table = TrialTable("squares", crash_always, Schema({"seed": "int", "marker": "str"}, SCHEMA.values))
    trials = [{"seed": s, "marker": "-"} for s in range(5)]
    with WorkerPool(2) as pool:
        rows = run_trials(table, trials, tmp_path, executor=pool, progress=False, retries=1)
    assert [r["error_class"] for r in rows] == ["", "", "WorkerCrashed", "", ""]
    assert "signal 9" in rows[2]["error"] and "2 runs" in rows[2]["error"]
    assert [r.get("square") for r in rows] == [0, 1, None, 9, 16]


PARENT = """
import sys, time
sys.path[:0] = {paths!r}
from studies.store import Schema
from studies.trials import TrialTable, run_trials
import test_trials
table = TrialTable("slow", test_trials.sleepy, Schema({{"seed": "int"}}, {{"square": "int"}}))
run_trials(table, [{{"seed": s}} for s in range(8)], {out!r}, workers=2, progress=False)
"""


def sleepy(seed: int) -> dict[str, Any]:
    time.sleep(30)
    return {"square": seed * seed}


def children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    out = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.add(int(entry.name))
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_sigkill_of_the_parent_leaves_no_worker_alive(tmp_path: Path) -> None:
    script = PARENT.format(paths=[str(HERE), str(HERE.parent)], out=str(tmp_path))
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 30
        kids: set[int] = set()
        while time.monotonic() < deadline and len(kids) < 3:  # 2 workers and the resource tracker
            time.sleep(0.2)
            kids = children(parent.pid)
        assert len(kids) >= 2, kids
        time.sleep(1.0)  # the workers are inside their trials
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(alive(k) for k in kids):
        time.sleep(0.1)
    assert not [k for k in kids if alive(k)]


def test_same_rows_with_one_worker_two_workers_and_dask(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    table = TrialTable(
        "plans", small_plan, Schema({"seed": "int"}, {"distance": "float", "per_platform": "list"})
    )
    trials = [{"seed": s} for s in range(3)]

    def values(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{k: v for k, v in r.items() if k != "run"} for r in rows]

    one = run_trials(table, trials, tmp_path / "one", workers=1, progress=False)
    two = run_trials(table, trials, tmp_path / "two", workers=2, progress=False)
    assert all(r["error_class"] == "" for r in one)
    assert values(one) == values(two)
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    from studies.trials import dask_executor

    with dask_executor(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as ex:
        dask_rows = run_trials(table, trials, tmp_path / "dask", executor=ex, progress=False)
    assert values(dask_rows) == values(one)


def test_bad_dask_addresses_fail_fast() -> None:
    for bad in ("notanaddress", "tcp://", "tcp://host", "http://host:1", ""):
        with pytest.raises(ConfigError, match="--dask-scheduler"):
            check_dask_address(bad)
    assert check_dask_address("127.0.0.1:8786") == "tcp://127.0.0.1:8786"
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    from studies.trials import dask_executor

    started = time.perf_counter()
    with pytest.raises(ConfigError, match="cannot connect"), dask_executor("tcp://127.0.0.1:1"):
        pass
    assert time.perf_counter() - started < 5


def test_a_real_dask_scheduler_answers_the_probe_and_a_worker_is_not_one() -> None:
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    from distributed import LocalCluster

    from studies.executors import probe_scheduler
    from studies.trials import dask_executor

    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", dashboard_address=None
    ) as cluster:
        assert probe_scheduler(cluster.scheduler_address, 5.0)["type"] == "Scheduler"
        with dask_executor(cluster.scheduler_address) as ex:
            assert ex.submit(pow, 2, 5).result() == 32
        worker = next(iter(cluster.scheduler_info["workers"]))
        with pytest.raises(ConfigError, match=rf"--dask-scheduler {worker}: answers as 'Worker'"):
            probe_scheduler(worker, 5.0)


def test_bad_workers_is_a_config_error() -> None:
    bad_values: list[Any] = [0, -1, 1.5, True]
    for bad in bad_values:
        with pytest.raises(ConfigError, match="workers"):
            local_executor(bad)
    assert isinstance(local_executor(1), InlineExecutor)


def test_progress_bar_is_shown(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_trials(COUNTED, TRIALS, tmp_path, label="my study")
    err = capsys.readouterr().err
    assert "my study" in err and "4/4" in err


def test_a_worker_that_dies_while_verifying_is_a_mismatch_not_a_traceback(tmp_path: Path) -> None:
    schema = Schema({"seed": "int", "marker": "str"}, SCHEMA.values)
    with ResultsFile(tmp_path / "squares.jsonl", schema, "squares", {}) as store:
        for s in range(4):
            store.append({"seed": s, "marker": "-"}, {"square": s * s, "root": math.sqrt(s)})
    with WorkerPool(2) as pool:
        _, mismatches = verify(TrialTable("squares", crash_always, schema), tmp_path, 4, executor=pool)
    assert [(m.trial, m.column, m.stored) for m in mismatches] == [
        ('{"marker":"-","seed":2}', "error_class", "")
    ]
    assert str(mismatches[0].fresh) == "WorkerCrashed"


def test_verify_passes_on_fresh_results_and_names_a_tampered_row(tmp_path: Path) -> None:
    run_trials(COUNTED, [{"seed": s} for s in range(10)], tmp_path, progress=False)
    assert pick_evenly(10, 3) == [0, 4, 9] and pick_evenly(10, 1) == [5] and pick_evenly(2, 5) == [0, 1]
    checked, mismatches = verify(COUNTED, tmp_path, 10)
    assert len(checked) == 10 and mismatches == []
    path = COUNTED.path(tmp_path)
    path.write_text(path.read_text().replace('"square":49', '"square":50'))
    _, mismatches = verify(COUNTED, tmp_path, 10)
    assert [(m.trial, m.column, m.stored, m.fresh) for m in mismatches] == [('{"seed":7}', "square", 50, 49)]
    lenient = TrialTable("squares", counted, SCHEMA, {"square": Check("close", atol=2, reason="test")})
    assert verify(lenient, tmp_path, 10)[1] == []
