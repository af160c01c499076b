"""When the companion sends OBSTACLE_DISTANCE, and what: always on the wire.

The autopilot's proximity driver declares "No Data" 0.5 s after the last message
(ArduPilot ``AP_Proximity_MAV``: ``PROXIMITY_MAV_TIMEOUT_MS``; PX4 Collision Prevention:
``RANGE_STREAM_TIMEOUT_US``), and ArduCopter refuses to arm on it ("PRX1: No Data"). So
the message goes out from start-up, before takeoff, in every mode and whether or not the
companion steers, at no less than :attr:`ProximityConfig.rate_hz`:

* each processed frame sends the sectors of the map it just updated, stamped with the
  frame's capture time, seen from where the vehicle is at the send (below): the vehicle
  moved while the frame was processed, and the distances are from where it is, so the
  processing latency does not add to the autopilot's reaction;
* a timer fills every gap longer than the period (before the first frame, during a
  takeoff, when frames stop): the same map (it remembers; it does not age) from where
  the vehicle is at the send, stamped with the capture time of the newest depth in the
  map; before any depth, every sector is unknown (``UINT16_MAX``) — honest, and enough
  for ArduCopter's pre-arm check; PX4 will not move in Position mode on it
  (``CP_GO_NO_DATA = 0``), which is what it should do.

**Where the vehicle is at the send** (:func:`position_at_send`): the map is in LOCAL_NED
and the autopilot reads each sector as a distance from where the vehicle is when the
message arrives (``AP_Proximity_MAV::handle_obstacle_distance_msg`` stores it against its
own receipt time; ``time_usec`` is not read). So the newest telemetry position is carried
forward with its velocity over the time since it arrived (the companion's own delay:
a loaded processor, a long frame): at 8 m/s every 0.1 s of it is 0.8 m the autopilot
would otherwise think it has left. A position older than :data:`POSE_STALE_S` is not
carried forward: the vehicle could be anywhere, and the sectors are sent unknown
(never clear, never an obstacle where there is none) until telemetry returns.

Pure: the caller passes the wall time (``now_s``) and the map; no clock, no I/O. In the
companion process a watchdog thread (:mod:`companion.proximity.stream`) also sends when
the main loop has sent nothing for 1.5 periods (a long frame, a starved processor): the
figures are kept under a lock, as both count while the main loop reads them.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from typing import Any

import numpy as np

from companion.known_space import KnownSpace
from companion.proximity.sectors import (
    ProximityConfig,
    ProximitySectors,
    map_reach_m,
    sectors_from_map,
    unknown_sectors,
)

__all__ = ["POSE_STALE_S", "ProximitySender", "pose_age_s", "position_at_send"]

#: Telemetry older than this [s wall] no longer places the vehicle in the map: the
#: autopilots' own proximity timeout (ArduPilot ``PROXIMITY_MAV_TIMEOUT_MS``, PX4
#: ``RANGE_STREAM_TIMEOUT_US``: 0.5 s) — sectors from an older position are not trusted.
POSE_STALE_S = 0.5
_RATE_WINDOW_S = 2.0  # the send rate is measured over this much wall time
_SLACK_S = 1e-3  # [s wall]


def position_at_send(pos_ned_m, vel_ned_mps, age_s: float) -> np.ndarray | None:
    """Where the vehicle is at the send [m, LOCAL_NED]: the telemetry position
    ``pos_ned_m`` carried forward by its velocity over ``age_s`` [s] since it arrived;
    None when it is older than :data:`POSE_STALE_S` (or not finite): not usable."""
    p = np.asarray(pos_ned_m, dtype=float)
    v = np.asarray(vel_ned_mps, dtype=float)
    if not (math.isfinite(age_s) and 0.0 <= age_s <= POSE_STALE_S):
        return None
    out = p + v * age_s
    return out if np.all(np.isfinite(out)) else None


def pose_age_s(
    now_ns: int, received_ns: int, frame_ns: int, rate: float, host_frame_clock: bool
) -> float:
    """Age of a pose at host time ``now_ns`` [s, frame clock]: the host time since its
    position was read (``received_ns``) × the frame clock's ``rate``; with frames on the
    host clock (``host_frame_clock``; ``frame_ns`` is then the autopilot's own stamp mapped
    by TIMESYNC) at least ``now_ns − frame_ns``, which also counts the time the message
    waited in the socket for a busy reader. On the autopilot's clock (the SIL) that second
    figure is not used: a paced simulator may stall, and its stamps cannot be compared
    with the host's (:meth:`~companion.clock_model.ClockModel.now_frame_ns`)."""
    age_s = (now_ns - received_ns) * 1e-9 * rate
    if host_frame_clock:
        age_s = max(age_s, (now_ns - frame_ns) * 1e-9)
    return age_s


