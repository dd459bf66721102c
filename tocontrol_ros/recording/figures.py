"""The paper's example (Section 5, Figures 2-4): solve it for several k and draw it.

Run as ``tocontrol-figures`` (pip), ``ros2 run tocontrol_ros figures`` (either route) or
``python -m tocontrol_ros.figures``. For each exponent ``k`` it solves the transfer of the
bundled 3R arm's end effector from (1.0, 1.0) to (2.2, 1.5) with a multistart (so that the
best basin of this many-basin problem is found), computes the optimum for the original box
``|u_i| <= 1`` with the direct method on a fine mesh, warm-started from the largest ``k``,
and writes into ``--out``:

- ``fig2_controls_k1.png``, ``fig3_controls_k4.png``: normalised controls v. time;
- ``fig4_motion_k4.png``: the arm at snapshots along the k = 4 motion;
- ``table.md``: T, T / T_box, max |u_i|, BVP residual and re-integration end error per k.

Plotting lives here, never in :mod:`tocontrol_ros.core`.
"""

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET
from tocontrol_ros.core.robot.kinematics import link_positions

#: The paper's task (Section 5): start and target of the end effector (m).
START, TARGET = PAPER_START, PAPER_TARGET
#: Mesh of the direct method for the box optimum: on the paper's example T_box moves by
#: 4e-6 (relative) from N = 200 to N = 400 (bang-bang switches fall between mesh points).
BOX_INTERVALS = 200
BOX_TOL = 1e-9
#: Multistart that finds the best basin of the paper's example (see BENCHMARKS.md).
STARTS = 16
CANDIDATES = 3
#: Arm snapshots in Figure 4.
SNAPSHOTS = 15


@dataclass(frozen=True)
class BoxOptimum:
    """The box optimum from the direct method.

    Attributes
    ----------
    T : float
        Minimum time (s).
    max_abs_u : float
        Largest normalised control on the mesh.
    intervals : int
        Mesh intervals.
    message : str
        IPOPT's return status.
    success : bool
    t : ndarray, shape (N + 1,)
        Mesh times (s).
    u : ndarray, shape (N + 1, n)
        Normalised controls at the mesh points.
    """

    T: float
    max_abs_u: float
    intervals: int
    message: str
    success: bool
    t: np.ndarray
    u: np.ndarray


def parse_ks(text):
    """Parse ``--ks``: comma-separated exponents, each in [1, 64].

    Parameters
    ----------
    text : str
        E.g. ``"1,2,4,8,16"``.

    Returns
    -------
    list of float
        Sorted, duplicates removed.

    Raises
    ------
    argparse.ArgumentTypeError
        Not numbers, or out of range.
    """
    try:
        ks = sorted({float(item) for item in text.split(",") if item.strip()})
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"`--ks` must be comma-separated numbers, got {text!r}") from exc
    if not ks or any(not (1.0 <= k <= 64.0) for k in ks):
        raise argparse.ArgumentTypeError(f"`--ks` values must be in [1, 64], got {text!r}")
    return ks


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog="figures",
        description="Solve the paper's example (3R arm, (1.0, 1.0) -> (2.2, 1.5)) for "
        "several k and the box optimum; write Figures 2-4 and a table.",
    )
    parser.add_argument("--out", type=Path, default=Path("docs"), metavar="DIR",
                        help="output directory (default: docs/)")
    parser.add_argument("--urdf", type=Path, default=None, metavar="PATH",
                        help="URDF of the arm (default: the bundled config/galicki_3r.urdf)")
    parser.add_argument("--ks", type=parse_ks, default=parse_ks("1,2,4,8,16"),
                        metavar="K,K,...",
                        help="convexification exponents (default: 1,2,4,8,16); figures 3 "
                        "and 4 need k = 4, figure 2 needs k = 1")
    return parser


