"""Several vehicles: the tour engine on the paper's 10 x 10 scenarios, open and closed routes.

Scenarios (100 targets in a 10 x 10 box, one instance per seed; the seed also seeds the engine):

- ``A``: targets on the grid 0.5 .. 9.5, four starts uniform in the box;
- ``B``: 100 uniform targets, starts (-1, 2.5), (-1, 5), (-1, 7.5);
- ``C``: 100 uniform targets, four uniform starts.

For each scenario, radius (0.3, 0.1) and route kind (open, closed) it prints the total length and the
longest route with ``objective="distance"``, then the longest route and total with ``objective="time"``,
averaged over the seeds, and writes the runs to JSON.

    python -m studies.tours_fleet                 # seeds 0-4
    python -m studies.tours_fleet --seeds 0 --scenarios A
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.tours import DiscProblem, TourSettings, check_tours, plan_tours
from studies.provenance import provenance

RESULTS = Path(__file__).resolve().parent / "results" / "tours_fleet"


def scenario(name: str, seed: int, radius: float, closed: bool) -> DiscProblem:
    """One instance of scenario ``name`` drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    if name == "A":
        g = np.arange(0.5, 10, 1.0)
        centres = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        starts = rng.uniform(0, 10, (4, 2))
    elif name == "B":
        centres = rng.uniform(0, 10, (100, 2))
        starts = np.array([[-1.0, 2.5], [-1.0, 5.0], [-1.0, 7.5]])
    elif name == "C":
        centres = rng.uniform(0, 10, (100, 2))
        starts = rng.uniform(0, 10, (4, 2))
    else:
        raise ValueError(f"unknown scenario {name!r}")
    return DiscProblem(starts, centres, np.full(len(centres), radius), closed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="*", default=["A", "B", "C"])
    parser.add_argument("--radii", type=float, nargs="*", default=[0.3, 0.1])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4])
    parser.add_argument("--name", default="fleet")
    parser.add_argument("--no-save", action="store_true")
    args = parser.parse_args(argv)
    out: dict[str, Any] = {"provenance": provenance(), "runs": []}
    head = f"{'case':16s} {'dist: total':>12s} {'makespan':>9s} {'time: makespan':>15s} {'total':>8s}"
    print(head + f" {'s/run':>6s}")
    for name in args.scenarios:
        for radius in args.radii:
            for closed in (False, True):
                rows = []
                for seed in args.seeds:
                    problem = scenario(name, seed, radius, closed)
                    row: dict[str, Any] = {"scenario": name, "radius": radius, "closed": closed, "seed": seed}
                    for objective in ("distance", "time"):
                        t0 = time.perf_counter()
                        tours = plan_tours(problem, TourSettings(seed=seed, objective=objective))
                        check_tours(tours)
                        row[objective] = {
                            "total": tours.total,
                            "makespan": tours.makespan,
                            "lengths": tours.lengths.tolist(),
                            "time": time.perf_counter() - t0,
                        }
                    rows.append(row)
                out["runs"].extend(rows)
                d = [r["distance"] for r in rows]
                t = [r["time"] for r in rows]
                label = f"{name} r={radius} {'closed' if closed else 'open'}"
                secs = np.mean([x["time"] for x in d + t])
                dt, dm = np.mean([x["total"] for x in d]), np.mean([x["makespan"] for x in d])
                tm, tt = np.mean([x["makespan"] for x in t]), np.mean([x["total"] for x in t])
                print(f"{label:16s} {dt:12.3f} {dm:9.3f} {tm:15.3f} {tt:8.3f} {secs:6.1f}", flush=True)
    if not args.no_save:
        RESULTS.mkdir(parents=True, exist_ok=True)
        path = RESULTS / f"{args.name}.json"
        path.write_text(json.dumps(out, indent=1) + "\n")
        print(f"written {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
