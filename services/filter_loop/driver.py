"""The filter thread's schedule on the bus: odometry goes before any other work.

Zenoh callbacks only enqueue (design section 3): odometry into the urgent lane; update results and refusals,
commands, liveliness changes and image arrivals into the normal lane (the image itself goes into a
one-slot buffer, newest only). One thread calls :meth:`FilterDriver.step` in a loop, which

1. takes the most urgent message, handles it and publishes its output at once (a pose leaves as
   soon as its odometry has been handled, before anything else is computed; the particles'
   prediction with that odometry runs right after the pose has been published);
2. returns if odometry is waiting (the next step handles it): no update work while a pose is due;
3. recomputes the estimate if a merge changed the particles (a pose due meanwhile does it itself);
   returns again if odometry arrived;
4. takes the newest image; returns again if odometry arrived meanwhile;
5. runs the periodic work (expire, start an update, particle cloud, status) and publishes it.

Each early return publishes the status if it is due: odometry that arrives faster than the thread
handles it (an overload) would otherwise starve step 5, and with it the one message that reports it.

With a ROS 2 bridge (:mod:`services.ros2.filter_bridge`), ROS odometry, images and commands
join the same lanes as locnerf's own (their payload is a ``(CDR, attachment)`` pair, translated on
this thread; a translation failure is counted like any bad message), camera infos join the normal
lane, and the bridge publishes the ROS counterparts of every pose and particle cloud. ROS depth
images wait in a small buffer of the bridge (a few of the newest; they are large), each announced
by a ``depth`` arrival in the normal lane, whose handling translates one of them into the bridge's
pairing. A ROS colour image taken in step 4 waits in that pairing for the depth image of its
stamp, and step 4 asks for the finished frame on every turn: the turn whose step 1 handles a late
depth image completes the pair in its step 4 (a colour image without depth goes alone once the
pairing's wait is over, at the first turn after it).

An odometry message therefore waits at most for one piece of non-odometry work that had already
started when it arrived. The durations of every kind of work and the odometry's wait are kept in
:class:`ThreadTimings` and logged every ``log_period`` seconds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError
from locnerf_services.filter_loop.lanes import LaneInbox
from locnerf_services.filter_loop.service import FilterLoop, Outgoing
from locnerf_services.filter_loop.timings import ThreadTimings
from locnerf_services.transport import Bus, LatestSlot
from locnerf_services.transport.bus import Closeable

if TYPE_CHECKING:
    from locnerf_services.ros2.filter_bridge import FilterRos2Bridge

logger = logging.getLogger(__name__)

URGENT, NORMAL = 0, 1

# (kind, key, payload, arrival in monotonic seconds); a ROS 2 payload is (CDR, attachment)
Arrival = tuple[str, str, Any, float]


class FilterDriver:
    """Connects a :class:`FilterLoop` to a bus and runs its thread's schedule.

    Args:
        loop: the filter (owned by the thread that calls :meth:`step`).
        bus: where messages come from and go to.
        clock: monotonic seconds (arrival stamps and timings).
        log_period: seconds between two timing summaries in the log.
        ros2: the ROS 2 bridge, if the filter speaks ROS 2.
    """

    def __init__(
        self,
        loop: FilterLoop,
        bus: Bus,
        clock: Callable[[], float] = time.monotonic,
        log_period: float = 30.0,
        ros2: FilterRos2Bridge | None = None,
    ) -> None:
        self.loop = loop
        self.bus = bus
        self.ros2 = ros2
        self.clock = clock
        self.log_period = log_period
        self.inbox: LaneInbox[Arrival] = LaneInbox(lanes=2, capacity=1024)
        self.images: LatestSlot[tuple[str, Any]] = LatestSlot()
        self.timings = ThreadTimings()
        self._handlers: dict[str, Callable[[str, Any], Outgoing]] = {
            "odometry": lambda key, payload: self._translated(key, payload, "odometry", loop.handle_odometry),
            "result": lambda _key, payload: loop.handle_result(payload),
            "refusal": lambda _key, payload: loop.handle_refusal(payload),
            "initial_pose": lambda key, payload: self._translated(key, payload, "initial_pose", loop.handle_initial_pose),
            "global_localization": lambda key, payload: self._translated(key, payload, "global_localization", loop.handle_global_localization),
            "camera_info": lambda key, payload: self._translated(key, payload, "camera_info", lambda _none: []),
            "depth_camera_info": lambda key, payload: self._translated(key, payload, "depth_camera_info", lambda _none: []),
            "depth": lambda _key, _payload: self._take_depth(),
            "worker": loop.worker_changed,
            "image": lambda _key, _payload: self._take_image(),
        }
        self._last_log = clock()

    def subscribe(self) -> list[Closeable]:
        """Subscribe the callbacks (they only enqueue); close the handles to stop receiving."""
        robot = self.loop.robot_id
        topics = {
            "result": keys.UPDATE_RESULT,
            "refusal": keys.UPDATE_REFUSAL,
            "initial_pose": keys.INITIAL_POSE,
            "global_localization": keys.GLOBAL_LOCALIZATION,
        }
        handles = [self.bus.subscribe(keys.key(robot, keys.ODOMETRY), lambda key, payload: self._arrive(URGENT, "odometry", key, payload))]
        handles += [
            self.bus.subscribe(keys.key(robot, topic), lambda key, payload, kind=kind: self._arrive(NORMAL, kind, key, payload))
            for kind, topic in topics.items()
        ]
        handles.append(self.bus.subscribe(keys.key(robot, keys.IMAGE), self._image_arrived))
        handles.append(self.bus.watch_liveliness(keys.workers_alive_pattern(robot), lambda key, alive: self._arrive(NORMAL, "worker", key, alive)))
        if self.ros2 is not None:
            self.ros2.subscribe(
                lambda urgent, kind, key, received: self._arrive(URGENT if urgent else NORMAL, kind, key, received),
                lambda key, received: self._image_arrived(key, received),
                lambda: self._arrive(NORMAL, "depth", "", None),
            )
            handles.append(self.ros2)
        return handles

    def _counted(self, translate: Callable[..., Any], *args: Any) -> Any:
        """``translate(*args)``, a ROS 2 translation; a failure is counted as a bad message and gives None."""
        try:
            return translate(*args)
        except DecodeError as error:
            self.loop.bad.record(error.kind, error.reason)
            return None

    def _translated(self, key: str, payload: Any, kind: str, handle: Callable[[Any], Outgoing]) -> Outgoing:
        """``handle`` a locnerf payload; a ROS 2 one, ``(CDR, attachment)``, is translated by the
        bridge first (a failure is counted as a bad message and dropped; a camera info gives nothing to handle)."""
        if isinstance(payload, tuple):
            payload = self._counted(getattr(self.ros2, kind), key, payload)
            if payload is None:
                return []
        return handle(payload)

    def _arrive(self, lane: int, kind: str, key: str, payload: Any) -> None:
        self.inbox.put(lane, (kind, key, payload, self.clock()))

    def _image_arrived(self, key: str, payload: Any) -> None:
        self.images.put((key, payload))
        self.inbox.put(NORMAL, ("image", key, None, self.clock()))

    def _take_depth(self) -> Outgoing:
        """Translate the oldest ROS depth image waiting in the bridge into its pairing (a colour image
        it completes leaves in step 4 of this turn)."""
        self._counted(self.ros2.sensors.take_depth)
        return []

    def _take_image(self) -> Outgoing:
        """Hand the newest image to the loop; a ROS colour image waits for its depth in the bridge,
        which hands on its frame once the pairing is settled (asked on every call)."""
        image = self.images.take()
        sensors = self.ros2.sensors if self.ros2 is not None else None
        frame = None
        if image is not None and not isinstance(image[1], tuple):
            frame = image[1]
        elif sensors is not None:
            if image is not None:
                self._counted(sensors.image, *image)
            frame = self._counted(sensors.paired_image)
        self._sync_counters()
        return self.loop.handle_image(frame) if frame is not None else []

    def _sync_counters(self) -> None:
        """Copy the counts kept on this side of the loop (images replaced or received in the slot and
        the ROS pairing, inbox drops) into the loop's counters, which its status reports."""
        sensors = self.ros2.sensors if self.ros2 is not None else None
        self.loop.images_replaced_upstream = self.images.replaced + (sensors.pairing.replaced if sensors is not None else 0)
        self.loop.images_without_depth = sensors.images_without_depth if sensors is not None else 0
        self.loop.images_received = self.images.received
        self.loop.inbox_dropped = self.inbox.dropped

    def _odometry_waiting(self) -> bool:
        """Odometry is waiting, so the rest of this turn is skipped; the status still leaves when due: under an
        overload that keeps odometry always waiting, it is what tells an operator so (and costs well under a millisecond)."""
        if not self.inbox.waiting(URGENT):
            return False
        self._sync_counters()
        self._run("tick", self.loop.status_if_due, only_if_output=True)
        return True

    def _run(self, kind: str, work: Callable[[], Outgoing], only_if_output: bool = False) -> None:
        """Do one piece of work, publish its output, record its duration under ``kind`` (periodic
        work that published nothing is not recorded; the topics it published are added to its kind).

        Odometry also records the thread's CPU time for its work (``odometry_cpu``): wall time above
        it is time the thread was runnable but not running, i.e. other processes on its cores."""
        started = self.clock()
        cpu_started = time.thread_time()
        outgoing = work()
        if kind == "odometry":
            self.timings.record("odometry_cpu", time.thread_time() - cpu_started)
        for key, payload in outgoing:
            self.bus.publish(key, payload)
        if self.ros2 is not None and outgoing:
            self.ros2.publish_outputs(outgoing)
        if outgoing or not only_if_output:
            if only_if_output:
                kind += ":" + "+".join(sorted({"update_start" if "/update/request/" in key else key.rsplit("/", 1)[-1] for key, _ in outgoing}))
            self.timings.record(kind, self.clock() - started)
        if kind == "odometry":
            predict_started = self.clock()
            self.loop.predict_pending()
            self.timings.record("predict", self.clock() - predict_started)

    def _run_estimate(self) -> None:
        """Recompute the estimate after a merge, as its own piece of work (recorded if done)."""
        started = self.clock()
        if self.loop.refresh_estimate():
            self.timings.record("estimate", self.clock() - started)

    def step(self, timeout: float = 0.01) -> None:
        """One turn of the schedule (module docstring), waiting up to ``timeout`` s for a message."""
        arrival = self.inbox.get(timeout)
        if arrival is not None:
            kind, key, payload, arrived = arrival
            if kind == "odometry":
                self.timings.record_wait(self.clock() - arrived)
            self._run(kind, lambda: self._handlers[kind](key, payload))
        for work in (
            self._run_estimate,
            lambda: self._run("image", self._take_image, only_if_output=True),
            lambda: self._run("tick", self.loop.tick, only_if_output=True),
        ):
            if self._odometry_waiting():
                return
            work()
        if self.clock() - self._last_log >= self.log_period:
            self._last_log = self.clock()
            logger.info("%s", self.timings.summary())
