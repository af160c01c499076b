"""A way back out of a boundary goes through space seen free (invariants 1 and 3), and
a way the camera has not looked along is looked at before it is flown.

Stop 43 noticed that ``hold.way_out``'s radial escape was sent unchecked against the map:
a vehicle inside a boundary was moved straight out along the radius, through whatever
lay there. The maps below are built voxel by voxel: an obstacle's core OCCUPIED, the
vehicle inside the boundary around it, facing the obstacle (west). In the first, seen
free everywhere except a slab beyond the boundary on the radial side (never seen, seen
occupied or hit once): the radial way out crosses the slab, the ways out to the side are
seen free. In the second, only a line east of the vehicle was seen (its rim never, as
beside a forward camera): the radial way is free once the camera looks along it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from companion.guidance.envelope import EnvelopeConfig
from companion.guidance.hold import (
    HoldPlacement,
    WayCheck,
    hold_point,
    inside_any,
    keep_target_out,
    way_out,
)
from companion.known_space import FREE, OCCUPIED, TENTATIVE, UNKNOWN, KnownSpace
from companion.perception import PerceptionConfig

pytestmark = pytest.mark.unit

VEHICLE_RADIUS_M = PerceptionConfig().vehicle_radius_m  # 0.35 m
ENVELOPE = EnvelopeConfig()
HALF_HEIGHT_M = ENVELOPE.vehicle_half_height_m
INFLATE_M = VEHICLE_RADIUS_M + PerceptionConfig().safety_margin_m  # 0.65 m
CLEARANCE_M = 0.3
CENTRE = np.array([0.0, 0.0, -7.0])
CORE_M = 0.35  # the obstacle: a ball of this radius, seen occupied
BOUNDARY_M = CORE_M + INFLATE_M  # 1.0 m
POS = CENTRE + np.array([0.0, 0.8, 0.0])  # 0.2 m inside the boundary, east of the centre
SLAB_EAST_M = 1.2  # beyond this east coordinate the slab (never seen free)
WEST_RAD = -math.pi / 2  # the vehicle faces the obstacle
EAST_RAD = math.pi / 2


@dataclass(frozen=True)
class Ball:
    center_ned_m: tuple[float, float, float]
    radius_m: float


BOUNDARY = Ball(tuple(CENTRE), BOUNDARY_M)


def _map(slab_state: int, everywhere: int = FREE) -> KnownSpace:
    """``everywhere`` (seen free by default), the obstacle's core OCCUPIED, and the slab
    east of ``SLAB_EAST_M`` in ``slab_state``."""
    space = KnownSpace()
    space.mark_vehicle(POS)
    idx = np.indices(space.grid.shape).reshape(3, -1).T
    centres = (idx + space.origin_vox + 0.5) * space.config.voxel_m
    state = np.full(len(centres), everywhere, np.int8)
    state[centres[:, 1] > SLAB_EAST_M] = slab_state
    state[np.linalg.norm(centres - CENTRE, axis=1) <= CORE_M] = OCCUPIED
    space.grid[...] = state.reshape(space.grid.shape)
    return space


def _check(space: KnownSpace, heading_rad: float = WEST_RAD) -> WayCheck:
    """The map's question, as the pipeline asks it (its section, near field, look rule)."""
    return WayCheck(
        free_distance=space.free_distance_m,
        radius_m=VEHICLE_RADIUS_M,
        half_height_m=HALF_HEIGHT_M,
        near_field_m=ENVELOPE.near_field_m,
        heading_rad=heading_rad,
        look_half_angle_deg=ENVELOPE.look_half_angle_deg,
    )


@pytest.mark.parametrize("slab_state", [UNKNOWN, OCCUPIED, TENTATIVE])
def test_the_way_out_avoids_a_radial_escape_through_space_not_seen_free(slab_state):
    check = _check(_map(slab_state))
    # the radial escape, unchecked (what was sent before): 0.5 m east, into the slab
    radial = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M)
    assert radial.placement is HoldPlacement.ESCAPE
    np.testing.assert_allclose(radial.pos_ned_m, CENTRE + np.array([0.0, 1.3, 0.0]), atol=1e-9)
    assert not check.seen_free(POS, radial.pos_ned_m, looked=True)  # not even once looked

    out = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=check)
    point = np.array(out.pos_ned_m)
    assert out.placement is HoldPlacement.NEAREST_OUT, out
    # its whole move seen free for the vehicle's section, rim included: no look needed
    assert check.seen_free(POS, point, looked=False)
    assert out.look_yaw_rad is None
    assert not inside_any(point, [Ball(BOUNDARY.center_ned_m, BOUNDARY_M + CLEARANCE_M - 1e-9)])
    # the nearest such way: no farther than straight north (d² + 0.8² = 1.3²: 1.025 m,
    # whose move keeps the rim at 0.8 + 0.35 = 1.15 m east, short of the slab), within the
    # search's ~14° of direction (up to 1.13 m on a direction 7° off) and 5 cm of step
    moved = float(np.linalg.norm(point - POS))
    assert 0.5 < moved <= 0.8 * math.sin(math.radians(7.0)) + math.sqrt(1.05 + 0.01) + 0.05
    assert point[1] <= SLAB_EAST_M  # never into the slab


