"""What ``~/status`` says of a plan: its values and its summary line (no ROS here).

Pure functions of the core's results, shared by the planning service
(:mod:`tocontrol_ros.nodes.planning_service`), which decides what each status event
carries, and the node, which turns the values into a ``diagnostic_msgs/DiagnosticStatus``
(:func:`tocontrol_ros.nodes.conversions.status_msg`, which re-exports these).
"""

from __future__ import annotations

__all__ = ["ROUTINE_NOTE", "certificate_values", "result_message", "result_values",
           "stamp_text"]


def stamp_text(ns: int) -> str:
    """A stamp (ns) as a ``~/status`` value: seconds with all nine decimals.

    ``"%.9g"``, the status's float format, would keep whole seconds of a stamp since the
    epoch.
    """
    ns = int(ns)
    sign, ns = ("-", -ns) if ns < 0 else ("", ns)
    return f"{sign}{ns // 10**9}.{ns % 10**9:09d}"


def certificate_values(certificate) -> dict[str, object]:
    """The ``~/status`` values of a plan's certificate (empty when there is none).

    Parameters
    ----------
    certificate : tocontrol_ros.core.checks.certificate.Certificate or None

    Returns
    -------
    dict
        ``certified`` (bool), ``cert_<item>`` (each item's value), ``cert_failed`` (the
        failed items' names, comma-separated, empty when none) and ``cert_tolerances``
        (``item=tol`` pairs, comma-separated).
    """
    if certificate is None:
        return {"certified": False}
    out: dict[str, object] = {"certified": certificate.passed}
    out.update({f"cert_{i.name}": i.value for i in certificate.items})
    out["cert_failed"] = ",".join(i.name for i in certificate.failures)
    out["cert_tolerances"] = ",".join(f"{i.name}={i.tol:.3g}" for i in certificate.items)
    return out


#: A solver note that is routine, not a warning: the warm start was tried and the solve
#: went on cold (the status stays OK and keeps the note).
ROUTINE_NOTE = "warm start did not converge"


def result_values(result) -> dict[str, object]:
    """The ``~/status`` values of a plan (:class:`~tocontrol_ros.core.types.result.PlanResult`).

    Returns
    -------
    dict
        ``T`` (s), ``iterations``, ``solve_time`` (s), ``residual``, ``max_abs_u``,
        ``solver_status``, ``method``, ``verify_time`` (s; None without a certificate),
        the certificate's (:func:`certificate_values`) and a first motion's
        ``guess_time`` and ``scaling_time`` (s).
    """
    return {"T": result.T, "iterations": result.iterations,
            "solve_time": result.timings.get("total"), "residual": result.residual,
            "max_abs_u": result.max_abs_u, "solver_status": result.status.name,
            "method": result.method,
            "verify_time": result.timings.get("verify") if result.certificate else None,
            **certificate_values(result.certificate), **_clearance_values(result),
            **_first_values(result)}


def _first_values(result) -> dict[str, object]:
    """A first (or quick) motion's parts of ``solve_time`` (s).

    ``guess_time`` (its end configuration: seed pairs, or a quick motion's Newton steps) and
    ``scaling_time`` (TOPP-RA).
    """
    if result.method != "first" or "scaling" not in result.timings:
        return {}
    return {"guess_time": result.timings.get("guess"),
            "scaling_time": result.timings.get("scaling")}


def _clearance_values(result) -> dict[str, object]:
    """``min_clearance`` (m) and ``closest_pair`` of a plan with a collision model."""
    figures = getattr(result, "verification", None) or {}
    if "min_clearance" not in figures:
        return {}
    return {"min_clearance": figures["min_clearance"],
            "closest_pair": figures["closest_pair"]}


def result_message(result) -> tuple[str, str]:
    """Level (``"OK"``, or ``"WARN"`` with warnings) and summary of a published plan.

    ``T``, ``k``, the iterations (TOPP-RA passes for a first motion), the solve time, the
    residual, ``max |u|``, whether it is certified, and its warnings: routine ones
    (:data:`ROUTINE_NOTE`) appended, any other makes it a ``WARN``.
    """
    verified = "certified" if result.certificate else "not certified (verify = false)"
    steps = "TOPP-RA passes" if result.method == "first" else "Newton iterations"
    message = (f"T = {result.T:.6g} s at k = {result.k:g}, {result.iterations} {steps}, "
               f"{result.timings['total']:.3f} s, residual {result.residual:.2g}, max |u| = "
               f"{result.max_abs_u:.4f}; {verified}")
    routine = [w for w in result.warnings if w.startswith(ROUTINE_NOTE)]
    warnings = [w for w in result.warnings if not w.startswith(ROUTINE_NOTE)]
    if routine:
        message += "; " + "; ".join(routine)
    if warnings:
        return "WARN", message + "; warnings: " + "; ".join(warnings)
    return "OK", message
