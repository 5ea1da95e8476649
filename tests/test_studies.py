"""The study commands end to end on tiny budgets: files written, resume, verify, exits, import hygiene."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import probe_study
import pytest

from pmht_opt.cli import main
from studies import anneal, table1
from studies.store import read_rows


def test_table1_writes_table_and_figures_and_resumes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = [
        "study",
        "table1",
        "--trials",
        "1",
        "--methods",
        "ga",
        "pmht",
        "--horizon",
        "40",
        "--out",
        str(tmp_path),
    ]
    assert main([*args, "--quiet"]) == 0
    out = capsys.readouterr().out
    assert (
        f"wrote: {tmp_path / 'table1.jsonl'}" in out
        and f"wrote: {tmp_path / 'figure1_iterations.png'}" in out
    )
    rows = read_rows(tmp_path / "table1.jsonl", table1.TABLE.schema, "table1")
    assert [(r["kind"], r["method"]) for r in rows] == [(k, m) for k in "ABC" for m in ("ga", "pmht")]
    assert all(r["error_class"] == "" for r in rows)
    assert all(r["coverage"] == 1.0 for r in rows if r["method"] == "ga")
    for name in ("table1.md", "figure5_locales_per_platform.png", "figure2_scenario_A.png"):
        assert (tmp_path / name).stat().st_size > 0
    summary = json.loads((tmp_path / "table1_summary.json").read_text())
    assert summary["provenance"]["cpu_count"] >= 1 and "numpy" in summary["provenance"]["packages"]
    assert "| A | GA-TSP | 1 |" in (tmp_path / "table1.md").read_text()
    # One more trial reuses the finished ones (their timings are unchanged).
    assert main(["study", "table1", "--trials", "2", *args[4:], "--no-figures", "--quiet"]) == 0
    again = read_rows(tmp_path / "table1.jsonl", table1.TABLE.schema, "table1")
    assert len(again) == 12
    first = {(r["kind"], r["method"]): r["wall"] for r in rows}
    assert all(first[(r["kind"], r["method"])] == r["wall"] for r in again if r["seed"] == 0)


def test_anneal_verify_passes_then_fails_on_a_tampered_row(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["study", "anneal", "--trials", "2", "--configs", "plain", "annealed", "--kinds", "B"]
    base += ["--horizon", "30", "--out", str(tmp_path)]
    assert main([*base, "--quiet"]) == 0
    capsys.readouterr()
    assert main([*base, "--verify", "2"]) == 0
    out = capsys.readouterr().out
    assert "not compared: time (wall-clock time differs from run to run)" in out and "agrees" in out
    path = tmp_path / "anneal.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    victim = max((r for r in rows if r["record"] == "row"), key=lambda r: r["trial"])  # verified first/last
    victim["coverage"] = victim["coverage"] + 0.125
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    assert main([*base, "--verify", "2"]) == 1
    out = capsys.readouterr().out
    assert f"MISMATCH trial {victim['trial']}: column 'coverage'" in out


def test_tables_only_rewrites_the_summary_from_stored_rows_and_runs_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["study", "anneal", "--configs", "plain", "--kinds", "B", "--horizon", "30"]
    base += ["--out", str(tmp_path)]
    assert main([*base, "--trials", "2", "--quiet"]) == 0
    path = tmp_path / "anneal.jsonl"
    stored = path.read_bytes()
    (tmp_path / "anneal.md").unlink()
    capsys.readouterr()
    # A third trial is asked for: it is not run, and the table says what it left out.
    assert main([*base, "--trials", "3", "--tables-only", "--quiet"]) == 0
    err = capsys.readouterr().err  # said even under --quiet: the summary is of part of the trials
    assert f"--tables-only: 1 of 3 trials have no row in {path}; they are left out." in err
    assert path.read_bytes() == stored  # nothing run, nothing appended (not even a run record)
    table = (tmp_path / "anneal.md").read_text()
    assert table.startswith("Written with --tables-only") and "| B | plain | 2 |" in table.replace("  ", " ")
    runs = json.loads((tmp_path / "anneal_summary.json").read_text())["runs"]
    assert len(runs) == 1 and runs[0]["packages"]["numpy"]
    assert main([*base, "--tables-only", "--fresh"]) == 2
    assert "cannot be used with --fresh or --verify" in capsys.readouterr().err
    empty = tmp_path / "empty"
    assert main([*base[:-1], str(empty), "--tables-only"]) == 2
    assert "--tables-only: no results file" in capsys.readouterr().err


def test_table1_summary_and_paper_columns() -> None:
    rows = [
        {"kind": "B", "seed": s, "method": "pmht", "distance": d, "cpu": 1.0, "coverage": 0.7, "excursion": e}
        for s, (d, e) in enumerate([(70.0, 1.0), (80.0, 3.0), (90.0, 0.0)])
    ]
    rows.append({"kind": "B", "seed": 3, "method": "pmht", "error": "x", "error_class": "SolverError"})
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


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["table1", "--trials", "0"], "--trials"),
        (["table1", "--workers", "0"], "--workers"),
        (["anneal", "--trials", "0"], "--trials"),
        (["anneal", "--verify", "-1"], "--verify"),
        # 0 is not "do not verify": it used to run (and append to) the study it was asked to check.
        (["anneal", "--trials", "1", "--configs", "plain", "--horizon", "20", "--verify", "0"], "--verify"),
        (["solvers", "--seeds", "-1"], "--seeds"),
        (["solvers", "--iterations", "0"], "--iterations"),
        (["scaling", "--quick", "--reps", "0"], "--reps"),
        (["anneal", "--dask-scheduler", "notanaddress"], "--dask-scheduler"),
        (["anneal", "--out", "{file}"], "is a file"),
        (["anneal", "--out", "{file}/sub"], "cannot write"),
    ],
)
def test_bad_inputs_are_config_errors_naming_the_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], field: str
) -> None:
    (tmp_path / "f").write_text("")
    argv = ["study", *(a.replace("{file}", str(tmp_path / "f")) for a in args)]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "out")]
    started = time.perf_counter()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert field in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert time.perf_counter() - started < 5
    assert not (tmp_path / "out").exists()  # checked before any work starts


def _imported(code: str) -> set[str]:
    """Top-level and dotted module names imported by ``python -X importtime -c code``."""
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", code], capture_output=True, text=True, check=True
    )
    return {
        line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")
    }


def test_the_core_imports_no_study_module() -> None:
    for code in (
        "import pmht_opt",
        "import sys; from pmht_opt.cli import main; sys.argv[1:] = ['--help']; main()",
    ):
        try:
            names = _imported(code)
        except subprocess.CalledProcessError as err:  # --help exits 0 through SystemExit
            raise AssertionError(err.stderr) from None
        assert "pmht_opt" in names
        assert not {n for n in names if n == "studies" or n.startswith("studies.")}, code
        assert "resource" not in names and "tqdm" not in names and "pandas" not in names, code


def test_a_study_run_as_a_script_shadows_no_module_its_libraries_import() -> None:
    """``python studies/NAME.py`` puts ``studies/`` first on the path, where a study module named
    like a package wins over it (some libraries try ``import coverage`` when they load). The
    libraries a study run loads must import from there as from anywhere else."""
    studies = Path(__file__).resolve().parent.parent / "studies"
    names = {p.stem for p in studies.glob("*.py")} | {p.name for p in studies.iterdir() if p.is_dir()}
    assert "coverage" not in names
    code = (
        f"import sys; sys.path.insert(0, {str(studies)!r})\n"
        "import matplotlib.pyplot, pandas, scipy.sparse, pyvrp"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_python_m_studies_and_the_script_forms(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "studies", "--help"], capture_output=True, text=True)
    assert done.returncode == 0 and "table1" in done.stdout and "python -m studies" in done.stdout
    done = subprocess.run(
        [sys.executable, "-m", "studies", "anneal", "--trials", "0"], capture_output=True, text=True
    )
    assert done.returncode == 2 and "--trials" in done.stderr


def test_ctrl_c_exits_130_and_keeps_finished_rows(tmp_path: Path) -> None:
    argv = ["study", "anneal", "--trials", "500", "--configs", "plain", "--kinds", "A", "--horizon", "20"]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from pmht_opt.cli import main; sys.exit(main(sys.argv[1:]))",
            *argv,
            "--out",
            str(tmp_path),
            "--quiet",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    path = tmp_path / "anneal.jsonl"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and (not path.exists() or path.read_text().count('"record":"row"') < 2):
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1].startswith("pmht-opt study: interrupted; finished trials are kept")
    rows = read_rows(path, anneal.TABLE.schema, "anneal")
    assert 2 <= len(rows) < 500 and all(r["error_class"] == "" for r in rows)


def test_a_missing_studies_extra_names_the_extra() -> None:
    code = (
        "import sys\n"
        "sys.modules['pandas'] = None  # as if the extra were not installed\n"
        "from pmht_opt.cli import main\n"
        "sys.exit(main(sys.argv[1:]))"
    )
    done = subprocess.run([sys.executable, "-c", code, "study", "anneal"], capture_output=True, text=True)
    assert done.returncode == 2
    assert (
        'pandas; install the extra: pip install ".[studies]"' in done.stderr
        and "Traceback" not in done.stderr
    )


def test_stress_trials_time_their_slowest_mstep() -> None:
    from studies.constraints_stress import trial

    # Named by the diagnosis after a failed M-step, not proven (the wall is not convex): that M-step is
    # timed up to the error.
    walled = trial("L", "walled-end", "clarabel")
    assert walled["outcome"] == "unproven" and walled["raised"] == "ScheduleError"
    assert 0.0 < walled["slowest_mstep"] <= walled["seconds"]
    # Named by a pre-check before any M-step: nothing to time.
    precheck = trial("L", "speed-1e-4+visit-0.05", "clarabel")
    assert precheck["outcome"] == "infeasible" and precheck["slowest_mstep"] is None


TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
#: Runs the study command in a fresh interpreter with the probe study (tests/probe_study.py) registered.
COMMAND = (
    f"import sys; sys.path.insert(0, {str(TESTS)!r})\n"
    "from studies import cli\n"
    "cli.STUDIES['probe'] = cli.Study('probe_study', 'the study command itself')\n"
    "sys.exit(cli.main(sys.argv[1:]))"
)


@pytest.fixture
def probe(monkeypatch: pytest.MonkeyPatch) -> None:
    """The probe study (tests/probe_study.py) as ``pmht-opt study probe``."""
    from studies import cli

    monkeypatch.setitem(cli.STUDIES, "probe", cli.Study("probe_study", "the study command itself"))


def test_a_crashed_trial_is_reported_and_fails_the_exit_status_under_quiet(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], probe: None
) -> None:
    argv = ["study", "probe", "--mode", "crash", "--workers", "2", "--quiet", "--out", str(tmp_path)]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "probe: 1 trial crashed their worker" in err and 'trial {"mode":"crash","seed":2}' in err
    assert "signal 9" in err and err.strip().splitlines()[-1].endswith("run the same command to retry them.")
    rows = read_rows(tmp_path / "probe.jsonl", probe_study.TABLE.schema, "probe")
    assert {r["seed"]: r["error_class"] for r in rows} == {0: "", 1: "", 2: "WorkerCrashed", 3: ""}
    assert (tmp_path / "probe.md").read_text().startswith("finished: 3")


def test_nan_results_are_flagged_by_trial_and_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], probe: None
) -> None:
    argv = ["study", "probe", "--mode", "nan", "--quiet", "--out", str(tmp_path)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    trial = '{"mode":"nan","seed":1}'
    path = tmp_path / "probe.jsonl"
    assert f"pmht-opt study: warning: {path}: trial {trial}: column square: the trial returned NaN" in err
    table = (tmp_path / "probe.md").read_text()
    assert "**NaN results** (1;" in table and f"- trial `{trial}`: column `square`" in table
    summary = json.loads((tmp_path / "probe_summary.json").read_text())
    assert summary["nan_results"] == [{"trial": trial, "column": "square"}]
    # Stored, it is flagged again whenever it is read.
    assert main(argv) == 0
    assert f"probe.jsonl:4: trial {trial}: column square: NaN result" in capsys.readouterr().err


def test_damage_is_reported_in_one_line_of_the_projects_own(tmp_path: Path) -> None:
    argv = ["probe", "--quiet", "--out", str(tmp_path)]
    done = subprocess.run([sys.executable, "-c", COMMAND, *argv], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    path = tmp_path / "probe.jsonl"
    lines = path.read_text().splitlines(keepends=True)
    lines[0] = lines[0][:25] + "\n"  # the header cut
    lines[3] = lines[3].replace('"square":1.0', '"square":"1"')
    path.write_text("".join(lines))
    done = subprocess.run([sys.executable, "-c", COMMAND, *argv], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    warned = [line for line in done.stderr.splitlines() if "warning" in line.lower()]
    assert warned == [
        f"pmht-opt study: warning: {path}:1: header: truncated or not JSON; a correct header is written "
        "and every valid row kept.",
        f'pmht-opt study: warning: {path}:4: trial {{"mode":"plain","seed":1}}: square: expected float, '
        "got str; the row is dropped and its trial runs again.",
    ]
    assert "Warning:" not in done.stderr and ".py:" not in done.stderr


def test_a_foreign_file_at_the_results_path_is_refused_not_overwritten(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], probe: None
) -> None:
    path = tmp_path / "probe.jsonl"
    path.write_text("name,value\nalpha,1\n")
    for extra in ([], ["--fresh"]):
        assert main(["study", "probe", "--quiet", "--out", str(tmp_path), *extra]) == 2
        err = capsys.readouterr().err
        assert f"{path}: not a results file of this project" in err and len(err.strip().splitlines()) == 1
        assert path.read_text() == "name,value\nalpha,1\n"


def test_a_silent_dask_scheduler_fails_within_seconds_naming_it(tmp_path: Path) -> None:
    """A port that accepts connections and never answers: Dask itself would wait for its handshake
    forever; the study stops within seconds with the project's error naming the address."""
    if importlib.util.find_spec("distributed") is None:
        pytest.skip("the dask extra is not installed")
    server = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def accept() -> None:
        with contextlib.suppress(OSError):
            while True:
                accepted.append(server.accept()[0])

    threading.Thread(target=accept, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    argv = ["probe", "--quiet", "--out", str(tmp_path), "--dask-scheduler", address]
    started = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, "-c", COMMAND, *argv], capture_output=True, text=True, cwd=ROOT, timeout=60
        )
    finally:
        server.close()
        for conn in accepted:
            conn.close()
    assert accepted  # the port really accepted the connection
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == (
        f"pmht-opt study: error: --dask-scheduler {address}: no answer from a Dask scheduler within 5 s "
        "(the port accepts connections but does not speak Dask's protocol)."
    )
    assert time.perf_counter() - started < 20
