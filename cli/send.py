"""``locnerf send initial-pose …`` / ``locnerf send global-localization``: commands to the filter.

The command waits until a filter status arrives (the filter is reachable) before sending.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time

from locnerf.errors import LocnerfInputError
from locnerf.messages import keys
from locnerf.messages.codec import encode
from locnerf.messages.schemas import GlobalLocalizationCommand, InitialPoseCommand
from locnerf_cli.bus_client import add_bus_arguments, open_cli_bus
from locnerf_cli.flags import from_flags
from locnerf_services.transport import Inbox

# Python's argparse (before 3.13) takes "-1.5e-05", as Python prints small negative numbers, for an
# option name; a pose copied from a log must parse, so these parsers know every float spelling.
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``locnerf send``."""
    commands = parser.add_subparsers(dest="command_name", required=True)
    initial = commands.add_parser("initial-pose", help="re-initialise around a pose")
    initial.add_argument("--pose", type=float, nargs=16, required=True, metavar="T", help="T_world_cam, 16 numbers row-major, metres")
    initial.add_argument("--sigma-position", type=float, default=0.1, help="standard deviation of the position per axis, metres")
    initial.add_argument("--sigma-rotation-deg", type=float, default=5.0, help="standard deviation of the rotation per axis, degrees")
    initial.add_argument("--covariance", type=float, nargs=36, metavar="C", help="full 6×6 covariance (rotation, translation), row-major")
    initial._negative_number_matcher = NEGATIVE_NUMBER
    global_ = commands.add_parser("global-localization", help="re-initialise over the whole map")
    for command in (initial, global_):
        add_bus_arguments(command)
        command.add_argument("--timeout", type=float, default=30.0, help="longest wait for the filter, seconds")
        command.set_defaults(func=run)


def _command(args: argparse.Namespace):
    stamp = time.time()
    if args.command_name == "global-localization":
        return keys.GLOBAL_LOCALIZATION, GlobalLocalizationCommand(stamp=stamp)
    for name, value in (("--sigma-position", args.sigma_position), ("--sigma-rotation-deg", args.sigma_rotation_deg)):
        if not value > 0:
            raise LocnerfInputError(f"{name} {value}: expected a positive standard deviation")
    pose = [args.pose[i : i + 4] for i in range(0, 16, 4)]
    if args.covariance is not None:
        covariance = [args.covariance[i : i + 6] for i in range(0, 36, 6)]
    else:
        variances = [math.radians(args.sigma_rotation_deg) ** 2] * 3 + [args.sigma_position**2] * 3
        covariance = [[variances[i] if i == j else 0.0 for j in range(6)] for i in range(6)]
    values = {"stamp": stamp, "T_world_cam": pose, "covariance": covariance}
    return keys.INITIAL_POSE, from_flags(InitialPoseCommand, values, {"T_world_cam": "--pose", "covariance": "--covariance"})


def run(args: argparse.Namespace) -> int:
    topic, message = _command(args)
    inbox = Inbox(capacity=4)
    bus = open_cli_bus(args.connect)
    subscription = bus.subscribe(keys.key(args.robot_id, keys.STATUS), lambda _k, payload: inbox.put(payload))
    try:
        if inbox.get(timeout=args.timeout) is None:
            print(f"no filter status for robot {args.robot_id!r} within {args.timeout} s: is the filter running?", file=sys.stderr)
            return 1
        bus.publish(keys.key(args.robot_id, topic), encode(message))
        print(f"sent {type(message).__name__} to {keys.key(args.robot_id, topic)}")
    finally:
        subscription.close()
        bus.close()
    return 0
