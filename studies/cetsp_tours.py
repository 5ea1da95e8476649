"""Benchmark of the straight-line tour engine on Mennell's close-enough TSP instances.

Runs :func:`pmht_opt.tours.plan_tours` (one vehicle, closed at the depot, per-target radii, default
settings) on each case of a BKS table and prints, per case: targets, straight length / BKS for each
seed, the spread of the seeds, the independent coverage check and the CPU time of each run (the
process's CPU seconds: less sensitive than wall time to other work on a shared machine; both are
saved). Results go to a JSON file
with their provenance.

    python -m studies.cetsp_tours                       # the 16 cases of the shared benchmark
    python -m studies.cetsp_tours --cases bubbles4 --seeds 0
    python -m studies.cetsp_tours --table studies/cetsp_extra/bks.csv --name extra

A table is a CSV with at least the columns ``name``, ``file`` (relative to the table), ``radius_factor``
and ``bks``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import importlib.metadata
import json
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.tours import DiscProblem, TourSettings, coverage_gaps, plan_tours, read_mennell

DEFAULT_TABLE = Path("/work/shared/benchmarks/cetsp/bks.csv")
RESULTS = Path(__file__).resolve().parent / "results" / "cetsp_tours"


def provenance() -> dict[str, Any]:
    """Commit (and whether the worktree was clean), date, Python and library versions."""
    repo = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        try:
            return subprocess.run(
                ["git", *args], cwd=repo, capture_output=True, text=True, check=True
            ).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    versions = {}
    for name in ("numpy", "scipy", "pyvrp", "clarabel"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return {
        "commit": git("rev-parse", "HEAD"),
        "clean": git("status", "--porcelain", "--untracked-files=no") == "",
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "versions": versions,
    }


def run_case(row: dict[str, str], base: Path, seeds: list[int]) -> dict[str, Any]:
    """Every seed on one case: lengths, ratios, coverage margins and times."""
    depot, centres, radii = read_mennell(base / row["file"], float(row["radius_factor"]))
    problem = DiscProblem(depot[None], centres, radii, closed=True)
    bks = float(row["bks"])
    runs = []
    for seed in seeds:
        t0, c0 = time.perf_counter(), time.process_time()
        tours = plan_tours(problem, TourSettings(seed=seed))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        gap = coverage_gaps(tours, rtol=0.0)
        runs.append(
            {
                "seed": seed,
                "length": tours.total,
                "ratio": tours.total / bks,
                "time": wall,
                "cpu": cpu,
                "iterations": tours.info["iterations"],
                "turns": len(tours.turns[0]),
                # Length / BKS after each stage: polyline through the centres in PyVRP's order, its
                # cone program, the first local search, ruin and recreate.
                "stages": {k: v / bks for k, v in tours.info["stages"].items()},
                # Largest (distance to polyline - radius) / radius: <= 1e-9 is covered.
                "worst_coverage": float(np.max(gap / radii)) if len(radii) else 0.0,
            }
        )
    ratios = [r["ratio"] for r in runs]
    return {
        "name": row["name"],
        "targets": len(radii),
        "bks": bks,
        "runs": runs,
        "best_ratio": min(ratios),
        "worst_ratio": max(ratios),
        "spread": max(ratios) / min(ratios) - 1,
        "covered": all(r["worst_coverage"] <= 1e-9 for r in runs),
    }


def invariance(row: dict[str, str], base: Path, factors: tuple[float, ...] = (0.01, 100.0)) -> dict[str, Any]:
    """Seed 0 twice at scale 1 and once at each scale factor: same routes, lengths scaled?"""
    depot, centres, radii = read_mennell(base / row["file"], float(row["radius_factor"]))
    runs = [plan_tours(DiscProblem(depot[None], centres, radii, closed=True)) for _ in range(2)]
    same_bits = bool(
        np.array_equal(runs[0].points, runs[1].points) and np.array_equal(runs[0].lengths, runs[1].lengths)
    )
    out: dict[str, Any] = {"name": row["name"], "same_bits": same_bits, "scales": {}}
    for f in factors:
        t = plan_tours(DiscProblem(depot[None] * f, centres * f, radii * f, closed=True))
        out["scales"][str(f)] = {
            "same_routes": all(np.array_equal(a, b) for a, b in zip(t.routes, runs[0].routes, strict=True)),
            "length_ratio_error": abs(t.total / (f * runs[0].total) - 1),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--table", type=Path, default=DEFAULT_TABLE, help="CSV of cases (name, file, radius_factor, bks)"
    )
    parser.add_argument("--cases", nargs="*", default=None, help="only these case names")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--name", default="benchmark", help="results file stem")
    parser.add_argument("--no-save", action="store_true", help="print only")
    parser.add_argument(
        "--invariance", action="store_true", help="instead: same bits twice, and scales 0.01 and 100, seed 0"
    )
    args = parser.parse_args(argv)
    with args.table.open() as fh:
        rows = [r for r in csv.DictReader(fh) if not args.cases or r["name"] in args.cases]
    if args.invariance:
        checks = [invariance(row, args.table.parent) for row in rows]
        for c in checks:
            print(c["name"], "same bits:", c["same_bits"], c["scales"], flush=True)
        if not args.no_save:
            RESULTS.mkdir(parents=True, exist_ok=True)
            record = {"provenance": provenance(), "checks": checks}
            (RESULTS / f"{args.name}_invariance.json").write_text(json.dumps(record, indent=1) + "\n")
        return 0
    out = {"provenance": provenance(), "table": str(args.table), "seeds": args.seeds, "cases": []}
    print(
        f"{'case':22s} {'N':>5s} " + " ".join(f"seed{s:<3d}" for s in args.seeds) + "  spread  cover  cpu/s"
    )
    for row in rows:
        case = run_case(row, args.table.parent, args.seeds)
        out["cases"].append(case)
        ratios = " ".join(f"{r['ratio']:7.4f}" for r in case["runs"])
        times = "/".join(f"{r['cpu']:.1f}" for r in case["runs"])
        print(
            f"{case['name']:22s} {case['targets']:5d} {ratios}  {100 * case['spread']:5.2f}%  "
            f"{'ok' if case['covered'] else 'FAIL':5s}  {times}",
            flush=True,
        )
    cases = out["cases"]
    if cases:
        mean = [float(np.mean([c["runs"][i]["ratio"] for c in cases])) for i in range(len(args.seeds))]
        out["summary"] = {
            "mean_ratio_per_seed": mean,
            "worst_case_ratio": max(c["worst_ratio"] for c in cases),
            "worst_spread": max(c["spread"] for c in cases),
            "all_covered": all(c["covered"] for c in cases),
            "max_time": max(r["time"] for c in cases for r in c["runs"]),
            "max_cpu": max(r["cpu"] for c in cases for r in c["runs"]),
        }
        print("mean ratio per seed:", " ".join(f"{m:.4f}" for m in mean))
        stages = {
            k: float(np.mean([r["stages"][k] for c in cases for r in c["runs"]]))
            for k in cases[0]["runs"][0]["stages"]
        }
        out["summary"]["mean_ratio_per_stage"] = stages
        print("mean ratio after each stage:", ", ".join(f"{k} {v:.4f}" for k, v in stages.items()))
        print(
            f"worst case ratio {out['summary']['worst_case_ratio']:.4f}, "
            f"worst spread {100 * out['summary']['worst_spread']:.2f}%"
        )
    if not args.no_save:
        RESULTS.mkdir(parents=True, exist_ok=True)
        path = RESULTS / f"{args.name}.json"
        path.write_text(json.dumps(out, indent=1) + "\n")
        print(f"written {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
