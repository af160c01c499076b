"""plant-sim through MAVSDK: a standard client must take it for a healthy ArduCopter.

Uses the native MAVSDK binding (PyPI ``mavsdk`` >= 4, ctypes over the bundled
libcmavsdk), through its blocking API: no event loop, so nothing asyncio can leak.
MAVSDK names ArduCopter modes its own way: GUIDED is ``OFFBOARD``, LOITER (and BRAKE,
POSHOLD) is ``HOLD``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import TypeVar

import pytest
from _plant_sim_proc import PlantProcess, free_port
from mavsdk import (
    Autopilot,
    ComponentType,
    Configuration,
    ConnectionResult,
    LogLevel,
    Mavsdk,
    System,
    Vehicle,
    log_subscribe,
    log_unsubscribe,
)
from mavsdk.plugins.action import Action, ActionResult
from mavsdk.plugins.info import Info
from mavsdk.plugins.param import Param, ParamResult
from mavsdk.plugins.telemetry import FlightMode, LandedState, Telemetry

START_NED = (20.0, 0.0, -7.0)  # the paper start: plant-sim begins airborne in GUIDED
HOME_NED = (20.0, 0.0, 0.0)

T = TypeVar("T")


@pytest.fixture
def plant(tmp_path) -> Iterator[PlantProcess]:
    port = free_port()
    p = PlantProcess(
        [
            "--mavlink",
            f"udpin:127.0.0.1:{port}",
            "--no-camera",
            "--speedup",
            "4",
            "--log-dir",
            str(tmp_path / "run"),
        ]
    )
    try:
        p.wait_ready(timeout_s=30.0)
        assert p.mavlink_port == port, p.logs()
        yield p
    finally:
        p.stop()
        print(p.logs())  # pytest shows it only when the test fails
        p.close()


@pytest.fixture
def mavsdk_log() -> Iterator[list[str]]:
    """MAVSDK's own log (it comes from its threads), printed at teardown, not to stdout."""
    lines: list[str] = []
    lock = threading.Lock()

    def on_log(level: LogLevel, message: str, file: str | None, line: int) -> bool:
        with lock:
            lines.append(f"[{level.name}] {message} ({file}:{line})")
        return True  # suppress MAVSDK's default printing

    log_subscribe(on_log)
    try:
        yield lines
    finally:
        log_unsubscribe()
        with lock:
            print("--- MAVSDK log ---\n" + "\n".join(lines))


@pytest.fixture
def drone(plant, mavsdk_log) -> Iterator[System]:
    """The autopilot MAVSDK discovers on plant-sim's port (as a ground station)."""
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    sdk = Mavsdk(config)
    try:
        url = f"udpout://127.0.0.1:{plant.mavlink_port}"
        assert sdk.add_any_connection(url) == ConnectionResult.SUCCESS
        system = sdk.first_autopilot(10.0)
        assert system is not None, "MAVSDK discovered no autopilot within 10 s"
        yield system
    finally:
        sdk.destroy()  # also releases the System and its plugins
        config.destroy()


def eventually(probe: Callable[[], T], ok: Callable[[T], bool], timeout_s: float) -> T:
    """Poll ``probe`` until ``ok`` holds or ``timeout_s`` passes; the last value either way."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = probe()
        if ok(value) or time.monotonic() > deadline:
            return value
        time.sleep(0.05)


def test_mavsdk_sees_a_healthy_airborne_arducopter(drone):
    assert drone.is_connected()
    assert drone.get_system_id() == 1
    assert drone.has_autopilot()
    assert drone.autopilot_type() == Autopilot.ARDUPILOT
    assert drone.vehicle_type() == Vehicle.MULTICOPTER

    tel = Telemetry(drone)
    assert eventually(tel.health_all_ok, bool, 10.0), vars(tel.health())
    health = vars(tel.health())
    assert all(health.values()), health  # gyro/accel/mag, local/global/home, armable

    assert eventually(tel.armed, bool, 5.0)
    assert eventually(tel.in_air, bool, 5.0)
    assert eventually(tel.landed_state, lambda s: s == LandedState.IN_AIR, 5.0) == (
        LandedState.IN_AIR
    )
    mode = eventually(tel.flight_mode, lambda m: m == FlightMode.OFFBOARD, 5.0)
    assert mode == FlightMode.OFFBOARD  # ArduCopter GUIDED

    home = eventually(tel.home, lambda h: h.latitude_deg != 0.0, 5.0)
    assert (home.local_north_m, home.local_east_m, home.local_down_m) == HOME_NED
    assert abs(home.relative_altitude_m) < 1e-3
    pos = eventually(tel.position, lambda p: abs(p.relative_altitude_m - 7.0) < 0.05, 5.0)
    assert abs(pos.relative_altitude_m - 7.0) < 0.05, vars(pos)
    assert abs(pos.absolute_altitude_m - home.absolute_altitude_m - 7.0) < 0.05
    # home and the start share a north/east (flat earth): the same latitude/longitude
    assert abs(pos.latitude_deg - home.latitude_deg) < 1e-6
    assert abs(pos.longitude_deg - home.longitude_deg) < 1e-6

    ned = eventually(
        tel.position_velocity_ned, lambda pv: abs(pv.position.down_m - START_NED[2]) < 0.05, 5.0
    ).position
    assert abs(ned.north_m - START_NED[0]) < 0.05 and abs(ned.east_m - START_NED[1]) < 0.05

    version = Info(drone).get_version()  # AUTOPILOT_VERSION: ArduCopter 4.5.0 official
    assert (version.flight_sw_major, version.flight_sw_minor) == (4, 5)


def test_mavsdk_commands_and_params_round_trip(drone):
    tel = Telemetry(drone)
    assert eventually(tel.flight_mode, lambda m: m == FlightMode.OFFBOARD, 5.0) == (
        FlightMode.OFFBOARD
    )

    param = Param(drone)
    assert param.get_param_int("LAND_SPEED") == 50  # PARAM_REQUEST_READ
    assert param.set_param_int("LAND_SPEED", 75) == ParamResult.SUCCESS  # PARAM_SET echo
    assert param.get_param_int("LAND_SPEED") == 75

    action = Action(drone)
    assert action.hold() == ActionResult.SUCCESS  # DO_SET_MODE LOITER → COMMAND_ACK
    mode = eventually(tel.flight_mode, lambda m: m == FlightMode.HOLD, 5.0)
    assert mode == FlightMode.HOLD  # the heartbeat now reports LOITER
    assert tel.armed() and tel.in_air()
