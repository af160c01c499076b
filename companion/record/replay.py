"""Replay a companion recording (``FILE.mcap``) through a fresh core, deterministically.

``stereo-avoid replay FILE.mcap`` runs :func:`replay`: it builds a new
:class:`~companion.core.CompanionCore` with the recorded configuration and instance id,
reads the recording in file order (= the order the service stepped its core,
:mod:`companion.record.format`) and feeds it every recorded input — ``Tick``,
``MavlinkReceived`` (the frame bytes parsed again), ``FrameReceived`` (the frame decoded
again) — with its recorded times. No clock is read: the recorded ``now_ns`` are the only
time there is, so every decision the core takes on wall time (link loss, failsafe,
keep-alive, mode requests, takeover) is taken again at the same step.

After each input, the MAVLink messages the core returns are compared with the ones the
service sent for that input (the recorded ``/mavlink/out`` frames that follow it): same
count, and per message the same id, source and payload bytes (sequence number, checksum
and signature belong to the link and are left out). Setpoints
(SET_POSITION_TARGET_LOCAL_NED) are counted apart; :attr:`ReplayResult.identical` is the
verdict ("bit for bit").
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core import (
    CompanionCore,
    FrameProcessed,
    FrameReceived,
    Input,
    MavlinkReceived,
    SendMavlink,
    SendSetpoint,
    Tick,
)
from companion.record import format as fmt
from protocols import stereo_frame

__all__ = ["Record", "RecordingError", "ReplayResult", "read_recording", "replay"]

_SETPOINT_ID = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
_INPUT_TOPICS = (fmt.TOPIC_TICK, fmt.TOPIC_MAVLINK_IN, fmt.TOPIC_STEREO)


class RecordingError(ValueError):
    """The file is not a readable companion recording; the message says why."""


@dataclass
class ReplayResult:
    """What replay found; :attr:`identical` is the verdict."""

    inputs: int = 0
    frames: int = 0  # FrameReceived inputs
    mavlink_compared: int = 0  # MAVLink outputs compared (setpoints included)
    setpoints_compared: int = 0
    mismatches: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        """Every output the same, and at least one setpoint compared."""
        return self.setpoints_compared > 0 and not self.mismatches

    def summary(self) -> dict:
        return {
            "inputs": self.inputs,
            "frames": self.frames,
            "mavlink_compared": self.mavlink_compared,
            "setpoints_compared": self.setpoints_compared,
            "identical": self.identical,
            "mismatches": len(self.mismatches),
            "first_mismatches": self.mismatches[:5],
        }


@dataclass(frozen=True)
class Record:
    """One message of a recording: topic, log time [ns host], payload bytes."""

    topic: str
    log_ns: int
    data: bytes


@dataclass(frozen=True)
class Recording:
    """A recording's metadata and its records (an iterator, in file order)."""

    config: object  # CompanionConfig
    instance_id: int
    records: Iterator[Record]


def read_recording(path: str | Path) -> Recording:
    """Open ``path``; raises :class:`RecordingError` for anything but a recording."""
    path = Path(path)
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise RecordingError(f"cannot open recording {path}: {exc.strerror}") from None
    try:
        reader = make_reader(fh)
        meta = None
        for record in reader.iter_metadata():
            if record.name == fmt.METADATA:
                meta = dict(record.metadata)
    except Exception as exc:  # the mcap library raises its own types on bad files
        fh.close()
        raise RecordingError(f"{path} is not a readable MCAP file: {exc}") from None
    if meta is None:
        fh.close()
        raise RecordingError(f"{path} has no '{fmt.METADATA}' metadata: not a companion recording")
    if meta.get("format") != fmt.FORMAT_VERSION:
        fh.close()
        raise RecordingError(
            f"{path}: recording format {meta.get('format')!r}, this replay reads "
            f"{fmt.FORMAT_VERSION!r}"
        )
    try:
        config = fmt.config_from_recorded(json.loads(meta["config"]), meta["signing"] == "1")
        instance_id = int(meta["instance_id"])
    except Exception as exc:  # ConfigError, KeyError, ValueError: say which
        fh.close()
        raise RecordingError(f"{path}: bad recording metadata ({exc})") from None

    def records() -> Iterator[Record]:
        try:
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                yield Record(channel.topic, message.log_time, message.data)
        except Exception as exc:
            raise RecordingError(f"{path}: damaged recording ({exc})") from None
        finally:
            fh.close()

    return Recording(config, instance_id, records())


