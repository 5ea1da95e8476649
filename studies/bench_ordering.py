"""Benchmark: the GA-TSP baseline's speed, and how far OR-Tools routing improves on its orderings.

(a) The paper's GA (population 80, 5000 generations) on scenario A, seed 1: wall time of several runs
    (target <= 1 s on the project's 2-core machine; the paper's MATLAB took about 18 s).
(b) Total distance of the OR-Tools ordering against the GA's on scenarios A, B and C for several
    scenario seeds, with per-scenario means and the relative improvement (GA - OR-Tools) / GA.

Every tour is checked with ``TourResult.validate`` (each locale once, distance recomputed). Writes
``studies/results/bench_ordering.json``.

    python studies/bench_ordering.py [--repeats 7] [--seeds 5] [--time-limit 3] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from pmht_opt.ordering import solve_ga_tsp, solve_ortools
from pmht_opt.scenario import paper_scenario

GA_TARGET_S = 1.0
#: Table 1 of the paper (SPEC section 5): GA-TSP total distance and CPU time per scenario.
PAPER_GA = {
    "A": {"distance": 117.8, "cpu_s": 18.3},
    "B": {"distance": 118.8, "cpu_s": 17.4},
    "C": {"distance": 87.8, "cpu_s": 18.0},
}


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def bench_ga_time(repeats: int, iterations: int, population: int) -> dict:
    scenario = paper_scenario("A", seed=1)
    solve_ga_tsp(scenario, seed=0, iterations=50)  # warm-up: imports and first allocations
    walls, dists = [], []
    for r in range(repeats):
        res = solve_ga_tsp(scenario, seed=r, population=population, iterations=iterations)
        res.validate(min_tour=1)
        walls.append(res.wall_time)
        dists.append(res.total_distance)
    median = float(np.median(walls))
    verdict = "met" if median <= GA_TARGET_S else "MISSED"
    print(
        f"GA {population} x {iterations} on A (seed 1): median {median:.3f} s over {repeats} runs "
        f"(min {min(walls):.3f}, max {max(walls):.3f}; target {GA_TARGET_S} s: {verdict}; paper ~18 s); "
        f"mean distance {np.mean(dists):.2f}"
    )
    return {
        "scenario": "A, seed 1",
        "population": population,
        "iterations": iterations,
        "ga_seeds": list(range(repeats)),
        "median_wall_s": median,
        "min_wall_s": float(min(walls)),
        "wall_s": [round(w, 4) for w in walls],
        "total_distance": [round(d, 4) for d in dists],
        "target_s": GA_TARGET_S,
        "target_met": median <= GA_TARGET_S,
        "paper_cpu_s": PAPER_GA["A"]["cpu_s"],
    }


def bench_distances(seeds: int, time_limit: float, iterations: int, population: int) -> dict:
    out = {}
    for kind in "ABC":
        rows = []
        for seed in range(1, seeds + 1):
            scenario = paper_scenario(kind, seed=seed)
            ga = solve_ga_tsp(scenario, seed=seed, population=population, iterations=iterations)
            ort = solve_ortools(scenario, time_limit=time_limit)
            ga.validate(min_tour=1)
            ort.validate(min_tour=1)
            rows.append(
                {
                    "seed": seed,
                    "ga_distance": ga.total_distance,
                    "ortools_distance": ort.total_distance,
                    "improvement": (ga.total_distance - ort.total_distance) / ga.total_distance,
                    "ga_wall_s": round(ga.wall_time, 4),
                    "ortools_wall_s": round(ort.wall_time, 4),
                    "ortools_solutions": int(ort.history.size),
                }
            )
        ga_mean = float(np.mean([r["ga_distance"] for r in rows]))
        or_mean = float(np.mean([r["ortools_distance"] for r in rows]))
        imp = [r["improvement"] for r in rows]
        out[kind] = {
            "ga_mean": ga_mean,
            "ortools_mean": or_mean,
            "improvement_of_means": (ga_mean - or_mean) / ga_mean,
            "improvement_mean": float(np.mean(imp)),
            "improvement_min": float(np.min(imp)),
            "improvement_max": float(np.max(imp)),
            "ortools_better_in": int(sum(r["ortools_distance"] < r["ga_distance"] for r in rows)),
            "paper_ga_distance": PAPER_GA[kind]["distance"],
            "trials": rows,
        }
        print(
            f"{kind}: GA mean {ga_mean:7.2f}  OR-Tools mean {or_mean:7.2f}  "
            f"improvement {100 * out[kind]['improvement_of_means']:.1f}% "
            f"(per seed {100 * min(imp):.1f}..{100 * max(imp):.1f}%; paper GA {PAPER_GA[kind]['distance']})"
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="GA timing runs (a)")
    parser.add_argument("--seeds", type=int, default=5, help="scenario seeds per scenario (b)")
    parser.add_argument("--time-limit", type=float, default=3.0, help="OR-Tools seconds per ordering (b)")
    parser.add_argument("--iterations", type=int, default=5000)
    parser.add_argument("--population", type=int, default=80)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_ordering.json")
    args = parser.parse_args()

    load_before = os.getloadavg()[0]  # other work on the machine slows the timings
    timing = bench_ga_time(args.repeats, args.iterations, args.population)
    distances = bench_distances(args.seeds, args.time_limit, args.iterations, args.population)
    payload = {
        "benchmark": "ordering: GA-TSP (Kirk-style) speed; OR-Tools vs GA total distance on A, B, C",
        "settings": {
            "ga": {"population": args.population, "iterations": args.iterations, "min_tour": 1},
            "ortools": {
                "time_limit_s": args.time_limit,
                "first_solution": "PATH_CHEAPEST_ARC",
                "metaheuristic": "GUIDED_LOCAL_SEARCH",
                "min_tour": 1,
            },
            "scenario_seeds": list(range(1, args.seeds + 1)),
            "ga_seed": "equal to the scenario seed",
        },
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "numpy": _version("numpy"),
            "ortools": _version("ortools"),
            "load_average_1min": {"before": round(load_before, 2), "after": round(os.getloadavg()[0], 2)},
        },
        "date": time.strftime("%Y-%m-%d"),
        "ga_timing": timing,
        "distances": distances,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"written: {args.out}")


if __name__ == "__main__":
    main()
