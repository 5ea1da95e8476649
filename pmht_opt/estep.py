"""The E-step: assignment weights, prior updates and the EM objective (SPEC section 2, paper eqs 9-12).

Everything is in the log domain: with ``r = 0.01`` and distances of a few units the likelihoods
``exp(-d^2 / 2r)`` underflow. Arrays are kept two-dimensional, ``(N, T*M)`` with column ``t*M + m``,
so that each step is one ufunc pass. Squared distances are formed elementwise (no ``|z|^2 - 2 z.p +
|p|^2`` cancellation), the same way in every path below, so all give bit-identical log weights.

Gating. When ``r`` is small only the (locale, time, platform) triples near the locale matter.
:func:`estep` with ``gate=G`` drops a triple when its log weight is more than ``G`` nats below the best
of its (locale, platform) pair, or more than 746 below its locale's best (where the dense computation's
``exp`` underflows to exactly zero anyway), and finds the others without forming the ``N x T x M``
array: a KD-tree per platform gives each pair's nearest path point, whose log weight (priors included)
bounds the pair's best from below, and a triple can only be kept if its distance satisfies
``d^2 <= 2r (max_t log pi^tau + log pi^k - bound + G)``, which a radius query returns. Gating per
pair, not per locale, keeps every platform's share ``pi^k[n, m] = sum_t w[n, t, m]`` (eq. 12) exact
down to the underflow, however small: the re-estimated platform prior can then revive a platform
exactly as in the dense EM. The weights are a ``scipy.sparse`` CSR matrix with the dense layout. With
``G = log(T M) + 37`` (``"auto"``) the mass dropped from a pair is below ``exp(-37) < 1e-16`` of it: W,
WZ, the normalisers and ``pi^k`` equal the dense ones to rounding. The time prior's re-estimate
``pi^tau[n, t] = sum_m w[n, t, m]`` is exact only where some triple of ``(n, t)`` is kept (zero
elsewhere, not tiny). Where the gate would admit too much (a wide ``r``, e.g. early in annealing) the
dense computation runs instead. A gated result keeps its inputs, and
:meth:`EStepResult.locale_weights` and :meth:`EStepResult.weights_ntm` recompute rows exactly as the
dense E-step does (bit for bit), dropped triples included, so consumers that rank tiny weights (the
visit choice of :class:`~pmht_opt.constraints.VisitAll`) see the same numbers.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from pmht_opt.exceptions import ConfigError, PmhtOptError

_LOG_2PI = float(np.log(2.0 * np.pi))
#: Above this coordinate magnitude the squared differences could overflow (the dense E-step then uses
#: ``hypot``; the gated one is not tried).
_SAFE_SCALE = 1e100
#: ``gate="auto"``: the margin is ``log(T M) + GATE_AUTO_NATS``, so the mass dropped from a (locale,
#: platform) pair is below ``exp(-GATE_AUTO_NATS)`` (8.5e-17) of it, under half the float64 epsilon.
GATE_AUTO_NATS = 37.0
#: Extra nats on the candidate radius so that rounding in the bound can never lose a kept triple.
_GATE_SLACK = 1.0
#: Log weights this far below their locale's best give ``exp(.) = 0`` in float64 (dense E-step too).
_UNDERFLOW = 746.0
#: The gated E-step runs when it would keep at most this fraction of the ``N T M`` triples (measured:
#: a candidate triple costs several times a dense one; see studies/results/scaling).
GATE_MAX_FRACTION = 0.1
#: Locales sampled to estimate the number of candidates before committing to the gated E-step.
_GATE_SAMPLE = 64


@dataclass
class EStepResult:
    """Weights and their sufficient statistics for one E-step.

    Attributes
    ----------
    weights
        ``w[n, t*M + m]``: posterior probability that locale ``n`` is visited by platform ``m`` at time
        ``t + 1`` (rows sum to one). A dense ``(N, T*M)`` array, or, from a gated E-step
        (:attr:`gated`), a ``scipy.sparse.csr_matrix`` of the same shape and layout whose missing
        entries are weights below ``exp(-gate)`` of their row's largest (zero). The methods below
        handle both; :meth:`weights_ntm` gives a dense ``(N, T, M)`` array.
    W
        ``(T, M)``, ``sum_n w[n, t, m]``: the weight of the synthetic measurement.
    WZ
        ``(T, M, 2)``, ``sum_n w[n, t, m] z_n``; the synthetic measurement is ``WZ / W`` (eq. 15).
    log_normaliser
        ``(N,)``, ``log sum_{t,m} pi^tau pi^k zeta(z_n | x_t^m)``; its sum is the data term of the EM
        objective.
    """

    weights: np.ndarray | sp.csr_matrix
    W: np.ndarray
    WZ: np.ndarray
    log_normaliser: np.ndarray
    n_platforms: int
    #: The E-step's inputs, kept by a gated E-step to recompute rows exactly.
    inputs: EStepInputs | None = field(default=None, repr=False, compare=False)

    @property
    def gated(self) -> bool:
        """Whether the weights are sparse (a gated E-step)."""
        return sp.issparse(self.weights)

    @property
    def n_times(self) -> int:
        """``T``."""
        return int(self.weights.shape[1]) // self.n_platforms

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
        """Weights as ``(N, T, M)``: a view of dense weights; for gated ones a new array, recomputed
        with every triple (the dropped ones too), as the dense E-step gives it."""
        w = self.weights
        if self.inputs is not None:
            return self.inputs.rows(0, w.shape[0]).reshape(w.shape[0], -1, self.n_platforms)
        dense = w.toarray() if isinstance(w, sp.csr_matrix) else w
        return np.asarray(dense).reshape(w.shape[0], -1, self.n_platforms)

    def locale_weights(self, n: int) -> np.ndarray:
        """Weights of locale ``n`` as ``(T, M)``: a view for dense weights; for gated ones the row
        recomputed with every triple, so the ones the gate dropped keep their (tiny) values and order."""
        w = self.weights
        if self.inputs is not None:
            return self.inputs.rows(n, n + 1).reshape(-1, self.n_platforms)
        if isinstance(w, sp.csr_matrix):
            out = np.zeros(w.shape[1])
            lo, hi = w.indptr[n], w.indptr[n + 1]
            out[w.indices[lo:hi]] = w.data[lo:hi]
            return out.reshape(-1, self.n_platforms)
        return np.asarray(w[n]).reshape(-1, self.n_platforms)

    def time_prior(self) -> np.ndarray:
        """Updated ``pi^tau[n, t] = sum_m w[n, t, m]`` (eq. 11), ``(N, T)``."""
        if self.gated:
            N, T, M = self.weights.shape[0], self.n_times, self.n_platforms
            rows, cols, vals = self._triples()
            return np.bincount(rows * T + cols // M, weights=vals, minlength=N * T).reshape(N, T)
        return self.weights_ntm().sum(axis=2)

    def platform_prior(self) -> np.ndarray:
        """Updated ``pi^k[n, m] = sum_t w[n, t, m]`` (eq. 12), ``(N, M)``."""
        if self.gated:
            N, M = self.weights.shape[0], self.n_platforms
            rows, cols, vals = self._triples()
            return np.bincount(rows * M + cols % M, weights=vals, minlength=N * M).reshape(N, M)
        return self.weights_ntm().sum(axis=1)

    def _argmax(self) -> np.ndarray:
        """Column of each row's largest weight (the first one among ties, as ``np.argmax``)."""
        w = self.weights
        if isinstance(w, sp.csr_matrix):
            starts = w.indptr[:-1]
            best = np.maximum.reduceat(w.data, starts)
            rows = np.repeat(np.arange(w.shape[0]), np.diff(w.indptr))
            cand = np.where(w.data == best[rows], w.indices, w.shape[1])
            return np.minimum.reduceat(cand, starts)
        return np.argmax(w, axis=1)

    def map_assignment(self) -> tuple[np.ndarray, np.ndarray]:
        """Most probable ``(platform, time)`` per locale; times are in ``1..T``."""
        idx = self._argmax()
        return idx % self.n_platforms, idx // self.n_platforms + 1

    def max_weight(self) -> np.ndarray:
        """``(N,)`` the weight of each locale's most probable ``(time, platform)``."""
        w = self.weights
        if isinstance(w, sp.csr_matrix):
            return np.maximum.reduceat(w.data, w.indptr[:-1])
        return np.max(w, axis=1)


