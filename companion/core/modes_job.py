"""Modes and takeover: engaging GUIDED/OFFBOARD, acknowledgements, another setpoint source.

A component of :class:`~companion.core.CompanionCore` that owns its state: the phase
machine (:class:`~companion.link.mode_watch.ModeWatch`), the twin and foreign-source rule
(:class:`~companion.takeover.TakeoverGuard`) with whether it blocks steering now, and the
last mode requested (what an accepting DO_SET_MODE acknowledges). Typed in: the
autopilot's heartbeat (flavour, custom mode), DO_SET_MODE acknowledgements, a twin's
heartbeat, another source's setpoints, the failsafe's hold wish and the timer. Out: mode
requests, notices and events in the step's :class:`~companion.core.outbox.Outbox`, and a
:class:`PhaseChange` whenever the phase moved, on which the core sends the first setpoint
at once when it engages.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from companion.config import LinkConfig
from companion.core.counters import CoreCounters
from companion.core.outbox import SEV_WARNING, Outbox
from companion.link.flavour import Flavour, ModeRequest, profile_for
from companion.link.messages import set_mode_command
from companion.link.mode_watch import ControlPhase, ModeWatch
from companion.takeover import TakeoverGuard

_log = logging.getLogger("companion")

__all__ = ["ModesJob", "PhaseChange"]

_ENGAGING = (ControlPhase.ACTIVE, ControlPhase.PRESTREAM)


@dataclass(frozen=True)
class PhaseChange:
    """The control phase moved from ``before`` to ``after``."""

    before: ControlPhase
    after: ControlPhase

    @property
    def engaging(self) -> bool:
        """Into the control mode (or PX4's pre-stream): the first setpoint goes at once."""
        return self.after in _ENGAGING


class ModesJob:
    """Who steers: the mode watch, mode requests and their ACKs, another source.

    Parameters
    ----------
    link : LinkConfig
        Our ids and the autopilot's, the mode to request, PX4's pre-stream time.
    instance_id : int
        This companion's 32-bit id (the twin rule, :mod:`companion.takeover`).
    out : Outbox
        Where requests, notices and events go (the core's, per step).
    counters : CoreCounters
        ``mode_requests``, ``mode_releases``, ``takeover_refusals``; ``setpoints_sent``
        is read for the phase event.
    """

    def __init__(
        self, link: LinkConfig, instance_id: int, out: Outbox, counters: CoreCounters
    ) -> None:
        self._link = link
        self._out = out
        self._counters = counters
        self.watch = ModeWatch(request_mode=link.request_mode, prestream_s=link.px4_prestream_s)
        self.takeover = TakeoverGuard((link.system_id, link.component_id), instance_id)
        self.takeover_blocked = False  # another setpoint source is around
        self._last_request: ModeRequest | None = None

    def reset(self) -> None:
        """Link lost or autopilot restarted: the phase starts over (the twin rule stays)."""
        self.watch.reset()

    # ---- views -----------------------------------------------------------------------
    @property
    def phase(self) -> ControlPhase:
        return self.watch.phase

    @property
    def steering(self) -> bool:
        """The autopilot is in a mode guidance steers (its setpoints are flown)."""
        return self.watch.steering

    @property
    def streaming_hold(self) -> bool:
        """PX4: a hold streamed in OFFBOARD."""
        return self.watch.streaming_hold

    @property
    def flavour(self) -> Flavour | None:
        """The autopilot's flavour (None: no heartbeat yet since the reset)."""
        return self.watch.flavour

    def mode_text(self) -> str:
        return self.watch.mode_text()

    def must_stream(self) -> bool:
        """The profile streams setpoints (PX4) and we steer or hold in its mode now."""
        flavour = self.watch.flavour
        return (
            flavour is not None
            and profile_for(flavour).streams_setpoints
            and (self.watch.steering or self.watch.streaming_hold)
        )

    # ---- inputs ----------------------------------------------------------------------
    def on_heartbeat(self, flavour: Flavour, custom_mode: int, now_s: float) -> PhaseChange | None:
        """The autopilot's heartbeat (not held back by a takeoff)."""
        before = self.watch.phase
        for notice in self.watch.on_heartbeat(now_s, flavour, custom_mode):
            self._out.notice(notice)
        return self.changed(before)

    def on_mode_ack(self, accepted: bool, result_text: str, now_s: float) -> PhaseChange | None:
        """A COMMAND_ACK of DO_SET_MODE (``result_text``: MAV_RESULT's name)."""
        before = self.watch.phase
        if accepted:
            if self._last_request is not None:
                for notice in self.watch.on_mode_accepted(now_s, self._last_request.custom_mode):
                    self._out.notice(notice)
        else:
            for notice in self.watch.on_mode_refused(now_s, result_text):
                self._out.notice(notice, SEV_WARNING)
        return self.changed(before)

    def tick(self, now_s: float) -> PhaseChange | None:
        """Engagement and retries: the mode watch's request, when one is due."""
        before = self.watch.phase
        request = self.watch.tick(now_s)
        if request is not None:
            self.request(request)
        return self.changed(before)

    def set_hold(self, now_s: float, hold: bool) -> ModeRequest | None:
        """The failsafe wants the autopilot's hold mode (or no longer): the request to
        send, if any (:meth:`request`, after the failsafe's own reports)."""
        return self.watch.set_hold(now_s, hold)

    def request(self, request: ModeRequest) -> None:
        """DO_SET_MODE to the autopilot."""
        cfg = self._link
        self._last_request = request
        self._counters.mode_requests += 1
        _log.info("requesting %s", request.name)
        self._out.send(set_mode_command(cfg.target_system, cfg.target_component, request))

    def changed(self, before: ControlPhase) -> PhaseChange | None:
        """The phase since ``before``: reported (event, releases counted) if it moved."""
        after = self.watch.phase
        if after is before:
            return None
        self._out.event(
            "phase",
            phase=after.value,
            mode=self.watch.mode_text(),
            setpoints_sent=self._counters.setpoints_sent,
        )
        if after is ControlPhase.RELEASED:
            self._counters.mode_releases += 1
        return PhaseChange(before, after)

    # ---- another setpoint source -----------------------------------------------------
    def on_twin_heartbeat(
        self, now_s: float, custom_mode: int, twin_in_control: bool, we_in_control: bool
    ) -> None:
        """A heartbeat from our own system and component: a twin companion."""
        self.takeover.on_twin_heartbeat(now_s, custom_mode, twin_in_control, we_in_control)
        self.check_takeover(now_s)

    def on_foreign_setpoint(self, now_s: float, src: tuple[int, int]) -> None:
        """Setpoints to our autopilot from another (system, component)."""
        self.takeover.on_foreign_setpoint(now_s, src)
        self.check_takeover(now_s)

    def check_takeover(self, now_s: float) -> None:
        """Refuse to steer, loudly, while another setpoint source is around."""
        state = self.takeover.state(now_s)
        if state.blocked == self.takeover_blocked:
            return
        self.takeover_blocked = state.blocked
        if state.blocked:
            self._counters.takeover_refusals += 1
            _log.error("not steering: %s; waiting until we are alone", state.reason)
            self._out.notice("Avoidance refused: another setpoint source", SEV_WARNING)
            self._out.event("takeover", blocked=True, reason=state.reason)
        else:
            _log.warning(
                "no other setpoint source for %.0f s: steering allowed again", self.takeover.quiet_s
            )
            self._out.notice("Avoidance: alone again, steering allowed")
            self._out.event("takeover", blocked=False, reason="")
