"""The generic QP layer: every backend on every shared problem, statuses, updates, errors."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import solvers
from solvers import SOC, Nonneg, QPProblem, QPSolution, Status, Zero
from solvers.kalman import rts_smoother

BACKENDS = ["osqp", "clarabel", "cvxpy"]
SOC_BACKENDS = ["clarabel", "cvxpy"]
#: Accuracy each backend is held to on the shared problems.
TOL = {"osqp": 1e-6, "clarabel": 1e-7, "cvxpy": 1e-6}


def eq_ineq_problem() -> tuple[QPProblem, np.ndarray]:
    """min 1/2 ||x - c||^2 s.t. x0 + x1 + x2 = 1, x0 <= 0.1: answer by hand."""
    c = np.array([1.0, 0.5, -0.2])
    # With x0 fixed at 0.1 (active), x1, x2 minimise ||(x1,x2)-(c1,c2)||^2 on x1 + x2 = 0.9.
    shift = (0.9 - c[1] - c[2]) / 2
    answer = np.array([0.1, c[1] + shift, c[2] + shift])
    prob = QPProblem(
        P=sp.eye(3, format="csc"),
        q=-c,
        A=sp.csc_matrix(np.array([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0]])),
        b=np.array([1.0, 0.1]),
        cones=(Zero(1), Nonneg(1)),
    )
    return prob, answer


def soc_problem() -> tuple[QPProblem, np.ndarray]:
    """min 1/2 ||x - (3, 4)||^2 s.t. ||x|| <= 1: the projection onto the unit disc."""
    prob = QPProblem(
        P=sp.eye(2, format="csc"),
        q=-np.array([3.0, 4.0]),
        A=sp.csc_matrix(np.vstack([np.zeros((1, 2)), -np.eye(2)])),
        b=np.array([1.0, 0.0, 0.0]),
        cones=(SOC(3),),
    )
    return prob, np.array([0.6, 0.8])


@pytest.mark.parametrize("backend", BACKENDS)
def test_equality_and_inequality_known_answer(backend: str) -> None:
    prob, answer = eq_ineq_problem()
    sol = solvers.solve_qp(prob, backend)
    assert sol.ok, sol.raw_status
    assert sol.status is Status.OPTIMAL
    np.testing.assert_allclose(sol.x, answer, atol=TOL[backend])
    res = sol.residuals(prob)
    assert res["primal"] < TOL[backend]
    assert res["objective"] == pytest.approx(prob.objective(answer), abs=TOL[backend])


@pytest.mark.parametrize("backend", SOC_BACKENDS)
def test_second_order_cone_known_answer(backend: str) -> None:
    prob, answer = soc_problem()
    sol = solvers.solve_qp(prob, backend)
    assert sol.ok
    np.testing.assert_allclose(sol.x, answer, atol=TOL[backend])


def test_osqp_rejects_second_order_cones() -> None:
    prob, _ = soc_problem()
    with pytest.raises(solvers.UnsupportedProblemError, match="second-order"):
        solvers.solve_qp(prob, "osqp")


@pytest.mark.parametrize("backend", BACKENDS)
def test_update_in_place_matches_a_fresh_solve(backend: str) -> None:
    prob, _ = eq_ineq_problem()
    session = solvers.open_session(prob, backend)
    assert session.solve().ok
    new_q = np.array([-0.3, 0.2, 0.4])
    new_P = np.array([2.0, 1.0, 3.0])
    session.update(q=new_q, P_data=new_P, b=np.array([2.0, 0.5]))
    updated = session.solve()
    fresh_prob = QPProblem(
        P=sp.diags(new_P, format="csc"),
        q=new_q,
        A=prob.A,
        b=np.array([2.0, 0.5]),
        cones=prob.cones,
    )
    fresh = solvers.solve_qp(fresh_prob, "clarabel")
    assert updated.ok and fresh.ok
    np.testing.assert_allclose(updated.x, fresh.x, atol=TOL[backend])


@pytest.mark.parametrize("backend", BACKENDS)
def test_infeasible_problem_is_reported_not_solved(backend: str) -> None:
    # x0 = 1 and x0 <= 0 cannot both hold.
    prob = QPProblem(
        P=sp.eye(1, format="csc"),
        q=np.zeros(1),
        A=sp.csc_matrix(np.array([[1.0], [1.0]])),
        b=np.array([1.0, 0.0]),
        cones=(Zero(1), Nonneg(1)),
    )
    sol = solvers.solve_qp(prob, backend)
    assert not sol.ok
    assert sol.status in solvers.INFEASIBLE


def test_max_iterations_is_not_a_solution() -> None:
    prob, _ = eq_ineq_problem()
    sol = solvers.solve_qp(prob, "osqp", max_iter=1, eps_abs=1e-12, eps_rel=1e-12)
    assert sol.status is Status.MAX_ITER
    assert not sol.ok and not sol.usable(accept_inaccurate=True)


def test_unknown_solver_lists_available() -> None:
    prob, _ = eq_ineq_problem()
    with pytest.raises(solvers.UnknownSolverError, match=r"available: .*clarabel"):
        solvers.solve_qp(prob, "gurobi-free")


@pytest.mark.parametrize("backend", ["osqp", "clarabel"])
def test_unknown_setting_raises_settings_error(backend: str) -> None:
    prob, _ = eq_ineq_problem()
    with pytest.raises(solvers.SettingsError):
        solvers.open_session(prob, backend, no_such_option=1)


def test_osqp_names_a_refused_setting_and_prints_nothing(capfd: pytest.CaptureFixture[str]) -> None:
    """OSQP's C code prints its refusal; the layer's exception carries it, the terminal gets none."""
    prob, _ = eq_ineq_problem()
    with pytest.raises(solvers.SettingsError, match="eps_abs must be nonnegative"):
        solvers.open_session(prob, "osqp", eps_abs=-1.0)
    session = solvers.open_session(box_smoothing_problem(), "osqp")
    with pytest.raises(solvers.SettingsError, match="max_iter"):
        session.resume(max_iter=0)
    assert capfd.readouterr() == ("", "")


def test_captured_output_is_per_thread(capsys: pytest.CaptureFixture[str]) -> None:
    """What one thread prints inside a capture is kept from the stream; other threads print as before."""
    import threading

    from solvers.quiet import captured

    inside, go, done = threading.Event(), threading.Event(), threading.Event()

    def capturing() -> None:
        with captured() as buffer:
            print("kept")
            inside.set()
            go.wait(5)
        assert buffer.getvalue() == "kept\n"
        done.set()

    worker = threading.Thread(target=capturing)
    worker.start()
    assert inside.wait(5)
    print("shown")  # the main thread, while the worker captures
    go.set()
    worker.join(5)
    assert done.is_set()
    assert capsys.readouterr().out == "shown\n"


def test_update_with_wrong_size_raises() -> None:
    prob, _ = eq_ineq_problem()
    session = solvers.open_session(prob, "clarabel")
    with pytest.raises(solvers.UpdateError, match="q has 2 values"):
        session.update(q=np.zeros(2))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"q": np.zeros(2)}, "P has shape"),
        ({"b": np.zeros(3)}, "cone dimensions add up"),
        ({"q": np.array([np.nan, 0.0, 0.0])}, "q has non-finite"),
        ({"q": "x"}, "q must be numeric"),
        ({"P": "x"}, "P must be numeric"),
        ({"cones": None}, "cones must be a sequence of Cone"),
        ({"cones": ["x"]}, "cones must be a sequence of Cone"),
    ],
)
def test_malformed_problem_raises(kwargs: dict, message: str) -> None:
    base = {
        "P": sp.eye(3, format="csc"),
        "q": np.zeros(3),
        "A": sp.csc_matrix(np.ones((2, 3))),
        "b": np.zeros(2),
        "cones": (Zero(2),),
    }
    base.update(kwargs)
    if "b" in kwargs:
        base["A"] = sp.csc_matrix(np.ones((3, 3)))
    with pytest.raises(solvers.ProblemError, match=message):
        QPProblem(**base)


def test_problem_keeps_explicit_zeros_in_P() -> None:
    P = sp.csc_matrix((np.array([0.0, 1.0]), np.array([0, 1]), np.array([0, 1, 2])), shape=(2, 2))
    prob = QPProblem(P=P, q=np.zeros(2), A=sp.csc_matrix((0, 2)), b=np.zeros(0), cones=())
    assert prob.P.nnz == 2


def test_rts_matches_dense_least_squares(rng: np.random.Generator) -> None:
    """The smoother's means are the exact minimiser of the weighted least-squares problem."""
    T = 12
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = np.array([[0.3, 0.1], [0.1, 0.2]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.5]])
    x0 = np.array([1.0, -0.5])
    y = rng.normal(size=T)
    w = rng.uniform(0.2, 2.0, size=T)
    w[[3, 7]] = 0.0
    res = rts_smoother(F, Q, H, R, x0[None, :, None], np.zeros((1, 2, 2)), y[None, :, None, None], w[None])
    # Dense normal equations over x_1..x_T (x_0 known).
    n = 2 * T
    Qi = np.linalg.inv(Q)
    A = np.zeros((n, n))
    g = np.zeros(n)
    for t in range(T):
        i = slice(2 * t, 2 * t + 2)
        A[i, i] += Qi
        if t + 1 < T:
            # The step x_{t+2} - F x_{t+1} couples this block i with the next block j.
            j = slice(2 * t + 2, 2 * t + 4)
            A[i, i] += F.T @ Qi @ F
            A[j, i] -= Qi @ F
            A[i, j] -= F.T @ Qi
        if t == 0:
            g[i] += Qi @ F @ x0
        A[i, i] += w[t] * H.T @ H / R[0, 0]
        g[i] += w[t] * H[0] * y[t] / R[0, 0]
    expected = np.linalg.solve(A, g).reshape(T, 2)
    np.testing.assert_allclose(res.means[0, 1:, :, 0], expected, atol=1e-9)
    np.testing.assert_allclose(res.means[0, 0, :, 0], x0)


