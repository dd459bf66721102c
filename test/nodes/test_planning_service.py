"""The planning service without ROS: its policy driven with fakes, no node, no spinning.

A fake planner (solves on demand, held at a gate while a test queues more requests), fake
outputs that record every publication in order, a fake arm and a fake clock for the stamps.
Nothing waits on wall time except for events the test itself triggers, each bounded.
"""

from __future__ import annotations

import itertools
import re
import threading
import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np
import pytest

from tocontrol_ros.core.errors import ProblemError
from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.nodes.planner_config import config_from_values, planner_limits
from tocontrol_ros.nodes.planning_service import Clock, PlanningService, replanning
from tocontrol_ros.nodes.replanning import REST_RESERVE
from tocontrol_ros.nodes.requests import PlanRequest

#: Bound of every wait in these tests (s): a failure, never a slow pass.
WAIT = 10.0

MODEL = load_robot(default_urdf_path())


# ------------------------------------------------------------------- fakes
@dataclass
class FakeSample:
    """A sampled trajectory: ``n`` samples of a 3-joint arm at rest."""

    n: int

    def __post_init__(self) -> None:
        self.t = np.linspace(0.0, 1.0, self.n)
        self.q = np.zeros((self.n, 3))
        self.qd = self.qdd = self.tau = np.zeros((self.n, 3))


@dataclass
class FakeResult:
    """What the service reads of a :class:`~tocontrol_ros.core.types.result.PlanResult`."""

    T: float
    status: str = "SOLVED"
    success: bool = True
    method: str = "shooting"
    message: str = ""
    samples: int = 5
    k: float = 8.0
    iterations: int = 3
    residual: float = 1e-10
    max_abs_u: float = 1.0
    certificate: object = None
    problem: object = None
    warm_state: object = None
    warnings: tuple = ()
    starts: list = field(default_factory=list)
    timings: dict = field(default_factory=lambda: {"total": 0.01})

    def __post_init__(self) -> None:
        self.status = SimpleNamespace(name=self.status)
        self.trajectory = SimpleNamespace(sample=lambda dt: FakeSample(self.samples)) \
            if self.success else None

    warm: bool = False  # whether a later request may warm-start from it

    def can_warm_start(self, problem) -> bool:
        return self.warm


class FakePlanner:
    """Returns the results it is told to; once ``hold`` is set, each solve waits at the gate.

    ``entered`` is set when a held solve has started (the worker is then busy).
    """

    def __init__(self, model) -> None:
        self.optimum = FakeResult(T=1.5)
        self.first_result = FakeResult(T=2.0, method="first")
        self.error: Exception | None = None
        self.hold = threading.Event()
        self.gate = threading.Event()
        self.entered = threading.Event()
        self.solved: list = []  # the problems solved after the warm-up, in order
        #: Given to a warm solve's ``on_first`` before it returns (the first iterate).
        self.iterate: FakeResult | None = None
        self.on_firsts: list = []  # whether each solve got an on_first

    def stale(self) -> bool:
        return False

    def prepare(self, problem, options) -> None:
        pass

    def first(self, problem, options) -> FakeResult:
        return self.first_result

    def plan(self, problem, options, warm_start=None, should_stop=None,
             on_first=None) -> FakeResult:
        if not self.hold.is_set():  # the warm-up's throw-away solves
            return self.optimum
        self.solved.append(problem)
        self.on_firsts.append(on_first is not None)
        self.entered.set()
        assert self.gate.wait(WAIT), "the test never opened the gate"
        if self.error is not None:
            raise self.error
        if on_first is not None and self.iterate is not None:
            on_first(self.iterate)
        return self.optimum


