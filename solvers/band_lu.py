"""LAPACK's banded LU of a block-diagonal band, its independent parts on concurrent threads.

SciPy's f2py wrappers of LAPACK (:mod:`scipy.linalg.lapack`) hold the global interpreter lock while
LAPACK runs, so two threads cannot factorise two bands at once through them. SciPy also exports the
same routines as C function pointers (:mod:`scipy.linalg.cython_lapack`); a call through
:mod:`ctypes` releases the lock for its duration, so the parts of a batch run on as many cores as
there are threads.

Factorising a block-diagonal band part by part gives the LU of the whole, bit for bit: partial
pivoting in a column compares only rows of the column's own system (every other row holds an exact
zero there), and the updates of one system's columns by another's rows multiply exact zeros. The
split is therefore a matter of speed only, never of the answer. Where the function pointers cannot be
had (a SciPy without them, or with other signatures), the whole band goes through the f2py wrappers
on the calling thread: the same arithmetic, one part.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import re
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

import numpy as np
from scipy.linalg import lapack

__all__ = ["BandLU", "usable_cores"]

_INT = ctypes.POINTER(ctypes.c_int)
_DBL = ctypes.POINTER(ctypes.c_double)
_CHAR = ctypes.c_char_p
#: The C signatures of the exported routines, with SciPy's typedef of ``double`` written ``d``.
_SIGNATURES: dict[str, tuple[str, list[Any]]] = {
    "dgbsv": (
        "void (int *, int *, int *, int *, d *, int *, int *, d *, int *, int *)",
        [_INT] * 4 + [_DBL, _INT, _INT, _DBL, _INT, _INT],
    ),
    "dgbtrs": (
        "void (char *, int *, int *, int *, int *, d *, int *, int *, d *, int *, int *)",
        [_CHAR] + [_INT] * 4 + [_DBL, _INT, _INT, _DBL, _INT, _INT],
    ),
}


def _routine(name: str) -> Callable[..., None] | None:
    """The exported LAPACK routine ``name`` as a ctypes function, or ``None`` if SciPy does not export
    it with the expected signature."""
    try:
        from scipy.linalg import cython_lapack

        capsule = cython_lapack.__pyx_capi__[name]
        get_name = ctypes.pythonapi.PyCapsule_GetName
        get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
        get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
        signature = get_name(capsule)
        text, argtypes = _SIGNATURES[name]
        if re.sub(r"__pyx_t_\w+_d\b", "d", signature.decode()) != text:
            return None
        function: Callable[..., None] = ctypes.CFUNCTYPE(None, *argtypes)(get_pointer(capsule, signature))
        return function
    except Exception:  # any failure means "not available": the f2py path is used
        return None


_GBSV = _routine("dgbsv")
_GBTRS = _routine("dgbtrs")
_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def usable_cores() -> int:
    """The number of cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def _forget_pool() -> None:
    """In a child made by ``fork`` the parent's pool threads do not exist: make a new pool there."""
    global _POOL
    _POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max(1, usable_cores() - 1), thread_name_prefix="band-lu")
        return _POOL


def _ref(value: int) -> Any:
    return ctypes.byref(ctypes.c_int(value))


