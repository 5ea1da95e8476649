"""Every backend equals the exact smoother on the M-steps that used to defeat them, or says it failed.

Fixtures (``tests/data/mstep_weights.npz``, written by ``tests/data/make_mstep_weights.py``): the
weights of annealing's first iteration (``r = 1``), of 30 iterations of ``PMHTConfig.paper()`` (long
coasting stretches after the last significant weight, a flat objective) and of a gated E-step (exact
zeros), on A, B and C. The reference is the RTS smoother run in extended precision, independently of
every backend. Then whole plans at a tiny ``r`` and a tiny ``dt``, where solvers used to report wrong
answers as solved: each backend gives the exact plan or raises ``SolverError``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from test_banded import rts_extended

import pmht_opt as po
from pmht_opt.mstep import solve_mstep

DATA = Path(__file__).parent / "data" / "mstep_weights.npz"
CASES = [f"{case}-{kind}" for case in ("anneal-first", "paper30", "gated") for kind in "ABC"]
#: Position agreement demanded of every backend, absolute (positions of order 10).
TOL = 1e-6


@cache
def _fixture(name: str) -> tuple[po.Scenario, np.ndarray, np.ndarray, float]:
    with np.load(DATA) as d:
        W, WZ, r, kind = d[f"{name}/W"], d[f"{name}/WZ"], float(d[f"{name}/r"]), str(d[f"{name}/kind"])
    return po.paper_scenario(kind, seed=1), W, WZ, r


@cache
def _reference(name: str) -> np.ndarray:
    """``(M, T+1, 2)`` positions of the extended-precision RTS smoother on the synthetic measurements."""
    sc, W, WZ, r = _fixture(name)
    model = sc.model
    h = np.array([1.0, 0.0, 0.0])
    out = np.zeros((sc.n_platforms, sc.horizon + 1, 2))
    for m in range(sc.n_platforms):
        w = W[:, m]
        with np.errstate(invalid="ignore", divide="ignore"):
            y = np.where(w[:, None] > 0, WZ[:, m] / np.where(w > 0, w, 1.0)[:, None], 0.0)
        for axis, cols in enumerate(((0, 1, 2), (3, 4, 5))):
            x0 = sc.initial_states[m, list(cols)]
            out[m, :, axis] = rts_extended(model.F3, model.Q3, h, r, x0, y[:, axis], w)[:, 0].astype(float)
    return out


@pytest.mark.parametrize("backend", ["banded", "kalman", "clarabel", "osqp"])
@pytest.mark.parametrize("name", CASES)
def test_every_backend_equals_the_exact_smoother_on_recorded_weights(name: str, backend: str) -> None:
    sc, W, WZ, r = _fixture(name)
    states = solve_mstep(sc, W, WZ, r, solver=backend)
    err = float(np.max(np.abs(states[:, :, [0, 3]] - _reference(name))))
    assert err <= TOL, f"{backend} on {name}: {err:.2e}"


@pytest.mark.parametrize("backend", ["clarabel", "osqp", "cvxpy"])
def test_an_idle_platform_takes_the_exact_coasting_path(backend: str) -> None:
    """A platform without weight is not solved: its answer is the exact smoother's (computed beside
    the other platforms' solves), the others' agree with it."""
    sc, W, WZ, r = _fixture("anneal-first-A")
    W, WZ = W.copy(), WZ.copy()
    W[:, 1], WZ[:, 1] = 0.0, 0.0
    exact = solve_mstep(sc, W, WZ, r, solver="banded")
    states = solve_mstep(sc, W, WZ, r, solver=backend)
    np.testing.assert_array_equal(states[1], exact[1])
    assert float(np.max(np.abs(states[:, :, [0, 3]] - exact[:, :, [0, 3]]))) <= TOL


#: Small plans OSQP used to give up on ("solved inaccurate") although nothing in them is hard: one
#: locale, two locales over three steps, a start far outside the area, coordinates of a few tenths.
TRIVIAL = {
    "one-locale-T30": {"locales": [[1.0, 2.0]], "starts": [[0.0, 0.0]], "horizon": 30},
    "two-locales-T3": {"locales": [[1.0, 2.0], [3.0, 1.0]], "starts": [[0.0, 0.0]], "horizon": 3},
    "far-start": {
        "locales": [[1.0, 2.0], [5.0, 5.0], [8.0, 3.0]],
        "starts": [[-1000.0, -1000.0]],
        "horizon": 30,
        "bounds": (0.0, 10.0, 0.0, 10.0),
    },
    "small-coordinates": {"locales": [[0.163, 0.071]], "starts": [[0.152, 1.404]], "horizon": 60},
    "two-platforms-T15": {
        "locales": [[0.394, 0.729]],
        "starts": [[4.631, 3.362], [-1.4, -3.321]],
        "horizon": 15,
    },
}


@pytest.mark.parametrize("name", list(TRIVIAL))
def test_osqp_plans_small_scenarios_as_the_exact_smoother_does(name: str) -> None:
    # OSQP's answer (ADMM, then polishing: the KKT system solved and refined) within 1e-9 of the
    # positions' scale of the exact smoother's plan, every M-step of the default annealed run.
    sc = po.Scenario(**TRIVIAL[name])  # type: ignore[arg-type]
    exact = _exact_plan(sc)
    res = po.plan_pmht(sc, po.PMHTConfig(solver="osqp"))
    scale = max(1.0, float(np.max(np.abs(exact.positions))))
    assert np.max(np.abs(res.positions - exact.positions)) <= 1e-9 * scale


@pytest.mark.parametrize("name", ["anneal-first-A", "paper30-B", "gated-C"])
def test_cvxpy_with_its_default_solver_equals_the_exact_smoother(name: str) -> None:
    sc, W, WZ, r = _fixture(name)
    states = solve_mstep(sc, W, WZ, r, solver="cvxpy")
    assert float(np.max(np.abs(states[:, :, [0, 3]] - _reference(name)))) <= TOL


def _exact_plan(sc: po.Scenario, **cfg: object) -> po.PlanResult:
    return po.plan_pmht(sc, po.PMHTConfig(solver="banded", **cfg))  # type: ignore[arg-type]


@pytest.mark.parametrize("backend", ["clarabel", "osqp", "cvxpy", "kalman"])
@pytest.mark.parametrize(("r", "dt"), [(1e-8, 1.0), (1e-2, 0.01), (1e-2, 0.001)])
def test_tiny_r_or_dt_gives_the_exact_plan_or_a_solver_error(backend: str, r: float, dt: float) -> None:
    # Plain EM, two iterations: at r = 1e-8 clarabel's positions used to end 4.19 units from the exact
    # smoother's with an objective 4132 lower, reported solved; at dt = 0.001 the objective read
    # -2.7e8 against the exact -3.1e4.
    sc = po.paper_scenario("A", seed=1, horizon=100, r=r, dt=dt)
    exact = _exact_plan(sc, anneal=None, max_iter=2)
    try:
        res = po.plan_pmht(sc, po.PMHTConfig(solver=backend, anneal=None, max_iter=2))
    except po.SolverError:
        return
    scale = max(1.0, float(np.max(np.abs(exact.positions))))
    assert np.max(np.abs(res.positions - exact.positions)) <= 1e-5 * scale
    np.testing.assert_allclose(res.history.objective, exact.history.objective, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("dt", [0.01, 0.001])
def test_the_objective_keeps_its_precision_at_small_dt(dt: float) -> None:
    # q dt^5 down to 1e-23: the prior term comes from the process noise, not from differences of
    # nearly equal states, so plain EM's objective never decreases.
    sc = po.paper_scenario("A", seed=1, horizon=100, dt=dt)
    res = _exact_plan(sc, anneal=None, max_iter=6)
    obj = res.history.objective
    assert np.all(np.diff(obj) >= -1e-9 * np.abs(obj[1:]))


@pytest.mark.parametrize("dt", [1e-3, 3e-3, 0.1, 1.0, 10.0])
def test_the_kalman_objective_is_the_exact_smoothers_at_every_dt(dt: float) -> None:
    # Same paths to 1e-14; the objective's prior term from the smoother's adjoint recursion, not from
    # differences of nearly equal states (which read 5.95e-5 too low at dt = 1e-3).
    sc = po.paper_scenario("A", seed=0, horizon=60, dt=dt)
    exact = _exact_plan(sc, max_iter=5)
    res = po.plan_pmht(sc, po.PMHTConfig(solver="kalman", max_iter=5))
    np.testing.assert_allclose(res.history.objective, exact.history.objective, rtol=1e-9, atol=0)


def test_an_answer_reported_solved_but_wrong_is_refused() -> None:
    # The check of every M-step answer against the exact smoother: a backend's "optimal" is not taken
    # on trust. A 1e-4 shift of one platform's path, or a non-finite entry, is refused with the status
    # the backend reported.
    from pmht_opt.mstep.base import MStepData, MStepOutput
    from pmht_opt.mstep.check import check_answer
    from pmht_opt.mstep.registry import make_mstep

    sc, W, WZ, r = _fixture("anneal-first-A")
    mstep = make_mstep(sc, "kalman")
    data = MStepData(W, WZ, r)
    good = mstep.solve(data)
    check_answer(mstep, data, good)  # the exact answer passes
    for change, match in ((1e-4, "platform 2 is 0.0001 from the exact"), (np.nan, "not finite")):
        states = good.states.copy()
        states[2, 7:, 0] += change
        with pytest.raises(po.WrongAnswerError, match=match) as info:
            check_answer(mstep, data, MStepOutput(states=states, raw_status="optimal"))
        assert info.value.status == "optimal" and isinstance(info.value, po.SolverError)


def test_scs_through_cvxpy_is_exact_or_refused() -> None:
    # SCS (first order, cvxpy's bundled conic solver) reports "optimal" at 1e-5 of the exact M-step on
    # annealing's first weights: the answer is refused, never used.
    sc, W, WZ, r = _fixture("anneal-first-A")
    try:
        states = solve_mstep(sc, W, WZ, r, solver="cvxpy", settings={"cvxpy_solver": "SCS"})
    except po.WrongAnswerError as err:
        assert err.status == "optimal"
        return
    assert float(np.max(np.abs(states[:, :, [0, 3]] - _reference("anneal-first-A")))) <= TOL
