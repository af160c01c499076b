"""Pilot sticks from MAVLink: RC_CHANNELS_OVERRIDE and MANUAL_CONTROL (pure, wall time in).

plant-sim has no RC receiver; a ground station or a test script flies it with the two
messages ground stations send for joysticks. Sticks are normalised to ``[-1, 1]``:
``forward`` (pitch stick forward = +1), ``right`` (roll), ``up`` (throttle above mid-stick)
and ``yaw`` (clockwise).

* **RC_CHANNELS_OVERRIDE** (ArduPilot's default ``RCMAP``: 1 roll, 2 pitch, 3 throttle,
  4 yaw; PWM 1000–2000 µs, 1500 centre; pitch forward is *low* PWM). ``0`` releases a
  channel, ``UINT16_MAX`` leaves it as it is. ArduPilot drops overrides after
  ``RC_OVERRIDE_TIME`` (3 s) without a new one.
* **MANUAL_CONTROL** (``x`` pitch +1000 forward, ``y`` roll +1000 right, ``z``
  throttle 0…1000 with 500 at mid-stick, ``r`` yaw +1000 clockwise); ``INT16_MAX`` on an
  axis means "not used". ArduPilot turns it into the same overrides with the same timeout.

A dead band of 20 µs of the 500 µs half-travel (ArduPilot's ``RCn_DZ`` default) centres
small deflections. A value outside its range is a refused message, counted by the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PilotInput", "Sticks"]

_PWM_CENTRE = 1500.0
_PWM_HALF = 500.0
_DEAD_BAND = 20.0 / _PWM_HALF
_UINT16_MAX = 65535
_INT16_MAX = 32767


@dataclass(frozen=True)
class Sticks:
    """Normalised stick deflections in ``[-1, 1]``."""

    forward: float = 0.0
    right: float = 0.0
    up: float = 0.0
    yaw: float = 0.0

    @property
    def centred(self) -> bool:
        return self.forward == 0.0 and self.right == 0.0 and self.up == 0.0 and self.yaw == 0.0


CENTRED = Sticks()


def _dead_band(x: float) -> float:
    """Remove the dead band and rescale so full stick is still ±1."""
    x = max(-1.0, min(1.0, x))
    if abs(x) <= _DEAD_BAND:
        return 0.0
    return math.copysign((abs(x) - _DEAD_BAND) / (1.0 - _DEAD_BAND), x)


class PilotInput:
    """The newest stick positions and when they expire.

    Parameters
    ----------
    timeout_s : float
        Overrides older than this [s wall] are released (RC_OVERRIDE_TIME).
    """

    def __init__(self, timeout_s: float = 3.0) -> None:
        self.timeout_s = timeout_s
        self._sticks = CENTRED
        self._pwm: dict[int, float] = {}
        self._time_s = -math.inf
        self.received = 0
        self.refused = 0

    def sticks(self, now_s: float) -> Sticks:
        """The sticks now (centred when the overrides expired)."""
        if now_s - self._time_s > self.timeout_s:
            return CENTRED
        return self._sticks

    def on_rc_override(self, msg, now_s: float) -> str | None:
        """RC_CHANNELS_OVERRIDE channels 1–4; returns a refusal reason or None."""
        values = {1: msg.chan1_raw, 2: msg.chan2_raw, 3: msg.chan3_raw, 4: msg.chan4_raw}
        pwm = dict(self._pwm)
        for ch, raw in values.items():
            raw = int(raw)
            if raw == _UINT16_MAX:
                continue
            if raw == 0:
                pwm.pop(ch, None)
                continue
            if not 800 <= raw <= 2200:
                self.refused += 1
                return f"RC override: channel {ch} value {raw} outside 800..2200"
            pwm[ch] = float(raw)
        self._pwm = pwm

        def norm(ch: int) -> float:
            return (pwm.get(ch, _PWM_CENTRE) - _PWM_CENTRE) / _PWM_HALF

        return self._set(Sticks(-norm(2), norm(1), norm(3), norm(4)), now_s)

    def on_manual_control(self, msg, now_s: float) -> str | None:
        """MANUAL_CONTROL x, y, z, r; returns a refusal reason or None."""
        axes = {"x": msg.x, "y": msg.y, "z": msg.z, "r": msg.r}
        used = {}
        for name, raw in axes.items():
            raw = int(raw)
            if raw == _INT16_MAX:
                continue
            low = 0 if name == "z" else -1000
            if not low <= raw <= 1000:
                self.refused += 1
                return f"MANUAL_CONTROL: {name} = {raw} outside {low}..1000"
            used[name] = raw
        return self._set(
            Sticks(
                used.get("x", 0) / 1000.0,
                used.get("y", 0) / 1000.0,
                (used.get("z", 500) - 500) / 500.0,
                used.get("r", 0) / 1000.0,
            ),
            now_s,
        )

    def _set(self, raw: Sticks, now_s: float) -> None:
        self.received += 1
        self._sticks = Sticks(*(_dead_band(v) for v in (raw.forward, raw.right, raw.up, raw.yaw)))
        self._time_s = now_s
        return None
