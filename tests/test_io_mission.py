"""Mission files: every part read with the library's own checks, typed values, written back the same."""

from __future__ import annotations

import inspect
import json
import re
from pathlib import Path

import numpy as np
import pytest

import pmht_opt as po
from pmht_opt.exceptions import ConfigError, PmhtOptError, ScenarioError
from pmht_opt.geometry.earth import GeoOrigin
from pmht_opt.io import (
    Mission,
    PlannerSettings,
    example_mission,
    load_mission,
    mission_from_dict,
    read_points,
    save_mission,
)
from pmht_opt.io.constraints import COMMON, KINDS
from pmht_opt.io.frame import Frame
from pmht_opt.io.settings import read_settings

#: The model's q and r given as the library's defaults (a mission without them takes its own, scaled to
#: its units: tested below).
BASE = """
name = "small"
horizon = 40
q = 1e-8
r = 0.01
locales = [[1.0, 1.0], [3.0, 1.5], [2.0, 3.5], [0.5, 3.0]]
starts = [[0.5, 0.5], [3.5, 3.5]]
"""

#: One table per kind, in the file's words, and the same constraint built by the library.
TABLES = {
    "speed_limit": (
        "vmax = 0.3\nsides = 8\nsoft = true\nweight = 500.0",
        po.SpeedLimit(0.3, sides=8, soft=True, weight=500.0),
    ),
    "accel_limit": ("amax = [0.01, 0.02]", po.AccelLimit([0.01, 0.02])),
    "area_bounds": ("xmin = 0.0\nxmax = 4.0\nymin = 0.0\nymax = 4.0", po.AreaBounds(0, 4, 0, 4)),
    "circle_obstacle": (
        "center = [2.0, 2.2]\nradius = 0.4\nmargin = 0.05",
        po.CircleObstacle((2.0, 2.2), 0.4, margin=0.05),
    ),
    "polygon_obstacle": (
        "vertices = [[1.5, 2.0], [2.5, 2.0], [2.5, 2.6], [1.5, 2.6]]\nplatforms = [1]",
        po.PolygonObstacle([[1.5, 2.0], [2.5, 2.0], [2.5, 2.6], [1.5, 2.6]], platforms=[1]),
    ),
    "visit_all": ("radius = 0.2\nwarmup = 1", po.VisitAll(0.2, warmup=1)),
    "terminal": ('velocity = [0.0, 0.0]\nposition = "start"', po.Terminal(velocity=(0, 0), position="start")),
}


def mission_text(*tables: tuple[str, str], planner: str = "") -> str:
    text = BASE + "".join(f'\n[[constraints]]\nkind = "{kind}"\n{body}\n' for kind, body in tables)
    if planner and "method" not in planner and "kind" not in planner:
        planner = f'method = "pmht"\n{planner}'  # these tests' planner settings are the PMHT planner's
    return text + (f"\n[planner]\n{planner}\n" if planner else "")


def write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_every_constructor_parameter_has_a_file_form() -> None:
    # A new parameter of a kind must be added to its table, or files cannot give it.
    for name, kind in KINDS.items():
        params = {p for p in inspect.signature(kind.cls).parameters if p != "kwargs"}
        assert params == set(kind.params), name
    assert set(COMMON) == set(inspect.signature(po.Constraint.__init__).parameters) - {"self"}


@pytest.mark.parametrize("kind", sorted(TABLES))
def test_each_kind_reads_as_the_library_builds_it(tmp_path: Path, kind: str) -> None:
    body, expected = TABLES[kind]
    mission = load_mission(write(tmp_path, mission_text((kind, body))))
    (con,) = mission.constraints
    assert type(con) is type(expected) and con.name == expected.name
    for attr in (
        "soft",
        "weight",
        "platforms",
        "limit",
        "box",
        "center",
        "radius",
        "vertices",
        "margin",
        "warmup",
        "ramp",
    ):
        if hasattr(expected, attr):
            a, b = getattr(con, attr), getattr(expected, attr)
            assert (
                (a == b) if a is None or isinstance(a, (bool, int, float, tuple)) else np.array_equal(a, b)
            ), attr


