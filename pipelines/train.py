"""Distributed batch training of one triangle map: epochs as map-reduce over row chunks of zarr.

Map (on the workers, :func:`chunk_pass`): read a row range of ``rings/level{L}``, standardize it
with the stored statistics, find BMUofN against the broadcast codebook, write that range's BMUs
and winning variations into the run (every epoch), and return the per-unit sums and counts plus
the sums behind the T-, Q- and QC-errors. Each worker process resolves its
BMU backend once (OpenCL context and compiled program, memoised in :mod:`meshsom.bmu_opencl`) and
keeps recently used standardized chunks in a bounded cache, read-only, so that on OpenCL their
device copies stay resident between epochs and only the codebook goes up each epoch.

Reduce (on the client, :func:`train_spec`): add the partial sums, smooth and divide
(:func:`meshsom.som.batch_update`), and checkpoint: the codebook is written to
``runs/<run>/weights`` first and the epoch is marked done in the run's attributes after, so a
resumed run continues from the last finished epoch and ends with the same codebook as an
uninterrupted one. After the last epoch one more pass with the final codebook writes the BMUs
(``bmu_unit``, ``bmu_variation``, ``bmu_dist2``, ``bmu_second``: the layout of
:mod:`meshsom.codebook`) and the final errors.

The arithmetic is that of :class:`meshsom.som.SOM` (same initialisation from the seed, same
radius schedule, same update); only the order of the float64 summation over chunks differs.
"""

from __future__ import annotations

import hashlib
import logging
import warnings
import json
import math
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass

import numpy as np

#: Bytes of standardized chunks a worker keeps between epochs.
CHUNK_CACHE_BYTES = 1 << 30
#: Tasks per worker and epoch when the store's row chunks are larger than that split.
TASKS_PER_WORKER = 2
#: Times a pass is run again when a worker dies under the client's own transfers, and the wait.
PASS_RETRIES = 3
PASS_RETRY_WAIT_S = 1.0

log = logging.getLogger(__name__)

_ENGINES: dict = {}
_CHUNKS: "OrderedDict[tuple, np.ndarray]" = OrderedDict()


@dataclass(frozen=True)
class TrainJob:
    """Everything that defines one map's training (its hash names a resumable state).

    Attributes
    ----------
    store : str
    level : int
    kernel : str
    mirror : bool
    rows, cols : int
    topology : str
    epochs : int
    sigma_start, sigma_end : float
    init : str
    seed : int
    backend : str
    device : str or None
    layout : str or None
        OpenCL kernel layouts to try in order, comma-separated (None: the device's fallback chain).
    source : str or None
        Array of the store to train on, rows = vectors (default: ``rings/level{L}``, standardized
        with the level's statistics). Any other array (domain vectors) is used as it is, with one
        variation.
    name : str or None
        Run group under ``runs/`` (default ``level{L}-{kernel}``).
    """

    store: str
    level: int
    kernel: str
    mirror: bool
    rows: int
    cols: int
    topology: str
    epochs: int
    sigma_start: float
    sigma_end: float
    init: str
    seed: int
    backend: str = "auto"
    device: str | None = None
    layout: str | None = None
    source: str | None = None
    name: str | None = None

    @property
    def run(self) -> str:
        return self.name or f"level{self.level}-{self.kernel}"

    def fingerprint(self) -> str:
        d = asdict(self)
        d.pop("store")
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- worker side


def _engine(backend: str, device: str | None, layout: str | None = None):
    """This process's engine for a backend, device and layout (resolved once, then reused)."""
    from meshsom.bmu import resolve_backend

    key = (backend, device, layout)
    if key not in _ENGINES:
        _ENGINES[key] = resolve_backend(backend, device, layout=layout)
    return _ENGINES[key]


def source_array(group, job: "TrainJob"):
    """The (N, D) array a job trains on."""
    from meshsom.errors import StoreError
    from meshsom.store import rings_array, store_path

    if job.source is None:
        return rings_array(group, job.level)
    try:
        return group[job.source]
    except KeyError:
        raise StoreError(f"{store_path(group)}: has no array {job.source!r}") from None


