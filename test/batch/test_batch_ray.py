"""`batch --ray local`: a private Ray cluster on loopback plans 20 motions of the paper's arm;
one worker is killed mid-run and every motion still lands in the library exactly once."""

import importlib.util
import json
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
import yaml

from tocontrol_ros.batch import cli as batch
from tocontrol_ros.batch.library import TOPIC_PREFIX, library_paths

AnyReader = pytest.importorskip("rosbags.highlevel").AnyReader
REPO = Path(__file__).resolve().parents[2]
# Not `importorskip("ray")`: --ray local must be the first to import ray (batch/ray_backend.py).
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                                 reason="missing: ray (pip install '.[test]')")]
RAY_PROCESSES = ("gcs_server", "raylet", "ray::")


def _entries(path):
    if not path.exists():
        return []
    lines = path.read_text().split("\n")[1:-1]  # header; a line being written is not whole
    return [json.loads(line) for line in lines]


class WorkerKiller(threading.Thread):
    """Once `after` motions are journaled, SIGKILLs the worker that planned the last one (it
    is then planning its next task: two are queued per CPU), and records the Ray processes'
    listening sockets."""

    def __init__(self, journal, after, timeout=240.0):
        super().__init__(daemon=True)
        self.journal, self.after, self.timeout = journal, after, timeout
        self.killed = None
        self.listening = ""
        self.stop = threading.Event()

    def run(self):
        deadline = time.monotonic() + self.timeout
        while not self.stop.is_set() and time.monotonic() < deadline:
            entries = _entries(self.journal)
            if len(entries) >= self.after:
                if shutil.which("ss"):
                    self.listening = subprocess.run(["ss", "-ltnpH"], capture_output=True,
                                                    text=True).stdout
                self.killed = int(entries[-1]["worker"])
                os.kill(self.killed, signal.SIGKILL)
                return
            time.sleep(0.02)


def test_ray_plans_20_motions_exactly_once_with_a_worker_killed(tmp_path, capsys):
    doc = yaml.safe_load((REPO / "config" / "cell_example.yaml").read_text())
    doc["solver"].update(starts=4, candidates=2, time_limit=60.0)  # bounded, still multistart
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(doc))
    paths = library_paths(tmp_path / "cell.mcap")
    killer = WorkerKiller(paths["journal"], after=3)
    killer.start()
    try:
        code = batch.main([str(path), "--ray", "local", "-j", "2"])
    finally:
        killer.stop.set()
        killer.join()
    err = capsys.readouterr().err
    assert code == 0, err
    assert killer.killed is not None, "no worker was killed"
    entries = _entries(paths["journal"])
    assert sorted(e["index"] for e in entries) == list(range(20)), err  # each once, none lost
    assert all(e["status"] == "SUCCESS" for e in entries), [e["message"] for e in entries]
    assert all(e["builds"] == 1 for e in entries)  # one model per worker process
    workers = {int(e["worker"]) for e in entries}
    assert killer.killed in workers and len(workers) >= 3  # a worker replaced the killed one
    retried = [e for e in entries if e["attempts"] > 1]
    assert len(retried) == 1 and retried[0]["worker"] != str(killer.killed), \
        "the killed worker's task in flight was planned again elsewhere"
    with AnyReader([paths["mcap"]]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {f"{TOPIC_PREFIX}motion_{i:05d}": 1 for i in range(20)}
    # Ray's own sockets (names as ss shows them) listened on loopback only
    ray_lines = [line for line in killer.listening.splitlines()
                 if any(name in line for name in RAY_PROCESSES)]
    if shutil.which("ss"):
        assert ray_lines, killer.listening
        for line in ray_lines:
            local = line.split()[3]
            assert local.startswith(("127.0.0.1:", "[::ffff:127.0.0.1]:")), line
