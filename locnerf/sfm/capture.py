"""What a capture to be posed by structure from motion holds: its images in capture order, and their depth images if any.

A capture is an image folder, a video file (frames picked by :mod:`locnerf.sfm.video`), an RGB-D
data set in the 7-Scenes layout whose pose files are not read, or a forward-facing LLFF capture
(``images_<d>/``; its ``poses_bounds.npy`` is not read). An existing COLMAP sparse model and a
nerfstudio ``transforms.json`` are posed already (:func:`capture_kind` tells them apart).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import cv2

from locnerf.data.detect import dataset_format
from locnerf.data.image_files import IMAGE_SUFFIXES
from locnerf.data.llff import image_folder
from locnerf.data.seven_scenes import COLOUR_INTRINSICS, colour_path, depth_camera_of, frame_stems, sequence_folders
from locnerf.errors import DatasetError
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sfm.video import VideoSelection, select_video_frames

logger = logging.getLogger(__name__)

MIN_IMAGES = 3
"""Fewest images structure from motion is run on (two make one pair and no check of it)."""
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
MODEL_FILES = ("cameras.bin", "cameras.txt")


@dataclass(frozen=True)
class Capture:
    """Images to pose, in capture order.

    Attributes:
        kind: ``images`` | ``video`` | ``rgbd`` | ``llff`` (forward-facing: the map gets NDC rays).
        source: the path the user named.
        image_root: folder the ``names`` are relative to (for a video, the folder its picked frames were written to).
        names: K image paths relative to ``image_root`` (COLMAP's image names).
        stamps: K capture times in seconds (video: frame time; 7-Scenes: frame number / 30 Hz; images: a numeric
            file stem, nanoseconds when above 1e12), or None when the names carry none.
        depth_paths: K uint16-millimetre depth images (RGB-D), else None.
        depth_camera: the depth camera at the colour images' full size (RGB-D), else None.
    """

    kind: str
    source: Path
    image_root: Path
    names: list[str]
    stamps: list[float] | None = None
    depth_paths: list[Path] | None = None
    depth_camera: PinholeIntrinsics | None = None

    def __len__(self) -> int:
        return len(self.names)


def model_folder(path: Path) -> Path | None:
    """The folder holding a COLMAP sparse model at ``path``, ``path/sparse/0`` or ``path/sparse``; None if there is none."""
    for folder in (path, path / "sparse" / "0", path / "sparse"):
        if folder.is_dir() and any((folder / name).is_file() for name in MODEL_FILES):
            return folder
    return None


def capture_kind(path: str | Path) -> str:
    """``video`` | ``colmap`` | ``transforms`` | ``rgbd`` | ``llff`` | ``images`` for a capture path.

    Raises:
        FileNotFoundError: naming the path when it does not exist.
    """
    path = Path(path)
    if path.is_file():
        return "transforms" if path.name == "transforms.json" else "video"
    if not path.is_dir():
        raise FileNotFoundError(f"capture {path}: no such file or folder")
    if model_folder(path) is not None:
        return "colmap"
    if (path / "transforms.json").is_file():
        return "transforms"
    try:
        kind = {"seven_scenes": "rgbd", "llff": "llff"}.get(dataset_format(path))
        if kind is not None:
            return kind
    except DatasetError:
        pass
    return "images"


def _stamp(name: str) -> float | None:
    """Seconds from a numeric file stem (``1311868164.363181.png``, ``000123456789000.png`` in ns), else None."""
    match = re.fullmatch(r"(\d+(?:\.\d+)?)", Path(name).name.rsplit(".", 1)[0])
    if match is None:
        return None
    value = float(match.group(1))
    return value * 1e-9 if value > 1e12 else value


def _check_sizes(root: Path, names: list[str]) -> tuple[int, int]:
    """The images' one size (width, height); images of mixed sizes are refused (one camera is estimated for all of them).

    Raises:
        DatasetError: naming the images whose size differs from the first one's, or one that cannot be read.
    """
    sizes = {}
    for name in names:
        image = cv2.imread(str(root / name), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise DatasetError(f"capture image {root / name}: cannot be decoded as an image")
        sizes[name] = (image.shape[1], image.shape[0])
    first = sizes[names[0]]
    odd = [f"{name} ({w}x{h})" for name, (w, h) in sizes.items() if (w, h) != first]
    if odd:
        raise DatasetError(
            f"capture {root}: {len(odd)} images differ in size from {names[0]} ({first[0]}x{first[1]}): {', '.join(odd[:10])}"
            f"{' ...' if len(odd) > 10 else ''}; expected one camera at one size (resize them or capture them apart)"
        )
    return first


def _enough(capture: Capture) -> Capture:
    if len(capture) < MIN_IMAGES:
        raise DatasetError(f"capture {capture.source}: {len(capture)} images, expected at least {MIN_IMAGES} overlapping views for structure from motion")
    return capture


def read_capture(
    path: str | Path, work_folder: Path, stride: int = 1, split: str = "train", video: VideoSelection | None = None, llff_downscale: int = 8
) -> Capture:
    """The images (and depth images) of an image folder, a video or an RGB-D data set, to be posed by SfM.

    Args:
        path: the capture.
        work_folder: where a video's picked frames are written (``work_folder/frames``).
        stride: keep every ``stride``-th image (image folders and RGB-D data; a video's frames are picked by :func:`select_video_frames`).
        split: RGB-D data: the split whose sequences are read (its pose files are not).
        video: how a video's frames are picked.
        llff_downscale: an LLFF capture's images are those of ``images_<llff_downscale>/`` (``poses_bounds.npy`` is not read).
    Raises:
        FileNotFoundError / DatasetError: naming the path, for a path that holds no images, too few images,
            images of mixed sizes, or a video that cannot be opened.
    """
    path = Path(path)
    if stride < 1:
        raise DatasetError(f"stride={stride}: expected an integer >= 1")
    kind = capture_kind(path)
    if kind == "video":
        frames = select_video_frames(path, work_folder / "frames", video or VideoSelection())
        return _enough(Capture("video", path, work_folder / "frames", [p.name for p in frames.paths], stamps=frames.stamps))
    if kind == "rgbd":
        stems = [stem for sequence in sequence_folders(path, split) for stem in frame_stems(sequence)][::stride]
        colours = [colour_path(stem) for stem in stems]
        names = [str(p.relative_to(path)) for p in colours]
        depths = [stem.with_name(stem.name + ".depth.png") for stem in stems]
        missing = [str(p) for p in depths if not p.is_file()]
        depth_paths = None if len(missing) == len(depths) else depths
        if depth_paths is not None and missing:
            raise DatasetError(f"capture {path}: {len(missing)} frames have no depth image, e.g. {missing[0]}; expected one per colour image or none")
        width, height = _check_sizes(path, names)
        full_size = PinholeIntrinsics.centred(
            COLOUR_INTRINSICS.fx * width / COLOUR_INTRINSICS.width, COLOUR_INTRINSICS.fy * width / COLOUR_INTRINSICS.width, width, height
        )
        stamps = [int(re.sub(r"\D", "", stem.name)) / 30.0 for stem in stems]
        return _enough(
            Capture(
                "rgbd",
                path,
                path,
                names,
                stamps=stamps,
                depth_paths=depth_paths,
                depth_camera=depth_camera_of(path, full_size) if depth_paths else None,
            )
        )
    if kind not in ("images", "llff"):
        raise DatasetError(f"capture {path}: a {kind} capture is posed already; it is read as it is, not by read_capture")
    root = path
    if kind == "llff":
        root, resize = image_folder(path, llff_downscale)
        if resize != 1:
            raise DatasetError(f"LLFF capture {path}: no images_{llff_downscale}/ folder; expected the images at the map's size (--downscale)")
    names = sorted(p.name for p in root.iterdir() if p.is_file() and p.suffix in IMAGE_SUFFIXES)[::stride]
    if not names:
        raise FileNotFoundError(f"capture {root}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder, and no video, 7-Scenes data or COLMAP model")
    _check_sizes(root, names)
    stamps = [_stamp(name) for name in names]
    return _enough(Capture(kind, path, root, names, stamps=None if None in stamps else stamps))
