"""Hostile input: the readers and preprocessing under fuzzed and malicious files.

The contract (``meshsom/io.py``): a bad input becomes a :class:`Rejection` with a reason, or, in
preprocessing, a :class:`MeshError`; nothing else escapes. Every example is read under a guard
that bounds its time (``signal.setitimer``) and its Python/NumPy allocations (``tracemalloc``),
and an audit hook records every file opened, every socket touched and every unpickling attempt.

Example budgets are fixed and ``derandomize=True``: the same examples run in CI every time.
"""

from __future__ import annotations

import bz2
import contextlib
import importlib.util
import json
import os
import pickle
import re
import signal
import struct
import sys
import tempfile
import tracemalloc
from pathlib import Path

import fiona  # noqa: F401 (imported before the guards: with botocore installed, importing it makes
#               urllib3 probe IPv6 with a local socket, which is not the reader reaching out)
import numpy as np
import pyarrow.parquet  # noqa: F401 (likewise loaded before the guards)
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cityjson_samples import CUBE_QUADS, CUBE_VERTS, cube_solid, doc
from meshsom.errors import ConfigError
from meshsom.generate import GeneratorParams, generate_corpus
from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file, write_cityjson
from meshsom.preprocess import PreprocessParams
from pipelines.ingest import process_one

#: Wall-clock seconds one input may take to read and preprocess.
SECONDS_PER_INPUT = 5.0
#: Peak traced allocation (Python objects and NumPy arrays) one small input may cause.
MEGABYTES_PER_INPUT = 64
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".city.json", ".city.jsonl", ".city.json.gz", ".gml",
            ".geojson", ".b3dm", ".cmpt", ".dae", ".gpkg", ".parquet", ".fgb", ".ifc", ".dxf", ".3dm", ".osm", ".fbx",
            ".3ds", ".osm.bz2", ".usda", ".usdc", ".usdz", ".3mf", ".wrl", ".x3d")


# ----------------------------------------------------------------------------- guards

class _Audit:
    """Process-wide audit hook (hooks cannot be removed), active only inside :func:`watched`."""

    events: list | None = None

    @classmethod
    def hook(cls, event, args):
        if cls.events is None:
            return
        if event == "open" or event.startswith(("socket.", "pickle.", "urllib.", "http.")) or event in (
            "subprocess.Popen", "os.system", "os.exec", "os.posix_spawn", "ctypes.dlopen",
        ):
            cls.events.append((event, args))
        if event.startswith(("socket.", "urllib.", "http.")):
            raise PermissionError(f"test_fuzz: network access attempted ({event} {args!r})")


sys.addaudithook(_Audit.hook)


class Overrun(BaseException):
    """Raised by the alarm when one input takes too long (a BaseException, so no ``except Exception`` hides it)."""


