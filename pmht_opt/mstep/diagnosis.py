"""Naming the constraints that make an M-step infeasible.

When a platform's constrained M-step fails (a verdict of infeasibility, or a solver that stalls, as
interior-point and ADMM solvers do on infeasible problems without always certifying it), a *phase-one*
problem decides: the same dynamics and constraint rows, every unit relaxed by a slack ``s >= 0``
(:meth:`~pmht_opt.mstep.rows.Imposed.relaxed`), and the total slack as the only cost. The motion's own
costs are left out on purpose: with them, a penalty on the slacks trades violations against the price
of a manoeuvre, and a merely expensive manoeuvre would be reported as an impossible one. The slacks
that stay positive show where the least relaxation has to give; the error names every hard
constraint of the platform as the set that cannot all be met (the slack can land on any member of a
conflicting pair: an acceleration limit and a visit it forbids share the blame), then those slacks.
If no slack stays positive the problem is feasible and the failure was the solver's own, a
:class:`~pmht_opt.exceptions.SolverError` with its status. A phase-one solve that itself ends
inaccurate names culprits only where the slack is far above its reduced tolerances
(:data:`INACCURATE_CULPRIT_SLACK`). The phase-one problem measures positions from the platform's start
(:func:`~pmht_opt.mstep.formulation.start_frame`).

Slack says the rows cannot all be met, but not yet that the *constraints* cannot: some rows are a
planner's choices (visits imposed at the steps the EM or a tour chose, obstacles linearised at an
iterate). Only the rows that are the constraints themselves can prove it (:func:`_proof`): if their
own phase-one problem needs slack, no path meets them (:class:`~pmht_opt.exceptions.InfeasibleError`);
otherwise the failure is the schedule's (:class:`~pmht_opt.exceptions.ScheduleError`), and the
planner may try another.

The phase-one problems are solved by Clarabel (an interior-point solve of a second-order cone
program, the cones exact whatever the failing backend takes), so every backend gets the same verdict
on the same rows.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.exceptions import InfeasibleError, PmhtOptError, ScheduleError, SolverError
from pmht_opt.model import MotionModel
from pmht_opt.mstep.formulation import QPLayout, dynamics_rows, in_increments, start_frame
from pmht_opt.mstep.rows import PlatformRows, SlackOwner, assemble

#: Slacks above this fraction of a constraint's own size (or absolute, for linear rows) mark a culprit.
CULPRIT_SLACK = 1e-6
#: The same when the phase-one solve itself ended inaccurate ("almost solved"): its slacks are then
#: only trusted well above its reduced tolerances.
INACCURATE_CULPRIT_SLACK = 1e-3


def phase_one(
    model: MotionModel,
    x0: np.ndarray,
    horizon: int,
    rows: PlatformRows,
    session_class: type[solvers.QPSession],
) -> tuple[solvers.QPSolution, np.ndarray, list[SlackOwner]]:
    """Solve the phase-one problem of the module docstring; return the answer, the slacks and their owners."""
    layout = QPLayout(1, horizon)
    t_idx = np.arange(1, horizon + 1)
    col_map = layout.x(0, t_idx[:, None], np.arange(6)).ravel()
    x0_rel, origin = start_frame(x0, horizon)  # the platform QP's own coordinates
    extra = assemble([i.relaxed(1.0) for i in rows.items], layout.n, col_map, origin, layout.units)
    A_dyn, b_dyn = dynamics_rows(model, layout, x0_rel[None, :])
    width = layout.n + extra.n_slack
    A_dyn = sp.csc_matrix(
        (A_dyn.data, A_dyn.indices, np.concatenate([A_dyn.indptr, np.full(extra.n_slack, A_dyn.indptr[-1])])),
        shape=(A_dyn.shape[0], width),
    )
    rows_A, rows_b = in_increments(extra.A, extra.b, A_dyn, b_dyn, layout.n)
    problem = solvers.QPProblem(
        P=sp.csc_matrix((width, width)),
        q=np.concatenate([np.zeros(layout.n), extra.slack_cost]),
        A=sp.vstack([A_dyn, rows_A], format="csc"),
        b=np.concatenate([b_dyn, rows_b]),
        cones=(solvers.Zero(A_dyn.shape[0]), *extra.cones),
    )
    sol = session_class(problem).solve()
    slacks = np.zeros(extra.n_slack) if sol.x is None else sol.x[layout.n :]
    return sol, slacks, extra.slack_owner


def diagnose(
    model: MotionModel,
    x0: np.ndarray,
    horizon: int,
    platform: int,
    rows: PlatformRows,
    sol: solvers.QPSolution,
    session_class: type[solvers.QPSession],
) -> PmhtOptError:
    """The error for platform ``platform``'s failed M-step ``sol``: which constraints conflict, where it
    can tell (module docstring)."""
    names = sorted({i.name for i in rows.items if not i.soft})
    where = f"platform {platform}: the constraints {', '.join(names)} cannot all be met"
    try:
        probe, slacks, owners = phase_one(model, x0, horizon, rows, session_class)
    except solvers.QPError:
        probe = None
    if probe is None or not probe.usable(True):
        return SolverError(
            f"{sol.backend}: the M-step solve failed (platform {platform}) with status {sol.raw_status!r}.",
            sol.backend,
            sol.raw_status,
        )
    culprits = _culprits(slacks, owners, CULPRIT_SLACK if probe.ok else INACCURATE_CULPRIT_SLACK)
    if not culprits:
        others = "'cvxpy' or 'osqp'" if sol.backend == "clarabel" else "'clarabel'"
        more = ""
        if sol.backend == "osqp":  # a first-order solver may only need more iterations
            more = ", or more work for OSQP (solver_settings={'mstep_work_limit': None})"
        return SolverError(
            f"{sol.backend}: the M-step solve failed (platform {platform}) with status {sol.raw_status!r}; "
            "its constraints can all be met (a feasibility solve needs no slack), so the failure is the "
            f"solver's: try solver={others}{more}, or soft=True on the tightest constraint.",
            sol.backend,
            sol.raw_status,
        )
    proof = _proof(model, x0, horizon, platform, rows, session_class)
    if proof is not None:
        message = f"{sol.backend}: {proof}. Relax them or pass soft=True."
        return InfeasibleError(message, sol.backend, sol.raw_status)
    # The rows the planner placed (soft ones too: a soft start's discs are its choice as well).
    chosen = sorted({i.name for i in rows.items if not i.exact})
    return ScheduleError(
        f"{sol.backend}: {where} where this iteration imposes them (the steps of {', '.join(chosen)}, chosen "
        f"by the planner); the least relaxation needs {_parts(platform, culprits)}. The constraints "
        "themselves were not shown to be infeasible: other steps may meet them.",
        sol.backend,
        "schedule infeasible",
    )


def _culprits(
    slacks: np.ndarray, owners: list[SlackOwner], threshold: float
) -> dict[str, list[tuple[int, str | None, float]]]:
    """The slacks above ``threshold``, by constraint: ``(time, label, slack)``."""
    out: dict[str, list[tuple[int, str | None, float]]] = {}
    for value, owner in zip(slacks, owners, strict=True):
        if value > threshold:
            out.setdefault(owner.constraint, []).append((owner.time, owner.label, float(value)))
    return out


def _parts(platform: int, culprits: dict[str, list[tuple[int, str | None, float]]]) -> str:
    """Where each culprit's slack lands, worst first, in words."""
    parts = []
    for name, hits in sorted(culprits.items(), key=lambda kv: -max(h[2] for h in kv[1])):
        times = sorted({h[0] for h in hits})
        labels = sorted({h[1] for h in hits if h[1]}, key=lambda s: (len(s), s))
        span = f"t = {times[0]}" if len(times) == 1 else f"{len(times)} steps in t = {times[0]}..{times[-1]}"
        if labels:
            span += " (" + ", ".join(labels[:5]) + (", ..." if len(labels) > 5 else "") + ")"
        parts.append(f"{name} on platform {platform} at {span}, short by up to {max(h[2] for h in hits):.3g}")
    return "; ".join(parts)


