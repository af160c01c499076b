"""plant-sim as a MAVLink autopilot: real processes on 127.0.0.1 (issue 5)."""

from __future__ import annotations

import itertools
import os
import random
import shutil
import socket
import subprocess
import sys
import time

import pytest
from _plant_sim_proc import command, connect, recv
from pymavlink import mavutil

from plant_sim.autopilot.params import PARAM_SPECS
from plant_sim.autopilot.simple_avoid import AVOID_PARAM_SPECS

mav = mavutil.mavlink
GUIDED, LOITER, LAND = 4, 5, 9


def _heartbeat_armed(hb) -> bool:
    return bool(hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)


def test_heartbeat_is_1hz_wall_and_identifies_arducopter(plant_factory):
    plant = plant_factory("--no-camera", "--speedup", "10")
    m = connect(plant)
    stamps, hb = [], None
    while len(stamps) < 4:
        hb = recv(m, "HEARTBEAT", 3.0, cond=lambda h: h.get_srcSystem() == 1)
        assert hb is not None, plant.logs()
        stamps.append(time.monotonic())
    periods = [b - a for a, b in itertools.pairwise(stamps)]
    assert all(0.8 < p < 1.2 for p in periods), periods  # wall clock, even at --speedup 10
    assert hb.type == mav.MAV_TYPE_QUADROTOR
    assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert hb.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.custom_mode == GUIDED and _heartbeat_armed(hb)  # default: airborne in GUIDED
    assert hb.get_srcComponent() == 1


