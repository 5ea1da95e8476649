"""Candidate (locale, time, platform) triples for the gated E-step (:mod:`pmht_opt.estep.gating`).

Two sources, each giving the candidates a block of locales at a time, sorted by locale and then
platform, so that the gate runs on small arrays whatever the size of the problem:

* :class:`TreeCandidates`: the path points within each (locale, platform) pair's radius, the radius
  following from a lower bound on the pair's best log weight (the gating module's docstring);
* :class:`SupportCandidates`: every triple whose priors are non-zero, when the priors confine each
  locale to a few times and platforms (as in :func:`~pmht_opt.plan_smoothed`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from pmht_opt.estep.likelihood import _UNDERFLOW, EStepInputs, squared_distance

#: Extra nats on the candidate radius so that rounding in the bound can never lose a kept triple.
_GATE_SLACK = 1.0
#: Locales sampled to estimate the number of candidates before committing to the gated E-step.
_GATE_SAMPLE = 64
#: Path points per chunk of the candidate search (:class:`TreeCandidates`).
_CHUNK = 32
#: Path points (or triples) handled per block of locales: a block's arrays stay a few MiB.
_BLOCK = 1 << 18
#: An exact count of at most ``2 * _GATE_SAMPLE`` locales' candidates first counts the points well
#: inside the discs when the chunks met could hold more than this many times the limit: a cheap lower
#: bound that settles "too many" without the search. Only the cost depends on it, never the count's
#: verdict (measured on A: the chunks hold 2-4 times the candidates).
_TRY_INSIDE = 2.5

#: A block of candidates: ``(lo, hi, row, t, platform, d2)`` for the locales ``lo .. hi - 1``, sorted by
#: locale, then platform; ``d2`` the squared distances where the source computed them, else ``None``.
Block = tuple[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]


class SupportCandidates:
    """Every triple whose priors are non-zero, a block of locales at a time.

    Parameters
    ----------
    inputs
        The E-step's inputs; only the priors' zero pattern is used.
    """

    def __init__(self, inputs: EStepInputs) -> None:
        M, T, _ = inputs.positions.shape
        N = inputs.locales.shape[0]
        lt, lk = inputs.log_time_prior, inputs.log_platform_prior
        self.ft = np.isfinite(lt) if lt is not None else np.ones((N, T), dtype=bool)
        self.fk = np.isfinite(lk) if lk is not None else np.ones((N, M), dtype=bool)

    def spans(self) -> list[tuple[int, int]]:
        """The blocks' locales ``[lo, hi)``, in order."""
        N, T = self.ft.shape
        step = max(1, _BLOCK // (T * self.fk.shape[1]))
        return [(lo, min(lo + step, N)) for lo in range(0, N, step)]

    def block(self, lo: int, hi: int) -> Block:
        """The candidates (:data:`Block`) of the locales ``lo .. hi - 1``, without distances."""
        mask = self.fk[lo:hi, :, None] & self.ft[lo:hi, None, :]
        n, m, t = np.nonzero(mask)
        return lo, hi, n + lo, t, m, None


class TreeCandidates:
    """Candidate triples within each (locale, platform) pair's radius (module docstring).

    A KD-tree per platform gives each pair's nearest path point, hence its radius. The points within
    the radius are then found a block of locales at a time: each path's points, in the tree's order,
    are cut into chunks of :data:`_CHUNK`, a chunk is skipped when its bounding disc lies outside the
    pair's radius, and the points of the others are measured directly (their squared distances are
    kept for the log weights). Radius queries of the trees would give the same candidates in the
    same order (up to points on a radius itself, which the bound's slack keeps far from any kept
    triple), but as Python lists, whose cost dominates once there are millions of candidates.

    Parameters
    ----------
    inputs
        The E-step's inputs.
    margin
        The gate's margin ``G`` in nats.
    scale
        The largest coordinate of the locales and paths (computed here if not given), which sets the
        rounding slack of the chunks' discs.
    """

    def __init__(self, inputs: EStepInputs, margin: float, scale: float | None = None) -> None:
        z, positions, r = inputs.locales, inputs.positions, inputs.r
        log_tau, log_k = inputs.log_time_prior, inputs.log_platform_prior
        M = positions.shape[0]
        N = z.shape[0]
        self.z = z
        self.zx, self.zy = inputs.coordinates
        self.positions = positions
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
                # Pairs with a zero platform prior keep a bound of -inf: no triple of theirs is kept.
                q = rows if log_k is None else np.flatnonzero(np.isfinite(lk[:, m]))
                if q.size == 0:
                    continue
                d, tn = self.trees[m].query(z[q])
                dmin2[q, m] = d * d
                lt_at = log_tau[q, tn] if log_tau is not None else 0.0
                low = lt_at + lk[q, m] - dmin2[q, m] * inv2r
                if log_tau is not None:
                    dp = z[q] - positions[m, t_peak[q]]
                    peak = lt_max[q] + lk[q, m] - np.einsum("ij,ij->i", dp, dp) * inv2r
                    np.maximum(low, peak, out=low)
                lower_nm[q, m] = low
            lower = lower_nm.max(axis=1)
            # Triples below lower - _UNDERFLOW are dropped whatever their pair's best.
            floor = lower[:, None] - (_UNDERFLOW + _GATE_SLACK)
            upper = lt_max[:, None] + lk  # bound on log pi^tau + log pi^k of the pair
            reach = upper - dmin2 * inv2r >= floor
            # A triple can be kept only if -d^2/2r + log pi^tau + log pi^k >= max(pair bound, floor) - G.
            rho2 = 2.0 * r * (upper - np.maximum(lower_nm, floor) + (margin + _GATE_SLACK))
        self.ok = bool(np.all(np.isfinite(lower)))
        self.query = reach & np.isfinite(rho2) & (rho2 >= 0)
        self.rho2 = np.where(self.query, rho2, 0.0)
        self.radius = np.sqrt(self.rho2)
        # Room for the rounding of the chunks' discs and distances, in the coordinates' units.
        if scale is None:
            scale = float(np.max([np.max(np.abs(z)), np.max(np.abs(positions))]))
        self.slack = 16.0 * np.finfo(float).eps * scale
        self._found: dict[tuple[int, int], Block] | None = None
        self._search_plan: _SearchPlan | None = None
        self._lock = threading.Lock()

    def estimate(self, limit: float = math.inf) -> float:
        """Expected number of candidates; inf if the bound cannot place every locale.

        Up to ``2 * _GATE_SAMPLE`` locales the count is exact, or above ``limit`` when it is: where
        the chunks the pairs' discs meet could hold more than :data:`_TRY_INSIDE` times ``limit``
        points, the points well inside the discs are counted first (:meth:`inside_count`, a lower
        bound), and a count past ``limit`` is returned as it is; otherwise, or when that count stays
        below ``limit``, the search itself runs and its count is exact (its blocks are kept for
        :meth:`block`), or it stops past ``limit`` and returns its count so far (then above
        ``limit``). Either way the caller's decision, "more than ``limit``", is the exact count's.
        Beyond ``2 * _GATE_SAMPLE`` locales, the radius counts of a sample of locales are scaled up.
        """
        if not self.ok:
            return math.inf
        N = self.z.shape[0]
        if N <= 2 * _GATE_SAMPLE:
            if self._plan().upper > _TRY_INSIDE * limit:
                inside = self.inside_count(limit)
                if inside > limit:
                    return float(inside)
            found: dict[tuple[int, int], Block] = {}
            exact = 0
            for block in self._search():
                found[block[0], block[1]] = block
                exact += block[2].size
                if exact > limit:
                    return float(exact)
            self._found = found
            return float(exact)
        sample = np.random.default_rng(N).choice(N, _GATE_SAMPLE, replace=False)
        count = 0.0
        for m, tree in enumerate(self.trees):
            q = sample[self.query[sample, m]]
            if q.size:
                lengths = tree.query_ball_point(self.z[q], self.radius[q, m], return_length=True)
                count += float(np.sum(lengths))
        return count * N / sample.size

    def inside_count(self, limit: float = math.inf) -> int:
        """A lower bound on the number of candidates: the path points within each pair's radius less
        the rounding room, counted by the trees (stopping once past ``limit``).

        The search keeps a point when its squared distance, as computed, is at most the pair's
        ``rho2``. A point the tree counts within ``radius (1 - 1e-9) - 4 slack`` is within
        ``radius - 3 slack`` in exact arithmetic and as the search computes it (the rounding of a
        coordinate difference is below ``2 eps scale``, an eighth of the slack), so it is kept:
        every point counted here is a candidate, and the count can only be below the search's.
        """
        count = 0
        for m, tree in enumerate(self.trees):
            q = np.flatnonzero(self.query[:, m])
            radius = self.radius[q, m] * (1.0 - 1e-9) - 4.0 * self.slack
            well = radius > 0
            if np.any(well):
                lengths = tree.query_ball_point(self.z[q[well]], radius[well], return_length=True)
                count += int(np.sum(lengths))
            if count > limit:
                break
        return count

    def spans(self) -> list[tuple[int, int]]:
        """The blocks' locales ``[lo, hi)``, in order."""
        return self._plan().spans

    def block(self, lo: int, hi: int) -> Block:
        """The candidates (:data:`Block`) of the span ``lo .. hi - 1`` with their squared distances:
        the block of :meth:`estimate`'s search if it ran, handed over once (the E-step turns the
        distances into log weights in place), else searched now. Safe to call from several threads."""
        with self._lock:
            found = None if self._found is None else self._found.pop((lo, hi), None)
        return found if found is not None else self._search_block(self._plan(), lo, hi)

    def _chunks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The path points in the trees' order, in chunks ``(2, M, K, C)`` (padded with infinite
        points, which no radius reaches), the time of each ``(M, K * C)``, and each chunk's bounding
        disc: centres ``(M, K, 2)`` and radii ``(M, K)``.

        A tree keeps its points leaf by leaf, so consecutive points are close in space and the chunks
        are compact; and within a pair the candidates come in the order in which a radius query of
        the tree lists them, so every sum over them is formed in that order.
        """
        M, T, _ = self.positions.shape
        K = -(-T // _CHUNK)
        pad = K * _CHUNK - T
        order = np.stack([tree.indices for tree in self.trees])  # (M, T)
        ordered = np.take_along_axis(self.positions, order[..., None], axis=1)
        # Each coordinate contiguous, (M, K, C): a block gathers whole chunks of one coordinate.
        points = np.concatenate([ordered, np.full((M, pad, 2), np.inf)], axis=1)
        points = np.ascontiguousarray(np.moveaxis(points, 2, 0)).reshape(2, M, K, _CHUNK)
        edge = np.concatenate([ordered, np.repeat(ordered[:, -1:], pad, axis=1)], axis=1)
        edge = edge.reshape(M, K, _CHUNK, 2)
        # One coordinate at a time: numpy reduces a strided axis of the whole array far more slowly.
        low = np.stack([edge[..., c].min(axis=2) for c in (0, 1)], axis=-1)
        high = np.stack([edge[..., c].max(axis=2) for c in (0, 1)], axis=-1)
        centre = 0.5 * (low + high)
        half = 0.5 * np.hypot(high[..., 0] - low[..., 0], high[..., 1] - low[..., 1])
        times = np.concatenate([order, np.zeros((M, pad), dtype=order.dtype)], axis=1)
        return points, times, centre, half

    def _search(self) -> Iterator[Block]:
        """The chunked search (class docstring), a block of locales at a time."""
        plan = self._plan()
        for lo, hi in plan.spans:
            yield self._search_block(plan, lo, hi)

    def _plan(self) -> _SearchPlan:
        """What every block of the search reads (computed once): the chunks, the pairs, which chunks
        each pair's disc meets, and the blocks of whole locales, about :data:`_BLOCK` points each."""
        with self._lock:
            if self._search_plan is None:
                self._search_plan = self._make_plan()
            return self._search_plan

    def _make_plan(self) -> _SearchPlan:
        z = self.z
        N = z.shape[0]
        points, times, centre, half = self._chunks()
        K = centre.shape[1]
        pair_n, pair_m = np.nonzero(self.query)  # sorted by (locale, platform)
        radius = self.radius[pair_n, pair_m]
        # Chunks whose bounding disc meets the pair's disc (with room for rounding), a slab of pairs
        # at a time.
        hits = np.empty((pair_n.size, K), dtype=bool)
        slab = max(1, _BLOCK // K)
        for p0 in range(0, pair_n.size, slab):
            p1 = min(p0 + slab, pair_n.size)
            m = pair_m[p0:p1]
            dx = z[pair_n[p0:p1], 0, None] - centre[m, :, 0]
            dy = z[pair_n[p0:p1], 1, None] - centre[m, :, 1]
            reach = (radius[p0:p1, None] + half[m]) * (1.0 + 1e-9) + self.slack
            hits[p0:p1] = dx * dx + dy * dy <= reach * reach
        cumulative = np.cumsum(np.bincount(pair_n, weights=hits.sum(axis=1), minlength=N) * _CHUNK)
        spans = []
        lo = 0
        while lo < N:
            before = cumulative[lo - 1] if lo else 0.0
            hi = int(np.searchsorted(cumulative, before + _BLOCK, side="right"))
            hi = min(max(hi, lo + 1), N)
            spans.append((lo, hi))
            lo = hi
        return _SearchPlan(
            points,
            times,
            pair_n,
            pair_m,
            self.rho2[pair_n, pair_m],
            hits,
            np.searchsorted(pair_n, np.arange(N + 1)),
            spans,
            float(cumulative[-1]) if N else 0.0,
            K,
        )

    def _search_block(self, plan: _SearchPlan, lo: int, hi: int) -> Block:
        """The candidates of the locales ``lo .. hi - 1``: the points of the chunks each pair's disc
        meets, measured directly."""
        z = self.z
        p0, p1 = int(plan.pair_start[lo]), int(plan.pair_start[hi])
        ph, kh = np.nonzero(plan.hits[p0:p1])
        ph += p0
        n, m = plan.pair_n[ph], plan.pair_m[ph]
        d2 = squared_distance(z[n, 0, None], z[n, 1, None], plan.points[0][m, kh], plan.points[1][m, kh])
        # The points inside, in the order of np.nonzero(d2 <= rho2), as flat indices into the (hits,
        # C) array: entry ``i`` is point ``i % C`` of hit ``i // C``, whose time sits at ``i`` plus
        # the hit's offset in the flat (M, K * C) array of times.
        inside = np.flatnonzero(d2 <= plan.rho2[ph, None])
        h = inside // _CHUNK
        offset = (m * plan.n_chunks + kh - np.arange(kh.size)) * _CHUNK
        times = plan.times.reshape(-1)[inside + offset[h]]
        return lo, hi, n[h], times, m[h], d2.reshape(-1)[inside]


class _SearchPlan(NamedTuple):
    """What every block of :class:`TreeCandidates`' search reads."""

    points: np.ndarray
    times: np.ndarray
    pair_n: np.ndarray
    pair_m: np.ndarray
    rho2: np.ndarray
    hits: np.ndarray
    pair_start: np.ndarray
    spans: list[tuple[int, int]]
    #: The points of the chunks the pairs' discs meet: an upper bound on the number of candidates.
    upper: float
    #: Chunks per path (``K``).
    n_chunks: int


__all__ = ["Block", "SupportCandidates", "TreeCandidates"]
