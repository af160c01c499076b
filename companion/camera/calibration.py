"""Stereo calibration (OpenCV ``stereoCalibrate`` outputs) and rectification of raw pairs.

Accepted file format
--------------------
One or more ``cv2.FileStorage`` files (YAML, XML or JSON) whose union holds the outputs of
``cv2.stereoCalibrate``. OpenCV's ``stereo_calib`` sample writes exactly this split into
``intrinsics.yml`` and ``extrinsics.yml``; pass both. Keys (aliases in brackets):

* ``K1`` [``M1``, ``cameraMatrix1``], ``K2`` [``M2``, ``cameraMatrix2``]: 3×3 camera matrices [px]
* ``D1`` [``distCoeffs1``], ``D2`` [``distCoeffs2``]: 4, 5, 8, 12 or 14 distortion coefficients
* ``R``: 3×3 rotation and ``T``: 3-vector, ``X_2 = R·X_1 + T`` (camera 1 = left, reference)
* image size (optional, the size of each eye during calibration): ``image_width`` +
  ``image_height``, or ``image_size`` [``imageSize``] as ``[width, height]``. Without it the
  size of the first captured pair is assumed.

``T`` is in the unit of the calibration target's square size; ``units`` says which
(metres by default), and a baseline that is implausible in metres is refused with a hint.

Rectification
-------------
``cv2.stereoRectify`` (``CALIB_ZERO_DISPARITY``, free scaling ``alpha``) then
``cv2.initUndistortRectifyMap`` + ``cv2.remap`` per eye. The published intrinsics are those
of the rectified pair: ``fx, fy, cx, cy`` from ``P1`` and ``baseline = -P2[0,3] / P2[0,0]``
(= ``|T|``). Pixel centres are at integer coordinates in OpenCV as in
:mod:`protocols.camera`. Pure: loading reads the given files, nothing else does I/O.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from protocols.camera import StereoIntrinsics

__all__ = [
    "UNIT_SCALE_M",
    "CalibrationError",
    "Rectifier",
    "StereoCalibration",
    "load_calibration",
]

#: Metres per unit of ``T`` for the accepted ``units``.
UNIT_SCALE_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}

_MAX_BASELINE_M = 2.0  # a larger |T| almost surely means T is not in metres
_MIN_BASELINE_M = 1e-3
_DIST_SIZES = (4, 5, 8, 12, 14)
_OPENCV_PREFIX = re.compile(r"^OpenCV\([^)]*\) \S+: error: ")
_ALIASES = {
    "K1": ("K1", "M1", "cameraMatrix1"),
    "D1": ("D1", "distCoeffs1"),
    "K2": ("K2", "M2", "cameraMatrix2"),
    "D2": ("D2", "distCoeffs2"),
    "R": ("R",),
    "T": ("T",),
}


class CalibrationError(ValueError):
    """The calibration is missing, unreadable or physically inconsistent (message says why)."""


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Raw (unrectified) stereo calibration, ``cv2.stereoCalibrate`` conventions.

    Attributes
    ----------
    K1, K2 : numpy.ndarray
        3×3 camera matrices of the left (reference) and right camera [px].
    D1, D2 : numpy.ndarray
        Distortion coefficients (OpenCV order).
    R : numpy.ndarray
        3×3 rotation from left- to right-camera coordinates.
    T_m : numpy.ndarray
        Translation [m], ``X_right = R·X_left + T_m``; ``T_m[0] < 0`` for a right camera to
        the right of the left one.
    image_size_px : tuple of int or None
        ``(width, height)`` of each eye during calibration; None if the file does not say.
    source : str
        Where it was loaded from (for messages).
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T_m: np.ndarray
    image_size_px: tuple[int, int] | None = None
    source: str = "<memory>"

    def __post_init__(self) -> None:
        where = self.source
        for name in ("K1", "K2"):
            K = np.asarray(getattr(self, name), dtype=np.float64)
            if K.shape != (3, 3) or not np.all(np.isfinite(K)):
                raise CalibrationError(f"{where}: {name} must be a finite 3x3 matrix")
            if not (K[0, 0] > 0 and K[1, 1] > 0) or not np.allclose(K[2], (0, 0, 1)):
                raise CalibrationError(
                    f"{where}: {name} is not a camera matrix (fx, fy > 0, last row 0 0 1)"
                )
            object.__setattr__(self, name, K)
        for name in ("D1", "D2"):
            D = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if D.size not in _DIST_SIZES or not np.all(np.isfinite(D)):
                raise CalibrationError(
                    f"{where}: {name} must hold {'/'.join(map(str, _DIST_SIZES))} finite "
                    f"coefficients, got {D.size}"
                )
            object.__setattr__(self, name, D)
        R = np.asarray(self.R, dtype=np.float64)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise CalibrationError(f"{where}: R must be a finite 3x3 matrix")
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0):
            raise CalibrationError(f"{where}: R is not a rotation (R·Rᵀ ≠ I or det ≤ 0)")
        T = np.asarray(self.T_m, dtype=np.float64).reshape(-1)
        if T.size != 3 or not np.all(np.isfinite(T)):
            raise CalibrationError(f"{where}: T must be 3 finite numbers")
        baseline_m = float(np.linalg.norm(T))
        if baseline_m > _MAX_BASELINE_M:
            raise CalibrationError(
                f"{where}: baseline |T| = {baseline_m:g} m is implausible; if T is in "
                "millimetres or centimetres, say so (units: mm / --calibration-units mm)"
            )
        if baseline_m < _MIN_BASELINE_M:
            raise CalibrationError(f"{where}: baseline |T| = {baseline_m:g} m is too small")
        if abs(T[1]) > abs(T[0]) or abs(T[2]) > abs(T[0]):
            raise CalibrationError(
                f"{where}: T = {T.tolist()} is not a horizontal rig (|T_x| must dominate)"
            )
        if T[0] > 0:
            raise CalibrationError(
                f"{where}: camera 2 is to the LEFT of camera 1 (T_x = {T[0]:g} > 0): "
                "swap the left and right inputs"
            )
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "T_m", T)
        if self.image_size_px is not None:
            object.__setattr__(self, "image_size_px", _check_size(where, self.image_size_px))

    @property
    def baseline_m(self) -> float:
        """``|T|`` [m]."""
        return float(np.linalg.norm(self.T_m))


def _check_size(where: str, size) -> tuple[int, int]:
    try:
        w, h = (float(x) for x in size)
    except (TypeError, ValueError):
        raise CalibrationError(
            f"{where}: image size must be [width, height], got {size!r}"
        ) from None
    if not (w.is_integer() and h.is_integer() and 1 <= w <= 8192 and 1 <= h <= 8192):
        raise CalibrationError(f"{where}: image size {size!r} is not two integers in 1..8192")
    return int(w), int(h)


def _node_array(node) -> np.ndarray | None:
    """A FileStorage node as a float array (matrix or plain sequence), or None if empty."""
    if node.empty() or node.isNone():
        return None
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.array([node.real()], dtype=np.float64)
    mat = node.mat()
    return None if mat is None else np.asarray(mat, dtype=np.float64)


def _read_file(path: Path) -> dict[str, np.ndarray | str]:
    if not path.is_file():
        raise CalibrationError(f"calibration file {path} does not exist")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 4.x raises SystemError on some bad input
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ else exc
        reason = _OPENCV_PREFIX.sub("", " ".join(str(cause).split())) or "parse error"
        raise CalibrationError(
            f"calibration file {path} is not OpenCV YAML/XML/JSON ({reason})"
        ) from None
    try:
        if not fs.isOpened():
            raise CalibrationError(f"calibration file {path} cannot be opened by cv2.FileStorage")
        values: dict[str, np.ndarray | str] = {}
        root = fs.root()
        for key in root.keys():  # noqa: SIM118 (a cv2.FileNode, not a dict)
            node = fs.getNode(key)
            if key == "units" and node.isString():
                values[key] = node.string()
                continue
            try:
                array = _node_array(node)
            except cv2.error:
                array = None
            if array is not None:
                values[key] = array
        return values
    finally:
        fs.release()


def load_calibration(
    paths: Path | str | Sequence[Path | str], units: str | None = None
) -> StereoCalibration:
    """Load and validate a stereo calibration from one or more ``cv2.FileStorage`` files.

    Parameters
    ----------
    paths : path or sequence of paths
        Files whose union holds K1, D1, K2, D2, R, T (and optionally the image size); a key
        found in several files must be given once.
    units : {'m', 'cm', 'mm'} or None
        Unit of ``T``; overrides a ``units`` entry in the files; default metres.

    Raises
    ------
    CalibrationError
        Naming the file and the key that is missing or wrong.
    """
    if isinstance(paths, str | Path):
        paths = [paths]
    paths = [Path(p) for p in paths]
    if not paths:
        raise CalibrationError("no calibration file given")
    where = ", ".join(str(p) for p in paths)
    merged: dict[str, np.ndarray | str] = {}
    for path in paths:
        for key, value in _read_file(path).items():
            if key in merged:
                raise CalibrationError(f"calibration key {key!r} appears in more than one file")
            merged[key] = value
    found: dict[str, np.ndarray] = {}
    for name, aliases in _ALIASES.items():
        hits = [a for a in aliases if a in merged]
        if not hits:
            raise CalibrationError(
                f"{where}: missing {name} (looked for {', '.join(aliases)}); expected the "
                "outputs of cv2.stereoCalibrate"
            )
        found[name] = merged[hits[0]]  # type: ignore[assignment]
    size = None
    if "image_width" in merged or "image_height" in merged:
        try:
            size = (merged["image_width"][0], merged["image_height"][0])  # type: ignore[index]
        except (KeyError, IndexError, TypeError):
            raise CalibrationError(f"{where}: image_width and image_height go together") from None
    else:
        for key in ("image_size", "imageSize"):
            if key in merged:
                size = tuple(np.asarray(merged[key]).reshape(-1).tolist())
                if len(size) != 2:
                    raise CalibrationError(f"{where}: {key} must be [width, height]")
                break
    unit = units if units is not None else merged.get("units", "m")
    if not isinstance(unit, str) or unit not in UNIT_SCALE_M:
        raise CalibrationError(
            f"{where}: units must be one of {sorted(UNIT_SCALE_M)}, got {unit!r}"
        )
    return StereoCalibration(
        K1=found["K1"],
        D1=found["D1"],
        K2=found["K2"],
        D2=found["D2"],
        R=found["R"],
        T_m=np.asarray(found["T"], dtype=np.float64) * UNIT_SCALE_M[unit],
        image_size_px=size,
        source=where,
    )


class Rectifier:
    """Rectification maps of one calibrated rig at one input size.

    Parameters
    ----------
    calibration : StereoCalibration
        The raw calibration.
    image_size_px : (int, int) or None
        ``(width, height)`` of the raw images; must equal the calibration's if that is known.
    alpha : float
        ``cv2.stereoRectify`` free scaling: 0 keeps only valid pixels (no black borders,
        which carry no texture for the matcher), 1 keeps every source pixel; -1 is OpenCV's
        default.
    output_size_px : (int, int) or None
        ``(width, height)`` of the rectified images (e.g. downscale to 320×240 for speed);
        default the input size.

    Raises
    ------
    CalibrationError
        If the sizes disagree or rectification yields an unusable geometry.
    """

    def __init__(
        self,
        calibration: StereoCalibration,
        image_size_px: tuple[int, int] | None = None,
        alpha: float = 0.0,
        output_size_px: tuple[int, int] | None = None,
    ) -> None:
        c = calibration
        size = image_size_px if image_size_px is not None else c.image_size_px
        if size is None:
            raise CalibrationError(f"{c.source}: image size unknown (not in the file, none given)")
        size = _check_size(c.source, size)
        if c.image_size_px is not None and size != c.image_size_px:
            raise CalibrationError(
                f"{c.source}: calibrated for {c.image_size_px[0]}x{c.image_size_px[1]} but the "
                f"images are {size[0]}x{size[1]}"
            )
        if not (math.isfinite(alpha) and (alpha == -1.0 or 0.0 <= alpha <= 1.0)):
            raise CalibrationError(f"alpha must be -1 or in [0, 1], got {alpha!r}")
        out = _check_size(c.source, output_size_px) if output_size_px is not None else size
        R1, R2, P1, P2, _Q, _roi1, _roi2 = cv2.stereoRectify(
            c.K1,
            c.D1,
            c.K2,
            c.D2,
            size,
            c.R,
            c.T_m,
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=alpha,
            newImageSize=out,
        )
        if not (np.all(np.isfinite(P1)) and np.all(np.isfinite(P2)) and P1[0, 0] > 0):
            raise CalibrationError(f"{c.source}: cv2.stereoRectify gave a degenerate result")
        baseline_m = -P2[0, 3] / P2[0, 0]
        if not baseline_m > 0 or abs(P2[1, 3]) > 1e-6 * abs(P2[0, 3]):
            raise CalibrationError(f"{c.source}: rectification is not horizontal left-right")
        self.input_size_px = size
        self.output_size_px = out
        self.R1, self.R2, self.P1, self.P2 = R1, R2, P1, P2
        self.intrinsics = StereoIntrinsics(
            width_px=int(out[0]),
            height_px=int(out[1]),
            fx_px=float(P1[0, 0]),
            fy_px=float(P1[1, 1]),
            cx_px=float(P1[0, 2]),
            cy_px=float(P1[1, 2]),
            baseline_m=float(baseline_m),
        )
        self._maps = tuple(
            cv2.initUndistortRectifyMap(K, D, Rr, P, out, cv2.CV_16SC2)
            for K, D, Rr, P in ((c.K1, c.D1, R1, P1), (c.K2, c.D2, R2, P2))
        )

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistort and rectify a raw pair (``(H, W)`` uint8 each) → rectified pair.

        Raises
        ------
        ValueError
            If an image does not have the input size.
        """
        w, h = self.input_size_px
        for name, image in (("left", left), ("right", right)):
            if image.shape[:2] != (h, w):
                raise ValueError(
                    f"{name} image is {image.shape[1]}x{image.shape[0]}, rectifier expects {w}x{h}"
                )
        return tuple(  # type: ignore[return-value]
            cv2.remap(image, m1, m2, cv2.INTER_LINEAR)
            for image, (m1, m2) in zip((left, right), self._maps, strict=True)
        )
