"""``python -m plant_sim`` / ``plant-sim``: the autopilot-and-world emulator process.

Parses the command line into a :class:`~plant_sim.service.PlantConfig` in one place
(:func:`config_from_args`) and runs :func:`run`. Once every socket is bound it prints one
readiness line on stdout (one line; wrapped here)::

    PLANT_SIM READY mavlink=udpin:0.0.0.0:14550,udpout:127.0.0.1:14551
        zenoh=listen:tcp/127.0.0.1:7447 key=stereo_avoid/sim1/stereo speedup=1

and at exit (SIGINT, SIGTERM, or ``--duration``) flushes the logs and prints
``PLANT_SIM STATS {json}``. With ``--pose-from URL`` it is a camera only
(:mod:`plant_sim.camera_only`): the pose comes from an external autopilot, and the
readiness line reads ``PLANT_SIM READY mode=camera-only pose-from=URL zenoh=... key=...``.
Exit status 0 on a clean stop, 2 on a bad configuration.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from protocols.process import (
    DEFAULT_ENDPOINT,
    add_signing_arguments,
    add_zenoh_arguments,
    default_listen,
    run_until_signalled,
    signing_key_text,
)
from protocols.threads import configure_threads

__all__ = ["build_parser", "config_from_args", "main", "run"]


def _speedup(text: str) -> float:
    if text.lower() in ("max", "inf"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"speedup must be a number or 'max', got {text!r}"
        ) from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"speedup must be > 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="plant-sim",
        description="Quadrotor plant + ArduCopter-compatible MAVLink autopilot + "
        "stereo camera over Zenoh.",
    )
    p.add_argument("--scenario", type=Path, help="scenario .toml/.json (default: the paper's §6)")
    p.add_argument(
        "--mavlink",
        action="append",
        metavar="URL",
        help="MAVLink endpoint, repeatable: udpin:HOST:PORT | udpout:HOST:PORT "
        "(default udpin:127.0.0.1:14550: this host only; other interfaces need an explicit "
        "URL, and MAVLink signing is advised there)",
    )
    add_zenoh_arguments(
        p,
        listen_default=f"default {DEFAULT_ENDPOINT}",
        connect_help="router or companion",
    )
    _add_simulation_arguments(p)
    _add_signing_and_log_arguments(p)
    _add_camera_only_arguments(p)
    p.add_argument(
        "--ready-file",
        type=Path,
        help="also write the readiness line to this file (removed at exit): a healthcheck",
    )
    p.add_argument(
        "--log-file", type=Path, help="also copy stdout and stderr to this file (appended)"
    )
    return p


def _add_simulation_arguments(p: argparse.ArgumentParser) -> None:
    """Camera, vehicle id, pace, duration, start state and autopilot flavour."""
    p.add_argument("--no-camera", action="store_true", help="do not render or publish frames")
    p.add_argument("--camera-rate-hz", type=float, help="override the scenario's camera rate")
    p.add_argument("--vehicle-id", help="override the scenario's vehicle id (Zenoh keys)")
    p.add_argument(
        "--speedup",
        type=_speedup,
        default=1.0,
        help="simulation seconds per wall second, or 'max' (default 1)",
    )
    p.add_argument(
        "--duration", type=float, metavar="SIM_S", help="stop after this simulation time"
    )
    p.add_argument(
        "--start-on-ground",
        action="store_true",
        help="start disarmed on the ground below the start point",
    )
    p.add_argument(
        "--autopilot-flavour",
        choices=["ardupilot", "px4"],
        default="ardupilot",
        help="look like an ArduCopter (default) or a PX4 multicopter: PX4 heartbeat and "
        "main/sub modes, OFFBOARD only after a > 2 Hz setpoint stream, offboard-loss "
        "failsafe after COM_OF_LOSS_T (1 s) to Hold, NAV_TAKEOFF in AMSL",
    )


def _add_signing_and_log_arguments(p: argparse.ArgumentParser) -> None:
    """MAVLink signing, the run's logs and rates, the log level."""
    add_signing_arguments(p)
    p.add_argument(
        "--signing-state",
        type=Path,
        metavar="FILE",
        help="where the signing replay-protection timestamps survive restarts (default "
        "$XDG_STATE_HOME/stereo-avoid/plant-sim-signing-<key id>.json)",
    )
    p.add_argument(
        "--log-dir",
        type=Path,
        help="directory for plant_sim.tlog and truth.csv (default runs/plant_sim-<time>)",
    )
    p.add_argument("--no-logs", action="store_true", help="write no .tlog / truth log")
    p.add_argument(
        "--autopilot-rate-hz",
        type=float,
        default=50.0,
        help="autopilot loop rate, simulation time (max telemetry rate)",
    )
    p.add_argument(
        "--truth-rate-hz", type=float, default=50.0, help="truth-log rows per sim second"
    )
    p.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])


