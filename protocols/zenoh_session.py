"""Zenoh session settings both processes (and the camera publisher) open sessions with.

Explicit endpoints and multicast scouting off by default (DESIGN.md: tests never rely on
scouting), or a Zenoh JSON5 config file for routers, TLS and access control, with any
endpoints given on top.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import zenoh

__all__ = ["ZenohSettings", "zenoh_config"]


@dataclass(frozen=True)
class ZenohSettings:
    """Where a Zenoh session listens / connects; ``config_file`` is a Zenoh JSON5 file."""

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: Path | None = None
    mode: str = "peer"

    def describe(self) -> str:
        """``listen:E,connect:E`` for readiness lines and logs; ``config`` when the
        endpoints come from the config file only."""
        eps = [f"listen:{e}" for e in self.listen] + [f"connect:{e}" for e in self.connect]
        return ",".join(eps) or "config"


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """The session config: the file (if any), else mode with multicast scouting off; then
    the listen/connect endpoints."""
    if settings.config_file is not None:
        conf = zenoh.Config.from_file(str(settings.config_file))
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(settings.mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
    if settings.listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    if settings.connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    return conf
