"""The ``locnerf`` entry point: a light ``--help`` and an ``import locnerf`` without side effects."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY_PACKAGES = {"torch", "zenoh", "services", "matplotlib"}


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
