"""The E-step: assignment weights, prior updates and the EM objective (SPEC section 2, paper eqs 9-12).

Everything is in the log domain: with ``r = 0.01`` and distances of a few units the likelihoods
``exp(-d^2 / 2r)`` underflow. Arrays are kept two-dimensional, ``(N, T*M)`` with column ``t*M + m``,
so that each step is one BLAS call or one ufunc pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmht_opt.exceptions import PmhtOptError

_LOG_2PI = float(np.log(2.0 * np.pi))
#: Above this coordinate magnitude the expanded form |z|^2 - 2 z.p + |p|^2 could overflow.
_SAFE_SCALE = 1e100


@dataclass
class EStepResult:
    """Weights and their sufficient statistics for one E-step.

    Attributes
    ----------
    weights
        ``w[n, t*M + m]``: posterior probability that locale ``n`` is visited by platform ``m`` at time
        ``t + 1`` (rows sum to one). Reshape with :meth:`weights_ntm`.
    W
        ``(T, M)``, ``sum_n w[n, t, m]``: the weight of the synthetic measurement.
    WZ
        ``(T, M, 2)``, ``sum_n w[n, t, m] z_n``; the synthetic measurement is ``WZ / W`` (eq. 15).
    log_normaliser
        ``(N,)``, ``log sum_{t,m} pi^tau pi^k zeta(z_n | x_t^m)``; its sum is the data term of the EM
        objective.
    """

    weights: np.ndarray
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    n_platforms: int

    @property
    def log_likelihood(self) -> float:
        """``sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)``."""
        return float(np.sum(self.log_normaliser))

    def weights_ntm(self) -> np.ndarray:
        """Weights as ``(N, T, M)`` (a view)."""
        n = self.weights.shape[0]
        return self.weights.reshape(n, -1, self.n_platforms)

    def time_prior(self) -> np.ndarray:
        """Updated ``pi^tau[n, t] = sum_m w[n, t, m]`` (eq. 11), ``(N, T)``."""
        return self.weights_ntm().sum(axis=2)

    def platform_prior(self) -> np.ndarray:
        """Updated ``pi^k[n, m] = sum_t w[n, t, m]`` (eq. 12), ``(N, M)``."""
        return self.weights_ntm().sum(axis=1)

    def map_assignment(self) -> tuple[np.ndarray, np.ndarray]:
        """Most probable ``(platform, time)`` per locale; times are in ``1..T``."""
        idx = np.argmax(self.weights, axis=1)
        return idx % self.n_platforms, idx // self.n_platforms + 1


def safe_log(p: np.ndarray) -> np.ndarray:
    """``log p`` with ``log 0 = -inf`` and no warning."""
    with np.errstate(divide="ignore"):
        return np.log(p)


def estep(
    locales: np.ndarray,
    positions: np.ndarray,
    log_time_prior: np.ndarray | None,
    log_platform_prior: np.ndarray | None,
    r: float,
) -> EStepResult:
    """Compute the weights ``w[n, t, m]`` (eq. 9) for paths ``positions``.

    Parameters
    ----------
    locales
        ``(N, 2)``.
    positions
        ``(M, T, 2)``: platform positions at ``t = 1..T`` (the known start ``t = 0`` is not a visit
        time).
    log_time_prior, log_platform_prior
        ``log pi^tau`` ``(N, T)`` and ``log pi^k`` ``(N, M)``; ``None`` means uniform. Entries may be
        ``-inf`` (a zero prior), but every locale needs some finite entry in each.
    r
        Variance of the Gaussian fitting penalty ``zeta = N(z; H x, r I)``.
    """
    z = locales
    M, T, _ = positions.shape
    N = z.shape[0]
    p = np.ascontiguousarray(positions.transpose(1, 0, 2)).reshape(T * M, 2)
    scale = max(float(np.max(np.abs(p))), float(np.max(np.abs(z))))
    if scale < _SAFE_SCALE:
        ll = z @ p.T
        ll *= -2.0
        ll += np.einsum("ij,ij->i", z, z)[:, None]
        ll += np.einsum("ij,ij->i", p, p)[None, :]
        np.maximum(ll, 0.0, out=ll)
    else:
        # Far-away paths (a diverged plan): hypot avoids the overflow of the squared coordinates.
        ll = np.hypot(z[:, None, 0] - p[None, :, 0], z[:, None, 1] - p[None, :, 1])
        with np.errstate(over="ignore"):
            ll *= ll
    distance2 = None if np.all(np.isfinite(ll)) else ll.copy()
    ll *= -0.5 / r
    ll -= _LOG_2PI + np.log(r)
    view = ll.reshape(N, T, M)
    if log_time_prior is not None:
        view += log_time_prior[:, :, None]
    else:
        ll -= np.log(T)
    if log_platform_prior is not None:
        view += log_platform_prior[:, None, :]
    else:
        ll -= np.log(M)
    mx = ll.max(axis=1)
    bad = ~np.isfinite(mx)
    if np.any(bad):
        _limit_rows(ll, mx, bad, distance2, log_time_prior, log_platform_prior, T, M)
    ll -= mx[:, None]
    np.exp(ll, out=ll)
    s = ll.sum(axis=1)
    ll /= s[:, None]
    lse = mx + np.log(s)
    if np.any(bad):
        lse[bad] = -np.inf  # the likelihood of these rows underflows to exactly zero
    W = ll.sum(axis=0).reshape(T, M)
    WZ = (z.T @ ll).T.reshape(T, M, 2)
    return EStepResult(weights=ll, W=W, WZ=WZ, log_normaliser=lse, n_platforms=M)


def _limit_rows(
    ll: np.ndarray,
    mx: np.ndarray,
    bad: np.ndarray,
    distance2: np.ndarray | None,
    log_time_prior: np.ndarray | None,
    log_platform_prior: np.ndarray | None,
    T: int,
    M: int,
) -> None:
    """Rows whose every log-likelihood is ``-inf``: every allowed pair is infinitely unlikely.

    The weights' limit puts all mass on the nearest allowed (time, platform) pairs, which is what is
    set here; the log-normaliser is ``-inf`` (the objective of such a plan is ``-inf``, not NaN).
    """
    rows = np.flatnonzero(bad)
    allowed = np.ones((rows.size, T, M), dtype=bool)
    if log_time_prior is not None:
        allowed &= np.isfinite(log_time_prior[rows])[:, :, None]
    if log_platform_prior is not None:
        allowed &= np.isfinite(log_platform_prior[rows])[:, None, :]
    allowed2 = allowed.reshape(rows.size, T * M)
    if not np.all(allowed2.any(axis=1)):
        raise PmhtOptError("A locale has a zero prior for every (time, platform) pair.")
    if distance2 is None:
        d2 = np.zeros((rows.size, T * M))
    else:
        d2 = distance2[rows]
    d2 = np.where(allowed2, d2, np.inf)
    best = d2.min(axis=1, keepdims=True)
    winners = allowed2 & (d2 == best) if np.all(np.isfinite(best)) else allowed2
    # log of an indicator: 0 where a winner, -inf elsewhere; the row then normalises over the winners.
    ll[rows] = np.where(winners, 0.0, -np.inf)
    mx[rows] = 0.0