def test_guided_arm_takeoff_goto_land_disarm(plant_factory):
    plant = plant_factory("--no-camera", "--speedup", "20", "--start-on-ground")
    m = connect(plant)
    for msg_id, interval_us in (
        (mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 50_000),
        (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 50_000),
    ):
        ack = command(m, mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)
        assert ack.result == mav.MAV_RESULT_ACCEPTED
    ack = command(m, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    assert recv(m, "HEARTBEAT", 3, cond=lambda h: h.custom_mode == GUIDED) is not None
    ess = recv(m, "EXTENDED_SYS_STATE", 3)
    assert ess.landed_state == mav.MAV_LANDED_STATE_ON_GROUND

    # at 20x, DISARM_DELAY (10 s) is 0.5 s of wall time: take off right after arming
    assert command(m, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mav.MAV_RESULT_ACCEPTED
    ack = command(m, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 7.0)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    assert recv(m, "EXTENDED_SYS_STATE", 3, cond=lambda e: e.landed_state == 3) is not None
    assert recv(m, "HEARTBEAT", 3, cond=_heartbeat_armed) is not None
    lp = recv(
        m, "LOCAL_POSITION_NED", 10, cond=lambda p: abs(p.z + 7.0) < 0.05 and abs(p.vz) < 0.05
    )
    assert lp is not None, "did not reach 7 m"
    gp = recv(m, "GLOBAL_POSITION_INT", 3)
    assert abs(gp.relative_alt - 7000) < 100
    assert recv(m, "EXTENDED_SYS_STATE", 3, cond=lambda e: e.landed_state == 2) is not None

    m.mav.set_position_target_local_ned_send(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 3576, 24.0, 2.0, -8.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    tgt = recv(m, "POSITION_TARGET_LOCAL_NED", 3, cond=lambda t: abs(t.x - 24.0) < 1e-4)
    assert tgt is not None and abs(tgt.y - 2.0) < 1e-4 and abs(tgt.z + 8.0) < 1e-4
    near = lambda p: abs(p.x - 24) < 0.1 and abs(p.y - 2) < 0.1 and abs(p.z + 8) < 0.1  # noqa: E731
    assert recv(m, "LOCAL_POSITION_NED", 15, cond=near) is not None, "did not reach the target"

    assert command(m, mav.MAV_CMD_NAV_LAND).result == mav.MAV_RESULT_ACCEPTED
    assert recv(m, "EXTENDED_SYS_STATE", 3, cond=lambda e: e.landed_state == 4) is not None
    hb = recv(m, "HEARTBEAT", 30, cond=lambda h: not _heartbeat_armed(h))
    assert hb is not None and hb.custom_mode == LAND, "did not land and disarm"
    lp = recv(m, "LOCAL_POSITION_NED", 3)
    assert abs(lp.z) < 0.02 and abs(lp.x - 24) < 0.2 and abs(lp.y - 2) < 0.2
    ess = recv(m, "EXTENDED_SYS_STATE", 3)
    assert ess.landed_state == mav.MAV_LANDED_STATE_ON_GROUND


def test_refusals_ack_once_with_statustext(plant_factory):
    plant = plant_factory("--no-camera", "--speedup", "10", "--start-on-ground")
    m = connect(plant)
    # takeoff while disarmed → FAILED and a STATUSTEXT
    m.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 5.0)
    text = recv(m, "STATUSTEXT", 3, cond=lambda s: "Takeoff" in s.text)  # sent before the ACK
    assert text is not None and text.severity == mav.MAV_SEVERITY_WARNING
    ack = recv(m, "COMMAND_ACK", 3)
    assert ack.command == mav.MAV_CMD_NAV_TAKEOFF and ack.result == mav.MAV_RESULT_FAILED
    # unknown command → UNSUPPORTED, exactly one ACK per (re)transmission
    for _ in range(3):
        m.mav.command_long_send(1, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0)
    acks = []
    while (a := recv(m, "COMMAND_ACK", 1.0)) is not None:
        acks.append(a)
    assert [a.result for a in acks] == [mav.MAV_RESULT_UNSUPPORTED] * 3
    # AUTO refused (no mission); legacy SET_MODE acknowledged
    ack = command(m, mav.MAV_CMD_DO_SET_MODE, 1, 3)
    assert ack.result == mav.MAV_RESULT_FAILED
    m.mav.set_mode_send(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 5)
    ack = recv(m, "COMMAND_ACK", 3, cond=lambda a: a.command == mav.MAVLINK_MSG_ID_SET_MODE)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    assert recv(m, "HEARTBEAT", 3, cond=lambda h: h.custom_mode == 5) is not None
    # empty mission
    m.mav.mission_request_list_send(1, 1)
    assert recv(m, "MISSION_COUNT", 3).count == 0
    # SYS_STATUS bits MAVSDK's health_all_ok reads
    st = recv(m, "SYS_STATUS", 3)
    need = (
        mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
        | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
        | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
        | mav.MAV_SYS_STATUS_SENSOR_GPS
        | mav.MAV_SYS_STATUS_PREARM_CHECK
    )
    for field in ("present", "enabled", "health"):
        assert getattr(st, f"onboard_control_sensors_{field}") & need == need
    # TIMESYNC answered in simulation time
    m.mav.timesync_send(0, 123456789)
    ts = recv(m, "TIMESYNC", 3, cond=lambda t: t.ts1 == 123456789)
    assert ts is not None and ts.tc1 > 0


def test_message_interval_request_message_and_params(plant_factory):
    plant = plant_factory("--no-camera", "--speedup", "1")
    m = connect(plant)
    lpn_id = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    ack = command(m, mav.MAV_CMD_SET_MESSAGE_INTERVAL, lpn_id, 20000)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    recv(m, "LOCAL_POSITION_NED", 2)
    t0, n, boot = time.monotonic(), 0, []
    while time.monotonic() - t0 < 2.0:
        msg = recv(m, "LOCAL_POSITION_NED", 1)
        if msg is not None:
            n += 1
            boot.append(msg.time_boot_ms)
    rate_wall = n / (time.monotonic() - t0)
    assert 45.0 <= rate_wall <= 55.0, rate_wall  # 50 Hz ± 10 % at --speedup 1
    steps = {b - a for a, b in itertools.pairwise(boot)}
    assert steps == {20}, steps  # exactly 20 ms of simulation time apart

    ack = command(m, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    av = recv(m, "AUTOPILOT_VERSION", 3)
    assert av.capabilities & mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert av.capabilities & mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    ack = command(m, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    home = recv(m, "HOME_POSITION", 3)
    assert (home.x, home.y, home.z) == (20.0, 0.0, 0.0)
    assert abs(home.latitude - 473979217) < 5

    m.mav.param_request_list_send(1, 1)
    got = {}
    while (pv := recv(m, "PARAM_VALUE", 1.0)) is not None:
        got[pv.param_index] = pv
    counts = {pv.param_count for pv in got.values()}
    assert len(counts) == 1 and sorted(got) == list(range(counts.pop()))
    names = {pv.param_id for pv in got.values()}
    assert {"GUID_TIMEOUT", "LAND_SPEED", "RTL_ALT", "SYSID_THISMAV"} <= names

    m.mav.param_set_send(1, 1, b"LAND_SPEED", 75.0, mav.MAV_PARAM_TYPE_INT16)
    pv = recv(m, "PARAM_VALUE", 3, cond=lambda p: p.param_id == "LAND_SPEED")
    assert pv.param_value == 75.0
    m.mav.param_request_read_send(1, 1, b"LAND_SPEED", -1)
    assert recv(m, "PARAM_VALUE", 3, cond=lambda p: p.param_id == "LAND_SPEED").param_value == 75.0
    m.mav.param_set_send(1, 1, b"SYSID_THISMAV", 7.0, mav.MAV_PARAM_TYPE_UINT8)
    pv = recv(m, "PARAM_VALUE", 3, cond=lambda p: p.param_id == "SYSID_THISMAV")
    assert pv.param_value == 1.0  # read-only: echoed unchanged


def test_signing_refuses_unsigned_and_wrong_key(plant_factory):
    key = bytes(range(32))
    plant = plant_factory(
        "--no-camera", "--speedup", "10", "--start-on-ground", "--signing-key", key.hex()
    )
    good = connect(plant, key=key)
    st0 = recv(good, "SYS_STATUS", 3)
    bad_clients = [plant.client(source_system=250), plant.client(source_system=251)]
    bad_clients[1].setup_signing(bytes(32), sign_outgoing=True)  # wrong key
    for c in bad_clients:
        c.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, LOITER, 0, 0, 0, 0, 0)
        c.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 21196, 0, 0, 0, 0, 0)
        c.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 7)
        c.mav.set_position_target_local_ned_send(
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 3576, 0, 0, -7, 0, 0, 0, 0, 0, 0, 0, 0
        )
    for c in bad_clients:
        assert recv(c, "COMMAND_ACK", 0.5) is None  # refused frames get no answer
    st = recv(good, "SYS_STATUS", 5, cond=lambda s: s.errors_count1 - st0.errors_count1 >= 8)
    assert st is not None, "refused frames not counted"
    hb = recv(good, "HEARTBEAT", 3)
    assert not _heartbeat_armed(hb) and hb.custom_mode == GUIDED  # unchanged
    lp = recv(good, "LOCAL_POSITION_NED", 3)
    assert abs(lp.z) < 1e-3 and abs(lp.vz) < 1e-3  # did not move
    assert good.mav.signing.goodsig_count > 0  # the plant's telemetry verifies with the key
    # the right key works
    assert command(good, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mav.MAV_RESULT_ACCEPTED
    assert recv(good, "HEARTBEAT", 3, cond=_heartbeat_armed) is not None
    stats = plant.stop()
    assert stats["link"]["unsigned_refused"] >= 4
    assert stats["link"]["bad_signature_refused"] >= 4
    assert key.hex() not in plant.logs()


def _garbage(n: int, seed: int = 5) -> list[bytes]:
    rng = random.Random(seed)
    enc = mav.MAVLink(None, srcSystem=42, srcComponent=1)
    valid = mav.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(enc)
    foreign = mav.MAVLink_command_long_message(2, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(enc)
    out = []
    for i in range(n):
        kind = i % 4
        if kind == 0:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
        elif kind == 1:
            out.append(valid[: rng.randrange(1, len(valid) - 1)])  # truncated
        elif kind == 2:
            b = bytearray(valid)
            b[rng.randrange(10, len(b))] ^= 0xFF  # bad CRC (or payload)
            out.append(bytes(b))
        else:
            out.append(foreign)  # valid, for system 2
    return out


def test_garbage_flood_is_counted_and_survived(plant_factory):
    plant = plant_factory("--no-camera", "--speedup", "10")
    m = connect(plant)
    datagrams = _garbage(10_000)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i, d in enumerate(datagrams):
            s.sendto(d, ("127.0.0.1", plant.mavlink_port))
            if i % 200 == 199:
                # let the plant drain: wait for one of its messages (bounded)
                recv(m, "LOCAL_POSITION_NED", 1.0)
    assert plant.proc.poll() is None, plant.logs()
    hb = recv(m, "HEARTBEAT", 3)
    assert _heartbeat_armed(hb)  # the foreign ARM/DISARM did nothing harmful
    ack = command(m, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED
    st = recv(m, "SYS_STATUS", 3, cond=lambda s: s.errors_comm > 0)
    assert st is not None
    stats = plant.stop()
    link = stats["link"]
    assert link["datagrams"] >= 9_500, link  # loopback may drop a few under the flood
    assert link["truncated"] > 1000 and link["bad_frames"] > 1000 and link["garbage_bytes"] > 0
    assert stats["foreign"] >= 2000, stats


def _lpn_after_target(plant, speedup: str, duration_s: float):
    m = connect(plant)
    for msg_id in (
        mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
        mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    ):
        assert command(m, mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 20000).result == 0
    m.mav.set_position_target_local_ned_send(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 2552, 15.0, 2.0, -8.0, 0, 0, 0, 0, 0, 0, 3.0, 0
    )
    t_apply = None
    samples = {}
    deadline = time.monotonic() + duration_s / float(speedup) + 10.0
    while time.monotonic() < deadline:
        msg = recv(m, ["POSITION_TARGET_LOCAL_NED", "LOCAL_POSITION_NED"], 2)
        if msg is None:
            continue
        if msg.get_type() == "POSITION_TARGET_LOCAL_NED":
            if t_apply is None and abs(msg.x - 15.0) < 1e-4:
                t_apply = msg.time_boot_ms
        elif t_apply is not None:
            dt = msg.time_boot_ms - t_apply
            samples[dt] = (msg.x, msg.y, msg.z)
            if dt >= duration_s * 1000:
                break
    return samples


def test_speedup_10_and_1_fly_the_same_trajectory(plant_factory):
    """Commands execute at autopilot ticks, so the trajectories agree to float precision."""
    runs = []
    for speedup, duration in (("1", 3.0), ("10", 3.0)):
        plant = plant_factory("--no-camera", "--speedup", speedup, log_dir=False)
        runs.append(_lpn_after_target(plant, speedup, duration))
        plant.stop()
    common = sorted(set(runs[0]) & set(runs[1]))
    assert len(common) >= 120, len(common)  # ≥ 2.4 s of 50 Hz samples in both
    moved = max(abs(runs[0][k][0] - 20.0) for k in common)
    assert moved > 1.0  # it did fly
    err = max(max(abs(a - b) for a, b in zip(runs[0][k], runs[1][k], strict=True)) for k in common)
    assert err < 1e-3, err  # tolerance: 1 mm (float32 telemetry)


@pytest.mark.skipif(
    shutil.which("mavproxy.py", path=os.path.dirname(sys.executable)) is None,
    reason="MAVProxy is not installed (pip install mavproxy)",
)
def test_mavproxy_connects_fetches_params_and_reports_mode(plant_factory, tmp_path):
    plant = plant_factory("--no-camera", "--speedup", "1")
    exe = shutil.which("mavproxy.py", path=os.path.dirname(sys.executable))
    proc = subprocess.Popen(
        [
            exe,
            f"--master=udpout:127.0.0.1:{plant.mavlink_port}",
            "--non-interactive",
            f"--state-basedir={tmp_path}",
            "--default-modules=param,mode,cmdlong",
            "--cmd=param fetch",
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    seen, lines = set(), []
    deadline = time.monotonic() + 40.0
    try:
        assert proc.stdout is not None
        os.set_blocking(proc.stdout.fileno(), False)
        while time.monotonic() < deadline and len(seen) < 2:
            line = proc.stdout.readline()
            if not line:
                if proc.poll() is not None:
                    break
                time.sleep(0.05)  # polling a pipe, bounded by the deadline
                continue
            lines.append(line.rstrip())
            if f"Received {len(PARAM_SPECS) + len(AVOID_PARAM_SPECS)} parameters" in line:
                seen.add("params")
            if "GUIDED" in line:
                seen.add("mode")
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        proc.stdout.close()
    assert seen == {"params", "mode"}, "\n".join(lines)


def test_ready_file_holds_the_readiness_line_while_running(plant_factory, tmp_path):
    """Container healthchecks test for the ready file; it goes away at a clean stop."""
    ready = tmp_path / "plant.ready"
    plant = plant_factory("--no-camera", "--ready-file", str(ready), log_dir=False)
    assert ready.read_text(encoding="utf-8").strip() == plant.ready.group(0)
    stats = plant.stop()
    assert stats is not None, plant.logs()
    assert not ready.exists()
