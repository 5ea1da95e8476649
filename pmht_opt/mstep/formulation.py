r"""The M-step as a sparse convex QP: variables, dynamics rows and the objective (docs/model.md section 5).

Given the E-step's weights, the M-step minimises over the paths

.. math::

    J(X) = \tfrac12 \sum_{t,m} \lVert u_t^m \rVert^2
         + \sum_{t,m} \frac{W[t,m]}{2 r} \lVert H x_t^m - \tilde z[t,m] \rVert^2

with :math:`x_t = F x_{t-1} + L u_t` (:math:`L L^\top = Q`) and :math:`x_0` known. Writing the process
noise as an explicit variable ``u`` scaled by the Cholesky factor of ``Q`` gives an identity Hessian on
``u`` and the penalty weights ``W / r`` on the positions; the alternative with :math:`Q^{-1}` in the
Hessian (entries near 1e10 against 1e2) is so badly conditioned that solvers report success far from
the answer.

Without coupling constraints the QP separates by platform, so each platform is its own QP. Its
variables, per step ``t = 1..T``, are a block of 12, ``[x_t (6), u_t (6)]``, at offset ``12 (t - 1)``;
its constraints ``x_t - F x_{t-1} - L u_t = 0`` (``x_1 - L u_1 = F x_0``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from pmht_opt.model import PX, PY, STATE_DIM, MotionModel

BLOCK = 2 * STATE_DIM  # [x_t, u_t]


class QPLayout:
    """Index arithmetic of the M-step QP's variable vector."""

    def __init__(self, n_platforms: int, horizon: int) -> None:
        self.M = n_platforms
        self.T = horizon
        self.n = BLOCK * n_platforms * horizon

    def x(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of state component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return BLOCK * (np.asarray(m) * self.T + np.asarray(t) - 1) + np.asarray(comp)

    def u(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of noise component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return self.x(m, t, comp) + STATE_DIM

    def states(self, xvec: np.ndarray) -> np.ndarray:
        """``(M, T, 6)`` states from a solution vector."""
        return xvec.reshape(self.M, self.T, BLOCK)[:, :, :STATE_DIM]

    def noise(self, xvec: np.ndarray) -> np.ndarray:
        """``(M, T, 6)`` whitened process noise ``u`` from a solution vector."""
        return xvec.reshape(self.M, self.T, BLOCK)[:, :, STATE_DIM:]


def dynamics_rows(model: MotionModel, layout: QPLayout, x0: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """Equality rows ``x_t - F x_{t-1} - L u_t = 0`` (``= F x_0`` at ``t = 1``) for every platform.

    The velocity rows are multiplied by ``T / 5`` and the acceleration rows by ``(T / 5)^2``. This is the
    same constraint, but it changes what a solver's residual tolerance means: a residual ``e`` left in a
    velocity row at step ``s`` moves every later position by ``(t - s) e``, and one in an acceleration
    row by ``(t - s)^2 e / 2``, so unscaled rows let an ``eps``-accurate solve drift in position by
    orders of magnitude more than ``eps``.
    """
    M, T = layout.M, layout.T
    F, L = model.F, model.L
    m_grid, t_grid = np.meshgrid(np.arange(M), np.arange(1, T + 1), indexing="ij")
    m_idx, t_idx = m_grid.ravel(), t_grid.ravel()
    row0 = STATE_DIM * (m_idx * T + t_idx - 1)
    rows, cols, vals = [], [], []
    for i in range(STATE_DIM):
        rows.append(row0 + i)
        cols.append(layout.x(m_idx, t_idx, i))
        vals.append(np.ones(row0.size))
        for j in range(STATE_DIM):
            if L[i, j] != 0.0:
                rows.append(row0 + i)
                cols.append(layout.u(m_idx, t_idx, j))
                vals.append(np.full(row0.size, -L[i, j]))
            if F[i, j] != 0.0:
                later = t_idx > 1
                rows.append(row0[later] + i)
                cols.append(layout.x(m_idx[later], t_idx[later] - 1, j))
                vals.append(np.full(int(later.sum()), -F[i, j]))
    n_rows = STATE_DIM * M * T
    A = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_rows, layout.n)
    )
    b = np.zeros(n_rows)
    first = (STATE_DIM * (np.arange(M) * T))[:, None] + np.arange(STATE_DIM)[None, :]
    b[first] = x0 @ F.T
    horizon = max(T / 5.0, 1.0)
    row_scale = np.tile(np.array([1.0, horizon, horizon**2, 1.0, horizon, horizon**2]), M * T)
    return (sp.diags(row_scale) @ A).tocsc(), row_scale * b


def mstep_objective(model: MotionModel, states: np.ndarray, W: np.ndarray, WZ: np.ndarray, r: float) -> float:
    """``J(X)`` of the module docstring for paths ``(M, T+1, 6)``, without terms constant in ``X``.

    Smaller is better; used to compare backends on one M-step.
    """
    u = model.process_noise(states)
    pos = states[:, 1:, [PX, PY]].transpose(1, 0, 2)  # (T, M, 2)
    fit = 0.5 * np.sum(W[..., None] * pos * pos) - np.sum(WZ * pos)
    return float(0.5 * np.sum(u * u) + fit / r)
