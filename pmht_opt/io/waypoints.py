"""Each platform's flight: waypoints that keep the plan's promises as flown, its speed and its end.

``source = "plan"``
    Points of the planned path: its ends, the point nearest each site it is assigned, and as many more
    as keep the straight legs within ``tolerance`` of the path (Douglas-Peucker, :func:`simplify`).
    A chord between two points of a path that bends round a keep-out zone can cut into the zone although
    the path does not, and a chord can pass a site further off than the path did. So the legs are then
    measured against every promise (:mod:`pmht_opt.io.flight`), and where a leg breaks one the
    simplification is refined there: the point of the path between the leg's ends that lies furthest
    from the leg becomes a waypoint, splitting the leg in two; a site that no leg covers gets both ends
    of the path's segment nearest to it, so that this segment is itself a leg. Each round adds points of
    the path and the path's own segments keep every promise to the planner's tolerance, so the rounds end,
    at worst with every point of the path. A leg that is already a segment of the path and still breaks
    a promise (a plan that does not keep it) is refused.
``source = "tour"``
    The coverage planner's straight-line tour (``extras["tour"]``), one polyline per platform, as it
    is: it meets every site's disc itself and is shorter than the smooth path. Its legs are measured the
    same way; there is nothing to refine, so a leg that breaks a promise (a tour drawn without the
    keep-out zones, say) is refused.

Each route is flown at one ground speed (:func:`cruise_speeds`: the plan's speed limit, which the
plan keeps on every step, else the mean planned speed) and ends as asked: a return to launch flies
one more straight leg, from the last waypoint home, measured like the others; a landing or a hold
adds none.

A refusal is :class:`~pmht_opt.exceptions.SolverError` naming the platform, the leg and the
constraint (or the site): no file is written that breaks a promise.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints import SpeedLimit
from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.geometry import point_polyline_distance
from pmht_opt.io.flight import Promises, Zone, deviation, plan_promises
from pmht_opt.io.frame import GEO_RESOLUTION

#: Where waypoints come from.
SOURCES = ("plan", "tour")
#: How a mission ends: return to launch, land at the last waypoint, or hold there.
ENDS = ("rtl", "land", "hover")
#: A route whose last waypoint is this close (m) to its first ends at home: it lands there by default.
AT_HOME = 1e-3

#: ``through(points)``: points ``(K, 2)`` of the plane as the file will hold them (rounded).
Through = Callable[[np.ndarray], np.ndarray]


def simplify(points: np.ndarray, tolerance: float, keep: Any = ()) -> np.ndarray:
    """Indices of ``points (K, 2)`` whose polyline stays within ``tolerance`` of every point
    (Douglas-Peucker), always including the first, the last and those in ``keep``, in order."""
    pts = np.asarray(points, dtype=float)
    chosen = {0, len(pts) - 1, *(int(k) for k in keep)}
    stack = list(itertools.pairwise(sorted(chosen)))
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        k, dist = _furthest(pts, i, j)
        if dist > tolerance:
            chosen.add(k)
            stack += [(i, k), (k, j)]
    return np.array(sorted(chosen), dtype=np.intp)


def _furthest(pts: np.ndarray, i: int, j: int) -> tuple[int, float]:
    """The index strictly between ``i`` and ``j`` (``j - i >= 2``) of the point furthest from the
    segment ``pts[i] -> pts[j]``, and its distance."""
    dist = point_polyline_distance(pts[i + 1 : j], pts[[i, j]])
    k = int(np.argmax(dist))
    return i + 1 + k, float(dist[k])


@dataclass(frozen=True)
class Route:
    """One platform's waypoints, as the file holds them, and how they fly.

    Attributes
    ----------
    platform
        The platform (from 0).
    waypoints
        ``(K, 2)`` in the plane, through the file's rounding, the start first.
    steps
        The path's steps ``t`` of the waypoints (``source = "plan"``), or ``None`` (the tour).
    added
        Waypoints added to the simplification to keep the promises.
    deviation
        The largest distance between the legs and the planned path (:func:`~pmht_opt.io.flight.deviation`).
    """

    platform: int
    waypoints: np.ndarray
    steps: np.ndarray | None
    added: int
    deviation: float


def _refusal(platform: int, leg: int, legs: int, zone: Zone, depth: float, why: str) -> SolverError:
    what = "keeps out of" if zone.box is None else "stays inside"
    return SolverError(
        f"platform {platform}, leg {leg} of {legs} (waypoints {leg} to {leg + 1}, counted from 0 at the "
        f"start): {zone.name} is "
        f"broken by {depth:.3g} m (tolerance {zone.tolerance:.2g} m) and {why}; no waypoint set {what} it.",
        status="export refused",
    )


def plan_routes(
    result: Any, promises: Promises, tolerance: float, through: Through, spacing: float
) -> list[Route]:
    """Every platform's waypoints chosen on the planned path and refined until every leg keeps every
    promise (module notes); ``through`` rounds points as the file will, ``spacing`` sets the accuracy
    of the deviation (:func:`~pmht_opt.io.flight.deviation`).

    Raises
    ------
    SolverError
        A segment of the planned path itself breaks a promise, or a site the plan promises is not
        covered by the planned paths themselves.
    """
    sc = result.scenario
    paths = np.asarray(result.positions, dtype=float)
    keep: list[set[int]] = []
    for m, path in enumerate(paths):
        mine = np.flatnonzero(np.asarray(result.assignment) == m)
        nearest = [int(np.argmin(np.hypot(*(path - sc.locales[n]).T))) for n in mine]
        keep.append(set(simplify(path, tolerance, keep=nearest).tolist()))
    first = [len(k) for k in keep]
    while True:
        changed = False
        for m, path in enumerate(paths):
            steps = sorted(keep[m])
            found = promises.first_breach(m, through(path[steps]))
            if found is not None:
                leg, zone, depth = found
                i, j = steps[leg], steps[leg + 1]
                if j - i < 2:
                    why = f"this leg is the planned path's own segment from step {i} to {j}"
                    raise _refusal(m, leg, len(steps) - 1, zone, depth, why)
                keep[m].add(_furthest(path, i, j)[0])
                changed = True
        if not changed and promises.coverage is not None:
            lines = [through(path[sorted(k)]) for path, k in zip(paths, keep, strict=True)]
            for n in np.flatnonzero(promises.coverage.gaps(lines) > 0):
                m, t = _nearest_segment(paths, promises.coverage.sites[n])
                gap = promises.coverage.gaps([through(paths[m, t : t + 2])])[n]
                if gap > 0:
                    radius = promises.coverage.radii[n]
                    raise SolverError(
                        f"site {n} is {gap:.3g} m beyond its promised radius {radius:g} m "
                        f"(with its tolerance) from every planned path, platform {m}'s the nearest: the plan "
                        "does not cover it, so no waypoints along it can.",
                        status="export refused",
                    )
                if not {t, t + 1} <= keep[m]:
                    keep[m] |= {t, t + 1}
                    changed = True
        if not changed:
            break
    routes = []
    for m, path in enumerate(paths):
        chosen = np.array(sorted(keep[m]), dtype=np.intp)
        points = through(path[chosen])
        routes.append(Route(m, points, chosen, len(chosen) - first[m], deviation(points, path, spacing)))
    return routes


def _nearest_segment(paths: np.ndarray, site: np.ndarray) -> tuple[int, int]:
    """``(platform, t)``: the segment ``t -> t + 1`` of all the paths ``(M, T+1, 2)`` nearest ``site``."""
    best = (np.inf, 0, 0)
    for m, path in enumerate(paths):
        a, b = path[:-1], path[1:]
        d = b - a
        len2 = np.einsum("ki,ki->k", d, d)
        s = np.clip(np.einsum("ki,ki->k", site - a, d) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
        dist = np.hypot(*(a + s[:, None] * d - site).T)
        t = int(np.argmin(dist))
        if dist[t] < best[0]:
            best = (float(dist[t]), m, t)
    return best[1], best[2]


def tour_routes(result: Any, promises: Promises, through: Through, spacing: float) -> list[Route]:
    """Every platform's waypoints on the coverage planner's tour (module notes).

    Raises
    ------
    ConfigError
        ``result`` has no tour (a planner other than ``coverage``): names ``source``.
    SolverError
        A leg of the tour breaks a promise, or the tours miss a site.
    """
    tours = result.extras.get("tour")
    if tours is None:
        raise ConfigError(
            "source: 'tour' takes the coverage planner's straight-line tour; the "
            f"{result.planner or 'given'} planner has none (use 'plan')."
        )
    routes = []
    paths = np.asarray(result.positions, dtype=float)
    for m, tour in enumerate(tours):
        points = through(np.asarray(tour, dtype=float).reshape(-1, 2))
        repeated = np.r_[False, np.all(np.diff(points, axis=0) == 0, axis=1)]
        points = points[~repeated]  # a leg of no length flies nowhere
        found = promises.first_breach(m, points)
        if found is not None:
            leg, zone, depth = found
            raise _refusal(m, leg, len(points) - 1, zone, depth, "the tour has no other points")
        routes.append(Route(m, points, None, 0, deviation(points, paths[m], spacing)))
    if promises.coverage is not None:
        gaps = promises.coverage.gaps([r.waypoints for r in routes])
        bad = np.flatnonzero(gaps > 0)
        if bad.size:
            n = int(bad[0])
            raise SolverError(
                f"site {n} is {gaps[n]:.3g} m beyond its radius from every leg of the tour; export the "
                "plan's waypoints instead (source 'plan').",
                status="export refused",
            )
    return routes


def return_breach(promises: Promises, route: Route) -> SolverError | None:
    """The refusal of a return to launch (a straight leg from the last waypoint to the first) that
    breaks a promise, or ``None``."""
    home = route.waypoints[[-1, 0]]
    found = promises.first_breach(route.platform, home)
    if found is None:
        return None
    _, zone, depth = found
    what = "keeps out of" if zone.box is None else "stays inside"
    return SolverError(
        f"platform {route.platform}: the return to launch, straight from the last waypoint home, breaks "
        f"{zone.name} by {depth:.3g} m (tolerance {zone.tolerance:.2g} m); no return {what} it: end with "
        "'land' or 'hover', or plan a return to base.",
        status="export refused",
    )


def checked_speed(speed: Any) -> float:
    """``speed`` (m/s), given or each platform's mean, if it is a non-negative number."""
    return validation.real("speed", speed, ConfigError, 0.0)


