"""The problem, the settings and the answer of the tour engine, each validated where it is made."""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError

#: Largest seed (PyVRP's generator takes 32 bits).
SEED_MAX = 2**32 - 1
OBJECTIVES = ("distance", "time")


def _array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{name}: expected an array of numbers ({err}).") from None
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise ConfigError(f"{name}: expected shape {want}, got {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name}: every value must be finite.")
    arr.setflags(write=False)
    return arr


def _caps(value: Any, M: int) -> np.ndarray:
    """Route length caps: ``(M,)`` positive numbers or ``inf`` (a scalar is broadcast)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"max_lengths: expected {M} positive numbers or inf ({err}).") from None
    if arr.ndim == 0:
        arr = np.full(M, float(arr))
    if arr.shape != (M,):
        raise ConfigError(f"max_lengths: expected one cap per vehicle, shape ({M},), got {arr.shape}.")
    if np.isnan(arr).any() or not (arr > 0).all():
        raise ConfigError(f"max_lengths: every cap must be a positive number or inf, got {arr.tolist()}.")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class DiscProblem:
    """Vehicles' starts and the target discs that their routes must meet.

    Attributes
    ----------
    starts
        ``(M, 2)`` start of each vehicle (``M >= 1``).
    centres
        ``(N, 2)`` target centres (``N >= 0``).
    radii
        ``(N,)`` radius of each target's disc (``> 0``); a scalar is broadcast.
    closed
        Per vehicle (or one value for all): whether its route returns to its own start.
    max_lengths
        Per vehicle (or one value for all): the longest its route may be, a positive number or
        ``inf``; None (default) for no cap. A cap is a hard constraint of every objective: for
        example what a platform can fly in a mission's horizon at its speed limit. Caps that are all
        ``inf`` are the same problem as None, solved to the same bits.
    """

    starts: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    closed: bool | np.ndarray = False
    max_lengths: np.ndarray | None = None

    def __post_init__(self) -> None:
        starts = _array("starts", self.starts, (None, 2))
        if starts.shape[0] < 1:
            raise ConfigError("starts: at least one vehicle is needed.")
        centres = _array(
            "centres",
            np.reshape(self.centres, (-1, 2)) if np.size(self.centres) == 0 else self.centres,
            (None, 2),
        )
        radii = (
            np.broadcast_to(np.asarray(self.radii, dtype=float), (centres.shape[0],))
            if np.ndim(self.radii) == 0
            else self.radii
        )
        radii = _array("radii", radii, (centres.shape[0],))
        if np.any(radii <= 0):
            raise ConfigError("radii: every radius must be positive.")
        closed = np.asarray(self.closed)
        if (
            closed.dtype != bool
            or closed.ndim > 1
            or (closed.ndim == 1 and closed.shape[0] != starts.shape[0])
        ):
            raise ConfigError(f"closed: expected a bool or {starts.shape[0]} bools, got {self.closed!r}.")
        closed = np.broadcast_to(closed, (starts.shape[0],)).copy()
        closed.setflags(write=False)
        object.__setattr__(self, "starts", starts)
        object.__setattr__(self, "centres", centres)
        object.__setattr__(self, "radii", radii.copy() if not radii.flags.owndata else radii)
        object.__setattr__(self, "closed", closed)
        if self.max_lengths is not None:
            object.__setattr__(self, "max_lengths", _caps(self.max_lengths, starts.shape[0]))

    @property
    def caps(self) -> np.ndarray | None:
        """``(M,)`` the finite caps with ``inf`` for none, or None when no route has a finite cap."""
        if self.max_lengths is None or not np.isfinite(self.max_lengths).any():
            return None
        return self.max_lengths

    @property
    def n_vehicles(self) -> int:
        """Number of vehicles ``M``."""
        return int(self.starts.shape[0])

    @property
    def n_targets(self) -> int:
        """Number of targets ``N``."""
        return int(self.centres.shape[0])


def _count(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < low:
        raise ConfigError(f"{name}: expected an integer >= {low}, got {value!r}.")


@dataclass(frozen=True)
class TourSettings:
    """Options of :func:`~pmht_opt.tours.plan_tours`; the defaults are the benchmark's.

    Every effort knob counts iterations, never seconds, so a seed fixes the answer.

    Attributes
    ----------
    seed
        Seed of every random choice (PyVRP's and the search's).
    objective
        ``"distance"`` (total length) or ``"time"`` (longest route, then total length).
    order_iterations
        PyVRP iterations of the first ordering (a TSP through the centres).
    iterations
        Ruin-and-recreate iterations at most.
    patience
        Stop after this many iterations without a better tour.
    ruin_min, ruin_max
        A ruin removes between these many key discs (a random one and its nearest).
    bisection
        With ``objective="time"``: PyVRP solves of the bisection on the longest route that gives the
        first order (0: start from the shortest-total order).
    accept
        Threshold acceptance: a recreated tour becomes the next one to ruin when it is within this
        fraction of the best score; the fraction falls linearly to 0 at ``iterations``. The best tour
        is kept apart and returned.
    neighbours
        Legs at which a relocate move tries each disc (the cheapest by a lower bound).
    resequence
        Every this many iterations the candidate is not a ruin and recreate but a re-sequencing: PyVRP
        orders the current tour's turn points anew (a multiple TSP through them, as it ordered the
        centres at first), then the cone program, a repair of any disc no longer met, and the descent
        (:func:`~pmht_opt.tours.engine.resequence`); 0 never.
    resequence_iterations
        PyVRP iterations of each re-sequencing.
    starts
        Independent searches (PyVRP's order, descent, ruin and recreate, each with ``iterations`` and
        ``patience`` of its own), the first seeded ``seed`` and the others from it
        (:func:`~pmht_opt.tours.engine.start_seed`); the best tour of all is kept. One start is the
        search of ``seed`` alone.
    """

    seed: int = 0
    objective: str = "distance"
    order_iterations: int = 2000
    iterations: int = 150
    patience: int = 60
    ruin_min: int = 2
    ruin_max: int = 20
    accept: float = 0.01
    bisection: int = 6
    neighbours: int = 12
    resequence: int = 5
    resequence_iterations: int = 300
    starts: int = 1

    def __post_init__(self) -> None:
        if (
            isinstance(self.seed, bool)
            or not isinstance(self.seed, numbers.Integral)
            or not 0 <= self.seed <= SEED_MAX
        ):
            raise ConfigError(f"seed: expected an integer in 0..{SEED_MAX}, got {self.seed!r}.")
        if self.objective not in OBJECTIVES:
            raise ConfigError(f"objective: expected one of {OBJECTIVES}, got {self.objective!r}.")
        _count("order_iterations", self.order_iterations, 1)
        _count("iterations", self.iterations, 0)
        _count("patience", self.patience, 1)
        _count("ruin_min", self.ruin_min, 1)
        _count("ruin_max", self.ruin_max, 1)
        if self.ruin_max < self.ruin_min:
            raise ConfigError(f"ruin_max: must be >= ruin_min ({self.ruin_min}), got {self.ruin_max}.")
        _count("neighbours", self.neighbours, 1)
        _count("starts", self.starts, 1)
        _count("resequence", self.resequence, 0)
        _count("resequence_iterations", self.resequence_iterations, 1)
        _count("bisection", self.bisection, 0)
        if not (isinstance(self.accept, int | float) and 0.0 <= self.accept < 1.0):
            raise ConfigError(f"accept: expected a number in [0, 1), got {self.accept!r}.")


@dataclass(frozen=True)
class Progress:
    """What a callback or a stopping criterion sees after each iteration.

    Attributes
    ----------
    iteration
        Iterations done (0 after the first tour).
    scores
        Best score after each iteration so far, lower is better (total length, or longest route for
        ``objective="time"``), in the user's units.
    elapsed
        Seconds since the start (reported, never used to decide anything by the engine itself).
    settled
        Iterations since the best tour last improved.
    """

    iteration: int
    scores: tuple[float, ...]
    elapsed: float
    settled: int


@dataclass(frozen=True)
class DiscTours:
    """Routes that meet every target's disc.

    Attributes
    ----------
    routes
        Per vehicle, every target it covers exactly once, in the order its polyline meets the discs
        (a target covered in passing sits where the polyline passes closest to its centre).
    points
        ``(N, 2)`` each target's visit point: a point of its route's polyline inside its disc.
    lengths
        ``(M,)`` straight-line length of each route (with the leg home when closed).
    turns
        Per vehicle, the polyline's turn points in order (start and end not included).
    problem
        The problem solved.
    info
        Iterations run, the seed and the search's history.
    """

    routes: list[np.ndarray]
    points: np.ndarray
    lengths: np.ndarray
    turns: list[np.ndarray]
    problem: DiscProblem
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def total(self) -> float:
        """Sum of the route lengths."""
        return float(self.lengths.sum())

    @property
    def makespan(self) -> float:
        """Longest route."""
        return float(self.lengths.max())

    def vertices(self, m: int) -> np.ndarray:
        """Polyline of route ``m``: its start, its turn points, and its start again when closed."""
        s = self.problem.starts[m][None]
        parts = [s, self.turns[m]]
        if bool(np.asarray(self.problem.closed)[m]):
            parts.append(s)
        return np.vstack(parts)