@pytest.mark.parametrize("H", [[[1.0, 0.0]], [[0.6, -0.8]], [[1.0, 0.0], [0.3, 1.0]]])
def test_rts_noise_is_the_whitened_difference_of_its_means(rng: np.random.Generator, H: list) -> None:
    """With a process noise of the states' size (nothing cancels), the noise of the adjoint recursion
    is ``L^-1 (x_t - F x_{t-1})`` of the smoothed means, for a picked component, a mixed scalar
    measurement and a vector one."""
    T, K = 15, 2
    F = np.array([[1.0, 0.5], [0.0, 1.0]])
    Q = np.array([[0.3, 0.1], [0.1, 0.2]])
    Hm = np.array(H)
    p = Hm.shape[0]
    x0 = rng.normal(size=(2, 2, K))
    y = rng.normal(size=(2, T, p, K))
    w = rng.uniform(0.2, 2.0, size=(2, T))
    w[:, [3, 4, 9]] = 0.0
    res = rts_smoother(F, Q, Hm, 0.5 * np.eye(p), x0, np.zeros((2, 2, 2)), y, w)
    means = res.means
    diff = means[:, 1:] - np.einsum("ij,btjk->btik", F, means[:, :-1])
    expected = np.linalg.solve(np.linalg.cholesky(Q), diff)
    np.testing.assert_allclose(res.noise, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.prior, 0.5 * np.einsum("btik,btik->bk", expected, expected), rtol=1e-12)


