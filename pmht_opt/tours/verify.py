"""An independent check of an answer: every disc met on the segments of its route, routes consistent.

It uses nothing of the search: the polylines are rebuilt from the answer's turn points, and each
target's distance to them is measured against the problem's own radius.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.exceptions import SolverError
from pmht_opt.tours.problem import DiscTours

#: Relative slack of the coverage test.
RTOL = 1e-9


def _distance_to_polyline(z: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Distance of each point ``z`` ``(n, 2)`` to the polyline through ``verts`` (one vertex: a point)."""
    if verts.shape[0] == 1:
        return np.hypot(*(z - verts[0]).T)
    a, b = verts[:-1], verts[1:]
    d = b - a
    dd = (d**2).sum(axis=1)
    rel = z[:, None, :] - a[None]
    t = np.clip((rel * d[None]).sum(-1) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    off = rel - t[..., None] * d[None]
    return np.hypot(off[..., 0], off[..., 1]).min(axis=1)


def coverage_gaps(tours: DiscTours, rtol: float = RTOL) -> np.ndarray:
    """``(N,)`` distance of each centre to the nearest route's polyline minus its radius times
    ``1 + rtol`` (positive: not covered)."""
    prob = tours.problem
    if prob.n_targets == 0:
        return np.zeros(0)
    dist = np.min(
        [_distance_to_polyline(prob.centres, tours.vertices(m)) for m in range(prob.n_vehicles)], axis=0
    )
    return dist - prob.radii * (1 + rtol)


def check_tours(tours: DiscTours, rtol: float = RTOL) -> None:
    """Raise SolverError unless every target is covered, the routes, points and lengths agree, and
    every route's polyline is within its cap (``problem.max_lengths``, to ``rtol``)."""
    prob = tours.problem
    N = prob.n_targets
    listed = (
        np.concatenate([np.asarray(r, dtype=np.intp) for r in tours.routes]) if tours.routes else np.zeros(0)
    )
    if len(tours.routes) != prob.n_vehicles or np.sort(listed).tolist() != list(range(N)):
        raise SolverError("the routes do not list every target exactly once.")
    gaps = coverage_gaps(tours, rtol)
    bad = np.flatnonzero(gaps > 0)
    if bad.size:
        raise SolverError(
            f"{bad.size} target(s) not met within their radius, e.g. target {bad[0]} by {gaps[bad[0]]:.3g}."
        )
    scale = max(
        float(np.ptp(np.vstack([prob.starts, prob.centres]))), float(prob.radii.max(initial=0.0)), 1e-300
    )
    for m, route in enumerate(tours.routes):
        route = np.asarray(route, dtype=np.intp)
        if route.size == 0:
            continue
        verts = tours.vertices(m)
        off = np.hypot(*(tours.points[route] - prob.centres[route]).T) - prob.radii[route] * (1 + rtol)
        on = _distance_to_polyline(tours.points[route], verts)
        if off.max() > 0 or on.max() > rtol * scale:
            raise SolverError(f"route {m}: a visit point is off its disc or off the route.")
        length = float(np.hypot(*np.diff(verts, axis=0).T).sum())
        if abs(length - tours.lengths[m]) > 1e-9 * max(length, scale):
            raise SolverError(
                f"route {m}: reported length {tours.lengths[m]} is not its polyline's {length}."
            )
    caps = prob.caps
    if caps is not None:
        for m in range(prob.n_vehicles):
            length = float(np.hypot(*np.diff(tours.vertices(m), axis=0).T).sum())
            if length > caps[m] * (1 + rtol):
                raise SolverError(f"route {m}: its length {length:.10g} is over its cap {caps[m]:.10g}.")
