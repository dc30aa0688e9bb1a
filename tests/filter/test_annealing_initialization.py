"""Annealing stages, initial distributions and the configuration presets."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from locnerf.config import PRESETS, load_config, preset
from locnerf.filter.annealing import AnnealingConfig, AnnealingStage, noise_scale, particle_count, stage_for_spread
from locnerf.filter.initialization import global_particles, inerf_particles, uniform_particles
from locnerf.geometry import make_pose, rotation_error_deg, so3_exp

CENTER = make_pose(so3_exp(torch.tensor([0.2, -0.4, 0.1], dtype=torch.float64)), torch.tensor([0.5, -0.2, 1.0], dtype=torch.float64))


def test_stage_thresholds_and_effects():
    config = AnnealingConfig(alpha_refine=0.08, alpha_super_refine=0.03, reduced_particles=100)
    assert stage_for_spread(0.2, config) is AnnealingStage.COARSE
    assert stage_for_spread(0.05, config) is AnnealingStage.REFINE
    assert stage_for_spread(0.01, config) is AnnealingStage.SUPER_REFINE
    assert [noise_scale(s, config) for s in AnnealingStage] == [1.0, 0.5, 0.25]
    assert particle_count(AnnealingStage.REFINE, 300, config) == 100
    assert particle_count(AnnealingStage.COARSE, 300, config) == 300
    assert stage_for_spread(0.0, AnnealingConfig(enabled=False)) is AnnealingStage.COARSE


def test_thresholds_out_of_order_are_refused():
    with pytest.raises(ValueError, match="alpha_super_refine"):
        AnnealingConfig(alpha_refine=0.02, alpha_super_refine=0.05)


def test_inerf_particles_stay_within_protocol_bounds(generator):
    poses = inerf_particles(CENTER, 2000, generator)
    offsets = poses[:, :3, 3] - CENTER[:3, 3]
    assert offsets.abs().max() <= 0.1 + 1e-12
    angles = rotation_error_deg(poses, CENTER.expand(2000, 4, 4))
    assert angles.max() <= 40.0 + 1e-9
    assert angles.mean() > 15.0  # uniform in [-40, 40]: mean |angle| is 20°


def test_global_particles_keep_roll_and_pitch(generator):
    up = (0.0, 1.0, 0.0)
    poses = global_particles(CENTER, 1000, generator, half_width=1.0, up=up)
    gravity_in_camera = poses[:, :3, :3].transpose(-1, -2) @ torch.tensor(up, dtype=torch.float64)
    expected = CENTER[:3, :3].T @ torch.tensor(up, dtype=torch.float64)
    assert torch.allclose(gravity_in_camera, expected.expand(1000, 3), atol=1e-12)
    assert (poses[:, :3, 3] - CENTER[:3, 3]).abs().max() <= 1.0
    yaw_spread = rotation_error_deg(poses, CENTER.expand(1000, 4, 4))
    assert yaw_spread.max() > 170.0


def test_uniform_particles_respect_bounds_and_refuse_bad_bounds(generator):
    bounds = torch.tensor([[-1.0, 0.0, -2.0], [1.0, 0.5, 2.0]], dtype=torch.float64)
    poses = uniform_particles(bounds, 500, generator)
    assert ((poses[:, :3, 3] >= bounds[0]) & (poses[:, :3, 3] <= bounds[1])).all()
    with pytest.raises(ValueError, match="bounds"):
        uniform_particles(bounds.flip(0), 5, generator)


@pytest.mark.parametrize("up", [(0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 1.0, 0.0)])
def test_uniform_particles_without_a_tilt_are_level_about_the_maps_up(generator, up):
    """Level: the camera's y axis (OpenGL: up) along the map's up, its viewing direction (−z) horizontal, any heading."""
    bounds = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    poses = uniform_particles(bounds, 500, generator, up=up)
    axis = torch.nn.functional.normalize(torch.tensor(up, dtype=torch.float64), dim=0)
    torch.testing.assert_close(poses[:, :3, 1], axis.expand(500, 3))
    viewing = -poses[:, :3, 2]
    torch.testing.assert_close(viewing @ axis, torch.zeros(500, dtype=torch.float64))
    headings = torch.linalg.cross(viewing, axis.expand(500, 3))  # horizontal, turning with the yaw
    assert (headings.mean(dim=0).norm() < 0.1) and headings.norm(dim=-1).min() > 0.99


def test_uniform_particles_about_y_up_are_turns_about_y(generator):
    """The y-up case is as before: the identity turned by a yaw about y."""
    bounds = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    rotations = uniform_particles(bounds, 100, generator)[:, :3, :3]
    yaw = torch.atan2(rotations[:, 0, 2], rotations[:, 2, 2])
    cos, sin = torch.cos(yaw), torch.sin(yaw)
    zero, one = torch.zeros_like(yaw), torch.ones_like(yaw)
    turns = torch.stack([cos, zero, sin, zero, one, zero, -sin, zero, cos], dim=-1).reshape(100, 3, 3)
    torch.testing.assert_close(rotations, turns)


def test_presets_reproduce_the_original_parameters():
    llff, global_, jackal = preset("llff"), preset("llff_global"), preset("jackal")
    assert (llff.particles, llff.annealing.reduced_particles, llff.measurement.pixels) == (300, 100, 64)
    assert (global_.particles, global_.annealing.reduced_particles, global_.measurement.pixels) == (600, 100, 32)
    assert (jackal.particles, jackal.annealing.reduced_particles, jackal.measurement.pixels) == (400, 150, 32)
    assert (llff.annealing.alpha_refine, global_.annealing.alpha_refine, jackal.annealing.alpha_refine) == (0.08, 0.08, 0.18)
    assert {c.annealing.alpha_super_refine for c in (llff, global_, jackal)} == {0.03}
    assert llff.motion.translation_sigma == (0.01,) * 3 and global_.motion.translation_sigma == (0.02,) * 3
    assert jackal.motion.translation_sigma == (0.002, 0.002, 0.003)
    assert llff.motion.rotation_sigma == (0.02,) * 3 and global_.motion.rotation_sigma == (0.01, 0.04, 0.01)
    assert jackal.motion.rotation_sigma == (0.002,) * 3
    assert [c.convergence_protection.count for c in (llff, global_, jackal)] == [10, 10, 15]
    assert {c.convergence_protection.half_width for c in (llff, global_, jackal)} == {0.2}
    assert {(c.mlp_coarse_samples, c.mlp_fine_samples) for c in (llff, global_, jackal)} == {(64, 64)}
    assert {c.measurement.sampling for c in (llff, global_, jackal)} == {"uniform"}
    assert set(PRESETS) == {"llff", "llff_global", "jackal", "tracking", "precise"}
    assert not any(c.recovery.enabled for c in (llff, global_, jackal))


def test_tracking_preset_is_llff_global_with_recovery():
    tracking, global_ = preset("tracking"), preset("llff_global")
    assert tracking.recovery.enabled
    assert (tracking.particles, tracking.motion) == (global_.particles, global_.motion)


def test_precise_preset_is_llff_keeping_its_particles_with_gradient_pixels():
    precise, llff = preset("precise"), preset("llff")
    assert precise.annealing.reduced_particles == precise.particles == llff.particles
    assert precise.measurement.sampling == "gradient" and preset("tracking").measurement.sampling == "uniform"
    assert (precise.motion, precise.measurement.pixels) == (llff.motion, llff.measurement.pixels)


def test_toml_config_overrides_a_preset(tmp_path):
    path = tmp_path / "filter.toml"
    path.write_text('preset = "jackal"\nparticles = 123\n[motion]\ntranslation_sigma = [0.1, 0.2, 0.3]\n')
    config = load_config(path)
    assert config.particles == 123 and config.motion.translation_sigma == (0.1, 0.2, 0.3)
    assert config.annealing.reduced_particles == 150


@pytest.mark.parametrize(
    "text,message",
    [("particles = [", "not valid TOML"), ('preset = "nope"', "unknown preset"), ("particles = -3", "invalid"), ("colour = 1", "invalid")],
)
def test_bad_config_files_are_refused(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_config(path)


def test_unknown_preset_name():
    with pytest.raises(ValueError, match="unknown preset 'fern'"):
        preset("fern")


def test_the_configuration_files_of_measured_results_load():
    """Every file in configs/ is a valid localizer configuration; the lego orbit one has the
    recovery and pivot noise that docs/RESULTS.md describes."""
    folder = Path(__file__).resolve().parents[2] / "configs"
    files = sorted(folder.glob("*.toml"))
    assert files, f"no configuration files in {folder}"
    configs = {path.stem: load_config(path) for path in files}
    orbit = configs["lego_orbit_tracking"]
    assert orbit.particles == 2400 and orbit.annealing.reduced_particles == 2400
    assert orbit.recovery.enabled and orbit.recovery.keyframe_share == 0.8 and orbit.motion.pivot_noise() is not None
