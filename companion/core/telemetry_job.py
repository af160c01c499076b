"""Telemetry into the pose history, on one clock with the frames.

A mixin of :class:`~companion.core.CompanionCore`. GPS_RAW_INT's ``h_acc`` is the
accuracy the autopilot states for its position (it widens the margins,
:mod:`companion.position_uncertainty`). LOCAL_POSITION_NED and ATTITUDE go
into the pose history at their ``time_boot_ms`` mapped onto the frame clock
(:mod:`companion.clock_model`); a ``time_boot_ms`` that jumps back is a reboot once
confirmed, an implausible one is dropped and counted. The streams and TIMESYNC are
:class:`~companion.core.streams_job.StreamsJob`'s; a TIMESYNC answer's sample goes to the
autopilot's clock here.
"""

from __future__ import annotations

import math

from companion.clock_model import BootTime, SyncResult

#: a stated accuracy older than this is not used (GPS_RAW_INT streams at 1-5 Hz) [s]
H_ACC_MAX_AGE_S = 5.0
REBOOT_BACKSTEP_MS = 500  # time_boot_ms going back this far: the autopilot restarted
MAX_POS_M = 1e5  # |LOCAL_NED| beyond this is not a position of a multirotor
_MAX_SPEED_MPS = 300.0


def in_range(values, bound: float) -> bool:
    """Every value finite and within ±``bound``."""
    return all(math.isfinite(v) and abs(v) <= bound for v in values)


__all__ = [
    "H_ACC_MAX_AGE_S",
    "MAX_POS_M",
    "REBOOT_BACKSTEP_MS",
    "TelemetryJob",
    "in_range",
]


class TelemetryJob:
    """Poses on the frame clock and the autopilot's boot time.

    Owns ``clock``, ``poses``, ``boot_time``, ``_telemetry_newest_ns``,
    ``_newest_seen_ns``, ``_last_boot_ms``, ``_position_host_ns``, ``_h_acc``.
    """

    def _telemetry_seen(self, t_ns: int) -> None:
        """The newest autopilot telemetry stamp on the frame clock: the clock's "now"."""
        if self._telemetry_newest_ns is None or t_ns > self._telemetry_newest_ns:
            self._telemetry_newest_ns = t_ns

    def _observe(self, t_ns: int) -> None:
        if self._newest_seen_ns is None or t_ns > self._newest_seen_ns:
            self._newest_seen_ns = t_ns

    def _check_boot_time(self, time_boot_ms: int, now_s: float) -> bool:
        """Plausible autopilot time (True), an implausible stamp (dropped, False), or a
        confirmed reboot (state reset, then True: the stamp starts the new time base)."""
        last = self.boot_time.last_ms
        verdict = self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        if verdict is BootTime.DROP:
            self.counters.telemetry_implausible_time += 1
            self._log_drop(
                "telemetry_implausible_time",
                self.counters.telemetry_implausible_time,
                "time_boot_ms",
                (last, time_boot_ms),
            )
            return False
        if verdict is BootTime.REBOOT:
            self._autopilot_restarted(now_s, f"time_boot_ms {last} → {time_boot_ms}")
            self.boot_time.check(time_boot_ms, now_s, self.clock.autopilot.rate)
        self._last_boot_ms = self.boot_time.last_ms
        return True

    def _on_local_position(self, msg, now_s: float) -> None:
        pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
        if not in_range(pos, MAX_POS_M) or not in_range(vel, _MAX_SPEED_MPS):
            self.counters.telemetry_out_of_range += 1
            self._log_drop(
                "telemetry_out_of_range",
                self.counters.telemetry_out_of_range,
                "LOCAL_POSITION_NED",
                pos + vel,
            )
        elif self._check_boot_time(msg.time_boot_ms, now_s):
            t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
            if t is None:
                self.counters.telemetry_unmapped += 1
            elif self.poses.add_position(t, pos, vel):
                self._position_host_ns = self._now_ns  # proximity: its age at a send
                self._observe(t)
                self._telemetry_seen(t)

    def _on_attitude(self, msg, now_s: float) -> None:
        angles = (msg.roll, msg.pitch, msg.yaw)
        if not in_range(angles, 2.0 * math.pi):
            self.counters.telemetry_out_of_range += 1
            self._log_drop(
                "telemetry_out_of_range", self.counters.telemetry_out_of_range, "ATTITUDE", angles
            )
        elif self._check_boot_time(msg.time_boot_ms, now_s):
            t = self.clock.frame_ns_from_boot_ms(msg.time_boot_ms)
            if t is None:
                self.counters.telemetry_unmapped += 1
            elif self.poses.add_attitude(t, *angles):
                self._observe(t)
                self._telemetry_seen(t)

    def _on_gps_raw(self, msg, now_s: float) -> None:
        """GPS_RAW_INT ``h_acc`` [mm]: the accuracy the autopilot states for its position
        (0: none stated), which widens the margins (:mod:`companion.position_uncertainty`)."""
        h_acc_mm = getattr(msg, "h_acc", 0)  # a MAVLink 1 frame has no extension fields
        self._h_acc = (h_acc_mm * 1e-3, now_s) if h_acc_mm and h_acc_mm < 0xFFFFFFFF else None

    def _stated_h_acc_m(self, now_s: float) -> float | None:
        """The autopilot's stated horizontal accuracy [m], None if none or stale."""
        if self._h_acc is None or now_s - self._h_acc[1] > H_ACC_MAX_AGE_S:
            return None
        return self._h_acc[0]

    def _log_drop(self, kind: str, count: int, what: str, values) -> None:
        """One warning per ``kind`` every 2 s for an input dropped ``count`` times."""
        self.out.drop_log(kind, "%s: dropped %s %s (%d so far)", kind, what, values, count)

    def _on_timesync(self, msg, now_s: float) -> None:
        """TIMESYNC (:class:`~companion.core.streams_job.StreamsJob`); an answer to our
        request is a sample of the autopilot's clock."""
        sample = self.streams.on_timesync(msg, self._now_ns)
        if sample is None:
            return
        if self.clock.autopilot.add_sample(sample) is SyncResult.REBOOT:
            self._autopilot_restarted(now_s, "TIMESYNC went backwards")