def load_chunk(job: "TrainJob", start: int, stop: int) -> np.ndarray:
    """Rows ``start..stop`` of the job's vectors, standardized for ring levels (cached per worker).

    Returns
    -------
    (stop - start, D) float32, read-only
        The cached array itself: read-only, so that its device copy stays resident between epochs
        (:class:`meshsom.bmu_opencl.ResidentRows`) and only the codebook goes up each epoch.
    """
    key = (job.store, job.level, job.source, start, stop)
    if key in _CHUNKS:
        _CHUNKS.move_to_end(key)
        return _CHUNKS[key]
    from meshsom.standardize import standardize
    from meshsom.store import open_store, read_stats

    group = open_store(job.store)
    x = np.asarray(source_array(group, job)[start:stop])
    if job.source is None:
        x = standardize(x, read_stats(group, job.level))
    x = x.astype(np.float32)  # a copy of its own: nothing else can write to it
    x.flags.writeable = False
    _CHUNKS[key] = x
    while sum(a.nbytes for a in _CHUNKS.values()) > CHUNK_CACHE_BYTES and len(_CHUNKS) > 1:
        _CHUNKS.popitem(last=False)
    return x


def chunk_pass(job: TrainJob, start: int, stop: int, W: np.ndarray, write_bmus: bool = False) -> dict:
    """The map step of one epoch on rows ``start..stop``.

    Returns
    -------
    dict
        ``sums`` (M, D) float64, ``counts`` (M,) float64, ``n``, ``t_bad`` (vectors whose best and
        second-best units are not neighbours), ``q_sum`` (sum of BMU distances), ``qc_sum`` (sum over
        vectors of the mean per-component distance), and what computed it: ``backend``, ``device``,
        ``layout``, ``fallback`` (:meth:`meshsom.bmu.Engine.describe`).
    """
    from meshsom.metrics import are_neighbours, residuals
    from meshsom.som import partial_sums
    from meshsom.variations import variation_table

    X = load_chunk(job, start, stop)
    if job.source is None:
        index, sign = variation_table(job.level, mirror=job.mirror, kernel=job.kernel)
    else:
        index = sign = None  # one variation: the identity
    engine = _engine(job.backend, job.device, job.layout)
    sums, counts, bmu = partial_sums(X, W, index, sign, backend=engine)
    res = residuals(X, W, bmu, index, sign)
    parts = res.reshape(len(X), -1, 3) if X.shape[1] % 3 == 0 else res[:, :, None]
    comp = np.sqrt(np.einsum("ijk,ijk->ij", parts, parts))
    out = {
        "sums": sums, "counts": counts, "n": len(X),
        "t_bad": int((~are_neighbours(bmu.unit, bmu.second, job.rows, job.cols, job.topology)).sum()),
        "q_sum": float(np.sqrt(np.einsum("ij,ij->i", res, res)).sum()),
        "qc_sum": float(comp.mean(axis=1).sum()),
        **engine.describe(X.shape[1], 1 if index is None else len(index), X.dtype),
    }
    if write_bmus:
        from meshsom.codebook import BMU_ARRAYS
        from meshsom.store import open_store, run_group

        g = run_group(open_store(job.store, mode="r+"), job.run)
        for attr, name in BMU_ARRAYS.items():
            g[name][start:stop] = np.asarray(getattr(bmu, attr), np.float64 if attr == "dist2" else np.int64)
    return out


# ----------------------------------------------------------------------------- client side


def row_ranges(n: int, chunk_rows: int, n_workers: int) -> list[tuple[int, int]]:
    """Task row ranges: the store's chunks, split further so every worker gets work."""
    step = max(1, min(chunk_rows, math.ceil(n / max(1, n_workers * TASKS_PER_WORKER))))
    return [(a, min(n, a + step)) for a in range(0, n, step)]


def _codebook(W: np.ndarray) -> np.ndarray:
    """Identity task that holds the epoch's codebook on the cluster."""
    return W


def _pass(client, job: TrainJob, ranges, W: np.ndarray, retries: int = PASS_RETRIES) -> dict:
    """One pass over every row chunk against codebook ``W``, reduced in task order.

    A worker dying while the codebook is broadcast or while results are fetched (a connection
    closed under us) makes the whole pass run again: its tasks are pure and their BMU writes are
    idempotent region writes, so a repeated pass gives the same result. Dask itself reruns the
    tasks of a dead worker; this covers the client's own transfers.
    """
    for attempt in range(retries + 1):
        try:
            # The codebook travels as a task's input, not by scatter: if the worker holding it dies,
            # the scheduler recomputes it from the graph instead of losing it.
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=".*[Ll]arge (object|graph).*")
                wf = client.submit(_codebook, W, pure=False)
            return _reduce([client.submit(chunk_pass, job, a, b, wf, True, pure=False) for a, b in ranges])
        except OSError as err:  # distributed's CommClosedError is an OSError
            if attempt == retries:
                raise
            log.warning("training pass of %s interrupted (%s); running it again", job.run, err)
            time.sleep(PASS_RETRY_WAIT_S)
    raise AssertionError("unreachable")