def test_rts_rejects_bad_shapes() -> None:
    with pytest.raises(solvers.ProblemError, match="weight has shape"):
        rts_smoother(
            np.eye(2),
            np.eye(2),
            np.ones((1, 2)),
            np.eye(1),
            np.zeros((1, 2, 1)),
            np.zeros((1, 2, 2)),
            np.zeros((1, 3, 1, 1)),
            np.ones((2, 3)),
        )


def test_retry_chain_runs_in_order_skips_the_callers_and_stops_on_infeasibility() -> None:
    failed = QPSolution(Status.MAX_ITER, "x", "max iterations")
    good = QPSolution(Status.OPTIMAL, "x", "solved", x=np.zeros(1))
    tried: list[dict] = []

    def attempt(settings: dict) -> QPSolution:
        tried.append(settings)
        return good if settings.get("rho") == 30 else failed

    chain = solvers.RetryChain(({"rho": 100}, {"rho": 30}, {"rho": 1}))
    out, used = solvers.retry_failed(failed, {"eps": 1}, chain, attempt)
    assert out is good and used == {"eps": 1, "rho": 30}
    assert tried == [{"eps": 1, "rho": 100}, {"eps": 1, "rho": 30}]
    assert out.info["fallback"] == {"rho": 30} and out.info["first_status"] == "max iterations"
    # The caller chose rho: nothing is tried; a verdict of infeasibility is final.
    assert chain.without({"rho"}).sets == ()
    infeasible = QPSolution(Status.PRIMAL_INFEASIBLE, "x", "infeasible")
    assert solvers.retry_failed(infeasible, {}, chain, attempt) == (infeasible, None)
    tried.clear()
    assert solvers.retry_failed(failed, {}, solvers.RetryChain(({"rho": 5},)), attempt) == (failed, None)
    assert tried == [{"rho": 5}]


