"""Condensed constrained M-steps (:mod:`pmht_opt.mstep.condensed`): the full QP's optimum, from a small QP.

Every test compares the condensed answer with an independent one: the full QP through the same backend
(``condense`` off), a dense solve of the optimality conditions, or the exact smoother.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pmht_opt as po
from pmht_opt.mstep import MStepData, make_mstep, mstep_objective
from pmht_opt.mstep.condensed import CondensedQP
from pmht_opt.verify import tolerance
from solvers import ProblemError, Status
from solvers.banded import BandedSmoother

FULL = {"condense": False}


def weights(scenario: po.Scenario, seed: int, zero_fraction: float = 0.5) -> MStepData:
    """Random weights pulling the platforms across the area (an M-step with fast, long moves)."""
    rng = np.random.default_rng(seed)
    T, M = scenario.horizon, scenario.n_platforms
    W = rng.uniform(0.0, 2.0, (T, M))
    W[rng.uniform(size=(T, M)) < zero_fraction] = 0.0
    return MStepData(W=W, WZ=W[..., None] * rng.uniform(-1.0, 11.0, (T, M, 2)), r=scenario.r)


def top_speed(states: np.ndarray) -> float:
    return float(np.max(np.hypot(states[:, 1:, 1], states[:, 1:, 4])))


def constraint_sets(scenario: po.Scenario, free: np.ndarray) -> dict[str, list[po.Constraint]]:
    vmax = 0.6 * top_speed(free)
    return {
        "speed+area": [po.SpeedLimit(vmax), po.AreaBounds(0, 10, 0, 10)],
        "soft speed": [po.SpeedLimit(0.5 * vmax, soft=True, weight=1.0)],
        "terminal": [po.Terminal(velocity=(0.0, 0.0), position=(5.0, 5.0), radius=0.5)],
        "terminal point": [po.Terminal(position=(5.0, 5.0))],
        "accel": [po.AccelLimit(0.5 * float(np.max(np.abs(free[:, 1:, [2, 5]]))))],
    }


def cost(scenario: po.Scenario, states: np.ndarray, data: MStepData) -> float:
    return mstep_objective(scenario.model, states, data.W, data.WZ, data.r)


@pytest.mark.parametrize("case", ["speed+area", "soft speed", "terminal", "terminal point", "accel"])
def test_condensed_and_full_qp_reach_the_same_optimum(scenario_a: po.Scenario, case: str) -> None:
    data = weights(scenario_a, 3)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "banded")
    cons = constraint_sets(scenario_a, free)[case]
    condensed = make_mstep(scenario_a, "clarabel", constraints=tuple(cons))
    full = make_mstep(scenario_a, "clarabel", FULL, constraints=tuple(cons))
    ctx = po.constraints.ConstraintContext(scenario_a, free)
    active = tuple(range(len(cons)))
    a = condensed.solve(MStepData(data.W, data.WZ, data.r, ctx, active))
    b = full.solve(MStepData(data.W, data.WZ, data.r, ctx, active))
    assert a.constrained  # the rows bind: otherwise both are the exact smoother's answer
    for con in cons:
        if not con.soft:
            assert con.violation(a.states, ctx).max_violation <= tolerance("clarabel", con, scenario_a)
    ca, cb = cost(scenario_a, a.states, data), cost(scenario_a, b.states, data)
    # One optimum: the costs agree to the backends' tolerance (1e-10 of the condensed QP, 1e-8 of the full).
    assert ca == pytest.approx(cb, rel=1e-8, abs=1e-8)
    # The positions agree as far as the objective's curvature fixes them.
    assert np.max(np.abs(a.states[:, :, [0, 3]] - b.states[:, :, [0, 3]])) < 1e-4
    # Above the unconstrained optimum, as constraints must be.
    assert ca >= cost(scenario_a, free, data) - 1e-9 * abs(ca)


def test_a_terminal_point_matches_a_dense_solve_of_the_optimality_conditions() -> None:
    """One platform, 40 steps, its end fixed: the QP in the process noise ``u`` is dense and well
    conditioned (the positions are linear in ``u``), so a dense KKT solve is an exact reference."""
    sc = po.Scenario(locales=[[3.0, 1.0], [1.0, 4.0]], starts=[[0.0, 0.0]], horizon=40, r=0.05)
    T, model = sc.horizon, sc.model
    rng = np.random.default_rng(2)
    W = rng.uniform(0.0, 1.0, (T, 1))
    WZ = W[..., None] * rng.uniform(0.0, 5.0, (T, 1, 2))
    target = np.array([4.0, 3.0])
    got = po.solve_mstep(sc, W, WZ, sc.r, "clarabel", [po.Terminal(position=target)])
    # x_t = F^t x_0 + sum_{s <= t} F^(t-s) L u_s: positions as an affine map of u (6 T).
    F, L = model.F, model.L
    G = np.zeros((T, 6, 6 * T))
    c = np.zeros((T, 6))
    x, acc = sc.initial_states[0], np.zeros((6, 6 * T))
    for t in range(T):
        x = F @ x
        acc = F @ acc
        acc[:, 6 * t : 6 * t + 6] += L
        G[t], c[t] = acc, x
    Pmat = G[:, [0, 3], :]  # (T, 2, 6T)
    H = np.eye(6 * T) + np.einsum("t,tai,taj->ij", W[:, 0] / sc.r, Pmat, Pmat)
    g = np.einsum("ta,tai->i", WZ[:, 0] / sc.r - W[:, 0:1] / sc.r * c[:, [0, 3]], Pmat)
    A = Pmat[-1]
    K = np.block([[H, A.T], [A, np.zeros((2, 2))]])
    sol = np.linalg.solve(K, np.concatenate([g, target - c[-1, [0, 3]]]))
    positions = np.einsum("tai,i->ta", Pmat, sol[: 6 * T]) + c[:, [0, 3]]
    np.testing.assert_allclose(got[0, 1:, [0, 3]].T, positions, atol=1e-7)
    np.testing.assert_allclose(got[0, -1, [0, 3]], target, atol=1e-9)


def test_the_working_set_does_not_change_the_answer(scenario_a: po.Scenario) -> None:
    """Started afresh (every unit the free optimum violates), from one unit (rounds add the rest) or
    from the last answer's binding units: one optimum."""
    import solvers
    from pmht_opt.constraints import ConstraintContext
    from pmht_opt.mstep.rows import RowBuilder, assemble

    data = weights(scenario_a, 4)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "banded")
    cons = (po.SpeedLimit(0.7 * top_speed(free)), po.AreaBounds(-0.5, 10.5, -0.5, 10.5))
    rows = RowBuilder(cons, conic=True).rows(ConstraintContext(scenario_a, free), (0, 1))
    qp = make_mstep(scenario_a, "clarabel", constraints=cons).blocks[0].qp(scenario_a.horizon)
    extra = assemble(rows[0].items, qp.layout.n, qp.col_map, units=qp.layout.units, margin=qp.margin)
    clarabel = solvers.get_session_class("clarabel")
    ref = make_mstep(scenario_a, "banded").solve(MStepData(data.W, data.WZ, data.r))
    exact = (ref.states[0, 1:], ref.noise[0])
    answers, sizes = [], []
    for start in ("afresh", "one unit", "last"):
        cqp = CondensedQP(scenario_a.model, qp.layout)
        first = cqp.solve(extra, data.W[:, 0], data.r, clarabel, {}, exact)
        assert first is not None
        if start == "one unit":
            assert cqp._rows is not None
            margin = cqp._rows.units.margin(cqp._rows.b - cqp._rows.C @ free[0, 1:].ravel())
            cqp._bound = np.array([int(np.argmin(margin))])
        sol = first
        if start != "afresh":
            sol = cqp.solve(extra, data.W[:, 0], data.r, clarabel, {}, exact)
        assert sol is not None and sol.ok and sol.x is not None
        answers.append(qp.layout.states(sol.x[: qp.layout.n])[0][:, [0, 3]])
        sizes.append(sol.info["condensed"]["units"])
    assert sizes[1] < sizes[0]  # the starts really differ
    assert np.max(np.abs(answers[0] - answers[1])) < 1e-5
    assert np.max(np.abs(answers[0] - answers[2])) < 1e-5


