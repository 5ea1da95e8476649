"""Annealed EM: the schedule, the objective history and the failure modes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt import Anneal, ConfigError, PMHTConfig, plan_pmht


@pytest.fixture(scope="module")
def small_b() -> po.Scenario:
    return po.paper_scenario("B", seed=3, horizon=150)


def test_geometric_schedule_starts_at_start_and_ends_exactly_at_r() -> None:
    vals = Anneal(start=1.0, iterations=30).values(0.01, 100)
    assert vals.shape == (100,)
    assert vals[0] == 1.0
    assert vals[29] == 0.01  # exactly, not to rounding
    assert np.all(vals[29:] == 0.01)
    ratios = vals[1:30] / vals[:29]
    assert np.allclose(ratios, 0.01 ** (1 / 29), rtol=1e-12)
    assert po.Schedule.of(Anneal(1.0, 30), 0.01, 100).settled == 30


def test_linear_and_custom_schedules() -> None:
    lin = Anneal(start=0.5, iterations=5, shape="linear").values(0.1, 8)
    assert np.allclose(lin, [0.5, 0.4, 0.3, 0.2, 0.1, 0.1, 0.1, 0.1])
    assert lin[4] == 0.1
    # A bare callable covers every iteration and must reach r; the schedule ends where it does.
    cfg = PMHTConfig(anneal=lambda i: max(0.01, 0.8**i))
    vals = cfg.anneal.values(0.01, 100)
    assert vals[0] == 0.8 and vals[-1] == 0.01
    assert po.Schedule.of(cfg.anneal, 0.01, 100).settled == math.ceil(
        math.log(0.01) / math.log(0.8)
    )  # first 0.8**i <= r
    # With a length, the callable's last value is replaced by r.
    custom = Anneal.custom(lambda i: 2.0 / i, iterations=4).values(0.25, 6)
    assert np.allclose(custom, [2.0, 1.0, 2.0 / 3.0, 0.25, 0.25, 0.25])


def test_schedule_longer_than_the_run_is_cut() -> None:
    vals = Anneal(1.0, 30).values(0.01, 10)
    assert vals.shape == (10,) and vals[-1] > 0.01
    assert po.Schedule.of(Anneal(1.0, 30), 0.01, 10).settled == 11  # never settles within the run


@pytest.mark.parametrize(
    ("anneal", "match"),
    [
        (Anneal.custom(lambda i: -1.0, 3), "r at iteration 1"),
        (Anneal.custom(lambda i: float("nan"), 3), "r at iteration 1"),
        (Anneal.custom(lambda i: 1.0 if i < 3 else float("inf"), 3), "r at iteration 3"),
        (Anneal.custom(lambda i: 1 / 0, 3), "raised at iteration 1"),
        (lambda i: 0.5, "must reach the scenario's r"),
        (Anneal.custom(lambda i: 1.0, 5), "custom schedule takes 5 iterations but the run may take only 3"),
    ],
)
def test_bad_schedule_values_raise_config_error(anneal: object, match: str, small_b: po.Scenario) -> None:
    with pytest.raises(ConfigError, match=match):
        plan_pmht(small_b, PMHTConfig(max_iter=3, anneal=anneal))


@pytest.mark.parametrize("stop", [{"max_iter": 10}, {"stop": [po.MaxIterations(10)]}])
def test_a_run_shorter_than_its_schedule_compresses_it_and_says_so(
    small_b: po.Scenario, stop: dict[str, object]
) -> None:
    """Stopping after 10 iterations under the default 30-iteration schedule: the schedule takes the
    same share of the run (3 iterations), the plan is fitted at the scenario's r, and the history
    says the schedule was compressed."""
    res = plan_pmht(small_b, PMHTConfig(**stop))  # type: ignore[arg-type]
    h = res.history
    assert h.n_iterations == 10 and h.fitted_r == small_b.r
    assert h.settled == 3 and np.all(h.r[3:] == small_b.r) and h.r[1] > small_b.r
    assert "compressed from 30 to 3 iterations to fit a run of 10" in h.anneal
    assert res.anneal == h.anneal


def test_a_plan_stopped_during_annealing_reports_its_r(small_b: po.Scenario) -> None:
    """A criterion other than the iteration limit that stops the run while annealing: the plan comes
    with a PlanWarning and its history says at which r it was fitted."""
    with pytest.warns(po.PlanWarning, match=r"fitted at r = .*not the scenario's r = 0.01"):
        res = po.plan(small_b, "pmht", stop=po.AnyOf((po.MaxIterations(100), _StopAt(4))))
    assert res.history.fitted_r > small_b.r and res.history.stop_reason == "_StopAt"


class _StopAt:
    """Stops after a given iteration (a criterion the schedule cannot plan for)."""

    def __init__(self, iteration: int) -> None:
        self.iteration = iteration

    def __call__(self, progress: po.Progress) -> bool:
        return progress.iteration >= self.iteration


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start": 0.0}, "anneal.start"),
        ({"start": -1.0}, "anneal.start"),
        ({"start": float("inf")}, "anneal.start"),
        ({"start": "wide"}, "anneal.start"),
        ({"iterations": -2}, "anneal.iterations"),
        ({"iterations": 2.5}, "anneal.iterations"),
        ({"shape": "cosine"}, "anneal.shape"),
    ],
)
def test_bad_schedule_parameters_raise_config_error(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        Anneal(**kwargs)  # type: ignore[arg-type]


def test_bad_anneal_setting_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="anneal"):
        PMHTConfig(anneal="fast")
    with pytest.raises(ConfigError, match="anneal"):
        PMHTConfig(anneal={"begin": 1.0})
    assert PMHTConfig(anneal=(0.5, 10)).anneal == Anneal(0.5, 10)


def test_presets() -> None:
    assert PMHTConfig().anneal == Anneal(iterations=30)
    assert Anneal().start_for(0.01) == 1.0 and Anneal().start_for(400.0) == 40000.0
    paper = PMHTConfig.paper()
    assert paper.anneal.empty and paper.update_time_prior and paper.update_platform_prior


@pytest.mark.parametrize("solver", ["clarabel", "kalman"])
def test_objective_never_decreases_after_the_schedule(small_b: po.Scenario, solver: str) -> None:
    res = plan_pmht(small_b, PMHTConfig(solver=solver, max_iter=40, anneal=Anneal(1.0, 15)))
    h = res.history
    assert h.r.shape == h.objective.shape
    assert h.r[0] == 1.0 and h.r[15] == small_b.r and np.all(h.r[15:] == small_b.r)
    assert h.settled == 15
    steps = np.diff(h.objective[15:])
    assert np.all(steps >= -1e-9 * np.abs(h.objective[15:-1]))


def test_history_objective_uses_the_iterations_r(small_b: po.Scenario) -> None:
    """objective[i] = log P(X_i) + data term at r_i, with the priors of that iteration."""
    cfg = PMHTConfig(max_iter=20, anneal=Anneal(1.0, 15), update_platform_prior=False, stop=[_StopAt(6)])
    with pytest.warns(po.PlanWarning):  # stopped during annealing, on purpose
        res = plan_pmht(small_b, cfg)
    h = res.history
    expected = (
        small_b.model.log_prior(res.states)
        + po.estep.estep(
            small_b.locales, res.states[:, 1:, :][..., [0, 3]], None, None, h.r[6]
        ).log_likelihood
    )
    # The planner takes log P(X) from the M-step's own process noise; differencing the states agrees
    # to the dynamics' residual.
    assert h.objective[6] == pytest.approx(expected, rel=1e-10)
    assert h.r[6] == pytest.approx(1.0 * 0.01 ** (5 / 14), rel=1e-12)


@pytest.mark.parametrize("solver", ["clarabel", "osqp", "kalman", "cvxpy"])
def test_empty_schedule_is_plain_em(small_b: po.Scenario, solver: str) -> None:
    plain = plan_pmht(small_b, PMHTConfig(solver=solver, max_iter=8, anneal=None))
    empty = plan_pmht(small_b, PMHTConfig(solver=solver, max_iter=8, anneal=Anneal(5.0, 0)))
    one = plan_pmht(small_b, PMHTConfig(solver=solver, max_iter=8, anneal=Anneal(5.0, 1)))
    assert np.array_equal(plain.states, empty.states)
    assert np.array_equal(plain.history.objective, empty.history.objective)
    assert np.array_equal(plain.states, one.states)  # a one-step schedule is already at r
    assert plain.history.settled == 0 and np.all(plain.history.r == small_b.r)


@pytest.mark.parametrize("solver", ["clarabel", "osqp", "kalman", "cvxpy"])
def test_annealing_works_with_every_backend(small_b: po.Scenario, solver: str) -> None:
    ref = plan_pmht(small_b, PMHTConfig(solver="kalman", max_iter=6, anneal=Anneal(1.0, 4)))
    got = plan_pmht(small_b, PMHTConfig(solver=solver, max_iter=6, anneal=Anneal(1.0, 4)))
    assert np.max(np.abs(got.positions - ref.positions)) < 1e-4
    assert got.anneal == "geometric from r=1 over 4 iterations"
    assert got.metrics()["anneal"] == got.anneal


def test_annealing_differs_from_plain_and_runs_with_constraints(small_b: po.Scenario) -> None:
    area = po.AreaBounds(-1.5, 10.5, -0.5, 10.5)
    plain = plan_pmht(small_b, PMHTConfig(max_iter=20, anneal=None, constraints=[area]))
    ann = plan_pmht(small_b, PMHTConfig(max_iter=20, anneal=Anneal(1.0, 10), constraints=[area]))
    assert not np.allclose(plain.positions, ann.positions)
    assert ann.max_violation <= 1e-6


def test_cli_anneal_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pmht_opt.cli import main

    out = tmp_path / "demo.png"
    demo = ["demo", "--planner", "pmht", "--iterations", "2", "--quiet"]
    assert main([*demo, "--anneal", "0.5", "2", "--out", str(out)]) == 0
    assert "geometric from r=0.5 over 2 iterations" in capsys.readouterr().out
    assert out.stat().st_size > 0
    assert main([*demo, "--no-anneal", "--out", str(out)]) == 0
    assert "annealing" in capsys.readouterr().out
    assert main([*demo, "--anneal", "x", "2"]) == 2
    assert "--anneal" in capsys.readouterr().err
