"""Configuration models filled from command-line flags, with validation errors that name the flag."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, TypeVar

from pydantic import BaseModel, ValidationError

from locnerf.errors import LocnerfInputError

if TYPE_CHECKING:
    from locnerf.filter.localizer_config import LocalizerConfig

Model = TypeVar("Model", bound=BaseModel)


def flag_of(field: str) -> str:
    """The flag that sets ``field`` by default: ``camera_rate`` -> ``--camera-rate``."""
    return "--" + field.replace("_", "-")


def from_flags(model: type[Model], values: Mapping[str, Any], flags: Mapping[str, str] | None = None) -> Model:
    """``model`` validated from ``values`` (field -> value), most of them given on the command line.

    ``flags`` names the flag of a field where it is not :func:`flag_of` the field's name
    (``{"translation_drift": "--drift"}``).

    Raises:
        LocnerfInputError: a value the model refuses, naming its flag, e.g.
            ``--particles: must be greater than or equal to 1, got 0``.
    """
    try:
        return model.model_validate(dict(values))
    except ValidationError as error:
        problems = []
        for problem in error.errors():
            field = str(problem["loc"][0]) if problem["loc"] else ""
            flag = (flags or {}).get(field, flag_of(field))
            reason = problem["msg"].removeprefix("Value error, ").replace("Input should be", "must be", 1)
            problems.append(f"{flag}: {reason}, got {problem['input']!r}")
        raise LocnerfInputError("; ".join(problems)) from error


NO_DEPTH_HELP = "colour only: ignore the data set's depth images even when the configuration sets [measurement.depth]"


def without_depth(config: LocalizerConfig, no_depth: bool) -> LocalizerConfig:
    """``config`` without its depth term when ``no_depth`` (the ``--no-depth`` flag), else unchanged."""
    if not no_depth or config.measurement.depth is None:
        return config
    return config.model_copy(update={"measurement": config.measurement.model_copy(update={"depth": None})})


POSES_HELP = (
    "7-Scenes ground truth: dslam (the data set's frame-NNNNNN.pose.txt, KinectFusion) or sfm (the SfM pseudo ground truth in pgt_sfm/, "
    "Brachmann et al. 2021); a map is scored against the poses it was built from"
)


def add_poses_argument(parser: Any) -> None:
    """``--poses dslam|sfm`` (checked by :func:`locnerf.data.sfm_poses.check_pose_source`, which names the choices)."""
    parser.add_argument("--poses", default="dslam", help=POSES_HELP)
