"""plant-sim under hostile input: fuzzed messages, floods, replays (issue 10).

Real plant-sim processes on 127.0.0.1. Every message type plant-sim handles is sent with
hostile field values from a seeded generator; the process must answer, count and survive,
and then fly normally.
"""

from __future__ import annotations

import math
import socket
import time

from _hostile import HostileMavlink, flood_and_watch_heartbeats
from _plant_sim_proc import PlantProcess, command, connect, recv
from pymavlink import mavutil

from plant_sim.autopilot.commands import SUPPORTED_COMMANDS

mav = mavutil.mavlink
GUIDED = 4

#: every message type plant-sim's dispatcher handles
PLANT_INPUT_TYPES = (
    "command_long",
    "command_int",
    "set_mode",
    "set_position_target_local_ned",
    "set_position_target_global_int",
    "param_request_list",
    "param_request_read",
    "param_set",
    "mission_request_list",
    "mission_clear_all",
    "mission_count",
    "request_data_stream",
    "timesync",
    "heartbeat",
)


def _reposition(m, lat_e7: int, lon_e7: int, alt_m: float, flags: int = 0):
    """DO_REPOSITION (COMMAND_INT, altitude above home, yaw unchanged) and its ACK."""
    m.mav.command_int_send(
        1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION,
        0, 0, -1, flags, 0, math.nan, lat_e7, lon_e7, alt_m,
    )  # fmt: skip
    return recv(m, "COMMAND_ACK", 3, cond=lambda a: a.command == mav.MAV_CMD_DO_REPOSITION)


