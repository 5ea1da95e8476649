"""Single M-steps: every backend against the RTS reference on random weights."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ALL_BACKENDS, POSITION_TOL, QP_BACKENDS

import pmht_opt as po
from pmht_opt.constraints import ConstraintContext
from pmht_opt.mstep import MStepData, make_mstep, mstep_objective
from pmht_opt.mstep.tuning import RETRIES
from solvers import RetryChain


def random_weights(scenario: po.Scenario, rng: np.random.Generator, zero_fraction: float) -> MStepData:
    T, M = scenario.horizon, scenario.n_platforms
    W = rng.uniform(0.0, 2.0, (T, M))
    W[rng.uniform(size=(T, M)) < zero_fraction] = 0.0
    targets = rng.uniform(0.0, 10.0, (T, M, 2))
    return MStepData(W=W, WZ=W[..., None] * targets, r=scenario.r)


@pytest.mark.parametrize("backend", QP_BACKENDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_random_mstep_agrees_with_rts(scenario_a: po.Scenario, backend: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    data = random_weights(scenario_a, rng, zero_fraction=0.4)
    ref = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, solver="kalman")
    got = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, solver=backend)
    np.testing.assert_array_equal(got[:, 0], scenario_a.initial_states)
    assert np.max(np.abs(got[:, :, [0, 3]] - ref[:, :, [0, 3]])) < POSITION_TOL
    obj_ref = mstep_objective(scenario_a.model, ref, data.W, data.WZ, data.r)
    assert mstep_objective(scenario_a.model, got, data.W, data.WZ, data.r) == pytest.approx(obj_ref, rel=1e-9)


@pytest.mark.parametrize("backend", ALL_BACKENDS)
def test_repeated_updates_agree_with_rts(backend: str, rng: np.random.Generator) -> None:
    """The QP is built once; later solves with new weights must stay exact (in-place updates)."""
    sc = po.paper_scenario("C", seed=4, horizon=150)
    mstep = make_mstep(sc, backend)
    kalman = make_mstep(sc, "kalman")
    for zero_fraction in (0.0, 0.5, 0.9):
        data = random_weights(sc, rng, zero_fraction)
        diff = np.abs(mstep.solve(data).states - kalman.solve(data).states)[:, :, [0, 3]]
        assert diff.max() < POSITION_TOL
    mstep.close()


def test_all_zero_weights_keep_platforms_still(scenario_a: po.Scenario) -> None:
    data = MStepData(W=np.zeros((500, 4)), WZ=np.zeros((500, 4, 2)), r=0.01)
    for backend in ("kalman", "clarabel", "osqp"):
        states = make_mstep(scenario_a, backend).solve(data).states
        np.testing.assert_allclose(states, np.repeat(scenario_a.initial_states[:, None], 501, 1), atol=1e-7)


def test_single_weighted_target_is_reached_closely() -> None:
    """A heavy weight at one time pulls the path there: the answer is the target up to the prior's pull."""
    sc = po.Scenario(locales=[[5.0, 5.0]], starts=[[0.0, 0.0]], horizon=200)
    W = np.zeros((200, 1))
    W[149, 0] = 1.0
    WZ = np.zeros((200, 1, 2))
    WZ[149, 0] = [5.0, 5.0]
    states = make_mstep(sc, "clarabel").solve(MStepData(W, WZ, sc.r)).states
    assert np.hypot(*(states[0, 150, [0, 3]] - 5.0)) < 0.05


def test_unknown_backend_lists_available(scenario_a: po.Scenario) -> None:
    with pytest.raises(po.UnknownSolverError, match=r"available: .*kalman"):
        make_mstep(scenario_a, "gurobi")


def test_bad_backend_setting_is_a_config_error(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(0), 0.3)
    with pytest.raises(po.ConfigError, match="solver_settings"):
        make_mstep(scenario_a, "osqp", {"no_such_option": 3}).solve(data)
    with pytest.raises(po.ConfigError, match="solver_settings"):
        make_mstep(scenario_a, "kalman", {"eps": 1})


def test_failed_solve_raises_solver_error_with_status(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(0), 0.3)
    mstep = make_mstep(scenario_a, "osqp", {"max_iter": 5})
    with pytest.raises(po.SolverError, match="maximum iterations") as info:
        mstep.solve(data)
    assert info.value.backend == "osqp"
    assert "maximum iterations" in info.value.status


def test_a_failed_platform_fails_the_mstep_before_the_next_is_solved(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(0), 0.3)
    mstep = make_mstep(scenario_a, "osqp", {"max_iter": 5})
    with pytest.raises(po.SolverError, match=r"\(platform 0\)"):
        mstep.solve(data)
    assert [len(block._qps) for block in mstep.blocks] == [1, 0, 0, 0]


