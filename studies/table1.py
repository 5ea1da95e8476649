"""Study 1: the paper's Table 1 and Figures 1-5, with what the paper lacked.

Every trial is one (scenario, seed, method). The methods:

``ga``
    The paper's GA-TSP (Kirk's operators, ``operators="kirk"``; population 80, 5000 iterations):
    straight legs between locales.
``ga-smoothed``
    GA-TSP PMHT smoothed: that GA's tour as hard ordered visit constraints (radius 0.1).
``ga-improved``
    The project's default GA (segment move, route exchange, restarts; ``operators="improved"``).
``ortools``
    The OR-Tools ordering (greedy descent from the cheapest-arc start: deterministic; guided local
    search for 2 s gave the same tours on the scenarios tried).
``ortools-smoothed``
    The OR-Tools tour, smoothed like ``ga-smoothed``.
``pmht``
    PMHT with the project's default configuration (annealed EM, uniform time prior).
``pmht-paper``
    PMHT exactly as the paper states it (:meth:`PMHTConfig.paper`: no annealing, both prior updates).
``pmht-visitall``
    The default PMHT with :class:`~pmht_opt.constraints.VisitAll` (radius 0.1): every locale visited.

CPU time is the worker process's CPU time for the method (one thread per worker); a smoothed plan's
time includes the ordering it smooths, as in the paper.

    pmht-opt study table1 --trials 100 --workers 2 --out studies/results/table1
    python studies/table1.py [--trials 100] [--workers 2]
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError
from pmht_opt.ordering import TourResult
from pmht_opt.planners.pmht import plan_pmht
from pmht_opt.result import PlanResult, excursion
from pmht_opt.scenario import Scenario, paper_scenario
from pmht_opt.settings import PMHTConfig
from studies.options import Choices, Count, RunOptions, StudyOptions, Without, option
from studies.report import EXCURSION_LIMIT, Columns, frame, markdown_table, summarise
from studies.trials import CONSTRAINED, ROUNDED_PATHS, TIME_CHECKS, TIME_COLUMNS, TrialTable

#: The coverage radius the table reports (the scenarios' default sensor footprint).
DEFAULT_RADIUS = 0.3

METHODS: dict[str, str] = {
    "ga": "GA-TSP",
    "ga-smoothed": "GA-TSP PMHT smoothed",
    "ga-improved": "GA-TSP (improved operators)",
    "pmht-paper": "PMHT (paper's settings)",
    "pmht": "PMHT (default: annealed)",
    "pmht-visitall": "PMHT + VisitAll(0.1)",
    "ortools": "OR-Tools ordering",
    "ortools-smoothed": "OR-Tools PMHT smoothed",
}
#: Table 1 of the paper (docs/model.md section 12): distance and CPU seconds per scenario and algorithm.
PAPER: dict[str, dict[str, tuple[float, float]]] = {
    "A": {"ga": (117.8, 18.3), "ga-smoothed": (124.6, 39.4), "pmht": (94.6, 23.1)},
    "B": {"ga": (118.8, 17.4), "ga-smoothed": (93.8, 33.3), "pmht": (77.8, 16.7)},
    "C": {"ga": (87.8, 18.0), "ga-smoothed": (92.8, 38.9), "pmht": (78.8, 22.8)},
}
PAPER_COLUMN = {"ga": "ga", "ga-smoothed": "ga-smoothed", "pmht-paper": "pmht", "pmht": "pmht"}
VISIT_RADIUS = 0.1
AREA = (0.0, 10.0, 0.0, 10.0)
FIGURE_SEED = 0
KINDS = ("A", "B", "C")
HORIZON = 500


def _order(sc: Scenario, method: str, seed: int) -> TourResult:
    from pmht_opt.ordering import solve_ga_tsp, solve_ortools

    if method.startswith("ga"):
        return solve_ga_tsp(sc, seed=seed, operators="improved" if method == "ga-improved" else "kirk")
    return solve_ortools(sc, time_limit=60.0, metaheuristic="GREEDY_DESCENT")


def _plan(sc: Scenario, method: str, seed: int, snapshots: tuple[int, ...] = ()) -> PlanResult | TourResult:
    """The plan (``PlanResult``) or tour (``TourResult``) of ``method`` on ``sc``."""
    from pmht_opt.constraints import VisitAll
    from pmht_opt.planners.smoothed import plan_smoothed

    if method in {"ga", "ga-improved", "ortools"}:
        return _order(sc, method, seed)
    if method in ("ga-smoothed", "ortools-smoothed"):
        return plan_smoothed(sc, _order(sc, method, seed), PMHTConfig(threads=1), VISIT_RADIUS)
    if method == "pmht":
        return plan_pmht(sc, PMHTConfig(threads=1, snapshots=snapshots))
    if method == "pmht-paper":
        return plan_pmht(sc, PMHTConfig.paper(threads=1, snapshots=snapshots))
    if method == "pmht-visitall":
        return plan_pmht(sc, PMHTConfig(threads=1, constraints=[VisitAll(VISIT_RADIUS)]))
    raise ConfigError(f"method: expected one of {', '.join(METHODS)}, got {method!r}.")


def trial(kind: str, seed: int, method: str, horizon: int) -> dict[str, Any]:
    """One method on one seeded paper scenario: distance, coverage, excursion, CPU and wall time.

    The trial of seed :data:`FIGURE_SEED` also returns its paths (and, for PMHT, the paths after
    iterations 5 and 20), rounded to 1e-3, for the figures.
    """
    sc = paper_scenario(kind, seed=seed, horizon=horizon)
    figure = seed == FIGURE_SEED
    cpu, wall = time.process_time(), time.perf_counter()
    out = _plan(sc, method, seed, snapshots=(5, 20) if figure and method.startswith("pmht") else ())
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    row: dict[str, Any]
    if isinstance(out, TourResult):
        lines = [np.vstack([sc.start_positions[m : m + 1], sc.locales[r]]) for m, r in enumerate(out.routes)]
        row = {
            "distance": float(out.total_distance),
            "coverage": 1.0,
            "excursion": excursion(np.vstack(lines), sc.bounds or AREA),
            "locales_per_platform": [len(r) for r in out.routes],
        }
    else:
        m = out.metrics()
        lines = list(out.positions)
        row = {
            "distance": m["total_distance"],
            "coverage": m["coverage"],
            "excursion": m["max_excursion"],
            "locales_per_platform": m["locales_per_platform"],
        }
    row.update(cpu=cpu, wall=wall)
    if figure:
        row["paths"] = [_rounded(line) for line in lines]
        snapshots = out.snapshots if isinstance(out, PlanResult) else {}
        for it, pos in snapshots.items():
            row[f"paths_{it}"] = [_rounded(line) for line in pos]
    return row


#: What a trial records: the plan's (or tour's) measures, its times and, for the figures' seed, its paths.
RESULTS = {
    "distance": "float",
    "coverage": "float",
    "excursion": "float",
    "locales_per_platform": "list",
    **TIME_COLUMNS,
    "paths": "list?",
    "paths_5": "list?",
    "paths_20": "list?",
}
TABLE = TrialTable.of(
    "table1",
    trial,
    RESULTS,
    {
        **TIME_CHECKS,
        "distance": CONSTRAINED,
        "excursion": CONSTRAINED,
        **dict.fromkeys(("paths", "paths_5", "paths_20"), ROUNDED_PATHS),
    },
)


def _rounded(line: np.ndarray) -> list[list[float]]:
    return np.round(np.asarray(line, dtype=float), 3).tolist()


# ------------------------------------------------------------------ tables


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, method): distance, CPU, coverage statistics and the paper's figures."""
    df = frame(rows)
    out = []
    for kind in KINDS:
        for method in METHODS:
            mine = df[(df["kind"] == kind) & (df["method"] == method)]
            if mine.empty:
                continue
            ok = mine[mine["error"] == ""]
            dist = summarise(ok["distance"]) if len(ok) else summarise([])
            paper = PAPER[kind].get(PAPER_COLUMN.get(method, ""), (float("nan"), float("nan")))
            out.append(
                {
                    "scenario": kind,
                    "method": method,
                    "trials": len(ok),
                    "failed": len(mine) - len(ok),
                    "mean_distance": dist["mean"],
                    "median_distance": dist["median"],
                    "max_distance": dist["max"],
                    "sd_distance": float(np.std(ok["distance"].astype(float))) if len(ok) else float("nan"),
                    "paper_distance": paper[0],
                    "mean_cpu": summarise(ok["cpu"])["mean"] if len(ok) else float("nan"),
                    "paper_cpu": paper[1],
                    "mean_coverage": summarise(ok["coverage"])["mean"] if len(ok) else float("nan"),
                    "left_area": int((ok["excursion"].astype(float) > EXCURSION_LIMIT + 1e-9).sum())
                    if len(ok)
                    else 0,
                }
            )
    return out


