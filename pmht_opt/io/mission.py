"""Mission files: a scenario, its constraints, the planner's settings and, optionally, a geo origin.

A mission file (TOML or JSON) is a scenario file (:meth:`~pmht_opt.Scenario.load`) with up to three
more parts: ``[[constraints]]`` tables (:mod:`pmht_opt.io.constraints`), a ``[planner]`` table
(:mod:`pmht_opt.io.settings`) and a ``[geo]`` table that makes the mission geo-referenced:

.. code-block:: toml

    name = "survey"
    horizon = 600
    dt = 1.0                         # s
    q = 6.25e-4                      # m^2/s^5
    r = 625.0                        # m^2 (sigma = 25 m)
    coverage_radius = 75.0           # m
    locales = "sites.csv"            # or [[lat, lon], ...]; a CSV or GeoJSON file next to this one
    starts = [[-35.3632, 149.1652], [-35.3700, 149.1600]]

    [geo]
    origin = [-35.3632, 149.1652]    # [lat, lon], WGS84 degrees
    altitude = 40.0                  # m above the take-off point, for exported flight plans
    end = "land"                     # how exported flight plans end: "rtl", "land" or "hover"

    [planner]
    return_to_base = true

    [[constraints]]
    kind = "speed_limit"
    vmax = 10.0                      # m/s

With ``[geo]``, every point (``locales``, ``starts``, obstacle centres and vertices, a terminal
position) is ``[lat, lon]`` in degrees and every length, box (``bounds``, ``area_bounds``), speed
and acceleration is in metres and seconds in the origin's east-north plane (:mod:`pmht_opt.geometry.earth`).
Without it, points are ``[x, y]`` in the scenario's unit.

Every value's type is checked before the library sees it (``horizon = "300"`` is an error naming
``horizon``); the library's constructors then check the rest with their own messages. Every message
starts with the file's name.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt import validation
from pmht_opt.constraints.base import Constraint, fitting_constraints
from pmht_opt.exceptions import ConfigError, PmhtOptError, ScenarioError
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.io import fields
from pmht_opt.io.constraints import read_constraint, write_constraint
from pmht_opt.io.frame import Frame
from pmht_opt.io.points import read_points, read_radii
from pmht_opt.io.settings import PlannerSettings, read_settings
from pmht_opt.io.waypoints import ENDS
from pmht_opt.scenario import Scenario
from pmht_opt.toml_writer import dumps
from pmht_opt.validation import writing

#: Scenario fields in files, and how each is read.
SCENARIO_FIELDS = ("name", "horizon", "dt", "q", "r", "bounds", "coverage_radius", "locales", "starts")
#: The other top-level parts of a mission file.
MISSION_PARTS = ("geo", "planner", "constraints")
#: Flight altitude (m above the take-off point) of exported flight plans when ``[geo]`` gives none.
DEFAULT_ALTITUDE = 30.0


@dataclass
class Mission:
    """A planning problem as a file holds it.

    Attributes
    ----------
    scenario
        The scenario, in the plane (metres east and north of :attr:`origin` when geo-referenced).
    constraints
        The constraints of the ``[[constraints]]`` tables (not the planner's own, such as a return to
        base: :meth:`constraints_for_plan` adds those).
    planner
        Which planner runs, with which settings.
    origin
        The geo origin, or ``None`` for a mission in the plane.
    altitude
        Flight altitude (m above the take-off point) of exported flight plans.
    bounds_assumed
        True when the file gave no ``bounds``, so the scenario's are the locales' bounding box.
    source
        The file the mission was read from, if any.
    end
        How exported flight plans end (:func:`~pmht_opt.io.export_qgc_plan`): ``"rtl"``, ``"land"``
        or ``"hover"``; ``None``: landing where a route ends at its start, else a return to launch.
    """

    scenario: Scenario
    constraints: tuple[Constraint, ...] = ()
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    origin: GeoOrigin | None = None
    altitude: float = DEFAULT_ALTITUDE
    bounds_assumed: bool = False
    source: Path | None = None
    end: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise ConfigError(f"scenario: expected a Scenario, got {type(self.scenario).__name__}.")
        self.constraints = fitting_constraints(self.scenario, self.constraints)
        if not isinstance(self.planner, PlannerSettings):
            raise ConfigError(f"planner: expected PlannerSettings, got {type(self.planner).__name__}.")
        check_origin(self.origin)
        limit = validation.COORDINATE_MAX
        self.altitude = validation.real("altitude", self.altitude, ConfigError, 0.0, limit)
        if self.end is not None and (not isinstance(self.end, str) or self.end not in ENDS):
            raise ConfigError(f"end: expected one of {', '.join(ENDS)} or None, got {self.end!r}.")
        try:
            self.planner.check_r(self.scenario.r)
        except ConfigError as err:
            raise ConfigError(f"planner.{err}") from None

    @property
    def frame(self) -> Frame:
        """How this mission's points are written (plane or latitude/longitude)."""
        return Frame(self.origin)

    def constraints_for_plan(self) -> tuple[Constraint, ...]:
        """The file's constraints plus the planner's own (a return to base)."""
        from pmht_opt.constraints import Terminal

        extra = (Terminal.return_to_base(),) if self.planner.return_to_base else ()
        return (*self.constraints, *extra)

    def to_dict(self) -> dict[str, Any]:
        """The mission as a file holds it (points as ``[lat, lon]`` when geo-referenced)."""
        frame = self.frame
        sc = self.scenario
        out: dict[str, Any] = {
            "name": sc.name or None,
            "horizon": sc.horizon,
            "dt": sc.dt,
            "q": sc.q,
            "r": sc.r,
            "coverage_radius": sc.to_dict()["coverage_radius"],
            "bounds": None if self.bounds_assumed or sc.bounds is None else list(sc.bounds),
            "locales": frame.out_points(sc.locales),
        }
        if frame.geo and sc.starts.shape[1] != 2:
            raise ConfigError(
                "starts: a geo-referenced mission writes start positions only, not full states."
            )
        out["starts"] = frame.out_points(sc.starts) if sc.starts.shape[1] == 2 else sc.starts.tolist()
        if self.origin is not None:
            out["geo"] = {"origin": [self.origin.lat, self.origin.lon], "altitude": self.altitude}
            if self.end is not None:
                out["geo"]["end"] = self.end
        out["planner"] = self.planner.to_table()
        if self.constraints:
            out["constraints"] = [write_constraint(c, frame) for c in self.constraints]
        return out

    def save(self, path: str | Path) -> Path:
        """Write the mission to ``path`` (``.toml`` or ``.json``); see :func:`save_mission`."""
        return save_mission(self, path)


