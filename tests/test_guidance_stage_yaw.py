"""A staged vertical move faces where its stage is clear (issue 36, vertical-123).

The geometry of passage scene vertical-123 (ground truth, traced per frame): the goal
3.4 m straight above, the vehicle's yaw left at 52° by an avoidance manoeuvre, pointing
at the wall's boundary; the envelope's 12° stage along it ended inside the boundary, the
target was shortened to the vehicle and nothing turned the camera for 28 s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.guidance.avoidance import Guidance
from companion.guidance.cone import BoundarySphere
from companion.guidance.config import GuidanceConfig
from companion.guidance.modes import Mode, Reason
from companion.guidance.stage_yaw import STAGE_REACH_M, stage_yaw_rad, staged_move

ELEV_RAD = GuidanceConfig().max_aim_elevation_rad  # 12°
POS = np.array([0.0, 0.0, -6.0])
ABOVE = POS + np.array([0.05, 0.0, -3.4])


def _stage_clear(pos, yaw_rad, spheres, sign=-1.0, reach_m=STAGE_REACH_M) -> bool:
    """Closed form: the segment's distance to each centre is at least the radius."""
    u = np.array(
        [math.cos(ELEV_RAD) * math.cos(yaw_rad), math.cos(ELEV_RAD) * math.sin(yaw_rad),
         sign * math.sin(ELEV_RAD)]
    )  # fmt: skip
    for c, r in spheres:
        f = np.asarray(c) - pos
        t = min(max(float(f @ u), 0.0), reach_m)
        if np.linalg.norm(f - t * u) < r:
            return False
    return True


def test_a_clear_stage_keeps_the_yaw():
    wall = [((0.0, -3.0, -6.0), 1.5)]  # 1.5 m to the west of the column's boundary
    assert stage_yaw_rad(POS, ABOVE, 0.0, wall, ELEV_RAD) is None


@pytest.mark.parametrize("yaw_deg", [-130.0, -90.0, -60.0, -100.0])
def test_a_stage_into_a_boundary_turns_away_from_it(yaw_deg):
    wall = [((0.0, -2.0, -6.0), 1.5)]  # boundary surface 0.5 m west of the vehicle
    yaw = math.radians(yaw_deg)
    assert not _stage_clear(POS, yaw, wall)
    turned = stage_yaw_rad(POS, ABOVE, yaw, wall, ELEV_RAD)
    assert turned is not None and _stage_clear(POS, turned, wall)
    # straight away from the centre (east, +90°) is clear, and it is the first tried
    assert math.degrees(turned) == pytest.approx(90.0, abs=1e-9)


def test_the_turn_is_the_clear_bearing_nearest_away():
    # two boundaries: west (in the way) and one to the east-southeast: the way straight
    # east is taken, so the nearest clear bearing is 22.5° or more off it
    spheres = [((0.0, -2.0, -6.0), 1.5), ((-0.3, 1.6, -6.0), 1.0)]
    turned = stage_yaw_rad(POS, ABOVE, math.radians(-90.0), spheres, ELEV_RAD)
    assert turned is not None and _stage_clear(POS, turned, spheres)
    off_away = abs(math.degrees(math.remainder(turned - math.pi / 2, 2 * math.pi)))
    assert 22.5 - 1e-9 <= off_away <= 90.0 + 1e-9
    for k in range(16):  # no clear bearing nearer to straight away
        b = math.pi / 2 + k * math.pi / 8
        off = abs(math.degrees(math.remainder(b - math.pi / 2, 2 * math.pi)))
        if off < off_away - 1e-9:
            assert not _stage_clear(POS, b, spheres)


def test_a_descent_checks_the_stage_below():
    # a boundary above the vehicle's stage does not block a descent, one below does
    above = [((1.0, 0.0, -6.9), 0.5)]
    below = POS + np.array([0.0, 0.0, 4.0])
    assert stage_yaw_rad(POS, below, 0.0, above, ELEV_RAD) is None
    low = [((1.0, 0.0, -5.6), 0.4)]
    assert not _stage_clear(POS, 0.0, low, sign=+1.0)
    turned = stage_yaw_rad(POS, below, 0.0, low, ELEV_RAD)
    assert turned is not None and _stage_clear(POS, turned, low, sign=+1.0)


@pytest.mark.parametrize(
    "setpoint",
    [
        POS + np.array([0.4, 0.0, -0.3]),  # within the arrival tolerance above
        POS + np.array([0.4, 0.0, -0.05]),  # level
        POS + np.array([0.4, 0.0, 0.0]),
    ],
)
def test_a_goal_not_straight_above_or_below_keeps_the_yaw(setpoint):
    # a goal 0.4 m ahead before a wall it faces: arriving, the vehicle keeps facing it
    wall = [((1.5, 0.0, -6.0), 1.2)]
    assert stage_yaw_rad(POS, setpoint, 0.0, wall, ELEV_RAD) is None


