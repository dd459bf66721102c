"""The compile cache's two tiers (quick build now, optimised build in the background), its
progress reports, and the planner that loads the optimised libraries once they landed.

Every test uses a private, empty cache (``TOCONTROL_CACHE`` in ``tmp_path``) and small
functions with ``QUICK_SOURCE`` lowered, so that real compiles stay short.
"""

from __future__ import annotations

import shutil
import threading

import casadi as ca
import numpy as np
import pytest

from tocontrol_ros.core.robot import compiled

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                                reason="no C compiler")


#: How long a test waits for its background builds (an event bound, not a timing). Builds
#: are counted, queued and waited for per cache directory, so the earlier tests' builds into
#: the default cache (with an empty one: the Panda's, minutes at low priority on a loaded
#: machine) neither hold a test's private cache nor its slot.
BUILDS_WAIT = 1200.0


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TOCONTROL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("TOCONTROL_COMPILE", "1")
    monkeypatch.delenv("TOCONTROL_COMPILE_TIERS", raising=False)
    assert compiled.wait_for_builds(BUILDS_WAIT), "builds into the new private cache"
    yield tmp_path / "cache"
    assert compiled.wait_for_builds(BUILDS_WAIT)


def _function(name: str) -> ca.Function:
    x = ca.SX.sym("x", 3)
    y = ca.vertcat(ca.sin(x[0]) * x[1] ** 3, ca.exp(-x[2] ** 2) + x[0] * x[1])
    return ca.Function(name, [x], [y, ca.jacobian(y, x)])


def _libraries(cache, name):
    return sorted(p.name for p in cache.glob(f"{name}_*.so"))


def test_long_source_gets_a_quick_build_then_the_optimised_one(private_cache, monkeypatch):
    monkeypatch.setattr(compiled, "QUICK_SOURCE", 0)
    events = []
    listener = lambda event, name, info: events.append((event, name, info))  # noqa: E731
    compiled.add_listener(listener)
    try:
        fun = _function("tiers_probe")
        before = compiled.generation()
        quick, how = compiled.compile_function(fun)
        assert how == "compiled (quick build)", how
        assert compiled.wait_for_builds(BUILDS_WAIT)
        assert compiled.generation() == before + 1
        optimised, how2 = compiled.compile_function(fun)
        assert how2 == "cached", how2
    finally:
        compiled.remove_listener(listener)
    # Two libraries in the cache (the quick and the optimised build), same numbers as the
    # virtual machine.
    assert len(_libraries(private_cache, "tiers_probe")) == 2
    x = np.array([0.3, -1.2, 0.7])
    for f in (quick, optimised):
        for got, want in zip(f(x), fun(x), strict=True):
            np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-14)
    kinds = [(e, info["flags"].split()[0]) for e, name, info in events if name == "tiers_probe"]
    assert ("compiling", "-O0") in kinds and ("compiled", "-O0") in kinds, kinds
    assert ("optimising", compiled.CFLAGS[0]) in kinds, kinds
    assert ("optimised", compiled.CFLAGS[0]) in kinds, kinds
    done = [info for e, name, info in events if e == "compiled" and name == "tiers_probe"]
    assert done[0]["ok"] and done[0]["seconds"] > 0 and done[0]["bytes"] > 0


def test_short_source_and_tiers_off_build_optimised_at_once(private_cache, monkeypatch):
    fun = _function("short_probe")
    assert compiled.compile_function(fun)[1] == "compiled"  # far below QUICK_SOURCE
    assert compiled.pending_builds() == 0
    monkeypatch.setattr(compiled, "QUICK_SOURCE", 0)
    monkeypatch.setenv("TOCONTROL_COMPILE_TIERS", "0")
    other = _function("untiered_probe")
    assert compiled.compile_function(other)[1] == "compiled"
    assert compiled.pending_builds() == 0
    assert len(_libraries(private_cache, "untiered_probe")) == 1


def test_a_failing_listener_does_not_fail_the_build(private_cache):
    def broken(event, name, info):
        raise RuntimeError("listener bug")

    compiled.add_listener(broken)
    try:
        assert compiled.compile_function(_function("listener_probe"))[1] == "compiled"
    finally:
        compiled.remove_listener(broken)
    compiled.remove_listener(broken)  # twice: no error


