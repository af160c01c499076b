"""The companion's pure core, in process (no sockets, no sleeps): pipeline and core."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import FrameClock
from companion.config import CompanionConfig
from companion.core import (
    STREAMS,
    CompanionCore,
    Event,
    FrameReceived,
    MavlinkReceived,
    SendMavlink,
    SendSetpoint,
    Status,
    Tick,
)
from companion.pipeline import AvoidancePipeline, PoseAtCapture
from protocols.camera import CameraModel
from protocols.frames import rotation_321
from protocols.mavlink_modes import px4_custom_mode
from protocols.stereo_frame import StereoFrame

CAMERA = CameraModel()


def _blank_frame(seq: int, capture_ns: int) -> StereoFrame:
    """A textureless pair: nothing matched, so no obstacle and no free space."""
    flat = np.full((CAMERA.height_px, CAMERA.width_px), 128, dtype=np.uint8)
    return StereoFrame(seq, capture_ns, CAMERA.intrinsics, flat, flat.copy())


def test_pipeline_first_yaw_is_the_vehicles_own_when_no_direction_is_defined():
    """At the goal (no direction to face) the first yaw command keeps the vehicle's yaw.

    Guidance falls back to the vehicle's yaw only if it is given one; before the fix the
    pipeline did not pass it, so a vehicle facing east was turned north (yaw 0).
    """
    yaw_east_rad = math.pi / 2
    pos = np.array([3.0, -2.0, -7.0])
    pipeline = AvoidancePipeline(goal_ned_m=pos)
    pose = PoseAtCapture(pos, np.zeros(3), rotation_321(0.0, 0.0, yaw_east_rad))
    out = pipeline.process(_blank_frame(0, 1_000_000), pose)
    assert math.isclose(out.yaw_rad, yaw_east_rad, abs_tol=1e-12), out.yaw_rad


# ---- the core, in process: a scripted ArduCopter on the other side of typed events ---

GUIDED, BRAKE, LOITER = 4, 17, 5  # ArduCopter custom modes (DESIGN.md)
OFFBOARD = px4_custom_mode(6)  # PX4 (px4_custom_mode.h): main mode OFFBOARD
PX4_HOLD = px4_custom_mode(4, 3)  # main AUTO, sub AUTO_LOITER: PX4's Hold
SMALL = CameraModel(width_px=160, height_px=120)  # fast matcher; same field of view


class Rig:
    """A :class:`CompanionCore` and a scripted autopilot (system 1, component 1).

    Host time and autopilot time run at the same rate, ``boot_offset_ns`` apart; frames
    are stamped on the autopilot clock (the SIL's frame clock). Every 10 ms of host time
    the core gets a tick, every 20 ms telemetry, every 1/30 s a blank frame and every
    second a heartbeat; what it sends is kept in ``outputs`` and DO_SET_MODE is obeyed
    (ACK, then the new mode in the heartbeat).
    """

    def __init__(
        self, config: CompanionConfig | None = None, instance_id: int = 7, *, px4: bool = False
    ) -> None:
        self.core = CompanionCore(config or CompanionConfig(), instance_id)
        self.mav = {}
        self.now_ns = 1_000_000_000
        self.boot_offset_ns = 400_000_000
        self.px4 = px4  # a PX4 heartbeat; DO_SET_MODE's param2/param3 are main/sub mode
        self.custom_mode = OFFBOARD if px4 else GUIDED
        self.pos_ned_m = (0.0, 0.0, -7.0)
        self.yaw_rad = 0.0
        self.camera = SMALL
        self.outputs: list = []
        self._seq = 0
        self._tick = 0
        self.twin = None  # a second companion's heartbeat, sent every second if set
        self.frame_lag_s = 0.0  # frames captured this long before they arrive

    def message(self, msg, src=(1, 1)):
        """``msg`` as received from ``src``: packed and parsed like off the wire."""
        mav = self.mav.setdefault(src, mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
        return mav.decode(bytearray(msg.pack(mav)))

    def feed(self, event) -> list:
        out = self.core.step(event)
        self.outputs.extend(out)
        for o in out:
            if not isinstance(o, SendMavlink):
                continue
            if o.message.get_type() == "COMMAND_LONG":
                self._obey(o.message)
            elif o.message.get_type() == "TIMESYNC" and o.message.tc1 == 0:
                autopilot_ns = self.now_ns - self.boot_offset_ns
                reply = mavlink.MAVLink_timesync_message(autopilot_ns, o.message.ts1)
                self.feed(MavlinkReceived(self.message(reply), self.now_ns))
        return out

    def _obey(self, cmd) -> None:
        if cmd.command == mavlink.MAV_CMD_DO_SET_MODE:
            if self.px4:
                self.custom_mode = px4_custom_mode(int(cmd.param2), int(cmd.param3))
            else:
                self.custom_mode = int(cmd.param2)
        ack = mavlink.MAVLink_command_ack_message(cmd.command, mavlink.MAV_RESULT_ACCEPTED)
        self.feed(MavlinkReceived(self.message(ack), self.now_ns))

    @property
    def boot_ms(self) -> int:
        return (self.now_ns - self.boot_offset_ns) // 1_000_000

    def receive(self, msg, src=(1, 1)) -> None:
        self.feed(MavlinkReceived(self.message(msg, src), self.now_ns))

    def heartbeat(self) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        self.receive(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR,
                mavlink.MAV_AUTOPILOT_PX4 if self.px4 else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                base,
                self.custom_mode,
                mavlink.MAV_STATE_ACTIVE,
                3,
            )
        )

    def telemetry(self) -> None:
        p = self.pos_ned_m
        self.receive(mavlink.MAVLink_local_position_ned_message(self.boot_ms, *p, 0.0, 0.0, 0.0))
        self.receive(
            mavlink.MAVLink_attitude_message(self.boot_ms, 0.0, 0.0, self.yaw_rad, 0, 0, 0)
        )

    def frame(self) -> None:
        flat = np.full((self.camera.height_px, self.camera.width_px), 128, dtype=np.uint8)
        host_clock = self.core.config.link.frame_clock is FrameClock.HOST
        capture_ns = self.now_ns if host_clock else self.boot_ms * 1_000_000
        capture_ns -= round(self.frame_lag_s * 1e9)
        f = StereoFrame(self._seq, capture_ns, self.camera.intrinsics, flat, flat.copy())
        self._seq += 1
        self.feed(FrameReceived(f, self.now_ns, self.now_ns))

    def run(self, seconds: float, *, frames: bool = True, telemetry: bool = True) -> None:
        for _ in range(round(seconds / 0.01)):
            self.now_ns += 10_000_000
            self._tick += 1
            if self._tick % 100 == 1:
                self.heartbeat()
                if self.twin is not None:
                    self.receive(self.twin, src=(1, 196))
            if telemetry and self._tick % 2 == 0:
                self.telemetry()
            if frames and self._tick % 3 == 0:
                self.frame()
            self.feed(Tick(self.now_ns))

    def events(self, name: str) -> list[dict]:
        return [o.fields for o in self.outputs if isinstance(o, Event) and o.name == name]

    def sent(self, mtype: str) -> list:
        return [
            o.message
            for o in self.outputs
            if isinstance(o, SendMavlink | SendSetpoint) and o.message.get_type() == mtype
        ]

    def setpoints(self) -> list[SendSetpoint]:
        return [o for o in self.outputs if isinstance(o, SendSetpoint)]

    def statuses(self) -> list[dict]:
        return [o.document for o in self.outputs if isinstance(o, Status)]

    def texts(self) -> list[str]:
        return [m.text for m in self.sent("STATUSTEXT")]


def _steering_rig(config: CompanionConfig | None = None, *, px4: bool = False) -> Rig:
    rig = Rig(config, px4=px4)
    rig.run(3.0)  # listen 2.5 s before steering
    assert rig.events("steering"), rig.outputs[-5:]
    return rig


def test_core_engages_guided_and_steers_after_listening():
    """Heard for 2.5 s (another companion's heartbeat could arrive), then it steers."""
    rig = Rig()
    rig.run(2.3)
    assert rig.events("link_up") and rig.events("autopilot")
    assert not rig.setpoints()  # still listening
    rig.run(0.7)
    first = rig.setpoints()[0]
    # a blank camera sees nothing free: the carrot stays on the vehicle (safety envelope)
    np.testing.assert_allclose(first.target.pos_ned_m, rig.pos_ned_m, atol=1e-9)
    heartbeats = rig.sent("HEARTBEAT")
    assert len(heartbeats) == 3  # 1 Hz of the injected clock over 3 s
    assert all(h.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER for h in heartbeats)
    intervals = [m for m in rig.sent("COMMAND_LONG") if m.command == 511]
    assert {int(m.param1) for m in intervals} == {int(x) for x in STREAMS}
    assert all(m.param2 == pytest.approx(1e6 / 50.0) for m in intervals)  # 50 Hz [µs]


def test_core_failsafe_holds_on_stale_frames_and_resumes():
    """Issue 32: no frames for frame_timeout_s (frame clock) → a position hold in GUIDED
    (no mode request); none for frame_loss_s → BRAKE, the last resort; frames back for
    resume_after_s → GUIDED again and a resume event."""
    rig = _steering_rig()
    rig.run(1.5, frames=False)  # > frame_timeout_s (1 s)
    holds = rig.events("hold")
    assert [(h["reason"], h["command"]) for h in holds] == [("stale_frames", "hold position")]
    assert rig.custom_mode == GUIDED and rig.core.counters.mode_requests == 0
    rig.run(1.0, frames=False)  # 2.5 s without frames > frame_loss_s (2 s)
    holds = rig.events("hold")
    assert [(h["reason"], h["command"]) for h in holds] == [
        ("stale_frames", "hold position"),
        ("frames_lost", "BRAKE"),
    ]
    assert rig.custom_mode == BRAKE
    assert rig.core.counters.hold_commands == 1  # one hold, escalated
    n_setpoints = len(rig.setpoints())
    rig.run(0.5)
    assert not rig.events("resume")  # healthy for less than resume_after_s (1 s)
    rig.run(1.0)
    assert len(rig.events("resume")) == 1
    assert rig.custom_mode == GUIDED
    assert rig.core.counters.mode_requests == 2  # BRAKE, then GUIDED
    assert len(rig.setpoints()) > n_setpoints


def test_core_px4_failsafe_requests_hold_streams_through_it_and_resumes_offboard():
    """Issue 32 on PX4: late frames → a hold position in OFFBOARD; lost frames → PX4's
    Hold (AUTO_LOITER, DO_SET_MODE param2 = 4, param3 = 3), the hold setpoint streaming on
    at > 2 Hz so that OFFBOARD can be re-entered; healthy for resume_after_s → OFFBOARD."""
    rig = _steering_rig(px4=True)
    rig.run(1.5, frames=False)  # > frame_timeout_s (1 s)
    assert rig.custom_mode == OFFBOARD and rig.core.counters.mode_requests == 0
    rig.run(1.0, frames=False)  # > frame_loss_s (2 s)
    holds = [(h["reason"], h["command"]) for h in rig.events("hold")]
    assert holds == [("stale_frames", "hold position"), ("frames_lost", "AUTO_LOITER")]
    modes = [m for m in rig.sent("COMMAND_LONG") if m.command == mavlink.MAV_CMD_DO_SET_MODE]
    assert [(m.param2, m.param3) for m in modes] == [(4.0, 3.0)]
    assert rig.custom_mode == PX4_HOLD and rig.core.counters.mode_holds == 1
    n_setpoints = len(rig.setpoints())
    rig.run(1.0, frames=False)  # in the Hold: the stream goes on (20 Hz)
    assert len(rig.setpoints()) - n_setpoints >= 15
    rig.run(0.5)
    assert not rig.events("resume")  # healthy for less than resume_after_s (1 s)
    rig.run(1.0)
    assert len(rig.events("resume")) == 1
    assert rig.custom_mode == OFFBOARD
    assert rig.core.counters.mode_requests == 2  # Hold, then OFFBOARD


def test_time_in_a_failsafe_hold_is_not_counted_as_guidance_making_no_progress():
    """Frames that keep coming but late (older than frame_timeout_s on arrival): the core
    holds position (in GUIDED, issue 32) while guidance keeps stepping without being flown.
    Longer than stall_timeout_s of that is not NO_PROGRESS; the same time steering a
    vehicle that does not move is."""
    base = CompanionConfig()
    cfg = dataclasses.replace(
        base,
        waypoints_ned_m=((20.0, 0.0, -7.0),),
        guidance=dataclasses.replace(base.guidance, stall_timeout_s=3.0),
    )
    rig = _steering_rig(cfg)
    rig.frame_lag_s = 1.2  # frame_timeout_s is 1.0 s
    rig.run(5.0)
    assert [h["reason"] for h in rig.events("hold")] == ["stale_frames"]
    assert rig.custom_mode == GUIDED
    assert rig.core.counters.frames_processed > 100  # guidance stepped all along
    rig.frame_lag_s = 0.0
    rig.run(5.0)  # 1 s to resume, then 3 s steering without moving
    assert rig.events("resume")
    assert [h["reason"] for h in rig.events("hold")] == ["stale_frames", "no_progress"]


def test_core_failsafe_on_stale_telemetry_with_host_stamped_frames():
    """A real camera stamps frames on the host clock; telemetry maps onto it by TIMESYNC.
    Telemetry stops while frames go on → hold for stale telemetry."""
    cfg = CompanionConfig()
    cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, frame_clock=FrameClock.HOST))
    rig = _steering_rig(cfg)
    assert rig.core.clock.autopilot.synced
    rig.run(0.5, telemetry=False)
    assert [h["reason"] for h in rig.events("hold")] == ["stale_telemetry"]


