"""Limits on the norm of the velocity or the acceleration at every time step."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.constraints.blocks import DEFAULT_SIDES, Block, disc_block
from pmht_opt.constraints.params import check_sides
from pmht_opt.exceptions import ConfigError
from pmht_opt.model import AX, AY, VX, VY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


class _NormLimit(Constraint):
    """``||(x_t[a], x_t[b])|| <= limit`` for ``t = 1..T``: a cone per step (inner polygons on a backend
    without cones)."""

    needs = frozenset({"soc"})
    comps: ClassVar[tuple[int, int]] = (VX, VY)
    quantity: ClassVar[str] = ""

    def __init__(self, limit: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        cls = type(self).__name__
        try:
            arr = np.atleast_1d(np.asarray(limit, dtype=float))
        except (TypeError, ValueError):
            raise ConfigError(
                f"{cls}: expected a positive number or one per platform, got {limit!r}."
            ) from None
        if arr.ndim != 1 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise ConfigError(f"{cls}: expected a positive number or one per platform, got {limit!r}.")
        self.limit = arr
        self.sides = check_sides(cls, sides)

    @property
    def name(self) -> str:
        lim = f"{self.limit[0]:g}" if self.limit.size == 1 else str(self.limit.tolist())
        return f"{type(self).__name__}({lim})"

    def limit_for(self, platform: int) -> float:
        """The limit of ``platform``."""
        return float(self.limit[0] if self.limit.size == 1 else self.limit[platform])

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        if self.limit.size not in (1, scenario.n_platforms):
            raise ConfigError(
                f"{self.name}: {self.limit.size} limits given for {scenario.n_platforms} platforms."
            )

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        T = ctx.scenario.horizon
        times = np.arange(1, T + 1)
        return [
            disc_block(m, T, times, self.comps, np.zeros(2), np.full(T, self.limit_for(m)), self.sides)
            for m in self.applies_to(ctx.scenario)
        ]


class SpeedLimit(_NormLimit):
    """Speed ``||(vx, vy)|| <= vmax`` at every step ``t = 1..T``.

    Parameters
    ----------
    vmax
        Limit (distance per unit time), one for all platforms or one per platform.
    sides
        Sides of the inner regular polygon used on backends without cones (OSQP): it meets the limit
        with a margin of at most ``vmax (1 - cos(pi / sides))`` (2% at 16 sides).
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    comps = (VX, VY)

    def __init__(self, vmax: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(vmax, sides, **kwargs)


class AccelLimit(_NormLimit):
    """Acceleration ``||(ax, ay)|| <= amax`` at every step ``t = 1..T``.

    Parameters
    ----------
    amax
        Limit, one for all platforms or one per platform.
    sides
        Sides of the inner polygon on OSQP (see :class:`SpeedLimit`).
    soft, weight, platforms
        See :class:`~pmht_opt.constraints.base.Constraint`.
    """

    comps = (AX, AY)

    def __init__(self, amax: Any, sides: int = DEFAULT_SIDES, **kwargs: Any) -> None:
        super().__init__(amax, sides, **kwargs)
