"""What one child process of the scaling study measures: one timed plan, or gated against dense.

Each trial runs in a fresh spawned process (:func:`studies.scaling.verify_executor`), so its peak
resident set size (``ru_maxrss``) is that plan's alone: runs share no caches, pools or heap.
Before measuring, the child plans a tiny scenario with the same configuration (:func:`warm_up`), so
that what a process pays once (imports, thread pools) is not counted as the measured plan's.
``base_rss_mib`` is the child's peak before planning (interpreter, libraries, the warm-up,
scenario); ``peak_rss_mib`` the peak after.

Whether each E-step was gated is read from the plan's history (``IterationHistory.estep_gated``: the
initial E-step and, per iteration, the one whose weights feed the next M-step), never by patching
the planner.
"""

from __future__ import annotations

import platform
import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from pmht_opt import PMHTConfig, Scenario, Schedule, plan_pmht
from pmht_opt.estep import EStepResult, estep, safe_log
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import POS
from studies.scaling_study.design import scaling_scenario
from studies.trials import Check, TrialTable


def rss_mib() -> float:
    """Peak resident set size of this process so far (Linux reports KiB, macOS bytes)."""
    import resource  # POSIX only, and only in the child that measures

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(peak) / (1024.0 * 1024.0 if platform.system() == "Darwin" else 1024.0)


def config(solver: str, gate: str, iterations: int, plain: bool = False) -> PMHTConfig:
    """The default planner configuration with ``iterations`` iterations, gated (``"auto"``) or dense;
    ``plain`` starts at the scenario's ``r`` (no annealing)."""
    gate_opt = None if gate == "off" else "auto"
    if plain:
        return PMHTConfig(solver=solver, max_iter=iterations, estep_gate=gate_opt, anneal=None)
    return PMHTConfig(solver=solver, max_iter=iterations, estep_gate=gate_opt)


def trial(
    task: str,
    n_locales: int,
    horizon: int,
    n_platforms: int,
    solver: str,
    gate: str,
    iterations: int,
    seed: int,
    rep: int,
) -> dict[str, Any]:
    """One child's work: ``task="time"`` times one plan, ``task="scale"`` one plan of plain EM
    (:attr:`~studies.scaling_study.design.Design.scale`), ``task="agree"`` compares gated and dense.

    ``rep`` only tells repeats of the same plan apart.
    """
    warm_up(solver, gate, iterations, plain=task == "scale")
    sc = scaling_scenario(n_locales, horizon, n_platforms, seed)
    if task in ("time", "scale"):
        return time_plan(sc, solver, gate, iterations, plain=task == "scale")
    if task == "agree":
        return agreement(sc, solver, iterations)
    raise ConfigError(f"scaling: unknown task {task!r}.")


def warm_up(solver: str, gate: str, iterations: int, plain: bool = False) -> None:
    """The imports and pools a first plan loads, loaded before anything is measured: one plan of a
    tiny scenario (12 locales, 12 steps, 2 platforms) in this configuration and, unless the E-step is
    dense, three iterations of plain EM on one whose last E-step is gated (60 locales, 40 steps, 3
    platforms)."""
    plan_pmht(scaling_scenario(12, 12, 2, 0), config(solver, gate, iterations, plain))
    if gate != "off":
        plan_pmht(scaling_scenario(60, 40, 3, 0), config(solver, gate, 3, plain=True))


