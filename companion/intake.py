"""Frame intake adapter: the Zenoh session's stereo subscriber, and "why no frames?".

Opens the frame subscriber into a :class:`~companion.frames_sub.LatestFrameSlot` and, while
no frame arrives on our key, a :class:`~companion.frames_sub.PublisherProbe` that finds
which vehicle ids *do* publish (a wrong ``--vehicle-id``). :meth:`FrameIntake.watch` says
so every 10 s. I/O only: decisions about frames are the core's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import zenoh

from companion.core.events import Event
from companion.frames_sub import FrameSubscriber, LatestFrameSlot, PublisherProbe

__all__ = ["FrameIntake"]

_log = logging.getLogger("companion")


class FrameIntake:
    """Frames on ``key`` into ``slot``; ``accept_capture_ns`` is asked on Zenoh's thread."""

    def __init__(
        self,
        key: str,
        slot: LatestFrameSlot,
        accept_capture_ns: Callable[[int], bool | None],
    ) -> None:
        self.key = key
        self.slot = slot
        self._accept = accept_capture_ns
        self._subscriber: FrameSubscriber | None = None
        self._probe: PublisherProbe | None = None
        self._seen = 0
        self._silent_since_s = 0.0
        self._reported_s = -math.inf

    def open(self, session: zenoh.Session, now_s: float) -> None:
        self._subscriber = FrameSubscriber(
            session, self.key, self.slot, accept_capture_ns=self._accept
        )
        self._subscriber.open()
        self._probe = PublisherProbe(session)
        self._probe.open()  # until our own frames arrive: who publishes, if not us?
        self._silent_since_s = now_s

    def close(self) -> None:
        if self._probe is not None:
            self._probe.close()
        if self._subscriber is not None:
            self._subscriber.close()

    def watch(self, now_s: float) -> Event | None:
        """No frames on our key for a while: say so, and which vehicle ids do publish."""
        received = self.slot.counters.received
        if received != self._seen:
            self._seen = received
            self._silent_since_s = now_s
            if self._probe is not None and self._probe.active:
                self._probe.close()
            return None
        silent = now_s - self._silent_since_s
        if silent < 5.0 or now_s - self._reported_s < 10.0 or self._probe is None:
            return None
        self._reported_s = now_s
        if not self._probe.active:
            self._probe.open()
            return None  # give it a moment to see what is published
        others = self._probe.vehicles()
        hint = (
            f"frames are published for vehicle id(s) {', '.join(others)}: check --vehicle-id"
            if others
            else "nothing publishes stereo frames that this session can see: check the camera "
            "(stereo-camera / plant-sim), the Zenoh endpoints and credentials"
        )
        _log.warning("no stereo frames on %s for %.0f s; %s", self.key, silent, hint)
        return Event(
            "no_frames", {"key": self.key, "silent_s": round(silent, 1), "publishers": others}
        )
