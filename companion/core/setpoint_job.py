"""Setpoints and speed: what target goes out when, and the speed limit the autopilot is told.

A mixin of :class:`~companion.core.CompanionCore`. Targets follow the profile's setpoint
policy (:mod:`companion.link.setpoints`: persisting targets re-sent as a keep-alive, or a
stream); the envelope's speed limit goes out as DO_CHANGE_SPEED below the autopilot's own
WPNAV_SPEED, with the climb or descent speed that keeps the flown slope within the path's
(:mod:`companion.link.speed_limit`), and telemetry above it is reported.
"""

from __future__ import annotations

import logging

from companion.core.events import SendSetpoint
from companion.core.outbox import SEV_WARNING
from companion.failsafe import Response
from companion.link.flavour import profile_for
from companion.link.setpoints import PositionTarget, position_target_message
from companion.link.speed_limit import change_speed_command

_log = logging.getLogger("companion")

__all__ = ["SetpointJob"]


class SetpointJob:
    """Setpoints on the wire and the speed limit stated to the autopilot.

    Owns ``policy``, ``speed_policy``, ``_engaged``, ``_overspeed_notice_s``; reads the
    autopilot's WPNAV_SPEED from the ``params`` component (:mod:`~companion.core.param_job`).
    """

    def _send_target(self, target: PositionTarget, now_s: float, frame_ns: int | None) -> None:
        cfg = self.config.link
        ap_ns = None
        if frame_ns is not None:
            ap_ns = self.clock.frame_to_autopilot_ns(frame_ns)
        if ap_ns is None:
            ap_ns = (self.telemetry.last_boot_ms or 0) * 1_000_000
        msg = position_target_message(
            target, ap_ns // 1_000_000, cfg.target_system, cfg.target_component
        )
        self.out.append(SendSetpoint(msg, target))
        self.counters.mavlink_sent += 1
        assert self.policy is not None
        self.policy.sent(target, now_s)
        self.counters.setpoints_sent += 1
        if not self._engaged:
            self._engaged = True
            boot_ms = self.telemetry.last_boot_ms
            self.out.event(
                "steering",
                setpoint_ned_m=list(target.pos_ned_m),
                autopilot_time_s=None if boot_ms is None else boot_ms / 1e3,
            )

    def _setpoint_timer(self, now_s: float) -> None:
        """Keep-alive or stream: re-send when the policy says so."""
        policy = self.policy
        if policy is not None and (
            policy.due(now_s) or (policy.last is None and self.modes.must_stream())
        ):
            self._resend_now(now_s)

    def _resend_now(self, now_s: float) -> None:
        """Keep-alive / PX4 stream / hold: (re)send the appropriate target."""
        if self.policy is None or not self._may_steer(now_s):
            return
        hold = self.failsafe
        if self.modes.streaming_hold or (self.modes.steering and hold.hold is not Response.STEER):
            target = hold.hold_target or hold.current_hold(self._hold_view())
        elif (
            self.modes.steering and not self.failsafe.status.health.ok and self.modes.must_stream()
        ):
            target = hold.current_hold(self._hold_view())
        elif self.modes.steering and (self.failsafe.status.health.ok or self.policy.last is None):
            target = self.policy.last
            if target is None and self.modes.must_stream():
                target = hold.current_hold(self._hold_view())
        else:
            return
        if target is not None:
            self._send_target(target, now_s, None)

    def _state_speed_limit(self, envelope, now_s: float) -> None:
        """ArduPilot: the ``envelope``'s speed limit as MAV_CMD_DO_CHANGE_SPEED, and the
        climb or descent speed for its path (see :mod:`companion.link.speed_limit`); other
        autopilots: the carrot alone."""
        limit_mps = envelope.speed_limit_mps
        flavour = self.modes.flavour
        if flavour is None or not profile_for(flavour).states_speed_limit:
            return
        wpnav_speed_mps = self.params.wpnav_speed_mps
        if wpnav_speed_mps is None:
            # never state a speed before we know the pilot's own limit (ParamJob); the
            # carrot bounds the speed meanwhile
            self.params.request_if_due(now_s)
            return
        cfg = self.config.link
        horizontal_mps = min(limit_mps, wpnav_speed_mps)
        speed = self.speed_policy.due(horizontal_mps, now_s)
        if speed is not None:
            self.out.send(change_speed_command(speed, cfg.target_system, cfg.target_component))
            self.speed_policy.sent(speed, now_s)
            self.counters.speed_limits_sent += 1
        climb = self.speed_policy.climb
        stated_mps = self.speed_policy.quantize(horizontal_mps)
        vertical = climb.due(envelope.path_dir_ned, stated_mps, envelope.speed_mps, now_s)
        if vertical is not None:
            kind, vertical_mps = vertical
            self.out.send(
                change_speed_command(vertical_mps, cfg.target_system, cfg.target_component, kind)
            )
            climb.sent(kind, vertical_mps, now_s)
            self.counters.speed_limits_sent += 1

    def _on_speed_ack(self, accepted: bool, result: int) -> None:
        """A COMMAND_ACK of DO_CHANGE_SPEED: counted (refused: said once)."""
        if accepted:
            self.counters.speed_limits_accepted += 1
        else:
            self.counters.speed_limits_refused += 1
        if not accepted and self.counters.speed_limits_refused == 1:
            _log.info(
                "autopilot refuses DO_CHANGE_SPEED (result %d): the carrot alone bounds the speed",
                result,
            )

    def _check_overspeed(self, out) -> None:
        """Warn (log + STATUSTEXT, at most every 5 s) when telemetry exceeds the limit."""
        env = out.envelope
        if not env.overspeed:
            return
        self.counters.overspeed_frames += 1
        now_s = self._now_s
        if now_s - self._overspeed_notice_s >= 5.0:
            self._overspeed_notice_s = now_s
            self.out.notice(
                f"Speed {env.speed_mps:.1f} m/s above limit {env.speed_limit_mps:.1f} m/s",
                SEV_WARNING,
            )
