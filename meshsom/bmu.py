"""BMUofN dispatch: pick the NumPy/BLAS reference or the fused OpenCL kernel.

``backend="auto"`` runs OpenCL when a device exists and otherwise falls back to NumPy
with one logged warning (per process); ``"opencl"`` raises
:class:`~meshsom.errors.DeviceError` when there is no device; ``"numpy"`` never touches
OpenCL.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from meshsom.bmu_numpy import BMUResult, bmu_numpy
from meshsom.errors import DeviceError

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numpy", "opencl")
#: Device label of the NumPy backend.
NUMPY_DEVICE = "numpy/BLAS (CPU)"


@dataclass(frozen=True)
class Engine:
    """A resolved backend.

    Attributes
    ----------
    backend : str
        "numpy" or "opencl".
    device : str
        Human-readable device ("Portable Computing Language / cpu-...", or the NumPy label).
    context : pyopencl.Context or None
    """

    backend: str
    device: str
    context: object = None


_FELL_BACK = []  # holds one entry once the auto fallback warning has been logged


def resolve_backend(backend: str = "auto", device: str | None = None, context=None) -> Engine:
    """Turn a backend name (and optional device selector or context) into an :class:`Engine`.

    Raises
    ------
    ValueError
        Unknown backend name.
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
            raise
        if not _FELL_BACK:
            log.warning("no usable OpenCL device (%s); BMU search runs on the NumPy/BLAS backend", err)
            _FELL_BACK.append(True)
        return Engine("numpy", NUMPY_DEVICE)
    return Engine("opencl", bmu_opencl.device_name(context), context)


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
        Which backend and device ran.
    """
    engine = resolve_backend(backend, device, context)
    if engine.backend == "numpy":
        return bmu_numpy(X, W, index, sign), engine
    from meshsom.bmu_opencl import bmu_opencl

    return bmu_opencl(X, W, index, sign, context=engine.context), engine
