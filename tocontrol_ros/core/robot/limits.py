"""Joint position, velocity and acceleration limits of a problem.

They come from the URDF, may be narrowed by a MoveIt-style ``joint_limits.yaml``, and are
shrunk by a margin.

The effective limit of each joint is the tighter of the URDF's ``<limit lower upper velocity>``
and the YAML's ``min_position``/``max_position``/``max_velocity`` (where ``has_position_limits``
or ``has_velocity_limits`` is true): a YAML file narrows the URDF, it never widens it. The
YAML's ``max_acceleration`` (where ``has_acceleration_limits`` is true) adds an acceleration
limit (the URDF has none). A margin ``m`` in [0, 1) plans inside them: the position range
shrinks about its centre to ``1 - m`` of its width and the velocity and acceleration limits to
``1 - m`` of their values, as the torque ``reserve`` does for the torque limits. Continuous
joints have no position limit; a joint without a velocity or acceleration limit has an
infinite one. Jerk entries (``has_jerk_limits``, ``max_jerk``) are read as MoveIt writes them
and not enforced (docs/limits.md, "Acceleration and jerk").

Where they bind, the solver enforces them as hard bounds (see ``docs/limits.md``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tocontrol_ros.core.errors import ProblemError

__all__ = ["JointLimits", "load_joint_limits_yaml", "narrowed_efforts",
           "parse_joint_limits_yaml", "VELOCITY_SLACK"]

#: A measured joint velocity at most this fraction above its planning limit is a tracking
#: overshoot (a simulated or real arm driven at its limit passes it by a little): a plan from
#: that state starts at the limit (:meth:`JointLimits.admissible_velocity`). Farther above,
#: the start is refused, naming the joint.
VELOCITY_SLACK = 0.1
#: Limits with another margin kept per limits (:meth:`JointLimits.with_margin`): a node uses
#: one or two margins; a bound keeps a caller that tries many from holding them all.
MARGINS_KEPT = 4


@dataclass(frozen=True)
class JointLimits:
    """Position and velocity limits of the n joints of a model, and a planning margin.

    Attributes
    ----------
    names : tuple of str, length n
        Joint names, in the model's order.
    lower, upper : ndarray, shape (n,)
        Position limits (rad, m); ``-inf``/``inf`` where a joint has none.
    velocity : ndarray, shape (n,)
        Velocity limits (rad/s, m/s), > 0; ``inf`` where a joint has none.
    margin : float
        Fraction in [0, 1) of each range kept free (see the module's docstring).
    acceleration : ndarray, shape (n,), optional
        Acceleration limits (rad/s^2, m/s^2), > 0; ``inf`` where a joint has none (the
        default: none).
    """

    names: tuple[str, ...]
    lower: np.ndarray = field(repr=False)
    upper: np.ndarray = field(repr=False)
    velocity: np.ndarray = field(repr=False)
    margin: float = 0.0
    acceleration: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        n = len(self.names)
        if self.acceleration is None:
            object.__setattr__(self, "acceleration", np.full(n, np.inf))
        for name in ("lower", "upper", "velocity", "acceleration"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (n,) or np.any(np.isnan(a)):
                raise ProblemError(f"`{name}` limits must have shape ({n},) without NaN, "
                                   f"got {a.tolist()}")
            object.__setattr__(self, name, a)
        bad = np.flatnonzero(~(self.lower < self.upper))
        if bad.size:
            i = int(bad[0])
            raise ProblemError(f"joint {self.names[i]!r}: lower position limit "
                               f"{self.lower[i]:.6g} is not below the upper {self.upper[i]:.6g}")
        for name in ("velocity", "acceleration"):
            values = getattr(self, name)
            bad = np.flatnonzero(~(values > 0))
            if bad.size:
                i = int(bad[0])
                raise ProblemError(f"joint {self.names[i]!r}: {name} limit must be > 0, got "
                                   f"{values[i]:.6g}")
        m = float(self.margin)
        if not (np.isfinite(m) and 0.0 <= m < 1.0):
            raise ProblemError(f"`margin` must be in [0, 1), got {self.margin!r}")
        object.__setattr__(self, "margin", m)
        # The planning bounds, once (a replan reads them a few dozen times); read-only, as
        # they are shared by every reader.
        plan = (*self._shrunk(), (1.0 - m) * self.velocity, (1.0 - m) * self.acceleration)
        for a in plan:
            a.flags.writeable = False
        object.__setattr__(self, "_plan", plan)
        object.__setattr__(self, "_has_acceleration",
                           bool(np.any(np.isfinite(self.acceleration))))
        object.__setattr__(self, "_margins", {})  # with_margin's, by margin

    # ---------------------------------------------------------------- builders
    @classmethod
    def from_model(cls, model, margin: float = 0.0) -> JointLimits:
        """The URDF's limits of ``model`` (a :class:`~.model.RobotModel`)."""
        return cls(tuple(model.joint_names), model.q_lower.copy(), model.q_upper.copy(),
                   model.qd_max.copy(), margin)

    def narrowed(self, table: Mapping[str, Mapping], source: str = "joint limits") -> JointLimits:
        """These limits narrowed by a MoveIt ``joint_limits`` table (name -> entry).

        An entry may give ``has_position_limits`` with ``min_position``/``max_position``,
        ``has_velocity_limits`` with ``max_velocity`` and ``has_acceleration_limits`` with
        ``max_acceleration``; other keys (jerks, efforts) are accepted and not used here.
        Names that are not joints of the model raise, so that a typo is not silently
        ignored.
        """
        lower, upper, velocity = self.lower.copy(), self.upper.copy(), self.velocity.copy()
        acceleration = self.acceleration.copy()
        index = {name: i for i, name in enumerate(self.names)}
        for name, entry in table.items():
            if name not in index:
                raise ProblemError(f"{source}: joint {name!r} is not a moving joint of the "
                                   f"model (joints: {', '.join(self.names)})")
            if not isinstance(entry, Mapping):
                raise ProblemError(f"{source}: the entry of joint {name!r} must be a mapping, "
                                   f"got {entry!r}")
            i = index[name]
            if _flag(entry, "has_position_limits", name, source):
                lo = _number(entry, "min_position", name, source)
                hi = _number(entry, "max_position", name, source)
                if not lo < hi:
                    raise ProblemError(f"{source}: joint {name!r} min_position {lo:g} is not "
                                       f"below max_position {hi:g}")
                lower[i], upper[i] = max(lower[i], lo), min(upper[i], hi)
                if not lower[i] < upper[i]:
                    raise ProblemError(
                        f"{source}: joint {name!r} range [{lo:g}, {hi:g}] does not overlap the "
                        f"URDF range [{self.lower[i]:g}, {self.upper[i]:g}]")
            if _flag(entry, "has_velocity_limits", name, source):
                v = _number(entry, "max_velocity", name, source)
                if not v > 0:
                    raise ProblemError(f"{source}: joint {name!r} max_velocity must be > 0, "
                                       f"got {v:g}")
                velocity[i] = min(velocity[i], v)
            if _flag(entry, "has_acceleration_limits", name, source):
                a = _number(entry, "max_acceleration", name, source)
                if not a > 0:
                    raise ProblemError(f"{source}: joint {name!r} max_acceleration must be "
                                       f"> 0, got {a:g}")
                acceleration[i] = min(acceleration[i], a)
        return JointLimits(self.names, lower, upper, velocity, self.margin, acceleration)

    def with_margin(self, margin: float) -> JointLimits:
        """The same limits with another margin.

        Made once per margin (up to :data:`MARGINS_KEPT`): the planner node asks for them
        for every problem it makes.
        """
        made = self._margins.get(margin)
        if made is None:
            made = JointLimits(self.names, self.lower, self.upper, self.velocity, margin,
                               self.acceleration)
            if len(self._margins) < MARGINS_KEPT:
                self._margins[margin] = made
        return made

    # ---------------------------------------------------------------- planning bounds
    @property
    def plan_lower(self) -> np.ndarray:
        """Position bounds the planner keeps to (margin applied), shape (n,), read-only."""
        return self._plan[0]

    @property
    def plan_upper(self) -> np.ndarray:
        """See :attr:`plan_lower`."""
        return self._plan[1]

    @property
    def plan_velocity(self) -> np.ndarray:
        """Velocity bounds the planner keeps to (margin applied), shape (n,), read-only."""
        return self._plan[2]

    @property
    def plan_acceleration(self) -> np.ndarray:
        """Acceleration bounds the planner keeps to (margin applied), shape (n,), read-only."""
        return self._plan[3]

    @property
    def has_acceleration(self) -> bool:
        """Whether any joint has a finite acceleration limit."""
        return self._has_acceleration

    def _shrunk(self) -> tuple[np.ndarray, np.ndarray]:
        finite = np.isfinite(self.lower) & np.isfinite(self.upper)
        lo, hi = np.where(finite, self.lower, 0.0), np.where(finite, self.upper, 0.0)
        c = 0.5 * (lo + hi)
        h = np.where(finite, 0.5 * (hi - lo) * (1.0 - self.margin), np.inf)
        lo = np.where(finite, c - h, self.lower)
        hi = np.where(finite, c + h, self.upper)
        return lo, hi

    @property
    def active(self) -> bool:
        """Whether any joint has a finite position, velocity or acceleration limit."""
        return bool(np.any(np.isfinite(self.lower) | np.isfinite(self.upper))
                    or np.any(np.isfinite(self.velocity)) or self.has_acceleration)

    def admissible_velocity(self, qd: np.ndarray, slack: float = VELOCITY_SLACK) -> np.ndarray:
        """A measured velocity with its small overshoots of the limits taken back to them.

        Parameters
        ----------
        qd : ndarray, shape (n,)
            Joint velocities (rad/s, m/s), e.g. of the latest joint state.
        slack : float
            Components at or above the planning limit (:attr:`plan_velocity`) by at most this
            fraction of it are put just inside it (the sign kept); larger ones are returned
            unchanged, for :meth:`check_state` to refuse.

        Returns
        -------
        ndarray, shape (n,)
        """
        qd = np.asarray(qd, dtype=float)
        v = self.plan_velocity
        over = (np.abs(qd) >= v) & (np.abs(qd) <= (1.0 + slack) * v)
        return np.where(over, np.sign(qd) * v * (1.0 - 1e-9), qd)

    # ---------------------------------------------------------------- checks
    def check_state(self, name: str, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Raise :class:`ProblemError` naming the joint when a state is outside the limits.

        Strictly inside the planning bounds (margin applied) for positions, and below the
        planning velocity limit.
        """
        lo, hi = self.plan_lower, self.plan_upper
        for i, joint in enumerate(self.names):
            if not lo[i] < q[i] < hi[i]:
                what = ("its limits" if self.margin == 0.0 else
                        f"its limits shrunk by the margin {self.margin:g}")
                raise ProblemError(f"`{name}` joint {joint!r} at {q[i]:.6g} is not inside "
                                   f"{what} ({lo[i]:.6g}, {hi[i]:.6g})")
        if qd is None:
            return
        v = self.plan_velocity
        for i, joint in enumerate(self.names):
            if not abs(qd[i]) < v[i]:
                raise ProblemError(f"`{name}` joint {joint!r} velocity {qd[i]:.6g} is not "
                                   f"below its limit {v[i]:.6g}")

    def violations(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """Largest violation of the limits (margin NOT applied) along samples, as fractions.

        Parameters
        ----------
        q, qd : ndarray, shape (K, n)

        Returns
        -------
        (position, velocity) : float
            ``max(0, q - upper, lower - q) / (upper - lower)`` and
            ``max(0, |qd| - v) / v`` over samples and joints; 0 when within.
        """
        finite = np.isfinite(self.lower) & np.isfinite(self.upper)
        width = np.where(finite, self.upper - self.lower, 1.0)
        over = np.maximum(q - self.upper, self.lower - q)
        pos = float(np.max(np.where(finite, over / width, -np.inf), initial=0.0))
        vfin = np.isfinite(self.velocity)
        vel = float(np.max(np.where(vfin, (np.abs(qd) - self.velocity)
                                    / np.where(vfin, self.velocity, 1.0), -np.inf),
                           initial=0.0))
        return max(pos, 0.0), max(vel, 0.0)

    def acceleration_violation(self, qdd: np.ndarray) -> float:
        """Largest excess of ``|qdd|`` (K, n) over the acceleration limits, as a fraction.

        The margin is NOT applied (as :meth:`violations`); 0 when within, or without limits.
        """
        fin = np.isfinite(self.acceleration)
        if not np.any(fin):
            return 0.0
        qdd = np.atleast_2d(np.asarray(qdd, dtype=float))
        over = (np.abs(qdd[:, fin]) - self.acceleration[fin]) / self.acceleration[fin]
        return max(float(np.max(over, initial=0.0)), 0.0)


def narrowed_efforts(names, tau_max: np.ndarray, table: Mapping[str, Mapping],
                     source: str = "joint limits") -> np.ndarray:
    """The torque limits ``tau_max`` (n,) (N m, N) narrowed by a ``joint_limits`` table.

    Entries with ``has_effort_limits: true`` give ``max_effort``; the tighter of it and the
    URDF's ``<limit effort>`` is kept (a file narrows, never widens). Unknown joint names
    raise, as in :meth:`JointLimits.narrowed`.

    Returns
    -------
    ndarray, shape (n,)
    """
    tau = np.array(tau_max, dtype=float)
    index = {name: i for i, name in enumerate(names)}
    for name, entry in table.items():
        if name not in index:
            raise ProblemError(f"{source}: joint {name!r} is not a moving joint of the "
                               f"model (joints: {', '.join(names)})")
        if not isinstance(entry, Mapping):
            raise ProblemError(f"{source}: the entry of joint {name!r} must be a mapping, "
                               f"got {entry!r}")
        if _flag(entry, "has_effort_limits", name, source):
            e = _number(entry, "max_effort", name, source)
            if not e > 0:
                raise ProblemError(f"{source}: joint {name!r} max_effort must be > 0, got "
                                   f"{e:g}")
            tau[index[name]] = min(tau[index[name]], e)
    return tau


def _flag(entry: Mapping, key: str, joint: str, source: str) -> bool:
    value = entry.get(key, False)
    if not isinstance(value, bool):
        raise ProblemError(f"{source}: joint {joint!r} `{key}` must be true or false, got "
                           f"{value!r}")
    return value


def _number(entry: Mapping, key: str, joint: str, source: str) -> float:
    if key not in entry:
        raise ProblemError(f"{source}: joint {joint!r} has no `{key}`")
    value = entry[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not np.isfinite(value):
        raise ProblemError(f"{source}: joint {joint!r} `{key}` must be a finite number, got "
                           f"{value!r}")
    return float(value)


def parse_joint_limits_yaml(text: str, label: str = "joint limits YAML") -> dict:
    """The ``joint_limits`` table of MoveIt ``joint_limits.yaml`` text.

    Returns
    -------
    dict
        Joint name -> entry (``has_position_limits``, ``min_position``, ...).
    """
    import yaml

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ProblemError(f"{label} is not valid YAML: {exc}") from exc
    if not isinstance(data, Mapping) or not isinstance(data.get("joint_limits"), Mapping):
        raise ProblemError(f"{label} must have a top-level mapping `joint_limits:` (MoveIt's "
                           f"format), got {type(data).__name__}")
    return dict(data["joint_limits"])


def load_joint_limits_yaml(path: str | Path) -> dict:
    """The ``joint_limits`` table of a MoveIt ``joint_limits.yaml`` file.

    See :func:`parse_joint_limits_yaml`.
    """
    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"joint limits file {str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f"joint limits file {str(path)!r} cannot be read: {exc}") from exc
    return parse_joint_limits_yaml(text, f"joint limits file {str(path)!r}")
