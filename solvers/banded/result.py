"""What the exact smoother returns: means and the objective's parts, formed from its solution on use."""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["BandedSmootherResult"]


class BandedSmootherResult:
    """Smoothed means and the parts of the objective, per system and column.

    Formed from the solution of the KKT system on first use (a caller that reads the states only
    pays for no objective), each the same numbers whenever it is formed.

    Attributes
    ----------
    means
        ``(B, T+1, n, K)`` smoothed states, ``means[:, 0]`` is the known ``x0``.
    noise
        ``(B, T, n, K)`` whitened process noise ``u_t = L^-1 (x_t - F x_{t-1})`` (``L`` the lower
        Cholesky factor of ``Q``), computed as ``L' lam_t`` from the multipliers, so it keeps its
        relative precision when ``x_t - F x_{t-1}`` is many orders of magnitude below ``x_t``.
    prior
        ``(B, K)``: ``1/2 sum_t ||u_t||^2``.
    fit
        ``(B, K)``: ``sum_t w_t / (2 r) (h' x_t - y_t)^2``.
    backward_error
        Componentwise backward error of the final solution of the scaled KKT system,
        ``max_i |b - A z|_i / (|A| |z| + |b|)_i``, when asked for (``check=True``); else ``None``.
    """

    def __init__(
        self,
        z: np.ndarray,
        x0: np.ndarray,
        y: np.ndarray,
        rho: np.ndarray,
        L: np.ndarray,
        h: np.ndarray,
        backward_error: float | None = None,
    ) -> None:
        # z: (K, B, T, 2n) rows [lam_t, x_t] in the model's units; y: (K, B, T); x0: (B, n, K).
        self._z, self._x0, self._y, self._rho, self._L, self._h = z, x0, y, rho, L, h
        self.backward_error = backward_error

    @functools.cached_property
    def _noise_k(self) -> np.ndarray:
        """``(K, B, T, n)`` rows ``(L' lam_t)'``."""
        n = self._x0.shape[1]
        return np.asarray(self._z[..., :n] @ self._L)

    @functools.cached_property
    def means(self) -> np.ndarray:
        B, n, K = self._x0.shape
        means = np.empty((B, self._z.shape[2] + 1, n, K))
        means[:, 0] = self._x0
        means[:, 1:] = np.moveaxis(self._z[..., n:], 0, -1)
        return means

    @functools.cached_property
    def noise(self) -> np.ndarray:
        # A copy: a caller that changes it must not change the objective's parts formed later.
        return np.moveaxis(self._noise_k, 0, -1).copy()

    @functools.cached_property
    def prior(self) -> np.ndarray:
        noise = self._noise_k
        return np.asarray(0.5 * np.einsum("kbti,kbti->bk", noise, noise))

    @functools.cached_property
    def fit(self) -> np.ndarray:
        n = self._x0.shape[1]
        innov = self._y - self._z[..., n:] @ self._h
        return np.asarray(0.5 * np.einsum("bt,kbt->bk", self._rho, innov * innov))

    @property
    def objective(self) -> np.ndarray:
        """``(B, K)``: ``J = prior + fit`` at the smoothed means."""
        return np.asarray(self.prior + self.fit)

    def side_by_side(self) -> tuple[np.ndarray, np.ndarray]:
        """The columns' states and noise side by side: ``(B, T+1, K n)`` states (column ``k``'s in
        ``[k n, (k + 1) n)``, the start first) and ``(B, T, K n)`` whitened noise; the values of
        :attr:`means` and :attr:`noise`, laid out in one copy each."""
        B, n, K = self._x0.shape
        T = self._z.shape[2]
        states = np.empty((B, T + 1, K, n))
        states[:, 0] = np.moveaxis(self._x0, 2, 1)
        states[:, 1:] = self._z[..., n:].transpose(1, 2, 0, 3)
        noise = self._noise_k.transpose(1, 2, 0, 3).copy()  # a copy even where the transpose is one
        return states.reshape(B, T + 1, K * n), noise.reshape(B, T, K * n)
