"""Serving states: a stored motion re-solved on the serving mesh with its multipliers.

The paper's arm with velocity limits that bind (the bounded solve, as a real arm's memory):
one motion stored as a cold plan leaves it (its refined mesh, no serving state); the
conversion (:func:`~tocontrol_ros.core.memory.serve.convert`, the ``memory upgrade`` verb)
re-solves it on the serving mesh and keeps that solution and its NLP multipliers. A hit near
it then starts from them (a distant warm start): fewer IPOPT iterations than the old start
(the stored path fitted to the mesh), the same optimum as the solution alone, certified
(and re-integrated independently), its ``T`` within 1e-3 of the cold multistart's. Also the
file format: a memory of the previous format is refused with the command that upgrades it,
and upgraded keeps every motion.
"""

from __future__ import annotations

import io
import sqlite3
from dataclasses import replace

import numpy as np
import pytest
import yaml
from limited_arm import BASE, LIMITS, MODEL, OPTIONS, SPANS, problem

from tocontrol_ros.core import Planner
from tocontrol_ros.core.checks.certificate import certify_open_loop
from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.examples import PAPER_START
from tocontrol_ros.core.memory import store as store_mod
from tocontrol_ros.core.memory.codec import decode_warm, warm_result, without_multipliers
from tocontrol_ros.core.memory.recall import (
    distances,
    open_memory,
    recall,
    remember,
    stored_problem,
)
from tocontrol_ros.core.memory.serve import convert, serve_spans
from tocontrol_ros.core.memory.store import MemoryFileError, MotionStore, upgrade_format
from tocontrol_ros.core.planning.solver import solve_once
from tocontrol_ros.core.robot.model import default_urdf_path

STORED, NEAR = [2.2, 1.5], [2.21, 1.508]


@pytest.fixture(scope="module")
def planner():
    return Planner(MODEL)


@pytest.fixture(scope="module")
def stored(planner):
    res = planner.plan(problem(STORED), OPTIONS)
    assert res.success and res.method == "direct", res.message
    assert len(res.warm_state.breaks) - 1 != SPANS, "the refined mesh is not the serving one"
    return res


def _memory(path, stored):
    store = open_memory(path, stored.problem, create=True)
    assert remember(store, stored, "test", 0.0)
    return store


def test_conversion_stores_the_serving_mesh_and_its_multipliers(tmp_path, planner, stored):
    with _memory(tmp_path / "m.sqlite", stored) as store:
        assert not store.keys()["serve"].any(), "a remembered plan has no serving state"
        out = convert(store, planner, stored.problem, OPTIONS, SPANS)
        assert (out.converted, out.failed) == (1, 0), out.messages
        entry = store.get(int(store.keys()["id"][0]))
        assert store.keys()["serve"].all()
        again = convert(store, planner, stored.problem, OPTIONS, SPANS)
    assert (again.converted, again.skipped) == (0, 1), "a converted entry is not solved again"
    state, head = decode_warm("path", entry.serve)
    assert isinstance(state, PathWarmState) and serve_spans(entry.serve) == SPANS
    np.testing.assert_allclose(state.breaks, np.linspace(0.0, 1.0, SPANS + 1), atol=1e-12)
    assert state.lam_g is not None and state.lam_x is not None
    assert np.any(state.lam_g != 0.0), "multipliers of an NLP whose limits bind"
    # The serving mesh's optimum of the stored request: at or a little above the refined one.
    assert head["T"] == state.T
    assert stored.T * (1 - 1e-6) <= state.T <= stored.T * (1 + 1e-3), (state.T, stored.T)
    # The stored motion itself is kept as it was (its refined mesh and trajectory).
    assert entry.T == stored.T and entry.warm_kind == "path"


