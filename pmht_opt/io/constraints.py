"""Constraints in mission files: ``[[constraints]]`` tables with a snake-case ``kind`` and the
constraint's own parameter names.

.. code-block:: toml

    [[constraints]]
    kind = "speed_limit"
    vmax = 12.0          # m/s in a geo-referenced mission
    soft = true

    [[constraints]]
    kind = "circle_obstacle"
    center = [-35.3610, 149.1662]   # [lat, lon] in a geo-referenced mission, [x, y] otherwise
    radius = 80.0

Each parameter is first checked for its type (a string where a number belongs names the field), then
the library's constructor checks ranges and shapes with its own messages. Points (obstacle centres and
vertices, a terminal position) go through the mission's :class:`~pmht_opt.io.frame.Frame`; lengths,
boxes and vectors are in the plane's units.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.constraints import (
    AccelLimit,
    AreaBounds,
    CircleObstacle,
    Constraint,
    PolygonObstacle,
    SpeedLimit,
    StayNear,
    Terminal,
    VisitAll,
)
from pmht_opt.exceptions import ConfigError, ScenarioError
from pmht_opt.io import fields
from pmht_opt.io.frame import Frame

#: ``reader(field, value, frame) -> value`` for the constructor.
Reader = Callable[[str, Any, Frame], Any]
#: ``writer(constraint, frame) -> table`` of its own parameters.
Writer = Callable[[Any, Frame], dict[str, Any]]


def _planar(read: Callable[[str, Any], Any]) -> Reader:
    """A reader of a parameter that the mission's frame does not change (lengths, counts, flags)."""

    def reader(field: str, value: Any, frame: Frame) -> Any:
        return read(field, value)

    return reader


_number = _planar(fields.number)
_integer = _planar(fields.integer)
_boolean = _planar(fields.boolean)
_per_platform = _planar(fields.number_or_numbers)
_platforms = _planar(fields.integer_or_integers)
_vector = _planar(fields.vector_or_vectors)


def _point(field: str, value: Any, frame: Frame) -> Any:
    return frame.point(field, value)


def _points(field: str, value: Any, frame: Frame) -> Any:
    return frame.points(field, value)


def _position(field: str, value: Any, frame: Frame) -> Any:
    if isinstance(value, str):
        return value  # "start"; Terminal names anything else
    if isinstance(value, list) and value and isinstance(value[0], list):
        return frame.points(field, value)
    return frame.point(field, value)


def _limit(values: np.ndarray) -> Any:
    return float(values[0]) if values.size == 1 else values.tolist()


def _rows(arr: np.ndarray | None) -> Any:
    if arr is None:
        return None
    return arr[0].tolist() if arr.shape[0] == 1 else arr.tolist()


def _write_terminal(con: Terminal, frame: Frame) -> dict[str, Any]:
    out: dict[str, Any] = {"velocity": _rows(con.velocity), "acceleration": _rows(con.acceleration)}
    if con.at_start:
        out["position"] = "start"
    elif con.position is not None:
        pts = frame.out_points(con.position)
        out["position"] = pts[0] if len(pts) == 1 else pts
    out.update({"radius": con.radius, "sides": con.sides})
    return out


@dataclass(frozen=True)
class Kind:
    """One constraint kind in files: its class, how each own parameter is read, how it is written."""

    cls: type[Constraint]
    params: dict[str, Reader]
    write: Writer


#: Parameters every kind takes (:class:`~pmht_opt.constraints.base.Constraint`).
COMMON: dict[str, Reader] = {"soft": _boolean, "weight": _number, "platforms": _platforms}

