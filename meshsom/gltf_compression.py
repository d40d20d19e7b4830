"""Compressed glTF made plain: Draco (``KHR_draco_mesh_compression``) and meshopt
(``EXT_meshopt_compression``, ``KHR_meshopt_compression``) in a binary glTF (GLB).

City models tiled for the web are often compressed: Cesium ion and gltf-pipeline Draco-compress
the glTF of b3dm and glb tiles, gltfpack and gltf-transform meshopt-compress them. trimesh reads
neither, so :func:`decompress_glb` rewrites a GLB into the plain glTF it stands for, and the readers
(:mod:`meshsom.tiles3d`, :func:`meshsom.io.read_trimesh`) read that:

- **Draco**: each compressed primitive is decoded (Google's decoder through DracoPy); its
  positions, its triangles and its feature ids (``_BATCHID``, ``_FEATURE_ID_n``: which building a
  vertex belongs to; the texture coordinates of an ``EXT_mesh_features`` feature-id texture) become
  plain accessors, float32 and uint32; its other attributes (normals, other texture coordinates,
  colours: not used here) are dropped. Positions come back dequantized, as a
  viewer shows them (Draco's usual 11 to 14 bits: millimetres to centimetres over a tile; pg2b3dm's 11 bits
  over a 2.9 km tile: 1.4 m); each primitive's quantum (:func:`position_quantum`) is kept as the vertex
  attribute :data:`QUANTUM_ATTRIBUTE`, so that the primitives of one building can be welded.
- **meshopt**: each compressed buffer view is decoded (meshoptimizer's decoder through meshopt) into
  the plain bytes its fallback buffer stands for, filters (octahedral, quaternion, exponential,
  colour) undone.

- **Quantized positions** (``KHR_mesh_quantization``): positions stored as normalized integers (a
  component ``c`` of ``n`` bits standing for ``c / (2^n - 1)``, signed ``max(c / (2^(n-1) - 1), -1)``,
  the node's transform scaling them back to metres) become float32 accessors of those values; trimesh
  reads the integers as they are (a 10 m house 650,000 m wide). Positions quantized without
  ``normalized`` are read right by trimesh and kept.

The plain data is appended to the GLB's binary chunk, every buffer view then lies in it, and the
extensions are no longer declared. A GLB with no compression comes back as it is. A glTF JSON
file (``.gltf``) is first packed with its buffers into the GLB it stands for (:func:`pack_gltf`);
compressed data in a GLB's external buffer is refused with the reason (decompress it with
``gltf-transform copy``).
"""

from __future__ import annotations

import json
import struct

import numpy as np

from meshsom.errors import InputFileError

DRACO = "KHR_draco_mesh_compression"
MESHOPT = ("EXT_meshopt_compression", "KHR_meshopt_compression")
#: Every compression extension :func:`decompress_glb` undoes.
EXTENSIONS = (DRACO, *MESHOPT)
#: Quantized vertex attributes: its normalized positions are made float (:func:`decompress_glb`); the extension stays
#: declared (its other attributes, and positions quantized without ``normalized``, are left as they are).
QUANTIZATION = "KHR_mesh_quantization"
#: Integer component types of a normalized accessor: (NumPy dtype, the largest value, which stands for 1).
_NORMALIZED = {5120: ("<i1", 127), 5121: ("<u1", 255), 5122: ("<i2", 32767), 5123: ("<u2", 65535)}
#: Vertex attributes of a Draco primitive that are kept: positions and the feature (building) ids.
KEPT_ATTRIBUTES = ("POSITION", "_BATCHID", "_batchid")
KEPT_PREFIXES = ("_FEATURE_ID_",)

#: A vertex attribute :func:`decompress_glb` gives each decoded Draco primitive: its positions' quantum (metres in the
#: primitive's own frame, the same for every vertex; :func:`position_quantum`), so that a reader can weld the primitives
#: of one building, which Draco quantized each on its own grid (:func:`meshsom.tiles3d.batched_meshes`).
QUANTUM_ATTRIBUTE = "_DRACO_QUANTUM"
#: Most quantization bits looked for (Draco allows 1 to 30), and how far (in quanta) every decoded coordinate may lie
#: from its grid for the quantum to be taken as found (float32 rounding of the dequantized values aside).
MAX_QUANTIZATION_BITS = 30
GRID_TOL = 1e-3