def _proof(
    model: MotionModel,
    x0: np.ndarray,
    horizon: int,
    platform: int,
    rows: PlatformRows,
    session_class: type[solvers.QPSession],
) -> str | None:
    """A proof that no path of the platform meets its constraints, in words, or ``None``.

    The phase-one problem again, on the rows that *are* the user's constraints
    (:attr:`~pmht_opt.constraints.base.Constraint.exact`: convex, written whole, in their conic form
    whatever the backend takes): if even they need slack, no path meets them, whatever the planner's
    choices. Solved by the phase-one's interior point to its tolerance; slack above
    :data:`CULPRIT_SLACK` of a constraint's size counts.
    """
    exact = [i.conic() for i in rows.items if i.exact and not i.soft]
    if not exact:
        return None
    try:
        probe, slacks, owners = phase_one(model, x0, horizon, PlatformRows(exact, ()), session_class)
    except solvers.QPError:
        return None
    if not probe.ok:
        return None
    culprits = _culprits(slacks, owners, CULPRIT_SLACK)
    if not culprits:
        return None
    names = sorted({i.name for i in exact})
    return (
        f"platform {platform}: the constraints {', '.join(names)} cannot all be met by any path; the "
        f"least relaxation that reconciles them needs {_parts(platform, culprits)}"
    )
