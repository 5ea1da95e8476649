"""The gated E-step's outputs, filled a block of locales at a time (:mod:`pmht_opt.estep.gating`).

A block's gated, normalised weights become columns of the dense layout, their products with the
locales, each row's platform totals, entry count, largest weight and its column (on any thread); the sums
``W`` and ``WZ`` over all triples are then formed block by block in order. The weights themselves are
kept as the blocks' pieces (:class:`SparseParts`) and joined into one CSR matrix only when read.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from pmht_opt.estep.likelihood import EStepInputs

#: A gated block: ``(lo, hi, local rows, times, platforms, normalised weights, log-normalisers of rows
#: lo .. hi - 1)``.
GatedBlock = tuple[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class SparseParts:
    """CSR weights kept as the pieces a gated E-step computed them in, joined on first use.

    The gated E-step forms its weights a block of locales at a time; joining the blocks into one CSR
    matrix copies every weight and column into memory not touched before, about a tenth of the
    E-step's time at large sizes. The EM loop itself needs only ``W``, ``WZ`` and the normalisers,
    so :class:`EStepResult` joins the pieces only when its ``weights`` are first read.

    Parameters
    ----------
    values, columns
        Each block's weights and their columns, in row order.
    indptr
        ``(N + 1,)`` row pointers of the joined matrix.
    shape
        ``(N, T*M)``.
    """

    def __init__(
        self, values: list[np.ndarray], columns: list[np.ndarray], indptr: np.ndarray, shape: tuple[int, int]
    ) -> None:
        self.values, self.columns, self.indptr, self.shape = values, columns, indptr, shape

    def join(self) -> sp.csr_matrix:
        """The CSR matrix."""
        return sp.csr_matrix(
            (np.concatenate(self.values), np.concatenate(self.columns), self.indptr), shape=self.shape
        )


class GatedWeights(NamedTuple):
    """What the gated E-step computes: sparse weights with the dense layout and their statistics.

    ``platform_totals`` (``sum_t w[n, t, m]``), ``best_column`` (each row's column of largest weight,
    the first among ties) and ``largest`` (that weight) are those of ``weights``, computed block by
    block on the way (their sums in the order a pass over ``weights`` would form them).
    """

    weights: SparseParts
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    inputs: EStepInputs
    platform_totals: np.ndarray
    best_column: np.ndarray
    largest: np.ndarray


def row_maxima(
    data: np.ndarray, indices: np.ndarray, rows: np.ndarray, starts: np.ndarray, n_columns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's largest value and its column, the first among ties (as ``np.argmax`` of the dense
    row), for sparse rows given as ``data`` at columns ``indices``, row ``rows`` of each entry, the
    rows starting at ``starts`` (none empty)."""
    best = np.maximum.reduceat(data, starts)
    column = np.minimum.reduceat(np.where(data == best[rows], indices, n_columns), starts)
    return best, column


class PreparedBlock(NamedTuple):
    """One gated block made ready for :meth:`GatedAccumulator.add` (:meth:`GatedAccumulator.prepare`)."""

    lo: int
    hi: int
    col: np.ndarray
    w: np.ndarray
    wz: tuple[np.ndarray, np.ndarray]
    lse: np.ndarray
    platform: np.ndarray
    counts: np.ndarray
    largest: np.ndarray
    best_column: np.ndarray


class GatedAccumulator:
    """The gated E-step's outputs, filled a block of locales at a time (blocks in order).

    Each sum is formed in the order of the triples (by locale, then platform, then as the tree
    lists them), the order in which one pass over all of them forms it: ``np.add.at`` adds in order
    to what the earlier blocks left, as a single ``np.bincount`` would. Nothing the size of all the
    triples is allocated but the weights and their columns, which the CSR matrix keeps.
    """

    def __init__(self, inputs: EStepInputs, N: int, T: int, M: int) -> None:
        self.N, self.T, self.M = N, T, M
        # The locales' coordinates as two contiguous arrays: a block gathers from them twice.
        self.zx, self.zy = inputs.coordinates
        TM = T * M
        self.W = np.zeros(TM)
        self.WZ = np.zeros((2, TM))
        self.lse = np.empty(N)
        self.platform = np.empty((N, M))
        self.best_column = np.empty(N, dtype=np.intp)
        self.largest = np.empty(N)
        # Columns in the index type scipy keeps when every column fits in it (no conversion copy);
        # the row pointers are converted by scipy, as they are few.
        self.column_dtype = np.int32 if TM <= np.iinfo(np.int32).max else np.int64
        self.indptr = np.zeros(N + 1, dtype=np.int64)
        self.cols: list[np.ndarray] = []
        self.values: list[np.ndarray] = []

    def prepare(self, block: GatedBlock) -> PreparedBlock:
        """Everything of one block that does not depend on the blocks before it (safe on any thread):
        the gated weights ``w`` of locales ``lo .. hi - 1`` (rows ``lo + local``, sorted) at times
        ``t`` and platforms ``plat``, as columns, their products with the locales, the rows' platform
        totals, entry counts and largest weights."""
        lo, hi, local, t, plat, w, lse = block
        M, n = self.M, hi - lo
        col = (t * M + plat).astype(self.column_dtype)
        wz = (w * self.zx[lo:hi][local], w * self.zy[lo:hi][local])
        platform = np.bincount(local * M + plat, weights=w, minlength=n * M).reshape(n, M)
        # The rows are sorted: where each starts, and its number of entries, by bisection.
        bounds = np.searchsorted(local, np.arange(n + 1))
        starts, counts = bounds[:-1], np.diff(bounds)
        largest, best_column = row_maxima(w, col, local, starts, self.T * M)
        return PreparedBlock(lo, hi, col, w, wz, lse, platform, counts, largest, best_column)

    def add(self, block: PreparedBlock) -> None:
        """A prepared block, in order: the sums over all triples are formed here, by ``np.add.at`` in
        the order of the triples."""
        lo, hi, col, w = block.lo, block.hi, block.col, block.w
        np.add.at(self.W, col, w)
        np.add.at(self.WZ[0], col, block.wz[0])
        np.add.at(self.WZ[1], col, block.wz[1])
        self.lse[lo:hi] = block.lse
        self.platform[lo:hi] = block.platform
        self.largest[lo:hi], self.best_column[lo:hi] = block.largest, block.best_column
        self.indptr[lo + 1 : hi + 1] = block.counts
        self.cols.append(col)
        self.values.append(w)

    def result(self, inputs: EStepInputs) -> GatedWeights:
        """The weights (CSR with the dense layout, joined when first read) and everything computed
        with them."""
        N, T, M = self.N, self.T, self.M
        np.cumsum(self.indptr, out=self.indptr)
        weights = SparseParts(self.values, self.cols, self.indptr, (N, T * M))
        return GatedWeights(
            weights,
            self.W.reshape(T, M),
            self.WZ.T.reshape(T, M, 2),
            self.lse,
            inputs,
            self.platform,
            self.best_column,
            self.largest,
        )