def quantum_in_frame(attributes, linear) -> float | None:
    """The grid step of a decoded Draco primitive (its :data:`QUANTUM_ATTRIBUTE` vertex attribute, in the primitive's
    frame) in the frame that ``linear`` (a (3, 3) or (4, 4) matrix) maps it into: times the matrix's largest stretch;
    None for a primitive Draco did not quantize."""
    step = np.asarray(attributes.get(QUANTUM_ATTRIBUTE, ()), np.float64).ravel()
    return float(step[0]) * float(np.linalg.norm(np.asarray(linear)[:3, :3], 2)) if len(step) else None


#: Bytes one meshopt buffer view may decode to (its fallback's size bounds it too).
MAX_DECODED_BYTES = 1 << 32

_JSON, _BIN = 0x4E4F534A, 0x004E4942
_FLOAT, _UINT = 5126, 5125
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
_TRIANGLES = 4


def compression_used(gltf: dict) -> list[str]:
    """The compression extensions a glTF document declares (used or required), sorted."""
    return sorted(_declared(gltf).intersection(EXTENSIONS))


def _declared(gltf: dict) -> set:
    return set(gltf.get("extensionsUsed", []) or []) | set(gltf.get("extensionsRequired", []) or [])


def needs_rewriting(gltf: dict) -> bool:
    """Whether :func:`decompress_glb` changes a glTF document: it declares compression, or quantization with
    normalized positions."""
    declared = _declared(gltf)
    return bool(declared.intersection(EXTENSIONS)) or QUANTIZATION in declared and bool(_normalized_positions(gltf))


def _normalized_positions(gltf: dict) -> list[int]:
    """The normalized integer POSITION accessors of a glTF document's primitives, each once."""
    accessors, found = gltf.get("accessors", []) or [], []
    for mesh in gltf.get("meshes", []) or []:
        for primitive in (mesh.get("primitives", []) if isinstance(mesh, dict) else []) or []:
            k = (primitive.get("attributes") or {}).get("POSITION") if isinstance(primitive, dict) else None
            if isinstance(k, int) and 0 <= k < len(accessors) and k not in found and isinstance(accessors[k], dict) \
                    and accessors[k].get("normalized") and accessors[k].get("componentType") in _NORMALIZED:
                found.append(k)
    return found


def split_glb(glb: bytes, where: str) -> tuple[dict, bytes]:
    """The JSON document and binary chunk (b"" when none) of a GLB.

    Raises
    ------
    InputFileError
        Not a GLB, lengths that do not fit, or JSON that cannot be read.
    """
    if len(glb) < 20 or glb[:4] != b"glTF":
        raise InputFileError(where, "holds no binary glTF (its payload does not start with b'glTF')")
    (version,) = struct.unpack_from("<I", glb, 4)
    if version == 1:
        raise InputFileError(where, "holds glTF 1.0 (a GLB of version 1, KHR_binary_glTF), which is not read: upgrade "
                                    "it to glTF 2.0 (npx 3d-tiles-tools upgrade for a tileset or b3dm, gltf-pipeline "
                                    "for a .glb)")
    size, kind = struct.unpack_from("<II", glb, 12)
    if kind != _JSON or 20 + size > len(glb):
        raise InputFileError(where, f"holds a GLB whose first chunk is not JSON of {size} bytes within its {len(glb)}")
    try:
        gltf = json.loads(glb[20:20 + size])
    except ValueError as err:
        raise InputFileError(where, f"holds a glTF whose JSON cannot be read ({err})") from None
    binary = b""
    at = 20 + size
    if at + 8 <= len(glb):
        length, kind = struct.unpack_from("<II", glb, at)
        if kind == _BIN:
            if at + 8 + length > len(glb):
                raise InputFileError(where, f"holds a GLB binary chunk of {length} bytes, cut short at {len(glb) - at - 8}")
            binary = glb[at + 8:at + 8 + length]
    if not isinstance(gltf, dict):
        raise InputFileError(where, f"holds a glTF whose JSON is a {type(gltf).__name__}, expected an object")
    return gltf, binary