def test_one_residual_for_every_cone_kind() -> None:
    np.testing.assert_array_equal(solvers.cone_violation(np.array([0.5, -2.0]), "zero"), [0.5, 2.0])
    np.testing.assert_array_equal(solvers.cone_violation(np.array([0.5, -2.0]), "nonneg"), [0.0, 2.0])
    soc = solvers.cone_violation(np.array([5.0, 3.0, 4.0, 1.0, 3.0, 4.0]), "soc", 3)
    np.testing.assert_allclose(soc, [0.0, 4.0])
    with pytest.raises(solvers.ProblemError, match="cone kind"):
        solvers.cone_violation(np.zeros(2), "psd")


def test_cone_constraints_group_runs_of_equal_cones() -> None:
    import cvxpy as cp

    from solvers.cvxpy_ import cone_constraints

    # max x0 + x1 with x2 = x0, ||(x0, x1)|| <= 1, ||(x1, x2)|| <= 1 and x1 <= 0.5.
    x = cp.Variable(3)
    slack = cp.hstack([x[2] - x[0], 1.0, x[0], x[1], 1.0, x[1], x[2], 0.5 - x[1]])
    cones = [solvers.Zero(1), solvers.SOC(3), solvers.SOC(3), solvers.Nonneg(1)]
    out = cone_constraints(slack, cones)
    assert len(out) == 3  # the two cones are one vectorised constraint
    cp.Problem(cp.Minimize(-x[0] - x[1]), out).solve(solver="CLARABEL")
    np.testing.assert_allclose(x.value, [np.sqrt(0.75), 0.5, np.sqrt(0.75)], atol=1e-6)


def box_smoothing_problem() -> QPProblem:
    """A smoothing QP in a box: ADMM needs a few hundred iterations at tight tolerances."""
    n = 60
    D = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    return QPProblem(
        P=sp.csc_matrix(sp.triu(D.T @ D + 1e-3 * sp.eye(n))),
        q=-np.random.default_rng(0).normal(size=n),
        A=sp.csc_matrix(sp.vstack([sp.eye(n), -sp.eye(n)])),
        b=np.full(2 * n, 0.5),
        cones=(Nonneg(2 * n),),
    )


