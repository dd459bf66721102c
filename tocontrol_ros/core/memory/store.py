"""The memory file: one SQLite database (standard library, WAL mode) of certified motions.

Tables:

- ``meta`` (``key``, ``value``): ``format`` (:data:`FORMAT`), ``robot_hash`` and
  ``options_hash`` (:mod:`~tocontrol_ros.core.memory.keys`), ``robot`` (name and joint
  names, JSON), ``options`` (the problem class, JSON), ``created`` (Unix time), ``cell``
  (what the build was asked, JSON; empty for a memory the planner grew by itself).
- ``entries``: one row per motion: the request (``start_kind``, ``start``, ``target_kind``,
  ``target``: float64 vectors as bytes; ``start_point``, ``target_point``: the end-effector
  points, m), the end configuration ``end_q`` (rad; what tells basins apart), the certified
  result's summary (``T`` s, ``status``, ``method``, ``certificate``: JSON of its figures
  and verdict), the warm state (``warm_kind``, ``warm``: npz,
  :mod:`~tocontrol_ros.core.memory.codec`), the sampled joint trajectory (``trajectory``:
  npz), ``source`` (``build``, ``planner``...), ``solve_time`` (s), ``created``, and
  ``serve``: the same motion re-solved on the serving mesh (uniform spans) with its NLP
  multipliers (npz, kind ``path``; NULL until converted,
  :mod:`~tocontrol_ros.core.memory.serve`): what a hit continues.
  ``key`` (the request's hash) is unique: the same request stored twice keeps the lower T.
- ``tasks``: the build's log, one row per finished task of a cell (its key, status,
  message, ``T``, ``solve_time``, worker): a build run again skips them (resumable).

Opening checks everything before a motion is served: the file exists (unless created), is
a database of this format, and was made for this robot and these options; anything else
is a :class:`MemoryFileError` whose message says which and why (a file of an older format
names the command that upgrades it: :func:`upgrade_format`). Writers wait up to
:data:`BUSY_TIMEOUT` for a lock (WAL lets readers go on meanwhile), so two processes
writing one memory lose nothing; a lock held longer is an error, not a wait forever.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["MemoryFileError", "MotionStore", "StoredMotion", "Request", "FORMAT",
           "OLD_FORMATS", "BUSY_TIMEOUT", "request_key", "upgrade_format"]

#: The file format this code reads and writes (``meta.format``). Version 2 added the
#: column ``serve`` (the serving mesh's warm state).
FORMAT = "tocontrol_ros motion memory 2"
#: Formats :func:`upgrade_format` turns into :data:`FORMAT` (what the upgrade adds).
OLD_FORMATS = {"tocontrol_ros motion memory 1": "ALTER TABLE entries ADD COLUMN serve BLOB"}
#: How a user upgrades an old file (named in the error).
UPGRADE_COMMAND = "ros2 run tocontrol_ros memory upgrade FILE CELL.yaml"
#: Longest wait for another writer's lock (s): a build's commit takes milliseconds, so
#: longer means a stuck process, reported rather than waited for.
BUSY_TIMEOUT = 10.0
#: Decimals of the request's values in its key (1e-9 rad or m: the same request twice).
KEY_DECIMALS = 9

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS entries (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    key TEXT NOT NULL UNIQUE,
    start_kind TEXT NOT NULL, start BLOB NOT NULL,
    target_kind TEXT NOT NULL, target BLOB NOT NULL,
    start_point BLOB NOT NULL, target_point BLOB NOT NULL, end_q BLOB NOT NULL,
    T REAL NOT NULL, status TEXT NOT NULL, method TEXT NOT NULL,
    certificate TEXT NOT NULL,
    warm_kind TEXT NOT NULL, warm BLOB NOT NULL, trajectory BLOB NOT NULL,
    source TEXT NOT NULL, solve_time REAL NOT NULL, created REAL NOT NULL,
    serve BLOB
);
CREATE TABLE IF NOT EXISTS tasks (
    key TEXT PRIMARY KEY, status TEXT NOT NULL, message TEXT NOT NULL, T REAL,
    solve_time REAL, worker TEXT NOT NULL, finished REAL NOT NULL
);
"""
_KEY_COLUMNS = ("id", "start_kind", "start", "target_kind", "target", "start_point",
                "target_point", "end_q", "T", "serve IS NOT NULL")


