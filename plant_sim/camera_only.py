"""plant-sim camera-only mode: the world and the stereo camera around an external autopilot.

``plant-sim --pose-from URL`` runs no physics and no MAVLink autopilot of its own. It
connects to a real autopilot (ArduPilot or PX4 SITL, or a flight controller in a
hardware-in-the-loop rig) as a MAVLink camera component, asks for LOCAL_POSITION_NED and
ATTITUDE with SET_MESSAGE_INTERVAL (default 50 Hz, ≥ 30 Hz is needed), renders the
scenario's obstacles from the vehicle's pose and publishes the frames over Zenoh exactly
like the full plant, and writes the same ground-truth log (``truth.csv``: distance from the
vehicle's centre to every obstacle surface) from the same poses.

Clock (DESIGN.md "One clock for frames and poses"): frames are taken at ``k / rate_hz``
seconds of the **autopilot's** boot clock and stamped with that time (``capture_ns`` =
autopilot boot time in ns); each is rendered from the pose interpolated between the two
telemetry samples around it, and only once a sample at or after it has arrived, so a
frame's capture time *is* its pose's time, exactly, at any SITL ``--speedup``. The
companion therefore runs with ``--frame-clock autopilot`` (its poses come from the same
``time_boot_ms``); no TIMESYNC mapping sits between the two. Stamping with the host clock
instead would put the render's wall latency, times the SITL speed-up, between the pose
and the stamp. The frame of capture time t leaves at most one telemetry period after t
(autopilot time) plus the render: the camera's own latency. When the process falls
behind (several capture times due at once, e.g. a loaded machine and a fast SITL
``--speedup``) it renders only the newest and counts the others as dropped, like a camera
that drops frames, rather than deliver a backlog of stale ones.

Coordinates: the scenario (obstacles, goal, ground) is in the autopilot's LOCAL_NED
(origin = its EKF origin, ArduPilot/PX4 SITL: home), shifted by ``offset_ned_m``:
``p_scenario = p_autopilot_local_ned + offset_ned_m``. Yaw is not rotated.
"""

from __future__ import annotations

import collections
import logging
import math
import os
import select
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot.modes import FlightMode
from plant_sim.camera_publisher import StereoPublisher, readiness_fields
from plant_sim.pose_track import PoseTrack
from plant_sim.scenario import Scenario
from plant_sim.truth_log import TruthLogWriter
from protocols.config import ConfigError, bounded, check_fields
from protocols.frames import euler321_from_rotation, rotation_from_quat
from protocols.keys import stereo_key
from protocols.zenoh_session import ZenohSettings

__all__ = ["CameraOnlyConfig", "CameraOnlyService", "mode_name"]

_log = logging.getLogger("plant_sim.camera_only")
_M = mavlink
_REBOOT_BACKSTEP_S = 0.5  # time_boot_ms going back this far: the autopilot restarted
_ATTITUDE_TARGET_HZ = 10.0
_EXTENDED_SYS_STATE_HZ = 2.0


@dataclass(frozen=True)
class CameraOnlyConfig:
    """Everything a camera-only run needs (built from the CLI by ``__main__``)."""

    scenario: Scenario
    pose_from: str  # pymavlink URL of the autopilot: tcp:HOST:PORT, udpin:..., udpout:...
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    offset_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # scenario = local + offset
    log_dir: Path | None = None
    # requested LOCAL_POSITION_NED and ATTITUDE rate
    pose_rate_hz: float = bounded(50.0, "Hz", ge=30)
    # ground-truth rows per second of autopilot time
    truth_rate_hz: float = bounded(50.0, "Hz", gt=0)
    target_system: int = bounded(0, integer=True, ge=0, le=255)  # 0: the first autopilot heard
    system_id: int = bounded(1, integer=True, ge=1, le=255)  # ours: the vehicle's camera
    component_id: int = bounded(_M.MAV_COMP_ID_CAMERA, integer=True, ge=0, le=255)
    connect_timeout_s: float = bounded(30.0, "s", gt=0)  # wall
    # no frame from poses further apart [s autopilot time]
    max_gap_s: float = bounded(0.25, "s", gt=0)
    heartbeat_period_s: float = bounded(1.0, "s", gt=0)  # wall

    def __post_init__(self) -> None:
        check_fields(self)
        if len(self.offset_ned_m) != 3 or not all(math.isfinite(x) for x in self.offset_ned_m):
            raise ConfigError(
                f"must be 3 finite numbers, got {self.offset_ned_m!r}", key="offset_ned_m"
            )


