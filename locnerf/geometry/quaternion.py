"""Unit quaternions in (w, x, y, z) order and their conversions to matrices and rotation vectors."""

from __future__ import annotations

import torch


def quaternion_to_matrix(quaternion: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of a quaternion (w, x, y, z); the input is normalised first.

    Args:
        quaternion: (..., 4).
    Returns:
        (..., 3, 3).
    """
    q = quaternion / torch.linalg.vector_norm(quaternion, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = (
        torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), dim=-1),
        torch.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), dim=-1),
        torch.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), dim=-1),
    )
    return torch.stack(rows, dim=-2)


def matrix_to_quaternion(rotation: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix.

    Shepperd's method: of the four algebraically equal formulas, each element uses the one whose
    pivot (4w², 4x², 4y² or 4z²) is largest, so no division by a small number ever happens.

    Args:
        rotation: (..., 3, 3).
    Returns:
        (..., 4).
    """
    m = rotation
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    pivots = torch.stack((1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), dim=-1)
    d21, d12 = m[..., 2, 1], m[..., 1, 2]
    d02, d20 = m[..., 0, 2], m[..., 2, 0]
    d10, d01 = m[..., 1, 0], m[..., 0, 1]
    # Each candidate is 4·q_pivot·q; all four equal q up to scale when R is a rotation.
    candidates = torch.stack(
        (
            torch.stack((pivots[..., 0], d21 - d12, d02 - d20, d10 - d01), dim=-1),
            torch.stack((d21 - d12, pivots[..., 1], d10 + d01, d02 + d20), dim=-1),
            torch.stack((d02 - d20, d10 + d01, pivots[..., 2], d21 + d12), dim=-1),
            torch.stack((d10 - d01, d02 + d20, d21 + d12, pivots[..., 3]), dim=-1),
        ),
        dim=-2,
    )
    best = pivots.argmax(dim=-1)
    chosen = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = chosen / torch.linalg.vector_norm(chosen, dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quaternion_to_rotvec(quaternion: torch.Tensor) -> torch.Tensor:
    """Rotation vector (angle in [0, π]) of a quaternion (w, x, y, z), any non-zero norm.

    ``angle = 2·atan2(|v|, |w|)`` (the sign of q flipped so that w >= 0) and the rotation vector is
    ``angle · v / |v|``. Both are invariant to the quaternion's scale, so it is not normalised, and
    ``atan2`` is exact to rounding for tiny |v| (``2|v|/|w|``), so no series is needed; v = 0 gives 0.

    Args:
        quaternion: (..., 4).
    Returns:
        (..., 3).
    """
    w, v = quaternion[..., 0], quaternion[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)
    signed_double = torch.where(w < 0, -2.0, 2.0)
    factor = signed_double * torch.atan2(s, w.abs()) / s.clamp_min(torch.finfo(s.dtype).tiny)
    return v * factor[..., None]


def rotvec_to_quaternion(rotvec: torch.Tensor) -> torch.Tensor:
    """Quaternion (w, x, y, z) of a rotation vector (..., 3) -> (..., 4)."""
    angle = torch.linalg.vector_norm(rotvec, dim=-1)
    half = 0.5 * angle
    small = angle < 1e-6
    safe = torch.where(small, torch.ones_like(angle), angle)
    # sin(θ/2)/θ -> 1/2 - θ²/48 for small θ.
    scale = torch.where(small, 0.5 - angle * angle / 48.0, torch.sin(half) / safe)
    return torch.cat((torch.cos(half)[..., None], rotvec * scale[..., None]), dim=-1)
