"""Compiled loops of the gated E-step, used when numba is installed (the ``fast`` extra).

The gated E-step (:mod:`pmht_opt.gating`) works on a block of candidate triples at a time in about
ten passes of numpy: the candidate search (squared distances to the points of the chunks each pair's
disc meets, the test against the radius, the gathers), the log weights, the maxima of every
(locale, platform) pair and of every locale, the gate, the normalisation, the statistics of each row,
and the sums ``W`` and ``WZ`` over all triples. At large sizes (tens of millions of triples per
E-step) each pass is a trip through memory with arrays of the block's size. The loops here do the
same work in fewer passes (the search; the log weights with their maxima; the gate; the locales'
sums and the division by them; the columns with the rows' statistics; the ordered sums), each
reading and writing only what the next one needs, and without the numpy calls' overheads, which
dominate small E-steps. At ``N = 5000, T = 5000, M = 20`` a gated E-step takes about 0.35-0.45 s on
two threads against 0.75-0.9 s for the numpy passes (docs/decisions.md section 6.9); a default plan
of the paper's scenario A about 10% less time (section 1.12).

They give the same numbers to the last bit: every value is formed by the same IEEE operations in the
same order as the numpy passes (no fused multiply-add, no reassociation: numba compiles without fast
math), each sum adds its terms in the order of the triples as ``np.bincount`` and ``np.add.at`` do,
and the two transcendental steps, ``exp`` of the log weights and ``log`` of the normalisers, are left
to numpy, whose SIMD ``exp`` need not round like the C library's. ``tests/test_kernels.py`` checks
the identity on random and adversarial blocks.

numba is imported on first use only (``import pmht_opt`` stays free of it), about 0.3 s and 100 MB
with the loops loaded, once per process; the compiled code is cached on disk, so the compilation is
paid once per installation. The loops release the interpreter lock, so the blocks run on concurrent
threads as the numpy passes do.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError
from solvers import band_kernels

#: ``PMHT_OPT_KERNELS``: ``0`` runs the numpy passes and LAPACK even where numba is installed; ``auto``
#: (or unset) and ``1`` run the compiled loops of the E-step and of the exact M-step's banded LU
#: (:func:`lu_compiled`) wherever numba is installed, at every size: measured faster from the
#: smallest plans on (docs/decisions.md section 1.12).
ENV_SWITCH = "PMHT_OPT_KERNELS"

_LOCK = threading.Lock()
_COMPILED: SimpleNamespace | None = None
_TRIED = False


def _switch() -> str:
    value = os.environ.get(ENV_SWITCH, "auto").strip().lower() or "auto"
    if value not in ("0", "1", "auto"):
        raise ConfigError(f"{ENV_SWITCH} must be 0, 1 or auto, got {value!r}.")
    return value


def available() -> bool:
    """Whether the E-step's compiled loops run (numba importable and the switch not ``0``)."""
    return compiled() is not None


def lu_compiled() -> bool:
    """Whether the exact M-step's banded LU runs as compiled loops (:mod:`solvers.band_kernels`):
    numba installed and the switch not ``0``.

    At every size: on the smoother's band they are about three times as fast as LAPACK's routines
    (which make four BLAS calls per column), which takes about 15% off a default plan of the paper's
    scenario A, so the one import of numba per process is repaid within a few plans. With SciPy's
    OpenBLAS on a processor with fused multiply-add their numbers equal LAPACK's to the last bit
    (docs/decisions.md section 1.12).
    """
    return _switch() != "0" and band_kernels.available()


def compiled() -> SimpleNamespace | None:
    """The E-step's compiled loops, or ``None`` where the numpy passes run: numba missing or the
    switch ``0``."""
    return None if _switch() == "0" else _load()


def _load() -> SimpleNamespace | None:
    global _COMPILED, _TRIED
    if _TRIED:
        return _COMPILED
    with _LOCK:
        if not _TRIED:
            _COMPILED = _compile()
            _TRIED = True
    return _COMPILED


def _compile() -> SimpleNamespace | None:
    try:
        import numba
    except ImportError:
        return None
    jit = numba.njit(cache=True, nogil=True, fastmath=False, boundscheck=False)
    return SimpleNamespace(**{name: jit(loop) for name, loop in LOOPS.items()})


# The loops, written in numba's subset of Python. They are plain functions until compiled and run
# (slowly) as such: the tests run them uncompiled too, which checks the algorithm apart from numba.


def _maxima(
    d2: np.ndarray,
    row: np.ndarray,
    t: np.ndarray,
    plat: np.ndarray,
    lo: int,
    hi: int,
    c1: float,
    const: float,
    log_tau: np.ndarray,
    log_k: np.ndarray,
) -> Any:
    """The log weights of one block's candidates, in place, and their maxima.

    ``d2`` becomes ``d2 * c1 - const (+ log_tau[row, t]) (+ log_k[row, plat])`` (``log_tau``/``log_k``
    of shape ``(0, 0)`` mean "none"). Returns ``(pair_best, best)``: the largest log weight of each
    (locale, platform) pair, a run of equal ``(row, plat)``, stored at the run's first entry, and of
    each locale ``lo .. hi - 1`` (``-inf`` for a locale without candidates).
    """
    size = d2.size
    best = np.full(hi - lo, -np.inf)
    pair_best = np.empty(size)
    has_tau = log_tau.shape[0] > 0
    has_k = log_k.shape[0] > 0
    i = 0
    while i < size:
        r, p = row[i], plat[i]
        m = -np.inf
        j = i
        while j < size and row[j] == r and plat[j] == p:
            a = d2[j] * c1
            a = a - const
            if has_tau:
                a = a + log_tau[r, t[j]]
            if has_k:
                a = a + log_k[r, p]
            d2[j] = a
            if a > m:
                m = a
            j += 1
        pair_best[i] = m
        if m > best[r - lo]:
            best[r - lo] = m
        i = j
    return pair_best, best


