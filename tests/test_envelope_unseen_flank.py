"""The envelope's near-field excuse needs a look: a target beside an unseen flank waits.

Windy stereo seed 147 (stop 42): inside the boundary of a 1.37 m sphere, the escape
target came 0.13 m from the sphere's true surface. Within 1 m of it the sphere's shell
was unknown (never seen), the nearest OCCUPIED voxel 1.4 m away, and the envelope
excused the unseen rim of the vehicle's section within ``near_field_m`` because no
obstacle extent covered that flank. The map below is that state, built voxel by voxel:
the way the vehicle came seen free, a cap of the sphere seen occupied, the flank beside
the vehicle never seen.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from companion.guidance.config import GuidanceConfig
from companion.guidance.envelope import EnvelopeConfig, envelope_step
from companion.guidance.map_boundaries import MapBoundaryConfig, map_boundaries, solid_extent
from companion.known_space import FREE, OCCUPIED, UNKNOWN, KnownSpace
from companion.perception import PerceptionConfig
from protocols.camera import R_FRD_FROM_CAM, CameraModel
from protocols.frames import rotation_321

pytestmark = pytest.mark.unit

K = CameraModel().intrinsics
CENTRE = np.array([0.0, 0.0, -7.0])
RADIUS_M = 1.37  # seed 147's sphere
VEHICLE_RADIUS_M = PerceptionConfig().vehicle_radius_m
MAX_ELEV_RAD = GuidanceConfig().max_aim_elevation_rad
BOUNDARIES = MapBoundaryConfig(
    detect_range_m=PerceptionConfig().threshold_m,
    inflate_m=VEHICLE_RADIUS_M + PerceptionConfig().safety_margin_m,
)


def _sphere_depth(pos_ned_m, R_ned_from_frd) -> np.ndarray:
    """Exact depth image of the sphere seen by the left eye; +inf where a ray misses."""
    u, v = np.meshgrid(np.arange(K.width_px), np.arange(K.height_px))
    rays = np.stack([(u - K.cx_px) / K.fx_px, (v - K.cy_px) / K.fy_px, np.ones(u.shape)], -1)
    cam = np.asarray(pos_ned_m) + R_ned_from_frd @ np.array([0.0, -K.baseline_m / 2, 0.0])
    d = rays @ (R_ned_from_frd @ R_FRD_FROM_CAM).T
    oc = cam - CENTRE
    a = np.einsum("hwi,hwi->hw", d, d)
    b = 2.0 * d @ oc
    disc = b * b - 4 * a * (oc @ oc - RADIUS_M**2)
    t = (-b - np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
    return np.where(disc >= 0.0, t, np.inf).astype(np.float32)


def _map_with_an_unseen_flank(pos_ned_m: np.ndarray) -> KnownSpace:
    """Seen free where the vehicle came from (south and west of the sphere), a cap of the
    sphere facing south-west seen occupied, everything else (the north-west flank beside
    the vehicle) never seen."""
    space = KnownSpace()
    space.mark_vehicle(pos_ned_m)
    idx = np.indices(space.grid.shape).reshape(3, -1).T
    centres = (idx + space.origin_vox + 0.5) * space.config.voxel_m
    rel = centres - CENTRE
    r = np.linalg.norm(rel, axis=1)
    cap = rel @ np.array([-1.0, -1.0, 0.0]) / math.sqrt(2.0) > np.cos(np.radians(40.0)) * r
    state = np.full(len(centres), UNKNOWN, np.int8)
    state[((centres[:, 0] < -1.2) | (centres[:, 1] < -2.3)) & (r > RADIUS_M + 0.15)] = FREE
    state[cap & (np.abs(r - RADIUS_M) < 0.15)] = OCCUPIED
    space.grid[...] = state.reshape(space.grid.shape)
    space.mark_vehicle(pos_ned_m)  # the vehicle's own voxels
    return space


def _carrot(space: KnownSpace, pos, setpoint, heading_rad: float) -> np.ndarray:
    boundaries = map_boundaries(space, pos, setpoint, BOUNDARIES)
    out = envelope_step(
        pos_ned_m=pos,
        vel_ned_mps=np.zeros(3),
        setpoint_ned_m=setpoint,
        free_distance=functools.partial(
            space.free_distance_m, solid_ned_m=solid_extent(boundaries)
        ),
        vehicle_radius_m=VEHICLE_RADIUS_M,
        max_path_elevation_rad=MAX_ELEV_RAD,
        heading_rad=heading_rad,
    )
    return np.asarray(out.setpoint_ned_m)


def _least_surface_distance_m(start, end) -> float:
    """Least distance from the segment start → end to the sphere's true surface [m]."""
    seg = start + np.outer(np.linspace(0.0, 1.0, 200), end - start)
    return float(np.min(np.linalg.norm(seg - CENTRE, axis=1)) - RADIUS_M)


