"""LAPACK's banded LU of a block-diagonal band, its independent parts on concurrent threads.

SciPy's f2py wrappers of LAPACK (:mod:`scipy.linalg.lapack`) hold the global interpreter lock while
LAPACK runs, so two threads cannot factorise two bands at once through them. SciPy also exports the
same routines as C function pointers (:mod:`scipy.linalg.cython_lapack`); a call through
:mod:`ctypes` releases the lock for its duration, so the parts of a batch run on as many cores as
there are threads.

The caller fixes the parts (whole independent systems); the threads only decide how many run at
once, so the answer does not depend on their number. (For a narrow band, ``k <= 64``, LAPACK
factorises column by column and the parts' LU is also the whole band's, bit for bit: pivoting in a
column compares only rows of the column's own system, the others holding exact zeros. For a wider
band LAPACK works in blocks of columns counted from the start of each call, so the parts matter.)
Where the function pointers cannot be had (a SciPy without them, or with other signatures), each
part goes through the f2py wrappers on the calling thread: the same calls, one at a time.
"""

from __future__ import annotations

import ctypes
import itertools
import re
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any

import numpy as np
from scipy.linalg import lapack

from solvers.threads import LazyPool, usable_cores, wait_all

__all__ = ["BandLU"]

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
        # Function types of our own: setting argtypes on ctypes.pythonapi's would change them for
        # every other user in the process.
        get_name = ctypes.PYFUNCTYPE(ctypes.c_char_p, ctypes.py_object)(
            ("PyCapsule_GetName", ctypes.pythonapi)
        )
        get_pointer = ctypes.PYFUNCTYPE(ctypes.c_void_p, ctypes.py_object, ctypes.c_char_p)(
            ("PyCapsule_GetPointer", ctypes.pythonapi)
        )
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
_POOL = LazyPool(max(1, usable_cores() - 1), "band-lu")


def _ref(value: int) -> Any:
    return ctypes.byref(ctypes.c_int(value))