def _reduce(futures) -> dict:
    """Sum the partial results in task order, fetching one at a time.

    The order makes the float64 sums (and so the codebook) independent of which worker finished
    first; fetching one result at a time keeps the client's memory at two (M, D) arrays however
    many chunks there are.
    """
    total = None
    layouts: set = set()
    fallbacks: list = []
    for fut in futures:
        part = fut.result()
        layouts.update(filter(None, part["layout"].split(",")))
        fallbacks += [f for f in part["fallback"].split("; ") if f and f not in fallbacks]
        if total is None:
            total = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in part.items()}
        else:
            total["sums"] += part["sums"]
            total["counts"] += part["counts"]
            for k in ("n", "t_bad", "q_sum", "qc_sum"):
                total[k] += part[k]
        fut.release()
    n = total["n"]
    return {
        "sums": total["sums"], "counts": total["counts"],
        "t_error": total["t_bad"] / n, "q_error": total["q_sum"] / n, "qc_error": total["qc_sum"] / n,
        "backend": total["backend"], "device": total["device"], "layout": ",".join(sorted(layouts)),
        "fallback": "; ".join(fallbacks),
    }


def initial_weights(job: TrainJob, ranges) -> np.ndarray:
    """The codebook :class:`meshsom.som.SOM` starts from with the same seed.

    ``random`` draws the same rows as :func:`meshsom.som.init_weights` (read from zarr, not from a
    full array); ``pca`` uses chunked moments, equal to its SVD up to the signs of the components.
    """
    from meshsom.standardize import standardize
    from meshsom.store import open_store, read_stats

    group = open_store(job.store)
    rings = source_array(group, job)
    stats = read_stats(group, job.level) if job.source is None else None
    n = rings.shape[0]

    def prepare(x):
        return standardize(x, stats) if stats is not None else np.asarray(x, np.float32)

    M = job.rows * job.cols
    rng = np.random.default_rng(job.seed)
    if job.init == "random":
        pick = rng.choice(n, size=M, replace=n < M)
        uniq, inverse = np.unique(pick, return_inverse=True)
        rows = np.asarray(rings.get_orthogonal_selection((uniq, slice(None))))
        return prepare(rows).astype(np.float32)[inverse]
    # PCA from chunked moments (equal to the SVD of SOM.fit up to the signs of the components)
    mean = np.zeros(rings.shape[1])
    gram = np.zeros((rings.shape[1],) * 2)
    for a, b in ranges:
        x = prepare(np.asarray(rings[a:b])).astype(np.float64)
        mean += x.sum(axis=0)
        gram += x.T @ x
    mean /= n
    cov = (gram - n * np.outer(mean, mean)) / max(n - 1, 1)
    vals, vecs = np.linalg.eigh(cov)
    order = np.argsort(vals)[::-1][:2]
    comps = np.zeros((2, rings.shape[1]))
    comps[: len(order)] = (vecs[:, order] * np.sqrt(np.maximum(vals[order], 0))).T
    a = np.linspace(-1, 1, job.rows)
    b = np.linspace(-1, 1, job.cols)
    grid = a[:, None, None] * comps[0] + b[None, :, None] * comps[1]
    return (mean + grid.reshape(M, -1)).astype(np.float32)


def prepare_engine(client, job: TrainJob, D: int) -> None:
    """Probe the job's OpenCL layouts from the client before the first pass, when the workers share its machine.

    The probes log what they check; their verdicts go to the disk cache, so the workers start
    warm and the user sees the check (and any fallback) in the client's output. Workers of a
    remote scheduler probe on their own machines.
    """
    if job.backend == "numpy" or getattr(client, "cluster", None) is None:
        return
    from meshsom.errors import DeviceError
    from meshsom.variations import n_variations

    n = n_variations(job.level, job.kernel, job.mirror) if job.source is None else 1
    try:
        engine = _engine(job.backend, job.device, job.layout)
    except DeviceError:
        return  # the workers raise (strict) or fall back (auto) themselves, with the same message
    engine.prepare(D, n, np.float32)