@contextlib.contextmanager
def watched(seconds: float = SECONDS_PER_INPUT):
    """Record audit events, and fail the example after ``seconds``."""

    def on_alarm(signum, frame):
        raise Overrun(f"input took more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    events: list = []
    _Audit.events = events
    try:
        yield events
    finally:
        _Audit.events = None
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def peak_memory():
    """Peak traced allocation (bytes) inside the block, as ``box[0]``."""
    box = [0]
    tracemalloc.start()
    tracemalloc.reset_peak()
    try:
        yield box
    finally:
        box[0] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()


def opened_paths(events) -> list[Path]:
    out = []
    for event, args in events:
        if event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
            out.append(Path(os.fsdecode(args[0])).resolve())
    return out


def read_all(path: Path, options: ReaderOptions = ReaderOptions(), preprocess: bool = True):
    """Read one file (and preprocess what it yields) under the guards; returns (items, records, events).

    Asserts the contract: only RawMesh/Rejection come out of the reader, every RawMesh gives a
    manifest record, nothing outside the file's folder is opened, no socket, no unpickling.
    """
    # Overrun is raised from the alarm handler; an Exception escaping the reader fails the test.
    with watched() as events:
        items = list(read_file(path, options))
        records = [process_one(raw, PreprocessParams())[0] for raw in items] if preprocess else []
    assert all(isinstance(it, (RawMesh, Rejection)) for it in items), items
    for it in items:
        if isinstance(it, Rejection):
            assert it.reason and isinstance(it.reason, str)
    for rec in records:
        assert rec["status"] in ("accepted", "rejected")
        assert rec["status"] == "accepted" or rec["reason"]
    folder = path.parent.resolve()
    outside = [p for p in opened_paths(events) if not p.is_relative_to(folder) and not _is_library(p)
               and not _is_scratch(p)]
    assert outside == [], f"opened outside {folder}: {outside}"
    assert not [e for e, _ in events if e.startswith(("socket.", "urllib.", "http.", "pickle."))], events
    return items, records, events


def read_bounded(path: Path, options: ReaderOptions = ReaderOptions()):
    """:func:`read_all`, also asserting the peak allocation stays under ``MEGABYTES_PER_INPUT``."""
    with peak_memory() as peak:
        out = read_all(path, options)
    assert peak[0] < MEGABYTES_PER_INPUT * 2**20, f"{path.name}: peak {peak[0] / 2**20:.0f} MB"
    return out


def _is_scratch(p: Path) -> bool:
    """A reader's own scratch folder (``meshsom-*`` in the temporary folder: an Overpass answer written out as OSM XML,
    INSPIRE's inline parts as a file of parts), which it made and writes itself."""
    root = Path(tempfile.gettempdir()).resolve()
    return p.is_relative_to(root) and p != root and p.relative_to(root).parts[0].startswith("meshsom-")


def _is_library(p: Path) -> bool:
    """Modules Python itself may open while reading (lazy imports, source lines for a warning)."""
    if p.suffix not in (".py", ".pyc", ".so", ".zip"):
        return False
    roots = [d for d in sys.path if d] + [d for m in list(sys.modules.values()) for d in (getattr(m, "__path__", None) or [])]
    return any(p.is_relative_to(Path(d).resolve()) for d in roots if isinstance(d, str) and os.path.exists(d))


# ----------------------------------------------------------------------------- valid seeds

def _blocks(n=2, seed=4):
    return generate_corpus(GeneratorParams(n_blocks=n, seed=seed, families=("L", "gabled")))


def _valid_files() -> dict[str, bytes]:
    """Small valid inputs (bytes) to mutate: OBJ, PLY ascii and binary, CityJSON."""
    block = _blocks(1)[0]
    mesh = trimesh.Trimesh(block.vertices, block.faces, process=False)
    out = {
        ".obj": mesh.export(file_type="obj"),
        "ascii.ply": mesh.export(file_type="ply", encoding="ascii"),
        "binary.ply": mesh.export(file_type="ply", encoding="binary"),
    }
    return {k: v.encode() if isinstance(v, str) else v for k, v in out.items()}


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """One input folder, with a sentinel file beside it (outside) that must never be opened."""
    root = tmp_path_factory.mktemp("hostile")
    (root / "secret.bin").write_bytes(b"\0" * 4096)
    (root / "x.mtl").write_text("newmtl evil\nKd 1 0 0\nmap_Kd ../secret.png\n")
    inputs = root / "inputs"
    inputs.mkdir()
    # Warm up lazy imports so the audit log shows reads, not imports.
    block = _blocks(1)[0]
    for suffix in (".obj", ".ply", ".stl", ".off", ".glb"):
        trimesh.Trimesh(block.vertices, block.faces, process=False).export(str(inputs / f"warm{suffix}"))
        for raw in read_file(inputs / f"warm{suffix}"):
            process_one(raw, PreprocessParams())
        (inputs / f"warm{suffix}").unlink()
    if importlib.util.find_spec("ifcopenshell") is not None:  # IfcOpenShell's imports read grammar files
        from ifc_models import write_house

        for raw in read_file(write_house(inputs / "warm.ifc", garage=False)):
            process_one(raw, PreprocessParams())
        (inputs / "warm.ifc").unlink()
    for suffix, seed in ((".dxf", _dxf_seed), (".3dm", _rhino_seed), (".fbx", _scene_seed("fbx"))):  # ezdxf reads
        # its settings and fonts on import; the readers' modules are loaded
        (inputs / f"warm{suffix}").write_bytes(seed())
        for raw in read_file(inputs / f"warm{suffix}"):
            process_one(raw, PreprocessParams())
        (inputs / f"warm{suffix}").unlink()
    return inputs


def _dxf_seed() -> bytes:
    """A DXF drawing (ezdxf) of a box as 3DFACEs and a block of it inserted, turned."""
    import io

    import ezdxf

    doc = ezdxf.new("R2010")
    v, f = _blocks(1)[0].vertices, _blocks(1)[0].faces
    block = doc.blocks.new("house")
    for a, b, c in f:
        doc.modelspace().add_3dface([v[a], v[b], v[c], v[c]])
        block.add_3dface([v[a], v[b], v[c], v[c]])
    doc.modelspace().add_blockref("house", (100, 0, 0), dxfattribs={"rotation": 30})
    text = io.StringIO()
    doc.write(text)
    return text.getvalue().encode()


def _dxf_solid_seed() -> bytes:
    """A DXF drawing (R2010: SAT text) of an ACIS solid: a block with a curved facade, a courtyard and a round light
    well (planes, cylinders, arcs, holes)."""
    import io

    import ezdxf
    from acis_solids import add_solid, extrusion_body

    outline = [("line", (20.0, 0.0)), ("arc", (20.0, 12.0), (20.0, 6.0)), ("line", (0.0, 12.0)), ("line", (0.0, 0.0))]
    well = [("circle", (8.0, 6.0), 2.0, False)]
    doc = ezdxf.new("R2010")
    add_solid(doc.modelspace(), [extrusion_body([outline, well], 0.0, 15.0)])
    text = io.StringIO()
    doc.write(text)
    return text.getvalue().encode()


def _rhino_seed() -> bytes:
    """A Rhino model (openNURBS) of a box polysurface in millimetres."""
    import tempfile

    import rhino3dm

    model = rhino3dm.File3dm()
    model.Objects.AddBrep(rhino3dm.Brep.CreateFromBox(rhino3dm.Box(rhino3dm.BoundingBox(0, 0, 0, 10000, 6000, 4000))))
    with tempfile.TemporaryDirectory() as folder:
        assert model.Write(f"{folder}/seed.3dm", 8)
        return Path(f"{folder}/seed.3dm").read_bytes()


def _usd_seed(suffix: str):
    """A USD stage (text, crate, or a USDZ package of the crate) of two blocks, each a building with its mesh as
    quads and triangles, placed by a transform."""
    def seed() -> bytes:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdUtils

        with tempfile.TemporaryDirectory() as folder:
            layer = Path(folder) / f"seed{'.usdc' if suffix == '.usdz' else suffix}"
            stage = Usd.Stage.CreateNew(str(layer))
            UsdGeom.SetStageMetersPerUnit(stage, 1.0)
            UsdGeom.SetStageUpAxis(stage, "Z")
            stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/City").GetPrim())
            for k, block in enumerate(_blocks(2)):
                house = UsdGeom.Xform.Define(stage, f"/City/B{k}")
                house.AddTranslateOp().Set(Gf.Vec3d(40.0 * k, 0.0, 0.0))
                mesh = UsdGeom.Mesh.Define(stage, f"/City/B{k}/shell")
                mesh.CreatePointsAttr([Gf.Vec3f(*map(float, v)) for v in block.vertices])
                mesh.CreateFaceVertexCountsAttr([3] * len(block.faces))
                mesh.CreateFaceVertexIndicesAttr([int(i) for i in block.faces.ravel()])
            stage.GetRootLayer().Save()
            if suffix != ".usdz":
                return layer.read_bytes()
            UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer)), str(Path(folder) / "seed.usdz"))
            return (Path(folder) / "seed.usdz").read_bytes()
    return seed


