"""Parameter fetch: the autopilot's own speed limit (ArduCopter's WPNAV_SPEED), asked for.

A component of :class:`~companion.core.CompanionCore` that owns its state: the value once
reported and the requests made for it. DO_CHANGE_SPEED overrides WPNAV_SPEED without a
clip, so the companion states no speed before it knows the pilot's own limit (ours may
only lower it). Typed in: the step's time, PARAM_VALUE. Out: PARAM_REQUEST_READ in the
step's :class:`~companion.core.outbox.Outbox` (every 2 s, at most 5 times), and
:attr:`ParamJob.wpnav_speed_mps`.
"""

from __future__ import annotations

import logging
import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import LinkConfig
from companion.core.outbox import Outbox

_log = logging.getLogger("companion")

__all__ = ["WPNAV_SPEED", "ParamJob"]

WPNAV_SPEED = "WPNAV_SPEED"  # ArduCopter's horizontal speed limit parameter [cm/s]
_MAX_REQUESTS = 5
_REQUEST_PERIOD_S = 2.0  # [s wall]


class ParamJob:
    """WPNAV_SPEED: asked for until reported (or given up), then the ceiling of our limits.

    Parameters
    ----------
    link : LinkConfig
        The autopilot's ids.
    out : Outbox
        Where the requests go (the core's, per step).
    """

    def __init__(self, link: LinkConfig, out: Outbox) -> None:
        self._link = link
        self._out = out
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: the value is asked for again."""
        self.wpnav_speed_mps: float | None = None  # the autopilot's own speed limit
        self._next_request_s = 0.0
        self._requests = 0

    def request_if_due(self, now_s: float) -> None:
        """Ask for WPNAV_SPEED when due (not yet reported; every 2 s, at most 5 times)."""
        if self.wpnav_speed_mps is not None:
            return
        if now_s < self._next_request_s or self._requests >= _MAX_REQUESTS:
            return
        self._requests += 1
        if self._requests == _MAX_REQUESTS:
            _log.warning(
                "autopilot does not report %s: no speed limit stated, the carrot "
                "alone bounds the speed",
                WPNAV_SPEED,
            )
        self._next_request_s = now_s + _REQUEST_PERIOD_S
        cfg = self._link
        self._out.send(
            mavlink.MAVLink_param_request_read_message(
                cfg.target_system, cfg.target_component, WPNAV_SPEED.encode(), -1
            )
        )

    def on_param_value(self, msg) -> None:
        """WPNAV_SPEED [cm/s]: the ceiling of every speed limit we state (ArduPilot)."""
        name = (
            msg.param_id
            if isinstance(msg.param_id, str)
            else msg.param_id.decode("ascii", "replace")
        )
        value = float(msg.param_value)
        if name.split("\x00", 1)[0] != WPNAV_SPEED or not (math.isfinite(value) and value > 0):
            return
        if self.wpnav_speed_mps is None:
            _log.info(
                "autopilot WPNAV_SPEED %.2f m/s: stated speed limits stay below it", value / 100.0
            )
        self.wpnav_speed_mps = value / 100.0
