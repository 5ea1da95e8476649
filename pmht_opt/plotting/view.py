"""A readable view of a plan that runs far out of its area.

The view is clipped to the area and the starts; each path that leaves it is annotated where it leaves
with how far outside the area it goes, and an inset shows the whole extent with the view outlined.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pmht_opt.plotting.style import RUNAWAY_FRACTION, VIEW_MARGIN, platform_colour
from pmht_opt.scenario import Scenario


def clipped_view(
    bounds: tuple[float, float, float, float], starts: np.ndarray, lines: Sequence[np.ndarray]
) -> tuple[float, ...] | None:
    """Axis limits that clip a run-away plan to its area and starts, or ``None`` when everything fits
    near them."""
    xmin, xmax, ymin, ymax = bounds
    xmin, xmax = min(xmin, float(starts[:, 0].min())), max(xmax, float(starts[:, 0].max()))
    ymin, ymax = min(ymin, float(starts[:, 1].min())), max(ymax, float(starts[:, 1].max()))
    size = max(xmax - xmin, ymax - ymin, 1e-12)
    pts = np.vstack([np.asarray(line, dtype=float) for line in lines])
    far = RUNAWAY_FRACTION * size
    if pts[:, 0].min() >= xmin - far and pts[:, 0].max() <= xmax + far:
        if pts[:, 1].min() >= ymin - far and pts[:, 1].max() <= ymax + far:
            return None
    pad = VIEW_MARGIN * size
    return (xmin - pad, xmax + pad, ymin - pad, ymax + pad)


def annotate_excursions(
    ax: Any, view: tuple[float, ...], bounds: tuple[float, ...], lines: Sequence[np.ndarray], unit: str
) -> None:
    """Where each path leaves the clipped view: an arrow and how far outside the area it goes."""
    from pmht_opt.result import excursion

    x0, x1, y0, y1 = view
    for m, line in enumerate(lines):
        line = np.asarray(line, dtype=float)
        outside = (line[:, 0] < x0) | (line[:, 0] > x1) | (line[:, 1] < y0) | (line[:, 1] > y1)
        if not outside.any():
            continue
        k = int(np.argmax(outside))
        inside = line[max(k - 1, 0)]
        exit_pt = np.clip(line[k], [x0, y0], [x1, y1])
        far = excursion(line, bounds)  # type: ignore[arg-type]
        d = exit_pt - inside
        d = d / max(float(np.hypot(*d)), 1e-300)
        colour = platform_colour(m)
        ax.annotate(
            f"platform {m}: {far:.3g}{unit} out",
            xy=exit_pt,
            xytext=exit_pt - 0.12 * (x1 - x0) * d,
            textcoords="data",
            fontsize=7,
            color=colour,
            ha="center",
            va="center",
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.2},
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": colour, "lw": 0.6, "alpha": 0.9},
            zorder=6,
        )


def in_grid(ax: Any) -> bool:
    """Whether ``ax`` is one panel of several (insets not counted)."""
    return sum(1 for a in ax.figure.axes if a.get_subplotspec() is not None) > 1


def inset(ax: Any, scenario: Scenario, lines: Sequence[np.ndarray], view: tuple[float, ...]) -> Any:
    """A small map of the whole extent, with the clipped view outlined: beside a lone axes, in the
    upper right corner of a panel of a grid (where there is no room beside it)."""
    from matplotlib.patches import Rectangle

    ins = ax.inset_axes([0.63, 0.63, 0.36, 0.36] if in_grid(ax) else [1.04, 0.0, 0.42, 0.42])
    ins.set_facecolor((1, 1, 1, 0.92))
    for m, line in enumerate(lines):
        line = np.asarray(line, dtype=float)
        ins.plot(line[:, 0], line[:, 1], "-", color=platform_colour(m), lw=0.8)
    z = scenario.locales
    ins.plot(z[:, 0], z[:, 1], ".", color="k", ms=1.5)
    x0, x1, y0, y1 = view
    ins.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="k", lw=0.8, ls="--"))
    ins.set_aspect("equal", adjustable="datalim")
    ins.tick_params(labelsize=6)
    if in_grid(ax):
        ins.text(0.5, 0.03, "whole extent", transform=ins.transAxes, fontsize=6, ha="center", va="bottom")
    else:
        ins.set_title("whole extent (dashed: the main view)", fontsize=7)
    return ins


def frame(ax: Any, scenario: Scenario, lines: Sequence[np.ndarray], unit: str, clip: bool) -> None:
    """Set the view of ``ax``: clipped with annotations and an inset for a run-away plan (when
    ``clip``), else equal axes around everything drawn."""
    view = (
        clipped_view(scenario.bounds, scenario.start_positions, lines)
        if clip and scenario.bounds is not None and lines
        else None
    )
    if view is None:
        ax.set_aspect("equal", adjustable="datalim")
        return
    assert scenario.bounds is not None
    ax.set_xlim(view[0], view[1])
    ax.set_ylim(view[2], view[3])
    ax.set_aspect("equal", adjustable="box")
    annotate_excursions(ax, view, scenario.bounds, lines, unit)
    inset(ax, scenario, lines, view)