def test_plan_loads_the_optimised_libraries_once_they_landed(private_cache, monkeypatch):
    from tocontrol_ros.core.planning import prepared, solver

    class Model:  # Planner only needs a model for CanonicalSystem; not built here
        pass

    monkeypatch.setattr(prepared, "CanonicalSystem", lambda model: None)
    planner = solver.Planner(Model())
    assert not planner.stale()
    monkeypatch.setattr(compiled, "QUICK_SOURCE", 0)
    compiled.compile_function(_function("stale_probe"))
    assert compiled.wait_for_builds(BUILDS_WAIT)
    assert planner.stale()
    assert not solver.Planner(Model()).stale()


def test_parallel_builds_defer_then_the_next_pass_finds_the_cache(private_cache):
    funs = [_function(f"parallel_probe{i}") for i in range(3)]
    events = []
    listener = lambda event, name, info: events.append((event, name))  # noqa: E731
    compiled.add_listener(listener)
    try:
        with compiled.parallel_builds(jobs=2):
            deferred = [compiled.compile_function(f) for f in funs[:2]]
            many = compiled.compile_functions("parallel_lib", funs[2:])
        assert [how for _, how in deferred] == ["deferred", "deferred"]
        assert many[1] == "deferred" and many[0] == funs[2:]
        # The block waited for every build: the next pass only loads.
        assert [compiled.compile_function(f)[1] for f in funs[:2]] == ["cached", "cached"]
        assert compiled.compile_functions("parallel_lib", funs[2:])[1] == "cached"
    finally:
        compiled.remove_listener(listener)
    built = sorted(name for event, name in events if event == "compiled")
    assert built == ["parallel_lib", "parallel_probe0", "parallel_probe1"], events


def test_owned_functions_are_built_once_and_move_to_the_optimised_library(private_cache,
                                                                         monkeypatch):
    monkeypatch.setattr(compiled, "QUICK_SOURCE", 0)
    # The optimised build is held back until the quick build has been used twice: a probe
    # this small otherwise lands between the two calls on a fast machine.
    release, optimise = threading.Event(), compiled._optimise
    monkeypatch.setattr(compiled, "_optimise",
                        lambda *a: (release.wait(120.0), optimise(*a)))

    class Owner:
        pass

    owner, calls = Owner(), []

    def build():
        calls.append(1)
        return [_function("owned_probe")]

    quick, how = compiled.compile_owned(owner, "probe", "owned_lib", build)
    assert how == "compiled (quick build)", how
    assert compiled.compile_owned(owner, "probe", "owned_lib", build)[0] is quick
    release.set()
    assert compiled.wait_for_builds(BUILDS_WAIT)
    optimised, how = compiled.compile_owned(owner, "probe", "owned_lib", build)
    assert how == "cached" and optimised is not quick
    assert len(calls) == 1  # the symbolic functions were built once
    x = np.array([0.3, -1.2, 0.7])
    for got, want in zip(optimised[0](x), build()[0](x), strict=True):
        np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-14)


def test_a_loaded_optimised_library_is_returned_without_looking_at_files(private_cache,
                                                                          monkeypatch):
    """Once the optimised library is loaded, a call returns it as it is: no compiler lookup,
    no check of the cache's files (issue 47: a replan's quick motion asks about 13 times);
    with TOCONTROL_COMPILE=0 the symbolic functions, as before."""
    from pathlib import Path

    class Owner:
        pass

    owner, funs = Owner(), [_function("owned_loaded_probe")]
    compiled.compile_owned(owner, 1, "owned_loaded", lambda: funs)
    assert compiled.wait_for_builds(BUILDS_WAIT)
    optimised, how = compiled.compile_owned(owner, 1, "owned_loaded", lambda: funs)
    assert how in ("compiled", "cached") and optimised[0] is not funs[0]
    looked = []
    monkeypatch.setattr(Path, "is_file", lambda self: looked.append(self) or True)
    monkeypatch.setattr(compiled, "_compiler", lambda: looked.append("cc") or None)
    again, how_again = compiled.compile_owned(owner, 1, "owned_loaded", lambda: funs)
    assert again is optimised and how_again == how and looked == []
    monkeypatch.setenv("TOCONTROL_COMPILE", "0")
    symbolic, how = compiled.compile_owned(owner, 1, "owned_loaded", lambda: funs)
    assert symbolic == funs and "TOCONTROL_COMPILE=0" in how


