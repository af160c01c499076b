"""Clock model: the autopilot's boot time mapped onto the clock that stamps stereo frames.

Pure (no clocks are read here; callers pass ``host_ns`` from ``time.monotonic_ns()``).

Three clocks meet in the companion (DESIGN.md "One clock for frames and poses"):

* host — this computer's ``time.monotonic_ns()``;
* autopilot — ``time_boot_ms`` of its telemetry and ``tc1`` of its TIMESYNC replies
  (plant-sim: simulation time, which runs ``--speedup`` times faster than the host);
* frame — whatever stamps ``capture_ns``: the autopilot clock in the SIL
  (:attr:`FrameClock.AUTOPILOT`), or the host clock with a real camera
  (:attr:`FrameClock.HOST`).

:class:`AutopilotClock` fits ``autopilot_ns ≈ offset + rate · host_ns`` to TIMESYNC round
trips (rate ≈ 1 for real hardware, = speedup for plant-sim); :class:`ClockModel` uses it
for both cases with the same calls: telemetry time → frame clock (poses), frame clock →
autopilot time (setpoint stamps), and "now" on the frame clock (failsafe ages).
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass

__all__ = ["AutopilotClock", "ClockModel", "FrameClock", "SyncResult", "SyncSample"]


class FrameClock(enum.Enum):
    """Which clock stamps the stereo frames' ``capture_ns``."""

    AUTOPILOT = "autopilot"  # the autopilot's boot clock (plant-sim: simulation time)
    HOST = "host"  # this host's time.monotonic_ns(); autopilot time mapped with TIMESYNC


class SyncResult(enum.Enum):
    """What :meth:`AutopilotClock.add_sample` did with a round trip."""

    ACCEPTED = "accepted"
    REJECTED = "rejected"  # round trip too long or inconsistent; ignored
    REBOOT = "reboot"  # autopilot time went backwards: the model was reset to this sample


@dataclass(frozen=True)
class SyncSample:
    """One TIMESYNC round trip: request sent / reply received (host), autopilot time."""

    host_send_ns: int
    autopilot_ns: int
    host_recv_ns: int

    @property
    def host_mid_ns(self) -> float:
        return 0.5 * (self.host_send_ns + self.host_recv_ns)

    @property
    def rtt_ns(self) -> int:
        return self.host_recv_ns - self.host_send_ns


