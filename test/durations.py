"""Where a test run's time went, from its JUnit XML: by directory, by file, the slowest tests.

    scripts/dev test -q -p no:cacheprovider --junitxml=/tmp/run.xml -o junit_duration_report=total
    scripts/dev run python -P test/durations.py /tmp/run.xml [--top 40]

``junit_duration_report=total`` counts each test's setup and teardown with its call, so a
module-scoped fixture's cost lands on the first test that uses it. The shares are what to
compare between runs on a loaded machine: the absolute seconds scale with the load.
"""

from __future__ import annotations

import argparse
import collections
import sys
import xml.etree.ElementTree as ET


def read_times(path: str) -> list[tuple[float, str, str]]:
    """``(seconds, module path, test name)`` of every test case in a JUnit XML file.

    Parameters
    ----------
    path : str
        The file pytest's ``--junitxml`` wrote.

    Returns
    -------
    list of (float, str, str)
        Seconds (setup, call and teardown with ``junit_duration_report=total``), the test
        module as ``test/dir/test_file`` and the test's name with its parameters.
    """
    out = []
    for case in ET.parse(path).getroot().iter("testcase"):
        parts = case.get("classname", "").split(".")
        module = "/".join(p for p in parts if not p[:1].isupper())  # drop test classes
        out.append((float(case.get("time", 0.0)), module, case.get("name", "")))
    return out


def report(times: list[tuple[float, str, str]], top: int = 40) -> str:
    """The run's total, then the time by directory and file and the slowest tests.

    Parameters
    ----------
    times : list of (float, str, str)
        As :func:`read_times` returns them.
    top : int
        How many files and tests to list.

    Returns
    -------
    str
        The table, one line each, seconds and per cent of the total.
    """
    total = sum(t for t, _, _ in times) or 1.0
    lines = [f"{len(times)} tests, {total:.0f} s"]
    for title, key, count in (("directory", lambda m: "/".join(m.split("/")[:2]), None),
                              ("file", lambda m: m, top)):
        seconds, tests = collections.Counter(), collections.Counter()
        for t, module, _ in times:
            seconds[key(module)] += t
            tests[key(module)] += 1
        lines.append(f"== by {title}")
        lines += [f"{name:48s} {tests[name]:5d} tests {t:7.0f} s {100 * t / total:5.1f} %"
                  for name, t in seconds.most_common(count)]
    lines.append(f"== the {top} slowest tests")
    lines += [f"{t:7.1f} s {100 * t / total:5.2f} % {module}::{name}"
              for t, module, name in sorted(times, reverse=True)[:top]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print :func:`report` of the JUnit XML file given on the command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("junit_xml")
    parser.add_argument("--top", type=int, default=40)
    args = parser.parse_args(argv)
    print(report(read_times(args.junit_xml), args.top))
    return 0


if __name__ == "__main__":
    sys.exit(main())
