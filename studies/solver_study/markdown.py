"""The solver study's tables as markdown (``solvers.md``): how each number was measured, then the tables.

The text states every reference and every definition next to its table, so the file can be read
without the code: what "objective gap" and "position difference" are, which reference each part uses
and why, and how failures are counted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from studies.solver_study.backends import STATUS_OK
from studies.solver_study.iterates import OBSTACLE_RADIUS, SPEED_FRACTION
from studies.solver_study.msteps import REFERENCE_TOL
from studies.solver_study.summary import group

Rows = Sequence[Mapping[str, Any]]


def fmt(x: Any, digits: int = 2) -> str:
    """A number in a table cell: ``-`` for none, scientific notation for very large or small ones."""
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


def fmt_iterations(x: Any) -> str:
    """A (median) solver iteration count."""
    if x is None or not math.isfinite(float(x)):
        return "-"
    return f"{float(x):.0f}" if float(x).is_integer() or float(x) >= 100 else f"{float(x):.1f}"


def fmt_ms(x: Any) -> str:
    """Seconds as milliseconds."""
    return "-" if x is None or not math.isfinite(float(x)) else f"{1e3 * float(x):.1f}"


def _intro(settings: Mapping[str, Any], prov: Mapping[str, Any]) -> list[str]:
    """The title and how every number below was measured and defined."""
    return [
        "# Study 2: M-step backends",
        "",
        f"Machine: {prov['machine']}, {prov['cpu_count']} cores; load average {settings['load_average']} "
        "(other jobs inflate every time alike). QP backends on one thread. "
        f"Times are medians of {settings['repeats']} solves "
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


def unconstrained_section(msteps: Rows, settings: Mapping[str, Any]) -> list[str]:
    """The table of unconstrained single M-steps (reference: kalman)."""
    lines = [
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
    for s in msteps:
        if s["part"] != "unconstrained":
            continue
        lines.append(
            f"| {s['case'].replace('unconstrained-', '')} | {s['backend']} | {s['cases']} | {s['statuses']} "
            f"| {fmt_ms(s['median_time_s'])} | {fmt_ms(s['median_first_solve_s'])} "
            f"| {fmt_iterations(s['median_iterations'])} "
            f"| {fmt(s['max_abs_objective_gap'])} | {fmt(s['max_pos_diff'])} | {s['why']} |"
        )
    return lines


def constrained_section(msteps: Rows) -> list[str]:
    """The table of constrained single M-steps (reference: tight Clarabel with cones)."""
    lines = [
        "",
        "## Constrained single M-steps",
        "",
        "Late iterate. speed+area: `SpeedLimit` at "
        f"{SPEED_FRACTION:.0%} of the unconstrained answer's top speed and `AreaBounds` (the area, grown "
        f"to contain the starts); obstacle: `CircleObstacle` of radius {OBSTACLE_RADIUS:g} (linearised at "
        "the iterate). **Kalman cannot take constraints: the reference is Clarabel at tolerance "
        f"{REFERENCE_TOL:g} with iterative refinement, with second-order cones** (the tightest "
        "setting at which Clarabel still reports 'Solved'; 'cvxpy/CLARABEL (tight)' is the same problem "
        "at the same tolerances through cvxpy, and shows how far the reference itself is determined). "
        "osqp and 'clarabel (polygons)' impose the cones as inner 16-gons, so their gap to the reference "
        "includes that approximation; the 'same problem' columns compare them with the reference solve "
        "of the polygonal problem. Violation: largest violation of the exact (circular) constraints.",
        "",
        "| case | backend | M-steps | status | median time (ms) | first solve (ms) | iterations "
        "| max abs objective gap | max position difference | same problem: gap | same problem: "
        "position difference | max violation | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in msteps:
        if s["part"] != "constrained":
            continue
        lines.append(
            f"| {s['case']} | {s['backend']} | {s['cases']} | {s['statuses']} | {fmt_ms(s['median_time_s'])} "
            f"| {fmt_ms(s['median_first_solve_s'])} | {fmt_iterations(s['median_iterations'])} "
            f"| {fmt(s['max_abs_objective_gap'])} | {fmt(s['max_pos_diff'])} "
            f"| {fmt(s['max_abs_objective_gap_same'])} | {fmt(s['max_pos_diff_same'])} "
            f"| {fmt(s['max_violation'])} | {s['why']} |"
        )
    return lines


def plans_section(plans: Rows, settings: Mapping[str, Any]) -> list[str]:
    """The table of whole plans (reference: the kalman plan of the same scenario)."""
    horizon = settings["horizon"] if settings["horizon"] != 500 else "500 (the paper's)"
    lines = [
        "",
        "## Whole plans",
        "",
        f"{settings['iterations']} EM iterations, default configuration (annealed), horizon {horizon}; "
        f"seeds 0..{settings['seeds'] - 1} for kalman, clarabel and osqp, 0..{settings['cvxpy_seeds'] - 1} "
        "for each cvxpy solver (a cvxpy plan takes several seconds). **Reference: the kalman plan of the "
        "same scenario.** Plans are compared by statistics, not exactly: EM amplifies the M-steps' "
        "last-digit differences, so positions can drift apart over 100 iterations (docs/model.md section "
        "4.6). Plans do not accept inaccurate solves: such a plan fails, and is counted here, with the EM "
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
            f"| {s['backend']} | {s['plans']} | {s['statuses']} | {fmt(s['median_wall_time_s'])} "
            f"| {fmt(s['median_mstep_time_s'])} "
            f"| {fmt(s['mean_distance'], 3)} ({fmt(s['kalman_mean_distance'], 3)}) "
            f"| {fmt(s['max_abs_distance_rel_diff'])} | {fmt(s['median_max_pos_diff'])} "
            f"| {fmt(s['max_max_pos_diff'])} | {fmt_iterations(s['mean_solver_iterations'])} | {s['why']} |"
        )
    return lines


def per_plan_table(plan_rows: Rows) -> list[str]:
    """Each plan's largest position difference to the kalman plan, backends by scenario."""
    cols = sorted({f"{r['kind']}{r['seed']}" for r in plan_rows})
    lines = [
        "",
        "Per plan (max position difference to the kalman plan):",
        "",
        "| backend | " + " | ".join(cols) + " |",
        "|---|" + "---|" * len(cols),
    ]
    for (backend,), mine in group(plan_rows, ("backend",)).items():
        by = {f"{r['kind']}{r['seed']}": r for r in mine}
        cells = []
        for c in cols:
            r = by.get(c)
            if r is None:
                cells.append("")
            elif r.get("status") != STATUS_OK:
                cells.append(str(r.get("status")))
            else:
                cells.append(fmt(r.get("max_pos_diff")))
        lines.append(f"| {backend} | " + " | ".join(cells) + " |")
    return lines


def markdown(
    msteps: Rows, plans: Rows, plan_rows: Rows, settings: Mapping[str, Any], prov: Mapping[str, Any]
) -> str:
    """The study's tables: ``msteps`` and ``plans`` are the summaries, ``plan_rows`` the plans' rows."""
    lines = _intro(settings, prov)
    lines += unconstrained_section(msteps, settings)
    lines += constrained_section(msteps)
    lines += plans_section(plans, settings)
    lines += per_plan_table(plan_rows)
    versions = ", ".join(f"{k} {v}" for k, v in {"python": prov["python"], **prov["packages"]}.items())
    lines += [
        "",
        f"Versions: {versions}; commit {prov['commit']}" + (" (dirty)" if prov["dirty"] else "") + ".",
        "",
    ]
    return "\n".join(lines)
