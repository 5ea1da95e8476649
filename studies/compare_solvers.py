"""Study 2: the M-step backends against each other (``pmht-opt study solvers``).

Three parts, every backend (``kalman``, ``clarabel``, ``osqp``, and ``cvxpy`` with each installed cvxpy
solver) on the same problems:

Unconstrained single M-steps
    The E-step weights of real EM iterates: the kalman plan of paper scenarios A, B, C is run for
    ``K - 1`` iterations (default configuration: annealed), then the M-steps of iterations ``K`` and
    ``K + 1`` are set up exactly as the planner does. Every backend solves iteration ``K`` first (so a
    warm-starting backend starts from the previous answer, as inside a plan) and iteration ``K + 1``
    is timed; ``--repeats`` times, median reported. Two iterates: early (``K = 5``, annealed ``r``) and
    late (``K = 40``, the scenario's ``r``). Reference: the kalman (RTS) smoother.
Constrained single M-steps
    The late iterate with (a) a speed limit at 70% of the unconstrained answer's top speed plus area
    bounds, (b) a circular keep-out zone linearised at the iterate. Kalman cannot take constraints;
    the reference is Clarabel at 1e-10 with iterative refinement (tighter tolerances stop at
    'AlmostSolved'). OSQP gets inner polygons for the cones, so its objective gap includes that
    approximation; the ``*_same`` columns compare it with the reference solve of the polygonal problem.
Whole plans
    ``--iterations`` (100) EM iterations on A, B, C, ``--seeds`` seeds (kalman, clarabel, osqp) and
    ``--cvxpy-seeds`` seeds (each cvxpy solver): wall time, total distance and the largest position
    difference to the kalman plan of the same scenario. Whole runs are compared by statistics, not
    exactly (SPEC section 6): EM amplifies tiny M-step differences.

The QP backends run on one thread (``threads=1``) so the times compare the solvers, not the thread
pool. Every status is checked and classified: ``optimal``, ``inaccurate`` (single M-steps are solved
with ``accept_inaccurate=True`` so the answer can still be measured; plans are not), ``failed``, or
``n/a`` (the solver cannot take the problem class, e.g. an LP-only cvxpy solver). Solver options are
the library's defaults (``pmht_opt.mstep.BACKEND_DEFAULTS`` and ``CONSTRAINED_DEFAULTS``), and cvxpy's
defaults for cvxpy solvers other than CLARABEL.

Outputs in ``--out``: ``solvers_msteps.jsonl`` (one row per M-step and backend, written whole at the
end of a run), ``solvers_plans.jsonl`` (one row per plan; resumable, ``--fresh`` starts it afresh),
``solvers.json`` (settings, provenance, summaries), ``solvers.md`` (the tables) and ``solvers.png``
(time against position difference).

    pmht-opt study solvers --out studies/results/solvers
    python studies/compare_solvers.py [--quick] [--fresh]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.constraints import AreaBounds, CircleObstacle, SpeedLimit
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.estep import EStepResult, estep, safe_log
from pmht_opt.exceptions import ConfigError, InfeasibleError, PmhtOptError, SolverError
from pmht_opt.model import POS, VEL
from pmht_opt.mstep import MStep, MStepData, available_backends, make_mstep, mstep_objective
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.scenario import Scenario, paper_scenario
from studies.options import RunOptions, positive_int
from studies.provenance import load_average, provenance
from studies.report import finite, median, summarise, write_json, write_text
from studies.store import ResultsFile, Schema, read_rows
from studies.trials import Check, TrialTable, run_trials

#: Unconstrained iterates: stage name -> EM iteration ``K`` whose successor is the measured M-step.
STAGES: dict[str, int] = {"early": 5, "late": 40}
QUICK_STAGES: dict[str, int] = {"early": 3, "late": 12}
#: Constrained cases, built on the late iterate.
CONSTRAINED_CASES = ("speed+area", "obstacle")
#: Speed limit of the constrained case, as a fraction of the unconstrained answer's top speed.
SPEED_FRACTION = 0.7
OBSTACLE_RADIUS = 1.5
#: Candidate obstacle centres; the first one no start is near is used.
OBSTACLE_CENTRES = ((5.0, 5.0), (5.0, 3.5), (3.5, 5.0), (6.5, 5.0), (5.0, 6.5))

#: The constrained reference: Clarabel with iterative refinement at 1e-10 (measured on A, B, C:
#: 'Solved'; at 1e-11 and below it stops at 'AlmostSolved').
REFERENCE_TOL = 1e-10
REFERENCE_SETTINGS: dict[str, Any] = {
    "iterative_refinement_enable": True,
    "tol_gap_abs": REFERENCE_TOL,
    "tol_gap_rel": REFERENCE_TOL,
    "tol_feas": REFERENCE_TOL,
    "tol_ktratio": 1e-8,
}
#: The same tolerances through cvxpy: an independent formulation of the reference, to show how well
#: the reference itself is determined.
CVXPY_REFERENCE_SETTINGS: dict[str, Any] = {
    k: v for k, v in REFERENCE_SETTINGS.items() if k.startswith("tol")
}

STATUS_OK = "optimal"
STATUS_INACCURATE = "inaccurate"
STATUS_FAILED = "failed"
STATUS_NA = "n/a"
STATUS_INFEASIBLE = "infeasible"

#: cvxpy solvers left out of ``--quick``: HiGHS's active-set QP spends about a minute per iteration on
#: the short-horizon problem (reduced Hessian of dimension ~2900; at the paper's horizon the dimension
#: exceeds its nullspace limit of 4000 and it stops at once, which the full study reports); SCS takes
#: about 10 s to compile the speed-limited problem.
QUICK_SKIP = ("HIGHS", "SCS")

#: What a cvxpy solver's failure message says when it cannot take the problem class at all.
_NOT_APPLICABLE = ("cannot solve this problem", "not installed")


# ------------------------------------------------------------------------------------------ backends


def cvxpy_solvers() -> list[str]:
    """Installed cvxpy solvers, CLARABEL (the library's default) first; empty without cvxpy."""
    if "cvxpy" not in available_backends():
        return []
    import cvxpy as cp

    names = sorted(str(s) for s in cp.installed_solvers())
    return sorted(names, key=lambda s: s != "CLARABEL")


#: Suffix of a whole-plan backend label that runs the plan with ``accept_inaccurate=True``.
ACCEPT = " (accept inaccurate)"
#: Whole-plan variants run besides the plain backends: cvxpy/CLARABEL's plans stop at its
#: 'optimal_inaccurate' (AlmostSolved at the tight unconstrained tolerances), so this shows what
#: its plans would give if the planner took those solves.
PLAN_VARIANTS = ("cvxpy/CLARABEL" + ACCEPT,)


def backend_spec(label: str) -> tuple[str, dict[str, Any]]:
    """``("cvxpy", {"cvxpy_solver": "SCS"})`` for ``"cvxpy/SCS"``; ``(label, {})`` otherwise."""
    label = label.removesuffix(ACCEPT)
    if label.startswith("cvxpy/"):
        return "cvxpy", {"cvxpy_solver": label.split("/", 1)[1]}
    return label, {}


def backends(cvxpy_names: Sequence[str]) -> list[str]:
    """Backend labels of the study: the installed ones, then cvxpy with each solver."""
    have = available_backends()
    out: list[str] = [b for b in ("kalman", "clarabel", "osqp") if b in have]
    if "cvxpy" in have:
        out += [f"cvxpy/{s}" for s in cvxpy_names]
    return out


def classify(raw: str) -> str:
    """A solver's status string as one of the study's classes."""
    text = raw.lower()
    if any(s in text for s in _NOT_APPLICABLE):
        return STATUS_NA
    if "infeasible" in text:
        return STATUS_INFEASIBLE
    if "inaccurate" in text or "almost" in text:
        return STATUS_INACCURATE
    if text in ("solved", "optimal"):
        return STATUS_OK
    return STATUS_FAILED


def _error_status(err: BaseException) -> tuple[str, str, str]:
    """(class, raw status, message) of a failed solve."""
    message = f"{type(err).__name__}: {err}"
    if isinstance(err, InfeasibleError):
        return STATUS_INFEASIBLE, str(getattr(err, "status", "")), message
    if isinstance(err, SolverError):
        raw = str(err.status or "")
        cls = classify(raw)
        return (STATUS_FAILED if cls == STATUS_OK else cls), raw, message
    if any(s in str(err).lower() for s in _NOT_APPLICABLE):
        return STATUS_NA, "", message
    return STATUS_FAILED, "", message


# ------------------------------------------------------------------------------------------ iterates


def study_scenario(kind: str, seed: int, horizon: int | None = None) -> Scenario:
    """Paper scenario ``kind`` (seed ``seed``), optionally with a shorter horizon."""
    if horizon is None:
        return paper_scenario(kind, seed=seed)
    return paper_scenario(kind, seed=seed, horizon=int(horizon))


@dataclass
class Iterate:
    """Two consecutive M-steps of a real EM run: ``K`` (``prev``) and ``K + 1`` (``data``)."""

    scenario: Scenario
    iteration: int
    states_prev: np.ndarray  # iterate after K - 1 iterations: linearisation point of iteration K
    es_prev: EStepResult
    data_prev: MStepData
    states: np.ndarray  # iterate after K iterations
    es: EStepResult
    data: MStepData
    settled: int

    def with_ctx(self, prev: bool, conic: bool, constrained: bool) -> MStepData:
        """The M-step data of iteration ``K`` (``prev``) or ``K + 1``, with a constraint context."""
        d = self.data_prev if prev else self.data
        if not constrained:
            return MStepData(W=d.W, WZ=d.WZ, r=d.r)
        ctx = ConstraintContext(
            scenario=self.scenario,
            states=self.states_prev if prev else self.states,
            estep=self.es_prev if prev else self.es,
            iteration=self.iteration + (0 if prev else 1),
            max_iter=100,
            conic=conic,
            settled=self.settled,
        )
        return MStepData(W=d.W, WZ=d.WZ, r=d.r, ctx=ctx)


def make_iterate(scenario: Scenario, iteration: int) -> Iterate:
    """Run the default (annealed) planner with the kalman M-step to EM iteration ``iteration - 1`` and
    set up the M-steps of iterations ``iteration`` and ``iteration + 1`` exactly as the planner does."""
    K = max(int(iteration), 2)
    cfg = PMHTConfig(solver="kalman", max_iter=K - 1)
    r_sched = cfg.anneal.values(scenario.r, K + 1)
    res = plan_pmht(scenario, cfg)
    kalman = make_mstep(scenario, "kalman")
    r1, r2 = float(r_sched[K - 1]), float(r_sched[K])
    es1 = estep(scenario.locales, res.states[:, 1:, POS], None, safe_log(res.platform_prior), r1)
    d1 = MStepData(W=es1.W, WZ=es1.WZ, r=r1)
    states = kalman.solve(d1).states
    es2 = estep(scenario.locales, states[:, 1:, POS], None, safe_log(es1.platform_prior()), r2)
    d2 = MStepData(W=es2.W, WZ=es2.WZ, r=r2)
    return Iterate(
        scenario=scenario,
        iteration=K,
        states_prev=res.states,
        es_prev=es1,
        data_prev=d1,
        states=states,
        es=es2,
        data=d2,
        settled=cfg.anneal.end(scenario.r, 100),
    )


def max_speed(states: np.ndarray) -> float:
    """Largest speed over platforms and times of ``(M, T+1, 6)`` states."""
    v = states[:, :, VEL]
    return float(np.max(np.hypot(v[..., 0], v[..., 1])))


def case_constraints(case: str, scenario: Scenario, free_states: np.ndarray) -> tuple[Constraint, ...]:
    """The constraints of a constrained case, sized from the unconstrained answer ``free_states``."""
    starts = scenario.start_positions
    bounds = scenario.bounds if scenario.bounds is not None else (0.0, 10.0, 0.0, 10.0)
    box = (
        min(bounds[0], float(starts[:, 0].min())),
        max(bounds[1], float(starts[:, 0].max())),
        min(bounds[2], float(starts[:, 1].min())),
        max(bounds[3], float(starts[:, 1].max())),
    )
    if case == "speed+area":
        return (SpeedLimit(SPEED_FRACTION * max_speed(free_states)), AreaBounds(*box))
    if case == "obstacle":
        for centre in OBSTACLE_CENTRES:
            if np.min(np.hypot(*(starts - np.array(centre)).T)) > OBSTACLE_RADIUS + 0.25:
                return (CircleObstacle(centre, OBSTACLE_RADIUS),)
        return (CircleObstacle(OBSTACLE_CENTRES[0], 0.5),)
    raise ValueError(f"unknown constrained case {case!r}")


# ------------------------------------------------------------------------------------------ single M-steps


@dataclass
class Measured:
    """One backend's answer to one M-step."""

    status: str
    raw_status: str = ""
    message: str = ""
    states: np.ndarray | None = None
    iterations: int | None = None
    setup_s: float = math.nan
    first_s: float = math.nan
    times: list[float] | None = None


def measure(
    build: Callable[[], MStep],
    it: Iterate,
    repeats: int,
    conic: bool | None = None,
    constrained: bool = False,
    after_build: Callable[[MStep], None] | None = None,
    close: bool = True,
) -> Measured:
    """Build a backend, solve iteration ``K`` (warm-up, includes setup/compilation), then time the
    M-step of iteration ``K + 1`` ``repeats`` times, re-solving ``K`` before each so a warm start
    starts from where it would inside a plan. Never raises for a solver's failure: it is the result.
    ``close=False`` leaves the backend open for another measurement through the same ``build``."""
    built: list[MStep] = []
    try:
        with warnings.catch_warnings():
            # cvxpy warns "Solution may be inaccurate"; the status says so and is recorded.
            warnings.simplefilter("ignore")
            return _measure(build, it, repeats, conic, constrained, after_build, built)
    except Exception as err:  # a study: every failure is a measurement, never a crash
        cls, raw, message = _error_status(err)
        return Measured(status=cls, raw_status=raw, message=message[:400])
    finally:
        for ms in built if close else ():
            ms.close()


def _measure(
    build: Callable[[], MStep],
    it: Iterate,
    repeats: int,
    conic: bool | None,
    constrained: bool,
    after_build: Callable[[MStep], None] | None,
    built: list[MStep],
) -> Measured:
    t0 = time.perf_counter()
    ms = build()
    built.append(ms)
    if after_build is not None:
        after_build(ms)
    setup = time.perf_counter() - t0
    use_conic = ms.conic if conic is None else conic
    ms.conic = use_conic
    prev = it.with_ctx(True, use_conic, constrained)
    cur = it.with_ctx(False, use_conic, constrained)
    t0 = time.perf_counter()
    ms.solve(prev)
    first = time.perf_counter() - t0
    times = []
    out = None
    for rep in range(max(int(repeats), 1)):
        if rep:
            ms.solve(prev)
        t0 = time.perf_counter()
        out = ms.solve(cur)
        times.append(time.perf_counter() - t0)
    assert out is not None
    return Measured(
        status=classify(str(out.status)),
        raw_status=str(out.status),
        states=out.states,
        iterations=int(out.iterations),
        setup_s=setup,
        first_s=first,
        times=times,
    )


def _pos_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a[:, :, POS] - b[:, :, POS])))


