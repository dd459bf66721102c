"""The `batch` executable on the local process pool: task files, the library, failures,
interruption and resume, and replaying one motion from the library."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import yaml

from tocontrol_ros.batch import cli as batch
from tocontrol_ros.batch.library import TOPIC_PREFIX, library_paths
from tocontrol_ros.batch.tasks import TaskFileError, load_task_file
from tocontrol_ros.core.robot.model import default_urdf_path
from tocontrol_ros.recording import cdr

REPO = Path(__file__).resolve().parents[2]
#: Fast settings: one start, no re-integration (the library's format is under test here).
FAST = {"starts": 1, "candidates": 1, "verify": False, "time_limit": 60.0}
STATIONS = {"feeder": {"point": [1.0, 1.0]}, "press": {"point": [2.2, 1.5]},
            "conveyor": {"point": [3.0, -1.0]}, "home": {"q": [0.0, 1.5, 1.5]}}


def write_tasks(path, **changes):
    doc = {"k": 4, "solver": dict(FAST), "stations": dict(STATIONS),
           "motions": [{"start": "feeder", "target": "press"}]}
    doc.update(changes)
    path.write_text(yaml.safe_dump(doc))
    return path


def journal_entries(path):
    lines = path.read_text().splitlines()
    return [json.loads(line) for line in lines[1:]]


def read_summary(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def read_library(path):
    """topic -> list of decoded JointTrajectory messages, with rosbags."""
    # Imported here: only the tests that read a library need rosbags (a failure under
    # scripts/dev, a skip elsewhere), not all of this file's.
    AnyReader = pytest.importorskip("rosbags.highlevel").AnyReader  # noqa: N806
    out = {}
    with AnyReader([Path(path)]) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def batch_command():
    exe = Path(sys.prefix) / "lib" / "tocontrol_ros" / "batch"
    if exe.is_file():
        return [str(exe)], {}
    if os.environ.get("TOCONTROL_DEV_VENV"):
        pytest.fail(f"{exe} is not installed (scripts/dev should have installed it)")
    return [sys.executable, "-m", "tocontrol_ros.batch"], {"PYTHONPATH": str(REPO)}


# ------------------------------------------------------------------ bad task files
BAD_FILES = [
    ({"motions": [{"start": {"q": [0.1, 0.2]}, "target": "press"}]},
     r"motions\[0\]\.start\.q: expected 3 numbers"),
    ({"motions": [{"start": {"point": [float("nan"), 1.0]}, "target": "press"}]},
     r"motions\[0\]\.start\.point\[0\]: must be a finite number, got nan"),
    ({"speed": 3}, r"unknown key\(s\) \['speed'\]"),
    ({"motions": [{"start": "feeder", "goal": "press"}]},
     r"motions\[0\]: unknown key\(s\) \['goal'\]"),
    ({"solver": {"stars": 3}}, r"solver: unknown key\(s\) \['stars'\]"),
    ({"solver": {"starts": 0}}, r"solver: `starts` must be an integer >= 1"),
    ({"motions": [{"start": "feeder", "target": "nowhere"}]},
     r"motions\[0\]\.target: no station named 'nowhere'"),
    ({"motions": [{"start": "feeder", "target": {"point": [9.0, 0.0]}}]},
     r"motions\[0\] \(feeder -> inline\), k = 4, reserve = 0: `target` .* not reachable"),
    ({"motions": [{"start": "feeder", "target": {"q": [0, 1, 1], "qd": [0, 0, 1]}}]},
     r"motions\[0\].*`target` joint state must be at rest"),
    ({"k": [4, 100]}, r"motions\[0\].*k = 100.*`k` must be in \[1, 64\]"),
    ({"robot": {"urdf": "missing.urdf"}}, r"robot\.urdf: no such file: .*missing\.urdf"),
    ({"robot": {"tip_link": "nope"}}, r"robot \(.*galicki_3r\.urdf\): .*nope"),
    ({"motions": [{"all_pairs": ["feeder"]}]}, r"motions\[0\]\.all_pairs: must be"),
    ({"motions": []}, r"motions: must be a non-empty list"),
    ({"hard_timeout": -1}, r"motions\[0\]\.hard_timeout: must be positive"),
]


@pytest.mark.parametrize("changes, match", BAD_FILES)
def test_bad_task_file_names_the_field(tmp_path, changes, match):
    with pytest.raises(TaskFileError, match=match):
        load_task_file(write_tasks(tmp_path / "cell.yaml", **changes))


def test_missing_task_file_is_exit_2_with_its_name(tmp_path, capsys):
    assert batch.main([str(tmp_path / "nope.yaml")]) == 2
    assert f"task file not found: {tmp_path / 'nope.yaml'}" in capsys.readouterr().err


def test_bad_task_file_is_exit_2_and_plans_nothing(tmp_path, capsys):
    path = write_tasks(tmp_path / "cell.yaml", motions=[{"start": {"q": [1.0]},
                                                         "target": "press"}])
    assert batch.main([str(path)]) == 2
    assert "motions[0].start.q: expected 3 numbers" in capsys.readouterr().err
    assert not any(p.exists() for p in library_paths(tmp_path / "cell.mcap").values())


def test_all_pairs_expand_in_order_with_k_and_urdf_relative_to_the_file(tmp_path):
    (tmp_path / "arm.urdf").write_text(default_urdf_path().read_text())
    path = write_tasks(tmp_path / "cell.yaml", robot={"urdf": "arm.urdf"}, k=[1, 4],
                       motions=[{"all_pairs": ["feeder", "press", "home"]},
                                {"start": {"point": [1.0, 1.0]}, "target": "press",
                                 "reserve": 0.1}])
    task_set, model = load_task_file(path)
    pairs = [(t.start_name, t.target_name, t.k) for t in task_set.tasks]
    assert pairs[:4] == [("feeder", "press", 1.0), ("feeder", "press", 4.0),
                         ("feeder", "home", 1.0), ("feeder", "home", 4.0)]
    assert len(task_set.tasks) == 6 * 2 + 2
    assert [t.index for t in task_set.tasks] == list(range(14))
    assert task_set.tasks[-1].reserve == 0.1 and task_set.tasks[-1].start_name == ""
    assert len({t.key for t in task_set.tasks}) == 14
    assert task_set.robot.source == str(tmp_path / "arm.urdf")
    assert model.joint_names == ("joint1", "joint2", "joint3")


# ------------------------------------------------------------------ a run, its library
@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """Three motions on one worker; the last cannot finish in 1 ms."""
    tmp = tmp_path_factory.mktemp("batch")
    path = write_tasks(tmp / "cell.yaml", motions=[
        {"start": "feeder", "target": "press"},
        {"start": "home", "target": "conveyor"},
        {"start": "press", "target": "feeder", "solver": {"time_limit": 0.001}}])
    code = batch.main([str(path), "-j", "1", "--quiet"])
    return code, path, library_paths(tmp / "cell.mcap")


def test_failing_task_is_recorded_with_its_status_and_others_go_on(small_run):
    code, _, paths = small_run
    assert code == 0
    rows = read_summary(paths["csv"])
    assert [r["status"] for r in rows] == ["SUCCESS", "SUCCESS", "TIME_LIMIT"]
    failed = rows[2]
    assert failed["success"] == "False" and failed["topic"] == "" and failed["T"] == ""
    assert "time limit" in failed["message"]
    assert [r["start_name"] + ">" + r["target_name"] for r in rows] == \
        ["feeder>press", "home>conveyor", "press>feeder"]
    library = read_library(paths["mcap"])
    assert sorted(library) == [TOPIC_PREFIX + "motion_00000", TOPIC_PREFIX + "motion_00001"]


def test_the_worker_builds_the_model_once_for_all_its_tasks(small_run):
    entries = journal_entries(small_run[2]["journal"])
    assert len(entries) == 3 and len({e["worker"] for e in entries}) == 1
    assert [e["builds"] for e in entries] == [1, 1, 1]


def test_a_task_past_its_hard_timeout_is_stopped_and_recorded(tmp_path):
    # The multistart with re-integration takes seconds; 0.5 s of hard timeout stops it.
    path = write_tasks(tmp_path / "cell.yaml", motions=[
        {"start": "feeder", "target": "press", "hard_timeout": 0.5,
         "solver": {"starts": 16, "candidates": 3, "verify": True}},
        {"start": "home", "target": "conveyor"}])
    paths = library_paths(tmp_path / "cell.mcap")
    assert batch.main([str(path), "-j", "1", "--quiet"]) == 0
    rows = read_summary(paths["csv"])
    assert [r["status"] for r in rows] == ["TIMEOUT", "SUCCESS"]
    assert "hard_timeout 0.5 s" in rows[0]["message"]
    entries = journal_entries(paths["journal"])
    assert [e["index"] for e in entries] == [0, 1] and entries[1]["attempts"] == 1
    assert sorted(read_library(paths["mcap"])) == [TOPIC_PREFIX + "motion_00001"]


def test_library_holds_one_trajectory_per_solved_motion(small_run):
    _, _, paths = small_run
    rows = read_summary(paths["csv"])
    library = read_library(paths["mcap"])
    for row in rows[:2]:
        (msg,) = library[row["topic"]]
        assert msg.joint_names == ["joint1", "joint2", "joint3"]
        last = msg.points[-1].time_from_start
        assert last.sec + last.nanosec * 1e-9 == pytest.approx(float(row["T"]), abs=1e-9)
        q0 = np.array(msg.points[0].positions)
        assert np.all(np.isfinite(q0)) and len(msg.points) > 10
        assert np.allclose(msg.points[-1].velocities, 0.0, atol=1e-6)
    # the joint-state start is where the motion starts
    (msg,) = library[rows[1]["topic"]]
    assert np.allclose(msg.points[0].positions, [0.0, 1.5, 1.5], atol=1e-9)


def test_rerun_of_a_finished_run_plans_nothing(small_run, capsys):
    _, path, paths = small_run
    before = paths["journal"].read_text()
    assert batch.main([str(path), "--quiet"]) == 0
    assert "3 done already" in capsys.readouterr().err
    assert paths["journal"].read_text() == before
    assert len(read_library(paths["mcap"])) == 2


def test_a_changed_task_file_does_not_resume_another_journal(small_run, tmp_path, capsys):
    _, path, paths = small_run
    other = write_tasks(tmp_path / "cell.yaml", k=8)
    assert batch.main([str(other), "-o", str(paths["mcap"])]) == 2
    assert "belongs to another task set" in capsys.readouterr().err


# ------------------------------------------------------------------ interruption
def _wait_for_entries(journal, count, proc, timeout=120.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if journal.exists() and len(journal_entries(journal)) >= count:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.slow
def test_interrupted_and_killed_runs_resume_with_no_task_twice_and_none_lost(tmp_path):
    path = write_tasks(tmp_path / "cell.yaml", motions=[{"all_pairs": "all"}])  # 12
    paths = library_paths(tmp_path / "cell.mcap")
    cmd, extra = batch_command()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", **extra)
    # 1) Ctrl-C after two motions: the tasks in flight finish, then exit 130
    proc = subprocess.Popen(cmd + [str(path), "-j", "2"], env=env, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert _wait_for_entries(paths["journal"], 2, proc), proc.stderr.read()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == batch.EXIT_INTERRUPTED, err
    first = len(journal_entries(paths["journal"]))
    assert 2 <= first < 12, err
    assert "run the same command again to resume" in err
    assert len(read_library(paths["mcap"])) == first  # partial library written
    # 2) SIGKILL after one more motion: nothing written but the journal
    proc = subprocess.Popen(cmd + [str(path), "-j", "2"], env=env, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert _wait_for_entries(paths["journal"], first + 1, proc), proc.stderr.read()
        workers = _children(proc.pid)
        proc.kill()
        proc.wait(timeout=30)
        assert workers and _gone(workers, timeout=10), "workers outlived the killed run"
    finally:
        proc.kill()
    second = len(journal_entries(paths["journal"]))
    assert first < second < 12
    # 3) resume to the end
    done = subprocess.run(cmd + [str(path), "-j", "2"], env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"{second} done already" in done.stderr and f"{12 - second} to plan" in done.stderr
    entries = journal_entries(paths["journal"])
    assert sorted(e["index"] for e in entries) == list(range(12))  # each once, none lost
    assert len({e["key"] for e in entries}) == 12
    library = read_library(paths["mcap"])
    assert sorted(library) == [f"{TOPIC_PREFIX}motion_{i:05d}" for i in range(12)]
    assert all(len(msgs) == 1 for msgs in library.values())
    assert [r["status"] for r in read_summary(paths["csv"])] == ["SUCCESS"] * 12


def _children(pid):
    """Pids of the processes whose parent is `pid` (Linux /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and \
                    int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry.name))
        except OSError:
            continue
    return out


