"""What a certificate is: its tolerances, its items and the verdict (data only).

The checks that fill them are :func:`~tocontrol_ros.core.checks.certificate.certify_open_loop`
(any motion: its torques re-integrated through the model) and the maximum principle's
:func:`~tocontrol_ros.core.indirect.certificate.certify` (its canonical system too).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tocontrol_ros.core.errors import ProblemError

__all__ = ["CertificateOptions", "CertificateItem", "Certificate"]


@dataclass(frozen=True)
class CertificateOptions:
    """Tolerances of the certificate (validated on construction).

    Attributes
    ----------
    point_tol : float
        The open-loop end point must be within this of the target (m).
    velocity_tol : float
        ...and the open-loop end joint velocities within this of 0 (rad/s or m/s).
    position_tol : float
        For a joint-state target, the open-loop end joint positions within this (rad, m).
    defect_tol : float
        Max-norm of (re-integrated segment end minus next grid state), relative to
        ``max(1, |z|)`` of that state.
    boundary_tol : float
        Boundary and transversality conditions at both ends (m, rad/s, and the costate
        component along the self-motion manifold, relative to ``max(1, |psi_q|)``).
    hamiltonian_tol : float
        ``max |H|`` over the sampling (``H = 0`` along an exact solution).
    control_set_tol : float
        ``max sum u_i^(2k) - 1`` over the sampling (rounding only).
    residual_tol : float
        The solver's residual (max-norm of its BVP equations), when given.
    rtol, atol : float
        The integrator's tolerances (relative and absolute, per component of the state).
    segment_steps : int
        Grid steps per segment (the solver's RK4 steps per shooting interval gives the
        shooting intervals).
    check_limits : bool
        Check the problem's joint position and velocity limits (along the sampling and the
        open-loop state); the solver enforces them.
    limit_tol : float
        Tolerated excess over a joint limit, as a fraction of the position range or of the
        velocity limit.
    """

    point_tol: float = 1e-4
    velocity_tol: float = 1e-3
    position_tol: float = 1e-4
    defect_tol: float = 1e-5
    boundary_tol: float = 1e-6
    hamiltonian_tol: float = 1e-5
    control_set_tol: float = 1e-9
    residual_tol: float = 1e-6
    rtol: float = 1e-10
    atol: float = 1e-11
    segment_steps: int = 12
    check_limits: bool = True
    limit_tol: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("point_tol", "velocity_tol", "position_tol", "defect_tol",
                     "boundary_tol", "hamiltonian_tol", "control_set_tol", "residual_tol",
                     "rtol", "atol", "limit_tol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ProblemError(f"`{name}` must be a positive number, got {value!r}")
        if not (isinstance(self.segment_steps, (int, np.integer)) and self.segment_steps >= 1):
            raise ProblemError(f"`segment_steps` must be an integer >= 1, got "
                               f"{self.segment_steps!r}")
        if self.rtol > 1e-3 * min(self.point_tol, self.defect_tol):
            raise ProblemError(f"`rtol` ({self.rtol:g}) must be at least 1000 times below "
                               f"`point_tol` and `defect_tol`: the integrator's error must "
                               f"not count in the certificate")


@dataclass(frozen=True)
class CertificateItem:
    """One check: ``value`` against ``tol`` (passes when ``value <= tol``).

    Attributes
    ----------
    name : str
    value : float
    tol : float
    passed : bool
    unit : str
    meaning : str
    """

    name: str
    value: float
    tol: float
    passed: bool
    unit: str
    meaning: str

    def __str__(self) -> str:
        verdict = "ok" if self.passed else "FAILED"
        unit = f" {self.unit}" if self.unit else ""
        return f"{self.name} = {self.value:.3g}{unit} (tol {self.tol:.3g}): {verdict}"


@dataclass(frozen=True)
class Certificate:
    """Outcome of :func:`certify`.

    Attributes
    ----------
    passed : bool
        Every item passed.
    items : tuple of CertificateItem
    figures : dict
        Everything measured, the items' values by their names included: ``point_error``
        (m) and ``velocity_error`` (rad/s) of the open loop at ``T``; ``state_error``, its
        final state minus the trajectory's; ``open_loop_deviation``, the same max-norm over
        every segment end; ``max_set_error`` (``max |sum u^2k - 1|``, not only the excess);
        ``integrator_success``; ``steps`` and ``rejected`` (the integrator's), ``nfev``
        (right-hand sides), ``segments``, ``rtol``.
    options : CertificateOptions
    open_loop_end : ndarray, shape (2n,)
        ``(q, qd)`` reached at ``T`` by the nominal torques from ``x(0)``.
    """

    passed: bool
    items: tuple[CertificateItem, ...]
    figures: dict
    options: CertificateOptions
    open_loop_end: np.ndarray = field(repr=False)

    @property
    def failures(self) -> tuple[CertificateItem, ...]:
        """The items that failed."""
        return tuple(i for i in self.items if not i.passed)

    def item(self, name: str) -> CertificateItem:
        """The item called ``name``."""
        for i in self.items:
            if i.name == name:
                return i
        raise KeyError(f"`name` {name!r} is not an item of this certificate; items: "
                       f"{[i.name for i in self.items]}")

    def summary(self) -> str:
        """One line: passed, or the failed items with their values and tolerances."""
        if self.passed:
            return "certified"
        return "certificate failed: " + "; ".join(str(i) for i in self.failures)
