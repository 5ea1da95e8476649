"""Study: plain against annealed EM, with and without the time-prior update, on scenarios A, B, C.

For every trial (scenario kind, seed) and configuration: total distance, coverage at 0.3, the largest
excursion outside the 10 x 10 area, and time. The summary gives, per scenario and configuration, the
mean, median and maximum distance, mean coverage, and the number of runs that leave the area by more
than 1 unit (scenario B starts at x = -1, exactly 1 unit outside, which therefore does not count).

The pairs "annealed" / "annealed+time-prior" answer whether the planner should re-estimate the time
prior (paper eq. 11) once annealing is the default; "plain" / "plain+time-prior" show why annealing is.

    pmht-opt study anneal --workers 2 --out studies/results/anneal
    python studies/anneal.py [--trials 100] [--workers 2]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pmht_opt.anneal import Anneal
from pmht_opt.planners.pmht import plan_pmht
from pmht_opt.scenario import paper_scenario
from pmht_opt.settings import PMHTConfig
from studies.options import Choices, Count, StudyOptions, option
from studies.report import EXCURSION_LIMIT, Columns, frame, markdown_table, summarise
from studies.trials import Check, TrialTable

#: Configurations compared: name -> (anneal, update_time_prior). The first four are the main grid;
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
KINDS = ("A", "B", "C")
HORIZON = 500


def trial(kind: str, seed: int, config: str, horizon: int) -> dict[str, Any]:
    """One plan of scenario ``kind`` (seed ``seed``, ``horizon`` steps) with configuration ``config``."""
    anneal, time_prior = CONFIGS[config]
    sc = paper_scenario(kind, seed=seed, horizon=horizon)
    res = plan_pmht(sc, PMHTConfig(anneal=anneal, update_time_prior=time_prior, threads=1))
    m = res.metrics()
    return {
        "distance": m["total_distance"],
        "coverage": m["coverage"],
        "excursion": m["max_excursion"],
        "left_area": bool(m["max_excursion"] > EXCURSION_LIMIT + 1e-9),
        "time": m["wall_time"],
    }


TABLE = TrialTable.of(
    "anneal",
    trial,
    {"distance": "float", "coverage": "float", "excursion": "float", "left_area": "bool", "time": "float"},
    {"time": Check("skip", reason="wall-clock time differs from run to run")},
)


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study anneal``."""

    trials: int = option(100, Count("--trials", "trials per scenario and configuration"))
    configs: tuple[str, ...] = option(tuple(CONFIGS), Choices("--configs", known=tuple(CONFIGS)))
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))
    horizon: int = option(HORIZON, Count("--horizon", "time steps (default: the paper's 500)", minimum=2))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run, configuration-major."""
    return [
        {"kind": k, "seed": s, "config": c, "horizon": options.horizon}
        for c in options.configs
        for k in options.kinds
        for s in range(options.trials)
    ]


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, configuration): distance statistics, mean coverage, runs leaving the area."""
    df = frame(rows)
    out = []
    order = {c: i for i, c in enumerate(CONFIGS)}
    keys = sorted(
        {(k, c) for k, c in zip(df["kind"], df["config"], strict=True)}, key=lambda k: (k[0], order[k[1]])
    )
    for kind, config in keys:
        mine = df[(df["kind"] == kind) & (df["config"] == config)]
        ok = mine[mine["error"] == ""]
        dist = summarise(ok["distance"]) if "distance" in ok else summarise([])
        out.append(
            {
                "scenario": kind,
                "config": config,
                "trials": dist["n"],
                "failed": int((mine["error"] != "").sum()),
                "mean_distance": dist["mean"],
                "median_distance": dist["median"],
                "max_distance": dist["max"],
                "mean_coverage": summarise(ok["coverage"])["mean"] if len(ok) else float("nan"),
                "left_area": int(ok["left_area"].astype(bool).sum()) if len(ok) else 0,
                "median_time": summarise(ok["time"])["median"] if len(ok) else float("nan"),
            }
        )
    return out


#: The summary's markdown table.
COLUMNS: Columns = (
    ("scenario", lambda s: s["scenario"]),
    ("configuration", lambda s: s["config"]),
    ("trials", lambda s: s["trials"]),
    ("mean distance", lambda s: f"{s['mean_distance']:.1f}"),
    ("median", lambda s: f"{s['median_distance']:.1f}"),
    ("max", lambda s: f"{s['max_distance']:.1f}"),
    ("mean coverage (0.3)", lambda s: f"{s['mean_coverage']:.3f}"),
    ("runs leaving area by > 1", lambda s: s["left_area"]),
    ("median time (s)", lambda s: f"{s['median_time']:.2f}"),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    return markdown_table(COLUMNS, table)


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("anneal", __file__)
