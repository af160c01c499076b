"""Pure parts of plant-sim: scenario, setpoints, modes, params, framing, signing, tlog."""

from __future__ import annotations

import hashlib
import itertools
import math
import re
import struct

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from plant_sim.autopilot.link import parse_endpoint, split_frames
from plant_sim.autopilot.modes import (
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
    LandedState,
    ModeTimings,
)
from plant_sim.autopilot.params import ParamTable
from plant_sim.autopilot.setpoints import SetpointError, VehiclePose, decode_position_target
from plant_sim.autopilot.telemetry import StreamScheduler
from plant_sim.clock import Pacer
from plant_sim.scenario import ScenarioError, load_scenario, scenario_from_dict
from plant_sim.tlog import TlogWriter
from plant_sim.vehicle import Quadrotor
from protocols.signing import SignatureVerifier, SigningKey, signing_timestamp_now

POSE = VehiclePose(pos_ned_m=(1.0, 2.0, -3.0), yaw_rad=math.pi / 2)


# ---- scenario -------------------------------------------------------------------------
def test_scenario_defaults_are_the_papers():
    sc = scenario_from_dict({})
    assert sc.start.pos_ned_m == (20.0, 0.0, -7.0) and sc.start.airborne
    assert sc.start.mode is FlightMode.GUIDED
    (sphere,) = sc.world.spheres
    assert sphere.center_ned_m == (10.0, 0.0, -7.0) and sphere.radius_m == 1.5
    assert sc.camera.rate_hz == 30.0 and sc.camera.model.width_px == 320


@pytest.mark.parametrize(
    ("data", "name"),
    [
        ({"camera": {"fps": 30}}, "camera.fps"),
        ({"bogus": 1}, "bogus"),
        (
            {"obstacles": [{"center_ned_m": [0, 0, -1], "radius_m": 1, "colour": 2}]},
            "obstacles[0].colour",
        ),
        ({"start": {"pos": [0, 0, 0]}}, "start.pos"),
    ],
)
def test_scenario_unknown_key_is_named(data, name):
    with pytest.raises(ScenarioError, match=re.escape(f"unknown key '{name}'")):
        scenario_from_dict(data)


def test_scenario_file_toml_and_json(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text(
        'vehicle_id = "v2"\n[start]\npos_ned_m = [0, 0, -5]\nairborne = false\n'
        "[[obstacles]]\ncenter_ned_m = [5, 0, -5]\nradius_m = 1.0\n[streams]\nATTITUDE = 10\n"
    )
    sc = load_scenario(toml)
    assert sc.vehicle_id == "v2" and not sc.start.airborne
    assert dict(sc.stream_rates_hz)["ATTITUDE"] == 10.0
    js = tmp_path / "s.json"
    js.write_text('{"failsafe": {"guided_velocity_timeout_s": 2.0, "nope": 1}}')
    with pytest.raises(ScenarioError, match=r"failsafe\.nope"):
        load_scenario(js)


# ---- setpoints ------------------------------------------------------------------------
def test_position_only_3576_and_with_yaw_2552():
    t = decode_position_target(3576, 1, (5, 6, -7), (9, 9, 9), 1.0, 2.0, POSE)
    assert t == GuidedTarget(pos_ned_m=(5.0, 6.0, -7.0))
    t = decode_position_target(2552, 1, (5, 6, -7), (0, 0, 0), 1.0, 2.0, POSE)
    assert t.pos_ned_m == (5.0, 6.0, -7.0) and t.yaw_rad == 1.0 and t.yaw_rate_radps is None


def test_velocity_and_yaw_rate_and_body_frame():
    t = decode_position_target(0b0111_1100_0111, 1, (0, 0, 0), (1, 2, 3), 0, 0.5, POSE)
    assert t.pos_ned_m is None and t.vel_ned_mps == (1.0, 2.0, 3.0) and t.yaw_rate_radps == 0.5
    # BODY_OFFSET_NED: 1 m forward with heading east → 1 m east of the vehicle
    t = decode_position_target(3576, 9, (1, 0, 0), (0, 0, 0), 0, 0, POSE)
    assert t.pos_ned_m == pytest.approx((1.0, 3.0, -3.0))
    t = decode_position_target(3576, 7, (1, 0, 0), (0, 0, 0), 0, 0, POSE)  # LOCAL_OFFSET_NED
    assert t.pos_ned_m == pytest.approx((2.0, 2.0, -3.0))


@pytest.mark.parametrize(
    ("mask", "frame", "match"),
    [
        (3577, 1, "part of the position"),
        (3576, 6, "coordinate_frame"),
        (0b1111_0011_1111, 1, "acceleration"),
    ],
)
def test_setpoint_refusals(mask, frame, match):
    with pytest.raises(SetpointError, match=match):
        decode_position_target(mask, frame, (0, 0, 0), (0, 0, 0), 0, 0, POSE)


# ---- modes ----------------------------------------------------------------------------
def _kin(t, pos=(0.0, 0.0, -7.0), vel=(0.0, 0.0, 0.0), on_ground=False):
    return Kinematics(time_s=t, pos_ned_m=pos, vel_ned_mps=vel, yaw_rad=0.0, on_ground=on_ground)


def _airborne():
    return FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.GUIDED,
        armed=True,
        kin=_kin(0.0),
    )