class FakeOutputs:
    """Records each output as ``(kind, ...)`` in call order."""

    def __init__(self) -> None:
        self.events: list = []
        self._lock = threading.Lock()

    def _add(self, *event) -> None:
        with self._lock:
            self.events.append(event)

    def status(self, level, message, values, routine=False) -> None:
        self._add("status", level, message, dict(values))

    def log_error(self, message) -> None:
        self._add("log", message)

    def trajectory(self, sample, stamp_ns):
        self._add("trajectory", sample.n, stamp_ns)
        return ("trajectory", stamp_ns)

    def path(self, sample, stamp_ns):
        self._add("path", sample.n)
        return ("path", sample.n, stamp_ns)

    def follow(self, request_id, trajectory, config) -> None:
        self._add("follow", request_id)

    def markers(self, result, path, config, start_point, target) -> None:
        self._add("markers", result.T)

    def rest_path(self, point):
        return ("rest", tuple(point))

    def statuses(self, event: str | None = None) -> list:
        with self._lock:
            return [e for e in self.events if e[0] == "status"
                    and (event is None or e[3].get("event") == event)]

    def kinds(self) -> list:
        with self._lock:
            return [e[0] for e in self.events]


class FakeArm:
    """The arm at rest at the paper's start, no joint state with a stamp."""

    def start(self, config, since_ns, fresh=True) -> tuple:
        return ("point", np.array(config.default_start))

    def latest(self, config) -> tuple:
        return 0, None


class FakeClock:
    """The node's clock and the wall clock: 1 s further at each reading."""

    def __init__(self) -> None:
        self._ticks = itertools.count(1)

    def now_ns(self) -> int:
        return next(self._ticks) * 10**9

    def clock(self) -> Clock:
        return Clock(now_ns=self.now_ns, wall_ns=self.now_ns)


# ----------------------------------------------------------------- fixture
@pytest.fixture
def make_service():
    """A started service with the given parameters; stopped after the test."""
    services = []

    def make(**params):
        config = config_from_values(params, task_dim=MODEL.m)
        out = FakeOutputs()
        service = PlanningService(MODEL, planner_limits(config, MODEL), config, "base_link",
                                  out, FakeArm(), FakeClock().clock(),
                                  planner_factory=FakePlanner)
        services.append(service)
        service.start()
        assert service.ready.wait(WAIT), "no warm-up"
        service.planner.hold.set()
        return service, out

    yield make
    for service in services:
        service.planner.gate.set()
        service.stop()


def request(service, target=PAPER_TARGET, source="service", queue=False) -> PlanRequest:
    return PlanRequest(service.next_id(), source, ("point", np.array(PAPER_START)),
                       np.array(target), service.config, queue=queue)


def wait_until(predicate) -> None:
    deadline = time.monotonic() + WAIT
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def wait_done(*reqs) -> None:
    for req in reqs:
        assert req.done.wait(WAIT), f"request {req.id} got no outcome"


def final(out: FakeOutputs, req: PlanRequest) -> dict:
    """The final status of ``req``: level, event, message and values."""
    events = [e for e in out.statuses() if e[3].get("request_id") == req.id
              and e[3]["event"] not in ("accepted", "first")]
    assert len(events) == 1, events
    _, level, message, values = events[0]
    return {"level": level, "event": values["event"], "message": message, "values": values}


# ------------------------------------------------------------------- tests
def test_the_warm_up_reports_ready(make_service):
    _, out = make_service()
    events = [e[3]["event"] for e in out.statuses()]
    assert events[0] == "warming up" and events[-1] == "ready"


class BrokenBuildPlanner(FakePlanner):
    """Its warm-up build fails as a compile lock refused by the kernel once did."""

    def prepare(self, problem, options) -> None:
        raise OSError(35, "Resource deadlock avoided")


def test_a_warm_up_that_fails_says_so_and_the_service_still_serves():
    config = config_from_values({}, task_dim=MODEL.m)
    out = FakeOutputs()
    service = PlanningService(MODEL, planner_limits(config, MODEL), config, "base_link",
                              out, FakeArm(), FakeClock().clock(),
                              planner_factory=BrokenBuildPlanner)
    service.start()
    try:
        assert service.ready.wait(WAIT), "the worker died in the warm-up"
        ready = [e for e in out.statuses() if e[3]["event"] == "ready"]
        assert len(ready) == 1 and "warm-up failed: OSError" in ready[0][2], ready
        req = request(service)
        service.submit(req)
        wait_done(req)
        assert final(out, req)["event"] == "solved"
    finally:
        service.stop()