def _log_const(r: float, T: int, M: int, uniform_time: bool, uniform_platform: bool) -> float:
    """``log(2 pi r)`` plus the log of the uniform priors' sizes: subtracted from every log weight."""
    const = _LOG_2PI + math.log(r)
    if uniform_time:
        const += math.log(T)
    if uniform_platform:
        const += math.log(M)
    return const


def _log_weights_from_d2(d2: np.ndarray, r: float, const: float) -> np.ndarray:
    """``-d2 / 2r - const`` in place. The dense E-step (:func:`_dense_rows`), the gated one and the row
    recompute all use this and the same elementwise ``(zx - px)^2 + (zy - py)^2``, so they give
    bit-identical log weights (ties among times or platforms are then broken alike)."""
    d2 *= -0.5 / r
    d2 -= const
    return d2


@dataclass
class EStepInputs:
    """What a gated E-step was computed from: enough to recompute any row exactly."""

    locales: np.ndarray
    positions: np.ndarray
    log_time_prior: np.ndarray | None
    log_platform_prior: np.ndarray | None
    r: float

    def rows(self, lo: int, hi: int) -> np.ndarray:
        """``w[lo:hi]`` as ``(hi - lo, T*M)``, computed as the dense E-step computes it (bit for bit)."""
        M, T, _ = self.positions.shape
        lt, lk = self.log_time_prior, self.log_platform_prior
        p = np.ascontiguousarray(self.positions.transpose(1, 0, 2)).reshape(T * M, 2)
        out = np.empty((hi - lo, T * M))
        const = _log_const(self.r, T, M, lt is None, lk is None)
        step = max(1, _BLOCK // (T * M))
        tmp = np.empty((min(step, hi - lo), T * M))
        for i in range(lo, hi, step):
            j = min(i + step, hi)
            _dense_rows(
                self.locales[i:j],
                p,
                None if lt is None else lt[i:j],
                None if lk is None else lk[i:j],
                self.r,
                const,
                T,
                M,
                out[i - lo : j - lo],
                tmp[: j - i],
            )
        return out


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
    """
    z = locales
    M, T, _ = positions.shape
    N = z.shape[0]
    margin = gate_margin(gate, T, M)
    if margin is not None:
        gated = _estep_gated(z, positions, log_time_prior, log_platform_prior, r, margin)
        if gated is not None:
            return gated
    p = np.ascontiguousarray(positions.transpose(1, 0, 2)).reshape(T * M, 2)
    const = _log_const(r, T, M, log_time_prior is None, log_platform_prior is None)
    TM = T * M
    w = np.empty((N, TM))
    lse = np.empty(N)
    W = np.zeros(TM)
    WZ = np.zeros((2, TM))
    # Blocks of rows small enough to stay in cache through every pass.
    step = max(1, _BLOCK // TM)
    tmp = np.empty((min(step, N), TM))
    for i in range(0, N, step):
        j = min(i + step, N)
        block = w[i:j]
        lse[i:j] = _dense_rows(
            z[i:j],
            p,
            None if log_time_prior is None else log_time_prior[i:j],
            None if log_platform_prior is None else log_platform_prior[i:j],
            r,
            const,
            T,
            M,
            block,
            tmp[: j - i],
        )
        W += block.sum(axis=0)
        WZ += z[i:j].T @ block
    return EStepResult(
        weights=w, W=W.reshape(T, M), WZ=WZ.T.reshape(T, M, 2), log_normaliser=lse, n_platforms=M
    )


#: Elements per block of rows in the dense E-step (1 MiB of float64: the block and a temporary stay in
#: a 4 MiB L2 cache).
_BLOCK = 1 << 17


def _dense_rows(
    z: np.ndarray,
    p: np.ndarray,
    log_tau: np.ndarray | None,
    log_k: np.ndarray | None,
    r: float,
    const: float,
    T: int,
    M: int,
    out: np.ndarray,
    tmp: np.ndarray,
) -> np.ndarray:
    """Normalised weights of locales ``z`` against the ``(T*M, 2)`` points ``p`` into ``out``; returns
    their log-normalisers. ``tmp`` is scratch of ``out``'s shape. Every row is computed on its own, with
    the same operations whatever the block: the E-step and the exact row recompute agree bit for bit."""
    scale = max(float(np.max(np.abs(p))), float(np.max(np.abs(z))))
    distance2 = None
    if scale < _SAFE_SCALE:
        np.subtract.outer(z[:, 0], p[:, 0], out=out)
        out *= out
        np.subtract.outer(z[:, 1], p[:, 1], out=tmp)
        tmp *= tmp
        out += tmp
    else:
        # Far-away paths (a diverged plan): hypot avoids the overflow of the squared coordinates.
        np.hypot(z[:, None, 0] - p[None, :, 0], z[:, None, 1] - p[None, :, 1], out=out)
        with np.errstate(over="ignore"):
            out *= out
        if not np.all(np.isfinite(out)):
            distance2 = out.copy()
    ll = _log_weights_from_d2(out, r, const)
    view = ll.reshape(-1, T, M)
    if log_tau is not None:
        view += log_tau[:, :, None]
    if log_k is not None:
        view += log_k[:, None, :]
    mx = ll.max(axis=1)
    bad = ~np.isfinite(mx)
    if np.any(bad):
        _limit_rows(ll, mx, bad, distance2, log_tau, log_k, T, M)
    ll -= mx[:, None]
    below = ll < -_UNDERFLOW
    if np.count_nonzero(below) > below.size // 4:
        # Mostly below -746, where exp is exactly 0 but takes numpy's slow path: skip those entries.
        np.exp(ll, out=ll, where=~below)
        ll[below] = 0.0
    else:
        np.exp(ll, out=ll)
    s = ll.sum(axis=1)
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
    winners = allowed2 & (d2 == best) if np.all(np.isfinite(best)) else allowed2
    # log of an indicator: 0 where a winner, -inf elsewhere; the row then normalises over the winners.
    ll[rows] = np.where(winners, 0.0, -np.inf)
    mx[rows] = 0.0


def _ball_lists(tree: cKDTree, points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of ``tree``'s points within ``radii`` of each of ``points``: ``(counts, flat indices)``."""
    lists = tree.query_ball_point(points, radii, return_sorted=False)
    counts = np.fromiter(map(len, lists), dtype=np.intp, count=len(lists))
    flat = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.intp, count=int(counts.sum()))
    return counts, flat


