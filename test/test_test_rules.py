"""The test suite's own rules, checked on its source and on a throwaway suite.

- No assertion on elapsed wall time: a loaded machine stretches any time (issue 53). A
  wait is for an event with a generous bound, and a hang is caught by that bound, not by
  an ``assert elapsed < ...``.
- No ``time.sleep`` followed by a negative assertion ("nothing arrived", "not done yet"):
  on a busy machine the sleep proves nothing, on a fast one the race goes the other way.
  Hold the event instead (a gate the test opens, a solve held by a test hook).
- An xfail names the exception it expects (``raises=``).
- Under scripts/dev a skip for a missing dependency or data file is a failure naming it
  (test/skip_policy.py).
"""

import ast
import functools
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from skip_policy import DEV_ENV_VARIABLE

TEST_DIR = Path(__file__).resolve().parent
REPO = TEST_DIR.parent
CLOCKS = {"monotonic", "perf_counter", "time", "monotonic_ns", "perf_counter_ns", "time_ns"}


def _is_clock_call(node) -> bool:
    """``time.monotonic()`` and friends."""
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr in CLOCKS and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "time")


def _is_sleep(stmt) -> bool:
    return (isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Call)
            and isinstance(stmt.value.func, ast.Attribute) and stmt.value.func.attr == "sleep"
            and isinstance(stmt.value.func.value, ast.Name)
            and stmt.value.func.value.id == "time")


def _is_negative(test) -> bool:
    """``not x``, ``not any(...)``, ``x == 0``, ``x == []``, ``len(x) == n``, ``x is None``."""
    if isinstance(test, ast.UnaryOp) and isinstance(test.op, ast.Not):
        return True
    if isinstance(test, ast.BoolOp):
        return any(_is_negative(v) for v in test.values)
    if isinstance(test, ast.Compare) and len(test.ops) == 1:
        left, op, right = test.left, test.ops[0], test.comparators[0]
        if isinstance(op, ast.Is) and isinstance(right, ast.Constant) and right.value is None:
            return True
        if isinstance(op, ast.Eq):
            if isinstance(right, ast.Constant) and right.value in (0, 0.0):
                return True
            if isinstance(right, (ast.List, ast.Tuple, ast.Set, ast.Dict)) and not (
                    getattr(right, "elts", None) or getattr(right, "keys", None)):
                return True
            if isinstance(left, ast.Call) and isinstance(left.func, ast.Name) \
                    and left.func.id == "len":
                return True
    return False


def _bodies(tree):
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            stmts = getattr(node, field, None)
            if isinstance(stmts, list) and stmts and isinstance(stmts[0], ast.stmt):
                yield stmts
        for handler in getattr(node, "handlers", []):
            yield handler.body


def sleep_then_negative(tree) -> list[int]:
    """Lines of a ``time.sleep`` whose next statements (up to the next non-assertion)
    include a negative assertion."""
    found = []
    for stmts in _bodies(tree):
        for i, stmt in enumerate(stmts):
            if not _is_sleep(stmt):
                continue
            for after in stmts[i + 1:]:
                if not isinstance(after, ast.Assert):
                    break
                if _is_negative(after.test):
                    found.append(stmt.lineno)
                    break
    return found


def elapsed_assertions(tree) -> list[int]:
    """Lines of assertions on a difference of clock readings (directly or through names)."""
    found = []
    for func in ast.walk(tree):
        if not isinstance(func, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Module)):
            continue
        clock_names, elapsed_names = set(), set()

        def is_clock(node, clock_names=clock_names):
            return _is_clock_call(node) or (isinstance(node, ast.Name)
                                            and node.id in clock_names)

        def is_difference(node, clock_names=clock_names, elapsed_names=elapsed_names):
            for sub in ast.walk(node):
                if isinstance(sub, ast.BinOp) and isinstance(sub.op, ast.Sub) and (
                        is_clock(sub.left) or is_clock(sub.right)):
                    return True
                if isinstance(sub, ast.Name) and sub.id in elapsed_names:
                    return True
            return False

        for node in ast.walk(func):  # names first (ast.walk is breadth first: two passes)
            if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                    and isinstance(node.targets[0], ast.Name):
                if _is_clock_call(node.value):
                    clock_names.add(node.targets[0].id)
        for node in ast.walk(func):
            if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                    and isinstance(node.targets[0], ast.Name) and is_difference(node.value):
                elapsed_names.add(node.targets[0].id)
        for node in ast.walk(func):
            if isinstance(node, ast.Assert) and is_difference(node.test):
                found.append(node.lineno)
    return sorted(set(found))


