"""``--log-file``: a process's stdout and stderr also go to a file (the run folder).

Everything the process prints (readiness line, events, log records, errors) is copied,
line-buffered, to the file, so a container's log is kept beside its other logs in the run
folder. A folder that cannot be written is a clear error that names it and the user id
the process runs as, instead of a bare "Permission denied" later.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path
from typing import TextIO

__all__ = ["LogFileError", "start_log_file", "start_logging", "unwritable_message"]


class LogFileError(OSError):
    """The log file (or its folder) cannot be created or written."""


def unwritable_message(folder: Path, exc: OSError) -> str:
    """Why ``folder`` cannot be written, with its owner and the uid/gid that needs access."""
    uid, gid = os.getuid(), os.getgid()
    try:
        st = folder.stat()
        owner = f"owned by uid {st.st_uid} gid {st.st_gid}, mode {st.st_mode & 0o7777:o}"
    except OSError as stat_exc:
        owner = f"cannot stat it: {stat_exc.strerror}"
    return (
        f"run folder {folder} is not writable by this process (uid {uid}, gid {gid}): "
        f"{exc.strerror or exc} ({owner}). Make it writable for uid {uid}: on the host, "
        f"`chown {uid}:{gid} <folder>` or `chmod a+rwx <folder>` on the folder mounted there "
        "(Compose: runs/<RUN_NAME>)"
    )


class _Tee:
    """A text stream that writes to the original stream and to the log file."""

    def __init__(self, stream: TextIO, log: TextIO) -> None:
        self._stream = stream
        self._log = log

    def write(self, text: str) -> int:
        self._log.write(text)
        return self._stream.write(text)

    def flush(self) -> None:
        self._log.flush()
        self._stream.flush()

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def start_log_file(path: Path | None) -> TextIO | None:
    """Copy ``sys.stdout`` and ``sys.stderr`` to ``path`` (appended; folders created).

    Call before logging is configured, so log handlers write through the copy. No-op
    without a path.

    Raises
    ------
    LogFileError
        If the folder or the file cannot be created or written (the message names the
        folder and the uid needed).
    """
    if path is None:
        return None
    path = Path(path)
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        log = path.open("a", encoding="utf-8", buffering=1)
    except OSError as exc:
        existing = folder
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        raise LogFileError(unwritable_message(existing, exc)) from None
    sys.stdout = _Tee(sys.stdout, log)  # type: ignore[assignment]
    sys.stderr = _Tee(sys.stderr, log)  # type: ignore[assignment]
    return log


def start_logging(prog: str, log_file: Path | None, log_level: str) -> bool:
    """A process's logging at start-up: stdout and stderr copied to ``log_file`` (if any),
    log records at ``log_level`` and above to stderr. False, after saying why on stderr,
    when the log file cannot be opened (the process should exit with status 2)."""
    try:
        start_log_file(log_file)
    except LogFileError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return False
    logging.basicConfig(
        level=getattr(logging, log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    return True
