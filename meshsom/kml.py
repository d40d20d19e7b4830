"""KML placements of COLLADA models: the KMZ files of Google Earth, SketchUp and 3D Warehouse.

A KMZ is a zip of a KML document and the COLLADA (``.dae``) models it places. Each KML ``<Model>``
links one model (``<Link><href>``, relative to the KML's folder) and puts the model's origin at a
``<Location>`` (WGS 84 longitude and latitude, an altitude), turned by an ``<Orientation>``
(``heading``: degrees clockwise from true north of the model's y axis; ``tilt`` and ``roll``), and
scaled by ``<Scale>`` (x, y, z). A model's own frame is x east, y north, z up, in metres once
:mod:`meshsom.io` has read its COLLADA ``<unit>`` and ``<up_axis>``.

:func:`model_placements` reads a KML document; :meth:`ModelPlacement.place` moves a model into
WGS 84's UTM zone at its location (:func:`meshsom.crs.utm_point`: the heading is turned onto the
grid's north with the meridian convergence), its height from the altitude by ``altitudeMode``:
``absolute`` is the altitude, ``relativeToGround`` is the altitude above a ground KML does not
give (noted), ``clampToGround`` (the default) stands on a ground of unknown height (z from 0,
noted). Buildings stand upright: a tilt or roll is noted and not applied.

:func:`read_kml` reads a KML file on disk as an input (a KMZ's, once extracted, or one beside its
models in a folder: an unzipped KMZ): every model its Models link, placed; :func:`linked_models`
names those models, so that a folder's reader reads them through the KML only.

Buildings drawn as polygons (Google Earth's, ArcGIS' Layer To KML of an extruded layer: a Placemark's
``<Polygon>`` with ``<extrude>1</extrude>`` and altitudes ``relativeToGround``) are footprints
extruded from the ground to their altitude (:func:`footprint_features`, read as GeoJSON footprints
are: :func:`footprint_meshes`; a Placemark of polygons at different heights is a building of parts); a
polygon not extruded, or clamped to the ground, is a rejection saying it is a flat area, and one
extruded from ``absolute`` altitudes (the ground beneath is not in KML) is read only where its
``<ExtendedData>`` gives a height.
"""

from __future__ import annotations

import dataclasses
import math
import posixpath
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator
from urllib.parse import unquote

import numpy as np

__all__ = ["KmlFootprint", "ModelPlacement", "footprint_features", "footprint_meshes", "linked_models", "model_placements", "placed", "read_kml"]

KML_SUFFIX = ".kml"

#: KML's altitude modes (with Google's gx: extensions), and what each makes of the altitude.
ALTITUDE_MODES = ("clampToGround", "relativeToGround", "absolute", "clampToSeaFloor", "relativeToSeaFloor")


@dataclass(frozen=True)
class ModelPlacement:
    """One KML ``<Model>``: where it puts a COLLADA model.

    Attributes
    ----------
    href : str
        The model's path inside the archive (resolved against the KML's folder, ``/``-separated).
    name : str or None
        The placemark's ``<name>``.
    latitude, longitude : float
        Degrees, WGS 84.
    altitude : float
        Metres.
    altitude_mode : str
        One of :data:`ALTITUDE_MODES`.
    heading, tilt, roll : float
        Degrees.
    scale : (3,) tuple of float
    """

    href: str
    name: str | None
    latitude: float
    longitude: float
    altitude: float = 0.0
    altitude_mode: str = "clampToGround"
    heading: float = 0.0
    tilt: float = 0.0
    roll: float = 0.0
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def place(self, vertices: np.ndarray) -> tuple[np.ndarray, str]:
        """The model's vertices in WGS 84's UTM zone at its location.

        Parameters
        ----------
        vertices : (V, 3) float64
            Metres in the model's own frame (x east, y north, z up at heading 0).

        Returns
        -------
        placed : (V, 3) float64
            Metres: easting, northing, height.
        note : str
            Where it was put, in words (the EPSG code, the turn, the height's reading).

        Raises
        ------
        ValueError
            The location is outside UTM's extent (:func:`meshsom.crs.utm_point`).
        """
        from meshsom.crs import utm_point

        point = utm_point(self.latitude, self.longitude)
        absolute = self.altitude_mode == "absolute"
        height = self.altitude if self.altitude_mode in ("absolute", "relativeToGround", "relativeToSeaFloor") else 0.0
        placed = point.place(np.asarray(vertices, np.float64) * np.asarray(self.scale), math.radians(self.heading), height)
        notes = [f"KML: placed by its Model{f' {self.name!r}' if self.name else ''} at ({self.latitude:.6f}, "
                 f"{self.longitude:.6f}) in WGS 84 / UTM zone {point.zone} (EPSG:{point.epsg}), heading "
                 f"{self.heading:g} degrees (turned {math.degrees(point.convergence - math.radians(self.heading)):.4g} "
                 f"degrees on the grid)"]
        if self.scale != (1.0, 1.0, 1.0):
            notes.append(f"scaled by {', '.join(f'{s:g}' for s in self.scale)}")
        if not absolute:
            notes.append(f"its altitude is {self.altitude_mode} (the ground's height is not in KML): z from "
                         f"{height:g} m above an unknown ground")
        if self.tilt or self.roll:
            notes.append(f"its tilt ({self.tilt:g}) and roll ({self.roll:g}) not applied (a building stands upright)")
        return placed, "; ".join(notes)


