"""A city-sized CityJSON file split into a CityJSONSeq, so that it is read in ranges by tasks of their own.

A CityJSON document shares one vertex list among all its objects, so it cannot be read in pieces: a
reader parses it whole (about ten times its size in memory). A CityJSON Text Sequence (CityJSONSeq,
what ``cjseq cat`` writes) holds the same objects one feature per line, each a first-level city
object with its descendants and their own vertices, and is read a line at a time and in byte
ranges (:func:`meshsom.io.cityjsonseq_ranges`). :func:`split_cityjson` writes the sequence of a
document, as ``cjseq cat`` does:

- the header line is the document without its objects, vertices and appearance (its version,
  ``transform``, ``metadata``, reference system, ``geometry-templates``, extensions);
- a feature per object that has no parent (or whose parents are not in the file), holding it and
  its children, their children and so on, each object once;
- a feature's vertices are those its objects' ``boundaries`` (and addresses' ``location``) name, in
  the document's order, the indices renumbered; texture and material references (into the
  appearance, which is not read) are left out.

The meshes read from the sequence are those read from the document (same ids, coordinates and
faces: tests/test_corpus.py). A document whose boundaries are not lists of vertex indices within its
vertices is not split (None): read whole, its reader says what is wrong.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["split_cityjson"]

#: Members of a geometry that refer to the appearance (textures, materials), not read: left out of the features.
APPEARANCE_KEYS = ("texture", "material")


def split_cityjson(path: Path, out: Path, options) -> int | None:
    """Write a CityJSON file (plain or gzipped) as a CityJSONSeq file.

    Parameters
    ----------
    path : Path
    out : Path
        The ``.city.jsonl`` file written (its folder made).
    options : ReaderOptions
        Its ``max_bytes`` and the like bound the reading (:func:`meshsom.io.read_input_bytes`).

    Returns
    -------
    int or None
        The features written; None (nothing written) where the file is not a CityJSON document whose
        boundaries are vertex indices within its vertices: read whole, its reader says what is wrong.
    """
    from meshsom.errors import InputFileError
    from meshsom.io import _check_cityjson_header, _parse_json, read_input_bytes

    try:
        document = _parse_json(read_input_bytes(Path(path), options), str(path))
        _check_cityjson_header(document, str(path), options)
    except (InputFileError, OSError, TypeError, ValueError):
        return None
    objects, vertices = document.get("CityObjects"), document.get("vertices")
    if not isinstance(objects, dict) or not isinstance(vertices, list):
        return None
    header = {k: v for k, v in document.items() if k not in ("CityObjects", "vertices", "appearance")}
    header.update({"CityObjects": {}, "vertices": []})
    features = []
    try:
        taken: set = set()
        for oid, obj in objects.items():
            parents = obj.get("parents") if isinstance(obj, dict) else None
            if oid in taken or parents and any(p in objects for p in parents):
                continue
            features.append(_feature(oid, objects, vertices, taken))
        for oid in objects:  # objects of a cycle of parents (no first-level object above them): a feature each
            if oid not in taken:
                features.append(_feature(oid, objects, vertices, taken))
    except (IndexError, KeyError, TypeError, ValueError, AttributeError):
        return None
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", encoding="utf-8") as fh:
        fh.write(json.dumps(header, separators=(",", ":")) + "\n")
        for feature in features:
            fh.write(json.dumps(feature, separators=(",", ":")) + "\n")
    return len(features)


def _feature(oid: str, objects: dict, vertices: list, taken: set) -> dict:
    """The CityJSONFeature of a first-level object: it and its descendants (each once), their vertices renumbered in
    the document's order (a mesh read from it has its vertices in the order the document's gives)."""
    members, queue = [], [oid]
    while queue:
        m = queue.pop(0)
        if m in taken or m not in objects:
            continue
        taken.add(m)
        members.append(m)
        queue += list(objects[m].get("children") or [])
    named: set[int] = set()
    for m in members:
        for geometry in _geometries(objects[m]):
            _collect(geometry.get("boundaries", []), named, len(vertices))
    old = sorted(named)
    numbering = {v: k for k, v in enumerate(old)}
    found = {}
    for m in members:
        obj = dict(objects[m])
        if "geometry" in obj:
            obj["geometry"] = [_renumbered_geometry(g, numbering) for g in obj["geometry"]]
        if isinstance(obj.get("address"), list):
            obj["address"] = [{**a, "location": _renumbered_geometry(a["location"], numbering)}
                              if isinstance(a, dict) and isinstance(a.get("location"), dict) else a for a in obj["address"]]
        found[m] = obj
    return {"type": "CityJSONFeature", "id": oid, "CityObjects": found, "vertices": [vertices[i] for i in old]}


def _geometries(obj: dict) -> list:
    """An object's geometries and its addresses' locations: what names vertices."""
    found = list(obj.get("geometry") or [])
    if isinstance(obj.get("address"), list):
        found += [a["location"] for a in obj["address"] if isinstance(a, dict) and isinstance(a.get("location"), dict)]
    return found


def _collect(boundaries, named: set, n: int) -> None:
    """The vertex indices of nested lists, added to ``named``; ValueError for anything else."""
    stack = [boundaries]
    while stack:
        b = stack.pop()
        if isinstance(b, list):
            stack.extend(b)
        elif isinstance(b, bool) or not isinstance(b, int) or not 0 <= b < n:
            raise ValueError(f"not a vertex index: {b!r}")
        else:
            named.add(b)


def _renumbered_geometry(geometry: dict, numbering: dict) -> dict:
    out = {k: v for k, v in geometry.items() if k not in APPEARANCE_KEYS}
    if "boundaries" in geometry:
        out["boundaries"] = _renumbered(geometry["boundaries"], numbering)
    return out


def _renumbered(boundaries, numbering: dict):
    """Nested lists of vertex indices, each index replaced by its place among the feature's vertices."""
    if isinstance(boundaries, list):
        return [_renumbered(b, numbering) for b in boundaries]
    return numbering[boundaries]
