"""The banded LU by parts, by LAPACK and by the compiled loops of :mod:`solvers.band_kernels`."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import scipy.linalg

import pmht_opt as po
from pmht_opt import kernels
from solvers import band_kernels
from solvers.band_lu import BandLU
from solvers.banded import BandedSmoother, banded_smoother
from solvers.exceptions import ProblemError
from studies.smoother_reference import E1, ca_model

needs_numba = pytest.mark.skipif(not band_kernels.available(), reason="numba is not installed")


def random_band(
    rng: np.random.Generator, k: int, sizes: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """A block-diagonal matrix of random banded blocks, its LAPACK band storage (Fortran order, the
    fill-in rows zero) and the row ranges of its blocks."""
    N = sum(sizes)
    A = scipy.linalg.block_diag(*[np.triu(np.tril(rng.normal(size=(n, n)), k), -k) for n in sizes])
    band = np.zeros((3 * k + 1, N), order="F")
    for d in range(-k, k + 1):
        diag = np.diagonal(A, d)
        if d >= 0:
            band[2 * k - d, d:] = diag
        else:
            band[2 * k - d, : N + d] = diag
    ends = np.cumsum(sizes)
    parts = list(zip(np.r_[0, ends[:-1]].tolist(), ends.tolist(), strict=True))
    return A, band, parts


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_band_lu_parts_equal_lapack_whole(compiled: bool) -> None:
    """A block-diagonal band factorised and solved part by part equals LAPACK on the whole band, bit
    for bit through LAPACK's routines on any number of threads; by the compiled loops, to rounding
    (bit for bit where the BLAS fuses multiply-adds as they do)."""
    rng = np.random.default_rng(12)
    k = 3
    A, band, parts = random_band(rng, k, (700, 500, 900))
    N = A.shape[0]
    rhs = np.asfortranarray(rng.normal(size=(N, 2)))
    _lu, _piv, x_ref, info = scipy.linalg.lapack.dgbsv(k, k, band.copy(order="F"), rhs.copy(order="F"))
    assert info == 0
    np.testing.assert_allclose(A @ x_ref, rhs, atol=1e-9)
    numpy_ints = [(np.int64(lo), np.int64(hi)) for lo, hi in parts]  # as np.cumsum gives them
    for chosen in ([(0, N)], parts, numpy_ints):
        for threads in (1, 2):
            b = rhs.copy(order="F")
            fact = BandLU(band.copy(order="F"), k, b, chosen, threads, compiled=compiled)
            again = rhs.copy(order="F")
            fact.solve(again)
            np.testing.assert_array_equal(again, b)  # the kept factors solve as the first call did
            if compiled:
                np.testing.assert_allclose(b, x_ref, rtol=0, atol=1e-12 * np.abs(x_ref).max())
            else:
                np.testing.assert_array_equal(b, x_ref)


@needs_numba
@pytest.mark.parametrize(("k", "K"), [(1, 1), (2, 4), (5, 3)])  # (3, 2), the smoother's: tests below
def test_compiled_loops_take_lapacks_pivots(k: int, K: int) -> None:
    """The compiled loops pick LAPACK's pivots and give its factors and solutions to rounding, for
    the widths and numbers of right-hand sides they are compiled for."""
    rng = np.random.default_rng(100 + k)
    A, band, parts = random_band(rng, k, (40, 3 * k + 2, 90))
    rhs = np.asfortranarray(rng.normal(size=(A.shape[0], K)))
    got = []
    for compiled in (False, True):
        factors, b = band.copy(order="F"), rhs.copy(order="F")
        fact = BandLU(factors, k, b, parts, 2, compiled=compiled)
        got.append((factors, b, fact.ipiv))
    (f0, b0, p0), (f1, b1, p1) = got
    np.testing.assert_array_equal(p1, p0)
    np.testing.assert_allclose(f1, f0, rtol=0, atol=1e-12 * np.abs(f0).max())
    np.testing.assert_allclose(b1, b0, rtol=0, atol=1e-12 * np.abs(b0).max())
    np.testing.assert_allclose(A @ b1, rhs, atol=1e-9 * np.abs(A @ b1).max())


@needs_numba
def test_ties_pick_lapacks_pivot() -> None:
    """Where two candidates have the same magnitude LAPACK takes the first: so do the loops, on a band
    of small integers (ties everywhere) and on the smoother's own KKT band (ties between its unit
    entries), and they solve alike."""
    rng = np.random.default_rng(21)
    k = 3
    _A, band, parts = random_band(rng, k, (300, 200))
    band[:] = rng.integers(-2, 3, size=band.shape)
    band[2 * k] += np.where(band[2 * k] == 0, 1.0, 0.0)  # no zero on the diagonal
    band[:k] = 0.0
    F, Q = ca_model(0.1, 1e-4)
    sm = BandedSmoother(F, Q, E1, 200, 2)
    kkt = np.ascontiguousarray(sm._band_T).T.copy(order="F")
    w = rng.random((2, 200))
    w[:, 120:] = 0.0
    for index, value in zip(sm._pen_index, sm._pen_value, strict=True):
        kkt.T.reshape(-1)[index] += w / 1e-2 * value
    for matrix, parts_of in ((band, parts), (kkt, sm._parts())):
        rhs = np.asfortranarray(rng.normal(size=(matrix.shape[1], 2)))
        got = []
        for compiled in (False, True):
            factors, b = matrix.copy(order="F"), rhs.copy(order="F")
            fact = BandLU(factors, k, b, parts_of, 1, compiled=compiled)
            got.append((fact.ipiv, b))
        np.testing.assert_array_equal(got[1][0], got[0][0])
        np.testing.assert_allclose(got[1][1], got[0][1], rtol=0, atol=1e-12 * np.abs(got[0][1]).max())


def test_loops_uncompiled_are_lapacks_algorithm() -> None:
    """The loops' source run as plain Python (what numba compiles): LAPACK's pivots, and its factors
    and solution up to rounding (Python forms ``a - l u`` in two roundings)."""
    rng = np.random.default_rng(7)
    k, K = 2, 2
    A, band, parts = random_band(rng, k, (23, 17))
    rhs = np.asfortranarray(rng.normal(size=(A.shape[0], K)))
    factors, b = band.copy(order="F"), rhs.copy(order="F")
    fact = BandLU(factors, k, b, parts)
    factor, solve = band_kernels.band_loops(k, K)
    ab = band.copy(order="F")
    ab[:k] = np.nan  # the fill-in rows are set by the loops, whatever they held
    flat, x, ipiv = ab.T.reshape(-1), rhs.T.copy(), np.zeros(A.shape[0], dtype=np.intc)
    for lo, hi in parts:
        assert factor(flat, lo, hi, ipiv) == 0
        solve(flat, lo, hi, ipiv, x)
    np.testing.assert_array_equal(ipiv, fact.ipiv)
    np.testing.assert_allclose(ab, factors, rtol=0, atol=1e-12 * np.abs(factors).max())
    np.testing.assert_allclose(x.T, b, rtol=0, atol=1e-12 * np.abs(b).max())


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=needs_numba)])
def test_a_zero_pivot_is_named_by_its_row_in_the_whole_band(compiled: bool) -> None:
    k, N = 1, 40
    band = np.zeros((3 * k + 1, N), order="F")
    band[2 * k] = 1.0
    band[2 * k, 27] = 0.0  # row 28 (LAPACK counts from 1) of the second part
    for parts in ([(0, N)], [(0, 20), (20, N)]):
        for threads in (1, 2):
            with pytest.raises(np.linalg.LinAlgError, match="info=28"):
                BandLU(band.copy(order="F"), k, np.ones((N, 1), order="F"), parts, threads, compiled=compiled)


def test_compiled_falls_back_to_lapack(monkeypatch: pytest.MonkeyPatch) -> None:
    """Asked for compiled loops where they cannot run (numba missing, too many right-hand sides, too
    wide a band), BandLU runs LAPACK's routines, with LAPACK's numbers."""
    rng = np.random.default_rng(3)
    cases = [(3, band_kernels.MAX_RHS + 1, False), (band_kernels.MAX_HALF_BANDWIDTH + 1, 1, False)]
    cases.append((3, 2, True))  # numba made unimportable
    for k, K, hide in cases:
        _A, band, parts = random_band(rng, k, (60, 50))
        rhs = np.asfortranarray(rng.normal(size=(110, K)))
        expected = rhs.copy(order="F")
        BandLU(band.copy(order="F"), k, expected, parts)
        with monkeypatch.context() as m:
            if hide:
                m.setitem(sys.modules, "numba", None)  # "import numba" raises ImportError
                band_kernels._compile.cache_clear()
            got = rhs.copy(order="F")
            BandLU(band.copy(order="F"), k, got, parts, 2, compiled=True)
        band_kernels._compile.cache_clear()
        np.testing.assert_array_equal(got, expected)


@needs_numba
def test_smoother_compiled_or_not() -> None:
    """The exact smoother by the compiled loops and by LAPACK: the same paths to rounding, on
    coasting weights with a small r."""
    F, Q = ca_model(0.1, 1e-4)
    rng = np.random.default_rng(5)
    B, T = 3, 400
    W = rng.random((B, T))
    W[:, 150:] = 0.0
    y, x0 = rng.normal(size=(B, T, 2)), rng.normal(size=(B, 3, 2))
    paths = [
        BandedSmoother(F, Q, E1, T, B, compiled=c).solve(1e-6, x0, y, W, threads=2).means
        for c in (False, True)
    ]
    np.testing.assert_allclose(paths[1], paths[0], rtol=0, atol=1e-11 * np.abs(paths[0]).max())


def test_the_switch_decides_the_m_steps_lu(monkeypatch: pytest.MonkeyPatch) -> None:
    """``PMHT_OPT_KERNELS=0`` keeps the exact M-step on LAPACK; otherwise it is compiled where numba
    is installed. The plans agree to rounding."""
    scenario = po.paper_scenario("A", seed=0, horizon=120)
    config = po.PMHTConfig(max_iter=15)
    monkeypatch.setenv(kernels.ENV_SWITCH, "0")
    assert not kernels.lu_compiled()
    lapack = po.plan_pmht(scenario, config).states
    monkeypatch.setenv(kernels.ENV_SWITCH, "auto")
    assert kernels.lu_compiled() == band_kernels.available()
    compiled = po.plan_pmht(scenario, config).states
    np.testing.assert_allclose(compiled, lapack, rtol=0, atol=1e-9)


@pytest.mark.parametrize("bad", ["yes", 1, None, 0.0])
def test_compiled_must_be_a_bool(bad: object) -> None:
    F, Q = ca_model(0.1, 1e-4)
    with pytest.raises(ProblemError, match="compiled"):
        BandedSmoother(F, Q, E1, 10, 1, compiled=bad)  # type: ignore[arg-type]
    banded_smoother(F, Q, E1, 1.0, np.zeros((1, 3, 1)), np.zeros((1, 10, 1)), np.ones((1, 10)), compiled=True)
    with pytest.raises(ProblemError, match="compiled"):  # not taken for True by the cache either
        banded_smoother(
            F, Q, E1, 1.0, np.zeros((1, 3, 1)), np.zeros((1, 10, 1)), np.ones((1, 10)), compiled=bad
        )  # type: ignore[arg-type]
