"""Return to base: every orderer's closed tours against the exhaustive optimum, and their costs.

The reference instances and the exhaustive search (here with the legs home) are those of
``test_ordering``.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_ordering import (
    GA_SEEDS,
    GA_SMALL_ITERATIONS,
    RANDOM_SMALL,
    SMALL,
    assert_valid,
    brute_force,
    instance,
)

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering import (
    TourResult,
    order_locales,
    route_costs,
    solve_ga_tsp,
    solve_ortools,
    solve_pyvrp,
    tour_distance,
)
from pmht_opt.scenario import Scenario, paper_scenario

#: Agreement of the integer-cost solvers with the exhaustive optimum (rounding of about 1e-9 per arc).
INTEGER_TOL = 1e-7


def test_closed_distance_by_hand() -> None:
    sc = Scenario(locales=[[1.0, 0.0], [1.0, 2.0], [5.0, 5.0]], starts=[[0.0, 0.0], [5.0, 1.0]])
    # Platform 0: (0,0)->(1,0)->(1,2)->(0,0) = 1 + 2 + sqrt(5); platform 1: (5,1)->(5,5)->(5,1) = 8.
    np.testing.assert_allclose(route_costs(sc, [[0, 1], [2]], closed=True), [3 + np.sqrt(5), 8.0])
    assert tour_distance(sc, [[0, 1], [2]], closed=True) == pytest.approx(11 + np.sqrt(5))
    # An idle platform stays home: it flies nothing.
    assert tour_distance(sc, [[], [2, 1, 0]], closed=True) == pytest.approx(4 + 5 + 2 + np.hypot(4, 1))
    res = TourResult.from_routes(sc, [[0, 1], [2]], closed=True)
    assert res.closed and res.to_dict()["closed"] is True
    assert res.total_distance == pytest.approx(11 + np.sqrt(5))
    np.testing.assert_allclose(res.route_distances, [3 + np.sqrt(5), 8.0])
    res.validate()
    with pytest.raises(ConfigError, match=r"^closed: expected True"):
        tour_distance(sc, [[0, 1], [2]], closed="yes")  # type: ignore[arg-type]


@pytest.mark.parametrize(("n", "m", "min_tour", "seed"), SMALL + RANDOM_SMALL[:6])
def test_ga_closed_every_seed_finds_brute_force_optimum(n: int, m: int, min_tour: int, seed: int) -> None:
    sc = instance(n, m, seed)
    best, _ = brute_force(sc, min_tour, closed=True)
    for ga_seed in GA_SEEDS:
        res = solve_ga_tsp(sc, seed=ga_seed, iterations=GA_SMALL_ITERATIONS, min_tour=min_tour, closed=True)
        assert res.closed
        assert_valid(res, sc, min_tour)
        assert res.total_distance == pytest.approx(best, rel=1e-9), f"GA seed {ga_seed}"
        assert res.history[-1] == pytest.approx(res.total_distance, rel=1e-12)


@pytest.mark.parametrize(("n", "m", "min_tour", "seed"), SMALL[:6])
def test_kirk_ga_closed_costs_the_legs_home(n: int, m: int, min_tour: int, seed: int) -> None:
    """The paper's operators with the closed cost: valid closed tours whose history is their cost."""
    sc = instance(n, m, seed)
    best, _ = brute_force(sc, min_tour, closed=True)
    res = solve_ga_tsp(sc, seed=0, iterations=400, min_tour=min_tour, operators="kirk", closed=True)
    assert_valid(res, sc, min_tour)
    assert res.history[-1] == pytest.approx(res.total_distance, rel=1e-12)
    assert res.total_distance >= best * (1 - 1e-12)


@pytest.mark.parametrize(("n", "m", "min_tour", "seed"), SMALL)
def test_ortools_closed_finds_brute_force_optimum(n: int, m: int, min_tour: int, seed: int) -> None:
    pytest.importorskip("ortools")
    sc = instance(n, m, seed)
    best, _ = brute_force(sc, min_tour, closed=True)
    res = solve_ortools(sc, min_tour=min_tour, closed=True)
    assert res.closed
    assert_valid(res, sc, min_tour)
    assert res.total_distance == pytest.approx(best, rel=INTEGER_TOL)


@pytest.mark.parametrize(("n", "m", "min_tour", "seed"), SMALL + RANDOM_SMALL)
def test_pyvrp_closed_finds_brute_force_optimum(n: int, m: int, min_tour: int, seed: int) -> None:
    pytest.importorskip("pyvrp")
    sc = instance(n, m, seed)
    best, _ = brute_force(sc, min_tour, closed=True)
    res = solve_pyvrp(sc, iterations=200, min_tour=min_tour, closed=True)
    assert res.closed
    assert_valid(res, sc, min_tour)
    assert res.total_distance == pytest.approx(best, rel=INTEGER_TOL)


@pytest.mark.parametrize("method", ["ga", "ortools", "pyvrp"])
def test_closed_tours_cost_more_and_come_home(method: str) -> None:
    """Closed and open optima differ (B's starts lie off the map), each is costed its own way."""
    if method != "ga":
        pytest.importorskip(method)
    sc = paper_scenario("B", seed=1)
    options = {
        "ga": {"iterations": 300},
        "ortools": {"solution_limit": 60},
        "pyvrp": {"iterations": 200},
    }[method]
    opened = order_locales(sc, method, **options)
    closed = order_locales(sc, method, closed=True, **options)
    assert not opened.closed and closed.closed
    assert_valid(closed, sc)
    assert closed.total_distance == pytest.approx(tour_distance(sc, closed.routes, closed=True), rel=1e-12)
    assert closed.total_distance > tour_distance(sc, closed.routes) + 1.0
    assert closed.total_distance > opened.total_distance


@pytest.mark.parametrize("method", ["ga", "ortools", "pyvrp"])
def test_closed_must_be_a_bool(method: str) -> None:
    with pytest.raises(ConfigError, match=r"^closed: expected True"):
        order_locales(instance(6, 2, 0), method, closed=1)