def _local(tag: str) -> str:
    """A tag without its namespace (``{http://www.opengis.net/kml/2.2}Model`` -> ``Model``)."""
    return tag.rsplit("}", 1)[-1]


def _child(element, name: str):
    return next((c for c in element if _local(c.tag) == name), None)


def _number(element, name: str, default: float) -> float:
    child = _child(element, name) if element is not None else None
    if child is None or child.text is None or not child.text.strip():
        return default
    value = float(child.text.strip())  # ValueError: not a number, named by the caller
    if not math.isfinite(value):
        raise ValueError(f"<{name}> is {child.text.strip()!r}")
    return value


def _root(text, kml_path: str):
    """A KML document's root element: ``text`` parsed, or as it is where it is parsed already."""
    if isinstance(text, ET.Element):
        return text
    try:
        return ET.fromstring(text)
    except ET.ParseError as err:
        raise ValueError(f"{kml_path} is not XML ({err})") from None


def model_placements(text: "bytes | ET.Element", kml_path: str) -> tuple[list[ModelPlacement], list[tuple[str, str]]]:
    """Every ``<Model>`` of a KML document.

    Parameters
    ----------
    text : bytes or xml.etree.ElementTree.Element
        The KML document (or its parsed root).
    kml_path : str
        Its path inside the archive (``/``-separated): hrefs are resolved against its folder.

    Returns
    -------
    placements : list of ModelPlacement
        In document order; a Model without a link or a location is left out.
    problems : list of (str, str)
        The Models left out: (``ModelN``, N from 1 in document order; why, naming it).

    Raises
    ------
    ValueError
        The document is not XML.
    """
    root = _root(text, kml_path)
    placements, problems = [], []
    folder = posixpath.dirname(kml_path)
    names = {}  # each Model's placemark name
    for placemark in (e for e in root.iter() if _local(e.tag) == "Placemark"):
        name = _child(placemark, "name")
        for model in (e for e in placemark.iter() if _local(e.tag) == "Model"):
            names[id(model)] = name.text.strip() if name is not None and name.text else None
    for number, model in enumerate((e for e in root.iter() if _local(e.tag) == "Model"), start=1):
        name = names.get(id(model))
        what = f"Model {number}{f' ({name!r})' if name else ''} of {kml_path}"
        link = _child(model, "Link")
        link = link if link is not None else _child(model, "Url")  # (KML 2.0's name)
        href = _child(link, "href") if link is not None else None
        if href is None or not (href.text or "").strip():
            problems.append((f"Model{number}", f"{what} links no model"))
            continue
        target = unquote(href.text.strip())
        if "://" in target:
            problems.append((f"Model{number}", f"{what} links {target!r}, outside the archive"))
            continue
        target = posixpath.normpath(posixpath.join(folder, target.replace("\\", "/"))).lstrip("/")
        location, orientation, scale = _child(model, "Location"), _child(model, "Orientation"), _child(model, "Scale")
        mode = _child(model, "altitudeMode")
        mode = mode.text.strip() if mode is not None and mode.text else "clampToGround"
        try:
            if location is None or _child(location, "latitude") is None or _child(location, "longitude") is None:
                raise ValueError("no <Location> with a latitude and longitude")
            placement = ModelPlacement(
                href=target, name=name,
                latitude=_number(location, "latitude", 0.0), longitude=_number(location, "longitude", 0.0),
                altitude=_number(location, "altitude", 0.0),
                altitude_mode=mode if mode in ALTITUDE_MODES else "clampToGround",
                heading=_number(orientation, "heading", 0.0), tilt=_number(orientation, "tilt", 0.0),
                roll=_number(orientation, "roll", 0.0),
                scale=tuple(_number(scale, axis, 1.0) for axis in ("x", "y", "z")),
            )
        except ValueError as err:
            problems.append((f"Model{number}", f"{what} ({target}): {err}"))
            continue
        if not (-90 <= placement.latitude <= 90 and -180 <= placement.longitude <= 180):
            problems.append((f"Model{number}", f"{what} ({target}): latitude {placement.latitude:g}, longitude "
                                               f"{placement.longitude:g} are not on the earth"))
            continue
        if not all(s > 0 for s in placement.scale):
            problems.append((f"Model{number}", f"{what} ({target}): its scale {placement.scale} is not positive"))
            continue
        placements.append(placement)
    return placements, problems