# ------------------------------------------------------------------------ computation
def solve_all(model, ks, log=print):
    """Solve the paper's example for each ``k`` with the multistart.

    Parameters
    ----------
    model : RobotModel
    ks : sequence of float
    log : callable
        Receives one progress line per solve.

    Returns
    -------
    dict of float to PlanResult
    """
    from tocontrol_ros.core.planning.solver import SolverOptions, plan
    from tocontrol_ros.core.types.problem import Problem, point

    options = SolverOptions(starts=STARTS, candidates=CANDIDATES)
    results = {}
    for k in ks:
        t0 = time.perf_counter()
        res = plan(Problem(model, point(START), point(TARGET), k=k), options)
        log(f"k = {k:g}: {res.message}; T = {res.T:.6f} s, max |u| = {res.max_abs_u:.4f}, "
            f"{res.iterations} Newton iterations, {time.perf_counter() - t0:.2f} s")
        results[k] = res
    return results


def box_optimum(model, seed, intervals=BOX_INTERVALS, tol=BOX_TOL):
    """The optimum for the box ``|u_i| <= 1`` by direct collocation, warm-started.

    Parameters
    ----------
    model : RobotModel
    seed : PlanResult
        A successful solution (the largest k): sampled on the mesh, it is the guess.
    intervals : int
        Mesh intervals ``N``.
    tol : float
        IPOPT tolerance.

    Returns
    -------
    BoxOptimum
    """
    from tocontrol_ros.core.direct.collocation import DirectCollocation

    n = model.n
    sample = seed.trajectory.evaluate(np.linspace(0.0, seed.T, intervals + 1))
    direct = DirectCollocation(model, intervals, "point", "point", box=True, tol=tol)
    res = direct.solve(np.asarray(START), np.asarray(TARGET), 1.0, seed.T,
                       np.hstack([sample.q, sample.qd]), sample.u)
    return BoxOptimum(T=res.T, max_abs_u=float(np.max(np.abs(res.u))), intervals=intervals,
                      message=res.message, success=res.success, t=res.t, u=res.u[:, :n])


def _fmt(value, spec):
    return "—" if value is None or not np.isfinite(value) else format(value, spec)


def table_markdown(results, box):
    """The results table as Markdown.

    Parameters
    ----------
    results : dict of float to PlanResult
    box : BoxOptimum or None

    Returns
    -------
    str
    """
    t_box = box.T if box is not None and box.success else float("nan")
    lines = [
        "| k | T (s) | T / T_box | max \\|u_i\\| | BVP residual | "
        "re-integration end error (m) |",
        "|---|---|---|---|---|---|",
    ]
    for k, res in results.items():
        if not res.success:
            lines.append(f"| {k:g} | failed: {res.message} | | | | |")
            continue
        lines.append(
            f"| {k:g} | {res.T:.6f} | {_fmt(res.T / t_box, '.4f')} | {res.max_abs_u:.4f} | "
            f"{res.residual:.1e} | {_fmt(res.verification.get('point_error'), '.1e')} |")
    if box is not None:
        status = "" if box.success else f" ({box.message})"
        lines.append(f"| box, direct N = {box.intervals}{status} | {box.T:.6f} | "
                     f"{_fmt(box.T / t_box, '.4f')} | {box.max_abs_u:.4f} | — | — |")
    return "\n".join(lines) + "\n"