def test_infeasible_rows_are_named_as_with_the_full_qp(scenario_a: po.Scenario) -> None:
    data = weights(scenario_a, 5)
    cons = [po.SpeedLimit(1e-4), po.Terminal(position=(9.0, 9.0))]
    for options in ({}, FULL):
        with pytest.raises(
            po.InfeasibleError,
            match=r"constraints SpeedLimit\(0.0001\), Terminal\(position\) cannot all be met",
        ):
            po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "clarabel", cons, settings=options)


def test_condense_must_be_a_bool(scenario_a: po.Scenario) -> None:
    with pytest.raises(po.ConfigError, match="condense"):
        make_mstep(scenario_a, "clarabel", {"condense": "yes"})


def test_factor_solves_the_smoother_and_the_response_to_a_force() -> None:
    sc = po.paper_scenario("A", seed=1, horizon=60)
    m = sc.model
    T = sc.horizon
    rng = np.random.default_rng(0)
    W = rng.random(T) * (rng.random(T) < 0.5)
    WZ = W[:, None] * rng.uniform(0, 10, (T, 2))
    r = 0.1
    bs = BandedSmoother(m.F3, m.Q3, [1.0, 0.0, 0.0], T, 1)
    x0 = np.stack([sc.initial_states[0, 0:3], sc.initial_states[0, 3:6]], -1)[None]
    ref = bs.solve(r, x0, (WZ / np.where(W > 0, W, 1.0)[:, None])[None], W[None])
    factor = bs.factor(r, W[None])
    force = np.zeros((1, T, 3, 2))
    force[0, :, 0, :] = WZ / r
    states, noise = factor.solve(force, x0)
    np.testing.assert_allclose(states, ref.means[:, 1:], rtol=0, atol=1e-12 * np.abs(ref.means).max())
    np.testing.assert_allclose(noise, ref.noise, rtol=0, atol=1e-12 * max(1.0, np.abs(ref.noise).max()))
    # H^-1 c against the information form, well conditioned at 60 steps.
    Qi, F = np.linalg.inv(m.Q3), m.F3
    H = np.zeros((3 * T, 3 * T))
    for t in range(T):
        i = slice(3 * t, 3 * t + 3)
        H[i, i] += Qi
        if t:
            j = slice(3 * t - 3, 3 * t)
            H[j, j] += F.T @ Qi @ F
            H[i, j] -= Qi @ F
            H[j, i] -= F.T @ Qi
        H[3 * t, 3 * t] += W[t] / r
    c = rng.standard_normal((1, T, 3, 1))
    got = factor.solve(c)[0].ravel()
    # Backward stable: H got = c to the rounding of H's entries (H itself is too ill-conditioned, about
    # 2e11, for a forward comparison with a dense solve to say more than 1e-5).
    residual = np.abs(H @ got - c.ravel()).max()
    assert residual <= 1e-14 * np.abs(H).max() * np.abs(got).max()
    with pytest.raises(ProblemError, match="forcing"):
        factor.solve(np.zeros((1, T, 3)))
    with pytest.raises(ProblemError, match="weight"):
        bs.factor(r, -np.ones((1, T)))


