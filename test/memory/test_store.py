"""The memory file: round trip, refusals with a reason, corrupt and locked files, two writers.

The paper's arm (config/galicki_3r.urdf) planned for real, once per module: the stored warm
state and trajectory must come back bit for bit, and a memory made for another robot or
other options must be refused with a message that says which.
"""

from __future__ import annotations

import multiprocessing
import sqlite3
from dataclasses import replace

import numpy as np
import pytest

from tocontrol_ros.core import Planner, Problem, SolverOptions, load_robot, point
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.memory import recall as recall_mod
from tocontrol_ros.core.memory import store as store_mod
from tocontrol_ros.core.memory.codec import CodecError, decode_sample, decode_warm, encode_warm
from tocontrol_ros.core.memory.keys import options_hash, robot_hash
from tocontrol_ros.core.memory.recall import open_memory, remember, stored_problem
from tocontrol_ros.core.memory.store import MemoryFileError, MotionStore, Request
from tocontrol_ros.core.robot.model import default_urdf_path

MODEL = load_robot(default_urdf_path())
TARGETS = ([2.2, 1.5], [2.0, 1.8], [1.6, 2.2])


@pytest.fixture(scope="module")
def results():
    planner = Planner(MODEL)
    out = []
    for target in TARGETS:
        res = planner.plan(Problem(MODEL, point(PAPER_START), point(target), k=4),
                           SolverOptions(starts=4, candidates=2))
        assert res.success, res.message
        out.append(res)
    return out


def test_a_motion_comes_back_as_it_was_stored(tmp_path, results):
    res = results[0]
    path = tmp_path / "m.sqlite"
    with open_memory(path, res.problem, create=True) as store:
        assert remember(store, res, "test", 0.5)
        assert not remember(store, res, "test", 0.5), "the same request stored twice"
    with open_memory(path, res.problem) as store:
        assert store.count() == 1
        entry = store.get(int(store.keys()["id"][0]))
    assert entry.T == res.T and entry.method == res.method and entry.source == "test"
    assert entry.certificate["passed"] is True
    np.testing.assert_array_equal(entry.request.target, res.problem.target.value)
    sample = decode_sample(entry.trajectory)
    ref = res.trajectory.sample(recall_mod.SAMPLE_PERIOD)
    for name in ("t", "q", "qd", "qdd", "tau"):
        np.testing.assert_array_equal(sample[name], getattr(ref, name))
    state, head = decode_warm(entry.warm_kind, entry.warm)
    assert head["T"] == res.T and head["k"] == res.k
    kind, blob = encode_warm(res)
    assert kind == entry.warm_kind
    for name in ("lengths", "w", "kinds"):
        np.testing.assert_array_equal(getattr(state, name), getattr(res.warm_state, name))
    assert [tuple(b) for b in state.breaks] == [tuple(b) for b in res.warm_state.breaks]
    # The stored request rebuilt on the caller's model is the problem solved.
    again = stored_problem(res.problem, entry.request)
    np.testing.assert_array_equal(again.target_point, res.problem.target_point)


def test_the_lower_t_of_one_request_is_kept(tmp_path, results):
    res = results[0]
    path = tmp_path / "m.sqlite"
    with open_memory(path, res.problem, create=True) as store:
        assert remember(store, replace(res, T=res.T * 1.1), "slow", 1.0)
        assert remember(store, res, "fast", 1.0), "a lower T replaces the stored one"
        assert not remember(store, replace(res, T=res.T * 1.2), "slower", 1.0)
        (row,) = store.summary()
    assert row["T"] == res.T and row["source"] == "fast"


def test_a_memory_of_another_robot_or_other_options_is_refused(tmp_path, results):
    res = results[0]
    path = tmp_path / "m.sqlite"
    with open_memory(path, res.problem, create=True) as store:
        remember(store, res, "test", 0.5)
    other = load_robot(default_urdf_path(), gravity=(0.0, -9.81, 0.0))
    assert robot_hash(other) != robot_hash(MODEL)
    with pytest.raises(MemoryFileError, match="made for another robot: its robot_hash"):
        open_memory(path, Problem(other, point(PAPER_START), point(TARGETS[0]), k=4))
    with pytest.raises(MemoryFileError, match=r"another options \(k, reserve"):
        open_memory(path, Problem(MODEL, point(PAPER_START), point(TARGETS[0]), k=8))
    with pytest.raises(MemoryFileError, match="another options"):
        open_memory(path, Problem(MODEL, point(PAPER_START), point(TARGETS[0]), k=4,
                                  reserve=0.2))
    # The same arm loaded again (from the XML text this time) is the same robot.
    again = load_robot(default_urdf_path().read_text())
    assert robot_hash(again) == robot_hash(MODEL)
    assert options_hash(Problem(again, point(PAPER_START), point(TARGETS[1]), k=4)) == \
        options_hash(res.problem)


