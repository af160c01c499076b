"""OBSTACLE_DISTANCE with real processes (issue 34): plant-sim as ArduCopter / PX4 and the
companion as a proximity sensor the autopilot trusts.

plant-sim forwards what the companion sends to the other peers, as a MAVLink router does
for a ground station, so the test's own client sees the companion's messages as they
reach the autopilot. Every process on 127.0.0.1 with free ports and explicit Zenoh
endpoints; every wait bounded; the children's logs printed on failure.
"""

from __future__ import annotations

import contextlib
import itertools
import socket
import time
from collections.abc import Iterator

import pytest
from _plant_sim_proc import command, connect, recv
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.lockstep.sil import ChildProcess, free_port

M = mavlink
ARM = M.MAV_CMD_COMPONENT_ARM_DISARM
COMPANION = 196  # MAV_COMP_ID_OBSTACLE_AVOIDANCE

_ON_THE_GROUND = """\
[start]
pos_ned_m = [20.0, 0.0, -7.0]
airborne = false
mode = "LOITER"
"""


@contextlib.contextmanager
def _companion(mav_port: int, *args: str) -> Iterator[ChildProcess]:
    """A companion that only reports (it never asks for a mode), on its own Zenoh port."""
    zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    child = ChildProcess(
        "companion",
        "companion",
        ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", zenoh,
         "--no-request-mode", *args],
    )  # fmt: skip
    try:
        child.wait_line(r"^COMPANION READY ", 60)
        yield child
    finally:
        child.stop()
        print(child.logs())  # shown only when the test fails
        child.close()


def _set_param(m, name: str, value: float) -> None:
    m.mav.param_set_send(1, 1, name.encode(), float(value), M.MAV_PARAM_TYPE_REAL32)
    echo = recv(m, "PARAM_VALUE", 5.0, cond=lambda p: p.param_id == name)
    assert echo is not None and echo.param_value == pytest.approx(value), name


def _arm(m):
    return command(m, ARM, 1)


def _obstacle_distance_times(m, seconds: float) -> tuple[list[float], list]:
    """Receipt times [s wall] and messages of the companion's OBSTACLE_DISTANCE."""
    times, msgs = [], []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        msg = m.recv_match(type="OBSTACLE_DISTANCE", blocking=True, timeout=left)
        if msg is not None and msg.get_srcComponent() == COMPANION:
            times.append(time.monotonic())
            msgs.append(msg)
    return times, msgs


def test_prx1_arming_needs_the_companion_and_its_message_flows_before_takeoff(
    plant_factory, tmp_path
):
    """PRX1_TYPE = 2: refused with "PRX1: No Data" without the companion; with it running
    (no camera: all sectors unknown) OBSTACLE_DISTANCE arrives at >= 10 Hz before arming,
    arming passes; the companion stopped, 0.5 s later arming is refused again."""
    scenario = tmp_path / "ground.toml"
    scenario.write_text(_ON_THE_GROUND, encoding="utf-8")
    plant = plant_factory("--no-camera", "--scenario", str(scenario))
    m = connect(plant)
    _set_param(m, "PRX1_TYPE", 2)
    m.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
    text = recv(m, "STATUSTEXT", 3.0, cond=lambda t: "PRX1" in t.text)  # before the ACK
    assert text is not None and text.text.startswith("Arm: PRX1: No Data"), text
    ack = recv(m, "COMMAND_ACK", 3.0, cond=lambda a: a.command == ARM)
    assert ack is not None and ack.result == M.MAV_RESULT_FAILED
    with _companion(plant.mavlink_port):
        times, msgs = _obstacle_distance_times(m, 3.0)
        assert len(times) >= 20, f"{len(times)} OBSTACLE_DISTANCE in 3 s"
        rate_hz = (len(times) - 1) / (times[-1] - times[0])
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert rate_hz >= 10.0 and max(gaps) < 0.5, (rate_hz, max(gaps))
        for msg in msgs:
            assert msg.frame == M.MAV_FRAME_BODY_FRD and msg.increment_f == 5.0
            assert list(msg.distances) == [65535] * 72  # no camera: unknown, never clear
        ack = _arm(m)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED, ack
        print(f"OBSTACLE_DISTANCE before arming: {rate_hz:.1f} Hz, max gap {max(gaps):.3f} s")
        assert command(m, ARM, 0).result == M.MAV_RESULT_ACCEPTED
    time.sleep(0.6)  # the proximity driver's 0.5 s timeout (a wall-time rule)
    ack = _arm(m)
    assert ack is not None and ack.result == M.MAV_RESULT_FAILED
    stats = plant.stop()
    assert stats is not None and stats["obstacle_distance_received"] >= 20
