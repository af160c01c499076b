"""Health that means "steering is possible", for container healthchecks and supervisors.

The companion (``--health-file PATH``) rewrites one small JSON file about once a second,
atomically (write + rename)::

    {"healthy": false, "state": "no_telemetry", "reason": "autopilot heartbeats but no new
     LOCAL_POSITION_NED/ATTITUDE for 4.0 s", "time_unix": 1763937000.1, "pid": 7}

It is healthy only while autopilot heartbeats and telemetry (poses) arrive, and, once the
companion steers or holds the vehicle, stereo frames too. ``--ready-file`` stays what it
was (sockets bound); this file is the other question: can it steer *now*?

``python -m companion.health PATH [--max-age S]`` is the healthcheck: it prints the state
and reason and exits 0 when healthy, 1 when not, when the file is missing, or when it is
older than ``--max-age`` (the companion stopped rewriting it: hung or gone).

Only the standard library is imported here: a healthcheck runs every few seconds.
"""

from __future__ import annotations

import argparse
import enum
import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "HealthFile",
    "HealthInputs",
    "HealthReport",
    "HealthState",
    "HealthTracker",
    "check",
    "main",
]


class HealthState(enum.Enum):
    """Why the companion can or cannot steer (the file's ``state``)."""

    OK = "ok"
    NO_AUTOPILOT = "no_autopilot"  # nothing from the autopilot yet, or no heartbeat
    LINK_LOST = "link_lost"  # it was there, now nothing arrives
    NO_TELEMETRY = "no_telemetry"  # heartbeats, but no (new) LOCAL_POSITION_NED/ATTITUDE
    NO_FRAMES = "no_frames"  # steering or holding, but no (new) stereo frame
    FATAL = "fatal"  # a terminal error (a refused takeoff): the service stops
    STOPPED = "stopped"  # the service has stopped


@dataclass(frozen=True)
class HealthInputs:
    """What the service already knows, sampled once per report (wall clock: monotonic s)."""

    now_s: float
    link_up: bool  # an autopilot message within the link timeout
    autopilot_seen: bool  # an autopilot heartbeat since the (re)connection
    link_url: str
    telemetry_stamp_ns: int | None  # newest pose time (any clock), None: none yet
    frames_received: int  # frames received on our key, ever
    flying: bool  # the companion steers or holds the vehicle: frames are needed
    fatal: str | None = None  # a terminal error: the service stops


@dataclass(frozen=True)
class HealthReport:
    healthy: bool
    state: HealthState
    reason: str  # one line for people


