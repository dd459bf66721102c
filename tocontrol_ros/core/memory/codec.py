"""A result's warm state and motion as bytes (numpy ``.npz``), and back.

A stored motion carries what its method needs to continue it (the contract's
:meth:`~tocontrol_ros.core.methods.contract.Method.warm_start`): for the bounded solve
(:class:`~tocontrol_ros.core.direct.warm.PathWarmState`) the B-spline mesh, control points,
``T`` and the NLP's multipliers; for the maximum principle
(:class:`~tocontrol_ros.core.indirect.warm.WarmState`) the shooting mesh and unknowns (the
LU factors are not kept: a warm start refactors). Plain arrays in an ``.npz``
(``allow_pickle=False`` on reading), so that a memory file never runs code and reads the
same on any machine. A blob that does not decode raises :class:`CodecError` naming what was
wrong.
"""

from __future__ import annotations

import io
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from tocontrol_ros.core.direct.warm import PathWarmState
from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.indirect.warm import WarmState
from tocontrol_ros.core.types.problem import Problem
from tocontrol_ros.core.types.result import PlanResult, Status

__all__ = ["CodecError", "encode_warm", "decode_warm", "encode_sample", "decode_sample",
           "warm_result", "without_multipliers", "SampledPath", "WARM_KINDS"]

#: The warm states a memory can hold, by the name stored with them.
WARM_KINDS = ("path", "shooting")
_SAMPLE_FIELDS = ("t", "q", "qd", "qdd", "tau")


class CodecError(TocontrolError, ValueError):
    """A stored blob that does not decode (corrupt, or of another version)."""