def test_velocity_target_times_out_after_guid_timeout_then_brakes():
    m = _airborne()
    assert m.guided_target(GuidedTarget(vel_ned_mps=(1.0, 0.0, 0.0)), _kin(1.0)) is None
    assert m.setpoint.vel_ned_mps == (1.0, 0.0, 0.0)
    assert m.update(_kin(3.9, vel=(1, 0, 0))) == []
    notices = m.update(_kin(4.1, vel=(1, 0, 0)))
    assert notices  # timed out: brakes at WPNAV_ACCEL from the vehicle's 1 m/s
    accel = ModeTimings().guided_limits.accel_ne_mps2
    pos_at_timeout = m.setpoint.pos_ned_m
    assert m.setpoint.vel_ned_mps[0] == pytest.approx(1.0, abs=0.02)
    t, speeds = 4.1, []
    while t < 6.0:
        t += 0.02
        m.update(_kin(t, vel=(1, 0, 0)))
        speeds.append(m.setpoint.vel_ned_mps[0] if m.setpoint.vel_ned_mps else 0.0)
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(speeds))  # decelerates
    assert speeds[-1] == 0.0 and m.setpoint.vel_ned_mps is None  # then holds a position
    # where it stopped: at least the v²/(2a) of a stop at WPNAV_ACCEL past the timeout
    travelled = m.setpoint.pos_ned_m[0] - pos_at_timeout[0]
    assert 1.0 / (2 * accel) - 0.02 <= travelled <= 1.0 / (2 * accel) + 1.0 * 1.0, travelled


def test_position_target_persists_and_faces_the_target():
    m = _airborne()
    m.guided_target(GuidedTarget(pos_ned_m=(-10.0, 0.0, -7.0)), _kin(0.0))
    for t in (1.0, 10.0, 100.0):
        m.update(_kin(t))
    assert m.setpoint.pos_ned_m == (-10.0, 0.0, -7.0)
    assert m.setpoint.yaw_rad == pytest.approx(math.pi)


def test_land_descends_and_disarms_on_touchdown():
    m = _airborne()
    assert m.set_mode(FlightMode.LAND, _kin(0.0)) is None
    assert m.landed_state is LandedState.LANDING
    m.update(_kin(2.0, pos=(0, 0, -6)))
    assert m.setpoint.pos_ned_m[2] == pytest.approx(-6.0)  # 0.5 m/s for 2 s from -7
    m.update(_kin(20.0, pos=(0, 0, 0), on_ground=True))
    notices = m.update(_kin(21.1, pos=(0, 0, 0), on_ground=True))
    assert not m.armed and m.landed and "Land complete" in notices[0]


def test_arming_checks_and_auto_refused():
    m = FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.LAND,
        armed=False,
        kin=_kin(0.0, pos=(0, 0, 0), on_ground=True),
    )
    assert "not armable" in m.arm(_kin(0.0, pos=(0, 0, 0), on_ground=True))
    assert m.set_mode(FlightMode.AUTO, _kin(0.0)) is not None
    assert m.set_mode(FlightMode.GUIDED, _kin(0.0)) is None
    assert m.arm(_kin(0.0, pos=(0, 0, 0), on_ground=True)) is None and m.armed
    assert m.disarm(_kin(0.0)) is None  # landed: allowed


# ---- params ---------------------------------------------------------------------------
def test_param_table_set_bounds_and_read_only():
    p = ParamTable()
    assert p.set("LAND_SPEED", 75.4) is None and p.value("LAND_SPEED") == 75.0  # INT16
    assert "outside" in p.set("LAND_SPEED", 5000)
    assert "read-only" in p.set("SYSID_THISMAV", 3)
    assert "Unknown" in p.set("NOPE", 1)
    names = [p.entry(i)[0].name for i in range(len(p))]
    assert len(set(names)) == len(names) and all(len(n) <= 16 for n in names)