def test_a_newer_request_supersedes_the_pending_one_and_cancels_the_running_one(make_service):
    service, out = make_service()
    a = request(service)
    service.submit(a)
    assert service.planner.entered.wait(WAIT)
    b, c = request(service), request(service)
    service.submit(b)  # a is cancelled during its solve; b waits
    assert a.cancelled.is_set()
    service.submit(c)  # b is replaced before its solve started
    wait_done(b)
    assert final(out, b)["event"] == "superseded"
    assert "before its solve started" in final(out, b)["message"]
    service.planner.gate.set()
    wait_done(a, c)
    assert final(out, a)["event"] == "superseded" and final(out, a)["level"] == "WARN"
    assert "during its solve" in final(out, a)["message"]
    assert final(out, c)["event"] == "solved" and final(out, c)["level"] == "OK"
    # One answer each; only the newest published a motion.
    assert a.path is None and b.path is None and c.path == ("path", 5, c.path[2])
    assert out.kinds().count("trajectory") == 1


def test_replanning_goals_queue_behind_the_running_one(make_service):
    service, out = make_service(goal_queue=5)
    assert replanning(service.config)
    targets = [np.array(PAPER_TARGET) + [0.01 * i, 0.0] for i in range(3)]
    service.goal(service.next_id(), targets[0], 0, 0.0)
    assert service.planner.entered.wait(WAIT)
    for target in targets[1:]:
        service.goal(service.next_id(), target, 0, 0.0)
    assert not out.statuses("superseded")
    service.planner.gate.set()
    wait_until(lambda: len(out.statuses("solved")) == 3)
    solved = out.statuses("solved")
    # Solved in their order of arrival, none cancelled, each published.
    assert [e[3]["request_id"] for e in solved] == [1, 2, 3]
    assert [p.target_point.tolist() for p in service.planner.solved] == \
        [t.tolist() for t in targets]
    # A goal's plan is stamped the lead of motions from rest ahead of the wall clock of the
    # tracker's stamps (the fake clock's whole seconds; no joint state, so no grid to align
    # to): replan_min_lead plus the delivery reserve, at most REST_RESERVE more.
    lead = int(service.replanner.rest_lead(service.config) * 1e9)
    assert service.config.replan_min_lead * 1e9 < lead <= \
        (service.config.replan_min_lead + REST_RESERVE) * 1e9
    stamps = [e[2] for e in out.events if e[0] == "trajectory"]
    assert len(stamps) == 3 and all(s % 10**9 == lead for s in stamps)
    assert stamps == sorted(stamps)


def test_service_requests_never_queue(make_service):
    service, out = make_service(goal_queue=5)
    a = request(service)
    service.submit(a)
    assert service.planner.entered.wait(WAIT)
    b = request(service)
    service.submit(b)
    assert a.cancelled.is_set() and a.cancel_reason[0] == "superseded"
    service.planner.gate.set()
    wait_done(a, b)


def test_first_then_optimum_publishes_the_first_motion_before_the_optimum(make_service):
    service, out = make_service(publish="first_then_optimum")
    service.planner.gate.set()
    req = request(service)
    service.submit(req)
    wait_done(req)
    published = [e for e in out.events if e[0] in ("trajectory", "status")
                 and (e[0] == "trajectory" or e[3]["event"] in ("first", "solved"))]
    kinds = [e[0] if e[0] == "trajectory" else e[3]["event"] for e in published]
    assert kinds == ["trajectory", "first", "trajectory", "solved"]
    first = out.statuses("first")[0][3]
    assert first["published"] == "first" and first["T"] == 2.0
    done = final(out, req)["values"]
    assert done["published"] == "optimum" and done["T"] == 1.5
    assert out.kinds()[-1] == "markers"


def test_a_first_motion_that_is_faster_stands(make_service):
    service, out = make_service(publish="first_then_optimum")
    service.planner.optimum = FakeResult(T=2.5)
    service.planner.gate.set()
    req = request(service)
    service.submit(req)
    wait_done(req)
    done = final(out, req)
    assert done["level"] == "WARN" and "the first motion stands" in done["message"]
    assert done["values"]["optimum_T"] == 2.5 and done["values"]["T"] == 2.0
    assert out.kinds().count("trajectory") == 1 and req.path is not None