def test_owned_builds_started_in_parallel_are_loaded_without_generating_again(
        private_cache, monkeypatch):
    generated = []
    generate = compiled._generate_many
    monkeypatch.setattr(compiled, "_generate_many",
                        lambda *a: (generated.append(a[0]), generate(*a)))

    class Owner:
        pass

    owner = Owner()
    funs = [_function("owned_parallel_probe")]
    with compiled.parallel_builds(jobs=2, wait=False):
        assert compiled.compile_owned(owner, 1, "owned_parallel", lambda: funs)[1] == "deferred"
    loaded, how = compiled.compile_owned(owner, 1, "owned_parallel", lambda: funs)
    assert how == "cached" and loaded[0] is not funs[0]
    assert generated == ["owned_parallel"]


def test_bounded_transcription_moves_to_the_optimised_library(private_cache, monkeypatch):
    """A model's B-spline functions are reloaded once their optimised build landed (they
    were kept as the quick build for the model's lifetime)."""
    from tocontrol_ros.core.direct.flat import FlatTranscription
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    monkeypatch.setattr(compiled, "QUICK_SOURCE", 0)
    model = load_robot(default_urdf_path())
    assert FlatTranscription(model, 4).compile_status == "compiled (quick build)"
    assert compiled.wait_for_builds(BUILDS_WAIT)
    assert FlatTranscription(model, 4).compile_status == "cached"


@pytest.mark.slow  # compiles the paper's arm in full (about a minute under load)
def test_first_plan_compiles_the_shooting_only_when_a_solve_reaches_it(private_cache):
    """Issue 18: where the joint limits bind, the first plan of a model builds the guesses'
    and the bounded solve's libraries, none of the shooting's; a plan that reaches the
    shooting compiles those then, and succeeds (the compile time is not held against its
    time limit)."""
    from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
    from tocontrol_ros.core.planning.solver import SolverOptions, plan
    from tocontrol_ros.core.robot.limits import JointLimits
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
    from tocontrol_ros.core.types.problem import Problem, point

    model = load_robot(default_urdf_path())  # a new model: nothing of it loaded yet
    base = JointLimits.from_model(model)
    tight = JointLimits(base.names, np.array([-2.5, -np.inf, -np.inf]),
                        np.array([2.5, np.inf, np.inf]), np.array([0.4, 1.0, 1.0]))
    free = JointLimits(base.names, np.full(3, -np.inf), np.full(3, np.inf),
                       np.full(3, np.inf))
    built = []

    def listener(event, name, info):
        if event == "compiled":
            built.append(name)

    compiled.add_listener(listener)
    try:
        limited = plan(Problem(model, point(PAPER_START), point(PAPER_TARGET), k=4,
                               limits=tight), SolverOptions(starts=1, candidates=1))
        first = list(built)
        unlimited = plan(Problem(model, point(PAPER_START), point(PAPER_TARGET), k=4,
                                 limits=free),
                         SolverOptions(starts=1, candidates=1, time_limit=5.0))
    finally:
        compiled.remove_listener(listener)
    assert limited.success and limited.method == "direct", limited.message
    assert any(name.startswith("flat") for name in first), first
    assert any(name.startswith("direct_point") for name in first), first
    assert not any(name.startswith("tocontrol_") for name in first), first
    assert unlimited.success and unlimited.method != "direct", unlimited.message
    assert any(name.startswith("tocontrol_rk4") or name.startswith("tocontrol_fj")
               for name in built[len(first):]), built


def _every_build(fun: ca.Function) -> dict[str, ca.Function]:
    """``fun`` compiled with each set of flags (quick, optimised, long-source, portable),
    keyed by the flags joined by spaces."""
    cc = compiled._compiler()
    libraries = {}
    for flags in (compiled.QUICK_CFLAGS, compiled.CFLAGS, compiled.LARGE_CFLAGS,
                  compiled.PORTABLE_CFLAGS):
        with compiled.tempfile.TemporaryDirectory() as tmp:
            compiled._generate_one(fun, tmp)
            target, how = compiled._build(cc, fun.name(), tmp, flags)
        assert target is not None, how
        libraries[" ".join(flags)] = ca.external(fun.name(), str(target))
    return libraries


