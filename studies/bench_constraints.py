"""Benchmark: constrained plans, per backend, with the default configuration otherwise.

Three parts:

* scenario A under ``SpeedLimit`` (70% of the unconstrained plan's top speed) and ``AreaBounds`` (the
  10 x 10 area), 100 iterations;
* PMHT with guaranteed visits, ``VisitAll(0.1)``, on A;
* ``plan_smoothed`` of the GA tour of A, B and C (visit radius 0.1; stops once the visits settle).

Targets on this 2-core machine, clarabel, medians on A: speed + area at most 1.5 s, ``VisitAll(0.1)``
at most 3 s, ``plan_smoothed`` at most 2 s (:data:`TARGETS_S`). Writes
``studies/results/bench_constraints.json`` (with provenance).

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

#: Median seconds per plan on A with clarabel that the parts aim at.
TARGETS_S = {"speed_area": 1.5, "visit_all": 3.0, "smoothed": 2.0}


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


def visit_all(seed: int, backends: list[str], repeats: int) -> dict[str, dict[str, Any]]:
    """PMHT with ``VisitAll(0.1)`` on A per backend: times, distance and coverage at 0.1."""
    sc = po.paper_scenario("A", seed=seed)
    out: dict[str, dict[str, Any]] = {}
    for backend in backends:
        cfg = po.PMHTConfig(solver=backend, constraints=[po.VisitAll(0.1)])
        walls, res = _time(functools.partial(po.plan_pmht, sc, cfg), repeats)
        out[backend] = {
            "median_s": float(np.median(walls)),
            "runs_s": walls,
            "total_distance": res.total_distance,
            "coverage_0.1": res.coverage(0.1),
            "iterations": res.n_iterations,
        }
        print(
            f"A VisitAll(0.1) {backend:9s} median {np.median(walls):6.2f} s  "
            f"distance {res.total_distance:6.1f}  coverage at 0.1 {res.coverage(0.1):.2f}"
        )
    return out


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
    parser.add_argument("--smoothed-backends", nargs="*", default=["clarabel", "osqp"])
    parser.add_argument(
        "--out", type=Path, default=Path(__file__).parent / "results" / "bench_constraints.json"
    )
    args = parser.parse_args()
    vmax, by_backend = constrained(args.seed, args.backends, args.repeats)
    visits = visit_all(args.seed, args.backends, args.repeats)
    smooth = smoothed(args.seed, args.smoothed_backends, args.repeats)
    measured = {
        "speed_area": by_backend.get("clarabel", {}).get("median_s"),
        "visit_all": visits.get("clarabel", {}).get("median_s"),
        "smoothed": smooth.get("A/clarabel", {}).get("median_s"),
    }
    for part, target in TARGETS_S.items():
        got = measured[part]
        verdict = "not run" if got is None else ("met" if got <= target else "MISSED")
        print(f"target {part}: clarabel on A <= {target} s: " + (f"{got:.2f} s, " if got else "") + verdict)
    payload = {
        "seed": args.seed,
        "repeats": args.repeats,
        "targets_s": TARGETS_S,
        "clarabel_on_A_s": measured,
        "speed_limit": vmax,
        "constrained_A_speed_area": by_backend,
        "visit_all_A": visits,
        "smoothed": smooth,
    }
    print(f"wrote: {write_json(args.out, payload)}")


if __name__ == "__main__":
    main()
