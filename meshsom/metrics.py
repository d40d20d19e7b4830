"""Map geometry and quality measures: grid distances, T-, Q- and QC-errors, U-matrix.

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


def t_error(unit, second, rows: int, cols: int, topology: str = "toroidal", neighbourhood: int = 8) -> float:
    """Topographic error: share of vectors whose best and second-best units are not neighbours.

    Parameters
    ----------
    unit, second : (N,) int
    neighbourhood : {8, 4}

    Returns
    -------
    float
    """
    unit = np.asarray(unit)
    if len(unit) == 0:
        raise ValueError("t_error needs at least one vector, received 0")
    return float(np.mean(~are_neighbours(unit, second, rows, cols, topology, neighbourhood)))


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
    X = np.asarray(X)
    if index is None:
        xv = X.astype(np.float64)
    else:
        xv = varied(X, np.asarray(index, np.int64), np.asarray(sign, X.dtype), bmu.variation).astype(np.float64)
    return xv - np.asarray(W, np.float64)[bmu.unit]


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
    res = residuals(X, W, bmu, index, sign)
    return float(np.mean(np.sqrt(np.einsum("ij,ij->i", res, res))))


def qc_error(X, W, bmu: BMUResult, index=None, sign=None, component: int = COMPONENT) -> float:
    """Component quantization error: the Q-error distance per ``component``-value slice.

    The residual ``P_v* x - w_bmu`` is cut into ``D / component`` consecutive slices; the
    Euclidean norm of each slice is averaged over slices and vectors.

    Raises
    ------
    ValueError
        ``D`` is not a multiple of ``component``.
    """
    res = residuals(X, W, bmu, index, sign)
    N, D = res.shape
    if D % component:
        raise ValueError(f"QC-error needs D divisible by {component}, received D = {D}")
    parts = res.reshape(N, D // component, component)
    return float(np.mean(np.sqrt(np.einsum("ijk,ijk->ij", parts, parts))))


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
