"""Reading Esri scene layer packages (``.slpk``): I3S 3D object layers, one mesh per feature.

City models published from ArcGIS (multipatch feature classes shared as scene layers, New York's
DoITT buildings among them) come as I3S, an OGC community standard: a zip (stored, not deflated)
of gzipped JSON and binary resources. A *3D object* layer (``layerType`` ``3DObject``) holds
features (buildings) in a tree of nodes whose finer nodes replace coarser ones (``node-switching``);
the leaves hold every feature at full detail, so only they are read.

- **Nodes**: from the node pages (``nodepages/<n>.json.gz``, I3S 1.7 and later: a node's mesh names
  its geometry ``resource``, read from ``nodes/<resource>/geometries/<buffer>``) or, without them
  (1.6 and earlier), by walking the node index documents from ``nodes/root``.
- **Geometry**: the uncompressed geometry buffer (``geometryDefinitions``' buffer without
  ``compressedAttributes``, or the 1.6 ``defaultGeometrySchema``): a header of ``vertexCount`` and
  ``featureCount``, then each vertex attribute for every vertex (``position``, ``normal``, ``uv0``,
  ``color``, ``uvRegion``, in that order), then each feature attribute for every feature (``id``,
  ``faceRange``: the first and last triangle of the feature). Triangles are not indexed: every
  three vertices make one. Where a layer declares only a Draco-compressed buffer
  (``compressedAttributes``), or a node lacks its uncompressed one, the Draco buffer is decoded
  (Google's decoder through DracoPy): positions (scaled back by the position attribute's
  ``i3s-scale_x`` and ``i3s-scale_y`` metadata), indexed triangles, and each vertex's index into the
  feature ids of the ``feature-index`` attribute's ``i3s-feature-ids`` metadata
  (:mod:`meshsom.draco_metadata`); the positions are the publisher's quantisation (ArcGIS Pro's:
  about 0.1 mm on New York's DA12 package).
- **Coordinates**: positions are offsets from the node's centre (its oriented bounding box's, or
  its bounding sphere's before 1.7): in degrees of longitude and latitude and metres of height for a
  geographic layer (WGS 84, ``wkid`` 4326: converted to east-north-up metres about each building's
  centre, :func:`meshsom.crs.to_metres`), in the CRS's units for a projected one (scaled to metres).
  Heights are in ``heightModelInfo.heightUnit``.
- **Labels**: the feature's value of :attr:`meshsom.io.ReaderOptions.label_attribute` where the
  layer stores that attribute (``attributeStorageInfo``, per node, in the geometry's feature order).
- **Ids**: ``name#<feature id>``; a feature found in several leaves is one mesh of all its
  triangles (corners within :data:`SEAM_TOL_M` merged), noted.

Not read, each a rejection saying why: integrated meshes (a city's photogrammetric surface, no
features), point and point-cloud layers, building scene layers (BIM: a package of sublayers).
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import zipfile
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: I3S value types and their NumPy dtypes (little-endian).
VALUE_TYPES = {"UInt8": "<u1", "UInt16": "<u2", "UInt32": "<u4", "UInt64": "<u8", "Int8": "<i1", "Int16": "<i2",
               "Int32": "<i4", "Int64": "<i8", "Float32": "<f4", "Float64": "<f8"}
#: The order of the attributes in an I3S 1.7 geometry buffer (``geometryBuffer`` in the specification).
VERTEX_ORDER = ("position", "normal", "uv0", "color", "uvRegion")
FEATURE_ORDER = ("featureId", "faceRange")
#: Metres per unit of ``heightModelInfo.heightUnit``.
HEIGHT_UNITS = {"meter": 1.0, "metre": 1.0, "us-foot": 1200 / 3937, "foot": 0.3048, "international-foot": 0.3048,
                "kilometer": 1000.0, "centimeter": 0.01, "millimeter": 0.001}
#: Metres within which the corners of a feature split across leaf nodes are one vertex: each node
#: stores float32 offsets about its own centre (a 400 m node rounds them to about 0.05 mm).
SEAM_TOL_M = 1e-3
#: Metres within which the corners of a feature split across Draco-compressed leaves are one vertex:
#: each node quantises its positions over its own extent (1 cm is a 100 m node at 13 bits).
DRACO_SEAM_TOL_M = 1e-2
#: Draco attribute types (``draco::GeometryAttribute::Type``).
DRACO_POSITION, DRACO_GENERIC = 0, 4
#: Nodes walked at most (a package is a tree; this bounds a corrupt one).
MAX_NODES = 1_000_000


def read_slpk(path: Path, options, name: str | None = None) -> Iterator:
    """Read every feature of a scene layer package's leaves (as the module says): RawMesh or
    Rejection items.

    A leaf whose geometry is missing or corrupt is a Rejection ``name#node <resource>`` saying
    why; the other leaves are read.

    Raises
    ------
    InputFileError
        Not a zip, not a 3D object layer, no geometry buffer that can be read, no features, or
        more than ``options.max_bytes`` in all.
    """
    from meshsom.archives import open_zip
    from meshsom.io import Rejection

    name = name or path.name
    with open_zip(path, "a scene layer package (a zip)") as archive:
        package = _Package(archive, path, options)
        layer = package.json("3dSceneLayer.json")
        kind = str(layer.get("layerType", ""))
        if kind.lower() not in ("3dobject", "3d object"):
            raise InputFileError(str(path), f"is an I3S {kind or 'layer of no layerType'} layer; only 3D object layers (buildings as "
                                            "features) are read" + _KIND_HINTS.get(kind.lower(), ""))
        crs, notes = _layer_crs(layer, path)
        schema = _buffer_schema(layer, path)
        storage = next((a for a in layer.get("attributeStorageInfo") or [] if a.get("name") == options.label_attribute), None)
        labels: dict[int, str] = {}
        features: dict[int, list] = {}
        decoded: set[int] = set()  # features read from Draco-compressed geometry
        leaves, broken = 0, []
        for resource, centre in package.leaves():
            leaves += 1
            try:
                found, compressed = _node_features(package, resource, schema, path)
            except InputFileError as err:
                if package.total > int(options.max_bytes):  # the whole package is too large
                    raise
                broken.append(Rejection(f"{name}#node {resource}", str(path), f"{err.problem}; the node's features are not read"))
                continue
            for fid, triangles in found:
                if len(triangles):
                    features.setdefault(fid, []).append(triangles + centre)
                    if compressed:
                        decoded.add(fid)
            if storage is not None:
                try:
                    values = _attribute(package.read(f"nodes/{resource}/attributes/{storage['key']}/0"), storage)
                except (InputFileError, KeyError, ValueError) as err:
                    notes = notes + [f"labels ({options.label_attribute}) of node {resource} not read: "
                                     f"{getattr(err, 'problem', err)}"]
                    values = []
                for (fid, _), value in zip(found, values):
                    labels.setdefault(fid, value)
        if not features and not broken:
            raise InputFileError(str(path), f"its {leaves} leaf nodes hold no features")
        yield from broken
        yield from _meshes(features, labels, crs, notes, name, str(path), decoded)


_KIND_HINTS = {
    "integratedmesh": " (an integrated mesh is one surface, with no buildings in it)",
    "building": " (a building scene layer: export its sublayers as multipatch feature classes, then as 3D object layers "
                "or GeoPackage)",
    "point": " (points are not buildings)",
    "pointcloud": " (point clouds are not read: reconstruct buildings first)",
}


class _Package:
    """The resources of an opened package, gunzipped; all read together at most ``options.max_bytes``."""

    def __init__(self, archive: zipfile.ZipFile, path: Path, options):
        self.archive, self.path, self.options = archive, path, options
        self.names = set(archive.namelist())
        self.total = 0

    def holds(self, member: str) -> str | None:
        """The name under which the package holds ``member`` (gzipped or not, with ``.bin`` or not), or None."""
        return next((c for c in (f"{member}.gz", member, f"{member}.bin.gz", f"{member}.bin") if c in self.names), None)

    def count(self, nbytes: int) -> None:
        """Count ``nbytes`` more decoded (a Draco buffer's geometry) against ``options.max_bytes``."""
        self.total += int(nbytes)
        limit = int(self.options.max_bytes)
        if self.total > limit:
            raise InputFileError(str(self.path), f"expands to more than {limit:,} bytes (ReaderOptions.max_bytes)")

    def read(self, member: str) -> bytes:
        candidate = self.holds(member)
        if candidate is None:
            raise InputFileError(str(self.path), f"does not hold {member} (nor {member}.gz)")
        limit = int(self.options.max_bytes)
        try:
            with self.archive.open(candidate) as raw:
                stream = gzip.GzipFile(fileobj=raw) if candidate.endswith(".gz") else raw
                data = stream.read(limit - self.total + 1)
        except (OSError, EOFError, zipfile.BadZipFile, ValueError) as err:
            raise InputFileError(str(self.path), f"{candidate} cannot be read ({type(err).__name__}: {err})") from None
        self.count(len(data))
        return data

    def json(self, member: str) -> dict:
        try:
            document = json.loads(self.read(member))
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise InputFileError(str(self.path), f"{member} is not JSON ({err})") from None
        if not isinstance(document, dict):
            raise InputFileError(str(self.path), f"{member} is not a JSON object")
        return document

    def leaves(self) -> Iterator[tuple[str, np.ndarray]]:
        """Each leaf node with a mesh: (resource folder, centre (3,))."""
        pages = sorted((n for n in self.names if n.startswith("nodepages/")),
                       key=lambda n: int(n.split("/")[1].split(".")[0]) if n.split("/")[1].split(".")[0].isdigit() else -1)
        if pages:
            for page in pages:
                for node in self.json(page.removesuffix(".gz")).get("nodes", []):
                    mesh = node.get("mesh") or {}
                    geometry = mesh.get("geometry") or {}
                    if node.get("children") or "resource" not in geometry:
                        continue
                    yield str(geometry["resource"]), _centre(node, self.path)
            return
        todo, seen = ["nodes/root"], set()
        while todo:
            folder = todo.pop()
            if folder in seen or len(seen) > MAX_NODES:
                continue
            seen.add(folder)
            node = self.json(f"{folder}/3dNodeIndexDocument.json")
            children = node.get("children") or []
            for child in children:
                href = str(child.get("href") or child.get("id") or "")
                todo.append(f"nodes/{href.rstrip('/').split('/')[-1]}")
            if not children and node.get("geometryData"):
                yield folder.split("/", 1)[1], _centre(node, self.path)


def _centre(node: dict, path: Path) -> np.ndarray:
    """A node's centre: its oriented bounding box's, else its bounding sphere's (three numbers)."""
    obb = node.get("obb") or {}
    centre = obb.get("center") if isinstance(obb, dict) else None
    if centre is None:
        centre = (node.get("mbs") or [None] * 3)[:3]
    try:
        out = np.asarray(centre, np.float64).reshape(3)
    except (TypeError, ValueError):
        out = np.full(3, np.nan)
    if not np.isfinite(out).all():
        raise InputFileError(str(path), f"node {node.get('index', node.get('id'))!r} has no centre (obb or mbs)")
    return out


def _layer_crs(layer: dict, path: Path) -> tuple:
    """The layer's CRS (:class:`meshsom.crs.CoordinateSystem`, x east and y north) and notes."""
    from meshsom.crs import UnknownCRS, coordinate_system

    reference = layer.get("spatialReference") or {}
    code = reference.get("latestWkid") or reference.get("wkid")
    declared = f"EPSG:{int(code)}" if isinstance(code, (int, float)) else reference.get("wkt")
    if not declared:
        declared = (layer.get("store") or {}).get("vertexCRS")
    if not declared:
        raise InputFileError(str(path), "3dSceneLayer.json declares no spatialReference (wkid or wkt)")
    try:
        crs = coordinate_system(str(declared))
    except UnknownCRS as err:
        raise InputFileError(str(path), f"3dSceneLayer.json: {err}") from None
    unit = str((layer.get("heightModelInfo") or {}).get("heightUnit") or "meter").lower()
    if unit not in HEIGHT_UNITS:
        raise InputFileError(str(path), f"heights are in {unit!r}; expected one of {', '.join(HEIGHT_UNITS)}")
    crs = dataclasses.replace(crs, latitude_first=False, vertical_m=HEIGHT_UNITS[unit])  # I3S: x is east
    return crs, [f"I3S 3D object layer in {crs.name} (heights in {unit})"]


def _buffer_schema(layer: dict, path: Path) -> dict:
    """Where the uncompressed geometry buffer's attributes lie: ``{"buffer": n, "draco": m or None,
    "header": [dtype, ...], "vertex": [(name, dtype, components)], "feature": [(name, dtype,
    components)]}``; ``{"buffer": None, "draco": m}`` for a layer whose geometry is only Draco-compressed."""
    definitions = layer.get("geometryDefinitions")
    if definitions:
        buffers = (definitions[0] or {}).get("geometryBuffers") or []
        encodings = [None if "compressedAttributes" not in b else str((b["compressedAttributes"] or {}).get("encoding")).lower()
                     for b in buffers]
        draco = next((n for n, e in enumerate(encodings) if e == "draco"), None)
        for number, buffer in enumerate(buffers):
            if encodings[number] is not None:
                continue
            offset = int(buffer.get("offset", 0))
            if offset not in (0, 8):
                raise InputFileError(str(path), f"geometry buffer {number} starts at {offset}; expected 0 or 8")
            vertex = [(k, _dtype(buffer[k], path), int(buffer[k].get("component", 1))) for k in VERTEX_ORDER if k in buffer]
            feature = [(k, _dtype(buffer[k], path), int(buffer[k].get("component", 1))) for k in FEATURE_ORDER if k in buffer]
            if not vertex or vertex[0][0] != "position":
                raise InputFileError(str(path), f"geometry buffer {number} has no positions")
            return {"buffer": number, "draco": draco, "header": ["<u4", "<u4"] if offset == 8 else [], "vertex": vertex,
                    "feature": feature}
        if draco is not None:
            return {"buffer": None, "draco": draco}
        if buffers:
            kinds = sorted(set(map(str, encodings)))
            raise InputFileError(str(path), f"holds its geometry compressed as {', '.join(kinds)} only; expected an uncompressed "
                                            "geometry buffer or a Draco-compressed one")
    schema = (layer.get("store") or {}).get("defaultGeometrySchema")
    if not schema:
        raise InputFileError(str(path), "3dSceneLayer.json has neither geometryDefinitions nor store.defaultGeometrySchema")
    if schema.get("geometryType", "triangles") != "triangles":
        raise InputFileError(str(path), f"its geometry is {schema.get('geometryType')!r}; only triangles are read")
    vertex_attributes, feature_attributes = schema.get("vertexAttributes") or {}, schema.get("featureAttributes") or {}
    names = {"id": "featureId"}
    return {
        "buffer": 0,
        "draco": None,
        "header": [VALUE_TYPES.get(h.get("type"), "<u4") for h in schema.get("header") or []],
        "header_names": [h.get("property") for h in schema.get("header") or []],
        "vertex": [(k, _dtype({"type": vertex_attributes[k].get("valueType")}, path), int(vertex_attributes[k].get("valuesPerElement", 1)))
                   for k in schema.get("ordering") or [] if k in vertex_attributes],
        "feature": [(names.get(k, k), _dtype({"type": feature_attributes[k].get("valueType")}, path),
                     int(feature_attributes[k].get("valuesPerElement", 1)))
                    for k in schema.get("featureAttributeOrder") or [] if k in feature_attributes],
    }


def _dtype(attribute: dict, path: Path) -> str:
    kind = attribute.get("type")
    if kind not in VALUE_TYPES:
        raise InputFileError(str(path), f"a geometry attribute has the type {kind!r}; expected one of {', '.join(VALUE_TYPES)}")
    return VALUE_TYPES[kind]


def _node_features(package: _Package, resource: str, schema: dict, path: Path) -> tuple[list, bool]:
    """A leaf's features in its geometry's feature order, ``[(id, triangles (T, 3, 3))]`` (T may be
    0 for a Draco feature id with no triangles), and whether they were Draco-decoded: the
    uncompressed buffer where the layer has one and the package holds it, else the Draco buffer."""
    plain, draco = schema["buffer"], schema.get("draco")
    if plain is not None and (draco is None or package.holds(f"nodes/{resource}/geometries/{plain}")):
        member = f"nodes/{resource}/geometries/{plain}"
        return list(_features(package.read(member), schema, path, member)), False
    member = f"nodes/{resource}/geometries/{draco}"
    if plain is not None and not package.holds(member):
        raise InputFileError(str(path), f"does not hold nodes/{resource}/geometries/{plain} (nor .gz), nor its Draco-compressed "
                                        f"{member}")
    return _draco_features(package.read(member), package, path, member), True


def _draco_features(data: bytes, package: _Package, path: Path, resource: str) -> list[tuple[int, np.ndarray]]:
    """Each feature of one Draco-compressed geometry buffer, in the order of its ``i3s-feature-ids``:
    (id, triangles (T, 3, 3) float64 offsets from the node's centre, x and y scaled back by the
    position attribute's ``i3s-scale_x`` and ``i3s-scale_y``). Errors name the package and the resource."""
    from meshsom.draco_metadata import MetadataError, entry_double, entry_int32s, entry_text, read_metadata

    try:
        import DracoPy
    except ImportError as err:
        raise InputFileError(str(path), f"holds Draco-compressed geometry and DracoPy is not importable ({err})") from None
    try:
        metadata = read_metadata(data)
    except MetadataError as err:
        raise InputFileError(str(path), f"{resource}: {err}") from None
    try:
        mesh = DracoPy.decode(bytes(data))
    except Exception as err:  # DracoPy raises its own errors, and ValueError for corrupt data
        raise InputFileError(str(path), f"{resource} cannot be decoded by Draco ({type(err).__name__}: {err})") from None
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise InputFileError(str(path), f"{resource} is a Draco point cloud or an empty mesh: no triangles")
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    attributes = list(getattr(mesh, "attributes", None) or [])
    position = next((a for a in attributes if a.get("attribute_type") == DRACO_POSITION), None)
    if position is None or int(position.get("num_components", 0)) != 3:
        raise InputFileError(str(path), f"{resource} holds no Draco positions of three components")
    points = np.asarray(position["data"], np.float64).reshape(-1, 3)
    package.count(points.nbytes + faces.nbytes)
    entries = metadata.attributes.get(int(position["unique_id"]), {})
    try:
        scale = [entry_double(entries, "i3s-scale_x"), entry_double(entries, "i3s-scale_y")]
        index = next((a for a in attributes if entry_text(metadata.attributes.get(int(a["unique_id"]), {}), "i3s-attribute-type")
                      == "feature-index"), None)
        if index is None:  # the specification's type: a generic attribute of one integer per vertex
            index = next((a for a in attributes if a.get("attribute_type") == DRACO_GENERIC and int(a.get("num_components", 0)) == 1
                          and np.issubdtype(np.asarray(a["data"]).dtype, np.integer)), None)
        ids = None if index is None else entry_int32s(metadata.attributes.get(int(index["unique_id"]), {}), "i3s-feature-ids")
        if ids is None:
            ids = entry_int32s(metadata.geometry, "i3s-feature-ids")
    except MetadataError as err:
        raise InputFileError(str(path), f"{resource}: {err}") from None
    if index is None or ids is None:
        missing = "no feature-index attribute" if index is None else "no i3s-feature-ids metadata"
        raise InputFileError(str(path), f"{resource} holds Draco triangles of no feature ({missing}): not buildings")
    for axis, factor in enumerate(scale):
        if factor is not None:
            if not (np.isfinite(factor) and factor > 0):
                raise InputFileError(str(path), f"{resource}: i3s-scale_{'xy'[axis]} is {factor}; expected a positive number")
            points[:, axis] *= factor
    if faces.min() < 0 or faces.max() >= len(points):
        raise InputFileError(str(path), f"{resource}: a Draco face names vertex {int(faces.max())} of {len(points)}")
    per_vertex = np.asarray(index["data"]).reshape(-1).astype(np.int64)
    per_face = per_vertex[faces[:, 0]]  # the specification: a triangle's three vertices share their feature
    outside = (per_face < 0) | (per_face >= len(ids))
    if outside.any():
        raise InputFileError(str(path), f"{resource}: {int(outside.sum())} Draco triangles have a feature index outside the "
                                        f"{len(ids)} i3s-feature-ids (e.g. {int(per_face[outside][0])})")
    triangles = points[faces]
    order = np.argsort(per_face, kind="stable")
    pieces = np.split(triangles[order], np.cumsum(np.bincount(per_face, minlength=len(ids)))[:-1])
    return [(int(fid), piece) for fid, piece in zip(ids.tolist(), pieces)]


def _features(data: bytes, schema: dict, path: Path, resource: str) -> Iterator[tuple[int, np.ndarray]]:
    """Each feature of one geometry buffer: (id, triangles (T, 3, 3) float64 offsets from the
    node's centre). Errors name the package and the resource."""
    header = np.zeros(0)
    offset = 0
    if schema["header"]:
        dtype = np.dtype([(f"h{i}", d) for i, d in enumerate(schema["header"])])
        if len(data) < dtype.itemsize:
            raise InputFileError(str(path), f"{resource} has {len(data)} bytes, fewer than its header's {dtype.itemsize}")
        header = np.frombuffer(data, dtype, 1)[0]
        offset = dtype.itemsize
    names = schema.get("header_names") or ["vertexCount", "featureCount"]
    counts = {n: int(header[i]) for i, n in enumerate(names) if i < len(header)}
    vertices, feature_count = counts.get("vertexCount", 0), counts.get("featureCount", 0)
    arrays = {}
    for group, count in (("vertex", vertices), ("feature", feature_count)):
        for attribute, dtype, components in schema[group]:
            size = np.dtype(dtype).itemsize * components * count
            if offset + size > len(data):
                raise InputFileError(str(path), f"{resource} ends before its {attribute} ({count} x {components}, {len(data)} bytes)")
            arrays[attribute] = np.frombuffer(data, dtype, components * count, offset).reshape(count, components)
            offset += size
    if vertices % 3:
        raise InputFileError(str(path), f"{resource} holds {vertices} vertices, not a whole number of triangles")
    position = arrays.get("position")
    if position is None or position.shape[1] != 3:
        raise InputFileError(str(path), f"{resource} holds no positions of three components")
    triangles = position.astype(np.float64).reshape(-1, 3, 3)
    if feature_count == 0 or "featureId" not in arrays or "faceRange" not in arrays:
        raise InputFileError(str(path), f"{resource} holds triangles of no feature (no featureId and faceRange): not buildings")
    ranges = arrays["faceRange"].astype(np.int64)
    for fid, (first, last) in zip(arrays["featureId"][:, 0].tolist(), ranges.tolist()):
        if not 0 <= first <= last < len(triangles):
            raise InputFileError(str(path), f"{resource}: feature {fid}'s faceRange [{first}, {last}] is outside its {len(triangles)} triangles")
        yield int(fid), triangles[first:last + 1]


def _attribute(data: bytes, storage: dict) -> list[str]:
    """The values of one attribute buffer of a node (``attributeStorageInfo``: a count, then the
    values, strings after their byte counts), one per feature in the geometry's order, as text."""
    count = int(np.frombuffer(data, "<u4", 1, 0)[0])
    values = storage.get("attributeValues") or {}
    kind = values.get("valueType")
    if kind == "String":
        sizes = np.frombuffer(data, "<u4", count, 4).astype(np.int64)
        ends = 4 + 4 * count + np.cumsum(sizes)
        if len(ends) and ends[-1] > len(data):
            raise ValueError(f"{count} strings of {int(sizes.sum())} bytes in a buffer of {len(data)}")
        return [data[e - n:e].rstrip(b"\0").decode("utf-8", "replace") for e, n in zip(ends.tolist(), sizes.tolist())]
    dtype = {"Oid32": "<u4", "Oid64": "<u8"}.get(kind) or VALUE_TYPES.get(kind)
    if dtype is None:
        raise ValueError(f"attribute values of the type {kind!r}")
    offset = 4 + (-4 % np.dtype(dtype).itemsize)  # values aligned to their size
    return [(str(int(v)) if v.is_integer() else repr(v)) if isinstance(v, float) else str(v)
            for v in np.frombuffer(data, dtype, count, offset).tolist()]


def _meshes(features: dict, labels: dict, crs, notes: list[str], name: str, source: str, decoded: set) -> Iterator:
    from meshsom.crs import NotDegrees, to_metres
    from meshsom.io import RawMesh, Rejection, recentre

    for fid in sorted(features):
        pieces = features[fid]
        triangles = np.concatenate(pieces)
        mesh_id = f"{name}#{fid}"
        if not np.isfinite(triangles).all():
            yield Rejection(mesh_id, source, "has coordinates that are not finite numbers", len(triangles))
            continue
        world, inverse = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)  # one vertex per position
        faces = inverse.reshape(-1, 3).astype(np.int64)
        local, origin = recentre(world)
        try:
            local, note = to_metres(local, origin, crs)
        except NotDegrees as err:
            yield Rejection(mesh_id, source, str(err), len(triangles))
            continue
        more = ["read from Draco-compressed geometry (positions as the publisher quantised them)"] if fid in decoded else []
        if len(pieces) > 1:  # float32 offsets about two centres (quantised over two extents): a shared corner differs
            from meshsom.preprocess import weld

            tol = DRACO_SEAM_TOL_M if fid in decoded else SEAM_TOL_M
            local, remap = weld(local, tol)
            faces = remap[faces]
            more.append(f"its triangles are in {len(pieces)} leaf nodes, read as one mesh (corners within {tol:g} m merged)")
        yield RawMesh(mesh_id, source, local, faces, origin, labels.get(fid), notes=tuple(notes + ([note] if note else []) + more))
