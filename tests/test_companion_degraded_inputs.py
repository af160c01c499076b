"""Issue 32 on the pure core: measured data age, holds without mode flapping, safe hold targets.

The scripted ArduCopter of ``test_companion_core`` (host and autopilot clocks at one rate,
frames on the autopilot clock, DO_SET_MODE obeyed at once).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_companion_core import Rig

from companion.config import CompanionConfig


def _steering_rig(config: CompanionConfig | None = None) -> Rig:
    rig = Rig(config)
    rig.run(3.0)  # listen 2.5 s before steering
    assert rig.events("steering"), rig.outputs[-5:]
    return rig


def test_core_measures_the_data_age_of_its_commands_and_budgets_it():
    """Frames captured 0.4 s before they are handed over: the data age p50/p99 is 0.4 s,
    the latency budget 0.4 s + unmeasured_latency_s, the status document says so, and
    the companion keeps steering (slower) instead of holding."""
    rig = _steering_rig()
    env = rig.core.config.envelope
    doc = rig.statuses()[-1]["pipeline"]
    assert doc["latency_budget_s"] == env.latency_s  # an idle companion: the floor
    assert doc["rate_hz"] == pytest.approx(100.0 / 3.0, rel=0.02)  # a frame every 30 ms
    rig.frame_lag_s = 0.4
    rig.run(3.0)
    doc = rig.statuses()[-1]["pipeline"]
    # "now" on the autopilot clock is its newest telemetry stamp (every 20 ms): the age is
    # the lag less the time since that stamp, so up to 20 ms short
    assert 380.0 <= doc["data_age_p50_ms"] <= doc["data_age_p99_ms"] <= 400.0, doc
    assert doc["latency_budget_s"] == pytest.approx(
        doc["data_age_p99_ms"] * 1e-3 + env.unmeasured_latency_s, abs=0.011
    )
    assert doc["speed_limit_mps"] is not None
    assert "mode_requests" in rig.statuses()[-1]
    assert "latency budget 0.50 s" in rig.core.progress_text()
    # a slow frame is not a reason to stop: it budgets, it does not hold (frame_timeout_s)
    assert not rig.events("hold"), rig.events("hold")
    assert rig.statuses()[-1]["state"] != "hold"


def _hold_setpoints_after(rig: Rig, index: int) -> list:
    return [o.target for o in rig.outputs[index:] if type(o).__name__ == "SendSetpoint"]


def test_late_but_present_frames_hold_position_in_guided_with_zero_mode_requests():
    """A run of frames late by more than frame_timeout_s, for longer than frame_loss_s:
    position targets at the braking point, in GUIDED, not one DO_SET_MODE."""
    rig = _steering_rig()
    assert rig.core.counters.mode_requests == 0  # the rig starts in GUIDED
    start = len(rig.outputs)
    rig.frame_lag_s = 1.2  # > frame_timeout_s (1.0), frames keep coming
    rig.run(6.0)  # > 2 × frame_loss_s
    holds = rig.events("hold")
    assert [(h["reason"], h["command"]) for h in holds] == [("stale_frames", "hold position")]
    assert rig.core.counters.mode_requests == 0
    assert rig.core.counters.mode_holds == 0
    assert not [m for m in rig.sent("COMMAND_LONG") if m.command == 176]  # no DO_SET_MODE
    assert rig.custom_mode == 4  # GUIDED all along
    targets = _hold_setpoints_after(rig, start)
    assert targets, "hold targets are sent (and kept alive) in GUIDED"
    hold = holds[0]["setpoint_ned_m"]
    # the vehicle is still: its braking point is where it is
    np.testing.assert_allclose(hold, rig.pos_ned_m, atol=1e-9)
    later = targets[-5:]
    assert all(t.pos_ned_m == tuple(hold) for t in later), later
    assert rig.statuses()[-1]["state"] == "hold"
    # frames on time again: released only after resume_after_s of healthy inputs
    rig.frame_lag_s = 0.0
    rig.run(0.8)
    assert not rig.events("resume")
    rig.run(0.5)
    assert len(rig.events("resume")) == 1
    assert rig.core.counters.mode_requests == 0


def test_no_frames_for_the_last_resort_time_is_exactly_one_brake_then_a_settled_release():
    rig = _steering_rig()
    fs = rig.core.config.failsafe
    rig.run(fs.frame_loss_s - 0.2, frames=False)
    assert rig.core.counters.mode_requests == 0  # late, not lost yet
    rig.run(0.5, frames=False)
    assert rig.core.counters.mode_requests == 1 and rig.custom_mode == 17  # BRAKE
    rig.run(3.0, frames=False)  # no more requests while lost
    assert rig.core.counters.mode_requests == 1
    requests = [m for m in rig.sent("COMMAND_LONG") if m.command == 176]
    assert [int(m.param2) for m in requests] == [17]
    # frames back: GUIDED only after the settle time, then nothing more
    rig.run(fs.resume_after_s - 0.1)
    assert rig.custom_mode == 17 and not rig.events("resume")
    rig.run(0.3)
    assert rig.custom_mode == 4 and len(rig.events("resume")) == 1
    rig.run(3.0)
    assert rig.core.counters.mode_requests == 2


def test_frames_late_by_turns_do_not_flap_modes():
    """The loaded-machine pattern of issue 32: frames alternately late (past the timeout)
    and on time, for 40 s. Before: a BRAKE/GUIDED pair per cycle; now no mode request."""
    rig = _steering_rig()
    for _ in range(25):
        rig.frame_lag_s = 1.2  # > frame_timeout_s, long enough for the newest to age past it
        rig.run(1.4)
        rig.frame_lag_s = 0.0
        rig.run(0.3)
    assert rig.core.counters.mode_requests == 0
    assert rig.custom_mode == 4
    # at most one hold per late burst (released after the settle time), never a hold and
    # release at the frame rate
    assert 1 <= rig.core.counters.hold_commands <= 25


def test_hold_target_is_never_inside_a_boundary_and_is_told_once():
    """Braking point inside a boundary → short of it on the path; the vehicle inside a
    boundary → the way out of it. Told once per hold (STATUSTEXT + event)."""
    from companion.guidance.hold import HoldPlacement, hold_point, inside_any

    class Ball:
        def __init__(self, c, r):
            self.center_ned_m = np.array(c, dtype=float)
            self.radius_m = r

    wall = [Ball((3.0, 0.0, -7.0), 1.5)]
    # flying north at 4 m/s from 0: d_stop = 0.15·4 + 16/4 = 4.6 m → braking point at 4.6,
    # beyond the ball's near face at 1.5: short of it by the standoff
    hp = hold_point((0.0, 0.0, -7.0), (4.0, 0.0, 0.0), wall, latency_s=0.15, accel_mps2=2.0)
    assert hp.placement is HoldPlacement.SHORTENED
    assert hp.pos_ned_m[0] == pytest.approx(1.5 - 0.05)
    assert not inside_any(hp.pos_ned_m, wall)
    # slow enough to stop short: the braking point itself
    hp = hold_point((0.0, 0.0, -7.0), (1.0, 0.0, 0.0), wall, latency_s=0.15, accel_mps2=2.0)
    assert hp.placement is HoldPlacement.BRAKING_POINT
    assert hp.pos_ned_m[0] == pytest.approx(0.15 + 0.25)
    # inside (drifted 0.2 m into it): out radially, clearance beyond the surface
    hp = hold_point(
        (1.7, 0.0, -7.0), (0.0, 0.0, 0.0), wall, latency_s=0.15, accel_mps2=2.0, clearance_m=0.2
    )
    assert hp.placement is HoldPlacement.ESCAPE
    assert hp.pos_ned_m[0] == pytest.approx(3.0 - 1.5 - 0.2)
    assert not inside_any(hp.pos_ned_m, wall)
    # inside two overlapping balls whose way out leads into the other: the nearest point
    # out of both (tests/test_hold_point.py checks the distance), never where it is
    pair = [Ball((0.0, 0.5, -7.0), 1.0), Ball((0.0, -0.5, -7.0), 1.0)]
    hp = hold_point((0.0, 0.1, -7.0), (0.0, 0.0, 0.0), pair, latency_s=0.15, accel_mps2=2.0)
    assert hp.placement is HoldPlacement.NEAREST_OUT
    assert not inside_any(hp.pos_ned_m, pair)
    # inside two balls larger than the search reaches, each one's way out into the
    # other: where it is, never deeper
    huge = [Ball((0.0, 0.0, -7.0), 10.0), Ball((10.5, 0.0, -7.0), 10.0)]
    hp = hold_point((0.5, 0.0, -7.0), (0.0, 0.0, 0.0), huge, latency_s=0.15, accel_mps2=2.0)
    assert hp.placement is HoldPlacement.CURRENT and hp.pos_ned_m == (0.5, 0.0, -7.0)
    # bad velocity does not raise: hold where it is
    hp = hold_point((0.0, 0.0, -7.0), (np.nan, 0.0, 0.0), wall, latency_s=0.15, accel_mps2=2.0)
    assert hp.pos_ned_m == (0.0, 0.0, -7.0)


def test_core_hold_target_moves_out_of_a_boundary_once():
    """In a position hold, a boundary around the vehicle (drift into a margin) moves the
    hold target out along the escape direction, said once (STATUSTEXT + event)."""
    rig = _steering_rig()
    rig.frame_lag_s = 1.2  # > frame_timeout_s
    rig.run(1.5)
    assert rig.events("hold")

    class Ball:  # a map boundary (companion.guidance.map_boundaries.MapBoundary)
        center_ned_m = np.array([0.6, 0.0, -7.0])
        radius_m = 1.0
        piece_radius_m = 0.35  # the piece of occupied space inside it
        blind_depth_m = 0.0

    core = rig.core
    # what the map would give after a drift: the vehicle 0.4 m inside a boundary (blank
    # frames see nothing, so the boundary is put where a frame step would put it)
    core.frames.boundaries = (Ball(),)
    core.out.begin(core._now_s)
    core._recheck_hold_target(np.array(rig.pos_ned_m))
    moved = core.failsafe.hold_target.pos_ned_m
    assert moved[0] < 0.6 - 1.0  # out of the ball, to the south
    sent = [o for o in core.out.items if type(o).__name__ == "SendSetpoint"]
    assert [o.target.pos_ned_m for o in sent] == [moved]
    told = [o for o in core.out.items if getattr(o, "name", None) == "hold_target_moved"]
    assert len(told) == 1 and told[0].fields["placement"] == "escape"
    core.out.begin(core._now_s)
    core._recheck_hold_target(np.array(rig.pos_ned_m))  # target outside now: nothing
    rig.run(1.0)
    assert core.counters.hold_targets_moved == 1
    assert not rig.events("hold_target_moved")  # said once, not every frame
