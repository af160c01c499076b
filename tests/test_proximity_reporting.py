"""While the companion only reports (a pilot flies), a frame feeds the map and
OBSTACLE_DISTANCE and nothing else (issue 34): guidance, planning, the envelope and the
hold's way out are skipped and counted so; in control, every phase runs on every frame.

The core in process (no sockets, no sleeps), through the scripted autopilot of
``tests/test_companion_core.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_companion_core import GUIDED, LOITER, Rig

from companion.config import CompanionConfig
from companion.phase_times import Phase, PhaseClocks, PhaseTimes
from companion.pipeline import AvoidancePipeline, PoseAtCapture
from protocols.camera import CameraModel
from protocols.stereo_frame import StereoFrame

pytestmark = pytest.mark.unit

_GUIDANCE_WORK = (Phase.GUIDANCE, Phase.PLANNING, Phase.ENVELOPE, Phase.HOLD)


def _reporting_rig() -> Rig:
    """The autopilot in LOITER (a pilot flies) and a companion that never asks for a mode."""
    config = CompanionConfig()
    config = dataclasses.replace(config, link=dataclasses.replace(config.link, request_mode=False))
    rig = Rig(config)
    rig.custom_mode = LOITER
    return rig


def test_not_in_control_a_frame_feeds_the_map_and_the_report_only():
    """In LOITER: every processed frame ran the matcher, the map update, the boundaries
    and OBSTACLE_DISTANCE's sectors; guidance, planning, the envelope and the hold were
    skipped on every one; no setpoint, no speed bound stated, status says not guided."""
    rig = _reporting_rig()
    rig.run(4.0)
    phases = rig.core.phases
    processed = rig.core.counters.frames_processed
    assert processed >= 100  # 30 Hz for ~4 s after the clock
    for phase in (Phase.PERCEPTION, Phase.KNOWN_SPACE, Phase.BOUNDARIES, Phase.SECTORS):
        assert phases.runs(phase) == processed, phase
    for phase in _GUIDANCE_WORK:
        assert phases.runs(phase) == 0, phase
        assert phases.skipped(phase) == processed, phase
    assert not rig.setpoints() and not rig.events("steering")
    statuses = rig.statuses()
    assert len(statuses) == processed and not any(s["guided"] for s in statuses)
    assert statuses[-1]["pipeline"]["speed_limit_mps"] is None
    assert rig.core.proximity.from_frames == processed  # one OBSTACLE_DISTANCE per frame
    stats = rig.core.stats()["phases"]
    assert stats["guidance"] == {**stats["guidance"], "runs": 0, "skipped": processed}


def test_taking_control_runs_every_phase_on_every_frame_again():
    """The pilot hands over (GUIDED): from the first frame in control guidance, the
    envelope and the hold run on every frame, and the skips stop."""
    rig = _reporting_rig()
    rig.run(3.0)
    skipped = rig.core.phases.skipped(Phase.GUIDANCE)
    assert skipped > 0
    rig.custom_mode = GUIDED
    rig.run(1.05)  # the heartbeat with GUIDED, then frames in control
    before = rig.core.counters.frames_processed
    rig.run(1.0)
    phases = rig.core.phases
    guided_frames = rig.core.counters.frames_processed - before
    assert guided_frames >= 25
    assert phases.skipped(Phase.GUIDANCE) == rig.core.phases.skipped(Phase.ENVELOPE)
    for phase in (Phase.GUIDANCE, Phase.ENVELOPE, Phase.HOLD):
        assert phases.runs(phase) >= guided_frames, phase
    assert phases.skipped(Phase.GUIDANCE) <= skipped + 3  # at most the frames before it
    assert rig.statuses()[-1]["guided"] and rig.setpoints()


def test_steering_rig_never_skips_guidance_once_in_control():
    """A companion that engages GUIDED itself: after the listening window every frame is
    guided (the companion's own behaviour is unchanged)."""
    rig = Rig()
    rig.run(3.0)
    assert rig.events("steering")
    skipped = rig.core.phases.skipped(Phase.GUIDANCE)
    runs = rig.core.phases.runs(Phase.GUIDANCE)
    rig.run(2.0)
    phases = rig.core.phases
    assert phases.skipped(Phase.GUIDANCE) == skipped
    assert phases.runs(Phase.GUIDANCE) - runs >= 55
    assert all(s["guided"] for s in rig.statuses()[-55:])


def test_not_guided_output_matches_the_guided_map_and_sends_nothing_of_its_own():
    """The same frames with and without guidance: the same map (voxel for voxel) and the
    same boundaries; the skipped output stands at the vehicle, states no bound and is
    not guided."""
    camera = CameraModel(width_px=160, height_px=120)
    rng = np.random.default_rng(3)
    pos = np.array([0.0, 0.0, -7.0])
    pose = PoseAtCapture(pos, np.array([1.0, 0.0, 0.0]), np.eye(3))
    guided = AvoidancePipeline(goal_ned_m=(20.0, 0.0, -7.0))
    skipped = AvoidancePipeline(goal_ned_m=(20.0, 0.0, -7.0))
    for seq in range(4):
        left = rng.integers(0, 255, (camera.height_px, camera.width_px), dtype=np.uint8)
        right = np.roll(left, -10, axis=1)  # 10 px of disparity: 3.6 m, inside 4 m
        frame = StereoFrame(seq, (seq + 1) * 33_000_000, camera.intrinsics, left, right)
        a = guided.process(frame, pose)
        b = skipped.process(frame, pose, guide=False)
    np.testing.assert_array_equal(guided.known_space.grid, skipped.known_space.grid)
    assert len(a.boundaries) == len(b.boundaries) > 0
    assert a.guided and not b.guided
    np.testing.assert_array_equal(b.setpoint_ned_m, pos)
    assert b.envelope.speed_limit_mps == 0.0 and not b.envelope.overspeed
    assert b.envelope.speed_mps == pytest.approx(1.0)
    assert skipped.phases.runs(Phase.GUIDANCE) == 0 and skipped.phases.skipped(Phase.HOLD) == 4
    assert guided.phases.runs(Phase.GUIDANCE) == 4 and guided.phases.skipped(Phase.HOLD) == 0


def test_phase_times_count_without_clocks_and_time_with_them():
    """No clocks: runs and skips only, nothing read. Injected clocks: each run's wall and
    CPU time summed, the longest kept, means per run in ms."""
    bare = PhaseTimes()
    with bare.timed(Phase.PERCEPTION):
        pass
    bare.skip(Phase.GUIDANCE, Phase.ENVELOPE)
    assert bare.as_dict()["perception"]["runs"] == 1
    assert bare.as_dict()["perception"]["mean_wall_ms"] == 0.0
    assert bare.skipped(Phase.GUIDANCE) == 1 and set(bare.as_dict()) == {
        "perception",
        "guidance",
        "envelope",
    }
    ticks = iter(range(0, 10**9, 1_000_000))  # each read 1 ms later than the last
    timed = PhaseTimes(PhaseClocks(lambda: next(ticks), lambda: next(ticks)))
    for _ in range(3):
        with timed.timed(Phase.KNOWN_SPACE):
            pass
    figure = timed.as_dict()["known_space"]
    # reads: wall0, cpu0, wall1, cpu1 → wall 2 ms, CPU 2 ms per run
    assert figure["runs"] == 3
    assert figure["mean_wall_ms"] == pytest.approx(2.0)
    assert figure["mean_cpu_ms"] == pytest.approx(2.0)
    assert figure["max_wall_ms"] == pytest.approx(2.0)
    assert "known_space 3x2.0ms" in timed.text()


def test_the_frame_path_takes_the_newest_frame_and_never_an_older_one():
    """Three frames arrive while the main loop is busy: it takes the newest, the two older
    are counted superseded; a frame older than the last processed one is refused
    (``frames_stale``), never processed after a newer one."""
    from companion.core import FrameReceived
    from companion.frames_sub import LatestFrameSlot

    rig = _reporting_rig()
    rig.run(2.0)
    slot = LatestFrameSlot()
    flat = np.full((rig.camera.height_px, rig.camera.width_px), 128, dtype=np.uint8)
    now_ms = rig.boot_ms
    frames = [
        StereoFrame(1000 + i, (now_ms - 30 + 10 * i) * 1_000_000, rig.camera.intrinsics, flat, flat)
        for i in range(3)
    ]
    for frame in frames:
        slot.put(frame)
    taken = slot.take()
    assert taken is frames[-1] and slot.take() is None
    assert slot.counters.superseded == 2 and slot.counters.taken == 1
    processed = rig.core.counters.frames_processed
    rig.feed(FrameReceived(taken, rig.now_ns, rig.now_ns))
    assert rig.core.counters.frames_processed == processed + 1
    stale = rig.core.counters.frames_stale
    rig.feed(FrameReceived(frames[0], rig.now_ns, rig.now_ns))  # older, arriving late
    assert rig.core.counters.frames_processed == processed + 1
    assert rig.core.counters.frames_stale == stale + 1
    slot.close()
