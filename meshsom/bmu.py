"""BMUofN dispatch: pick the NumPy/BLAS reference or the fused OpenCL kernel.

``backend="auto"`` runs OpenCL when a device exists and otherwise falls back to NumPy
with one logged warning (per process); ``"opencl"`` raises
:class:`~meshsom.errors.DeviceError` when there is no device; ``"numpy"`` never touches
OpenCL.

On an OpenCL device the kernel layouts of the device's chain
(:func:`meshsom.bmu_opencl.layout_chain`, e.g. cpu -> cpu-narrow -> tiled) are tried in
order for each workload (dimension, variations, data type): a layout is used only after it
passed its probe in a child process (:mod:`meshsom.probe`), so a compiler that aborts cannot
take the process down. A layout that fails is skipped with one warning line naming the
device, the layout and the compiler's first error line; when every layout fails, ``"auto"``
runs the NumPy/BLAS backend (one more warning) and ``"opencl"`` raises a
:class:`~meshsom.errors.DeviceError` that says what to do. The :class:`Engine` records what
ran (:meth:`Engine.describe`), so results can say what computed them.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace

import numpy as np

from meshsom.bmu_numpy import BMUResult, bmu_numpy, unit_sums, validate
from meshsom.errors import DeviceError
from meshsom.metrics import COMPONENT, row_errors, tie_ruled_errors

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numpy", "opencl")
#: Device label of the NumPy backend.
NUMPY_DEVICE = "numpy/BLAS (CPU)"
#: Layout label of the NumPy backend.
NUMPY_LAYOUT = "numpy"
#: What a user can do when OpenCL does not work (the end of every OpenCL error line).
ADVICE = "run with --backend numpy (opencl.backend: numpy), or pick another device with --device (opencl.device)"
#: Where a batch epoch's update may run (:meth:`Engine.update_on_device`): "auto" (on the device
#: where it is a GPU with float64), "device" (wherever an OpenCL device with float64 took the
#: sums), "host" (always the host's :func:`meshsom.som.batch_update`).
UPDATES = ("auto", "host", "device")


@dataclass
class Engine:
    """A resolved backend, and a record of what it ran.

    Attributes
    ----------
    backend : str
        "numpy" or "opencl".
    device : str
        Human-readable device ("Portable Computing Language / cpu-...", or the NumPy label).
    context : pyopencl.Context or None
    layouts : tuple of str
        OpenCL kernel layouts to try, in order (empty for NumPy).
    strict : bool
        Raise when no layout works (``backend="opencl"``) instead of falling back to NumPy.
    used : dict
        Workload (D, n, dtype name) -> the layout that ran it (``"numpy"`` after a fallback).
    fallbacks : dict
        Workload -> one clause per layout that failed for it ("cpu -> cpu-narrow: reason").
    failed : set
        (layout, workload) pairs not to try again.
    sums_on_host : str
        Why per-unit sums and per-row errors are taken on the host on this OpenCL device ("" while
        they run on it: :meth:`unit_sums`, :meth:`row_errors`, :meth:`topographic_errors`).
    update_on_host : str
        Why an epoch's update asked on the device runs on the host ("" while none was refused:
        :meth:`update_on_device`, :meth:`batch_update`).
    search_only : set
        Layouts whose programs are built without the epoch's kernels: the full program failed its
        probe and the search alone passed (:meth:`search`); the epoch's reductions then run on the
        host (:attr:`sums_on_host`).
    """

    backend: str
    device: str
    context: object = None
    layouts: tuple = ()
    strict: bool = False
    used: dict = field(default_factory=dict)
    fallbacks: dict = field(default_factory=dict)
    failed: set = field(default_factory=set)
    sums_on_host: str = ""
    update_on_host: str = ""
    search_only: set = field(default_factory=set)

    def describe(self, D: int | None = None, n: int | None = None, dtype=np.float32) -> dict:
        """What computed the results: ``backend``, ``device``, ``layout``, ``fallback``.

        Parameters
        ----------
        D, n : int or None
            One workload (dimension, variations); None: every workload run so far.
        dtype : numpy dtype

        Returns
        -------
        dict
            ``layout``: the layouts that ran, comma-separated ("numpy" for the NumPy backend);
            ``fallback``: every fallback, one clause each, "" when none happened.
        """
        works = [w for w in {**self.used, **self.fallbacks}
                 if D is None or w == (int(D), int(n), np.dtype(dtype).name)]
        if self.backend == "numpy":
            layout = NUMPY_LAYOUT
        else:
            layout = ",".join(sorted({self.used[w] for w in works if w in self.used}))
        fallback = "; ".join(c for w in works for c in self.fallbacks.get(w, ()))
        if self.sums_on_host:
            host = f"per-unit sums and errors on the host: {self.sums_on_host}"
            fallback = "; ".join(c for c in (fallback, host) if c)
        if self.update_on_host:
            fallback = "; ".join(c for c in (fallback, f"epoch update on the host: {self.update_on_host}") if c)
        return {"backend": self.backend, "device": self.device, "layout": layout, "fallback": fallback}

    def prepare(self, D: int, n: int, dtype=np.float32) -> str:
        """Probe the chain for a workload without building anything in this process.

        The verdicts land in the disk cache (:mod:`meshsom.probe`), so processes that search
        later (Dask workers on this machine) start warm. Failures are recorded and logged as
        :meth:`search` does.

        Returns
        -------
        str
            The layout that will run the workload (``"numpy"`` when none works and not strict).
        """
        if self.backend == "numpy":
            return NUMPY_LAYOUT
        from meshsom import bmu_opencl

        work = (int(D), int(n), np.dtype(dtype).name)
        for name in self.layouts:
            if (name, work) in self.failed:
                continue
            verdict = bmu_opencl.probe_layout(self.context, name, D, n, dtype, name not in self.search_only)
            if verdict.ok or self._search_alone(name, work, verdict.reason, announce=True):
                return name
            self._failed(name, work, verdict.reason, announce=True)
        if self.strict:
            raise DeviceError(f"no BMUofN kernel layout works on {self.device} for D={D}, n={n}; {ADVICE}")
        return NUMPY_LAYOUT

    def _failed(self, name: str, work: tuple, reason: str, announce: bool) -> None:
        """Record a failed layout; log one warning line when ``announce`` (else at debug level:
        the process that probed it, usually the Dask client, has warned already)."""
        self.failed.add((name, work))
        later = [n for n in self.layouts if (n, work) not in self.failed]
        nxt = later[0] if later else ("nothing" if self.strict else NUMPY_LAYOUT)
        self.fallbacks.setdefault(work, []).append(f"{name} -> {nxt} (D={work[0]}, n={work[1]}): {reason}")
        log.log(logging.WARNING if announce else logging.DEBUG, "BMUofN kernel layout %r failed on %s (D=%d, n=%d): %s; using %s", name, self.device,
                    work[0], work[1], reason, f"layout {nxt!r}" if later else ("no layout (none is left)" if self.strict else "NumPy/BLAS"))

    def _params(self, name: str):
        """The tiling of layout ``name`` on this engine's device, without the epoch's kernels where
        they failed (:attr:`search_only`)."""
        from meshsom import bmu_opencl

        params = bmu_opencl.layout_params(self.context.devices[0], name)
        return replace(params, epoch_kernels=False) if name in self.search_only else params

    def _search_alone(self, name: str, work: tuple, reason: str, announce: bool) -> bool:
        """After layout ``name``'s full program failed: whether its search alone passes its probe
        (then the layout runs without the epoch's kernels, which move to the host with one warning
        line). Not tried where the program had no epoch kernels, or the failure was a hang (it
        would cost the probe's whole time limit again)."""
        from meshsom import bmu_opencl
        from meshsom.probe import HANG_REASON

        if name in self.search_only or not bmu_opencl.has_fp64(self.context) or reason.startswith(HANG_REASON):
            return False
        verdict = bmu_opencl.probe_layout(self.context, name, work[0], work[1], work[2], epoch_kernels=False)
        if not verdict.ok:
            return False
        self.search_only.add(name)
        if not self.sums_on_host:
            self.sums_on_host = f"the epoch kernels of layout {name!r} fail on this device ({reason})"
            log.log(logging.WARNING if announce else logging.DEBUG,
                    "layout %r on %s: its search works but the epoch's kernels do not (%s); the search runs on the "
                    "device, per-unit sums, errors and updates on the host", name, self.device, reason)
        return True

    def search(self, X, W, index=None, sign=None) -> BMUResult:
        """BMUofN of every row of X with this engine (the fallback chain on OpenCL).

        A layout whose program fails only because of the epoch's kernels runs its search alone
        (:attr:`search_only`)."""
        if self.backend == "numpy":
            return bmu_numpy(X, W, index, sign)
        from meshsom import bmu_opencl

        X, W, index, sign = validate(X, W, index, sign)
        work = (X.shape[1], len(index), X.dtype.name)
        reasons = []
        for name in self.layouts:
            if (name, work) in self.failed:
                continue
            try:
                try:
                    result = bmu_opencl.bmu_opencl(X, W, index, sign, context=self.context, params=self._params(name))
                except bmu_opencl.KernelLayoutError as err:  # the build or its probe, not a launch
                    if not self._search_alone(name, work, err.reason, announce=not err.cached):
                        raise
                    result = bmu_opencl.bmu_opencl(X, W, index, sign, context=self.context, params=self._params(name))
            except DeviceError as err:
                reason = getattr(err, "reason", str(err))
                reasons.append(f"{name}: {reason}")
                self._failed(name, work, reason, announce=not getattr(err, "cached", False))
                continue
            self.used[work] = name
            return result
        if self.strict:
            detail = "; ".join(reasons) or "every layout failed earlier in this process"
            raise DeviceError(f"no BMUofN kernel layout works on {self.device} for D={work[0]}, n={work[1]} "
                              f"({detail}); {ADVICE}")
        self.used[work] = NUMPY_LAYOUT
        return bmu_numpy(X, W, index, sign)

    def unit_sums(self, X, W, bmu: BMUResult, index=None, sign=None, blocks=None,
                  init=None, keep: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Per unit, the sum of the varied vectors it won and how many it won (a batch epoch's map step).

        On an OpenCL device with float64, where an OpenCL layout ran the search, the sums are taken
        on the device next to the (resident) rows (:func:`meshsom.bmu_opencl.unit_sums_opencl`),
        bit for bit the host's :func:`meshsom.bmu_numpy.unit_sums`; elsewhere, and after the
        device path failed once (one warning line; :attr:`sums_on_host` says why), on the host.

        Parameters
        ----------
        X : (N, D), W : (M, D)
        bmu : BMUResult
            This engine's answer for X against W.
        index, sign : (n, D) or None
            The variation table of the search.
        blocks : list of (start, stop) or None
            Row blocks summed apart and then added in order (:func:`meshsom.som.blocks_sums`);
            None: one block.
        init : (M, D) float64, DeviceArray or None
            Running sums of earlier rows the blocks are added to (None: zeros).
        keep : bool
            Where the sums are taken on the device, leave them there
            (:class:`meshsom.bmu_opencl.DeviceArray`) for :meth:`batch_update`.

        Returns
        -------
        sums : (M, D) float64, or a DeviceArray (``keep``, on the device)
        counts : (M,) float64
        """
        X, W, index, sign = validate(X, W, index, sign)
        found = self._on_device("unit_sums_opencl", X, W, bmu, index, sign, blocks=blocks, init=init, keep=keep)
        return found if found is not None else unit_sums(X, bmu.unit, bmu.variation, index, sign, len(W), blocks, init)

    def row_errors(self, X, W, bmu: BMUResult, index=None, sign=None, component: int = COMPONENT
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Per row, the Q- and QC-error distances of its winner (:func:`meshsom.metrics.row_errors`).

        On the device where :meth:`unit_sums` runs there (and ``component`` is the compiled
        :data:`meshsom.metrics.COMPONENT`), the same to rounding; else on the host.

        Returns
        -------
        q, qc : (N,) float64
        """
        X, W, index, sign = validate(X, W, index, sign)
        found = self._on_device("row_errors_opencl", X, W, bmu, index, sign) if component == COMPONENT else None
        return found if found is not None else row_errors(X, W, bmu, index, sign, component)

    def topographic_errors(self, X, W, bmu: BMUResult, rows: int, cols: int, topology: str = "toroidal", index=None,
                           sign=None, neighbourhood: int = 8) -> np.ndarray:
        """Per row, whether it is a topographic error, with the tie rule
        (:func:`meshsom.metrics.tie_ruled_errors`).

        On the device where :meth:`unit_sums` runs there (the same to rounding); else on the host.

        Returns
        -------
        (N,) bool
        """
        X, W, index, sign = validate(X, W, index, sign)
        found = self._on_device("topographic_errors_opencl", X, W, bmu, index, sign, rows=rows, cols=cols,
                                topology=topology, neighbourhood=neighbourhood)
        return found if found is not None else tie_ruled_errors(X, W, bmu, rows, cols, topology, index, sign,
                                                                neighbourhood)

    def update_on_device(self, policy: str = "auto") -> bool:
        """Whether a batch epoch should keep its sums on the device and update there (:data:`UPDATES`).

        ``"auto"``: on an OpenCL GPU with float64 (a CPU device gains nothing over the host's BLAS,
        and the host's update keeps every backend's codebook bit for bit equal). ``"device"``: on any
        OpenCL device with float64; where there is none, one warning line and the host
        (:attr:`update_on_host` says why). ``"host"``: never.

        Raises
        ------
        ValueError
            An unknown policy.
        """
        if policy not in UPDATES:
            raise ValueError(f"update must be one of {', '.join(UPDATES)}; received {policy!r}")
        if policy == "host":
            return False
        if self.backend != "opencl":
            reason = "the NumPy/BLAS backend has no device"
        elif self.sums_on_host or self.update_on_host:
            reason = self.sums_on_host or self.update_on_host
        else:
            from meshsom import bmu_opencl

            device = self.context.devices[0]
            if not bmu_opencl.has_fp64(self.context):
                reason = f"{self.device} has no float64 (cl_khr_fp64)"
            elif policy == "device" or not device.type & bmu_opencl._cl().device_type.CPU:
                return True
            else:
                return False
        if policy == "device" and not self.update_on_host:
            self.update_on_host = reason
            log.warning("epoch updates run on the host: %s", reason)
        return False

    def batch_update(self, W, sums, counts, sigma: float, rows: int, cols: int, topology: str = "toroidal",
                     min_weight: float | None = None) -> np.ndarray:
        """The update of a batch epoch (:func:`meshsom.som.batch_update`) where its sums are.

        Sums :meth:`unit_sums` kept on the device (``keep``) are smoothed and divided there
        (:func:`meshsom.bmu_opencl.batch_update_opencl`, the same as the host to rounding), and the
        new codebook stays resident for the next search; host sums, and device sums after a
        failure on the device (one warning line, :attr:`update_on_host`), are updated on the host.

        Parameters
        ----------
        W : (M, D) float
        sums : (M, D) float64 or DeviceArray
        counts : (M,) float64
        sigma : float
        rows, cols : int
        topology : str
        min_weight : float or None
            None: :data:`meshsom.som.MIN_WEIGHT`.

        Returns
        -------
        (M, D) W's dtype (read-only when made on the device)
        """
        from meshsom import som

        min_weight = som.MIN_WEIGHT if min_weight is None else min_weight
        if self.backend == "opencl" and not isinstance(sums, np.ndarray):
            from meshsom import bmu_opencl

            if isinstance(sums, bmu_opencl.DeviceArray):
                som.check_update_shapes(W, sums.shape, counts, rows, cols)
                if not self.update_on_host:
                    try:
                        return bmu_opencl.batch_update_opencl(
                            W, sums, counts, som.gaussian_kernel_1d(rows, sigma, topology),
                            som.gaussian_kernel_1d(cols, sigma, topology), min_weight)
                    except DeviceError as err:
                        self.update_on_host = getattr(err, "reason", str(err))
                        log.warning("epoch updates run on the host from now on: %s", self.update_on_host)
                sums = sums.get()
        return som.batch_update(W, sums, counts, sigma, rows, cols, topology, min_weight)

    def _on_device(self, function: str, X, W, bmu, index, sign, **options):
        """``meshsom.bmu_opencl.<function>`` on this engine's device for validated arrays, or None
        where it does not run there (NumPy backend, NumPy fallback for the workload, or an earlier
        failure; a failure now is recorded in :attr:`sums_on_host` with one warning line)."""
        work = (X.shape[1], len(index), X.dtype.name)
        if self.backend != "opencl" or self.sums_on_host or self.used.get(work, NUMPY_LAYOUT) == NUMPY_LAYOUT:
            return None
        from meshsom import bmu_opencl

        try:
            return getattr(bmu_opencl, function)(X, W, bmu, index, sign, context=self.context,
                                                 params=self._params(self.used[work]), **options)
        except DeviceError as err:
            self.sums_on_host = getattr(err, "reason", str(err))
            log.warning("per-unit sums and errors run on the host from now on: %s", self.sums_on_host)
            return None


_FELL_BACK = []  # holds one entry once the auto fallback warning has been logged
#: Set (to any value) in the environment of worker processes that share their client's machine and
#: environment (a LocalCluster's): the client has said the same "no usable OpenCL device"
#: fallback, so theirs is logged at INFO, not once more at WARNING per worker.
CLIENT_SAYS_FALLBACK_ENV = "MESHSOM_CLIENT_SAYS_FALLBACK"


def resolve_backend(backend: str = "auto", device: str | None = None, context=None,
                    layout: str | None = None) -> Engine:
    """Turn a backend name (and optional device selector or context) into an :class:`Engine`.

    Parameters
    ----------
    backend : {"auto", "numpy", "opencl"} or Engine
    device : str or None
        OpenCL device selector.
    context : pyopencl.Context or None
    layout : str or None
        OpenCL kernel layouts to try in this order instead of the device's chain, comma-separated
        (keys of :data:`meshsom.bmu_opencl.DEFAULT_PARAMS`; one name: that layout alone); None: the
        device's fallback chain.

    Raises
    ------
    ValueError
        Unknown backend or layout name.
    DeviceError
        ``backend="opencl"`` and no usable device.
    """
    if isinstance(backend, Engine):
        return backend
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; received {backend!r}")
    if backend == "numpy":
        return Engine("numpy", NUMPY_DEVICE)
    from meshsom import bmu_opencl

    try:
        context = context or bmu_opencl.get_context(device)
    except DeviceError as err:
        if backend == "opencl":
            raise DeviceError(f"{err}; {ADVICE}") from None
        if not _FELL_BACK:
            level = logging.INFO if os.environ.get(CLIENT_SAYS_FALLBACK_ENV) else logging.WARNING
            log.log(level, "no usable OpenCL device (%s); BMU search runs on the NumPy/BLAS backend", err)
            _FELL_BACK.append(True)
        return Engine("numpy", NUMPY_DEVICE)
    if layout is not None:
        layouts = tuple(n.strip() for n in layout.split(",") if n.strip())
        for name in layouts or (layout,):
            bmu_opencl.layout_params(context.devices[0], name)  # ValueError naming the known layouts
    else:
        layouts = bmu_opencl.layout_chain(context.devices[0])
    return Engine("opencl", bmu_opencl.device_name(context), context, layouts=layouts, strict=backend == "opencl")


def find_bmus(X, W, index=None, sign=None, backend="auto", device: str | None = None,
              context=None) -> tuple[BMUResult, Engine]:
    """BMUofN of every row of X against codebook W.

    Parameters
    ----------
    X : (N, D) float32
    W : (M, D) float32
    index : (n, D) int64 or None
        Variation gathers (None: identity only, the default kernel).
    sign : (n, D) float32 or None
    backend : {"auto", "numpy", "opencl"} or Engine
    device : str or None
        OpenCL device selector (see :mod:`meshsom.bmu_opencl`).
    context : pyopencl.Context or None
        Injected OpenCL context.

    Returns
    -------
    result : BMUResult
    engine : Engine
        Which backend and device ran (and, on OpenCL, which layouts and fallbacks).
    """
    engine = resolve_backend(backend, device, context)
    return engine.search(X, W, index, sign), engine
