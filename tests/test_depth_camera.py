"""Depth cameras (issue 35): the companion's depth-camera source against closed forms, the
frame's encoding choosing the source, and plant-sim's RealSense-like camera model.

The contract conformance of the source runs in tests/test_depth_source.py with the matchers.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from companion.config import CompanionConfig, ConfigError, config_from_dict
from companion.depth_camera import DepthCameraConfig, DepthCameraSource, depth_plane_m
from companion.depth_source import DISP_SCALE
from companion.perception import PerceptionConfig, StereoPerception
from companion.record.format import config_to_dict
from plant_sim.depth_camera import DepthNoiseParams, depth16_from_truth
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import Box, Sphere, World
from protocols.camera import CameraModel
from protocols.stereo_frame import DepthFrame, PixelEncoding, StereoFrame, decode, encode

CAMERA = CameraModel()  # the paper's: 320 x 240, f = 359.4 px, b = 0.2 m
K = CAMERA.intrinsics
FB = K.focal_baseline_m_px
SHAPE = (K.height_px, K.width_px)


def _d16(depth_mm: np.ndarray, left=None) -> DepthFrame:
    return DepthFrame(1, 2, K, depth_mm.astype(np.uint16), PixelEncoding.DEPTH16, 0.001, left)


def test_a_plane_is_its_depth_and_its_equivalent_disparity():
    """Uniform 3.000 m: depth 3 m exactly (to float32), disparity round(16 f b / 3)."""
    dm = DepthCameraSource().compute(_d16(np.full(SHAPE, 3000)))
    np.testing.assert_allclose(dm.depth_m, 3.0, rtol=1e-7)
    assert np.all(dm.disparity_fixed == round(DISP_SCALE * FB / 3.0))
    assert dm.counts.n_valid == 320 * 240 and dm.counts.n_unmatched == 0
    assert dm.blind_band_px == math.ceil(FB / 0.3)  # the default min range 0.3 m


def test_no_data_and_too_near_are_unknown_never_free():
    depth = np.full(SHAPE, 3000)
    depth[:, 200:] = 0  # no data
    depth[:50, :100] = 250  # 0.25 m: nearer than the 0.3 m minimum range
    dm = DepthCameraSource().compute(_d16(depth))
    assert np.isnan(dm.depth_m[:, 200:]).all() and np.isnan(dm.depth_m[:50, :100]).all()
    assert not np.isinf(dm.depth_m).any()
    assert (dm.disparity_fixed[np.isnan(dm.depth_m)] < 0).all()
    assert dm.counts.n_unmatched == 240 * 120 + 50 * 100
    assert dm.counts.n_valid + dm.counts.n_unmatched == dm.depth_m.size


@pytest.mark.parametrize(
    ("fb", "max_range_m", "expected_m"),
    [(FB, 10.0, 10.0), (19.25, 20.0, 0.05 * 19.25 / 0.08), (FB, 60.0, 0.05 * FB / 0.08)],
)
def test_range_is_where_the_z_squared_error_reaches_max_rel_error(fb, max_range_m, expected_m):
    """range = min(max_range, max_rel_error f b / subpixel): there sigma(z)/z = max_rel_error."""
    k = CameraModel(baseline_m=fb / CAMERA.fx_px).intrinsics
    cfg = DepthCameraConfig(max_range_m=max_range_m)
    assert cfg.range_m(k) == pytest.approx(expected_m, rel=1e-9)
    z = 0.05 * fb / 0.08
    assert cfg.depth_sigma_m(z, k) / z == pytest.approx(0.05, rel=1e-9)


def test_far_returns_are_free_only_when_trusted_large_and_outside_the_blind_band():
    """15 m (3 sigma = 0.75 m: trusted) is +inf right of the blind band, NaN inside it;
    10.2 m (10.2 - 3 sigma < 10 m: not trusted) and a small far island are NaN."""
    source = DepthCameraSource(DepthCameraConfig(min_range_m=1.0))
    band = source.config.blind_band_px(K)
    assert band == math.ceil(FB / 1.0) == 72
    depth = np.full(SHAPE, 15_000)
    depth[:40, :] = 10_200
    depth[100:104, 300:304] = 3000  # a near block
    depth[200:203, 150:153] = 0  # a hole
    dm = source.compute(_d16(depth))
    far = dm.depth_m[40:, band:]
    assert np.isinf(far[(far != 3.0) & ~np.isnan(far)]).all()
    assert np.isinf(dm.depth_m[60:90, band:]).all()
    assert np.isnan(dm.depth_m[:, :band]).all()
    assert np.isnan(dm.depth_m[:40]).all()
    assert (dm.disparity_fixed[:40] == math.floor(DISP_SCALE * FB / 10.2)).all()
    island = np.full(SHAPE, 0)
    island[100:110, 200:210] = 15_000  # 100 px < 1 % of 76 800
    dm = source.compute(_d16(island))
    assert not np.isinf(dm.depth_m).any()
    assert dm.counts.n_unmatched == island.size


def test_depth32f_reads_like_depth16():
    rng = np.random.default_rng(1)
    metres = rng.uniform(0.5, 9.0, SHAPE).astype(np.float32)
    metres[::7, ::5] = np.nan
    metres[3, 3] = 0.0
    f32 = DepthFrame(1, 2, K, metres, PixelEncoding.DEPTH32F, 1.0)
    mm = np.where(np.isnan(metres), 0, np.rint(metres * 1000.0))
    a, b = DepthCameraSource().compute(f32), DepthCameraSource().compute(_d16(mm))
    np.testing.assert_array_equal(np.isnan(a.depth_m), np.isnan(b.depth_m))
    known = np.isfinite(a.depth_m)
    np.testing.assert_allclose(a.depth_m[known], b.depth_m[known], atol=0.0005 + 1e-6)
    assert np.isnan(depth_plane_m(f32)[3, 3])


def test_a_stereo_pair_is_refused():
    image = np.zeros(SHAPE, np.uint8)
    with pytest.raises(ValueError, match="not a depth frame"):
        DepthCameraSource().compute(StereoFrame(0, 0, K, image, image))


def test_the_frame_encoding_picks_the_source_and_both_see_the_papers_sphere():
    """One StereoPerception, the sphere of the paper 4.5 m ahead (surface at 3 m): the pair
    goes through the matcher, the depth frame through the depth camera, no setting between
    them; both place the sphere within 0.1 m laterally and the nearest surface at 3 m."""
    sphere = Sphere((10.0, 0.0, -7.0), 1.5)
    pos = np.array([5.5, 0.0, -7.0])
    out = StereoCameraRenderer(CAMERA).render(World(spheres=(sphere,), ground=None), pos, np.eye(3))
    pair = StereoFrame(1, 1, K, out.left, out.right)
    plane = depth16_from_truth(out.depth_left_m, K, DepthNoiseParams(), seed=1)
    depth = decode(encode(DepthFrame(1, 1, K, plane, PixelEncoding.DEPTH16, 0.001, out.left)))
    perception = StereoPerception(PerceptionConfig(depth_camera=DepthCameraConfig(min_range_m=1.0)))
    matcher_calls = []
    compute = perception.source.compute
    perception.source.compute = lambda f: matcher_calls.append(f) or compute(f)
    for frame, via_matcher in ((pair, True), (depth, False)):
        matcher_calls.clear()
        result = perception.process(frame, pos, np.eye(3))
        assert bool(matcher_calls) == via_matcher
        assert len(result.obstacles) == 1, result.obstacles
        o = result.obstacles[0]
        np.testing.assert_allclose(o.center_ned_m[1:], [0.0, -7.0], atol=0.1)
        assert o.nearest_range_m == pytest.approx(3.0, abs=0.1)
        assert o.center_ned_m[0] >= 8.5 + o.raw_radius_m - 0.2  # behind the visible cap


# ---- plant-sim's camera model ---------------------------------------------------------


def test_noise_grows_with_z_squared():
    """On a wall at z the measured depth's spread is z^2 subpixel / (f b) within 10 %."""
    params = DepthNoiseParams(max_range_m=6.5, edge_hole_px=0, depth_scale_m=0.0001)
    for z in (2.0, 4.0, 6.0):
        truth = np.full(SHAPE, z)
        plane = depth16_from_truth(truth, K, params, seed=3).astype(float) * 0.0001
        seen = plane[:, 100:] > 0
        expected = z * z * 0.08 / FB
        assert np.std(plane[:, 100:][seen]) == pytest.approx(expected, rel=0.1), z
        assert np.mean(plane[:, 100:][seen]) == pytest.approx(z, abs=3 * expected / 100)


