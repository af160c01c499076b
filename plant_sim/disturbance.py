"""What the real world adds to a flight: wind with gusts, and a wandering position estimate.

Issue 31 item 4. Two processes, advanced in simulation time by :class:`Disturbances`:

**Wind** (LOCAL_NED [m/s]): a steady mean plus gusts, each horizontal and the vertical
component a first-order Gauss-Markov process (the Dryden model's low-order form: a gust
of standard deviation ``gust_std_mps`` correlated over ``gust_tau_s``). The vehicle's
translational drag, Eq. (12)'s ``K_t`` term, acts on the velocity relative to the air,
``ξ̇ − w`` (:meth:`plant_sim.vehicle.Quadrotor.set_wind_ned_mps`); the controller does not
know the wind (its feedback linearization cancels the drag of the ground velocity), so a
steady wind leaves the steady position offset a real LQ loop without an integrator has,
``K_t w / (m k_p)``. The paper's airframe is drag-limited to ~0.85 m/s at its 15° tilt
limit, so it cannot hold position in winds near that: give it light airs.

**Position estimate** (LOCAL_NED [m]): the error ``e`` between what the autopilot believes
and the truth, as GPS gives it: a Gauss-Markov wander of standard deviation ``wander_std_m``
correlated over ``wander_tau_s``, a steady ``drift_ned_mps`` (a slow bias), and jumps of
``jump_m`` in a random horizontal direction at random times (mean interval
``jump_every_s``; a jump joins the wander and decays with it, like a glitch the estimator
recovers from). The autopilot reports and controls ``truth + e`` — so holding a target
moves the true vehicle by ``−e`` — while the camera sees the true world.

**Stated accuracy** (:attr:`Disturbances.stated_accuracy_m`): what the autopilot says of
its own estimate, as GPS_RAW_INT ``h_acc``/``v_acc`` do (ArduPilot's
``AP_GPS::send_mavlink_gps_raw`` fills them from the receiver's horizontal and vertical
accuracy; PX4's ``MavlinkStreamGPSRawInt`` likewise). It follows the error simulated: the
root sum of squares of the wander's standard deviation, the jump size (while jumps are
on) and the drift accumulated so far, horizontal and vertical apart; (0, 0) with no
estimate error. ``stated_floor_m`` raises both to at least a fixed figure, as ArduPilot's
SITL does: its simulated receiver states ``SIM_GPS_ACC`` (0.3 m by default) for
``h_acc`` and ``v_acc`` whatever its wander (``libraries/SITL/SIM_GPS.cpp``,
``GPS::update``), so a companion flown against SITL widens its margins by 0.3 m. A
receiver states its accuracy, not its error: the stated figure never reveals ``e``
itself.

Pure: a seeded generator, time passed in; nothing here reads a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols.config import Checked, bounded, check_fields, vec3

__all__ = ["DisturbanceConfig", "Disturbances", "EstimateConfig", "WindConfig"]

_STEP_S = 0.02  # the processes' internal step [s]: the autopilot's 50 Hz


def _check_vectors(obj: Any, names: tuple[str, ...]) -> None:
    """Each of ``obj``'s fields ``names``: three finite numbers, stored as floats."""
    for name in names:
        object.__setattr__(obj, name, vec3(getattr(obj, name), name))


@dataclass(frozen=True)
class WindConfig:
    """Steady wind and gusts (LOCAL_NED)."""

    mean_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  # steady wind [m/s]
    gust_std_mps: float = bounded(0.0, "m/s", ge=0)  # horizontal gust standard deviation
    gust_vertical_std_mps: float = bounded(0.0, "m/s", ge=0)  # vertical gust standard deviation
    gust_tau_s: float = bounded(2.0, "s", gt=0)  # gust correlation time

    def __post_init__(self) -> None:
        check_fields(self)
        _check_vectors(self, ("mean_ned_mps",))


@dataclass(frozen=True)
class EstimateConfig:
    """How the reported position wanders from the truth (LOCAL_NED)."""

    wander_std_m: float = bounded(0.0, "m", ge=0)  # horizontal wander standard deviation
    wander_vertical_std_m: float = bounded(0.0, "m", ge=0)  # vertical wander standard deviation
    wander_tau_s: float = bounded(30.0, "s", gt=0)  # wander correlation time
    drift_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)  # steady error drift [m/s]
    jump_m: float = bounded(0.0, "m", ge=0)  # size of a jump, horizontal
    # mean time between jumps; inf: none
    jump_every_s: float = bounded(math.inf, "s", gt=0, finite=False)
    # the accuracy the receiver states at least, whatever its error (ArduPilot SITL's
    # SIM_GPS_ACC: SITL states 0.3 m by default with no wander at all)
    stated_floor_m: float = bounded(0.0, "m", ge=0)

    def __post_init__(self) -> None:
        check_fields(self)
        _check_vectors(self, ("drift_ned_mps",))


