"""Single M-steps: every backend on the same M-step, against a reference, as rows of a typed table.

Unconstrained M-steps are compared with the kalman (RTS) smoother, their exact answer. Kalman takes
no constraints, so constrained M-steps are compared with Clarabel at tight tolerances with iterative
refinement (:data:`REFERENCE_SETTINGS`); a backend without cones (osqp) imposes inner polygons, so its
gap to that reference includes the approximation, and the ``*_same`` columns compare it with the
reference solve of the polygonal problem instead.

The rows are timed one after another in this process, not trials, and are written whole at the end
of a run (:func:`write_msteps`) in the same typed format as the trial tables.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import solve_mstep
from pmht_opt.constraints import Constraint
from pmht_opt.model import POS
from pmht_opt.mstep import MStepData, mstep_objective
from pmht_opt.scenario import Scenario
from studies.provenance import provenance
from studies.solver_study.backends import STATUS_OK, takes_cones, takes_constraints
from studies.solver_study.iterates import Iterate, case_constraints
from studies.solver_study.measure import Job, Measured, measure, not_applicable
from studies.store import ResultsFile, Schema

#: The constrained reference: Clarabel with iterative refinement at the tightest tolerance at which
#: it still reports 'Solved' on the study's problems (docs/decisions.md section 8.3).
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
#: Row label of the cvxpy/CLARABEL solve at the reference's tolerances.
CVXPY_TIGHT = "cvxpy/CLARABEL (tight)"

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
    # A backend that failed, or does not take the problem, has no time and no answer to compare.
    not_measured={
        name: "no measurement where the backend failed or does not take the problem"
        for name in (
            "setup_s",
            "first_solve_s",
            "time_s",
            "objective",
            "objective_gap",
            "max_pos_diff",
            "max_violation",
            "objective_gap_same",
            "max_pos_diff_same",
        )
    },
)
MSTEPS_NAME = "solvers_msteps"

Row = dict[str, Any]


def pos_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest ``|x - x_ref|`` or ``|y - y_ref|`` over platforms and steps of two ``(M, T+1, 6)`` paths."""
    return float(np.max(np.abs(a[:, :, POS] - b[:, :, POS])))


def objective(scenario: Scenario, states: np.ndarray, data: MStepData) -> float:
    """The M-step cost ``J`` of ``states`` for the weights of ``data``."""
    return mstep_objective(scenario.model, states, data.W, data.WZ, data.r)


def make_row(
    base: Mapping[str, Any],
    backend: str,
    m: Measured,
    ref: np.ndarray | None,
    ref_objective: float,
    data: MStepData,
    scenario: Scenario,
) -> Row:
    """The row of one measurement, with its gap and position difference to the reference ``ref``."""
    row: Row = {**base, "backend": backend, "status": m.status, "raw_status": m.raw_status}
    row["message"] = m.message
    row["setup_s"] = m.setup_s
    row["first_solve_s"] = m.first_s
    row["time_s"] = float(np.median(m.times)) if m.times else math.nan
    row["times_s"] = m.times or []
    row["iterations"] = m.iterations
    if m.states is not None and ref is not None:
        j = objective(scenario, m.states, data)
        row["objective"] = j
        row["objective_gap"] = (j - ref_objective) / abs(ref_objective)
        row["max_pos_diff"] = pos_diff(m.states, ref)
    else:
        row["objective"] = row["objective_gap"] = row["max_pos_diff"] = math.nan
    return row


def _base(it: Iterate, part: str, case: str, seed: int, reference: str, constraints: str) -> Row:
    """The columns every row of one M-step shares: what was solved and against which reference."""
    sc = it.scenario
    return {
        "part": part,
        "case": case,
        "scenario": sc.name.split(" ")[0],
        "seed": seed,
        "iteration": it.cur.iteration,
        "r": it.cur.r,
        "horizon": sc.horizon,
        "reference": reference,
        "constraints": constraints,
    }


def _tick(bar: Any, text: str) -> None:
    """Advance the progress bar (if any) past the measurement ``text`` names."""
    if bar is not None:
        bar.set_postfix_str(text, refresh=False)
        bar.update(1)


def unconstrained_rows(
    it: Iterate, stage: str, seed: int, labels: Sequence[str], repeats: int, bar: Any
) -> list[Row]:
    """Every backend on the unconstrained M-step ``K + 1`` of ``it``; reference: kalman."""
    sc = it.scenario
    prev, cur = it.prev.data(sc), it.cur.data(sc)
    ref = solve_mstep(sc, cur.W, cur.WZ, cur.r, "kalman")
    j_ref = objective(sc, ref, cur)
    base = _base(it, "unconstrained", f"unconstrained-{stage}", seed, "kalman", "")
    rows = []
    for label in labels:
        m = measure(sc, Job(label), prev, cur, repeats)
        rows.append(make_row(base, label, m, ref, j_ref, cur, sc))
        _tick(bar, f"{base['scenario']} {stage} {label}")
    return rows


