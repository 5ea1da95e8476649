r"""The GA-TSP baseline: a Kirk-style genetic algorithm for the open multiple TSP (SPEC section 3).

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
each group is the parent of 8 children: a copy, a *flip* (reverse ``p[I..J]``), a *swap* (exchange
``p[I]`` and ``p[J]``), a *slide* (rotate ``p[I..J]`` left by one), and the same four again with new
random breaks. ``I <= J`` are drawn once per group. There is no crossover. All children of all groups are
built at once as index arrays into the parents (``child[k] = parent[idx[k]]``), with ``idx`` the identity
outside ``I..J`` and ``I + J - k`` (flip), ``k + 1`` / ``I`` (slide) or the exchanged pair (swap) inside.

Random breaks are uniform over the compositions of ``N`` into ``M`` routes of at least ``min_tour``
locales (stars and bars: ``M - 1`` distinct sorted slots ``c_m`` in ``0 .. N - M min_tour + M - 2`` give
``b_m = c_m + m (min_tour - 1) + 1``); with ``min_tour = 1`` this is Kirk's choice of ``M - 1`` distinct
breaks in ``1 .. N - 1``. (Kirk's code draws constrained breaks from a different, non-uniform law.)

Notes
-----
The initial population is ``population`` random permutations with random breaks. Random numbers are drawn
in batches of ``_CHUNK`` generations, so a seed fixes the whole run. Without crossover or any diversity
mechanism a run can stall at a tour that no single move (one flip, swap or slide with or without new
breaks) improves, even on a handful of locales; this is the baseline's nature, not something to fix here.
On the 10 x 10 grid of scenario A many tours tie exactly, so which of them wins depends on the last bits
of the floating-point sums.
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
#: Iterations whose random numbers are drawn in one batch (amortises the Generator's call overhead).
_CHUNK = 128

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
    """

    population: int = 80
    iterations: int = 5000
    min_tour: int = 1

    def __post_init__(self) -> None:
        pop = self.population
        if isinstance(pop, bool) or not isinstance(pop, numbers.Integral) or pop <= 0 or pop % GROUP:
            raise ConfigError(f"population: expected a positive multiple of {GROUP}, got {pop!r}.")
        object.__setattr__(self, "population", int(pop))
        object.__setattr__(self, "iterations", _check_int("iterations", self.iterations, 1))
        object.__setattr__(self, "min_tour", _check_int("min_tour", self.min_tour, 1))


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

    Returns
    -------
    TourResult
        ``history[i]`` is the best cost after generation ``i``; route ``m`` is platform ``m``'s.
    """
    params = GAParams(population, iterations, min_tour)
    check_min_tour(scenario, params.min_tour)
    if callback is not None and not callable(callback):
        raise ConfigError(f"callback: expected a callable(iteration, best_cost) or None, got {callback!r}.")
    rng = _rng(seed)
    t0 = time.perf_counter()
    perm, heads, history = _evolve(scenario, rng, params, callback)
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
        },
    )


def _evolve(
    scenario: Scenario, rng: np.random.Generator, params: GAParams, callback: Callback | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The GA loop; returns the best permutation, its heads and the best-cost history."""
    z = scenario.locales
    s = scenario.start_positions
    N, M = z.shape[0], s.shape[0]
    P, G, iters, min_tour = params.population, params.population // GROUP, params.iterations, params.min_tour

    # One table of leg lengths: rows 0..N-1 are locales, rows N..N+M-1 the starts, so every locale's
    # incoming leg is table[prev * N + locale] with prev the previous locale or, at a route head, the
    # platform's start. One gather and one row sum then cost the whole population.
    pts = np.vstack([z, s])
    table = np.sqrt(((pts[:, None, :] - z[None, :, :]) ** 2).sum(-1)).ravel()
    start_rows = (N + np.arange(M, dtype=np.intp)) * N

    pop = rng.permuted(np.tile(np.arange(N, dtype=np.intp), (P, 1)), axis=1)
    heads = _random_heads(rng, P, N, M, min_tour)
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

    best_cost = np.inf
    best_perm = pop[0].copy()
    best_heads = heads[0].copy()
    history = np.empty(iters)

    for it in range(iters):
        c = it % _CHUNK
        if c == 0:
            n = min(_CHUNK, iters - it)
            orders = rng.permuted(np.tile(np.arange(P), (n, 1)), axis=1).reshape(n, G, GROUP)
            IJ = np.sort(rng.integers(0, N, size=(n, G, 2)), axis=2)
            fresh = _random_heads(rng, n * G * 4, N, M, min_tour).reshape(n, G, 4, M)

        np.multiply(pop[:, :-1], N, out=legs_at[:, 1:])
        legs_at[rows, heads] = start_rows
        legs_at += pop
        cost = table[legs_at].sum(axis=1)

        i = int(np.argmin(cost))
        if cost[i] < best_cost:
            best_cost = float(cost[i])
            best_perm = pop[i].copy()
            best_heads = heads[i].copy()
        history[it] = best_cost
        if callback is not None:
            callback(it, best_cost)

        # The best of each group of 8 (after a random shuffle) is the parent of the group's children.
        order = orders[c]
        winners = order[grows, np.argmin(cost[order], axis=1)]

        i_pos, j_pos = IJ[c, :, 0], IJ[c, :, 1]
        I = IJ[c, :, 0:1] + goff  # noqa: E741 (the paper's I..J)
        J = IJ[c, :, 1:2] + goff
        inside = (kg >= I) & (kg <= J)
        flip = np.where(inside, I + J - kg, kg)
        swap = kg.copy()
        swap[grows, i_pos] = J[:, 0]
        swap[grows, j_pos] = I[:, 0]
        slide = kg + inside  # k + 1 on I..J-1, then J wraps to I
        slide[grows, j_pos] = I[:, 0]
        idx[:, 1] = flip
        idx[:, 5] = flip
        idx[:, 2] = swap
        idx[:, 6] = swap
        idx[:, 3] = slide
        idx[:, 7] = slide
        pop = pop[winners].ravel()[idx].reshape(P, N)
        new_heads[:, :4] = heads[winners][:, None, :]
        new_heads[:, 4:] = fresh[c]
        heads = new_heads.reshape(P, M).copy()

    return best_perm, best_heads, history
