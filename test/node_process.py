"""The project's executables as a user starts them: ``<prefix>/lib/tocontrol_ros/<name>`` (what
``ros2 run tocontrol_ros <name>`` runs) when installed, else ``python -m`` from the source tree.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def command(name: str = "demo") -> tuple[list[str], dict]:
    """The command line and environment that start executable ``name``."""
    installed = Path(sys.prefix) / "lib" / "tocontrol_ros" / name
    if installed.is_file():
        return [str(installed)], dict(os.environ, PYTHONUNBUFFERED="1")
    if os.environ.get("TOCONTROL_DEV_VENV"):
        pytest.fail(f"not installed: {installed}")
    return [sys.executable, "-m", f"tocontrol_ros.{name}"], dict(
        os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")


class NodeProcess:
    """Executable ``name`` with ``args`` in a subprocess, its output in ``log_dir/<name>.log``;
    ``env``: variables set on top of the executable's environment."""

    def __init__(self, name: str, args: list[str], log_dir: Path,
                 env: dict | None = None) -> None:
        cmd, base = command(name)
        env = {**base, **(env or {})}
        self.log = log_dir / f"{name}.log"
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen(cmd + args, env=env, stdout=log,
                                         stderr=subprocess.STDOUT)

    def stop(self) -> int:
        """SIGINT (then SIGKILL after 20 s); the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode
