"""Benchmark: exact solvers of the unconstrained M-step (one platform, one axis: a smoothing problem).

Every candidate solves the same batch of constant-acceleration smoothing problems (``M`` platforms,
the x and y axes as two columns sharing the weights) and is timed in interleaved rounds (one run of
each candidate per round, so a change of machine load hits all of them alike); medians are quoted
and compared as ratios to ``rts_smoother`` within the run. Accuracy is the largest position
difference to a reference: ``rts_smoother`` run in extended precision (``np.longdouble``) where that
is affordable, else ``rts_smoother`` itself.

Candidates:

* ``rts_smoother``: :func:`solvers.kalman.rts_smoother`, the existing batched RTS smoother (a
  Python loop over time).
* ``banded_kkt``: :class:`solvers.banded.BandedSmoother`, LU of the banded optimality system with
  the dynamics as constraints, one step of iterative refinement (the chosen kernel).
* ``banded_kkt_norefine``: the same without the refinement step.
* ``banded_kkt_function``: :func:`solvers.banded.banded_smoother`, the functional form (a cache
  lookup of the assembled band, then the same solve).
* ``kkt_solve_banded``: the same system unscaled, ``scipy.linalg.solve_banded`` per platform (both
  axes as right-hand sides), no refinement: the textbook use of scipy.
* ``normal_cholesky``: the information form ``(D' Q^-1 D + P) x = P y`` by a banded Cholesky
  (``scipy.linalg.solveh_banded``), all platforms in one band.
* ``normal_cholesky_refined``: the same with three steps of iterative refinement whose residual is
  evaluated from the factored form (``D' Q^-1 (D x)``).
* ``assoc_scan``: the RTS smoother as two associative (parallel-prefix) scans over time
  (Sarkka and Garcia-Fernandez, "Temporal parallelization of Bayesian smoothers", 2021), vectorised
  with numpy: a work-efficient scan of ``2 log2 T`` levels.

Cases: scenario-A-shaped batches (``M = 4``, ``T = 500``, ``dt = 1``, ``q = 1e-8``, ``r = 1e-2``) with
random weights, with coasting (exact zeros after a third of the horizon, one weighted step in the
middle), with the E-step weights of scenario A after 30 iterations of ``PMHTConfig.paper()``; a high
signal-to-noise corner (``q = 1e-4``, ``r = 1e-8``); and the scaling size ``M = 20``, ``T = 5000``.

    python studies/bench_smoother.py [--repeats 15] [--skip-large]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy
import scipy.linalg

from solvers.banded import BandedSmoother, banded_smoother
from solvers.kalman import rts_smoother

Array = np.ndarray
Solver = Callable[[Array, Array, float, Array, Array, Array], Array]
E1 = np.array([1.0, 0.0, 0.0])


def ca_model(dt: float, q: float) -> tuple[Array, Array]:
    """Constant-acceleration ``F`` and ``Q`` of one axis."""
    F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = q * np.array(
        [
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ]
    )
    return F, Q


def synthetic_batch(rng: np.random.Generator, M: int, T: int, kind: str) -> tuple[Array, Array, Array]:
    """Weights ``(M, T)``, measurements ``(M, T, 2)`` in the 10 x 10 box, starts ``(M, 3, 2)``."""
    if kind == "random":
        W = rng.random((M, T))
    else:  # coasting
        W = rng.random((M, T)) * (rng.random((M, T)) < 0.1)
        W[:, T // 3 :] = 0.0
        W[:, T // 2] = 0.7
    y = rng.uniform(0.0, 10.0, (M, T, 2))
    x0 = np.zeros((M, 3, 2))
    x0[:, 0, :] = rng.uniform(0.0, 10.0, (M, 2))
    return W, y, x0


def em_batch() -> tuple[Array, Array, Array, float, float, float] | None:
    """E-step weights of scenario A (seed 1) on the paths of 30 iterations of ``PMHTConfig.paper()``."""
    try:
        import pmht_opt as po
        from pmht_opt.estep import estep, safe_log
    except ImportError:  # pragma: no cover - the planner's layout may change
        return None
    sc = po.paper_scenario("A", seed=1)
    res = po.plan_pmht(sc, po.PMHTConfig.paper(solver="kalman", max_iter=30))
    es = estep(sc.locales, res.states[:, 1:, [0, 3]], None, safe_log(res.platform_prior), sc.r)
    W = np.asarray(es.W).T  # (M, T)
    WZ = np.asarray(es.WZ).transpose(1, 0, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        y = np.where(W[..., None] > 0, WZ / W[..., None], 0.0)
    x0 = np.stack([sc.initial_states[:, 0:3], sc.initial_states[:, 3:6]], axis=-1)
    return W, y, x0, float(sc.model.dt), float(sc.model.q), float(sc.r)


# -- candidates ---------------------------------------------------------------------------------


def run_rts(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M = W.shape[0]
    res = rts_smoother(F, Q, E1[None], np.array([[r]]), x0, np.zeros((M, 3, 3)), y[:, :, None, :], W)
    return res.means


def make_banded(F: Array, Q: Array, W: Array, refine: int) -> Solver:
    """Built once per model and size, as an EM loop would hold it."""
    smoother = BandedSmoother(F, Q, E1, W.shape[1], W.shape[0])

    def run(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
        return smoother.solve(r, x0, y, W, refine=refine).means

    return run


def run_banded_function(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """The functional form, which finds its assembled band in a cache."""
    return banded_smoother(F, Q, E1, r, x0, y, W).means


def run_kkt_solve_banded(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """Unscaled KKT ``[lam_t, x_t]`` per platform with ``scipy.linalg.solve_banded``."""
    M, T = W.shape
    n = 3
    N = 2 * n * T
    k = n  # F upper triangular, position measured: half-bandwidth n
    ab0 = np.zeros((2 * k + 1, N))

    def put(r0: Array, c0: Array, mat: Array) -> None:
        a, c = np.nonzero(mat)
        rows = (r0[:, None] + a).ravel()
        cols = (c0[:, None] + c).ravel()
        ab0[k + rows - cols, cols] = np.broadcast_to(mat[a, c], (r0.size, a.size)).ravel()

    starts = 2 * n * np.arange(T)
    put(starts, starts, -Q)
    put(starts, starts + n, np.eye(n))
    put(starts + n, starts, np.eye(n))
    put(starts[1:], starts[1:] - n, -F)
    put(starts[1:] - n, starts[1:], -F.T)
    out = np.empty((M, T + 1, n, 2))
    for m in range(M):
        ab = ab0.copy()
        rho = W[m] / r
        ab[k, starts + n] += rho
        rhs = np.zeros((T, 2 * n, 2))
        rhs[:, n, :] = rho[:, None] * y[m]
        rhs[0, :n, :] = F @ x0[m]
        z = scipy.linalg.solve_banded((k, k), ab, rhs.reshape(N, 2), check_finite=False)
        out[m, 0] = x0[m]
        out[m, 1:] = z.reshape(T, 2 * n, 2)[:, n:, :]
    return out


def _normal_band(F: Array, Q: Array, r: float, W: Array) -> tuple[Array, Array]:
    """Upper band of ``D' Q^-1 D + P`` for the stacked platforms, and ``Q^-1``."""
    M, T = W.shape
    n = 3
    Qi = np.linalg.inv(Q)
    Qi = 0.5 * (Qi + Qi.T)
    diag_inner = Qi + F.T @ Qi @ F
    off = -Qi @ F  # block (t, t-1)
    u = 2 * n - 1
    N = M * n * T
    ab = np.zeros((u + 1, N))
    blocks = M * T
    last = (np.arange(blocks) % T) == T - 1
    first = (np.arange(blocks) % T) == 0
    for a in range(n):
        for c in range(a, n):
            cols = n * np.arange(blocks) + c
            ab[u + a - c, cols] = np.where(last, Qi[a, c], diag_inner[a, c])
    for a in range(n):  # row in block t-1 (component a), column in block t (component c): off[c, a]
        for c in range(n):
            cols = n * np.arange(blocks) + c
            ab[u + (a - n) - c, cols] = np.where(first, 0.0, off[c, a])
    ab[u, n * np.arange(blocks)] += (W / r).ravel()
    return ab, Qi


