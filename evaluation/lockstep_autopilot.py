"""plant-sim's ArduCopter between the companion's commands and the plant, in lockstep.

The networked SIL puts plant-sim's autopilot between the companion and the paper's LQ
loop: the companion's position targets (SET_POSITION_TARGET_LOCAL_NED) and its stated
speed limit (MAV_CMD_DO_CHANGE_SPEED) go into the GUIDED mode logic
(:class:`~plant_sim.autopilot.modes.FlightModeMachine`), which shapes the target like
ArduCopter's position controller (:mod:`plant_sim.autopilot.shaping`) and hands the LQ
loop a reference with its velocity and acceleration as feed-forward, at the autopilot's
tick rate (plant-sim's service: 50 Hz of simulation time). :class:`LockstepAutopilot`
is that same path in process, so lockstep checks what the companion states as the SIL
does (issue 31).

What the companion sends, and when, mirrors :class:`companion.core.CompanionCore` with
an ArduPilot autopilot: a target on change (> 2 cm or 0.5°) and every 0.5 s
(:class:`companion.link.setpoints.SetpointPolicy`), then the envelope's speed limit,
no higher than the autopilot's own WPNAV_SPEED, rounded down to 0.25 m/s, lowered at once,
raised at most every 0.5 s, re-stated every 2 s, and the climb or descent speed that keeps
the flown slope within the path's
(:class:`companion.link.speed_limit.SpeedLimitPolicy`, DO_CHANGE_SPEED types 1, 2 and 3).
The companion's clock is the frame's capture time; the autopilot takes what was sent at
its next tick, as plant-sim takes its inbox. The estimate error of a disturbed scene is
the autopilot's: it closes its loop on truth + error, so the plant tracks the setpoint
less the error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from companion.link.flavour import Flavour
from companion.link.setpoints import PositionTarget, SetpointPolicy
from companion.link.speed_limit import SPEED_TYPE_CLIMB, SpeedLimitPolicy
from plant_sim.autopilot.modes import (
    FlightMode,
    FlightModeMachine,
    GuidedTarget,
    Kinematics,
    ModeTimings,
)
from plant_sim.autopilot.params import ParamTable, timings_from_params
from plant_sim.vehicle import Quadrotor, Setpoint, VehicleState

__all__ = ["AutopilotStats", "LockstepAutopilot", "autopilot_params"]


def autopilot_params(max_tilt_deg: float, overrides: Mapping[str, float]) -> ParamTable:
    """plant-sim's ArduCopter parameters for an airframe tilting at most ``max_tilt_deg``
    (ANGLE_MAX, as plant-sim's service sets it), with ``overrides`` (ArduCopter names and
    units, e.g. ``{"WPNAV_SPEED": 100}``) applied as PARAM_SET would: a bad name or value
    is a ``ValueError`` naming it."""
    table = ParamTable({"ANGLE_MAX": max_tilt_deg * 100.0})
    for name, value in overrides.items():
        reason = table.set(name, float(value))
        if reason is not None:
            raise ValueError(f"autopilot parameter {name}={value!r}: {reason}")
    return table


@dataclass
class AutopilotStats:
    """What went over the (absent) link: counts of the companion's commands."""

    targets_sent: int = 0
    speed_limits_sent: int = 0
    speed_limits_refused: int = 0
    lowest_speed_stated_mps: float = math.inf


