"""The report's page in a real browser: headless Chromium (the Debian package ``chromium``)
opens ``index.html`` and must load it with no error and every figure decoded.

Driven over the Chrome DevTools Protocol on a pipe (``--remote-debugging-pipe``: JSON
messages ending in a NUL byte on file descriptors 3 and 4), so no WebSocket client or
driver package is needed. Slow-marked; skipped, saying why, when ``chromium`` is absent.
"""

import json
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recording"))
from test_report import write_two_motions  # noqa: E402 (the report tests' helper)

from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.recording import report

pytestmark = pytest.mark.slow
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]


_PLACE_FDS = """import fcntl, os, sys
a, b = (fcntl.fcntl(int(fd), fcntl.F_DUPFD, 10) for fd in sys.argv[1:3])
os.dup2(a, 3)
os.dup2(b, 4)
os.execv(sys.argv[3], sys.argv[3:])
"""


class DevTools:
    """A CDP session with a browser started with ``--remote-debugging-pipe``."""

    def __init__(self, executable, user_data_dir):
        to_browser_r, self._write = os.pipe()
        self._read, from_browser_w = os.pipe()
        # The browser reads commands on its fd 3 and writes replies and events on its fd 4:
        # a small Python puts the pipe ends there (above 9 first: they may be 3 or 4), then
        # becomes the browser.
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _PLACE_FDS, str(to_browser_r), str(from_browser_w),
             executable, *FLAGS, f"--user-data-dir={user_data_dir}",
             "--remote-debugging-pipe", "about:blank"],
            pass_fds=(to_browser_r, from_browser_w), stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self.events = []

    def send(self, method, params=None, session=None, timeout=30.0):
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        reply = self.wait(lambda m: m.get("id") == self._next_id, timeout, method)
        if "error" in reply:
            raise AssertionError(f"{method}: {reply['error']}")
        return reply.get("result", {})

    def wait(self, predicate, timeout, what):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                message = json.loads(raw)
                if "method" in message:
                    self.events.append(message)
                if predicate(message):
                    return message
            ready, _, _ = select.select([self._read], [], [], 0.1)
            if ready:
                chunk = os.read(self._read, 1 << 16)
                if not chunk:
                    break
                self._buffer += chunk
        raise AssertionError(f"no answer from Chromium for {what} in {timeout:g} s")

    def close(self):
        try:
            self.send("Browser.close", timeout=5.0)
        except (AssertionError, OSError):
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._write)
        os.close(self._read)


def test_report_page_loads_in_chromium_with_every_image(tmp_path):
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium); the report "
                    "page is not checked in a browser")
    recording = tmp_path / "run.mcap"
    write_two_motions(recording, load_robot(default_urdf_path()))
    out = tmp_path / "report"
    assert report.main([str(recording), "--out", str(out)]) == 0
    pngs = sorted(p.name for p in out.glob("motion_*.png"))
    assert pngs == ["motion_1.png", "motion_2.png", "motion_3.png"]

    browser = DevTools(executable, tmp_path / "chromium-profile")
    try:
        targets = browser.send("Target.getTargets")["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        session = browser.send("Target.attachToTarget",
                               {"targetId": page["targetId"], "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            browser.send(f"{domain}.enable", session=session)
        browser.send("Page.navigate", {"url": (out / "index.html").resolve().as_uri()},
                     session=session)
        browser.wait(lambda m: m.get("method") == "Page.loadEventFired", 30.0, "page load")
        result = browser.send("Runtime.evaluate", {
            "expression": "JSON.stringify({title: document.title, rows: "
                          "document.querySelectorAll('#motions tbody tr').length, images: "
                          "Array.from(document.images).map(i => [i.getAttribute('src'), "
                          "i.complete, i.naturalWidth, i.naturalHeight])})",
            "returnByValue": True}, session=session)
        state = json.loads(result["result"]["value"])
    finally:
        browser.close()
    problems = [e for e in browser.events
                if e["method"] in ("Runtime.exceptionThrown", "Network.loadingFailed")
                or (e["method"] == "Log.entryAdded"
                    and e["params"]["entry"]["level"] == "error")
                or (e["method"] == "Runtime.consoleAPICalled"
                    and e["params"]["type"] == "error")]
    assert problems == [], problems
    assert state["title"] == "Report: run.mcap" and state["rows"] == 3, state
    assert [img[0] for img in state["images"]] == pngs, state
    for src, complete, width, height in state["images"]:
        # Decoded, at the size the page declares.
        assert complete and (width, height) == (990, 720), (src, state)
