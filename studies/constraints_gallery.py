"""Constraints gallery: one scenario planned unconstrained, with a speed limit, with obstacles, with
VisitAll, and with area bounds plus the time-prior update; a figure each and their metrics.

Writes ``studies/results/gallery/*.png`` and ``studies/results/constraints_gallery.json`` (with
provenance).

    python studies/constraints_gallery.py [--scenario A] [--seed 1] [--solver clarabel]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pmht_opt as po
from pmht_opt.plotting import plot_result
from studies.report import write_json


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="A")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--solver", default="clarabel")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()

    sc = po.paper_scenario(args.scenario, seed=args.seed)
    free = po.plan_pmht(sc, po.PMHTConfig(solver=args.solver))
    vmax = round(0.7 * free.max_speed, 4)
    obstacles = [
        po.CircleObstacle((3.0, 6.5), 0.9),
        po.PolygonObstacle([(6, 3.5), (7.5, 3.5), (7.5, 6), (6, 6)]),
    ]
    cases = {
        "unconstrained": po.PMHTConfig(solver=args.solver),
        "speed_limit": po.PMHTConfig(solver=args.solver, constraints=[po.SpeedLimit(vmax)]),
        "obstacles": po.PMHTConfig(solver=args.solver, constraints=obstacles),
        "visit_all": po.PMHTConfig(solver=args.solver, constraints=[po.VisitAll(0.1)]),
        "area_bounds_time_prior": po.PMHTConfig(
            solver=args.solver, update_time_prior=True, constraints=[po.AreaBounds(0, 10, 0, 10)]
        ),
        "time_prior_unbounded": po.PMHTConfig(solver=args.solver, update_time_prior=True),
    }
    figdir = args.out / "gallery"
    figdir.mkdir(parents=True, exist_ok=True)
    table: dict[str, dict[str, Any]] = {}
    for name, cfg in cases.items():
        res = po.plan_pmht(sc, cfg)
        m = res.metrics()
        row = {
            "constraints": [c.name for c in cfg.constraints],
            "update_time_prior": cfg.update_time_prior,
            "total_distance": m["total_distance"],
            "coverage_0.3": m["coverage"],
            "coverage_0.1": res.coverage(0.1),
            "max_speed": m["max_speed"],
            "max_excursion": m["max_excursion"],
            "max_violation": res.max_violation,
            "constraint_reports": m["constraints"],
            "wall_time_s": m["wall_time"],
        }
        table[name] = row
        title = (
            f"{sc.name}: {name.replace('_', ' ')}; distance {res.total_distance:.1f}, "
            f"cov@0.3 {res.coverage():.0%}"
        )
        print(f"wrote: {plot_result(res, figdir / f'{name}.png', title=title)}")
        print(
            f"{name:24s} distance {row['total_distance']:7.1f}  cov@0.3 {row['coverage_0.3']:.2f}  "
            f"excursion {row['max_excursion']:.2f}  violation {row['max_violation']:.1e}  "
            f"{row['wall_time_s']:.1f} s"
        )
    payload = {"scenario": sc.name, "speed_limit": vmax, "cases": table}
    print(f"wrote: {write_json(args.out / 'constraints_gallery.json', payload)}")


if __name__ == "__main__":
    main()