def _published(out: FakeOutputs, req: PlanRequest, since: int) -> list:
    """The trajectories from event ``since`` on and ``req``'s ``first``/``solved`` statuses,
    in order: ("trajectory",) or (event, T)."""
    return [("trajectory",) if e[0] == "trajectory" else (e[3]["event"], e[3]["T"])
            for e in out.events[since:] if e[0] == "trajectory" or (
                e[0] == "status" and e[3].get("request_id") == req.id
                and e[3]["event"] in ("first", "solved"))]


def test_a_warm_solves_first_iterate_is_published_before_the_optimum(make_service):
    """``first_then_optimum`` with a warm start: the solve's first certified iterate
    (``on_first``) is published at once as a first motion when it is faster than the first
    motion published before it; the optimum follows as before. Without a warm start the
    solve gets no ``on_first``."""
    service, out = make_service(publish="first_then_optimum")
    service.planner.optimum = FakeResult(T=1.5, warm=True)
    service.planner.iterate = FakeResult(T=1.6, method="direct")
    service.planner.gate.set()
    cold = request(service)
    service.submit(cold)
    wait_done(cold)
    warm, since = request(service), len(out.events)
    service.submit(warm)
    wait_done(warm)
    assert service.planner.on_firsts == [False, True]
    assert _published(out, warm, since) == [("trajectory",), ("first", 2.0), ("trajectory",),
                                     ("first", 1.6), ("trajectory",), ("solved", 1.5)]
    iterate = [e[3] for e in out.statuses("first") if e[3]["request_id"] == warm.id][1]
    assert iterate["published"] == "first" and iterate["iterate"] is True
    assert final(out, warm)["values"]["published"] == "optimum"


def test_a_first_iterate_slower_than_the_first_motion_is_not_published(make_service):
    """The warm solve's first iterate is no faster than the first motion published: not
    published; and an optimum slower than the iterate published leaves the iterate
    standing."""
    service, out = make_service(publish="first_then_optimum")
    service.planner.optimum = FakeResult(T=1.5, warm=True)
    service.planner.gate.set()
    cold = request(service)
    service.submit(cold)
    wait_done(cold)
    service.planner.iterate = FakeResult(T=2.2, method="direct")
    slower, since = request(service), len(out.events)
    service.submit(slower)
    wait_done(slower)
    assert _published(out, slower, since) == [("trajectory",), ("first", 2.0), ("trajectory",),
                                       ("solved", 1.5)]
    service.planner.iterate = FakeResult(T=1.4, method="direct")
    service.planner.optimum = FakeResult(T=1.45, warm=True)
    stands, since = request(service), len(out.events)
    service.submit(stands)
    wait_done(stands)
    assert _published(out, stands, since) == [("trajectory",), ("first", 2.0), ("trajectory",),
                                       ("first", 1.4), ("solved", 1.4)]
    done = final(out, stands)
    assert "the first motion stands" in done["message"] and done["values"]["optimum_T"] == 1.45


def test_a_failed_solve_publishes_nothing(make_service):
    service, out = make_service()
    service.planner.optimum = FakeResult(T=float("nan"), status="NO_CONVERGENCE",
                                         success=False, message="no convergence")
    service.planner.gate.set()
    req = request(service)
    service.submit(req)
    wait_done(req)
    done = final(out, req)
    assert done["level"] == "ERROR" and done["event"] == "failed"
    assert "trajectory" not in out.kinds() and req.path is None


def test_bad_input_fails_that_request_and_the_service_keeps_serving(make_service):
    service, out = make_service()
    service.planner.gate.set()
    far = request(service, target=(50.0, 50.0))  # out of the 3R arm's reach
    service.submit(far)
    wait_done(far)
    assert final(out, far)["level"] == "ERROR" and final(out, far)["event"] == "failed"
    with pytest.raises(ProblemError):
        service.problem(service.config, far.start, far.target)
    ok = request(service)
    service.submit(ok)
    wait_done(ok)
    assert final(out, ok)["event"] == "solved"