def _read_scenario(data: dict[str, Any], frame: Frame, base: Path) -> tuple[Scenario, bool]:
    kwargs: dict[str, Any] = {}
    for key in ("locales", "starts"):
        if key not in data:
            raise ScenarioError(f"no {key!r}: a mission needs locales and starts.")
        value = data[key]
        if isinstance(value, str):
            kind = "locale" if key == "locales" else "start"
            kwargs[key] = read_points(base / value, frame, kind)
            radii = read_radii(base / value) if key == "locales" else None
            if radii is not None:
                if "coverage_radius" in data:
                    raise ScenarioError(
                        f"coverage_radius: {value} gives each locale its own radius; give one or the other."
                    )
                kwargs["coverage_radius"] = radii
        elif frame.geo:
            kwargs[key] = frame.points(key, value)
        else:
            kwargs[key] = fields.numbers(key, value, 2)
    readers = {
        "name": fields.string,
        "horizon": fields.integer,
        "dt": fields.number,
        "q": fields.number,
        "r": fields.number,
        "coverage_radius": fields.number_or_numbers,
    }
    for key, read in readers.items():
        if key in data:
            kwargs[key] = read(key, data[key])
    _model_defaults(kwargs)
    if "bounds" in data:
        bounds = fields.numbers("bounds", data["bounds"], 1)
        if len(bounds) != 4:
            raise ScenarioError(f"bounds: expected [xmin, xmax, ymin, ymax], got {len(bounds)} values.")
        kwargs["bounds"] = tuple(bounds)
    return Scenario(**kwargs), "bounds" not in data