def cruise_speeds(result: Any, speed: float | None = None) -> np.ndarray:
    """``(M,)`` each platform's ground speed (m/s): ``speed`` if given, else the smallest
    :class:`~pmht_opt.constraints.SpeedLimit` binding the platform, else its mean planned speed
    (length over the horizon).

    Raises
    ------
    ConfigError
        A ``speed`` above a hard speed limit of the plan (named): it would break the plan's promise.
    """
    sc = result.scenario
    limits = np.full(sc.n_platforms, np.inf)
    hard = np.full(sc.n_platforms, np.inf)
    for con in result.constraints:
        if isinstance(con, SpeedLimit):
            for m in con.applies_to(sc):
                limits[m] = min(limits[m], con.limit_for(m))
                if not con.soft:
                    hard[m] = min(hard[m], con.limit_for(m))
    if speed is not None:
        speed = checked_speed(speed)
        over = np.flatnonzero(speed > hard)
        if over.size:
            m = int(over[0])
            raise ConfigError(
                f"speed: {speed:g} m/s is above platform {m}'s speed limit {hard[m]:g} m/s, which the plan "
                "promises; give at most the limit, or leave speed out to fly at it."
            )
        return np.full(sc.n_platforms, speed)
    seg = np.diff(np.asarray(result.positions), axis=1)
    mean = np.hypot(seg[..., 0], seg[..., 1]).sum(axis=1) / (sc.horizon * sc.dt)
    return np.array([checked_speed(v) for v in np.where(np.isfinite(limits), limits, mean)])


