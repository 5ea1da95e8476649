"""The validation boundary: every input the fuzzing pass found, refused with the project's own error
naming the field, or handled correctly; foreign exceptions translated inside a plan; interrupts kept
as interrupts; files read back as written."""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import pmht_opt as po
import solvers
from pmht_opt import cli, validation
from pmht_opt.constraints import Terminal
from pmht_opt.exceptions import ConfigError, ScenarioError, SolverError
from pmht_opt.io import export_csv, export_geojson, load_mission, save_mission
from pmht_opt.io.mission import Mission
from pmht_opt.plotting import plot_result

LOCALES = [[1.0, 1.0], [2.0, 2.5], [3.0, 1.0]]
FAST = po.PMHTConfig(max_iter=2, anneal=None)
#: The smoothed planner fixes the EM's own options itself: only its stop is taken from a config.
SMOOTHED = po.PMHTConfig(max_iter=2)


def scenario(**changes: Any) -> po.Scenario:
    fields: dict[str, Any] = {"locales": LOCALES, "starts": [[0.0, 0.0]], "horizon": 20, **changes}
    return po.Scenario(**fields)


def field_of(err: Exception) -> str:
    """The field a message names first (``"dt: expected ..."`` -> ``"dt"``)."""
    return str(err).split(":")[0].split(" ")[0]


# ------------------------------------------------------------------ files read back as written

NAMES = [
    "plain",
    "a\U0001f600b outside the BMP \U00010348",
    "controls \x00\x01\x08\t\n\x0b\x0c\r\x1b\x1f and delete \x7f",
    "quotes \" ' \"\"\" ''' and backslashes \\ \\\\ \\u0041",
    "",
]


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize("name", NAMES)
def test_scenario_files_round_trip_any_name(tmp_path: Path, suffix: str, name: str) -> None:
    sc = scenario(name=name, bounds=(0, 4, 0, 3))
    path = sc.save(tmp_path / "new" / "folder" / f"s{suffix}")  # missing folders are created
    back = po.Scenario.load(path)
    assert back.name == name
    assert back.to_dict() == sc.to_dict()


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_mission_files_round_trip_any_name(tmp_path: Path, suffix: str) -> None:
    mission = Mission(scenario(name=NAMES[1] + NAMES[2] + NAMES[3]))
    path = save_mission(mission, tmp_path / "sub" / f"m{suffix}")
    assert load_mission(path).scenario.name == mission.scenario.name


def test_a_name_no_file_can_hold_is_refused() -> None:
    with pytest.raises(ScenarioError, match="name: expected text, got an unpaired surrogate"):
        scenario(name="a\ud800b")
    with pytest.raises(ScenarioError, match="name: expected a string"):
        scenario(name=5)


def test_a_file_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "latin1.json"
    path.write_bytes(b'{"name": "\xe9t\xe9", "locales": [[1, 1]], "starts": [[0, 0]]}')
    with pytest.raises(ScenarioError, match="not UTF-8"):
        po.Scenario.load(path)


def test_an_unwritable_scenario_path_is_a_scenario_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    with pytest.raises(ScenarioError, match="path: cannot write"):
        scenario().save(tmp_path / "file" / "s.toml")


def test_every_writer_creates_missing_folders(tmp_path: Path) -> None:
    res = po.plan_pmht(scenario(), FAST)
    assert export_csv(res, tmp_path / "a" / "p.csv").exists()
    assert export_geojson(res, tmp_path / "b" / "p.geojson").exists()
    assert save_mission(Mission(scenario()), tmp_path / "c" / "m.toml").exists()
    assert scenario().save(tmp_path / "d" / "s.json").exists()


