"""``ros2 action send_goal --feedback`` on the planner's ``~/plan_motion``, across processes.

The ``ros2`` command line is not installable here (no ros2cli wheel), so :func:`send_goal`
does what ``ros2 action send_goal --feedback ACTION TYPE YAML`` does (ros2action's
``send_goal``): the type resolved from its name, the goal's fields set from the YAML text
(``rosidl_runtime_py.set_message_fields``' rules: nested mappings, lists), the goal sent with a
feedback callback that prints each feedback, then the result printed. The planner is the
installed executable in a process of its own, its solve held at a file gate
(test/solve_gate.py) until the client has printed feedback.
"""

import importlib
import os
import threading

import numpy as np
import pytest
import yaml
from planner_harness import PAPER_TARGET, PlannerClient
from test_planner_process import PlannerProcess, _wait_warm

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.action_calls import SerialActionClient

pytestmark = pytest.mark.ros
pytest.importorskip("tocontrol_msgs.action")
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 120.0


def action_type(name: str):
    """``pkg/action/Name`` -> the class, as ``rosidl_runtime_py.utilities.get_action``."""
    package, kind, cls = name.split("/")
    assert kind == "action", name
    return getattr(importlib.import_module(f"{package}.action"), cls)


def set_fields(msg, values: dict) -> None:
    """The YAML goal's fields into ``msg`` (``rosidl_runtime_py.set_message_fields``)."""
    for field, value in values.items():
        current = getattr(msg, field)
        if isinstance(value, dict):
            set_fields(current, value)
        elif isinstance(value, list):
            setattr(msg, field, value)
        else:
            setattr(msg, field, type(current)(value))


class Cli:
    """``ros2 action send_goal --feedback``: its printed lines in :attr:`lines`."""

    def __init__(self, client: PlannerClient):
        self.client = client
        self.lines: list[str] = []
        self._lock = threading.Lock()

    def print(self, text: str) -> None:
        with self._lock:
            self.lines.append(text)

    def printed(self) -> list[str]:
        with self._lock:
            return list(self.lines)

    def send_goal(self, action: str, type_name: str, goal_yaml: str, on_accepted=None):
        kind = action_type(type_name)
        goal = kind.Goal()
        set_fields(goal, yaml.safe_load(goal_yaml))
        # The requests on the executor, as the CLI's own spin does (rclpy's race avoided).
        client = SerialActionClient(self.client.node, kind, action)
        assert client.wait_for_server(HANG), f"no action server {action}"
        self.print("Sending goal:")
        future = client.send_goal(
            goal, feedback_callback=lambda f: self.print(f"Feedback:\n    {f.feedback}"))
        self.client.wait_for(future.done, HANG, "the goal's acceptance")
        handle = future.result()
        self.print("Goal accepted" if handle.accepted else "Goal was rejected.")
        if on_accepted is not None:
            on_accepted()
        result = client.get_result(handle)
        self.client.wait_for(result.done, HANG, "the result")
        response = result.result()
        self.print(f"Result:\n    {response.result}")
        self.print(f"Goal finished with status: {response.status}")
        return response


@pytest.fixture(scope="module")
def process(tmp_path_factory):
    proc = PlannerProcess(tmp_path_factory.mktemp("cli"), f"/cli_{os.getpid()}")
    yield proc
    code, _ = proc.stop()
    assert code == 0, proc.log()


@pytest.fixture(scope="module")
def client(process):
    c = PlannerClient(process.name)
    _wait_warm(c, process)
    yield c
    c.close()


def test_send_goal_with_feedback_prints_feedback_and_the_trajectory(process, client):
    model = load_robot(default_urdf_path())
    cli = Cli(client)
    goal = f"""
start_type: 1
start_state: {{name: [joint1, joint2, joint3], position: [0.3, 1.0, -0.5]}}
target_type: 0
target_point: {{header: {{frame_id: base_link}}, point: {{x: {PAPER_TARGET[0]},
                                                          y: {PAPER_TARGET[1]}}}}}
"""
    process.gate.arm()

    def feedback_then_open():
        client.wait_for(process.gate.held, HANG, "the solve held at the gate")
        client.wait_for(lambda: any(line.startswith("Feedback:") for line in cli.printed()),
                        HANG, "printed feedback")
        process.gate.open()

    response = cli.send_goal(f"{process.name}/plan_motion", "tocontrol_msgs/action/PlanMotion",
                             goal, on_accepted=feedback_then_open)
    process.gate.disarm()
    printed = "\n".join(cli.printed())
    assert "Goal accepted" in printed and "stage='planning'" in printed, printed
    assert "Goal finished with status: 4" in printed, printed  # SUCCEEDED
    result = response.result
    assert result.code == 0 and result.certified, result.message
    end = np.array(result.trajectory.points[-1].positions)
    np.testing.assert_allclose(model.point(end), PAPER_TARGET, atol=1e-6)
    np.testing.assert_allclose(result.trajectory.points[0].positions, [0.3, 1.0, -0.5],
                               atol=1e-9)
    assert all(len(p.effort) == model.n for p in result.trajectory.points)


def test_send_goal_joint_target(process, client):
    cli = Cli(client)
    response = cli.send_goal(
        f"{process.name}/plan_motion", "tocontrol_msgs/action/PlanMotion",
        "{start_type: 1, start_state: {name: [joint1, joint2, joint3], position: [0.3, 1.0, "
        "-0.5]}, target_type: 2, target_joints: {name: [joint3, joint1, joint2], position: "
        "[0.7, 1.2, -0.4]}}")
    assert response.status == 4 and response.result.code == 0, response.result.message
    np.testing.assert_allclose(response.result.trajectory.points[-1].positions,
                               [1.2, -0.4, 0.7], atol=1e-6)
