"""Study: total distance at equal coverage, on scenarios A, B, C, at sensor radii 0.05 to 0.5.

Two families of planners (docs/model.md section 11 defines coverage):

- **Full coverage at radius rho** (one trial per radius): an ordering of the locales smoothed with every
  locale passed within rho (``ga-smoothed``, ``ortools-smoothed``, ``pyvrp-smoothed``:
  :func:`~pmht_opt.plan_smoothed` with ``split="distance"``), ``pmht-visitall`` (PMHT with
  ``VisitAll(rho)``) and ``coverage`` (:func:`~pmht_opt.plan_coverage`). Their distance is the cost of
  covering everything; a trial that raises is a row with its error.
- **Partial coverage** (one trial, coverage measured at every radius): PMHT with its default settings
  (``pmht``), the paper's literal settings (``pmht-paper``) and the default with other penalties ``r``
  (``pmht-r0.001`` ...): points (coverage at rho, distance) on the trade-off.

Every setting is deterministic (orderings stopped on iterations or greedy descent, never on wall time),
so ``--verify`` reproduces the rows. The summary gives, per scenario, radius and planner, the mean and
median distance, the mean coverage, failures and time, and for ``coverage`` its ratio to the best of
the OR-Tools and PyVRP smoothed plans; the figures (one per scenario) draw distance against radius and
the coverage-distance points with their Pareto front.

    pmht-opt study coverage --workers 2 --out studies/results/coverage
    pmht-opt study coverage --trials 2 --radii 0.1 0.3 --methods coverage ortools-smoothed pmht
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.constraints import VisitAll
from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering import METHODS as ORDERINGS
from pmht_opt.ordering import order_locales
from pmht_opt.planners.coverage import plan_coverage
from pmht_opt.planners.pmht import plan_pmht
from pmht_opt.planners.smoothed import plan_smoothed
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.settings import PMHTConfig
from studies.options import Choices, Count, Positives, RunOptions, StudyOptions, option
from studies.report import Columns, frame, markdown_table, summarise
from studies.trials import CONSTRAINED, TIME_CHECKS, TIME_COLUMNS, TrialTable

KINDS = ("A", "B", "C")
RADII = (0.05, 0.1, 0.2, 0.3, 0.5)
HORIZON = 500
#: Planners that cover every locale at the trial's radius.
FULL = ("ga-smoothed", "ortools-smoothed", "pyvrp-smoothed", "pmht-visitall", "coverage")
#: Planners whose coverage is whatever they achieve; penalties ``r`` of the ``pmht-r*`` variants.
PARTIAL_R = {"pmht-r0.001": 1e-3, "pmht-r0.003": 3e-3, "pmht-r0.03": 3e-2}
PARTIAL = ("pmht", "pmht-paper", *PARTIAL_R)
METHODS = FULL + PARTIAL
#: The baselines ``coverage`` is judged against (the best of them, per scenario and radius).
BASELINES = ("ortools-smoothed", "pyvrp-smoothed")
#: Deterministic ordering settings: OR-Tools' greedy descent (the limit is a guard, never reached).
ORDER_OPTIONS: dict[str, dict[str, Any]] = {
    "ga": {},
    "ortools": {"metaheuristic": "GREEDY_DESCENT", "time_limit": 600.0},
    "pyvrp": {},
}


def default_methods() -> tuple[str, ...]:
    """Every planner whose ordering method is installed in this library (PyVRP is an extra)."""
    return tuple(m for m in METHODS if not m.endswith("-smoothed") or m.split("-")[0] in ORDERINGS)


def _tour(sc: Scenario, method: str, seed: int) -> Any:
    name = method.split("-")[0]
    options = dict(ORDER_OPTIONS[name])
    if name != "ortools":
        options["seed"] = seed
    return order_locales(sc, name, **options)


def _plan(sc: Scenario, method: str, radius: float, seed: int) -> PlanResult:
    cfg = PMHTConfig(threads=1)
    if method.endswith("-smoothed"):
        return plan_smoothed(sc, _tour(sc, method, seed), cfg, radius, split="distance")
    if method == "pmht-visitall":
        return plan_pmht(sc, PMHTConfig(threads=1, constraints=[VisitAll(radius)]))
    if method == "coverage":
        return plan_coverage(sc, radius, cfg, seed=seed)
    if method == "pmht":
        return plan_pmht(sc, cfg)
    if method == "pmht-paper":
        return plan_pmht(sc, PMHTConfig.paper(threads=1))
    if method in PARTIAL_R:
        return plan_pmht(sc.replace(r=PARTIAL_R[method]), cfg)
    raise ConfigError(f"method: expected one of {', '.join(METHODS)}, got {method!r}.")


def trial(kind: str, seed: int, method: str, radius: float, horizon: int) -> dict[str, Any]:
    """One planner on one seeded paper scenario: distance, coverage at every radius, smoothness, time.

    ``radius`` is the radius a full-coverage planner must cover at (0 for the partial planners, whose
    ``coverage`` is then null: ``coverage_at`` holds their coverage at every radius of the study).
    ``energy`` is the motion prior's cost of the paths, ``1/2 sum ||u||^2`` (docs/model.md section 2):
    how hard they manoeuvre.
    """
    sc = paper_scenario(kind, seed=seed, horizon=horizon)
    cpu, wall = time.process_time(), time.perf_counter()
    res = _plan(sc, method, radius, seed)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    miss = res.miss_distance
    return {
        "distance": res.total_distance,
        "coverage": res.coverage(radius) if radius > 0 else None,
        "coverage_at": {f"{r:g}": float(np.mean(miss <= r * (1 + 1e-6))) for r in RADII},
        "max_miss": float(np.max(miss)),
        "max_acceleration": res.max_acceleration,
        "energy": -sc.model.log_prior(res.states),
        "excursion": res.max_excursion(),
        "cpu": cpu,
        "wall": wall,
    }


#: What a trial records: the plan's measures, its coverage at every radius of the study and its times.
RESULTS = {
    "distance": "float",
    "coverage": "float?",
    "coverage_at": "dict",
    "max_miss": "float",
    "max_acceleration": "float",
    "energy": "float",
    "excursion": "float",
    **TIME_COLUMNS,
}
#: The measures of a plan that its constrained M-steps' tolerance reaches.
PLAN_MEASURES = ("distance", "max_miss", "max_acceleration", "energy", "excursion")
TABLE = TrialTable.of(
    "coverage",
    trial,
    RESULTS,
    {**TIME_CHECKS, **dict.fromkeys(PLAN_MEASURES, CONSTRAINED)},
)


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study coverage``."""

    trials: int = option(100, Count("--trials", "seeds 0..TRIALS-1 per scenario"))
    radii: tuple[float, ...] = option(RADII, Positives("--radii", "coverage radii"))
    methods: tuple[str, ...] = option(
        METHODS,
        Choices(
            "--methods",
            "planners (default: all whose ordering is installed)",
            known=METHODS,
            installed=default_methods,
        ),
    )
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))
    horizon: int = option(HORIZON, Count("--horizon", "time steps (default: the paper's 500)", minimum=2))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run: full-coverage planners once per radius, partial ones once (radius 0)."""
    out = []
    for method in options.methods:
        radii = options.radii if method in FULL else (0.0,)
        for radius in radii:
            for kind in options.kinds:
                for seed in range(options.trials):
                    out.append(
                        {
                            "kind": kind,
                            "seed": seed,
                            "method": method,
                            "radius": radius,
                            "horizon": options.horizon,
                        }
                    )
    return out


def summary(rows: Sequence[Mapping[str, Any]], radii: Sequence[float]) -> list[dict[str, Any]]:
    """Per (scenario, radius, planner): distance statistics, mean coverage, failures, median time, and
    for ``coverage`` the ratio of its mean distance to the best baseline's on the same trials."""
    df = frame(rows)
    out = []
    for kind in sorted(set(df["kind"])):
        for radius in radii:
            base: dict[str, float] = {}
            for method in METHODS:
                mine = df[(df["kind"] == kind) & (df["method"] == method)]
                mine = mine[mine["radius"] == (radius if method in FULL else 0.0)]
                if mine.empty:
                    continue
                ok = mine[mine["error"] == ""]
                dist = summarise(ok["distance"]) if len(ok) else summarise([])
                cov = [c.get(f"{radius:g}") for c in ok["coverage_at"]] if len(ok) else []
                entry = {
                    "scenario": kind,
                    "radius": radius,
                    "method": method,
                    "trials": dist["n"],
                    "failed": int((mine["error"] != "").sum()),
                    "mean_distance": dist["mean"],
                    "median_distance": dist["median"],
                    "mean_coverage": summarise(cov)["mean"],
                    "median_time": summarise(ok["wall"])["median"] if len(ok) else float("nan"),
                }
                if method in BASELINES:
                    base[method] = dist["mean"]
                out.append(entry)
            _ratios(out, kind, radius, base)
    return out


