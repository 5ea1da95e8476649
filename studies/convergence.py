"""Study: when can the EM stop? A stopping rule on the assignment and the paths, chosen by measurement.

Every trial runs the planner's full 100 iterations and records, after each iteration, the signals a
stopping rule can use (the largest position change, whether any locale changed platform, whether the
run is in its final regime) and what a user cares about (total distance and coverage at the scenario's
radius). The analysis then replays candidate rules :class:`pmht_opt.Converged` (``path_rtol``,
``stable``) on the recorded runs: for each, the iteration it would stop at and how far the distance and
coverage there are from those after 100 iterations. The rule adopted as the default is the one that
stops soonest while changing nothing a user cares about (docs/decisions.md).

    pmht-opt study convergence --workers 2 --out studies/results/convergence
    python studies/convergence.py [--trials 100] [--configs default visitall-0.3]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.constraints import VisitAll
from pmht_opt.em import EMCallbacks, EMRun, IterationRecord
from pmht_opt.geometry import point_polyline_distance
from pmht_opt.model import POS
from pmht_opt.ordering import order_locales
from pmht_opt.planners.smoothed import plan_smoothed
from pmht_opt.scenario import paper_scenario
from pmht_opt.settings import PMHTConfig
from studies.options import Choices, Count, StudyOptions, option
from studies.report import Columns, frame, markdown_table
from studies.trials import Check, TrialTable

KINDS = ("A", "B", "C")
CONFIGS = ("default", "visitall-0.3", "smoothed-0.3")
#: Candidate rules replayed on the recorded runs: ``(path_rtol, stable)``.
CANDIDATES = tuple((tol, k) for tol in (3e-3, 1e-3, 3e-4, 1e-4, 1e-5) for k in (3, 5, 10))


def _config(name: str) -> PMHTConfig:
    constraints = [VisitAll(0.3)] if name == "visitall-0.3" else []
    return PMHTConfig(max_iter=100, threads=1, constraints=constraints)


def trial(kind: str, seed: int, config: str) -> dict[str, Any]:
    """One 100-iteration plan, with the stopping signals and the metrics after every iteration."""
    sc = paper_scenario(kind, seed=seed)
    cfg = _config(config)
    signals: dict[str, list[Any]] = {
        "path_change": [],
        "changed": [],
        "settled": [],
        "distance": [],
        "coverage": [],
    }

    def after(run: EMRun, rec: IterationRecord) -> None:
        pos = run.states[:, :, POS]
        seg = np.diff(pos, axis=1)
        miss = np.min([point_polyline_distance(sc.locales, pos[m]) for m in range(pos.shape[0])], axis=0)
        signals["path_change"].append(rec.path_change)
        signals["changed"].append(rec.assignment_changed)
        signals["settled"].append(run.schedule.settled_at(cfg.constraints, rec.iteration))
        signals["distance"].append(float(np.hypot(seg[..., 0], seg[..., 1]).sum()))
        signals["coverage"].append(float(np.mean(miss <= sc.coverage_radius * (1 + 1e-6))))

    callbacks = EMCallbacks(after_iteration=after)
    if config == "smoothed-0.3":
        tour = order_locales(sc, "pyvrp", seed=seed)
        plan_smoothed(
            sc,
            tour,
            PMHTConfig(max_iter=100, threads=1),
            visit_radius=0.3,
            callbacks=callbacks,
            converge=None,
        )
    else:
        with EMRun(sc, cfg, callbacks=callbacks) as run:
            run.run()
    return {**signals, "scale": 10.0}


#: What a trial records: each signal after every iteration, and the length its path changes are judged
#: against.
RESULTS = {
    "path_change": "list",
    "changed": "list",
    "settled": "list",
    "distance": "list",
    "coverage": "list",
    "scale": "float",
}
TABLE = TrialTable.of(
    "convergence",
    trial,
    RESULTS,
    {"path_change": Check("close", rtol=1e-6, atol=1e-9, reason="last-digit differences of the solver")},
)


def stop_iteration(row: Mapping[str, Any], path_rtol: float, stable: int) -> int:
    """The iteration (1-based) at which :class:`pmht_opt.Converged` would stop this recorded run."""
    age = 0
    for i, (change, changed, settled) in enumerate(
        zip(row["path_change"], row["changed"], row["settled"], strict=True)
    ):
        age = 0 if changed else age + 1
        if settled and age >= stable and change <= path_rtol * row["scale"]:
            return i + 1
    return len(row["path_change"])


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per (scenario, configuration, candidate rule): iterations saved and what changes against 100."""
    df = frame(rows)
    df = df[df["error"] == ""]
    out = []
    for (kind, config), group in df.groupby(["kind", "config"]):
        recs = group.to_dict("records")
        for tol, k in CANDIDATES:
            stops = np.array([stop_iteration(r, tol, k) for r in recs])
            d_rel = np.array(
                [
                    abs(r["distance"][s - 1] - r["distance"][-1]) / r["distance"][-1]
                    for r, s in zip(recs, stops, strict=True)
                ]
            )
            d_cov = np.array(
                [r["coverage"][s - 1] - r["coverage"][-1] for r, s in zip(recs, stops, strict=True)]
            )
            out.append(
                {
                    "scenario": kind,
                    "config": config,
                    "path_rtol": tol,
                    "stable": k,
                    "trials": len(recs),
                    "mean_iterations": float(stops.mean()),
                    "max_iterations": int(stops.max()),
                    "mean_rel_distance_change": float(d_rel.mean()),
                    "max_rel_distance_change": float(d_rel.max()),
                    "max_coverage_change": float(np.abs(d_cov).max()),
                    "trials_coverage_changed": int(np.sum(d_cov != 0)),
                }
            )
    return out


#: The replay's markdown table.
COLUMNS: Columns = (
    ("scenario", lambda s: s["scenario"]),
    ("configuration", lambda s: s["config"]),
    ("path_rtol", lambda s: f"{s['path_rtol']:g}"),
    ("stable", lambda s: s["stable"]),
    ("mean iterations", lambda s: f"{s['mean_iterations']:.1f}"),
    ("max", lambda s: s["max_iterations"]),
    ("mean rel. distance change", lambda s: f"{s['mean_rel_distance_change']:.2e}"),
    ("max", lambda s: f"{s['max_rel_distance_change']:.2e}"),
    ("max coverage change", lambda s: f"{s['max_coverage_change']:.3f}"),
    ("trials with coverage changed", lambda s: s["trials_coverage_changed"]),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The replay as a markdown table."""
    return markdown_table(COLUMNS, table)


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study convergence``."""

    trials: int = option(100, Count("--trials", "trials per scenario and configuration"))
    configs: tuple[str, ...] = option(CONFIGS, Choices("--configs", known=CONFIGS))
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run."""
    return [
        {"kind": k, "seed": s, "config": c}
        for c in options.configs
        for k in options.kinds
        for s in range(options.trials)
    ]


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("convergence", __file__)
