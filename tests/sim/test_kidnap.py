"""Choosing a kidnapping's jump by its size (locnerf.sim.kidnap), on frames whose jumps are known in closed form."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from locnerf.errors import LocnerfInputError
from locnerf.field.protocol import MapNormalization
from locnerf.geometry import make_pose, so3_exp
from locnerf.sim.kidnap import kidnap_shift_for_jump
from locnerf.sim.paths import SequencePath
from locnerf.sim.scenario import ScenarioConfig, build_scenario
from locnerf.sim.sensors import VioConfig
from tests.sim.test_scenario import tiny_sequence

PERFECT_VIO = VioConfig(translation_drift=0.0, yaw_drift_rate=0.0, translation_noise=0.0, rotation_noise=0.0)


def line_path() -> SequencePath:
    """8 frames 1 m apart along x, turning 10° of yaw per frame, one frame per odometry period (15 Hz):
    from frame 1 (the kidnapping's stamp at 1/15 s) the jump over k <= 6 frames is k metres and 10 k degrees."""
    frames = tiny_sequence(count=8)
    count = len(frames)
    yaw = torch.arange(count, dtype=torch.float64) * math.radians(10.0)
    rotations = so3_exp(torch.stack([torch.zeros(count, dtype=torch.float64), yaw, torch.zeros(count, dtype=torch.float64)], dim=-1))
    positions = torch.stack(
        [torch.arange(count, dtype=torch.float64), torch.zeros(count, dtype=torch.float64), torch.zeros(count, dtype=torch.float64)], dim=-1
    )
    return SequencePath(dataclasses.replace(frames, T_world_cam=make_pose(rotations, positions)), speed=1.0, odom_rate=15.0, frame_rate=15.0)


@pytest.mark.parametrize(("distance", "angle", "frames"), [(1.99, 19.9, 2), (2.5, 10.0, 3), (1.0, 55.0, 6)])
def test_the_nearest_jump_at_least_as_large_is_chosen(distance: float, angle: float, frames: int) -> None:
    jump = kidnap_shift_for_jump(line_path(), 1 / 15, 15.0, distance, angle)
    assert jump.shift == pytest.approx(frames / 15)
    assert jump.distance == pytest.approx(frames, abs=1e-9)
    assert jump.angle_deg == pytest.approx(10.0 * frames, abs=1e-6)


def test_the_scenario_lands_on_the_chosen_frame() -> None:
    path = line_path()
    jump = kidnap_shift_for_jump(path, 1 / 15, 15.0, 1.99, 19.9)
    config = ScenarioConfig(duration=0.2, image_rate=5.0, vio=PERFECT_VIO, kidnap_at=1 / 15, kidnap_shift=jump.shift)
    scenario = build_scenario(path, config, MapNormalization())
    assert scenario.kidnap_tick == 1
    torch.testing.assert_close(scenario.truth[1:3], path.frames.T_world_cam[3:5].double())


def test_a_jump_larger_than_the_loop_is_refused() -> None:
    with pytest.raises(LocnerfInputError, match=r"farthest is 6.000 m"):
        kidnap_shift_for_jump(line_path(), 1 / 15, 15.0, 7.0, 10.0)
    with pytest.raises(LocnerfInputError, match="expected a positive distance"):
        kidnap_shift_for_jump(line_path(), 1 / 15, 15.0, 0.0, 20.0)
