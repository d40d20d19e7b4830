"""Map geometry and quality measures: grid distances, T-, Q- and QC-errors, U-matrix.

The T-error's tie rule: a vector's second-best unit is not always unique. Units whose prototypes
are equal (bitwise, or up to float32 rounding: batch training on many identical ring vectors, such
as a corpus of extruded blocks, flattens whole regions of the map onto one prototype) are equally
far from every vector, and which of them the search reports as "second" is an accident of unit
numbering and rounding. A vector therefore counts as a topographic error only when *no* unit tied
for second place is a grid neighbour of its best unit: :func:`tied_with_neighbour` checks whether
some neighbour of the BMU lies within ``TIE_RTOL * (||x||^2 + ||w||^2)`` of the second-best
distance (distances recomputed in float64 for the few vectors whose reported second is not a
neighbour). Without ties the rule is Kohonen's T-error unchanged.

Units are numbered row-major: unit ``j`` sits at row ``j // cols``, column ``j % cols``
(the order of ``weights_.reshape(rows, cols, D)``, and of MiniSom's ``_weights``).
On a toroidal map the row and column offsets wrap: ``min(|dr|, rows - |dr|)``.
"""

from __future__ import annotations

import numpy as np

from meshsom.bmu_numpy import BMUResult, varied

TOPOLOGIES = ("toroidal", "planar")
#: Neighbourhoods on the rectangular grid: 8 (king moves) or 4 (rook moves).
NEIGHBOURHOODS = {
    8: np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)], np.int64),
    4: np.array([(-1, 0), (0, -1), (0, 1), (1, 0)], np.int64),
}
#: Values per fold component (alpha, u, v) for the QC-error.
COMPONENT = 3
#: Two squared distances tie when they differ by at most this share of ``||x||^2 + ||w||^2``
#: (about 8 float32 rounding steps of the distance's terms).
TIE_RTOL = 1e-6


def _check_topology(topology: str) -> None:
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology must be one of {', '.join(TOPOLOGIES)}; received {topology!r}")


def _check_neighbourhood(neighbourhood: int) -> np.ndarray:
    if neighbourhood not in NEIGHBOURHOODS:
        raise ValueError(f"neighbourhood must be one of {sorted(NEIGHBOURHOODS)}; received {neighbourhood!r}")
    return NEIGHBOURHOODS[neighbourhood]


def grid_coords(rows: int, cols: int) -> np.ndarray:
    """Row and column of every unit.

    Returns
    -------
    (rows*cols, 2) int64
    """
    r, c = np.divmod(np.arange(rows * cols, dtype=np.int64), cols)
    return np.stack([r, c], axis=1)


def grid_offsets(a, b, rows: int, cols: int, topology: str = "toroidal") -> tuple[np.ndarray, np.ndarray]:
    """Absolute row and column offsets between units ``a`` and ``b`` (wrapped on a torus).

    Parameters
    ----------
    a, b : (...) int
        Unit numbers (broadcast against each other).

    Returns
    -------
    dr, dc : (...) int64
    """
    _check_topology(topology)
    ra, ca = np.divmod(np.asarray(a, np.int64), cols)
    rb, cb = np.divmod(np.asarray(b, np.int64), cols)
    dr = np.abs(ra - rb)
    dc = np.abs(ca - cb)
    if topology == "toroidal":
        dr = np.minimum(dr, rows - dr)
        dc = np.minimum(dc, cols - dc)
    return dr, dc


def grid_distance(a, b, rows: int, cols: int, topology: str = "toroidal") -> np.ndarray:
    """Euclidean cell distance ``sqrt(dr^2 + dc^2)`` between units (DESIGN.md §4).

    Returns
    -------
    (...) float64
    """
    dr, dc = grid_offsets(a, b, rows, cols, topology)
    return np.hypot(dr, dc)


def are_neighbours(a, b, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8) -> np.ndarray:
    """Whether units ``a`` and ``b`` are distinct grid neighbours.

    Returns
    -------
    (...) bool
    """
    _check_neighbourhood(neighbourhood)
    dr, dc = grid_offsets(a, b, rows, cols, topology)
    step = np.maximum(dr, dc) if neighbourhood == 8 else dr + dc
    return step == 1


