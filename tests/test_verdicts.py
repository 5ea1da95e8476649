"""Honest verdicts: "cannot be met" (InfeasibleError) only with a proof.

A planner whose own schedule fails (the visit steps it chose, an obstacle's side) while the constraints
can be met starts again from plans that meet them; if that fails too it says the schedule failed
(ScheduleError), never that the constraints cannot be met. Plans are measured here on their positions
with the studies' own geometry, independent of the planners' verification.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import VIOLATION_TOL, examples
from hypothesis import given, settings
from hypothesis import strategies as st

import pmht_opt as po
from pmht_opt.geometry import COVERAGE_RTOL
from pmht_opt.planners.windows import window_priors, witness_visits
from studies.constraint_measures import measure


def _worst(sc: po.Scenario, res: po.PlanResult, constraints: list) -> float:
    return max(measure(sc, res.positions, constraints).values())


def test_a_visit_pinned_at_the_return_home_is_a_schedule_not_a_proof() -> None:
    # EM's most likely step for a visit is t = T, where the return to base fixes the position: the
    # first schedule fails, and the coverage planner's plan shows the constraints can be met.
    sc = po.Scenario(
        locales=[[0.719, 1.547], [1.692, 4.42], [3.285, 0.61], [1.968, 0.514], [3.529, 4.275], [0.467, 2.499],
                 [1.223, 1.425], [3.734, 4.885]],
        starts=[[1.395, 2.713], [1.552, 0.311]],
        horizon=50,
        bounds=(0, 5, 0, 5),
    )  # fmt: skip
    shared = [po.Terminal.return_to_base(), po.AreaBounds(0, 5, 0, 5)]
    witness = po.plan_coverage(sc, 0.3, po.PMHTConfig(constraints=shared))
    assert _worst(sc, witness, [*shared, po.VisitAll(0.3)]) <= VIOLATION_TOL["clarabel"]
    constraints = [*shared, po.VisitAll(0.3)]
    res = po.plan_pmht(sc, po.PMHTConfig(constraints=constraints))
    assert _worst(sc, res, constraints) <= VIOLATION_TOL["clarabel"]
    assert res.coverage(0.3) == 1.0


def test_a_schedule_that_keeps_failing_says_so_and_what_was_tried() -> None:
    # 3.87 units of disc tour against 4 units of travel at the speed limit: the constraints may be met
    # (no proof either way), but no schedule the planners find is.
    rng = np.random.default_rng(7)
    sc = po.Scenario(locales=rng.uniform(0, 2, (4, 2)), starts=[[0.0, 0.0]], horizon=40, bounds=(0, 2, 0, 2))
    with pytest.raises(po.ScheduleError) as err:
        po.plan_pmht(sc, po.PMHTConfig(constraints=[po.SpeedLimit(0.1), po.VisitAll(0.1)], max_iter=40))
    msg = str(err.value)
    assert not isinstance(err.value, po.InfeasibleError)
    assert "not shown to be infeasible" in msg and "started again" in msg
    assert "coverage planner" in msg and "smoothed planner" in msg


def test_a_proof_stays_a_proof() -> None:
    # Four locales 5 units of travel apart, 4 units at the speed limit: proven before any solve.
    rng = np.random.default_rng(28)
    sc = po.Scenario(locales=rng.uniform(0, 2, (4, 2)), starts=[[0.0, 0.0]], horizon=40, bounds=(0, 2, 0, 2))
    for method in ("pmht", "smoothed"):
        with pytest.raises(po.InfeasibleError, match=r"SpeedLimit\(0\.1\)"):
            po.plan(sc, method, settings=po.Settings(constraints=[po.SpeedLimit(0.1), po.VisitAll(0.1)]))


def test_visits_kept_where_a_witness_makes_them_are_met_by_it() -> None:
    rng = np.random.default_rng(3)
    sc = po.Scenario(locales=rng.uniform(0, 5, (10, 2)), starts=[[0.0, 0.0], [5.0, 5.0]], horizon=60)
    witness = po.plan(sc, "coverage")
    platform, windows = witness_visits(sc, witness.positions, sc.radii)
    assert np.all(windows[:, 0] <= windows[:, 1]) and windows.min() >= 1 and windows.max() <= sc.horizon
    for n, (m, (lo, hi)) in enumerate(zip(platform, windows, strict=True)):
        gaps = np.hypot(*(witness.positions[m, 1:] - sc.locales[n]).T)
        if np.any(gaps <= sc.radii[n]):  # every step of the window inside the disc, the longest such run
            assert np.all(gaps[lo - 1 : hi] <= sc.radii[n])
            inside = np.concatenate([[False], gaps <= sc.radii[n], [False]])
            runs = np.diff(np.flatnonzero(np.diff(inside.astype(int))))[::2]
            assert hi - lo + 1 == runs.max()
        else:  # met on a segment, not at a step: the closest step, within the coverage tolerance
            assert lo == hi and gaps[lo - 1] == gaps.min()
            assert gaps.min() <= sc.radii[n] * (1 + COVERAGE_RTOL) + 1e-9
    time_prior, platform_prior = window_priors(sc, platform, windows)
    assert np.array_equal(time_prior.sum(axis=1), windows[:, 1] - windows[:, 0] + 1)
    assert np.array_equal(platform_prior.argmax(axis=1), platform) and np.all(platform_prior.sum(axis=1) == 1)


@settings(max_examples=examples(4))
@given(
    seed=st.integers(0, 2**16),
    n=st.integers(3, 5),
    m=st.integers(1, 2),
    home=st.booleans(),
    slack=st.floats(1.5, 3.0),
)
def test_no_planner_says_infeasible_where_a_witness_plan_exists(
    seed: int, n: int, m: int, home: bool, slack: float
) -> None:
    """For a small random scenario whose constraints a coverage plan meets (measured independently),
    every planner returns a plan that meets them too, or says its schedule failed: never infeasible."""
    rng = np.random.default_rng(seed)
    sc = po.Scenario(
        locales=rng.uniform(0, 4, (n, 2)), starts=rng.uniform(0, 4, (m, 2)), horizon=40, bounds=(0, 4, 0, 4)
    )
    radius = 0.3
    shared: list = [po.AreaBounds(-0.5, 4.5, -0.5, 4.5)]
    if home:
        shared.append(po.Terminal.return_to_base())
    free = po.plan(sc, "coverage", settings=po.Settings(constraints=shared), radius=radius)
    # A speed limit the witness flies within, by the drawn factor: tight for the planners' schedules.
    vmax = float(np.linalg.norm(np.diff(free.positions, axis=1), axis=2).max() / sc.dt)
    shared.append(po.SpeedLimit(vmax * slack))
    try:
        witness = po.plan(sc, "coverage", settings=po.Settings(constraints=shared), radius=radius)
    except po.SolverError:
        return  # no witness under the limit: nothing to hold the others to
    constraints = [*shared, po.VisitAll(radius)]
    assert _worst(sc, witness, constraints) <= VIOLATION_TOL["clarabel"]
    for method, options in (("pmht", {"stop": po.MaxIterations(30)}), ("smoothed", {"visit_radius": radius})):
        kept = constraints if method == "pmht" else shared
        try:
            res = po.plan(sc, method, settings=po.Settings(constraints=kept), **options)
        except po.InfeasibleError as err:  # pragma: no cover - the defect this test guards against
            pytest.fail(f"{method} said infeasible with a witness plan: {err}")
        except po.ScheduleError:
            continue
        assert _worst(sc, res, constraints) <= VIOLATION_TOL["clarabel"]
