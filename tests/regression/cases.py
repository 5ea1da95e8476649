"""The cases of the behaviour-regression test, written against the public API only.

Small sizes (horizon 60, few iterations) keep the test fast; they still run every backend through
annealing and plain EM, a constrained plan, the smoothed planner, guaranteed visits and both GAs.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

import pmht_opt as po

HORIZON = 60
#: The smoothed planner needs a step per locale of a route.
SMOOTHED_HORIZON = 200
SEEDS = (0, 1)
KINDS = ("A", "B", "C")
BACKENDS = ("kalman", "clarabel", "osqp", "cvxpy")


def _scenario(kind: str, seed: int) -> po.Scenario:
    return po.paper_scenario(kind, seed=seed, horizon=HORIZON)


def _plan(result: po.PlanResult) -> dict[str, np.ndarray]:
    return {
        "positions": result.positions,
        "assignment": result.assignment,
        "visit_time": result.visit_time,
    }


def _default(kind: str, seed: int, solver: str) -> dict[str, np.ndarray]:
    cfg = po.PMHTConfig(solver=solver, max_iter=25, anneal=po.Anneal(1.0, 15))
    return _plan(po.plan_pmht(_scenario(kind, seed), cfg))


def _paper(kind: str, seed: int, solver: str) -> dict[str, np.ndarray]:
    return _plan(po.plan_pmht(_scenario(kind, seed), po.PMHTConfig.paper(solver=solver, max_iter=10)))


def _constrained(kind: str, seed: int) -> dict[str, np.ndarray]:
    cons = [po.SpeedLimit(0.3), po.AreaBounds(-1.5, 10.5, -0.5, 10.5), po.CircleObstacle((5.0, 5.0), 1.0)]
    cfg = po.PMHTConfig(max_iter=20, anneal=po.Anneal(1.0, 10), constraints=cons)
    return _plan(po.plan_pmht(_scenario(kind, seed), cfg))


def _visit_all(kind: str, seed: int) -> dict[str, np.ndarray]:
    cfg = po.PMHTConfig(max_iter=25, anneal=po.Anneal(1.0, 10), constraints=[po.VisitAll(0.1, warmup=5)])
    return _plan(po.plan_pmht(_scenario(kind, seed), cfg))


def _ga(kind: str, seed: int, operators: str) -> dict[str, np.ndarray]:
    tour = po.order_locales(_scenario(kind, seed), "ga", seed=seed, iterations=400, operators=operators)
    return {
        "assignment": tour.assignment,
        "order": tour.order,
        "history": tour.history,
    }


def _smoothed(kind: str, seed: int) -> dict[str, np.ndarray]:
    sc = po.paper_scenario(kind, seed=seed, horizon=SMOOTHED_HORIZON)
    tour = po.order_locales(sc, "ga", seed=seed, iterations=400)
    return _plan(po.plan_smoothed(sc, tour, po.PMHTConfig(max_iter=6), visit_radius=0.2))


def _cases() -> dict[str, Callable[[], dict[str, np.ndarray]]]:
    out: dict[str, Callable[[], dict[str, np.ndarray]]] = {}
    for kind in KINDS:
        for seed in SEEDS:
            tag = f"{kind}{seed}"
            for solver in BACKENDS:
                out[f"default-{solver}-{tag}"] = lambda k=kind, s=seed, b=solver: _default(k, s, b)
                out[f"paper-{solver}-{tag}"] = lambda k=kind, s=seed, b=solver: _paper(k, s, b)
            out[f"constrained-{tag}"] = lambda k=kind, s=seed: _constrained(k, s)
            out[f"visitall-{tag}"] = lambda k=kind, s=seed: _visit_all(k, s)
            out[f"smoothed-{tag}"] = lambda k=kind, s=seed: _smoothed(k, s)
            for ops in ("improved", "kirk"):
                out[f"ga-{ops}-{tag}"] = lambda k=kind, s=seed, o=ops: _ga(k, s, o)
    return out


CASES = _cases()

#: Largest position difference (absolute; the areas are about 10 across) accepted against the
#: recorded plan, by what solved the case's M-steps. Each is the accuracy the backend promises on one
#: M-step, widened for what a few tens of EM iterations make of it (each M-step's answer feeds the
#: next E-step): the exact smoother solves to rounding; Clarabel stops at a relative gap of 1e-12
#: without constraints and 1e-8 with them, where hard rows are met to 1e-5 of their size
#: (:data:`pmht_opt.mstep.rows.BACKOFF`); OSQP stops ADMM at 1e-9 without constraints, 1e-5 with
#: them. Another CPU or BLAS moves the plans by far less (at most 1.2e-6 in clarabel's constrained
#: cases and 6.6e-6 in osqp's, measured); a change of behaviour moves them by far more.
POSITION_TOL = {
    "exact": 1e-8,
    "interior point": 1e-5,
    "interior point, constrained": 1e-4,
    "admm": 1e-4,
    "admm, constrained": 1e-3,
}


def tolerance(name: str) -> float:
    """The position tolerance of case ``name`` (:data:`POSITION_TOL`)."""
    kind = name.split("-")[0]
    if kind in ("constrained", "visitall", "smoothed"):
        return POSITION_TOL["interior point, constrained"]  # "auto" with constraints: Clarabel
    backend = name.split("-")[1]
    return POSITION_TOL[
        {"kalman": "exact", "clarabel": "interior point", "cvxpy": "interior point"}.get(backend, "admm")
    ]


def run_case(name: str) -> dict[str, np.ndarray]:
    """The arrays of one case."""
    return CASES[name]()
