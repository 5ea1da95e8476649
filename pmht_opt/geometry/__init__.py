"""Geometry: the plane the planner works in, coverage measured in it, and the earth it maps onto.

- :mod:`~pmht_opt.geometry.plane`: distances to polylines, crossings between paths;
- :mod:`~pmht_opt.geometry.coverage`: the one coverage measure (which locales a set of paths misses);
- :mod:`~pmht_opt.geometry.earth`: latitude and longitude to a local east-north plane and back.
"""

from pmht_opt.geometry.coverage import COVERAGE_RTOL, miss_distances, missed, missed_locales
from pmht_opt.geometry.earth import GeoOrigin, LocalTangentPlane, check_origin
from pmht_opt.geometry.plane import count_crossings, point_polyline_distance, segments_cross

__all__ = [
    "COVERAGE_RTOL",
    "GeoOrigin",
    "LocalTangentPlane",
    "check_origin",
    "count_crossings",
    "miss_distances",
    "missed",
    "missed_locales",
    "point_polyline_distance",
    "segments_cross",
]
