"""The GA loop and its parameters: :func:`solve_ga_tsp`.

Iteration (after Kirk's MATLAB mTSP GAs): evaluate everyone and keep the global best; shuffle the
population into groups of ``len(slots)`` (8); the best member of each group is the parent of one child
per slot of the operator table (:mod:`.operators`). A restart policy (:mod:`.restart`) may redraw a
stalled population; a stopping criterion (:mod:`pmht_opt.stopping`, scored by the best cost) ends the
run.

All children of all groups are built at once as index arrays into the parents
(``child[k] = parent[idx[k]]``), and the random numbers of up to :data:`~.operators.BATCH` generations
are drawn together (restarts draw theirs when they happen), so a seed fixes the whole run. The draws of
a batch come in a fixed order: the group shuffles, the segments ``I <= J`` (one per group), the new
random breaks of every ``Breaks.FRESH`` slot, then each move's own numbers in the order of the table.
When the stopping criterion has an iteration limit (:func:`pmht_opt.stopping.iteration_limit`), the
last batch stops at it, so a run with ``MaxIterations(n)`` draws exactly what ``iterations=n`` draws.

The initial population is ``population`` random permutations with random breaks. On the 10 x 10 grid of
scenario A many tours tie exactly, so which of them wins depends on the last bits of the floating-point
sums.
"""

from __future__ import annotations

import math
import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering.ga.encoding import PopulationCost, heads_to_routes, random_heads, random_population
from pmht_opt.ordering.ga.operators import OPERATOR_SETS, Breaks, Layout, MovePlan, OperatorSet
from pmht_opt.ordering.ga.restart import NoRestart, RestartPolicy, StallRestart
from pmht_opt.ordering.tour import (
    TourResult,
    _check_closed,
    check_count,
    check_min_tour,
    tour_distance,
)
from pmht_opt.scenario import Scenario
from pmht_opt.stopping import AnyOf, MaxIterations, Progress, StoppingCriterion, iteration_limit
from pmht_opt.validation import integer

Callback = Callable[[int, float], Any]


#: Largest population: the GA holds ``population x N`` locale indices and costs them every generation.
POPULATION_MAX = 10_000


@dataclass(frozen=True)
class GAParams:
    """Parameters of :func:`solve_ga_tsp`, validated on construction.

    Attributes
    ----------
    population
        Population size: a positive multiple of the group size (8 for both built-in tables). Paper: 80.
    iterations
        At most this many generations (paper: 5000); None for no cap, which needs ``stop``.
    min_tour
        Minimum number of locales per route (Kirk's ``minTour``), ``>= 1``.
    operators
        ``"improved"`` (default: segment move, route exchange), ``"kirk"`` (the paper's GA) or an
        :class:`~pmht_opt.ordering.ga.operators.OperatorSet`.
    restart
        A restart policy; None: :class:`NoRestart` with ``"kirk"``, ``StallRestart(5.0)`` otherwise.
    stop
        A stopping criterion, combined with ``iterations`` (whichever comes first).
    closed
        Return to base: each route's leg back to its platform's start is part of the cost.
    """

    population: int = 80
    iterations: int | None = 5000
    min_tour: int = 1
    operators: str | OperatorSet = "improved"
    restart: RestartPolicy | None = None
    stop: StoppingCriterion | None = None
    closed: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "closed", _check_closed(self.closed))
        group = self.operator_set.group
        pop = self.population
        if isinstance(pop, bool) or not isinstance(pop, numbers.Integral) or pop <= 0 or pop % group:
            raise ConfigError(f"population: expected a positive multiple of {group}, got {pop!r}.")
        if pop > POPULATION_MAX:
            raise ConfigError(f"population: expected a multiple of {group} up to {POPULATION_MAX}, got {pop}")
        object.__setattr__(self, "population", int(pop))
        if self.iterations is not None:
            iterations = check_count("iterations", self.iterations)
            object.__setattr__(self, "iterations", iterations)
        object.__setattr__(self, "min_tour", integer("min_tour", self.min_tour, ConfigError, 1))
        if self.restart is not None and not isinstance(self.restart, RestartPolicy):
            raise ConfigError(
                f"restart: expected a restart policy (e.g. StallRestart(), NoRestart()) or None, "
                f"got {self.restart!r}."
            )
        if self.stop is not None and not callable(self.stop):
            raise ConfigError(f"stop: expected a stopping criterion (callable) or None, got {self.stop!r}.")
        if self.stop is None and self.iterations is None:
            raise ConfigError("iterations: expected a number of generations when no stop is given, got None.")

    @property
    def operator_set(self) -> OperatorSet:
        """The table of operators (``operators`` resolved)."""
        ops = self.operators
        if isinstance(ops, OperatorSet):
            return ops
        if isinstance(ops, str) and ops in OPERATOR_SETS:
            return OPERATOR_SETS[ops]
        raise ConfigError(
            f"operators: expected one of {', '.join(map(repr, OPERATOR_SETS))} or an OperatorSet, "
            f"got {ops!r}."
        )

    @property
    def restart_policy(self) -> RestartPolicy:
        """The restart policy (``restart`` resolved)."""
        if self.restart is not None:
            return self.restart
        return NoRestart() if self.operator_set.name == "kirk" else StallRestart()

    @property
    def criterion(self) -> StoppingCriterion:
        """The stopping criterion: ``iterations`` and ``stop`` combined."""
        if self.stop is None:
            assert self.iterations is not None
            return MaxIterations(self.iterations)
        if self.iterations is None:
            return self.stop
        return AnyOf((MaxIterations(self.iterations), self.stop))


