"""Benchmark: constrained plans. Scenario A, SpeedLimit (70% of the unconstrained plan's top speed)
and AreaBounds (the 10 x 10 area), 100 iterations, per backend; and GA-TSP PMHT smoothed plans of
A, B and C (GA tour, visit radius 0.1, 100 iterations).

Target: the best backend <= 5 s median for the constrained plan on the project's 2-core machine.
Writes ``studies/results/bench_constraints.json`` (with provenance).

    python studies/bench_constraints.py [--repeats 3] [--backends clarabel osqp cvxpy]
"""

from __future__ import annotations

import argparse
import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import pmht_opt as po
from studies.report import write_json


def _time(fn: Callable[[], po.PlanResult], repeats: int) -> tuple[list[float], po.PlanResult]:
    """Wall times of ``repeats`` calls of ``fn`` and its last result."""
    walls: list[float] = []
    out = None
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
    assert out is not None
    return walls, out


def constrained(seed: int, backends: list[str], repeats: int) -> tuple[float, dict[str, dict[str, Any]]]:
    """Scenario A under a speed limit (70% of the unconstrained plan's top speed) and the area's bounds,
    per backend: the limit, and each backend's times and plan."""
    sc = po.paper_scenario("A", seed=seed)
    free = po.plan_pmht(sc, po.PMHTConfig())
    vmax = 0.7 * free.max_speed
    cons = [po.SpeedLimit(vmax), po.AreaBounds(0, 10, 0, 10)]
    out: dict[str, dict[str, Any]] = {}
    for backend in backends:
        cfg = po.PMHTConfig(solver=backend, constraints=cons)
        walls, res = _time(functools.partial(po.plan_pmht, sc, cfg), repeats)
        out[backend] = {
            "median_s": float(np.median(walls)),
            "runs_s": walls,
            "total_distance": res.total_distance,
            "max_speed": res.max_speed,
            "max_violation": res.max_violation,
            "mstep_s_per_iteration": float(np.median(res.history.mstep_time)),
        }
        print(
            f"A speed+area {backend:9s} median {np.median(walls):6.2f} s  "
            f"distance {res.total_distance:6.1f}  "
            f"max speed {res.max_speed:.4f} (limit {vmax:.4f})  max violation {res.max_violation:.1e}"
        )
    return vmax, out


def smoothed(seed: int, backends: list[str], repeats: int) -> dict[str, dict[str, Any]]:
    """GA-TSP PMHT smoothed plans of A, B and C per backend: times, tour and smoothed distances."""
    out: dict[str, dict[str, Any]] = {}
    for kind in "ABC":
        sck = po.paper_scenario(kind, seed=seed)
        t0 = time.perf_counter()
        tour = po.order_locales(sck, "ga", seed=seed)
        ga_s = time.perf_counter() - t0
        for backend in backends:
            plan = functools.partial(po.plan_smoothed, sck, tour, po.PMHTConfig(solver=backend))
            walls, res = _time(plan, repeats)
            out[f"{kind}/{backend}"] = {
                "median_s": float(np.median(walls)),
                "runs_s": walls,
                "ga_s": ga_s,
                "tour_distance": tour.total_distance,
                "smoothed_distance": res.total_distance,
                "max_violation": res.max_violation,
            }
            print(
                f"{kind} smoothed {backend:9s} median {np.median(walls):6.2f} s (GA {ga_s:.2f} s)  "
                f"tour {tour.total_distance:6.1f} -> smoothed {res.total_distance:6.1f}"
            )
    return out


def main() -> None:
    """Run both parts and write their JSON (with provenance)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--backends", nargs="*", default=["clarabel", "osqp", "cvxpy"])
    parser.add_argument("--smoothed-backends", nargs="*", default=["clarabel", "osqp", "cvxpy"])
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).parent / "results" / "bench_constraints.json"
    )
    args = parser.parse_args()
    vmax, by_backend = constrained(args.seed, args.backends, args.repeats)
    payload = {
        "repeats": args.repeats,
        "speed_limit": vmax,
        "constrained_A_speed_area": by_backend,
        "target_s": 5.0,
        "smoothed": smoothed(args.seed, args.smoothed_backends, args.repeats),
    }
    print(f"wrote: {write_json(args.out, payload)}")


if __name__ == "__main__":
    main()