class MemoryFileError(TocontrolError, OSError):
    """A memory file that cannot be used; the message names the file and the reason."""


@dataclass(frozen=True)
class Request:
    """A stored request: ``kind`` ("point" or "state") and ``value`` of each end.

    ``start``/``target``: shape (m,) for a point (m), (2n,) for a joint state (rad, rad/s).
    """

    start_kind: str
    start: np.ndarray
    target_kind: str
    target: np.ndarray


@dataclass(frozen=True)
class StoredMotion:
    """One entry of the memory (see the module docstring for the fields)."""

    id: int
    key: str
    request: Request
    start_point: np.ndarray
    target_point: np.ndarray
    end_q: np.ndarray
    T: float
    status: str
    method: str
    certificate: dict
    warm_kind: str
    warm: bytes
    trajectory: bytes
    source: str
    solve_time: float
    created: float
    serve: bytes | None = None


def _vec(blob) -> np.ndarray:
    return np.frombuffer(bytes(blob), dtype="<f8").copy()


def _blob(a) -> bytes:
    return np.ascontiguousarray(np.asarray(a, dtype="<f8").ravel()).tobytes()


def request_key(request: Request) -> str:
    """The request's identity (16 hex digits): its kinds and values to 1e-9."""
    body = [request.start_kind, np.round(request.start, KEY_DECIMALS).tolist(),
            request.target_kind, np.round(request.target, KEY_DECIMALS).tolist()]
    return hashlib.sha256(json.dumps(body).encode()).hexdigest()[:16]


