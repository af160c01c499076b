"""plant-sim's PX4 flavour (``--autopilot-flavour px4``, issue 12): PX4's modes and
offboard rules (pure), the companion's PX4 path flying the paper's scene from the ground,
and MAVSDK's offboard plugin against it."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import Flavour, control_mode
from companion.link.messages import set_mode_command
from plant_sim.autopilot.modes import (
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
    ModeTimings,
)
from plant_sim.autopilot.px4 import (
    PX4_OFFBOARD_LOST_TEXT,
    Px4Main,
    Px4Modes,
    Px4Sub,
    px4_custom_mode,
)

M = mavlink
OFFBOARD = px4_custom_mode(Px4Main.OFFBOARD)
HOLD = px4_custom_mode(Px4Main.AUTO, Px4Sub.LOITER)


def _kin(t: float, down: float = -7.0, on_ground: bool = False) -> Kinematics:
    return Kinematics(t, (0.0, 0.0, down), (0.0, 0.0, 0.0), 0.0, on_ground)


def _hovering() -> Px4Modes:
    machine = FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.LOITER,
        armed=True,
        kin=_kin(0.0),
    )
    return Px4Modes(machine, home_amsl_m=488.0)


TARGET = GuidedTarget(pos_ned_m=(5.0, 0.0, -7.0))


def test_offboard_needs_a_setpoint_stream_faster_than_2_hz():
    px4 = _hovering()
    assert px4.custom_mode == HOLD and px4.name == "AUTO_LOITER"
    ok, text, temporary = px4.set_mode(OFFBOARD, _kin(1.0))
    assert not ok and temporary and "setpoint stream" in text
    for t in (1.0, 1.5, 2.0):  # 2 Hz: not more than 2 Hz
        px4.setpoint(TARGET, _kin(t))
    assert px4.machine.reported_target.pos_ned_m != TARGET.pos_ned_m  # not flown outside OFFBOARD
    assert not px4.set_mode(OFFBOARD, _kin(2.0))[0]
    assert not px4.set_mode(OFFBOARD, _kin(2.6))[0]  # the newest is 0.6 s old
    for k in range(1, 6):  # 10 Hz for 0.5 s
        px4.setpoint(TARGET, _kin(2.0 + 0.1 * k))
    ok, text, _ = px4.set_mode(OFFBOARD, _kin(2.5))
    assert ok and text is None and px4.custom_mode == OFFBOARD
    px4.setpoint(TARGET, _kin(2.6))
    assert px4.machine.mode is FlightMode.GUIDED
    assert px4.machine.reported_target.pos_ned_m == TARGET.pos_ned_m  # flown in OFFBOARD


def test_offboard_loss_after_com_of_loss_t_holds_and_says_so():
    px4 = _hovering()
    for k in range(20):
        px4.setpoint(TARGET, _kin(0.05 * k))
    assert px4.set_mode(OFFBOARD, _kin(0.95))[0]
    assert px4.update(_kin(1.9), []) == []  # 0.95 s without a setpoint: still OFFBOARD
    assert px4.update(_kin(1.96), []) == [PX4_OFFBOARD_LOST_TEXT]
    assert px4.custom_mode == HOLD and px4.machine.mode is FlightMode.LOITER
    assert px4.offboard_losses == 1


def test_a_companions_hold_request_stops_the_vehicle_and_offboard_resumes_at_once():
    """The companion's last resort on PX4 (issue 32): DO_SET_MODE AUTO_LOITER from
    OFFBOARD (main 4, sub 3, as ``hold_mode(PX4)`` sends them). The vehicle brakes and
    holds where it stopped; the setpoints that keep streaming are not flown in Hold and
    count for the stream, so OFFBOARD is accepted again at once."""
    from companion.link.flavour import hold_mode

    request = hold_mode(Flavour.PX4)
    assert tuple(int(x) for x in request.command_params[1:]) == (4, 3)
    px4 = _hovering()
    for k in range(20):
        px4.setpoint(TARGET, _kin(0.05 * k))
    assert px4.set_mode(OFFBOARD, _kin(0.95))[0]
    moving = Kinematics(1.0, (2.0, 0.0, -7.0), (1.5, 0.0, 0.0), 0.0, False)
    px4.setpoint(TARGET, moving)
    ok, text, _ = px4.set_mode(px4_custom_mode(*request.command_params[1:]), moving)
    assert ok and text is None and px4.custom_mode == HOLD and px4.name == "AUTO_LOITER"
    assert px4.machine.mode is FlightMode.LOITER
    away = GuidedTarget(pos_ned_m=(-30.0, 0.0, -7.0))
    for k in range(1, 21):  # the companion's hold stream goes on at 20 Hz
        kin = Kinematics(1.0 + 0.05 * k, (2.0, 0.0, -7.0), (0.0, 0.0, 0.0), 0.0, False)
        px4.setpoint(away, kin)
        assert px4.update(kin, []) == []  # no offboard loss: not in OFFBOARD
    assert px4.machine.reported_target.pos_ned_m[0] > 1.9  # holds ahead, not at -30 m
    ok, _, _ = px4.set_mode(OFFBOARD, _kin(2.0))
    assert ok and px4.custom_mode == OFFBOARD  # the stream never stopped


def test_takeoff_is_amsl_or_mis_takeoff_alt_and_holds_at_the_top():
    machine = FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=FlightMode.LOITER,
        armed=False,
        kin=_kin(0.0, 0.0, True),
    )
    px4 = Px4Modes(machine, home_amsl_m=488.0)
    assert px4.takeoff(495.0, _kin(0.0, 0.0, True)) == "Takeoff denied: disarmed"
    assert machine.arm(_kin(0.0, 0.0, True)) is None
    assert px4.takeoff(math.nan, _kin(0.1, 0.0, True)) is None  # NaN: MIS_TAKEOFF_ALT
    assert px4.name == "AUTO_TAKEOFF"
    assert machine._goal_down_m == pytest.approx(-2.5)
    px4.update(_kin(5.0, -2.5), ["Takeoff complete"])
    assert px4.name == "AUTO_LOITER" and machine.mode is FlightMode.LOITER


def test_unknown_or_unsupported_modes_are_refused():
    px4 = _hovering()
    assert px4.set_mode(px4_custom_mode(42), _kin(0.0))[:1] == (False,)
    ok, text, _ = px4.set_mode(px4_custom_mode(Px4Main.ACRO), _kin(0.0))
    assert not ok and "ACRO" in text


def test_the_companion_requests_px4_modes_the_way_px4_reads_them():
    """PX4's Commander casts DO_SET_MODE param2/param3 to uint8 main/sub mode."""
    px4 = set_mode_command(1, 1, control_mode(Flavour.PX4))
    assert (px4.param1, px4.param2, px4.param3) == (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    apm = set_mode_command(1, 1, control_mode(Flavour.ARDUPILOT))
    assert (apm.param2, apm.param3) == (4, 0)


# ---- real processes ------------------------------------------------------------------


@pytest.fixture
def rig(tmp_path):
    from test_companion_sil import Rig

    r = Rig(tmp_path)
    yield r
    r.close()


@pytest.mark.slow
def test_companion_px4_path_flies_the_paper_scene_from_the_ground(rig):
    """plant-sim as a PX4 multicopter, on the ground: the companion arms, takes off with an
    AMSL altitude, PX4 holds at the top, the companion streams setpoints, enters OFFBOARD
    and flies the paper's scenario to the goal without a collision. On the way, frames stop
    for longer than frame_loss_s: the companion asks for PX4's Hold (AUTO_LOITER), and
    when frames are back for the settle time, for OFFBOARD again (issue 32)."""
    from test_companion_sil import Forwarder

    from evaluation.sil import _read_truth

    companion = rig.companion("--takeoff-alt", "7", "--vehicle-id", "fwd")
    rig.plant("--autopilot-flavour", "px4", "--start-on-ground", connect=False)
    fwd = Forwarder(rig)  # frames relayed, so that they can be stopped
    try:
        ap = rig.wait_event(companion, "autopilot", 30)
        assert ap["flavour"] == "px4"
        rig.wait_event(companion, "takeoff", 60, cond=lambda f: f["step"] == "done")
        active = rig.wait_event(companion, "phase", 30, cond=lambda f: f["phase"] == "active")
        assert active["mode"] == "OFFBOARD"
        rig.wait_event(companion, "steering", 10)
        fwd.paused.set()
        hold = rig.wait_event(companion, "hold", 10, cond=lambda f: f["reason"] == "frames_lost")
        assert hold["command"] == "AUTO_LOITER"
        fwd.paused.clear()
        rig.wait_event(companion, "resume", 10)
        rig.wait_event(companion, "goal_reached", 90)
    finally:
        fwd.close()
    steps = [f["step"] for _, f in companion.events("takeoff")]
    assert steps[:1] == ["probe"] and steps[-3:] == ["takeoff", "climb", "done"]
    assert "set_mode" not in steps  # PX4: arm and NAV_TAKEOFF, no GUIDED
    truth = _read_truth(rig.tmp / "run0" / "truth.csv")
    assert truth["pos_d_m"][0] == pytest.approx(0.0, abs=0.05)
    assert float(np.min(truth["surface_distance_m"])) > 0.5
    rows = np.genfromtxt(
        rig.tmp / "run0" / "truth.csv", delimiter=",", names=True, dtype=None, encoding=None
    )
    modes = [m for i, m in enumerate(rows["mode"]) if i == 0 or m != rows["mode"][i - 1]]
    # Hold on the ground, AUTO_TAKEOFF, then OFFBOARD (PX4 lets OFFBOARD interrupt the
    # takeoff's last decimetres once the companion's 0.5 m tolerance is met); the
    # companion's Hold while frames were lost, and OFFBOARD again to the goal
    assert modes[:2] == ["AUTO_LOITER", "AUTO_TAKEOFF"], modes
    first = modes.index("OFFBOARD")  # (PX4 may hold at the top for a moment first)
    assert set(modes[2:first]) <= {"AUTO_LOITER"}, modes
    assert modes[first:] == ["OFFBOARD", "AUTO_LOITER", "OFFBOARD"], modes
    companion.stop()
    mode_requests = companion.stats("COMPANION STATS ")["mode_requests"]
    assert 3 <= mode_requests <= 4, mode_requests  # OFFBOARD (a retry at most), Hold, OFFBOARD


@pytest.mark.slow
def test_mavsdk_offboard_plugin_flies_the_px4_flavour(tmp_path):
    """MAVSDK (a PX4-first SDK) sets MIS_TAKEOFF_ALT, arms, takes off (NAV_TAKEOFF with NaN
    altitude) and flies a position through its offboard plugin; Offboard.stop() returns
    to Hold."""
    from _plant_sim_proc import PlantProcess, free_port
    from mavsdk import Autopilot, ComponentType, Configuration, ConnectionResult, Mavsdk
    from mavsdk.plugins.action import Action, ActionResult
    from mavsdk.plugins.offboard import Offboard, OffboardResult, PositionNedYaw
    from mavsdk.plugins.telemetry import FlightMode as MavsdkMode
    from mavsdk.plugins.telemetry import Telemetry

    port = free_port()
    plant = PlantProcess(
        [
            "--mavlink",
            f"udpin:127.0.0.1:{port}",
            "--no-camera",
            "--autopilot-flavour",
            "px4",
            "--start-on-ground",
            "--speedup",
            "2",
            "--log-dir",
            str(tmp_path / "run"),
        ]
    )
    config = sdk = None
    try:
        plant.wait_ready(timeout_s=30.0)
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        sdk = Mavsdk(config)
        assert sdk.add_any_connection(f"udpout://127.0.0.1:{port}") == ConnectionResult.SUCCESS
        drone = sdk.first_autopilot(10.0)
        assert drone is not None and drone.autopilot_type() == Autopilot.PX4
        tel, action, offboard = Telemetry(drone), Action(drone), Offboard(drone)

        def wait(probe, ok, timeout_s):
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                value = probe()
                if ok(value):
                    return value
                time.sleep(0.05)
            raise AssertionError(f"{probe} still {probe()!r} after {timeout_s} s")

        wait(tel.flight_mode, lambda m: m == MavsdkMode.HOLD, 10)
        assert action.get_takeoff_altitude() == pytest.approx(2.5)  # MIS_TAKEOFF_ALT
        assert action.set_takeoff_altitude(4.0) == ActionResult.SUCCESS  # PARAM_SET
        assert action.arm() == ActionResult.SUCCESS
        assert action.takeoff() == ActionResult.SUCCESS
        wait(tel.flight_mode, lambda m: m == MavsdkMode.TAKEOFF, 5)
        wait(tel.flight_mode, lambda m: m == MavsdkMode.HOLD, 20)
        alt = tel.position_velocity_ned().position.down_m
        assert alt == pytest.approx(-4.0, abs=0.2)  # MIS_TAKEOFF_ALT as set
        target = PositionNedYaw(north_m=18.0, east_m=2.0, down_m=-4.0, yaw_deg=0.0)
        start = tel.position_velocity_ned().position
        target.north_m, target.east_m = start.north_m - 2.0, start.east_m + 2.0
        assert offboard.set_position_ned(target) == OffboardResult.SUCCESS
        assert offboard.start() == OffboardResult.SUCCESS  # streams, then DO_SET_MODE 6
        wait(tel.flight_mode, lambda m: m == MavsdkMode.OFFBOARD, 5)

        def near():
            p = tel.position_velocity_ned().position
            return math.dist(
                (p.north_m, p.east_m, p.down_m), (target.north_m, target.east_m, target.down_m)
            )

        wait(near, lambda d: d < 0.3, 30)
        assert offboard.stop() == OffboardResult.SUCCESS
        wait(tel.flight_mode, lambda m: m == MavsdkMode.HOLD, 5)
    finally:
        if sdk is not None:
            sdk.destroy()
        if config is not None:
            config.destroy()
        plant.stop()
        print(plant.logs())
        plant.close()