@pytest.mark.parametrize(
    "text, field",
    [
        ('horizon = "300"', "horizon: expected an integer, got a string ('300')"),
        ("horizon = 300.0", "horizon: expected an integer, got float"),
        ('dt = "1"', "dt: expected a number, got a string"),
        ("r = true", "r: expected a number, got a boolean"),
        ('bounds = [0, 4, "0", 4]', "bounds[2]: expected a number, got a string"),
        ("name = 3", "name: expected a string"),
    ],
)
def test_strings_where_numbers_belong_name_the_field(tmp_path: Path, text: str, field: str) -> None:
    base = BASE.replace('name = "small"\nhorizon = 40\n', "").replace("r = 0.01\n", "")
    path = write(tmp_path, text + "\n" + base)
    with pytest.raises(ScenarioError) as err:
        load_mission(path)
    assert str(err.value).startswith("m.toml: ") and field in str(err.value)


@pytest.mark.parametrize(
    "table, message",
    [
        (
            'kind = "speed_limit"\nvmax = "0.1"',
            "constraints[0] (speed_limit).vmax: expected a number, got a string ('0.1')",
        ),
        (
            'kind = "speed_limit"\nvmax = -1.0',
            "constraints[0] (speed_limit): SpeedLimit: expected a finite positive number",
        ),
        (
            'kind = "speed_limit"\nvmax = 0.1\nsoft = "yes"',
            "constraints[0] (speed_limit).soft: expected true or false",
        ),
        (
            'kind = "speed_limit"\nvmax = 0.1\nspeed = 2',
            "unknown parameter 'speed'; speed_limit takes vmax, sides",
        ),
        ('kind = "speed_limit"', "constraints[0] (speed_limit): missing vmax"),
        ('kind = "speedlimit"', "constraints[0].kind: expected one of speed_limit, accel_limit"),
        ("vmax = 0.1", "constraints[0]: no 'kind'"),
        (
            'kind = "circle_obstacle"\ncenter = [0.5, 0.5]\nradius = 0.2',
            "constraints[0]: platform 0 starts at (0.5, 0.5), inside",
        ),
        ('kind = "circle_obstacle"\ncenter = [1, "2"]\nradius = 0.2', "center[1]: expected a number"),
        (
            'kind = "terminal"\nposition = "home"',
            "Terminal.position: expected coordinates or 'start', got 'home'",
        ),
        ('kind = "accel_limit"\namax = [0.1, 0.1, 0.1]', "3 limits given for 2 platforms"),
        ('kind = "visit_all"\nwarmup = 1.5', "(visit_all).warmup: expected an integer"),
    ],
)
def test_constraint_errors_name_file_table_and_field(tmp_path: Path, table: str, message: str) -> None:
    path = write(tmp_path, BASE + f"\n[[constraints]]\n{table}\n")
    with pytest.raises(PmhtOptError) as err:
        load_mission(path)
    assert str(err.value).startswith("m.toml: ") and message in str(err.value), str(err.value)


def test_unknown_fields_and_bad_files(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"m\.toml: unknown field 'constraint'; a mission has name"):
        load_mission(write(tmp_path, BASE + "\n[[constraint]]\nkind = 'speed_limit'\n"))
    with pytest.raises(ScenarioError, match=r"m\.toml: not valid TOML"):
        load_mission(write(tmp_path, BASE + "\n[[constraints]\n"))
    with pytest.raises(ScenarioError, match=r"mission files end in \.toml or \.json"):
        load_mission(write(tmp_path, BASE, "m.yaml"))
    with pytest.raises(ScenarioError, match="cannot read"):
        load_mission(tmp_path / "absent.toml")
    with pytest.raises(ScenarioError, match="no 'starts'"):
        mission_from_dict({"locales": [[0, 0]]})


