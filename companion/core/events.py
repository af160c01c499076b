"""The companion core's inputs and outputs: explicit, typed, time-stamped events.

Everything that reaches :class:`~companion.core.CompanionCore` is one of the *inputs*
below, each stamped with the host's monotonic clock (``now_ns``, the core's only notion of
wall time); everything it does is one of the *outputs*, returned in the order the adapters
must carry them out. A recorder that captures the inputs can feed them back to a fresh
core and get the same outputs (the core draws no random numbers and reads no clock; its
instance id is an input of its constructor).

Inputs
------
:class:`Tick`
    The clock advanced (timers: heartbeat, TIMESYNC, stream and mode requests, link loss,
    setpoint keep-alive, failsafe).
:class:`MavlinkReceived`
    One MAVLink message from the link (pymavlink object; ``message.get_msgbuf()`` is its
    wire form for a recorder).
:class:`FrameReceived`
    One decoded stereo frame taken from the intake (``received_ns``: when it arrived).

Outputs
-------
:class:`SendMavlink`
    A MAVLink message to send to the autopilot (STATUSTEXT, commands, TIMESYNC, ...).
:class:`SendSetpoint`
    A position target to send (a MAVLink message too; separate so the adapter can stamp
    the time it went on the wire for the latency figures).
:class:`Event`
    Something worth a test's or an operator's attention (``COMPANION EVENT <name>``).
:class:`Status`
    The status document of one processed frame (published on Zenoh).
:class:`FrameProcessed`
    Only from a core built with ``report_pipeline=True`` (a viewer is attached): the
    frame, its pose and the pipeline's whole output, for drawing (never carried out).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from companion.link.setpoints import PositionTarget
from protocols.stereo_frame import StereoFrame

if TYPE_CHECKING:
    from companion.known_space import KnownSpace
    from companion.pipeline import PipelineOutput, PoseAtCapture

__all__ = [
    "Event",
    "FrameProcessed",
    "FrameReceived",
    "Input",
    "MavlinkReceived",
    "MissionStep",
    "Notice",
    "Output",
    "SendMavlink",
    "SendSetpoint",
    "Status",
    "Tick",
]


@dataclass(frozen=True)
class Tick:
    """The host clock read ``now_ns`` [ns, monotonic]."""

    now_ns: int


@dataclass(frozen=True, eq=False)
class MavlinkReceived:
    """``message`` (a pymavlink ``MAVLink_message``) arrived at ``now_ns`` [ns, monotonic]."""

    message: Any
    now_ns: int


@dataclass(frozen=True, eq=False)
class FrameReceived:
    """A decoded frame, received at ``received_ns`` and handed over at ``now_ns`` [ns]."""

    frame: StereoFrame
    received_ns: int
    now_ns: int


Input = Tick | MavlinkReceived | FrameReceived


@dataclass(frozen=True, eq=False)
class SendMavlink:
    """Send ``message`` (pymavlink ``MAVLink_message``) to the autopilot."""

    message: Any


@dataclass(frozen=True, eq=False)
class SendSetpoint:
    """Send the position target ``target`` as ``message`` (SET_POSITION_TARGET_LOCAL_NED)."""

    message: Any
    target: PositionTarget


@dataclass(frozen=True)
class Event:
    """A named event with JSON-ready fields (``COMPANION EVENT <name> {fields}``)."""

    name: str
    fields: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Status:
    """One processed frame's status document (:func:`companion.status.status_document`).

    ``host_capture_ns``: the frame's capture time on the host's clock (None when frames
    are stamped on the simulation clock), for the capture-to-send latency the adapter adds.
    """

    document: dict[str, Any]
    received_ns: int
    started_ns: int
    host_capture_ns: int | None


@dataclass(frozen=True)
class Notice:
    """A line for the operator (STATUSTEXT on the networked path)."""

    text: str
    warning: bool = False


@dataclass(frozen=True, eq=False)
class MissionStep:
    """One frame's result: the pipeline output toward waypoint ``waypoint`` and reports."""

    output: PipelineOutput
    waypoint: int
    notices: tuple[Notice, ...]
    events: tuple[Event, ...]


@dataclass(frozen=True, eq=False)
class FrameProcessed:
    """A frame went through the mission (for viewers; see :mod:`companion.viz`).

    ``pose`` (:class:`~companion.pipeline.PoseAtCapture`) gave ``step``
    (:class:`MissionStep`: the pipeline output and waypoint);
    ``goal_ned_m`` is the waypoint flown to [m, NED]; ``known_space`` the pipeline's live
    known-space model (read it on another thread only as a picture: it keeps changing);
    ``setpoint_sent``: the frame's setpoint went to the autopilot. Read-only.
    """

    frame: StereoFrame
    pose: PoseAtCapture
    step: MissionStep
    goal_ned_m: np.ndarray
    known_space: KnownSpace
    setpoint_sent: bool


Output = SendMavlink | SendSetpoint | Event | Status | FrameProcessed
