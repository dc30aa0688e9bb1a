"""Dataset readers: LLFF, NeRF-synthetic and nerfstudio ``transforms.json``, 7-Scenes, into one posed-image type."""

from locnerf.data.detect import dataset_format, read_dataset
from locnerf.data.llff import normalize_llff_poses, read_llff
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import read_seven_scenes
from locnerf.data.transforms_json import read_nerf_synthetic, read_nerfstudio

__all__ = [
    "PosedImages",
    "dataset_format",
    "normalize_llff_poses",
    "read_dataset",
    "read_llff",
    "read_nerf_synthetic",
    "read_nerfstudio",
    "read_seven_scenes",
]