class BandLU:
    """The LU factors of a block-diagonal band matrix, factorised and applied part by part.

    Parameters
    ----------
    band
        ``(3k + 1, N)`` Fortran-ordered float64 LAPACK band storage (``A[i, j]`` at
        ``band[2k + i - j, j]``, the top ``k`` rows free for fill-in), overwritten by the factors.
    k
        Half-bandwidth (lower and upper).
    b
        ``(N, K)`` Fortran-ordered float64 right-hand sides, overwritten by the solution.
    parts
        Row ranges ``[lo, hi)`` covering ``0..N`` in order, each a union of whole independent
        systems: each is factorised and solved by its own LAPACK call.
    threads
        How many parts run at once (the calling thread takes one lane of them). The answer does not
        depend on it.

    Raises
    ------
    numpy.linalg.LinAlgError
        A zero pivot (the matrix is singular to working precision), with the row as LAPACK's
        ``info`` counts it in the whole band.

    Notes
    -----
    The pivot indices (``ipiv``) are LAPACK's within each part.
    """

    def __init__(
        self,
        band: np.ndarray,
        k: int,
        b: np.ndarray,
        parts: Sequence[tuple[int, int]],
        threads: int = 1,
    ) -> None:
        if band.ndim != 2 or band.shape[0] != 3 * k + 1:
            raise ValueError(f"band {band.shape} does not fit k = {k}.")
        if not band.flags.f_contiguous or band.dtype != np.float64:
            raise ValueError("the band must be a Fortran-ordered float64 array.")
        self.band, self.k = band, k
        self.N = band.shape[1]
        self._check_rhs(b)
        covered = (
            len(parts) > 0
            and parts[0][0] == 0
            and parts[-1][1] == self.N
            and all(lo < hi for lo, hi in parts)
            and all(a[1] == b[0] for a, b in itertools.pairwise(parts))
        )
        if not covered:  # a wrong range would let LAPACK write outside the arrays
            raise ValueError(f"parts {list(parts)} do not cover rows 0..{self.N} in order.")
        self.parts = [(int(lo), int(hi)) for lo, hi in parts]  # ctypes takes Python integers only
        self.threads = max(1, int(threads))
        self.ipiv = np.empty(self.N, dtype=np.intc)
        infos = self._run(b, factorise=True)
        for (lo, _), info in zip(self.parts, infos, strict=True):
            if info != 0:
                raise np.linalg.LinAlgError(f"LAPACK gbsv info={lo + info if info > 0 else info}")

    def solve(self, b: np.ndarray) -> None:
        """Overwrite the ``(N, K)`` Fortran-ordered float64 ``b`` with ``A^-1 b``."""
        self._check_rhs(b)
        infos = self._run(b, factorise=False)
        if any(infos):  # pragma: no cover - gbtrs only reports invalid arguments
            raise np.linalg.LinAlgError(f"LAPACK gbtrs info={infos}")

    def _check_rhs(self, b: np.ndarray) -> None:
        if b.ndim != 2 or b.shape[0] != self.N or b.shape[1] < 1:
            raise ValueError(f"right-hand sides {b.shape} do not fit a band of {self.N} rows.")
        if not b.flags.f_contiguous or b.dtype != np.float64:
            raise ValueError("the right-hand sides must be a Fortran-ordered float64 array.")

    # -- the calls ------------------------------------------------------------------------------

    def _run(self, b: np.ndarray, *, factorise: bool) -> list[int]:
        """Factorise (``factorise``) and solve, or only solve, every part for the right-hand sides
        ``b``, in ``threads`` lanes (the first on this thread); waits for every lane, also through
        interrupts, so that no thread writes into the arrays after this returns. Returns each
        part's ``info``."""

        def call(lo: int, hi: int) -> int:
            return self._gbsv(lo, hi, b) if factorise else self._gbtrs(lo, hi, b)

        lanes = min(self.threads, len(self.parts)) if _GBSV is not None and _GBTRS is not None else 1
        infos = [0] * len(self.parts)

        def lane(first: int) -> None:
            for i in range(first, len(self.parts), lanes):
                infos[i] = call(*self.parts[i])

        futures: list[Future[None]] = []
        try:
            for first in range(1, lanes):
                futures.append(_POOL.get().submit(lane, first))
            lane(0)
            for future in futures:
                future.result()
        finally:
            wait_all(futures)  # all done already, unless something above was interrupted or failed
        return infos

    def _arguments(self, lo: int, hi: int, b: np.ndarray, info: ctypes.c_int) -> tuple[Any, ...]:
        """``(n, kl, ku, nrhs, ab, ldab, ipiv, b, ldb, info)`` of part ``[lo, hi)`` for LAPACK's
        ``gbsv`` and ``gbtrs``: the part's columns of the band, rows of ``b`` and pivots."""
        width = self.band.shape[0]
        band = ctypes.cast(self.band.ctypes.data + 8 * width * lo, _DBL)
        ipiv = ctypes.cast(self.ipiv.ctypes.data + 4 * lo, _INT)
        rhs = ctypes.cast(b.ctypes.data + 8 * lo, _DBL)
        k = _ref(self.k)
        n, nrhs, ldab, ldb = _ref(hi - lo), _ref(b.shape[1]), _ref(width), _ref(self.N)
        return n, k, k, nrhs, band, ldab, ipiv, rhs, ldb, ctypes.byref(info)

    def _gbsv(self, lo: int, hi: int, b: np.ndarray) -> int:
        info = ctypes.c_int(0)
        if _GBSV is None or _GBTRS is None:
            lu, piv, x, info_f2py = lapack.dgbsv(
                self.k, self.k, self.band[:, lo:hi], b[lo:hi], overwrite_ab=1
            )
            self.band[:, lo:hi], self.ipiv[lo:hi], b[lo:hi] = lu, piv, x
            return int(info_f2py)
        _GBSV(*self._arguments(lo, hi, b, info))
        return info.value

    def _gbtrs(self, lo: int, hi: int, b: np.ndarray) -> int:
        info = ctypes.c_int(0)
        if _GBSV is None or _GBTRS is None:
            x, info_f2py = lapack.dgbtrs(self.band[:, lo:hi], self.k, self.k, b[lo:hi], self.ipiv[lo:hi])
            b[lo:hi] = x
            return int(info_f2py)
        _GBTRS(b"N", *self._arguments(lo, hi, b, info))
        return info.value
