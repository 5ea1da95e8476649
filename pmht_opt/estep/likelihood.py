"""Log-domain likelihoods of locales against path points: the arithmetic every E-step shares.

With ``r = 0.01`` and distances of a few units the likelihoods ``exp(-d^2 / 2r)`` underflow, so
everything is in the log domain. Arrays are kept two-dimensional, ``(N, T*M)`` with column
``t*M + m``, so that each step is one ufunc pass. Squared distances are formed elementwise (no
``|z|^2 - 2 z.p + |p|^2`` cancellation), the same way in the dense and the gated E-step and in the
row recompute, so all give bit-identical log weights (ties among times or platforms are then broken
alike).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from pmht_opt.exceptions import PmhtOptError
from pmht_opt.parallel import ordered_map, scratch

_LOG_2PI = float(np.log(2.0 * np.pi))
#: Above this coordinate magnitude the squared differences could overflow (the dense E-step then uses
#: ``hypot``; the gated one is not tried).
_SAFE_SCALE = 1e100
#: Log weights this far below their locale's best give ``exp(.) = 0`` in float64 (dense E-step too).
_UNDERFLOW = 746.0
#: Elements per block of rows in the dense E-step (1 MiB of float64: the block and a temporary stay in
#: a 4 MiB L2 cache).
_BLOCK = 1 << 17


def log_const(r: float, T: int, M: int, uniform_time: bool, uniform_platform: bool) -> float:
    """``log(2 pi r)`` plus the log of the uniform priors' sizes: subtracted from every log weight."""
    const = _LOG_2PI + math.log(r)
    if uniform_time:
        const += math.log(T)
    if uniform_platform:
        const += math.log(M)
    return const


def log_weights_from_d2(d2: np.ndarray, r: float, const: float, out: np.ndarray | None = None) -> np.ndarray:
    """``-d2 / 2r - const``, in place or into ``out`` (``d2`` then unchanged). The dense E-step, the
    gated one and the row recompute all use this and the same elementwise ``(zx - px)^2 + (zy - py)^2``,
    so they give bit-identical log weights (ties among times or platforms are then broken alike)."""
    out = np.multiply(d2, -0.5 / r, out=d2 if out is None else out)
    out -= const
    return out


def squared_distance(
    zx: np.ndarray,
    zy: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    out: np.ndarray | None = None,
    tmp: np.ndarray | None = None,
) -> np.ndarray:
    """``(zx - px)^2 + (zy - py)^2`` elementwise (with broadcasting), into ``out`` if given, with
    ``tmp`` as scratch.

    The one squared-distance arithmetic of every E-step: the dense one, the gated one's candidates and
    the row recompute all form their distances here, so their log weights agree bit for bit.
    """
    d2 = np.subtract(zx, px, out=out)
    d2 *= d2
    dy = np.subtract(zy, py, out=tmp)
    dy *= dy
    d2 += dy
    return d2


