"""Autopilot profiles: everything the companion does differently per autopilot family.

Pure. One :class:`AutopilotProfile` per :class:`Flavour` (:data:`PROFILES`,
:func:`profile_for`) owns the mode numbers (control and hold mode, names, how a HEARTBEAT
mode is compared), guided/offboard entry, the setpoint streaming rule, the takeoff's mode
and altitude reference and whether a speed limit is stated. No other module branches on
the flavour; they read the profile.

ArduPilot (``MAV_AUTOPILOT_ARDUPILOTMEGA``): ArduCopter custom modes, GUIDED = 4 to
steer, BRAKE = 17 to hold. PX4 (``MAV_AUTOPILOT_PX4``): ``custom_mode`` packs the main
mode in bits 16–23 and the sub mode in bits 24–31 (PX4 ``src/modules/commander/
px4_custom_mode.h``: ``PX4_CUSTOM_MAIN_MODE_AUTO`` = 4, ``PX4_CUSTOM_SUB_MODE_AUTO_LOITER``
= 3); OFFBOARD is main mode 6 (``6 << 16``) and the failsafe hold is Hold, AUTO_LOITER
(``4 << 16 | 3 << 24``). Setpoints keep streaming through a Hold, so that OFFBOARD can be
re-entered at once when it ends (PX4 enters OFFBOARD only with a live stream). Anything
else is treated like ArduPilot (the most common MAVLink "GUIDED" semantics) and reported
as GENERIC.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from protocols.mavlink_modes import ArduCopterMode, Px4Main, Px4Sub, px4_custom_mode, px4_split

__all__ = [
    "ARDUCOPTER_BRAKE",
    "ARDUCOPTER_GUIDED",
    "PROFILES",
    "PX4_MAIN_MODE_OFFBOARD",
    "AutopilotProfile",
    "Flavour",
    "ModeRequest",
    "control_mode",
    "detect_flavour",
    "hold_mode",
    "is_autopilot_heartbeat",
    "mode_name",
    "profile_for",
    "px4_custom_mode",
    "same_mode",
]

ARDUCOPTER_GUIDED = int(ArduCopterMode.GUIDED)
ARDUCOPTER_BRAKE = int(ArduCopterMode.BRAKE)
PX4_MAIN_MODE_OFFBOARD = int(Px4Main.OFFBOARD)


class Flavour(enum.Enum):
    """Which autopilot family is on the other end of the link."""

    ARDUPILOT = "ardupilot"
    PX4 = "px4"
    GENERIC = "generic"


@dataclass(frozen=True)
class ModeRequest:
    """A mode as MAV_CMD_DO_SET_MODE parameters."""

    base_mode: int
    custom_mode: int  # as in HEARTBEAT.custom_mode
    name: str
    px4: bool = False  # PX4 reads DO_SET_MODE as param2 = main mode, param3 = sub mode

    @property
    def command_params(self) -> tuple[float, ...]:
        """MAV_CMD_DO_SET_MODE param1.. for this mode. ArduPilot: (base_mode, custom_mode).
        PX4 casts param2 and param3 to uint8 main and sub mode (Commander; the SET_MODE
        message is translated the same way), so the packed custom_mode would be read as
        mode 0 there: (base_mode, main, sub)."""
        if self.px4:
            return (
                float(self.base_mode),
                *(float(x) for x in px4_split(self.custom_mode)),
            )
        return float(self.base_mode), float(self.custom_mode)


def is_autopilot_heartbeat(autopilot: int, mav_type: int) -> bool:
    """True for a vehicle's autopilot (not a GCS, camera, companion ...)."""
    return autopilot != mavlink.MAV_AUTOPILOT_INVALID and mav_type not in (
        mavlink.MAV_TYPE_GCS,
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink.MAV_TYPE_GIMBAL,
        mavlink.MAV_TYPE_CAMERA,
    )


def detect_flavour(autopilot: int) -> Flavour:
    """Flavour from HEARTBEAT.autopilot."""
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return Flavour.ARDUPILOT
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return Flavour.PX4
    return Flavour.GENERIC


_CUSTOM = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