def _row(
    base: Mapping[str, Any],
    backend: str,
    m: Measured,
    ref: np.ndarray | None,
    ref_objective: float,
    data: MStepData,
    scenario: Scenario,
) -> dict[str, Any]:
    row: dict[str, Any] = {**base, "backend": backend, "status": m.status, "raw_status": m.raw_status}
    row["message"] = m.message
    row["setup_s"] = m.setup_s
    row["first_solve_s"] = m.first_s
    row["time_s"] = float(np.median(m.times)) if m.times else math.nan
    row["times_s"] = m.times or []
    row["iterations"] = m.iterations
    if m.states is not None and ref is not None:
        j = mstep_objective(scenario.model, m.states, data)
        row["objective"] = j
        row["objective_gap"] = (j - ref_objective) / abs(ref_objective)
        row["max_pos_diff"] = _pos_diff(m.states, ref)
    else:
        row["objective"] = row["objective_gap"] = row["max_pos_diff"] = math.nan
    return row


def _builder(sc: Scenario, label: str, constraints: tuple[Constraint, ...] = ()) -> Callable[[], MStep]:
    solver, settings = backend_spec(label)

    def build() -> MStep:
        return make_mstep(
            sc, solver, settings or None, accept_inaccurate=True, threads=1, constraints=constraints
        )

    return build