def test_a_hit_from_the_stored_multipliers(tmp_path, planner, stored):
    near = problem(NEAR)
    with _memory(tmp_path / "m.sqlite", stored) as store:
        d = float(distances(store.keys(), near, OPTIONS.warm_joint_radius)[0])
        assert 0.0 < d <= 1.0, d
        fitted = recall(planner, near, OPTIONS, store, spans=SPANS)  # not converted yet
        convert(store, planner, stored.problem, OPTIONS, SPANS)
        found = recall(planner, near, OPTIONS, store, spans=SPANS)
        entry = store.get(int(store.keys()["id"][0]))
    assert fitted.starts == ("path fit",) and fitted.result is not None, fitted.messages
    assert found.hit and found.result is not None, found.messages
    assert found.starts == ("serve+multipliers",), found.messages
    res = found.result
    assert res.success and res.method == "direct" and res.certificate.passed
    assert res.intervals == SPANS and found.iterations == res.iterations
    # The same serving solution without its multipliers, through the same contract.
    warm = warm_result(stored_problem(near, entry.request), "path", entry.serve, entry.method)
    options = replace(OPTIONS, warm_only=True, replan_spans=SPANS)
    primal = solve_once(planner, near, options, without_multipliers(warm), None,
                        float("inf"))
    assert primal.success, primal.message
    # Fewer iterations than the old start (the stored path fitted to the mesh). Against the
    # serving solution alone (IPOPT's barrier from WARM_MU): not on this arm since a hit is
    # a distant warm start whatever its move (1.3 cm: 31 against 20), which on the Panda's
    # cell certified 72 of 72 hits of 0.5-2 cm where that start failed 10
    # (bench/memory_density.py, docs/memory.md "A denser memory").
    assert res.iterations < fitted.iterations, (res.iterations, fitted.iterations)
    assert res.T == pytest.approx(primal.T, rel=1e-6), "one NLP, one optimum"
    # Checked independently: the torques re-integrated from the start state.
    cert = certify_open_loop(near, res.trajectory, res.certificate.options)
    assert cert.passed, cert.summary()
    cold = planner.plan(near, OPTIONS)
    assert cold.success, cold.message
    assert res.T <= cold.T * (1 + 1e-3), (res.T, cold.T)
    assert found.timings["certificate"] > 0.0 and found.timings["solve"] > 0.0


def _format_1(path, stored) -> None:
    """A file as the previous format wrote it (no ``serve`` column, format 1)."""
    _memory(path, stored).close()
    _downgrade(path)


def _downgrade(path) -> None:
    db = sqlite3.connect(str(path))
    with db:
        db.execute("ALTER TABLE entries DROP COLUMN serve")
        db.execute("UPDATE meta SET value = ? WHERE key = 'format'",
                   (next(iter(store_mod.OLD_FORMATS)),))
    db.close()


def test_an_old_file_is_refused_then_upgraded(tmp_path, stored):
    path = tmp_path / "old.sqlite"
    _format_1(path, stored)
    with pytest.raises(MemoryFileError, match="memory upgrade") as err:
        open_memory(path, stored.problem)
    assert "motion memory 1" in str(err.value)
    assert upgrade_format(path) == next(iter(store_mod.OLD_FORMATS))
    assert upgrade_format(path) is None, "a current file is left alone"
    with open_memory(path, stored.problem) as store:
        assert store.count() == 1 and not store.keys()["serve"].any()
        assert store.get(int(store.keys()["id"][0])).T == stored.T
    db = sqlite3.connect(str(path))
    with db:
        db.execute("UPDATE meta SET value = 'someone else 7' WHERE key = 'format'")
    db.close()
    with pytest.raises(MemoryFileError, match="known format"):
        upgrade_format(path)
    with pytest.raises(MemoryFileError, match="no such file"):
        upgrade_format(tmp_path / "none.sqlite")


def test_the_build_stores_serving_states_and_the_upgrade_verb_converts(tmp_path, capsys):
    from tocontrol_ros.memory import cli

    limits = tmp_path / "limits.yaml"
    limits.write_text(yaml.safe_dump({"joint_limits": {
        name: {"has_velocity_limits": True, "max_velocity": float(v),
               **({"has_position_limits": True, "min_position": -2.5, "max_position": 2.5}
                  if i == 0 else {})}
        for i, (name, v) in enumerate(zip(BASE.names, LIMITS.velocity, strict=True))}}))
    cell = {"robot": {"urdf": str(default_urdf_path()), "joint_limits": str(limits)},
            "k": 4, "reserve": 0.0, "solver": {"starts": 4, "candidates": 2},
            "starts": {"stations": {"a": {"point": list(PAPER_START)}}},
            "targets": {"points": [STORED]}}
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text(yaml.safe_dump(cell))
    path = tmp_path / "cell.sqlite"

    def run(*argv):
        err = io.StringIO()
        return cli.run(cli.build_parser().parse_args([str(a) for a in argv]), err), \
            err.getvalue()

    code, err = run("build", cell_file, path, "-j", "1")
    assert code == 0 and "1 motions in" in err, err
    with MotionStore(path) as store:
        built = store.get(int(store.keys()["id"][0]))
    assert built.method == "direct" and serve_spans(built.serve) == SPANS, \
        "the build stores the serving state"
    _downgrade(path)
    code, err = run("upgrade", tmp_path / "none.sqlite", cell_file)
    assert code == 2 and "no such file" in err, err
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({**cell, "k": 2}))
    code, err = run("upgrade", path, other)
    assert code == 2 and "options" in err, err
    code, err = run("upgrade", path, cell_file, "--spans", str(SPANS))
    assert code == 0, err
    assert "upgraded" in err and "1 motions given a serving state" in err, err
    assert "0 without one" in err, err
    with MotionStore(path) as store:
        entry = store.get(int(store.keys()["id"][0]))
    assert serve_spans(entry.serve) == SPANS and entry.T == built.T
    code, _ = run("inspect", path)
    assert code == 0 and "serving states: 1 of 1 motions" in capsys.readouterr().out
    code, _ = run("inspect", path, entry.id)
    assert code == 0 and f"serving state: {SPANS} uniform spans" in capsys.readouterr().out


