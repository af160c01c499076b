"""Setpoints and speed: what target goes out when, and the speed limit the autopilot is told.

A component of :class:`~companion.core.CompanionCore` that owns its state: the setpoint
policy (:mod:`companion.link.setpoints`: persisting targets re-sent as a keep-alive, or a
stream; made when the autopilot is found), the speed limit policy
(:mod:`companion.link.speed_limit`), whether a guidance setpoint went out since the last
reset, and when the last overspeed was said. Typed in: a target with the autopilot time
to stamp it with, the envelope of a processed frame, the autopilot's WPNAV_SPEED (from
:class:`~companion.core.param_job.ParamJob`) and DO_CHANGE_SPEED acknowledgements. Out:
SET_POSITION_TARGET_LOCAL_NED, DO_CHANGE_SPEED (below WPNAV_SPEED, with the climb or
descent speed that keeps the flown slope within the path's), notices and events in the
step's :class:`~companion.core.outbox.Outbox`. Which target to (re)send when is the
core's (it reads the modes and the failsafe); this job carries it out.
"""

from __future__ import annotations

import logging
import math

from companion.config import LinkConfig
from companion.core.counters import CoreCounters
from companion.core.events import SendSetpoint
from companion.core.outbox import SEV_WARNING, Outbox
from companion.link.flavour import Flavour
from companion.link.setpoints import PositionTarget, SetpointPolicy, position_target_message
from companion.link.speed_limit import SpeedLimitPolicy, change_speed_command

_log = logging.getLogger("companion")

__all__ = ["SetpointJob"]

_OVERSPEED_NOTICE_S = 5.0  # at most one overspeed STATUSTEXT per this long [s wall]


class SetpointJob:
    """Setpoints on the wire and the speed limit stated to the autopilot.

    Parameters
    ----------
    link : LinkConfig
        The autopilot's ids, ArduPilot's keep-alive period and PX4's stream rate.
    out : Outbox
        Where setpoints, commands, notices and events go (the core's, per step).
    counters : CoreCounters
        ``setpoints_sent``, ``speed_limits_*``, ``overspeed_frames``.
    """

    def __init__(self, link: LinkConfig, out: Outbox, counters: CoreCounters) -> None:
        self._link = link
        self._out = out
        self._counters = counters
        self.speed_policy = SpeedLimitPolicy()
        self._overspeed_notice_s = -math.inf
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: no policy until the autopilot is found."""
        self.policy: SetpointPolicy | None = None
        self.engaged = False  # a guidance setpoint was sent since the last reset

    def found(self, flavour: Flavour) -> None:
        """The autopilot was found: its flavour's setpoint policy."""
        cfg = self._link
        self.policy = SetpointPolicy(
            flavour,
            ardupilot_period_s=cfg.ardupilot_setpoint_period_s,
            px4_rate_hz=cfg.px4_setpoint_rate_hz,
        )

    def engaging(self) -> None:
        """Into the control mode: the first setpoint goes at once, the speed is stated
        again (ArduCopter resets its speed on entering GUIDED)."""
        if self.policy is not None:
            self.policy.reset()
            self.speed_policy.reset()

    def due(self, now_s: float, must_stream: bool) -> bool:
        """A keep-alive or a stream's next setpoint is due (the timer)."""
        policy = self.policy
        return policy is not None and (policy.due(now_s) or (policy.last is None and must_stream))

    def send(
        self, target: PositionTarget, now_s: float, time_boot_ms: int, last_boot_ms: int | None
    ) -> None:
        """``target`` stamped with ``time_boot_ms`` (autopilot time); the first since the
        reset says "steering" (with the newest autopilot time, ``last_boot_ms``)."""
        cfg = self._link
        msg = position_target_message(target, time_boot_ms, cfg.target_system, cfg.target_component)
        self._out.append(SendSetpoint(msg, target))
        self._counters.mavlink_sent += 1
        assert self.policy is not None
        self.policy.sent(target, now_s)
        self._counters.setpoints_sent += 1
        if not self.engaged:
            self.engaged = True
            self._out.event(
                "steering",
                setpoint_ned_m=list(target.pos_ned_m),
                autopilot_time_s=None if last_boot_ms is None else last_boot_ms / 1e3,
            )

    def state_speed_limit(self, envelope, wpnav_speed_mps: float, now_s: float) -> None:
        """ArduPilot: the ``envelope``'s speed limit, below the pilot's own
        ``wpnav_speed_mps``, as MAV_CMD_DO_CHANGE_SPEED, and the climb or descent speed for
        its path (see :mod:`companion.link.speed_limit`)."""
        cfg = self._link
        horizontal_mps = min(envelope.speed_limit_mps, wpnav_speed_mps)
        speed = self.speed_policy.due(horizontal_mps, now_s)
        if speed is not None:
            self._out.send(change_speed_command(speed, cfg.target_system, cfg.target_component))
            self.speed_policy.sent(speed, now_s)
            self._counters.speed_limits_sent += 1
        climb = self.speed_policy.climb
        stated_mps = self.speed_policy.quantize(horizontal_mps)
        vertical = climb.due(envelope.path_dir_ned, stated_mps, envelope.speed_mps, now_s)
        if vertical is not None:
            kind, vertical_mps = vertical
            self._out.send(
                change_speed_command(vertical_mps, cfg.target_system, cfg.target_component, kind)
            )
            climb.sent(kind, vertical_mps, now_s)
            self._counters.speed_limits_sent += 1

    def on_speed_ack(self, accepted: bool, result: int) -> None:
        """A COMMAND_ACK of DO_CHANGE_SPEED: counted (refused: said once)."""
        if accepted:
            self._counters.speed_limits_accepted += 1
        else:
            self._counters.speed_limits_refused += 1
        if not accepted and self._counters.speed_limits_refused == 1:
            _log.info(
                "autopilot refuses DO_CHANGE_SPEED (result %d): the carrot alone bounds the speed",
                result,
            )

    def check_overspeed(self, envelope, now_s: float) -> None:
        """Warn (log + STATUSTEXT, at most every 5 s) when telemetry exceeds the limit."""
        if not envelope.overspeed:
            return
        self._counters.overspeed_frames += 1
        if now_s - self._overspeed_notice_s >= _OVERSPEED_NOTICE_S:
            self._overspeed_notice_s = now_s
            self._out.notice(
                f"Speed {envelope.speed_mps:.1f} m/s above limit "
                f"{envelope.speed_limit_mps:.1f} m/s",
                SEV_WARNING,
            )
