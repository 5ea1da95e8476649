"""Geo-referenced missions: latitude/longitude on the WGS84 ellipsoid to a local east-north plane and back.

The planner works in a plane. A geo-referenced mission fixes an *origin* (latitude, longitude) and
plans in the local tangent plane there: the east-north-up (ENU) frame whose origin is the origin on
the ellipsoid, ``e`` pointing east, ``n`` north and ``u`` along the ellipsoid's normal. A point on the
ellipsoid (height 0) is mapped to ECEF (earth-centred, earth-fixed) coordinates, rotated into ENU, and
its ``(e, n)`` kept; the small ``u`` (the drop of the curved surface below the plane, ``-s^2 / 2R``:
about 8 m at 10 km) is dropped. That is an orthographic projection onto the tangent plane, exact in
both directions: :meth:`LocalTangentPlane.to_geodetic` finds the point of the ellipsoid whose
projection is ``(e, n)`` (to 1e-9 m).

What it costs is distortion: the plane shortens distances along the radius from the origin by a factor
``cos(s / R)`` (``s`` the distance from the origin, ``R`` the earth's radius of curvature), and leaves
them unchanged across it. A distance measured in the plane between points within ``s`` of the origin
is shorter than the geodesic distance on the ellipsoid by at most about ``d s^2 / (2 R^2)`` for a
leg of length ``d``: under 1 cm for any two points within 5 km of the origin, under 3 cm within 10 km
(the tests hold it to 0.1 m within 10 km against exact geodesics), half a metre at 50 km, which is why
points further than :data:`MAX_DISTANCE` from the origin are refused. Headings are exact at the origin
and off by under ``s^2 / (2 R^2)`` radians elsewhere.

Units are SI: metres in the plane, so a geo-referenced scenario's speeds are m/s, accelerations m/s^2,
``q`` m^2/s^5 and ``r`` m^2 (docs/conventions.md section 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pmht_opt.exceptions import ConfigError, ScenarioError

#: WGS84 semi-major axis (m).
WGS84_A = 6378137.0
#: WGS84 flattening.
WGS84_F = 1.0 / 298.257223563
#: First eccentricity squared.
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
#: Points further than this (m) from the origin are refused: beyond it the plane's distances are off by
#: more than half a metre, and such a point is more often a swapped latitude and longitude.
MAX_DISTANCE = 50_000.0


def geodetic_to_ecef(lat: Any, lon: Any, height: Any = 0.0) -> np.ndarray:
    """ECEF coordinates ``(..., 3)`` in metres of latitudes and longitudes in degrees at ``height`` (m)
    above the WGS84 ellipsoid."""
    phi = np.radians(np.asarray(lat, dtype=float))
    lam = np.radians(np.asarray(lon, dtype=float))
    h = np.asarray(height, dtype=float)
    sin_phi = np.sin(phi)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_phi**2)  # prime vertical radius of curvature
    x = (n + h) * np.cos(phi) * np.cos(lam)
    y = (n + h) * np.cos(phi) * np.sin(lam)
    z = (n * (1.0 - WGS84_E2) + h) * sin_phi
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude and longitude (degrees) and height (m) of ECEF points ``(..., 3)``.

    The latitude is found by fixed-point iteration on ``tan(phi) = z / (p (1 - e^2 N / (N + h)))``,
    which contracts by a factor of about ``e^2`` per step near the surface: ten steps reach the
    rounding of double precision (1e-9 m) anywhere a vehicle flies.
    """
    p3 = np.asarray(xyz, dtype=float)
    x, y, z = p3[..., 0], p3[..., 1], p3[..., 2]
    p = np.hypot(x, y)
    lam = np.arctan2(y, x)
    phi = np.arctan2(z, p * (1.0 - WGS84_E2))
    h = np.zeros_like(p)
    for _ in range(10):
        n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(phi) ** 2)
        cos_phi, sin_phi = np.cos(phi), np.sin(phi)
        # Near the poles p / cos(phi) loses precision; z / sin(phi) does not. Both branches are
        # evaluated: each divides by 1 where its own divisor vanishes (the other branch is taken there).
        h = np.where(
            np.abs(cos_phi) > 1e-3,
            p / np.where(cos_phi == 0, 1.0, cos_phi) - n,
            z / np.where(sin_phi == 0, 1.0, sin_phi) - n * (1.0 - WGS84_E2),
        )
        phi = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    return np.degrees(phi), np.degrees(lam), h


