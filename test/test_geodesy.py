"""WGS84 geodesy against hand-computed ECEF cases and pymap3d (an independent implementation)."""
import numpy as np
import pymap3d
import pytest

from herd_ros.ingest.geodesy import (WGS84_A, WGS84_E2, ecef_to_geodetic, enu_to_geodetic,
                                     geodetic_to_ecef, geodetic_to_enu)

A = 6378137.0
B = 6356752.314245            # WGS84 semi-minor axis as published (NIMA TR8350.2)


@pytest.mark.parametrize('lat, lon, alt, xyz', [
    (0.0, 0.0, 0.0, (A, 0.0, 0.0)),
    (0.0, 90.0, 0.0, (0.0, A, 0.0)),
    (0.0, 180.0, 100.0, (-(A + 100.0), 0.0, 0.0)),
    (90.0, 0.0, 0.0, (0.0, 0.0, B)),
    (-90.0, 0.0, 1000.0, (0.0, 0.0, -(B + 1000.0))),
    # 45°N on the ellipsoid, by hand in 40-digit decimal arithmetic: e² = 0.0066943799901413,
    # N = a / sqrt(1 - e²/2) = 6388838.290121 m, X = N cos45 = 4517590.878849,
    # Z = N (1 - e²) sin45 = 4487348.408866
    (45.0, 0.0, 0.0, (4517590.878849, 0.0, 4487348.408866)),
])
def test_hand_computed_ecef(lat, lon, alt, xyz):
    got = geodetic_to_ecef(lat, lon, alt)
    np.testing.assert_allclose(got, xyz, atol=1e-3)
    back = ecef_to_geodetic(*xyz)
    assert abs(back[0] - lat) < 1e-9
    if abs(lat) < 90:
        assert abs(((back[1] - lon + 180) % 360) - 180) < 1e-9
    assert abs(back[2] - alt) < 1e-3


def test_wgs84_constants():
    assert WGS84_A == A
    assert abs(WGS84_A * np.sqrt(1 - WGS84_E2) - B) < 1e-6


def _points_near(lat0, lon0, alt0, radius, n, rng):
    """Points up to ``radius`` metres (horizontally) from the datum, ±500 m in height."""
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    lat, lon, alt = pymap3d.enu2geodetic(r * np.cos(th), r * np.sin(th),
                                         rng.uniform(-500, 500, n), lat0, lon0, alt0)
    return lat, lon, alt


DATUMS = [(27.0153, -108.7937, 50.0), (-33.9, 151.2, 10.0), (0.0, 179.99, 0.0),
          (64.5, -21.0, 300.0), (89.9, 45.0, 0.0)]


@pytest.mark.parametrize('datum', DATUMS)
def test_enu_matches_pymap3d_within_1mm_at_10km(datum):
    rng = np.random.default_rng(1)
    lat, lon, alt = _points_near(*datum, 10_000.0, 2000, rng)
    e, n, u = geodetic_to_enu(lat, lon, alt, *datum)
    e2, n2, u2 = pymap3d.geodetic2enu(lat, lon, alt, *datum)
    assert np.max(np.abs(e - e2)) < 1e-3
    assert np.max(np.abs(n - n2)) < 1e-3
    assert np.max(np.abs(u - u2)) < 1e-3
    assert np.max(np.hypot(e, n)) > 9_000        # really out to ~10 km
    lat3, lon3, alt3 = enu_to_geodetic(e2, n2, u2, *datum)
    lat4, lon4, alt4 = pymap3d.enu2geodetic(e2, n2, u2, *datum)
    assert np.max(np.abs(lat3 - lat4)) < 1e-9
    assert np.max(np.abs(((lon3 - lon4 + 180) % 360) - 180)) < 1e-9
    assert np.max(np.abs(alt3 - alt4)) < 1e-3


@pytest.mark.parametrize('datum', DATUMS)
def test_round_trip_lat_lon_within_1e9_degrees(datum):
    rng = np.random.default_rng(2)
    lat, lon, alt = _points_near(*datum, 10_000.0, 2000, rng)
    back = enu_to_geodetic(*geodetic_to_enu(lat, lon, alt, *datum), *datum)
    assert np.max(np.abs(back[0] - lat)) < 1e-9
    assert np.max(np.abs(((back[1] - lon + 180) % 360) - 180)) < 1e-9
    assert np.max(np.abs(back[2] - alt)) < 1e-6


def test_ecef_round_trip_worldwide_including_high_altitude():
    rng = np.random.default_rng(3)
    lat = np.concatenate([rng.uniform(-90, 90, 20000), [90, -90, 0, 89.999999, -0.0]])
    lon = np.concatenate([rng.uniform(-180, 180, 20000), [0, 0, 180, -180, 12]])
    alt = np.concatenate([rng.uniform(-1000, 40_000, 20000), [0, 0, 0, 1e4, 0]])
    back = ecef_to_geodetic(*geodetic_to_ecef(lat, lon, alt))
    assert np.max(np.abs(back[0] - lat)) < 1e-11
    away = np.abs(lat) < 89.9999
    assert np.max(np.abs(((back[1] - lon + 180) % 360) - 180)[away]) < 1e-11
    assert np.max(np.abs(back[2] - alt)) < 1e-6


def test_enu_distance_is_the_ecef_chord():
    """Invariant: the ENU rotation preserves distance."""
    rng = np.random.default_rng(4)
    datum = (45.0, 7.0, 200.0)
    lat, lon, alt = _points_near(*datum, 5_000.0, 100, rng)
    e, n, u = geodetic_to_enu(lat, lon, alt, *datum)
    x, y, z = geodetic_to_ecef(lat, lon, alt)
    x0, y0, z0 = geodetic_to_ecef(*datum)
    np.testing.assert_allclose(np.sqrt(e**2 + n**2 + u**2),
                               np.sqrt((x - x0)**2 + (y - y0)**2 + (z - z0)**2), atol=1e-6)


def test_east_and_north_axes():
    """A point due north has e == 0 and n > 0; a point on the same parallel to the east
    has n > 0 by the parallel's curvature towards the pole: n ≈ e² tan φ / (2 N)."""
    e, n, _ = geodetic_to_enu(45.01, 7.0, 0.0, 45.0, 7.0, 0.0)
    assert abs(e) < 1e-9 and n > 1100
    e, n, _ = geodetic_to_enu(45.0, 7.01, 0.0, 45.0, 7.0, 0.0)
    n_expected = e**2 * np.tan(np.radians(45.0)) / (2 * 6388838.29)
    assert e > 780 and abs(n - n_expected) < 1e-3


def test_nan_altitude_propagates_or_is_replaced():
    e, n, u = geodetic_to_enu(45.001, 7.001, np.nan, 45.0, 7.0, 0.0)
    assert np.isnan(e) and np.isnan(n) and np.isnan(u)
    got = geodetic_to_enu([45.001, 45.002], [7.001, 7.0], [np.nan, 5.0], 45.0, 7.0, 0.0,
                          nan_alt=0.0)
    ref = geodetic_to_enu([45.001, 45.002], [7.001, 7.0], [0.0, 5.0], 45.0, 7.0, 0.0)
    np.testing.assert_array_equal(got, ref)
