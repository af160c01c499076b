"""Pure parts of the hostile-input defences (issue 10): validation, limits, clocks, takeover."""

from __future__ import annotations

import math

import pytest

from companion.clock_model import BootTime, BootTimeMonitor, ClockModel, FrameClock
from companion.takeover import TakeoverGuard
from plant_sim.autopilot.commands import MavCmd, MavResult, handle_command
from plant_sim.autopilot.geodesy import FlatEarth
from plant_sim.autopilot.link import load_signing_state, save_signing_state
from plant_sim.autopilot.modes import FlightMode, FlightModeMachine, Kinematics, ModeTimings
from plant_sim.autopilot.ratelimit import RateLimits, RequestLimiter, TokenBucket
from plant_sim.autopilot.setpoints import (
    SetpointError,
    VehiclePose,
    check_target_range,
    decode_global_target,
)
from protocols.signing import SignatureVerifier, SigningKey

HOSTILE = (math.nan, math.inf, -math.inf, 1e30, -1e30, -1.0, 2.5e9)
EARTH = FlatEarth(-35.363261, 149.165230, 584.0)


def _kin(t=0.0, pos=(0.0, 0.0, -7.0), on_ground=False):
    return Kinematics(
        time_s=t, pos_ned_m=pos, vel_ned_mps=(0, 0, 0), yaw_rad=0.0, on_ground=on_ground
    )


def _machine(mode=FlightMode.GUIDED, armed=True, on_ground=False):
    return FlightModeMachine(
        ModeTimings(),
        home_ned_m=(0.0, 0.0, 0.0),
        ground_down_m=0.0,
        mode=mode,
        armed=armed,
        kin=_kin(pos=(0.0, 0.0, 0.0 if on_ground else -7.0), on_ground=on_ground),
    )


def _run(command, params, machine=None, frame=None):
    machine = machine or _machine()
    params = tuple(params) + (0.0,) * (7 - len(params))
    return handle_command(
        int(command),
        tuple(float(p) for p in params),
        machine,
        _kin(),
        arming_checks=True,
        known_message_ids=frozenset({33, 242}),
        frame=frame,
        earth=EARTH,
    )


@pytest.mark.parametrize("command", list(MavCmd))
@pytest.mark.parametrize("bad", HOSTILE)
def test_every_command_survives_hostile_parameters(command, bad):
    """Each parameter slot hostile in turn: an outcome (never an exception), and any
    refusal is a non-ACCEPTED result."""
    for slot in range(7):
        params = [0.0] * 7
        params[slot] = bad
        outcome = _run(command, params, frame=6 if command == MavCmd.DO_REPOSITION else None)
        assert isinstance(outcome.result, MavResult)
        if outcome.result is not MavResult.ACCEPTED:
            assert outcome.text or outcome.result is MavResult.UNSUPPORTED


@pytest.mark.parametrize(
    ("command", "params"),
    [
        (MavCmd.COMPONENT_ARM_DISARM, (math.nan, 21196)),
        (MavCmd.COMPONENT_ARM_DISARM, (1.0, math.nan)),  # arms without force: checks apply
        (MavCmd.DO_SET_MODE, (math.inf, 4)),
        (MavCmd.DO_SET_MODE, (1, math.nan)),
        (MavCmd.SET_MESSAGE_INTERVAL, (math.nan, 1000)),
        (MavCmd.SET_MESSAGE_INTERVAL, (33, math.inf)),
        (MavCmd.REQUEST_MESSAGE, (-math.inf,)),
        (MavCmd.NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 1e30)),
    ],
)
def test_the_crashes_of_the_issue_are_clear_refusals(command, params):
    outcome = _run(
        command, params, machine=_machine(FlightMode.GUIDED, armed=False, on_ground=True)
    )
    if command == MavCmd.COMPONENT_ARM_DISARM and not math.isnan(params[0]):
        return  # a plain arm request: the arming checks decide
    assert outcome.result in (MavResult.DENIED, MavResult.FAILED)
    assert outcome.text


def test_do_reposition_projects_onto_local_ned_and_round_trips():
    machine = _machine()
    lat, lon, _ = EARTH.geodetic_e7((30.0, -12.0, 0.0))
    outcome = _run(MavCmd.DO_REPOSITION, (-1, 0, 0, math.nan, lat, lon, 9.0), machine, frame=6)
    assert outcome.result is MavResult.ACCEPTED
    n, e, d = machine.reported_target.pos_ned_m
    assert abs(n - 30.0) < 0.01 and abs(e + 12.0) < 0.01 and abs(d + 9.0) < 1e-9
    # AMSL frame: 600 m AMSL with the origin at 584 m → 16 m up
    outcome = _run(MavCmd.DO_REPOSITION, (-1, 0, 0, 90.0, lat, lon, 600.0), machine, frame=5)
    assert outcome.result is MavResult.ACCEPTED
    assert abs(machine.reported_target.pos_ned_m[2] + 16.0) < 1e-9
    assert abs(machine.setpoint.yaw_rad - math.pi / 2) < 1e-9


