"""A wall-clock limit on one mesh's preprocessing, checked where the work loops.

Preprocessing one building is bounded by counts (cut searches, union attempts, repair rounds),
not by time, and a real city holds meshes no test has seen: one of them must not hold up a run.
:func:`time_limit` sets a deadline for the code it wraps (per thread and task, through a context
variable, so Dask's worker threads keep their own), and :func:`check`, called at the top of each
repair round, cut search and union attempt, raises :class:`TimeLimitExceeded` once it has passed.
That exception is not a :class:`meshsom.errors.MeshError`: no repair step takes it as "this
repair failed, try the next", so it ends the mesh's preprocessing, and
:func:`pipelines.ingest.process_one` lists the mesh as rejected with the stage it stopped in.
"""

from __future__ import annotations

import contextvars
import time
from contextlib import contextmanager

#: (monotonic deadline, the limit in seconds) of the code running in this context, or None.
_DEADLINE: contextvars.ContextVar[tuple[float, float] | None] = contextvars.ContextVar("meshsom_deadline", default=None)


class TimeLimitExceeded(Exception):
    """The wrapped work ran past its limit.

    Attributes
    ----------
    seconds : float
        The limit.
    stage : str
        What was running when a check found it passed.
    """

    def __init__(self, seconds: float, stage: str):
        self.seconds, self.stage = seconds, stage
        super().__init__(f"took more than {seconds:g} s, stopped while {stage}")

    def __reduce__(self):  # picklable across Dask
        return (type(self), (self.seconds, self.stage))


@contextmanager
def time_limit(seconds: float):
    """Run the block with a deadline ``seconds`` from now (0 or less: none); nested limits keep the
    earlier deadline."""
    outer = _DEADLINE.get()
    if not seconds or seconds <= 0:
        yield
        return
    deadline = (time.monotonic() + float(seconds), float(seconds))
    token = _DEADLINE.set(deadline if outer is None or deadline[0] < outer[0] else outer)
    try:
        yield
    finally:
        _DEADLINE.reset(token)


def check(stage: str) -> None:
    """Raise :class:`TimeLimitExceeded` where the deadline of the enclosing :func:`time_limit` has
    passed; nothing outside one."""
    deadline = _DEADLINE.get()
    if deadline is not None and time.monotonic() > deadline[0]:
        raise TimeLimitExceeded(deadline[1], stage)
