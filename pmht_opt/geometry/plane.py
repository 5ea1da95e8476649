"""Plane geometry on paths: distances to polylines and crossings between them."""

from __future__ import annotations

import numpy as np

#: Segments compared per block when counting crossings (bounds the memory to block x T).
_BLOCK = 256


def point_polyline_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance from each of ``points (K, 2)`` to the polyline through ``path (T+1, 2)``."""
    a = path[:-1]
    d = np.diff(path, axis=0)
    len2 = np.einsum("ij,ij->i", d, d)
    out = np.empty(points.shape[0])
    for start in range(0, points.shape[0], _BLOCK):
        pts = points[start : start + _BLOCK]
        rel = pts[:, None, :] - a[None, :, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.einsum("kti,ti->kt", rel, d) / len2
        s = np.clip(np.nan_to_num(s, nan=0.0), 0.0, 1.0)
        diff = rel - s[..., None] * d[None, :, :]
        out[start : start + _BLOCK] = np.sqrt(np.min(np.einsum("kti,kti->kt", diff, diff), axis=1))
    if path.shape[0] == 1:
        out = np.hypot(points[:, 0] - path[0, 0], points[:, 1] - path[0, 1])
    return out


def _orient(
    ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray, cx: np.ndarray, cy: np.ndarray
) -> np.ndarray:
    return np.sign((bx - ax) * (cy - ay) - (by - ay) * (cx - ax))


def segments_cross(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Whether segments ``p1-p2`` and ``q1-q2`` cross properly (broadcasting over leading axes)."""
    o1 = _orient(p1[..., 0], p1[..., 1], p2[..., 0], p2[..., 1], q1[..., 0], q1[..., 1])
    o2 = _orient(p1[..., 0], p1[..., 1], p2[..., 0], p2[..., 1], q2[..., 0], q2[..., 1])
    o3 = _orient(q1[..., 0], q1[..., 1], q2[..., 0], q2[..., 1], p1[..., 0], p1[..., 1])
    o4 = _orient(q1[..., 0], q1[..., 1], q2[..., 0], q2[..., 1], p2[..., 0], p2[..., 1])
    return (o1 * o2 < 0) & (o3 * o4 < 0)


def count_crossings(paths: np.ndarray) -> int:
    """Number of proper intersections between segments of different paths in ``paths (M, T+1, 2)``."""
    M = paths.shape[0]
    total = 0
    lo = np.minimum(paths[:, :-1], paths[:, 1:])
    hi = np.maximum(paths[:, :-1], paths[:, 1:])
    for i in range(M):
        for j in range(i + 1, M):
            a1, a2 = paths[i, :-1], paths[i, 1:]
            b1, b2 = paths[j, :-1], paths[j, 1:]
            for s in range(0, a1.shape[0], _BLOCK):
                sl = slice(s, s + _BLOCK)
                # Bounding boxes first: most segment pairs are far apart.
                near = np.all(
                    (lo[i, sl, None, :] <= hi[j, None, :, :]) & (lo[j, None, :, :] <= hi[i, sl, None, :]),
                    axis=-1,
                )
                ia, ib = np.nonzero(near)
                if ia.size:
                    ia = ia + s
                    total += int(np.count_nonzero(segments_cross(a1[ia], a2[ia], b1[ib], b2[ib])))
    return total
