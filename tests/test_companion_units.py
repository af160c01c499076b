"""Companion pure logic: poses, clocks, failsafe, config, setpoints, flavour, mode watch."""

from __future__ import annotations

import argparse
import math
import re

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.clock_model import AutopilotClock, ClockModel, FrameClock, SyncResult, SyncSample
from companion.config import (
    ConfigError,
    SigningKey,
    build_parser,
    config_from_args,
    config_from_dict,
)
from companion.failsafe import FailsafeMonitor, Health, assess
from companion.link.flavour import (
    Flavour,
    control_mode,
    detect_flavour,
    hold_mode,
    mode_name,
    px4_custom_mode,
)
from companion.link.mode_watch import ControlPhase, ModeWatch
from companion.link.setpoints import (
    TYPE_MASK_POSITION,
    TYPE_MASK_POSITION_YAW,
    PositionTarget,
    SetpointPolicy,
    position_target_message,
)
from companion.pose_history import PoseHistory, PoseStatus
from protocols.frames import euler321_from_rotation, rotation_321
from protocols.signing import signature_valid

MS = 1_000_000

# ---- pose history -------------------------------------------------------------------


def _history_with_line(n=10, dt_ms=20, yaw_step_rad=0.05):
    h = PoseHistory(max_extrapolation_ns=50 * MS)
    for i in range(n):
        t = i * dt_ms * MS
        h.add_position(t, (1.0 * i, -0.5 * i, -7.0), (50.0, -25.0, 0.0))
        h.add_attitude(t, 0.1, -0.05, yaw_step_rad * i)
    return h


def test_pose_interpolates_position_linearly_and_attitude_by_slerp():
    h = _history_with_line()
    r = h.at(30 * MS)  # halfway between samples 1 (20 ms) and 2 (40 ms)
    assert r.status is PoseStatus.OK
    np.testing.assert_allclose(r.pose.pos_ned_m, [1.5, -0.75, -7.0], atol=1e-12)
    np.testing.assert_allclose(r.pose.vel_ned_mps, [50.0, -25.0, 0.0])
    roll, pitch, yaw = euler321_from_rotation(r.pose.R_ned_from_frd)
    # slerp between two attitudes differing in yaw only = the attitude at the mean yaw
    np.testing.assert_allclose((roll, pitch, yaw), (0.1, -0.05, 0.075), atol=1e-9)
    np.testing.assert_allclose(r.pose.R_ned_from_frd, rotation_321(0.1, -0.05, 0.075), atol=1e-9)
    R = r.pose.R_ned_from_frd
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_pose_slerp_takes_the_short_way_across_yaw_wrap():
    h = PoseHistory()
    h.add_position(0, (0, 0, 0), (0, 0, 0))
    h.add_position(20 * MS, (0, 0, 0), (0, 0, 0))
    h.add_attitude(0, 0.0, 0.0, math.pi - 0.1)
    h.add_attitude(20 * MS, 0.0, 0.0, -math.pi + 0.1)
    _, _, yaw = euler321_from_rotation(h.at(10 * MS).pose.R_ned_from_frd)
    assert abs(abs(yaw) - math.pi) < 1e-9  # through ±π, not through 0


def test_pose_extrapolates_a_little_with_velocity_then_refuses():
    h = _history_with_line()
    newest = 9 * 20 * MS
    r = h.at(newest + 10 * MS)
    assert r.status is PoseStatus.EXTRAPOLATED
    np.testing.assert_allclose(r.pose.pos_ned_m, [9.0 + 0.5, -4.5 - 0.25, -7.0], atol=1e-12)
    assert h.at(newest + 51 * MS).status is PoseStatus.TOO_NEW
    assert h.at(-1).status is PoseStatus.TOO_OLD
    assert not PoseStatus.TOO_NEW.usable


def test_pose_empty_out_of_order_and_horizon():
    h = PoseHistory(horizon_ns=100 * MS)
    assert h.at(0).status is PoseStatus.EMPTY
    h.add_position(0, (0, 0, 0), (0, 0, 0))
    assert h.at(0).status is PoseStatus.EMPTY  # no attitude yet
    assert not h.add_position(0, (1, 1, 1), (0, 0, 0))
    assert h.out_of_order == 1
    assert not h.add_position(5 * MS, (math.nan, 0, 0), (0, 0, 0))
    for i in range(1, 20):
        h.add_position(i * 20 * MS, (i, 0, 0), (0, 0, 0))
        h.add_attitude(i * 20 * MS, 0, 0, 0)
    assert h.at(100 * MS).status is PoseStatus.TOO_OLD  # beyond the 100 ms horizon
    assert h.at(19 * 20 * MS).status is PoseStatus.OK