def test_every_build_of_a_source_gives_the_same_bits(private_cache, galicki):
    """Same request, same plan whichever library is loaded: the quick build (-O0), the
    optimised ones (-O2, -O1 for long sources, -march=native) and the portable fallback round
    alike (no fused multiply-add: ``compiled.SAME_BITS``). The function is the arm's forward
    dynamics with its Jacobian, evaluated at 200 random states."""
    q, qd, tau = (ca.SX.sym(name, galicki.n) for name in ("q", "qd", "tau"))
    qdd = galicki.forward_dynamics_sym(q, qd, tau)
    args = ca.vertcat(q, qd, tau)
    fun = ca.Function("same_bits_probe", [args], [qdd, ca.jacobian(qdd, args)])
    rng = np.random.default_rng(7)
    x = rng.uniform(-2.0, 2.0, size=(3 * galicki.n, 200))
    outputs = {flags: tuple(np.array(o).tobytes() for o in lib.map(x.shape[1])(x))
               for flags, lib in _every_build(fun).items()}
    vm = fun.map(x.shape[1])(x)
    assert np.allclose(np.array(vm[0]), np.frombuffer(outputs[" ".join(compiled.CFLAGS)][0])
                       .reshape(np.array(vm[0]).shape, order="C"), rtol=1e-12, atol=1e-12)
    reference = outputs[" ".join(compiled.CFLAGS)]
    differ = [flags for flags, out in outputs.items() if out != reference]
    assert not differ, f"other bits than {' '.join(compiled.CFLAGS)}: {differ}"


def test_generating_c_never_changes_the_working_directory(tmp_path, monkeypatch):
    """Another thread's files must not land in whatever directory this one moved to."""
    import os

    import casadi as ca

    from tocontrol_ros.core.robot import compiled

    def no_chdir(path):
        raise AssertionError(f"os.chdir({path!r}) while generating C")

    x = ca.SX.sym("x", 2)
    fun = ca.Function("gen_probe", [x], [ca.sin(x) * x[0]])
    out = tmp_path / "out"
    out.mkdir()
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    monkeypatch.setattr(os, "chdir", no_chdir)
    compiled._generate_one(fun, str(out))
    assert [p.name for p in out.iterdir()] == ["gen_probe.c"]
    assert list(here.iterdir()) == []


def test_the_pandas_collocation_hessian_has_the_same_bits_from_every_build(private_cache,
                                                                          panda):
    """The Panda's Hermite-Simpson Hessian (``direct_asm_hess``, one interval) from every
    set of flags, at 100 random arguments: the same bits. With -march=native, gcc's
    vectorizer changed the last bit of 12 of its entries against -O0 until ``SAME_BITS``
    turned it off: a first plan made while the optimised library was building then differed
    from the same plan made after it had landed."""
    from tocontrol_ros.core.direct.collocation_nlp import Layout, _assembly_functions

    lay = Layout(panda.n, panda.m, 1, "state", "point", False)
    fun = next(f for f in _assembly_functions(panda, lay) if f.name() == "direct_asm_hess")
    rng = np.random.default_rng(3)
    args = [[rng.uniform(-1.0, 1.0, fun.sparsity_in(i).nnz()) for i in range(fun.n_in())]
            for _ in range(100)]
    outputs = {flags: b"".join(
        np.array(lib(*[ca.DM(fun.sparsity_in(i), a[i]) for i in range(fun.n_in())])
                 .nonzeros()).tobytes() for a in args)
        for flags, lib in _every_build(fun).items()}
    reference = outputs[" ".join(compiled.CFLAGS)]
    differ = [flags for flags, out in outputs.items() if out != reference]
    assert not differ, f"other bits than {' '.join(compiled.CFLAGS)}: {differ}"


def test_builds_into_another_cache_neither_count_nor_keep_a_wait(private_cache, tmp_path):
    """A build queued into another cache directory (the default cache's, started by an
    earlier test) is not this cache's: not pending here, and a wait returns at once; one into
    this cache is."""
    other, own = tmp_path / "elsewhere" / "lib_other.so", private_cache / "lib_own.so"
    with compiled._done:
        compiled._pending.add(other)
    try:
        assert compiled.pending_builds() == 0
        assert compiled.wait_for_builds(0.0)
        with compiled._done:
            compiled._pending.add(own)
        assert compiled.pending_builds() == 1
        assert not compiled.wait_for_builds(0.0)
    finally:
        with compiled._done:
            compiled._pending.difference_update({other, own})
            compiled._done.notify_all()


