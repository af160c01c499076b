"""The autopilot's parameter table and the PARAM_* protocol logic (pure, no sockets).

Names and units follow ArduCopter so ground stations recognise them. Values travel as
PARAM_VALUE floats cast from their type (ArduPilot's MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST),
which AUTOPILOT_VERSION advertises. Indices are stable: the order of :data:`PARAM_SPECS`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

from plant_sim.autopilot.integrator import VelocityIntegrator
from plant_sim.autopilot.modes import ModeTimings
from plant_sim.autopilot.shaping import BrakeProfile, ShapingLimits

#: g for the airframe's deceleration bound g·tan(ANGLE_MAX) [m/s²]
GRAVITY_MPS2 = 9.81

__all__ = [
    "PARAM_SPECS",
    "ParamSpec",
    "ParamTable",
    "ParamType",
    "timings_from_params",
]


class ParamType(enum.IntEnum):
    """MAV_PARAM_TYPE."""

    UINT8 = 1
    INT8 = 2
    UINT16 = 3
    INT16 = 4
    UINT32 = 5
    INT32 = 6
    REAL32 = 9


_INT_RANGES = {
    ParamType.UINT8: (0, 2**8 - 1),
    ParamType.INT8: (-(2**7), 2**7 - 1),
    ParamType.UINT16: (0, 2**16 - 1),
    ParamType.INT16: (-(2**15), 2**15 - 1),
    ParamType.UINT32: (0, 2**32 - 1),
    ParamType.INT32: (-(2**31), 2**31 - 1),
}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name (≤ 16 chars), type, default, bounds, read-only flag."""

    name: str
    type: ParamType
    default: float
    minimum: float = -math.inf
    maximum: float = math.inf
    read_only: bool = False


#: The table, in index order. Units in the comments (ArduCopter's).
PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("SYSID_THISMAV", ParamType.UINT8, 1, read_only=True),
    ParamSpec("SYSID_MYGCS", ParamType.UINT8, 255, 1, 255),
    ParamSpec("FRAME_CLASS", ParamType.INT8, 1, read_only=True),  # 1 = quad
    ParamSpec("FRAME_TYPE", ParamType.INT8, 1, read_only=True),  # 1 = X
    ParamSpec("ARMING_CHECK", ParamType.INT32, 1, 0, 2**31 - 1),  # bitmask, 0 = off
    ParamSpec("DISARM_DELAY", ParamType.INT8, 10, 0, 127),  # s
    ParamSpec("GUID_TIMEOUT", ParamType.REAL32, 3.0, 0.1, 5.0),  # s
    ParamSpec("LAND_SPEED", ParamType.INT16, 50, 30, 200),  # cm/s
    ParamSpec("RTL_ALT", ParamType.INT32, 1500, 200, 300000),  # cm
    ParamSpec("WPNAV_SPEED_UP", ParamType.REAL32, 150.0, 10.0, 1000.0),  # cm/s
    ParamSpec("WPNAV_SPEED", ParamType.REAL32, 1000.0, 10.0, 2000.0),  # cm/s
    ParamSpec("WPNAV_SPEED_DN", ParamType.REAL32, 150.0, 10.0, 500.0),  # cm/s
    ParamSpec("WPNAV_ACCEL", ParamType.REAL32, 250.0, 50.0, 500.0),  # cm/s²
    ParamSpec("WPNAV_ACCEL_Z", ParamType.REAL32, 100.0, 50.0, 500.0),  # cm/s²
    ParamSpec("PSC_JERK_XY", ParamType.REAL32, 5.0, 1.0, 20.0),  # m/s³
    ParamSpec("PSC_JERK_Z", ParamType.REAL32, 5.0, 5.0, 50.0),  # m/s³
    ParamSpec("PSC_VELXY_I", ParamType.REAL32, 1.0, 0.0, 1.0),  # (cm/s²)/(cm/s)/s
    ParamSpec("PSC_VELXY_IMAX", ParamType.REAL32, 1000.0, 0.0, 4500.0),  # cm/s²
    ParamSpec("LOIT_SPEED", ParamType.REAL32, 1250.0, 20.0, 3500.0),  # cm/s
    ParamSpec("LOIT_ACC_MAX", ParamType.REAL32, 500.0, 100.0, 981.0),  # cm/s²
    ParamSpec("LOIT_BRK_DECEL", ParamType.REAL32, 250.0, 25.0, 250.0),  # cm/s²
    ParamSpec("LOIT_BRK_JERK", ParamType.REAL32, 500.0, 500.0, 5000.0),  # cm/s³
    ParamSpec("LOIT_BRK_DELAY", ParamType.REAL32, 1.0, 0.0, 2.0),  # s
    ParamSpec("SIM_GUID_SHAPE", ParamType.INT8, 1, 0, 1),  # GUIDED targets shaped (1)
    ParamSpec("ANGLE_MAX", ParamType.INT16, 1500, read_only=True),  # cdeg (paper: 15°)
    ParamSpec("FS_GCS_ENABLE", ParamType.INT8, 0, 0, 7),
    ParamSpec("BRD_SAFETY_DEFLT", ParamType.INT8, 0, read_only=True),
    ParamSpec("SIM_SPEEDUP", ParamType.REAL32, 1.0, read_only=True),
    ParamSpec("SIM_CAM_RATE", ParamType.REAL32, 30.0, read_only=True),  # Hz (sim time)
)


