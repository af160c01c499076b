#!/usr/bin/env bash
# Docker smoke test of the companion alone against an autopilot on the host (not part of
# the default test run; run it when docker/ changes): docker/compose.autopilot.yaml runs
# the companion container; ArduCopter SITL (the binary named by $ARDUCOPTER_SITL, which a
# user builds from ArduPilot's repository) and plant-sim as the camera only (`plant-sim --pose-from`, on the
# host, frames over Zenoh into the container's published port) run on this host.
#
# Checks, in order (each prints a PASS/FAIL line):
#   1. the container is healthy only once SITL's heartbeats and telemetry arrive
#      (and says why it is not before);
#   2. the companion takes off (GUIDED, arm, 7 m), flies to the goal 20 m north and
#      avoids the 1.5 m sphere 10 m north (plant-sim's truth.csv: closest to the goal
#      < 0.5 m, obstacle surface distance > 0.35 m, the radius with propellers);
#   3. SITL frozen (SIGSTOP: nothing arrives, the TCP link stays open): the container
#      turns unhealthy with the reason "link_lost"; SIGCONT: healthy again;
#   4. the camera stopped while the companion steers: unhealthy with "no_frames".
# Logs: runs/autopilot-smoke/ (companion.log, plant_sim.log, truth.csv, sitl.log).
# Needs a Docker engine (DOCKER_HOST) and docker-compose or `docker compose`.
set -euo pipefail
cd "$(dirname "$0")/.."
if docker compose version >/dev/null 2>&1; then
    compose="docker compose"
elif command -v docker-compose >/dev/null 2>&1; then
    compose="docker-compose"
else
    echo "docker-smoke-autopilot: neither 'docker compose' nor 'docker-compose' is installed" >&2
    exit 2
fi
if ! docker info >/dev/null 2>&1; then
    echo "docker-smoke-autopilot: no Docker engine reachable (DOCKER_HOST=${DOCKER_HOST:-unset})" >&2
    exit 2
fi
bash scripts/setup.sh
$compose -f docker/compose.autopilot.yaml config >/dev/null
run=runs/autopilot-smoke
rm -rf "$run" && mkdir -p "$run" && chmod a+rwx "$run"
export SMOKE_COMPOSE="$compose" SMOKE_RUN="$run"
exec .venv/bin/python - <<'PY'
import csv
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from evaluation.sil import free_port
from evaluation.sitl_scene import paper_sitl_scene
from evaluation.sitl import (
    SITL_HOWTO,
    ArduCopterSitl,
    find_arducopter_sitl,
    free_sitl_instance,
)

RUN = Path(os.environ["SMOKE_RUN"]).resolve()
COMPOSE = os.environ["SMOKE_COMPOSE"].split()
GOAL = (20.0, 0.0, -7.0)
SPEEDUP = float(os.environ.get("SITL_SPEEDUP", "2"))
results: list[bool] = []


def say(text: str) -> None:
    print(f"docker-smoke-autopilot: {text}", flush=True)


def verdict(ok: bool, text: str) -> None:
    results.append(ok)
    say(f"{'PASS' if ok else 'FAIL'}: {text}")


binary = find_arducopter_sitl()
if binary is None:
    sys.exit(f"docker-smoke-autopilot: {SITL_HOWTO}")
(RUN / "scenario.json").write_text(json.dumps(paper_sitl_scene().scenario, indent=2) + "\n")
(RUN / "wpnav100.parm").write_text("WPNAV_SPEED 100\n")  # GUIDED targets at <= 1 m/s
instance = free_sitl_instance()
zenoh_port = free_port(socket.SOCK_STREAM)
udp_port = free_port(socket.SOCK_DGRAM)
project = f"smoke-autopilot-{os.getpid()}"
env = dict(
    os.environ,
    COMPANION_MAVLINK_URL="",  # set below, once the SITL ports are known
    COMPANION_TAKEOFF_ALT="7",
    COMPANION_WAYPOINTS=",".join(f"{x:g}" for x in GOAL),
    COMPANION_FRAME_CLOCK="autopilot",
    COMPANION_ZENOH_PORT=str(zenoh_port),
    COMPANION_MAVLINK_UDP_PORT=str(udp_port),
    VEHICLE_ID="sim1",
    RUN_NAME=RUN.name,
)
compose = [*COMPOSE, "-p", project, "-f", "docker/compose.autopilot.yaml"]
sitl = plant = None


def health(container: str) -> tuple[str, str]:
    out = subprocess.run(
        ["docker", "inspect", "--format", "{{json .State.Health}}", container],
        capture_output=True, text=True, check=True,
    ).stdout
    state = json.loads(out)
    log = state.get("Log") or []
    return state["Status"], (log[-1]["Output"].strip() if log else "")


def wait_health(container: str, want: str, timeout_s: float) -> tuple[bool, str, list[str]]:
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status, output = health(container)
        if output and (not seen or seen[-1] != output):
            seen.append(output)
        if status == want:
            return True, output, seen
        time.sleep(1.0)
    return False, health(container)[1], seen


