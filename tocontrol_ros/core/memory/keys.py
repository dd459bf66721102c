"""What a memory is valid for: the robot's hash and the options' hash.

A stored motion is an optimum of one model (its chain, inertias, torque limits, gravity,
task axes) and one problem class (exponent ``k``, torque ``reserve``, the joint limits with
their margin, the method). A memory is keyed by both; one made for another robot or other
options is refused (:class:`~tocontrol_ros.core.memory.store.MemoryFileError`) rather than
served, since its motions would be optimal for something else. How widely the build
searched (``starts``, ``candidates``) is not in the key: a wider search is the point of
building offline.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

__all__ = ["robot_hash", "options_hash", "options_summary", "HASH_DIGITS"]

#: Hex digits kept of each SHA-256 (64 bits: no accidental collision among a site's robots).
HASH_DIGITS = 16
#: Significant digits of every float hashed: far below any tolerance of a model or limit,
#: far above the noise of a URDF parsed twice (which is none: parsing is deterministic).
_DIGITS = 12


def _canonical(value):
    """JSON-able, deterministic form of a model's fields (dataclasses, arrays, numbers)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _canonical(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.init and not f.name.startswith("_")}
    if isinstance(value, np.ndarray):
        return [_canonical(v) for v in value.tolist()] if value.ndim else \
            _canonical(value.item())
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return repr(v) if not np.isfinite(v) else float(f"{v:.{_DIGITS}g}")
    return str(value)


def _digest(value) -> str:
    text = json.dumps(_canonical(value), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:HASH_DIGITS]


def robot_hash(model) -> str:
    """The hash of a :class:`~tocontrol_ros.core.robot.model.RobotModel` (16 hex digits).

    Over every field the model was built with (chain, inertias, limits, friction, gravity,
    task axes), not over the URDF text: the same arm loaded from a file or from
    ``robot_description`` has the same hash.
    """
    return _digest(model)


def options_summary(problem, method: str = "auto") -> dict:
    """The problem class a memory holds optimal motions of (what :func:`options_hash` hashes).

    Parameters
    ----------
    problem : Problem
        Any problem of the class: its ``k``, ``reserve`` and ``limits`` count.
    method : str
        ``SolverOptions.method``.
    """
    limits = problem.limits
    lim = None if limits is None else {
        "names": list(limits.names), "lower": limits.lower, "upper": limits.upper,
        "velocity": limits.velocity, "margin": limits.margin}
    return _canonical({"k": problem.k, "reserve": problem.reserve, "limits": lim,
                       "method": method})


def options_hash(problem, method: str = "auto") -> str:
    """The hash of :func:`options_summary` (16 hex digits)."""
    return _digest(options_summary(problem, method))
