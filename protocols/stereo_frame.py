"""Stereo-frame wire format for Zenoh: versioned little-endian header + left and right planes.

Layout (version 1, all little-endian, ``HEADER_SIZE`` = 76 bytes)::

    offset size  field
     0      4    magic            b"SAVF"
     4      2    version          u16, = 1
     6      2    header_size      u16, = 76 (bytes before the first plane)
     8      8    sequence         u64
    16      8    capture_ns       i64, >= 0, capture time on the shared clock (DESIGN.md)
    24      4    width_px         u32, 1..8192
    28      4    height_px        u32, 1..8192
    32      1    encoding         u8, PixelEncoding
    33      3    reserved         zero
    36      8    fx_px            f64, finite > 0
    44      8    fy_px            f64, finite > 0
    52      8    cx_px            f64, finite, within [-W, 2W]
    60      8    cy_px            f64, finite, within [-H, 2H]
    68      8    baseline_m       f64, finite > 0
    76     W·H·bpp  left plane (reference image), row-major
    ...    W·H·bpp  right plane

:func:`decode` checks every field and the exact byte count and raises
:class:`FrameDecodeError` (a ``ValueError``) with the reason; it raises nothing else on
arbitrary bytes.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = [
    "FORMAT_VERSION",
    "HEADER_SIZE",
    "MAGIC",
    "MAX_DIMENSION_PX",
    "FrameDecodeError",
    "PixelEncoding",
    "StereoFrame",
    "decode",
    "encode",
    "validate",
]

MAGIC = b"SAVF"
FORMAT_VERSION = 1
MAX_DIMENSION_PX = 8192
_HEADER = struct.Struct("<4sHHQqIIB3s5d")
HEADER_SIZE = _HEADER.size


class FrameDecodeError(ValueError):
    """A stereo-frame payload is malformed; the message says which field and why."""


class PixelEncoding(enum.IntEnum):
    """Pixel encoding of both planes."""

    MONO8 = 1  # 8-bit grayscale, one byte per pixel

    @property
    def bytes_per_pixel(self) -> int:
        """Bytes per pixel of one plane."""
        return 1

    @property
    def dtype(self) -> np.dtype:
        """Numpy dtype of one plane."""
        return np.dtype(np.uint8)


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One rectified stereo pair with its capture time and intrinsics.

    Attributes
    ----------
    sequence : int
        Frame counter of the publisher (u64).
    capture_ns : int
        Capture time [ns] on the clock shared with telemetry (simulation time in the SIL).
    intrinsics : StereoIntrinsics
        Image size, focal lengths, principal point and baseline.
    left, right : numpy.ndarray
        ``(height_px, width_px)`` planes; ``left`` is the reference image.
    encoding : PixelEncoding
        Pixel encoding of both planes.
    """

    sequence: int
    capture_ns: int
    intrinsics: StereoIntrinsics
    left: np.ndarray
    right: np.ndarray
    encoding: PixelEncoding = PixelEncoding.MONO8


def _fail(reason: str) -> FrameDecodeError:
    return FrameDecodeError(f"bad stereo frame: {reason}")


def _check_header(
    magic: bytes,
    version: int,
    header_size: int,
    capture_ns: int,
    width: int,
    height: int,
    encoding: int,
    reserved: bytes,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    baseline: float,
) -> PixelEncoding:
    if magic != MAGIC:
        raise _fail(f"magic {magic!r} != {MAGIC!r}")
    if version != FORMAT_VERSION:
        raise _fail(f"unsupported version {version} (this decoder reads {FORMAT_VERSION})")
    if header_size != HEADER_SIZE:
        raise _fail(f"header_size {header_size} != {HEADER_SIZE}")
    if capture_ns < 0:
        raise _fail(f"negative capture_ns {capture_ns}")
    for name, value in (("width_px", width), ("height_px", height)):
        if not 1 <= value <= MAX_DIMENSION_PX:
            raise _fail(f"{name} {value} outside 1..{MAX_DIMENSION_PX}")
    try:
        pixel_encoding = PixelEncoding(encoding)
    except ValueError:
        raise _fail(f"unknown pixel encoding {encoding}") from None
    if reserved != b"\x00\x00\x00":
        raise _fail(f"reserved bytes not zero: {reserved!r}")
    for name, value in (("fx_px", fx), ("fy_px", fy), ("baseline_m", baseline)):
        if not (math.isfinite(value) and value > 0.0):
            raise _fail(f"{name} {value!r} is not finite and positive")
    for name, value, size in (("cx_px", cx, width), ("cy_px", cy, height)):
        if not (math.isfinite(value) and -size <= value <= 2 * size):
            raise _fail(f"{name} {value!r} is not finite or outside [-{size}, {2 * size}]")
    return pixel_encoding


def decode(payload: bytes | bytearray | memoryview) -> StereoFrame:
    """Parse and validate a payload; the planes are read-only zero-copy views.

    Raises
    ------
    FrameDecodeError
        On any malformed field or byte count (and on nothing else).
    """
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise _fail(f"payload must be bytes-like, got {type(payload).__name__}")
    try:
        buf = memoryview(payload).cast("B")
    except TypeError as exc:
        raise _fail(f"payload buffer is not contiguous bytes ({exc})") from None
    if len(buf) < HEADER_SIZE:
        raise _fail(f"{len(buf)} bytes is shorter than the {HEADER_SIZE}-byte header")
    (
        magic,
        version,
        header_size,
        sequence,
        capture_ns,
        width,
        height,
        encoding,
        reserved,
        fx,
        fy,
        cx,
        cy,
        baseline,
    ) = _HEADER.unpack_from(buf, 0)
    pixel_encoding = _check_header(
        magic,
        version,
        header_size,
        capture_ns,
        width,
        height,
        encoding,
        reserved,
        fx,
        fy,
        cx,
        cy,
        baseline,
    )
    plane_bytes = width * height * pixel_encoding.bytes_per_pixel
    expected = HEADER_SIZE + 2 * plane_bytes
    if len(buf) != expected:
        raise _fail(
            f"{len(buf)} bytes, expected {expected} for two {width}x{height} "
            f"{pixel_encoding.name} planes"
        )
    planes = np.frombuffer(buf, dtype=pixel_encoding.dtype, offset=HEADER_SIZE)
    planes = planes.reshape(2, height, width)
    planes.flags.writeable = False
    intrinsics = StereoIntrinsics(
        width_px=int(width),
        height_px=int(height),
        fx_px=float(fx),
        fy_px=float(fy),
        cx_px=float(cx),
        cy_px=float(cy),
        baseline_m=float(baseline),
    )
    return StereoFrame(
        sequence=int(sequence),
        capture_ns=int(capture_ns),
        intrinsics=intrinsics,
        left=planes[0],
        right=planes[1],
        encoding=pixel_encoding,
    )


def validate(payload: bytes | bytearray | memoryview) -> None:
    """Raise :class:`FrameDecodeError` if ``payload`` is not a valid frame; else return None."""
    decode(payload)


def encode(frame: StereoFrame) -> bytes:
    """Serialize ``frame``; checks the same invariants :func:`decode` enforces.

    Raises
    ------
    ValueError
        If a field is out of range or a plane does not match the intrinsics/encoding.
    """
    k = frame.intrinsics
    encoding = PixelEncoding(frame.encoding)
    if not 0 <= frame.sequence < 2**64:
        raise ValueError(f"sequence {frame.sequence} does not fit u64")
    if not 0 <= frame.capture_ns < 2**63:
        raise ValueError(f"capture_ns {frame.capture_ns} does not fit a non-negative i64")
    _check_header(
        MAGIC,
        FORMAT_VERSION,
        HEADER_SIZE,
        frame.capture_ns,
        k.width_px,
        k.height_px,
        int(encoding),
        b"\x00\x00\x00",
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        k.baseline_m,
    )
    shape = (k.height_px, k.width_px)
    for name, plane in (("left", frame.left), ("right", frame.right)):
        if plane.shape != shape or plane.dtype != encoding.dtype:
            raise ValueError(
                f"{name} plane is {plane.dtype}{plane.shape}, expected {encoding.dtype}{shape}"
            )
    header = _HEADER.pack(
        MAGIC,
        FORMAT_VERSION,
        HEADER_SIZE,
        frame.sequence,
        frame.capture_ns,
        k.width_px,
        k.height_px,
        int(encoding),
        b"\x00\x00\x00",
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        k.baseline_m,
    )
    left = np.ascontiguousarray(frame.left, dtype=encoding.dtype.newbyteorder("<"))
    right = np.ascontiguousarray(frame.right, dtype=encoding.dtype.newbyteorder("<"))
    return b"".join((header, left.tobytes(), right.tobytes()))