def test_core_flies_waypoints_in_order_and_reports_the_goal():
    """The mission advances within goal_tolerance_m of each waypoint; the last is the goal."""
    wps = ((5.0, 0.0, -7.0), (5.0, 5.0, -7.0), (0.0, 5.0, -7.0))
    rig = _steering_rig(dataclasses.replace(CompanionConfig(), waypoints_ned_m=wps))
    assert rig.statuses()[-1]["waypoint"] == 0
    for k, wp in enumerate(wps):
        rig.pos_ned_m = (wp[0] + 0.2, wp[1], wp[2])  # within the 0.5 m tolerance
        rig.run(0.3)
        assert rig.statuses()[-1]["waypoint"] == min(k + 1, len(wps) - 1)
    assert rig.texts().count("Waypoint 1 of 2") == 1
    assert rig.texts().count("Waypoint 2 of 2") == 1
    goal = rig.events("goal_reached")
    assert len(goal) == 1 and goal[0]["distance_m"] == pytest.approx(0.2)
    assert rig.core.stats()["waypoint"] == 2


def test_core_refuses_to_steer_while_another_source_sends_setpoints():
    rig = _steering_rig()
    before = len(rig.setpoints())
    foreign = mavlink.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 3576, 1, 2, -7, 0, 0, 0, 0, 0, 0, 0, 0
    )
    rig.receive(foreign, src=(255, 190))
    assert rig.events("takeover") == [
        {"blocked": True, "reason": rig.events("takeover")[0]["reason"]}
    ]
    rig.run(1.0)
    assert len(rig.setpoints()) == before
    assert rig.core.counters.takeover_refusals == 1
    rig.run(rig.core.modes.takeover.quiet_s + 1.0)  # quiet again: steering allowed
    assert rig.events("takeover")[-1]["blocked"] is False
    assert len(rig.setpoints()) > before


