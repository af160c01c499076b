"""A quadrotor you can step: paper dynamics + flight controller behind a NED interface.

:class:`Quadrotor` takes setpoints in MAVLink LOCAL_NED (metres, rad) and exposes its
state in NED/FRD with MAVLink 3-2-1 angles; the paper's z-up frame stays inside. Time is
simulation time in seconds, advanced only by :meth:`Quadrotor.step`: no clocks here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from plant_sim import flight_control as fc
from plant_sim import paper_frames
from plant_sim.dynamics import STATE_SIZE, physics_constants, rk4_step
from plant_sim.lq import design_tracker
from plant_sim.params import ControlParams, QuadrotorParams
from protocols import frames

__all__ = ["Quadrotor", "Setpoint", "VehicleState"]


@dataclass(frozen=True)
class Setpoint:
    """What the flight controller tracks, in LOCAL_NED.

    ``pos_ned_m`` and ``vel_ned_mps`` may each be None (not controlled); with both None
    the vehicle holds zero velocity. ``acc_ned_mps2`` is an acceleration feed-forward (a
    shaped reference's second derivative), None for none. ``yaw_rad`` None keeps the
    previous heading target; ``yaw_rate_radps`` turns the heading target at that rate.
    """

    pos_ned_m: tuple[float, float, float] | None = None
    vel_ned_mps: tuple[float, float, float] | None = None
    yaw_rad: float | None = None
    yaw_rate_radps: float | None = None
    acc_ned_mps2: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("pos_ned_m", "vel_ned_mps", "acc_ned_mps2"):
            value = getattr(self, name)
            if value is None:
                continue
            vec = tuple(float(v) for v in value)
            if len(vec) != 3 or not all(math.isfinite(v) for v in vec):
                raise ValueError(f"Setpoint.{name} must be 3 finite numbers, got {value!r}")
            object.__setattr__(self, name, vec)
        for name in ("yaw_rad", "yaw_rate_radps"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise ValueError(f"Setpoint.{name} must be finite, got {value!r}")


@dataclass(frozen=True)
class VehicleState:
    """A snapshot of the vehicle and its controller, NED/FRD, MAVLink angle conventions."""

    time_s: float
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    body_rates_frd_radps: np.ndarray
    rotor_thrusts_n: np.ndarray
    roll_cmd_rad: float
    pitch_cmd_rad: float
    yaw_cmd_rad: float
    total_thrust_cmd_n: float
    tilt_saturated: bool
    rotor_saturated: bool
    on_ground: bool
    armed: bool

    @property
    def R_ned_from_frd(self) -> np.ndarray:
        """Body FRD → NED rotation."""
        return frames.rotation_321(self.roll_rad, self.pitch_rad, self.yaw_rad)


@numba.njit(cache=True)
def _advance(
    state: np.ndarray,
    ctrl_out: np.ndarray,
    n_steps: int,
    phase: int,
    yaw_sp_ned_rad: float,
    loop: tuple,
) -> tuple[np.ndarray, int, float, bool]:
    """Advance ``n_steps`` RK4 steps with the controller every ``steps_per_control`` steps.

    Returns the new state, the control phase, the (possibly turning) yaw target and
    whether the vehicle rests on the ground. The controller is
    :func:`plant_sim.flight_control.control_law`, its acceleration feed-forward through
    the drag-lag lead (issue 31) and the velocity-loop integrator (off unless set:
    :meth:`Quadrotor.set_velocity_integrator`). (numba caches this loop, callees compiled
    in, by this file's stamp: a change to the controller or the dynamics must touch this
    file.)
    Ground contact is inelastic: the vehicle stops on the plane ``z = ground_z_m`` (paper
    frame) and sits level there. ``loop`` holds what the steps do not change
    (:meth:`Quadrotor._loop_args`).
    """
    (
        steps_per_control,
        dt_s,
        pos_sp_m,
        vel_sp_mps,
        acc_sp_mps2,
        yaw_rate_sp_radps,
        gains_pos,
        gains_att,
        max_tilt_rad,
        min_vertical_accel_mps2,
        k,
        armed,
        ground_z_m,
        vel_i,
        vel_i_gain,
        vel_i_max,
    ) = loop
    on_ground = False
    for _ in range(n_steps):
        if phase == 0:
            if not math.isnan(yaw_rate_sp_radps):
                yaw_sp_ned_rad += yaw_rate_sp_radps * dt_s * steps_per_control
            if not armed or on_ground:
                vel_i[:] = 0.0  # ArduCopter resets its integrators on the ground
            elif vel_i_gain[0] > 0.0 or vel_i_gain[1] > 0.0:
                fc.velocity_integrator(
                    state,
                    pos_sp_m,
                    vel_sp_mps,
                    acc_sp_mps2,
                    gains_pos,
                    vel_i,
                    vel_i_gain,
                    vel_i_max,
                    dt_s * steps_per_control,
                    ctrl_out[fc.OUT_TILT_SAT] > 0.5,
                )
            if armed:
                fc.control_law(
                    state,
                    pos_sp_m,
                    vel_sp_mps,
                    acc_sp_mps2,
                    yaw_sp_ned_rad,
                    gains_pos,
                    gains_att,
                    max_tilt_rad,
                    min_vertical_accel_mps2,
                    k,
                    ctrl_out,
                    vel_i,
                )
            else:
                for i in range(fc.OUT_SIZE):
                    ctrl_out[i] = 0.0
        phase = (phase + 1) % steps_per_control
        state = rk4_step(state, ctrl_out[0:4], dt_s, k)
        on_ground = False
        if not math.isnan(ground_z_m) and state[2] <= ground_z_m and state[5] <= 0.0:
            state[2] = ground_z_m
            for i in (3, 4, 5, 6, 7, 9, 10, 11):
                state[i] = 0.0
            on_ground = True
    return state, phase, yaw_sp_ned_rad, on_ground


@numba.njit(cache=True)
def _advance_watching(
    state, ctrl_out, n_steps, phase, yaw_sp_ned_rad, loop, centres_paper_m, radii_m
):
    """:func:`_advance` one step at a time, watching after each step the commanded tilt
    (MAVLink roll and pitch, as :meth:`Quadrotor.tilt_cmd_rad`) and the distance from the
    vehicle to the nearest sphere surface (centres in the paper frame).

    Returns (state, phase, yaw target, on_ground, max |roll cmd|, max |pitch cmd|,
    min surface distance).
    """
    max_roll = 0.0
    max_pitch = 0.0
    min_surface = np.inf
    on_ground = False
    for _ in range(n_steps):
        state, phase, yaw_sp_ned_rad, on_ground = _advance(
            state, ctrl_out, 1, phase, yaw_sp_ned_rad, loop
        )
        phi = ctrl_out[fc.OUT_PHI_D]
        theta = ctrl_out[fc.OUT_THETA_D]
        psi = ctrl_out[fc.OUT_PSI_D]
        sf, cf = math.sin(phi), math.cos(phi)
        st, ct = math.sin(theta), math.cos(theta)
        sp, cp = math.sin(psi), math.cos(psi)
        r20 = -cf * st * cp + sf * sp
        r21 = cf * st * sp + sf * cp
        max_roll = max(max_roll, abs(math.atan2(r21, cf * ct)))
        max_pitch = max(max_pitch, abs(math.asin(max(-1.0, min(1.0, r20)))))
        for j in range(radii_m.shape[0]):
            dx = state[0] - centres_paper_m[j, 0]
            dy = state[1] - centres_paper_m[j, 1]
            dz = state[2] - centres_paper_m[j, 2]
            min_surface = min(min_surface, math.sqrt(dx * dx + dy * dy + dz * dz) - radii_m[j])
    return state, phase, yaw_sp_ned_rad, on_ground, max_roll, max_pitch, min_surface


class Quadrotor:
    """The paper's quadrotor with its FL + LQ flight controller, stepped in simulation time.

    Parameters
    ----------
    params, control : vehicle and controller parameters (defaults: the paper's).
    pos_ned_m : initial position, LOCAL_NED [m].
    yaw_rad : initial MAVLink heading [rad]; also the initial heading target.
    ground_down_m : NED down coordinate of a flat ground, or None for no ground.
    armed : whether the rotors run from the start.

    The initial setpoint holds the initial position.
    """

    def __init__(
        self,
        params: QuadrotorParams | None = None,
        control: ControlParams | None = None,
        *,
        pos_ned_m: Sequence[float] = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        ground_down_m: float | None = 0.0,
        armed: bool = True,
    ) -> None:
        self.params = params or QuadrotorParams()
        self.control = control or ControlParams()
        self._k = physics_constants(self.params)
        self._gains_pos = design_tracker(
            self.control.q_position, self.control.r_position
        ).per_axis_gains()
        self._gains_att = design_tracker(
            self.control.q_attitude, self.control.r_attitude
        ).per_axis_gains()
        self._max_tilt_rad = math.radians(self.control.max_tilt_deg)
        self._dt_s = self.control.physics_dt_s
        self._ground_z_m = math.nan if ground_down_m is None else -float(ground_down_m)

        self._state = np.zeros(STATE_SIZE)
        self._state[0:3] = paper_frames.paper_from_ned(np.asarray(pos_ned_m, dtype=float))
        self._state[6:9] = paper_frames.paper_euler_from_mavlink_euler(0.0, 0.0, float(yaw_rad))
        self._ctrl_out = np.zeros(fc.OUT_SIZE)
        self._phase = 0
        self._steps = 0
        self._armed = bool(armed)
        self._on_ground = False
        self._pos_sp = np.full(3, np.nan)
        self._vel_sp = np.full(3, np.nan)
        self._acc_sp = np.full(3, np.nan)
        self._yaw_sp_rad = float(yaw_rad)
        self._yaw_rate_sp = math.nan
        self._vel_i = np.zeros(3)  # velocity-loop integrator sum [m/s², paper frame]
        self._vel_i_gain = np.zeros(2)  # [horizontal, vertical] [1/s²]; 0: the paper's law
        self._vel_i_max = np.zeros(2)  # [horizontal, vertical] [m/s²]
        self.set_setpoint(Setpoint(pos_ned_m=tuple(pos_ned_m), yaw_rad=float(yaw_rad)))

    # ---- commands ----------------------------------------------------------------------
    @property
    def armed(self) -> bool:
        """True while the rotors run."""
        return self._armed

    def set_armed(self, armed: bool) -> None:
        """Start or stop the rotors (disarmed: all rotor thrusts zero)."""
        self._armed = bool(armed)

    def set_wind_ned_mps(self, wind_ned_mps) -> None:
        """The air's velocity from now on, LOCAL_NED [m/s] (:mod:`plant_sim.disturbance`);
        the drag of Eq. (12) acts on the velocity relative to it."""
        wind_ned = np.asarray(wind_ned_mps, dtype=float).reshape(3)
        if not np.all(np.isfinite(wind_ned)):
            raise ValueError(f"wind must be finite, got {wind_ned_mps!r}")
        x, y, z = (float(v) for v in paper_frames.paper_from_ned(wind_ned))
        self._k = self._k._replace(wind_x=x, wind_y=y, wind_z=z)

    def set_velocity_integrator(
        self,
        gain_xy_per_s2: float,
        imax_xy_mps2: float,
        gain_z_per_s2: float = 0.0,
        imax_z_mps2: float = 0.0,
    ) -> None:
        """An ArduCopter-like velocity-loop integrator from now on (PSC_VELXY_I and
        PSC_VELXY_IMAX in SI units; :func:`plant_sim.flight_control.velocity_integrator`);
        all zero (the default): the paper's law. A gain of 0 clears that sum."""
        values = (gain_xy_per_s2, imax_xy_mps2, gain_z_per_s2, imax_z_mps2)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f"integrator gains and limits must be finite and >= 0: {values}")
        self._vel_i_gain = np.array([gain_xy_per_s2, gain_z_per_s2], dtype=float)
        self._vel_i_max = np.array([imax_xy_mps2, imax_z_mps2], dtype=float)
        if gain_xy_per_s2 == 0.0:
            self._vel_i[0:2] = 0.0
        if gain_z_per_s2 == 0.0:
            self._vel_i[2] = 0.0

    @property
    def velocity_integrator_ned_mps2(self) -> np.ndarray:
        """The velocity-loop integrator's sum, NED [m/s²] (zeros without one)."""
        return paper_frames.ned_from_paper(self._vel_i.copy())

    def set_setpoint(self, sp: Setpoint) -> None:
        """Track ``sp`` from the next controller update on."""
        self._pos_sp = (
            np.full(3, np.nan)
            if sp.pos_ned_m is None
            else paper_frames.paper_from_ned(np.asarray(sp.pos_ned_m))
        )
        self._vel_sp = (
            np.full(3, np.nan)
            if sp.vel_ned_mps is None
            else paper_frames.paper_from_ned(np.asarray(sp.vel_ned_mps))
        )
        self._acc_sp = (
            np.full(3, np.nan)
            if sp.acc_ned_mps2 is None
            else paper_frames.paper_from_ned(np.asarray(sp.acc_ned_mps2))
        )
        if sp.yaw_rad is not None:
            self._yaw_sp_rad = float(sp.yaw_rad)
        self._yaw_rate_sp = math.nan if sp.yaw_rate_radps is None else float(sp.yaw_rate_radps)

    @property
    def setpoint(self) -> Setpoint:
        """What the controller tracks now (yaw target included, turned by any yaw rate)."""
        pos = None if np.isnan(self._pos_sp).all() else paper_frames.ned_from_paper(self._pos_sp)
        vel = None if np.isnan(self._vel_sp).all() else paper_frames.ned_from_paper(self._vel_sp)
        acc = None if np.isnan(self._acc_sp).all() else paper_frames.ned_from_paper(self._acc_sp)
        return Setpoint(
            pos_ned_m=None if pos is None else tuple(np.nan_to_num(pos)),
            vel_ned_mps=None if vel is None else tuple(np.nan_to_num(vel)),
            acc_ned_mps2=None if acc is None else tuple(np.nan_to_num(acc)),
            yaw_rad=_wrap_pi(self._yaw_sp_rad),
            yaw_rate_radps=None if math.isnan(self._yaw_rate_sp) else self._yaw_rate_sp,
        )

    # ---- time --------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulation time [s]."""
        return self._steps * self._dt_s

    @property
    def dt_s(self) -> float:
        """Physics step [s]."""
        return self._dt_s

    def _loop_args(self) -> tuple:
        """What the compiled loop does not change: control rate, step, setpoints, gains,
        limits, parameters, arming, ground, and the velocity integrator (its sum, changed
        in place, gains and limits) (``loop`` of :func:`_advance`)."""
        return (
            self.control.steps_per_control,
            self._dt_s,
            self._pos_sp,
            self._vel_sp,
            self._acc_sp,
            self._yaw_rate_sp,
            self._gains_pos,
            self._gains_att,
            self._max_tilt_rad,
            self.control.min_vertical_accel_mps2,
            self._k,
            self._armed,
            self._ground_z_m,
            self._vel_i,
            self._vel_i_gain,
            self._vel_i_max,
        )

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` physics steps."""
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        if n_steps == 0:
            return
        self._run(_advance, n_steps)

    def _run(self, advance, n_steps: int, *watch) -> tuple:
        """Run the compiled loop ``advance`` for ``n_steps`` (> 0) steps from the current
        state, keep what it returns of the state and return the rest (what it watched)."""
        out = advance(
            self._state,
            self._ctrl_out,
            int(n_steps),
            self._phase,
            self._yaw_sp_rad,
            self._loop_args(),
            *watch,
        )
        self._state, self._phase, self._yaw_sp_rad, self._on_ground = out[:4]
        self._steps += int(n_steps)
        if not np.all(np.isfinite(self._state)):
            raise FloatingPointError(f"vehicle state diverged at t={self.time_s:.3f} s")
        return out[4:]

    def step_watching(
        self, n_steps: int, sphere_centres_ned_m: np.ndarray, sphere_radii_m: np.ndarray
    ) -> tuple[float, float, float]:
        """:meth:`step` ``n_steps`` times one step at a time, in one compiled call, watching.

        Returns the largest |commanded roll| and |commanded pitch| [rad] after any of the
        steps (as :meth:`tilt_cmd_rad` would read them) and the smallest distance from the
        vehicle to a sphere's surface [m] (``inf`` with no sphere): the lockstep harness's
        per-step monitoring without a Python call per step.

        Parameters
        ----------
        n_steps : int
            Physics steps, >= 0.
        sphere_centres_ned_m : numpy.ndarray, shape (N, 3)
            Sphere centres, LOCAL_NED [m].
        sphere_radii_m : numpy.ndarray, shape (N,)
            Sphere radii [m].
        """
        if n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        centres = np.asarray(sphere_centres_ned_m, dtype=float).reshape(-1, 3)
        radii = np.asarray(sphere_radii_m, dtype=float).reshape(-1)
        if centres.shape[0] != radii.shape[0]:
            raise ValueError(f"{centres.shape[0]} sphere centres but {radii.shape[0]} radii")
        if n_steps == 0:
            return 0.0, 0.0, math.inf
        centres_paper = np.ascontiguousarray(paper_frames.paper_from_ned(centres))
        max_roll, max_pitch, min_surface = self._run(
            _advance_watching, n_steps, centres_paper, radii
        )
        return float(max_roll), float(max_pitch), float(min_surface)

    def run_until(self, time_s: float) -> None:
        """Advance to the physics step at or just after ``time_s``."""
        target = math.ceil(time_s / self._dt_s - 1e-9)
        self.step(max(0, target - self._steps))

    # ---- state -------------------------------------------------------------------------
    @property
    def pos_ned_m(self) -> np.ndarray:
        """Position, LOCAL_NED [m]."""
        return paper_frames.ned_from_paper(self._state[0:3])

    @property
    def vel_ned_mps(self) -> np.ndarray:
        """Velocity, LOCAL_NED [m/s]."""
        return paper_frames.ned_from_paper(self._state[3:6])

    @property
    def rotor_thrusts_n(self) -> np.ndarray:
        """Rotor thrusts F1..F4 applied over the last step [N]."""
        return self._ctrl_out[fc.OUT_ROTORS].copy()

    def tilt_cmd_rad(self) -> tuple[float, float]:
        """Commanded MAVLink (roll, pitch) [rad] of the last controller update.

        Cheap scalar path for per-step monitoring: with ``R_ned = T R T`` (Eq. 4),
        ``roll = atan2(R21, R22)`` and ``pitch = asin(R20_paper)``.
        """
        out = self._ctrl_out
        phi, theta, psi = out[fc.OUT_PHI_D], out[fc.OUT_THETA_D], out[fc.OUT_PSI_D]
        sf, cf = math.sin(phi), math.cos(phi)
        st, ct = math.sin(theta), math.cos(theta)
        sp, cp = math.sin(psi), math.cos(psi)
        r20 = -cf * st * cp + sf * sp
        r21 = cf * st * sp + sf * cp
        return math.atan2(r21, cf * ct), math.asin(max(-1.0, min(1.0, r20)))

    def snapshot(self) -> VehicleState:
        """The vehicle and its controller now, in NED/FRD with MAVLink angles."""
        s = self._state
        R_paper = paper_frames.rotation_123(s[6], s[7], s[8])
        roll, pitch, yaw = frames.euler321_from_rotation(
            paper_frames.rotation_ned_from_paper(R_paper)
        )
        # body rates: Ω = R_r φ̇ (Eq. 5) in paper body axes (FLU), then FRD
        st, ct = math.sin(s[7]), math.cos(s[7])
        sp, cp = math.sin(s[8]), math.cos(s[8])
        omega_flu = np.array(
            [
                ct * cp * s[9] + sp * s[10],
                -ct * sp * s[9] + cp * s[10],
                st * s[9] + s[11],
            ]
        )
        out = self._ctrl_out
        roll_c, pitch_c, yaw_c = paper_frames.mavlink_euler_from_paper_euler(
            out[fc.OUT_PHI_D], out[fc.OUT_THETA_D], out[fc.OUT_PSI_D]
        )
        return VehicleState(
            time_s=self.time_s,
            pos_ned_m=self.pos_ned_m,
            vel_ned_mps=self.vel_ned_mps,
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=yaw,
            body_rates_frd_radps=paper_frames.ned_from_paper(omega_flu),
            rotor_thrusts_n=self.rotor_thrusts_n,
            roll_cmd_rad=roll_c,
            pitch_cmd_rad=pitch_c,
            yaw_cmd_rad=yaw_c,
            total_thrust_cmd_n=float(out[fc.OUT_TOTAL_THRUST]),
            tilt_saturated=bool(out[fc.OUT_TILT_SAT]),
            rotor_saturated=bool(out[fc.OUT_ROTOR_SAT]),
            on_ground=self._on_ground,
            armed=self._armed,
        )


def _wrap_pi(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi
