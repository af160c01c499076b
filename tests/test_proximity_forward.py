"""The OBSTACLE_DISTANCE process as the socket's reader, its pure parts (issue 34): the
forwarding stream keeps every datagram, in order, through a full buffer; the pose reader
takes only the autopilot's LOCAL_POSITION_NED and ATTITUDE, only correctly signed with a
key; the link parses forwarded datagrams as its own reads (peers included)."""

from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.connection import MavlinkConnection
from companion.proximity.child import _pose_to_use
from companion.proximity.forward import ForwardQueue, ForwardReader, encode_record, forward_pair
from companion.proximity.pose_reader import PoseReader, frames_of
from companion.proximity.shared import SharedPose
from evaluation.sil import free_port
from protocols.signing import SigningKey, signing_timestamp_now

pytestmark = pytest.mark.unit

KEY = SigningKey(bytes(range(32)))
FORGED = SigningKey(bytes(range(1, 33)))
AUTOPILOT = (1, 1)


def _mav(system=1, component=1, key: SigningKey | None = None) -> mavlink.MAVLink:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        mav.signing.secret_key = key.secret
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_timestamp_now()
    return mav


def _position(mav, t_ms: int, north_m: float, vel_n_mps: float = 0.0) -> bytes:
    msg = mavlink.MAVLink_local_position_ned_message(t_ms, north_m, 2.0, -7.0, vel_n_mps, 0, 0)
    return msg.pack(mav)


def _attitude(mav, t_ms: int, yaw_rad: float) -> bytes:
    return mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, yaw_rad, 0, 0, 0).pack(mav)


def test_a_burst_reaches_the_main_loop_whole_and_in_order_through_a_full_buffer():
    """20 000 datagrams of 1-300 bytes (more than the stream's buffers hold) pushed while
    the main loop reads nothing, then read as it drains: every one, in order, none cut."""
    ours, theirs = forward_pair()
    queue, reader = ForwardQueue(), ForwardReader(ours)
    sent = [
        (("127.0.0.1" if i % 3 else "10.0.0.7", 14550 + i % 5), bytes([i % 251]) * (1 + i % 300))
        for i in range(20_000)
    ]
    got = []
    try:
        for addr, data in sent:
            queue.push(addr, data)
            queue.flush(theirs)
        assert len(queue) > 0  # the buffer filled: the rest waits in the process
        deadline = time.monotonic() + 30.0
        while len(got) < len(sent) and time.monotonic() < deadline:
            queue.flush(theirs)
            got += reader.take(max_bytes=100_000)  # a main loop that reads in pieces
        assert len(got) == len(sent) and got == sent
        assert queue.forwarded == len(sent) and queue.dropped == 0
        theirs.close()  # the process ended: the main loop sees the stream closed
        assert reader.take() == [] and reader.closed
    finally:
        reader.close()
        theirs.close()


def test_a_full_queue_drops_whole_datagrams_and_counts_them():
    queue = ForwardQueue(limit_bytes=1000)
    for _ in range(20):
        queue.push(("127.0.0.1", 1), b"x" * 92)  # 100 bytes a record
    assert len(queue) == 10 and queue.dropped == 10
    queue.push(("::1", 1), b"x")  # no IPv4 address: no record, counted
    queue.push(("127.0.0.1", 1), b"x" * 70_000)
    assert queue.dropped == 12
    assert encode_record(("127.0.0.1", 70_000), b"x") is None


def test_frames_of_finds_each_frame_of_a_packed_datagram_by_its_header():
    signed = _position(_mav(key=KEY), 10, 1.0)
    plain = _attitude(_mav(1, 1), 10, 0.5)
    v1 = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3).pack(_mav(7, 9), force_mavlink1=True)
    found = list(frames_of(signed + plain + v1))
    assert [(m, s, c) for m, s, c, _ in found] == [(32, 1, 1), (30, 1, 1), (0, 7, 9)]
    assert b"".join(f for *_, f in found) == signed + plain + v1
    assert [m for m, *_ in frames_of(signed + plain[:-3])] == [32]  # a cut frame ends it
    assert list(frames_of(b"\x00garbage" + signed)) == []


