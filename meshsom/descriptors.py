"""Global shape descriptors: the classic baseline for domain maps.

Osada, Funkhouser, Chazelle and Dobkin (2002), *Shape distributions*: D2 is the
distribution of distances between random pairs of points on the surface. Dividing the
distances by their mean makes it scale invariant; it is invariant to rotation and
translation by construction. Fed to the same domain SOM as the domain vectors, it is
the baseline against which the fold encoding's grouping of families is measured.
"""

from __future__ import annotations

import numpy as np

#: Upper end of the D2 histogram, in mean pair distances (longer pairs go to the last bin).
D2_RANGE = 3.0


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), received {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must be a non-empty (F, 3) array, received shape {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise TypeError(f"faces must hold integers, received dtype {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"faces reference vertices {faces.min()}..{faces.max()}, mesh has {len(vertices)} vertices")
    return vertices.astype(np.float64), faces.astype(np.int64)


def sample_surface(vertices, faces, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """Points uniformly distributed on a triangle mesh's surface.

    Triangles are drawn with probability proportional to their area (inverse CDF on the
    cumulative areas), points inside uniformly: ``(1 - sqrt(r1)) a + sqrt(r1) (1 - r2) b +
    sqrt(r1) r2 c`` (Osada et al., eq. 1).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    n_points : int
    rng : numpy.random.Generator

    Returns
    -------
    (n_points, 3) float64
    """
    vertices, faces = _check_mesh(vertices, faces)
    tri = vertices[faces]  # (F, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cdf = np.cumsum(area)
    if not cdf[-1] > 0:
        raise ValueError(f"the mesh has zero surface area ({len(faces)} faces); cannot sample it")
    u, r1, r2 = rng.random((3, n_points))
    pick = np.minimum(np.searchsorted(cdf / cdf[-1], u, side="right"), len(faces) - 1)
    s = np.sqrt(r1)[:, None]
    a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
    return (1.0 - s) * a + s * (1.0 - r2[:, None]) * b + s * r2[:, None] * c


def d2_histogram(vertices, faces, n_pairs: int = 4096, bins: int = 64, seed: int = 0) -> np.ndarray:
    """Osada et al.'s D2 shape distribution, scale invariant.

    ``2 * n_pairs`` surface points (:func:`sample_surface`) make ``n_pairs`` disjoint pairs;
    their distances are divided by their mean and counted in ``bins`` equal bins over
    ``[0, D2_RANGE]`` mean distances (longer ones in the last bin), divided by ``n_pairs``.

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
    n_pairs : int
    bins : int
    seed : int
        Seed of the point sampling; the same seed gives the same histogram, and a mesh
        scaled by any factor gives the same histogram as the original.

    Returns
    -------
    (bins,) float64
        Sums to 1.
    """
    if n_pairs < 1 or bins < 1:
        raise ValueError(f"n_pairs and bins must be >= 1, received {n_pairs} and {bins}")
    rng = np.random.default_rng(seed)
    points = sample_surface(vertices, faces, 2 * n_pairs, rng)
    dist = np.linalg.norm(points[:n_pairs] - points[n_pairs:], axis=1)
    mean = dist.mean()
    if not mean > 0:
        raise ValueError("all sampled points coincide (a degenerate mesh); D2 is undefined")
    scaled = np.minimum(dist / mean, D2_RANGE)
    idx = np.minimum((scaled * (bins / D2_RANGE)).astype(np.int64), bins - 1)
    return np.bincount(idx, minlength=bins) / float(n_pairs)


def d2_histograms(meshes, n_pairs: int = 4096, bins: int = 64, seed: int = 0) -> np.ndarray:
    """D2 of several meshes, each with the same ``seed`` (so equal shapes give equal rows).

    Parameters
    ----------
    meshes : sequence of (vertices (V, 3) float64, faces (F, 3) int64)

    Returns
    -------
    (n_meshes, bins) float64
    """
    rows = [d2_histogram(v, f, n_pairs, bins, seed) for v, f in meshes]  # one vectorised call per mesh
    if not rows:
        raise ValueError("meshes is empty; expected at least one (vertices, faces) pair")
    return np.stack(rows)