def _3mf_seed() -> bytes:
    """A 3MF package (zip: content types, relationships, the model) of two blocks as build items, in metres."""
    import io
    import zipfile

    objects, items = [], []
    for k, block in enumerate(_blocks(2), 1):
        vertices = "".join(f'<vertex x="{x:.4f}" y="{y:.4f}" z="{z:.4f}"/>' for x, y, z in block.vertices)
        triangles = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in block.faces)
        objects.append(f'<object id="{k}" type="model" name="house {k}"><mesh><vertices>{vertices}</vertices>'
                       f'<triangles>{triangles}</triangles></mesh></object>')
        items.append(f'<item objectid="{k}" transform="1 0 0 0 1 0 0 0 1 {40 * k} 0 0"/>')
    model = ('<?xml version="1.0" encoding="UTF-8"?><model unit="meter" xml:lang="en-US" '
             'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">'
             f'<resources>{"".join(objects)}</resources><build>{"".join(items)}</build></model>')
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as package:
        package.writestr("[Content_Types].xml", '<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.'
                         'openxmlformats.org/package/2006/content-types"><Default Extension="model" ContentType="'
                         'application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
        package.writestr("_rels/.rels", '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
                         'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.model" '
                         'Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>'
                         '</Relationships>')
        package.writestr("3D/3dmodel.model", model)
    return out.getvalue()


def _x3d_seed(suffix: str):
    """An X3D (XML) or VRML97 scene of two blocks, each a DEF'd Transform of an IndexedFaceSet."""
    def seed() -> bytes:
        nodes = []
        for k, block in enumerate(_blocks(2)):
            points = ", ".join(" ".join(f"{c:.4f}" for c in v) for v in block.vertices)
            index = " ".join(f"{a} {b} {c} -1" for a, b, c in block.faces)
            if suffix == ".wrl":
                nodes.append(f"DEF B{k} Transform {{ translation {40 * k} 0 0 children [ Shape {{ geometry "
                             f"IndexedFaceSet {{ coord Coordinate {{ point [ {points} ] }} coordIndex [ {index} ] }} "
                             f"}} ] }}")
            else:
                nodes.append(f"<Transform DEF='B{k}' translation='{40 * k} 0 0'><Shape><IndexedFaceSet "
                             f"coordIndex='{index}'><Coordinate point='{points}'/></IndexedFaceSet></Shape></Transform>")
        if suffix == ".wrl":
            return ("#VRML V2.0 utf8\n" + "\n".join(nodes) + "\n").encode()
        return ("<?xml version='1.0' encoding='UTF-8'?><X3D profile='Interchange' version='3.3'><Scene>"
                + "".join(nodes) + "</Scene></X3D>").encode()
    return seed


@pytest.mark.parametrize("suffix,seeder", [(".usda", _usd_seed(".usda")), (".usdc", _usd_seed(".usdc")),
                                           (".usdz", _usd_seed(".usdz")), (".3mf", _3mf_seed),
                                           (".wrl", _x3d_seed(".wrl")), (".x3d", _x3d_seed(".x3d"))],
                         ids=["usda", "usdc", "usdz", "3mf", "wrl", "x3d"])
def test_mutated_scene_files_are_read_or_rejected(folder, suffix, seeder):
    """Mutations of a USD stage (Pixar's text and crate parsers, a USDZ package), a 3MF package and X3D and VRML
    scenes (their own parsers) are read or rejected: no exception escapes (USD's errors quote bytes that are not
    UTF-8, and a damaged crate value raises only when it is read), no library takes the process down."""
    seed = seeder()
    items, records, _ = read_all(_write(folder / f"valid{suffix}", seed))
    assert len(records) == 2 and all(r["status"] == "accepted" for r in records)  # the unmutated seed: 2 buildings

    @settings(FUZZ, max_examples=60)
    @given(data=mutated(seed))
    def check(data):
        read_bounded(_write(folder / f"mutant{suffix}", data))

    check()


@pytest.fixture(scope="module")
def city_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("city") / "blocks.city.json"
    write_cityjson(path, _blocks(2))
    return path.read_bytes()


# ----------------------------------------------------------------------------- 1. random bytes

MAGIC = {
    ".obj": [b"", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", b"mtllib ../x.mtl\n"],
    ".ply": [b"", b"ply\nformat ascii 1.0\n", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
              b"property float x\nproperty float y\nproperty float z\nelement face 1\n"
              b"property list uchar int vertex_indices\nend_header\n"],
    ".stl": [b"", b"solid x\n", b"\0" * 80 + struct.pack("<I", 3)],
    ".off": [b"", b"OFF\n", b"OFF\n3 1 0\n"],
    ".glb": [b"", b"glTF" + struct.pack("<II", 2, 64), b"glTF" + struct.pack("<III", 2, 64, 40) + b"JSON"],
    ".gltf": [b"", b'{"asset": {"version": "2.0"}, ', b'{"buffers": [{"uri": "../secret.bin", "byteLength": 4096}], ',
              b'{"extensionsUsed": ["KHR_draco_mesh_compression"], "buffers": [{"uri": "data:;base64,AAAA", "byteLength": 3}], '],
    ".city.json": [b"", b'{"type": "CityJSON", "version": "2.0", ', b'{"type":"CityJSON","version":"1.0","vertices":[[0,0,0]],'],
    ".city.jsonl": [b"", b'{"type":"CityJSON","version":"2.0","transform":{"scale":[1,1,1],"translate":[0,0,0]},'
                    b'"CityObjects":{},"vertices":[]}\n{"type":"CityJSONFeature","id":"a",', b"\n\n{"],
    ".city.json.gz": [b"", b"\x1f\x8b", b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff"],
    ".geojson": [b"", b'{"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": ',
                 b'{"type": "Feature", "place": {"type": "Polyhedron", "coordinates": [[[[['],
    ".gml": [b"", b'<CityModel xmlns:gml="http://www.opengis.net/gml"><cityObjectMember><Building gml:id="a">',
             b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY e SYSTEM "../secret.bin">]><CityModel>&e;'],
    ".gpkg": [b"", b"SQLite format 3\0", b"SQLite format 3\0\x10\x00\x01\x01\x00\x40\x20\x20"],
    ".parquet": [b"", b"PAR1", b"PAR1\x15\x04\x15\x10"],
    ".fgb": [b"", b"fgb\x03fgb\x00", b"fgb\x03fgb\x01\x00\x00\x00"],
    ".b3dm": [b"", b"b3dm" + struct.pack("<6I", 1, 1600, 24, 0, 16, 0) + b'{"BATCH_LENGTH": 2}     ' + b'{"id": [1, 2]}  ',
              b"b3dm" + struct.pack("<6I", 1, 4 * 10**9, 8, 0, 0, 0) + b'{}      glTF'],
    ".dae": [b"", b'<?xml version="1.0"?><COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">',
             b'<COLLADA><asset><unit meter="0"/><up_axis>Q_UP</up_axis></asset><library_geometries><geometry><mesh>'],
    ".dxf": [b"", b"  0\nSECTION\n  2\nENTITIES\n  0\n3DFACE\n  8\n0\n 10\n", b"AutoCAD Binary DXF\r\n\x1a\x00"],
    ".osm": [b"", b'<?xml version="1.0"?><osm version="0.6"><node id="1" lat="47" lon="8"/><way id="2"><nd ref="1"/>',
             b'<osm><relation id="1"><member type="way" ref="1" role="outer"/><tag k="type" v="multipolygon"/>'],
    ".3dm": [b"", b"3D Geometry File Format        ", b"3D Geometry File Format        \x01\x00\x00\x00 3dm file"],
    ".osm.bz2": [b"", b"BZh9", bz2.compress(b'<?xml version="1.0"?><osm version="0.6"><node id="1" lat="47" lon="8"/>')],
    ".fbx": [b"", b"Kaydara FBX Binary  \x00\x1a\x00" + struct.pack("<I", 7400),
             b"; FBX 7.4.0 project file\nObjects:  {\n\tGeometry: 1, \"Geometry::a\", \"Mesh\" {\n\t\tVertices: *9 {\n"],
    ".3ds": [b"", struct.pack("<HI", 0x4D4D, 10**9) + struct.pack("<HI", 0x3D3D, 2000),
             struct.pack("<HI", 0x4D4D, 64) + struct.pack("<HI", 0x3D3D, 58) + struct.pack("<HI", 0x4000, 52) + b"a\0"],
    ".ifc": [b"", b"ISO-10303-21;\nHEADER;\n", b"ISO-10303-21;\nHEADER;\nFILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\n"
             b"#1=IFCBUILDING('0p49tVvDnBOh5$bRyf1JGA',$,'b',$,$,$,$,$,$,$,$,$);\n"],
    ".usda": [b"", b"#usda 1.0\n", b'#usda 1.0\n(\n    metersPerUnit = 1\n)\ndef Mesh "m" {\n    point3f[] points = [(0, 0, 0), '],
    ".usdc": [b"", b"PXR-USDC", b"PXR-USDC\x00\x08\x00\x00\x00\x00\x00\x00" + struct.pack("<Q", 10**12)],
    ".usdz": [b"", b"PK\x03\x04", b"PK\x03\x04\x14\x00\x00\x00\x00\x00" + b"\x00" * 16 + struct.pack("<HH", 9, 0) + b"seed.usdc"],
    ".3mf": [b"", b"PK\x03\x04", b"PK\x05\x06" + b"\x00" * 18],
    ".wrl": [b"", b"#VRML V2.0 utf8\n", b"#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord Coordinate { point [ "],
    ".x3d": [b"", b"<X3D><Scene>", b"<?xml version='1.0'?><X3D><Scene><Shape><IndexedFaceSet coordIndex='0 1 2 -1'>"],
    ".cmpt": [b"", b"cmpt" + struct.pack("<III", 1, 1600, 2) + b"b3dm" + struct.pack("<II", 1, 40),
              b"cmpt" + struct.pack("<III", 1, 4 * 10**9, 3) + b"cmpt" + struct.pack("<III", 1, 32, 1)],
}


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_random_bytes_give_rejections_only(folder, suffix):
    @FUZZ
    @given(prefix=st.sampled_from(MAGIC[suffix]), body=st.binary(max_size=1500))
    def check(prefix, body):
        items, records, _ = read_bounded(_write(folder / f"random{suffix}", prefix + body))
        assert items, "a file must be accounted for: at least one mesh or one rejection"
        assert len(records) == len(items)

    check()


# ----------------------------------------------------------------------------- 2. mutations of valid files

HOSTILE_NUMBERS = [b"1e308", b"-1e308", b"1e999", b"nan", b"NaN", b"inf", b"-inf", b"-1", b"-7", b"0",
                   b"4294967296", b"1000000000000", b"9223372036854775808", b"1" * 40, b"1.5", b"-0"]
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


@st.composite
def mutated(draw, data: bytes):
    """``data`` with 1-4 random mutations: byte flips, truncation, line edits, hostile numbers."""
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "truncate", "dup_line", "del_line", "number", "insert"]))
        if not data:
            break
        if op == "flip":
            i = draw(st.integers(0, len(data) - 1))
            data = data[:i] + bytes([data[i] ^ draw(st.integers(1, 255))]) + data[i + 1:]
        elif op == "truncate":  # mostly late, where the parser has got going
            data = data[: draw(st.sampled_from([len(data) - 1 - draw(st.integers(0, len(data) // 2)), draw(st.integers(0, len(data) - 1))]))]
        elif op in ("dup_line", "del_line"):
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i:i + 1] = [lines[i]] * 2 if op == "dup_line" else []
            data = b"\n".join(lines)
        elif op == "number":
            spans = [m.span() for m in NUMBER.finditer(data)]
            if spans:
                a, b = spans[draw(st.integers(0, len(spans) - 1))]
                data = data[:a] + draw(st.sampled_from(HOSTILE_NUMBERS)) + data[b:]
        else:
            i = draw(st.integers(0, len(data)))
            data = data[:i] + draw(st.binary(min_size=1, max_size=16)) + data[i:]
    return data


@pytest.mark.parametrize("kind", [".obj", "ascii.ply", "binary.ply"])
def test_mutated_meshes_are_read_or_rejected(folder, kind):
    seed = _valid_files()[kind]
    suffix = ".ply" if kind.endswith(".ply") else kind
    items, records, _ = read_all(_write(folder / f"valid{suffix}", seed))
    assert [r["status"] for r in records] == ["accepted"]  # the unmutated seed is valid

    @settings(FUZZ, max_examples=100)
    @given(data=mutated(seed))
    def check(data):
        read_bounded(_write(folder / f"mutant{suffix}", data))

    check()


def test_mutated_ifc_is_read_or_rejected(folder, tmp_path_factory):
    """Mutations of an IFC file (numbers, lines, bytes of its STEP text) are read or rejected;
    IfcOpenShell never takes the process down."""
    pytest.importorskip("ifcopenshell")
    from ifc_models import write_house

    seed = write_house(tmp_path_factory.mktemp("ifc") / "seed.ifc", garage=False, georeferenced=False).read_bytes()
    items, records, _ = read_all(_write(folder / "valid.ifc", seed))
    assert [r["status"] for r in records] == ["accepted"]  # the unmutated seed is read

    @settings(FUZZ, max_examples=40)
    @given(data=mutated(seed))
    def check(data):
        read_bounded(_write(folder / "mutant.ifc", data))

    check()


def _scene_seed(kind: str):
    """An FBX scene (binary: deflated arrays; or ASCII) of two blocks, one turned, or a 3DS file of them."""
    def seed() -> bytes:
        import tempfile

        from scene_files import fbx_document, write_3ds, write_fbx_ascii, write_fbx_binary

        a, b = _blocks(2)
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "seed"
            if kind == "3ds":
                write_3ds(path, [("a", a.vertices, a.faces), ("b", b.vertices + [30.0, 0, 0], b.faces)])
            else:
                nodes = fbx_document([("a", a.vertices, a.faces.tolist(), (0, 0, 0), (0, 0, 0), (1, 1, 1)),
                                      ("b", b.vertices, b.faces.tolist(), (30, 0, 0), (0, 0, 30), (1, 1, 1))])
                (write_fbx_binary if kind == "fbx" else write_fbx_ascii)(path, nodes)
            return path.read_bytes()
    return seed


@pytest.mark.parametrize("suffix,seeder", [(".dxf", _dxf_seed), (".dxf", _dxf_solid_seed), (".3dm", _rhino_seed),
                                           (".fbx", _scene_seed("fbx")), (".fbx", _scene_seed("fbx-ascii")),
                                           (".3ds", _scene_seed("3ds"))],
                         ids=["dxf", "dxf of an ACIS solid", "3dm", "fbx", "fbx ascii", "3ds"])
def test_mutated_cad_files_are_read_or_rejected(folder, suffix, seeder):
    """Mutations of a DXF drawing (its group codes and numbers, as text; and of an ACIS solid's SAT records), of a
    Rhino model (openNURBS's binary chunks), of an FBX scene (assimp's parsers, binary and ASCII) and of a 3DS file
    (its chunks) are read or rejected; no library takes the process down."""
    seed = seeder()
    items, records, _ = read_all(_write(folder / f"valid{suffix}", seed))
    assert records and all(r["status"] == "accepted" for r in records)  # the unmutated seed is read

    @settings(FUZZ, max_examples=60)
    @given(data=mutated(seed))
    def check(data):
        read_bounded(_write(folder / f"mutant{suffix}", data))

    check()


def test_mutated_b3dm_is_read_or_rejected(folder):
    from test_tiles3d import _buildings, b3dm

    seed = b3dm(_buildings(2), lambda v: v)
    items, records, _ = read_all(_write(folder / "valid.b3dm", seed))
    assert len(records) == 2 and records[0]["status"] == "accepted"  # the unmutated seed is read

    @settings(FUZZ, max_examples=100)
    @given(data=mutated(seed))
    def check(data):
        read_bounded(_write(folder / "mutant.b3dm", data))

    check()


@pytest.mark.parametrize("kind", ["binary.ply"])
def test_binary_ply_with_hostile_values(folder, kind):
    """Binary PLY payload values replaced by NaN, huge floats, and out-of-range or negative indices."""
    seed = _valid_files()[kind]
    head, _, body = seed.partition(b"end_header\n")
    head += b"end_header\n"
    values = [struct.pack("<f", x) for x in (np.nan, np.inf, -3e38, 3e38, -1.0)] + [
        struct.pack("<i", x) for x in (-1, 2**31 - 1, 10**6, -(2**31))] + [b"\xff"]

    @FUZZ
    @given(edits=st.lists(st.tuples(st.integers(0, max(0, len(body) - 4)), st.sampled_from(values)), min_size=1, max_size=6))
    def check(edits):
        data = bytearray(body)
        for at, value in edits:
            data[at:at + len(value)] = value
        items, records, _ = read_bounded(_write(folder / "hostile.ply", head + bytes(data)))
        assert items, "a file must be accounted for: at least one mesh or one rejection"
        assert len(records) == len(items)

    check()


JSON_HOSTILE = st.one_of(
    st.sampled_from([None, True, -1, 0, 10**12, 2**63, 10**40, 1.5, float("nan"), float("inf"), -1e308, "", "x",
                     "Building", "BuildingPart", "Solid", "MultiSurface", "CompositeSolid", "2.0", [], {}, [[]], [[[]]],
                     [0, 1, 2], [[0, 1, 2]], {"type": "Solid"}, [10**12, 0, 1], [-1, 0, 1]]),
    st.recursive(st.integers(-5, 10**13) | st.floats(allow_nan=True) | st.text(max_size=4) | st.none(),
                 lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=3), max_leaves=8),
)


def _json_paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _json_paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _json_paths(v, prefix + (i,))


@st.composite
def mutated_json(draw, document):
    """A copy of ``document`` with 1-3 values (anywhere in the tree) replaced, deleted or duplicated."""
    document = json.loads(json.dumps(document))
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_json_paths(document))[1:]
        if not paths:
            break
        where = draw(st.sampled_from(paths))
        parent = document
        for key in where[:-1]:
            parent = parent[key]
        op = draw(st.sampled_from(["replace", "replace", "delete", "duplicate"]))
        if op == "replace":  # a copy: sampled lists and dicts are shared, and later steps edit in place
            parent[where[-1]] = json.loads(json.dumps(draw(JSON_HOSTILE)))
        elif op == "delete":
            del parent[where[-1]]
        elif isinstance(parent, list):
            parent.insert(where[-1], json.loads(json.dumps(parent[where[-1]])))
    return document


@pytest.mark.parametrize("seed", ["blocks", "instances"])
def test_mutated_cityjson_structure(folder, city_bytes, seed):
    """``instances``: a building placed from a geometry template (GeometryInstance) and one written out."""
    from cityjson_samples import instanced_box_doc

    document = json.loads(city_bytes) if seed == "blocks" else instanced_box_doc({})
    items, records, _ = read_all(_write(folder / "valid.city.json", json.dumps(document).encode()))
    assert [r["status"] for r in records] == ["accepted", "accepted"]

    @settings(FUZZ, max_examples=150 if seed == "blocks" else 80)
    @given(d=mutated_json(document))
    def check(d):
        read_bounded(_write(folder / "mutant.city.json", json.dumps(d).encode()))

    check()


def test_mutated_overpass_answers(folder, tmp_path_factory):
    """An Overpass API answer (JSON: the OpenStreetMap district of tests/test_osm.py, ``out geom``, with building
    relations) with values anywhere replaced, deleted or duplicated: read or rejected, never an exception."""
    from test_osm import _overpass_answer, _related_district

    xml, _ = _related_district(tmp_path_factory.mktemp("overpass") / "r.osm")
    document = _overpass_answer(xml, True)
    kept = {("way", 100), ("way", 101), ("way", 102), ("way", 110), ("relation", 150), ("relation", 170)}
    document["elements"] = [e for e in document["elements"] if (e["type"], e["id"]) in kept or e["type"] == "node"]
    items, records, _ = read_all(_write(folder / "valid.json", json.dumps(document).encode()))
    assert sum(r["status"] == "accepted" for r in records) == 2  # the tower of parts and its neighbour

    @settings(FUZZ, max_examples=50)
    @given(d=mutated_json(document))
    def check(d):
        items, records, _ = read_bounded(_write(folder / "mutant.json", json.dumps(d).encode()))
        assert items and len(records) == len(items)

    check()


def mutants_are_accounted_for(path: Path, seed: bytes, max_examples: int = 100) -> None:
    """Every mutation of ``seed`` written to ``path`` gives meshes or rejections (at least one), each
    preprocessed into a record, within the time and memory bounds."""
    @settings(FUZZ, max_examples=max_examples)
    @given(data=mutated(seed))
    def check(data):
        items, records, _ = read_bounded(_write(path, data))
        assert items, "a file must be accounted for: at least one mesh or one rejection"
        assert len(records) == len(items)

    check()


def test_mutated_osm_building_relations(folder):
    """An OpenStreetMap extract of a building relation (an outline, its overhanging part, a missing member) and its
    neighbour, its bytes mutated (ids, roles, member types, numbers): read or rejected, never an exception."""
    from test_osm import OsmWriter

    osm = OsmWriter()
    osm.way(100, (0, 0, 20, 20), building="office")
    osm.way(101, (0, 0, 20, 20), **{"building:part": "yes"})
    osm.way(102, (10, 10, 36, 36), min_height="12", height="20", **{"building:part": "yes"})
    osm.way(110, (21, 21, 40, 40), building="yes", height="6")
    osm.building_relation(150, [("outline", "way/100"), ("part", "way/101"), ("part", "way/102"), ("part", "way/9")],
                          height="10")
    seed = osm.text().encode()
    items, records, _ = read_all(_write(folder / "valid.osm", seed))
    assert [r["status"] for r in records] == ["accepted", "accepted"]
    mutants_are_accounted_for(folder / "mutant.osm", seed, max_examples=40)


def test_mutated_inspire_inline_parts(folder):
    """An INSPIRE file whose Buildings hold their BuildingParts (taken out, read by GDAL as a file of parts), its bytes
    mutated: read or rejected, never an exception."""
    from test_inspire import HEADER, _inline

    seed = (HEADER + _inline("DE.B1", (0, 0, 20, 10), 5, [("DE.P1", (0, 0, 10, 10), 2), ("DE.P2", (10, 0, 10, 10), None)])
            + "</gml:FeatureCollection>\n").encode()
    items, records, _ = read_all(_write(folder / "valid.gml", seed))
    assert [r["status"] for r in records] == ["accepted"] and items[0].parts
    mutants_are_accounted_for(folder / "mutant.gml", seed, max_examples=50)


def test_mutated_cityjson_bytes(folder, city_bytes):
    items, records, _ = read_all(_write(folder / "valid.city.json", city_bytes))
    assert len(records) == 2 and records[0]["status"] == "accepted"  # the unmutated seed is read
    mutants_are_accounted_for(folder / "mutant.city.json", city_bytes)


@pytest.fixture(scope="module")
def seq_bytes(city_bytes) -> bytes:
    from cityjson_samples import to_cityjsonseq

    return b"".join(json.dumps(line).encode() + b"\n" for line in to_cityjsonseq(json.loads(city_bytes)))


def test_mutated_cityjsonseq_bytes(folder, seq_bytes):
    """Mutated CityJSONSeq: every line's building is read, or rejected naming its line; nothing else."""
    items, records, _ = read_all(_write(folder / "valid.city.jsonl", seq_bytes))
    assert [r["status"] for r in records] == ["accepted", "accepted"]
    mutants_are_accounted_for(folder / "mutant.city.jsonl", seq_bytes)


def test_mutated_citygml_bytes(folder, city_bytes):
    """Mutated CityGML (with boundary surfaces and xlink:href solids)."""
    from test_citygml import to_citygml

    seed = to_citygml(json.loads(city_bytes), href=True).encode()
    items, records, _ = read_all(_write(folder / "valid.gml", seed))
    assert [r["status"] for r in records] == ["accepted", "accepted"]
    mutants_are_accounted_for(folder / "mutant.gml", seed)


def _geojson_seed() -> dict:
    """OSM-like footprints in longitude/latitude (a height as text, a courtyard, a storey count)
    and a JSON-FG prism and polyhedron in a projected CRS."""
    lon, lat = 4.357, 52.011
    d = 1e-4

    def ring(x0, y0, w, h):
        return [[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h], [x0, y0]]

    cube = [[[[list(map(float, CUBE_VERTS[i])) for i in q] + [list(map(float, CUBE_VERTS[q[0]]))]] for q in CUBE_QUADS]]
    return {"type": "FeatureCollection", "coordRefSys": "EPSG:28992", "features": [
        {"type": "Feature", "id": "a", "geometry": {"type": "Polygon", "coordinates": [ring(lon, lat, d, d)]},
         "properties": {"height": "9 m"}},
        {"type": "Feature", "id": "b", "geometry": {"type": "Polygon", "coordinates": [
            ring(lon + 2 * d, lat, 3 * d, 3 * d), ring(lon + 3 * d, lat + d, d, d)[::-1]]},
         "properties": {"building:levels": 3}},
        {"type": "Feature", "id": "c", "geometry": None, "place": {
            "type": "Prism", "base": {"type": "Polygon", "coordinates": [ring(85000, 447000, 10, 6)]}, "upper": 7}},
        {"type": "Feature", "id": "e", "geometry": None, "place": {"type": "Polyhedron", "coordinates": cube}},
    ]}


def test_mutated_geojson(folder):
    """Mutated GeoJSON / JSON-FG, structure and bytes: features read or rejected, nothing else."""
    document = _geojson_seed()
    seed = json.dumps(document).encode()
    items, records, _ = read_all(_write(folder / "valid.geojson", seed))
    assert [r["status"] for r in records] == ["accepted"] * 4

    @settings(FUZZ, max_examples=100)
    @given(d=mutated_json(document))
    def check(d):
        read_bounded(_write(folder / "mutant.geojson", json.dumps(d).encode()))

    check()
    mutants_are_accounted_for(folder / "mutant.fg.json", seed, max_examples=60)


def test_xml_entity_bomb_is_a_rejection_and_external_entities_are_not_read(folder):
    laughs = b'<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "' + b"x" * 64 + b'">' + b"".join(
        b'<!ENTITY %s "%s">' % (bytes([98 + k]), (b"&" + bytes([97 + k]) + b";") * 10) for k in range(9)) + b"]><CityModel>&j;</CityModel>"
    (rej,) = read_bounded(_write(folder / "laughs.gml", laughs))[0]
    assert isinstance(rej, Rejection) and "XML" in rej.reason
    external = b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><CityModel>&e;</CityModel>'
    (rej,) = read_bounded(_write(folder / "external.gml", external))[0]
    assert isinstance(rej, Rejection)


@pytest.mark.parametrize("suffix", [".city.json.gz", ".city.jsonl.gz", ".obj.gz"])
def test_mutated_gzip_bytes(folder, city_bytes, seq_bytes, suffix):
    """Flipped, truncated and inserted bytes in the compressed stream (header, deflate data, CRC)."""
    import gzip

    plain = {".city.json.gz": city_bytes, ".city.jsonl.gz": seq_bytes, ".obj.gz": _valid_files()[".obj"]}[suffix]
    seed = gzip.compress(plain, mtime=0)
    items, records, _ = read_all(_write(folder / f"valid{suffix}", seed))
    assert records and all(r["status"] == "accepted" for r in records)
    mutants_are_accounted_for(folder / f"mutant{suffix}", seed, max_examples=60)


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# ----------------------------------------------------------------------------- 3. size claims

def test_cityjson_index_of_ten_to_the_twelve_is_refused_without_allocating(folder):
    d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS)
    d["CityObjects"]["X"]["geometry"][0]["boundaries"][0][0][0][0] = 10**12
    path = _write(folder / "claims.city.json", json.dumps(d).encode())
    with peak_memory() as peak:
        items, _, _ = read_all(path)
    assert peak[0] < 4 * 2**20  # a (10**12, 3) gather would be 24 TB
    assert len(items) == 1 and isinstance(items[0], Rejection)
    assert "vertex index 1000000000000 out of range (the file has 8 vertices)" in items[0].reason


def test_cityjson_vertices_beyond_the_limit_are_refused_before_conversion(folder):
    n = 100_000
    d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, CUBE_VERTS + [[1, 2, 3]] * n)
    path = _write(folder / "many.city.json", json.dumps(d).encode())
    with peak_memory() as accepted:
        (item,), _, _ = read_all(path, preprocess=False)
    assert isinstance(item, RawMesh)
    with peak_memory() as refused:
        (item,), _, _ = read_all(path, ReaderOptions(max_vertices=1000))
    assert isinstance(item, Rejection)
    assert f"declares {n + 8} vertices, more than the limit of 1000" in item.reason
    # The parsed JSON costs about ten times the file; the (n, 3) int64 array is never made.
    assert refused[0] < 12 * path.stat().st_size
    assert refused[0] < accepted[0] - 0.9 * 24 * n


def test_cityjson_cycle_of_parts_terminates(folder):
    d = doc({"B": {"type": "Building", "children": ["P"]},
             "P": {"type": "BuildingPart", "parents": ["B"], "children": ["P", "Q"], "geometry": [cube_solid()]},
             "Q": {"type": "BuildingPart", "parents": ["P"], "children": ["P"]}}, CUBE_VERTS)
    (item,), records, _ = read_all(_write(folder / "cycle.city.json", json.dumps(d).encode()))
    assert isinstance(item, RawMesh) and records[0]["status"] == "accepted"


def test_cityjson_spiky_ring_is_fast(folder):
    """A footprint ring going back and forth along one line (every vertex a spike) is not quadratic."""
    ring = [0, 1] * 20_000
    d = doc({"X": {"type": "Building", "geometry": [{"type": "MultiSurface", "lod": "1", "boundaries": [[ring]]}]}},
            CUBE_VERTS)
    (item,), _, _ = read_all(_write(folder / "spiky.city.json", json.dumps(d).encode()))
    assert isinstance(item, Rejection)


def test_cityjson_deeply_nested_json_is_a_rejection(folder):
    path = _write(folder / "deep.city.json", b'{"type": "CityJSON", "x": ' + b"[" * 200_000 + b"]" * 200_000 + b"}")
    (item,), _, _ = read_all(path)
    assert isinstance(item, Rejection) and "deep.city.json" in item.source


_PLY_HEAD = (b"element vertex 1000000000000\nproperty float x\nproperty float y\nproperty float z\n"
             b"element face 1000000000000\nproperty list uchar int vertex_indices\nend_header\n")
HEADER_CLAIMS = {
    "binary.ply": b"ply\nformat binary_little_endian 1.0\n" + _PLY_HEAD + b"\0" * 64,
    "ascii.ply": b"ply\nformat ascii 1.0\n" + _PLY_HEAD + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    ".off": b"OFF\n1000000000000 1000000000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    ".stl": b"\0" * 80 + struct.pack("<I", 2**32 - 1) + b"\0" * 100,
    ".glb": b"glTF" + struct.pack("<III", 2, 2**32 - 1, 2**32 - 20) + b"JSON" + b'{"buffers": [{"byteLength": 1000000000000}]}',
    ".gltf": b'{"asset": {"version": "2.0"}, "buffers": [{"byteLength": 1000000000000, "uri": '
              b'"data:application/octet-stream;base64,AAAA"}], "accessors": [{"bufferView": 0, '
              b'"componentType": 5126, "count": 1000000000000, "type": "VEC3"}], "bufferViews": '
              b'[{"buffer": 0, "byteLength": 12000000000000}], "meshes": [{"primitives": '
              b'[{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}',
}


@pytest.mark.parametrize("kind", HEADER_CLAIMS)
def test_mesh_headers_claiming_ten_to_the_twelve_elements(folder, kind):
    """Counts in headers are not trusted: the file is rejected, nothing of the claimed size is allocated."""
    suffix = ".ply" if kind.endswith(".ply") else kind
    with peak_memory() as peak:
        (item,), _, _ = read_all(_write(folder / f"claims{suffix}", HEADER_CLAIMS[kind]))
    assert isinstance(item, Rejection)
    assert peak[0] < 16 * 2**20


# ----------------------------------------------------------------------------- 4. references outside the folder

def _gltf_with_buffer(uri: str) -> bytes:
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes() + np.array([0, 1, 2], np.uint16).tobytes()
    return json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"uri": uri, "byteLength": len(tri)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }).encode()


