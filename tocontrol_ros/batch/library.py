"""The ``batch`` library: an append-only journal, the MCAP library and its CSV summary.

Three files share the output's stem (``cell.mcap``):

- ``cell.journal.jsonl``: the source of truth while a run goes on. A header line (the task
  set's fingerprint), then one JSON line per finished task with its outcome and, for a
  solved task, the exact CDR bytes of its ``trajectory_msgs/JointTrajectory`` (base64).
  Each line is flushed and fsynced when the task finishes, so an interrupted run loses
  only the tasks in flight; a torn last line (a kill mid-write) is ignored and its task
  planned again. A task is never journaled twice (the first line of a key wins).
- ``cell.mcap``: rewritten from the journal at the end of each run (written aside, then
  renamed over the old one), in the recorder's rosbag2 layout
  (:mod:`tocontrol_ros.recording.mcap_io`):
  one topic ``/library/motion_<index>`` per solved motion with its one trajectory, QoS
  reliable and transient local like the planner's ``~/trajectory``.
- ``cell.csv``: the summary, one row per task in index order (see :data:`SUMMARY_COLUMNS`),
  for ``pandas.read_csv``; unfinished tasks have status ``PENDING``.
"""

from __future__ import annotations

import base64
import csv
import json
import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from builtin_interfaces.msg import Time

from tocontrol_ros.batch.tasks import Task, TaskFileError
from tocontrol_ros.nodes import conversions, qos
from tocontrol_ros.recording import mcap_io
from tocontrol_ros.recording.cdr import serialize_exact

__all__ = ["Journal", "library_paths", "trajectory_cdr", "write_library", "write_summary",
           "SUMMARY_COLUMNS", "TRAJECTORY_TYPE", "PENDING"]

TRAJECTORY_TYPE = "trajectory_msgs/msg/JointTrajectory"
TOPIC_PREFIX = "/library/"
PENDING = "PENDING"
#: Columns of the CSV summary.
SUMMARY_COLUMNS = ("index", "name", "topic", "status", "success", "T", "solve_time",
                   "iterations", "residual", "max_abs_u", "k", "reserve", "start_name",
                   "start_kind", "start", "target_name", "target_kind", "target", "attempts",
                   "worker", "message", "key")
_OUTCOME_FIELDS = ("status", "success", "message", "T", "solve_time", "iterations",
                   "residual", "max_abs_u", "attempts", "worker")


def library_paths(output) -> dict[str, Path]:
    """``mcap``, ``csv`` and ``journal`` paths of an output ``.mcap`` path."""
    output = Path(output)
    stem = output.with_suffix("") if output.suffix == ".mcap" else output
    return {"mcap": stem.with_suffix(".mcap"), "csv": stem.with_suffix(".csv"),
            "journal": stem.with_suffix(".journal.jsonl")}


def trajectory_cdr(sample: dict, joint_names, frame_id: str) -> bytes:
    """Exact CDR of the ``JointTrajectory`` of a worker's sample (see :func:`run_task`)."""
    msg = conversions.trajectory_msg(SimpleNamespace(**sample), joint_names, frame_id, Time())
    return serialize_exact(msg)


def _clean(value):
    """JSON-safe scalars (NaN becomes None: JSON has no NaN)."""
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


class Journal:
    """Append-only record of finished tasks of one task set (see the module docstring).

    Parameters
    ----------
    path : pathlib.Path
    fingerprint : str
        The task set's; an existing journal of another task set is refused.
    """

    def __init__(self, path, fingerprint: str) -> None:
        self.path = Path(path)
        self.entries: dict[str, dict] = {}
        self.torn = 0
        if self.path.exists():
            self._read(fingerprint)
            self._file = open(self.path, "a", encoding="utf-8")  # noqa: SIM115 (close())
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "x", encoding="utf-8")  # noqa: SIM115 (close())
            self._append({"journal": "tocontrol_ros batch", "fingerprint": fingerprint,
                          "created": time.time()})

    def _read(self, fingerprint: str) -> None:
        lines = self.path.read_bytes().split(b"\n")
        complete, last = lines[:-1], lines[-1]
        if last.strip():
            self.torn = 1  # killed mid-write: that task is planned again
        if not complete:
            raise TaskFileError(f"{self.path}: empty journal (delete it to start over)")
        header = json.loads(complete[0])
        if header.get("fingerprint") != fingerprint:
            raise TaskFileError(
                f"{self.path} belongs to another task set (fingerprint "
                f"{header.get('fingerprint')}, this task file {fingerprint}): the robot or the "
                "motions changed since that run; give another --output or delete the journal")
        for number, line in enumerate(complete[1:], start=2):
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                raise TaskFileError(f"{self.path}:{number}: corrupt journal line") from None
            self.entries.setdefault(entry["key"], entry)
        if self.torn:
            with open(self.path, "r+b") as f:  # drop the torn tail so appends stay lines
                f.truncate(sum(len(line) + 1 for line in complete))

    def _append(self, entry: dict) -> None:
        self._file.write(json.dumps(entry, separators=(",", ":")) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def record(self, task: Task, result: dict, attempts: int, cdr: bytes | None) -> bool:
        """Append a finished task; False (and nothing written) when it is recorded already."""
        if task.key in self.entries:
            return False
        entry = {"key": task.key, "index": task.index, "finished": time.time_ns(),
                 **{f: _clean(result.get(f)) for f in _OUTCOME_FIELDS if f != "attempts"},
                 "attempts": attempts, "worker": str(result.get("pid", "")),
                 "builds": result.get("builds"),  # models its worker built: 1 = once
                 "cdr": base64.b64encode(cdr).decode("ascii") if cdr else None}
        self._append(entry)
        self.entries[task.key] = entry
        return True

    def close(self) -> None:
        """Close the file."""
        self._file.close()


def _end_text(end) -> str:
    return json.dumps([round(v, 12) for v in end[1]])


def write_summary(path, tasks, entries: dict) -> None:
    """The CSV summary, one row per task (written aside, then renamed)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, SUMMARY_COLUMNS)
        writer.writeheader()
        for task in tasks:
            entry = entries.get(task.key, {"status": PENDING, "success": False})
            row = {c: entry.get(c) for c in _OUTCOME_FIELDS}
            row.update(index=task.index, name=task.name, key=task.key, k=task.k,
                       reserve=task.reserve, start_name=task.start_name,
                       start_kind=task.start[0], start=_end_text(task.start),
                       target_name=task.target_name, target_kind=task.target[0],
                       target=_end_text(task.target),
                       topic=TOPIC_PREFIX + task.name if entry.get("cdr") else "")
            writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    os.replace(tmp, path)


def write_library(path, tasks, entries: dict) -> int:
    """The MCAP library from the journal's entries; returns the motions written.

    Written to ``<path>.tmp`` and renamed, so a reader never sees a half-written library.
    """
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)  # left by a run killed while writing
    written = 0
    with mcap_io.RecordingWriter(tmp, compression="zstd") as writer:
        for task in tasks:
            entry = entries.get(task.key)
            if not entry or not entry.get("cdr"):
                continue
            topic = TOPIC_PREFIX + task.name
            writer.add_topic(topic, TRAJECTORY_TYPE, [qos.LATCHED])
            writer.write(topic, base64.b64decode(entry["cdr"]), entry["finished"],
                         sequence=task.index)
            written += 1
    os.replace(tmp, path)
    return written