def unconstrained_rows(
    it: Iterate, stage: str, seed: int, labels: Sequence[str], repeats: int, bar: Any
) -> list[dict[str, Any]]:
    """Every backend on the unconstrained M-step ``K + 1`` of ``it``; reference: kalman."""
    sc = it.scenario
    ref = make_mstep(sc, "kalman").solve(it.data).states
    j_ref = mstep_objective(sc.model, ref, it.data)
    base = {
        "part": "unconstrained",
        "case": f"unconstrained-{stage}",
        "scenario": sc.name.split(" ")[0],
        "seed": seed,
        "iteration": it.iteration + 1,
        "r": it.data.r,
        "horizon": sc.horizon,
        "reference": "kalman",
        "constraints": "",
    }
    rows = []
    for label in labels:
        m = measure(_builder(sc, label), it, repeats)
        rows.append(_row(base, label, m, ref, j_ref, it.data, sc))
        if bar is not None:
            bar.set_postfix_str(f"{base['scenario']} {stage} {label}", refresh=False)
            bar.update(1)
    return rows


def _reusing(build: Callable[[], MStep]) -> Callable[[], MStep]:
    """``build`` that builds once and hands the same backend out again."""
    made: list[MStep] = []

    def once() -> MStep:
        if not made:
            made.append(build())
        return made[0]

    return once


def _tighten(ms: MStep) -> None:
    """Put a cvxpy/CLARABEL backend on the reference's tolerances."""
    opts = getattr(ms, "options", None)
    if isinstance(opts, dict):
        opts.update(CVXPY_REFERENCE_SETTINGS)


