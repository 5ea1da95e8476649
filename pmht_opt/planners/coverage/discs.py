"""Every locale's disc met by its route's platform at one step near where the tour meets it."""

from __future__ import annotations

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext, ConstraintReport
from pmht_opt.constraints.blocks import Block, disc_block
from pmht_opt.constraints.visits import can_share_step
from pmht_opt.model import POS, PX, PY
from pmht_opt.scenario import describe_radius


class VisitDiscs(Constraint):
    """Locale ``n`` within ``radii[n]`` of platform ``platform[n]`` at one step near ``times[n]``.

    Unlike :class:`~pmht_opt.constraints.VisitAll`, the platform is given: the tour's. The step is
    re-chosen at every iteration: the step within ``window`` of ``times[n]`` at which the current path
    is closest to the locale. A path that met the discs at the last iteration's steps meets them at
    these too, so once one iteration is feasible every later one is. A path that does not meet them
    yet can be closest to two discs that no point meets at one step; that platform then keeps the
    given ``times`` for the iteration.
    """

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

    def visit_steps(self, ctx: ConstraintContext) -> np.ndarray:
        """``(N,)`` the step of each locale's disc in the M-step of ``ctx``."""
        T = ctx.scenario.horizon
        if self.window == 0:
            return self.times
        pos = ctx.states[:, :, POS]
        out = self.times.copy()
        for n, (m, t) in enumerate(zip(self.platform, self.times, strict=True)):
            lo, hi = max(1, t - self.window), min(T, t + self.window)
            out[n] = lo + int(np.argmin(np.hypot(*(pos[m, lo : hi + 1] - self.centres[n]).T)))
        for m in np.unique(self.platform):
            mine = np.flatnonzero(self.platform == m)
            if _clash(out[mine], self.centres[mine], self.radii[mine]):
                out[mine] = self.times[mine]
        return out

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        times, T = self.visit_steps(ctx), ctx.scenario.horizon
        out = []
        for m in range(ctx.scenario.n_platforms):
            mine = np.flatnonzero(self.platform == m)
            if mine.size:
                blk = disc_block(
                    m,
                    T,
                    times[mine],
                    (PX, PY),
                    self.centres[mine],
                    self.radii[mine],
                    labels=[f"locale {n}" for n in mine.tolist()],
                )
                nominal = self.times[mine]
                blk.span = np.column_stack(
                    [np.maximum(nominal - self.window, 1), np.minimum(nominal + self.window, T)]
                )
                out.append(blk)
        return out

    def violation(self, states: np.ndarray, ctx: ConstraintContext) -> ConstraintReport:
        report = super().violation(states, ctx)
        times = self.visit_steps(ctx)
        dist = np.hypot(*(states[self.platform, times][:, POS] - self.centres).T)
        report.details["visits_met"] = int(np.sum(dist <= self.radii * (1.0 + 1e-6)))
        return report


def _clash(steps: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> bool:
    """Whether two of one platform's discs share a step although no point meets both
    (:func:`~pmht_opt.constraints.visits.can_share_step`)."""
    same = steps[:, None] == steps[None, :]
    apart = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
    return bool(np.any(same & ~can_share_step(apart, radii[:, None] + radii[None, :])))
