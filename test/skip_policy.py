"""In the project's own environment a missing dependency or data file fails its tests.

``scripts/dev`` sets ``TOCONTROL_DEV_VENV``: there every optional test dependency (the
``test`` extra of setup.py) and data file is installed, so a test skipped because one is
missing would hide a broken environment behind a green run. Such a skip is turned into a
failure that names what is missing, and the run's summary lists them all. Elsewhere (a bare
``pytest`` in a venv of one's own) they stay skips, each reported by ``-ra``.

A skip counts as "missing" when its reason starts with ``missing:`` (use :func:`missing`)
or is ``pytest.importorskip``'s ("could not import ..."). Other skips (what a machine may
truly lack, e.g. a system browser) are left alone.

The hooks are imported into test/conftest.py; test/test_test_rules.py runs them on a
throwaway suite.
"""

import os
import sys
from pathlib import Path

import pytest

#: Set by scripts/dev: the environment it made must hold everything.
DEV_ENV_VARIABLE = "TOCONTROL_DEV_VENV"
MISSING = "missing: "
_MISSING_PREFIXES = (MISSING, "could not import ")

_found = []  # (nodeid, reason) of the skips turned into failures


def missing(what: str) -> None:
    """Skip the calling test because ``what`` is not installed (a failure under scripts/dev).

    ``what`` names the package or file and how to get it, e.g.
    ``"example-robot-data (pip install '.[test]')"``.
    """
    pytest.skip(MISSING + what)


def panda_urdf() -> Path:
    """example-robot-data's Panda URDF, installed by the test extra; else :func:`missing`."""
    for d in sys.path:
        path = (Path(d) / "cmeel.prefix/share/example-robot-data/robots/panda_description/"
                "urdf/panda.urdf")
        if path.is_file():
            return path
    missing("example-robot-data (pip install '.[test]')")


def panda_srdf() -> Path:
    """example-robot-data's Panda SRDF (beside its URDF); else :func:`missing`."""
    srdf = panda_urdf().parent.parent / "srdf" / "panda.srdf"
    if not srdf.is_file():
        missing("example-robot-data's panda.srdf (pip install '.[test]')")
    return srdf


def _reason(report) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        reason = str(longrepr[2])
    else:
        reason = str(longrepr)
    return reason.removeprefix("Skipped: ")


def _fail_if_missing(report) -> None:
    if not os.environ.get(DEV_ENV_VARIABLE) or not report.skipped:
        return
    if hasattr(report, "wasxfail"):
        return
    reason = _reason(report)
    if not reason.startswith(_MISSING_PREFIXES):
        return
    _found.append((report.nodeid, reason))
    report.outcome = "failed"
    report.longrepr = (
        f"skipped for a missing dependency or data file, which is a failure in the project's "
        f"own environment ({DEV_ENV_VARIABLE} is set by scripts/dev): {reason}")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_if_missing(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _fail_if_missing(outcome.get_result())


def pytest_terminal_summary(terminalreporter):
    if not _found:
        return
    terminalreporter.section("missing in the project's own environment")
    for nodeid, reason in _found:
        terminalreporter.write_line(f"{nodeid}: {reason}")