#: OSQP settings whose iterations are reproducible (no time-based adaptive rho, a test every step).
EXACT_ITERATIONS = {"eps_abs": 1e-9, "eps_rel": 1e-9, "adaptive_rho": False, "check_termination": 1}


def test_osqp_resume_continues_from_its_iterate() -> None:
    prob = box_smoothing_problem()
    cold = solvers.open_session(prob, "osqp", polishing=False, **EXACT_ITERATIONS).solve()
    assert cold.ok and cold.iterations > 100
    half = cold.iterations // 2
    session = solvers.open_session(prob, "osqp", polishing=False, max_iter=half, **EXACT_ITERATIONS)
    assert session.solve().status is Status.MAX_ITER
    more = session.resume(max_iter=100_000)
    assert more is not None and more.ok
    # Continuing costs only the iterations a single solve would still have needed.
    assert half + more.iterations == cold.iterations
    np.testing.assert_allclose(more.x, cold.x, atol=1e-12)
    # A setting OSQP cannot change in place (rho) needs a new session; Clarabel never resumes.
    assert session.resume(rho=10.0) is None
    assert solvers.open_session(prob, "clarabel").resume(max_iter=5) is None


def test_only_osqp_with_an_adaptive_rho_adapts_to_updates() -> None:
    prob, _ = eq_ineq_problem()
    assert solvers.open_session(prob, "osqp").adapts_to_updates
    assert not solvers.open_session(prob, "osqp", adaptive_rho=False).adapts_to_updates
    assert not solvers.open_session(prob, "clarabel").adapts_to_updates
    assert not solvers.open_session(prob, "cvxpy").adapts_to_updates


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_rescaled_session_solves_as_a_new_one_on_the_same_numbers(backend: str) -> None:
    """After numbers that moved by orders of magnitude, :meth:`rescale` gives the answer of a session
    set up on them, to the last bit; cvxpy keeps its compiled problem for it."""
    # A fixed rho: OSQP's adaptive rho may depend on the setup's timing.
    settings = {"adaptive_rho": False} if backend == "osqp" else {}
    prob, _ = eq_ineq_problem()
    session = solvers.open_session(prob, backend, **settings)
    assert session.solve().ok
    compiled = getattr(session, "_problem", None)
    new_P, new_q = np.array([2e4, 1e4, 3e4]), np.array([-3e3, 2e3, 4e3])
    session.update(P_data=new_P, q=new_q)
    session.rescale()
    rescaled = session.solve()
    fresh_prob = QPProblem(P=sp.diags(new_P, format="csc"), q=new_q, A=prob.A, b=prob.b, cones=prob.cones)
    fresh = solvers.open_session(fresh_prob, backend, **settings).solve()
    assert rescaled.ok and fresh.ok
    np.testing.assert_array_equal(rescaled.x, fresh.x)
    if backend == "cvxpy":
        assert session._problem is compiled


def test_osqp_work_limit_bounds_every_solve_of_the_same_numbers() -> None:
    prob = box_smoothing_problem()
    session = solvers.open_session(prob, "osqp", polishing=False, **EXACT_ITERATIONS, work_limit=1.0)
    assert session.size == prob.P.nnz + prob.A.nnz + prob.n + prob.m
    room = 40
    session = solvers.open_session(
        prob, "osqp", polishing=False, **EXACT_ITERATIONS, work_limit=room * session.size
    )
    first = session.solve()
    assert first.status is Status.MAX_ITER and first.iterations == room
    # Resumed with a far higher iteration limit: the limit on the work still holds.
    spent = session.resume(max_iter=100_000)
    assert spent is not None and spent.status is Status.MAX_ITER and spent.iterations == 0
    assert spent.raw_status == "work limit reached" and not spent.usable(accept_inaccurate=True)
    # New numbers, new work: the limit counts the solves of one set of numbers.
    session.update(q=prob.q * 0.5)
    assert session.solve().iterations == room


