"""The banded KKT smoother: agreement with RTS, with independent references, known answers, errors."""

from __future__ import annotations

import pickle
import threading
from fractions import Fraction

import numpy as np
import pytest
import scipy.linalg

from solvers.banded import BandedSmoother, banded_smoother
from solvers.exceptions import ProblemError
from solvers.kalman import rts_smoother
from studies.smoother_reference import E1, ca_model, rts_extended


def make_batch(
    rng: np.random.Generator, B: int, T: int, K: int = 2, kind: str = "random"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights ``(B, T)``, measurements ``(B, T, K)`` in the 10 x 10 box and starts ``(B, 3, K)``.

    ``coast``: sparse weights up to a third of the horizon, one weighted step at the middle, then
    exact zeros to the end (the path extrapolates with constant acceleration). ``single``: one
    weighted step. ``none``: no weight at all.
    """
    if kind == "random":
        W = rng.random((B, T))
    elif kind == "coast":
        W = rng.random((B, T)) * (rng.random((B, T)) < 0.1)
        W[:, T // 3 :] = 0.0
        W[:, T // 2] = 0.7
    elif kind == "single":
        W = np.zeros((B, T))
        W[:, T // 2] = 1.0
    elif kind == "none":
        W = np.zeros((B, T))
    else:  # pragma: no cover - test helper
        raise ValueError(kind)
    y = rng.uniform(0.0, 10.0, (B, T, K))
    x0 = np.zeros((B, 3, K))
    x0[:, 0, :] = rng.uniform(0.0, 10.0, (B, K))
    x0[:, 1, :] = rng.uniform(-0.05, 0.05, (B, K))
    return W, y, x0


def rts_means(
    F: np.ndarray, Q: np.ndarray, r: float, W: np.ndarray, y: np.ndarray, x0: np.ndarray
) -> np.ndarray:
    """``rts_smoother`` with a known start and the position measured: ``(B, T+1, 3, K)``."""
    B = W.shape[0]
    res = rts_smoother(F, Q, E1[None], np.array([[r]]), x0, np.zeros((B, 3, 3)), y[:, :, None, :], W)
    return res.means


def position_tol(*paths: np.ndarray) -> float:
    """1e-9 for positions of order 10; relative beyond (coasting paths reach 1e4 at dt = 10)."""
    scale = max(float(np.max(np.abs(p[:, :, 0]))) for p in paths)
    return 1e-9 * max(1.0, scale / 10.0)


# -- independent references -------------------------------------------------------------------


def _fr_matmul(A: list[list[Fraction]], B: list[list[Fraction]]) -> list[list[Fraction]]:
    return [
        [sum((A[i][k] * B[k][j] for k in range(len(B))), Fraction(0)) for j in range(len(B[0]))]
        for i in range(len(A))
    ]


def _fr_transpose(A: list[list[Fraction]]) -> list[list[Fraction]]:
    return [list(row) for row in zip(*A, strict=True)]


def _fr_solve(S: list[list[Fraction]], b: list[Fraction]) -> list[Fraction]:
    """Gaussian elimination in exact arithmetic."""
    n = len(b)
    M = [[*S[i], b[i]] for i in range(n)]
    for c in range(n):
        p = next(i for i in range(c, n) if M[i][c] != 0)
        M[c], M[p] = M[p], M[c]
        for i in range(n):
            if i != c and M[i][c] != 0:
                f = M[i][c] / M[c][c]
                M[i] = [a - f * bb for a, bb in zip(M[i], M[c], strict=True)]
    return [M[i][n] / M[i][i] for i in range(n)]


def exact_means_fr(
    F: np.ndarray, Q: np.ndarray, h: np.ndarray, r: float, x0: np.ndarray, y: np.ndarray, w: np.ndarray
) -> list[list[Fraction]]:
    """Posterior mean of one system by Gaussian conditioning, in exact rational arithmetic.

    The prior of ``x_1..x_T`` is Gaussian with means ``F^t x0`` and covariances
    ``Cov(x_s, x_t) = F^(s-t) P_t`` (``s >= t``, ``P_t = F P_{t-1} F' + Q``); the measured steps
    ``y_a = h' x_a + e_a`` give ``E[x_s | y] = m_s + sum_a Cov(x_s, x_a) h beta_a`` with
    ``(h' Cov(x_a, x_b) h + delta_ab r / w_a) beta = y - h' m``. The float data are converted
    exactly, so this is the exact answer for them.
    """
    n, T = F.shape[0], len(w)
    Ff = [[Fraction(float(v)) for v in row] for row in F]
    Qf = [[Fraction(float(v)) for v in row] for row in Q]
    hf = [Fraction(float(v)) for v in h]
    means = [[[Fraction(float(v))] for v in x0]]
    covs = [[[Fraction(0)] * n for _ in range(n)]]
    for _ in range(T):
        means.append(_fr_matmul(Ff, means[-1]))
        P = _fr_matmul(_fr_matmul(Ff, covs[-1]), _fr_transpose(Ff))
        covs.append([[P[i][j] + Qf[i][j] for j in range(n)] for i in range(n)])

    def cross(s: int, t: int) -> list[list[Fraction]]:
        """Cov(x_s, x_t)."""
        if s >= t:
            out = covs[t]
            for _ in range(s - t):
                out = _fr_matmul(Ff, out)
            return out
        return _fr_transpose(cross(t, s))

    def hv(M: list[list[Fraction]]) -> list[Fraction]:  # M h
        return [sum((M[i][j] * hf[j] for j in range(n)), Fraction(0)) for i in range(n)]

    measured = [t + 1 for t in range(T) if w[t] > 0]
    S = [
        [sum((hf[i] * v for i, v in enumerate(hv(cross(a, b)))), Fraction(0)) for b in measured]
        for a in measured
    ]
    for i, a in enumerate(measured):
        S[i][i] += Fraction(float(r)) / Fraction(float(w[a - 1]))
    innov = [
        Fraction(float(y[a - 1])) - sum((hf[j] * means[a][j][0] for j in range(n)), Fraction(0))
        for a in measured
    ]
    beta = _fr_solve(S, innov) if measured else []
    out = []
    for s in range(T + 1):
        col = [means[s][i][0] for i in range(n)]
        for bi, a in zip(beta, measured, strict=True):
            ch = hv(cross(s, a)) if s > 0 else [Fraction(0)] * n
            col = [c + v * bi for c, v in zip(col, ch, strict=True)]
        out.append(col)
    return out


def exact_means(
    F: np.ndarray, Q: np.ndarray, h: np.ndarray, r: float, x0: np.ndarray, y: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """:func:`exact_means_fr` rounded to floats, ``(T+1, n)``."""
    return np.array([[float(c) for c in col] for col in exact_means_fr(F, Q, h, r, x0, y, w)])


def lstsq_means(
    F: np.ndarray, Q: np.ndarray, h: np.ndarray, r: float, x0: np.ndarray, y: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """One system by a dense least-squares solve in the whitened process noise ``u``.

    ``x_t = F^t x0 + sum_{j <= t} F^(t-j) L u_j`` makes the objective ``1/2 ||u||^2 +
    sum_t w_t / (2r) (h' x_t - y_t)^2`` an ordinary least-squares problem in ``u`` whose matrix
    ``[I; diag(sqrt(w / r)) G]`` has singular values at least 1.
    """
    n, T = F.shape[0], len(w)
    L = np.linalg.cholesky(Q)
    G = np.zeros((T, T * n))
    free = np.empty(T)  # h' F^t x0
    x = x0.astype(float)
    powers = [np.eye(n)]
    for _ in range(T):
        powers.append(F @ powers[-1])
    for t in range(1, T + 1):
        x = F @ x
        free[t - 1] = h @ x
        for j in range(1, t + 1):
            G[t - 1, (j - 1) * n : j * n] = h @ powers[t - j] @ L
    sw = np.sqrt(w / r)
    A = np.vstack([np.eye(T * n), sw[:, None] * G])
    rhs = np.concatenate([np.zeros(T * n), sw * (y - free)])
    u = scipy.linalg.lstsq(A, rhs, lapack_driver="gelsy")[0].reshape(T, n)
    out = np.empty((T + 1, n))
    out[0] = x0
    for t in range(1, T + 1):
        out[t] = F @ out[t - 1] + L @ u[t - 1]
    return out


# -- agreement with rts_smoother ----------------------------------------------------------------


@pytest.mark.parametrize("kind", ["random", "coast", "single", "none"])
def test_matches_rts_scenario_a_shape(kind: str) -> None:
    rng = np.random.default_rng(1)
    F, Q = ca_model(1.0, 1e-8)
    W, y, x0 = make_batch(rng, 4, 500, kind=kind)
    res = banded_smoother(F, Q, E1, 1e-2, x0, y, W)
    ref = rts_means(F, Q, 1e-2, W, y, x0)
    assert res.means.shape == ref.shape == (4, 501, 3, 2)
    assert np.max(np.abs(res.means[:, :, 0] - ref[:, :, 0])) <= 1e-9
    np.testing.assert_allclose(res.means, ref, rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(res.means[:, 0], x0)


@pytest.mark.parametrize("dt", [0.01, 1.0, 10.0])
@pytest.mark.parametrize("q", [1e-12, 1e-8, 1e-4])
@pytest.mark.parametrize("r", [1e-8, 1e-2, 1.0])
def test_matches_rts_over_parameter_ranges(dt: float, q: float, r: float) -> None:
    """T = 60 keeps RTS itself accurate in the high signal-to-noise corners (see the extended
    precision test below for what happens to RTS at T = 500)."""
    rng = np.random.default_rng(hash((dt, q, r)) % 2**32)
    F, Q = ca_model(dt, q)
    for kind in ("random", "coast", "single"):
        W, y, x0 = make_batch(rng, 2, 60, kind=kind)
        res = banded_smoother(F, Q, E1, r, x0, y, W)
        ref = rts_means(F, Q, r, W, y, x0)
        err = np.max(np.abs(res.means[:, :, 0] - ref[:, :, 0]))
        assert err <= position_tol(ref), (kind, err)


@pytest.mark.parametrize("T", [2, 3, 17, 5000])
def test_matches_rts_over_horizons(T: int) -> None:
    rng = np.random.default_rng(T)
    F, Q = ca_model(1.0, 1e-8)
    for kind in ("random", "coast"):
        W, y, x0 = make_batch(rng, 2, T, kind=kind)
        res = banded_smoother(F, Q, E1, 1e-2, x0, y, W)
        ref = rts_means(F, Q, 1e-2, W, y, x0)
        assert np.max(np.abs(res.means[:, :, 0] - ref[:, :, 0])) <= position_tol(ref)


def test_generic_model_matches_rts() -> None:
    """A full transition (half-bandwidth 2n - 1), a mixed measurement and one column."""
    rng = np.random.default_rng(7)
    n, B, T = 4, 3, 80
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    A = rng.standard_normal((n, n))
    Q = 0.01 * (A @ A.T + n * np.eye(n))
    h = rng.standard_normal(n)
    W = rng.random((B, T)) * (rng.random((B, T)) < 0.5)
    y = rng.standard_normal((B, T, 1))
    x0 = rng.standard_normal((B, n, 1))
    sm = BandedSmoother(F, Q, h, T, B)
    assert sm.k == 2 * n - 1
    res = sm.solve(0.3, x0, y, W)
    ref = rts_smoother(F, Q, h[None], np.array([[0.3]]), x0, np.zeros((B, n, n)), y[:, :, None, :], W).means
    np.testing.assert_allclose(res.means, ref, rtol=0, atol=1e-11)


@pytest.mark.parametrize("dt", [1e-3, 3e-3, 0.1, 1.0, 10.0])
@pytest.mark.parametrize("r", [1e-2, 1.0])
def test_rts_objective_equals_the_exact_smoothers_at_every_dt(dt: float, r: float) -> None:
    """The prior term of ``rts_smoother`` comes from its adjoint recursion, not from differences of
    smoothed states (which lose every digit once ``q dt^5`` is far below the positions), so its
    process noise and objective are the banded smoother's, taken from the multipliers."""
    rng = np.random.default_rng(11)
    F, Q = ca_model(dt, 1e-8)
    for kind in ("random", "coast"):
        W, y, x0 = make_batch(rng, 3, 120, kind=kind)
        exact = banded_smoother(F, Q, E1, r, x0, y, W)
        res = rts_smoother(F, Q, E1[None], np.array([[r]]), x0, np.zeros((3, 3, 3)), y[:, :, None, :], W)
        objective = res.prior + exact.fit  # the fit term is the same for paths equal to 1e-14
        np.testing.assert_allclose(objective, exact.objective, rtol=1e-9, atol=0)


# -- independent references ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("dt", "q", "r"), [(1.0, 1e-8, 1e-2), (0.01, 1e-12, 1e-8), (10.0, 1e-4, 1.0), (1.0, 1e-4, 1e-8)]
)
def test_exact_rational_reference(dt: float, q: float, r: float) -> None:
    rng = np.random.default_rng(3)
    F, Q = ca_model(dt, q)
    W, y, x0 = make_batch(rng, 1, 6, K=1)
    W[0, [1, 2]] = 0.0  # a coasting stretch inside the horizon
    res = banded_smoother(F, Q, E1, r, x0, y, W)
    exact = exact_means(F, Q, E1, r, x0[0, :, 0], y[0, :, 0], W[0])
    got = res.means[0, :, :, 0]
    np.testing.assert_allclose(got[:, 0], exact[:, 0], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(got, exact, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["random", "coast", "single"])
@pytest.mark.parametrize(("dt", "q", "r"), [(1.0, 1e-8, 1e-2), (1.0, 1e-8, 1.0), (0.1, 1e-4, 1e-2)])
def test_dense_least_squares_reference(kind: str, dt: float, q: float, r: float) -> None:
    rng = np.random.default_rng(5)
    F, Q = ca_model(dt, q)
    W, y, x0 = make_batch(rng, 1, 40, K=1, kind=kind)
    res = banded_smoother(F, Q, E1, r, x0, y, W)
    ref = lstsq_means(F, Q, E1, r, x0[0, :, 0], y[0, :, 0], W[0])
    assert np.max(np.abs(res.means[0, :, 0, 0] - ref[:, 0])) <= 1e-9


@pytest.mark.skipif(
    bool(np.finfo(np.longdouble).eps > 1e-18), reason="needs an extended-precision long double"
)
def test_rts_is_the_less_accurate_at_high_signal_to_noise() -> None:
    """dt = 1, q = 1e-4, r = 1e-8, T = 500 random weights: the variance of one step's position noise
    is 5e4 times the measurement's, and the RTS backward pass (gain ``Pf F' Pp^-1``) amplifies its
    rounding errors with the horizon. Run in extended precision, RTS agrees with the banded solve;
    in double precision it is more than 1e-9 away from both."""
    rng = np.random.default_rng(11)
    F, Q = ca_model(1.0, 1e-4)
    W, y, x0 = make_batch(rng, 1, 500, K=1)
    res = banded_smoother(F, Q, E1, 1e-8, x0, y, W)
    ext = rts_extended(F, Q, E1, 1e-8, x0[0, :, 0], y[0, :, 0], W[0]).astype(float)
    rts = rts_means(F, Q, 1e-8, W, y, x0)[0, :, 0, 0]
    ours = res.means[0, :, 0, 0]
    assert np.max(np.abs(ours - ext[:, 0])) <= 1e-11
    assert np.max(np.abs(rts - ext[:, 0])) > 1e-9


# -- known answers -------------------------------------------------------------------------------


def test_one_step_is_a_kalman_update() -> None:
    F, Q = ca_model(1.0, 1e-2)
    x0 = np.array([1.0, 0.5, -0.1])
    w, r, y = 0.8, 0.05, 3.0
    pred = F @ x0
    gain = Q[:, 0] / (Q[0, 0] + r / w)
    expected = pred + gain * (y - pred[0])
    res = banded_smoother(F, Q, E1, r, x0[None, :, None], np.full((1, 1, 1), y), np.array([[w]]))
    np.testing.assert_allclose(res.means[0, 1, :, 0], expected, rtol=1e-13)


def test_two_steps_by_hand() -> None:
    """T = 2, measured only at t = 2: Gaussian conditioning of (x_1, x_2) on p_2."""
    F, Q = ca_model(1.0, 1e-2)
    x0 = np.array([2.0, -0.3, 0.05])
    w2, r, y2 = 0.5, 0.01, 1.5
    m1, m2 = F @ x0, F @ F @ x0
    P2 = F @ Q @ F.T + Q
    cov_x1_p2 = (Q @ F.T)[:, 0]  # Cov(x_1, x_2) = Q F' (x_1 = F x0 + v_1, x_2 = F x_1 + v_2)
    cov_x2_p2 = P2[:, 0]
    s = P2[0, 0] + r / w2
    x1 = m1 + cov_x1_p2 * (y2 - m2[0]) / s
    x2 = m2 + cov_x2_p2 * (y2 - m2[0]) / s
    res = banded_smoother(F, Q, E1, r, x0[None, :, None], np.array([[[7.0], [y2]]]), np.array([[0.0, w2]]))
    np.testing.assert_allclose(res.means[0, 1, :, 0], x1, rtol=1e-12)
    np.testing.assert_allclose(res.means[0, 2, :, 0], x2, rtol=1e-12)


def test_no_weight_coasts_with_constant_acceleration() -> None:
    F, Q = ca_model(1.0, 1e-8)
    x0 = np.array([[1.0, 3.0], [0.2, -0.1], [0.01, 0.0]])[None]
    res = banded_smoother(F, Q, E1, 1e-2, x0, np.zeros((1, 30, 2)), np.zeros((1, 30)))
    expected = [x0[0]]
    for _ in range(30):
        expected.append(F @ expected[-1])
    np.testing.assert_allclose(res.means[0], np.array(expected), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(res.objective, 0.0, atol=1e-30)


# -- objective and noise -------------------------------------------------------------------------


def test_objective_parts_match_their_definitions() -> None:
    rng = np.random.default_rng(2)
    F, Q = ca_model(1.0, 1e-4)
    W, y, x0 = make_batch(rng, 3, 200, kind="coast")
    r = 1e-2
    res = banded_smoother(F, Q, E1, r, x0, y, W)
    L = np.linalg.cholesky(Q)
    X = res.means
    diff = X[:, 1:] - np.einsum("ij,btjk->btik", F, X[:, :-1])
    u = np.linalg.solve(L, diff.transpose(0, 3, 2, 1)).transpose(0, 3, 2, 1)  # (B, T, 3, K)
    np.testing.assert_allclose(res.noise, u, rtol=1e-6, atol=1e-9)
    prior = 0.5 * np.sum(u * u, axis=(1, 2))
    fit = np.sum(W[..., None] / (2 * r) * (X[:, 1:, 0] - y) ** 2, axis=1)
    np.testing.assert_allclose(res.prior, prior, rtol=1e-8)
    np.testing.assert_allclose(res.fit, fit, rtol=1e-10)
    np.testing.assert_allclose(res.objective, prior + fit, rtol=1e-8)


def test_objective_is_minimal() -> None:
    rng = np.random.default_rng(4)
    F, Q = ca_model(1.0, 1e-4)
    W, y, x0 = make_batch(rng, 1, 50, K=1)
    r = 0.1
    res = banded_smoother(F, Q, E1, r, x0, y, W)
    Qi = np.linalg.inv(Q)

    def J(X: np.ndarray) -> float:
        d = X[1:] - X[:-1] @ F.T
        return float(
            0.5 * np.einsum("ti,ij,tj->", d, Qi, d) + np.sum(W[0] / (2 * r) * (X[1:, 0] - y[0, :, 0]) ** 2)
        )

    X = res.means[0, :, :, 0]
    assert J(X) == pytest.approx(float(res.objective[0, 0]), rel=1e-9)
    for _ in range(5):
        bump = np.zeros_like(X)
        bump[1:] = 1e-3 * rng.standard_normal((50, 3)) * np.sqrt(np.diag(Q))
        assert J(X + bump) > J(X)


def test_noise_keeps_its_precision_when_q_dt5_is_tiny() -> None:
    """dt = 0.01, q = 1e-12: one step's position noise has a standard deviation near 2e-12 against
    positions of order 10, so ``x_t - F x_{t-1}`` formed from the states in floating point has
    almost no correct digit; the noise from the multipliers matches the exact rational answer."""
    rng = np.random.default_rng(9)
    F, Q = ca_model(0.01, 1e-12)
    W, y, x0 = make_batch(rng, 1, 5, K=1)
    res = banded_smoother(F, Q, E1, 1e-2, x0, y, W)
    X = exact_means_fr(F, Q, E1, 1e-2, x0[0, :, 0], y[0, :, 0], W[0])
    Ff = [[Fraction(float(v)) for v in row] for row in F]
    diffs = np.array(
        [
            [float(X[t][i] - sum((Ff[i][j] * X[t - 1][j] for j in range(3)), Fraction(0))) for i in range(3)]
            for t in range(1, 6)
        ]
    )
    L = np.linalg.cholesky(Q)
    exact = np.linalg.solve(L, diffs.T).T  # (T, 3); each difference is exact before rounding
    ours = res.noise[0, :, :, 0]
    np.testing.assert_allclose(ours, exact, rtol=1e-9, atol=1e-9 * np.max(np.abs(exact)))
    naive = np.linalg.solve(L, (res.means[0, 1:, :, 0] - res.means[0, :-1, :, 0] @ F.T).T).T
    assert np.max(np.abs(naive - exact)) > 1e-2 * np.max(np.abs(exact))


# -- precision diagnostics -----------------------------------------------------------------------


def test_refinement_brings_backward_error_to_rounding_level() -> None:
    rng = np.random.default_rng(6)
    F, Q = ca_model(10.0, 1e-4)
    W, y, x0 = make_batch(rng, 2, 300, kind="coast")
    refined = banded_smoother(F, Q, E1, 1e-8, x0, y, W, check=True)
    plain = banded_smoother(F, Q, E1, 1e-8, x0, y, W, refine=0, check=True)
    assert refined.backward_error is not None and plain.backward_error is not None
    assert refined.backward_error < 1e-12
    assert plain.backward_error > refined.backward_error


def test_batch_and_columns_are_independent() -> None:
    rng = np.random.default_rng(8)
    F, Q = ca_model(1.0, 1e-8)
    W, y, x0 = make_batch(rng, 3, 100, K=3, kind="coast")
    together = banded_smoother(F, Q, E1, 1e-2, x0, y, W).means
    for b in range(3):
        for k in range(3):
            alone = banded_smoother(
                F, Q, E1, 1e-2, x0[b : b + 1, :, k : k + 1], y[b : b + 1, :, k : k + 1], W[b : b + 1]
            )
            np.testing.assert_allclose(together[b, :, :, k], alone.means[0, :, :, 0], rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("K", [1, 2, 3])
def test_side_by_side_is_the_means_and_noise_laid_out(K: int) -> None:
    rng = np.random.default_rng(9)
    F, Q = ca_model(1.0, 1e-6)
    W, y, x0 = make_batch(rng, 4, 60, K=K, kind="coast")
    res = banded_smoother(F, Q, E1, 1e-2, x0, y, W)
    # The parts are formed on first use, from the data as they were passed: the result does not read
    # the caller's arrays again.
    y_passed, x0_passed = y.copy(), x0.copy()
    y += 1.0
    x0 += 1.0
    states, noise = res.side_by_side()  # formed before the means: no shared cache decides the values
    assert states.shape == (4, 61, 3 * K) and noise.shape == (4, 60, 3 * K)
    for k in range(K):
        np.testing.assert_array_equal(states[:, :, 3 * k : 3 * k + 3], res.means[..., k])
        np.testing.assert_array_equal(noise[:, :, 3 * k : 3 * k + 3], res.noise[..., k])
    np.testing.assert_array_equal(res.means[:, 0], x0_passed)
    # What a caller does to the arrays it gets changes nothing the result forms later.
    u = res.noise.copy()
    noise[:] = 0.0
    res.noise[:] = 0.0
    np.testing.assert_array_equal(res.side_by_side()[1][:, :, 0:3], u[..., 0])
    np.testing.assert_allclose(res.prior, 0.5 * np.einsum("btik,btik->bk", u, u), rtol=1e-13)
    innov = y_passed - res.means[:, 1:, 0, :]
    np.testing.assert_allclose(res.fit, 0.5 * np.einsum("bt,btk->bk", W / 1e-2, innov**2), rtol=1e-12)


def test_a_measured_component_alone_gives_the_general_products_bit_for_bit() -> None:
    """Where ``h`` picks one component the penalty's products work on that column only; the answer,
    its noise and objective are those of the general products, to the last bit."""
    rng = np.random.default_rng(12)
    F, Q = ca_model(1.0, 1e-8)
    sm = BandedSmoother(F, Q, E1, 300, 3)
    W, y, x0 = make_batch(rng, 3, 300)
    W[:, 100:250] = 0.0  # a coasting stretch: the refinement step's correction matters there
    fast = sm.solve(1e-4, x0, y, W)
    assert sm._pick is not None
    sm._pick = None
    general = sm.solve(1e-4, x0, y, W)
    for name in ("means", "noise", "prior", "fit"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(general, name), err_msg=name)


def test_instance_is_reusable_across_threads_and_pickles() -> None:
    rng = np.random.default_rng(10)
    F, Q = ca_model(1.0, 1e-8)
    sm = BandedSmoother(F, Q, E1, 200, 4)
    batches = [make_batch(rng, 4, 200) for _ in range(4)]
    expected = [sm.solve(1e-2, x0, y, W).means for W, y, x0 in batches]
    out: list[np.ndarray | None] = [None] * 4

    def work(i: int) -> None:
        for _ in range(3):
            W, y, x0 = batches[i]
            out[i] = sm.solve(1e-2, x0, y, W).means

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for got, exp in zip(out, expected, strict=True):
        np.testing.assert_array_equal(got, exp)
    clone = pickle.loads(pickle.dumps(sm))
    W, y, x0 = batches[0]
    np.testing.assert_array_equal(clone.solve(1e-2, x0, y, W).means, expected[0])


@pytest.mark.parametrize("kind", ["random", "coast"])
def test_threads_change_no_digit(kind: str) -> None:
    """The batch split over threads gives the single-threaded answer bit for bit."""
    rng = np.random.default_rng(11)
    F, Q = ca_model(0.1, 1e-4)
    W, y, x0 = make_batch(rng, 5, 1200, kind=kind)
    sm = BandedSmoother(F, Q, E1, 1200, 5)
    assert len(sm._parts()) == 5  # the size is large enough to be split, one system per part
    one = sm.solve(1e-2, x0, y, W, threads=1, check=True)
    for threads in (2, 3, 8):
        got = sm.solve(1e-2, x0, y, W, threads=threads, check=True)
        for name in ("means", "noise", "prior", "fit"):
            np.testing.assert_array_equal(getattr(got, name), getattr(one, name), err_msg=name)
        assert got.backward_error == one.backward_error


def test_threads_change_no_digit_for_a_wide_band(monkeypatch: pytest.MonkeyPatch) -> None:
    """With a half-bandwidth above 64 LAPACK factorises in blocks of columns counted from the start of
    each call, so another split into parts can change digits (with SciPy's bundled OpenBLAS, three
    parts instead of two do at this size): the parts are fixed by the batch's size, and the thread
    count still changes nothing. (Parts of fewer steps than the default keep the band small: 8k rows
    instead of the 130k it takes to split a batch at the default size.)"""
    from solvers.banded import smoother as banded

    monkeypatch.setattr(banded, "MIN_STEPS_PER_THREAD", 60)
    rng = np.random.default_rng(15)
    n, T, B = 33, 20, 6
    F = np.eye(n) + 0.01 * rng.normal(size=(n, n))  # a general F: half-bandwidth 2n - 1 = 65
    L = 0.1 * np.tril(rng.normal(size=(n, n))) + np.eye(n)
    Q = L @ L.T
    h = np.zeros(n)
    h[0] = 1.0
    sm = BandedSmoother(F, Q, h, T, B)
    assert sm.k > 64 and len(sm._parts()) > 1
    W = rng.random((B, T))
    y = rng.normal(size=(B, T, 2))
    x0 = rng.normal(size=(B, n, 2))
    one = sm.solve(0.5, x0, y, W, threads=1)
    for threads in (2, 3):
        np.testing.assert_array_equal(sm.solve(0.5, x0, y, W, threads=threads).means, one.means)
    monkeypatch.setattr(banded, "MIN_STEPS_PER_THREAD", 40)  # the parts follow the constant
    assert len(sm._parts()) == 3
    np.testing.assert_allclose(sm.solve(0.5, x0, y, W, threads=2).means, one.means, rtol=1e-6, atol=1e-9)


def test_band_lu_without_exported_lapack(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where SciPy exports no LAPACK pointers, the f2py path gives the same answer on one thread."""
    from solvers import band_lu

    rng = np.random.default_rng(13)
    F, Q = ca_model(0.1, 1e-4)
    W, y, x0 = make_batch(rng, 4, 600, kind="coast")
    sm = BandedSmoother(F, Q, E1, 600, 4)
    expected = sm.solve(1e-2, x0, y, W, threads=2)
    monkeypatch.setattr(band_lu, "_GBSV", None)
    got = sm.solve(1e-2, x0, y, W, threads=2)
    np.testing.assert_array_equal(got.means, expected.means)


def test_band_lu_refuses_what_lapack_would_misread() -> None:
    from solvers.band_lu import BandLU

    band, b = np.zeros((10, 20), order="F"), np.zeros((20, 2), order="F")
    with pytest.raises(ValueError, match="Fortran"):
        BandLU(np.zeros((10, 20)), 3, b, [(0, 20)])
    with pytest.raises(ValueError, match="float64"):
        BandLU(band.astype(np.float32), 3, b, [(0, 20)])
    with pytest.raises(ValueError, match="fit"):
        BandLU(band, 2, b, [(0, 20)])
    band[6] = 1.0  # the identity: factorised, then solve's right-hand sides are checked too
    fact = BandLU(band.copy(order="F"), 3, b.copy(order="F"), [(0, 20)])
    for bad in (
        np.zeros((20, 2)),
        np.zeros((19, 2), order="F"),
        np.zeros((20, 2), dtype=np.float32, order="F"),
    ):
        with pytest.raises(ValueError, match="right-hand sides"):
            fact.solve(bad)
    for parts in ([(0, 10)], [(0, 10), (12, 20)], [(0, 25)], [(5, 20)], [(0, 0), (0, 20)], []):
        with pytest.raises(ValueError, match="cover"):
            BandLU(band.copy(order="F"), 3, b.copy(order="F"), parts)


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, None, "2"])
def test_bad_threads_raise(threads: object) -> None:
    F, Q, W, y, x0 = _good()
    with pytest.raises(ProblemError, match="threads"):
        banded_smoother(F, Q, E1, 1e-2, x0, y, W, threads=threads)  # type: ignore[arg-type]


def test_singular_system_is_a_problem_error() -> None:
    """A zero pivot is a ProblemError naming the singular system, not a LAPACK code."""
    F, Q = ca_model(1.0, 1e-8)
    W, y, x0 = make_batch(np.random.default_rng(14), 2, 50)
    sm = BandedSmoother(F, Q, E1, 50, 2)
    sm._band_T[:] = 0.0  # every entry of the assembled matrix zero: singular
    with pytest.raises(ProblemError, match="singular"):
        sm.solve(1e-2, x0, y, np.zeros_like(W))


# -- bad inputs ----------------------------------------------------------------------------------


def _good() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    F, Q = ca_model(1.0, 1e-8)
    W, y, x0 = make_batch(np.random.default_rng(0), 2, 10)
    return F, Q, W, y, x0


@pytest.mark.parametrize(
    "change",
    [
        "x0_shape",
        "x0_2d",
        "y_shape",
        "y_columns",
        "weight_shape",
        "weight_1d",
        "weight_negative",
        "weight_nan",
        "y_nan",
        "x0_inf",
        "weight_overflow",
        "r_zero",
        "r_negative",
        "r_nan",
        "refine_negative",
    ],
)
def test_bad_data_raise(change: str) -> None:
    F, Q, W, y, x0 = _good()
    r = 1e-2
    refine = 1
    if change == "x0_shape":
        x0 = x0[:, :2]
    elif change == "x0_2d":
        x0 = x0[:, :, 0]
    elif change == "y_shape":
        y = y[:, :-1]
    elif change == "y_columns":
        y = y[:, :, :1]
    elif change == "weight_shape":
        W = W[:1]
    elif change == "weight_1d":
        W = W[0]
    elif change == "weight_negative":
        W[1, 3] = -1e-300
    elif change == "weight_nan":
        W[0, 0] = np.nan
    elif change == "y_nan":
        y[0, 4, 1] = np.nan
    elif change == "x0_inf":
        x0[1, 0, 0] = np.inf
    elif change == "weight_overflow":
        W[0, 0] = 1e300
        r = 1e-20
    elif change == "r_zero":
        r = 0.0
    elif change == "r_negative":
        r = -1.0
    elif change == "r_nan":
        r = float("nan")
    elif change == "refine_negative":
        refine = -1
    with pytest.raises(ProblemError):
        banded_smoother(F, Q, E1, r, x0, y, W, refine=refine)


@pytest.mark.parametrize(
    "change", ["F_nonsquare", "F_nan", "Q_shape", "Q_asymmetric", "Q_indefinite", "h_zero", "h_shape"]
)
def test_bad_model_raises(change: str) -> None:
    F, Q = ca_model(1.0, 1e-8)
    h = E1.copy()
    if change == "F_nonsquare":
        F = F[:2]
    elif change == "F_nan":
        F = F.copy()
        F[0, 1] = np.nan
    elif change == "Q_shape":
        Q = Q[:2, :2]
    elif change == "Q_asymmetric":
        Q = Q.copy()
        Q[0, 1] *= 2
    elif change == "Q_indefinite":
        Q = -Q
    elif change == "h_zero":
        h = np.zeros(3)
    elif change == "h_shape":
        h = np.ones(2)
    with pytest.raises(ProblemError):
        BandedSmoother(F, Q, h, 10, 2)


@pytest.mark.parametrize(("horizon", "batch"), [(0, 1), (5, 0), (2.5, 1)])
def test_bad_sizes_raise(horizon: float, batch: int) -> None:
    F, Q = ca_model(1.0, 1e-8)
    with pytest.raises(ProblemError):
        BandedSmoother(F, Q, E1, horizon, batch)  # type: ignore[arg-type]
