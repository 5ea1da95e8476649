"""Constraint rows for the M-step: which blocks are imposed, in which form, and the one soft rule.

:class:`RowBuilder` turns the constraints active in an iteration into per-platform lists of
:class:`Imposed` blocks, in the form the backend can take (second-order cones, or their inner
polygons for a backend with linear rows only), with a key that changes exactly when the rows can
have changed: the rows of a static constraint are written once per run. :func:`assemble` turns a
platform's blocks into rows of a :mod:`solvers` problem ``A x + s = b, s in K`` on that QP's own
variable vector.

Soft blocks (:func:`assemble`) follow one rule, an exact L1 penalty: each unit (a linear row, a whole
cone, or the rows of a polygon standing for one cone) gets one slack ``s >= 0`` that relaxes it, and
``weight * s`` joins the cost. A relaxed inequality reads ``h - G z + s >= 0``, a relaxed equality
``|h - G z| <= s`` and a relaxed cone ``(h - G z)_0 + s >= ||(h - G z)_1..||``. Native cvxpy constraints
follow the same rule (:func:`soften_cvxpy`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.constraints.blocks import Block, inner_polygon, with_span_pattern
from pmht_opt.model import STATE_DIM

#: Relative tightening of hard rows in the M-step QP (see :func:`_backed_off`).
BACKOFF = 1e-5


@dataclass
class Imposed:
    """A block, the name of the constraint that wrote it, and how it is imposed."""

    block: Block
    name: str
    soft: bool = False
    weight: float = 0.0
    #: Whether the constraint's rows are the constraint itself (:attr:`Constraint.exact`).
    exact: bool = False
    #: The block in its conic form, before any inner polygon stood in for its cones: what a proof of
    #: infeasibility is solved on, whatever the backend takes.
    cone: Block | None = None

    def relaxed(self, weight: float) -> Imposed:
        """The same block imposed softly with ``weight`` (for infeasibility diagnoses)."""
        return Imposed(self.block, self.name, True, weight, self.exact, self.cone)

    def conic(self) -> Imposed:
        """The same constraint with its conic block, imposed hard."""
        return Imposed(self.cone if self.cone is not None else self.block, self.name, False, 0.0, self.exact)


@dataclass
class PlatformRows:
    """One platform's blocks for one M-step, and a key: equal keys mean identical rows."""

    items: list[Imposed]
    key: tuple[tuple[int, ...], ...]


class RowBuilder:
    """The blocks of the active constraints, per platform, in the form a backend takes.

    Parameters
    ----------
    constraints
        Every constraint of the run.
    conic
        Whether the backend takes second-order cones; if not, cones become inner polygons.
    """

    def __init__(self, constraints: Sequence[Constraint], conic: bool) -> None:
        self.constraints = tuple(constraints)
        self.conic = conic
        self._static: dict[int, list[Imposed]] = {}

    def _impose(self, con: Constraint, ctx: ConstraintContext) -> list[Imposed]:
        out = []
        for cone in con.blocks(ctx):
            blk = inner_polygon(cone) if cone.kind == "soc" and not self.conic else cone
            out.append(Imposed(blk, con.name, con.soft, con.weight, con.exact, cone))
        return out

    def rows(
        self, ctx: ConstraintContext | None, active: Sequence[int], strengths: Sequence[float] = ()
    ) -> dict[int, PlatformRows]:
        """The rows of the constraints ``active`` (indices) for the iterate in ``ctx``, per platform.

        A static constraint's rows are written at its first use and reused; a dynamic one's are
        written afresh for every iteration, and its key part names the iteration.
        """
        out: dict[int, PlatformRows] = {}
        if ctx is None or not active:
            return out
        for j, i in enumerate(active):
            con = self.constraints[i]
            tag: tuple[int, ...]
            if con.dynamic:
                strength = strengths[j] if strengths else 1.0
                items, tag = self._impose(con, replace(ctx, strength=strength)), (i, ctx.iteration)
            else:
                if i not in self._static:
                    self._static[i] = self._impose(con, ctx)
                items, tag = self._static[i], (i,)
            for item in items:
                rows = out.setdefault(item.block.platform, PlatformRows([], ()))
                rows.items.append(item)
                if not rows.key or rows.key[-1] != tag:
                    rows.key = (*rows.key, tag)
        return out


