"""``companion --record FILE.mcap``: the core's inputs and MAVLink outputs, for replay.

:class:`McapRecorder` is a :class:`~companion.observe.CompanionObserver`. Its
:meth:`~McapRecorder.on_step` only queues the core's input and the outputs it returned
(references: frames are immutable, MAVLink messages are not touched again by the
service); a thread of its own encodes and writes the MCAP file (format:
:mod:`companion.record.format`), so the service's per-frame latency barely moves
(``benchmarks/bench_view.py`` measures it). If the writer falls behind by more than
``max_pending`` steps, new ones are dropped and counted (a recording with drops does not
replay bit for bit; the stats and the log say so).
"""

from __future__ import annotations

import base64
import json
import logging
import queue
import threading
from collections.abc import Sequence
from pathlib import Path

from mcap.writer import CompressionType, Writer
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.events import (
    FrameReceived,
    Input,
    MavlinkReceived,
    Output,
    SendMavlink,
    SendSetpoint,
    Tick,
)
from companion.observe import CompanionObserver
from companion.record import format as fmt
from protocols import stereo_frame
from protocols.stereo_frame import StereoFrame

__all__ = ["McapRecorder", "RecorderStats"]

_log = logging.getLogger("companion.record")
_STOP = object()
_PREVIEW_PERIOD_NS = 100_000_000  # /camera/left (Foxglove preview) at most at 10 Hz


class RecorderStats:
    """What was written and what was dropped."""

    def __init__(self) -> None:
        self.ticks = 0
        self.frames = 0
        self.mavlink_in = 0
        self.mavlink_out = 0
        self.dropped = 0
        self.write_errors = 0

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))


