"""Known space: a voxel hit in one frame only (TENTATIVE) and what later frames do with it.

Issue 36, facing_away-304 (stereo): two voxels hit once by a false match lay on the path's
centre line 0.5-0.8 m ahead, at the camera's height, where the view is open sky (no match,
the column above unmatched too). The open-sky rule freed only UNKNOWN voxels, so they
stayed TENTATIVE, and the vehicle sat before them for 40 s. These tests fly that pattern on
the map alone, and the cases where a voxel hit once must stay in the way: a pole that then
falls in the matcher's blind band, or that the sky stops short of.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.known_space import FREE, TENTATIVE, KnownSpace
from protocols.camera import CameraModel
from protocols.frames import rotation_321

pytestmark = pytest.mark.unit

K = CameraModel().intrinsics
LEVEL_NORTH = rotation_321(0.0, 0.0, 0.0)  # body FRD = NED: the camera looks north
NORTH = np.array([1.0, 0.0, 0.0])
# the envelope's swept section: radius, half height, body, near field [m]
SECTION = {"radius_m": 0.35, "half_height_m": 0.2, "body_m": 0.35, "near_field_m": 1.05}


def _sky_over_far_ground() -> np.ndarray:
    """Nothing matched but far ground in the bottom rows: everything above is open sky."""
    depth = np.full((K.height_px, K.width_px), np.nan, np.float32)
    depth[-8:, :] = 40.0
    return depth


def _pixel(point_ned_m, cam_ned_m) -> tuple[int, int]:
    """Pixel (u, v) of a NED point for the level, north-facing left eye."""
    rel = np.asarray(point_ned_m) - cam_ned_m  # NED = FRD here; camera x right, y down
    return (
        round(K.cx_px + K.fx_px * rel[1] / rel[0]),
        round(K.cy_px + K.fy_px * rel[2] / rel[0]),
    )


def _false_match(point_ned_m, pos_ned_m) -> np.ndarray:
    """The sky frame with a 4 × 4 block matched at ``point_ned_m`` (one frame's mismatch)."""
    cam = np.asarray(pos_ned_m) + np.array([0.0, -K.baseline_m / 2, 0.0])
    u, v = _pixel(point_ned_m, cam)
    u0, v0 = 4 * (u // 4), 4 * (v // 4)
    depth = _sky_over_far_ground()
    depth[v0 : v0 + 4, u0 : u0 + 4] = float(np.asarray(point_ned_m)[0] - cam[0])
    return depth


def test_a_false_match_in_open_sky_does_not_block_the_path_for_long():
    """A one-frame hit 1.6 m ahead on the centre line, then frames that see open sky
    through it (the vehicle comes to 0.6 m of it, nearer than the matcher reaches): the
    open sky that frees unknown space frees the voxel too, within a frame, and the path is
    free to the sky's reach. On 231a1e1 it stayed TENTATIVE and the path ended before it
    for as long as the vehicle looked (facing_away-304: 40 s)."""
    pos = np.array([0.1, 0.1, -7.1])  # a voxel centre: the centre line runs through voxels
    phantom = pos + np.array([1.6, 0.0, 0.0])
    space = KnownSpace()
    space.integrate(_sky_over_far_ground(), K, pos, LEVEL_NORTH)
    space.integrate(_false_match(phantom, pos), K, pos, LEVEL_NORTH)
    assert space.state_at(phantom) == TENTATIVE
    assert space.free_distance_m(pos, NORTH, limit_m=8.0, **SECTION) < 1.6
    for step in range(30):  # one second at 30 frames/s, closing in to 0.6 m
        here = pos + np.array([min(step, 10) * 0.1, 0.0, 0.0])
        space.integrate(_sky_over_far_ground(), K, here, LEVEL_NORTH)
    assert space.state_at(phantom) == FREE
    here = pos + np.array([1.0, 0.0, 0.0])
    assert space.free_distance_m(here, NORTH, limit_m=8.0, **SECTION) >= 6.0


def test_a_pole_hit_once_then_in_the_blind_band_stays_in_the_way():
    """A pole taller than the view, matched in one frame just right of the blind band,
    then (the vehicle yawed 8° right) inside it: the band is never sky, so no ray sees
    the pole's voxels free and they stay TENTATIVE, in the way of a path toward them.
    (Far ground is matched below the band here, so that the reach rule, which also keeps
    the sky out of a column with nothing matched, does not hide the band rule.)"""
    band_px = 64
    pos = np.array([0.1, 0.1, -7.1])
    cam = pos + np.array([0.0, -K.baseline_m / 2, 0.0])
    depth_m = 3.0
    u_pole = band_px + 2  # the pole's left edge, just outside the band
    first = _sky_over_far_ground()
    first[:-8, :band_px] = np.nan  # far ground matched below the band (the band rule alone)
    first[:, u_pole : u_pole + 8] = depth_m  # 8 px: 6.7 cm at 3 m
    space = KnownSpace()
    space.integrate(first, K, pos, LEVEL_NORTH, blind_band_px=band_px)
    east_m = depth_m * (u_pole + 4 - K.cx_px) / K.fx_px
    pole = cam + np.array([depth_m + 0.01, east_m, 0.0])
    assert space.state_at(pole) == TENTATIVE
    yawed = rotation_321(0.0, 0.0, math.radians(8.0))  # the pole moves 50 px left
    for _ in range(30):
        later = _sky_over_far_ground()
        later[:-8, :band_px] = np.nan
        space.integrate(later, K, pos, yawed, blind_band_px=band_px)
    assert space.state_at(pole) == TENTATIVE
    toward = (pole - pos) / np.linalg.norm(pole - pos)
    assert space.free_distance_m(pos, toward, limit_m=8.0, **SECTION) < depth_m


def test_a_pole_hit_once_then_unmatched_stays_behind_the_ground_before_it():
    """A textureless pole (0.33 m wide) matched in one frame only (its top in view), then unmatched
    from the top of the view down to the ground in front of it: the sky in its columns
    ends where the last ground was matched (the reach rule), short of the pole, so the
    pole's voxels stay TENTATIVE."""
    pos = np.array([0.1, 0.1, -7.1])
    cam = pos + np.array([0.0, -K.baseline_m / 2, 0.0])
    depth_m = 3.0
    u0 = 4 * (round(K.cx_px) // 4)
    first = _sky_over_far_ground()
    v_top = round(K.cy_px - K.fy_px * 0.5 / depth_m)  # the pole's top 0.5 m above the camera
    first[v_top:, u0 - 16 : u0 + 24] = depth_m  # 40 px: 0.33 m at 3 m
    space = KnownSpace()
    space.integrate(first, K, pos, LEVEL_NORTH)
    pole = cam + np.array([depth_m + 0.01, (u0 + 4 - K.cx_px) / K.fx_px * depth_m, 0.0])
    assert space.state_at(pole) == TENTATIVE
    for _ in range(30):
        later = _sky_over_far_ground()
        # the ground before the pole's foot (7 m below, 2.5 m ahead) is all it matches
        later[-8:, u0 - 16 : u0 + 24] = 2.5
        space.integrate(later, K, pos, LEVEL_NORTH)
    assert space.state_at(pole) == TENTATIVE
    assert space.free_distance_m(pos, NORTH, limit_m=8.0, **SECTION) < depth_m
