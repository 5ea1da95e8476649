"""Plans as GeoJSON (RFC 7946): paths, sites and starts, and the shapes the plan keeps to.

* ``kind = "path"`` LineString, one per platform: its positions ``t = 0..T`` (vertex ``t`` at time
  ``t dt``); properties ``platform``, ``distance``, ``duration`` (s), ``dt``, ``locales`` (how many
  it is assigned). A path that crosses the antimeridian is a MultiLineString of its parts.
* ``kind = "locale"`` Point, one per locale: properties ``index``, ``platform`` (its assignment),
  ``visit_step`` (``1..T``), ``visit_time`` (s), ``miss_distance`` (to the nearest path) and
  ``covered`` (within the scenario's coverage radius).
* ``kind = "start"`` Point, one per platform: property ``platform``.
* Polygons, drawn first so that a GIS tool shows them beneath the paths:
  ``kind = "bounds"``, the scenario's area; ``kind = "area_bounds"``, each
  :class:`~pmht_opt.constraints.AreaBounds` (property ``constraint``, its name); ``kind = "keep_out"``,
  each :class:`~pmht_opt.constraints.CircleObstacle` and :class:`~pmht_opt.constraints.PolygonObstacle`
  (properties ``constraint``, ``shape`` ``"circle"`` or ``"polygon"``, ``platforms``: those it binds,
  ``null`` for all; a circle's ``center`` and ``radius``); ``kind = "coverage"``, each site's disc of
  its coverage radius (properties ``index`` and ``radius``). A disc is a polygon of
  :data:`CIRCLE_SIDES` sides: circumscribed round a keep-out disc, so that the drawn zone holds the
  whole zone, and inscribed in a coverage disc, so that the drawn footprint claims no more than the
  sensor sees (either way within ``1 - cos(pi / CIRCLE_SIDES)``, 0.1%, of the radius).

Platforms and locales are 0-based, as in the library. With a geo origin the coordinates are
``[longitude, latitude]`` on WGS84 (RFC 7946 section 3.1.1), to 1e-9 degrees, lengths are metres,
lines and polygons are cut at the antimeridian and polygons wound counter-clockwise
(:mod:`pmht_opt.io.antimeridian`), and the collection has a ``bbox``. A scenario that is not
geo-referenced has no place on the globe: its file holds the plane's ``[x, y]`` in the scenario's unit,
and says so in a foreign member, ``"pmht_opt": {"frame": "plane"}`` (RFC 7946 section 4 allows other
coordinates only by prior arrangement; a GIS tool will draw them near longitude 0, latitude 0).
:func:`~pmht_opt.io.read_points` reads locales and starts back from either.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.constraints import AreaBounds, CircleObstacle, PolygonObstacle
from pmht_opt.exceptions import ScenarioError
from pmht_opt.geometry.coverage import COVERAGE_RTOL
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.io.antimeridian import Globe
from pmht_opt.result import check_plan
from pmht_opt.validation import file_path, writing

#: Every feature's ``kind`` property.
KINDS = ("bounds", "area_bounds", "keep_out", "coverage", "path", "locale", "start")
#: Sides of the polygon that draws a disc.
CIRCLE_SIDES = 72


class _Writer:
    """Geometry in the file's coordinates: on the globe (:class:`~pmht_opt.io.antimeridian.Globe`)
    or the plane's own."""

    def __init__(self, origin: GeoOrigin | None) -> None:
        self.origin = origin
        self.globe = None if origin is None else Globe(origin.lon)

    def _latlon(self, points: np.ndarray) -> np.ndarray:
        assert self.origin is not None
        return self.origin.plane.to_geodetic(np.asarray(points, dtype=float).reshape(-1, 2))

    def points(self, points: np.ndarray) -> list[Any]:
        if self.globe is None:
            return np.asarray(points, dtype=float).tolist()
        return self.globe.point(self._latlon(points))

    def line(self, points: np.ndarray) -> dict[str, Any]:
        if self.globe is None:
            return {"type": "LineString", "coordinates": np.asarray(points, dtype=float).tolist()}
        return self.globe.line(self._latlon(points))

    def polygon(self, ring: np.ndarray) -> dict[str, Any]:
        """The polygon of ``ring (K, 2)`` (not closed; either orientation): closed, counter-clockwise."""
        ring = np.asarray(ring, dtype=float)
        if self.globe is not None:
            return self.globe.polygon(self._latlon(ring))
        x, y = ring[:, 0], ring[:, 1]
        if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
            ring = ring[::-1]
        return {"type": "Polygon", "coordinates": [[*ring.tolist(), ring[0].tolist()]]}


