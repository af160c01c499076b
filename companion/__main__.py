"""``python -m companion`` / ``companion``: the onboard avoidance service.

Parses the command line (and ``--config`` file) into a
:class:`~companion.config.CompanionConfig` in one place and runs :func:`run`. Once MAVLink
and Zenoh are open it prints one readiness line on stdout (one line; wrapped here)::

    COMPANION READY mavlink=udpout:127.0.0.1:14550 zenoh=connect:tcp/127.0.0.1:7447
        key=stereo_avoid/sim1/stereo status=stereo_avoid/sim1/companion/status
        sysid=1 compid=196 signing=off

then ``COMPANION EVENT <name> {json}`` lines (link up/lost, autopilot, phase, hold, resume,
signing refusals, takeoff steps) and at exit (SIGINT, SIGTERM) ``COMPANION STATS {json}``.
Exit status 0 on a clean stop, 2 on a configuration error, 1 if a socket cannot be opened,
3 if ``--takeoff-alt`` was refused by the autopilot or did not complete (the service stops
rather than steer a vehicle that is not flying).
"""

from __future__ import annotations

import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from protocols.process import run_until_signalled
from protocols.threads import configure_threads

__all__ = ["main", "run"]


def run(
    config,
    ready_file: Path | None = None,
    health_file: Path | None = None,
    observers: Sequence = (),
) -> int:
    """Open the service, print the readiness line, run until SIGINT/SIGTERM, print stats.

    With ``ready_file`` the readiness line is also written there (sockets bound); it is
    removed at exit. With ``health_file`` the service rewrites it every second
    (:mod:`companion.health`: can it steer now?). ``observers``: recorders and viewers
    (:mod:`companion.observe`).
    """
    from companion.health import HealthFile
    from companion.service import CompanionService

    service = CompanionService(config, observers=observers)
    if health_file is not None:
        service.health = HealthFile(health_file)
    stats = run_until_signalled(service, log_name="companion", ready_file=ready_file)
    print("COMPANION STATS " + json.dumps(stats, sort_keys=True), flush=True)
    if service.fatal is not None:
        print(f"companion: {service.fatal}", file=sys.stderr, flush=True)
        return 3
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point (``companion``)."""
    try:
        threads = configure_threads()
    except ValueError as exc:
        print(f"companion: configuration error: {exc}", file=sys.stderr)
        return 2
    from companion.config import ConfigError, build_parser, config_from_args
    from protocols.logfile import start_logging

    args = build_parser().parse_args(argv)
    if not start_logging("companion", args.log_file, args.log_level):
        return 2
    logging.getLogger("companion").info("companion: %s", threads.describe())
    try:
        config = config_from_args(args)
    except ConfigError as exc:
        print(f"companion: configuration error: {exc}", file=sys.stderr)
        return 2
    try:
        from companion.viz.options import ViewOptionError, observers_from_args

        observers = observers_from_args(args.record, args.rerun)
    except ViewOptionError as exc:
        print(f"companion: configuration error: {exc}", file=sys.stderr)
        return 2
    try:
        return run(config, args.ready_file, args.health_file, observers)
    except OSError as exc:
        print(f"companion: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
