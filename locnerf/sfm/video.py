"""Picking the frames of a video worth posing: sharp ones, spaced by motion rather than by time.

Consecutive video frames overlap almost entirely and many are blurred by the camera's motion.
Every frame is measured on a small grey thumbnail: sharpness as the variance of its Laplacian, and
motion since the last kept frame as the median displacement of corners tracked by pyramidal
Lucas-Kanade, a fraction of the thumbnail's width. Once the motion since the last kept frame reaches ``motion``, the sharpest
frame among the next ``window`` frames is kept; frames blurrier than ``blur_ratio`` times the
video's median sharpness are never kept.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from locnerf.errors import DatasetError

logger = logging.getLogger(__name__)

THUMBNAIL_WIDTH = 160
MIN_TRACKED = 10


class VideoSelection(BaseModel):
    """How frames are picked from a video."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    motion: float = Field(0.05, gt=0, description="Median image motion since the last kept frame, as a fraction of the width, before the next is kept.")
    window: int = Field(5, ge=1, description="Frames, from the one that reached the motion on, among which the sharpest is kept.")
    blur_ratio: float = Field(0.4, ge=0, lt=1, description="Frames whose sharpness is below this fraction of the video's median are never kept.")
    max_frames: int = Field(400, ge=3, description="Most frames kept (the motion threshold is raised until they fit).")


@dataclass(frozen=True)
class PickedFrames:
    """Frames written as PNG files, their frame numbers and times (seconds from the video's start)."""

    paths: list[Path]
    numbers: list[int]
    stamps: list[float]


def _thumbnail(frame: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
    height = max(8, round(grey.shape[0] * THUMBNAIL_WIDTH / grey.shape[1]))
    return cv2.resize(grey, (THUMBNAIL_WIDTH, height), interpolation=cv2.INTER_AREA)


def sharpness(thumbnail: np.ndarray) -> float:
    """Variance of the Laplacian of a grey image (higher: sharper)."""
    return float(cv2.Laplacian(thumbnail, cv2.CV_64F).var())


def motion(previous: np.ndarray, current: np.ndarray) -> float:
    """Median displacement of corners tracked from one grey thumbnail to the next (pyramidal Lucas-Kanade), as a
    fraction of the width; infinite when fewer than MIN_TRACKED corners are found or followed (the view changed entirely)."""
    corners = cv2.goodFeaturesToTrack(previous, maxCorners=200, qualityLevel=0.01, minDistance=5)
    if corners is None or len(corners) < MIN_TRACKED:
        return float("inf")
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(previous, current, corners, None, winSize=(21, 21), maxLevel=3)
    found = status.reshape(-1) == 1
    if found.sum() < MIN_TRACKED:
        return float("inf")
    return float(np.median(np.linalg.norm((tracked - corners).reshape(-1, 2)[found], axis=1)) / previous.shape[1])


def _open(path: Path) -> cv2.VideoCapture:
    video = cv2.VideoCapture(str(path))
    if not video.isOpened():
        raise DatasetError(f"video {path}: cannot be opened (not a video, or a codec this OpenCV build lacks); convert it to MP4/H.264 or extract its frames")
    return video


def _measure(path: Path) -> tuple[list[np.ndarray], list[float], float, tuple[int, int]]:
    """Thumbnails and sharpness of every frame, the frame rate, and the frame size (width, height)."""
    video = _open(path)
    fps = video.get(cv2.CAP_PROP_FPS) or 30.0
    total = int(video.get(cv2.CAP_PROP_FRAME_COUNT)) or None
    thumbnails, sharp, size = [], [], None
    with tqdm(total=total, desc="video frames", unit="frame", leave=False) as bar:
        while True:
            ok, frame = video.read()
            if not ok:
                break
            size = size or (frame.shape[1], frame.shape[0])
            if (frame.shape[1], frame.shape[0]) != size:
                raise DatasetError(f"video {path}: frame {len(thumbnails)} is {frame.shape[1]}x{frame.shape[0]}, expected {size[0]}x{size[1]} like frame 0")
            thumbnails.append(_thumbnail(frame))
            sharp.append(sharpness(thumbnails[-1]))
            bar.update(1)
    video.release()
    if not thumbnails:
        raise DatasetError(f"video {path}: opened but no frame could be decoded")
    return thumbnails, sharp, fps, size


def _pick(thumbnails: list[np.ndarray], sharp: list[float], selection: VideoSelection, threshold: float) -> list[int]:
    """Frame numbers kept at one motion threshold (see the module docstring)."""
    floor = selection.blur_ratio * float(np.median(sharp))
    usable = [i for i, value in enumerate(sharp) if value >= floor]
    if not usable:
        return []
    kept = [max(usable[: selection.window], key=lambda i: sharp[i])]
    i = kept[0] + 1
    while i < len(thumbnails):
        if sharp[i] >= floor and motion(thumbnails[kept[-1]], thumbnails[i]) >= threshold:
            window = [j for j in range(i, min(i + selection.window, len(thumbnails))) if sharp[j] >= floor]
            kept.append(max(window, key=lambda j: sharp[j]))
            i = kept[-1] + 1
        else:
            i += 1
    return kept


def select_video_frames(path: Path, folder: Path, selection: VideoSelection) -> PickedFrames:
    """Pick sharp frames spaced by motion from a video and write them to ``folder`` as ``frame-NNNNNN.png``.

    Raises:
        DatasetError: naming the video when it cannot be opened, decodes no frame, changes size, or has no usable frame.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video {path}: no such file")
    thumbnails, sharp, fps, size = _measure(path)
    threshold = selection.motion
    kept = _pick(thumbnails, sharp, selection, threshold)
    while len(kept) > selection.max_frames:
        threshold *= 1.25
        kept = _pick(thumbnails, sharp, selection, threshold)
    if not kept:
        raise DatasetError(f"video {path}: all {len(thumbnails)} frames are blurred (sharpness below {selection.blur_ratio} of the median)")
    folder.mkdir(parents=True, exist_ok=True)
    wanted, paths = set(kept), []
    video = _open(path)
    for number in range(len(thumbnails)):
        ok, frame = video.read()
        if not ok:
            break
        if number in wanted:
            paths.append(folder / f"frame-{number:06d}.png")
            cv2.imwrite(str(paths[-1]), frame)
    video.release()
    logger.info(
        "video %s: %d of %d frames (%dx%d, %.1f fps) kept at motion %.3f of the width, sharpness >= %.0f",
        path,
        len(paths),
        len(thumbnails),
        size[0],
        size[1],
        fps,
        threshold,
        selection.blur_ratio * float(np.median(sharp)),
    )
    return PickedFrames(paths, kept[: len(paths)], [number / fps for number in kept[: len(paths)]])
