"""Versions of one building in a mesh file: the LoDs a multi-LoD export writes under one name.

``cjio export obj`` writes every geometry of a CityJSON object (3D BAG: LoD 1.2, 1.3 and 2.2, in
the object's ``geometry`` order) as its own ``o`` block, every block named by the object's id;
``cjio export glb`` writes them one after the other into the one primitive of a mesh named by the
id (under an unnamed node). Joined, as the objects (or primitives) of one name of other files are,
they are the union of the LoDs, a volume that is no LoD's (3D BAG's 6751773: 566.3 m3, where its
LoD 2.2 holds 418.6 m3).

The test that tells such versions from a building's parts written under one name (its roof and
its walls, each open; a house and its detached garage): each piece closes on its own (every edge,
by position, is used an even number of times) and each piece's bounding box overlaps the most
detailed piece's by at least :data:`LOD_VERSION_MIN_OVERLAP` of their union. Versions of one
building share its footprint and differ in their roofs; parts fail one test or the other.
"""
from __future__ import annotations

import re

import numpy as np

#: Same-named closed pieces are versions of one building (LoDs) when the bounding box of each
#: overlaps the most detailed piece's by at least this share of the two boxes' union
#: (intersection over union, by volume). 3D BAG's LoD 1.2 and 2.2 of one building overlap by 0.7 to
#: 1.0 (the block's flat top at the roof's 70th height percentile, under or over the ridge); a
#: chimney, a dormer or an annex written as a closed object of its building's name by less than 0.2.
LOD_VERSION_MIN_OVERLAP = 0.5

#: An odd 64-bit multiplier (the golden ratio's, as in Fibonacci hashing) spreading edge keys over
#: 64 bits, so that the exclusive-or of a run's edges is 0 only when every edge is used an even
#: number of times (but with a chance of 2**-64 a run).
_EDGE_HASH = np.uint64(0x9E3779B97F4A7C15)

_OBJ_OBJECT_OR_FACE = re.compile(rb"^[ \t]*(o|f)[ \t]+(.*?)[ \t]*\r?$", re.M)


