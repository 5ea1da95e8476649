"""Problem and solution types of the generic conic QP layer.

The standard form is the one Clarabel uses::

    minimise    1/2 x' P x + q' x
    subject to  A x + s = b,   s in K = K_1 x K_2 x ... x K_p

where each cone ``K_i`` is one of

* ``Zero(d)``: ``s = 0`` (equalities ``A_i x = b_i``),
* ``Nonneg(d)``: ``s >= 0`` (inequalities ``A_i x <= b_i``),
* ``SOC(d)``: ``s_0 >= ||s_1..s_{d-1}||`` (second-order cone).

Both types check themselves: :class:`QPProblem` validates shapes and finiteness on construction, and
:class:`QPSolution` can be judged against its problem (residuals, cone membership, objective) without
trusting the backend that produced it.
"""

from __future__ import annotations

import enum
import numbers
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp

from solvers.exceptions import ProblemError

ConeKind = Literal["zero", "nonneg", "soc"]


@dataclass(frozen=True)
class Cone:
    """One block of rows of ``A x + s = b`` and the cone its slack ``s`` lives in."""

    kind: ConeKind
    dim: int

    def __post_init__(self) -> None:
        if self.kind not in ("zero", "nonneg", "soc"):
            raise ProblemError(f"Expected cone kind 'zero', 'nonneg' or 'soc', got {self.kind!r}.")
        if isinstance(self.dim, bool) or not isinstance(self.dim, numbers.Integral) or self.dim < 1:
            raise ProblemError(f"Expected a positive integer cone dimension, got {self.dim!r}.")
        if self.kind == "soc" and self.dim < 2:
            raise ProblemError("Expected a second-order cone of dimension >= 2.")


def Zero(dim: int) -> Cone:
    """Equality rows: ``A_i x = b_i``."""
    return Cone("zero", dim)


def Nonneg(dim: int) -> Cone:
    """Inequality rows: ``A_i x <= b_i``."""
    return Cone("nonneg", dim)


def SOC(dim: int) -> Cone:
    """Second-order cone rows: ``||(b - A x)[1:]|| <= (b - A x)[0]``."""
    return Cone("soc", dim)