def _add_camera_only_arguments(p: argparse.ArgumentParser) -> None:
    """Camera-only mode: render from an external autopilot's pose."""
    cam = p.add_argument_group(
        "camera-only mode",
        "follow an external MAVLink autopilot (ArduPilot/PX4 SITL, a HIL rig): no physics, "
        "no autopilot of our own; render the scenario from the autopilot's pose",
    )
    cam.add_argument(
        "--pose-from",
        metavar="URL",
        help="pymavlink URL of the autopilot, e.g. tcp:127.0.0.1:5762 (ArduPilot SITL "
        "SERIAL1) or udpin:0.0.0.0:14541; frames are stamped with its boot time "
        "(run the companion with --frame-clock autopilot)",
    )
    cam.add_argument(
        "--pose-offset-ned",
        nargs=3,
        type=float,
        metavar=("N", "E", "D"),
        default=(0.0, 0.0, 0.0),
        help="scenario position = autopilot LOCAL_NED + this offset [m] (default 0 0 0)",
    )
    cam.add_argument(
        "--pose-rate-hz",
        type=float,
        default=50.0,
        help="LOCAL_POSITION_NED and ATTITUDE rate requested (>= 30, default 50)",
    )
    cam.add_argument(
        "--target-system",
        type=int,
        default=0,
        help="the autopilot's system id (default 0: the first autopilot heard)",
    )


def _camera_only_config(args: argparse.Namespace, scenario):
    from plant_sim.camera_only import CameraOnlyConfig
    from protocols.zenoh_session import ZenohSettings

    clashes = [
        flag
        for flag, given in (
            ("--mavlink", bool(args.mavlink)),
            ("--speedup", args.speedup != 1.0),
            ("--duration", args.duration is not None),
            ("--start-on-ground", args.start_on_ground),
            ("--autopilot-flavour", args.autopilot_flavour != "ardupilot"),
        )
        if given
    ]
    if signing_key_text(args) is not None:
        raise ValueError(
            "MAVLink signing is not supported with --pose-from yet: give the camera an "
            "unsigned link (e.g. a mavlink-router endpoint) or run without a key"
        )
    if clashes:
        raise ValueError(
            f"--pose-from follows an external autopilot: {', '.join(clashes)} do not apply "
            "(set them on the autopilot)"
        )
    listen = default_listen(args.zenoh_listen, args.zenoh_connect, args.zenoh_config)
    log_dir = None
    if not args.no_logs:
        log_dir = args.log_dir or Path("runs") / time.strftime("plant_sim-%Y%m%d-%H%M%S")
    return CameraOnlyConfig(
        scenario=scenario,
        pose_from=args.pose_from,
        zenoh=ZenohSettings(
            listen=listen, connect=tuple(args.zenoh_connect), config_file=args.zenoh_config
        ),
        offset_ned_m=tuple(args.pose_offset_ned),
        log_dir=log_dir,
        pose_rate_hz=args.pose_rate_hz,
        truth_rate_hz=args.truth_rate_hz,
        target_system=args.target_system,
    )


