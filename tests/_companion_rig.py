"""A hovering plant-sim and a companion waiting for frames, its status on a test session.

The rig of the tests in which an outside frame source (``stereo-camera replay`` of image
pairs or of a ROS 2 bag) drives the companion process: plant-sim as the autopilot only
(no camera), the companion with ``--frame-clock host`` (frames stamped with this host's
monotonic clock, mapped to autopilot time with TIMESYNC, as with a real camera), and a
Zenoh subscriber to the companion's status declared before the companion starts (the
companion connects to it, so no status is missed).
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import zenoh
from _plant_sim_proc import free_port

from evaluation.sil import ChildProcess
from protocols.keys import companion_status_key
from protocols.zenoh_session import ZenohSettings, zenoh_config

VEHICLE_ID = "cam"


@dataclass
class CompanionRig:
    """The running rig: where frames go, the children, and the statuses received."""

    companion_zenoh: str
    companion: ChildProcess
    children: list[ChildProcess]
    docs: list[dict] = field(default_factory=list)
    avoiding: threading.Event = field(default_factory=threading.Event)

    def start(self, name: str, module: str, args: Sequence[str]) -> ChildProcess:
        """Start another child (stopped with the rig)."""
        child = ChildProcess(name, module, list(args))
        self.children.append(child)
        return child

    def logs(self) -> str:
        return "\n".join(c.logs() for c in self.children)


@contextlib.contextmanager
def companion_rig(companion_args: Sequence[str] = ()) -> Iterator[CompanionRig]:
    """Start the rig (module docstring); ``companion_args`` are added to the companion's
    command line. Everything is stopped and closed on exit."""
    mav_port = free_port()
    companion_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    test_zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    children: list[ChildProcess] = []
    docs: list[dict] = []
    avoiding = threading.Event()

    def on_status(sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        docs.append(doc)
        if doc["obstacles"] and doc["avoidance_flag"]:
            avoiding.set()

    session = zenoh.open(zenoh_config(ZenohSettings(listen=(test_zenoh,))))
    session.declare_subscriber(companion_status_key(VEHICLE_ID), on_status)
    try:
        plant_args = ["--mavlink", f"udpin:127.0.0.1:{mav_port}", "--no-camera", "--no-logs"]
        plant = ChildProcess("plant-sim", "plant_sim", plant_args)
        children.append(plant)
        plant.wait_line(r"^PLANT_SIM READY ", 60)
        companion = ChildProcess(
            "companion",
            "companion",
            ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", companion_zenoh,
             "--zenoh-connect", test_zenoh, "--vehicle-id", VEHICLE_ID, "--frame-clock", "host",
             *companion_args],
        )  # fmt: skip
        children.append(companion)
        companion.wait_line(r"^COMPANION READY ", 60)
        yield CompanionRig(companion_zenoh, companion, children, docs, avoiding)
    finally:
        session.close()
        for child in reversed(children):
            child.stop()
        for child in children:
            child.close()


def sees_sphere(doc: dict, start_ned_m, sphere) -> str | None:
    """Why the status ``doc``'s obstacles (the known-space map's safety boundaries,
    schema 2) do not show ``sphere`` seen from ``start_ned_m``, or None when they do: the
    true surface point nearest the start lies inside one of the reported spheres, and the
    nearest reported range is the true distance to that surface within 0.3 m (half a
    0.2 m voxel's diagonal plus the matcher's error at 3 m)."""
    import numpy as np

    if doc.get("schema") != 2 or not doc["obstacles"]:
        return f"no schema-2 obstacles in {doc}"
    to_centre = np.subtract(sphere.center_ned_m, start_ned_m)
    distance = float(np.linalg.norm(to_centre)) - sphere.radius_m
    surface = np.asarray(start_ned_m) + to_centre / np.linalg.norm(to_centre) * distance
    obstacles = doc["obstacles"]
    if not any(
        np.linalg.norm(surface - np.asarray(o["center_ned_m"])) <= o["radius_m"] for o in obstacles
    ):
        return f"surface point {surface} outside every reported sphere {obstacles}"
    nearest = min(o["range_m"] for o in obstacles)
    if abs(nearest - distance) > 0.3:
        return f"nearest range {nearest} m, the surface is {distance} m away"
    return None