@pytest.mark.parametrize("bearing_deg", [140.0, 150.0])
def test_a_target_beside_an_unseen_flank_waits_for_the_camera(bearing_deg):
    """The vehicle 0.6 m outside the sphere on its never-seen flank, facing away from a
    target 2 m off whose straight path passes 0.1 m from the surface. On main (stop 42)
    the near-field excuse sent a carrot 0.7 m along it, the swept line 0.22 m from the
    surface (the collision distance is 0.35 m). Now the carrot waits until the camera has
    looked; once it has (two frames facing the path), what it saw keeps the carrot's line
    a vehicle radius from the surface."""
    a = math.radians(bearing_deg)
    pos = CENTRE + (RADIUS_M + 0.6) * np.array([math.cos(a), math.sin(a), 0.0])
    inward = (CENTRE - pos) / np.linalg.norm(CENTRE - pos)
    side = np.array([inward[1], -inward[0], 0.0])
    off = math.asin((RADIUS_M + 0.1) / np.linalg.norm(CENTRE - pos))
    path = math.cos(off) * inward + math.sin(off) * side  # passes 0.1 m from the surface
    setpoint = pos + 2.0 * path
    assert _least_surface_distance_m(pos, setpoint) == pytest.approx(0.1, abs=0.01)
    space = _map_with_an_unseen_flank(pos)
    facing = math.atan2(path[1], path[0])

    carrot = _carrot(space, pos, setpoint, heading_rad=facing + math.pi)
    least = _least_surface_distance_m(pos, carrot)
    assert least >= VEHICLE_RADIUS_M, (carrot - pos, least)

    R = rotation_321(0.0, 0.0, facing)
    for _ in range(2):  # the vehicle turned toward its target: the flank is in the view
        space.integrate(_sphere_depth(pos, R), K, pos, R)
    carrot = _carrot(space, pos, setpoint, heading_rad=facing)
    least = _least_surface_distance_m(pos, carrot)
    assert least >= VEHICLE_RADIUS_M, (carrot - pos, least)


def _recording_free(free_m: float):
    calls = []

    def free(pos, direction, radius_m, limit_m, half_height_m, body_m, near_field_m):
        calls.append(near_field_m)
        return free_m

    return free, calls


@pytest.mark.parametrize(
    ("path_bearing_deg", "heading_deg", "excused"),
    [
        (0.0, 0.0, True),
        (0.0, 23.0, True),
        (0.0, -23.0, True),
        (0.0, 25.0, False),
        (90.0, 0.0, False),
        (180.0, 0.0, False),
        (170.0, -170.0, True),  # across ±180°
        (0.0, None, True),  # no heading stated: the excuse as before
    ],
)
def test_the_near_field_is_excused_only_along_the_heading(path_bearing_deg, heading_deg, excused):
    cfg = EnvelopeConfig()
    free, calls = _recording_free(5.0)
    b = math.radians(path_bearing_deg)
    envelope_step(
        pos_ned_m=np.zeros(3),
        vel_ned_mps=np.zeros(3),
        setpoint_ned_m=[3.0 * math.cos(b), 3.0 * math.sin(b), 0.0],
        free_distance=free,
        vehicle_radius_m=VEHICLE_RADIUS_M,
        max_path_elevation_rad=MAX_ELEV_RAD,
        config=cfg,
        heading_rad=None if heading_deg is None else math.radians(heading_deg),
    )
    assert calls[0] == (cfg.near_field_m if excused else 0.0)


def test_a_vertical_path_keeps_the_excuse():
    """A path with no horizontal part has nothing to turn toward (step 7 climbs along the
    heading where it can): the excuse is as before."""
    cfg = EnvelopeConfig(stage_horizontal_m=0.0)
    free, calls = _recording_free(5.0)
    envelope_step(
        pos_ned_m=np.zeros(3),
        vel_ned_mps=np.zeros(3),
        setpoint_ned_m=[0.0, 0.0, -3.0],
        free_distance=free,
        vehicle_radius_m=VEHICLE_RADIUS_M,
        max_path_elevation_rad=MAX_ELEV_RAD,
        config=cfg,
        heading_rad=math.radians(120.0),
    )
    assert calls[0] == cfg.near_field_m