def test_guidance_turns_the_yaw_it_holds_for_a_goal_straight_above():
    """Through guidance: the yaw held from the last frame (52°, as in vertical-123) faces
    the boundary; the yaw guidance commands turns its stage clear, and stays there."""
    g = Guidance(GuidanceConfig())
    wall = BoundarySphere((1.6, 2.0, -6.0), 2.2)  # surface 0.36 m from the vehicle
    yaw0 = math.radians(52.0)
    assert not _stage_clear(POS, yaw0, [(wall.center_ned_m, wall.radius_m)])
    yaws = []
    for k in range(5):
        out = g.step(
            time_s=0.1 * k, pos_ned_m=POS, vel_ned_mps=np.zeros(3), goal_ned_m=ABOVE,
            detections=[wall], yaw_rad=yaw0,
        )  # fmt: skip
        yaws.append(out.yaw_rad)
    assert all(_stage_clear(POS, y, [(wall.center_ned_m, wall.radius_m)]) for y in yaws[1:])
    assert len({round(y, 9) for y in yaws[1:]}) == 1  # held once turned


# vertical-7 (stereo, traced per frame at 6.7 s): 1.1 m off the column, the goal 4.2 m
# below, a stage's swing at 0.22 m/s toward a wall piece whose surface is 1.4 m away
_STAGE_POS = np.array([0.0, 0.0, -9.3])
_STAGE_VEL = np.array([0.21, 0.06, 0.04])
_WALL_PIECE = BoundarySphere((3.0, 0.0, -9.3), 1.6)


def _mode_after(goal, detections, vel=_STAGE_VEL, frames=4):
    g = Guidance(GuidanceConfig())
    for k in range(frames):  # past the memory's confirmation (2 of 3 frames)
        out = g.step(
            time_s=0.1 * k, pos_ned_m=_STAGE_POS, vel_ned_mps=vel, goal_ned_m=goal,
            detections=detections, yaw_rad=math.radians(40.6),
        )  # fmt: skip
    return out.mode, out.reason


def test_a_stage_swing_toward_a_wall_beside_the_column_is_not_a_threat():
    """Issue 36, vertical-7 and vertical-19: the velocity of a staged descent is the stages'
    swing about the column; the goal straight below is clear of the wall piece, so guidance
    navigates (the cone test on the velocity made it CRITICAL, and the detour round the
    wall's end lost both flights to ``NO_PROGRESS``)."""
    below = _STAGE_POS + np.array([-0.84, -0.76, 4.2])
    assert staged_move(_STAGE_POS, below, ELEV_RAD)
    assert _mode_after(below, [_WALL_PIECE]) == (Mode.NAVIGATE, Reason.NO_THREAT)


def test_the_velocity_stays_the_reference_off_the_column():
    """A goal as far below but 3 m off the column is no staged move: the paper's rule
    (the velocity inside the piece's cone, its surface nearer than the goal) stands."""
    off = _STAGE_POS + np.array([-3.0, 0.0, 4.2])
    assert not staged_move(_STAGE_POS, off, ELEV_RAD)
    assert _mode_after(off, [_WALL_PIECE]) == (Mode.AVOID, Reason.CRITICAL)


def test_an_obstacle_in_the_column_stays_a_threat_whatever_the_swing():
    """The direction to the goal is the reference: an obstacle under the vehicle in the
    column is a threat although the swing points away from it (the velocity missed it);
    no 12° aim passes it, so guidance holds."""
    below = _STAGE_POS + np.array([0.05, 0.0, 4.2])
    under = BoundarySphere((0.0, 0.0, -7.3), 0.9)
    held = _mode_after(below, [under], vel=np.array([-0.2, 0.0, 0.04]))
    assert held == (Mode.HOLD, Reason.NO_FREE_DIRECTION)


@pytest.mark.parametrize("dz_m, horiz_m, staged", [
    (4.0, 0.0, True), (-4.0, 1.4, True), (4.0, 1.6, False), (0.4, 0.0, False),
    (0.25, 1.0, False),
])  # fmt: skip
def test_staged_move_is_steep_near_the_column_and_half_a_metre_up_or_down(dz_m, horiz_m, staged):
    goal = _STAGE_POS + np.array([horiz_m, 0.0, dz_m])
    assert staged_move(_STAGE_POS, goal, ELEV_RAD) is staged