def t_error(unit, second, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8,
            tied=None) -> float:
    """Topographic error: share of vectors whose best and second-best units are not neighbours.

    Parameters
    ----------
    unit, second : (N,) int
    neighbourhood : {8, 4}
    tied : (N,) bool or None
        Vectors whose second place is shared by a neighbour of their best unit
        (:func:`tied_with_neighbour`); they do not count as errors. None: no ties.

    Returns
    -------
    float
    """
    unit = np.asarray(unit)
    if len(unit) == 0:
        raise ValueError("t_error needs at least one vector, received 0")
    return float(np.mean(topographic_errors(unit, second, rows, cols, topology, neighbourhood, tied)))


def topographic_errors(unit, second, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8,
                       tied=None) -> np.ndarray:
    """Per vector, whether it is a topographic error (see :func:`t_error`).

    Returns
    -------
    (N,) bool
    """
    bad = ~are_neighbours(unit, second, rows, cols, topology, neighbourhood)
    return bad if tied is None else bad & ~np.asarray(tied, bool)


def neighbour_units(unit, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8) -> np.ndarray:
    """The grid neighbours of every unit.

    Parameters
    ----------
    unit : (N,) int

    Returns
    -------
    (N, k) int64
        ``k`` = 8 or 4; -1 where a planar map has no neighbour (edges and corners).
    """
    steps = _check_neighbourhood(neighbourhood)
    _check_topology(topology)
    r, c = np.divmod(np.asarray(unit, np.int64), cols)
    nr = r[:, None] + steps[None, :, 0]
    nc = c[:, None] + steps[None, :, 1]
    if topology == "toroidal":
        return (nr % rows) * cols + nc % cols
    inside = (nr >= 0) & (nr < rows) & (nc >= 0) & (nc < cols)
    return np.where(inside, nr * cols + nc, -1)


def dist2_to(xv, W, units) -> np.ndarray:
    """``||xv_i - w_u||^2`` for given units of every (varied) vector, exactly in float64.

    Parameters
    ----------
    xv : (N, D) float
        Vectors in their winning variation (:func:`meshsom.bmu_numpy.varied`).
    W : (M, D) float
    units : (N, k) int
        -1: no unit (gives +inf).

    Returns
    -------
    (N, k) float64
    """
    xv = np.asarray(xv, np.float64)
    W = np.asarray(W, np.float64)
    units = np.asarray(units, np.int64)
    out = np.full(units.shape, np.inf)
    for k in range(units.shape[1]):
        ok = units[:, k] >= 0
        diff = xv[ok] - W[units[ok, k]]
        out[ok, k] = np.einsum("ij,ij->i", diff, diff)
    return out


def tied_with_neighbour(X, W, bmu: BMUResult, rows: int, cols: int, topology: str = "toroidal", index=None,
                        sign=None, neighbourhood: int = 8, tie_rtol: float = TIE_RTOL) -> np.ndarray:
    """Per vector, whether a grid neighbour of its best unit ties with its second-best unit.

    Only vectors whose reported second-best unit is not a neighbour are examined (the rest are
    not topographic errors anyway); for them the distances to the second-best unit and to every
    neighbour of the best unit are recomputed exactly (float64), in the vector's winning
    variation as the search ranks its second-best unit.

    Parameters
    ----------
    X : (N, D) float
    W : (M, D) float
    bmu : BMUResult
    index, sign : (n, D) or None
        The variation table the BMUs were found with.
    tie_rtol : float
        Ties: ``d(neighbour) <= d(second) + tie_rtol * (||x||^2 + ||w_second||^2)``.

    Returns
    -------
    (N,) bool
    """
    unit, second = np.asarray(bmu.unit, np.int64), np.asarray(bmu.second, np.int64)
    out = np.zeros(len(unit), bool)
    look = np.flatnonzero(~are_neighbours(unit, second, rows, cols, topology, neighbourhood) & (second >= 0))
    if len(look) == 0:
        return out
    X = np.asarray(X)[look]
    W = np.asarray(W)
    xv = winning_vectors(X, np.asarray(bmu.variation)[look], index, sign)
    d_second = dist2_to(xv, W, second[look, None])[:, 0]
    d_nbr = dist2_to(xv, W, neighbour_units(unit[look], rows, cols, topology, neighbourhood)).min(axis=1)
    w64 = W[second[look]].astype(np.float64)
    scale = np.einsum("ij,ij->i", xv, xv) + np.einsum("ij,ij->i", w64, w64)
    out[look] = d_nbr <= d_second + tie_rtol * scale
    return out