def test_core_yields_to_a_twin_with_a_higher_instance_id():
    """Two companions with the same ids, neither steering yet: the higher id yields."""
    rig = Rig(instance_id=5)
    rig.twin = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink.MAV_AUTOPILOT_INVALID,
        0,
        3,  # the twin's instance id
        mavlink.MAV_STATE_STANDBY,
        3,
    )
    rig.run(4.0)
    assert [e["blocked"] for e in rig.events("takeover")] == [True]
    assert not rig.setpoints()
    lower = Rig(instance_id=2)  # now the twin (3) is the higher one: it yields, we steer
    lower.twin = rig.twin
    lower.run(4.0)
    assert not lower.events("takeover") and lower.setpoints()


def test_core_in_its_hold_keeps_control_when_a_standby_twin_appears():
    """A companion in its failsafe hold still counts as in control (its heartbeat says
    MAV_STATE_CRITICAL, which a twin reads as "in control"): a standby twin with a lower
    instance id appearing then must not make it yield, or both yield and nobody steers."""
    rig = _steering_rig()  # instance 7
    rig.run(1.5, frames=False)  # > frame_timeout_s
    assert [h["reason"] for h in rig.events("hold")] == ["stale_frames"]
    rig.twin = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink.MAV_AUTOPILOT_INVALID,
        0,
        3,  # lower instance id: it would win the tie-break between two standby twins
        mavlink.MAV_STATE_STANDBY,
        3,
    )
    rig.run(2.0, frames=False)
    n_setpoints = len(rig.setpoints())
    rig.run(3.0)  # frames back: resume and steer again, the twin still heartbeating
    assert not [e for e in rig.events("takeover") if e["blocked"]], rig.events("takeover")
    assert len(rig.events("resume")) == 1
    assert len(rig.setpoints()) > n_setpoints


