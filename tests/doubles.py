"""Plumbing shared by the test doubles that stand in for the coupled model in sweep and optimizer tests.

Call logs: a double appends one line per evaluation to the file named by an environment variable, so a test
can count what was computed (and recomputed after a resume), and can simulate Ctrl-C once the log holds a given
number of lines.
Environment variables, not arguments, because the sweep calls the double in worker processes and through the CLI.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).parent


def logged_calls(path) -> list[str]:
    """The lines logged so far at ``path`` (none if it does not exist)."""
    path = Path(path)
    return path.read_text().splitlines() if path.exists() else []


def record_call(line: str, log_env: str, stop_env: str | None = None) -> None:
    """Append ``line`` to the log ``$log_env`` names (if set); first raise KeyboardInterrupt if ``$stop_env``
    names a count the log has reached."""
    log = os.environ.get(log_env)
    if not log:
        return
    stop = int(os.environ.get(stop_env, "0")) if stop_env else 0
    if stop and len(logged_calls(log)) >= stop:
        raise KeyboardInterrupt("test double: interrupted")
    with open(log, "a") as fh:
        fh.write(line + "\n")


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python -m latticeopt ARGS`` in a subprocess that can import the test modules (``--evaluate
    test_module:double``); output captured as text."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "latticeopt", *args], env=env, capture_output=True, text=True,
                          timeout=timeout)
