r"""Restart policies: when the GA redraws a stalled population.

Without crossover the best member of a group takes over its group at once, so a run that falls into a
tour no single move improves stays there. A restart redraws the whole population at random; the best
tour so far is kept outside the population, so the best cost never increases. A policy is any object
with ``patience(n_locales, groups) -> float``: the number of generations without a better tour in the
current run after which the population is redrawn (``inf``: never).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from pmht_opt.exceptions import ConfigError


@runtime_checkable
class RestartPolicy(Protocol):
    """``policy.patience(n_locales, groups) -> float``: stalled generations before a restart."""

    def patience(self, n_locales: int, groups: int) -> float:
        """Generations without a better tour after which the population is redrawn."""
        ...


@dataclass(frozen=True)
class StallRestart:
    r"""Restart after ``ceil(stall * N (N + 1) / (2 G))`` generations without a better tour.

    ``N (N + 1) / 2`` is the number of segments ``I..J`` and every generation draws one per group, so
    the patience is about ``stall`` draws of every segment with every move. It grows as ``N^2``: 18
    generations for 8 locales and 80 members, 2525 for 100, so restarts serve small instances and
    leave long runs on large ones essentially alone.
    """

    stall: float = 5.0

    def __post_init__(self) -> None:
        s = self.stall
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not (math.isfinite(s) and s > 0):
            raise ConfigError(f"StallRestart.stall: expected a positive finite number, got {s!r}.")

    def patience(self, n_locales: int, groups: int) -> float:
        N = n_locales
        return math.ceil(self.stall * N * (N + 1) / (2 * groups))


@dataclass(frozen=True)
class NoRestart:
    """Never restart (Kirk's GA)."""

    def patience(self, n_locales: int, groups: int) -> float:
        return math.inf
