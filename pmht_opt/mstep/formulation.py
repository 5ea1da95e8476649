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

A QP with constraint rows measures velocities and accelerations in a unit of time of ``T / 5``
steps (:func:`state_units`). The infeasibility diagnosis's phase-one problem
(:mod:`pmht_opt.mstep.diagnosis`) also measures positions from the start (:func:`start_frame`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from pmht_opt.model import PX, PY, STATE_DIM, MotionModel

BLOCK = 2 * STATE_DIM  # [x_t, u_t]


def time_unit(horizon: int) -> float:
    """The QP's unit of time in steps, ``max(T / 5, 1)``: velocities and accelerations are measured per
    this unit (:func:`state_units`) and the dynamics rows scaled by it (:func:`dynamics_rows`)."""
    return max(horizon / 5.0, 1.0)


def state_units(horizon: int) -> np.ndarray:
    """``(6,)`` factors ``c``: the QP's state variable is ``x / c``, so a state ``x = c * xq``.

    Positions keep their unit; velocities are measured per :func:`time_unit` steps and accelerations
    per its square, so that the three are numbers of one size along a path that crosses the area in a
    fraction of the horizon. Without it a binding acceleration limit (scenario C, ``|a| <= 1e-3``, an
    acceleration of ``1e-3`` beside positions of 3) stalled Clarabel at a primal residual of 7e-6.
    """
    h = time_unit(horizon)
    return np.array([1.0, 1.0 / h, 1.0 / h**2, 1.0, 1.0 / h, 1.0 / h**2])


class QPLayout:
    """Index arithmetic of the M-step QP's variable vector, and its units (:func:`state_units`)."""

    def __init__(self, n_platforms: int, horizon: int, scaled: bool = True) -> None:
        self.M = n_platforms
        self.T = horizon
        self.n = BLOCK * n_platforms * horizon
        #: Per state component, the state's size of one unit of its QP variable (ones if not ``scaled``).
        self.units = state_units(horizon) if scaled else np.ones(STATE_DIM)

    def x(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of state component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return BLOCK * (np.asarray(m) * self.T + np.asarray(t) - 1) + np.asarray(comp)

    def u(self, m: Any, t: Any, comp: Any) -> Any:
        """Index of noise component ``comp`` of platform ``m`` at time ``t`` (``1..T``)."""
        return self.x(m, t, comp) + STATE_DIM

    def states(self, xvec: np.ndarray) -> np.ndarray:
        """``(M, T, 6)`` states from a solution vector (in the states' own units)."""
        return xvec.reshape(self.M, self.T, BLOCK)[:, :, :STATE_DIM] * self.units

    def column_units(self) -> np.ndarray:
        """``(n,)`` factor of each QP column: :attr:`units` on states, 1 on the noise."""
        one = np.ones(BLOCK)
        one[:STATE_DIM] = self.units
        return np.tile(one, self.M * self.T)

    def noise(self, xvec: np.ndarray) -> np.ndarray:
        """``(M, T, 6)`` whitened process noise ``u`` from a solution vector."""
        return xvec.reshape(self.M, self.T, BLOCK)[:, :, STATE_DIM:]


def dynamics_rows(model: MotionModel, layout: QPLayout, x0: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """Equality rows ``x_t - F x_{t-1} - L u_t = 0`` (``= F x_0`` at ``t = 1``) for every platform.

    The columns are in the layout's units (:func:`state_units`). The velocity rows are multiplied by
    ``T / 5`` and the acceleration rows by ``(T / 5)^2``. This is the same constraint, but it changes
    what a solver's residual tolerance means: a residual ``e`` left in a velocity row at step ``s``
    moves every later position by ``(t - s) e``, and one in an acceleration row by ``(t - s)^2 e / 2``,
    so unscaled rows let an ``eps``-accurate solve drift in position by orders of magnitude more than
    ``eps``.
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
    cols_all = np.concatenate(cols)
    A = sp.csc_matrix(
        (np.concatenate(vals) * layout.column_units()[cols_all], (np.concatenate(rows), cols_all)),
        shape=(n_rows, layout.n),
    )
    b = np.zeros(n_rows)
    first = (STATE_DIM * (np.arange(M) * T))[:, None] + np.arange(STATE_DIM)[None, :]
    b[first] = x0 @ F.T
    horizon = time_unit(T)
    row_scale = np.tile(np.array([1.0, horizon, horizon**2, 1.0, horizon, horizon**2]), M * T)
    return (sp.diags(row_scale) @ A).tocsc(), row_scale * b


def start_frame(x0: np.ndarray, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates measured from one platform's start: ``(x0', origin)``, the start state with its
    position at zero and the stacked states ``(6 horizon,)`` of the start's position held at every step
    ``1..horizon`` (zero velocity and acceleration); states are ``origin + x'``.

    The dynamics do not change (``F`` carries a constant position over unchanged) and a constraint
    ``h - G z`` becomes ``(h - G z_0) - G z'``. Solvers' tolerances are relative to the size of the
    numbers they are given: at the paper's scale (positions up to 10) a limit of 1e-5 on the second
    difference of positions is, in absolute coordinates, a cone whose offset is 1e6 times its radius;
    a feasibility solve of it ended "almost solved" 2.7e-7 short of the limit at the first step, which
    read as an infeasibility. From the start, the same solve needs no slack.
    """
    x0_rel = np.array(x0, dtype=float)
    x0_rel[[PX, PY]] = 0.0
    one = np.zeros(STATE_DIM)
    one[[PX, PY]] = np.asarray(x0, dtype=float)[[PX, PY]]
    return x0_rel, np.tile(one, horizon)


def mstep_objective(model: MotionModel, states: np.ndarray, W: np.ndarray, WZ: np.ndarray, r: float) -> float:
    """``J(X)`` of the module docstring for paths ``(M, T+1, 6)``, without terms constant in ``X``.

    Smaller is better; used to compare backends on one M-step.
    """
    u = model.process_noise(states)
    pos = states[:, 1:, [PX, PY]].transpose(1, 0, 2)  # (T, M, 2)
    fit = 0.5 * np.sum(W[..., None] * pos * pos) - np.sum(WZ * pos)
    return float(0.5 * np.sum(u * u) + fit / r)


def in_increments(
    A: sp.csc_matrix, b: np.ndarray, A_dyn: sp.csc_matrix, b_dyn: np.ndarray, n: int
) -> tuple[sp.csc_matrix, np.ndarray]:
    r"""Constraint rows ``(A, b)`` of one platform's QP (``n`` variables, then any slacks) with finite
    differences of positions written on the position increments.

    A row whose position coefficients ``c_j`` (on ``p_j``, per axis) sum to zero is a finite
    difference: :math:`\sum_j c_j p_j = \sum_s e_s (p_s - p_{s-1})` with :math:`e_s = \sum_{j \ge s} c_j`.
    The dynamics make each increment :math:`p_s - p_{s-1}` a function of the velocity, acceleration
    and process noise (``(F x_{s-1})_p - p_{s-1} + (L u_s)_p``), so subtracting ``e_s`` times the
    position row of step ``s`` of the dynamics (``A_dyn``, ``b_dyn``: equalities, so the rows mean the
    same) removes the positions from the row. A row whose earliest position is ``p_1`` is rewritten the
    same way whatever its sum (the known ``p_0`` takes the rest: the first steps' differences, and a
    visit at a step whose window starts at 1). Why: a speed or acceleration limit of 1e-5 is a cone of
    radius 1e-5 on differences of positions of size 10; normalised by its radius its coefficients are
    2e5 beside dynamics rows of order 1, and Clarabel stalled on it ("insufficient progress"). On the
    increments the largest coefficient was 1e3 and the same M-step solved in 12 iterations.

    The sparsity pattern of the result depends only on that of ``A`` (coefficients that cancel
    exactly are dropped by position, not by value), so a session can take new numbers in place.
    """
    A = A.tocoo()
    row, col, val = A.row, A.col, A.data
    state = col < n
    comp = np.where(state, col % BLOCK, -1)
    step = np.where(state, col // BLOCK + 1, 0)
    pos, first = _differences(A.shape[0], row, comp, step, val)
    if not np.any(pos):
        return A.tocsc(), b
    # e_s for s from the row's first step to each entry's step: entry (j, c_j) adds c_j to e_s, s <= j.
    r_pos, s_pos, c_pos = row[pos], step[pos], val[pos]
    ax_pos = np.where(comp[pos] == PY, PY, PX)
    lo = first[r_pos * 2 + (ax_pos == PY)]
    span = s_pos - lo + 1
    rep = np.repeat(np.arange(r_pos.size), span)
    s_all = lo[rep] + (np.arange(rep.size) - np.repeat(np.cumsum(span) - span, span))
    E = sp.csr_matrix(
        (c_pos[rep], (r_pos[rep], STATE_DIM * (s_all - 1) + ax_pos[rep])),
        shape=(A.shape[0], A_dyn.shape[0]),
    )
    E.sum_duplicates()
    E_coo = E.tocoo()  # explicit zeros kept: the pattern must not depend on the values
    p_row, p_col, p_val = _times_dynamics(E_coo, A_dyn, n)
    keep_a = ~pos  # positions cancel: p_j has c_j - e_j + e_{j+1} = 0 in every rewritten row
    out = sp.coo_matrix(
        (
            np.concatenate([val[keep_a], p_val]),
            (np.concatenate([row[keep_a], p_row]), np.concatenate([col[keep_a], p_col])),
        ),
        shape=A.shape,
    ).tocsc()
    out.sort_indices()
    return out, b - E_coo @ b_dyn


def _differences(
    n_rows: int, row: np.ndarray, comp: np.ndarray, step: np.ndarray, val: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For the entries of rows (COO ``row``, state component ``comp`` or -1, ``step``, ``val``): the
    mask of position entries in rows :func:`in_increments` rewrites, and each ``(row, axis)``'s earliest
    step (index ``2 row + axis``, ``axis`` 1 for y).

    A row is rewritten if every state entry is on a position and, per axis, its coefficients sum to
    zero or its earliest step is 1.
    """
    on_pos = (comp == PX) | (comp == PY)
    eligible = np.zeros(n_rows, dtype=bool)
    eligible[row[on_pos]] = True
    eligible[row[(comp >= 0) & ~on_pos]] = False
    pos = on_pos & eligible[row]
    key = row[pos] * 2 + (comp[pos] == PY)
    total = np.zeros(2 * n_rows)
    scale = np.zeros(2 * n_rows)
    np.add.at(total, key, val[pos])
    np.add.at(scale, key, np.abs(val[pos]))
    first = np.full(2 * n_rows, np.iinfo(np.int64).max)
    np.minimum.at(first, key, step[pos])
    ok = (np.abs(total) <= 1e-12 * scale) | (first == 1)
    eligible[np.unique(key[~ok[key]] // 2)] = False
    return on_pos & eligible[row], first


def _times_dynamics(E: sp.coo_matrix, A_dyn: sp.csc_matrix, n: int) -> tuple[np.ndarray, ...]:
    """The entries ``(rows, cols, values)`` of ``-E @ A_dyn`` off the position columns, every product
    term kept (scipy's product drops terms that cancel, which would make the pattern depend on values)."""
    D = A_dyn.tocsr()
    starts, lengths = D.indptr[E.col], np.diff(D.indptr)[E.col]
    offsets = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    idx = np.repeat(starts, lengths) + offsets
    rows = np.repeat(E.row, lengths)
    cols = D.indices[idx]
    vals = -np.repeat(E.data, lengths) * D.data[idx]
    comp = cols % BLOCK
    keep = ~((comp == PX) | (comp == PY)) | (cols >= n)
    return rows[keep], cols[keep], vals[keep]
