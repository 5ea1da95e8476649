"""Figures in the style of the paper (locales as crosses, starts as boxes, one colour per platform).

matplotlib is imported inside the functions, with the non-interactive Agg backend, so importing
pmht_opt never touches a display.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import singledispatch
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.constraints.area import AreaBounds
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.obstacles import CircleObstacle, PolygonObstacle
from pmht_opt.scenario import Scenario

#: How keep-out zones are drawn: hatched grey, under the paths.
KEEP_OUT_STYLE: dict[str, Any] = {"fc": "0.85", "ec": "0.3", "lw": 0.8, "hatch": "//", "zorder": 0}
#: How area bounds are drawn: a dashed red box.
BOUNDS_STYLE: dict[str, Any] = {"fill": False, "ls": "--", "lw": 1.2, "ec": "C3"}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


@singledispatch
def draw_constraint(con: Constraint, ax: Any) -> None:
    """Draw a constraint's shape in the plane on matplotlib axes ``ax``; kinds without one draw nothing.

    Register a drawing for a new kind with ``@draw_constraint.register``.
    """


@draw_constraint.register
def _(con: AreaBounds, ax: Any) -> None:
    from matplotlib.patches import Rectangle

    xmin, xmax, ymin, ymax = con.box
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, **BOUNDS_STYLE))


@draw_constraint.register
def _(con: CircleObstacle, ax: Any) -> None:
    from matplotlib.patches import Circle

    ax.add_patch(Circle(tuple(con.center), con.radius, **KEEP_OUT_STYLE))


@draw_constraint.register
def _(con: PolygonObstacle, ax: Any) -> None:
    from matplotlib.patches import Polygon

    ax.add_patch(Polygon(con.vertices, closed=True, **KEEP_OUT_STYLE))


def draw_paths(
    ax: Any,
    scenario: Scenario,
    positions: np.ndarray | Sequence[np.ndarray],
    title: str | None = None,
    assignment: np.ndarray | None = None,
    constraints: Sequence[Any] = (),
) -> None:
    """Draw locales, starts and one polyline per platform on the matplotlib axes ``ax``.

    ``positions`` is ``(M, T+1, 2)`` paths or a list of ``(K_m, 2)`` polylines (e.g. tours);
    ``constraints`` draw their shapes (obstacles, area bounds) underneath.
    """
    for con in constraints:
        draw_constraint(con, ax)
    colours = [f"C{i % 10}" for i in range(len(positions))]
    if scenario.bounds is not None:
        xmin, xmax, ymin, ymax = scenario.bounds
        ax.add_patch(
            _pyplot().Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, ls=":", lw=0.8, ec="0.5")
        )
    z = scenario.locales
    if assignment is None:
        ax.plot(z[:, 0], z[:, 1], "x", color="k", ms=5, mew=1.0, label="locales")
    else:
        for m, colour in enumerate(colours):
            mine = assignment == m
            ax.plot(z[mine, 0], z[mine, 1], "x", color=colour, ms=5, mew=1.2)
    for m, colour in enumerate(colours):
        line = np.asarray(positions[m])
        ax.plot(line[:, 0], line[:, 1], "-", color=colour, lw=1.4, label=f"platform {m + 1}")
    s = scenario.start_positions
    ax.plot(s[:, 0], s[:, 1], "s", mfc="none", mec="c", ms=9, mew=2.0, label="starts")
    ax.set_xlabel("X Position")
    ax.set_ylabel("Y Position")
    ax.set_aspect("equal", adjustable="datalim")
    if title:
        ax.set_title(title, fontsize=9)


def plot_paths(
    scenario: Scenario,
    positions: np.ndarray | Sequence[np.ndarray],
    path: str | Path,
    title: str | None = None,
    assignment: np.ndarray | None = None,
    constraints: Sequence[Any] = (),
) -> Path:
    """Write one figure of paths to ``path`` and return it."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    try:
        draw_paths(ax, scenario, positions, title=title, assignment=assignment, constraints=constraints)
        fig.tight_layout()
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=120)
    finally:
        plt.close(fig)
    return out
