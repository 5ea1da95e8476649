"""Benchmark: full PMHT plans of scenario A (N=100, M=4, T=500, 100 iterations) per backend.

Prints the median wall time of several runs per backend (with the E-step / M-step split) and writes
them, with their provenance, to ``studies/results/bench_core.json``. Targets on the project's 2-core
machine: kalman <= 0.5 s, clarabel <= 3 s, osqp <= 3 s per plan. cvxpy is timed for reference (its
first plan includes compiling the parametrised problem).

    python studies/bench_core.py [--repeats 5] [--seed 1]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

import pmht_opt as po
from studies.report import write_json

TARGETS = {"kalman": 0.5, "clarabel": 3.0, "osqp": 3.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--backends", nargs="*", default=["kalman", "clarabel", "osqp", "cvxpy"])
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_core.json")
    args = parser.parse_args()

    scenario = po.paper_scenario("A", seed=args.seed)
    rows: dict[str, dict[str, Any]] = {}
    for backend in args.backends:
        walls: list[float] = []
        estep: list[float] = []
        mstep: list[float] = []
        dist: list[float] = []
        iters: list[int] = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = po.plan_pmht(scenario, po.PMHTConfig(solver=backend, max_iter=100, tol=0.0))
            walls.append(time.perf_counter() - t0)
            estep.append(float(res.history.estep_time.sum()))
            mstep.append(float(res.history.mstep_time.sum()))
            dist.append(res.total_distance)
            iters.append(int(res.history.solver_iterations.sum()))
        row = {
            "median_wall_s": float(np.median(walls)),
            "min_wall_s": float(np.min(walls)),
            "median_estep_s": float(np.median(estep)),
            "median_mstep_s": float(np.median(mstep)),
            "total_distance": float(dist[-1]),
            "solver_iterations_per_plan": iters[-1],
            "runs": [round(w, 4) for w in walls],
            "target_s": TARGETS.get(backend),
        }
        rows[backend] = row
        target = TARGETS.get(backend)
        median_wall = float(np.median(walls))
        verdict = (
            ""
            if target is None
            else f"  (target {target:.1f} s: {'met' if median_wall <= target else 'MISSED'})"
        )
        print(
            f"{backend:<9} median {row['median_wall_s']:.2f} s  "
            f"(E-step {row['median_estep_s']:.2f} s, M-step {row['median_mstep_s']:.2f} s, "
            f"distance {row['total_distance']:.3f}){verdict}"
        )
    payload = {
        "benchmark": f"scenario A, seed {args.seed}: N=100, M=4, T=500, 100 EM iterations, tol=0",
        "repeats": args.repeats,
        "results": rows,
    }
    print(f"wrote: {write_json(args.out, payload)}")


if __name__ == "__main__":
    main()
