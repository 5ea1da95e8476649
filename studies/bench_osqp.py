"""OSQP against Clarabel where OSQP used to fail: its time on a guaranteed-visit plan, and its answer on
trivial ones.

Two parts:

- **smoothed**: ``plan(C seed 1000, "smoothed")`` with the GA's tour (seed 1000, 300 generations),
  ``visit_radius=0.1``, 30 iterations, on ``clarabel`` and ``osqp`` in alternating rounds in one
  process: the median CPU and wall seconds of each and the ratio of the medians (target: OSQP within
  3x Clarabel). The plans must cover every locale within 0.1 on both.
- **trivial**: one locale, one platform, horizon 30, no constraints; two locales at horizon 3; a start
  far outside the bounds: OSQP's positions against the exact smoother's (``banded``), the largest
  difference (target: within 1e-6).

    python -m studies.bench_osqp                  # 3 rounds, both parts
    python -m studies.bench_osqp --rounds 5 --parts smoothed
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import pmht_opt as po
from studies.provenance import provenance

RESULTS = Path(__file__).resolve().parent / "results" / "bench_osqp.json"


def smoothed(rounds: int) -> dict[str, Any]:
    """The guaranteed-visit plan on both backends, alternating, ``rounds`` times."""
    sc = po.paper_scenario("C", seed=1000)
    tour = po.order_locales(sc, "ga", seed=1000, iterations=300)
    runs: dict[str, list[dict[str, float]]] = {"clarabel": [], "osqp": []}
    for k in range(rounds):
        for solver in runs:
            settings = po.Settings(solver=solver)
            cpu, wall = time.process_time(), time.perf_counter()
            res = po.plan(
                sc, "smoothed", settings=settings, stop=po.MaxIterations(30), tour=tour, visit_radius=0.1
            )
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
            runs[solver].append(
                {"cpu": cpu, "wall": wall, "distance": res.total_distance, "coverage": res.coverage(0.1)}
            )
            print(
                f"round {k} {solver:8s} {wall:6.2f} s wall {cpu:6.2f} s cpu distance {res.total_distance:.4f}"
            )
    out: dict[str, Any] = {"runs": runs}
    for key in ("cpu", "wall"):
        med = {s: statistics.median(r[key] for r in rs) for s, rs in runs.items()}
        out[f"median_{key}"] = med
        out[f"ratio_{key}"] = med["osqp"] / med["clarabel"]
    out["covered"] = all(r["coverage"] == 1.0 for rs in runs.values() for r in rs)
    out["met"] = out["ratio_cpu"] <= 3.0 and out["covered"]
    print(
        f"osqp / clarabel: {out['ratio_cpu']:.2f}x CPU, {out['ratio_wall']:.2f}x wall (target <= 3x); "
        f"every plan covers: {out['covered']}"
    )
    return out


def trivial() -> dict[str, Any]:
    """OSQP's plans of trivial scenarios against the exact smoother's."""
    cases = {
        "one locale, T = 30": po.Scenario(
            locales=np.array([[1.0, 1.0]]), starts=np.zeros((1, 2)), horizon=30
        ),
        "two locales, T = 3": po.Scenario(
            locales=np.array([[1.0, 1.0], [2.0, 0.5]]), starts=np.zeros((1, 2)), horizon=3
        ),
        "start far outside the bounds": po.Scenario(
            locales=np.array([[1.0, 1.0], [2.0, 2.0]]),
            starts=np.array([[40.0, -30.0]]),
            horizon=50,
            bounds=(0, 3, 0, 3),
        ),
    }
    out: dict[str, Any] = {}
    for name, sc in cases.items():
        plans = {s: po.plan(sc, "pmht", settings=po.Settings(solver=s)) for s in ("banded", "osqp")}
        gap = float(np.max(np.abs(plans["osqp"].positions - plans["banded"].positions)))
        out[name] = {"max_position_difference": gap, "met": gap <= 1e-6}
        print(f"{name}: osqp within {gap:.2e} of the exact smoother")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--parts", nargs="*", default=["trivial", "smoothed"], choices=["trivial", "smoothed"]
    )
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--no-save", action="store_true")
    args = parser.parse_args(argv)
    out: dict[str, Any] = {"provenance": provenance()}
    if "trivial" in args.parts:
        out["trivial"] = trivial()
    if "smoothed" in args.parts:
        out["smoothed"] = smoothed(args.rounds)
    if not args.no_save:
        RESULTS.write_text(json.dumps(out, indent=1) + "\n")
        print(f"written {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
