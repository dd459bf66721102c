"""setup.py's EXECUTABLES, the ros2-run wrappers and the modules agree.

Also checks the wrapper's choice of interpreter on both routes with stand-in
interpreters, without installing anything.
"""

import ast
import os
import shutil
import subprocess
import sys

import pytest

PACKAGE = "tocontrol_ros"
WRAPPER_DIR = ("scripts", "ros2run")


def _wrapper_dir(repo):
    return repo.joinpath(*WRAPPER_DIR)


def test_one_wrapper_per_executable(repo, executables):
    wrappers = {p.name for p in _wrapper_dir(repo).iterdir() if not p.name.startswith(".")}
    assert wrappers == set(executables), (
        "scripts/ros2run/ must hold exactly one wrapper per setup.py EXECUTABLES entry"
    )


def test_wrappers_are_executable_posix_sh(repo, executables):
    for name, module in executables.items():
        path = _wrapper_dir(repo) / name
        text = path.read_text()
        assert text.startswith("#!/bin/sh\n"), path
        assert os.access(path, os.X_OK), f"{path} lacks the exec bit (git update-index --chmod)"
        assert f'exec "$PY" -m {module} "$@"' in text, f"{path} does not run {module}"
        subprocess.run(["sh", "-n", str(path)], check=True)


def test_modules_have_main_and_run_as_scripts(repo, executables):
    """Each executable's module has a main() (defined, or imported from the subpackage that
    holds the code: the thin entry modules of issue 31) and runs under ``python -m``: a
    module by its ``__main__`` guard, a package by its ``__main__.py``."""
    for name, module in executables.items():
        assert module.startswith(PACKAGE + "."), f"{name}: {module} is outside the package"
        path = repo.joinpath(*module.split("."))
        package = path.is_dir()
        if package:
            assert (path / "__main__.py").is_file(), f"{name}: {module} has no __main__.py"
            path = path / "__init__.py"
        else:
            path = path.with_suffix(".py")
        assert path.is_file(), f"{name}: no module file {path}"
        tree = ast.parse(path.read_text(), filename=str(path))
        functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        functions |= {alias.asname or alias.name for n in tree.body
                      if isinstance(n, ast.ImportFrom) for alias in n.names}
        assert "main" in functions, f"{module} has no top-level main()"
        guards = [
            n
            for n in tree.body
            if isinstance(n, ast.If) and "__main__" in ast.unparse(n.test)
        ]
        assert package or guards, (
            f'{module} lacks `if __name__ == "__main__":` (python -m runs it)')


def _fake_python(path, label):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'#!/bin/sh\necho "{label} $*"\n')
    path.chmod(0o755)


@pytest.mark.parametrize("route", ["pip", "colcon"])
def test_wrapper_picks_interpreter(repo, tmp_path, route):
    prefix = tmp_path / "prefix"
    wrapper = prefix / "lib" / PACKAGE / "demo"
    wrapper.parent.mkdir(parents=True)
    shutil.copy2(_wrapper_dir(repo) / "demo", wrapper)
    if route == "pip":
        _fake_python(prefix / "bin" / "python3", "prefix-python")
    _fake_python(tmp_path / "path" / "python3", "path-python")
    env = {"PATH": f"{tmp_path / 'path'}:/usr/bin:/bin"}
    out = subprocess.run(
        [str(wrapper), "--urdf", "a b.urdf"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    expected = "prefix-python" if route == "pip" else "path-python"
    assert out == f"{expected} -m tocontrol_ros.demo --urdf a b.urdf"


#: The node executables: one BLAS thread unless the user set it, before numpy loads.
SINGLE_BLAS = ("planner", "tracker", "recorder", "replay")
WATCH_BLAS = """
import importlib.abc, os, sys
seen = {}
class Watch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name in ("numpy", "casadi") and name not in seen:
            seen[name] = os.environ.get("OPENBLAS_NUM_THREADS")
sys.meta_path.insert(0, Watch())
import tocontrol_ros.%s
print(seen.get("numpy"), seen.get("casadi"))
"""


@pytest.mark.parametrize("module", SINGLE_BLAS)
@pytest.mark.parametrize("user", [None, "3"], ids=["unset", "user_set"])
def test_node_executables_load_blas_single_threaded(module, user):
    """A node's BLAS loads with one thread, unless the user set ``OPENBLAS_NUM_THREADS``.

    Under load the solves' small banded factorisations were 12 times slower with the two
    threads OpenBLAS takes by default on two cores (docs/speed.md). What numpy and CasADi
    see is recorded at the moment they are first imported, in a fresh interpreter.
    """
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if user is not None:
        env["OPENBLAS_NUM_THREADS"] = user
    out = subprocess.run([sys.executable, "-P", "-c", WATCH_BLAS % module], env=env,
                         capture_output=True, text=True, timeout=120, check=True).stdout
    seen_numpy, seen_casadi = out.split()[-2:]
    assert seen_numpy == (user or "1"), out
    assert seen_casadi in (user or "1", "None"), out  # the recorder and replay need no CasADi
