"""Observers of the companion core: what recorders and viewers see, no cost when none is set.

The service (:mod:`companion.service`) hands every core step to its :class:`Observers`:
the typed input (:mod:`companion.core.events`: ``Tick``, ``MavlinkReceived``,
``FrameReceived``) and the outputs the core returned for it, *after* the adapters carried
them out (so a MAVLink output's ``get_msgbuf()`` holds the bytes that went on the wire).
An empty :class:`Observers` is falsy: the service pays one truth test per step when
recording and viewing are off.

Contract for an observer (:class:`CompanionObserver`): every method is called on the
service's thread and must return quickly (any file or network I/O on a thread of its
own); the arguments are the core's own objects and must not be modified; an exception
raised by an observer is logged once per observer and method and never reaches the
service. An observer that draws the pipeline sets ``wants_pipeline = True``: the core is
then built to return a :class:`~companion.core.events.FrameProcessed` per processed frame.

==================================  ===================================================
method                              when
==================================  ===================================================
``on_start(config, instance_id)``   once, after the sockets are open (``instance_id``:
                                    the core's constructor input, for replay)
``on_step(event, outputs)``         every core step, in order
``close()``                         once, at exit: flush and release
==================================  ===================================================
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from companion.core.events import Input, Output

__all__ = ["CompanionObserver", "Observers"]

_log = logging.getLogger("companion.observe")


class CompanionObserver:
    """Base class: every method does nothing; override the ones you need."""

    wants_pipeline: bool = False  # True: the core reports FrameProcessed outputs

    def on_start(self, config, instance_id: int) -> None:
        """The service is open; ``config`` is its :class:`~companion.config.CompanionConfig`."""

    def on_step(self, event: Input, outputs: Sequence[Output]) -> None:
        """The core took ``event`` and returned ``outputs`` (already carried out)."""

    def close(self) -> None:
        """Flush and release; called once at exit."""


class Observers(CompanionObserver):
    """A list of observers behind one observer; falsy when empty (the service's guard)."""

    def __init__(self, observers: Sequence[CompanionObserver] = ()) -> None:
        self._observers: list[CompanionObserver] = list(observers)
        self._failed: set[tuple[int, str]] = set()

    def __bool__(self) -> bool:
        return bool(self._observers)

    def __len__(self) -> int:
        return len(self._observers)

    @property
    def wants_pipeline(self) -> bool:  # type: ignore[override]
        return any(o.wants_pipeline for o in self._observers)

    def _call(self, method: str, *args: Any) -> None:
        for i, obs in enumerate(self._observers):
            try:
                getattr(obs, method)(*args)
            except Exception as exc:  # an observer's bug must never stop the companion
                if (i, method) not in self._failed:
                    self._failed.add((i, method))
                    _log.error(
                        "%s.%s failed (%s: %s); further failures of it are not logged",
                        type(obs).__name__,
                        method,
                        type(exc).__name__,
                        exc,
                    )

    def on_start(self, config, instance_id: int) -> None:
        self._call("on_start", config, instance_id)

    def on_step(self, event: Input, outputs: Sequence[Output]) -> None:
        self._call("on_step", event, outputs)

    def close(self) -> None:
        self._call("close")
