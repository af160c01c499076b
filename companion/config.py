"""Companion configuration: CLI flags and a TOML/JSON file become one frozen config here.

The file (TOML via ``tomllib``, or JSON) has top-level keys and sections; every key is
optional, and an unknown key anywhere is an error that names it (``link.rate`` →
"unknown key 'link.rate'")::

    vehicle_id = "sim1"
    goal_ned_m = [0.0, 0.0, -7.0]        # or: waypoints_ned_m = [[...], [...]]
    goal_tolerance_m = 0.5

    [mavlink]
    url = "udpout:127.0.0.1:14550"       # pymavlink style: udpin:, udpout:, tcp:, /dev/tty..
    baud = 921600
    system_id = 1
    component_id = 196                   # MAV_COMP_ID_OBSTACLE_AVOIDANCE
    signing_key = "..."                  # 64 hex digits or a passphrase (SHA-256)
    takeoff_alt_m = 0.0                  # > 0: arm and take off if on the ground (SIL runs)
    takeoff_tolerance_m = 0.5            # climb done within this of takeoff_alt_m
    takeoff_timeout_s = 0.0              # climb limit, autopilot time; 0: alt/0.5 m/s + 15 s
    takeoff_ready_timeout_s = 180.0      # on the ground: wait for EKF/GPS, pre-arm, frames
    request_mode = true                  # ask for GUIDED / OFFBOARD ourselves
    telemetry_rate_hz = 50.0             # LOCAL_POSITION_NED and ATTITUDE
    frame_clock = "autopilot"            # or "host": frames stamped with this host's clock

    [zenoh]
    listen = []
    connect = ["tcp/127.0.0.1:7447"]     # default when neither endpoints nor a file is given
    config_file = "zenoh.json5"

    [failsafe]
    frame_timeout_s = 1.0                # frames late: hold position (frame clock, sim time in SIL)
    telemetry_timeout_s = 0.3            # telemetry late: hold position
    frame_loss_s = 2.0                   # no frames this long: BRAKE/LOITER (last resort)
    telemetry_loss_s = 2.0               # no telemetry this long: BRAKE/LOITER (last resort)
    resume_after_s = 1.0                 # after a hold: healthy this long before resuming
    link_timeout_s = 1.5                 # wall time without any message → link lost
    frame_time_window_s = 2.0            # capture time this far from the clock: refused

    [proximity]                          # OBSTACLE_DISTANCE from the known-space map
    enabled = true                       # on by default (ArduPilot PRX1_TYPE=2, PX4 CP_DIST)
    thread = true                        # a watchdog sends when the main loop is late
    own_process = true                   # ... a process of its own sends (UDP links)
    realtime_priority = 10               # its SCHED_FIFO priority (0: a normal task)
    rate_hz = 20.0                       # least send rate, from start-up, in every mode
    n_sectors = 72                       # ≤ 72; n_sectors × increment_deg ≤ 360
    increment_deg = 5.0
    angle_offset_deg = 0.0               # body bearing of sector 0's centre
    band_half_height_m = 0.3             # vehicle half-height + margin
    ignore_within_m = 0.3                # the vehicle's own body
    min_distance_m = 0.2
    unseen_extension_m = 1.0             # occupied this near the unseen band counts in it

    [perception]                         # companion.perception.PerceptionConfig fields
    [perception.depth_camera]            # companion.depth_camera.DepthCameraConfig fields
    [guidance]                           # companion.guidance.GuidanceConfig fields
    [known_space]                        # companion.known_space.KnownSpaceConfig fields
    [envelope]                           # companion.guidance.envelope.EnvelopeConfig fields

CLI flags override the file (:func:`config_from_args`, the only place flags become config).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.clock_model import FrameClock
from companion.guidance import GuidanceConfig
from companion.guidance.envelope import EnvelopeConfig
from companion.known_space import KnownSpaceConfig
from companion.perception import PerceptionConfig
from companion.proximity.sectors import ProximityConfig
from protocols.config import (
    ConfigError,
    bounded,
    check_fields,
    check_keys,
    dataclass_from_mapping,
    vec3,
)
from protocols.keys import validate_vehicle_id
from protocols.process import (
    DEFAULT_ENDPOINT,
    add_signing_arguments,
    add_zenoh_arguments,
    signing_key_text,
)
from protocols.signing import SigningKey
from protocols.zenoh_session import ZenohSettings as ZenohConfig

__all__ = [
    "CompanionConfig",
    "ConfigError",
    "FailsafeConfig",
    "FrameClock",
    "LinkConfig",
    "SigningKey",
    "ZenohConfig",
    "build_parser",
    "config_from_args",
    "config_from_dict",
    "load_file",
]


@dataclass(frozen=True)
class LinkConfig:
    """MAVLink link to the autopilot."""

    url: str = "udpout:127.0.0.1:14550"  # pymavlink connection string
    baud: int = bounded(921600, "bit/s", integer=True, gt=0)  # serial only
    system_id: int = bounded(1, integer=True, ge=1, le=255)  # ours (the vehicle's)
    component_id: int = bounded(196, integer=True, ge=0, le=255)  # MAV_COMP_ID_OBSTACLE_AVOIDANCE
    target_system: int = bounded(1, integer=True, ge=1, le=255)  # the autopilot
    target_component: int = bounded(1, integer=True, ge=0, le=255)
    signing_key: SigningKey | None = None
    # > 0: on the ground → GUIDED, arm, take off to this
    takeoff_alt_m: float = bounded(0.0, "m", ge=0)
    takeoff_tolerance_m: float = bounded(0.5, "m", gt=0)  # climb done within this of the alt
    # climb limit [s autopilot time]; 0: alt / 0.5 m/s + 15 s
    takeoff_timeout_s: float = bounded(0.0, "s", ge=0)
    # on the ground: wait this long [s wall] for a local position (EKF origin, GPS), the
    # pre-arm checks and camera frames before giving up (ArduPilot SITL needs ~40 s)
    takeoff_ready_timeout_s: float = bounded(180.0, "s", gt=0)
    request_mode: bool = True  # request GUIDED / OFFBOARD ourselves at start
    telemetry_rate_hz: float = bounded(50.0, "Hz", gt=0)  # LOCAL_POSITION_NED and ATTITUDE
    frame_clock: FrameClock = FrameClock.AUTOPILOT
    heartbeat_period_s: float = bounded(1.0, "s", gt=0)  # wall time
    timesync_period_s: float = bounded(0.2, "s", gt=0)  # wall time
    ardupilot_setpoint_period_s: float = bounded(0.5, "s", gt=0)  # re-send on ArduPilot [wall]
    # continuous stream on PX4 [wall]: PX4 leaves OFFBOARD below 2 Hz
    px4_setpoint_rate_hz: float = bounded(20.0, "Hz", gt=2)
    px4_prestream_s: float = bounded(1.2, "s", gt=0)  # stream this long before OFFBOARD [wall]

    def __post_init__(self) -> None:
        if not self.url:
            raise ConfigError("is empty", key="url")
        check_fields(self)
        if self.takeoff_alt_m > 0 and not self.takeoff_tolerance_m < self.takeoff_alt_m:
            raise ConfigError(
                f"must be below takeoff_alt_m {self.takeoff_alt_m}, got "
                f"{self.takeoff_tolerance_m!r}",
                key="takeoff_tolerance_m",
            )


@dataclass(frozen=True)
class FailsafeConfig:
    """When to stop steering and hold (frame clock = simulation time in the SIL)."""

    # newest frame older than this → hold position [s]; below it the measured latency budget
    # slows the vehicle instead (issue 32: a slow frame is not a reason to stop)
    frame_timeout_s: float = bounded(1.0, "s", gt=0)
    # newest pose older than this → hold position
    telemetry_timeout_s: float = bounded(0.3, "s", gt=0)
    # the last resort: the autopilot's own hold (BRAKE; PX4: Hold) only when no frame
    # (no pose) arrived for this long [s, frame clock]; > the timeouts above
    frame_loss_s: float = bounded(2.0, "s", gt=0)
    telemetry_loss_s: float = bounded(2.0, "s", gt=0)
    # settle: after a hold, healthy this long before resuming
    resume_after_s: float = bounded(1.0, "s", gt=0)
    # wall time without any autopilot message → link lost
    link_timeout_s: float = bounded(1.5, "s", gt=0)
    # frames newer than the newest pose by ≤ this
    max_pose_extrapolation_s: float = bounded(0.05, "s", gt=0)
    pose_history_s: float = bounded(2.0, "s", gt=0)  # how far back poses are kept
    # frames stamped farther than this from now: refused
    frame_time_window_s: float = bounded(2.0, "s", gt=0)

    def __post_init__(self) -> None:
        check_fields(self)
        for loss, late in (
            ("frame_loss_s", "frame_timeout_s"),
            ("telemetry_loss_s", "telemetry_timeout_s"),
        ):
            if not getattr(self, loss) > getattr(self, late):
                raise ConfigError(
                    f"must be longer than {late} ({getattr(self, late)!r}), got "
                    f"{getattr(self, loss)!r}",
                    key=loss,
                )


@dataclass(frozen=True)
class CompanionConfig:
    """Everything one companion process needs."""

    vehicle_id: str = "sim1"
    waypoints_ned_m: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, -7.0),)
    # a waypoint is reached within this distance
    goal_tolerance_m: float = bounded(0.5, "m", gt=0)
    link: LinkConfig = field(default_factory=LinkConfig)
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    known_space: KnownSpaceConfig = field(default_factory=KnownSpaceConfig)
    envelope: EnvelopeConfig = field(default_factory=EnvelopeConfig)
    proximity: ProximityConfig = field(default_factory=ProximityConfig)
    status_log_period_s: float = bounded(1.0, "s", gt=0)  # progress log line period [wall]

    def __post_init__(self) -> None:
        try:
            validate_vehicle_id(self.vehicle_id)
        except ValueError as exc:
            raise ConfigError(str(exc), key="vehicle_id") from None
        if not self.waypoints_ned_m:
            raise ConfigError("at least one waypoint (goal_ned_m) is needed")
        check_fields(self)
        depth_range_m = self.perception.depth_camera.max_range_m
        if depth_range_m < self.known_space.max_range_m:
            raise ConfigError(
                f"perception.depth_camera.max_range_m {depth_range_m} is below "
                f"known_space.max_range_m {self.known_space.max_range_m}: a depth camera's far "
                "return would free space it does not vouch for"
            )


# ---- dict → config -------------------------------------------------------------------

_TOP_KEYS = {
    "vehicle_id",
    "goal_ned_m",
    "waypoints_ned_m",
    "goal_tolerance_m",
    "status_log_period_s",
    "mavlink",
    "zenoh",
    "failsafe",
    "perception",
    "guidance",
    "known_space",
    "envelope",
    "proximity",
}


def _frame_clock(value: Any) -> FrameClock:
    try:
        return FrameClock(str(value).lower())
    except ValueError:
        raise ConfigError(
            f"mavlink.frame_clock must be one of {[c.value for c in FrameClock]}, got {value!r}"
        ) from None


def config_from_dict(d: Mapping[str, Any]) -> CompanionConfig:
    """Build a :class:`CompanionConfig` from a parsed file (unknown keys are an error)."""
    d = check_keys(d, _TOP_KEYS, "")
    kw: dict[str, Any] = {}
    for key in ("vehicle_id", "goal_tolerance_m", "status_log_period_s"):
        if key in d:
            kw[key] = d[key]
    if "goal_ned_m" in d and "waypoints_ned_m" in d:
        raise ConfigError("give goal_ned_m or waypoints_ned_m, not both")
    if "goal_ned_m" in d:
        kw["waypoints_ned_m"] = (vec3(d["goal_ned_m"], "goal_ned_m"),)
    if "waypoints_ned_m" in d:
        kw["waypoints_ned_m"] = tuple(
            vec3(w, f"waypoints_ned_m[{i}]") for i, w in enumerate(d["waypoints_ned_m"])
        )
    if "mavlink" in d:
        kw["link"] = dataclass_from_mapping(
            LinkConfig,
            d["mavlink"],
            "mavlink",
            {"signing_key": SigningKey.from_text, "frame_clock": _frame_clock},
        )
    if "zenoh" in d:
        kw["zenoh"] = dataclass_from_mapping(
            ZenohConfig,
            d["zenoh"],
            "zenoh",
            {"listen": tuple, "connect": tuple, "config_file": Path},
        )
    if "failsafe" in d:
        kw["failsafe"] = dataclass_from_mapping(FailsafeConfig, d["failsafe"], "failsafe")
    if "proximity" in d:
        kw["proximity"] = dataclass_from_mapping(ProximityConfig, d["proximity"], "proximity")
    try:
        if "perception" in d:
            kw["perception"] = PerceptionConfig.from_dict(dict(d["perception"]))
        if "guidance" in d:
            kw["guidance"] = GuidanceConfig.from_dict(dict(d["guidance"]))
        if "known_space" in d:
            kw["known_space"] = KnownSpaceConfig.from_dict(dict(d["known_space"]))
        if "envelope" in d:
            kw["envelope"] = EnvelopeConfig.from_dict(dict(d["envelope"]))
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    return CompanionConfig(**kw)


def load_file(path: str | Path) -> dict[str, Any]:
    """Parse a ``.toml`` or ``.json`` config file into a dict."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text(encoding="utf-8"))
        else:
            with path.open("rb") as fh:
                data = tomllib.load(fh)
    except (OSError, ValueError) as exc:  # tomllib.TOMLDecodeError is a ValueError
        raise ConfigError(f"cannot read config file {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path}: top level must be a table/object")
    return data


