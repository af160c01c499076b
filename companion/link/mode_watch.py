"""Who is in control: engaging GUIDED/OFFBOARD, failsafe holds, and a pilot taking over.

Pure; times are wall seconds passed in by the caller (heartbeats and mode requests are
link-level, 1 Hz wall-clock events). :class:`ModeWatch` follows the autopilot's HEARTBEAT
mode against what the companion asked for:

* It engages the control mode (GUIDED on ArduPilot, OFFBOARD on PX4 after streaming
  setpoints for ``prestream_s``) when ``request_mode`` is set, or waits for the pilot to
  select it.
* A failsafe hold for lost inputs asks for the profile's hold mode (BRAKE on ArduPilot,
  Hold = AUTO_LOITER on PX4); on PX4 the hold-position setpoint keeps streaming through
  it, so that resuming can ask for OFFBOARD at once (PX4 refuses OFFBOARD without a live
  stream). Resuming asks for the control mode again.
* If the vehicle leaves the mode the companion expects and the companion did not ask for it
  (a pilot or ground station switched to LOITER, RTL ...), the phase becomes RELEASED at
  once: no more setpoints or mode requests until someone selects the control mode again.

A heartbeat sent just before the autopilot executed our own request still shows the old
mode, so for ``grace_s`` after a request the previous mode is tolerated.
"""

from __future__ import annotations

import enum
import math

from companion.link.flavour import (
    Flavour,
    ModeRequest,
    control_mode,
    hold_mode,
    mode_name,
    profile_for,
    same_mode,
)

__all__ = ["ControlPhase", "ModeWatch"]


class ControlPhase(enum.Enum):
    """The companion's authority over the vehicle."""

    NO_AUTOPILOT = "no_autopilot"  # no heartbeat yet (or link lost)
    WAIT_MODE = "wait_mode"  # waiting for a pilot to select GUIDED/OFFBOARD
    PRESTREAM = "prestream"  # PX4: streaming setpoints before requesting OFFBOARD
    REQUESTED = "requested"  # control mode requested, not yet confirmed
    ACTIVE = "active"  # in GUIDED/OFFBOARD: the companion steers
    HOLD = "hold"  # failsafe hold commanded by the companion
    RELEASED = "released"  # someone else changed the mode: hands off, waiting


