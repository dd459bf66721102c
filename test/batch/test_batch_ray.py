"""`batch --ray local`: a private Ray cluster on loopback plans motions of the paper's arm.

A fast one (a few motions, in the default run: users run batch on Ray) and a slow one (20
motions, a worker killed mid-run, every motion still in the library exactly once). Both
check that Ray's processes listen on loopback only (read from /proc, no tool needed)."""

import importlib.util
import ipaddress
import json
import os
import signal
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
pytestmark = [pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                                 reason="missing: ray (pip install '.[test]')")]
RAY_PROCESSES = ("gcs_server", "raylet", "ray::")


def _entries(path):
    if not path.exists():
        return []
    lines = path.read_text().split("\n")[1:-1]  # header; a line being written is not whole
    return [json.loads(line) for line in lines]


def _address(hex_address: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    """The host of a /proc/net/tcp{,6} local address ("0100007F:1F90": 127.0.0.1)."""
    host = bytes.fromhex(hex_address.split(":")[0])
    # Each 32-bit word is in the machine's (little-endian) order.
    host = b"".join(host[i:i + 4][::-1] for i in range(0, len(host), 4))
    return ipaddress.ip_address(host)


def ray_listening() -> list[tuple[str, str]]:
    """``(host, process)`` of each TCP socket a Ray process of this user listens on."""
    listening = {}
    for table in ("tcp", "tcp6"):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A":  # TCP_LISTEN
                listening[fields[9]] = _address(fields[1])
    found = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            name = os.path.basename((proc / "cmdline").read_bytes().split(b"\0")[0].decode())
            fds = list((proc / "fd").iterdir())
        except OSError:  # gone, or another user's
            continue
        if not any(ray_name in name for ray_name in RAY_PROCESSES):
            continue
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:[") and target[8:-1] in listening:
                found.append((str(listening[target[8:-1]]), name))
    return found


def _loopback(host: str) -> bool:
    address = ipaddress.ip_address(host)
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


class JournalWatcher(threading.Thread):
    """Once ``after`` motions are journaled, records the Ray processes' listening sockets and,
    with ``kill``, SIGKILLs the worker that planned the last one (it is then planning its
    next task: two are queued per CPU)."""

    def __init__(self, journal, after, kill=False, timeout=240.0):
        super().__init__(daemon=True)
        self.journal, self.after, self.kill, self.timeout = journal, after, kill, timeout
        self.killed = None
        self.listening = None
        self.stop = threading.Event()

    def run(self):
        deadline = time.monotonic() + self.timeout
        while not self.stop.is_set() and time.monotonic() < deadline:
            entries = _entries(self.journal)
            if len(entries) >= self.after:
                self.listening = ray_listening()
                if self.kill:
                    self.killed = int(entries[-1]["worker"])
                    os.kill(self.killed, signal.SIGKILL)
                return
            time.sleep(0.02)


def _cell(tmp_path, stations=None):
    doc = yaml.safe_load((REPO / "config" / "cell_example.yaml").read_text())
    doc["solver"].update(starts=4, candidates=2, time_limit=60.0)  # bounded, still multistart
    if stations is not None:
        doc["stations"] = {name: doc["stations"][name] for name in stations}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _assert_loopback_only(listening):
    assert listening, "no Ray process was seen listening (read too early?)"
    for host, name in listening:
        assert _loopback(host), (host, name)


def test_the_proc_reading_decodes_a_listening_socket():
    import socket

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        found = [_address(line.split()[1]) for line in
                 Path("/proc/net/tcp").read_text().splitlines()[1:]
                 if line.split()[3] == "0A" and int(line.split()[1].split(":")[1], 16) == port]
    assert found == [ipaddress.ip_address("127.0.0.1")]
    assert _loopback("127.0.0.1") and _loopback("::ffff:127.0.0.1") and _loopback("::1")
    assert not _loopback("0.0.0.0") and not _loopback("192.168.1.2")


def test_ray_local_plans_a_few_motions_on_loopback(tmp_path, capsys):
    # Users run batch on Ray: a private cluster of 2 CPUs, 2 motions (feeder <-> press).
    path = _cell(tmp_path, stations=("feeder", "press"))
    paths = library_paths(tmp_path / "cell.mcap")
    watcher = JournalWatcher(paths["journal"], after=1)
    watcher.start()
    try:
        code = batch.main([str(path), "--ray", "local", "-j", "2"])
    finally:
        watcher.stop.set()
        watcher.join()
    err = capsys.readouterr().err
    assert code == 0, err
    entries = _entries(paths["journal"])
    assert sorted(e["index"] for e in entries) == [0, 1], err
    assert all(e["status"] == "SUCCESS" for e in entries), [e["message"] for e in entries]
    assert all(e["worker"] != str(os.getpid()) for e in entries)  # planned by Ray workers
    with AnyReader([paths["mcap"]]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {f"{TOPIC_PREFIX}motion_{i:05d}": 1 for i in range(2)}
    _assert_loopback_only(watcher.listening)


@pytest.mark.slow
def test_ray_plans_20_motions_exactly_once_with_a_worker_killed(tmp_path, capsys):
    path = _cell(tmp_path)
    paths = library_paths(tmp_path / "cell.mcap")
    killer = JournalWatcher(paths["journal"], after=3, kill=True)
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
    # Ray's own sockets listened on loopback only.
    _assert_loopback_only(killer.listening)