def _pack(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def _unpack(blob: bytes, what: str) -> dict:
    try:
        with np.load(io.BytesIO(bytes(blob)), allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except Exception as exc:  # noqa: BLE001  (zip, npy and value errors alike: corrupt)
        raise CodecError(f"{what}: not a readable npz blob ({type(exc).__name__}: {exc})"
                         ) from None


def encode_warm(result: PlanResult) -> tuple[str, bytes]:
    """``(kind, blob)`` of a successful result's warm state (``kind`` in :data:`WARM_KINDS`).

    The blob also holds ``T`` (s), ``k`` and ``delta`` of the result (a maximum-principle
    warm start steps from them).

    Raises
    ------
    CodecError
        No warm state, or one of a kind a memory cannot hold.
    """
    st = result.warm_state
    head = {"T": np.float64(result.T), "k": np.float64(result.k),
            "delta": np.float64(result.delta if math.isfinite(result.delta) else 0.0)}
    if isinstance(st, PathWarmState):
        arrays = {**head, "breaks": np.asarray(st.breaks, float), "P": np.asarray(st.P, float),
                  "path_T": np.float64(st.T)}
        if st.lam_g is not None and st.lam_x is not None:
            arrays.update(lam_g=np.asarray(st.lam_g, float), lam_x=np.asarray(st.lam_x, float))
        return "path", _pack(arrays)
    if isinstance(st, WarmState):
        breaks = np.asarray(st.breaks, dtype=np.int64).reshape(-1, 2)
        return "shooting", _pack({**head, "lengths": np.asarray(st.lengths, float),
                                  "w": np.asarray(st.w, float),
                                  "steps": np.int64(st.steps),
                                  "kinds": np.asarray(st.kinds, np.int64),
                                  "breaks": breaks})
    raise CodecError(f"the result has no warm state a memory can hold "
                     f"({type(st).__name__}); only 'direct' and 'indirect' results do")


def _field(data: dict, name: str, what: str, ndim: int | None = None) -> np.ndarray:
    if name not in data:
        raise CodecError(f"{what}: field {name!r} missing")
    value = data[name]
    if ndim is not None and value.ndim != ndim:
        raise CodecError(f"{what}: field {name!r} has {value.ndim} dimensions, expected {ndim}")
    if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
        raise CodecError(f"{what}: field {name!r} is not finite")
    return value


def decode_warm(kind: str, blob: bytes, what: str = "warm state") -> tuple[object, dict]:
    """The warm state of a blob and its ``{"T", "k", "delta"}``; raises :class:`CodecError`."""
    data = _unpack(blob, what)
    head = {name: float(_field(data, name, what, 0)) for name in ("T", "k", "delta")}
    if kind == "path":
        lam = ("lam_g" in data and "lam_x" in data)
        state = PathWarmState(breaks=_field(data, "breaks", what, 1),
                              P=_field(data, "P", what, 2),
                              T=float(_field(data, "path_T", what, 0)),
                              lam_g=_field(data, "lam_g", what, 1) if lam else None,
                              lam_x=_field(data, "lam_x", what, 1) if lam else None)
    elif kind == "shooting":
        breaks = _field(data, "breaks", what, 2)
        state = WarmState(lengths=_field(data, "lengths", what, 1),
                          w=_field(data, "w", what, 1), steps=int(_field(data, "steps", what, 0)),
                          kinds=_field(data, "kinds", what, 1),
                          breaks=[(int(j), int(i)) for j, i in breaks], factors=None)
    else:
        raise CodecError(f"{what}: unknown warm-state kind {kind!r}; known: {WARM_KINDS}")
    return state, head


class SampledPath:
    """A stored motion's joint path between its samples (cubic Hermite in ``q`` and ``qd``).

    What a bounded warm re-solve on another mesh fits its start to
    (``SolverOptions.replan_spans``): ``evaluate(t)`` with ``t``, ``q`` and ``qd``.

    Parameters
    ----------
    sample : dict
        :func:`decode_sample`'s arrays: ``t`` (K,) s, ``q`` and ``qd`` (K, n).
    """

    def __init__(self, sample: dict) -> None:
        from scipy.interpolate import CubicHermiteSpline

        self.T = float(sample["t"][-1])
        self._q = CubicHermiteSpline(sample["t"], sample["q"], sample["qd"])
        self._qd = CubicHermiteSpline(sample["t"], sample["qd"], sample["qdd"])

    def evaluate(self, t) -> SimpleNamespace:
        """``t`` (s, clipped to [0, T]), ``q`` (rad) and ``qd`` (rad/s) at those times."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        return SimpleNamespace(t=t, q=self._q(t), qd=self._qd(t))


def warm_result(problem: Problem, kind: str, blob: bytes, method: str,
                what: str = "warm state", trajectory=None) -> PlanResult:
    """A :class:`PlanResult` that warm-starts a solve from a stored motion.

    Parameters
    ----------
    problem : Problem
        The stored motion's problem, rebuilt on the caller's model (a warm start continues
        only a result of the same model object).
    kind, blob : str, bytes
        From :func:`encode_warm`.
    method : str
        The stored result's ``method``.
    trajectory : SampledPath, optional
        The stored motion's path, for a warm re-solve on another mesh.

    Returns
    -------
    PlanResult
        Success, the stored ``T``, ``k``, ``delta``, warm state and path: only a warm start
        reads it.
    """
    state, head = decode_warm(kind, blob, what)
    return PlanResult(success=True, status=Status.SUCCESS, message="stored motion",
                      T=head["T"], k=head["k"], trajectory=trajectory, residual=0.0,
                      iterations=0,
                      timings={}, continuation=(), max_abs_u=float("nan"),
                      delta=head["delta"], intervals=0, problem=problem, warm_state=state,
                      method=method)


def without_multipliers(warm: PlanResult) -> PlanResult | None:
    """The same warm start from the path alone (no NLP multipliers); None without any.

    A bounded warm re-solve from a solution and its multipliers is IPOPT's quickest when it
    works, but from a stored motion a few centimetres away it can fail in its first steps
    (``Error_In_Step_Computation``) where the same path without multipliers converges.
    """
    st = warm.warm_state
    if not isinstance(st, PathWarmState) or st.lam_g is None:
        return None
    return replace(warm, warm_state=replace(st, lam_g=None, lam_x=None))


def encode_sample(sample) -> bytes:
    """The sampled motion (``t`` (K,) s; ``q``, ``qd``, ``qdd`` (K, n); ``tau`` (K, n) N m)."""
    return _pack({name: np.asarray(getattr(sample, name), float) for name in _SAMPLE_FIELDS})


def decode_sample(blob: bytes, what: str = "trajectory") -> dict:
    """The arrays of :func:`encode_sample` by name; raises :class:`CodecError`."""
    data = _unpack(blob, what)
    out = {name: _field(data, name, what) for name in _SAMPLE_FIELDS}
    if out["t"].ndim != 1 or any(out[n].shape[:1] != out["t"].shape for n in _SAMPLE_FIELDS):
        raise CodecError(f"{what}: the sample's arrays do not have one row per time")
    return out
