"""The Compose stack without an engine: files exist and parse, the containers run exactly
the entry points the integration tests start, with flags those entry points accept (with
the environment's defaults and with values set), and the image installs nothing the
README's setup does not. (scripts/docker-smoke.sh flies the stack,
scripts/docker-smoke-autopilot.sh the companion alone against ArduCopter SITL.)
"""

import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml
import zenoh

from companion.config import build_parser as companion_parser
from companion.config import config_from_args as companion_config
from plant_sim.__main__ import build_parser as plant_parser
from plant_sim.__main__ import config_from_args as plant_config
from plant_sim.scenario import load_scenario, paper_scenario

REPO = Path(__file__).resolve().parents[1]
COMPOSE = REPO / "docker" / "compose.yaml"
AUTOPILOT = REPO / "docker" / "compose.autopilot.yaml"
SERIAL = REPO / "docker" / "compose.serial.yaml"
ENV_DEFAULT = re.compile(r"\$\{(\w+):-([^}]*)\}")
ANY_VARIABLE = re.compile(r"\$\{?\w")


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def autopilot():
    return yaml.safe_load(AUTOPILOT.read_text(encoding="utf-8"))


def _expand(arg: str, env: dict[str, str] | None = None) -> str:
    """Compose's ${VAR:-default}: the value from ``env`` if set and not empty, else the
    default. Any other form of variable is refused (the tests would not cover it)."""
    env = env or {}
    out = ENV_DEFAULT.sub(lambda m: env.get(m.group(1)) or m.group(2), str(arg))
    assert not ANY_VARIABLE.search(out), f"variable without a default in {arg!r}"
    return out


def _companion_args(service: dict, env: dict[str, str] | None = None):
    command = [_expand(a, env) for a in service["command"]]
    assert command[0] == "companion"
    args = companion_parser().parse_args(command[1:])
    args.config = _mounted(service, str(args.config))
    return args


def _health_file(service: dict) -> str:
    """The companion's healthcheck runs companion.health on its --health-file."""
    test = service["healthcheck"]["test"]
    assert test[:4] == ["CMD", "python", "-m", "companion.health"], test
    return test[4]


def _mounted(service: dict, container_path: str) -> Path:
    """Host path of a file the service reads from a bind mount."""
    for volume in service.get("volumes", []):
        host, target, *_ = volume.split(":")
        if container_path.startswith(target + "/"):
            return (COMPOSE.parent / host / container_path[len(target) + 1 :]).resolve()
    raise AssertionError(f"{container_path} is not on a mounted volume")


def test_services_build_and_files_exist(compose):
    services = compose["services"]
    assert set(services) >= {"plant-sim", "companion"}
    build = services["companion"]["build"]
    assert (COMPOSE.parent / build["context"] / build["dockerfile"]).is_file()
    assert services["companion"]["image"] == services["plant-sim"]["image"]
    # the companion listens (Zenoh with authentication, MAVLink): it is up first; plant-sim
    # (the autopilot) cannot wait for it to be healthy (healthy needs an autopilot), so it
    # waits for the companion's ready file on the shared "ready" volume
    assert services["plant-sim"]["depends_on"] == ["companion"]
    command = services["plant-sim"]["command"]
    assert command[:3] == ["python", "-m", "protocols.wait_ready"]
    ready = command[3]
    args = companion_parser().parse_args([_expand(a) for a in services["companion"]["command"][1:]])
    assert str(args.ready_file) == ready
    for name in ("companion", "plant-sim"):
        mounts = [v for v in services[name]["volumes"] if v.startswith("ready:")]
        assert mounts and Path(ready).parent == Path(mounts[0].split(":")[1])
    assert compose["volumes"]["ready"]["driver_opts"]["type"] == "tmpfs"


def test_every_service_reaches_the_host_and_logs_to_the_run_folder(compose, autopilot):
    for name, service in [*compose["services"].items(), *autopilot["services"].items()]:
        assert "host.docker.internal:host-gateway" in service["extra_hosts"], name
        assert "../runs:/app/runs" in service["volumes"], name
        command = [_expand(a) for a in service["command"]]
        log = command[command.index("--log-file") + 1]
        assert log.startswith("/app/runs/") and log.endswith(".log"), (name, log)