# ---- clock model --------------------------------------------------------------------


def _sync_run(clock, rate, offset_ns, n=20, period_ns=200 * MS, rtt_ns=2 * MS, start=10**12):
    for i in range(n):
        send = start + i * period_ns
        mid = send + rtt_ns // 2
        clock.add_sample(SyncSample(send, round(offset_ns + rate * mid), send + rtt_ns))


def test_autopilot_clock_fits_speedup_and_offset():
    clock = AutopilotClock()
    assert clock.autopilot_from_host(0) is None
    host0 = 10**12
    _sync_run(clock, rate=4.0, offset_ns=-4 * host0 + 3_000_000_000, start=host0)
    assert clock.rate == pytest.approx(4.0, rel=1e-9)
    host = host0 + 5_000_000_000
    assert clock.autopilot_from_host(host) == pytest.approx(4.0 * host - 4 * host0 + 3e9, abs=1e3)
    assert clock.host_from_autopilot(clock.autopilot_from_host(host)) == pytest.approx(host, abs=2)


def test_autopilot_clock_rejects_long_round_trips_and_detects_reboot():
    clock = AutopilotClock(max_rtt_ns=50 * MS)
    assert clock.add_sample(SyncSample(0, 10**9, 60 * MS)) is SyncResult.REJECTED
    assert clock.add_sample(SyncSample(0, 10**9, 2 * MS)) is SyncResult.ACCEPTED
    assert clock.add_sample(SyncSample(100 * MS, 10, 102 * MS)) is SyncResult.REBOOT
    assert clock.reboots == 1 and clock.synced


def test_clock_model_same_calls_for_sil_and_hardware():
    sil = ClockModel(FrameClock.AUTOPILOT)
    # SIL: frames and telemetry share the autopilot clock (plant-sim: simulation time)
    assert sil.frame_ns_from_boot_ms(1234) == 1234 * MS
    assert sil.frame_to_autopilot_ns(5 * MS) == 5 * MS
    assert sil.now_frame_ns(host_ns=999, newest_observed_ns=77) == 77
    hw = ClockModel(FrameClock.HOST)
    assert hw.frame_ns_from_boot_ms(1234) is None  # no TIMESYNC yet: cannot map
    host0 = 5 * 10**12
    # autopilot booted 1 h after the host: ap = host - 3600 s
    _sync_run(hw.autopilot, rate=1.0, offset_ns=-3600 * 10**9, start=host0)
    boot_ms = (host0 - 3600 * 10**9) // MS + 1000
    assert hw.frame_ns_from_boot_ms(boot_ms) == pytest.approx(host0 + 1000 * MS, abs=1000)
    assert hw.now_frame_ns(host_ns=42, newest_observed_ns=None) == 42


# ---- failsafe -----------------------------------------------------------------------


def test_failsafe_decisions_on_frame_clock():
    kw = {"frame_timeout_s": 0.3, "telemetry_timeout_s": 0.3}
    s = 10**9
    assert assess(None, None, None, **kw).health is Health.NO_CLOCK
    assert assess(5 * s, None, None, **kw).health is Health.NO_TELEMETRY
    assert assess(5 * s, None, 5 * s, **kw).health is Health.NO_FRAMES
    assert assess(5 * s, 5 * s - 290 * MS, 5 * s, **kw).health is Health.HEALTHY
    st = assess(5 * s, 5 * s - 310 * MS, 5 * s, **kw)
    assert st.health is Health.STALE_FRAMES and st.frame_age_s == pytest.approx(0.31)
    assert assess(5 * s, 5 * s, 5 * s - 400 * MS, **kw).health is Health.STALE_TELEMETRY
    mon = FailsafeMonitor(0.3, 0.3)
    assert mon.update(5 * s, 5 * s, 5 * s) is Health.HEALTHY
    assert mon.update(5 * s + MS, 5 * s, 5 * s + MS) is None  # unchanged: reported once
    assert mon.update(6 * s, 5 * s, 6 * s) is Health.STALE_FRAMES
    assert mon.holds == 1
    assert mon.update(6 * s, 6 * s, 6 * s) is Health.HEALTHY  # resume when healthy


