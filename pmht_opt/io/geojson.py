"""Plans as GeoJSON (RFC 7946): a LineString per platform, a Point per locale and per start.

* ``kind = "path"`` LineString, one per platform: its positions ``t = 0..T`` (vertex ``t`` at time
  ``t dt``); properties ``platform``, ``distance``, ``duration`` (s), ``dt``, ``locales`` (how many
  it is assigned).
* ``kind = "locale"`` Point, one per locale: properties ``index``, ``platform`` (its assignment),
  ``visit_step`` (``1..T``), ``visit_time`` (s), ``miss_distance`` (to the nearest path) and
  ``covered`` (within the scenario's coverage radius).
* ``kind = "start"`` Point, one per platform: property ``platform``.

Platforms and locales are 0-based, as in the library. With a geo origin the coordinates are
``[longitude, latitude]`` on WGS84 (RFC 7946 section 3.1.1), to 1e-9 degrees, and lengths are
metres. A scenario that is not geo-referenced has no place on the globe: its file holds the plane's
``[x, y]`` in the scenario's unit, and says so in a foreign member, ``"pmht_opt": {"frame":
"plane"}`` (RFC 7946 section 4 allows other coordinates only by prior arrangement; a GIS tool will
draw them near longitude 0, latitude 0). :func:`~pmht_opt.io.read_points` reads locales and starts
back from either.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pmht_opt.exceptions import ScenarioError
from pmht_opt.geometry.coverage import COVERAGE_RTOL
from pmht_opt.geometry.earth import GeoOrigin, check_origin
from pmht_opt.io.frame import GEO_DECIMALS
from pmht_opt.result import check_plan
from pmht_opt.validation import file_path, writing

#: Every feature's ``kind`` property.
KINDS = ("path", "locale", "start")


def _coords(points: np.ndarray, origin: GeoOrigin | None) -> list[Any]:
    """Positions of ``points (..., 2)`` in the file: ``[lon, lat]`` or the plane's ``[x, y]``."""
    if origin is None:
        return np.asarray(points, dtype=float).tolist()
    latlon = np.round(origin.plane.to_geodetic(points), GEO_DECIMALS)
    return latlon[..., ::-1].tolist()


def plan_geojson(result: Any, origin: GeoOrigin | None = None) -> dict[str, Any]:
    """The GeoJSON object (a FeatureCollection) of the plan ``result`` (module notes)."""
    sc = result.scenario
    pos = np.asarray(result.positions)
    M, T1, _ = pos.shape
    miss = np.asarray(result.miss_distance)
    counts = np.bincount(result.assignment, minlength=M)
    features: list[dict[str, Any]] = []
    for m in range(M):
        seg = np.diff(pos[m], axis=0)
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": _coords(pos[m], origin)},
                "properties": {
                    "kind": "path",
                    "platform": m,
                    "distance": float(np.hypot(seg[:, 0], seg[:, 1]).sum()),
                    "duration": (T1 - 1) * sc.dt,
                    "dt": sc.dt,
                    "locales": int(counts[m]),
                },
            }
        )
    locale_xy = _coords(sc.locales, origin)
    radii = sc.radii
    for n in range(sc.n_locales):
        step = int(result.visit_time[n])
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": locale_xy[n]},
                "properties": {
                    "kind": "locale",
                    "index": n,
                    "platform": int(result.assignment[n]),
                    "visit_step": step,
                    "visit_time": step * sc.dt,
                    "miss_distance": float(miss[n]),
                    "radius": float(radii[n]),
                    "covered": bool(miss[n] <= radii[n] * (1 + COVERAGE_RTOL)),
                },
            }
        )
    start_xy = _coords(sc.start_positions, origin)
    for m in range(M):
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": start_xy[m]},
                "properties": {"kind": "start", "platform": m},
            }
        )
    out: dict[str, Any] = {"type": "FeatureCollection"}
    radius = sc.coverage_radius
    meta: dict[str, Any] = {
        "scenario": sc.name,
        "coverage_radius": radius.tolist() if isinstance(radius, np.ndarray) else radius,
        "dt": sc.dt,
    }
    if origin is None:
        meta["frame"] = "plane"
    else:
        meta.update({"frame": "wgs84", "origin": [origin.lat, origin.lon]})
        every = np.array([c for f in features for c in _flat(f["geometry"])])
        out["bbox"] = [*every.min(axis=0).tolist(), *every.max(axis=0).tolist()]
    out["pmht_opt"] = meta
    out["features"] = features
    return out


def _flat(geometry: dict[str, Any]) -> list[list[float]]:
    coords = geometry["coordinates"]
    return [coords] if geometry["type"] == "Point" else list(coords)


def export_geojson(result: Any, path: str | Path, origin: GeoOrigin | None = None) -> Path:
    """Write the plan ``result`` to ``path`` as GeoJSON (module notes); returns ``path``."""
    text = json.dumps(plan_geojson(check_plan(result), check_origin(origin))) + "\n"
    with writing(path) as part:
        part.write_text(text, encoding="utf-8")
    return file_path("path", path)


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
            (int(f["properties"]["platform"]), np.asarray(f["geometry"]["coordinates"], dtype=float))
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
