"""The constant-acceleration smoothing problem of one axis, and its reference in extended precision.

The exact smoothers (:mod:`solvers.banded`, :mod:`solvers.kalman`) are judged against the RTS smoother
run in ``np.longdouble`` (64-bit mantissa on x86-64): the smoother benchmark
(``studies/bench_smoother.py``) and the tests use this one reference, so that both hold the solvers to
the same thing.
"""

from __future__ import annotations

import numpy as np

#: The measurement vector of a position-only measurement: ``h' x`` is the position.
E1 = np.array([1.0, 0.0, 0.0])


def ca_model(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-acceleration ``F`` and ``Q`` of one axis."""
    F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = q * np.array(
        [
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ]
    )
    return F, Q


def ld_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` by Gauss-Jordan with partial pivoting, in the dtype of the inputs (numpy's solvers
    have no extended precision)."""
    n = A.shape[0]
    M = np.concatenate([A, B], axis=1)
    for c in range(n):
        p = c + int(np.argmax(np.abs(M[c:, c])))
        M[[c, p]] = M[[p, c]]
        M[c] = M[c] / M[c, c]
        for i in range(n):
            if i != c:
                M[i] = M[i] - M[i, c] * M[c]
    return M[:, n:]


def rts_extended(
    F: np.ndarray, Q: np.ndarray, h: np.ndarray, r: float, x0: np.ndarray, y: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """The RTS smoother of one system run in ``np.longdouble``: its states ``(T+1, n)``, or
    ``(T+1, n, K)`` for ``K`` measurement columns sharing the weights (``x0 (n, K)``, ``y (T, K)``)."""
    ld = np.longdouble
    F, Q, h = F.astype(ld), Q.astype(ld), h.astype(ld)
    T, n = len(w), F.shape[0]
    m = x0.astype(ld)
    P = np.zeros((n, n), dtype=ld)
    mf, Pf, mp, Pp = [m], [P], [m], [P]
    for t in range(T):
        m = F @ m
        P = F @ P @ F.T + Q
        mp.append(m)
        Pp.append(P)
        if w[t] > 0:
            Ph = P @ h
            g = Ph / (h @ Ph + ld(r) / ld(w[t]))
            m = m + np.multiply.outer(g, np.asarray(y[t], dtype=ld) - h @ m)
            P = P - np.outer(g, Ph)
        mf.append(m)
        Pf.append(P)
    ms = [mf[T]]
    for t in range(T - 1, -1, -1):
        G = ld_solve(Pp[t + 1], F @ Pf[t]).T  # Pf F' Pp^-1
        ms.append(mf[t] + G @ (ms[-1] - mp[t + 1]))
    return np.array(ms[::-1], dtype=ld)