def time_plan(sc: Scenario, solver: str, gate: str, iterations: int, plain: bool = False) -> dict[str, Any]:
    """Wall time, E- and M-step time, gated E-steps and peak memory of one plan of ``sc``.

    ``estep_settled_s`` is the E-step time from the end of annealing on, where gating pays most
    (``r`` is at its sharpest).
    """
    cfg = config(solver, gate, iterations, plain)
    base = rss_mib()
    started = time.perf_counter()
    res = plan_pmht(sc, cfg)
    wall = time.perf_counter() - started
    peak = rss_mib()
    e = res.history.estep_time
    gated = res.history.estep_gated
    settled = Schedule.of(cfg.anneal, sc.r, iterations).settled
    return {
        "wall_s": wall,
        "estep_s": float(np.sum(e)),
        "estep_settled_s": float(np.sum(e[settled:])),
        "mstep_s": float(np.sum(res.history.mstep_time)),
        "estep_calls": int(gated.size),
        "estep_gated_calls": int(np.sum(gated)),
        "base_rss_mib": base,
        "peak_rss_mib": peak,
        "distance": float(res.total_distance),
        "objective": float(res.history.objective[-1]),
    }


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference relative to the largest magnitude of the reference ``b``."""
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


def agreement(sc: Scenario, solver: str, iterations: int) -> dict[str, Any]:
    """Gated against dense: whole plans, then the last E-step of the dense plan computed both ways."""
    gated = plan_pmht(sc, config(solver, "auto", iterations))
    dense = plan_pmht(sc, config(solver, "off", iterations))
    args = (sc.locales, dense.states[:, 1:, POS], None, safe_log(dense.platform_prior), sc.r)
    ed = estep(*args)
    t0 = time.perf_counter()
    eg = estep(*args, gate="auto")
    t_gated = time.perf_counter() - t0
    t0 = time.perf_counter()
    estep(*args)
    t_dense = time.perf_counter() - t0
    return {
        "pos_max_diff": float(np.max(np.abs(gated.positions - dense.positions))),
        "objective_rel_diff": _rel(gated.history.objective, dense.history.objective),
        "assignment_equal": bool(np.array_equal(gated.assignment, dense.assignment)),
        "visit_time_equal": bool(np.array_equal(gated.visit_time, dense.visit_time)),
        "distance_gated": float(gated.total_distance),
        "distance_dense": float(dense.total_distance),
        "wall_gated_s": float(gated.wall_time),
        "wall_dense_s": float(dense.wall_time),
        **_estep_agreement(eg, ed),
        "estep_time_gated_s": t_gated,
        "estep_time_dense_s": t_dense,
    }


def _estep_agreement(eg: EStepResult, ed: EStepResult) -> dict[str, Any]:
    """How far the gated E-step ``eg`` is from the dense one ``ed`` of the same paths and priors."""
    nnz = int(eg.weights.nnz) if isinstance(eg.weights, sp.csr_matrix) else int(eg.weights.size)
    map_equal = all(
        np.array_equal(a, b) for a, b in zip(eg.map_assignment(), ed.map_assignment(), strict=True)
    )
    return {
        "estep_gated": bool(eg.gated),
        "estep_kept_fraction": float(nnz) / float(eg.weights.shape[0] * eg.weights.shape[1]),
        "estep_W_rel": _rel(eg.W, ed.W),
        "estep_WZ_rel": _rel(eg.WZ, ed.WZ),
        "estep_lse_max_abs": float(np.max(np.abs(eg.log_normaliser - ed.log_normaliser))),
        "estep_platform_prior_max_abs": float(np.max(np.abs(eg.platform_prior() - ed.platform_prior()))),
        "estep_map_equal": bool(map_equal),
    }


#: Columns that are measurements of the machine.
TIMES = (
    "wall_s",
    "estep_s",
    "estep_settled_s",
    "mstep_s",
    "base_rss_mib",
    "peak_rss_mib",
    "wall_gated_s",
    "wall_dense_s",
    "estep_time_gated_s",
    "estep_time_dense_s",
)
#: What a child records; the tasks record different results, so every column is optional.
RESULTS = {
    **{name: "float?" for name in TIMES},
    "estep_calls": "int?",
    "estep_gated_calls": "int?",
    "distance": "float?",
    "objective": "float?",
    "pos_max_diff": "float?",
    "objective_rel_diff": "float?",
    "assignment_equal": "bool?",
    "visit_time_equal": "bool?",
    "distance_gated": "float?",
    "distance_dense": "float?",
    "estep_gated": "bool?",
    "estep_kept_fraction": "float?",
    "estep_W_rel": "float?",
    "estep_WZ_rel": "float?",
    "estep_lse_max_abs": "float?",
    "estep_platform_prior_max_abs": "float?",
    "estep_map_equal": "bool?",
}
TABLE = TrialTable.of(
    "scaling",
    trial,
    RESULTS,
    {name: Check("skip", reason="time and memory are measurements of the machine") for name in TIMES},
)
