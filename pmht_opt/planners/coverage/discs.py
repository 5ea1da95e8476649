r"""Every locale's disc met by its route's platform, on a segment of its path near where the tour meets it.

Coverage is measured on the segments between consecutive positions (a platform flies straight between
them), so the constraint is written on a segment too: for locale :math:`n` on platform :math:`m`, a
step :math:`t_n` and a fraction :math:`\alpha_n \in [0, 1]`,

.. math::

    \lVert (1 - \alpha_n)\, p^m_{t_n} + \alpha_n\, p^m_{t_n + 1} - z_n \rVert \le \rho_n,

one second-order cone on two positions: the point of the segment at :math:`\alpha_n` within the disc.
Written on a sample alone (:math:`\alpha_n = 0`), a disc the tour only touches would have to hold a
sample exactly at the touch point, which the motion reaches between two steps: the smoother would have
to bend the path there, against a speed limit at its cruise speed.

:math:`(t_n, \alpha_n)` is re-chosen at every iteration: the point of the current path, within
``window`` steps of where the motion first reaches the locale's visit point, nearest the locale. A path
that met the discs at the last iteration's points meets them at these too (the nearest point is no
further), so once one iteration is feasible every later one is.
"""

from __future__ import annotations

import bisect

import numpy as np
import scipy.sparse as sp

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block
from pmht_opt.model import POS, PX, PY, STATE_DIM
from pmht_opt.scenario import describe_radius

#: Two points of a path closer than this (in steps) are the same point.
SAME_PLACE = 1e-12


class VisitDiscs(Constraint):
    """Locale ``n`` within ``radii[n]`` of platform ``platform[n]``'s path, on the segment after step
    ``t`` at fraction ``alpha`` (module notes), near step ``times[n]``."""

    needs = frozenset({"soc"})
    dynamic = True

    def __init__(
        self,
        platform: np.ndarray,
        times: np.ndarray,
        centres: np.ndarray,
        radii: np.ndarray,
        window: int = 0,
    ) -> None:
        super().__init__()
        self.platform = np.asarray(platform, dtype=int)
        self.times = np.asarray(times, dtype=int)
        self.centres = np.asarray(centres, dtype=float)
        self.radii = np.broadcast_to(np.asarray(radii, dtype=float), self.platform.shape)
        self.window = int(window)

    @property
    def name(self) -> str:
        return f"VisitDiscs({describe_radius(self.radii)})"

    def scale(self, scenario: object) -> float:
        """The smallest radius: violations are judged relative to it."""
        return float(np.min(self.radii)) if self.radii.size else 1.0

    def tightened(self, fraction: float) -> VisitDiscs:
        """The same discs, each imposed ``fraction`` of its radius inside it."""
        out = VisitDiscs(self.platform, self.times, self.centres, self.radii * (1.0 - fraction), self.window)
        out.soft = self.soft
        return out

    def visit_points(self, positions: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
        """``(steps (N,), alpha (N,))``: for each locale, the point of ``positions (M, T+1, 2)``
        within the window of its nominal step nearest to it, as the segment after a step
        (``1..T``; the last step's segment is the point itself) and a fraction of it."""
        N = self.platform.shape[0]
        window = self.window
        steps = np.empty(N, dtype=int)
        alpha = np.zeros(N)
        for n in range(N):
            m, t0 = int(self.platform[n]), int(self.times[n])
            lo, hi = max(1, t0 - window), min(T, t0 + window)
            a = positions[m, lo : hi + 1]  # segment starts, steps lo..hi
            b = positions[m, np.minimum(np.arange(lo, hi + 1) + 1, T)]
            d = b - a
            len2 = np.einsum("ij,ij->i", d, d)
            along = np.einsum("ij,ij->i", self.centres[n] - a, d) / np.maximum(len2, 1e-300)
            u = np.clip(np.where(len2 > 0, along, 0.0), 0.0, 1.0)
            gap = np.hypot(*(a + u[:, None] * d - self.centres[n]).T)
            j = int(np.argmin(gap))
            steps[n], alpha[n] = lo + j, u[j] if lo + j < T else 0.0
        return self._apart(steps, alpha, T)

    def _apart(self, steps: np.ndarray, alpha: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
        """The chosen points moved apart where two discs that share no point got the same point of a
        path (both nearest to one sample: ``alpha`` clipped to 1 on one segment, to 0 on the next, or
        equal): no point lies in both, so that choice alone would make the M-step infeasible. The later
        disc in route order takes the middle of the next half segment instead."""
        at = np.minimum(steps + alpha, T)  # the point's place along the path: t + alpha
        for m in np.unique(self.platform):
            mine = np.flatnonzero(self.platform == m)
            if np.all(np.diff(np.sort(at[mine])) > SAME_PLACE):
                continue  # no two of the platform's points coincide: nothing to move
            mine = mine[np.lexsort((at[mine], self.times[mine]))]  # route order
            placed: list[tuple[float, int, int]] = []  # (place, rank in route order, disc), sorted
            for rank, n in enumerate(mine):
                lo = bisect.bisect_left(placed, (at[n] - SAME_PLACE, -1, -1))
                hi = bisect.bisect_right(placed, (at[n] + SAME_PLACE, len(mine), len(mine)))
                for _, _, k in sorted(placed[lo:hi], key=lambda p: p[1]):  # earlier discs in route order
                    if np.hypot(*(self.centres[n] - self.centres[k])) > self.radii[n] + self.radii[k]:
                        at[n] = at[k] + 0.5 if at[k] + 0.5 <= T else at[k] - 0.5
                        break
                bisect.insort(placed, (float(at[n]), rank, int(n)))
        steps = np.clip(np.floor(at).astype(int), 1, T)
        return steps, np.where(steps < T, at - steps, 0.0)

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        T = ctx.scenario.horizon
        steps, alpha = self.visit_points(ctx.states[:, :, POS], T)
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(self.platform == m)
            if mine.size == 0:
                continue
            blk = _segment_discs(m, T, steps[mine], alpha[mine], self.centres[mine], self.radii[mine])
            blk.labels = [f"locale {n}" for n in mine.tolist()]
            nominal = self.times[mine]
            blk.span = np.column_stack(
                [np.maximum(nominal - self.window, 1), np.minimum(nominal + self.window + 1, T)]
            )
            out.append(blk)
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        T = ctx.scenario.horizon
        pos = states[:, :, POS]
        steps, alpha = self.visit_points(pos, T)
        after = np.minimum(steps + 1, T)
        at = (1 - alpha)[:, None] * pos[self.platform, steps] + alpha[:, None] * pos[self.platform, after]
        dist = np.hypot(*(at - self.centres).T)
        report.details["visits_met"] = int(np.sum(dist <= self.radii * (1.0 + 1e-6)))
        return report


def _segment_discs(
    platform: int, T: int, steps: np.ndarray, alpha: np.ndarray, centres: np.ndarray, radii: np.ndarray
) -> Block:
    """``||(1 - a) p_t + a p_{t+1} - c|| <= r`` per unit (module notes): rows ``(r, c - point)``."""
    k = steps.shape[0]
    rows, cols, vals = [], [], []
    for axis, comp in enumerate((PX, PY)):
        row = 3 * np.arange(k) + 1 + axis
        rows += [row, row]
        cols += [STATE_DIM * (steps - 1) + comp, STATE_DIM * (np.minimum(steps + 1, T) - 1) + comp]
        vals += [1.0 - alpha, alpha]
    G = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * k, STATE_DIM * T)
    )
    G.sum_duplicates()
    h = np.column_stack([radii, centres]).ravel()
    return Block(platform, "soc", G, h, dim=3, times=steps)
