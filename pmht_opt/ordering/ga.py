"""The GA-TSP baseline: a Kirk-style genetic algorithm for the open multiple TSP (SPEC section 3).

Encoding
--------
A solution is a permutation ``p`` of the ``N`` locales and ``M - 1`` sorted break points
``0 < b_1 < ... < b_{M-1} < N``. With ``b_0 = 0`` and ``b_M = N``, platform ``m`` (0-based) flies
``p[b_m : b_{m+1}]`` from its own start; a minimum route length ``min_tour`` means
``b_{m+1} - b_m >= min_tour``. Internally the population keeps the *heads* ``[b_0, ..., b_{M-1}]``,
the position in ``p`` of each route's first locale.

Cost
----
With ``D`` the locale-to-locale distance matrix and ``S[m, n]`` the distance from start ``m`` to locale
``n``, the cost of ``(p, b)`` is the sum of every leg of the chain ``p`` minus the ``M - 1`` legs that
straddle a break, plus the ``M`` start legs:

.. math::

    C = \\sum_{k=0}^{N-2} D[p_k, p_{k+1}] - \\sum_{m=1}^{M-1} D[p_{b_m - 1}, p_{b_m}]
        + \\sum_{m=0}^{M-1} S[m, p_{b_m}].

That is three gathers and three row sums for the whole population, the core of the vectorised evaluation.

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
breaks in ``1 .. N - 1``.
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

    Dflat = np.sqrt(((z[:, None, :] - z[None, :, :]) ** 2).sum(-1)).ravel()
    # Start legs indexed as Sflat[m * N + locale]; the m * N offsets are added to the heads' locales.
    Sflat = np.sqrt(((s[:, None, :] - z[None, :, :]) ** 2).sum(-1)).ravel()
    start_off = np.arange(M) * N

    pop = rng.permuted(np.tile(np.arange(N, dtype=np.intp), (P, 1)), axis=1)
    heads = _random_heads(rng, P, N, M, min_tour)
    rows = np.arange(P)[:, None]
    grows = np.arange(G)

    # Child c of group g reads parent row g at idx[g, c, k]; offsets g * N make it a flat gather.
    k = np.arange(N, dtype=np.intp)
    goff = (np.arange(G, dtype=np.intp) * N)[:, None]
    idx = np.empty((G, GROUP, N), dtype=np.intp)
    idx[:, 0] = k + goff
    idx[:, 4] = k + goff
    new_heads = np.empty((G, GROUP, M), dtype=np.intp)

    best_cost = np.inf
    best_perm = pop[0].copy()
    best_heads = heads[0].copy()
    history = np.empty(iters)

    for it in range(iters):
        c = it % _CHUNK
        if c == 0:
            n = min(_CHUNK, iters - it)
            orders = rng.permuted(np.tile(np.arange(P), (n, 1)), axis=1)
            IJ = np.sort(rng.integers(0, N, size=(n, G, 2)), axis=2)
            fresh = _random_heads(rng, n * G * 4, N, M, min_tour).reshape(n, G, 4, M)

        # Evaluate: chain legs minus break legs plus start legs.
        legs = Dflat[pop[:, :-1] * N + pop[:, 1:]]
        cost = legs.sum(axis=1)
        if M > 1:
            cost -= legs[rows, heads[:, 1:] - 1].sum(axis=1)
        cost += Sflat[pop[rows, heads] + start_off].sum(axis=1)

        i = int(np.argmin(cost))
        if cost[i] < best_cost:
            best_cost = float(cost[i])
            best_perm = pop[i].copy()
            best_heads = heads[i].copy()
        history[it] = best_cost
        if callback is not None:
            callback(it, best_cost)

        # Select the best of each group of 8 after a random shuffle.
        order = orders[c].reshape(G, GROUP)
        winners = order[grows, np.argmin(cost[order], axis=1)]
        parents = pop[winners]

        I = IJ[c, :, 0:1] + goff  # noqa: E741 (the paper's I..J)
        J = IJ[c, :, 1:2] + goff
        kg = idx[:, 0]
        inside = (kg >= I) & (kg <= J)
        flip = np.where(inside, I + J - kg, kg)
        swap = np.where(kg == I, J, np.where(kg == J, I, kg))
        slide = np.where(kg == J, I, np.where(inside, kg + 1, kg))
        idx[:, 1] = flip
        idx[:, 5] = flip
        idx[:, 2] = swap
        idx[:, 6] = swap
        idx[:, 3] = slide
        idx[:, 7] = slide
        pop = parents.ravel()[idx].reshape(P, N)
        new_heads[:, :4] = heads[winners][:, None, :]
        new_heads[:, 4:] = fresh[c]
        heads = new_heads.reshape(P, M).copy()

    return best_perm, best_heads, history
