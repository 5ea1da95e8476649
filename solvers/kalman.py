"""Rauch-Tung-Striebel smoother for a batch of independent linear-Gaussian state-space models.

Each system ``b`` of the batch follows::

    x_0 ~ N(x0[b], P0[b]),   x_t = F x_{t-1} + v_t,  v_t ~ N(0, Q),
    y_t = H x_t + e_t,  e_t ~ N(0, R / weight[b, t])   (no measurement where weight[b, t] == 0)

for ``t = 1..T``. The smoothed means are the minimisers of the corresponding weighted least-squares
problem, which is what makes the smoother a cross-check for QP formulations of the same problem.

Several mean sequences may share one covariance sequence (``K`` "columns"): systems that differ only
in their measurement values, such as the independent x and y axes of a planar constant-acceleration
model with isotropic measurement noise. The covariance recursion is then run once for all of them.

The loop over time is sequential (the filter is a recursion); the batch is vectorised, and the
backward gains are computed for all steps at once after the forward pass.

The process noise of the smoothed path (what the prior term ``1/2 sum ||L^-1 (x_t - F x_{t-1})||^2`` of
the objective is made of) is not taken from the smoothed states: ``x_t - F x_{t-1}`` is a difference of
nearly equal numbers whenever ``Q`` is tiny against the states (``q dt^5`` is 1e-23 at ``dt = 1e-3``),
and it keeps none of its digits. It comes from the adjoint (Bryson-Frazier) recursion instead, ``v_t =
Q rho_t`` with::

    rho_{T+1} = 0,   rho_t = H' S_t^-1 e_t + (I - K_t H)' F' rho_{t+1}

over the filter's innovations ``e_t``, their covariances ``S_t`` and gains ``K_t``: sums of terms of
the size of the result, with no difference of states (``x_t|T = x_t|t-1 + P_t|t-1 rho_t``). The
whitened noise ``L^-1 v_t = L' rho_t`` (``L L' = Q``) is what :class:`solvers.banded.BandedSmoother`
takes from its multipliers; the objectives of the two agree to the rounding level at every ``dt`` a
scenario accepts. Where ``I - K_t H`` has a diagonal entry ``1 - g`` with ``g`` close to 1 (a
measurement far more precise than its prediction), that entry is formed as ``var / S_t`` instead.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from solvers.exceptions import ProblemError
from solvers.problem import dense


@dataclass
class SmootherResult:
    """Moments of the smoother. ``means`` is ``(B, T+1, n, K)`` and includes ``t = 0``.

    :attr:`noise` and :attr:`prior` are formed on first use (a caller that reads the means pays for
    neither).
    """

    means: np.ndarray
    filtered_means: np.ndarray
    filtered_covs: np.ndarray
    predicted_covs: np.ndarray
    _adjoint: tuple[np.ndarray, ...] = field(repr=False, compare=False)

    @functools.cached_property
    def noise(self) -> np.ndarray:
        """``(B, T, n, K)`` whitened process noise ``u_t = L^-1 (x_t - F x_{t-1})`` of the smoothed path
        (``L`` the lower Cholesky factor of ``Q``), from the adjoint recursion of the module docstring:
        it keeps its relative precision when ``x_t - F x_{t-1}`` is far below ``x_t``."""
        return _noise(*self._adjoint)

    @functools.cached_property
    def prior(self) -> np.ndarray:
        """``(B, K)``: ``1/2 sum_t ||u_t||^2``, the prior term of the objective at the smoothed means."""
        return np.asarray(0.5 * np.einsum("btik,btik->bk", self.noise, self.noise))


@dataclass
class _Filtered:
    """The forward pass, time-major: filtered and predicted moments, index ``t`` for ``t = 0..T``
    (the predicted ones are unset at ``t = 0``), and for the adjoint recursion the whitened
    innovations ``a_t = S_t^-1 e_t`` ``(T+1, B, p, K)`` and ``I - K_t H`` ``(T+1, B, n, n)`` (zero and
    the identity where there is no measurement; unset at ``t = 0``)."""

    mf: np.ndarray
    Pf: np.ndarray
    mp: np.ndarray
    Pp: np.ndarray
    a: np.ndarray
    keep: np.ndarray


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

    The result's :attr:`~SmootherResult.noise` and :attr:`~SmootherResult.prior` are the smoothed
    path's whitened process noise and prior term, without cancellation (module docstring).

    Parameters
    ----------
    F, Q
        Transition matrix and process noise covariance, ``(n, n)``; ``Q`` must be positive definite.
    H, R
        Measurement matrix ``(p, n)`` and unit-weight measurement covariance ``(p, p)``.
    x0, P0
        Prior means ``(B, n, K)`` and covariances ``(B, n, n)`` of ``x_0`` (``P0 = 0`` for a known
        start). ``K`` mean sequences share each covariance.
    y
        Measurements ``(B, T, p, K)`` for ``t = 1..T``; ignored where the weight is zero.
    weight
        Non-negative measurement weights ``(B, T)``: the covariance at step ``t`` is ``R / weight``.
    """
    F, Q, H, R = _model(F, Q, H, R)
    x0, P0, y, weight = _batch(H, x0, P0, y, weight)
    T = weight.shape[1]
    # A weight whose reciprocal overflows (below ~1e-308) is a measurement of infinite variance, whose
    # gain is exactly zero: treat it as no measurement instead of dividing by it.
    present = weight > 1.0 / np.finfo(float).max
    # Measurement covariance scale 1 / weight; 1.0 where there is no measurement (its gain is
    # masked to zero, so the value only has to keep the arithmetic finite).
    scale = np.divide(1.0, weight, out=np.ones_like(weight), where=present).T
    B, n, K = x0.shape
    p = H.shape[0]
    f = _Filtered(
        mf=np.empty((T + 1, B, n, K)),
        Pf=np.empty((T + 1, B, n, n)),
        mp=np.empty((T + 1, B, n, K)),
        Pp=np.empty((T + 1, B, n, n)),
        a=np.empty((T + 1, B, p, K)),
        keep=np.empty((T + 1, B, n, n)),
    )
    f.mf[0] = x0
    f.Pf[0] = P0
    # Time-major copies so each step reads contiguous memory.
    yt = np.ascontiguousarray(np.moveaxis(y, 1, 0))
    _forward(f, F, Q, H, R, scale, yt, present.T)
    return _smooth(f, F, Q, H)


