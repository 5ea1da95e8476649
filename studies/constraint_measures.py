"""Hard constraints measured on a plan's positions with the study's own geometry, independently of the
solvers and of the planner's verification (:mod:`studies.constraints_stress`).

- speed: ``max_t |p_t - p_{t-1}| / dt`` against ``vmax`` (the displacement per step, what a user
  measures);
- acceleration: ``max_t |p_{t+1} - 2 p_t + p_{t-1}| / dt^2`` against ``amax``;
- keep-out zones: every *segment* between consecutive positions against the true disc or polygon
  (segment-to-centre distance; a separating-axis test for the polygon), the depth of the worst entry;
- visits: each locale's distance to the nearest platform's path (segments) against the radius;
- area bounds: positions outside the box.

Each figure is relative to the constraint's size (the limit, the radius, the box's side).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

import pmht_opt as po
from pmht_opt.geometry import point_polyline_distance


def _segment_point_distance(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distance from point ``c`` to each segment ``a[i] b[i]``."""
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > 0, np.einsum("ij,ij->i", c - a, ab) / denom, 0.0)
    s = np.clip(s, 0.0, 1.0)
    return np.linalg.norm(a + s[:, None] * ab - c, axis=1)


def _segment_polygon_depth(a: np.ndarray, b: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """How deep each segment ``a[i] b[i]`` reaches into the convex polygon (0 if it stays outside).

    Separating axes: the polygon's edge normals and the segment's normal. The depth is the smallest
    overlap of the projections over those axes (0 when one of them separates).
    """
    axes = []
    k = len(poly)
    for i in range(k):
        e = poly[(i + 1) % k] - poly[i]
        axes.append(np.broadcast_to(np.array([-e[1], e[0]]) / np.linalg.norm(e), a.shape))
    seg = b - a
    length = np.linalg.norm(seg, axis=1, keepdims=True)
    normal = np.where(length > 0, np.column_stack([-seg[:, 1], seg[:, 0]]) / np.maximum(length, 1e-300), 0.0)
    axes.append(normal)
    depth = np.full(a.shape[0], np.inf)
    for ax in axes:
        pa, pb = np.einsum("ij,ij->i", a, ax), np.einsum("ij,ij->i", b, ax)
        pp = poly @ ax.T  # (k, S)
        overlap = np.minimum(np.maximum(pa, pb), pp.max(axis=0)) - np.maximum(
            np.minimum(pa, pb), pp.min(axis=0)
        )
        depth = np.minimum(depth, overlap)
    return np.maximum(depth, 0.0)


def measure(sc: po.Scenario, positions: np.ndarray, constraints: Sequence[po.Constraint]) -> dict[str, float]:
    """Each hard constraint's worst violation on ``positions`` ``(M, T+1, 2)``, relative to its size."""
    out: dict[str, float] = {}
    dt = sc.dt
    a, b = positions[:, :-1].reshape(-1, 2), positions[:, 1:].reshape(-1, 2)
    for con in constraints:
        if con.soft:
            continue
        if isinstance(con, po.SpeedLimit):
            vmax = float(np.asarray(con.limit).min())
            step = np.linalg.norm(np.diff(positions, axis=1), axis=2) / dt
            value = float(step.max() - vmax) / vmax
        elif isinstance(con, po.AccelLimit):
            amax = float(np.asarray(con.limit).min())
            acc = np.linalg.norm(np.diff(positions, 2, axis=1), axis=2) / dt**2
            value = float(acc.max() - amax) / amax
        elif isinstance(con, po.CircleObstacle):
            keep_out = con.radius + con.margin
            d = _segment_point_distance(a, b, np.asarray(con.center, dtype=float))
            value = float(keep_out - d.min()) / keep_out
        elif isinstance(con, po.PolygonObstacle):
            poly = np.asarray(con.vertices, dtype=float)
            size = float(np.max(np.linalg.norm(poly - poly.mean(axis=0), axis=1)))
            value = float(_segment_polygon_depth(a, b, poly).max()) / size
        elif isinstance(con, po.VisitAll):
            radii = np.broadcast_to(con.radius_for(sc), (sc.n_locales,))
            miss = np.min([point_polyline_distance(sc.locales, p) for p in positions], axis=0)
            value = float(np.max((miss - radii) / radii))
        elif isinstance(con, po.AreaBounds):
            lo = np.array([con.box[0], con.box[2]])
            hi = np.array([con.box[1], con.box[3]])
            size = float(np.max(hi - lo))
            value = float(np.max(np.maximum(lo - positions, positions - hi))) / size
        else:  # pragma: no cover - every case above uses these kinds
            continue
        out[con.name] = max(out.get(con.name, -np.inf), value)
    return out
