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
from pathlib import Path

import numpy as np
import scipy

from studies.report import write_text
from studies.smoother_candidates import (
    Array,
    Solver,
    make_banded,
    make_normal,
    run_assoc_scan,
    run_banded_function,
    run_kkt_solve_banded,
    run_rts,
)
from studies.smoother_reference import E1, ca_model, rts_extended


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


def reference_positions(F: Array, Q: Array, r: float, W: Array, y: Array, x0: Array) -> Array:
    """Positions ``(M, T+1, 2)`` of :func:`~studies.smoother_reference.rts_extended`, platform by
    platform (the x and y axes as its two columns)."""
    return np.array([rts_extended(F, Q, E1, r, x0[m], y[m], W[m])[:, 0] for m in range(W.shape[0])])


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


def candidates(F: Array, Q: Array, W: Array, skip: set[str]) -> dict[str, Solver]:
    """Every candidate not in ``skip``; the banded ones built for this model and size."""
    every: dict[str, Solver] = {
        "rts_smoother": run_rts,
        "banded_kkt": make_banded(F, Q, W, refine=1),
        "banded_kkt_norefine": make_banded(F, Q, W, refine=0),
        "banded_kkt_function": run_banded_function,
        "kkt_solve_banded": run_kkt_solve_banded,
        "normal_cholesky": make_normal(0),
        "normal_cholesky_refined": make_normal(3),
        "assoc_scan": run_assoc_scan,
    }
    return {k: v for k, v in every.items() if k not in skip}


def timed(
    solvers: dict[str, Solver], args: tuple[Array, Array, float, Array, Array, Array], repeats: int
) -> tuple[dict[str, Array], dict[str, list[float]], dict[str, str]]:
    """Each solver's answer (its warm-up run), its times over ``repeats`` interleaved rounds, and the
    failures of those that raised."""
    outputs: dict[str, Array] = {}
    failures: dict[str, str] = {}
    for cname, fn in solvers.items():  # warm-up, and the answers compared below
        try:
            outputs[cname] = fn(*args)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            failures[cname] = f"{type(exc).__name__}: {exc}"
    times: dict[str, list[float]] = {c: [] for c in outputs}
    for _ in range(repeats):
        for cname in outputs:
            t0 = time.perf_counter()
            solvers[cname](*args)
            times[cname].append(time.perf_counter() - t0)
    return outputs, times, failures


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
    outputs, times, failures = timed(candidates(F, Q, W, skip), (F, Q, r, W, y, x0), repeats)
    rts_pos = outputs["rts_smoother"][:, :, 0, :]
    ref_name = "rts_smoother"
    ref = rts_pos
    sub = W.shape[0]
    if extended > 0:
        sub = min(extended, W.shape[0])
        ref = reference_positions(F, Q, r, W[:sub], y[:sub], x0[:sub]).astype(float)
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


def run_cases(repeats: int, large_repeats: int, skip_large: bool) -> dict[str, dict[str, object]]:
    """Every case of the module notes, in order, each timed by :func:`bench_case`."""
    rng = np.random.default_rng(2024)
    F, Q = ca_model(1.0, 1e-8)
    cases: dict[str, dict[str, object]] = {}
    for kind in ("random", "coast"):
        W, y, x0 = synthetic_batch(rng, 4, 500, kind)
        label = f"A-shaped, {kind} weights"
        cases[label] = bench_case(label, F, Q, 1e-2, W, y, x0, repeats, 4, set())
    em = em_batch()
    if em is not None:
        W, y, x0, dt, q, r = em
        Fm, Qm = ca_model(dt, q)
        label = "scenario A, E-step weights after 30 paper iterations"
        cases[label] = bench_case(label, Fm, Qm, r, W, y, x0, repeats, 4, set())
    Fh, Qh = ca_model(1.0, 1e-4)
    W, y, x0 = synthetic_batch(rng, 4, 500, "random")
    label = "A-shaped, high signal-to-noise (q=1e-4, r=1e-8)"
    cases[label] = bench_case(label, Fh, Qh, 1e-8, W, y, x0, repeats, 4, set())
    if not skip_large:
        for kind in ("random", "coast"):
            W, y, x0 = synthetic_batch(rng, 20, 5000, kind)
            label = f"M=20, T=5000, {kind} weights"
            cases[label] = bench_case(label, F, Q, 1e-2, W, y, x0, large_repeats, 2, set())
    return cases


def main() -> None:
    """Run the benchmark and write its JSON (cases, machine, load before and after)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--large-repeats", type=int, default=5)
    parser.add_argument("--skip-large", action="store_true", help="skip M = 20, T = 5000")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_smoother.json")
    args = parser.parse_args()

    load_before = os.getloadavg()
    cases = run_cases(args.repeats, args.large_repeats, args.skip_large)
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
    written = write_text(args.out, json.dumps(payload, indent=2) + "\n")
    print(f"\nload average before {load_before}, after {os.getloadavg()}; written: {written}")


if __name__ == "__main__":
    main()
