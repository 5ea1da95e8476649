"""QGroundControl exports keep the plan's promises as flown: legs measured on the file read back.

A drone flies straight legs between waypoints. Every test here reads the written ``.plan`` back
(:func:`read_qgc_plan`), takes the legs between its waypoints and measures them with the test's own
segment geometry (and the constraints' exact ``segment_depth``), not with the exporter's.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.exceptions import ConfigError, SolverError
from pmht_opt.geometry import COVERAGE_RTOL
from pmht_opt.geometry.earth import GeoOrigin
from pmht_opt.io import Mission, PlannerSettings, export_qgc_plan, plan_mission, read_qgc_plan
from pmht_opt.io.flight import plan_promises
from pmht_opt.io.frame import GEO_RESOLUTION
from pmht_opt.io.waypoints import simplify

ORIGIN = GeoOrigin(-35.36, 149.16)
#: Commands at the end of a mission.
RTL, LAND, WAYPOINT = 20, 21, 16


def seg_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from the point ``p`` to each segment ``a[k] -> b[k]`` (the tests' own geometry)."""
    d = b - a
    s = np.clip(np.sum((p - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
    return np.hypot(*(a + s[:, None] * d - p).T)


def legs_of(file: Path, origin: GeoOrigin = ORIGIN) -> np.ndarray:
    """The waypoints of a written plan, read back, in the mission's plane."""
    return origin.plane.to_local(read_qgc_plan(file)["waypoints"][:, :2])


def items_of(file: Path) -> list[dict[str, Any]]:
    items: list[dict[str, Any]] = json.loads(file.read_text())["mission"]["items"]
    return items


# --------------------------------------------------------------------------------- missions


def grazing_mission(zone: po.Constraint, **planner: Any) -> Mission:
    """One drone from (-900, 0) to a site at (900, 0), round a keep-out zone whose near side crosses
    the straight line: the smooth path bends round it, touching it."""
    sc = po.Scenario(
        locales=np.array([[900.0, 0.0]]),
        starts=np.array([[-900.0, 0.0]]),
        horizon=100,
        dt=2.0,
        q=6.3e-5,
        r=1600.0,
        coverage_radius=60.0,
        bounds=(-1000.0, 1000.0, -500.0, 500.0),
        name="graze",
    )
    settings = PlannerSettings(method="pmht", iterations=8, options={"anneal": None}, **planner)
    return Mission(sc, (zone, po.SpeedLimit(20.0), po.AreaBounds(-1000, 1000, -500, 500)), settings, ORIGIN)


@pytest.fixture(scope="module")
def grazed() -> tuple[po.PlanResult, po.CircleObstacle]:
    zone = po.CircleObstacle((0.0, -80.0), 300.0)
    return plan_mission(grazing_mission(zone)), zone


def ring_mission(method: str) -> Mission:
    """Two drones, six sites round them, a speed limit and a return to base."""
    sites = np.array([[-500, 300], [0, 450], [450, 250], [500, -300], [0, -450], [-450, -250.0]])
    sc = po.Scenario(
        locales=sites,
        starts=np.array([[-100.0, 0.0], [100.0, 0.0]]),
        horizon=120,
        dt=2.0,
        q=6.3e-5,
        r=1600.0,
        coverage_radius=80.0,
        bounds=(-700.0, 700.0, -600.0, 600.0),
        name="ring",
    )
    settings = PlannerSettings(method=method, iterations=10, return_to_base=True)
    return Mission(sc, (po.SpeedLimit(15.0),), settings, ORIGIN)


@pytest.fixture(scope="module")
def covering() -> po.PlanResult:
    return plan_mission(ring_mission("coverage"))


def covered_on_legs(result: po.PlanResult, files: list[Path]) -> np.ndarray:
    """Each site's distance beyond its radius (with the stated slack) from every leg read back."""
    sc = result.scenario
    lines = [legs_of(f) for f in files]
    near = np.array(
        [
            min(
                seg_distance(site, w[:-1], w[1:]).min() if len(w) > 1 else np.hypot(*(w[0] - site))
                for w in lines
            )
            for site in sc.locales
        ]
    )
    return near - (sc.radii * (1 + COVERAGE_RTOL) + GEO_RESOLUTION)


# ------------------------------------------------------------------------------- keep-out zones


def test_legs_keep_out_of_a_zone_the_smooth_path_grazes(
    tmp_path: Path, grazed: tuple[po.PlanResult, po.CircleObstacle]
) -> None:
    result, zone = grazed
    path = result.positions[0]
    assert zone.segment_depth(path[:-1], path[1:]).max() <= 1e-6 * zone.radius  # the plan keeps out
    # The simplification alone cuts the corner: its legs enter the zone by metres.
    tol = result.scenario.coverage_radius / 10
    old = path[simplify(path, tol, keep=[int(np.argmin(np.hypot(*(path - result.scenario.locales[0]).T)))])]
    assert zone.segment_depth(old[:-1], old[1:]).max() > 1.0
    files = export_qgc_plan(result, tmp_path / "g.plan", ORIGIN, end="land")
    flight = files.flights[0]
    assert flight.route.added > 0
    # The exporter's own measure, then the file read back, measured with the tests' geometry.
    assert plan_promises(result, GEO_RESOLUTION).first_breach(0, flight.route.waypoints) is None
    wp = legs_of(files[0])
    assert np.allclose(wp, flight.route.waypoints, atol=1e-6)
    assert seg_distance(zone.center, wp[:-1], wp[1:]).min() >= zone.radius - GEO_RESOLUTION
    assert zone.segment_depth(wp[:-1], wp[1:]).max() <= GEO_RESOLUTION
    assert np.all(np.abs(wp[:, 0]) <= 1000 + GEO_RESOLUTION) and np.all(
        np.abs(wp[:, 1]) <= 500 + GEO_RESOLUTION
    )
    # The legs stay near the path, and the reported distance says how near.
    assert flight.deviation <= tol + 0.5
    assert flight.deviation >= np.max(po.geometry.point_polyline_distance(path, wp)) - 1e-6


def test_legs_keep_out_of_a_polygon_the_path_hugs(tmp_path: Path, covering: po.PlanResult) -> None:
    """Platform 0 drawn round three sides of a 12-sided keep-out zone, 5 m off its edges: the chords of
    a simplification cut its corners; the exported legs keep out."""
    n, apothem, offset = 12, 300.0, 5.0
    corner = apothem / math.cos(math.pi / n)
    vertex_angle = np.arange(n) * 2 * np.pi / n
    rel = corner * np.column_stack([np.cos(vertex_angle), np.sin(vertex_angle)])
    angle = np.linspace(-0.6 - np.pi / 2, np.pi / 2 + 0.6, covering.scenario.horizon + 1)
    facing = np.floor((angle - np.pi / n) / (2 * np.pi / n) + 0.5) * (2 * np.pi / n) + np.pi / n
    reach = (apothem + offset) / np.cos(angle - facing)  # on the line 5 m off the edge it faces
    arc = reach[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    center = covering.scenario.start_positions[0] - arc[0]
    zone = po.PolygonObstacle(center + rel, platforms=[0])
    states = covering.states.copy()
    states[0, :, [0, 3]] = (center + arc).T
    states[1] = states[1, :1]  # platform 1 stays at its start
    result = dataclasses.replace(covering, states=states, constraints=(zone,), planner="pmht")
    path = result.positions[0]
    assert zone.segment_depth(path[:-1], path[1:]).max() == 0  # the plan keeps out
    old = path[simplify(path, 15.0)]
    assert zone.segment_depth(old[:-1], old[1:]).max() > 1.0
    files = export_qgc_plan(result, tmp_path / "p.plan", ORIGIN, tolerance=15.0, end="hover")
    wp = legs_of(files[0])
    assert len(wp) > len(old) and files.flights[0].route.added > 0
    assert zone.segment_depth(wp[:-1], wp[1:]).max() <= GEO_RESOLUTION
    # The tests' own measure: no leg reaches past 1e-4 m inside any edge's line (a leg enters a convex
    # polygon exactly when some point of it is inside every edge's line).
    inward = -zone.normals  # the constraint's outward normals, reversed
    for a, b in itertools.pairwise(wp):
        s = np.linspace(0.0, 1.0, 2001)[:, None]
        depth = np.min((a + s * (b - a)) @ inward.T + zone.offsets, axis=1)
        assert depth.max() <= GEO_RESOLUTION


def test_a_plan_that_breaks_a_zone_is_refused_naming_platform_leg_and_constraint(
    tmp_path: Path, grazed: tuple[po.PlanResult, po.CircleObstacle]
) -> None:
    result, zone = grazed
    states = result.states.copy()
    states[0, 40:43, [0, 3]] = zone.center[:, None]  # through the zone's centre
    broken = dataclasses.replace(result, states=states)
    with pytest.raises(SolverError, match=r"^platform 0, leg \d+ of \d+ .*CircleObstacle\(\(0, -80\), 300\)"):
        export_qgc_plan(broken, tmp_path / "b.plan", ORIGIN, end="land")
    assert not list(tmp_path.iterdir())


def test_a_return_to_launch_through_a_zone_is_refused(
    tmp_path: Path, grazed: tuple[po.PlanResult, po.CircleObstacle]
) -> None:
    """The plan ends at the site, across the zone from home: the straight leg home would cross it."""
    result, _ = grazed
    with pytest.raises(
        SolverError, match=r"platform 0: the return to launch.*CircleObstacle.*'land' or 'hover'"
    ):
        export_qgc_plan(result, tmp_path / "r.plan", ORIGIN)  # the default end: rtl, away from home
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------------- the end


def test_missions_end_as_asked(tmp_path: Path, grazed: tuple[po.PlanResult, po.CircleObstacle]) -> None:
    result, _ = grazed
    ends = {}
    for end in ("land", "hover"):
        (file,) = export_qgc_plan(result, tmp_path / f"{end}.plan", ORIGIN, end=end)
        ends[end] = items_of(file)
        assert read_qgc_plan(file)["end"] == end
    land = ends["land"][-1]
    assert land["command"] == LAND and land["params"][4:6] == ends["land"][-2]["params"][4:6]
    assert ends["hover"][-1]["command"] == WAYPOINT
    assert ends["hover"][:-1] == ends["land"][:-2] and ends["hover"][-1] == ends["land"][-2]
    # Without the zone on the way home, a return to launch: MAVLink 20, no position, the default here.
    clear = dataclasses.replace(result, constraints=())
    (file,) = export_qgc_plan(clear, tmp_path / "rtl.plan", ORIGIN)
    rtl = items_of(file)[-1]
    assert (rtl["command"], rtl["frame"], rtl["params"]) == (RTL, 2, [0, 0, 0, 0, 0, 0, 0])
    assert read_qgc_plan(file)["end"] == "rtl"


def test_a_return_to_base_lands_at_home_by_default(tmp_path: Path, covering: po.PlanResult) -> None:
    files = export_qgc_plan(covering, tmp_path / "c.plan", ORIGIN)
    for m, file in enumerate(files):
        items = items_of(file)
        assert items[-1]["command"] == LAND
        home = ORIGIN.plane.to_local([items[-1]["params"][4:6]])[0]
        assert np.hypot(*(home - covering.scenario.start_positions[m])) < 1e-3
    assert [f.end for f in files.flights] == ["land", "land"]


def test_the_older_land_option_still_works_and_contradictions_are_refused(
    tmp_path: Path, covering: po.PlanResult
) -> None:
    (one, *_) = export_qgc_plan(covering, tmp_path / "a.plan", ORIGIN, land=True)
    assert items_of(one)[-1]["command"] == LAND
    (two, *_) = export_qgc_plan(covering, tmp_path / "b.plan", ORIGIN, land=False)
    assert items_of(two)[-1]["command"] == WAYPOINT  # land=False always meant: no landing
    (three, *_) = export_qgc_plan(covering, tmp_path / "c.plan", ORIGIN, land=True, end="land")
    assert items_of(three)[-1]["command"] == LAND
    with pytest.raises(ConfigError, match=r"^land: land=True asks for end 'land', but end='rtl'"):
        export_qgc_plan(covering, tmp_path / "x.plan", ORIGIN, land=True, end="rtl")
    for bad, field in (({"end": "fly"}, "end"), ({"end": 1}, "end"), ({"source": "path"}, "source")):
        with pytest.raises(ConfigError, match=f"^{field}: expected one of"):
            export_qgc_plan(covering, tmp_path / "x.plan", ORIGIN, **bad)
    assert not list(tmp_path.glob("x*"))


# ----------------------------------------------------------------------------------- the speed


def test_cruise_speed_is_the_speed_limit(tmp_path: Path, covering: po.PlanResult) -> None:
    def speeds(result: po.PlanResult, **options: Any) -> list[float]:
        files = export_qgc_plan(result, tmp_path / "s.plan", ORIGIN, **options)
        out = []
        for file in files:
            mission = json.loads(file.read_text())["mission"]
            change = [i for i in mission["items"] if i["command"] == 178]
            assert len(change) == 1 and change[0]["params"][:2] == [1, mission["cruiseSpeed"]]
            assert read_qgc_plan(file)["speed"] == mission["cruiseSpeed"] == mission["hoverSpeed"]
            out.append(mission["cruiseSpeed"])
        return out

    assert speeds(covering) == [15.0, 15.0]
    # The smallest limit that binds each platform, soft ones too.
    limits = (po.SpeedLimit(15.0), po.SpeedLimit([12.0, 20.0]), po.SpeedLimit(9.0, platforms=[1], soft=True))
    assert speeds(dataclasses.replace(covering, constraints=limits)) == [12.0, 9.0]
    assert speeds(covering, speed=6.5) == [6.5, 6.5]  # --speed overrides, within the limit
    with pytest.raises(ConfigError, match=r"^speed: 16 m/s is above platform 0's speed limit 15 m/s"):
        export_qgc_plan(covering, tmp_path / "x.plan", ORIGIN, speed=16.0)
    # Without a limit, each platform's mean planned speed, as before.
    free = dataclasses.replace(covering, constraints=())
    mean = free.distance_per_platform / (free.scenario.horizon * free.scenario.dt)
    assert np.allclose(speeds(free)[:1], mean[:1], atol=1e-3)


# ----------------------------------------------------------------------------------- coverage


@pytest.mark.parametrize("method", ["coverage", "smoothed"])
def test_covering_planners_export_flights_that_cover_every_site(
    tmp_path: Path, covering: po.PlanResult, method: str
) -> None:
    result = covering if method == "coverage" else plan_mission(ring_mission(method))
    assert result.planner == method and result.missed_locales().size == 0
    files = export_qgc_plan(result, tmp_path / f"{method}.plan", ORIGIN)
    assert np.all(covered_on_legs(result, files) <= 0)


def test_sites_the_simplified_legs_would_miss_get_waypoints(tmp_path: Path, covering: po.PlanResult) -> None:
    """With a coarse tolerance and no site kept by assignment, the simplification's legs pass sites far
    off; the exporter adds the path's nearest segments until every leg read back covers them."""
    result = dataclasses.replace(covering, assignment=np.full(covering.scenario.n_locales, 1))
    rough = [p[simplify(p, 400.0)] for p in result.positions]
    sc = result.scenario
    far = [
        min(seg_distance(s, w[:-1], w[1:]).min() for w in rough if len(w) > 1) - r
        for s, r in zip(sc.locales, sc.radii, strict=True)
    ]
    assert max(far) > 50  # the simplification alone misses sites by far
    files = export_qgc_plan(result, tmp_path / "r.plan", ORIGIN, tolerance=400.0)
    assert np.all(covered_on_legs(result, files) <= 0)
    assert sum(f.route.added for f in files.flights) > 0


def test_a_plan_that_misses_a_site_is_refused(tmp_path: Path, covering: po.PlanResult) -> None:
    sc = covering.scenario
    moved = dataclasses.replace(covering, scenario=sc.replace(locales=sc.locales + np.array([0.0, 300.0])))
    with pytest.raises(SolverError, match=r"^site \d+ is .* from every planned path"):
        export_qgc_plan(moved, tmp_path / "m.plan", ORIGIN)
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------ the tour


def test_the_tour_is_a_shorter_waypoint_mission_that_covers_every_site(
    tmp_path: Path, covering: po.PlanResult
) -> None:
    tours = export_qgc_plan(covering, tmp_path / "t.plan", ORIGIN, source="tour")
    plans = export_qgc_plan(covering, tmp_path / "p.plan", ORIGIN)
    assert np.all(covered_on_legs(covering, tours) <= 0)
    for m, (tour_file, plan_file) in enumerate(zip(tours, plans, strict=True)):
        wp = legs_of(tour_file)
        own = np.asarray(covering.extras["tour"][m])
        keep = np.r_[True, np.any(np.diff(own, axis=0) != 0, axis=1)]
        assert np.allclose(wp, own[keep], atol=1e-3)  # the tour's own corners, in order
        assert len(wp) <= len(legs_of(plan_file))
        length = np.hypot(*np.diff(wp, axis=0).T).sum()
        assert length <= covering.distance_per_platform[m] + 1e-6
        assert items_of(tour_file)[-1]["command"] == LAND  # the closed tour ends at home
    assert tours.deviation.shape == (2,) and tours.deviation.max() > 0


def test_the_tour_is_refused_without_one_or_across_a_zone(
    tmp_path: Path, covering: po.PlanResult, grazed: tuple[po.PlanResult, po.CircleObstacle]
) -> None:
    with pytest.raises(ConfigError, match=r"^source: 'tour' .* the pmht planner has none"):
        export_qgc_plan(grazed[0], tmp_path / "x.plan", ORIGIN, source="tour")
    tour = np.asarray(covering.extras["tour"][0])
    middle = 0.5 * (tour[1] + tour[2])  # a zone on the tour's second leg
    zone = po.CircleObstacle(middle, 20.0)
    blocked = dataclasses.replace(covering, constraints=(zone,))
    with pytest.raises(
        SolverError, match=r"^platform 0, leg 1 of \d+ .*CircleObstacle.* the tour has no other"
    ):
        export_qgc_plan(blocked, tmp_path / "x.plan", ORIGIN, source="tour")
    assert not list(tmp_path.iterdir())
