"""How an E-step's weights are held: formed when first read, never before.

A gated E-step computes its weights a block of locales at a time and keeps them as the blocks' pieces
(:class:`~pmht_opt.estep.gated_sums.SparseParts`), joined into one CSR matrix when read; a dense E-step
keeps none and recomputes them, bit for bit, from its inputs when read (:class:`DenseRows`). The EM
loop itself needs only ``W``, ``WZ``, the normalisers and the rows' statistics, which both form on the
way. :class:`WeightsOnRead` is the field of :class:`~pmht_opt.estep.EStepResult` that does this.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from pmht_opt.estep.gated_sums import SparseParts
from pmht_opt.estep.likelihood import EStepInputs

#: Weights below this are left out of an :class:`EStepSummary` (each locale's weights sum to one).
SUMMARY_FLOOR = 1e-12


class DenseRows:
    """The dense weights of an E-step, not kept but recomputed from its inputs when first read.

    The EM loop needs of a dense E-step only ``W``, ``WZ``, the normalisers and the rows' statistics,
    all formed block by block on the way; the ``N x T*M`` weights themselves (4 GB at N = 5000,
    T = 5000, M = 20) are formed again, bit for bit (:meth:`EStepInputs.rows`), only if something reads
    them.
    """

    def __init__(self, inputs: EStepInputs) -> None:
        self.inputs = inputs

    def join(self) -> np.ndarray:
        """The ``(N, T*M)`` weights."""
        return self.inputs.rows(0, self.inputs.locales.shape[0])


class WeightsOnRead:
    """A dataclass field that may be given as :class:`SparseParts` or :class:`DenseRows` and reads as
    the joined matrix or the recomputed array, formed once, on the first read (the pieces are then
    dropped; two threads reading at once wait for one)."""

    _lock = threading.Lock()

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, obj: object, objtype: type | None = None) -> np.ndarray | sp.csr_matrix:
        if obj is None:  # no default: the field is required
            raise AttributeError(self.slot[1:])
        value = obj.__dict__[self.slot]
        if isinstance(value, (SparseParts, DenseRows)):
            with self._lock:
                value = obj.__dict__[self.slot]
                if isinstance(value, (SparseParts, DenseRows)):
                    value = obj.__dict__[self.slot] = value.join()
        return value

    def __set__(self, obj: object, value: np.ndarray | sp.csr_matrix | SparseParts | DenseRows) -> None:
        obj.__dict__[self.slot] = value

    def sparse(self, obj: object) -> bool:
        """Whether ``obj``'s value is sparse, without joining pieces."""
        value = obj.__dict__[self.slot]
        return isinstance(value, SparseParts) or sp.issparse(value)

    def dense(self, obj: object) -> np.ndarray | None:
        """``obj``'s dense weights if they are held (given, or recomputed by an earlier read), else
        ``None``; forms nothing."""
        value = obj.__dict__[self.slot]
        return value if isinstance(value, np.ndarray) else None

    def unread(self, obj: object) -> DenseRows | None:
        """``obj``'s dense weights not yet recomputed, else ``None``."""
        value = obj.__dict__[self.slot]
        return value if isinstance(value, DenseRows) else None


WEIGHTS = WeightsOnRead()


def dense_to_csr(rows: Callable[[int, int], np.ndarray], N: int, C: int, floor: float) -> sp.csr_matrix:
    """The entries of the dense ``(N, C)`` weights at or above ``floor`` as CSR (the matrix ``scipy``
    builds from the floored array), formed a few rows at a time (``rows(lo, hi)``): a pass to count
    each row's entries, a pass to copy them, and nothing of the weights' size allocated but the
    result."""
    step = max(1, (1 << 20) // max(C, 1))
    indptr = np.zeros(N + 1, dtype=np.int64)
    for lo in range(0, N, step):
        block = rows(lo, min(lo + step, N))
        indptr[lo + 1 : lo + 1 + block.shape[0]] = np.count_nonzero(kept_entries(block, floor), axis=1)
    np.cumsum(indptr, out=indptr)
    index = np.int32 if max(int(indptr[-1]), C) <= np.iinfo(np.int32).max else np.int64
    data = np.empty(int(indptr[-1]))
    cols = np.empty(int(indptr[-1]), dtype=index)
    for lo in range(0, N, step):
        block = rows(lo, min(lo + step, N))
        keep = kept_entries(block, floor)
        a, b = indptr[lo], indptr[lo + block.shape[0]]
        data[a:b] = block[keep]
        cols[a:b] = np.nonzero(keep)[1]
    return sp.csr_matrix((data, cols, indptr.astype(index, copy=False)), shape=(N, C))


def kept_entries(block: np.ndarray, floor: float) -> np.ndarray:
    """The entries a summary keeps: at or above ``floor``, and non-zero (scipy keeps no zeros)."""
    keep = block >= floor
    if floor <= 0.0:
        keep &= block != 0.0
    return keep


@dataclass(frozen=True)
class EStepSummary:
    """An E-step kept compactly, as a plan keeps its final one.

    Attributes
    ----------
    weights
        ``(N, T*M)`` sparse weights ``w[n, t*M + m]`` (visit of locale ``n`` by platform ``m`` at time
        ``t + 1``), the entries below ``floor`` left out.
    platform_probability
        ``(N, M)`` probability that each locale is visited by each platform, ``sum_t w[n, t, m]``
        computed before the floor (exact).
    log_normaliser
        ``(N,)`` each locale's log-likelihood term of the EM objective.
    n_platforms
        ``M``.
    floor
        The weight below which entries were left out.
    """

    weights: sp.csr_matrix
    platform_probability: np.ndarray
    log_normaliser: np.ndarray
    n_platforms: int
    floor: float = SUMMARY_FLOOR

    @property
    def n_times(self) -> int:
        """``T``."""
        return int(self.weights.shape[1]) // self.n_platforms

    def locale_weights(self, n: int) -> np.ndarray:
        """``(T, M)`` weights of locale ``n`` (zero below the floor)."""
        return np.asarray(self.weights[n].toarray()).reshape(-1, self.n_platforms)

    def visit_time_distribution(self, n: int) -> np.ndarray:
        """``(T,)`` probability of each visit time of locale ``n``, over all platforms."""
        return self.locale_weights(n).sum(axis=1)