try:
    sitl = ArduCopterSitl(
        binary, [binary.parent / "copter.parm", RUN / "wpnav100.parm"], instance, SPEEDUP
    )
    sitl.wait_output(r"Waiting for connection", 30.0)
    env["COMPANION_MAVLINK_URL"] = f"tcp:host.docker.internal:{sitl.port(0)}"
    say(f"ArduCopter SITL -I{instance} at {SPEEDUP:g}x; companion container on "
        f"{env['COMPANION_MAVLINK_URL']}, Zenoh published on 127.0.0.1:{zenoh_port}")
    subprocess.run([*compose, "up", "-d", "--build"], env=env, check=True)
    container = subprocess.run(
        [*compose, "ps", "-q", "companion"], env=env, capture_output=True, text=True, check=True
    ).stdout.strip()

    # 1. healthy only with heartbeats and telemetry
    ok, output, seen = wait_health(container, "healthy", 180.0)
    before = [s for s in seen if s.startswith("unhealthy")]
    say(f"healthcheck outputs before healthy: {before[:3]}")
    verdict(
        ok and any("no_telemetry" in s or "no_autopilot" in s for s in before),
        f"companion container unhealthy until SITL's telemetry arrives, then healthy: {output}",
    )
    if not ok:
        raise SystemExit(1)

    # 2. frames from plant-sim camera-only on the host; the companion takes off and flies
    sitl.wait_output(r"SERIAL1 on TCP port", 30.0)
    plant_log = (RUN / "plant_sim.stdout").open("w")
    plant = subprocess.Popen(
        [
            ".venv/bin/plant-sim", "--pose-from", sitl.url(1),
            "--scenario", str(RUN / "scenario.json"),
            "--zenoh-config", "docker/config/zenoh/publisher.json5",
            "--zenoh-connect", f"tcp/127.0.0.1:{zenoh_port}",
            "--vehicle-id", "sim1", "--log-dir", str(RUN),
            "--log-file", str(RUN / "plant_sim.log"),
        ],
        stdout=plant_log, stderr=subprocess.STDOUT,
    )
    companion_log = RUN / "companion.log"
    deadline = time.monotonic() + 300.0
    reached = False
    while time.monotonic() < deadline and plant.poll() is None:
        text = companion_log.read_text(errors="replace") if companion_log.exists() else ""
        if "COMPANION EVENT goal_reached" in text:
            reached = True
            break
        if "takeoff failed" in text:
            break
        time.sleep(1.0)
    time.sleep(2.0)  # a few more truth rows at the goal
    status, output = health(container)
    verdict(status == "healthy", f"healthy while steering with frames: {output}")
    rows = list(csv.DictReader((RUN / "truth.csv").open(newline="")))
    flying = [r for r in rows if float(r["pos_d_m"]) < -1.0]
    dist = [math.dist([float(r[k]) for k in ("pos_n_m", "pos_e_m", "pos_d_m")], GOAL)
            for r in flying] or [math.inf]
    surface = min((float(r["surface_distance_m"]) for r in flying if r["surface_distance_m"]),
                  default=math.nan)
    verdict(
        reached and min(dist) < 0.5 and surface > 0.35,
        f"companion event goal_reached={reached}: closest to goal {min(dist):.2f} m, min "
        f"distance to obstacle surface {surface:.2f} m, {len(rows)} truth rows",
    )

    # 3. link lost: SITL frozen, then resumed (the camera keeps running)
    os.kill(sitl.proc.pid, signal.SIGSTOP)
    ok, output, _ = wait_health(container, "unhealthy", 60.0)
    verdict(ok and "link_lost" in output, f"SITL frozen: container unhealthy: {output}")
    os.kill(sitl.proc.pid, signal.SIGCONT)
    ok, output, _ = wait_health(container, "healthy", 90.0)
    verdict(ok, f"SITL resumed: container healthy again: {output}")

    # 4. no frames while steering
    plant.send_signal(signal.SIGTERM)
    plant.wait(timeout=30)
    ok, output, _ = wait_health(container, "unhealthy", 60.0)
    verdict(ok and "no_frames" in output, f"camera stopped: container unhealthy: {output}")
finally:
    if plant is not None and plant.poll() is None:
        plant.kill()
    subprocess.run([*compose, "logs", "--no-color", "--tail", "40", "companion"], env=env)
    subprocess.run([*compose, "down", "--remove-orphans"], env=env, capture_output=True)
    if sitl is not None:
        os.kill(sitl.proc.pid, signal.SIGCONT)
        sitl.stop()
        (RUN / "sitl.log").write_text(sitl.output())
ok = bool(results) and all(results)
say(f"{'PASS' if ok else 'FAIL'}: {sum(results)}/{len(results)} checks")
sys.exit(0 if ok else 1)
PY
