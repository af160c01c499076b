"""Config declared once (issue 33 item 4): conformance of every config dataclass to the
one validator of ``protocols.config``.

Config classes are found by discovery (a ``@dataclass`` whose name ends in ``Config``,
``Params``, ``Settings``, ``Rules`` or ``Timings`` in the product's packages), not by a
list. Each must declare every numeric field with :func:`protocols.config.bounded` (unit and
bounds), and a value outside a declared bound must raise :class:`ConfigError` naming the
field. There are no exceptions: a new config class that checks its numbers by hand fails.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import math
import re
from pathlib import Path

import pytest

from protocols.config import Bounds, ConfigError, bounded, check_fields, field_bounds

pytestmark = pytest.mark.contracts

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("companion", "plant_sim", "protocols", "evaluation")
SUFFIXES = ("Config", "Params", "Settings", "Rules", "Timings")


def _required(name: str) -> dict:
    """Values for the fields without a default (what a process builds from its CLI)."""
    from companion.camera.config import SourceConfig, SourceKind
    from plant_sim.autopilot.link import parse_endpoint
    from plant_sim.scenario import Scenario

    return {
        "plant_sim.service:PlantConfig": {
            "scenario": Scenario(),
            "mavlink": (parse_endpoint("udpin:127.0.0.1:14550"),),
        },
        "plant_sim.camera_only:CameraOnlyConfig": {
            "scenario": Scenario(),
            "pose_from": "udpin:127.0.0.1:14550",
        },
        "companion.link.takeoff:TakeoffSettings": {"alt_m": 7.0},
        "companion.camera.config:SourceConfig": {"kind": SourceKind.REPLAY},
        "companion.camera.config:CameraConfig": {"source": SourceConfig(SourceKind.REPLAY)},
    }.get(name, {})


def _discover() -> list[str]:
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            for node in tree.body:
                if (
                    isinstance(node, ast.ClassDef)
                    and node.name.endswith(SUFFIXES)
                    and any("dataclass" in ast.unparse(d) for d in node.decorator_list)
                ):
                    found.append(f"{module}:{node.name}")
    return found


CLASSES = _discover()


def _load(name: str) -> type:
    module, cls = name.split(":")
    return getattr(importlib.import_module(module), cls)


def _numeric_fields(cls: type) -> list[str]:
    """Fields annotated ``int`` or ``float`` (alone or ``| None``)."""
    out = []
    for f in dataclasses.fields(cls):
        text = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        if re.fullmatch(r"(int|float)( \| None)?", text.strip()):
            out.append(f.name)
    return out


def _outside(spec: Bounds):
    """A value each bound refuses (one per side that has one), and a wrong type."""
    if spec.ge is not None:
        yield spec.ge - 1 if spec.integer else spec.ge - abs(spec.ge) * 1e-6 - 1e-9
    if spec.gt is not None:
        yield int(spec.gt) if spec.integer and spec.gt == int(spec.gt) else spec.gt
    if spec.le is not None:
        yield spec.le + 1 if spec.integer else spec.le + abs(spec.le) * 1e-6 + 1e-9
    if spec.lt is not None:
        yield int(spec.lt) if spec.integer and spec.lt == int(spec.lt) else spec.lt
    yield math.nan
    yield "1"
    if spec.integer:
        yield 2.5


def test_discovery_finds_the_configs_and_the_exceptions_exist():
    assert "companion.config:LinkConfig" in CLASSES
    assert "companion.perception:PerceptionConfig" in CLASSES
    assert "companion.guidance.config:GuidanceConfig" in CLASSES
    assert "plant_sim.autopilot.px4:Px4Rules" in CLASSES


@pytest.mark.parametrize("name", CLASSES)
def test_every_numeric_field_is_declared_and_checked(name):
    cls = _load(name)
    specs = field_bounds(cls)
    undeclared = sorted(set(_numeric_fields(cls)) - set(specs))
    assert not undeclared, f"{name}: declare these with bounded(): {undeclared}"
    required = _required(name)
    cls(**required)  # the defaults are within their bounds
    for field, spec in specs.items():
        for bad in _outside(spec):
            with pytest.raises(ConfigError) as err:
                cls(**{**required, field: bad})
            assert err.value.key == field, (field, bad, str(err.value))


def test_bounds_read_as_words_and_refuse_what_they_say():
    @dataclasses.dataclass(frozen=True)
    class Example:
        rate_hz: float = bounded(50.0, "Hz", gt=0)
        system_id: int = bounded(1, integer=True, ge=1, le=255)
        sigma_px: float | None = bounded(None, "px", ge=0, optional=True)
        far_m: float = bounded(math.inf, "m", gt=0, finite=False)

        def __post_init__(self) -> None:
            check_fields(self)

    assert field_bounds(Example)["system_id"].describe() == "an integer in [1, 255]"
    assert field_bounds(Example)["rate_hz"].describe() == "a finite number > 0 Hz"
    with pytest.raises(ConfigError, match=r"^system_id: must be an integer in \[1, 255\], got 0$"):
        Example(system_id=0)
    with pytest.raises(ConfigError, match="system_id"):
        Example(system_id=True)  # a bool is not an integer
    with pytest.raises(ConfigError, match="far_m"):
        Example(far_m=math.nan)  # +inf allowed, NaN never
    assert Example(far_m=math.inf).far_m == math.inf
    assert Example(sigma_px=1).sigma_px == 1.0 and isinstance(Example(rate_hz=5).rate_hz, float)
    with pytest.raises(ValueError, match="outside its own bounds"):
        bounded(-1.0, "m", ge=0)


def test_a_scenario_file_error_names_the_file_the_key_and_the_bound(tmp_path):
    from plant_sim.scenario import load_scenario

    path = tmp_path / "scene.toml"
    for text, message in (
        (
            "[failsafe]\nland_speed_mps = 0\n",
            r"failsafe\.land_speed_mps: must be a finite number > 0 m/s",
        ),
        ("[camera]\nrate_hz = -30\n", r"camera\.rate_hz: must be a finite number > 0 Hz"),
        ("[start]\nyaw_deg = nan\n", r"start\.yaw_deg: must be a finite number \[deg\], got nan"),
    ):
        path.write_text(text, encoding="utf-8")
        with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}: {message}"):
            load_scenario(path)


@pytest.mark.parametrize(
    ("name", "kwargs", "key"),
    [
        ("companion.guidance.config:GuidanceConfig", {"confirm_n": 3, "confirm_m": 2}, "confirm_n"),
        (
            "companion.guidance.config:GuidanceConfig",
            {"min_setpoint_distance_m": 5.0, "max_setpoint_distance_m": 4.0},
            "max_setpoint_distance_m",
        ),
        (
            "companion.link.takeoff:TakeoffSettings",
            {"alt_m": 1.0, "tolerance_m": 1.0},
            "tolerance_m",
        ),
        ("companion.camera.config:CameraConfig", {"alpha": -0.5}, "alpha"),
        ("plant_sim.depth_camera:DepthNoiseParams", {"max_range_m": 1.0}, "max_range_m"),
        (
            "plant_sim.depth_camera:DepthNoiseParams",
            {"max_range_m": 70.0, "depth_scale_m": 0.001},
            "max_range_m",
        ),
    ],
)
def test_a_rule_between_fields_names_the_field_it_refuses(name, kwargs, key):
    """What one field's bounds cannot say (an order between two fields, a gap in a range,
    a product that must fit 16 bits) stays in the class, and its error is keyed the same
    way (the loader then prefixes the section and the file)."""
    cls = _load(name)
    with pytest.raises(ConfigError) as err:
        cls(**{**_required(name), **kwargs})
    assert err.value.key == key, str(err.value)


def test_a_companion_file_error_names_the_file_the_guidance_key_and_the_bound(tmp_path):
    from companion.config import build_parser, config_from_args

    path = tmp_path / "companion.toml"
    for text, message in (
        ("[guidance]\nn_candidates = 0\n", r"guidance\.n_candidates: must be an integer >= 1"),
        (
            "[guidance]\ndetour_reach_step_m = 0\n",
            r"guidance\.detour_reach_step_m: must be a finite number > 0 m",
        ),
        ("[guidance]\nconfirm_n = 4\n", r"guidance\.confirm_n: must be <= confirm_m \(3\), got 4"),
    ):
        path.write_text(text, encoding="utf-8")
        args = build_parser().parse_args(["--config", str(path)])
        with pytest.raises(ConfigError, match=f"^{re.escape(str(path))}: {message}"):
            config_from_args(args, environ={})