def join_glb(gltf: dict, binary: bytes) -> bytes:
    """A GLB of a JSON document and a binary chunk (each padded to 4 bytes: spaces, zeros)."""
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(text), _JSON) + text
    if binary:
        chunks += struct.pack("<II", len(binary), _BIN) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def pack_gltf(text: bytes, resolver, where: str) -> bytes:
    """A glTF JSON file and the buffers it names, as one GLB (so that its compression can be undone
    and it can be read as 3D Tiles content is).

    Every buffer with data (an external file through ``resolver.get(name)``: :class:`meshsom.io.FolderResolver`,
    or a ``data:`` URI) goes into the binary chunk, on a 4-byte boundary, and the buffer views and
    meshopt sources that pointed into it point there; a meshopt fallback buffer (no data) stays a
    buffer of its own. Materials are left out (only geometry is read), and images, textures and
    samplers too unless feature ids are read from a texture (``EXT_mesh_features``): those images are
    moved into the binary chunk, the others left empty.

    Raises
    ------
    InputFileError
        Not glTF JSON, a buffer without data or shorter than its ``byteLength``, a reference to a
        buffer it does not have, or a file the resolver refuses.
    """
    try:
        gltf = json.loads(bytes(text).decode("utf-8-sig"))
    except (ValueError, UnicodeDecodeError) as err:
        raise InputFileError(where, f"is not glTF JSON ({type(err).__name__}: {err})") from None
    if not isinstance(gltf, dict):
        raise InputFileError(where, f"is JSON of a {type(gltf).__name__}, not a glTF object")
    try:
        return _packed(gltf, resolver, where)
    except InputFileError:
        raise
    except (AttributeError, KeyError, IndexError, TypeError, ValueError) as err:  # JSON of other shapes than the spec's
        raise InputFileError(where, f"holds glTF laid out otherwise than its specification says "
                                    f"({type(err).__name__}: {err})") from None


def _packed(gltf: dict, resolver, where: str) -> bytes:
    """:func:`pack_gltf` of a parsed document."""
    out, moved, kept = _Binary(b""), {}, []  # moved: buffer -> its offset in the chunk; kept: fallbacks
    for k, buffer in enumerate(gltf.get("buffers") or []):
        length = buffer.get("byteLength") if isinstance(buffer, dict) else None
        if not (isinstance(length, int) and not isinstance(length, bool) and length >= 0):
            raise InputFileError(where, f"has buffer {k} without a byteLength")
        uri = buffer.get("uri")
        if uri is None:
            if any((buffer.get("extensions") or {}).get(e, {}).get("fallback") for e in MESHOPT):
                kept.append(k)
                continue
            raise InputFileError(where, f"has buffer {k} without a uri (the binary chunk of a GLB, in a glTF JSON file)")
        if not isinstance(uri, str):
            raise InputFileError(where, f"has buffer {k} whose uri is not text")
        data = _uri_bytes(uri, resolver, where, f"buffer {k}")
        if len(data) < length:
            raise InputFileError(where, f"has buffer {k} ({uri[:60]}) of {len(data)} bytes, fewer than its byteLength {length}")
        moved[k] = out.append(bytes(data[:length]))
    renumbered = {k: 1 + j for j, k in enumerate(kept)}

    def point(obj: dict, what: str) -> None:
        b = obj.get("buffer", 0)
        if b in moved:
            obj["buffer"], obj["byteOffset"] = 0, int(obj.get("byteOffset", 0)) + moved[b]
        elif b in renumbered:
            obj["buffer"] = renumbered[b]
        else:
            raise InputFileError(where, f"has {what} in buffer {b!r}, which it does not have")

    for k, view in enumerate(gltf.get("bufferViews") or []):
        point(view, f"buffer view {k}")
        for name in MESHOPT:
            if name in (view.get("extensions") or {}):
                point(view["extensions"][name], f"the meshopt data of buffer view {k}")
    images = _feature_images(gltf)
    for k, image in enumerate(gltf.get("images") or []):  # those of feature ids, moved into the chunk
        if k not in images:
            gltf["images"][k] = {}
        elif isinstance(image, dict) and isinstance(image.get("uri"), str):
            data = _uri_bytes(image["uri"], resolver, where, f"image {k}")
            gltf.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": out.append(data), "byteLength": len(data)})
            gltf["images"][k] = {"bufferView": len(gltf["bufferViews"]) - 1,
                                 "mimeType": image.get("mimeType", "image/png")}
    buffers = gltf.get("buffers") or []
    gltf["buffers"] = ([{"byteLength": len(out.data)}] if out.data else [{"byteLength": 0}]) + [buffers[k] for k in kept]
    for key in ("materials",) if images else ("images", "textures", "samplers", "materials"):
        gltf.pop(key, None)
    for mesh in gltf.get("meshes") or []:
        for primitive in mesh.get("primitives") or []:
            if isinstance(primitive, dict):
                primitive.pop("material", None)
    return join_glb(gltf, bytes(out.data))


