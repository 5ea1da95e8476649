"""The candidates of the smoother benchmark (``studies/bench_smoother.py``): exact solvers of the
unconstrained M-step of one axis, each ``solver(F, Q, r, W, y, x0) -> means (M, T+1, 3, 2)``.

They are the library's own two (:func:`solvers.kalman.rts_smoother`, :class:`solvers.banded.BandedSmoother`)
and the alternatives they were chosen against: the banded KKT system solved by scipy without scaling or
refinement, the information form by a banded Cholesky (with and without refinement), and the RTS
smoother as two associative scans (Sarkka and Garcia-Fernandez, "Temporal parallelization of Bayesian
smoothers", 2021). The benchmark's docstring says what each one is.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg

from solvers.banded import BandedSmoother, banded_smoother
from solvers.kalman import rts_smoother
from studies.smoother_reference import E1

Array = np.ndarray
Solver = Callable[[Array, Array, float, Array, Array, Array], Array]


def run_rts(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M = W.shape[0]
    res = rts_smoother(F, Q, E1[None], np.array([[r]]), x0, np.zeros((M, 3, 3)), y[:, :, None, :], W)
    return res.means


def make_banded(F: Array, Q: Array, W: Array, refine: int) -> Solver:
    """Built once per model and size, as an EM loop would hold it."""
    smoother = BandedSmoother(F, Q, E1, W.shape[1], W.shape[0])

    def run(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
        return smoother.solve(r, x0, y, W, refine=refine).means

    return run


def run_banded_function(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """The functional form, which finds its assembled band in a cache."""
    return banded_smoother(F, Q, E1, r, x0, y, W).means


def run_kkt_solve_banded(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """Unscaled KKT ``[lam_t, x_t]`` per platform with ``scipy.linalg.solve_banded``."""
    M, T = W.shape
    n = 3
    N = 2 * n * T
    k = n  # F upper triangular, position measured: half-bandwidth n
    ab0 = np.zeros((2 * k + 1, N))

    def put(r0: Array, c0: Array, mat: Array) -> None:
        a, c = np.nonzero(mat)
        rows = (r0[:, None] + a).ravel()
        cols = (c0[:, None] + c).ravel()
        ab0[k + rows - cols, cols] = np.broadcast_to(mat[a, c], (r0.size, a.size)).ravel()

    starts = 2 * n * np.arange(T)
    put(starts, starts, -Q)
    put(starts, starts + n, np.eye(n))
    put(starts + n, starts, np.eye(n))
    put(starts[1:], starts[1:] - n, -F)
    put(starts[1:] - n, starts[1:], -F.T)
    out = np.empty((M, T + 1, n, 2))
    for m in range(M):
        ab = ab0.copy()
        rho = W[m] / r
        ab[k, starts + n] += rho
        rhs = np.zeros((T, 2 * n, 2))
        rhs[:, n, :] = rho[:, None] * y[m]
        rhs[0, :n, :] = F @ x0[m]
        z = scipy.linalg.solve_banded((k, k), ab, rhs.reshape(N, 2), check_finite=False)
        out[m, 0] = x0[m]
        out[m, 1:] = z.reshape(T, 2 * n, 2)[:, n:, :]
    return out


def _normal_band(F: Array, Q: Array, r: float, W: Array) -> tuple[Array, Array]:
    """Upper band of ``D' Q^-1 D + P`` for the stacked platforms, and ``Q^-1``."""
    M, T = W.shape
    n = 3
    Qi = np.linalg.inv(Q)
    Qi = 0.5 * (Qi + Qi.T)
    diag_inner = Qi + F.T @ Qi @ F
    off = -Qi @ F  # block (t, t-1)
    u = 2 * n - 1
    N = M * n * T
    ab = np.zeros((u + 1, N))
    blocks = M * T
    last = (np.arange(blocks) % T) == T - 1
    first = (np.arange(blocks) % T) == 0
    for a in range(n):
        for c in range(a, n):
            cols = n * np.arange(blocks) + c
            ab[u + a - c, cols] = np.where(last, Qi[a, c], diag_inner[a, c])
    for a in range(n):  # row in block t-1 (component a), column in block t (component c): off[c, a]
        for c in range(n):
            cols = n * np.arange(blocks) + c
            ab[u + (a - n) - c, cols] = np.where(first, 0.0, off[c, a])
    ab[u, n * np.arange(blocks)] += (W / r).ravel()
    return ab, Qi


