"""Recording and viewing on a real SIL flight: plant-sim and the companion as processes.

1. ``companion --record FILE.mcap --rerun FILE.rrd`` during a short SIL flight toward the
   paper's obstacle; ``stereo-avoid replay FILE.mcap`` must reproduce every setpoint bit
   for bit, and the .rrd must hold the scene's entities, one depth map per frame.
2. ``companion --rerun serve:PORT`` during a SIL flight, opened in headless Chromium: a
   screenshot must show the 3-D view and the depth image drawn (colourful, non-blank
   regions). ``STEREO_AVOID_SCREENSHOT=PATH`` keeps the screenshot (README picture).
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import time

import pytest
from _chromium import Browser, colourful_fraction, ink_fraction
from _plant_sim_proc import free_port

from companion.record.replay import replay
from plant_sim.lockstep.sil import ChildProcess

pytestmark = pytest.mark.slow

# the 3-D view (left three fifths: anything drawn on its background, > 0.8 % of it; the
# viewer's loading screen is 0.3 %) and the depth panel (right column, middle: colour-mapped
# depth, > 10 %), as fractions
# of the 1280×720 page laid out by companion.viz.rerun_log.blueprint
BOX_3D = (0.02, 0.10, 0.58, 0.90)
BOX_DEPTH = (0.62, 0.40, 0.98, 0.60)


# the paper's scene, started 4 m closer (surface 4.5 m ahead): avoidance within seconds
SCENARIO = """
vehicle_id = "sim1"
goal_ned_m = [0.0, 0.0, -7.0]
[start]
pos_ned_m = [16.0, 0.0, -7.0]
yaw_deg = 180.0
airborne = true
mode = "GUIDED"
[[obstacles]]
center_ned_m = [10.0, 0.0, -7.0]
radius_m = 1.5
[ground]
down_m = 0.0
"""


def _start_sil(children, companion_args, speedup, tmp_path):
    """plant-sim (:data:`SCENARIO`) and the companion on loopback; returns the companion."""
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(SCENARIO)
    mav_port = free_port()
    zen = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    companion = ChildProcess(
        "companion",
        "companion",
        ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", zen, *companion_args],
    )
    children.append(companion)
    companion.wait_line(r"^COMPANION READY ", 60)
    plant = ChildProcess(
        "plant-sim",
        "plant_sim",
        ["--mavlink", f"udpin:127.0.0.1:{mav_port}", "--zenoh-connect", zen,
         "--speedup", f"{speedup:g}", "--log-dir", str(tmp_path),
         "--scenario", str(scenario)],
    )  # fmt: skip
    children.append(plant)
    plant.wait_line(r"^PLANT_SIM READY ", 60)
    companion.wait_line(r"^COMPANION EVENT steering ", 60)
    return companion


def _stop(children) -> None:
    for child in reversed(children):
        child.stop()
    for child in children:
        child.close()


def test_sil_recording_replays_bit_for_bit_and_rerun_file_has_the_scene(tmp_path):
    mcap, rrd = tmp_path / "flight.mcap", tmp_path / "flight.rrd"
    children: list[ChildProcess] = []
    try:
        companion = _start_sil(
            children, ("--record", str(mcap), "--rerun", str(rrd)), 4.0, tmp_path
        )
        # fly into the avoidance (the obstacle comes within 4 m), a little more, stop
        companion.wait_line(r"^COMPANION EVENT avoidance .*\"active\": true", 40)
        time.sleep(1.0)
        companion.stop()
        stats = companion.stats("COMPANION STATS ")
        log = companion.stderr_text()
    except BaseException:
        print("\n".join(c.logs() for c in children))
        raise
    finally:
        _stop(children)
    assert stats is not None and stats["frames_processed"] > 50, stats
    assert "'dropped': 0" in log and "'write_errors': 0" in log, log[-3000:]

    replayed = replay(mcap)
    assert replayed.identical, replayed.summary()
    assert replayed.frames_replayed == stats["frames_processed"]
    # every setpoint a frame put on the wire was compared (keep-alive re-sends are extra)
    assert 0 < replayed.setpoints_on_wire <= stats["setpoints_sent"]
    assert replayed.pose_source == "telemetry"

    from rerun.chunk import RrdReader

    chunks = RrdReader(rrd).store().stream().to_chunks()
    entities = {c.entity_path for c in chunks}
    for entity in (
        "/world/vehicle",
        "/world/vehicle/camera/image",
        "/world/vehicle/camera/depth",
        "/world/vehicle/camera/classes",
        "/world/obstacle_points",
        "/world/tracks",
        "/world/cones",
        "/world/aiming_point",
        "/world/setpoint",
        "/world/goal",
        "/world/known_space",
        "/status/avoidance_flag",
    ):
        assert entity in entities, (entity, sorted(entities))

    def rows(entity: str) -> int:
        return sum(c.num_rows for c in chunks if c.entity_path == entity and not c.is_static)

    # every processed frame is logged, counted as skipped (the view lags) or decimated
    # (at most 10 frames per second of capture time from a 30 Hz camera)
    found = re.search(
        r"Rerun view closed: (\d+) frames logged, (\d+) skipped, (\d+) decimated", log
    )
    logged, skipped, decimated = map(int, found.groups())
    assert logged + skipped + decimated == stats["frames_processed"]
    assert 0 < logged <= stats["frames_processed"] // 2
    assert rows("/world/vehicle") == rows("/world/setpoint") == logged
    assert rows("/world/vehicle/camera/depth") == rows("/world/vehicle/camera/image") == logged


def _two_free_tcp_ports() -> int:
    """A port p with p + 1 also free (Rerun: web viewer on p, gRPC on p + 1)."""
    for _ in range(50):
        p = free_port(socket.SOCK_STREAM)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", p + 1))
            except OSError:
                continue
        return p
    raise RuntimeError("no two adjacent free TCP ports")


def test_live_web_view_in_headless_chromium_during_sil(tmp_path):
    web = _two_free_tcp_ports()
    children: list[ChildProcess] = []
    browser = None
    try:
        _start_sil(children, ("--rerun", f"serve:{web}"), 1.0, tmp_path)
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{web + 1}%2Fproxy"
        browser = Browser(url, free_port(socket.SOCK_STREAM))
        deadline = time.monotonic() + 150.0  # software rendering compiles the viewer slowly
        shot, drawn = _blank_png(), (0.0, 0.0)
        while time.monotonic() < deadline:
            time.sleep(3.0)
            got = browser.screenshot()
            if got is None:
                continue
            shot = got
            drawn = (ink_fraction(shot, BOX_3D), colourful_fraction(shot, BOX_DEPTH))
            if drawn[0] > 0.008 and drawn[1] > 0.10:
                break
        (tmp_path / "web_view.png").write_bytes(shot)
        keep = os.environ.get("STEREO_AVOID_SCREENSHOT")
        if keep:
            shutil.copy(tmp_path / "web_view.png", keep)
        assert drawn[0] > 0.008, f"3-D view blank ({drawn}); {tmp_path / 'web_view.png'}\n" + (
            "\n".join(c.logs() for c in children)
        )
        assert drawn[1] > 0.10, f"depth image blank ({drawn}); {tmp_path / 'web_view.png'}"
        # and blank before: the same measure on an empty page is zero
        assert ink_fraction(_blank_png(), BOX_3D) == colourful_fraction(_blank_png(), BOX_3D) == 0
    finally:
        if browser is not None:
            browser.close()
        _stop(children)


def _blank_png() -> bytes:
    import cv2
    import numpy as np

    ok, buf = cv2.imencode(".png", np.full((720, 1280, 3), 20, np.uint8))
    assert ok
    return buf.tobytes()