#: A process that builds ``_function("race_probe")`` into the cache and, as its compile
#: starts (inside the build's lock), waits for the file ``go`` before it goes on.
_HOLDER = """
import sys, time
from pathlib import Path
import casadi as ca
from tocontrol_ros.core.robot import compiled
here = Path(sys.argv[1])
def hold(event, name, info):
    if event == "compiling" and name.startswith("race_probe"):
        (here / "holding").touch()
        for _ in range(1200):
            if (here / "go").exists():
                break
            time.sleep(0.05)
compiled.add_listener(hold)
x = ca.SX.sym("x", 3)
y = ca.vertcat(ca.sin(x[0]) * x[1] ** 3, ca.exp(-x[2] ** 2) + x[0] * x[1])
fun = ca.Function("race_probe", [x], [y, ca.jacobian(y, x)])
print(compiled.compile_function(fun)[1])
"""


def test_a_library_another_process_is_building_is_waited_for_not_built_again(
        private_cache, tmp_path):
    """Two processes missing the same library: the second waits for the first's build.

    The other process (a child) holds its build open (a listener at the start of its
    compile waits for a file); this process's build of the same source, started then, must
    wait for the lock and find the library (``cached``), not compile it a second time.
    """
    import os
    import subprocess
    import sys
    import time

    child = subprocess.Popen([sys.executable, "-c", _HOLDER, str(tmp_path)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "TOCONTROL_CACHE": str(private_cache)})
    try:
        for _ in range(2400):  # bounded: the child's import and source generation
            if (tmp_path / "holding").exists() or child.poll() is not None:
                break
            time.sleep(0.05)
        assert (tmp_path / "holding").exists(), child.communicate()[1][-2000:]
        out: dict = {}
        mine = threading.Thread(target=lambda: out.update(
            how=compiled.compile_function(_function("race_probe"))[1]))
        mine.start()
        mine.join(2.0)  # this build reaches the lock (or, without one, compiles) meanwhile
        (tmp_path / "go").touch()
        mine.join(120.0)
        stdout, stderr = child.communicate(timeout=120.0)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, stderr[-2000:]
    assert stdout.split() == ["compiled"]
    assert out["how"] == "cached"
    assert len(_libraries(private_cache, "race_probe")) == 1


#: A process that holds ``two``'s build lock and, once this one waits for it, asks on
#: another thread for ``one``'s, which this process holds: a cycle for the kernel's
#: per-process deadlock detection, which refuses one of the two requests (``EDEADLK``).
_CROSSED = """
import sys, threading, time
from pathlib import Path
from tocontrol_ros.core.robot import compiled
here = Path(sys.argv[1])
errors = []
def ask_one():
    try:
        with compiled._process_lock(here / "one.so"):
            pass
    except OSError as exc:
        errors.append(repr(exc))
with compiled._process_lock(here / "two.so"):
    (here / "child holds two").touch()
    for _ in range(2400):
        if (here / "parent waits").exists():
            break
        time.sleep(0.05)
    other = threading.Thread(target=ask_one)
    other.start()
    other.join(1.0)  # it waits for one (or is refused) meanwhile
other.join(120.0)
print(errors)
sys.exit(1 if errors or other.is_alive() else 0)
"""


def test_a_lock_refused_as_a_deadlock_between_processes_is_waited_out(tmp_path):
    """Build locks crossed between two processes on two threads each (a library each
    builds, the other's asked for meanwhile): no real deadlock (each build ends), but the
    kernel sees locks per process and refuses one request with ``EDEADLK``; that request
    waits and gets its lock instead of failing (a warm-up thread died of it before)."""
    import os
    import subprocess
    import sys
    import time

    out: dict = {}

    def ask_two():
        try:
            with compiled._process_lock(tmp_path / "two.so"):
                out["two"] = True
        except OSError as exc:
            out["error"] = repr(exc)

    with compiled._process_lock(tmp_path / "one.so"):
        child = subprocess.Popen([sys.executable, "-c", _CROSSED, str(tmp_path)],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 env=dict(os.environ))
        for _ in range(2400):  # bounded: the child's import
            if (tmp_path / "child holds two").exists() or child.poll() is not None:
                break
            time.sleep(0.05)
        assert (tmp_path / "child holds two").exists(), child.communicate()[1][-2000:]
        mine = threading.Thread(target=ask_two)
        mine.start()
        mine.join(1.0)  # it waits for two (or is refused) meanwhile
        (tmp_path / "parent waits").touch()
        mine.join(120.0)  # the child lets two go once its other thread asked for one
    try:
        stdout, stderr = child.communicate(timeout=120.0)
    finally:
        if child.poll() is None:
            child.kill()
    assert out == {"two": True}, out
    assert child.returncode == 0, (stdout, stderr[-2000:])
