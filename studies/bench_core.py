"""Benchmark: full PMHT plans of scenario A (N=100, M=4, T=500, 100 iterations) per backend.

For each backend, the median wall time of several plans with the default configuration (annealed EM,
gated E-step, ``tol = 0``), with the E-step / M-step split and the E-step's time per iteration after
annealing. Beside them, measured in the same run:

* an **independent reference**: the same 100 M-steps (the weights recorded from the default plan)
  smoothed by a plain Rauch-Tung-Struebel smoother written here, vectorised over platforms and axes
  with a Python loop over time (the usual way to write one), plus the default plan's E-step time;
* with ``--baseline DIR``, the **earlier code** in the git checkout ``DIR`` (its own
  ``studies/bench_core.py`` in a subprocess, one plan per backend and round): the ratio new / old per
  backend.

Everything runs in ``--repeats`` rounds, each with one plan per backend (``--fast-plans`` of the
default ``auto`` and of ``banded``, whose plans are short), the reference and the baseline's plans,
so that a change of load on a shared machine hits all of them; besides the ratio of the medians,
the median of the rounds' own ratios is reported.

Results (medians, all runs, provenance) go to ``studies/results/bench_core.json``. Targets on this
2-core machine: the default plan at most 0.35 s; every backend no slower than the baseline.

    python studies/bench_core.py [--repeats 5] [--fast-plans 5] [--seed 1] [--baseline ../old-checkout]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import pmht_opt as po
from pmht_opt.em import EMCallbacks, EMRun
from studies.report import write_json

BACKENDS = ("auto", "banded", "kalman", "clarabel", "osqp", "cvxpy")
#: The default plan's target (s).
TARGET_S = 0.35
#: Backends of a plan of about 0.3 s, timed ``--fast-plans`` times per round: one plan that short is at
#: the mercy of a moment's load.
FAST = ("auto", "banded")


def rts_reference(
    F: np.ndarray, Q: np.ndarray, x0: np.ndarray, y: np.ndarray, w: np.ndarray, r: float
) -> np.ndarray:
    """RTS smoother of ``B`` independent axes, ``x0 (B, 3)``, ``y, w (B, T)``; returns ``(B, T+1)``
    positions. A plain forward-backward pass, vectorised over ``B``, looping over time."""
    B, T = w.shape
    n = F.shape[0]
    mf = np.empty((T + 1, B, n))
    Pf = np.empty((T + 1, B, n, n))
    mp = np.empty((T + 1, B, n))
    Pp = np.empty((T + 1, B, n, n))
    m, P = x0.copy(), np.zeros((B, n, n))
    mf[0], Pf[0] = m, P
    for t in range(T):
        m = m @ F.T
        P = F @ P @ F.T + Q
        mp[t + 1], Pp[t + 1] = m, P
        S = P[:, 0, 0] + np.where(w[:, t] > 0, r / np.where(w[:, t] > 0, w[:, t], 1.0), np.inf)
        g = P[:, :, 0] / S[:, None]
        m = m + g * (y[:, t] - m[:, 0])[:, None]
        P = P - g[:, :, None] * P[:, None, 0, :]
        mf[t + 1], Pf[t + 1] = m, P
    out = np.empty((T + 1, B))
    ms = mf[T]
    out[T] = ms[:, 0]
    for t in range(T - 1, -1, -1):
        G = np.linalg.solve(Pp[t + 1] + 1e-300 * np.eye(n), F @ Pf[t]).transpose(0, 2, 1)
        ms = mf[t] + np.einsum("bij,bj->bi", G, ms - mp[t + 1])
        out[t] = ms[:, 0]
    return out.T


def _recorded_msteps(scenario: po.Scenario) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The ``(W, WZ, r)`` of the default plan's 100 M-steps."""
    steps: list[tuple[np.ndarray, np.ndarray, float]] = []

    def after(run: EMRun, es: Any) -> None:  # the weights of the next M-step, at its r
        nxt = min(run.iteration + 1, run.schedule.max_iter)
        steps.append((es.W.copy(), es.WZ.copy(), float(run.schedule.r_at(nxt))))

    cfg = po.PMHTConfig()
    with EMRun(scenario, cfg, callbacks=EMCallbacks(after_estep=after)) as run:
        run.run()
    return steps[: cfg.max_iter]