class LockstepAutopilot:
    """The GUIDED mode logic flying ``quad`` in lockstep; see the module docstring.

    Parameters
    ----------
    quad : the plant (airborne, armed) at its start.
    params : the autopilot's parameters (:func:`autopilot_params`).
    ground_down_m : NED down of the ground, or None.
    rate_hz : the autopilot's tick rate [Hz of simulation time].
    state_speed_limit : whether the companion states the envelope's speed limit
        (False: the carrot alone bounds the speed).
    """

    def __init__(
        self,
        quad: Quadrotor,
        params: ParamTable,
        *,
        ground_down_m: float | None,
        rate_hz: float = 50.0,
        state_speed_limit: bool = True,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"autopilot rate must be > 0 Hz, got {rate_hz!r}")
        per_tick = quad.control.physics_rate_hz / rate_hz
        if abs(per_tick - round(per_tick)) > 1e-9 or round(per_tick) < 1:
            raise ValueError(
                f"autopilot rate {rate_hz:g} Hz must divide the physics rate "
                f"{quad.control.physics_rate_hz:g} Hz"
            )
        self.steps_per_tick = round(per_tick)
        self.wpnav_speed_mps = params.value("WPNAV_SPEED") / 100.0
        state = quad.snapshot()
        pos = state.pos_ned_m
        self._start_ned_m = (float(pos[0]), float(pos[1]), float(pos[2]))
        home = (float(pos[0]), float(pos[1]), 0.0 if ground_down_m is None else ground_down_m)
        timings = timings_from_params(ModeTimings(), params)
        # ArduCopter's velocity integrator (PSC_VELXY_I) on the plant's LQ loop, as
        # plant-sim's service puts it
        timings.velocity_integrator.apply_to(quad)
        self.machine = FlightModeMachine(
            timings,
            home_ned_m=home,
            ground_down_m=ground_down_m,
            mode=FlightMode.GUIDED,
            armed=True,
            kin=kinematics(state, np.zeros(3)),
        )
        self.state_speed_limit = state_speed_limit
        self.stats = AutopilotStats()
        self._targets = SetpointPolicy(Flavour.ARDUPILOT)
        self._speed = SpeedLimitPolicy()
        # what was sent since the last tick: targets, and DO_CHANGE_SPEED as (kind, m/s)
        self._inbox: list[PositionTarget | tuple[str, float]] = []
        self._error_ned_m = np.zeros(3)
        self._next_tick_step = 0
        quad.set_setpoint(self.machine.setpoint)

    # ---- the companion's side -------------------------------------------------------
    def command(
        self,
        target_ned_m,
        yaw_rad: float,
        speed_limit_mps: float,
        capture_s: float,
        path_dir_ned=None,
        speed_mps: float | None = None,
    ) -> None:
        """A frame's output, as the companion sends it at ``capture_s`` (its clock): the
        target, the envelope's speed limit and, given its path ``path_dir_ned`` and the
        speed flown ``speed_mps``, the path's climb or descent speed."""
        target = PositionTarget(tuple(float(x) for x in target_ned_m), float(yaw_rad))
        if self._targets.on_new_target(target, capture_s):
            self._inbox.append(target)
            self._targets.sent(target, capture_s)
            self.stats.targets_sent += 1
        if not self.state_speed_limit:
            return
        horizontal_mps = min(float(speed_limit_mps), self.wpnav_speed_mps)
        speed = self._speed.due(horizontal_mps, capture_s)
        if speed is not None:
            self._inbox.append(("ne", speed))
            self._speed.sent(speed, capture_s)
            self.stats.speed_limits_sent += 1
            self.stats.lowest_speed_stated_mps = min(self.stats.lowest_speed_stated_mps, speed)
        if path_dir_ned is None:
            return
        climb = self._speed.climb
        stated_mps = self._speed.quantize(horizontal_mps)
        vertical = climb.due(path_dir_ned, stated_mps, speed_mps, capture_s)
        if vertical is not None:
            kind, vertical_mps = vertical
            self._inbox.append(("up" if kind == SPEED_TYPE_CLIMB else "down", vertical_mps))
            climb.sent(kind, vertical_mps, capture_s)
            self.stats.speed_limits_sent += 1

    def command_output(self, out, capture_s: float) -> None:
        """:meth:`command` with a frame's :class:`~companion.pipeline.PipelineOutput`."""
        env = out.envelope
        self.command(
            out.setpoint_ned_m,
            out.yaw_rad,
            env.speed_limit_mps,
            capture_s,
            path_dir_ned=env.path_dir_ned,
            speed_mps=env.speed_mps,
        )

    # ---- the autopilot's side -------------------------------------------------------
    def next_tick_step(self) -> int:
        """The physics step count of the next tick."""
        return self._next_tick_step

    def tick(self, quad: Quadrotor, error_ned_m: np.ndarray) -> None:
        """One autopilot tick at the plant's time: take what was sent, update the modes,
        put the setpoint on the plant (the autopilot closes its loop on its estimate, the
        truth moved by ``error_ned_m``)."""
        self._error_ned_m = np.asarray(error_ned_m, dtype=float)
        kin = kinematics(quad.snapshot(), self._error_ned_m)
        inbox, self._inbox = self._inbox, []
        for what in inbox:
            if isinstance(what, PositionTarget):
                self.machine.guided_target(
                    GuidedTarget(pos_ned_m=what.pos_ned_m, yaw_rad=what.yaw_rad), kin
                )
            elif self.machine.change_speed(*what) is not None:  # DO_CHANGE_SPEED
                self.stats.speed_limits_refused += 1
        self.machine.update(kin)
        quad.set_setpoint(shifted(self.machine.setpoint, self._error_ned_m))
        self._next_tick_step += self.steps_per_tick

    @property
    def last_target_ned_m(self) -> tuple[float, float, float]:
        """The last position target the companion sent (the start before any) [m, NED]."""
        last = self._targets.last
        return self._start_ned_m if last is None else last.pos_ned_m


def kinematics(state: VehicleState, error_ned_m: np.ndarray) -> Kinematics:
    """What the mode logic reads: the vehicle as the autopilot's estimate has it."""
    return Kinematics.of(state, error_ned_m)


def shifted(sp: Setpoint, error_ned_m: np.ndarray) -> Setpoint:
    """``sp`` in the true frame when the estimate is off by ``error_ned_m``."""
    if sp.pos_ned_m is None or not np.any(error_ned_m):
        return sp
    pos = tuple(float(p - e) for p, e in zip(sp.pos_ned_m, error_ned_m, strict=True))
    return replace(sp, pos_ned_m=pos)
