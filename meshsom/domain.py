"""Domain maps (DESIGN.md §5) and how well they group labelled meshes.

A mesh's *domain vector* is the histogram of its triangles' best-matching units on the
triangle map, divided by its triangle count, smoothed with a Gaussian of ``sigma`` cells on
the (toroidal) grid and flattened. A small domain SOM (one variation) places every mesh at a
unit; a figure (:mod:`meshsom.thumbnails`) draws each mesh there.

Clustering quality against known labels (the synthetic corpus's families):

- :func:`knn_label_agreement`: share of each mesh's k nearest other meshes *on the map* that
  carry its label, averaged; :func:`label_agreement_chance` is its expectation under a
  random placement;
- the adjusted Rand index (scikit-learn's ``adjusted_rand_score``) of map regions
  (:func:`map_regions`, scikit-learn's k-means on the domain prototypes) against the labels.

Everything here is pure NumPy over arrays; units are numbered row-major as in
:mod:`meshsom.metrics`.
"""

from __future__ import annotations

import numpy as np

from meshsom.metrics import TIE_RTOL, TOPOLOGIES, grid_distance, neighbour_units, topographic_errors
from meshsom.som import (
    INITS, SOM, default_sigma_start, gaussian_kernel_1d, pca_by_shape, pca_codebook, random_pick, smooth, train_batch,
)


def _check_topology(topology: str) -> None:
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {', '.join(TOPOLOGIES)}; received {topology!r}")


def _check_grid(rows: int, cols: int) -> None:
    if int(rows) != rows or int(cols) != cols or rows < 1 or cols < 1:
        raise ValueError(f"rows and cols must be positive integers, received {rows!r} x {cols!r}")


def _int_array(name: str, values, ndim: int = 1) -> np.ndarray:
    arr = np.asarray(values)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-D array, received shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must hold integers, received dtype {arr.dtype}")
    return arr.astype(np.int64)


