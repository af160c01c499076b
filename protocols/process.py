"""What every stereo-avoid process does the same way at its edges.

Command-line flags for Zenoh endpoints and the MAVLink signing key, and the service
lifecycle: open, announce readiness, run until SIGINT/SIGTERM, close. Each process's
``__main__`` still owns its own flags and the one place they become its config.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

from protocols.readiness import announce_ready, withdraw_ready
from protocols.signing import SIGNING_KEY_ENV

SIGNING_KEY_FILE_ENV = SIGNING_KEY_ENV + "_FILE"  # a path: the key file (containers)

__all__ = [
    "DEFAULT_ENDPOINT",
    "Service",
    "add_signing_arguments",
    "add_zenoh_arguments",
    "default_listen",
    "run_until_signalled",
    "signing_key_text",
]


class Service(Protocol):
    """The lifecycle :func:`run_until_signalled` drives."""

    def open(self) -> None: ...
    def readiness_line(self) -> str: ...
    def run(self, should_stop: Callable[[], bool]) -> None: ...
    def close(self) -> dict[str, Any]: ...


#: where a publisher (plant-sim, stereo-camera) listens and the companion connects when
#: no endpoint and no config file is given
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def default_listen(listen, connect, config_file) -> tuple[str, ...]:
    """``listen`` as given, or :data:`DEFAULT_ENDPOINT` when nothing at all is given."""
    if not listen and not connect and config_file is None:
        return (DEFAULT_ENDPOINT,)
    return tuple(listen)


def add_zenoh_arguments(parser, *, listen_default: str, connect_help: str) -> None:
    """``--zenoh-listen``, ``--zenoh-connect`` (both repeatable) and ``--zenoh-config``."""
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help=f"Zenoh listen endpoint, repeatable ({listen_default})",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to connect to ({connect_help}), repeatable",
    )
    parser.add_argument(
        "--zenoh-config", type=Path, help="Zenoh JSON5 config file (routers, TLS, ACL)"
    )


def add_signing_arguments(parser) -> None:
    """``--signing-key`` and ``--signing-key-file`` (the environment is the third source)."""
    parser.add_argument(
        "--signing-key",
        metavar="HEX|PASSPHRASE",
        help=f"MAVLink 2 signing key (prefer --signing-key-file or ${SIGNING_KEY_ENV})",
    )
    parser.add_argument(
        "--signing-key-file",
        type=Path,
        help=f"file holding the signing key (or ${SIGNING_KEY_FILE_ENV})",
    )


def signing_key_text(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> str | None:
    """The key text from ``--signing-key-file``, else ``--signing-key``, else the
    environment (``$STEREO_AVOID_SIGNING_KEY_FILE``, a file, else
    ``$STEREO_AVOID_SIGNING_KEY``); None when signing is off.

    Raises
    ------
    OSError
        If the key file cannot be read.
    """
    env = os.environ if env is None else env
    if args.signing_key_file is not None:
        return args.signing_key_file.read_text(encoding="utf-8")
    if args.signing_key:
        return args.signing_key
    key_file = env.get(SIGNING_KEY_FILE_ENV)
    if key_file:
        return Path(key_file).read_text(encoding="utf-8")
    return env.get(SIGNING_KEY_ENV) or None


def run_until_signalled(
    service: Service, *, log_name: str, ready_file: Path | None = None
) -> dict[str, Any]:
    """Open ``service``, announce readiness (stdout and ``ready_file``), run it until
    SIGINT/SIGTERM or until it returns, then close it; returns :meth:`close`'s stats."""
    stop = threading.Event()

    def _on_signal(signum, _frame) -> None:
        logging.getLogger(log_name).info("signal %d: stopping", signum)
        stop.set()

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        service.open()
        announce_ready(service.readiness_line(), ready_file)
        service.run(stop.is_set)
    finally:
        withdraw_ready(ready_file)
        stats = service.close()
        for s, handler in previous.items():
            signal.signal(s, handler)
    return stats