class BandLU:
    """The LU factors of a block-diagonal band matrix, factorised and applied part by part.

    Parameters
    ----------
    band
        ``(3k + 1, N)`` Fortran-ordered LAPACK band storage (``A[i, j]`` at ``band[2k + i - j, j]``, the
        top ``k`` rows free for fill-in), overwritten by the factors.
    k
        Half-bandwidth (lower and upper).
    b
        ``(N, K)`` Fortran-ordered right-hand sides, overwritten by the solution.
    parts
        Row ranges ``[lo, hi)`` covering ``0..N`` in order, each a union of whole independent
        systems; each is factorised on its own thread (the calling thread takes the first).

    Raises
    ------
    numpy.linalg.LinAlgError
        A zero pivot (the matrix is singular to working precision), with LAPACK's ``info``.
    """

    def __init__(self, band: np.ndarray, k: int, b: np.ndarray, parts: Sequence[tuple[int, int]]) -> None:
        if band.shape[0] != 3 * k + 1 or b.shape[0] != band.shape[1] or b.ndim != 2:
            raise ValueError(f"band {band.shape} and right-hand sides {b.shape} do not fit k = {k}.")
        if not (band.flags.f_contiguous and b.flags.f_contiguous):
            raise ValueError("the band and the right-hand sides must be Fortran-ordered.")
        if band.dtype != np.float64 or b.dtype != np.float64:
            raise ValueError("the band and the right-hand sides must be float64.")
        self.band, self.k = band, k
        self.N = band.shape[1]
        covered = (
            len(parts) > 0
            and parts[0][0] == 0
            and parts[-1][1] == self.N
            and all(lo < hi for lo, hi in parts)
            and all(a[1] == b[0] for a, b in itertools.pairwise(parts))
        )
        if not covered:  # a wrong range would let LAPACK write outside the arrays
            raise ValueError(f"parts {list(parts)} do not cover rows 0..{self.N} in order.")
        self.parts = list(parts) if _GBSV is not None and _GBTRS is not None else [(0, self.N)]
        if _GBSV is None or _GBTRS is None:
            lu, piv, x, info = lapack.dgbsv(k, k, band, b, overwrite_ab=1, overwrite_b=1)
            if info != 0:
                raise np.linalg.LinAlgError(f"LAPACK gbsv info={info}")
            self.band, self.ipiv = lu, piv
            b[...] = x
            return
        self.ipiv = np.empty(self.N, dtype=np.intc)
        infos = self._run(lambda lo, hi: self._gbsv(lo, hi, b))
        bad = [info for info in infos if info != 0]
        if bad:
            raise np.linalg.LinAlgError(f"LAPACK gbsv info={bad[0]}")

    def solve(self, b: np.ndarray) -> None:
        """Overwrite the ``(N, K)`` Fortran-ordered ``b`` with ``A^-1 b``."""
        if _GBSV is None or _GBTRS is None:
            x, info = lapack.dgbtrs(self.band, self.k, self.k, b, self.ipiv, overwrite_b=1)
            if info != 0:  # pragma: no cover - gbtrs only reports invalid arguments
                raise np.linalg.LinAlgError(f"LAPACK gbtrs info={info}")
            b[...] = x
            return
        self._run(lambda lo, hi: self._gbtrs(lo, hi, b))

    # -- the calls ------------------------------------------------------------------------------

    def _run(self, call: Callable[[int, int], int]) -> list[int]:
        """``call`` on every part, the first on this thread; waits for all, even when interrupted, so
        that no thread writes into the arrays after this returns."""
        futures: list[Future[int]] = [_pool().submit(call, lo, hi) for lo, hi in self.parts[1:]]
        try:
            first = call(*self.parts[0])
        finally:
            wait(futures)
        return [first, *(f.result() for f in futures)]

    def _pointers(self, lo: int, b: np.ndarray) -> tuple[Any, Any, Any]:
        width = self.band.shape[0]
        band = ctypes.cast(self.band.ctypes.data + 8 * width * lo, _DBL)
        ipiv = ctypes.cast(self.ipiv.ctypes.data + 4 * lo, _INT)
        rhs = ctypes.cast(b.ctypes.data + 8 * lo, _DBL)
        return band, ipiv, rhs

    def _gbsv(self, lo: int, hi: int, b: np.ndarray) -> int:
        band, ipiv, rhs = self._pointers(lo, b)
        info = ctypes.c_int(0)
        k, K, width = self.k, b.shape[1], self.band.shape[0]
        assert _GBSV is not None
        _GBSV(
            _ref(hi - lo),
            _ref(k),
            _ref(k),
            _ref(K),
            band,
            _ref(width),
            ipiv,
            rhs,
            _ref(self.N),
            ctypes.byref(info),
        )
        return info.value

    def _gbtrs(self, lo: int, hi: int, b: np.ndarray) -> int:
        band, ipiv, rhs = self._pointers(lo, b)
        info = ctypes.c_int(0)
        k, K, width = self.k, b.shape[1], self.band.shape[0]
        assert _GBTRS is not None
        _GBTRS(
            b"N",
            _ref(hi - lo),
            _ref(k),
            _ref(k),
            _ref(K),
            band,
            _ref(width),
            ipiv,
            rhs,
            _ref(self.N),
            ctypes.byref(info),
        )
        return info.value