def test_holes_at_depth_edges_beyond_range_and_in_the_left_band():
    box = Box((6.0, 0.0, -7.0), (0.2, 2.0, 2.0))
    world = World(boxes=(box, Box((40.0, 0.0, -7.0), (0.2, 80.0, 80.0))), ground=None)
    truth = StereoCameraRenderer(CAMERA).render_depth(world, np.array([0.0, 0.0, -7.0]), np.eye(3))
    params = DepthNoiseParams()
    plane = depth16_from_truth(truth, K, params, seed=0)
    assert (plane[truth > params.max_range_m] == 0).all()  # the far wall at 40 m
    near = np.isfinite(truth) & (truth < 6.0)
    rows, cols = np.nonzero(near)
    assert (plane[rows.min() : rows.max() + 1, cols.min() - 1] == 0).all()  # its left edge
    assert (plane[rows.min() + 2 : rows.max() - 1, cols.min() + 2] > 0).all()  # inside it
    band = np.arange(320)[None, :] < FB / np.where(np.isfinite(truth), truth, np.inf)
    assert (plane[band] == 0).all()
    np.testing.assert_array_equal(plane, depth16_from_truth(truth, K, params, seed=0))


# ---- configuration ---------------------------------------------------------------------


def test_config_section_and_its_errors():
    cfg = config_from_dict({"perception": {"depth_camera": {"min_range_m": 0.5}}})
    assert cfg.perception.depth_camera == DepthCameraConfig(min_range_m=0.5)
    with pytest.raises(ConfigError, match=r"unknown key 'perception\.depth_camera\.min_range'"):
        config_from_dict({"perception": {"depth_camera": {"min_range": 0.5}}})
    # the key and the bound, declared once with the field
    with pytest.raises(
        ConfigError, match=r"^perception\.depth_camera\.min_range_m: must be a finite number > 0 m"
    ):
        config_from_dict({"perception": {"depth_camera": {"min_range_m": -1.0}}})
    with pytest.raises(ConfigError, match=r"^perception\.depth_camera\.max_range_m: must be above"):
        config_from_dict({"perception": {"depth_camera": {"max_range_m": 0.2}}})
    recorded = json.loads(json.dumps(config_to_dict(cfg)))  # as a recording keeps it
    assert config_from_dict(recorded).perception == cfg.perception
    with pytest.raises(ConfigError, match="free space it does not vouch for"):
        CompanionConfig(
            perception=PerceptionConfig(depth_camera=DepthCameraConfig(max_range_m=5.0))
        )