def test_do_reposition_refusals_follow_arducopter():
    loiter = _machine(FlightMode.LOITER)
    lat, lon, _ = EARTH.geodetic_e7((5.0, 0.0, 0.0))
    assert (
        _run(MavCmd.DO_REPOSITION, (-1, 0, 0, 0, lat, lon, 5), loiter, 6).result is MavResult.DENIED
    )
    ok = _run(MavCmd.DO_REPOSITION, (-1, 1, 0, 0, lat, lon, 5), loiter, 6)
    assert ok.result is MavResult.ACCEPTED and loiter.mode is FlightMode.GUIDED
    far_lat, _, _ = EARTH.geodetic_e7((20_000.0, 0.0, 0.0))
    far = _run(MavCmd.DO_REPOSITION, (-1, 0, 0, 0, far_lat, lon, 5), _machine(), 6)
    assert far.result is MavResult.DENIED and "from home" in far.text
    bad = _run(MavCmd.DO_REPOSITION, (-1, 0, 0, 0, 950_000_000, lon, 5), _machine(), 6)
    assert bad.result is MavResult.DENIED
    terrain = _run(MavCmd.DO_REPOSITION, (-1, 0, 0, 0, lat, lon, 5), _machine(), 10)
    assert terrain.result is MavResult.DENIED


def test_global_target_decodes_like_local_and_refuses_nonsense():
    pose = VehiclePose((0.0, 0.0, -7.0), 0.0)
    lat, lon, alt_mm = EARTH.geodetic_e7((8.0, 3.0, -10.0))
    t = decode_global_target(3576, 5, (lat, lon), alt_mm / 1000, (0, 0, 0), 0, 0, pose, EARTH, 0.0)
    assert math.dist(t.pos_ned_m, (8.0, 3.0, -10.0)) < 0.02
    rel = decode_global_target(3576, 6, (lat, lon), 10.0, (0, 0, 0), 0, 0, pose, EARTH, 0.0)
    assert abs(rel.pos_ned_m[2] + 10.0) < 1e-9
    with pytest.raises(SetpointError):
        decode_global_target(3576, 5, (lat, lon), math.nan, (0, 0, 0), 0, 0, pose, EARTH, 0.0)
    with pytest.raises(SetpointError):
        decode_global_target(3576, 1, (lat, lon), 10.0, (0, 0, 0), 0, 0, pose, EARTH, 0.0)


@pytest.mark.parametrize(
    "target",
    [
        {"pos_ned_m": (1e30, 0.0, -5.0)},
        {"pos_ned_m": (0.0, 10_001.0, 0.0)},
        {"vel_ned_mps": (51.0, 0.0, 0.0)},
        {"vel_ned_mps": (0.0, 0.0, 1e30)},
        {"yaw_rate_radps": 1e30},
    ],
)
def test_out_of_range_targets_are_refused(target):
    from plant_sim.autopilot.modes import GuidedTarget

    with pytest.raises(SetpointError):
        check_target_range(GuidedTarget(**target), (0.0, 0.0, 0.0))


def test_token_bucket_rate_and_burst():
    b = TokenBucket(10.0, 5.0, now_s=0.0)
    assert sum(b.take(0.0) for _ in range(20)) == 5  # the burst
    assert sum(b.take(1.0) for _ in range(20)) == 5  # refilled to the burst, not beyond
    assert sum(b.take(1.3) for _ in range(20)) == 3  # 0.3 s × 10/s


def test_limiter_is_per_peer_and_weights_expensive_requests():
    lim = RequestLimiter(
        RateLimits(per_peer_rate=100, per_peer_burst=200, total_rate=1000, total_burst=1000)
    )
    flood = sum(lim.allow((66, 1), "PARAM_REQUEST_LIST", 0.0) for _ in range(1000))
    assert flood == 2  # 200 tokens, 100 each
    assert lim.allow((255, 190), "COMMAND_LONG", 0.0)  # another peer is unaffected
    assert lim.allow((66, 1), "HEARTBEAT", 0.0)  # exempt
    assert lim.dropped == {"PARAM_REQUEST_LIST": 998}
    # spoofed source ids share one total budget
    spoofed = sum(lim.allow((i % 250, 1), "COMMAND_LONG", 0.1) for i in range(5000))
    assert spoofed <= 1000


