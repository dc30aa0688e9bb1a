"""The pairing of colour and depth images by stamp (pure logic, a hand-driven clock)."""

from __future__ import annotations

import numpy as np
import pytest

from locnerf_services.ros2.depth_pairing import DepthPairing


class Clock:
    """Monotonic seconds that move only when told to."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def pairing(tolerance: float = 0.02, max_wait: float = 0.1, capacity: int = 16) -> tuple[DepthPairing[str, str], Clock]:
    clock = Clock()
    return DepthPairing(tolerance, max_wait, clock, capacity), clock


def test_a_depth_image_that_came_first_pairs_at_once():
    pairs, _ = pairing()
    pairs.add_depth(10.0, "depth 10.0")
    pairs.add_colour(10.0, "colour 10.0")
    assert pairs.release() == ("colour 10.0", "depth 10.0")
    assert (pairs.paired, pairs.without_depth, pairs.release(), pairs.time_left()) == (1, 0, None, None)


def test_a_late_depth_image_completes_the_waiting_colour_image():
    pairs, clock = pairing()
    pairs.add_depth(9.967, "previous frame's depth")  # 33 ms earlier: outside the tolerance
    pairs.add_colour(10.0, "colour")
    clock.now += 0.05
    assert pairs.release() is None and pairs.time_left() == pytest.approx(0.05)
    pairs.add_depth(10.004, "late depth")
    assert pairs.release() == ("colour", "late depth")
    assert (pairs.paired, pairs.without_depth) == (1, 0)


def test_without_depth_the_colour_image_goes_alone_after_the_wait():
    pairs, clock = pairing(max_wait=0.1)
    pairs.add_colour(10.0, "colour")
    clock.now += 0.099
    assert pairs.release() is None
    clock.now += 0.001
    assert pairs.release() == ("colour", None)
    assert (pairs.paired, pairs.without_depth, pairs.time_left()) == (0, 1, None)


def test_a_later_depth_image_outside_the_tolerance_settles_the_pairing_at_once():
    """Depth images arrive in stamp order: once one stamped after the colour image is in, no nearer
    one can come, so the colour image goes without waiting out ``max_wait``."""
    pairs, _ = pairing(tolerance=0.02, max_wait=10.0)
    pairs.add_colour(10.0, "colour")
    pairs.add_depth(10.5, "far later depth")
    assert pairs.release() == ("colour", None) and pairs.without_depth == 1
    pairs.add_colour(10.5, "next colour")
    assert pairs.release() == ("next colour", "far later depth"), "the later depth image is kept for a later colour image"


@pytest.mark.parametrize(("offset", "paired"), [(0.25, True), (-0.25, True), (0.2500001, False), (-0.2500001, False)])
def test_the_tolerance_is_inclusive(offset, paired):
    """Stamps of whole nanoseconds, as ROS sends them (0.25 s is exact in binary; 100 ns more is out)."""
    pairs, clock = pairing(tolerance=0.25, max_wait=0.1)
    pairs.add_colour(10.0, "colour")
    pairs.add_depth(10.0 + offset, "depth")
    clock.now += 0.1
    assert pairs.release() == ("colour", "depth" if paired else None)


def test_the_nearest_depth_image_within_the_tolerance_is_chosen():
    pairs, clock = pairing(tolerance=0.02, max_wait=0.1)
    for stamp in (9.985, 9.995):  # a 100 Hz depth stream, both before the colour image
        pairs.add_depth(stamp, f"depth {stamp}")
    pairs.add_colour(10.0, "colour")
    assert pairs.release() is None, "a depth image nearer than 5 ms may still come"
    pairs.add_depth(10.003, "depth 10.003")
    assert pairs.release() == ("colour", "depth 10.003")
    pairs.add_colour(10.01, "colour 10.01")  # 10.003 was used (and the older ones dropped)
    clock.now += 0.1
    assert pairs.release() == ("colour 10.01", None)


def test_at_the_deadline_the_nearest_earlier_depth_within_the_tolerance_is_taken():
    pairs, clock = pairing(tolerance=0.02, max_wait=0.1)
    pairs.add_depth(9.99, "depth 9.99")
    pairs.add_colour(10.0, "colour")
    assert pairs.release() is None
    clock.now += 0.1
    assert pairs.release() == ("colour", "depth 9.99")


def test_a_newer_colour_image_replaces_the_waiting_one_and_keeps_its_deadline():
    """The filter uses only the newest image; the deadline is kept so that colour images keep coming,
    every max_wait seconds, when the depth stream stops (a camera at 33 Hz outruns a 0.1 s wait)."""
    pairs, clock = pairing(max_wait=0.1)
    for frame in range(4):
        clock.now = 100.0 + 0.03 * frame
        pairs.add_colour(10.0 + 0.03 * frame, f"colour {frame}")
        assert pairs.release() is None
    assert pairs.replaced == 3 and pairs.time_left() == pytest.approx(0.01)
    clock.now = 100.1
    assert pairs.release() == ("colour 3", None)
    pairs.add_colour(10.2, "colour 4")
    assert pairs.time_left() == pytest.approx(0.1), "a colour image after a release waits the whole max_wait"


def test_only_the_newest_depth_images_are_kept():
    pairs, clock = pairing(capacity=2)
    for stamp in (10.0, 10.1, 10.2):
        pairs.add_depth(stamp, f"depth {stamp}")
    pairs.add_colour(10.0, "colour")
    assert pairs.release() == ("colour", None), "depth 10.0 fell out of the buffer; 10.1 is after it, so it is final"


def test_seeded_streams_never_pair_the_wrong_frame_and_account_for_every_colour_image():
    """A 30 Hz camera whose depth image comes 0-60 ms after its colour image (stamp jitter ±2 ms) and
    loses every tenth depth image, the consumer checking at each arrival: a released colour image
    carries its own frame's depth image, or none when that had not arrived (or never does); every
    colour image is released, replaced or still waiting. The counts pin this seed's run: with depth
    often later than the next colour image, many colour images are replaced (the filter takes only
    the newest anyway)."""
    generator = np.random.default_rng(7)
    pairs, clock = pairing(tolerance=0.01, max_wait=0.1)
    events: list[tuple[float, str, float, str]] = []  # (arrival, kind, stamp, frame name)
    for frame in range(60):
        stamp = frame / 30
        events.append((stamp + 0.002, "colour", stamp, f"frame {frame}"))
        if frame % 10 != 9:
            events.append((stamp + 0.002 + generator.uniform(0.0, 0.06), "depth", stamp + generator.uniform(-0.002, 0.002), f"frame {frame}"))
    released: list[tuple[str, str | None]] = []
    depths_arrived: set[str] = set()

    def check() -> None:
        result = pairs.release()
        if result is not None:
            colour, depth = result
            assert depth == colour if depth is not None else colour not in depths_arrived, result
            released.append(result)

    for arrival, kind, stamp, name in sorted(events):
        clock.now = 100.0 + arrival
        check()
        if kind == "colour":
            pairs.add_colour(stamp, name)
        else:
            pairs.add_depth(stamp, name)
            depths_arrived.add(name)
        check()
    waiting = pairs.time_left() is not None
    assert pairs.paired + pairs.without_depth == len(released) and pairs.replaced + len(released) + waiting == 60
    assert (pairs.paired, pairs.without_depth, pairs.replaced) == (21, 5, 33)


def test_invalid_settings_raise():
    with pytest.raises(ValueError, match="tolerance -1"):
        DepthPairing(-1, 0.1)