def _in_a_worker(model, ctx, tries):
    """What a pool worker does with a basin (``recall``'s map item): its own prepared model
    (``PreparedModel(model)``, as the pool's factory builds it) and the portable context."""
    from tocontrol_ros.core.memory.recall import _entry_item
    from tocontrol_ros.core.planning.prepared import PreparedModel

    return _entry_item(PreparedModel(model), ctx, tries)


def test_a_basin_re_solved_in_a_worker_process_is_the_one_solved_here(tmp_path, planner,
                                                                      stored):
    """The item ``recall`` hands the planner's worker processes when basins go side by side:
    pickled there (the entry's starts, the context without its system), solved by that
    process's own compiled functions, pickled back: the same re-solve to the bit."""
    import multiprocessing

    from tocontrol_ros.core.memory.recall import _entry_item, _warm_starts
    from tocontrol_ros.core.methods.context import SolveContext

    near = problem(NEAR)
    with _memory(tmp_path / "m.sqlite", stored) as store:
        convert(store, planner, stored.problem, OPTIONS, SPANS)
        entry = store.get(int(store.keys()["id"][0]))
    tries = _warm_starts(near, entry, SPANS)
    options = replace(OPTIONS, warm_only=True, replan_spans=SPANS, warm_far=True)
    ctx = SolveContext(planner.system, near, options, float("inf"))
    here = _entry_item(planner, ctx, tries)
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        there = pool.apply(_in_a_worker, (MODEL, ctx.portable(), tries))
    assert here[0] is not None and here[0].success and here[1] == ["serve+multipliers"]
    assert there[0].success and there[0].certificate.passed
    assert there[0].T == here[0].T and there[1:3] == here[1:3]
    np.testing.assert_array_equal(there[0].warm_state.P, here[0].warm_state.P)


def test_bounded_basins_go_side_by_side_with_the_answer_of_one_after_the_other(
        tmp_path, planner, stored, monkeypatch):
    """Two stored bounded motions taken as two basins (``BASIN_RADIUS`` 0 here), re-solved
    with two workers: one map of the planner's pool with both entries, and the result, the
    starts, the messages and the iterations of the re-solves one after the other; with a
    ``first`` receiver too, once the moved stored motion went to it."""
    from tocontrol_ros.core.memory import recall as recall_mod

    other = planner.plan(problem([2.21, 1.49]), OPTIONS)
    assert other.success and other.method == "direct", other.message
    monkeypatch.setattr(recall_mod, "BASIN_RADIUS", 0.0)
    near = problem(NEAR)
    options = replace(OPTIONS, time_limit=600.0)
    with _memory(tmp_path / "m.sqlite", stored) as store:
        assert remember(store, other, "test", 0.0)
        convert(store, planner, stored.problem, options, SPANS)
        alone = recall(planner, near, options, store, radius=10.0, basins=2, spans=SPANS)
        maps = []
        real = type(planner).map

        def recorded(self, fn, ctx, items):
            maps.append((fn.__name__, len(items)))
            return real(self, fn, ctx, items)
        monkeypatch.setattr(type(planner), "map", recorded)
        side = recall(planner, near, replace(options, workers=2), store, radius=10.0,
                      basins=2, spans=SPANS)
        # With a first receiver: the nearest's stored motion moved is offered before the
        # re-solves, which then go side by side all the same.
        firsts = []
        with_first = recall(planner, near, replace(options, workers=2), store, radius=10.0,
                            basins=2, spans=SPANS, first=firsts.append)

        def broken(self, fn, ctx, items):
            raise RuntimeError("worker: Exception('cannot pickle')")
        monkeypatch.setattr(type(planner), "map", broken)
        fallback = recall(planner, near, replace(options, workers=2), store, radius=10.0,
                          basins=2, spans=SPANS)
    assert "side by side failed" in fallback.messages[0] and "cannot pickle" in \
        fallback.messages[0], fallback.messages
    assert fallback.result.T == alone.result.T and fallback.starts == alone.starts
    assert maps == [("_entry_item", 2)] * 2, maps
    assert len(firsts) == 1 and firsts[0].iterations == 0 and firsts[0].certificate.passed
    assert with_first.result.T == alone.result.T and with_first.starts == alone.starts
    assert len(alone.entries) == 2 and side.entries == alone.entries
    assert side.result is not None and alone.result is not None
    assert side.result.T == alone.result.T and side.result.certificate.passed
    assert (side.starts, side.iterations) == (alone.starts, alone.iterations)
    assert [m.split(": ", 1)[0] for m in side.messages] == \
        [m.split(": ", 1)[0] for m in alone.messages]