@dataclass
class SlackOwner:
    """Where one slack variable came from, for reports and infeasibility diagnoses."""

    constraint: str
    platform: int
    time: int
    label: str | None


@dataclass
class ExtraRows:
    """Rows to append below a QP's own constraints.

    ``A`` has ``n_vars + n_slack`` columns; ``cones`` covers its rows in order.
    """

    A: sp.csc_matrix
    b: np.ndarray
    cones: list[solvers.Cone]
    n_slack: int
    slack_cost: np.ndarray
    slack_owner: list[SlackOwner] = field(default_factory=list)
    #: Per row, the size of the constraint it belongs to in the rows' own units: the radius of the cone
    #: an inner polygon's row stands for, 1 for any other row. Dividing by it measures every row
    #: relative to its constraint (:class:`~pmht_opt.mstep.units.CondensedRows`).
    row_size: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def pattern_key(self) -> tuple[object, ...]:
        """Everything that fixes the structure (not the numbers) of these rows."""
        return (
            self.n_slack,
            self.A.shape,
            self.A.indptr.tobytes(),
            self.A.indices.tobytes(),
            tuple((c.kind, c.dim) for c in self.cones),
        )


class _Rows:
    """Triplets of the rows being assembled."""

    def __init__(self, col_map: np.ndarray) -> None:
        self.col_map = col_map
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self.cones: list[solvers.Cone] = []
        self.count = 0
        #: Per row, the size its rows are measured in (a polygon's radius; 1 otherwise).
        self.sizes: list[np.ndarray] = []

    def block(self, G: sp.coo_matrix, sign: float, h: np.ndarray, size: np.ndarray | None = None) -> int:
        """Rows ``sign * (h - G z)`` of sizes ``size`` (default 1); returns the first row's index."""
        start = self.count
        self.sizes.append(np.ones(G.shape[0]) if size is None else np.where(size > 0, size, 1.0))
        self.rows.append(G.row + start)
        self.cols.append(self.col_map[G.col])
        self.vals.append(sign * G.data)
        self.b.append(sign * h)
        self.count += G.shape[0]
        return start

    def slack(self, rows: np.ndarray, slacks: np.ndarray, scale: np.ndarray | float = 1.0) -> None:
        """Add slack column ``slacks[i]`` with coefficient ``scale[i]`` to ``b - A x`` of row ``rows[i]``."""
        self.rows.append(rows)
        self.cols.append(slacks)
        self.vals.append(-np.broadcast_to(scale, rows.shape).astype(float))

    def nonneg_slacks(self, slacks: np.ndarray) -> None:
        """Rows ``s >= 0`` for the given slack columns."""
        start = self.count
        self.slack(start + np.arange(slacks.size), slacks)
        self.b.append(np.zeros(slacks.size))
        self.sizes.append(np.ones(slacks.size))
        self.count += slacks.size
        self.cones.append(solvers.Nonneg(slacks.size))


def assemble(
    imposed: Sequence[Imposed],
    n_vars: int,
    col_map: np.ndarray,
    origin: np.ndarray | None = None,
    units: np.ndarray | None = None,
    margin: float = 0.0,
) -> ExtraRows:
    """Rows for ``imposed`` blocks on a QP with ``n_vars`` variables; ``col_map[j]`` is the QP column of
    stacked-state entry ``j``. Soft blocks get slack columns after the QP's own (module docstring).

    ``origin`` (stacked states, or ``None`` for zero) is the point the QP's variables are measured
    from: a block ``h - G z`` on the states ``z = origin + z'`` is written ``(h - G origin) - G z'``.
    ``units`` (``(6,)``, or ``None`` for ones) is the size of one unit of the QP's variable per state
    component (:func:`~pmht_opt.mstep.formulation.state_units`): ``G``'s columns are multiplied by it.
    ``margin`` is the least absolute back-off of a hard cone (:func:`_backed_off`).
    """
    n_slack = sum(i.block.units // i.block.group for i in imposed if i.soft)
    out = _Rows(col_map)
    slack_cost = np.zeros(n_slack)
    owners: list[SlackOwner] = []
    slack0 = n_vars
    for item in imposed:
        blk = item.block
        G, h, unit_scale = _normalised(blk, origin, units)
        k = G.shape[0]
        size = blk.radius  # an inner polygon's rows: the size of the cone they stand for
        if not item.soft:
            least = margin * unit_scale if size is None else margin / np.where(size > 0, size, 1.0)
            out.block(G, 1.0, _backed_off(blk, h, least), size)
            out.cones.extend(_hard_cones(blk.kind, k, blk.dim))
            continue
        n = blk.units // blk.group
        sl = slack0 + np.arange(n)
        slack0 += n
        slack_cost[sl - n_vars] = item.weight
        firsts = np.arange(n) * blk.group
        owners.extend(
            SlackOwner(
                item.name, blk.platform, int(blk.times[u]), None if blk.labels is None else blk.labels[u]
            )
            for u in firsts.tolist()
        )
        start = out.block(G, 1.0, h, size)
        if blk.kind == "zero":  # |h - G z| <= s: two inequality rows, s >= 0 implied
            out.block(G, -1.0, h)
            out.slack(start + np.arange(k), np.repeat(sl, blk.group))
            out.slack(start + k + np.arange(k), np.repeat(sl, blk.group))
            out.cones.append(solvers.Nonneg(2 * k))
        elif blk.kind == "nonneg":  # h - G z + s >= 0, s >= 0
            out.slack(start + np.arange(k), np.repeat(sl, blk.group))
            out.cones.append(solvers.Nonneg(k))
            out.nonneg_slacks(sl)
        else:  # (h - G z)_0 + s >= ||(h - G z)_1..||, s >= 0 (rows scaled: so is the slack)
            out.slack(start + blk.dim * np.arange(blk.units), sl, unit_scale)
            out.cones.extend(solvers.SOC(blk.dim) for _ in range(blk.units))
            out.nonneg_slacks(sl)
    width = n_vars + n_slack
    if out.rows:
        A = sp.csc_matrix(
            (np.concatenate(out.vals), (np.concatenate(out.rows), np.concatenate(out.cols))),
            shape=(out.count, width),
        )
        b = np.concatenate(out.b)
    else:
        A = sp.csc_matrix((0, width))
        b = np.zeros(0)
    A.sort_indices()
    return ExtraRows(
        A=A,
        b=b,
        cones=merge_cones(out.cones),
        n_slack=n_slack,
        slack_cost=slack_cost,
        slack_owner=owners,
        row_size=np.concatenate(out.sizes) if out.sizes else np.zeros(0),
    )


def _normalised(
    blk: Block, origin: np.ndarray | None = None, units: np.ndarray | None = None
) -> tuple[sp.coo_matrix, np.ndarray, np.ndarray]:
    """``(G, h)`` of ``blk`` on the QP's variables (measured from ``origin``, in ``units``:
    :func:`assemble`), with each second-order cone divided by its radius ``h_0`` (when positive), and
    the factor per unit.

    A cone is unchanged by a positive factor, but a solver's feasibility tolerance is absolute on the
    rows it is given: divided by its radius, a limit of 1e-3 is met to the same relative precision as
    a limit of 1. Linear rows are left as they are (unit normals and bounds), the rows of an inner
    polygon too: divided by the radius, OSQP's whole QP under limits of 1e-3 needed several times the
    ADMM iterations and failed within its budget (B with ``SpeedLimit(1e-3)``, ``AccelLimit(1e-3)``).
    Each row's radius is kept beside it (:attr:`ExtraRows.row_size`) for the condensed QP, whose
    tolerances are relative to its rows.
    """
    G = with_span_pattern(blk).tocoo()
    h = blk.h if origin is None else blk.h - G @ origin
    if units is not None:
        G.data = G.data * units[G.col % STATE_DIM]
    if blk.kind == "soc":
        radius = h[:: blk.dim]
    else:
        return G, h, np.ones(blk.units)
    scale = np.where(radius > 0, 1.0 / np.where(radius > 0, radius, 1.0), 1.0)
    per_row = np.repeat(scale, blk.dim)
    G.data = G.data * per_row[G.row]
    return G, h * per_row, scale


def _backed_off(blk: Block, h: np.ndarray, least: np.ndarray | float = 0.0) -> np.ndarray:
    """``h`` of a hard block (normalised by :func:`_normalised`) tightened by :data:`BACKOFF`, each
    cone by at least ``least`` (per unit, relative to its radius; at most half of it).

    An interior-point solver meets its rows to a tolerance relative to the norms of the whole problem
    (thousands of variables, positions of order 10), which can leave one row 1e-7 out in absolute
    terms: a visit disc of radius 0.1 was met to 1.07e-6 of its radius with a primal residual of
    5e-11, past the verification's 1e-6. Imposing each hard cone at ``1 - BACKOFF`` of its radius and
    each inequality ``BACKOFF max(|h|, 1)`` inside its bound keeps that error on the safe side, at a
    cost far below anything a plan can show. Equalities and cones of zero radius are left as they are.

    A cone of a tiny radius (an acceleration limit of 1e-9 bounds second differences of positions of
    size 10 to 1e-9) is also tightened by an absolute margin, ``least`` times its radius: the
    positions' own rounding, which verification allows (:func:`pmht_opt.verify.resolution`), and
    a solve's error in them, are then inside the limit. With the relative back-off alone, 1e-14,
    such a plan broke its limit by 4.5e-13 against the verification's 1.1e-13.
    """
    if blk.kind == "soc":
        out = h.copy()
        radius = out[:: blk.dim]
        cut = np.minimum(np.maximum(BACKOFF, np.broadcast_to(least, radius.shape)), 0.5)
        radius[radius > 0] -= cut[radius > 0]  # normalised: the radius is 1
        return out
    if blk.radius is not None:
        # An inner polygon: the cone's radius (normalised to 1) shrunk as above, which moves each row
        # by cos(pi / S) times the cut. Backed off like other linear rows, a polygon of a limit below
        # 1e-5 would be empty.
        cut = np.minimum(np.maximum(BACKOFF, np.broadcast_to(least, h.shape)), 0.5)
        return np.where(blk.radius > 0, h - np.cos(np.pi / blk.sides) * cut * blk.radius, h)
    if blk.kind == "nonneg":
        return h - BACKOFF * np.maximum(np.abs(h), 1.0)
    return h


def _hard_cones(kind: str, rows: int, dim: int) -> list[solvers.Cone]:
    if kind == "zero":
        return [solvers.Zero(rows)]
    if kind == "nonneg":
        return [solvers.Nonneg(rows)]
    return [solvers.SOC(dim) for _ in range(rows // dim)]


def merge_cones(cones: list[solvers.Cone]) -> list[solvers.Cone]:
    """Merge neighbouring linear cones of one kind (fewer, larger cones for the backends)."""
    out: list[solvers.Cone] = []
    for c in cones:
        if out and c.kind == out[-1].kind and c.kind in ("zero", "nonneg"):
            out[-1] = solvers.Cone(c.kind, out[-1].dim + c.dim)
        else:
            out.append(c)
    return out


def soften_cvxpy(items: Sequence[Any], weight: float) -> tuple[list[Any], Any]:
    """Native cvxpy constraints relaxed by the module's rule: ``(constraints, penalty)``.

    Each entry of an inequality ``lhs <= rhs`` gets a slack ``s >= 0`` with ``lhs - rhs <= s``, each
    entry of an equality ``|lhs - rhs| <= s``; the penalty is ``weight * sum(s)``. Other constraint
    types have no unit violation to relax and raise ``TypeError``.
    """
    import cvxpy as cp

    constraints: list[Any] = []
    penalty: Any = 0
    for c in items:
        if isinstance(c, cp.constraints.Inequality):
            gap = c.args[0] - c.args[1]
            s = cp.Variable(gap.shape, nonneg=True)
            constraints.append(gap <= s)
        elif isinstance(c, cp.constraints.Equality):
            gap = c.args[0] - c.args[1]
            s = cp.Variable(gap.shape, nonneg=True)
            constraints += [gap <= s, -gap <= s]
        else:
            raise TypeError(type(c).__name__)
        penalty += weight * cp.sum(s)
    return constraints, penalty
