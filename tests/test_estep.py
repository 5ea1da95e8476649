"""E-step weights against a direct computation, prior updates, and robustness."""

from __future__ import annotations

import dataclasses
import tracemalloc
from typing import Any

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.special import logsumexp

from pmht_opt.estep import estep, estep_scored, log_likelihood
from pmht_opt.estep.dense import platform_sums
from pmht_opt.estep.weights import WEIGHTS
from pmht_opt.exceptions import ConfigError


def brute_force(
    z: np.ndarray, pos: np.ndarray, log_tau: np.ndarray, log_k: np.ndarray, r: float
) -> np.ndarray:
    N = z.shape[0]
    M, T, _ = pos.shape
    ll = np.empty((N, T, M))
    for n in range(N):
        for t in range(T):
            for m in range(M):
                d2 = np.sum((z[n] - pos[m, t]) ** 2)
                ll[n, t, m] = log_tau[n, t] + log_k[n, m] - d2 / (2 * r) - np.log(2 * np.pi * r)
    return ll


def test_weights_match_direct_formula(rng: np.random.Generator) -> None:
    N, T, M, r = 5, 7, 3, 0.05
    z = rng.uniform(0, 3, (N, 2))
    pos = rng.uniform(0, 3, (M, T, 2))
    tau = rng.dirichlet(np.ones(T), size=N)
    k = rng.dirichlet(np.ones(M), size=N)
    es = estep(z, pos, np.log(tau), np.log(k), r)
    ll = brute_force(z, pos, np.log(tau), np.log(k), r)
    lse = logsumexp(ll, axis=(1, 2))
    np.testing.assert_allclose(es.weights_ntm(), np.exp(ll - lse[:, None, None]), atol=1e-12)
    np.testing.assert_allclose(es.log_normaliser, lse, rtol=1e-12)
    w = es.weights_ntm()
    np.testing.assert_allclose(es.W, w.sum(axis=0))
    np.testing.assert_allclose(es.WZ, np.einsum("ntm,nd->tmd", w, z))
    np.testing.assert_allclose(es.time_prior(), w.sum(axis=2))
    np.testing.assert_allclose(es.platform_prior(), w.sum(axis=1))
    np.testing.assert_allclose(es.time_prior().sum(axis=1), 1.0)


def test_weights_that_mostly_underflow_match_the_direct_formula(rng: np.random.Generator) -> None:
    """Small ``r`` over a wide field: most log weights lie below -746, where only the others'
    exponentials are formed; the weights are still the direct formula's, with exact zeros there and
    the subnormal range (log weights between -746 and -708) kept."""
    N, T, M, r = 6, 40, 3, 1e-3
    z = rng.uniform(0, 3, (N, 2))
    pos = rng.uniform(0, 3, (M, T, 2))
    pos[0, 0] = z[0] + [np.sqrt(2 * r * 730.0), 0.0]  # a weight of about e^-730 relative to the best
    pos[1, 0] = z[0]
    tau = rng.dirichlet(np.ones(T), size=N)
    k = rng.dirichlet(np.ones(M), size=N)
    ll = brute_force(z, pos, np.log(tau), np.log(k), r)
    rel = ll - ll.max(axis=(1, 2), keepdims=True)
    assert np.mean(rel < -746) > 0.5  # the path that gathers the survivors
    es = estep(z, pos, np.log(tau), np.log(k), r)
    lse = logsumexp(ll, axis=(1, 2))
    w = es.weights_ntm()
    np.testing.assert_allclose(w, np.exp(ll - lse[:, None, None]), rtol=1e-9, atol=1e-300)
    assert np.all(w[rel < -746] == 0.0)
    assert 0.0 < w[0, 0, 0] < 1e-300  # subnormal, not flushed
    np.testing.assert_allclose(es.log_normaliser, lse, rtol=1e-12)


def test_uniform_priors_are_the_default(rng: np.random.Generator) -> None:
    N, T, M = 4, 6, 2
    z = rng.uniform(0, 1, (N, 2))
    pos = rng.uniform(0, 1, (M, T, 2))
    a = estep(z, pos, None, None, 0.01)
    b = estep(z, pos, np.full((N, T), -np.log(T)), np.full((N, M), -np.log(M)), 0.01)
    np.testing.assert_allclose(a.weights, b.weights, atol=1e-14)
    np.testing.assert_allclose(a.log_normaliser, b.log_normaliser)


