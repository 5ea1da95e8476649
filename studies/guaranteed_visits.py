"""Study: guaranteed visits on the paper's scenarios. Do they always solve, and do the plans stay home?

Each trial plans one Table 1 scenario (A, B or C, one seed) with ``VisitAll(radius)`` on a backend
(clarabel by default) and the planner's default configuration, and records the outcome (a plan, or the
error's class), the time, the coverage at the visit radius (measured on the segments), the total
distance, and how far the plan leaves the area beyond its starts: ``excursion - start excursion``,
which the constraint keeps at or below its ``keep_within`` (0.5).

    pmht-opt study guaranteed_visits --workers 2 --out studies/results/guaranteed_visits
    python studies/guaranteed_visits.py [--trials 100] [--radii 0.1 0.3]
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import pmht_opt as po
from pmht_opt.result import excursion
from studies.options import Choices, Count, Positives, StudyOptions, option
from studies.report import Columns, frame, markdown_table
from studies.trials import CONSTRAINED, ERROR_COLUMNS, OUTCOME_CHECKS, TrialTable

KINDS = ("A", "B", "C")
BACKENDS = ("clarabel", "osqp", "cvxpy")


def trial(kind: str, seed: int, radius: float, backend: str) -> dict[str, Any]:
    """One plan with guaranteed visits; the outcome and what a user would check on it."""
    sc = po.paper_scenario(kind, seed=seed)
    assert sc.bounds is not None
    cfg = po.PMHTConfig(solver=backend, constraints=[po.VisitAll(radius)], threads=1)
    t0 = time.perf_counter()
    row: dict[str, Any] = {"raised": None, "message": None, "coverage": None, "distance": None}
    row["extra_excursion"] = None
    try:
        res = po.plan_pmht(sc, cfg)
    except po.PmhtOptError as err:
        row.update(outcome="error", raised=type(err).__name__, message=str(err)[:300])
    else:
        row.update(
            outcome="plan",
            coverage=res.coverage(radius),
            distance=res.total_distance,
            extra_excursion=res.max_excursion() - excursion(sc.start_positions, sc.bounds),
            fallbacks=int(np.sum(res.history.fallbacks)),
        )
    row.setdefault("fallbacks", None)
    row["seconds"] = time.perf_counter() - t0
    return row


#: What a trial records: its outcome (a plan, or the error), the plan's measures and the time it took.
RESULTS = {
    "outcome": "str",
    **ERROR_COLUMNS,
    "coverage": "float?",
    "distance": "float?",
    "extra_excursion": "float?",
    "fallbacks": "int?",
    "seconds": "float",
}
TABLE = TrialTable.of(
    "guaranteed_visits",
    trial,
    RESULTS,
    {**OUTCOME_CHECKS, "distance": CONSTRAINED, "extra_excursion": CONSTRAINED},
)


def summary(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per scenario, radius and backend: plans, errors, full coverage, excursions, time."""
    df = frame(rows)
    df = df[df["error"] == ""]
    out = []
    for (kind, radius, backend), g in df.groupby(["kind", "radius", "backend"]):
        plans = g[g["outcome"] == "plan"]
        out.append(
            {
                "scenario": kind,
                "radius": float(radius),
                "backend": backend,
                "trials": len(g),
                "errors": int((g["outcome"] != "plan").sum()),
                "error_classes": ", ".join(sorted(set(g["raised"].dropna()))),
                "full_coverage": int((plans["coverage"] >= 1.0).sum()),
                "over_half_unit_out": int((plans["extra_excursion"] > 0.5 + 1e-9).sum()),
                "over_one_unit_out": int((plans["extra_excursion"] > 1.0).sum()),
                "max_extra_excursion": float(plans["extra_excursion"].max()) if len(plans) else 0.0,
                "mean_distance": float(plans["distance"].mean()) if len(plans) else 0.0,
                "mean_seconds": float(g["seconds"].mean()),
                "median_seconds": float(g["seconds"].median()),
            }
        )
    return out


#: The summary's markdown table.
COLUMNS: Columns = (
    ("scenario", lambda s: s["scenario"]),
    ("radius", lambda s: f"{s['radius']:g}"),
    ("backend", lambda s: s["backend"]),
    ("trials", lambda s: s["trials"]),
    ("errors", lambda s: f"{s['errors']}" + (f" ({s['error_classes']})" if s["error_classes"] else "")),
    ("full coverage", lambda s: s["full_coverage"]),
    ("> 0.5 out", lambda s: s["over_half_unit_out"]),
    ("> 1 out", lambda s: s["over_one_unit_out"]),
    ("max out", lambda s: f"{s['max_extra_excursion']:.3f}"),
    ("mean distance", lambda s: f"{s['mean_distance']:.1f}"),
    ("mean s", lambda s: f"{s['mean_seconds']:.2f}"),
    ("median s", lambda s: f"{s['median_seconds']:.2f}"),
)


def markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """The summary as a markdown table."""
    return markdown_table(COLUMNS, table)


@dataclass(frozen=True)
class Options(StudyOptions):
    """Options of ``pmht-opt study guaranteed_visits``."""

    trials: int = option(100, Count("--trials", "seeds per scenario and radius"))
    radii: tuple[float, ...] = option((0.1, 0.3), Positives("--radii", "visit radii"))
    kinds: tuple[str, ...] = option(KINDS, Choices("--kinds", "scenarios", known=KINDS))
    backends: tuple[str, ...] = option(("clarabel",), Choices("--backends", known=BACKENDS))


def params(options: Options) -> list[dict[str, Any]]:
    """The trials of a run."""
    return [
        {"kind": k, "seed": s, "radius": float(r), "backend": b}
        for b in options.backends
        for r in options.radii
        for k in options.kinds
        for s in range(options.trials)
    ]


if __name__ == "__main__":
    from studies.cli import run_script

    run_script("guaranteed_visits", __file__)
