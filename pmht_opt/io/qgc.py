"""Plans as QGroundControl missions: one ``.plan`` file per platform, flown as the plan promises.

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
   lat, lon, alt]``): points of the planned path or the coverage planner's tour
   (:mod:`pmht_opt.io.waypoints`);
4. its end (``end``): a return to launch (``MAV_CMD_NAV_RETURN_TO_LAUNCH``, 20), a landing at the last
   waypoint (``MAV_CMD_NAV_LAND``, 21), or nothing, so that the vehicle holds at the last waypoint
   ("hover"). By default it lands where the route already ends at its start (a return to base) and
   returns to launch otherwise.

The vehicle flies straight legs between the waypoints, so the legs, not the planned samples, must
keep the plan's promises: every leg, and a return to launch's straight leg home, stays out of every
keep-out zone and inside every area, and with the planners that promise coverage the legs pass within
each site's radius. :mod:`pmht_opt.io.flight` measures that on the coordinates as written; where a
leg breaks a promise more waypoints are taken, and where none can keep it the export is refused
(:class:`~pmht_opt.exceptions.SolverError`), before any file is written.

A flight plan has no clock: the vehicle flies the legs at one speed, by default the plan's speed limit
(the smallest :class:`~pmht_opt.constraints.SpeedLimit` that binds the platform: the plan flies no
faster, and covers its route in the least time at it), else the platform's mean planned speed. It keeps
the plan's route but not its timing.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.io.frame import GEO_DECIMALS
from pmht_opt.io.waypoints import ENDS, SOURCES, Flight, checked_speed, flights, simplify
from pmht_opt.result import check_plan
from pmht_opt.validation import file_path, writing

#: MAVLink commands used.
NAV_WAYPOINT, NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF, DO_CHANGE_SPEED = 16, 20, 21, 22, 178
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

__all__ = [
    "ENDS",
    "SOURCES",
    "Flight",
    "PlanFiles",
    "export_qgc_plan",
    "qgc_paths",
    "read_qgc_plan",
    "simplify",
]


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
    end: str | None
    firmware: str
    vehicle: str
    source: str

    def __post_init__(self) -> None:
        for name, value, choices in (
            ("firmware", self.firmware, FIRMWARE),
            ("vehicle", self.vehicle, VEHICLES),
            ("end", self.end, ENDS),
            ("source", self.source, SOURCES),
        ):
            if not (name == "end" and value is None) and (not isinstance(value, str) or value not in choices):
                raise ConfigError(f"{name}: expected one of {', '.join(choices)}, got {value!r}.")
        for name, number in (("altitude", self.altitude), ("acceptance_radius", self.acceptance_radius)):
            validation.real(name, number, ConfigError, 0.0)
        if self.speed is not None:
            checked_speed(self.speed)
        if self.tolerance is not None:
            validation.real("tolerance", self.tolerance, ConfigError, 0.0, lo_open=True)
        if not (isinstance(self.takeoff, (bool, np.bool_)) or self.takeoff is None):
            raise ConfigError(f"takeoff: expected True or False, got {self.takeoff!r}.")


def _end(end: str | None, land: Any) -> str | None:
    """``end`` with the older ``land`` folded in: ``land=True`` is ``end="land"``, ``land=False`` is
    ``end="hover"`` (the mission stops at its last waypoint, as ``land=False`` always meant)."""
    if land is None:
        return end
    if not isinstance(land, (bool, np.bool_)):
        raise ConfigError(f"land: expected True or False (or None), got {land!r}.")
    older = "land" if land else "hover"
    if end is not None and end != older:
        raise ConfigError(f"land: land={bool(land)} asks for end {older!r}, but end={end!r}; give end alone.")
    return older


def _through(origin: GeoOrigin) -> Any:
    """Points of the plane as a file holds them: to degrees, rounded, and back."""
    plane = origin.plane

    def through(points: np.ndarray) -> np.ndarray:
        return plane.to_local(np.round(plane.to_geodetic(np.asarray(points, float)), GEO_DECIMALS))

    return through


class PlanFiles(list[Path]):
    """The files :func:`export_qgc_plan` wrote, in platform order (a list of paths), with each
    platform's :class:`~pmht_opt.io.waypoints.Flight` in :attr:`flights`."""

    def __init__(self, files: list[Path], flights: list[Flight]) -> None:
        super().__init__(files)
        self.flights = tuple(flights)

    @property
    def deviation(self) -> np.ndarray:
        """``(M,)`` the largest distance (m) between each platform's legs and its planned path."""
        return np.array([f.deviation for f in self.flights])


