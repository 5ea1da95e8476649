r"""The cheapest way through one disc between two fixed points: the move cost of the local searches.

For fixed neighbours :math:`a, b` the best point of disc :math:`(z, \rho)` solves

.. math:: f(a, b) = \min_{\lVert p - z\rVert \le \rho} \lVert a - p\rVert + \lVert p - b\rVert .

If the segment :math:`[a, b]` meets the disc, :math:`f = \lVert a - b\rVert` (the point of the segment
closest to :math:`z` is optimal). Otherwise the optimum lies on the circle, on the arc between the
directions from :math:`z` to :math:`a` and to :math:`b` (the two unit vectors' shorter arc), where
the objective is unimodal in the angle (the sum of two distances to points outside a disc, restricted
to its facing arc); a fixed number of golden-section steps finds it to about ``1e-9`` of the arc, and is
vectorised over any number of (a, b, disc) triples. The *detour* :math:`f - \lVert a - b \rVert` is the
price of inserting the disc between :math:`a` and :math:`b`.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.geometry import inner

_GOLD = (np.sqrt(5.0) - 1.0) / 2.0
#: Golden-section steps: the bracket shrinks to 0.618**44, about 1e-9 of the arc.
STEPS = 44


def best_points(
    a: np.ndarray, b: np.ndarray, z: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Best points ``(n, 2)`` and costs ``(n,)`` :math:`f(a, b)` for broadcastable ``(n, 2)`` inputs.

    ``a``, ``b``, ``z`` of shape ``(n, 2)`` (or broadcastable) and ``r`` of shape ``(n,)``.
    """
    a, b, z = np.broadcast_arrays(a, b, z)
    r = np.broadcast_to(r, a.shape[:-1])
    d = b - a
    dd = np.einsum("...k,...k->...", d, d)
    t = np.clip(np.einsum("...k,...k->...", z - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    t = np.where(dd > 0, t, 0.0)
    foot = a + t[..., None] * d
    off = foot - z
    gap = np.hypot(off[..., 0], off[..., 1])
    hit = gap <= inner(r)
    point = foot.copy()
    cost = np.sqrt(dd)
    miss = ~hit
    if miss.any():
        am, bm, zm, rm = a[miss], b[miss], z[miss], r[miss]
        ua = np.arctan2(am[:, 1] - zm[:, 1], am[:, 0] - zm[:, 0])
        ub = np.arctan2(bm[:, 1] - zm[:, 1], bm[:, 0] - zm[:, 0])
        span = np.mod(ub - ua + np.pi, 2 * np.pi) - np.pi  # signed shorter arc from a's to b's direction
        lo = np.zeros_like(ua)
        hi = np.ones_like(ua)

        def f(s: np.ndarray) -> np.ndarray:
            ang = ua + s * span
            p = zm + rm[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
            return np.hypot(*(am - p).T) + np.hypot(*(bm - p).T)

        x1 = hi - _GOLD * (hi - lo)
        x2 = lo + _GOLD * (hi - lo)
        f1, f2 = f(x1), f(x2)
        for _ in range(STEPS):
            left = f1 <= f2
            hi = np.where(left, x2, hi)
            lo = np.where(left, lo, x1)
            x2n = np.where(left, x1, lo + _GOLD * (hi - lo))
            x1n = np.where(left, hi - _GOLD * (hi - lo), x2)
            fx = f(np.where(left, x1n, x2n))
            f1, f2 = np.where(left, fx, f2), np.where(left, f1, fx)
            x1, x2 = x1n, x2n
        s = (lo + hi) / 2
        ang = ua + s * span
        pm = zm + inner(rm)[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        point[miss] = pm
        cost[miss] = np.hypot(*(am - pm).T) + np.hypot(*(bm - pm).T)
    return point, cost


def reach_points(a: np.ndarray, z: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of the discs to ``a`` and their distances (the price of an open route's new end)."""
    a, z = np.broadcast_arrays(a, z)
    off = a - z
    norm = np.hypot(off[..., 0], off[..., 1])
    rin = inner(np.asarray(r, dtype=float))
    inside = norm <= rin
    scale = np.where(inside, 1.0, rin / np.where(norm > 0, norm, 1.0))
    return z + off * scale[..., None], np.maximum(norm - rin, 0.0)