class HealthTracker:
    """Turns :class:`HealthInputs` samples into a :class:`HealthReport`.

    Telemetry and frames count as arriving while their stamp/counter advanced within
    ``telemetry_timeout_s`` / ``frame_timeout_s`` of wall time.
    """

    def __init__(self, telemetry_timeout_s: float = 2.0, frame_timeout_s: float = 2.0) -> None:
        if not (telemetry_timeout_s > 0 and frame_timeout_s > 0):
            raise ValueError("health timeouts must be > 0")
        self.telemetry_timeout_s = telemetry_timeout_s
        self.frame_timeout_s = frame_timeout_s
        self._stamp: int | None = None
        self._stamp_s: float | None = None
        self._frames = 0
        self._frames_s: float | None = None
        self._ever_up = False

    def update(self, x: HealthInputs) -> HealthReport:
        if x.telemetry_stamp_ns is not None and x.telemetry_stamp_ns != self._stamp:
            self._stamp, self._stamp_s = x.telemetry_stamp_ns, x.now_s
        if x.frames_received != self._frames:
            self._frames, self._frames_s = x.frames_received, x.now_s
        if x.fatal is not None:
            return HealthReport(False, HealthState.FATAL, x.fatal)
        if not x.link_up:
            if self._ever_up:
                return HealthReport(
                    False,
                    HealthState.LINK_LOST,
                    f"autopilot link lost: nothing received on {x.link_url}",
                )
            return HealthReport(
                False,
                HealthState.NO_AUTOPILOT,
                f"no message from the autopilot on {x.link_url} yet",
            )
        self._ever_up = True
        if not x.autopilot_seen:
            return HealthReport(
                False,
                HealthState.NO_AUTOPILOT,
                f"messages on {x.link_url} but no autopilot heartbeat",
            )
        if self._stamp_s is None:
            return HealthReport(
                False,
                HealthState.NO_TELEMETRY,
                "autopilot heartbeats but no LOCAL_POSITION_NED/ATTITUDE yet "
                "(no EKF origin/GPS, or streams refused)",
            )
        age = x.now_s - self._stamp_s
        if age > self.telemetry_timeout_s:
            return HealthReport(
                False,
                HealthState.NO_TELEMETRY,
                f"autopilot heartbeats but no new LOCAL_POSITION_NED/ATTITUDE for {age:.1f} s",
            )
        if x.flying:
            if self._frames_s is None:
                return HealthReport(
                    False, HealthState.NO_FRAMES, "steering the vehicle but no frame yet"
                )
            frame_age = x.now_s - self._frames_s
            if frame_age > self.frame_timeout_s:
                return HealthReport(
                    False,
                    HealthState.NO_FRAMES,
                    f"steering the vehicle but no stereo frame for {frame_age:.1f} s",
                )
            return HealthReport(
                True, HealthState.OK, "autopilot heartbeats, telemetry and frames arrive"
            )
        frames = "frames arrive" if self._frames_s is not None else "no frames yet"
        return HealthReport(
            True,
            HealthState.OK,
            f"autopilot heartbeats and telemetry arrive (not steering; {frames})",
        )


class HealthFile:
    """Writes each report to ``path`` atomically (a sibling ``.partial`` file, renamed)."""

    def __init__(self, path: Path, tracker: HealthTracker | None = None) -> None:
        self.path = Path(path)
        self.tracker = tracker if tracker is not None else HealthTracker()
        self.last: HealthReport | None = None

    def update(self, inputs: HealthInputs) -> HealthReport:
        report = self.tracker.update(inputs)
        self.write(report)
        return report

    def write(self, report: HealthReport) -> None:
        self.last = report
        record = {
            "healthy": report.healthy,
            "state": report.state.value,
            "reason": report.reason,
            "time_unix": round(time.time(), 3),
            "pid": os.getpid(),
        }
        partial = self.path.with_name(self.path.name + ".partial")
        partial.write_text(json.dumps(record) + "\n", encoding="utf-8")
        partial.replace(self.path)

    def stopped(self, why: str = "the companion stopped") -> None:
        self.write(HealthReport(False, HealthState.STOPPED, why))


def check(path: Path, max_age_s: float, now_unix: float | None = None) -> tuple[bool, str]:
    """(healthy, one line for the healthcheck's output) from a health file."""
    now = time.time() if now_unix is None else now_unix
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
        healthy, state, reason = record["healthy"], record["state"], record["reason"]
        stamp = float(record["time_unix"])
    except FileNotFoundError:
        return False, f"unhealthy: no health file {path} (not started, or no --health-file)"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return False, f"unhealthy: unreadable health file {path}: {exc}"
    age = now - stamp
    if age > max_age_s:
        return False, (
            f"unhealthy: health file {path} is {age:.0f} s old (last: {state}: {reason}); "
            "the companion stopped updating it"
        )
    return bool(healthy), f"{'healthy' if healthy else 'unhealthy'}: {state}: {reason}"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m companion.health",
        description="Healthcheck: exit 0 if the companion's health file says it can steer.",
    )
    p.add_argument("path", type=Path, help="the companion's --health-file")
    p.add_argument(
        "--max-age", type=float, default=5.0, help="older than this [s]: unhealthy (default 5)"
    )
    args = p.parse_args(argv)
    healthy, line = check(args.path, args.max_age)
    print(line, flush=True)
    return 0 if healthy else 1


if __name__ == "__main__":
    sys.exit(main())
