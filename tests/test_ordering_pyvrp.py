"""The PyVRP orderer: exhaustive optimum on the small instances, determinism, parameters.

The reference instances and the exhaustive search are those of ``test_ordering``, which also checks
the error of a missing PyVRP along with that of a missing OR-Tools.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_ordering import RANDOM_SMALL, SMALL, assert_valid, brute_force, instance

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering import order_locales, solve_pyvrp
from pmht_opt.scenario import paper_scenario

pytest.importorskip("pyvrp")

#: Iterations on the small instances (the first local search usually finds the optimum already).
SMALL_ITERATIONS = 200
#: Agreement with the exhaustive optimum: integer arc costs round each arc by about 5e-9 of the longest.
PYVRP_TOL = 1e-7


@pytest.mark.parametrize(("n", "m", "min_tour", "seed"), SMALL + RANDOM_SMALL)
def test_pyvrp_finds_brute_force_optimum(n: int, m: int, min_tour: int, seed: int) -> None:
    sc = instance(n, m, seed)
    best, _ = brute_force(sc, min_tour)
    res = solve_pyvrp(sc, iterations=SMALL_ITERATIONS, min_tour=min_tour)
    assert_valid(res, sc, min_tour)
    assert res.total_distance == pytest.approx(best, rel=PYVRP_TOL)
    assert res.method == "pyvrp"
    assert np.all(np.diff(res.history) < 0)
    assert res.history[-1] == pytest.approx(res.total_distance, rel=PYVRP_TOL)


def test_pyvrp_gives_every_platform_a_locale() -> None:
    """Scenario B's starts lie off the map: left alone, PyVRP would leave a far platform idle."""
    sc = paper_scenario("B", seed=0)
    res = solve_pyvrp(sc, iterations=300)
    assert_valid(res, sc, min_tour=1)
    assert res.route_lengths.min() >= 1


@pytest.mark.parametrize(("n", "m", "min_tour"), [(12, 4, 3), (9, 3, 3), (10, 2, 4)])
def test_pyvrp_min_tour_above_one(n: int, m: int, min_tour: int) -> None:
    """The soft bound through waiting time: met exactly when N = M min_tour leaves no slack."""
    sc = instance(n, m, n)
    res = solve_pyvrp(sc, iterations=300, min_tour=min_tour)
    assert_valid(res, sc, min_tour)
    if n == m * min_tour:
        np.testing.assert_array_equal(res.route_lengths, min_tour)
    if n <= 9:
        best, _ = brute_force(sc, min_tour)
        assert res.total_distance == pytest.approx(best, rel=PYVRP_TOL)


def test_pyvrp_same_seed_same_tour() -> None:
    sc = paper_scenario("C", seed=2)
    a = solve_pyvrp(sc, seed=5, iterations=300)
    b = solve_pyvrp(sc, seed=5, iterations=300)
    c = order_locales(sc, "pyvrp", seed=np.random.default_rng(11), iterations=300)
    d = order_locales(sc, "pyvrp", seed=np.random.default_rng(11), iterations=300)
    for x, y in ((a, b), (c, d)):
        assert [r.tolist() for r in x.routes] == [r.tolist() for r in y.routes]
        np.testing.assert_array_equal(x.history, y.history)
        assert x.extras == y.extras
    assert_valid(a, sc)


def test_pyvrp_stops_on_no_improvement() -> None:
    sc = instance(9, 2, 4)
    res = solve_pyvrp(sc, iterations=5000, no_improvement=50)
    assert res.extras["iterations"] < 5000
    assert res.extras["no_improvement"] == 50
    best, _ = brute_force(sc)
    assert res.total_distance == pytest.approx(best, rel=PYVRP_TOL)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"seed": -1}, "seed"),
        ({"seed": 2**32}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"iterations": 0}, "iterations"),
        ({"iterations": 2.5}, "iterations"),
        ({"no_improvement": 0}, "no_improvement"),
        ({"no_improvement": "10"}, "no_improvement"),
        ({"min_tour": 0}, "min_tour"),
        ({"min_tour": 5}, "min_tour"),
    ],
)
def test_pyvrp_bad_parameters(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=rf"^{field}: expected"):
        solve_pyvrp(instance(8, 2, 0), **kwargs)
