"""GeoJSON for GIS tools: valid RFC 7946 under an independent validator, cut at the antimeridian, with
the plan's zones, areas and footprints as counter-clockwise polygons."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geojson_checks import check_rfc7946, lines, rings, shoelace, validator_findings

import pmht_opt as po
from pmht_opt.geometry.earth import GeoOrigin
from pmht_opt.io import (
    Mission,
    PlannerSettings,
    export_geojson,
    plan_mission,
    read_geojson_paths,
    read_points,
)
from pmht_opt.io.antimeridian import Globe
from pmht_opt.io.frame import Frame
from pmht_opt.io.geojson import CIRCLE_SIDES, line_positions

#: Over Fiji, 1.07 km west of the antimeridian.
FIJI = GeoOrigin(-16.5, 179.99)


@pytest.fixture(scope="module")
def fiji(tmp_path_factory: pytest.TempPathFactory) -> tuple[po.PlanResult, dict[str, Any], Path]:
    """A drone from 600 m west of the origin to two sites across the antimeridian and back; a keep-out
    disc, a keep-out square, the area and a site's footprint straddle the meridian."""
    sites = np.array([[1800.0, 150.0], [1800.0, -150.0], [1100.0, 250.0]])
    sc = po.Scenario(
        locales=sites,
        starts=np.array([[-600.0, 0.0]]),
        horizon=200,
        dt=2.0,
        q=6.3e-5,
        r=1600.0,
        coverage_radius=80.0,
        bounds=(-800.0, 2200.0, -700.0, 700.0),
        name="fiji",
    )
    constraints = (
        po.CircleObstacle((1067.0, 520.0), 120.0),
        po.PolygonObstacle([[1000, -600], [1150, -600], [1150, -450], [1000, -450]]),
        po.AreaBounds(-750, 2150, -650, 650),
        po.SpeedLimit(30.0),
    )
    settings = PlannerSettings(method="pmht", iterations=8, options={"anneal": None}, return_to_base=True)
    result = plan_mission(Mission(sc, constraints, settings, FIJI))
    path = export_geojson(result, tmp_path_factory.mktemp("fiji") / "fiji.geojson", FIJI)
    return result, json.loads(path.read_text()), path


def _of(obj: dict[str, Any], kind: str) -> list[dict[str, Any]]:
    return [f for f in obj["features"] if f["properties"]["kind"] == kind]


def _unwrapped(lon: np.ndarray) -> np.ndarray:
    """Longitudes east of the antimeridian as 180 and more, for arithmetic across it."""
    return np.where(np.asarray(lon) < 0, np.asarray(lon) + 360.0, lon)


def test_a_path_across_the_antimeridian_is_cut_where_it_meets_it(
    fiji: tuple[po.PlanResult, dict[str, Any], Path],
) -> None:
    result, obj, file = fiji
    check_rfc7946(obj)  # the validator, closed counter-clockwise rings, no jump across 180
    (feature,) = _of(obj, "path")
    assert feature["geometry"]["type"] == "MultiLineString"
    parts = lines(feature["geometry"])
    assert len(parts) == 3  # out across the meridian and back
    assert [p[-1, 0] for p in parts[:-1]] == [180.0, -180.0] and [p[0, 0] for p in parts[1:]] == [
        -180.0,
        180.0,
    ]
    # Each cut is where the planned segment that crosses meets longitude 180, at the latitude found by
    # interpolating along it.
    latlon = FIJI.plane.to_geodetic(result.positions[0])
    lon = _unwrapped(latlon[:, 1])
    crossing = np.flatnonzero(np.diff(np.sign(lon - 180.0)) != 0)
    assert crossing.size == 2
    for cut, t in zip(parts[:-1], crossing, strict=True):
        share = (180.0 - lon[t]) / (lon[t + 1] - lon[t])
        assert abs(cut[-1, 1] - (latlon[t, 0] + share * (latlon[t + 1, 0] - latlon[t, 0]))) <= 1e-9
    # The file reads back to the plan's positions (the cuts are not positions of the plan).
    (back,) = read_geojson_paths(file, FIJI)
    assert back.shape == result.positions[0].shape
    assert np.max(np.abs(back - result.positions[0])) < 1e-3
    # The box crosses the antimeridian: west of it is greater than east (RFC 7946 section 5.2).
    west, south, east, north = obj["bbox"]
    assert west > east and 179.9 < west < 180 and -180 < east < -179.9 and south < north
    every = np.array(
        [c for f in obj["features"] for part in lines(f["geometry"]) + rings(f["geometry"]) for c in part]
    )
    assert np.all((every[:, 0] >= west) | (every[:, 0] <= east))
    sites = np.array(read_points(file, Frame(FIJI), "locale"))
    assert np.max(np.abs(sites - result.scenario.locales)) < 1e-3


