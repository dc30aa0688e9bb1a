"""The simulated odometry's flags, shared by ``locnerf eval tracking`` and ``locnerf bag export``
(turned into a :class:`~locnerf.sim.sensors.VioConfig` by ``locnerf_cli.eval_tracking.vio_config``)."""

from __future__ import annotations

import argparse


def add_odometry_arguments(parser: argparse.ArgumentParser) -> None:
    """--odom-rate, --drift, --yaw-drift, --noise, --rotation-noise."""
    parser.add_argument("--odom-rate", type=float, default=15.0, help="odometry messages per second")
    parser.add_argument("--drift", type=float, default=0.01, help="odometry scale drift (0.01: 1 %% of the distance travelled)")
    parser.add_argument("--yaw-drift", type=float, default=0.2, help="odometry yaw drift, degrees per second")
    parser.add_argument("--noise", type=float, default=2e-3, help="odometry white translation noise per message, metres per axis")
    parser.add_argument("--rotation-noise", type=float, default=0.057, help="odometry white rotation noise per message, degrees per axis")
