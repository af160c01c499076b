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
from companion.guidance.stage_yaw import STAGE_REACH_M, stage_yaw_rad

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