def _normal_rhs(F: Array, Qi: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M, T = W.shape
    rhs = np.zeros((M, T, 3, 2))
    rhs[:, :, 0, :] = (W / r)[..., None] * y
    rhs[:, 0] += np.einsum("ij,mjk->mik", Qi @ F, x0)
    return rhs


def make_normal(refine: int) -> Solver:
    def run(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
        M, T = W.shape
        ab, Qi = _normal_band(F, Q, r, W)
        rhs = _normal_rhs(F, Qi, r, W, y, x0)
        cb = scipy.linalg.cholesky_banded(ab, check_finite=False)
        x = scipy.linalg.cho_solve_banded((cb, False), rhs.reshape(-1, 2), check_finite=False)
        for _ in range(refine):
            s = x.reshape(M, T, 3, 2)
            prev = np.concatenate([x0[:, None], s[:, :-1]], axis=1)
            e = s - np.einsum("ij,mtjk->mtik", F, prev)  # x_t - F x_{t-1}, x_0 included
            g = np.einsum("ij,mtjk->mtik", Qi, e)
            Hx = g.copy()
            Hx[:, :-1] -= np.einsum("ji,mtjk->mtik", F, g[:, 1:])
            res = np.zeros_like(s)
            res[:, :, 0, :] = (W / r)[..., None] * (y - s[:, :, 0, :])
            res -= Hx
            x = x + scipy.linalg.cho_solve_banded((cb, False), res.reshape(-1, 2), check_finite=False)
        out = np.empty((M, T + 1, 3, 2))
        out[:, 0] = x0
        out[:, 1:] = x.reshape(M, T, 3, 2)
        return out

    return run


def _inv3(A: Array) -> Array:
    """Inverses of a stack of 3 x 3 matrices by cofactors (numpy's batched inverse loops in C
    over LAPACK calls and is several times slower at this size)."""
    a, b, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    d, e, f = A[..., 1, 0], A[..., 1, 1], A[..., 1, 2]
    g, h, i = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
    co = np.empty_like(A)
    co[..., 0, 0] = e * i - f * h
    co[..., 0, 1] = c * h - b * i
    co[..., 0, 2] = b * f - c * e
    co[..., 1, 0] = f * g - d * i
    co[..., 1, 1] = a * i - c * g
    co[..., 1, 2] = c * d - a * f
    co[..., 2, 0] = d * h - e * g
    co[..., 2, 1] = b * g - a * h
    co[..., 2, 2] = a * e - b * d
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    return co / det[..., None, None]


def _prefix_scan(elems: tuple[Array, ...], combine: Callable[..., tuple[Array, ...]]) -> tuple[Array, ...]:
    """Inclusive prefix products along axis 1 with ``2 log2 L`` vectorised levels (work ``O(L)``)."""
    L = elems[0].shape[1]
    if L == 1:
        return elems
    even = tuple(e[:, 0 : L - 1 : 2] for e in elems)
    odd = tuple(e[:, 1:L:2] for e in elems)
    pref = _prefix_scan(combine(even, odd), combine)  # pref[i] = e_0 ... e_{2i+1}
    out = tuple(np.empty_like(e) for e in elems)
    for o, p, e in zip(out, pref, elems, strict=True):
        o[:, 1::2] = p
        o[:, 0] = e[:, 0]
    rest = tuple(e[:, 2::2] for e in elems)
    if rest[0].shape[1]:
        joined = combine(tuple(p[:, : rest[0].shape[1]] for p in pref), rest)
        for o, j in zip(out, joined, strict=True):
            o[:, 2::2] = j
    return out


def _filter_combine(first: tuple[Array, ...], second: tuple[Array, ...]) -> tuple[Array, ...]:
    Ai, bi, Ci, ei, Ji = first
    Aj, bj, Cj, ej, Jj = second
    eye = np.eye(Ai.shape[-1])
    Mx = _inv3(eye + Ci @ Jj)
    AjM = Aj @ Mx
    MtT = np.swapaxes(Mx, -1, -2)  # (I + J C)^-1 = ((I + C J)^-1)' for symmetric C, J
    AiT = np.swapaxes(Ai, -1, -2)
    AiTM = AiT @ MtT
    A = AjM @ Ai
    b = AjM @ (bi + Ci @ ej) + bj
    C = AjM @ Ci @ np.swapaxes(Aj, -1, -2) + Cj
    e = AiTM @ (ej - Jj @ bi) + ei
    J = AiTM @ Jj @ Ai + Ji
    return A, b, C, e, J


def _smoother_combine(later: tuple[Array, ...], earlier: tuple[Array, ...]) -> tuple[Array, ...]:
    """Reversed-time order: ``later`` holds the suffix already combined, ``earlier`` the new steps."""
    El, gl = later
    Ee, ge = earlier
    return Ee @ El, Ee @ gl + ge


def run_assoc_scan(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M, T = W.shape
    n = 3
    h = E1
    Sinv = W / (W * (h @ Q @ h) + r)  # 1 / (h'Qh + r / w), zero without a measurement
    Kg = (Q @ h)[None, None, :] * Sinv[..., None]  # (M, T, n)
    hF = h @ F
    A = np.broadcast_to(F, (M, T, n, n)) - Kg[..., :, None] * hF[None, None, None, :]
    C = np.broadcast_to(Q, (M, T, n, n)) - Kg[..., :, None] * (h @ Q)[None, None, None, :]
    b = Kg[..., :, None] * y[:, :, None, :]  # (M, T, n, 2)
    Fh = F.T @ h
    eta = Fh[None, None, :, None] * (Sinv[..., None] * y)[:, :, None, :]
    J = np.outer(Fh, Fh)[None, None] * Sinv[..., None, None]
    # The first step starts from the known x0 (no prior covariance).
    pred = np.einsum("ij,mjk->mik", F, x0)
    A = A.copy()
    A[:, 0] = 0.0
    b[:, 0] = pred + Kg[:, 0, :, None] * (y[:, 0, None, :] - pred[:, 0:1, :])
    eta[:, 0] = 0.0
    J = J.copy()
    J[:, 0] = 0.0
    _, mf, Pf, _, _ = _prefix_scan((A, b, C, eta, J), _filter_combine)
    # Smoother elements E_t = Pf_t F' (F Pf_t F' + Q)^-1, g_t = m_t - E_t F m_t; E_T = 0, g_T = m_T.
    E = np.zeros((M, T, n, n))
    Pp = F @ Pf[:, :-1] @ F.T + Q
    E[:, :-1] = Pf[:, :-1] @ F.T @ _inv3(Pp)
    g = mf - E @ (F @ mf)
    _, gs = _prefix_scan((E[:, ::-1], g[:, ::-1]), _smoother_combine)
    out = np.empty((M, T + 1, n, 2))
    out[:, 0] = x0
    out[:, 1:] = gs[:, ::-1]
    return out
