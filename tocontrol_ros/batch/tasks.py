"""Task files of the ``batch`` executable: YAML in, validated :class:`Task` objects out.

A task file names the robot, the planning settings and the motions::

    robot:                        # optional; no urdf: the bundled arm (config/galicki_3r.urdf)
      urdf: galicki_3r.urdf       # relative to the task file
      base_link: base             # optional, as load_robot takes them
      tip_link: tool
      locked_joints: {}
      task_axes: xy
      gravity: [0.0, 0.0, -9.80665]
    k: 4                          # a number, or a list: each motion planned for each k
    reserve: 0.0                  # torque reserve in [0, 1), a number or a list
    sample_period: 0.005          # s between the stored trajectory points
    solver: {starts: 16, candidates: 3, time_limit: 60}   # SolverOptions fields
    hard_timeout: 150             # s; default 2 time_limit + 30: the worker is stopped
    stations:                     # optional named ends
      feeder: {point: [1.0, 1.0]}
      press: {point: [2.2, 1.5]}
      home: {q: [0.3, 1.2, -0.4]} # joint state (qd optional, default 0)
    motions:
      - {start: feeder, target: press}
      - {start: {q: [0.1, 0.2, 0.3]}, target: {point: [2.2, 1.5]}, k: 8}
      - all_pairs: [feeder, press, home]   # every ordered pair; `all_pairs: all` = all stations

A motion may override ``k``, ``reserve``, ``hard_timeout`` and ``solver`` fields. The
solver stops itself at ``time_limit`` (status ``TIME_LIMIT``); ``hard_timeout`` is the
runner's backstop for a task that does not come back at all (status ``TIMEOUT``).
Each (motion, k, reserve) is one :class:`Task`. Every error is a :class:`TaskFileError`
that names the field (``motions[2].start.q``) and what was wrong; every task is checked by
building its :class:`~tocontrol_ros.core.types.problem.Problem` (reachable points, joint limits)
before any planning starts. No ROS import here: workers use this module too.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from tocontrol_ros.core.errors import TocontrolError

__all__ = ["TaskFileError", "RobotSpec", "Task", "TaskSet", "load_task_file", "parse_tasks",
           "build_problem", "load_model", "content_key"]

TOP_KEYS = ("robot", "k", "reserve", "sample_period", "hard_timeout", "solver", "stations",
            "motions")
ROBOT_KEYS = ("urdf", "base_link", "tip_link", "locked_joints", "task_axes", "gravity")
MOTION_KEYS = ("start", "target", "all_pairs", "k", "reserve", "hard_timeout", "solver")
#: Default spacing of the stored trajectory points (s): the planner's default sample period.
DEFAULT_SAMPLE_PERIOD = 0.005
#: Default hard timeout: HARD_TIMEOUT_FACTOR * time_limit + HARD_TIMEOUT_GRACE (s), far past
#: the solver's own stop, so that only a task that hangs or whose worker stalls reaches it.
HARD_TIMEOUT_FACTOR = 2.0
HARD_TIMEOUT_GRACE = 30.0


class TaskFileError(TocontrolError, ValueError):
    """An invalid task file; the message names the file and the field."""


@dataclass(frozen=True)
class RobotSpec:
    """The robot as workers rebuild it: the URDF text and :func:`load_robot`'s options.

    Attributes
    ----------
    urdf : str
        The URDF XML itself (workers on other machines need not see the file).
    source : str
        Where it came from, for messages.
    options : tuple of (str, object)
        Keyword arguments of :func:`~tocontrol_ros.core.robot.model.load_robot`, sorted.
    """

    urdf: str
    source: str
    options: tuple = ()


def content_key(item, skip: str) -> str:
    """A dataclass's identity: 16 hex digits of the SHA-256 of its fields but ``skip``.

    The fields as sorted JSON (values JSON cannot hold as their ``str``): the batch
    journal's and the memory build's log key their tasks by it, so a run again skips what
    is done.
    """
    body = {f.name: getattr(item, f.name) for f in dataclasses.fields(item) if f.name != skip}
    return hashlib.sha256(json.dumps(body, sort_keys=True, default=str).encode()
                          ).hexdigest()[:16]


@dataclass(frozen=True)
class Task:
    """One motion to plan (a unit of work).

    Attributes
    ----------
    index : int
        Position in the expanded task list (0-based); names the motion in the library.
    start, target : tuple of (str, tuple of float)
        ``("point", p)`` with ``p`` shape (m,) (m), or ``("state", q + qd)`` shape (2n,).
    start_name, target_name : str
        Station names ("" for ends written inline).
    k, reserve : float
    solver : tuple of (str, object)
        :class:`~tocontrol_ros.core.planning.solver.SolverOptions` fields, sorted.
    sample_period : float
        Spacing of the stored trajectory points (s).
    hard_timeout : float
        Wall time (s) after which the runner stops the task's worker and records it.
    where : str
        The entry of the task file it came from (``motions[3]``), for messages.
    """

    index: int
    start: tuple
    target: tuple
    start_name: str
    target_name: str
    k: float
    reserve: float
    solver: tuple
    sample_period: float
    hard_timeout: float
    where: str

    @property
    def key(self) -> str:
        """Identity of the task's content (everything but ``where``): 16 hex digits."""
        return content_key(self, "where")

    @property
    def name(self) -> str:
        """``motion_<index>`` (5 digits): the library's topic is ``/library/<name>``."""
        return f"motion_{self.index:05d}"


