"""The E-step: assignment weights, prior updates and the EM objective (paper eqs 9-12;
docs/model.md sections 4.2-4.3 and 7).

:func:`estep` weighs every locale against every (time, platform) point of the current paths in the log
domain (:mod:`pmht_opt.estep.likelihood`), densely or, when ``r`` is small, gated
(:mod:`pmht_opt.estep.gating`): only the triples that can carry weight are evaluated and the weights
are a ``scipy.sparse`` CSR matrix
with the dense layout. A gated result keeps its inputs, and :meth:`EStepResult.locale_weights` and
:meth:`EStepResult.weights_ntm` recompute rows exactly as the dense E-step does (bit for bit), dropped
triples included, so consumers that rank tiny weights (the visit choice of
:class:`~pmht_opt.constraints.VisitAll`) see the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from pmht_opt import validation
from pmht_opt.estep.dense import DenseSums, estep_dense
from pmht_opt.estep.gated_sums import GatedWeights, row_maxima
from pmht_opt.estep.gating import GATE_MAX_FRACTION, estep_gated, gate_margin, gated_log_normalisers
from pmht_opt.estep.likelihood import EStepInputs
from pmht_opt.estep.weights import (
    SUMMARY_FLOOR,
    WEIGHTS,
    DenseRows,
    EStepSummary,
    WeightsOnRead,
    dense_to_csr,
)
from pmht_opt.exceptions import ConfigError
from pmht_opt.parallel import thread_count


@dataclass(kw_only=True)
class EStepResult:
    """Weights and their sufficient statistics for one E-step.

    Attributes
    ----------
    weights
        ``w[n, t*M + m]``: posterior probability that locale ``n`` is visited by platform ``m`` at time
        ``t + 1`` (rows sum to one). A dense ``(N, T*M)`` array, or, from a gated E-step
        (:attr:`gated`), a ``scipy.sparse.csr_matrix`` of the same shape and layout whose missing
        entries are weights below ``exp(-gate)`` of their row's largest (zero). The methods below
        handle both; :meth:`weights_ntm` gives a dense ``(N, T, M)`` array. Either is formed when
        first read (:mod:`pmht_opt.estep.weights`): a gated E-step's from the blocks' pieces, a dense
        E-step's recomputed from its inputs, bit for bit.
    W
        ``(T, M)``, ``sum_n w[n, t, m]``: the weight of the synthetic measurement.
    WZ
        ``(T, M, 2)``, ``sum_n w[n, t, m] z_n``; the synthetic measurement is ``WZ / W`` (eq. 15).
    log_normaliser
        ``(N,)``, ``log sum_{t,m} pi^tau pi^k zeta(z_n | x_t^m)``; its sum is the data term of the EM
        objective.
    """

    weights: WeightsOnRead = WEIGHTS
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    n_platforms: int
    #: The E-step's inputs, kept to recompute rows exactly. Not copied: arrays changed in place after
    #: the E-step would change the weights recomputed from them (nothing in the package does).
    inputs: EStepInputs | None = field(default=None, repr=False, compare=False)
    #: Computed by the E-step on the way, so as not to pass over the weights again:
    #: ``sum_t w[n, t, m]`` ``(N, M)``, each row's column of largest weight and that weight.
    platform_totals: np.ndarray | None = field(default=None, repr=False, compare=False)
    best_column: np.ndarray | None = field(default=None, repr=False, compare=False)
    largest: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: ``sum_m w[n, t, m]`` ``(N, T)``, computed on the way by a dense E-step asked for it
    #: (``estep(time_totals=True)``); otherwise :meth:`time_prior` recomputes it from the weights.
    time_totals: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def gated(self) -> bool:
        """Whether the weights are sparse (a gated E-step)."""
        return WEIGHTS.sparse(self)

    @property
    def n_times(self) -> int:
        """``T``."""
        return int(self.W.shape[0])

    @property
    def log_likelihood(self) -> float:
        """``sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)``."""
        return float(np.sum(self.log_normaliser))

    def _triples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stored entries of sparse weights as ``(row, column, value)``."""
        w = self.weights
        assert isinstance(w, sp.csr_matrix)
        rows = np.repeat(np.arange(w.shape[0]), np.diff(w.indptr))
        return rows, w.indices, w.data

    def weights_ntm(self) -> np.ndarray:
        """Weights as ``(N, T, M)``: a view of dense weights held; otherwise a new array, recomputed
        (for gated weights with every triple, the dropped ones too) as the dense E-step gives it."""
        held = WEIGHTS.dense(self)
        if held is not None:
            return held.reshape(held.shape[0], -1, self.n_platforms)
        if self.inputs is not None:  # recomputed: the weights need not be formed (nor joined)
            N = self.log_normaliser.shape[0]
            return self.inputs.rows(0, N).reshape(N, -1, self.n_platforms)
        w = self.weights
        dense = w.toarray() if isinstance(w, sp.csr_matrix) else w
        return np.asarray(dense).reshape(w.shape[0], -1, self.n_platforms)

    def locale_weights(self, n: int) -> np.ndarray:
        """Weights of locale ``n`` as ``(T, M)``: a view of dense weights held; otherwise the row
        recomputed (for gated weights with every triple, so the ones the gate dropped keep their
        tiny values and order)."""
        held = WEIGHTS.dense(self)
        if held is not None:
            return held[n].reshape(-1, self.n_platforms)
        return self.locales_weights(n, n + 1)[0]

    def locales_weights(self, lo: int, hi: int) -> np.ndarray:
        """Weights of locales ``lo .. hi - 1`` as ``(hi - lo, T, M)``, each row as :meth:`locale_weights`
        gives it (recomputed rows agree with one another bit for bit whatever the range)."""
        held = WEIGHTS.dense(self)
        if held is not None:
            rows = held[lo:hi]
        elif self.inputs is not None:  # recomputed: the weights need not be formed (nor joined)
            rows = self.inputs.rows(lo, hi)
        else:  # sparse weights without their inputs
            w = self.weights
            assert isinstance(w, sp.csr_matrix)
            rows = w[lo:hi].toarray()
        return rows.reshape(hi - lo, self.n_times, self.n_platforms)

    def time_prior(self) -> np.ndarray:
        """Updated ``pi^tau[n, t] = sum_m w[n, t, m]`` (eq. 11), ``(N, T)``."""
        if self.time_totals is not None:
            return self.time_totals.copy()
        if self.gated:
            N, T, M = self.weights.shape[0], self.n_times, self.n_platforms
            rows, cols, vals = self._triples()
            return np.bincount(rows * T + cols // M, weights=vals, minlength=N * T).reshape(N, T)
        return self.weights_ntm().sum(axis=2)

    def platform_prior(self) -> np.ndarray:
        """Updated ``pi^k[n, m] = sum_t w[n, t, m]`` (eq. 12), ``(N, M)``."""
        if self.platform_totals is not None:
            return self.platform_totals.copy()
        if self.gated:
            N, M = self.weights.shape[0], self.n_platforms
            rows, cols, vals = self._triples()
            return np.bincount(rows * M + cols % M, weights=vals, minlength=N * M).reshape(N, M)
        return self.weights_ntm().sum(axis=1)

    def _argmax(self) -> np.ndarray:
        """Column of each row's largest weight (the first one among ties, as ``np.argmax``)."""
        if self.best_column is not None:
            return self.best_column
        w = self.weights
        if isinstance(w, sp.csr_matrix):
            rows, cols, vals = self._triples()
            return row_maxima(vals, cols, rows, w.indptr[:-1], w.shape[1])[1]
        return np.argmax(w, axis=1)

    def map_assignment(self) -> tuple[np.ndarray, np.ndarray]:
        """Most probable ``(platform, time)`` per locale; times are in ``1..T``."""
        idx = self._argmax()
        return idx % self.n_platforms, idx // self.n_platforms + 1

    def max_weight(self) -> np.ndarray:
        """``(N,)`` the weight of each locale's most probable ``(time, platform)``."""
        if self.largest is not None:
            return self.largest.copy()
        w = self.weights
        if isinstance(w, sp.csr_matrix):
            return np.maximum.reduceat(w.data, w.indptr[:-1])
        return np.max(w, axis=1)

    def summary(self, floor: float = SUMMARY_FLOOR) -> EStepSummary:
        """This E-step without its dense arrays: weights at or above ``floor`` and the exact
        per-locale platform probabilities (:class:`EStepSummary`)."""
        unread = WEIGHTS.unread(self)
        if unread is not None:  # the rows recomputed a block at a time, never all at once
            csr = dense_to_csr(unread.inputs.rows, self.log_normaliser.shape[0], self.W.size, floor)
        elif isinstance(w := self.weights, sp.csr_matrix):
            csr = w.copy()
            csr.data[csr.data < floor] = 0.0
            csr.eliminate_zeros()
        else:
            csr = dense_to_csr(lambda lo, hi: w[lo:hi], w.shape[0], w.shape[1], floor)
        return EStepSummary(
            weights=csr,
            platform_probability=self.platform_prior(),
            log_normaliser=self.log_normaliser.copy(),
            n_platforms=self.n_platforms,
            floor=floor,
        )


def log_likelihood(
    locales: np.ndarray,
    positions: np.ndarray,
    log_time_prior: np.ndarray | None,
    log_platform_prior: np.ndarray | None,
    r: float,
    gate: float | str | None = None,
    threads: int = 1,
) -> float:
    """``estep(...).log_likelihood`` (bit for bit, the same gate decision and arithmetic), without
    forming or keeping the weights: the data term of the EM objective where only it is wanted.

    Annealing scores each iteration at its own ``r`` but weighs the next one at the next ``r``, so
    every annealing iteration needs an objective at a penalty whose weights are never used.

    Parameters
    ----------
    locales, positions, log_time_prior, log_platform_prior, r, gate, threads
        As for :func:`estep`.

    Returns
    -------
    float
        ``sum_n log sum_{t,m} pi^tau[n,t] pi^k[n,m] zeta(z_n | x_t^m)``.
    """
    margin, threads = _settings(positions, gate, threads)
    inputs = EStepInputs(locales, positions, log_time_prior, log_platform_prior, _penalty("r", r))
    return _log_likelihood(inputs, margin, threads)


def _settings(positions: np.ndarray, gate: float | str | None, threads: int) -> tuple[float | None, int]:
    """The gate's margin and the thread count, checked (:class:`ConfigError` naming the field)."""
    M, T, _ = positions.shape
    return gate_margin(gate, T, M), thread_count(threads)


def _penalty(field: str, r: float) -> float:
    """A penalty ``r`` as a positive finite float; :class:`ConfigError` naming ``field`` otherwise."""
    return validation.real(field, r, ConfigError, lo=0.0, lo_open=True)


def _log_likelihood(inputs: EStepInputs, margin: float | None, threads: int) -> float:
    """:func:`log_likelihood` of checked inputs."""
    lse = gated_log_normalisers(inputs, margin, threads) if margin is not None else None
    if lse is None:
        lse = np.empty(inputs.locales.shape[0])
        for block in inputs.dense_blocks(None, threads):
            lse[block.i : block.j] = block.lse
    return float(np.sum(lse))


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
    gate: float | str | None = None,
    threads: int = 1,
    *,
    time_totals: bool = True,
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
    gate
        ``None`` (default): the dense computation. A margin ``G`` in nats (or ``"auto"``, see
        :func:`gate_margin`): drop the triples whose log weight is more than ``G`` below the best of
        their (locale, platform) pair (module docstring); the dense computation still runs when the
        gate would keep more than :data:`GATE_MAX_FRACTION` of the triples or the paths are not
        finite.
    threads
        Blocks of locales computed concurrently on up to this many threads. The blocks, their
        arithmetic and the order of every sum over them do not depend on it: the result is the same
        to the last bit.
    time_totals
        Whether a dense E-step forms ``sum_m w[n, t, m]`` on the way, for :meth:`EStepResult.time_prior`
        (which otherwise recomputes the weights, with the same numbers): only a re-estimated time prior
        needs it, and the sum over the few platforms of every ``(n, t)`` costs as much as the rest of
        the statistics together.
    """
    margin, threads = _settings(positions, gate, threads)
    time_totals = validation.flag("time_totals", time_totals)
    inputs = EStepInputs(locales, positions, log_time_prior, log_platform_prior, _penalty("r", r))
    if margin is not None:
        gated = estep_gated(inputs, margin, threads)
        if gated is not None:
            return _gated_result(gated, positions.shape[0])
    return _dense_result(estep_dense(inputs, threads, time_totals))


def estep_scored(
    locales: np.ndarray,
    positions: np.ndarray,
    log_time_prior: np.ndarray | None,
    log_platform_prior: np.ndarray | None,
    r: float,
    score_at: float,
    gate: float | str | None = None,
    threads: int = 1,
    *,
    time_totals: bool = True,
) -> tuple[EStepResult, float]:
    """``estep(..., r, ...)`` and ``log_likelihood(..., score_at, ...)`` of the same paths, bit for bit
    (the same gate decisions and arithmetic), the squared distances formed once where both are dense.

    Annealing weighs the next iteration at the next ``r`` but scores this one at its own: the two
    differ only in the penalty, and the distances are a third of a dense E-step's work.

    Parameters
    ----------
    locales, positions, log_time_prior, log_platform_prior, r, gate, threads, time_totals
        As for :func:`estep`.
    score_at
        The penalty of the log-likelihood.

    Returns
    -------
    tuple[EStepResult, float]
        The E-step at ``r`` and the log-likelihood at ``score_at``.
    """
    margin, threads = _settings(positions, gate, threads)
    time_totals = validation.flag("time_totals", time_totals)
    inputs = EStepInputs(locales, positions, log_time_prior, log_platform_prior, _penalty("r", r))
    score_at = _penalty("score_at", score_at)
    scored = EStepInputs(locales, positions, log_time_prior, log_platform_prior, score_at)
    M = positions.shape[0]
    if margin is not None:
        gated = estep_gated(inputs, margin, threads)
        if gated is not None:
            return _gated_result(gated, M), _log_likelihood(scored, margin, threads)
        lse = gated_log_normalisers(scored, margin, threads)
        if lse is not None:
            return _dense_result(estep_dense(inputs, threads, time_totals)), float(np.sum(lse))
    dense = estep_dense(inputs, threads, time_totals, score_at)
    assert dense.score is not None
    return _dense_result(dense), float(np.sum(dense.score))


def _gated_result(gated: GatedWeights, M: int) -> EStepResult:
    """The :class:`EStepResult` of a gated E-step."""
    return EStepResult(
        weights=gated.weights,
        W=gated.W,
        WZ=gated.WZ,
        log_normaliser=gated.log_normaliser,
        n_platforms=M,
        inputs=gated.inputs,
        platform_totals=gated.platform_totals,
        best_column=gated.best_column,
        largest=gated.largest,
    )


def _dense_result(dense: DenseSums) -> EStepResult:
    """The :class:`EStepResult` of a dense E-step: its weights are recomputed only if read."""
    return EStepResult(
        weights=DenseRows(dense.inputs),
        W=dense.W,
        WZ=dense.WZ,
        log_normaliser=dense.log_normaliser,
        n_platforms=dense.W.shape[1],
        inputs=dense.inputs,
        platform_totals=dense.platform_totals,
        best_column=dense.best_column,
        largest=dense.largest,
        time_totals=dense.time_totals,
    )


__all__ = [
    "GATE_MAX_FRACTION",
    "SUMMARY_FLOOR",
    "EStepInputs",
    "EStepResult",
    "EStepSummary",
    "estep",
    "estep_scored",
    "gate_margin",
    "log_likelihood",
    "safe_log",
]
