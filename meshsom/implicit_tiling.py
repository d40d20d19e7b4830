"""3D Tiles 1.1 implicit tiling: the tiles a quadtree or octree's subtree files say exist, and the
content each holds.

A tileset made by pg2b3dm, py3dtiles or Cesium's tilers may not list its tiles: a tile with
``implicitTiling`` names them by templates (``content/{level}/{x}/{y}.glb``) and says which exist
in *subtree* files (``subtrees/{level}.{x}.{y}.subtree``), each covering ``subtreeLevels`` levels
with bitstreams of tile, content and child-subtree availability. :func:`implicit_contents` walks the
subtrees from the root and yields every available content with its tile and whether the tile is at
the finest level (no available child), which the tileset reader needs for ``REPLACE`` refinement.

Subtree files: binary (magic ``subt``, version 1, JSON and binary chunk) or JSON; bitstreams in
the internal binary chunk or in buffer files beside the subtree (within the tileset's folder);
availability as a bitstream or a constant. Bit order as the specification fixes it: tiles level by
level from the subtree's root, each level in Morton order (x in the lowest bit, then y, then z),
bit i of a bitstream in byte i // 8 at bit i % 8.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from meshsom.errors import InputFileError

#: Available tiles an implicit tileset may hold before it is refused (a memory guard: every available
#: tile is kept while the subtrees are walked).
MAX_IMPLICIT_TILES = 2_000_000
#: Tiles a subtree may cover (its availability bitstreams' bits): 12 quadtree levels, 8 octree levels.
MAX_SUBTREE_TILES = 1 << 24
#: Levels an implicit tileset may declare (``availableLevels``): 2^30 tiles along an axis.
MAX_LEVELS = 31
_SCHEMES = {"QUADTREE": 2, "OCTREE": 3}


@dataclass(frozen=True)
class ImplicitContent:
    """One available content of an implicit tileset."""

    uri: str  # the content template filled in, relative to the tileset's folder
    level: int
    coordinates: tuple[int, ...]  # (x, y) or (x, y, z)
    leaf: bool  # no child tile is available: the finest level where it stands


def _template(template: str, level: int, coordinates: tuple[int, ...]) -> str:
    values = {"level": level, "x": coordinates[0], "y": coordinates[1]}
    if len(coordinates) == 3:
        values["z"] = coordinates[2]
    return re.sub(r"\{(level|x|y|z)\}", lambda m: str(values.get(m.group(1), m.group(0))), template)


def morton_decode(index: np.ndarray, dims: int) -> np.ndarray:
    """(n, dims) coordinates of Morton indices (x in bit 0, y in bit 1, z in bit 2 of each group)."""
    index = np.asarray(index, np.int64)
    out = np.zeros((len(index), dims), np.int64)
    for bit in range(64 // dims):
        for d in range(dims):
            out[:, d] |= ((index >> (bit * dims + d)) & 1) << bit
    return out


def morton_encode(coordinates: np.ndarray, dims: int) -> np.ndarray:
    """Morton indices of (n, dims) coordinates (:func:`morton_decode`'s inverse)."""
    c = np.asarray(coordinates, np.int64)
    out = np.zeros(len(c), np.int64)
    for bit in range(64 // dims):
        for d in range(dims):
            out |= ((c[:, d] >> bit) & 1) << (bit * dims + d)
    return out


def _bits(availability, views: list[bytes], count: int, where: str, what: str) -> np.ndarray:
    """An availability as ``count`` booleans: a constant, or a bitstream of a buffer view."""
    if not isinstance(availability, dict):
        raise InputFileError(where, f"has {what} that is not an object: {str(availability)[:60]}")
    if "constant" in availability:
        if availability["constant"] not in (0, 1):
            raise InputFileError(where, f"has {what} of constant {availability['constant']!r}, expected 0 or 1")
        return np.full(count, bool(availability["constant"]))
    view = availability.get("bitstream", availability.get("bufferView"))
    if not isinstance(view, int) or not 0 <= view < len(views):
        raise InputFileError(where, f"has {what} in buffer view {view!r}, not among its {len(views)}")
    data = np.frombuffer(views[view], np.uint8)
    if len(data) * 8 < count:
        raise InputFileError(where, f"has {what} of {len(data) * 8} bits, expected {count}")
    return np.unpackbits(data, bitorder="little")[:count].astype(bool)


def read_subtree(data: bytes, where: str, buffer_file: Callable[[str], bytes]) -> tuple[dict, list[bytes]]:
    """A subtree file's JSON and the bytes of its buffer views.

    Parameters
    ----------
    data : bytes
        The file: binary (``subt``) or JSON.
    where : str
    buffer_file : callable
        The bytes of a buffer's ``uri`` (relative to the subtree file).
    """
    binary = b""
    if data[:4] == b"subt":
        if len(data) < 24:
            raise InputFileError(where, f"is a subtree file of {len(data)} bytes, shorter than its 24-byte header")
        version, json_length, binary_length = struct.unpack_from("<IQQ", data, 4)
        if version != 1 or 24 + json_length + binary_length > len(data):
            raise InputFileError(where, f"is a subtree file of version {version} whose chunks ({json_length} + "
                                        f"{binary_length} bytes) do not fit its {len(data) - 24}")
        text, binary = data[24:24 + json_length], data[24 + json_length:24 + json_length + binary_length]
    else:
        text = data
    try:
        subtree = json.loads(text)
    except ValueError as err:
        raise InputFileError(where, f"is a subtree whose JSON cannot be read ({err})") from None
    if not isinstance(subtree, dict):
        raise InputFileError(where, f"is a subtree whose JSON is a {type(subtree).__name__}, expected an object")
    buffers = []
    for buffer in subtree.get("buffers", []) or []:
        uri = buffer.get("uri") if isinstance(buffer, dict) else None
        buffers.append(binary if uri is None else buffer_file(uri))
    views = []
    for k, view in enumerate(subtree.get("bufferViews", []) or []):
        try:
            source = buffers[view["buffer"]]
            start, length = int(view.get("byteOffset", 0)), int(view["byteLength"])
        except (KeyError, IndexError, TypeError, ValueError):
            raise InputFileError(where, f"has buffer view {k} that names no buffer or length: {str(view)[:80]}") from None
        if start < 0 or length < 0 or start + length > len(source):
            raise InputFileError(where, f"has buffer view {k} at bytes {start}..+{length}, beyond its {len(source)}-byte buffer")
        views.append(source[start:start + length])
    return subtree, views


def implicit_contents(tile: dict, folder: Path, where: str, read: Callable[[Path], bytes],
                      content_templates: list[str]) -> Iterator[ImplicitContent]:
    """Every available content of an implicit tile's tree (as the module says).

    Parameters
    ----------
    tile : dict
        The tile holding ``implicitTiling``.
    folder : Path
        The folder its templates are relative to (the tileset's).
    where : str
        The tileset, for messages.
    read : callable
        The bytes of a file (subtrees, buffers): :func:`meshsom.io.read_input_bytes` with the reader's
        limits; it raises InputFileError or OSError.
    content_templates : list of str
        The tile's content URI templates (``content``, or each of ``contents``).

    Raises
    ------
    InputFileError
        A malformed ``implicitTiling``, a subtree that cannot be read or is inconsistent, or more
        than :data:`MAX_IMPLICIT_TILES` tiles.
    """
    spec = tile["implicitTiling"]
    dims = _SCHEMES.get(str(spec.get("subdivisionScheme", "")).upper())
    levels, available = spec.get("subtreeLevels"), spec.get("availableLevels", spec.get("maximumLevel"))
    template = (spec.get("subtrees") or {}).get("uri") if isinstance(spec.get("subtrees"), dict) else None
    if dims is None:
        raise InputFileError(where, f"has implicit tiling of scheme {spec.get('subdivisionScheme')!r}, expected QUADTREE or OCTREE")
    if "availableLevels" not in spec and isinstance(available, int):
        available += 1  # the 3DTILES_implicit_tiling extension's maximumLevel: the last level, not a count
    if not (isinstance(levels, int) and isinstance(available, int) and 0 < levels and 0 < available <= MAX_LEVELS):
        raise InputFileError(where, f"has implicit tiling of subtreeLevels {levels!r} and availableLevels {available!r}, "
                                    f"expected whole numbers from 1 (at most {MAX_LEVELS} levels)")
    if not isinstance(template, str):
        raise InputFileError(where, "has implicit tiling without a subtrees URI template")
    children = 2 ** dims
    if (children ** levels - 1) // (children - 1) > MAX_SUBTREE_TILES:
        raise InputFileError(where, f"has implicit subtrees of {levels} levels ({children ** levels:,} tiles in the "
                                    f"last), more than {MAX_SUBTREE_TILES:,} tiles per subtree (MAX_SUBTREE_TILES)")
    offsets = [(children ** level - 1) // (children - 1) for level in range(levels + 1)]
    tiles: dict[int, list[np.ndarray]] = {}  # level -> coordinates of its available tiles
    contents: list[tuple[int, np.ndarray, int]] = []  # (level, coordinates, content index)
    queue = [(0, np.zeros(dims, np.int64))]
    total = 0
    while queue:
        root_level, root = queue.pop()
        uri = _template(template, root_level, tuple(int(c) for c in root))
        path = folder / uri
        subtree_where = f"{where}: subtree {uri}"
        try:
            data = bytes(read(path))
            subtree, views = read_subtree(data, subtree_where, lambda name: bytes(read(path.parent / name)))
        except OSError as err:
            raise InputFileError(where, f"names subtree {uri}, which cannot be read ({err})") from None
        deep = min(levels, available - root_level)  # levels of this subtree within availableLevels
        bits = _bits(subtree.get("tileAvailability"), views, offsets[deep], subtree_where, "tile availability")
        held = subtree.get("contentAvailability", [])
        if isinstance(held, dict):  # the extension's draft: one object
            held = [held]
        content_bits = [_bits(a, views, offsets[deep], subtree_where, f"content availability {k}") for k, a in enumerate(held)]
        for level in range(deep):
            local = np.nonzero(bits[offsets[level]:offsets[level + 1]])[0]
            total += len(local)
            if total > MAX_IMPLICIT_TILES:
                raise InputFileError(where, f"has more than {MAX_IMPLICIT_TILES:,} available tiles (MAX_IMPLICIT_TILES)")
            coords = (root << level) + morton_decode(local, dims)
            tiles.setdefault(root_level + level, []).append(coords)
            for k, cb in enumerate(content_bits[:len(content_templates)]):
                with_content = cb[offsets[level]:offsets[level + 1]][local]
                contents.extend((root_level + level, c, k) for c in coords[with_content])
        if root_level + levels < available:
            child = _bits(subtree.get("childSubtreeAvailability", {"constant": 0}), views, children ** levels,
                          subtree_where, "child subtree availability")
            for index in np.nonzero(child)[0][::-1]:
                queue.append((root_level + levels, (root << levels) + morton_decode(np.array([index]), dims)[0]))
    # a tile is a leaf when none of the tiles one level down is its child
    parents = {level: {tuple(c) for c in np.concatenate(found) >> 1} for level, found in tiles.items()}
    for level, coords, k in sorted(contents, key=lambda c: (c[0], tuple(c[1]), c[2])):
        key = tuple(int(c) for c in coords)
        yield ImplicitContent(_template(content_templates[k], level, key), level, key,
                              key not in parents.get(level + 1, set()))
