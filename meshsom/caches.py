"""Cache folders that must be writable: the user's (PoCL, pyopencl, pytools and meshsom write
there) and meshsom's own.

By default everything goes under the user's cache folder (``$XDG_CACHE_HOME``, else ``~/.cache``).
Where that cannot be written (a container user whose home is ``/nonexistent``, a read-only home on
a cluster), things failed in three ways:

- PoCL, which compiles kernels into ``pocl/kcache`` there, shows **no device at all**, so a run
  fell back to NumPy saying "no OpenCL device found", which was not the reason;
- pyopencl's kernel invoker cache (pytools' ``WriteOncePersistentDict``) raised in every probe;
- meshsom's verdict cache could not be created and a run stopped with a traceback.

So, before OpenCL is first used in a process (:func:`ensure_user_cache`) and before meshsom's cache
is (:func:`meshsom_cache_root`), each folder is checked; where it cannot be written, a folder of
this user's own under the temporary folder is used instead (``XDG_CACHE_HOME``, which PoCL, pyopencl
and pytools follow and child processes inherit; ``POCL_CACHE_DIR`` or ``MESHSOM_CACHE_DIR`` where
those name an unwritable folder), with one warning line that says why and what to set. The
temporary folder lasts until the machine cleans it; probes and builds are then redone.
"""

from __future__ import annotations

import functools
import logging
import os
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)

#: meshsom's cache folder, when set (else ``$XDG_CACHE_HOME/meshsom``, else ``~/.cache/meshsom``).
ENV_CACHE = "MESHSOM_CACHE_DIR"
#: PoCL's kernel cache folder, when set (else ``$XDG_CACHE_HOME/pocl/kcache``, else
#: ``~/.cache/pocl/kcache``: PoCL's own defaults).
ENV_POCL_CACHE = "POCL_CACHE_DIR"


def user_cache() -> Path | None:
    """The user's cache folder: ``$XDG_CACHE_HOME``, else ``~/.cache``; None without a home."""
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg:
        return Path(xdg)
    try:
        return Path.home() / ".cache"
    except (RuntimeError, KeyError):  # no $HOME and no passwd entry
        return None


def unwritable(folder: Path | None) -> str | None:
    """Why ``folder`` cannot hold cache files (it is created if missing), or None when it can."""
    if folder is None:
        return "there is no home folder"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=folder, prefix=".meshsom-write-check-")
        probe.close()
    except OSError as err:
        return f"{type(err).__name__}: {err.strerror or err}"
    return None


def private_temp(name: str) -> Path:
    """A folder of this user's own under the temporary folder (``meshsom-<uid>/<name>``, mode 700);
    a fresh one when that name is taken by someone else."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    root = Path(tempfile.gettempdir()) / f"meshsom-{uid}"
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        if hasattr(os, "getuid") and root.stat().st_uid != uid:
            raise PermissionError(f"{root} belongs to another user")
        folder = root / name
        folder.mkdir(mode=0o700, exist_ok=True)
        if unwritable(folder) is None:
            return folder
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix=f"meshsom-{name}-"))


def _warn(message: str, *args) -> None:
    """One warning per process; where the client has said it already (a LocalCluster's workers,
    :data:`meshsom.bmu.CLIENT_SAYS_FALLBACK_ENV`), at INFO."""
    from meshsom.bmu import CLIENT_SAYS_FALLBACK_ENV

    log.log(logging.INFO if os.environ.get(CLIENT_SAYS_FALLBACK_ENV) else logging.WARNING, message, *args)


@functools.lru_cache(maxsize=None)
def _root(base: str | None, xdg: str | None, home: str | None) -> Path:  # keyed by what decides the folder
    if base:
        root = Path(base)
    else:
        cache = user_cache()
        root = cache / "meshsom" if cache is not None else None
    why = unwritable(root)
    if why is None:
        return root
    fallback = private_temp("cache")
    _warn("meshsom's cache folder %s cannot be written (%s); kernel verdicts and tunings go to %s "
          "(set %s to a writable folder to keep them)", root or "~/.cache/meshsom", why, fallback, ENV_CACHE)
    return fallback


def meshsom_cache_root() -> Path:
    """meshsom's cache folder (``$MESHSOM_CACHE_DIR``, else ``meshsom`` in :func:`user_cache`, after
    :func:`ensure_user_cache`), or, where that cannot be written, a private temporary folder (one
    warning per process)."""
    ensure_user_cache()
    return _root(os.environ.get(ENV_CACHE), os.environ.get("XDG_CACHE_HOME"), os.environ.get("HOME"))


_CHECKED: list[bool] = []


def ensure_user_cache() -> dict[str, str]:
    """Before OpenCL is first used in this process: where the user's cache folder cannot be
    written, point ``XDG_CACHE_HOME`` at a private temporary folder (PoCL would show no device,
    pyopencl could not launch a kernel); where ``POCL_CACHE_DIR`` is set to a folder that cannot be
    written, point it at one too. One warning each; child processes inherit the environment.
    matplotlib's configuration folder, where it cannot be written, gets one too (``MPLCONFIGDIR``,
    without a word: matplotlib would warn in two lines).

    Returns
    -------
    dict
        The variables set (empty when nothing had to change).
    """
    if _CHECKED:
        return {}
    _CHECKED.append(True)
    changed = {}
    cache = user_cache()
    why = unwritable(cache)
    if why is not None:
        folder = private_temp("xdg-cache")
        os.environ["XDG_CACHE_HOME"] = changed["XDG_CACHE_HOME"] = str(folder)
        _warn("the user's cache folder %s cannot be written (%s): PoCL would show no OpenCL device and pyopencl "
              "could not launch kernels; XDG_CACHE_HOME=%s for this run (set XDG_CACHE_HOME to a writable folder "
              "to keep compiled kernels and probe verdicts)", cache or "~/.cache", why, folder)
    if not os.environ.get("MPLCONFIGDIR"):  # matplotlib would say so in two lines of its own
        try:
            config = Path(os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config") / "matplotlib"
        except (RuntimeError, KeyError):
            config = None
        if unwritable(config) is not None:
            os.environ["MPLCONFIGDIR"] = changed["MPLCONFIGDIR"] = str(private_temp("matplotlib"))
    pocl = os.environ.get(ENV_POCL_CACHE)
    if pocl:
        why = unwritable(Path(pocl))
        if why is not None:
            folder = private_temp("pocl")
            os.environ[ENV_POCL_CACHE] = changed[ENV_POCL_CACHE] = str(folder)
            _warn("%s=%s cannot be written (%s): PoCL would show no OpenCL device; %s=%s for this run",
                  ENV_POCL_CACHE, pocl, why, ENV_POCL_CACHE, folder)
    return changed
