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

The parts: :mod:`~pmht_opt.plotting.style` (styles, colours, matplotlib),
:mod:`~pmht_opt.plotting.marks` (constraint shapes, headings, arrows), :mod:`~pmht_opt.plotting.view`
(the clipped view of a run-away plan), :mod:`~pmht_opt.plotting.paths` (a plan on one axes, with its
legend); this module writes whole figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError
from pmht_opt.plotting.marks import draw_constraint
from pmht_opt.plotting.paths import draw_paths
from pmht_opt.plotting.style import (
    AREA_STYLE,
    BOUNDS_STYLE,
    KEEP_OUT_STYLE,
    MISSED_STYLE,
    RUNAWAY_FRACTION,
    VIEW_MARGIN,
    figure_formats,
    platform_colour,
    pyplot,
)
from pmht_opt.scenario import Scenario
from pmht_opt.validation import file_path, writing

__all__ = [
    "AREA_STYLE",
    "BOUNDS_STYLE",
    "KEEP_OUT_STYLE",
    "MISSED_STYLE",
    "RUNAWAY_FRACTION",
    "VIEW_MARGIN",
    "draw_constraint",
    "draw_paths",
    "figure_formats",
    "platform_colour",
    "plot_paths",
    "plot_result",
    "plot_tour",
    "pyplot",
]


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
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.2, 5.6))
    try:
        draw_paths(
            ax, scenario, positions, title=title, assignment=assignment, constraints=constraints, **options
        )
        out = figure_path(path)
        with writing(out) as part:
            fig.savefig(part, dpi=120, bbox_inches="tight")
    finally:
        plt.close(fig)
    return out


def figure_path(path: Any) -> Path:
    """The file a figure goes to: ``path``, with ``.png`` added when it has no suffix (what matplotlib
    writes then); ConfigError naming ``path`` for a directory or a format matplotlib cannot write."""
    out = file_path("path", path)
    if out.is_dir():
        raise ConfigError(f"path: {str(out)!r} is a directory; give a file name for the figure.")
    if not out.suffix:
        out = out.with_name(out.name + ".png")
    formats = figure_formats()
    if out.suffix.lower() not in formats:
        raise ConfigError(
            f"path: matplotlib cannot write {out.suffix!r} figures; use one of {', '.join(sorted(formats))}."
        )
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
        who = f"{result.planner} ({result.solver})" if result.planner else result.solver
        title = (
            f"{name}{who}, distance {result.total_distance:.1f}{' ' + u if u else ''}, "
            f"coverage within {sc.radius_text}{' ' + u if u else ''}: {result.coverage():.0%}"
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


def plot_tour(
    tour: Any,
    path: str | Path,
    scenario: Scenario | None = None,
    title: str | None = None,
    constraints: Sequence[Any] = (),
) -> Path:
    """Write the figure of a :class:`~pmht_opt.ordering.TourResult` to ``path``: the starts (boxes),
    locales (crosses, coloured by route), the routes' legs (closed routes back to their start) and the
    ``constraints`` (keep-out zones, areas). ``scenario`` is needed when the tour does not hold the one
    it was ordered for."""
    from pmht_opt.ordering.tour import route_legs

    sc = tour.scenario_for(scenario)
    legs = route_legs(sc, tour.routes, tour.closed)
    label = title if title is not None else f"{tour.method}: total distance {tour.total_distance:.2f}"
    return plot_paths(sc, legs, path, title=label, assignment=tour.assignment, constraints=constraints)
