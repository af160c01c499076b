"""Modes and takeover: engaging GUIDED/OFFBOARD, acknowledgements, another setpoint source.

A mixin of :class:`~companion.core.CompanionCore`. The phase machine is
:class:`~companion.link.mode_watch.ModeWatch`, the twin and foreign-source rule
:class:`~companion.takeover.TakeoverGuard`; this job carries their requests and notices
out and reacts to a phase change (the first setpoint at once on engaging).
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.outbox import SEV_WARNING
from companion.link.flavour import Flavour, profile_for
from companion.link.messages import set_mode_command
from companion.link.mode_watch import ControlPhase

_log = logging.getLogger("companion")

__all__ = ["ModesJob"]


class ModesJob:
    """Who steers: the mode watch, mode requests and their ACKs, another source.

    Owns ``modes``, ``takeover``, ``_takeover_blocked``, ``_last_mode_request``.
    """

    def _steering(self, now_s: float) -> bool:
        """Our setpoints are flown now: the autopilot in a mode we steer, healthy inputs,
        and alone on the link."""
        return (
            self.modes.steering
            and self.failsafe.status.health.ok
            and self.policy is not None
            and self._may_steer(now_s)
        )

    def _may_steer(self, now_s: float) -> bool:
        """Alone on the link, and it was heard long enough to know (wall seconds)."""
        return not self._takeover_blocked and now_s >= self._listen_until_s

    def _check_takeover(self, now_s: float) -> None:
        """Refuse to steer, loudly, while another setpoint source is around."""
        state = self.takeover.state(now_s)
        if state.blocked == self._takeover_blocked:
            return
        self._takeover_blocked = state.blocked
        if state.blocked:
            self.counters.takeover_refusals += 1
            _log.error("not steering: %s; waiting until we are alone", state.reason)
            self.out.notice("Avoidance refused: another setpoint source", SEV_WARNING)
            self.out.event("takeover", blocked=True, reason=state.reason)
        else:
            _log.warning(
                "no other setpoint source for %.0f s: steering allowed again", self.takeover.quiet_s
            )
            self.out.notice("Avoidance: alone again, steering allowed")
            self.out.event("takeover", blocked=False, reason="")

    def _mode_heartbeat(self, flavour: Flavour, custom_mode: int, now_s: float) -> None:
        before = self.modes.phase
        for notice in self.modes.on_heartbeat(now_s, flavour, custom_mode):
            self.out.notice(notice)
        self._after_phase_change(before, now_s)

    def _after_phase_change(self, before: ControlPhase, now_s: float) -> None:
        after = self.modes.phase
        if after is before:
            return
        self.out.event(
            "phase",
            phase=after.value,
            mode=self.modes.mode_text(),
            setpoints_sent=self.counters.setpoints_sent,
        )
        if after is ControlPhase.RELEASED:
            self.counters.mode_releases += 1
        if after in (ControlPhase.ACTIVE, ControlPhase.PRESTREAM) and self.policy is not None:
            self.policy.reset()  # first setpoint goes out at once
            self.speed_policy.reset()  # ArduCopter resets its speed on entering GUIDED
            self._resend_now(now_s)

    def _on_ack(self, msg, now_s: float) -> None:
        accepted = msg.result == mavlink.MAV_RESULT_ACCEPTED
        if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self.streams.on_stream_ack(accepted)
            return
        if msg.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if accepted:
                self.counters.speed_limits_accepted += 1
            else:
                self.counters.speed_limits_refused += 1
            if not accepted and self.counters.speed_limits_refused == 1:
                _log.info("autopilot refuses DO_CHANGE_SPEED (result %d): the carrot alone "
                          "bounds the speed", msg.result)  # fmt: skip
            return
        if msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            before = self.modes.phase
            if accepted:
                mode = self._last_mode_request
                if mode is not None:
                    for notice in self.modes.on_mode_accepted(now_s, mode.custom_mode):
                        self.out.notice(notice)
            else:
                result = mavlink.enums["MAV_RESULT"].get(msg.result)
                for notice in self.modes.on_mode_refused(
                    now_s, result.name if result else str(msg.result)
                ):
                    self.out.notice(notice, SEV_WARNING)
            self._after_phase_change(before, now_s)

    def _request_mode(self, request) -> None:
        cfg = self.config.link
        self._last_mode_request = request
        self.counters.mode_requests += 1
        _log.info("requesting %s", request.name)
        self.out.send(set_mode_command(cfg.target_system, cfg.target_component, request))

    def _mode_timer(self, now_s: float) -> None:
        """Engagement and retries: the mode watch's request, when one is due."""
        before = self.modes.phase
        request = self.modes.tick(now_s)
        if request is not None:
            self._request_mode(request)
        self._after_phase_change(before, now_s)

    def _must_stream(self) -> bool:
        flavour = self.modes.flavour
        return (
            flavour is not None
            and profile_for(flavour).streams_setpoints
            and (self.modes.steering or self.modes.streaming_hold)
        )
