"""The planning service's warm-up and its switch to the optimised libraries (no ROS here).

The worker of :class:`~tocontrol_ros.nodes.planning_service.PlanningService` runs
:func:`warm_up` before the first request, so that no request pays for a build, and
:func:`load_optimised` between requests once the optimised builds of a model's first use
landed. Both report on ``~/status`` through the service's
:class:`~tocontrol_ros.nodes.planning_service.Outputs`.
"""

from __future__ import annotations

from typing import Any

from tocontrol_ros.core.errors import TocontrolError
from tocontrol_ros.core.robot import compiled
from tocontrol_ros.nodes.planner_config import solver_options, warm_up_problems

__all__ = ["compile_message", "load_optimised", "warm_up"]


def compile_message(event: str, name: str, info: dict) -> str | None:
    """The status line of a compile listener's event; None for an event not reported.

    Parameters
    ----------
    event : str
        ``"compiling"`` or ``"compiled"`` are reported.
    name : str
        The library.
    info : dict
        ``bytes`` (of C), ``flags``, ``seconds`` and ``ok`` (after the build).
    """
    if event not in ("compiling", "compiled"):
        return None
    quick = " (quick build; optimised in the background)" \
        if info.get("flags", "").startswith("-O0") else ""
    if event == "compiling":
        return f"warming up: compiling {name} ({info['bytes'] / 1e3:.0f} kB of C){quick}"
    return (f"warming up: compiled {name} in {info['seconds']:.1f} s"
            + ("" if info.get("ok") else " (failed: the virtual machine is used)"))


def warm_up(service: Any) -> None:
    """Build what requests need, so that no request pays for a build.

    First the direct transcription and the compiled functions of every problem kind the
    node serves (point to point for ``~/plan``, joint state to point for ``~/goal`` and
    ``~/plan`` without a start frame), always, with one ``~/status`` per compiled
    library; then one throw-away solve of each kind (builds the rest, e.g. the
    certificate's functions), stopped early when a request arrives or the service stops.
    Sets ``service.ready`` at the end.

    Parameters
    ----------
    service : PlanningService
        (Typed ``Any``: the service's module imports this one.)
    """
    out, clock = service.out, service.clock
    out.status("OK", "warming up (the first start on a machine compiles the model's C code)",
               {"event": "warming up"})
    t0 = clock.monotonic()

    def progress(event: str, name: str, info: dict) -> None:
        message = compile_message(event, name, info)
        if message is not None:
            out.status("OK", message, {"event": "warming up", "compile": event,
                                       "library": name, "c_bytes": info["bytes"],
                                       "seconds": info.get("seconds")})

    compiled.add_listener(progress)
    try:
        note = _warm_up_solves(service)
    finally:
        compiled.remove_listener(progress)
    if service.stopping.is_set():
        return
    service.ready.set()
    out.status("OK", f"ready after {clock.monotonic() - t0:.1f} s{note}",
               {"event": "ready", "warmup_time": clock.monotonic() - t0})


def _warm_up_solves(service: Any) -> str:
    """The warm-up's builds and throw-away solves; returns a note for the status."""
    config = service.config
    note = ""
    try:
        options = solver_options(config)  # verify as configured: compiles the certificate
        problems = warm_up_problems(config, service.model, service.limits)
        for problem in problems:
            if service.stopping.is_set():
                return note
            service.planner.prepare(problem, options)
        for problem in problems:
            service.planner.first(problem, options)  # loads TOPP-RA, builds its integrator
            result = service.planner.plan(problem, options, should_stop=lambda:
                                          service.stopping.is_set()
                                          or service.slot.has_pending())
            if not result.success and not note:
                note = f" (warm-up solve: {result.message})"
    except TocontrolError as exc:
        note = f" (warm-up skipped: {exc})"
    except Exception as exc:  # noqa: BLE001  (the worker must go on to serve requests)
        # An error of the builds (a compiler, the cache's disk or lock): the node serves
        # anyway, each request building what it needs and failing with its own message.
        note = f" (warm-up failed: {type(exc).__name__}: {exc})"
    return note


def load_optimised(service: Any) -> None:
    """Between requests: a new planner on the optimised libraries once they all landed.

    Parameters
    ----------
    service : PlanningService
        Its ``planner`` is replaced (built by its ``planner_factory``).
    """
    if not service.planner.stale() or service.stopping.is_set():
        return
    t0 = service.clock.monotonic()
    planner = service.planner_factory(service.model)
    config = service.config
    options = solver_options(config)
    try:
        for problem in warm_up_problems(config, service.model, service.limits):
            planner.prepare(problem, options)
    except Exception:  # noqa: BLE001  (the worker serves on with the planner it has)
        return
    service.planner = planner
    service.out.status("OK", f"optimised code loaded in {service.clock.monotonic() - t0:.1f} s",
                       {"event": "optimised"})
