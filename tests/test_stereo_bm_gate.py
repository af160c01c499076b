"""The padded StereoBM's edge and band gate (companion.stereo_bm._gate) against the OpenCV
composition it replaces: 3x3 Sobel magnitudes (``cv2.spatialGradient``, saturated by
``cv2.convertScaleAbs``) averaged over the block (``cv2.blur``), a pixel refused where the
horizontal average scaled by ``1 / ratio`` is below the vertical one; and the band rule."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from companion.stereo_bm import _edge_table, _gate

_BAND_MARGIN_PX = 6


def _reference_gate(disp, image, block, ratio, band_limit):
    """The gate as OpenCV calls (the implementation before the compiled kernel)."""
    out = disp.copy()
    if ratio > 0.0:
        dx, dy = cv2.spatialGradient(image)
        ax = cv2.blur(cv2.convertScaleAbs(dx), (block, block))
        ay = cv2.blur(cv2.convertScaleAbs(dy), (block, block))
        scaled = cv2.convertScaleAbs(np.arange(256, dtype=np.uint8).reshape(1, -1), alpha=1 / ratio)
        out[scaled.reshape(-1)[ax] < ay] = -16
    n_band = min(band_limit.shape[0], disp.shape[1])
    band = out[:, :n_band]
    band[band > band_limit[:n_band]] = -16
    return out


def _image(rng, shape, kind):
    if kind == "noise":
        return rng.integers(0, 256, shape, dtype=np.uint8)
    if kind == "stripes":  # near-horizontal edges: the case the gate exists for
        rows = (np.arange(shape[0])[:, None] + 0.05 * np.arange(shape[1])[None, :]) // 3
        return ((rows % 2) * 200 + rng.integers(0, 20, shape)).astype(np.uint8)
    return cv2.GaussianBlur(rng.integers(0, 256, shape, dtype=np.uint8), (0, 0), 1.5)


@pytest.mark.parametrize("shape", [(240, 320), (61, 83), (9, 9), (4, 7), (1, 1), (1, 12), (12, 1)])
@pytest.mark.parametrize("block", [5, 9, 15])
def test_gate_equals_the_opencv_composition_bit_for_bit(shape, block):
    rng = np.random.default_rng([block, *shape])
    band_limit = (16 * (np.arange(block // 2 + 2 + 48) - _BAND_MARGIN_PX)).astype(np.int16)
    for kind in ("noise", "stripes", "smooth"):
        image = _image(rng, shape, kind)
        for ratio in (0.0, 0.1, 0.5, 0.95):
            disp = rng.integers(-16, 64 * 16, shape).astype(np.int16)
            expected = _reference_gate(disp, image, block, ratio, band_limit)
            table = _edge_table(ratio, block) if ratio > 0.0 else np.zeros(0, np.int32)
            _gate(disp, image, block, table, band_limit)
            np.testing.assert_array_equal(
                disp, expected, err_msg=f"{kind} {shape} block {block} ratio {ratio}"
            )


def test_gate_refuses_near_horizontal_edges_and_keeps_vertical_ones():
    """The invariant behind the numbers: on horizontal stripes every match is refused, on
    vertical stripes every match is kept (no band)."""
    stripes = np.where((np.arange(80) // 4) % 2 == 0, 220, 30).astype(np.uint8)
    horizontal = np.ascontiguousarray(np.repeat(stripes[:60, None], 80, axis=1))
    vertical = np.ascontiguousarray(np.repeat(stripes[None, :], 60, axis=0))
    table = _edge_table(0.1, 9)
    for image, kept in ((horizontal, 0), (vertical, 160)):
        disp = np.full(image.shape, 160, np.int16)
        _gate(disp, image, 9, table, np.zeros(0, np.int16))
        assert np.all(disp == (kept if kept else -16)), image[:3, :6]
