"""pymeshlab's mesh repairs (``PreprocessParams.repair``), run in a child process.

pymeshlab may not run in the user's process. Its filters live in Qt plugins that a global plugin
manager loads on first use, as Qt objects bound to the thread that loaded them. Where that is not
the main thread -- a Dask worker's task thread, where the pipelines preprocess -- Qt frees that
thread's data when the thread ends, and the plugin manager's destructor, run at exit, reads and
frees it again: heap corruption, and ``malloc_consolidate(): unaligned fastbin chunk detected``
aborting ``meshsom ingest --repair`` after its work (valgrind: ``QThreadData::deref`` in
``PluginManager::~PluginManager``, the block freed at the thread's end). A corrupted heap can
change results before it aborts anything. So the repairs run in one long-lived child process per
process (``python -m meshsom.meshlab_repair``), in its main thread, started on the first repair:
meshes go to it and back through pipes (NumPy's ``.npy`` format, no pickle), and a child that
crashes or hangs costs the mesh it was repairing (a :class:`meshsom.errors.MeshError` saying so),
not the process; the next repair starts a new child.

The repair: duplicate vertices and faces removed, non-manifold edges repaired, holes of up to
:data:`MAX_HOLE_EDGES` edges closed.

Test hook (never set it otherwise): ``MESHSOM_MESHLAB_INJECT=abort`` makes the child abort on its
first request (as a native crash would), ``hang`` makes it sleep past any timeout.
"""

from __future__ import annotations

import atexit
import importlib
import io
import os
import select
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from meshsom.errors import MeshError

#: Holes of up to this many edges are closed.
MAX_HOLE_EDGES = 10_000
#: Seconds one repair may take in the child before it is killed and the mesh rejected.
REPAIR_TIMEOUT_S = 300.0
#: Seconds the child is given to start (Python, NumPy and pymeshlab imported) before a request counts.
START_TIMEOUT_S = 120.0
ENV_INJECT = "MESHSOM_MESHLAB_INJECT"
_OK, _FAILED, _READY = b"k", b"e", b"r"


def _arrays_to_bytes(*arrays: np.ndarray) -> bytes:
    out = io.BytesIO()
    for a in arrays:
        np.save(out, np.ascontiguousarray(a), allow_pickle=False)
    return out.getvalue()


def _bytes_to_arrays(data: bytes, count: int) -> list[np.ndarray]:
    stream = io.BytesIO(data)
    return [np.load(stream, allow_pickle=False) for _ in range(count)]


def _repair_here(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The repair itself, in this process (the child's; raises pymeshlab's exceptions)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(vertices, np.float64), face_matrix=np.asarray(faces, np.int32)))
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_duplicate_faces()
    ms.meshing_repair_non_manifold_edges()
    ms.meshing_close_holes(maxholesize=MAX_HOLE_EDGES)
    m = ms.current_mesh()
    return np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64)


class _Child:
    """One child process and the pipes to it."""

    def __init__(self):
        self.stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "meshsom.meshlab_repair"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.stderr, bufsize=0)
        self.pid = os.getpid()
        try:  # ready once pymeshlab is imported (START_TIMEOUT_S): a request's time is the repair's only
            if self._read(1, time.monotonic() + START_TIMEOUT_S) != _READY:
                raise EOFError
        except (TimeoutError, EOFError):
            what = self.what_happened()
            raise MeshError("pymeshlab", f"its repair process did not start within {START_TIMEOUT_S:g} s ({what})") from None

    def _read(self, n: int, deadline: float) -> bytes:
        fd, data = self.proc.stdout.fileno(), bytearray()
        while len(data) < n:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError
            chunk = os.read(fd, n - len(data))
            if not chunk:
                raise EOFError
            data += chunk
        return bytes(data)

    def request(self, payload: bytes, timeout: float) -> tuple[bytes, bytes]:
        self.proc.stdin.write(struct.pack("<Q", len(payload)) + payload)
        deadline = time.monotonic() + timeout
        status = self._read(1, deadline)
        (size,) = struct.unpack("<Q", self._read(8, deadline))
        return status, self._read(size, deadline)

    def what_happened(self) -> str:
        """Why the child stopped: its exit status and the last line it wrote to stderr."""
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.kill()
        code = self.proc.returncode
        self.stderr.seek(0)
        lines = [line for line in self.stderr.read().decode("utf-8", "replace").splitlines() if line.strip()]
        how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit status {code}"
        return how + (f": {lines[-1].strip()[:200]}" if lines else "")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def close(self) -> None:
        try:
            self.proc.stdin.close()  # the child's loop ends at end of input
            self.proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            self.kill()
        self.stderr.close()


