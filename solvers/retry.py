"""Retrying a failed solve with other settings: one policy for every backend and caller.

A solve that fails *without* a verdict on the problem (an iteration limit, insufficient progress, an
inaccurate answer) says more about the settings than about the problem, and a backend's slower,
more robust settings often solve it. A verdict of infeasibility is final: no setting changes it.

:class:`RetryChain` holds the settings to try, in order, on top of the base settings; sets that touch
a setting the caller chose are dropped (the caller's choice wins), and sets already contained in the
base settings are skipped (they are what just failed). :func:`retry_failed` runs the chain after a
first attempt. What to do with the settings that solved (keep them for later solves or not) is the
caller's decision: :func:`retry_failed` returns them.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Any

from solvers.problem import INFEASIBLE, QPSolution

Settings = Mapping[str, Any]


@dataclass(frozen=True)
class RetryChain:
    """Settings tried in turn, each merged over the base settings, after a failed solve."""

    sets: tuple[Settings, ...] = ()

    def without(self, chosen: Collection[str]) -> RetryChain:
        """The chain without the sets that change any of the ``chosen`` settings."""
        return RetryChain(tuple(s for s in self.sets if not set(s) & set(chosen)))


def retry_failed(
    first: QPSolution,
    base: Settings,
    chain: RetryChain,
    attempt: Callable[[dict[str, Any]], QPSolution],
) -> tuple[QPSolution, dict[str, Any] | None]:
    """Run ``chain`` after ``first`` failed; return the answer and the settings that gave it.

    Parameters
    ----------
    first
        The answer with ``base``.
    base
        The settings ``first`` was solved with.
    chain
        Sets to merge over ``base`` and try in turn.
    attempt
        ``attempt(settings) -> QPSolution``: solve the same problem afresh with ``settings``.

    Returns
    -------
    solution, settings
        The first answer that is optimal, with ``info["fallback"]`` (the set) and
        ``info["first_status"]`` (the failed status) recorded and the merged settings; or ``first``
        and ``None`` when ``first`` is optimal, certifies infeasibility, or no set solves.
    """
    if first.ok or first.status in INFEASIBLE:
        return first, None
    for extra in chain.sets:
        if extra.items() <= base.items():
            continue
        merged = {**base, **extra}
        retry = attempt(merged)
        if retry.ok:
            retry.info["fallback"] = dict(extra)
            retry.info["first_status"] = first.raw_status
            return retry, merged
    return first, None


#: The chain that retries nothing.
NO_RETRY = RetryChain()
