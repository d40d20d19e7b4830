"""A closed triangle mesh moved outwards (or inwards) by a distance: every planar face by exactly
that distance, along its normal, where at most three planes meet at a vertex (a mitered offset).

Used to close the hairline gaps between the elements of a BIM model (:mod:`meshsom.ifc`): each
element grown by half the gap, the union taken, the union shrunk back by as much (a morphological
closing; manifold3d's exact Minkowski sums of thousands of elements take minutes, this a
fraction of a second).

Each vertex moves by the least-squares solution ``d`` of ``n_i . d = distance`` over the unit
normals ``n_i`` of its faces (the smallest such ``d`` where they do not fix it: a vertex inside a
flat region or on an edge): exact for a vertex of one, two or three planes, as a box's corners
are. Where more planes meet at a sharp point (a needle's tip), ``d`` is held to ``miter_limit``
times the distance, as 2D strokes are.
"""

from __future__ import annotations

import numpy as np

__all__ = ["mitered_offset"]

#: Longest move of a vertex, in distances (at a sharp tip the exact offset point runs far out).
MITER_LIMIT = 3.0
#: Singular values of a vertex's normal matrix below this share of its largest are taken for zero
#: (faces of one plane, or of two, leave directions that the offset does not fix).
RCOND = 1e-6


def mitered_offset(vertices: np.ndarray, faces: np.ndarray, distance: float,
                   miter_limit: float = MITER_LIMIT) -> np.ndarray:
    """The vertices of the mesh offset by ``distance`` along its outward normals.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Closed and oriented outwards (counter-clockwise seen from outside).
    distance : float
        Metres; negative moves inwards. Features thinner than twice a negative distance turn
        inside out.
    miter_limit : float
        Longest move of a vertex, in multiples of ``|distance|``.

    Returns
    -------
    (V, 3) float64
        Moved vertices; the faces stay as they are.
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if distance == 0 or not len(faces):
        return vertices.copy()
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    norm = np.linalg.norm(cross, axis=1)
    normal = np.where(norm[:, None] > 0, cross / np.where(norm > 0, norm, 1.0)[:, None], 0.0)
    outer = normal[:, :, None] * normal[:, None, :]
    matrix = np.zeros((len(vertices), 3, 3))
    rhs = np.zeros((len(vertices), 3))
    for k in range(3):
        np.add.at(matrix, faces[:, k], outer)
        np.add.at(rhs, faces[:, k], normal * distance)
    move = np.einsum("vij,vj->vi", np.linalg.pinv(matrix, rcond=RCOND, hermitian=True), rhs)
    length = np.linalg.norm(move, axis=1)
    limit = miter_limit * abs(distance)
    move *= np.minimum(1.0, limit / np.where(length > 0, length, 1.0))[:, None]
    return vertices + move