@pytest.mark.parametrize("limit", [0, -1.0, float("nan"), float("inf"), True, "1e9"])
def test_osqp_work_limit_must_be_a_positive_finite_number(limit: object) -> None:
    with pytest.raises(solvers.SettingsError, match="work_limit"):
        solvers.open_session(box_smoothing_problem(), "osqp", work_limit=limit)


def test_osqp_polish_tolerance_makes_an_accurate_polish_part_of_solved() -> None:
    prob = box_smoothing_problem()
    exact = solvers.open_session(prob, "osqp", polishing=False, **EXACT_ITERATIONS).solve()
    loose = {"eps_abs": 1e-3, "eps_rel": 1e-3, "polish_tolerance": 1e-10}
    # ADMM's iterate at 1e-3 is solved by OSQP's own test, not by the tolerance.
    session = solvers.open_session(prob, "osqp", polishing=False, **loose)
    admm = session.solve()
    assert admm.status is Status.OPTIMAL_INACCURATE and admm.raw_status == "solved, not polished"
    assert not admm.ok and admm.usable(accept_inaccurate=True)
    # Polished (the active set found, the reduced KKT system refined) it is exact, and solved.
    polished = session.resume(polishing=True)
    assert polished is not None and polished.ok and polished.raw_status == "solved"
    np.testing.assert_allclose(polished.x, exact.x, atol=1e-8)
    # Without the tolerance, OSQP's own verdict stands.
    lifted = session.resume(polishing=False, polish_tolerance=None)
    assert lifted is not None and lifted.ok


@pytest.mark.parametrize("tol", [0, -1.0, float("nan"), True, "1e-9"])
def test_osqp_polish_tolerance_must_be_a_positive_finite_number(tol: object) -> None:
    with pytest.raises(solvers.SettingsError, match="polish_tolerance"):
        solvers.open_session(box_smoothing_problem(), "osqp", polish_tolerance=tol)


def test_a_work_budget_is_shared_by_the_sessions_that_hold_it() -> None:
    prob = box_smoothing_problem()
    first = solvers.open_session(prob, "osqp", polishing=False, **EXACT_ITERATIONS)
    budget = solvers.WorkBudget(100 * first.size)
    first.budget = budget
    assert first.solve().iterations == 100 and budget.spent == 100 * first.size
    # A second session on the same budget finds it spent; one without a budget is not limited.
    second = solvers.open_session(prob, "osqp", polishing=False, **EXACT_ITERATIONS)
    second.budget = budget
    assert second.solve().raw_status == "work limit reached"
    second.budget = None
    assert second.solve().ok
    # Interior-point sessions ignore it.
    clarabel = solvers.open_session(prob, "clarabel")
    clarabel.budget = budget
    assert clarabel.solve().ok


@pytest.mark.parametrize("limit", [0, -1.0, float("nan"), float("inf"), True])
def test_a_work_budget_must_be_a_positive_finite_number(limit: object) -> None:
    with pytest.raises(solvers.SettingsError, match="work budget"):
        solvers.WorkBudget(limit)  # type: ignore[arg-type]


def test_sessions_refuse_what_is_not_a_problem_or_not_numbers() -> None:
    with pytest.raises(solvers.ProblemError, match="cone dimension"):
        Zero("x")  # type: ignore[arg-type]
    with pytest.raises(solvers.ProblemError, match="problem: expected a QPProblem, got NoneType"):
        solvers.solve_qp(None, "clarabel")  # type: ignore[arg-type]
    problem = QPProblem(
        sp.eye(2, format="csc"), np.zeros(2), sp.eye(2, format="csc"), np.ones(2), (Nonneg(2),)
    )
    session = solvers.open_session(problem, "clarabel")
    with pytest.raises(solvers.UpdateError, match="b must be numeric"):
        session.update(b="x")  # type: ignore[arg-type]