def reference_mstep_seconds(
    scenario: po.Scenario, steps: list[tuple[np.ndarray, np.ndarray, float]]
) -> float:
    """Time of the independent RTS on the recorded M-steps (both axes of every platform at once)."""
    model = scenario.model
    x0 = np.concatenate([scenario.initial_states[:, 0:3], scenario.initial_states[:, 3:6]])
    t0 = time.perf_counter()
    for W, WZ, r in steps:
        w = np.concatenate([W.T, W.T])
        with np.errstate(invalid="ignore", divide="ignore"):
            y = np.concatenate([WZ[:, :, 0].T, WZ[:, :, 1].T]) / np.where(w > 0, w, 1.0)
        rts_reference(model.F3, model.Q3, x0, y, w, r)
    return time.perf_counter() - t0


def time_backend(scenario: po.Scenario, backend: str, repeats: int) -> dict[str, Any]:
    """Median wall time and split of ``repeats`` default plans with ``backend``."""
    walls, esteps, msteps, per_iter = [], [], [], []
    res = None
    for _ in range(repeats):
        gc.collect()  # the garbage of earlier plans (cvxpy's above all) is not this plan's to collect
        t0 = time.perf_counter()
        res = po.plan_pmht(scenario, po.PMHTConfig(solver=backend))
        walls.append(time.perf_counter() - t0)
        h = res.history
        esteps.append(float(h.estep_time.sum()))
        msteps.append(float(h.mstep_time.sum()))
        settled = h.settled
        per_iter.append(float(np.median(h.estep_time[settled + 1 :])))
    assert res is not None
    return {
        "median_wall_s": float(np.median(walls)),
        "runs_s": [round(w, 4) for w in walls],
        "median_estep_s": float(np.median(esteps)),
        "median_mstep_s": float(np.median(msteps)),
        "estep_per_iteration_after_annealing_ms": 1e3 * float(np.median(per_iter)),
        "total_distance": res.total_distance,
    }


