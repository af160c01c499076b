"""``--takeoff-alt``: the takeoff state machine against a scripted fake autopilot, and the
paper's flight from the ground with real processes (plant-sim ``--start-on-ground``).

The fake autopilot answers each COMMAND_LONG from a script of results per command (``None``
= the ACK is lost), sends HEARTBEAT (mode, armed), EXTENDED_SYS_STATE and
LOCAL_POSITION_NED, and climbs at ``climb_mps`` after an accepted NAV_TAKEOFF. Wall time and
autopilot time advance together in steps of ``DT`` (``speedup`` × for autopilot time).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.config import ConfigError, LinkConfig, build_parser, config_from_args
from companion.link.flavour import ARDUCOPTER_GUIDED, Flavour, px4_custom_mode
from companion.link.takeoff import (
    TakeoffCommand,
    TakeoffEvent,
    TakeoffNotice,
    TakeoffSequence,
    TakeoffSettings,
    TakeoffStep,
)

M = mavlink
DT = 0.05  # wall seconds per step
LOITER = 5
PX4_HOLD = px4_custom_mode(4, 3)  # AUTO_LOITER
ACCEPTED = M.MAV_RESULT_ACCEPTED
FAILED = M.MAV_RESULT_FAILED
DENIED = M.MAV_RESULT_DENIED
UNSUPPORTED = M.MAV_RESULT_UNSUPPORTED
TEMP = M.MAV_RESULT_TEMPORARILY_REJECTED
IN_PROGRESS = 5
ARM, TAKEOFF, SET_MODE = 400, 22, 176


class FakeAutopilot:
    """A scripted autopilot (see the module docstring)."""

    def __init__(
        self,
        *,
        flavour: Flavour = Flavour.ARDUPILOT,
        mode: int = LOITER,
        armed: bool = False,
        landed_state: int | None = M.MAV_LANDED_STATE_ON_GROUND,
        script: dict[int, list] | None = None,
        climb_mps: float = 1.5,
        speedup: float = 4.0,
        home_amsl_m: float = 488.0,
        texts: dict[int, str] | None = None,
        camera: bool = True,
        position_after_s: float = 0.0,
        prearm_after_s: float | None = None,
    ) -> None:
        self.flavour = flavour
        self.mode = mode
        self.armed = armed
        self.landed_state = landed_state
        self.script = defaultdict(list, {k: list(v) for k, v in (script or {}).items()})
        self.climb_mps = climb_mps
        self.speedup = speedup
        self.home_amsl_m = home_amsl_m
        self.texts = texts or {}
        self.down_m = 0.0
        self.target_down_m: float | None = None
        self.ap_s = 0.0
        self.sent: list[TakeoffCommand] = []  # what the companion sent (not REQUEST_MESSAGE)
        self.notices: list[TakeoffNotice] = []
        self.events: list[dict] = []
        self.pending: list[tuple[float, int, int]] = []  # (deliver at wall s, cmd, result)
        self.ack_delay_s = 0.02
        self.freeze_autopilot_time = False
        self.camera = camera  # frames arrive
        self.position_after_s = position_after_s  # no LOCAL_POSITION_NED before (EKF origin)
        self.prearm_after_s = prearm_after_s  # SYS_STATUS pre-arm bit healthy from (None: n/a)

    def _execute(self, cmd: TakeoffCommand) -> int:
        """Default behaviour of an ArduCopter-like autopilot."""
        if cmd.command == SET_MODE:
            self.mode = round(cmd.params[1])
            return ACCEPTED
        if cmd.command == ARM:
            self.armed = True
            return ACCEPTED
        if cmd.command == TAKEOFF:
            if not self.armed or self.landed_state not in (None, M.MAV_LANDED_STATE_ON_GROUND):
                return FAILED
            alt = cmd.params[6]
            if self.flavour is Flavour.PX4:
                alt -= self.home_amsl_m
            self.target_down_m = self.down_m - alt
            self.landed_state = M.MAV_LANDED_STATE_TAKEOFF
            return ACCEPTED
        return UNSUPPORTED

    def handle(self, seq: TakeoffSequence, now_s: float) -> None:
        for action in seq.pop_actions():
            if isinstance(action, TakeoffNotice):
                self.notices.append(action)
            elif isinstance(action, TakeoffEvent):
                self.events.append(action.fields)
            elif action.command != M.MAV_CMD_REQUEST_MESSAGE:
                self.sent.append(action)
                scripted = self.script[action.command]
                result = scripted.pop(0) if scripted else "do"
                if result in ("do", "lost"):  # executed; "lost": the ACK goes missing
                    ack = self._execute(action)
                    if result == "do":
                        self.pending.append((now_s + self.ack_delay_s, action.command, ack))
                elif result is not None:
                    if result in self.texts:
                        seq.on_statustext(self.texts[result])
                    self.pending.append((now_s + self.ack_delay_s, action.command, result))

    def step(self, seq: TakeoffSequence, now_s: float) -> None:
        if not self.freeze_autopilot_time:
            self.ap_s += DT * self.speedup
            if self.target_down_m is not None and self.armed:
                self.down_m = max(
                    self.target_down_m, self.down_m - self.climb_mps * DT * self.speedup
                )
                if self.down_m < -0.3:
                    self.landed_state = M.MAV_LANDED_STATE_TAKEOFF
                if self.down_m == self.target_down_m:
                    self.landed_state = M.MAV_LANDED_STATE_IN_AIR
        for item in [p for p in self.pending if p[0] <= now_s]:
            self.pending.remove(item)
            seq.on_ack(now_s, item[1], item[2])
        if round(now_s / DT) % 20 == 0:  # 1 Hz
            seq.on_heartbeat(now_s, self.mode, self.armed)
            if self.landed_state is not None:
                seq.on_landed_state(now_s, self.landed_state)
            seq.on_home_amsl(self.home_amsl_m)
            if self.prearm_after_s is not None:
                bit = M.MAV_SYS_STATUS_PREARM_CHECK
                seq.on_sys_status(now_s, bit, bit if now_s >= self.prearm_after_s else 0)
        if not self.freeze_autopilot_time and now_s >= self.position_after_s:
            seq.on_position(now_s, self.ap_s, self.down_m)
        if self.camera:
            seq.on_frame(now_s)
        seq.tick(now_s)
        self.handle(seq, now_s)


def fly(fake: FakeAutopilot, limit_s: float = 400.0, **settings) -> TakeoffSequence:
    settings.setdefault("alt_m", 7.0)
    seq = TakeoffSequence(fake.flavour, TakeoffSettings(**settings), 0.0)
    fake.handle(seq, 0.0)
    seq.on_heartbeat(0.0, fake.mode, fake.armed)  # the heartbeat that created it
    fake.handle(seq, 0.0)
    t = 0.0
    while not seq.finished and t < limit_s:
        t += DT
        fake.step(seq, t)
    assert seq.finished, (seq.step, fake.sent)
    fake.end_s = t
    return seq


def commands(fake: FakeAutopilot) -> list[tuple[int, int]]:
    return [(c.command, c.confirmation) for c in fake.sent]


def steps(fake: FakeAutopilot) -> list[str]:
    return [e["step"] for e in fake.events]


# ---- ArduPilot -------------------------------------------------------------------------


def test_ardupilot_from_loiter_on_ground_guided_arm_takeoff_climb():
    fake = FakeAutopilot(mode=LOITER)
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    assert commands(fake) == [(SET_MODE, 0), (ARM, 0), (TAKEOFF, 0)]
    mode_cmd, arm_cmd, takeoff_cmd = fake.sent
    assert mode_cmd.params[:2] == (1.0, float(ARDUCOPTER_GUIDED))  # custom mode GUIDED
    assert arm_cmd.params[0] == 1.0
    assert takeoff_cmd.params[6] == 7.0  # ArduCopter: metres above home
    assert steps(fake) == ["probe", "set_mode", "arm", "takeoff", "climb", "done"]
    assert abs(seq.height_m - 7.0) <= 0.5
    # 7 m at 1.5 m/s: about 4.3 s of autopilot time (within the 0.5 m tolerance earlier)
    assert 3.5 <= seq.climb_autopilot_s <= 4.7, seq.climb_autopilot_s
    assert any("Takeoff complete" in n.text for n in fake.notices)


def test_ardupilot_already_guided_and_disarmed_skips_the_mode_request():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED)
    fly(fake)
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0)]


def test_armed_on_the_ground_only_takes_off():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, armed=True)
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    assert commands(fake) == [(TAKEOFF, 0)]


@pytest.mark.parametrize("state", [M.MAV_LANDED_STATE_IN_AIR, M.MAV_LANDED_STATE_TAKEOFF])
def test_airborne_vehicle_skips_takeoff_and_says_so(state):
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, armed=True, landed_state=state)
    seq = fly(fake)
    assert seq.step is TakeoffStep.SKIPPED and fake.sent == []
    assert "already airborne" in seq.reason
    assert any(n.text.startswith("Takeoff skipped: already airborne") for n in fake.notices)


def test_armed_without_landed_state_is_assumed_airborne_after_the_probe_timeout():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, armed=True, landed_state=None)
    seq = fly(fake)
    assert seq.step is TakeoffStep.SKIPPED and fake.sent == []
    assert "assuming airborne" in seq.reason
    assert fake.end_s == pytest.approx(3.0, abs=2 * DT)


def test_disarmed_without_landed_state_is_on_the_ground():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, landed_state=None)
    assert fly(fake).step is TakeoffStep.DONE


# ---- refusals ------------------------------------------------------------------------


def test_prearm_failure_is_retried_then_a_clear_terminal_error():
    text = "PreArm: Gyros not calibrated"
    fake = FakeAutopilot(
        mode=ARDUCOPTER_GUIDED, script={ARM: [FAILED, FAILED, FAILED]}, texts={FAILED: text}
    )
    seq = fly(fake)
    assert seq.step is TakeoffStep.FAILED
    assert commands(fake) == [(ARM, 0), (ARM, 1), (ARM, 2)]  # max_refusals = 3
    assert "ARM refused (FAILED: PreArm: Gyros not calibrated)" in seq.reason
    assert fake.end_s == pytest.approx(2 * 2.0 + 3 * DT, abs=0.3)  # two 2 s pauses
    final = fake.notices[-1]
    assert final.text.startswith("Takeoff failed: ARM refused")
    assert final.severity == M.MAV_SEVERITY_CRITICAL
    assert steps(fake)[-1] == "failed"
    retries = [n for n in fake.notices if "retry" in n.text]
    assert [n.severity for n in retries] == [M.MAV_SEVERITY_WARNING] * 2


def test_one_denial_then_accepted_continues():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={ARM: [DENIED]})
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    assert commands(fake) == [(ARM, 0), (ARM, 1), (TAKEOFF, 0)]


def test_unsupported_fails_at_once():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={TAKEOFF: [UNSUPPORTED]})
    seq = fly(fake)
    assert seq.step is TakeoffStep.FAILED
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0)]
    assert seq.reason == "TAKEOFF refused (UNSUPPORTED)"


def test_temporarily_rejected_is_retried():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={TAKEOFF: [TEMP, TEMP]})
    assert fly(fake).step is TakeoffStep.DONE
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0), (TAKEOFF, 1), (TAKEOFF, 2)]


def test_in_progress_waits_for_the_final_ack_without_resending():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={ARM: [IN_PROGRESS]})
    seq = TakeoffSequence(Flavour.ARDUPILOT, TakeoffSettings(7.0), 0.0)
    seq.on_position(0.0, 0.0, 0.0)
    seq.on_heartbeat(0.0, fake.mode, False)
    fake.handle(seq, 0.0)
    for i in range(1, 101):  # 5 s > ack_timeout_s, < in_progress_timeout_s
        fake.step(seq, i * DT)
    assert commands(fake) == [(ARM, 0)] and seq.step is TakeoffStep.ARM
    assert any("ARM in progress" in n.text for n in fake.notices)
    seq.on_ack(5.1, ARM, ACCEPTED)
    assert seq.step is TakeoffStep.TAKEOFF


# ---- lost ACKs -----------------------------------------------------------------------


def test_no_ack_at_all_is_bounded_by_max_attempts():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={ARM: [None] * 10})
    seq = fly(fake)
    assert seq.step is TakeoffStep.FAILED
    assert commands(fake) == [(ARM, 0), (ARM, 1), (ARM, 2), (ARM, 3)]
    assert "no accepting COMMAND_ACK for ARM after 4 attempt(s)" in seq.reason
    assert fake.end_s == pytest.approx(4 * 1.5, abs=0.3)


def test_lost_arm_ack_is_completed_by_the_armed_heartbeat():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, script={ARM: ["lost"]})
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0)]
    assert "confirmed by telemetry" in fake.events[2]["after"]


def test_lost_takeoff_ack_and_refused_retransmission_is_not_an_error():
    """The first NAV_TAKEOFF worked but its ACK was lost; the retransmission is FAILED
    ("already flying"), and the climb shows the takeoff happened."""
    fake = FakeAutopilot(
        mode=ARDUCOPTER_GUIDED, script={TAKEOFF: ["lost", FAILED]}, climb_mps=0.3, speedup=1.0
    )
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE, seq.reason
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0), (TAKEOFF, 1)]
    assert [e.get("after") for e in fake.events if e["step"] == "climb"] == [
        "confirmed by telemetry"
    ]


def test_acks_of_other_commands_are_ignored():
    seq = TakeoffSequence(Flavour.ARDUPILOT, TakeoffSettings(7.0), 0.0)
    seq.on_position(0.0, 0.0, 0.0)
    seq.on_frame(0.0)
    seq.on_heartbeat(0.0, ARDUCOPTER_GUIDED, False)
    assert seq.step is TakeoffStep.ARM
    seq.on_ack(0.1, M.MAV_CMD_SET_MESSAGE_INTERVAL, FAILED)
    seq.on_ack(0.1, TAKEOFF, ACCEPTED)
    assert seq.step is TakeoffStep.ARM


# ---- climb bounds and takeovers --------------------------------------------------------


def test_climb_timeout_in_autopilot_time():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, climb_mps=0.1, speedup=10.0)
    seq = fly(fake, climb_timeout_s=20.0)
    assert seq.step is TakeoffStep.FAILED
    assert "after 20 s (autopilot time)" in seq.reason
    assert fake.end_s == pytest.approx(2.0, abs=0.3)  # 20 s of autopilot time at 10x


def test_climb_wall_backstop_when_autopilot_time_stops():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, climb_mps=0.0)
    seq = TakeoffSequence(Flavour.ARDUPILOT, TakeoffSettings(7.0, climb_timeout_wall_s=5.0), 0.0)
    fake.handle(seq, 0.0)
    t = 0.0
    while not seq.finished and t < 60:
        t += DT
        fake.freeze_autopilot_time = seq.step is TakeoffStep.CLIMB
        fake.step(seq, t)
    assert seq.step is TakeoffStep.FAILED and "(wall)" in seq.reason
    assert t < 8.0


def test_pilot_mode_change_during_climb_aborts():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, climb_mps=0.3, speedup=1.0)
    seq = TakeoffSequence(Flavour.ARDUPILOT, TakeoffSettings(7.0), 0.0)
    seq.on_heartbeat(0.0, fake.mode, fake.armed)
    t = 0.0
    while not seq.finished and t < 60:
        t += DT
        if t > 6.0:
            fake.mode = LOITER
        fake.step(seq, t)
    assert seq.step is TakeoffStep.FAILED
    assert "mode changed to LOITER during takeoff" in seq.reason


def test_disarm_during_climb_aborts():
    fake = FakeAutopilot(mode=ARDUCOPTER_GUIDED, climb_mps=0.3, speedup=1.0)
    seq = TakeoffSequence(Flavour.ARDUPILOT, TakeoffSettings(7.0), 0.0)
    seq.on_heartbeat(0.0, fake.mode, fake.armed)
    t = 0.0
    while not seq.finished and t < 60:
        t += DT
        if t > 6.0:
            fake.armed = False
        fake.step(seq, t)
    assert seq.step is TakeoffStep.FAILED and "disarmed" in seq.reason


def test_waits_for_the_ekf_origin_with_progress_then_takes_off():
    """ArduPilot sends no LOCAL_POSITION_NED until its EKF has an origin and uses GPS
    (~40 s after boot on SITL): the takeoff waits, saying so every 5 s, then flies."""
    fake = FakeAutopilot(position_after_s=40.0)
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    waits = [e for e in fake.events if e["step"] == "wait"]
    assert len(waits) == 7  # at 5, 10, ... 35 s
    assert all(e["waiting"] == ["position (EKF origin/GPS)"] for e in waits)
    texts = [n.text for n in fake.notices]
    assert "Takeoff waits for position (EKF origin/GPS) (5 s)" in texts
    assert fake.sent[0].command == SET_MODE  # nothing was sent before the position
    assert steps(fake)[-4:] == ["arm", "takeoff", "climb", "done"]


def test_waits_for_the_prearm_checks_when_the_autopilot_reports_them():
    fake = FakeAutopilot(prearm_after_s=12.0, position_after_s=3.0)
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    waits = [e for e in fake.events if e["step"] == "wait"]
    assert [e["waiting"] for e in waits] == [["pre-arm checks"], ["pre-arm checks"]]
    arm = next(c for c in fake.sent if c.command == ARM)
    assert arm.confirmation == 0  # armed at the first attempt: no refusal to retry


def test_refuses_to_take_off_without_camera_frames_and_says_why():
    fake = FakeAutopilot(camera=False)
    seq = fly(fake, ready_timeout_s=20.0)
    assert seq.step is TakeoffStep.FAILED
    assert seq.reason == "on the ground but no camera frames after 20 s"
    assert fake.sent == []  # neither mode, arm nor takeoff
    texts = [n.text for n in fake.notices]
    assert texts[-1] == "Takeoff failed: on the ground but no camera frames after 20 s"
    assert fake.notices[-1].severity == M.MAV_SEVERITY_CRITICAL
    assert "Takeoff waits for camera frames (15 s)" in texts


def test_no_position_at_all_is_a_bounded_wait():
    fake = FakeAutopilot(position_after_s=math.inf)
    seq = fly(fake, ready_timeout_s=30.0)
    assert seq.step is TakeoffStep.FAILED and fake.sent == []
    assert seq.reason == "on the ground but no position (EKF origin/GPS) after 30 s"
    assert fake.end_s == pytest.approx(30.0, abs=2 * DT)


# ---- PX4 -----------------------------------------------------------------------------


def test_px4_arms_and_takes_off_with_an_amsl_altitude():
    fake = FakeAutopilot(flavour=Flavour.PX4, mode=PX4_HOLD, home_amsl_m=488.0)
    seq = fly(fake)
    assert seq.step is TakeoffStep.DONE
    assert commands(fake) == [(ARM, 0), (TAKEOFF, 0)]  # no mode request: PX4 does it
    assert fake.sent[1].params[6] == pytest.approx(495.0)  # home AMSL + 7 m
    assert math.isnan(fake.sent[1].params[3])  # yaw: keep


def test_px4_without_home_altitude_fails_clearly():
    fake = FakeAutopilot(flavour=Flavour.PX4, mode=PX4_HOLD, home_amsl_m=math.nan)
    seq = fly(fake)
    assert seq.step is TakeoffStep.FAILED and "home altitude" in seq.reason
    assert fake.sent == []


def test_px4_requests_home_and_landed_state():
    seq = TakeoffSequence(Flavour.PX4, TakeoffSettings(7.0), 0.0)
    requests = [a for a in seq.pop_actions() if isinstance(a, TakeoffCommand)]
    assert {round(a.params[0]) for a in requests} == {
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
        M.MAVLINK_MSG_ID_HOME_POSITION,
    }


# ---- configuration -------------------------------------------------------------------


def test_takeoff_config_accepted_and_validated():
    cfg = config_from_args(build_parser().parse_args(["--takeoff-alt", "7"]), environ={})
    assert cfg.link.takeoff_alt_m == 7.0 and cfg.link.takeoff_tolerance_m == 0.5
    with pytest.raises(ConfigError, match="takeoff_alt_m"):
        LinkConfig(takeoff_alt_m=-1.0)
    with pytest.raises(ConfigError, match="takeoff_tolerance_m"):
        LinkConfig(takeoff_alt_m=1.0, takeoff_tolerance_m=2.0)
    with pytest.raises(ConfigError, match="takeoff_timeout_s"):
        LinkConfig(takeoff_alt_m=1.0, takeoff_timeout_s=math.nan)


# ---- real processes ------------------------------------------------------------------


@pytest.fixture
def rig(tmp_path):
    from test_companion_sil import Rig

    r = Rig(tmp_path)
    yield r
    r.close()


def test_takeoff_from_the_ground_then_the_paper_flight_to_the_goal(rig):
    """plant-sim starts disarmed on the ground in GUIDED; the companion arms, takes off to
    7 m, and only then steers the paper's scenario to the goal without a collision."""
    from evaluation.sil import _read_truth

    companion = rig.companion("--takeoff-alt", "7")
    started = time.monotonic()
    plant = rig.plant("--start-on-ground")
    done = rig.wait_event(companion, "takeoff", 60, cond=lambda f: f["step"] == "done")
    takeoff_wall_s = time.monotonic() - started
    rig.wait_event(companion, "goal_reached", 90)
    # the companion first: stopped after plant-sim, a slow exit on a loaded machine sees
    # the link lost and forgets the takeoff it reports in its exit statistics
    companion.stop()
    plant.stop()
    assert [f["step"] for _, f in companion.events("takeoff")] == [
        "probe",
        "arm",
        "takeoff",
        "climb",
        "done",
    ], rig.logs()
    assert abs(done["height_m"] - 7.0) <= 0.5
    # the first setpoint went out after the takeoff, never before
    active = companion.events("phase")[0][1]
    assert active["phase"] == "active" and active["setpoints_sent"] == 0
    stats = companion.stats("COMPANION STATS ")
    assert stats["takeoff"] == "done" and stats["frames_during_takeoff"] > 0
    truth = _read_truth(rig.tmp / "run0" / "truth.csv")
    assert truth["pos_d_m"][0] == pytest.approx(0.0, abs=0.05)  # started on the ground
    assert truth["armed"][0] == 0
    assert float(np.min(truth["surface_distance_m"])) > 0.25  # no collision
    print(
        f"takeoff to 7 m: climb {done['climb_autopilot_s']:.2f} s autopilot time, "
        f"{done['climb_wall_s']:.2f} s wall; companion start → done {takeoff_wall_s:.1f} s wall"
    )