# ------------------------------------------------------------------ nonsense and extremes refused


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"q": "1e-8"}, "q"),
        ({"horizon": "3"}, "horizon"),
        ({"horizon": 3.0}, "horizon"),
        ({"horizon": True}, "horizon"),
        ({"horizon": 10**400}, "horizon"),
        ({"horizon": 10**12}, "horizon"),
        ({"dt": True}, "dt"),
        ({"dt": 1e-300}, "dt"),
        ({"dt": 1e62}, "dt"),
        ({"r": 1e-311}, "r"),
        ({"q": 1e5}, "q"),
        ({"coverage_radius": 0.0}, "coverage_radius"),
        ({"coverage_radius": 1e8}, "coverage_radius"),
        ({"locales": [["1", "2"]]}, "locales"),
        ({"locales": [[True, False]]}, "locales"),
        ({"locales": [[1e8, 0.0]]}, "locales"),
        ({"locales": [[1, 10**400]]}, "locales"),
        ({"locales": [[1.0, 2.0], [3.0]]}, "locales"),
        ({"starts": [[0, 1.7e308, 0, 0, 0, 0]]}, "starts"),
        ({"starts": [[1e300, 0.0]]}, "starts"),
        ({"starts": [[0, 1e31, 0, 0, 0, 0]]}, "starts"),
        ({"bounds": 5}, "bounds"),
        ({"bounds": "1234"}, "bounds"),
        ({"bounds": (0, 1, 0, "1")}, "bounds[3]"),
        ({"bounds": (0, 1, 0, 1e9)}, "bounds[3]"),
    ],
)
def test_the_scenario_refuses_what_it_cannot_plan_with(changes: dict[str, Any], field: str) -> None:
    with pytest.raises(ScenarioError) as info:
        scenario(**changes)
    assert field_of(info.value) == field


def test_the_ranges_are_inclusive_and_plan() -> None:
    lo = scenario(dt=1e-4, q=1e-14, r=1e-10, horizon=2, coverage_radius=1e-12)
    hi = scenario(dt=1e4, q=1e3, r=1e12, coverage_radius=1e7, locales=[[1e7, -1e7]])
    for sc in (lo, hi):
        res = po.plan_pmht(sc, FAST)
        assert np.all(np.isfinite(res.states))


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: po.paper_scenario("A", seed=-1), "seed"),
        (lambda: po.paper_scenario("A", seed=1.5), "seed"),
        (lambda: po.paper_scenario("A", seed="x"), "seed"),
        (lambda: po.paper_scenario("A", seed=True), "seed"),
        (lambda: po.paper_scenario("A", seed=0, foo=1), "foo"),
        (lambda: po.paper_scenario(1), "kind"),
        (lambda: po.paper_scenario("A", horizon="300"), "horizon"),
    ],
)
def test_paper_scenario_names_the_field(call: Any, field: str) -> None:
    with pytest.raises(ScenarioError) as info:
        call()
    assert field_of(info.value) == field


@pytest.mark.parametrize(
    ("call", "error", "field"),
    [
        (lambda: Terminal(velocity=[[0, 0], [1]]), ConfigError, "Terminal.velocity"),
        (lambda: po.PMHTConfig(snapshots=("a",)), ConfigError, "snapshots[0]"),
        (lambda: po.PMHTConfig(snapshots=5), ConfigError, "snapshots"),
        (lambda: po.PMHTConfig(tol="0.1"), ConfigError, "tol"),
        (lambda: po.PMHTConfig(max_iter=10**7), ConfigError, "max_iter"),
        (lambda: po.PMHTConfig(estep_gate=10**400), ConfigError, "estep_gate"),
        (lambda: po.PMHTConfig(solver=3), ConfigError, "solver"),
        (lambda: po.PMHTConfig(solver_settings={"eps_abs": float("nan")}), ConfigError, "solver_settings"),
        (lambda: po.PMHTConfig(anneal=("1", 3)), ConfigError, "anneal.start"),
        (lambda: po.Anneal(start=1e13), ConfigError, "anneal.start"),
        (lambda: po.Anneal(iterations=10**12), ConfigError, "anneal.iterations"),
        (lambda: po.plan_pmht(scenario(), FAST, time_prior="abc"), ScenarioError, "time_prior"),
        (
            lambda: po.plan_pmht(scenario(), FAST, platform_prior=[[True]] * 3),
            ScenarioError,
            "platform_prior",
        ),
        (lambda: po.SpeedLimit("1"), ConfigError, "SpeedLimit"),
        (lambda: po.SpeedLimit(1e300), ConfigError, "SpeedLimit"),
        (lambda: po.CircleObstacle((10**400, 0), 1.0), ConfigError, "CircleObstacle.center"),
        (lambda: po.CircleObstacle((1e8, 0), 1.0), ConfigError, "CircleObstacle.center"),
        (lambda: po.AreaBounds(0, 10**400, 0, 1), ConfigError, "AreaBounds.xmax"),
        (lambda: po.VisitAll(True), ConfigError, "VisitAll.radius"),
        (lambda: po.solve_ga_tsp(scenario(), population=8 * 10**6), ConfigError, "population"),
        (lambda: po.solve_ga_tsp(scenario(), iterations=10**30), ConfigError, "iterations"),
        (lambda: po.order_locales(scenario(), "ortools", time_limit=10**400), ConfigError, "time_limit"),
    ],
)
def test_configs_constraints_and_orderers_name_the_field(call: Any, error: type, field: str) -> None:
    with pytest.raises(error) as info:
        call()
    assert field_of(info.value) == field


