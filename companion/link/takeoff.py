"""Arm and take off before steering (``--takeoff-alt``): a small, bounded state machine.

Pure: inputs are telemetry and COMMAND_ACKs with the caller's clocks, outputs are
:class:`TakeoffCommand`, :class:`TakeoffNotice` and :class:`TakeoffEvent` actions the
service carries out (:meth:`TakeoffSequence.pop_actions`). Steps::

    PROBE ─┬─ airborne ─────────────────────────────────────────────▶ SKIPPED
           └─ on the ground ─▶ [SET_MODE GUIDED] ─▶ [ARM] ─▶ TAKEOFF ─▶ CLIMB ─▶ DONE
                                   (any step) ── refused / no answer / timeout ──▶ FAILED

* PROBE: on the ground if EXTENDED_SYS_STATE says ON_GROUND or the HEARTBEAT says
  disarmed; airborne if armed and landed_state is IN_AIR / TAKEOFF / LANDING, or armed
  with no landed state within ``probe_timeout_s`` (wall).
* On the ground it waits, like a pilot, until the vehicle is ready and it can see: a local
  position (ArduPilot sends LOCAL_POSITION_NED only once its EKF has an origin and uses
  GPS, ~40 s after boot on SITL), PX4's home altitude, the autopilot's pre-arm checks
  passing (SYS_STATUS ``MAV_SYS_STATUS_PREARM_CHECK``, when it reports them) and camera
  frames (it never takes off blind). What it waits for is said every
  ``progress_period_s`` (STATUSTEXT and event); after ``ready_timeout_s`` (wall) it gives
  up (FAILED) naming what is missing.
* ArduPilot (and GENERIC): DO_SET_MODE GUIDED (unless already), COMPONENT_ARM_DISARM
  param1 = 1 (unless already armed), NAV_TAKEOFF param7 = altitude above home [m].
* PX4: arm, then NAV_TAKEOFF. PX4 reads a COMMAND_LONG's param7 as an AMSL altitude (NaN
  would mean MIS_TAKEOFF_ALT), so param7 = home AMSL (HOME_POSITION or
  GLOBAL_POSITION_INT alt − relative_alt) + altitude. PX4 holds (AUTO_LOITER) at the top;
  OFFBOARD is engaged afterwards by :class:`~companion.link.mode_watch.ModeWatch` with its
  usual setpoint pre-stream.
* CLIMB: done when the height above the position at the takeoff command is within
  ``tolerance_m`` of the altitude; bounded in autopilot time (``climb_timeout_s``) and,
  as a backstop, in wall time.

COMMAND_ACK rules, per step (one COMMAND_LONG per attempt, ``confirmation`` = attempt − 1):
ACCEPTED completes the step; IN_PROGRESS extends the wait for the final ACK to
``in_progress_timeout_s`` without resending; TEMPORARILY_REJECTED is retried after
``refusal_retry_s``; DENIED and FAILED are retried after ``refusal_retry_s`` up to
``max_refusals`` answers in all (pre-arm checks may still be settling), then FAILED with
the autopilot's last STATUSTEXT; UNSUPPORTED, CANCELLED or an unknown result fail at once.
No ACK within ``ack_timeout_s`` (wall) → resend, at most ``max_attempts`` sends. Telemetry
that shows the step done (mode GUIDED, armed, climbing) completes it without an ACK, so a
lost ACK followed by a refused retransmission ("already flying") is not an error.
"""

from __future__ import annotations

import enum
import math
from dataclasses import MISSING, dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.flavour import (
    Flavour,
    ModeRequest,
    mode_name,
    profile_for,
    same_mode,
)
from protocols.config import ConfigError, bounded, check_fields

__all__ = [
    "TakeoffCommand",
    "TakeoffEvent",
    "TakeoffNotice",
    "TakeoffSequence",
    "TakeoffSettings",
    "TakeoffStep",
]

_M = mavlink
_ON_GROUND = _M.MAV_LANDED_STATE_ON_GROUND
_AIRBORNE = (_M.MAV_LANDED_STATE_IN_AIR, _M.MAV_LANDED_STATE_TAKEOFF, _M.MAV_LANDED_STATE_LANDING)
_MAV_RESULT_IN_PROGRESS = 5
_MAV_RESULT_CANCELLED = 6


