"""Sensor faults with real filter and worker processes: the test is the ingest, streaming the
procedural world in real time with an odometry outage, a camera outage and clock jumps.

Schedule (sensor seconds; G = $LOCNERF_FAULT_ODOMETRY_GAP, 2 s in the suite, 10 s for the docs):
[0, 3) normal; [3, 3+G) no odometry (images go on); 3 s normal; 3 s without images; 2 s normal;
then one odometry message stamped 2 s ahead, one image stamped 3 s back, one odometry message
stamped 0.5 s back; 3 s normal. The filter starts from an initial-pose command at the true pose.
"""

from __future__ import annotations

import dataclasses
import os
import threading

import torch

from locnerf.geometry.metrics import translation_error
from locnerf.messages import keys
from locnerf.messages.codec import encode
from locnerf.messages.schemas import InitialPoseCommand
from locnerf.sim.events import GroundTruthEvent, ImageEvent, OdometryEvent, SensorEvent
from locnerf.sim.world import ProceduralWorld
from locnerf_services.filter_loop.__main__ import FilterProcessConfig
from locnerf_services.filter_loop.service import FilterLoopConfig
from locnerf_services.sensor_ingest.service import Pacer, event_message
from locnerf_services.sensor_ingest.world_source import WorldSourceConfig, world_events
from locnerf_services.supervisor import write_config
from tests.integration.conftest import ROBOT, wait_for
from tests.integration.fault_report import covariance_trace, poses_lost, report

RATE = 15  # odometry ticks per second; images are every third tick


@dataclasses.dataclass(frozen=True)
class Schedule:
    """When each fault happens, in odometry ticks (stamp × 15)."""

    gap: float

    def tick(self, seconds: float) -> int:
        return round(seconds * RATE)

    @property
    def odometry_gap(self) -> tuple[float, float]:
        return 3.0, 3.0 + self.gap

    @property
    def image_gap(self) -> tuple[float, float]:
        start = self.odometry_gap[1] + 3.0
        return start, start + 3.0

    @property
    def jumps(self) -> float:
        return self.image_gap[1] + 2.0

    @property
    def end(self) -> float:
        return self.jumps + 3.0

    def apply(self, event: SensorEvent) -> SensorEvent | None:
        """The event as the faulty sensors deliver it (None: not delivered)."""
        tick, jumps = self.tick(event.stamp), self.tick(self.jumps)
        if isinstance(event, OdometryEvent):
            if self.tick(self.odometry_gap[0]) <= tick < self.tick(self.odometry_gap[1]):
                return None
            if tick == jumps:
                return dataclasses.replace(event, stamp=event.stamp + 2.0)
            if tick == jumps + 15:
                return dataclasses.replace(event, stamp=event.stamp - 0.5)
        if isinstance(event, ImageEvent):
            if self.tick(self.image_gap[0]) <= tick < self.tick(self.image_gap[1]):
                return None
            if tick == jumps + 6:
                return dataclasses.replace(event, stamp=event.stamp - 3.0)
        return event


