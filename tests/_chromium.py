"""Headless Chromium for the web-view test: start, screenshot over DevTools, judge regions.

Chromium is Debian's ``chromium`` package (``scripts/setup.sh`` installs it when missing);
the DevTools protocol is spoken with ``websocket-client``. Rendering is software
(SwiftShader), so the Rerun viewer takes tens of seconds to compile and draw: callers poll
:func:`Browser.screenshot` until :func:`colourful_fraction` says the panels are drawn.
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request

import cv2
import numpy as np

__all__ = ["Browser", "chromium_path", "colourful_fraction", "ink_fraction"]


def chromium_path() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise RuntimeError(
        "no Chromium on PATH: run scripts/setup.sh (installs Debian's chromium package)"
    )


def colourful_fraction(png: bytes, box: tuple[float, float, float, float]) -> float:
    """Fraction of saturated, lit pixels (HSV S > 90, V > 60) in ``box`` = (x0, y0, x1, y1)
    as fractions of the image: drawn data (points, spheres, colour-mapped depth) rather than
    the viewer's grey chrome, grid and empty background."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    h, w = image.shape[:2]
    x0, y0, x1, y1 = box
    crop = image[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w)]
    hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
    return float(np.mean((hsv[..., 1] > 90) & (hsv[..., 2] > 60)))


def ink_fraction(png: bytes, box: tuple[float, float, float, float]) -> float:
    """Fraction of pixels in ``box`` that differ clearly (sum of |ΔRGB| > 150) from the
    region's most common colour (its background): drawn things of any colour, not the
    faint grid of an empty 3-D view nor a uniform loading screen."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    h, w = image.shape[:2]
    x0, y0, x1, y1 = box
    crop = image[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w)].reshape(-1, 3)
    values, counts = np.unique(crop, axis=0, return_counts=True)
    background = values[counts.argmax()].astype(int)
    return float(np.mean(np.abs(crop.astype(int) - background).sum(axis=1) > 150))


class Browser:
    """One headless Chromium page on ``url``, driven over the DevTools protocol."""

    def __init__(self, url: str, port: int, width: int = 1280, height: int = 720) -> None:
        import websocket

        self._profile = tempfile.mkdtemp(prefix="chromium-")
        self.proc = subprocess.Popen(
            [
                chromium_path(),
                "--headless=new",
                "--no-sandbox",  # root in containers and CI
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                f"--window-size={width},{height}",
                f"--remote-debugging-port={port}",
                "--remote-allow-origins=*",
                f"--user-data-dir={self._profile}",
                "--no-first-run",
                url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 30.0
        page = None
        while page is None:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError(f"Chromium did not open DevTools on port {port}")
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=1) as r:
                    tabs = json.loads(r.read())
                page = next((t for t in tabs if t.get("type") == "page"), None)
            except OSError:
                time.sleep(0.2)
        # a screenshot waits for a drawn frame: long while the viewer compiles (software GL)
        self._ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=60)
        self._id = 0
        self._call(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
        )

    def _call(self, method: str, params: dict | None = None) -> dict:
        self._id += 1
        self._ws.send(json.dumps({"id": self._id, "method": method, "params": params or {}}))
        while True:
            reply = json.loads(self._ws.recv())
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"DevTools {method}: {reply['error']}")
                return reply["result"]

    def screenshot(self) -> bytes | None:
        """The page as PNG bytes; None if the page drew no frame within the timeout."""
        import websocket

        try:
            reply = self._call("Page.captureScreenshot", {"format": "png"})
        except (TimeoutError, websocket.WebSocketTimeoutException):
            return None
        return base64.b64decode(reply["data"])

    def close(self) -> None:
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        shutil.rmtree(self._profile, ignore_errors=True)