def _keep(
    a: np.ndarray,
    row: np.ndarray,
    t: np.ndarray,
    plat: np.ndarray,
    lo: int,
    pair_best: np.ndarray,
    best: np.ndarray,
    margin: float,
    underflow: float,
) -> int:
    """The gate on one block's log weights ``a`` (maxima from :func:`_maxima`), in place: a triple is
    kept when ``a >= max(pair_best - margin, best - underflow)``; the kept ones are moved to the front
    of ``a`` (as ``a - best``), ``row`` (made local, ``row - lo``), ``t`` and ``plat``. Returns how
    many were kept."""
    size = a.size
    kept = 0
    i = 0
    while i < size:
        j = i + 1
        while j < size and row[j] == row[i] and plat[j] == plat[i]:
            j += 1
        local = row[i] - lo
        threshold = max(pair_best[i] - margin, best[local] - underflow)
        for q in range(i, j):
            if a[q] >= threshold:
                a[kept] = a[q] - best[local]
                row[kept] = local
                t[kept] = t[q]
                plat[kept] = plat[q]
                kept += 1
        i = j
    return kept


def _normalise(a: np.ndarray, local: np.ndarray, n: int) -> np.ndarray:
    """Each locale's sum ``s`` of the weights ``a`` (in the order of the triples, as ``np.bincount``
    adds), and ``a`` divided by it in place as ``a * (1 / s)[local]``. Returns ``s``."""
    s = np.zeros(n)
    for i in range(a.size):
        s[local[i]] += a[i]
    inv = 1.0 / s
    for i in range(a.size):
        a[i] = a[i] * inv[local[i]]
    return s


def _prepare(
    w: np.ndarray,
    local: np.ndarray,
    t: np.ndarray,
    plat: np.ndarray,
    zx: np.ndarray,
    zy: np.ndarray,
    M: int,
    n: int,
    col: np.ndarray,
    wzx: np.ndarray,
    wzy: np.ndarray,
    platform: np.ndarray,
    counts: np.ndarray,
    largest: np.ndarray,
    best_column: np.ndarray,
) -> None:
    """A gated block's columns ``t M + plat``, products with the locales' coordinates (``zx``, ``zy``
    of the block's locales), platform totals ``(n, M)`` (summed in order), entries per row, and each
    row's largest weight and smallest column holding it; into the given arrays."""
    for k in range(n):
        counts[k] = 0
        largest[k] = -np.inf
        best_column[k] = 0
    for q in range(n * M):
        platform.flat[q] = 0.0
    for i in range(w.size):
        k = local[i]
        c = t[i] * M + plat[i]
        col[i] = c
        wzx[i] = w[i] * zx[k]
        wzy[i] = w[i] * zy[k]
        platform[k, plat[i]] += w[i]
        counts[k] += 1
        # The largest weight and the smallest column among its ties (as np.argmax of the dense row).
        if w[i] > largest[k] or (w[i] == largest[k] and c < best_column[k]):
            largest[k] = w[i]
            best_column[k] = c


def _accumulate(sums: np.ndarray, col: np.ndarray, w: np.ndarray, wzx: np.ndarray, wzy: np.ndarray) -> None:
    """``sums[col] += (w, wzx, wzy)``, in the order of the triples (as ``np.add.at``); ``sums`` is
    ``(T M, 3)``, the three sums of a column side by side in memory."""
    for i in range(w.size):
        c = col[i]
        sums[c, 0] += w[i]
        sums[c, 1] += wzx[i]
        sums[c, 2] += wzy[i]


def _search(
    hits: np.ndarray,
    p0: int,
    p1: int,
    pair_n: np.ndarray,
    pair_m: np.ndarray,
    rho2: np.ndarray,
    points: np.ndarray,
    times: np.ndarray,
    zx: np.ndarray,
    zy: np.ndarray,
) -> Any:
    """The candidates of pairs ``p0 .. p1 - 1``: the points of the chunks each pair's disc meets
    (``hits``) within its squared radius ``rho2``, in the order of the pairs, their chunks and the
    points in a chunk. Returns ``(row, time, platform, squared distance)``."""
    K, C = points.shape[2], points.shape[3]
    total = 0
    for p in range(p0, p1):
        for k in range(K):
            if hits[p, k]:
                total += 1
    row = np.empty(total * C, dtype=np.intp)
    t = np.empty(total * C, dtype=np.intp)
    plat = np.empty(total * C, dtype=np.intp)
    d2 = np.empty(total * C)
    out = 0
    for p in range(p0, p1):
        n, m, r2 = pair_n[p], pair_m[p], rho2[p]
        x, y = zx[n], zy[n]
        for k in range(K):
            if not hits[p, k]:
                continue
            for c in range(C):
                dx = x - points[0, m, k, c]
                dx = dx * dx
                dy = y - points[1, m, k, c]
                dy = dy * dy
                d = dx + dy
                if d <= r2:
                    row[out] = n
                    t[out] = times[m, k * C + c]
                    plat[out] = m
                    d2[out] = d
                    out += 1
    return row[:out], t[:out], plat[:out], d2[:out]


#: The loops by the names the E-step calls them, uncompiled (:func:`compiled` gives them compiled).
LOOPS: dict[str, Callable[..., Any]] = {
    "search": _search,
    "maxima": _maxima,
    "keep": _keep,
    "normalise": _normalise,
    "prepare": _prepare,
    "accumulate": _accumulate,
}
