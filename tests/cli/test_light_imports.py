"""The operator's clients, the router and the wire schemas load without torch (seconds of CPU and hundreds of MB
per process): `locnerf echo`, `locnerf send`, `locnerf run router` start at once."""

from __future__ import annotations

import subprocess
import sys

LIGHT = ("locnerf.messages.schemas", "locnerf.messages.codec", "locnerf_cli.echo", "locnerf_cli.send", "locnerf_services.router.__main__")


def test_the_clients_the_router_and_the_schemas_import_no_torch():
    probe = f"import sys\nfor name in {LIGHT!r}:\n    __import__(name)\nprint('torch' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "False", "one of them imports torch: check with python -X importtime"


def test_the_probe_sees_torch_when_it_is_imported():
    result = subprocess.run(
        [sys.executable, "-c", "import sys, locnerf.filter.localizer\nprint('torch' in sys.modules)"], capture_output=True, text=True, timeout=120
    )
    assert result.stdout.strip() == "True"
