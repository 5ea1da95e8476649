"""Turning constraint blocks into rows of a QP in the :mod:`solvers` form ``A x + s = b, s in K``.

The M-step QP of a platform has its own variable vector (states and noise interleaved); a block's rows
are written on the stacked states, so their columns are remapped through ``col_map``. Soft blocks get
slack columns appended after the QP's own variables, with a linear cost ``weight`` each (the exact L1
penalty of :mod:`pmht_opt.constraints.base`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.constraints.base import Block, Constraint


@dataclass
class Imposed:
    """A block, the name of the constraint that wrote it, and how it is imposed."""

    block: Block
    name: str
    soft: bool = False
    weight: float = 0.0
    dynamic: bool = True

    @classmethod
    def of(cls, block: Block, constraint: Constraint) -> Imposed:
        """The block as ``constraint`` asks for it (hard or soft)."""
        return cls(block, constraint.name, constraint.soft, constraint.weight, type(constraint).dynamic)

    def relaxed(self, weight: float) -> Imposed:
        """The same block imposed softly with ``weight`` (for infeasibility diagnoses)."""
        return Imposed(self.block, self.name, True, weight, self.dynamic)


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

    def pattern_key(self) -> tuple[object, ...]:
        """Everything that fixes the structure (not the numbers) of these rows."""
        return (
            self.A.shape,
            self.A.indptr.tobytes(),
            self.A.indices.tobytes(),
            tuple((c.kind, c.dim) for c in self.cones),
        )


def assemble(imposed: list[Imposed], n_vars: int, col_map: np.ndarray) -> ExtraRows:
    """Rows for ``imposed`` blocks on a QP with ``n_vars`` variables; ``col_map[j]`` is the QP column of
    stacked-state entry ``j``."""
    n_slack = sum(i.block.units for i in imposed if i.soft)
    width = n_vars + n_slack
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    b_parts: list[np.ndarray] = []
    cones: list[solvers.Cone] = []
    slack_cost = np.zeros(n_slack)
    owners: list[SlackOwner] = []
    row0 = 0
    slack0 = n_vars

    def add(G: sp.coo_matrix, sign: float, h: np.ndarray) -> None:
        nonlocal row0
        rows.append(G.row + row0)
        cols.append(col_map[G.col])
        vals.append(sign * G.data)
        b_parts.append(sign * h)
        row0 += G.shape[0]

    def add_slack(row_idx: np.ndarray, slack_idx: np.ndarray) -> None:
        rows.append(row_idx)
        cols.append(slack_idx)
        vals.append(-np.ones(row_idx.size))

    for item in imposed:
        blk = item.block
        G = blk.G.tocoo()
        k = G.shape[0]
        if not item.soft:
            add(G, 1.0, blk.h)
            cones.extend(_hard_cones(blk.kind, k, blk.dim))
            continue
        units = blk.units
        sl = slack0 + np.arange(units)
        slack_cost[sl - n_vars] = item.weight
        for u in range(units):
            owners.append(
                SlackOwner(
                    item.name, blk.platform, int(blk.times[u]), None if blk.labels is None else blk.labels[u]
                )
            )
        slack0 += units
        if blk.kind == "nonneg":  # h - G z + s >= 0
            start = row0
            add(G, 1.0, blk.h)
            add_slack(start + np.arange(k), sl)
            cones.append(solvers.Nonneg(k))
        elif blk.kind == "zero":  # |h - G z| <= s, as two non-negative rows
            start = row0
            add(G, 1.0, blk.h)
            add(G, -1.0, blk.h)
            add_slack(start + np.arange(k), sl)
            add_slack(start + k + np.arange(k), sl)
            cones.append(solvers.Nonneg(2 * k))
        else:  # (h - G z)[0] + s >= ||(h - G z)[1:]||, and s >= 0
            start = row0
            add(G, 1.0, blk.h)
            add_slack(start + blk.dim * np.arange(units), sl)
            cones.extend(solvers.SOC(blk.dim) for _ in range(units))
            rows.append(row0 + np.arange(units))
            cols.append(sl)
            vals.append(-np.ones(units))
            b_parts.append(np.zeros(units))
            row0 += units
            cones.append(solvers.Nonneg(units))
    if rows:
        A = sp.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row0, width)
        )
        b = np.concatenate(b_parts)
    else:
        A = sp.csc_matrix((0, width))
        b = np.zeros(0)
    A.sort_indices()
    return ExtraRows(
        A=A, b=b, cones=_merge(cones), n_slack=n_slack, slack_cost=slack_cost, slack_owner=owners
    )


def _hard_cones(kind: str, rows: int, dim: int) -> list[solvers.Cone]:
    if kind == "zero":
        return [solvers.Zero(rows)]
    if kind == "nonneg":
        return [solvers.Nonneg(rows)]
    return [solvers.SOC(dim) for _ in range(rows // dim)]


def _merge(cones: list[solvers.Cone]) -> list[solvers.Cone]:
    """Merge neighbouring linear cones of one kind (fewer, larger cones for the backends)."""
    out: list[solvers.Cone] = []
    for c in cones:
        if out and c.kind == out[-1].kind and c.kind in ("zero", "nonneg"):
            out[-1] = (
                solvers.Zero(out[-1].dim + c.dim) if c.kind == "zero" else solvers.Nonneg(out[-1].dim + c.dim)
            )
        else:
            out.append(c)
    return out