def test_an_internal_error_fails_that_request_and_the_service_keeps_serving(make_service):
    service, out = make_service()
    service.planner.error = RuntimeError("a bug")
    service.planner.gate.set()
    bad = request(service)
    service.submit(bad)
    wait_done(bad)
    assert "internal error" in final(out, bad)["message"]
    assert ("log", f"request {bad.id}: internal error: RuntimeError('a bug')") in out.events
    service.planner.error = None
    ok = request(service)
    service.submit(ok)
    wait_done(ok)
    assert final(out, ok)["event"] == "solved"


def test_stop_answers_the_pending_request(make_service):
    service, out = make_service()
    # Two goals: the second queues behind the running one (which it does not cancel).
    running, pending = (request(service, source="goal", queue=True) for _ in range(2))
    service.submit(running)
    assert service.planner.entered.wait(WAIT)
    service.submit(pending)
    assert not running.cancelled.is_set()
    service.stop(timeout=0.0)
    wait_done(pending)
    assert final(out, pending)["event"] == "cancelled"
    assert "node shutting down" in final(out, pending)["message"]
    service.planner.gate.set()
    wait_done(running)
    assert final(out, running)["event"] == "cancelled"



def test_a_plan_only_request_publishes_nothing_and_keeps_its_motions(make_service):
    """``execute`` false (the ~/plan_motion action's default): the first motion and the
    optimum are solved and kept on the request, nothing is published (issue 52)."""
    service, out = make_service(publish="first_then_optimum")
    service.planner.gate.set()
    req = request(service)
    req.execute = False
    service.submit(req)
    wait_done(req)
    assert "trajectory" not in out.kinds() and "markers" not in out.kinds()
    assert req.first is service.planner.first_result
    assert req.result is service.planner.optimum
    assert final(out, req)["values"]["published"] == "returned"


def test_a_first_motion_finished_after_a_cancel_is_kept_not_published(make_service):
    """A cancel during the first motion (it is not interruptible): the motion, certified, is
    kept as the request's best known one, for the action's result; nothing is published."""
    service, out = make_service(publish="first_then_optimum")
    req = request(service)
    planner = service.planner
    real_first = planner.first

    def first_then_cancelled(problem, options):
        req.cancel("cancelled", "cancelled by the action client")
        return real_first(problem, options)

    planner.first = first_then_cancelled
    planner.gate.set()
    service.submit(req)
    wait_done(req)
    assert req.first is planner.first_result and req.result is None
    assert final(out, req)["event"] == "cancelled"
    assert "trajectory" not in out.kinds()


def two_motions(make_service):
    """A service that published two motions, one request after the other: ``(service, out,
    a, b)``, ``b``'s motion the last published."""
    service, out = make_service()
    service.planner.gate.set()
    a, b = request(service), request(service)
    service.submit(a)
    wait_done(a)
    service.submit(b)
    wait_done(b)
    return service, out, a, b


def test_a_motion_the_controller_refused_is_no_longer_continued(make_service):
    """The controller refused the last published motion: a ``refused`` status, and the
    replanner forgets it (the next goal starts from the measured state); a refusal of an
    older motion, replaced since, changes nothing."""
    service, out, a, b = two_motions(make_service)
    assert service.replanner.has_motion()
    service.controller_refused(a.id, "rejected")  # replaced by b's motion since
    assert service.replanner.has_motion() and out.statuses("refused") == []
    service.controller_refused(b.id, "the controller at /arm/follow rejected it")
    assert not service.replanner.has_motion()
    [(_, level, message, values)] = out.statuses("refused")
    assert level == "WARN" and values["request_id"] == b.id
    assert "not executing (the controller at /arm/follow rejected it)" in message


