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

__all__ = [
    "AutopilotClock",
    "BootTime",
    "BootTimeMonitor",
    "ClockModel",
    "FrameClock",
    "SyncResult",
    "SyncSample",
]


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

    def frame_time_plausible(
        self, capture_ns: int, host_ns: int, newest_telemetry_ns: int | None, window_ns: int
    ) -> bool | None:
        """True when ``capture_ns`` lies within ``window_ns`` of the frame clock's "now".

        "Now" comes from the clock model alone, never from frames: the host clock for
        host-stamped frames, the newest autopilot telemetry stamp for autopilot-stamped
        ones (None — no verdict, the frame cannot be placed — before there is any). A frame
        outside the window (stamped 0, 2^63−1, seconds off) is refused, so it cannot move
        the clock or look like a reboot.
        """
        now = host_ns if self.frame_clock is FrameClock.HOST else newest_telemetry_ns
        if now is None:
            return None
        return abs(int(capture_ns) - int(now)) <= window_ns

    def frame_to_autopilot_ns(self, frame_ns: int) -> int | None:
        """Inverse of :meth:`frame_ns_from_autopilot_ns` (setpoint timestamps)."""
        if self.frame_clock is FrameClock.AUTOPILOT:
            return int(frame_ns)
        return self.autopilot.autopilot_from_host(frame_ns)


class BootTime(enum.Enum):
    """What :meth:`BootTimeMonitor.check` decided for one telemetry timestamp."""

    ACCEPT = "accept"
    DROP = "drop"  # implausible against the current time base: ignore the message
    REBOOT = "reboot"  # confirmed: the autopilot's clock restarted


class BootTimeMonitor:
    """Plausibility of the autopilot's ``time_boot_ms``, and confirmed reboots.

    A timestamp is *consistent* when it lies between ``backstep_ms`` before the newest one
    and as far ahead as the host time elapsed since (× the autopilot clock rate, × 2, plus
    ``slack_ms``) allows. Consistent stamps are accepted. An inconsistent one is dropped,
    unless ``confirm`` inconsistent stamps in a row agree with each other: then they are a
    new time base — a reboot when they went backwards. So one forged or corrupt stamp (0,
    2^32−1, far ahead) neither resets the mission nor moves the clock.

    Parameters are in milliseconds of autopilot time; ``host_s`` and ``rate`` (autopilot
    seconds per host second) are passed in by the caller.
    """

    def __init__(self, *, backstep_ms: int = 500, slack_ms: int = 2000, confirm: int = 3) -> None:
        self.backstep_ms = backstep_ms
        self.slack_ms = slack_ms
        self.confirm = confirm
        self.reset()

    def reset(self) -> None:
        self.last_ms: int | None = None
        self._last_host_s = 0.0
        self._candidates: list[tuple[int, float]] = []
        self.dropped = 0

    def _consistent(self, t_ms: int, ref_ms: int, ref_host_s: float, host_s: float, rate: float):
        ahead = max(0.0, host_s - ref_host_s) * max(rate, 1.0) * 2000.0 + self.slack_ms
        return ref_ms - self.backstep_ms <= t_ms <= ref_ms + ahead

    def check(self, time_boot_ms: int, host_s: float, rate: float = 1.0) -> BootTime:
        t = int(time_boot_ms)
        if self.last_ms is None:
            self.last_ms, self._last_host_s = t, host_s
            return BootTime.ACCEPT
        if self._consistent(t, self.last_ms, self._last_host_s, host_s, rate):
            self.last_ms = max(self.last_ms, t)
            self._last_host_s = host_s
            self._candidates.clear()
            return BootTime.ACCEPT
        cands = self._candidates
        if cands and not self._consistent(t, cands[-1][0], cands[-1][1], host_s, rate):
            cands.clear()
        cands.append((t, host_s))
        if len(cands) < self.confirm:
            self.dropped += 1
            return BootTime.DROP
        went_back = t < self.last_ms
        self.last_ms, self._last_host_s = max(c[0] for c in cands), host_s
        cands.clear()
        return BootTime.REBOOT if went_back else BootTime.ACCEPT
