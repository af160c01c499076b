"""The autopilot's proximity driver: OBSTACLE_DISTANCE in, as ArduPilot and PX4 read it.

Pure: the caller passes wall time (the sender's rate and the 0.5 s freshness rule are a
link matter, like a heartbeat; DESIGN.md, "Two clocks"). One message is kept, the newest;
what each autopilot makes of it:

* **ArduPilot** (``libraries/AP_Proximity/AP_Proximity_MAV.cpp``, ``PRX1_TYPE = 2``):
  the ``frame`` field is not read; sector ``j`` lies at body bearing
  ``j · increment + angle_offset`` (``increment_f`` when non-zero, else ``increment``;
  ``min(360 / |increment| + 0.5, 72)`` sectors); ``0``, ``UINT16_MAX`` and readings
  below ``min_distance`` or above ``max_distance`` are dropped; what remains goes to
  eight 45° faces centred on 0°, 45°, … (``AP_Proximity_Boundary_3D::get_face``), each
  keeping its nearest reading and that reading's bearing; a face with none is reset.
  Each face's distance is low-pass filtered at ``PRX_FILT`` Hz (0.25 by default; 0: off)
  as it is set, and the filter restarts from the reading when the face was last set
  ``PROXIMITY_FILT_RESET_TIME`` (1 s) ago or more
  (``AP_Proximity_Boundary_3D::set_filtered_distance``); AC_Avoid's boundary reads the
  filtered distance. Approaching at ``v`` the filtered face lags ``v / (2π·PRX_FILT)``
  behind (5 m at 8 m/s with the default).
  No message for ``PROXIMITY_MAV_TIMEOUT_MS`` (500 ms): status "No Data" — the pre-arm
  check fails ("PRX1: No Data") and AC_Avoid ignores the sensor.
  Not modelled: the ``PRX1_ORIENT`` / ``PRX1_YAW_CORR`` corrections, the 3-D boundary's
  layers (one horizontal layer here), the boundary's line segments between faces, and
  the object database that BendyRuler/Dijkstra use.
* **PX4** (``src/lib/collision_prevention/CollisionPrevention.cpp``): the message is
  mapped onto 72 bins of 5° (``bin i = [5i, 5i + 5)``, body frame) with
  ``msg_index = ceil(wrap_360(5 i − angle_offset) / increment)``, MAV_FRAME_BODY_FRD or
  LOCAL_NED (then rotated by the vehicle's yaw); ``UINT16_MAX`` leaves a bin without data;
  a bin older than ``RANGE_STREAM_TIMEOUT_US`` (500 ms) is reset to no data; a bin that
  has taken a reading once stays "in the field of view" (``_data_fov``). Not
  modelled: fusing several sensors (``_enterData``'s range rules beyond one source),
  DISTANCE_SENSOR input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ARDUPILOT_FACES",
    "PROXIMITY_TIMEOUT_S",
    "PX4_BINS",
    "Face",
    "ProximityReceiver",
]

PROXIMITY_TIMEOUT_S = 0.5  # AP_Proximity_MAV PROXIMITY_MAV_TIMEOUT_MS; PX4 RANGE_STREAM_TIMEOUT_US
ARDUPILOT_FACES = 8  # PROXIMITY_NUM_SECTORS: faces of 45°
PX4_BINS = 72  # CollisionPrevention BIN_COUNT (BIN_SIZE 5°)
_FILT_RESET_S = 1.0  # PROXIMITY_FILT_RESET_TIME 1000 ms
_UINT16_MAX = 65535
_MAV_FRAME_GLOBAL = 0
_MAV_FRAME_LOCAL_NED = 1
_MAV_FRAME_BODY_FRD = 12


@dataclass(frozen=True)
class Face:
    """One of ArduPilot's 45° faces with a reading: body bearing [rad, clockwise from the
    nose] and distance [m] of its nearest sector."""

    bearing_rad: float
    distance_m: float


@dataclass(frozen=True)
class _Reading:
    distances_cm: tuple[int, ...]
    increment_deg: float
    angle_offset_deg: float
    min_cm: int
    max_cm: int
    frame: int
    received_s: float


class ProximityReceiver:
    """The newest OBSTACLE_DISTANCE and the counts of what came and what was dropped."""

    def __init__(self) -> None:
        self._last: _Reading | None = None
        self.received = 0
        self.dropped = 0
        self.filter_hz = 0.25  # ArduPilot's PRX_FILT, set by the caller from its parameter
        self._faces: dict[int, Face] = {}  # ArduPilot's faces with a reading, filtered
        self._filtered_m: dict[int, float] = {}  # per face, kept while it has no reading
        self._face_set_s: dict[int, float] = {}  # when each face last had a reading
        self.px4_fov = np.zeros(PX4_BINS, dtype=bool)  # PX4 bins that have had a reading

    def on_message(self, msg, now_s: float) -> str | None:
        """Keep ``msg`` (an OBSTACLE_DISTANCE) received at wall time ``now_s``; returns
        why it was dropped, or None."""
        inc = float(msg.increment_f) if msg.increment_f != 0 else float(msg.increment)
        if not math.isfinite(inc) or inc == 0.0:
            self.dropped += 1
            return "OBSTACLE_DISTANCE: no valid increment"
        offset = float(msg.angle_offset)
        if not math.isfinite(offset):
            self.dropped += 1
            return "OBSTACLE_DISTANCE: angle_offset not finite"
        self.received += 1
        self._last = _Reading(
            tuple(int(d) for d in msg.distances),
            inc,
            offset,
            int(msg.min_distance),
            int(msg.max_distance),
            int(msg.frame),
            now_s,
        )
        self._set_faces(self._last, now_s)
        return None

    def _set_faces(self, r: _Reading, now_s: float) -> None:
        """ArduPilot's faces from reading ``r``: each face's nearest sector, its distance
        through the face's low-pass filter (module docstring); faces without one reset."""
        n = min(int(360.0 / abs(r.increment_deg) + 0.5), len(r.distances_cm))
        raw: dict[int, Face] = {}
        for j in range(n):
            d = r.distances_cm[j]
            if d == 0 or d == _UINT16_MAX or d < r.min_cm or d > r.max_cm:
                continue
            bearing_deg = (j * r.increment_deg + r.angle_offset_deg) % 360.0
            face = int(((bearing_deg + 22.5) % 360.0) // 45.0)
            if face not in raw or d * 0.01 < raw[face].distance_m:
                raw[face] = Face(math.radians(bearing_deg), d * 0.01)
        faces: dict[int, Face] = {}
        for k, face in raw.items():
            dt = now_s - self._face_set_s.get(k, -math.inf)
            filtered = face.distance_m
            if self.filter_hz > 0.0 and dt < _FILT_RESET_S:
                # LowPassFilterFloat::apply: alpha = dt / (dt + 1 / (2π·fc))
                alpha = dt / (dt + 1.0 / (2.0 * math.pi * self.filter_hz))
                filtered = self._filtered_m[k] + alpha * (face.distance_m - self._filtered_m[k])
            self._filtered_m[k] = filtered
            self._face_set_s[k] = now_s
            faces[k] = Face(face.bearing_rad, filtered)
        self._faces = faces

    def fresh(self, now_s: float) -> bool:
        """A message within the last 0.5 s (the driver's status is Good)."""
        return self._last is not None and now_s - self._last.received_s <= PROXIMITY_TIMEOUT_S

    def age_s(self, now_s: float) -> float:
        """Wall seconds since the newest message (inf: none yet)."""
        return math.inf if self._last is None else now_s - self._last.received_s

    def ardupilot_faces(self, now_s: float) -> list[Face]:
        """ArduPilot's faces with a reading, their distances filtered (none when the data
        is not fresh)."""
        if self._last is None or not self.fresh(now_s):
            return []
        return [self._faces[k] for k in sorted(self._faces)]

    def px4_bins(self, now_s: float, yaw_rad: float) -> tuple[np.ndarray, float]:
        """PX4's 72 body-frame bins [m] (inf where no data) and the sensor's range [m];
        all inf when the data is stale. Bins with a reading join :attr:`px4_fov`."""
        bins, range_m = self._px4_bins(now_s, yaw_rad)
        self.px4_fov |= np.isfinite(bins)
        return bins, range_m

    def _px4_bins(self, now_s: float, yaw_rad: float) -> tuple[np.ndarray, float]:
        bins = np.full(PX4_BINS, np.inf)
        r = self._last
        if r is None or not self.fresh(now_s):
            return bins, 0.0
        if r.frame in (_MAV_FRAME_GLOBAL, _MAV_FRAME_LOCAL_NED):
            rotate_deg = math.degrees(yaw_rad)
        elif r.frame == _MAV_FRAME_BODY_FRD:
            rotate_deg = 0.0
        else:
            return bins, 0.0  # "Obstacle message received in unsupported frame"
        for i in range(PX4_BINS):
            angle = (rotate_deg + 5.0 * i - r.angle_offset_deg) % 360.0
            k = math.ceil(angle / r.increment_deg - 1e-9)
            if not 0 <= k < len(r.distances_cm):
                continue
            d = r.distances_cm[k]
            if d != _UINT16_MAX:
                bins[i] = d * 0.01
        return bins, r.max_cm * 0.01
