r"""The shortest polyline that meets a sequence of discs in a fixed order: a second-order cone program.

For a route that leaves start :math:`s`, meets the discs :math:`(z_k, \rho_k)`, :math:`k = 1..K`, in that
order and, when closed, comes back to :math:`s`, the turn points solve (Coutinho et al. 2016)

.. math::

    \min_{p, \ell}\ \sum_{k=1}^{L} \ell_k \quad\text{s.t.}\quad
    \lVert p_k - p_{k-1} \rVert \le \ell_k,\qquad \lVert p_k - z_k \rVert \le \rho_k,

with :math:`p_0 = s`, :math:`L = K` for an open route and :math:`L = K + 1` with :math:`p_{K+1} = s`
for a closed one. It is convex, always feasible (the centres are a solution), and its optimum is the
exact length of the best polyline for that order: the *visit points* :math:`p_k`. A disc that the
optimal polyline merely crosses gets a point on a straight leg, which is how covering in passing shows
up here. The cone program is posed in the project's ``solvers`` layer (Clarabel, an interior point
method); it costs milliseconds for a few hundred discs, so the searches call it once per round, never
per move.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

import solvers
from pmht_opt.tours.geometry import polyline_length, pull_inside


def disc_sequence(
    start: np.ndarray, centres: np.ndarray, radii: np.ndarray, closed: bool
) -> tuple[np.ndarray, float]:
    """Visit points ``(K, 2)`` and length of the shortest polyline from ``start`` through the discs.

    Parameters
    ----------
    start
        ``(2,)`` first point (and, when ``closed``, last point) of the polyline.
    centres, radii
        ``(K, 2)`` and ``(K,)``: the discs in the order they must be met.
    closed
        Whether the polyline returns to ``start`` (the leg home counts in the length).

    If the cone program is not solved (Clarabel's "almost solved" answer is taken, pulled into the
    discs), the centres are returned: a feasible answer, never a wrong one.
    """
    K = centres.shape[0]
    if K == 0:
        return np.zeros((0, 2)), 0.0
    L = K + 1 if closed else K
    n = 2 * K + L
    k = np.arange(K)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    b = np.zeros(3 * L + 3 * K)
    # Leg cones, rows 3j..3j+2: s = b - A x = (l_j, p_j - p_{j-1}); p_0 = p_{K+1} = start.
    j = np.arange(L)
    rows.append(3 * j)
    cols.append(2 * K + j)
    vals.append(-np.ones(L))
    for d in range(2):
        rows.append(3 * k + 1 + d)  # + p_k in leg k (legs 0..K-1 end at p_k)
        cols.append(2 * k + d)
        vals.append(-np.ones(K))
        rows.append(3 * (k[:-1] + 1) + 1 + d)  # - p_{k} in leg k+1
        cols.append(2 * k[:-1] + d)
        vals.append(np.ones(K - 1))
        b[1 + d] = -start[d]
        if closed:  # leg K: start - p_K
            rows.append(np.array([3 * K + 1 + d]))
            cols.append(np.array([2 * (K - 1) + d]))
            vals.append(np.ones(1))
            b[3 * K + 1 + d] = start[d]
    base = 3 * L
    b[base + 3 * k] = radii
    for d in range(2):
        rows.append(base + 3 * k + 1 + d)
        cols.append(2 * k + d)
        vals.append(-np.ones(K))
        b[base + 3 * k + 1 + d] = -centres[:, d]
    A = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * (L + K), n)
    )
    q = np.concatenate([np.zeros(2 * K), np.ones(L)])
    problem = solvers.QPProblem(sp.csc_matrix((n, n)), q, A, b, tuple(solvers.SOC(3) for _ in range(L + K)))
    sol = solvers.solve_qp(problem, "clarabel")
    if sol.usable(accept_inaccurate=True) and sol.x is not None and np.all(np.isfinite(sol.x)):
        # The interior point method meets the cones to its tolerance: pull each point into its disc.
        pts = pull_inside(sol.x[: 2 * K].reshape(K, 2), centres, radii)
    else:
        # Not solved ("almost solved" once on a route of 15 discs of A at radius 0.3, where an earlier
        # version failed the plan): the centres are a feasible answer, and every caller keeps the tour
        # it had unless the new one is shorter and meets every disc, so a weaker answer here costs
        # length, never validity.
        pts = centres.copy()
    verts = np.vstack([start, pts, start]) if closed else np.vstack([start, pts])
    return pts, polyline_length(verts)
