"""Study: total distance at equal coverage, on scenarios A, B, C, at sensor radii 0.05 to 0.5.

Two families of planners (docs/model.md section 11 defines coverage):

- **Full coverage at radius rho** (one trial per radius): an ordering of the locales smoothed with every
  locale passed within rho (``ga-smoothed``, ``ortools-smoothed``, ``pyvrp-smoothed``:
  :func:`~pmht_opt.plan_smoothed` with ``split="distance"``), ``pmht-visitall`` (PMHT with
  ``VisitAll(rho)``) and ``coverage`` (``pmht_opt.plan(scenario, "coverage", radius=rho)``: the
  straight-line tour engine, then smooth paths along it; the straight tour's length is recorded too).
  Their distance is the cost of covering everything; a trial that raises is a row with its error.
- **Partial coverage** (one trial, coverage measured at every radius): PMHT with its default settings
  (``pmht``), the paper's literal settings (``pmht-paper``) and the default with other penalties ``r``
  (``pmht-r0.001`` ...): points (coverage at rho, distance) on the trade-off.

Every setting is deterministic (orderings stopped on iterations or greedy descent, never on wall time),
so ``--verify`` reproduces the rows. A planner with a search of its own (``coverage``, and the GA's and
PyVRP's orderings) runs on the trial's ``plan_seed`` (``--plan-seeds``, default 0 1 2: every plan seed on
the first ``--spread-trials`` scenario seeds, the first plan seed on the others), independent of the
scenario's ``seed``. Coverage at the trial's radius is also checked by the study itself, on the
segments between positions (:mod:`studies.segment_coverage`): ``covered`` and ``worst_gap``.

The summary gives, per scenario, radius and planner (first plan seed), the mean and median distance,
the mean coverage, failures and time, and for ``coverage`` the mean ratio of the smooth path to its
straight tour, its ratio to the best of the OR-Tools and PyVRP smoothed plans, the spread of its plan
seeds (worst / best - 1 per scenario seed) and, with ``--previous FILE`` (the results file of an earlier
run), the trial-by-trial comparison with the earlier ``coverage`` rows of the same scenario, seed and
radius; the figures (one per scenario) draw distance against radius and the coverage-distance points
with their Pareto front.

    pmht-opt study coverage --workers 2 --out studies/results/coverage
    pmht-opt study coverage --trials 2 --radii 0.1 0.3 --methods coverage ortools-smoothed pmht
    pmht-opt study coverage --methods coverage --radii 0.1 0.3 --out studies/results/coverage \
        --previous studies/results/coverage_previous/coverage.jsonl
"""

from __future__ import annotations

import json
import math
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
from pmht_opt.planners import plan
from pmht_opt.planners.pmht import plan_pmht
from pmht_opt.planners.smoothed import plan_smoothed
from pmht_opt.result import PlanResult
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.settings import PMHTConfig, Settings
from studies.options import Choices, Count, Integers, Positives, RunOptions, StudyOptions, Text, option
from studies.report import Columns, frame, markdown_table, summarise
from studies.segment_coverage import covered_fraction, relative_gaps
from studies.trials import CONSTRAINED, TIME_CHECKS, TIME_COLUMNS, Check, TrialTable

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
#: Planners with a search of their own, run on the trial's ``plan_seed``; the others ignore it.
SEEDED = ("coverage", "ga-smoothed", "pyvrp-smoothed")
PLAN_SEEDS = (0, 1, 2)
#: Scenario seeds planned with every plan seed (the others with the first).
SPREAD_TRIALS = 3
#: A distance longer than the earlier run's by more than this (relative) counts as longer.
LONGER = 1e-9
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
    """Plan ``sc`` with ``method`` (at ``radius`` for the full-coverage planners); ``seed`` seeds a
    planner's own search."""
    cfg = PMHTConfig(threads=1)
    if method.endswith("-smoothed"):
        return plan_smoothed(sc, _tour(sc, method, seed), cfg, radius, split="distance")
    if method == "pmht-visitall":
        return plan_pmht(sc, PMHTConfig(threads=1, constraints=[VisitAll(radius)]))
    if method == "coverage":
        return plan(sc, "coverage", settings=Settings(threads=1, seed=seed), radius=radius)
    if method == "pmht":
        return plan_pmht(sc, cfg)
    if method == "pmht-paper":
        return plan_pmht(sc, PMHTConfig.paper(threads=1))
    if method in PARTIAL_R:
        return plan_pmht(sc.replace(r=PARTIAL_R[method]), cfg)
    raise ConfigError(f"method: expected one of {', '.join(METHODS)}, got {method!r}.")