def _rng(seed: Any) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ConfigError(f"seed: expected a non-negative integer or a numpy.random.Generator, got {seed!r}.")
    return np.random.default_rng(int(seed))


def solve_ga_tsp(
    scenario: Scenario,
    seed: int | np.random.Generator = 0,
    population: int = 80,
    iterations: int | None = 5000,
    min_tour: int = 1,
    callback: Callback | None = None,
    operators: str | OperatorSet = "improved",
    restart: RestartPolicy | None = None,
    stop: StoppingCriterion | None = None,
    closed: bool = False,
) -> TourResult:
    """Order the locales with the Kirk-style GA for the multiple TSP from per-platform starts.

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
        At most this many generations (paper: 5000); None: no cap (``stop`` must be given).
    min_tour
        Minimum locales per route, ``>= 1`` with ``min_tour * M <= N``.
    callback
        Called as ``callback(iteration, best_cost)`` after each generation (``iteration`` from 0).
    operators
        ``"improved"`` (default): the segment move and the route exchange instead of Kirk's slides,
        with restarts of a stalled population; every seed reaches the optimum on small instances, so
        it is the better ordering. ``"kirk"``: the paper's GA (flip, swap, slide, and the same with
        new random breaks; no restarts), to replicate the paper's baseline. Or an ``OperatorSet``.
    restart
        Restart policy, e.g. ``StallRestart(stall=5.0)`` or ``NoRestart()``; None: none with
        ``"kirk"``, ``StallRestart()`` otherwise.
    stop
        Stopping criterion from :mod:`pmht_opt.stopping` (scored by the best cost), e.g.
        ``NoImprovement(500)``; the run ends at ``iterations`` or ``stop``, whichever comes first.
        Avoid ``TimeBudget`` where results must be reproducible.
    closed
        Return to base: each platform flies back to its start and the cost includes that leg (the
        moves are the same; only the cost changes). Default: open routes, as in the paper.

    Returns
    -------
    TourResult
        ``history[i]`` is the best cost after generation ``i``; route ``m`` is platform ``m``'s;
        ``extras["restarts"]`` counts the restarts of a stalled population, ``extras["iterations"]``
        the generations run and ``extras["operators"]`` names the table.
    """
    params = GAParams(population, iterations, min_tour, operators, restart, stop, closed)
    check_min_tour(scenario, params.min_tour)
    if callback is not None and not callable(callback):
        raise ConfigError(f"callback: expected a callable(iteration, best_cost) or None, got {callback!r}.")
    rng = _rng(seed)
    t0 = time.perf_counter()
    run = _Evolution(scenario, rng, params)
    history = run.evolve(params.criterion, callback, t0)
    wall = time.perf_counter() - t0
    routes = heads_to_routes(run.best_perm, run.best_heads)
    return TourResult(
        routes=routes,
        total_distance=tour_distance(scenario, routes, params.closed),
        history=history,
        wall_time=wall,
        method="ga",
        scenario=scenario,
        extras={
            "population": params.population,
            "iterations": int(history.size),
            "min_tour": params.min_tour,
            "restarts": run.restarts,
            "operators": params.operator_set.name,
        },
        closed=params.closed,
    )


def _slots(ops: OperatorSet, rule: Breaks) -> slice | np.ndarray:
    """The slots with break rule ``rule``: a slice when they are contiguous (a cheaper assignment)."""
    slots = np.array([s for s, slot in enumerate(ops.slots) if slot.breaks is rule], dtype=np.intp)
    if slots.size and np.array_equal(slots, np.arange(slots[0], slots[-1] + 1)):
        return slice(int(slots[0]), int(slots[-1]) + 1)
    return slots


@dataclass
class _Batch:
    """The random numbers of ``n`` generations: group shuffles, fresh breaks and the moves' plans."""

    orders: np.ndarray  # (n, G, group): population rows of each group
    fresh: np.ndarray  # (n, G, n_fresh, M)
    plans: list[MovePlan]


