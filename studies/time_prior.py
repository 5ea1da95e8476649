"""Study: should the planner re-estimate the time prior (paper eq. 11)? Chooses PMHTConfig's default.

For each scenario (A, B, C) and each setting of ``update_time_prior``, plans ``--trials`` seeded trials
(100 iterations, clarabel) and reports mean / median / max total distance, mean coverage at 0.3 and
the number of runs whose path leaves the 10 x 10 area by more than 1 unit. Writes
``studies/results/time_prior.json`` and prints a markdown table.

    python studies/time_prior.py [--trials 20]
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import pmht_opt as po


def trial(args: tuple[str, int, bool]) -> dict:
    kind, seed, update = args
    res = po.plan_pmht(
        po.paper_scenario(kind, seed=seed),
        po.PMHTConfig(max_iter=100, update_time_prior=update, threads=1),
    )
    return {
        "distance": res.total_distance,
        "coverage": res.coverage(0.3),
        "excursion": res.max_excursion(),
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "time_prior.json")
    args = parser.parse_args()
    jobs = [(k, s, u) for k in "ABC" for u in (False, True) for s in range(args.trials)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(trial, jobs, chunksize=2))
    table = {}
    print(
        "| scenario | update_time_prior | mean dist | median dist | max dist | coverage@0.3 | runs > 1 outside |"
    )
    print("|---|---|---|---|---|---|---|")
    for k in "ABC":
        for u in (False, True):
            sel = [r for (kk, _s, uu), r in zip(jobs, rows, strict=True) if kk == k and uu == u]
            d = np.array([r["distance"] for r in sel])
            c = np.array([r["coverage"] for r in sel])
            e = np.array([r["excursion"] for r in sel])
            entry = {
                "mean_distance": float(d.mean()),
                "median_distance": float(np.median(d)),
                "max_distance": float(d.max()),
                "mean_coverage": float(c.mean()),
                "runs_outside_by_1": int(np.sum(e > 1.0)),
                "trials": len(sel),
            }
            table[f"{k}/update_time_prior={u}"] = entry
            print(
                f"| {k} | {u} | {entry['mean_distance']:.1f} | {entry['median_distance']:.1f} | "
                f"{entry['max_distance']:.1f} | {entry['mean_coverage']:.2f} | {entry['runs_outside_by_1']} |"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {"trials": args.trials, "iterations": 100, "solver": "clarabel", "results": table}, indent=2
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