def qgc_flights(result: Any, origin: GeoOrigin, options: _Flight) -> list[Flight]:
    """Every platform's :class:`~pmht_opt.io.waypoints.Flight` under ``options``, checked against the
    plan's promises on the coordinates as the file holds them (module notes)."""
    tol = float(result.scenario.radii.min()) / 10 if options.tolerance is None else float(options.tolerance)
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError(f"tolerance: expected a positive number of metres, got {options.tolerance!r}.")
    return flights(result, _through(origin), tol, speed=options.speed, end=options.end, source=options.source)


def platform_plan(flight: Flight, origin: GeoOrigin, options: _Flight) -> dict[str, Any]:
    """The QGroundControl plan (a dict) of one platform's :class:`~pmht_opt.io.waypoints.Flight`; see
    :func:`export_qgc_plan`."""
    latlon = np.round(origin.plane.to_geodetic(flight.route.waypoints), GEO_DECIMALS)
    flies = options.vehicle not in ("rover", "boat")
    cruise = round(flight.speed, 3) if flight.speed > 0 else 1.0
    takeoff = flies if options.takeoff is None else bool(options.takeoff)
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "pmht-opt",
        "mission": {
            "version": 2,
            "firmwareType": FIRMWARE[options.firmware],
            "vehicleType": VEHICLES[options.vehicle],
            "cruiseSpeed": cruise,
            "hoverSpeed": cruise,
            "globalPlanAltitudeMode": 1,
            "plannedHomePosition": [*latlon[0].tolist(), 0],
            "items": _items(latlon, flight, takeoff, options),
        },
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
    }