def config_from_args(args: argparse.Namespace):
    """The one place CLI flags become a :class:`PlantConfig`, or a
    :class:`~plant_sim.camera_only.CameraOnlyConfig` with ``--pose-from`` (raises
    ValueError if invalid)."""
    from plant_sim.autopilot.link import parse_endpoint
    from plant_sim.scenario import load_scenario, paper_scenario
    from plant_sim.service import PlantConfig
    from protocols.keys import validate_vehicle_id
    from protocols.signing import SigningKey
    from protocols.zenoh_session import ZenohSettings

    scenario = load_scenario(args.scenario) if args.scenario else paper_scenario()
    if args.vehicle_id:
        scenario = dataclasses.replace(scenario, vehicle_id=validate_vehicle_id(args.vehicle_id))
    camera = scenario.camera
    if args.no_camera:
        camera = dataclasses.replace(camera, enabled=False)
    if args.camera_rate_hz is not None:
        if not args.camera_rate_hz > 0:
            raise ValueError(f"--camera-rate-hz must be > 0, got {args.camera_rate_hz}")
        camera = dataclasses.replace(camera, rate_hz=args.camera_rate_hz)
    scenario = dataclasses.replace(scenario, camera=camera)
    if args.pose_from:
        return _camera_only_config(args, scenario)
    if args.start_on_ground:
        scenario = dataclasses.replace(
            scenario, start=dataclasses.replace(scenario.start, airborne=False)
        )
    endpoints = tuple(parse_endpoint(u) for u in (args.mavlink or ["udpin:127.0.0.1:14550"]))
    listen = default_listen(args.zenoh_listen, args.zenoh_connect, args.zenoh_config)
    key_text = signing_key_text(args)
    signing_key = SigningKey.from_text(key_text) if key_text is not None else None
    signing_state = args.signing_state
    if signing_key is not None and signing_state is None:
        signing_state = default_signing_state(signing_key)
    log_dir = None
    if not args.no_logs:
        log_dir = args.log_dir or Path("runs") / time.strftime("plant_sim-%Y%m%d-%H%M%S")
    if args.duration is not None and not args.duration > 0:
        raise ValueError(f"--duration must be > 0, got {args.duration}")
    return PlantConfig(
        scenario=scenario,
        mavlink=endpoints,
        zenoh=ZenohSettings(
            listen=listen, connect=tuple(args.zenoh_connect), config_file=args.zenoh_config
        ),
        speedup=args.speedup,
        signing_key=signing_key,
        signing_state=signing_state,
        log_dir=log_dir,
        autopilot_rate_hz=args.autopilot_rate_hz,
        truth_rate_hz=args.truth_rate_hz,
        duration_s=args.duration,
        autopilot_flavour=args.autopilot_flavour,
    )


def default_signing_state(key) -> Path:
    """Per-key state file under ``$XDG_STATE_HOME`` (``~/.local/state``); the key id is a
    hash of a hash, so the file name reveals nothing of the key."""
    import hashlib

    base = os.environ.get("XDG_STATE_HOME") or os.path.join(
        os.path.expanduser("~"), ".local", "state"
    )
    key_id = hashlib.sha256(hashlib.sha256(key.secret).digest()).hexdigest()[:16]
    return Path(base) / "stereo-avoid" / f"plant-sim-signing-{key_id}.json"


def run(config, ready_file: Path | None = None) -> int:
    """Open the plant, print the readiness line, run until stopped, close, print stats.

    With ``ready_file`` the readiness line is also written there once every socket is
    bound, and the file is removed at exit (container healthchecks test for it).
    """
    from plant_sim.camera_only import CameraOnlyConfig, CameraOnlyService
    from plant_sim.service import PlantService, stats_line

    service = (
        CameraOnlyService(config) if isinstance(config, CameraOnlyConfig) else PlantService(config)
    )
    stats = run_until_signalled(service, log_name="plant_sim", ready_file=ready_file)
    print(stats_line(stats), flush=True)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point (``plant-sim``)."""
    try:
        threads = configure_threads()
    except ValueError as exc:
        print(f"plant-sim: configuration error: {exc}", file=sys.stderr)
        return 2
    from protocols.logfile import start_logging

    args = build_parser().parse_args(argv)
    if not start_logging("plant-sim", args.log_file, args.log_level):
        return 2
    logging.getLogger("plant_sim").info("plant-sim: %s", threads.describe())
    try:
        config = config_from_args(args)
    except (ValueError, OSError) as exc:
        print(f"plant-sim: configuration error: {exc}", file=sys.stderr)
        return 2
    try:
        return run(config, args.ready_file)
    except OSError as exc:
        print(f"plant-sim: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
