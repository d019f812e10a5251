"""Exact WGS84 geodesy: geodetic (lat, lon, alt) <-> ECEF <-> local ENU about a datum.

Everything is vectorized with numpy (any broadcastable shapes), angles in degrees, lengths in
metres. No flat-earth approximation anywhere (doc/formats.md, "Frames and units").

* geodetic -> ECEF: the closed form (e.g. Hofmann-Wellenhof, Lichtenegger & Wasle, *GNSS*,
  2008, eq. 10.4)::

      N(φ) = a / sqrt(1 - e² sin²φ)
      X = (N + h) cos φ cos λ,  Y = (N + h) cos φ sin λ,  Z = (N (1 - e²) + h) sin φ

* ECEF -> geodetic: H. Vermeille, "Direct transformation from geocentric coordinates to
  geodetic coordinates", *Journal of Geodesy* 76:451-454 (2002). A closed form (no iteration)
  exact to floating-point precision (sub-nanometre, ~1e-15 rad) for every point outside the
  evolute of the ellipse, i.e. more than ~43 km from the Earth's centre — every GNSS receiver.
* ECEF <-> ENU: the rotation of the tangent plane at the datum (same reference, eq. 10.14)::

      [e]   [      -sin λ0             cos λ0        0    ] [X - X0]
      [n] = [-sin φ0 cos λ0    -sin φ0 sin λ0    cos φ0  ] [Y - Y0]
      [u]   [ cos φ0 cos λ0     cos φ0 sin λ0    sin φ0  ] [Z - Z0]

NavSatFix allows a NaN altitude (no vertical solution). Every function that takes an altitude
has ``nan_alt``: ``None`` (default) propagates NaN as IEEE arithmetic does; a number replaces
a NaN altitude by that value (``nan_alt=0.0`` treats it as on the ellipsoid; the ingest path
passes the datum's altitude, which keeps the horizontal error of a missing altitude at
~h·d/R, about 1.5 cm for 10 m of height error at 10 km from the datum).
"""
from __future__ import annotations

import numpy as np

#: WGS84 semi-major axis (m) and flattening (NIMA TR8350.2, 3rd ed., table 3.1).
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)            # first eccentricity squared
WGS84_B = WGS84_A * (1.0 - WGS84_F)             # semi-minor axis (m)


def _fill_alt(alt, nan_alt):
    alt = np.asarray(alt, dtype=float)
    if nan_alt is None:
        return alt
    return np.where(np.isnan(alt), float(nan_alt), alt)


def geodetic_to_ecef(lat, lon, alt, *, nan_alt=None):
    """WGS84 geodetic -> Earth-centred, Earth-fixed coordinates.

    Args:
        lat, lon: geodetic latitude and longitude (degrees), broadcastable arrays.
        alt: height above the ellipsoid (m).
        nan_alt: value replacing a NaN altitude (``None``: NaN propagates).

    Returns:
        (x, y, z) in metres, arrays of the broadcast shape.
    """
    with np.errstate(invalid='ignore'):          # a missing fix (NaN/inf) stays NaN
        phi = np.radians(np.asarray(lat, dtype=float))
        lam = np.radians(np.asarray(lon, dtype=float))
    h = _fill_alt(alt, nan_alt)
    sin_phi = np.sin(phi)
    cos_phi = np.cos(phi)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * sin_phi * sin_phi)
    x = (n + h) * cos_phi * np.cos(lam)
    y = (n + h) * cos_phi * np.sin(lam)
    z = (n * (1.0 - WGS84_E2) + h) * sin_phi
    return x, y, z