def merge_rounds(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One row from single-plan rows of :func:`time_backend`: medians over the rounds."""
    walls = [w for r in runs for w in r["runs_s"]]
    keys = ("median_estep_s", "median_mstep_s", "estep_per_iteration_after_annealing_ms")
    return {
        "median_wall_s": float(np.median(walls)),
        "runs_s": walls,
        **{k: float(np.median([r[k] for r in runs])) for k in keys},
        "total_distance": runs[-1]["total_distance"],
    }


def baseline(checkout: Path, repeats: int, seed: int, backends: list[str]) -> dict[str, Any]:
    """The earlier code's own benchmark, run in ``checkout`` (its package imported from there)."""
    # The checkout's package first on the path: this environment's own (possibly editable) install
    # of pmht-opt must not stand in for the earlier code.
    env = {**os.environ, "PYTHONPATH": str(checkout.resolve())}
    where = subprocess.run(
        [sys.executable, "-c", "import pmht_opt; print(pmht_opt.__file__)"],
        cwd=checkout,
        env=env,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    if not Path(where).resolve().is_relative_to(checkout.resolve()):
        raise SystemExit(f"--baseline: the checkout's package is not the one imported ({where})")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "old.json"
        cmd = [sys.executable, "studies/bench_core.py", "--repeats", str(repeats), "--seed", str(seed)]
        cmd += ["--backends", *backends, "--out", str(out)]
        subprocess.run(cmd, cwd=checkout, env=env, check=True, capture_output=True, text=True)
        data: dict[str, Any] = json.loads(out.read_text())
    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=checkout, capture_output=True, text=True, check=False
    ).stdout.strip()
    return {"commit": commit, "results": data.get("results", {})}


def run_rounds(scenario: po.Scenario, args: argparse.Namespace, common: list[str]) -> list[dict[str, Any]]:
    """``--repeats`` rounds, each with one plan per backend (``--fast-plans`` of :data:`FAST`), the
    independent reference on the recorded M-steps and (with ``--baseline``) the earlier code's plans
    of ``common``: a change of this shared machine's speed hits them all, and the ratios are read
    within each round."""
    steps = _recorded_msteps(scenario)
    rounds: list[dict[str, Any]] = []
    for _ in range(args.repeats):
        one: dict[str, Any] = {
            "new": {b: time_backend(scenario, b, args.fast_plans if b in FAST else 1) for b in args.backends}
        }
        one["reference_mstep_s"] = reference_mstep_seconds(scenario, steps)
        if args.baseline is not None:
            one["old"] = baseline(args.baseline, 1, args.seed, common)
        rounds.append(one)
    return rounds


def reference_summary(rounds: list[dict[str, Any]], default_b: str) -> dict[str, Any]:
    """The reference plan (its M-steps plus the default plan's E-step) against the default plan: the
    medians, and the ratio within each round."""
    ref_m = float(np.median([r["reference_mstep_s"] for r in rounds]))
    estep = float(np.median([r["new"][default_b]["median_estep_s"] for r in rounds]))
    speedups = [
        (r["reference_mstep_s"] + r["new"][default_b]["median_estep_s"])
        / r["new"][default_b]["median_wall_s"]
        for r in rounds
    ]
    return {
        "median_mstep_s": ref_m,
        "plan_s": ref_m + estep,
        "speedup_per_round": [round(x, 3) for x in speedups],
        "median_speedup": float(np.median(speedups)),
    }


def add_baseline(rows: dict[str, dict[str, Any]], rounds: list[dict[str, Any]], common: list[str]) -> None:
    """The earlier code's medians in ``rows`` of ``common``, with the ratio of the medians and the
    rounds' own ratios new / old."""
    for b in common:
        old = [r["old"]["results"][b]["median_wall_s"] for r in rounds]
        ratios = [r["new"][b]["median_wall_s"] / o for r, o in zip(rounds, old, strict=True)]
        row = rows[b]
        row["baseline_median_wall_s"] = float(np.median(old))
        row["ratio_to_baseline"] = row["median_wall_s"] / row["baseline_median_wall_s"]
        row["ratio_per_round"] = [round(x, 3) for x in ratios]
        row["median_ratio_per_round"] = float(np.median(ratios))


def report(rows: dict[str, dict[str, Any]], reference: dict[str, Any], default: dict[str, Any]) -> None:
    """One line per backend, one for the reference and the target."""
    for b, row in rows.items():
        print(
            f"{b:<9} median {row['median_wall_s']:.3f} s (E-step {row['median_estep_s']:.3f} s, "
            f"{row['estep_per_iteration_after_annealing_ms']:.2f} ms per iteration after annealing; "
            f"M-step {row['median_mstep_s']:.3f} s)"
            + (
                f"  baseline {row['baseline_median_wall_s']:.3f} s, ratio {row['ratio_to_baseline']:.2f}"
                f" (median of the rounds' ratios {row['median_ratio_per_round']:.2f})"
                if "ratio_to_baseline" in row
                else ""
            )
        )
    print(
        f"reference RTS plan {reference['plan_s']:.3f} s (M-steps {reference['median_mstep_s']:.3f} s): "
        f"default plan {reference['plan_s'] / default['median_wall_s']:.1f}x faster (median of the "
        f"rounds' ratios {reference['median_speedup']:.1f}x); target {TARGET_S} s: "
        f"{'met' if default['median_wall_s'] <= TARGET_S else 'MISSED'}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--fast-plans", type=int, default=5, help="plans per round of auto and banded")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--backends", nargs="*", default=list(BACKENDS))
    parser.add_argument("--baseline", type=Path, default=None, help="a checkout of the earlier code")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_core.json")
    args = parser.parse_args()
    if args.repeats < 1 or args.fast_plans < 1:
        parser.error("--repeats and --fast-plans must be at least 1")
    unknown = sorted(set(args.backends) - set(BACKENDS))
    if not args.backends or unknown:
        parser.error(f"--backends: choose among {', '.join(BACKENDS)} (got {unknown or 'none'})")

    scenario = po.paper_scenario("A", seed=args.seed)
    common = [b for b in args.backends if b in ("kalman", "clarabel", "osqp", "cvxpy")]
    rounds = run_rounds(scenario, args, common)
    rows = {b: merge_rounds([r["new"][b] for r in rounds]) for b in args.backends}
    default_b = "auto" if "auto" in rows else args.backends[0]
    reference = reference_summary(rounds, default_b)
    if args.baseline is not None:
        add_baseline(rows, rounds, common)
    report(rows, reference, rows[default_b])
    payload = {
        "benchmark": f"scenario A, seed {args.seed}: N=100, M=4, T=500, 100 EM iterations, default settings",
        "repeats": args.repeats,
        "fast_plans_per_round": args.fast_plans,
        "target_default_plan_s": TARGET_S,
        "results": rows,
        "independent_reference": reference,
        "baseline": None if args.baseline is None else {"commit": rounds[0]["old"]["commit"]},
    }
    print(f"wrote: {write_json(args.out, payload)}")


if __name__ == "__main__":
    main()
