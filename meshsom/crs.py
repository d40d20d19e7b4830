"""Coordinate reference systems of the inputs: every building is read in metres.

Preprocessing, the encoding's tolerances and the footprint extrusion all work in metres. Most city
models are in a projected CRS in metres (RD New, UTM, Swiss LV95), which is read as it is. Two
common classes are not:

- **Geographic CRSs** (latitude, longitude in degrees, height in metres): Japan's PLATEAU
  (EPSG:6697), and CityJSON or CityGML exported in WGS 84 (EPSG:4326, 4979). Read as they are, a
  building 20 m wide spans 2e-4 on x and y and 20 on z: a needle. Each building is converted to a
  local east-north-up frame in metres about its own centre (geodetic -> geocentric -> ENU on the
  CRS's ellipsoid), on the tangent plane (:func:`local_tangent`: heights stay heights, so flat roofs stay
  flat and walls vertical), exact to far below a millimetre over a building's extent.
- **Projected CRSs in feet** (New York's EPSG:2263 in US survey feet, other US state planes):
  scaled to metres, horizontal and vertical axes each by their own unit.
- **Projections that distort lengths** (Web Mercator, EPSG:3857, in which web services and ArcGIS
  Online export: lengths 1 / cos(latitude) too long while heights are metres): where the point scale
  at a building's centre is off 1 by more than :data:`MAX_SCALE_ERROR`, the building is converted to
  east-north-up metres through longitude and latitude, as a geographic one is.

The CRS is the one the file declares (CityJSON ``metadata.referenceSystem``, a GML ``srsName``),
else :attr:`meshsom.io.ReaderOptions.crs`. It is identified with pyproj (EPSG codes, OGC URNs and
URLs, compound CRSs, OGC's compound URN ``urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::7837`` in the forms PROJ refuses:
one part, or a part without its version field, ``crs:EPSG:31467``); the German AdV names (``urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH``) are
metric projected CRSs. A mesh's ``origin`` stays in the file's own coordinates.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass

import numpy as np

#: AdV (German surveying authorities) CRS names used in German CityGML: all in metres.
_ADV = re.compile(r"^urn:adv:crs:(ETRS89_UTM\d+|DE_DHDN_3GK\d|ETRS89_3GK\d|DE_RD83_3GK\d|DE_PD83_3GK\d)", re.I)


@dataclass(frozen=True)
class CoordinateSystem:
    """What the reader needs to know of a CRS.

    Attributes
    ----------
    name : str
        The CRS as pyproj names it (``"JGD2011 + JGD2011 (vertical) height"``), or as declared.
    declared : str
        The reference as the file gives it.
    geographic : bool
        Latitude and longitude in degrees.
    latitude_first : bool
        Geographic only: the first axis is latitude (EPSG's order for EPSG:4326, 4979, 6697).
    horizontal_m : float
        Metres per unit of the first two axes (projected CRSs).
    vertical_m : float
        Metres per unit of the third axis (1 when the CRS has none: heights read as metres).
    unit : str
        The horizontal unit's name (``"metre"``, ``"US survey foot"``, ``"degree"``).
    semi_major : float
        The ellipsoid's semi-major axis (m), geographic only.
    flattening : float
        The ellipsoid's flattening, geographic only.
    """

    name: str
    declared: str
    geographic: bool = False
    latitude_first: bool = True
    horizontal_m: float = 1.0
    vertical_m: float = 1.0
    unit: str = "metre"
    semi_major: float = 6378137.0
    flattening: float = 1 / 298.257222101

    @property
    def metric(self) -> bool:
        """Read as it is: projected, in metres on all three axes."""
        return not self.geographic and self.horizontal_m == 1.0 and self.vertical_m == 1.0


class NotDegrees(ValueError):
    """Coordinates of a geographic CRS beyond +/-90 and +/-180 (:func:`to_metres`; the message says so)."""


class UnknownCRS(ValueError):
    """A CRS reference that pyproj does not know (the message says what was received)."""


#: GML 2's (and GeoServer's) CRS URL, ``http://www.opengis.net/gml/srs/epsg.xml#4326``: the EPSG code.
_GML_EPSG = re.compile(r"^https?://www\.opengis\.net/gml/srs/epsg\.xml#(\d+)$", re.I)
#: OGC's compound-CRS URN (OGC 07-092r3): ``urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::7837``, its parts
#: ``crs:<authority>:<version>:<code>`` (the version may be empty: ``crs:EPSG:6.12:31467``, ``crs:EPSG::5783``).
_OGC_COMPOUND = re.compile(r"^urn:ogc:def:crs,(crs:.+)$", re.I)
#: One part of it; writers also leave the version out with its colon (``crs:EPSG:31467``, as the geoRES test data
#: of CityGML 1.0 writes), which the last field tells apart: the code is always last.
_OGC_PART = re.compile(r"^crs:([A-Za-z][\w.\-]*):(?:([\w.\-]*):)?(\w+)$")


def _ogc_compound(text: str) -> str | None:
    """A compound-CRS URN (:data:`_OGC_COMPOUND`) in a form PROJ reads, or None where ``text`` is none or a part is
    not ``crs:<authority>:[<version>:]<code>``: one part is that CRS (``EPSG:31467``; PROJ refuses a compound of one),
    several are their compound with versions kept (``urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::7837``)."""
    match = _OGC_COMPOUND.match(text)
    if match is None:
        return None
    parts = [_OGC_PART.match(part.strip()) for part in match.group(1).split(",")]
    if not all(parts):
        return None
    if len(parts) == 1:
        return f"{parts[0].group(1)}:{parts[0].group(3)}"
    return "urn:ogc:def:crs," + ",".join(f"crs:{p.group(1)}:{p.group(2) or ''}:{p.group(3)}" for p in parts)


def _pyproj_crs(text: str):
    """``pyproj.CRS`` of a reference: GML 2's URL as its EPSG code, OGC's compound URN as :func:`_ogc_compound`
    writes it (where PROJ does not read it as it is). Raises ``pyproj.exceptions.CRSError``."""
    import pyproj

    gml = _GML_EPSG.match(text)  # GML 2's form, which PROJ does not know
    try:
        return pyproj.CRS.from_user_input(f"EPSG:{gml.group(1)}" if gml else text)
    except pyproj.exceptions.CRSError:
        compound = _ogc_compound(text)
        if compound is None:
            raise
        return pyproj.CRS.from_user_input(compound)


@functools.lru_cache(maxsize=64)
def coordinate_system(reference: str) -> CoordinateSystem:
    """Identify a CRS reference.

    Parameters
    ----------
    reference : str
        ``"EPSG:7415"``, ``"urn:ogc:def:crs:EPSG::4979"``,
        ``"https://www.opengis.net/def/crs/EPSG/0/6697"``, a compound URN, WKT, ...

    Returns
    -------
    CoordinateSystem

    Raises
    ------
    UnknownCRS
        pyproj cannot identify it, or it is neither geographic nor projected (a geocentric CRS).
    """
    text = str(reference).strip()
    if _ADV.match(text):
        return CoordinateSystem(name=text, declared=text)
    import pyproj

    try:
        crs = _pyproj_crs(text)
    except pyproj.exceptions.CRSError as err:
        raise UnknownCRS(f"CRS {text!r} is not known to pyproj ({str(err).splitlines()[0][:120]})") from None
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    axes = crs.axis_info
    if horizontal.is_geographic and len(horizontal.axis_info) >= 2:
        first = horizontal.axis_info[0].direction.lower()
        vertical = axes[2].unit_conversion_factor if len(axes) > 2 else 1.0
        ellipsoid = horizontal.ellipsoid
        return CoordinateSystem(
            name=crs.name, declared=text, geographic=True, latitude_first=first in ("north", "south"),
            vertical_m=float(vertical), unit=horizontal.axis_info[0].unit_name,
            semi_major=float(ellipsoid.semi_major_metre), flattening=1.0 / float(ellipsoid.inverse_flattening),
        )
    if horizontal.is_projected and len(horizontal.axis_info) >= 2:
        factor = float(horizontal.axis_info[0].unit_conversion_factor)
        vertical = float(axes[2].unit_conversion_factor) if len(axes) > 2 else factor
        return CoordinateSystem(name=crs.name, declared=text, horizontal_m=factor, vertical_m=vertical,
                                unit=horizontal.axis_info[0].unit_name)
    kind = "geocentric" if crs.is_geocentric else crs.type_name
    raise UnknownCRS(f"CRS {text!r} ({crs.name}) is {kind}; expected a projected or geographic CRS")


def geocentric(geodetic: np.ndarray, semi_major: float, flattening: float) -> np.ndarray:
    """Geocentric (ECEF) coordinates of geodetic ones.

    Parameters
    ----------
    geodetic : (V, 3) float64
        Latitude (degrees), longitude (degrees), ellipsoidal height (metres).
    semi_major, flattening : float
        The ellipsoid.

    Returns
    -------
    (V, 3) float64
        X, Y, Z in metres.
    """
    lat = np.radians(geodetic[:, 0])
    lon = np.radians(geodetic[:, 1])
    h = geodetic[:, 2]
    e2 = flattening * (2.0 - flattening)
    sin_lat = np.sin(lat)
    n = semi_major / np.sqrt(1.0 - e2 * sin_lat**2)
    return np.stack([
        (n + h) * np.cos(lat) * np.cos(lon),
        (n + h) * np.cos(lat) * np.sin(lon),
        (n * (1.0 - e2) + h) * sin_lat,
    ], axis=1)


def east_north_up(geodetic: np.ndarray, centre: np.ndarray, semi_major: float, flattening: float) -> np.ndarray:
    """Local east-north-up coordinates (metres) of geodetic points about a geodetic centre.

    Parameters
    ----------
    geodetic : (V, 3) float64
        Latitude, longitude (degrees), height (metres).
    centre : (3,) float64
        The same, of the frame's origin.
    semi_major, flattening : float

    Returns
    -------
    (V, 3) float64
        East, north, up (metres): a right-handed frame with z up, as projected data reads.
    """
    points = geocentric(np.asarray(geodetic, np.float64), semi_major, flattening)
    origin = geocentric(np.asarray(centre, np.float64).reshape(1, 3), semi_major, flattening)[0]
    lat, lon = np.radians(centre[0]), np.radians(centre[1])
    rotation = np.array([
        [-np.sin(lon), np.cos(lon), 0.0],
        [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
        [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
    ])
    return (points - origin) @ rotation.T


#: WGS 84, the ellipsoid of earth-centred (ECEF) coordinates such as 3D Tiles': semi-major axis
#: (metres) and flattening.
WGS84 = (6378137.0, 1.0 / 298.257223563)


def geodetic(points: np.ndarray, semi_major: float, flattening: float) -> np.ndarray:
    """Geodetic coordinates of geocentric (ECEF) ones; the inverse of :func:`geocentric`.

    Parameters
    ----------
    points : (V, 3) float64
        X, Y, Z in metres.
    semi_major, flattening : float

    Returns
    -------
    (V, 3) float64
        Latitude, longitude (degrees), ellipsoidal height (metres). Latitude by fixed-point
        iteration (Bowring's start; well below a micrometre after 5 steps at any height a
        building has).
    """
    x, y, z = np.asarray(points, np.float64).T
    e2 = flattening * (2.0 - flattening)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - e2))
    for _ in range(5):
        n = semi_major / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        h = p * np.cos(lat) + z * np.sin(lat) - semi_major * np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        lat = np.arctan2(z, p * (1.0 - e2 * n / (n + h)))
    n = semi_major / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    h = p * np.cos(lat) + z * np.sin(lat) - semi_major * np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack([np.degrees(lat), np.degrees(np.arctan2(y, x)), h], axis=1)


def east_north_up_of_geocentric(points: np.ndarray, centre: np.ndarray, semi_major: float = WGS84[0],
                                flattening: float = WGS84[1]) -> np.ndarray:
    """East-north-up coordinates (metres) of geocentric points about a geocentric centre.

    Parameters
    ----------
    points : (V, 3) float64
        ECEF X, Y, Z (metres).
    centre : (3,) float64
        ECEF of the frame's origin; its up is the ellipsoid's normal there.
    semi_major, flattening : float
        The ellipsoid (WGS 84 by default).

    Returns
    -------
    (V, 3) float64
    """
    lat, lon, _ = np.radians(geodetic(np.asarray(centre, np.float64).reshape(1, 3), semi_major, flattening)[0])
    rotation = np.array([
        [-np.sin(lon), np.cos(lon), 0.0],
        [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
        [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
    ])
    return (np.asarray(points, np.float64) - centre) @ rotation.T


def to_metres(local: np.ndarray, origin: np.ndarray, crs: CoordinateSystem) -> tuple[np.ndarray, str | None]:
    """A building's coordinates in metres, in a frame with z up.

    Parameters
    ----------
    local : (V, 3) float64
        Coordinates relative to ``origin``, in the CRS's units and axis order.
    origin : (3,) float64
        The building's centre in the CRS (it stays the mesh's world position).
    crs : CoordinateSystem

    Returns
    -------
    local_m : (V, 3) float64
        Projected: each axis scaled by its unit; where the projection's point scale at ``origin`` is off 1 by more
        than :data:`MAX_SCALE_ERROR` (Web Mercator), east, north, up about it, as geographic. Geographic: east,
        north, up about ``origin``.
    note : str or None
        What was done, in words, when anything was (``None`` for a metric projected CRS).

    Raises
    ------
    NotDegrees
        A geographic CRS's coordinates beyond +/-90 and +/-180 (after the axis order is settled).
    """
    if not crs.geographic:
        distorted = _distorted(local, origin, crs)
        if distorted is not None:
            return distorted
    if crs.metric:
        return local, None
    if not crs.geographic:
        scale = np.array([crs.horizontal_m, crs.horizontal_m, crs.vertical_m])
        return local * scale, (f"scaled to metres from {crs.unit} ({crs.name}; x and y times {crs.horizontal_m:.10g}, "
                               f"z times {crs.vertical_m:.10g})")
    order = [0, 1] if crs.latitude_first else [1, 0]
    centre = origin[[order[0], order[1], 2]]
    swapped = ""
    if abs(centre[0]) > 90 and abs(centre[1]) <= 90:  # declared latitude-first, written longitude-first
        order = order[::-1]
        centre = origin[[order[0], order[1], 2]]
        swapped = "; its axes were read in the other order, as the first is beyond +/-90 degrees"
    geodetic = (local + origin)[:, [order[0], order[1], 2]]
    finite = geodetic[np.isfinite(geodetic).all(axis=1)]
    if len(finite) and (np.abs(finite[:, 0]).max() > 90 or np.abs(finite[:, 1]).max() > 180):
        raise NotDegrees(f"its coordinates reach {np.abs(finite[:, :2]).max(axis=0).max():.6g}, beyond the +/-90 "
                         f"and +/-180 degrees of the geographic CRS it declares ({crs.name}): the declaration is wrong "
                         f"(projected coordinates labelled as degrees?)")
    geodetic[:, 2] *= crs.vertical_m
    centre = centre * np.array([1.0, 1.0, crs.vertical_m])
    return local_tangent(geodetic, centre, crs.semi_major, crs.flattening), (
        f"converted to metres from geographic coordinates ({crs.name}), east-north-up about the building's "
        f"centre{swapped}")


def local_tangent(geodetic: np.ndarray, centre: np.ndarray, semi_major: float, flattening: float) -> np.ndarray:
    """East and north (metres) of geodetic points on the tangent plane at ``centre`` (their east-north-up position at
    the centre's height), and up as their height above the centre's: what a projected CRS gives a building, where a
    geocentric east-north-up frame curves it (a flat roof 50 m across sags 0.2 mm at its edges, a wall leans 8e-6 rad
    away from the centre, so that a part on its building's roof no longer meets it). Arguments and result as
    :func:`east_north_up`'s.
    """
    level = np.array(geodetic, np.float64)
    level[:, 2] = centre[2]
    out = east_north_up(level, centre, semi_major, flattening)
    out[:, 2] = geodetic[:, 2] - centre[2]
    return out


#: A projected CRS whose point scale at a building's centre is off 1 by more than this has the building converted to
#: east-north-up metres as a geographic CRS's is: Web Mercator (EPSG:3857, ArcGIS Online's 102100), whose lengths
#: grow as 1 / cos(latitude) (31 % at 40 degrees) while heights stay metres; Lambert-93 at its edges (3e-3). National
#: grids and UTM within its zone (under 1e-3) are read as they are.
MAX_SCALE_ERROR = 1e-3


@functools.lru_cache(maxsize=64)
def _projection(declared: str):
    """(to longitude and latitude, the projection, semi-major axis, flattening) of a projected CRS, or None."""
    import pyproj

    try:
        crs = _pyproj_crs(declared)
    except pyproj.exceptions.CRSError:
        return None
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    if not horizontal.is_projected:
        return None
    geodetic_crs = horizontal.geodetic_crs
    ellipsoid = geodetic_crs.ellipsoid
    return (pyproj.Transformer.from_crs(horizontal, geodetic_crs, always_xy=True), pyproj.Proj(horizontal),
            float(ellipsoid.semi_major_metre), 1.0 / float(ellipsoid.inverse_flattening))


def point_scale(crs: CoordinateSystem, x: float, y: float) -> float | None:
    """The projection's largest point scale (meridional or parallel) at (x, y) of a projected CRS; None where
    pyproj cannot tell (an unknown or geographic CRS)."""
    projection = _projection(crs.declared)
    if projection is None:
        return None
    to_lonlat, proj, _, _ = projection
    lon, lat = to_lonlat.transform(x, y)
    factors = proj.get_factors(lon, lat)
    scales = (float(factors.meridional_scale), float(factors.parallel_scale))
    return max(scales, key=lambda k: abs(k - 1.0)) if all(math.isfinite(k) for k in scales) else None


def _distorted(local: np.ndarray, origin: np.ndarray, crs: CoordinateSystem) -> tuple[np.ndarray, str] | None:
    """A building of a projected CRS whose point scale at its centre is off 1 by more than :data:`MAX_SCALE_ERROR`
    in east-north-up metres about its centre (through longitude and latitude), and the note; else None."""
    scale = point_scale(crs, float(origin[0]), float(origin[1]))
    if scale is None or abs(scale - 1.0) <= MAX_SCALE_ERROR:
        return None
    to_lonlat, _, semi_major, flattening = _projection(crs.declared)
    world = local + origin
    lon, lat = to_lonlat.transform(world[:, 0], world[:, 1])
    geodetic = np.stack([np.asarray(lat), np.asarray(lon), world[:, 2] * crs.vertical_m], axis=1)
    centre_lon, centre_lat = to_lonlat.transform(float(origin[0]), float(origin[1]))
    centre = np.array([centre_lat, centre_lon, float(origin[2]) * crs.vertical_m])
    enu = east_north_up(geodetic, centre, semi_major, flattening)
    return enu, (f"converted to metres east-north-up about the building's centre: {crs.name} scales lengths there by "
                 f"{scale:.4g}")


def looks_geographic(local: np.ndarray, origin: np.ndarray) -> str | None:
    """Why coordinates of no declared CRS look like degrees, or None.

    A building whose x and y span less than 0.01 while z spans over 100 times as much, at
    |x|, |y| <= 180, is a building in latitude and longitude (metres of a real building span
    the same order on all axes).

    Parameters
    ----------
    local : (V, 3) float64
    origin : (3,) float64
    """
    if len(local) == 0:
        return None
    span = local.max(axis=0) - local.min(axis=0)
    flat = max(span[0], span[1])
    if (0 < flat < 0.01 and span[2] > 100 * flat and abs(origin[0]) <= 180 and abs(origin[1]) <= 180):
        return (f"its coordinates look like degrees of latitude and longitude (x and y span {flat:.2g}, "
                f"z spans {span[2]:.3g}) and the file declares no CRS; declare it (CityJSON "
                f"metadata.referenceSystem, GML srsName) or give one (--crs EPSG:4979, reader.crs)")
    return None


@dataclass(frozen=True)
class UtmPoint:
    """A point of WGS 84 in its UTM zone (:func:`utm_point`).

    Attributes
    ----------
    epsg : int
        WGS 84 / UTM zone's EPSG code (32601-32660 north, 32701-32760 south).
    zone : str
        ``"32N"``.
    easting, northing : float
        Metres.
    convergence : float
        Radians from the grid's north to true north there, counter-clockwise (the meridian
        convergence): a frame whose y axis points to true north is turned by this onto the grid.
    """

    epsg: int
    zone: str
    easting: float
    northing: float
    convergence: float

    def place(self, frame: np.ndarray, north: float, height: float) -> np.ndarray:
        """(V, 3) metres of a local frame whose y axis is ``north`` radians clockwise of true north
        (z up, its origin at this point, ``height`` metres up) as (V, 3) metres of the UTM grid."""
        angle = self.convergence - north
        cos, sin = math.cos(angle), math.sin(angle)
        x, y, z = frame[:, 0], frame[:, 1], frame[:, 2]
        return np.stack([cos * x - sin * y + self.easting, sin * x + cos * y + self.northing, z + height], axis=1)


#: True north on a UTM grid is found by projecting a point this far (metres) north of another.
METRES_NORTH = 1.0


def utm_point(latitude: float, longitude: float) -> UtmPoint:
    """Project a WGS 84 latitude and longitude (degrees) into its UTM zone, with the direction of
    true north there (pyproj; a point ``METRES_NORTH`` up the meridian, projected too).

    Raises
    ------
    ValueError
        Latitude outside [-84, 84] (UTM's extent; the poles have UPS) or longitude outside [-180, 180].
    """
    if not (-84.0 <= latitude <= 84.0 and -180.0 <= longitude <= 180.0):
        raise ValueError(f"latitude {latitude:g}, longitude {longitude:g}: outside UTM's extent "
                         f"(latitudes -84 to 84, longitudes -180 to 180)")
    zone = int((longitude + 180.0) // 6.0) % 60 + 1
    epsg = (32600 if latitude >= 0 else 32700) + zone
    to_grid = _utm_transformer(epsg)
    east, north = to_grid.transform(longitude, latitude)
    east1, north1 = to_grid.transform(longitude, latitude + METRES_NORTH / 111_000.0)
    convergence = math.atan2(north1 - north, east1 - east) - math.pi / 2
    return UtmPoint(epsg, f"{zone}{'N' if latitude >= 0 else 'S'}", float(east), float(north), convergence)


@functools.lru_cache(maxsize=8)
def _utm_transformer(epsg: int):
    import pyproj

    return pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
