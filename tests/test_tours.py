"""Straight-line tours through discs (pmht_opt.tours): known answers, invariances, checks, errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pmht_opt.exceptions import ConfigError, InfeasibleError, SolverError
from pmht_opt.tours import (
    DiscProblem,
    DiscTours,
    Progress,
    TourSettings,
    check_tours,
    coverage_gaps,
    plan_tours,
    read_mennell,
)
from pmht_opt.tours.engine import resequence, start_seed
from pmht_opt.tours.polish import solve_keys
from pmht_opt.tours.socp import disc_sequence
from pmht_opt.tours.tour import Layout, Tour

FAST = TourSettings(order_iterations=200, iterations=20, patience=10)


def _random(seed: int, n: int = 25, m: int = 1, closed: bool = True) -> DiscProblem:
    rng = np.random.default_rng(seed)
    return DiscProblem(
        rng.uniform(0, 10, (m, 2)), rng.uniform(0, 10, (n, 2)), rng.uniform(0.2, 1.0, n), closed
    )


def test_disc_holding_the_start_needs_no_travel() -> None:
    for closed in (True, False):
        tours = plan_tours(DiscProblem([[1.0, 1.0]], [[1.5, 1.0]], 1.0, closed), FAST)
        assert tours.total == 0.0
        assert tours.routes[0].tolist() == [0]
        np.testing.assert_allclose(tours.points[0], [1.0, 1.0])


def test_collinear_discs_open_and_closed() -> None:
    centres = [[2.0, 0.0], [4.0, 0.0], [6.0, 0.0]]
    open_ = plan_tours(DiscProblem([[0.0, 0.0]], centres, 0.5, False), FAST)
    closed = plan_tours(DiscProblem([[0.0, 0.0]], centres, 0.5, True), FAST)
    assert open_.total == pytest.approx(5.5, rel=1e-7)
    assert closed.total == pytest.approx(11.0, rel=1e-7)
    assert open_.routes[0].tolist() == [0, 1, 2]
    assert closed.routes[0].tolist() == [0, 1, 2]  # met on the way out
    assert len(closed.vertices(0)) == 3 and np.array_equal(closed.vertices(0)[-1], [0.0, 0.0])


def test_overlapping_discs_met_by_one_point() -> None:
    tours = plan_tours(DiscProblem([[0.0, 0.0]], [[3.0, 1.0], [3.0, -1.0]], 1.2, False), FAST)
    assert tours.total == pytest.approx(3 - np.sqrt(1.2**2 - 1), rel=1e-7)


def test_per_target_radii() -> None:
    tours = plan_tours(DiscProblem([[0.0, 0.0]], [[5.0, 0.0], [10.0, 0.0]], [2.0, 1.0], False), FAST)
    assert tours.total == pytest.approx(9.0, rel=1e-7)
    assert np.all(coverage_gaps(tours, rtol=0.0) <= 1e-12)


def test_closed_route_counts_the_leg_home() -> None:
    problem = _random(3, n=15)
    closed = plan_tours(problem, FAST)
    open_ = plan_tours(DiscProblem(problem.starts, problem.centres, problem.radii, False), FAST)
    assert open_.total < closed.total
    v = closed.vertices(0)
    assert np.array_equal(v[0], v[-1])
    assert closed.lengths[0] == pytest.approx(float(np.hypot(*np.diff(v, axis=0).T).sum()), rel=1e-12)


def test_every_target_once_and_covered_on_segments() -> None:
    problem = _random(5, n=30, m=2, closed=False)
    tours = plan_tours(problem, FAST)
    listed = np.sort(np.concatenate(tours.routes))
    assert listed.tolist() == list(range(30))
    assert np.all(coverage_gaps(tours, rtol=1e-9) <= 0)
    check_tours(tours)


def test_same_seed_same_bits() -> None:
    problem = _random(7)
    a, b = plan_tours(problem, FAST), plan_tours(problem, FAST)
    assert [r.tolist() for r in a.routes] == [r.tolist() for r in b.routes]
    assert np.array_equal(a.points, b.points) and np.array_equal(a.lengths, b.lengths)


@pytest.mark.parametrize("factor", [0.01, 100.0])
def test_units_do_not_matter(factor: float) -> None:
    problem = _random(11)
    base = plan_tours(problem, FAST)
    scaled = plan_tours(
        DiscProblem(problem.starts * factor, problem.centres * factor, problem.radii * factor, True), FAST
    )
    assert [r.tolist() for r in scaled.routes] == [r.tolist() for r in base.routes]
    np.testing.assert_allclose(scaled.lengths, base.lengths * factor, rtol=1e-9)


def test_more_starts_search_at_least_as_well_and_stay_deterministic() -> None:
    problem = _random(5, n=30, m=2, closed=False)
    one = plan_tours(problem, FAST)
    three = plan_tours(problem, replace(FAST, starts=3))
    # The first of the starts is the one-start search itself, and the best start's tour is kept.
    assert three.info["stages"]["search"] <= one.info["stages"]["search"]
    assert three.info["iterations"] > one.info["iterations"]
    again = plan_tours(problem, replace(FAST, starts=3))
    assert [r.tolist() for r in again.routes] == [r.tolist() for r in three.routes]
    assert np.array_equal(again.points, three.points)


def test_start_seeds_are_the_seed_then_drawn_from_it() -> None:
    assert start_seed(42, 0) == 42
    seeds = [start_seed(42, k) for k in range(1, 6)]
    assert len(set(seeds)) == 5 and all(0 <= s < 2**32 for s in seeds)
    assert seeds == [start_seed(42, k) for k in range(1, 6)]
    assert start_seed(43, 1) != start_seed(42, 1)


def test_callback_and_stop_see_progress() -> None:
    seen: list[Progress] = []
    tours = plan_tours(_random(2), FAST, callback=seen.append, stop=lambda p: p.iteration >= 3)
    assert [p.iteration for p in seen] == [0, 1, 2, 3]
    assert all(len(p.scores) == p.iteration + 1 for p in seen)
    assert seen[-1].scores[-1] == pytest.approx(tours.total)


def test_bad_input_names_the_field() -> None:
    with pytest.raises(ConfigError, match="radii"):
        DiscProblem([[0.0, 0.0]], [[1.0, 1.0]], -1.0)
    with pytest.raises(ConfigError, match="starts"):
        DiscProblem([0.0, 0.0], [[1.0, 1.0]], 1.0)
    with pytest.raises(ConfigError, match="centres"):
        DiscProblem([[0.0, 0.0]], [[1.0, np.nan]], 1.0)
    with pytest.raises(ConfigError, match="closed"):
        DiscProblem([[0.0, 0.0]], [[1.0, 1.0]], 1.0, closed=np.array([True, False]))
    with pytest.raises(ConfigError, match="objective"):
        TourSettings(objective="fast")
    with pytest.raises(ConfigError, match="seed"):
        TourSettings(seed=-1)
    with pytest.raises(ConfigError, match="iterations"):
        TourSettings(iterations=1.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="starts"):
        TourSettings(starts=0)
    with pytest.raises(ConfigError, match="resequence"):
        TourSettings(resequence=-1)
    with pytest.raises(ConfigError, match="resequence_iterations"):
        TourSettings(resequence_iterations=0)


def test_check_refuses_a_wrong_tour() -> None:
    tours = plan_tours(_random(4, n=10), FAST)
    far = DiscTours(tours.routes, tours.points, tours.lengths, [t * 0 for t in tours.turns], tours.problem)
    with pytest.raises(SolverError):
        check_tours(far)


def test_read_mennell(tmp_path: Path) -> None:
    good = tmp_path / "a.cetsp"
    good.write_text("//comment\n1 2 0 0.5 3\n3 4 0 0.25 1\n//Depot: 2.5, 1.5, 0\n")
    depot, centres, radii = read_mennell(good, radius_factor=2.0)
    np.testing.assert_array_equal(depot, [2.5, 1.5])
    np.testing.assert_array_equal(centres, [[1, 2], [3, 4]])
    np.testing.assert_array_equal(radii, [1.0, 0.5])
    other = tmp_path / "b.cetsp"
    other.write_text("//Depot is 100, 100, 0\n5 5 0 1 1\n")
    assert read_mennell(other)[0].tolist() == [100.0, 100.0]
    bad = tmp_path / "c.cetsp"
    bad.write_text("//Depot is 1, 1, 0\n5 5 zero 1 1\n")
    with pytest.raises(ConfigError, match=r"c\.cetsp, line 2"):
        read_mennell(bad)
    with pytest.raises(ConfigError, match="Depot"):
        (tmp_path / "d.cetsp").write_text("5 5 0 1 1\n")
        read_mennell(tmp_path / "d.cetsp")


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 7),
    m=st.integers(1, 2),
    closed=st.booleans(),
)
def test_random_instances(seed: int, n: int, m: int, closed: bool) -> None:
    rng = np.random.default_rng(seed)
    problem = DiscProblem(
        rng.uniform(0, 5, (m, 2)), rng.uniform(0, 5, (n, 2)), rng.uniform(0.1, 1.5, n), closed
    )
    tours = plan_tours(problem, TourSettings(order_iterations=50, iterations=5, patience=5))
    assert np.all(coverage_gaps(tours) <= 0)
    for k in range(m):
        route = tours.routes[k]
        c, r, s = problem.centres[route], problem.radii[route], problem.starts[k]
        lower = disc_sequence(s, c, r, closed)[1]  # the best polyline meeting the discs in this order
        through = np.vstack([s, c, s] if closed else [s, c])
        upper = float(np.hypot(*np.diff(through, axis=0).T).sum())
        assert lower * (1 - 1e-6) - 1e-9 <= tours.lengths[k] <= upper * (1 + 1e-9) + 1e-12


def test_time_objective_shortens_the_longest_route() -> None:
    rng = np.random.default_rng(8)
    problem = DiscProblem([[0.0, 0.0], [0.0, 1.0], [0.0, 2.0]], rng.uniform(0, 10, (30, 2)), 0.3, False)
    dist = plan_tours(problem, FAST)
    settings = TourSettings(objective="time", order_iterations=200, iterations=20, patience=10, bisection=2)
    time_ = plan_tours(problem, settings)
    assert time_.makespan <= dist.makespan * (1 + 1e-9)
    assert time_.total >= dist.total * (1 - 1e-9) or time_.makespan < dist.makespan
    check_tours(time_)


def test_every_vehicle_starts_from_its_own_start() -> None:
    problem = DiscProblem([[0.0, 0.0], [10.0, 10.0]], [[1.0, 0.0], [9.0, 10.0]], 0.2, True)
    tours = plan_tours(problem, FAST)
    assert tours.routes[0].tolist() == [0] and tours.routes[1].tolist() == [1]
    assert tours.total == pytest.approx(2 * 0.8 * 2, rel=1e-7)
    for m in range(2):
        assert np.array_equal(tours.vertices(m)[0], problem.starts[m])


# Route length caps (DiscProblem.max_lengths).


def _same(a: DiscTours, b: DiscTours) -> bool:
    return (
        [r.tolist() for r in a.routes] == [r.tolist() for r in b.routes]
        and np.array_equal(a.points, b.points)
        and np.array_equal(a.lengths, b.lengths)
        and all(np.array_equal(x, y) for x, y in zip(a.turns, b.turns, strict=True))
        and a.info["history"] == b.info["history"]
    )


@pytest.mark.parametrize(
    ("seed", "m", "closed", "objective"),
    [(0, 1, True, "distance"), (1, 2, False, "distance"), (2, 3, True, "distance"), (3, 3, False, "time")],
)
def test_no_caps_and_infinite_caps_give_the_same_bits(
    seed: int, m: int, closed: bool, objective: str
) -> None:
    # Infinite caps against none, solved side by side: the feature is inert until a cap is finite.
    # (The answers without caps were also compared with the engine's before caps, on 16 cases.)
    problem = _random(seed, n=15, m=m, closed=closed)
    search = TourSettings(seed=seed, objective=objective, order_iterations=150, iterations=10, bisection=1)
    caps = np.inf if seed % 2 else np.full(m, np.inf)
    capped = DiscProblem(problem.starts, problem.centres, problem.radii, closed, max_lengths=caps)
    assert capped.caps is None and capped.max_lengths is not None
    assert _same(plan_tours(capped, search), plan_tours(problem, search))


def test_caps_share_the_work_out() -> None:
    # Two vehicles at one start: the shortest total sends one of them round every disc.
    rng = np.random.default_rng(8)
    problem = DiscProblem([[0.0, 0.0], [0.0, 0.0]], rng.uniform(0, 10, (14, 2)), 0.3, True)
    free = plan_tours(problem, FAST)
    caps = np.array([0.7, 0.8]) * free.makespan
    capped = plan_tours(DiscProblem(problem.starts, problem.centres, problem.radii, True, caps), FAST)
    assert np.all(capped.lengths <= caps)
    assert capped.total >= free.total * (1 - 1e-9)
    check_tours(capped)
    timed = TourSettings(objective="time", order_iterations=200, iterations=20, patience=10, bisection=2)
    both = plan_tours(DiscProblem(problem.starts, problem.centres, problem.radii, True, caps), timed)
    assert np.all(both.lengths <= caps)


def test_a_target_out_of_reach_of_every_cap_is_proven_infeasible() -> None:
    starts = [[0.0, 0.0], [10.0, 0.0]]
    centres = [[1.0, 0.0], [9.0, 0.0], [5.0, 6.0]]  # the third is 6.3 from both starts, less 0.5
    with pytest.raises(InfeasibleError, match="target 2"):
        plan_tours(DiscProblem(starts, centres, 0.5, True, max_lengths=[11.0, 11.0]), FAST)
    # Open routes need only reach it: the same caps are then proven nothing.
    tours = plan_tours(DiscProblem(starts, centres, 0.5, False, max_lengths=[11.0, 11.0]), FAST)
    assert np.all(tours.lengths <= 11.0)
    with pytest.raises(InfeasibleError, match="target 2"):
        plan_tours(DiscProblem(starts, centres, 0.5, False, max_lengths=[5.0, 5.0]), FAST)


def test_caps_the_search_cannot_meet_are_a_solver_error_not_a_proof() -> None:
    # Each disc is within reach of the cap, all four together are not: nothing proven.
    centres = [[5.0, 0.0], [0.0, 5.0], [-5.0, 0.0], [0.0, -5.0]]
    problem = DiscProblem([[0.0, 0.0]], centres, 0.1, True, max_lengths=10.5)
    with pytest.raises(SolverError, match="max_lengths: the search did not find") as caught:
        plan_tours(problem, FAST)
    assert not isinstance(caught.value, InfeasibleError) and caught.value.status == "caps"


def test_check_refuses_a_route_over_its_cap() -> None:
    tours = plan_tours(_random(4, n=10), FAST)
    p = tours.problem
    over = DiscProblem(p.starts, p.centres, p.radii, p.closed, max_lengths=tours.lengths * 0.99)
    with pytest.raises(SolverError, match="over its cap"):
        check_tours(DiscTours(tours.routes, tours.points, tours.lengths, tours.turns, over))


@pytest.mark.parametrize(
    "caps", [[1.0, -1.0], [1.0, 0.0], [1.0, np.nan], [1.0], [[1.0, 2.0]], "long", -np.inf]
)
def test_bad_caps_are_named(caps: object) -> None:
    with pytest.raises(ConfigError, match="max_lengths"):
        DiscProblem([[0.0, 0.0], [1.0, 0.0]], [[1.0, 1.0]], 1.0, max_lengths=caps)  # type: ignore[arg-type]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 7),
    m=st.integers(1, 3),
    closed=st.booleans(),
    factor=st.floats(0.3, 1.2),
)
def test_caps_hold_or_are_refused(seed: int, n: int, m: int, closed: bool, factor: float) -> None:
    rng = np.random.default_rng(seed)
    starts, centres, radii = rng.uniform(0, 5, (m, 2)), rng.uniform(0, 5, (n, 2)), rng.uniform(0.1, 1.5, n)
    caps = factor * rng.uniform(0.5, 1.0, m) * 10.0
    problem = DiscProblem(starts, centres, radii, closed, max_lengths=caps)
    try:
        tours = plan_tours(problem, TourSettings(order_iterations=50, iterations=5, patience=5))
    except InfeasibleError as err:  # only with a proof: some disc out of every route's reach
        gap = np.maximum(np.hypot(*(centres[:, None] - starts[None]).T).T - radii[:, None], 0.0)
        need = gap * (2 if closed else 1)
        n_lost = int(str(err).split("target ")[1].split(" ")[0])
        assert np.all(need[n_lost] > caps)
        return
    except SolverError as err:
        assert err.status == "caps"
        return
    assert np.all(tours.lengths <= caps)
    assert np.all(coverage_gaps(tours) <= 0)


def _line_layout() -> Layout:
    """Five discs of radius 0.1 at x = 1, 3, 5, 7, 9 on a line, one open route from the origin."""
    centres = np.column_stack([np.arange(1.0, 10.0, 2.0), np.zeros(5)])
    return Layout(np.zeros((1, 2)), np.array([False]), centres, np.full(5, 0.1))


def test_resequencing_straightens_a_scrambled_route() -> None:
    lay = _line_layout()
    order = [3, 0, 4, 1, 2]
    scrambled = Tour(lay, [order], [lay.centres[order].copy()])
    assert scrambled.lengths()[0] > 20.0
    out = resequence(scrambled, FAST, np.random.default_rng(0))
    # One straight leg from the origin into the last disc: 9 - 0.1; the others are crossed on the way.
    assert out.covered().all()
    assert out.lengths()[0] == pytest.approx(8.9, abs=1e-6)
    again = resequence(scrambled, FAST, np.random.default_rng(0))
    assert again.keys == out.keys
    assert all(np.array_equal(a, b) for a, b in zip(again.pts, out.pts, strict=True))
    assert scrambled.keys == [order]  # the tour it is given is left as it was


def test_resequencing_keeps_every_disc_met_on_random_fleets() -> None:
    for seed in range(4):
        problem = _random(seed, n=30, m=3, closed=bool(seed % 2))
        tours = plan_tours(problem, replace(FAST, resequence=1))  # every candidate a re-sequencing
        check_tours(tours)
        assert tours.info["iterations"] >= 1


def test_a_route_solved_once_is_not_solved_again() -> None:
    lay = _line_layout()
    tour = Tour(lay, [[4, 2]], [lay.centres[[4, 2]].copy()])
    first = solve_keys(tour)
    assert list(lay.solved) == [(0, (4, 2))]
    first.pts[0][:] = -1.0  # a search that changes turn points in place does not change what is kept
    second = solve_keys(tour)
    np.testing.assert_array_equal(second.pts[0], lay.solved[(0, (4, 2))])
    expected, _ = disc_sequence(lay.starts[0], lay.centres[[4, 2]], lay.radii[[4, 2]], False)
    np.testing.assert_array_equal(second.pts[0], expected)


def test_a_cone_program_clarabel_does_not_solve_still_gives_points_in_every_disc() -> None:
    # A zig-zag of 15 discs from A at radius 0.3 (unit box) that Clarabel ended "almost solved" on
    # this machine, which used to fail the whole plan; solved or not, the answer must be feasible.
    lo, mid, hi = 0.4479166669771075, 0.5520833330228925, 0.34375
    x = [0.65625, 0.7604166669771075, 0.7604166669771075, 0.65625, 0.7604166669771075, 0.65625, 0.65625]
    x += [mid, mid, lo, lo, hi, hi, 0.23958333302289248, 0.23958333302289248]
    y = [0.23958333302289248, 0.23958333302289248, hi, hi, lo, lo, mid, mid, lo, mid, lo, lo, mid, mid, lo]
    centres = np.column_stack([x, y])
    radii = np.full(15, 0.03124999813735485)
    start = np.array([0.6399050047621131, 0.15541657898575068])
    pts, length = disc_sequence(start, centres, radii, False)
    assert np.all(np.hypot(*(pts - centres).T) <= radii)
    through_centres = float(np.hypot(*np.diff(np.vstack([start, centres]), axis=0).T).sum())
    assert length <= through_centres
    assert length == pytest.approx(float(np.hypot(*np.diff(np.vstack([start, pts]), axis=0).T).sum()))
