r"""The GA-TSP baseline: a Kirk-style genetic algorithm for the open multiple TSP (SPEC section 3).

Two variants, chosen by ``operators`` (:class:`GAParams`):

``"improved"`` (the default)
    Kirk's flip and swap, a segment move and a route exchange instead of his two slides, and restarts of
    a stalled population: every seed reaches the optimum on small instances (below), so this is the GA to
    use as an ordering.
``"kirk"``
    The paper's GA as published (Kirk's operators, no restarts), for replicating the paper's Table 1: on
    its scenarios the improved GA is much stronger than the baseline the paper compared against. It is
    bit for bit the GA of this module before the improvements (same seed, same tours and history).

Encoding
--------
A solution is a permutation ``p`` of the ``N`` locales and ``M - 1`` sorted break points
``0 < b_1 < ... < b_{M-1} < N``. With ``b_0 = 0`` and ``b_M = N``, platform ``m`` (0-based) flies
``p[b_m : b_{m+1}]`` from its own start; a minimum route length ``min_tour`` means
``b_{m+1} - b_m >= min_tour``. Internally the population keeps the *heads* ``[b_0, ..., b_{M-1}]``,
the position in ``p`` of each route's first locale.

Cost
----
Stack the locales ``z_0 .. z_{N-1}`` and the starts ``s_0 .. s_{M-1}`` as rows ``0 .. N+M-1`` of a table
``L[r, n] = ||row_r - z_n||``. Each locale is entered exactly once, from the previous locale of its route
or, if it heads route ``m``, from start ``s_m``. With ``prev_k = p_{k-1}`` and ``prev_{b_m} = N + m``,

.. math::

    C(p, b) = \sum_{k=0}^{N-1} L[\mathrm{prev}_k, p_k],

so the whole population is costed by one gather ``L.ravel()[prev * N + p]`` and one row sum.

Iteration (after Kirk's MATLAB mTSP GAs)
----------------------------------------
Evaluate everyone and keep the global best; shuffle the population into groups of 8; the best member of
each group is the parent of 8 children. In Kirk's GA these are a copy, a *flip* (reverse ``p[I..J]``), a
*swap* (exchange ``p[I]`` and ``p[J]``), a *slide* (rotate ``p[I..J]`` left by one), and the same four
again with new random breaks; ``I <= J`` are drawn once per group and there is no crossover. Here the
children are

====  ==============================  ============================================
slot  order                           breaks
====  ==============================  ============================================
0     copy                            parent's
1     flip ``p[I..J]``                parent's
2     swap ``p[I]``, ``p[J]``         parent's
3     *segment move* (Kirk: slide)    follow their locales
4     copy                            new random
5     flip                            new random
6     swap                            new random
7     *route exchange* (Kirk: slide)  exchanged with the routes (Kirk: new random)
====  ==============================  ============================================

and, beyond Kirk's GA, a run that stops improving is *restarted* (below). With one platform there is
no route to exchange and slot 7 is Kirk's slide. ``operators="kirk"`` keeps Kirk's children (slot 3 the
slide, slot 7 the slide with new random breaks) and never restarts.

*Segment move* (or-opt): the block ``p[I .. I+r-1]``, ``1 <= r <= J - I`` uniform, goes behind ``p[J]``,
reversed with probability ``REVERSE``; unreversed with ``r = 1`` it is Kirk's slide. The breaks follow:
heads between the block and ``p[J]`` move up by ``r``, heads inside the block (after ``I``) move with
it. So a block within one route leaves it for ``p[J]``'s route and every other locale keeps its route.
If a route ends up shorter than ``min_tour`` (or empty), the child keeps the parent's breaks.

*Route exchange*: two routes ``m1 < m2`` (uniform pair) trade their locales, order and number kept;
``A X B -> B X A`` on the positions from route ``m1``'s head to route ``m2``'s end, and the heads of
routes ``m1 + 1 .. m2`` shift by ``len(B) - len(A)``.

*Restart*: once the best cost of the current run has not fallen for ``STALL * N (N + 1) / (2 G)``
generations (``G`` groups: about ``STALL`` draws of every segment ``I..J`` with every operator), the
whole population is redrawn at random. The best tour so far is kept outside the population, so the
history never increases. The limit grows as ``N^2``: 18 generations for 8 locales, 2525 for the paper's
100 (where Kirk's GA still improves every few hundred generations at 5000), so restarts serve small
instances and leave the paper's runs essentially alone.

All children of all groups are built at once as index arrays into the parents
(``child[k] = parent[idx[k]]``): ``idx`` is the identity outside ``I..J`` and ``I + J - k`` (flip), the
exchanged pair (swap) or a rotation (segment move) inside; the route exchange adds a shift that is
constant on five runs of positions. The moves that do not depend on the parent's breaks are built for a
batch of generations at once.

Random breaks are uniform over the compositions of ``N`` into ``M`` routes of at least ``min_tour``
locales (stars and bars: ``M - 1`` distinct sorted slots ``c_m`` in ``0 .. N - M min_tour + M - 2`` give
``b_m = c_m + m (min_tour - 1) + 1``); with ``min_tour = 1`` this is Kirk's choice of ``M - 1`` distinct
breaks in ``1 .. N - 1``. (Kirk's code draws constrained breaks from a different, non-uniform law.)

Why the changes, and their measured effect
------------------------------------------
On 300 random instances of 5-8 locales and 2-3 platforms (``min_tour`` 1 or more), 5 seeds each, 600
generations, checked against exhaustive search, Kirk's GA missed the optimum in 209 of the 1500 runs
(14 %), on 91 of the instances (46 % of their runs). A missed run converges within a few dozen
generations to a tour that no single GA move improves, whatever the new breaks (checked exhaustively),
and stays there: the elite takes over the population at once and there is no crossover. Typical traps:
two routes that should trade places (``[[0, 3, 2, 7], [1], [5, 6, 4]]`` against the optimal
``[[5, 6, 4], [1], [0, 3, 2, 7]]``: a swap moves one locale, and new breaks are a blind draw), or a
segment that should move to another route, reversed, with its break. The segment move and the route
exchange make these one move; without restarts they cut the missed runs on those 91 instances (300
generations, other seeds) from 47 % to 13 %. The remaining traps have large basins, and restarts escape
them: with both, 0 of the 1500 runs missed the optimum (and 0 of 910 more runs on the 91 instances; at
300 generations 0.3 % of those still did). On the paper's scenario A (seed 1, 5000 generations, 5 seeds)
the mean distance fell from 122.4 to 109.4 and a run takes about 1.4 times as long.

Notes
-----
The initial population is ``population`` random permutations with random breaks. Random numbers are drawn
in batches of up to ``_CHUNK`` generations (restarts draw theirs when they happen), so a seed fixes the
whole run. The Kirk variant always draws batches of ``_CHUNK`` and only the old draws (no segment
lengths, reversals or route pairs; four sets of new breaks per group), so it consumes the generator exactly
as before the improvements. On the 10 x 10 grid of scenario A many tours tie exactly, so which of them wins
depends on the last bits of the floating-point sums.
"""

