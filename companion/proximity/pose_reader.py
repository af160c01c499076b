"""The OBSTACLE_DISTANCE process's own pose: LOCAL_POSITION_NED and ATTITUDE, nothing else.

The process reads every datagram of the companion's socket
(:mod:`companion.proximity.forward`) and decodes only the two messages that place the
vehicle in the map, from the autopilot (``target_system`` / ``target_component``): it looks
at each MAVLink frame's message id in its header before it decodes anything (a 50 Hz
stream of both costs ~5 ms of CPU a second; every other message is only forwarded). With
a signing key only frames whose signature is right and whose timestamp is new are used
(:class:`protocols.signing.SignatureVerifier`, its own replay state: the main loop checks
the same bytes again with its own). Values out of range are not used, nor a message older
than the newest (``time_boot_ms`` back by less than a reboot's
:data:`~companion.core.telemetry_job.REBOOT_BACKSTEP_MS`).

The pose's host time is the moment the process read the datagram (it reads at arrival),
so :func:`~companion.proximity.sender.pose_age_s` ages it on the host clock alone
(``host_frame_clock`` False). Pure apart from the clock value the caller passes.
"""

from __future__ import annotations

import math
import struct

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.core.telemetry_job import MAX_POS_M, REBOOT_BACKSTEP_MS
from companion.proximity.shared import SharedPose
from protocols.signing import SignatureVerifier, SigningKey

__all__ = ["PoseReader", "frames_of"]

_LOCAL_POSITION_NED = mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED
_ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
_WANTED = (_LOCAL_POSITION_NED, _ATTITUDE)
_V1, _V2 = 0xFE, 0xFD
_IFLAG_SIGNED = 0x01
_MAX_SPEED_MPS = 300.0


def frames_of(datagram: bytes):
    """(message id, system, component, frame) of each MAVLink frame the datagram holds
    back to back (ArduPilot packs several into one); stops at anything that is not a
    frame's start (the main loop's parser deals with it)."""
    pos, n = 0, len(datagram)
    while pos + 8 <= n:
        magic = datagram[pos]
        if magic == _V2:
            if pos + 12 > n:
                return
            length = datagram[pos + 1]
            signed = datagram[pos + 2] & _IFLAG_SIGNED
            end = pos + 12 + length + (13 if signed else 0)
            msgid = datagram[pos + 7] | datagram[pos + 8] << 8 | datagram[pos + 9] << 16
            system, component = datagram[pos + 5], datagram[pos + 6]
        elif magic == _V1:
            length = datagram[pos + 1]
            end = pos + 8 + length
            system, component, msgid = datagram[pos + 3], datagram[pos + 4], datagram[pos + 5]
        else:
            return
        if end > n:
            return
        yield msgid, system, component, datagram[pos:end]
        pos = end


class PoseReader:
    """The newest pose in the datagrams the process read.

    Parameters
    ----------
    autopilot : tuple of int
        (system, component) whose telemetry is used.
    signing_secret : bytes or None
        With a key, only correctly signed, non-replayed frames are used.
    """

    def __init__(self, autopilot: tuple[int, int], signing_secret: bytes | None) -> None:
        self._autopilot = autopilot
        self._verifier = (
            None if signing_secret is None else SignatureVerifier(SigningKey(signing_secret))
        )
        self._mav = mavlink.MAVLink(None)  # decodes frames already verified here
        self._position = None  # (time_boot_ms, pos, vel, host ns)
        self._yaw: tuple[int, float] | None = None  # (time_boot_ms, yaw [rad])
        self.used = 0  # messages that updated the pose
        self.refused = 0  # wanted messages not used: signature, range, order, decoding

    def feed(self, datagram: bytes, now_ns: int) -> None:
        """Take the pose messages of one datagram read at host time ``now_ns``."""
        for msgid, system, component, frame in frames_of(datagram):
            if msgid not in _WANTED or (system, component) != self._autopilot:
                continue
            if self._verifier is not None and self._verifier.verify(bytes(frame)) is not None:
                self.refused += 1
                continue
            try:
                msg = self._mav.decode(bytearray(frame))
            except (mavlink.MAVError, struct.error, ValueError, IndexError):
                self.refused += 1
                continue
            if not self._take(msg, now_ns):
                self.refused += 1

    def _take(self, msg, now_ns: int) -> bool:
        t_ms = int(msg.time_boot_ms)
        if msg.get_msgId() == _LOCAL_POSITION_NED:
            pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
            if not (_within(pos, MAX_POS_M) and _within(vel, _MAX_SPEED_MPS)):
                return False
            if self._position is not None and _older(t_ms, self._position[0]):
                return False
            self._position = (t_ms, pos, vel, now_ns)
        else:
            if not _within((msg.yaw,), 2.0 * math.pi):
                return False
            if self._yaw is not None and _older(t_ms, self._yaw[0]):
                return False
            self._yaw = (t_ms, float(msg.yaw))
        self.used += 1
        return True

    def pose(self) -> SharedPose | None:
        """The newest position with the newest yaw (None until both arrived)."""
        if self._position is None or self._yaw is None:
            return None
        t_ms, pos, vel, host_ns = self._position
        return SharedPose(
            pos_ned_m=tuple(float(v) for v in pos),
            vel_ned_mps=tuple(float(v) for v in vel),
            yaw_rad=self._yaw[1],
            frame_ns=t_ms * 1_000_000,
            received_ns=host_ns,
            host_frame_clock=False,
        )


def _within(values, bound: float) -> bool:
    return all(math.isfinite(v) and abs(v) <= bound for v in values)


def _older(t_ms: int, newest_ms: int) -> bool:
    """Older than the newest, and not by a reboot's step back."""
    return newest_ms - REBOOT_BACKSTEP_MS < t_ms < newest_ms
