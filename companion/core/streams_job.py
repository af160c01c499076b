"""Streams and TIMESYNC: the telemetry streams requested until acknowledged, TIMESYNC both ways.

A component of :class:`~companion.core.CompanionCore` that owns its state: the stream
requests (SET_MESSAGE_INTERVAL for :data:`STREAMS`, repeated each second until every one
is acknowledged) and our outstanding TIMESYNC requests. Typed in: the step's time, the
autopilot's TIMESYNC and its SET_MESSAGE_INTERVAL acknowledgements. Out: its messages in
the step's :class:`~companion.core.outbox.Outbox`, and the
:class:`~companion.clock_model.SyncSample` of each answer that matches a request of ours,
which the core feeds to the autopilot's clock (:mod:`companion.clock_model`).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import SyncSample
from companion.config import LinkConfig
from companion.core.counters import CoreCounters
from companion.core.outbox import Outbox
from companion.link.messages import set_message_interval, timesync_reply, timesync_request

__all__ = ["STREAMS", "StreamsJob"]

#: telemetry streams the core requests with SET_MESSAGE_INTERVAL
STREAMS = (
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE,
)
_MAX_TIMESYNC_PENDING = 32  # our outstanding TIMESYNC requests (replies must match one)
_STREAM_RETRY_S = 1.0  # stream requests again after this long without every ack [s wall]


class StreamsJob:
    """Stream requests until acknowledged; TIMESYNC requests, replies and answers.

    Parameters
    ----------
    link : LinkConfig
        The autopilot's ids, the telemetry rate and the TIMESYNC period.
    out : Outbox
        Where the requests and replies go (the core's, per step).
    counters : CoreCounters
        ``timesync_unmatched`` counts answers to no request of ours.
    """

    def __init__(self, link: LinkConfig, out: Outbox, counters: CoreCounters) -> None:
        self._link = link
        self._out = out
        self._counters = counters
        self._timesync_pending: list[int] = []  # host ns stamps of our requests
        self._next_timesync_s = 0.0
        self._streams_acked = 0  # accepted SET_MESSAGE_INTERVAL since the last request
        self._next_stream_request_s = 0.0

    def reset(self) -> None:
        """Link lost or autopilot restarted: the streams are requested again."""
        self._streams_acked = 0
        self._next_stream_request_s = 0.0

    def link_up(self, now_s: float) -> None:
        """The link came up: request the streams and the autopilot's time at once."""
        self._next_stream_request_s = now_s
        self._next_timesync_s = now_s

    def request_streams_now(self, now_s: float) -> None:
        """The autopilot restarted: request the streams at once."""
        self._next_stream_request_s = now_s

    def timers(self, now_s: float, now_ns: int) -> None:
        """TIMESYNC requests (stamped ``now_ns``, host ns) and the stream requests, when
        due (the link is up)."""
        cfg = self._link
        if now_s >= self._next_timesync_s:
            self._timesync_pending.append(now_ns)
            del self._timesync_pending[:-_MAX_TIMESYNC_PENDING]
            self._out.send(timesync_request(now_ns))
            self._next_timesync_s = now_s + cfg.timesync_period_s
        if now_s >= self._next_stream_request_s and self._streams_acked < len(STREAMS):
            self._streams_acked = 0
            for msg_id in STREAMS:
                self._out.send(
                    set_message_interval(
                        cfg.target_system, cfg.target_component, msg_id, cfg.telemetry_rate_hz
                    )
                )
            self._next_stream_request_s = now_s + _STREAM_RETRY_S

    def on_stream_ack(self, accepted: bool) -> None:
        """A COMMAND_ACK of SET_MESSAGE_INTERVAL."""
        if accepted:
            self._streams_acked += 1

    def on_timesync(self, msg, now_ns: int) -> SyncSample | None:
        """The autopilot's TIMESYNC at host time ``now_ns``: its request answered, or our
        request's answer as a sample for the clock (None: not an answer to us, counted)."""
        if msg.tc1 == 0:  # the autopilot asks for our time
            self._out.send(timesync_reply(now_ns, msg.ts1))
            return None
        if msg.ts1 not in self._timesync_pending:
            self._counters.timesync_unmatched += 1  # not an answer to a request of ours
            return None
        self._timesync_pending.remove(msg.ts1)
        return SyncSample(msg.ts1, msg.tc1, now_ns)