def test_constrained_plans_agree_with_the_full_qp(scenario_a: po.Scenario) -> None:
    """A whole annealed plan under a speed limit and area bounds: the same plan to the M-steps'
    tolerance, both meeting their constraints on the returned positions."""
    sc = po.paper_scenario("A", seed=2, horizon=150)
    free = po.plan_pmht(sc, po.PMHTConfig(max_iter=30))
    cons = [po.SpeedLimit(0.7 * free.max_speed), po.AreaBounds(0, 10, 0, 10)]
    a = po.plan_pmht(sc, po.PMHTConfig(solver="clarabel", constraints=cons, max_iter=30))
    full = po.PMHTConfig(solver="clarabel", constraints=cons, max_iter=30, solver_settings=FULL)
    b = po.plan_pmht(sc, full)
    assert a.max_violation <= 1e-9 and b.max_violation <= 1e-9
    assert abs(a.total_distance - b.total_distance) < 1e-4 * b.total_distance
    # Where a limit binds, the M-step cost is flat to 1e-10 along moves of positions of 1e-4: the
    # two answers are equally optimal, and the iterates then differ by that much.
    np.testing.assert_allclose(a.history.objective, b.history.objective, rtol=1e-6)


def test_a_limit_binding_everywhere_goes_to_the_full_qp() -> None:
    """A speed limit that binds at most steps: a condensed QP of that many rows is past its cap (or,
    without the cap, ends "almost solved" at its tight tolerances), so every M-step is the full QP's
    and the plan equals the one without condensing to the last bit."""
    sc = po.paper_scenario("A", seed=0, horizon=200)
    cons = [po.SpeedLimit(0.02)]
    a = po.plan_pmht(sc, po.PMHTConfig(solver="clarabel", constraints=cons, max_iter=12))
    b = po.plan_pmht(
        sc, po.PMHTConfig(solver="clarabel", constraints=cons, max_iter=12, solver_settings=FULL)
    )
    np.testing.assert_array_equal(a.states, b.states)
    assert a.max_violation <= 1e-9