def test_planner_settings_read_typed_and_checked(tmp_path: Path) -> None:
    text = mission_text(
        planner='method = "smoothed"\nsolver = "osqp"\niterations = 7\n'
        'return_to_base = true\nsplit = "distance"\norderer = "ga"\n'
        "order_options = { seed = 3, iterations = 50 }"
    )
    s = load_mission(write(tmp_path, text)).planner
    assert (s.method, s.shared, s.iterations, s.return_to_base) == ("smoothed", {"solver": "osqp"}, 7, True)
    assert s.options == {"split": "distance", "orderer": "ga", "order_options": {"seed": 3, "iterations": 50}}
    assert s.settings(()).solver == "osqp" and s.stop() == po.MaxIterations(7)
    pmht = load_mission(write(tmp_path, mission_text(planner="anneal = [0.5, 3]\ntol = 0.001"))).planner
    assert pmht.schedule().start == 0.5 and pmht.schedule().iterations == 3
    for bad, message in [
        ('iterations = "7"', "planner.iterations: expected an integer"),
        ('method = "fast"', "planner.method: expected one of coverage, smoothed, pmht"),
        ('method = "coverage"\nmethod_x = 1', "planner.method_x: not a setting of the 'coverage' planner"),
        ('kind = "pmht"\nmethod = "pmht"', "planner: give method or kind, not both"),
        ('solver = "gurobi"', "planner: solver: "),
        ("anneal = [1.0]", "planner.anneal: expected [start, iterations]"),
        ("anneal = { start = 1.0, steps = 3 }", "planner.anneal: unknown key 'steps'"),
        ('return_to_base = "yes"', "planner.return_to_base: expected true or false"),
        ("speed = 3", "planner.speed: not a setting of the 'pmht' planner"),
        ('method = "coverage"\nanneal = false', "planner.anneal: not a setting of the 'coverage' planner"),
        ('method = "coverage"\ntol = 0.1', "planner: tol: a setting of the pmht planner"),
    ]:
        with pytest.raises(PmhtOptError) as err:
            load_mission(write(tmp_path, mission_text(planner=bad)))
        assert message in str(err.value), (bad, str(err.value))


def test_an_anneal_below_r_is_refused_with_what_to_write() -> None:
    """The default schedule starts at 100 r, in the mission's units; a start below r is refused."""
    data = {"locales": [[0, 0], [100, 50]], "starts": [[0, 0]], "r": 25.0}
    assert mission_from_dict(data).planner.schedule().start_for(25.0) == 2500.0
    with pytest.raises(ConfigError, match=r"planner.anneal: the schedule starts at r = 1, not above"):
        mission_from_dict({**data, "planner": {"method": "pmht", "anneal": {"start": 1.0, "iterations": 30}}})
    ok = mission_from_dict(
        {**data, "planner": {"method": "pmht", "anneal": {"start": 2500.0, "iterations": 30}}}
    )
    assert ok.planner.schedule().start == 2500.0
    assert (
        mission_from_dict({**data, "planner": {"method": "pmht", "anneal": False}}).planner.schedule().empty
    )


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_write_then_read_gives_the_same_mission(tmp_path: Path, suffix: str) -> None:
    text = mission_text(
        *[(k, TABLES[k][0]) for k in sorted(TABLES)], planner="iterations = 5\nanneal = false"
    )
    mission = load_mission(write(tmp_path, text))
    again = load_mission(save_mission(mission, tmp_path / f"again{suffix}"))
    assert again.to_dict() == mission.to_dict()
    assert [c.name for c in again.constraints] == [c.name for c in mission.constraints]
    if suffix == ".json":
        assert json.loads((tmp_path / "again.json").read_text())["constraints"][0]["kind"] == "accel_limit"