class McapRecorder(CompanionObserver):
    """Record the companion's inputs and decisions to ``path`` (MCAP).

    Parameters
    ----------
    path : str or Path
        Output file (created or truncated by :meth:`on_start`).
    max_pending : int
        Steps queued for the writer beyond which new ones are dropped (most steps are
        ticks and telemetry; a 320×240 frame step holds ~154 kB).
    compression : CompressionType
        MCAP chunk compression (LZ4 by default: fast, and a recording stays replayable).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_pending: int = 2000,
        compression: CompressionType = CompressionType.LZ4,
    ) -> None:
        self.path = Path(path)
        self.max_pending = max_pending
        self.compression = compression
        self.stats = RecorderStats()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._pending = 0
        self._pending_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._file = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self._warned_drop = False
        self._preview_ns: int | None = None  # capture time of the last /camera/left
        self._encoder = None

    # ---- observer hooks (service thread) ---------------------------------------------
    def on_start(self, config, instance_id: int) -> None:
        self._file = self.path.open("wb")
        writer = Writer(self._file, compression=self.compression)
        writer.start(profile=fmt.PROFILE, library="stereo-avoid companion")
        raw_image = writer.register_schema(
            "foxglove.RawImage", "jsonschema", json.dumps(fmt.RAW_IMAGE_SCHEMA).encode()
        )
        self._channels = {
            topic: writer.register_channel(topic, encoding, schema)
            for topic, encoding, schema in (
                (fmt.TOPIC_TICK, fmt.ENC_TICK, 0),
                (fmt.TOPIC_MAVLINK_IN, fmt.ENC_MAVLINK_IN, 0),
                (fmt.TOPIC_STEREO, fmt.ENC_FRAME_IN, 0),
                (fmt.TOPIC_MAVLINK_OUT, fmt.ENC_MAVLINK, 0),
                (fmt.TOPIC_LEFT, fmt.ENC_JSON, raw_image),
            )
        }
        writer.add_metadata(
            fmt.METADATA,
            {
                "format": fmt.FORMAT_VERSION,
                "config": json.dumps(fmt.config_to_dict(config)),
                "signing": "1" if config.link.signing_key is not None else "0",
                "instance_id": str(instance_id),
            },
        )
        system_id, component_id = config.link.system_id, config.link.component_id
        self._encoder = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._writer = writer
        self._thread = threading.Thread(target=self._run, name="mcap-recorder", daemon=True)
        self._thread.start()
        _log.info("recording to %s", self.path)

    def on_step(self, event: Input, outputs: Sequence[Output]) -> None:
        if self._writer is None:
            return
        with self._pending_lock:
            if self._pending >= self.max_pending:
                self.stats.dropped += 1
                if not self._warned_drop:
                    self._warned_drop = True
                    _log.warning(
                        "recorder: the writer is %d steps behind; dropping (the recording "
                        "will not replay exactly)",
                        self._pending,
                    )
                return
            self._pending += 1
        sent = [o.message for o in outputs if isinstance(o, SendMavlink | SendSetpoint)]
        self._queue.put((event, sent))

    def close(self) -> None:
        if self._thread is None:
            return
        self._queue.put(_STOP)
        self._thread.join(timeout=30.0)
        if self._thread.is_alive():
            _log.error("recorder: writer did not finish within 30 s; %s is incomplete", self.path)
            return
        self._thread = None
        _log.info("recording %s closed: %s", self.path, self.stats.as_dict())

    # ---- writer thread ---------------------------------------------------------------
    def _add(self, topic: str, t_ns: int, data: bytes) -> None:
        assert self._writer is not None
        self._sequence += 1
        self._writer.add_message(self._channels[topic], t_ns, data, t_ns, self._sequence)

    def _write(self, event: Input, sent: list) -> None:
        t_ns = event.now_ns
        if isinstance(event, Tick):
            self._add(fmt.TOPIC_TICK, t_ns, fmt.NS.pack(t_ns))
            self.stats.ticks += 1
        elif isinstance(event, MavlinkReceived):
            raw = event.message.get_msgbuf()
            self._add(fmt.TOPIC_MAVLINK_IN, t_ns, fmt.NS.pack(t_ns) + bytes(raw))
            self.stats.mavlink_in += 1
        elif isinstance(event, FrameReceived):
            frame = event.frame
            header = fmt.FRAME_IN_HEADER.pack(event.received_ns, t_ns)
            self._add(fmt.TOPIC_STEREO, t_ns, header + stereo_frame.encode(frame))
            self.stats.frames += 1
            self._preview(frame, t_ns)
        for message in sent:
            raw = message.get_msgbuf()
            if not raw:  # not packed: the link was down when the core asked
                raw = message.pack(self._encoder)
            self._add(fmt.TOPIC_MAVLINK_OUT, t_ns, bytes(raw))
            self.stats.mavlink_out += 1

    def _preview(self, frame: StereoFrame, t_ns: int) -> None:
        """The left plane as foxglove.RawImage, at most every 100 ms of capture time (none
        for a depth camera's frame that came without its left image)."""
        if frame.left is None:
            return
        t = frame.capture_ns
        if self._preview_ns is not None and 0 <= t - self._preview_ns < _PREVIEW_PERIOD_NS:
            return
        self._preview_ns = t
        h, w = frame.left.shape
        image = {
            "timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
            "frame_id": "camera_left",
            "width": w,
            "height": h,
            "encoding": "mono8",
            "step": w,
            "data": base64.b64encode(frame.left.tobytes()).decode("ascii"),
        }
        self._add(fmt.TOPIC_LEFT, t_ns, json.dumps(image).encode())

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                break
            with self._pending_lock:
                self._pending -= 1
            try:
                self._write(*item)
            except Exception as exc:  # a full disk must not kill the companion
                self.stats.write_errors += 1
                if self.stats.write_errors == 1:
                    _log.error("recorder: writing %s failed: %s", self.path, exc)
        try:
            assert self._writer is not None and self._file is not None
            self._writer.finish()
            self._file.close()
        except Exception as exc:
            _log.error("recorder: closing %s failed: %s", self.path, exc)
