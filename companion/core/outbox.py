"""The companion core's outputs of one step, in order, and the log lines beside them.

:class:`Outbox` collects what :meth:`CompanionCore.step <companion.core.CompanionCore.step>`
returns (MAVLink messages, setpoints, events, status) and writes the operator's lines:
STATUSTEXT (chunked above 50 characters, MAVLink 2) and rate-limited drop warnings. Pure:
the time it stamps rate limits with is the step's, set by :meth:`Outbox.begin`.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.counters import CoreCounters
from companion.core.events import Event, Output, SendMavlink, SendSetpoint
from companion.link.messages import statustext_messages
from companion.link.setpoints import PositionTarget

__all__ = ["SEV_INFO", "SEV_WARNING", "Outbox"]

_log = logging.getLogger("companion")

SEV_INFO = mavlink.MAV_SEVERITY_INFO
SEV_WARNING = mavlink.MAV_SEVERITY_WARNING
_DROP_LOG_PERIOD_S = 2.0  # one warning per kind of drop per this long [s wall]


class Outbox:
    """One step's outputs; counts every MAVLink message in ``counters.mavlink_sent``."""

    def __init__(self, counters: CoreCounters) -> None:
        self.counters = counters
        self._items: list[Output] = []
        self._now_s = 0.0
        self._text_id = 0  # id of the last chunked STATUSTEXT (1..255)
        self._drop_log_s: dict[str, float] = {}

    def begin(self, now_s: float) -> None:
        """A new step at ``now_s`` [s, host monotonic]: nothing collected yet."""
        self._now_s = now_s
        self._items = []

    def take(self) -> list[Output]:
        """What was collected since :meth:`begin`, in order."""
        items, self._items = self._items, []
        return items

    @property
    def items(self) -> list[Output]:
        """What was collected so far (read-only view for tests and viewers)."""
        return list(self._items)

    def send(self, message) -> None:
        """A MAVLink message to the autopilot."""
        self._items.append(SendMavlink(message))
        self.counters.mavlink_sent += 1

    def setpoint(self, message, target: PositionTarget) -> None:
        """SET_POSITION_TARGET_LOCAL_NED ``message`` carrying ``target``."""
        self._items.append(SendSetpoint(message, target))
        self.counters.mavlink_sent += 1

    def append(self, output: Output) -> None:
        """An output that is not a MAVLink message (status, a frame for the viewer)."""
        self._items.append(output)

    def extend(self, outputs) -> None:
        self._items.extend(outputs)

    def event(self, name: str, **fields: Any) -> None:
        self._items.append(Event(name, fields))

    def notice(self, text: str, severity: int = SEV_INFO) -> None:
        """STATUSTEXT to the ground station; longer than 50 characters: MAVLink 2 chunks."""
        _log.info("STATUSTEXT: %s", text)
        if len(text) > 50:
            self._text_id = self._text_id % 255 + 1
        for msg in statustext_messages(text, severity, self._text_id or 1):
            self.send(msg)

    def drop_log(self, key: str, fmt: str, *args: Any) -> None:
        """A warning, at most one per ``key`` every 2 s."""
        if self._now_s - self._drop_log_s.get(key, -math.inf) >= _DROP_LOG_PERIOD_S:
            self._drop_log_s[key] = self._now_s
            _log.warning(fmt, *args)

    def dropped(self, kind: str, count: int, what: str, values: Any) -> None:
        """An input of ``kind`` dropped (``count`` so far): one warning every 2 s."""
        self.drop_log(kind, "%s: dropped %s %s (%d so far)", kind, what, values, count)
