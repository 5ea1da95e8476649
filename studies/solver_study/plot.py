"""The solver study's figure (``solvers.png``): time against position difference, one panel per part.

A backend keeps its colour and marker across the three panels, so the eye can follow it from single
M-steps to whole plans; inaccurate solves are hollow, and failed or not applicable ones are left out
(the tables list them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from studies.solver_study.backends import ACCEPT, STATUS_INACCURATE, STATUS_OK

Rows = Sequence[Mapping[str, Any]]

#: Zero differences are drawn at this height (log axes).
FLOOR = 1e-16

#: Colour and marker of the backends the study always has; others get spares.
STYLE: dict[str, tuple[str, str]] = {
    "kalman": ("black", "o"),
    "banded": ("tab:gray", "P"),
    "reference (cones)": ("black", "h"),
    "clarabel": ("tab:blue", "s"),
    "clarabel (polygons)": ("tab:blue", "*"),
    "osqp": ("tab:green", "D"),
    "cvxpy/CLARABEL": ("tab:red", "^"),
    "cvxpy/CLARABEL (tight)": ("tab:red", "v"),
    "cvxpy/CLARABEL" + ACCEPT: ("tab:red", "<"),
    "cvxpy/OSQP": ("tab:olive", ">"),
    "cvxpy/SCS": ("tab:purple", "p"),
}
_SPARE = [(c, m) for m in "XPd" for c in ("tab:orange", "tab:brown", "tab:pink", "tab:cyan", "tab:gray")]


def styles(labels: Sequence[str]) -> dict[str, tuple[str, str]]:
    """Colour and marker of every label: :data:`STYLE`, then spares in order."""
    style = dict(STYLE)
    for b in labels:
        if b not in style:
            style[b] = _SPARE[len(style) % len(_SPARE)]
    return style


def _panel(ax: Any, title: str, rows: Rows, tkey: str, style: Mapping[str, tuple[str, str]]) -> None:
    """One part's points: time against difference to that part's reference."""
    from matplotlib.ticker import NullFormatter

    shown = set()
    for r in rows:
        if r.get("status") not in (STATUS_OK, STATUS_INACCURATE):
            continue
        t, d = r.get(tkey), r.get("max_pos_diff")
        if t is None or d is None or not (math.isfinite(t) and math.isfinite(d)):
            continue
        b = str(r["backend"])
        color, marker = style[b]
        ax.scatter(
            t,
            max(d, FLOOR),
            color=color,
            marker=marker,
            s=36,
            alpha=0.8,
            facecolors="none" if r.get("status") == STATUS_INACCURATE else color,
            label=None if b in shown else b,
        )
        shown.add(b)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_title(title)
    ax.set_xlabel("wall time per plan (s)" if tkey == "wall_time" else "M-step solve time (s)")
    ax.set_ylabel("max position difference to the reference")
    ax.grid(True, which="both", alpha=0.3)
    if shown:
        ax.legend(fontsize=7, loc="best")


def plot(msteps: Rows, plan_rows: Rows, path: Path) -> Path:
    """Time against position difference per backend: unconstrained, constrained M-steps, whole plans."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    labels = list(dict.fromkeys([str(r["backend"]) for r in msteps] + [str(r["backend"]) for r in plan_rows]))
    style = styles(labels)
    fig, axes = plt.subplots(1, 3, figsize=(17, 5.5))
    panels = [
        (
            "Unconstrained M-steps (ref: kalman)",
            [r for r in msteps if r["part"] == "unconstrained"],
            "time_s",
        ),
        (
            "Constrained M-steps (ref: tight Clarabel)",
            [r for r in msteps if r["part"] == "constrained"],
            "time_s",
        ),
        ("Whole plans (ref: kalman plan)", list(plan_rows), "wall_time"),
    ]
    for ax, (title, rows, tkey) in zip(axes, panels, strict=True):
        _panel(ax, title, rows, tkey, style)
    fig.text(
        0.5,
        0.01,
        f"Zero differences drawn at {FLOOR:g}; hollow markers: inaccurate; failed and n/a solves are "
        "omitted (see solvers.md).",
        ha="center",
        fontsize=8,
    )
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
