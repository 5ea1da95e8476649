r"""Tours of the multiple travelling salesman problem from per-platform starts, and their cost.

A *tour* is one route per platform: route ``m`` is an integer array of locale indices in visiting order,
flown by platform ``m`` from its start. Every locale is in exactly one route. In an *open* tour (the
paper's problem) nobody returns, so the cost of a tour is

.. math::

    C = \sum_{m=1}^{M} \Big( \lVert z_{r_m(1)} - s_m \rVert
        + \sum_{k=2}^{|r_m|} \lVert z_{r_m(k)} - z_{r_m(k-1)} \rVert \Big),

with ``s_m`` platform ``m``'s start and an empty route costing 0. In a *closed* tour (return to base)
each platform flies back to its start after its last locale, which adds
:math:`\lVert s_m - z_{r_m(|r_m|)} \rVert` per non-empty route. The solvers compute ``C`` from
precomputed distance matrices; :func:`route_costs` recomputes it here from coordinates alone, so a result
can be checked without trusting the solver that made it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.scenario import Scenario
from pmht_opt.validation import integer

#: Relative tolerance of :meth:`TourResult.validate` on the stored total distance.
DISTANCE_RTOL = 1e-9


def _as_route(index: int, route: Any, n_locales: int) -> np.ndarray:
    """One route as an ``intp`` array, or ConfigError saying what is wrong with it."""
    if isinstance(route, (list, tuple)) and any(isinstance(v, (bool, np.bool_)) for v in route):
        raise ConfigError(f"routes[{index}]: expected integer locale indices, got a boolean in {route!r}.")
    try:
        arr = np.asarray(route)
    except (TypeError, ValueError):
        raise ConfigError(f"routes[{index}]: expected a sequence of locale indices, got {route!r}.") from None
    if arr.ndim != 1:
        raise ConfigError(
            f"routes[{index}]: expected a 1-D sequence of locale indices, got shape {arr.shape}."
        )
    if arr.size == 0:
        return np.zeros(0, dtype=np.intp)
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise ConfigError(f"routes[{index}]: expected integer locale indices, got dtype {arr.dtype}.")
    if arr.dtype.kind == "f":
        # Whole floats (e.g. from a JSON round trip) are accepted; fractions are a mistake.
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise ConfigError(f"routes[{index}]: expected integer locale indices, got {arr.tolist()}.")
    out = arr.astype(np.intp)
    bad = (out < 0) | (out >= n_locales)
    if np.any(bad):
        raise ConfigError(
            f"routes[{index}]: locale index {int(out[bad][0])} is out of range 0..{n_locales - 1}."
        )
    return out


def check_routes(scenario: Scenario, routes: Sequence[Any]) -> list[np.ndarray]:
    """Validate a tour and return its routes as ``intp`` arrays.

    Parameters
    ----------
    scenario
        The scenario the tour is for.
    routes
        One sequence of locale indices per platform (empty for an idle platform).

    Raises
    ------
    ConfigError
        Naming what is wrong: the number of routes, a route that is not a 1-D integer sequence, an index
        out of range, a locale visited more than once or not at all.
    """
    check_scenario(scenario)
    if isinstance(routes, (str, bytes)) or not isinstance(routes, (Sequence, np.ndarray)):
        raise ConfigError(f"routes: expected a sequence of routes, got {type(routes).__name__}.")
    M, N = scenario.n_platforms, scenario.n_locales
    if len(routes) != M:
        raise ConfigError(f"routes: expected one route per platform ({M}), got {len(routes)}.")
    out = [_as_route(m, r, N) for m, r in enumerate(routes)]
    allidx = np.concatenate(out) if out else np.zeros(0, dtype=np.intp)
    counts = np.bincount(allidx, minlength=N)
    if np.any(counts > 1):
        dup = int(np.flatnonzero(counts > 1)[0])
        where = [m for m, r in enumerate(out) if np.any(r == dup)]
        raise ConfigError(
            f"routes: locale {dup} is visited {int(counts[dup])} times (routes {where}); "
            "every locale must be in exactly one route."
        )
    if np.any(counts == 0):
        missing = np.flatnonzero(counts == 0)
        shown = ", ".join(str(int(i)) for i in missing[:10]) + (", ..." if missing.size > 10 else "")
        raise ConfigError(
            f"routes: {missing.size} locale(s) are in no route ({shown}); "
            "every locale must be in exactly one route."
        )
    return out


def _check_closed(closed: Any) -> bool:
    if not isinstance(closed, (bool, np.bool_)):
        raise ConfigError(f"closed: expected True (return to base) or False (open routes), got {closed!r}.")
    return bool(closed)


def route_legs(scenario: Scenario, routes: Sequence[Any], closed: bool = False) -> list[np.ndarray]:
    """The points each platform flies through: its start, its locales and, if ``closed``, its start again.

    Returns
    -------
    list of numpy.ndarray
        ``(k, 2)`` per platform; just the start for an empty route.
    """
    closed = _check_closed(closed)
    checked = check_routes(scenario, routes)
    starts = scenario.start_positions
    legs = []
    for m, route in enumerate(checked):
        back = [starts[m : m + 1]] if closed and route.size else []
        legs.append(np.vstack([starts[m : m + 1], scenario.locales[route], *back]))
    return legs


def route_costs(scenario: Scenario, routes: Sequence[Any], closed: bool = False) -> np.ndarray:
    """Distance flown by each platform: start to first locale, the legs between locales and, if
    ``closed``, the leg from the last locale back to the start.

    Computed from coordinates (not from any distance matrix), after validating the tour with
    :func:`check_routes`.

    Returns
    -------
    numpy.ndarray
        ``(M,)`` distances; 0 for an empty route.
    """
    legs = route_legs(scenario, routes, closed)
    return np.array([float(np.hypot(*np.diff(pts, axis=0).T).sum()) for pts in legs])


def tour_distance(scenario: Scenario, routes: Sequence[Any], closed: bool = False) -> float:
    """Total distance of a tour, validating it first (see :func:`check_routes` for the errors).

    ``closed``: each platform returns to its start, and the return legs count.
    """
    return float(route_costs(scenario, routes, closed).sum())


@dataclass
class TourResult:
    """An ordering of the locales: one route per platform, and what it costs.

    Attributes
    ----------
    routes
        One ``intp`` array of locale indices per platform, in visiting order; route ``m`` starts at
        platform ``m``'s start.
    total_distance
        Sum over platforms of start-to-first-locale plus consecutive legs (and the legs back to the
        starts if :attr:`closed`), in scenario units, recomputed in floating point from the routes.
    history
        Best cost found after each iteration (GA), or the costs of the successive improving solutions
        (OR-Tools); never increasing.
    wall_time
        Seconds spent in the solver call.
    method
        ``"ga"``, ``"ortools"`` or ``"given"``.
    scenario
        The scenario solved (used by :meth:`validate` and :meth:`plot`).
    extras
        Solver-specific details (parameters used, status, ...).
    closed
        Whether each platform returns to its start (return to base) and the return legs are costed.
    """

    routes: list[np.ndarray]
    total_distance: float
    history: np.ndarray
    wall_time: float
    method: str
    scenario: Scenario | None = field(default=None, repr=False)
    extras: dict[str, Any] = field(default_factory=dict)
    closed: bool = False

    @classmethod
    def from_routes(
        cls, scenario: Scenario, routes: Sequence[Any], method: str = "given", closed: bool = False
    ) -> TourResult:
        """Wrap a user-supplied tour, validating it and computing its distance."""
        if not isinstance(method, str):
            raise ConfigError(f"method: expected a name (a string), got {method!r}.")
        checked = check_routes(scenario, routes)
        dist = tour_distance(scenario, checked, closed)
        return cls(checked, dist, np.array([dist]), 0.0, method, scenario, closed=closed)

    @property
    def n_platforms(self) -> int:
        """``M``: number of routes."""
        return len(self.routes)

    @property
    def n_locales(self) -> int:
        """``N``: number of locales visited."""
        return int(sum(r.size for r in self.routes))

    @property
    def n_iterations(self) -> int:
        """Entries of :attr:`history`."""
        return int(self.history.shape[0])

    @property
    def route_lengths(self) -> np.ndarray:
        """``(M,)`` number of locales in each route."""
        return np.array([r.size for r in self.routes], dtype=np.intp)

    @property
    def route_distances(self) -> np.ndarray:
        """``(M,)`` distance flown by each platform (needs :attr:`scenario`)."""
        return route_costs(self.scenario_for(None), self.routes, self.closed)

    @property
    def assignment(self) -> np.ndarray:
        """``(N,)`` platform of each locale."""
        out = np.empty(self.n_locales, dtype=np.intp)
        for m, r in enumerate(self.routes):
            out[r] = m
        return out

    @property
    def order(self) -> np.ndarray:
        """``(N,)`` position (0-based) of each locale within its route."""
        out = np.empty(self.n_locales, dtype=np.intp)
        for r in self.routes:
            out[r] = np.arange(r.size)
        return out

    def scenario_for(self, scenario: Scenario | None) -> Scenario:
        sc = scenario if scenario is not None else self.scenario
        if sc is None:
            raise ConfigError("scenario: this TourResult holds no scenario; pass one.")
        return check_scenario(sc)

    def validate(self, scenario: Scenario | None = None, min_tour: int = 0) -> None:
        """Check the tour against a scenario without trusting the solver.

        Every locale must be in exactly one route, each route must hold at least ``min_tour`` locales,
        and :attr:`total_distance` must equal the distance recomputed from coordinates, with the return
        legs if :attr:`closed` (relative tolerance :data:`DISTANCE_RTOL`).

        Raises
        ------
        ConfigError
            A malformed tour (see :func:`check_routes`) or a route shorter than ``min_tour``.
        SolverError
            A stored distance that disagrees with the recomputation.
        """
        sc = self.scenario_for(scenario)
        min_tour = integer("min_tour", min_tour, ConfigError, 0)
        recomputed = tour_distance(sc, self.routes, self.closed)
        short = [m for m, r in enumerate(self.routes) if len(r) < min_tour]
        if short:
            raise ConfigError(f"routes: route(s) {short} hold fewer than min_tour={min_tour} locales.")
        if not np.isclose(self.total_distance, recomputed, rtol=DISTANCE_RTOL, atol=0.0):
            raise SolverError(
                f"total_distance {self.total_distance!r} disagrees with the recomputed {recomputed!r}.",
                backend=self.method,
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain-Python form (lists and floats), e.g. for JSON."""
        return {
            "method": self.method,
            "total_distance": self.total_distance,
            "wall_time": self.wall_time,
            "routes": [r.tolist() for r in self.routes],
            "closed": self.closed,
            "history_last": float(self.history[-1]) if self.history.size else None,
            "n_iterations": self.n_iterations,
        }