class _Evolution:
    """One run of the GA: the population, the best tour so far and the buffers of the children."""

    def __init__(self, scenario: Scenario, rng: np.random.Generator, params: GAParams) -> None:
        self.ops = ops = params.operator_set
        N, M = scenario.n_locales, scenario.n_platforms
        P, group = params.population, ops.group
        self.layout = Layout(N, M, P // group, params.min_tour)
        self.rng, self.P = rng, P
        self.cost = PopulationCost(scenario, P, params.closed)
        self.patience = params.restart_policy.patience(N, self.layout.G)
        moves = ops.moves
        # Per distinct move, the slots it fills (the first one computed, the others copied).
        self.slots_of_move = [[s for s, slot in enumerate(ops.slots) if slot.move == move] for move in moves]
        self.parent_slots = _slots(ops, Breaks.PARENT)
        self.fresh_slots = _slots(ops, Breaks.FRESH)
        self.n_fresh = int(np.arange(group)[self.fresh_slots].size)
        self.moved_slots = [
            (s, moves.index(slot.move)) for s, slot in enumerate(ops.slots) if slot.breaks is Breaks.MOVED
        ]
        self.pop, self.heads = random_population(rng, P, N, M, params.min_tour)
        # Child s of group g reads parent row g at idx[g, s, k]; offsets g * N make that one gather.
        self.groups = np.arange(self.layout.G)
        self.goff = (self.groups * N)[:, None]
        self.idx = np.empty((self.layout.G, group, N), dtype=np.intp)
        self.new_heads = np.empty((self.layout.G, group, M), dtype=np.intp)
        self.best_cost = math.inf
        self.best_perm, self.best_heads = self.pop[0].copy(), self.heads[0].copy()
        self.restarts = 0

    def draw(self, n: int) -> _Batch:
        """Draw the random numbers of ``n`` generations, in the documented order."""
        lay, rng, group = self.layout, self.rng, self.ops.group
        N, M, G = lay.N, lay.M, lay.G
        orders = rng.permuted(np.tile(np.arange(self.P), (n, 1)), axis=1).reshape(n, G, group)
        IJ = np.sort(rng.integers(0, N, size=(n, G, 2)), axis=2)
        n_fresh = self.n_fresh
        rows = n * G * n_fresh
        fresh = random_heads(rng, rows, N, M, lay.min_tour) if rows else np.zeros((0, M), np.intp)
        plans = [move.plan(rng, IJ, lay) for move in self.ops.moves]
        return _Batch(orders, fresh.reshape(n, G, n_fresh, M), plans)

    def restart(self) -> None:
        lay = self.layout
        self.pop, self.heads = random_population(self.rng, self.P, lay.N, lay.M, lay.min_tour)
        self.restarts += 1

    def evolve(self, stop: StoppingCriterion, callback: Callback | None, t0: float) -> np.ndarray:
        """Run generations until ``stop``; returns the history of the best cost."""
        limit = iteration_limit(stop)
        batch_size = self.ops.batch_size(self.layout)
        scores: list[float] = [math.inf]  # before the first generation: no tour yet
        run_best, stall = math.inf, 0  # best cost since the last (re)start, generations since it fell
        it = 0
        while True:
            c = it % batch_size
            if c == 0:
                n = batch_size if limit is None else max(1, min(batch_size, limit - it))
                batch = self.draw(n)
            if stall >= self.patience:
                self.restart()
                run_best, stall = math.inf, 0
            cost = self.cost(self.pop, self.heads)
            i = int(np.argmin(cost))
            if cost[i] < run_best:
                run_best, stall = float(cost[i]), 0
                if run_best < self.best_cost:
                    self.best_cost = run_best
                    self.best_perm, self.best_heads = self.pop[i].copy(), self.heads[i].copy()
            else:
                stall += 1
            scores.append(self.best_cost)
            if callback is not None:
                callback(it, self.best_cost)
            it += 1
            if stop(Progress(it, scores, time.perf_counter() - t0)):
                return np.array(scores[1:])
            self.breed(batch, c, cost)

    def breed(self, batch: _Batch, c: int, cost: np.ndarray) -> None:
        """Replace the population by the children of each group's best (the parents)."""
        order = batch.orders[c]
        winners = order[self.groups, np.argmin(cost[order], axis=1)]
        parent_heads = self.heads[winners]
        children = [plan.child(c, parent_heads) for plan in batch.plans]
        idx, new_heads = self.idx, self.new_heads
        for (index, _), slots in zip(children, self.slots_of_move, strict=True):
            np.add(index, self.goff, out=idx[:, slots[0]])
            for s in slots[1:]:
                idx[:, s] = idx[:, slots[0]]
        new_heads[:, self.parent_slots] = parent_heads[:, None, :]
        new_heads[:, self.fresh_slots] = batch.fresh[c]
        for s, m in self.moved_slots:
            moved = children[m][1]
            assert moved is not None  # OperatorSet checks that MOVED slots hold moves that carry breaks
            new_heads[:, s] = moved
        self.pop = self.pop[winners].ravel()[idx].reshape(self.pop.shape)
        self.heads = new_heads.reshape(self.heads.shape).copy()
