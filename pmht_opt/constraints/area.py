"""Keep every position inside an axis-aligned box."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.base import Constraint, ConstraintContext
from pmht_opt.constraints.blocks import Block, state_rows
from pmht_opt.constraints.params import is_real, positive_number
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.model import PX, PY

if TYPE_CHECKING:
    from pmht_opt.scenario import Scenario


class AreaBounds(Constraint):
    """``xmin <= px_t <= xmax`` and ``ymin <= py_t <= ymax`` for ``t = 1..T`` (four rows per step).

    A platform starting outside the box raises :class:`~pmht_opt.exceptions.ScenarioError` before any
    solve.
    """

    exact = True

    def __init__(self, xmin: float, xmax: float, ymin: float, ymax: float, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if not all(is_real(v) for v in (xmin, xmax, ymin, ymax)):
            raise ConfigError(
                f"AreaBounds: expected four numbers xmin, xmax, ymin, ymax, got {(xmin, xmax, ymin, ymax)!r}."
            )
        lim = validation.COORDINATE_MAX
        names = ("xmin", "xmax", "ymin", "ymax")
        box = np.array(
            [
                validation.real(f"AreaBounds.{k}", v, ConfigError, -lim, lim)
                for k, v in zip(names, (xmin, xmax, ymin, ymax), strict=True)
            ]
        )
        if box[0] >= box[1] or box[2] >= box[3]:
            raise ConfigError(f"AreaBounds: expected finite xmin < xmax and ymin < ymax, got {box.tolist()}.")
        self.box = box

    @classmethod
    def of(cls, scenario: Scenario, margin: float = 0.0, **kwargs: Any) -> AreaBounds:
        """The scenario's own area grown by ``margin``."""
        if scenario.bounds is None:
            raise ConfigError("AreaBounds.of: the scenario has no bounds; give them explicitly.")
        xmin, xmax, ymin, ymax = scenario.bounds
        return cls(xmin - margin, xmax + margin, ymin - margin, ymax + margin, **kwargs)

    @property
    def name(self) -> str:
        return "AreaBounds({:g}, {:g}, {:g}, {:g})".format(*self.box)

    def scale(self, scenario: Scenario) -> float:
        """The box's smaller side."""
        xmin, xmax, ymin, ymax = self.box
        return float(min(xmax - xmin, ymax - ymin))

    def check_scenario(self, scenario: Scenario) -> None:
        super().check_scenario(scenario)
        xmin, xmax, ymin, ymax = self.box
        for m in self.applies_to(scenario):
            x, y = scenario.start_positions[m]
            if not (xmin <= x <= xmax and ymin <= y <= ymax):
                raise ScenarioError(
                    f"platform {m} starts at ({x:g}, {y:g}), outside {self.name}; move the start or "
                    "widen the bounds."
                )

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        return [box_block(m, ctx.scenario.horizon, self.box) for m in self.applies_to(ctx.scenario)]


def box_block(platform: int, horizon: int, box: np.ndarray) -> Block:
    """Rows keeping ``platform``'s positions at ``t = 1..T`` in ``box = (xmin, xmax, ymin, ymax)``."""
    T = horizon
    xmin, xmax, ymin, ymax = box
    # Rows per step: px <= xmax, -px <= -xmin, py <= ymax, -py <= -ymin.
    times = np.repeat(np.arange(1, T + 1), 4)
    coeff = np.tile(np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), (T, 1))
    G = state_rows(T, times, np.array([PX, PY]), coeff)
    h = np.tile(np.array([xmax, -xmin, ymax, -ymin]), T)
    return Block(platform, "nonneg", G, h, times=times)


class StayNear(Constraint):
    """Every platform stays within ``margin`` of the scenario's area, beyond what its own start needs.

    The area is the scenario's ``bounds``, grown to include the platform's start; the rows bound ``x``
    and ``y`` at ``margin / sqrt(2)`` beyond it, so that even beyond a corner no position is further
    from the area than ``margin`` plus the start's own distance from it. :class:`VisitAll` implies it
    (``keep_within``, default 0.5): visits imposed at fixed times on a smooth path can otherwise be met
    by a loop far outside the area (Table 1 scenarios: up to 4 units out).
    """

    def __init__(self, margin: float = 0.5, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.margin = positive_number("StayNear.margin", margin)

    @property
    def name(self) -> str:
        return f"StayNear({self.margin:g})"

    def scale(self, scenario: Scenario) -> float:
        """The area's smaller side."""
        xmin, xmax, ymin, ymax = scenario.bounds or (0.0, 1.0, 0.0, 1.0)
        return float(max(min(xmax - xmin, ymax - ymin), 1e-12))

    def box(self, scenario: Scenario, platform: int) -> np.ndarray:
        """``(xmin, xmax, ymin, ymax)`` that ``platform``'s positions must stay in."""
        xmin, xmax, ymin, ymax = scenario.bounds or (0.0, 1.0, 0.0, 1.0)
        x, y = scenario.start_positions[platform]
        grow = self.margin / np.sqrt(2.0)
        return np.array([min(xmin, x) - grow, max(xmax, x) + grow, min(ymin, y) - grow, max(ymax, y) + grow])

    def blocks(self, ctx: ConstraintContext) -> list[Block]:
        sc = ctx.scenario
        return [box_block(m, sc.horizon, self.box(sc, m)) for m in self.applies_to(sc)]