@dataclass
class EStepInputs:
    """What an E-step is computed from: enough to recompute any row exactly."""

    locales: np.ndarray
    positions: np.ndarray
    log_time_prior: np.ndarray | None
    log_platform_prior: np.ndarray | None
    r: float

    def __post_init__(self) -> None:
        # Native float64 throughout (no copy where they already are): every path of the E-step, numpy
        # or compiled, then computes in the same precision from the same values.
        self.locales = np.asarray(self.locales, dtype=np.float64)
        self.positions = np.asarray(self.positions, dtype=np.float64)
        if self.log_time_prior is not None:
            self.log_time_prior = np.asarray(self.log_time_prior, dtype=np.float64)
        if self.log_platform_prior is not None:
            self.log_platform_prior = np.asarray(self.log_platform_prior, dtype=np.float64)

    @functools.cached_property
    def coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """The locales' x and y, each contiguous: the gated E-step gathers from them block by block."""
        return np.ascontiguousarray(self.locales[:, 0]), np.ascontiguousarray(self.locales[:, 1])

    def rows(self, lo: int, hi: int) -> np.ndarray:
        """``w[lo:hi]`` as ``(hi - lo, T*M)``, computed as the dense E-step computes it (bit for bit)."""
        M, T, _ = self.positions.shape
        out = np.empty((hi - lo, T * M))
        for _ in self.of_locales(lo, hi).dense_blocks(out):
            pass
        return out

    def of_locales(self, lo: int, hi: int) -> EStepInputs:
        """The inputs of locales ``lo .. hi - 1`` only (the paths and ``r`` are shared)."""
        lt, lk = self.log_time_prior, self.log_platform_prior
        return EStepInputs(
            self.locales[lo:hi],
            self.positions,
            None if lt is None else lt[lo:hi],
            None if lk is None else lk[lo:hi],
            self.r,
        )

    def dense_blocks(
        self,
        out: np.ndarray | None,
        threads: int = 1,
        finish: Callable[[int, int, np.ndarray], Any] | None = None,
        score_at: float | None = None,
    ) -> Iterator[DenseBlock]:
        """Fill ``out (N, T*M)`` with the normalised weights of the locales ``(N, 2)`` against the paths
        ``(M, T, 2)``, a block of rows at a time; yields a :class:`DenseBlock` after each block, in
        order, ``finish`` (default none) computing what the caller wants of the block while it is in
        cache. With ``out=None`` each block's weights go to a scratch block, overwritten later
        (``finish`` must then not return a view of it): for a caller that wants the log-normalisers
        only. With ``threads > 1`` the blocks, ``finish`` included, are computed on threads
        (:func:`pmht_opt.parallel.ordered_map`): the same blocks with the same arithmetic.

        ``score_at``: also the log-normalisers at this second penalty, from the same squared
        distances (the ones the E-step at that penalty would give, bit for bit): annealing scores an
        iteration at its own ``r`` while it weighs the next at the next one.
        """
        M, T, _ = self.positions.shape
        N = self.locales.shape[0]
        TM = T * M
        p = np.ascontiguousarray(self.positions.transpose(1, 0, 2)).reshape(TM, 2)
        uniform = (self.log_time_prior is None, self.log_platform_prior is None)
        const = log_const(self.r, T, M, *uniform)
        const2 = None if score_at is None else log_const(score_at, T, M, *uniform)
        # Blocks of rows small enough to stay in cache through every pass.
        step = max(1, _BLOCK // TM)
        spans = [(i, min(i + step, N)) for i in range(0, N, step)]
        keep = out is not None or finish is not None  # someone reads the weights

        def block(i: int, j: int) -> DenseBlock:
            # Work arrays of the computing thread, kept across calls (fresh memory is slow to touch).
            rows = scratch("dense_rows", j - i, TM) if out is None else out[i:j]
            part = self.of_locales(i, j)
            distance2 = _squared_distances_rows(part.locales, p, rows, scratch("dense_tmp", j - i, TM))
            priors = _prior_rows(part, T, M)
            score = None
            if score_at is not None and const2 is not None:
                other = scratch("dense_score", j - i, TM)
                score = _normalise_rows(rows, score_at, const2, priors, distance2, part, T, M, False, other)
            lse = _normalise_rows(rows, self.r, const, priors, distance2, part, T, M, keep)
            return DenseBlock(i, j, lse, None if finish is None else finish(i, j, rows), score)

        yield from ordered_map(block, spans, threads)


class DenseBlock(NamedTuple):
    """One block of :meth:`EStepInputs.dense_blocks`: rows ``i .. j - 1``, their log-normalisers, what
    ``finish`` made of the block, and the log-normalisers at ``score_at`` (``None`` if not asked)."""

    i: int
    j: int
    lse: np.ndarray
    done: Any
    score: np.ndarray | None


def _squared_distances_rows(
    z: np.ndarray, p: np.ndarray, out: np.ndarray, tmp: np.ndarray
) -> np.ndarray | None:
    """Squared distances of the locales ``z`` to the ``(T*M, 2)`` points ``p`` into ``out`` (``tmp``:
    scratch of its shape); returns a copy of them where some are not finite (for the rows whose every
    log weight is ``-inf``), else ``None``.

    Far-away rows (a diverged plan, or a locale far out) go through ``hypot``, which avoids the
    overflow of the squared coordinates. That is decided row by row (NaN counts as far), so that a
    row's weights never depend on the other rows of its block.
    """
    far = ~(np.maximum(np.max(np.abs(z), axis=1), float(np.max(np.abs(p)))) < _SAFE_SCALE)
    distance2 = None
    if not np.any(far):
        squared_distance(z[:, 0, None], z[:, 1, None], p[None, :, 0], p[None, :, 1], out=out, tmp=tmp)
    else:
        near = ~far
        if np.any(near):
            out[near] = squared_distance(z[near, 0, None], z[near, 1, None], p[None, :, 0], p[None, :, 1])
        zf = z[far]
        far_d = np.hypot(zf[:, None, 0] - p[None, :, 0], zf[:, None, 1] - p[None, :, 1])
        with np.errstate(over="ignore"):
            far_d *= far_d
        out[far] = far_d
        if not np.all(np.isfinite(out)):
            distance2 = out.copy()
    return distance2


def _prior_rows(block: EStepInputs, T: int, M: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The log priors of ``block``'s rows in the block's layout (column ``t*M + m``): ``log pi^tau``
    repeated over the platforms, ``log pi^k`` tiled over the times (``None`` where uniform). Adding
    these is a contiguous pass; a broadcast over an axis of length ``M`` runs NumPy's inner loop ``M``
    elements at a time, three times slower, for the same numbers."""
    lt, lk = block.log_time_prior, block.log_platform_prior
    return (
        None if lt is None else np.repeat(lt, M, axis=1),
        None if lk is None else np.tile(lk, T),
    )


def _normalise_rows(
    d2: np.ndarray,
    r: float,
    const: float,
    priors: tuple[np.ndarray | None, np.ndarray | None],
    distance2: np.ndarray | None,
    block: EStepInputs,
    T: int,
    M: int,
    weights: bool = True,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """The squared distances ``d2`` of ``block``'s rows turned, in place or into ``out`` (``d2`` then
    unchanged), into their normalised weights at penalty ``r`` (unnormalised without ``weights``: for a
    caller that wants the log-normalisers only); returns the rows' log-normalisers. Every row is
    computed on its own, with the same operations whatever the block: the E-step and the exact row
    recompute agree bit for bit."""
    ll = log_weights_from_d2(d2, r, const, out)
    for rows in priors:
        if rows is not None:
            ll += rows
    mx = ll.max(axis=1)
    bad = ~np.isfinite(mx)
    if np.any(bad):
        _limit_rows(ll, mx, bad, distance2, block.log_time_prior, block.log_platform_prior, T, M)
    ll -= mx[:, None]
    below = ll < -_UNDERFLOW
    if np.count_nonzero(below) > below.size // 4:
        # Mostly below -746, where exp is exactly 0 but takes NumPy's slow path (ten times its fast
        # one): the exponentials of the others only, gathered, by the same vectorised exp (the same
        # numbers), and zeros. A masked exp and a masked store would cost as much as the slow path.
        flat = ll.reshape(-1)
        alive = np.flatnonzero(~below)
        kept = np.exp(flat[alive])
        flat.fill(0.0)
        flat[alive] = kept
    else:
        np.exp(ll, out=ll)
    s = ll.sum(axis=1)
    if weights:
        ll *= (1.0 / s)[:, None]
    lse = mx + np.log(s)
    lse[bad] = -np.inf  # the likelihood of these rows underflows to exactly zero
    return lse


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
    # Each row on its own: the nearest allowed pairs, or every allowed pair where even the nearest
    # distance overflows.
    winners = allowed2 & ((d2 == best) | ~np.isfinite(best))
    # log of an indicator: 0 where a winner, -inf elsewhere; the row then normalises over the winners.
    ll[rows] = np.where(winners, 0.0, -np.inf)
    mx[rows] = 0.0
