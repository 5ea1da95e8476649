"""The solver study's summaries: per backend (and case), counts by class, times, worst gaps.

Summaries take the worst case over scenarios for gaps and differences (a backend is as good as its
worst M-step) and medians for times (one slow solve on a busy machine says little).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from studies.report import finite, median, summarise
from studies.solver_study.backends import STATUS_INACCURATE, STATUS_OK, STATUS_ORDER

Rows = Sequence[Mapping[str, Any]]

#: Longest note kept in a table cell.
NOTE_WIDTH = 90


def group(rows: Rows, keys: Sequence[str]) -> dict[tuple[Any, ...], list[Mapping[str, Any]]]:
    """``rows`` by the values of ``keys``, in order of first appearance."""
    out: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return out


def max_abs(values: Sequence[Any]) -> float:
    """Largest absolute value among the finite ``values``; NaN when there are none."""
    vals = finite(values)
    return max(abs(v) for v in vals) if vals else math.nan


def statuses(rows: Rows) -> str:
    """Counts by class, e.g. ``"optimal 2, n/a 1"``."""
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    return ", ".join(f"{k} {counts[k]}" for k in STATUS_ORDER if k in counts)


def why(rows: Rows) -> str:
    """The distinct raw statuses / messages of rows that are not optimal (shortened), with the EM
    iterations at which plans stopped."""
    seen: dict[str, list[int]] = {}
    for r in rows:
        if r["status"] == STATUS_OK:
            continue
        text = r.get("raw_status") or r.get("message") or ""
        text = str(text).replace("|", "/").replace("\n", " ")
        if len(text) > NOTE_WIDTH:
            text = text[: NOTE_WIDTH - 3] + "..."
        if text:
            at = seen.setdefault(text, [])
            if r.get("failed_at") is not None:
                at.append(int(r["failed_at"]))
        elif r["status"] == STATUS_INACCURATE:
            seen.setdefault("inaccurate", [])
    parts = []
    for text, at in seen.items():
        where = f" (at EM iteration {', '.join(str(i) for i in sorted(set(at)))})" if at else ""
        parts.append(text + where)
    return "; ".join(parts)


def summarise_msteps(rows: Rows) -> list[dict[str, Any]]:
    """Per (part, case group, backend): times, iterations, worst gaps and differences."""
    out = []
    for (part, case, backend), mine in group(rows, ("part", "group", "backend")).items():
        good = [r for r in mine if r["status"] in (STATUS_OK, STATUS_INACCURATE)]
        entry: dict[str, Any] = {
            "part": part,
            "case": case,
            "backend": backend,
            "cases": len(mine),
            "statuses": statuses(mine),
            "why": why(mine),
            "median_time_s": median([r["time_s"] for r in good]),
            "max_time_s": max(finite([r["time_s"] for r in good]), default=math.nan),
            "median_first_solve_s": median([r["first_solve_s"] for r in good]),
            "median_iterations": median([r["iterations"] for r in good]),
            "max_abs_objective_gap": max_abs([r["objective_gap"] for r in good]),
            "max_pos_diff": max_abs([r["max_pos_diff"] for r in good]),
        }
        if part == "constrained":
            entry["max_violation"] = max_abs([r.get("max_violation") for r in good])
            entry["max_abs_objective_gap_same"] = max_abs([r.get("objective_gap_same") for r in good])
            entry["max_pos_diff_same"] = max_abs([r.get("max_pos_diff_same") for r in good])
        out.append(entry)
    return out


def summarise_plans(rows: Rows) -> list[dict[str, Any]]:
    """Per backend: plans by class, median time, distances and differences to the kalman plan."""
    out = []
    for (backend,), mine in group(rows, ("backend",)).items():
        good = [r for r in mine if r.get("status") == STATUS_OK]
        diffs = summarise(finite([r.get("max_pos_diff") for r in good]))
        out.append(
            {
                "backend": backend,
                "plans": len(mine),
                "scenarios": " ".join(sorted({f"{r['kind']}{r['seed']}" for r in mine})),
                "statuses": statuses(mine),
                "why": why(mine),
                "median_wall_time_s": median([r.get("wall_time") for r in good]),
                "median_mstep_time_s": median([r.get("mstep_time") for r in good]),
                "mean_distance": summarise(finite([r.get("total_distance") for r in good]))["mean"],
                "kalman_mean_distance": summarise(finite([r.get("kalman_distance") for r in good]))["mean"],
                "max_abs_distance_rel_diff": max_abs([r.get("distance_rel_diff") for r in good]),
                "median_max_pos_diff": diffs["median"],
                "max_max_pos_diff": diffs["max"],
                "mean_solver_iterations": median([r.get("mean_solver_iterations") for r in good]),
            }
        )
    return out