# -------------------------------------------------------------------------- plotting
def plot_controls(res, path):
    """Normalised controls v. time, one panel per joint, dashed lines at +-1.

    Parameters
    ----------
    res : PlanResult
        A successful solution.
    path : pathlib.Path
        PNG to write.
    """
    import matplotlib.pyplot as plt

    sample = res.trajectory.evaluate(np.linspace(0.0, res.T, 1001))
    n = sample.u.shape[1]
    fig, axes = plt.subplots(n, 1, sharex=True, figsize=(6.4, 1.7 * n + 1.0))
    for i, ax in enumerate(np.atleast_1d(axes)):
        ax.plot(sample.t, sample.u[:, i], color="C0", lw=1.6)
        for level in (-1.0, 1.0):
            ax.axhline(level, color="0.4", ls="--", lw=0.8)
        ax.axhline(0.0, color="0.8", lw=0.6)
        ax.set_ylim(-1.2, 1.2)
        ax.set_yticks([-1, 0, 1])
        ax.set_ylabel(f"$u_{i + 1}$")
        ax.set_xlim(0.0, res.T)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[-1].set_xlabel("t (s)")
    fig.suptitle(f"Time-optimal controls v. time, k = {res.k:g}\n"
                 f"T = {res.T:.4f} s, max |u_i| = {res.max_abs_u:.3f}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_motion(model, res, path, snapshots=SNAPSHOTS):
    """The arm at ``snapshots`` instants along the motion, the end-effector path, the ends.

    Parameters
    ----------
    model : RobotModel
    res : PlanResult
        A successful solution.
    path : pathlib.Path
        PNG to write.
    snapshots : int
    """
    import matplotlib.pyplot as plt

    ax_x, ax_y = 0, 1  # the paper's plane: base-frame x and y
    fine = res.trajectory.evaluate(np.linspace(0.0, res.T, 401))
    tip = np.array([link_positions(model, q)[-1] for q in fine.q])
    snap = res.trajectory.evaluate(np.linspace(0.0, res.T, snapshots))
    colors = plt.cm.viridis(np.linspace(0.0, 0.9, snapshots))
    fig, ax = plt.subplots(figsize=(6.4, 6.0))
    for j, (t, q) in enumerate(zip(snap.t, snap.q, strict=True)):
        pts = link_positions(model, q)
        ends = j in (0, snapshots - 1)
        ax.plot(pts[:, ax_x], pts[:, ax_y], "-o", color=colors[j], lw=2.2 if ends else 1.1,
                ms=4 if ends else 2.5, alpha=1.0 if ends else 0.75,
                label=f"t = {t:.3f} s" if ends else None)
    ax.plot(tip[:, ax_x], tip[:, ax_y], color="C3", lw=1.4, label="end-effector path")
    ax.plot(*START, "s", color="k", ms=8, mfc="white", mew=1.8, label="start $P_s$ (1.0, 1.0)")
    ax.plot(*TARGET, "*", color="C3", ms=14, label="target $P_f$ (2.2, 1.5)")
    ax.plot(0.0, 0.0, "^", color="0.3", ms=9, label="base")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"Optimal manipulator motion, k = {res.k:g} (T = {res.T:.4f} s, "
                 f"{snapshots} snapshots)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    """Solve, draw and tabulate the paper's example.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments without the program name; ``sys.argv[1:]`` if None.

    Returns
    -------
    int
        0 when every solve succeeded, 1 otherwise (the outputs that could be made are
        written either way).
    """
    args = build_parser().parse_args(argv)
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    urdf = args.urdf if args.urdf is not None else default_urdf_path()
    if not Path(urdf).is_file():
        raise SystemExit(f"figures: --urdf: no such file: {urdf}")

    model = load_robot(str(urdf))
    args.out.mkdir(parents=True, exist_ok=True)
    results = solve_all(model, args.ks)
    ok = [k for k, r in results.items() if r.success]
    box = None
    if ok:
        t0 = time.perf_counter()
        box = box_optimum(model, results[max(ok)])
        print(f"box optimum (direct, N = {box.intervals}, from k = {max(ok):g}): "
              f"{box.message}; T_box = {box.T:.6f} s, {time.perf_counter() - t0:.2f} s")
    table = table_markdown(results, box)
    (args.out / "table.md").write_text(table)
    print()
    print(table)
    written = ["table.md"]
    for k, name in ((1.0, "fig2_controls_k1.png"), (4.0, "fig3_controls_k4.png")):
        if k in results and results[k].success:
            plot_controls(results[k], args.out / name)
            written.append(name)
    if 4.0 in results and results[4.0].success:
        plot_motion(model, results[4.0], args.out / "fig4_motion_k4.png")
        written.append("fig4_motion_k4.png")
    print(f"wrote {', '.join(written)} to {args.out}/")
    return 0 if len(ok) == len(results) and box is not None and box.success else 1


if __name__ == "__main__":
    sys.exit(main())
