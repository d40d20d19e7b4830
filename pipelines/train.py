"""Distributed batch training of one triangle map: epochs as map-reduce over row chunks of zarr.

Map (on the workers, :func:`chunk_pass`): read a row range of ``rings/level{L}``, standardize it
with the stored statistics, find BMUofN against the broadcast codebook, write that range's BMUs
and winning variations into the run (every epoch), and return the per-unit sums and counts plus
the sums behind the T-, Q- and QC-errors. Each worker process resolves its
BMU backend once (OpenCL context and compiled program, memoised in :mod:`meshsom.bmu_opencl`) and
keeps recently used standardized chunks in a bounded cache, read-only, so that on OpenCL their
device copies stay resident between epochs and only the codebook goes up each epoch. Each block
runs on the same worker every epoch (:func:`block_workers`), so that those caches hold.

Reduce (on the client, :func:`train_spec`): add the partial sums, smooth and divide
(:func:`meshsom.som.batch_update`), and checkpoint: the codebook is written to
``runs/<run>/weights`` first and the epoch is marked done in the run's attributes after, so a
resumed run continues from the last finished epoch and ends with the same codebook as an
uninterrupted one. After the last epoch one more pass with the final codebook writes the BMUs
(``bmu_unit``, ``bmu_variation``, ``bmu_dist2``, ``bmu_second``: the layout of
:mod:`meshsom.codebook`) and the final errors.

The epochs run in :func:`meshsom.som.train_batch`, the driver :class:`meshsom.som.SOM` uses too:
tasks are the row blocks of :func:`meshsom.som.row_blocks`, their sums are added in block order, the
initialisation comes from :func:`meshsom.som.random_pick` or the block moments of
:func:`meshsom.som.principal_axes`. A map trained here is bitwise equal to ``SOM.fit`` on the same
standardized rows, whatever the number of workers. ``meshsom train`` runs this same code on an
in-process cluster (:func:`pipelines.cluster.connect_serial`).
"""

from __future__ import annotations

import hashlib
import logging
import warnings
import json
import time
from collections import OrderedDict
from dataclasses import asdict, dataclass

import numpy as np

#: Bytes of standardized chunks a worker keeps between epochs.
CHUNK_CACHE_BYTES = 1 << 30
#: Times a pass is run again when a worker dies under the client's own transfers, and the wait.
PASS_RETRIES = 3
PASS_RETRY_WAIT_S = 1.0
#: Seconds between checks, while waiting for a block pinned to a worker, that the worker is still there.
PLACEMENT_CHECK_S = 2.0

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


def load_level(group, level: int) -> np.ndarray:
    """All standardized fold vectors of a level in memory, read block by block.

    Returns
    -------
    (F, D) float32
    """
    from meshsom.som import row_blocks
    from meshsom.standardize import standardize
    from meshsom.store import read_stats, rings_array

    rings = rings_array(group, level)
    stats = read_stats(group, level)
    out = np.empty(rings.shape, np.float32)
    for a, b in row_blocks(rings.shape[0]):
        out[a:b] = standardize(np.asarray(rings[a:b]), stats)
    return out


def chunk_pass(job: TrainJob, start: int, stop: int, W: np.ndarray, write_bmus: bool = False) -> dict:
    """The map step of one epoch on the row block ``start..stop``.

    Returns
    -------
    dict
        :func:`meshsom.som.block_sums` without the BMUs (``counts``, ``n``, ``t_bad``, ``q_sum``,
        ``qc_sum``), the sums of the units the block won only (``won`` (k,) int32 and ``sums``
        (k, D): a block of 16,384 rows wins a fraction of an 18,000-unit map, and this is what
        travels to the client every epoch), and what computed it: ``backend``, ``device``,
        ``layout``, ``fallback`` (:meth:`meshsom.bmu.Engine.describe`).
    """
    from meshsom.som import block_sums
    from meshsom.variations import variation_table

    X = load_chunk(job, start, stop)
    if job.source is None:
        index, sign = variation_table(job.level, mirror=job.mirror, kernel=job.kernel)
    else:
        index = sign = None  # one variation: the identity
    engine = _engine(job.backend, job.device, job.layout)
    out = block_sums(X, W, job.rows, job.cols, job.topology, index, sign, backend=engine)
    bmu = out.pop("bmu")
    won = np.flatnonzero(out["counts"])
    out["won"], out["sums"] = won.astype(np.int32), out["sums"][won]
    out.update(engine.describe(X.shape[1], 1 if index is None else len(index), X.dtype))
    if write_bmus:
        from meshsom.store import open_store, run_group, write_bmu_rows

        write_bmu_rows(run_group(open_store(job.store, mode="r+"), job.run), bmu, start)
    return out


# ----------------------------------------------------------------------------- client side


def _codebook(W: np.ndarray) -> np.ndarray:
    """Identity task that holds the epoch's codebook on the cluster."""
    return W


class WorkerLost(OSError):
    """A worker that row blocks are pinned to left the cluster during a pass (the pass runs again)."""