class ProximitySender:
    """Schedules OBSTACLE_DISTANCE and keeps its figures for the status.

    Parameters
    ----------
    config : ProximityConfig
    """

    def __init__(self, config: ProximityConfig) -> None:
        self.config = config
        self.period_s = 1.0 / config.rate_hz
        self.sent = 0
        self.from_frames = 0
        self.stale_pose = 0  # sends all unknown because telemetry was older than 0.5 s
        # sends more than POSE_STALE_S (the autopilots' 0.5 s proximity timeout) after the
        # previous one: the autopilot had dropped the data meanwhile (a starved companion)
        self.late = 0
        self.longest_gap_s = 0.0
        self.last: ProximitySectors | None = None
        self._last_send_s = float("-inf")
        self._times: deque[float] = deque()
        self._lock = threading.Lock()

    def due(self, now_s: float) -> bool:
        """The timer must send now (nothing went out for a period, less a millisecond
        of slack so that a caller ticking at a divisor of the period keeps the rate)."""
        return now_s - self._last_send_s >= self.period_s - _SLACK_S

    def since_send_s(self, now_s: float) -> float:
        """Seconds since the last send (inf: none yet)."""
        with self._lock:
            return now_s - self._last_send_s

    def count_stale_pose(self) -> None:
        """One send made all unknown because the position was too old."""
        with self._lock:
            self.stale_pose += 1

    def on_frame(
        self, space: KnownSpace, pos_ned_m, yaw_rad: float | None, now_s: float
    ) -> ProximitySectors:
        """Sectors of the map just updated by a frame, at the vehicle's position at the
        send (None: stale → all unknown)."""
        with self._lock:
            self.from_frames += 1
        return self.on_timer(space, pos_ned_m, yaw_rad, now_s)

    def on_timer(
        self, space: KnownSpace | None, pos_ned_m, yaw_rad: float | None, now_s: float
    ) -> ProximitySectors:
        """Sectors at the vehicle's position at the send (None: not known yet, or stale →
        all unknown)."""
        if space is None or space.frames == 0 or pos_ned_m is None or yaw_rad is None:
            reach = 0.0 if space is None else map_reach_m(space)
            return self._sent(unknown_sectors(self.config, reach), now_s)
        return self._sent(sectors_from_map(space, pos_ned_m, yaw_rad, self.config), now_s)

    def figures(self, now_s: float) -> dict[str, Any]:
        """Message count, send rate over the last 2 s [Hz wall] and the last sectors."""
        with self._lock:
            return self._figures(now_s)

    def _figures(self, now_s: float) -> dict[str, Any]:
        self._trim(now_s)
        counts = (None, None, None) if self.last is None else self.last.counts()
        return {
            "sent": self.sent,
            "from_frames": self.from_frames,
            "stale_pose": self.stale_pose,
            "late": self.late,
            "longest_gap_s": round(self.longest_gap_s, 3),
            "rate_hz": round(len(self._times) / _RATE_WINDOW_S, 2),
            "obstacle_sectors": counts[0],
            "clear_sectors": counts[1],
            "unknown_sectors": counts[2],
            "nearest_m": None if self.last is None else self._nearest_m(self.last),
        }

    def _sent(self, sectors: ProximitySectors, now_s: float) -> ProximitySectors:
        with self._lock:
            self._count_sent(sectors, now_s)
        return sectors

    def _count_sent(self, sectors: ProximitySectors, now_s: float) -> None:
        gap_s = now_s - self._last_send_s
        if math.isfinite(gap_s):
            self.longest_gap_s = max(self.longest_gap_s, gap_s)
            if gap_s > POSE_STALE_S:
                self.late += 1
        self.sent += 1
        self.last = sectors
        self._last_send_s = now_s
        self._times.append(now_s)
        self._trim(now_s)

    def _trim(self, now_s: float) -> None:
        while self._times and self._times[0] <= now_s - _RATE_WINDOW_S:
            self._times.popleft()

    @staticmethod
    def _nearest_m(sectors: ProximitySectors) -> float | None:
        d = sectors.distances_cm[: sectors.n_sectors]
        seen = d[d <= sectors.max_distance_cm]
        return None if seen.size == 0 else round(float(seen.min()) / 100.0, 2)