def mode_name(autopilot: int | None, custom_mode: int | None) -> str:
    """Readable flight mode of a HEARTBEAT (ArduCopter names, PX4 main/sub modes)."""
    if custom_mode is None:
        return "-"
    if autopilot == _M.MAV_AUTOPILOT_PX4:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        return f"PX4_{main}_{sub}"
    try:
        return FlightMode(custom_mode).name
    except ValueError:
        return f"MODE_{custom_mode}"


def _percentile(values, q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q / 100.0 * len(s)) - 1))]


class CameraOnlyService:
    """Follows an external autopilot's pose; :meth:`open`, :meth:`run`, :meth:`close`."""

    def __init__(self, config: CameraOnlyConfig) -> None:
        self.config = config
        sc = config.scenario
        self.track = PoseTrack(
            sc.camera.rate_hz if sc.camera.enabled else config.truth_rate_hz,
            max_gap_s=config.max_gap_s,
        )
        self.publisher: StereoPublisher | None = None
        if sc.camera.enabled:
            self.publisher = StereoPublisher(
                config.zenoh, stereo_key(sc.vehicle_id), sc.camera, sc.world
            )
        self._conn = None
        self._truth: TruthLogWriter | None = None
        self._target: tuple[int, int] | None = None  # autopilot (system, component)
        self._autopilot_kind: int | None = None
        self._custom_mode: int | None = None
        self._armed: bool | None = None
        self._on_ground: bool | None = None
        self._cmd_rpy_rad: tuple[float, float, float] | None = None
        self._last_boot_s: float | None = None
        self._next_heartbeat_s = 0.0
        self._next_request_s = 0.0
        self._newest_rx_ns = 0  # wall time the newest pose sample arrived
        self._latency_ms: collections.deque[float] = collections.deque(maxlen=20000)
        self._seen = {"LOCAL_POSITION_NED": 0, "ATTITUDE": 0}
        self.counters = {
            "frames_published": 0,
            "frames_skipped": 0,
            "frames_dropped_late": 0,  # several capture times due at once: older ones dropped
            "truth_rows": 0,
            "samples_rejected": 0,
            "autopilot_restarts": 0,
            "bad_data": 0,
            "stream_requests": 0,
        }
        self._wall_start = time.monotonic()

    # ---- lifecycle -----------------------------------------------------------------
    def open(self) -> None:
        """Connect to the autopilot (bounded retries), open Zenoh and the truth log."""
        os.environ["MAVLINK20"] = "1"
        deadline = time.monotonic() + self.config.connect_timeout_s
        url = self.config.pose_from
        while True:
            try:
                conn = mavutil.mavlink_connection(
                    url,
                    source_system=self.config.system_id,
                    source_component=self.config.component_id,
                    dialect="ardupilotmega",
                    autoreconnect=True,
                )
                break
            except (ConnectionRefusedError, ConnectionResetError, TimeoutError) as exc:
                if time.monotonic() >= deadline:
                    raise OSError(f"cannot connect to the autopilot at {url!r}: {exc}") from None
                _log.info("autopilot at %s not reachable yet (%s); retrying", url, exc)
                time.sleep(0.5)
            except (OSError, ValueError) as exc:  # a bad URL or host: retrying will not help
                raise OSError(f"cannot connect to the autopilot at {url!r}: {exc}") from None
        conn.mav.robust_parsing = True
        self._conn = conn
        if self.config.log_dir is not None:
            self.config.log_dir.mkdir(parents=True, exist_ok=True)
            sc = self.config.scenario
            self._truth = TruthLogWriter(
                self.config.log_dir / "truth.csv", sc.world, sc.vehicle.body_radius_m
            )
        if self.publisher is not None:
            self.publisher.open()

    def readiness_line(self) -> str:
        """``PLANT_SIM READY mode=camera-only pose-from=URL zenoh=... key=KEY``."""
        return (
            f"PLANT_SIM READY mode=camera-only pose-from={self.config.pose_from} "
            f"{readiness_fields(self.publisher)}"
        )

    def close(self) -> dict:
        stats = self.stats()
        if self.publisher is not None:
            self.publisher.close()
        if self._conn is not None:
            try:
                self._conn.close()
            except (OSError, AttributeError) as exc:  # pymavlink tcp: no socket after an EOF
                _log.debug("closing MAVLink connection: %s", exc)
            self._conn = None
        if self._truth is not None:
            self._truth.close()
        return stats

    def stats(self) -> dict:
        lat = list(self._latency_ms)
        clearance = None if self._truth is None else self._truth.min_clearance_m
        return {
            "mode": "camera-only",
            "autopilot_time_s": None if self._last_boot_s is None else round(self._last_boot_s, 3),
            "wall_time_s": round(time.monotonic() - self._wall_start, 3),
            "samples": dict(self._seen),
            "latency_ms": {
                "pose_to_frame_p50": _round(_percentile(lat, 50)),
                "pose_to_frame_p99": _round(_percentile(lat, 99)),
                "n": len(lat),
            },
            "min_clearance_m": None
            if clearance is None or not math.isfinite(clearance)
            else round(clearance, 4),
            **self.counters,
        }

    # ---- main loop -----------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool]) -> None:
        assert self._conn is not None
        fd = getattr(self._conn, "fd", None)
        while not should_stop():
            if isinstance(fd, int) and fd >= 0:
                try:
                    select.select([fd], [], [], 0.01)
                except (InterruptedError, OSError, ValueError):
                    time.sleep(0.01)
            else:
                time.sleep(0.002)
            now_s = time.monotonic()
            self._timers(now_s)
            self._receive()
            self._render_due()

    def _timers(self, now_s: float) -> None:
        if now_s >= self._next_heartbeat_s:
            self._next_heartbeat_s = now_s + self.config.heartbeat_period_s
            self._send(
                _M.MAVLink_heartbeat_message(
                    _M.MAV_TYPE_CAMERA, _M.MAV_AUTOPILOT_INVALID, 0, 0, _M.MAV_STATE_ACTIVE, 3
                )
            )
        if self._target is not None and now_s >= self._next_request_s:
            streaming = all(n > 0 for n in self._seen.values())
            self._next_request_s = now_s + (10.0 if streaming else 2.0)
            self._request_streams()

    def _request_streams(self) -> None:
        assert self._target is not None
        rates = (
            (_M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, self.config.pose_rate_hz),
            (_M.MAVLINK_MSG_ID_ATTITUDE, self.config.pose_rate_hz),
            (_M.MAVLINK_MSG_ID_ATTITUDE_TARGET, _ATTITUDE_TARGET_HZ),
            (_M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, _EXTENDED_SYS_STATE_HZ),
        )
        for msg_id, rate_hz in rates:
            self._send(
                _M.MAVLink_command_long_message(
                    self._target[0],
                    self._target[1],
                    _M.MAV_CMD_SET_MESSAGE_INTERVAL,
                    0,
                    float(msg_id),
                    1e6 / rate_hz,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )
        self.counters["stream_requests"] += 1

    def _send(self, msg) -> None:
        if self._conn is None:
            return
        try:
            self._conn.mav.send(msg)
        except (OSError, mavlink.MAVError) as exc:
            _log.debug("MAVLink send failed: %s", exc)

    # ---- input ---------------------------------------------------------------------
    def _receive(self) -> None:
        conn = self._conn
        for _ in range(5000):
            try:
                msg = conn.recv_msg()
            except (OSError, mavlink.MAVError, ValueError, IndexError) as exc:
                self.counters["bad_data"] += 1
                _log.debug("MAVLink receive error: %s", exc)
                return
            if msg is None:
                return
            self._dispatch(msg)

    def _dispatch(self, msg) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self.counters["bad_data"] += 1
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if mtype == "HEARTBEAT":
            if self._target is None and self._is_autopilot(msg, src[0]):
                self._target = src
                self._autopilot_kind = msg.autopilot
                self._next_request_s = 0.0
                _log.info("autopilot found: system %d component %d", *src)
            if src == self._target:
                self._custom_mode = msg.custom_mode
                self._armed = bool(msg.base_mode & _M.MAV_MODE_FLAG_SAFETY_ARMED)
            return
        if src != self._target:
            return
        if mtype == "LOCAL_POSITION_NED":
            t = self._boot_s(msg.time_boot_ms)
            off = self.config.offset_ned_m
            pos = (msg.x + off[0], msg.y + off[1], msg.z + off[2])
            self._sample(
                "LOCAL_POSITION_NED", self.track.add_position(t, pos, (msg.vx, msg.vy, msg.vz))
            )
        elif mtype == "ATTITUDE":
            t = self._boot_s(msg.time_boot_ms)
            self._sample("ATTITUDE", self.track.add_attitude(t, msg.roll, msg.pitch, msg.yaw))
        elif mtype == "ATTITUDE_TARGET":
            q = tuple(float(x) for x in msg.q)
            n = math.sqrt(sum(x * x for x in q))
            if all(math.isfinite(x) for x in q) and n > 0.5:
                self._cmd_rpy_rad = euler321_from_rotation(
                    rotation_from_quat(tuple(x / n for x in q))
                )
        elif mtype == "EXTENDED_SYS_STATE":
            if msg.landed_state:
                self._on_ground = msg.landed_state == _M.MAV_LANDED_STATE_ON_GROUND
        elif mtype == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
            _log.info("autopilot: %s", text.rstrip("\x00"))

    def _is_autopilot(self, msg, sysid: int) -> bool:
        if msg.autopilot == _M.MAV_AUTOPILOT_INVALID:
            return False
        if msg.type in (_M.MAV_TYPE_GCS, _M.MAV_TYPE_ONBOARD_CONTROLLER, _M.MAV_TYPE_CAMERA):
            return False
        return self.config.target_system in (0, sysid)

    def _boot_s(self, time_boot_ms: int) -> float:
        t = time_boot_ms * 1e-3
        last = self._last_boot_s
        if last is not None and t < last - _REBOOT_BACKSTEP_S:
            self.counters["autopilot_restarts"] += 1
            _log.warning("autopilot restarted (boot time %.3f → %.3f s): starting over", last, t)
            self.track.reset()
        if last is None or t > last:
            self._last_boot_s = t
        return t

    def _sample(self, name: str, accepted: bool) -> None:
        if accepted:
            self._seen[name] += 1
            self._newest_rx_ns = time.monotonic_ns()
        else:
            self.counters["samples_rejected"] += 1

    # ---- output --------------------------------------------------------------------
    def _render_due(self) -> None:
        if self.publisher is not None:
            due = self.track.due_frames()
            if len(due) > 1:  # fell behind: like a camera, deliver the newest, drop the rest
                self.counters["frames_dropped_late"] += len(due) - 1
                due = due[-1:]
            for t in due:
                pose = self.track.at(t)
                if pose is None:
                    continue
                self.publisher.publish(t, pose.pos_ned_m, pose.R_ned_from_frd)
                self.counters["frames_published"] += 1
                self._latency_ms.append((time.monotonic_ns() - self._newest_rx_ns) * 1e-6)
            self.counters["frames_skipped"] = self.track.frames_skipped
        if self._truth is not None:
            times, _skipped = self.track.due_times(self.config.truth_rate_hz)
            for t in times:
                pose = self.track.at(t)
                if pose is None:
                    continue
                self._truth.write_external(
                    t,
                    pose.pos_ned_m,
                    pose.vel_ned_mps,
                    pose.roll_pitch_yaw_rad,
                    self._cmd_rpy_rad,
                    on_ground=self._on_ground,
                    armed=self._armed,
                    mode_name=mode_name(self._autopilot_kind, self._custom_mode),
                )
                self.counters["truth_rows"] += 1


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 3)