#: A mission's default penalty: sigma = a third of the median coverage radius (the paper: 0.3, 0.01).
SIGMA_PER_RADIUS = 1.0 / 3.0
#: A mission's default smoothing: the smoother's time constant (r dt / q)^(1/6) is this share of the
#: mission's duration (the paper: 10 s of 500, from q = 1e-8, r = 0.01).
TAU_SHARE = 1.0 / 50.0


def _model_defaults(kwargs: dict[str, Any]) -> None:
    """The model's ``r`` and ``q`` of a mission that leaves them out, in the mission's own units.

    ``r`` is ``(rho / 3)^2`` with ``rho`` the median coverage radius (three standard deviations of the
    penalty are the sensor's footprint); ``q`` makes the smoother's time constant
    ``(r dt / q)^(1/6)`` a fiftieth of the mission's duration ``T dt``. Both give the paper's values
    for its scenarios (``rho = 0.3``, ``T = 500``, ``dt = 1``: ``r = 0.01``, ``q = 1e-8``), and both
    follow the mission's units of length and time, so a mission in metres plans without model
    settings (docs/model.md section 16).
    """
    numbers = [kwargs.get(k) for k in ("coverage_radius", "r", "dt", "horizon") if k in kwargs]
    if not all(validation.is_real(v) or isinstance(v, list) for v in numbers):
        return  # a field of the wrong type: the scenario names it
    try:
        radius = float(np.median(np.atleast_1d(np.asarray(kwargs.get("coverage_radius", 0.3), dtype=float))))
    except (TypeError, ValueError):
        return
    if not (np.isfinite(radius) and radius > 0):
        return
    if "r" not in kwargs:
        lo, hi = validation.R_RANGE
        kwargs["r"] = float(min(max((SIGMA_PER_RADIUS * radius) ** 2, lo), hi))
    if "q" not in kwargs:
        dt = float(kwargs.get("dt", 1.0))
        horizon = float(kwargs.get("horizon", 500))
        lo, hi = validation.Q_RANGE
        q = kwargs["r"] * dt / (TAU_SHARE * horizon * dt) ** 6
        kwargs["q"] = float(min(max(q, lo), hi))


def _read_geo(data: Any) -> tuple[GeoOrigin, float, str | None]:
    table = fields.table("geo", data)
    unknown = sorted(set(table) - {"origin", "altitude", "end"})
    if unknown:
        raise ScenarioError(f"geo: unknown key {unknown[0]!r}; it takes origin, altitude, end.")
    end = table.get("end")
    if end is not None and (not isinstance(end, str) or end not in ENDS):
        raise ScenarioError(f"geo.end: expected one of {', '.join(ENDS)}, got {fields.describe(end)}.")
    if "origin" not in table:
        raise ScenarioError("geo: no origin; expected origin = [lat, lon] in degrees.")
    origin = fields.numbers("geo.origin", table["origin"], 1)
    if len(origin) != 2:
        raise ScenarioError(f"geo.origin: expected [lat, lon], got {len(origin)} values.")
    altitude = fields.number("geo.altitude", table.get("altitude", DEFAULT_ALTITUDE))
    if not 0.0 <= altitude <= validation.COORDINATE_MAX:
        raise ScenarioError(
            f"geo.altitude: expected metres above the take-off point in [0, {validation.COORDINATE_MAX:g}], "
            f"got {altitude:g}."
        )
    try:
        return GeoOrigin(origin[0], origin[1]), altitude, end
    except ScenarioError as err:
        raise ScenarioError(f"geo.{err}") from None


