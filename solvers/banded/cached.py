"""The exact smoother in one call, its assemblies cached: :func:`banded_smoother`."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
from numpy.typing import ArrayLike

from solvers.banded.result import BandedSmootherResult
from solvers.banded.smoother import BandedSmoother
from solvers.exceptions import ProblemError

__all__ = ["banded_smoother"]


_CACHE: OrderedDict[tuple[object, ...], BandedSmoother] = OrderedDict()
_CACHE_SIZE = 4
_CACHE_LOCK = threading.Lock()


def banded_smoother(
    F: ArrayLike,
    Q: ArrayLike,
    h: ArrayLike,
    r: float,
    x0: ArrayLike,
    y: ArrayLike,
    weight: ArrayLike,
    *,
    refine: int = 1,
    check: bool = False,
    threads: int = 1,
) -> BandedSmootherResult:
    """Smooth a batch of systems sharing ``(F, Q, h, r)``: exact, one banded LU for the batch.

    The same smoother as :func:`solvers.kalman.rts_smoother` with a known start (``P0 = 0``) and a
    scalar measurement (``H = h[None]``, ``R = [[r]]``, ``y`` without its measurement axis), but
    computed from the KKT system of the least-squares problem (module docstring). The last few
    ``(F, Q, h, T, B)`` assemblies are cached, so calling it every EM iteration costs no rebuild.

    Parameters
    ----------
    F, Q, h
        ``(n, n)`` transition, ``(n, n)`` positive definite process noise covariance, ``(n,)``
        measurement vector.
    r
        Unit-weight measurement variance (``> 0``).
    x0
        ``(B, n, K)`` known initial states.
    y
        ``(B, T, K)`` measurements for ``t = 1..T``.
    weight
        ``(B, T)`` non-negative weights: the measurement variance at step ``t`` is ``r / w_t``.
    refine, check, threads
        See :meth:`BandedSmoother.solve`.

    Returns
    -------
    BandedSmootherResult
        ``means`` is ``(B, T+1, n, K)`` like ``rts_smoother(...).means``.

    Examples
    --------
    The constant-acceleration model of one axis, four systems, x and y as two columns::

        F = [[1, dt, dt**2 / 2], [0, 1, dt], [0, 0, 1]]
        res = banded_smoother(F, Q, [1, 0, 0], r, x0, y, W)  # x0 (4, 3, 2), y (4, T, 2), W (4, T)
        positions = res.means[:, :, 0, :]                   # (4, T+1, 2)
    """
    Fa = np.asarray(F, dtype=float)
    Qa = np.asarray(Q, dtype=float)
    ha = np.asarray(h, dtype=float)
    w = np.asarray(weight)
    if w.ndim != 2:
        raise ProblemError(f"weight must have shape (B, T), got {w.shape}.")
    B, T = w.shape
    key = (
        Fa.shape,
        Fa.tobytes(),
        Qa.shape,
        Qa.tobytes(),
        ha.shape,
        ha.tobytes(),
        T,
        B,
    )
    with _CACHE_LOCK:
        smoother = _CACHE.get(key)
        if smoother is not None:
            _CACHE.move_to_end(key)
    if smoother is None:
        smoother = BandedSmoother(Fa, Qa, ha, T, B)
        with _CACHE_LOCK:
            _CACHE[key] = smoother
            while len(_CACHE) > _CACHE_SIZE:
                _CACHE.popitem(last=False)
    return smoother.solve(r, x0, y, weight, refine=refine, check=check, threads=threads)
