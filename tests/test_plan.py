"""The one way in: every planner and every ordering behind one verb, with one settings, stop and
callback contract."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import pmht_opt as po

#: A paper scenario small enough for every planner in a second or two.
SCENARIO = po.paper_scenario("A", seed=0, horizon=150)


@pytest.mark.parametrize("method", list(po.PLANNERS))
def test_every_planner_takes_the_same_stop_and_reports_the_same_record(method: str) -> None:
    seen: list[po.Progress] = []
    res = po.plan(SCENARIO, method, stop=po.MaxIterations(5), callback=seen.append)
    assert seen and all(isinstance(p, po.Progress) for p in seen)
    assert [p.iteration for p in seen] == sorted(p.iteration for p in seen)
    assert res.planner == method and res.positions.shape == (4, 151, 2)
    assert np.all(np.isfinite(res.positions))
    if method in ("pmht", "smoothed"):  # EM iterations: exactly the five the criterion allows
        assert res.n_iterations == 5 and seen[-1].iteration == 5 and len(seen) == 5
    if method in ("smoothed", "coverage"):  # both promise every locale within its radius
        assert res.coverage() == 1.0


@pytest.mark.parametrize("method", ["ga", "pyvrp", "ortools"])
def test_every_ordering_takes_the_same_stop_and_reports_the_same_record(method: str) -> None:
    seen: list[po.Progress] = []
    tour = po.order_locales(SCENARIO, method, stop=po.MaxIterations(5), callback=seen.append)
    assert len(seen) == 5 and all(isinstance(p, po.Progress) and p.stage == "ordering" for p in seen)
    assert [p.iteration for p in seen] == [1, 2, 3, 4, 5]
    # Scores are the best tour's cost so far: never rising, the last one the tour returned.
    best = [p.scores[-1] for p in seen]
    assert all(b <= a for a, b in itertools.pairwise(best))
    assert best[-1] == pytest.approx(tour.total_distance, rel=1e-6)


def test_the_shared_settings_reach_the_planner() -> None:
    settings = po.Settings(solver="clarabel", constraints=[po.SpeedLimit(0.2)], threads=1)
    res = po.plan(SCENARIO, "pmht", settings=settings, stop=po.MaxIterations(3))
    assert res.solver == "clarabel" and [c.name for c in res.constraints] == ["SpeedLimit(0.2)"]
    assert res.max_speed <= 0.2 * (1 + 1e-6)


def test_plan_and_plan_pmht_are_the_same_run() -> None:
    """The alias and the entry point give the same plan, to the last bit."""
    a = po.plan(SCENARIO, "pmht", stop=po.MaxIterations(8))
    b = po.plan_pmht(SCENARIO, po.PMHTConfig(max_iter=8))
    np.testing.assert_array_equal(a.states, b.states)
    assert a.anneal == b.anneal and "compressed from 30 to 2 iterations" in a.anneal


def test_an_option_a_planner_would_ignore_is_refused_naming_it() -> None:
    with pytest.raises(po.ConfigError, match=r"^visit_radius: not an option of the 'pmht' planner"):
        po.plan(SCENARIO, "pmht", visit_radius=0.3)
    with pytest.raises(po.ConfigError, match=r"^anneal: not an option of the 'coverage' planner"):
        po.plan(SCENARIO, "coverage", anneal=None)
    with pytest.raises(po.ConfigError, match=r"^threads: a setting every planner shares"):
        po.plan(SCENARIO, "smoothed", threads=1)
