r"""The shortest route through a sequence of discs: where a tour should touch each locale's disc.

A sensor of footprint :math:`\rho` covers locale :math:`z_n` once the path passes anywhere in the disc
:math:`D_n = \{p : \lVert p - z_n \rVert \le \rho\}`; it never has to reach the centre. For a route that
leaves start :math:`s` and meets the discs of locales :math:`n_1, \dots, n_K` in that order, the
shortest polyline is the convex problem (a travelling salesman problem with neighbourhoods, the order
fixed)

.. math::

    \min_{p_1..p_K}\ \sum_{k=1}^{K} \lVert p_k - p_{k-1} \rVert
    \quad\text{s.t.}\quad \lVert p_k - z_{n_k} \rVert \le \rho,\qquad p_0 = s,

a second-order cone program: an epigraph variable :math:`\ell_k \ge \lVert p_k - p_{k-1}\rVert` per leg
and one cone per disc. Its solution, the *visit points* :math:`p_k`, is what the coverage planner
orders again and what its paths are made to follow. Locales whose discs overlap get the same point
when one pass covers them all, so clustering comes out of the geometry rather than out of a rule.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.exceptions import SolverError
from pmht_opt.scenario import Scenario


def disc_route(start: np.ndarray, centres: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """Visit points ``(K, 2)`` and length of the shortest polyline from ``start`` through the discs.

    Parameters
    ----------
    start
        ``(2,)`` first point of the polyline (the platform's start).
    centres
        ``(K, 2)`` disc centres in visiting order.
    radius
        Common disc radius (``0`` gives the polyline through the centres).

    Raises
    ------
    SolverError
        If the cone program is not solved to optimality (it is always feasible).
    """
    K = centres.shape[0]
    if K == 0:
        return np.zeros((0, 2)), 0.0
    if radius <= 0.0:
        pts = np.vstack([start, centres])
        return centres.copy(), float(np.hypot(*np.diff(pts, axis=0).T).sum())
    # Variables: x = (p_1, ..., p_K, l_1, ..., l_K); cones in the order leg 1..K, disc 1..K.
    n = 3 * K
    k = np.arange(K)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    b = np.zeros(6 * K)
    # Leg cone k, rows 3k..3k+2: s = (l_k, p_k - p_{k-1}) with s = b - A x.
    rows.append(3 * k)
    cols.append(2 * K + k)
    vals.append(-np.ones(K))
    for d in range(2):
        rows.append(3 * k + 1 + d)
        cols.append(2 * k + d)
        vals.append(-np.ones(K))
        rows.append(3 * k[1:] + 1 + d)
        cols.append(2 * k[:-1] + d)
        vals.append(np.ones(K - 1))
        b[1 + d] = -start[d]
    # Disc cone k, rows 3K + 3k..: s = (radius, p_k - z_k).
    base = 3 * K
    b[base + 3 * k] = radius
    for d in range(2):
        rows.append(base + 3 * k + 1 + d)
        cols.append(2 * k + d)
        vals.append(-np.ones(K))
        b[base + 3 * k + 1 + d] = -centres[:, d]
    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(6 * K, n))
    q = np.concatenate([np.zeros(2 * K), np.ones(K)])
    problem = solvers.QPProblem(sp.csc_matrix((n, n)), q, A, b, tuple(solvers.SOC(3) for _ in range(2 * K)))
    sol = solvers.solve_qp(problem, "clarabel")
    if not sol.ok or sol.x is None:
        raise SolverError(
            f"the shortest route through {K} discs was not solved ({sol.raw_status}).",
            backend="clarabel",
            status=sol.raw_status,
        )
    pts = sol.x[: 2 * K].reshape(K, 2)
    # Pull each point back into its disc: the interior point method meets the cones to its tolerance.
    off = pts - centres
    norm = np.hypot(off[:, 0], off[:, 1])
    over = norm > radius
    pts[over] = centres[over] + off[over] * (radius / norm[over])[:, None]
    length = float(np.hypot(*np.diff(np.vstack([start, pts]), axis=0).T).sum())
    return pts, length


def visit_points(scenario: Scenario, routes: Sequence[np.ndarray], radius: float) -> tuple[np.ndarray, float]:
    """``(N, 2)`` visit point of every locale and the total length of the routes' polylines.

    Each route is solved by :func:`disc_route` from its platform's start.
    """
    pts = np.zeros((scenario.n_locales, 2))
    total = 0.0
    for m, route in enumerate(routes):
        p, length = disc_route(scenario.start_positions[m], scenario.locales[route], radius)
        pts[route] = p
        total += length
    return pts, total
