"""The companion process: sockets and threads around the pure :class:`CompanionCore`.

One main thread (Zenoh's callback only decodes into the latest-frame slot). Each pass
waits on the MAVLink socket and the frame slot (``select``), then hands the core, as typed inputs
(:mod:`companion.core.events`) stamped with the host's monotonic clock, every MAVLink
message received, a clock tick and the newest frame, and carries out what it returns:
MAVLink messages and setpoints onto the link, ``COMPANION EVENT <name> {json}`` lines on
stdout, status documents on Zenoh. OBSTACLE_DISTANCE keeps its rate while this loop is
busy: on a UDP link (by default, ``[proximity] own_process``) a process of its own sends
it every period through this loop's socket, inherited through the fork, so the autopilot
sees one peer (:mod:`companion.proximity.process`). That process is the socket's only
reader: it takes its pose from the telemetry as it arrives and forwards every datagram,
unchanged and in order, to this loop, which parses them as if it had read them itself
(:meth:`MavlinkConnection.forward_from`); when the process ends or stops running, this
loop reads the socket itself (said once). This loop shares with it, in shared memory, the
map copy taken after each frame, the core's newest pose (the process's fallback), the
socket's peers, the signing timestamp and one MAVLink sequence counter. Elsewhere
(serial, TCP, no fork, ``own_process = false``, or a process that does not come up) a
watchdog thread sends when this loop has sent none for 1.5 periods
(:mod:`companion.proximity.stream`), reading the link itself for a fresh position (one
lock for the link; the main loop takes what it read first). Neither with a recorder or
viewer attached: a recording replays the core's sends bit for bit.
Around that, reporting only: the health file, the progress log, signing refusals and "no frames on
our key" hints. The log goes to stderr.
Recorders and viewers (``--record``, ``--rerun``) see every step's input and outputs
through :mod:`companion.observe`.
"""

from __future__ import annotations

import json
import logging
import random
import select
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TextIO

import zenoh

from companion.clock_model import FrameClock
from companion.config import CompanionConfig
from companion.core import (
    CompanionCore,
    Event,
    FrameReceived,
    Input,
    MavlinkReceived,
    Output,
    SendMavlink,
    SendSetpoint,
    Status,
    Tick,
)
from companion.frames_sub import LatestFrameSlot
from companion.health import HealthFile, HealthInputs
from companion.intake import FrameIntake
from companion.link.connection import MavlinkConnection
from companion.observe import CompanionObserver, Observers
from companion.phase_times import Phase, PhaseClocks
from companion.proximity.process import ProximityProcess, new_spec, own_process_refusal
from companion.proximity.sender import ProximitySender
from companion.proximity.shared import SharedLink, SharedPose
from companion.proximity.stream import SLAB_MARGIN_M, ProximityStream, snapshot_map
from companion.status import StatusPublisher
from protocols.keys import companion_status_key, stereo_key
from protocols.zenoh_session import zenoh_config

__all__ = ["CompanionService"]

_log = logging.getLogger("companion")
_PHASES_EVERY = 10  # progress lines between two lines of the phases' figures