# ---- scheduler, pacer -----------------------------------------------------------------
def test_stream_scheduler_intervals_in_sim_time():
    s = StreamScheduler({"ATTITUDE": 4.0})
    due = [t / 100 for t in range(0, 201) if "ATTITUDE" in s.due(t / 100)]
    assert due == [0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0]
    s.set_interval_us(mav.MAVLINK_MSG_ID_ATTITUDE, -1, 2.0)
    assert s.next_due_s() == math.inf
    s.request_data_stream(mav.MAV_DATA_STREAM_EXTRA1, 10, True, 2.0)  # explicit wins
    assert s.next_due_s() == math.inf


def test_pacer_speedup_and_slip():
    p = Pacer(10.0, max_lag_wall_s=0.25)
    p.start(100.0, 0.0)
    assert p.target_sim_s(100.1, 0.0) == pytest.approx(1.0)
    assert p.wall_at(2.0) == pytest.approx(100.2)
    assert p.target_sim_s(101.0, 0.0) == 0.0 and p.stats.slips == 1  # 10 s behind: re-anchor


# ---- link: framing and signing --------------------------------------------------------
def _signed_frame(key: bytes, timestamp: int, sysid: int = 255) -> bytes:
    enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=190)
    enc.signing.secret_key = key
    enc.signing.sign_outgoing = True
    enc.signing.timestamp = timestamp
    return mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(enc)


def test_forged_high_timestamp_does_not_block_the_genuine_stream():
    key = SigningKey.from_text("correct horse battery staple")
    assert key.secret == hashlib.sha256(b"correct horse battery staple").digest()
    assert "horse" not in repr(key)
    v = SignatureVerifier(key)
    now = signing_timestamp_now()
    forged = bytearray(_signed_frame(bytes(32), now + 10**9))  # wrong key, huge timestamp
    assert v.verify(bytes(forged)) == "bad_signature"
    genuine = _signed_frame(key.secret, now)
    assert v.verify(genuine) is None  # pymavlink's own order would refuse this as "old"
    assert v.verify(genuine) == "replay"
    assert v.verify(_signed_frame(key.secret, now - 10**8)) == "replay"  # stale new stream?
    unsigned = mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav.MAVLink(None, 9, 9))
    assert v.verify(unsigned) == "unsigned"


def test_split_frames_garbage_and_truncation():
    frame = mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav.MAVLink(None, 9, 9))
    parts = list(split_frames(b"\x00\x01" + frame + frame[:5]))
    assert [k for k, _, _ in parts] == ["garbage", "frame", "truncated"]
    assert parts[1][2] == frame


def test_endpoint_parsing():
    assert parse_endpoint("udp:0.0.0.0:14550").kind == "udpin"
    assert parse_endpoint("udpout:127.0.0.1:14551").port == 14551
    for bad in ("tcp:1.2.3.4:5", "udpin:host", "udpout:127.0.0.1:0", "udpin:h:x"):
        with pytest.raises(ValueError, match="MAVLink endpoint"):
            parse_endpoint(bad)


# ---- tlog -----------------------------------------------------------------------------
def test_tlog_is_read_by_pymavlink(tmp_path):
    path = tmp_path / "t.tlog"
    enc = mav.MAVLink(None, 1, 1)
    with TlogWriter(path) as w:
        for i in range(3):
            w.write(
                mav.MAVLink_local_position_ned_message(i * 20, i, 0, -7, 0, 0, 0).pack(enc),
                1.7e9 + i,
            )
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    while (msg := log.recv_match(type="LOCAL_POSITION_NED")) is not None:
        msgs.append(msg)
    log.close()
    assert [m.time_boot_ms for m in msgs] == [0, 20, 40]
    assert msgs[1]._timestamp == pytest.approx(1.7e9 + 1)
    assert struct.unpack(">Q", path.read_bytes()[:8])[0] == int(1.7e9 * 1e6)


def test_quadrotor_hovers_under_the_autopilot_defaults():
    q = Quadrotor(pos_ned_m=(20.0, 0.0, -7.0), yaw_rad=math.pi)
    q.run_until(2.0)
    assert q.pos_ned_m == pytest.approx((20.0, 0.0, -7.0), abs=1e-3)
