"""The procedural world: an analytic textured room with boxes, rendered exactly along any ray.

A room of ``size`` metres (x, z horizontal, y up, floor at y = 0) holds boxes and pillars placed
from a seed. Every surface carries a view-independent procedural texture (:mod:`.textures`). The
world implements :class:`locnerf.field.protocol.RadianceMap` with one "sample" per ray, so it can
stand wherever a NeRF map can: as ground truth in tests and as the source of synthetic streams.
"""

from __future__ import annotations

import hashlib
import math

import torch
from pydantic import BaseModel, ConfigDict, Field

from locnerf.field.protocol import MapNormalization
from locnerf.geometry.se3 import make_pose
from locnerf.geometry.so3 import so3_exp
from locnerf.geometry.validation import validate_poses
from locnerf.render.camera import PinholeIntrinsics
from locnerf.render.image import render_image
from locnerf.sim.raycast import nearest_box_hit, room_exit_hit
from locnerf.sim.textures import ProceduralTexture, TextureConfig

# Room faces are surfaces 0..5 (axis * 2 + side); box b is surface 6 + b.
_ROOM_SURFACES = 6


class WorldConfig(BaseModel):
    """Layout, texture and default camera of the procedural world."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    seed: int = Field(7, description="Seed of the layout and texture draws.")
    room_size: tuple[float, float, float] = Field((8.0, 3.0, 8.0), description="Room extent along x, y (height), z in metres.")
    boxes: int = Field(14, ge=0, description="Boxes and pillars placed in the room.")
    box_size_range: tuple[float, float] = Field((0.3, 1.4), description="Range of box side lengths, metres.")
    camera_margin: float = Field(0.8, ge=0, description="Clearance of plausible camera positions from walls, metres.")
    camera_height_range: tuple[float, float] = Field((0.6, 2.2), description="Range of plausible camera heights, metres.")
    background: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="Colour of rays that hit nothing.")
    texture: TextureConfig = Field(default_factory=TextureConfig, description="Procedural texture scales.")
    image_width: int = Field(160, ge=1, description="Default camera width, pixels.")
    image_height: int = Field(120, ge=1, description="Default camera height, pixels.")
    horizontal_fov_deg: float = Field(70.0, gt=0, lt=180, description="Default camera horizontal field of view, degrees.")


class ProceduralWorld:
    """An exactly renderable room; satisfies the RadianceMap protocol.

    Args:
        config: layout and texture parameters.
        device: where rendering computes.
    """

    samples_per_ray = 1

    def __init__(self, config: WorldConfig | None = None, device: torch.device | str = "cpu") -> None:
        self.config = config or WorldConfig()
        self._device = torch.device(device)
        generator = torch.Generator().manual_seed(self.config.seed)
        sx, sy, sz = self.config.room_size
        self.room_min = torch.tensor([-sx / 2, 0.0, -sz / 2], dtype=torch.float64)
        self.room_max = torch.tensor([sx / 2, sy, sz / 2], dtype=torch.float64)
        self.box_min, self.box_max = self._place_boxes(generator)
        self.texture = ProceduralTexture(_ROOM_SURFACES + self.config.boxes, self.config.texture, generator)
        self._normalization = MapNormalization(near=0.0, far=float(torch.linalg.vector_norm(self.room_max - self.room_min)), up=(0.0, 1.0, 0.0))
        self._intrinsics = PinholeIntrinsics.from_fov(self.config.image_width, self.config.image_height, math.radians(self.config.horizontal_fov_deg))

    @classmethod
    def default(cls, device: torch.device | str = "cpu") -> ProceduralWorld:
        """The deterministic default world."""
        return cls(WorldConfig(), device)

    def _place_boxes(self, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Boxes standing on the floor (some tall, pillar-like) or hanging on walls, from the seed."""
        count = self.config.boxes
        low, high = self.config.box_size_range
        size = low + (high - low) * torch.rand(count, 3, dtype=torch.float64, generator=generator)
        pillars = torch.rand(count, generator=generator) < 0.3
        size[pillars, 1] = self.room_max[1] * 0.9  # pillars nearly reach the ceiling
        span = (self.room_max - self.room_min) - size
        corner = self.room_min + torch.rand(count, 3, dtype=torch.float64, generator=generator) * span
        corner[:, 1] = 0.0  # on the floor
        return corner, corner + size

    # ------------------------------------------------------------------ RadianceMap protocol
    @property
    def device(self) -> torch.device:
        return self._device

    @property
    def normalization(self) -> MapNormalization:
        return self._normalization

    @property
    def default_intrinsics(self) -> PinholeIntrinsics:
        return self._intrinsics

    @property
    def checksum(self) -> str:
        """SHA-256 (hex) of the configuration, which fixes the whole world (layout and textures are drawn from its seed)."""
        return hashlib.sha256(b"locnerf procedural world\n" + self.config.model_dump_json().encode()).hexdigest()

    def camera_bounds(self) -> torch.Tensor:
        """(2, 3) region of plausible camera positions: the room less a margin, between two heights."""
        margin = self.config.camera_margin
        low_h, high_h = self.config.camera_height_range
        return torch.tensor(
            [[self.room_min[0] + margin, low_h, self.room_min[2] + margin], [self.room_max[0] - margin, high_h, self.room_max[2] - margin]],
            dtype=torch.float64,
        )

    def cast(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest surface along rays: origins, directions (R, 3) -> t (R,) (inf on a miss), surface id (R,)."""
        dtype, device = origins.dtype, origins.device
        t_box, box = nearest_box_hit(origins, directions, self.box_min.to(device, dtype), self.box_max.to(device, dtype))
        t_room, axis, side = room_exit_hit(origins, directions, self.room_min.to(device, dtype), self.room_max.to(device, dtype))
        use_box = t_box < t_room
        t = torch.where(use_box, t_box, t_room)
        surface = torch.where(use_box, _ROOM_SURFACES + box, axis * 2 + side)
        return t, surface

    def render_rays(self, origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        """Exact colours of rays (R, 3) + (R, 3) -> (R, 3) in [0, 1]."""
        return self.render_surface(origins, directions)[0]

    def render_surface(self, origins: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Exact colours (R, 3), surface points (R, 3) (the origin on a miss) and opacity (R,) (1 on a hit, 0 on a miss) of rays (R, 3) x2."""
        if origins.shape != directions.shape or origins.ndim != 2 or origins.shape[-1] != 3:
            raise ValueError(f"rays: expected origins and directions of shape (R, 3), got {tuple(origins.shape)} and {tuple(directions.shape)}")
        t, surface = self.cast(origins, directions)
        hit = torch.isfinite(t)
        points = origins + torch.where(hit, t, torch.zeros_like(t))[:, None] * directions
        colours = self.texture.colour(points, surface)
        background = torch.tensor(self.config.background, dtype=origins.dtype, device=origins.device)
        return torch.where(hit[:, None], colours, background), points, hit.to(origins.dtype)

    # ------------------------------------------------------------------ conveniences
    def render_image(self, T_world_cam: torch.Tensor, intrinsics: PinholeIntrinsics | None = None) -> torch.Tensor:
        """Render a whole image (H, W, 3) from a camera-to-world pose (4, 4)."""
        validate_poses(T_world_cam, name="T_world_cam")
        return render_image(self.render_rays, T_world_cam.to(self._device), intrinsics or self._intrinsics)

    def is_free(self, points: torch.Tensor, clearance: float = 0.0) -> torch.Tensor:
        """(N,) bool: points (N, 3) inside the room and at least ``clearance`` away from every box."""
        if points.ndim != 2 or points.shape[-1] != 3:
            raise ValueError(f"points: expected shape (N, 3), got {tuple(points.shape)}")
        p = points.double().cpu()
        inside_room = ((p >= self.room_min + clearance) & (p <= self.room_max - clearance)).all(dim=-1)
        in_box = ((p[:, None] >= self.box_min - clearance) & (p[:, None] <= self.box_max + clearance)).all(dim=-1).any(dim=-1)
        return inside_room & ~in_box

    def sample_camera_pose(self, generator: torch.Generator, max_pitch_deg: float = 20.0, max_roll_deg: float = 5.0, min_depth: float = 1.0) -> torch.Tensor:
        """A random plausible camera pose (4, 4) float64: free position, near-horizontal view,
        with the surface straight ahead at least ``min_depth`` away.

        Raises:
            RuntimeError: if no such pose is found in 1000 draws (a degenerate layout).
        """
        bounds = self.camera_bounds()
        for _ in range(1000):
            position = bounds[0] + (bounds[1] - bounds[0]) * torch.rand(3, dtype=torch.float64, generator=generator)
            angles = (torch.rand(3, dtype=torch.float64, generator=generator) * 2 - 1) * torch.tensor(
                [math.pi, math.radians(max_pitch_deg), math.radians(max_roll_deg)], dtype=torch.float64
            )
            # OpenGL cameras look along -z with y up: yaw about the world y axis, then pitch about
            # the camera's x axis, then roll about its z axis.
            yaw, pitch, roll = angles.tolist()
            rotation = (
                so3_exp(torch.tensor([0.0, yaw, 0.0], dtype=torch.float64))
                @ so3_exp(torch.tensor([pitch, 0.0, 0.0], dtype=torch.float64))
                @ so3_exp(torch.tensor([0.0, 0.0, roll], dtype=torch.float64))
            )
            pose = make_pose(rotation, position)
            if not bool(self.is_free(position[None], clearance=0.3)[0]):
                continue
            depth, _ = self.cast(position[None], -rotation[:, 2][None])
            if float(depth[0]) >= min_depth:
                return pose
        raise RuntimeError("no plausible camera pose found in 1000 draws: the layout leaves no free space")