def test_any_camera_and_any_depth_keep_the_contract():
    """Random intrinsics (f from 5 to 5000 px, baselines from 1 cm to 1 m), sizes, depth
    scales and depths, DEPTH16 and DEPTH32F: the contract's invariants hold, nothing
    raises (a hostile or odd camera is a bad map at worst, never a crash)."""
    from test_depth_source import check_contract

    rng = np.random.default_rng(35)
    source = DepthCameraSource()
    for i in range(60):
        w, h = int(rng.integers(1, 90)), int(rng.integers(1, 70))
        f = float(10 ** rng.uniform(0.7, 3.7))
        k = CameraModel(width_px=w, height_px=h).intrinsics
        k = type(k)(w, h, f, f, w / 2, h / 2, float(10 ** rng.uniform(-2, 0)))
        if i % 2:
            scale = float(10 ** rng.uniform(-6, -1))
            plane = rng.integers(0, 65536, (h, w), dtype=np.uint16)
            frame = DepthFrame(i, i, k, plane, PixelEncoding.DEPTH16, scale)
        else:
            plane = (10 ** rng.uniform(-3, 3, (h, w))).astype(np.float32)
            plane[rng.random((h, w)) < 0.2] = np.nan
            frame = DepthFrame(i, i, k, plane, PixelEncoding.DEPTH32F, 1.0)
        dm = source.compute(decode(encode(frame)))
        check_contract(frame, dm, source.config.range_m(k))
        assert dm.blind_band_px == min(w, math.ceil(k.focal_baseline_m_px / 0.3))