def block_workers(client, n_blocks: int) -> list:
    """The worker each row block runs on in every pass: the cluster's workers in address order,
    round robin over the blocks (None for all: no worker yet).

    The same block goes to the same worker every epoch, so that its standardized chunk stays in
    that worker's cache (:func:`load_chunk`) and, on OpenCL, resident on its device: left to
    itself the scheduler moves blocks between workers from epoch to epoch, and each worker ends
    up reading, standardizing and uploading every block (measured with 2 workers: each held all
    4 blocks of a run). The placement is strict, as only strict restrictions keep Dask's work
    stealing off a task; a pass whose worker leaves runs again on the workers there are
    (:class:`WorkerLost`, :func:`_pass`).
    """
    workers = sorted(client.nthreads())  # asked of the scheduler now (scheduler_info() may be stale)
    return [workers[i % len(workers)] if workers else None for i in range(n_blocks)]


def _pass(client, job: TrainJob, ranges, W: np.ndarray, retries: int = PASS_RETRIES) -> dict:
    """One pass over every row chunk against codebook ``W``, reduced in task order, each chunk on
    its worker (:func:`block_workers`).

    A worker dying while the codebook is broadcast or while results are fetched (a connection
    closed under us) makes the whole pass run again: its tasks are pure and their BMU writes are
    idempotent region writes, so a repeated pass gives the same result. Dask itself reruns the
    tasks of a dead worker; this covers the client's own transfers.
    """
    for attempt in range(retries + 1):
        futures = []
        try:
            # The codebook travels as a task's input, not by scatter: if the worker holding it dies,
            # the scheduler recomputes it from the graph instead of losing it.
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=".*[Ll]arge (object|graph).*")
                wf = client.submit(_codebook, W, pure=False)
            homes = block_workers(client, len(ranges))
            futures = [client.submit(chunk_pass, job, a, b, wf, True, pure=False,
                                     **({} if home is None else {"workers": [home]}))
                       for (a, b), home in zip(ranges, homes)]
            return _reduce(futures, client, homes)
        except OSError as err:  # distributed's CommClosedError is an OSError, and so is WorkerLost
            try:
                client.cancel(futures)  # blocks pinned to a lost worker would wait forever
            except Exception:  # noqa: BLE001 - the pass runs again (or fails) either way
                pass
            if attempt == retries:
                raise
            log.warning("training pass of %s interrupted (%s); running it again", job.run, err)
            time.sleep(PASS_RETRY_WAIT_S)
    raise AssertionError("unreachable")


def add_won_sums(total: dict | None, part: dict) -> dict:
    """Add one :func:`chunk_pass` result (sums of its won units only) to a running total with dense
    (M, D) sums, in place (None: the first block).

    Bit for bit :func:`meshsom.som.add_sums` of the dense sums: a unit the block did not win would
    add 0.0, which leaves a sum as it is (a sum is never -0.0: each block's starts from 0.0).
    """
    from meshsom.som import SUM_KEYS

    part = dict(part)
    won, sums = part.pop("won"), part.pop("sums")
    if total is None:
        total = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in part.items()}
        total["sums"] = np.zeros((len(part["counts"]), sums.shape[1]))
    else:
        for k in SUM_KEYS:
            if k != "sums":
                total[k] += part[k]
    total["sums"][won] += sums
    return total


def _result(client, fut, home):
    """``fut.result()``; for a block pinned to worker ``home``, checked every :data:`PLACEMENT_CHECK_S`
    that the worker is still in the cluster (else :class:`WorkerLost`)."""
    if client is None or home is None:
        return fut.result()
    while True:
        try:
            return fut.result(timeout=PLACEMENT_CHECK_S)
        except TimeoutError:
            if home not in client.nthreads():
                raise WorkerLost(f"worker {home} left the cluster") from None


def _reduce(futures, client=None, homes=None) -> dict:
    """Add the blocks' sums in block order (as :func:`meshsom.som.add_sums`), fetching one at a time.

    The order makes the float64 sums (and so the codebook) independent of which worker finished
    first, and equal to ``SOM.fit``'s; fetching one result at a time keeps the client's memory at
    two (M, D) arrays however many blocks there are. With ``client`` and ``homes`` (the worker each
    block is pinned to), a block whose worker left raises :class:`WorkerLost`.
    """
    total = None
    layouts: set = set()
    fallbacks: list = []
    for i, fut in enumerate(futures):
        part = _result(client, fut, None if homes is None else homes[i])
        layouts.update(filter(None, part["layout"].split(",")))
        fallbacks += [f for f in part["fallback"].split("; ") if f and f not in fallbacks]
        total = add_won_sums(total, part)
        fut.release()
    total["layout"] = ",".join(sorted(layouts))
    total["fallback"] = "; ".join(fallbacks)
    return total