# ---- CLI → config --------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="companion",
        description="Stereo-vision obstacle avoidance companion for any MAVLink autopilot.",
    )
    p.add_argument("--config", type=Path, help="config file (.toml or .json)")
    p.add_argument("--mavlink", metavar="URL", help="pymavlink URL, e.g. udpout:127.0.0.1:14550")
    p.add_argument("--baud", type=int, help="serial baud rate")
    p.add_argument("--system-id", type=int, help="our MAVLink system id (default 1)")
    p.add_argument("--component-id", type=int, help="our MAVLink component id (default 196)")
    add_zenoh_arguments(
        p,
        listen_default="e.g. for a stereo camera to connect to",
        connect_help=f"router or plant-sim/stereo-camera; default {DEFAULT_ENDPOINT}",
    )
    p.add_argument("--vehicle-id", help="vehicle id of the Zenoh keys")
    p.add_argument(
        "--goal",
        type=float,
        nargs=3,
        metavar=("N", "E", "D"),
        help="goal in LOCAL_NED [m] (default 0 0 -7)",
    )
    p.add_argument(
        "--waypoint",
        type=float,
        nargs=3,
        action="append",
        metavar=("N", "E", "D"),
        help="waypoint in LOCAL_NED [m], repeatable (instead of --goal)",
    )
    p.add_argument(
        "--waypoints",
        metavar="N,E,D[;N,E,D...]",
        help="waypoints in LOCAL_NED [m] as one argument, e.g. '0,0,-7' or '20,0,-7;40,0,-7' "
        "(for environment variables; instead of --goal/--waypoint)",
    )
    _add_behaviour_arguments(p)
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    p.add_argument(
        "--ready-file",
        type=Path,
        help="also write the readiness line to this file (removed at exit): a healthcheck",
    )
    p.add_argument(
        "--health-file",
        type=Path,
        help="rewrite this JSON file every second: healthy only while autopilot heartbeats, "
        "telemetry (and, when steering, frames) arrive; check it with "
        "`python -m companion.health FILE`",
    )
    p.add_argument(
        "--log-file", type=Path, help="also copy stdout and stderr to this file (appended)"
    )
    # [observe] recording and viewing (companion.record, companion.viz); off by default
    p.add_argument(
        "--record",
        type=Path,
        metavar="FILE.mcap",
        help="record the core's inputs (frames, MAVLink in, clock ticks) and MAVLink out "
        "(MCAP) for `stereo-avoid replay FILE.mcap`; Foxglove opens it (needs the [view] extra)",
    )
    p.add_argument(
        "--rerun",
        metavar="FILE.rrd|serve[:PORT]",
        help="log depth, obstacles, cones, setpoints to Rerun: a .rrd file, or 'serve' for "
        "a live web viewer on http://127.0.0.1:PORT (default 9090); needs the [view] extra",
    )
    return p


