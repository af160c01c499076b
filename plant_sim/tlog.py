"""MAVLink telemetry log (.tlog): each frame prefixed by its time, as pymavlink writes it.

Record = 8-byte big-endian unsigned timestamp [µs since the Unix epoch, wall clock] followed
by the raw MAVLink frame — the format of MAVProxy's logs, read by
``pymavlink.mavutil.mavlink_connection("run.tlog")`` and MAVExplorer. The frames' own
``time_boot_ms`` / ``time_usec`` fields carry simulation time.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path
from typing import BinaryIO

__all__ = ["TlogWriter"]

_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append frames to a .tlog; use as a context manager or call :meth:`close`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO | None = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self.frames = 0

    def write(self, frame: bytes, wall_unix_s: float | None = None) -> None:
        """Record ``frame`` with the wall time ``wall_unix_s`` (default: now)."""
        if self._file is None:
            return
        now = time.time() if wall_unix_s is None else wall_unix_s
        self._file.write(_STAMP.pack(int(now * 1e6)))
        self._file.write(frame)
        self.frames += 1

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