def test_zero_priors_get_zero_weight(rng: np.random.Generator) -> None:
    N, T, M = 3, 5, 2
    z = rng.uniform(0, 1, (N, 2))
    pos = rng.uniform(0, 1, (M, T, 2))
    with np.errstate(divide="ignore"):
        log_k = np.log(np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]]))
    es = estep(z, pos, None, log_k, 0.01)
    w = es.weights_ntm()
    assert np.all(w[0, :, 1] == 0) and np.all(w[1, :, 0] == 0)
    np.testing.assert_allclose(w.sum(axis=(1, 2)), 1.0)


def test_far_paths_do_not_underflow_to_nan() -> None:
    """Likelihoods exp(-d^2 / 2r) are all zero in double precision here; weights must still exist."""
    z = np.array([[0.0, 0.0], [5.0, 5.0]])
    pos = np.array([[[100.0, 0.0], [200.0, 0.0]], [[0.0, 300.0], [0.0, 400.0]]])  # (M=2, T=2, 2)
    es = estep(z, pos, None, None, 0.01)
    assert np.all(np.isfinite(es.weights)) and np.all(np.isfinite(es.log_normaliser))
    # Locale 0 is nearest to platform 0 at t=1 (distance 100 against 300).
    assert es.map_assignment()[0][0] == 0 and es.map_assignment()[1][0] == 1


def test_extreme_but_finite_coordinates_give_finite_weights() -> None:
    z = np.array([[0.0, 0.0], [1.0, 1.0]])
    pos = np.array([[[1e200, 1e200], [1e250, -1e250]], [[-1e300, 0.0], [3e200, 1.0]]])
    es = estep(z, pos, None, None, 0.01)
    assert np.all(np.isfinite(es.weights))
    np.testing.assert_allclose(es.weights.sum(axis=1), 1.0)
    assert not np.any(np.isnan(es.log_normaliser))
    # All mass on the nearest pair: platform 0 at t=1 is at distance ~1.4e200, the nearest.
    assert es.map_assignment()[0][0] == 0


def test_the_summary_of_dense_weights_is_scipys_matrix_of_the_floored_array(rng: np.random.Generator) -> None:
    """The dense E-step's summary is formed a few rows at a time; it must be the very matrix scipy
    builds from the floored array (same entries, column order and index type), whatever the floor,
    including rows with nothing kept and a floor that keeps nothing."""
    import scipy.sparse as sp

    N, T, M = 40, 9000, 3  # several blocks of rows
    z = rng.uniform(0, 3, (N, 2))
    pos = rng.uniform(0, 3, (M, T, 2))
    es = estep(z, pos, None, None, 0.02)
    assert not es.gated
    es.weights[3, :100] = 0.0  # exact zeros, which scipy never keeps
    for floor in (0.0, 1e-12, 1e-4, 2.0):
        got = es.summary(floor).weights
        want = sp.csr_matrix(np.where(es.weights >= floor, es.weights, 0.0))
        assert got.shape == want.shape and got.has_sorted_indices
        assert got.indices.dtype == want.indices.dtype
        np.testing.assert_array_equal(got.indptr, want.indptr)
        np.testing.assert_array_equal(got.indices, want.indices)
        np.testing.assert_array_equal(got.data, want.data)


def _paths(seed: int, N: int, T: int, M: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0, 10, (N, 2))
    pos = np.cumsum(rng.normal(0, 0.1, (M, T, 2)), axis=1) + rng.uniform(2, 8, (M, 1, 2))
    return z, pos


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("priors", [False, True])
def test_dense_statistics_are_those_of_a_pass_over_the_weights(seed: int, priors: bool) -> None:
    """The dense E-step forms its rows' statistics block by block without keeping the weights; they
    equal bit for bit those of a pass over the weights, which are recomputed when read."""
    z, pos = _paths(seed, 150, 700, 3)  # several blocks of rows
    rng = np.random.default_rng(seed)
    lt = np.log(rng.dirichlet(np.ones(700), 150)) if priors else None
    lk = np.log(rng.dirichlet(np.ones(3), 150)) if priors else None
    es = estep(z, pos, lt, lk, 0.3, gate=None, threads=2)
    assert WEIGHTS.unread(es) is not None
    stats = (es.platform_prior(), es.time_prior(), *es.map_assignment(), es.max_weight())
    summary = es.summary(1e-9)
    assert WEIGHTS.unread(es) is not None  # none of these formed the weights
    w = es.weights
    assert isinstance(w, np.ndarray) and w.shape == (150, 700 * 3)
    bare = dataclasses.replace(es, platform_totals=None, best_column=None, largest=None, time_totals=None)
    bare.inputs = None  # a pass over the stored array, as before the weights were recomputed
    w3 = w.reshape(150, 700, 3)
    expected = (w3.sum(axis=1), w3.sum(axis=2), *bare.map_assignment(), w.max(axis=1))
    for got, want in zip(stats, expected, strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.argmax(w, axis=1) % 3, stats[2])
    floored = sp.csr_matrix(np.where(w >= 1e-9, w, 0.0))
    for part in ("data", "indices", "indptr"):
        np.testing.assert_array_equal(getattr(summary.weights, part), getattr(floored, part))
    # The recomputed weights are the dense E-step's: the rows sum to one, with the direct formula.
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-12)


