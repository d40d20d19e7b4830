"""Reading 3D Studio files (``.3ds``): city models offered for 3D Studio and its heirs (Berlin's LoD 2 model is one
of its download formats; many building models of the web are 3DS).

A 3DS file is a tree of chunks, each ``(id: uint16, length: uint32)`` then its content (:data:`CHUNKS`): the main
chunk holds the editor chunk, which holds an object chunk per object (its name, zero-terminated, then its
sub-chunks). An object's triangle mesh is its vertices (float32 triples, world coordinates) and its faces (three
uint16 indices and a flags word each); its local frame (``TRI_LOCAL``) is the object's pivot, already applied to
the vertices, so it is not applied again (as lib3ds and 3ds Max read it). Lights and cameras are not meshes.

- **Objects**: each object with a triangle mesh is one building, id ``<file>#<object name>`` (a name met again:
  ``<name> (2)``, ...).
- **Units**: 3DS names none; coordinates are read as metres (``corpus.reader.crs`` names their CRS where they are
  in one). Axes: z up, as 3D Studio draws.
- **Labels**: ``labels.csv`` beside the file, as for OBJ.
- A chunk that claims more than its parent holds (a truncated or damaged file) stops the reading with a rejection
  naming its offset; an object whose faces name vertices it has not is rejected alone.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Iterator

import numpy as np

from meshsom.errors import InputFileError

#: The chunks read (the others are passed over).
CHUNKS = {"MAIN": 0x4D4D, "EDIT": 0x3D3D, "OBJECT": 0x4000, "TRIMESH": 0x4100, "VERTICES": 0x4110,
          "FACES": 0x4120}
#: A chunk's header: id and length (the header included).
HEADER = struct.Struct("<HI")


def _chunks(data: bytes, start: int, stop: int, where: str) -> Iterator[tuple[int, int, int]]:
    """``(id, content start, end)`` of the chunks between ``start`` and ``stop``."""
    at = start
    while at + HEADER.size <= stop:
        cid, length = HEADER.unpack_from(data, at)
        if length < HEADER.size or at + length > stop:
            raise InputFileError(where, f"chunk 0x{cid:04X} at byte {at} claims {length} bytes, more than the "
                                        f"{stop - at} its parent holds there (a truncated or damaged 3DS file)")
        yield cid, at + HEADER.size, at + length
        at += length


def _objects(data: bytes, where: str) -> Iterator[tuple[str, np.ndarray | None, np.ndarray | None]]:
    """``(name, vertices (V, 3) float64 or None, faces (F, 3) int64 or None)`` of each object with a triangle mesh."""
    first = HEADER.unpack_from(data, 0)[0] if len(data) >= HEADER.size else None
    if first != CHUNKS["MAIN"]:
        said = "is too short" if first is None else f"starts with chunk 0x{first:04X}"
        raise InputFileError(where, f"is not a 3DS file: it {said}, expected the main chunk 0x4D4D")
    main = next(_chunks(data, 0, len(data), where))
    for cid, a, b in _chunks(data, main[1], main[2], where):
        if cid != CHUNKS["EDIT"]:
            continue
        for oid, oa, ob in _chunks(data, a, b, where):
            if oid != CHUNKS["OBJECT"]:
                continue
            end = data.find(b"\x00", oa, ob)
            if end < 0:
                raise InputFileError(where, f"the object at byte {oa - HEADER.size} has no name")
            name = data[oa:end].decode("latin-1")
            for tid, ta, tb in _chunks(data, end + 1, ob, where):
                if tid != CHUNKS["TRIMESH"]:
                    continue  # a light, a camera
                vertices = faces = None
                for mid, ma, mb in _chunks(data, ta, tb, where):
                    if mid == CHUNKS["VERTICES"] and ma + 2 <= mb:
                        (n,) = struct.unpack_from("<H", data, ma)
                        if ma + 2 + 12 * n > mb:
                            raise InputFileError(where, f"object {name!r}: {n} vertices do not fit in their chunk")
                        vertices = np.frombuffer(data, "<f4", 3 * n, ma + 2).reshape(n, 3).astype(np.float64)
                    elif mid == CHUNKS["FACES"] and ma + 2 <= mb:
                        (n,) = struct.unpack_from("<H", data, ma)
                        if ma + 2 + 8 * n > mb:
                            raise InputFileError(where, f"object {name!r}: {n} faces do not fit in their chunk")
                        faces = np.frombuffer(data, "<u2", 4 * n, ma + 2).reshape(n, 4)[:, :3].astype(np.int64)
                yield name, vertices, faces


def read_3ds(path: Path, options, name: str | None = None) -> Iterator:
    """The buildings of a 3DS file: a RawMesh per object with a triangle mesh (or a Rejection), as the module says.

    Raises
    ------
    InputFileError
        The file is larger than ``options.max_bytes``, is not 3DS, is damaged before its first object, or holds no
        triangle mesh.
    """
    from meshsom.io import (
        Rejection, _connected_pieces, _labels_beside, file_crs, free_id, placed_mesh, read_input_bytes,
    )

    data = bytes(read_input_bytes(path, options))
    labels = _labels_beside(path)
    label = labels.get(path.name)
    name = name or path.name
    crs = file_crs(None, options)
    taken: set[str] = set()
    found = 0
    for object_name, vertices, faces in _objects(data, str(path)):  # damage: the objects before it, then the error
        found += 1
        key = object_name or f"object-{found}"
        key = free_id(key, taken) if key in taken else key  # a name met again: "<name> (2)"
        taken.add(key)
        mesh_id = f"{name}#{key}"
        item_label = labels.get(f"{path.name}#{key}", label)
        if vertices is None or faces is None or not len(faces):
            yield Rejection(mesh_id, str(path), "holds no faces", 0, item_label)
            continue
        if faces.max() >= len(vertices):
            yield Rejection(mesh_id, str(path), f"a face refers to vertex {int(faces.max())}, but the object has "
                                                f"{len(vertices)} vertices", 0, item_label)
            continue
        pieces = _connected_pieces(mesh_id, vertices, faces, item_label) if options.split_components else [
            (mesh_id, vertices, faces, item_label)]
        for piece_id, v, f, piece_label in pieces:
            yield placed_mesh(piece_id, str(path), v, f, piece_label, crs)
    if not found:
        raise InputFileError(str(path), "holds no object with a triangle mesh")
