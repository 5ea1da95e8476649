r"""The cheapest way through one disc between two fixed points: the move cost of the local searches.

For fixed neighbours :math:`a, b` the best point of disc :math:`(z, \rho)` solves

.. math:: f(a, b) = \min_{\lVert p - z\rVert \le \rho} \lVert a - p\rVert + \lVert p - b\rVert .

If the segment :math:`[a, b]` meets the disc, :math:`f = \lVert a - b\rVert` (the point of the segment
closest to :math:`z` is optimal). Otherwise the optimum lies on the circle, on the arc between the
directions from :math:`z` to :math:`a` and to :math:`b` (the two unit vectors' shorter arc), where
the objective is unimodal in the angle (the sum of two distances to points outside a disc, restricted
to its facing arc); nested grids on the arc and a final parabola find it, vectorised over any number
of (a, b, disc) triples in a few dozen array operations. The *detour* :math:`f - \lVert a - b \rVert` is the
price of inserting the disc between :math:`a` and :math:`b`.
"""

from __future__ import annotations

import numpy as np

from pmht_opt.tours.geometry import inner

#: Points per grid and nested grids of the arc search: the bracket shrinks to 4**-3 of the arc and a
#: parabola places the minimum within it (cost error about 1e-7 of the radius).
GRID = 9
STAGES = 3


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
        # Nested grids on s in [0, 1] (angle ua + s span): the objective is unimodal there, so the best
        # of GRID points brackets the minimum between its neighbours; each stage narrows the bracket
        # by (GRID - 1) / 2, and a parabola through the last three points places the minimum.
        zx, zy = zm[:, 0:1], zm[:, 1:2]
        ax, ay, bx, by = am[:, 0:1] - zx, am[:, 1:2] - zy, bm[:, 0:1] - zx, bm[:, 1:2] - zy
        rr, u0, sp = rm[:, None], ua[:, None], span[:, None]
        lo = np.zeros((len(ua), 1))
        width = np.ones((len(ua), 1))
        grid = np.linspace(0.0, 1.0, GRID)[None, :]
        rows = np.arange(len(ua))
        for _ in range(STAGES):
            s_ = lo + width * grid
            ang = u0 + s_ * sp
            cx, cy = np.cos(ang), np.sin(ang)
            f = np.hypot(rr * cx - ax, rr * cy - ay) + np.hypot(rr * cx - bx, rr * cy - by)
            i = np.clip(np.argmin(f, axis=1), 1, GRID - 2)
            step = width[:, 0] / (GRID - 1)
            f0, f1, f2 = f[rows, i - 1], f[rows, i], f[rows, i + 1]
            lo = (s_[rows, i] - step)[:, None]
            width = (2 * step)[:, None]
        curv = f0 - 2 * f1 + f2
        shift = np.where(curv > 0, 0.5 * (f0 - f2) / np.where(curv > 0, curv, 1.0), 0.0)
        x = np.clip(lo[:, 0] + width[:, 0] / 2 + np.clip(shift, -1, 1) * step, 0.0, 1.0)
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