def test_time_totals_left_to_a_read_are_the_same() -> None:
    """Without ``time_totals`` a dense E-step leaves the time prior to a recompute of its weights:
    the same numbers to the last bit, and nothing else changes."""
    z, pos = _paths(2, 90, 300, 4)
    full = estep(z, pos, None, None, 0.2, gate=None, threads=2)
    lean = estep(z, pos, None, None, 0.2, gate=None, threads=2, time_totals=False)
    assert full.time_totals is not None and lean.time_totals is None
    np.testing.assert_array_equal(lean.time_prior(), full.time_prior())
    for name in ("W", "WZ", "log_normaliser", "platform_totals", "best_column", "largest"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(full, name))


@pytest.mark.parametrize(
    ("r", "score_at", "gate", "far", "gated"),
    [
        (0.5, 0.8, "auto", False, (False, False)),  # both dense: the distances shared
        (0.5, 0.8, None, False, (False, False)),
        (0.5, 0.8, "auto", True, (False, False)),  # a far locale, through hypot
        (0.002, 0.003, "auto", False, (True, True)),
        (0.002, 3.0, "auto", False, (True, False)),
        (0.5, 0.002, "auto", False, (False, True)),
        (0.002, 0.003, 4.0, False, (True, True)),  # a margin of its own
        (0.5, 3.0, 4.0, False, (False, False)),
    ],
)
@pytest.mark.parametrize("priors", [False, True])
@pytest.mark.parametrize("threads", [1, 2])
def test_a_scored_estep_is_the_estep_and_the_log_likelihood(
    r: float,
    score_at: float,
    gate: str | None,
    far: bool,
    gated: tuple[bool, bool],
    priors: bool,
    threads: int,
) -> None:
    """``estep_scored`` gives ``estep``'s result and ``log_likelihood``'s number to the last bit,
    whichever of the two is gated."""
    from pmht_opt.estep.gating import gate_margin, gated_log_normalisers
    from pmht_opt.estep.likelihood import EStepInputs

    z, pos = _paths(5, 120, 400, 3)
    if far:
        z[7] = [1e120, -3e119]
    rng = np.random.default_rng(5)
    lt = np.log(rng.dirichlet(np.ones(400), 120)) if priors else None
    lk = np.log(rng.dirichlet(np.ones(3), 120)) if priors else None
    es, score = estep_scored(z, pos, lt, lk, r, score_at, gate=gate, threads=threads, time_totals=priors)
    want = estep(z, pos, lt, lk, r, gate=gate, threads=threads, time_totals=priors)
    assert score == log_likelihood(z, pos, lt, lk, score_at, gate=gate, threads=threads)
    margin = gate_margin(gate, 400, 3)
    scored = EStepInputs(z, pos, lt, lk, score_at)
    assert (es.gated, margin is not None and gated_log_normalisers(scored, margin) is not None) == gated
    names = ("W", "WZ", "log_normaliser", "platform_totals", "best_column", "largest", "time_totals")
    for name in names:
        np.testing.assert_array_equal(getattr(es, name), getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(es.weights_ntm(), want.weights_ntm())


def test_a_scored_estep_over_many_blocks_on_threads_is_the_one_thread_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Many blocks on two threads, each with its own scratch for the score: the same E-step and
    score as on one thread, run after run, and the score equals ``log_likelihood``'s."""
    from pmht_opt.estep import likelihood

    monkeypatch.setattr(likelihood, "_BLOCK", 4000)  # a dozen rows per block
    z, pos = _paths(6, 300, 100, 4)
    one, score = estep_scored(z, pos, None, None, 0.5, 0.8, gate="auto", threads=1)
    assert score == log_likelihood(z, pos, None, None, 0.8, threads=1)
    for _ in range(5):
        two, score2 = estep_scored(z, pos, None, None, 0.5, 0.8, gate="auto", threads=2)
        assert score2 == score
        np.testing.assert_array_equal(two.W, one.W)
        np.testing.assert_array_equal(two.log_normaliser, one.log_normaliser)


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda z, p: estep(z, p, None, None, -1.0), "r"),
        (lambda z, p: log_likelihood(z, p, None, None, "a"), "r"),
        (lambda z, p: estep_scored(z, p, None, None, 0.1, float("nan")), "score_at"),
        (lambda z, p: estep(z, p, None, None, 0.1, time_totals="yes"), "time_totals"),
    ],
)
def test_bad_penalties_and_flags_are_config_errors(call: Any, field: str) -> None:
    z, pos = np.ones((3, 2)), np.zeros((2, 5, 2))
    with pytest.raises(ConfigError, match=f"^{field}: expected"):
        call(z, pos)