def test_failsafe_hysteresis_one_late_frame_is_one_hold_not_a_flap():
    """Issue 12: on SITL one frame just past the 0.3 s timeout commanded BRAKE and GUIDED
    again 0.03-0.6 s later, twice in a flight. With ``resume_after_s`` the hold ends only
    after frames have been healthy for that long without a break."""
    s = 10**9
    mon = FailsafeMonitor(0.3, 0.3, resume_after_s=1.0)
    assert mon.update(5 * s, 5 * s, 5 * s) is Health.HEALTHY  # first health: at once
    # frames at 30 Hz, one of them 0.31 s late
    assert mon.update(5 * s + 310 * MS, 5 * s, 5 * s + 310 * MS) is Health.STALE_FRAMES
    changes = []
    t = 5 * s + 320 * MS
    while t < 8 * s:
        changes.append((t, mon.update(t, t - 20 * MS, t)))
        t += 33 * MS
    reported = [(t, h) for t, h in changes if h is not None]
    assert len(reported) == 1 and reported[0][1] is Health.HEALTHY
    assert (reported[0][0] - (5 * s + 320 * MS)) * 1e-9 == pytest.approx(1.0, abs=0.04)
    assert mon.holds == 1
    # while waiting, the status keeps the reason with the current ages
    mon2 = FailsafeMonitor(0.3, 0.3, resume_after_s=1.0)
    mon2.update(5 * s, 5 * s, 5 * s)
    mon2.update(6 * s, 5 * s, 6 * s)
    assert mon2.update(6 * s + 100 * MS, 6 * s + 90 * MS, 6 * s + 100 * MS) is None
    assert mon2.status.health is Health.STALE_FRAMES
    assert mon2.status.frame_age_s == pytest.approx(0.01)
    # a new late frame during the wait starts the wait again
    assert mon2.update(6 * s + 600 * MS, 6 * s + 200 * MS, 6 * s + 600 * MS) is None
    assert mon2.update(7 * s + 500 * MS, 7 * s + 490 * MS, 7 * s + 500 * MS) is None
    assert mon2.update(8 * s + 400 * MS, 8 * s + 390 * MS, 8 * s + 400 * MS) is None
    assert mon2.update(8 * s + 500 * MS, 8 * s + 490 * MS, 8 * s + 500 * MS) is Health.HEALTHY


def test_statustext_longer_than_50_characters_goes_out_in_mavlink2_chunks():
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from companion.link.messages import statustext_messages
    from protocols.statustext import statustext_chunks

    text = "Failsafe stale_frames: BRAKE, avoidance stopped until frames are back"
    msgs = statustext_messages(text, mavlink.MAV_SEVERITY_WARNING, 9)
    assert [(m.id, m.chunk_seq) for m in msgs] == [(9, 0), (9, 1)]
    # what a ground station reassembles from the wire
    mav = mavlink.MAVLink(None)
    wire = [mav.parse_char(m.pack(mav)) for m in msgs]
    assert "".join(w.text for w in wire) == text
    assert statustext_chunks("short", 0) == [(0, 0, b"short")]  # one chunk: id 0
    exact = statustext_chunks("x" * 100, 3)
    assert [len(c) for _, _, c in exact] == [50, 50, 0]  # an empty chunk terminates
    long = statustext_chunks("y" * 1000, 4)
    assert len(long) == 8 and long[-1][2].endswith(b"...")
    with pytest.raises(ValueError, match="text_id"):
        statustext_chunks("z" * 60, 0)


# ---- config -------------------------------------------------------------------------


