"""Route length caps: the shortest total within the caps, against the uncapped optimum and the earliest
finish.

Two parts:

- **fleet**: the closed scenarios of :mod:`studies.tours_fleet` (100 targets, radius 0.3), each capped
  at ``--factor`` times the longest route of its uncapped ``objective="distance"`` answer; the total
  with the caps against the uncapped total and against ``objective="time"``.
- **survey**: the example mission ``survey`` (3 drones, 36 sites, closed routes, 10 m/s limit, 450
  steps of 2 s), capped at each drone's route budget
  (:func:`pmht_opt.planners.routes.route_budgets`); total and longest route by distance without
  caps, with them, and by time.

    python -m studies.tours_caps                      # seeds 0-2, factor 0.8, both parts
    python -m studies.tours_caps --parts survey
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np

from pmht_opt.io import example_mission
from pmht_opt.planners.routes import closed_routes, route_budgets
from pmht_opt.tours import DiscProblem, DiscTours, TourSettings, plan_tours
from studies.provenance import provenance
from studies.tours_fleet import RESULTS, scenario


def capped(problem: DiscProblem, caps: np.ndarray) -> DiscProblem:
    """The same problem with route length caps."""
    return DiscProblem(problem.starts, problem.centres, problem.radii, problem.closed, max_lengths=caps)


def summary(tours: DiscTours) -> dict[str, Any]:
    """Total, longest route and every route's length."""
    return {"total": tours.total, "makespan": tours.makespan, "lengths": tours.lengths.tolist()}


def fleet(seeds: list[int], factor: float) -> list[dict[str, Any]]:
    """The fleet scenarios capped at ``factor`` times their uncapped longest route."""
    rows: list[dict[str, Any]] = []
    print(f"{'case':5s} {'distance':>17s} {'cap':>7s} {'with caps':>17s} {'time':>17s}   total / longest")
    for name in ("A", "B", "C"):
        for seed in seeds:
            problem = scenario(name, seed, 0.3, True)
            free = plan_tours(problem, TourSettings(seed=seed))
            caps = np.full(problem.n_vehicles, factor * free.makespan)
            within = plan_tours(capped(problem, caps), TourSettings(seed=seed))
            timed = plan_tours(problem, TourSettings(seed=seed, objective="time"))
            rows.append(
                {
                    "case": f"{name}{seed}",
                    "cap": float(caps[0]),
                    "distance": summary(free),
                    "capped": summary(within),
                    "time": summary(timed),
                }
            )
            cells = [f"{t.total:8.3f} {t.makespan:8.3f}" for t in (free, within, timed)]
            print(f"{name}{seed:<4d} {cells[0]} {caps[0]:7.3f} {cells[1]} {cells[2]}", flush=True)
    over = [r["capped"]["total"] / r["distance"]["total"] - 1 for r in rows]
    save = [1 - r["capped"]["total"] / r["time"]["total"] for r in rows]
    print(
        f"with caps: {100 * np.mean(over):.2f}% longer than uncapped (worst {100 * max(over):.2f}%), "
        f"{100 * np.mean(save):.2f}% shorter than by time (least {100 * min(save):.2f}%)"
    )
    return rows


def survey(seeds: list[int]) -> list[dict[str, Any]]:
    """The survey mission's tours: by distance, by distance within the route budgets, by time."""
    mission = example_mission("survey")
    sc, constraints = mission.scenario, mission.constraints_for_plan()
    budgets = route_budgets(sc, constraints)
    problem = DiscProblem(sc.start_positions, sc.locales, sc.radii, closed_routes(sc, constraints))
    print(f"survey: budgets {np.round(budgets, 1).tolist()} m")
    rows = []
    for seed in seeds:
        runs = {
            "distance": plan_tours(problem, TourSettings(seed=seed)),
            "capped": plan_tours(capped(problem, budgets), TourSettings(seed=seed)),
            "time": plan_tours(problem, TourSettings(seed=seed, objective="time")),
        }
        rows.append({"seed": seed, "budgets": budgets.tolist(), **{k: summary(t) for k, t in runs.items()}})
        for key, t in runs.items():
            lengths = np.round(t.lengths, 1).tolist()
            print(f"seed {seed} {key:9s} total {t.total:8.1f} longest {t.makespan:7.1f} routes {lengths}")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--parts", nargs="*", default=["fleet", "survey"], choices=["fleet", "survey"])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--factor", type=float, default=0.8)
    parser.add_argument("--name", default="caps")
    parser.add_argument("--no-save", action="store_true")
    args = parser.parse_args(argv)
    out: dict[str, Any] = {"provenance": provenance(), "factor": args.factor}
    if "fleet" in args.parts:
        out["fleet"] = fleet(args.seeds, args.factor)
    if "survey" in args.parts:
        out["survey"] = survey(args.seeds)
    if not args.no_save:
        RESULTS.mkdir(parents=True, exist_ok=True)
        path = RESULTS / f"{args.name}.json"
        path.write_text(json.dumps(out, indent=1) + "\n")
        print(f"written {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
