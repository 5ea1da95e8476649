"""The M-step: the smoothing problem of one EM iteration, and its backends.

Given the E-step's weights the M-step finds the paths that maximise ``log P(X)`` plus the weighted fit
to the locales (docs/model.md section 4.4), subject to the constraints active in the iteration. Backends:

* ``banded``: the exact smoother of the unconstrained problem, a banded LU of its optimality
  conditions (:mod:`~pmht_opt.mstep.banded`): what ``solver="auto"`` runs without constraints, and the
  reference every other backend's answers are checked against (:mod:`~pmht_opt.mstep.check`);
* ``clarabel``, ``osqp``: the sparse QP of :mod:`pmht_opt.mstep.formulation` through :mod:`solvers`,
  one QP per platform, built once and updated in place (:mod:`~pmht_opt.mstep.qp`);
* ``cvxpy``: the same problem written in cvxpy, any installed cvxpy solver, native cvxpy constraints
  (:mod:`~pmht_opt.mstep.cvxpy_`);
* ``kalman``: a Rauch-Tung-Striebel smoother on the synthetic measurements, the exact cross-check of
  the unconstrained problem (:mod:`~pmht_opt.mstep.kalman`).

Settings tuned per backend are data in :mod:`~pmht_opt.mstep.tuning`; constraint rows are built by
:mod:`~pmht_opt.mstep.rows`; :mod:`~pmht_opt.mstep.registry` names the backends and checks what each
can impose.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.base import Constraint, ConstraintContext, fitting_constraints, pinned_ends
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.mstep.base import MStep, MStepData, MStepOutput
from pmht_opt.mstep.formulation import mstep_objective
from pmht_opt.mstep.registry import BACKENDS, available_backends, check_backend, make_mstep
from pmht_opt.scenario import Scenario


def _weights(name: str, value: Any, shape: tuple[int, ...], nonneg: bool) -> np.ndarray:
    arr = validation.real_array(name, value, ConfigError)
    if arr.shape != shape:
        raise ConfigError(f"{name}: expected shape {shape}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: contains NaN or infinite values.")
    if nonneg and np.any(arr < 0):
        raise ConfigError(f"{name}: expected non-negative weights.")
    return arr


@validation.plan_boundary("the M-step")
def solve_mstep(
    scenario: Scenario,
    W: Any,
    WZ: Any,
    r: float,
    solver: str = "clarabel",
    constraints: Sequence[Constraint] = (),
    *,
    settings: dict[str, Any] | None = None,
    accept_inaccurate: bool = False,
    paths: Any = None,
) -> np.ndarray:
    """Solve one M-step: the paths that best fit the weighted locales under the motion model.

    Parameters
    ----------
    scenario
        Starts, horizon and model.
    W
        ``(T, M)`` summed weights of each (time, platform), ``t = 1..T``.
    WZ
        ``(T, M, 2)`` weighted sums of the locales, ``sum_n w[n, t, m] z_n``.
    r
        Variance of the fitting penalty.
    solver
        Backend name (:func:`available_backends`).
    constraints
        Constraints imposed in this M-step (all of them; kinds that choose their rows from an E-step,
        such as :class:`~pmht_opt.constraints.VisitAll`, need the planner and raise ``ConfigError``).
    settings, accept_inaccurate
        As in :class:`~pmht_opt.PMHTConfig`.
    paths
        ``(M, T+1, 6)`` iterate at which non-convex constraints (obstacles) are linearised; default:
        every platform standing at its start.

    Returns
    -------
    numpy.ndarray
        ``(M, T+1, 6)`` states, ``t = 0..T``.

    Raises
    ------
    ScenarioError, ConfigError, UnknownSolverError
        Bad input, naming the field.
    InfeasibleError
        Hard constraints no answer can meet.
    WrongAnswerError
        An answer the backend reported as solved but the check refused (not finite, away from the
        exact smoother's without constraints, cheaper than the unconstrained optimum with them).
    SolverError
        Any other solve the backend did not stand behind.
    """
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"scenario: expected a Scenario, got {type(scenario).__name__}.")
    T, M = scenario.horizon, scenario.n_platforms
    W = _weights("W", W, (T, M), nonneg=True)
    WZ = _weights("WZ", WZ, (T, M, 2), nonneg=False)
    r = validation.real("r", r, ConfigError, *validation.R_RANGE)
    cons = fitting_constraints(scenario, constraints, (Sequence, set, frozenset))
    validation.flag("accept_inaccurate", accept_inaccurate)
    settings = {} if settings is None else settings
    validation.solver_settings("settings", settings)
    if paths is None:
        states = np.repeat(scenario.initial_states[:, None, :], T + 1, axis=1)
    else:
        states = _weights("paths", paths, (M, T + 1, 6), nonneg=False)
    ctx = None
    if cons:
        ctx = ConstraintContext(scenario=scenario, states=states, ends=pinned_ends(scenario, cons))
    mstep = make_mstep(scenario, check_backend(solver), settings, accept_inaccurate, 1, cons)
    try:
        out = mstep.solve(MStepData(W, WZ, r, ctx, tuple(range(len(cons)))))
    finally:
        mstep.close()
    return out.states


__all__ = [
    "BACKENDS",
    "MStep",
    "MStepData",
    "MStepOutput",
    "available_backends",
    "check_backend",
    "make_mstep",
    "mstep_objective",
    "solve_mstep",
]