def test_signing_state_round_trip_and_refuses_old_frames(tmp_path):
    key = SigningKey(bytes(range(32)))
    path = tmp_path / "state.json"
    save_signing_state(path, {(0, 255, 190): 123_456_789})
    state = load_signing_state(path)
    assert state == {(0, 255, 190): 123_456_789}
    v = SignatureVerifier(key, last_timestamps=state)
    assert v.last_timestamps[(0, 255, 190)] == 123_456_789
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"bad\.json"):
        load_signing_state(tmp_path / "bad.json")
    assert load_signing_state(tmp_path / "missing.json") == {}


def test_boot_time_drops_single_outliers_and_confirms_reboots():
    m = BootTimeMonitor(backstep_ms=500, slack_ms=2000, confirm=3)
    assert m.check(10_000, host_s=0.0) is BootTime.ACCEPT
    assert m.check(10_020, host_s=0.02) is BootTime.ACCEPT
    for bad in (0, 2**32 - 1, 10_020 - 10_000, 10_020 + 60_000):  # one forged stamp each
        assert m.check(bad, host_s=0.03) is BootTime.DROP
        assert m.check(10_060, host_s=0.06) is BootTime.ACCEPT
    assert m.last_ms == 10_060
    # a genuine reboot: consistent stamps from a new, earlier base
    assert m.check(50, host_s=1.0) is BootTime.DROP
    assert m.check(70, host_s=1.02) is BootTime.DROP
    assert m.check(90, host_s=1.04) is BootTime.REBOOT
    assert m.check(110, host_s=1.06) is BootTime.ACCEPT


def test_boot_time_allows_what_the_clock_rate_explains():
    m = BootTimeMonitor()
    m.check(1_000, host_s=0.0)
    # at speedup 10, 1 s of host time is 10 s of autopilot time
    assert m.check(11_000, host_s=1.0, rate=10.0) is BootTime.ACCEPT
    assert m.check(200_000, host_s=1.1, rate=10.0) is BootTime.DROP


@pytest.mark.parametrize("capture_ns", [0, 2**63 - 1, 90_000_000_000, 110_000_000_000])
def test_frames_far_from_the_clock_are_implausible(capture_ns):
    window = 2_000_000_000
    auto = ClockModel(FrameClock.AUTOPILOT)
    assert not auto.frame_time_plausible(capture_ns, 0, 100_000_000_000, window)
    assert auto.frame_time_plausible(100_500_000_000, 0, 100_000_000_000, window)
    assert auto.frame_time_plausible(100_000_000_000, 0, None, window) is None  # no clock yet
    host = ClockModel(FrameClock.HOST)
    assert not host.frame_time_plausible(capture_ns, 100_000_000_000, None, window)
    assert host.frame_time_plausible(99_000_000_000, 100_000_000_000, None, window)


def test_takeover_one_of_two_twins_steers():
    a, b = TakeoverGuard((1, 196), 0x10), TakeoverGuard((1, 196), 0x20)
    # a steers already; b starts and sees a's ACTIVE heartbeat: b yields, a does not
    b.on_twin_heartbeat(0.0, 0x10, twin_active=True, we_active=False)
    a.on_twin_heartbeat(0.0, 0x20, twin_active=False, we_active=True)
    assert b.state(0.5).blocked and "another companion" in b.state(0.5).reason
    assert not a.state(0.5).blocked
    # both active (a race): the higher instance id yields
    a2, b2 = TakeoverGuard((1, 196), 0x10), TakeoverGuard((1, 196), 0x20)
    a2.on_twin_heartbeat(0.0, 0x20, twin_active=True, we_active=True)
    b2.on_twin_heartbeat(0.0, 0x10, twin_active=True, we_active=True)
    assert [a2.state(0.1).blocked, b2.state(0.1).blocked] == [False, True]
    # alone again once the twin is quiet for quiet_s
    assert not b.state(3.1).blocked
    # our own echo is not a twin
    c = TakeoverGuard((1, 196), 0x30)
    c.on_twin_heartbeat(0.0, 0x30, twin_active=True, we_active=False)
    assert not c.state(0.1).blocked


def test_takeover_foreign_setpoints_block_until_quiet():
    g = TakeoverGuard((1, 196), 7, quiet_s=3.0)
    g.on_foreign_setpoint(10.0, (255, 190))
    assert g.state(12.9).blocked and "255/190" in g.state(12.9).reason
    assert not g.state(13.1).blocked
    g.on_foreign_setpoint(20.0, (1, 196))  # ours: ignored
    assert not g.state(20.0).blocked
