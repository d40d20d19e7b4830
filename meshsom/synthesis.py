"""Synthesis: decode ring vectors back into triangle patches, with or without leveling (DESIGN.md §3).

A level-L vector holds the folds of its walk's slots (:mod:`meshsom.rings`). Unfolding places the
root, then every leaf from its fold, slot by slot in walk order:

- the root's edge 0 runs from (0, 0, 0) to (1, 0, 0) in the plane z = 0 (normal +z); its apex
  comes from the back-fold ``f(s_0, back)`` (level >= 2: where the root's apex sits seen from
  its first leaf); a level-1 vector says nothing of the root's shape, so the root is equilateral;
- the leaf across edge ``e`` of a placed face gets its apex from the fold ``(alpha, u, v)``
  (:func:`meshsom.folds.apex_of_fold`); its own edge 0 is the shared edge, walked back.

The patch of a level has a fixed topology (:func:`patch_topology`): ``3 * 2**L - 2`` faces, the
root's three vertices plus one apex per further face. Unfolding reads only the first copy of every
fold (``level_by="none"``).

A vector holds many entries that a patch ties together: a level-3 ring repeats folds of its 10
slots in 16 one-rings, the dihedral angle of an edge appears from both of its sides, and a face's
shape is seen from its parent and from each of its children. The copies of a fold inside one ring
vector, or one SOM prototype, are always equal, so averaging them changes nothing; what disagrees in
a trained prototype is the geometry that the entries imply. Leveling (``level_by="lsq"``) is least
squares over that redundancy: the patch's vertex positions that minimise the squared difference
between the patch's own encoding and every entry of the vector, angles compared on the circle and
each component weighted by ``1 / std`` of the standardization (so the objective is the squared
Euclidean distance of standardized vectors), started from the unfolding. It is a Levenberg-Marquardt
fit run on whole arrays over a batch of vectors (:func:`level_patches`): a dense Jacobian per vector
from central differences of every fold over its four vertices, a damped normal-equation step per
vector, a step kept only where it lowers that vector's cost. The gauge (similarity) is fixed by the
unfolding's frame: the root's first two vertices and the z of its apex stay put. The fit is
deterministic.

The re-translation error (:mod:`reports.fig10`) compares the re-encoding of a synthesized patch
(:func:`encode_patches`) with a vector, per fold entry (:func:`entry_deviation`) and per ring depth
(:func:`entry_depth`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from meshsom.folds import apex_of_fold, fold_of_apex, folds
from meshsom.rings import encode_level, template
from meshsom.topology import Adjacency

__all__ = [
    "LEVEL_BY", "LSQ_MAX_ITER", "LSQ_FTOL", "V_MIN", "Patch", "PatchTopology", "clip_v", "decode",
    "encode_patches", "entry_depth", "entry_deviation", "level_patches", "nearest_mapped", "patch_topology",
    "qc_distance",
    "reencode", "retranslation_error", "synthesize", "unfold", "write_patch",
]

#: Leveling methods: ``none`` unfolds from the first copy of every fold, ``lsq`` fits the patch to all.
LEVEL_BY = ("none", "lsq")
#: Smallest ``v`` (apex distance from its edge, in edge lengths) synthesized; trained prototypes can
#: fall below it, and an apex on its edge line has no dihedral angle.
V_MIN = 1e-3
#: Levenberg-Marquardt iterations at most.
LSQ_MAX_ITER = 60
#: A vector's fit stops when an accepted step lowers its cost by less than this fraction.
LSQ_FTOL = 1e-10
#: Initial damping, and the factors it is multiplied by after a kept / a refused step.
LSQ_LAMBDA0 = 1e-3
LSQ_LAMBDA_DOWN = 0.3
LSQ_LAMBDA_UP = 10.0
#: Damping beyond which a vector's fit stops (no step lowers its cost any more).
LSQ_LAMBDA_MAX = 1e12
#: Added to the diagonal of the damping term, so that coordinates no entry sees stay put.
LSQ_DIAG_FLOOR = 1e-9
#: Central-difference step (in root-edge lengths: the root's edge 0 has length 1).
LSQ_FD_STEP = 1e-6
#: Vectors fitted together (memory: about ``batch * 3 * D * 3 * P`` float64 for the Jacobian).
LSQ_BATCH = 256
#: Coordinates fixed by the gauge: the root's vertices 0 and 1 and the z of its apex (vertex 2).
GAUGE = (0, 1, 2, 3, 4, 5, 8)


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


@dataclass(frozen=True)
class PatchTopology:
    """The fixed topology of a level's patch and where every entry of a vector comes from.

    Attributes
    ----------
    level : int
    faces : (S, 3) int64
        Face ``i`` is ``slots[i]``; the root first; a leaf's edge 0 is the edge shared with its parent.
    slots : tuple of tuple of int
    adjacency : Adjacency
    place : (P - 3, 4) int64
        How unfolding places vertex ``3 + j``: ``(face, edge, key, unused)``: across ``edge`` of
        ``face`` with the fold of key ``key``.
    corners : (K, 4) int64
        Per distinct fold (key): the vertices ``p, q`` of its edge, the third vertex of its face (for
        the normal) and the apex of the neighbour.
    ref_key : (R,) int64
        Key of every fold entry of the vector, ``R = dims / 3``.
    key_depth : (K,) int64
        Depth of the face a fold belongs to (0: the root, 1: the first ring, ...).
    root_back : int
        Key of the back-fold ``f(s_0, back)`` that shapes the root; -1 at level 1 (none).
    """

    level: int
    faces: np.ndarray
    slots: tuple
    adjacency: Adjacency
    place: np.ndarray
    corners: np.ndarray
    ref_key: np.ndarray
    key_depth: np.ndarray
    root_back: int

    @property
    def n_vertices(self) -> int:
        return 3 + len(self.place)


@lru_cache(maxsize=None)
def patch_topology(level: int) -> PatchTopology:
    """The (cached) patch topology of a level (see :class:`PatchTopology`)."""
    tpl = template(level)
    keys = list(zip(tpl.slots_of_refs(), tpl.ref_edge.tolist()))
    key_id: dict = {}
    ref_key = np.array([key_id.setdefault(k, len(key_id)) for k in keys], np.int64)
    faces = [[0, 1, 2]]
    index = {(): 0}
    slots = [()]
    place, links = [], []  # links: (parent face, parent edge, child face)
    for slot in sorted(tpl.slots, key=len):
        fi = index[slot]
        tri = faces[fi]
        for e in range(3):
            child = slot + (e,)
            if (slot and e == 0) or (slot, e) not in key_id or child in index:
                continue
            vi = 3 + len(place)
            place.append((fi, e, key_id[(slot, e)], 0))
            ci = len(faces)
            faces.append([tri[(e + 1) % 3], tri[e], vi])  # (q, p, r): edge 0 walks back
            index[child] = ci
            slots.append(child)
            links.append((fi, e, ci))
    nb = np.zeros((len(faces), 3), np.int64)
    bk = np.zeros((len(faces), 3), np.int64)
    parent = {}
    for fi, e, ci in links:
        nb[fi, e], bk[fi, e] = ci, 0
        nb[ci, 0], bk[ci, 0] = fi, e
        parent[ci] = (fi, e)
    corners = np.zeros((len(key_id), 4), np.int64)
    depth = np.zeros(len(key_id), np.int64)
    for (slot, e), k in key_id.items():
        fi = index[slot]
        tri = faces[fi]
        if slot and e == 0:
            pf, pe = parent[fi]
            apex = faces[pf][(pe + 2) % 3]  # the parent's vertex off the shared edge
        else:
            apex = faces[index[slot + (e,)]][2]
        corners[k] = (tri[e], tri[(e + 1) % 3], tri[(e + 2) % 3], apex)
        depth[k] = len(slot)
    return PatchTopology(int(level), np.array(faces, np.int64), tuple(slots), Adjacency(nb, bk),
                         np.array(place, np.int64).reshape(-1, 4), corners, ref_key, depth,
                         key_id.get(((0,), 0), -1))


def entry_depth(level: int) -> np.ndarray:
    """Ring depth of every fold entry of a level's vector: that of the face the fold belongs to.

    Returns
    -------
    depth : (dims / 3,) int64
        0 for the root's folds, 1 for the first ring's, ... up to ``level - 1``.
    """
    topo = patch_topology(level)
    return topo.key_depth[topo.ref_key]


def _check(X: np.ndarray, level: int) -> np.ndarray:
    X = np.asarray(X, np.float64)
    dims = template(level).dims
    if X.ndim != 2 or X.shape[1] != dims:
        raise ValueError(f"level-{level} vectors have {dims} values; received an array of shape {X.shape}")
    return X


def clip_v(X: np.ndarray, v_min: float = V_MIN) -> np.ndarray:
    """Raw vectors with every ``v`` entry raised to at least ``v_min`` (a copy).

    Parameters
    ----------
    X : (..., D) float
    v_min : float

    Returns
    -------
    (..., D) float64
    """
    X = np.array(X, np.float64)
    X[..., 2::3] = np.maximum(X[..., 2::3], v_min)
    return X


def unfold(X: np.ndarray, level: int) -> np.ndarray:
    """Vertices of the patches unfolded from the first copy of every fold (no leveling).

    Parameters
    ----------
    X : (B, D) float
        Raw (de-standardized) level-``level`` vectors; ``v`` entries must be > 0.
    level : int

    Returns
    -------
    vertices : (B, P, 3) float64
        Faces: ``patch_topology(level).faces``.
    """
    X = _check(X, level)
    topo = patch_topology(level)
    F = X.reshape(len(X), -1, 3)
    first = np.full(len(topo.corners), -1, np.int64)
    for r in range(len(topo.ref_key) - 1, -1, -1):  # first reference of every key
        first[topo.ref_key[r]] = r
    V = np.zeros((len(X), topo.n_vertices, 3))
    V[:, 1, 0] = 1.0
    if topo.root_back < 0:
        V[:, 2] = [0.5, np.sqrt(3.0) / 2.0, 0.0]
    else:
        back = F[:, first[topo.root_back]]
        V[:, 2, 0] = 0.5 - back[:, 1]  # the back edge runs (1,0,0) -> (0,0,0); into the root is +y
        V[:, 2, 1] = back[:, 2]
    for j, (fi, e, k, _) in enumerate(topo.place):
        tri = topo.faces[fi]
        p, q, t = V[:, tri[e]], V[:, tri[(e + 1) % 3]], V[:, tri[(e + 2) % 3]]
        n = np.cross(q - p, t - p)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        V[:, 3 + j] = apex_of_fold(p, q, n, F[:, first[k]])
    return V


def _corner_folds(Q: np.ndarray) -> np.ndarray:
    """Folds from corners ``Q[..., (p, q, t, r), :]``: edge ``p -> q`` of face ``(p, q, t)``, apex ``r``.

    Parameters
    ----------
    Q : (..., 4, 3) float64

    Returns
    -------
    (..., 3) float64
    """
    p, q, t, r = Q[..., 0, :], Q[..., 1, :], Q[..., 2, :], Q[..., 3, :]
    n = np.cross(q - p, t - p)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return fold_of_apex(p, q, n, r)


def encode_patches(V: np.ndarray, level: int) -> np.ndarray:
    """Ring vectors (start leaf 0) of patches of a level's topology, vectorised.

    Parameters
    ----------
    V : (B, P, 3) float64
        Vertices; faces ``patch_topology(level).faces``.
    level : int

    Returns
    -------
    X : (B, D) float64
        Equal to :func:`reencode` of every patch.
    """
    topo = patch_topology(level)
    V = np.asarray(V, np.float64)
    kf = _corner_folds(V[:, topo.corners])  # (B, K, 3)
    return kf[:, topo.ref_key].reshape(len(V), -1)


def _weights(stats) -> np.ndarray:
    if stats is None:
        return np.ones(3)
    from meshsom.standardize import Stats

    return 1.0 / (stats if isinstance(stats, Stats) else Stats.from_dict(stats)).std


def _wrap(d: np.ndarray) -> np.ndarray:
    """Angle differences into [-pi, pi)."""
    return np.mod(d + np.pi, 2.0 * np.pi) - np.pi


def _residuals(kf: np.ndarray, T: np.ndarray, ref_key: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted differences (B, R, 3) of key folds ``kf`` (B, K, 3) from targets ``T`` (B, R, 3)."""
    d = kf[:, ref_key] - T
    d[..., 0] = _wrap(d[..., 0])
    return d * w


def _jacobian(V: np.ndarray, topo: PatchTopology, w: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Jacobian (B, 3R, n_free) of the weighted residuals over the free coordinates (central differences)."""
    B, P = V.shape[:2]
    Q = V[:, topo.corners]  # (B, K, 4, 3)
    E = (LSQ_FD_STEP * np.eye(12)).reshape(12, 4, 3)
    plus = _corner_folds(Q[:, :, None] + E)  # (B, K, 12, 3)
    minus = _corner_folds(Q[:, :, None] - E)
    dk = plus - minus
    dk[..., 0] = _wrap(dk[..., 0])
    dk /= 2.0 * LSQ_FD_STEP
    R = len(topo.ref_key)
    dr = np.swapaxes(dk[:, topo.ref_key], 2, 3) * w[:, None]  # (B, R, 3, 12)
    rows = np.broadcast_to(np.arange(3 * R).reshape(R, 3, 1), (R, 3, 12))
    cols = np.broadcast_to((3 * topo.corners[topo.ref_key][:, :, None] + np.arange(3)).reshape(R, 1, 12), (R, 3, 12))
    J = np.zeros((B, 3 * R, 3 * P))
    J[:, rows.reshape(-1), cols.reshape(-1)] = dr.reshape(B, -1)
    return J[:, :, free]


def _fit_batch(V: np.ndarray, T: np.ndarray, topo: PatchTopology, w: np.ndarray, max_iter: int) -> tuple:
    B, P = V.shape[:2]
    free = np.setdiff1d(np.arange(3 * P), GAUGE)

    def cost_of(Vb, Tb):
        r = _residuals(_corner_folds(Vb[:, topo.corners]), Tb, topo.ref_key, w)
        c = 0.5 * np.einsum("brc,brc->b", r, r)
        return r.reshape(len(Vb), -1), np.where(np.isfinite(c), c, np.inf)

    r, cost = cost_of(V, T)
    start_cost = cost.copy()
    lam = np.full(B, LSQ_LAMBDA0)
    active = np.isfinite(cost)
    iters = np.zeros(B, np.int64)
    for _ in range(max_iter):
        a = np.flatnonzero(active)
        if not len(a):
            break
        J = _jacobian(V[a], topo, w, free)
        A = np.einsum("bri,brj->bij", J, J)
        g = np.einsum("bri,br->bi", J, r[a])
        diag = np.einsum("bii->bi", A) + LSQ_DIAG_FLOOR
        M = A + lam[a, None, None] * (diag[:, :, None] * np.eye(len(free)))
        step = -np.linalg.solve(M, g[..., None])[..., 0]
        Vn = V[a].reshape(len(a), -1).copy()
        Vn[:, free] += step
        Vn = Vn.reshape(len(a), P, 3)
        rn, cn = cost_of(Vn, T[a])
        keep = cn < cost[a]
        k = a[keep]
        small = (cost[k] - cn[keep]) <= LSQ_FTOL * cost[k]
        V[k], r[k], cost[k] = Vn[keep], rn[keep], cn[keep]
        iters[a] += 1
        lam[a] = np.where(keep, lam[a] * LSQ_LAMBDA_DOWN, lam[a] * LSQ_LAMBDA_UP)
        active[k[small]] = False
        active[a[lam[a] > LSQ_LAMBDA_MAX]] = False
        active[cost == 0] = False
    return V, start_cost, cost, iters


def level_patches(X: np.ndarray, level: int, stats=None, start: np.ndarray | None = None,
                  max_iter: int = LSQ_MAX_ITER) -> tuple[np.ndarray, dict]:
    """Leveling: fit every patch's vertices to all entries of its vector (least squares).

    Minimises, per vector, ``sum_r || w * (fold_r(patch) - x_r) ||^2`` over the patch's vertices,
    alpha differences taken on the circle, ``w = 1 / std`` per component type (the standardization's
    scale; ones without ``stats``), from the unfolding (or ``start``), by Levenberg-Marquardt on whole
    arrays (module constants ``LSQ_*``). The cost never rises above the start's.

    Parameters
    ----------
    X : (B, D) float
        Raw (de-standardized) level-``level`` vectors.
    level : int
    stats : Stats or dict, optional
        Standardization statistics (only ``std`` is used).
    start : (B, P, 3) float64, optional
        Starting vertices (default: :func:`unfold` of ``X``), in the unfolding's gauge.
    max_iter : int

    Returns
    -------
    vertices : (B, P, 3) float64
    info : dict
        ``cost_start``, ``cost`` (B,) float64: half the weighted squared residual before and after;
        ``iterations`` (B,) int64.
    """
    X = _check(X, level)
    topo = patch_topology(level)
    V = unfold(X, level) if start is None else np.array(start, np.float64)
    if V.shape != (len(X), topo.n_vertices, 3):
        raise ValueError(f"start must have shape ({len(X)}, {topo.n_vertices}, 3), received {V.shape}")
    w = _weights(stats)
    T = X.reshape(len(X), -1, 3)
    c0, c1, it = np.zeros(len(X)), np.zeros(len(X)), np.zeros(len(X), np.int64)
    for s in range(0, len(X), LSQ_BATCH):
        sl = slice(s, s + LSQ_BATCH)
        V[sl], c0[sl], c1[sl], it[sl] = _fit_batch(V[sl], T[sl], topo, w, max_iter)
    return V, {"cost_start": c0, "cost": c1, "iterations": it}


def synthesize(X: np.ndarray, level: int, level_by: str = "lsq", stats=None) -> np.ndarray:
    """Patch vertices of raw vectors, unfolded (``level_by="none"``) or leveled (``"lsq"``).

    Parameters
    ----------
    X : (B, D) float
        Raw (de-standardized) vectors; ``v`` entries must be > 0 (see :func:`clip_v`).
    level : int
    level_by : {"none", "lsq"}
    stats : Stats or dict, optional
        Weights of the fit (see :func:`level_patches`).

    Returns
    -------
    vertices : (B, P, 3) float64
        Faces: ``patch_topology(level).faces``.
    """
    methods = {"none": lambda: unfold(X, level), "lsq": lambda: level_patches(X, level, stats)[0]}
    if level_by not in methods:
        raise ValueError(f"level_by must be one of {', '.join(LEVEL_BY)}; received {level_by!r}")
    return methods[level_by]()


def decode(x: np.ndarray, level: int, level_by: str = "none", stats=None) -> Patch:
    """One raw ring vector as a triangle patch (see :func:`synthesize`).

    Parameters
    ----------
    x : (D,) float
        Raw (de-standardized) level-``level`` vector; ``v`` entries must be > 0.
    level : int
    level_by : {"none", "lsq"}
    stats : Stats or dict, optional

    Returns
    -------
    Patch
    """
    x = np.asarray(x, np.float64).reshape(-1)
    tpl = template(level)
    if x.shape != (tpl.dims,):
        raise ValueError(f"a level-{level} vector has {tpl.dims} values; received shape {x.shape}")
    topo = patch_topology(level)
    V = synthesize(x[None], level, level_by, stats)[0]
    return Patch(V, topo.faces.copy(), list(topo.slots), topo.adjacency, level)


def reencode(patch: Patch) -> np.ndarray:
    """Ring vector of a patch's root (start leaf 0), float64, through :func:`meshsom.folds.folds`.

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


def entry_deviation(Z: np.ndarray, Y: np.ndarray, stats, circular: bool = False) -> np.ndarray:
    """Per fold entry, the distance between standardized vectors and standardized raw ones.

    Parameters
    ----------
    Z : (B, D) float
        Standardized vectors (originals or prototypes).
    Y : (B, D) float
        Raw vectors (re-encodings of synthesized patches).
    stats : Stats or dict
    circular : bool
        Compare alpha on the circle (as leveling does); False: as the SOM's QC-error does.

    Returns
    -------
    (B, D / 3) float64
        The row means are the QC-errors.
    """
    from meshsom.standardize import Stats, destandardize

    s = stats if isinstance(stats, Stats) else Stats.from_dict(stats)
    d = (destandardize(np.asarray(Z, np.float64), s) - np.asarray(Y, np.float64)).reshape(len(Z), -1, 3)
    if circular:
        d[..., 0] = _wrap(d[..., 0])
    return np.linalg.norm(d / s.std, axis=-1)


def nearest_mapped(unit: np.ndarray, dist2: np.ndarray, n_units: int) -> np.ndarray:
    """Per map unit, the vector mapped to it that lies nearest to its prototype: its *original*.

    Parameters
    ----------
    unit : (N,) int64
        Best-matching unit of every training vector (its winning variation's).
    dist2 : (N,) float
        Squared distance of that variation to the unit's prototype.
    n_units : int

    Returns
    -------
    original : (n_units,) int64
        Row of the original of every unit (the lowest row on ties); -1 where nothing is mapped.
    """
    unit = np.asarray(unit, np.int64)
    order = np.lexsort((np.arange(len(unit)), np.asarray(dist2, np.float64), unit))
    first = np.ones(len(order), bool)
    first[1:] = unit[order][1:] != unit[order][:-1]
    out = np.full(int(n_units), -1, np.int64)
    out[unit[order][first]] = order[first]
    return out


def retranslation_error(x: np.ndarray, level: int, level_by: str = "none", stats=None) -> float:
    """QC-error between a raw vector and the re-encoding of its own synthesized patch.

    Parameters
    ----------
    x : (D,) float
        Raw vector.
    level : int
    level_by : {"none", "lsq"}
    stats : Stats or dict, optional
        Measure in standardized units (as the SOM sees them) and weight the fit.
    """
    y = encode_patches(synthesize(np.asarray(x, np.float64)[None], level, level_by, stats), level)[0]
    if stats is not None:
        from meshsom.standardize import standardize

        return qc_distance(standardize(np.asarray(x, np.float64), stats), standardize(y, stats))
    return qc_distance(x, y)


def write_patch(patch: Patch, path, scale: float = 1.0) -> None:
    """Export a patch through trimesh (format from the file name: .obj, .ply, .glb, .stl, .off)."""
    import trimesh

    trimesh.Trimesh(patch.vertices * scale, patch.faces, process=False).export(path)
