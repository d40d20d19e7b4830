"""Nested N-rings: precomputed walks that turn the fold array into ring vectors with one gather.

A level-1 ring of triangle ``t`` from start leaf ``k`` is ``[f(t, k), f(t, k+1), f(t, k+2)]``
(9 values). A level-L ring is four overlapping level-(L-1) rings (DESIGN.md §3)::

    R_L(t, k) = [R_(L-1)(t, k), R_(L-1)(s_k, back), R_(L-1)(s_(k+1), back), R_(L-1)(s_(k+2), back)]

where each nested ring starts at the edge that leads back to its parent.

The walk is written once per level as a list of *fold references*: a walk from the root (edge
offsets, each relative to the current face's start edge) and the fold's edge offset. Walking
back to the parent (offset 0 below the root) cancels a step, so every reference has a canonical
form ``(slot, edge)``: ``slot`` is a path of edge offsets from the root without back-steps (the
root's offsets relative to its start, deeper ones relative to each face's back edge), ``edge``
is relative to the slot's start. Two entries with the same canonical form hold the same value
on every mesh; variations (:mod:`meshsom.variations`) and synthesis (:mod:`meshsom.synthesis`)
rely on that.

Encoding a level for all faces is then one pass per distinct slot (a chain of gathers through
the adjacency) plus one gather from the fold array: no Python loop over faces.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from meshsom.topology import Adjacency

__all__ = ["MAX_LEVEL", "RingTemplate", "canonical", "dims", "encode_level", "faces_in_walk", "ring_index", "template"]

#: Deepest level with a template (8 is Table 1's last row; 147,456 dimensions).
MAX_LEVEL = 8


def dims(level: int) -> int:
    """Length of a level-L ring vector: ``9 * 4**(L-1)``."""
    return 9 * 4 ** (level - 1)


def faces_in_walk(level: int) -> int:
    """Distinct faces a level-L ring touches on a large mesh: ``3 * 2**L - 2``."""
    return 3 * 2**level - 2


def canonical(walk: tuple[int, ...], edge: int, start: int = 0) -> tuple[tuple[int, ...], int]:
    """Canonical ``(slot, edge)`` of a fold reference.

    Parameters
    ----------
    walk : tuple of int
        Edge offsets from the root, each relative to the current face's start edge (the root's
        start is ``start``; every other face starts at its back edge).
    edge : int
        Edge offset of the fold, relative to the last face's start.
    start : int
        The root's start edge, relative to the root's canonical start 0.

    Returns
    -------
    slot : tuple of int
        Path without back-steps; offsets relative to canonical starts.
    edge : int
        Relative to the slot's canonical start.
    """
    stack: list[int] = []
    shift = start % 3
    for o in walk:
        eo = (shift + o) % 3
        if stack and eo == 0:
            shift = stack.pop()  # back to the parent, arriving through the popped child's edge
        else:
            stack.append(eo)
            shift = 0
    return tuple(stack), (shift + edge) % 3


def _walk_refs(level: int, walk: tuple[int, ...] = ()) -> list[tuple[tuple[int, ...], int]]:
    if level == 1:
        return [(walk, j) for j in range(3)]
    refs = _walk_refs(level - 1, walk)
    for j in range(3):
        refs += _walk_refs(level - 1, walk + (j,))
    return refs


@dataclass(frozen=True)
class RingTemplate:
    """The walk of one level.

    Attributes
    ----------
    level : int
    refs : tuple of (walk, edge)
        The raw fold references, ``dims(level) / 3`` of them, in vector order.
    slots : tuple of tuple of int
        Distinct canonical slots, in order of first use (slot 0 is the root).
    ref_slot : (R,) int64
        Slot of every reference (index into ``slots``).
    ref_edge : (R,) int64
        Canonical edge offset of every reference.
    """

    level: int
    refs: tuple
    slots: tuple
    ref_slot: np.ndarray
    ref_edge: np.ndarray

    @property
    def dims(self) -> int:
        return 3 * len(self.refs)

    def keys(self, start: int = 0, mirror: bool = False) -> list[tuple[tuple[int, ...], int]]:
        """Canonical key of every reference when the root starts at ``start`` (optionally mirrored).

        A mirror image walks every offset the other way round (``o -> -o mod 3``).
        """
        sign = -1 if mirror else 1
        return [
            canonical(tuple(sign * o for o in walk), sign * edge, sign * start) for walk, edge in self.refs
        ]

    def n_faces(self) -> int:
        """Distinct faces touched (slots and the leaves of their folds) on a large mesh."""
        faces = set(self.slots)
        for slot, edge in zip(self.slots_of_refs(), self.ref_edge.tolist()):
            faces.add(slot[:-1] if slot and edge == 0 else slot + (edge,))
        return len(faces)

    def slots_of_refs(self) -> list[tuple[int, ...]]:
        return [self.slots[i] for i in self.ref_slot.tolist()]


@lru_cache(maxsize=None)
def template(level: int) -> RingTemplate:
    """The (cached) ring template of a level.

    Parameters
    ----------
    level : int
        1 .. MAX_LEVEL.
    """
    if not (isinstance(level, (int, np.integer)) and 1 <= level <= MAX_LEVEL):
        raise ValueError(f"ring level must be an integer in 1..{MAX_LEVEL}, received {level!r}")
    refs = _walk_refs(int(level))
    slots: dict[tuple[int, ...], int] = {}
    ref_slot, ref_edge = [], []
    for walk, edge in refs:
        slot, e = canonical(walk, edge)
        ref_slot.append(slots.setdefault(slot, len(slots)))
        ref_edge.append(e)
    return RingTemplate(
        level=int(level), refs=tuple(refs), slots=tuple(slots),
        ref_slot=np.array(ref_slot, np.int64), ref_edge=np.array(ref_edge, np.int64),
    )


def ring_index(adj: Adjacency, level: int, faces: np.ndarray | None = None, start: int | np.ndarray = 0) -> np.ndarray:
    """Indices into the flattened fold array ``folds.reshape(-1, 3)`` of every fold of every ring.

    Parameters
    ----------
    adj : Adjacency
    level : int
    faces : (n,) int64, optional
        Root faces (default: all).
    start : int or (n,) int64
        Start leaf ``k`` of each root.

    Returns
    -------
    index : (n, dims(level) // 3) int64
    """
    tpl = template(level)
    nb, back = adj.neighbour, adj.back
    root = np.arange(len(nb), dtype=np.int64) if faces is None else np.asarray(faces, np.int64)
    start = np.broadcast_to(np.asarray(start, np.int64) % 3, root.shape)
    place: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {(): (root, start)}
    for slot in sorted(tpl.slots, key=len):  # every prefix of a slot is a slot
        if slot in place:
            continue
        face, s = place[slot[:-1]]
        edge = (s + slot[-1]) % 3
        place[slot] = (nb[face, edge], back[face, edge])
    out = np.empty((len(root), len(tpl.refs)), np.int64)
    for i, slot in enumerate(tpl.slots):
        cols = np.flatnonzero(tpl.ref_slot == i)
        face, s = place[slot]
        out[:, cols] = face[:, None] * 3 + (s[:, None] + tpl.ref_edge[cols][None, :]) % 3
    return out


def encode_level(
    folds: np.ndarray,
    adj: Adjacency,
    level: int,
    faces: np.ndarray | None = None,
    start: int | np.ndarray = 0,
    dtype=np.float32,
) -> np.ndarray:
    """Ring vectors of one level (raw fold values, not standardized).

    Parameters
    ----------
    folds : (F, 3, 3) float64
        From :func:`meshsom.folds.folds`.
    adj : Adjacency
    level : int
    faces : (n,) int64, optional
        Root faces (default: all, in order).
    start : int or (n,) int64
        Start leaf ``k`` (the store uses 0).
    dtype : numpy dtype
        Output type (float32 in the store; float64 for checks).

    Returns
    -------
    rings : (n, dims(level)) dtype
        ``rings[t, 3 r + c]`` is component ``c`` (alpha, u, v) of reference ``r``.
    """
    idx = ring_index(adj, level, faces, start)
    flat = np.asarray(folds).reshape(-1, 3)
    return flat[idx].reshape(len(idx), -1).astype(dtype, copy=False)


def encode_mesh(vertices: np.ndarray, faces: np.ndarray, levels, source: str = "mesh", dtype=np.float32) -> dict:
    """Ring vectors of every face of one closed mesh at several levels.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Closed, outward-oriented 2-manifold (as :func:`meshsom.preprocess.preprocess` returns).
    levels : iterable of int
    source : str
        Named in errors.

    Returns
    -------
    rings : dict of int -> (F, dims(level)) dtype

    Raises
    ------
    MeshError
        If the mesh is not a closed, consistently oriented 2-manifold.
    """
    from meshsom.folds import folds
    from meshsom.topology import adjacency

    adj = adjacency(faces, source=source)
    fo = folds(vertices, faces, adj)
    return {int(level): encode_level(fo, adj, int(level), dtype=dtype) for level in levels}
