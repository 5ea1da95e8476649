"""The gated E-step: only the (locale, time, platform) triples that can matter, without forming the
``N x T x M`` array.

With ``gate=G`` a triple is dropped when its log weight is more than ``G`` nats below the best of its
(locale, platform) pair, or more than 746 below its locale's best (where the dense computation's ``exp``
underflows to exactly zero anyway). A KD-tree per platform gives each pair's nearest path point, whose
log weight (priors included) bounds the pair's best from below, and a triple can only be kept if its
distance satisfies ``d^2 <= 2r (max_t log pi^tau + log pi^k - bound + G)``, which a radius query
returns. Gating per pair, not per locale, keeps every platform's share ``pi^k[n, m] = sum_t w[n, t, m]``
exact down to the underflow, however small: the re-estimated platform prior can then revive a platform
exactly as in the dense EM. With ``G = log(T M) + 37`` (``"auto"``) the mass dropped from a pair is below
``exp(-37) < 1e-16`` of it: ``W``, ``WZ``, the normalisers and ``pi^k`` equal the dense ones to rounding.
The time prior's re-estimate ``pi^tau[n, t] = sum_m w[n, t, m]`` is exact only where some triple of
``(n, t)`` is kept (zero elsewhere, not tiny). Where the gate would admit too much (a wide ``r``, early
in annealing) the caller runs the dense computation instead.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from pmht_opt.exceptions import ConfigError
from pmht_opt.likelihood import _SAFE_SCALE, _UNDERFLOW, EStepInputs, log_const, log_weights_from_d2

#: ``gate="auto"``: the margin is ``log(T M) + GATE_AUTO_NATS``, so the mass dropped from a (locale,
#: platform) pair is below ``exp(-GATE_AUTO_NATS)`` (8.5e-17) of it, under half the float64 epsilon.
GATE_AUTO_NATS = 37.0
#: Extra nats on the candidate radius so that rounding in the bound can never lose a kept triple.
_GATE_SLACK = 1.0
#: The gated E-step runs when it would keep at most this fraction of the ``N T M`` triples: a candidate
#: triple costs several times a dense one (docs/decisions.md section 6.1).
GATE_MAX_FRACTION = 0.1
#: Locales sampled to estimate the number of candidates before committing to the gated E-step.
_GATE_SAMPLE = 64


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


class GatedWeights(NamedTuple):
    """What the gated E-step computes: sparse weights with the dense layout and their statistics."""

    weights: sp.csr_matrix
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    inputs: EStepInputs


def _ball_lists(tree: cKDTree, points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of ``tree``'s points within ``radii`` of each of ``points``: ``(counts, flat indices)``."""
    lists = tree.query_ball_point(points, radii, return_sorted=False)
    counts = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
    flat = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.intp, count=int(counts.sum()))
    return counts, flat


def estep_gated(inputs: EStepInputs, margin: float) -> GatedWeights | None:
    """The gated E-step (module docstring), or ``None`` where the dense one should run instead."""
    z, positions, r = inputs.locales, inputs.positions, inputs.r
    log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
    found = _candidates(inputs, margin)
    if found is None or found[0].size == 0:
        return None
    M, T, _ = positions.shape
    N = z.shape[0]
    row, t, plat, seg_count, seg_row = found
    # The candidates' log weights, with the dense E-step's arithmetic (bit for bit the same).
    const = log_const(r, T, M, log_tau is None, log_k is None)
    flat = plat * T + t
    a = z[:, 0][row] - positions[:, :, 0].ravel()[flat]
    a *= a
    dy = z[:, 1][row] - positions[:, :, 1].ravel()[flat]
    dy *= dy
    a += dy
    del dy
    a = log_weights_from_d2(a, r, const)
    if log_tau is not None:
        a += log_tau[row, t]
    if log_k is not None:
        a += log_k[row, plat]
    # Candidates come in segments, one per (locale, platform) pair.
    seg_start = np.zeros(seg_count.size, dtype=np.intp)
    np.cumsum(seg_count[:-1], out=seg_start[1:])
    pair_best = np.maximum.reduceat(a, seg_start)
    best = np.full(N, -np.inf)
    np.maximum.at(best, seg_row, pair_best)
    if not np.all(np.isfinite(best)):
        return None
    threshold = np.maximum(pair_best - margin, best[seg_row] - _UNDERFLOW)
    keep = a >= np.repeat(threshold, seg_count)
    if not np.all(keep):
        row, t, plat, a = row[keep], t[keep], plat[keep], a[keep]
    a -= best[row]
    np.exp(a, out=a)
    s = np.bincount(row, weights=a, minlength=N)
    a *= (1.0 / s)[row]
    return _assemble(z, row, t * M + plat, a, best + np.log(s), T, M, inputs)


