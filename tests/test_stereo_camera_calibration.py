"""Stereo calibration files and rectification: round trip on a known rig, row alignment, errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.camera.calibration import (
    CalibrationError,
    Rectifier,
    StereoCalibration,
    load_calibration,
)

SIZE = (640, 480)  # (width, height) of each raw eye
K1 = np.array([[400.0, 0.0, 319.5], [0.0, 401.0, 239.5], [0.0, 0.0, 1.0]])
K2 = np.array([[405.0, 0.0, 322.0], [0.0, 404.0, 236.0], [0.0, 0.0, 1.0]])
D1 = np.array([-0.08, 0.02, 0.001, -0.0005, 0.0])
D2 = np.array([-0.06, 0.015, -0.0008, 0.0004, 0.0])
R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]  # right camera slightly rotated
T = np.array([-0.12, 0.002, -0.001])  # right camera 12 cm to the right [m]
BASELINE_M = float(np.linalg.norm(T))


def write_calibration(path, keys=("K1", "D1", "K2", "D2", "R", "T"), T_value=T, size=SIZE):
    """Write the known rig with cv2.FileStorage (aliases: pass e.g. 'M1' for 'K1')."""
    values = {"K1": K1, "M1": K1, "D1": D1, "K2": K2, "M2": K2, "D2": D2, "R": R, "T": T_value}
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key in keys:
        value = np.asarray(values[key], dtype=np.float64)
        fs.write(key, value.reshape(-1, 1) if value.ndim == 1 else value)  # vectors as columns
    if size is not None:
        fs.write("image_width", size[0])
        fs.write("image_height", size[1])
    fs.release()
    return path


def _blob_image(points_px: np.ndarray, sigma_px: float = 2.5) -> np.ndarray:
    """Gaussian dots at sub-pixel positions on black, uint8 (W, H = SIZE)."""
    v, u = np.mgrid[0 : SIZE[1], 0 : SIZE[0]].astype(np.float64)
    image = np.zeros(u.shape)
    for x, y in points_px:
        image += np.exp(-((u - x) ** 2 + (v - y) ** 2) / (2 * sigma_px**2))
    return np.clip(image * 250.0, 0, 255).astype(np.uint8)


def _centroid(image: np.ndarray, near_px, half_px: int = 7) -> np.ndarray:
    x0, y0 = (round(c) for c in near_px)
    win = image[y0 - half_px : y0 + half_px + 1, x0 - half_px : x0 + half_px + 1].astype(float)
    win = np.clip(win - 10.0, 0.0, None)  # ignore interpolation fringe
    v, u = np.mgrid[-half_px : half_px + 1, -half_px : half_px + 1]
    return np.array([x0 + (u * win).sum() / win.sum(), y0 + (v * win).sum() / win.sum()])


def _write_bytes(path, data: bytes):
    path.write_bytes(data)
    return path


@pytest.fixture(params=["yaml", "xml", "split_m_aliases"])
def calibration_files(request, tmp_path):
    if request.param == "yaml":
        return [write_calibration(tmp_path / "stereo.yml")]
    if request.param == "xml":
        return [write_calibration(tmp_path / "stereo.xml")]
    # OpenCV's stereo_calib sample: intrinsics.yml (M1 D1 M2 D2) + extrinsics.yml (R T)
    return [
        write_calibration(tmp_path / "intrinsics.yml", ("M1", "D1", "M2", "D2")),
        write_calibration(tmp_path / "extrinsics.yml", ("R", "T"), size=None),
    ]


def test_load_round_trip(calibration_files):
    calib = load_calibration(calibration_files)
    np.testing.assert_allclose(calib.K1, K1, err_msg="K1")
    np.testing.assert_allclose(calib.K2, K2, err_msg="K2")
    np.testing.assert_allclose(calib.D1, D1, err_msg="D1")
    np.testing.assert_allclose(calib.D2, D2, err_msg="D2")
    np.testing.assert_allclose(calib.R, R, err_msg="R")
    np.testing.assert_allclose(calib.T_m, T, err_msg="T")
    assert calib.image_size_px == SIZE
    assert calib.baseline_m == pytest.approx(BASELINE_M, rel=1e-12)


@pytest.mark.parametrize("output_size", [None, (320, 240)])
def test_rectified_intrinsics_and_rows_align(tmp_path, output_size):
    """Known 3-D points → raw distorted images → rectify: rows agree, depth = f·b/d."""
    rect = Rectifier(
        load_calibration(write_calibration(tmp_path / "s.yml")), SIZE, 0.0, output_size
    )
    k = rect.intrinsics
    out_w, out_h = output_size or SIZE
    assert (k.width_px, k.height_px) == (out_w, out_h)
    assert k.baseline_m == pytest.approx(BASELINE_M, rel=1e-9)  # rotation keeps |T|
    assert k.fx_px == pytest.approx(k.fy_px)  # stereoRectify makes square pixels
    assert 0 < k.cx_px < out_w and 0 < k.cy_px < out_h
    assert rect.P2[0, 2] == pytest.approx(k.cx_px)  # CALIB_ZERO_DISPARITY: same cx both eyes

    # points in the left camera frame, spread over the view, 2–6 m away
    X = np.array(
        [
            [x * z / 4, y * z / 4, z]
            for z, (x, y) in zip(
                [2.0, 3.0, 4.0, 6.0, 2.5, 5.0],
                [(-1.5, -1.0), (1.0, -0.8), (0.0, 0.0), (-0.8, 0.9), (1.4, 1.0), (0.6, 0.4)],
                strict=True,
            )
        ]
    )
    left_px = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K1, D1)[0].reshape(-1, 2)
    right_px = cv2.projectPoints(X, cv2.Rodrigues(R)[0], T, K2, D2)[0].reshape(-1, 2)
    left, right = rect.rectify(_blob_image(left_px), _blob_image(right_px))
    assert left.dtype == np.uint8 and left.shape == (out_h, out_w)

    X_rect = X @ rect.R1.T  # the rectified left camera frame
    for i, p in enumerate(X_rect):
        expect_left = np.array([k.fx_px * p[0] / p[2] + k.cx_px, k.fy_px * p[1] / p[2] + k.cy_px])
        disparity_px = k.fx_px * k.baseline_m / p[2]  # Eq. (26)
        got_left = _centroid(left, expect_left)
        got_right = _centroid(right, expect_left - (disparity_px, 0.0))
        np.testing.assert_allclose(got_left, expect_left, atol=0.25, err_msg=f"point {i} left")
        assert abs(got_left[1] - got_right[1]) < 0.2, (i, got_left, got_right)  # same row
        depth_m = k.fx_px * k.baseline_m / (got_left[0] - got_right[0])  # Eq. (27)
        assert depth_m == pytest.approx(p[2], rel=0.02), i


def test_image_size_taken_from_frames_when_file_omits_it(tmp_path):
    calib = load_calibration(write_calibration(tmp_path / "s.yml", size=None))
    assert calib.image_size_px is None
    with pytest.raises(CalibrationError, match="image size unknown"):
        Rectifier(calib)
    assert Rectifier(calib, SIZE).intrinsics.width_px == SIZE[0]


def test_units_mm(tmp_path):
    path = write_calibration(tmp_path / "mm.yml", T_value=T * 1000.0)
    with pytest.raises(CalibrationError, match=r"implausible.*mm"):
        load_calibration(path)
    assert load_calibration(path, units="mm").baseline_m == pytest.approx(BASELINE_M)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda p: p / "nope.yml", "does not exist"),
        (
            lambda p: _write_bytes(p / "junk.yml", b"\x00\x01garbage{["),
            "cannot be opened|not OpenCV",
        ),
        (lambda p: _write_bytes(p / "empty.xml", b""), "cannot be opened|not OpenCV|missing"),
        (lambda p: write_calibration(p / "noT.yml", ("K1", "D1", "K2", "D2", "R")), "missing T"),
        (lambda p: write_calibration(p / "swap.yml", T_value=-T), "swap the left and right"),
    ],
    ids=["missing", "garbage", "empty", "missing_key", "swapped_eyes"],
)
def test_bad_files_raise_clear_errors(tmp_path, make, match):
    with pytest.raises(CalibrationError, match=match) as info:
        load_calibration(make(tmp_path))
    assert "\n" not in str(info.value)


def test_invalid_geometry_is_refused():
    good = dict(K1=K1, D1=D1, K2=K2, D2=D2, R=R, T_m=T)
    with pytest.raises(CalibrationError, match="not a rotation"):
        StereoCalibration(**{**good, "R": R * 1.1})
    with pytest.raises(CalibrationError, match="not a horizontal rig"):
        StereoCalibration(**{**good, "T_m": np.array([-0.01, 0.12, 0.0])})
    with pytest.raises(CalibrationError, match="K1 is not a camera matrix"):
        StereoCalibration(**{**good, "K1": -K1})
    with pytest.raises(CalibrationError, match="D2 must hold"):
        StereoCalibration(**{**good, "D2": np.zeros(3)})


def test_size_mismatch_with_calibration(tmp_path):
    calib = load_calibration(write_calibration(tmp_path / "s.yml"))
    with pytest.raises(CalibrationError, match="calibrated for 640x480 but the images are 320x240"):
        Rectifier(calib, (320, 240))
    rect = Rectifier(calib)
    with pytest.raises(ValueError, match="expects 640x480"):
        rect.rectify(np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8))