def floats(name: str, arr: Any, error: type[Exception] = ProblemError) -> np.ndarray:
    """``arr`` as a float array, or ``error`` naming it (strings, objects, ragged lists)."""
    try:
        return np.asarray(arr, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{name} must be numeric, got {type(arr).__name__}.") from None


def dense(name: str, arr: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``arr`` as a float array of ``shape`` with finite entries; :class:`ProblemError` naming it if not."""
    out = floats(name, arr)
    if out.shape != shape:
        raise ProblemError(f"{name} has shape {out.shape}, expected {shape}.")
    if not np.all(np.isfinite(out)):
        raise ProblemError(f"{name} has non-finite entries.")
    return out


def _as_csc(name: str, mat: Any, shape: tuple[int, int]) -> sp.csc_matrix:
    if not sp.issparse(mat):
        arr = floats(name, mat)
        if arr.ndim != 2:
            raise ProblemError(f"{name} must be a 2-D matrix, got an array of shape {arr.shape}.")
        mat = sp.csc_matrix(arr)
    out = sp.csc_matrix(mat, dtype=float)
    if out.shape != shape:
        raise ProblemError(f"{name} has shape {out.shape}, expected {shape}.")
    if not np.all(np.isfinite(out.data)):
        raise ProblemError(f"{name} has non-finite entries.")
    out.sort_indices()
    return out


@dataclass
class QPProblem:
    """A convex QP with conic constraints in Clarabel's standard form.

    Parameters
    ----------
    P
        Symmetric positive semidefinite cost matrix, shape ``(n, n)``. Only the upper triangle is used;
        a full symmetric matrix is reduced to it. Explicitly stored zeros are kept, so a caller can fix a
        sparsity pattern and later update the values in place.
    q
        Linear cost, shape ``(n,)``.
    A
        Constraint matrix, shape ``(m, n)``.
    b
        Constraint right-hand side, shape ``(m,)``.
    cones
        Cones in row order; their dimensions must add up to ``m``.
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    cones: tuple[Cone, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        q = floats("q", self.q)
        if q.ndim != 1:
            raise ProblemError(f"q must be a vector, got shape {q.shape}.")
        n = q.shape[0]
        if n == 0:
            raise ProblemError("The problem has no variables.")
        self.q = q
        self.P = _upper_triangle(_as_csc("P", self.P, (n, n)))
        b = floats("b", self.b).reshape(-1)
        self.b = b
        self.A = _as_csc("A", self.A, (b.shape[0], n))
        if not isinstance(self.cones, (tuple, list)) or not all(isinstance(c, Cone) for c in self.cones):
            raise ProblemError(f"cones must be a sequence of Cone (Zero, Nonneg, SOC), got {self.cones!r}.")
        self.cones = tuple(self.cones)
        if sum(c.dim for c in self.cones) != b.shape[0]:
            raise ProblemError(
                f"The cone dimensions add up to {sum(c.dim for c in self.cones)}, "
                f"but A and b have {b.shape[0]} rows."
            )
        if not np.all(np.isfinite(q)):
            raise ProblemError("q has non-finite entries.")
        if not np.all(np.isfinite(b)):
            raise ProblemError("b has non-finite entries.")

    @property
    def n(self) -> int:
        """Number of variables."""
        return int(self.q.shape[0])

    @property
    def m(self) -> int:
        """Number of constraint rows."""
        return int(self.b.shape[0])

    @property
    def has_soc(self) -> bool:
        """Whether any cone is a second-order cone."""
        return any(c.kind == "soc" for c in self.cones)

    def objective(self, x: np.ndarray) -> float:
        """``1/2 x' P x + q' x`` with ``P`` symmetric (stored as its upper triangle)."""
        px = self.P @ x + self.P.T @ x - self.P.diagonal() * x
        return float(0.5 * x @ px + self.q @ x)

    def cone_slices(self) -> list[tuple[Cone, slice]]:
        """Each cone with the slice of rows it covers."""
        out = []
        start = 0
        for cone in self.cones:
            out.append((cone, slice(start, start + cone.dim)))
            start += cone.dim
        return out

    def violation(self, x: np.ndarray) -> np.ndarray:
        """Per-row violation of ``x`` (zero where the row holds), shape ``(m,)``.

        Equality rows give ``|b - A x|``; inequality rows ``max(0, A x - b)``; each second-order cone
        puts ``max(0, ||s_1..|| - s_0)`` on its first row and zeros on the others
        (:func:`cone_violation`).
        """
        s = self.b - self.A @ x
        out = np.zeros(self.m)
        for cone, rows in self.cone_slices():
            if cone.kind == "soc":
                out[rows.start] = cone_violation(s[rows], "soc", cone.dim)[0]
            else:
                out[rows] = cone_violation(s[rows], cone.kind, 1)
        return out


def cone_violation(s: np.ndarray, kind: str, dim: int = 1) -> np.ndarray:
    """How far the slacks ``s`` are from their cones: one value per unit, 0 where it holds.

    ``s`` holds consecutive units of ``dim`` rows each (``dim = 1`` for the linear kinds). A ``zero``
    row is violated by ``|s|``, a ``nonneg`` row by ``max(0, -s)``, a second-order cone
    ``(s_0, s_1..)`` by ``max(0, ||s_1..|| - s_0)``: the distance, in the units of the rows, by which
    the constraint is missed. The one residual every checker of this library uses.
    """
    s = np.asarray(s, dtype=float)
    if kind == "zero":
        return np.abs(s)
    if kind == "nonneg":
        return np.maximum(-s, 0.0)
    if kind != "soc":
        raise ProblemError(f"Expected cone kind 'zero', 'nonneg' or 'soc', got {kind!r}.")
    units = s.reshape(-1, dim)
    return np.maximum(np.linalg.norm(units[:, 1:], axis=1) - units[:, 0], 0.0)


def _upper_triangle(P: sp.csc_matrix) -> sp.csc_matrix:
    """The upper triangle of ``P`` in CSC form, keeping explicitly stored zeros."""
    coo = P.tocoo()
    keep = coo.row <= coo.col
    lower = ~keep
    if np.any(lower):
        # A full symmetric matrix: check symmetry, then drop the lower half.
        diff = abs(P - P.T)
        if diff.nnz and diff.max() > 1e-9 * max(1.0, abs(P).max()):
            raise ProblemError("P is neither upper triangular nor symmetric.")
    out = sp.csc_matrix((coo.data[keep], (coo.row[keep], coo.col[keep])), shape=P.shape)
    out.sort_indices()
    return out


class Status(enum.Enum):
    """The library's solver statuses; each backend maps its own codes onto these."""

    OPTIMAL = "optimal"
    OPTIMAL_INACCURATE = "optimal_inaccurate"
    PRIMAL_INFEASIBLE = "primal_infeasible"
    DUAL_INFEASIBLE = "dual_infeasible"
    INFEASIBLE_INACCURATE = "infeasible_inaccurate"
    MAX_ITER = "max_iter"
    TIME_LIMIT = "time_limit"
    NUMERICAL_ERROR = "numerical_error"
    INTERRUPTED = "interrupted"
    UNKNOWN = "unknown"


#: Statuses whose solution vector the backend stands behind.
SOLUTION_PRESENT = frozenset({Status.OPTIMAL})
#: Statuses with a solution vector that is usable only if the caller accepts inaccuracy.
SOLUTION_INACCURATE = frozenset({Status.OPTIMAL_INACCURATE})
#: Statuses that certify (possibly inaccurately) that no feasible point exists.
INFEASIBLE = frozenset({Status.PRIMAL_INFEASIBLE, Status.INFEASIBLE_INACCURATE})


@dataclass
class QPSolution:
    """What a backend returned, with the backend's own status kept for messages.

    ``x`` is ``None`` only when the backend produced no primal vector at all. A solution is never
    ``None`` on failure: check :attr:`ok` (or :meth:`usable`) before using ``x``.
    """

    status: Status
    backend: str
    raw_status: str
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    objective: float = float("nan")
    iterations: int = 0
    solve_time: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """The backend reports an optimal solution."""
        return self.status in SOLUTION_PRESENT and self.x is not None

    def usable(self, accept_inaccurate: bool = False) -> bool:
        """Whether ``x`` may be used, optionally accepting an inaccurate optimum."""
        if self.ok:
            return True
        return accept_inaccurate and self.status in SOLUTION_INACCURATE and self.x is not None

    def residuals(self, problem: QPProblem) -> dict[str, float]:
        """Independent checks of this solution against ``problem``.

        Returns the largest constraint violation (``primal``) and the objective recomputed from ``x``
        (``objective``). Raises :class:`ProblemError` if there is no primal vector.
        """
        if self.x is None:
            raise ProblemError(f"{self.backend} returned no primal vector (status {self.raw_status}).")
        viol = problem.violation(self.x)
        return {
            "primal": float(viol.max(initial=0.0)),
            "objective": problem.objective(self.x),
        }