from __future__ import annotations

import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering.tour import TourResult, _check_int, check_min_tour, tour_distance
from pmht_opt.scenario import Scenario

#: Children per parent, and so the group size (Kirk's GA).
GROUP = 8
#: A run restarts after ``STALL * N (N + 1) / (2 G)`` generations without a better tour (module notes).
STALL = 5.0
#: Probability that the segment move reverses the block it moves.
REVERSE = 0.5
#: Iterations whose random numbers are drawn in one batch (amortises the Generator's call overhead).
_CHUNK = 128
#: The variants of :func:`solve_ga_tsp` (module notes): the default first.
OPERATORS = ("improved", "kirk")
#: Cap on the entries of each of a batch's precomputed index arrays (smaller batches for large ``N``).
_CHUNK_ENTRIES = 1 << 17

Callback = Callable[[int, float], Any]


@dataclass(frozen=True)
class GAParams:
    """Parameters of :func:`solve_ga_tsp`, validated on construction.

    Attributes
    ----------
    population
        Population size: a positive multiple of 8 (one group of 8 per parent). Paper: 80.
    iterations
        Number of generations. Paper: 5000.
    min_tour
        Minimum number of locales per route (Kirk's ``minTour``), ``>= 1``.
    operators
        ``"improved"`` (default: segment move, route exchange, restarts) or ``"kirk"`` (the paper's GA,
        for replication); see the module notes.
    """

    population: int = 80
    iterations: int = 5000
    min_tour: int = 1
    operators: str = "improved"

    def __post_init__(self) -> None:
        pop = self.population
        if isinstance(pop, bool) or not isinstance(pop, numbers.Integral) or pop <= 0 or pop % GROUP:
            raise ConfigError(f"population: expected a positive multiple of {GROUP}, got {pop!r}.")
        object.__setattr__(self, "population", int(pop))
        object.__setattr__(self, "iterations", _check_int("iterations", self.iterations, 1))
        object.__setattr__(self, "min_tour", _check_int("min_tour", self.min_tour, 1))
        if not isinstance(self.operators, str) or self.operators not in OPERATORS:
            raise ConfigError(
                f"operators: expected one of {', '.join(map(repr, OPERATORS))}, got {self.operators!r}."
            )


