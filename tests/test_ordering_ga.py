"""The GA's parts passed in: operator tables, restart policies and stopping criteria.

The reference instances and the exhaustive search are those of ``test_ordering``.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_ordering import assert_valid, brute_force, instance

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering import TourResult, solve_ga_tsp
from pmht_opt.ordering.ga import (
    IMPROVED,
    KIRK,
    Breaks,
    Copy,
    Flip,
    GAParams,
    NoRestart,
    OperatorSet,
    RouteExchange,
    SegmentMove,
    Slide,
    Slot,
    StallRestart,
    Swap,
)
from pmht_opt.stopping import AnyOf, MaxIterations, NoImprovement, TimeBudget


def same_tour(a: TourResult, b: TourResult) -> bool:
    """Same routes and the same history, bit for bit."""
    routes = all(np.array_equal(x, y) for x, y in zip(a.routes, b.routes, strict=True))
    return routes and np.array_equal(a.history, b.history)


@pytest.mark.parametrize("operators", ["improved", "kirk"])
def test_max_iterations_stop_is_the_iterations_option(operators: str) -> None:
    """A run stopped by MaxIterations(n) draws exactly what iterations=n draws (130 crosses a batch)."""
    sc = instance(12, 3, 4)
    ref = solve_ga_tsp(sc, seed=3, iterations=130, min_tour=2, operators=operators)
    for kwargs in (
        {"iterations": None, "stop": MaxIterations(130)},
        {"iterations": 130, "stop": MaxIterations(400)},
        {"iterations": None, "stop": AnyOf((MaxIterations(130), NoImprovement(10_000)))},
    ):
        res = solve_ga_tsp(sc, seed=3, min_tour=2, operators=operators, **kwargs)
        assert same_tour(res, ref), kwargs
        assert res.extras == ref.extras


def test_no_improvement_stops_early_on_the_capped_runs_path() -> None:
    """With an iteration cap the draws are those of the capped run, so an early stop is a prefix of it."""
    sc = instance(14, 3, 2)
    full = solve_ga_tsp(sc, seed=1, iterations=600, operators="kirk")
    early = solve_ga_tsp(sc, seed=1, iterations=600, operators="kirk", stop=NoImprovement(40))
    n = early.history.size
    assert n < 600
    np.testing.assert_array_equal(early.history, full.history[:n])
    assert early.extras["iterations"] == n
    # It stopped because the last 40 generations did not beat the ones before them.
    assert early.history[-1] == early.history[-41]
    assert np.all(np.diff(early.history[:-40]) <= 0)
    assert_valid(early, sc)


def test_uncapped_run_ends_on_its_criterion() -> None:
    sc = instance(8, 2, 3)
    best, _ = brute_force(sc)
    res = solve_ga_tsp(sc, seed=0, iterations=None, stop=NoImprovement(100))
    assert res.total_distance == pytest.approx(best, rel=1e-9)
    assert res.history.size > 100
    assert res.history[-1] == res.history[-101]
    quick = solve_ga_tsp(sc, seed=0, iterations=None, stop=TimeBudget(0.05))
    assert_valid(quick, sc)


def test_operator_tables_by_name_and_by_object_agree() -> None:
    sc = instance(9, 2, 1)
    for name, table in (("kirk", KIRK), ("improved", IMPROVED)):
        a = solve_ga_tsp(sc, seed=2, iterations=150, operators=name)
        b = solve_ga_tsp(sc, seed=2, iterations=150, operators=table)
        assert same_tour(a, b)
        assert b.extras["operators"] == name


def test_restart_policies() -> None:
    sc = instance(8, 3, 4)
    default = solve_ga_tsp(sc, seed=7, iterations=300, min_tour=2)
    explicit = solve_ga_tsp(sc, seed=7, iterations=300, min_tour=2, restart=StallRestart(stall=5.0))
    assert same_tour(default, explicit)
    assert default.extras["restarts"] > 0
    never = solve_ga_tsp(sc, seed=7, iterations=300, min_tour=2, restart=NoRestart())
    assert never.extras["restarts"] == 0
    eager = solve_ga_tsp(sc, seed=7, iterations=300, min_tour=2, restart=StallRestart(stall=1.0))
    assert eager.extras["restarts"] > default.extras["restarts"]
    # Restarts never lose the best tour: the history still never increases.
    assert np.all(np.diff(eager.history) <= 0)
    assert StallRestart(5.0).patience(100, 10) == 2525
    assert StallRestart(5.0).patience(8, 10) == 18
    assert NoRestart().patience(100, 10) == float("inf")
    # Kirk's table with restarts: allowed, and the restarts happen.
    kirk = solve_ga_tsp(sc, seed=7, iterations=300, min_tour=2, operators="kirk", restart=StallRestart())
    assert kirk.extras["restarts"] > 0


def test_a_custom_table_of_four_slots() -> None:
    """A table is data: four children per parent, so the population is a multiple of 4."""
    table = OperatorSet(
        "mine",
        (
            Slot(Copy(), Breaks.PARENT),
            Slot(SegmentMove(reverse=1.0), Breaks.MOVED),
            Slot(Flip(), Breaks.FRESH),
            Slot(RouteExchange(), Breaks.MOVED),
        ),
    )
    sc = instance(7, 2, 5)
    best, _ = brute_force(sc)
    res = solve_ga_tsp(sc, seed=0, population=12, iterations=400, operators=table)
    assert_valid(res, sc)
    assert res.extras["operators"] == "mine"
    assert res.total_distance == pytest.approx(best, rel=1e-9)
    with pytest.raises(ConfigError, match=r"^population: expected a positive multiple of 4, got 10\.$"):
        solve_ga_tsp(sc, population=10, operators=table)


def test_single_move_tables_keep_valid_tours() -> None:
    """Every move on its own, with each break rule it allows, over batches and min_tour."""
    sc = instance(11, 3, 8)
    for move in (Copy(), Flip(), Swap(), Slide(), SegmentMove(), RouteExchange()):
        rules = [Breaks.PARENT, Breaks.FRESH] + ([Breaks.MOVED] if move.carries_breaks else [])
        for rule in rules:
            table = OperatorSet("one", (Slot(Copy(), Breaks.PARENT), Slot(move, rule)))
            res = solve_ga_tsp(sc, seed=1, population=10, iterations=140, min_tour=3, operators=table)
            assert_valid(res, sc, min_tour=3)


@pytest.mark.parametrize(
    ("make", "pattern"),
    [
        (lambda: OperatorSet("x", ()), r"^OperatorSet\.slots: expected at least one slot"),
        (lambda: OperatorSet("x", (Slot(Flip(), Breaks.MOVED),)), r"^OperatorSet\.slots\[0\]\.breaks: Flip"),
        (lambda: OperatorSet("x", (Slot(Flip(), "fresh"),)), r"^OperatorSet\.slots\[0\]\.breaks: expected"),
        (lambda: OperatorSet("x", ("flip",)), r"^OperatorSet\.slots\[0\]: expected a Slot"),
        (lambda: SegmentMove(reverse=1.5), r"^SegmentMove\.reverse: expected a probability"),
        (lambda: StallRestart(stall=0), r"^StallRestart\.stall: expected a positive finite number"),
        (lambda: GAParams(iterations=None), r"^iterations: expected a number of generations"),
        (lambda: GAParams(stop=3), r"^stop: expected a stopping criterion"),
        (lambda: GAParams(restart="stall"), r"^restart: expected a restart policy"),
        (lambda: GAParams(operators=KIRK.slots), r"^operators: expected one of"),
    ],
)
def test_bad_parts_name_the_field(make: object, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        make()  # type: ignore[operator]
