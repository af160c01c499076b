"""Telemetry: poses on the frame clock, the autopilot's boot time and stated accuracy.

A component of :class:`~companion.core.CompanionCore` that owns its state: the clock model
(:mod:`companion.clock_model`; the frame clock and the autopilot's TIMESYNC fit), the pose
history, the autopilot's boot time, the newest stamps seen on the frame clock, and the
accuracy the autopilot states for its position (GPS_RAW_INT ``h_acc``, which widens the
margins, :mod:`companion.position_uncertainty`). Typed in: LOCAL_POSITION_NED, ATTITUDE,
GPS_RAW_INT, a TIMESYNC :class:`~companion.clock_model.SyncSample`, the capture times of
frames. Out: dropped inputs counted (and logged through the step's
:class:`~companion.core.outbox.Outbox`), and a :class:`Restarted` when the autopilot's
time went back for good: this job has already started the new time base (the message
that showed it is kept), and the core resets what the other jobs learnt of the vehicle.

A ``time_boot_ms`` that jumps back is a reboot once confirmed
(:class:`~companion.clock_model.BootTimeMonitor`); an implausible one is dropped and
counted; values out of range are dropped and counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.clock_model import (
    BootTime,
    BootTimeMonitor,
    ClockModel,
    FrameClock,
    SyncResult,
    SyncSample,
)
from companion.config import FailsafeConfig, LinkConfig
from companion.core.counters import CoreCounters
from companion.core.outbox import Outbox
from companion.pose_history import PoseHistory

#: a stated accuracy older than this is not used (GPS_RAW_INT streams at 1-5 Hz) [s]
H_ACC_MAX_AGE_S = 5.0
REBOOT_BACKSTEP_MS = 500  # time_boot_ms going back this far: the autopilot restarted
MAX_POS_M = 1e5  # |LOCAL_NED| beyond this is not a position of a multirotor
_MAX_SPEED_MPS = 300.0
_RATE_BOUNDS = (0.01, 1000.0)  # frame-clock seconds per host second we believe


def in_range(values, bound: float) -> bool:
    """Every value finite and within ±``bound``."""
    return all(math.isfinite(v) and abs(v) <= bound for v in values)


__all__ = [
    "H_ACC_MAX_AGE_S",
    "MAX_POS_M",
    "REBOOT_BACKSTEP_MS",
    "Restarted",
    "TelemetryJob",
    "in_range",
]


@dataclass(frozen=True)
class Restarted:
    """The autopilot restarted: its new time base is started, the rest must start over."""

    reason: str


class TelemetryJob:
    """Poses on the frame clock, the autopilot's boot time and its stated accuracy.

    Parameters
    ----------
    link : LinkConfig
        ``frame_clock``: which clock frames are stamped with.
    failsafe : FailsafeConfig
        The pose history's horizon and extrapolation, the frame time window.
    out : Outbox
        Where drop warnings go (the core's, per step).
    counters : CoreCounters
        ``telemetry_out_of_range``, ``telemetry_implausible_time``, ``telemetry_unmapped``.
    """

    def __init__(
        self, link: LinkConfig, failsafe: FailsafeConfig, out: Outbox, counters: CoreCounters
    ) -> None:
        self._out = out
        self._counters = counters
        self._frame_time_window_ns = round(failsafe.frame_time_window_s * 1e9)
        self.clock = ClockModel(link.frame_clock)
        self.poses = PoseHistory(
            horizon_ns=round(failsafe.pose_history_s * 1e9),
            max_extrapolation_ns=round(failsafe.max_pose_extrapolation_s * 1e9),
        )
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: the poses, the clock fit and boot time go."""
        self.clock.autopilot.reset()
        self.poses.clear()
        self.boot_time = BootTimeMonitor(backstep_ms=REBOOT_BACKSTEP_MS)
        self.last_boot_ms: int | None = None  # the newest plausible time_boot_ms
        self.telemetry_newest_ns: int | None = None  # read by the Zenoh thread too
        self.newest_seen_ns: int | None = None  # newest frame-clock stamp observed
        self.position_host_ns: int | None = None  # host time the newest position came
        self._h_acc: tuple[float, float] | None = None  # h_acc [m], when it came [s, host]

    # ---- the frame clock -----------------------------------------------------------
    def observe(self, t_ns: int) -> None:
        """A frame-clock stamp seen on the wire (telemetry or a frame's capture time)."""
        if self.newest_seen_ns is None or t_ns > self.newest_seen_ns:
            self.newest_seen_ns = t_ns

    def now_frame_ns(self, now_ns: int) -> int | None:
        """The frame clock's time at host time ``now_ns`` (None: not known yet)."""
        return self.clock.now_frame_ns(now_ns, self.newest_seen_ns)

    def frame_time_plausible(self, capture_ns: int, now_ns: int) -> bool | None:
        """Capture time within the window around the clock model's now (any thread)."""
        return self.clock.frame_time_plausible(
            capture_ns, now_ns, self.telemetry_newest_ns, self._frame_time_window_ns
        )

    def frame_clock_rate(self) -> float:
        """Frame-clock seconds per host second (plant-sim at --speedup N: N)."""
        if self.clock.frame_clock is FrameClock.HOST:
            return 1.0
        rate = self.clock.autopilot.rate
        return min(max(rate, _RATE_BOUNDS[0]), _RATE_BOUNDS[1]) if math.isfinite(rate) else 1.0

    # ---- messages --------------------------------------------------------------------
    def on_local_position(self, msg, now_s: float, now_ns: int) -> Restarted | None:
        """LOCAL_POSITION_NED at host time ``now_s`` / ``now_ns`` into the pose history."""
        pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
        if not in_range(pos, MAX_POS_M) or not in_range(vel, _MAX_SPEED_MPS):
            self._counters.telemetry_out_of_range += 1
            self._out.dropped(
                "telemetry_out_of_range",
                self._counters.telemetry_out_of_range,
                "LOCAL_POSITION_NED",
                pos + vel,
            )
            return None
        ok, restarted = self._check_boot_time(msg.time_boot_ms, now_s)
        if ok:
            t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
            if t is None:
                self._counters.telemetry_unmapped += 1
            elif self.poses.add_position(t, pos, vel):
                self.position_host_ns = now_ns  # proximity: its age at a send
                self._seen(t)
        return restarted

    def on_attitude(self, msg, now_s: float) -> Restarted | None:
        """ATTITUDE at host time ``now_s`` into the pose history."""
        angles = (msg.roll, msg.pitch, msg.yaw)
        if not in_range(angles, 2.0 * math.pi):
            self._counters.telemetry_out_of_range += 1
            self._out.dropped(
                "telemetry_out_of_range", self._counters.telemetry_out_of_range, "ATTITUDE", angles
            )
            return None
        ok, restarted = self._check_boot_time(msg.time_boot_ms, now_s)
        if ok:
            t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
            if t is None:
                self._counters.telemetry_unmapped += 1
            elif self.poses.add_attitude(t, *angles):
                self._seen(t)
        return restarted

    def newest_pose(self):
        """(frame-clock time, host time its position was read, pose) of the newest complete
        pose; None before one (the OBSTACLE_DISTANCE process places the vehicle with it,
        :mod:`companion.proximity.process`)."""
        newest, host_ns = self.poses.newest_ns, self.position_host_ns
        if newest is None or host_ns is None:
            return None
        pose = self.poses.at(newest).pose
        return None if pose is None else (newest, host_ns, pose)

    def on_gps_raw(self, msg, now_s: float) -> None:
        """GPS_RAW_INT ``h_acc`` [mm]: the accuracy the autopilot states for its position
        (0 or UINT32_MAX: none stated)."""
        h_acc_mm = getattr(msg, "h_acc", 0)  # a MAVLink 1 frame has no extension fields
        self._h_acc = (h_acc_mm * 1e-3, now_s) if h_acc_mm and h_acc_mm < 0xFFFFFFFF else None

    def stated_h_acc_m(self, now_s: float) -> float | None:
        """The autopilot's stated horizontal accuracy [m], None if none or stale."""
        if self._h_acc is None or now_s - self._h_acc[1] > H_ACC_MAX_AGE_S:
            return None
        return self._h_acc[0]

    def on_sync_sample(self, sample: SyncSample) -> Restarted | None:
        """An answer to our TIMESYNC request (:class:`~companion.core.streams_job.StreamsJob`):
        a sample of the autopilot's clock; going backwards, a restart."""
        if self.clock.autopilot.add_sample(sample) is not SyncResult.REBOOT:
            return None
        self.reset()
        return Restarted("TIMESYNC went backwards")

    # ---- internals -------------------------------------------------------------------
    def _seen(self, t_ns: int) -> None:
        """Telemetry at ``t_ns``: observed, and the newest telemetry (the clock's "now")."""
        self.observe(t_ns)
        if self.telemetry_newest_ns is None or t_ns > self.telemetry_newest_ns:
            self.telemetry_newest_ns = t_ns

    def _check_boot_time(self, time_boot_ms: int, now_s: float) -> tuple[bool, Restarted | None]:
        """(usable, restart): plausible autopilot time; an implausible stamp (dropped); or a
        confirmed reboot (this job starts over and the stamp starts the new time base)."""
        last = self.boot_time.last_ms
        verdict = self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        if verdict is BootTime.DROP:
            self._counters.telemetry_implausible_time += 1
            self._out.dropped(
                "telemetry_implausible_time",
                self._counters.telemetry_implausible_time,
                "time_boot_ms",
                (last, time_boot_ms),
            )
            return False, None
        restarted = None
        if verdict is BootTime.REBOOT:
            restarted = Restarted(f"time_boot_ms {last} → {time_boot_ms}")
            self.reset()
            self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        self.last_boot_ms = self.boot_time.last_ms
        return True, restarted