def _model(F: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, ...]:
    """``F, Q`` ``(n, n)`` and ``H (p, n)``, ``R (p, p)`` as finite float arrays, or :class:`ProblemError`."""
    F = np.asarray(F, dtype=float)
    n = F.shape[0]
    F = dense("F", F, (n, n))
    Q = dense("Q", Q, (n, n))
    H = np.asarray(H, dtype=float)
    p = H.shape[0]
    H = dense("H", H, (p, n))
    R = dense("R", R, (p, p))
    return F, Q, H, R


def _batch(
    H: np.ndarray, x0: np.ndarray, P0: np.ndarray, y: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, ...]:
    """The batch's starts, measurements and weights as float arrays whose shapes fit each other and the
    measurement matrix ``H``; :class:`ProblemError` naming the first that does not (or is not finite,
    or a negative weight)."""
    p, n = H.shape
    x0 = np.asarray(x0, dtype=float)
    if x0.ndim != 3:
        raise ProblemError(f"x0 must have shape (B, n, K), got {x0.shape}.")
    B, K = x0.shape[0], x0.shape[2]
    x0 = dense("x0", x0, (B, n, K))
    P0 = dense("P0", P0, (B, n, n))
    weight = np.asarray(weight, dtype=float)
    T = weight.shape[1] if weight.ndim == 2 else -1
    weight = dense("weight", weight, (B, T))
    y = dense("y", y, (B, T, p, K))
    if np.any(weight < 0):
        raise ProblemError("weight has negative entries.")
    return x0, P0, y, weight


def _forward(
    f: _Filtered,
    F: np.ndarray,
    Q: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    scale: np.ndarray,
    yt: np.ndarray,
    active: np.ndarray,
) -> None:
    """The forward pass into ``f`` from its moments at ``t = 0``: measurements ``yt (T, B, p, K)`` of
    covariance ``R * scale`` (``scale (T, B)``) where ``active (T, B)``."""
    if H.shape[0] == 1:
        _forward_scalar(f, F, Q, H[0], float(R[0, 0]) * scale, yt, active)
        return
    m, P = f.mf[0], f.Pf[0]
    FT = F.T
    eye = np.eye(F.shape[0])
    HT = H.T
    for t in range(1, f.mf.shape[0]):
        m = F @ m
        P = F @ P @ FT + Q
        f.mp[t] = m
        f.Pp[t] = P
        Rt = R[None] * scale[t - 1][:, None, None]
        S = H @ P @ HT + Rt
        gain = np.swapaxes(np.linalg.solve(S, H @ P), 1, 2)
        gain *= active[t - 1][:, None, None]
        innov = yt[t - 1] - H @ m
        f.a[t] = np.linalg.solve(S, innov) * active[t - 1][:, None, None]
        m = m + gain @ innov
        # Joseph form keeps P symmetric positive semidefinite with tiny process noise.
        IKH = np.subtract(eye, gain @ H, out=f.keep[t])
        P = IKH @ P @ np.swapaxes(IKH, 1, 2) + gain @ Rt @ np.swapaxes(gain, 1, 2)
        f.mf[t] = m
        f.Pf[t] = P


