"""A gate in front of the planner's solves: a test holds a solve until it says so.

Tests of the serving order ("the newest call supersedes a running solve", "a shutdown
cancels the solve in flight") once made the solve slow (a big multistart) and hoped it was
still running when the next event came: a faster solver or a busier machine broke them.
Here the solve is held at its start by the test, so the order is the test's:

    gate = SolveGate.install(monkeypatch)   # on Planner.plan, the class (see below)
    ... wait until the planner is ready ...
    gate.arm()                              # from now on each solve waits at the gate
    client.send_goal(...)
    assert gate.held.wait(HANG)             # a solve is running, held
    ...                                     # the event under test
    gate.open()                             # held solves go on (and later ones pass)

A held solve also goes on as soon as its ``should_stop`` says so (cancelled, superseded,
the node stopping), as a real one would stop at its next check: it then runs the real solve
with that ``should_stop``, which returns at once with the solver's own outcome.

:func:`install_from_environment` puts the same gate in a planner *process* (see
``test/gated_planner.py``): there files stand for the events.
"""

import os
import threading
from pathlib import Path

#: How often a held solve looks at its should_stop (s): a poll, not a claim about speed.
POLL = 0.005


class SolveGate:
    """Holds ``Planner.plan`` calls made while armed, until opened or told to stop."""

    def __init__(self, real):
        self.real = real
        self.armed = threading.Event()
        self.opened = threading.Event()
        #: Set when a solve is waiting at the gate.
        self.held = threading.Event()
        #: Outcomes of the solves that came through the gate while armed, in order.
        self.outcomes = []
        self._lock = threading.Lock()

    @classmethod
    def install(cls, monkeypatch):
        """Put a gate on ``Planner.plan`` (the class: the node makes new planners)."""
        from tocontrol_ros.core.planning import solver as solver_module

        gate = cls(solver_module.Planner.plan)
        monkeypatch.setattr(solver_module.Planner, "plan", gate.wrapper())
        return gate

    def arm(self) -> None:
        self.opened.clear()
        self.held.clear()
        self.armed.set()

    def open(self) -> None:
        self.opened.set()

    def wrapper(self):
        gate = self

        def plan(planner, problem, options=None, warm_start=None, should_stop=None):
            if not gate.armed.is_set() or gate.opened.is_set():
                return gate.real(planner, problem, options, warm_start, should_stop)
            gate.held.set()
            while not gate.opened.wait(POLL):
                if should_stop is not None and should_stop():
                    break
            result = gate.real(planner, problem, options, warm_start, should_stop)
            with gate._lock:
                gate.outcomes.append(result)
            return result

        return plan


#: Environment variable naming the directory of a planner process's gate files.
GATE_DIR = "TOCONTROL_TEST_SOLVE_GATE"


def install_from_environment() -> None:
    """In a planner process: a gate driven by files in ``$TOCONTROL_TEST_SOLVE_GATE``.

    ``armed`` (the test creates it) arms the gate; the process creates ``held`` when a solve
    waits at it, and appends each gated solve's status name to ``outcomes``; ``open`` (the
    test creates it) lets held solves go on.
    """
    directory = os.environ.get(GATE_DIR)
    if not directory:
        return
    from tocontrol_ros.core.planning import solver as solver_module

    folder = Path(directory)
    real = solver_module.Planner.plan

    def plan(planner, problem, options=None, warm_start=None, should_stop=None):
        if not (folder / "armed").exists() or (folder / "open").exists():
            return real(planner, problem, options, warm_start, should_stop)
        (folder / "held").touch()
        stop = threading.Event()
        while not stop.wait(POLL) and not (folder / "open").exists():
            if should_stop is not None and should_stop():
                break
        result = real(planner, problem, options, warm_start, should_stop)
        with open(folder / "outcomes", "a") as f:
            f.write(result.status.name + "\n")
        return result

    solver_module.Planner.plan = plan
