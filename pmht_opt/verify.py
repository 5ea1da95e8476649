"""Every returned plan is checked against its hard constraints, by code independent of the solver.

A solver's "solved" says its own residuals are small on the rows it was given, in its own scaling. The
user's question is different: do the returned positions meet the constraints, measured on the exact
geometry (true discs, polygons and segments, speeds from the positions)? Each constraint's
:meth:`~pmht_opt.constraints.Constraint.violation` answers it, and a plan is returned only if every
hard constraint holds within a tolerance relative to the constraint's own size
(:meth:`~pmht_opt.constraints.Constraint.scale`): a speed limit of 1e-9 is not met by 1e-7.

The tolerance depends on the backend that made the plan, stated once here: interior-point backends
meet their rows to about 1e-9 of the rows' scale; OSQP stops ADMM at 1e-5 on constrained M-steps, and
its cones are inner polygons, so its plans are held to 1e-3.

Below that, a floor: every measure is computed from positions in double precision, and differences of
positions of magnitude ``P`` (a displacement, a second difference) cannot be resolved below a few
units in the last place of ``P``. A limit so small that its relative tolerance falls under
:data:`ULPS` units of the scenario's coordinates (``AccelLimit(1e-9)`` on a 10 x 10 area: 1e-15 against
2e-15 per unit in the last place) is checked to that resolution instead, so rounding is never
reported as a broken constraint.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintReport
from pmht_opt.exceptions import SolverError
from pmht_opt.scenario import Scenario

#: Relative tolerance of the verification, per backend (relative to each constraint's scale).
RTOL: dict[str, float] = {"clarabel": 1e-6, "cvxpy": 1e-6, "osqp": 1e-3}
#: For a backend not listed.
DEFAULT_RTOL = 1e-6
#: Units in the last place of the scenario's coordinates below which no violation is resolved.
ULPS = 64.0


def resolution(scenario: Scenario) -> float:
    """The smallest violation measurable on positions of this scenario: :data:`ULPS` units in the last
    place of its largest coordinate (locales, starts, bounds; at least 1)."""
    extent = max(
        1.0, float(np.max(np.abs(scenario.locales))), float(np.max(np.abs(scenario.start_positions)))
    )
    if scenario.bounds is not None:
        extent = max(extent, *(abs(float(b)) for b in scenario.bounds))
    return ULPS * float(np.spacing(extent))


def tolerance(backend: str, constraint: Constraint, scenario: Scenario) -> float:
    """The largest violation of ``constraint`` accepted on a plan of ``backend``."""
    return max(RTOL.get(backend, DEFAULT_RTOL) * constraint.scale(scenario), resolution(scenario))


def verify_plan(
    backend: str, scenario: Scenario, constraints: Sequence[Constraint], reports: Sequence[ConstraintReport]
) -> None:
    """Raise :class:`SolverError` naming the constraint, platform and step if a hard constraint is broken."""
    for con, rep in zip(constraints, reports, strict=True):
        if con.soft:
            continue
        tol = tolerance(backend, con, scenario)
        if rep.max_violation > tol:
            where = "" if rep.worst is None else f" on platform {rep.worst[0]} at t = {rep.worst[1]}"
            raise SolverError(
                f"{backend}: the plan breaks {rep.name}{where} by {rep.max_violation:.3g} (tolerance "
                f"{tol:.3g}; {rep.n_violations} step(s) over 1e-6 of its size) although every M-step "
                "reported success.",
                backend=backend,
                status="verification failed",
            )