@pytest.mark.parametrize("content, match", [
    (None, "no such file"),
    (b"this is not a database at all" * 100, "corrupt or not a database"),
    (b"", "not a motion memory"),
])
def test_missing_corrupt_and_foreign_files_say_why(tmp_path, results, content, match):
    path = tmp_path / "m.sqlite"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(MemoryFileError, match=match):
        open_memory(path, results[0].problem)


def test_a_truncated_memory_is_an_error_not_a_crash(tmp_path, results):
    path = tmp_path / "m.sqlite"
    with open_memory(path, results[0].problem, create=True) as store:
        for res in results:
            remember(store, res, "test", 0.5)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 3] + b"\0" * 100)
    with pytest.raises(MemoryFileError, match=f"memory {path}"):
        with open_memory(path, results[0].problem) as store:
            for i in store.keys()["id"]:
                store.get(int(i))


def test_a_corrupt_blob_is_a_codec_error_naming_the_entry():
    with pytest.raises(CodecError, match="entry 7: not a readable npz blob"):
        decode_warm("path", b"garbage", "entry 7")
    with pytest.raises(CodecError, match="unknown warm-state kind 'spline'"):
        decode_warm("spline", encode_warm_blob(), "entry 7")


def encode_warm_blob() -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, T=np.float64(1.0), k=np.float64(4.0), delta=np.float64(0.0))
    return buf.getvalue()


def test_a_locked_memory_is_an_error_after_the_busy_timeout(tmp_path, results, monkeypatch):
    path = tmp_path / "m.sqlite"
    with open_memory(path, results[0].problem, create=True):
        pass
    monkeypatch.setattr(store_mod, "BUSY_TIMEOUT", 0.2)
    holder = sqlite3.connect(str(path), isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        with pytest.raises(MemoryFileError, match="locked by another process"):
            with open_memory(path, results[0].problem) as store:
                remember(store, results[0], "test", 0.5)
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    with open_memory(path, results[0].problem) as store:  # usable once released
        assert remember(store, results[0], "test", 0.5)


def _writer(path: str, hashes: tuple, offset: int, count: int) -> None:
    store = MotionStore(path, *hashes)
    for i in range(count):
        x = float(offset + i)
        store.add(Request("point", np.array([x, 0.0]), "point", np.array([x, 1.0])),
                  start_point=[x, 0.0], target_point=[x, 1.0], end_q=[x, x, x], T=1.0 + x,
                  status="SUCCESS", method="indirect", certificate={"passed": True},
                  warm_kind="shooting", warm=b"w" * 1000, trajectory=b"t" * 5000,
                  source=f"writer{offset}", solve_time=0.0)
    store.close()


def test_two_writers_lose_nothing(tmp_path, results):
    path = tmp_path / "m.sqlite"
    problem = results[0].problem
    with open_memory(path, problem, create=True):
        pass
    hashes = (robot_hash(MODEL), options_hash(problem))
    ctx = multiprocessing.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(str(path), hashes, offset, 60))
             for offset in (0, 1000)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    with MotionStore(path, *hashes) as store:
        rows = store.summary()
    assert len(rows) == 120
    assert sorted(r["source"] for r in rows) == ["writer0"] * 60 + ["writer1000"] * 60


def test_the_keys_are_read_again_after_any_connections_write(tmp_path, results):
    """Kept between lookups, re-read after this store's writes and another connection's."""
    path = tmp_path / "m.sqlite"
    with open_memory(path, results[0].problem, create=True) as store, \
            open_memory(path, results[0].problem) as other:
        assert len(store.keys()["id"]) == 0
        assert remember(store, results[0], "test", 0.5)
        first = store.keys()
        assert len(first["id"]) == 1 and not first["serve"][0]
        assert store.keys() is first  # unchanged file: the same arrays
        assert remember(other, results[1], "test", 0.5)  # another connection's commit
        assert sorted(store.keys()["T"]) == sorted([results[0].T, results[1].T])
        assert store.set_serve(int(first["id"][0]), encode_warm_blob())
        assert store.keys()["serve"].tolist() == [True, False]
        assert len(other.keys()["id"]) == 2 and other.keys()["serve"].tolist() == [True, False]
        assert store.delete([int(first["id"][0])]) == 1
        assert len(other.keys()["id"]) == 1 and len(store.keys()["id"]) == 1