def test_osqp_constrained_solves_stop_at_their_work_limit(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(5), 0.5)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r)
    vmax = 0.5 * float(np.max(np.hypot(free[:, 1:, 1], free[:, 1:, 4])))
    limit = [po.SpeedLimit(vmax)]
    # The default constrained settings solve it; a work limit of a few iterations cannot, and the
    # failure says that the constraints can be met (the probe) and names the limit it hit.
    capped = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "osqp", limit)
    assert np.max(np.hypot(capped[:, 1:, 1], capped[:, 1:, 4])) <= vmax * (1 + 1e-3)
    mstep = make_mstep(scenario_a, "osqp", {"work_limit": 1e6}, constraints=tuple(limit))
    still = np.repeat(scenario_a.initial_states[:, None, :], scenario_a.horizon + 1, axis=1)
    data = MStepData(data.W, data.WZ, data.r, ConstraintContext(scenario=scenario_a, states=still), (0,))
    with pytest.raises(po.SolverError, match=r"maximum iterations.*can all be met"):
        mstep.solve(data)
    # The first platform that fails ends the M-step.
    assert sum(len(block._qps) for block in mstep.blocks) == 1


def test_a_constrained_osqp_mstep_stops_within_its_work_budget(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(5), 0.5)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r)
    vmax = 0.5 * float(np.max(np.hypot(free[:, 1:, 1], free[:, 1:, 4])))
    limit = [po.SpeedLimit(vmax)]
    # Without a budget it solves; a budget of a few iterations fails the M-step and names the platform
    # (the whole QP's solves: without condensing or a working set first).
    whole = {"condense": False, "working_set": False}
    solved = po.solve_mstep(
        scenario_a, data.W, data.WZ, data.r, "osqp", limit, settings={**whole, "mstep_work_limit": None}
    )
    assert np.max(np.hypot(solved[:, 1:, 1], solved[:, 1:, 4])) <= vmax * (1 + 1e-3)
    with pytest.raises(po.SolverError, match=r"\(platform \d\).*can all be met.*'mstep_work_limit': None"):
        po.solve_mstep(
            scenario_a, data.W, data.WZ, data.r, "osqp", limit, settings={**whole, "mstep_work_limit": 1e6}
        )
    # With the default budget, condensing and the working set first: an optimum at least as good (the
    # whole QP's ADMM stops 1e-5 from its optimum; positions along a binding limit are that flat).
    default = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "osqp", limit)
    costs = [mstep_objective(scenario_a.model, s, data.W, data.WZ, data.r) for s in (default, solved)]
    assert costs[0] <= costs[1] + 1e-6 * abs(costs[1])
    with pytest.raises(po.ConfigError, match="mstep_work_limit"):
        po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "osqp", limit, settings={"mstep_work_limit": -1})


def test_inaccurate_solutions_are_refused_unless_accepted(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(0), 0.3)
    settings = {"max_iter": 4, "tol_gap_abs": 1e-14, "tol_gap_rel": 1e-14, "tol_feas": 1e-14}
    strict = make_mstep(scenario_a, "clarabel", settings)
    try:
        strict.solve(data)
    except po.SolverError as err:
        assert err.status in {"MaxIterations", "AlmostSolved"}
    lenient = make_mstep(scenario_a, "osqp", {"max_iter": 50, "eps_abs": 1e-3, "eps_rel": 1e-3})
    # Loose tolerances are a caller's choice: OSQP stands behind them, so the solve is accepted.
    assert lenient.solve(data).states.shape == (4, 501, 6)


def test_fallback_settings_give_way_to_the_callers(scenario_a: po.Scenario) -> None:
    assert make_mstep(scenario_a, "osqp").blocks[0].retries == RETRIES["osqp"]
    # A caller who picks the polishing's refinement has chosen what the fallback would change: none
    # is tried.
    assert make_mstep(scenario_a, "osqp", {"polish_refine_iter": 5}).blocks[0].retries.sets == ()
    only = make_mstep(scenario_a, "clarabel", {"max_iter": 50}).blocks[0].retries
    assert only == RETRIES["clarabel"]


