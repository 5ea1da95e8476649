r"""Exact turn points for the key discs: the cone program, covering in passing, and the final routes.

The local searches price moves with the other turn points fixed; the cone program of
:mod:`pmht_opt.tours.socp` then moves all turn points of a route together to the shortest polyline for
its order of key discs. That polyline may stop meeting a disc that was covered in passing; such a disc
becomes a key at the place where the new polyline passes closest to it and the program is solved
again, until every disc is met (or the old tour is kept). Keys whose turn point is no turn (the
detour :math:`\lVert a - p\rVert + \lVert p - b\rVert - \lVert a - b\rVert` through it is nil) are
dropped: the polyline is the same without them, and the next solve is freer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmht_opt.tours.geometry import passing, pull_inside
from pmht_opt.tours.socp import disc_sequence
from pmht_opt.tours.tour import Tour

#: A vertex is a turn when the detour through it exceeds this (unit box).
TURN = 1e-8
#: Key sequences whose turn points a layout keeps (:attr:`~pmht_opt.tours.tour.Layout.solved`); all
#: are forgotten when there are more.
KEEP = 50_000


def solve_keys(tour: Tour) -> Tour:
    """The same keys with the cone program's turn points (coverage in passing not checked); a route
    whose key sequence the layout has seen before gets the turn points solved then."""
    lay = tour.layout
    out = tour.copy()
    for m, keys in enumerate(tour.keys):
        key = (m, tuple(keys))
        pts = lay.solved.get(key)
        if pts is None:
            idx = np.array(keys, dtype=np.intp)
            pts, _ = disc_sequence(lay.starts[m], lay.centres[idx], lay.radii[idx], bool(lay.closed[m]))
            if len(lay.solved) >= KEEP:
                lay.solved.clear()
            lay.solved[key] = pts
        out.pts[m] = pts.copy()
    return out


def thin(tour: Tour) -> Tour:
    """The tour without keys whose turn point is no turn.

    Dropping them leaves the polyline as it is up to the detour threshold :data:`TURN`; a dropped key
    whose disc that small change leaves unmet is kept (and the tour returned as it was if some other
    disc is lost).
    """
    out = tour.copy()
    dropped: list[np.ndarray] = []
    for m in range(len(out.keys)):
        V = out.verts(m)
        if len(out.keys[m]) == 0:
            dropped.append(np.zeros(0, dtype=bool))
            continue
        a, p, b = V[:-2], V[1:-1], V[2:]
        detour = np.hypot(*(p - a).T) + np.hypot(*(b - p).T) - np.hypot(*(b - a).T)
        if not out.layout.closed[m]:
            detour[-1] = np.inf  # an open route's end point is where it stops
        dropped.append(detour <= TURN)
    for _ in range(2):
        cand = tour.copy()
        for m, drop in enumerate(dropped):
            cand.keys[m] = [k for k, f in zip(tour.keys[m], drop, strict=True) if not f]
            cand.pts[m] = tour.pts[m][~drop]
        lost = np.flatnonzero(~cand.covered())
        if lost.size == 0:
            return cand
        for m, drop in enumerate(dropped):  # keep the dropped keys whose disc was lost
            drop &= ~np.isin(np.array(tour.keys[m], dtype=np.intp), lost)
    return tour


def refine(tour: Tour, objective: str = "distance", rounds: int = 4) -> Tour:
    """The cone program's polyline for the tour's keys, made to meet every disc; never worse (total
    length, or longest route then total for ``objective="time"``)."""
    lay = tour.layout
    cur = tour
    for _ in range(rounds):
        cur = solve_keys(cur)
        miss = np.flatnonzero(~cur.covered())
        if miss.size == 0:
            cur = thin(cur)
            return cur if cur.score(objective) < tour.score(objective) else tour
        # Each lost disc becomes a key where the route passing closest to it passes.
        table = [passing(lay.centres[miss], cur.verts(m)) for m in range(len(cur.keys))]
        dist = np.stack([t.distance for t in table])
        route = np.argmin(dist, axis=0)
        cur = cur.copy()
        for m in range(len(cur.keys)):
            add = miss[route == m]
            if add.size == 0:
                continue
            pos = np.concatenate(
                [np.arange(1, len(cur.keys[m]) + 1, dtype=float), table[m].position[route == m]]
            )
            merged = np.concatenate([np.array(cur.keys[m], dtype=np.intp), add])
            near = pull_inside(table[m].point[route == m], lay.centres[add], lay.radii[add])
            pts = np.vstack([cur.pts[m], near])
            order = np.argsort(pos, kind="stable")
            cur.keys[m] = [int(k) for k in merged[order]]
            cur.pts[m] = pts[order]
    return tour


@dataclass(frozen=True)
class Placed:
    """Every disc placed on the tour: its route, its visit point and the routes' full orders."""

    routes: list[np.ndarray]
    points: np.ndarray


def place(tour: Tour) -> Placed:
    """Each disc on the route whose polyline passes closest, at that closest point; routes in order."""
    lay = tour.layout
    M = len(tour.keys)
    table = [passing(lay.centres, tour.verts(m)) for m in range(M)]
    dist = np.stack([t.distance for t in table])
    route = np.argmin(dist, axis=0)
    points = np.zeros_like(lay.centres)
    routes = []
    for m in range(M):
        mine = np.flatnonzero(route == m)
        routes.append(mine[np.argsort(table[m].position[mine], kind="stable")])
        points[mine] = table[m].point[mine]
    return Placed(routes=routes, points=points)
