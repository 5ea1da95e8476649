"""Benchmark of the orderers: GA speed, and tour length against LKH-3 on scenarios A, B and C.

(a) The paper's GA (population 80, 5000 generations) on scenario A, seed 1: wall time of several runs
    (target <= 1 s on the project's 2-core machine; the paper's MATLAB took about 18 s).
(b) Total distance of the open mTSP tours on A, B and C, scenario seeds 0-4, from the GA (the paper's
    Kirk operators and the improved table), OR-Tools in its deterministic mode (a solution limit, no
    wall-clock limit), PyVRP (an iteration limit) and LKH-3 through ``elkai`` as the near-optimal
    reference. Target: PyVRP's mean tour within 0.5 % of LKH-3's in each scenario.

LKH-3 solves one asymmetric TSP (the standard transform of the open mTSP with a start per platform):
nodes are the locales and the starts; a start to a locale costs their distance, a locale to a locale
their distance, a locale to any start 0 (a route ends, the next platform's begins) and a start to a
start more than any tour (so every platform gets a locale, as in the other orderers). Cutting the
cycle at the starts gives the routes. LKH works on integers: distances are scaled so the longest arc is
:data:`LKH_SCALE`. ``elkai`` is a benchmark-only tool, not a dependency of pmht-opt:
``pip install elkai`` to run this part (without it the LKH column is left out).

Every tour is checked with ``TourResult.validate`` (each locale once, distance recomputed in floating
point). Writes ``studies/results/bench_ordering.json`` with the machine, the package versions, the
commit and the load average.

    python studies/bench_ordering.py [--repeats 7] [--seeds 5] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.ordering import TourResult, solve_ga_tsp, solve_ortools, solve_pyvrp
from pmht_opt.ordering.ortools_ import DEFAULT_SOLUTION_LIMIT
from pmht_opt.scenario import Scenario, paper_scenario

GA_TARGET_S = 1.0
#: PyVRP's mean tour at most this far above LKH-3's, per scenario.
PYVRP_GAP_TARGET = 0.005
#: Integer cost of LKH's longest arc.
LKH_SCALE = 100_000
#: Table 1 of the paper: GA-TSP total distance and CPU time per scenario.
PAPER_GA = {
    "A": {"distance": 117.8, "cpu_s": 18.3},
    "B": {"distance": 118.8, "cpu_s": 17.4},
    "C": {"distance": 87.8, "cpu_s": 18.0},
}
PACKAGES = ("pmht-opt", "numpy", "scipy", "ortools", "pyvrp", "elkai")


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def provenance() -> dict[str, Any]:
    """Machine, package versions, commit and load: what a reader needs to judge the timings."""

    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", *args], capture_output=True, text=True, check=True, timeout=10)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip()

    return {
        "commit": git("rev-parse", "HEAD"),
        "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
        },
        "packages": {name: _version(name) for name in PACKAGES},
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
    }


def solve_lkh(scenario: Scenario, runs: int = 10) -> TourResult:
    """LKH-3 (through elkai) on the asymmetric-TSP transform of the open mTSP (module notes)."""
    import elkai

    z, s = scenario.locales, scenario.start_positions
    N, M = z.shape[0], s.shape[0]
    pts = np.vstack([z, s])
    dist = np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1))
    arcs = np.rint(dist * (LKH_SCALE / dist.max())).astype(np.int64)
    cost = np.zeros((N + M, N + M), dtype=np.int64)
    cost[:, :N] = arcs[:, :N]  # from a locale or a start into a locale
    cost[N:, N:] = LKH_SCALE * (N + M + 1)  # start to start: an empty route
    np.fill_diagonal(cost, 0)
    t0 = time.perf_counter()
    cycle = elkai.DistanceMatrix(cost.tolist()).solve_tsp(runs=runs)[:-1]
    wall = time.perf_counter() - t0
    first = next(i for i, node in enumerate(cycle) if node >= N)
    routes: list[list[int]] = [[] for _ in range(M)]
    current = routes[0]  # the rotated cycle opens on a start, which sets it
    for node in cycle[first:] + cycle[:first]:
        if node >= N:
            current = routes[node - N]
        else:
            current.append(int(node))
    result = TourResult.from_routes(scenario, routes, method="lkh")
    result.wall_time = wall
    result.extras = {"runs": runs, "scale": LKH_SCALE}
    return result


def bench_ga_time(repeats: int, iterations: int, population: int) -> dict[str, Any]:
    scenario = paper_scenario("A", seed=1)
    solve_ga_tsp(scenario, seed=0, iterations=50)  # warm-up: imports and first allocations
    out: dict[str, Any] = {"scenario": "A, seed 1", "population": population, "iterations": iterations}
    for operators in ("kirk", "improved"):
        walls, dists = [], []
        for r in range(repeats):
            res = solve_ga_tsp(
                scenario, seed=r, population=population, iterations=iterations, operators=operators
            )
            res.validate(min_tour=1)
            walls.append(res.wall_time)
            dists.append(res.total_distance)
        median = float(np.median(walls))
        print(
            f"GA {operators} {population} x {iterations} on A (seed 1): median {median:.3f} s over {repeats} "
            f"runs (target {GA_TARGET_S} s; paper ~18 s); mean distance {np.mean(dists):.2f}"
        )
        out[operators] = {
            "ga_seeds": list(range(repeats)),
            "median_wall_s": median,
            "wall_s": [round(w, 4) for w in walls],
            "total_distance": [round(d, 4) for d in dists],
            "target_met": median <= GA_TARGET_S,
        }
    out["target_s"] = GA_TARGET_S
    out["paper_cpu_s"] = PAPER_GA["A"]["cpu_s"]
    return out


def orderers(args: argparse.Namespace) -> dict[str, Callable[[Scenario, int], TourResult]]:
    """The methods compared, each ``solve(scenario, seed)`` with the study's settings."""
    methods: dict[str, Callable[[Scenario, int], TourResult]] = {
        "ga_kirk": lambda sc, seed: solve_ga_tsp(sc, seed=seed, iterations=args.iterations, operators="kirk"),
        "ga": lambda sc, seed: solve_ga_tsp(sc, seed=seed, iterations=args.iterations),
        "ortools": lambda sc, seed: solve_ortools(sc, solution_limit=args.ortools_solutions),
        "pyvrp": lambda sc, seed: solve_pyvrp(sc, seed=seed, iterations=args.pyvrp_iterations),
    }
    if _version("elkai") is not None:
        methods["lkh"] = lambda sc, seed: solve_lkh(sc, runs=args.lkh_runs)
    else:
        print("elkai is not installed: the LKH-3 reference is left out (pip install elkai)")
    return methods