@dataclass(frozen=True)
class GeoOrigin:
    """The origin of a geo-referenced mission: latitude and longitude in degrees (WGS84).

    Raises :class:`~pmht_opt.exceptions.ScenarioError` naming the field for a value that is not a
    finite number in range.
    """

    lat: float
    lon: float

    def __post_init__(self) -> None:
        limits: dict[str, float] = {"lat": 90.0, "lon": 180.0}
        for key, limit in limits.items():
            value: Any = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ScenarioError(f"origin.{key}: expected a number of degrees, got {value!r}.")
            try:
                degrees = float(value)
            except OverflowError:  # an integer beyond the float range
                degrees = math.inf
            if not math.isfinite(degrees) or abs(degrees) > limit:
                raise ScenarioError(
                    f"origin.{key}: expected degrees in [-{limit:g}, {limit:g}], got {value!r}."
                )
            object.__setattr__(self, key, degrees)
        if abs(self.lat) == 90.0:
            raise ScenarioError("origin.lat: a pole has no east and north; choose an origin off the pole.")

    @property
    def plane(self) -> LocalTangentPlane:
        """The local tangent plane at this origin."""
        return LocalTangentPlane(self)


class LocalTangentPlane:
    """The east-north plane tangent to the WGS84 ellipsoid at ``origin`` (module notes).

    Parameters
    ----------
    origin
        Latitude and longitude of the plane's origin, in degrees.
    """

    def __init__(self, origin: GeoOrigin) -> None:
        self.origin = origin
        phi, lam = math.radians(origin.lat), math.radians(origin.lon)
        sp, cp, sl, cl = math.sin(phi), math.cos(phi), math.sin(lam), math.cos(lam)
        #: Rows: the east, north and up unit vectors in ECEF.
        self.rotation = np.array(
            [
                [-sl, cl, 0.0],
                [-sp * cl, -sp * sl, cp],
                [cp * cl, cp * sl, sp],
            ]
        )
        self.center = geodetic_to_ecef(origin.lat, origin.lon)

    def to_local(self, latlon: Any, name: str = "points") -> np.ndarray:
        """``(..., 2)`` east and north (m) of points given as ``(..., 2)`` latitude and longitude
        (degrees), on the ellipsoid.

        Raises
        ------
        ScenarioError
            A latitude or longitude out of range, or a point further than :data:`MAX_DISTANCE` from
            the origin (the message names ``name`` and the row, and suggests swapped coordinates).
        """
        arr = np.asarray(latlon, dtype=float)
        if arr.shape[-1:] != (2,):
            raise ScenarioError(f"{name}: expected [lat, lon] pairs, got shape {arr.shape}.")
        lat, lon = arr[..., 0], arr[..., 1]
        bad = np.flatnonzero((np.abs(lat) > 90.0).ravel() | (np.abs(lon) > 180.0).ravel())
        if bad.size:
            row = int(bad[0])
            raise ScenarioError(
                f"{name}: row {row} is not [lat, lon] in degrees: {arr.reshape(-1, 2)[row].tolist()}."
            )
        enu = (geodetic_to_ecef(lat, lon) - self.center) @ self.rotation.T
        far = np.flatnonzero((np.linalg.norm(enu, axis=-1) > MAX_DISTANCE).ravel())
        if far.size:
            row = int(far[0])
            dist = float(np.linalg.norm(enu.reshape(-1, 3)[row]))
            raise ScenarioError(
                f"{name}: row {row} ({arr.reshape(-1, 2)[row].tolist()}) is {dist / 1000:.0f} km from the "
                f"origin ({self.origin.lat:g}, {self.origin.lon:g}); points must lie within "
                f"{MAX_DISTANCE / 1000:g} km (are latitude and longitude swapped? points are [lat, lon])."
            )
        return np.ascontiguousarray(enu[..., :2])

    def to_geodetic(self, en: Any) -> np.ndarray:
        """``(..., 2)`` latitude and longitude (degrees) of the ellipsoid points whose projections on
        the plane are ``(..., 2)`` east and north (m): the inverse of :meth:`to_local`.

        The point is ``center + e E + n N + u U`` with the ``u`` that puts it on the ellipsoid; ``u``
        is found by Newton steps on the height, whose derivative along ``U`` is the cosine of the
        angle between the plane's normal and the local one (1 to within ``s^2 / 2R^2``), so three
        steps reach 1e-9 m.
        """
        en = np.asarray(en, dtype=float)
        if en.shape[-1:] != (2,):
            raise ScenarioError(f"expected (..., 2) east and north, got shape {en.shape}.")
        east, north = en[..., 0], en[..., 1]
        u = -(east**2 + north**2) / (2.0 * WGS84_A)  # the sphere's drop: a close first guess
        for _ in range(4):
            enu = np.stack([east, north, u], axis=-1)
            lat, lon, h = ecef_to_geodetic(self.center + enu @ self.rotation)
            u = u - h
        return np.stack([lat, lon], axis=-1)


def check_origin(origin: Any) -> GeoOrigin | None:
    """``origin`` if it is a :class:`GeoOrigin` or ``None``, else :class:`ConfigError` naming it."""
    if origin is not None and not isinstance(origin, GeoOrigin):
        raise ConfigError(f"origin: expected a GeoOrigin or None, got {type(origin).__name__}.")
    return origin