#: The property a KML footprint's height (its altitude above the ground, ``relativeToGround``) is given in
#: (:func:`footprint_meshes`).
KML_HEIGHT = "height"


def _altitude_mode(element) -> str:
    mode = next((c for c in element if _local(c.tag) == "altitudeMode"), None)  # KML's, or Google's gx: one
    return mode.text.strip() if mode is not None and mode.text and mode.text.strip() in ALTITUDE_MODES else "clampToGround"


def _ring(element) -> list[list[float]] | None:
    """A LinearRing's ``<coordinates>`` (``lon,lat[,alt]`` tuples), else None; ValueError where a position is
    not 2 or 3 finite numbers."""
    coordinates = next((e for e in element.iter() if _local(e.tag) == "coordinates"), None)
    if coordinates is None or not coordinates.text:
        return None
    ring = [[float(v) for v in t.split(",")] for t in coordinates.text.split()]
    if any(len(p) not in (2, 3) or not all(math.isfinite(v) for v in p) for p in ring):
        raise ValueError("a position that is not 2 or 3 finite numbers (lon,lat[,alt])")
    return ring


def _extended_data(placemark) -> dict[str, str]:
    """A Placemark's ``<ExtendedData>``: ``<Data name><value>`` and ``<SchemaData><SimpleData name>`` (as ArcGIS'
    Layer To KML writes a feature's attributes)."""
    found = {}
    data = _child(placemark, "ExtendedData")
    for e in data.iter() if data is not None else ():
        if _local(e.tag) == "Data" and e.get("name"):
            value = _child(e, "value")
            found[e.get("name")] = value.text.strip() if value is not None and value.text else None
        elif _local(e.tag) == "SimpleData" and e.get("name"):
            found[e.get("name")] = e.text.strip() if e.text else None
    return found


@dataclass(frozen=True)
class KmlFootprint:
    """A building a KML Placemark draws as extruded polygons (:func:`footprint_features`).

    Attributes
    ----------
    id : str
        The placemark's ``id``, else ``PlacemarkN`` (N from 1 in document order).
    properties : dict
        Its ``<ExtendedData>`` and ``name``.
    polygons : list of (list, float or None)
        Each Polygon's rings (the outer first; WGS 84 longitude, latitude) and its height above the ground (its
        highest altitude, ``relativeToGround``; None: the properties' height).
    absolute : bool
        Its altitudes are ``absolute``: the ground beneath is not in KML, so only its properties can give a height.
    """

    id: str
    properties: dict
    polygons: list
    absolute: bool


