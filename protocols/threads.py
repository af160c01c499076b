"""Thread counts for compiled kernels, OpenCV and BLAS in every process (issue 32 item 7).

A parallel kernel splits each call into one piece per thread and waits for the slowest.
On a machine that is never idle (a Raspberry Pi running a camera driver and a logger, a
CI runner, the Monte Carlo's own workers) one of those threads is always waiting for a
core, and the call takes as long as the preempted piece: measured on a 2-core machine
with a busy process on the other core, the stereo renderer took 16 ms per 320×240 pair
with 2 numba threads against 4.2 ms with one (``benchmarks/bench_perception.py
--threads``). One thread per process is therefore the default: a busy neighbour then
costs a process at most its share of a core, never a barrier's worth of waiting, and the
processes of a flight (plant-sim, the companion, a camera publisher) are parallel with
each other instead.

``STEREO_AVOID_THREADS`` (a positive integer) raises it on a machine with cores to spare;
an explicit ``NUMBA_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` or ``OMP_NUM_THREADS`` still
wins for its own library. Every process calls :func:`configure_threads` first thing in
its ``main``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping
from dataclasses import dataclass

__all__ = ["DEFAULT_THREADS", "THREADS_ENV", "ThreadCounts", "configure_threads", "threads_from"]

THREADS_ENV = "STEREO_AVOID_THREADS"
DEFAULT_THREADS = 1
_MAX_THREADS = 256


@dataclass(frozen=True)
class ThreadCounts:
    """What a process runs with (for its log line and status)."""

    numba: int
    opencv: int

    def describe(self) -> str:
        return f"threads numba={self.numba} opencv={self.opencv} ({THREADS_ENV})"


def threads_from(environ: MutableMapping[str, str]) -> int:
    """The thread count ``environ`` asks for (:data:`THREADS_ENV`, default 1).

    Raises
    ------
    ValueError
        If the variable is set to anything but an integer in [1, 256].
    """
    text = environ.get(THREADS_ENV, "").strip()
    if not text:
        return DEFAULT_THREADS
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= _MAX_THREADS:
        raise ValueError(f"{THREADS_ENV} must be an integer in [1, {_MAX_THREADS}], got {text!r}")
    return n


def configure_threads(environ: MutableMapping[str, str] | None = None) -> ThreadCounts:
    """Apply the thread policy to this process (call it before the work starts).

    Sets the BLAS and numba variables for libraries not yet imported, then numba's count
    for the calling thread and OpenCV's (process-wide) count. Raises ``ValueError`` for a
    bad :data:`THREADS_ENV` (the caller reports it as a configuration error).
    """
    env = os.environ if environ is None else environ
    n = threads_from(env)
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(name, "1")
    if "numba" not in sys.modules:
        env.setdefault("NUMBA_NUM_THREADS", str(n))
    import cv2
    import numba

    numba_n = min(int(env.get("NUMBA_NUM_THREADS", n)), numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(max(1, numba_n))
    cv2.setNumThreads(n)
    return ThreadCounts(numba=numba.get_num_threads(), opencv=cv2.getNumThreads())
