"""Folds: how every triangle's neighbour folds across each of its edges (DESIGN.md §3).

For triangle ``t = (a0, a1, a2)`` (counter-clockwise from outside, unit normal ``n``) and edge
``i`` from ``p = a_i`` to ``q = a_(i+1)``, with ``L = |q - p|``, ``e = (q - p) / L``,
``m = (p + q) / 2``, ``b = n x e`` (in t's plane, pointing into t), and ``r`` the apex of the
neighbour ``s_i``, ``d = (r - m) - ((r - m).e) e``:

- ``alpha = pi + atan2(d.n, -d.b)``: the interior dihedral angle, pi where flat, pi/2 at a convex
  right angle, 3 pi/2 at a concave one;
- ``u = (r - m).e / L``: the apex's position along the edge, from its midpoint, in edge lengths;
- ``v = |d| / L``: the apex's distance from the edge line, in edge lengths.

Folds are invariant to rigid motion and uniform scale; a mirror image negates ``u`` and reverses
each claw's order.
"""

from __future__ import annotations

import numpy as np

from meshsom.topology import Adjacency

__all__ = ["COMPONENTS", "apex_of_fold", "fold_of_apex", "folds"]

#: The three values of a fold, in storage order.
COMPONENTS = ("alpha", "u", "v")


def fold_of_apex(p: np.ndarray, q: np.ndarray, n: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Fold ``(alpha, u, v)`` of apex ``r`` across edge ``p -> q`` of a triangle with normal ``n``.

    Parameters
    ----------
    p, q : (..., 3) float64
        Edge start and end.
    n : (..., 3) float64
        Unit normal of the triangle the edge belongs to.
    r : (..., 3) float64
        Apex of the neighbouring triangle.

    Returns
    -------
    fold : (..., 3) float64
    """
    edge = q - p
    length = np.linalg.norm(edge, axis=-1, keepdims=True)
    e = edge / length
    m = 0.5 * (p + q)
    b = np.cross(n, e)
    rm = r - m
    along = np.sum(rm * e, axis=-1, keepdims=True)
    d = rm - along * e
    alpha = np.pi + np.arctan2(np.sum(d * n, axis=-1), -np.sum(d * b, axis=-1))
    u = along[..., 0] / length[..., 0]
    v = np.linalg.norm(d, axis=-1) / length[..., 0]
    return np.stack([alpha, u, v], axis=-1)


def apex_of_fold(p: np.ndarray, q: np.ndarray, n: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Inverse of :func:`fold_of_apex`: the apex that a fold places across edge ``p -> q``.

    Parameters
    ----------
    p, q, n : (..., 3) float64
    fold : (..., 3) float64
        ``(alpha, u, v)``.

    Returns
    -------
    r : (..., 3) float64
    """
    edge = q - p
    length = np.linalg.norm(edge, axis=-1, keepdims=True)
    e = edge / length
    b = np.cross(n, e)
    phi = fold[..., 0:1] - np.pi
    u, v = fold[..., 1:2], fold[..., 2:3]
    d = v * length * (np.sin(phi) * n - np.cos(phi) * b)
    return 0.5 * (p + q) + u * length * e + d


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals of the faces (counter-clockwise = outward).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    normals : (F, 3) float64
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def folds(vertices: np.ndarray, faces: np.ndarray, adj: Adjacency) -> np.ndarray:
    """Fold of every face across each of its three edges.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Closed, outward-oriented 2-manifold.
    adj : Adjacency
        From :func:`meshsom.topology.adjacency`.

    Returns
    -------
    folds : (F, 3, 3) float64
        ``folds[t, i] = (alpha, u, v)`` of leaf ``s_i`` across edge ``i`` of ``t``.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    n = face_normals(vertices, faces)[:, None, :].repeat(3, axis=1)
    p = vertices[faces]
    q = vertices[np.roll(faces, -1, axis=1)]
    # apex of s_i: its vertex after the back edge's end, (back + 2) % 3
    apex = faces[adj.neighbour, (adj.back + 2) % 3]
    return fold_of_apex(p, q, n, vertices[apex])