OUTSIDE_URIS = ["../secret.bin", "sub/../../secret.bin", "{root}/secret.bin", "file://{root}/secret.bin",
                "/etc/passwd", "file:///etc/passwd", "http://127.0.0.1:9/secret.bin", "https://example.com/x.bin",
                "%2e%2e/secret.bin", "..\\secret.bin"]


@pytest.mark.parametrize("uri", OUTSIDE_URIS)
def test_gltf_buffer_outside_the_folder_is_never_opened(folder, uri):
    uri = uri.format(root=folder.parent)
    (item,), _, events = read_all(_write(folder / "outside.gltf", _gltf_with_buffer(uri)))
    assert isinstance(item, Rejection), item
    assert "outside.gltf" in item.source


def test_gltf_buffer_inside_the_folder_is_read(folder):
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes() + np.array([0, 1, 2], np.uint16).tobytes()
    (folder / "inside.bin").write_bytes(tri)
    (item,), _, events = read_all(_write(folder / "inside.gltf", _gltf_with_buffer("inside.bin")), preprocess=False)
    assert isinstance(item, RawMesh) and len(item.faces) == 1
    assert (folder / "inside.bin").resolve() in opened_paths(events)


def test_symlink_out_of_the_folder_is_not_followed(folder):
    link = folder / "link.bin"
    if not link.exists():
        link.symlink_to(folder.parent / "secret.bin")
    (item,), _, _ = read_all(_write(folder / "symlinked.gltf", _gltf_with_buffer("link.bin")))
    assert isinstance(item, Rejection)


