"""Recording and viewing on a real SIL flight: plant-sim and the companion as processes.

One flight toward the paper's obstacle with ``companion --record FILE.mcap --rerun
serve:PORT``, the live web view opened in headless Chromium:

1. a screenshot must show the 3-D view and the depth image drawn (colourful, non-blank
   regions); ``STEREO_AVOID_SCREENSHOT=PATH`` keeps it (docs/viewing.md picture);
2. ``stereo-avoid replay FILE.mcap`` must reproduce every MAVLink output of the flight,
   every setpoint included, bit for bit.

The Rerun file sink and what is logged per frame are checked in process
(``test_view_units.py``), on the same observer.
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
from evaluation.sil import ChildProcess

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


def test_sil_flight_live_web_view_and_recording_replays_bit_for_bit(tmp_path):
    mcap = tmp_path / "flight.mcap"
    web = _two_free_tcp_ports()
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(SCENARIO)
    mav_port = free_port()
    zen = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    children: list[ChildProcess] = []
    browser = None
    try:
        companion = ChildProcess(
            "companion",
            "companion",
            ["--mavlink", f"udpout:127.0.0.1:{mav_port}", "--zenoh-listen", zen,
             "--record", str(mcap), "--rerun", f"serve:{web}"],
        )  # fmt: skip
        children.append(companion)
        companion.wait_line(r"^COMPANION READY ", 60)
        # the viewer compiles (software rendering: tens of seconds) while the plant starts
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{web + 1}%2Fproxy"
        browser = Browser(url, free_port(socket.SOCK_STREAM))
        plant = ChildProcess(
            "plant-sim",
            "plant_sim",
            ["--mavlink", f"udpin:127.0.0.1:{mav_port}", "--zenoh-connect", zen,
             "--camera-rate-hz", "10", "--log-dir", str(tmp_path), "--scenario", str(scenario)],
        )  # fmt: skip
        children.append(plant)
        plant.wait_line(r"^PLANT_SIM READY ", 60)
        companion.wait_line(r"^COMPANION EVENT steering ", 60)
        # the obstacle comes within the 4 m threshold within seconds
        companion.wait_line(r"^COMPANION EVENT avoidance .*\"active\": true", 40)
        deadline = time.monotonic() + 150.0
        shot, drawn = _blank_png(), (0.0, 0.0)
        while time.monotonic() < deadline:
            got = browser.screenshot()
            if got is not None:
                shot = got
                drawn = (ink_fraction(shot, BOX_3D), colourful_fraction(shot, BOX_DEPTH))
                if drawn[0] > 0.008 and drawn[1] > 0.10:
                    break
            time.sleep(1.0)
        companion.stop()
        stats = companion.stats("COMPANION STATS ")
        log = companion.stderr_text()
    except BaseException:
        print("\n".join(c.logs() for c in children))
        raise
    finally:
        if browser is not None:
            browser.close()
        _stop(children)
    (tmp_path / "web_view.png").write_bytes(shot)
    keep = os.environ.get("STEREO_AVOID_SCREENSHOT")
    if keep:
        shutil.copy(tmp_path / "web_view.png", keep)
    assert drawn[0] > 0.008, f"3-D view blank ({drawn}); {tmp_path / 'web_view.png'}"
    assert drawn[1] > 0.10, f"depth image blank ({drawn}); {tmp_path / 'web_view.png'}"
    # and on a blank page the same measures are zero
    assert ink_fraction(_blank_png(), BOX_3D) == colourful_fraction(_blank_png(), BOX_3D) == 0

    assert stats is not None and stats["frames_processed"] > 20, stats
    assert "'dropped': 0" in log and "'write_errors': 0" in log, log[-3000:]
    found = re.search(r"Rerun view closed: (\d+) frames logged", log)
    assert found and int(found.group(1)) > 0, log[-3000:]
    processed = []
    replayed = replay(mcap, on_frame=processed.append)
    assert replayed.identical, replayed.summary()
    # the fresh core processed the same frames and sent the same messages (keep-alive
    # re-sends included), every setpoint compared bit for bit
    assert len(processed) == stats["frames_processed"]
    assert replayed.setpoints_compared == stats["setpoints_sent"]
    assert replayed.mavlink_compared == stats["mavlink_sent"]
    assert any(p.step.output.guidance.avoidance_flag for p in processed)


def _stop(children) -> None:
    for child in reversed(children):
        child.stop()
    for child in children:
        child.close()


def _blank_png() -> bytes:
    import cv2
    import numpy as np

    ok, buf = cv2.imencode(".png", np.full((720, 1280, 3), 20, np.uint8))
    assert ok
    return buf.tobytes()
