"""Edge-face adjacency of triangle meshes: half-edges, edges, leaves and back-edges.

Conventions (DESIGN.md §3): triangle ``t = (a0, a1, a2)`` is counter-clockwise seen from
outside; edge ``i`` of ``t`` runs from ``a_i`` to ``a_(i+1 mod 3)``; half-edge ``h = 3 t + i``.
Leaf ``i`` of ``t`` is the neighbour across edge ``i``, so the leaves come in normal order.
Everything is vectorised: one sort of the ``3F`` half-edges, no loop per face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshsom.errors import MeshError

__all__ = ["Adjacency", "adjacency", "edge_table", "half_edges", "signed_volume", "vertex_pieces"]


def half_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges of every face, in half-edge order.

    Parameters
    ----------
    faces : (F, 3) int64

    Returns
    -------
    half_edges : (3F, 2) int64
        Row ``3 t + i`` is ``(faces[t, i], faces[t, (i + 1) % 3])``.
    """
    faces = np.asarray(faces, dtype=np.int64)
    return np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)


def edge_table(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges and how many half-edges use each.

    Parameters
    ----------
    faces : (F, 3) int64

    Returns
    -------
    edges : (E, 2) int64
        Unique undirected edges, smaller vertex first, sorted.
    edge_of : (3F,) int64
        Edge index of every half-edge.
    counts : (E,) int64
        Number of half-edges (faces) on each edge: 2 on a closed 2-manifold.
    """
    he = half_edges(faces)
    if len(he) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    lo, hi = he.min(axis=1), he.max(axis=1)
    n = int(hi.max()) + 1
    key = lo * n + hi
    uniq, edge_of, counts = np.unique(key, return_inverse=True, return_counts=True)
    edges = np.stack([uniq // n, uniq % n], axis=1)
    return edges, edge_of.reshape(-1), counts


@dataclass(frozen=True)
class Adjacency:
    """Dual-graph adjacency of a closed, consistently oriented 2-manifold triangle mesh.

    Attributes
    ----------
    neighbour : (F, 3) int64
        ``neighbour[t, i]`` is leaf ``s_i``: the face across edge ``i`` of ``t``.
    back : (F, 3) int64
        ``back[t, i]`` is the edge ``j`` of ``s_i`` that leads back to ``t``
        (``neighbour[s_i, j] == t``).
    """

    neighbour: np.ndarray
    back: np.ndarray


def adjacency(faces: np.ndarray, source: str = "mesh") -> Adjacency:
    """Leaves and back-edges of every face.

    Parameters
    ----------
    faces : (F, 3) int64
        A closed, edge-manifold, consistently oriented triangle mesh.
    source : str
        Named in errors.

    Returns
    -------
    Adjacency

    Raises
    ------
    MeshError
        If the mesh is open, non-manifold or inconsistently oriented.
    """
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise MeshError(source, f"expected faces of shape (F, 3) with F > 0, received {faces.shape}")
    he = half_edges(faces)
    _, edge_of, counts = edge_table(faces)
    open_edges, crowded = int((counts == 1).sum()), int((counts > 2).sum())
    if open_edges or crowded:
        raise MeshError(
            source,
            f"not a closed 2-manifold: {open_edges} edges on an open boundary, {crowded} edges shared by "
            "more than two faces (run it through `meshsom ingest` first)",
        )
    order = np.argsort(edge_of, kind="stable").reshape(-1, 2)
    h0, h1 = order[:, 0], order[:, 1]
    if not (np.array_equal(he[h0, 0], he[h1, 1]) and np.array_equal(he[h0, 1], he[h1, 0])):
        bad = int((he[h0, 0] != he[h1, 1]).sum())
        raise MeshError(source, f"inconsistently oriented: {bad} edges are walked the same way by both faces")
    twin = np.empty(len(he), np.int64)
    twin[h0], twin[h1] = h1, h0
    return Adjacency(neighbour=(twin // 3).reshape(-1, 3), back=(twin % 3).reshape(-1, 3))


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed mesh (positive when oriented outward).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    centre = vertices.mean(axis=0) if len(vertices) else np.zeros(3)
    a, b, c = a - centre, b - centre, c - centre
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def vertex_pieces(vertices: np.ndarray, faces: np.ndarray, joined_by: np.ndarray | None = None
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pieces of a mesh whose faces are joined through shared vertices, each with its own vertices, numbered in
    the order of their first faces (one sort of the faces, no scan per piece).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    joined_by : (F, 3) int64, optional
        The vertex ids that join faces, where they are not ``faces``' own (vertices welded by position).

    Returns
    -------
    list of ((V_i, 3) float64, (F_i, 3) int64)
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return []
    joined = faces if joined_by is None else np.asarray(joined_by, np.int64).reshape(-1, 3)
    n, k = len(faces), int(joined.max()) + 1
    incidence = sparse.coo_matrix((np.ones(3 * n, np.int8), (np.repeat(np.arange(n), 3), joined.reshape(-1))),
                                  shape=(n, k)).tocsr()
    _, component = connected_components(sparse.bmat([[None, incidence], [incidence.T, None]]), directed=False)
    _, piece = np.unique(component[:n], return_inverse=True)  # the pieces that have faces, 0..m-1
    m = int(piece.max()) + 1
    first = np.full(m, n)
    np.minimum.at(first, piece, np.arange(n))
    rank = np.empty(m, np.int64)
    rank[np.argsort(first)] = np.arange(m)
    piece = rank[piece]
    order = np.argsort(piece, kind="stable")
    out = []
    for f in np.split(faces[order], np.cumsum(np.bincount(piece, minlength=m))[:-1]):
        used, local = np.unique(f, return_inverse=True)
        out.append((np.asarray(vertices)[used], local.reshape(-1, 3)))
    return out
