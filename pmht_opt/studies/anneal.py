"""Study: plain against annealed EM (issue 5), with both time-prior settings, on scenarios A, B, C.

For every trial (scenario kind, seed) and configuration: total distance, coverage at 0.3, the largest
excursion outside the 10 x 10 area, and time. The summary gives, per scenario and configuration, the
mean, median and maximum distance, mean coverage, and the number of runs that leave the area by more
than 1 unit (scenario B starts at x = -1, exactly 1 unit outside, which therefore does not count).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.montecarlo import run_trials, summarise
from pmht_opt.planner import PMHTConfig, plan_pmht
from pmht_opt.scenario import paper_scenario
from pmht_opt.studies.common import EXCURSION_LIMIT, write_summary

#: Configurations compared: name -> (anneal, update_time_prior). The first four are the issue's grid;
#: the rest vary the schedule so the default is chosen among more than one annealed candidate.
CONFIGS: dict[str, tuple[Anneal | None, bool]] = {
    "plain": (None, False),
    "plain+time-prior": (None, True),
    "annealed": (Anneal(1.0, 30), False),
    "annealed+time-prior": (Anneal(1.0, 30), True),
    "annealed-1.0x15": (Anneal(1.0, 15), False),
    "annealed-1.0x50": (Anneal(1.0, 50), False),
    "annealed-0.1x30": (Anneal(0.1, 30), False),
}
GRID = ("plain", "plain+time-prior", "annealed", "annealed+time-prior")


def trial(kind: str, seed: int, config: str, solver: str = "clarabel") -> dict[str, Any]:
    """One plan of scenario ``kind`` (seed ``seed``) with configuration ``config``."""
    anneal, time_prior = CONFIGS[config]
    sc = paper_scenario(kind, seed=seed)
    res = plan_pmht(sc, PMHTConfig(solver=solver, anneal=anneal, update_time_prior=time_prior, threads=1))
    m = res.metrics()
    return {
        "distance": m["total_distance"],
        "coverage": m["coverage"],
        "excursion": m["max_excursion"],
        "left_area": bool(m["max_excursion"] > EXCURSION_LIMIT + 1e-9),
        "time": m["wall_time"],
    }


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, configuration): distance statistics, mean coverage, runs leaving the area."""
    out = []
    keys = sorted({(r["kind"], r["config"]) for r in rows}, key=lambda k: (k[0], list(CONFIGS).index(k[1])))
    for kind, config in keys:
        mine = [r for r in rows if r["kind"] == kind and r["config"] == config and not r.get("error")]
        dist = summarise([r["distance"] for r in mine])
        cov = summarise([r["coverage"] for r in mine])
        out.append(
            {
                "scenario": kind,
                "config": config,
                "trials": dist["n"],
                "failed": sum(
                    1 for r in rows if r["kind"] == kind and r["config"] == config and r.get("error")
                ),
                "mean_distance": dist["mean"],
                "median_distance": dist["median"],
                "max_distance": dist["max"],
                "mean_coverage": cov["mean"],
                "left_area": sum(1 for r in mine if r["left_area"]),
                "median_time": summarise([r["time"] for r in mine])["median"],
            }
        )
    return out


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    lines = [
        "| scenario | configuration | trials | mean distance | median | max | mean coverage (0.3) "
        "| runs leaving area by > 1 | median time (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in table:
        lines.append(
            f"| {s['scenario']} | {s['config']} | {s['trials']} | {s['mean_distance']:.1f} "
            f"| {s['median_distance']:.1f} | {s['max_distance']:.1f} | {s['mean_coverage']:.3f} "
            f"| {s['left_area']} | {s['median_time']:.2f} |"
        )
    return "\n".join(lines)


def run(
    out_dir: Path,
    trials: int = 100,
    configs: tuple[str, ...] = tuple(CONFIGS),
    kinds: tuple[str, ...] = ("A", "B", "C"),
    workers: int = 1,
    executor: Any = None,
    progress: bool = True,
    resume: bool = True,
) -> list[dict[str, Any]]:
    """Run the study into ``out_dir`` (``anneal.csv``, ``anneal_summary.json``, ``anneal.md``)."""
    params = [{"kind": k, "seed": s, "config": c} for c in configs for k in kinds for s in range(trials)]
    rows = run_trials(
        trial,
        params,
        out_dir / "anneal.csv",
        executor=executor,
        workers=workers,
        progress=progress,
        label="anneal study",
        resume=resume,
    )
    table = summary(rows)
    write_summary(out_dir, "anneal", table, markdown(table))
    return table


def add_arguments(p: Any) -> None:
    """Options of ``pmht-opt study anneal``."""
    p.add_argument("--trials", type=int, default=100, help="trials per scenario and configuration")
    p.add_argument(
        "--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS), help="configurations to run"
    )


def main(args: Any) -> int:
    """``pmht-opt study anneal``."""
    from pmht_opt.studies.common import executor_from_args

    with executor_from_args(args) as ex:
        run(
            args.out,
            trials=args.trials,
            configs=tuple(args.configs),
            executor=ex,
            progress=not args.quiet,
            resume=not args.fresh,
        )
    return 0