def initial_weights(job: TrainJob, ranges) -> np.ndarray:
    """The codebook :class:`meshsom.som.SOM` starts from with the same seed, read block by block.

    ``random``: the rows :func:`meshsom.som.random_pick` draws (read from zarr, not from a full
    array); ``pca``: :func:`meshsom.som.principal_axes` of the moments added over the same blocks
    (fewer rows than dimensions: all rows in memory, as ``SOM.fit`` does).
    """
    from meshsom.som import add_moments, init_weights, moments, pca_codebook, principal_axes, random_pick
    from meshsom.standardize import standardize
    from meshsom.store import open_store, read_stats

    group = open_store(job.store)
    rings = source_array(group, job)
    stats = read_stats(group, job.level) if job.source is None else None
    n, D = rings.shape

    def prepare(x):
        return (standardize(x, stats) if stats is not None else np.asarray(x)).astype(np.float32)

    M = job.rows * job.cols
    if job.init == "random":
        pick = random_pick(n, M, job.seed)
        uniq, inverse = np.unique(pick, return_inverse=True)
        return prepare(np.asarray(rings.get_orthogonal_selection((uniq, slice(None)))))[inverse.ravel()]
    if n < D:
        return init_weights(prepare(np.asarray(rings[:])), job.rows, job.cols, job.init, job.seed)
    total = None
    for a, b in ranges:
        total = add_moments(total, moments(prepare(np.asarray(rings[a:b]))))
    return pca_codebook(*principal_axes(total), job.rows, job.cols)


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


def train_spec(client, job: TrainJob, resume: bool = False, on_epoch=None, progress=None) -> dict:
    """Train one map on the cluster, checkpointing every epoch into ``runs/<run>``.

    Parameters
    ----------
    client : distributed.Client
    job : TrainJob
    resume : bool
        Continue from the last finished epoch of the same job (same fingerprint).
    on_epoch : callable, optional
        ``on_epoch(epoch, metrics)`` after every epoch (metrics of the search against the
        codebook before that epoch's update; ``epoch`` 0-based).
    progress : callable, optional
        ``progress(done_epochs, total_epochs)``.

    Returns
    -------
    dict
        ``run``, ``metrics`` (final t/q/qc errors), ``history`` (per epoch), ``backend``, ``device``,
        ``layout``, ``fallback``, ``seconds``, ``resumed_from`` (epoch), ``n_vectors``, ``dims``.
    """
    from meshsom.metrics import errors_of
    from meshsom.som import BLOCK_ROWS, row_blocks, train_batch
    from meshsom.store import (
        create_bmu_arrays, open_store, read_checkpoint, reset_run, run_group, write_checkpoint, write_run_header,
        write_run_result,
    )
    from meshsom.variations import n_variations

    t0 = time.perf_counter()
    group = open_store(job.store, mode="r+")
    rings = source_array(group, job)
    n, D = rings.shape
    ranges = row_blocks(n)
    fp = job.fingerprint()
    g = run_group(group, job.run)
    cp = read_checkpoint(g) if resume else None
    start_epoch, history = 0, []
    if cp is not None and cp["fingerprint"] == fp:
        if cp["final_done"]:
            return {**cp["result"], "resumed_from": cp["epoch_done"]}
        start_epoch, history, W = cp["epoch_done"], cp["history"], cp["weights"]
    else:
        g = reset_run(group, job.run)
        W = initial_weights(job, ranges)
    write_run_header(g, job.rows, job.cols, job.topology, job.level, job.kernel, fp, asdict(job))
    prepare_engine(client, job, D)
    # BMUs, variations, distances and second-best units of every vector, rewritten by every pass
    # (chunks are the row blocks: no two tasks write one chunk)
    create_bmu_arrays(g, n, min(max(n, 1), BLOCK_ROWS))

    def checkpoint(info, W):
        metrics = {k: float(v) for k, v in info.errors.items()}
        history.append({"epoch": info.epoch, "sigma": info.sigma, **metrics})
        # the codebook first, then the mark (the BMUs on disk are those of this epoch's search)
        write_checkpoint(g, W, info.epoch + 1, history, info.epoch)
        if on_epoch:
            on_epoch(info.epoch, metrics)
        if progress:
            progress(info.epoch + 1, job.epochs)

    W = train_batch(W, lambda W: _pass(client, job, ranges, W), job.rows, job.cols, job.epochs, job.sigma_start,
                    job.sigma_end, job.topology, start_epoch=start_epoch, callbacks=(checkpoint,))
    # final pass: BMUs of every vector against the final codebook, and the final errors
    red = _pass(client, job, ranges, W)
    final = {k: float(v) for k, v in errors_of(red).items()}
    result = {
        "run": job.run, "metrics": final, "history": history, "backend": red["backend"], "device": red["device"],
        "layout": red["layout"], "fallback": red["fallback"],
        "seconds": time.perf_counter() - t0, "resumed_from": start_epoch, "n_vectors": int(n),
        "dims": f"{n_variations(job.level, job.kernel, job.mirror) if job.source is None else 1}x{D}",
    }
    write_run_result(g, final, result, {k: red[k] for k in ("backend", "device", "layout", "fallback")}, job.epochs)
    return result

