"""The gated E-step: only the (locale, time, platform) triples that can matter, without forming the
``N x T x M`` array.

With ``gate=G`` a triple is dropped when its log weight is more than ``G`` nats below the best of its
(locale, platform) pair, or more than 746 below its locale's best (where the dense computation's ``exp``
underflows to exactly zero anyway). A KD-tree per platform gives each pair's nearest path point, whose
log weight (priors included) bounds the pair's best from below, and a triple can only be kept if its
distance satisfies ``d^2 <= 2r (max_t log pi^tau + log pi^k - bound + G)``: the candidates are the
path points within that radius (:mod:`pmht_opt.estep.candidates`). Gating per pair, not per locale, keeps
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
from typing import TypeVar

import numpy as np

from pmht_opt.estep.candidates import Block, SupportCandidates, TreeCandidates
from pmht_opt.estep.gated_sums import GatedAccumulator, GatedBlock, GatedWeights
from pmht_opt.estep.likelihood import (
    _SAFE_SCALE,
    _UNDERFLOW,
    EStepInputs,
    log_const,
    log_weights_from_d2,
    squared_distance,
)
from pmht_opt.exceptions import ConfigError
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


def estep_gated(inputs: EStepInputs, margin: float, threads: int = 1) -> GatedWeights | None:
    """The gated E-step (module docstring), or ``None`` where the dense one should run instead.

    The candidates come a block of locales at a time, sorted by locale and platform, so every
    locale's and every (locale, platform) pair's candidates are contiguous and the whole computation
    of a block (log weights, the pair and locale maxima, the gate, the normalisation) runs on arrays
    of a block's size; only the weights and their columns, which the CSR matrix keeps, grow with
    the number of triples.
    """
    out = GatedAccumulator(inputs, *_sizes(inputs))
    for block in _gated_blocks(inputs, margin, threads, out.prepare):
        if block is None:
            return None
        out.add(block)
    return out.result(inputs)


def gated_log_normalisers(inputs: EStepInputs, margin: float, threads: int = 1) -> np.ndarray | None:
    """The log-normalisers of :func:`estep_gated` alone (bit for bit), without keeping its weights;
    ``None`` where it would give way to the dense E-step."""
    lse = np.empty(inputs.locales.shape[0])
    for block in _gated_blocks(inputs, margin, threads, lambda b: (b[0], b[1], b[-1])):
        if block is None:
            return None
        lo, hi, lse[lo:hi] = block
    return lse


def _sizes(inputs: EStepInputs) -> tuple[int, int, int]:
    """``(N, T, M)`` of an E-step's inputs."""
    M, T, _ = inputs.positions.shape
    return inputs.locales.shape[0], T, M


B = TypeVar("B")


def _gated_blocks(
    inputs: EStepInputs, margin: float, threads: int, finish: Callable[[GatedBlock], B]
) -> Iterator[B | None]:
    """The gated E-step a block of locales at a time: ``finish`` of ``(lo, hi, local rows, times,
    platforms, normalised weights, log-normalisers of rows lo .. hi - 1)`` for the kept triples, in
    order; a ``None`` (and nothing after it) where the dense E-step should run instead. With
    ``threads > 1`` the blocks, ``finish`` included, are worked on concurrently and taken in order
    (:func:`pmht_opt.parallel.ordered_map`): the same blocks, arithmetic and decisions."""
    source = _choose_source(inputs, margin)
    if source is None:
        yield None
        return
    N, T, M = _sizes(inputs)
    budget = GATE_MAX_FRACTION * N * T * M
    const = log_const(inputs.r, T, M, inputs.log_time_prior is None, inputs.log_platform_prior is None)

    def work(lo: int, hi: int) -> tuple[int, B | None]:
        count, block = _gate(inputs, source.block(lo, hi), const, margin)
        return count, None if block is None else finish(block)

    total = 0
    for count, done in ordered_map(work, source.spans(), threads):
        total += count
        if total > budget or done is None:
            yield None
            return
        yield done


def _gate(
    inputs: EStepInputs, candidates: Block, const: float, margin: float
) -> tuple[int, GatedBlock | None]:
    """One block's candidates gated and normalised: ``(number of candidates, the block)``, the block
    ``None`` if some locale of it has no finite candidate."""
    z, positions, r = inputs.locales, inputs.positions, inputs.r
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    M = positions.shape[0]
    lo, hi, row, t, plat, d2 = candidates
    count = row.size
    if d2 is None:
        d2 = _squared_distances(z, positions, row, t, plat)
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


def _squared_distances(
    z: np.ndarray, positions: np.ndarray, row: np.ndarray, t: np.ndarray, plat: np.ndarray
) -> np.ndarray:
    """Squared distances of the triples ``(row, t, plat)``, with the dense E-step's arithmetic."""
    T = positions.shape[1]
    flat = plat * T + t
    px, py = positions[:, :, 0].ravel()[flat], positions[:, :, 1].ravel()[flat]
    return squared_distance(z[row, 0], z[row, 1], px, py)


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


def _choose_source(inputs: EStepInputs, margin: float) -> TreeCandidates | SupportCandidates | None:
    """Where the candidates come from, or ``None`` where the gate would keep too many to pay.

    Candidates come from whichever is smaller: the points within the pairs' radii, or the support of
    the priors (all triples with a non-zero prior, when the priors confine each locale to a few times
    and platforms, as in :func:`~pmht_opt.plan_smoothed`).
    """
    z, positions, r = inputs.locales, inputs.positions, inputs.r
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    M, T, _ = positions.shape
    N = z.shape[0]
    # Not max(): a NaN second argument would lose to the first.
    scale = float(np.max([np.max(np.abs(positions)), np.max(np.abs(z))]))
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
    tree = TreeCandidates(inputs, margin, scale)
    estimate = tree.estimate(limit=budget)
    if min(support, estimate) > budget:
        return None
    if support <= estimate:
        return SupportCandidates(inputs)
    return tree
