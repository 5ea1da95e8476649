"""Plans as QGroundControl missions: one ``.plan`` file per platform.

QGroundControl's plan file is JSON: ``fileType = "Plan"``, ``version = 1``, ``groundStation``, a
``mission`` object (``version = 2``, ``firmwareType`` and ``vehicleType`` as MAVLink's
``MAV_AUTOPILOT`` and ``MAV_TYPE`` values, ``cruiseSpeed``, ``hoverSpeed``, ``items``,
``plannedHomePosition = [lat, lon, alt]``) and optional ``geoFence`` and ``rallyPoints``. Each item
here is a ``SimpleItem``: one MAVLink mission command with seven ``params``; positions are in
``frame = 3`` (``MAV_FRAME_GLOBAL_RELATIVE_ALT``: altitude in metres above the home position).

A platform's mission is:

1. a take-off (``MAV_CMD_NAV_TAKEOFF``, 22) at its start, for vehicles that fly;
2. a speed change (``MAV_CMD_DO_CHANGE_SPEED``, 178: ground speed, m/s);
3. waypoints (``MAV_CMD_NAV_WAYPOINT``, 16: ``params = [hold, acceptance radius, pass radius, yaw,
   lat, lon, alt]``) along the planned path;
4. optionally a landing (``MAV_CMD_NAV_LAND``, 21) at its end.

The waypoints are points of the planned path itself: its end, the point nearest each locale it is
assigned, and as many more as keep the straight legs between waypoints within ``tolerance`` of the
path (Douglas-Peucker simplification). A flight plan has no clock: the vehicle flies the legs at the
set speed, by default the platform's mean planned speed, so it keeps the plan's route but not its
timing.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.geometry import point_polyline_distance
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.io.frame import GEO_DECIMALS
from pmht_opt.result import check_plan
from pmht_opt.validation import file_path, writing

#: MAVLink commands used.
NAV_WAYPOINT, NAV_LAND, NAV_TAKEOFF, DO_CHANGE_SPEED = 16, 21, 22, 178
#: ``MAV_FRAME_MISSION`` (commands without a position) and ``MAV_FRAME_GLOBAL_RELATIVE_ALT``.
FRAME_MISSION, FRAME_RELATIVE_ALT = 2, 3
#: ``MAV_AUTOPILOT`` values by name.
FIRMWARE = {"generic": 0, "ardupilot": 3, "px4": 12}
#: ``MAV_TYPE`` values by name: quadrotor, fixed wing, ground rover, surface boat.
VEHICLES = {"multirotor": 2, "fixedwing": 1, "rover": 10, "boat": 11}
#: The keys QGroundControl's plan format documents, at each level.
PLAN_KEYS = ("fileType", "version", "groundStation", "mission", "geoFence", "rallyPoints")
MISSION_KEYS = (
    "version",
    "firmwareType",
    "vehicleType",
    "cruiseSpeed",
    "hoverSpeed",
    "items",
    "plannedHomePosition",
)
ITEM_KEYS = ("autoContinue", "command", "doJumpId", "frame", "params", "type")


def simplify(points: np.ndarray, tolerance: float, keep: Any = ()) -> np.ndarray:
    """Indices of ``points (K, 2)`` whose polyline stays within ``tolerance`` of every point
    (Douglas-Peucker), always including the first, the last and those in ``keep``, in order."""
    pts = np.asarray(points, dtype=float)
    chosen = {0, len(pts) - 1, *(int(k) for k in keep)}
    anchors = sorted(chosen)
    stack = list(itertools.pairwise(anchors))
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        seg = pts[i : j + 1]
        dist = point_polyline_distance(seg[1:-1], np.vstack([seg[0], seg[-1]]))
        k = int(np.argmax(dist))
        if dist[k] > tolerance:
            mid = i + 1 + k
            chosen.add(mid)
            stack += [(i, mid), (mid, j)]
    return np.array(sorted(chosen), dtype=np.intp)


def _item(
    jump: int, command: int, frame: int, params: list[Any], altitude: float | None = None
) -> dict[str, Any]:
    item: dict[str, Any] = {}
    if altitude is not None:
        item.update({"AMSLAltAboveTerrain": None, "Altitude": altitude, "AltitudeMode": 1})
    item.update(
        {
            "autoContinue": True,
            "command": command,
            "doJumpId": jump,
            "frame": frame,
            "params": params,
            "type": "SimpleItem",
        }
    )
    return item


@dataclass(frozen=True)
class _Flight:
    """How every platform's mission flies (the options of :func:`export_qgc_plan`), checked once."""

    altitude: float
    speed: float | None
    tolerance: float | None
    acceptance_radius: float
    takeoff: bool | None
    land: bool
    firmware: str
    vehicle: str

    def __post_init__(self) -> None:
        if not isinstance(self.firmware, str) or self.firmware not in FIRMWARE:
            raise ConfigError(f"firmware: expected one of {', '.join(FIRMWARE)}, got {self.firmware!r}.")
        if not isinstance(self.vehicle, str) or self.vehicle not in VEHICLES:
            raise ConfigError(f"vehicle: expected one of {', '.join(VEHICLES)}, got {self.vehicle!r}.")
        for name, value in (("altitude", self.altitude), ("acceptance_radius", self.acceptance_radius)):
            validation.real(name, value, ConfigError, 0.0)
        if self.speed is not None:
            _checked_speed(self.speed)
        if self.tolerance is not None:
            validation.real("tolerance", self.tolerance, ConfigError, 0.0, lo_open=True)
        for name, flag in (("takeoff", self.takeoff), ("land", self.land)):
            if not (isinstance(flag, (bool, np.bool_)) or (name == "takeoff" and flag is None)):
                raise ConfigError(f"{name}: expected True or False, got {flag!r}.")


