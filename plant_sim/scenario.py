"""Scenario of a plant-sim run: world, start pose, geodetic anchor, camera, rates, failsafes.

A scenario is a TOML (``tomllib``) or JSON file; every key is optional and defaults to the
paper's §6 scenario (DESIGN.md): start NED (20, 0, −7) hovering in GUIDED facing the goal
(0, 0, −7), one sphere of radius 1.5 m at (10, 0, −7), ground at z = 0. Unknown keys are an
error that names the key (``camera.fps`` → "unknown key 'camera.fps'"). Example::

    vehicle_id = "sim1"
    goal_ned_m = [0.0, 0.0, -7.0]

    [start]
    pos_ned_m = [20.0, 0.0, -7.0]
    yaw_deg = 180.0
    airborne = true          # false: disarmed on the ground below pos_ned_m
    mode = "GUIDED"

    [origin]                 # geodetic position of the LOCAL_NED origin (flat earth)
    lat_deg = 47.397742
    lon_deg = 8.545594
    alt_amsl_m = 488.0

    [[obstacles]]            # shape = "sphere" (default), "box" or "cylinder"
    center_ned_m = [10.0, 0.0, -7.0]
    radius_m = 1.5
    material = "textured"    # or "low_texture", "textureless"

    [[obstacles]]            # a wall across the path
    shape = "box"
    center_ned_m = [5.0, 0.0, -5.0]
    size_m = [0.2, 12.0, 10.0]   # north, east, down extent [m]

    [[obstacles]]            # a pole
    shape = "cylinder"
    center_ned_m = [14.0, 2.0, -5.0]
    radius_m = 0.15
    height_m = 10.0

    [ground]
    down_m = 0.0             # or: ground = false for none

    [camera]
    enabled = true
    rate_hz = 30.0           # simulation time
    width_px = 320
    height_px = 240
    noise_std = 2.0          # sensor noise [grey levels]; image degradations:
    gain_right = 1.0         # right/left gain mismatch
    misrect_v_px = 0.0       # right image shifted down [px]
    blur_h_px = 0.0          # horizontal / vertical motion blur length [px]
    blur_v_px = 0.0
    jpeg_quality = 0         # 1..100 compresses both images; 0 = off
    encoding = "mono8"       # "depth16" / "depth32f": a RealSense-like depth camera
    [camera.depth]           # its errors: plant_sim.depth_camera.DepthNoiseParams fields
    subpixel_rms_px = 0.08   # disparity error [px]: depth error grows with z^2
    min_range_m = 1.0        # nearer, farther, at depth edges: no data (0)
    max_range_m = 30.0

    [streams]                # default rates [Hz of simulation time]; 0 = off
    LOCAL_POSITION_NED = 4.0

    [failsafe]
    guided_velocity_timeout_s = 3.0

    [disturbance]            # plant_sim.disturbance: all optional, default none
    seed = 0
    [disturbance.wind]       # steady wind + Gauss-Markov gusts, LOCAL_NED
    mean_ned_mps = [0.3, 0.0, 0.0]
    gust_std_mps = 0.1
    gust_tau_s = 2.0
    [disturbance.estimate]   # the reported position wanders from the truth (GPS-like)
    wander_std_m = 0.2
    wander_tau_s = 30.0
    drift_ned_mps = [0.0, 0.0, 0.0]
    jump_m = 0.5
    jump_every_s = 60.0
    stated_floor_m = 0.3     # GPS_RAW_INT h_acc/v_acc at least this (SITL: SIM_GPS_ACC 0.3)

    profile = "paper"        # plant_sim.profiles: "paper" (default) or "fast"
    [vehicle]                # plant_sim.params.QuadrotorParams overrides (of the profile)
    [control]                # plant_sim.params.ControlParams overrides (of the profile)

Pure: :func:`load_scenario` reads one file; :func:`scenario_from_dict` does the rest.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant_sim.autopilot.modes import FlightMode
from plant_sim.depth_camera import CameraEncoding, DepthNoiseParams
from plant_sim.disturbance import DisturbanceConfig, EstimateConfig, WindConfig
from plant_sim.params import ControlParams, QuadrotorParams, from_dict
from plant_sim.profiles import profile
from plant_sim.stereo_camera import RenderParams
from plant_sim.world import Box, Cylinder, GroundPlane, Material, Sphere, World, paper_world
from protocols.camera import CameraModel
from protocols.config import (
    Checked,
    ConfigError,
    bounded,
    check_keys,
    dataclass_from_mapping,
    vec3,
)
from protocols.keys import validate_vehicle_id

__all__ = [
    "DEFAULT_STREAM_RATES_HZ",
    "CameraConfig",
    "FailsafeConfig",
    "GeoOrigin",
    "Scenario",
    "ScenarioError",
    "StartConfig",
    "load_scenario",
    "paper_scenario",
    "read_scenario_data",
    "scenario_from_dict",
]

#: Streams sent without any request, and their rates [Hz of simulation time]. HEARTBEAT is
#: not here: it is always 1 Hz of wall time (DESIGN.md).
DEFAULT_STREAM_RATES_HZ: dict[str, float] = {
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "HOME_POSITION": 0.5,
    "GPS_RAW_INT": 1.0,
    "SYSTEM_TIME": 1.0,
    "GLOBAL_POSITION_INT": 4.0,
    "LOCAL_POSITION_NED": 4.0,
    "ATTITUDE": 4.0,
    "POSITION_TARGET_LOCAL_NED": 4.0,
}


#: a scenario file or mapping is invalid (the message names the file and the key)
ScenarioError = ConfigError


@dataclass(frozen=True)
class StartConfig(Checked):
    """Initial state of the vehicle."""

    pos_ned_m: tuple[float, float, float] = (20.0, 0.0, -7.0)  # LOCAL_NED [m]
    # heading, 180 = facing south, towards the paper's goal
    yaw_deg: float = bounded(180.0, "deg")
    airborne: bool = True  # True: armed, hovering at pos; False: disarmed on the ground below
    mode: FlightMode = FlightMode.GUIDED


@dataclass(frozen=True)
class GeoOrigin:
    """Geodetic position of the LOCAL_NED origin (flat-earth conversion around it)."""

    lat_deg: float = 47.397742  # [deg] (PX4/ArduPilot SITL default site, Zurich)
    lon_deg: float = 8.545594  # [deg]
    alt_amsl_m: float = 488.0  # [m] above mean sea level


@dataclass(frozen=True)
class CameraConfig(Checked):
    """Camera: model (Table 1), frame rate, rendering, and what it publishes: a stereo pair
    (``mono8``) or, as a RealSense-like depth camera, depth frames (``depth16``,
    ``depth32f``) with the errors of ``depth`` (plant_sim.depth_camera)."""

    enabled: bool = True
    rate_hz: float = bounded(30.0, "Hz", gt=0)  # frames per second of simulation time
    model: CameraModel = field(default_factory=CameraModel)
    render: RenderParams = field(default_factory=RenderParams)
    encoding: CameraEncoding = CameraEncoding.MONO8
    depth: DepthNoiseParams = field(default_factory=DepthNoiseParams)


@dataclass(frozen=True)
class FailsafeConfig(Checked):
    """Autopilot timeouts and speeds (defaults: ArduCopter's parameter defaults)."""

    # GUID_TIMEOUT: velocity targets expire [s sim]
    guided_velocity_timeout_s: float = bounded(3.0, "s", gt=0)
    # DISARM_DELAY: auto-disarm when landed and idle [s sim]
    disarm_delay_s: float = bounded(10.0, "s", gt=0)
    land_speed_mps: float = bounded(0.5, "m/s", gt=0)  # LAND_SPEED 50 cm/s
    takeoff_climb_mps: float = bounded(1.5, "m/s", gt=0)  # climb rate of NAV_TAKEOFF
    # RTL_ALT 1500 cm: minimum return altitude above home
    rtl_alt_m: float = bounded(15.0, "m", gt=0)
    land_detect_s: float = bounded(1.0, "s", gt=0)  # on the ground this long → landed [s sim]


@dataclass(frozen=True)
class Scenario:
    """Everything a plant-sim run needs besides the network settings."""

    vehicle_id: str = "sim1"
    start: StartConfig = field(default_factory=StartConfig)
    goal_ned_m: tuple[float, float, float] | None = (0.0, 0.0, -7.0)  # for logs and verdicts
    origin: GeoOrigin = field(default_factory=GeoOrigin)
    world: World = field(default_factory=paper_world)
    camera: CameraConfig = field(default_factory=CameraConfig)
    stream_rates_hz: tuple[tuple[str, float], ...] = tuple(DEFAULT_STREAM_RATES_HZ.items())
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)
    disturbance: DisturbanceConfig = field(default_factory=DisturbanceConfig)
    vehicle: QuadrotorParams = field(default_factory=QuadrotorParams)
    control: ControlParams = field(default_factory=ControlParams)

    @property
    def ground_down_m(self) -> float | None:
        """NED down coordinate of the ground, or None without ground."""
        return None if self.world.ground is None else self.world.ground.down_m


