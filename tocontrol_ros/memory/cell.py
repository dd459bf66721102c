"""Cell files of the ``memory`` tool: the robot, the starts, the target region, the options.

A cell file (YAML) describes the region a memory covers::

    robot:
      urdf: example-robot-data:panda   # a URDF path (relative to this file), or an
                                       # example-robot-data robot by name
      tip_link: panda_hand             # base_link, locked_joints, task_axes, gravity too
      joint_limits: limits.yaml        # optional MoveIt joint_limits.yaml (as the planner's)
      limit_margin: 0.0                # as the planner's parameter
    k: 4
    reserve: 0.1                       # the planner's default
    method: auto
    sample_period: 0.005               # s between the stored trajectory's samples
    solver: {starts: 24, candidates: 8, time_limit: 120}   # the build's (wider) search
    hard_timeout: 300                  # s; default 2 time_limit + 30
    starts:
      stations:                        # named starts: a joint state or a point
        home: {q: [0, -0.3, 0, -2.2, 0, 2.0, 0.8]}
        tray: {point: [0.3, 0.4, 0.3]}
      boxes:                           # joint-space boxes, sampled (rest states)
        - {lower: [...], upper: [...], count: 10, seed: 0}
    targets:
      boxes:                           # task-space boxes, a grid at `spacing` (m)
        - {lower: [0.3, -0.2, 0.2], upper: [0.7, 0.2, 0.5], spacing: 0.1}
      points: [[0.5, 0.0, 0.4]]

Every start is paired with every target: one task each. The density is the targets'
``spacing`` (a grid that includes both corners; each axis gets ``ceil(extent / spacing) + 1``
points) and the start boxes' ``count``. The problem class (``k``, ``reserve``, the limits and
their margin, ``method``) is what a planner must have for the memory to serve it (the
options' hash); ``solver`` is only how widely the build searches. Errors are
:class:`~tocontrol_ros.batch.tasks.TaskFileError` naming the field.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tocontrol_ros.batch.tasks import (
    HARD_TIMEOUT_FACTOR,
    HARD_TIMEOUT_GRACE,
    RobotSpec,
    TaskFileError,
    content_key,
    load_model,
)
from tocontrol_ros.core.errors import TocontrolError

__all__ = ["Cell", "MotionTask", "load_cell", "parse_cell", "example_robot_data_urdf",
           "task_problem", "cell_problem"]

TOP_KEYS = ("robot", "k", "reserve", "method", "sample_period", "solver", "hard_timeout",
            "starts", "targets")
ROBOT_KEYS = ("urdf", "base_link", "tip_link", "locked_joints", "task_axes", "gravity",
              "joint_limits", "limit_margin")
ERD_PREFIX = "example-robot-data:"
#: Most tasks a cell may expand to (a typo in a spacing must not start a week's build).
MAX_TASKS = 100_000


@dataclass(frozen=True)
class MotionTask:
    """One motion of a cell (the batch runner's unit of work).

    Attributes
    ----------
    index : int
    start, target : tuple
        ``("point", p)`` (m) or ``("state", q + qd)`` (rad, rad/s).
    start_name : str
        The station's name, or ``box<i>[<j>]``.
    k, reserve : float
    limits : tuple
        ``(names, lower, upper, velocity, margin)`` as tuples: the planner's limits.
    method : str
    solver : tuple of (str, object)
        The build's SolverOptions fields.
    sample_period, hard_timeout : float
        s.
    """

    index: int
    start: tuple
    target: tuple
    start_name: str
    k: float
    reserve: float
    limits: tuple
    method: str
    solver: tuple
    sample_period: float
    hard_timeout: float

    @property
    def key(self) -> str:
        """The task's identity (16 hex digits) over everything but ``index``."""
        return content_key(self, "index")


@dataclass(frozen=True)
class Cell:
    """A parsed cell file: the robot, its model, the tasks, what was asked."""

    robot: RobotSpec
    model: object
    limits: object
    tasks: tuple[MotionTask, ...]
    k: float
    reserve: float
    method: str
    description: dict


def example_robot_data_urdf(name: str) -> Path:
    """The URDF of example-robot-data's robot ``name`` (``panda``, ``ur5``...).

    Raises
    ------
    TaskFileError
        example-robot-data is not installed, or has no such robot (the known names listed).
    """
    roots = [Path(d) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
             for d in sys.path if d]
    root = next((r for r in roots if r.is_dir()), None)
    if root is None:
        raise TaskFileError(f"robot.urdf: {ERD_PREFIX}{name}: example-robot-data is not "
                            "installed (pip install example-robot-data)")
    path = root / f"{name}_description" / "urdf" / f"{name}.urdf"
    if not path.is_file():
        known = sorted(p.parent.parent.name.removesuffix("_description")
                       for p in root.glob("*_description/urdf/*.urdf")
                       if p.stem == p.parent.parent.name.removesuffix("_description"))
        raise TaskFileError(f"robot.urdf: {ERD_PREFIX}{name}: no such robot in "
                            f"example-robot-data; known: {known}")
    return path


def _mapping(where, value) -> dict:
    if not isinstance(value, dict):
        raise TaskFileError(f"{where}: must be a mapping, got {value!r}")
    return value


def _unknown(where, mapping, allowed) -> None:
    extra = sorted(set(mapping) - set(allowed))
    if extra:
        raise TaskFileError(f"{where}: unknown key(s) {extra}; allowed: {sorted(allowed)}")


def _number(where, value, low=-math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or value < low:
        raise TaskFileError(f"{where}: must be a finite number >= {low:g}, got {value!r}")
    return float(value)


def _vector(where, value, size, what) -> np.ndarray:
    if not isinstance(value, list) or len(value) != size:
        raise TaskFileError(f"{where}: must be a list of {size} numbers ({what}), got {value!r}")
    return np.array([_number(f"{where}[{i}]", v) for i, v in enumerate(value)])


def _robot(base: Path, value, label: str) -> tuple[RobotSpec, dict]:
    value = _mapping(f"{label}: robot", value)
    _unknown(f"{label}: robot", value, ROBOT_KEYS)
    urdf = value.get("urdf")
    if not isinstance(urdf, str) or not urdf:
        raise TaskFileError(f"{label}: robot.urdf: must be a path or "
                            f"'{ERD_PREFIX}NAME', got {urdf!r}")
    path = example_robot_data_urdf(urdf[len(ERD_PREFIX):]) if urdf.startswith(ERD_PREFIX) \
        else (base / urdf).expanduser()
    if not path.is_file():
        raise TaskFileError(f"{label}: robot.urdf: no such file: {path}")
    options = {}
    for key in ("base_link", "tip_link"):
        if value.get(key) is not None:
            options[key] = str(value[key])
    if value.get("locked_joints"):
        locked = _mapping(f"{label}: robot.locked_joints", value["locked_joints"])
        options["locked_joints"] = tuple(sorted(
            (str(k), _number(f"{label}: robot.locked_joints.{k}", v)) for k, v in locked.items()))
    if value.get("task_axes") is not None:
        axes = value["task_axes"]
        options["task_axes"] = axes if isinstance(axes, str) else tuple(axes)
    if value.get("gravity") is not None:
        options["gravity"] = tuple(_vector(f"{label}: robot.gravity", value["gravity"], 3,
                                           "m/s^2"))
    extra = {"joint_limits": None, "limit_margin": 0.0}
    if value.get("joint_limits") is not None:
        limits_path = (base / str(value["joint_limits"])).expanduser()
        if not limits_path.is_file():
            raise TaskFileError(f"{label}: robot.joint_limits: no such file: {limits_path}")
        extra["joint_limits"] = limits_path
    if value.get("limit_margin") is not None:
        extra["limit_margin"] = _number(f"{label}: robot.limit_margin", value["limit_margin"],
                                        0.0)
    return RobotSpec(urdf=path.read_text(), source=str(path),
                     options=tuple(sorted(options.items()))), extra


def _limits(model, extra: dict, label: str):
    from tocontrol_ros.core.robot.limits import JointLimits, load_joint_limits_yaml

    limits = JointLimits.from_model(model)
    try:
        if extra["joint_limits"] is not None:
            # As the planner's `joint_limits` parameter narrows them (planner_limits).
            limits = limits.narrowed(load_joint_limits_yaml(extra["joint_limits"]),
                                     f"`joint_limits` file {str(extra['joint_limits'])!r}")
        return limits.with_margin(extra["limit_margin"])
    except TocontrolError as exc:
        raise TaskFileError(f"{label}: robot.joint_limits: {exc}") from None


def _end(where, value, model) -> tuple:
    value = _mapping(where, value)
    _unknown(where, value, ("point", "q", "qd"))
    if "point" in value:
        return ("point", tuple(_vector(f"{where}.point", value["point"], model.m, "m")))
    if "q" not in value:
        raise TaskFileError(f"{where}: needs `point` (m) or `q` (rad)")
    q = _vector(f"{where}.q", value["q"], model.n, "rad")
    qd = _vector(f"{where}.qd", value.get("qd", [0.0] * model.n), model.n, "rad/s")
    return ("state", tuple(q) + tuple(qd))


def _starts(where, value, model) -> list[tuple[str, tuple]]:
    value = _mapping(where, value)
    _unknown(where, value, ("stations", "boxes"))
    out = []
    for name, end in _mapping(f"{where}.stations", value.get("stations") or {}).items():
        out.append((str(name), _end(f"{where}.stations.{name}", end, model)))
    for i, box in enumerate(value.get("boxes") or []):
        w = f"{where}.boxes[{i}]"
        box = _mapping(w, box)
        _unknown(w, box, ("lower", "upper", "count", "seed"))
        lo = _vector(f"{w}.lower", box.get("lower"), model.n, "rad")
        hi = _vector(f"{w}.upper", box.get("upper"), model.n, "rad")
        if np.any(hi < lo):
            raise TaskFileError(f"{w}: upper must be >= lower in every joint")
        count = box.get("count")
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise TaskFileError(f"{w}.count: must be an integer >= 1, got {count!r}")
        rng = np.random.default_rng(int(box.get("seed", 0)))
        for j in range(count):
            q = lo + rng.uniform(0.0, 1.0, model.n) * (hi - lo)
            out.append((f"box{i}[{j}]", ("state", tuple(q) + (0.0,) * model.n)))
    if not out:
        raise TaskFileError(f"{where}: no start (give stations and/or boxes)")
    return out


def _targets(where, value, model) -> list[tuple]:
    value = _mapping(where, value)
    _unknown(where, value, ("boxes", "points"))
    out = []
    for i, box in enumerate(value.get("boxes") or []):
        w = f"{where}.boxes[{i}]"
        box = _mapping(w, box)
        _unknown(w, box, ("lower", "upper", "spacing"))
        lo = _vector(f"{w}.lower", box.get("lower"), model.m, "m")
        hi = _vector(f"{w}.upper", box.get("upper"), model.m, "m")
        if np.any(hi < lo):
            raise TaskFileError(f"{w}: upper must be >= lower on every axis")
        spacing = _number(f"{w}.spacing", box.get("spacing"), 1e-4)
        counts = [int(math.ceil((b - a) / spacing - 1e-9)) + 1
                  for a, b in zip(lo, hi, strict=True)]
        if math.prod(counts) > MAX_TASKS:
            raise TaskFileError(f"{w}: {math.prod(counts)} grid points; at most {MAX_TASKS}")
        axes = [np.linspace(a, b, c) for a, b, c in zip(lo, hi, counts, strict=True)]
        for p in np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, model.m):
            out.append(("point", tuple(float(v) for v in p)))
    for i, p in enumerate(value.get("points") or []):
        out.append(("point", tuple(_vector(f"{where}.points[{i}]", p, model.m, "m"))))
    if not out:
        raise TaskFileError(f"{where}: no target (give boxes and/or points)")
    return out


def cell_problem(cell: Cell, task: MotionTask):
    """The core's problem of one task (the model and limits of the cell)."""
    return task_problem(cell.model, cell.limits, task)


def task_problem(model, limits, task: MotionTask):
    """The core's problem of one task on ``model`` within ``limits``."""
    from tocontrol_ros.core.types.problem import Problem, joint_state, point

    def end(spec):
        kind, values = spec
        return point(values) if kind == "point" else \
            joint_state(values[:model.n], values[model.n:])

    return Problem(model, end(task.start), end(task.target), k=task.k, reserve=task.reserve,
                   limits=limits)


def parse_cell(data, base: Path, label: str = "cell file") -> Cell:
    """Validate a loaded cell file and expand its tasks (see the module docstring).

    Raises
    ------
    TaskFileError
        Naming the field; also for an unreachable target or a start outside the limits
        (each task's problem is built before any planning).
    """
    from tocontrol_ros.core.planning.solver import SolverOptions

    data = _mapping(label, data)
    _unknown(label, data, TOP_KEYS)
    robot, extra = _robot(base, data.get("robot"), label)
    model = load_model(robot)
    limits = _limits(model, extra, label)
    k = _number(f"{label}: k", data.get("k", 4.0), 1.0)
    reserve = _number(f"{label}: reserve", data.get("reserve", 0.1), 0.0)
    method = str(data.get("method", "auto"))
    period = _number(f"{label}: sample_period", data.get("sample_period", 0.005), 1e-6)
    solver = dict(_mapping(f"{label}: solver", data.get("solver") or {}))
    solver = {name: tuple(v) if isinstance(v, list) else v for name, v in solver.items()}
    try:
        options = SolverOptions(**{**solver, "method": method})
    except (TocontrolError, TypeError) as exc:
        raise TaskFileError(f"{label}: solver: {exc}") from None
    solver["method"] = method
    hard = data.get("hard_timeout")
    hard = HARD_TIMEOUT_FACTOR * options.time_limit + HARD_TIMEOUT_GRACE if hard is None \
        else _number(f"{label}: hard_timeout", hard, 1e-3)
    starts = _starts(f"{label}: starts", data.get("starts") or {}, model)
    targets = _targets(f"{label}: targets", data.get("targets") or {}, model)
    if len(starts) * len(targets) > MAX_TASKS:
        raise TaskFileError(f"{label}: {len(starts)} starts x {len(targets)} targets; at "
                            f"most {MAX_TASKS} tasks")
    lim = (tuple(limits.names), tuple(limits.lower.tolist()), tuple(limits.upper.tolist()),
           tuple(limits.velocity.tolist()), float(limits.margin))
    tasks = []
    for name, start in starts:
        for target in targets:
            task = MotionTask(len(tasks), start, target, name, k, reserve, lim, method,
                              tuple(sorted(solver.items())), period, hard)
            try:
                task_problem(model, limits, task)
            except TocontrolError as exc:
                raise TaskFileError(f"{label}: start {name} -> target {list(target[1])}: "
                                    f"{exc}") from None
            tasks.append(task)
    return Cell(robot, model, limits, tuple(tasks), k, reserve, method, data)


def load_cell(path) -> Cell:
    """Read and validate a cell file; see :func:`parse_cell`."""
    path = Path(path)
    if not path.is_file():
        raise TaskFileError(f"cell file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise TaskFileError(f"{path}: not valid YAML: {exc}") from None
    return parse_cell(data, path.resolve().parent, label=str(path))
