"""The gated E-step: only the (locale, time, platform) triples that can matter, without forming the
``N x T x M`` array.

With ``gate=G`` a triple is dropped when its log weight is more than ``G`` nats below the best of its
(locale, platform) pair, or more than 746 below its locale's best (where the dense computation's ``exp``
underflows to exactly zero anyway). A KD-tree per platform gives each pair's nearest path point, whose
log weight (priors included) bounds the pair's best from below, and a triple can only be kept if its
distance satisfies ``d^2 <= 2r (max_t log pi^tau + log pi^k - bound + G)``: the candidates are the
path points within that radius (:mod:`pmht_opt.candidates`). Gating per pair, not per locale, keeps
every platform's share ``pi^k[n, m] = sum_t w[n, t, m]`` exact down to the underflow, however small:
the re-estimated platform prior can then revive a platform exactly as in the dense EM. With
``G = log(T M) + 37`` (``"auto"``) the mass dropped from a pair is below ``exp(-37) < 1e-16`` of it:
``W``, ``WZ``, the normalisers and ``pi^k`` equal the dense ones to rounding. The time prior's
re-estimate ``pi^tau[n, t] = sum_m w[n, t, m]`` is exact only where some triple of ``(n, t)`` is kept
(zero elsewhere, not tiny). Where the gate would admit too much (a wide ``r``, early in annealing) the
caller runs the dense computation instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple, TypeVar

import numpy as np
import scipy.sparse as sp

from pmht_opt import kernels
from pmht_opt.candidates import Block, SupportCandidates, TreeCandidates
from pmht_opt.exceptions import ConfigError
from pmht_opt.likelihood import (
    _SAFE_SCALE,
    _UNDERFLOW,
    EStepInputs,
    log_const,
    log_weights_from_d2,
    squared_distance,
)
from pmht_opt.parallel import ordered_map

#: ``gate="auto"``: the margin is ``log(T M) + GATE_AUTO_NATS``, so the mass dropped from a (locale,
#: platform) pair is below ``exp(-GATE_AUTO_NATS)`` (8.5e-17) of it, under half the float64 epsilon.
GATE_AUTO_NATS = 37.0
#: The gated E-step runs when it would keep at most this fraction of the ``N T M`` triples: a candidate
#: triple costs several times a dense one (docs/decisions.md section 6.1).
GATE_MAX_FRACTION = 0.1


def gate_margin(gate: float | str | None, T: int, M: int) -> float | None:
    """The gate's log-weight margin: ``None`` (no gate), a positive number, or ``"auto"``.

    ``"auto"`` is ``log(T M) + GATE_AUTO_NATS``. Raises :class:`ConfigError` for anything else.
    """
    if gate is None:
        return None
    if isinstance(gate, str):
        if gate.lower() == "auto":
            return math.log(T * M) + GATE_AUTO_NATS
        raise ConfigError(f"estep_gate: expected 'auto', a positive number or None, got {gate!r}.")
    if isinstance(gate, (bool, np.bool_)) or not isinstance(gate, (int, float, np.integer, np.floating)):
        raise ConfigError(f"estep_gate: expected 'auto', a positive number or None, got {gate!r}.")
    value = float(gate)
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"estep_gate: expected a finite positive margin (nats), got {gate!r}.")
    return value


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


def estep_gated(inputs: EStepInputs, margin: float, threads: int = 1) -> GatedWeights | None:
    """The gated E-step (module docstring), or ``None`` where the dense one should run instead.

    The candidates come a block of locales at a time, sorted by locale and platform, so every
    locale's and every (locale, platform) pair's candidates are contiguous and the whole computation
    of a block (log weights, the pair and locale maxima, the gate, the normalisation) runs on arrays
    of a block's size; only the weights and their columns, which the CSR matrix keeps, grow with
    the number of triples.
    """
    loops = _loops(inputs)
    out = _Accumulator(inputs.locales, *_sizes(inputs), loops)
    for block in _gated_blocks(inputs, margin, threads, out.prepare, loops):
        if block is None:
            return None
        out.add(block)
    return out.result(inputs)


def gated_log_normalisers(inputs: EStepInputs, margin: float, threads: int = 1) -> np.ndarray | None:
    """The log-normalisers of :func:`estep_gated` alone (bit for bit), without keeping its weights;
    ``None`` where it would give way to the dense E-step."""
    lse = np.empty(inputs.locales.shape[0])
    for block in _gated_blocks(inputs, margin, threads, lambda b: (b[0], b[1], b[-1]), _loops(inputs)):
        if block is None:
            return None
        lo, hi, lse[lo:hi] = block
    return lse


def _loops(inputs: EStepInputs) -> Any:
    """The compiled loops for this E-step, or ``None`` for the numpy passes: decided once per E-step,
    so that every block of it is computed, and summed, the same way."""
    N, T, M = _sizes(inputs)
    return kernels.compiled(N * T * M)


def _sizes(inputs: EStepInputs) -> tuple[int, int, int]:
    """``(N, T, M)`` of an E-step's inputs."""
    M, T, _ = inputs.positions.shape
    return inputs.locales.shape[0], T, M