def test_takeoff_alt_with_an_airborne_vehicle_is_skipped(rig):
    companion = rig.companion("--takeoff-alt", "7")
    rig.plant()
    ev = rig.wait_event(companion, "takeoff", 30, cond=lambda f: f["step"] == "skipped")
    assert "already airborne" in ev["reason"]
    rig.wait_event(companion, "steering", 10)
    assert companion.stderr_text().count("takeoff: sending") == 0


def test_prearm_refusal_over_udp_is_a_clear_terminal_error(rig):
    """A scripted ArduCopter on the companion's UDP port refuses every ARM with a PreArm
    STATUSTEXT: the companion retries a bounded number of times, tells the ground station,
    and exits with status 3 — it neither hangs nor steers. (Blank camera frames are
    published: without frames it would not even try.)"""
    import zenoh
    from pymavlink import mavutil

    from protocols.camera import CameraModel
    from protocols.frame_publisher import FramePublisher
    from protocols.keys import stereo_key

    companion = rig.companion("--takeoff-alt", "7")
    ap = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{rig.mav_port}",
        source_system=1,
        source_component=1,
        dialect="ardupilotmega",
    )
    rig.gcs = ap  # closed by the rig
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", f'["{rig.companion_zenoh}"]')
    session = zenoh.open(conf)
    camera = FramePublisher(session, stereo_key("sim1"))
    intr = CameraModel().intrinsics
    blank = np.zeros((intr.height_px, intr.width_px), dtype=np.uint8)
    frames = 0
    arms, texts, setpoints, heard = 0, [], 0, False
    deadline = time.monotonic() + 30
    next_tx = 0.0
    t0 = time.monotonic()
    while companion.proc.poll() is None and time.monotonic() < deadline:
        msg = ap.recv_match(blocking=True, timeout=0.05)
        heard = heard or msg is not None  # udpin answers whoever wrote to it last
        now = time.monotonic()
        if now >= next_tx and heard:
            next_tx = now + 0.2
            ms = int((now - t0) * 1000)
            ap.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 1, 4, 3)
            ap.mav.extended_sys_state_send(0, M.MAV_LANDED_STATE_ON_GROUND)
            ap.mav.local_position_ned_send(ms, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            assert camera.publish(frames, ms * 1_000_000, intr, blank, blank)
            frames += 1
        if msg is None:
            continue
        mtype = msg.get_type()
        if mtype == "COMMAND_LONG":
            result = M.MAV_RESULT_ACCEPTED
            if msg.command == M.MAV_CMD_COMPONENT_ARM_DISARM:
                arms += 1
                ap.mav.statustext_send(M.MAV_SEVERITY_CRITICAL, b"PreArm: Gyros not calibrated")
                result = M.MAV_RESULT_FAILED
            ap.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), 196)
        elif mtype == "STATUSTEXT":
            texts.append(msg.text)
        elif mtype == "SET_POSITION_TARGET_LOCAL_NED":
            setpoints += 1
    assert companion.proc.wait(timeout=10) == 3, rig.logs()
    camera.close()
    session.close()
    assert arms == 3 and setpoints == 0
    err = companion.stderr_text()
    assert "takeoff failed: ARM refused (FAILED: PreArm: Gyros not calibrated)" in err, err
    assert any(t.startswith("Takeoff failed: ARM refused") for t in texts), texts
    assert companion.events("takeoff")[-1][1]["step"] == "failed"
