"""Structure from motion with pycolmap on the CPU: SIFT features, matching, incremental mapping, bundle adjustment.

Small captures (up to ``exhaustive_up_to`` images) match every pair; longer ones match each image
with its ``overlap`` successors and those 2, 4, 8, ... images on (COLMAP's quadratic sequential
overlap, which closes loops over a walk through a room when it passes the same place again within
2^overlap frames). COLMAP's own loop detection needs a vocabulary-tree file (``vocab_tree``): with
one, it is used. One camera is estimated for all images (``camera_model``, SIMPLE_RADIAL by default).

The result is cached in ``folder/<key>/`` where ``key`` hashes the images (names, sizes, times of
modification), the settings and the pycolmap version: a second run on the same capture loads the
model instead of redoing it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from locnerf.errors import DatasetError
from locnerf.sfm.capture import Capture

logger = logging.getLogger(__name__)

DONE_FILE = "sfm.json"


class SfmConfig(BaseModel):
    """Settings of the structure-from-motion run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    camera_model: str = Field("SIMPLE_RADIAL", description="COLMAP camera model shared by all images (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV).")
    max_features: int = Field(4096, gt=0, description="Most SIFT features per image.")
    max_image_size: int = Field(1600, gt=0, description="Images are scaled down to this longest side for feature extraction.")
    exhaustive_up_to: int = Field(60, ge=2, description="Captures of at most this many images match every pair; longer ones sequentially.")
    overlap: int = Field(10, ge=1, description="Sequential matching: successors matched with each image (and as many at quadratic spacing).")
    vocab_tree: str | None = Field(None, description="COLMAP vocabulary-tree file enabling its loop detection in sequential matching.")
    min_registered_fraction: float = Field(
        0.5, gt=0, le=1, description="Fewest images of the capture the reconstruction must pose; below it SfM fails with the images it could not pose."
    )
    threads: int = Field(-1, description="CPU threads of COLMAP (-1: all).")
    seed: int = Field(0, ge=0, description="Seed of COLMAP's random draws (RANSAC, initial pair); it fixes the reconstruction only with threads=1.")


@dataclass
class SfmResult:
    """A reconstruction and what it left out.

    Attributes:
        model_folder: the COLMAP sparse model (binary files).
        reconstruction: the largest model (``pycolmap.Reconstruction``).
        unregistered: image name -> why it has no pose.
        seconds: wall time of the run (0 when loaded from the cache).
        cached: loaded from the cache.
    """

    model_folder: Path
    reconstruction: object
    unregistered: dict[str, str]
    seconds: float
    cached: bool


