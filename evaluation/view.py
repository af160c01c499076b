"""``stereo-avoid paper|replay --rerun`` and ``stereo-avoid replay FILE.mcap``.

The lockstep side of the companion's viewing and recording (:mod:`companion.viz`,
:mod:`companion.record`): a Rerun logger stepped by the lockstep harness, with the
simulator's ground truth, and the command that replays a companion recording. Both need
the optional ``view`` extra; without it they fail with a :class:`ViewOptionError` that
names it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from companion.viz.options import ViewOptionError, require_extra
from evaluation.harness import RunConfig
from evaluation.scenes import Scene

__all__ = ["LockstepView", "ViewOptionError", "replay_recording"]


class LockstepView:
    """Rerun view of a lockstep run: the mission's view plus the true world and pose.

    Raises :class:`ViewOptionError` for a bad ``spec`` or without rerun-sdk.
    """

    def __init__(self, spec: str, scene: Scene, cfg: RunConfig) -> None:
        from companion.viz.rerun_log import RerunTarget

        try:
            self.target = RerunTarget.parse(spec)
        except ValueError as exc:
            raise ViewOptionError(str(exc)) from None
        require_extra("--rerun", "rerun", "rerun-sdk")
        from companion.viz.rerun_log import RerunLogger, open_stream

        self.rec = open_stream(self.target, f"lockstep_{scene.name}")
        self.logger = RerunLogger(self.rec, cfg.perception.threshold_m)
        self.logger.log_truth_world(scene.world)
        self._n = 0

    def on_step(self, frame, pose, step, mission) -> None:
        """Harness hook: one frame (the pose is the plant's true pose at capture)."""
        self._n += 1
        pipeline = mission.pipeline
        self.logger.log_truth_pose(frame.capture_ns, pose.pos_ned_m)
        self.logger.log_step(
            frame,
            pose,
            step.output,
            goal_ned_m=pipeline.goal_ned_m,
            known_space=pipeline.known_space if self._n % 5 == 1 else None,
        )

    def close(self) -> None:
        self.rec.flush()
        if self.target.path is not None:
            self.rec.disconnect()


def replay_recording(path: Path, rerun: str | None, as_json: bool) -> int:
    """Replay ``path``; print a summary; 0 when identical, 1 when not, 2 on a bad file."""
    try:
        require_extra("stereo-avoid replay FILE.mcap", "mcap", "mcap")
    except ViewOptionError as exc:
        print(f"stereo-avoid replay: {exc}", file=sys.stderr)
        return 2
    from companion.record.replay import RecordingError, replay

    log = sys.stderr if as_json else sys.stdout
    on_frame = on_config = None
    rec = target = None
    if rerun is not None:
        from companion.viz.rerun_log import RerunTarget

        try:
            target = RerunTarget.parse(rerun)
            require_extra("--rerun", "rerun", "rerun-sdk")
        except (ValueError, ViewOptionError) as exc:
            print(f"stereo-avoid replay: {exc}", file=sys.stderr)
            return 2
        from companion.viz.rerun_log import RerunLogger, open_stream

        rec = open_stream(target, f"replay_{path.stem}")
        logger: RerunLogger | None = None

        def on_config(config) -> None:
            nonlocal logger
            logger = RerunLogger(rec, config.perception.threshold_m)

        def on_frame(done) -> None:
            assert logger is not None
            logger.log_step(done.frame, done.pose, done.step.output, goal_ned_m=done.goal_ned_m)

    print(f"replaying {path} through a fresh companion core (recorded clock)", file=log)
    try:
        result = replay(path, on_frame=on_frame, on_config=on_config)
    except RecordingError as exc:
        print(f"stereo-avoid replay: {exc}", file=sys.stderr)
        return 2
    finally:
        if rec is not None:
            rec.flush()
            if target is not None and target.path is not None:
                rec.disconnect()
    summary = result.summary()
    if as_json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"inputs               {summary['inputs']} ({summary['frames']} frames)")
        print(f"MAVLink compared     {summary['mavlink_compared']}")
        print(f"setpoints compared   {summary['setpoints_compared']}")
        if result.mismatches:
            verdict = f"DIFFERENT ({len(result.mismatches)})"
        elif result.identical:
            verdict = "IDENTICAL"
        else:
            verdict = "NOT SHOWN: the recording holds no setpoint to compare"
        print(f"outputs              {verdict}")
        for line in summary["first_mismatches"]:
            print(f"  {line}")
    return 0 if result.identical else 1