_LOCK = threading.Lock()
_CHILD: list[_Child] = []  # at most one, of this process (a forked process starts its own)


def _child() -> _Child:
    if _CHILD and (_CHILD[0].pid != os.getpid() or _CHILD[0].proc.poll() is not None):
        old = _CHILD.pop()
        if old.pid == os.getpid():
            old.close()
    if not _CHILD:
        _CHILD.append(_Child())
    return _CHILD[0]


def shutdown() -> None:
    """Stop this process's repair child (also at exit); the next repair starts a new one."""
    with _LOCK:
        if _CHILD and _CHILD[0].pid == os.getpid():
            _CHILD.pop().close()


atexit.register(shutdown)


def repair(vertices: np.ndarray, faces: np.ndarray, source: str, timeout: float = REPAIR_TIMEOUT_S
           ) -> tuple[np.ndarray, np.ndarray]:
    """pymeshlab's repair of a mesh, in the child process (see the module).

    Parameters
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) integer
    source : str
        The mesh, for messages.
    timeout : float
        Seconds the repair may take.

    Returns
    -------
    vertices : (V', 3) float64
    faces : (F', 3) int64

    Raises
    ------
    MeshError
        pymeshlab failed, or its child crashed or took longer than ``timeout`` (and was stopped).
    """
    payload = _arrays_to_bytes(np.asarray(vertices, np.float64), np.asarray(faces, np.int32))
    with _LOCK:
        try:
            child = _child()
        except MeshError as err:
            raise MeshError(source, f"pymeshlab repair: {err.problem}") from None
        try:
            status, data = child.request(payload, timeout)
        except TimeoutError:
            child.kill()
            _CHILD.clear()
            raise MeshError(source, f"pymeshlab repair took longer than {timeout:g} s and was stopped") from None
        except (EOFError, BrokenPipeError, OSError):
            what = child.what_happened()
            _CHILD.clear()
            raise MeshError(source, f"pymeshlab repair crashed ({what}); the mesh is not repaired") from None
    if status == _FAILED:
        raise MeshError(source, f"pymeshlab repair failed ({data.decode('utf-8', 'replace').strip()})")
    v, f = _bytes_to_arrays(data, 2)
    return v, f


def _serve() -> int:
    """The child's loop: a request (length, two arrays) in, the status and answer out, until end of input."""
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    inject = os.environ.get(ENV_INJECT, "")
    importlib.import_module("pymeshlab")  # its plugins loaded here, in the main thread

    stdout.write(_READY)
    stdout.flush()
    while True:
        head = stdin.read(8)
        if len(head) < 8:
            return 0
        (size,) = struct.unpack("<Q", head)
        data = stdin.read(size)
        if inject == "abort":
            os.abort()
        if inject == "hang":
            time.sleep(3600)
        try:
            vertices, faces = _bytes_to_arrays(data, 2)
            answer, status = _arrays_to_bytes(*_repair_here(vertices, faces)), _OK
        except Exception as err:  # pymeshlab.PyMeshLabException and anything else: the parent's MeshError
            text = str(err).strip() if type(err).__name__ == "PyMeshLabException" else f"{type(err).__name__}: {err}"
            answer, status = text.encode(), _FAILED
        stdout.write(status + struct.pack("<Q", len(answer)) + answer)
        stdout.flush()


if __name__ == "__main__":
    sys.exit(_serve())
