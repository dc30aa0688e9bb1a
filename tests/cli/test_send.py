"""``locnerf send initial-pose`` parses every spelling of a float a robot's log may print."""

from __future__ import annotations

import pytest

from locnerf.messages.schemas import InitialPoseCommand
from locnerf_cli.main import build_parser
from locnerf_cli.send import _command

POSE = ["1", "0", "0", "-1.5e-05", "0", "1", "0", "-2.", "0", "0", "1", "-.25", "0", "0", "0", "1"]


def test_negative_numbers_in_scientific_notation_are_values():
    args = build_parser().parse_args(["send", "initial-pose", "--pose", *POSE, "--sigma-position", "0.05"])
    assert args.pose == [float(x) for x in POSE]
    _, message = _command(args)
    assert isinstance(message, InitialPoseCommand)
    assert message.T_world_cam[0][3] == -1.5e-05 and message.T_world_cam[2][3] == -0.25
    assert message.covariance[3][3] == pytest.approx(0.05**2)


def test_option_names_still_end_the_pose():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["send", "initial-pose", "--pose", *POSE[:15], "--sigma-position", "0.05"])


def test_negative_covariance_is_refused_with_the_reason():
    covariance = ["0"] * 36
    covariance[0] = "-1e-3"
    args = build_parser().parse_args(["send", "initial-pose", "--pose", *POSE, "--covariance", *covariance])
    with pytest.raises(ValueError, match="positive semi-definite"):
        _command(args)
