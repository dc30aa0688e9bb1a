"""The ``locnerf`` entry point: a light ``--help``, an ``import locnerf`` without side effects, and
input errors told apart from bugs."""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys

import pytest

import locnerf_cli.certs
from locnerf.errors import LocnerfInputError
from locnerf_cli.main import main

HEAVY_PACKAGES = {"torch", "zenoh", "locnerf_services", "matplotlib"}


def run_python(code: str) -> str:
    """stdout of ``python -c code`` in a fresh interpreter."""
    return subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout


def test_help_lists_every_command_without_importing_torch_zenoh_or_the_services():
    code = (
        "import contextlib, io, json, sys\n"
        "from cli.main import COMMANDS, main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        f"heavy = sorted({{name.split('.')[0] for name in sys.modules}} & {HEAVY_PACKAGES!r})\n"
        "print(json.dumps({'heavy': heavy, 'help': out.getvalue(), 'commands': list(COMMANDS)}))\n"
    )
    result = json.loads(run_python(code))
    assert result["heavy"] == []
    assert all(name in result["help"] for name in result["commands"])


def test_importing_locnerf_leaves_the_environment_alone():
    code = "import json, os\nbefore = dict(os.environ)\nimport locnerf\nprint(json.dumps([before, dict(os.environ)]))\n"
    before, after = json.loads(run_python(code))
    assert after == before


def test_an_input_error_is_one_line_and_its_traceback_shows_at_vv(caplog, monkeypatch):
    def refuse(_: argparse.Namespace) -> int:
        raise LocnerfInputError("--days 0: expected >= 1")

    monkeypatch.setattr(locnerf_cli.certs, "run", refuse)
    assert main(["certs"]) == 2
    assert caplog.records[-1].getMessage() == "--days 0: expected >= 1" and not caplog.records[-1].exc_info
    caplog.clear()
    assert main(["-vv", "certs"]) == 2
    assert caplog.records[-1].levelno == logging.ERROR and caplog.records[-1].exc_info


def test_a_bug_keeps_its_traceback(monkeypatch):
    def broken(_: argparse.Namespace) -> int:
        raise ValueError("internal: shapes (3,) and (4,) do not broadcast")

    monkeypatch.setattr(locnerf_cli.certs, "run", broken)
    with pytest.raises(ValueError, match="do not broadcast"):
        main(["certs"])
