"""The plant-sim process: physics, autopilot, MAVLink link, camera and logs in one loop.

One thread. Each pass: send the wall-clock heartbeat; advance the physics towards the
simulation time the :class:`~plant_sim.clock.Pacer` allows, stopping at every autopilot
tick (default 50 Hz of simulation time) and camera frame; then wait on the sockets until
the next event is due. Incoming messages are queued and executed at the next autopilot
tick, as a real autopilot's scheduler does, so a command takes effect at the same
simulation time at any ``--speedup`` (TIMESYNC is answered at once). Telemetry samples
are taken at ticks, stamped with simulation time.

The MAVLink input (rate limits, the inbox, the message handlers, the parameter protocol)
is :mod:`plant_sim.service_inbound`; the flavour's differences are strategies
(:mod:`plant_sim.autopilot.flavours`); telemetry is built by
:mod:`plant_sim.autopilot.telemetry` and frames by :mod:`plant_sim.camera_publisher`.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from plant_sim.autopilot.flavours import FLAVOUR_NAMES, flavour_class, flavour_for, param_specs_for
from plant_sim.autopilot.link import EndpointSpec, MavlinkLink
from plant_sim.autopilot.modes import (
    FlightModeMachine,
    Kinematics,
    ModeTimings,
)
from plant_sim.autopilot.params import ParamTable, timings_from_params
from plant_sim.autopilot.pilot_flight import PilotFlight
from plant_sim.autopilot.ratelimit import RequestLimiter
from plant_sim.autopilot.telemetry import (
    StreamScheduler,
    TelemetryBuilder,
    VehicleIdentity,
)
from plant_sim.camera_publisher import StereoPublisher, readiness_fields
from plant_sim.clock import Pacer
from plant_sim.disturbance import Disturbances
from plant_sim.scenario import Scenario
from plant_sim.service_inbound import MessageHandlers
from plant_sim.tlog import TlogWriter
from plant_sim.truth_log import TruthLogWriter
from plant_sim.vehicle import Quadrotor, Setpoint, VehicleState
from protocols.config import bounded, check_fields
from protocols.keys import stereo_key
from protocols.signing import SigningKey
from protocols.statustext import statustext_chunks
from protocols.zenoh_session import ZenohSettings

__all__ = ["PlantConfig", "PlantService"]

_log = logging.getLogger("plant_sim")

_SEVERITY_WARNING = mavlink.MAV_SEVERITY_WARNING
_SEVERITY_INFO = mavlink.MAV_SEVERITY_INFO


@dataclass(frozen=True)
class PlantConfig:
    """Everything one plant-sim run needs (built from the CLI by ``__main__``)."""

    scenario: Scenario
    mavlink: tuple[EndpointSpec, ...]
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    # simulation seconds per wall second; inf = as fast as possible
    speedup: float = bounded(1.0, gt=0, finite=False)
    signing_key: SigningKey | None = None
    log_dir: Path | None = None  # .tlog and truth CSV go here; None = no logs
    # mode logic, command execution, telemetry sampling
    autopilot_rate_hz: float = bounded(50.0, "Hz", gt=0)
    # ground-truth rows per simulation second (≤ autopilot rate)
    truth_rate_hz: float = bounded(50.0, "Hz", gt=0)
    # stop after this much simulation time
    duration_s: float | None = bounded(None, "s", ge=0, optional=True)
    heartbeat_period_s: float = bounded(1.0, "s", gt=0)  # wall time
    signing_state: Path | None = None  # replay-protection timestamps kept across restarts
    autopilot_flavour: str = "ardupilot"  # or "px4": PX4 heartbeat, modes, offboard rules

    def __post_init__(self) -> None:
        if self.autopilot_flavour not in FLAVOUR_NAMES:
            raise ValueError(
                f"autopilot flavour must be one of {FLAVOUR_NAMES}, got {self.autopilot_flavour!r}"
            )
        if not self.mavlink:
            raise ValueError("at least one --mavlink endpoint is needed")
        check_fields(self)


def _initial_vehicle(scenario) -> Quadrotor:
    """The quadrotor at the scenario's start: airborne where it says, else on the ground
    below it (disarmed)."""
    start = scenario.start
    ground = scenario.ground_down_m
    pos = start.pos_ned_m
    if not start.airborne:
        pos = (pos[0], pos[1], ground if ground is not None else pos[2])
    return Quadrotor(
        scenario.vehicle,
        scenario.control,
        pos_ned_m=pos,
        yaw_rad=math.radians(start.yaw_deg),
        ground_down_m=ground,
        armed=start.airborne,
    )


def _param_table(config: PlantConfig) -> ParamTable:
    """The autopilot's parameters, from the scenario's failsafe and control settings
    (ArduCopter names and units: cm, cm/s, centidegrees)."""
    sc = config.scenario
    fs = sc.failsafe
    return ParamTable(
        {
            "GUID_TIMEOUT": fs.guided_velocity_timeout_s,
            "DISARM_DELAY": fs.disarm_delay_s,
            "LAND_SPEED": fs.land_speed_mps * 100.0,
            "RTL_ALT": fs.rtl_alt_m * 100.0,
            "WPNAV_SPEED_UP": fs.takeoff_climb_mps * 100.0,
            "ANGLE_MAX": sc.control.max_tilt_deg * 100.0,
            "SIM_SPEEDUP": config.speedup if math.isfinite(config.speedup) else 0.0,
            "SIM_CAM_RATE": sc.camera.rate_hz if sc.camera.enabled else 0.0,
        },
        extra_specs=param_specs_for(config.autopilot_flavour),
    )


def _shifted(sp: Setpoint, error_ned_m) -> Setpoint:
    """``sp`` in the true frame when the estimate is off by ``error_ned_m``."""
    if sp.pos_ned_m is None:
        return sp
    pos = tuple(float(p - e) for p, e in zip(sp.pos_ned_m, error_ned_m, strict=True))
    return dataclasses.replace(sp, pos_ned_m=pos)


class PlantService(MessageHandlers):
    """Owns the plant's parts; :meth:`open`, :meth:`run`, :meth:`close`.

    The MAVLink message handlers are :class:`~plant_sim.service_inbound.MessageHandlers`.
    """

    def __init__(self, config: PlantConfig) -> None:
        self.config = config
        sc = config.scenario
        fs = sc.failsafe
        ground = sc.ground_down_m
        self.quad = _initial_vehicle(sc)
        pos = self.quad.pos_ned_m
        self.params = _param_table(config)
        self._base_timings = ModeTimings(land_detect_s=fs.land_detect_s)
        home = (float(pos[0]), float(pos[1]), ground if ground is not None else 0.0)
        self.disturbances = Disturbances(sc.disturbance) if sc.disturbance.active else None
        kin = self._kinematics(self._estimated(self.quad.snapshot()))
        timings = self._timings()
        timings.velocity_integrator.apply_to(self.quad)  # the position controller's
        self.machine = FlightModeMachine(
            timings,
            home_ned_m=home,
            ground_down_m=ground,
            mode=sc.start.mode,
            armed=sc.start.airborne,
            kin=kin,
        )
        self._applied_setpoint = None
        # ArduCopter or PX4: modes, heartbeat, commands, setpoints (plant_sim.autopilot.flavours)
        self.flavour = flavour_for(
            config.autopilot_flavour, self.machine, kin, self._home_amsl_m(), self.params
        )
        self.pilot = PilotFlight(  # sticks + proximity avoidance
            self.flavour.pilot_rules,
            drag_per_s=self.quad.params.drag_force_kgps[0] / self.quad.params.mass_kg,
        )
        self._tick_wall_s = time.monotonic()  # the wall time the current tick is due at
        self._apply_machine()
        self.telemetry = TelemetryBuilder(
            VehicleIdentity(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_amsl_m)
        )
        self.scheduler = StreamScheduler(dict(sc.stream_rates_hz), self.quad.time_s)
        self.pacer = Pacer(config.speedup)
        self._tlog: TlogWriter | None = None
        self._truth: TruthLogWriter | None = None
        self.link = MavlinkLink(
            list(config.mavlink),
            signing_key=config.signing_key,
            on_send=self._tlog_write,
            on_receive=self._tlog_write,
            signing_state=config.signing_state,
        )
        self.publisher: StereoPublisher | None = None
        if sc.camera.enabled:
            self.publisher = StereoPublisher(
                config.zenoh, stereo_key(sc.vehicle_id), sc.camera, sc.world
            )
        self._tick = 0
        self._tick_dt_s = 1.0 / config.autopilot_rate_hz
        self._truth_every = max(1, round(config.autopilot_rate_hz / config.truth_rate_hz))
        self._frame = 0
        self._frame_dt_s = 1.0 / sc.camera.rate_hz
        self._inbox: list = []
        self._last_snapshot: VehicleState | None = None
        self._tilt_sat_prev = False
        self._tilt_sat_last_text_s = -math.inf
        self._refusal_last_text: dict[str, float] = {}
        self._text_id = 0  # id of the last chunked STATUSTEXT (1..255)
        self.limiter = RequestLimiter()
        self._param_sends: dict[tuple[int, int], int] = {}  # requester → next index
        self.handler_errors: dict[str, int] = {}
        self.counters = {
            "commands": 0,
            "setpoints": 0,
            "setpoints_refused": 0,
            "foreign": 0,
            "inbox_overflow": 0,
        }
        self._wall_start = time.monotonic()
        self._run_wall_start: float | None = None
        self._run_sim_start = 0.0

    # ---- lifecycle -----------------------------------------------------------------
    def open(self) -> None:
        """Bind sockets, open Zenoh and the logs; compile the JIT kernels."""
        log_dir = self.config.log_dir
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            self._tlog = TlogWriter(log_dir / "plant_sim.tlog")
            self._truth = TruthLogWriter(
                log_dir / "truth.csv",
                self.config.scenario.world,
                self.config.scenario.vehicle.body_radius_m,
            )
        self.link.open()
        if self.config.signing_key is None:
            for spec in self.config.mavlink:
                if spec.kind == "udpin" and spec.host not in ("127.0.0.1", "localhost", "::1"):
                    _log.warning(
                        "MAVLink on %s without signing: anyone who reaches this address can "
                        "command the vehicle (give --signing-key, or bind 127.0.0.1)",
                        spec.url,
                    )
        if self.publisher is not None:
            self.publisher.open()

    def readiness_line(self) -> str:
        """``PLANT_SIM READY mavlink=URL[,URL] zenoh=ENDPOINTS|off key=KEY speedup=N``."""
        return (
            f"PLANT_SIM READY mavlink={','.join(self.link.bound_urls)} "
            f"{readiness_fields(self.publisher)} speedup={self.config.speedup:g}"
        )

    def close(self) -> dict:
        """Close sockets and sessions, flush logs; returns the run's statistics."""
        stats = self.stats()
        if self.publisher is not None:
            self.publisher.close()
        self.link.close()
        if self._truth is not None:
            self._truth.close()
        if self._tlog is not None:
            self._tlog.close()
        return stats

    def stats(self) -> dict:
        now = time.monotonic()
        run_wall = now - (self._run_wall_start if self._run_wall_start is not None else now)
        run_sim = self.quad.time_s - self._run_sim_start
        return {
            "sim_time_s": round(self.quad.time_s, 4),
            "wall_time_s": round(now - self._wall_start, 3),  # including start-up
            "run_wall_time_s": round(run_wall, 3),  # the main loop only
            "real_time_factor": round(run_sim / run_wall, 2) if run_wall > 0 else None,
            "frames_published": self.publisher.sequence if self.publisher else 0,
            "pace_slips": self.pacer.stats.slips,
            "mavlink_sent": self.link.sent_frames,
            "link": self.link.stats.as_dict(),
            "rate_limited": dict(self.limiter.dropped),
            "handler_errors": dict(self.handler_errors),
            "min_clearance_m": None
            if self._truth is None or not math.isfinite(self._truth.min_clearance_m)
            else round(self._truth.min_clearance_m, 4),
            **self.counters,
            **self.pilot.stats(),
        }

    # ---- main loop -----------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool]) -> None:
        """Run until ``should_stop()`` or the configured duration."""
        link, pacer, quad = self.link, self.pacer, self.quad
        now = time.monotonic()
        self._run_wall_start, self._run_sim_start = now, quad.time_s
        pacer.start(now, quad.time_s)
        next_heartbeat = now
        duration = self.config.duration_s
        while not should_stop():
            now = time.monotonic()
            if now >= next_heartbeat:
                link.send(self._heartbeat())
                next_heartbeat += self.config.heartbeat_period_s
                if next_heartbeat < now:
                    next_heartbeat = now + self.config.heartbeat_period_s
            target = pacer.target_sim_s(now, quad.time_s)
            if duration is not None:
                target = min(target, duration)
            budget_end = now + 0.01  # serve the sockets at least every 10 ms of wall time
            while quad.time_s < target - 1e-9:
                quad.run_until(min(self._next_event_s(), target))
                self._events()
                if time.monotonic() > budget_end:
                    break
            if duration is not None and quad.time_s >= duration - 1e-9:
                break
            wake = min(pacer.wall_at(self._next_event_s()), next_heartbeat)
            timeout = min(0.05, max(0.0, wake - time.monotonic()))
            link.wait(timeout)
            self._receive()

    def _next_event_s(self) -> float:
        t = self._tick * self._tick_dt_s
        if self.publisher is not None:
            t = min(t, self._frame * self._frame_dt_s)
        return t

    # ---- events at simulation times ------------------------------------------------
    def _events(self) -> None:
        t = self.quad.time_s
        snap = None
        if t >= self._tick * self._tick_dt_s - 1e-9:
            snap = self.quad.snapshot()
            self._on_tick(snap)
            self._tick += 1
        if self.publisher is not None and t >= self._frame * self._frame_dt_s - 1e-9:
            snap = snap if snap is not None else self.quad.snapshot()
            self.publisher.publish(snap.time_s, snap.pos_ned_m, snap.R_ned_from_frd)
            self._frame += 1

    def _on_tick(self, truth: VehicleState) -> None:
        # the autopilot's view: its estimate of the position (the truth without
        # disturbances); the camera and the truth log see the true vehicle
        snap = self._estimated(truth)
        self._last_snapshot = snap
        # the wall time this tick is due at: a tick run late to catch up after the process
        # was starved is judged as of when it was due, not when it ran, for the wall-time
        # link rules (stick expiry, the proximity timeout). A real autopilot is not
        # starved so; the messages it would have had meanwhile wait in the socket here.
        now = time.monotonic()
        self._tick_wall_s = (
            now if self.pacer.unpaced else min(now, self.pacer.wall_at(truth.time_s))
        )
        kin = self._kinematics(snap)
        inbox, self._inbox = self._inbox, []
        for msg in inbox:
            self._dispatch_safely(msg, kin, snap)
        self._send_param_batch()
        notices = self.machine.update(kin)
        for notice in notices:
            self._statustext(notice, _SEVERITY_INFO)
        for notice in self.flavour.update(kin, notices, self._home_amsl_m()):
            self._statustext(notice, _SEVERITY_WARNING)
        self.pilot.step(
            kin,
            self.machine,
            self.flavour.pilot_main,
            self.params,
            self._tick_wall_s,
            self._tick_dt_s,
        )
        self._apply_machine()
        self._tilt_notice(snap)
        wall_unix = time.time()
        for name in self.scheduler.due(snap.time_s):
            self.link.send(self._build(name, snap, wall_unix))
        if self._truth is not None and self._tick % self._truth_every == 0:
            self._truth.write(truth, self._mode_name())

    def _heartbeat(self):
        return self.flavour.heartbeat(self.telemetry)

    def _home_amsl_m(self) -> float:
        """AMSL altitude of home (PX4's takeoff altitudes are AMSL)."""
        return self.config.scenario.origin.alt_amsl_m - self.machine.home_ned_m[2]

    def _mode_name(self) -> str:
        return self.flavour.mode_name()

    def _build(self, name: str, snap: VehicleState, wall_unix: float):
        return self.telemetry.build(
            name,
            snap,
            self.machine,
            wall_unix_s=wall_unix,
            comm_errors=self.link.stats.dropped,
            signing_refused=self.link.stats.signing_refused,
            accuracy_m=(0.0, 0.0)
            if self.disturbances is None
            else self.disturbances.stated_accuracy_m,
        )

    def _tilt_notice(self, snap: VehicleState) -> None:
        sat = snap.tilt_saturated
        if sat and not self._tilt_sat_prev and snap.time_s - self._tilt_sat_last_text_s >= 1.0:
            self._tilt_sat_last_text_s = snap.time_s
            limit = self.config.scenario.control.max_tilt_deg
            self._statustext(f"Tilt limit {limit:g} deg saturated", _SEVERITY_INFO)
        self._tilt_sat_prev = sat

    # ---- helpers -------------------------------------------------------------------
    @staticmethod
    def _kinematics(snap: VehicleState) -> Kinematics:
        return Kinematics.of(snap)

    def _timings(self) -> ModeTimings:
        """The mode logic's timings from the parameters, as the flavour flies them
        (:meth:`~plant_sim.autopilot.flavours.AutopilotFlavour.timings`)."""
        base = timings_from_params(self._base_timings, self.params)
        return flavour_class(self.config.autopilot_flavour).timings(base)

    def _estimated(self, truth: VehicleState) -> VehicleState:
        """The vehicle as the autopilot's estimator has it: the truth moved by the
        estimate error, and the wind of this moment put on the physics."""
        d = self.disturbances
        if d is None:
            return truth
        d.advance(truth.time_s)
        self.quad.set_wind_ned_mps(d.wind_ned_mps)
        error = np.asarray(d.estimate_error_ned_m)
        return dataclasses.replace(truth, pos_ned_m=truth.pos_ned_m + error)

    def _apply_machine(self) -> None:
        m = self.machine
        if m.armed != self.quad.armed:
            self.quad.set_armed(m.armed)
        setpoint = m.setpoint
        if self.pilot.setpoint is not None and self.pilot.pilot_mode(m, self.flavour.pilot_main):
            setpoint = self.pilot.setpoint  # the pilot flies (LOITER / Position mode)
        if self.disturbances is not None:
            # the controller closes its loop on the estimate: tracking a target with the
            # estimate is tracking target − error with the truth
            self.quad.set_setpoint(_shifted(setpoint, self.disturbances.estimate_error_ned_m))
        elif setpoint is not self._applied_setpoint:
            self.quad.set_setpoint(setpoint)
            self._applied_setpoint = setpoint

    def _tlog_write(self, frame: bytes) -> None:
        if self._tlog is not None:
            self._tlog.write(frame)

    def _statustext(self, text: str, severity: int = _SEVERITY_WARNING) -> None:
        """STATUSTEXT; longer than 50 characters: MAVLink 2 chunks (id, chunk_seq)."""
        _log.info("STATUSTEXT: %s", text)
        if len(text) > 50:
            self._text_id = self._text_id % 255 + 1
        for text_id, seq, chunk in statustext_chunks(text, self._text_id or 1):
            self.link.send(mavlink.MAVLink_statustext_message(severity, chunk, text_id, seq))

    def _refusal(self, key: str, text: str, sim_s: float) -> None:
        """STATUSTEXT for a repeated refusal at most once per second of simulation time."""
        if sim_s - self._refusal_last_text.get(key, -math.inf) >= 1.0:
            self._refusal_last_text[key] = sim_s
            self._statustext(text)
        else:
            _log.debug("refused (%s): %s", key, text)


def stats_line(stats: dict) -> str:
    """``PLANT_SIM STATS {json}`` printed at exit."""
    return "PLANT_SIM STATS " + json.dumps(stats, sort_keys=True)