@dataclass(frozen=True)
class DisturbanceConfig(Checked):
    """Wind and estimate error of a flight; ``seed`` makes them repeatable."""

    wind: WindConfig = field(default_factory=WindConfig)
    estimate: EstimateConfig = field(default_factory=EstimateConfig)
    seed: int = bounded(0, integer=True, ge=0)

    @property
    def active(self) -> bool:
        """Whether anything is disturbed at all."""
        return self != DisturbanceConfig(seed=self.seed)


def _gauss_markov(x: np.ndarray, std: np.ndarray, tau_s: float, dt: float, rng) -> np.ndarray:
    """One exact step of ``dx = −x/τ dt + σ √(2/τ) dW``: stationary standard deviation σ."""
    a = math.exp(-dt / tau_s)
    return a * x + std * math.sqrt(1.0 - a * a) * rng.standard_normal(3)


class Disturbances:
    """The wind and estimate error of :class:`DisturbanceConfig`, in simulation time.

    Starts at ``start_time_s`` with the gusts and wander drawn from their stationary
    distribution (the flight does not begin in a lull) and no drift or jump yet.
    """

    def __init__(self, config: DisturbanceConfig, start_time_s: float = 0.0) -> None:
        self.config = config
        self._rng = np.random.default_rng(config.seed)
        w, e = config.wind, config.estimate
        self._gust_std = np.array([w.gust_std_mps, w.gust_std_mps, w.gust_vertical_std_mps])
        self._wander_std = np.array([e.wander_std_m, e.wander_std_m, e.wander_vertical_std_m])
        self._gust = self._gust_std * self._rng.standard_normal(3)
        self._wander = self._wander_std * self._rng.standard_normal(3)
        self._drift = np.zeros(3)
        self._time_s = float(start_time_s)
        self.jumps = 0  # jumps so far

    @property
    def time_s(self) -> float:
        return self._time_s

    @property
    def wind_ned_mps(self) -> tuple[float, float, float]:
        mean = self.config.wind.mean_ned_mps
        return tuple(float(m + g) for m, g in zip(mean, self._gust, strict=True))

    @property
    def estimate_error_ned_m(self) -> tuple[float, float, float]:
        return tuple(float(v) for v in self._wander + self._drift)

    @property
    def stated_accuracy_m(self) -> tuple[float, float]:
        """(horizontal, vertical) accuracy the autopilot states for its estimate [m, 1σ]."""
        e = self.config.estimate
        jump = 0.0 if math.isinf(e.jump_every_s) else e.jump_m
        h = math.sqrt(e.wander_std_m**2 + jump**2 + self._drift[0] ** 2 + self._drift[1] ** 2)
        v = math.hypot(e.wander_vertical_std_m, float(self._drift[2]))
        return max(h, e.stated_floor_m), max(v, e.stated_floor_m)

    def advance(self, time_s: float) -> None:
        """Step both processes to ``time_s`` (no-op for a time not after the current)."""
        w, e = self.config.wind, self.config.estimate
        drift = np.asarray(e.drift_ned_mps, dtype=float)
        jump_rate = 0.0 if math.isinf(e.jump_every_s) or e.jump_m == 0.0 else 1.0 / e.jump_every_s
        while self._time_s < time_s - 1e-12:
            dt = min(_STEP_S, time_s - self._time_s)
            self._gust = _gauss_markov(self._gust, self._gust_std, w.gust_tau_s, dt, self._rng)
            self._wander = _gauss_markov(
                self._wander, self._wander_std, e.wander_tau_s, dt, self._rng
            )
            self._drift += drift * dt
            if jump_rate > 0.0 and self._rng.random() < jump_rate * dt:
                heading = self._rng.uniform(0.0, 2.0 * math.pi)
                self._wander += e.jump_m * np.array([math.cos(heading), math.sin(heading), 0.0])
                self.jumps += 1
            self._time_s += dt
