"""Takeoff: the ``--takeoff-alt`` sequence fed with what it watches, its actions sent.

A component of :class:`~companion.core.CompanionCore` that owns its state: the sequence
(:class:`~companion.link.takeoff.TakeoffSequence`, pure), the autopilot heartbeat held back
from the mode watch while the sequence runs, and the fatal error of a refused takeoff.
Typed in: the messages the sequence watches, the autopilot's heartbeat (flavour, custom
mode, armed), the time of each frame (frames only prove the camera works) and the timer.
Out: its commands, notices and events in the step's :class:`~companion.core.outbox.Outbox`,
and an :class:`Engage` when the climb is over: the held heartbeat, which the core hands to
the mode watch at once. A refused takeoff is fatal (:attr:`TakeoffJob.fatal`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from companion.config import LinkConfig
from companion.core.link_job import statustext
from companion.core.outbox import Outbox
from companion.link.flavour import Flavour
from companion.link.messages import command_long
from companion.link.takeoff import (
    TakeoffCommand,
    TakeoffEvent,
    TakeoffNotice,
    TakeoffSequence,
    TakeoffSettings,
    TakeoffStep,
)

_log = logging.getLogger("companion")

__all__ = ["Engage", "TakeoffJob"]


@dataclass(frozen=True)
class Engage:
    """The climb is over: the mode watch takes this held autopilot heartbeat now."""

    flavour: Flavour
    custom_mode: int


class TakeoffJob:
    """``--takeoff-alt``: the sequence fed and carried out, then steering.

    Parameters
    ----------
    link : LinkConfig
        The takeoff altitude, tolerances and timeouts, and the ids commands go to.
    out : Outbox
        Where the sequence's commands, notices and events go (the core's, per step).
    """

    def __init__(self, link: LinkConfig, out: Outbox) -> None:
        self._link = link
        self._out = out
        self.sequence: TakeoffSequence | None = None  # --takeoff-alt, until finished
        self.fatal: str | None = None  # a refused takeoff: stop the process
        self._held: Engage | None = None  # the heartbeat the mode watch gets afterwards

    def reset(self) -> None:
        """Link lost or autopilot restarted: the sequence and the held heartbeat go (a
        fatal error stays)."""
        self.sequence = None
        self._held = None

    @property
    def busy(self) -> bool:
        """The sequence runs: frames and the autopilot's heartbeat are its."""
        return self.sequence is not None and self.sequence.busy

    def start(self, flavour: Flavour, now_s: float) -> None:
        """The autopilot was found and ``--takeoff-alt`` is set: the sequence starts."""
        cfg = self._link
        self.sequence = TakeoffSequence(
            flavour,
            TakeoffSettings(
                cfg.takeoff_alt_m,
                tolerance_m=cfg.takeoff_tolerance_m,
                climb_timeout_s=cfg.takeoff_timeout_s,
                ready_timeout_s=cfg.takeoff_ready_timeout_s,
            ),
            now_s,
        )

    def tick(self, now_s: float) -> Engage | None:
        """The timer: the sequence's timeouts and retries."""
        if not self.busy:
            return None
        assert self.sequence is not None
        self.sequence.tick(now_s)
        return self._drive(now_s)

    def on_heartbeat(
        self, flavour: Flavour, custom_mode: int, armed: bool, now_s: float
    ) -> Engage | None:
        """The autopilot's heartbeat while :attr:`busy`: held back from the mode watch."""
        assert self.sequence is not None
        self._held = Engage(flavour, custom_mode)
        self.sequence.on_heartbeat(now_s, custom_mode, armed)
        return self._drive(now_s)

    def on_frame(self, now_s: float) -> Engage | None:
        """A frame while :attr:`busy`: the camera works."""
        assert self.sequence is not None
        self.sequence.on_frame(now_s)
        return self._drive(now_s)

    def on_message(self, msg, mtype: str, now_s: float) -> Engage | None:
        """Feed the sequence what it watches of a message, while :attr:`busy`."""
        seq = self.sequence
        assert seq is not None
        if mtype == "EXTENDED_SYS_STATE":
            seq.on_landed_state(now_s, msg.landed_state)
        elif mtype == "LOCAL_POSITION_NED":
            seq.on_position(now_s, msg.time_boot_ms * 1e-3, msg.z)
        elif mtype == "HOME_POSITION":
            seq.on_home_amsl(msg.altitude * 1e-3)
        elif mtype == "GLOBAL_POSITION_INT" and seq.home_amsl_m is None:
            seq.on_home_amsl((msg.alt - msg.relative_alt) * 1e-3)
        elif mtype == "STATUSTEXT":
            seq.on_statustext(statustext(msg))
        elif mtype == "SYS_STATUS":
            seq.on_sys_status(
                now_s,
                msg.onboard_control_sensors_present,
                msg.onboard_control_sensors_health,
            )
        elif mtype == "COMMAND_ACK" and self._ack_is_ours(msg):
            seq.on_ack(now_s, msg.command, msg.result)
        else:
            return None
        return self._drive(now_s)

    def _ack_is_ours(self, msg) -> bool:
        """COMMAND_ACK addressed to us (0 = not filled in by a MAVLink 1 sender)."""
        cfg = self._link
        return getattr(msg, "target_system", 0) in (0, cfg.system_id) and getattr(
            msg, "target_component", 0
        ) in (0, cfg.component_id)

    def _drive(self, now_s: float) -> Engage | None:
        """Carry out the sequence's actions; the held heartbeat once it is over."""
        seq = self.sequence
        if seq is None:
            return None
        cfg = self._link
        for action in seq.pop_actions():
            if isinstance(action, TakeoffCommand):
                if action.name != "REQUEST_MESSAGE":
                    _log.info(
                        "takeoff: sending %s (attempt %d)", action.name, action.confirmation + 1
                    )
                self._out.send(
                    command_long(
                        cfg.target_system,
                        cfg.target_component,
                        action.command,
                        *action.params,
                        confirmation=action.confirmation,
                    )
                )
            elif isinstance(action, TakeoffNotice):
                self._out.notice(action.text, action.severity)
            elif isinstance(action, TakeoffEvent):
                self._out.event("takeoff", **action.fields)
        if seq.step is TakeoffStep.FAILED and self.fatal is None:
            self.fatal = f"takeoff failed: {seq.reason}"
            _log.error("%s; not steering, stopping", self.fatal)
        elif seq.step in (TakeoffStep.DONE, TakeoffStep.SKIPPED) and self._held is not None:
            engage, self._held = self._held, None
            return engage
        return None