#: The kinds by their name in files.
KINDS: dict[str, Kind] = {
    "speed_limit": Kind(
        SpeedLimit,
        {"vmax": _per_platform, "sides": _integer},
        lambda c, f: {"vmax": _limit(c.limit), "sides": c.sides},
    ),
    "accel_limit": Kind(
        AccelLimit,
        {"amax": _per_platform, "sides": _integer},
        lambda c, f: {"amax": _limit(c.limit), "sides": c.sides},
    ),
    "area_bounds": Kind(
        AreaBounds,
        {"xmin": _number, "xmax": _number, "ymin": _number, "ymax": _number},
        lambda c, f: dict(zip(("xmin", "xmax", "ymin", "ymax"), map(float, c.box), strict=True)),
    ),
    "stay_near": Kind(StayNear, {"margin": _number}, lambda c, f: {"margin": c.margin}),
    "circle_obstacle": Kind(
        CircleObstacle,
        {"center": _point, "radius": _number, "margin": _number},
        lambda c, f: {"center": f.out_points(c.center)[0], "radius": c.radius, "margin": c.margin},
    ),
    "polygon_obstacle": Kind(
        PolygonObstacle,
        {"vertices": _points, "margin": _number},
        lambda c, f: {"vertices": f.out_points(c.vertices), "margin": c.margin},
    ),
    "visit_all": Kind(
        VisitAll,
        {"radius": _number, "warmup": _integer, "ramp": _integer, "sides": _integer, "keep_within": _number},
        lambda c, f: {
            "radius": c.radius,
            "warmup": c.warmup,
            "ramp": c.ramp,
            "sides": c.sides,
            "keep_within": c.keep_within,
        },
    ),
    "terminal": Kind(
        Terminal,
        {
            "velocity": _vector,
            "position": _position,
            "radius": _number,
            "acceleration": _vector,
            "sides": _integer,
        },
        _write_terminal,
    ),
}


def kind_name(con: Constraint) -> str:
    """The file name of ``con``'s kind; :class:`ConfigError` for a kind files cannot hold."""
    for name, kind in KINDS.items():
        if type(con) is kind.cls:
            return name
    raise ConfigError(
        f"{con.name}: mission files hold the kinds {', '.join(KINDS)}; {type(con).__name__} has no file form."
    )


def read_constraint(where: str, data: Any, frame: Frame) -> Constraint:
    """Build one constraint from its table.

    Parameters
    ----------
    where
        How messages name the table, e.g. ``"constraints[2]"``.
    data
        The table: ``kind`` and the kind's parameters.
    frame
        How points are read (plane or latitude/longitude).

    Raises
    ------
    ScenarioError
        A missing or unknown ``kind``, an unknown parameter (the message lists the kind's), or a value
        of the wrong type.
    ConfigError
        A value the constraint's constructor rejects (its own message, after ``where``).
    """
    table = fields.table(where, data)
    if "kind" not in table:
        raise ScenarioError(f"{where}: no 'kind'; expected one of {', '.join(KINDS)}.")
    name = fields.string(f"{where}.kind", table["kind"])
    kind = KINDS.get(name)
    if kind is None:
        raise ScenarioError(f"{where}.kind: expected one of {', '.join(KINDS)}, got {name!r}.")
    label = f"{where} ({name})"
    readers = {**kind.params, **COMMON}
    unknown = sorted(set(table) - set(readers) - {"kind"})
    if unknown:
        raise ScenarioError(f"{label}: unknown parameter {unknown[0]!r}; {name} takes {', '.join(readers)}.")
    kwargs = {
        key: readers[key](f"{label}.{key}", value, frame) for key, value in table.items() if key != "kind"
    }
    try:
        return kind.cls(**kwargs)
    except ConfigError as err:
        raise ConfigError(f"{label}: {err}") from None
    except TypeError as err:  # a required parameter missing
        missing = [
            p.name
            for p in inspect.signature(kind.cls).parameters.values()
            if p.default is inspect.Parameter.empty
            and p.kind is p.POSITIONAL_OR_KEYWORD
            and p.name not in kwargs
        ]
        what = f"missing {', '.join(missing)}" if missing else str(err)
        raise ScenarioError(f"{label}: {what}.") from None


def write_constraint(con: Constraint, frame: Frame) -> dict[str, Any]:
    """The table of ``con``: ``kind``, its own parameters, and the common ones that differ from the
    defaults."""
    name = kind_name(con)
    out: dict[str, Any] = {"kind": name}
    out.update({k: v for k, v in KINDS[name].write(con, frame).items() if v is not None})
    if con.soft:
        out["soft"] = True
        out["weight"] = con.weight
    if con.platforms is not None:
        out["platforms"] = list(con.platforms)
    return out