def _candidates(inputs: EStepInputs, margin: float) -> Candidates | None:
    """The triples worth evaluating, or ``None`` where the gate would keep too many to pay.

    Candidates come from whichever is smaller: the radius queries, or the support of the priors (all
    triples with a non-zero prior, when the priors confine each locale to a few times and platforms,
    as in :func:`~pmht_opt.plan_smoothed`).
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
    # of the area the locales and paths span.
    lo = np.minimum(z.min(axis=0), positions.min(axis=(0, 1)))
    hi = np.maximum(z.max(axis=0), positions.max(axis=(0, 1)))
    area = float(np.prod(hi - lo))
    if area > 0 and math.pi * 2.0 * r * margin > GATE_MAX_FRACTION * area and log_tau is None:
        return None
    n_times = np.isfinite(log_tau).sum(axis=1) if log_tau is not None else np.full(N, T)
    n_plats = np.isfinite(log_k).sum(axis=1) if log_k is not None else np.full(N, M)
    support = float(np.sum(n_times * n_plats))
    tree = _TreeCandidates(inputs, margin)
    if N <= 2 * _GATE_SAMPLE and tree.ok:
        # Few locales: the estimate would query every one of them, as the candidates do. Query once,
        # stopping past the budget or the support (the same choice as with the estimate, which is then
        # exact).
        found = tree.candidates(min(budget, support - 0.5))
        if found is not None:
            return found
        estimate = math.inf
    else:
        estimate = tree.estimate()
    if min(support, estimate) > budget:
        return None
    if support <= estimate:
        return _support_candidates(log_tau, log_k, N, T, M)
    return tree.candidates(budget)


def _assemble(
    z: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    w: np.ndarray,
    lse: np.ndarray,
    T: int,
    M: int,
    inputs: EStepInputs,
) -> GatedWeights:
    """Weights ``w`` of triples at ``(row, col)`` as CSR with the dense layout, and their sums."""
    N = z.shape[0]
    TM = T * M
    W = np.bincount(col, weights=w, minlength=TM).reshape(T, M)
    WZ = np.empty((T, M, 2))
    WZ[:, :, 0] = np.bincount(col, weights=w * z[row, 0], minlength=TM).reshape(T, M)
    WZ[:, :, 1] = np.bincount(col, weights=w * z[row, 1], minlength=TM).reshape(T, M)
    # CSR: the candidates are platform-major, so a stable sort by row is a merge of M sorted runs.
    order = np.argsort(row, kind="stable")
    indptr = np.zeros(N + 1, dtype=np.intp)
    np.cumsum(np.bincount(row, minlength=N), out=indptr[1:])
    weights = sp.csr_matrix((w[order], col[order], indptr), shape=(N, TM))
    return GatedWeights(weights, W, WZ, lse, inputs)


Candidates = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _support_candidates(
    log_tau: np.ndarray | None, log_k: np.ndarray | None, N: int, T: int, M: int
) -> Candidates:
    """Every triple whose priors are non-zero: ``(row, t, platform)`` grouped in segments, one per
    (locale, platform) pair, platform-major, and the segments' ``(length, row)``."""
    ft = np.isfinite(log_tau) if log_tau is not None else np.ones((N, T), dtype=bool)
    fk = np.isfinite(log_k) if log_k is not None else np.ones((N, M), dtype=bool)
    rows, ts, ms, counts, seg_rows = [], [], [], [], []
    for m in range(M):
        mask = ft & fk[:, m, None]
        rr, tt = np.nonzero(mask)
        rows.append(rr)
        ts.append(tt)
        ms.append(np.full(rr.size, m, dtype=np.intp))
        c = mask.sum(axis=1)
        counts.append(c[c > 0])
        seg_rows.append(np.flatnonzero(c))
    return (
        np.concatenate(rows),
        np.concatenate(ts),
        np.concatenate(ms),
        np.concatenate(counts),
        np.concatenate(seg_rows),
    )


