"""Open any supported data set by looking at what its folder holds."""

from __future__ import annotations

from pathlib import Path

from locnerf.data.llff import read_llff
from locnerf.data.posed_images import PosedImages
from locnerf.data.transforms_json import read_nerf_synthetic, read_nerfstudio


def dataset_format(path: str | Path) -> str:
    """``llff`` | ``nerf_synthetic`` | ``nerfstudio`` for a data-set folder (or a transforms.json).

    Raises:
        FileNotFoundError / ValueError: naming the path when nothing recognisable is there.
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
    raise ValueError(f"data set {path}: expected poses_bounds.npy (LLFF), transforms_<split>.json (NeRF-synthetic) or transforms.json (nerfstudio)")


def read_dataset(path: str | Path, split: str = "train", downscale: int | None = None, skip_missing: bool = False) -> PosedImages:
    """Read one split of a data set of any supported format.

    Args:
        path: data-set folder (or a nerfstudio ``transforms.json``).
        split: ``train`` | ``test`` | ``val`` (NeRF-synthetic) | ``all`` (LLFF, nerfstudio); LLFF and
            nerfstudio hold out every 8th image as ``test``.
        downscale: image size divisor; default 8 for LLFF (``images_8``), 1 otherwise.
        skip_missing: NeRF-synthetic only: leave out frames whose image is absent.
    """
    kind = dataset_format(path)
    if kind == "llff":
        return read_llff(path, downscale=downscale or 8, split=split)
    if kind == "nerf_synthetic":
        return read_nerf_synthetic(path, split=split, downscale=downscale or 1, skip_missing=skip_missing)
    return read_nerfstudio(path, downscale=downscale or 1, split=split)