def _ratios(out: list[dict[str, Any]], kind: str, radius: float, base: Mapping[str, float]) -> None:
    """``ratio``: ``coverage``'s mean distance over the best baseline's (when any baseline ran)."""
    finite = [v for v in base.values() if np.isfinite(v)]
    if not finite:
        return
    for entry in out:
        if entry["scenario"] == kind and entry["radius"] == radius and entry["method"] == "coverage":
            entry["ratio"] = entry["mean_distance"] / min(finite)
            entry["baseline"] = min(base, key=lambda k: base[k] if np.isfinite(base[k]) else np.inf)


#: The summary's markdown table.
COLUMNS: Columns = (
    ("scenario", lambda s: s["scenario"]),
    ("radius", lambda s: f"{s['radius']:g}"),
    ("planner", lambda s: s["method"]),
    ("trials (failed)", lambda s: f"{s['trials']} ({s['failed']})"),
    ("mean distance", lambda s: f"{s['mean_distance']:.2f}"),
    ("median", lambda s: f"{s['median_distance']:.2f}"),
    ("mean coverage", lambda s: f"{s['mean_coverage']:.3f}"),
    ("median time (s)", lambda s: f"{s['median_time']:.2f}"),
    ("coverage / best baseline", lambda s: f"{s['ratio']:.3f} ({s['baseline']})" if "ratio" in s else ""),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    return markdown_table(COLUMNS, table)


def main(run: RunOptions, options: Options) -> list[Path]:
    """Run the study into ``run.out``: ``coverage.jsonl``, the summary, the table and one figure per
    scenario."""
    from studies.coverage_figures import write_figures

    out, rows = run.run_trials(TABLE, params(options))
    table = summary(rows, options.radii)
    written = run.publish(TABLE, out, table, markdown(table), rows=rows)
    return [*written, *write_figures(rows, options.radii, out)]


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("coverage", __file__)
