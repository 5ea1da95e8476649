"""The scaling study's summary: medians over repeats, log-log slopes per sweep, the target's verdict.

Times are medians over the repeats (one slow run on a busy machine says little). A sweep's slope is
the least-squares slope of log time (and of log memory above the child's baseline) against log size,
so 1 is linear growth in that size.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from studies.provenance import load_average
from studies.report import median
from studies.scaling_study.design import (
    FULL,
    GATES,
    SCALE_GIB,
    SCALE_SECONDS,
    TARGET_GIB,
    TARGET_SECONDS,
    Design,
)

Rows = Sequence[Mapping[str, Any]]

#: Columns of a trial row that describe the trial, not the agreement measured.
_NOT_AGREEMENT = ("task", "gate", "rep", "trial", "error", "error_class", "run")


def ok(rows: Rows) -> list[Mapping[str, Any]]:
    """The rows of trials that did not raise."""
    return [r for r in rows if not r.get("error")]


def select(rows: Rows, **match: Any) -> list[Mapping[str, Any]]:
    """The rows of finished trials whose columns equal ``match``."""
    return [r for r in ok(rows) if all(r[k] == v for k, v in match.items())]


def _median(rows: Rows, key: str) -> float:
    """Median of column ``key`` over ``rows``."""
    return median(r[key] for r in rows)


def summarise_point(rows: Rows) -> dict[str, Any]:
    """Medians over the repeats of one (size, solver, gate)."""
    return {
        "runs": len(rows),
        "wall_s": _median(rows, "wall_s"),
        "wall_s_all": [float(r["wall_s"]) for r in rows],
        "estep_s": _median(rows, "estep_s"),
        "estep_settled_s": _median(rows, "estep_settled_s"),
        "mstep_s": _median(rows, "mstep_s"),
        "estep_calls": _median(rows, "estep_calls"),
        "estep_gated_calls": _median(rows, "estep_gated_calls"),
        "peak_rss_mib": _median(rows, "peak_rss_mib"),
        "base_rss_mib": _median(rows, "base_rss_mib"),
    }


def fit_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of ``log y`` against ``log x`` (NaN with fewer than two usable points)."""
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    usable = np.isfinite(xa) & np.isfinite(ya) & (xa > 0) & (ya > 0)
    if np.sum(usable) < 2 or np.ptp(np.log(xa[usable])) == 0:
        return math.nan
    return float(np.polyfit(np.log(xa[usable]), np.log(ya[usable]), 1)[0])


def summarise_sweeps(rows: Rows, sweeps: Mapping[str, Sequence[tuple[int, int, int]]]) -> dict[str, Any]:
    """Per sweep: its points and, gated and dense, the medians at each point and both slopes."""
    out: dict[str, Any] = {}
    for axis, pts in sweeps.items():
        idx = "NTM".index(axis)
        entry: dict[str, Any] = {"points": [list(p) for p in pts]}
        xs = [p[idx] for p in pts]
        for g in GATES:
            stats = [
                summarise_point(select(rows, n_locales=a, horizon=b, n_platforms=c, gate=g))
                for a, b, c in pts
            ]
            entry[g] = {
                "stats": stats,
                "time_slope": fit_slope(xs, [s["wall_s"] for s in stats]),
                "memory_slope": fit_slope(xs, [s["peak_rss_mib"] - s["base_rss_mib"] for s in stats]),
            }
        out[axis] = entry
    return out


def agreement_rows(rows: Rows) -> list[dict[str, Any]]:
    """The agreement trials' rows without the columns that only describe the trial."""
    return [{k: v for k, v in r.items() if k not in _NOT_AGREEMENT} for r in ok(rows)]


def target(design: Design, headline: Mapping[str, Any]) -> dict[str, Any]:
    """The target and whether the gated headline met it; ``met`` is ``None`` unless the design's
    headline is the target's problem (the full study's)."""
    gated = headline["auto"]
    met = None
    if (design.headline, design.iterations) == (FULL.headline, FULL.iterations):
        met = bool(
            gated["runs"] > 0
            and gated["wall_s"] <= TARGET_SECONDS
            and gated["peak_rss_mib"] <= TARGET_GIB * 1024
        )
    return {"seconds": TARGET_SECONDS, "gib": TARGET_GIB, "met": met}


def scale_point(design: Design, rows: Rows) -> dict[str, Any]:
    """The scale point's plan (:attr:`Design.scale`) and its verdict against :data:`SCALE_SECONDS` and
    :data:`SCALE_GIB`; ``met`` is ``None`` unless it is the full study's point, or without a plan."""
    stats = summarise_point(ok(rows))
    met: bool | None = None
    if design.scale != FULL.scale or design.iterations != FULL.iterations:
        verdict = "not measured (not the target's size and iterations)"
    elif not stats["runs"]:
        verdict = "not measured (no plan finished)"
    else:
        met = bool(stats["wall_s"] <= SCALE_SECONDS and stats["peak_rss_mib"] <= SCALE_GIB * 1024)
        verdict = "met" if met else "NOT met"
    errors = [str(r.get("error")) for r in rows if r.get("error")]
    return {
        "size": list(design.scale),
        **stats,
        "errors": errors,
        "target": {"seconds": SCALE_SECONDS, "gib": SCALE_GIB, "met": met, "verdict": verdict},
    }


def design_info(design: Design, seed: int) -> dict[str, Any]:
    """The sizes, iterations, repeats, seed and planner configuration of a run, for its summary."""
    return {
        "headline": list(design.headline),
        "centre": list(design.centre),
        "scale": list(design.scale),
        "iterations": design.iterations,
        "reps": design.reps,
        "seed": seed,
        "config": "PMHTConfig defaults (annealed, platform prior re-estimated), threads = min(M, cores)",
    }


def machine(prov: Mapping[str, Any], load_start: float | None) -> dict[str, Any]:
    """The machine of a run: cores, platform, and the 1-minute load average before and now (other work
    on the machine skews the times)."""
    return {
        "cores": prov["cpu_count"],
        "platform": prov["platform"],
        "load_average_start": load_start,
        "load_average_end": load_average(),
    }