def footprint_features(text: "bytes | ET.Element", kml_path: str) -> tuple[list[KmlFootprint], list[tuple[str, str]]]:
    """The buildings a KML document draws as polygons: each Placemark whose Polygons (also inside a MultiGeometry)
    are extruded (``<extrude>1``) from the ground to their altitude above it (``relativeToGround``), as Google Earth
    draws a building and ArcGIS' Layer To KML exports an extruded layer.

    Returns
    -------
    footprints : list of KmlFootprint
    problems : list of (str, str)
        The placemarks with polygons that are not buildings, or cannot be read: (id, why).

    Raises
    ------
    ValueError
        The document is not XML.
    """
    root = _root(text, kml_path)
    found, problems = [], []
    for number, placemark in enumerate((e for e in root.iter() if _local(e.tag) == "Placemark"), start=1):
        polygons = [e for e in placemark.iter() if _local(e.tag) == "Polygon"]
        if not polygons:
            continue
        fid = placemark.get("id") or f"Placemark{number}"
        name = _child(placemark, "name")
        try:
            rings = []
            for polygon in polygons:
                outer = next((e for e in polygon if _local(e.tag) == "outerBoundaryIs"), None)
                shell = _ring(outer) if outer is not None else None
                if shell is None or len(shell) < 4:
                    raise ValueError("a Polygon without an outer ring of at least 4 positions")
                inner = [r for r in (_ring(e) for e in polygon if _local(e.tag) == "innerBoundaryIs") if r is not None]
                rings.append([shell] + inner)
        except ValueError as err:
            problems.append((fid, f"its Polygon cannot be read ({err})"))
            continue
        modes = {_altitude_mode(p) for p in polygons}
        extruded = all((_child(p, "extrude") is not None and (_child(p, "extrude").text or "").strip() in ("1", "true"))
                       for p in polygons)
        if not extruded or modes & {"clampToGround", "clampToSeaFloor"}:
            problems.append((fid, "is a KML polygon that is not extruded from the ground (<extrude>1</extrude>, an "
                                  "altitude relative to the ground): a flat area, not a building"))
            continue
        relative = modes == {"relativeToGround"}
        props = {**_extended_data(placemark), **({"name": name.text.strip()} if name is not None and name.text else {})}
        parts = []
        for polygon in rings:
            top = max((p[2] for p in polygon[0] if len(p) > 2), default=0.0) if relative else 0.0
            parts.append(([[[p[0], p[1]] for p in ring] for ring in polygon], top if top > 0 else None))
        found.append(KmlFootprint(fid, props, parts, not relative))
    return found, problems


def footprint_meshes(footprint: KmlFootprint, options, name: str, source: str) -> Iterator:
    """A KML footprint's mesh (:func:`meshsom.osm.building_meshes`, as OpenStreetMap's buildings are read): its
    polygons extruded to their heights, several polygons of different heights the building's parts (united); a
    Rejection where it has no height."""
    from meshsom.io import Rejection, file_crs
    from meshsom.osm import _Area, building_meshes

    system, unknown = file_crs("OGC:CRS84", options)
    crs = (dataclasses.replace(system, latitude_first=False), unknown)
    heights = {h for _, h in footprint.polygons}
    with_height = lambda h: {**footprint.properties, **({KML_HEIGHT: h} if h is not None else {})}  # noqa: E731
    if len(heights) == 1:
        area = _Area(footprint.id, with_height(heights.pop()),
                     {"type": "MultiPolygon", "coordinates": [rings for rings, _ in footprint.polygons]})
        items = building_meshes(area, [], None, options, name, source, crs)
    else:
        parts = [_Area(f"{footprint.id}/{k}", with_height(h), {"type": "Polygon", "coordinates": rings})
                 for k, (rings, h) in enumerate(footprint.polygons, 1)]
        items = building_meshes(_Area(footprint.id, footprint.properties, None), parts, None, options, name, source, crs,
                                how=f"{len(parts)} extruded polygons of one KML Placemark, each at its own height: "
                                    "read as its parts")
    for item in items:
        if isinstance(item, Rejection) and footprint.absolute:
            item = dataclasses.replace(item, reason=item.reason + "; its altitudes are absolute: the ground beneath "
                                                                  "is not in KML (export it relative to the ground)")
        yield item


def _model_file(kml: Path, href: str) -> Path | None:
    """The file a Model's ``href`` (relative to the KML's folder) names, or None where it leaves
    the KML's folder (a KML is read with the models beneath it, as a KMZ holds them)."""
    target = (kml.parent / href).resolve()
    return target if target.is_relative_to(kml.parent.resolve()) else None