def two_platforms() -> po.Scenario:
    return scenario(starts=[[0.0, 0.0], [4.0, 4.0]])


def mutated_radius() -> po.Scenario:
    sc = scenario()
    sc.coverage_radius = "0.3"  # type: ignore[assignment]
    return sc


@pytest.mark.parametrize(
    ("call", "error", "field"),
    [
        # The coverage planner and the orderers: impossible or unchecked requests.
        (
            lambda: po.plan_coverage(scenario(), config=po.PMHTConfig(constraints=[po.VisitAll(0.01)])),
            ConfigError,
            "constraints",
        ),
        (lambda: po.plan_coverage(scenario(), iterations=10**9), ConfigError, "iterations"),
        (lambda: po.plan_coverage(scenario(), starts=10**6), ConfigError, "starts"),
        (lambda: po.plan_coverage(scenario(), seed=2**32), ConfigError, "seed"),
        (lambda: po.plan_coverage(two_platforms().replace(locales=[[1.0, 1.0]])), ConfigError, "scenario"),
        (lambda: po.plan_coverage(mutated_radius()), ScenarioError, "coverage_radius"),
        (lambda: po.order_locales(scenario(), "ortools", time_limit=1e300), ConfigError, "time_limit"),
        (
            lambda: po.order_locales(scenario(), "ortools", solution_limit=2**63),
            ConfigError,
            "solution_limit",
        ),
        (lambda: po.order_locales(scenario(), "pyvrp", iterations=2**70), ConfigError, "iterations"),
        (lambda: po.order_locales(two_platforms().replace(locales=[[1.0, 1.0]])), ConfigError, "scenario"),
        # The smoothed planner's tour and options.
        (lambda: po.plan_smoothed(None, [[0, 1]]), ConfigError, "scenario"),
        (lambda: po.tour_distance(None, [[0, 1]]), ConfigError, "scenario"),
        (
            lambda: po.plan_smoothed(scenario(), [[True, 0, *range(2, len(LOCALES))]], SMOOTHED),
            ConfigError,
            "routes[0]",
        ),
        (
            lambda: po.plan_smoothed(scenario(), [list(range(len(LOCALES)))], SMOOTHED, converge="x"),
            ConfigError,
            "converge",
        ),
        (
            lambda: po.plan_smoothed(
                scenario(),
                po.TourResult.from_routes(
                    scenario(locales=np.add(LOCALES, 0.5)), [list(range(len(LOCALES)))]
                ),
                SMOOTHED,
            ),
            ConfigError,
            "tour",
        ),
        # The single M-step, the run's observers and priors, the model.
        (
            lambda: po.solve_mstep(
                scenario(), np.zeros((20, 1)), np.zeros((20, 1, 2)), 0.01, constraints=None
            ),
            ConfigError,
            "constraints",
        ),
        (
            lambda: po.solve_mstep(scenario(), np.zeros((20, 1)), np.zeros((20, 1, 2)), 0.01, settings="x"),
            ConfigError,
            "settings",
        ),
        (
            lambda: po.solve_mstep(
                scenario(), np.zeros((20, 1)), np.zeros((20, 1, 2)), 0.01, accept_inaccurate="yes"
            ),
            ConfigError,
            "accept_inaccurate",
        ),
        (lambda: po.EMCallbacks(after_iteration=1), ConfigError, "EMCallbacks.after_iteration"),
        (lambda: po.AnyOf(po.MaxIterations(1)), ConfigError, "AnyOf"),
        (lambda: po.Schedule(r=np.array([-1.0]), settled=1), ConfigError, "Schedule.r"),
        (lambda: po.Schedule(r=np.array([1.0]), settled=5), ConfigError, "Schedule.settled"),
        (lambda: po.MotionModel(dt=float("nan")), ScenarioError, "dt"),
        (lambda: po.MotionModel(q=-1.0), ScenarioError, "q"),
        (lambda: scenario().replace(locales=None), ScenarioError, "locales"),
        (
            lambda: po.Scenario.from_dict({**scenario().to_dict(), "coverage_radius": None}),
            ScenarioError,
            "coverage_radius",
        ),
        # Mission settings built in Python, whichever planner they name.
        (lambda: po.io.PlannerSettings(method="fast"), ConfigError, "method"),
        (lambda: po.io.PlannerSettings(paper="yes"), ConfigError, "paper"),
        (lambda: po.io.PlannerSettings("coverage", options={"radius": -1}), ConfigError, "radius"),
        (lambda: po.io.PlannerSettings("coverage", options={"anneal": None}), ConfigError, "anneal"),
        (lambda: po.io.PlannerSettings(shared={"solver": "gurobi"}), ConfigError, "solver"),
        (lambda: po.io.PlannerSettings(shared={"bogus": 1}), ConfigError, "bogus"),
        (lambda: po.io.PlannerSettings("coverage", tol=0.1), ConfigError, "tol"),
        (lambda: po.plan(scenario(), "coverage", anneal=None), ConfigError, "anneal"),
        (lambda: po.plan(scenario(), "pmht", solver="osqp"), ConfigError, "solver"),
        (lambda: po.plan(scenario(), "fastest"), ConfigError, "method"),
        (lambda: po.plan(scenario(), "pmht", stop=5), ConfigError, "stop"),
        (lambda: po.plan(scenario(), "pmht", callback=5), ConfigError, "callback"),
        (lambda: po.plan(scenario(), "pmht", settings={"solver": "osqp"}), ConfigError, "settings"),
        (lambda: po.plan_smoothed(scenario(), [[0, 1, 2]], FAST), ConfigError, "config.anneal"),
        (lambda: po.plan_coverage(scenario(), 0.3, po.PMHTConfig(tol=1.0)), ConfigError, "config.tol"),
        (lambda: po.Settings(seed=-1), ConfigError, "seed"),
        (lambda: po.Settings(threads=0), ConfigError, "threads"),
        (
            lambda: po.TourResult.from_routes(scenario(), [[0, 1, 2]]).validate(min_tour="x"),
            ConfigError,
            "min_tour",
        ),
        (lambda: po.TourResult.from_routes(scenario(), [[0, 1, 2]]).validate("x"), ConfigError, "scenario"),
        (lambda: po.TourResult.from_routes(scenario(), [[0, 1, 2]], method=5), ConfigError, "method"),
        (lambda: po.CvxpyConstraint(lambda v: [], name=5), ConfigError, "CvxpyConstraint.name"),
        # Missions built in Python.
        (lambda: Mission(None), ConfigError, "scenario"),  # type: ignore[arg-type]
        (lambda: Mission(scenario(), constraints=[1]), ConfigError, "constraints"),  # type: ignore[list-item]
        (lambda: Mission(scenario(), planner="x"), ConfigError, "planner"),  # type: ignore[arg-type]
        (lambda: Mission(scenario(), altitude=-1.0), ConfigError, "altitude"),
        (lambda: Mission(scenario(), origin=(0.0, 0.0)), ConfigError, "origin"),  # type: ignore[arg-type]
        (lambda: po.io.plan_mission(None), ConfigError, "mission"),  # type: ignore[arg-type]
        (lambda: save_mission(None, "m.toml"), ConfigError, "mission"),  # type: ignore[arg-type]
    ],
)
def test_planners_orderers_and_settings_name_the_field(call: Any, error: type, field: str) -> None:
    with pytest.raises(error) as info:
        call()
    assert field_of(info.value) == field