def _estep_gated(
    z: np.ndarray,
    positions: np.ndarray,
    log_tau: np.ndarray | None,
    log_k: np.ndarray | None,
    r: float,
    margin: float,
) -> EStepResult | None:
    """The gated E-step (module docstring), or ``None`` where the dense one should run instead.

    Candidates come from whichever is smaller: the radius queries, or the support of the priors (all
    triples with a non-zero prior, when the priors confine each locale to a few times and platforms,
    as in :func:`~pmht_opt.plan_smoothed`).
    """
    M, T, _ = positions.shape
    N = z.shape[0]
    scale = max(float(np.max(np.abs(positions))), float(np.max(np.abs(z))))
    if not scale < _SAFE_SCALE:  # also NaN
        return None
    budget = GATE_MAX_FRACTION * N * T * M
    # Cheap first look: a disc of the gate's radius around every locale already covers this fraction
    # of the area the locales and paths span (the candidates measured are about twice that).
    lo = np.minimum(z.min(axis=0), positions.min(axis=(0, 1)))
    hi = np.maximum(z.max(axis=0), positions.max(axis=(0, 1)))
    area = float(np.prod(hi - lo))
    if area > 0 and math.pi * 2.0 * r * margin > GATE_MAX_FRACTION * area and log_tau is None:
        return None
    n_times = np.isfinite(log_tau).sum(axis=1) if log_tau is not None else np.full(N, T)
    n_plats = np.isfinite(log_k).sum(axis=1) if log_k is not None else np.full(N, M)
    support = float(np.sum(n_times * n_plats))
    tree = _TreeCandidates(z, positions, log_tau, log_k, r, margin)
    estimate = tree.estimate()
    if min(support, estimate) > budget:
        return None
    found: Candidates | None
    if support <= estimate:
        found = _support_candidates(log_tau, log_k, N, T, M)
    else:
        found = tree.candidates(budget)
    if found is None or found[0].size == 0:
        return None
    row, t, plat, seg_count, seg_row = found
    # The candidates' log weights, with the dense E-step's arithmetic (bit for bit the same).
    const = _log_const(r, T, M, log_tau is None, log_k is None)
    flat = plat * T + t
    a = z[:, 0][row] - positions[:, :, 0].ravel()[flat]
    a *= a
    dy = z[:, 1][row] - positions[:, :, 1].ravel()[flat]
    dy *= dy
    a += dy
    del dy
    a = _log_weights_from_d2(a, r, const)
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
    lse = best + np.log(s)
    col = t * M + plat
    TM = T * M
    W = np.bincount(col, weights=a, minlength=TM).reshape(T, M)
    WZ = np.empty((T, M, 2))
    WZ[:, :, 0] = np.bincount(col, weights=a * z[row, 0], minlength=TM).reshape(T, M)
    WZ[:, :, 1] = np.bincount(col, weights=a * z[row, 1], minlength=TM).reshape(T, M)
    # CSR: the candidates are platform-major, so a stable sort by row is a merge of M sorted runs.
    order = np.argsort(row, kind="stable")
    indptr = np.zeros(N + 1, dtype=np.intp)
    np.cumsum(np.bincount(row, minlength=N), out=indptr[1:])
    weights = sp.csr_matrix((a[order], col[order], indptr), shape=(N, TM))
    inputs = EStepInputs(z, positions, log_tau, log_k, r)
    return EStepResult(weights=weights, W=W, WZ=WZ, log_normaliser=lse, n_platforms=M, inputs=inputs)


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

    def __init__(
        self,
        z: np.ndarray,
        positions: np.ndarray,
        log_tau: np.ndarray | None,
        log_k: np.ndarray | None,
        r: float,
        margin: float,
    ) -> None:
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
        """Every triple within its pair's radius, as :func:`_support_candidates` returns them, or
        ``None`` past ``budget``."""
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
        if not rows_parts:
            return None
        return (
            np.concatenate(rows_parts),
            np.concatenate(t_parts),
            np.concatenate(m_parts),
            np.concatenate(count_parts),
            np.concatenate(seg_parts),
        )
