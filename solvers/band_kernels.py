"""LAPACK's banded LU and solve as compiled loops (numba, optional), for narrow bands.

LAPACK factorises a band with fewer than about 64 sub-diagonals by its unblocked algorithm
(``dgbtf2``): for every column a search for the pivot, a row swap, a scaling by the reciprocal of
the pivot and a rank-one update of the trailing band, four calls to the BLAS on vectors of ``k`` or
``2k`` entries. For the smoother's band (``k = 3``, 12000 columns for the paper's scenario) the cost
of those calls, not their arithmetic, is most of the factorisation: about 100 ns per column, where
the arithmetic is some 30 floating-point operations. ``dgbtrs`` solves column by column likewise.

The loops here are those two algorithms written out, with the half-bandwidth ``k`` and the number of
right-hand sides fixed when a loop is compiled (so that the inner loops unroll): the same pivots
(the first entry of largest magnitude), the same reciprocal scaling and the same updates in the same
order. Each update ``a - l u`` may be formed as one fused multiply-add (numba's ``contract`` flag),
as optimised BLAS kernels form it on processors that have the instruction; with SciPy's OpenBLAS on
such a processor the factors, pivots and solutions of finite bands were measured equal to LAPACK's
to the last bit, up to the sign of a zero (docs/decisions.md section 1.12), and elsewhere they
differ by rounding only. Non-finite entries are not LAPACK's business either way: a NaN is never
chosen as a pivot here (it can be by OpenBLAS's pivot search), and an update by an exact zero is
skipped, as reference LAPACK skips it. On the paper's scenario they take about a third of LAPACK's
time.

numba is imported on first use; the compiled loops are cached on disk, one pair per ``(k, K)``.
They release the interpreter lock, so :class:`solvers.band_lu.BandLU` runs its parts on concurrent
threads as it does LAPACK's routines.
"""

from __future__ import annotations

import functools
import importlib.util
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["available", "band_loops", "compiled_loops"]

#: The widest band the loops serve: LAPACK's blocked algorithm takes over beyond it, and unrolling
#: wider loops gains nothing.
MAX_HALF_BANDWIDTH = 8
#: The most right-hand sides the solve is compiled for; more go through LAPACK.
MAX_RHS = 8

_LOCK = threading.Lock()


def available() -> bool:
    """Whether numba can be imported (without importing it)."""
    return importlib.util.find_spec("numba") is not None


def band_loops(k: int, K: int) -> tuple[Callable[..., int], Callable[..., None]]:
    """The factorisation and the solve for half-bandwidth ``k`` and ``K`` right-hand sides, as plain
    Python functions (what numba compiles; the tests run them uncompiled on small bands).

    ``factor(ab, lo, hi, ipiv) -> info`` factorises rows and columns ``[lo, hi)`` of the band ``ab``
    in place: ``ab`` is the flat C-ordered ``(N, 3k + 1)`` array whose row ``j`` is column ``j`` of
    LAPACK's band storage (``A[i, j]`` at ``ab[j * (3k + 1) + 2k + i - j]``, the first ``k`` entries
    of each row free for fill-in, which this sets to zero first). ``ipiv[lo + j]`` becomes
    the 1-based pivot row within the part, as LAPACK's; ``info`` is 0, or the 1-based column within
    the part of the first zero pivot (the factorisation stops there).

    ``solve(ab, lo, hi, ipiv, b)`` overwrites columns ``[lo, hi)`` of ``b`` (``(K, N)``, C-ordered:
    one right-hand side per row) with the solution, from the factors.
    """
    kv = 2 * k
    width = 3 * k + 1

    def factor(ab: np.ndarray, lo: int, hi: int, ipiv: np.ndarray) -> int:
        n = hi - lo
        for c in range(lo, hi):  # the rows of fill-in start at zero, whatever the caller left there
            for i in range(k):
                ab[c * width + i] = 0.0
        ju = 0  # the last column reached by the row swaps so far (LAPACK's JU)
        for j in range(n):
            km = k if n - 1 - j > k else n - 1 - j
            cj = (lo + j) * width + kv  # the diagonal entry of column j
            jp = 0
            big = abs(ab[cj])
            for i in range(1, km + 1):
                v = abs(ab[cj + i])
                if v > big:
                    big = v
                    jp = i
            ipiv[lo + j] = j + jp + 1
            pivot = ab[cj + jp]
            if pivot == 0.0:
                return j + 1
            reach = j + k + jp if j + k + jp < n - 1 else n - 1
            if reach > ju:
                ju = reach
            if jp != 0:  # rows j and j + jp, columns j .. ju
                for c in range(j, ju + 1):
                    p = (lo + c) * width + kv + j - c
                    t = ab[p]
                    ab[p] = ab[p + jp]
                    ab[p + jp] = t
            if km > 0:
                rcp = 1.0 / pivot
                for i in range(1, km + 1):
                    ab[cj + i] *= rcp
                for c in range(j + 1, ju + 1):
                    p = (lo + c) * width + kv + j - c
                    u = ab[p]
                    if u != 0.0:
                        for i in range(1, km + 1):
                            ab[p + i] -= ab[cj + i] * u
        return 0

    def solve(ab: np.ndarray, lo: int, hi: int, ipiv: np.ndarray, b: np.ndarray) -> None:
        n = hi - lo
        for j in range(n):  # L: the row swaps and the multipliers, column by column
            km = k if n - 1 - j > k else n - 1 - j
            row = lo + j
            p = lo + ipiv[row] - 1
            cj = row * width + kv
            for r in range(K):
                x = b[r, p]
                if p != row:
                    b[r, p] = b[r, row]
                    b[r, row] = x
                for i in range(1, km + 1):
                    b[r, row + i] -= ab[cj + i] * x
        for j in range(n - 1, -1, -1):  # U, of half-bandwidth 2k, from the last column back
            row = lo + j
            cj = row * width + kv
            m = kv if j > kv else j
            for r in range(K):
                x = b[r, row] / ab[cj]
                b[r, row] = x
                for i in range(1, m + 1):
                    b[r, row - i] -= ab[cj - i] * x

    return factor, solve


@functools.cache
def _compile(k: int, K: int) -> tuple[Callable[..., int], Callable[..., None]] | None:
    try:
        import numba
    except ImportError:
        return None
    jit = numba.njit(cache=True, nogil=True, boundscheck=False, fastmath={"contract"})
    factor, solve = band_loops(k, K)
    # numba names a function's cache files after its qualified name and saves entries into them
    # without a lock between processes: two processes compiling two pairs of one name at once could
    # index one pair's code under the other's key. A name per pair gives each pair its own files.
    for loop, name in ((factor, f"band_factor_k{k}"), (solve, f"band_solve_k{k}_K{K}")):
        loop.__name__ = loop.__qualname__ = name
    return jit(factor), jit(solve)


def compiled_loops(k: int, K: int) -> tuple[Callable[..., Any], Callable[..., Any]] | None:
    """The compiled ``(factor, solve)`` of :func:`band_loops`, or ``None`` where they cannot run:
    numba missing, ``k`` above :data:`MAX_HALF_BANDWIDTH` or ``K`` above :data:`MAX_RHS`."""
    if not (1 <= k <= MAX_HALF_BANDWIDTH and 1 <= K <= MAX_RHS):
        return None
    with _LOCK:  # one compilation (or load from the disk cache) per pair, whatever the threads
        return _compile(k, K)