_Block = tuple[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
B = TypeVar("B")


def _gated_blocks(
    inputs: EStepInputs, margin: float, threads: int, finish: Callable[[_Block], B], loops: Any
) -> Iterator[B | None]:
    """The gated E-step a block of locales at a time: ``finish`` of ``(lo, hi, local rows, times,
    platforms, normalised weights, log-normalisers of rows lo .. hi - 1)`` for the kept triples, in
    order; a ``None`` (and nothing after it) where the dense E-step should run instead. With
    ``threads > 1`` the blocks, ``finish`` included, are worked on concurrently and taken in order
    (:func:`pmht_opt.parallel.ordered_map`): the same blocks, arithmetic and decisions."""
    source = _choose_source(inputs, margin, loops)
    if source is None:
        yield None
        return
    N, T, M = _sizes(inputs)
    budget = GATE_MAX_FRACTION * N * T * M
    const = log_const(inputs.r, T, M, inputs.log_time_prior is None, inputs.log_platform_prior is None)

    def work(lo: int, hi: int) -> tuple[int, B | None]:
        count, block = _gate(inputs, source.block(lo, hi), const, margin, loops)
        return count, None if block is None else finish(block)

    total = 0
    for count, done in ordered_map(work, source.spans(), threads):
        total += count
        if total > budget or done is None:
            yield None
            return
        yield done


def _gate(
    inputs: EStepInputs, candidates: Block, const: float, margin: float, loops: Any = None
) -> tuple[int, _Block | None]:
    """One block's candidates gated and normalised: ``(number of candidates, the block)``, the block
    ``None`` if some locale of it has no finite candidate; by the compiled ``loops`` if given."""
    z, positions, r = inputs.locales, inputs.positions, inputs.r
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    M = positions.shape[0]
    lo, hi, row, t, plat, d2 = candidates
    count = row.size
    if d2 is None:
        d2 = _squared_distances(z, positions, row, t, plat)
    if loops is not None:
        return _gate_compiled(loops, inputs, (lo, hi, row, t, plat, d2), const, margin)
    # The candidates' log weights, with the dense E-step's arithmetic (bit for bit the same).
    a = log_weights_from_d2(d2, r, const)
    if log_tau is not None:
        a += log_tau[row, t]
    if log_k is not None:
        a += log_k[row, plat]
    kept = _gate_block(a, row, plat, lo, hi, M, margin)
    if kept is None:
        return count, None
    keep, best = kept
    if keep is not None:
        row, t, plat, a = row[keep], t[keep], plat[keep], a[keep]
    local = row - lo
    a -= best[local]
    np.exp(a, out=a)
    s = np.bincount(local, weights=a, minlength=hi - lo)
    a *= (1.0 / s)[local]
    return count, (lo, hi, local, t, plat, a, best + np.log(s))


def _gate_compiled(
    loops: Any, inputs: EStepInputs, candidates: Block, const: float, margin: float
) -> tuple[int, _Block | None]:
    """:func:`_gate` by the compiled loops (:mod:`pmht_opt.kernels`): the same numbers in two passes
    and numpy's ``exp`` and ``log``."""
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    lo, hi, row, t, plat, d2 = candidates
    assert d2 is not None
    none = np.empty((0, 0))
    kept, best = loops.gate(
        d2,
        row,
        t,
        plat,
        lo,
        hi,
        inputs.positions.shape[0],
        -0.5 / inputs.r,
        const,
        none if log_tau is None else log_tau,
        none if log_k is None else log_k,
        margin,
        _UNDERFLOW,
    )
    if kept < 0:
        return row.size, None
    a = np.exp(d2[:kept])  # a new array: the weights are kept, the candidates' arrays are not
    local, t, plat = row[:kept], t[:kept], plat[:kept]
    s = loops.normalise(a, local, hi - lo)
    return row.size, (lo, hi, local, t, plat, a, best + np.log(s))


def _squared_distances(
    z: np.ndarray, positions: np.ndarray, row: np.ndarray, t: np.ndarray, plat: np.ndarray
) -> np.ndarray:
    """Squared distances of the triples ``(row, t, plat)``, with the dense E-step's arithmetic."""
    T = positions.shape[1]
    flat = plat * T + t
    px, py = positions[:, :, 0].ravel()[flat], positions[:, :, 1].ravel()[flat]
    return squared_distance(z[row, 0], z[row, 1], px, py)


def row_maxima(
    data: np.ndarray, indices: np.ndarray, rows: np.ndarray, starts: np.ndarray, n_columns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's largest value and its column, the first among ties (as ``np.argmax`` of the dense
    row), for sparse rows given as ``data`` at columns ``indices``, row ``rows`` of each entry, the
    rows starting at ``starts`` (none empty)."""
    best = np.maximum.reduceat(data, starts)
    column = np.minimum.reduceat(np.where(data == best[rows], indices, n_columns), starts)
    return best, column


def _gate_block(
    a: np.ndarray, row: np.ndarray, plat: np.ndarray, lo: int, hi: int, M: int, margin: float
) -> tuple[np.ndarray | None, np.ndarray] | None:
    """The gate on one block's log weights ``a``: ``(keep mask or None for all, best per locale)``, or
    ``None`` if some locale of the block has no finite candidate."""
    if a.size == 0:
        return None
    key = row * M + plat
    starts = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1])))
    pair_best = np.maximum.reduceat(a, starts)
    pair_count = np.diff(np.append(starts, a.size))
    pair_row = row[starts] - lo
    best = np.full(hi - lo, -np.inf)
    np.maximum.at(best, pair_row, pair_best)
    if not np.all(np.isfinite(best)):
        return None
    threshold = np.maximum(pair_best - margin, best[pair_row] - _UNDERFLOW)
    keep = a >= np.repeat(threshold, pair_count)
    return (None if np.all(keep) else keep), best


class _Prepared(NamedTuple):
    """One gated block made ready for :meth:`_Accumulator.add` (:meth:`_Accumulator.prepare`)."""

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


class _Accumulator:
    """The gated E-step's outputs, filled a block of locales at a time (blocks in order).

    Each sum is formed in the order of the triples (by locale, then platform, then as the tree
    lists them), the order in which one pass over all of them forms it: ``np.add.at`` adds in order
    to what the earlier blocks left, as a single ``np.bincount`` would. Nothing the size of all the
    triples is allocated but the weights and their columns, which the CSR matrix keeps.
    """

    def __init__(self, z: np.ndarray, N: int, T: int, M: int, loops: Any = None) -> None:
        self.N, self.T, self.M = N, T, M
        #: The compiled loops (:mod:`pmht_opt.kernels`) that prepare and add every block, or ``None``.
        self.loops = loops
        # The locales' coordinates as two contiguous arrays: a block gathers from them twice.
        self.zx, self.zy = np.ascontiguousarray(z[:, 0]), np.ascontiguousarray(z[:, 1])
        TM = T * M
        self.W = np.zeros(TM)
        self.WZ = np.zeros((2, TM))
        #: The compiled loops' sums, ``(T M, 3)``: ``W`` and ``WZ`` of a column side by side.
        self.sums: np.ndarray | None = None
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

    def prepare(self, block: _Block) -> _Prepared:
        """Everything of one block that does not depend on the blocks before it (safe on any thread):
        the gated weights ``w`` of locales ``lo .. hi - 1`` (rows ``lo + local``, sorted) at times
        ``t`` and platforms ``plat``, as columns, their products with the locales, the rows' platform
        totals, entry counts and largest weights."""
        lo, hi, local, t, plat, w, lse = block
        M, n = self.M, hi - lo
        if self.loops is not None:
            return self._prepare_compiled(self.loops, block)
        col = (t * M + plat).astype(self.column_dtype)
        wz = (w * self.zx[lo:hi][local], w * self.zy[lo:hi][local])
        platform = np.bincount(local * M + plat, weights=w, minlength=n * M).reshape(n, M)
        # The rows are sorted: where each starts, and its number of entries, by bisection.
        bounds = np.searchsorted(local, np.arange(n + 1))
        starts, counts = bounds[:-1], np.diff(bounds)
        largest, best_column = row_maxima(w, col, local, starts, self.T * M)
        return _Prepared(lo, hi, col, w, wz, lse, platform, counts, largest, best_column)

    def _prepare_compiled(self, loops: Any, block: _Block) -> _Prepared:
        """:meth:`prepare` by the compiled loop (:mod:`pmht_opt.kernels`): the same numbers, one pass."""
        lo, hi, local, t, plat, w, lse = block
        M, n = self.M, hi - lo
        col = np.empty(w.size, dtype=self.column_dtype)
        wzx, wzy = np.empty(w.size), np.empty(w.size)
        platform = np.empty((n, M))
        counts = np.empty(n, dtype=np.intp)
        largest = np.empty(n)
        best_column = np.empty(n, dtype=np.intp)
        zx, zy = self.zx[lo:hi], self.zy[lo:hi]
        loops.prepare(w, local, t, plat, zx, zy, M, n, col, wzx, wzy, platform, counts, largest, best_column)
        return _Prepared(lo, hi, col, w, (wzx, wzy), lse, platform, counts, largest, best_column)

    def add(self, block: _Prepared) -> None:
        """A prepared block, in order: the sums over all triples are formed here, by ``np.add.at`` in
        the order of the triples."""
        lo, hi, col, w = block.lo, block.hi, block.col, block.w
        if self.loops is not None:
            if self.sums is None:
                self.sums = np.zeros((self.T * self.M, 3))
            self.loops.accumulate(self.sums, col, w, block.wz[0], block.wz[1])
        else:
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
        if self.sums is not None:
            self.W[:] = self.sums[:, 0]
            self.WZ[:] = self.sums[:, 1:].T
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


def _choose_source(
    inputs: EStepInputs, margin: float, loops: Any = None
) -> TreeCandidates | SupportCandidates | None:
    """Where the candidates come from, or ``None`` where the gate would keep too many to pay.

    Candidates come from whichever is smaller: the points within the pairs' radii, or the support of
    the priors (all triples with a non-zero prior, when the priors confine each locale to a few times
    and platforms, as in :func:`~pmht_opt.plan_smoothed`).
    """
    z, positions, r = inputs.locales, inputs.positions, inputs.r
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    M, T, _ = positions.shape
    N = z.shape[0]
    scale = max(float(np.max(np.abs(positions))), float(np.max(np.abs(z))))
    if not scale < _SAFE_SCALE:  # also NaN
        return None
    budget = GATE_MAX_FRACTION * N * T * M
    # Cheap first look: a disc of the gate's radius around every locale already covers this fraction
    # of the area the locales and paths span (their box, a coordinate at a time: numpy's reductions
    # over several axes of a small array are slow, docs/decisions.md section 6.3).
    width = [
        max(z[:, c].max(), positions[..., c].max()) - min(z[:, c].min(), positions[..., c].min())
        for c in (0, 1)
    ]
    area = float(width[0] * width[1])
    if area > 0 and math.pi * 2.0 * r * margin > GATE_MAX_FRACTION * area and log_tau is None:
        return None
    n_times = np.isfinite(log_tau).sum(axis=1) if log_tau is not None else np.full(N, T)
    n_plats = np.isfinite(log_k).sum(axis=1) if log_k is not None else np.full(N, M)
    support = float(np.sum(n_times * n_plats))
    tree = TreeCandidates(inputs, margin, scale, loops)
    estimate = tree.estimate(limit=budget)
    if min(support, estimate) > budget:
        return None
    if support <= estimate:
        return SupportCandidates(inputs)
    return tree
