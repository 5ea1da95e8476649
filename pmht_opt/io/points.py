"""Locales and starts from CSV and GeoJSON files.

* **CSV**: a header row, then one point per row. Columns ``x`` and ``y`` (the plane) or ``lat`` and
  ``lon`` (degrees, for a geo-referenced mission; ``latitude``/``longitude`` also read), and for
  locales an optional ``radius`` column (each locale's own coverage radius, in the scenario's units:
  metres for a geo-referenced mission, :func:`read_radii`); other columns (names, notes) are ignored.
* **GeoJSON** (RFC 7946): every ``Point`` and ``MultiPoint`` of a FeatureCollection, a Feature or a
  bare geometry, coordinates ``[lon, lat]``. When features carry a ``kind`` property (as the files
  written by :func:`~pmht_opt.io.export_geojson` do), only those of the wanted kind are read
  (``"locale"`` or ``"start"``), starts in the order of their ``platform`` property. A file written
  from a scenario that is not geo-referenced says so (``"pmht_opt": {"frame": "plane"}``) and holds
  ``[x, y]``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from pmht_opt.exceptions import ScenarioError
from pmht_opt.io import fields
from pmht_opt.io.frame import Frame

_LAT = ("lat", "latitude")
_LON = ("lon", "lng", "long", "longitude")


def read_points(path: str | Path, frame: Frame | None = None, kind: str = "locale") -> list[list[float]]:
    """Points ``[[x, y], ...]`` in the plane, read from a CSV or GeoJSON file.

    Parameters
    ----------
    path
        ``.csv``, ``.geojson`` or ``.json``.
    frame
        How the file's points map to the plane (default: the plane itself).
    kind
        ``"locale"`` or ``"start"``: which features of a GeoJSON file that labels them.

    Raises
    ------
    ScenarioError
        An unreadable file, a missing column, a value that is not a number (naming the row and
        column), coordinates of the wrong frame.
    """
    path = Path(path)
    frame = frame if frame is not None else Frame()
    suffix = path.suffix.lower()
    text = fields.text(path, "utf-8-sig")
    if suffix == ".csv":
        return _read_csv(path.name, text, frame)
    if suffix in (".geojson", ".json"):
        return _read_geojson(path.name, text, frame, kind)
    raise ScenarioError(f"{path.name}: points are read from .csv or .geojson files.")


def read_radii(path: str | Path) -> list[float] | None:
    """The locales' own coverage radii of a point file: a CSV's ``radius`` column, or the ``radius``
    property of a GeoJSON file's locale features (as :func:`~pmht_opt.io.export_geojson` writes
    them); ``None`` where the file has none.

    Raises
    ------
    ScenarioError
        A radius that is not a positive number, naming the row (or feature).
    """
    path = Path(path)
    text = fields.text(path, "utf-8-sig")
    if path.suffix.lower() == ".csv":
        rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
        if not rows:
            return None
        col = _column(path.name, rows[0], ("radius",))
        if col is None:
            return None
        cells: list[tuple[int, Any]] = [
            (line, row[col].strip() if col < len(row) else "") for line, row in enumerate(rows[1:], 2)
        ]
    else:
        try:
            obj = json.loads(text)
        except (RecursionError, ValueError):
            return None  # read_points names what is wrong with the file
        found = [props for _, props in _geometries(obj) if props.get("kind", "locale") == "locale"]
        if not any("radius" in props for props in found):
            return None
        cells = [(i + 1, props.get("radius")) for i, props in enumerate(found)]
    out = []
    for where, cell in cells:
        try:
            value = float(cell)
        except (TypeError, ValueError):
            value = float("nan")
        if not value > 0 or value == float("inf"):
            raise ScenarioError(f"{path.name}, {where}: radius: expected a positive number, got {cell!r}.")
        out.append(value)
    return out


def _column(name: str, header: list[str], options: tuple[str, ...]) -> int | None:
    for i, h in enumerate(header):
        if h.strip().lower() in options:
            return i
    return None


def _read_csv(name: str, text: str, frame: Frame) -> list[list[float]]:
    rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
    if not rows:
        raise ScenarioError(f"{name}: empty; expected a header row and one point per row.")
    header = rows[0]
    lat, lon = _column(name, header, _LAT), _column(name, header, _LON)
    x, y = _column(name, header, ("x",)), _column(name, header, ("y",))
    if frame.geo:
        if lat is None or lon is None:
            raise ScenarioError(
                f"{name}: a geo-referenced mission reads columns 'lat' and 'lon'; the header is {header}."
            )
        cols = (lat, lon)
    else:
        if x is None or y is None:
            hint = " (latitude and longitude need a [geo] origin in the mission)" if lat is not None else ""
            raise ScenarioError(f"{name}: expected columns 'x' and 'y'{hint}; the header is {header}.")
        cols = (x, y)
    out = []
    for line, row in enumerate(rows[1:], start=2):
        point = []
        for c in cols:
            cell = row[c].strip() if c < len(row) else ""
            try:
                point.append(float(cell))
            except ValueError:
                raise ScenarioError(
                    f"{name}, line {line}, column {header[c].strip()!r}: expected a number, got {cell!r}."
                ) from None
        out.append(point)
    if not out:
        raise ScenarioError(f"{name}: no points after the header.")
    return frame.points(name, out)


def _geometries(obj: Any) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """``(geometry, properties)`` of every feature or geometry in a GeoJSON object."""
    if not isinstance(obj, dict):
        return []
    kind = obj.get("type")
    if kind == "FeatureCollection":
        return [g for f in obj.get("features") or [] for g in _geometries(f)]
    if kind == "Feature":
        geom = obj.get("geometry")
        props = obj.get("properties") or {}
        return [(geom, props)] if isinstance(geom, dict) else []
    if kind == "GeometryCollection":
        return [(g, {}) for g in obj.get("geometries") or [] if isinstance(g, dict)]
    return [(obj, {})]


def _read_geojson(name: str, text: str, frame: Frame, kind: str) -> list[list[float]]:
    try:
        obj = json.loads(text)
    except RecursionError:
        raise ScenarioError(f"{name}: nested too deeply to read.") from None
    except ValueError as err:  # the decoder's errors, and integers longer than Python reads
        raise ScenarioError(f"{name}: not valid JSON: {err}.") from None
    plane = isinstance(obj, dict) and (obj.get("pmht_opt") or {}).get("frame") == "plane"
    if plane and frame.geo:
        raise ScenarioError(f"{name}: holds plane [x, y] coordinates, but the mission is geo-referenced.")
    if not plane and not frame.geo:
        raise ScenarioError(
            f"{name}: GeoJSON coordinates are longitude and latitude (RFC 7946); give the mission a "
            "[geo] origin to read them."
        )
    found = _geometries(obj)
    labelled = any("kind" in props for _, props in found)
    picked: list[tuple[float, list[Any]]] = []
    for geom, props in found:
        if labelled and props.get("kind") != kind:
            continue
        coords = geom.get("coordinates")
        if geom.get("type") == "Point":
            pts = [coords]
        elif geom.get("type") == "MultiPoint":
            pts = list(coords or [])
        else:
            continue
        order = props.get("platform", len(picked))
        for p in pts:
            if not isinstance(p, list) or len(p) < 2:
                raise ScenarioError(f"{name}: a point's coordinates must be [lon, lat], got {p!r}.")
            picked.append((order if isinstance(order, (int, float)) else len(picked), p[:2]))
    if not picked:
        which = f"{kind} " if labelled else ""
        raise ScenarioError(f"{name}: no {which}points (Point or MultiPoint features).")
    if kind == "start":
        picked.sort(key=lambda item: item[0])
    coords = [p for _, p in picked]
    if plane:
        return frame.points(name, coords)
    return frame.points(name, [[p[1], p[0]] for p in coords])  # [lon, lat] -> [lat, lon]
