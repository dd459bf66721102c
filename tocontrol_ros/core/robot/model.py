"""Rigid-body dynamics of a serial manipulator read from a URDF, as CasADi expressions.

The URDF becomes a chain of bodies in :mod:`~tocontrol_ros.core.robot.urdf` (one rigid body per
moving joint); :func:`load_robot` adds gravity and the task space. The dynamics are a
recursive Newton-Euler algorithm written over CasADi ``SX`` symbols, so that every quantity
(mass matrix, bias forces, forward dynamics, task-space point and its Jacobian) comes with
exact derivatives of any order, and the solver can compile them.

Why our own recursive Newton-Euler and not a URDF-to-CasADi library: the solver needs the
model as symbolic expressions it can differentiate twice and compile together with the
costate equations, plus URDF ``<dynamics damping>`` as viscous friction and a task space
restricted to some coordinates. The algorithm is forty lines; it is checked against closed
forms and against Pinocchio in the tests.

Conventions: joint torques (N m) or forces (N) ``tau``; normalised controls
``u = tau / tau_max`` with ``|u_i| <= 1``; state ``x = (q, qd)``.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields

import casadi as ca
import numpy as np

from tocontrol_ros.core.errors import ModelError
from tocontrol_ros.core.robot.urdf import (
    Body,
    Chain,
    chain_from_urdf,
    default_urdf_path,
    read_urdf,
)

__all__ = ["Body", "RobotModel", "load_robot", "default_urdf_path"]

#: Relative tolerance for calling joint axes parallel when detecting a planar chain.
PLANAR_TOL = 1e-9
STANDARD_GRAVITY = (0.0, 0.0, -9.80665)


def spd_solve(a, b):
    """Solve ``a x = b`` for a symmetric positive definite symbolic ``a`` by LDL^T.

    The mass matrix needs no pivoting; this graph is about a third smaller than CasADi's
    generic symbolic ``solve`` (QR), which matters because every RK4 step of the canonical
    system and its Jacobian goes through it. Only the lower triangle of ``a`` is read.

    Parameters
    ----------
    a : casadi.SX, shape (n, n)
    b : casadi.SX, shape (n, 1)

    Returns
    -------
    casadi.SX, shape (n, 1)
    """
    n = a.shape[0]
    low = [[None] * n for _ in range(n)]
    diag = [None] * n
    for j in range(n):
        diag[j] = a[j, j] - sum(low[j][i] ** 2 * diag[i] for i in range(j))
        for r in range(j + 1, n):
            low[r][j] = (a[r, j] - sum(low[r][i] * low[j][i] * diag[i] for i in range(j))) \
                / diag[j]
    y = [None] * n
    for r in range(n):
        y[r] = b[r] - sum(low[r][i] * y[i] for i in range(r))
    x = [None] * n
    for r in reversed(range(n)):
        x[r] = y[r] / diag[r] - sum(low[i][r] * x[i] for i in range(r + 1, n))
    return ca.vertcat(*x)


@dataclass(frozen=True, eq=False)
class RobotModel(Chain):
    """A serial manipulator with bounded joint torques, with symbolic and numeric dynamics.

    Build it with :func:`load_robot`. Dynamics: ``M(q) qdd + b(q, qd) = tau`` with
    ``b = C(q, qd) qd + g(q) + D qd`` (Coriolis/centrifugal, gravity, viscous friction) and
    ``|tau_i| <= tau_max_i``. The task-space point ``P(q)`` is the tip frame's origin in the
    base frame, restricted to ``task_axes``.

    Attributes
    ----------
    name, joint_names, bodies, tip_rotation, tip_translation, base_link, tip_link
        The chain read from the URDF (:class:`~tocontrol_ros.core.robot.urdf.Chain`).
    tau_max, damping, q_lower, q_upper, qd_max, coulomb : ndarray, shape (n,)
        Its joint limits and friction (:class:`~tocontrol_ros.core.robot.urdf.Chain`); the
        position and velocity limits are kept for checks, Coulomb friction is reported,
        not modelled (it is discontinuous).
    gravity : ndarray, shape (3,)
        Gravity acceleration in the base frame (m/s^2).
    task_axes : tuple of int
        Which base-frame coordinates (0 = x, 1 = y, 2 = z) form the task space; ``m`` of them.
    """

    gravity: np.ndarray
    task_axes: tuple[int, ...]
    _functions: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __reduce__(self):
        """Pickled as its data, without its compiled functions.

        A worker process builds its own (:mod:`~tocontrol_ros.core.planning.pool`); the model is
        unpickled once per process and content.
        """
        return (_restored, ({f.name: getattr(self, f.name) for f in fields(self) if f.init},))

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.bodies)

    @property
    def m(self) -> int:
        """Task-space dimension."""
        return len(self.task_axes)

    # ----------------------------------------------------- symbolic algorithms
    def _joint_transform(self, body: Body, q):
        """Symbolic rotation (3, 3) and translation (3,) of a body in its parent's frame."""
        a = ca.DM(body.axis)
        r0 = ca.DM(body.rotation)
        p0 = ca.DM(body.translation)
        if body.kind == "prismatic":
            return r0, p0 + ca.mtimes(r0, a) * q
        k = ca.skew(a)
        rj = ca.DM.eye(3) + ca.sin(q) * k + (1 - ca.cos(q)) * ca.mtimes(k, k)
        return ca.mtimes(r0, rj), p0

    def rnea_sym(self, q, qd, qdd, gravity: bool = True, friction: bool = True):
        """Inverse dynamics ``tau = M(q) qdd + b(q, qd)`` as a CasADi expression.

        Parameters
        ----------
        q, qd, qdd : casadi.SX or MX, shape (n, 1)
            Joint positions (rad, m), velocities and accelerations.
        gravity, friction : bool
            Include the gravity and the viscous-friction terms.

        Returns
        -------
        casadi.SX or MX, shape (n, 1)
            Joint torques (N m) or forces (N).
        """
        n = self.n
        w = ca.DM.zeros(3)
        wd = ca.DM.zeros(3)
        vd = -ca.DM(self.gravity) if gravity else ca.DM.zeros(3)
        frames, forces, torques = [], [], []
        for i, body in enumerate(self.bodies):
            rot, pos = self._joint_transform(body, q[i])
            e = rot.T
            a = ca.DM(body.axis)
            w_in = ca.mtimes(e, w)
            wd_in = ca.mtimes(e, wd)
            vd_new = ca.mtimes(e, vd + ca.cross(wd, pos) + ca.cross(w, ca.cross(w, pos)))
            if body.kind == "prismatic":
                w, wd = w_in, wd_in
                vd = vd_new + 2 * ca.cross(w, a * qd[i]) + a * qdd[i]
            else:
                w = w_in + a * qd[i]
                wd = wd_in + a * qdd[i] + ca.cross(w_in, a * qd[i])
                vd = vd_new
            c = ca.DM(body.com)
            inertia = ca.DM(body.inertia)
            acc_com = vd + ca.cross(wd, c) + ca.cross(w, ca.cross(w, c))
            force = body.mass * acc_com
            torque = ca.mtimes(inertia, wd) + ca.cross(w, ca.mtimes(inertia, w))
            frames.append((rot, pos))
            forces.append(force)
            torques.append(torque + ca.cross(c, force))
        tau = [None] * n
        f_next = ca.DM.zeros(3)
        n_next = ca.DM.zeros(3)
        for i in range(n - 1, -1, -1):
            if i + 1 < n:
                rot_next, pos_next = frames[i + 1]
                f_child = ca.mtimes(rot_next, f_next)
                n_child = ca.mtimes(rot_next, n_next) + ca.cross(pos_next, f_child)
            else:
                f_child = ca.DM.zeros(3)
                n_child = ca.DM.zeros(3)
            f_next = forces[i] + f_child
            n_next = torques[i] + n_child
            a = ca.DM(self.bodies[i].axis)
            moment = f_next if self.bodies[i].kind == "prismatic" else n_next
            tau[i] = ca.dot(moment, a)
            if friction:
                tau[i] = tau[i] + float(self.damping[i]) * qd[i]
        return ca.vertcat(*tau)

    def tip_pose_sym(self, q):
        """Tip frame in the base frame: rotation (3, 3) and position (3, 1), symbolic."""
        rot = ca.DM.eye(3)
        pos = ca.DM.zeros(3)
        for i, body in enumerate(self.bodies):
            r, p = self._joint_transform(body, q[i])
            pos = pos + ca.mtimes(rot, p)
            rot = ca.mtimes(rot, r)
        pos = pos + ca.mtimes(rot, ca.DM(self.tip_translation))
        rot = ca.mtimes(rot, ca.DM(self.tip_rotation))
        return rot, pos

    def body_frames_sym(self, q) -> list:
        """Each body's frame in the base frame, symbolic.

        A list of n (rotation (3, 3), position (3, 1)) (m); body ``i``'s frame is the one its
        joint moves.
        """
        rot = ca.DM.eye(3)
        pos = ca.DM.zeros(3)
        out = []
        for i, body in enumerate(self.bodies):
            r, p = self._joint_transform(body, q[i])
            pos = pos + ca.mtimes(rot, p)
            rot = ca.mtimes(rot, r)
            out.append((rot, pos))
        return out

    def point_sym(self, q):
        """Task-space point ``P(q)``, shape (m, 1), symbolic (m)."""
        _, pos = self.tip_pose_sym(q)
        return ca.vertcat(*[pos[k] for k in self.task_axes])

    def mass_matrix_sym(self, q):
        """Joint-space inertia matrix ``M(q)``, shape (n, n), symbolic."""
        sym = ca.SX if isinstance(q, ca.SX) else ca.MX
        qdd = sym.sym("qdd", self.n)
        tau = self.rnea_sym(q, sym.zeros(self.n), qdd, gravity=False, friction=False)
        # tau is linear in qdd, so its Jacobian is M(q) and does not depend on qdd.
        return ca.jacobian(tau, qdd)

    def bias_sym(self, q, qd):
        """Bias forces ``b(q, qd)`` (Coriolis/centrifugal, gravity, friction), (n, 1)."""
        zeros = ca.SX.zeros(self.n) if isinstance(q, ca.SX) else ca.MX.zeros(self.n)
        return self.rnea_sym(q, qd, zeros)

    def forward_dynamics_sym(self, q, qd, tau):
        """Joint accelerations ``qdd = M(q)^-1 (tau - b(q, qd))``, shape (n, 1), symbolic."""
        return spd_solve(self.mass_matrix_sym(q), tau - self.bias_sym(q, qd))

    def state_derivative_sym(self, x, u):
        """State-space dynamics ``xd = f(x, u)`` with normalised controls ``u = tau / tau_max``.

        Parameters
        ----------
        x : casadi.SX, shape (2n, 1)
            State ``(q, qd)``.
        u : casadi.SX, shape (n, 1)
            Normalised controls (dimensionless).

        Returns
        -------
        casadi.SX, shape (2n, 1)
        """
        n = self.n
        q, qd = x[:n], x[n:]
        qdd = self.forward_dynamics_sym(q, qd, ca.DM(self.tau_max) * u)
        return ca.vertcat(qd, qdd)

    # ------------------------------------------------------ compiled functions
    def function(self, name: str) -> ca.Function:
        """A CasADi function of the model, built on first use and cached.

        Parameters
        ----------
        name : str
            One of ``"M"`` (q -> M), ``"M_diag"`` (q -> the diagonal of M, (n,)),
            ``"bias"`` ((q, qd) -> b), ``"fd"`` ((q, qd, tau) -> qdd),
            ``"id"`` ((q, qd, qdd) -> tau), ``"P"`` (q -> P), ``"J"`` (q -> dP/dq, (m, n)),
            ``"f"`` ((x, u) -> xd), ``"energy"`` ((q, qd) -> (kinetic, potential), J).

        Returns
        -------
        casadi.Function
            Differentiable to any order with ``jacobian()``/``hessian`` machinery.
        """
        if name in self._functions:
            return self._functions[name]
        n = self.n
        q = ca.SX.sym("q", n)
        qd = ca.SX.sym("qd", n)
        v = ca.SX.sym("v", n)
        builders = {
            "M": lambda: ca.Function("M", [q], [self.mass_matrix_sym(q)], ["q"], ["M"]),
            "M_diag": lambda: ca.Function("M_diag", [q], [ca.diag(self.mass_matrix_sym(q))],
                                          ["q"], ["M_diag"]),
            "bias": lambda: ca.Function("bias", [q, qd], [self.bias_sym(q, qd)],
                                        ["q", "qd"], ["b"]),
            "fd": lambda: ca.Function("fd", [q, qd, v],
                                      [self.forward_dynamics_sym(q, qd, v)],
                                      ["q", "qd", "tau"], ["qdd"]),
            "id": lambda: ca.Function("id", [q, qd, v], [self.rnea_sym(q, qd, v)],
                                      ["q", "qd", "qdd"], ["tau"]),
            "P": lambda: ca.Function("P", [q], [self.point_sym(q)], ["q"], ["P"]),
            "J": lambda: ca.Function("J", [q], [ca.jacobian(self.point_sym(q), q)],
                                     ["q"], ["J"]),
            "f": lambda: self._state_function(),
            "energy": lambda: self._energy_function(),
        }
        if name not in builders:
            raise KeyError(f"`name` must be one of {sorted(builders)}, got {name!r}")
        self._functions[name] = builders[name]()
        return self._functions[name]

    def _state_function(self) -> ca.Function:
        x = ca.SX.sym("x", 2 * self.n)
        u = ca.SX.sym("u", self.n)
        return ca.Function("f", [x, u], [self.state_derivative_sym(x, u)], ["x", "u"], ["xd"])

    def _energy_function(self) -> ca.Function:
        n = self.n
        q = ca.SX.sym("q", n)
        qd = ca.SX.sym("qd", n)
        kinetic = 0.5 * ca.dot(qd, ca.mtimes(self.mass_matrix_sym(q), qd))
        # Potential energy: -sum m_i g . c_i with c_i each body's centre of mass in the base.
        rot = ca.DM.eye(3)
        pos = ca.DM.zeros(3)
        potential = 0
        for i, body in enumerate(self.bodies):
            r, p = self._joint_transform(body, q[i])
            pos = pos + ca.mtimes(rot, p)
            rot = ca.mtimes(rot, r)
            com = pos + ca.mtimes(rot, ca.DM(body.com))
            potential = potential - body.mass * ca.dot(ca.DM(self.gravity), com)
        return ca.Function("energy", [q, qd], [kinetic, potential], ["q", "qd"], ["T", "V"])

    # ------------------------------------------------------- numeric wrappers
    def _vec(self, name: str, value, size: int) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (size,):
            raise ValueError(f"`{name}` must have shape ({size},), got {arr.shape}")
        return arr

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia matrix, shape (n, n) (kg m^2 for revolute joints)."""
        return np.array(self.function("M")(self._vec("q", q, self.n)))

    def diagonal_inertia(self, q: np.ndarray) -> np.ndarray:
        """The diagonals of the inertia matrices at configurations ``q`` (S, n): (S, n).

        What the bang-bang time estimates with diagonal inertia use (the seed ranking, the
        initial paths, the first motion's candidates): one call of the model's ``M_diag``
        mapped over the ``S`` columns (the mapped function cached per ``S``).
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        key = ("M_diag", len(q))
        if key not in self._functions:
            self._functions[key] = self.function("M_diag").map(len(q))
        return np.array(self._functions[key](q.T)).T.reshape(len(q), self.n)

    def bias(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Bias forces ``C qd + g + D qd``, shape (n,) (N m)."""
        return np.array(self.function("bias")(self._vec("q", q, self.n),
                                               self._vec("qd", qd, self.n))).ravel()

    def forward_dynamics(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations for torques ``tau`` (N m), shape (n,) (rad/s^2)."""
        return np.array(self.function("fd")(self._vec("q", q, self.n),
                                             self._vec("qd", qd, self.n),
                                             self._vec("tau", tau, self.n))).ravel()

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torques that produce ``qdd``, shape (n,) (N m)."""
        return np.array(self.function("id")(self._vec("q", q, self.n),
                                             self._vec("qd", qd, self.n),
                                             self._vec("qdd", qdd, self.n))).ravel()

    def point(self, q: np.ndarray) -> np.ndarray:
        """Task-space point ``P(q)``, shape (m,) (m).

        Through :meth:`point_and_jacobian` (the same expression, the same bits: a CasADi
        call of ``P`` took ten times as long, and a replan asks for a few points).
        """
        return self.point_and_jacobian(self._vec("q", q, self.n))[0]

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """Task-space Jacobian ``dP/dq``, shape (m, n)."""
        return np.array(self.function("J")(self._vec("q", q, self.n)))

    def point_and_jacobian(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``P(q)``, shape (m,) (m), and ``dP/dq``, shape (m, n), in one evaluation.

        The values of :meth:`point` and :meth:`jacobian` to the bit (the same expressions),
        through numpy buffers (:class:`~tocontrol_ros.core.robot.compiled.BufferedFunction`):
        about 7 us on the paper's arm against 0.1 ms for the two calls, for the Newton steps
        of a replan's inverse kinematics (issue 47). ``q`` is not checked (shape (n,), finite:
        the caller's). Thread-safe.
        """
        fun = self._functions.get("PJ buffered")
        if fun is None:
            from tocontrol_ros.core.robot.compiled import BufferedFunction

            x = ca.SX.sym("q", self.n)
            p = self.point_sym(x)
            fun = self._functions["PJ buffered"] = BufferedFunction(
                ca.Function("PJ", [x], [ca.densify(p), ca.densify(ca.jacobian(p, x))],
                            ["q"], ["P", "J"]))
        point, jac = fun(q)
        return point, jac.reshape(self.m, self.n)

    def energy(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """Kinetic and potential energy (J) at ``(q, qd)``."""
        kin, pot = self.function("energy")(self._vec("q", q, self.n),
                                           self._vec("qd", qd, self.n))
        return float(kin), float(pot)

    def reach(self) -> float:
        """Upper bound of the distance from the first joint to the tip (m)."""
        return float(sum(np.linalg.norm(b.translation) for b in self.bodies[1:])
                     + np.linalg.norm(self.tip_translation)
                     + sum(abs(hi - lo) for b, lo, hi in zip(self.bodies, self.q_lower,
                                                              self.q_upper, strict=True)
                           if b.kind == "prismatic"))

    # ------------------------------------------------------------- reporting
    def summary(self) -> str:
        """A human-readable description of the model: chain, inertias, limits, task space."""
        axes = "".join("xyz"[k] for k in self.task_axes)
        lines = [
            f"robot '{self.name}': {self.n} joints, base '{self.base_link}' -> tip "
            f"'{self.tip_link}', task space {axes} (m = {self.m}, redundancy n - m = "
            f"{self.n - self.m})",
            f"gravity {np.array2string(self.gravity, precision=4)} m/s^2 (base frame)",
            f"{'joint':<14}{'type':<11}{'mass kg':>9}{'tau_max':>9}{'damping':>9}"
            f"{'q range':>20}{'qd_max':>9}  links",
        ]
        for i, b in enumerate(self.bodies):
            rng = ("continuous" if not np.isfinite(self.q_lower[i])
                   else f"[{self.q_lower[i]:.3g}, {self.q_upper[i]:.3g}]")
            lines.append(
                f"{b.joint:<14}{b.kind:<11}{b.mass:>9.3f}{self.tau_max[i]:>9.3g}"
                f"{self.damping[i]:>9.3g}{rng:>20}{self.qd_max[i]:>9.3g}  "
                + ", ".join(b.links))
        if np.any(self.coulomb != 0):
            lines.append("note: URDF <dynamics friction> (Coulomb) is reported, not modelled")
        return "\n".join(lines)

    def check_dynamics(self, seed: int = 0, samples: int = 5) -> str:
        """Self-check at random states: M symmetric positive definite, ID(FD(tau)) = tau.

        Parameters
        ----------
        seed : int
            Seed of the random states.
        samples : int
            Number of random states.

        Returns
        -------
        str
            A short report with the worst figures found.
        """
        rng = np.random.default_rng(seed)
        worst_sym = worst_rt = 0.0
        min_eig = np.inf
        for _ in range(samples):
            q = rng.uniform(-np.pi, np.pi, self.n)
            q = np.clip(q, self.q_lower, self.q_upper)
            qd = rng.uniform(-1, 1, self.n)
            tau = rng.uniform(-1, 1, self.n) * self.tau_max
            mass = self.mass_matrix(q)
            worst_sym = max(worst_sym, float(np.max(np.abs(mass - mass.T))))
            min_eig = min(min_eig, float(np.linalg.eigvalsh(mass).min()))
            qdd = self.forward_dynamics(q, qd, tau)
            back = self.inverse_dynamics(q, qd, qdd)
            worst_rt = max(worst_rt, float(np.max(np.abs(back - tau)) / np.max(self.tau_max)))
        ok = worst_sym < 1e-12 and min_eig > 0 and worst_rt < 1e-10
        return "\n".join([
            f"dynamics check over {samples} random states (seed {seed}): "
            + ("OK" if ok else "FAILED"),
            f"  max |M - M^T|                      {worst_sym:.2e}",
            f"  min eigenvalue of M                {min_eig:.4g} kg m^2",
            f"  max |ID(q, qd, FD(q, qd, tau)) - tau| / tau_max  {worst_rt:.2e}",
        ])


# ---------------------------------------------------------------------- loading
def load_robot(
    source: str | os.PathLike,
    base_link: str | None = None,
    tip_link: str | None = None,
    gravity: Sequence[float] = STANDARD_GRAVITY,
    task_axes: str | Sequence[int] | None = None,
    locked_joints: Mapping[str, float] | None = None,
) -> RobotModel:
    """Load a serial chain from a URDF file or string.

    Parameters
    ----------
    source : str or os.PathLike
        Path of a URDF file, or the URDF XML itself (e.g. a ``robot_description``).
    base_link : str, optional
        Link fixed to the world. Default: the URDF's root link.
    tip_link : str, optional
        Link whose origin is the end-effector point. Default: the only leaf link.
    gravity : sequence of 3 float
        Gravity acceleration in the base frame (m/s^2).
    task_axes : str or sequence of int, optional
        Coordinates of the tip position forming the task space, e.g. ``"xy"`` or ``(0, 1)``.
        Default: the plane of motion for a planar chain (all revolute axes parallel), else
        ``"xyz"``.
    locked_joints : mapping of str to float, optional
        Moving joints to treat as fixed at the given position (rad or m). Moving joints at
        or below the tip link (a gripper's fingers) are locked without being named: at 0,
        or at the nearer position limit when 0 is outside the limits; name them here to
        lock them elsewhere. A moving joint that branches off the base-tip path above the
        tip must be named (or another tip chosen).

    Returns
    -------
    RobotModel

    Raises
    ------
    ModelError
        Malformed URDF, missing links, a chain that branches or closes, an unsupported
        joint type, a body without inertia, a missing or non-positive limit.
    """
    robot, label = read_urdf(source)
    gravity_arr = np.asarray(gravity, dtype=float)
    if gravity_arr.shape != (3,) or not np.all(np.isfinite(gravity_arr)):
        raise ModelError(f"`gravity` must be 3 finite numbers, got {gravity!r}")
    chain = chain_from_urdf(robot, label, base_link, tip_link, locked_joints)
    model = RobotModel(**{f.name: getattr(chain, f.name) for f in fields(Chain)},
                       gravity=gravity_arr, task_axes=_task_axes(task_axes, list(chain.bodies)))
    _check_positive_definite(model)
    return model


#: Models unpickled in this process, by the digest of their data (see RobotModel.__reduce__).
_RESTORED: dict[str, RobotModel] = {}


def _restored(data: dict) -> RobotModel:
    """The model with ``data`` (its init fields): the same object for the same data."""
    key = hashlib.sha256(pickle.dumps(data, protocol=5)).hexdigest()
    model = _RESTORED.get(key)
    if model is None:
        model = _RESTORED[key] = RobotModel(**data)
    return model


def _task_axes(task_axes, bodies: list[Body]) -> tuple[int, ...]:
    if task_axes is not None:
        if isinstance(task_axes, str):
            if not task_axes or any(c not in "xyz" for c in task_axes) or \
                    len(set(task_axes)) != len(task_axes):
                raise ModelError(f"`task_axes` must be distinct letters of 'xyz', got "
                                 f"{task_axes!r}")
            return tuple("xyz".index(c) for c in task_axes)
        try:
            axes = tuple(task_axes)
        except TypeError:
            axes = ()
        if not axes or any(isinstance(k, bool) or k not in (0, 1, 2) for k in axes) or \
                len(set(axes)) != len(axes):
            raise ModelError(f"`task_axes` must be distinct letters of 'xyz' or distinct "
                             f"indices in 0..2, got {task_axes!r}")
        return tuple(int(k) for k in axes)
    # Planar detection at q = 0: every revolute axis parallel to one base axis e, every
    # prismatic axis orthogonal to it, every link offset in the plane -> the other two axes.
    rot = np.eye(3)
    revolute, prismatic = [], []
    offsets = []
    for b in bodies:
        offsets.append(rot @ b.translation)
        rot = rot @ b.rotation
        (prismatic if b.kind == "prismatic" else revolute).append(rot @ b.axis)
    for e in range(3):
        unit = np.eye(3)[e]
        if revolute and all(abs(abs(a @ unit) - 1) < PLANAR_TOL for a in revolute) and \
                all(abs(a @ unit) < PLANAR_TOL for a in prismatic):
            return tuple(k for k in range(3) if k != e)
    return (0, 1, 2)


def _check_positive_definite(model: RobotModel) -> None:
    q = np.clip(np.zeros(model.n), model.q_lower, model.q_upper)
    mass = model.mass_matrix(q)
    diag = np.diag(mass)
    for i, value in enumerate(diag):
        if not value > 1e-12 * max(1.0, diag.max()):
            raise ModelError(
                f"joint {model.joint_names[i]!r}: the bodies it moves have no inertia about "
                f"or along its axis (M[{i},{i}] = {value:.3g}); add mass or inertia")
    if np.linalg.eigvalsh(mass).min() <= 0:
        raise ModelError("the mass matrix is not positive definite at q = 0; check the "
                         "<inertial> elements")