def test_a_motion_the_tracker_rejected_on_the_topic_is_no_longer_continued(make_service):
    """A tracker's ``rejected`` status with the stamp of the last published trajectory: as a
    controller's refusal (a ``refused`` status, the replanner forgets the motion); another
    stamp (an older trajectory, or one never published) changes nothing."""
    service, out, a, b = two_motions(make_service)
    stamps = [e[2] for e in out.events if e[0] == "trajectory"]
    assert len(stamps) == 2 and service.replanner.has_motion()
    service.tracker_rejected(stamps[0] * 1e-9, "an older one")
    service.tracker_rejected(stamps[1] * 1e-9 + 1e-3, "another stamp")
    assert service.replanner.has_motion() and out.statuses("refused") == []
    service.tracker_rejected(stamps[1] * 1e-9, "at its take-over its position is 0.2 rad off")
    assert not service.replanner.has_motion()
    [(_, level, message, values)] = out.statuses("refused")
    assert level == "WARN" and values["request_id"] == b.id
    assert "the tracker rejected it: at its take-over its position is 0.2 rad off" in message


def _refused_before_any_solve(service, out, req, message: str) -> None:
    """Submit ``req``; it fails (ERROR) with ``message`` (a regex), nothing solved or sent."""
    service.submit(req)
    # The refusal's IK rounds and exact distances (about 1 s of CPU) on a loaded machine.
    assert req.done.wait(6 * WAIT), "no outcome"
    done = final(out, req)
    assert done["level"] == "ERROR" and done["event"] == "failed"
    assert re.search(message, done["message"]), done["message"]
    assert service.planner.solved == [] and "trajectory" not in out.kinds()


@pytest.mark.slow  # the Panda's collision model and the refusal: 27 s at load 16
def test_a_target_with_no_clear_configuration_fails_before_any_solve():
    # The Panda with a 10 cm ball around the target (issue 51): the request fails with the
    # core's refusal, naming the closest pair; the planner is never asked to solve it.
    pytest.importorskip("coal")
    from skip_policy import panda_srdf, panda_urdf

    from tocontrol_ros.core.geometry.collision import collision_model
    from tocontrol_ros.core.geometry.scene import scene_from_dict
    from tocontrol_ros.nodes.pose_goals import pose_target

    urdf = panda_urdf()
    panda = load_robot(urdf, tip_link="panda_hand",
                       locked_joints={"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0})
    config = config_from_values({"default_start": [0.3, 0.0, 0.5]}, task_dim=panda.m)
    out = FakeOutputs()
    service = PlanningService(panda, planner_limits(config, panda), config, "panda_link0",
                              out, FakeArm(), FakeClock().clock(), planner_factory=FakePlanner)
    service.collision = collision_model(panda, urdf, panda_srdf(), scene_from_dict(
        {"obstacles": [{"name": "block", "type": "sphere", "radius": 0.1,
                        "position": [0.3, 0.4, 0.5]}]}))
    service.start()
    try:
        assert service.ready.wait(WAIT), "no warm-up"
        service.planner.hold.set()
        service.planner.gate.set()
        req = PlanRequest(service.next_id(), "service", ("point", np.array([0.3, 0.0, 0.5])),
                          np.array([0.3, 0.4, 0.5]), config)
        _refused_before_any_solve(service, out, req, r"`target` point \[0\.3, 0\.4, 0\.5\] "
                                  r"has no configuration clear of the scene by the margin "
                                  r".* \w+ and block closest")
        assert req.path is None
        # A pose there (the hand pointing down): each IK solution a joint-state target, each
        # refused as in collision with the block, and none of the further search's clear
        # either (reach.clear_pose_configuration); the request fails naming it.
        start = ("state", np.array([0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]), np.zeros(7))
        pose = pose_target((0.3, 0.4, 0.5), (1.0, 0.0, 0.0, 0.0), "panda_link0", panda,
                           "panda_link0", start, "goal_pose")
        posed = PlanRequest(service.next_id(), "goal_pose", start, pose.position, config,
                            target_pose=pose)
        _refused_before_any_solve(service, out, posed, r"none of the pose's \d+ IK solutions "
                                  r"can be planned to: `target` joint state is in collision: "
                                  r"\w+ and block .*; searched further with the scene: of "
                                  r"\d+ more IK solutions inside the limits \(from 128 seeds\) "
                                  r"none is clear by the margin \(0\.01 m\), the clearest has "
                                  r"\w+ and block -[0-9.]+ m apart")
    finally:
        service.planner.gate.set()
        service.stop()