def trial(kind: str, seed: int, method: str, radius: float, horizon: int, plan_seed: int) -> dict[str, Any]:
    """One planner on one seeded paper scenario: distance, coverage at every radius, smoothness, time.

    ``radius`` is the radius a full-coverage planner must cover at (0 for the partial planners, whose
    ``coverage`` is then null: ``coverage_at`` holds their coverage at every radius of the study).
    ``plan_seed`` seeds the planner's own search (:data:`SEEDED`; the others ignore it).
    ``energy`` is the motion prior's cost of the paths, ``1/2 sum ||u||^2`` (docs/model.md section 2):
    how hard they manoeuvre. ``covered`` and ``worst_gap`` are the study's own check at ``radius`` on
    the segments (the fraction within it, and the worst locale's (distance - radius) / radius);
    ``tour_length`` is the coverage planner's straight-line tour.
    """
    sc = paper_scenario(kind, seed=seed, horizon=horizon)
    cpu, wall = time.process_time(), time.perf_counter()
    res = _plan(sc, method, radius, plan_seed)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    miss = res.miss_distance
    gaps = relative_gaps(sc.locales, radius, list(res.positions)) if radius > 0 else None
    return {
        "distance": res.total_distance,
        "coverage": res.coverage(radius) if radius > 0 else None,
        "covered": None if gaps is None else covered_fraction(gaps),
        "worst_gap": None if gaps is None else float(gaps.max()),
        "tour_length": res.extras.get("tour_length") if method == "coverage" else None,
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
    "covered": "float?",
    "worst_gap": "float?",
    "tour_length": "float?",
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
    {
        **TIME_CHECKS,
        **dict.fromkeys(PLAN_MEASURES, CONSTRAINED),
        "worst_gap": Check(
            "close", rtol=1e-5, atol=1e-6, reason="discs met at their radius, to the M-steps' tolerance"
        ),
    },
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
    plan_seeds: tuple[int, ...] = option(
        PLAN_SEEDS, Integers("--plan-seeds", "seeds of the planners' own searches (default 0 1 2)")
    )
    spread_trials: int = option(
        SPREAD_TRIALS,
        Count(
            "--spread-trials",
            "scenario seeds 0..K-1 planned with every plan seed, the others with the first (default 3)",
            minimum=0,
        ),
    )
    previous: str = option(
        "",
        Text("--previous", "the results file of an earlier run: compare the coverage planner with its rows"),
    )


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run: full-coverage planners once per radius, partial ones once (radius 0); a
    seeded planner with every plan seed on the first ``spread_trials`` scenario seeds."""
    out = []
    for method in options.methods:
        radii = options.radii if method in FULL else (0.0,)
        for radius in radii:
            for kind in options.kinds:
                for seed in range(options.trials):
                    spread = method in SEEDED and seed < options.spread_trials
                    for plan_seed in options.plan_seeds if spread else options.plan_seeds[:1]:
                        out.append(
                            {
                                "kind": kind,
                                "seed": seed,
                                "method": method,
                                "radius": radius,
                                "horizon": options.horizon,
                                "plan_seed": plan_seed,
                            }
                        )
    return out


def previous_distances(path: str | Path) -> dict[tuple[str, int, float, int], float]:
    """The ``coverage`` planner's distance per (scenario, seed, radius, horizon) in the results file of
    an earlier run (whatever its schema; the rows that planned, with the first plan seed when it has
    plan seeds).

    Raises
    ------
    ConfigError
        Naming the file when it cannot be read or a line is not JSON.
    """
    out: dict[tuple[str, int, float, int], float] = {}
    try:
        text = Path(path).read_text()
    except OSError as err:
        raise ConfigError(f"--previous: cannot read {path} ({err.strerror or err}).") from None
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            raise ConfigError(f"--previous: {path}, line {n}: not JSON.") from None
        if rec.get("record") != "row" or rec.get("method") != "coverage" or rec.get("error_class"):
            continue
        if rec.get("plan_seed", 0) != 0:
            continue
        out[(rec["kind"], int(rec["seed"]), float(rec["radius"]), int(rec["horizon"]))] = float(
            rec["distance"]
        )
    return out


def summary(
    rows: Sequence[Mapping[str, Any]],
    radii: Sequence[float],
    *,
    plan_seed: int = 0,
    previous: Mapping[tuple[str, int, float, int], float] | None = None,
) -> list[dict[str, Any]]:
    """Per (scenario, radius, planner): distance statistics, mean coverage, failures, median time, and
    for ``coverage`` the ratio of its mean distance to the best baseline's on the same trials.

    The statistics are those of the rows with ``plan_seed`` (rows without one count as 0). A seeded
    planner's entry adds the spread of its plan seeds; ``coverage``'s adds the smooth path over its
    straight tour, the study's own coverage check and, given the ``previous`` run's distances
    (:func:`previous_distances`), the comparison trial by trial.
    """
    every = frame(rows)
    if "plan_seed" not in every:
        every["plan_seed"] = 0
    df = every[every["plan_seed"] == plan_seed]
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
                if method in SEEDED:
                    same = every[(every["kind"] == kind) & (every["method"] == method)]
                    entry.update(_seed_spread(same[same["radius"] == radius]))
                if method == "coverage" and len(ok):
                    entry.update(_coverage_measures(ok, previous))
                out.append(entry)
            _ratios(out, kind, radius, base)
    return out


def _seed_spread(rows: Any) -> dict[str, Any]:
    """Over the scenario seeds planned with several plan seeds: worst / best - 1 of the distance (and of
    the straight tour, where there is one), its mean and maximum, and how many scenario seeds."""
    ok = rows[rows["error"] == ""]
    spreads: dict[str, list[float]] = {"distance": [], "tour_length": []}
    for _, g in ok.groupby("seed"):
        if len(g) < 2:
            continue
        for col in spreads:
            vals = [float(v) for v in g[col]] if col in g else []
            vals = [v for v in vals if math.isfinite(v)]
            if len(vals) >= 2:
                spreads[col].append(max(vals) / min(vals) - 1)
    if not spreads["distance"]:
        return {}
    out: dict[str, Any] = {
        "plan_seeds": sorted(int(v) for v in set(ok["plan_seed"])),
        "spread_trials": len(spreads["distance"]),
        "seed_spread_max": max(spreads["distance"]),
        "seed_spread_mean": float(np.mean(spreads["distance"])),
    }
    if spreads["tour_length"]:
        out["tour_seed_spread_max"] = max(spreads["tour_length"])
    return out


def _coverage_measures(
    ok: Any, previous: Mapping[tuple[str, int, float, int], float] | None
) -> dict[str, Any]:
    """The coverage planner's smooth path over its straight tour, the study's own coverage check, and
    the comparison with an earlier run's distances on the same trials."""
    out: dict[str, Any] = {}
    if "tour_length" in ok:
        ratio = [d / t for d, t in zip(ok["distance"], ok["tour_length"], strict=True) if t and t > 0]
        out["mean_tour_length"] = summarise(ok["tour_length"])["mean"]
        out["mean_smooth_over_straight"] = summarise(ratio)["mean"]
        out["max_smooth_over_straight"] = summarise(ratio)["max"]
    if "covered" in ok:
        covered = [v for v in ok["covered"] if v is not None and math.isfinite(v)]
        out["min_covered"] = min(covered) if covered else float("nan")
        out["fully_covered"] = sum(1 for v in covered if v == 1.0)
        out["max_gap"] = summarise(ok["worst_gap"])["max"]
    if previous:
        now, before = [], []
        for _, r in ok.iterrows():
            key = (str(r["kind"]), int(r["seed"]), float(r["radius"]), int(r["horizon"]))
            if key in previous:
                now.append(float(r["distance"]))
                before.append(previous[key])
        change = [a / b - 1 for a, b in zip(now, before, strict=True)]
        longer = [c for c in change if c > LONGER]
        out["previous"] = {
            "trials": len(change),
            "mean_distance_before": summarise(before)["mean"],
            "mean_distance_now": summarise(now)["mean"],
            "longer": len(longer),
            "max_longer": max(longer) if longer else 0.0,
            "mean_change": summarise(change)["mean"],
            "best_change": min(change) if change else float("nan"),
        }
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
    (
        "smooth / straight",
        lambda s: f"{s['mean_smooth_over_straight']:.4f}" if "mean_smooth_over_straight" in s else "",
    ),
    ("covered (own check)", lambda s: f"{s['fully_covered']}/{s['trials']}" if "fully_covered" in s else ""),
    (
        "plan-seed spread max",
        lambda s: f"{100 * s['seed_spread_max']:.2f}%" if "seed_spread_max" in s else "",
    ),
    ("vs previous: longer (max)", lambda s: _previous_cell(s.get("previous"))),
)


def _previous_cell(p: Mapping[str, Any] | None) -> str:
    if not p or not p["trials"]:
        return ""
    return (
        f"{p['longer']}/{p['trials']} ({100 * p['max_longer']:+.2f}%), mean {100 * p['mean_change']:+.2f}%, "
        f"{p['mean_distance_before']:.2f} -> {p['mean_distance_now']:.2f}"
    )


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    return markdown_table(COLUMNS, table)


def main(run: RunOptions, options: Options) -> list[Path]:
    """Run the study into ``run.out``: ``coverage.jsonl``, the summary, the table and one figure per
    scenario."""
    from studies.coverage_figures import write_figures

    if options.previous and Path(options.previous).resolve() == TABLE.path(run.out).resolve():
        raise ConfigError("--previous: the earlier run's file cannot be this run's results file (--out).")
    previous = previous_distances(options.previous) if options.previous else None
    out, rows = run.run_trials(TABLE, params(options))
    first = options.plan_seeds[0]
    table = summary(rows, options.radii, plan_seed=first, previous=previous)
    written = run.publish(TABLE, out, table, markdown(table), rows=rows)
    return [*written, *write_figures([r for r in rows if r["plan_seed"] == first], options.radii, out)]


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("coverage", __file__)
