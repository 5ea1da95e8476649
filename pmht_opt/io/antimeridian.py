"""GeoJSON geometry on the globe: lines and rings cut at the antimeridian, rings wound counter-clockwise.

RFC 7946 section 3.1.9: a line or polygon that crosses the antimeridian (longitude 180) is cut in two
there, each part on its own side, with longitudes in ``[-180, 180]``; a GIS tool that draws a segment
from 179.9999 to -179.9998 draws it the long way round the globe. Section 3.1.6: a polygon's exterior
ring is counter-clockwise (the right-hand rule), closed by repeating its first position.

The plane's points are near a mission's origin (within 50 km, :mod:`pmht_opt.geometry.earth`), so
their longitudes are *unwrapped* around the origin's, ``lon_u = lon0 + ((lon - lon0 + 180) mod 360
- 180)``: continuous, and within one turn of each other. At most one antimeridian is then in reach:
``L = 180`` for an origin east of Greenwich, ``L = -180`` west of it. With ``x = lon_u - L``, points
with ``x <= 0`` lie on its west side and are written at ``lon = x + 180``, points with ``x >= 0`` on its
east side at ``lon = x - 180``.

* A line is cut where a segment from one side to the other meets ``x = 0``: at the latitude
  interpolated linearly along the segment in longitude and latitude (the straight line a GIS tool
  draws), ``lat = lat_a + (0 - x_a) / (x_b - x_a) (lat_b - lat_a)``. That point ends one part and
  starts the next, each writing it on its own side (longitude 180 west of the meridian, -180 east of
  it): the parts meet on the meridian. A vertex exactly on the meridian where the line changes sides
  is repeated, so that every cut is the same pair (:func:`pmht_opt.io.read_geojson_paths` drops it).
* A ring is clipped to each side (Sutherland-Hodgman against the half-planes ``x <= 0`` and
  ``x >= 0``: exact for the convex shapes exported here), each piece closed and wound
  counter-clockwise.
"""

from __future__ import annotations

import itertools

import numpy as np

from pmht_opt.exceptions import ScenarioError
from pmht_opt.io.frame import GEO_DECIMALS


class Globe:
    """Writes ``[lat, lon]`` points near ``lon0`` (degrees) as RFC 7946 geometry (module notes)."""

    def __init__(self, lon0: float) -> None:
        self.lon0 = float(lon0)
        self.meridian = 180.0 if self.lon0 >= 0 else -180.0

    def x(self, latlon: np.ndarray) -> np.ndarray:
        """``(K, 2)`` ``[x, lat]``: each point's unwrapped longitude less the meridian's, and latitude."""
        ll = np.asarray(latlon, dtype=float).reshape(-1, 2)
        lon_u = self.lon0 + (np.mod(ll[:, 1] - self.lon0 + 180.0, 360.0) - 180.0)
        if ll.shape[0] and np.ptp(lon_u) >= 180.0:
            raise ScenarioError(
                "GeoJSON: a shape spans 180 degrees of longitude or more (it is near a pole), which "
                "longitude and latitude cannot draw as one; choose an origin further from the pole."
            )
        return np.column_stack([lon_u - self.meridian, ll[:, 0]])

    def lon(self, x: np.ndarray, side: int) -> np.ndarray:
        """Longitudes ``[-180, 180]`` of ``x`` on ``side`` (``-1`` west of the meridian, ``+1`` east)."""
        out = np.asarray(x, dtype=float) + (180.0 if side < 0 else -180.0)
        return np.clip(out, -180.0, 180.0)

    def _out(self, xy: np.ndarray, side: int) -> list[list[float]]:
        lon = self.lon(xy[:, 0], side)
        return np.round(np.column_stack([lon, xy[:, 1]]), GEO_DECIMALS).tolist()

    def line(self, latlon: np.ndarray) -> dict[str, object]:
        """A LineString through ``latlon (K, 2)``, or a MultiLineString of its parts when it crosses
        the antimeridian (module notes)."""
        xy = self.x(latlon)
        parts: list[list[np.ndarray]] = [[xy[0]]]
        sides = [_side(xy[0, 0])]
        for a, b in itertools.pairwise(xy):
            sb = _side(b[0])
            if sb and sides[-1] and sb != sides[-1]:
                t = (0.0 - a[0]) / (b[0] - a[0])
                cut = np.array([0.0, a[1] + t * (b[1] - a[1])])
                parts[-1].append(cut)
                parts.append([cut])
                sides.append(sb)
            parts[-1].append(b)
            if sb and not sides[-1]:
                sides[-1] = sb
        out = [self._out(np.array(p), s or -1) for p, s in zip(parts, sides, strict=True)]
        if len(out) == 1:
            return {"type": "LineString", "coordinates": out[0]}
        return {"type": "MultiLineString", "coordinates": out}

    def polygon(self, latlon: np.ndarray) -> dict[str, object]:
        """A Polygon of the ring through ``latlon (K, 2)`` (not repeating its first point), or a
        MultiPolygon of its pieces either side of the antimeridian, each closed and counter-clockwise."""
        xy = self.x(latlon)
        pieces = []
        for side in (-1, 1):
            piece = _clip(xy, side)
            if piece.shape[0] >= 3 and abs(_area2(piece)) > 0:
                ring = self._out(piece if _area2(piece) > 0 else piece[::-1], side)
                pieces.append([[*ring, ring[0]]])
        if len(pieces) == 1:
            return {"type": "Polygon", "coordinates": pieces[0]}
        return {"type": "MultiPolygon", "coordinates": pieces}

    def point(self, latlon: np.ndarray) -> list[list[float]]:
        """``[lon, lat]`` of each point, longitudes in ``[-180, 180]``."""
        xy = self.x(latlon)
        lon = np.where(xy[:, 0] <= 0, self.lon(xy[:, 0], -1), self.lon(xy[:, 0], 1))
        return np.round(np.column_stack([lon, xy[:, 1]]), GEO_DECIMALS).tolist()

    def bbox(self, lonlat: np.ndarray) -> list[float]:
        """``[west, south, east, north]`` of written positions ``lonlat (K, 2)`` (RFC 7946 section
        5.2): ``west > east`` when the box crosses the antimeridian."""
        ll = np.asarray(lonlat, dtype=float).reshape(-1, 2)
        x = self.x(ll[:, ::-1])[:, 0]
        lo, hi = float(x.min()), float(x.max())
        west = float(self.lon(np.array([lo]), -1 if lo < 0 else 1)[0])
        east = float(self.lon(np.array([hi]), -1 if hi <= 0 else 1)[0])
        return [west, float(ll[:, 1].min()), east, float(ll[:, 1].max())]


def _side(x: float) -> int:
    return int(np.sign(x))


def _area2(ring: np.ndarray) -> float:
    """Twice the signed area of ``ring (K, 2)`` (shoelace): positive when counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _clip(ring: np.ndarray, side: int) -> np.ndarray:
    """The part of the polygon ``ring (K, 2)`` with ``side * x >= 0`` (Sutherland-Hodgman), without
    repeated consecutive points."""
    out: list[np.ndarray] = []
    for a, b in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        a_in, b_in = side * a[0] >= 0, side * b[0] >= 0
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (0.0 - a[0]) / (b[0] - a[0])
            out.append(np.array([0.0, a[1] + t * (b[1] - a[1])]))
    pts = np.array(out).reshape(-1, 2)
    if pts.shape[0] == 0:
        return pts
    repeated = np.all(pts == np.roll(pts, 1, axis=0), axis=1)
    return pts[~repeated] if not repeated.all() else pts[:1]
