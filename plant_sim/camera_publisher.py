"""Camera frames over Zenoh: render at the camera rate of simulation time, stamp, publish.

A stereo pair, or with ``[camera] encoding = "depth16"`` (or ``"depth32f"``) the depth frame
of a RealSense-like depth camera made from the left eye's true depth
(:mod:`plant_sim.depth_camera`), with the left image beside it for the viewer.

Each frame's ``capture_ns`` is the simulation time of the pose it was rendered at, the same
clock as MAVLink ``time_boot_ms`` (DESIGN.md "One clock"). The session uses explicit
endpoints (``tcp/127.0.0.1:7447``) with multicast scouting disabled, or a Zenoh config file
for routers, TLS and access control (explicit endpoints given on the command line are then
added to the file's).
"""

from __future__ import annotations

import numpy as np
import zenoh

from plant_sim.depth_camera import CameraEncoding, depth_frame
from plant_sim.scenario import CameraConfig
from plant_sim.stereo_camera import StereoCameraRenderer
from plant_sim.world import World
from protocols.frame_publisher import FramePublisher
from protocols.zenoh_session import ZenohSettings, zenoh_config

__all__ = ["StereoPublisher", "readiness_fields"]


class StereoPublisher:
    """Renders and publishes stereo frames on ``key``; open with :meth:`open`."""

    def __init__(
        self,
        settings: ZenohSettings,
        key: str,
        camera: CameraConfig,
        world: World,
    ) -> None:
        self.settings = settings
        self.key = key
        self.camera = camera
        self.world = world
        self._renderer = StereoCameraRenderer(camera.model, camera.render)
        self._intrinsics = camera.model.intrinsics
        self._session: zenoh.Session | None = None
        self._publisher: FramePublisher | None = None
        self.sequence = 0

    @property
    def publish_errors(self) -> int:
        return 0 if self._publisher is None else self._publisher.publish_errors

    def open(self) -> None:
        """Compile the renderer (one frame, so the JIT is done before the first deadline),
        open the Zenoh session and declare the publisher."""
        self.warm_up()
        self._session = zenoh.open(zenoh_config(self.settings))
        self._publisher = FramePublisher(self._session, self.key, drop=True)

    def warm_up(self) -> None:
        """Render one frame (and make its depth frame, for a depth camera) so the JIT
        compiles before the first deadline."""
        render = self._renderer.render(self.world, np.zeros(3), np.eye(3), noise_seed=0)
        if self.camera.encoding is not CameraEncoding.MONO8:
            depth_frame(
                0,
                0,
                self._intrinsics,
                render.depth_left_m,
                render.left,
                self.camera.depth,
                self.camera.encoding,
            )

    def publish(self, capture_time_s: float, pos_ned_m, R_ned_from_frd) -> None:
        """Render the view from the pose at ``capture_time_s`` and publish it (a pair, or a
        depth frame)."""
        render = self._renderer.render(
            self.world, pos_ned_m, R_ned_from_frd, noise_seed=self.sequence
        )
        sequence, self.sequence = self.sequence, self.sequence + 1
        if self._publisher is None:
            return
        capture_ns = round(capture_time_s * 1e9)
        if self.camera.encoding is CameraEncoding.MONO8:
            self._publisher.publish(
                sequence, capture_ns, self._intrinsics, render.left, render.right
            )
            return
        frame = depth_frame(
            sequence,
            capture_ns,
            self._intrinsics,
            render.depth_left_m,
            render.left,
            self.camera.depth,
            self.camera.encoding,
        )
        self._publisher.publish_frame(frame)

    def close(self) -> None:
        if self._publisher is not None:
            self._publisher.close()
            self._publisher = None
        if self._session is not None:
            self._session.close()
            self._session = None


def readiness_fields(publisher: StereoPublisher | None) -> str:
    """The camera's part of a ``PLANT_SIM READY`` line: ``zenoh=ENDPOINTS key=KEY``, or
    ``zenoh=off key=-`` without a camera."""
    if publisher is None:
        return "zenoh=off key=-"
    return f"zenoh={publisher.settings.describe()} key={publisher.key}"