def ecef_to_geodetic(x, y, z):
    """ECEF -> WGS84 geodetic by Vermeille's (2002) closed form.

    With p = (X²+Y²)/a², q = (1-e²) Z²/a², r = (p+q-e⁴)/6, s = e⁴pq/(4r³),
    t = ∛(1+s+√(s(2+s))), u = r(1+t+1/t), v = √(u²+e⁴q), w = e²(u+v-q)/(2v),
    k = √(u+v+w²) - w, D = k√(X²+Y²)/(k+e²):

        φ = 2 atan(Z / (D + √(D²+Z²))),  λ = atan2(Y, X),  h = (k+e²-1)/k · √(D²+Z²).

    Valid (and exact to rounding) outside the evolute, i.e. for points more than ~43 km from
    the Earth's centre.

    Returns:
        (lat, lon, alt): degrees, degrees, metres.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    z = np.asarray(z, dtype=float)
    a2 = WGS84_A * WGS84_A
    e2 = WGS84_E2
    e4 = e2 * e2
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    p = rho2 / a2
    q = (1.0 - e2) * z * z / a2
    r = (p + q - e4) / 6.0
    s = e4 * p * q / (4.0 * r ** 3)
    t = np.cbrt(1.0 + s + np.sqrt(s * (2.0 + s)))
    u = r * (1.0 + t + 1.0 / t)
    v = np.sqrt(u * u + e4 * q)
    w = e2 * (u + v - q) / (2.0 * v)
    k = np.sqrt(u + v + w * w) - w
    d = k * rho / (k + e2)
    dz = np.sqrt(d * d + z * z)
    lat = np.degrees(2.0 * np.arctan2(z, d + dz))
    lon = np.degrees(np.arctan2(y, x))
    alt = (k + e2 - 1.0) / k * dz
    return lat, lon, alt


def _enu_rotation(lat0, lon0):
    """Rows of the ECEF->ENU rotation at (lat0, lon0): (east, north, up), each (3, ...)."""
    phi = np.radians(np.asarray(lat0, dtype=float))
    lam = np.radians(np.asarray(lon0, dtype=float))
    sp, cp, sl, cl = np.sin(phi), np.cos(phi), np.sin(lam), np.cos(lam)
    zero = np.zeros_like(sp)
    east = (-sl, cl, zero)
    north = (-sp * cl, -sp * sl, cp)
    up = (cp * cl, cp * sl, sp)
    return east, north, up


def ecef_to_enu(x, y, z, lat0, lon0, alt0, *, nan_alt=None):
    """ECEF -> local ENU (m) about the datum (lat0, lon0, alt0) (degrees, degrees, m)."""
    x0, y0, z0 = geodetic_to_ecef(lat0, lon0, alt0, nan_alt=nan_alt)
    dx = np.asarray(x, dtype=float) - x0
    dy = np.asarray(y, dtype=float) - y0
    dz = np.asarray(z, dtype=float) - z0
    east, north, up = _enu_rotation(lat0, lon0)
    e = east[0] * dx + east[1] * dy
    n = north[0] * dx + north[1] * dy + north[2] * dz
    u = up[0] * dx + up[1] * dy + up[2] * dz
    return e, n, u


def enu_to_ecef(e, n, u, lat0, lon0, alt0, *, nan_alt=None):
    """Local ENU (m) about the datum -> ECEF (m): the transpose rotation plus the datum."""
    x0, y0, z0 = geodetic_to_ecef(lat0, lon0, alt0, nan_alt=nan_alt)
    e = np.asarray(e, dtype=float)
    n = np.asarray(n, dtype=float)
    u = np.asarray(u, dtype=float)
    east, north, up = _enu_rotation(lat0, lon0)
    x = x0 + east[0] * e + north[0] * n + up[0] * u
    y = y0 + east[1] * e + north[1] * n + up[1] * u
    z = z0 + north[2] * n + up[2] * u
    return x, y, z


def geodetic_to_enu(lat, lon, alt, lat0, lon0, alt0, *, nan_alt=None):
    """WGS84 geodetic -> local ENU about the datum (lat0, lon0, alt0).

    Args:
        lat, lon, alt: the points (degrees, degrees, m above the ellipsoid), broadcastable.
        lat0, lon0, alt0: the datum (degrees, degrees, m).
        nan_alt: value replacing a NaN altitude of the points and of the datum (``None``:
            NaN propagates to e, n, u).

    Returns:
        (e, n, u): metres east, north, up of the datum's tangent plane.
    """
    x, y, z = geodetic_to_ecef(lat, lon, alt, nan_alt=nan_alt)
    return ecef_to_enu(x, y, z, lat0, lon0, alt0, nan_alt=nan_alt)


def enu_to_geodetic(e, n, u, lat0, lon0, alt0, *, nan_alt=None):
    """Local ENU about the datum -> WGS84 geodetic (lat, lon in degrees, alt in m).

    The exact inverse of :func:`geodetic_to_enu` (rotation back to ECEF, then Vermeille).
    ``nan_alt`` replaces a NaN datum altitude.
    """
    x, y, z = enu_to_ecef(e, n, u, lat0, lon0, alt0, nan_alt=nan_alt)
    return ecef_to_geodetic(x, y, z)