def test_config_errors_name_the_file_the_key_and_the_bound(tmp_path):
    """Issue 33: each field is declared once with its unit and bounds; an error names the
    file, the dotted key and the bound, and the reason is the declaration's."""
    path = tmp_path / "companion.toml"
    cases = [
        ("[mavlink]\nsystem_id = 0\n", r"mavlink\.system_id: must be an integer in \[1, 255\]"),
        ("[failsafe]\nframe_loss_s = 0.5\n", r"failsafe\.frame_loss_s: must be longer than"),
        ("[known_space]\npiece_vox = 5\n", r"known_space\.piece_vox: must be even"),
        (
            "[perception]\nmin_edge_ratio = 1.0\n",
            r"perception\.min_edge_ratio: must be a finite number in \[0, 1\), got 1\.0",
        ),
        ("[envelope]\naccel_mps2 = 0\n", r"envelope\.accel_mps2: must be a finite number > 0 m/s²"),
        ("[proximity]\nn_sectors = 73\n", r"proximity\.n_sectors: must be an integer in \[1, 72\]"),
    ]
    for text, message in cases:
        path.write_text(text, encoding="utf-8")
        with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}: {message}"):
            config_from_args(build_parser().parse_args(["--config", str(path)]), environ={})


def test_config_unknown_keys_are_named():
    with pytest.raises(ConfigError, match="unknown key 'colour'"):
        config_from_dict({"colour": 1})
    with pytest.raises(ConfigError, match=r"unknown key 'mavlink\.rate'"):
        config_from_dict({"mavlink": {"rate": 5}})
    with pytest.raises(ConfigError, match=r"unknown key 'failsafe\.frame_timout_s'"):
        config_from_dict({"failsafe": {"frame_timout_s": 1}})
    with pytest.raises(ConfigError, match="threshhold_m"):
        config_from_dict({"perception": {"threshhold_m": 4}})
    with pytest.raises(ConfigError, match="tie_angle"):
        config_from_dict({"guidance": {"tie_angle": 4}})


def test_config_file_and_cli_merge(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(
        'vehicle_id = "v2"\n'
        "waypoints_ned_m = [[5, 0, -7], [0, 0, -7]]\n"
        '[mavlink]\nurl = "udpin:0.0.0.0:14551"\nframe_clock = "host"\n'
        "[perception]\nthreshold_m = 5.0\n"
    )
    args = build_parser().parse_args(["--config", str(path), "--signing-key", "secret"])
    cfg = config_from_args(args, environ={})
    assert cfg.vehicle_id == "v2"
    assert cfg.waypoints_ned_m == ((5.0, 0.0, -7.0), (0.0, 0.0, -7.0))
    assert cfg.link.url == "udpin:0.0.0.0:14551"
    assert cfg.link.frame_clock is FrameClock.HOST
    assert cfg.perception.threshold_m == 5.0
    assert cfg.link.component_id == 196
    assert cfg.zenoh.connect == ("tcp/127.0.0.1:7447",)  # plant-sim's default
    assert "secret" not in repr(cfg)  # keys never in logs / reprs
    args = build_parser().parse_args(["--goal", "1", "2", "-3", "--mavlink", "tcp:1.2.3.4:5760"])
    cfg = config_from_args(args, environ={"STEREO_AVOID_SIGNING_KEY": "a" * 64})
    assert cfg.waypoints_ned_m == ((1.0, 2.0, -3.0),)
    assert cfg.link.signing_key.secret == bytes.fromhex("a" * 64)
    with pytest.raises(ConfigError, match="frame_clock"):
        config_from_dict({"mavlink": {"frame_clock": "gps"}})
    with pytest.raises(ConfigError):
        config_from_args(argparse.Namespace(**{**vars(args), "vehicle_id": "a/b"}), environ={})


def test_signing_key_hex_or_passphrase():
    import hashlib

    assert SigningKey.from_text("00" * 32).secret == bytes(32)
    assert SigningKey.from_text("hello").secret == hashlib.sha256(b"hello").digest()
    assert repr(SigningKey.from_text("hello")) == "SigningKey(<redacted>)"


# ---- setpoints ----------------------------------------------------------------------


def test_setpoint_encoding_position_and_yaw():
    assert TYPE_MASK_POSITION_YAW == 2552
    assert TYPE_MASK_POSITION == 3576
    msg = position_target_message(PositionTarget((1.0, -2.0, -7.0), 3 * math.pi), 1234, 1, 1)
    enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=196)
    dec = mavlink.MAVLink(None).decode(bytearray(msg.pack(enc)))
    assert dec.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
    assert dec.type_mask == 2552 and dec.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED
    assert (dec.x, dec.y, dec.z) == (1.0, -2.0, -7.0)
    assert dec.yaw == pytest.approx(math.pi, abs=1e-6) or dec.yaw == pytest.approx(-math.pi)
    assert (dec.time_boot_ms, dec.target_system, dec.target_component) == (1234, 1, 1)
    with pytest.raises(ValueError):
        PositionTarget((math.nan, 0.0, 0.0), 0.0)


