"""Telemetry: the stream scheduler (SET_MESSAGE_INTERVAL) and the message builders (pure).

Stream intervals run on simulation time, as ArduPilot SITL's scheduler does under
``--speedup``, so a companion sees the same samples at any speed; HEARTBEAT is not
scheduled here (1 Hz of wall time, DESIGN.md). Every ``time_boot_ms`` / ``time_usec`` field
carries simulation time ("One clock"). Positions: LOCAL_NED; geodetic fields come from a
flat-earth projection around :class:`~plant_sim.scenario.GeoOrigin`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot.geodesy import FlatEarth
from plant_sim.autopilot.modes import FlightMode, FlightModeMachine
from plant_sim.autopilot.setpoints import type_mask_for
from plant_sim.vehicle import Setpoint, VehicleState

__all__ = [
    "AUTOPILOT_CAPABILITIES",
    "DATA_STREAM_GROUPS",
    "MESSAGE_IDS",
    "SENSORS_PRESENT",
    "StreamScheduler",
    "TelemetryBuilder",
    "VehicleIdentity",
]

#: Messages this autopilot can stream or send on request, by name → id.
MESSAGE_IDS: dict[str, int] = {
    "HEARTBEAT": mavlink.MAVLINK_MSG_ID_HEARTBEAT,
    "SYS_STATUS": mavlink.MAVLINK_MSG_ID_SYS_STATUS,
    "SYSTEM_TIME": mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
    "GPS_RAW_INT": mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE,
    "LOCAL_POSITION_NED": mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "GLOBAL_POSITION_INT": mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "POSITION_TARGET_LOCAL_NED": mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED,
    "AUTOPILOT_VERSION": mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
    "HOME_POSITION": mavlink.MAVLINK_MSG_ID_HOME_POSITION,
    "EXTENDED_SYS_STATE": mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
}
_NAME_BY_ID = {v: k for k, v in MESSAGE_IDS.items()}

#: Legacy REQUEST_DATA_STREAM groups (MAVProxy still uses them) → message names.
DATA_STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT", "EXTENDED_SYS_STATE"),
    mavlink.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mavlink.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    mavlink.MAV_DATA_STREAM_RAW_CONTROLLER: ("POSITION_TARGET_LOCAL_NED",),
}

#: SYS_STATUS sensors reported present, enabled and healthy. MAVSDK's health_all_ok reads
#: gyro, accel, mag, GPS and the pre-arm check bit.
SENSORS_PRESENT = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_PREARM_CHECK
)

#: AUTOPILOT_VERSION.capabilities: what a client may use.
AUTOPILOT_CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
)

# ArduCopter 4.5.0, official: major << 24 | minor << 16 | patch << 8 | FIRMWARE_VERSION_TYPE
_UINT32_MAX = 0xFFFFFFFF  # GPS_RAW_INT h_acc / v_acc are uint32 [mm]
_FLIGHT_SW_VERSION = (4 << 24) | (5 << 16) | (0 << 8) | 255


class StreamScheduler:
    """Per-message intervals [s of simulation time] and next due times.

    ``explicit`` marks messages set by SET_MESSAGE_INTERVAL: legacy REQUEST_DATA_STREAM
    does not override them (so a ground station's 4 Hz request cannot slow down the
    companion's 50 Hz stream).
    """

    def __init__(self, default_rates_hz: dict[str, float], start_time_s: float = 0.0) -> None:
        for name in default_rates_hz:
            if name not in MESSAGE_IDS:
                raise ValueError(f"unknown stream {name!r}; known: {sorted(MESSAGE_IDS)}")
        self._default_hz = dict(default_rates_hz)
        self._interval_s: dict[str, float] = {}
        self._next_s: dict[str, float] = {}
        self._explicit: set[str] = set()
        for name, hz in default_rates_hz.items():
            self._apply(name, hz, start_time_s)

    def _apply(self, name: str, rate_hz: float, now_s: float) -> None:
        if rate_hz <= 0.0:
            self._interval_s.pop(name, None)
            self._next_s.pop(name, None)
            return
        self._interval_s[name] = 1.0 / rate_hz
        self._next_s[name] = now_s  # first sample now, then on the new grid

    def set_interval_us(self, msg_id: int, interval_us: float, now_s: float) -> None:
        """SET_MESSAGE_INTERVAL semantics: -1 off, 0 default rate, > 0 interval [µs]."""
        name = _NAME_BY_ID[msg_id]
        self._explicit.add(name)
        if interval_us == 0:
            self._apply(name, self._default_hz.get(name, 0.0), now_s)
        elif interval_us < 0:
            self._apply(name, 0.0, now_s)
        else:
            self._apply(name, 1e6 / interval_us, now_s)

    def interval_us(self, msg_id: int) -> float:
        """Current interval [µs], -1 if off (MESSAGE_INTERVAL reply)."""
        interval = self._interval_s.get(_NAME_BY_ID.get(msg_id, ""))
        return -1.0 if interval is None else interval * 1e6

    def request_data_stream(
        self, stream_id: int, rate_hz: float, start: bool, now_s: float
    ) -> None:
        """Legacy REQUEST_DATA_STREAM: set the rate of a message group."""
        if stream_id == mavlink.MAV_DATA_STREAM_ALL:
            names = tuple(n for group in DATA_STREAM_GROUPS.values() for n in group)
        else:
            names = DATA_STREAM_GROUPS.get(stream_id, ())
        for name in names:
            if name not in self._explicit:
                self._apply(name, rate_hz if start else 0.0, now_s)

    def due(self, now_s: float) -> list[str]:
        """Names due at ``now_s``; each advances by its interval (no catch-up bursts)."""
        out = []
        for name, next_s in self._next_s.items():
            if next_s <= now_s + 1e-9:
                out.append(name)
                nxt = next_s + self._interval_s[name]
                self._next_s[name] = nxt if nxt > now_s else now_s + self._interval_s[name]
        return out

    def next_due_s(self) -> float:
        """Earliest due time [s], inf if nothing streams."""
        return min(self._next_s.values(), default=math.inf)


@dataclass(frozen=True)
class VehicleIdentity:
    """Fixed facts a client reads: geodetic origin and the vehicle's uid."""

    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_amsl_m: float
    uid: int = 0x5354455245304156  # "STERE0AV"


def _ms(time_s: float) -> int:
    return int(time_s * 1000.0 + 1e-6) & 0xFFFFFFFF  # + 1e-6: k·dt must not truncate to k·dt − 1 ms


def _wrap_cdeg(yaw_rad: float) -> int:
    return round(math.degrees(yaw_rad) * 100.0) % 36000


class TelemetryBuilder:
    """Builds pymavlink message objects from the vehicle snapshot and the mode machine."""

    def __init__(self, identity: VehicleIdentity) -> None:
        self.identity = identity
        self.earth = FlatEarth(
            identity.origin_lat_deg, identity.origin_lon_deg, identity.origin_alt_amsl_m
        )

    # ---- geodesy -------------------------------------------------------------------
    def geodetic(self, pos_ned_m) -> tuple[int, int, int]:
        """(lat degE7, lon degE7, alt mm AMSL) of a LOCAL_NED point (flat earth)."""
        return self.earth.geodetic_e7(pos_ned_m)

    # ---- messages ------------------------------------------------------------------
    def heartbeat(self, machine: FlightModeMachine) -> mavlink.MAVLink_heartbeat_message:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if machine.mode in (FlightMode.GUIDED, FlightMode.AUTO, FlightMode.RTL):
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        if machine.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if machine.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            int(machine.mode),
            state,
            3,
        )

    def build(
        self,
        name: str,
        snap: VehicleState,
        machine: FlightModeMachine,
        *,
        wall_unix_s: float,
        comm_errors: int = 0,
        signing_refused: int = 0,
        accuracy_m: tuple[float, float] = (0.0, 0.0),
    ):
        """The message ``name`` for the state at ``snap.time_s``; ``accuracy_m``: the
        (horizontal, vertical) accuracy stated for the position [m]
        (:attr:`plant_sim.disturbance.Disturbances.stated_accuracy_m`)."""
        if name == "HEARTBEAT":
            return self.heartbeat(machine)
        if name == "LOCAL_POSITION_NED":
            return _local_position(snap)
        if name == "ATTITUDE":
            return _attitude(snap)
        if name == "GLOBAL_POSITION_INT":
            return self.global_position(snap, machine)
        if name == "GPS_RAW_INT":
            return self.gps_raw(snap, accuracy_m)
        if name == "SYS_STATUS":
            return _sys_status(comm_errors, signing_refused)
        if name == "EXTENDED_SYS_STATE":
            return mavlink.MAVLink_extended_sys_state_message(
                mavlink.MAV_VTOL_STATE_UNDEFINED, int(machine.landed_state)
            )
        if name == "HOME_POSITION":
            return self.home_position(machine, snap.time_s)
        if name == "POSITION_TARGET_LOCAL_NED":
            return self.position_target(machine.reported_target, snap)
        if name == "AUTOPILOT_VERSION":
            return self.autopilot_version()
        if name == "SYSTEM_TIME":
            return mavlink.MAVLink_system_time_message(int(wall_unix_s * 1e6), _ms(snap.time_s))
        raise KeyError(f"no builder for message {name!r}")

    def global_position(self, snap: VehicleState, machine: FlightModeMachine):
        """GLOBAL_POSITION_INT: position about the fixed home, altitude above home."""
        lat, lon, alt = self.geodetic(snap.pos_ned_m)
        rel_mm = round((machine.home_ned_m[2] - float(snap.pos_ned_m[2])) * 1000.0)
        v = snap.vel_ned_mps
        return mavlink.MAVLink_global_position_int_message(
            _ms(snap.time_s),
            lat,
            lon,
            alt,
            rel_mm,
            round(float(v[0]) * 100.0),
            round(float(v[1]) * 100.0),
            round(float(v[2]) * 100.0),
            _wrap_cdeg(snap.yaw_rad),
        )

    def gps_raw(self, snap: VehicleState, accuracy_m: tuple[float, float] = (0.0, 0.0)):
        """GPS_RAW_INT: a 3-D fix with 12 satellites, course over ground above 0.1 m/s,
        ``h_acc``/``v_acc`` [mm] the stated (horizontal, vertical) accuracy [m]."""
        h_acc_mm, v_acc_mm = (min(round(a * 1000.0), _UINT32_MAX) for a in accuracy_m)
        lat, lon, alt = self.geodetic(snap.pos_ned_m)
        v = snap.vel_ned_mps
        ground_speed = math.hypot(float(v[0]), float(v[1]))
        cog = _wrap_cdeg(math.atan2(float(v[1]), float(v[0]))) if ground_speed > 0.1 else 65535
        return mavlink.MAVLink_gps_raw_int_message(
            int(snap.time_s * 1e6),
            mavlink.GPS_FIX_TYPE_3D_FIX,
            lat,
            lon,
            alt,
            80,  # eph: HDOP 0.8
            120,  # epv: VDOP 1.2
            round(ground_speed * 100.0),
            cog,
            12,
            h_acc=h_acc_mm,
            v_acc=v_acc_mm,
        )

    def home_position(self, machine: FlightModeMachine, time_s: float):
        home = machine.home_ned_m
        lat, lon, alt = self.geodetic(home)
        return mavlink.MAVLink_home_position_message(
            lat,
            lon,
            alt,
            home[0],
            home[1],
            home[2],
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            int(time_s * 1e6),
        )

    def position_target(self, sp: Setpoint, snap: VehicleState):
        """POSITION_TARGET_LOCAL_NED: what the controller tracks now."""
        pos = sp.pos_ned_m or (0.0, 0.0, 0.0)
        vel = sp.vel_ned_mps or (0.0, 0.0, 0.0)
        if sp.pos_ned_m is None and sp.vel_ned_mps is None:
            vel_used = True  # both None: the controller holds zero velocity
        else:
            vel_used = sp.vel_ned_mps is not None
        mask = type_mask_for(
            pos=sp.pos_ned_m is not None,
            vel=vel_used,
            yaw=True,
            yaw_rate=sp.yaw_rate_radps is not None,
        )
        return mavlink.MAVLink_position_target_local_ned_message(
            _ms(snap.time_s),
            mavlink.MAV_FRAME_LOCAL_NED,
            mask,
            pos[0],
            pos[1],
            pos[2],
            vel[0],
            vel[1],
            vel[2],
            0.0,
            0.0,
            0.0,
            snap.yaw_cmd_rad if sp.yaw_rad is None else sp.yaw_rad,
            sp.yaw_rate_radps or 0.0,
        )

    def autopilot_version(self):
        return mavlink.MAVLink_autopilot_version_message(
            AUTOPILOT_CAPABILITIES,
            _FLIGHT_SW_VERSION,
            0,
            0,
            0,
            list(b"plantsim"),
            [0] * 8,
            [0] * 8,
            0,
            0,
            self.identity.uid,
            [0] * 18,
        )


def _local_position(snap: VehicleState):
    p, v = snap.pos_ned_m, snap.vel_ned_mps
    return mavlink.MAVLink_local_position_ned_message(
        _ms(snap.time_s),
        float(p[0]),
        float(p[1]),
        float(p[2]),
        float(v[0]),
        float(v[1]),
        float(v[2]),
    )


def _attitude(snap: VehicleState):
    w = snap.body_rates_frd_radps
    return mavlink.MAVLink_attitude_message(
        _ms(snap.time_s),
        snap.roll_rad,
        snap.pitch_rad,
        snap.yaw_rad,
        float(w[0]),
        float(w[1]),
        float(w[2]),
    )


def _sys_status(comm_errors: int, signing_refused: int):
    """SYS_STATUS: every sensor present, enabled and healthy (MAVSDK's health_all_ok);
    the link's errors and refused signatures in its error counters."""
    return mavlink.MAVLink_sys_status_message(
        SENSORS_PRESENT,
        SENSORS_PRESENT,
        SENSORS_PRESENT,
        100,  # load 10 %
        12600,  # mV
        -1,  # current unknown
        100,  # battery %
        0,
        min(comm_errors, 65535),
        min(signing_refused, 65535),
        0,
        0,
        0,
    )
