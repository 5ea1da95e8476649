"""When iterative methods stop, and what they report after every iteration.

Every iterative method of the package (the PMHT planner's EM, the smoothed and coverage planners, the
orderings that iterate) reports after each of its iterations with one kind of record,
:class:`Progress` (the EM's :class:`EMProgress` adds what only it knows), and asks the same stopping
criteria, passed in as ``stop=`` (:func:`pmht_opt.plan`, :func:`pmht_opt.order_locales`). A callback
``callback(progress)`` receives the same record.

A criterion is any callable ``criterion(progress) -> bool`` that says whether to stop after the
iteration ``progress`` describes. Criteria are small frozen dataclasses, passed in rather than hard-wired,
and hold no state of their own: everything they judge is in the :class:`Progress` record, so one
criterion object can serve any number of runs. Combine them with :class:`AnyOf`.

Scores are "lower is better": the GA reports its best tour cost, the EM planner the negative of its
objective.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from pmht_opt.exceptions import ConfigError


@dataclass(frozen=True)
class Progress:
    """What a stopping criterion sees after an iteration.

    Attributes
    ----------
    iteration
        Iterations completed so far (1 after the first).
    scores
        The score before the first iteration (index 0) and after each one since; lower is better.
    elapsed
        Seconds since the run started.
    settled
        Whether the method is in its final regime (the EM: annealing over and every constraint
        imposed; always true for methods without such phases). Convergence tests only count settled
        iterations.
    stage
        What is iterating: ``"em"``, ``"search"`` (a tour search), ``"ordering"``, ...
    """

    iteration: int
    scores: Sequence[float]
    elapsed: float = 0.0
    settled: bool = True
    stage: str = ""


@dataclass(frozen=True)
class EMProgress(Progress):
    """What a stopping criterion sees after an EM iteration, beyond :class:`Progress`.

    Attributes
    ----------
    path_change
        Largest distance any position moved in the last iteration.
    assignment_age
        Iterations since the MAP platform of some locale last changed (0: it changed in the last one).
    scale
        The size of the scenario's area, which path changes are judged against.
    """

    path_change: float = float("inf")
    assignment_age: int = 0
    scale: float = 1.0


@runtime_checkable
class StoppingCriterion(Protocol):
    """``criterion(progress) -> bool``: stop after the iteration ``progress`` describes."""

    def __call__(self, progress: Progress) -> bool:
        """Whether to stop now."""
        ...


def _positive_int(owner: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{owner}: expected a positive integer, got {value!r}.")
    return value


def _non_negative(owner: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{owner}: expected a finite non-negative number, got {value!r}.")
    out = float(value)
    if not math.isfinite(out) or out < 0:
        raise ConfigError(f"{owner}: expected a finite non-negative number, got {value!r}.")
    return out


@dataclass(frozen=True)
class MaxIterations:
    """Stop after ``limit`` iterations."""

    limit: int

    def __post_init__(self) -> None:
        _positive_int("MaxIterations.limit", self.limit)

    def __call__(self, progress: Progress) -> bool:
        return progress.iteration >= self.limit


@dataclass(frozen=True)
class ObjectiveTolerance:
    """Stop once a settled iteration changes the score by at most ``rtol`` relative to the previous one.

    ``rtol = 0`` never stops (a change of exactly zero is not taken as convergence, so a run with
    ``rtol = 0`` always runs to its other criteria).
    """

    rtol: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "rtol", _non_negative("ObjectiveTolerance.rtol", self.rtol))

    def __call__(self, progress: Progress) -> bool:
        scores = progress.scores
        if self.rtol <= 0 or not progress.settled or len(scores) < 2:
            return False
        prev, last = scores[-2], scores[-1]
        return abs(last - prev) <= self.rtol * max(abs(prev), 1e-300)


@dataclass(frozen=True)
class TimeBudget:
    """Stop once ``seconds`` of wall-clock time have passed.

    Wall-clock limits make a run's result depend on the machine's load: use them for interactive
    work, never in a study whose results are recorded.
    """

    seconds: float

    def __post_init__(self) -> None:
        value = _non_negative("TimeBudget.seconds", self.seconds)
        if value == 0:
            raise ConfigError("TimeBudget.seconds: expected a positive number of seconds, got 0.")
        object.__setattr__(self, "seconds", value)

    def __call__(self, progress: Progress) -> bool:
        return progress.elapsed >= self.seconds


@dataclass(frozen=True)
class NoImprovement:
    """Stop when the best score has not fallen for ``iterations`` settled iterations."""

    iterations: int

    def __post_init__(self) -> None:
        _positive_int("NoImprovement.iterations", self.iterations)

    def __call__(self, progress: Progress) -> bool:
        scores = progress.scores
        k = self.iterations
        if not progress.settled or len(scores) <= k:
            return False
        return min(scores[-k:]) >= min(scores[:-k])


@dataclass(frozen=True)
class Converged:
    """Stop once the plan has stopped changing: in the final regime, no locale has changed platform for
    ``stable`` iterations and no position moved more than ``path_rtol`` times the area's size in the
    last one. For the EM only (it reads :class:`EMProgress`); other progress never stops it."""

    path_rtol: float = 1e-4
    stable: int = 5

    def __post_init__(self) -> None:
        object.__setattr__(self, "path_rtol", _non_negative("Converged.path_rtol", self.path_rtol))
        _positive_int("Converged.stable", self.stable)

    def __call__(self, progress: Progress) -> bool:
        if not isinstance(progress, EMProgress) or not progress.settled:
            return False
        return (
            progress.assignment_age >= self.stable and progress.path_change <= self.path_rtol * progress.scale
        )


@dataclass(frozen=True)
class AnyOf:
    """Stop as soon as any of ``criteria`` says so."""

    criteria: tuple[StoppingCriterion, ...]

    def __post_init__(self) -> None:
        if callable(self.criteria) or not isinstance(self.criteria, (tuple, list)):
            raise ConfigError(f"AnyOf: expected a sequence of stopping criteria, got {self.criteria!r}.")
        crit = tuple(self.criteria)
        for c in crit:
            if not callable(c):
                raise ConfigError(f"AnyOf: expected stopping criteria, got {type(c).__name__}.")
        object.__setattr__(self, "criteria", crit)

    def __call__(self, progress: Progress) -> bool:
        return any(c(progress) for c in self.criteria)


def as_criterion(stop: object, field: str = "stop") -> StoppingCriterion:
    """``stop`` as one criterion: a criterion, or a sequence of them (any of which stops the run).

    Raises :class:`ConfigError` naming ``field`` for anything else.
    """
    if callable(stop):
        return stop
    if isinstance(stop, (list, tuple)):
        for c in stop:
            if not callable(c):
                raise ConfigError(f"{field}: expected stopping criteria, got {type(c).__name__}.")
        return AnyOf(tuple(stop))
    raise ConfigError(
        f"{field}: expected a stopping criterion such as MaxIterations(50), or a list of them, "
        f"got {type(stop).__name__}."
    )


#: ``callback(progress)``: what every iterative method calls after each iteration.
ProgressObserver = Callable[[Progress], object]


def check_callback(callback: object, field: str = "callback") -> ProgressObserver | None:
    """``callback`` if it is ``None`` or callable, else :class:`ConfigError` naming ``field``."""
    if callback is not None and not callable(callback):
        raise ConfigError(f"{field}: expected a callable(progress), got {type(callback).__name__}.")
    return callback


def fired(criterion: StoppingCriterion, progress: Progress) -> str | None:
    """The name of the criterion inside ``criterion`` that says stop after ``progress`` (the first,
    looking inside :class:`AnyOf`), or ``None`` if none does."""
    if isinstance(criterion, AnyOf):
        for c in criterion.criteria:
            name = fired(c, progress)
            if name is not None:
                return name
        return None
    return type(criterion).__name__ if criterion(progress) else None


class Watched:
    """A solver's own per-iteration hook turned into this module's contract.

    Called with the solver's best score after each of its iterations (``watched(score) -> bool``,
    the form PyVRP's and OR-Tools' stopping hooks take), it keeps the scores, calls ``callback``
    with a :class:`Progress` (stage ``"ordering"``) and says whether ``stop`` says stop. ``convert``
    maps the solver's score to the scenario's units; ``t0`` is the run's start
    (``time.perf_counter()``).
    """

    def __init__(
        self,
        stop: StoppingCriterion | None,
        callback: ProgressObserver | None,
        convert: Callable[[float], float],
        t0: float,
    ) -> None:
        self.stop, self.callback, self.convert, self.t0 = stop, callback, convert, t0
        self.scores: list[float] = [math.inf]

    def __call__(self, score: float) -> bool:
        self.scores.append(min(self.scores[-1], self.convert(float(score))))
        elapsed = time.perf_counter() - self.t0
        progress = Progress(len(self.scores) - 1, list(self.scores), elapsed, True, "ordering")
        if self.callback is not None:
            self.callback(progress)
        return bool(self.stop is not None and self.stop(progress))


def iteration_limit(criterion: StoppingCriterion) -> int | None:
    """The smallest :class:`MaxIterations` limit inside ``criterion`` (``None`` if it has none).

    Methods that plan ahead (an annealing schedule, a batch of random draws) use it as the run's length.
    """
    if isinstance(criterion, MaxIterations):
        return criterion.limit
    if isinstance(criterion, AnyOf):
        limits = [lim for c in criterion.criteria if (lim := iteration_limit(c)) is not None]
        return min(limits) if limits else None
    return None