def linked_models(path: Path) -> set[Path]:
    """The model files that a KML file's usable Models place (and which a folder's reader reads
    through the KML only).

    Parameters
    ----------
    path : Path
        A KML file.

    Returns
    -------
    set of Path
        The existing model files (resolved); empty when the KML cannot be read or is not XML (its
        models are then read as they are, in their own frames).
    """
    try:
        found, _ = model_placements(path.read_bytes(), path.name)
    except (OSError, ValueError):
        return set()
    files = (_model_file(path, p.href) for p in found)
    return {f for f in files if f is not None and f.is_file()}


def read_kml(path: Path, options, name: str | None = None) -> Iterator:
    """Every model a KML file's Models link, placed (:meth:`ModelPlacement.place`): RawMesh or
    Rejection items.

    Models are read from beneath the KML's folder (:func:`meshsom.io.read_file`, any type meshsom
    reads; COLLADA by KML's specification); a model's ids start with its path relative to the
    KML's input root (``name``'s folder joined with the ``href``), with ``@2`` and on for a model
    placed more than once. A Model that cannot be used is a Rejection ``<name>#ModelN`` saying why,
    as is a linked model that is missing or outside the KML's folder
    (``<name>#<href>``).

    Parameters
    ----------
    path : Path
        The KML file.
    options : meshsom.io.ReaderOptions
    name : str, optional
        The KML's name relative to its input root (:attr:`meshsom.io.InputFile.name`); default: the
        file name.

    Raises
    ------
    InputFileError
        The file cannot be read, is not XML, or holds no Model.
    """
    from meshsom.errors import InputFileError
    from meshsom.io import Rejection, read_file

    name = name or path.name
    try:
        text = path.read_bytes()
    except OSError as err:
        raise InputFileError(str(path), f"cannot be read ({type(err).__name__}: {err})") from None
    try:
        root = _root(text, path.name)  # parsed once, for its Models and its polygons
        placements, problems = model_placements(root, path.name)
        footprints, flat = footprint_features(root, path.name)
    except ValueError as err:
        raise InputFileError(str(path), f"KML: {err}; the models it links are read in their own frames") from None
    if not placements and not problems and not footprints and not flat:
        raise InputFileError(str(path), "holds no KML <Model> linking a 3D model and no Polygon extruded from the "
                                        "ground (KML points and lines are not buildings)")
    for model, reason in problems:  # ("Model2", why)
        yield Rejection(f"{name}#{model}", str(path), f"KML: {reason}")
    for fid, reason in flat:
        yield Rejection(f"{name}#{fid}", str(path), f"KML: {reason}")
    for footprint in footprints:  # buildings drawn as extruded polygons: footprints with a height, in WGS 84
        yield from footprint_meshes(footprint, options, name, str(path))
    by_href: dict[str, list[ModelPlacement]] = {}
    for placement in placements:
        by_href.setdefault(placement.href, []).append(placement)
    for href, group in by_href.items():
        model_name = posixpath.join(posixpath.dirname(name), href)
        target = _model_file(path, href)
        if target is None:
            yield Rejection(f"{name}#{href}", str(path), f"a KML Model of {path.name} links {href!r}, outside its folder; "
                                                   "not followed (models are read from beneath the KML)")
        elif not target.is_file():
            yield Rejection(model_name, str(target), f"a KML Model of {path.name} links it, but there is no such file "
                                                     "beneath the KML (its folder or archive does not hold it)")
        else:
            for item in read_file(target, options, model_name):
                if isinstance(item, Rejection):
                    yield item
                else:
                    yield from placed(item, group)


def placed(item, placements: list[ModelPlacement]) -> Iterator:
    """A read model (:class:`meshsom.io.RawMesh`) as each KML Model places it: ids ``#...@2`` and on
    for a model placed more than once; a Rejection where a placement cannot be used."""
    from meshsom.io import Rejection, recentre

    for k, placement in enumerate(placements):
        mesh_id = item.id if len(placements) == 1 else f"{item.id}@{k + 1}"
        try:
            world, note = placement.place(item.vertices + item.origin)
        except ValueError as err:
            yield Rejection(mesh_id, item.source, f"KML: {err}", len(item.faces), item.label)
            continue
        local, origin = recentre(world)
        yield dataclasses.replace(item, id=mesh_id, vertices=local, origin=origin, notes=(*item.notes, note))
