"""The PX4 flavour of plant-sim's autopilot (``--autopilot-flavour px4``): PX4's modes and
offboard rules over the same flight logic (pure).

PX4 packs its mode into HEARTBEAT ``custom_mode`` as main mode (bits 16–23) and sub mode
(bits 24–31; PX4 ``px4_custom_mode.h``): MANUAL 1, ALTCTL 2, POSCTL 3, AUTO 4 (sub modes
READY 1, TAKEOFF 2, LOITER 3, MISSION 4, RTL 5, LAND 6), ACRO 5, OFFBOARD 6, STABILIZED 7.
:class:`Px4Modes` maps them onto :class:`~plant_sim.autopilot.modes.FlightModeMachine`:

=====================  ===================================  ============================
PX4 mode               what the vehicle does                machine mode
=====================  ===================================  ============================
AUTO_LOITER (Hold)     stop, hold position                  LOITER
POSCTL                 hold position (sticks centred)       LOITER
AUTO_TAKEOFF           climb to the takeoff altitude        GUIDED + takeoff
OFFBOARD               track SET_POSITION_TARGET_LOCAL_NED  GUIDED
AUTO_RTL / AUTO_LAND   return / land                        RTL / LAND
=====================  ===================================  ============================

PX4's rules that a companion must live with:

* OFFBOARD is entered only while setpoints stream faster than ``min_stream_hz`` (2 Hz):
  the newest younger than half a second and no longer gap in the last
  ``stream_window_s``; otherwise the mode change is TEMPORARILY_REJECTED ("Offboard: no
  setpoint stream").
* In OFFBOARD, no setpoint for ``COM_OF_LOSS_T`` (``loss_timeout_s``, default 1 s) is
  the offboard-loss failsafe: the vehicle holds (AUTO_LOITER) and says so.
* ``MAV_CMD_NAV_TAKEOFF`` is accepted in any mode when armed and landed; param7 is an
  AMSL altitude (NaN: ``MIS_TAKEOFF_ALT``, 2.5 m above home); the vehicle climbs in
  AUTO_TAKEOFF and holds (AUTO_LOITER) at the top.
* Setpoints are accepted in every mode (they count for the stream) and flown only in
  OFFBOARD.

Times are simulation time [s].
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

from plant_sim.autopilot.modes import FlightMode, FlightModeMachine, GuidedTarget, Kinematics
from plant_sim.autopilot.params import ParamSpec, ParamTable, ParamType
from protocols.config import Checked, bounded
from protocols.mavlink_modes import Px4Main, Px4Sub, px4_custom_mode, px4_split

__all__ = [
    "PX4_OFFBOARD_LOST_TEXT",
    "PX4_PARAM_SPECS",
    "Px4Main",
    "Px4Modes",
    "Px4Rules",
    "Px4Sub",
    "px4_custom_mode",
    "rules_from_params",
]

PX4_OFFBOARD_LOST_TEXT = "Failsafe: offboard lost, holding"


@dataclass(frozen=True)
class Px4Rules(Checked):
    """PX4 parameters behind the offboard and takeoff rules."""

    loss_timeout_s: float = bounded(1.0, "s", ge=0)  # COM_OF_LOSS_T
    min_stream_hz: float = bounded(2.0, "Hz", gt=0)  # OFFBOARD needs more than this
    stream_window_s: float = bounded(1.0, "s", gt=0)  # over this window
    takeoff_alt_m: float = bounded(2.5, "m", gt=0)  # MIS_TAKEOFF_ALT [m above home]


#: PX4's parameters behind :class:`Px4Rules` (ground stations and MAVSDK set them).
PX4_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("COM_OF_LOSS_T", ParamType.REAL32, 1.0, 0.0, 60.0),  # s
    ParamSpec("MIS_TAKEOFF_ALT", ParamType.REAL32, 2.5, 0.5, 100.0),  # m above home
)


def rules_from_params(table: ParamTable) -> Px4Rules:
    """:class:`Px4Rules` with the values of :data:`PX4_PARAM_SPECS`."""
    return Px4Rules(
        loss_timeout_s=table.value("COM_OF_LOSS_T"),
        takeoff_alt_m=table.value("MIS_TAKEOFF_ALT"),
    )


class Px4Modes:
    """PX4's mode view of a :class:`FlightModeMachine`; every call is simulation time.

    Parameters
    ----------
    machine : the ArduCopter-like flight logic it drives.
    home_amsl_m : AMSL altitude of the LOCAL_NED origin's ground (home) [m].
    rules : PX4 parameters.
    """

    def __init__(
        self, machine: FlightModeMachine, home_amsl_m: float, rules: Px4Rules | None = None
    ) -> None:
        self.machine = machine
        self.home_amsl_m = float(home_amsl_m)
        self.rules = rules or Px4Rules()
        self._setpoint_times: deque[float] = deque(maxlen=256)
        self.main = Px4Main.AUTO
        self.sub = Px4Sub.LOITER
        if machine.mode is FlightMode.GUIDED and machine.armed:
            self.main, self.sub = Px4Main.OFFBOARD, Px4Sub.NONE
        self.offboard_losses = 0

    # ---- queries -------------------------------------------------------------------
    @property
    def custom_mode(self) -> int:
        """HEARTBEAT custom_mode."""
        return px4_custom_mode(self.main, self.sub)

    @property
    def name(self) -> str:
        if self.main is Px4Main.AUTO:
            return f"AUTO_{self.sub.name}"
        return self.main.name

    def streaming(self, now_s: float) -> bool:
        """Setpoints arrive fast enough for OFFBOARD: the newest is younger than a 2 Hz
        period and, over the last ``stream_window_s``, none came after a longer gap. (PX4
        checks that its offboard signal is fresh; a client that sets one setpoint and then
        starts streaming, as MAVSDK's offboard plugin does, passes.)"""
        r = self.rules
        period = 1.0 / r.min_stream_hz
        times = [t for t in self._setpoint_times if now_s - t < r.stream_window_s]
        if not times or now_s - times[-1] >= period:
            return False
        return all(b - a < period for a, b in itertools.pairwise(times))

    # ---- inputs --------------------------------------------------------------------
    def set_mode(self, custom_mode: int, kin: Kinematics) -> tuple[bool, str | None, bool]:
        """A mode request: (accepted, STATUSTEXT or None, temporary refusal)."""
        main, sub = px4_split(int(custom_mode))
        try:
            main_mode = Px4Main(main)
        except ValueError:
            return False, f"Unknown PX4 main mode {main}", False
        if main_mode is Px4Main.OFFBOARD:
            if not self.streaming(kin.time_s):
                return False, "Offboard: no setpoint stream (> 2 Hz needed)", True
            if not self.machine.armed or self.machine.landed:
                return False, "Offboard: not flying", True
            return self._enter(Px4Main.OFFBOARD, Px4Sub.NONE, FlightMode.GUIDED, kin)
        if main_mode is Px4Main.POSCTL:
            return self._enter(Px4Main.POSCTL, Px4Sub.NONE, FlightMode.LOITER, kin)
        if main_mode is Px4Main.AUTO:
            target = {
                Px4Sub.LOITER: FlightMode.LOITER,
                Px4Sub.RTL: FlightMode.RTL,
                Px4Sub.LAND: FlightMode.LAND,
            }
            try:
                sub_mode = Px4Sub(sub)
            except ValueError:
                sub_mode = Px4Sub.NONE
            if sub_mode is Px4Sub.TAKEOFF:
                alt = self.home_amsl_m + self.rules.takeoff_alt_m
                reason = self.takeoff(alt, kin)
                return reason is None, reason, False
            if sub_mode in target:
                return self._enter(Px4Main.AUTO, sub_mode, target[sub_mode], kin)
            return False, f"AUTO sub mode {sub} not supported", False
        return False, f"{main_mode.name} not supported by this vehicle", False

    def land(self, kin: Kinematics) -> str | None:
        ok, text, _ = self._enter(Px4Main.AUTO, Px4Sub.LAND, FlightMode.LAND, kin)
        return None if ok else text

    def rtl(self, kin: Kinematics) -> str | None:
        ok, text, _ = self._enter(Px4Main.AUTO, Px4Sub.RTL, FlightMode.RTL, kin)
        return None if ok else text

    def takeoff(self, alt_amsl_m: float, kin: Kinematics) -> str | None:
        """NAV_TAKEOFF (param7 AMSL; NaN: MIS_TAKEOFF_ALT); refusal or None."""
        if not math.isfinite(alt_amsl_m):
            alt_amsl_m = self.home_amsl_m + self.rules.takeoff_alt_m
        rel_m = alt_amsl_m - self.home_amsl_m
        if not self.machine.armed:
            return "Takeoff denied: disarmed"
        if not self.machine.landed:
            return "Takeoff denied: already flying"
        if not rel_m > 0.5:
            return f"Takeoff denied: altitude {rel_m:.1f} m above home"
        previous = self.machine.mode
        self.machine.set_mode(FlightMode.GUIDED, kin)
        reason = self.machine.takeoff(rel_m, kin)
        if reason is not None:
            self.machine.set_mode(previous, kin)
            return reason
        self.main, self.sub = Px4Main.AUTO, Px4Sub.TAKEOFF
        return None

    def setpoint(self, target: GuidedTarget, kin: Kinematics) -> str | None:
        """SET_POSITION_TARGET_LOCAL_NED: counts for the stream; flown in OFFBOARD only."""
        self._setpoint_times.append(kin.time_s)
        if self.main is not Px4Main.OFFBOARD:
            return None
        return self.machine.guided_target(target, kin)

    def update(self, kin: Kinematics, notices: list[str]) -> list[str]:
        """After the machine's own update: takeoff end, offboard loss; more notices."""
        out = []
        if self.main is Px4Main.AUTO and self.sub is Px4Sub.TAKEOFF:
            if "Takeoff complete" in notices:
                self.machine.set_mode(FlightMode.LOITER, kin)
                self.sub = Px4Sub.LOITER
            elif not self.machine.armed:
                self.sub = Px4Sub.LOITER
        if self.main is Px4Main.OFFBOARD:
            newest = self._setpoint_times[-1] if self._setpoint_times else -math.inf
            if kin.time_s - newest > self.rules.loss_timeout_s:
                self.offboard_losses += 1
                self._enter(Px4Main.AUTO, Px4Sub.LOITER, FlightMode.LOITER, kin)
                out.append(PX4_OFFBOARD_LOST_TEXT)
        if self.machine.mode is FlightMode.LAND and not self.machine.armed:
            self.main, self.sub = Px4Main.AUTO, Px4Sub.LOITER  # landed and disarmed
        return out

    def _enter(
        self, main: Px4Main, sub: Px4Sub, mode: FlightMode, kin: Kinematics
    ) -> tuple[bool, str | None, bool]:
        reason = self.machine.set_mode(mode, kin)
        if reason is not None:
            return False, reason, False
        self.main, self.sub = main, sub
        return True, None, False
