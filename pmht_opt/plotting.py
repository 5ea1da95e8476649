"""Figures of plans and tours that a reader understands without the code.

Every figure says what it shows: a legend names the locales (covered, or missed: further than the
coverage radius from every path), the starts (squares) and ends (a triangle pointing along the last
heading) drawn in each platform's colour, and the platforms; arrowheads along each path give its
direction; constraints with a shape (keep-out zones, area bounds, terminal positions) are drawn
underneath. A plan that runs far out of its area keeps the area readable: the view is clipped to the
area, each excursion is annotated where it leaves the view with how far it goes, and an inset shows
the whole extent.

matplotlib is imported inside the functions, with the non-interactive Agg backend, so importing
pmht_opt never touches a display.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import singledispatch
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.constraints.area import AreaBounds
from pmht_opt.constraints.base import Constraint
from pmht_opt.constraints.obstacles import CircleObstacle, PolygonObstacle
from pmht_opt.constraints.terminal import Terminal
from pmht_opt.geometry import point_polyline_distance
from pmht_opt.scenario import Scenario

#: How keep-out zones are drawn: hatched grey, under the paths.
KEEP_OUT_STYLE: dict[str, Any] = {"fc": "0.85", "ec": "0.3", "lw": 0.8, "hatch": "//", "zorder": 0}
#: How area bounds are drawn: a dashed red box.
BOUNDS_STYLE: dict[str, Any] = {"fill": False, "ls": "--", "lw": 1.2, "ec": "C3"}
#: How the scenario's area is drawn: a dotted grey box.
AREA_STYLE: dict[str, Any] = {"fill": False, "ls": ":", "lw": 0.8, "ec": "0.5"}
#: How a missed locale is marked: a red ring around its cross.
MISSED_STYLE: dict[str, Any] = {"marker": "o", "ms": 9, "mfc": "none", "mec": "red", "mew": 1.4, "ls": "none"}
#: Paths reaching further than this fraction of the area's size outside it are clipped, with an inset.
RUNAWAY_FRACTION = 0.25
#: Margin around the area in a clipped view, as a fraction of its size.
VIEW_MARGIN = 0.08
#: Relative slack of the coverage test (as :meth:`pmht_opt.PlanResult.coverage`).
COVERAGE_RTOL = 1e-6


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def figure_formats() -> set[str]:
    """File suffixes (``".png"``, ``".pdf"``, ...) matplotlib can write figures to."""
    _pyplot()
    from matplotlib.backend_bases import FigureCanvasBase

    return {f".{k}" for k in FigureCanvasBase.get_supported_filetypes()}


def platform_colour(m: int) -> str:
    """The colour of platform ``m`` in every figure (matplotlib's default cycle)."""
    return f"C{m % 10}"


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


def miss_distances(locales: np.ndarray, lines: Sequence[np.ndarray]) -> np.ndarray:
    """``(N,)`` distance of each locale to the nearest of ``lines`` (polylines ``(K, 2)``), measured
    on their segments (docs/model.md section 11)."""
    if not lines:
        return np.full(locales.shape[0], np.inf)
    return np.min([point_polyline_distance(locales, np.asarray(line, dtype=float)) for line in lines], axis=0)


def _heading(line: np.ndarray) -> float | None:
    """Angle (degrees) of the last segment of ``line`` that moves, or ``None`` if none moves."""
    seg = np.diff(line, axis=0)
    size = np.hypot(seg[:, 0], seg[:, 1])
    scale = max(float(np.ptp(line, axis=0).max()), 1e-300)
    moving = np.flatnonzero(size > 1e-6 * scale)
    if moving.size == 0:
        return None
    dx, dy = seg[moving[-1]]
    return float(np.degrees(np.arctan2(dy, dx)))


def _end_marker(angle: float | None) -> Any:
    from matplotlib.markers import MarkerStyle
    from matplotlib.transforms import Affine2D

    if angle is None:
        return MarkerStyle("o")
    return MarkerStyle(">", transform=Affine2D().rotate_deg(angle))


def _direction_arrows(
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


def _view(
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


def _annotate_excursions(
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


def _in_grid(ax: Any) -> bool:
    """Whether ``ax`` is one panel of several (insets not counted)."""
    return sum(1 for a in ax.figure.axes if a.get_subplotspec() is not None) > 1


def _inset(ax: Any, scenario: Scenario, lines: Sequence[np.ndarray], view: tuple[float, ...]) -> Any:
    """A small map of the whole extent, with the clipped view outlined: beside a lone axes, in the
    upper right corner of a panel of a grid (where there is no room beside it)."""
    from matplotlib.patches import Rectangle

    ins = ax.inset_axes([0.63, 0.63, 0.36, 0.36] if _in_grid(ax) else [1.04, 0.0, 0.42, 0.42])
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
    if _in_grid(ax):
        ins.text(0.5, 0.03, "whole extent", transform=ins.transAxes, fontsize=6, ha="center", va="bottom")
    else:
        ins.set_title("whole extent (dashed: the main view)", fontsize=7)
    return ins


@dataclass
class _Labelled:
    """A legend entry whose artist carries no label of its own (or is a tuple drawn overlaid)."""

    artist: Any
    label: str


def _labels(handles: Sequence[Any]) -> list[str]:
    return [h.label if isinstance(h, _Labelled) else h.get_label() for h in handles]


def draw_paths(
    ax: Any,
    scenario: Scenario,
    positions: np.ndarray | Sequence[np.ndarray],
    title: str | None = None,
    assignment: np.ndarray | None = None,
    constraints: Sequence[Any] = (),
    *,
    radius: float | None = None,
    show_radius: bool = False,
    legend: str | None = "auto",
    labels: tuple[str, str] = ("x", "y"),
    unit: str = "",
    clip: bool = True,
) -> None:
    """Draw a plan or tour on the matplotlib axes ``ax``: locales, starts, ends, paths, constraints.

    Parameters
    ----------
    ax
        Axes to draw on.
    scenario
        The scenario (locales, starts, area).
    positions
        ``(M, T+1, 2)`` paths or a list of ``(K_m, 2)`` polylines (e.g. tours), one per platform.
    title
        Axes title.
    assignment
        ``(N,)`` platform of each locale: colours the crosses by platform (black otherwise).
    constraints
        Constraints whose shapes are drawn underneath (:func:`draw_constraint`).
    radius
        Coverage radius: locales further than it from every path are marked missed (red ring).
        Default: the scenario's coverage radius.
    show_radius
        Draw a circle of the coverage radius around every locale.
    legend
        ``"outside"`` (right of the axes), ``"inside"`` (best place within), ``"below"``, ``None``,
        or ``"auto"``: outside a lone axes; in a grid of panels, below the bottom-left panel only
        (one legend for the figure, its entries the same for every panel).
    labels, unit
        Axis labels, and the unit of lengths in annotations (e.g. ``" m"``).
    clip
        Clip a run-away plan's view to its area, annotating the excursions, with an inset of the
        whole extent (module notes).
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Rectangle

    lines = [np.asarray(positions[m], dtype=float) for m in range(len(positions))]
    grid = _in_grid(ax)
    if legend == "auto":
        spec = ax.get_subplotspec()
        if not grid:
            legend = "outside"
        else:
            legend = "below" if spec is not None and spec.is_last_row() and spec.is_first_col() else None
    for con in constraints:
        draw_constraint(con, ax)
    if scenario.bounds is not None:
        xmin, xmax, ymin, ymax = scenario.bounds
        ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, label="area", **AREA_STYLE))
    rho = scenario.coverage_radius if radius is None else float(radius)
    z = scenario.locales
    missed = miss_distances(z, lines) > rho * (1 + COVERAGE_RTOL)
    if show_radius:
        for p in z:
            ax.add_patch(Circle(tuple(p), rho, fill=False, ec="0.6", lw=0.6, ls="--", zorder=1))
    handles: list[Any] = []
    if assignment is None:
        ax.plot(z[:, 0], z[:, 1], "x", color="k", ms=5, mew=1.0, ls="none", zorder=2)
    else:
        for m in range(len(lines)):
            mine = np.asarray(assignment) == m
            ax.plot(z[mine, 0], z[mine, 1], "x", color=platform_colour(m), ms=5, mew=1.2, ls="none", zorder=2)
    cross = Line2D([], [], marker="x", color="k", ls="none", ms=5)
    covered = "locale" if grid else f"locale, covered (within {rho:g}{unit} of a path)"
    handles.append(_Labelled(cross, covered))
    if missed.any():
        ring_style = {**MISSED_STYLE, "ms": 6, "mew": 1.0} if grid else MISSED_STYLE
        ax.plot(z[missed, 0], z[missed, 1], zorder=2, **ring_style)
        ring = Line2D([], [], **ring_style)
        label = f"locale, missed ({int(missed.sum())} of {len(z)})"
        if grid:
            label = f"missed (> {rho:g}{unit} from every path)"
        handles.append(_Labelled((cross, ring), label))
    if show_radius:
        handles.append(
            Line2D(
                [],
                [],
                marker="o",
                ms=9,
                mfc="none",
                mec="0.6",
                ls="none",
                label=f"coverage radius {rho:g}{unit}",
            )
        )
    for m, line in enumerate(lines):
        colour = platform_colour(m)
        (path_line,) = ax.plot(
            line[:, 0], line[:, 1], "-", color=colour, lw=1.4, zorder=3, label=f"platform {m}"
        )
        handles.append(path_line)
        _direction_arrows(ax, line, colour)
        if line.shape[0] > 1:
            end = line[-1]
            ax.plot(*end, marker=_end_marker(_heading(line)), color=colour, ms=9, mec="k", mew=0.6, zorder=5)
    starts = scenario.start_positions
    for m in range(min(len(lines), starts.shape[0])):
        ax.plot(*starts[m], marker="s", ms=9, mfc="white", mec=platform_colour(m), mew=2.0, zorder=4)
    handles.append(Line2D([], [], marker="s", ms=8, mfc="white", mec="k", mew=1.6, ls="none", label="start"))
    handles.append(
        Line2D(
            [],
            [],
            marker=">",
            ms=8,
            color="0.4",
            mec="k",
            mew=0.6,
            ls="none",
            label="end (heading)" if grid else "end (pointing along the heading)",
        )
    )
    for patch in ax.patches:
        label = patch.get_label()
        if label and not label.startswith("_") and label not in _labels(handles):
            handles.append(patch)
    for line2d in ax.lines:
        label = line2d.get_label()
        if label == "required end" and label not in _labels(handles):
            handles.append(line2d)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    view = (
        _view(scenario.bounds, scenario.start_positions, lines)
        if clip and scenario.bounds is not None and lines
        else None
    )
    if view is not None:
        assert scenario.bounds is not None
        ax.set_xlim(view[0], view[1])
        ax.set_ylim(view[2], view[3])
        ax.set_aspect("equal", adjustable="box")
        _annotate_excursions(ax, view, scenario.bounds, lines, unit)
        _inset(ax, scenario, lines, view)
    else:
        ax.set_aspect("equal", adjustable="datalim")
    if title:
        ax.set_title(title, fontsize=9)
    if legend is not None:
        from matplotlib.legend_handler import HandlerTuple

        entries = [h.artist if isinstance(h, _Labelled) else h for h in handles]
        where: dict[str, Any] = {
            "outside": {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "fontsize": 7, "frameon": False},
            "below": {
                "loc": "upper left",
                "bbox_to_anchor": (0.0, -0.14),
                "fontsize": 6.5,
                "ncol": 2,
                "columnspacing": 0.8,
                "handletextpad": 0.4,
            },
            "inside": {"loc": "best", "fontsize": 6, "framealpha": 0.85},
        }[legend]
        ax.legend(entries, _labels(handles), handler_map={tuple: HandlerTuple(ndivide=None, pad=0)}, **where)


def plot_paths(
    scenario: Scenario,
    positions: np.ndarray | Sequence[np.ndarray],
    path: str | Path,
    title: str | None = None,
    assignment: np.ndarray | None = None,
    constraints: Sequence[Any] = (),
    **options: Any,
) -> Path:
    """Write one figure of paths to ``path`` and return it; ``options`` go to :func:`draw_paths`."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8.2, 5.6))
    try:
        draw_paths(
            ax, scenario, positions, title=title, assignment=assignment, constraints=constraints, **options
        )
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=120, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out


def plot_result(
    result: Any,
    path: str | Path,
    title: str | None = None,
    *,
    show_radius: bool = False,
    show_assignment: bool = False,
    unit: str = "",
) -> Path:
    """Write the figure of a :class:`~pmht_opt.PlanResult` to ``path``: its paths, constraints and
    which locales it covers. ``unit`` (e.g. ``" (m)"``) marks a geo-referenced plan, whose axes are
    metres east and north of the origin."""
    sc = result.scenario
    u = unit.strip(" ()")
    if title is None:
        name = f"{sc.name}: " if sc.name else ""
        title = (
            f"{name}{result.solver}, distance {result.total_distance:.1f}{' ' + u if u else ''}, "
            f"coverage within {sc.coverage_radius:g}{' ' + u if u else ''}: {result.coverage():.0%}"
        )
    labels = ("east (m)", "north (m)") if u == "m" else ("x", "y")
    return plot_paths(
        sc,
        result.positions,
        path,
        title=title,
        assignment=result.assignment if show_assignment else None,
        constraints=result.constraints,
        show_radius=show_radius,
        labels=labels,
        unit=f" {u}" if u else "",
    )