def _rng(seed: Any) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ConfigError(f"seed: expected a non-negative integer or a numpy.random.Generator, got {seed!r}.")
    return np.random.default_rng(int(seed))


def _random_heads(rng: np.random.Generator, rows: int, N: int, M: int, min_tour: int) -> np.ndarray:
    """``(rows, M)`` route heads ``[0, b_1, ..., b_{M-1}]``, uniform over valid compositions."""
    heads = np.zeros((rows, M), dtype=np.intp)
    k = M - 1
    if k == 0:
        return heads
    slots = N - M * min_tour + k  # values 0 .. slots-1
    # Floyd's algorithm for a uniform k-subset, run for all rows at once: k vectorised steps.
    chosen = np.empty((rows, k), dtype=np.intp)
    for s in range(k):
        j = slots - k + s
        t = rng.integers(0, j + 1, size=rows)
        taken = (chosen[:, :s] == t[:, None]).any(axis=1)
        chosen[:, s] = np.where(taken, j, t)
    chosen.sort(axis=1)
    heads[:, 1:] = chosen + np.arange(1, M) * (min_tour - 1) + 1
    return heads


def _heads_to_routes(perm: np.ndarray, heads: np.ndarray) -> list[np.ndarray]:
    bounds = [*heads.tolist(), perm.size]
    return [perm[bounds[m] : bounds[m + 1]].copy() for m in range(heads.size)]


def solve_ga_tsp(
    scenario: Scenario,
    seed: int | np.random.Generator = 0,
    population: int = 80,
    iterations: int = 5000,
    min_tour: int = 1,
    callback: Callback | None = None,
    operators: str = "improved",
) -> TourResult:
    """Order the locales with the Kirk-style GA for the open multiple TSP (SPEC section 3).

    Parameters
    ----------
    scenario
        Locales ``(N, 2)`` and platforms' starts ``(M, 2)``.
    seed
        Seed or ``numpy.random.Generator``: the only source of randomness, so the same seed gives the
        same tour.
    population
        A positive multiple of 8 (paper: 80).
    iterations
        Generations (paper: 5000).
    min_tour
        Minimum locales per route, ``>= 1`` with ``min_tour * M <= N``.
    callback
        Called as ``callback(iteration, best_cost)`` after each generation (``iteration`` from 0).
    operators
        ``"improved"`` (default): segment move and route exchange instead of Kirk's slides, and restarts
        of a stalled population; every seed reaches the optimum on small instances, so it is the better
        ordering. ``"kirk"``: the paper's GA (flip, swap, slide, and the same with new random breaks; no
        restarts), to replicate the paper's baseline; bit-identical to this module's GA before the
        improvements (commit be6fbcd^) for the same seed and parameters.

    Returns
    -------
    TourResult
        ``history[i]`` is the best cost after generation ``i``; route ``m`` is platform ``m``'s;
        ``extras["restarts"]`` counts the restarts of a stalled population (module notes; always 0 with
        ``"kirk"``) and ``extras["operators"]`` names the variant.
    """
    params = GAParams(population, iterations, min_tour, operators)
    check_min_tour(scenario, params.min_tour)
    if callback is not None and not callable(callback):
        raise ConfigError(f"callback: expected a callable(iteration, best_cost) or None, got {callback!r}.")
    rng = _rng(seed)
    t0 = time.perf_counter()
    perm, heads, history, restarts = _evolve(scenario, rng, params, callback)
    wall = time.perf_counter() - t0
    routes = _heads_to_routes(perm, heads)
    return TourResult(
        routes=routes,
        total_distance=tour_distance(scenario, routes),
        history=history,
        wall_time=wall,
        method="ga",
        scenario=scenario,
        extras={
            "population": params.population,
            "iterations": params.iterations,
            "min_tour": params.min_tour,
            "restarts": restarts,
            "operators": params.operators,
        },
    )


def _stall_limit(N: int, groups: int) -> int:
    """Generations without a better tour after which the population is redrawn (see module notes)."""
    return int(np.ceil(STALL * N * (N + 1) / (2 * groups)))