def test_core_clock_timesync_maps_and_implausible_frames_are_dropped():
    """TIMESYNC requests carry the injected clock; frames far from now are dropped."""
    rig = _steering_rig()
    requests = [m for m in rig.sent("TIMESYNC") if m.tc1 == 0]
    assert len(requests) >= 10  # every 0.2 s of injected wall time once the link is up
    assert all(m.ts1 <= rig.now_ns for m in requests)
    stale = StereoFrame(
        999, (rig.boot_ms - 10_000) * 1_000_000, SMALL.intrinsics, *_blank_pair(SMALL)
    )
    rig.feed(FrameReceived(stale, rig.now_ns, rig.now_ns))
    assert rig.core.counters.frames_implausible_time == 1


def test_core_obstacle_distance_is_on_the_wire_from_start_up_all_unknown_before_frames():
    """Default config, no autopilot heard and no frame: honest all-unknown at >= 10 Hz."""
    rig = Rig()
    rig.run(2.0, frames=False, telemetry=False)
    msgs = rig.sent("OBSTACLE_DISTANCE")
    assert len(msgs) >= 2.0 * 10, f"{len(msgs)} messages in 2 s"
    assert len(msgs) == pytest.approx(2.0 * CompanionConfig().proximity.rate_hz, abs=2)
    for m in msgs:
        assert list(m.distances) == [65535] * 72
        assert m.frame == mavlink.MAV_FRAME_BODY_FRD
        assert m.increment_f == 5.0 and m.angle_offset == 0.0
        # the map's reach: its far layer's (16 m of 0.4 m voxels; the fine grid alone: 6.2 m)
        assert m.max_distance == 1600


