"""``python -m protocols.wait_ready FILE [--timeout S] -- COMMAND...``: start COMMAND once
another process's ready file (``--ready-file``) exists.

In the Compose SIL stack plant-sim *is* the autopilot, so it cannot wait for the
companion to be healthy (the companion is healthy only once an autopilot talks to it);
it waits for the companion's sockets instead (its ready file on a volume both containers
mount), then replaces itself with COMMAND (``exec``: signals and exit status are
COMMAND's). After ``--timeout`` seconds without the file it exits 2 with a message.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main", "wait_for_file"]


def wait_for_file(path: Path, timeout_s: float, poll_s: float = 0.1) -> bool:
    """True once ``path`` exists, False after ``timeout_s`` seconds without it."""
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if time.monotonic() >= deadline:
            return False
        time.sleep(poll_s)
    return True


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m protocols.wait_ready",
        description="Run COMMAND once FILE (another process's --ready-file) exists.",
    )
    p.add_argument("file", type=Path)
    p.add_argument("--timeout", type=float, default=120.0, help="seconds (default 120)")
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv or argv.index("--") == len(argv) - 1:
        p.error("no command given: FILE [--timeout S] -- COMMAND [ARGS...]")
    split = argv.index("--")
    args = p.parse_args(argv[:split])
    command = argv[split + 1 :]
    if not wait_for_file(args.file, args.timeout):
        print(
            f"wait_ready: {args.file} did not appear within {args.timeout:g} s: the process "
            f"that writes it (its --ready-file) is not up; see its log. Not starting {command[0]}",
            file=sys.stderr,
            flush=True,
        )
        return 2
    try:
        os.execvp(command[0], command)
    except OSError as exc:
        print(f"wait_ready: cannot run {command[0]}: {exc}", file=sys.stderr, flush=True)
        return 127
    raise AssertionError("unreachable: execvp returns only by raising")


if __name__ == "__main__":
    sys.exit(main())
