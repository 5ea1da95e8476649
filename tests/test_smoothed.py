"""plan_smoothed: a tour becomes hard visit constraints inside ordered sub-batches."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import VIOLATION_TOL

from pmht_opt import (
    ConfigError,
    InfeasibleError,
    PMHTConfig,
    Scenario,
    Settings,
    SolverError,
    SpeedLimit,
    order_locales,
    paper_scenario,
    plan_smoothed,
)
from pmht_opt.planners.smoothed import SmoothedOptions, order_for, sub_batches

ITERATIONS = {"clarabel": 8, "osqp": 4, "cvxpy": 8}
#: OSQP's first solve with the visit rows takes thousands of ADMM iterations: it plans the same tours
#: over 150 of the paper's 500 steps (same locales and assertions, about half the time of 250; at 100
#: steps OSQP stops at its iteration limit). cvxpy, whose compile and solves scale with the horizon,
#: over 250.
HORIZON = {"osqp": 150, "cvxpy": 250}


@pytest.fixture(scope="module")
def tours() -> dict:
    out = {}
    for kind in "ABC":
        sc = paper_scenario(kind, seed=1)
        out[kind] = (sc, order_locales(sc, "ga", seed=1, iterations=300))
    return out


# Every scenario on Clarabel and cvxpy; OSQP, the slowest here, on C (the others share its rows).
@pytest.mark.parametrize(
    ("kind", "solver"), [(k, s) for s in ("clarabel", "cvxpy") for k in "ABC"] + [("C", "osqp")]
)
def test_smoothed_visits_every_locale_in_tour_order(kind: str, solver: str, tours: dict) -> None:
    sc, tour = tours[kind]
    if solver in HORIZON:
        sc = paper_scenario(kind, seed=1, horizon=HORIZON[solver])
    res = plan_smoothed(sc, tour, PMHTConfig(solver=solver, max_iter=ITERATIONS[solver]), visit_radius=0.1)
    windows = res.extras["sub_batches"]
    times = res.visit_time
    for m, route in enumerate(tour.routes):
        assert np.all(res.assignment[route] == m)
        # In tour order: visit steps strictly increase along the route ...
        assert np.all(np.diff(times[route]) > 0)
        # ... and each lies inside its own sub-batch.
        assert np.all((times[route] >= windows[route, 0]) & (times[route] <= windows[route, 1]))
        dist = np.hypot(*(res.positions[m, times[route]] - sc.locales[route]).T)
        assert np.all(dist <= 0.1 + VIOLATION_TOL[solver])  # solver tolerances
    rep = res.constraint_reports()[-1]
    assert rep.details["visits_met"] == sc.n_locales and rep.details["times_in_sub_batch"] == sc.n_locales


def test_sub_batches_partition_each_horizon_in_order() -> None:
    sc = paper_scenario("B", seed=2)
    tour = order_locales(sc, "ga", seed=0, iterations=50)
    for split in ("equal", "distance"):
        w = sub_batches(sc, tour.routes, split)
        for route in tour.routes:
            lo, hi = w[route, 0], w[route, 1]
            assert lo[0] == 1 and hi[-1] == sc.horizon
            assert np.all(lo[1:] == hi[:-1] + 1) and np.all(hi >= lo)


def test_smoothed_accepts_plain_routes_and_rejects_bad_ones() -> None:
    sc = paper_scenario("A", seed=3, horizon=120)
    routes = [list(range(k, 100, 4)) for k in range(4)]
    res = plan_smoothed(sc, routes, PMHTConfig(max_iter=2))  # visit radius: the coverage radius
    assert res.coverage(sc.coverage_radius + 1e-6) == 1.0 and res.coverage() == 1.0
    tight = plan_smoothed(sc, routes, PMHTConfig(max_iter=2), visit_radius=0.1)
    assert tight.coverage(0.1 + 1e-6) == 1.0
    with pytest.raises(ConfigError):
        plan_smoothed(sc, [list(range(50)), list(range(50, 99)), [], []])  # locale 99 missing
    with pytest.raises(ConfigError):
        plan_smoothed(sc, routes, visit_radius=0.0)
    with pytest.raises(ConfigError, match="split"):
        plan_smoothed(sc, routes, split="random")


def test_smoothed_infeasible_names_platform_and_locale() -> None:
    sc = paper_scenario("A", seed=3, horizon=120)
    routes = [list(range(k, 100, 4)) for k in range(4)]
    with pytest.raises(InfeasibleError, match=r"platform \d.*locale \d+"):
        plan_smoothed(sc, routes, PMHTConfig(max_iter=2, constraints=[SpeedLimit(0.01)]))


@pytest.mark.parametrize("gate", [None, "auto"])
def test_tour_visits_take_the_first_most_probable_step_of_each_window(
    gate: object, tours: dict, monkeypatch: pytest.MonkeyPatch
) -> None:
    from pmht_opt.constraints.base import ConstraintContext
    from pmht_opt.estep import estep
    from pmht_opt.planners import windows as smoothed

    sc, tour = tours["B"]
    platform, windows = np.empty(sc.n_locales, dtype=int), sub_batches(sc, tour.routes)
    for m, route in enumerate(tour.routes):
        platform[route] = m
    rng = np.random.default_rng(3)
    paths = rng.uniform(0.0, 10.0, (sc.n_platforms, sc.horizon, 2))
    es = estep(sc.locales, paths, None, None, 0.05, gate=gate)
    visits = smoothed.TourVisits(platform, windows, radius=0.1)
    # Blocks of a few locales, so that the block boundaries are crossed.
    monkeypatch.setattr(smoothed, "VISIT_BLOCK", 3 * sc.horizon * sc.n_platforms)
    _, times = visits.visits(ConstraintContext(scenario=sc, states=np.zeros(0), estep=es))
    for n, (m, (lo, hi)) in enumerate(zip(platform, windows, strict=True)):
        assert times[n] == lo + int(np.argmax(es.locale_weights(n)[lo - 1 : hi, m]))


def test_the_tours_orderer_caps_routes_at_what_the_horizon_allows() -> None:
    # Two platforms west of 16 locales: the shortest routes in total use one platform (9.95 long);
    # at a speed limit of 0.08 each can fly 8.89 in the 120 steps, so both fly, still by distance.
    rng = np.random.default_rng(0)
    sc = Scenario(rng.uniform(0, 4, (16, 2)), [[-1.0, 1.0], [-1.0, 3.0]], horizon=120, coverage_radius=0.3)
    options = SmoothedOptions(order_options={"order_iterations": 300, "iterations": 20})
    free, _ = order_for(sc, Settings(), options)
    assert min(len(r) for r in free) == 0
    capped, objective = order_for(sc, Settings(constraints=[SpeedLimit(0.08)]), options)
    assert objective == "distance" and min(len(r) for r in capped) > 0
    with pytest.raises(SolverError, match="lengthen the horizon, raise the speed limit or add platforms"):
        order_for(sc, Settings(constraints=[SpeedLimit(0.05)]), options)
