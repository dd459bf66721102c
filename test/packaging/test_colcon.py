"""The colcon route: `colcon build` of this package, then what `ros2 run` would exec.

colcon and colcon-ros come from the Python package registry into a throwaway venv
(pinned by colcon-requirements.txt); there is no `ros2` command here, so the test
resolves the executable as `ros2 run` does (ament index -> <prefix>/lib/<pkg>/<name>)
and runs it in a shell that has sourced the workspace's local_setup.sh.
"""

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from skip_policy import missing

PACKAGE = "tocontrol_ros"

pytestmark = pytest.mark.slow

# What `ros2 run PKG NAME ARGS` does, minus the CLI: find the prefix in the ament index,
# then exec <prefix>/lib/PKG/NAME.
ROS2RUN = """
import os, sys
from ament_index_python.packages import get_package_prefix
pkg, name, *args = sys.argv[1:]
path = os.path.join(get_package_prefix(pkg), "lib", pkg, name)
os.execv(path, [path, *args])
"""


def _run(cmd, **kwargs):
    kwargs.setdefault("capture_output", True)
    kwargs.setdefault("text", True)
    return subprocess.run(cmd, **kwargs)


@pytest.fixture(scope="module")
def colcon(tmp_path_factory, repo):
    venv = tmp_path_factory.mktemp("colcon-venv")
    _run([sys.executable, "-m", "venv", str(venv)], check=True)
    proc = _run(
        [
            str(venv / "bin" / "python"),
            "-m",
            "pip",
            "install",
            "--quiet",
            "-r",
            str(repo / "test" / "packaging" / "colcon-requirements.txt"),
        ],
        timeout=600,
    )
    if proc.returncode != 0:
        missing("colcon: pip could not install test/packaging/colcon-requirements.txt: "
                f"{proc.stderr.strip()[-800:]}")
    return venv / "bin" / "colcon"


@pytest.fixture(scope="module", params=["copy", "symlink"])
def workspace(request, colcon, tmp_path_factory, repo):
    ws = tmp_path_factory.mktemp(f"ws-{request.param}")
    (ws / "src").mkdir()
    (ws / "src" / PACKAGE).symlink_to(repo, target_is_directory=True)
    cmd = [str(colcon), "build", "--packages-select", PACKAGE]
    if request.param == "symlink":
        cmd.append("--symlink-install")
    # colcon's own venv python runs setup.py; nothing from the dev env must leak in.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    proc = _run(cmd, cwd=ws, env=env, timeout=600)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    return ws


def test_install_layout(workspace):
    prefix = workspace / "install" / PACKAGE
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    assert marker.is_file()
    assert (prefix / "share" / PACKAGE / "package.xml").is_file()
    assert (prefix / "share" / PACKAGE / "config" / "galicki_3r.urdf").is_file()
    for name in ("demo", "tocontrol-demo"):
        path = prefix / "lib" / PACKAGE / name
        assert path.is_file() and os.access(path, os.X_OK), path


def _sourced(workspace, command):
    """Run `command` (argv) in sh after sourcing the workspace, dev env's python3 on PATH.

    The dev env stands in for a Jazzy install's system Python with the dependencies.
    """
    setup = workspace / "install" / "local_setup.sh"
    script = f". {shlex.quote(str(setup))} && exec {shlex.join(command)}"
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    env.pop("AMENT_PREFIX_PATH", None)  # only the workspace: no pip-installed copy
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"
    return _run(["sh", "-c", script], env=env, cwd="/", timeout=300)


def test_ros2_run_help(workspace):
    proc = _sourced(workspace, ["python3", "-c", ROS2RUN, PACKAGE, "demo", "--help"])
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout


def test_workspace_package_is_the_one_imported(workspace):
    proc = _sourced(
        workspace,
        ["python3", "-P", "-c", "import tocontrol_ros; print(tocontrol_ros.__file__)"],
    )
    assert proc.returncode == 0, proc.stderr
    # Not the pip-installed copy of the dev env: the workspace's (install/ for a copy
    # install, build/ for a symlink install).
    assert str(workspace) in proc.stdout


def test_ros2_run_demo(workspace):
    proc = _sourced(workspace, ["python3", "-c", ROS2RUN, PACKAGE, "demo"])
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert proc.stdout.strip()


def test_colcon_builds_tocontrol_msgs(colcon, repo, tmp_path_factory):
    """The colcon route of the project's own interface package (issue 52).

    colcon does not look inside a package for others (``tocontrol_ros`` is the repository's
    root), so a workspace names the folder: ``--base-paths`` (or a link in ``src/``), as
    interfaces/README.md says. The dev env's rosidl wheels stand in for a Jazzy install's
    ament and rosidl (found through ``AMENT_PREFIX_PATH`` as a sourced install would be);
    the generated Python package is then imported from the workspace.
    """
    import sysconfig

    import numpy

    ws = tmp_path_factory.mktemp("ws-msgs")
    folder = repo / "interfaces" / "tocontrol_msgs"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["AMENT_PREFIX_PATH"] = sys.prefix
    env["CMAKE_PREFIX_PATH"] = sys.prefix
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"
    proc = _run([str(colcon), "build", "--base-paths", str(folder), "--cmake-args",
                 f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF",
                 f"-DTOCONTROL_PYTHON_INCLUDE={sysconfig.get_paths()['include']}",
                 f"-DTOCONTROL_NUMPY_INCLUDE={numpy.get_include()}"],
                cwd=ws, env=env, timeout=900)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    site = next((ws / "install" / "tocontrol_msgs" / "lib").glob("python3*/site-packages"))
    check = _run([sys.executable, "-P", "-c", "import tocontrol_msgs.action as a, sys; "
                  "print(a.__file__); print(a.PlanMotion.Goal().k)"],
                 env={**env, "PYTHONPATH": str(site),
                      "LD_LIBRARY_PATH": f"{ws / 'install' / 'tocontrol_msgs' / 'lib'}:"
                                         f"{env.get('LD_LIBRARY_PATH', '')}"}, timeout=120)
    assert check.returncode == 0, check.stderr[-3000:]
    assert str(ws) in check.stdout and "-1.0" in check.stdout
