"""Where a mission file's points live: the plane itself, or latitude and longitude around an origin."""

from __future__ import annotations

from typing import Any

import numpy as np

from pmht_opt.exceptions import ScenarioError
from pmht_opt.geometry.earth import GeoOrigin
from pmht_opt.io import fields

#: Decimal places of degrees written to files (1e-9 degrees: 0.1 mm).
GEO_DECIMALS = 9
#: How far (m) that rounding moves a point at most: half of 1e-9 degrees of latitude and of longitude
#: (5.6e-5 m each at most), 7.9e-5 m together, rounded up.
GEO_RESOLUTION = 1e-4


class Frame:
    """Reads and writes a mission file's points.

    Without an origin, points are ``[x, y]`` in the scenario's unit and pass through unchanged. With a
    :class:`~pmht_opt.geometry.earth.GeoOrigin`, points in the file are ``[lat, lon]`` in degrees and
    are projected to east and north metres of the origin's tangent plane
    (:mod:`pmht_opt.geometry.earth`); lengths, boxes (``bounds``, ``area_bounds``) and vectors
    (velocities) are metres and m/s in that plane.
    """

    def __init__(self, origin: GeoOrigin | None = None) -> None:
        self.origin = origin
        self._plane = origin.plane if origin is not None else None

    @property
    def geo(self) -> bool:
        """Whether points are latitude and longitude."""
        return self._plane is not None

    def point(self, field: str, value: Any) -> list[float]:
        """One point of the file, ``[x, y]`` or ``[lat, lon]``, in the plane."""
        fields.numbers(field, value, 1)
        return self._to_plane(field, [value])[0]

    def points(self, field: str, value: Any) -> list[list[float]]:
        """An array of points of the file, in the plane."""
        fields.numbers(field, value, 2)
        return self._to_plane(field, value)

    def _to_plane(self, field: str, value: list[Any]) -> list[list[float]]:
        if self._plane is None:
            return [list(map(float, p)) for p in value]
        bad = [i for i, p in enumerate(value) if len(p) != 2]
        if bad:
            raise ScenarioError(
                f"{field}[{bad[0]}]: a geo-referenced mission takes points as [lat, lon], got "
                f"{len(value[bad[0]])} values."
            )
        if not value:
            return []
        return self._plane.to_local(np.asarray(value, dtype=float), name=field).tolist()

    def out_points(self, arr: np.ndarray) -> list[list[float]]:
        """Points ``(K, 2)`` of the plane as the file writes them."""
        a = np.asarray(arr, dtype=float).reshape(-1, 2)
        if self._plane is None:
            return a.tolist()
        # 1e-9 degrees is 0.1 mm: written points read back as typed, not with rounding noise.
        return np.round(self._plane.to_geodetic(a), GEO_DECIMALS).tolist()
