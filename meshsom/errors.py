"""The project's own error types.

Every error raised for bad *input* (a file, a mesh, a config) is one of these, so
callers can catch exactly what meshsom documents and nothing else. Each carries
the name of the source it came from, and its message says what was received and
what was expected.
"""

from __future__ import annotations


class MeshsomError(Exception):
    """Base class of every error meshsom raises on purpose."""


class InputFileError(MeshsomError, ValueError):
    """A file could not be read or does not hold what it should.

    Parameters
    ----------
    source : str
        The file (and, where known, the object inside it) the problem is in.
    problem : str
        What was received and what was expected.
    """

    def __init__(self, source: str, problem: str):
        self.source = str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}")


class MeshError(MeshsomError, ValueError):
    """A mesh is not what a step needs (open, non-manifold, inside-out, degenerate).

    Parameters
    ----------
    source : str
        The mesh id (file + object id) or a description of the array.
    problem : str
        What was received and what was expected.
    """

    def __init__(self, source: str, problem: str):
        self.source = str(source)
        self.problem = problem
        super().__init__(f"{self.source}: {problem}")


class ConfigError(MeshsomError, ValueError):
    """A configuration file or value is invalid; the message names the key."""


class StoreError(MeshsomError, ValueError):
    """A zarr store is missing something or does not follow the layout."""


class DeviceError(MeshsomError, RuntimeError):
    """No usable OpenCL device where one was asked for explicitly."""