@settings(max_examples=12, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    speed=st.floats(0.3, 0.95),
    wall=st.floats(0.0, 2.0),
    zeros=st.floats(0.0, 0.9),
)
def test_condensed_optimum_property(seed: int, speed: float, wall: float, zeros: float) -> None:
    """Random weights, a speed limit at a random fraction of the free top speed and area bounds at a
    random inset (never past a start): the condensed answer meets every constraint and costs what
    the full QP's does."""
    sc = po.paper_scenario("A", seed=seed % 50, horizon=120)
    data = weights(sc, seed, zeros)
    free = po.solve_mstep(sc, data.W, data.WZ, data.r, "banded")
    starts = sc.initial_states[:, [0, 3]]
    lo, hi = min(wall, float(starts.min())), max(10 - wall, float(starts.max()))  # the starts inside
    cons = (po.SpeedLimit(speed * top_speed(free)), po.AreaBounds(lo, hi, lo, hi))
    ctx = po.constraints.ConstraintContext(sc, free)
    step = MStepData(data.W, data.WZ, data.r, ctx, (0, 1))
    a = make_mstep(sc, "clarabel", constraints=cons).solve(step)
    b = make_mstep(sc, "clarabel", FULL, constraints=cons).solve(step)
    for con in cons:
        assert con.violation(a.states, ctx).max_violation <= tolerance("clarabel", con, sc)
    assert cost(sc, a.states, data) == pytest.approx(cost(sc, b.states, data), rel=1e-8, abs=1e-8)


def test_a_terminal_point_after_a_long_coast_is_met_exactly() -> None:
    """Weights on the first 10 of 500 steps, r = 1e-8, the end fixed: the small QP's (unrefined)
    Sigma can leave the equality missed on the path; the working set is checked on the path itself,
    so the answer meets the point to rounding (or the full QP is solved)."""
    base = po.paper_scenario("A", seed=1)
    sc = po.Scenario(locales=base.locales, starts=base.start_positions, horizon=500, r=1e-8)
    data = weights(sc, 0)
    W, WZ = data.W.copy(), data.WZ.copy()
    W[10:], WZ[10:] = 0.0, 0.0
    got = po.solve_mstep(sc, W, WZ, sc.r, "clarabel", [po.Terminal(position=(5.0, 5.0))])
    assert np.max(np.abs(got[:, -1, [0, 3]] - 5.0)) <= 1e-9