def cache_key(capture: Capture, config: SfmConfig) -> str:
    """A hash of the images (names, sizes, modification times), the settings and pycolmap's version."""
    import pycolmap

    digest = hashlib.sha256()
    digest.update(json.dumps({"config": config.model_dump(mode="json"), "pycolmap": pycolmap.__version__}, sort_keys=True).encode())
    for name in capture.names:
        stat = (capture.image_root / name).stat()
        digest.update(f"{name}|{stat.st_size}|{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()[:16]


def _pycolmap():
    try:
        import pycolmap
    except ImportError as error:  # an optional extra
        raise DatasetError("structure from motion needs pycolmap: pip install 'locnerf[sfm]' (or pip install 'pycolmap>=4.2')") from error
    return pycolmap


def _extract_and_match(pycolmap, database: Path, capture: Capture, config: SfmConfig) -> None:
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = config.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = config.max_features
    extraction.max_image_size = config.max_image_size
    extraction.num_threads = config.threads
    started = time.monotonic()
    pycolmap.extract_features(
        database,
        capture.image_root,
        image_names=capture.names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    logger.info("SfM: SIFT features of %d images in %.0f s", len(capture), time.monotonic() - started)
    started = time.monotonic()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.threads
    if len(capture) <= config.exhaustive_up_to:
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
        how = "every pair"
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.overlap
        pairing.quadratic_overlap = True
        pairing.num_threads = config.threads
        if config.vocab_tree:
            pairing.loop_detection = True
            pairing.vocab_tree_path = config.vocab_tree
        pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
        how = f"sequential, overlap {config.overlap} (quadratic){', loop detection' if config.vocab_tree else ''}"
    logger.info("SfM: matched (%s) in %.0f s", how, time.monotonic() - started)


def _why_unregistered(pycolmap, database: Path, names: list[str]) -> dict[str, str]:
    """For each image name: its features and geometrically verified image pairs, as the reason it got no pose."""
    db = pycolmap.Database.open(database)
    try:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        pair_ids, inliers = db.read_two_view_geometry_num_inliers()
        verified: dict[int, int] = {}
        for pair_id, count in zip(pair_ids, inliers):
            if count > 0:
                for image_id in pycolmap.pair_id_to_image_pair(pair_id):
                    verified[image_id] = verified.get(image_id, 0) + 1
        reasons = {}
        for name in names:
            features = db.num_keypoints_for_image(ids[name]) if name in ids else 0
            pairs = verified.get(ids.get(name, -1), 0)
            if features == 0:
                reasons[name] = "no SIFT features (blank, dark or blurred image)"
            elif pairs == 0:
                reasons[name] = f"{features} features but no verified match with any other image (no overlap, or too little texture)"
            else:
                reasons[name] = f"{features} features and {pairs} verified image pairs, but its pose could not be estimated in the main model"
        return reasons
    finally:
        db.close()


def run_sfm(capture: Capture, folder: Path, config: SfmConfig = SfmConfig(), progress: bool = True) -> SfmResult:
    """Pose a capture's images by incremental SfM, or load the cached result of an identical earlier run.

    Args:
        capture: the images.
        folder: cache folder (the run goes to ``folder/<cache_key>``).
    Raises:
        DatasetError: no model could be built, or it poses fewer than ``min_registered_fraction`` of the
            images (the message names the images left out and why).
    """
    pycolmap = _pycolmap()
    pycolmap.logging.minloglevel = 0 if logger.isEnabledFor(logging.DEBUG) else 1  # COLMAP's own step-by-step log at -vv only
    work = folder / cache_key(capture, config)
    model = work / "sparse"
    if (work / DONE_FILE).is_file():
        record = json.loads((work / DONE_FILE).read_text())
        logger.info("SfM: loaded the cached reconstruction %s (%d of %d images posed)", model, len(capture) - len(record["unregistered"]), len(capture))
        return SfmResult(model, pycolmap.Reconstruction(model), record["unregistered"], 0.0, True)
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    database = work / "database.db"
    started = time.monotonic()
    pycolmap.set_random_seed(config.seed)
    _extract_and_match(pycolmap, database, capture, config)
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = config.threads
    options.random_seed = config.seed
    options.min_model_size = min(10, len(capture))
    bar = tqdm(total=len(capture), desc="SfM mapping", unit="image", disable=not progress)
    mapping_folder = work / "models"
    mapping_folder.mkdir()
    models = pycolmap.incremental_mapping(database, capture.image_root, mapping_folder, options, next_image_callback=lambda: bar.update(1))
    bar.close()
    if not models:
        reasons = _why_unregistered(pycolmap, database, capture.names)
        raise DatasetError(f"capture {capture.source}: structure from motion found no model; {_listing(reasons)}")
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    registered = {image.name for image in reconstruction.images.values() if image.has_pose}
    missing = [name for name in capture.names if name not in registered]
    reasons = _why_unregistered(pycolmap, database, missing)
    for other in models.values():
        if other is not reconstruction:
            for image in other.images.values():
                if image.has_pose and image.name in reasons:
                    reasons[image.name] = f"posed only in a separate model of {other.num_reg_images()} images that shares no views with the main one"
    seconds = time.monotonic() - started
    if len(registered) < config.min_registered_fraction * len(capture):
        raise DatasetError(f"capture {capture.source}: structure from motion posed {len(registered)} of {len(capture)} images; {_listing(reasons)}")
    if reasons:
        logger.warning("SfM: %d of %d images have no pose and are left out: %s", len(reasons), len(capture), _listing(reasons))
    model.mkdir()
    reconstruction.write(model)
    (work / DONE_FILE).write_text(json.dumps({"unregistered": reasons, "seconds": round(seconds, 1), "config": config.model_dump(mode="json")}, indent=1))
    logger.info("SfM: %d of %d images posed in %.0f s; %s", len(registered), len(capture), seconds, reconstruction.summary().replace("\n", " "))
    return SfmResult(model, reconstruction, reasons, seconds, False)


def _listing(reasons: dict[str, str], most: int = 20) -> str:
    """``name: why; ...`` for the first ``most`` images."""
    items = [f"{name}: {why}" for name, why in list(reasons.items())[:most]]
    return "; ".join(items) + (f"; ... ({len(reasons) - most} more)" if len(reasons) > most else "")
