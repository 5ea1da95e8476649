"""The command line is the library: every constraint kind and every planner from a mission file gives
the plan the library gives; outputs are checked before planning; exits are clean."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geojson_checks import check_rfc7946
from test_io_flights import ring_mission
from test_io_mission import BASE, TABLES, mission_text, write

import pmht_opt as po
from pmht_opt import cli
from pmht_opt.cli import main
from pmht_opt.ordering import METHODS

#: Plans in these tests: few iterations, no annealing (so VisitAll's warm-up ends at once).
PLANNER = "iterations = 4\nanneal = false"


def plan_json(tmp_path: Path, argv: list[str]) -> dict[str, Any]:
    out = tmp_path / "plan.json"
    assert main([*argv, "--json", str(out), "--quiet"]) == 0
    return json.loads(out.read_text())  # type: ignore[no-any-return]


def library_scenario() -> po.Scenario:
    return po.Scenario(
        locales=[[1.0, 1.0], [3.0, 1.5], [2.0, 3.5], [0.5, 3.0]], starts=[[0.5, 0.5], [3.5, 3.5]], horizon=40
    )


@pytest.mark.parametrize("kind", sorted(TABLES))
def test_each_constraint_kind_plans_as_the_library(tmp_path: Path, kind: str) -> None:
    body, constraint = TABLES[kind]
    path = write(tmp_path, mission_text((kind, body), planner=PLANNER))
    got = plan_json(tmp_path, ["plan", str(path)])
    want = po.plan_pmht(library_scenario(), po.PMHTConfig(max_iter=4, anneal=None, constraints=[constraint]))
    assert np.allclose(got["positions"], want.positions, rtol=0, atol=1e-9)
    assert got["metrics"]["constraints"].keys() == want.metrics()["constraints"].keys()


def test_the_smoothed_planner_plans_as_the_library(tmp_path: Path) -> None:
    planner = 'method = "smoothed"\niterations = 4\norderer = "ga"\n'
    planner += "order_options = { seed = 2, iterations = 300 }"
    got = plan_json(tmp_path, ["plan", str(write(tmp_path, mission_text(planner=planner)))])
    sc = library_scenario()
    tour = po.order_locales(sc, "ga", seed=2, iterations=300)
    want = po.plan(sc, "smoothed", stop=po.MaxIterations(4), tour=tour)
    assert np.allclose(got["positions"], want.positions, rtol=0, atol=1e-9)
    # An older file's [planner.ordering] table says the same.
    older = 'kind = "smoothed"\niterations = 4\n[planner.ordering]\nmethod = "ga"\nseed = 2\niterations = 300'
    same = plan_json(tmp_path, ["plan", str(write(tmp_path, mission_text(planner=older)))])
    assert same["positions"] == got["positions"]
    # The command line's options override the file's; the file's smoothed options are the smoothed
    # planner's, so switching planner drops them.
    again = plan_json(tmp_path, ["plan", str(tmp_path / "m.toml"), "--planner", "pmht", "--iterations", "2"])
    assert again["metrics"]["iterations"] == 2


def test_the_coverage_planner_plans_as_the_library(tmp_path: Path) -> None:
    path = write(tmp_path, mission_text(planner='method = "coverage"\nradius = 0.5'))
    got = plan_json(tmp_path, ["plan", str(path), "--return-to-base"])
    settings = po.Settings(constraints=[po.Terminal.return_to_base()])
    want = po.plan(library_scenario(), "coverage", settings=settings, radius=0.5)
    assert np.allclose(got["positions"], want.positions, rtol=0, atol=1e-9)
    assert want.coverage(0.5) == 1.0
    # An option the chosen planner does not take is refused, naming it.
    bad = write(tmp_path, mission_text(planner='method = "coverage"\nanneal = false'))
    assert main(["plan", str(bad), "--quiet"]) == 2


def test_return_to_base_ends_at_the_start_at_rest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path, mission_text(planner=PLANNER))
    got = plan_json(tmp_path, ["plan", str(path), "--return-to-base", "--export", str(tmp_path / "p.csv")])
    end = np.array(got["positions"])[:, -1]
    assert np.max(np.abs(end - library_scenario().start_positions)) < 1e-6
    states = po.io.read_plan_csv(tmp_path / "p.csv")
    assert np.max(np.abs(states[:, -1, [1, 2, 4, 5]])) < 1e-6  # velocity and acceleration
    assert "return to base" in capsys.readouterr().out


def test_order_runs_the_library_orderings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path, mission_text())
    out = tmp_path / "tour.json"
    assert (
        main(["order", str(path), "--method", "ga", "--seed", "1", "--iterations", "200", "--json", str(out)])
        == 0
    )
    tour = po.order_locales(library_scenario(), "ga", seed=1, iterations=200)
    assert json.loads(out.read_text())["routes"] == [r.tolist() for r in tour.routes]
    assert f"total distance  {tour.total_distance:.2f}" in capsys.readouterr().out


def test_closed_orderings_are_asked_for_by_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[bool] = []

    def closing_ga(scenario: po.Scenario, seed: int = 0, closed: bool = False) -> po.TourResult:
        asked.append(closed)
        return po.solve_ga_tsp(scenario, seed=seed, iterations=50)

    monkeypatch.setitem(METHODS, "ga", closing_ga)
    path = write(tmp_path, mission_text())
    assert main(["order", str(path), "--method", "ga", "--return-to-base", "--seed", "0"]) == 0
    assert asked == [True]


@pytest.mark.parametrize(
    "option, message",
    [
        (["--out", "{tmp}"], "is a directory; give a file name"),
        (["--out", "{tmp}/fig.xyz"], "unknown figure format '.xyz'"),
        (["--export", "{tmp}/paths.kml"], "unknown export format '.kml'"),
        (["--export", "{tmp}/a.plan"], "a QGroundControl plan needs a geo-referenced mission"),
        (["--out", "{tmp}/m.toml/fig.png"], "is not a directory"),
        (["--json", "{tmp}/m.csv"], "unknown metrics format"),
        (["--animate", "{tmp}/a.mp4"], "unknown animation format '.mp4'"),
        (["--altitude", "-5"], "--altitude: expected"),
        (["--speed", "nan"], "--speed: expected"),
        (["--altitude", "40"], "--altitude: applies to QGroundControl exports only"),
        (["--speed", "3", "--export", "{tmp}/p.csv"], "--speed: applies to QGroundControl exports only"),
        (["--end", "fly", "--export", "{tmp}/p.csv"], "--end: expected one of rtl, land, hover, got 'fly'"),
        (["--end", "land"], "--end: applies to QGroundControl exports only"),
        (["--waypoints", "path"], "--waypoints: expected one of plan, tour, got 'path'"),
        (
            ["--waypoints", "tour", "--export", "{tmp}/p.csv"],
            "--waypoints: applies to QGroundControl exports",
        ),
    ],
)
def test_outputs_are_checked_before_planning(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    option: list[str],
    message: str,
) -> None:
    path = write(tmp_path, mission_text())

    def never(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("planned before checking the outputs")

    monkeypatch.setattr(cli.commands, "plan_mission", never)
    argv = ["plan", str(path), *[o.format(tmp=tmp_path) for o in option]]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmht-opt: error: ") and message in err and "Traceback" not in err
    assert err.count("\n") == 1


def test_an_unwritable_directory_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if not Path("/proc/self").is_dir():
        pytest.skip("needs /proc")
    assert main(["plan", str(write(tmp_path, mission_text())), "--out", "/proc/self/fig.png"]) == 2
    assert "cannot write in '/proc/self'" in capsys.readouterr().err


def test_bad_inputs_exit_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", str(tmp_path / "absent.toml")]) == 2
    assert capsys.readouterr().err.startswith("pmht-opt: error: cannot read")
    assert main(["plan", str(write(tmp_path, 'horizon = "300"\n' + BASE.replace("horizon = 40\n", "")))]) == 2
    assert "m.toml: horizon: expected an integer, got a string ('300')" in capsys.readouterr().err
    assert main(["plan", "--planner", "fast"]) == 2  # argparse's own usage error
    assert "invalid choice: 'fast'" in capsys.readouterr().err
    assert main(["plan"]) == 2
    assert "give a mission file, or --example NAME" in capsys.readouterr().err
    assert (
        main(["plan", str(write(tmp_path, mission_text())), "--planner", "pmht", "--anneal", "0.001", "5"])
        == 2
    )
    assert "--anneal: anneal: the schedule starts at r = 0.001, not above" in capsys.readouterr().err


def test_version_and_help_show_the_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"pmht-opt {po.__version__}"
    for command, shown in [
        ("demo", ["(default: A)", "(default: 0)", "(default: pmht-demo-SCENARIO.png)"]),
        ("plan", ["else coverage)", "else the planner's own stop)", "else pyvrp)", "over 30 iterations)"]),
        ("order", ["else pyvrp)", "(default: the method's)"]),
        ("scenario", ["(default: 0)"]),
    ]:
        assert main([command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        for s in shown:
            assert s in text, (command, s)
        assert "(default: None)" not in text


def test_example_lists_prints_and_copies(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["example"]) == 0
    assert capsys.readouterr().out.startswith("survey ")
    assert main(["example", "survey"]) == 0
    assert "[geo]" in capsys.readouterr().out
    assert main(["example", "survey", "--out", str(tmp_path / "ex")]) == 0
    assert sorted(p.name for p in (tmp_path / "ex").iterdir()) == ["survey-sites.csv", "survey.toml"]
    mission = po.io.load_mission(tmp_path / "ex" / "survey.toml")
    assert mission.scenario.n_locales == 36


def test_missing_bounds_are_announced(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan_json(tmp_path, ["plan", str(write(tmp_path, mission_text(planner="iterations = 1")))])
    assert "bounds: none given; assumed the locales' bounding box [0.5, 3, 1, 3.5]" in capsys.readouterr().out


def test_demo_animates_the_iterations(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gif = tmp_path / "em.gif"
    code = main(
        [
            "demo",
            "--planner",
            "pmht",
            "--scenario",
            "B",
            "--iterations",
            "2",
            "--out",
            str(tmp_path / "d.png"),
            "--animate",
            str(gif),
        ]
    )
    assert code == 0 and gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames >= 3  # the standing start and two iterations (the last one held)
    assert f"animation: {gif}" in capsys.readouterr().out


# ------------------------------------------------------------------ real processes


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONFAULTHANDLER"] = "1"  # a child that has to be aborted prints its threads' stacks
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1]) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_python_dash_m_runs_the_command() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "pmht_opt", "--version"],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )
    assert done.returncode == 0 and done.stdout.strip() == f"pmht-opt {po.__version__}"


def test_a_closed_pipe_exits_quietly() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "pmht_opt", "example", "survey"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_env(),
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away before the command writes anything
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == cli.EXIT_PIPE
    assert err == ""
    shell = subprocess.run(
        f"{sys.executable} -m pmht_opt example survey | head -1",
        shell=True,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )
    assert shell.stdout.startswith("#") and "Traceback" not in shell.stderr and "Error" not in shell.stderr


def _as_a_terminal_job() -> None:
    """In the child before exec: Ctrl-C at its default, as a shell starts a foreground job. A child
    that inherits an ignored SIGINT (from whatever ran before in this test process) is started with
    Ctrl-C ignored, and Python keeps it so."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_with_one_line_and_status_130(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pmht_opt",
            "demo",
            "--planner",
            "pmht",
            "--iterations",
            "100000",
            "--out",
            str(tmp_path / "x.png"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_env(),
        cwd=tmp_path,
        preexec_fn=_as_a_terminal_job,
    )
    assert proc.stderr is not None
    os.set_blocking(proc.stderr.fileno(), False)
    seen = b""
    deadline = time.monotonic() + 60
    while b"objective" not in seen and time.monotonic() < deadline:  # the progress bar: planning has begun
        time.sleep(0.2)
        seen += proc.stderr.read() or b""
        if b"objective" not in seen and b"it/s" not in seen and time.monotonic() > deadline - 50:
            break  # no progress bar (tqdm missing): the plan has surely started by now
    proc.send_signal(signal.SIGINT)
    try:
        _, rest = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:  # a hang: make the child dump every thread's stack, then fail
        proc.send_signal(signal.SIGABRT)
        _, rest = proc.communicate(timeout=30)
        raise AssertionError("no exit 60 s after SIGINT:\n" + rest.decode()[-6000:]) from None
    err = (seen + rest).decode()
    assert proc.returncode == cli.EXIT_INTERRUPTED
    assert "Traceback" not in err and err.rstrip().splitlines()[-1] == "pmht-opt: interrupted."
    assert not (tmp_path / "x.png").exists()


