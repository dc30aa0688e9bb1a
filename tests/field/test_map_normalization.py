"""MapNormalization's frame conversions against float64 oracles written out by hand."""

from __future__ import annotations

import pytest
import torch

from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, pose_inverse, se3_exp, so3_exp

TURN = make_pose(so3_exp(torch.tensor([0.0, 0.5, 0.0], dtype=torch.float64)), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))


def test_metric_to_map_scales_then_moves() -> None:
    normalization = MapNormalization(T_map_dataset=TURN.tolist(), scale=2.0)
    pose = make_pose(so3_exp(torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)), torch.tensor([0.5, -1.0, 0.25], dtype=torch.float64))
    mapped = normalization.metric_to_map(pose[None])[0]
    torch.testing.assert_close(mapped[:3, 3], TURN[:3, :3] @ (2.0 * pose[:3, 3]) + TURN[:3, 3])
    torch.testing.assert_close(mapped[:3, :3], TURN[:3, :3] @ pose[:3, :3])


def test_metric_map_metric_round_trip_is_exact_in_float64() -> None:
    normalization = MapNormalization(T_map_dataset=TURN.tolist(), scale=0.37)
    poses = se3_exp(torch.randn(50, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 2.0)  # (50, 4, 4)
    in_map = normalization.metric_to_map(poses)
    back = normalization.map_to_metric(in_map)
    assert in_map.dtype == back.dtype == torch.float64 and back.shape == (50, 4, 4)
    torch.testing.assert_close(back, poses, atol=1e-12, rtol=0)
    # Oracle of the inverse: undo the move with the explicit inverse, then divide the translation by the scale.
    moved_back = torch.linalg.inv(TURN) @ in_map
    torch.testing.assert_close(back[:, :3, 3], moved_back[:, :3, 3] / 0.37, atol=1e-12, rtol=0)


def test_increment_is_scaled_to_map_units() -> None:
    previous = make_pose(so3_exp(torch.tensor([0.0, 0.3, 0.0], dtype=torch.float64)), torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    step = make_pose(so3_exp(torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64)), torch.tensor([0.0, 0.0, -0.5], dtype=torch.float64))
    normalization = MapNormalization(T_map_dataset=TURN.tolist(), scale=3.0)
    increment = normalization.increment_to_map(pose_inverse(previous) @ (previous @ step))
    torch.testing.assert_close(increment[:3, :3], step[:3, :3])
    torch.testing.assert_close(increment[:3, 3], torch.tensor([0.0, 0.0, -1.5], dtype=torch.float64))
    # The increment between two map-frame poses equals the converted metric increment: T_map_dataset cancels.
    torch.testing.assert_close(pose_inverse(normalization.metric_to_map(previous)) @ normalization.metric_to_map(previous @ step), increment)


def test_covariance_blocks_scale_by_the_scale_and_its_square() -> None:
    generator = torch.Generator().manual_seed(1)
    factor = torch.randn(6, 6, dtype=torch.float64, generator=generator)
    covariance = factor @ factor.T + 0.1 * torch.eye(6, dtype=torch.float64)
    normalization = MapNormalization(scale=4.0)
    in_map = normalization.covariance_to_map(covariance)
    torch.testing.assert_close(in_map[:3, :3], covariance[:3, :3], atol=0, rtol=0)  # radians stay radians
    torch.testing.assert_close(in_map[:3, 3:], 4.0 * covariance[:3, 3:], atol=1e-12, rtol=0)
    torch.testing.assert_close(in_map[3:, 3:], 16.0 * covariance[3:, 3:], atol=1e-12, rtol=0)
    torch.testing.assert_close(normalization.covariance_to_metric(in_map), covariance, atol=1e-12, rtol=0)
    assert normalization.covariance_to_map(covariance.float()).dtype == torch.float64


def test_a_covariance_of_the_wrong_shape_is_refused() -> None:
    with pytest.raises(ValueError, match=r"covariance: expected shape \(6, 6\).*got \(3, 3\)"):
        MapNormalization().covariance_to_map(torch.eye(3, dtype=torch.float64))
