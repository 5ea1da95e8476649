"""The exact smoother of a batch of systems (:mod:`solvers.banded`, whose notes say why it is built so):
the band of the optimality conditions, its LU by parts, the solve with one step of refinement, and the
factorisation kept for other right-hand sides (:class:`BandedFactor`)."""

from __future__ import annotations

import functools
import threading

import numpy as np
from numpy.typing import ArrayLike

from solvers.band_lu import BandLU
from solvers.banded.result import BandedSmootherResult
from solvers.exceptions import ProblemError
from solvers.problem import dense

__all__ = ["BandedFactor", "BandedSmoother"]

#: Steps of the batch (systems times horizon) per LAPACK call below which the batch is not split.
MIN_STEPS_PER_THREAD = 1000
#: Most LAPACK calls a solve is split into.
MAX_PARTS = 64


class BandedSmoother:
    """Exact smoother for a fixed model ``(F, Q, h)``, horizon ``T`` and batch size ``B``.

    Building it assembles the weight-independent part of the banded KKT matrix once; :meth:`solve`
    adds the weights, factorises and solves. Reuse one instance across calls with the same model
    and sizes (an EM loop); :func:`banded_smoother` keeps a few in a cache. Instances may be shared
    between threads: each thread gets its own work arrays.

    Parameters
    ----------
    F
        ``(n, n)`` transition matrix.
    Q
        ``(n, n)`` process noise covariance, symmetric positive definite.
    h
        ``(n,)`` measurement vector: the scalar measurement is ``h' x_t``.
    horizon
        ``T >= 1``, the number of steps after the known ``x_0``.
    batch
        ``B >= 1``, the number of independent systems solved together.

    Raises
    ------
    ProblemError
        Wrong shapes, non-finite entries, ``Q`` not symmetric positive definite, ``h`` zero.

    Notes
    -----
    Memory: the band takes ``(3k + 1) * 2n * T * B`` doubles, twice (the assembled part and one work
    copy per thread): 96 MB for ``n = 3``, ``T = 5000``, ``B = 20``.
    """

    def __init__(self, F: ArrayLike, Q: ArrayLike, h: ArrayLike, horizon: int, batch: int) -> None:
        F = np.asarray(F, dtype=float)
        if F.ndim != 2 or F.shape[0] != F.shape[1] or F.shape[0] < 1:
            raise ProblemError(f"F must be a square matrix, got shape {F.shape}.")
        n = F.shape[0]
        F = dense("F", F, (n, n))
        Q = dense("Q", Q, (n, n))
        h = dense("h", h, (n,))
        if not np.allclose(Q, Q.T, rtol=1e-12, atol=0.0):
            raise ProblemError("Q must be symmetric.")
        try:
            L = np.linalg.cholesky(Q)
        except np.linalg.LinAlgError:
            raise ProblemError("Q must be positive definite.") from None
        if not np.any(h):
            raise ProblemError("h must not be zero.")
        if int(horizon) != horizon or horizon < 1:
            raise ProblemError(f"horizon must be a positive integer, got {horizon!r}.")
        if int(batch) != batch or batch < 1:
            raise ProblemError(f"batch must be a positive integer, got {batch!r}.")
        self.n, self.T, self.B = n, int(horizon), int(batch)
        self.F, self.Q, self.h, self.L = F.copy(), Q.copy(), h.copy(), L  # the caller's may change
        # Dimensionless unknowns: x = d * xs, lam = lam_s / d (module docstring).
        d = np.sqrt(np.diag(Q))
        self.d = d
        self.Fs = F * d[None, :] / d[:, None]
        self.Qs = Q / d[:, None] / d[None, :]
        self.hs = h * d
        # The same matrix as blocks acting on z_t = [lam_t, x_t] (2n): the diagonal block without
        # the penalty, the coupling of z_t's rows to z_{t-1} (lam_t to x_{t-1}) and to z_{t+1}.
        eye, zero = np.eye(n), np.zeros((n, n))
        self._A0 = np.block([[-self.Qs, eye], [eye, zero]])
        self._Aprev = np.block([[zero, -self.Fs], [zero, zero]])
        self._Anext = self._Aprev.T.copy()
        self._A0_neg_T = -self._A0.T
        self._Aprev_T = self._Aprev.T.copy()
        self._Anext_T = self._Anext.T.copy()
        self._hz = np.concatenate([np.zeros(n), self.hs])  # penalty direction in z_t
        # Where h picks one component (a position measured), the penalty's products touch that column
        # of z_t only: ``z @ hz`` is then ``z[..., i] * hz[i]`` exactly (the other terms are exact
        # zeros), and the rest of a product with ``hz`` is zeros, so that column alone is worked on.
        nonzero = np.flatnonzero(self._hz)
        self._pick = int(nonzero[0]) if nonzero.size == 1 else None
        self._unscale = np.concatenate([1.0 / d, d])  # z_t -> [lam_t, x_t] in the model's units
        self._build_band()
        self._local = threading.local()

    def __getstate__(self) -> dict[str, object]:
        state = self.__dict__.copy()
        del state["_local"]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._local = threading.local()

    # -- assembly -------------------------------------------------------------------------------

    def _build_band(self) -> None:
        """LAPACK band storage of the weight-independent part of the KKT matrix for the batch."""
        n, T, B = self.n, self.T, self.B
        steps = T * B
        self.N = N = 2 * n * steps
        starts = 2 * n * np.arange(steps)  # column of lam_t for every (system, step)
        later = starts[np.arange(steps) % T != 0]  # steps with a predecessor (t > 1)
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []
        vals: list[np.ndarray] = []

        def block(r0: np.ndarray, c0: np.ndarray, mat: np.ndarray) -> None:
            a, c = np.nonzero(mat)
            rows.append((r0[:, None] + a).ravel())
            cols.append((c0[:, None] + c).ravel())
            vals.append(np.broadcast_to(mat[a, c], (r0.size, a.size)).ravel())

        block(starts, starts, self._A0)
        block(later, later - 2 * n, self._Aprev)
        block(later - 2 * n, later, self._Anext)
        i = np.concatenate(rows)
        j = np.concatenate(cols)
        v = np.concatenate(vals)
        # Half-bandwidth: that of the pattern including the penalty block h h' on (x_t, x_t).
        pa, pc = np.nonzero(np.outer(self.hs, self.hs))
        k = int(max(np.max(np.abs(i - j)), np.max(np.abs(pa - pc), initial=0)))
        self.k = k
        width = 3 * k + 1  # gbtrf storage: A[i, j] at ab[2k + i - j, j], k rows of fill-in on top
        # Kept transposed, (N, 3k + 1) in C order, so that its ``.T`` is the column-major array
        # LAPACK works on in place.
        band = np.zeros((N, width))
        band[j, 2 * k + i - j] = v
        self._band_T = band
        xcol = (starts + n).reshape(B, T)
        self._pen_index = [(xcol + c) * width + 2 * k + a - c for a, c in zip(pa, pc, strict=True)]
        self._pen_value = [float(self.hs[a] * self.hs[c]) for a, c in zip(pa, pc, strict=True)]

    def _work(self) -> np.ndarray:
        """This thread's copy of the band, to be factorised in place."""
        work: np.ndarray | None = getattr(self._local, "band", None)
        if work is None:
            work = np.empty_like(self._band_T)
            self._local.band = work
        return work

    # -- solve ----------------------------------------------------------------------------------

    def solve(
        self,
        r: float,
        x0: ArrayLike,
        y: ArrayLike,
        weight: ArrayLike,
        *,
        refine: int = 1,
        check: bool = False,
        threads: int = 1,
    ) -> BandedSmootherResult:
        """Smooth the batch for these weights and measurements.

        Parameters
        ----------
        r
            Unit-weight measurement variance, ``r > 0``: the variance at step ``t`` is ``r / w_t``.
        x0
            ``(B, n, K)`` known initial states; the ``K`` columns share the weights.
        y
            ``(B, T, K)`` measurements for ``t = 1..T``; their value does not matter where the
            weight is zero, but it must be finite.
        weight
            ``(B, T)`` non-negative weights ``w_t``.
        refine
            Steps of iterative refinement after the LU solve (``>= 0``). One brings the
            componentwise backward error to the rounding level (module docstring) for about half
            as much time again; ``0`` is faster but only normwise stable, which can cost digits
            on long coasting stretches with a small ``r``.
        check
            Also compute the componentwise backward error of the final solution (reported in
            :attr:`BandedSmootherResult.backward_error`), at the cost of two residual evaluations.
        threads
            Factorise and solve the groups of systems of the batch on up to this many concurrent
            threads (:class:`solvers.band_lu.BandLU`; LAPACK runs without the interpreter lock). The
            groups depend on the batch's size only, so the answer is the same to the last bit for
            any number of threads.

        Returns
        -------
        BandedSmootherResult

        Raises
        ------
        ProblemError
            Wrong shapes, non-finite data, negative weights, ``r <= 0``, or weights so large
            relative to ``r`` that the system cannot be represented.
        """
        r, x0, y, rho = self._data(r, x0, y, weight, refine)
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ProblemError(f"threads must be a positive integer, got {threads!r}.")
        n, K = self.n, x0.shape[2]
        # Unknowns and right-hand sides as (K, B, T, 2n), rows z_t = [lam_t, x_t] (scaled): the
        # transpose of the column-major (N, K) array LAPACK works on.
        xs0 = np.moveaxis(x0, 2, 0) / self.d  # (K, B, n)
        yk = np.moveaxis(y, 2, 0)  # (K, B, T)
        if self._pick is None:
            rhs = (rho * yk)[..., None] * self._hz
        else:
            rhs = np.zeros((K, self.B, self.T, 2 * n))
            rhs[..., self._pick] = (rho * yk) * self._hz[self._pick]
        rhs[:, :, 0, :n] += xs0 @ self.Fs.T

        band = self._work()
        b = rhs.reshape(K, self.N).T  # (N, K), column-major: LAPACK works on it in place
        try:
            lu = self._factorise(band, rho, b, threads)
        except BaseException:
            self._local.band = None  # never reused after a failure, whatever may still touch it
            raise
        z = b.T.reshape(rhs.shape)  # b was solved in place (``rhs.reshape`` may have copied)
        for _ in range(int(refine)):
            correction = self._residual(z, xs0, yk, rho).reshape(K, self.N).T
            lu.solve(correction)
            z += correction.T.reshape(z.shape)
        if not np.all(np.isfinite(z)):
            raise ProblemError("The solve produced non-finite values: the data are out of range.")
        backward_error = self._backward_error(z, xs0, yk, rho) if check else None
        return self._result(z, x0, yk, rho, backward_error)

    def factor(self, r: float, weight: ArrayLike, *, threads: int = 1) -> BandedFactor:
        """The KKT matrix of these weights factorised, to be solved for any forcing
        (:class:`BandedFactor`): the same matrix :meth:`solve` factorises, kept.

        Raises
        ------
        ProblemError
            As :meth:`solve`, for ``r`` and ``weight``.
        """
        zero = np.zeros((self.B, self.n, 1))
        r, _, _, rho = self._data(r, zero, np.zeros((self.B, self.T, 1)), weight, 0)
        lu = self._factorise(np.empty_like(self._band_T), rho, np.zeros((self.N, 1), order="F"), threads)
        return BandedFactor(self, rho, lu)

    def _factorise(self, band: np.ndarray, rho: np.ndarray, b: np.ndarray, threads: int) -> BandLU:
        """``band`` (a work array of the band's shape) set to the KKT matrix for the penalties ``rho``,
        factorised in place and ``b`` solved in place."""
        np.copyto(band, self._band_T)
        flat = band.reshape(-1)
        for index, value in zip(self._pen_index, self._pen_value, strict=True):
            flat[index] += rho * value
        try:
            return BandLU(band.T, self.k, b, self._parts(), threads)
        except np.linalg.LinAlgError as err:
            raise ProblemError(
                f"The KKT matrix is numerically singular ({err}): the weights or r are out of range."
            ) from None

    def _parts(self) -> list[tuple[int, int]]:
        """Rows ``[lo, hi)`` of the groups of whole systems that LAPACK factorises one call each: about
        :data:`MIN_STEPS_PER_THREAD` steps per group, at most one system each and at most
        :data:`MAX_PARTS`. They depend on the batch's size only, never on the number of threads, so
        neither does the answer."""
        return list(_groups(self.B, self.T, self.n, MIN_STEPS_PER_THREAD, MAX_PARTS))

    def _data(
        self, r: float, x0: ArrayLike, y: ArrayLike, weight: ArrayLike, refine: int
    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """The arguments of :meth:`solve` checked: ``r``, ``x0 (B, n, K)``, ``y (B, T, K)`` and the
        penalties ``rho = w / r (B, T)``; :class:`ProblemError` naming the first that is wrong."""
        n, T, B = self.n, self.T, self.B
        r = float(r)
        if not (np.isfinite(r) and r > 0.0):
            raise ProblemError(f"r must be a positive finite number, got {r!r}.")
        x0 = np.asarray(x0, dtype=float)
        if x0.ndim != 3 or x0.shape[2] < 1:
            raise ProblemError(f"x0 must have shape (B, n, K) = ({B}, {n}, K >= 1), got {x0.shape}.")
        K = x0.shape[2]
        x0 = dense("x0", x0, (B, n, K))
        y = dense("y", y, (B, T, K))
        w = dense("weight", weight, (B, T))
        if np.any(w < 0):
            raise ProblemError("weight has negative entries.")
        if int(refine) != refine or refine < 0:
            raise ProblemError(f"refine must be a non-negative integer, got {refine!r}.")
        with np.errstate(over="ignore"):
            rho = w / r
        if not np.all(np.isfinite(rho)):
            raise ProblemError("weight / r overflows: the weights are too large for this r.")
        return r, x0, y, rho

    def _result(
        self, z: np.ndarray, x0: np.ndarray, yk: np.ndarray, rho: np.ndarray, backward_error: float | None
    ) -> BandedSmootherResult:
        """The result of the scaled solution ``z`` (``(K, B, T, 2n)``, scaled in place back to the
        model's units). It keeps its own copies of the caller's ``x0`` and ``y``, which it reads
        when its parts are first asked for."""
        z *= self._unscale
        return BandedSmootherResult(z, x0.copy(), yk.copy(), rho, self.L, self.h, backward_error)

    def _residual(self, z: np.ndarray, xs0: np.ndarray, yk: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """``b - A z`` of the scaled KKT system, evaluated from its block form.

        The dynamics rows of step 1 take ``x_0`` as if it were an unknown (their right-hand side
        is then zero), and the penalty rows multiply the innovation ``y_t - h' x_t`` by the weight
        instead of forming the two large products separately.
        """
        n = self.n
        res = z @ self._A0_neg_T
        res[:, :, 1:] -= z[:, :, :-1] @ self._Aprev_T
        res[:, :, :-1] -= z[:, :, 1:] @ self._Anext_T
        res[:, :, 0, :n] += xs0 @ self.Fs.T
        if self._pick is None:
            res += (rho * (yk - z @ self._hz))[..., None] * self._hz
        else:
            i, hi = self._pick, self._hz[self._pick]
            res[..., i] += (rho * (yk - z[..., i] * hi)) * hi
        return res

    def _backward_error(self, z: np.ndarray, xs0: np.ndarray, yk: np.ndarray, rho: np.ndarray) -> float:
        """Componentwise backward error ``max_i |b - A z|_i / (|A| |z| + |b|)_i`` of ``z``.

        A row whose magnitude ``(|A| |z| + |b|)_i`` is below the rounding unit times the largest
        of its system is measured against that floor instead: where the solution is zero in exact
        arithmetic (the multipliers after the last measurement), the computed values are rounding
        noise whose relative residual says nothing about the solution.
        """
        n = self.n
        res = np.abs(self._residual(z, xs0, yk, rho))
        za = np.abs(z)
        hz = np.abs(self._hz)
        scale = za @ np.abs(self._A0).T
        scale[:, :, 1:] += za[:, :, :-1] @ np.abs(self._Aprev).T
        scale[:, :, :-1] += za[:, :, 1:] @ np.abs(self._Anext).T
        scale[:, :, 0, :n] += np.abs(xs0) @ np.abs(self.Fs).T
        scale += (rho * (np.abs(yk) + za @ hz))[..., None] * hz
        floor = np.finfo(float).eps * scale.max(axis=(2, 3), keepdims=True)
        denom = np.maximum(scale, floor)
        ratio = np.divide(res, denom, out=np.zeros_like(res), where=denom > 0)
        if np.any(res[denom == 0] > 0):  # pragma: no cover - a zero system with a residual
            return float(np.inf)
        return float(ratio.max())


class BandedFactor:
    r"""The factorised KKT matrix of :class:`BandedSmoother` for one set of weights
    (:meth:`BandedSmoother.factor`).

    :meth:`solve` returns the minimiser of ``J(x) - sum_t f_t' x_t`` for a forcing ``f``, ``J`` the
    smoother's objective with its measurements left out (the fit ``w_t / (2 r) (h' x_t)^2`` kept):
    the solution of ``(D' Q^-1 D + P) x = f`` with the start's term, ``P`` the penalty. With
    ``f_t = (w_t / r) y_t h`` it is the smoothed path; with ``x_0 = 0`` and ``f = c`` it is ``H^-1 c``,
    the response of the path to a force ``c``, which is what a constrained problem needs of ``H``.
    Each solve takes one step of iterative refinement by default, as :meth:`BandedSmoother.solve`.
    """

    def __init__(self, smoother: BandedSmoother, rho: np.ndarray, lu: BandLU) -> None:
        self.smoother, self.rho, self.lu = smoother, rho, lu

    def solve(
        self, forcing: ArrayLike, x0: ArrayLike | None = None, *, refine: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """The states and whitened process noise, both ``(B, T, n, K)``, for ``forcing (B, T, n, K)``
        on the states (the model's units) and the known starts ``x0 (B, n, K)`` (zero if ``None``).

        Raises
        ------
        ProblemError
            Wrong shapes or non-finite values.
        """
        s = self.smoother
        n, B, T = s.n, s.B, s.T
        f = np.asarray(forcing, dtype=float)
        if f.ndim != 4 or f.shape[3] < 1:
            raise ProblemError(
                f"forcing must have shape (B, T, n, K) = ({B}, {T}, {n}, K >= 1), got {f.shape}."
            )
        K = f.shape[3]
        f = dense("forcing", f, (B, T, n, K))
        x0a = np.zeros((B, n, K)) if x0 is None else dense("x0", x0, (B, n, K))
        if int(refine) != refine or refine < 0:
            raise ProblemError(f"refine must be a non-negative integer, got {refine!r}.")
        xs0 = np.moveaxis(x0a, 2, 0) / s.d  # (K, B, n)
        push = np.moveaxis(f, 3, 0) * s.d  # (K, B, T, n): the x rows scaled by d
        rhs = np.zeros((K, B, T, 2 * n))
        rhs[..., n:] = push
        rhs[:, :, 0, :n] += xs0 @ s.Fs.T
        b = rhs.reshape(K, s.N).T  # (N, K), column-major
        self.lu.solve(b)
        z = b.T.reshape(rhs.shape)
        no_y = np.zeros((K, B, T))
        for _ in range(int(refine)):
            res = s._residual(z, xs0, no_y, self.rho)
            res[..., n:] += push
            correction = res.reshape(K, s.N).T
            self.lu.solve(correction)
            z += correction.T.reshape(z.shape)
        if not np.all(np.isfinite(z)):
            raise ProblemError("The solve produced non-finite values: the data are out of range.")
        z *= s._unscale
        return np.moveaxis(z[..., n:], 0, -1), np.moveaxis(z[..., :n] @ s.L, 0, -1)


@functools.lru_cache(maxsize=64)
def _groups(B: int, T: int, n: int, min_steps: int, max_parts: int) -> tuple[tuple[int, int], ...]:
    """:meth:`BandedSmoother._parts` for a batch of ``B`` systems of ``T`` steps of ``n`` states (computed
    once per size: it is asked at every solve)."""
    groups = min(B, max_parts, max(1, (T * B) // min_steps))
    rows = 2 * n * T
    bounds = [len(g) for g in np.array_split(np.arange(B), groups)]
    ends = np.cumsum(bounds) * rows
    return tuple((int(lo), int(hi)) for lo, hi in zip(np.r_[0, ends[:-1]], ends, strict=True))
