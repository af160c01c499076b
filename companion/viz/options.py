"""``--record`` and ``--rerun`` flags → companion observers (imports only when asked for).

Recording and viewing need the optional ``view`` extra (``pip install 'stereo-avoid[view]'``:
mcap, rerun-sdk, rosbags); without it the flags fail with an error that says so, and
nothing of it is imported when they are off.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

__all__ = ["EXTRA_HINT", "ViewOptionError", "observers_from_args", "require_extra"]

EXTRA_HINT = "pip install 'stereo-avoid[view]'"


class ViewOptionError(ValueError):
    """A bad ``--record`` / ``--rerun`` value, or the extra is missing; says which flag."""


def require_extra(flag: str, module: str, package: str) -> None:
    """Raise :class:`ViewOptionError` when ``module`` (of ``package``) is not installed."""
    if importlib.util.find_spec(module) is None:
        raise ViewOptionError(
            f"{flag} needs {package}, which is in the optional 'view' extra: {EXTRA_HINT}"
        )


def observers_from_args(record: Path | None, rerun: str | None) -> list:
    """The observers the flags ask for (none when both are off: nothing is imported)."""
    observers: list = []
    if record is not None:
        if record.suffix != ".mcap":
            raise ViewOptionError(f"--record takes FILE.mcap, got {str(record)!r}")
        if not record.parent.is_dir():
            raise ViewOptionError(f"--record: folder {str(record.parent)!r} does not exist")
        require_extra("--record", "mcap", "mcap")
        from companion.record.recorder import McapRecorder

        observers.append(McapRecorder(record))
    if rerun is not None:
        from companion.viz.rerun_log import RerunTarget

        try:
            target = RerunTarget.parse(rerun)
        except ValueError as exc:
            raise ViewOptionError(str(exc)) from None
        require_extra("--rerun", "rerun", "rerun-sdk")
        from companion.viz.rerun_log import RerunObserver

        observers.append(RerunObserver(target))
    return observers