def test_setpoint_policy_px4_streams_ardupilot_on_change_and_periodic():
    a, b = PositionTarget((0, 0, -7), 0.0), PositionTarget((0, 0.5, -7), 0.0)
    px4 = SetpointPolicy(Flavour.PX4, px4_rate_hz=20.0)
    assert px4.on_new_target(a, 0.0)
    px4.sent(a, 0.0)
    assert px4.on_new_target(a, 0.001)  # every new target at once
    assert not px4.due(0.03) and px4.due(0.05)  # and repeated at 20 Hz
    ap = SetpointPolicy(Flavour.ARDUPILOT, ardupilot_period_s=0.5)
    assert ap.on_new_target(a, 0.0)
    ap.sent(a, 0.0)
    assert not ap.on_new_target(a, 0.1)  # unchanged
    assert ap.on_new_target(b, 0.1)  # changed
    assert not ap.due(0.4) and ap.due(0.5)  # periodic keep-alive
    with pytest.raises(ValueError):
        SetpointPolicy(Flavour.PX4, px4_rate_hz=2.0)


# ---- flavour and modes --------------------------------------------------------------


def test_flavour_detection_and_mode_encoding():
    assert detect_flavour(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA) is Flavour.ARDUPILOT
    assert detect_flavour(mavlink.MAV_AUTOPILOT_PX4) is Flavour.PX4
    assert detect_flavour(mavlink.MAV_AUTOPILOT_GENERIC) is Flavour.GENERIC
    assert control_mode(Flavour.ARDUPILOT).custom_mode == 4
    assert control_mode(Flavour.PX4).custom_mode == 6 << 16 == px4_custom_mode(6)
    assert control_mode(Flavour.PX4).base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hold_mode(Flavour.ARDUPILOT).custom_mode == 17
    # PX4's Hold: AUTO_LOITER (px4_custom_mode.h: main AUTO 4, sub AUTO_LOITER 3)
    assert hold_mode(Flavour.PX4).custom_mode == 4 << 16 | 3 << 24 == px4_custom_mode(4, 3)
    assert mode_name(Flavour.PX4, px4_custom_mode(4, 3)) == "AUTO_LOITER"
    assert mode_name(Flavour.PX4, px4_custom_mode(4)) == "AUTO"
    assert mode_name(Flavour.PX4, px4_custom_mode(3)) == "POSCTL"
    assert mode_name(Flavour.ARDUPILOT, 5) == "LOITER"


AP = Flavour.ARDUPILOT
GUIDED, LOITER, BRAKE = 4, 5, 17


def test_mode_watch_pilot_takeover_stops_commanding_and_waits():
    w = ModeWatch()
    notes = w.on_heartbeat(0.0, AP, GUIDED)
    assert w.phase is ControlPhase.ACTIVE and w.steering and notes
    notes = w.on_heartbeat(1.0, AP, LOITER)  # a ground station switched to LOITER
    assert w.phase is ControlPhase.RELEASED and not w.steering
    assert "LOITER" in notes[0]
    assert w.tick(5.0) is None  # never asks for GUIDED back by itself
    assert w.set_hold(5.0, True) is None  # nor commands BRAKE
    w.on_heartbeat(9.0, AP, GUIDED)  # the pilot hands back
    assert w.phase is ControlPhase.ACTIVE


def test_mode_watch_requests_guided_and_tolerates_a_stale_heartbeat():
    w = ModeWatch(request_mode=True)
    w.on_heartbeat(0.0, AP, LOITER)
    assert w.phase is ControlPhase.REQUESTED and not w.steering
    req = w.tick(0.0)
    assert req.custom_mode == GUIDED
    w.on_heartbeat(0.5, AP, LOITER)  # still the old mode: not a takeover
    assert w.phase is ControlPhase.REQUESTED
    w.on_mode_accepted(0.6, GUIDED)
    assert w.phase is ControlPhase.ACTIVE
    w.on_heartbeat(1.0, AP, LOITER)  # heartbeat sent before the switch
    assert w.phase is ControlPhase.ACTIVE
    w.on_heartbeat(2.0, AP, GUIDED)
    w.on_heartbeat(9.0, AP, LOITER)  # later: a real takeover
    assert w.phase is ControlPhase.RELEASED