def _feature_images(gltf: dict) -> set:
    """The images of a glTF document's feature-id textures (``EXT_mesh_features``: which building a texel belongs to)."""
    textures, found = gltf.get("textures") if isinstance(gltf.get("textures"), list) else [], set()
    for mesh in gltf.get("meshes") if isinstance(gltf.get("meshes"), list) else []:
        for primitive in (mesh.get("primitives") or []) if isinstance(mesh, dict) else []:
            ext = ((primitive.get("extensions") or {}) if isinstance(primitive, dict) else {}).get("EXT_mesh_features")
            for spec in (ext.get("featureIds") or []) if isinstance(ext, dict) else []:
                index = (spec.get("texture") or {}).get("index") if isinstance(spec, dict) else None
                if isinstance(index, int) and 0 <= index < len(textures) and isinstance(textures[index], dict) \
                        and isinstance(textures[index].get("source"), int):
                    found.add(textures[index]["source"])
    return found


def _uri_bytes(uri: str, resolver, where: str, what: str) -> bytes:
    """The bytes a glTF buffer or image ``uri`` names: a base64 ``data:`` URI, or a file beside the glTF
    (``resolver.get``)."""
    import base64
    from urllib.parse import unquote

    if uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        if not head.endswith(";base64"):
            raise InputFileError(where, f"has {what} as a data URI that is not base64 ({head[:40]})")
        try:
            return base64.b64decode(payload)
        except ValueError as err:
            raise InputFileError(where, f"has {what} as base64 that cannot be decoded ({err})") from None
    return resolver.get(unquote(uri))


class _Binary:
    """The GLB's binary chunk, growing: appended data starts on a 4-byte boundary."""

    def __init__(self, data: bytes):
        self.data = bytearray(data)

    def append(self, data: bytes) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        at = len(self.data)
        self.data += data
        return at


def _buffer_bytes(gltf: dict, binary: bytes, index, where: str, what: str) -> bytes:
    buffers = gltf.get("buffers", [])
    if not isinstance(index, int) or not 0 <= index < len(buffers):
        raise InputFileError(where, f"holds {what} in buffer {index!r}, which is not among its {len(buffers)} buffers")
    if index != 0 or buffers[0].get("uri") is not None:
        raise InputFileError(where, f"holds {what} in an external buffer ({buffers[index].get('uri', 'buffer %d' % index)!r}): "
                                    "only compressed data in the GLB's own binary chunk is read (gltf-transform copy "
                                    "decompresses it)")
    return binary


def _slice(data: bytes, offset, length, where: str, what: str) -> bytes:
    if not (isinstance(offset, int) and isinstance(length, int) and 0 <= offset and 0 <= length
            and offset + length <= len(data)):
        raise InputFileError(where, f"holds {what} at bytes {offset!r}..+{length!r}, beyond its {len(data)}-byte buffer")
    return data[offset:offset + length]