class MotionStore:
    """An open memory file (see the module docstring).

    Parameters
    ----------
    path : str or Path
    robot_hash, options_hash : str or None
        What the caller plans for; a file made for others is refused. None: accept any
        (the command-line tools, which only read, list and prune).
    create : bool
        Make the file when it does not exist (then both hashes must be given).
    meta : dict, optional
        More ``meta`` entries for a new file (``robot``, ``options``, ``cell``: JSON-able).

    Raises
    ------
    MemoryFileError
        Missing, not a memory (or corrupt), another format, another robot or options,
        locked beyond :data:`BUSY_TIMEOUT`.
    """

    def __init__(self, path, robot_hash: str | None = None, options_hash: str | None = None,
                 create: bool = False, meta: dict | None = None) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._keys = None
        self._version = None
        if not self.path.exists() and not create:
            raise MemoryFileError(f"memory {self.path}: no such file")
        if create and (robot_hash is None or options_hash is None):
            raise MemoryFileError(f"memory {self.path}: a new memory needs both hashes")
        try:
            self._db = sqlite3.connect(str(self.path), timeout=BUSY_TIMEOUT,
                                       check_same_thread=False, isolation_level=None)
        except sqlite3.Error as exc:
            raise MemoryFileError(f"memory {self.path}: cannot be opened ({exc})") from None
        try:
            self._open(robot_hash, options_hash, create, meta or {})
        except sqlite3.DatabaseError as exc:
            self._db.close()
            raise MemoryFileError(f"memory {self.path}: {_reason(exc)}") from None
        except MemoryFileError:
            self._db.close()
            raise

    def _open(self, robot_hash, options_hash, create, meta) -> None:
        db = self._db
        db.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT * 1000)}")
        mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise MemoryFileError(f"memory {self.path}: WAL mode refused (journal mode {mode})")
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "meta" not in tables:
            if not create:
                raise MemoryFileError(f"memory {self.path}: not a motion memory (no meta "
                                      "table)")
            db.execute("BEGIN IMMEDIATE")
            try:
                for statement in _SCHEMA.split(";"):
                    if statement.strip():
                        db.execute(statement)
                values = {"format": FORMAT, "robot_hash": robot_hash,
                          "options_hash": options_hash, "created": repr(time.time()),
                          **{k: json.dumps(v) for k, v in meta.items()}}
                db.executemany("INSERT OR IGNORE INTO meta VALUES (?, ?)", values.items())
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise
        self.meta = dict(db.execute("SELECT key, value FROM meta"))
        if self.meta.get("format") in OLD_FORMATS:
            raise MemoryFileError(f"memory {self.path}: format {self.meta['format']!r}, "
                                  f"this planner reads {FORMAT!r}; upgrade it (its motions "
                                  f"re-solved on the serving mesh): {UPGRADE_COMMAND}")
        if self.meta.get("format") != FORMAT:
            raise MemoryFileError(f"memory {self.path}: format {self.meta.get('format')!r}, "
                                  f"this planner reads {FORMAT!r}")
        for name, want in (("robot_hash", robot_hash), ("options_hash", options_hash)):
            have = self.meta.get(name)
            if want is not None and have != want:
                what = "robot" if name == "robot_hash" else "options (k, reserve, joint " \
                    "limits and margin, method)"
                raise MemoryFileError(
                    f"memory {self.path}: made for another {what}: its {name} is {have}, "
                    f"this planner's {want}; {self._describe(name)}")

    def _describe(self, name: str) -> str:
        key = "robot" if name == "robot_hash" else "options"
        return f"the memory's {key}: {self.meta.get(key, 'not recorded')}"

    # ------------------------------------------------------------------ writing
    def add(self, request: Request, *, start_point, target_point, end_q, T: float,
            status: str, method: str, certificate: dict, warm_kind: str, warm: bytes,
            trajectory: bytes, source: str, solve_time: float,
            serve: bytes | None = None) -> bool:
        """Store one motion; False when the same request is stored with a ``T`` as low.

        ``serve``: its warm state on the serving mesh (None: not converted yet).

        Raises
        ------
        MemoryFileError
            Locked beyond :data:`BUSY_TIMEOUT`, read-only, or disk full.
        """
        if not (np.isfinite(T) and T >= 0):
            raise MemoryFileError(f"memory {self.path}: `T` must be finite and >= 0, got {T!r}")
        row = (request_key(request), request.start_kind, _blob(request.start),
               request.target_kind, _blob(request.target), _blob(start_point),
               _blob(target_point), _blob(end_q), float(T), status, method,
               json.dumps(certificate, default=_jsonable), warm_kind, bytes(warm),
               bytes(trajectory), source, float(solve_time), time.time(),
               None if serve is None else bytes(serve))
        sql = ("INSERT INTO entries (key, start_kind, start, target_kind, target, start_point, "
               "target_point, end_q, T, status, method, certificate, warm_kind, warm, "
               "trajectory, source, solve_time, created, serve) VALUES "
               "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
               "ON CONFLICT(key) DO UPDATE SET T = excluded.T, status = excluded.status, "
               "method = excluded.method, certificate = excluded.certificate, "
               "end_q = excluded.end_q, warm_kind = excluded.warm_kind, "
               "warm = excluded.warm, trajectory = excluded.trajectory, "
               "source = excluded.source, solve_time = excluded.solve_time, "
               "created = excluded.created, serve = excluded.serve "
               "WHERE excluded.T < entries.T")
        with self._lock:
            self._keys = None  # this connection's writes leave its data_version as it was
            try:
                changed = self._db.execute(sql, row).rowcount
            except sqlite3.DatabaseError as exc:
                raise MemoryFileError(f"memory {self.path}: cannot store the motion "
                                      f"({_reason(exc)})") from None
        return changed > 0

    def set_serve(self, entry_id: int, serve: bytes | None) -> bool:
        """Store (or clear, None) an entry's serving-mesh warm state; False: no such entry.

        Raises
        ------
        MemoryFileError
            Locked beyond :data:`BUSY_TIMEOUT`, read-only, or disk full.
        """
        with self._lock:
            self._keys = None
            try:
                return self._db.execute(
                    "UPDATE entries SET serve = ? WHERE id = ?",
                    (None if serve is None else bytes(serve), int(entry_id))).rowcount > 0
            except sqlite3.DatabaseError as exc:
                raise MemoryFileError(f"memory {self.path}: cannot store the serving state "
                                      f"({_reason(exc)})") from None

    def log_task(self, key: str, status: str, message: str, T: float, solve_time: float,
                 worker: str = "") -> bool:
        """Record a finished build task; False when it was recorded already."""
        with self._lock:
            try:
                return self._db.execute(
                    "INSERT OR IGNORE INTO tasks VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (key, status, message, T if T is not None and np.isfinite(T) else None,
                     solve_time, worker, time.time())).rowcount > 0
            except sqlite3.DatabaseError as exc:
                raise MemoryFileError(f"memory {self.path}: cannot log the task "
                                      f"({_reason(exc)})") from None

    def tasks(self) -> dict[str, dict]:
        """The build's log: key -> ``status``, ``message``, ``T``, ``solve_time``, ``worker``."""
        with self._lock:
            rows = self._db.execute("SELECT key, status, message, T, solve_time, worker, "
                                    "finished FROM tasks").fetchall()
        return {r[0]: {"status": r[1], "message": r[2], "T": r[3], "solve_time": r[4],
                       "worker": r[5], "finished": r[6]} for r in rows}

    def forget_failed(self) -> int:
        """Drop the build log's failed tasks (a build run again retries them); the count."""
        with self._lock:
            return self._db.execute(
                "DELETE FROM tasks WHERE key NOT IN (SELECT t.key FROM tasks t WHERE "
                "t.status IN ('SUCCESS', 'TRIVIAL'))").rowcount

    def delete(self, ids) -> int:
        """Remove the entries ``ids``; the count removed."""
        ids = [int(i) for i in ids]
        with self._lock:
            self._keys = None
            try:
                self._db.execute("BEGIN IMMEDIATE")
                n = sum(self._db.execute("DELETE FROM entries WHERE id = ?", (i,)).rowcount
                        for i in ids)
                self._db.execute("COMMIT")
            except sqlite3.DatabaseError as exc:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise MemoryFileError(f"memory {self.path}: cannot delete ({_reason(exc)})"
                                      ) from None
        return n

    def vacuum(self) -> None:
        """Give the space of deleted entries back (after a prune)."""
        with self._lock:
            self._keys = None
            self._db.execute("VACUUM")

    # ------------------------------------------------------------------ reading
    def count(self) -> int:
        """How many motions are stored."""
        with self._lock:
            return int(self._db.execute("SELECT count(*) FROM entries").fetchone()[0])

    def keys(self) -> dict:
        """Every entry's lookup data as arrays (re-read only when the file changed).

        Kept between calls: read again after this store's own writes, or when another
        connection (another process's, another node's) committed a change to the file
        (SQLite's ``PRAGMA data_version``).

        Returns
        -------
        dict
            ``id`` (E,), ``start_kind``, ``target_kind`` (lists of E str), ``start``,
            ``target`` (lists of E vectors), ``start_point``, ``target_point`` (E, 3 or m),
            ``end_q`` (E, n), ``T`` (E,), ``serve`` (E,) bool: a serving-mesh state is
            stored.
        """
        with self._lock:
            try:
                # Changed by another connection (PRAGMA data_version) or by this one's
                # writes (which drop the keys): a summary of the rows read every row, its
                # blobs' overflow pages too (3-12 ms for the Panda cell's 215 motions).
                version = self._db.execute("PRAGMA data_version").fetchone()
                if self._keys is not None and version == self._version:
                    return self._keys
                rows = self._db.execute(
                    f"SELECT {', '.join(_KEY_COLUMNS)} FROM entries ORDER BY id").fetchall()
            except sqlite3.DatabaseError as exc:
                raise MemoryFileError(f"memory {self.path}: cannot be read ({_reason(exc)})"
                                      ) from None
        cols = list(zip(*rows, strict=True)) if rows else [[] for _ in _KEY_COLUMNS]
        keys = {"id": np.array(cols[0], dtype=np.int64),
                "start_kind": list(cols[1]), "start": [_vec(b) for b in cols[2]],
                "target_kind": list(cols[3]), "target": [_vec(b) for b in cols[4]],
                "T": np.array(cols[8], dtype=float),
                "serve": np.array(cols[9], dtype=bool)}
        for i, name in ((5, "start_point"), (6, "target_point"), (7, "end_q")):
            vecs = [_vec(b) for b in cols[i]]
            keys[name] = np.array(vecs) if vecs else np.zeros((0, 0))
        self._keys, self._version = keys, version
        return keys

    def get(self, entry_id: int) -> StoredMotion:
        """One entry by id; raises :class:`MemoryFileError` when there is none."""
        with self._lock:
            try:
                row = self._db.execute("SELECT * FROM entries WHERE id = ?",
                                       (int(entry_id),)).fetchone()
                names = [d[0] for d in self._db.execute(
                    "SELECT * FROM entries LIMIT 0").description]
            except sqlite3.DatabaseError as exc:
                raise MemoryFileError(f"memory {self.path}: cannot be read ({_reason(exc)})"
                                      ) from None
        if row is None:
            raise MemoryFileError(f"memory {self.path}: no entry {entry_id}")
        r = dict(zip(names, row, strict=True))
        return StoredMotion(
            id=r["id"], key=r["key"],
            request=Request(r["start_kind"], _vec(r["start"]), r["target_kind"],
                            _vec(r["target"])),
            start_point=_vec(r["start_point"]), target_point=_vec(r["target_point"]),
            end_q=_vec(r["end_q"]), T=float(r["T"]), status=r["status"], method=r["method"],
            certificate=json.loads(r["certificate"]), warm_kind=r["warm_kind"],
            warm=bytes(r["warm"]), trajectory=bytes(r["trajectory"]), source=r["source"],
            solve_time=float(r["solve_time"]), created=float(r["created"]),
            serve=None if r["serve"] is None else bytes(r["serve"]))

    def summary(self) -> list[dict]:
        """One small dict per entry (no blobs): id, kinds, points, T, status, method, sizes."""
        with self._lock:
            rows = self._db.execute(
                "SELECT id, start_kind, start_point, target_point, T, status, method, source, "
                "solve_time, length(warm) + length(trajectory) + coalesce(length(serve), 0) "
                "FROM entries ORDER BY id"
            ).fetchall()
        return [{"id": r[0], "start_kind": r[1], "start_point": _vec(r[2]),
                 "target_point": _vec(r[3]), "T": r[4], "status": r[5], "method": r[6],
                 "source": r[7], "solve_time": r[8], "bytes": r[9]} for r in rows]

    def close(self) -> None:
        """Close the connection (the WAL is checkpointed by SQLite)."""
        with self._lock:
            self._db.close()

    def __enter__(self) -> MotionStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def upgrade_format(path, robot_hash: str | None = None,
                   options_hash: str | None = None) -> str | None:
    """Bring a memory file of an older format (:data:`OLD_FORMATS`) to :data:`FORMAT`.

    In one transaction: the columns the newer format adds (empty: an upgraded file's motions
    have no serving state until :func:`~tocontrol_ros.core.memory.serve.convert` fills it)
    and ``meta.format``. Nothing is done to a file of this format, nor to one made for
    another robot or options than the hashes given (None: not checked).

    Returns
    -------
    str or None
        The format the file had when it was upgraded; None when it was current.

    Raises
    ------
    MemoryFileError
        No such file, not a memory, an unknown format, or locked.
    """
    path = Path(path)
    if not path.exists():
        raise MemoryFileError(f"memory {path}: no such file")
    db = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT, isolation_level=None)
    try:
        db.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT * 1000)}")
        db.execute("BEGIN IMMEDIATE")
        try:
            row = db.execute("SELECT value FROM meta WHERE key = 'format'").fetchone()
        except sqlite3.OperationalError:
            row = None
        have = None if row is None else row[0]
        if have == FORMAT:
            db.execute("ROLLBACK")
            return None
        if have not in OLD_FORMATS:
            db.execute("ROLLBACK")
            raise MemoryFileError(f"memory {path}: not a motion memory of a known format "
                                  f"({have!r}; this planner reads {FORMAT!r})")
        meta = dict(db.execute("SELECT key, value FROM meta"))
        for name, want in (("robot_hash", robot_hash), ("options_hash", options_hash)):
            if want is not None and meta.get(name) != want:
                db.execute("ROLLBACK")
                raise MemoryFileError(f"memory {path}: made for another "
                                      f"{name.split('_')[0]}: its {name} is "
                                      f"{meta.get(name)}, this planner's {want}")
        db.execute(OLD_FORMATS[have])
        db.execute("UPDATE meta SET value = ? WHERE key = 'format'", (FORMAT,))
        db.execute("COMMIT")
        return have
    except sqlite3.DatabaseError as exc:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise MemoryFileError(f"memory {path}: cannot be upgraded ({_reason(exc)})") from None
    finally:
        db.close()


def _reason(exc: sqlite3.Error) -> str:
    text = str(exc)
    if "locked" in text or "busy" in text:
        return (f"locked by another process for more than {BUSY_TIMEOUT:g} s ({text})")
    if "not a database" in text or "malformed" in text or "corrupt" in text:
        return f"corrupt or not a database ({text})"
    return text


def _jsonable(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