def _normal_rhs(F: Array, Qi: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M, T = W.shape
    rhs = np.zeros((M, T, 3, 2))
    rhs[:, :, 0, :] = (W / r)[..., None] * y
    rhs[:, 0] += np.einsum("ij,mjk->mik", Qi @ F, x0)
    return rhs


def make_normal(refine: int) -> Solver:
    def run(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
        M, T = W.shape
        ab, Qi = _normal_band(F, Q, r, W)
        rhs = _normal_rhs(F, Qi, r, W, y, x0)
        cb = scipy.linalg.cholesky_banded(ab, check_finite=False)
        x = scipy.linalg.cho_solve_banded((cb, False), rhs.reshape(-1, 2), check_finite=False)
        for _ in range(refine):
            s = x.reshape(M, T, 3, 2)
            prev = np.concatenate([x0[:, None], s[:, :-1]], axis=1)
            e = s - np.einsum("ij,mtjk->mtik", F, prev)  # x_t - F x_{t-1}, x_0 included
            g = np.einsum("ij,mtjk->mtik", Qi, e)
            Hx = g.copy()
            Hx[:, :-1] -= np.einsum("ji,mtjk->mtik", F, g[:, 1:])
            res = np.zeros_like(s)
            res[:, :, 0, :] = (W / r)[..., None] * (y - s[:, :, 0, :])
            res -= Hx
            x = x + scipy.linalg.cho_solve_banded((cb, False), res.reshape(-1, 2), check_finite=False)
        out = np.empty((M, T + 1, 3, 2))
        out[:, 0] = x0
        out[:, 1:] = x.reshape(M, T, 3, 2)
        return out

    return run


def _inv3(A: Array) -> Array:
    """Inverses of a stack of 3 x 3 matrices by cofactors (numpy's batched inverse loops in C
    over LAPACK calls and is several times slower at this size)."""
    a, b, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    d, e, f = A[..., 1, 0], A[..., 1, 1], A[..., 1, 2]
    g, h, i = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
    co = np.empty_like(A)
    co[..., 0, 0] = e * i - f * h
    co[..., 0, 1] = c * h - b * i
    co[..., 0, 2] = b * f - c * e
    co[..., 1, 0] = f * g - d * i
    co[..., 1, 1] = a * i - c * g
    co[..., 1, 2] = c * d - a * f
    co[..., 2, 0] = d * h - e * g
    co[..., 2, 1] = b * g - a * h
    co[..., 2, 2] = a * e - b * d
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    return co / det[..., None, None]


def _prefix_scan(elems: tuple[Array, ...], combine: Callable[..., tuple[Array, ...]]) -> tuple[Array, ...]:
    """Inclusive prefix products along axis 1 with ``2 log2 L`` vectorised levels (work ``O(L)``)."""
    L = elems[0].shape[1]
    if L == 1:
        return elems
    even = tuple(e[:, 0 : L - 1 : 2] for e in elems)
    odd = tuple(e[:, 1:L:2] for e in elems)
    pref = _prefix_scan(combine(even, odd), combine)  # pref[i] = e_0 ... e_{2i+1}
    out = tuple(np.empty_like(e) for e in elems)
    for o, p, e in zip(out, pref, elems, strict=True):
        o[:, 1::2] = p
        o[:, 0] = e[:, 0]
    rest = tuple(e[:, 2::2] for e in elems)
    if rest[0].shape[1]:
        joined = combine(tuple(p[:, : rest[0].shape[1]] for p in pref), rest)
        for o, j in zip(out, joined, strict=True):
            o[:, 2::2] = j
    return out


def _filter_combine(first: tuple[Array, ...], second: tuple[Array, ...]) -> tuple[Array, ...]:
    Ai, bi, Ci, ei, Ji = first
    Aj, bj, Cj, ej, Jj = second
    eye = np.eye(Ai.shape[-1])
    Mx = _inv3(eye + Ci @ Jj)
    AjM = Aj @ Mx
    MtT = np.swapaxes(Mx, -1, -2)  # (I + J C)^-1 = ((I + C J)^-1)' for symmetric C, J
    AiT = np.swapaxes(Ai, -1, -2)
    AiTM = AiT @ MtT
    A = AjM @ Ai
    b = AjM @ (bi + Ci @ ej) + bj
    C = AjM @ Ci @ np.swapaxes(Aj, -1, -2) + Cj
    e = AiTM @ (ej - Jj @ bi) + ei
    J = AiTM @ Jj @ Ai + Ji
    return A, b, C, e, J


def _smoother_combine(later: tuple[Array, ...], earlier: tuple[Array, ...]) -> tuple[Array, ...]:
    """Reversed-time order: ``later`` holds the suffix already combined, ``earlier`` the new steps."""
    El, gl = later
    Ee, ge = earlier
    return Ee @ El, Ee @ gl + ge


def run_assoc_scan(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    M, T = W.shape
    n = 3
    h = E1
    Sinv = W / (W * (h @ Q @ h) + r)  # 1 / (h'Qh + r / w), zero without a measurement
    Kg = (Q @ h)[None, None, :] * Sinv[..., None]  # (M, T, n)
    hF = h @ F
    A = np.broadcast_to(F, (M, T, n, n)) - Kg[..., :, None] * hF[None, None, None, :]
    C = np.broadcast_to(Q, (M, T, n, n)) - Kg[..., :, None] * (h @ Q)[None, None, None, :]
    b = Kg[..., :, None] * y[:, :, None, :]  # (M, T, n, 2)
    Fh = F.T @ h
    eta = Fh[None, None, :, None] * (Sinv[..., None] * y)[:, :, None, :]
    J = np.outer(Fh, Fh)[None, None] * Sinv[..., None, None]
    # The first step starts from the known x0 (no prior covariance).
    pred = np.einsum("ij,mjk->mik", F, x0)
    A = A.copy()
    A[:, 0] = 0.0
    b[:, 0] = pred + Kg[:, 0, :, None] * (y[:, 0, None, :] - pred[:, 0:1, :])
    eta[:, 0] = 0.0
    J = J.copy()
    J[:, 0] = 0.0
    _, mf, Pf, _, _ = _prefix_scan((A, b, C, eta, J), _filter_combine)
    # Smoother elements E_t = Pf_t F' (F Pf_t F' + Q)^-1, g_t = m_t - E_t F m_t; E_T = 0, g_T = m_T.
    E = np.zeros((M, T, n, n))
    Pp = F @ Pf[:, :-1] @ F.T + Q
    E[:, :-1] = Pf[:, :-1] @ F.T @ _inv3(Pp)
    g = mf - E @ (F @ mf)
    _, gs = _prefix_scan((E[:, ::-1], g[:, ::-1]), _smoother_combine)
    out = np.empty((M, T + 1, n, 2))
    out[:, 0] = x0
    out[:, 1:] = gs[:, ::-1]
    return out


# -- reference -----------------------------------------------------------------------------------


def _ld_solve(A: Array, B: Array) -> Array:
    n = A.shape[0]
    Mx = np.concatenate([A, B], axis=1)
    for c in range(n):
        p = c + int(np.argmax(np.abs(Mx[c:, c])))
        Mx[[c, p]] = Mx[[p, c]]
        Mx[c] = Mx[c] / Mx[c, c]
        for i in range(n):
            if i != c:
                Mx[i] = Mx[i] - Mx[i, c] * Mx[c]
    return Mx[:, n:]


def rts_extended(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """``rts_smoother`` in ``np.longdouble`` (64-bit mantissa on x86-64), positions ``(M, T+1, 2)``."""
    ld = np.longdouble
    Fl, Ql, h = F.astype(ld), Q.astype(ld), E1.astype(ld)
    M, T = W.shape
    out = np.empty((M, T + 1, 2), dtype=ld)
    for m in range(M):
        mean = x0[m].astype(ld)  # (n, 2)
        P = np.zeros((3, 3), dtype=ld)
        mf, Pf, mp, Pp = [mean], [P], [mean], [P]
        for t in range(T):
            mean = Fl @ mean
            P = Fl @ P @ Fl.T + Ql
            mp.append(mean)
            Pp.append(P)
            if W[m, t] > 0:
                Ph = P @ h
                gain = Ph / (h @ Ph + ld(r) / ld(W[m, t]))
                mean = mean + np.outer(gain, y[m, t].astype(ld) - h @ mean)
                P = P - np.outer(gain, Ph)
            mf.append(mean)
            Pf.append(P)
        ms = mf[T]
        out[m, T] = ms[0]
        for t in range(T - 1, -1, -1):
            G = _ld_solve(Pp[t + 1], Fl @ Pf[t]).T
            ms = mf[t] + G @ (ms - mp[t + 1])
            out[m, t] = ms[0]
    return out


# -- driver --------------------------------------------------------------------------------------


def commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):  # pragma: no cover - not a checkout
        return "unknown"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:  # pragma: no cover - not Linux
        pass
    return platform.processor()


def bench_case(
    name: str,
    F: Array,
    Q: Array,
    r: float,
    W: Array,
    y: Array,
    x0: Array,
    repeats: int,
    extended: int,
    skip: set[str],
) -> dict[str, object]:
    """Time every candidate and compare positions; ``extended`` systems get the extended-precision
    reference (all of them when it is at least ``M``, none when 0)."""
    candidates: dict[str, Solver] = {
        "rts_smoother": run_rts,
        "banded_kkt": make_banded(F, Q, W, refine=1),
        "banded_kkt_norefine": make_banded(F, Q, W, refine=0),
        "banded_kkt_function": run_banded_function,
        "kkt_solve_banded": run_kkt_solve_banded,
        "normal_cholesky": make_normal(0),
        "normal_cholesky_refined": make_normal(3),
        "assoc_scan": run_assoc_scan,
    }
    candidates = {k: v for k, v in candidates.items() if k not in skip}
    outputs: dict[str, Array] = {}
    failures: dict[str, str] = {}
    for cname, fn in candidates.items():  # warm-up, and the answers compared below
        try:
            outputs[cname] = fn(F, Q, r, W, y, x0)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            failures[cname] = f"{type(exc).__name__}: {exc}"
    times: dict[str, list[float]] = {c: [] for c in outputs}
    for _ in range(repeats):
        for cname in outputs:
            t0 = time.perf_counter()
            candidates[cname](F, Q, r, W, y, x0)
            times[cname].append(time.perf_counter() - t0)
    rts_pos = outputs["rts_smoother"][:, :, 0, :]
    ref_name = "rts_smoother"
    ref = rts_pos
    sub = W.shape[0]
    if extended > 0:
        sub = min(extended, W.shape[0])
        ref = rts_extended(F, Q, r, W[:sub], y[:sub], x0[:sub]).astype(float)
        ref_name = "rts_smoother in extended precision"
        if sub < W.shape[0]:
            ref_name += f" (first {sub} of {W.shape[0]} platforms)"
    t_rts = float(np.median(times["rts_smoother"]))
    rows: dict[str, object] = {}
    print(f"\n{name}: M={W.shape[0]}, T={W.shape[1]}, r={r:g}; reference: {ref_name}")
    print(f"  {'candidate':<24} {'median ms':>10} {'x RTS':>7} {'max |dp| ref':>13} {'max |dp| RTS':>13}")
    for cname in outputs:
        pos = outputs[cname][:, :, 0, :]
        med = float(np.median(times[cname]))
        row = {
            "median_ms": 1e3 * med,
            "min_ms": 1e3 * float(np.min(times[cname])),
            "ratio_to_rts": med / t_rts,
            "max_position_diff_to_reference": float(np.max(np.abs(pos[:sub] - ref))),
            "max_position_diff_to_rts": float(np.max(np.abs(pos - rts_pos))),
            "runs_ms": [round(1e3 * t, 3) for t in times[cname]],
        }
        rows[cname] = row
        print(
            f"  {cname:<24} {row['median_ms']:>10.3f} {row['ratio_to_rts']:>7.3f} "
            f"{row['max_position_diff_to_reference']:>13.1e} {row['max_position_diff_to_rts']:>13.1e}"
        )
    for cname, msg in failures.items():
        rows[cname] = {"failed": msg}
        print(f"  {cname:<24} failed: {msg}")
    return {
        "M": int(W.shape[0]),
        "T": int(W.shape[1]),
        "r": r,
        "zero_weight_fraction": float(np.mean(W == 0)),
        "max_abs_position": float(np.max(np.abs(rts_pos))),
        "reference": ref_name,
        "candidates": rows,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--large-repeats", type=int, default=5)
    parser.add_argument("--skip-large", action="store_true", help="skip M = 20, T = 5000")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_smoother.json")
    args = parser.parse_args()

    load_before = os.getloadavg()
    rng = np.random.default_rng(2024)
    F, Q = ca_model(1.0, 1e-8)
    cases: dict[str, dict[str, object]] = {}
    for kind in ("random", "coast"):
        W, y, x0 = synthetic_batch(rng, 4, 500, kind)
        cases[f"A-shaped, {kind} weights"] = bench_case(
            f"A-shaped, {kind} weights", F, Q, 1e-2, W, y, x0, args.repeats, 4, set()
        )
    em = em_batch()
    if em is not None:
        W, y, x0, dt, q, r = em
        Fm, Qm = ca_model(dt, q)
        label = "scenario A, E-step weights after 30 paper iterations"
        cases[label] = bench_case(label, Fm, Qm, r, W, y, x0, args.repeats, 4, set())
    Fh, Qh = ca_model(1.0, 1e-4)
    W, y, x0 = synthetic_batch(rng, 4, 500, "random")
    cases["A-shaped, high signal-to-noise (q=1e-4, r=1e-8)"] = bench_case(
        "A-shaped, high signal-to-noise (q=1e-4, r=1e-8)", Fh, Qh, 1e-8, W, y, x0, args.repeats, 4, set()
    )
    if not args.skip_large:
        for kind in ("random", "coast"):
            W, y, x0 = synthetic_batch(rng, 20, 5000, kind)
            cases[f"M=20, T=5000, {kind} weights"] = bench_case(
                f"M=20, T=5000, {kind} weights", F, Q, 1e-2, W, y, x0, args.large_repeats, 2, set()
            )
    payload = {
        "benchmark": "exact solvers of the unconstrained M-step, median of interleaved runs",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "commit": commit(),
        "machine": {
            "cpus": os.cpu_count(),
            "cpu": cpu_model(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "load_average_before": [round(v, 2) for v in load_before],
            "load_average_after": [round(v, 2) for v in os.getloadavg()],
        },
        "repeats": args.repeats,
        "large_repeats": args.large_repeats,
        "cases": cases,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"\nload average before {load_before}, after {os.getloadavg()}; written: {args.out}")


if __name__ == "__main__":
    main()
