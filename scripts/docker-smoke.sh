#!/usr/bin/env bash
# Docker smoke test (not part of the default test run; run it when docker/ changes):
# validates docker/compose.yaml, builds the image, flies the paper's scenario with the
# two containers at 4x speed and checks plant-sim's ground truth (goal reached within
# 0.5 m, no collision), that every service's log is in runs/compose/ and that the
# companion's healthcheck said healthy during the flight. Needs a Docker engine
# (DOCKER_HOST) and docker-compose or `docker compose`; see README "Docker".
# The companion alone against ArduCopter SITL: scripts/docker-smoke-autopilot.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
if docker compose version >/dev/null 2>&1; then
    compose=(docker compose)
elif command -v docker-compose >/dev/null 2>&1; then
    compose=(docker-compose)
else
    echo "docker-smoke: neither 'docker compose' nor 'docker-compose' is installed" >&2
    exit 2
fi
if ! docker info >/dev/null 2>&1; then
    echo "docker-smoke: no Docker engine reachable (DOCKER_HOST=${DOCKER_HOST:-unset})" >&2
    exit 2
fi
bash scripts/setup.sh
file=docker/compose.yaml
"${compose[@]}" -f "$file" config >/dev/null
rm -rf runs/compose && mkdir -p runs/compose && chmod a+rwx runs/compose
export SPEEDUP=${SPEEDUP:-4} SIM_DURATION_S=${SIM_DURATION_S:-60}
trap '"${compose[@]}" -f "$file" down --remove-orphans >/dev/null 2>&1 || true' EXIT
"${compose[@]}" -f "$file" up --build --abort-on-container-exit --exit-code-from plant-sim
companion=$("${compose[@]}" -f "$file" ps -q companion)
docker inspect --format '{{json .State.Health}}' "$companion" > runs/compose/companion-health.json
.venv/bin/python - <<'PY'
import csv, math, sys
rows = list(csv.DictReader(open("runs/compose/truth.csv", newline="")))
if not rows:
    sys.exit("docker-smoke: FAIL: empty runs/compose/truth.csv")
goal = (0.0, 0.0, -7.0)
dist = [math.dist([float(r[k]) for k in ("pos_n_m", "pos_e_m", "pos_d_m")], goal) for r in rows]
surface = min(float(r["surface_distance_m"]) for r in rows if r["surface_distance_m"])
ok = min(dist) < 0.5 and surface > 0.35  # collision: the radius with propellers
print(f"docker-smoke: {'PASS' if ok else 'FAIL'}: closest to goal {min(dist):.2f} m, "
      f"min distance to obstacle surface {surface:.2f} m, {len(rows)} truth rows")
import json
from pathlib import Path
logs = {n: Path("runs/compose", n) for n in ("companion.log", "plant_sim.log")}
ready = {"companion.log": "COMPANION READY", "plant_sim.log": "PLANT_SIM READY"}
logs_ok = all(p.is_file() and ready[n] in p.read_text(errors="replace") for n, p in logs.items())
print(f"docker-smoke: {'PASS' if logs_ok else 'FAIL'}: service logs in runs/compose: "
      + ", ".join(f"{n} {p.stat().st_size if p.is_file() else 'missing'} B" for n, p in logs.items()))
checks = json.loads(Path("runs/compose/companion-health.json").read_text()).get("Log") or []
outputs = [c["Output"].strip() for c in checks]
health_ok = any(o.startswith("healthy: ok") for o in outputs)
print(f"docker-smoke: {'PASS' if health_ok else 'FAIL'}: companion healthchecks at the end "
      f"of the flight: {outputs}")
sys.exit(0 if ok and logs_ok and health_ok else 1)
PY