def test_huge_priors_are_normalised_without_overflow() -> None:
    sc = scenario(horizon=20)
    huge = po.plan_pmht(sc, FAST, time_prior=np.full((len(LOCALES), 20), 1e308))
    plain = po.plan_pmht(sc, FAST, time_prior=np.ones((len(LOCALES), 20)))
    assert np.array_equal(huge.positions, plain.positions)


def test_metrics_name_the_field() -> None:
    res = po.plan_pmht(scenario(), FAST)
    for bad in ("a", True, -1.0, 10**400):
        with pytest.raises(ConfigError, match="radius"):
            res.coverage(bad)  # type: ignore[arg-type]
    for box in ("abcd", 5, (0, 1, 0)):
        with pytest.raises(ConfigError, match="bounds"):
            res.max_excursion(box)  # type: ignore[arg-type]


def test_an_annealing_start_not_above_r_is_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"anneal.start: the schedule starts at r = 1e-05, not above .* 0.01"
    ):
        po.plan_pmht(scenario(), po.PMHTConfig(max_iter=3, anneal=(1e-5, 3)))
    with pytest.raises(ConfigError, match=r"anneal.start: .* r = 1, not above the scenario's r = 2"):
        po.plan_pmht(scenario(r=2.0), po.PMHTConfig(max_iter=3, anneal=(1.0, 3)))
    # The default schedule starts at 100 r, whatever the units.
    assert po.plan_pmht(scenario(r=2.0), po.PMHTConfig(max_iter=10)).history.r[1] == 200.0


