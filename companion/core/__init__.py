"""The companion's pure core: typed inputs in, typed outputs out (no sockets, no clock).

:class:`CompanionCore` (the whole companion: link state machine, failsafe, takeover,
takeoff, mission; one module per job behind it) and :class:`Mission` (waypoints around
the avoidance pipeline, which the lockstep harness runs too); their inputs and outputs are
in :mod:`companion.core.events`.
"""

from companion.core.companion_core import STREAMS, CompanionCore
from companion.core.events import (
    Event,
    FrameProcessed,
    FrameReceived,
    Input,
    MavlinkReceived,
    Output,
    SendMavlink,
    SendSetpoint,
    Status,
    Tick,
)
from companion.core.mission import Mission, MissionStep, Notice

__all__ = [
    "STREAMS",
    "CompanionCore",
    "Event",
    "FrameProcessed",
    "FrameReceived",
    "Input",
    "MavlinkReceived",
    "Mission",
    "MissionStep",
    "Notice",
    "Output",
    "SendMavlink",
    "SendSetpoint",
    "Status",
    "Tick",
]