@pytest.mark.parametrize(
    ("backend", "fast", "chain"),
    [
        ("osqp", {"max_iter": 5}, ({"max_iter": 6}, {"max_iter": 50_000})),
        ("clarabel", {"max_iter": 0}, ({"max_iter": 0, "equilibrate_enable": True}, {"max_iter": 200})),
    ],
)
def test_failed_solves_go_through_the_fallback_chain_in_order(
    scenario_a: po.Scenario, backend: str, fast: dict, chain: tuple
) -> None:
    data = random_weights(scenario_a, np.random.default_rng(0), 0.3)
    mstep = make_mstep(scenario_a, backend, fast)
    for block in mstep.blocks:
        block.retries = RetryChain(chain)  # the first set still fails, the second solves
    out = mstep.solve(data)
    active = int(np.sum(np.any(data.W > 0, axis=0)))
    assert out.fallbacks == active >= 1
    ref = make_mstep(scenario_a, "kalman").solve(data)
    assert np.max(np.abs(out.states - ref.states)) <= POSITION_TOL
    # The set that solved is kept for the platform's later solves: the next needs no fallback.
    assert mstep.blocks[0].settings["max_iter"] == chain[1]["max_iter"]
    again = mstep.solve(data)
    assert again.fallbacks == 0
    assert np.max(np.abs(again.states - ref.states)) <= POSITION_TOL
    # No set solves: the first failure is what the caller sees.
    failing = make_mstep(scenario_a, backend, fast)
    for block in failing.blocks:
        block.retries = RetryChain(chain[:1])
    with pytest.raises(po.SolverError, match="M-step solve failed"):
        failing.solve(data)


def test_a_plan_records_fallback_solves(scenario_a: po.Scenario) -> None:
    res = po.plan_pmht(scenario_a, po.PMHTConfig(solver="osqp", max_iter=2, anneal=None))
    assert res.history.fallbacks.shape == (2,) and res.history.fallbacks.dtype.kind == "i"
    assert res.metrics()["solver_fallbacks"] == int(res.history.fallbacks.sum())


def test_annealing_sets_up_a_session_afresh_only_where_it_does_not_adapt_to_updates(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Annealing moves r a hundredfold: OSQP with its adaptive rho keeps each platform's first session
    (and its warm start); with a fixed rho the session is set up afresh as r moves, and the plan is the
    same up to the solver's tolerance."""
    import osqp

    setups = [0]
    real_setup = osqp.OSQP.setup

    def counted_setup(self: osqp.OSQP, *args: object, **kwargs: object) -> object:
        setups[0] += 1
        return real_setup(self, *args, **kwargs)

    monkeypatch.setattr(osqp.OSQP, "setup", counted_setup)
    sc = po.paper_scenario("A", seed=0, horizon=60)
    plans, counts = [], []
    for settings in ({}, {"adaptive_rho": False}):
        setups[0] = 0
        cfg = po.PMHTConfig(solver="osqp", max_iter=25, anneal=po.Anneal(1.0, 15), solver_settings=settings)
        plans.append(po.plan_pmht(sc, cfg).positions)
        counts.append(setups[0])
    assert counts[0] == sc.n_platforms
    assert counts[1] > 2 * sc.n_platforms
    np.testing.assert_allclose(plans[0], plans[1], atol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"W": np.zeros((3, 4))}, "W: expected shape"),
        ({"W": -np.ones((500, 4))}, "W: expected non-negative"),
        ({"WZ": np.full((500, 4, 2), np.nan)}, "WZ: contains NaN"),
        ({"r": 0.0}, "r: expected a number in"),
        ({"r": "x"}, "r: expected a number in"),
        ({"solver": "gurobi"}, "solver: unknown solver 'gurobi'"),
        ({"constraints": ["speed"]}, "constraints: expected"),
        ({"constraints": [po.VisitAll(0.1)]}, "E-step"),
        ({"solver": "kalman", "constraints": [po.SpeedLimit(0.1)]}, "kalman backend"),
    ],
)
def test_solve_mstep_checks_its_input(scenario_a: po.Scenario, kwargs: dict, field: str) -> None:
    args = {"W": np.ones((500, 4)), "WZ": np.ones((500, 4, 2)), "r": 0.01, **kwargs}
    with pytest.raises(po.ConfigError, match=field):
        po.solve_mstep(scenario_a, **args)


def test_solve_mstep_with_constraints_meets_them(scenario_a: po.Scenario) -> None:
    data = random_weights(scenario_a, np.random.default_rng(5), 0.5)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r)
    vmax = 0.5 * float(np.max(np.hypot(free[:, 1:, 1], free[:, 1:, 4])))
    for solver in ("clarabel", "cvxpy"):
        capped = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, solver, [po.SpeedLimit(vmax)])
        assert np.max(np.hypot(capped[:, 1:, 1], capped[:, 1:, 4])) <= vmax + 1e-6