def mission_from_dict(
    data: Any, base: str | Path = ".", source: Path | None = None, *, check_schedule: bool = True
) -> Mission:
    """A mission from a parsed file (a dict); ``base`` is where relative point files are found.

    ``check_schedule=False`` leaves the ``[planner]`` annealing schedule unchecked against the
    scenario's ``r``, for a caller that replaces it (the command line's ``--anneal`` and
    ``--no-anneal``) and checks its own.

    Raises
    ------
    ScenarioError, ConfigError
        Naming the field (or table and key) that is wrong.
    """
    top = fields.table("the mission", data)
    unknown = sorted(set(top) - set(SCENARIO_FIELDS) - set(MISSION_PARTS))
    if unknown:
        raise ScenarioError(
            f"unknown field {unknown[0]!r}; a mission has {', '.join(SCENARIO_FIELDS + MISSION_PARTS)}."
        )
    origin, altitude, end = _read_geo(top["geo"]) if "geo" in top else (None, DEFAULT_ALTITUDE, None)
    frame = Frame(origin)
    scenario, assumed = _read_scenario(top, frame, Path(base))
    raw = top.get("constraints", [])
    if not isinstance(raw, list):
        raise ScenarioError(f"constraints: expected an array of tables, got {fields.describe(raw)}.")
    constraints = tuple(read_constraint(f"constraints[{i}]", c, frame) for i, c in enumerate(raw))
    for i, con in enumerate(constraints):
        try:
            con.check_scenario(scenario)
        except PmhtOptError as err:
            raise type(err)(f"constraints[{i}]: {err}") from None
    planner = read_settings("planner", top["planner"]) if "planner" in top else PlannerSettings()
    if check_schedule:
        try:
            planner.check_r(scenario.r)
        except ConfigError as err:
            raise ConfigError(f"planner.{err}") from None
    mission = Mission(scenario, constraints, PlannerSettings(), origin, altitude, assumed, source, end)
    mission.planner = planner  # checked above, or by a caller that replaces its schedule
    return mission


def load_mission(path: str | Path, *, check_schedule: bool = True) -> Mission:
    """Read a mission (or plain scenario) file, ``.toml`` or ``.json`` (``check_schedule``: see
    :func:`mission_from_dict`).

    Raises
    ------
    ScenarioError, ConfigError
        Every message starts with the file's name, then the field.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise ScenarioError(f"{path.name}: mission files end in .toml or .json.")
    text = fields.text(path)
    try:
        data = json.loads(text) if suffix == ".json" else tomllib.loads(text)
    except RecursionError:
        raise ScenarioError(f"{path.name}: nested too deeply to read.") from None
    except ValueError as err:  # the decoders' errors, and integers longer than Python reads
        raise ScenarioError(f"{path.name}: not valid {suffix[1:].upper()}: {err}.") from None
    try:
        return mission_from_dict(data, path.parent, path, check_schedule=check_schedule)
    except PmhtOptError as err:
        raise type(err)(f"{path.name}: {err}") from None


def check_mission(mission: Any) -> Mission:
    """``mission`` if it is a :class:`Mission`, else ConfigError naming it."""
    if not isinstance(mission, Mission):
        raise ConfigError(f"mission: expected a Mission, got {type(mission).__name__}.")
    return mission


def save_mission(mission: Mission, path: str | Path) -> Path:
    """Write ``mission`` to ``path``, ``.toml`` or ``.json`` by the suffix; :func:`load_mission` reads
    it back to the same mission (geo points to 1e-9 degrees, 0.1 mm)."""
    check_mission(mission)
    path = validation.file_path("path", path)
    suffix = path.suffix.lower()
    data = mission.to_dict()
    if suffix == ".json":
        text = json.dumps({k: v for k, v in data.items() if v is not None}, indent=1, ensure_ascii=False)
        text += "\n"
    elif suffix == ".toml":
        text = dumps(data, header="pmht-opt mission")
    else:
        raise ScenarioError(f"{path.name}: mission files end in .toml or .json.")
    with writing(path) as out:
        out.write_text(text, encoding="utf-8")
    return path