def _readme_block(after: str) -> list[str]:
    """The lines of the first ``bash`` block of the README after the heading ``after``."""
    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = text[text.index(after) :]
    block = section[section.index("```bash\n") + len("```bash\n") :]
    return block[: block.index("```")].strip().splitlines()


def test_the_readme_geo_example_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    setup_venv, setup_install, run = _readme_block("### A real mission")
    assert setup_venv.startswith("python3 -m venv .venv") and setup_install == "pip install ."
    argv = run.split()
    assert argv[0] == "pmht-opt"
    monkeypatch.chdir(tmp_path)
    assert main(argv[1:]) == 0
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == [
        "survey-0.plan",
        "survey-1.plan",
        "survey-2.plan",
        "survey.geojson",
        "survey.png",
    ]
    plan = json.loads((out / "survey-1.plan").read_text())
    assert plan["fileType"] == "Plan" and plan["mission"]["items"][2]["params"][6] == 60.0
    features = json.loads((out / "survey.geojson").read_text())["features"]
    assert sum(f["properties"]["kind"] == "locale" for f in features) == 36
    # The plan returns to base, at rest, within the speed limit.
    mission = po.io.example_mission("survey")
    paths = po.io.read_geojson_paths(out / "survey.geojson", mission.origin)
    for m, path in enumerate(paths):
        assert np.hypot(*(path[-1] - mission.scenario.start_positions[m])) < 1e-3


