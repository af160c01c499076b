"""The readiness signal every process gives once its sockets are bound.

One line on stdout (tests and orchestration wait for it) and, optionally, the same line
in a file that exists exactly while the process is ready (container healthchecks test
for it). The file is complete before the stdout line appears.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["announce_ready", "withdraw_ready"]


def announce_ready(line: str, ready_file: Path | None = None) -> None:
    """Write ``line`` to ``ready_file`` (atomically, if given), then print it to stdout."""
    if ready_file is not None:
        partial = ready_file.with_name(ready_file.name + ".partial")
        partial.write_text(line + "\n", encoding="utf-8")
        partial.replace(ready_file)
    print(line, flush=True)


def withdraw_ready(ready_file: Path | None) -> None:
    """Remove the ready file at shutdown (no-op without one)."""
    if ready_file is not None:
        ready_file.unlink(missing_ok=True)
