"""Constraints: every kind holds on the returned plans for every backend that takes it; backends agree
on constrained M-steps; constraints never improve the objective; infeasible and soft cases."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest
from conftest import VIOLATION_TOL

from pmht_opt import (
    AccelLimit,
    Anneal,
    AreaBounds,
    CircleObstacle,
    ConfigError,
    CvxpyConstraint,
    InfeasibleError,
    PMHTConfig,
    PolygonObstacle,
    Scenario,
    ScenarioError,
    ScheduleError,
    SolverError,
    SpeedLimit,
    Terminal,
    VisitAll,
    paper_scenario,
    plan_pmht,
)
from pmht_opt.constraints.base import ConstraintContext
from pmht_opt.constraints.user import CvxpyVariables
from pmht_opt.estep import estep
from pmht_opt.model import POS
from pmht_opt.mstep import MStepData, make_mstep, mstep_objective

ITERATIONS = {"clarabel": 6, "osqp": 4, "cvxpy": 6}


def _unconstrained_speed(kind: str) -> float:
    res = plan_pmht(paper_scenario(kind, seed=1), PMHTConfig(max_iter=20))
    return res.max_speed


def _obstacles(sc: Scenario) -> list:
    circle = CircleObstacle((3.0, 6.5), 0.8)
    square = PolygonObstacle([(6.0, 4.0), (7.5, 4.0), (7.5, 6.0), (6.0, 6.0)])
    for ob in (circle, square):
        assert np.all(ob.penetration(sc.start_positions) == 0), "test obstacle covers a start"
    return [circle, square]


@pytest.fixture(scope="module")
def speeds() -> dict[str, float]:
    return {kind: _unconstrained_speed(kind) for kind in "ABC"}


#: The horizon of the slower backends' cases below.
SHORT = {"osqp": 150, "cvxpy": 100}
#: Every scenario with clarabel, each other backend on some: OSQP's constrained M-steps run thousands of
#: ADMM iterations (seconds each), and the backends' agreement is tested on single M-steps below.
CASES = [
    ("A", "clarabel"),
    ("B", "clarabel"),
    ("C", "clarabel"),
    ("B", "osqp"),
    ("A", "cvxpy"),
    ("C", "cvxpy"),
]


@pytest.mark.parametrize(("kind", "solver"), CASES)
def test_motion_area_obstacles_terminal_hold(kind: str, solver: str, speeds: dict[str, float]) -> None:
    # The slower backends on a shorter horizon: the same rows, a fraction of the cost. OSQP's on B over
    # 150 steps, where its paths would enter the square without the obstacle rows (over 100 they
    # would not); cvxpy's on C over 100, where the circle still binds.
    sc = paper_scenario(kind, seed=1, **({} if solver == "clarabel" else {"horizon": SHORT[solver]}))
    vmax = 0.7 * speeds[kind]
    cons = [
        SpeedLimit(vmax),
        AccelLimit(0.05),
        AreaBounds(-1.5, 10.5, -0.5, 10.5),  # B starts at x = -1
        *_obstacles(sc),
        Terminal(velocity=(0.0, 0.0)),
    ]
    # A schedule as long as the run: it anneals throughout and ends at the scenario's r.
    n = ITERATIONS[solver]
    res = plan_pmht(sc, PMHTConfig(solver=solver, max_iter=n, anneal=Anneal(iterations=n), constraints=cons))
    tol = VIOLATION_TOL[solver]
    reports = res.constraint_reports()
    assert [r.name for r in reports] == [c.name for c in cons]
    for rep in reports:
        assert rep.max_violation <= tol, rep
    # Independent checks on the paths themselves.
    v = res.states[:, 1:, [1, 4]]
    assert np.max(np.hypot(v[..., 0], v[..., 1])) <= vmax + tol
    p = res.positions[:, 1:]
    assert p[..., 0].min() >= -1.5 - tol and p[..., 0].max() <= 10.5 + tol
    assert np.hypot(p[..., 0] - 3.0, p[..., 1] - 6.5).min() >= 0.8 - tol
    assert np.max(np.abs(res.states[:, -1, [1, 4]])) <= tol
    assert res.max_violation <= tol


#: Every scenario with clarabel; each other backend on one scenario (OSQP's constrained solves of
#: guaranteed visits take thousands of ADMM iterations: seconds per M-step).
VISIT_CASES = [("A", "clarabel"), ("B", "clarabel"), ("C", "clarabel"), ("A", "osqp"), ("C", "cvxpy")]


@pytest.mark.parametrize(("kind", "solver"), VISIT_CASES)
def test_visit_all_guarantees_coverage(kind: str, solver: str) -> None:
    sc = paper_scenario(kind, seed=1, **({"horizon": 250} if solver == "cvxpy" else {}))
    # A short annealing schedule; VisitAll's warm-up counts from its end (settled r), so the visits
    # are chosen from sharp weights and imposed on the last iterations.
    n_iter, anneal = 12, 6
    cfg = PMHTConfig(
        solver=solver,
        max_iter=n_iter,
        anneal=Anneal(1.0, anneal),
        constraints=[VisitAll(0.1, warmup=n_iter - anneal - 1)],
    )
    res = plan_pmht(sc, cfg)
    assert res.history.r[anneal] == sc.r
    # VisitAll brings StayNear(0.5) with it: the paths stay near the area.
    rep, near = res.constraint_reports()
    assert near.name == "StayNear(0.5)" and near.max_violation <= VIOLATION_TOL[solver] * 10
    assert rep.max_violation <= VIOLATION_TOL[solver]
    assert rep.details["visits_met"] == sc.n_locales
    # Every locale lies within the radius of some path.
    assert res.coverage(0.1 + VIOLATION_TOL[solver]) == 1.0


@pytest.mark.parametrize("kind", ["A", "B", "C"])
def test_cvxpy_user_constraint(kind: str) -> None:
    # Half the paper's horizon: cvxpy's compile and solves scale with it; the rows are the same kind.
    sc = paper_scenario(kind, seed=1, horizon=250)
    # Platform 0 stays west of a line through the middle of the area (it starts west of it) ...
    x_start = float(sc.start_positions[0, 0])
    wall = max(5.0, x_start + 0.5)
    west = CvxpyConstraint(lambda v: [v.positions[0][:, 0] <= wall], name="west")
    # ... and every platform's mean speed over the plan stays under a cap (70% of the fastest
    # platform's without it), a constraint no built-in kind expresses.
    free = plan_pmht(sc, PMHTConfig(max_iter=4)).states[:, 1:, [1, 4]]
    cap = 0.7 * float(np.hypot(free[..., 0], free[..., 1]).mean(axis=1).max())

    def mean_speed_cap(v: CvxpyVariables) -> list:
        return [cp.sum(cp.norm(vel, axis=1)) / sc.horizon <= cap for vel in v.velocities]

    slow = CvxpyConstraint(mean_speed_cap, name="mean speed")
    res = plan_pmht(sc, PMHTConfig(solver="cvxpy", max_iter=4, constraints=[west, slow]))
    assert res.positions[0, 1:, 0].max() <= wall + 1e-6
    v = res.states[:, 1:, [1, 4]]
    mean_speed = np.hypot(v[..., 0], v[..., 1]).mean(axis=1)
    assert np.all(mean_speed <= cap + 1e-6) and mean_speed.max() >= cap - 1e-4  # binding
    reports = res.constraint_reports()
    assert [r.name for r in reports] == ["west", "mean speed"]
    assert all(r.max_violation <= 1e-6 for r in reports)


# ---------------------------------------------------------------- single M-steps


def _small() -> Scenario:
    rng = np.random.default_rng(3)
    return Scenario(
        locales=rng.uniform(0, 10, (12, 2)),
        starts=[[1.0, 1.0], [9.0, 2.0]],
        horizon=80,
        bounds=(0, 10, 0, 10),
    )


def _random_mstep(seed: int, sc: Scenario) -> tuple[MStepData, np.ndarray]:
    rng = np.random.default_rng(seed)
    T = sc.horizon
    # Random smooth-ish paths to weigh the locales against.
    states = np.repeat(sc.initial_states[:, None, :], T + 1, axis=1)
    drift = rng.uniform(-0.08, 0.08, (sc.n_platforms, 1, 2)) * np.arange(T + 1)[None, :, None]
    states[:, :, POS] = states[:, :, POS] + drift
    es = estep(sc.locales, states[:, 1:, POS], None, None, sc.r * 30)
    return MStepData(W=es.W, WZ=es.WZ, r=sc.r), states


def _objective(sc: Scenario, states: np.ndarray, data: MStepData) -> float:
    return mstep_objective(sc.model, states, data.W, data.WZ, data.r)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_backends_agree_on_constrained_msteps(seed: int) -> None:
    sc = _small()
    data, states = _random_mstep(seed, sc)
    es = estep(sc.locales, states[:, 1:, POS], None, None, sc.r * 30)
    cons = (
        SpeedLimit(0.12),
        AreaBounds(0, 10, 0, 10),
        Terminal(velocity=(0, 0)),
        CircleObstacle((5, 5), 1.0),
    )
    objectives = {}
    paths = {}
    ctx = ConstraintContext(scenario=sc, states=states, estep=es, iteration=5)
    everything = tuple(range(len(cons)))
    for solver in ("clarabel", "cvxpy", "clarabel-poly", "osqp"):
        ms = make_mstep(sc, solver.split("-")[0], constraints=cons)
        if solver == "clarabel-poly":
            ms.rows.conic = False  # the polygons OSQP gets, on Clarabel
        out = ms.solve(MStepData(W=data.W, WZ=data.WZ, r=data.r, ctx=ctx, active=everything))
        ms.close()
        objectives[solver] = _objective(sc, out.states, data)
        paths[solver] = out.states
        for con in cons:
            assert con.violation(out.states, ctx).max_violation <= VIOLATION_TOL[solver.split("-")[0]]
    rel = abs(objectives["clarabel"] - objectives["cvxpy"]) / abs(objectives["clarabel"])
    assert rel <= 1e-6, objectives
    # OSQP against Clarabel on the identical polygonal problem, within OSQP's ADMM tolerance.
    rel_poly = abs(objectives["osqp"] - objectives["clarabel-poly"]) / abs(objectives["clarabel-poly"])
    assert rel_poly <= 1e-3, objectives
    # The inner polygon is a tighter feasible set than the cone: never a better objective.
    assert objectives["clarabel-poly"] >= objectives["clarabel"] - 1e-9 * abs(objectives["clarabel"])


@pytest.mark.parametrize("solver", ["clarabel", "osqp", "cvxpy"])
def test_constraints_never_improve_the_objective(solver: str) -> None:
    sc = _small()
    data, states = _random_mstep(7, sc)
    es = estep(sc.locales, states[:, 1:, POS], None, None, sc.r * 30)
    free = make_mstep(sc, solver)
    ctx = ConstraintContext(scenario=sc, states=states, estep=es, iteration=1)
    j_free = _objective(sc, free.solve(data).states, data)
    kinds = [[SpeedLimit(0.1)], [AreaBounds(0, 10, 0, 10), AccelLimit(0.01)]]
    if solver != "osqp":
        # Visits at the MAP times of these random paths force a manoeuvre with process noise up to
        # 9e4 and an objective of 1.3e10 (against 3 and -2e4 unconstrained): Clarabel solves it, ADMM
        # is still 1e-2 infeasible after 50 000 iterations with every fallback rho, and says so
        # (SolverError). See mstep.tuning.RETRIES for the realistic cases OSQP does solve.
        kinds.append([VisitAll(0.2, warmup=0)])
    for cons in kinds:
        ms = make_mstep(sc, solver, constraints=tuple(cons))
        out = ms.solve(MStepData(W=data.W, WZ=data.WZ, r=data.r, ctx=ctx, active=tuple(range(len(cons)))))
        j = _objective(sc, out.states, data)
        assert j >= j_free - 1e-6 * abs(j_free)


# ---------------------------------------------------------------- failure modes and soft mode


def _impossible(soft: bool = False) -> list:
    # A final position outside the area the path must stay in.
    return [
        AreaBounds(0, 5, 0, 10, soft=soft, platforms=[0]),
        Terminal(position=(9.0, 9.0), soft=soft, platforms=[0]),
    ]


def _unreachable() -> list:
    # A wall 200 units long between platform 0 and its end: going round it takes at least 200 units of
    # travel, the speed limit allows 40 in the horizon. The straight line (4 units) passes every
    # pre-check: only the solver finds this one, and the diagnosis names it. The obstacle is not convex
    # (the path picks a side of it), so the phase-one problem can prove only that the side chosen fails.
    wall = [(2.5, -100.0), (3.0, -100.0), (3.0, 100.0), (2.5, 100.0)]
    return [
        PolygonObstacle(wall, platforms=[0]),
        SpeedLimit(0.5, platforms=[0]),
        Terminal(position=(5.0, 1.0), platforms=[0]),
    ]


@pytest.mark.parametrize("solver", ["clarabel", "osqp", "cvxpy"])
def test_infeasible_constraints_raise(solver: str) -> None:
    sc = _small()
    # Named before any solve: the end lies outside the area, proven by convex constraints alone.
    with pytest.raises(InfeasibleError, match=r"Terminal\(position\) and AreaBounds.* platform 0"):
        plan_pmht(sc, PMHTConfig(solver=solver, max_iter=2, constraints=_impossible()))
    # Found by the solver, named by the diagnosis, and not called infeasible: no convex proof exists.
    with pytest.raises(SolverError) as err:
        plan_pmht(sc, PMHTConfig(solver=solver, max_iter=2, constraints=_unreachable()))
    assert not isinstance(err.value, InfeasibleError)
    assert isinstance(err.value, ScheduleError)
    msg = str(err.value)
    assert "PolygonObstacle" in msg and "Terminal" in msg
    assert "platform 0" in msg and "t = " in msg
    assert "not shown to be infeasible" in msg


def test_soft_mode_returns_plan_and_reports_violations() -> None:
    sc = _small()
    res = plan_pmht(sc, PMHTConfig(max_iter=3, constraints=_impossible(soft=True)))
    reports = {r.name.split("(")[0]: r for r in res.constraint_reports()}
    assert all(r.soft for r in reports.values())
    assert max(r.max_violation for r in reports.values()) > 1e-3
    assert not all(r.satisfied for r in reports.values())
    assert res.metrics()["constraints"]


def test_soft_mode_matches_hard_when_feasible() -> None:
    sc = _small()
    hard = plan_pmht(sc, PMHTConfig(max_iter=3, constraints=[SpeedLimit(0.1)], anneal=None))
    soft = plan_pmht(
        sc, PMHTConfig(max_iter=3, constraints=[SpeedLimit(0.1, soft=True, weight=1e6)], anneal=None)
    )
    # Plain EM: under annealing's wide first penalties the exact-penalty optimum is equally the hard
    # one, but both solves are less sharp. The hard limit is imposed 1e-5 inside (rows.BACKOFF): over
    # 80 steps at the limit that moves positions by up to 80 x 0.1 x 1e-5 = 8e-5.
    assert np.max(np.abs(hard.positions - soft.positions)) < 1e-4
    assert hard.max_speed <= 0.1 and soft.max_speed <= 0.1 * (1 + 1e-6)


def test_start_inside_obstacle_or_outside_area_is_a_scenario_error() -> None:
    sc = _small()
    with pytest.raises(ScenarioError, match=r"platform 0 starts .* inside CircleObstacle"):
        plan_pmht(sc, PMHTConfig(max_iter=1, constraints=[CircleObstacle((1.2, 1.0), 0.5)]))
    with pytest.raises(ScenarioError, match=r"platform 1 starts .* outside AreaBounds"):
        plan_pmht(sc, PMHTConfig(max_iter=1, constraints=[AreaBounds(0, 5, 0, 10)]))


def test_backend_support_and_parameters_are_checked() -> None:
    with pytest.raises(ConfigError, match="kalman"):
        PMHTConfig(solver="kalman", constraints=[SpeedLimit(1.0)])
    with pytest.raises(ConfigError, match="osqp"):
        PMHTConfig(solver="osqp", constraints=[CvxpyConstraint(lambda v: [])])
    with pytest.raises(ConfigError, match="SpeedLimit"):
        SpeedLimit(-1.0)
    with pytest.raises(ConfigError, match="AreaBounds"):
        AreaBounds(1, 0, 0, 1)
    with pytest.raises(ConfigError, match="convex"):
        PolygonObstacle([(0, 0), (2, 0), (1, 0.2), (2, 2), (0, 2)])
    with pytest.raises(ConfigError, match="weight"):
        SpeedLimit(1.0, soft=True, weight=float("nan"))
    with pytest.raises(ConfigError, match="constraints"):
        PMHTConfig(constraints=["speed"])
    with pytest.raises(ConfigError, match="platforms"):
        plan_pmht(_small(), PMHTConfig(max_iter=1, constraints=[SpeedLimit([0.1, 0.2, 0.3])]))


def test_obstacle_report_counts_cutting_segments() -> None:
    sc = _small()
    ob = CircleObstacle((5.0, 5.0), 1.0)
    states = np.zeros((2, 3, 6))
    states[0, :, 0] = [3.0, 7.0, 7.0]  # a straight hop through the disc, both ends outside
    states[0, :, 3] = [5.0, 5.0, 8.0]
    states[1, :, 0] = 9.0
    ctx = ConstraintContext(scenario=sc, states=states)
    rep = ob.violation(states, ctx)
    # The segment passes through the centre: it enters the disc by its whole radius.
    assert rep.max_violation == pytest.approx(1.0) and rep.worst == (0, 1)
    assert rep.details["segments_entering"] == 1
    sq = PolygonObstacle([(4, 4), (6, 4), (6, 6), (4, 6)])
    rep = sq.violation(states, ctx)
    assert rep.max_violation == pytest.approx(1.0) and rep.details["segments_entering"] == 1
    # A segment that only grazes a corner: exact depth along it.
    graze = np.zeros((2, 2, 6))
    graze[1, :, 0] = 9.0  # platform 1 far away
    graze[0, :, 0] = [3.5, 4.5]
    graze[0, :, 3] = [4.5, 3.5]  # crosses the corner (4, 4) at depth 0
    graze_ctx = ConstraintContext(scenario=sc, states=graze)
    assert sq.violation(graze, graze_ctx).max_violation == pytest.approx(0.0)
    dent = graze.copy()
    dent[0, :, 3] = [4.7, 3.7]  # passes 0.2 / sqrt(2) inside the corner
    depth = sq.violation(dent, ConstraintContext(scenario=sc, states=dent)).max_violation
    assert depth == pytest.approx(0.1)


@pytest.mark.parametrize("solver", ["clarabel", "osqp", "cvxpy"])
def test_no_segment_cuts_an_obstacle(solver: str) -> None:
    # A platform pulled across a disc: the half-planes on both ends of each segment keep every
    # segment outside it, not only the sampled positions.
    sc = Scenario(locales=[[9.0, 6.2]], starts=[[1.0, 5.4]], horizon=40, q=1e-6, bounds=(0, 10, 0, 10))
    disc = CircleObstacle((5.0, 5.0), 1.0)

    def clearance(res: object) -> float:
        pos = res.positions[0]  # type: ignore[attr-defined]
        d = pos[1:] - pos[:-1]
        s = np.clip(np.einsum("ij,ij->i", disc.center - pos[:-1], d) / np.einsum("ij,ij->i", d, d), 0, 1)
        return float(np.min(np.hypot(*(pos[:-1] + s[:, None] * d - disc.center).T)))

    free = plan_pmht(sc, PMHTConfig(max_iter=10, anneal=None))
    assert clearance(free) < 0.9  # the straight path would cut the disc
    res = plan_pmht(sc, PMHTConfig(solver=solver, max_iter=10, anneal=None, constraints=[disc]))
    assert clearance(res) >= 1.0 - VIOLATION_TOL[solver]
    assert res.coverage(0.5) == 1.0  # it went round


def test_self_intersecting_polygons_are_refused() -> None:
    star = [(np.cos(a), np.sin(a)) for a in np.pi / 2 + 4 * np.pi / 5 * np.arange(5)]  # a pentagram
    with pytest.raises(ConfigError, match="crosses itself"):
        PolygonObstacle(star)
    with pytest.raises(ConfigError, match="in a line"):
        PolygonObstacle([(0, 0), (1, 0), (2, 0), (1, 1)])
    PolygonObstacle([(0, 0), (1, 0), (1, 1), (0, 1)])  # a square is fine, either orientation
    PolygonObstacle([(0, 0), (0, 1), (1, 1), (1, 0)])


# ---------------------------------------------------------------- blocks and the soft rule


def test_inner_polygon_of_a_cone_block_is_inscribed() -> None:
    from pmht_opt.constraints.blocks import disc_block, inner_polygon

    T = 3
    blk = disc_block(0, T, np.array([2]), (0, 3), np.array([[1.0, 2.0]]), np.array([0.5]), sides=8)
    poly = inner_polygon(blk)
    assert poly.kind == "nonneg" and poly.units == 8 and poly.group == 8
    angles = 2 * np.pi * (np.arange(8) + 0.5) / 8
    for radius, inside in ((0.5 * np.cos(np.pi / 8) - 1e-9, True), (0.5 + 1e-9, False)):
        for a in angles:
            z = np.zeros(6 * T)
            z[6 + 0], z[6 + 3] = 1.0 + radius * np.cos(a), 2.0 + radius * np.sin(a)
            assert bool(np.all(poly.residual(z) == 0)) is inside
            if inside:
                assert blk.residual(z)[0] == 0  # the inner polygon implies the cone
    # The polygon's vertices lie on the circle, between the face normals 2 pi k / 8.
    z = np.zeros(6 * T)
    z[6], z[9] = 1.0 + 0.5 * np.cos(np.pi / 8), 2.0 + 0.5 * np.sin(np.pi / 8)
    assert np.max(poly.residual(z)) < 1e-12 and blk.residual(z)[0] < 1e-12


@pytest.mark.parametrize("radius", [1e-9, 1e-5, 0.1, 3.0])
def test_a_hard_polygon_is_backed_off_as_its_cone(radius: float) -> None:
    """Inner polygons (OSQP's cones) are shrunk by the cone's relative back-off, and carry the cone's
    radius for whoever measures their rows relative to it: an acceleration limit of 1e-5 or 1e-9 keeps
    a polygon around its centre (backed off like other linear rows, by 1e-5 absolute, it was empty)."""
    from pmht_opt.constraints.blocks import disc_block, inner_polygon
    from pmht_opt.mstep.rows import BACKOFF, Imposed, assemble

    T = 3
    centre = np.array([[1.0, 2.0]])
    cone = disc_block(0, T, np.array([2]), (0, 3), centre, np.array([radius]), sides=8)
    rows = assemble([Imposed(inner_polygon(cone), "limit")], 6 * T, np.arange(6 * T))
    z = np.zeros(6 * T)
    z[6], z[9] = centre[0]
    # At the centre: cos(pi / 8) of the radius, less the cut (up to the rounding of coordinates of
    # size 2), on rows whose coefficients are the faces' unit normals.
    slack = rows.b - rows.A @ z
    rounding = 64 * np.finfo(float).eps * 2.0
    np.testing.assert_allclose(slack, np.cos(np.pi / 8) * radius * (1.0 - BACKOFF), rtol=1e-12, atol=rounding)
    np.testing.assert_allclose(np.sqrt(rows.A.multiply(rows.A).sum(axis=1)).A1, 1.0, rtol=1e-12)
    np.testing.assert_array_equal(rows.row_size, radius)


def test_span_pattern_keeps_one_sparsity_for_moving_rows() -> None:
    from pmht_opt.constraints.blocks import disc_block, with_span_pattern

    early = disc_block(0, 10, np.array([3]), (0, 3), np.zeros((1, 2)), np.ones(1))
    late = disc_block(0, 10, np.array([6]), (0, 3), np.zeros((1, 2)), np.ones(1))
    early.span = late.span = np.array([[2, 7]])
    a, b = with_span_pattern(early), with_span_pattern(late)
    assert (a != 0).nnz == (b != 0).nnz == 2
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.indptr, b.indptr)


def test_span_pattern_stores_every_touched_component_over_each_units_span() -> None:
    from pmht_opt.constraints.blocks import disc_block, with_span_pattern

    rng = np.random.default_rng(2)
    T, k = 40, 7
    times = rng.integers(5, 35, k)
    blk = disc_block(1, T, times, (0, 3), rng.uniform(0, 5, (k, 2)), np.full(k, 0.3))
    blk.span = np.stack([times - rng.integers(0, 5, k), times + rng.integers(0, 5, k)], axis=1)
    got = with_span_pattern(blk)
    # By definition: each row of unit u stores px and py (the components the disc touches) at every
    # step of u's span, plus its own entries with their values.
    want = set()
    for u, (lo, hi) in enumerate(blk.span):
        for row in range(3 * u, 3 * u + 3):
            want |= {(row, 6 * (t - 1) + comp) for t in range(lo, hi + 1) for comp in (0, 3)}
    coo = got.tocoo()
    assert set(zip(coo.row.tolist(), coo.col.tolist(), strict=True)) == want | set(
        zip(*blk.G.nonzero(), strict=True)
    )
    np.testing.assert_array_equal(got.toarray(), blk.G.toarray())


def test_soft_inequalities_cost_nothing_when_met() -> None:
    # A soft keep-out disc far from every path is inactive: the plan equals the unconstrained one.
    # (An unbounded slack would reward keeping away from it instead.)
    sc = _small()
    free = plan_pmht(sc, PMHTConfig(max_iter=3, anneal=None))
    far = CircleObstacle((30.0, 30.0), 1.0, soft=True, weight=1e3)
    soft = plan_pmht(sc, PMHTConfig(max_iter=3, anneal=None, constraints=[far]))
    assert np.max(np.abs(soft.positions - free.positions)) < 1e-6


def test_return_to_base_ends_at_the_start_at_rest() -> None:
    sc = _small()
    res = plan_pmht(sc, PMHTConfig(max_iter=3, constraints=[Terminal.return_to_base()]))
    np.testing.assert_allclose(res.positions[:, -1], sc.start_positions, atol=1e-6)
    np.testing.assert_allclose(res.states[:, -1][:, [1, 2, 4, 5]], 0.0, atol=1e-6)
    assert Terminal.return_to_base().name == "Terminal(velocity, acceleration, start)"
    with pytest.raises(ConfigError, match="'start'"):
        Terminal(position="home")