def _num(x: float, fmt: str) -> str:
    return "—" if not np.isfinite(x) else format(x, fmt)


#: Table 1 side by side with the paper's numbers, plus the columns the paper lacked.
COLUMNS: Columns = (
    ("scenario", lambda s: s["scenario"]),
    ("method", lambda s: METHODS[s["method"]]),
    ("trials", lambda s: f"{s['trials']}" + (f" ({s['failed']} failed)" if s["failed"] else "")),
    ("distance: mean (sd)", lambda s: f"{_num(s['mean_distance'], '.1f')} ({_num(s['sd_distance'], '.1f')})"),
    ("median", lambda s: _num(s["median_distance"], ".1f")),
    ("max", lambda s: _num(s["max_distance"], ".1f")),
    ("paper", lambda s: _num(s["paper_distance"], ".1f")),
    ("CPU s: mean", lambda s: _num(s["mean_cpu"], ".2f")),
    ("paper", lambda s: _num(s["paper_cpu"], ".1f")),
    (f"coverage at {DEFAULT_RADIUS}", lambda s: _num(s["mean_coverage"], ".3f")),
    ("runs leaving area by > 1", lambda s: s["left_area"]),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Table 1 side by side with the paper's numbers, plus the columns the paper lacked."""
    return markdown_table(COLUMNS, table)


# ------------------------------------------------------------------ figures


def _paths(
    rows: Sequence[Mapping[str, Any]], kind: str, method: str, key: str = "paths"
) -> tuple[list[np.ndarray], Mapping[str, Any]] | tuple[None, None]:
    for r in rows:
        if r["kind"] == kind and r["method"] == method and r["seed"] == FIGURE_SEED and r.get(key):
            return [np.asarray(line) for line in r[key]], r
    return None, None


def figures(out_dir: Path, rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> list[Path]:
    """Figure 1 (PMHT paths at iterations 5, 20 and the last), Figures 2-4 (every method on the
    seed-0 trial of A, B, C) and Figure 5 (histogram of locales per platform), from the trials' rows."""
    from pmht_opt.plotting import draw_paths, pyplot

    plt = pyplot()
    written = []
    sc = paper_scenario("A", seed=FIGURE_SEED)
    panels = [
        (m, name) for m, name in (("pmht-paper", "paper's settings"), ("pmht", "default")) if m in methods
    ]
    if panels:
        fig, axes = plt.subplots(len(panels), 3, figsize=(13, 4.3 * len(panels)), squeeze=False)
        for row, (method, name) in enumerate(panels):
            for col, key in enumerate(("paths_5", "paths_20", "paths")):
                lines, _ = _paths(rows, "A", method, key)
                label = {"paths_5": "iteration 5", "paths_20": "iteration 20", "paths": "last iteration"}[key]
                if lines is None:
                    axes[row, col].set_visible(False)
                    continue
                draw_paths(axes[row, col], sc, lines, title=f"PMHT, {name}: {label}")
        fig.suptitle(f"Figure 1: scenario A (seed {FIGURE_SEED}), paths during the EM")
        fig.tight_layout()
        written.append(_save(fig, out_dir / "figure1_iterations.png", plt))
    for number, kind in zip((2, 3, 4), ("A", "B", "C"), strict=True):
        sc = paper_scenario(kind, seed=FIGURE_SEED)
        shown = [(m, *_paths(rows, kind, m)) for m in methods]
        shown = [(m, lines, r) for m, lines, r in shown if lines is not None]
        if not shown:
            continue
        cols = min(4, len(shown))
        nrows = -(-len(shown) // cols)
        fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 4.4 * nrows), squeeze=False)
        for ax, (method, lines, r) in zip(axes.ravel(), shown, strict=False):
            draw_paths(ax, sc, lines, title=f"{METHODS[method]}: {r['distance']:.1f}")
        for ax in axes.ravel()[len(shown) :]:
            ax.set_visible(False)
        fig.suptitle(f"Figure {number}: scenario {kind} (seed {FIGURE_SEED}); titles give total distance")
        fig.tight_layout()
        written.append(_save(fig, out_dir / f"figure{number}_scenario_{kind}.png", plt))
    hist_methods = [m for m in ("pmht-paper", "pmht", "ga") if m in methods]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for ax, kind in zip(axes, ("A", "B", "C"), strict=True):
        for method in hist_methods:
            counts = [
                c
                for r in rows
                if r["kind"] == kind and r["method"] == method and not r.get("error")
                for c in r["locales_per_platform"]
            ]
            if counts:
                ax.hist(counts, bins=np.arange(0, 101, 4), histtype="step", lw=1.5, label=METHODS[method])
        ax.set_title(f"scenario {kind}")
        ax.set_xlabel("locales per platform")
        ax.set_ylabel("platforms (all trials)")
        ax.legend(fontsize=7)
    fig.suptitle("Figure 5: locales assigned per platform")
    fig.tight_layout()
    written.append(_save(fig, out_dir / "figure5_locales_per_platform.png", plt))
    return written


def _save(fig: Any, path: Path, plt: Any) -> Path:
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ entry points


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study table1``."""

    trials: int = option(100, Count("--trials", "trials (seeds) per scenario (default 100)"))
    methods: tuple[str, ...] = option(tuple(METHODS), Choices("--methods", known=tuple(METHODS)))
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))
    horizon: int = option(HORIZON, Count("--horizon", "time steps (default: the paper's 500)", minimum=2))
    figures: bool = option(True, Without("--no-figures", "skip the figures"))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run, seed-major, so a run stopped part-way has covered every scenario and method
    evenly."""
    return [
        {"kind": k, "seed": s, "method": m, "horizon": options.horizon}
        for s in range(options.trials)
        for k in options.kinds
        for m in options.methods
    ]


def main(run: RunOptions, options: Options) -> list[Path]:
    """Run the study into ``run.out``: ``table1.jsonl`` (one row per trial), ``table1.md``,
    ``table1_summary.json`` and the figures; return the paths written."""
    out, rows = run.run_trials(TABLE, params(options))
    table = summary(rows)
    n = options.trials
    header = f"Table 1 over {n} trials per scenario (seeds 0..{n - 1}); the paper: 100 trials.\n\n"
    written = run.publish(TABLE, out, table, markdown(table), header, rows=rows)
    if options.figures:
        written += figures(out, rows, list(options.methods))
    return written


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("table1", __file__)