@dataclass(frozen=True)
class AutopilotProfile:
    """How the companion drives one autopilot family.

    Attributes
    ----------
    flavour : Flavour
    control_mode : ModeRequest
        The mode in which the companion steers (GUIDED, OFFBOARD).
    hold_mode : ModeRequest or None
        What a failsafe hold for lost inputs asks for (BRAKE, PX4's Hold); None: stay in
        the control mode and send a hold-position setpoint.
    streams_setpoints : bool
        Setpoints must flow continuously (> 2 Hz; PX4 leaves OFFBOARD when they stop):
        every frame's target is sent, they stream for a while *before* the control mode
        is requested (pre-stream), and a hold-position setpoint streams through a hold.
        Otherwise targets persist in the autopilot: sent when they change, re-sent as a
        keep-alive.
    takeoff_mode : ModeRequest or None
        Mode to select before arming for ``--takeoff-alt`` (GUIDED); None: take off from
        the current mode (PX4 runs NAV_TAKEOFF in its own takeoff mode).
    takeoff_alt_amsl : bool
        NAV_TAKEOFF's altitude is above mean sea level (PX4: home altitude needed) rather
        than relative to home.
    states_speed_limit : bool
        The envelope's speed limit is stated with MAV_CMD_DO_CHANGE_SPEED below the
        autopilot's WPNAV_SPEED (ArduPilot); otherwise the carrot alone bounds the speed.
    packed_modes : bool
        HEARTBEAT.custom_mode packs a main mode (bits 16–23) and sub mode (24–31) (PX4).
    """

    flavour: Flavour
    control_mode: ModeRequest
    hold_mode: ModeRequest | None
    streams_setpoints: bool
    takeoff_mode: ModeRequest | None
    takeoff_alt_amsl: bool
    states_speed_limit: bool
    packed_modes: bool = False

    def mode_name(self, custom_mode: int) -> str:
        """Human name of a HEARTBEAT custom mode."""
        if self.packed_modes:
            main, sub = px4_split(custom_mode)
            if main not in Px4Main.__members__.values():
                return f"PX4_MODE_{custom_mode:#x}"
            if main == Px4Main.AUTO and sub in Px4Sub.__members__.values() and sub:
                return f"AUTO_{Px4Sub(sub).name}"  # AUTO_LOITER is PX4's Hold
            return Px4Main(main).name
        if custom_mode in ArduCopterMode.__members__.values():
            return ArduCopterMode(custom_mode).name
        return f"MODE_{custom_mode}"

    def same_mode(self, custom_mode: int, wanted: ModeRequest) -> bool:
        """Whether a HEARTBEAT custom_mode is ``wanted`` (packed: main and sub mode)."""
        if self.packed_modes:
            return px4_split(custom_mode) == px4_split(wanted.custom_mode)
        return custom_mode == wanted.custom_mode


_GUIDED = ModeRequest(_CUSTOM, ARDUCOPTER_GUIDED, "GUIDED")
_BRAKE = ModeRequest(_CUSTOM, ARDUCOPTER_BRAKE, "BRAKE")

#: the profile of each flavour; GENERIC gets ArduPilot's GUIDED semantics (the most
#: common among other MAVLink autopilots) without the ArduPilot-only speed command
PROFILES: dict[Flavour, AutopilotProfile] = {
    Flavour.ARDUPILOT: AutopilotProfile(
        Flavour.ARDUPILOT,
        control_mode=_GUIDED,
        hold_mode=_BRAKE,
        streams_setpoints=False,
        takeoff_mode=_GUIDED,
        takeoff_alt_amsl=False,
        states_speed_limit=True,
    ),
    Flavour.PX4: AutopilotProfile(
        Flavour.PX4,
        control_mode=ModeRequest(
            _CUSTOM, px4_custom_mode(PX4_MAIN_MODE_OFFBOARD), "OFFBOARD", px4=True
        ),
        hold_mode=ModeRequest(
            _CUSTOM, px4_custom_mode(Px4Main.AUTO, Px4Sub.LOITER), "AUTO_LOITER", px4=True
        ),
        streams_setpoints=True,
        takeoff_mode=None,
        takeoff_alt_amsl=True,
        states_speed_limit=False,
        packed_modes=True,
    ),
    Flavour.GENERIC: AutopilotProfile(
        Flavour.GENERIC,
        control_mode=_GUIDED,
        hold_mode=_BRAKE,
        streams_setpoints=False,
        takeoff_mode=_GUIDED,
        takeoff_alt_amsl=False,
        states_speed_limit=False,
    ),
}


def profile_for(flavour: Flavour) -> AutopilotProfile:
    """The :class:`AutopilotProfile` of ``flavour``."""
    return PROFILES[flavour]


def control_mode(flavour: Flavour) -> ModeRequest:
    """The mode in which the companion steers: GUIDED (ArduPilot) or OFFBOARD (PX4)."""
    return PROFILES[flavour].control_mode


def hold_mode(flavour: Flavour) -> ModeRequest | None:
    """The mode a failsafe for lost inputs asks for: BRAKE (ArduPilot), AUTO_LOITER (PX4's
    Hold); None: a hold-position setpoint in the control mode."""
    return PROFILES[flavour].hold_mode


def mode_name(flavour: Flavour, custom_mode: int) -> str:
    """Human name of a HEARTBEAT custom mode."""
    return PROFILES[flavour].mode_name(custom_mode)


def same_mode(flavour: Flavour, custom_mode: int, wanted: ModeRequest) -> bool:
    """Whether a HEARTBEAT custom_mode is ``wanted``."""
    return PROFILES[flavour].same_mode(custom_mode, wanted)