def test_the_hold_and_the_kept_out_carrot_take_the_same_way_out():
    check = _check(_map(UNKNOWN))
    expected = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=check)
    held = hold_point(
        POS,
        np.zeros(3),
        [BOUNDARY],
        latency_s=0.15,
        accel_mps2=2.0,
        clearance_m=CLEARANCE_M,
        way_check=check,
    )
    assert held == expected
    # a carrot held short inside the boundary (nothing seen free along its ray beyond
    # 0.1 m): the way out, checked
    kept = keep_target_out(
        POS,
        POS + np.array([0.0, 0.1, 0.0]),
        [BOUNDARY],
        free_m=0.1,
        clearance_m=CLEARANCE_M,
        way_check=check,
    )
    assert kept == expected


def test_with_no_way_out_seen_free_the_vehicle_holds_where_it_is_and_says_so():
    # every voxel around seen occupied (a vehicle boxed in; its own centre is excused):
    # no way out is seen free, and looking along one would not make it so
    for heading in (WEST_RAD, EAST_RAD):
        space = _map(OCCUPIED, everywhere=OCCUPIED)
        out = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=_check(space, heading))
        assert out.placement is HoldPlacement.UNSEEN
        assert out.look_yaw_rad is None
        assert out.moved  # reported: the braking point was not used
        np.testing.assert_array_equal(out.pos_ned_m, POS)  # where it is, never deeper


def _map_seen_along_a_line_east() -> KnownSpace:
    """Nothing seen but the obstacle's core and a line of voxels east of the vehicle,
    along the radial way out: what the camera shows of a way it looks along (the rim
    beside the vehicle stays unseen, outside any forward camera's view)."""
    space = _map(UNKNOWN, everywhere=UNKNOWN)
    idx = np.indices(space.grid.shape).reshape(3, -1).T
    centres = (idx + space.origin_vox + 0.5) * space.config.voxel_m
    rel = centres - CENTRE
    line = (np.abs(rel[:, 0]) < 0.2) & (np.abs(rel[:, 2]) < 0.2) & (rel[:, 1] > 0.5)
    space.grid.reshape(-1)[line] = FREE
    return space


def test_a_way_out_seen_only_along_its_line_is_looked_at_before_it_is_flown():
    space = _map_seen_along_a_line_east()
    # facing the obstacle: the way out (east, behind) is not in the view; nothing moves,
    # the vehicle turns to look along it (its bearing: east)
    out = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=_check(space, WEST_RAD))
    assert out.placement is HoldPlacement.UNSEEN
    np.testing.assert_array_equal(out.pos_ned_m, POS)
    assert out.look_yaw_rad == pytest.approx(EAST_RAD, abs=1e-9)
    # facing it (within the look half-angle, 24°): flown, still facing it
    for off_deg in (0.0, 20.0, -20.0):
        heading = EAST_RAD + math.radians(off_deg)
        out = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=_check(space, heading))
        assert out.placement is HoldPlacement.ESCAPE, (off_deg, out)
        np.testing.assert_allclose(out.pos_ned_m, CENTRE + np.array([0.0, 1.3, 0.0]), atol=1e-9)
        assert out.look_yaw_rad == pytest.approx(EAST_RAD, abs=1e-9)


def test_a_way_out_checked_by_a_plain_rule_is_the_nearest_allowed():
    """The map's free distance as any callable: nothing free with an eastward part, the
    nearest way out is the tangent one (north, south, up or down: 1.025 m)."""

    def not_east(start, unit, radius_m, limit_m, *_) -> float:
        return limit_m if float(unit[1]) <= 1e-9 else 0.0

    check = WayCheck(not_east, VEHICLE_RADIUS_M, HALF_HEIGHT_M)
    out = way_out(POS, [BOUNDARY], clearance_m=CLEARANCE_M, way_check=check)
    point = np.array(out.pos_ned_m)
    assert out.placement is HoldPlacement.NEAREST_OUT
    assert point[1] <= POS[1] + 1e-9
    assert float(np.linalg.norm(point - CENTRE)) >= BOUNDARY_M + CLEARANCE_M - 1e-9
    best = math.sqrt((BOUNDARY_M + CLEARANCE_M) ** 2 - 0.8**2)
    moved = float(np.linalg.norm(point - POS))
    assert best - 1e-9 <= moved <= best / math.cos(math.radians(8.0)) + 0.05