def disc(center: Any, radius: float, outside: bool) -> np.ndarray:
    """``(CIRCLE_SIDES, 2)`` corners, counter-clockwise, of a regular polygon round the disc: its
    edges tangent to the circle (``outside``: it contains the disc, corners at ``radius / cos(pi /
    n)``), or its corners on it (it lies inside the disc)."""
    n = CIRCLE_SIDES
    angle = 2 * np.pi * (np.arange(n) + 0.5) / n
    reach = radius / np.cos(np.pi / n) if outside else radius
    return np.asarray(center, dtype=float) + reach * np.column_stack([np.cos(angle), np.sin(angle)])


def _box(box: Any) -> np.ndarray:
    xmin, xmax, ymin, ymax = (float(v) for v in box)
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]])


def _feature(geometry: dict[str, Any], **properties: Any) -> dict[str, Any]:
    return {"type": "Feature", "geometry": geometry, "properties": properties}


def _shapes(result: Any, out: _Writer) -> list[dict[str, Any]]:
    """The polygon features (module notes): the area, the constraints' shapes, the footprints."""
    sc = result.scenario
    features = []
    if sc.bounds is not None:
        features.append(_feature(out.polygon(_box(sc.bounds)), kind="bounds"))
    for con in result.constraints:
        platforms = None if con.platforms is None else [int(m) for m in con.platforms]
        if isinstance(con, AreaBounds):
            features.append(_feature(out.polygon(_box(con.box)), kind="area_bounds", constraint=con.name))
        elif isinstance(con, CircleObstacle):
            geometry = out.polygon(disc(con.center, con.radius, outside=True))
            features.append(
                _feature(
                    geometry,
                    kind="keep_out",
                    constraint=con.name,
                    shape="circle",
                    platforms=platforms,
                    center=out.points(con.center[None])[0],
                    radius=float(con.radius),
                )
            )
        elif isinstance(con, PolygonObstacle):
            geometry = out.polygon(con.vertices)
            features.append(
                _feature(geometry, kind="keep_out", constraint=con.name, shape="polygon", platforms=platforms)
            )
    for n, (site, radius) in enumerate(zip(sc.locales, sc.radii, strict=True)):
        geometry = out.polygon(disc(site, float(radius), outside=False))
        features.append(_feature(geometry, kind="coverage", index=n, radius=float(radius)))
    return features


def plan_geojson(result: Any, origin: GeoOrigin | None = None) -> dict[str, Any]:
    """The GeoJSON object (a FeatureCollection) of the plan ``result`` (module notes)."""
    sc = result.scenario
    out = _Writer(origin)
    pos = np.asarray(result.positions)
    M, T1, _ = pos.shape
    miss = np.asarray(result.miss_distance)
    counts = np.bincount(result.assignment, minlength=M)
    features = _shapes(result, out)
    for m in range(M):
        seg = np.diff(pos[m], axis=0)
        properties = {
            "kind": "path",
            "platform": m,
            "distance": float(np.hypot(seg[:, 0], seg[:, 1]).sum()),
            "duration": (T1 - 1) * sc.dt,
            "dt": sc.dt,
            "locales": int(counts[m]),
        }
        features.append(_feature(out.line(pos[m]), **properties))
    locale_xy = out.points(sc.locales)
    radii = sc.radii
    for n in range(sc.n_locales):
        step = int(result.visit_time[n])
        properties = {
            "kind": "locale",
            "index": n,
            "platform": int(result.assignment[n]),
            "visit_step": step,
            "visit_time": step * sc.dt,
            "miss_distance": float(miss[n]),
            "radius": float(radii[n]),
            "covered": bool(miss[n] <= radii[n] * (1 + COVERAGE_RTOL)),
        }
        features.append(_feature({"type": "Point", "coordinates": locale_xy[n]}, **properties))
    start_xy = out.points(sc.start_positions)
    for m in range(M):
        features.append(_feature({"type": "Point", "coordinates": start_xy[m]}, kind="start", platform=m))
    collection: dict[str, Any] = {"type": "FeatureCollection"}
    radius = sc.coverage_radius
    meta: dict[str, Any] = {
        "scenario": sc.name,
        "coverage_radius": radius.tolist() if isinstance(radius, np.ndarray) else radius,
        "dt": sc.dt,
    }
    if out.globe is None:
        meta["frame"] = "plane"
    else:
        assert origin is not None
        meta.update({"frame": "wgs84", "origin": [origin.lat, origin.lon]})
        collection["bbox"] = out.globe.bbox(np.array([c for f in features for c in positions(f["geometry"])]))
    collection["pmht_opt"] = meta
    collection["features"] = features
    return collection


