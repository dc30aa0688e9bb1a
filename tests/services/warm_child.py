"""``python -m tests.services.warm_child CODE [polite]``: a child for the warm-start tests.

Prints its arguments, working directory, ``LOCNERF_WARM_PROBE`` and whether torch was imported before it ran; then
exits with CODE ("raise": an uncaught error), or with ``polite`` waits for SIGTERM and exits 3 when it arrives.
"""

from __future__ import annotations

import os
import signal
import sys
import time

if __name__ == "__main__":
    print(f"argv {sys.argv[1:]} cwd {os.getcwd()} probe {os.environ.get('LOCNERF_WARM_PROBE')}", flush=True)
    if sys.argv[1] == "raise":
        raise RuntimeError("an uncaught error in the child")
    if sys.argv[2:] == ["polite"]:
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))
        print("ready", flush=True)
        time.sleep(60)
    print("to stderr", file=sys.stderr, flush=True)
    sys.exit(int(sys.argv[1]))
