"""The EM loop as an object: stepping, observers, stopping criteria, the schedule and the final E-step."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import small_scenario

import pmht_opt as po
import solvers


def test_stepping_by_hand_equals_plan_pmht() -> None:
    sc = small_scenario(seed=2)
    cfg = po.PMHTConfig(max_iter=12, anneal=po.Anneal(1.0, 5))
    planned = po.plan_pmht(sc, cfg)
    with po.EMRun(sc, cfg) as run:
        records = []
        while not run.done:
            records.append(run.step())
        stepped = run.result()
    np.testing.assert_array_equal(stepped.positions, planned.positions)
    np.testing.assert_array_equal(stepped.history.objective, planned.history.objective)
    assert [r.iteration for r in records] == list(range(1, 13))
    assert run.stop_reason == "MaxIterations" and not stepped.converged
    with pytest.raises(po.ConfigError, match="stopped"):
        run.step()


def test_callbacks_see_every_estep_mstep_and_iteration() -> None:
    sc = small_scenario(seed=3)
    seen: dict[str, list[object]] = {"e": [], "m": [], "it": []}
    callbacks = po.EMCallbacks(
        after_estep=lambda run, es: seen["e"].append(es.gated),
        after_mstep=lambda run, out: seen["m"].append(out.status),
        after_iteration=lambda run, rec: seen["it"].append((rec.iteration, rec.objective)),
    )
    with po.EMRun(sc, po.PMHTConfig(max_iter=6, anneal=None), callbacks=callbacks) as run:
        res = run.run()
    assert len(seen["e"]) == 7 and len(seen["m"]) == 6
    assert all(s is solvers.Status.OPTIMAL for s in seen["m"])
    assert [i for i, _ in seen["it"]] == list(range(1, 7))
    np.testing.assert_array_equal([o for _, o in seen["it"]], res.history.objective[1:])
    # The typed statuses reach the history too.
    assert res.history.mstep_status == (solvers.Status.OPTIMAL,) * 6
    assert res.history.estep_gated.shape == (7,)


def test_plan_callback_gets_iteration_and_objective() -> None:
    calls: list[tuple[int, float]] = []
    res = po.plan_pmht(
        small_scenario(), po.PMHTConfig(max_iter=4), callback=lambda i, o: calls.append((i, o))
    )
    assert [i for i, _ in calls] == [1, 2, 3, 4]
    assert [o for _, o in calls] == list(res.history.objective[1:])


class _StopAt:
    """A user criterion: stop after a given iteration."""

    def __init__(self, at: int) -> None:
        self.at = at

    def __call__(self, progress: po.Progress) -> bool:
        return progress.iteration >= self.at


def test_extra_stopping_criteria_end_the_run() -> None:
    sc = small_scenario(seed=4)
    with pytest.warns(po.PlanWarning, match=r"fitted at r = .* during annealing"):  # stopped at a wide r
        res = po.plan_pmht(sc, po.PMHTConfig(max_iter=50, stop=_StopAt(7)))
    assert res.n_iterations == 7 and res.history.stop_reason == "_StopAt" and not res.converged
    budget = po.plan_pmht(sc, po.PMHTConfig(max_iter=10_000, anneal=None, stop=[po.TimeBudget(0.3)]))
    assert budget.history.stop_reason == "TimeBudget" and budget.n_iterations < 10_000


def test_tolerance_is_judged_only_once_settled() -> None:
    sc = small_scenario(seed=5)
    # Annealing over 20 iterations: whatever the tolerance, the run goes past the schedule.
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=200, tol=0.5, anneal=po.Anneal(1.0, 20)))
    assert res.converged and res.history.stop_reason == "ObjectiveTolerance"
    assert res.n_iterations == 21  # the first iteration after the schedule's last change
    # A warming-up constraint postpones it too.
    warm = po.PMHTConfig(max_iter=200, tol=0.5, anneal=None, constraints=[po.VisitAll(0.5, warmup=6)])
    assert po.plan_pmht(sc, warm).n_iterations >= 11  # imposed from 7, whole from 10, compared from 11


@pytest.mark.parametrize(
    ("criterion", "progress", "stop"),
    [
        (po.MaxIterations(3), po.Progress(3, [0.0]), True),
        (po.MaxIterations(3), po.Progress(2, [0.0]), False),
        (po.ObjectiveTolerance(1e-3), po.Progress(2, [-100.0, -100.05]), True),
        (po.ObjectiveTolerance(1e-3), po.Progress(2, [-100.0, -100.05], settled=False), False),
        (po.ObjectiveTolerance(0.0), po.Progress(2, [-1.0, -1.0]), False),
        (po.NoImprovement(2), po.Progress(4, [5.0, 3.0, 3.0, 3.5]), True),
        (po.NoImprovement(2), po.Progress(4, [5.0, 3.0, 3.0, 2.0]), False),
        (po.TimeBudget(1.0), po.Progress(1, [0.0], elapsed=1.5), True),
        (po.AnyOf((po.MaxIterations(9), po.TimeBudget(1.0))), po.Progress(1, [0.0], elapsed=2.0), True),
    ],
)
def test_stopping_criteria(criterion: po.StoppingCriterion, progress: po.Progress, stop: bool) -> None:
    assert criterion(progress) is stop
    assert isinstance(criterion, po.StoppingCriterion)


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: po.MaxIterations(0), "MaxIterations.limit"),
        (lambda: po.MaxIterations(True), "MaxIterations.limit"),
        (lambda: po.ObjectiveTolerance(-1.0), "ObjectiveTolerance.rtol"),
        (lambda: po.TimeBudget(0), "TimeBudget.seconds"),
        (lambda: po.TimeBudget(float("nan")), "TimeBudget.seconds"),
        (lambda: po.NoImprovement(-2), "NoImprovement.iterations"),
        (lambda: po.AnyOf((3,)), "AnyOf"),
        (lambda: po.PMHTConfig(stop=[1]), "stop"),
        (lambda: po.PMHTConfig(stop=5), "stop"),
    ],
)
def test_bad_stopping_criteria_name_the_field(make: object, field: str) -> None:
    with pytest.raises(po.ConfigError, match=field):
        make()  # type: ignore[operator]


def test_schedule_answers_r_settled_and_constraints() -> None:
    sched = po.Schedule.of(po.Anneal(1.0, 10), 0.01, 30)
    assert sched.max_iter == 30 and sched.settled == 10
    assert sched.r_at(1) == 1.0 and sched.r_at(10) == 0.01 and sched.r_at(30) == 0.01
    always = po.SpeedLimit(1.0)
    visits = po.VisitAll(0.1, warmup=5)
    assert sched.imposes(always, 1)
    assert not sched.imposes(visits, 14) and sched.imposes(visits, 15)
    assert sched.active([always, visits], 3) == (0,)
    # Brought in over its ramp of 4 iterations, at full strength from iteration 18.
    assert [sched.strength(visits, i) for i in (15, 16, 17, 18, 30)] == [0.25, 0.5, 0.75, 1.0, 1.0]
    assert sched.strength(always, 1) == 1.0 and sched.strengths([always, visits], 16) == (1.0, 0.5)
    assert not sched.settled_at([], 10) and sched.settled_at([], 11)
    assert not sched.settled_at([visits], 18) and sched.settled_at([visits], 19)
    # A warm-up longer than the run: started early enough to end at full strength.
    late = po.VisitAll(0.1, warmup=100)
    assert not sched.imposes(late, 26) and sched.imposes(late, 27) and sched.strength(late, 30) == 1.0
    whole = po.VisitAll(0.1, warmup=100, ramp=0)
    assert not sched.imposes(whole, 29) and sched.strength(whole, 30) == 1.0
    plain = po.Schedule.of(po.Anneal(iterations=0), 0.01, 5)
    assert plain.settled == 1 and np.all(plain.r == 0.01)


def test_final_estep_is_kept_compactly() -> None:
    sc = small_scenario(n_locales=8, n_platforms=2, horizon=50, seed=6)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=15))
    es = res.estep
    assert es is not None
    assert es.weights.shape == (8, 50 * 2) and es.n_times == 50
    np.testing.assert_allclose(es.platform_probability.sum(axis=1), 1.0)
    assert np.all(es.weights.data >= es.floor)
    # The MAP of the kept weights is the plan's assignment and visit time.
    for n in range(8):
        w = es.locale_weights(n)
        t, m = np.unravel_index(np.argmax(w), w.shape)
        assert (m, t + 1) == (res.assignment[n], res.visit_time[n])
        np.testing.assert_allclose(es.visit_time_distribution(n).sum(), 1.0, atol=1e-9)


def test_without_constraints_the_used_estep_is_released_before_the_next(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A run without constraints holds one E-step's weights at a time: whenever an E-step is formed,
    every earlier one is gone (nothing of the run refers to it), annealing's objective-only E-steps
    included; the run's own ``estep`` is the current one between iterations."""
    import gc
    import weakref

    from pmht_opt import em

    formed: list[weakref.ref[object]] = []
    alive_at_each_call: list[int] = []
    real, real_scored = em.estep, em.estep_scored

    def counted(es: object) -> None:
        formed.append(weakref.ref(es))

    def alive() -> None:
        gc.collect()
        alive_at_each_call.append(sum(ref() is not None for ref in formed))

    def counting(*args: object, **kwargs: object) -> object:
        alive()
        es = real(*args, **kwargs)  # type: ignore[arg-type]
        counted(es)
        return es

    def counting_scored(*args: object, **kwargs: object) -> object:  # annealing's E-steps
        alive()
        es, score = real_scored(*args, **kwargs)  # type: ignore[arg-type]
        counted(es)
        return es, score

    monkeypatch.setattr(em, "estep", counting)
    monkeypatch.setattr(em, "estep_scored", counting_scored)
    sc = small_scenario(seed=4)
    with po.EMRun(sc, po.PMHTConfig(max_iter=5, anneal=po.Anneal(1.0, 3))) as run:
        for _ in range(5):
            run.step()
            assert formed[-1]() is run.estep
            assert run.last_context is not None and run.last_context.estep is None
        assert np.all(np.isfinite(run.result().positions))
    assert len(alive_at_each_call) == 6 and alive_at_each_call == [0] * 6