class _TreeCandidates:
    """Candidate triples from a KD-tree per platform (module docstring)."""

    def __init__(self, inputs: EStepInputs, margin: float) -> None:
        z, positions, r = inputs.locales, inputs.positions, inputs.r
        log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
        M = positions.shape[0]
        N = z.shape[0]
        self.z = z
        self.trees = [cKDTree(positions[m], balanced_tree=False, compact_nodes=False) for m in range(M)]
        inv2r = 0.5 / r
        rows = np.arange(N)
        if log_tau is not None:
            t_peak = np.argmax(log_tau, axis=1)
            lt_max = log_tau[rows, t_peak]
        else:
            lt_max = np.zeros(N)
        lk = log_k if log_k is not None else np.zeros((N, M))
        # Lower bounds on each (locale, platform) pair's best log weight (without the common constant):
        # the exact log weight at the platform's nearest path point and at the time prior's peak.
        lower_nm = np.full((N, M), -np.inf)
        dmin2 = np.zeros((N, M))
        with np.errstate(invalid="ignore"):
            for m in range(M):
                if log_k is not None and not np.any(np.isfinite(lk[:, m])):
                    continue
                d, tn = self.trees[m].query(z)
                dmin2[:, m] = d * d
                lt_at = log_tau[rows, tn] if log_tau is not None else 0.0
                lower_nm[:, m] = lt_at + lk[:, m] - dmin2[:, m] * inv2r
                if log_tau is not None:
                    dp = z - positions[m, t_peak]
                    peak = lt_max + lk[:, m] - np.einsum("ij,ij->i", dp, dp) * inv2r
                    np.maximum(lower_nm[:, m], peak, out=lower_nm[:, m])
            lower = lower_nm.max(axis=1)
            # Triples below lower - _UNDERFLOW are dropped whatever their pair's best.
            floor = lower[:, None] - (_UNDERFLOW + _GATE_SLACK)
            upper = lt_max[:, None] + lk  # bound on log pi^tau + log pi^k of the pair
            reach = upper - dmin2 * inv2r >= floor
            # A triple can be kept only if -d^2/2r + log pi^tau + log pi^k >= max(pair bound, floor) - G.
            rho2 = 2.0 * r * (upper - np.maximum(lower_nm, floor) + (margin + _GATE_SLACK))
        self.ok = bool(np.all(np.isfinite(lower)))
        self.query = reach & np.isfinite(rho2) & (rho2 >= 0)
        self.radius = np.sqrt(np.where(self.query, rho2, 0.0))

    def estimate(self) -> float:
        """Expected number of candidates (from a sample of locales when there are many); inf if the
        bound cannot place every locale."""
        if not self.ok:
            return math.inf
        N = self.z.shape[0]
        sample = np.arange(N)
        if N > 2 * _GATE_SAMPLE:
            sample = np.random.default_rng(N).choice(N, _GATE_SAMPLE, replace=False)
        count = 0.0
        for m, tree in enumerate(self.trees):
            q = sample[self.query[sample, m]]
            if q.size:
                lengths = tree.query_ball_point(self.z[q], self.radius[q, m], return_length=True)
                count += float(np.sum(lengths))
        return count * N / sample.size

    def candidates(self, budget: float) -> Candidates | None:
        """Every triple within its pair's radius, as :func:`_support_candidates` returns them (empty
        arrays when no pair is queried), or ``None`` past ``budget``."""
        rows_parts: list[np.ndarray] = []
        t_parts: list[np.ndarray] = []
        m_parts: list[np.ndarray] = []
        count_parts: list[np.ndarray] = []
        seg_parts: list[np.ndarray] = []
        total = 0
        for m, tree in enumerate(self.trees):
            q = np.flatnonzero(self.query[:, m])
            if q.size == 0:
                continue
            counts, ts = _ball_lists(tree, self.z[q], self.radius[q, m])
            total += ts.size
            if total > budget:
                return None
            rows_parts.append(np.repeat(q, counts))
            t_parts.append(ts)
            m_parts.append(np.full(ts.size, m, dtype=np.intp))
            count_parts.append(counts[counts > 0])
            seg_parts.append(q[counts > 0])
        if not rows_parts:  # no pair to query: no candidate (the caller then runs the dense E-step)
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, empty, empty, empty
        return (
            np.concatenate(rows_parts),
            np.concatenate(t_parts),
            np.concatenate(m_parts),
            np.concatenate(count_parts),
            np.concatenate(seg_parts),
        )
