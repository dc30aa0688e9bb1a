"""``locnerf echo pose``: print the filter's stamped poses, with errors when ground truth is published."""

from __future__ import annotations

import argparse
import time

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import PoseEstimate, PoseStamped
from locnerf_cli.bus_client import add_bus_arguments, open_cli_bus
from locnerf_cli.monitor import GroundTruthMatcher, ScoredPoses, pose_line
from locnerf_services.transport import Inbox


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf echo``."""
    parser.add_argument("topic", choices=["pose"], help="what to print")
    parser.add_argument("--count", type=int, default=0, help="stop after this many poses (0: until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=0.0, help="stop after this many seconds (0: no limit)")
    add_bus_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    inbox = Inbox(capacity=256)
    matcher = GroundTruthMatcher()
    bus = open_cli_bus(args.connect)
    handles = [
        bus.subscribe(keys.key(args.robot_id, keys.GROUND_TRUTH), lambda _k, payload: inbox.put(("truth", payload))),
        bus.subscribe(keys.key(args.robot_id, keys.POSE), lambda _k, payload: inbox.put(("pose", payload))),
    ]
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else float("inf")
    poses = ScoredPoses(matcher)
    printed = 0
    try:
        while time.monotonic() < deadline and (args.count == 0 or printed < args.count):
            item = inbox.get(timeout=0.1)
            if item is not None:
                kind, payload = item
                try:
                    if kind == "truth":
                        matcher.add_truth(decode(payload, PoseStamped))
                    else:
                        poses.add(decode(payload, PoseEstimate), time.monotonic())
                except DecodeError as error:
                    print(f"bad {kind} message: {error}")
            for estimate, error in poses.release(time.monotonic()):
                if args.count == 0 or printed < args.count:
                    print(pose_line(estimate, error), flush=True)
                    printed += 1
    except KeyboardInterrupt:
        pass
    finally:
        for handle in handles:
            handle.close()
        bus.close()
    return 0
