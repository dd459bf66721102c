"""A stage-wise solution as a trajectory that the project's certificate takes.

:func:`~tocontrol_ros.core.checks.certificate.certify_open_loop` needs ``T``, ``t_grid``,
``evaluate``, ``state`` and ``control``; this adapter gives them for a solution ``w`` of a
:class:`~tocontrol_ros.core.direct.stagewise.StagewiseTranscription`: the joint path is the
interval's polynomial, the torques its inverse dynamics (so the certificate re-integrates
exactly the torques the NLP bounded).
"""

from __future__ import annotations

import numpy as np

from tocontrol_ros.core.direct.stagewise import StagewiseTranscription, inverse_dynamics
from tocontrol_ros.core.types.trajectory import TrajectorySample

__all__ = ["StageTrajectory"]


class StageTrajectory:
    """The motion of a stage-wise solution.

    Parameters
    ----------
    transcription : StagewiseTranscription
    w : ndarray
        Its solution vector (stage order).
    scale : ndarray, shape (n,)
        Torque limits times ``1 - reserve`` (N m): ``u = tau / scale``.

    Attributes
    ----------
    T : float
        Final time (s).
    t_grid : ndarray, shape (N + 1,)
        Node times (s).
    """

    def __init__(self, transcription: StagewiseTranscription, w: np.ndarray,
                 scale: np.ndarray) -> None:
        self.tr, self.w = transcription, np.asarray(w, dtype=float)
        self.scale = np.asarray(scale, dtype=float)
        self.n = transcription.model.n
        self.T = transcription.unpack(self.w)[0]
        self.t_grid = transcription.node_times(self.w)

    def evaluate(self, t) -> TrajectorySample:
        """``q, qd, qdd``, the torques and ``u`` at times ``t`` (s); no costates (NaN)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.T)
        q, qd, qdd = self.tr.evaluate(self.w, t)
        tau = inverse_dynamics(self.tr.model, q, qd, qdd)
        nan = np.full((len(t), self.n), np.nan)
        return TrajectorySample(t=t, q=q, qd=qd, qdd=qdd, u=tau / self.scale, tau=tau,
                                psi=np.hstack([nan, nan]), S=nan, H=np.full(len(t), np.nan))

    def state(self, t) -> np.ndarray:
        """Joint states (K, 2n) at times ``t`` (s)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q, qd, _ = self.tr.evaluate(self.w, t)
        return np.hstack([q, qd])

    def control(self, t: float) -> np.ndarray:
        """Normalised torques (n,) at one time (s)."""
        return self.evaluate(np.array([float(t)])).u[0]