def _order_moves(
    IJ: np.ndarray, block_u: np.ndarray | None, reverse: np.ndarray | None, N: int, slide: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Gather indices of the moves that do not depend on the parent's breaks, for a batch of generations.

    ``IJ (n, G, 2)`` are the sorted ``I <= J`` of ``n`` generations of ``G`` groups. Returns, each
    ``(n, G, N)`` and local to the group (position ``k`` of a child reads position ``idx[k]`` of its
    parent): the flip, the swap, the segment move, the segment move's new position of each old position
    (where the breaks go), and Kirk's slide if ``slide``, else None. Without ``block_u`` (the Kirk
    variant) the segment move and its positions are None.
    """
    dtype: Any = np.int16 if N < 2**15 else np.intp  # small ints: these arrays are memory bound
    k = np.arange(N, dtype=dtype)
    I, J = IJ[..., 0:1].astype(dtype), IJ[..., 1:2].astype(dtype)  # noqa: E741 (the paper's I..J)
    inside = (k >= I) & (k <= J)
    flip = np.where(inside, I + J - k, k)
    swap = np.where(k == I, J, np.where(k == J, I, k))
    slides = np.where(inside, np.where(k == J, I, k + 1), k) if slide else None
    if block_u is None or reverse is None:
        return flip, swap, None, None, slides
    # Segment move: the block p[I .. I+r-1] goes behind p[J] (r = 1 unreversed is Kirk's slide),
    # reversed with probability REVERSE; 1 <= r <= J - I (r = 1 and no move if I = J).
    span = J - I + 1
    r = 1 + (block_u * (span - 1)).astype(dtype)
    tail = k > J - r  # where the block lands
    seg = np.where(inside, np.where(tail, np.where(reverse, flip, k - (span - r)), k + r), k)
    # Old position -> new one, for the heads: those inside the block (but not at I) move with it, those
    # after it up to J move up by r. A head at I stays: the block leaves the front of that route.
    moves_to = k + np.where(inside & (k > I), np.where(k < I + r, span - r, -r), 0)
    return flip, swap, seg, moves_to, slides


def _evolve(
    scenario: Scenario, rng: np.random.Generator, params: GAParams, callback: Callback | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The GA loop; returns the best permutation, its heads, the best-cost history and the restarts."""
    z = scenario.locales
    s = scenario.start_positions
    N, M = z.shape[0], s.shape[0]
    P, G, iters, min_tour = params.population, params.population // GROUP, params.iterations, params.min_tour
    kirk = params.operators == "kirk"  # Kirk's slides, four sets of new breaks, no restarts

    # One table of leg lengths: rows 0..N-1 are locales, rows N..N+M-1 the starts, so every locale's
    # incoming leg is table[prev * N + locale] with prev the previous locale or, at a route head, the
    # platform's start. One gather and one row sum then cost the whole population.
    pts = np.vstack([z, s])
    table = np.sqrt(((pts[:, None, :] - z[None, :, :]) ** 2).sum(-1)).ravel()
    start_rows = (N + np.arange(M, dtype=np.intp)) * N

    def random_population() -> tuple[np.ndarray, np.ndarray]:
        perms = rng.permuted(np.tile(np.arange(N, dtype=np.intp), (P, 1)), axis=1)
        return perms, _random_heads(rng, P, N, M, min_tour)

    pop, heads = random_population()
    rows = np.arange(P)[:, None]
    grows = np.arange(G)
    legs_at = np.empty((P, N), dtype=np.intp)

    # Child c of group g reads parent row g at idx[g, c, k]; offsets g * N make that one flat gather.
    goff = (np.arange(G, dtype=np.intp) * N)[:, None]
    kg = np.arange(N, dtype=np.intp) + goff
    idx = np.empty((G, GROUP, N), dtype=np.intp)
    idx[:, 0] = kg
    idx[:, 4] = kg
    new_heads = np.empty((G, GROUP, M), dtype=np.intp)
    bounds = np.full((G, M + 1), N, dtype=np.intp)  # heads then N: differences are the route lengths
    route_no = np.arange(M)
    runs = np.empty((G, 5), dtype=np.intp)
    shifts = np.zeros((G, 5), dtype=np.intp)
    pairs = np.array([(a, b) for a in range(M) for b in range(a + 1, M)], dtype=np.intp).reshape(-1, 2)
    # Kirk's GA keeps the old batch size: it fixes the order of the draws and so the results.
    chunk = _CHUNK if kirk else max(1, min(_CHUNK, _CHUNK_ENTRIES // (G * N)))
    n_fresh = 4 if kirk else 3  # children with new random breaks

    best_cost = np.inf
    best_perm = pop[0].copy()
    best_heads = heads[0].copy()
    history = np.empty(iters)
    limit = np.inf if kirk else _stall_limit(N, G)
    run_best = np.inf  # best cost since the last (re)start
    stall = 0  # generations since run_best last fell
    restarts = 0

    for it in range(iters):
        c = it % chunk
        if c == 0:
            n = min(chunk, iters - it)
            orders = rng.permuted(np.tile(np.arange(P), (n, 1)), axis=1).reshape(n, G, GROUP)
            IJ = np.sort(rng.integers(0, N, size=(n, G, 2)), axis=2)
            fresh = _random_heads(rng, n * G * n_fresh, N, M, min_tour).reshape(n, G, n_fresh, M)
            if kirk:
                block_u = reverse = pair = None
            else:
                block_u = rng.random((n, G, 1))
                reverse = rng.random((n, G, 1)) < REVERSE
                pair = pairs[rng.integers(0, max(len(pairs), 1), size=(n, G))] if M > 1 else None
            flips, swaps, segs, moves_to, slides = _order_moves(IJ, block_u, reverse, N, kirk or M == 1)
            if pair is not None:
                # Flat indices into bounds of route m1's head and end, route m2's head and end.
                ends4 = np.concatenate(
                    [pair[..., :1], pair[..., :1] + 1, pair[..., 1:], pair[..., 1:] + 1], axis=2
                )
                ends4 += (grows * (M + 1))[:, None]
                between = (route_no > pair[..., :1]) & (route_no <= pair[..., 1:])
        if stall >= limit:
            pop, heads = random_population()
            run_best, stall = np.inf, 0
            restarts += 1

        np.multiply(pop[:, :-1], N, out=legs_at[:, 1:])
        legs_at[rows, heads] = start_rows
        legs_at += pop
        cost = table[legs_at].sum(axis=1)

        i = int(np.argmin(cost))
        if cost[i] < run_best:
            run_best, stall = float(cost[i]), 0
            if run_best < best_cost:
                best_cost = run_best
                best_perm = pop[i].copy()
                best_heads = heads[i].copy()
        else:
            stall += 1
        history[it] = best_cost
        if callback is not None:
            callback(it, best_cost)

        # The best of each group of 8 (after a random shuffle) is the parent of the group's children.
        order = orders[c]
        winners = order[grows, np.argmin(cost[order], axis=1)]
        ph = heads[winners]
        np.add(flips[c], goff, out=idx[:, 1])
        np.add(swaps[c], goff, out=idx[:, 2])
        idx[:, 5] = idx[:, 1]
        idx[:, 6] = idx[:, 2]
        new_heads[:, :4] = ph[:, None, :]
        new_heads[:, 4 : 4 + n_fresh] = fresh[c]

        if segs is not None and moves_to is not None:
            # The segment move's breaks follow their locales; a route left shorter than min_tour (or
            # empty) keeps the parent's breaks instead.
            np.add(segs[c], goff, out=idx[:, 3])
            bounds[:, :M] = moves_to[c][grows[:, None], ph]
            fits = (bounds[:, 1:] - bounds[:, :-1]).min(axis=1) >= min_tour
            np.copyto(new_heads[:, 3], bounds[:, :M], where=fits[:, None])

        if kirk:  # Kirk's slide, with the parent's breaks (slot 3) and new ones (slot 7, set above)
            assert slides is not None
            np.add(slides[c], goff, out=idx[:, 3])
            idx[:, 7] = idx[:, 3]
        elif slides is not None:  # one platform: Kirk's slide
            np.add(slides[c], goff, out=idx[:, 7])
            new_heads[:, 7] = ph
        elif pair is not None:
            # Route exchange: routes m1 < m2 trade their locales (order and number kept) and the routes
            # between them shift: A X B -> B X A on positions lo .. hi - 1, with A = p[lo:e1] (route m1),
            # X = p[e1:s2], B = p[s2:hi] (route m2). Each output position reads position + shift, the
            # shift constant on the five runs [0, lo), B's new place, X's, A's, [hi, N).
            bounds[:, :M] = ph
            lo, e1, s2, hi = bounds.take(ends4[c]).T
            runs[:, 0] = lo
            runs[:, 1] = hi - s2
            runs[:, 2] = s2 - e1
            runs[:, 3] = e1 - lo
            runs[:, 4] = N - hi
            shifts[:, 1] = s2 - lo
            shifts[:, 2] = runs[:, 3] - runs[:, 1]
            shifts[:, 3] = e1 - hi
            np.add(kg, np.repeat(shifts.ravel(), runs.ravel()).reshape(G, N), out=idx[:, 7])
            new_heads[:, 7] = ph - shifts[:, 2:3] * between[c]
        pop = pop[winners].ravel()[idx].reshape(P, N)
        heads = new_heads.reshape(P, M).copy()

    return best_perm, best_heads, history, restarts
