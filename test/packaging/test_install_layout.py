"""The pip route: what `pip install .` puts in the prefix is what `ros2 run` needs."""

import importlib.metadata
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = "tocontrol_ros"
BUNDLED_URDF = "galicki_3r.urdf"


def _env_without_prefix_bin(prefix, **extra):
    """Environment whose PATH lacks <prefix>/bin, so that `python3` is not the venv's."""
    env = dict(os.environ)
    bindir = str(prefix / "bin")
    env["PATH"] = os.pathsep.join(
        p for p in env.get("PATH", "").split(os.pathsep) if p and p != bindir
    )
    env.pop("VIRTUAL_ENV", None)
    env.update(extra)
    return env


def _installed_urdf(prefix):
    return prefix / "share" / PACKAGE / "config" / BUNDLED_URDF


def test_ament_index_marker_installed(prefix):
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    assert marker.is_file()


def test_package_xml_installed_unchanged(prefix, repo):
    installed = prefix / "share" / PACKAGE / "package.xml"
    assert installed.read_text() == (repo / "package.xml").read_text()


def test_config_files_installed(prefix, repo):
    share_config = prefix / "share" / PACKAGE / "config"
    assert (share_config / BUNDLED_URDF).is_file()
    source = {p.name for p in (repo / "config").iterdir() if p.is_file() and p.name[0] != "."}
    installed = {p.name for p in share_config.iterdir()}
    assert source <= installed, f"not installed: {sorted(source - installed)}"


@pytest.mark.parametrize("kind", ["ros2run_wrapper", "console_script"])
def test_executables_installed(prefix, executables, kind):
    for name in executables:
        if kind == "ros2run_wrapper":
            path = prefix / "lib" / PACKAGE / name
        else:
            path = prefix / "bin" / f"tocontrol-{name}"
        assert path.is_file(), f"missing: {path}"
        assert os.access(path, os.X_OK), f"not executable: {path}"


def test_installed_console_scripts_match_executables(prefix, executables):
    entry_points = importlib.metadata.distribution(PACKAGE).entry_points
    scripts = {ep.name: ep.value for ep in entry_points if ep.group == "console_scripts"}
    assert scripts == {f"tocontrol-{n}": f"{m}:main" for n, m in executables.items()}


def test_tests_import_the_installed_package(prefix):
    if not os.environ.get("TOCONTROL_DEV_VENV"):
        pytest.skip("only meaningful under scripts/dev (installed, non-editable)")
    import tocontrol_ros

    site = Path(tocontrol_ros.__file__).resolve()
    assert Path(prefix).resolve() in site.parents, (
        f"tocontrol_ros imported from {site}, not from the install in {prefix}: the source "
        "tree is shadowing it (a test/__init__.py, or pytest run without python -P?)"
    )


def test_ament_index_finds_share_directory(prefix, monkeypatch):
    from ament_index_python.packages import get_package_share_directory

    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    share = Path(get_package_share_directory(PACKAGE))
    assert share.resolve() == (prefix / "share" / PACKAGE).resolve()


def test_ros2run_wrapper_help_uses_venv_python(prefix, executables):
    # PATH without the venv: the wrapper must find <prefix>/bin/python3 by itself.
    env = _env_without_prefix_bin(prefix, AMENT_PREFIX_PATH=str(prefix))
    for name in executables:
        proc = subprocess.run(
            [str(prefix / "lib" / PACKAGE / name), "--help"],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            cwd="/",
        )
        assert proc.returncode == 0, proc.stderr
        assert "usage:" in proc.stdout


def test_demo_runs_through_ros2run_wrapper(prefix):
    # What `ros2 run tocontrol_ros demo` execs; the URDF is found via the ament index.
    env = _env_without_prefix_bin(prefix, AMENT_PREFIX_PATH=str(prefix))
    proc = subprocess.run(
        [str(prefix / "lib" / PACKAGE / "demo")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd="/",
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert proc.stdout.strip()


# The whole demo (its three node processes) a second time: with the slow tests. The default
# run keeps the demo through the ros2-run wrapper (test_demo_runs_through_ros2run_wrapper) and
# the URDF found without the ament environment (test_default_urdf_found_without_ament_environment).
@pytest.mark.slow
def test_demo_console_script_without_ament_environment(prefix):
    # A plain pip venv, nothing sourced: the URDF is found under sys.prefix/share.
    env = dict(os.environ)
    env.pop("AMENT_PREFIX_PATH", None)
    proc = subprocess.run(
        [str(prefix / "bin" / "tocontrol-demo")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd="/",
    )
    assert proc.returncode == 0, proc.stderr[-4000:]


def test_default_urdf_found_without_ament_environment(prefix, monkeypatch):
    from tocontrol_ros import demo

    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    assert demo.default_urdf_path().resolve() == _installed_urdf(prefix).resolve()


def test_running_interpreter_is_the_prefix_python(prefix):
    # Sanity: the wrapper's `../../bin/python3` resolves to an interpreter of this prefix.
    wrapper_target = prefix / "lib" / PACKAGE / ".." / ".." / "bin" / "python3"
    assert os.access(wrapper_target, os.X_OK)
    out = subprocess.run(
        [str(wrapper_target), "-c", "import sys; print(sys.prefix)"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(out).resolve() == Path(sys.prefix).resolve()