@pytest.mark.parametrize("ref", ["../x.mtl", "{root}/x.mtl", "/etc/passwd", "file:///etc/passwd", "http://127.0.0.1:9/x.mtl"])
def test_obj_mtllib_outside_the_folder_is_never_opened(folder, ref):
    ref = ref.format(root=folder.parent)
    cube = "".join(f"v {x / 1000} {y / 1000} {z / 1000}\n" for x, y, z in CUBE_VERTS)
    cube += "usemtl evil\n" + "".join(f"f {a + 1} {b + 1} {c + 1}\nf {a + 1} {c + 1} {d + 1}\n" for a, b, c, d in CUBE_QUADS)
    (item,), records, _ = read_all(_write(folder / "mtl.obj", f"mtllib {ref}\n{cube}".encode()))
    assert isinstance(item, RawMesh) and records[0]["status"] == "accepted"  # the geometry is still read


def test_folder_resolver_confines_names(folder):
    from meshsom.errors import InputFileError
    from meshsom.io import FolderResolver

    (folder / "sub").mkdir(exist_ok=True)
    (folder / "sub" / "a.bin").write_bytes(b"abc")
    resolver = FolderResolver(folder, "model.gltf")
    assert resolver["sub/a.bin"] == b"abc" and "sub/a.bin" in resolver
    assert resolver.namespaced("sub").get("a.bin") == b"abc"
    for name in ["../secret.bin", "/etc/passwd", "file:///etc/passwd", "http://x/y", "~/x", "sub/../../secret.bin", "", None]:
        assert name not in resolver
        with pytest.raises(InputFileError, match="model.gltf"):
            resolver.get(name)
    with pytest.raises(InputFileError, match="outside"):
        resolver.namespaced("..")
    with pytest.raises(InputFileError, match="never writes"):
        resolver.write("x.bin", b"")