def test_odometry_and_camera_outages_and_clock_jumps(hub, tmp_path):
    stack, observer, bus = hub
    schedule = Schedule(gap=float(os.environ.get("LOCNERF_FAULT_ODOMETRY_GAP", "2")))
    config = write_config(tmp_path / "filter.toml", FilterProcessConfig(loop=FilterLoopConfig(start="wait", update_timeout=2.0)))
    stack.start("filter", "run", "filter", "--robot-id", ROBOT, "--device", "cpu", "--config", str(config))
    stack.start("w", "run", "worker", "--robot-id", ROBOT, "--device", "cpu", "--worker-id", "w")
    wait_for(lambda: observer.workers() == ["w"], 120, "the filter and its worker", stack)

    world, source = ProceduralWorld.default(), WorldSourceConfig(duration=schedule.end)
    start = next(e for e in world_events(world, source, seed=0) if isinstance(e, GroundTruthEvent))
    covariance = torch.diag(torch.tensor([1e-4] * 3 + [1e-4] * 3, dtype=torch.float64))
    bus.publish(
        keys.key(ROBOT, keys.INITIAL_POSE), encode(InitialPoseCommand(stamp=0.0, T_world_cam=start.T_world_cam.tolist(), covariance=covariance.tolist()))
    )
    wait_for(lambda: observer.status.state == "running", 30, "the initial pose command", stack)

    truth: dict[float, torch.Tensor] = {}
    merged_at: dict[str, int] = {}
    statuses_at: dict[str, int] = {}
    marks = {
        schedule.tick(schedule.odometry_gap[0] + 0.5): "odometry_gap_early",
        schedule.tick(schedule.odometry_gap[1] - 0.1): "odometry_gap_end",
        schedule.tick(schedule.image_gap[0] + 1.0): "image_gap_early",
        schedule.tick(schedule.image_gap[1]): "image_gap_end",
    }

    def stream() -> None:
        for event in Pacer(1.0).paced(world_events(world, source, seed=0)):
            if isinstance(event, GroundTruthEvent):
                truth[event.stamp] = event.T_world_cam
                if schedule.tick(event.stamp) in marks:
                    merged_at[marks[schedule.tick(event.stamp)]] = observer.counter("updates_merged")
                    statuses_at[marks[schedule.tick(event.stamp)]] = observer.statuses
            delivered = schedule.apply(event)
            if delivered is not None:
                bus.publish(*event_message(ROBOT, delivered))

    streamer = threading.Thread(target=stream)
    streamer.start()
    streamer.join(timeout=schedule.end + 60)
    wait_for(lambda: observer.poses and observer.poses[-1].stamp >= schedule.end - 0.2, 10, "the last poses", stack)
    assert stack.processes["filter"].poll() is None and stack.processes["w"].poll() is None
    wait_for(lambda: observer.status.stamp >= schedule.end - 1.0, 5, "a status after the stream", stack)
    counters = dict(observer.status.counters)

    with observer.lock:
        poses = list(observer.poses)

    def between(a: float, b: float):
        return [p for p in poses if a <= p.stamp < b]

    def worst_error(selected) -> float:
        return max(float(translation_error(torch.tensor(p.T_world_cam, dtype=torch.float64), truth[p.stamp])) for p in selected if p.stamp in truth)

    # Odometry outage: no pose inside it (poses are published per odometry message); then the
    # stream resumes at rate, the particles carried across the outage by the odometry increment.
    gap_start, gap_end = schedule.odometry_gap
    assert between(gap_start + 0.01, gap_end - 0.01) == []
    status_during_gap = statuses_at["odometry_gap_end"] - statuses_at["odometry_gap_early"]
    assert status_during_gap >= 1  # the filter is alive and reports at 1 Hz through the outage
    after_gap = between(gap_end, gap_end + 3.0)
    assert len(after_gap) >= 0.8 * 3 * RATE
    assert counters.get("bad_image_ahead", 0) >= 1, counters  # images during the outage cannot be placed
    assert worst_error(between(gap_end, schedule.image_gap[0])) < 0.3

    # Camera outage: poses continue from odometry alone, covariance grows, no update merged; updates resume after.
    image_start, image_end = schedule.image_gap
    assert len(between(image_start, image_end)) >= 0.8 * 3 * RATE
    early, late = between(image_start + 0.9, image_start + 1.1)[0], between(image_end - 0.1, image_end)[-1]
    assert covariance_trace(late) > 1.5 * covariance_trace(early)
    assert merged_at["image_gap_end"] == merged_at["image_gap_early"]
    resumed = between(schedule.jumps - 0.2, schedule.jumps)[-1]
    assert counters["updates_merged"] > merged_at["image_gap_end"] and covariance_trace(resumed) < covariance_trace(late)

    # Clock jumps: the 2-s-ahead odometry stamp is accepted, the stamps after it are dropped until
    # odometry_resync (3) of them start a new odometry session; the stray old stamp and the image
    # from the past are dropped and counted; poses go on.
    assert counters["odometry_restarts"] == 1 and counters["bad_stamp_backwards"] == 3 and counters["bad_image_too_old"] >= 1, counters
    assert len(between(schedule.jumps + 1.5, schedule.end)) >= 0.8 * 1.5 * RATE
    assert worst_error(between(schedule.jumps + 2.5, schedule.end)) < 0.3
    report(
        "sensor_faults",
        odometry_gap_s=schedule.gap,
        poses_during_odometry_gap=len(between(gap_start + 0.01, gap_end - 0.01)),
        status_messages_during_odometry_gap=status_during_gap,
        images_dropped_ahead=counters.get("bad_image_ahead", 0),
        error_after_odometry_gap_m=round(worst_error(between(gap_end, schedule.image_gap[0])), 3),
        covariance_trace_growth=round(covariance_trace(late) / covariance_trace(early), 2),
        poses_lost_camera_gap=poses_lost(poses, image_start, image_end),
        poses_lost_clock_jumps=poses_lost(poses, schedule.jumps - 1, schedule.end),
        odometry_restarts=counters["odometry_restarts"],
        stamps_backwards=counters["bad_stamp_backwards"],
        images_too_old=counters["bad_image_too_old"],
    )