def _add_behaviour_arguments(p: argparse.ArgumentParser) -> None:
    """Detection, signing, take-off, mode requests, clocks, failsafe timeouts."""
    p.add_argument("--threshold-m", type=float, help="obstacle detection range [m]")
    p.add_argument("--safety-margin-m", type=float, help="boundary inflation margin [m]")
    add_signing_arguments(p)
    p.add_argument(
        "--takeoff-alt",
        type=float,
        metavar="M",
        help="if on the ground: (GUIDED,) arm and take off to M metres before steering "
        "(waits for EKF origin/GPS, pre-arm checks and camera frames)",
    )
    p.add_argument(
        "--takeoff-wait-s",
        type=float,
        metavar="S",
        help="with --takeoff-alt: give up after S wall seconds without a local position, "
        "pre-arm checks or frames (default 180)",
    )
    p.add_argument("--no-request-mode", action="store_true", help="never request GUIDED/OFFBOARD")
    p.add_argument("--frame-clock", choices=[c.value for c in FrameClock])
    p.add_argument("--telemetry-rate-hz", type=float)
    p.add_argument("--frame-timeout-s", type=float, help="hold position if frames are older [s]")
    p.add_argument(
        "--frame-loss-s",
        type=float,
        help="request BRAKE (PX4: Hold) if no frame came for this long [s]",
    )
    p.add_argument("--telemetry-timeout-s", type=float, help="hold if poses are older [s]")
    p.add_argument(
        "--obstacle-distance",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="send OBSTACLE_DISTANCE from the known-space map (default: on; "
        "--no-obstacle-distance turns it off)",
    )


