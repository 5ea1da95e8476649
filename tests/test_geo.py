"""The local tangent plane: exact both ways, and distances within 0.1 m of geodesics over 10 km."""

from __future__ import annotations

import numpy as np
import pytest

from pmht_opt.exceptions import ScenarioError
from pmht_opt.geometry.earth import MAX_DISTANCE, GeoOrigin, ecef_to_geodetic, geodetic_to_ecef

#: Origins: mid-latitude south (the example mission), high north, on the equator next to the
#: antimeridian, near the pole.
ORIGINS = [(-35.363261, 149.165230), (60.0, 10.0), (0.0, 179.99), (85.0, -40.0)]
#: The stated bound on plane-against-geodesic distances within 10 km of the origin.
DISTANCE_TOL = 0.1


def _points_around(origin: GeoOrigin, radius: float, n: int, seed: int = 0) -> np.ndarray:
    """``(n, 2)`` lat/lon scattered within ``radius`` metres of ``origin`` (exact geodesics)."""
    geodesic = pytest.importorskip("geographiclib.geodesic").Geodesic.WGS84
    rng = np.random.default_rng(seed)
    out = []
    for az, s in zip(rng.uniform(0, 360, n), radius * np.sqrt(rng.uniform(0, 1, n)), strict=True):
        d = geodesic.Direct(origin.lat, origin.lon, az, s)
        out.append([d["lat2"], d["lon2"]])
    return np.array(out)


def test_ecef_round_trip_is_exact() -> None:
    rng = np.random.default_rng(1)
    lat, lon, h = rng.uniform(-89.9, 89.9, 500), rng.uniform(-180, 180, 500), rng.uniform(-100, 9000, 500)
    lat2, lon2, h2 = ecef_to_geodetic(geodetic_to_ecef(lat, lon, h))
    assert np.max(np.abs(lat2 - lat)) < 1e-11 and np.max(np.abs(lon2 - lon)) < 1e-11
    assert np.max(np.abs(h2 - h)) < 1e-6
    # A known value: the equator at the prime meridian is one semi-major axis from the centre.
    assert np.allclose(geodetic_to_ecef(0.0, 0.0), [6378137.0, 0.0, 0.0])


@pytest.mark.parametrize("lat0, lon0", ORIGINS)
def test_projection_round_trip(lat0: float, lon0: float) -> None:
    origin = GeoOrigin(lat0, lon0)
    rng = np.random.default_rng(2)
    en = rng.uniform(-20_000, 20_000, (200, 2))
    back = origin.plane.to_local(origin.plane.to_geodetic(en))
    assert np.max(np.abs(back - en)) < 1e-6  # metres
    assert np.allclose(origin.plane.to_local([[lat0, lon0]]), 0.0, atol=1e-9)


@pytest.mark.parametrize("lat0, lon0", ORIGINS)
def test_plane_distances_match_geodesics_within_10_km(lat0: float, lon0: float) -> None:
    geodesic = pytest.importorskip("geographiclib.geodesic").Geodesic.WGS84
    origin = GeoOrigin(lat0, lon0)
    pts = _points_around(origin, 10_000.0, 60)
    en = origin.plane.to_local(pts)
    worst = 0.0
    for i in range(len(pts)):
        for j in range(i + 1, len(pts), 3):
            ref = geodesic.Inverse(*pts[i], *pts[j])["s12"]
            worst = max(worst, abs(float(np.hypot(*(en[i] - en[j]))) - ref))
        # From the origin too: the radial shortening s - R sin(s / R).
        ref0 = geodesic.Inverse(lat0, lon0, *pts[i])["s12"]
        worst = max(worst, abs(float(np.hypot(*en[i])) - ref0))
    assert worst < DISTANCE_TOL
    # Headings are true at the origin: a point due north has no east component.
    north = geodesic.Direct(lat0, lon0, 0.0, 5_000.0)
    e, n = origin.plane.to_local([[north["lat2"], north["lon2"]]])[0]
    assert abs(e) < 1e-6 and abs(n - 5_000.0) < 0.01


def test_agrees_with_pyproj_topocentric_when_installed() -> None:
    pyproj = pytest.importorskip("pyproj")
    origin = GeoOrigin(-35.363261, 149.165230)
    pts = np.array([[-35.37, 149.15], [-35.35, 149.18], [-35.40, 149.2]])
    ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    topo = pyproj.Transformer.from_pipeline(
        f"+proj=topocentric +ellps=WGS84 +lat_0={origin.lat} +lon_0={origin.lon} +h_0=0"
    )
    x, y, z = ecef.transform(pts[:, 1], pts[:, 0], np.zeros(len(pts)))
    e, n, _ = topo.transform(x, y, z)
    assert np.allclose(origin.plane.to_local(pts), np.column_stack([e, n]), atol=1e-6)


def test_bad_origins_and_points_name_the_field() -> None:
    with pytest.raises(ScenarioError, match=r"origin.lat: expected degrees in \[-90, 90\]"):
        GeoOrigin(95.0, 10.0)
    with pytest.raises(ScenarioError, match=r"origin\.lon: expected a number"):
        GeoOrigin(10.0, "149")  # type: ignore[arg-type]
    with pytest.raises(ScenarioError, match="pole"):
        GeoOrigin(90.0, 0.0)
    plane = GeoOrigin(-35.36, 149.16).plane
    with pytest.raises(ScenarioError, match=r"locales: row 1 is not \[lat, lon\] in degrees"):
        plane.to_local([[-35.36, 149.16], [149.16, -35.36]], name="locales")
    alps = GeoOrigin(45.9, 7.1).plane
    with pytest.raises(ScenarioError, match=r"locales: row 0 .*latitude and longitude swapped"):
        alps.to_local([[7.1, 45.9]], name="locales")
    with pytest.raises(ScenarioError, match=f"within {MAX_DISTANCE / 1000:g} km"):
        plane.to_local([[-36.5, 149.16]], name="starts")


@pytest.mark.parametrize("lon", [0.0, 45.0, 180.0, -180.0])
def test_the_equator_converts_without_numpy_warnings(lon: float) -> None:
    import warnings

    plane = GeoOrigin(0.0, lon).plane
    points = np.array([[0.0, lon], [0.001, lon - 0.001 if lon > 0 else lon + 0.001], [-0.01, lon]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # 0 / sin(0) in the branch not taken used to warn
        back = plane.to_geodetic(plane.to_local(points))
    assert np.abs(back - points).max() < 1e-12
