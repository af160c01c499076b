"""Takeoff: the ``--takeoff-alt`` sequence fed with what it watches, its actions sent.

A mixin of :class:`~companion.core.CompanionCore`. The sequence itself is
:class:`~companion.link.takeoff.TakeoffSequence` (pure); while it runs, frames only prove
the camera works and the autopilot's heartbeat is held back from the mode watch, which
gets it once the climb is over (engage at once). A refused takeoff is fatal.
"""

from __future__ import annotations

import logging

from companion.core.link_job import statustext
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
from protocols.stereo_frame import StereoFrame

_log = logging.getLogger("companion")

__all__ = ["TakeoffJob"]


class TakeoffJob:
    """``--takeoff-alt``: the sequence fed and carried out, then steering.

    Owns ``takeoff``, ``_held_heartbeat``, ``fatal``.
    """

    def _start_takeoff(self, flavour: Flavour, now_s: float) -> None:
        """The autopilot was found and ``--takeoff-alt`` is set: the sequence starts."""
        cfg = self.config.link
        self.takeoff = TakeoffSequence(
            flavour,
            TakeoffSettings(
                cfg.takeoff_alt_m,
                tolerance_m=cfg.takeoff_tolerance_m,
                climb_timeout_s=cfg.takeoff_timeout_s,
                ready_timeout_s=cfg.takeoff_ready_timeout_s,
            ),
            now_s,
        )

    def _takeoff_timer(self, now_s: float) -> None:
        if self._takeoff_busy():
            assert self.takeoff is not None
            self.takeoff.tick(now_s)
            self._drive_takeoff(now_s)

    def _takeoff_busy(self) -> bool:
        return self.takeoff is not None and self.takeoff.busy

    def _takeoff_input(self, msg, mtype: str, now_s: float) -> None:
        """Feed the takeoff sequence what it watches (heartbeats go via _on_heartbeat)."""
        seq = self.takeoff
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
            return
        self._drive_takeoff(now_s)

    def _ack_is_ours(self, msg) -> bool:
        """COMMAND_ACK addressed to us (0 = not filled in by a MAVLink 1 sender)."""
        cfg = self.config.link
        return getattr(msg, "target_system", 0) in (0, cfg.system_id) and getattr(
            msg, "target_component", 0
        ) in (0, cfg.component_id)

    def _drive_takeoff(self, now_s: float) -> None:
        """Carry out the sequence's actions; start steering when it is over."""
        seq = self.takeoff
        if seq is None:
            return
        cfg = self.config.link
        for action in seq.pop_actions():
            if isinstance(action, TakeoffCommand):
                if action.name != "REQUEST_MESSAGE":
                    _log.info(
                        "takeoff: sending %s (attempt %d)", action.name, action.confirmation + 1
                    )
                self.out.send(
                    command_long(
                        cfg.target_system,
                        cfg.target_component,
                        action.command,
                        *action.params,
                        confirmation=action.confirmation,
                    )
                )
            elif isinstance(action, TakeoffNotice):
                self.out.notice(action.text, action.severity)
            elif isinstance(action, TakeoffEvent):
                self.out.event("takeoff", **action.fields)
        if seq.step is TakeoffStep.FAILED and self.fatal is None:
            self.fatal = f"takeoff failed: {seq.reason}"
            _log.error("%s; not steering, stopping", self.fatal)
        elif seq.step in (TakeoffStep.DONE, TakeoffStep.SKIPPED) and self._held_heartbeat:
            flavour, custom_mode = self._held_heartbeat
            self._held_heartbeat = None
            self._mode_heartbeat(flavour, custom_mode, now_s)  # engage at once

    def _frame_during_takeoff(self, frame: StereoFrame) -> None:
        self._observe(frame.capture_ns)
        self.counters.frames_during_takeoff += 1  # not steering before the climb
        assert self.takeoff is not None
        self.takeoff.on_frame(self._now_s)
        if self._newest_frame_ns is None or frame.capture_ns > self._newest_frame_ns:
            self._newest_frame_ns = frame.capture_ns  # the camera works: health
        self._drive_takeoff(self._now_s)
