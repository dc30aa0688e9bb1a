"""Building maps from posed images, and measuring them."""

from locnerf.train.build import BuildConfig, ForwardFacingConfig, RoomConfig, build_map, evaluate_held_out, evaluate_map, training_views
from locnerf.train.metrics import psnr, ssim

__all__ = ["BuildConfig", "ForwardFacingConfig", "RoomConfig", "build_map", "evaluate_held_out", "evaluate_map", "psnr", "ssim", "training_views"]