def _gone(pids, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not [p for p in pids if Path(f"/proc/{p}").exists()
                and "Z" not in Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1][:3]]:
            return True
        time.sleep(0.1)
    for p in pids:  # do not leave them running after a failure
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return False


# ------------------------------------------------------------------ replay one motion
@pytest.mark.ros
def test_replay_plays_one_motion_of_the_library(small_run):
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from trajectory_msgs.msg import JointTrajectory

    from tocontrol_ros.recording import mcap_io

    _, _, paths = small_run
    topic = f"/t{uuid.uuid4().hex[:8]}/planner/trajectory"
    motion = TOPIC_PREFIX + "motion_00001"
    stored = [r.data for r in mcap_io.iter_records(paths["mcap"], topics=[motion])]
    exe = Path(sys.prefix) / "lib" / "tocontrol_ros" / "replay"
    cmd = [str(exe)] if exe.is_file() else [sys.executable, "-m", "tocontrol_ros.replay"]
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("batch_replay_check", context=ctx)
    got = []
    node.create_subscription(JointTrajectory, topic, lambda m: got.append(m),
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    proc = subprocess.Popen(cmd + [str(paths["mcap"]), "--topics", motion, "--delay", "4.0",
                                   "--ros-args", "-r", f"{motion}:={topic}"],
                            env=dict(os.environ, PYTHONPATH=str(REPO)),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not got:
            executor.spin_once(timeout_sec=0.05)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert proc.returncode == 0, out
    assert "published 1 messages" in out
    assert len(got) == 1 and len(stored) == 1, (out, topic)
    assert cdr.serialize_exact(got[0]) == stored[0]


# ------------------------------------------------------------------ journal and progress
def _three_tasks(tmp_path):
    path = write_tasks(tmp_path / "cell.yaml", motions=[{"all_pairs": ["feeder", "press"]},
                                                        {"start": "home", "target": "press"}])
    task_set, _ = load_task_file(path)
    return task_set


def _outcome(task):
    return {"status": "TIME_LIMIT", "success": False, "message": "m", "T": float("nan"),
            "pid": 7, "builds": 1, "index": task.index}


def test_journal_drops_a_torn_last_line_and_plans_that_task_again(tmp_path):
    from tocontrol_ros.batch.library import Journal

    task_set = _three_tasks(tmp_path)
    path = tmp_path / "cell.journal.jsonl"
    journal = Journal(path, task_set.fingerprint)
    for task in task_set.tasks[:2]:
        assert journal.record(task, _outcome(task), 1, None)
    journal.close()
    with open(path, "a") as f:  # a run killed in the middle of writing the third line
        f.write('{"key":"' + task_set.tasks[2].key + '","index":2,"sta')
    journal = Journal(path, task_set.fingerprint)
    assert journal.torn == 1
    assert sorted(journal.entries) == sorted(t.key for t in task_set.tasks[:2])
    assert journal.record(task_set.tasks[2], _outcome(task_set.tasks[2]), 1, None)
    journal.close()
    lines = path.read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines[1:]] == [0, 1, 2]
    assert all(e["T"] is None for e in journal_entries(path))  # NaN is not JSON


def test_journal_records_a_task_once(tmp_path):
    from tocontrol_ros.batch.library import Journal

    task_set = _three_tasks(tmp_path)
    journal = Journal(tmp_path / "j.jsonl", task_set.fingerprint)
    task = task_set.tasks[0]
    assert journal.record(task, _outcome(task), 1, None)
    assert not journal.record(task, _outcome(task), 2, None)
    journal.close()
    assert len(journal_entries(tmp_path / "j.jsonl")) == 1


def test_progress_line_counts_rate_and_eta():
    import io

    from tocontrol_ros.batch.runner import Progress

    out = io.StringIO()
    progress = Progress(total=10, done=4, stream=out, period=0.0)
    assert "ETA ?" in progress.line()
    progress.t0 -= 200.0  # started 200 s ago
    progress.update(True)
    progress.update(False)
    line = out.getvalue().splitlines()[-1]
    assert "6/10 (1 failed)" in line and "0.01 motions/s" in line and "ETA 0:06:40" in line
