"""The core's components on their own (companion/core/*_job.py that own their state):
typed inputs in, their messages in the Outbox, typed decisions out."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import SyncSample
from companion.config import LinkConfig
from companion.core.counters import CoreCounters
from companion.core.events import SendMavlink
from companion.core.outbox import Outbox
from companion.core.param_job import WPNAV_SPEED, ParamJob
from companion.core.status_job import StateView, companion_state
from companion.core.streams_job import STREAMS, StreamsJob
from companion.failsafe import Response
from companion.link.messages import CompanionState
from companion.link.mode_watch import ControlPhase


def _sent(out: Outbox) -> list:
    return [o.message for o in out.take() if isinstance(o, SendMavlink)]


def _outbox() -> Outbox:
    out = Outbox(CoreCounters())
    out.begin(0.0)
    return out


def _param_value(name: str, value: float):
    return mavlink.MAVLink_param_value_message(
        name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32, 1, 0
    )


def test_wpnav_speed_is_asked_for_every_2_s_at_most_5_times():
    out = _outbox()
    params = ParamJob(LinkConfig(), out)
    asked_at = []
    for tenth in range(0, 200):  # 20 s of steps at 10 Hz
        now_s = tenth / 10.0
        params.request_if_due(now_s)
        if _sent(out):
            asked_at.append(now_s)
    assert asked_at == pytest.approx([0.0, 2.0, 4.0, 6.0, 8.0])
    assert params.wpnav_speed_mps is None


def test_a_reported_wpnav_speed_stops_the_requests_and_other_values_are_ignored():
    out = _outbox()
    params = ParamJob(LinkConfig(), out)
    params.request_if_due(0.0)
    assert len(_sent(out)) == 1
    for name, value in (("WPNAV_ACCEL", 250.0), (WPNAV_SPEED, math.nan), (WPNAV_SPEED, -1.0)):
        params.on_param_value(_param_value(name, value))
        assert params.wpnav_speed_mps is None
    params.on_param_value(_param_value(WPNAV_SPEED, 550.0))  # [cm/s]
    assert params.wpnav_speed_mps == pytest.approx(5.5)
    params.request_if_due(10.0)
    assert _sent(out) == []
    params.reset()  # a new connection: asked for again
    assert params.wpnav_speed_mps is None
    params.request_if_due(10.0)
    assert len(_sent(out)) == 1


def test_streams_are_requested_each_second_until_every_one_is_acknowledged():
    out = _outbox()
    link = LinkConfig()
    streams = StreamsJob(link, out, CoreCounters())
    streams.link_up(0.0)
    rounds = []
    for tenth in range(0, 40):
        now_s = tenth / 10.0
        if tenth == 25:  # both acknowledged after the third round
            for _ in STREAMS:
                streams.on_stream_ack(True)
        streams.timers(now_s, round(now_s * 1e9))
        ids = [m.param1 for m in _sent(out) if m.get_type() == "COMMAND_LONG"]
        if ids:
            assert ids == list(STREAMS)
            rounds.append(now_s)
    assert rounds == pytest.approx([0.0, 1.0, 2.0])


def test_timesync_answers_the_autopilot_and_matches_our_requests():
    out = _outbox()
    counters = CoreCounters()
    streams = StreamsJob(LinkConfig(), out, counters)
    streams.link_up(0.0)
    streams.timers(0.0, 1_000)
    (request,) = [m for m in _sent(out) if m.get_type() == "TIMESYNC"]
    assert (request.tc1, request.ts1) == (0, 1_000)
    # the autopilot asks for our time: answered, no sample
    ask = mavlink.MAVLink_timesync_message(0, 77)
    assert streams.on_timesync(ask, 5_000) is None
    (reply,) = _sent(out)
    assert (reply.tc1, reply.ts1) == (5_000, 77)
    # an answer to no request of ours: counted, no sample
    assert streams.on_timesync(mavlink.MAVLink_timesync_message(9, 999), 6_000) is None
    assert counters.timesync_unmatched == 1
    # the answer to ours: its sample, once
    answer = mavlink.MAVLink_timesync_message(42_000, 1_000)
    assert streams.on_timesync(answer, 7_000) == SyncSample(1_000, 42_000, 7_000)
    assert streams.on_timesync(answer, 8_000) is None
    assert counters.timesync_unmatched == 2


def _view(**kw) -> StateView:
    fields = dict(
        link_up=True,
        link_lost_before=False,
        may_steer=True,
        phase=ControlPhase.ACTIVE,
        hold=Response.STEER,
        steering=True,
        health_ok=True,
        frame_processed=True,
    )
    return StateView(**{**fields, **kw})


@pytest.mark.parametrize(
    ("change", "state"),
    [
        ({}, CompanionState.ACTIVE),
        ({"link_up": False}, CompanionState.BOOT),
        ({"link_up": False, "link_lost_before": True}, CompanionState.LINK_LOST),
        ({"may_steer": False, "phase": ControlPhase.HOLD}, CompanionState.STANDBY),
        ({"phase": ControlPhase.HOLD}, CompanionState.HOLD),
        ({"hold": Response.HOLD_POSITION}, CompanionState.HOLD),
        ({"health_ok": False}, CompanionState.STANDBY),
        ({"steering": False, "frame_processed": False}, CompanionState.BOOT),
    ],
)
def test_the_companion_state_follows_link_takeover_hold_and_health_in_that_order(change, state):
    assert companion_state(_view(**change)) is state