def xfails_without_raises(tree) -> list[int]:
    """Lines of ``pytest.mark.xfail(...)`` without ``raises=``: a crash would count as the
    expected failure."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and node.func.attr == "xfail" and not any(kw.arg == "raises"
                                                          for kw in node.keywords):
            found.append(node.lineno)
    return found


def _test_sources():
    return sorted(p for p in TEST_DIR.rglob("*.py") if "__pycache__" not in p.parts)


@functools.cache
def _parsed_suite() -> tuple:
    """``(path, tree)`` of every test source, parsed once for the three scans (the checks
    only read the trees)."""
    return tuple((path, ast.parse(path.read_text(), filename=str(path)))
                 for path in _test_sources())


@pytest.mark.parametrize("check", [sleep_then_negative, elapsed_assertions,
                                   xfails_without_raises],
                         ids=["sleep-then-negative", "elapsed-time", "xfail-raises"])
def test_no_timed_or_raced_assertions_in_the_suite(check):
    offenders = []
    for path, tree in _parsed_suite():
        offenders += [f"{path.relative_to(REPO)}:{line}" for line in check(tree)]
    assert offenders == [], f"{check.__name__}: {offenders}"


@pytest.mark.parametrize("source, check, lines", [
    ("time.sleep(0.2)\nassert not got\n", sleep_then_negative, [1]),
    ("time.sleep(0.2)\nassert x > 0\nassert len(got) == 2\n", sleep_then_negative, [1]),
    ("time.sleep(0.2)\nwait_for(got)\nassert not got\n", sleep_then_negative, []),
    ("time.sleep(0.2)\nassert got\n", sleep_then_negative, []),
    ("t0 = time.monotonic()\nrun()\nassert time.monotonic() - t0 < 1\n",
     elapsed_assertions, [3]),
    ("def f():\n    t0 = time.monotonic()\n    e = time.monotonic() - t0\n    assert e < 9\n",
     elapsed_assertions, [4]),
    ("deadline = time.monotonic() + 9\nassert time.monotonic() < deadline\n",
     elapsed_assertions, []),
    ("@pytest.mark.xfail(strict=True, reason='x')\ndef test(): pass\n",
     xfails_without_raises, [1]),
    ("@pytest.mark.xfail(raises=ValueError)\ndef test(): pass\n", xfails_without_raises, []),
], ids=["sleep-not", "sleep-len", "sleep-then-wait", "sleep-positive", "direct", "named",
        "deadline", "xfail", "xfail-raises"])
def test_the_scan_finds_what_it_should(source, check, lines):
    assert check(ast.parse(source)) == lines


SUITE = textwrap.dedent("""
    import pytest
    from skip_policy import missing

    def test_data_file():
        missing("a_data_file (pip install nothing)")

    def test_import():
        pytest.importorskip("tocontrol_no_such_module")

    def test_machine():
        pytest.skip("no browser here")

    def test_fine():
        pass
""")


def _run_suite(tmp_path, dev_env: bool, *files):
    env = dict(os.environ, PYTHONPATH=str(TEST_DIR))
    env.pop(DEV_ENV_VARIABLE, None)
    if dev_env:
        env[DEV_ENV_VARIABLE] = "1"
    return subprocess.run([sys.executable, "-P", "-m", "pytest", "-p", "no:cacheprovider",
                           "-ra", *map(str, files)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)


def test_a_missing_dependency_fails_in_the_project_environment_and_skips_elsewhere(tmp_path):
    (tmp_path / "conftest.py").write_text("from skip_policy import *  # noqa: F403\n")
    (tmp_path / "test_suite.py").write_text(SUITE)
    (tmp_path / "test_collect.py").write_text(
        "import pytest\npytest.importorskip('tocontrol_missing_at_collection')\n"
        "def test_x():\n    pass\n")
    dev = _run_suite(tmp_path, True, "test_suite.py")
    out = dev.stdout + dev.stderr
    assert dev.returncode == 1, out
    assert "2 failed, 1 passed, 1 skipped" in out, out
    summary = out.split("missing in the project's own environment")[1]
    assert "a_data_file" in summary and "tocontrol_no_such_module" in summary, out
    assert "SKIPPED [1] test_suite.py" in out and "no browser here" in out, out
    # At collection (a module-level importorskip): an error that stops the run.
    dev = _run_suite(tmp_path, True, "test_collect.py")
    out = dev.stdout + dev.stderr
    assert dev.returncode == 2, out
    summary = out.split("missing in the project's own environment")[1]
    assert "tocontrol_missing_at_collection" in summary, out
    bare = _run_suite(tmp_path, False, "test_suite.py", "test_collect.py")
    out = bare.stdout + bare.stderr
    assert bare.returncode == 0, out
    assert "1 passed, 4 skipped" in out, out


def test_an_uninstalled_test_dependency_fails_the_suite_naming_it(tmp_path):
    # rosbags hidden (a package of that name that cannot be imported, first on the path), as
    # if uninstalled from the dev environment: collecting the recording tests fails naming it.
    hidden = tmp_path / "hidden" / "rosbags"
    hidden.mkdir(parents=True)
    (hidden / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'rosbags'\", name='rosbags')\n")
    env = dict(os.environ, PYTHONPATH=str(hidden.parent), **{DEV_ENV_VARIABLE: "1"})
    done = subprocess.run(
        [sys.executable, "-P", "-m", "pytest", "-p", "no:cacheprovider", "--collect-only",
         "-q", str(TEST_DIR / "recording" / "test_mcap_io.py")],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    out = done.stdout + done.stderr
    assert done.returncode != 0, out
    summary = out.split("missing in the project's own environment")[1]
    assert "rosbags" in summary, out
