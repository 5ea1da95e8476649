"""Flown legs checked against a plan's promises, on their own exact geometry.

A drone given waypoints flies the straight legs between them, not the planned samples. The planner
keeps its promises on its own path (:mod:`pmht_opt.verify`); an export keeps them only if the legs it
writes keep them too. This module measures legs ``a[k] -> b[k]`` (``(K, 2)`` each, in the plane)
against each promise with segment geometry of its own: nothing here calls a constraint's methods or the
planner's linearisations, only reads the shapes (a centre and radius, corners, a box).

Keep-out zones (:class:`~pmht_opt.constraints.CircleObstacle`, :class:`~pmht_opt.constraints.PolygonObstacle`)
    A leg's *depth* into a zone is the largest, over the points ``p`` of the leg, of how far ``p`` lies
    inside: ``radius - |p - c|`` for a disc, ``min_k (d_k - n_k . p)`` for a convex polygon with outward
    unit normals ``n_k`` and offsets ``d_k`` (the distance to the nearest edge's line, which inside a
    convex polygon is the distance to its boundary). For a disc the deepest point of the leg is the
    point nearest the centre (the projection of ``c`` on the segment, clamped to it). For a polygon,
    the points of the leg deeper than ``t`` are those inside the polygon shrunk by ``t``, the
    intersection of the half-planes ``n_k . p <= d_k - t``; clipping the segment against them
    (Cyrus-Beck) leaves an interval of the leg, empty exactly when the depth is below ``t``, and a
    bisection on ``t`` finds the depth to the last bits.
Areas (:class:`~pmht_opt.constraints.AreaBounds`, :class:`~pmht_opt.constraints.StayNear`)
    A box is convex: a leg lies in it exactly when both its ends do, so its *excess* is the larger of
    the two ends' distances outside.
Coverage (the ``coverage`` and ``smoothed`` planners, and any hard :class:`~pmht_opt.constraints.VisitAll`)
    Site ``n`` is covered when some leg of some platform passes within its radius: the distance from
    the site to the segment, at the clamped projection.

Tolerances. The planned path keeps each promise to the planner's own tolerance
(:func:`pmht_opt.verify.tolerance`, relative to the constraint's size; coverage to
:data:`~pmht_opt.geometry.COVERAGE_RTOL` of the radius), so legs through points of the path can keep it
to no less. Waypoints are measured as the file holds them, whose coordinates are rounded
(``resolution``: 1e-9 degrees shift a point by at most 0.08 mm); that rounding is added to every
tolerance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.constraints import AreaBounds, CircleObstacle, PolygonObstacle, StayNear, VisitAll
from pmht_opt.geometry.coverage import COVERAGE_RTOL
from pmht_opt.verify import DEFAULT_RTOL, RTOL, tolerance

#: Planners whose plans promise that every site is within its radius of some path.
COVERING_PLANNERS = ("coverage", "smoothed")
#: Bisection steps of a polygon's depth: halves the bracket down to double precision.
_BISECTIONS = 64


def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(P, K)`` distance from each of ``points (P, 2)`` to each segment ``a[k] -> b[k]``.

    The nearest point of a segment to ``p`` is ``a + s (b - a)`` with ``s`` the projection
    ``(p - a) . (b - a) / |b - a|^2`` clamped to ``[0, 1]`` (``s = 0`` for a segment of no length).
    """
    p = np.asarray(points, dtype=float)[:, None, :]
    d = b - a
    len2 = np.einsum("ki,ki->k", d, d)
    s = np.einsum("pki,ki->pk", p - a[None], d) / np.where(len2 > 0, len2, 1.0)
    s = np.clip(np.where(len2 > 0, s, 0.0), 0.0, 1.0)
    gap = p - (a[None] + s[..., None] * d[None])
    return np.sqrt(np.einsum("pki,pki->pk", gap, gap))


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """``(P,)`` distance from each of ``points (P, 2)`` to the polyline ``line (K, 2)`` (a single
    point when ``K = 1``), a block of points at a time."""
    line = np.asarray(line, dtype=float)
    a, b = (line[:-1], line[1:]) if line.shape[0] > 1 else (line, line)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    block = max(1, 2**20 // max(1, a.shape[0]))
    return np.concatenate(
        [segment_distance(pts[i : i + block], a, b).min(axis=1) for i in range(0, len(pts), block)]
        or [np.zeros(0)]
    )


@dataclass(frozen=True, eq=False)
class Zone:
    """One promise about where legs go: keep out of a disc or a convex polygon, or stay in a box.

    Attributes
    ----------
    name
        The constraint's name, for messages.
    platforms
        The platforms it binds.
    tolerance
        The largest depth (or excess) that still keeps it.
    center, radius
        A keep-out disc.
    vertices
        A keep-out convex polygon's corners ``(E, 2)``.
    box
        ``(xmin, xmax, ymin, ymax)`` that legs must stay in.
    """

    name: str
    platforms: frozenset[int]
    tolerance: float
    center: np.ndarray | None = None
    radius: float = 0.0
    vertices: np.ndarray | None = None
    box: np.ndarray | None = None

    def depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(K,)`` how far each leg ``a[k] -> b[k]`` breaks the zone (0: not at all; module notes)."""
        if self.center is not None:
            near = segment_distance(self.center[None], a, b)[0]
            return np.maximum(self.radius - near, 0.0)
        if self.box is not None:
            xmin, xmax, ymin, ymax = self.box
            out = [
                np.maximum.reduce([xmin - e[:, 0], e[:, 0] - xmax, ymin - e[:, 1], e[:, 1] - ymax])
                for e in (a, b)
            ]
            return np.maximum(np.maximum(*out), 0.0)
        assert self.vertices is not None
        return _polygon_depth(self.vertices, a, b)


def _half_planes(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals ``(E, 2)`` and offsets ``(E,)`` of a convex polygon: inside is
    ``n_k . p <= d_k`` for every edge, whichever way its corners turn."""
    v = np.asarray(vertices, dtype=float)
    area2 = float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    if area2 < 0:
        v = v[::-1]
    edge = np.roll(v, -1, axis=0) - v
    normals = np.stack([edge[:, 1], -edge[:, 0]], axis=1) / np.hypot(edge[:, 0], edge[:, 1])[:, None]
    return normals, np.einsum("ki,ki->k", normals, v)


def _clipped(
    normals: np.ndarray, offsets: np.ndarray, a: np.ndarray, b: np.ndarray, t: np.ndarray
) -> np.ndarray:
    """Whether some point of each leg ``a[k] -> b[k]`` is ``t[k]`` or more inside the polygon: Cyrus-Beck
    clipping of ``a + s (b - a)``, ``s in [0, 1]``, against ``n_j . p <= d_j - t``."""
    slope = (b - a) @ normals.T  # (K, E): n_j . (b - a)
    room = offsets[None, :] - t[:, None] - a @ normals.T  # (K, E): d_j - t - n_j . a; need s slope <= room
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = room / slope
    lo = np.max(np.where(slope < 0, ratio, -np.inf), axis=1, initial=0.0)
    hi = np.min(np.where(slope > 0, ratio, np.inf), axis=1, initial=1.0)
    parallel_ok = np.all((slope != 0) | (room >= 0), axis=1)
    return parallel_ok & (lo <= hi)


def _polygon_depth(vertices: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(K,)`` the depth of each leg into a convex polygon: a bisection on ``t`` of the clipping
    test, from ``[0, extent]`` (no point of a polygon is deeper than its extent) to double precision.
    A leg that misses the polygon, or only touches its boundary, has depth 0."""
    normals, offsets = _half_planes(vertices)
    lo = np.zeros(a.shape[0])
    hi = np.full(a.shape[0], float(np.ptp(vertices, axis=0).max()))
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        deeper = _clipped(normals, offsets, a, b, mid)
        lo = np.where(deeper, mid, lo)
        hi = np.where(deeper, hi, mid)
    return lo


@dataclass(frozen=True, eq=False)
class Coverage:
    """The promise that every site is within its radius of some leg.

    Attributes
    ----------
    sites
        ``(N, 2)`` the sites.
    radii
        ``(N,)`` each site's promised radius.
    slack
        ``(N,)`` how far beyond its radius a site may lie and still be covered.
    """

    sites: np.ndarray
    radii: np.ndarray
    slack: np.ndarray

    def gaps(self, lines: Sequence[np.ndarray]) -> np.ndarray:
        """``(N,)`` how far each site lies beyond its radius plus slack from every one of ``lines``
        (polylines ``(K, 2)``); 0 where covered."""
        near = np.min([polyline_distance(self.sites, line) for line in lines], axis=0)
        return np.maximum(near - self.radii - self.slack, 0.0)


@dataclass(frozen=True)
class Promises:
    """What a plan promises about where its platforms go (:func:`plan_promises`)."""

    zones: tuple[Zone, ...]
    coverage: Coverage | None

    def zones_of(self, platform: int) -> list[Zone]:
        """The zones binding ``platform``."""
        return [z for z in self.zones if platform in z.platforms]

    def first_breach(self, platform: int, points: np.ndarray) -> tuple[int, Zone, float] | None:
        """``(leg, zone, depth)`` of the first leg of ``platform`` flying through ``points (K, 2)``
        that breaks a zone beyond its tolerance (legs numbered from 0), or ``None``."""
        if points.shape[0] < 2:
            return None
        a, b = points[:-1], points[1:]
        found: tuple[int, Zone, float] | None = None
        for zone in self.zones_of(platform):
            depth = zone.depth(a, b)
            bad = np.flatnonzero(depth > zone.tolerance)
            if bad.size and (found is None or bad[0] < found[0]):
                found = (int(bad[0]), zone, float(depth[bad[0]]))
        return found


def plan_promises(result: Any, resolution: float = 0.0) -> Promises:
    """The promises of ``result`` (a :class:`~pmht_opt.PlanResult`) that flown legs must keep.

    Every hard keep-out zone and box among its constraints, with the planner's tolerance for it plus
    ``resolution`` (the rounding of the coordinates the legs are measured on); and, for the planners
    that guarantee coverage (:data:`COVERING_PLANNERS`) or with a hard
    :class:`~pmht_opt.constraints.VisitAll`, every site within its radius: the ``coverage`` planner's
    radii are its scenario's; a visit constraint's are its own (the ``smoothed`` planner's visit
    radius); with several, the smallest.
    """
    sc = result.scenario
    backend = str(result.solver)
    zones: list[Zone] = []
    visit_radii: list[np.ndarray] = []
    for con in result.constraints:
        if con.soft:
            continue
        bound = frozenset(con.applies_to(sc))
        tol = tolerance(backend, con, sc) + resolution
        if isinstance(con, CircleObstacle):
            zones.append(Zone(con.name, bound, tol, center=np.asarray(con.center, float), radius=con.radius))
        elif isinstance(con, PolygonObstacle):
            zones.append(Zone(con.name, bound, tol, vertices=np.asarray(con.vertices, float)))
        elif isinstance(con, AreaBounds):
            zones.append(Zone(con.name, bound, tol, box=np.asarray(con.box, float)))
        elif isinstance(con, StayNear):
            for m in bound:
                zones.append(Zone(con.name, frozenset({m}), tol, box=np.asarray(con.box(sc, m), float)))
        elif isinstance(con, VisitAll):
            visit_radii.append(np.broadcast_to(np.asarray(con.radius_for(sc), float), (sc.n_locales,)))
    coverage = None
    if visit_radii or result.planner in COVERING_PLANNERS:
        if visit_radii:
            radii = np.min(visit_radii, axis=0)
        else:
            radius = result.extras.get("visit_radius") if result.planner == "smoothed" else None
            radii = np.broadcast_to(
                np.asarray(sc.radii if radius is None else radius, float), (sc.n_locales,)
            )
        rtol = max(COVERAGE_RTOL, RTOL.get(backend, DEFAULT_RTOL))
        coverage = Coverage(np.asarray(sc.locales, float), np.array(radii), rtol * radii + resolution)
    return Promises(tuple(zones), coverage)


def deviation(legs: np.ndarray, path: np.ndarray, spacing: float) -> float:
    """The largest distance between the polylines ``legs`` and ``path`` ((K, 2) each): the Hausdorff
    distance, the larger of the two directed distances (how far a point of one can be from the other).

    Distance to a polyline is 1-Lipschitz along the other, so measuring it at points no more than
    ``spacing`` apart along each polyline (every vertex among them) finds it to within ``spacing / 2``.
    """
    return max(
        float(np.max(polyline_distance(_densified(legs, spacing), path))),
        float(np.max(polyline_distance(_densified(path, spacing), legs))),
    )


def _densified(line: np.ndarray, spacing: float) -> np.ndarray:
    """The vertices of ``line`` and points between them at most ``spacing`` apart."""
    line = np.asarray(line, dtype=float)
    if line.shape[0] < 2:
        return line
    seg = np.diff(line, axis=0)
    pieces = np.maximum(1, np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / spacing)).astype(int)
    out = [line[:1]]
    for k, n in enumerate(pieces):
        s = np.arange(1, n + 1)[:, None] / n
        out.append(line[k] + s * seg[k])
    return np.concatenate(out)
