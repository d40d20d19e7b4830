"""Synthesis: decode a ring vector back into a triangle patch by unfolding (DESIGN.md §3).

A level-L vector holds the folds of its walk's slots (:mod:`meshsom.rings`). Decoding places the
root, then every leaf from its fold, slot by slot in walk order:

- the root's edge 0 runs from (0, 0, 0) to (1, 0, 0) in the plane z = 0 (normal +z); its apex
  comes from the back-fold ``f(s_0, back)`` (level >= 2: where the root's apex sits seen from
  its first leaf); a level-1 vector says nothing of the root's shape, so the root is equilateral;
- the leaf across edge ``e`` of a placed face gets its apex from the fold ``(alpha, u, v)``
  (:func:`meshsom.folds.apex_of_fold`); its own edge 0 is the shared edge, walked back.

A vector holds many copies of the same quantity: a level-3 ring repeats folds of its 10 slots in
16 one-rings, and the dihedral angle of an edge appears from both of its sides. Without leveling,
the first copy of each fold is used; with leveling, every copy of the same quantity is averaged
first: identical folds, and the two angles of an edge (on the circle, so that copies on both sides
of 0 / 2 pi agree). Averaging the shape of each face over its parent's fold and its children's
back-folds as well was tried and raises the QC-error (it spreads a concentrated error over every
component), so it is not done. The re-translation error is the QC-error between a vector and the
re-encoding of its own patch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshsom.folds import apex_of_fold, folds
from meshsom.rings import encode_level, template
from meshsom.topology import Adjacency

__all__ = ["Patch", "decode", "level_vector", "qc_distance", "reencode", "retranslation_error", "write_patch"]


@dataclass
class Patch:
    """A decoded triangle patch.

    Attributes
    ----------
    vertices : (P, 3) float64
    faces : (S, 3) int64
        Counter-clockwise from outside; face ``i`` is ``slots[i]`` (its edge 0 is its start edge),
        the root first.
    slots : list of tuple of int
        Canonical path of every face (leaves included).
    adjacency : Adjacency
        Neighbours along the walk (edges leaving the patch point to face 0 and are never walked).
    level : int
    """

    vertices: np.ndarray
    faces: np.ndarray
    slots: list
    adjacency: Adjacency
    level: int


def _keys(level: int) -> list[tuple[tuple[int, ...], int]]:
    tpl = template(level)
    return list(zip(tpl.slots_of_refs(), tpl.ref_edge.tolist()))


def _reverse(key):
    """The same edge seen from the other face: (slot, edge) of the back-fold."""
    slot, edge = key
    if slot and edge == 0:
        return slot[:-1], slot[-1]
    return slot + (edge,), 0


def level_vector(x: np.ndarray, level: int) -> np.ndarray:
    """Leveling: average every copy of the same quantity.

    Copies are the entries of the same fold (same canonical slot and edge), and, for alpha, the
    fold of the same edge seen from its other face.

    Parameters
    ----------
    x : (D,) float
        Raw (de-standardized) ring vector.
    level : int

    Returns
    -------
    leveled : (D,) float64
    """
    keys = _keys(level)
    f = np.asarray(x, np.float64).reshape(-1, 3)
    ids: dict = {}
    fold_id = np.array([ids.setdefault(k, len(ids)) for k in keys])
    n = len(ids)
    mean = np.zeros((n, 3))
    np.add.at(mean, fold_id, f)
    mean /= np.bincount(fold_id, minlength=n)[:, None]
    # alpha: pool a fold with its back-fold when both are in the vector
    edges: dict = {}
    edge_id = np.array([edges.setdefault(min(k, _reverse(k)), len(edges)) for k in keys])
    # alpha is an angle: averaged on the circle, so copies on both sides of 0 / 2 pi agree
    n_edges = edge_id.max() + 1
    c = np.bincount(edge_id, weights=np.cos(f[:, 0]), minlength=n_edges)
    s = np.bincount(edge_id, weights=np.sin(f[:, 0]), minlength=n_edges)
    alpha = np.mod(np.arctan2(s, c), 2 * np.pi)
    alpha = np.where(alpha <= 0, 2 * np.pi, alpha)
    out = mean[fold_id]
    out[:, 0] = alpha[edge_id]
    return out.reshape(-1)


def decode(x: np.ndarray, level: int, leveling: bool = False) -> Patch:
    """Unfold a raw ring vector into a triangle patch.

    Parameters
    ----------
    x : (D,) float
        Raw (de-standardized) level-``level`` vector; ``v`` entries must be > 0.
    level : int
    leveling : bool
        Average every copy of the same quantity first.

    Returns
    -------
    Patch
    """
    x = np.asarray(x, np.float64).reshape(-1)
    tpl = template(level)
    if x.shape != (tpl.dims,):
        raise ValueError(f"a level-{level} vector has {tpl.dims} values; received shape {x.shape}")
    if leveling:
        x = level_vector(x, level)
    values: dict = {}
    for key, fold in zip(_keys(level), x.reshape(-1, 3)):
        values.setdefault(key, fold)

    # root: edge 0 on the x axis, apex from the back-fold of its first leaf (level >= 2)
    back = values.get(((0,), 0))
    if back is not None:
        u, v = back[1], back[2]
        apex = np.array([0.5 - u, v, 0.0])  # the back edge runs (1,0,0) -> (0,0,0); into the root is +y
    else:
        apex = np.array([0.5, np.sqrt(3.0) / 2.0, 0.0])
    verts = [np.zeros(3), np.array([1.0, 0.0, 0.0]), apex]
    faces = [[0, 1, 2]]
    normals = [np.array([0.0, 0.0, 1.0])]
    index = {(): 0}
    slots = [()]
    links: list[tuple[int, int, int]] = []  # (parent face, parent edge, child face)
    for slot in sorted(tpl.slots, key=len):
        fi = index[slot]
        tri = faces[fi]
        for e in range(3):
            if slot and e == 0:
                continue  # the leaf across the back edge is the parent
            fold = values.get((slot, e))
            child = slot + (e,)
            if fold is None or child in index:
                continue
            p, q = verts[tri[e]], verts[tri[(e + 1) % 3]]
            r = apex_of_fold(p, q, normals[fi], fold)
            verts.append(r)
            ci = len(faces)
            faces.append([tri[(e + 1) % 3], tri[e], len(verts) - 1])  # (q, p, r): edge 0 walks back
            n = np.cross(p - q, r - q)
            normals.append(n / np.linalg.norm(n))
            index[child] = ci
            slots.append(child)
            links.append((fi, e, ci))
    nb = np.zeros((len(faces), 3), np.int64)
    bk = np.zeros((len(faces), 3), np.int64)
    for fi, e, ci in links:
        nb[fi, e], bk[fi, e] = ci, 0
        nb[ci, 0], bk[ci, 0] = fi, e
    return Patch(np.array(verts), np.array(faces, np.int64), slots, Adjacency(nb, bk), level)


def reencode(patch: Patch) -> np.ndarray:
    """Ring vector of a patch's root (start leaf 0), float64.

    Returns
    -------
    x : (D,) float64
    """
    fo = folds(patch.vertices, patch.faces, patch.adjacency)
    return encode_level(fo, patch.adjacency, patch.level, faces=np.array([0]), dtype=np.float64)[0]


def qc_distance(x: np.ndarray, y: np.ndarray) -> float:
    """QC-distance: mean Euclidean distance over the 3-value components of two vectors."""
    d = np.asarray(x, np.float64).reshape(-1, 3) - np.asarray(y, np.float64).reshape(-1, 3)
    return float(np.linalg.norm(d, axis=1).mean())


def retranslation_error(x: np.ndarray, level: int, leveling: bool = False, stats=None) -> float:
    """QC-error between a raw vector and the re-encoding of its own synthesized patch.

    Parameters
    ----------
    x : (D,) float
        Raw vector.
    level : int
    leveling : bool
    stats : Stats or dict, optional
        Measure in standardized units (as the SOM sees them).
    """
    y = reencode(decode(x, level, leveling))
    if stats is not None:
        from meshsom.standardize import standardize

        return qc_distance(standardize(np.asarray(x, np.float64), stats), standardize(y, stats))
    return qc_distance(x, y)


def write_patch(patch: Patch, path, scale: float = 1.0) -> None:
    """Export a patch through trimesh (format from the file name: .obj, .ply, .glb, .stl, .off)."""
    import trimesh

    trimesh.Trimesh(patch.vertices * scale, patch.faces, process=False).export(path)