def test_a_nan_locale_gives_the_same_estep_gated_or_not() -> None:
    """A NaN coordinate sends the gate to the dense E-step (its row's likelihood is zero) instead of
    reaching the candidate search."""
    z = np.array([[1.0, 2.0], [np.nan, 1.0], [3.0, 3.0]])
    pos = np.random.default_rng(0).uniform(0, 4, (2, 10, 2))
    dense, gated = (estep(z, pos, None, None, 0.01, gate=g) for g in (None, "auto"))
    np.testing.assert_array_equal(gated.log_normaliser, dense.log_normaliser)
    assert gated.log_normaliser[1] == -np.inf


@pytest.mark.parametrize("M", range(1, 25))
def test_platform_sums_are_numpys_to_the_last_bit(M: int) -> None:
    """The dense E-step's per-platform sums over time are ``sum(axis=1)``'s, bit for bit, for every
    number of platforms (numpy sums a contiguous axis pairwise and a strided one in order)."""
    rng = np.random.default_rng(M)
    for T in (1, 2, 7, 9, 17, 129, 1001):
        for n in (1, 3, 40):
            ntm = rng.random((n, T, M)) ** 6  # a wide range of magnitudes: the order of a sum shows
            np.testing.assert_array_equal(platform_sums(ntm), ntm.sum(axis=1))


def test_a_dense_estep_does_not_allocate_its_weights() -> None:
    """Memory: the N x T*M weights (32 MB here) are not allocated by the E-step or its statistics (its
    time totals, N x T, take 6.4 MB; the blocks' work arrays about 3 MB)."""
    z, pos = _paths(3, 400, 2000, 5)
    tracemalloc.start()
    try:
        es = estep(z, pos, None, None, 0.5, gate=None)
        es.map_assignment(), es.platform_prior(), es.time_prior()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20e6, peak


def test_a_far_locale_leaves_the_other_rows_of_its_block_alone() -> None:
    """Each row is computed on its own (the overflow-safe distance only for far rows): rows recomputed
    in other blocks, singly or by the summary's chunks, equal the E-step's bit for bit."""
    z, pos = _paths(0, 300, 800, 6)
    z[220] = 1e200
    es = estep(z, pos, None, None, 0.3)
    alone = [es.locale_weights(n).copy() for n in (216, 219, 221, 244)]
    summary = es.summary(0.0).weights
    w = np.asarray(es.weights)
    for n, row in zip((216, 219, 221, 244), alone, strict=True):
        np.testing.assert_array_equal(row.ravel(), w[n])
    floored = sp.csr_matrix(w)
    for part in ("data", "indices", "indptr"):
        np.testing.assert_array_equal(getattr(summary, part), getattr(floored, part))


def test_the_limit_of_an_infinitely_unlikely_row_is_its_own() -> None:
    """Where every log weight of a row is -inf (diverged paths), its mass goes to its nearest allowed
    pairs, whatever the other rows of its block (one of which may have only infinitely far pairs)."""
    rng = np.random.default_rng(0)
    N, T, M = 6, 4, 2
    z = rng.uniform(0, 10, (N, 2))
    pos = np.zeros((M, T, 2))
    pos[0], pos[1] = 1e200, 1e153
    pos[1, :, 0] += np.arange(T) * 1e152  # distinct distances on platform 1, nearest at t = 1
    lk = np.zeros((N, M))
    lk[0, 1] = -np.inf  # locale 0 may only use platform 0, whose squared distances overflow
    with np.errstate(over="ignore"):
        es = estep(z, pos, None, lk, 1e-3)
        alone = es.locale_weights(3).copy()
        w = es.weights_ntm()
    expected = np.zeros((T, M))
    expected[0, 1] = 1.0
    np.testing.assert_array_equal(w[3], expected)
    np.testing.assert_array_equal(alone, expected)
    np.testing.assert_array_equal(w[0][:, 0], np.full(T, 1.0 / T))  # no finite distance: all allowed
    assert np.all(np.isinf(es.log_normaliser))
