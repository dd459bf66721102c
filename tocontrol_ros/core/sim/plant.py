"""The simulated plant: the true arm and its integration over one control period.

The true arm may differ from the planning model (:func:`make_plant_model`: masses, inertias,
friction, a payload); it is integrated with classical RK4 at the simulation step, the torque
held over the control period (:func:`plant_period_function`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.robot.model import RobotModel
from tocontrol_ros.core.robot.urdf import Body
from tocontrol_ros.core.validate import finite_array

__all__ = ["PlantConfig", "make_plant_model", "plant_period_function"]

#: RK4 substeps per control period up to which the period is one unrolled expression;
#: beyond, a single step is mapped (smaller graph, a little more call overhead).
MAX_UNROLLED_SUBSTEPS = 16
#: Upper bound of ``sim_rate / control_rate`` (a guard against typos such as 1e6).
MAX_SUBSTEPS = 1000


@dataclass(frozen=True)
class PlantConfig:
    """The simulated plant: how the true arm differs from the planning model, and its timing.

    The defaults make the plant identical to the planning model, without noise.

    Attributes
    ----------
    mass_scale : float
        Factor on every body's mass (> 0). Centres of mass stay; the rotational inertia
        about them is scaled by ``inertia_scale`` only (set both for uniformly heavier
        links).
    inertia_scale : float
        Factor on every body's inertia tensor about its centre of mass (> 0).
    friction_scale : float
        Factor on the viscous friction (URDF damping) of every joint (>= 0).
    payload_mass : float
        Point mass (kg, >= 0) at the tip frame's origin, lumped into the last body
        (parallel-axis theorem).
    torque_noise : float
        Standard deviation of Gaussian torque noise, as a fraction of ``tau_max`` (>= 0);
        one draw per joint and control period, added to the applied torque.
    noise_seed : int
        Seed of the noise.
    initial_offset : tuple of float
        Added to the plant's initial state: ``n`` position offsets (rad, m), or ``2n``
        values (positions, then velocities). Empty: none.
    sim_rate : float
        Integration rate of the plant (Hz): fixed-step RK4 with step ``1 / sim_rate``.
    control_rate : float
        Rate of the control law (Hz); ``sim_rate`` must be an integer multiple of it.

    Raises
    ------
    ProblemError
        A value out of range, or rates whose ratio is not an integer.
    """

    mass_scale: float = 1.0
    inertia_scale: float = 1.0
    friction_scale: float = 1.0
    payload_mass: float = 0.0
    torque_noise: float = 0.0
    noise_seed: int = 0
    initial_offset: tuple[float, ...] = ()
    sim_rate: float = 2000.0
    control_rate: float = 1000.0

    def __post_init__(self) -> None:
        checks = {"mass_scale": "positive", "inertia_scale": "positive",
                  "friction_scale": "non-negative", "payload_mass": "non-negative",
                  "torque_noise": "non-negative", "sim_rate": "positive",
                  "control_rate": "positive"}
        for name, kind in checks.items():
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError) as exc:
                raise ProblemError(f"`{name}` must be a number, got {value!r}") from exc
            ok = math.isfinite(value) and (value > 0 if kind == "positive" else value >= 0)
            if not ok:
                raise ProblemError(f"`{name}` must be {kind} and finite, got "
                                   f"{getattr(self, name)!r}")
            object.__setattr__(self, name, value)
        if isinstance(self.noise_seed, bool) or not isinstance(self.noise_seed,
                                                               (int, np.integer)):
            raise ProblemError(f"`noise_seed` must be an integer, got {self.noise_seed!r}")
        offset = finite_array("initial_offset", self.initial_offset, ndim=1)
        object.__setattr__(self, "initial_offset", tuple(float(v) for v in offset))
        ratio = self.sim_rate / self.control_rate
        if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
            raise ProblemError(f"`sim_rate` ({self.sim_rate:g} Hz) must be an integer multiple "
                               f"of `control_rate` ({self.control_rate:g} Hz)")
        if round(ratio) > MAX_SUBSTEPS:
            raise ProblemError(f"`sim_rate` / `control_rate` must be at most {MAX_SUBSTEPS}, "
                               f"got {ratio:g}")

    @property
    def substeps(self) -> int:
        """RK4 steps per control period."""
        return int(round(self.sim_rate / self.control_rate))

    @property
    def control_period(self) -> float:
        """Control period (s)."""
        return 1.0 / self.control_rate

    @property
    def identical(self) -> bool:
        """True when the plant's dynamics are the planning model's (offset and noise aside)."""
        return (self.mass_scale == 1.0 and self.inertia_scale == 1.0
                and self.friction_scale == 1.0 and self.payload_mass == 0.0)

    def offset(self, n: int) -> np.ndarray:
        """Initial-state offset for ``n`` joints, shape (2n,).

        Raises
        ------
        ProblemError
            When ``initial_offset`` has neither 0, ``n`` nor ``2n`` values.
        """
        off = np.asarray(self.initial_offset, dtype=float)
        if off.size == 0:
            return np.zeros(2 * n)
        if off.size == n:
            return np.concatenate([off, np.zeros(n)])
        if off.size == 2 * n:
            return off.copy()
        raise ProblemError(f"`initial_offset` must have 0, {n} (positions) or {2 * n} "
                           f"(positions, velocities) values, got {off.size}")


def make_plant_model(model: RobotModel, plant: PlantConfig) -> RobotModel:
    """The true arm: ``model`` with the masses, inertias, friction and payload of ``plant``.

    Parameters
    ----------
    model : RobotModel
        The planning model.
    plant : PlantConfig

    Returns
    -------
    RobotModel
        ``model`` itself when ``plant.identical``; else a new model (its own function cache).
    """
    if plant.identical:
        return model
    bodies = [dataclasses.replace(b, mass=b.mass * plant.mass_scale,
                                  inertia=b.inertia * plant.inertia_scale)
              for b in model.bodies]
    if plant.payload_mass > 0:
        bodies[-1] = _add_point_mass(bodies[-1], plant.payload_mass,
                                     np.asarray(model.tip_translation, dtype=float))
    return dataclasses.replace(model, bodies=tuple(bodies),
                               damping=model.damping * plant.friction_scale)


def _add_point_mass(body: Body, mass: float, where: np.ndarray) -> Body:
    """``body`` with a point mass (kg) at ``where`` (its frame, m) lumped in."""
    total = body.mass + mass
    com = (body.mass * body.com + mass * where) / total

    def shift(m, d):
        return m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))

    inertia = body.inertia + shift(body.mass, body.com - com) + shift(mass, where - com)
    return dataclasses.replace(body, mass=total, com=com, inertia=inertia)


def plant_period_function(plant_model: RobotModel, substeps: int, h: float) -> ca.Function:
    """``(x, tau) -> x`` after ``substeps`` RK4 steps of length ``h`` with ``tau`` held."""
    n = plant_model.n
    fd = plant_model.function("fd")
    x = ca.SX.sym("x", 2 * n)
    tau = ca.SX.sym("tau", n)

    def f(z):
        return ca.vertcat(z[n:], fd(z[:n], z[n:], tau))

    def rk4(z):
        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        return z + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

    if substeps <= MAX_UNROLLED_SUBSTEPS:
        z = x
        for _ in range(substeps):
            z = rk4(z)
        return ca.Function("plant_period", [x, tau], [z], ["x", "tau"], ["x_next"])
    step = ca.Function("plant_step", [x, tau], [rk4(x)], ["x", "tau"], ["x_next"])
    acc = step.mapaccum("plant_steps", substeps)
    xm = ca.MX.sym("x", 2 * n)
    tm = ca.MX.sym("tau", n)
    traj = acc(xm, ca.repmat(tm, 1, substeps))
    return ca.Function("plant_period", [xm, tm], [traj[:, -1]], ["x", "tau"], ["x_next"])
