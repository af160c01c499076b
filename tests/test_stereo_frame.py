"""Stereo-frame wire format: round trip, exact layout, and one clear error for bad payloads."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from protocols.camera import CameraModel
from protocols.stereo_frame import (
    HEADER_SIZE,
    MAGIC,
    FrameDecodeError,
    PixelEncoding,
    StereoFrame,
    decode,
    encode,
    validate,
)


def _frame(width: int = 32, height: int = 24, seed: int = 0) -> StereoFrame:
    rng = np.random.default_rng(seed)
    cam = CameraModel(width_px=width, height_px=height)
    return StereoFrame(
        sequence=42,
        capture_ns=1_234_567_890_123,
        intrinsics=cam.intrinsics,
        left=rng.integers(0, 256, (height, width), dtype=np.uint8),
        right=rng.integers(0, 256, (height, width), dtype=np.uint8),
    )


def _patched(payload: bytes, fmt: str, offset: int, value) -> bytes:
    buf = bytearray(payload)
    struct.pack_into(fmt, buf, offset, value)
    return bytes(buf)


def test_round_trip():
    frame = _frame()
    payload = encode(frame)
    assert len(payload) == HEADER_SIZE + 2 * 32 * 24
    out = decode(payload)
    assert (out.sequence, out.capture_ns, out.encoding) == (
        42,
        1_234_567_890_123,
        PixelEncoding.MONO8,
    )
    assert out.intrinsics == frame.intrinsics
    np.testing.assert_array_equal(out.left, frame.left)
    np.testing.assert_array_equal(out.right, frame.right)
    assert not out.left.flags.writeable
    assert decode(bytearray(payload)).sequence == 42
    assert decode(memoryview(payload)).sequence == 42
    validate(payload)


def test_header_layout_is_little_endian_and_documented():
    payload = encode(_frame())
    assert HEADER_SIZE == 76
    assert payload[:4] == MAGIC
    assert struct.unpack_from("<HHQq", payload, 4) == (1, 76, 42, 1_234_567_890_123)
    assert struct.unpack_from("<IIB3x", payload, 24) == (32, 24, PixelEncoding.MONO8)
    fx, fy, cx, cy, baseline = struct.unpack_from("<5d", payload, 36)
    cam = CameraModel(width_px=32, height_px=24)
    assert (fx, fy, cx, cy, baseline) == (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px, 0.2)


GOOD = encode(_frame())

MALFORMED = {
    "empty": b"",
    "header only": GOOD[:HEADER_SIZE],
    "truncated header": GOOD[:40],
    "truncated plane": GOOD[:-1],
    "one byte too many": GOOD + b"\x00",
    "bad magic": b"XXXX" + GOOD[4:],
    "version 0": _patched(GOOD, "<H", 4, 0),
    "version 2": _patched(GOOD, "<H", 4, 2),
    "header size": _patched(GOOD, "<H", 6, 80),
    "negative capture time": _patched(GOOD, "<q", 16, -5),
    "width 0": _patched(GOOD, "<I", 24, 0),
    "height 0": _patched(GOOD, "<I", 28, 0),
    "width mismatch": _patched(GOOD, "<I", 24, 31),
    "huge width": _patched(GOOD, "<I", 24, 2**32 - 1),
    "unknown encoding": _patched(GOOD, "<B", 32, 9),
    "encoding 0": _patched(GOOD, "<B", 32, 0),
    "reserved": _patched(GOOD, "<B", 34, 1),
    "fx nan": _patched(GOOD, "<d", 36, float("nan")),
    "fx negative": _patched(GOOD, "<d", 36, -359.0),
    "fx zero": _patched(GOOD, "<d", 36, 0.0),
    "fy inf": _patched(GOOD, "<d", 44, float("inf")),
    "cx nan": _patched(GOOD, "<d", 52, float("nan")),
    "cx far outside": _patched(GOOD, "<d", 52, 1e9),
    "cy -inf": _patched(GOOD, "<d", 60, float("-inf")),
    "baseline negative": _patched(GOOD, "<d", 68, -0.2),
    "baseline nan": _patched(GOOD, "<d", 68, float("nan")),
}


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_malformed_frames_raise_the_clear_error(name):
    with pytest.raises(FrameDecodeError, match="bad stereo frame"):
        decode(MALFORMED[name])
    assert issubclass(FrameDecodeError, ValueError)


@pytest.mark.parametrize("payload", [None, "text", 12, [1, 2, 3], np.zeros((2, 2))[:, 0]])
def test_non_bytes_payloads(payload):
    with pytest.raises(FrameDecodeError):
        decode(payload)


def test_fuzz_random_and_mutated_payloads_only_raise_frame_decode_error():
    rng = np.random.default_rng(7)
    small = encode(_frame(width=4, height=3))
    decoded = 0
    for i in range(3000):
        if i % 3 == 0:
            payload = rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes()
        elif i % 3 == 1:
            buf = bytearray(small)
            for _ in range(int(rng.integers(1, 4))):
                buf[int(rng.integers(0, HEADER_SIZE))] = int(rng.integers(0, 256))
            payload = bytes(buf)
        else:
            payload = small[: int(rng.integers(0, len(small) + 1))]
            payload += rng.integers(0, 256, int(rng.integers(0, 3)), dtype=np.uint8).tobytes()
        try:
            frame = decode(payload)
        except FrameDecodeError:
            continue
        decoded += 1
        assert frame.left.shape == (frame.intrinsics.height_px, frame.intrinsics.width_px)
    assert decoded > 0  # some mutations hit only the sequence/time fields and stay valid


def test_encode_rejects_inconsistent_frames():
    frame = _frame()
    bad_shape = StereoFrame(1, 0, frame.intrinsics, frame.left[:, :-1], frame.right)
    with pytest.raises(ValueError, match="left plane"):
        encode(bad_shape)
    bad_dtype = StereoFrame(1, 0, frame.intrinsics, frame.left, frame.right.astype(np.uint16))
    with pytest.raises(ValueError, match="right plane"):
        encode(bad_dtype)
    with pytest.raises(ValueError, match="capture_ns"):
        encode(StereoFrame(1, -1, frame.intrinsics, frame.left, frame.right))