def _edge_hashes(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The hash of every face's three edges, joined by position.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int

    Returns
    -------
    (F, 3) uint64
        Equal for the same undirected edge (by vertex position), whichever faces hold it.
    """
    _, at = np.unique(np.asarray(vertices, np.float64), axis=0, return_inverse=True)
    f = at.reshape(-1)[np.asarray(faces, np.int64)].astype(np.uint64)
    a, b = f, np.roll(f, -1, axis=1)
    key = np.minimum(a, b) * np.uint64(len(at) + 1) + np.maximum(a, b) + np.uint64(1)
    with np.errstate(over="ignore"):
        h = key * _EDGE_HASH
        h ^= h >> np.uint64(29)
        h *= _EDGE_HASH
    return h


def is_closed(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Whether a triangle mesh (``vertices (V, 3)``, ``faces (F, 3)``) is closed: every edge, by
    position, used an even number of times (twice by a closed shell)."""
    if len(faces) == 0:
        return False
    return not np.bitwise_xor.reduce(_edge_hashes(vertices, faces), axis=None)


def closed_runs(vertices: np.ndarray, faces: np.ndarray) -> list[int]:
    """The ends of the runs of consecutive faces that each close on their own (``cjio export glb``
    writes a mesh's geometries one after the other).

    ``vertices (V, 3)`` and ``faces (F, 3)`` are a triangle mesh's.

    Returns
    -------
    list of int
        Face indices ``[e1, e2, ..., F]``: faces ``[0, e1)``, ``[e1, e2)``, ... each closed, each
        the shortest such run from its start; a last run that does not close ends at ``F``.
    """
    if len(faces) == 0:
        return []
    prefix = np.bitwise_xor.accumulate(np.bitwise_xor.reduce(_edge_hashes(vertices, faces), axis=1))
    ends, start, before = [], 0, np.uint64(0)
    while start < len(faces):
        hit = np.flatnonzero(prefix[start:] == before)
        end = start + int(hit[0]) + 1 if len(hit) else len(faces)
        ends.append(end)
        before, start = prefix[end - 1], end
    return ends


def obj_repeated_objects(text: bytes) -> dict[str, list[int]]:
    """The OBJ object names written more than once (``o`` blocks of one name, as ``cjio export obj``
    writes a building's LoDs), each with its blocks' triangle counts in file order (a polygon of
    n vertices counts n - 2, as it is split)."""
    counts: dict[str, list[int]] = {}
    current = None
    for kind, rest in _OBJ_OBJECT_OR_FACE.findall(text):
        if kind == b"o":
            current = rest.decode("utf-8", "replace")
            counts.setdefault(current, []).append(0)
        elif current is not None:
            counts[current][-1] += max(len(rest.split()) - 2, 0)
    return {name: c for name, c in counts.items() if len(c) > 1}


def _box_overlap(boxes: np.ndarray, ref: int) -> np.ndarray:
    """Intersection over union (by volume) of each of ``boxes (N, 2, 3)`` with box ``ref``, as (N,) float."""
    lo = np.maximum(boxes[:, 0], boxes[ref, 0])
    hi = np.minimum(boxes[:, 1], boxes[ref, 1])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
    vol = np.prod(boxes[:, 1] - boxes[:, 0], axis=1)
    union = vol + vol[ref] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def one_version(vertices: np.ndarray, faces: np.ndarray, ends: list[int], lod: str, writer: str
                ) -> tuple[np.ndarray, np.ndarray, str] | None:
    """One of the versions a mesh holds as consecutive runs of faces, or None where they are not versions.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
    ends : list of int
        The end (face index) of each run, the last ``F``.
    lod : str
        :attr:`meshsom.io.ReaderOptions.lod`: ``"lowest"`` reads the run of fewest faces; otherwise the
        one of most faces (the most detailed; of equals the last, as CityJSON objects list their LoDs upwards
        and cjio writes them in that order); a LoD number cannot be told from these files (noted).
    writer : str
        What wrote the runs, in the note (``"a multi-LoD export, e.g. cjio's"``).

    Returns
    -------
    tuple or None
        ``(vertices (V', 3), faces (F', 3), note)`` of the version read, with its own vertices; None
        where there are fewer than two runs, one does not close or one does not overlap the most
        detailed by :data:`LOD_VERSION_MIN_OVERLAP` (parts of a building, joined as before).
    """
    faces = np.asarray(faces, np.int64)
    starts = [0] + list(ends[:-1])
    if len(ends) < 2 or ends[-1] != len(faces) or min(e - s for s, e in zip(starts, ends)) <= 0:
        return None
    runs = [faces[s:e] for s, e in zip(starts, ends)]
    if not all(is_closed(vertices, r) for r in runs):
        return None
    boxes = np.stack([[vertices[np.unique(r)].min(axis=0), vertices[np.unique(r)].max(axis=0)] for r in runs])
    sizes = np.array([len(r) for r in runs])
    richest = len(sizes) - 1 - int(np.argmax(sizes[::-1]))  # of equals the last: CityJSON lists LoDs upwards
    if not (_box_overlap(boxes, richest) >= LOD_VERSION_MIN_OVERLAP).all():
        return None
    pick = int(np.argmin(sizes)) if lod == "lowest" else richest
    chosen = "the least detailed" if lod == "lowest" else "the most detailed"
    if lod not in ("highest", "lowest"):
        chosen += f" (LoD {lod} cannot be told in such a file: it names none)"
    used, inverse = np.unique(runs[pick], return_inverse=True)
    note = (f"{len(runs)} versions of the object in the file ({writer}), of "
            f"{', '.join(str(int(s)) for s in sizes)} triangles: {chosen}, version {pick + 1}, read")
    return np.asarray(vertices)[used], inverse.reshape(-1, 3), note
