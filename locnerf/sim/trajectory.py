"""Smooth closed camera trajectories through the procedural world, sampled at any time.

The default path is a horizontal figure-eight (a 1:2 Lissajous curve) at 1.7 m with a gentle
height wave, 0.3-0.8 m/s, placed where it keeps 0.3 m from every box of the default world. The body looks along its direction of motion (OpenGL axes: it looks along its
own -z, y up) plus a small periodic "head motion" in yaw and pitch.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.geometry.se3 import make_pose
from locnerf.geometry.so3 import so3_exp


class TrajectoryConfig(BaseModel):
    """Shape and timing of the figure-eight trajectory (metres, seconds, radians)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    centre: tuple[float, float, float] = Field((0.5, 1.7, 1.75), description="Centre of the figure-eight (x, y height, z), metres.")
    amplitude_x: float = Field(1.5, gt=0, description="Half-length of the figure-eight along its long axis (world x before `orientation`), metres.")
    amplitude_z: float = Field(1.1, gt=0, description="Half-width of the figure-eight across its long axis (world z before `orientation`), metres.")
    orientation: float = Field(math.pi / 2, description="Rotation of the figure-eight's long axis from world x about world y, radians.")
    amplitude_height: float = Field(0.1, ge=0, description="Amplitude of the height wave, metres.")
    period: float = Field(22.0, gt=0, description="Time for one loop, seconds (the trajectory repeats).")
    head_yaw: float = Field(math.radians(8.0), ge=0, description="Amplitude of the head's yaw oscillation, radians.")
    head_pitch: float = Field(math.radians(5.0), ge=0, description="Amplitude of the head's pitch oscillation, radians.")
    head_yaw_cycles: int = Field(4, ge=0, description="Head yaw oscillations per loop (whole numbers keep the loop closed).")
    head_pitch_cycles: int = Field(3, ge=0, description="Head pitch oscillations per loop (whole numbers keep the loop closed).")


class FigureEightTrajectory:
    """A closed, smooth body trajectory ``T_world_body(t)`` (float64).

    Args:
        config: shape and timing.
    """

    def __init__(self, config: TrajectoryConfig | None = None) -> None:
        self.config = config or TrajectoryConfig()

    @property
    def duration(self) -> float:
        """Length of one loop, seconds; ``poses_at(t + duration) == poses_at(t)``."""
        return self.config.period

    def _times(self, times: torch.Tensor | float) -> torch.Tensor:
        t = torch.as_tensor(times, dtype=torch.float64)
        if t.ndim > 1:
            raise ValueError(f"times: expected a scalar or shape (N,), got shape {tuple(t.shape)}")
        if not torch.isfinite(t).all():
            raise ValueError(f"times: expected finite seconds, got {t.tolist()}")
        return t

    def positions_and_velocities(self, times: torch.Tensor | float) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions and velocities at times (N,) or a scalar: each (N, 3) or (3,), metres and m/s."""
        c = self.config
        t = self._times(times)
        w = 2 * math.pi / c.period
        phase = w * t
        centre = torch.tensor(c.centre, dtype=torch.float64)
        offset = torch.stack([c.amplitude_x * torch.sin(phase), c.amplitude_height * torch.sin(3 * phase), c.amplitude_z * torch.sin(2 * phase)], dim=-1)
        velocity = torch.stack(
            [c.amplitude_x * w * torch.cos(phase), 3 * c.amplitude_height * w * torch.cos(3 * phase), 2 * c.amplitude_z * w * torch.cos(2 * phase)],
            dim=-1,
        )
        turn = so3_exp(torch.tensor([0.0, c.orientation, 0.0], dtype=torch.float64))
        return offset @ turn.T + centre, velocity @ turn.T

    def poses_at(self, times: torch.Tensor | float) -> torch.Tensor:
        """Body poses ``T_world_body`` at times (N,) -> (N, 4, 4), or at a scalar time -> (4, 4)."""
        c = self.config
        position, velocity = self.positions_and_velocities(times)
        t = self._times(times)
        loop_phase = 2 * math.pi * t / c.period
        # The OpenGL body looks along its -z: a yaw ψ about world y turns -z into (-sin ψ, 0, -cos ψ).
        yaw = torch.atan2(-velocity[..., 0], -velocity[..., 2]) + c.head_yaw * torch.sin(c.head_yaw_cycles * loop_phase)
        pitch = c.head_pitch * torch.sin(c.head_pitch_cycles * loop_phase)
        zeros = torch.zeros_like(yaw)
        rotation = so3_exp(torch.stack([zeros, yaw, zeros], dim=-1)) @ so3_exp(torch.stack([pitch, zeros, zeros], dim=-1))
        return make_pose(rotation, position)

    def pose_at(self, time: float) -> torch.Tensor:
        """Body pose ``T_world_body`` (4, 4) at one time, seconds."""
        return self.poses_at(float(time))

    def check_free(self, is_free: Callable[..., torch.Tensor], clearance: float = 0.3, step: float = 0.05) -> None:
        """Raise ValueError if the path, sampled every ``step`` seconds, leaves free space.

        Args:
            is_free: callable (N, 3) points, clearance -> (N,) bool, e.g. ``ProceduralWorld.is_free``.
        """
        times = torch.arange(0.0, self.duration, step, dtype=torch.float64)
        positions, _ = self.positions_and_velocities(times)
        free = is_free(positions, clearance=clearance)
        if not bool(free.all()):
            index = int((~free).nonzero()[0, 0])
            raise ValueError(
                f"trajectory: at t = {times[index]:.2f} s the position {positions[index].tolist()} is within {clearance} m "
                "of an obstacle or outside the room; expected a path through free space"
            )