def constrained_rows(
    it: Iterate, case: str, seed: int, labels: Sequence[str], repeats: int, bar: Any
) -> list[dict[str, Any]]:
    """Every backend on a constrained M-step ``K + 1`` of ``it``; reference: tight Clarabel."""
    sc = it.scenario
    free = make_mstep(sc, "kalman").solve(it.data).states
    cons = case_constraints(case, sc, free)
    names = "; ".join(c.name for c in cons)
    base = {
        "part": "constrained",
        "case": case,
        "scenario": sc.name.split(" ")[0],
        "seed": seed,
        "iteration": it.iteration + 1,
        "r": it.data.r,
        "horizon": sc.horizon,
        "reference": f"clarabel tol {REFERENCE_TOL:g} + iterative refinement (cones)",
        "constraints": names,
    }
    data_cone = it.with_ctx(False, True, True)
    data_poly = it.with_ctx(False, False, True)

    def qp(solver: str, settings: dict[str, Any] | None = None) -> Callable[[], MStep]:
        return lambda: make_mstep(sc, solver, settings, accept_inaccurate=True, threads=1, constraints=cons)

    refs: dict[bool, Measured] = {
        conic: measure(qp("clarabel", REFERENCE_SETTINGS), it, 1, conic=conic, constrained=True)
        for conic in (True, False)
    }
    ref_cone, ref_poly = refs[True], refs[False]
    ok_ref = ref_cone.states is not None and ref_cone.status == STATUS_OK
    ref = ref_cone.states if ok_ref else None
    j_ref = mstep_objective(sc.model, ref, data_cone) if ref is not None else math.nan
    poly = ref_poly.states if ref_poly.states is not None and ref_poly.status == STATUS_OK else None
    j_poly = mstep_objective(sc.model, poly, data_poly) if poly is not None else math.nan

    # (label, build, conic, after_build, close)
    runs: list[tuple[str, Callable[[], MStep], bool | None, Callable[[MStep], None] | None, bool]] = []
    for label in labels:
        solver, settings = backend_spec(label)
        if label == "cvxpy/CLARABEL":
            # Then the same problem at the reference's tolerances (how well the reference itself is
            # determined), on the same backend object with its options tightened.
            once = _reusing(qp(solver, settings))
            runs.append((label, once, None, None, False))
            runs.append(("cvxpy/CLARABEL (tight)", once, None, _tighten, True))
            continue
        runs.append((label, qp(solver, settings or None), None, None, True))
        if label == "clarabel":
            runs.append(("clarabel (polygons)", qp("clarabel"), False, None, True))
    rows = [_row(base, "reference (cones)", ref_cone, ref, j_ref, data_cone, sc)]
    rows[0]["reference_status"] = ref_cone.raw_status
    for label, build, conic, after, close in runs:
        if label == "kalman":
            m = Measured(status=STATUS_NA, message="kalman takes no constraints")
        else:
            m = measure(build, it, repeats, conic=conic, constrained=True, after_build=after, close=close)
        used_conic = conic if conic is not None else label != "osqp"
        data = data_cone if used_conic else data_poly
        row = _row(base, label, m, ref, j_ref, data_cone, sc)
        row["conic"] = used_conic
        ctx = data.ctx
        row["max_violation"] = (
            max(c.violation(m.states, ctx).max_violation for c in cons)
            if m.states is not None and ctx is not None
            else math.nan
        )
        same, j_same = (ref, j_ref) if used_conic else (poly, j_poly)
        if m.states is not None and same is not None:
            row["objective_gap_same"] = (mstep_objective(sc.model, m.states, data) - j_same) / abs(j_same)
            row["max_pos_diff_same"] = _pos_diff(m.states, same)
        else:
            row["objective_gap_same"] = row["max_pos_diff_same"] = math.nan
        rows.append(row)
        if bar is not None:
            bar.set_postfix_str(f"{base['scenario']} {case} {label}", refresh=False)
            bar.update(1)
    return rows


# ------------------------------------------------------------------------------------------ whole plans


#: Kalman plans of this process (positions, total distance), by plan parameters: the reference of the
#: other backends' trials, which follow the kalman trial of the same scenario.
_KALMAN_PLANS: dict[tuple[str, int, int, int | None], tuple[np.ndarray, float]] = {}


def _kalman_plan(kind: str, seed: int, iterations: int, horizon: int | None) -> tuple[np.ndarray, float]:
    key = (kind, seed, iterations, horizon)
    if key not in _KALMAN_PLANS:
        sc = study_scenario(kind, seed, horizon)
        res = plan_pmht(sc, PMHTConfig(solver="kalman", max_iter=iterations, threads=1))
        _remember(key, res.positions, res.total_distance)
    return _KALMAN_PLANS[key]


def _remember(key: tuple[str, int, int, int | None], positions: np.ndarray, distance: float) -> None:
    while len(_KALMAN_PLANS) >= 4:
        _KALMAN_PLANS.pop(next(iter(_KALMAN_PLANS)))
    _KALMAN_PLANS[key] = (positions.copy(), distance)