def summarise(kind: str, rows: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    means = {m: float(np.mean([r[m]["distance"] for r in rows])) for m in methods}
    times = {m: float(np.mean([r[m]["wall_s"] for r in rows])) for m in methods}
    out: dict[str, Any] = {"mean_distance": means, "mean_wall_s": times}
    if "lkh" in means:
        gaps = {m: (means[m] - means["lkh"]) / means["lkh"] for m in methods if m != "lkh"}
        out["gap_to_lkh"] = gaps
        out["pyvrp_target_met"] = gaps["pyvrp"] <= PYVRP_GAP_TARGET
    out["paper_ga_distance"] = PAPER_GA[kind]["distance"]
    out["trials"] = rows
    line = "  ".join(f"{m} {means[m]:7.2f}" for m in methods)
    gap = f"; PyVRP {100 * out['gap_to_lkh']['pyvrp']:+.2f}% vs LKH" if "gap_to_lkh" in out else ""
    print(f"{kind}: {line}{gap}; PyVRP {times['pyvrp']:.2f} s per ordering")
    return out


def bench_distances(args: argparse.Namespace) -> dict[str, Any]:
    methods = orderers(args)
    out = {}
    for kind in "ABC":
        rows = []
        for seed in range(args.seeds):
            scenario = paper_scenario(kind, seed=seed)
            row: dict[str, Any] = {"seed": seed}
            for name, solve in methods.items():
                res = solve(scenario, seed)
                res.validate(min_tour=1)
                row[name] = {"distance": res.total_distance, "wall_s": round(res.wall_time, 4)}
                if name == "pyvrp":
                    row[name]["iterations"] = res.extras["iterations"]
            rows.append(row)
        out[kind] = summarise(kind, rows, list(methods))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="GA timing runs (a)")
    parser.add_argument("--seeds", type=int, default=5, help="scenario seeds 0..seeds-1 per scenario (b)")
    parser.add_argument("--iterations", type=int, default=5000, help="GA generations")
    parser.add_argument("--population", type=int, default=80, help="GA population (a)")
    parser.add_argument("--ortools-solutions", type=int, default=DEFAULT_SOLUTION_LIMIT)
    parser.add_argument("--pyvrp-iterations", type=int, default=5000)
    parser.add_argument("--lkh-runs", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_ordering.json")
    args = parser.parse_args()

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    timing = bench_ga_time(args.repeats, args.iterations, args.population)
    distances = bench_distances(args)
    payload = {
        "benchmark": "orderers on A, B, C: GA (Kirk, improved), OR-Tools, PyVRP against LKH-3; GA speed",
        "settings": {
            "ga": {"population": args.population, "iterations": args.iterations, "seed": "scenario seed"},
            "ortools": {"solution_limit": args.ortools_solutions, "time_limit": None},
            "pyvrp": {"iterations": args.pyvrp_iterations, "seed": "scenario seed"},
            "lkh": {
                "runs": args.lkh_runs,
                "scale": LKH_SCALE,
                "transform": "asymmetric TSP, starts as nodes",
            },
            "scenario_seeds": list(range(args.seeds)),
            "min_tour": 1,
            "routes": "open",
        },
        "provenance": {
            **provenance(),
            "load_average": {
                "before": [round(x, 2) for x in load_before],
                "after": [round(x, 2) for x in os.getloadavg()],
            },
            "elapsed_s": round(time.perf_counter() - t0, 1),
        },
        "ga_timing": timing,
        "distances": distances,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"written: {args.out}")


if __name__ == "__main__":
    main()