class ParamTable:
    """Current values of :data:`PARAM_SPECS` (and ``extra_specs``, appended: a flavour's
    own parameters); ``overrides`` replace defaults by name."""

    def __init__(
        self,
        overrides: dict[str, float] | None = None,
        extra_specs: tuple[ParamSpec, ...] = (),
    ) -> None:
        self._specs = PARAM_SPECS + tuple(extra_specs)
        self._index = {s.name: i for i, s in enumerate(self._specs)}
        self._values = [float(s.default) for s in self._specs]
        for name, value in (overrides or {}).items():
            self._values[self._lookup(name)] = self._coerce(self._specs[self._lookup(name)], value)

    def __len__(self) -> int:
        return len(self._specs)

    def _lookup(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"unknown parameter {name!r}") from None

    def index_of(self, name: str) -> int | None:
        """Index of ``name`` or None."""
        return self._index.get(name)

    def entry(self, index: int) -> tuple[ParamSpec, float]:
        """(spec, value) at ``index`` (IndexError if out of range)."""
        if not 0 <= index < len(self._specs):
            raise IndexError(f"parameter index {index} outside 0..{len(self._specs) - 1}")
        return self._specs[index], self._values[index]

    def value(self, name: str) -> float:
        """Current value of ``name``."""
        return self._values[self._lookup(name)]

    def set(self, name: str, value: float) -> str | None:
        """Set ``name``; returns a refusal reason (unknown, read-only, out of range) or None."""
        index = self._index.get(name)
        if index is None:
            return f"Unknown parameter {name}"
        spec = self._specs[index]
        if spec.read_only:
            return f"Param {name} is read-only"
        if not math.isfinite(value):
            return f"Param {name}: value not finite"
        coerced = self._coerce(spec, value)
        if not spec.minimum <= coerced <= spec.maximum:
            return f"Param {name}: {value:g} outside [{spec.minimum:g}, {spec.maximum:g}]"
        self._values[index] = coerced
        return None

    @staticmethod
    def _coerce(spec: ParamSpec, value: float) -> float:
        if spec.type is ParamType.REAL32:
            return float(value)
        lo, hi = _INT_RANGES[spec.type]
        return float(min(hi, max(lo, round(value))))


def timings_from_params(base: ModeTimings, table: ParamTable) -> ModeTimings:
    """Mode timings with the values of the parameters that set them (SI units)."""
    return replace(
        base,
        guided_velocity_timeout_s=table.value("GUID_TIMEOUT"),
        disarm_delay_s=table.value("DISARM_DELAY") if table.value("DISARM_DELAY") > 0 else math.inf,
        land_speed_mps=table.value("LAND_SPEED") / 100.0,
        rtl_alt_m=table.value("RTL_ALT") / 100.0,
        takeoff_climb_mps=table.value("WPNAV_SPEED_UP") / 100.0,
        guided_shaping=table.value("SIM_GUID_SHAPE") == 1,
        guided_limits=ShapingLimits(
            speed_ne_mps=table.value("WPNAV_SPEED") / 100.0,
            speed_up_mps=table.value("WPNAV_SPEED_UP") / 100.0,
            speed_down_mps=table.value("WPNAV_SPEED_DN") / 100.0,
            accel_ne_mps2=table.value("WPNAV_ACCEL") / 100.0,
            accel_d_mps2=table.value("WPNAV_ACCEL_Z") / 100.0,
            jerk_ne_mps3=table.value("PSC_JERK_XY"),
            jerk_d_mps3=table.value("PSC_JERK_Z"),
        ),
        loiter=BrakeProfile(
            decel_mps2=table.value("LOIT_BRK_DECEL") / 100.0,
            jerk_mps3=table.value("LOIT_BRK_JERK") / 100.0,
            delay_s=table.value("LOIT_BRK_DELAY"),
            drag_per_s=table.value("LOIT_ACC_MAX") / table.value("LOIT_SPEED"),
        ),
        velocity_integrator=VelocityIntegrator(
            gain_xy_per_s2=table.value("PSC_VELXY_I"),
            imax_xy_mps2=table.value("PSC_VELXY_IMAX") / 100.0,
        ),
        max_decel_mps2=0.8
        * GRAVITY_MPS2
        * math.tan(math.radians(table.value("ANGLE_MAX") / 100.0)),
    )
