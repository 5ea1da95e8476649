"""The marks on a plan's figure that are not its paths: constraint shapes, headings, direction arrows.

Constraints with a shape in the plane (keep-out zones, area bounds, terminal positions) are drawn
underneath the paths; each kind registers its drawing with :func:`draw_constraint`, so a new kind
draws itself without this module knowing it.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import singledispatch
from typing import Any

import numpy as np

from pmht_opt.constraints.area import AreaBounds
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.obstacles import CircleObstacle, PolygonObstacle
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.plotting.style import BOUNDS_STYLE, KEEP_OUT_STYLE


@singledispatch
def draw_constraint(con: Constraint, ax: Any) -> None:
    """Draw a constraint's shape in the plane on matplotlib axes ``ax``; kinds without one draw nothing.

    Register a drawing for a new kind with ``@draw_constraint.register``; give the artist a ``label``
    and the legend names it.
    """


@draw_constraint.register
def _(con: AreaBounds, ax: Any) -> None:
    from matplotlib.patches import Rectangle

    xmin, xmax, ymin, ymax = con.box
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, label="area bounds", **BOUNDS_STYLE))


@draw_constraint.register
def _(con: CircleObstacle, ax: Any) -> None:
    from matplotlib.patches import Circle

    ax.add_patch(Circle(tuple(con.center), con.radius, label="keep-out zone", **KEEP_OUT_STYLE))


@draw_constraint.register
def _(con: PolygonObstacle, ax: Any) -> None:
    from matplotlib.patches import Polygon

    ax.add_patch(Polygon(con.vertices, closed=True, label="keep-out zone", **KEEP_OUT_STYLE))


@draw_constraint.register
def _(con: Terminal, ax: Any) -> None:
    if con.position is None:
        return  # at the start (drawn as the starts) or free
    p = np.asarray(con.position)
    ax.plot(p[:, 0], p[:, 1], "*", ms=13, mfc="gold", mec="k", ls="none", label="required end", zorder=4)


def heading(line: np.ndarray) -> float | None:
    """Angle (degrees) of the last segment of ``line`` that moves, or ``None`` if none moves."""
    seg = np.diff(line, axis=0)
    size = np.hypot(seg[:, 0], seg[:, 1])
    scale = max(float(np.ptp(line, axis=0).max()), 1e-300)
    moving = np.flatnonzero(size > 1e-6 * scale)
    if moving.size == 0:
        return None
    dx, dy = seg[moving[-1]]
    return float(np.degrees(np.arctan2(dy, dx)))


def end_marker(angle: float | None) -> Any:
    """A triangle pointing along ``angle`` (degrees), or a dot for a path that never moves."""
    from matplotlib.markers import MarkerStyle
    from matplotlib.transforms import Affine2D

    if angle is None:
        return MarkerStyle("o")
    return MarkerStyle(">", transform=Affine2D().rotate_deg(angle))


def direction_arrows(
    ax: Any, line: np.ndarray, colour: str, fractions: Sequence[float] = (0.3, 0.65)
) -> None:
    """Arrowheads along ``line`` at fractions of its length, pointing the way it is flown."""
    seg = np.diff(line, axis=0)
    size = np.hypot(seg[:, 0], seg[:, 1])
    total = float(size.sum())
    if total <= 0:
        return
    cum = np.cumsum(size)
    for f in fractions:
        i = int(np.searchsorted(cum, f * total))
        i = min(i, len(size) - 1)
        if size[i] <= 0:
            continue
        mid = line[i] + 0.5 * seg[i]
        ax.annotate(
            "",
            xy=mid + 1e-3 * seg[i],
            xytext=mid,
            arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 0, "mutation_scale": 13},
            annotation_clip=True,
            zorder=3,
        )
