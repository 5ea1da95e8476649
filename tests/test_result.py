"""Metrics on hand-made paths with known answers, and the figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.geometry import count_crossings, point_polyline_distance
from pmht_opt.plotting import plot_result
from pmht_opt.result import IterationHistory


def hand_made(positions: np.ndarray, locales: np.ndarray, assignment: np.ndarray) -> po.PlanResult:
    M, T1, _ = positions.shape
    states = np.zeros((M, T1, 6))
    states[:, :, 0] = positions[:, :, 0]
    states[:, :, 3] = positions[:, :, 1]
    states[:, 1:, 1] = np.diff(positions[:, :, 0], axis=1)
    states[:, 1:, 4] = np.diff(positions[:, :, 1], axis=1)
    sc = po.Scenario(locales=locales, starts=positions[:, 0], horizon=T1 - 1, bounds=(0, 4, 0, 4))
    hist = IterationHistory(np.zeros(1), np.zeros(1), np.zeros(0), np.zeros(0, dtype=int))
    return po.PlanResult(
        sc, states, assignment, np.ones(len(locales), dtype=int), np.ones((len(locales), M)), hist
    )


def test_distance_coverage_miss_and_crossings() -> None:
    # Two straight paths crossing once, away from their vertices; four steps each.
    p0 = np.linspace([0, 0], [4, 4], 5)
    p1 = np.linspace([0, 4], [4, 0.5], 5)
    locales = np.array([[1.0, 1.2], [3.0, 1.0], [2.0, 3.0]])
    res = hand_made(np.stack([p0, p1]), locales, np.array([0, 0, 0]))
    assert res.total_distance == pytest.approx(4 * np.sqrt(2) + np.hypot(4, 3.5))
    np.testing.assert_allclose(res.distance_per_platform, [4 * np.sqrt(2), np.hypot(4, 3.5)])
    # Coverage is to the nearest path (any platform), measured on the segments: path 1 lies along
    # 3.5 x + 4 y = 16, at |3.5 x + 4 y - 16| / sqrt(3.5^2 + 4^2) from a point.
    to_p1 = np.abs(3.5 * locales[:, 0] + 4 * locales[:, 1] - 16) / np.hypot(3.5, 4)
    to_p0 = np.abs(locales[:, 0] - locales[:, 1]) / np.sqrt(2)
    np.testing.assert_allclose(res.miss_distance, np.minimum(to_p0, to_p1), atol=1e-12)
    assert res.coverage(0.3) == pytest.approx(2 / 3)
    np.testing.assert_array_equal(res.missed_locales(0.3), [2])
    assert res.coverage(1.0) == 1.0
    assert res.coverage() == res.coverage(0.3)  # the scenario's default radius
    assert res.metrics()["missed_locales"] == [2]
    assert res.crossings == 1
    np.testing.assert_array_equal(res.locales_per_platform, [3, 0])
    assert res.max_speed == pytest.approx(np.sqrt(2))  # the first path's steps of (1, 1)
    assert res.max_speed_state == pytest.approx(np.sqrt(2))
    assert res.max_excursion() == 0.0
    with pytest.raises(po.ConfigError, match="radius"):
        res.coverage(-1)


def test_speed_and_acceleration_are_measured_on_the_positions() -> None:
    # Velocity states at rest while the positions jump: the state figures say 0, the measured ones the
    # jump (2 per step, then back to rest).
    positions = np.array([[[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [4.0, 0.0]]])
    res = hand_made(positions, np.array([[1.0, 0.0]]), np.array([0]))
    res.states[:, :, [1, 4]] = 0.0
    assert res.max_speed_state == 0.0
    assert res.max_speed == pytest.approx(2.0)
    # p_-1 = p_0 (at rest): second differences 2, 0, -2.
    assert res.max_acceleration == pytest.approx(2.0)
    assert res.max_acceleration_state == 0.0
    assert res.metrics()["max_speed"] == res.max_speed


def test_coverage_counts_the_segments_not_only_the_samples() -> None:
    # Two hops of length 4; the locale is 0.1 from the middle of the first, 2 from every sample.
    path = np.array([[[0.0, 0.0], [4.0, 0.0], [8.0, 0.0]]])
    res = hand_made(path, np.array([[2.0, 0.1]]), np.array([0]))
    assert res.miss_distance[0] == pytest.approx(0.1)
    assert res.coverage(0.15) == 1.0 and res.coverage(0.05) == 0.0
    wide = po.Scenario(locales=[[2.0, 1.0]], starts=[[0.0, 0.0]], horizon=2, coverage_radius=1.5)
    assert wide.coverage_radius == 1.5
    with pytest.raises(po.ScenarioError, match="coverage_radius"):
        po.Scenario(locales=[[2.0, 1.0]], starts=[[0.0, 0.0]], horizon=2, coverage_radius=0.0)


def test_excursion_outside_the_area() -> None:
    p = np.array([[[1.0, 1.0], [5.0, 1.0], [4.0, 7.0]]])
    res = hand_made(p, np.array([[1.0, 1.0]]), np.array([0]))
    assert res.max_excursion() == pytest.approx(np.hypot(0.0, 3.0))


def test_point_polyline_distance_known() -> None:
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]])
    pts = np.array([[1.0, 1.0], [3.0, 3.0], [-1.0, 0.0]])
    np.testing.assert_allclose(point_polyline_distance(pts, path), [1.0, np.sqrt(2), 1.0])


def test_parallel_paths_do_not_cross() -> None:
    t = np.linspace(0, 1, 6)
    a = np.column_stack([t, 0 * t])
    b = np.column_stack([t, 0 * t + 0.1])
    assert count_crossings(np.stack([a, b])) == 0
    # A zig-zag across the line crosses it on every pass.
    zig = np.column_stack([np.linspace(0.05, 1.05, 6), [-1, 1, -1, 1, -1, 1]])
    assert count_crossings(np.stack([a, zig])) == 5


def test_plot_writes_a_png(tmp_path: Path) -> None:
    sc = po.paper_scenario("B", seed=0, horizon=60)
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=5))
    out = plot_result(res, tmp_path / "fig" / "paths.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    metrics = res.metrics()
    assert set(metrics) >= {"total_distance", "coverage", "crossings", "max_speed", "max_acceleration"}


def test_plot_draws_obstacles_and_area_bounds(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon, Rectangle

    from pmht_opt.plotting import draw_paths

    sc = po.paper_scenario("A", seed=1, horizon=60)
    cons = [
        po.CircleObstacle((3.0, 6.5), 0.8),
        po.PolygonObstacle([(6, 4), (7.5, 4), (7.5, 6), (6, 6)]),
        po.AreaBounds(0, 10, 0, 10),
        po.SpeedLimit(0.5),  # no shape: draws nothing
    ]
    res = po.plan_pmht(sc, po.PMHTConfig(max_iter=2, constraints=cons))
    fig, ax = plt.subplots()
    try:
        draw_paths(ax, sc, res.positions, constraints=res.constraints)
        circles = [p for p in ax.patches if isinstance(p, Circle)]
        polygons = [p for p in ax.patches if type(p) is Polygon]
        dashed = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_linestyle() == "--"]
        assert len(circles) == 1 and circles[0].radius == 0.8
        assert len(polygons) == 1 and np.allclose(polygons[0].get_xy()[:4].min(axis=0), [6, 4])
        assert len(dashed) == 1 and dashed[0].get_width() == 10
    finally:
        plt.close(fig)
    assert plot_result(res, tmp_path / "obstacles.png").stat().st_size > 10_000