class ModeWatch:
    """State machine of :class:`ControlPhase` driven by heartbeats and failsafe holds."""

    def __init__(
        self,
        *,
        request_mode: bool = True,
        prestream_s: float = 1.2,
        grace_s: float = 2.5,
        retry_s: float = 2.0,
        max_retries: int = 5,
    ) -> None:
        self.request_mode = request_mode
        self.prestream_s = prestream_s
        self.grace_s = grace_s
        self.retry_s = retry_s
        self.max_retries = max_retries
        self.released_by_pilot = False
        self.reset()

    def reset(self) -> None:
        """Link lost or autopilot restarted: start over (a pilot's takeover is remembered)."""
        self.phase = ControlPhase.NO_AUTOPILOT
        self.flavour: Flavour | None = None
        self.mode: int | None = None
        self._expected: ModeRequest | None = None  # the mode we asked for last
        self._tolerated: int | None = None  # the mode before our request (grace window)
        self._requested_s = -math.inf
        self._retries = 0
        self._phase_since_s = 0.0
        self._hold_wanted = False

    # ---- queries ------------------------------------------------------------------
    @property
    def steering(self) -> bool:
        """The companion may send guidance setpoints."""
        if self._streams():
            return self.phase in (
                ControlPhase.PRESTREAM,
                ControlPhase.REQUESTED,
                ControlPhase.ACTIVE,
            )
        return self.phase is ControlPhase.ACTIVE

    @property
    def streaming_hold(self) -> bool:
        """PX4 failsafe: keep streaming a hold-position setpoint through the Hold (OFFBOARD
        can only be re-entered with a live stream)."""
        return self._streams() and self.phase is ControlPhase.HOLD

    def _streams(self) -> bool:
        return self.flavour is not None and profile_for(self.flavour).streams_setpoints

    def mode_text(self) -> str:
        if self.mode is None or self.flavour is None:
            return "-"
        return mode_name(self.flavour, self.mode)

    # ---- inputs -------------------------------------------------------------------
    def on_heartbeat(self, now_s: float, flavour: Flavour, custom_mode: int) -> list[str]:
        """Autopilot heartbeat; returns notices (for STATUSTEXT and the log)."""
        notices: list[str] = []
        self.mode = custom_mode
        if self.flavour is None:
            self.flavour = flavour
            ctrl = control_mode(flavour)
            if same_mode(flavour, custom_mode, ctrl):
                self._enter(ControlPhase.ACTIVE, now_s)
                notices.append(f"Avoidance active in {ctrl.name}")
            elif self.request_mode and not self.released_by_pilot:
                self._enter(
                    ControlPhase.PRESTREAM
                    if profile_for(flavour).streams_setpoints
                    else ControlPhase.REQUESTED,
                    now_s,
                )
                self._tolerated = custom_mode
                self._requested_s = -math.inf  # tick() sends the request
            else:
                self._enter(ControlPhase.WAIT_MODE, now_s)
                notices.append(f"Avoidance waiting for {ctrl.name}")
            return notices

        ctrl = control_mode(self.flavour)
        in_ctrl = same_mode(self.flavour, custom_mode, ctrl)
        hold = hold_mode(self.flavour)
        in_hold = hold is not None and same_mode(self.flavour, custom_mode, hold)
        in_grace = now_s - self._requested_s <= self.grace_s
        tolerated = in_grace and custom_mode == self._tolerated
        phase = self.phase

        if phase in (ControlPhase.WAIT_MODE, ControlPhase.RELEASED):
            if in_ctrl:
                self.released_by_pilot = False
                self._enter(ControlPhase.ACTIVE, now_s)
                notices.append(f"{ctrl.name} selected: avoidance active")
        elif phase is ControlPhase.PRESTREAM:
            if in_ctrl:
                self._enter(ControlPhase.ACTIVE, now_s)
        elif phase is ControlPhase.REQUESTED:
            if in_ctrl:
                self._enter(ControlPhase.ACTIVE, now_s)
                notices.append(f"Avoidance active in {ctrl.name}")
            elif custom_mode != self._tolerated:  # neither ours nor the one we left
                self._release(now_s, notices)
        elif phase is ControlPhase.ACTIVE:
            if not in_ctrl and not tolerated:
                self._release(now_s, notices)
        elif phase is ControlPhase.HOLD:
            # BRAKE / Hold, or still the control mode (stale heartbeat / not executed yet)
            ok = in_hold or in_ctrl
            if not ok and not tolerated:
                self._release(now_s, notices)
        return notices

    def on_mode_accepted(self, now_s: float, custom_mode: int) -> list[str]:
        """COMMAND_ACK ACCEPTED for our DO_SET_MODE ``custom_mode``: act on it at once
        (the next heartbeat may be a second away)."""
        if self.flavour is None or self._expected is None:
            return []
        if custom_mode != self._expected.custom_mode:
            return []
        ctrl = control_mode(self.flavour)
        if self.phase is ControlPhase.REQUESTED and same_mode(self.flavour, custom_mode, ctrl):
            self.mode = custom_mode
            self._requested_s = now_s  # older heartbeats may still show the previous mode
            self._enter(ControlPhase.ACTIVE, now_s)
            return [f"Avoidance active in {ctrl.name}"]
        if self.phase is ControlPhase.HOLD:
            self.mode = custom_mode
            self._requested_s = now_s
        return []

    def on_mode_refused(self, now_s: float, result_text: str) -> list[str]:
        """COMMAND_ACK of our DO_SET_MODE was not ACCEPTED."""
        if self.phase is not ControlPhase.REQUESTED and not self._hold_wanted:
            return []
        want = self._expected.name if self._expected else "mode"
        return [f"{want} refused by autopilot ({result_text})"]

    def tick(self, now_s: float) -> ModeRequest | None:
        """A mode request to send now (engagement, retries), or None."""
        if self.flavour is None:
            return None
        if self.phase is ControlPhase.PRESTREAM:
            if now_s - self._phase_since_s >= self.prestream_s:
                self._enter(ControlPhase.REQUESTED, now_s)
                return self._request(control_mode(self.flavour), now_s)
            return None
        if self.phase is ControlPhase.REQUESTED and now_s - self._requested_s >= self.retry_s:
            if self._retries >= self.max_retries:
                self._enter(ControlPhase.WAIT_MODE, now_s)
                return None
            self._retries += 1
            return self._request(control_mode(self.flavour), now_s)
        return None

    def set_hold(self, now_s: float, hold: bool) -> ModeRequest | None:
        """Failsafe: start (True) or end (False) a hold; returns the mode to request."""
        if self.flavour is None:
            return None
        if hold and self.phase in (ControlPhase.ACTIVE, ControlPhase.REQUESTED):
            self._hold_wanted = True
            self._tolerated = self.mode
            self._enter(ControlPhase.HOLD, now_s)
            wanted = hold_mode(self.flavour)
            if wanted is None:
                return None
            self._retries = 0
            return self._request(wanted, now_s)
        if not hold and self.phase is ControlPhase.HOLD:
            self._hold_wanted = False
            wanted = hold_mode(self.flavour)
            if wanted is None:  # no hold mode: still in the control mode
                self._enter(ControlPhase.ACTIVE, now_s)
                return None
            self._tolerated = self.mode
            self._retries = 0
            self._enter(ControlPhase.REQUESTED, now_s)
            return self._request(control_mode(self.flavour), now_s)
        return None

    # ---- helpers ------------------------------------------------------------------
    def _enter(self, phase: ControlPhase, now_s: float) -> None:
        self.phase = phase
        self._phase_since_s = now_s

    def _request(self, wanted: ModeRequest, now_s: float) -> ModeRequest:
        self._expected = wanted
        self._requested_s = now_s
        return wanted

    def _release(self, now_s: float, notices: list[str]) -> None:
        assert self.flavour is not None
        was = self._expected.name if self._expected else control_mode(self.flavour).name
        if self.phase is ControlPhase.ACTIVE:
            was = control_mode(self.flavour).name
        now = mode_name(self.flavour, self.mode if self.mode is not None else -1)
        self.released_by_pilot = True
        self._hold_wanted = False
        self._enter(ControlPhase.RELEASED, now_s)
        notices.append(f"Mode {now} not ours (was {was}): avoidance stopped")