def paper_scenario() -> Scenario:
    """The paper's §6 scenario with the defaults above."""
    return Scenario()


# ---- parsing -------------------------------------------------------------------------


def _number(value: Any, where: str, *, positive: bool = False, minimum: float | None = None):
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ScenarioError(f"{where} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(f"{where} must be > 0, got {value!r}")
    if minimum is not None and value < minimum:
        raise ScenarioError(f"{where} must be >= {minimum}, got {value!r}")
    return float(value)


def _bool(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise ScenarioError(f"{where} must be true or false, got {value!r}")
    return value


def _dataclass_fields(cls) -> set[str]:
    return set(cls.__dataclass_fields__)


def _start(d: Any) -> StartConfig:
    d = check_keys(d, _dataclass_fields(StartConfig), "start")
    kw: dict[str, Any] = {}
    if "pos_ned_m" in d:
        kw["pos_ned_m"] = vec3(d["pos_ned_m"], "start.pos_ned_m")
    if "yaw_deg" in d:
        kw["yaw_deg"] = d["yaw_deg"]  # checked by StartConfig's declaration
    if "airborne" in d:
        kw["airborne"] = _bool(d["airborne"], "start.airborne")
    if "mode" in d:
        try:
            kw["mode"] = FlightMode[str(d["mode"]).upper()]
        except KeyError:
            raise ScenarioError(
                f"start.mode {d['mode']!r} is not one of {[m.name for m in FlightMode]}"
            ) from None
    return dataclass_from_mapping(StartConfig, kw, "start")


def _origin(d: Any) -> GeoOrigin:
    d = check_keys(d, _dataclass_fields(GeoOrigin), "origin")
    kw = {k: _number(v, f"origin.{k}") for k, v in d.items()}
    if not -90.0 < kw.get("lat_deg", 0.0) < 90.0:
        raise ScenarioError(f"origin.lat_deg must be in (-90, 90), got {kw['lat_deg']}")
    if not -180.0 <= kw.get("lon_deg", 0.0) <= 180.0:
        raise ScenarioError(f"origin.lon_deg must be in [-180, 180], got {kw['lon_deg']}")
    return GeoOrigin(**kw)


_SHAPE_KEYS = {
    "sphere": {"center_ned_m", "radius_m"},
    "box": {"center_ned_m", "size_m"},
    "cylinder": {"center_ned_m", "radius_m", "height_m"},
}


def _obstacles(items: Any) -> tuple[tuple[Sphere, ...], tuple[Box, ...], tuple[Cylinder, ...]]:
    """Obstacle tables → (spheres, boxes, cylinders); ``shape`` defaults to ``"sphere"``."""
    if not isinstance(items, list):
        raise ScenarioError(f"obstacles must be a list of tables, got {items!r}")
    shapes: dict[str, list] = {"sphere": [], "box": [], "cylinder": []}
    for i, item in enumerate(items):
        where = f"obstacles[{i}]"
        if not isinstance(item, Mapping):
            raise ScenarioError(f"{where} must be a table/object, got {item!r}")
        shape = item.get("shape", "sphere")
        if shape not in _SHAPE_KEYS:
            raise ScenarioError(f"{where}.shape {shape!r} is not one of {sorted(_SHAPE_KEYS)}")
        required = _SHAPE_KEYS[shape]
        item = check_keys(item, required | {"shape", "texture_seed", "material"}, where)
        for name in sorted(required):
            if name not in item:
                raise ScenarioError(f"{where}.{name} is required for a {shape}")
        try:
            material = Material(item.get("material", "textured"))
        except ValueError:
            raise ScenarioError(
                f"{where}.material {item['material']!r} is not one of {[m.value for m in Material]}"
            ) from None
        kw: dict[str, Any] = {
            "center_ned_m": vec3(item["center_ned_m"], f"{where}.center_ned_m"),
            "texture_seed": int(item.get("texture_seed", i)),
            "material": material,
        }
        for name in ("radius_m", "height_m"):
            if name in required:
                kw[name] = _number(item[name], f"{where}.{name}", positive=True)
        if shape == "box":
            size = vec3(item["size_m"], f"{where}.size_m")
            if min(size) <= 0.0:
                raise ScenarioError(f"{where}.size_m must be positive, got {list(size)}")
            kw["size_m"] = size
        shapes[shape].append({"sphere": Sphere, "box": Box, "cylinder": Cylinder}[shape](**kw))
    return tuple(shapes["sphere"]), tuple(shapes["box"]), tuple(shapes["cylinder"])


def _ground(value: Any) -> GroundPlane | None:
    if value is False:
        return None
    if value is True:
        return GroundPlane()
    d = check_keys(value, {"down_m", "texture_seed"}, "ground")
    return GroundPlane(
        down_m=_number(d.get("down_m", 0.0), "ground.down_m"),
        texture_seed=int(d.get("texture_seed", 1)),
    )


_CAMERA_MODEL_KEYS = _dataclass_fields(CameraModel)
_RENDER_KEYS = _dataclass_fields(RenderParams)


def _camera_encoding(value: Any) -> CameraEncoding:
    try:
        return CameraEncoding(value)
    except ValueError:
        raise ScenarioError(
            f"camera.encoding must be one of {[e.value for e in CameraEncoding]}, got {value!r}"
        ) from None


def _camera(d: Any) -> CameraConfig:
    d = check_keys(
        d,
        {"enabled", "rate_hz", "encoding", "depth"} | _CAMERA_MODEL_KEYS | _RENDER_KEYS,
        "camera",
    )
    model_kw = {k: d[k] for k in _CAMERA_MODEL_KEYS if k in d}
    render_kw = {k: d[k] for k in _RENDER_KEYS if k in d}
    depth_kw = check_keys(d.get("depth", {}), _dataclass_fields(DepthNoiseParams), "camera.depth")
    try:
        model = CameraModel(**model_kw)
        render = RenderParams(**render_kw)
        depth = DepthNoiseParams(**depth_kw)
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f"camera: {exc}") from None
    fields = {
        "enabled": _bool(d.get("enabled", True), "camera.enabled"),
        "rate_hz": d.get("rate_hz", 30.0),  # checked by CameraConfig's declaration
        "model": model,
        "render": render,
        "encoding": _camera_encoding(d.get("encoding", "mono8")),
        "depth": depth,
    }
    return dataclass_from_mapping(CameraConfig, fields, "camera")


def _streams(d: Any) -> tuple[tuple[str, float], ...]:
    d = check_keys(d, set(DEFAULT_STREAM_RATES_HZ), "streams")
    rates = dict(DEFAULT_STREAM_RATES_HZ)
    for name, value in d.items():
        rates[name] = _number(value, f"streams.{name}", minimum=0.0)
    return tuple(rates.items())


def _failsafe(d: Any) -> FailsafeConfig:
    d = check_keys(d, _dataclass_fields(FailsafeConfig), "failsafe")
    return dataclass_from_mapping(FailsafeConfig, d, "failsafe")


def _disturbance(d: Any) -> DisturbanceConfig:
    """``[disturbance]``: ``seed``, ``[disturbance.wind]``, ``[disturbance.estimate]``
    (:mod:`plant_sim.disturbance`; every field optional, unknown keys named)."""
    d = check_keys(d, {"seed", "wind", "estimate"}, "disturbance")
    parts: dict[str, Any] = {"seed": d["seed"]} if "seed" in d else {}
    for name, cls in (("wind", WindConfig), ("estimate", EstimateConfig)):
        if name in d:
            inf = {"jump_every_s": _inf_or_value}
            parts[name] = dataclass_from_mapping(cls, d[name], f"disturbance.{name}", inf)
    return dataclass_from_mapping(DisturbanceConfig, parts, "disturbance")


def _inf_or_value(value: Any) -> Any:
    """``"inf"`` (a TOML string some files use) as ``math.inf``; anything else as is."""
    return math.inf if value == "inf" else value


_TOP_KEYS = {
    "vehicle_id",
    "start",
    "goal_ned_m",
    "origin",
    "obstacles",
    "ground",
    "camera",
    "streams",
    "failsafe",
    "disturbance",
    "vehicle",
    "control",
    "profile",
}


def scenario_from_dict(d: Mapping[str, Any]) -> Scenario:
    """Build a :class:`Scenario` from a parsed file; missing keys keep the paper's values.

    Raises
    ------
    ScenarioError
        On an unknown key (named with its section) or an invalid value.
    """
    d = check_keys(d, _TOP_KEYS, "")
    kw: dict[str, Any] = {}
    if "vehicle_id" in d:
        try:
            kw["vehicle_id"] = validate_vehicle_id(d["vehicle_id"])
        except ValueError as exc:
            raise ScenarioError(str(exc)) from None
    if "start" in d:
        kw["start"] = _start(d["start"])
    if "goal_ned_m" in d:
        goal = d["goal_ned_m"]
        kw["goal_ned_m"] = None if goal is False else vec3(goal, "goal_ned_m")
    if "origin" in d:
        kw["origin"] = _origin(d["origin"])
    default_world = paper_world()
    if "obstacles" in d:
        spheres, boxes, cylinders = _obstacles(d["obstacles"])
    else:
        spheres, boxes, cylinders = default_world.spheres, (), ()
    ground = _ground(d["ground"]) if "ground" in d else default_world.ground
    kw["world"] = World(spheres=spheres, ground=ground, boxes=boxes, cylinders=cylinders)
    if "camera" in d:
        kw["camera"] = _camera(d["camera"])
    if "streams" in d:
        kw["stream_rates_hz"] = _streams(d["streams"])
    if "failsafe" in d:
        kw["failsafe"] = _failsafe(d["failsafe"])
    if "disturbance" in d:
        kw["disturbance"] = _disturbance(d["disturbance"])
    try:
        base = profile(str(d.get("profile", "paper")))
    except ValueError as exc:
        raise ScenarioError(f"profile: {exc}") from None
    kw["vehicle"], kw["control"] = base.vehicle, base.control
    for section, cls in (("vehicle", QuadrotorParams), ("control", ControlParams)):
        if section in d:
            try:
                overrides = check_keys(d[section], set(d[section]), section)
                kw[section] = from_dict(cls, {**dataclasses.asdict(kw[section]), **dict(overrides)})
            except (TypeError, ValueError) as exc:
                raise ScenarioError(f"{section}: {exc}") from None
    scenario = Scenario(**kw)
    ground_down = scenario.ground_down_m
    if ground_down is not None and scenario.start.pos_ned_m[2] > ground_down:
        raise ScenarioError(
            f"start.pos_ned_m {scenario.start.pos_ned_m} is below the ground (down_m = "
            f"{ground_down})"
        )
    if not scenario.start.airborne and ground_down is None:
        raise ScenarioError("start.airborne = false needs a ground")
    return scenario


def read_scenario_data(path: str | Path) -> dict[str, Any]:
    """The parsed content of a ``.toml`` or ``.json`` scenario file, not yet checked.

    Raises
    ------
    ScenarioError
        If the file cannot be read or parsed, or is not a table of keys.
    """
    path = Path(path)
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario {path}: {exc}") from None
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            data = tomllib.loads(text.decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"cannot parse scenario {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{path}: a scenario is a table of keys, got {type(data).__name__}")
    return data


def load_scenario(path: str | Path) -> Scenario:
    """Read a ``.toml`` or ``.json`` scenario file.

    Raises
    ------
    ScenarioError
        If the file cannot be parsed or holds an invalid scenario (the message names the
        file and the key).
    """
    data = read_scenario_data(path)
    try:
        return scenario_from_dict(data)
    except ScenarioError as exc:
        raise exc.in_file(path) from None
