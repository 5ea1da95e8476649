"""The coverage planner: every locale within its radius, user constraints kept, closed tours closed,
deterministic, independent of the horizon and of the units, bad input named."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.planners.coverage import missed_locales
from pmht_opt.planners.routes import route_budgets


def small_scenario(kind: str, seed: int = 0, horizon: int = 120) -> po.Scenario:
    """A, B and C of the paper shrunk to 16 locales in a 4 x 4 box (a few seconds for the whole file)."""
    rng = np.random.default_rng(seed)
    if kind == "A":
        g = np.arange(4) + 0.5
        locales = np.column_stack([np.repeat(g, 4), np.tile(g, 4)])
        starts = rng.uniform(0, 4, size=(3, 2))
    elif kind == "B":
        locales = rng.uniform(0, 4, size=(16, 2))
        starts = np.array([[-1.0, 1.0], [-1.0, 3.0]])
    else:
        locales = rng.uniform(0, 4, size=(16, 2))
        starts = rng.uniform(0, 4, size=(3, 2))
    return po.Scenario(locales=locales, starts=starts, horizon=horizon, bounds=(0, 4, 0, 4))


def distance_to_paths(locales: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Distance of each locale to the nearest segment of any path, written out here on purpose."""
    best = np.full(locales.shape[0], np.inf)
    for path in positions:
        a, b = path[:-1], path[1:]
        ab = b - a
        for n, z in enumerate(locales):
            az = z - a
            denom = np.maximum((ab * ab).sum(axis=1), 1e-300)
            s = np.clip((az * ab).sum(axis=1) / denom, 0.0, 1.0)
            closest = a + s[:, None] * ab
            best[n] = min(best[n], float(np.min(np.linalg.norm(z - closest, axis=1))))
    return best


#: A short tour search, for tests of what the planner promises rather than of how short its tours are.
QUICK = {"order_iterations": 300, "iterations": 20, "patience": 10}


def cover(
    sc: po.Scenario, radius: Any = None, constraints: tuple = (), threads: int = 1, seed: int = 0
) -> po.PlanResult:
    """The coverage planner with a short search."""
    settings = po.Settings(threads=threads, constraints=constraints, seed=seed)
    return po.plan(sc, "coverage", settings=settings, radius=radius, search=QUICK)


def assert_covers(result: po.PlanResult, radius: float) -> None:
    dist = distance_to_paths(result.scenario.locales, result.positions)
    assert np.all(dist <= radius * (1 + 1e-6)), f"missed: {np.flatnonzero(dist > radius * (1 + 1e-6))}"


@pytest.mark.parametrize("radius", [0.1, 0.3])
@pytest.mark.parametrize("kind", ["A", "B", "C"])
def test_every_locale_within_the_radius(kind: str, radius: float) -> None:
    sc = small_scenario(kind, seed=1)
    res = cover(sc, radius)
    assert_covers(res, radius)
    assert res.coverage(radius) == 1.0 and res.planner == "coverage"
    assert res.positions.shape == (sc.n_platforms, sc.horizon + 1, 2)
    np.testing.assert_array_equal(res.states[:, 0], sc.initial_states)
    assert sorted(np.concatenate(res.extras["routes"]).tolist()) == list(range(sc.n_locales))
    # The visit each locale is promised: its platform within the radius on the segment after its step.
    after = np.minimum(res.visit_time + 1, sc.horizon)
    for n, (m, t, u) in enumerate(zip(res.assignment, res.visit_time, after, strict=True)):
        segment = res.positions[m, [t, u]][None]
        assert distance_to_paths(sc.locales[n : n + 1], segment)[0] <= radius * (1 + 1e-6)
    # The straight-line tour it flew covers every locale too, and is no longer than the smooth plan.
    tour = res.extras["tour"]
    assert_covers_lines(sc.locales, tour, radius)
    assert res.extras["tour_length"] <= res.total_distance * (1 + 1e-9)


def assert_covers_lines(locales: np.ndarray, lines: list[np.ndarray], radius: float) -> None:
    best = np.min([distance_to_paths(locales, line[None]) for line in lines], axis=0)
    assert np.all(best <= radius * (1 + 1e-6))


def test_each_locale_its_own_radius() -> None:
    sc = small_scenario("C", seed=2)
    radii = np.linspace(0.05, 0.5, sc.n_locales)
    res = cover(sc.replace(coverage_radius=radii))
    dist = distance_to_paths(sc.locales, res.positions)
    assert np.all(dist <= radii * (1 + 1e-6))
    assert res.coverage() == 1.0


def test_default_radius_is_the_scenarios() -> None:
    sc = small_scenario("B", seed=2).replace(coverage_radius=0.25)
    res = cover(sc)
    assert_covers(res, 0.25)


def test_shorter_than_the_tour_through_the_centres() -> None:
    sc = small_scenario("C", seed=3)
    res = po.plan_coverage(sc, 0.3, po.PMHTConfig(threads=1))
    tour = po.order_locales(sc, "pyvrp", seed=0)
    assert res.total_distance < tour.total_distance


def test_user_constraints_hold() -> None:
    sc = small_scenario("C", seed=4, horizon=150)
    obstacle = po.CircleObstacle((2.0, 2.0), 0.4)
    locales = sc.locales[np.linalg.norm(sc.locales - 2.0, axis=1) > 0.9]  # every disc reachable
    sc = sc.replace(locales=locales)
    vmax = 0.1
    res = cover(sc, 0.3, (po.SpeedLimit(vmax), obstacle))
    assert_covers(res, 0.3)
    speed = np.linalg.norm(res.states[:, :, [1, 4]], axis=2)
    assert speed.max() <= vmax * (1 + 1e-6)
    clearance = np.linalg.norm(res.positions - np.array([2.0, 2.0]), axis=2)
    assert clearance.min() >= 0.4 - 1e-6
    assert all(r.satisfied for r in res.constraint_reports())


def test_a_return_to_base_is_flown_as_a_closed_tour() -> None:
    sc = small_scenario("A", seed=5)
    cfg = po.PMHTConfig(threads=1, constraints=[po.Terminal.return_to_base()])
    res = po.plan_coverage(sc, 0.3, cfg)
    assert_covers(res, 0.3)
    np.testing.assert_allclose(res.positions[:, -1], sc.start_positions, atol=1e-5)
    # The tour was ordered closed: each route's polyline ends where it started.
    for line, start in zip(res.extras["tour"], sc.start_positions, strict=True):
        np.testing.assert_allclose(line[-1], start, atol=1e-12)
    # Closing the open routes of the same scenario gives tours no shorter than the closed search.
    open_tour = po.plan_coverage(sc, 0.3, po.PMHTConfig(threads=1)).extras["tour"]
    closed_again = sum(
        float(np.hypot(*np.diff(np.vstack([line, start]), axis=0).T).sum())
        for line, start in zip(open_tour, sc.start_positions, strict=True)
    )
    assert res.extras["tour_length"] <= closed_again * (1 + 1e-9)


def test_same_seed_same_plan() -> None:
    sc = small_scenario("C", seed=6)
    a = cover(sc, 0.3, threads=1, seed=3)
    b = cover(sc, 0.3, threads=2, seed=3)
    np.testing.assert_array_equal(a.states, b.states)


def test_the_plan_does_not_depend_on_the_units() -> None:
    """The same scenario in other units (coordinates and radii scaled by s): the same tour, scaled,
    and the same flight to the M-step's accuracy."""
    sc = small_scenario("B", seed=8)
    base = cover(sc, 0.3)
    for s in (0.01, 100.0):
        box = tuple(np.multiply(sc.bounds, s))
        big = sc.replace(locales=sc.locales * s, starts=sc.start_positions * s, bounds=box)
        res = cover(big, 0.3 * s)
        assert res.extras["tour_length"] == pytest.approx(s * base.extras["tour_length"], rel=1e-9)
        # The flight to the interior point's accuracy on constrained M-steps (hard rows 1e-5 inside).
        np.testing.assert_allclose(res.positions / s, base.positions, rtol=0, atol=1e-4)
        assert res.total_distance == pytest.approx(s * base.total_distance, rel=1e-4)


def test_the_plan_does_not_depend_on_the_horizon() -> None:
    """The same tour flown over 200, 400 and 800 steps: the same length within half a percent."""
    sc = small_scenario("C", seed=9)
    lengths = [cover(sc.replace(horizon=T), 0.3).total_distance for T in (200, 400, 800)]
    assert max(lengths) <= min(lengths) * 1.005


def test_progress_and_stop_follow_the_tour_search() -> None:
    seen: list[po.Progress] = []
    po.plan(small_scenario("B"), "coverage", stop=po.MaxIterations(3), callback=seen.append)
    assert [p.iteration for p in seen] == [0, 1, 2, 3] and {p.stage for p in seen} == {"search"}
    assert all(p.elapsed >= 0 for p in seen)


def test_an_unreachable_disc_is_refused() -> None:
    sc = small_scenario("C", seed=7)
    centre = sc.locales[0]
    cfg = po.PMHTConfig(threads=1, constraints=[po.CircleObstacle(tuple(centre), 0.5)])
    if np.any(np.linalg.norm(sc.start_positions - centre, axis=1) < 0.6):
        pytest.skip("a start inside the obstacle")
    with pytest.raises(po.InfeasibleError):
        po.plan_coverage(sc, 0.3, cfg)


def test_missed_locales_on_a_known_path() -> None:
    sc = po.Scenario(locales=[[0.5, 0.2], [0.5, 0.6]], starts=[[0.0, 0.0]], horizon=2)
    path = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]])
    assert missed_locales(sc, path, 0.3).tolist() == [1]
    assert missed_locales(sc, path, 0.6).tolist() == []


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"radius": -1.0}, "radius"),
        ({"radius": "wide"}, "radius"),
        ({"config": "fast"}, "config"),
        ({"seed": -1}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"objective": "fast"}, "objective"),
        ({"smoothing": 0.0}, "smoothing"),
        ({"iterations": 0}, "iterations"),
        ({"orderer": "ga"}, "orderer"),
        ({"starts": 3}, "starts"),
        ({"time_budget": 1.0}, "time_budget"),
        ({"config": po.PMHTConfig(max_iter=5)}, "config.max_iter"),
    ],
)
def test_bad_input_names_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(po.ConfigError, match=field):
        po.plan_coverage(small_scenario("A"), **kwargs)


def test_not_a_scenario() -> None:
    with pytest.raises(po.ConfigError, match="scenario"):
        po.plan_coverage("A")  # type: ignore[arg-type]


def test_a_plan_that_fails_the_check_is_never_returned(monkeypatch: pytest.MonkeyPatch) -> None:
    import pmht_opt.planners.coverage.fly as fly

    monkeypatch.setattr(fly, "missed_locales", lambda locales, positions, radius: np.array([3]))
    with pytest.raises(po.SolverError, match=r"locales \[3\]"):
        po.plan_coverage(small_scenario("B"), 0.3, po.PMHTConfig(threads=1))


#: A short tour search: these tests are about the speed limit's caps, not the search's quality.
def test_the_speed_limit_caps_each_route_and_keeps_the_objective() -> None:
    # Scenario B, seed 0: the shortest routes in total send one platform round every locale (9.95);
    # at 0.08 a platform can fly 8.89 in the horizon, so the work is shared, the total still shortest.
    sc = small_scenario("B", seed=0)
    free = po.plan(sc, "coverage", settings=po.Settings(threads=1), radius=0.3, search=QUICK)
    limit = [po.SpeedLimit(0.08)]
    settings = po.Settings(threads=1, constraints=limit)
    res = po.plan(sc, "coverage", settings=settings, radius=0.3, search=QUICK)
    budgets = route_budgets(sc, limit)
    lengths = np.array([np.hypot(*np.diff(line, axis=0).T).sum() for line in res.extras["tour"]])
    assert res.extras["objective"] == "distance"
    assert max(np.hypot(*np.diff(line, axis=0).T).sum() for line in free.extras["tour"]) > budgets[0]
    assert np.all(lengths <= budgets) and lengths.sum() >= free.extras["tour_length"] * (1 - 1e-9)
    assert_covers(res, 0.3)
    assert res.max_speed <= 0.08 * (1 + 1e-6)


def test_routes_the_search_cannot_fit_in_the_horizon_say_what_to_change() -> None:
    sc = small_scenario("B", seed=0)
    settings = po.Settings(threads=1, constraints=[po.SpeedLimit(0.05)])  # every locale within reach
    with pytest.raises(po.SolverError, match="lengthen the horizon, raise the speed limit or add") as caught:
        po.plan(sc, "coverage", settings=settings, radius=0.3, search=QUICK)
    assert not isinstance(caught.value, po.InfeasibleError)
    assert "does not prove" in str(caught.value)


def test_two_discs_that_share_no_point_are_never_asked_of_one_point() -> None:
    """Both discs are nearest to the same sample of the path (the segment before it at fraction 1, the
    one after at 0): one point cannot lie in both, so the later one takes another point of the path."""
    from pmht_opt.planners.coverage.discs import VisitDiscs

    T = 10
    positions = np.zeros((1, T + 1, 2))
    positions[0, :, 0] = np.arange(T + 1, dtype=float)  # along the x axis, one unit a step
    centres = np.array([[5.0, 0.8], [5.0, -0.8]])  # both nearest to the sample at x = 5
    discs = VisitDiscs(np.zeros(2, dtype=int), np.array([5, 5]), centres, np.array([0.5, 0.5]), window=2)
    steps, alpha = discs.visit_points(positions, T)
    places = steps + alpha
    assert places[0] == 5.0 and places[1] == 5.5
    # Discs that do share a point keep the nearest point, shared.
    near = VisitDiscs(np.zeros(2, dtype=int), np.array([5, 5]), centres, np.array([1.0, 1.0]), window=2)
    steps, alpha = near.visit_points(positions, T)
    assert np.all(steps + alpha == 5.0)
