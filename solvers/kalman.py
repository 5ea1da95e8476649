"""Rauch-Tung-Striebel smoother for a batch of independent linear-Gaussian state-space models.

Each system ``b`` of the batch follows::

    x_0 ~ N(x0[b], P0[b]),   x_t = F x_{t-1} + v_t,  v_t ~ N(0, Q),
    y_t = H x_t + e_t,  e_t ~ N(0, R / weight[b, t])   (no measurement where weight[b, t] == 0)

for ``t = 1..T``. The smoothed means are the minimisers of the corresponding weighted least-squares
problem, which is what makes the smoother a cross-check for QP formulations of the same problem.

The loop over time is sequential (the filter is a recursion); the batch dimension is vectorised, and
the backward gains are computed for all steps at once after the forward pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.exceptions import ProblemError


@dataclass
class SmootherResult:
    """Filtered and smoothed moments; ``means`` has shape ``(B, T+1, n)`` and includes ``t = 0``."""

    means: np.ndarray
    filtered_means: np.ndarray
    filtered_covs: np.ndarray
    predicted_covs: np.ndarray


def _check(name: str, arr: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    out = np.asarray(arr, dtype=float)
    if out.shape != shape:
        raise ProblemError(f"{name} has shape {out.shape}, expected {shape}.")
    if not np.all(np.isfinite(out)):
        raise ProblemError(f"{name} has non-finite entries.")
    return out


def rts_smoother(
    F: np.ndarray,
    Q: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    x0: np.ndarray,
    P0: np.ndarray,
    y: np.ndarray,
    weight: np.ndarray,
) -> SmootherResult:
    """Smooth a batch of systems sharing ``F, Q, H, R``.

    Parameters
    ----------
    F, Q
        Transition matrix and process noise covariance, ``(n, n)``; ``Q`` must be positive definite.
    H, R
        Measurement matrix ``(p, n)`` and unit-weight measurement covariance ``(p, p)``.
    x0, P0
        Prior mean ``(B, n)`` and covariance ``(B, n, n)`` of ``x_0`` (``P0 = 0`` for a known start).
    y
        Measurements ``(B, T, p)`` for ``t = 1..T``; ignored where the weight is zero.
    weight
        Non-negative measurement weights ``(B, T)``: the covariance at step ``t`` is ``R / weight``.
    """
    F = np.asarray(F, dtype=float)
    n = F.shape[0]
    F = _check("F", F, (n, n))
    Q = _check("Q", Q, (n, n))
    H = np.asarray(H, dtype=float)
    p = H.shape[0]
    H = _check("H", H, (p, n))
    R = _check("R", R, (p, p))
    x0 = np.asarray(x0, dtype=float)
    B = x0.shape[0]
    x0 = _check("x0", x0, (B, n))
    P0 = _check("P0", P0, (B, n, n))
    weight = np.asarray(weight, dtype=float)
    T = weight.shape[1] if weight.ndim == 2 else -1
    weight = _check("weight", weight, (B, T))
    y = _check("y", y, (B, T, p))
    if np.any(weight < 0):
        raise ProblemError("weight has negative entries.")

    has_meas = weight > 0
    # Unused where the weight is zero; 1.0 keeps the arithmetic finite and the gain is masked to 0.
    safe_w = np.where(has_meas, weight, 1.0)
    FT = F.T
    HT = H.T

    mf = np.empty((T + 1, B, n))
    Pf = np.empty((T + 1, B, n, n))
    mp = np.empty((T + 1, B, n))
    Pp = np.empty((T + 1, B, n, n))
    m = x0.copy()
    P = P0.copy()
    mf[0] = m
    Pf[0] = P
    eye = np.eye(n)
    for t in range(1, T + 1):
        m = m @ FT
        P = F @ P @ FT + Q
        mp[t] = m
        Pp[t] = P
        active = has_meas[:, t - 1]
        if np.any(active):
            S = H @ P @ HT + R / safe_w[:, t - 1, None, None]
            PHt = P @ HT
            K = np.linalg.solve(S, np.swapaxes(PHt, 1, 2)).swapaxes(1, 2)
            K *= active[:, None, None]
            innov = y[:, t - 1] - m @ HT
            m = m + np.einsum("bij,bj->bi", K, innov)
            # Joseph form keeps P symmetric and positive semidefinite with tiny process noise.
            IKH = eye - K @ H
            P = IKH @ P @ np.swapaxes(IKH, 1, 2) + K @ (R / safe_w[:, t - 1, None, None]) @ np.swapaxes(
                K, 1, 2
            )
        mf[t] = m
        Pf[t] = P

    # Gains G_t = Pf_t F' Pp_{t+1}^{-1}, all at once: solve Pp_{t+1} G_t' = F Pf_t.
    rhs = F @ Pf[:-1]
    G = np.swapaxes(np.linalg.solve(Pp[1:], rhs), -1, -2)
    ms = np.empty_like(mf)
    ms[T] = mf[T]
    for t in range(T - 1, -1, -1):
        ms[t] = mf[t] + np.einsum("bij,bj->bi", G[t], ms[t + 1] - mp[t + 1])
    return SmootherResult(
        means=np.swapaxes(ms, 0, 1),
        filtered_means=np.swapaxes(mf, 0, 1),
        filtered_covs=np.swapaxes(Pf, 0, 1),
        predicted_covs=np.swapaxes(Pp, 0, 1),
    )
