"""Call logs of the test doubles that stand in for the coupled model in sweep and optimizer tests.

A double appends one line per evaluation to the file named by an environment variable, so a test can count what
was computed (and recomputed after a resume), and can simulate Ctrl-C once the log holds a given number of lines.
Environment variables, not arguments, because the sweep calls the double in worker processes and through the CLI.
"""

from __future__ import annotations

import os
from pathlib import Path


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