def test_responses_of_no_new_rows_add_nothing() -> None:
    """Rows already seen, or rows without entries, add no response and no solve."""
    import scipy.sparse as sp

    from pmht_opt.mstep.responses import Responses

    C = sp.random(8, 6 * 5, density=0.3, format="csr", random_state=0).tolil()
    C[3, :] = 0
    responses = Responses(sp.csr_matrix(C), factor=None, T=5)  # type: ignore[arg-type]  # never solves
    responses._add([])
    responses._add([3])
    assert responses.R.shape == (15, 0) and responses._parts == {3: []}


@pytest.mark.parametrize("case", ["speed+area", "terminal"])
def test_osqp_condenses_polygons_onto_a_basis_of_their_rows(
    case: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """OSQP's cones are inner polygons, whose rows are combinations of the cone's two rows on the path:
    more than two of them made Sigma singular and every such M-step went to the whole QP. Written on a
    basis of independent rows, the condensed QP solves them: its answer meets the constraints and
    costs no more than the whole QP's (solved by ADMM to 1e-5: it may cost a little more)."""
    answers: list[bool] = []
    real = CondensedQP.solve

    def spy(self: CondensedQP, *args: object, **kwargs: object) -> object:
        out = real(self, *args, **kwargs)  # type: ignore[arg-type]
        answers.append(out is not None)
        return out

    monkeypatch.setattr(CondensedQP, "solve", spy)
    scenario_a = po.paper_scenario("A", seed=1, horizon=200)
    data = weights(scenario_a, 3)
    free = po.solve_mstep(scenario_a, data.W, data.WZ, data.r, "banded")
    cons = constraint_sets(scenario_a, free)[case]
    ctx = po.constraints.ConstraintContext(scenario_a, free)
    step = MStepData(data.W, data.WZ, data.r, ctx, tuple(range(len(cons))))
    a = make_mstep(scenario_a, "osqp", constraints=tuple(cons)).solve(step)
    assert answers and all(answers)
    whole = {"condense": False, "working_set": False, "mstep_work_limit": None}
    b = make_mstep(scenario_a, "osqp", whole, constraints=tuple(cons)).solve(step)
    for con in cons:
        assert con.violation(a.states, ctx).max_violation <= tolerance("osqp", con, scenario_a)
    ca, cb = cost(scenario_a, a.states, data), cost(scenario_a, b.states, data)
    assert ca <= cb + 1e-6 * abs(cb)
    assert ca >= cost(scenario_a, free, data) - 1e-9 * abs(ca)


def test_an_osqp_plan_under_a_speed_limit_solves() -> None:
    """Scenario C with SpeedLimit(0.1): OSQP's whole QP (ADMM to 1e-5, its polish failing) used to
    return an answer 4e-6 (relative) below the unconstrained optimum, refused by the answer check; the
    condensed QP is exact where it binds."""
    sc = po.paper_scenario("C", seed=0)
    cons = [po.SpeedLimit(0.1)]
    res = po.plan_pmht(sc, po.PMHTConfig(solver="osqp", constraints=cons, threads=1))
    assert res.max_violation <= tolerance("osqp", cons[0], sc)
    assert res.history.mstep_status[-1] is Status.OPTIMAL


def test_row_basis_keeps_two_rows_of_each_polygon() -> None:
    """The rows of an inner polygon are combinations of its cone's two rows: a basis of two per
    polygon, which gives back every row; rows that share no column stay independent."""
    import scipy.sparse as sp

    from pmht_opt.constraints.blocks import disc_block, inner_polygon
    from pmht_opt.mstep.basis import row_basis

    T = 6
    cones = disc_block(0, T, np.array([2, 3, 5]), (0, 3), np.ones((3, 2)), np.full(3, 0.1), sides=16)
    poly = inner_polygon(cones).G.tocsr()
    rows = sp.vstack([poly, sp.csr_matrix(([1.0], ([0], [6 * 3 + 1])), shape=(1, 6 * T))]).tocsr()
    basis, T_map = row_basis(rows)
    assert basis.size == 3 * 2 + 1 and T_map is not None
    np.testing.assert_allclose(T_map @ rows[basis].toarray(), rows.toarray(), atol=1e-14)
    alone, none = row_basis(rows[basis])
    assert none is None and alone.size == basis.size


def test_the_sides_of_each_polygon_form_one_group_and_the_most_violated_is_taken() -> None:
    """Three visit polygons of 16 sides at steps 2, 3 and 5, a bound on a coordinate at step 3 and an
    equality: the sides of each polygon share a group, the others are groups of their own; of the
    violated units, one per group is taken, the most violated."""
    import scipy.sparse as sp

    import solvers
    from pmht_opt.constraints.blocks import disc_block, inner_polygon
    from pmht_opt.mstep.units import Units, groups, most_violated

    T, sides = 6, 16
    cones = disc_block(0, T, np.array([2, 3, 5]), (0, 3), np.ones((3, 2)), np.full(3, 0.1), sides=sides)
    poly = inner_polygon(cones).G.tocsr()
    assert poly.shape[0] == 3 * sides
    bound = sp.csr_matrix(([1.0], ([0], [6 * 3])), shape=(1, 6 * T))
    equality = sp.csr_matrix(([1.0, -1.0], ([0, 0], [6 * 3, 6 * 3 + 3])), shape=(1, 6 * T))
    rows = sp.vstack([poly, bound, equality]).tocsr()
    units = Units.of([solvers.Nonneg(3 * sides + 1), solvers.Zero(1)])
    g = groups(rows, units)
    for k in range(3):
        assert np.unique(g[k * sides : (k + 1) * sides]).size == 1
    assert np.unique(g).size == 3 + 2
    # The point (2, 2) at every step: outside each unit disc near (1, 1) of radius 0.1.
    x = np.zeros(6 * T)
    x[0::6], x[3::6] = 2.0, 2.0
    b = np.concatenate([inner_polygon(cones).h, [1.5], [0.0]])
    margin = b - rows @ x
    violated = np.flatnonzero(margin < 0)
    picked = most_violated(violated, margin, g)
    assert picked.size == np.unique(g[violated]).size >= 4  # one per violated group (polygons, bound)
    for unit in picked:
        same = violated[g[violated] == g[unit]]
        assert margin[unit] == margin[same].min()


def test_guaranteed_visits_stay_condensed_after_a_costly_first_m_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The first M-step of guaranteed visits on OSQP finds its binding rows from nothing (tens of
    thousands of ADMM iterations on C seed 1000); later M-steps carry them over and condense cheaply.
    That first cost must not send the next M-steps to a working set of the whole QP, which does not
    settle on visits: every M-step is condensed and none tries a working set."""
    from pmht_opt.mstep.horizon import HorizonQP

    tried: list[bool] = []
    real = HorizonQP._solve_working

    def spy(self: HorizonQP, *args: object, **kwargs: object) -> object:
        tried.append(True)
        return real(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(HorizonQP, "_solve_working", spy)
    sc = po.paper_scenario("C", seed=1000)
    tour = po.order_locales(sc, "ga", seed=1000, iterations=300)
    seen: list[po.Progress] = []
    res = po.plan(
        sc,
        "smoothed",
        settings=po.Settings(solver="osqp", threads=1),
        stop=po.MaxIterations(3),
        tour=tour,
        visit_radius=0.1,
        callback=seen.append,
    )
    assert res.coverage(0.1) == 1.0
    assert len(seen) >= 3 and not tried