def test_assumed_bounds_are_logged(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.INFO, logger="pmht_opt"):
        sc = scenario()
    assert sc.bounds == (1.0, 3.0, 1.0, 2.5)
    assert "bounds: none given; assumed the locales' bounding box [1, 3, 1, 2.5]" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="pmht_opt"):
        scenario(bounds=(0, 4, 0, 4))
    assert "bounds" not in caplog.text


# ------------------------------------------------------------------ inside a plan


def test_a_foreign_exception_inside_a_plan_is_a_solver_error_with_its_cause(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from pmht_opt.mstep.banded import BandedMStep

    def broken(self: Any, data: Any) -> Any:
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr(BandedMStep, "_solve", broken)
    with pytest.raises(SolverError, match="an EM iteration failed: LinAlgError: singular matrix") as info:
        po.plan_pmht(scenario(), FAST)
    assert isinstance(info.value.__cause__, np.linalg.LinAlgError)

    monkeypatch.setattr(BandedMStep, "_solve", lambda self, data: [][0])
    with pytest.raises(SolverError, match="the M-step failed: IndexError") as info:
        po.solve_mstep(scenario(), np.ones((20, 1)), np.ones((20, 1, 2)), 0.01, solver="banded")
    assert isinstance(info.value.__cause__, IndexError)


def test_memory_errors_inside_a_plan_are_solver_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    import pmht_opt.em

    def no_memory(*args: Any, **kwargs: Any) -> Any:
        raise MemoryError

    monkeypatch.setattr(pmht_opt.em, "estep", no_memory)
    with pytest.raises(SolverError, match="setting up the plan failed: out of memory") as info:
        po.plan_pmht(scenario(), FAST)
    assert isinstance(info.value.__cause__, MemoryError)


def test_the_callers_own_exceptions_and_interrupts_pass_unchanged() -> None:
    def callback(iteration: int, objective: float) -> None:
        raise ZeroDivisionError("the caller's")

    with pytest.raises(ZeroDivisionError, match="the caller's"):
        po.plan_pmht(scenario(), FAST, callback=callback)

    def stop(progress: Any) -> bool:
        raise KeyError("criterion")

    with pytest.raises(KeyError, match="criterion"):
        po.plan_pmht(scenario(), po.PMHTConfig(max_iter=2, anneal=None, stop=[stop]))

    def interrupt(iteration: int, objective: float) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        po.plan_pmht(scenario(), FAST, callback=interrupt)


def test_a_plan_with_a_non_finite_state_is_never_returned() -> None:
    with pytest.raises(SolverError, match="non-finite"):
        validation.check_finite_plan(np.array([[[0.0, np.nan]]]), "osqp")
    with po.EMRun(scenario(), FAST) as run:
        run.step()
        run.states[0, 5, 0] = np.inf
        with pytest.raises(SolverError, match="banded: the plan has non-finite states"):
            run.result()


# ------------------------------------------------------------------ backends


def test_backend_setup_errors_are_the_projects(capfd: pytest.CaptureFixture[str]) -> None:
    for solver, settings in (
        ("osqp", {"eps_abs": -1}),
        ("osqp", {"eps_abs": "x"}),
        ("clarabel", {"max_iter": -1}),
        ("clarabel", {"direct_solve_method": "foo"}),
        ("cvxpy", {"no_such_option": 1}),
    ):
        with pytest.raises(ConfigError, match="solver_settings") as info:
            po.plan_pmht(scenario(), po.PMHTConfig(solver=solver, max_iter=2, solver_settings=settings))
        assert isinstance(info.value.__cause__, solvers.SettingsError), (solver, settings)
    capfd.readouterr()  # OSQP's C code prints its own line on stderr
    # Data OSQP refuses (bounds beyond its infinity) is the layer's ProblemError.
    problem = solvers.QPProblem(P=np.eye(1), q=np.zeros(1), A=np.eye(1), b=[1e31], cones=[solvers.Zero(1)])
    with pytest.raises(solvers.ProblemError, match="OSQP refused the problem"):
        solvers.get_session_class("osqp")(problem)
    capfd.readouterr()


# ------------------------------------------------------------------ interrupts


@pytest.mark.parametrize("backend", ["osqp", "clarabel"])
def test_an_interrupted_status_is_an_interrupt_not_a_retry(
    monkeypatch: pytest.MonkeyPatch, backend: str
) -> None:
    session = solvers.get_session_class(backend)
    calls: list[int] = []

    def interrupted(self: Any) -> solvers.QPSolution:
        calls.append(1)
        raw = "interrupted" if backend == "osqp" else "CallbackTerminated"
        return solvers.QPSolution(status=solvers.Status.INTERRUPTED, backend=self.name, raw_status=raw)

    monkeypatch.setattr(session, "_solve", interrupted)
    with pytest.raises(KeyboardInterrupt, match=f"{backend}: the solve was interrupted"):
        po.plan_pmht(scenario(), po.PMHTConfig(solver=backend, max_iter=3, anneal=None))
    assert len(calls) == 1  # no fresh session, no fallback settings


CHILD = textwrap.dedent(
    """
    import sys
    import solvers.osqp_
    from pmht_opt import cli
    from pmht_opt.mstep import tuning

    # Settings that never converge: the solve runs until it is interrupted.
    slow = {"eps_abs": 1e-30, "eps_rel": 0.0, "max_iter": 10**9, "check_termination": 0}
    tuning.DEFAULTS["osqp"] = {**tuning.DEFAULTS["osqp"], **slow}
    solve = solvers.osqp_.OSQPSession._solve

    def traced(self):
        print("osqp solve", file=sys.stderr, flush=True)
        return solve(self)

    solvers.osqp_.OSQPSession._solve = traced
    sys.exit(cli.main(sys.argv[1:]))
    """
)


def test_sigint_during_an_osqp_solve_exits_130_without_a_retry(tmp_path: Path) -> None:
    mission = tmp_path / "m.toml"
    mission.write_text(
        "locales = [[1.0, 1.0], [3.0, 2.0]]\nstarts = [[0.0, 0.0]]\nhorizon = 300\n\n"
        '[planner]\nmethod = "pmht"\nsolver = "osqp"\n'
        "iterations = 3\nanneal = false\n"
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1]) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, "plan", str(mission), "--quiet", "--json", str(tmp_path / "p.json")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a shell's foreground job
    )
    assert proc.stderr is not None
    os.set_blocking(proc.stderr.fileno(), False)
    seen = b""
    deadline = time.monotonic() + 60
    while b"osqp solve" not in seen and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.1)
        seen += proc.stderr.read() or b""
    time.sleep(0.5)  # well inside the solve
    proc.send_signal(signal.SIGINT)
    _, rest = proc.communicate(timeout=60)
    err = (seen + rest).decode()
    assert proc.returncode == cli.EXIT_INTERRUPTED, err
    assert err.count("osqp solve") == 1, err  # interrupted once, never retried
    assert "Traceback" not in err and err.rstrip().splitlines()[-1] == "pmht-opt: interrupted."
    assert not (tmp_path / "p.json").exists()