def constrained_jobs(labels: Sequence[str]) -> list[Job]:
    """The constrained measurements besides the reference, in table order.

    cvxpy/CLARABEL is also run at the reference's tolerances, and clarabel also on the polygonal
    problem (so a backend without cones has a same-problem counterpart that takes cones).
    """
    jobs = []
    for label in labels:
        jobs.append(Job(label))
        if label == "cvxpy/CLARABEL":
            jobs.append(Job(CVXPY_TIGHT, label, CVXPY_REFERENCE_SETTINGS))
        if label == "clarabel":
            jobs.append(Job("clarabel (polygons)", label, polygons=True))
    return jobs


def _solved(m: Measured) -> np.ndarray | None:
    """The paths of a reference solve, if it is one to compare with (optimal, not merely accepted)."""
    return m.states if m.states is not None and m.status == STATUS_OK else None


def constrained_rows(
    it: Iterate, case: str, seed: int, labels: Sequence[str], repeats: int, bar: Any
) -> list[Row]:
    """Every backend on a constrained M-step ``K + 1`` of ``it``; reference: tight Clarabel."""
    sc = it.scenario
    free = it.cur.data(sc)
    cons = case_constraints(case, sc, solve_mstep(sc, free.W, free.WZ, free.r, "kalman"))
    prev, cur = it.prev.data(sc, cons), it.cur.data(sc, cons)
    reference = f"clarabel tol {REFERENCE_TOL:g} + iterative refinement (cones)"
    base = _base(it, "constrained", case, seed, reference, "; ".join(c.name for c in cons))
    refs = {
        polygons: measure(
            sc, Job("clarabel", settings=REFERENCE_SETTINGS, polygons=polygons), prev, cur, 1, cons
        )
        for polygons in (False, True)
    }
    ref, poly = _solved(refs[False]), _solved(refs[True])
    j_ref = objective(sc, ref, cur) if ref is not None else math.nan
    j_poly = objective(sc, poly, cur) if poly is not None else math.nan
    rows = [make_row(base, "reference (cones)", refs[False], ref, j_ref, cur, sc)]
    rows[0]["reference_status"] = refs[False].raw_status
    for job in constrained_jobs(labels):
        if not takes_constraints(job.backend_label):
            m = not_applicable(f"{job.label} takes no constraints")
        else:
            m = measure(sc, job, prev, cur, repeats, cons)
        row = make_row(base, job.label, m, ref, j_ref, cur, sc)
        row.update(_same_problem(job, m, cons, cur, sc, (ref, j_ref), (poly, j_poly)))
        rows.append(row)
        _tick(bar, f"{base['scenario']} {case} {job.label}")
    return rows


def _same_problem(
    job: Job,
    m: Measured,
    cons: tuple[Constraint, ...],
    data: MStepData,
    sc: Scenario,
    cones: tuple[np.ndarray | None, float],
    polygons: tuple[np.ndarray | None, float],
) -> Row:
    """The columns that compare a constrained answer with the reference of the problem it solved
    (cones or polygons), and its violation of the exact constraints."""
    # The exact smoothers solve nothing here, in neither form.
    conic = (
        takes_cones(job.backend_label) and not job.polygons if takes_constraints(job.backend_label) else None
    )
    out: Row = {"conic": conic}
    ctx = data.ctx
    out["max_violation"] = (
        max(c.violation(m.states, ctx).max_violation for c in cons)
        if m.states is not None and ctx is not None
        else math.nan
    )
    same, j_same = cones if conic else polygons
    if m.states is not None and same is not None:
        out["objective_gap_same"] = (objective(sc, m.states, data) - j_same) / abs(j_same)
        out["max_pos_diff_same"] = pos_diff(m.states, same)
    else:
        out["objective_gap_same"] = out["max_pos_diff_same"] = math.nan
    return out


def write_msteps(path: Path, rows: Sequence[Mapping[str, Any]]) -> Path:
    """Write the single M-step rows afresh as a typed results file."""
    keys = set(MSTEPS.params)
    with ResultsFile(path, MSTEPS, MSTEPS_NAME, provenance(), resume=False) as store:
        for r in rows:
            store.append({k: r[k] for k in MSTEPS.params}, {k: v for k, v in r.items() if k not in keys})
    return path
