"""A plan or tour on one matplotlib axes, with a legend that says what every mark is.

The legend names the locales (covered, or missed: further than the coverage radius from every path),
the starts (squares) and ends (a triangle pointing along the last heading) drawn in each platform's
colour, the platforms, and every constraint shape drawn. Entries whose artist carries no label of its
own, or is several artists overlaid, are :class:`Labelled`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.geometry.coverage import missed_locales as missed_locales_of
from pmht_opt.plotting.marks import direction_arrows, draw_constraint, end_marker, heading
from pmht_opt.plotting.style import AREA_STYLE, MISSED_STYLE, platform_colour
from pmht_opt.plotting.view import frame, in_grid
from pmht_opt.scenario import Scenario, describe_radius

#: Where each kind of legend goes, as matplotlib's ``legend`` options.
LEGEND_PLACES: dict[str, dict[str, Any]] = {
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
}


@dataclass
class Labelled:
    """A legend entry whose artist carries no label of its own (or is a tuple drawn overlaid)."""

    artist: Any
    label: str


def _labels(handles: Sequence[Any]) -> list[str]:
    return [h.label if isinstance(h, Labelled) else h.get_label() for h in handles]


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
        whole extent (:mod:`pmht_opt.plotting.view`).
    """
    from matplotlib.patches import Rectangle

    lines = [np.asarray(positions[m], dtype=float) for m in range(len(positions))]
    grid = in_grid(ax)
    place = _legend_place(ax, legend, grid)
    for con in constraints:
        draw_constraint(con, ax)
    if scenario.bounds is not None:
        xmin, xmax, ymin, ymax = scenario.bounds
        ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, label="area", **AREA_STYLE))
    rho = scenario.radii if radius is None else np.full(scenario.n_locales, float(radius))
    handles = _draw_locales(ax, scenario.locales, lines, rho, assignment, show_radius, grid, unit)
    handles += _draw_platforms(ax, lines, scenario.start_positions, grid)
    handles += _shape_entries(ax, handles)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    frame(ax, scenario, lines, unit, clip)
    if title:
        ax.set_title(title, fontsize=9)
    if place is not None:
        from matplotlib.legend_handler import HandlerTuple

        entries = [h.artist if isinstance(h, Labelled) else h for h in handles]
        tuples = {tuple: HandlerTuple(ndivide=None, pad=0)}
        ax.legend(entries, _labels(handles), handler_map=tuples, **LEGEND_PLACES[place])


def _legend_place(ax: Any, legend: str | None, grid: bool) -> str | None:
    """Where the legend goes: ``legend`` itself unless it is ``"auto"`` (see :func:`draw_paths`)."""
    if legend != "auto":
        return legend
    if not grid:
        return "outside"
    spec = ax.get_subplotspec()
    return "below" if spec is not None and spec.is_last_row() and spec.is_first_col() else None


def _draw_locales(
    ax: Any,
    z: np.ndarray,
    lines: Sequence[np.ndarray],
    rho: np.ndarray,
    assignment: np.ndarray | None,
    show_radius: bool,
    grid: bool,
    unit: str,
) -> list[Any]:
    """The locales ``z`` as crosses (coloured by ``assignment``), rings around the missed ones and,
    with ``show_radius``, the coverage radius around each; their legend entries."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    missed = np.zeros(z.shape[0], dtype=bool)
    missed[missed_locales_of(z, lines, rho)] = True
    if show_radius:
        for p, r in zip(z, rho, strict=True):
            ax.add_patch(Circle(tuple(p), float(r), fill=False, ec="0.6", lw=0.6, ls="--", zorder=1))
    if assignment is None:
        ax.plot(z[:, 0], z[:, 1], "x", color="k", ms=5, mew=1.0, ls="none", zorder=2)
    else:
        for m in range(len(lines)):
            mine = np.asarray(assignment) == m
            ax.plot(z[mine, 0], z[mine, 1], "x", color=platform_colour(m), ms=5, mew=1.2, ls="none", zorder=2)
    cross = Line2D([], [], marker="x", color="k", ls="none", ms=5)
    covered = "locale" if grid else f"locale, covered (within {describe_radius(rho)}{unit} of a path)"
    handles: list[Any] = [Labelled(cross, covered)]
    if missed.any():
        ring_style = {**MISSED_STYLE, "ms": 6, "mew": 1.0} if grid else MISSED_STYLE
        ax.plot(z[missed, 0], z[missed, 1], zorder=2, **ring_style)
        ring = Line2D([], [], **ring_style)
        label = f"locale, missed ({int(missed.sum())} of {len(z)})"
        if grid:
            label = f"missed (> {describe_radius(rho)}{unit} from every path)"
        handles.append(Labelled((cross, ring), label))
    if show_radius:
        radius = f"coverage radius {describe_radius(rho)}{unit}"
        handles.append(Line2D([], [], marker="o", ms=9, mfc="none", mec="0.6", ls="none", label=radius))
    return handles


def _draw_platforms(ax: Any, lines: Sequence[np.ndarray], starts: np.ndarray, grid: bool) -> list[Any]:
    """Each platform's path with its direction arrows, its end pointing along its heading and its start;
    their legend entries."""
    from matplotlib.lines import Line2D

    handles: list[Any] = []
    for m, line in enumerate(lines):
        colour = platform_colour(m)
        (path_line,) = ax.plot(
            line[:, 0], line[:, 1], "-", color=colour, lw=1.4, zorder=3, label=f"platform {m}"
        )
        handles.append(path_line)
        direction_arrows(ax, line, colour)
        if line.shape[0] > 1:
            end = line[-1]
            ax.plot(*end, marker=end_marker(heading(line)), color=colour, ms=9, mec="k", mew=0.6, zorder=5)
    for m in range(min(len(lines), starts.shape[0])):
        ax.plot(*starts[m], marker="s", ms=9, mfc="white", mec=platform_colour(m), mew=2.0, zorder=4)
    handles.append(Line2D([], [], marker="s", ms=8, mfc="white", mec="k", mew=1.6, ls="none", label="start"))
    end_label = "end (heading)" if grid else "end (pointing along the heading)"
    handles.append(
        Line2D([], [], marker=">", ms=8, color="0.4", mec="k", mew=0.6, ls="none", label=end_label)
    )
    return handles


def _shape_entries(ax: Any, handles: Sequence[Any]) -> list[Any]:
    """Legend entries of the labelled shapes on ``ax`` (constraints, the area) not yet in ``handles``."""
    entries: list[Any] = []
    for patch in ax.patches:
        label = patch.get_label()
        if label and not label.startswith("_") and label not in _labels([*handles, *entries]):
            entries.append(patch)
    for line2d in ax.lines:
        label = line2d.get_label()
        if label == "required end" and label not in _labels([*handles, *entries]):
            entries.append(line2d)
    return entries