@pytest.mark.parametrize(
    ("off", "seen_free"),
    [
        ((0.3, 0.0, 0.0), True),  # north, beside the obstacle, in seen-free space
        ((0.0, 0.0, -1.0), True),  # up
        ((0.0, 0.3, 0.0), True),  # east, the centre stops at 1.1 m, short of the slab
        ((0.0, 0.6, 0.0), False),  # east into the slab (1.4 m)
        ((0.0, -0.6, 0.0), False),  # west (looked along), into the obstacle's core
        ((0.5, 0.38, 0.0), False),  # the rim (0.35 m beside the centre) reaches the slab
    ],
)
def test_the_seen_free_question_is_the_sections_free_distance(off, seen_free):
    """``WayCheck.seen_free``: the vehicle's section (0.35 m wide, 0.2 m high) in FREE
    voxels over the whole move; off the camera's heading (west), no near-field excuse."""
    check = _check(_map(UNKNOWN))
    assert check.seen_free(POS, POS + np.array(off)) is seen_free
    assert check.seen_free(POS, POS)  # staying put is no move


def _step_search(pos, balls, clearance_m, prefer, search_m=4.0, step_m=0.05):
    """The per-step search ``nearest_outside`` ran before it became the first of
    ``ways_outside`` (one step at a time over all 200 directions)."""
    from companion.guidance.hold import _DIRECTIONS

    centres = np.array([b.center_ned_m for b in balls])
    radii = np.array([b.radius_m for b in balls])
    along = None if prefer is None else _DIRECTIONS @ (prefer / np.linalg.norm(prefer))
    for clearance in (clearance_m, 0.0) if clearance_m > 0.0 else (0.0,):
        for k in range(1, int(search_m / step_m) + 1):
            points = pos + _DIRECTIONS * (k * step_m)
            dist = np.linalg.norm(points[:, None, :] - centres[None, :, :], axis=-1)
            clear = np.flatnonzero(np.all(dist >= radii + clearance, axis=1))
            if clear.size:
                return points[clear[0] if along is None else clear[np.argmax(along[clear])]]
    return None


@pytest.mark.parametrize("seed", range(10))
def test_the_first_way_out_is_the_nearest_point_the_step_search_found(seed):
    """Unchecked, the way out is what it was: ``ways_outside`` tests the steps in blocks
    and drops directions already out, on the same points (bit for bit)."""
    from companion.guidance.hold import nearest_outside

    rng = np.random.default_rng([seed, 36])
    for _ in range(20):
        balls = [
            Ball(tuple(rng.uniform(-2.0, 2.0, 3)), float(rng.uniform(0.3, 1.5)))
            for _ in range(int(rng.integers(1, 30)))
        ]
        pos = rng.uniform(-2.5, 2.5, 3)
        prefer = rng.normal(size=3) if rng.uniform() < 0.5 else None
        clearance = float(rng.choice([0.0, 0.3]))
        if not inside_any(pos, [Ball(b.center_ned_m, b.radius_m + clearance) for b in balls]):
            continue
        got = nearest_outside(pos, balls, clearance_m=clearance, prefer_ned=prefer)
        want = _step_search(pos, balls, clearance, prefer)
        assert (got is None) == (want is None)
        if want is not None:
            np.testing.assert_array_equal(got, want)


def test_a_hold_with_no_way_out_seen_free_is_said_as_such():
    from types import SimpleNamespace

    from companion.core.mission import Mission

    mission = Mission([(0.0, 0.0, -7.0)], goal_tolerance_m=0.5)
    out = SimpleNamespace(target_kept_out=HoldPlacement.UNSEEN, setpoint_ned_m=POS)
    notices, events = [], []
    mission._report_kept_out(out, 0, notices, events)
    assert [n.text for n in notices] == [
        "Inside a boundary, no way out seen free: holding where it is"
    ]
    assert [(e.name, e.fields["placement"]) for e in events] == [
        ("target_kept_out", "no_way_out_seen_free")
    ]
