"""Coverage measured on the segments of polylines, with the study's own geometry.

A locale (a target) is covered when some path passes within its radius: the distance from its centre
to the nearest *segment* between consecutive points of any polyline, not to the points themselves
(a straight tour has few vertices, and a smooth path may pass a locale between two samples). This
module uses nothing of the library's geometry, so a study can check a plan independently of the
planner's own verification.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: A locale counts as covered up to this relative slack on its radius (a plan made to touch a disc at
#: exactly its radius meets it to its solver's tolerance).
RTOL = 1e-6
#: Centres measured at once against every segment (bounds the memory of one block).
BLOCK = 256


def segment_distances(centres: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """``(N,)`` distance of each of ``centres (N, 2)`` to the segments of ``polyline (K, 2)`` (one
    point: the distance to it)."""
    pts = np.asarray(polyline, dtype=float).reshape(-1, 2)
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    if pts.shape[0] == 0:
        return np.full(c.shape[0], np.inf)
    if pts.shape[0] == 1:
        return np.hypot(*(c - pts[0]).T)
    a, d = pts[:-1], np.diff(pts, axis=0)
    dd = np.einsum("ij,ij->i", d, d)
    out = np.empty(c.shape[0])
    for lo in range(0, c.shape[0], BLOCK):
        rel = c[lo : lo + BLOCK, None, :] - a[None]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = np.where(dd > 0, np.einsum("nsk,sk->ns", rel, d) / np.where(dd > 0, dd, 1.0), 0.0)
        u = np.clip(u, 0.0, 1.0)
        off = rel - u[..., None] * d[None]
        out[lo : lo + BLOCK] = np.hypot(off[..., 0], off[..., 1]).min(axis=1)
    return out


def relative_gaps(
    centres: np.ndarray, radii: np.ndarray | float, polylines: Sequence[np.ndarray]
) -> np.ndarray:
    """``(N,)`` each locale's distance to the nearest polyline minus its radius, over its radius
    (``<= RTOL``: covered; negative: inside its disc)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radii, dtype=float), (c.shape[0],))
    if c.shape[0] == 0:
        return np.zeros(0)
    dist = (
        np.min([segment_distances(c, p) for p in polylines], axis=0) if polylines else np.full(len(c), np.inf)
    )
    return np.asarray((dist - r) / r)


def covered_fraction(gaps: np.ndarray) -> float:
    """Fraction of locales whose relative gap is at most :data:`RTOL` (1 for none)."""
    return float(np.mean(gaps <= RTOL)) if gaps.size else 1.0


__all__ = ["RTOL", "covered_fraction", "relative_gaps", "segment_distances"]