def _checked_speed(speed: Any) -> float:
    """``speed`` (m/s), given or each platform's mean, if it is a non-negative number."""
    return validation.real("speed", speed, ConfigError, 0.0)


def platform_plan(result: Any, platform: int, origin: GeoOrigin, flight: _Flight) -> dict[str, Any]:
    """The QGroundControl plan (a dict) of one platform of ``result``; see :func:`export_qgc_plan`."""
    sc = result.scenario
    path = np.asarray(result.positions[platform])
    tol = float(sc.radii.min()) / 10 if flight.tolerance is None else float(flight.tolerance)
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError(f"tolerance: expected a positive number of metres, got {flight.tolerance!r}.")
    mine = np.flatnonzero(np.asarray(result.assignment) == platform)
    nearest = [int(np.argmin(np.hypot(*(path - sc.locales[n]).T))) for n in mine]
    steps = simplify(path, tol, keep=nearest)
    seg = np.diff(path, axis=0)
    length = float(np.hypot(seg[:, 0], seg[:, 1]).sum())
    speed = _checked_speed(length / (sc.horizon * sc.dt) if flight.speed is None else flight.speed)
    latlon = np.round(origin.plane.to_geodetic(path[steps]), GEO_DECIMALS)
    flies = flight.vehicle not in ("rover", "boat")
    cruise = round(speed, 3) if speed > 0 else 1.0
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "pmht-opt",
        "mission": {
            "version": 2,
            "firmwareType": FIRMWARE[flight.firmware],
            "vehicleType": VEHICLES[flight.vehicle],
            "cruiseSpeed": cruise,
            "hoverSpeed": cruise,
            "globalPlanAltitudeMode": 1,
            "plannedHomePosition": [*latlon[0].tolist(), 0],
            "items": _items(latlon, speed, flies if flight.takeoff is None else flight.takeoff, flight),
        },
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
    }


def _items(latlon: np.ndarray, speed: float, takeoff: bool, flight: _Flight) -> list[dict[str, Any]]:
    """The mission items (module notes) through the waypoints ``latlon`` (degrees), numbered from 1."""
    altitude = flight.altitude
    items: list[dict[str, Any]] = []
    home = latlon[0].tolist()
    if takeoff:
        items.append(
            _item(len(items) + 1, NAV_TAKEOFF, FRAME_RELATIVE_ALT, [0, 0, 0, None, *home, altitude], altitude)
        )
    if speed > 0:
        items.append(
            _item(len(items) + 1, DO_CHANGE_SPEED, FRAME_MISSION, [1, round(speed, 3), -1, 0, 0, 0, 0])
        )
    for k, (lat, lon) in enumerate(latlon.tolist()):
        if k == 0 and takeoff:
            continue  # the take-off is there
        params = [0, flight.acceptance_radius, 0, None, lat, lon, altitude]
        items.append(_item(len(items) + 1, NAV_WAYPOINT, FRAME_RELATIVE_ALT, params, altitude))
    if flight.land:
        items.append(
            _item(len(items) + 1, NAV_LAND, FRAME_RELATIVE_ALT, [0, 0, 0, None, *latlon[-1].tolist(), 0], 0.0)
        )
    return items


