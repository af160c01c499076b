"""The companion's MCAP recording format (``companion --record FILE.mcap``): topics, payloads.

A recording holds the companion core's *inputs* (:mod:`companion.core.events`), each
followed by the MAVLink *outputs* the core returned for it, in the order the service
stepped the core: file order *is* step order (replay reads it that way,
:mod:`companion.record.replay`). ``log_time`` and ``publish_time`` are the input's
``now_ns`` (this host's ``time.monotonic_ns()``); an output has its input's.

================================  ==========================  ===================================
topic                             message encoding            payload
================================  ==========================  ===================================
``/companion/tick``               ``stereo_avoid.tick``       ``<q now_ns>``: a ``Tick``
``/mavlink/in``                   ``stereo_avoid.mavlink_in`` ``<q now_ns>`` + the MAVLink frame
                                                              as received (signature included):
                                                              a ``MavlinkReceived``
``/stereo_avoid/stereo``          ``stereo_avoid.frame_in``   ``<q received_ns><q now_ns>`` +
                                                              the frame in the Zenoh wire format
                                                              (:mod:`protocols.stereo_frame`:
                                                              capture time, camera model, both
                                                              raw planes): a ``FrameReceived``
``/mavlink/out``                  ``mavlink2``                a MAVLink frame the core sent
                                                              (``SendMavlink``/``SendSetpoint``),
                                                              as it went on the wire
``/camera/left``                  ``json``                    ``foxglove.RawImage`` of the left
                                                              plane (Foxglove preview, ≤ 10 Hz)
================================  ==========================  ===================================

Metadata ``stereo_avoid.recording``: ``config`` (:func:`config_to_dict`, JSON; never the
signing key, only whether one was set), ``instance_id`` (the core's constructor input)
and ``format`` (:data:`FORMAT_VERSION`). Floats in JSON are written with ``repr``
precision (exact round trip).
"""

from __future__ import annotations

import dataclasses
import enum
import struct
from pathlib import Path
from typing import Any

__all__ = [
    "ENC_FRAME_IN",
    "ENC_JSON",
    "ENC_MAVLINK",
    "ENC_MAVLINK_IN",
    "ENC_TICK",
    "FORMAT_VERSION",
    "FRAME_IN_HEADER",
    "METADATA",
    "NS",
    "PROFILE",
    "RAW_IMAGE_SCHEMA",
    "TOPIC_LEFT",
    "TOPIC_MAVLINK_IN",
    "TOPIC_MAVLINK_OUT",
    "TOPIC_STEREO",
    "TOPIC_TICK",
    "config_from_recorded",
    "config_to_dict",
    "mavlink_frame_fields",
]

PROFILE = "stereo_avoid"
FORMAT_VERSION = "2"  # 2: the core's inputs and outputs (1: the old service's hooks)
TOPIC_TICK = "/companion/tick"
TOPIC_MAVLINK_IN = "/mavlink/in"
TOPIC_STEREO = "/stereo_avoid/stereo"
TOPIC_MAVLINK_OUT = "/mavlink/out"
TOPIC_LEFT = "/camera/left"
ENC_TICK = "stereo_avoid.tick"
ENC_MAVLINK_IN = "stereo_avoid.mavlink_in"
ENC_FRAME_IN = "stereo_avoid.frame_in"
ENC_MAVLINK = "mavlink2"
ENC_JSON = "json"
METADATA = "stereo_avoid.recording"
NS = struct.Struct("<q")  # now_ns [ns, host monotonic]
FRAME_IN_HEADER = struct.Struct("<qq")  # received_ns, now_ns [ns, host monotonic]

RAW_IMAGE_SCHEMA = {
    "title": "foxglove.RawImage",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
        "width": {"type": "integer"},
        "height": {"type": "integer"},
        "encoding": {"type": "string"},
        "step": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}

_MAVLINK2_STX = 0xFD
_MAVLINK1_STX = 0xFE


def _plain(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _section(value)  # a nested section, e.g. [perception.depth_camera]
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _section(obj, leave_out: tuple[str, ...] = ()) -> dict[str, Any]:
    return {
        f.name: _plain(getattr(obj, f.name))
        for f in dataclasses.fields(obj)
        if f.name not in leave_out
    }


def config_to_dict(config) -> dict[str, Any]:
    """A :class:`~companion.config.CompanionConfig` in the config file's layout (so
    :func:`companion.config.config_from_dict` reads it back): everything the core reads.
    The signing key and the Zenoh section (endpoints, credentials files) are left out."""
    return {
        "vehicle_id": config.vehicle_id,
        "waypoints_ned_m": _plain(config.waypoints_ned_m),
        "goal_tolerance_m": config.goal_tolerance_m,
        "status_log_period_s": config.status_log_period_s,
        "mavlink": _section(config.link, leave_out=("signing_key",)),
        "failsafe": _section(config.failsafe),
        "perception": _section(config.perception),
        "guidance": _section(config.guidance),
        "known_space": _section(config.known_space),
        "envelope": _section(config.envelope),
    }


def config_from_recorded(config_dict: dict[str, Any], signing: bool):
    """The :class:`~companion.config.CompanionConfig` a recording was made with.

    ``signing``: a key was set. The core only asks *whether* one is (for the wording of
    its "no autopilot" hint), so replay sets a placeholder key; the secret is never
    recorded.
    """
    from companion.config import config_from_dict
    from protocols.signing import SigningKey

    config = config_from_dict(config_dict)
    if signing:
        placeholder = SigningKey(bytes(32))
        config = dataclasses.replace(
            config, link=dataclasses.replace(config.link, signing_key=placeholder)
        )
    return config


def mavlink_frame_fields(buf: bytes) -> tuple[int, int, int, bytes]:
    """(message id, system id, component id, payload) of one MAVLink 1 or 2 frame.

    The payload is what a message *says*; the sequence number, the checksum and the
    signature (which depend on the link, not on the message) are left out.

    Raises
    ------
    ValueError
        Not a whole MAVLink frame.
    """
    if len(buf) < 8:
        raise ValueError(f"{len(buf)} bytes is not a MAVLink frame")
    length = buf[1]
    if buf[0] == _MAVLINK2_STX:
        if len(buf) < 12 + length:
            raise ValueError("truncated MAVLink 2 frame")
        msgid = buf[7] | buf[8] << 8 | buf[9] << 16
        return msgid, buf[5], buf[6], bytes(buf[10 : 10 + length])
    if buf[0] == _MAVLINK1_STX:
        if len(buf) < 8 + length:
            raise ValueError("truncated MAVLink 1 frame")
        return buf[5], buf[3], buf[4], bytes(buf[6 : 6 + length])
    raise ValueError(f"not a MAVLink frame (first byte 0x{buf[0]:02x})")
