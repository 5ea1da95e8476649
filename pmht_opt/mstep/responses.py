"""The exact smoother's responses to the rows of a condensed M-step (:mod:`pmht_opt.mstep.condensed`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from pmht_opt.model import STATE_DIM
from solvers.banded import BandedFactor


class Responses:
    """The responses ``H^-1 c`` of rows ``c`` of ``C`` to the factorised ``H``, solved as rows join the
    working set, and the path's response to ``C_S' w``.

    ``H`` is the same for both axes and does not couple them, so a row's response is that of its x
    part on the x axis plus that of its y part on the y axis, and parts that are multiples of one
    pattern (a visit's x and y rows, a speed cone's two components, the two walls of a bound) share
    one solve of the one-axis system.
    """

    def __init__(self, C: sp.csr_matrix, factor: BandedFactor, T: int) -> None:
        self.C, self.factor, self.T = C, factor, T
        #: Per-axis responses ``(3 T, columns)``, and the column of each pattern.
        self.R = np.zeros((3 * T, 0))
        self._pattern: dict[bytes, int] = {}
        #: Per row: ``(axis, column, scale)`` of each part.
        self._parts: dict[int, list[tuple[int, int, float]]] = {}

    def _add(self, new: list[int]) -> None:
        """Solve for the patterns of rows ``new`` not seen yet (without iterative refinement: the
        responses only form the small QP's matrix ``Sigma``, whose rounding moves the optimum ``w``
        by as little; the path itself is solved refined, :meth:`apply`)."""
        parts: dict[int, list[tuple[int, int, float]]] = {i: [] for i in new}
        sub = self.C[new]
        if sub.nnz == 0:  # nothing new, or rows without entries: no response to solve
            self._parts.update(parts)
            return
        # Every row's parts: its entries on one axis, in the matrix's order, as (row, axis) segments.
        cols, vals = sub.indices, sub.data
        segment = np.repeat(2 * np.arange(len(new)), np.diff(sub.indptr)) + (cols % STATE_DIM) // 3
        order = np.argsort(segment, kind="stable")
        cols, vals, segment = cols[order], vals[order], segment[order]
        starts = np.flatnonzero(np.concatenate(([True], segment[1:] != segment[:-1])))
        ends = np.append(starts[1:], segment.size)
        scale = vals[starts]
        idx = 3 * (cols // STATE_DIM) + cols % 3  # in the one-axis stacked states
        shape = vals / np.repeat(scale, ends - starts)
        forces: list[tuple[np.ndarray, np.ndarray]] = []
        spans = zip(starts.tolist(), ends.tolist(), segment[starts].tolist(), scale.tolist(), strict=True)
        for a, b, seg, sc in spans:
            key = idx[a:b].tobytes() + shape[a:b].tobytes()
            column = self._pattern.get(key)
            if column is None:
                column = self._pattern[key] = self.R.shape[1] + len(forces)
                forces.append((idx[a:b], shape[a:b]))
            parts[new[seg // 2]].append((seg % 2, column, sc))
        self._parts.update(parts)
        if forces:
            force = np.zeros((3 * self.T, len(forces)))
            rows = np.concatenate([f[0] for f in forces])
            which = np.repeat(np.arange(len(forces)), [f[0].size for f in forces])
            force[rows, which] = np.concatenate([f[1] for f in forces])
            st, _ = self.factor.solve(force.reshape(1, self.T, 3, len(forces)), refine=0)
            self.R = np.concatenate([self.R, st[0].reshape(3 * self.T, len(forces))], axis=1)

    def sigma(self, state_rows: np.ndarray) -> np.ndarray:
        """``Sigma = C_S H^-1 C_S'`` of ``state_rows``, symmetrised."""
        rows = state_rows.tolist()
        self._add([i for i in rows if i not in self._parts])
        k = len(rows)
        resp = np.zeros((2, 3 * self.T, k))
        parts = [(axis, j, col, scale) for j, i in enumerate(rows) for axis, col, scale in self._parts[i]]
        if parts:
            axes, js, columns, scales = (np.array(v) for v in zip(*parts, strict=True))
            resp[axes, :, js] = (self.R[:, columns] * scales).T
        sub = self.C[state_rows].tocoo()
        axis = (sub.col % STATE_DIM) // 3
        idx = 3 * (sub.col // STATE_DIM) + sub.col % 3
        sigma = np.zeros((k, k))
        for a in (0, 1):
            on = axis == a
            part = sp.csr_matrix((sub.data[on], (sub.row[on], idx[on])), shape=(k, 3 * self.T))
            sigma += part @ resp[a]
        return 0.5 * (sigma + sigma.T)

    def apply(self, state_rows: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states and whitened noise, both ``(6 T,)``, of ``H^-1 C_S' w``: one refined solve."""
        if state_rows.size == 0:
            zero = np.zeros(STATE_DIM * self.T)
            return zero, zero.copy()
        push = (self.C[state_rows].T @ w).reshape(self.T, 2, 3)
        st, nz = self.factor.solve(np.moveaxis(push, 1, -1)[None])
        return _stack(st[0]).ravel(), _stack(nz[0]).ravel()


def _stack(per_axis: np.ndarray) -> np.ndarray:
    """``(T, 3, 2)`` per-axis states as ``(T, 6)`` ``[px, vx, ax, py, vy, ay]``."""
    return np.concatenate([per_axis[..., 0], per_axis[..., 1]], axis=1)