def test_geo_mission_points_are_projected_and_lengths_stay_metres(tmp_path: Path) -> None:
    text = """
horizon = 50
dt = 2.0
r = 400.0
coverage_radius = 60.0
locales = [[-35.3600, 149.1650], [-35.3650, 149.1700]]
starts = [[-35.3632, 149.1652]]
[geo]
origin = [-35.3632, 149.1652]
altitude = 45.0
[planner]
method = "pmht"
anneal = { start = 40000.0, iterations = 10 }
[[constraints]]
kind = "circle_obstacle"
center = [-35.3620, 149.1680]
radius = 50.0
[[constraints]]
kind = "area_bounds"
xmin = -1000.0
xmax = 1000.0
ymin = -1000.0
ymax = 1000.0
"""
    mission = load_mission(write(tmp_path, text))
    plane = mission.origin.plane  # type: ignore[union-attr]
    assert np.allclose(mission.scenario.start_positions, 0.0, atol=1e-6)
    assert np.allclose(mission.scenario.locales, plane.to_local([[-35.36, 149.165], [-35.365, 149.17]]))
    circle = mission.constraints[0]
    assert isinstance(circle, po.CircleObstacle) and circle.radius == 50.0
    assert 200 < np.hypot(*circle.center) < 300  # metres east and north
    assert mission.altitude == 45.0 and mission.bounds_assumed
    again = load_mission(save_mission(mission, tmp_path / "geo.toml"))
    assert np.allclose(again.scenario.locales, mission.scenario.locales, atol=1e-3)
    assert np.allclose(again.constraints[0].center, circle.center, atol=1e-3)  # type: ignore[attr-defined]
    with pytest.raises(
        ScenarioError, match=r"starts\[0\]: a geo-referenced mission takes points as \[lat, lon\]"
    ):
        load_mission(
            write(
                tmp_path,
                text.replace("starts = [[-35.3632, 149.1652]]", "starts = [[-35.36, 149.16, 0, 0, 0, 0]]"),
            )
        )
    with pytest.raises(ScenarioError, match=r"geo\.origin: expected"):
        load_mission(write(tmp_path, text.replace("origin = [-35.3632, 149.1652]", 'origin = "Canberra"')))


def test_geo_end_says_how_exported_flights_end(tmp_path: Path) -> None:
    text = """
horizon = 50
locales = [[-35.3600, 149.1650]]
starts = [[-35.3632, 149.1652]]
[geo]
origin = [-35.3632, 149.1652]
altitude = 45.0
end = "land"
"""
    mission = load_mission(write(tmp_path, text))
    assert mission.end == "land"
    again = load_mission(save_mission(mission, tmp_path / "again.toml"))
    assert again.end == "land" and 'end = "land"' in (tmp_path / "again.toml").read_text()
    assert load_mission(write(tmp_path, text.replace('end = "land"\n', ""))).end is None
    for bad, shown in (('"fly"', "a string ('fly')"), ("true", "a boolean (True)")):
        with pytest.raises(
            ScenarioError, match=rf"geo\.end: expected one of rtl, land, hover, got {re.escape(shown)}"
        ):
            load_mission(write(tmp_path, text.replace('"land"', bad)))
    with pytest.raises(ScenarioError, match=r"geo: unknown key 'ending'; it takes origin, altitude, end"):
        load_mission(write(tmp_path, text.replace("end =", "ending =")))
    with pytest.raises(ConfigError, match=r"^end: expected one of rtl, land, hover or None, got 'up'"):
        Mission(mission.scenario, origin=mission.origin, end="up")