# ---------------------------------------------------------------------- domain vectors
def _check_bmus(face_mesh, units, n_meshes: int, n_units: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated (face_mesh, units) as int64 arrays, and every mesh's triangle count (n_meshes,)."""
    face_mesh = _int_array("face_mesh", face_mesh)
    units = _int_array("units", units)
    if face_mesh.shape != units.shape:
        raise ValueError(f"face_mesh and units must have the same length, received {len(face_mesh)} and {len(units)}")
    if n_meshes < 1 or n_units < 1:
        raise ValueError(f"n_meshes and n_units must be >= 1, received {n_meshes} and {n_units}")
    for name, arr, n in (("face_mesh", face_mesh, n_meshes), ("units", units, n_units)):
        bad = np.flatnonzero((arr < 0) | (arr >= n))
        if len(bad):
            raise ValueError(f"{name}[{bad[0]}] = {arr[bad[0]]} lies outside 0..{n - 1} ({len(bad)} such entries)")
    totals = np.bincount(face_mesh, minlength=n_meshes)
    empty = np.flatnonzero(totals == 0)
    if len(empty):
        raise ValueError(f"every mesh needs at least one triangle; meshes {empty[:10].tolist()} have none "
                         f"({len(empty)} of {n_meshes})")
    return face_mesh, units, totals


def bmu_histograms(face_mesh, units, n_meshes: int, n_units: int) -> np.ndarray:
    """Per mesh, the share of its triangles won by each unit of the triangle map.

    Parameters
    ----------
    face_mesh : (F,) int
        Mesh number of every triangle, in ``0..n_meshes-1``.
    units : (F,) int
        Best-matching unit of every triangle, in ``0..n_units-1``.
    n_meshes, n_units : int

    Returns
    -------
    (n_meshes, n_units) float64
        Row ``m`` is the BMU histogram of mesh ``m`` divided by its triangle count (sums to 1).

    Raises
    ------
    ValueError
        Mismatched lengths, an index out of range, or a mesh without triangles.
    """
    face_mesh, units, totals = _check_bmus(face_mesh, units, n_meshes, n_units)
    counts = np.bincount(face_mesh * n_units + units, minlength=n_meshes * n_units).reshape(n_meshes, n_units)
    return counts / totals[:, None].astype(np.float64)


def domain_vectors(hist, rows: int, cols: int, sigma: float, topology: str = "toroidal") -> np.ndarray:
    """Smooth every BMU histogram with a Gaussian of ``sigma`` cells on the grid.

    Each unit's mass is spread with ``exp(-d^2 / (2 sigma^2))`` (``d`` the cell distance of
    DESIGN.md §4, wrapped on a torus), divided by that kernel's total over the grid, so the
    mass is conserved: a histogram summing to 1 gives a vector summing to 1. On a torus the
    kernel's total is the same for every unit, so a mesh whose triangles all hit unit ``u``
    gives exactly ``exp(-d(u, j)^2 / (2 sigma^2)) / sum_j' exp(-d(u, j')^2 / (2 sigma^2))``.
    On a planar grid each source unit is normalised by its own (truncated) total.

    The smoothing is separable (:func:`meshsom.som.smooth`): ``O(n_meshes * M * (rows + cols))``.

    Parameters
    ----------
    hist : (n_meshes, rows*cols) float
        From :func:`bmu_histograms`.
    rows, cols : int
        The triangle map's size.
    sigma : float
        Radius in cells, > 0.
    topology : {"toroidal", "planar"}

    Returns
    -------
    (n_meshes, rows*cols) float32
    """
    _check_topology(topology)
    _check_grid(rows, cols)
    hist = np.asarray(hist, np.float64)
    M = rows * cols
    if hist.ndim != 2 or hist.shape[1] != M:
        raise ValueError(f"hist must have shape (n_meshes, {M}) for a {rows} x {cols} map, received {hist.shape}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, received {sigma}")
    total = smooth(np.ones(M), sigma, rows, cols, topology)  # (M,): kernel total per source unit
    out = smooth((hist / total[None, :]).T, sigma, rows, cols, topology).T
    return np.ascontiguousarray(out, np.float32)


# ---------------------------------------------------------------------- domain SOM
def train_domain_map(vectors, rows: int, cols: int, epochs: int, seed: int, sigma_start: float | None = None,
                     sigma_end: float = 1.0, init: str = "pca", topology: str = "toroidal",
                     backend: str = "numpy") -> SOM:
    """Train the small domain SOM (one variation: the identity) on domain vectors.

    Parameters
    ----------
    vectors : (n_meshes, D) float
        Domain vectors (:func:`domain_vectors`) or any per-mesh descriptor (e.g. D2).
    rows, cols : int
        Domain map size.
    epochs : int
    seed : int
        ``random_state`` of the SOM.
    sigma_start : float or None
        None: ``max(rows, cols) / 4`` (the SOM's default).
    sigma_end : float
    init : {"pca", "random"}
        PCA is deterministic and spreads a few hundred meshes better than samples.
    topology : {"toroidal", "planar"}
    backend : {"numpy", "opencl", "auto"}

    Returns
    -------
    SOM
        Fitted; ``weights_ (rows*cols, D) float32``.
    """
    return SOM(rows=rows, cols=cols, topology=topology, epochs=epochs, sigma_start=sigma_start,
               sigma_end=sigma_end, init=init, random_state=seed, backend=backend).fit(vectors)


def place(vectors, som: SOM) -> np.ndarray:
    """Unit of every mesh on a fitted domain map.

    Parameters
    ----------
    vectors : (n_meshes, D) float
    som : SOM
        Fitted on vectors of the same D.

    Returns
    -------
    (n_meshes,) int64
    """
    return np.asarray(som.predict(vectors), np.int64)


# ---------------------------------------------------------------------- sparse domain vectors
#: Mesh pairs of units handled at once by :meth:`SparseDomainVectors.sq_norms` (bounds its memory
#: to about 100 bytes per pair); meshes with more pairs than this are smoothed densely instead.
PAIRS_PER_CHUNK = 1 << 20
#: Meshes smoothed densely at once by :meth:`SparseDomainVectors.sq_norms`.
DENSE_BATCH = 64


class SparseDomainVectors:
    """Domain vectors kept as their sparse BMU histograms: ``V = H @ B`` with ``B = diag(1/t) @ K``.

    ``K`` is the (symmetric, separable) Gaussian of :func:`domain_vectors` on the triangle map's
    grid and ``t`` its total per source unit, so row ``i`` of ``V`` is exactly mesh ``i``'s domain
    vector, but only ``H`` is stored: a mesh has at most as many non-zeros as triangles, so a
    city's ``V`` (meshes x 18,000 units, gigabytes) is a few megabytes here. Everything a batch
    SOM needs comes without forming ``V``:

    - ``V @ W.T = H @ (diag(1/t) @ K @ W.T)``: one smoothing of the k prototypes;
    - ``||v_i||^2 = sum_jk a_ij a_ik (K^2)_jk`` with ``a = H diag(1/t)`` and ``K^2`` separable
      (``(Kr @ Kr) x (Kc @ Kc)``), summed over the pairs of a mesh's non-zeros;
    - the sum of the ``v_i`` a unit wins: the sum of their histograms, smoothed once.

    Parameters
    ----------
    face_mesh : (F,) int
        Mesh of every triangle.
    units : (F,) int
        Triangle-map BMU of every triangle.
    n_meshes : int
    rows, cols : int
        The triangle map's size.
    sigma : float
        Radius in cells, > 0.
    topology : {"toroidal", "planar"}
    """

    def __init__(self, face_mesh, units, n_meshes: int, rows: int, cols: int, sigma: float,
                 topology: str = "toroidal"):
        from scipy import sparse

        _check_topology(topology)
        _check_grid(rows, cols)
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, received {sigma}")
        M = rows * cols
        face_mesh, units, totals = _check_bmus(face_mesh, units, n_meshes, M)
        counts = sparse.csr_matrix((np.ones(len(units)), (face_mesh, units)), shape=(n_meshes, M))
        self.rows, self.cols, self.sigma, self.topology = rows, cols, float(sigma), topology
        self.kernel_total = smooth(np.ones(M), sigma, rows, cols, topology)  # (M,) t
        # a = H diag(1/t): the histogram (divided by the triangle count) over the kernel totals
        self.a = sparse.csr_matrix(sparse.diags(1.0 / totals) @ counts @ sparse.diags(1.0 / self.kernel_total))
        self.a.sort_indices()

    @property
    def shape(self) -> tuple[int, int]:
        """(n_meshes, rows*cols)."""
        return self.a.shape

    def _smooth_rows(self, values: np.ndarray) -> np.ndarray:
        """``values @ K`` for (k, M) values (K symmetric: smoothing of every row)."""
        return smooth(np.asarray(values, np.float64).T, self.sigma, self.rows, self.cols, self.topology).T

    def dense(self, rows=None) -> np.ndarray:
        """Domain vectors of the given meshes (all: None), (k, M) float64, equal to :func:`domain_vectors`."""
        a = self.a if rows is None else self.a[np.asarray(rows, np.int64)]
        return self._smooth_rows(a.toarray())

    def dot(self, W) -> np.ndarray:
        """``V @ W.T`` for prototypes W (k, M): (n_meshes, k) float64.

        Identical prototypes (seeded samples drawn with replacement) get bitwise identical
        columns, so their exact ties go to the lowest unit as in the dense search.
        """
        unique, inverse = np.unique(np.asarray(W), axis=0, return_inverse=True)
        return np.asarray(self.a @ self._smooth_rows(unique).T)[:, inverse.ravel()]

    def group_sums(self, unit, n_units: int) -> np.ndarray:
        """Per unit, the sum of the domain vectors of the meshes it won: (n_units, M) float64."""
        from scipy import sparse

        unit = _int_array("unit", unit)
        onehot = sparse.csr_matrix((np.ones(len(unit)), (unit, np.arange(len(unit)))), shape=(n_units, len(unit)))
        return self._smooth_rows((onehot @ self.a).toarray())

    def apply(self, V) -> np.ndarray:
        """``domain_vectors @ V`` for (M, k) V: (n_meshes, k) float64."""
        return np.asarray(self.a @ smooth(np.asarray(V, np.float64), self.sigma, self.rows, self.cols, self.topology))

    def project(self, U) -> np.ndarray:
        """``domain_vectors.T @ U`` for (n_meshes, k) U: (M, k) float64."""
        return smooth(np.asarray(self.a.T @ np.asarray(U, np.float64)), self.sigma, self.rows, self.cols, self.topology)

    def gram(self, batch: int = 256) -> np.ndarray:
        """``V @ V.T`` of the domain vectors, (n_meshes, n_meshes) float64, in batches of meshes."""
        n = self.shape[0]
        out = np.empty((n, n))
        for a in range(0, n, batch):
            block = self.a[a:a + batch].toarray().T  # (M, b): the histograms over kernel totals
            twice = smooth(smooth(block, self.sigma, self.rows, self.cols, self.topology), self.sigma, self.rows,
                           self.cols, self.topology)
            out[:, a:a + batch] = np.asarray(self.a @ twice)
        return out

    def moments(self) -> dict:
        """:func:`meshsom.som.moments` of the domain vectors, (M, M) scatter: for small triangle maps."""
        n, M = self.shape
        ata = np.asarray((self.a.T @ self.a).toarray())
        gram = smooth(smooth(ata, self.sigma, self.rows, self.cols, self.topology).T, self.sigma, self.rows,
                      self.cols, self.topology)
        return {"n": n, "sum": self.project(np.ones((n, 1)))[:, 0], "gram": gram}

    def pca(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and principal axes of the domain vectors by :func:`meshsom.som.pca_by_shape`, the
        PCA of the in-memory path, without forming the vectors."""
        n, M = self.shape
        return pca_by_shape(n, M, moments=self.moments, gram=self.gram, project=self.project, apply=self.apply,
                            mean=lambda: self.project(np.ones((n, 1)))[:, 0] / n)

    def sq_norms(self) -> np.ndarray:
        """``||v_i||^2`` of every mesh, (n_meshes,) float64, without forming V.

        Meshes with more than ``sqrt(PAIRS_PER_CHUNK)`` non-zeros (large, detailed buildings) are
        smoothed densely one batch at a time instead of summed over their pairs.
        """
        kr = gaussian_kernel_1d(self.rows, self.sigma, self.topology)
        kc = gaussian_kernel_1d(self.cols, self.sigma, self.topology)
        kr2, kc2 = kr @ kr, kc @ kc
        indptr, indices, data = self.a.indptr, self.a.indices, self.a.data
        r, c = np.divmod(indices, self.cols)
        nnz = np.diff(indptr).astype(np.int64)
        out = np.zeros(len(nnz))
        heavy = np.flatnonzero(nnz**2 > PAIRS_PER_CHUNK)
        for start in range(0, len(heavy), DENSE_BATCH):
            batch = heavy[start:start + DENSE_BATCH]
            out[batch] = (self.dense(batch) ** 2).sum(axis=1)
        light = np.flatnonzero(nnz**2 <= PAIRS_PER_CHUNK)
        pairs = nnz[light] ** 2
        ends = np.cumsum(pairs)
        first = 0
        while first < len(light):  # chunks of meshes with at most PAIRS_PER_CHUNK pairs
            last = int(np.searchsorted(ends, ends[first] - pairs[first] + PAIRS_PER_CHUNK, side="right"))
            rows = light[first:last]
            n = nnz[rows]
            p = pairs[first:last]
            mesh = np.repeat(np.arange(len(rows)), p)
            k = np.arange(p.sum()) - np.repeat(np.cumsum(p) - p, p)  # pair number within its mesh
            width = np.repeat(n, p)
            i = indptr[rows][mesh] + k // width
            j = indptr[rows][mesh] + k % width
            val = data[i] * data[j] * kr2[r[i], r[j]] * kc2[c[i], c[j]]
            out[rows] = np.bincount(mesh, val, minlength=len(rows))
            first = last
        return out


def train_domain_map_sparse(vectors: SparseDomainVectors, rows: int, cols: int, epochs: int, seed: int,
                            sigma_start: float | None = None, sigma_end: float = 1.0, init: str = "pca",
                            topology: str = "toroidal") -> dict:
    """Batch-train a domain SOM on sparse domain vectors: :func:`meshsom.som.train_batch` with the
    initialisation of :class:`SOM` (:func:`meshsom.som.random_pick` rows, or the PCA of
    :meth:`SparseDomainVectors.pca`) and one variation, the search in float64, then a final search.

    Parameters
    ----------
    vectors : SparseDomainVectors
    rows, cols : int
        Domain map size.
    epochs : int
    seed : int
    sigma_start : float or None
        None: :func:`meshsom.som.default_sigma_start`.
    sigma_end : float
    init : {"pca", "random"}
    topology : {"toroidal", "planar"}

    Returns
    -------
    dict
        ``weights`` (rows*cols, M) float32, ``units`` (n_meshes,) int64 (final BMUs),
        ``q_error`` and ``t_error`` of the final search (tie rule of :mod:`meshsom.metrics`).
    """
    _check_topology(topology)
    _check_grid(rows, cols)
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, received {epochs}")
    n = vectors.shape[0]
    M = rows * cols
    if init == "random":
        W = vectors.dense(random_pick(n, M, seed)).astype(np.float32)
    elif init == "pca":
        W = pca_codebook(*vectors.pca(), rows, cols)
    else:
        raise ValueError(f"init must be one of {', '.join(INITS)}; received {init!r}")
    norms = vectors.sq_norms()
    sigma_start = float(sigma_start if sigma_start is not None else default_sigma_start(rows, cols))

    def search(W):
        """Best and second units, their squared distances, and the whole (n, k) distance matrix."""
        w64 = W.astype(np.float64)
        d = np.maximum(norms[:, None] - 2.0 * vectors.dot(W) + np.einsum("ij,ij->i", w64, w64), 0.0)
        unit = np.argmin(d, axis=1)
        rest = d.copy()
        rest[np.arange(n), unit] = np.inf
        second = np.argmin(rest, axis=1)
        return unit, second, d

    def step(W):
        unit, second, d = search(W)
        best = d[np.arange(n), unit]
        # tie rule: a neighbour of the best unit as close as the second-best unit (metrics.tied_with_neighbour)
        nbrs = neighbour_units(unit, rows, cols, topology)
        d_nbr = np.where(nbrs >= 0, d[np.arange(n)[:, None], np.maximum(nbrs, 0)], np.inf).min(axis=1)
        d_second = d[np.arange(n), second]
        scale = norms + np.einsum("ij,ij->i", W[second].astype(np.float64), W[second].astype(np.float64))
        tied = d_nbr <= d_second + TIE_RTOL * scale
        return {"sums": vectors.group_sums(unit, M), "counts": np.bincount(unit, minlength=M).astype(np.float64),
                "n": n, "t_bad": int(topographic_errors(unit, second, rows, cols, topology, tied=tied).sum()),
                "q_sum": float(np.sqrt(best).sum()), "qc_sum": float("nan"), "unit": unit}

    W = train_batch(W, step, rows, cols, epochs, sigma_start, sigma_end, topology)
    final = step(W)
    return {"weights": W, "units": final["unit"].astype(np.int64),
            "q_error": final["q_sum"] / n, "t_error": final["t_bad"] / n}


# ---------------------------------------------------------------------- clustering quality
#: k-means restarts of :func:`map_regions` (the best of them is kept).
KMEANS_RESTARTS = 4

#: Nearest meshes on the map whose labels :func:`knn_label_agreement` compares (the pipeline's and the reports' k).
KNN = 5


def knn_label_agreement(units, labels, rows: int, cols: int, k: int = KNN, topology: str = "toroidal") -> float:
    """Mean share of each mesh's ``k`` nearest other meshes on the map that share its label.

    Nearness is the grid distance between the meshes' units (DESIGN.md §4, wrapped on a
    torus); meshes on the same unit are at distance 0. Ties are broken by mesh index (the
    lower first), so the result is deterministic.

    Parameters
    ----------
    units : (n,) int
        Unit of every mesh (:func:`place`).
    labels : (n,) any
        Label of every mesh (e.g. family names).
    rows, cols : int
        Map size.
    k : int
        ``1 <= k <= n - 1``.
    topology : {"toroidal", "planar"}

    Returns
    -------
    float
        In [0, 1]; compare with :func:`label_agreement_chance`.
    """
    _check_topology(topology)
    _check_grid(rows, cols)
    units = _int_array("units", units)
    labels = np.asarray(labels)
    n = len(units)
    if labels.shape != (n,):
        raise ValueError(f"labels must have shape ({n},) like units, received {labels.shape}")
    if not 1 <= k <= n - 1:
        raise ValueError(f"k must lie in 1..{n - 1} for {n} meshes, received {k}")
    if n and (units.min() < 0 or units.max() >= rows * cols):
        raise ValueError(f"units must lie in 0..{rows * cols - 1}, received {units.min()}..{units.max()}")
    d = grid_distance(units[:, None], units[None, :], rows, cols, topology)  # (n, n)
    np.fill_diagonal(d, np.inf)
    nearest = np.argsort(d, axis=1, kind="stable")[:, :k]  # stable: ties by mesh index
    _, codes = np.unique(labels, return_inverse=True)
    return float(np.mean(codes[nearest] == codes[:, None]))


def label_agreement_chance(labels) -> float:
    """Expected :func:`knn_label_agreement` when meshes are placed at random.

    A random other mesh shares mesh ``i``'s label with probability
    ``(n_label(i) - 1) / (n - 1)``; this is that probability averaged over meshes.

    Parameters
    ----------
    labels : (n,) any, n >= 2

    Returns
    -------
    float
    """
    labels = np.asarray(labels)
    n = len(labels)
    if labels.ndim != 1 or n < 2:
        raise ValueError(f"labels must be a 1-D array of at least 2 entries, received shape {labels.shape}")
    _, codes, sizes = np.unique(labels, return_inverse=True, return_counts=True)
    return float(np.mean((sizes[codes] - 1) / (n - 1)))


def map_regions(som_weights, rows: int, cols: int, n_regions: int, seed: int) -> np.ndarray:
    """Cut the domain map into regions: k-means on its prototypes.

    A mesh's region is its unit's: ``map_regions(...)[place(vectors, som)]``, to be compared
    with the labels by ``sklearn.metrics.adjusted_rand_score``.

    Parameters
    ----------
    som_weights : (rows*cols, D) float
        Domain prototypes (``SOM.weights_``).
    rows, cols : int
    n_regions : int
        ``1 <= n_regions <= rows*cols``.
    seed : int

    Returns
    -------
    (rows*cols,) int64
        Region of every unit, in ``0..n_regions-1``.
    """
    _check_grid(rows, cols)
    W = np.asarray(som_weights)
    if W.ndim != 2 or len(W) != rows * cols:
        raise ValueError(f"som_weights must have shape ({rows * cols}, D) for a {rows} x {cols} map, "
                         f"received {W.shape}")
    if not 1 <= n_regions <= len(W):
        raise ValueError(f"n_regions must lie in 1..{len(W)}, received {n_regions}")
    from sklearn.cluster import KMeans

    km = KMeans(n_clusters=n_regions, n_init=KMEANS_RESTARTS, random_state=seed).fit(np.asarray(W, np.float64))
    return km.labels_.astype(np.int64)
