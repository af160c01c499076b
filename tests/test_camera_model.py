"""Camera model: Table 1, Eq. (24)–(27) and the camera ↔ body ↔ NED transforms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocols.camera import (
    R_FRD_FROM_CAM,
    CameraModel,
    StereoIntrinsics,
    backproject_px,
    depth_from_disparity,
    disparity_from_depth,
    points_cam_from_ned,
    points_frd_from_cam,
    points_ned_from_cam,
    project_cam,
)
from protocols.frames import rotation_321

# Paper Table 1 as printed (disparities 11–14 are elided with "…" in the paper).
TABLE_1 = {
    1: 71.87, 2: 35.94, 3: 23.96, 4: 17.97, 5: 14.37, 6: 11.98, 7: 10.27, 8: 8.98,
    9: 7.99, 10: 7.19, 15: 4.79, 16: 4.49, 17: 4.23, 18: 3.99, 19: 3.78, 20: 3.59,
    21: 3.42, 22: 3.27, 23: 3.12, 24: 3.00, 25: 2.87, 26: 2.76, 27: 2.66, 28: 2.57,
    29: 2.48, 30: 2.40, 31: 2.32,
}  # fmt: skip


@pytest.fixture
def paper_camera() -> CameraModel:
    return CameraModel()


def test_focal_length_from_fov(paper_camera):
    assert paper_camera.fx_px == pytest.approx(160.0 / math.tan(math.radians(24.0)))
    assert paper_camera.fx_px == pytest.approx(359.37, abs=0.01)
    assert paper_camera.intrinsics.focal_baseline_m_px == pytest.approx(71.87, abs=0.005)
    assert (paper_camera.cx_px, paper_camera.cy_px) == (159.5, 119.5)


@pytest.mark.parametrize("disparity_px", sorted(TABLE_1))
def test_table_1(paper_camera, disparity_px):
    depth_m = float(depth_from_disparity(disparity_px, paper_camera.intrinsics))
    if disparity_px == 24:
        # Misprint in the paper: f·b/24 = 71.873/24 = 2.9947 m, i.e. 2.99, not 3.00. No single
        # f·b and rounding rule gives both 71.87 at d = 1 (f·b < 71.875) and 3.00 at d = 24
        # (f·b >= 71.88); half-up, floor, ceil and double rounding all fail here or elsewhere.
        assert round(depth_m, 2) == 2.99
        assert depth_m == pytest.approx(TABLE_1[24], abs=0.006)
    else:
        assert round(depth_m, 2) == TABLE_1[disparity_px], f"d = {disparity_px}: {depth_m:.4f}"


def test_threshold_4m_means_disparity_18_and_up(paper_camera):
    """§5: with a 4 m threshold the pixels with disparity 18..31 are obstacles."""
    d = np.arange(1, 32)
    depth = depth_from_disparity(d, paper_camera.intrinsics)
    assert list(d[depth < 4.0]) == list(range(18, 32))


def test_disparity_depth_inverse_and_invalid(paper_camera):
    k = paper_camera.intrinsics
    depths = np.array([0.5, 1.0, 3.7, 40.0])
    np.testing.assert_allclose(depth_from_disparity(disparity_from_depth(depths, k), k), depths)
    assert np.all(np.isinf(depth_from_disparity(np.array([0.0, -1.0, -16.0]), k)))


def test_stereo_projection_eq_24_to_26(paper_camera):
    """Project one NED point through both eyes: u_L − u_R = f·b / z, v_L = v_R."""
    k = paper_camera.intrinsics
    pos = np.array([3.0, -2.0, -7.0])
    R = rotation_321(0.1, -0.2, 0.7)
    point_ned = pos + R @ np.array([5.0, 0.4, -0.3])
    p_left = points_cam_from_ned(point_ned, pos, R, k.baseline_m, "left")
    p_right = points_cam_from_ned(point_ned, pos, R, k.baseline_m, "right")
    assert p_left[2] == pytest.approx(p_right[2])
    u_l, v_l = project_cam(p_left, k)
    u_r, v_r = project_cam(p_right, k)
    assert u_l - u_r == pytest.approx(k.focal_baseline_m_px / p_left[2])
    assert v_l == pytest.approx(v_r)


def test_camera_axes_in_body_frame():
    """Optical z is body forward, optical x body right, optical y body down; left eye at −b/2."""
    np.testing.assert_allclose(R_FRD_FROM_CAM @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_allclose(R_FRD_FROM_CAM @ [1, 0, 0], [0, 1, 0])
    np.testing.assert_allclose(R_FRD_FROM_CAM @ [0, 1, 0], [0, 0, 1])
    np.testing.assert_allclose(points_frd_from_cam([0, 0, 5.0], 0.2, "left"), [5.0, -0.1, 0.0])
    np.testing.assert_allclose(points_frd_from_cam([0, 0, 5.0], 0.2, "right"), [5.0, 0.1, 0.0])


def test_camera_to_ned_with_yaw_and_pitch():
    """Facing east (yaw 90°) and nose up 30°: a point 10 m ahead is east and above."""
    pos = np.array([1.0, 2.0, -7.0])
    R = rotation_321(0.0, math.radians(30.0), math.radians(90.0))
    p = points_ned_from_cam([0.0, 0.0, 10.0], pos, R, 0.0)
    np.testing.assert_allclose(
        p, pos + np.array([0.0, 10 * math.cos(math.radians(30)), -5.0]), atol=1e-12
    )
    # Image right (optical +x) is south when facing east.
    p_right = points_ned_from_cam([1.0, 0.0, 0.0], pos, R, 0.0)
    np.testing.assert_allclose(p_right, pos + np.array([-1.0, 0.0, 0.0]), atol=1e-12)


def test_cam_ned_round_trip():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50, 3)) * 5
    for _ in range(10):
        pos = rng.normal(size=3) * 10
        R = rotation_321(*rng.uniform(-1, 1, size=3))
        for eye in ("left", "right"):
            ned = points_ned_from_cam(points, pos, R, 0.2, eye)
            np.testing.assert_allclose(points_cam_from_ned(ned, pos, R, 0.2, eye), points)


def test_backproject_project_round_trip(paper_camera):
    k = paper_camera.intrinsics
    u, v = np.meshgrid(np.arange(0, 320, 37.0), np.arange(0, 240, 29.0))
    pts = backproject_px(u, v, 4.2, k)
    u2, v2 = project_cam(pts, k)
    np.testing.assert_allclose(u2, u)
    np.testing.assert_allclose(v2, v)
    np.testing.assert_allclose(pts[..., 2], 4.2)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"width_px": 0},
        {"height_px": -3},
        {"hfov_deg": 0.0},
        {"vfov_deg": 180.0},
        {"hfov_deg": float("nan")},
        {"baseline_m": 0.0},
        {"baseline_m": float("inf")},
    ],
)
def test_camera_model_rejects_bad_values(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        CameraModel(**kwargs)


def test_intrinsics_reject_bad_values():
    good = CameraModel().intrinsics
    for name, bad in (("fx_px", -1.0), ("fy_px", float("nan")), ("cx_px", float("inf"))):
        values = {**good.__dict__, name: bad}
        with pytest.raises(ValueError, match=name):
            StereoIntrinsics(**values)


@pytest.mark.parametrize(("width", "hfov"), [(320, 48.0), (640, 48.0), (640, 90.0), (1280, 72.5)])
def test_intrinsics_hfov_inverts_the_camera_model(width, hfov):
    """The model's HFOV is the one it was built with, at every resolution."""
    cam = CameraModel(width_px=width, height_px=width * 3 // 4, hfov_deg=hfov)
    assert cam.intrinsics.hfov_deg == pytest.approx(hfov, abs=1e-9)
