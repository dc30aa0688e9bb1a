"""``locnerf bench world``: how fast the procedural world renders rays, one row per dtype."""

from __future__ import annotations

import argparse

import torch

from locnerf.devices import resolve_device
from locnerf.errors import LocnerfInputError
from locnerf.sim.benchmark import benchmark_world
from locnerf_cli.bench_table import BenchTable


def add_target(targets: argparse._SubParsersAction) -> None:
    """Add ``world`` to the targets of ``locnerf bench``."""
    parser = targets.add_parser("world", help="time the procedural world's ray renderer (float32 and float64)")
    parser.add_argument("--rays", type=int, default=300 * 64, help="rays per call (default 300 particles × 64 pixels)")
    parser.add_argument("--repeats", type=int, default=30, help="timed calls per dtype")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (the services use 1)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.threads < 1:
        raise LocnerfInputError(f"--threads {args.threads}: expected at least 1")
    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    table = BenchTable(("dtype", "rays", "median_ms"), {"device": str(device), "threads": args.threads, "repeats": args.repeats}, args.json)
    for row in benchmark_world(args.rays, args.repeats, device):
        table.row(row)
    return 0