def test_with_constraints_the_last_context_keeps_its_estep() -> None:
    sc = small_scenario(seed=4)
    cfg = po.PMHTConfig(max_iter=3, anneal=None, solver="clarabel", constraints=[po.AreaBounds(0, 4, 0, 4)])
    with po.EMRun(sc, cfg) as run:
        used = run.estep
        run.step()
        assert run.last_context is not None and run.last_context.estep is used


class _InterruptOnce:
    """``em.estep`` that raises ``KeyboardInterrupt`` on its ``n``-th call, as Ctrl-C would."""

    def __init__(self, n: int) -> None:
        from pmht_opt import em

        self.real, self.calls, self.n = em.estep, 0, n

    def __call__(self, *args: object, **kwargs: object) -> object:
        self.calls += 1
        if self.calls == self.n:
            raise KeyboardInterrupt
        return self.real(*args, **kwargs)  # type: ignore[arg-type]


def test_an_interrupted_iteration_leaves_the_last_finished_one(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C in an E-step (after the used one was released) leaves the run as the last finished
    iteration left it: its plan is that of a run stopped there, and stepping on gives the plan of a
    run never interrupted, to the last digit."""
    from pmht_opt import em

    sc = small_scenario(seed=4)
    cfg = po.PMHTConfig(max_iter=5, anneal=None)
    whole = po.plan_pmht(sc, cfg)
    two = po.plan_pmht(sc, po.PMHTConfig(max_iter=2, anneal=None))
    with po.EMRun(sc, cfg) as run:
        run.step()
        run.step()
        monkeypatch.setattr(em, "estep", _InterruptOnce(1))
        with pytest.raises(KeyboardInterrupt):
            run.step()
        assert run.iteration == 2
        stopped = run.result()
        np.testing.assert_array_equal(stopped.positions, two.positions)
        np.testing.assert_array_equal(stopped.estep.log_normaliser, two.estep.log_normaliser)
        np.testing.assert_array_equal(stopped.history.objective, two.history.objective)
        while not run.done:
            run.step()
        np.testing.assert_array_equal(run.result().positions, whole.positions)
        np.testing.assert_array_equal(run.result().history.objective, whole.history.objective)


def test_a_constrained_run_interrupted_after_its_mstep_gives_no_stale_plan(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With constraints the interrupted iteration's context has replaced the finished one's, so the
    run refuses a plan (by name) until an iteration finishes; it never returns paths with the
    reports of another iteration."""
    from pmht_opt import em

    sc = small_scenario(seed=4)
    cfg = po.PMHTConfig(max_iter=4, anneal=None, solver="clarabel", constraints=[po.AreaBounds(0, 4, 0, 4)])
    with po.EMRun(sc, cfg) as run:
        run.step()
        monkeypatch.setattr(em, "estep", _InterruptOnce(1))
        with pytest.raises(KeyboardInterrupt):
            run.step()
        with pytest.raises(po.ConfigError, match="iteration 2 stopped after its M-step"):
            run.result()
        run.step()
        assert run.iteration == 2
        res = run.result()
        assert all(rep.satisfied for rep in res.reports)
