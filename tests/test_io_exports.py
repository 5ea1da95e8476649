"""Exports: CSV and GeoJSON read back to the plan; QGroundControl plans checked against the format's
documented keys and their waypoints against the paths."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geojson_checks import check_rfc7946

import pmht_opt as po
from pmht_opt.exceptions import ConfigError
from pmht_opt.geometry import point_polyline_distance
from pmht_opt.io import (
    example_mission,
    export_csv,
    export_geojson,
    export_qgc_plan,
    plan_mission,
    read_geojson_paths,
    read_plan_csv,
    read_points,
    read_qgc_plan,
)
from pmht_opt.io.frame import Frame
from pmht_opt.io.geojson import positions
from pmht_opt.io.qgc import ITEM_KEYS, MISSION_KEYS, PLAN_KEYS, simplify


@pytest.fixture(scope="module")
def plane_plan() -> po.PlanResult:
    sc = po.paper_scenario("C", seed=2, horizon=60)
    return po.plan_pmht(sc, po.PMHTConfig(max_iter=4))


@pytest.fixture(scope="module")
def geo_plan() -> tuple[po.PlanResult, Any]:
    mission = example_mission("survey")
    mission.planner = mission.planner.replace(iterations=6)
    return plan_mission(mission), mission.origin


def _strict_json(path: Path) -> Any:
    def refuse(name: str) -> None:
        raise AssertionError(f"{path.name} holds {name}, which is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_csv_round_trips_the_states(tmp_path: Path, plane_plan: po.PlanResult) -> None:
    path = export_csv(plane_plan, tmp_path / "plan.csv")
    header = path.read_text().splitlines()[0].split(",")
    assert header == ["platform", "step", "time", "x", "y", "vx", "vy", "ax", "ay"]
    M, T1, _ = plane_plan.states.shape
    assert len(path.read_text().splitlines()) == 1 + M * T1
    assert np.array_equal(read_plan_csv(path), plane_plan.states)


def test_csv_of_a_geo_plan_adds_latitude_and_longitude(
    tmp_path: Path, geo_plan: tuple[po.PlanResult, Any]
) -> None:
    result, origin = geo_plan
    path = export_csv(result, tmp_path / "geo.csv", origin)
    rows = path.read_text().splitlines()
    assert rows[0].endswith(",lat,lon")
    first = rows[1 + 5].split(",")  # platform 0, step 5
    assert float(first[2]) == 5 * result.scenario.dt
    lat, lon = float(first[-2]), float(first[-1])
    assert np.allclose(origin.plane.to_local([[lat, lon]])[0], result.positions[0, 5], atol=1e-6)
    assert np.array_equal(read_plan_csv(path), result.states)


def _check_geojson_object(obj: dict[str, Any], geo: bool) -> None:
    """RFC 7946's structure: a FeatureCollection of Features with geometry and properties, valid under an
    independent validator (tests/geojson_checks.py), with closed counter-clockwise rings."""
    assert obj["type"] == "FeatureCollection" and "crs" not in obj
    for f in obj["features"]:
        assert f["type"] == "Feature" and set(f) >= {"geometry", "properties"}
        assert f["geometry"]["type"] in ("Point", "LineString", "MultiLineString", "Polygon", "MultiPolygon")
    check_rfc7946(obj, geo)
    if geo:
        west, south, east, north = obj["bbox"]
        every = np.array([c for f in obj["features"] for c in positions(f["geometry"])])
        assert np.allclose([west, south], every.min(axis=0)) and np.allclose([east, north], every.max(axis=0))


def test_geojson_round_trips_paths_locales_and_starts(tmp_path: Path, plane_plan: po.PlanResult) -> None:
    path = export_geojson(plane_plan, tmp_path / "plan.geojson")
    obj = _strict_json(path)
    _check_geojson_object(obj, geo=False)
    assert obj["pmht_opt"]["frame"] == "plane"
    paths = read_geojson_paths(path)
    assert np.array_equal(np.stack(paths), plane_plan.positions)
    sc = plane_plan.scenario
    assert np.array_equal(read_points(path, kind="locale"), sc.locales)
    assert np.array_equal(read_points(path, kind="start"), sc.start_positions)
    locales = [f["properties"] for f in obj["features"] if f["properties"]["kind"] == "locale"]
    assert [p["platform"] for p in locales] == plane_plan.assignment.tolist()
    assert [p["visit_step"] for p in locales] == plane_plan.visit_time.tolist()
    assert np.allclose([p["miss_distance"] for p in locales], plane_plan.miss_distance)
    assert sum(not p["covered"] for p in locales) == plane_plan.missed_locales().size


def test_geojson_of_a_geo_plan_is_wgs84(tmp_path: Path, geo_plan: tuple[po.PlanResult, Any]) -> None:
    result, origin = geo_plan
    path = export_geojson(result, tmp_path / "geo.geojson", origin)
    obj = _strict_json(path)
    _check_geojson_object(obj, geo=True)
    assert obj["pmht_opt"]["frame"] == "wgs84"
    paths = read_geojson_paths(path, origin)
    assert np.max(np.abs(np.stack(paths) - result.positions)) < 1e-3  # metres (1e-9 degrees written)
    frame = Frame(origin)
    assert np.max(np.abs(np.array(read_points(path, frame, "locale")) - result.scenario.locales)) < 1e-3
    lon, lat = obj["features"][-1]["geometry"]["coordinates"]  # the last start
    assert abs(lat + 35.3745) < 0.01 and abs(lon - 149.18) < 0.01


def test_simplify_keeps_ends_and_required_points_within_tolerance() -> None:
    t = np.linspace(0, 2 * np.pi, 400)
    pts = np.column_stack([np.cos(t), np.sin(3 * t)])
    keep = simplify(pts, 0.01, keep=[123])
    assert keep[0] == 0 and keep[-1] == 399 and 123 in keep and np.all(np.diff(keep) > 0)
    assert point_polyline_distance(pts, pts[keep]).max() <= 0.01
    assert len(keep) < 100


def test_qgc_plans_follow_the_documented_format_and_the_paths(
    tmp_path: Path, geo_plan: tuple[po.PlanResult, Any]
) -> None:
    result, origin = geo_plan
    files = export_qgc_plan(result, tmp_path / "survey.plan", origin, altitude=55.0)
    assert [f.name for f in files] == ["survey-0.plan", "survey-1.plan", "survey-2.plan"]
    tolerance = result.scenario.coverage_radius / 10
    for m, file in enumerate(files):
        plan = _strict_json(file)
        assert set(plan) >= set(PLAN_KEYS)
        assert (plan["fileType"], plan["version"]) == ("Plan", 1)
        mission = plan["mission"]
        assert set(mission) >= set(MISSION_KEYS) and mission["version"] == 2
        assert (mission["firmwareType"], mission["vehicleType"]) == (12, 2)  # PX4, quadrotor
        home = mission["plannedHomePosition"]
        assert len(home) == 3 and np.allclose(
            origin.plane.to_local([home[:2]]), result.positions[m, 0], atol=1e-3
        )
        items = mission["items"]
        assert [i["doJumpId"] for i in items] == list(range(1, len(items) + 1))
        for item in items:
            assert set(item) >= set(ITEM_KEYS) and item["type"] == "SimpleItem" and len(item["params"]) == 7
            assert item["autoContinue"] is True
        assert [i["command"] for i in items[:2]] == [22, 178]  # take off, then set the speed
        assert all(i["command"] == 16 and i["frame"] == 3 for i in items[2:-1])
        assert items[-1]["command"] == 21  # the survey returns to base: it lands there
        flown = [i for i in items if i["frame"] == 3 and i["command"] != 21]
        assert all(i["params"][6] == 55.0 and i["Altitude"] == 55.0 for i in flown)
        assert items[-1]["params"][6] == 0.0 and items[-1]["params"][4:6] == items[-2]["params"][4:6]
        speed = items[1]["params"]
        assert speed[0] == 1 and speed[1] == 10.0 and mission["cruiseSpeed"] == 10.0  # the speed limit
        # Waypoints are points of the path, in its order, and the legs between them follow it.
        read = read_qgc_plan(file)
        wp = origin.plane.to_local(read["waypoints"][:, :2])
        path = result.positions[m]
        steps, after = [], 0
        for w in wp:  # in order: a path that comes back passes near its own points twice
            close = np.flatnonzero(np.hypot(*(path[after:] - w).T) < 1e-3)
            assert close.size, f"waypoint {w} is on no later point of platform {m}'s path"
            steps.append(after + int(close[0]))
            after = steps[-1] + 1
        # From the start to where the path ends (it may get there early and wait: no waypoint then).
        assert steps[0] == 0 and np.hypot(*(path[-1] - wp[-1])) < 1e-3
        assert point_polyline_distance(path, wp).max() <= tolerance + 1e-3
        # Every locale the platform is assigned has a waypoint at its nearest point of the path.
        for n in np.flatnonzero(result.assignment == m):
            nearest = int(np.argmin(np.hypot(*(path - result.scenario.locales[n]).T)))
            assert nearest in steps


def test_qgc_options_and_refusals(tmp_path: Path, geo_plan: tuple[po.PlanResult, Any]) -> None:
    result, origin = geo_plan
    (file, *_) = export_qgc_plan(
        result, tmp_path / "r.plan", origin, speed=4.0, land=True, firmware="ardupilot", vehicle="multirotor"
    )
    plan = _strict_json(file)
    items = plan["mission"]["items"]
    assert (
        plan["mission"]["firmwareType"] == 3 and items[1]["params"][1] == 4.0 and items[-1]["command"] == 21
    )
    (rover, *_) = export_qgc_plan(result, tmp_path / "v.plan", origin, vehicle="rover")
    assert _strict_json(rover)["mission"]["items"][0]["command"] == 178  # rovers do not take off
    with pytest.raises(ConfigError, match="vehicle: expected one of"):
        export_qgc_plan(result, tmp_path / "x.plan", origin, vehicle="blimp")
    with pytest.raises(ConfigError, match="needs a geo-referenced mission"):
        export_qgc_plan(result, tmp_path / "x.plan", None)  # type: ignore[arg-type]
    bad: list[tuple[dict[str, Any], str]] = [
        ({"altitude": True}, "altitude"),
        ({"speed": True}, "speed"),
        ({"tolerance": "x"}, "tolerance"),
        ({"tolerance": 0.0}, "tolerance"),
        ({"takeoff": "no"}, "takeoff"),
        ({"land": "yes"}, "land"),
        ({"firmware": ["px4"]}, "firmware"),
    ]
    for options, field in bad:
        with pytest.raises(ConfigError, match=f"^{field}: expected"):
            export_qgc_plan(result, tmp_path / "x.plan", origin, **options)
    with pytest.raises(ConfigError, match="result: expected a PlanResult, got NoneType"):
        export_qgc_plan(None, tmp_path / "x.plan", origin)
    assert not list(tmp_path.glob("x*.plan"))