def _items(latlon: np.ndarray, flight: Flight, takeoff: bool, options: _Flight) -> list[dict[str, Any]]:
    """The mission items (module notes) through the waypoints ``latlon`` (degrees), numbered from 1."""
    altitude = options.altitude
    items: list[dict[str, Any]] = []

    def add(command: int, frame: int, params: list[Any], alt: float | None = None) -> None:
        items.append(_item(len(items) + 1, command, frame, params, alt))

    if takeoff:
        add(NAV_TAKEOFF, FRAME_RELATIVE_ALT, [0, 0, 0, None, *latlon[0].tolist(), altitude], altitude)
    if flight.speed > 0:
        add(DO_CHANGE_SPEED, FRAME_MISSION, [1, round(flight.speed, 3), -1, 0, 0, 0, 0])
    for k, (lat, lon) in enumerate(latlon.tolist()):
        if k == 0 and takeoff:
            continue  # the take-off is there
        add(
            NAV_WAYPOINT,
            FRAME_RELATIVE_ALT,
            [0, options.acceptance_radius, 0, None, lat, lon, altitude],
            altitude,
        )
    if flight.end == "land":
        add(NAV_LAND, FRAME_RELATIVE_ALT, [0, 0, 0, None, *latlon[-1].tolist(), 0], 0.0)
    elif flight.end == "rtl":
        add(NAV_RETURN_TO_LAUNCH, FRAME_MISSION, [0, 0, 0, 0, 0, 0, 0])
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
    end: str | None = None,
    land: bool | None = None,
    firmware: str = "px4",
    vehicle: str = "multirotor",
    source: str = "plan",
) -> PlanFiles:
    """Write one QGroundControl ``.plan`` per platform of ``result`` whose legs keep the plan's
    promises (module notes).

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
        Ground speed (m/s) of every leg, at most the plan's speed limit; ``None``: the plan's speed
        limit (the smallest that binds the platform), else each platform's mean planned speed.
    tolerance
        Largest distance (m) between the path and the legs of the simplification (``source="plan"``),
        before waypoints are added to keep the promises; ``None``: a tenth of the smallest coverage
        radius.
    acceptance_radius
        Each waypoint's acceptance radius (m); 0 leaves it to the autopilot.
    takeoff
        Start with a take-off (default: for vehicles that fly).
    end
        ``"rtl"`` (return to launch), ``"land"`` (at the last waypoint) or ``"hover"`` (hold at the
        last waypoint); ``None``: ``"land"`` where the route ends at its start, else ``"rtl"``.
    land
        The older form of ``end``: ``True`` is ``"land"``, ``False`` is ``"hover"``; ``None`` leaves
        ``end`` to say. Contradicting ``end`` is an error.
    firmware, vehicle
        ``"px4"``, ``"ardupilot"`` or ``"generic"``; ``"multirotor"``, ``"fixedwing"``, ``"rover"``
        or ``"boat"``.
    source
        ``"plan"``: waypoints on the planned path; ``"tour"``: the coverage planner's straight-line
        tour (:mod:`pmht_opt.io.waypoints`).

    Returns
    -------
    PlanFiles
        The files written, in platform order (a list of paths), with each platform's
        :class:`~pmht_opt.io.waypoints.Flight` (``.flights``: waypoints, speed, end, and the largest
        distance between the legs and the planned path, ``.deviation``).

    Raises
    ------
    ConfigError
        An option out of range, naming it (``source="tour"`` without a tour, a speed above the
        plan's limit).
    SolverError
        No waypoints keep a promise: names the platform, the leg and the constraint. Nothing is written.
    """
    check_plan(result)
    if check_origin(origin) is None:
        raise ConfigError("origin: a QGroundControl plan needs a geo-referenced mission (an origin).")
    options = _Flight(
        altitude, speed, tolerance, acceptance_radius, takeoff, _end(end, land), firmware, vehicle, source
    )
    files = qgc_paths(path, result.scenario.n_platforms)
    # Every platform's plan first: a refusal (an option, a broken promise) leaves no file behind.
    flights = qgc_flights(result, origin, options)
    plans = [platform_plan(f, origin, options) for f in flights]
    for file, plan in zip(files, plans, strict=True):
        with writing(file) as out_file:
            out_file.write_text(json.dumps(plan, indent=2) + "\n", encoding="utf-8")
    return PlanFiles(list(files), flights)


def read_qgc_plan(path: str | Path) -> dict[str, Any]:
    """The parts of a ``.plan`` file a check needs: ``waypoints (K, 3)`` (lat, lon, alt of the
    waypoint and take-off items, in order), ``speed`` (the last speed change, or ``None``), ``home``
    and ``end`` (``"rtl"``, ``"land"`` or ``"hover"``: the last item, or ``None`` for a mission without
    waypoints)."""
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
        points, speed, end = [], None, None
        for item in mission["items"]:
            command = item["command"]
            if command in (NAV_TAKEOFF, NAV_WAYPOINT):
                point = [float(v) for v in item["params"][4:7]]
                if len(point) != 3:
                    raise IndexError("a waypoint's params hold no latitude, longitude and altitude")
                points.append(point)
                end = "hover"
            elif command == DO_CHANGE_SPEED:
                speed = float(item["params"][1])
            elif command in (NAV_LAND, NAV_RETURN_TO_LAUNCH):
                end = "land" if command == NAV_LAND else "rtl"
        home = mission["plannedHomePosition"]
        waypoints = np.asarray(points, dtype=float).reshape(-1, 3)
    except (KeyError, IndexError, TypeError, ValueError) as err:
        raise ScenarioError(
            f"{path.name}: not a readable QGroundControl plan (its mission, items or their params are "
            f"malformed: {type(err).__name__} {err})."
        ) from None
    return {"waypoints": waypoints, "speed": speed, "home": home, "end": end}
