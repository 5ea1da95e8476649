"""RFC 7946 checks of a GeoJSON object: an independent validator's, then the tests' own.

The validator is the ``geojson-validator`` package (its JSON-schema lint of the structure, and its
geometry criteria: closed rings, at least three distinct corners, counter-clockwise exteriors, no
self-intersection, no line that jumps across the antimeridian, coordinates in range). The tests' own
checks repeat the ones that matter most here with plain arithmetic: rings closed and counter-clockwise
by the shoelace formula, no step longer than half the globe within a part, and the parts of a line cut
at the antimeridian meeting on it at one latitude.
"""

from __future__ import annotations

import itertools
from typing import Any

import geojson_validator
import numpy as np

geojson_validator.configure_logging(enabled=False)

#: The validator's criteria that are "problematic" rather than "invalid" but still wrong for these files
#: (``duplicate_nodes`` is left out: a path at rest repeats its position; ``excessive_coordinate_precision``
#: too: 1e-9 degrees, 0.1 mm, is the files' stated resolution; and ``crosses_antimeridian``, which reads
#: longitude 180 as -180 and so flags RFC 7946's own example of a line cut at the antimeridian, section
#: 3.1.9: the checks below test for jumps themselves).
PROBLEMS = (
    "holes",
    "self_intersection",
    "outside_lat_lon_boundaries",
    "3d_coordinates",
)


def validator_findings(obj: dict[str, Any], geo: bool = True) -> dict[str, Any]:
    """What the independent validator finds wrong with ``obj``: ``{}`` when nothing."""
    found: dict[str, Any] = {}
    structure = geojson_validator.validate_structure(obj, check_crs=True)
    if structure:
        found["structure"] = structure
    problems = [p for p in PROBLEMS if geo or p != "outside_lat_lon_boundaries"]
    geometries = geojson_validator.validate_geometries(obj, criteria_problematic=problems)
    for key in ("invalid", "problematic"):
        if geometries[key]:
            found[key] = geometries[key]
    if geometries["skipped_validation"]:
        found["skipped"] = geometries["skipped_validation"]
    return found


def shoelace(ring: np.ndarray) -> float:
    """Twice the signed area of a ring (positive: counter-clockwise)."""
    x, y = ring[:, 0], ring[:, 1]
    return float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def rings(geometry: dict[str, Any]) -> list[np.ndarray]:
    """The exterior rings of a Polygon or MultiPolygon."""
    if geometry["type"] == "Polygon":
        return [np.asarray(geometry["coordinates"][0], dtype=float)]
    if geometry["type"] == "MultiPolygon":
        return [np.asarray(p[0], dtype=float) for p in geometry["coordinates"]]
    return []


def lines(geometry: dict[str, Any]) -> list[np.ndarray]:
    """The parts of a LineString or MultiLineString."""
    if geometry["type"] == "LineString":
        return [np.asarray(geometry["coordinates"], dtype=float)]
    if geometry["type"] == "MultiLineString":
        return [np.asarray(p, dtype=float) for p in geometry["coordinates"]]
    return []


def check_rfc7946(obj: dict[str, Any], geo: bool = True) -> None:
    """Assert that ``obj`` is valid RFC 7946 (module notes); ``geo``: coordinates are longitude and
    latitude."""
    found = validator_findings(obj, geo)
    assert not found, f"geojson-validator: {found}"
    for feature in obj["features"]:
        geometry = feature["geometry"]
        for ring in rings(geometry):
            assert ring.shape[0] >= 4 and np.array_equal(ring[0], ring[-1]), "a ring is not closed"
            assert shoelace(ring[:-1]) > 0, f"a {feature['properties']['kind']} ring is not counter-clockwise"
        parts = lines(geometry) + rings(geometry)
        if geo:
            for part in parts:
                assert np.all(np.abs(part[:, 0]) <= 180) and np.all(np.abs(part[:, 1]) <= 90)
                assert np.all(np.abs(np.diff(part[:, 0])) < 180), "a part jumps across the antimeridian"
        if geometry["type"] == "MultiLineString":
            for a, b in itertools.pairwise(parts):
                assert abs(a[-1, 0]) == 180 and b[0, 0] == -a[-1, 0] and a[-1, 1] == b[0, 1], (
                    "the parts of a line do not meet on the antimeridian"
                )