@dataclass(frozen=True)
class Flight:
    """One platform's exported mission: where it flies, how fast and how it ends.

    Attributes
    ----------
    route
        Its waypoints (:class:`Route`: points as written, the largest distance
        between its legs and the planned path, waypoints added to keep the promises).
    speed
        Ground speed, m/s.
    end
        ``"rtl"``, ``"land"`` or ``"hover"``.
    """

    route: Route
    speed: float
    end: str

    @property
    def deviation(self) -> float:
        """The largest distance (m) between the legs and the planned path."""
        return self.route.deviation


def flights(
    result: Any,
    through: Through,
    tolerance: float,
    *,
    speed: float | None = None,
    end: str | None = None,
    source: str = "plan",
) -> list[Flight]:
    """Every platform's :class:`Flight`: its route from ``source`` (module notes), its speed
    (:func:`cruise_speeds`) and its end (``None``: ``"land"`` where the route ends within
    :data:`AT_HOME` of its start, the plan's return to base, else ``"rtl"``); ``through`` rounds points
    as the file will (:data:`~pmht_opt.io.frame.GEO_RESOLUTION` at most), ``tolerance`` is the
    simplification's.

    Raises
    ------
    ConfigError
        ``source="tour"`` without a tour, a speed above the plan's limit.
    SolverError
        No waypoints keep a promise, or a return to launch's leg home breaks one.
    """
    speeds = cruise_speeds(result, speed)
    promises = plan_promises(result, GEO_RESOLUTION)
    spacing = float(np.clip(tolerance / 10, 0.01, 0.5))  # the deviation to within half of it
    if source == "tour":
        routes = tour_routes(result, promises, through, spacing)
    else:
        routes = plan_routes(result, promises, tolerance, through, spacing)
    out = []
    for route, cruise in zip(routes, speeds, strict=True):
        home = float(np.hypot(*(route.waypoints[-1] - route.waypoints[0])))
        ending = end or ("land" if home <= AT_HOME else "rtl")
        if ending == "rtl":
            refusal = return_breach(promises, route)
            if refusal is not None:
                raise refusal
        out.append(Flight(route, float(cruise), ending))
    return out