def _fly_normally(plant: PlantProcess) -> None:
    """GUIDED, arm, take off if landed, fly 4 m north of where it is, and get there."""
    m = connect(plant, sysid=250)
    # a client sets the streams it needs: the fuzz may have slowed them (SET_MESSAGE_INTERVAL)
    for msg_id in (mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE):
        ack = command(m, mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 100_000)
        assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED, plant.logs()
    ack = command(m, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED, plant.logs()
    ack = command(m, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED, plant.logs()
    ess = recv(m, "EXTENDED_SYS_STATE", 3)
    if ess is not None and ess.landed_state == mav.MAV_LANDED_STATE_ON_GROUND:
        ack = command(m, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5.0)
        assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED, plant.logs()
        assert recv(m, "LOCAL_POSITION_NED", 20, cond=lambda p: p.z < -4.5) is not None
    lp = recv(m, "LOCAL_POSITION_NED", 3)
    assert lp is not None, plant.logs()
    target = (lp.x + 4.0, lp.y, min(lp.z, -3.0))
    m.mav.set_position_target_local_ned_send(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 3576, *target, 0, 0, 0, 0, 0, 0, 0, 0
    )

    def near(p):
        return math.dist((p.x, p.y, p.z), target) < 0.2

    assert recv(m, "LOCAL_POSITION_NED", 30, cond=near) is not None, plant.logs()


def _wait_drained(watcher, marker: int, timeout_s: float = 5.0) -> None:
    """Flow control for a flood: a TIMESYNC behind the batch just sent, and its echo.

    On loopback the datagrams reach plant-sim's socket in the order sent, so the echo of
    ``marker`` says it has read everything before it. Without this a loaded machine that
    leaves plant-sim unscheduled for a while lets the kernel drop what overflows its
    socket buffer (8,897 of 20,000 arrived at load 20), and the test would measure the
    machine, not plant-sim. Bounded: a lost echo costs ``timeout_s``, nothing else."""
    watcher.mav.timesync_send(0, marker)
    recv(watcher, "TIMESYNC", timeout_s, cond=lambda t: t.tc1 != 0 and t.ts1 == marker)


def test_fuzz_every_handled_message_then_fly(plant_factory):
    """20,000 hostile messages over every handled type: 0 exits, then a normal flight."""
    plant = plant_factory("--no-camera", "--speedup", "10", "--start-on-ground")
    gen = HostileMavlink(
        PLANT_INPUT_TYPES,
        target=(1, 1),
        seed=10,
        commands=(*sorted(SUPPORTED_COMMANDS), 192, 178, 31000),
        sources=tuple((200 + i, 190) for i in range(10)),
    )
    frames = gen.frames(20_000)
    watcher = connect(plant)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        batch_start = time.monotonic()
        for i, frame in enumerate(frames):
            s.sendto(frame, ("127.0.0.1", plant.mavlink_port))
            if i % 250 == 249:  # at most 2,500 messages/s: under the shared rate limit
                time.sleep(max(0.0, batch_start + 0.1 - time.monotonic()))
                _wait_drained(watcher, marker=i)
                batch_start = time.monotonic()  # a late echo is no licence to burst
            if i % 2000 == 1999:
                assert plant.proc.poll() is None, plant.logs()
    assert recv(watcher, "HEARTBEAT", 3) is not None, plant.logs()
    _fly_normally(plant)
    stats = plant.stop()
    assert plant.proc.returncode == 0, plant.logs()
    assert stats["handler_errors"] == {}, stats
    handled = stats["commands"] + stats["setpoints"]
    assert handled > 5_000, stats  # the fuzz reached the handlers, not just the limiter
    assert stats["link"]["frames_ok"] >= 19_000, stats


def test_param_list_flood_leaves_heartbeats_on_time(plant_factory):
    """5,000 PARAM_REQUEST_LIST/s for 10 s: another client's heartbeat gap stays < 3 s."""
    plant = plant_factory("--no-camera", "--speedup", "1")
    flood = mav.MAVLink_param_request_list_message(1, 1).pack(
        mav.MAVLink(None, srcSystem=66, srcComponent=190)
    )
    sent, gap_s = flood_and_watch_heartbeats(plant.mavlink_port, bytes(flood), 5000.0, 10.0)
    print(f"flood: {sent} PARAM_REQUEST_LIST in 10 s, largest heartbeat gap {gap_s:.2f} s")
    assert sent >= 40_000
    assert gap_s < 3.0
    stats = plant.stop()
    assert stats["rate_limited"].get("PARAM_REQUEST_LIST", 0) > 30_000, stats


def test_do_reposition_and_global_target_move_the_vehicle_in_guided(plant_factory):
    """A ground station's "fly here" (DO_REPOSITION) and SET_POSITION_TARGET_GLOBAL_INT."""
    plant = plant_factory("--no-camera", "--speedup", "10")
    m = connect(plant)
    home = recv(m, "HOME_POSITION", 5)
    if home is None:
        command(m, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
        home = recv(m, "HOME_POSITION", 5)
    assert home is not None
    # 10 m north, 5 m east of home at 9 m above home (1 m of latitude ≈ 89.8 degE7)
    lat = home.latitude + round(10.0 / 6378137.0 * 180 / math.pi * 1e7)
    coslat = math.cos(math.radians(home.latitude * 1e-7))
    lon = home.longitude + round(5.0 / (6378137.0 * coslat) * 180 / math.pi * 1e7)
    ack = _reposition(m, lat, lon, 9.0, flags=0)
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED, plant.logs()

    def at(n, e, d):
        return lambda p: math.dist((p.x, p.y, p.z), (n, e, d)) < 0.15

    home_d = home.z
    assert (
        recv(m, "LOCAL_POSITION_NED", 40, cond=at(home.x + 10.0, home.y + 5.0, home_d - 9.0))
        is not None
    )
    # SET_POSITION_TARGET_GLOBAL_INT, altitude AMSL: back to 2 m north at 6 m above home
    lat2 = home.latitude + round(2.0 / 6378137.0 * 180 / math.pi * 1e7)
    alt_amsl = home.altitude * 1e-3 + 6.0
    m.mav.set_position_target_global_int_send(
        0,
        1,
        1,
        mav.MAV_FRAME_GLOBAL_INT,
        3576,
        lat2,
        home.longitude,
        alt_amsl,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
        0,
    )
    assert (
        recv(m, "LOCAL_POSITION_NED", 40, cond=at(home.x + 2.0, home.y, home_d - 6.0)) is not None
    )
    # outside GUIDED without the change-mode flag: denied, as ArduCopter does
    assert command(m, mav.MAV_CMD_DO_SET_MODE, 1, 5).result == mav.MAV_RESULT_ACCEPTED
    ack = _reposition(m, lat, lon, 9.0, flags=0)
    assert ack is not None and ack.result == mav.MAV_RESULT_DENIED
    # with MAV_DO_REPOSITION_FLAGS_CHANGE_MODE it switches to GUIDED and goes
    ack = _reposition(m, lat, lon, 9.0, flags=1)
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED
    assert recv(m, "HEARTBEAT", 3, cond=lambda h: h.custom_mode == GUIDED) is not None
    assert (
        recv(m, "LOCAL_POSITION_NED", 40, cond=at(home.x + 10.0, home.y + 5.0, home_d - 9.0))
        is not None
    )


def test_signed_frame_replayed_after_a_restart_is_refused(plant_factory, tmp_path):
    """Signing timestamps survive a restart: a frame captured before it is refused after."""
    key = bytes(range(32))
    state = tmp_path / "signing.json"
    args = (
        "--no-camera",
        "--speedup",
        "10",
        "--start-on-ground",
        "--signing-key",
        key.hex(),
        "--signing-state",
        str(state),
    )
    plant = plant_factory(*args)
    m = connect(plant, key=key)
    captured = bytes(
        m.mav.command_long_encode(
            1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
        ).pack(m.mav)
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(captured, ("127.0.0.1", plant.mavlink_port))
    hb = recv(m, "HEARTBEAT", 3, cond=lambda h: h.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    assert hb is not None, "the genuine frame was refused"
    assert command(m, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == mav.MAV_RESULT_ACCEPTED
    port = plant.mavlink_port
    plant.stop()
    assert state.exists()

    again = PlantProcess(["--mavlink", f"udpin:127.0.0.1:{port}", "--no-logs", *args])
    try:
        again.wait_ready()
        watch = connect(again, key=key, sysid=251)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(captured, ("127.0.0.1", port))  # the replay, within a minute of capture
        assert recv(watch, "COMMAND_ACK", 1.5) is None
        hb = recv(watch, "HEARTBEAT", 3)
        assert not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, "the replay armed the vehicle"
        # the genuine sender goes on with newer timestamps and is served
        ack = command(m, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
        assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED
        stats = again.stop()
        assert stats["link"]["replay_refused"] >= 1, stats
    finally:
        print(again.logs())
        again.close()
