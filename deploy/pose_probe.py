"""The host's view of a running stack for deploy/check_stack.sh: read poses through the router's
published port, optionally stop and start the router mid-stream, and print what was seen as one JSON line.

    python deploy/pose_probe.py --connect tcp/127.0.0.1:7447 --count 150 \
        --stop "docker compose stop zenohd" --start "docker compose start zenohd" --after 30

One client session (as a robot's consumer would hold) stays open throughout. Output fields: poses,
rate_hz (poses per second between the first and the last of the first ``count``), first_pose_s
(from the session's opening), and with ``--stop``/``--start``: down_s (the stop command's duration),
router_up_s (from the start command's start until a new session with the router opens), recovery_s (from
the start command's start to the first pose after it), poses_after.
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import subprocess
import sys
import time

import zenoh

from locnerf.messages import keys
from locnerf.messages.codec import DecodeError, decode
from locnerf.messages.schemas import PoseEstimate
from locnerf_services.transport import Inbox, TransportConfig, open_bus


def arrivals(inbox: Inbox[tuple[float, bytes]], count: int, timeout: float, what: str) -> list[float]:
    """Monotonic arrival times of ``count`` decodable poses; exits naming ``what`` after ``timeout`` seconds."""
    times: list[float] = []
    deadline = time.monotonic() + timeout
    while len(times) < count:
        item = inbox.get(timeout=max(0.0, min(0.5, deadline - time.monotonic())))
        if item is None:
            if time.monotonic() > deadline:
                raise SystemExit(f"pose_probe: {len(times)} of {count} poses {what} within {timeout:.0f} s")
            continue
        try:
            decode(item[1], PoseEstimate)
        except DecodeError as error:
            raise SystemExit(f"pose_probe: undecodable pose ({error})") from None
        times.append(item[0])
    return times


def router_up_at(endpoint: str, since: float, timeout: float) -> float:
    """Seconds from ``since`` until a new client session of ``endpoint`` opens (tried every 0.1 s):
    the router answers Zenoh, not only the published port (Docker's proxy accepts TCP before)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            open_bus(TransportConfig(mode="client", connect=(endpoint,))).close()
            return time.monotonic() - since
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise SystemExit(f"pose_probe: no Zenoh session with {endpoint} within {timeout:.0f} s") from None
            time.sleep(0.1)


def run_command(command: str) -> float:
    """Run ``command`` (its output to stderr); returns its monotonic start time."""
    started = time.monotonic()
    subprocess.run(shlex.split(command), check=True, stdout=sys.stderr)
    return started


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", default="tcp/127.0.0.1:7447", help="router endpoint (the compose file publishes 7447)")
    parser.add_argument("--robot-id", default="robot")
    parser.add_argument("--count", type=int, default=150, help="poses to read before the restart")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for each batch of poses")
    parser.add_argument("--stop", default="", help="command that stops the router, run after --count poses")
    parser.add_argument("--start", default="", help="command that starts it again, run once --stop returned")
    parser.add_argument("--after", type=int, default=30, help="poses to read after the restart")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")

    # A client of the router: the session survives the router's restart and reconnects to it.
    bus = open_bus(TransportConfig(mode="client", connect=(args.connect,), connect_retry=args.timeout))
    inbox: Inbox[tuple[float, bytes]] = Inbox(capacity=4096)
    opened = time.monotonic()
    handle = bus.subscribe(keys.key(args.robot_id, keys.POSE), lambda _key, payload: inbox.put((time.monotonic(), payload)))
    try:
        before = arrivals(inbox, args.count, args.timeout, "before the restart")
        report: dict[str, float | int] = {
            "poses": len(before),
            "rate_hz": round((len(before) - 1) / (before[-1] - before[0]), 3),
            "first_pose_s": round(before[0] - opened, 2),
        }
        if args.stop:
            stopping = run_command(args.stop)
            stopped = time.monotonic()
            while inbox.get(timeout=0.0) is not None:  # poses that passed before the router went down
                pass
            starting = run_command(args.start)
            router_up = router_up_at(args.connect, starting, args.timeout)
            after = arrivals(inbox, args.after, args.timeout, "after the restart")
            report |= {
                "down_s": round(stopped - stopping, 2),
                "router_up_s": round(router_up, 2),
                "recovery_s": round(after[0] - starting, 2),
                "poses_after": len(after),
            }
    finally:
        handle.close()
        bus.close()
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