def test_the_pose_reader_takes_the_autopilots_newest_pose_and_nothing_else():
    reader = PoseReader(AUTOPILOT, None)
    mav = _mav()
    reader.feed(_position(mav, 1000, 4.0, 3.0), 1_000)
    assert reader.pose() is None  # no yaw yet
    reader.feed(_attitude(mav, 1000, 0.25) + _position(mav, 1020, 4.5, 3.0), 2_000)
    pose = reader.pose()
    assert pose.pos_ned_m == (4.5, 2.0, -7.0) and pose.vel_ned_mps == (3.0, 0.0, 0.0)
    assert pose.yaw_rad == pytest.approx(0.25) and pose.received_ns == 2_000
    assert not pose.host_frame_clock and pose.frame_ns == 1_020_000_000
    reader.feed(_position(mav, 1010, 9.0), 3_000)  # older than the newest: not used
    reader.feed(_position(_mav(2, 1), 1030, 9.0), 3_000)  # another system
    reader.feed(_position(_mav(1, 196), 1030, 9.0), 3_000)  # another component
    reader.feed(_position(mav, 1040, math.inf), 3_000)  # out of range
    gps = mavlink.MAVLink_gps_raw_int_message(0, 3, 1, 2, 3, 0, 0, 0, 0, 9)
    reader.feed(gps.pack(mav), 3_000)  # not a pose message: not even decoded
    assert reader.pose().pos_ned_m[0] == 4.5 and reader.refused == 2
    reader.feed(_position(mav, 950, 1.0), 4_000)  # 70 ms back: reordered, not used
    assert reader.pose().pos_ned_m[0] == 4.5 and reader.refused == 3
    reader.feed(_position(mav, 200, 1.0), 5_000)  # 820 ms back: the autopilot restarted
    assert reader.pose().pos_ned_m[0] == 1.0 and reader.pose().received_ns == 5_000


def test_with_a_key_only_correctly_signed_poses_are_used():
    reader = PoseReader(AUTOPILOT, KEY.secret)
    genuine = _mav(key=KEY)
    reader.feed(_attitude(genuine, 10, 0.0) + _position(genuine, 10, 3.0), 1)
    assert reader.pose().pos_ned_m[0] == 3.0 and reader.refused == 0
    forged = _mav(key=FORGED)
    forged.signing.timestamp = genuine.signing.timestamp + 10**9  # far ahead: no matter
    reader.feed(_position(forged, 20, 50.0), 2)  # wrong key
    reader.feed(_position(_mav(), 20, 50.0), 2)  # unsigned
    replay = _position(genuine, 30, 4.0)
    reader.feed(replay, 3)
    reader.feed(replay, 4)  # the same frame again: its timestamp is not new
    assert reader.refused == 3
    assert reader.pose().pos_ned_m[0] == 4.0 and reader.pose().received_ns == 3
    reader.feed(_position(genuine, 40, 5.0), 5)  # the forgery blocked nothing
    assert reader.pose().pos_ned_m[0] == 5.0


def test_the_process_uses_its_own_pose_while_it_reads_and_else_the_newest():
    def pose(received_ns: int) -> SharedPose:
        return SharedPose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, 0, received_ns, False)

    own, main_loops = pose(100), pose(105)  # the main loop read the same message later
    assert _pose_to_use(own, main_loops, reading=True) is own
    assert _pose_to_use(None, main_loops, reading=True) is main_loops  # no yaw yet
    assert _pose_to_use(own, main_loops, reading=False) is main_loops  # it reads itself
    assert _pose_to_use(pose(200), main_loops, reading=False).received_ns == 200
    assert _pose_to_use(None, None, reading=False) is None


class _Forwarder:
    def __init__(self) -> None:
        self.pending: list = []
        self.main = False

    def forwarded(self):
        out, self.pending = self.pending, []
        return out

    def main_reads(self) -> bool:
        return self.main


def test_the_link_parses_forwarded_datagrams_as_its_own_and_learns_their_peers():
    port = free_port()
    link = MavlinkConnection(f"udpin:127.0.0.1:{port}")
    link.open()
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        forwarder = _Forwarder()
        link.forward_from(forwarder)
        mav = _mav()
        ground = ("127.0.0.1", 40001)
        forwarder.pending = [
            (("127.0.0.1", 40000), _position(mav, 1, 1.0) + _position(mav, 2, 2.0)),
            (ground, b"\x01\x02no frame"),
            (("127.0.0.1", 40000), _position(mav, 3, 3.0)),
        ]
        peer.sendto(_position(mav, 4, 4.0), ("127.0.0.1", port))  # on the socket itself
        time.sleep(0.05)
        got = [m.x for m in link.poll() if m.get_type() == "LOCAL_POSITION_NED"]
        assert got == [1.0, 2.0, 3.0] and link.forwarded  # the socket is the process's
        assert link.udp_peers() == [("127.0.0.1", 40000), ground]
        forwarder.main = True  # the process ended: the link reads its socket again
        forwarder.pending = [(("127.0.0.1", 40000), _position(mav, 5, 5.0))]
        got = [m.x for m in link.poll() if m.get_type() == "LOCAL_POSITION_NED"]
        assert got == [5.0, 4.0] and not link.forwarded  # forwarded first, then its own
        link.forward_from(None)
        peer.sendto(_position(mav, 6, 6.0), ("127.0.0.1", port))
        time.sleep(0.05)
        assert [m.x for m in link.poll()] == [6.0]
    finally:
        peer.close()
        link.close()