def parse_waypoints(text: str) -> list[list[float]]:
    """``"N,E,D;N,E,D"`` → ``[[N, E, D], [N, E, D]]`` (raises :class:`ConfigError`)."""
    out = []
    for i, part in enumerate(text.split(";")):
        fields = [f for f in part.replace(",", " ").split() if f]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            values = []
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise ConfigError(
                f"--waypoints: waypoint {i + 1} {part.strip()!r} is not three numbers N,E,D "
                f"(in {text!r}; separate waypoints with ';')"
            )
        out.append(values)
    return out


def _merge(base: dict[str, Any], section: str, values: dict[str, Any]) -> None:
    values = {k: v for k, v in values.items() if v is not None}
    if values:
        sub = dict(base.get(section, {}))
        sub.update(values)
        base[section] = sub


def _from_dict_of_file(d: Mapping[str, Any], path: Path | None) -> CompanionConfig:
    """:func:`config_from_dict`; an error names the file (its keys, perhaps overridden by
    a flag) when there is one."""
    try:
        return config_from_dict(d)
    except ConfigError as exc:
        raise exc if path is None else exc.in_file(path) from None


def config_from_args(
    args: argparse.Namespace, environ: Mapping[str, str] | None = None
) -> CompanionConfig:
    """The one place CLI flags (over an optional file) become a :class:`CompanionConfig`."""
    env = os.environ if environ is None else environ
    d: dict[str, Any] = load_file(args.config) if args.config is not None else {}
    check_keys(d, _TOP_KEYS, "")
    if args.vehicle_id:
        d["vehicle_id"] = args.vehicle_id
    given = [
        n
        for n, v in (
            ("--goal", args.goal),
            ("--waypoint", args.waypoint),
            ("--waypoints", args.waypoints),
        )
        if v
    ]
    if len(given) > 1:
        raise ConfigError(f"give one of --goal, --waypoint, --waypoints, not {' and '.join(given)}")
    if args.waypoints:
        d.pop("goal_ned_m", None)
        d["waypoints_ned_m"] = parse_waypoints(args.waypoints)
    if args.goal is not None:
        d.pop("waypoints_ned_m", None)
        d["goal_ned_m"] = list(args.goal)
    if args.waypoint:
        d.pop("goal_ned_m", None)
        d["waypoints_ned_m"] = [list(w) for w in args.waypoint]
    try:
        key_text = signing_key_text(args, env)
    except OSError as exc:
        raise ConfigError(
            f"cannot read the signing key file {exc.filename}: {exc.strerror}"
        ) from None
    _merge(
        d,
        "mavlink",
        {
            "url": args.mavlink,
            "baud": args.baud,
            "system_id": args.system_id,
            "component_id": args.component_id,
            "signing_key": key_text,
            "takeoff_alt_m": args.takeoff_alt,
            "takeoff_ready_timeout_s": args.takeoff_wait_s,
            "request_mode": False if args.no_request_mode else None,
            "frame_clock": args.frame_clock,
            "telemetry_rate_hz": args.telemetry_rate_hz,
        },
    )
    _merge(
        d,
        "zenoh",
        {
            "listen": list(args.zenoh_listen) or None,
            "connect": list(args.zenoh_connect) or None,
            "config_file": str(args.zenoh_config) if args.zenoh_config else None,
        },
    )
    _merge(
        d,
        "failsafe",
        {
            "frame_timeout_s": args.frame_timeout_s,
            "frame_loss_s": args.frame_loss_s,
            "telemetry_timeout_s": args.telemetry_timeout_s,
        },
    )
    _merge(d, "proximity", {"enabled": args.obstacle_distance})
    _merge(
        d, "perception", {"threshold_m": args.threshold_m, "safety_margin_m": args.safety_margin_m}
    )
    cfg = _from_dict_of_file(d, args.config)
    z = cfg.zenoh
    if not z.listen and not z.connect and z.config_file is None:
        # plant-sim's default listen endpoint
        cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(z, connect=(DEFAULT_ENDPOINT,)))
    return cfg
