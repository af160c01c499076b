"""Picture in docs/viewing.md: the Rerun web view of the paper's scenario, mid-avoidance.

Flies the paper's §6 scene in lockstep with ``--rerun serve`` (the pipeline's view plus the
true world; logged from ``--log-from-north-m`` on), stops ``--after-avoid-s`` seconds into
the avoidance, opens the web viewer in headless Chromium (``tests/_chromium.py``) and saves
a 1280×720 screenshot once the 3-D view and the depth image are drawn and the viewer had
``--settle-s`` to take in the stream.

Usage: ``.venv/bin/python scripts/rerun_pictures.py [--out docs/figures/rerun_paper.png]``
"""

from __future__ import annotations

import argparse
import contextlib
import socket
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from _chromium import Browser, colourful_fraction, ink_fraction  # noqa: E402

from evaluation.harness import RunConfig, run_scene  # noqa: E402
from evaluation.scenes import paper_scene  # noqa: E402
from evaluation.view import LockstepView  # noqa: E402


class _EnoughFlownError(Exception):
    """Raised from the step hook to end the lockstep run early."""


def _free_pair() -> int:
    for _ in range(50):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
        with socket.socket() as b, socket.socket() as c:
            try:
                b.bind(("127.0.0.1", port))
                c.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
        return port
    raise RuntimeError("no two adjacent free ports")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=REPO / "docs/figures/rerun_paper.png")
    p.add_argument("--after-avoid-s", type=float, default=2.5)
    p.add_argument("--log-from-north-m", type=float, default=17.0, help="log from here on")
    p.add_argument("--settle-s", type=float, default=60.0, help="wait after the first draw")
    args = p.parse_args()
    port = _free_pair()
    scene, cfg = paper_scene(), RunConfig()
    view = LockstepView(f"serve:{port}", scene, cfg)
    avoid_since = None

    def on_step(frame, pose, step, mission) -> None:
        nonlocal avoid_since
        # log only the approach: the software-rendered viewer ingests slowly
        if pose.pos_ned_m[0] < args.log_from_north_m:
            view.on_step(frame, pose, step, mission)
        t = frame.capture_ns * 1e-9
        if step.output.guidance.avoidance_flag and avoid_since is None:
            avoid_since = t
        if avoid_since is not None and t - avoid_since >= args.after_avoid_s:
            raise _EnoughFlownError

    with contextlib.suppress(_EnoughFlownError):
        run_scene(scene, cfg, on_step=on_step)
    view.rec.flush()
    url = f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port + 1}%2Fproxy"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        devtools = s.getsockname()[1]
    browser = Browser(url, devtools)
    try:
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline:
            time.sleep(5.0)
            shot = browser.screenshot()
            if shot is None:
                continue
            drawn = (
                ink_fraction(shot, (0.02, 0.10, 0.58, 0.90)),
                colourful_fraction(shot, (0.62, 0.40, 0.98, 0.60)),
            )
            if drawn[0] > 0.008 and drawn[1] > 0.10:
                # the viewer draws as the recording streams in: give it time to reach the end
                time.sleep(args.settle_s)
                shot = browser.screenshot() or shot
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_bytes(shot)
                print(f"wrote {args.out} (drawn fractions {drawn})")
                return 0
        print("the viewer did not draw within 300 s", file=sys.stderr)
        return 1
    finally:
        browser.close()


if __name__ == "__main__":
    sys.exit(main())
