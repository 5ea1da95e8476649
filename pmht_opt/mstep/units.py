"""A platform's constraint rows as condensing reads them (:mod:`pmht_opt.mstep.condensed`): units, and
the rows split into their part on the stacked states and their part on the slacks.

A *unit* is what holds or fails as one: a linear row (an equality or an inequality), or a whole
second-order cone. Its *margin* is how far inside its cone the rows' slacks ``s = b - A x`` are:
``s`` for an inequality, ``s_0 - ||s_1..||`` for a cone, ``-|s|`` for an equality; negative when
it is violated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.model import STATE_DIM
from pmht_opt.mstep.formulation import BLOCK, QPLayout
from pmht_opt.mstep.rows import ExtraRows, merge_cones


@dataclass
class Units:
    """The units of a set of rows (a linear row, or a whole cone), in row order."""

    start: np.ndarray  # first row of each unit
    size: np.ndarray  # rows per unit
    kind: np.ndarray  # 0 zero, 1 nonneg, 2 soc
    of_row: np.ndarray  # unit of each row

    @classmethod
    def of(cls, cones: list[solvers.Cone]) -> Units:
        starts, sizes, kinds = [], [], []
        row = 0
        for cone in cones:
            if cone.kind == "soc":
                starts.append(np.array([row]))
                sizes.append(np.array([cone.dim]))
                kinds.append(np.array([2]))
            else:
                starts.append(row + np.arange(cone.dim))
                sizes.append(np.ones(cone.dim, dtype=int))
                kinds.append(np.full(cone.dim, 0 if cone.kind == "zero" else 1))
            row += cone.dim
        start = np.concatenate(starts) if starts else np.zeros(0, dtype=int)
        size = np.concatenate(sizes) if sizes else np.zeros(0, dtype=int)
        return cls(
            start=start,
            size=size,
            kind=np.concatenate(kinds) if kinds else np.zeros(0, dtype=int),
            of_row=np.repeat(np.arange(start.size), size),
        )

    def margin(self, s: np.ndarray) -> np.ndarray:
        """Per unit, how far the slacks ``s`` of the rows are inside their cone (negative: outside)."""
        if self.start.size == 0:
            return np.zeros(0)
        first = s[self.start]
        rest = s * s
        rest[self.start] = 0.0
        norm = np.sqrt(np.add.reduceat(rest, self.start))
        return np.where(self.kind == 2, first - norm, np.where(self.kind == 0, -np.abs(first), first))

    def rows(self, units: np.ndarray) -> np.ndarray:
        """The rows of ``units`` (sorted unit indices), in order."""
        size = self.size[units]
        offsets = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
        return np.repeat(self.start[units], size) + offsets

    def cones(self, units: np.ndarray) -> list[solvers.Cone]:
        """The cones of ``units`` (sorted), neighbouring linear ones merged."""
        linear = (solvers.Zero(1), solvers.Nonneg(1))
        kinds, dims = self.kind[units].tolist(), self.size[units].tolist()
        cones = [solvers.SOC(d) if k == 2 else linear[k] for k, d in zip(kinds, dims, strict=True)]
        return merge_cones(cones)


class CondensedRows:
    """One platform's assembled rows (:func:`~pmht_opt.mstep.rows.assemble`) split for condensing:
    ``C`` on the stacked states (the model's units), ``E`` on the slacks, ``b``, the units, and each
    slack's own ``s >= 0`` unit."""

    def __init__(self, extra: ExtraRows, layout: QPLayout) -> None:
        n = layout.n
        # Every row measured relative to its constraint (an inner polygon's by the radius of its
        # cone), as the tolerances of the small QP and of the working set's checks are.
        per_row = extra.row_size if extra.row_size.size == extra.A.shape[0] else np.ones(extra.A.shape[0])
        A = (sp.diags(1.0 / per_row) @ extra.A).tocsr()
        coo = A[:, :n].tocoo()
        step, comp = np.divmod(coo.col, BLOCK)
        if np.any(comp >= STATE_DIM):  # pragma: no cover - rows are written on the states only
            raise ValueError("constraint rows on the process noise cannot be condensed")
        self.C = sp.csr_matrix(
            (coo.data / layout.units[comp], (coo.row, STATE_DIM * step + comp)),
            shape=(A.shape[0], STATE_DIM * layout.T),
        )
        self.E = A[:, n:].tocsr()
        # Stored zeros (a sparsity pattern kept for the full QP's sessions) carry no number here.
        self.C.eliminate_zeros()
        self.E.eliminate_zeros()
        self.b = extra.b / per_row
        self.units = Units.of(extra.cones)
        self.has_state = np.diff(self.C.indptr) > 0
        # Units whose rows touch only slacks (``s >= 0``), by their slack column.
        #: Per unit, whether any of its rows is on the states (not only on slacks).
        self.on_state = on_state = np.zeros(self.units.start.size, dtype=bool)
        on_state[self.units.of_row[self.has_state]] = True
        self.slack_unit = np.full(extra.n_slack, -1)
        own = np.flatnonzero(~on_state[self.units.of_row])
        own = own[np.diff(self.E.indptr)[own] == 1]
        self.slack_unit[self.E.indices[self.E.indptr[own]]] = self.units.of_row[own]
        self.always = np.flatnonzero(self.units.kind == 0)
        self.group = groups(self.C, self.units)
        #: Per unit, the largest ``|b|`` of its rows: the size of the numbers whose difference is its
        #: slack, which bounds the slack's rounding.
        self.size = np.maximum.reduceat(np.abs(self.b), self.units.start) if self.b.size else np.zeros(0)


def groups(C: sp.csr_matrix, units: Units) -> np.ndarray:
    """Per unit, a group number shared by the inequality units whose rows have the same columns (the
    sides of one polygon, the two bounds of one coordinate at one step); every equality, every cone
    and every empty row is a group of its own.

    A polygon that stands for a cone (OSQP takes no cones) has many sides on the same few columns; a
    point outside it violates up to half of them, but one, the most violated, is usually enough to
    pull the answer back, and the others only make ADMM slower (nearly parallel rows). So a working
    set takes the most violated unit of each group at a time (:func:`most_violated`).
    """
    n = units.start.size
    out = np.full(n, -1, dtype=np.intp)
    lengths = np.diff(C.indptr)[units.start] if n else np.zeros(0, dtype=int)
    linear = units.kind == 1
    used = 0
    for length in np.unique(lengths[linear & (lengths > 0)]):
        sel = np.flatnonzero(linear & (lengths == length))
        cols = np.sort(C.indices[C.indptr[units.start[sel]][:, None] + np.arange(length)], axis=1)
        _, inverse = np.unique(cols, axis=0, return_inverse=True)
        out[sel] = used + inverse.ravel()
        used += int(inverse.max()) + 1
    own = np.flatnonzero(out < 0)
    out[own] = used + np.arange(own.size)
    return out


def most_violated(units: np.ndarray, margin: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Of ``units``, the most violated (least margin) of each group, sorted."""
    if units.size == 0:
        return units
    order = units[np.lexsort((margin[units], group[units]))]
    first = np.ones(order.size, dtype=bool)
    first[1:] = group[order[1:]] != group[order[:-1]]
    return np.sort(order[first])
