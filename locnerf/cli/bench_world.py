"""``locnerf bench-world``: how fast the procedural world renders rays (JSON line per dtype)."""

from __future__ import annotations

import argparse
import json

from locnerf.devices import resolve_device
from locnerf.sim.benchmark import benchmark_world


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench-world", help="time the procedural world's ray renderer")
    parser.add_argument("--rays", type=int, default=300 * 64, help="rays per call (default 300 particles × 64 pixels)")
    parser.add_argument("--repeats", type=int, default=30, help="timed calls per dtype")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    for row in benchmark_world(args.rays, args.repeats, resolve_device(args.device)):
        print(json.dumps(row))
    return 0
