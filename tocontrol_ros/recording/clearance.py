"""The executed motions' clearance in the report (issue 51): Coal on the URDF's own geometry.

The planner's certificate checks the planned motion; this checks what the tracker executed,
from a recording alone: the measured joint states of each execution, every recorded sample,
with the same exact check (:meth:`~tocontrol_ros.core.geometry.collision.CollisionModel.
clearance`: Coal's signed distance of every checked pair on the URDF's ``<collision>``
meshes and primitives) and the planner's pairs (every link against every obstacle, every two
links but adjacent ones and an SRDF's disabled pairs, less the scene's allowed pairs).

Where the inputs come from:

- the geometry: the URDF the report loads (the recording's ``/robot_description``, which the
  recorder writes with ``link_frames``, or ``--urdf``; meshes found as the planner finds
  them, ``package://`` included);
- the obstacles: the planner's ``/planner/markers`` as recorded, namespace ``scene`` (the
  scene each plan avoided, names in the markers' ``text``): for a motion, the first markers
  message after its trajectory (before the next trajectory), else the last one before it;
  ``--scene FILE`` (the planner's ``scene_file``) where the recording has no scene markers;
- what the recording does not hold: the margin (``--margin``, default the planner's
  default, 0.01 m), the allowed pairs (``--scene FILE``'s ``allowed``) and the SRDF's
  disabled pairs (``--srdf FILE``, the planner's ``robot_description_semantic``).

The check runs when the recording has a scene (scene markers, or a ``min_clearance`` on
``/planner/status``: the planner checked clearance) or ``--scene``/``--srdf`` is given.

Between two samples ``h`` apart a pair's distance falls at most ``v h / 2`` below the mean
of its two ends (as the certificate bounds it, :meth:`CollisionModel.swept`), ``v`` the
pair's links' speed bound from the joint speeds (their lever arms,
:meth:`CollisionModel.lever_arms`) here taken as the recording shows them: each joint's
larger measured speed at the two ends (``velocity``, when recorded) or the chord's,
``|dq| / h``. That bound is an estimate, not a guarantee: the joint states do not show a
speed peak between two samples; record faster (the tracker's ``publish_rate``) for a tighter
bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tocontrol_ros.core.errors import ModelError, ProblemError
from tocontrol_ros.core.geometry.collision import CollisionModel, collision_model
from tocontrol_ros.core.geometry.scene import Scene, load_scene
from tocontrol_ros.core.geometry.tuning import DEFAULT_MARGIN
from tocontrol_ros.recording import mcap_io

__all__ = ["MARKERS", "SCENE_NS", "ClearanceOptions", "ExecutedClearance", "ClearanceCheck",
           "recorded_scenes", "executed_clearance", "planned_clearance", "plot_clearance"]

#: The planner's markers (the scene each plan avoided, namespace :data:`SCENE_NS`).
MARKERS = "/planner/markers"
SCENE_NS = "scene"
#: The planned motion's clearance is drawn at most at this many of its points.
PLANNED_POINTS = 200
#: Pairs drawn beside the minimum over all pairs: the ones that come closest.
PAIRS_DRAWN = 3
#: Size (inches) and resolution of a clearance figure: 990 x 360 pixels.
FIGSIZE, DPI = (11, 4), 90


@dataclass(frozen=True)
class ClearanceOptions:
    """What the recording does not hold (the report's options).

    Attributes
    ----------
    margin : float or None
        The planner's ``margin`` (m); None: its default (:data:`DEFAULT_MARGIN`).
    scene_file : str or None
        The planner's ``scene_file``: its allowed pairs, and its obstacles where the
        recording has no scene markers.
    srdf : str or None
        The planner's ``robot_description_semantic`` (SRDF file or XML): its disabled pairs.
    """

    margin: float | None = None
    scene_file: str | None = None
    srdf: str | None = None


@dataclass(frozen=True)
class ExecutedClearance:
    """One execution's clearance.

    Attributes
    ----------
    times : ndarray, shape (K,)
        The joint states' times from the execution's start (s).
    distance : ndarray, shape (K,)
        The least exact distance over the checked pairs at each sample (m; < 0 penetration).
    pair_distances : dict
        Pair ``(a, b)`` -> distances (K,) (m).
    minimum : float
        The least of ``distance`` (m).
    pair : tuple of str
        The pair at the minimum (``link/obstacle`` or ``link/link``).
    time : float
        When (s from the execution's start).
    lower_bound : float
        The least distance between the samples by the speed bound (m; module docstring).
    margin : float
        The margin checked (m).
    obstacles : tuple of str
        The scene's obstacles.
    """

    times: np.ndarray
    distance: np.ndarray
    pair_distances: dict = field(repr=False)
    minimum: float = np.inf
    pair: tuple = ("", "")
    time: float = 0.0
    lower_bound: float = np.inf
    margin: float = DEFAULT_MARGIN
    obstacles: tuple = ()

    @property
    def held(self) -> bool:
        """Whether every sample keeps the margin."""
        return bool(self.minimum >= self.margin)

    def line(self, index: int) -> str:
        """The summary's line for motion ``index``."""
        verdict = "margin held" if self.held else (
            f"margin VIOLATED ({'in contact' if self.minimum <= 0 else 'closer than the margin'})")
        return (f"motion {index} clearance: min {self.minimum:.4f} m ({'/'.join(self.pair)}) "
                f"at t = {self.time:.3f} s over {len(self.times)} joint states, margin "
                f"{self.margin:g} m: {verdict}; between samples >= {self.lower_bound:.4f} m "
                f"(joint speeds as recorded)")


def recorded_scenes(path) -> list[tuple[int, Scene]]:
    """The scenes of the recording's ``/planner/markers``: (log time ns, Scene) per message.

    A message without scene markers gives an empty scene. Obstacles are named by their
    markers' ``text`` (the planner's names), else ``scene/<id>``.

    Raises
    ------
    ProblemError
        A scene marker the planner would not have drawn (another type, a bad size).
    """
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import MarkerArray

    from tocontrol_ros.nodes.scene_markers import scene_from_markers

    if MARKERS not in mcap_io.read_channels(path):
        return []
    out = []
    for record in mcap_io.iter_records(path, topics=[MARKERS]):
        msg = deserialize_message(record.data, MarkerArray)
        drawn = [m for m in msg.markers if m.ns == SCENE_NS]
        if not drawn:
            out.append((record.log_time, Scene()))
            continue
        scene = scene_from_markers(MarkerArray(markers=drawn), Scene(),
                                   drawn[0].header.frame_id)
        names = {f"{m.ns}/{m.id}": m.text for m in drawn if m.text}
        out.append((record.log_time, Scene(tuple(
            replace(o, name=names.get(o.name, o.name), _coal=[]) for o in scene.obstacles))))
    return out


def scene_for(scenes: list, planned: int, next_planned: int | None) -> Scene | None:
    """The recorded scene of a plan logged at ``planned`` (ns): see the module; None: none."""
    after = [s for t, s in scenes if t >= planned and (next_planned is None
                                                        or t < next_planned)]
    if after:
        return after[0]
    before = [s for t, s in scenes if t < planned]
    return before[-1] if before else None


class ClearanceCheck:
    """The report's clearance check of one recording (built once, applied per motion).

    Parameters
    ----------
    model : RobotModel
        The report's model.
    urdf : str or os.PathLike or None
        Its URDF (XML or file); None: not known (nothing is checked).
    options : ClearanceOptions
    scenes : list of (int, Scene)
        :func:`recorded_scenes`.
    planner_clearance : bool
        Whether the planner's status reported a clearance (it checked one).

    Attributes
    ----------
    reason : str
        Empty when the check runs; else the one line that says why not.
    """

    def __init__(self, model, urdf, options: ClearanceOptions, scenes: list,
                 planner_clearance: bool) -> None:
        self.model = model
        self.options = options
        self.scenes = scenes
        self.base: CollisionModel | None = None
        self.file_scene = Scene()
        self.reason = ""
        margin = DEFAULT_MARGIN if options.margin is None else options.margin
        self.margin_source = "default" if options.margin is None else "--margin"
        wanted = (any(s.obstacles for _, s in scenes) or planner_clearance
                  or options.scene_file or options.srdf)
        if not wanted:
            self.reason = ("clearance: not checked (no scene in the recording: no scene "
                           "markers on /planner/markers, no min_clearance on /planner/status; "
                           "--scene FILE or --srdf FILE checks it)")
            return
        if urdf is None:
            self.reason = ("clearance: not checked (no URDF: the recording has no "
                           "/robot_description; --urdf FILE)")
            return
        try:
            if options.scene_file:
                self.file_scene = load_scene(options.scene_file, frame=model.base_link)
            self.base = collision_model(model, urdf, options.srdf, None, margin)
        except (ModelError, ProblemError) as exc:
            self.reason = f"clearance: not checked ({exc})"

    def header(self) -> str:
        """The summary's line about the check's inputs."""
        col = self.base
        srdf = f"SRDF {self.options.srdf}" if self.options.srdf else "no SRDF (--srdf)"
        allowed = (f"allowed pairs from {self.options.scene_file}" if self.options.scene_file
                   else "no allowed pairs (--scene)")
        return (f"clearance: executed joint states against the URDF's collision geometry "
                f"(Coal), margin {col.margin:g} m ({self.margin_source}), scene from "
                f"{MARKERS}, {srdf}, {allowed}")

    def model_for(self, planned: int, next_planned: int | None) -> CollisionModel:
        """The collision model of a plan logged at ``planned`` (ns): its scene, allowed pairs.

        Raises
        ------
        ProblemError
            Nothing to check (no obstacle, no self pair).
        """
        recorded = scene_for(self.scenes, planned, next_planned)
        obstacles = recorded.obstacles if recorded is not None and recorded.obstacles \
            else self.file_scene.obstacles
        known = set(self.base.links) | {o.name for o in obstacles}
        allowed = frozenset(p for p in self.file_scene.allowed if set(p) <= known)
        return self.base.with_scene(Scene(obstacles, allowed))


def executed_clearance(col: CollisionModel, t: np.ndarray, q: np.ndarray,
                       qd: np.ndarray | None = None) -> ExecutedClearance:
    """The clearance of an executed motion's joint states.

    Parameters
    ----------
    col : CollisionModel
    t : ndarray, shape (K,)
        Times from the execution's start (s), increasing.
    q : ndarray, shape (K, n)
        Measured joint positions in the model's joint order (rad, m).
    qd : ndarray, shape (K, n), optional
        Measured joint velocities (rad/s, m/s); None: the chords' speeds only.

    Raises
    ------
    ProblemError
        Nothing to check (no obstacle, no self pair).
    """
    t = np.asarray(t, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    exact = col.clearance(q)
    lower = np.inf
    if len(t) > 1:
        h = np.diff(t)
        speed = np.abs(np.diff(q, axis=0)) / np.where(h > 0, h, np.inf)[:, None]
        if qd is not None:
            qd = np.abs(np.asarray(qd, dtype=float))
            speed = np.maximum(speed, np.maximum(qd[:-1], qd[1:]))
        levers = col.link_levers  # the certificate's (speed_bounds)
        for (a, b), d in exact.pair_distances.items():
            rate = speed @ levers[a] + (speed @ levers[b] if b in levers else 0.0)
            lower = min(lower, float(np.min(0.5 * (d[:-1] + d[1:]) - rate * h / 2)))
    else:
        lower = exact.minimum
    return ExecutedClearance(t, exact.distance, exact.pair_distances, exact.minimum,
                             exact.pair, float(t[exact.index]), lower, col.margin,
                             col.scene.names())


def planned_clearance(col: CollisionModel, t: np.ndarray, q: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The planned motion's least distance at up to :data:`PLANNED_POINTS` of its points.

    Returns times (s) and distances (m), both (K,).
    """
    pick = np.unique(np.linspace(0, len(t) - 1, min(len(t), PLANNED_POINTS)).round()
                     .astype(int))
    return np.asarray(t)[pick], col.clearance(np.asarray(q)[pick]).distance


def plot_clearance(plt, index: int, found: ExecutedClearance, planned, path):
    """``clearance_<i>.png``: the executed clearance against time, the margin, the plan's.

    Parameters
    ----------
    plt : module
        ``matplotlib.pyplot``.
    index : int
        The motion's number.
    found : ExecutedClearance
    planned : tuple of ndarray or None
        :func:`planned_clearance`'s times (s) and distances (m), drawn dashed.
    path : pathlib.Path
        Where the PNG goes (returned).
    """
    fig, ax = plt.subplots(figsize=FIGSIZE)
    closest = sorted(found.pair_distances.items(), key=lambda kv: float(np.min(kv[1])))
    for i, (pair, d) in enumerate(closest[:PAIRS_DRAWN]):
        ax.plot(found.times, d, color=f"C{i + 1}", lw=1.0, label="/".join(pair))
    ax.plot(found.times, found.distance, color="k", lw=1.8, label="executed (least)")
    if planned is not None:
        ax.plot(planned[0], planned[1], "--", color="C0", lw=1.2, label="planned (least)")
    ax.axhline(found.margin, color="C3", ls=":", lw=1.2, label=f"margin {found.margin:g} m")
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.plot([found.time], [found.minimum], "o", color="C3", ms=6)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("distance (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="upper right")
    ax.set_title(f"Motion {index}: clearance of the executed joint states (Coal), min "
                 f"{found.minimum:.4f} m {'/'.join(found.pair)} at t = {found.time:.3f} s")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