class CompanionService:
    """The core plus its adapters; :meth:`open`, :meth:`run`, :meth:`close`.

    Parameters
    ----------
    config : CompanionConfig
    events : text stream for ``COMPANION EVENT`` lines (default stdout).
    observers : recorders and viewers (:mod:`companion.observe`); none by default.
    """

    def __init__(
        self,
        config: CompanionConfig,
        events: TextIO | None = None,
        observers: Sequence[CompanionObserver] = (),
    ) -> None:
        self.config = config
        self._events = events if events is not None else sys.stdout
        self.observers = Observers(observers)
        link = config.link
        self.link = MavlinkConnection(
            link.url,
            system_id=link.system_id,
            component_id=link.component_id,
            baud=link.baud,
            signing_key=link.signing_key,
        )
        self.core = CompanionCore(
            config,
            random.SystemRandom().getrandbits(32),
            report_pipeline=self.observers.wants_pipeline,
            phase_clocks=PhaseClocks(time.perf_counter_ns, time.thread_time_ns),
        )
        self.frame_key = stereo_key(config.vehicle_id)
        self.status_key = companion_status_key(config.vehicle_id)
        self.slot = LatestFrameSlot()
        self.intake = FrameIntake(
            self.frame_key,
            self.slot,
            lambda capture_ns: self.core.frame_time_plausible(capture_ns, time.monotonic_ns()),
        )
        self._session: zenoh.Session | None = None
        self._link_lock = threading.Lock()  # the link is read and written by two threads
        # OBSTACLE_DISTANCE's own thread or process
        self.proximity: ProximityStream | ProximityProcess | None = None
        self._mission = self.core.mission  # whose map the thread has a copy of
        self._shared_pose: SharedPose | None = None  # what the process was last given
        self._shared_pose_key: tuple | None = None
        self._status: StatusPublisher | None = None
        self.health: HealthFile | None = None  # --health-file: rewritten once a second
        self._next_report_s = 0.0
        self._next_progress_s = 0.0
        self._progress_lines = 0
        self._refusals_reported = 0

    @property
    def fatal(self) -> str | None:
        """Why the service stopped by itself (a refused takeoff), else None."""
        return self.core.fatal

    # ---- lifecycle -----------------------------------------------------------------
    def open(self) -> None:
        """Open MAVLink and Zenoh; start the OBSTACLE_DISTANCE thread."""
        self.link.open()
        sender = self.core.proximity
        if sender is not None and self.config.proximity.thread and not self.observers:
            self.proximity = self._start_proximity(sender)
        self._session = zenoh.open(zenoh_config(self.config.zenoh))
        self.intake.open(self._session, time.monotonic())
        self._status = StatusPublisher(self._session, self.status_key)
        self._status.open()
        if self.observers:
            self.observers.on_start(self.config, self.core.instance_id)

    def _start_proximity(self, sender: ProximitySender) -> ProximityStream | ProximityProcess:
        """The stream's own process where the link allows one (forked here, before Zenoh
        starts its threads), else (or when it does not come up) the watchdog thread."""
        link = self.config.link
        if self.config.proximity.own_process:
            refusal = own_process_refusal(link.url)
            fd = self.link.fileno()
            if refusal is None and fd is None:
                refusal = "the link has no socket to share"
            if refusal is None:
                process = ProximityProcess(sender, new_spec(self.config, sender, fd))
                try:
                    process.start(self._shared_link())
                except RuntimeError as exc:
                    _log.error("%s: the watchdog thread sends instead", exc)
                else:
                    if process.wait_ready():
                        self.link.forward_from(process)
                        self.link.seq_source = process.next_seq
                        return process
                    process.close()
                    _log.error(
                        "the OBSTACLE_DISTANCE process did not start within its start-up "
                        "time: the watchdog thread sends instead"
                    )
            else:
                _log.info(
                    "OBSTACLE_DISTANCE from a watchdog thread, not a process of its own: %s "
                    "(it keeps the rate less well on a loaded processor)",
                    refusal,
                )
        stream = ProximityStream(
            sender, self._poll_link, self._send, (link.target_system, link.target_component)
        )
        stream.start()
        return stream

    def readiness_line(self) -> str:
        return (
            f"COMPANION READY mavlink={self.config.link.url} zenoh={self.config.zenoh.describe()} "
            f"key={self.frame_key} status={self.status_key} "
            f"sysid={self.config.link.system_id} compid={self.config.link.component_id} "
            f"signing={'on' if self.link.signing else 'off'}"
        )

    def close(self) -> dict[str, Any]:
        if self.proximity is not None:
            self.proximity.close()
        self.intake.close()  # first: no frame is counted after the final figures are taken
        stats = self.stats()
        if self.health is not None:
            self.health.stopped(self.fatal or "the companion stopped")
        if self._status is not None:
            self._status.close()
        if self._session is not None:
            self._session.close()
            self._session = None
        self.link.close()
        self.slot.close()
        self.observers.close()
        return stats

    def stats(self) -> dict[str, Any]:
        f = self.slot.counters
        return {
            **self.core.stats(),
            "frames_received": f.received,
            "frames_decoded": f.decoded,
            "frames_malformed": f.malformed,
            "frames_superseded": f.superseded,
            "frames_implausible_at_intake": f.implausible_time,
            "frames_before_clock": f.no_clock,
            "mavlink": self.link.counters.as_dict(),
            "obstacle_distance_thread": None
            if self.proximity is None
            else self.proximity.figures(),
        }

    # ---- main loop -----------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool]) -> None:
        link_fd = self.link.fileno()
        timeout = 0.01 if link_fd is not None else 0.002
        while not should_stop() and self.fatal is None:
            fds = [self.slot.fileno()]
            if self.proximity is not None:
                fds.append(self.proximity.fileno())  # with the process: what it forwards
            if link_fd is not None and not self.link.forwarded:
                fds.append(link_fd)
            try:
                select.select(fds, [], [], timeout)
            except InterruptedError:
                continue
            phases = self.core.phases
            with phases.timed(Phase.MAVLINK):
                for msg in self._received():
                    self._step(MavlinkReceived(msg, time.monotonic_ns()))
            self._share_with_process()
            with phases.timed(Phase.TICK):
                self._step(Tick(time.monotonic_ns()))
            frame = self.slot.take()
            if frame is not None:
                now_ns = time.monotonic_ns()
                with phases.timed(Phase.FRAME):
                    self._step(FrameReceived(frame, now_ns, now_ns))
                with phases.timed(Phase.SNAPSHOT):
                    self._snapshot_map(frame.capture_ns)
                # at once: the core takes the frame's data age (capture → its setpoint on
                # the wire) from the next input's clock (companion.guidance.latency)
                self._step(Tick(time.monotonic_ns()))
            self._report(time.monotonic())

    def _step(self, event: Input) -> None:
        """One core step: carry its outputs out, then show both to the observers."""
        outputs = self.core.step(event)
        self._carry_out(outputs)
        if self.observers:
            self.observers.on_step(event, outputs)
        if self.proximity is not None:
            self.proximity.set_clock(self.core.frame_clock_rate(), self.core.poses.newest_ns)
            if self.core.mission is not self._mission:  # reset: the old map goes too
                self._mission = self.core.mission
                self.proximity.set_map(None)

    # ---- the link, shared with the OBSTACLE_DISTANCE thread ----------------------------
    def _poll_link(self) -> list:
        with self._link_lock:
            return self.link.poll()

    def _send(self, msg) -> None:
        with self._link_lock:
            self.link.send(msg)

    def _received(self) -> list:
        """What the OBSTACLE_DISTANCE thread read, then what waits on the link."""
        if self.proximity is None:
            return self._poll_link()
        earlier = self.proximity.take_inbox()
        now = self._poll_link()
        self.proximity.observe(now, time.monotonic_ns())
        return earlier + now

    def _share_with_process(self) -> None:
        """Hand the OBSTACLE_DISTANCE process the core's newest pose (when it changed), the
        socket's peers and the signing timestamp."""
        if not isinstance(self.proximity, ProximityProcess):
            return
        telemetry = self.core.telemetry
        key = (telemetry.poses.newest_ns, telemetry.position_host_ns)
        pose = self._shared_pose if key == self._shared_pose_key else self._pose_to_share()
        self._shared_pose_key, self._shared_pose = key, pose
        self.proximity.share(pose, self._shared_link())

    def _pose_to_share(self) -> SharedPose | None:
        newest = self.core.telemetry.newest_pose()
        if newest is None:
            return None
        frame_ns, received_ns, pose = newest
        return SharedPose(
            pos_ned_m=tuple(float(x) for x in pose.pos_ned_m),
            vel_ned_mps=tuple(float(x) for x in pose.vel_ned_mps),
            yaw_rad=float(pose.yaw_rad),
            frame_ns=int(frame_ns),
            received_ns=int(received_ns),
            host_frame_clock=self.core.clock.frame_clock is FrameClock.HOST,
        )

    def _shared_link(self) -> SharedLink:
        return SharedLink(tuple(self.link.udp_peers() or ()), self.link.signing_timestamp)

    def _snapshot_map(self, capture_ns: int) -> None:
        """Hand the OBSTACLE_DISTANCE thread a copy of the map the frame just updated."""
        if self.proximity is None:
            return
        space = self.core.mission.pipeline.known_space
        if space is None or space.frames == 0:
            self.proximity.set_map(None)
            return
        pose = self.proximity.pose()
        cfg = self.config.proximity
        half_m = cfg.band_half_height_m + cfg.unseen_extension_m + SLAB_MARGIN_M
        down_m = None if pose is None else pose.pos_ned_m[2]
        self.proximity.set_map(snapshot_map(space, down_m, half_m, capture_ns))

    def _carry_out(self, outputs: Iterable[Output]) -> None:
        """Do what the core asked, in order; stamp when setpoints went on the wire."""
        returned_ns = time.monotonic_ns()
        sent_ns: int | None = None
        for out in outputs:
            if isinstance(out, SendSetpoint):
                self._send(out.message)
                sent_ns = time.monotonic_ns()
            elif isinstance(out, SendMavlink):
                self._send(out.message)
            elif isinstance(out, Event):
                self._event(out)
            elif isinstance(out, Status) and self._status is not None:
                doc = _with_latency(out, returned_ns, sent_ns)
                if isinstance(doc.get("pipeline"), dict):
                    superseded = self.slot.counters.superseded
                    doc["pipeline"] = {**doc["pipeline"], "frames_superseded": superseded}
                if self.proximity is not None:
                    doc["obstacle_distance_stream"] = self.proximity.figures()
                self._status.publish(doc)

    def _event(self, event: Event) -> None:
        line = f"COMPANION EVENT {event.name} {json.dumps(event.fields, default=str)}"
        print(line, file=self._events, flush=True)

    # ---- reporting -----------------------------------------------------------------
    def _report(self, now_s: float) -> None:
        if isinstance(self.proximity, ProximityProcess):
            ended = self.proximity.check()
            if ended is not None:
                _log.error("%s", ended)
                self._event(Event("obstacle_distance_process_ended", {"reason": ended}))
        no_frames = self.intake.watch(now_s)
        if no_frames is not None:
            self._event(no_frames)
        if now_s >= self._next_report_s:
            self._next_report_s = now_s + self.config.link.heartbeat_period_s
            self._report_refusals()
            self._report_health(now_s)
        if now_s >= self._next_progress_s:
            self._next_progress_s = now_s + self.config.status_log_period_s
            f = self.slot.counters
            _log.info(
                "%s; frames received %d (malformed %d, superseded %d)%s",
                self.core.progress_text(),
                f.received,
                f.malformed,
                f.superseded,
                self._stream_text(),
            )
            self._progress_lines += 1
            if self._progress_lines % _PHASES_EVERY == 0:  # where the work went, CPU
                _log.info("work per run (CPU): %s", self.core.phases.text())

    def _stream_text(self) -> str:
        """The OBSTACLE_DISTANCE process's or watchdog thread's figures, for the progress
        line."""
        if self.proximity is None:
            return ""
        f = self.proximity.figures()
        if not f.get("process"):
            return f"; OBSTACLE_DISTANCE watchdog thread: {f['fills']} sends of its own"
        state = "sending" if f["alive"] else "ENDED"
        return (
            f"; OBSTACLE_DISTANCE process {state}: {f['sent']} sent, longest gap "
            f"{f['longest_gap_s']:.2f} s"
            + (f", {f['stale_pose']} all unknown (pose > 0.5 s old)" if f["stale_pose"] else "")
            + (f", {f['no_peer']} with no peer yet" if f["no_peer"] else "")
            + (f", {f['errors']} errors" if f["errors"] else "")
            + f"; it read {f['forwarded']} datagrams for this loop"
            + (f" ({f['forward_dropped']} dropped)" if f["forward_dropped"] else "")
            + (", this loop reads the socket" if f["main_reads"] else "")
        )

    def _report_health(self, now_s: float) -> None:
        """Rewrite the health file (companion.health) from the state we already have."""
        if self.health is None:
            return
        core = self.core
        self.health.update(
            HealthInputs(
                now_s=now_s,
                link_up=core.link_up,
                autopilot_seen=core.autopilot_seen,
                link_url=self.config.link.url,
                telemetry_stamp_ns=core.poses.newest_ns,
                frames_received=self.slot.counters.received,
                flying=core.flying,
                fatal=core.fatal,
            )
        )

    def _report_refusals(self) -> None:
        refused = self.link.counters.signing_refused
        if refused > self._refusals_reported:
            _log.error(
                "MAVLink signing: %d message(s) from the link refused (unsigned or bad "
                "signature, %d in total): check that both ends use the same key",
                refused - self._refusals_reported,
                refused,
            )
            self._event(Event("signing_refused", {"total": refused}))
            self._refusals_reported = refused


def _with_latency(status: Status, returned_ns: int, sent_ns: int | None) -> dict[str, Any]:
    """The status document with the frame's latencies [ms, host monotonic clock]."""

    def ms(delta_ns: float) -> float:
        return round(delta_ns * 1e-6, 3)

    capture = status.host_capture_ns
    return {
        **status.document,
        "latency_ms": {
            "receive_to_compute_start": ms(status.started_ns - status.received_ns),
            "compute": ms(returned_ns - status.started_ns),
            "receive_to_send": None if sent_ns is None else ms(sent_ns - status.received_ns),
            "capture_to_send": None
            if sent_ns is None or capture is None
            else ms(sent_ns - capture),
        },
    }
