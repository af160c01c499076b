"""The Compose stack without an engine: files exist and parse, the containers run exactly
the entry points the integration tests start, with flags those entry points accept, and
the image installs nothing the README's setup does not. (scripts/docker-smoke.sh flies it.)
"""

import re
import shlex
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
ENV_DEFAULT = re.compile(r"\$\{(\w+):-([^}]*)\}")


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))


def _expand(arg: str) -> str:
    """Compose's ${VAR:-default} with the defaults (nothing set in the environment)."""
    return ENV_DEFAULT.sub(lambda m: m.group(2), arg)


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
    # the companion listens (Zenoh with authentication, MAVLink): it is up first
    assert services["plant-sim"]["depends_on"]["companion"]["condition"] == "service_healthy"


def test_entry_points_are_the_ones_the_tests_run():
    """`plant-sim`/`companion` are the console scripts of `python -m plant_sim|companion`."""
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["plant-sim"] == "plant_sim.__main__:main"
    assert scripts["companion"] == "companion.__main__:main"


def test_plant_sim_command_is_accepted_and_reads_the_mounted_scenario(compose):
    service = compose["services"]["plant-sim"]
    command = [_expand(a) for a in service["command"]]
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


def test_companion_command_is_accepted_and_reads_the_mounted_config(compose):
    service = compose["services"]["companion"]
    command = [_expand(a) for a in service["command"]]
    assert command[0] == "companion"
    args = companion_parser().parse_args(command[1:])
    args.config = _mounted(service, str(args.config))
    config = companion_config(args)
    assert config.waypoints_ned_m == ((0.0, 0.0, -7.0),)
    assert config.link.url == "udpin:0.0.0.0:14550"
    assert config.zenoh.listen == ("tcp/0.0.0.0:7447",)
    zenoh_file = _mounted(service, str(config.zenoh.config_file))
    text = zenoh_file.read_text()
    assert "/config/zenoh/credentials.txt" in text and 'default_permission: "deny"' in text
    assert _mounted(service, "/config/zenoh/credentials.txt").is_file()
    assert service["healthcheck"]["test"] == ["CMD", "test", "-f", str(args.ready_file)]


def test_image_installs_only_the_package():
    """Every pip install in the Dockerfile installs `.` (a subset of the README's
    `.[dev]`), and nothing comes from apt."""
    lines = (REPO / "docker" / "Dockerfile").read_text(encoding="utf-8").splitlines()
    dockerfile = "\n".join(line for line in lines if not line.lstrip().startswith("#"))
    assert "apt-get" not in dockerfile
    installs = re.findall(r"pip install ([^;\n\\]+)", dockerfile)
    assert installs
    for install in installs:
        targets = [t for t in shlex.split(install) if not t.startswith("-")]
        assert targets == ["."], install