def test_unreadable_labels_table_is_a_rejection_naming_it(tmp_path):
    block = _blocks(1)[0]
    trimesh.Trimesh(block.vertices, block.faces, process=False).export(str(tmp_path / "a.stl"))
    (tmp_path / "labels.csv").write_bytes(b"file,label\n\xff\xfe broken")
    (item,) = read_file(tmp_path / "a.stl")
    assert isinstance(item, Rejection) and "labels.csv beside it is not a readable CSV" in item.reason


@pytest.mark.parametrize("big", [1e61, 1e160, 1e307])
def test_preprocess_refuses_coordinates_that_would_overflow(big):
    from meshsom.errors import MeshError
    from meshsom.preprocess import preprocess

    v = np.array(CUBE_VERTS, np.float64)
    v[0] = [big, 0, 0]
    f = np.array([[a, b, c] for a, b, c, d in CUBE_QUADS] + [[a, c, d] for a, b, c, d in CUBE_QUADS], np.int64)
    with pytest.raises(MeshError, match="diagonal"):
        preprocess(v, f, source="big")


# ----------------------------------------------------------------------------- 5. nothing unpickled or evaluated

def test_pickle_and_npz_disguised_as_meshes_are_rejected(folder, tmp_path):
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    payloads = {
        "pickle.ply": pickle.dumps(Evil()),
        "pickle.obj": pickle.dumps(Evil()),
        "pickle.glb": pickle.dumps(Evil()),
    }
    buf = __import__("io").BytesIO()
    np.savez(buf, vertices=np.array([Evil()], dtype=object), faces=np.zeros((1, 3), np.int64))
    payloads["npz.ply"] = payloads["npz.off"] = payloads["npz.stl"] = buf.getvalue()
    buf = __import__("io").BytesIO()
    np.save(buf, np.array([Evil()], dtype=object), allow_pickle=True)
    payloads["npy.ply"] = buf.getvalue()
    for name, data in payloads.items():
        (item,), _, events = read_all(_write(folder / name, data))
        assert isinstance(item, Rejection), name
        assert not [e for e, _ in events if e.startswith("pickle.") or e in ("os.system", "subprocess.Popen")]
    assert not marker.exists()


def test_yaml_config_with_python_tag_is_a_config_error(tmp_path):
    from meshsom.config import load_config

    marker = tmp_path / "pwned"
    path = tmp_path / "evil.yaml"
    path.write_text(f"corpus: !!python/object/apply:os.system [\"touch {marker}\"]\n")
    with pytest.raises(ConfigError, match="evil.yaml"):
        load_config(path)
    assert not marker.exists()


def test_cityjson_extreme_integer_coordinates_are_rejected(folder):
    for value in (-(2**63), 2**62, 2**53 + 1):
        verts = [list(v) for v in CUBE_VERTS]
        verts[3] = [value, 0, 0]
        d = doc({"X": {"type": "Building", "geometry": [cube_solid()]}}, verts)
        (item,), _, _ = read_all(_write(folder / "extreme.city.json", json.dumps(d).encode()))
        assert isinstance(item, Rejection) and f"integer vertex coordinate {value} beyond" in item.reason


# ----------------------------------------------------------------------------- 6. preprocessing alone

COORDS = st.sampled_from([0.0, 1.0, -1.0, 0.5, 1e-9, 2.0, 1e6, -1e6, 4e59, 1e61, 3.0])


@st.composite
def soups(draw):
    """Small triangle soups: a few vertices from a handful of values (so coincident, collinear and
    coplanar cases are common), faces over them, sometimes a valid box with faces perturbed."""
    if draw(st.booleans()):
        v = np.array(CUBE_VERTS, np.float64) / 1000
        f = np.array([[a, b, c] for a, b, c, d in CUBE_QUADS] + [[a, c, d] for a, b, c, d in CUBE_QUADS], np.int64)
        for _ in range(draw(st.integers(1, 3))):
            op = draw(st.sampled_from(["move", "flip", "drop", "dup", "reindex"]))
            k = draw(st.integers(0, len(f) - 1))
            if op == "move":
                v[draw(st.integers(0, len(v) - 1))] = [draw(COORDS) for _ in range(3)]
            elif op == "flip":
                f[k] = f[k, ::-1]
            elif op == "drop":
                f = np.delete(f, k, axis=0)
            elif op == "dup":
                f = np.concatenate([f, f[k:k + 1]])
            else:
                f[k, draw(st.integers(0, 2))] = draw(st.integers(0, len(v) - 1))
        return v, f
    n = draw(st.integers(3, 9))
    v = np.array([[draw(COORDS) for _ in range(3)] for _ in range(n)], np.float64)
    f = np.array(draw(st.lists(st.tuples(*[st.integers(0, n - 1)] * 3), min_size=1, max_size=16)), np.int64)
    return v, f


def test_preprocess_gives_a_mesh_or_a_mesh_error():
    from meshsom.errors import MeshError
    from meshsom.preprocess import preprocess

    @settings(FUZZ, max_examples=200)
    @given(soup=soups(), repair=st.booleans())
    def check(soup, repair):
        v, f = soup
        with watched():
            try:
                out = preprocess(v, f, PreprocessParams(repair=repair), source="soup")
            except MeshError as err:
                assert err.problem
                return
        assert np.isfinite(out.vertices).all() and out.faces.shape[1] == 3

    check()


def test_links_out_of_an_input_folder_are_not_followed(tmp_path):
    from meshsom.io import expand_inputs

    outside = tmp_path / "outside.obj"
    outside.write_text("v 0 0 0\n")
    folder = tmp_path / "inputs"
    folder.mkdir()
    (folder / "inside.obj").write_text("v 0 0 0\n")
    (folder / "link.obj").symlink_to(outside)
    (folder / "alias.obj").symlink_to(folder / "inside.obj")
    files, rejected = expand_inputs([folder])
    assert [f.name for f in files] == ["alias.obj", "inside.obj"]
    assert [r.id for r in rejected] == [str(folder / "link.obj")] and "outside the folder" in rejected[0].reason
