"""Camera-frame wire format: stereo pairs and depth frames round trip, exact layout, one clear
error for bad payloads, version 1 still read, and the version-1 decoder refuses version 2."""

from __future__ import annotations

import struct
import sys

import numpy as np
import pytest

from protocols.camera import CameraModel
from protocols.stereo_frame import (
    HEADER_SIZE,
    MAGIC,
    DepthFrame,
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
    assert HEADER_SIZE == 84
    assert payload[:4] == MAGIC
    assert struct.unpack_from("<HHQq", payload, 4) == (2, 84, 42, 1_234_567_890_123)
    assert struct.unpack_from("<IIBB2x", payload, 24) == (32, 24, PixelEncoding.MONO8, 0)
    fx, fy, cx, cy, baseline, scale = struct.unpack_from("<6d", payload, 36)
    cam = CameraModel(width_px=32, height_px=24)
    assert (fx, fy, cx, cy, baseline) == (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px, 0.2)
    assert scale == 0.0


GOOD = encode(_frame())

MALFORMED = {
    "empty": b"",
    "header only": GOOD[:HEADER_SIZE],
    "truncated header": GOOD[:40],
    "truncated plane": GOOD[:-1],
    "one byte too many": GOOD + b"\x00",
    "bad magic": b"XXXX" + GOOD[4:],
    "version 0": _patched(GOOD, "<H", 4, 0),
    "version 3": _patched(GOOD, "<H", 4, 3),
    "header size": _patched(GOOD, "<H", 6, 80),
    "version 1 header on a version 2 frame": _patched(GOOD, "<H", 4, 1),
    "flags on a pair": _patched(GOOD, "<B", 33, 1),
    "depth scale on a pair": _patched(GOOD, "<d", 76, 0.001),
    "negative capture time": _patched(GOOD, "<q", 16, -5),
    "width 0": _patched(GOOD, "<I", 24, 0),
    "height 0": _patched(GOOD, "<I", 28, 0),
    "width mismatch": _patched(GOOD, "<I", 24, 31),
    "huge width": _patched(GOOD, "<I", 24, 2**32 - 1),
    "unknown encoding": _patched(GOOD, "<B", 32, 9),
    "encoding 0": _patched(GOOD, "<B", 32, 0),
    "reserved": _patched(GOOD, "<B", 34, 1),
    "reserved 2": _patched(GOOD, "<B", 35, 1),
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
    with pytest.raises(FrameDecodeError, match="bad camera frame"):
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
        plane = frame.left if isinstance(frame, StereoFrame) else frame.depth
        assert plane.shape == (frame.intrinsics.height_px, frame.intrinsics.width_px)
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


# ---- depth frames ---------------------------------------------------------------------


def _depth16(width=32, height=24, left=True, scale=0.001) -> DepthFrame:
    rng = np.random.default_rng(3)
    cam = CameraModel(width_px=width, height_px=height)
    depth = rng.integers(0, 65536, (height, width), dtype=np.uint16)
    depth[0, :5] = 0  # no data
    image = rng.integers(0, 256, (height, width), dtype=np.uint8) if left else None
    return DepthFrame(7, 99, cam.intrinsics, depth, PixelEncoding.DEPTH16, scale, image)


def _depth32(width=32, height=24) -> DepthFrame:
    rng = np.random.default_rng(4)
    cam = CameraModel(width_px=width, height_px=height)
    depth = rng.uniform(0.1, 30.0, (height, width)).astype(np.float32)
    depth[1, 2] = np.nan
    depth[2, 3] = 0.0
    return DepthFrame(8, 100, cam.intrinsics, depth, PixelEncoding.DEPTH32F, 1.0)


@pytest.mark.parametrize("left", [True, False])
def test_depth16_round_trip_and_layout(left):
    frame = _depth16(left=left)
    payload = encode(frame)
    assert len(payload) == HEADER_SIZE + 32 * 24 * 2 + (32 * 24 if left else 0)
    assert struct.unpack_from("<BB", payload, 32) == (PixelEncoding.DEPTH16, int(left))
    assert struct.unpack_from("<d", payload, 76) == (0.001,)
    out = decode(payload)
    assert isinstance(out, DepthFrame)
    assert (out.sequence, out.capture_ns, out.encoding, out.depth_scale_m) == (
        7,
        99,
        PixelEncoding.DEPTH16,
        0.001,
    )
    assert out.intrinsics == frame.intrinsics
    np.testing.assert_array_equal(out.depth, frame.depth)
    assert out.depth.dtype == np.uint16 and not out.depth.flags.writeable
    # the depth plane is little-endian on the wire: its first value is the first two bytes
    assert struct.unpack_from("<H", payload, HEADER_SIZE)[0] == frame.depth[0, 0]
    if left:
        np.testing.assert_array_equal(out.left, frame.left)
        assert not out.left.flags.writeable
    else:
        assert out.left is None


def test_depth32f_round_trip_keeps_nan_and_zero():
    frame = _depth32()
    out = decode(encode(frame))
    assert isinstance(out, DepthFrame) and out.encoding is PixelEncoding.DEPTH32F
    assert out.depth.dtype == np.float32 and out.depth_scale_m == 1.0
    np.testing.assert_array_equal(out.depth, frame.depth)  # NaN == NaN for this assert
    assert np.isnan(out.depth[1, 2]) and out.depth[2, 3] == 0.0


GOOD_D16 = encode(_depth16())
GOOD_D32 = encode(_depth32())


def _with_value(payload: bytes, value: float, index: int = 0) -> bytes:
    return _patched(payload, "<f", HEADER_SIZE + 4 * index, value)


MALFORMED_DEPTH = {
    "depth16 scale zero": _patched(GOOD_D16, "<d", 76, 0.0),
    "depth16 scale negative": _patched(GOOD_D16, "<d", 76, -0.001),
    "depth16 scale nan": _patched(GOOD_D16, "<d", 76, float("nan")),
    "depth16 scale inf": _patched(GOOD_D16, "<d", 76, float("inf")),
    "depth16 scale too large": _patched(GOOD_D16, "<d", 76, 1.0),
    "depth16 scale too small": _patched(GOOD_D16, "<d", 76, 1e-9),
    "depth16 left flag without the image": GOOD_D16[: -32 * 24],
    "depth16 image without the flag": _patched(GOOD_D16, "<B", 33, 0),
    "depth16 unknown flag": _patched(GOOD_D16, "<B", 33, 3),
    "depth16 truncated": GOOD_D16[:-1],
    "depth16 one byte too many": GOOD_D16 + b"\x00",
    "depth16 as version 1": _patched(GOOD_D16[:76] + GOOD_D16[84:], "<H", 4, 1),
    "depth32f scale 0.001": _patched(GOOD_D32, "<d", 76, 0.001),
    "depth32f +inf": _with_value(GOOD_D32, float("inf")),
    "depth32f -inf": _with_value(GOOD_D32, float("-inf"), 5),
    "depth32f negative": _with_value(GOOD_D32, -1.0, 31),
    "depth32f tiny negative": _with_value(GOOD_D32, -1e-30, 100),
    "depth32f odd byte count": GOOD_D32[:-2],
    "depth32f as depth16 bytes": _patched(GOOD_D32, "<B", 32, PixelEncoding.DEPTH16),
}


@pytest.mark.parametrize("name", sorted(MALFORMED_DEPTH))
def test_malformed_depth_frames_raise_the_clear_error(name):
    with pytest.raises(FrameDecodeError, match="bad camera frame"):
        decode(MALFORMED_DEPTH[name])


def test_depth32f_error_names_the_value_and_pixel():
    with pytest.raises(FrameDecodeError, match=r"first -1\.0 at \(x=31, y=0\)"):
        decode(_with_value(GOOD_D32, -1.0, 31))


def test_encode_rejects_inconsistent_depth_frames():
    frame = _depth16()
    k = frame.intrinsics
    with pytest.raises(ValueError, match="depth plane"):
        encode(DepthFrame(1, 0, k, frame.depth.astype(np.float32), PixelEncoding.DEPTH16))
    with pytest.raises(ValueError, match="left plane"):
        encode(DepthFrame(1, 0, k, frame.depth, PixelEncoding.DEPTH16, 0.001, frame.left[:-1]))
    with pytest.raises(ValueError, match="depth_scale_m"):
        encode(DepthFrame(1, 0, k, frame.depth, PixelEncoding.DEPTH16, 0.0))
    with pytest.raises(ValueError, match="MONO8"):
        encode(DepthFrame(1, 0, k, frame.left, PixelEncoding.MONO8))
    bad = _depth32().depth.copy()
    bad[0, 0] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        encode(DepthFrame(1, 0, k, bad, PixelEncoding.DEPTH32F, 1.0))


def test_fuzz_mutated_depth_payloads_only_raise_frame_decode_error():
    rng = np.random.default_rng(11)
    seeds = [encode(_depth16(4, 3)), encode(_depth16(4, 3, left=False)), encode(_depth32(4, 3))]
    decoded = 0
    for i in range(3000):
        buf = bytearray(seeds[i % 3])
        for _ in range(int(rng.integers(1, 4))):
            buf[int(rng.integers(0, len(buf)))] = int(rng.integers(0, 256))
        try:
            frame = decode(bytes(buf))
        except FrameDecodeError:
            continue
        decoded += 1
        if isinstance(frame, DepthFrame) and frame.encoding is PixelEncoding.DEPTH32F:
            assert not np.any(np.isinf(frame.depth)) and not np.any(frame.depth < 0)
    assert decoded > 0


def test_version_1_pairs_are_still_read():
    """A recording or an old camera sends the 76-byte version-1 header: read as before."""
    frame = _frame()
    v2 = encode(frame)
    v1 = bytearray(v2[:33] + b"\x00\x00\x00" + v2[36:76] + v2[84:])
    struct.pack_into("<HH", v1, 4, 1, 76)
    out = decode(bytes(v1))
    assert isinstance(out, StereoFrame) and out.intrinsics == frame.intrinsics
    np.testing.assert_array_equal(out.right, frame.right)


def _main_decoder(tmp_path, monkeypatch):
    """The version-1 decoder as it was on main before depth frames (git a6ae43e)."""
    import importlib
    import pathlib
    import subprocess

    root = pathlib.Path(__file__).resolve().parents[1]
    try:
        source = subprocess.run(
            ["git", "-C", str(root), "show", "a6ae43e:protocols/stereo_frame.py"],
            capture_output=True,
            text=True,
            check=True,
            timeout=30,
        ).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.fail(f"cannot read the version-1 decoder from git: {exc}")
    (tmp_path / "stereo_frame_v1.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    return importlib.import_module("stereo_frame_v1")


@pytest.mark.parametrize("payload", [GOOD, GOOD_D16, GOOD_D32], ids=["pair", "d16", "d32"])
def test_a_version_1_peer_refuses_version_2_with_a_clear_error(payload, tmp_path, monkeypatch):
    monkeypatch.delitem(sys.modules, "stereo_frame_v1", raising=False)
    old = _main_decoder(tmp_path, monkeypatch)
    with pytest.raises(old.FrameDecodeError, match="unsupported version 2"):
        old.decode(payload)