# ------------------------------------------------------------------ the command line


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["scenario", "A", "--out", "{tmp}/s.yaml"], "--out: unknown scenario format '.yaml'"),
        (["scenario", "A", "--out", "/proc/self/s.toml"], "--out: cannot write in '/proc/self'"),
        (["plan", "{mission}", "--json", "{tmp}/m.txt"], "--json: unknown metrics format '.txt'"),
        (["plan", "{mission}", "--json", "/proc/self/m.json"], "--json: cannot write in '/proc/self'"),
        (["plan", "{mission}", "--out", "{tmp}/f.docx"], "--out: unknown figure format '.docx'"),
        (["plan", "{mission}", "--out", "{tmp}"], "is a directory"),
        (["plan", "{bad}"], "b.toml: horizon: expected an integer from 2 to 100000, got 1000000"),
        (["plan", "{mission}", "--seed", "-1"], "seed: expected an integer from 0"),
        (["plan", "{mission}", "--ordering", "ga"], "--ordering: an option of the smoothed planner"),
        (["plan", "{mission}", "--example", "survey"], "give a mission file or --example NAME, not both"),
    ],
)
def test_cli_outputs_and_inputs_are_checked_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    if "/proc/self" in " ".join(argv) and not Path("/proc/self").is_dir():
        pytest.skip("needs /proc")
    mission = tmp_path / "m.toml"
    mission.write_text(
        "locales = [[1.0, 1.0]]\nstarts = [[0.0, 0.0]]\nhorizon = 20\n"
        '[planner]\nmethod = "pmht"\niterations = 2\n'
    )
    bad = tmp_path / "b.toml"
    bad.write_text("locales = [[1.0, 1.0]]\nstarts = [[0.0, 0.0]]\nhorizon = 1000000\n")
    args = [a.format(tmp=tmp_path, mission=mission, bad=bad) for a in argv]
    assert cli.main([*args, "--quiet"] if args[0] == "plan" else args) == cli.EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("pmht-opt: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "p.json").exists()


def test_cli_round_trips_a_scenario_through_json_and_toml(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for suffix in (".toml", ".json"):
        path = tmp_path / "deep" / f"s{suffix}"
        assert cli.main(["scenario", "C", "--seed", "3", "--out", str(path)]) == 0
        assert po.Scenario.load(path).to_dict() == po.paper_scenario("C", seed=3).to_dict()
    capsys.readouterr()
    text = json.loads((tmp_path / "deep" / "s.json").read_text(encoding="utf-8"))
    assert text["name"] == "C (seed 3)"


def test_cli_schedule_options_replace_a_files_unsuitable_schedule(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file in metres (r = 25) plans with the library's default schedule (it starts at 100 r); a
    file's schedule that starts below r is refused, naming what to write, unless the command line
    replaces it."""
    mission = tmp_path / "m.toml"
    mission.write_text("locales = [[0.0, 0.0], [100.0, 50.0]]\nstarts = [[0.0, 0.0]]\nhorizon = 20\nr = 25.0")
    assert cli.main(["plan", str(mission), "--quiet", "--iterations", "2"]) == 0
    planner = '\n[planner]\nmethod = "pmht"\nanneal = { start = 1.0, iterations = 2 }'
    mission.write_text(mission.read_text() + planner)
    assert cli.main(["plan", str(mission), "--quiet", "--iterations", "2"]) == cli.EXIT_ERROR
    assert "planner.anneal: the schedule starts at r = 1, not above" in capsys.readouterr().err
    assert cli.main(["plan", str(mission), "--quiet", "--iterations", "2", "--no-anneal"]) == 0
    assert cli.main(["plan", str(mission), "--quiet", "--iterations", "2", "--anneal", "2500", "2"]) == 0
    assert cli.main(["plan", str(mission), "--quiet", "--anneal", "1", "2"]) == cli.EXIT_ERROR
    assert "--anneal: anneal: the schedule starts at r = 1, not above" in capsys.readouterr().err


def test_mission_and_point_files_that_are_not_utf8_are_refused(tmp_path: Path) -> None:
    mission = tmp_path / "m.toml"
    mission.write_bytes(b'name = "\xff"\nlocales = [[1.0, 1.0]]\nstarts = [[0.0, 0.0]]\n')
    with pytest.raises(ScenarioError, match=r"m\.toml: not UTF-8"):
        load_mission(mission)
    (tmp_path / "sites.csv").write_bytes(b"x,y\n1,\xff\n")
    mission.write_text('locales = "sites.csv"\nstarts = [[0.0, 0.0]]\n')
    with pytest.raises(ScenarioError, match=r"sites\.csv: not UTF-8"):
        load_mission(mission)


PLAN_FILES = [
    ("p.plan", "[1, 2]", "not a QGroundControl plan"),
    ("p.plan", '{"fileType": "Plan"}', "mission, items or their params are malformed"),
    ("p.plan", '{"fileType": "Plan", "mission": {"items": [{"command": 16}]}}', "malformed"),
    ("p.plan", '{"fileType": "Plan", "mission": {"items": [{"command": 16, "params": [1]}]}}', "no latitude"),
    ("g.geojson", "[1]", "frame None"),
    ("g.geojson", '{"pmht_opt": {"frame": "plane"}, "features": []}', "no path feature"),
    (
        "g.geojson",
        '{"pmht_opt": {"frame": "plane"}, "features": [{"properties": {"kind": "path"}, "geometry": '
        '{"coordinates": [[0, 0]]}}]}',
        "malformed",
    ),
    (
        "g.geojson",
        '{"pmht_opt": {"frame": "plane"}, "features": [{"properties": {"kind": "path", "platform": 0}, '
        '"geometry": {"coordinates": [[1]]}}]}',
        "finite",
    ),
    (
        "g.geojson",
        '{"pmht_opt": {"frame": "plane"}, "features": [{"properties": {"kind": "path", "platform": 0}, '
        '"geometry": {"type": "MultiLineString", "coordinates": [[[0, 0], [1, 1]], [[1, 1]]]}}]}',
        "fewer than two positions",
    ),
    ("c.csv", b"\xff\xfe", "cannot read"),
    ("p.plan", b"\xff\xfe", "cannot read"),
]


@pytest.mark.parametrize(("name", "content", "message"), PLAN_FILES)
def test_malformed_plan_files_are_scenario_errors(
    tmp_path: Path, name: str, content: Any, message: str
) -> None:
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    read = {".plan": po.io.read_qgc_plan, ".geojson": po.io.read_geojson_paths, ".csv": po.io.read_plan_csv}
    with pytest.raises(ScenarioError, match=message):
        read[path.suffix](path)


def test_exports_check_their_path_origin_and_format(tmp_path: Path) -> None:
    res = po.plan_pmht(scenario(), FAST)
    with pytest.raises(ScenarioError, match=r"path: cannot write .*: Is a directory"):
        export_csv(res, tmp_path)
    with pytest.raises(ConfigError, match="path: expected a file path, got None"):
        export_geojson(res, None)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="origin: expected a GeoOrigin or None, got tuple"):
        export_csv(res, tmp_path / "a.csv", origin=(35.0, 149.0))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"matplotlib cannot write '\.xyz' figures"):
        plot_result(res, tmp_path / "f.xyz")
    assert plot_result(res, tmp_path / "f") == tmp_path / "f.png" and (tmp_path / "f.png").stat().st_size > 0
    with pytest.raises(ConfigError, match="is a directory"):
        plot_result(res, tmp_path)
    with pytest.raises(ScenarioError, match=r"origin\.lat"):
        po.geometry.GeoOrigin(lat=2**2000, lon=0.0)


def test_contradictory_cvxpy_constraints_are_infeasible_not_a_solver_failure() -> None:
    # Clarabel (through cvxpy) reports this one as a numerical failure at annealing's first r; the
    # backend's probe of the constraints alone tells the user what is wrong.
    sc = po.Scenario(locales=LOCALES * 2, starts=[[0.0, 0.0], [4.0, 4.0]], horizon=30, bounds=(0, 4, 0, 4))
    both = po.CvxpyConstraint(lambda v: [v.positions[0][0, 0] >= 1, v.positions[0][0, 0] <= 0], name="both")
    with pytest.raises(po.InfeasibleError, match="the constraints both cannot all be met"):
        po.plan_pmht(sc, po.PMHTConfig(constraints=[both]))


def test_a_mission_files_altitude_is_checked_when_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(
        "locales = [[1.0, 1.0]]\nstarts = [[0.0, 0.0]]\n[geo]\norigin = [47.0, 8.0]\naltitude = -5.0\n"
    )
    with pytest.raises(ScenarioError, match=r"geo\.altitude: expected metres above the take-off point"):
        load_mission(path)


def test_plan_coverage_takes_every_seed_the_settings_take() -> None:
    sc = po.Scenario(locales=LOCALES, starts=[[0.0, 0.0]], horizon=30)
    res = po.plan_coverage(sc, 0.3, seed=2**32 - 1)
    assert res.coverage(0.3) == 1.0


def test_a_write_that_fails_leaves_neither_the_file_nor_a_part(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "plan.csv"
    target.parent.mkdir()
    target.write_text("the previous plan\n")
    with pytest.raises(KeyboardInterrupt), validation.writing(target) as part:
        part.write_text("half a pl")
        raise KeyboardInterrupt
    assert target.read_text() == "the previous plan\n"  # untouched, not half-written
    assert [p.name for p in target.parent.iterdir()] == ["plan.csv"]
    with validation.writing(target) as part:
        part.write_text("the new plan\n")
    assert target.read_text() == "the new plan\n" and len(list(target.parent.iterdir())) == 1


def test_scenario_fields_that_are_not_text_are_named() -> None:
    with pytest.raises(po.ScenarioError, match=r"field names must be text, got 1"):
        po.Scenario.from_dict({1: 2, "locales": [[0, 0]], "starts": [[0, 0]]})


def test_a_motion_limit_below_what_solvers_resolve_is_refused() -> None:
    sc = po.Scenario(locales=[[0.0, 0.0], [1.0, 1.0]], starts=[[0.5, 0.5]], horizon=20)
    for con, name in ((po.SpeedLimit(1e-300), "SpeedLimit"), (po.AccelLimit(1e-300), "AccelLimit")):
        with pytest.raises(po.ConfigError, match=rf"^{name}\(1e-300\): .* cannot resolve"):
            po.plan(sc, "pmht", settings=po.Settings(constraints=[con]))
    po.plan(sc, "pmht", settings=po.Settings(constraints=[po.SpeedLimit(1e-6)]), stop=po.MaxIterations(2))
