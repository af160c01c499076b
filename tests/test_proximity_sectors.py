"""OBSTACLE_DISTANCE sectors from the known-space map against closed forms."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from companion.known_space import FREE, OCCUPIED, TENTATIVE, UNKNOWN, KnownSpace, KnownSpaceConfig
from companion.proximity.sectors import (
    MAX_SECTORS,
    UINT16_MAX,
    ProximityConfig,
    map_reach_m,
    sectors_from_map,
    unknown_sectors,
)

POS = np.array([3.0, -2.0, -7.0])  # off the voxel grid's lines on purpose
CFG = ProximityConfig()
VOXEL = 0.2
DIAG = VOXEL * math.sqrt(2.0)  # the footprint's diagonal: the sectoring's resolution


GRID_ONLY = KnownSpaceConfig(far_range_m=0.0)  # the 0.2 m grid without its far layer


def _map(fill=FREE, config=GRID_ONLY) -> KnownSpace:
    space = KnownSpace(config)
    space.mark_vehicle(POS)
    space.grid[:] = fill
    if space.far is not None:
        space.far.grid[:] = fill
    return space


def _centres(space: KnownSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """North, east, down of every voxel centre relative to POS [m] (broadcastable)."""
    v = space.config.voxel_m
    n, e, d = (
        (np.arange(s) + o + 0.5) * v - p
        for s, o, p in zip(space.grid.shape, space.origin_vox, POS, strict=True)
    )
    return n[:, None, None], e[None, :, None], d[None, None, :]


def _wall(space: KnownSpace, d_m: float, alpha_rad: float) -> None:
    """OCCUPIED every voxel that touches the half-space beyond a plane at ``d_m`` whose
    normal points to bearing ``alpha_rad`` (NED) from POS."""
    n, e, _ = _centres(space)
    c, s = math.cos(alpha_rad), math.sin(alpha_rad)
    along = n * c + e * s
    touch = along >= d_m - 0.5 * VOXEL * (abs(c) + abs(s))
    space.grid[np.broadcast_to(touch, space.grid.shape)] = OCCUPIED


def _wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize(
    ("d_m", "alpha_deg", "yaw_deg"),
    [(3.0, 0.0, 0.0), (2.2, 17.0, 0.0), (4.1, -63.0, 30.0), (1.5, 135.0, -100.0)],
)
def test_wall_sector_distances_are_d_over_cos(d_m, alpha_deg, yaw_deg):
    """A wall at distance d whose normal points to body bearing α: sector k reads
    d / cos(max(0, |θ_k − α| − increment/2)): at most that (1 cm: the cm floor), and no
    nearer than the same for the voxelized wall's front (d less the voxels' depth along
    the normal), less one footprint diagonal (a voxel's nearest point is conservative)."""
    space = _map()
    _wall(space, d_m, math.radians(alpha_deg + yaw_deg))
    sec = sectors_from_map(space, POS, math.radians(yaw_deg), CFG)
    reach = map_reach_m(space)
    a = math.radians(alpha_deg + yaw_deg)
    thick = VOXEL * (abs(math.cos(a)) + abs(math.sin(a)))  # the voxelized wall's front
    theta = sec.bearings_deg()
    off = np.maximum(np.abs(_wrap_deg(theta - alpha_deg)) - CFG.increment_deg / 2.0, 0.0)
    checked = 0
    for k in range(CFG.n_sectors):
        got_cm = int(sec.distances_cm[k])
        if off[k] >= 90.0:
            assert got_cm == sec.no_obstacle_cm, f"sector {k} faces away: clear"
            continue
        expect = d_m / math.cos(math.radians(off[k]))
        lowest = (d_m - thick) / math.cos(math.radians(off[k])) - DIAG
        if lowest > reach:
            assert got_cm == sec.no_obstacle_cm, f"sector {k}: wall beyond reach"
        elif expect < reach:
            got = got_cm / 100.0
            assert lowest - 0.01 <= got <= expect + 0.01, (
                f"sector {k} (θ={theta[k]:.1f}°): {got:.3f} m, closed form {expect:.3f} m"
            )
            checked += 1
    assert checked >= 8


def test_unknown_is_never_clear():
    """All UNKNOWN: every sector UINT16_MAX; all FREE: every sector 'no obstacle'; one
    unseen voxel: only the sectors its footprint touches are unknown."""
    assert np.all(sectors_from_map(_map(UNKNOWN), POS, 0.0, CFG).distances_cm == UINT16_MAX)
    clear = sectors_from_map(_map(FREE), POS, 0.0, CFG)
    assert np.all(clear.distances_cm[:72] == clear.no_obstacle_cm)
    assert clear.counts() == (0, 72, 0)
    for state in (UNKNOWN, TENTATIVE):
        space = _map(FREE)
        target = POS + np.array([3.0 * math.cos(0.6), 3.0 * math.sin(0.6), 0.0])
        idx = np.floor(target / VOXEL).astype(int) - space.origin_vox
        space.grid[tuple(idx)] = state
        sec = sectors_from_map(space, POS, 0.0, CFG)
        unknown = np.flatnonzero(sec.distances_cm[:72] == UINT16_MAX)
        centre = (idx + space.origin_vox + 0.5) * VOXEL - POS
        corners = [
            math.degrees(math.atan2(centre[1] + de, centre[0] + dn))
            for dn in (-0.1, 0.1)
            for de in (-0.1, 0.1)
        ]
        lo, hi = min(corners), max(corners)
        expect = [
            k
            for k in range(72)
            if 5.0 * k - 2.5 < hi and 5.0 * k + 2.5 > lo  # sector touches the footprint
        ]
        assert list(unknown) == expect and 1 <= len(expect) <= 2


def test_the_height_band_and_the_body_are_respected():
    """Occupied ground below the band, a ceiling above it and the vehicle's own voxels
    do not count; an obstacle inside the band does."""
    space = _map(FREE)
    _, _, down = _centres(space)
    band = CFG.band_half_height_m
    outside = (down - 0.5 * VOXEL > band + 1e-9) | (down + 0.5 * VOXEL < -band - 1e-9)
    space.grid[np.broadcast_to(outside, space.grid.shape)] = OCCUPIED
    idx = np.floor(POS / VOXEL).astype(int) - space.origin_vox
    space.grid[tuple(idx)] = OCCUPIED  # the vehicle's own voxel
    sec = sectors_from_map(space, POS, 0.0, CFG)
    assert sec.counts() == (0, 72, 0)
    edge = (down + 0.5 * VOXEL > band) & (down - 0.5 * VOXEL < band)  # touches the band
    n, e, _ = _centres(space)
    post = (np.abs(n - 2.5) < 0.15) & (np.abs(e) < 0.15) & edge
    space.grid[np.broadcast_to(post, space.grid.shape)] = OCCUPIED
    sec = sectors_from_map(space, POS, 0.0, CFG)
    assert sec.counts()[0] >= 1
    assert 2.5 - DIAG <= sec.distances_cm[0] / 100.0 <= 2.5


def test_body_frame_follows_yaw():
    """A post due east reads at body bearing 90° heading north, 0° heading east and
    −90° (sector 54) heading west."""
    space = _map(FREE)
    n, e, _ = _centres(space)
    post = (np.abs(n) < 0.15) & (np.abs(e - 3.0) < 0.15)
    space.grid[np.broadcast_to(post, space.grid.shape)] = OCCUPIED
    for yaw_deg, sector in ((0.0, 18), (90.0, 0), (-90.0, 36), (180.0, 54)):
        sec = sectors_from_map(space, POS, math.radians(yaw_deg), CFG)
        d = sec.distances_cm[:72]
        nearest = np.flatnonzero(d == d.min())  # the post's corners reach the neighbours
        assert sector in nearest and len(nearest) <= 3, f"yaw {yaw_deg}°: nearest {nearest}"
        assert np.count_nonzero(d < sec.no_obstacle_cm) <= 3


def test_an_obstacle_nearer_than_min_distance_is_reported_at_it():
    """Autopilots drop readings below min_distance: a real obstacle is never dropped."""
    space = _map(FREE)
    n, e, _ = _centres(space)
    post = (np.abs(n - 0.45) < 0.15) & (np.abs(e) < 0.15)
    space.grid[np.broadcast_to(post, space.grid.shape)] = OCCUPIED
    cfg = ProximityConfig(min_distance_m=0.5)
    sec = sectors_from_map(space, POS, 0.0, cfg)
    assert sec.distances_cm[0] == 50 == sec.min_distance_cm


def test_layout_is_configurable():
    """36 sectors of 10° centred from −175°; 10 sectors of 4.8° (the camera's 48°)."""
    space = _map(FREE)
    _wall(space, 3.0, 0.0)
    wide = sectors_from_map(space, POS, 0.0, ProximityConfig(n_sectors=36, increment_deg=10.0))
    assert wide.distances_cm[0] / 100.0 == pytest.approx(3.0, abs=DIAG + 0.01)
    assert np.all(wide.distances_cm[36:] == UINT16_MAX)
    front = ProximityConfig(n_sectors=10, increment_deg=4.8, angle_offset_deg=-21.6)
    sec = sectors_from_map(space, POS, 0.0, front)
    expect = 3.0 / np.cos(np.radians(np.maximum(np.abs(sec.bearings_deg()) - 2.4, 0.0)))
    np.testing.assert_allclose(sec.distances_cm[:10] / 100.0, expect, atol=DIAG + 0.01)
    assert np.all(sec.distances_cm[10:] == UINT16_MAX)


def test_before_the_map_everything_is_unknown_and_bad_configs_are_refused():
    sec = unknown_sectors(CFG, 6.2)
    assert sec.distances_cm.shape == (MAX_SECTORS,)
    assert np.all(sec.distances_cm == UINT16_MAX) and sec.max_distance_cm == 620
    for bad in (
        {"n_sectors": 73},
        {"n_sectors": 72, "increment_deg": 6.0},
        {"rate_hz": 0.0},
        {"min_distance_m": 0.0},
        {"enabled": "yes"},
    ):
        with pytest.raises(ValueError):
            ProximityConfig(**bad)


def test_reach_is_the_smaller_of_the_trusted_range_and_the_grid():
    """The grid alone: 8 m trusted range, but the vehicle may sit 32 voxels from the edge;
    with the far layer (default): its 16 m, in a grid of 4 × (16 / 0.4 + 1) voxels."""
    assert map_reach_m(KnownSpace(GRID_ONLY)) == pytest.approx(6.2)
    space = KnownSpace()
    assert map_reach_m(space) == pytest.approx(16.0)
    assert space.far.grid.shape == (164, 164, 32) and space.far.config.voxel_m == 0.4


def test_the_far_layer_reports_a_wall_beyond_the_grid_and_defers_to_it_within():
    """A wall 11 m ahead known only to the far layer reads d / cos within the far voxel's
    diagonal; an OCCUPIED far voxel inside the grid's reach, where the grid saw free space,
    is not reported (the fine grid is the model there)."""
    space = _map(FREE, KnownSpaceConfig())
    far = space.far
    n, e, _ = _centres(far)
    far.grid[np.broadcast_to(n >= 11.0 - 0.2, far.grid.shape)] = OCCUPIED  # the wall's voxels
    sec = sectors_from_map(space, POS, 0.0, CFG)
    far_diag = 0.4 * math.sqrt(2.0)
    for k, theta in enumerate(sec.bearings_deg()):
        off = max(abs(_wrap_deg(theta)) - CFG.increment_deg / 2.0, 0.0)
        expect = 11.0 / math.cos(math.radians(off)) if off < 90.0 else math.inf
        got = sec.distances_cm[k] / 100.0
        if expect <= 16.0 - far_diag:
            assert expect - 0.4 - far_diag - 0.01 <= got <= expect + 0.01, (k, got, expect)
        elif expect > 16.0 + far_diag:
            assert sec.distances_cm[k] == sec.no_obstacle_cm, k
    space = _map(FREE, KnownSpaceConfig())
    far = space.far
    n, e, _ = _centres(far)
    post = (np.abs(n - 3.0) < 0.3) & (np.abs(e) < 0.3)
    far.grid[np.broadcast_to(post, far.grid.shape)] = OCCUPIED
    assert sectors_from_map(space, POS, 0.0, CFG).counts() == (0, 72, 0)


@pytest.mark.parametrize(
    ("below_m", "between", "extension_m", "reported"),
    [
        (0.6, UNKNOWN, 1.0, True),  # seen only below the unseen band: it continues into it
        (0.6, FREE, 1.0, False),  # seen free between: it stops below the band
        (1.4, UNKNOWN, 1.0, False),  # farther below than the extension
        (0.6, UNKNOWN, 0.0, False),  # the extension off: the band alone
    ],
)
def test_an_obstacle_seen_only_below_the_unseen_band_continues_into_it(
    below_m, between, extension_m, reported
):
    """A post 3 m ahead whose top was seen ``below_m`` under the band's edge while the
    band above it is unseen (a camera pitched by the speed): an obstacle at 3 m when
    joined to the band through unseen voxels within ``unseen_extension_m``; else the
    sector is unknown, never clear."""
    space = _map(FREE)
    n, e, d = _centres(space)
    column = (np.abs(n - 3.1) < 0.05) & (np.abs(e - 0.1) < 0.05)  # nearest point (3, 0)
    band = CFG.band_half_height_m
    top = band + below_m  # [m below the vehicle]
    space.grid[np.broadcast_to(column & (d + 0.1 > -band) & (d - 0.1 < top), space.grid.shape)] = (
        UNKNOWN
    )
    under = column & (d - 0.1 >= band) & (d + 0.1 <= top)  # between the band and the top
    space.grid[np.broadcast_to(under, space.grid.shape)] = between
    space.grid[np.broadcast_to(column & (d - 0.1 >= top), space.grid.shape)] = OCCUPIED
    cfg = ProximityConfig(unseen_extension_m=extension_m)
    got = sectors_from_map(space, POS, 0.0, cfg).distances_cm[0]
    if reported:
        assert 3.0 - 0.01 <= got / 100.0 <= 3.0
    else:
        assert got == UINT16_MAX


def test_sectoring_is_cheap():
    """Budget: well below a millisecond-scale share of a frame (median of 20 calls)."""
    space = _map(FREE)
    _wall(space, 3.0, 0.3)
    sectors_from_map(space, POS, 0.0, CFG)
    times = []
    for _ in range(20):
        t0 = time.perf_counter()
        sectors_from_map(space, POS, 0.1, CFG)
        times.append(time.perf_counter() - t0)
    assert float(np.median(times)) < 2e-3, f"median {np.median(times) * 1e3:.2f} ms"


def test_the_run_keeps_the_sectors_of_its_closest_approach_and_draws_them():
    """History keeps the sectors at the smallest surface distance; the polar figure's
    obstacle bars are the sector distances and the other sectors reach the map's reach."""
    from evaluation.history import History
    from evaluation.plots import proximity_polar

    space = _map(FREE)
    _wall(space, 3.0, 0.0)
    history = History()
    calls = []

    def sectors():
        calls.append(1)
        return sectors_from_map(space, POS, 0.0, CFG)

    for surface in (5.0, 3.0):
        history.note_proximity(surface, sectors)
    history.settle_proximity(4.0)  # the next frame is farther: 3.0 m's sectors are kept
    history.note_proximity(4.0, sectors)
    assert history.proximity_surface_m == 3.0 and len(calls) == 1  # only the closest
    sec = history.proximity_at_closest
    assert len(calls) == 1
    fig = proximity_polar(sec, 3.0)
    heights = sorted(round(p.get_height(), 6) for p in fig.axes[0].patches)
    seen = sec.distances_cm[:72][sec.distances_cm[:72] <= sec.max_distance_cm] / 100.0
    expect = sorted([round(x, 6) for x in seen] + [6.2] * (72 - len(seen)))
    assert heights == pytest.approx(expect)


def test_position_at_send_is_carried_by_its_velocity_until_stale():
    """The newest telemetry position moved by v·age; older than 0.5 s (the autopilots'
    proximity timeout) it places nothing."""
    from companion.proximity.sender import POSE_STALE_S, position_at_send

    p, v = np.array([1.0, 2.0, -7.0]), np.array([8.0, -2.0, 0.5])
    assert np.allclose(position_at_send(p, v, 0.0), p)
    assert np.allclose(position_at_send(p, v, 0.125), p + v * 0.125)
    assert np.allclose(position_at_send(p, v, POSE_STALE_S), p + v * POSE_STALE_S)
    assert position_at_send(p, v, POSE_STALE_S + 1e-3) is None
    assert position_at_send(p, v, -0.01) is None  # a clock gone backward: not trusted
    assert position_at_send(p, v, math.inf) is None
    assert position_at_send(p, np.array([math.nan, 0.0, 0.0]), 0.1) is None


def test_the_age_of_a_pose_counts_the_wait_for_the_reader_only_on_the_host_clock():
    """Host time since the position was read × the frame clock's rate; with frames on the
    host clock at least the time since the autopilot stamped it (a busy main loop read it
    late); on the autopilot's clock (the SIL) the stamp is not compared with the host's."""
    from companion.proximity.sender import pose_age_s

    s = 1_000_000_000
    # read 0.1 s ago, stamped 0.4 s ago: it waited 0.3 s in the socket
    assert pose_age_s(10 * s, 9.9 * s, 9.6 * s, 1.0, True) == pytest.approx(0.4)
    assert pose_age_s(10 * s, 9.9 * s, 9.6 * s, 1.0, False) == pytest.approx(0.1)
    # a simulator at 4x: 0.1 s of host time is 0.4 s of its clock
    assert pose_age_s(10 * s, 9.9 * s, 123, 4.0, False) == pytest.approx(0.4)
    # a stamp the mapping puts ahead of now never shortens the receipt age
    assert pose_age_s(10 * s, 9.9 * s, 10.2 * s, 1.0, True) == pytest.approx(0.1)