def positions(geometry: dict[str, Any]) -> list[list[float]]:
    """Every position of a Point, LineString, Polygon or their Multi- forms, in order."""
    coords, kind = geometry["coordinates"], geometry["type"]
    depth = {"Point": 0, "LineString": 1, "MultiPoint": 1, "Polygon": 2, "MultiLineString": 2}.get(kind, 3)
    out = [coords]
    for _ in range(depth):
        out = [c for part in out for c in part]
    return out


def export_geojson(result: Any, path: str | Path, origin: GeoOrigin | None = None) -> Path:
    """Write the plan ``result`` to ``path`` as GeoJSON (module notes); returns ``path``."""
    text = json.dumps(plan_geojson(check_plan(result), check_origin(origin))) + "\n"
    with writing(path) as part:
        part.write_text(text, encoding="utf-8")
    return file_path("path", path)


def line_positions(geometry: dict[str, Any]) -> np.ndarray:
    """A path's positions ``(K, 2)``: a LineString's coordinates, or the parts of a MultiLineString
    joined again. Each cut at the antimeridian ends one part and starts the next
    (:mod:`pmht_opt.io.antimeridian`), so both copies of it are dropped."""
    if geometry.get("type") != "MultiLineString":
        return np.asarray(geometry["coordinates"], dtype=float)
    parts = [np.asarray(p, dtype=float) for p in geometry["coordinates"]]
    if any(p.ndim != 2 or p.shape[0] < 2 for p in parts):
        raise ValueError("a part of a path holds fewer than two positions")
    last = len(parts) - 1
    return np.concatenate([p[(k > 0) : len(p) - (k < last)] for k, p in enumerate(parts)])


def read_geojson_paths(path: str | Path, origin: GeoOrigin | None = None) -> list[np.ndarray]:
    """The platforms' paths ``(T+1, 2)`` in the plane, in platform order, from a file written by
    :func:`export_geojson` (``origin`` must be the one it was written with, or ``None``)."""
    path = file_path("path", path)
    origin = check_origin(origin)
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:  # unreadable, not UTF-8, not JSON
        raise ScenarioError(f"cannot read {path.name}: {err}.") from None
    meta = obj.get("pmht_opt") if isinstance(obj, dict) else None
    frame = meta.get("frame") if isinstance(meta, dict) else None
    if (frame == "plane") != (origin is None):
        raise ScenarioError(f"{path.name}: frame {frame!r} does not match the origin given ({origin}).")
    try:
        found = [
            (int(f["properties"]["platform"]), line_positions(f["geometry"]))
            for f in obj.get("features", [])
            if (f.get("properties") or {}).get("kind") == "path"
        ]
        platforms = [m for m, _ in found]
        if sorted(platforms) != list(range(len(found))):
            raise ValueError(f"the path features' platforms are {sorted(platforms)}, not 0..{len(found) - 1}")
        if any(c.ndim != 2 or c.shape[1] != 2 or not np.all(np.isfinite(c)) for _, c in found):
            raise ValueError("a path's coordinates are not a list of finite [x, y] pairs")
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as err:
        raise ScenarioError(
            f"{path.name}: not a plan written by pmht-opt (its path features are malformed: {err})."
        ) from None
    if not found:
        raise ScenarioError(f"{path.name}: holds no path feature.")
    found.sort(key=lambda item: item[0])
    if origin is None:
        return [c for _, c in found]
    return [origin.plane.to_local(c[:, ::-1]) for _, c in found]