class AutopilotClock:
    """Linear fit ``autopilot_ns = offset + rate · host_ns`` over recent TIMESYNC samples.

    Parameters
    ----------
    window : int
        Samples kept for the fit.
    max_rtt_ns : int
        Round trips longer than this are rejected (their midpoint is too uncertain).
    min_span_ns : int
        Host-time span of the kept samples before the rate is fitted; until then the rate
        is ``default_rate``.
    reboot_backstep_ns : int
        Autopilot time going back by more than this means the autopilot restarted.
    """

    def __init__(
        self,
        *,
        window: int = 20,
        max_rtt_ns: int = 200_000_000,
        min_span_ns: int = 300_000_000,
        default_rate: float = 1.0,
        reboot_backstep_ns: int = 200_000_000,
    ) -> None:
        self._samples: deque[SyncSample] = deque(maxlen=window)
        self._max_rtt_ns = max_rtt_ns
        self._min_span_ns = min_span_ns
        self._default_rate = default_rate
        self._reboot_backstep_ns = reboot_backstep_ns
        self._rate = default_rate
        self._offset_ns = 0.0
        self.reboots = 0

    @property
    def synced(self) -> bool:
        """True once at least one round trip was accepted."""
        return bool(self._samples)

    @property
    def rate(self) -> float:
        """Autopilot seconds per host second (plant-sim: its speedup)."""
        return self._rate

    def reset(self) -> None:
        self._samples.clear()
        self._rate = self._default_rate
        self._offset_ns = 0.0

    def add_sample(self, sample: SyncSample) -> SyncResult:
        """Add a round trip and refit."""
        if sample.rtt_ns < 0 or sample.rtt_ns > self._max_rtt_ns or sample.autopilot_ns < 0:
            return SyncResult.REJECTED
        result = SyncResult.ACCEPTED
        if self._samples:
            last = self._samples[-1]
            if sample.autopilot_ns < last.autopilot_ns - self._reboot_backstep_ns:
                self.reset()
                self.reboots += 1
                result = SyncResult.REBOOT
            elif sample.host_mid_ns <= last.host_mid_ns:
                return SyncResult.REJECTED
        self._samples.append(sample)
        self._fit()
        return result

    def _fit(self) -> None:
        s = self._samples
        span = s[-1].host_mid_ns - s[0].host_mid_ns
        if len(s) >= 3 and span >= self._min_span_ns:
            # least squares on centred data (ns magnitudes stay well inside float precision)
            h0, a0 = s[0].host_mid_ns, float(s[0].autopilot_ns)
            xs = [x.host_mid_ns - h0 for x in s]
            ys = [x.autopilot_ns - a0 for x in s]
            mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
            sxx = sum((x - mx) ** 2 for x in xs)
            sxy = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True))
            if sxx > 0 and sxy > 0:
                self._rate = sxy / sxx
                self._offset_ns = a0 + my - self._rate * (h0 + mx)
                return
        # too few samples for a rate: the shortest round trip sets the offset
        best = min(s, key=lambda x: x.rtt_ns)
        self._offset_ns = best.autopilot_ns - self._rate * best.host_mid_ns

    def autopilot_from_host(self, host_ns: int) -> int | None:
        """Autopilot time at host time ``host_ns``; None before the first sample."""
        if not self._samples:
            return None
        return round(self._offset_ns + self._rate * host_ns)

    def host_from_autopilot(self, autopilot_ns: int) -> int | None:
        """Host time at autopilot time ``autopilot_ns``; None before the first sample."""
        if not self._samples:
            return None
        return round((autopilot_ns - self._offset_ns) / self._rate)


class ClockModel:
    """Autopilot ``time_boot_ms`` → frame clock, and "now" on the frame clock.

    The same calls serve the SIL (frames on the autopilot's clock: identity) and real
    hardware (frames on the host clock: through the TIMESYNC fit).
    """

    def __init__(self, frame_clock: FrameClock, autopilot: AutopilotClock | None = None) -> None:
        self.frame_clock = FrameClock(frame_clock)
        self.autopilot = autopilot or AutopilotClock()

    def frame_ns_from_autopilot_ns(self, autopilot_ns: int) -> int | None:
        """A telemetry timestamp on the frame clock; None if it cannot be mapped yet."""
        if self.frame_clock is FrameClock.AUTOPILOT:
            return int(autopilot_ns)
        return self.autopilot.host_from_autopilot(autopilot_ns)

    def frame_ns_from_boot_ms(self, time_boot_ms: int) -> int | None:
        """``time_boot_ms`` of a telemetry message on the frame clock (or None)."""
        return self.frame_ns_from_autopilot_ns(int(time_boot_ms) * 1_000_000)

    def now_frame_ns(self, host_ns: int, newest_observed_ns: int | None) -> int | None:
        """The frame clock's current time; None when it cannot be known yet.

        ``newest_observed_ns`` is the newest frame-clock timestamp seen on the wire (pose or
        frame capture). With frames on the autopilot's clock that observation *is* "now":
        a paced simulator may stall, and its own stamps are the only exact simulation clock
        (an extrapolation would count a stall as age and trip the failsafe). With frames
        on the host clock, now is the host's time.
        """
        if self.frame_clock is FrameClock.HOST:
            return int(host_ns)
        return newest_observed_ns

    def now_autopilot_ns(self, host_ns: int) -> int | None:
        return self.autopilot.autopilot_from_host(host_ns)

    def frame_to_autopilot_ns(self, frame_ns: int) -> int | None:
        """Inverse of :meth:`frame_ns_from_autopilot_ns` (setpoint timestamps)."""
        if self.frame_clock is FrameClock.AUTOPILOT:
            return int(frame_ns)
        return self.autopilot.autopilot_from_host(frame_ns)
