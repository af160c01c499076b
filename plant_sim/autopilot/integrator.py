"""ArduCopter's velocity-loop integrator as a setting of plant-sim's autopilot.

``AC_PosControl`` (ArduPilot, ``libraries/AC_AttitudeControl/AC_PosControl.cpp``) runs a
velocity PID whose integrator (``PSC_VELXY_I``, ``PSC_VELXY_IMAX``) removes a steady
disturbance; plant-sim's ArduCopter puts it on the paper's LQ loop
(:func:`plant_sim.flight_control.velocity_integrator`). Pure settings, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["NO_VELOCITY_INTEGRATOR", "VelocityIntegrator"]


@dataclass(frozen=True)
class VelocityIntegrator:
    """ArduCopter's horizontal velocity-loop integrator, put on the paper's LQ loop
    (:func:`plant_sim.flight_control.velocity_integrator`): ``PSC_VELXY_I`` and
    ``PSC_VELXY_IMAX`` (``AC_PosControl.cpp`` defaults 1.0 and 1000 cm/s²) in SI units.
    It removes the steady offset a wind leaves (the LQ loop has none of its own)."""

    gain_xy_per_s2: float = 1.0  # PSC_VELXY_I [(m/s²)/(m/s)/s]
    imax_xy_mps2: float = 10.0  # PSC_VELXY_IMAX 1000 cm/s²

    def apply_to(self, quad) -> None:
        """Put this integrator on ``quad`` (:class:`plant_sim.vehicle.Quadrotor`)."""
        quad.set_velocity_integrator(self.gain_xy_per_s2, self.imax_xy_mps2)


#: no integrator: the paper's LQ loop as it is (the PX4 flavour: its MPC_XY_VEL_I_ACC
#: is not modelled)
NO_VELOCITY_INTEGRATOR = VelocityIntegrator(0.0, 0.0)
