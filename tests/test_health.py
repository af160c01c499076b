"""companion.health: healthy only while the companion could steer; the healthcheck command
reports the reason and fails on a missing or stale file. Also the companion's --health-file,
--log-file and --waypoints flags and the signing key file from the environment."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from companion.config import ConfigError, build_parser, config_from_args
from companion.health import HealthFile, HealthInputs, HealthState, HealthTracker, check
from protocols.logfile import LogFileError, start_log_file

URL = "udpin:0.0.0.0:14550"


def _inputs(now_s, **kw):
    base = dict(
        now_s=now_s,
        link_up=True,
        autopilot_seen=True,
        link_url=URL,
        telemetry_stamp_ns=None,
        frames_received=0,
        flying=False,
    )
    base.update(kw)
    return HealthInputs(**base)


def test_nothing_from_the_autopilot_is_unhealthy_with_the_url():
    report = HealthTracker().update(_inputs(0.0, link_up=False, autopilot_seen=False))
    assert not report.healthy and report.state is HealthState.NO_AUTOPILOT
    assert URL in report.reason


def test_heartbeats_without_telemetry_are_unhealthy():
    report = HealthTracker().update(_inputs(0.0))
    assert not report.healthy and report.state is HealthState.NO_TELEMETRY


def test_heartbeats_and_telemetry_are_healthy_then_stale_telemetry_is_not():
    tracker = HealthTracker(telemetry_timeout_s=2.0)
    assert tracker.update(_inputs(0.0, telemetry_stamp_ns=1)).healthy
    assert tracker.update(_inputs(1.5, telemetry_stamp_ns=1)).healthy
    stale = tracker.update(_inputs(2.5, telemetry_stamp_ns=1))  # same stamp: nothing new
    assert not stale.healthy and stale.state is HealthState.NO_TELEMETRY and "2.5 s" in stale.reason
    assert tracker.update(_inputs(3.0, telemetry_stamp_ns=2)).healthy


def test_flying_needs_frames():
    tracker = HealthTracker(frame_timeout_s=1.0)
    no_frames = tracker.update(_inputs(0.0, telemetry_stamp_ns=1, flying=True))
    assert not no_frames.healthy and no_frames.state is HealthState.NO_FRAMES
    assert tracker.update(
        _inputs(0.5, telemetry_stamp_ns=2, frames_received=3, flying=True)
    ).healthy
    lost = tracker.update(_inputs(2.0, telemetry_stamp_ns=3, frames_received=3, flying=True))
    assert not lost.healthy and lost.state is HealthState.NO_FRAMES
    # on the ground / not steering: frames are not required
    assert tracker.update(_inputs(2.1, telemetry_stamp_ns=4, frames_received=3)).healthy


def test_link_lost_after_it_was_up():
    tracker = HealthTracker()
    assert tracker.update(_inputs(0.0, telemetry_stamp_ns=1)).healthy
    lost = tracker.update(_inputs(5.0, link_up=False, autopilot_seen=False))
    assert not lost.healthy and lost.state is HealthState.LINK_LOST and URL in lost.reason


def test_fatal_wins():
    report = HealthTracker().update(_inputs(0.0, telemetry_stamp_ns=1, fatal="takeoff failed"))
    assert (
        not report.healthy
        and report.state is HealthState.FATAL
        and report.reason == "takeoff failed"
    )


def test_health_file_is_rewritten_and_checked(tmp_path):
    path = tmp_path / "companion.health"
    health = HealthFile(path)
    health.update(_inputs(0.0, telemetry_stamp_ns=1))
    record = json.loads(path.read_text())
    assert record["healthy"] is True and record["state"] == "ok"
    assert not (tmp_path / "companion.health.partial").exists()
    ok, line = check(path, max_age_s=5.0)
    assert ok and line.startswith("healthy: ok:")
    health.update(_inputs(10.0, telemetry_stamp_ns=1))
    ok, line = check(path, max_age_s=5.0)
    assert not ok and "no_telemetry" in line
    health.stopped()
    assert check(path, 5.0) == (False, "unhealthy: stopped: the companion stopped")


def test_check_refuses_a_stale_or_missing_file(tmp_path):
    path = tmp_path / "h.json"
    assert not check(path, 5.0)[0] and "no health file" in check(path, 5.0)[1]
    HealthFile(path).update(_inputs(0.0, telemetry_stamp_ns=1))
    stamp = json.loads(path.read_text())["time_unix"]
    ok, line = check(path, max_age_s=5.0, now_unix=stamp + 30.0)
    assert not ok and "30 s old" in line and "stopped updating" in line
    path.write_text("{not json")
    assert not check(path, 5.0)[0]


def test_healthcheck_command_prints_the_reason_and_exits_nonzero(tmp_path):
    path = tmp_path / "companion.health"
    HealthFile(path).update(_inputs(0.0, link_up=False, autopilot_seen=False))
    cmd = [sys.executable, "-m", "companion.health", str(path)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    assert done.returncode == 1
    assert "unhealthy: no_autopilot: no message from the autopilot on udpin" in done.stdout
    HealthFile(path).update(_inputs(0.0, telemetry_stamp_ns=1))
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and done.stdout.startswith("healthy: ok")


def test_service_hook_writes_the_file_from_its_state(tmp_path):
    from companion.config import CompanionConfig
    from companion.service import CompanionService

    service = CompanionService(CompanionConfig())  # not opened: no sockets
    service.health = HealthFile(tmp_path / "h")
    service._report_health(0.0)
    ok, line = check(tmp_path / "h", 5.0)
    assert not ok and "no_autopilot" in line and "udpout:127.0.0.1:14550" in line


def _args(*argv):
    return build_parser().parse_args(list(argv))


def test_waypoints_flag_in_one_argument():
    cfg = config_from_args(_args("--waypoints", "20,0,-7; 40,5,-7"), environ={})
    assert cfg.waypoints_ned_m == ((20.0, 0.0, -7.0), (40.0, 5.0, -7.0))
    with pytest.raises(ConfigError, match="waypoint 2 '1,2' is not three numbers"):
        config_from_args(_args("--waypoints", "0,0,-7;1,2"), environ={})
    with pytest.raises(ConfigError, match="not --goal and --waypoints"):
        config_from_args(_args("--goal", "1", "2", "3", "--waypoints", "0,0,-7"), environ={})


def test_signing_key_file_from_the_environment(tmp_path):
    key = tmp_path / "key"
    key.write_text("correct horse battery staple\n")
    env = {"STEREO_AVOID_SIGNING_KEY_FILE": str(key)}
    assert config_from_args(_args(), environ=env).link.signing_key is not None
    assert config_from_args(_args(), environ={}).link.signing_key is None
    missing = {"STEREO_AVOID_SIGNING_KEY_FILE": str(tmp_path / "nope")}
    with pytest.raises(ConfigError, match=f"cannot read the signing key file {tmp_path}/nope"):
        config_from_args(_args(), environ=missing)


def test_log_file_copies_output_and_names_an_unusable_folder(tmp_path):
    blocker = tmp_path / "runs"
    blocker.write_text("a file where the run folder should be")
    with pytest.raises(LogFileError) as info:
        start_log_file(blocker / "compose" / "companion.log")
    message = str(info.value)
    assert str(tmp_path) in message and f"uid {os.getuid()}" in message
    code = (
        "import sys; from pathlib import Path; from protocols.logfile import start_log_file;"
        f"start_log_file(Path({str(tmp_path / 'run' / 'x.log')!r}));"
        "print('to stdout'); print('to stderr', file=sys.stderr)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and done.stdout == "to stdout\n"
    assert (tmp_path / "run" / "x.log").read_text() == "to stdout\nto stderr\n"


def test_companion_exits_2_naming_an_unwritable_run_folder(tmp_path):
    blocker = tmp_path / "runs"
    blocker.write_text("")
    log = blocker / "companion.log"
    done = subprocess.run(
        [sys.executable, "-m", "companion", "--log-file", str(log)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert done.returncode == 2
    assert f"run folder {tmp_path}" in done.stderr and f"uid {os.getuid()}" in done.stderr