def _forward_scalar(
    f: _Filtered,
    F: np.ndarray,
    Q: np.ndarray,
    h: np.ndarray,
    var: np.ndarray,
    yt: np.ndarray,
    active: np.ndarray,
) -> None:
    """The forward pass for scalar measurements ``h' x`` of variance ``var (T, B)`` where ``active``.

    No matrix inverse, and ``P - g (P h)'`` keeps ``P`` positive semidefinite. Each step writes its
    moments straight into ``f`` (a Python loop over time: the fewer array operations per step, the
    faster), with a measurement's absence as an infinite variance (its gain is then exactly zero)
    and, where ``h`` picks one component, that component read instead of a product with ``h``.
    """
    m, P = f.mf[0], f.Pf[0]
    FT = F.T
    var = np.where(active, var, np.inf)
    picked = np.flatnonzero(h)
    unit = int(picked[0]) if picked.size == 1 and h[picked[0]] == 1.0 else None
    T, B, n = f.mf.shape[0] - 1, f.mf.shape[1], F.shape[0]
    gains = np.empty((T + 1, B, n))
    spreads = np.empty((T + 1, B))
    for t in range(1, T + 1):
        m = np.matmul(F, m, out=f.mp[t])
        P = np.matmul(F @ P, FT, out=f.Pp[t])
        P += Q
        PH = P[:, :, unit] if unit is not None else P @ h  # (B, n)
        hPH = PH[:, unit] if unit is not None else PH @ h
        spread = np.add(hPH, var[t - 1], out=spreads[t])  # S_t; infinite where there is no measurement
        gain = np.divide(PH, spread[:, None], out=gains[t])
        innov = yt[t - 1, :, 0, :] - (m[:, unit, :] if unit is not None else h @ m)  # (B, K)
        np.divide(innov, spread[:, None], out=f.a[t, :, 0, :])
        m_new = np.multiply(gain[:, :, None], innov[:, None, :], out=f.mf[t])
        m_new += m
        P_new = np.multiply(gain[:, :, None], PH[:, None, :], out=f.Pf[t])
        m, P = m_new, np.subtract(P, P_new, out=P_new)
    # I - g h' for the adjoint recursion, all steps at once. Where h picks one component, that
    # component's share kept is var / S, not 1 - hPh / S: when the measurement is far more precise
    # than the prediction, g is 1 to within rounding and the difference would keep none of its digits.
    keep = np.subtract(np.eye(n), gains[1:, :, :, None] * h, out=f.keep[1:])
    if unit is not None:
        share = np.ones((T, B))
        np.divide(var, spreads[1:], out=share, where=active)
        keep[:, :, unit, unit] = share


def _smooth(f: _Filtered, F: np.ndarray, Q: np.ndarray, H: np.ndarray) -> SmootherResult:
    """The backward pass over the filtered moments; the result in batch-major layout."""
    T = f.mf.shape[0] - 1
    # Gains G_t = Pf_t F' Pp_{t+1}^-1 for all t at once: solve Pp_{t+1} G_t' = F Pf_t.
    G = np.swapaxes(np.linalg.solve(f.Pp[1:], F @ f.Pf[:-1]), -1, -2)
    ms = np.empty_like(f.mf)
    ms[T] = f.mf[T]
    step = np.empty_like(f.mf[0])
    for t in range(T - 1, -1, -1):
        np.subtract(ms[t + 1], f.mp[t + 1], out=step)
        np.matmul(G[t], step, out=ms[t])
        ms[t] += f.mf[t]
    return SmootherResult(
        means=np.moveaxis(ms, 0, 1),
        filtered_means=np.moveaxis(f.mf, 0, 1),
        filtered_covs=np.moveaxis(f.Pf, 0, 1),
        predicted_covs=np.moveaxis(f.Pp, 0, 1),
        _adjoint=(F, Q, H, f.a, f.keep),
    )


def _noise(F: np.ndarray, Q: np.ndarray, H: np.ndarray, a: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``(B, T, n, K)`` whitened noise ``L' rho_t`` from the adjoint recursion (module docstring) over
    the whitened innovations ``a (T+1, B, p, K)`` and ``keep = I - K H`` ``(T+1, B, n, n)`` of the
    forward pass; :class:`ProblemError` when ``Q`` is not positive definite."""
    try:
        L = np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        raise ProblemError("Q must be positive definite.") from None
    T = a.shape[0] - 1
    B, n, K = keep.shape[1], keep.shape[2], a.shape[3]
    FT, HT, LT = F.T, H.T, L.T
    keepT = np.swapaxes(keep, -1, -2)
    rho = np.zeros((B, n, K))
    noise = np.empty((T, B, n, K))
    for t in range(T, 0, -1):
        rho = keepT[t] @ (FT @ rho) + HT @ a[t]
        np.matmul(LT, rho, out=noise[t - 1])
    return np.moveaxis(noise, 0, 1)