def plan_trial(kind: str, seed: int, backend: str, iterations: int, horizon: int) -> dict[str, Any]:
    """One whole plan with ``backend``; compared with the kalman plan of the same scenario."""
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
        cls, raw, message = _error_status(err)
        return {
            # A plan that stops at an inaccurate solve has failed; 'n/a' and 'infeasible' stay.
            "status": STATUS_FAILED if cls == STATUS_INACCURATE else cls,
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
        ref_pos, ref_dist = _kalman_plan(kind, seed, iterations, horizon)
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


PLANS = TrialTable(
    name="solvers_plans",
    fn=plan_trial,
    schema=Schema(
        params={"kind": "str", "seed": "int", "backend": "str", "iterations": "int", "horizon": "int"},
        values={
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
        },
    ),
    checks={
        name: Check("skip", reason="wall-clock time differs from run to run")
        for name in ("wall_time", "estep_time", "mstep_time")
    },
)
#: The study's trial table, for ``--verify``.
TABLE = PLANS

#: Single M-step measurements: written whole at the end of a run (they are timed one after another in
#: this process, not trials), in the same typed format as the trial tables.
MSTEPS = Schema(
    params={"part": "str", "case": "str", "scenario": "str", "seed": "int", "backend": "str"},
    values={
        "group": "str",
        "iteration": "int",
        "r": "float",
        "horizon": "int",
        "reference": "str",
        "constraints": "str?",
        "status": "str",
        "raw_status": "str?",
        "message": "str?",
        "setup_s": "float",
        "first_solve_s": "float",
        "time_s": "float",
        "times_s": "list",
        "iterations": "int?",
        "objective": "float",
        "objective_gap": "float",
        "max_pos_diff": "float",
        "conic": "bool?",
        "max_violation": "float?",
        "objective_gap_same": "float?",
        "max_pos_diff_same": "float?",
        "reference_status": "str?",
    },
)
MSTEPS_NAME = "solvers_msteps"


def write_msteps(path: Path, rows: Sequence[Mapping[str, Any]]) -> Path:
    """Write the single M-step rows afresh as a typed results file."""
    keys = set(MSTEPS.params)
    with ResultsFile(path, MSTEPS, MSTEPS_NAME, provenance(), resume=False) as store:
        for r in rows:
            store.append({k: r[k] for k in MSTEPS.params}, {k: v for k, v in r.items() if k not in keys})
    return path


# ------------------------------------------------------------------------------------------ summaries


def _max_abs(values: Sequence[Any]) -> float:
    vals = finite(values)
    return max(abs(v) for v in vals) if vals else math.nan


def _statuses(rows: Sequence[Mapping[str, Any]]) -> str:
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    order = [STATUS_OK, STATUS_INACCURATE, STATUS_INFEASIBLE, STATUS_FAILED, STATUS_NA]
    return ", ".join(f"{k} {counts[k]}" for k in order if k in counts)


def _why(rows: Sequence[Mapping[str, Any]]) -> str:
    """The distinct raw statuses / messages of rows that are not optimal (shortened), with the EM
    iterations at which plans stopped."""
    seen: dict[str, list[int]] = {}
    for r in rows:
        if r["status"] == STATUS_OK:
            continue
        text = r.get("raw_status") or r.get("message") or ""
        text = str(text).replace("|", "/").replace("\n", " ")
        if len(text) > 90:
            text = text[:87] + "..."
        if text:
            at = seen.setdefault(text, [])
            if r.get("failed_at") is not None:
                at.append(int(r["failed_at"]))
        elif r["status"] == STATUS_INACCURATE:
            seen.setdefault("inaccurate", [])
    parts = []
    for text, at in seen.items():
        where = f" (at EM iteration {', '.join(str(i) for i in sorted(set(at)))})" if at else ""
        parts.append(text + where)
    return "; ".join(parts)


Rows = Sequence[Mapping[str, Any]]


def _group(rows: Rows, keys: Sequence[str]) -> dict[tuple[Any, ...], list[Mapping[str, Any]]]:
    out: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return out


def summarise_msteps(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (part, case group, backend): times, iterations, worst gaps and differences."""
    out = []
    for (part, case, backend), mine in _group(rows, ("part", "group", "backend")).items():
        good = [r for r in mine if r["status"] in (STATUS_OK, STATUS_INACCURATE)]
        entry: dict[str, Any] = {
            "part": part,
            "case": case,
            "backend": backend,
            "cases": len(mine),
            "statuses": _statuses(mine),
            "why": _why(mine),
            "median_time_s": median([r["time_s"] for r in good]),
            "max_time_s": max(finite([r["time_s"] for r in good]), default=math.nan),
            "median_first_solve_s": median([r["first_solve_s"] for r in good]),
            "median_iterations": median([r["iterations"] for r in good]),
            "max_abs_objective_gap": _max_abs([r["objective_gap"] for r in good]),
            "max_pos_diff": _max_abs([r["max_pos_diff"] for r in good]),
        }
        if part == "constrained":
            entry["max_violation"] = _max_abs([r.get("max_violation") for r in good])
            entry["max_abs_objective_gap_same"] = _max_abs([r.get("objective_gap_same") for r in good])
            entry["max_pos_diff_same"] = _max_abs([r.get("max_pos_diff_same") for r in good])
        out.append(entry)
    return out


def summarise_plans(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per backend: plans by status, median time, distances and differences to the kalman plan."""
    out = []
    for (backend,), mine in _group(rows, ("backend",)).items():
        good = [r for r in mine if r.get("status") == STATUS_OK]
        diffs = summarise(finite([r.get("max_pos_diff") for r in good]))
        out.append(
            {
                "backend": backend,
                "plans": len(mine),
                "scenarios": " ".join(sorted({f"{r['kind']}{r['seed']}" for r in mine})),
                "statuses": _statuses(mine),
                "why": _why(mine),
                "median_wall_time_s": median([r.get("wall_time") for r in good]),
                "median_mstep_time_s": median([r.get("mstep_time") for r in good]),
                "mean_distance": summarise(finite([r.get("total_distance") for r in good]))["mean"],
                "kalman_mean_distance": summarise(finite([r.get("kalman_distance") for r in good]))["mean"],
                "max_abs_distance_rel_diff": _max_abs([r.get("distance_rel_diff") for r in good]),
                "median_max_pos_diff": diffs["median"],
                "max_max_pos_diff": diffs["max"],
                "mean_solver_iterations": median([r.get("mean_solver_iterations") for r in good]),
            }
        )
    return out


def _f(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, int):
        return str(x)
    x = float(x)
    if x == 0:
        return "0"
    if abs(x) >= 1e4 or abs(x) < 1e-2:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits + 1}g}" if abs(x) < 10 else f"{x:.{max(digits - 1, 0)}f}"


def _it(x: Any) -> str:
    if x is None or not math.isfinite(float(x)):
        return "-"
    return f"{float(x):.0f}" if float(x).is_integer() or float(x) >= 100 else f"{float(x):.1f}"


def _ms(x: Any) -> str:
    return "-" if x is None or not math.isfinite(float(x)) else f"{1e3 * float(x):.1f}"