@dataclass(frozen=True)
class TaskSet:
    """A parsed task file: the robot and the expanded tasks.

    Attributes
    ----------
    robot : RobotSpec
    tasks : tuple of Task
    fingerprint : str
        Hash of the robot and every task: a journal belongs to one fingerprint.
    """

    robot: RobotSpec
    tasks: tuple[Task, ...]
    fingerprint: str


# ------------------------------------------------------------------ field checks
def _unknown(where: str, mapping: dict, allowed) -> None:
    extra = sorted(set(mapping) - set(allowed))
    if extra:
        raise TaskFileError(f"{where}: unknown key(s) {extra}; allowed: {sorted(allowed)}")


def _mapping(where: str, value) -> dict:
    if not isinstance(value, dict):
        raise TaskFileError(f"{where}: must be a mapping, got {type(value).__name__} {value!r}")
    return value


def _number(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TaskFileError(f"{where}: must be a number, got {value!r}")
    if not math.isfinite(value):
        raise TaskFileError(f"{where}: must be a finite number, got {value!r}")
    return float(value)


def _vector(where: str, value, size: int, what: str) -> tuple[float, ...]:
    if not isinstance(value, list):
        raise TaskFileError(f"{where}: must be a list of {size} numbers ({what}), got {value!r}")
    if len(value) != size:
        raise TaskFileError(f"{where}: expected {size} numbers ({what}), got {len(value)}")
    return tuple(_number(f"{where}[{i}]", v) for i, v in enumerate(value))


def _numbers(where: str, value) -> list[float]:
    """A number or a non-empty list of numbers."""
    if isinstance(value, list):
        if not value:
            raise TaskFileError(f"{where}: must be a number or a non-empty list of numbers")
        return [_number(f"{where}[{i}]", v) for i, v in enumerate(value)]
    return [_number(where, value)]


def _endpoint(where: str, value, model, stations: dict) -> tuple[str, tuple, str]:
    """(kind, values, station name) of a start or target."""
    if isinstance(value, str):
        if value not in stations:
            raise TaskFileError(f"{where}: no station named {value!r}; stations: "
                                f"{sorted(stations)}")
        kind, values, _ = stations[value]
        return kind, values, value
    value = _mapping(where, value)
    _unknown(where, value, ("point", "q", "qd"))
    if "point" in value:
        if set(value) != {"point"}:
            raise TaskFileError(f"{where}: give either `point` or `q` (with optional `qd`), "
                                f"not both")
        axes = "".join("xyz"[a] for a in model.task_axes)
        return "point", _vector(f"{where}.point", value["point"], model.m,
                                f"task-space {axes} in m"), ""
    if "q" not in value:
        raise TaskFileError(f"{where}: needs `point` (task space) or `q` (joint positions)")
    joints = ", ".join(model.joint_names)
    q = _vector(f"{where}.q", value["q"], model.n, f"joint positions of {joints}")
    qd = _vector(f"{where}.qd", value.get("qd", [0.0] * model.n), model.n,
                 f"joint velocities of {joints}")
    return "state", q + qd, ""


def _solver(where: str, value) -> dict:
    from tocontrol_ros.core.planning.solver import SolverOptions

    value = _mapping(where, value)
    _unknown(where, value, [f.name for f in dataclasses.fields(SolverOptions)])
    out = {}
    for name, v in value.items():
        out[name] = tuple(v) if isinstance(v, list) else v
    return out


def _solver_options(where: str, fields: dict):
    from tocontrol_ros.core.planning.solver import SolverOptions

    try:
        return SolverOptions(**fields)
    except TocontrolError as exc:
        raise TaskFileError(f"{where}: {exc}") from None


# ------------------------------------------------------------------ robot
def _robot(base: Path, value, label: str) -> RobotSpec:
    from tocontrol_ros.core.robot.model import default_urdf_path

    value = _mapping(f"{label}: robot", value if value is not None else {})
    _unknown(f"{label}: robot", value, ROBOT_KEYS)
    if value.get("urdf") is None:
        path = default_urdf_path()
    else:
        if not isinstance(value["urdf"], str):
            raise TaskFileError(f"{label}: robot.urdf: must be a path, got {value['urdf']!r}")
        path = (base / value["urdf"]).expanduser()
    if not path.is_file():
        raise TaskFileError(f"{label}: robot.urdf: no such file: {path}")
    options = {}
    for key in ("base_link", "tip_link"):
        if value.get(key) is not None:
            if not isinstance(value[key], str):
                raise TaskFileError(f"{label}: robot.{key}: must be a link name, got "
                                    f"{value[key]!r}")
            options[key] = value[key]
    if value.get("locked_joints"):
        locked = _mapping(f"{label}: robot.locked_joints", value["locked_joints"])
        options["locked_joints"] = tuple(sorted(
            (str(k), _number(f"{label}: robot.locked_joints.{k}", v)) for k, v in locked.items()))
    if value.get("task_axes") is not None:
        axes = value["task_axes"]
        options["task_axes"] = axes if isinstance(axes, str) else tuple(axes)
    if value.get("gravity") is not None:
        options["gravity"] = _vector(f"{label}: robot.gravity", value["gravity"], 3, "m/s^2")
    return RobotSpec(urdf=path.read_text(), source=str(path),
                     options=tuple(sorted(options.items())))


def load_model(robot: RobotSpec):
    """The :class:`~tocontrol_ros.core.robot.model.RobotModel` of a spec (a worker builds it once).

    Raises
    ------
    TaskFileError
        When :func:`load_robot` rejects the URDF or the options (message from the core).
    """
    from tocontrol_ros.core.robot.model import load_robot

    kwargs = dict(robot.options)
    if "locked_joints" in kwargs:
        kwargs["locked_joints"] = dict(kwargs["locked_joints"])
    try:
        return load_robot(robot.urdf, **kwargs)
    except TocontrolError as exc:
        raise TaskFileError(f"robot ({robot.source}): {exc}") from None


def build_problem(model, task: Task):
    """The core's :class:`~tocontrol_ros.core.types.problem.Problem` of a task."""
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    def end(spec):
        kind, values = spec
        if kind == "point":
            return point(values)
        return joint_state(values[:model.n], values[model.n:])

    return Problem(model, end(task.start), end(task.target), k=task.k, reserve=task.reserve)


# ------------------------------------------------------------------ the file
def parse_tasks(data, base: Path, label: str = "task file") -> tuple[TaskSet, object]:
    """Validate a loaded task file and expand its motions.

    Parameters
    ----------
    data : object
        The YAML document (a mapping).
    base : pathlib.Path
        Directory that relative URDF paths start from.
    label : str
        The file's name, for messages.

    Returns
    -------
    TaskSet
    RobotModel
        The model, loaded once here (the main process needs its joint names).

    Raises
    ------
    TaskFileError
        Naming the field: unknown keys, wrong counts, NaN, unknown stations, unreachable
        points, bad solver options.
    """
    data = _mapping(label, data)
    _unknown(label, data, TOP_KEYS)
    robot = _robot(base, data.get("robot"), label)
    model = load_model(robot)
    ks = _numbers(f"{label}: k", data.get("k", 1.0))
    reserves = _numbers(f"{label}: reserve", data.get("reserve", 0.0))
    period = _number(f"{label}: sample_period", data.get("sample_period", DEFAULT_SAMPLE_PERIOD))
    if period <= 0:
        raise TaskFileError(f"{label}: sample_period: must be positive (s), got {period!r}")
    solver = _solver(f"{label}: solver", data.get("solver") or {})
    _solver_options(f"{label}: solver", solver)
    stations = {}
    for name, value in _mapping(f"{label}: stations", data.get("stations") or {}).items():
        kind, values, _ = _endpoint(f"{label}: stations.{name}", value, model, {})
        stations[str(name)] = (kind, values, str(name))
    motions = data.get("motions")
    if not isinstance(motions, list) or not motions:
        raise TaskFileError(f"{label}: motions: must be a non-empty list of motions, got "
                            f"{motions!r}")
    tasks = []
    for i, entry in enumerate(motions):
        where = f"{label}: motions[{i}]"
        entry = _mapping(where, entry)
        _unknown(where, entry, MOTION_KEYS)
        pairs = _pairs(where, entry, model, stations)
        m_ks = _numbers(f"{where}.k", entry["k"]) if "k" in entry else ks
        m_reserves = _numbers(f"{where}.reserve", entry["reserve"]) if "reserve" in entry \
            else reserves
        m_solver = {**solver, **_solver(f"{where}.solver", entry.get("solver") or {})}
        options = _solver_options(f"{where}.solver", m_solver)
        hard = entry.get("hard_timeout", data.get("hard_timeout"))
        if hard is None:
            hard = HARD_TIMEOUT_FACTOR * options.time_limit + HARD_TIMEOUT_GRACE
        hard = _number(f"{where}.hard_timeout", hard)
        if hard <= 0:
            raise TaskFileError(f"{where}.hard_timeout: must be positive (s), got {hard!r}")
        for start, target in pairs:
            for k in m_ks:
                for reserve in m_reserves:
                    task = Task(index=len(tasks), start=start[:2], target=target[:2],
                                start_name=start[2], target_name=target[2], k=k,
                                reserve=reserve, solver=tuple(sorted(m_solver.items())),
                                sample_period=period, hard_timeout=hard, where=where)
                    _check_problem(model, task)
                    tasks.append(task)
    fingerprint = hashlib.sha256(json.dumps(
        [robot.urdf, robot.options, [t.key for t in tasks]], default=str).encode()).hexdigest()
    return TaskSet(robot=robot, tasks=tuple(tasks), fingerprint=fingerprint[:16]), model


def _pairs(where: str, entry: dict, model, stations: dict) -> list:
    if "all_pairs" in entry:
        if "start" in entry or "target" in entry:
            raise TaskFileError(f"{where}: give `all_pairs` or `start` and `target`, not both")
        names = entry["all_pairs"]
        if names == "all":
            names = list(stations)
        if not isinstance(names, list) or len(names) < 2:
            raise TaskFileError(f"{where}.all_pairs: must be `all` or a list of at least two "
                                f"stations or ends, got {names!r}")
        ends = [_endpoint(f"{where}.all_pairs[{j}]", v, model, stations)
                for j, v in enumerate(names)]
        return [(a, b) for a in ends for b in ends if a is not b]
    for key in ("start", "target"):
        if key not in entry:
            raise TaskFileError(f"{where}: missing `{key}` (or give `all_pairs`)")
    return [(_endpoint(f"{where}.start", entry["start"], model, stations),
             _endpoint(f"{where}.target", entry["target"], model, stations))]


def _check_problem(model, task: Task) -> None:
    names = (f" ({task.start_name or 'inline'} -> {task.target_name or 'inline'})"
             if task.start_name or task.target_name else "")
    try:
        build_problem(model, task)
    except TocontrolError as exc:
        raise TaskFileError(f"{task.where}{names}, k = {task.k:g}, reserve = "
                            f"{task.reserve:g}: {exc}") from None


def load_task_file(path) -> tuple[TaskSet, object]:
    """Read and validate a task file (see the module docstring); see :func:`parse_tasks`."""
    path = Path(path)
    if not path.is_file():
        raise TaskFileError(f"task file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise TaskFileError(f"{path}: not valid YAML: {exc}") from None
    return parse_tasks(data, path.resolve().parent, label=str(path))
