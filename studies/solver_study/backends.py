"""Which backends the solver study compares, and how it classifies what each of them did.

A backend *label* is an M-step backend name (``kalman``, ``clarabel``, ``osqp``) or ``cvxpy/NAME`` for
the cvxpy backend with the cvxpy solver ``NAME``; a whole-plan label may end in :data:`ACCEPT`.

Every outcome is one of five classes. A solve that returned is classified by its typed
:class:`solvers.Status`. A solve that raised carries no typed status (the library's errors keep the
backend's own words, for messages), so it is classified by the error's type, and by what the backend
can take: a cvxpy solver that cvxpy itself refuses for the problem class (an LP-only solver given a
quadratic objective, a QP-only solver given second-order cones) is "n/a", not "failed".
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import solvers
from pmht_opt.exceptions import InfeasibleError, SolverError, UnknownSolverError, WrongAnswerError
from pmht_opt.mstep import BACKENDS, available_backends

STATUS_OK = "optimal"
STATUS_INACCURATE = "inaccurate"
STATUS_FAILED = "failed"
STATUS_NA = "n/a"
STATUS_INFEASIBLE = "infeasible"
#: The classes in the order the tables list them.
STATUS_ORDER = (STATUS_OK, STATUS_INACCURATE, STATUS_INFEASIBLE, STATUS_FAILED, STATUS_NA)

#: Suffix of a whole-plan backend label that runs the plan with ``accept_inaccurate=True``.
ACCEPT = " (accept inaccurate)"
#: Whole-plan variants run besides the plain backends: cvxpy/CLARABEL's plans can stop at its
#: 'optimal_inaccurate' (AlmostSolved at the tight unconstrained tolerances), so this shows what its
#: plans would give if the planner took those solves.
PLAN_VARIANTS = ("cvxpy/CLARABEL" + ACCEPT,)

#: cvxpy solvers left out of ``--quick``: HiGHS's active-set QP and SCS's compilation of cones are
#: slow even on the quick problems (docs/decisions.md section 8.3); the full study reports them.
QUICK_SKIP = ("HIGHS", "SCS")


def cvxpy_solvers() -> list[str]:
    """Installed cvxpy solvers, CLARABEL (the library's default) first; empty without cvxpy."""
    if "cvxpy" not in available_backends():
        return []
    import cvxpy as cp

    names = sorted(str(s) for s in cp.installed_solvers())
    return sorted(names, key=lambda s: s != "CLARABEL")


def backends(cvxpy_names: Sequence[str]) -> list[str]:
    """Backend labels of the study: the installed ones, then cvxpy with each solver."""
    have = available_backends()
    out: list[str] = [b for b in ("kalman", "banded", "clarabel", "osqp") if b in have]
    if "cvxpy" in have:
        out += [f"cvxpy/{s}" for s in cvxpy_names]
    return out


def backend_spec(label: str) -> tuple[str, dict[str, Any]]:
    """The M-step backend and its settings of a label.

    ``("cvxpy", {"cvxpy_solver": "SCS"})`` for ``"cvxpy/SCS"``; ``(label, {})`` otherwise (without the
    :data:`ACCEPT` suffix).
    """
    label = label.removesuffix(ACCEPT)
    if label.startswith("cvxpy/"):
        return "cvxpy", {"cvxpy_solver": label.split("/", 1)[1]}
    return label, {}


def takes_constraints(label: str) -> bool:
    """Whether the backend of ``label`` imposes constraints at all (not the exact smoothers)."""
    solver, _ = backend_spec(label)
    return bool(BACKENDS[solver].supports)


def takes_cones(label: str) -> bool:
    """Whether the backend of ``label`` imposes second-order cones as cones (not inner polygons)."""
    solver, _ = backend_spec(label)
    return "soc" in BACKENDS[solver].supports


def classify(status: solvers.Status) -> str:
    """The study's class of a solve that returned with ``status``."""
    if status in solvers.SOLUTION_PRESENT:
        return STATUS_OK
    if status in solvers.SOLUTION_INACCURATE:
        return STATUS_INACCURATE
    if status in solvers.INFEASIBLE or status is solvers.Status.DUAL_INFEASIBLE:
        return STATUS_INFEASIBLE
    return STATUS_FAILED


@functools.cache
def cvxpy_takes(solver: str, needs: frozenset[str]) -> bool:
    """Whether cvxpy accepts the solver ``solver`` for the M-step's problem class.

    The class is a quadratic objective with equality rows, plus linear inequalities and second-order
    cones as ``needs`` (constraint capabilities, :data:`pmht_opt.constraints.CAPABILITIES`) asks. A
    tiny problem of that class is compiled for the solver (``cvxpy.Problem.get_problem_data``, which
    builds cvxpy's solving chain without solving): cvxpy raises its ``SolverError`` when the solver
    cannot take the class or is not installed.
    """
    import cvxpy as cp

    x = cp.Variable(3)
    rows = [x[0] == 1.0]
    if "linear" in needs:
        rows.append(x[1] <= 2.0)
    if "soc" in needs:
        rows.append(cp.SOC(x[2] + 3.0, x[:2]))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x) + x[1]), rows)
    try:
        problem.get_problem_data(solver=solver)
    except cp.error.SolverError:
        return False
    return True


def applicable(label: str, needs: frozenset[str] = frozenset()) -> bool:
    """Whether the backend of ``label`` can take an M-step whose constraints need ``needs``."""
    solver, settings = backend_spec(label)
    if not BACKENDS[solver].supports:  # the exact smoothers: no constraints
        return not needs
    if solver == "cvxpy":
        return cvxpy_takes(str(settings["cvxpy_solver"]), needs)
    return True


def error_status(err: BaseException, label: str, needs: frozenset[str] = frozenset()) -> tuple[str, str, str]:
    """``(class, raw status, message)`` of a solve of ``label`` that raised ``err``.

    ``needs`` are the capabilities the M-step's constraints need (empty: the unconstrained M-step).
    """
    message = f"{type(err).__name__}: {err}"
    raw = str(err.status or "") if isinstance(err, SolverError) else ""
    if isinstance(err, WrongAnswerError):  # reported solved, refused by the library's check
        raw = f"{raw or 'solved'} reported, answer refused by the check"
    if isinstance(err, InfeasibleError):
        return STATUS_INFEASIBLE, raw, message
    if isinstance(err, UnknownSolverError) or not applicable(label, needs):
        return STATUS_NA, raw, message
    return STATUS_FAILED, raw, message