def markdown(
    msteps: Sequence[Mapping[str, Any]],
    plans: Sequence[Mapping[str, Any]],
    plan_rows: Sequence[Mapping[str, Any]],
    settings: Mapping[str, Any],
    prov: Mapping[str, Any],
) -> str:
    """The study's tables."""
    repeats = settings["repeats"]
    lines = [
        "# Study 2: M-step backends",
        "",
        f"Machine: {prov['machine']}, {prov['cpu_count']} cores; load average {settings['load_average']} "
        "(other jobs inflate every time alike). QP backends on one thread. "
        f"Times are medians of {repeats} solves "
        "of the same M-step (each after re-solving the previous iteration's M-step, so warm starts are "
        "as inside a plan); 'first solve' is the previous iteration's M-step solved right after setup, "
        "including cvxpy's compilation (cvxpy compiles a constrained problem at every solve, so its "
        "constrained times include compilation). Iterations: the sum over the platforms' QPs for clarabel"
        " and osqp, the one stacked problem for cvxpy, none for kalman (a direct smoother). Objective "
        "gap: (J - J_ref) / |J_ref| of the M-step cost J (`pmht_opt.mstep.mstep_objective`). Position "
        "difference: largest |x - x_ref| or |y - y_ref| over platforms and steps. Every problem here is "
        "feasible (the unconstrained ones trivially, the constrained ones solved by the reference), so an"
        " 'infeasible' verdict is a solver failure. 'n/a': the solver cannot take the problem class "
        "(an LP-only solver, or a QP-only solver given second-order cones).",
        f"Reproduce: `{settings['command']}`.",
        "",
    ]
    unc = [s for s in msteps if s["part"] == "unconstrained"]
    lines += [
        "## Unconstrained single M-steps",
        "",
        f"Scenarios {', '.join(settings['kinds'])} (seed {settings['mstep_seed']}), M-step of EM iteration "
        + " and ".join(f"{k + 1} ({name})" for name, k in settings["stages"].items())
        + " of the default (annealed) plan. **Reference: the kalman (RTS) smoother.** Worst case over "
        "the scenarios.",
        "",
        "| iterate | backend | M-steps | status | median time (ms) | first solve (ms) | iterations "
        "| max abs objective gap | max position difference | notes |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in unc:
        lines.append(
            f"| {s['case'].replace('unconstrained-', '')} | {s['backend']} | {s['cases']} | {s['statuses']} "
            f"| {_ms(s['median_time_s'])} | {_ms(s['median_first_solve_s'])} | {_it(s['median_iterations'])} "
            f"| {_f(s['max_abs_objective_gap'])} | {_f(s['max_pos_diff'])} | {s['why']} |"
        )
    con = [s for s in msteps if s["part"] == "constrained"]
    lines += [
        "",
        "## Constrained single M-steps",
        "",
        "Late iterate. speed+area: `SpeedLimit` at "
        f"{SPEED_FRACTION:.0%} of the unconstrained answer's top speed and `AreaBounds` (the area, grown "
        f"to contain the starts); obstacle: `CircleObstacle` of radius {OBSTACLE_RADIUS:g} (linearised at "
        "the iterate). **Kalman cannot take constraints: the reference is Clarabel at tolerance "
        f"{REFERENCE_TOL:g} with iterative refinement, with second-order cones** (the tightest "
        "setting at which Clarabel still reports 'Solved'; 'cvxpy/CLARABEL (tight)' is the same problem "
        "at the same tolerances through cvxpy, solved on the compiled problem of the row above it, and "
        "shows how far the reference itself is determined). "
        "osqp and 'clarabel (polygons)' impose the cones as inner 16-gons, so their gap to the reference "
        "includes that approximation; the 'same problem' columns compare them with the reference solve "
        "of the polygonal problem. Violation: largest violation of the exact (circular) constraints.",
        "",
        "| case | backend | M-steps | status | median time (ms) | first solve (ms) | iterations "
        "| max abs objective gap | max position difference | same problem: gap | same problem: "
        "position difference | max violation | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in con:
        lines.append(
            f"| {s['case']} | {s['backend']} | {s['cases']} | {s['statuses']} | {_ms(s['median_time_s'])} "
            f"| {_ms(s['median_first_solve_s'])} | {_it(s['median_iterations'])} "
            f"| {_f(s['max_abs_objective_gap'])} | {_f(s['max_pos_diff'])} "
            f"| {_f(s['max_abs_objective_gap_same'])} | {_f(s['max_pos_diff_same'])} "
            f"| {_f(s['max_violation'])} | {s['why']} |"
        )
    horizon = settings["horizon"] if settings["horizon"] != 500 else "500 (the paper's)"
    lines += [
        "",
        "## Whole plans",
        "",
        f"{settings['iterations']} EM iterations, default configuration (annealed), horizon {horizon}; "
        f"seeds 0..{settings['seeds'] - 1} for kalman, clarabel and osqp, 0..{settings['cvxpy_seeds'] - 1} "
        "for each cvxpy solver (a cvxpy plan takes several seconds). **Reference: the kalman plan of the "
        "same scenario.** Plans are compared by statistics, not exactly: EM amplifies the M-steps' "
        "last-digit differences, so positions can drift apart over 100 iterations (SPEC section 6). "
        "Plans do not accept inaccurate solves: such a plan fails, and is counted here, with the EM "
        "iteration it stopped at; the '(accept inaccurate)' variant runs the same plans with "
        "`accept_inaccurate=True`.",
        "",
        "| backend | plans | status | median wall time (s) | median M-step time (s) | mean distance "
        "(kalman, same plans) "
        "| max abs distance difference (rel.) | position difference: median | max "
        "| solver iterations per M-step | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in plans:
        lines.append(
            f"| {s['backend']} | {s['plans']} | {s['statuses']} | {_f(s['median_wall_time_s'])} "
            f"| {_f(s['median_mstep_time_s'])} "
            f"| {_f(s['mean_distance'], 3)} ({_f(s['kalman_mean_distance'], 3)}) "
            f"| {_f(s['max_abs_distance_rel_diff'])} | {_f(s['median_max_pos_diff'])} "
            f"| {_f(s['max_max_pos_diff'])} | {_it(s['mean_solver_iterations'])} | {s['why']} |"
        )
    lines += [
        "",
        "Per plan (max position difference to the kalman plan):",
        "",
        "| backend | " + " | ".join(sorted({f"{r['kind']}{r['seed']}" for r in plan_rows})) + " |",
        "|---|" + "---|" * len({f"{r['kind']}{r['seed']}" for r in plan_rows}),
    ]
    cols = sorted({f"{r['kind']}{r['seed']}" for r in plan_rows})
    for (backend,), mine in _group(plan_rows, ("backend",)).items():
        by = {f"{r['kind']}{r['seed']}": r for r in mine}
        cells = []
        for c in cols:
            r = by.get(c)
            if r is None:
                cells.append("")
            elif r.get("status") != STATUS_OK:
                cells.append(str(r.get("status")))
            else:
                cells.append(_f(r.get("max_pos_diff")))
        lines.append(f"| {backend} | " + " | ".join(cells) + " |")
    versions = ", ".join(f"{k} {v}" for k, v in {"python": prov["python"], **prov["packages"]}.items())
    lines += [
        "",
        f"Versions: {versions}; commit {prov['commit']}" + (" (dirty)" if prov["dirty"] else "") + ".",
        "",
    ]
    return "\n".join(lines)


def plot(msteps: Sequence[Mapping[str, Any]], plan_rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Time against position difference per backend: unconstrained, constrained M-steps, whole plans."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    floor = 1e-16
    from matplotlib.ticker import NullFormatter

    labels = list(dict.fromkeys([str(r["backend"]) for r in msteps] + [str(r["backend"]) for r in plan_rows]))
    style: dict[str, tuple[str, str]] = {
        "kalman": ("black", "o"),
        "reference (cones)": ("black", "h"),
        "clarabel": ("tab:blue", "s"),
        "clarabel (polygons)": ("tab:blue", "*"),
        "osqp": ("tab:green", "D"),
        "cvxpy/CLARABEL": ("tab:red", "^"),
        "cvxpy/CLARABEL (tight)": ("tab:red", "v"),
        "cvxpy/CLARABEL" + ACCEPT: ("tab:red", "<"),
        "cvxpy/OSQP": ("tab:olive", ">"),
        "cvxpy/SCS": ("tab:purple", "p"),
    }
    spare = [(c, m) for m in "XPd" for c in ("tab:orange", "tab:brown", "tab:pink", "tab:cyan", "tab:gray")]
    for b in labels:
        if b not in style:
            style[b] = spare[len(style) % len(spare)]
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5))
    unc = [r for r in msteps if r["part"] == "unconstrained"]
    con = [r for r in msteps if r["part"] == "constrained"]
    panels = [
        ("Unconstrained M-steps (ref: kalman)", unc, "time_s"),
        ("Constrained M-steps (ref: tight Clarabel)", con, "time_s"),
        ("Whole plans (ref: kalman plan)", list(plan_rows), "wall_time"),
    ]
    for ax, (title, rows, tkey) in zip(axes, panels, strict=True):
        shown = set()
        for r in rows:
            if r.get("status") not in (STATUS_OK, STATUS_INACCURATE):
                continue
            t, d = r.get(tkey), r.get("max_pos_diff")
            if t is None or d is None or not (math.isfinite(t) and math.isfinite(d)):
                continue
            b = str(r["backend"])
            color, marker = style[b]
            ax.scatter(
                t,
                max(d, floor),
                color=color,
                marker=marker,
                s=36,
                alpha=0.8,
                facecolors="none" if r.get("status") == STATUS_INACCURATE else color,
                label=None if b in shown else b,
            )
            shown.add(b)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(title)
        ax.set_xlabel("wall time per plan (s)" if tkey == "wall_time" else "M-step solve time (s)")
        ax.set_ylabel("max position difference to the reference")
        ax.grid(True, which="both", alpha=0.3)
        if shown:
            ax.legend(fontsize=7, loc="best")
    fig.text(
        0.5,
        0.01,
        f"Zero differences drawn at {floor:g}; hollow markers: inaccurate; failed and n/a solves are "
        "omitted (see solvers.md).",
        ha="center",
        fontsize=8,
    )
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------ driver


def run(
    out_dir: Path,
    *,
    kinds: Sequence[str] = ("A", "B", "C"),
    mstep_seed: int = 0,
    stages: Mapping[str, int] | None = None,
    repeats: int = 5,
    seeds: int = 5,
    cvxpy_seeds: int = 2,
    iterations: int = 100,
    horizon: int = 500,
    parts: Sequence[str] = ("unconstrained", "constrained", "plans"),
    cvxpy_names: Sequence[str] | None = None,
    executor: Any = None,
    progress: bool = True,
    resume: bool = True,
    command: str = "pmht-opt study solvers",
    tables_only: bool = False,
) -> tuple[dict[str, Any], list[Path]]:
    """Run the study into ``out_dir``; return the summaries (also written to ``solvers.json``) and the
    paths written.

    ``tables_only`` rewrites the summaries, tables and figure from the raw tables already in
    ``out_dir`` (and the settings in its ``solvers.json``) without measuring anything."""
    out_dir = Path(out_dir)
    if tables_only:
        return _report(out_dir, progress)
    load_start = load_average()
    stages = dict(STAGES if stages is None else stages)
    names = cvxpy_solvers() if cvxpy_names is None else [str(s).upper() for s in cvxpy_names]
    labels = backends(names)
    n_con_labels = len(labels) + int("clarabel" in labels) + int("cvxpy/CLARABEL" in labels)
    n_units = 0
    if "unconstrained" in parts:
        n_units += len(kinds) * len(stages) * len(labels)
    if "constrained" in parts:
        n_units += len(kinds) * len(CONSTRAINED_CASES) * n_con_labels
    from tqdm import tqdm

    bar = tqdm(total=n_units, desc="solvers: M-steps", disable=not (progress and n_units), file=sys.stderr)
    mstep_rows: list[dict[str, Any]] = []
    try:
        for kind in kinds:
            sc = study_scenario(kind, mstep_seed, horizon)
            iterates = {name: make_iterate(sc, k) for name, k in stages.items()}
            if "unconstrained" in parts:
                for name, it in iterates.items():
                    mstep_rows += unconstrained_rows(it, name, mstep_seed, labels, repeats, bar)
            if "constrained" in parts:
                late = iterates[list(stages)[-1]]
                for case in CONSTRAINED_CASES:
                    mstep_rows += constrained_rows(late, case, mstep_seed, labels, repeats, bar)
    finally:
        bar.close()
    for r in mstep_rows:
        r["group"] = r["case"].split("-")[-1] if r["part"] == "unconstrained" else r["case"]
    written: list[Path] = []
    if mstep_rows:
        written.append(write_msteps(out_dir / f"{MSTEPS_NAME}.jsonl", mstep_rows))

    plan_rows: list[dict[str, Any]] = []
    if "plans" in parts:
        plan_labels: list[str] = []
        for label in labels:
            plan_labels.append(label)
            plan_labels += [v for v in PLAN_VARIANTS if v.removesuffix(ACCEPT) == label]
        trials = []
        for kind in kinds:
            for seed in range(max(seeds, cvxpy_seeds)):
                for label in plan_labels:
                    if seed >= (cvxpy_seeds if label.startswith("cvxpy/") else seeds):
                        continue
                    trials.append(
                        {
                            "kind": kind,
                            "seed": seed,
                            "backend": label,
                            "iterations": iterations,
                            "horizon": horizon,
                        }
                    )
        plan_rows = run_trials(
            PLANS,
            trials,
            out_dir,
            executor=executor,
            progress=progress,
            label="solvers: plans",
            resume=resume,
        )
        written.append(PLANS.path(out_dir))
    settings = {
        "kinds": list(kinds),
        "mstep_seed": mstep_seed,
        "stages": stages,
        "repeats": repeats,
        "seeds": seeds,
        "cvxpy_seeds": cvxpy_seeds,
        "iterations": iterations,
        "horizon": horizon,
        "parts": list(parts),
        "backends": labels,
        "reference_settings": REFERENCE_SETTINGS,
        "load_average": f"{load_start} at the start, {load_average()} at the end",
        "command": command,
    }
    summary, files = _write(out_dir, settings, mstep_rows, plan_rows, progress)
    return summary, written + files


def _write(
    out_dir: Path, settings: Mapping[str, Any], mstep_rows: Rows, plan_rows: Rows, progress: bool
) -> tuple[dict[str, Any], list[Path]]:
    mstep_summary = summarise_msteps(mstep_rows)
    plan_summary = summarise_plans(plan_rows)
    prov = provenance()
    summary = {"settings": dict(settings), "provenance": prov, "msteps": mstep_summary, "plans": plan_summary}
    text = markdown(mstep_summary, plan_summary, plan_rows, settings, prov)
    files = [
        write_json(out_dir / "solvers.json", summary),
        write_text(out_dir / "solvers.md", text),
        plot(mstep_rows, plan_rows, out_dir / "solvers.png"),
    ]
    if progress:
        print(text)
    return summary, files


def _report(out_dir: Path, progress: bool) -> tuple[dict[str, Any], list[Path]]:
    """Summaries, tables and figure again from the raw tables and settings already in ``out_dir``."""
    try:
        settings = json.loads((out_dir / "solvers.json").read_text())["settings"]
    except (OSError, ValueError, KeyError) as err:
        raise ConfigError(f"--tables-only: no usable {out_dir / 'solvers.json'} ({err}).") from None
    parts = settings["parts"]
    mstep_rows: list[dict[str, Any]] = []
    if "unconstrained" in parts or "constrained" in parts:
        mstep_rows = read_rows(out_dir / f"{MSTEPS_NAME}.jsonl", MSTEPS, MSTEPS_NAME)
    plan_rows = []
    if "plans" in parts:
        # The table may hold rows of other runs (other seeds, horizons): keep this run's.
        backends_run = {*settings["backends"], *PLAN_VARIANTS}
        for r in read_rows(PLANS.path(out_dir), PLANS.schema, PLANS.name):
            seeds = settings["cvxpy_seeds"] if r["backend"].startswith("cvxpy/") else settings["seeds"]
            if (
                r["kind"] in settings["kinds"]
                and r["backend"] in backends_run
                and r["seed"] < seeds
                and r["iterations"] == settings["iterations"]
                and r["horizon"] == settings["horizon"]
            ):
                plan_rows.append(r)
    return _write(out_dir, settings, mstep_rows, plan_rows, progress)


@dataclass(frozen=True)
class Options:
    """Options of ``pmht-opt study solvers``; ``quick`` is a reduced run (scenario A, short horizon)."""

    quick: bool = False
    kinds: tuple[str, ...] = ("A", "B", "C")
    repeats: int = 5
    seeds: int = 5
    cvxpy_seeds: int = 2
    iterations: int = 100
    horizon: int = 500
    parts: tuple[str, ...] = ("unconstrained", "constrained", "plans")
    cvxpy_solvers: tuple[str, ...] | None = None
    tables_only: bool = False

    def __post_init__(self) -> None:
        positive_int("--repeats", self.repeats)
        positive_int("--seeds", self.seeds)
        positive_int("--cvxpy-seeds", self.cvxpy_seeds, minimum=0)
        positive_int("--iterations", self.iterations)
        positive_int("--horizon", self.horizon, minimum=2)
        if not self.kinds or not self.parts:
            raise ConfigError("--kinds and --parts: expected at least one value each.")

    @staticmethod
    def add_arguments(p: argparse.ArgumentParser) -> None:
        """The command-line options of this study."""
        p.add_argument("--quick", action="store_true", help="a reduced run (scenario A, short horizon)")
        p.add_argument("--kinds", nargs="+", default=None, choices=["A", "B", "C"], help="paper scenarios")
        p.add_argument("--repeats", type=int, default=None, help="timed solves per M-step (default 5)")
        p.add_argument(
            "--seeds", type=int, default=None, help="plan seeds for kalman/clarabel/osqp (default 5)"
        )
        p.add_argument(
            "--cvxpy-seeds", type=int, default=None, help="plan seeds per cvxpy solver (default 2)"
        )
        p.add_argument("--iterations", type=int, default=None, help="EM iterations per plan (default 100)")
        p.add_argument("--horizon", type=int, default=None, help="time steps (default: the paper's 500)")
        p.add_argument(
            "--parts",
            nargs="+",
            default=["unconstrained", "constrained", "plans"],
            choices=["unconstrained", "constrained", "plans"],
            help="which parts to run",
        )
        p.add_argument(
            "--cvxpy-solvers", nargs="+", default=None, help="cvxpy solvers (default: all installed)"
        )
        p.add_argument(
            "--tables-only",
            action="store_true",
            help="only rewrite solvers.md, solvers.json and solvers.png from the raw tables in --out",
        )

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> Options:
        """The options from parsed arguments; ``--quick`` changes the defaults of those not given."""
        quick = bool(ns.quick)

        def pick(value: int | None, full: int, reduced: int) -> int:
            return value if value is not None else (reduced if quick else full)

        names = ns.cvxpy_solvers
        if names is None and quick:
            names = [n for n in cvxpy_solvers() if n not in QUICK_SKIP]
        return cls(
            quick=quick,
            kinds=tuple(ns.kinds) if ns.kinds else (("A",) if quick else ("A", "B", "C")),
            repeats=pick(ns.repeats, 5, 2),
            seeds=pick(ns.seeds, 5, 1),
            cvxpy_seeds=pick(ns.cvxpy_seeds, 2, 1),
            iterations=pick(ns.iterations, 100, 10),
            horizon=pick(ns.horizon, 500, 80),
            parts=tuple(ns.parts),
            cvxpy_solvers=None if names is None else tuple(names),
            tables_only=bool(ns.tables_only),
        )


def main(run_options: RunOptions, options: Options) -> list[Path]:
    """``pmht-opt study solvers``: return the paths written."""
    out = run_options.prepare()
    with run_options.executor() as ex:
        _, written = run(
            out,
            kinds=options.kinds,
            stages=QUICK_STAGES if options.quick else STAGES,
            repeats=options.repeats,
            seeds=options.seeds,
            cvxpy_seeds=options.cvxpy_seeds,
            iterations=options.iterations,
            horizon=options.horizon,
            parts=options.parts,
            cvxpy_names=options.cvxpy_solvers,
            executor=ex,
            progress=not run_options.quiet,
            resume=not run_options.fresh,
            command="pmht-opt study solvers" + (" --quick" if options.quick else ""),
            tables_only=options.tables_only,
        )
    return written


if __name__ == "__main__":
    from studies.cli import main as cli_main

    sys.exit(
        cli_main(["solvers", "--out", str(Path(__file__).parent / "results" / "solvers"), *sys.argv[1:]])
    )