def train_spec(client, job: TrainJob, resume: bool = False, on_epoch=None, progress=None,
               chunk_rows: int | None = None) -> dict:
    """Train one map on the cluster, checkpointing every epoch into ``runs/<run>``.

    Parameters
    ----------
    client : distributed.Client
    job : TrainJob
    resume : bool
        Continue from the last finished epoch of the same job (same fingerprint).
    on_epoch : callable, optional
        ``on_epoch(epoch, metrics)`` after every epoch (metrics of the search against the
        codebook before that epoch's update) and ``on_epoch(job.epochs, final_metrics)`` at the end.
    progress : callable, optional
        ``progress(done_epochs, total_epochs)``.

    Returns
    -------
    dict
        ``run``, ``metrics`` (final t/q/qc errors), ``history`` (per epoch), ``backend``, ``device``,
        ``seconds``, ``resumed_from`` (epoch), ``n_vectors``, ``dims``.
    """
    from meshsom.codebook import BMU_ARRAYS
    from meshsom.som import batch_update, sigma_schedule
    from meshsom.store import open_store, run_group
    from meshsom.variations import n_variations

    t0 = time.perf_counter()
    group = open_store(job.store, mode="r+")
    rings = source_array(group, job)
    n, D = rings.shape
    M = job.rows * job.cols
    n_workers = max(1, len(client.scheduler_info()["workers"]))
    ranges = row_ranges(n, chunk_rows or rings.chunks[0], n_workers)
    g = run_group(group, job.run)
    fp = job.fingerprint()
    attrs = dict(g.attrs)
    start_epoch, history = 0, []
    if resume and attrs.get("fingerprint") == fp and attrs.get("epoch_done", 0) > 0 and "weights" in g:
        start_epoch = int(attrs["epoch_done"])
        history = list(attrs.get("history", []))[:start_epoch]
        W = np.asarray(g["weights"][:])
        if attrs.get("final_done"):
            return {**attrs["result"], "resumed_from": start_epoch}
    else:
        for name in list(g.array_keys()):
            del g[name]
        g.attrs.clear()
        W = initial_weights(job, ranges)
    g.attrs.update({
        "rows": job.rows, "cols": job.cols, "topology": job.topology, "level": job.level, "kernel": job.kernel,
        "fingerprint": fp, "job": asdict(job),
    })
    sigma_start = job.sigma_start
    backend = device = None
    prepare_engine(client, job, D)
    # BMUs, variations, distances and second-best units of every vector, rewritten by every pass
    # (chunks aligned with the task row ranges: no two tasks write one chunk)
    step = ranges[0][1] - ranges[0][0]
    for attr, name in BMU_ARRAYS.items():
        if name not in g or g[name].shape != (n,) or g[name].chunks != (max(1, step),):
            g.create_array(name, shape=(n,), dtype=np.float64 if attr == "dist2" else np.int64,
                           chunks=(max(1, step),), overwrite=True)
    for epoch in range(start_epoch, job.epochs):
        sigma = sigma_schedule(epoch, job.epochs, sigma_start, job.sigma_end)
        red = _pass(client, job, ranges, W)
        backend, device = red["backend"], red["device"]
        W = batch_update(W, red["sums"], red["counts"], sigma, job.rows, job.cols, job.topology)
        metrics = {k: float(red[k]) for k in ("t_error", "q_error", "qc_error")}
        history.append({"epoch": epoch, "sigma": sigma, **metrics})
        _put(g, "weights", W, job.rows * job.cols)  # write first ...
        # ... then mark (the BMUs on disk are those of this epoch's search, before its update)
        g.attrs.update({"epoch_done": epoch + 1, "history": history, "bmu_epoch": epoch})
        if on_epoch:
            on_epoch(epoch, metrics)
        if progress:
            progress(epoch + 1, job.epochs)
    # final pass: BMUs of every vector against the final codebook, and the final errors
    red = _pass(client, job, ranges, W)
    final = {k: float(red[k]) for k in ("t_error", "q_error", "qc_error")}
    result = {
        "run": job.run, "metrics": final, "history": history, "backend": red["backend"], "device": red["device"],
        "layout": red["layout"], "fallback": red["fallback"],
        "seconds": time.perf_counter() - t0, "resumed_from": start_epoch, "n_vectors": int(n),
        "dims": f"{n_variations(job.level, job.kernel, job.mirror) if job.source is None else 1}x{D}",
    }
    g.attrs.update({"metrics": final, "result": result, "final_done": True, "bmu_epoch": job.epochs,
                    "engine": {k: red[k] for k in ("backend", "device", "layout", "fallback")}})
    if on_epoch:
        on_epoch(job.epochs, final)
    return result


def _put(group, name: str, data: np.ndarray, rows: int) -> None:
    if name in group and group[name].shape == data.shape:
        group[name][...] = data
        return
    arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=(max(1, rows),) + data.shape[1:], overwrite=True)
    arr[...] = data