def tie_ruled_errors(X, W, bmu: BMUResult, rows: int, cols: int, topology: str = "toroidal", index=None, sign=None,
                     neighbourhood: int = 8) -> np.ndarray:
    """Per vector, whether it is a topographic error under the tie rule: :func:`topographic_errors`
    with :func:`tied_with_neighbour` (the host's reference of the OpenCL ``topographic_errors`` kernel).

    Returns
    -------
    (N,) bool
    """
    tied = tied_with_neighbour(X, W, bmu, rows, cols, topology, index, sign, neighbourhood)
    return topographic_errors(bmu.unit, bmu.second, rows, cols, topology, neighbourhood, tied)


def error_sums(X, W, bmu: BMUResult, rows: int, cols: int, topology: str = "toroidal", index=None, sign=None,
               neighbourhood: int = 8, component: int = COMPONENT, distances=None, bad=None) -> dict:
    """The sums behind the T-, Q- and QC-errors of one block of vectors (add blocks, divide by ``n``).

    Parameters
    ----------
    distances : (q, qc) of (N,) float64, or None
        The per-row distances of :func:`row_errors` where they were taken already (on an OpenCL
        device: :meth:`meshsom.bmu.Engine.row_errors`); None: computed here.
    bad : (N,) bool or None
        The per-row topographic errors (:func:`tie_ruled_errors`) where they were
        taken already (:meth:`meshsom.bmu.Engine.topographic_errors`); None: computed here.

    Returns
    -------
    dict
        ``n``; ``t_bad`` (topographic errors, tie rule included); ``q_sum`` (sum of the BMU
        distances ``||P_v* x - w_bmu||``); ``qc_sum`` (sum over vectors of the mean distance per
        ``component``-value slice; NaN when D is not a multiple of ``component``).
    """
    q, qc = distances if distances is not None else row_errors(X, W, bmu, index, sign, component)
    if bad is None:
        bad = tie_ruled_errors(X, W, bmu, rows, cols, topology, index, sign, neighbourhood)
    return {
        "n": int(len(q)),
        "t_bad": int(np.count_nonzero(bad)),
        "q_sum": float(q.sum()),
        "qc_sum": float(qc.sum()),
    }


def errors_of(sums: dict) -> dict:
    """T-, Q- and QC-errors from summed :func:`error_sums`.

    Returns
    -------
    dict
        ``t_error``, ``q_error``, ``qc_error``.
    """
    n = sums["n"]
    if n == 0:
        raise ValueError("errors need at least one vector, received 0")
    return {"t_error": sums["t_bad"] / n, "q_error": sums["q_sum"] / n, "qc_error": sums["qc_sum"] / n}


#: Rows per block of :func:`row_errors`: bounds its float64 temporaries to this many rows x D.
ROW_ERRORS_BLOCK = 16384