def test_polygons_across_the_antimeridian_are_cut_into_counter_clockwise_pieces(
    fiji: tuple[po.PlanResult, dict[str, Any], Path],
) -> None:
    result, obj, _ = fiji
    counts = {k: len(_of(obj, k)) for k in ("bounds", "area_bounds", "keep_out", "coverage")}
    assert counts == {"bounds": 1, "area_bounds": 1, "keep_out": 2, "coverage": 3}
    straddling = [
        *_of(obj, "bounds"),
        *_of(obj, "area_bounds"),
        *_of(obj, "keep_out"),
        _of(obj, "coverage")[2],
    ]
    for feature in straddling:
        pieces = rings(feature["geometry"])
        assert feature["geometry"]["type"] == "MultiPolygon" and len(pieces) == 2
        west, east = sorted(pieces, key=lambda r: -r[:, 0].max())
        assert west[:, 0].max() == 180.0 and east[:, 0].min() == -180.0
        assert np.all(west[:, 0] > 0) and np.all(east[:, 0] < 0)
        # The pieces make up the whole: their areas add up to the unsplit ring's.
        whole = np.concatenate([west[:-1], east[:-1]])
        whole[:, 0] = _unwrapped(whole[:, 0])
        pieces_area = shoelace(west[:-1]) + shoelace(
            np.column_stack([_unwrapped(east[:-1, 0]), east[:-1, 1]])
        )
        hull_area = _hull_area(whole)
        assert abs(pieces_area - hull_area) <= 1e-9 * hull_area
    # Footprints away from the meridian are single polygons, inscribed in their discs.
    for feature, site in zip(_of(obj, "coverage")[:2], result.scenario.locales[:2], strict=True):
        (ring,) = rings(feature["geometry"])
        corners = FIJI.plane.to_local(ring[:-1, ::-1])
        assert len(corners) == CIRCLE_SIDES
        assert np.allclose(np.hypot(*(corners - site).T), 80.0, atol=1e-3)


def _hull_area(points: np.ndarray) -> float:
    """Twice the area of the convex hull of ``points`` (gift wrapping by angle about the centroid)."""
    c = points.mean(axis=0)
    order = np.argsort(np.arctan2(points[:, 1] - c[1], points[:, 0] - c[0]))
    return shoelace(points[order])


def test_lines_cut_at_the_meridian_read_back_whole() -> None:
    """Lines that cross and come back, touch it, start on it or cross it at a vertex, either side of
    the globe, read back to their own positions."""
    for lon0, meridian in ((179.99, 180.0), (-179.99, -180.0)):
        globe = Globe(lon0)
        east = 1 if meridian > 0 else -1
        cases = {
            "there and back": [(-16.5, lon0), (-16.49, lon0 + east * 0.02), (-16.48, lon0)],
            "on the meridian at a vertex": [(-16.5, lon0), (-16.49, meridian), (-16.48, lon0 + east * 0.02)],
            "touching": [(-16.5, lon0), (-16.49, meridian), (-16.48, lon0)],
            "from the meridian": [(-16.49, meridian), (-16.48, lon0 + east * 0.02)],
            "one side": [(-16.5, lon0), (-16.49, lon0 + east * 0.001)],
        }
        for name, points in cases.items():
            latlon = np.array(points)
            latlon[:, 1] = (latlon[:, 1] + 180.0) % 360.0 - 180.0  # as the plane's conversion gives them
            geometry = globe.line(latlon)
            feature = {"type": "Feature", "properties": {"kind": "path"}, "geometry": geometry}
            check_rfc7946({"type": "FeatureCollection", "features": [feature]})
            back = line_positions(geometry)
            want = np.column_stack([latlon[:, 1], latlon[:, 0]])
            same = np.isclose(np.abs(back[:, 0]), 180.0) & np.isclose(np.abs(want[:, 0]), 180.0)
            assert back.shape == want.shape, name
            assert np.all(same | np.isclose(back[:, 0], want[:, 0], atol=1e-9)), name
            assert np.allclose(back[:, 1], want[:, 1], atol=1e-9), name
        assert globe.line(np.array(cases["one side"]))["type"] == "LineString"
        assert len(globe.line(np.array(cases["there and back"]))["coordinates"]) == 3