def test_backends_declare_capabilities_and_constraints_their_needs() -> None:
    from pmht_opt.mstep import BACKENDS

    assert BACKENDS["clarabel"].supports == {"linear", "soc"}
    assert BACKENDS["osqp"].supports == {"linear"}  # cones reach it as inner polygons
    assert BACKENDS["cvxpy"].supports == {"linear", "soc", "cvxpy"}
    assert BACKENDS["kalman"].supports == frozenset()
    assert BACKENDS["osqp"].can_impose(po.SpeedLimit(1.0).needs)
    assert not BACKENDS["osqp"].can_impose(po.CvxpyConstraint(lambda v: []).needs)
    assert po.Terminal(velocity=(0, 0)).needs == {"linear"}
    assert po.Terminal(position=(1, 1), radius=0.5).needs == {"linear", "soc"}
    with pytest.raises(po.ConfigError, match="use one of cvxpy"):
        po.PMHTConfig(solver="clarabel", constraints=[po.CvxpyConstraint(lambda v: [])])


def test_static_rows_are_written_once_and_dynamic_ones_every_iteration(scenario_a: po.Scenario) -> None:
    from pmht_opt.constraints import ConstraintContext
    from pmht_opt.mstep.rows import RowBuilder

    states = np.repeat(scenario_a.initial_states[:, None, :], 501, axis=1)
    cons = (po.SpeedLimit(0.1), po.CircleObstacle((50.0, 50.0), 1.0))
    builder = RowBuilder(cons, conic=True)
    first = builder.rows(ConstraintContext(scenario_a, states, iteration=1), (0, 1))
    again = builder.rows(ConstraintContext(scenario_a, states, iteration=2), (0, 1))
    only_static = builder.rows(ConstraintContext(scenario_a, states, iteration=3), (0,))
    assert first[0].key == ((0,), (1, 1)) and again[0].key == ((0,), (1, 2))
    assert only_static[0].key == ((0,),)
    assert first[0].items[0] is again[0].items[0]  # the speed limit's rows are reused
    polygons = RowBuilder(cons, conic=False).rows(ConstraintContext(scenario_a, states), (0,))
    assert {i.block.kind for i in polygons[0].items} == {"nonneg"}


def test_difference_rows_on_the_increments_mean_the_same_on_paths_that_obey_the_dynamics() -> None:
    # A speed limit, an acceleration limit and a visit disc on one platform of scenario C: rewritten on
    # the position increments, every row takes the same value on any path that obeys the dynamics; the
    # difference rows no longer touch a position; the rows' pattern does not depend on their values.
    import scipy.sparse as sp

    from pmht_opt.constraints.base import ConstraintContext
    from pmht_opt.model import PX, PY
    from pmht_opt.mstep.formulation import BLOCK, QPLayout, dynamics_rows, in_increments
    from pmht_opt.mstep.rows import RowBuilder, assemble

    sc = po.paper_scenario("C", seed=0, horizon=40)
    T, model, x0 = sc.horizon, sc.model, sc.initial_states[0]
    lay = QPLayout(1, T)
    A_dyn, b_dyn = dynamics_rows(model, lay, x0[None, :])
    states = model.propagate(sc.initial_states, T)
    ctx = ConstraintContext(scenario=sc, states=states)
    cons = [po.SpeedLimit(1e-2), po.AccelLimit(1e-5), po.Terminal(position=(1.0, 2.0))]
    rows = RowBuilder(cons, conic=True).rows(ctx, [0, 1, 2])[0]
    t_idx = np.arange(1, T + 1)
    col_map = lay.x(0, t_idx[:, None], np.arange(6)).ravel()
    extra = assemble(rows.items, lay.n, col_map, units=lay.units)
    A2, b2 = in_increments(extra.A, extra.b, A_dyn, b_dyn, lay.n)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(T, 6))
    x = np.empty((T + 1, 6))
    x[0] = x0
    for t in range(1, T + 1):
        x[t] = model.F @ x[t - 1] + model.L @ u[t - 1]
    z = np.concatenate([x[1:] / lay.units, u], axis=1).ravel()
    assert np.max(np.abs(A_dyn @ z - b_dyn)) < 1e-12
    before, after = extra.b - extra.A @ z, b2 - A2 @ z
    np.testing.assert_allclose(after, before, rtol=1e-9, atol=1e-12)
    # The speed and acceleration rows (all but the terminal's, the last 2) no longer touch a position.
    pos_cols = np.flatnonzero(np.isin(np.arange(lay.n) % BLOCK, [PX, PY]))
    assert sp.csr_matrix(A2)[: A2.shape[0] - 2][:, pos_cols].nnz == 0
    assert extra.A[:, pos_cols].nnz > 0
    halved = assemble(rows.items, lay.n, col_map, units=lay.units)
    halved.A.data[:] = 0.5 * halved.A.data
    A3, _ = in_increments(halved.A, halved.b, A_dyn, b_dyn, lay.n)
    assert np.array_equal(A3.indptr, A2.indptr) and np.array_equal(A3.indices, A2.indices)