def test_points_from_csv_and_geojson_files(tmp_path: Path) -> None:
    (tmp_path / "sites.csv").write_text("site,x,y\nA,1.0,1.0\nB,3.0,1.5\nC,2.0,3.5\n")
    (tmp_path / "bases.geojson").write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "pmht_opt": {"frame": "plane"},
                "features": [
                    {
                        "type": "Feature",
                        "geometry": {"type": "Point", "coordinates": [3.5, 3.5]},
                        "properties": {"kind": "start", "platform": 1},
                    },
                    {
                        "type": "Feature",
                        "geometry": {"type": "Point", "coordinates": [0.5, 0.5]},
                        "properties": {"kind": "start", "platform": 0},
                    },
                    {
                        "type": "Feature",
                        "geometry": {"type": "Point", "coordinates": [9, 9]},
                        "properties": {"kind": "locale"},
                    },
                ],
            }
        )
    )
    mission = load_mission(write(tmp_path, 'horizon = 30\nlocales = "sites.csv"\nstarts = "bases.geojson"\n'))
    assert np.array_equal(mission.scenario.locales, [[1, 1], [3, 1.5], [2, 3.5]])
    assert np.array_equal(mission.scenario.start_positions, [[0.5, 0.5], [3.5, 3.5]])
    (tmp_path / "bad.csv").write_text("x,y\n1,2\n3,north\n")
    with pytest.raises(ScenarioError, match=r"bad.csv, line 3, column 'y': expected a number, got 'north'"):
        read_points(tmp_path / "bad.csv")
    (tmp_path / "ll.csv").write_text("lat,lon\n-35.36,149.16\n")
    with pytest.raises(
        ScenarioError, match=r"expected columns 'x' and 'y' \(latitude and longitude need a \[geo\] origin"
    ):
        read_points(tmp_path / "ll.csv")
    (tmp_path / "wgs.geojson").write_text(json.dumps({"type": "Point", "coordinates": [149.16, -35.36]}))
    with pytest.raises(ScenarioError, match="RFC 7946"):
        read_points(tmp_path / "wgs.geojson")
    geo = Frame(GeoOrigin(-35.36, 149.16))
    assert np.allclose(read_points(tmp_path / "wgs.geojson", geo), 0.0, atol=1e-6)
    assert np.allclose(read_points(tmp_path / "ll.csv", geo), 0.0, atol=1e-6)


def test_the_example_mission_loads() -> None:
    mission = example_mission("survey")
    sc = mission.scenario
    assert mission.origin is not None and sc.n_locales == 36 and sc.n_platforms == 3
    assert np.ptp(sc.locales[:, 0]) > 2000 and np.ptp(sc.locales[:, 1]) > 1500  # a real-sized area, metres
    assert [type(c) for c in mission.constraints] == [po.SpeedLimit] and mission.planner.return_to_base
    assert isinstance(mission, Mission) and not mission.bounds_assumed


def test_settings_defaults_are_the_librarys() -> None:
    """A [planner] table without keys is the library's defaults: the coverage planner (``plan``'s
    default method), its options and stop."""
    s = PlannerSettings()
    assert s.method == "coverage" == inspect.signature(po.plan).parameters["method"].default
    assert s.stop() is None and s.settings(()) == po.Settings()
    assert po.PLANNERS["coverage"].options(s.planner_options()) == po.PLANNERS["coverage"].Options()
    paper = read_settings("planner", {"method": "pmht", "paper": True}).planner_options()
    assert paper["update_time_prior"] and paper["anneal"].empty


def test_a_mission_without_model_settings_takes_them_in_its_own_units() -> None:
    """r = (rho / 3)^2 and q for a smoother's time constant of a fiftieth of the mission: the paper's
    values for its scenarios, and the same shape of plan in any units."""
    one = {"locales": [[1, 1]], "starts": [[0, 0]]}
    paper = mission_from_dict({**one, "horizon": 500, "coverage_radius": 0.3})
    assert paper.scenario.r == pytest.approx(0.01) and paper.scenario.q == pytest.approx(1e-8)
    metres = mission_from_dict(
        {"locales": [[100, 100]], "starts": [[0, 0]], "horizon": 450, "dt": 2.0, "coverage_radius": 100.0}
    )
    assert metres.scenario.r == pytest.approx(100.0**2 / 9)
    tau = (metres.scenario.r * 2.0 / metres.scenario.q) ** (1 / 6)
    assert tau == pytest.approx(450 * 2.0 / 50)
    given = mission_from_dict({**one, "r": 400.0, "coverage_radius": 100.0})
    assert given.scenario.r == 400.0 and given.scenario.q == pytest.approx(400.0 / 10.0**6)
