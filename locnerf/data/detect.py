"""Open any supported data set by looking at what its folder holds."""

from __future__ import annotations

from pathlib import Path

import torch

from locnerf.data.llff import read_llff
from locnerf.data.posed_images import PosedImages
from locnerf.data.seven_scenes import DEFAULT_DOWNSCALE as SEVEN_SCENES_DOWNSCALE
from locnerf.data.seven_scenes import read_seven_scenes
from locnerf.data.sfm_poses import SFM_FOLDER, check_pose_source
from locnerf.data.transforms_json import read_nerf_synthetic, read_nerfstudio
from locnerf.data.tum_rgbd import DEFAULT_DOWNSCALE as TUM_DOWNSCALE
from locnerf.data.tum_rgbd import is_tum_rgbd, read_tum_rgbd
from locnerf.errors import DatasetError


def dataset_format(path: str | Path) -> str:
    """``llff`` | ``nerf_synthetic`` | ``nerfstudio`` | ``seven_scenes`` | ``tum_rgbd`` for a data-set folder (or a transforms.json).

    Raises:
        FileNotFoundError / DatasetError: naming the path when nothing recognisable is there.
    """
    path = Path(path)
    if path.is_file() and path.name == "transforms.json":
        return "nerfstudio"
    if not path.is_dir():
        raise FileNotFoundError(f"data set {path}: no such folder")
    if (path / "poses_bounds.npy").is_file():
        return "llff"
    if any(path.glob("transforms_*.json")):
        return "nerf_synthetic"
    if (path / "transforms.json").is_file():
        return "nerfstudio"
    if (path / "TrainSplit.txt").is_file() or (path / "TestSplit.txt").is_file():
        return "seven_scenes"
    if is_tum_rgbd(path):
        return "tum_rgbd"
    raise DatasetError(
        f"data set {path}: expected poses_bounds.npy (LLFF), transforms_<split>.json (NeRF-synthetic), "
        "transforms.json (nerfstudio), TrainSplit.txt/TestSplit.txt (7-Scenes) or rgb.txt, depth.txt and groundtruth.txt (TUM RGB-D)"
    )


def read_dataset(
    path: str | Path,
    split: str = "train",
    downscale: int | None = None,
    skip_missing: bool = False,
    stride: int = 1,
    poses: str = "dslam",
    T_depth_colour: torch.Tensor | None = None,
) -> PosedImages:
    """Read one split of a data set of any supported format.

    Args:
        path: data-set folder (or a nerfstudio ``transforms.json``).
        split: ``train`` | ``test`` | ``val`` (NeRF-synthetic) | ``all`` (LLFF, nerfstudio, 7-Scenes);
            LLFF, nerfstudio and TUM RGB-D hold out every 8th image as ``test``; 7-Scenes uses its split files.
        downscale: image size divisor; default 8 for LLFF (``images_8``), 4 for 7-Scenes and TUM RGB-D, 1 otherwise.
        skip_missing: NeRF-synthetic only: leave out frames whose image is absent.
        stride: keep every ``stride``-th frame of the split.
        poses: 7-Scenes: ``dslam`` (the frames' own poses) or ``sfm`` (the SfM pseudo ground truth,
            :mod:`locnerf.data.sfm_poses`); other formats have their own poses only (``dslam`` means those).
        T_depth_colour: 7-Scenes with ``sfm``: the colour camera's calibration (see :func:`read_seven_scenes`).
    """
    if stride < 1:
        raise DatasetError(f"stride={stride}: expected an integer >= 1")
    kind = dataset_format(path)
    if kind == "seven_scenes":
        return read_seven_scenes(path, split=split, downscale=downscale or SEVEN_SCENES_DOWNSCALE, stride=stride, poses=poses, T_depth_colour=T_depth_colour)
    if kind == "tum_rgbd" and check_pose_source(poses) == "dslam":
        return read_tum_rgbd(path, split=split, downscale=downscale or TUM_DOWNSCALE, stride=stride)
    if check_pose_source(poses) != "dslam":
        raise DatasetError(f"--poses {poses}: {path} is a {kind} data set, which has its own poses only; --poses sfm reads a 7-Scenes folder's {SFM_FOLDER}/")
    if kind == "llff":
        images = read_llff(path, downscale=downscale or 8, split=split)
    elif kind == "nerf_synthetic":
        images = read_nerf_synthetic(path, split=split, downscale=downscale or 1, skip_missing=skip_missing)
    else:
        images = read_nerfstudio(path, downscale=downscale or 1, split=split)
    return images if stride == 1 else images.subset(list(range(0, len(images), stride)))