def test_mode_watch_failsafe_brake_and_resume():
    w = ModeWatch()
    w.on_heartbeat(0.0, AP, GUIDED)
    req = w.set_hold(1.0, True)
    assert req.custom_mode == BRAKE and w.phase is ControlPhase.HOLD and not w.steering
    w.on_heartbeat(1.2, AP, GUIDED)  # stale
    w.on_heartbeat(2.0, AP, BRAKE)
    assert w.phase is ControlPhase.HOLD
    req = w.set_hold(3.0, False)
    assert req.custom_mode == GUIDED and w.phase is ControlPhase.REQUESTED
    w.on_heartbeat(3.5, AP, BRAKE)  # stale
    assert w.phase is ControlPhase.REQUESTED
    w.on_mode_accepted(3.6, GUIDED)
    assert w.phase is ControlPhase.ACTIVE and w.steering


def test_mode_watch_px4_streams_before_requesting_offboard():
    w = ModeWatch(prestream_s=1.2)
    posctl = px4_custom_mode(3)
    w.on_heartbeat(0.0, Flavour.PX4, posctl)
    assert w.phase is ControlPhase.PRESTREAM and w.steering  # stream setpoints already
    assert w.tick(1.0) is None
    req = w.tick(1.3)
    assert req.custom_mode == 6 << 16
    w.on_heartbeat(2.0, Flavour.PX4, px4_custom_mode(6))
    assert w.phase is ControlPhase.ACTIVE
    hold = px4_custom_mode(4, 3)  # AUTO_LOITER, PX4's Hold
    req = w.set_hold(3.0, True)
    assert req.custom_mode == hold and req.command_params[1:] == (4.0, 3.0)
    assert w.streaming_hold and not w.steering  # the hold setpoint streams through the Hold
    w.on_heartbeat(3.2, Flavour.PX4, px4_custom_mode(6))  # stale
    w.on_heartbeat(4.0, Flavour.PX4, hold)
    assert w.phase is ControlPhase.HOLD and w.mode_text() == "AUTO_LOITER"
    req = w.set_hold(5.0, False)  # the stream never stopped: OFFBOARD at once
    assert req.custom_mode == 6 << 16 and w.phase is ControlPhase.REQUESTED and w.steering
    w.on_heartbeat(5.5, Flavour.PX4, hold)  # stale
    assert w.phase is ControlPhase.REQUESTED
    w.on_heartbeat(6.0, Flavour.PX4, px4_custom_mode(6))
    assert w.phase is ControlPhase.ACTIVE


# ---- signing order ------------------------------------------------------------------


def _signed_frame(key: bytes, timestamp: int, sysid=1, compid=1) -> bytes:
    enc = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    enc.signing.secret_key = key
    enc.signing.sign_outgoing = True
    enc.signing.timestamp = timestamp
    return bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(enc))


def test_forged_high_timestamp_does_not_block_the_genuine_stream():
    from companion.link.connection import _verified_by
    from protocols.signing import SignatureVerifier, SigningKey

    key, wrong = bytes(range(32)), bytes(32)
    now = 300_000_000_000
    forged = _signed_frame(wrong, now + 10**9)
    genuine = _signed_frame(key, now + 1)
    assert not signature_valid(key, forged) and signature_valid(key, genuine)
    dec = mavlink.MAVLink(None)
    dec.signing.secret_key = key
    dec.signing.timestamp = now
    import types

    # the verifier's clock at ``now`` (signing timestamps count 10 µs from 2015-01-01)
    verifier = SignatureVerifier(SigningKey(key), clock_unix_s=lambda: 1420070400 + now * 1e-5)
    dec.check_signature = types.MethodType(_verified_by(verifier), dec)
    with pytest.raises(mavlink.MAVError):
        dec.decode(bytearray(forged))
    assert dec.decode(bytearray(genuine)).get_type() == "HEARTBEAT"