def qgc_paths(path: str | Path, n_platforms: int) -> list[Path]:
    """The files :func:`export_qgc_plan` writes for ``path``: ``NAME-0.plan``, ``NAME-1.plan``, ...
    (one per platform, numbered from 0 as in the library)."""
    path = file_path("path", path)
    return [path.with_name(f"{path.stem}-{m}{path.suffix or '.plan'}") for m in range(n_platforms)]


def export_qgc_plan(
    result: Any,
    path: str | Path,
    origin: GeoOrigin,
    *,
    altitude: float = 30.0,
    speed: float | None = None,
    tolerance: float | None = None,
    acceptance_radius: float = 0.0,
    takeoff: bool | None = None,
    land: bool = False,
    firmware: str = "px4",
    vehicle: str = "multirotor",
) -> list[Path]:
    """Write one QGroundControl ``.plan`` per platform of ``result`` (module notes).

    Parameters
    ----------
    result
        A geo-referenced plan (:class:`~pmht_opt.PlanResult`, positions in metres east and north of
        ``origin``).
    path
        ``NAME.plan``: platform ``m`` goes to ``NAME-m.plan`` (:func:`qgc_paths`).
    origin
        The mission's origin.
    altitude
        Flight altitude, metres above the home position.
    speed
        Ground speed (m/s) of every leg; ``None``: each platform's mean planned speed.
    tolerance
        Largest distance (m) between the path and the legs between waypoints; ``None``: a tenth of
        the scenario's coverage radius.
    acceptance_radius
        Each waypoint's acceptance radius (m); 0 leaves it to the autopilot.
    takeoff, land
        Start with a take-off (default: for vehicles that fly), end with a landing.
    firmware, vehicle
        ``"px4"``, ``"ardupilot"`` or ``"generic"``; ``"multirotor"``, ``"fixedwing"``, ``"rover"``
        or ``"boat"``.

    Returns
    -------
    list of Path
        The files written, in platform order.
    """
    check_plan(result)
    if check_origin(origin) is None:
        raise ConfigError("origin: a QGroundControl plan needs a geo-referenced mission (an origin).")
    flight = _Flight(altitude, speed, tolerance, acceptance_radius, takeoff, land, firmware, vehicle)
    files = qgc_paths(path, result.scenario.n_platforms)
    # Every platform's plan first: a refusal (a tolerance, a speed) leaves no file behind.
    plans = [platform_plan(result, m, origin, flight) for m in range(len(files))]
    for file, plan in zip(files, plans, strict=True):
        with writing(file) as out_file:
            out_file.write_text(json.dumps(plan, indent=2) + "\n", encoding="utf-8")
    return list(files)


def read_qgc_plan(path: str | Path) -> dict[str, Any]:
    """The parts of a ``.plan`` file a check needs: ``waypoints (K, 3)`` (lat, lon, alt of the
    waypoint and take-off items, in order), ``speed`` (the last speed change, or ``None``) and
    ``home``."""
    path = file_path("path", path)
    try:
        plan = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:  # unreadable, not UTF-8, not JSON
        raise ScenarioError(f"cannot read {path.name}: {err}.") from None
    if not isinstance(plan, dict) or plan.get("fileType") != "Plan":
        kind = plan.get("fileType") if isinstance(plan, dict) else type(plan).__name__
        raise ScenarioError(f"{path.name}: not a QGroundControl plan (fileType {kind!r}).")
    try:
        mission = plan["mission"]
        points, speed = [], None
        for item in mission["items"]:
            if item["command"] in (NAV_TAKEOFF, NAV_WAYPOINT):
                point = [float(v) for v in item["params"][4:7]]
                if len(point) != 3:
                    raise IndexError("a waypoint's params hold no latitude, longitude and altitude")
                points.append(point)
            elif item["command"] == DO_CHANGE_SPEED:
                speed = float(item["params"][1])
        home = mission["plannedHomePosition"]
        waypoints = np.asarray(points, dtype=float).reshape(-1, 3)
    except (KeyError, IndexError, TypeError, ValueError) as err:
        raise ScenarioError(
            f"{path.name}: not a readable QGroundControl plan (its mission, items or their params are "
            f"malformed: {type(err).__name__} {err})."
        ) from None
    return {"waypoints": waypoints, "speed": speed, "home": home}