def test_core_obstacle_distance_follows_frames_with_their_capture_time():
    """Processed frames send the map's sectors stamped with the frame's capture time; a
    textureless camera shows nothing matched, so the sectors stay unknown, never clear."""
    rig = Rig()
    rig.run(3.0)
    by_frame = rig.core.proximity.from_frames
    assert by_frame >= 60  # 30 Hz frames, each sends one
    msgs = rig.sent("OBSTACLE_DISTANCE")
    capture_us = {s["capture_ns"] // 1000 for s in rig.statuses()}
    assert sum(m.time_usec in capture_us for m in msgs) >= by_frame
    last = msgs[-1]
    assert 65535 in list(last.distances) and 1601 not in list(last.distances)[:72]
    status = rig.statuses()[-1]["proximity"]
    assert status["sent"] == len(msgs) and status["rate_hz"] >= 10.0
    assert status["unknown_sectors"] == 72


def test_core_obstacle_distance_sees_what_the_map_holds():
    """A map with a wall 3 m north and everything else free: sectors at the wall read
    ≈ 3 m, the others clear (the message is the map guidance uses)."""
    from companion.known_space import FREE, OCCUPIED

    rig = Rig()
    rig.run(1.0)
    space = rig.core.mission.pipeline.known_space
    for layer in (space, space.far):  # the fine grid and the far layer beyond its reach
        layer.grid[:] = FREE
        n = (np.arange(layer.grid.shape[0]) + layer.origin_vox[0] + 0.5) * layer.config.voxel_m
        layer.grid[n >= 3.0] = OCCUPIED
    rig.run(0.2, frames=False)
    last = rig.sent("OBSTACLE_DISTANCE")[-1]
    d = np.array(last.distances, dtype=float)
    assert d[0] == pytest.approx(300, abs=30)
    assert np.all(d[19:54] == 1601)  # facing away from the wall: clear to the far reach


def test_core_obstacle_distance_is_from_where_the_vehicle_is_at_the_send():
    """Between telemetry the sectors are seen from the newest position carried forward by
    its velocity (a wall 3 m ahead, 4 m/s toward it: 0.25 s later it reads 2 m); once the
    newest position is older than 0.5 s the vehicle could be anywhere: all unknown."""
    from companion.known_space import FREE, OCCUPIED
    from companion.proximity.sender import POSE_STALE_S

    rig = Rig()
    rig.run(1.0)
    space = rig.core.mission.pipeline.known_space
    for layer in (space, space.far):
        layer.grid[:] = FREE
        n = (np.arange(layer.grid.shape[0]) + layer.origin_vox[0] + 0.5) * layer.config.voxel_m
        layer.grid[n >= 3.0] = OCCUPIED
    rig.now_ns += 5_000_000  # newer than the rig's last telemetry
    rig.receive(mavlink.MAVLink_local_position_ned_message(rig.boot_ms, 0.0, 0.0, -7.0, 4, 0, 0))
    rig.receive(mavlink.MAVLink_attitude_message(rig.boot_ms, 0.0, 0.0, 0.0, 0, 0, 0))
    n_before = len(rig.sent("OBSTACLE_DISTANCE"))
    rig.run(0.25, frames=False, telemetry=False)
    sent = rig.sent("OBSTACLE_DISTANCE")[n_before:]
    assert len(sent) >= 4
    # the wall's sector, carried 4 m/s × 0.25 s (± a voxel and a send period of 0.2 m)
    assert sent[-1].distances[0] == pytest.approx(300 - 100, abs=30), sent[-1].distances[0]
    assert sent[0].distances[0] > sent[-1].distances[0] + 50  # it closed in between sends
    rig.run(POSE_STALE_S, frames=False, telemetry=False)
    assert list(rig.sent("OBSTACLE_DISTANCE")[-1].distances) == [65535] * 72
    assert rig.core.proximity.stale_pose > 0
    rig.run(0.1)  # telemetry again (at rest): the wall is back where it is
    assert rig.sent("OBSTACLE_DISTANCE")[-1].distances[0] == pytest.approx(300, abs=30)


def test_core_obstacle_distance_counts_sends_past_the_autopilots_timeout():
    """A companion starved for 0.7 s (no input at all) sent nothing for longer than the
    autopilots' 0.5 s proximity timeout: counted, with the longest gap, in the status."""
    rig = Rig()
    rig.run(0.5)
    assert rig.core.proximity.late == 0
    rig.now_ns += 700_000_000  # the process did not run
    rig.run(0.2)
    assert rig.core.proximity.late == 1
    figures = rig.core.proximity.figures(rig.core._now_s)
    # 0.7 s + the next 10 ms tick, + up to one 50 ms send period before the stall
    assert figures["late"] == 1 and 0.71 - 1e-9 <= figures["longest_gap_s"] <= 0.76


def test_core_obstacle_distance_can_be_turned_off():
    cfg = CompanionConfig()
    cfg = dataclasses.replace(cfg, proximity=dataclasses.replace(cfg.proximity, enabled=False))
    rig = Rig(cfg)
    rig.run(1.0)
    assert rig.sent("OBSTACLE_DISTANCE") == []


def test_core_replay_of_the_same_inputs_gives_the_same_outputs():
    """Deterministic: a recorder's inputs fed to a fresh core reproduce its outputs."""

    def record() -> list:
        rig = Rig()
        rig.run(3.5)
        rig.run(0.5, frames=False)
        return [_comparable(o) for o in rig.outputs]

    assert record() == record()


def _comparable(o):
    if isinstance(o, SendMavlink | SendSetpoint):
        return (type(o).__name__, o.message.get_type(), repr(o.message.to_dict()))
    if isinstance(o, Status):
        return ("Status", repr(o.document))
    return (type(o).__name__, o.name, repr(o.fields))


def _blank_pair(camera: CameraModel):
    flat = np.full((camera.height_px, camera.width_px), 128, dtype=np.uint8)
    return flat, flat.copy()


def test_core_counters_are_one_typed_record_in_the_exit_statistics():
    """Issue 33: the counters are fields of CoreCounters, not strings; the exit statistics
    carry each of them once, and a frame dropped for its pose counts by the lookup's
    status (a usable lookup is not a drop)."""
    from companion.core.counters import CoreCounters
    from companion.pose_history import PoseStatus

    counters = CoreCounters()
    assert counters.pose_dropped(PoseStatus.TOO_NEW) == 1 == counters.pose_too_new
    assert counters.pose_dropped(PoseStatus.TOO_OLD) == 1 and counters.pose_empty == 0
    with pytest.raises(ValueError, match="usable"):
        counters.pose_dropped(PoseStatus.OK)
    rig = _steering_rig()
    stats = rig.core.stats()
    fields = [f.name for f in dataclasses.fields(CoreCounters)]
    assert list(stats)[: len(fields)] == fields
    assert stats["frames_processed"] == rig.core.counters.frames_processed > 0
    sent = sum(1 for o in rig.outputs if isinstance(o, SendMavlink | SendSetpoint))
    assert stats["mavlink_sent"] == sent  # every message counted once, by the outbox


def _gps_raw(rig: Rig, h_acc_mm: int):
    return mavlink.MAVLink_gps_raw_int_message(
        rig.boot_ms * 1000, 3, 0, 0, 0, 80, 120, 0, 65535, 12, h_acc=h_acc_mm
    )


def test_core_widens_its_margins_by_the_autopilots_stated_accuracy():
    """GPS_RAW_INT h_acc reaches the pipeline with each frame's pose (issue 31): 0.15 m
    widens by 0.15 m; 2 m is beyond what the margins take (0.5 m), said once per episode;
    a stale statement (no GPS_RAW_INT for 5 s) is no statement."""
    rig = _steering_rig()
    pipeline = rig.core.mission.pipeline
    assert pipeline.widen_m == 0.0
    rig.receive(_gps_raw(rig, 150))
    rig.run(0.2)
    assert pipeline.widen_m == pytest.approx(0.15)
    assert not [t for t in rig.texts() if t.startswith("Position accuracy")]
    for _ in range(3):
        rig.receive(_gps_raw(rig, 2000))
        rig.run(1.0)
    assert pipeline.widen_m == pytest.approx(0.5)
    told = [t for t in rig.texts() if t.startswith("Position accuracy")]
    assert told == ["Position accuracy 2.00 m, margins cover 0.50 m"]
    rig.run(5.5)
    assert pipeline.widen_m == 0.0