def row_errors(X, W, bmu: BMUResult, index=None, sign=None, component: int = COMPONENT
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per vector, its Q-error distance and its QC-error distance.

    With the residual ``d = P_v* x - w_bmu`` in float64: ``q = ||d||``, its squares added in
    dimension order from 0; ``qc`` the mean over the ``D / component`` consecutive slices of the
    slice norms (squares added in order within a slice, norms added in slice order), NaN when
    ``component`` does not divide D. This order is the one the OpenCL ``row_errors`` kernel
    (``kernels/epoch_sums.cl``) follows, so both agree to rounding (a device may fuse a square
    and its add).

    Parameters
    ----------
    X : (N, D) float
    W : (M, D) float
    bmu : BMUResult
    index, sign : (n, D) or None
        The variation table (None: identity).
    component : int

    Returns
    -------
    q, qc : (N,) float64
    """
    X = np.asarray(X)
    N, D = X.shape
    W = np.asarray(W, np.float64)
    q = np.empty(N)
    qc = np.full(N, np.nan)
    slices = D // component if D % component == 0 else 0
    for start in range(0, N, ROW_ERRORS_BLOCK):
        stop = min(N, start + ROW_ERRORS_BLOCK)
        squares = np.ascontiguousarray(residuals(X[start:stop], W, bmu.rows(start, stop), index, sign).T)
        squares *= squares  # (D, rows)
        total = np.zeros(stop - start)
        for k in range(D):
            total += squares[k]
        q[start:stop] = np.sqrt(total)
        if slices:
            norms = np.zeros(stop - start)
            for j in range(slices):
                part = np.zeros(stop - start)
                for k in range(j * component, (j + 1) * component):
                    part += squares[k]
                norms += np.sqrt(part)
            qc[start:stop] = norms / slices
    return q, qc


def residuals(X, W, bmu: BMUResult, index=None, sign=None) -> np.ndarray:
    """``P_v* x - w_bmu`` for every vector (v* its winning variation), in float64.

    Parameters
    ----------
    X : (N, D) float
    W : (M, D) float
    bmu : BMUResult
    index, sign : (n, D) or None
        The variation table the BMUs were found with (None: identity).

    Returns
    -------
    (N, D) float64
    """
    return winning_vectors(X, bmu.variation, index, sign) - np.asarray(W, np.float64)[bmu.unit]


def winning_vectors(X, variation, index=None, sign=None) -> np.ndarray:
    """``P_v x`` of every vector in its winning variation ``v``, in float64.

    Parameters
    ----------
    X : (N, D) float
    variation : (N,) int
    index, sign : (n, D) or None
        The variation table (None: identity; ``variation`` is then ignored).

    Returns
    -------
    (N, D) float64
    """
    X = np.asarray(X)
    if index is None:
        return X.astype(np.float64)
    return varied(X, np.asarray(index, np.int64), np.asarray(sign, X.dtype), variation).astype(np.float64)


def q_error(X, W, bmu: BMUResult, index=None, sign=None) -> float:
    """Quantization error: mean ``||P_v* x - w_bmu||``.

    Parameters
    ----------
    X : (N, D) float
    W : (M, D) float
    bmu : BMUResult
    index, sign : (n, D) or None
        The variation table (None: identity).
    """
    return float(np.mean(row_errors(X, W, bmu, index, sign)[0]))


def qc_error(X, W, bmu: BMUResult, index=None, sign=None, component: int = COMPONENT) -> float:
    """Component quantization error: the Q-error distance per ``component``-value slice.

    The residual ``P_v* x - w_bmu`` is cut into ``D / component`` consecutive slices; the
    Euclidean norm of each slice is averaged over slices and vectors.

    Raises
    ------
    ValueError
        ``D`` is not a multiple of ``component``.
    """
    D = np.shape(X)[1]
    if D % component:
        raise ValueError(f"QC-error needs D divisible by {component}, received D = {D}")
    return float(np.mean(row_errors(X, W, bmu, index, sign, component)[1]))


def u_matrix(W, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8) -> np.ndarray:
    """Mean Euclidean distance of each prototype to its grid neighbours.

    On a planar map the border units average over the neighbours they have.

    Parameters
    ----------
    W : (rows*cols, D) float

    Returns
    -------
    (rows, cols) float64
    """
    _check_topology(topology)
    offsets = _check_neighbourhood(neighbourhood)
    W = np.asarray(W, np.float64)
    if W.ndim != 2 or len(W) != rows * cols:
        raise ValueError(f"W must have shape ({rows * cols}, D) for a {rows} x {cols} map, received {W.shape}")
    grid = W.reshape(rows, cols, -1)
    total = np.zeros((rows, cols))
    count = np.zeros((rows, cols))
    r = np.arange(rows)[:, None]
    c = np.arange(cols)[None, :]
    for dr, dc in offsets:  # 4 or 8 whole-map shifts
        rr, cc = r + dr, c + dc
        if topology == "toroidal":
            valid = np.ones((rows, cols), bool)
            rr, cc = rr % rows, cc % cols
        else:
            valid = ((rr >= 0) & (rr < rows)) & ((cc >= 0) & (cc < cols))
            rr, cc = np.clip(rr, 0, rows - 1), np.clip(cc, 0, cols - 1)
        rr, cc = np.broadcast_to(rr, (rows, cols)), np.broadcast_to(cc, (rows, cols))
        diff = grid - grid[rr, cc]
        total += np.where(valid, np.sqrt(np.einsum("ijk,ijk->ij", diff, diff)), 0.0)
        count += valid
    return total / np.maximum(count, 1)