#: Upper bound of iteration counts and limits of the orderers: beyond it a run would not end in any
#: useful time (and the solvers' own integer fields would overflow).
COUNT_MAX = 10_000_000


def check_count(name: str, value: Any) -> int:
    """An iteration count or limit of an orderer: an integer in ``1..COUNT_MAX``, or ConfigError."""
    return integer(name, value, ConfigError, 1, COUNT_MAX)


def check_scenario(scenario: Any) -> Scenario:
    """``scenario`` if it is a :class:`Scenario`, else ConfigError naming it."""
    if not isinstance(scenario, Scenario):
        raise ConfigError(f"scenario: expected a Scenario, got {type(scenario).__name__}.")
    return scenario


def check_min_tour(scenario: Scenario, min_tour: Any) -> int:
    """``min_tour`` as an int, checked against the scenario (``min_tour * M <= N``)."""
    check_scenario(scenario)
    value = integer("min_tour", min_tour, ConfigError, 1)
    M, N = scenario.n_platforms, scenario.n_locales
    if N < M:
        raise ConfigError(
            f"scenario: an ordering gives every platform a route of at least one locale, and this "
            f"scenario has {N} locales for {M} platforms; plan it with plan_pmht, which can leave "
            "platforms idle."
        )
    if value * M > N:
        raise ConfigError(
            f"min_tour: expected min_tour * platforms <= locales, i.e. at most {N // M} for {M} platforms "
            f"and {N} locales, got {value}."
        )
    return value