def _input(record: Record, parser) -> Input:
    """The core input an input record holds; raises RecordingError when unreadable."""
    if record.topic == fmt.TOPIC_TICK:
        return Tick(fmt.NS.unpack_from(record.data)[0])
    if record.topic == fmt.TOPIC_MAVLINK_IN:
        now_ns = fmt.NS.unpack_from(record.data)[0]
        messages = parser.parse_buffer(record.data[fmt.NS.size :]) or []
        messages = [m for m in messages if m.get_type() != "BAD_DATA"]
        if len(messages) != 1:
            raise RecordingError(f"MAVLink input at {record.log_ns} ns holds {len(messages)}")
        return MavlinkReceived(messages[0], now_ns)
    received_ns, now_ns = fmt.FRAME_IN_HEADER.unpack_from(record.data)
    try:
        frame = stereo_frame.decode(record.data[fmt.FRAME_IN_HEADER.size :])
    except stereo_frame.FrameDecodeError as exc:
        raise RecordingError(f"frame input at {record.log_ns} ns undecodable: {exc}") from None
    return FrameReceived(frame, received_ns, now_ns)


def replay(
    path: str | Path,
    *,
    on_config: Callable[[object], None] | None = None,
    on_frame: Callable[[FrameProcessed], None] | None = None,
) -> ReplayResult:
    """Replay the recording at ``path``; see the module docstring.

    Parameters
    ----------
    path : recording made with ``companion --record``.
    on_config : called once with the recorded :class:`~companion.config.CompanionConfig`.
    on_frame : called with every processed frame (a Rerun logger); the core is then built
        with ``report_pipeline=True``.

    Raises
    ------
    RecordingError
        Not a recording, or a damaged one.
    """
    recording = read_recording(path)
    config = recording.config
    if on_config is not None:
        on_config(config)
    link = config.link
    core = CompanionCore(config, recording.instance_id, report_pipeline=on_frame is not None)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    encoder = mavlink.MAVLink(None, srcSystem=link.system_id, srcComponent=link.component_id)
    result = ReplayResult()
    expected: list[bytes] = []  # what the core returned for the last input, packed
    where = "start"

    def settle() -> None:
        """The recorded outputs of the previous input are all read: none may be left."""
        for buf in expected:
            msgid = fmt.mavlink_frame_fields(buf)[0]
            result.mismatches.append(f"{where}: replay sent message {msgid}, the service did not")
        expected.clear()

    for record in recording.records:
        if record.topic in _INPUT_TOPICS:
            settle()
            event = _input(record, parser)
            result.inputs += 1
            where = f"input {result.inputs} ({type(event).__name__} at {event.now_ns} ns)"
            if isinstance(event, FrameReceived):
                result.frames += 1
            for out in core.step(event):
                if isinstance(out, SendMavlink | SendSetpoint):
                    expected.append(bytes(out.message.pack(encoder)))
                elif isinstance(out, FrameProcessed) and on_frame is not None:
                    on_frame(out)
        elif record.topic == fmt.TOPIC_MAVLINK_OUT:
            _compare(record.data, expected, where, result)
    settle()
    return result


def _compare(recorded: bytes, expected: list[bytes], where: str, result: ReplayResult) -> None:
    try:
        want = fmt.mavlink_frame_fields(recorded)
    except ValueError as exc:
        result.mismatches.append(f"{where}: recorded output unreadable ({exc})")
        return
    if not expected:
        result.mismatches.append(f"{where}: the service sent message {want[0]}, replay did not")
        return
    got = fmt.mavlink_frame_fields(expected.pop(0))
    result.mavlink_compared += 1
    if want[0] == _SETPOINT_ID:
        result.setpoints_compared += 1
    if got != want:
        result.mismatches.append(
            f"{where}: message {got[0]} from {got[1]}/{got[2]} payload {got[3].hex()} != "
            f"recorded {want[0]} from {want[1]}/{want[2]} payload {want[3].hex()}"
        )