class TakeoffStep(enum.Enum):
    """Where the sequence is."""

    PROBE = "probe"  # finding out whether the vehicle is on the ground
    SET_MODE = "set_mode"  # ArduPilot: DO_SET_MODE GUIDED
    ARM = "arm"  # COMPONENT_ARM_DISARM param1 = 1
    TAKEOFF = "takeoff"  # NAV_TAKEOFF sent, waiting for the ACK
    CLIMB = "climb"  # accepted, waiting for the altitude
    DONE = "done"  # at altitude: steering may start
    SKIPPED = "skipped"  # already airborne: steering may start
    FAILED = "failed"  # terminal: the autopilot refused or did not answer

    @property
    def finished(self) -> bool:
        return self in (TakeoffStep.DONE, TakeoffStep.SKIPPED, TakeoffStep.FAILED)


@dataclass(frozen=True)
class TakeoffSettings:
    """Bounds of the sequence (times in wall seconds unless noted)."""

    alt_m: float = bounded(MISSING, "m", gt=0)  # takeoff height above the ground position
    tolerance_m: float = bounded(0.5, "m", gt=0)  # climb done within this of alt_m
    # [s autopilot time]; 0: alt_m / 0.5 m/s + 15 s
    climb_timeout_s: float = bounded(0.0, "s", ge=0)
    climb_timeout_wall_s: float = bounded(300.0, "s", gt=0)  # if autopilot time stops advancing
    ack_timeout_s: float = bounded(1.5, "s", gt=0)  # per attempt, no ACK → resend
    max_attempts: int = bounded(4, integer=True, ge=1)  # sends per step
    max_refusals: int = bounded(3, integer=True, ge=1)  # DENIED / FAILED answers per step
    refusal_retry_s: float = bounded(2.0, "s", ge=0)  # pause after a refusal
    in_progress_timeout_s: float = bounded(10.0, "s", gt=0)  # IN_PROGRESS: wait for final ACK
    probe_timeout_s: float = bounded(3.0, "s", gt=0)  # armed, no landed state this long → airborne
    # on the ground: wait this long for position/frames/pre-arm
    ready_timeout_s: float = bounded(180.0, "s", gt=0)
    progress_period_s: float = bounded(5.0, "s", gt=0)  # say what it waits for this often
    require_frames: bool = True  # never take off without camera frames
    grace_s: float = bounded(2.5, "s", ge=0)  # heartbeats this soon after an ACK may predate it

    def __post_init__(self) -> None:
        check_fields(self)
        if self.tolerance_m >= self.alt_m:
            raise ConfigError(
                f"must be < alt_m ({self.alt_m!r}), got {self.tolerance_m!r}", key="tolerance_m"
            )

    @property
    def climb_limit_s(self) -> float:
        if self.climb_timeout_s > 0:
            return self.climb_timeout_s
        return self.alt_m / 0.5 + 15.0


@dataclass(frozen=True)
class TakeoffCommand:
    """A COMMAND_LONG to send (params 1..7)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    confirmation: int
    name: str


@dataclass(frozen=True)
class TakeoffNotice:
    """A STATUSTEXT (and log line) for the ground station."""

    text: str
    severity: int = _M.MAV_SEVERITY_INFO


@dataclass(frozen=True)
class TakeoffEvent:
    """A ``COMPANION EVENT takeoff`` line."""

    fields: dict = field(default_factory=dict)


TakeoffAction = TakeoffCommand | TakeoffNotice | TakeoffEvent


def _result_name(result: int) -> str:
    entry = _M.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry else f"RESULT_{result}"


def _params(*values: float) -> tuple[float, float, float, float, float, float, float]:
    p = [float(v) for v in values] + [0.0] * (7 - len(values))
    return tuple(p)  # type: ignore[return-value]


class TakeoffSequence:
    """Probe, (GUIDED), arm, take off and climb; see the module docstring.

    Parameters
    ----------
    flavour : Flavour
        From the first autopilot HEARTBEAT.
    settings : TakeoffSettings
    now_s : float
        Wall time of the start (the probe's clock).
    """

    def __init__(self, flavour: Flavour, settings: TakeoffSettings, now_s: float) -> None:
        self.flavour = flavour
        self.settings = settings
        self.step = TakeoffStep.PROBE
        self.reason: str | None = None  # why FAILED / SKIPPED
        self._actions: list[TakeoffAction] = []
        self._start_s = now_s
        self.profile = profile_for(flavour)
        self._guided: ModeRequest | None = self.profile.takeoff_mode
        # telemetry
        self.armed: bool | None = None
        self.custom_mode: int | None = None
        self.landed_state: int | None = None
        self.home_amsl_m: float | None = None
        self.down_m: float | None = None  # newest LOCAL_POSITION_NED z [m]
        self._autopilot_s: float | None = None
        self._last_statustext = ""
        self.frames = 0  # camera frames seen since the start
        self.prearm_ok: bool | None = None  # None: the autopilot does not report it
        self._next_wait_notice_s = now_s + settings.progress_period_s
        # current command step
        self._attempts = 0
        self._refusals = 0
        self._deadline_s = math.inf  # resend (or give up) at this wall time
        self._acked_s = -math.inf  # wall time of the step's last ACCEPTED
        self._in_progress_reported = False
        # climb
        self._ref_down_m: float | None = None
        self._climb_wall_s = math.inf
        self._climb_ap0_s: float | None = None
        self._takeoff_sent_s = math.inf
        self.climb_wall_s: float | None = None  # wall seconds from the command to altitude
        self.climb_autopilot_s: float | None = None  # autopilot seconds, same span
        self._event(step=self.step.value, alt_m=settings.alt_m, flavour=flavour.value)
        kinds = [_M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE]
        if self.profile.takeoff_alt_amsl:
            kinds.append(_M.MAVLINK_MSG_ID_HOME_POSITION)
        for msg_id in kinds:  # fire and forget: the stream usually has them anyway
            self._actions.append(
                TakeoffCommand(_M.MAV_CMD_REQUEST_MESSAGE, _params(msg_id), 0, "REQUEST_MESSAGE")
            )

    # ---- queries ------------------------------------------------------------------
    @property
    def finished(self) -> bool:
        return self.step.finished

    @property
    def busy(self) -> bool:
        """Steering must wait."""
        return not self.step.finished

    @property
    def height_m(self) -> float | None:
        """Height above the position at the takeoff command [m]."""
        if self._ref_down_m is None or self.down_m is None:
            return None
        return self._ref_down_m - self.down_m

    def pop_actions(self) -> list[TakeoffAction]:
        out, self._actions = self._actions, []
        return out

    # ---- inputs -------------------------------------------------------------------
    def on_heartbeat(self, now_s: float, custom_mode: int, armed: bool) -> None:
        self.custom_mode = custom_mode
        self.armed = armed
        self._advance(now_s)

    def on_landed_state(self, now_s: float, landed_state: int) -> None:
        """EXTENDED_SYS_STATE.landed_state (MAV_LANDED_STATE; 0 = undefined is ignored)."""
        if landed_state:
            self.landed_state = landed_state
        self._advance(now_s)

    def on_home_amsl(self, alt_amsl_m: float) -> None:
        """Home altitude AMSL [m] (PX4's NAV_TAKEOFF param7 is AMSL)."""
        if math.isfinite(alt_amsl_m):
            self.home_amsl_m = alt_amsl_m

    def on_position(self, now_s: float, autopilot_s: float, down_m: float) -> None:
        """LOCAL_POSITION_NED: ``autopilot_s`` = time_boot_ms / 1000, ``down_m`` = z."""
        self.down_m = down_m
        self._autopilot_s = autopilot_s
        self._advance(now_s)

    def on_frame(self, now_s: float) -> None:
        """A camera frame arrived (the companion can see)."""
        self.frames += 1
        self._advance(now_s)

    def on_sys_status(self, now_s: float, present: int, health: int) -> None:
        """SYS_STATUS sensor bits: pre-arm checks passing, if the autopilot reports them."""
        bit = _M.MAV_SYS_STATUS_PREARM_CHECK
        self.prearm_ok = bool(health & bit) if present & bit else None
        self._advance(now_s)

    def on_statustext(self, text: str) -> None:
        """Autopilot STATUSTEXT; the newest is quoted in a refusal (e.g. a PreArm check)."""
        self._last_statustext = text.strip()

    def on_ack(self, now_s: float, command: int, result: int) -> None:
        """COMMAND_ACK for ``command``; ACKs of other commands are ignored."""
        cmd = self._current_command()
        if cmd is None or command != cmd.command:
            return
        name = cmd.name
        if result == _M.MAV_RESULT_ACCEPTED:
            self._acked_s = now_s
            self._step_done(now_s, f"{name} accepted")
        elif result == _MAV_RESULT_IN_PROGRESS:
            self._deadline_s = now_s + self.settings.in_progress_timeout_s
            if not self._in_progress_reported:
                self._in_progress_reported = True
                self._notice(f"Takeoff: {name} in progress")
        elif result == _M.MAV_RESULT_TEMPORARILY_REJECTED:
            self._notice(f"Takeoff: {name} temporarily rejected, retrying", _M.MAV_SEVERITY_WARNING)
            self._deadline_s = now_s + self.settings.refusal_retry_s
        elif result in (_M.MAV_RESULT_DENIED, _M.MAV_RESULT_FAILED):
            if self._confirmed(now_s):  # e.g. a retransmitted takeoff: "already flying"
                self._step_done(now_s, f"{name} already done")
                return
            self._refusals += 1
            why = f"{name} refused ({_result_name(result)}"
            why += f": {self._last_statustext})" if self._last_statustext else ")"
            if self._refusals >= self.settings.max_refusals:
                self._fail(f"{why}, {self._refusals} time(s)")
                return
            self._notice(
                f"Takeoff: {why}; retry {self._refusals}/{self.settings.max_refusals - 1}",
                _M.MAV_SEVERITY_WARNING,
            )
            self._deadline_s = now_s + self.settings.refusal_retry_s
        else:  # UNSUPPORTED, CANCELLED, unknown: retrying will not help
            self._fail(f"{name} refused ({_result_name(result)})")

    def tick(self, now_s: float) -> None:
        """Timeouts (wall time); call often."""
        self._advance(now_s)
        if self.step in (TakeoffStep.SET_MODE, TakeoffStep.ARM, TakeoffStep.TAKEOFF):
            if now_s >= self._deadline_s:
                self._send(now_s)
        elif self.step is TakeoffStep.CLIMB and now_s >= self._climb_wall_s:
            self._fail(
                f"climb not complete after {self.settings.climb_timeout_wall_s:.0f} s "
                f"(wall) at {_fmt(self.height_m)} m of {self.settings.alt_m:.1f} m"
            )

    # ---- internals ----------------------------------------------------------------
    def _advance(self, now_s: float) -> None:
        step = self.step
        if step is TakeoffStep.PROBE:
            self._probe(now_s)
        elif step in (TakeoffStep.SET_MODE, TakeoffStep.ARM, TakeoffStep.TAKEOFF):
            if self._lost_authority(now_s):
                return
            if self._confirmed(now_s):
                self._step_done(now_s, "confirmed by telemetry")
        elif step is TakeoffStep.CLIMB:
            self._climb(now_s)

    def _probe(self, now_s: float) -> None:
        if self.armed is None:
            return
        waited = now_s - self._start_s
        on_ground = self.landed_state == _ON_GROUND or not self.armed
        if not on_ground:
            if self.landed_state in _AIRBORNE:
                state = _M.enums["MAV_LANDED_STATE"][self.landed_state].name
                self._skip(f"already airborne ({state.removeprefix('MAV_LANDED_STATE_')})")
            elif waited >= self.settings.probe_timeout_s:
                self._skip("armed and no landed state: assuming airborne")
            return
        missing = self.missing()
        if missing:
            if waited >= self.settings.ready_timeout_s:
                self._fail(f"on the ground but no {', '.join(missing)} after {waited:.0f} s")
            elif now_s >= self._next_wait_notice_s:
                self._next_wait_notice_s = now_s + self.settings.progress_period_s
                self._notice(f"Takeoff waits for {', '.join(missing)} ({waited:.0f} s)")
                self._event(step="wait", waiting=missing, waited_s=round(waited, 1))
            return
        self._notice(
            f"Takeoff to {self.settings.alt_m:.1f} m: on the ground, "
            f"{'armed' if self.armed else 'disarmed'}"
        )
        if self._guided is not None and not same_mode(
            self.flavour, self.custom_mode or 0, self._guided
        ):
            self._enter(TakeoffStep.SET_MODE, now_s)
        elif not self.armed:
            self._enter(TakeoffStep.ARM, now_s)
        else:
            self._enter(TakeoffStep.TAKEOFF, now_s)

    def missing(self) -> list[str]:
        """What the vehicle on the ground still lacks before the takeoff (short names)."""
        out = []
        if self.down_m is None:
            out.append("position (EKF origin/GPS)")
        if self.profile.takeoff_alt_amsl and self.home_amsl_m is None:
            out.append("home altitude")
        if self.prearm_ok is False and not self.armed:
            out.append("pre-arm checks")
        if self.settings.require_frames and self.frames == 0:
            out.append("camera frames")
        return out

    def _current_command(self) -> TakeoffCommand | None:
        step = self.step
        if step is TakeoffStep.SET_MODE and self._guided is not None:
            mode = self._guided
            return TakeoffCommand(
                _M.MAV_CMD_DO_SET_MODE,
                _params(mode.base_mode, mode.custom_mode),
                self._attempts - 1,
                f"mode {mode.name}",
            )
        if step is TakeoffStep.ARM:
            return TakeoffCommand(
                _M.MAV_CMD_COMPONENT_ARM_DISARM, _params(1.0), self._attempts - 1, "ARM"
            )
        if step is TakeoffStep.TAKEOFF:
            alt = self.settings.alt_m
            if self.profile.takeoff_alt_amsl:
                assert self.home_amsl_m is not None
                alt = self.home_amsl_m + alt
            p = _params(0.0, 0.0, 0.0, math.nan, math.nan, math.nan, alt)
            return TakeoffCommand(_M.MAV_CMD_NAV_TAKEOFF, p, self._attempts - 1, "TAKEOFF")
        return None

    def _confirmed(self, now_s: float) -> bool:
        """Telemetry shows the current step's effect (a lost ACK is then harmless)."""
        step = self.step
        fresh = now_s - self._acked_s > self.settings.grace_s
        if step is TakeoffStep.SET_MODE:
            return self._guided is not None and same_mode(
                self.flavour, self.custom_mode or 0, self._guided
            )
        if step is TakeoffStep.ARM:
            return bool(self.armed)
        if step is TakeoffStep.TAKEOFF:
            h = self.height_m
            return (h is not None and h > self.settings.tolerance_m) or (
                fresh and self.landed_state in _AIRBORNE and self._attempts > 0
            )
        return False

    def _lost_authority(self, now_s: float) -> bool:
        """Someone else changed the mode or disarmed the vehicle under us."""
        if now_s - self._acked_s <= self.settings.grace_s:
            return False
        past_mode = self.step in (TakeoffStep.ARM, TakeoffStep.TAKEOFF, TakeoffStep.CLIMB)
        if (
            past_mode
            and self._guided is not None
            and self.custom_mode is not None
            and not same_mode(self.flavour, self.custom_mode, self._guided)
        ):
            self._fail(
                f"mode changed to {mode_name(self.flavour, self.custom_mode)} during takeoff: "
                "stopped, the pilot is in control"
            )
            return True
        past_arm = self.step in (TakeoffStep.TAKEOFF, TakeoffStep.CLIMB)
        if past_arm and self.armed is False:
            self._fail("vehicle disarmed during takeoff")
            return True
        return False

    def _step_done(self, now_s: float, how: str) -> None:
        step = self.step
        if step is TakeoffStep.SET_MODE:
            self._enter(TakeoffStep.TAKEOFF if self.armed else TakeoffStep.ARM, now_s, how)
        elif step is TakeoffStep.ARM:
            self._enter(TakeoffStep.TAKEOFF, now_s, how)
        elif step is TakeoffStep.TAKEOFF:
            self._enter(TakeoffStep.CLIMB, now_s, how)

    def _enter(self, step: TakeoffStep, now_s: float, how: str | None = None) -> None:
        self.step = step
        self._attempts = 0
        self._refusals = 0
        self._in_progress_reported = False
        self._deadline_s = now_s  # send at once
        fields: dict = {"step": step.value}
        if how:
            fields["after"] = how
        if step is TakeoffStep.TAKEOFF:
            self._ref_down_m = self.down_m
        if step is TakeoffStep.CLIMB:
            self._deadline_s = math.inf
            self._climb_wall_s = now_s + self.settings.climb_timeout_wall_s
            self._climb_ap0_s = self._autopilot_s
            fields["from_down_m"] = self._ref_down_m
        self._event(**fields)
        if step in (TakeoffStep.SET_MODE, TakeoffStep.ARM, TakeoffStep.TAKEOFF):
            self._send(now_s)
        elif step is TakeoffStep.CLIMB:
            self._climb(now_s)

    def _send(self, now_s: float) -> None:
        if self._attempts >= self.settings.max_attempts:
            name = self._current_command()
            what = name.name if name else self.step.value
            self._fail(
                f"no accepting COMMAND_ACK for {what} after {self._attempts} attempt(s) "
                f"({self.settings.ack_timeout_s:g} s each)"
            )
            return
        self._attempts += 1
        cmd = self._current_command()
        assert cmd is not None
        if cmd.command == _M.MAV_CMD_NAV_TAKEOFF and self._attempts == 1:
            self._takeoff_sent_s = now_s
        self._deadline_s = now_s + self.settings.ack_timeout_s
        self._actions.append(cmd)

    def _climb(self, now_s: float) -> None:
        if self._lost_authority(now_s):
            return
        h = self.height_m
        ap = self._autopilot_s
        if self._climb_ap0_s is None:
            self._climb_ap0_s = ap
        if h is not None and abs(h - self.settings.alt_m) <= self.settings.tolerance_m:
            self.climb_wall_s = now_s - self._takeoff_sent_s
            if ap is not None and self._climb_ap0_s is not None:
                self.climb_autopilot_s = ap - self._climb_ap0_s
            self.step = TakeoffStep.DONE
            self._notice(f"Takeoff complete at {h:.1f} m")
            self._event(
                step=self.step.value,
                height_m=round(h, 3),
                climb_autopilot_s=_round(self.climb_autopilot_s),
                climb_wall_s=_round(self.climb_wall_s),
            )
            return
        t0 = self._climb_ap0_s
        if ap is not None and t0 is not None and ap - t0 > self.settings.climb_limit_s:
            self._fail(
                f"climb not complete after {self.settings.climb_limit_s:.0f} s "
                f"(autopilot time) at {_fmt(h)} m of {self.settings.alt_m:.1f} m"
            )

    def _skip(self, why: str) -> None:
        self.step = TakeoffStep.SKIPPED
        self.reason = why
        self._notice(f"Takeoff skipped: {why}")
        self._event(step=self.step.value, reason=why)

    def _fail(self, why: str) -> None:
        self.step = TakeoffStep.FAILED
        self.reason = why
        self._notice(f"Takeoff failed: {why}", _M.MAV_SEVERITY_CRITICAL)
        self._event(step=self.step.value, reason=why)

    def _notice(self, text: str, severity: int = _M.MAV_SEVERITY_INFO) -> None:
        self._actions.append(TakeoffNotice(text, severity))

    def _event(self, **fields) -> None:
        self._actions.append(TakeoffEvent(fields))


def _fmt(value: float | None) -> str:
    return "?" if value is None else f"{value:.1f}"


def _round(value: float | None) -> float | None:
    return None if value is None else round(value, 3)