def _meshopt(gltf: dict, binary: bytes, out: _Binary, where: str) -> None:
    """Every meshopt-compressed buffer view decoded into ``out``, pointing there."""
    views = [v for v in gltf.get("bufferViews", []) if any(e in (v.get("extensions") or {}) for e in MESHOPT)]
    if not views:
        return
    try:
        import meshopt
    except ImportError as err:  # pragma: no cover - a dependency
        raise InputFileError(where, f"holds meshopt-compressed glTF and meshopt is not importable ({err})") from None
    for k, view in enumerate(views):
        name = next(e for e in MESHOPT if e in view["extensions"])
        ext = view["extensions"][name]
        what = f"meshopt data (buffer view {k})"
        source = _slice(_buffer_bytes(gltf, binary, ext.get("buffer"), where, what), ext.get("byteOffset", 0),
                        ext.get("byteLength"), where, what)
        count, stride, mode = ext.get("count"), ext.get("byteStride"), ext.get("mode")
        if not (isinstance(count, int) and isinstance(stride, int) and count >= 0 and 0 < stride <= 256):
            raise InputFileError(where, f"holds {what} of count {count!r} and byte stride {stride!r}")
        if count * stride > min(view.get("byteLength", 0), MAX_DECODED_BYTES):  # a decompression bomb is refused
            raise InputFileError(where, f"holds {what} of {count} x {stride} bytes, more than its buffer view's "
                                        f"{view.get('byteLength')} (at most {MAX_DECODED_BYTES:,})")
        try:
            plain = meshopt.decode_gltf_buffer(source, count, stride, mode, ext.get("filter", "NONE"))
        except Exception as err:  # the decoder reports malformed data with ValueError (and others)
            raise InputFileError(where, f"holds {what} that cannot be decoded ({type(err).__name__}: {err})") from None
        plain = np.ascontiguousarray(plain).tobytes()
        if len(plain) != count * stride:
            raise InputFileError(where, f"holds {what} decoded to {len(plain)} bytes, expected {count} x {stride}")
        view["byteOffset"] = out.append(plain)
        view["byteLength"] = len(plain)
        view["buffer"] = 0
        del view["extensions"][name]
        if not view["extensions"]:
            del view["extensions"]


def _dequantized(gltf: dict, binary: bytes, out: _Binary, where: str) -> None:
    """Every normalized integer POSITION accessor (:data:`QUANTIZATION`) made a float32 one in ``out`` of the values
    it stands for."""
    accessors, views = gltf.get("accessors", []), gltf.get("bufferViews", [])
    for k in _normalized_positions(gltf):
        accessor = accessors[k]
        what = f"quantized positions (accessor {k})"
        dtype, top = _NORMALIZED[accessor["componentType"]]
        count, size = accessor.get("count"), np.dtype(dtype).itemsize
        if not isinstance(count, int) or count < 0 or accessor.get("type") != "VEC3" or "sparse" in accessor:
            raise InputFileError(where, f"holds {what} of count {count!r}, type {accessor.get('type')!r}"
                                        f"{' and sparse values' if 'sparse' in accessor else ''}: expected dense VEC3")
        view = views[accessor["bufferView"]]
        stride = view.get("byteStride") or 3 * size
        data = _buffer_bytes(gltf, binary, view.get("buffer", 0), where, what)
        start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
        raw = _slice(data, start, (count - 1) * stride + 3 * size if count else 0, where, what)
        values = np.ndarray((count, 3), dtype, raw, 0, (stride, size)) if count else np.zeros((0, 3), dtype)
        plain = np.maximum(values.astype(np.float64) / top, -1.0).astype("<f4")  # signed: -2^(n-1) is -1 too
        views.append({"buffer": 0, "byteOffset": out.append(plain.tobytes()), "byteLength": plain.nbytes})
        accessor.update(bufferView=len(views) - 1, byteOffset=0, componentType=_FLOAT, normalized=False)
        if count:
            accessor.update(min=plain.min(axis=0).tolist(), max=plain.max(axis=0).tolist())


def position_quantum(points: np.ndarray) -> float | None:
    """The quantum of Draco-dequantized positions: Draco quantizes a primitive's positions to ``bits`` bits over one
    range for all three axes (the bounding box's largest extent ``R``) from its minimum corner, so the decoded values
    lie on a grid of step ``R / (2^bits - 1)`` from the decoded minimum, and one axis spans the whole range. The bits
    are found as the fewest for which every coordinate lies within :data:`GRID_TOL` quanta (and float32 rounding) of
    that grid; None where none does (positions not quantized, or fewer than two distinct values).

    Parameters
    ----------
    points : (V, 3) float32 or float64

    Returns
    -------
    float or None
    """
    points = np.asarray(points, np.float64)
    if len(points) < 2 or not np.isfinite(points).all():
        return None
    low = points.min(axis=0)
    extent = float((points.max(axis=0) - low).max())
    if extent <= 0:
        return None
    gaps = np.concatenate([np.diff(np.unique(points[:, k])) for k in range(3)])
    smallest = float(gaps[gaps > 0].min())
    rounding = 4 * float(np.spacing(np.float32(np.abs(points).max())))  # float32 values of the dequantized ones
    steps = (points - low)
    for bits in range(max(1, int(np.floor(np.log2(extent / smallest + 1)))), MAX_QUANTIZATION_BITS + 1):
        quantum = extent / (2 ** bits - 1)
        if quantum < 4 * rounding:  # a grid finer than float32 tells nothing
            return None
        if np.abs(steps / quantum - np.rint(steps / quantum)).max() * quantum <= GRID_TOL * quantum + rounding:
            return quantum
    return None


def _kept(semantic: str) -> bool:
    return semantic in KEPT_ATTRIBUTES or semantic.startswith(KEPT_PREFIXES)


