"""Study 2 (``pmht-opt study solvers``): the quick run writes its files, and the numbers behave."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
import solvers
from pmht_opt import PMHTConfig, plan_pmht
from pmht_opt.cli import main
from pmht_opt.exceptions import InfeasibleError, SolverError, UnknownSolverError
from studies.solver_study.backends import (
    STATUS_FAILED,
    STATUS_INACCURATE,
    STATUS_INFEASIBLE,
    STATUS_NA,
    STATUS_OK,
    classify,
    cvxpy_takes,
    error_status,
)
from studies.solver_study.iterates import make_iterate, study_scenario
from studies.solver_study.msteps import MSTEPS, MSTEPS_NAME
from studies.solver_study.plans import PLANS
from studies.store import read_rows


def test_quick_solvers_study(tmp_path: Path) -> None:
    # CLARABEL through cvxpy (and its tight and accept-inaccurate rows) and GLOP, an LP-only solver
    # that must come out 'n/a': the other cvxpy solvers only add time.
    args = ["study", "solvers", "--quick", "--cvxpy-solvers", "CLARABEL", "GLOP", "--repeats", "1"]
    assert main([*args, "--out", str(tmp_path), "--quiet"]) == 0
    for name in ("solvers.md", "solvers.png", "solvers.json", "solvers_msteps.jsonl", "solvers_plans.jsonl"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert (tmp_path / "solvers.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    rows = read_rows(tmp_path / "solvers_msteps.jsonl", MSTEPS, MSTEPS_NAME)
    unc = [r for r in rows if r["part"] == "unconstrained"]
    assert {r["case"] for r in unc} == {"unconstrained-early", "unconstrained-late"}
    for r in unc:
        if r["backend"] == "kalman":
            assert r["status"] == "optimal" and r["max_pos_diff"] == 0.0
        if r["backend"] in ("banded", "clarabel", "osqp"):
            # The banded smoother and the QP backends solve the same M-step as the RTS smoother.
            assert r["status"] == "optimal", r
            assert r["max_pos_diff"] < 1e-6, r
            assert abs(r["objective_gap"]) < 1e-9, r
            assert r["iterations"] >= 0 and r["time_s"] > 0  # an equality QP may need no IPM step
        if r["backend"] == "cvxpy/GLOP":
            assert r["status"] == "n/a", r
        # Every row has a status; a failed or n/a one says why and has no measurement.
        assert r["status"] in ("optimal", "inaccurate", "failed", "infeasible", "n/a")
        if r["status"] in ("failed", "n/a"):
            assert r["message"] and not math.isfinite(r["max_pos_diff"])

    con = [r for r in rows if r["part"] == "constrained"]
    by = {(r["case"], r["backend"]): r for r in con}
    for case in ("speed+area", "obstacle"):
        assert by[(case, "kalman")]["status"] == by[(case, "banded")]["status"] == "n/a"
        ref = by[(case, "reference (cones)")]
        assert ref["status"] == "optimal" and ref["max_pos_diff"] == 0.0
        clar = by[(case, "clarabel")]
        assert clar["status"] == "optimal" and clar["max_violation"] < 1e-6
        assert clar["conic"] is True and by[(case, "clarabel (polygons)")]["conic"] is False
        assert abs(clar["objective_gap"]) < 1e-8
        # OSQP solves the polygonal problem: compared with its exact solve it is close; its gap to the
        # conic reference is never negative beyond tolerance (an inner polygon cannot do better).
        osqp = by[(case, "osqp")]
        assert osqp["status"] == "optimal" and osqp["conic"] is False
        assert osqp["max_pos_diff_same"] < 1e-2
        assert osqp["objective_gap"] > -1e-6
        assert by[(case, "cvxpy/CLARABEL (tight)")]["status"] == "optimal"

    plans = read_rows(tmp_path / "solvers_plans.jsonl", PLANS.schema, PLANS.name)
    kinds = {r["backend"]: r for r in plans}
    assert kinds["kalman"]["status"] == "optimal" and kinds["kalman"]["max_pos_diff"] == 0.0
    assert kinds["clarabel"]["status"] == "optimal" and kinds["clarabel"]["max_pos_diff"] < 1e-4
    assert kinds["banded"]["status"] == "optimal" and kinds["banded"]["max_pos_diff"] < 1e-8
    assert kinds["osqp"]["iterations_done"] == 10
    assert kinds["cvxpy/GLOP"]["status"] == "n/a" and kinds["cvxpy/GLOP"]["failed_at"] == 1

    summary = json.loads((tmp_path / "solvers.json").read_text())
    assert {s["backend"] for s in summary["plans"]} >= {"kalman", "banded", "clarabel", "osqp"}
    text = (tmp_path / "solvers.md").read_text()
    assert "Reference: the kalman (RTS) smoother" in text
    assert "Kalman cannot take constraints: the reference is Clarabel" in text

    # The tables again from the raw tables alone: the same text.
    (tmp_path / "solvers.md").unlink()
    assert main(["study", "solvers", "--out", str(tmp_path), "--tables-only", "--quiet"]) == 0
    assert (tmp_path / "solvers.md").read_text() == text
    again = json.loads((tmp_path / "solvers.json").read_text())
    assert again["tables_only"] and again["provenance"] == summary["provenance"]  # the measuring run's
    assert again["runs"][0]["commit"] == summary["provenance"]["commit"]


def test_iterate_is_the_planners_run() -> None:
    # The M-steps measured are those of the planner's own run: the paths before iteration K and
    # K + 1 are the plans of K - 1 and K iterations, bit for bit.
    sc = study_scenario("A", 0, horizon=30)
    it = make_iterate(sc, 3)
    assert (it.prev.iteration, it.cur.iteration) == (3, 4)
    for step, done in ((it.prev, 2), (it.cur, 3)):
        # Stopped after ``done`` iterations of the default run (not an iteration limit, which would
        # compress its annealing schedule): a plan fitted during annealing, on purpose.
        with pytest.warns(po.PlanWarning):
            plan = plan_pmht(sc, PMHTConfig(solver="kalman", stop=[lambda p, k=done: p.iteration >= k]))
        np.testing.assert_array_equal(step.states, plan.states)
        assert step.r == PMHTConfig().anneal.values(sc.r, 10)[done]
    data = it.cur.data(sc)
    assert data.ctx is None and data.W.shape == (sc.horizon, sc.n_platforms)


@pytest.mark.parametrize(
    ("status", "expected"),
    [
        (solvers.Status.OPTIMAL, STATUS_OK),
        (solvers.Status.OPTIMAL_INACCURATE, STATUS_INACCURATE),
        (solvers.Status.PRIMAL_INFEASIBLE, STATUS_INFEASIBLE),
        (solvers.Status.DUAL_INFEASIBLE, STATUS_INFEASIBLE),
        (solvers.Status.MAX_ITER, STATUS_FAILED),
        (solvers.Status.NUMERICAL_ERROR, STATUS_FAILED),
    ],
)
def test_statuses_are_classified_by_type(status: solvers.Status, expected: str) -> None:
    assert classify(status) == expected


def test_failures_are_classified_by_type_and_capability() -> None:
    err = SolverError("failed", backend="x", status="whatever the backend says")
    assert error_status(err, "clarabel")[:2] == (STATUS_FAILED, "whatever the backend says")
    assert error_status(InfeasibleError("no", status="Infeasible"), "clarabel")[0] == STATUS_INFEASIBLE
    assert error_status(UnknownSolverError("solver: no such"), "cvxpy/NOPE")[0] == STATUS_NA
    # Kalman takes no constraints; an LP-only cvxpy solver takes no quadratic objective; a QP-only
    # one takes no cones.
    assert error_status(err, "kalman", frozenset({"soc"}))[0] == STATUS_NA
    cp = pytest.importorskip("cvxpy")
    installed = set(cp.installed_solvers())
    if "GLOP" in installed:
        assert error_status(err, "cvxpy/GLOP")[0] == STATUS_NA
    if "OSQP" in installed:
        assert cvxpy_takes("OSQP", frozenset({"linear"})) and not cvxpy_takes("OSQP", frozenset({"soc"}))
    assert cvxpy_takes("CLARABEL", frozenset({"linear", "soc"}))
    assert not cvxpy_takes("NO_SUCH_SOLVER", frozenset())


def test_the_reproduce_command_names_every_option_a_run_changed() -> None:
    from studies.compare_solvers import Options

    assert Options().command() == "pmht-opt study solvers"
    assert Options(seeds=2, kinds=("A", "C"), cvxpy_solvers=("CLARABEL", "SCS")).command() == (
        "pmht-opt study solvers --kinds A C --seeds 2 --cvxpy-solvers CLARABEL SCS"
    )
    quick = Options.from_args(
        argparse.Namespace(
            quick=True,
            kinds=["B"],
            repeats=None,
            seeds=3,
            cvxpy_seeds=None,
            iterations=None,
            horizon=None,
            parts=["plans"],
            cvxpy_solvers=["CLARABEL"],
        )
    )
    assert quick.command() == (
        "pmht-opt study solvers --quick --kinds B --seeds 3 --parts plans --cvxpy-solvers CLARABEL"
    )
