"""The banded LU by parts (LAPACK through SciPy), on any number of threads."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from solvers.band_lu import BandLU


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


def test_band_lu_parts_equal_lapack_whole() -> None:
    """A block-diagonal band factorised and solved part by part equals LAPACK on the whole band, bit
    for bit, on any number of threads."""
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
            fact = BandLU(band.copy(order="F"), k, b, chosen, threads)
            again = rhs.copy(order="F")
            fact.solve(again)
            np.testing.assert_array_equal(again, b)  # the kept factors solve as the first call did
            np.testing.assert_array_equal(b, x_ref)


def test_a_zero_pivot_is_named_by_its_row_in_the_whole_band() -> None:
    k, N = 1, 40
    band = np.zeros((3 * k + 1, N), order="F")
    band[2 * k] = 1.0
    band[2 * k, 27] = 0.0  # row 28 (LAPACK counts from 1) of the second part
    for parts in ([(0, N)], [(0, 20), (20, N)]):
        for threads in (1, 2):
            with pytest.raises(np.linalg.LinAlgError, match="info=28"):
                BandLU(band.copy(order="F"), k, np.ones((N, 1), order="F"), parts, threads)