def _draco(gltf: dict, binary: bytes, out: _Binary, where: str) -> None:
    """Every Draco-compressed primitive decoded: plain accessors in ``out`` for its positions, feature ids
    and triangles."""
    primitives = [p for mesh in gltf.get("meshes", []) for p in mesh.get("primitives", [])
                  if DRACO in (p.get("extensions") or {})]
    if not primitives:
        return
    try:
        import DracoPy
    except ImportError as err:  # pragma: no cover - a dependency
        raise InputFileError(where, f"holds Draco-compressed glTF and DracoPy is not importable ({err})") from None
    views, accessors = gltf.setdefault("bufferViews", []), gltf.setdefault("accessors", [])

    def add(array: np.ndarray, component: int, target: int | None) -> int:
        data = np.ascontiguousarray(array)
        view = {"buffer": 0, "byteOffset": out.append(data.tobytes()), "byteLength": data.nbytes}
        if target:
            view["target"] = target
        views.append(view)
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": len(data),
                    "type": _TYPES[data.shape[1] if data.ndim == 2 else 1]}
        if component == _FLOAT and data.ndim == 2:
            accessor["min"], accessor["max"] = data.min(axis=0).tolist(), data.max(axis=0).tolist()
        accessors.append(accessor)
        return len(accessors) - 1

    for k, primitive in enumerate(primitives):
        ext = primitive["extensions"][DRACO]
        what = f"Draco data (primitive {k})"
        view = views[ext["bufferView"]] if isinstance(ext.get("bufferView"), int) and 0 <= ext["bufferView"] < len(views) else None
        if view is None:
            raise InputFileError(where, f"holds {what} in buffer view {ext.get('bufferView')!r}, which it does not have")
        data = _slice(_buffer_bytes(gltf, binary, view.get("buffer"), where, what), view.get("byteOffset", 0),
                      view.get("byteLength"), where, what)
        if primitive.get("mode", _TRIANGLES) != _TRIANGLES:
            raise InputFileError(where, f"holds {what} of mode {primitive.get('mode')}, expected triangles (4)")
        try:
            mesh = DracoPy.decode(bytes(data))
        except Exception as err:  # DracoPy raises its own errors and ValueError for corrupt data
            raise InputFileError(where, f"holds {what} that cannot be decoded ({type(err).__name__}: {err})") from None
        faces = getattr(mesh, "faces", None)  # a Draco point cloud has none
        faces = None if faces is None else np.asarray(faces)
        if faces is None or faces.ndim != 2 or faces.shape[1] != 3:
            raise InputFileError(where, f"holds {what} that decodes to points, not triangles")
        by_id = {a["unique_id"]: a for a in mesh.attributes}
        attributes = {}
        features = (primitive.get("extensions") or {}).get("EXT_mesh_features") or {}
        read_at = {f"TEXCOORD_{s['texture'].get('texCoord', 0)}" for s in features.get("featureIds") or []
                   if isinstance(s, dict) and isinstance(s.get("texture"), dict)}  # of feature-id textures
        for semantic, uid in (ext.get("attributes") or {}).items():
            if not _kept(semantic) and semantic not in read_at:
                continue
            if uid not in by_id:
                raise InputFileError(where, f"holds {what} whose {semantic} (Draco attribute {uid!r}) is not in it")
            values = np.asarray(by_id[uid]["data"], np.float32).reshape(-1, by_id[uid]["num_components"])
            attributes[semantic] = add(values if values.shape[1] > 1 else values[:, 0], _FLOAT, 34962)
        if "POSITION" not in attributes:
            raise InputFileError(where, f"holds {what} without positions")
        count = accessors[attributes["POSITION"]]["count"]
        quantum = position_quantum(np.asarray(mesh.points).reshape(count, 3))
        if quantum is not None:
            attributes[QUANTUM_ATTRIBUTE] = add(np.full(count, quantum, np.float32), _FLOAT, 34962)
        if faces.size and (faces.min() < 0 or faces.max() >= count):
            raise InputFileError(where, f"holds {what} whose triangles index beyond its {count} vertices")
        primitive["attributes"] = attributes
        primitive["indices"] = add(faces.astype(np.uint32).ravel(), _UINT, 34963)
        del primitive["extensions"][DRACO]
        if not primitive["extensions"]:
            del primitive["extensions"]


def decompress_glb(glb: bytes, where: str) -> bytes:
    """A GLB with its Draco and meshopt compression undone (see the module); the same bytes when it has none.

    Parameters
    ----------
    glb : bytes
    where : str
        The file (and part of it) for messages.

    Raises
    ------
    InputFileError
        Compressed data that is corrupt, out of its buffer, in an external buffer, or not triangles.
    """
    gltf, binary = split_glb(glb, where)
    if not needs_rewriting(gltf):
        return glb
    out = _Binary(binary)
    try:
        _meshopt(gltf, binary, out, where)
        _draco(gltf, binary, out, where)
        _dequantized(gltf, bytes(out.data), out, where)
    except InputFileError:
        raise
    except (AttributeError, KeyError, IndexError, TypeError, ValueError) as err:  # JSON of other shapes than the spec's
        raise InputFileError(where, f"holds compressed glTF laid out otherwise than its specification says "
                                    f"({type(err).__name__}: {err})") from None
    for view in gltf.get("bufferViews", []):
        if view.get("buffer", 0) != 0:  # a meshopt fallback buffer holds no data: nothing may point there
            raise InputFileError(where, f"holds a buffer view in buffer {view.get('buffer')!r}, which is external "
                                        "or a fallback without data")
    buffers = gltf.get("buffers", [])
    if buffers and buffers[0].get("uri") is not None:
        raise InputFileError(where, "holds compressed glTF whose first buffer is external; only GLB binary chunks are read")
    gltf["buffers"] = [{"byteLength": len(out.data)}]
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in gltf:
            gltf[key] = [e for e in gltf[key] if e not in EXTENSIONS]
            if not gltf[key]:
                del gltf[key]
    return join_glb(gltf, bytes(out.data))
