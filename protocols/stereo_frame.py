"""Camera-frame wire format for Zenoh: versioned little-endian header + image planes.

Two kinds of frame share one header. A **stereo frame** (encoding ``MONO8``) carries a
rectified left and right plane; the companion runs its own matcher. A **depth frame**
(``DEPTH16`` or ``DEPTH32F``) carries the depth a depth camera computed itself (Intel
RealSense D4xx, Luxonis OAK-D, ZED), registered to its left imager, and optionally that
imager's MONO8 picture for the viewer; the companion runs no matcher.

Layout (version 2, all little-endian, ``HEADER_SIZE`` = 84 bytes)::

    offset size  field
     0      4    magic            b"SAVF"
     4      2    version          u16, = 2
     6      2    header_size      u16, = 84 (bytes before the first plane)
     8      8    sequence         u64
    16      8    capture_ns       i64, >= 0, capture time on the shared clock (DESIGN.md)
    24      4    width_px         u32, 1..8192
    28      4    height_px        u32, 1..8192
    32      1    encoding         u8, PixelEncoding
    33      1    flags            u8, bit 0 LEFT_IMAGE (depth frames only); other bits zero
    34      2    reserved         zero
    36      8    fx_px            f64, finite > 0
    44      8    fy_px            f64, finite > 0
    52      8    cx_px            f64, finite, within [-W, 2W]
    60      8    cy_px            f64, finite, within [-H, 2H]
    68      8    baseline_m       f64, finite > 0 (a depth camera's own stereo baseline)
    76      8    depth_scale_m    f64, metres per depth unit: MONO8 0; DEPTH16 in
                                  [1e-6, 0.1] (RealSense: 0.001, D405: 0.0001); DEPTH32F 1
    84     ...   planes, row-major:
                 MONO8     left (W·H·1), right (W·H·1)
                 DEPTH16   depth u16 (W·H·2), 0 = no data; then the left image (W·H·1)
                           if LEFT_IMAGE
                 DEPTH32F  depth f32 [m] (W·H·4), NaN (or 0) = no data, never negative or
                           infinite; then the left image (W·H·1) if LEFT_IMAGE

Depth is along the optical axis of the left imager (the frame whose intrinsics the header
carries), as RealSense's depth stream is. Version 1 (76-byte header, no ``flags`` or
``depth_scale_m``, MONO8 only) is still decoded; a version-1 decoder refuses version 2 with
"unsupported version 2", so an old companion never misreads a depth frame as a pair.

:func:`decode` checks every field, the exact byte count and (DEPTH32F) every value, and
raises :class:`FrameDecodeError` (a ``ValueError``) with the reason; it raises nothing else
on arbitrary bytes.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = [
    "DEPTH16_SCALE_RANGE_M",
    "FORMAT_VERSION",
    "HEADER_SIZE",
    "MAGIC",
    "MAX_DIMENSION_PX",
    "DepthFrame",
    "Frame",
    "FrameDecodeError",
    "FrameFlags",
    "PixelEncoding",
    "StereoFrame",
    "decode",
    "encode",
    "validate",
]

MAGIC = b"SAVF"
FORMAT_VERSION = 2
MAX_DIMENSION_PX = 8192
DEPTH16_SCALE_RANGE_M = (1e-6, 0.1)  # metres per DEPTH16 unit, inclusive bounds
_HEADER_V1 = struct.Struct("<4sHHQqIIB3s5d")
_HEADER = struct.Struct("<4sHHQqIIBB2s6d")
HEADER_SIZE = _HEADER.size


class FrameDecodeError(ValueError):
    """A camera-frame payload is malformed; the message says which field and why."""


class PixelEncoding(enum.IntEnum):
    """What the planes of a frame hold (module docstring)."""

    MONO8 = 1  # rectified stereo pair, 8-bit grayscale
    DEPTH16 = 2  # depth camera: u16 depth units (× depth_scale_m), 0 = no data
    DEPTH32F = 3  # depth camera: float32 metres, NaN = no data

    @property
    def is_depth(self) -> bool:
        """The frame carries a camera-computed depth plane, not a stereo pair."""
        return self is not PixelEncoding.MONO8

    @property
    def bytes_per_pixel(self) -> int:
        """Bytes per pixel of the first plane."""
        return self.dtype.itemsize

    @property
    def dtype(self) -> np.dtype:
        """Numpy dtype of the first plane (both planes of a stereo pair)."""
        return np.dtype(_DTYPES[self])


_DTYPES = {
    PixelEncoding.MONO8: np.uint8,
    PixelEncoding.DEPTH16: np.uint16,
    PixelEncoding.DEPTH32F: np.float32,
}


class FrameFlags(enum.IntFlag):
    """Bits of the header's ``flags`` byte."""

    LEFT_IMAGE = 1  # a depth frame carries its left imager's MONO8 picture after the depth


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


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One depth image computed by a depth camera, registered to its left imager.

    Attributes
    ----------
    sequence : int
        Frame counter of the publisher (u64).
    capture_ns : int
        Capture time [ns] on the clock shared with telemetry.
    intrinsics : StereoIntrinsics
        The left imager's size, focal lengths and principal point, and the camera's stereo
        baseline (it places the left imager on the vehicle and scales equivalent disparity).
    depth : numpy.ndarray
        ``(height_px, width_px)`` depth along the optical axis: uint16 units of
        ``depth_scale_m`` (0 = no data) for DEPTH16, float32 metres (NaN or 0 = no data)
        for DEPTH32F.
    encoding : PixelEncoding
        ``DEPTH16`` or ``DEPTH32F``.
    depth_scale_m : float
        Metres per depth unit (DEPTH16; RealSense's ``depth_scale``); 1 for DEPTH32F.
    left : numpy.ndarray or None
        The left imager's MONO8 picture (for the viewer), or None.
    """

    sequence: int
    capture_ns: int
    intrinsics: StereoIntrinsics
    depth: np.ndarray
    encoding: PixelEncoding = PixelEncoding.DEPTH16
    depth_scale_m: float = 0.001
    left: np.ndarray | None = None


Frame = StereoFrame | DepthFrame


def _fail(reason: str) -> FrameDecodeError:
    return FrameDecodeError(f"bad camera frame: {reason}")


def _check_encoding(encoding: int) -> PixelEncoding:
    try:
        return PixelEncoding(encoding)
    except ValueError:
        raise _fail(f"unknown pixel encoding {encoding}") from None


def _check_geometry(capture_ns, width, height, fx, fy, cx, cy, baseline) -> None:
    if capture_ns < 0:
        raise _fail(f"negative capture_ns {capture_ns}")
    for name, value in (("width_px", width), ("height_px", height)):
        if not 1 <= value <= MAX_DIMENSION_PX:
            raise _fail(f"{name} {value} outside 1..{MAX_DIMENSION_PX}")
    for name, value in (("fx_px", fx), ("fy_px", fy), ("baseline_m", baseline)):
        if not (math.isfinite(value) and value > 0.0):
            raise _fail(f"{name} {value!r} is not finite and positive")
    for name, value, size in (("cx_px", cx, width), ("cy_px", cy, height)):
        if not (math.isfinite(value) and -size <= value <= 2 * size):
            raise _fail(f"{name} {value!r} is not finite or outside [-{size}, {2 * size}]")


def _check_depth_fields(encoding: PixelEncoding, flags: int, depth_scale_m: float) -> None:
    if flags & ~int(FrameFlags.LEFT_IMAGE):
        raise _fail(f"unknown flag bits 0x{flags:02x}")
    if encoding is PixelEncoding.MONO8:
        if flags:
            raise _fail("a stereo pair (MONO8) carries no LEFT_IMAGE flag")
        if depth_scale_m != 0.0:
            raise _fail(f"depth_scale_m {depth_scale_m!r} must be 0 for a stereo pair (MONO8)")
    elif encoding is PixelEncoding.DEPTH16:
        low, high = DEPTH16_SCALE_RANGE_M
        if not (math.isfinite(depth_scale_m) and low <= depth_scale_m <= high):
            raise _fail(f"DEPTH16 depth_scale_m {depth_scale_m!r} outside [{low}, {high}] m")
    elif depth_scale_m != 1.0:
        raise _fail(f"DEPTH32F depth_scale_m {depth_scale_m!r} must be 1 (metres)")


def _plane_sizes(encoding: PixelEncoding, flags: int, width: int, height: int) -> list[int]:
    area = width * height
    if encoding is PixelEncoding.MONO8:
        return [area, area]
    sizes = [area * encoding.bytes_per_pixel]
    if flags & FrameFlags.LEFT_IMAGE:
        sizes.append(area)
    return sizes


def _check_depth32f(depth: np.ndarray) -> None:
    """NaN or finite >= 0 everywhere (0 and NaN mean no data)."""
    bad = ~(np.isnan(depth) | ((depth >= 0.0) & (depth < np.inf)))
    if bad.any():
        y, x = (int(v[0]) for v in np.nonzero(bad))
        raise _fail(
            f"DEPTH32F holds {int(bad.sum())} negative or infinite value(s), first "
            f"{float(depth[y, x])!r} at (x={x}, y={y}); no data is NaN or 0"
        )


@dataclass(frozen=True)
class _Header:
    """The header fields of a payload, checked."""

    size: int
    sequence: int
    capture_ns: int
    encoding: PixelEncoding
    flags: int
    depth_scale_m: float
    intrinsics: StereoIntrinsics


def _unpack_header(buf: memoryview) -> tuple:
    """The raw header fields of version 1 or 2, in version 2's order (version 1: no flags,
    a zero depth scale); raises on a short payload, a bad magic or an unknown version."""
    if len(buf) < _HEADER_V1.size:
        raise _fail(f"{len(buf)} bytes is shorter than the {_HEADER_V1.size}-byte v1 header")
    magic, version = struct.unpack_from("<4sH", buf, 0)
    if magic != MAGIC:
        raise _fail(f"magic {magic!r} != {MAGIC!r}")
    if version == 1:
        fields = _HEADER_V1.unpack_from(buf, 0)
        reserved_ok = fields[8] == b"\x00\x00\x00"
        return (*fields[1:8], 0, fields[8], reserved_ok, *fields[9:], 0.0)
    if version == FORMAT_VERSION:
        if len(buf) < HEADER_SIZE:
            raise _fail(f"{len(buf)} bytes is shorter than the {HEADER_SIZE}-byte header")
        fields = _HEADER.unpack_from(buf, 0)
        return (*fields[1:10], fields[9] == b"\x00\x00", *fields[10:])
    raise _fail(f"unsupported version {version} (this decoder reads 1 and {FORMAT_VERSION})")


def _parse_header(buf: memoryview) -> _Header:
    """Every header field of ``buf`` checked (module docstring)."""
    (
        version,
        header_size,
        sequence,
        capture_ns,
        width,
        height,
        encoding,
        flags,
        reserved,
        reserved_ok,
        fx,
        fy,
        cx,
        cy,
        baseline,
        depth_scale_m,
    ) = _unpack_header(buf)
    expected_header = _HEADER_V1.size if version == 1 else HEADER_SIZE
    if header_size != expected_header:
        raise _fail(f"header_size {header_size} != {expected_header} for version {version}")
    pixel_encoding = _check_encoding(encoding)
    if version == 1 and pixel_encoding is not PixelEncoding.MONO8:
        raise _fail(f"version 1 carries MONO8 pairs only, not {pixel_encoding.name}")
    if not reserved_ok:
        raise _fail(f"reserved bytes not zero: {reserved!r}")
    _check_geometry(capture_ns, width, height, fx, fy, cx, cy, baseline)
    _check_depth_fields(pixel_encoding, flags, depth_scale_m)
    intrinsics = StereoIntrinsics(
        width_px=int(width),
        height_px=int(height),
        fx_px=float(fx),
        fy_px=float(fy),
        cx_px=float(cx),
        cy_px=float(cy),
        baseline_m=float(baseline),
    )
    return _Header(
        int(header_size),
        int(sequence),
        int(capture_ns),
        pixel_encoding,
        int(flags),
        float(depth_scale_m),
        intrinsics,
    )


def decode(payload: bytes | bytearray | memoryview) -> Frame:
    """Parse and validate a payload; the planes are read-only zero-copy views.

    Returns a :class:`StereoFrame` (MONO8) or a :class:`DepthFrame` (DEPTH16, DEPTH32F).

    Raises
    ------
    FrameDecodeError
        On any malformed field, value or byte count (and on nothing else).
    """
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise _fail(f"payload must be bytes-like, got {type(payload).__name__}")
    try:
        buf = memoryview(payload).cast("B")
    except TypeError as exc:
        raise _fail(f"payload buffer is not contiguous bytes ({exc})") from None
    h = _parse_header(buf)
    k = h.intrinsics
    width, height = k.width_px, k.height_px
    sizes = _plane_sizes(h.encoding, h.flags, width, height)
    expected = h.size + sum(sizes)
    if len(buf) != expected:
        raise _fail(
            f"{len(buf)} bytes, expected {expected} for {width}x{height} "
            f"{h.encoding.name} (planes of {sizes} bytes)"
        )
    if h.encoding is PixelEncoding.MONO8:
        planes = np.frombuffer(buf, dtype=np.uint8, offset=h.size).reshape(2, height, width)
        planes.flags.writeable = False
        return StereoFrame(h.sequence, h.capture_ns, k, planes[0], planes[1], h.encoding)
    depth = np.frombuffer(
        buf, dtype=h.encoding.dtype.newbyteorder("<"), count=width * height, offset=h.size
    ).reshape(height, width)
    if h.encoding is PixelEncoding.DEPTH32F:
        _check_depth32f(depth)
    depth.flags.writeable = False
    left = None
    if h.flags & FrameFlags.LEFT_IMAGE:
        left = np.frombuffer(buf, dtype=np.uint8, offset=h.size + sizes[0])
        left = left.reshape(height, width)
        left.flags.writeable = False
    return DepthFrame(h.sequence, h.capture_ns, k, depth, h.encoding, h.depth_scale_m, left)


def validate(payload: bytes | bytearray | memoryview) -> None:
    """Raise :class:`FrameDecodeError` if ``payload`` is not a valid frame; else return None."""
    decode(payload)


def _planes(frame: Frame, encoding: PixelEncoding) -> tuple[int, float, list[np.ndarray]]:
    """(flags, depth_scale_m, planes to write) of ``frame``; ValueError if they do not fit."""
    k = frame.intrinsics
    shape = (k.height_px, k.width_px)
    if isinstance(frame, StereoFrame):
        if encoding is not PixelEncoding.MONO8:
            raise ValueError(f"a StereoFrame is MONO8, not {encoding.name}")
        named = [
            ("left", frame.left, np.dtype(np.uint8)),
            ("right", frame.right, np.dtype(np.uint8)),
        ]
        flags, scale = 0, 0.0
    elif isinstance(frame, DepthFrame):
        if not encoding.is_depth:
            raise ValueError(f"a DepthFrame is DEPTH16 or DEPTH32F, not {encoding.name}")
        named = [("depth", frame.depth, encoding.dtype)]
        if frame.left is not None:
            named.append(("left", frame.left, np.dtype(np.uint8)))
        flags = int(FrameFlags.LEFT_IMAGE) if frame.left is not None else 0
        scale = float(frame.depth_scale_m)
    else:
        raise TypeError(f"frame must be a StereoFrame or DepthFrame, got {type(frame).__name__}")
    planes = []
    for name, plane, dtype in named:
        plane = np.asarray(plane)
        if plane.shape != shape or plane.dtype != dtype:
            raise ValueError(f"{name} plane is {plane.dtype}{plane.shape}, expected {dtype}{shape}")
        planes.append(np.ascontiguousarray(plane, dtype=np.dtype(dtype).newbyteorder("<")))
    return flags, scale, planes


def encode(frame: Frame) -> bytes:
    """Serialize ``frame`` (version 2); checks the same invariants :func:`decode` enforces.

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
    flags, scale, planes = _planes(frame, encoding)
    _check_geometry(
        frame.capture_ns,
        k.width_px,
        k.height_px,
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        k.baseline_m,
    )
    _check_depth_fields(encoding, flags, scale)
    if encoding is PixelEncoding.DEPTH32F:
        _check_depth32f(planes[0])
    header = _HEADER.pack(
        MAGIC,
        FORMAT_VERSION,
        HEADER_SIZE,
        frame.sequence,
        frame.capture_ns,
        k.width_px,
        k.height_px,
        int(encoding),
        flags,
        b"\x00\x00",
        k.fx_px,
        k.fy_px,
        k.cx_px,
        k.cy_px,
        k.baseline_m,
        scale,
    )
    return b"".join([header, *(plane.tobytes() for plane in planes)])