def test_wait_ready_runs_the_command_once_the_file_exists(tmp_path):
    ready = tmp_path / "companion.ready"
    cmd = [sys.executable, "-m", "protocols.wait_ready", str(ready), "--timeout", "0.3"]
    late = subprocess.run([*cmd, "--", "true"], capture_output=True, text=True, timeout=30)
    assert late.returncode == 2 and f"{ready} did not appear within 0.3 s" in late.stderr
    ready.write_text("COMPANION READY\n")
    done = subprocess.run(
        [*cmd, "--", sys.executable, "-c", "import sys; print('ran'); sys.exit(7)"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 7 and done.stdout == "ran\n"  # exec'd: its status is ours


def test_entry_points_are_the_ones_the_tests_run():
    """`plant-sim`/`companion` are the console scripts of `python -m plant_sim|companion`."""
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["plant-sim"] == "plant_sim.__main__:main"
    assert scripts["companion"] == "companion.__main__:main"


def test_plant_sim_command_is_accepted_and_reads_the_mounted_scenario(compose):
    service = compose["services"]["plant-sim"]
    command = [_expand(a) for a in service["command"]]
    command = command[command.index("--") + 1 :]  # after protocols.wait_ready
    assert command[0] == "plant-sim"
    args = plant_parser().parse_args(command[1:])
    args.scenario = _mounted(service, str(args.scenario))
    config = plant_config(args)  # raises on anything plant-sim would refuse
    assert config.scenario == paper_scenario()
    assert load_scenario(args.scenario) == paper_scenario()
    assert config.mavlink[0].url == "udpout:companion:14550"
    assert config.zenoh.connect == ("tcp/companion:7447",)
    zenoh_file = _mounted(service, str(config.zenoh.config_file))
    zenoh.Config.from_file(str(zenoh_file))  # a config Zenoh accepts
    assert '"plant-sim"' in zenoh_file.read_text()  # the user the companion admits
    ready = str(args.ready_file)
    assert service["healthcheck"]["test"] == ["CMD", "test", "-f", ready]
    assert config.log_dir == Path("/app/runs/compose")
    assert args.log_file == Path("/app/runs/compose/plant_sim.log")
    assert config.scenario.vehicle_id == "sim1"


def test_companion_command_is_accepted_and_reads_the_mounted_config(compose):
    service = compose["services"]["companion"]
    args = _companion_args(service)
    config = companion_config(args, environ={})
    assert config.waypoints_ned_m == ((0.0, 0.0, -7.0),)
    assert config.vehicle_id == "sim1"
    assert config.link.url == "udpin:0.0.0.0:14550"
    assert config.link.signing_key is None
    assert config.zenoh.listen == ("tcp/0.0.0.0:7447",)
    assert args.log_file == Path("/app/runs/compose/companion.log")
    zenoh_file = _mounted(service, str(config.zenoh.config_file))
    text = zenoh_file.read_text()
    assert "/config/zenoh/credentials.txt" in text and 'default_permission: "deny"' in text
    assert _mounted(service, "/config/zenoh/credentials.txt").is_file()
    assert _health_file(service) == str(args.health_file)


def test_companion_environment_sets_link_zenoh_vehicle_waypoints_and_key(compose, tmp_path):
    key = tmp_path / "signing.key"
    key.write_text("a passphrase for the test\n")
    env = {
        "COMPANION_MAVLINK_URL": "tcp:host.docker.internal:5760",
        "COMPANION_ZENOH_LISTEN": "tcp/0.0.0.0:7500",
        "VEHICLE_ID": "drone7",
        "COMPANION_WAYPOINTS": "20,0,-7;40,0,-7",
        "RUN_NAME": "flight3",
    }
    service = compose["services"]["companion"]
    args = _companion_args(service, env)
    config = companion_config(args, environ={"STEREO_AVOID_SIGNING_KEY_FILE": str(key)})
    assert config.link.url == "tcp:host.docker.internal:5760"
    assert config.zenoh.listen == ("tcp/0.0.0.0:7500",)
    assert config.vehicle_id == "drone7"
    assert config.waypoints_ned_m == ((20.0, 0.0, -7.0), (40.0, 0.0, -7.0))
    assert config.link.signing_key is not None
    assert args.log_file == Path("/app/runs/flight3/companion.log")
    # the key variables reach both containers; the same vehicle id too
    for name in ("companion", "plant-sim"):
        environment = compose["services"][name]["environment"]
        assert set(environment) == {"STEREO_AVOID_SIGNING_KEY", "STEREO_AVOID_SIGNING_KEY_FILE"}
    plant = [_expand(a, env) for a in compose["services"]["plant-sim"]["command"]]
    assert plant[plant.index("--vehicle-id") + 1] == "drone7"
    assert plant[plant.index("--log-dir") + 1] == "/app/runs/flight3"


def test_autopilot_compose_runs_the_companion_alone_against_the_host(autopilot, tmp_path):
    services = autopilot["services"]
    assert set(services) == {"companion"}
    service = services["companion"]
    args = _companion_args(service)
    config = companion_config(args, environ={})
    assert config.link.url == "tcp:host.docker.internal:5760"  # ArduPilot SITL SERIAL0
    assert config.link.takeoff_alt_m == 0.0  # takes off only when asked
    assert config.link.frame_clock.value == "autopilot"
    assert config.zenoh.listen == ("tcp/0.0.0.0:7447",)
    assert "7447" in service["ports"][0].split(":")[-1]
    assert service["ports"][1].endswith(":14550/udp")
    assert _health_file(service) == str(args.health_file)
    env = {
        "COMPANION_MAVLINK_URL": "/dev/ttyACM0",
        "COMPANION_BAUD": "57600",
        "COMPANION_TAKEOFF_ALT": "7",
        "COMPANION_WAYPOINTS": "20,0,-7",
        "COMPANION_FRAME_CLOCK": "host",
    }
    config = companion_config(_companion_args(service, env), environ={})
    assert (config.link.url, config.link.baud) == ("/dev/ttyACM0", 57600)
    assert config.link.takeoff_alt_m == 7.0 and config.waypoints_ned_m == ((20.0, 0.0, -7.0),)
    assert config.link.frame_clock.value == "host"
    build = service["build"]
    assert (AUTOPILOT.parent / build["context"] / build["dockerfile"]).is_file()


def test_serial_override_passes_the_device_through():
    service = yaml.safe_load(SERIAL.read_text(encoding="utf-8"))["services"]["companion"]
    device = _expand(service["devices"][0], {"MAVLINK_DEVICE": "/dev/ttyUSB1"})
    assert device == "/dev/ttyUSB1:/dev/ttyUSB1"
    assert _expand(service["devices"][0]) == "/dev/ttyACM0:/dev/ttyACM0"
    assert service["group_add"] == ["dialout"]


def test_pip_index_build_arguments_reach_the_build_stage(compose, autopilot):
    names = {"PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL", "PIP_TRUSTED_HOST"}
    for doc in (compose, autopilot):
        assert set(doc["services"]["companion"]["build"]["args"]) == names
    text = (REPO / "docker" / "Dockerfile").read_text(encoding="utf-8")
    stages = re.split(r"^FROM ", text, flags=re.M)[1:]
    assert len(stages) == 2 and " AS build" in stages[0].splitlines()[0]
    build, runtime = stages
    for name in names:
        assert f"ARG {name}" in build and name not in runtime.replace("# ", "")
    # the CA certificates are added to the system store of the build stage only
    assert "docker/ca/" in build and "update-ca-certificates" in build
    assert "docker/ca" not in runtime and "COPY --from=build /opt/venv /opt/venv" in runtime


def test_image_installs_only_the_package():
    """The Dockerfile's pip installs are the package (`.`, a subset of the README's
    `.[dev]`) and a requirements file made from pyproject.toml's own dependency lists
    (project.dependencies + build-system.requires), and nothing comes from apt."""
    lines = (REPO / "docker" / "Dockerfile").read_text(encoding="utf-8").splitlines()
    dockerfile = "\n".join(line for line in lines if not line.lstrip().startswith("#"))
    assert "apt-get" not in dockerfile
    installs = re.findall(r"pip install ([^;\n\\]+)", dockerfile)
    assert len(installs) == 2, installs
    targets = [[t for t in shlex.split(i) if not t.startswith("-")] for i in installs]
    assert targets == [["/tmp/requirements.txt"], ["."]], installs
    assert "--no-deps" in installs[1]
    # the requirements file is written from pyproject.toml only
    generator = dockerfile[: dockerfile.index("> /tmp/requirements.txt")]
    assert 'p["project"]["dependencies"] + p["build-system"]["requires"]' in generator


@pytest.mark.parametrize(
    "files", [[COMPOSE], [AUTOPILOT], [AUTOPILOT, SERIAL]], ids=["sil", "autopilot", "serial"]
)
def test_compose_v1_accepts_the_files(files, tmp_path):
    """`docker-compose config` validates against the Compose schema without an engine."""
    binary = shutil.which("docker-compose")
    if binary is None:
        pytest.skip("docker-compose (Compose v1) is not installed")
    args = [binary, *(a for f in files for a in ("-f", str(f))), "config", "-q"]
    env = {"PATH": os.environ.get("PATH", ""), "HOME": str(tmp_path)}
    done = subprocess.run(args, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr
