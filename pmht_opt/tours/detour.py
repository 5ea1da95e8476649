r"""The cheapest way through one disc between two fixed points: the move cost of the local searches.

For fixed neighbours :math:`a, b` the best point of disc :math:`(z, \rho)` solves

.. math:: f(a, b) = \min_{\lVert p - z\rVert \le \rho} \lVert a - p\rVert + \lVert p - b\rVert .

If the segment :math:`[a, b]` meets the disc, :math:`f = \lVert a - b\rVert` (the point of the segment
closest to :math:`z` is optimal). Otherwise the optimum lies on the circle, on the arc between the
directions from :math:`z` to :math:`a` and to :math:`b` (the two unit vectors' shorter arc), where
the objective is unimodal in the angle (the sum of two distances to points outside a disc, restricted
to its facing arc); a fixed number of safeguarded Newton steps on the angle finds it, vectorised over
any number of (a, b, disc) triples. The *detour* :math:`f - \lVert a - b \rVert` is the
price of inserting the disc between :math:`a` and :math:`b`.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.geometry import inner

#: Safeguarded Newton steps (quadratic convergence; bisection where Newton would leave the bracket).
STEPS = 12


def best_points(a: np.ndarray, b: np.ndarray, z: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
        # Safeguarded Newton on s in [0, 1] (angle ua + s span): the slope is negative at s = 0 (the
        # point nearest a) and positive at s = 1, so [lo, hi] always brackets the minimum.
        lo = np.zeros_like(ua)
        hi = np.ones_like(ua)
        wa = np.hypot(*(am - zm).T)
        wb = np.hypot(*(bm - zm).T)
        x = wb / np.maximum(wa + wb, 1e-300)  # start nearer the nearer point's direction
        zx, zy = zm[:, 0], zm[:, 1]
        ax, ay, bx, by = am[:, 0] - zx, am[:, 1] - zy, bm[:, 0] - zx, bm[:, 1] - zy
        for _ in range(STEPS):
            ang = ua + x * span
            cx, cy = np.cos(ang), np.sin(ang)
            pax, pay = rm * cx - ax, rm * cy - ay
            pbx, pby = rm * cx - bx, rm * cy - by
            na = np.maximum(np.hypot(pax, pay), 1e-300)
            nb = np.maximum(np.hypot(pbx, pby), 1e-300)
            ta = (cx * pay - cy * pax) / na  # tangent (-sin, cos) . (p - a) / |p - a|
            tb = (cx * pby - cy * pbx) / nb
            ra = (cx * pax + cy * pay) / na
            rb = (cx * pbx + cy * pby) / nb
            gs = rm * (ta + tb) * span  # slope in s
            hs = (rm * (-ra - rb) + rm**2 * ((1 - ta**2) / na + (1 - tb**2) / nb)) * span**2
            lo = np.where(gs < 0, x, lo)
            hi = np.where(gs > 0, x, hi)
            step = np.where(hs > 0, x - gs / np.where(hs > 0, hs, 1.0), -1.0)
            x = np.where((step > lo) & (step < hi), step, (lo + hi) / 2)
        ang = ua + x * span
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
