"""Figures a reader understands: legend, coloured starts and ends, missed locales, radii, clipped
run-away plans, the EM animation."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.geometry import miss_distances
from pmht_opt.plotting import (
    draw_paths,
    figure_formats,
    platform_colour,
    plot_paths,
    plot_result,
    plot_tour,
)
from pmht_opt.plotting.animation import animate_iterations, animate_plan, pick_frames


@pytest.fixture
def axes() -> Iterator[Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def _scenario() -> po.Scenario:
    return po.Scenario(
        locales=[[1.0, 1.0], [2.0, 1.0], [3.0, 3.0], [0.0, 3.0]],
        starts=[[0.0, 0.0], [3.0, 0.0]],
        horizon=4,
        bounds=(0.0, 3.0, 0.0, 3.0),
        coverage_radius=0.3,
    )


def _paths() -> np.ndarray:
    # Platform 0 passes locales 0 and 1; platform 1 passes locale 2; locale 3 is missed.
    return np.array(
        [
            [[0, 0], [1, 1], [1.5, 1.0], [2, 1], [2, 1.2]],
            [[3, 0], [3, 1], [3, 2], [3, 3], [2.5, 3]],
        ],
        dtype=float,
    )


def _legend(ax: Any) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_legend_names_every_kind_of_mark(axes: Any) -> None:
    draw_paths(axes, _scenario(), _paths(), constraints=[po.CircleObstacle((1.5, 2.2), 0.3)])
    names = _legend(axes)
    assert names[:2] == ["locale, covered (within 0.3 of a path)", "locale, missed (1 of 4)"]
    for name in (
        "platform 0",
        "platform 1",
        "start",
        "end (pointing along the heading)",
        "area",
        "keep-out zone",
    ):
        assert name in names


def test_starts_and_ends_in_the_platforms_colours_ends_pointing_along_the_heading(axes: Any) -> None:
    draw_paths(axes, _scenario(), _paths(), legend=None)
    starts = [ln for ln in axes.lines if ln.get_marker() == "s"]
    assert [ln.get_markeredgecolor() for ln in starts] == [platform_colour(0), platform_colour(1)]
    ends = [ln for ln in axes.lines if ln.get_zorder() == 5]
    assert [ln.get_color() for ln in ends] == [platform_colour(0), platform_colour(1)]
    # Platform 1's last leg heads west, platform 0's north: their ends are triangles pointing so.
    from matplotlib.markers import MarkerStyle

    for end, towards in zip(ends, ("^", "<"), strict=True):
        turned = end._marker.get_transform().get_matrix()
        assert np.allclose(turned, MarkerStyle(towards).get_transform().get_matrix(), atol=1e-12)
    arrows = [a for a in axes.texts if getattr(a, "arrow_patch", None) is not None]
    assert len(arrows) == 4  # two along each path


def test_missed_locales_are_ringed_and_the_radius_drawable(axes: Any) -> None:
    from matplotlib.patches import Circle

    sc = _scenario()
    assert np.flatnonzero(miss_distances(sc.locales, list(_paths())) > 0.3).tolist() == [3]
    draw_paths(axes, sc, _paths(), show_radius=True, legend="inside")
    rings = [ln for ln in axes.lines if ln.get_marker() == "o" and ln.get_markeredgecolor() == "red"]
    assert len(rings) == 1 and np.array_equal(np.c_[rings[0].get_xdata(), rings[0].get_ydata()], [[0.0, 3.0]])
    circles = [p for p in axes.patches if isinstance(p, Circle)]
    assert len(circles) == 4 and all(c.radius == 0.3 for c in circles)
    assert "coverage radius 0.3" in _legend(axes)


def test_a_run_away_plan_keeps_the_area_readable(axes: Any) -> None:
    paths = _paths()
    paths[1, -1] = [40.0, 3.0]  # platform 1 flies 37 units out of a 3-unit area
    draw_paths(axes, _scenario(), paths, unit=" m")
    x0, x1 = axes.get_xlim()
    assert x0 > -1 and x1 < 4  # the main view stays on the area
    notes = [t.get_text() for t in axes.texts if t.get_text()]
    assert notes == ["platform 1: 37 m out"]
    (inset,) = axes.child_axes
    assert inset.get_xlim()[1] >= 40  # the inset shows the whole extent


def test_plain_plans_are_not_clipped(axes: Any) -> None:
    draw_paths(axes, _scenario(), _paths())
    assert not axes.child_axes and not [t for t in axes.texts if t.get_text()]


def test_figures_of_plans_tours_and_geo_plans(tmp_path: Path) -> None:
    sc = po.paper_scenario("A", seed=1, horizon=60)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=3, constraints=[po.SpeedLimit(0.5)]))
    png = plot_result(res, tmp_path / "r.png", show_radius=True)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = plot_result(res, tmp_path / "r.svg", unit=" (m)").read_text()
    assert "east (m)" in svg and "north (m)" in svg
    tour = po.order_locales(sc, "ga", seed=0, iterations=50)
    assert plot_tour(tour, tmp_path / "t.png").stat().st_size > 10_000
    assert plot_paths(sc, res.positions, tmp_path / "deep" / "p.pdf").exists()
    assert {".png", ".pdf", ".svg"} <= figure_formats()


def test_pick_frames_keeps_the_early_iterations_and_the_last() -> None:
    assert pick_frames(range(10)) == list(range(10))
    frames = pick_frames(range(101), limit=40)
    assert len(frames) <= 41 and frames[:20] == list(range(20)) and frames[-1] == 100
    assert np.all(np.diff(frames) > 0)


def test_the_em_animation_has_a_frame_per_iteration(tmp_path: Path) -> None:
    from PIL import Image

    sc = po.paper_scenario("C", seed=0, horizon=50)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=4, snapshots=tuple(range(5))))
    gif = animate_plan(res, tmp_path / "em.gif", fps=2, dpi=50)
    with Image.open(gif) as im:
        assert im.n_frames == 5  # iterations 0-4
        im.seek(0)
        first, shown = np.asarray(im.convert("RGB")), im.info["duration"]
        im.seek(4)
        last, held = np.asarray(im.convert("RGB")), im.info["duration"]
    assert held >= 4 * shown  # the last iteration is held (two seconds at 2 frames per second)
    assert not np.array_equal(first, last)  # the paths move
    with pytest.raises(po.ConfigError, match="no iterations to animate"):
        animate_iterations(sc, {}, tmp_path / "none.gif")