def test_plane_files_draw_the_zones_areas_and_footprints(tmp_path: Path) -> None:
    sc = po.paper_scenario("A", seed=1, horizon=40)
    zones = (
        po.CircleObstacle((5.0, 5.0), 0.8),
        po.PolygonObstacle([[2.0, 7.0], [3.0, 7.0], [3.0, 8.0]], platforms=[1]),
        po.AreaBounds(-1.0, 11.0, -1.0, 11.0),
    )
    result = po.plan_pmht(sc, po.PMHTConfig(max_iter=3, constraints=list(zones)))
    obj = json.loads(export_geojson(result, tmp_path / "p.geojson").read_text())
    check_rfc7946(obj, geo=False)
    (circle, triangle) = _of(obj, "keep_out")
    assert circle["properties"]["shape"] == "circle" and circle["properties"]["platforms"] is None
    assert circle["properties"]["center"] == [5.0, 5.0] and circle["properties"]["radius"] == 0.8
    assert triangle["properties"] == {
        "kind": "keep_out",
        "constraint": zones[1].name,
        "shape": "polygon",
        "platforms": [1],
    }
    # A keep-out polygon holds its whole disc (every edge at least the radius from the centre); a
    # footprint lies inside its disc (every corner on the circle).
    (ring,) = rings(circle["geometry"])
    a, b = ring[:-1], ring[1:]
    edge = b - a
    rel = a - [5.0, 5.0]
    reach = np.abs(edge[:, 0] * rel[:, 1] - edge[:, 1] * rel[:, 0]) / np.hypot(*edge.T)
    assert np.all(reach >= 0.8 - 1e-12) and np.all(reach <= 0.8 * (1 + 1e-3))
    (tri,) = rings(triangle["geometry"])
    assert {tuple(p) for p in tri[:-1]} == {(2.0, 7.0), (3.0, 7.0), (3.0, 8.0)}
    for feature, site, radius in zip(_of(obj, "coverage"), sc.locales, sc.radii, strict=True):
        (ring,) = rings(feature["geometry"])
        assert np.allclose(np.hypot(*(ring - site).T), radius) and feature["properties"]["radius"] == radius
    (area,) = _of(obj, "area_bounds")
    (box,) = rings(area["geometry"])
    assert box.min(axis=0).tolist() == [-1.0, -1.0] and box.max(axis=0).tolist() == [11.0, 11.0]
    assert obj["features"][-1]["properties"]["kind"] == "start"


def test_the_validator_is_no_rubber_stamp(fiji: tuple[po.PlanResult, dict[str, Any], Path]) -> None:
    """The independent validator finds a clockwise ring and an open one in an otherwise valid file."""
    _, obj, _ = fiji
    assert validator_findings(obj) == {}
    for spoil, criterion in ((lambda r: r.reverse(), "exterior_not_ccw"), (lambda r: r.pop(), "unclosed")):
        bad = copy.deepcopy(obj)
        feature = _of(bad, "coverage")[0]
        spoil(feature["geometry"]["coordinates"][0])
        assert criterion in validator_findings(bad).get("invalid", {})
    with pytest.raises(AssertionError):
        check_rfc7946(bad)
