"""Whole plans: one trial per (scenario, seed, backend), compared with the kalman plan of the scenario.

EM amplifies the last-digit differences between M-step backends (docs/model.md section 4.6), so whole
plans are compared by statistics (distance, largest position difference), not exactly. A plan does
not accept inaccurate solves unless its label asks to (:data:`~studies.solver_study.backends.ACCEPT`):
one that stops at such a solve has failed, and the row says at which EM iteration.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from pmht_opt import PMHTConfig, plan_pmht
from pmht_opt.exceptions import PmhtOptError
from studies.solver_study.backends import ACCEPT, STATUS_OK, backend_spec, error_status
from studies.solver_study.iterates import study_scenario
from studies.trials import Check, TrialTable

#: Kalman plans of this process (positions, total distance), by plan parameters: the reference of the
#: other backends' trials, which follow the kalman trial of the same scenario. Bounded, since a study
#: runs scenario after scenario.
_KALMAN_PLANS: dict[tuple[str, int, int, int | None], tuple[np.ndarray, float]] = {}
_KEEP = 4


def _remember(key: tuple[str, int, int, int | None], positions: np.ndarray, distance: float) -> None:
    """Keep a kalman plan, dropping the oldest beyond :data:`_KEEP`."""
    while len(_KALMAN_PLANS) >= _KEEP:
        _KALMAN_PLANS.pop(next(iter(_KALMAN_PLANS)))
    _KALMAN_PLANS[key] = (positions.copy(), distance)


def kalman_plan(kind: str, seed: int, iterations: int, horizon: int | None) -> tuple[np.ndarray, float]:
    """Positions and total distance of the kalman plan of a scenario (planned once per process)."""
    key = (kind, seed, iterations, horizon)
    if key not in _KALMAN_PLANS:
        sc = study_scenario(kind, seed, horizon)
        res = plan_pmht(sc, PMHTConfig(solver="kalman", max_iter=iterations, threads=1))
        _remember(key, res.positions, res.total_distance)
    return _KALMAN_PLANS[key]


def plan_trial(kind: str, seed: int, backend: str, iterations: int, horizon: int) -> dict[str, Any]:
    """One whole plan with ``backend``; compared with the kalman plan of the same scenario.

    QP backends run on one thread so the times compare the solvers, not the thread pool.
    """
    sc = study_scenario(kind, seed, horizon)
    solver, settings = backend_spec(backend)
    cfg = PMHTConfig(
        solver=solver,
        solver_settings=settings,
        max_iter=iterations,
        threads=1,
        accept_inaccurate=backend.endswith(ACCEPT),
    )
    done = [0]

    def progress(it: int, objective: float) -> None:
        done[0] = it

    t0 = time.perf_counter()
    try:
        res = plan_pmht(sc, cfg, callback=progress)
    except PmhtOptError as err:
        cls, raw, message = error_status(err, backend)
        return {
            "status": cls,
            "raw_status": raw,
            "message": message[:400],
            "wall_time": time.perf_counter() - t0,
            "iterations_done": done[0],
            "failed_at": done[0] + 1,
        }
    wall = time.perf_counter() - t0
    if backend == "kalman":
        ref_pos, ref_dist = res.positions, res.total_distance
        _remember((kind, seed, iterations, horizon), ref_pos, ref_dist)
    else:
        ref_pos, ref_dist = kalman_plan(kind, seed, iterations, horizon)
    it_hist = res.history.solver_iterations
    return {
        "status": STATUS_OK,
        "raw_status": "",
        "message": "",
        "wall_time": wall,
        "iterations_done": int(res.history.mstep_time.size),
        "estep_time": float(res.history.estep_time.sum()),
        "mstep_time": float(res.history.mstep_time.sum()),
        "total_distance": res.total_distance,
        "kalman_distance": ref_dist,
        "distance_rel_diff": (res.total_distance - ref_dist) / ref_dist,
        "max_pos_diff": float(np.max(np.abs(res.positions - ref_pos))),
        "mean_solver_iterations": float(np.mean(it_hist)) if it_hist.size else 0.0,
        "max_solver_iterations": int(np.max(it_hist)) if it_hist.size else 0,
    }


#: What a plan records: its status, times and length, and how far it is from the kalman plan.
RESULTS = {
    "status": "str",
    "raw_status": "str?",
    "message": "str?",
    "wall_time": "float",
    "iterations_done": "int",
    "failed_at": "int?",
    "estep_time": "float?",
    "mstep_time": "float?",
    "total_distance": "float?",
    "kalman_distance": "float?",
    "distance_rel_diff": "float?",
    "max_pos_diff": "float?",
    "mean_solver_iterations": "float?",
    "max_solver_iterations": "int?",
}
PLANS = TrialTable.of(
    "solvers_plans",
    plan_trial,
    RESULTS,
    {
        **{
            name: Check("skip", reason="wall-clock time differs from run to run")
            for name in ("wall_time", "estep_time", "mstep_time")
        },
        "message": Check("skip", reason="an error's wording; its class and status are compared"),
    },
)