def test_the_readme_quick_start_commands() -> None:
    assert _readme_block("## Quick start") == ["python3 -m venv .venv && . .venv/bin/activate"]
    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "pip install . && pmht-opt demo" in text
    ci = (Path(__file__).resolve().parents[1] / ".ci" / "run").read_text()
    command = re.search(r"^TEST_COMMAND='(.+)'$", ci, re.M)
    assert command is not None and f"\n{command.group(1)}\n" in text  # CI runs the README's command
    assert "Python 3.11 or newer" in text and 'pip install ".[ortools]"' in text
    ignored = (Path(__file__).resolve().parents[1] / ".gitignore").read_text().split()
    assert "/pmht-demo-*.png" in ignored and "/out/" in ignored


def test_messages_speak_in_the_command_lines_words() -> None:
    """A library hint written for Python callers reaches a command-line user as flags and file keys."""
    said = cli.cli_words(
        "try solver='cvxpy' or 'osqp', or more work for OSQP (solver_settings={'mstep_work_limit': None}),"
        " or soft=True on the tightest constraint; leave it out and give the radius instead."
    )
    assert "--solver cvxpy or --solver osqp" in said and "solver=" not in said
    assert "soft = true in the constraint's table" in said and "--radius" in said
    assert "mstep_work_limit in the mission's [planner] solver_settings" in said


