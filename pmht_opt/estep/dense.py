"""The dense E-step: every (locale, time, platform) triple, a block of locales at a time.

The counterpart of the gated E-step (:mod:`pmht_opt.estep.gating`), for wide ``r`` (early in annealing) and
wherever the gate would keep too much. Each block's weights are formed in a scratch array
(:meth:`~pmht_opt.estep.likelihood.EStepInputs.dense_blocks`) and reduced while in cache to what the EM loop
reads: ``W``, ``WZ``, the log-normalisers and each row's statistics. The ``N x T*M`` weights are not
kept; :class:`~pmht_opt.estep.weights.DenseRows` recomputes them, bit for bit, if something reads them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pmht_opt.estep.likelihood import EStepInputs

__all__ = ["DenseSums", "estep_dense", "platform_sums"]


class DenseSums(NamedTuple):
    """What the dense E-step computes: ``W (T, M)``, ``WZ (T, M, 2)``, the log-normalisers ``(N,)``,
    each row's ``sum_t w`` ``(N, M)``, ``sum_m w`` ``(N, T)`` (``None`` unless asked for), column of
    largest weight (the first among ties) and that weight, and the log-normalisers at the second
    penalty (``None`` unless asked for)."""

    inputs: EStepInputs
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    platform_totals: np.ndarray
    best_column: np.ndarray
    largest: np.ndarray
    time_totals: np.ndarray | None
    score: np.ndarray | None


def estep_dense(
    inputs: EStepInputs, threads: int = 1, time_totals: bool = True, score_at: float | None = None
) -> DenseSums:
    """The dense E-step of ``inputs``, its sums and its rows' statistics formed block by block on the
    way (``time_totals``: also ``sum_m w``); with ``score_at`` also the log-normalisers at that
    penalty (:meth:`EStepInputs.dense_blocks`). Blocks on up to ``threads`` threads, the same numbers
    for any number."""
    z = inputs.locales
    M, T, _ = inputs.positions.shape
    N = z.shape[0]
    TM = T * M
    lse = np.empty(N)
    score = None if score_at is None else np.empty(N)
    W = np.zeros(TM)
    WZ = np.zeros((2, TM))
    platform, by_time = np.empty((N, M)), np.empty((N, T)) if time_totals else None
    best_column, largest = np.empty(N, dtype=np.intp), np.empty(N)

    def sums(i: int, j: int, block: np.ndarray) -> tuple[np.ndarray | None, ...]:
        """A block's sums and its rows' statistics, formed with the block (on its thread; the block is
        scratch, overwritten later), the sums then added in block order."""
        ntm = block.reshape(j - i, T, M)
        column = np.argmax(block, axis=1)
        top = block[np.arange(j - i), column]
        by_time = ntm.sum(axis=2) if time_totals else None
        return block.sum(axis=0), z[i:j].T @ block, platform_sums(ntm), by_time, column, top

    for block in inputs.dense_blocks(None, threads, sums, score_at):
        i, j, parts = block.i, block.j, block.done
        lse[i:j] = block.lse
        if score is not None and block.score is not None:
            score[i:j] = block.score
        W += parts[0]
        WZ += parts[1]
        platform[i:j], by_block, best_column[i:j], largest[i:j] = parts[2:]
        if by_time is not None:
            by_time[i:j] = by_block
    return DenseSums(
        inputs=inputs,
        W=W.reshape(T, M),
        WZ=WZ.T.reshape(T, M, 2),
        log_normaliser=lse,
        platform_totals=platform,
        best_column=best_column,
        largest=largest,
        time_totals=by_time,
        score=score,
    )


def platform_sums(ntm: np.ndarray) -> np.ndarray:
    """``ntm.sum(axis=1)`` of an ``(n, T, M)`` array, bit for bit, several times faster for ``M > 1``.

    With ``M > 1`` NumPy adds the ``T`` terms of each ``(n, m)`` in order, one time step after another,
    in an inner loop ``M`` elements long, whose overhead per call dominates; ``einsum`` adds them in the
    same order over longer loops (tested for every ``M`` up to 24). With ``M = 1`` the terms are
    contiguous and NumPy sums them pairwise, which ``einsum`` does not reproduce.
    """
    if ntm.shape[2] == 1:
        return ntm.sum(axis=1)
    return np.einsum("ntm->nm", ntm)
