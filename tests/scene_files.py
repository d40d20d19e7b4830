"""FBX and 3DS files written as their producers write them, for the readers' tests (independent of meshsom).

FBX (Autodesk's interchange format, 7.4): the binary encoding every exporter writes by default (the node-record
layout Blender's ``io_scene_fbx`` encodes: a node's end offset, property count and length, name, typed properties,
nested records closed by a null record; arrays of doubles and int32 written plain) and the ASCII one; a
``GlobalSettings`` naming the up and front axes and the unit (``UnitScaleFactor``: centimetres per unit); a
``Geometry`` (``Vertices``, ``PolygonVertexIndex`` with each polygon's last index written as ``-index - 1``) and a
``Model`` (``Lcl Translation`` / ``Rotation`` / ``Scaling``) per object, connected to the scene's root.

3DS (3D Studio): chunks of ``(id: uint16, length: uint32)``: ``MAIN3DS`` 0x4D4D holds ``EDIT3DS`` 0x3D3D holding an
``EDIT_OBJECT`` 0x4000 per object (its name, zero-terminated, then an ``OBJ_TRIMESH`` 0x4100 of ``TRI_VERTEXL``
0x4110, ``TRI_LOCAL`` 0x4160 and ``TRI_FACEL1`` 0x4120: uint16 counts, float32 world coordinates, faces of three
uint16 indices and a flags word).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

#: FBX's axis systems as exporters write them: (UpAxis, UpAxisSign, FrontAxis, FrontAxisSign, CoordAxis, CoordAxisSign).
AXES = {
    "z-up": (2, 1, 1, -1, 0, 1),  # 3ds Max, Revit, PLATEAU's FBX: right-handed, z up
    "y-up": (1, 1, 2, 1, 0, 1),  # Blender's default export (-Z forward, Y up), Maya, Unity
}


def _properties70(items) -> list:
    return [("P", list(item), []) for item in items]


def fbx_document(objects, axes: str = "z-up", unit: float = 100.0, application: str | None = None) -> list:
    """The node tree of an FBX 7.4 scene.

    Parameters
    ----------
    objects : list of (name, vertices (V, 3), polygons (list of index lists), translation, rotation (degrees, XYZ),
        scaling[, parent name])
        An object of no vertices (None) is an empty node ("Null" model, a group); one with a parent is its child.
    axes : str
        A key of :data:`AXES`.
    unit : float
        ``UnitScaleFactor``: centimetres per unit (100: metres).
    application : str or None
        The application the header's ``SceneInfo`` names (``Original|ApplicationName``, with CityEngine's vendor
        "Esri R&D Center Zurich Inc." when it is "CityEngine", as CityEngine and PyPRT write it); None: no SceneInfo.

    Returns
    -------
    list of (name, properties, children)
    """
    up, up_sign, front, front_sign, coord, coord_sign = AXES[axes]
    settings = _properties70([
        ("UpAxis", "int", "Integer", "", up), ("UpAxisSign", "int", "Integer", "", up_sign),
        ("FrontAxis", "int", "Integer", "", front), ("FrontAxisSign", "int", "Integer", "", front_sign),
        ("CoordAxis", "int", "Integer", "", coord), ("CoordAxisSign", "int", "Integer", "", coord_sign),
        ("UnitScaleFactor", "double", "Number", "", float(unit)),
        ("OriginalUnitScaleFactor", "double", "Number", "", float(unit)),
    ])
    objs, links = [], []
    model_ids = {}
    for k, (name, vertices, polygons, t, r, s, *parent) in enumerate(objects):
        gid, mid = np.int64(1_000_000 + 2 * k), np.int64(1_000_001 + 2 * k)  # ids: int64 ('L')
        model_ids[name] = mid
        if vertices is not None:
            index = []
            for poly in polygons:
                index += [int(i) for i in poly[:-1]] + [-int(poly[-1]) - 1]
            objs.append(("Geometry", [gid, f"{name}\x00\x01Geometry", "Mesh"], [
                ("Vertices", [np.asarray(vertices, np.float64).ravel()], []),
                ("PolygonVertexIndex", [np.asarray(index, np.int32)], []),
                ("GeometryVersion", [124], []),
            ]))
            links.append(("C", ["OO", gid, mid], []))
        links.append(("C", ["OO", mid, model_ids[parent[0]] if parent else np.int64(0)], []))
        objs.append(("Model", [mid, f"{name}\x00\x01Model", "Mesh" if vertices is not None else "Null"], [
            ("Version", [232], []),
            ("Properties70", [], _properties70([
                ("Lcl Translation", "Lcl Translation", "", "A", *map(float, t)),
                ("Lcl Rotation", "Lcl Rotation", "", "A", *map(float, r)),
                ("Lcl Scaling", "Lcl Scaling", "", "A", *map(float, s)),
            ])),
        ]))
    header = [("FBXHeaderVersion", [1003], []), ("FBXVersion", [7400], [])]
    if application is not None:
        vendor = "Esri R&D Center Zurich Inc." if application == "CityEngine" else "Vendor"
        header.append(("SceneInfo", ["GlobalInfo\x00\x01SceneInfo", "UserData"], [("Properties70", [], _properties70([
            ("Original|ApplicationVendor", "KString", "", "", vendor),
            ("Original|ApplicationName", "KString", "", "", application),
        ]))]))
    return [
        ("FBXHeaderExtension", [], header),
        ("GlobalSettings", [], [("Version", [1000], []), ("Properties70", [], settings)]),
        ("Objects", [], objs),
        ("Connections", [], links),
    ]


def _binary_property(value) -> bytes:
    if isinstance(value, str):
        data = value.encode("utf-8")
        return b"S" + struct.pack("<I", len(data)) + data
    if isinstance(value, bool):
        return b"C" + struct.pack("<?", value)
    if isinstance(value, np.int64):
        return b"L" + struct.pack("<q", int(value))
    if isinstance(value, (int, np.integer)):
        return (b"I" + struct.pack("<i", int(value))) if -2**31 <= int(value) < 2**31 else (b"L" + struct.pack("<q", int(value)))
    if isinstance(value, float):
        return b"D" + struct.pack("<d", value)
    array = np.asarray(value)
    code, dtype = {"f": (b"d", "<f8"), "i": (b"i", "<i4")}[array.dtype.kind]
    data = array.astype(dtype).tobytes()
    packed = zlib.compress(data) if len(data) > 64 else data  # exporters deflate large arrays
    return code + struct.pack("<III", len(array), 1 if packed is not data else 0, len(packed)) + packed


def _binary_node(name: str, properties, children, offset: int) -> bytes:
    props = b"".join(_binary_property(p) for p in properties)
    head = 13 + len(name)
    body = b""
    at = offset + head + len(props)
    for child in children:
        record = _binary_node(*child, at)
        body += record
        at += len(record)
    if children or not properties:
        body += b"\x00" * 13  # the null record that closes a nested list
    end = offset + head + len(props) + len(body)
    return struct.pack("<IIIB", end, len(properties), len(props), len(name)) + name.encode() + props + body


def write_fbx_binary(path, nodes) -> None:
    """An FBX 7.4 binary file of ``nodes`` (:func:`fbx_document`)."""
    out = b"Kaydara FBX Binary  \x00\x1a\x00" + struct.pack("<I", 7400)
    for node in nodes:
        out += _binary_node(*node, len(out))
    out += b"\x00" * 13
    out += bytes.fromhex("fa bc ab 09 d0 c8 d4 66 b1 76 fb 83 1c f7 26 7e") + b"\x00" * 4  # the footer's id
    out += b"\x00" * ((16 - len(out) % 16) % 16) + struct.pack("<I", 7400) + b"\x00" * 120
    out += bytes.fromhex("f8 5a 8c 6a de f5 d9 7e ec e9 0c e3 75 8f 29 0b")
    with open(path, "wb") as fh:
        fh.write(out)


def _ascii_value(value) -> str:
    if isinstance(value, str):
        name, _, kind = value.partition("\x00\x01")  # binary's "name\x00\x01Class" is ASCII's "Class::name"
        return f'"{kind}::{name}"' if kind else f'"{value}"'
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def _ascii_node(name: str, properties, children, indent: str) -> list[str]:
    if len(properties) == 1 and isinstance(properties[0], np.ndarray):
        array = properties[0].ravel()
        values = ",".join(repr(float(x)) if array.dtype.kind == "f" else str(int(x)) for x in array)
        return [f"{indent}{name}: *{len(array)} {{", f"{indent}\ta: {values}", f"{indent}}}"]
    line = f"{indent}{name}: " + ", ".join(_ascii_value(p) for p in properties)
    if not children:
        return [line]
    out = [line + " {"]
    for child in children:
        out += _ascii_node(*child, indent + "\t")
    return out + [f"{indent}}}"]


def write_fbx_ascii(path, nodes) -> None:
    """An FBX 7.4 ASCII file of ``nodes`` (:func:`fbx_document`)."""
    lines = ["; FBX 7.4.0 project file"]
    for node in nodes:
        lines += _ascii_node(*node, "")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def _chunk(cid: int, data: bytes) -> bytes:
    return struct.pack("<HI", cid, 6 + len(data)) + data


def write_3ds(path, objects) -> None:
    """A 3DS file of ``objects``: (name, vertices (V, 3) in world coordinates, triangles (F, 3))."""
    edit = _chunk(0x3D3E, struct.pack("<I", 3))
    for name, vertices, faces in objects:
        v = np.asarray(vertices, "<f4")
        f = np.asarray(faces, np.int64)
        verts = _chunk(0x4110, struct.pack("<H", len(v)) + v.tobytes())
        local = _chunk(0x4160, np.concatenate([np.eye(3), np.zeros((1, 3))]).astype("<f4").tobytes())
        words = np.column_stack([f, np.full(len(f), 7)]).astype("<u2")
        tris = _chunk(0x4120, struct.pack("<H", len(f)) + words.tobytes())
        edit += _chunk(0x4000, name.encode("latin-1") + b"\x00" + _chunk(0x4100, verts + local + tris))
    with open(path, "wb") as fh:
        fh.write(_chunk(0x4D4D, _chunk(0x0002, struct.pack("<I", 3)) + _chunk(0x3D3D, edit)))