def test_an_ordering_figure_draws_the_missions_obstacles(tmp_path: Path) -> None:
    from pmht_opt.plotting import plot_tour

    sc = library_scenario()
    tour = po.order_locales(sc, "ga", seed=0, iterations=50)
    plain = plot_tour(tour, tmp_path / "plain.png", sc)
    zoned = plot_tour(tour, tmp_path / "zoned.png", sc, constraints=[po.CircleObstacle((2.0, 2.0), 0.5)])
    assert plain.read_bytes() != zoned.read_bytes()


def test_a_tour_or_a_speed_over_the_limit_is_refused_before_planning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def never(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("planned before checking the outputs")

    monkeypatch.setattr(cli.commands, "plan_mission", never)
    argv = ["plan", "--example", "survey", "--planner", "pmht", "--export", str(tmp_path / "s.plan")]
    assert main([*argv, "--waypoints", "tour"]) == 2
    err = capsys.readouterr().err
    assert "--waypoints tour: the pmht planner draws no straight-line tour" in err and err.count("\n") == 1
    assert main([*argv, "--speed", "12"]) == 2
    err = capsys.readouterr().err
    assert "--speed: 12 m/s is above platform 0's speed limit 10 m/s" in err and err.count("\n") == 1


def test_the_survey_exports_flights_that_end_with_rtl_or_land(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    argv = "plan --example survey --planner pmht --export out/s.plan out/s.geojson --quiet".split()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    for m in range(3):
        plan = po.io.read_qgc_plan(tmp_path / "out" / f"s-{m}.plan")
        assert plan["end"] in ("rtl", "land") and plan["speed"] == 10.0  # the survey's speed limit
        assert re.search(rf"s-{m}\.plan \(\d+ waypoints.*; ends (rtl|land); legs within [\d.]+ m", printed)
    check_rfc7946(json.loads((tmp_path / "out" / "s.geojson").read_text()))


def test_flight_options_from_the_mission_and_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = ring_mission("coverage")
    mission.end = "hover"
    path = po.io.save_mission(mission, tmp_path / "ring.toml")
    assert main(["plan", str(path), "--export", str(tmp_path / "a.plan"), "--quiet"]) == 0
    assert [po.io.read_qgc_plan(tmp_path / f"a-{m}.plan")["end"] for m in range(2)] == ["hover", "hover"]
    argv = ["plan", str(path), "--export", str(tmp_path / "t.plan"), "--waypoints", "tour", "--end", "rtl"]
    assert main([*argv, "--quiet"]) == 0
    assert "ends rtl" in capsys.readouterr().out
    for m in range(2):
        items = json.loads((tmp_path / f"t-{m}.plan").read_text())["mission"]["items"]
        assert items[-1]["command"] == 20


def test_help_lists_every_study(capsys: pytest.CaptureFixture[str]) -> None:
    from studies.cli import STUDIES

    assert main(["--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert all(name in text for name in STUDIES), text
    assert len(STUDIES) >= 9
