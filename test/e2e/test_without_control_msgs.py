"""The planner as a pip-only user runs it: without ``control_msgs`` (issue 52).

``control_msgs`` is made unimportable in the planner process (a package of that name on
``PYTHONPATH`` whose import raises ``ImportError``, as a missing package does). Without a
controller the planner starts and answers ``~/plan``; with ``controller_action`` set it
refuses to start with a message naming the parameter and how to get the interfaces.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from node_process import command
from planner_harness import PAPER_START, PAPER_TARGET, PlannerClient, close, path_end

pytestmark = pytest.mark.ros
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0


def _blocked_site(tmp_path: Path) -> Path:
    site = tmp_path / "no_control_msgs"
    (site / "control_msgs").mkdir(parents=True)
    (site / "control_msgs" / "__init__.py").write_text(
        'raise ImportError("No module named \'control_msgs\' (blocked by the test)")\n')
    return site


def _env(site: Path) -> dict:
    cmd, env = command("planner")
    env = dict(env, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", OPENBLAS_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")])))
    env.setdefault("ROS_DOMAIN_ID", "0")
    return env


def test_the_shadow_really_blocks_control_msgs(tmp_path):
    """The check above can fail: the same interpreter and path cannot import control_msgs."""
    site = _blocked_site(tmp_path)
    out = subprocess.run([sys.executable, "-c", "import control_msgs.action"],
                         env=_env(site), capture_output=True, text=True, timeout=HANG)
    assert out.returncode != 0 and "blocked by the test" in out.stderr, out


def test_planner_plans_without_control_msgs(tmp_path):
    site = _blocked_site(tmp_path)
    cmd, _ = command("planner")
    ns = f"/nocm_{os.getpid()}"
    log_path = tmp_path / "planner.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd + ["--ros-args", "-r", f"__ns:={ns}"], env=_env(site),
                                stdout=log, stderr=subprocess.STDOUT)
    client = None
    try:
        client = PlannerClient(f"{ns}/planner")
        try:
            client.wait_ready(HANG)
        except AssertionError:
            raise AssertionError(f"planner did not come up:\n{log_path.read_text()}") from None
        path, status, _ = client.call_plan(PAPER_START, PAPER_TARGET)
        assert status.event == "solved", status.message
        assert close(path_end(path), PAPER_TARGET + (0.0,), 1e-6)
    finally:
        if client is not None:
            client.close()
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, log_path.read_text()
    assert "control_msgs" not in log_path.read_text()


def test_a_controller_without_control_msgs_is_a_clear_error(tmp_path):
    site = _blocked_site(tmp_path)
    cmd, _ = command("planner")
    out = subprocess.run(cmd + ["--ros-args", "-r", f"__ns:=/nocm_bad_{os.getpid()}", "-p",
                                "controller_action:=/arm/follow_joint_trajectory"],
                         env=_env(site), capture_output=True, text=True, timeout=HANG)
    text = out.stdout + out.stderr
    assert out.returncode != 0, text
    assert "`controller_action` needs the control_msgs interfaces" in text, text
    assert "Traceback" not in text, text
