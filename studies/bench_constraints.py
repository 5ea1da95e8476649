"""Benchmark: constrained plans. Scenario A, SpeedLimit (70% of the unconstrained plan's top speed)
and AreaBounds (the 10 x 10 area), 100 iterations, per backend; and GA-TSP PMHT smoothed plans of
A, B and C (GA tour, visit radius 0.1, 100 iterations).

Target (issue 4): the best backend <= 5 s median for the constrained plan on this 2-core machine.
Writes ``studies/results/bench_constraints.json``.

    python studies/bench_constraints.py [--repeats 3] [--backends clarabel osqp cvxpy]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import pmht_opt as po


def _time(fn, repeats: int) -> tuple[list[float], object]:  # type: ignore[no-untyped-def]
    walls, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    return walls, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--backends", nargs="*", default=["clarabel", "osqp", "cvxpy"])
    parser.add_argument("--smoothed-backends", nargs="*", default=["clarabel", "osqp", "cvxpy"])
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_constraints.json")
    args = parser.parse_args()

    sc = po.paper_scenario("A", seed=args.seed)
    free = po.plan_pmht(sc, po.PMHTConfig())
    vmax = 0.7 * free.max_speed
    cons = [po.SpeedLimit(vmax), po.AreaBounds(0, 10, 0, 10)]
    constrained = {}
    for backend in args.backends:
        walls, res = _time(
            lambda b=backend: po.plan_pmht(sc, po.PMHTConfig(solver=b, constraints=cons)), args.repeats
        )
        assert isinstance(res, po.PlanResult)
        constrained[backend] = {
            "median_s": float(np.median(walls)),
            "runs_s": walls,
            "total_distance": res.total_distance,
            "max_speed": res.max_speed,
            "max_violation": res.max_violation,
            "mstep_s_per_iteration": float(np.median(res.history.mstep_time)),
        }
        print(f"A speed+area {backend:9s} median {np.median(walls):6.2f} s  distance {res.total_distance:6.1f}  "
              f"max speed {res.max_speed:.4f} (limit {vmax:.4f})  max violation {res.max_violation:.1e}")

    smoothed = {}
    for kind in "ABC":
        sck = po.paper_scenario(kind, seed=args.seed)
        t0 = time.perf_counter()
        tour = po.order_locales(sck, "ga", seed=args.seed)
        ga_s = time.perf_counter() - t0
        for backend in args.smoothed_backends:
            walls, res = _time(
                lambda b=backend, s=sck, t=tour: po.plan_smoothed(s, t, po.PMHTConfig(solver=b)), args.repeats
            )
            assert isinstance(res, po.PlanResult)
            smoothed[f"{kind}/{backend}"] = {
                "median_s": float(np.median(walls)),
                "runs_s": walls,
                "ga_s": ga_s,
                "tour_distance": tour.total_distance,
                "smoothed_distance": res.total_distance,
                "max_violation": res.max_violation,
            }
            print(f"{kind} smoothed {backend:9s} median {np.median(walls):6.2f} s (GA {ga_s:.2f} s)  "
                  f"tour {tour.total_distance:6.1f} -> smoothed {res.total_distance:6.1f}")

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "machine": {"cpus": os.cpu_count(), "load_average": os.getloadavg()},
                "repeats": args.repeats,
                "speed_limit": vmax,
                "constrained_A_speed_area": constrained,
                "target_s": 5.0,
                "smoothed": smoothed,
            },
            indent=2,
        )
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
