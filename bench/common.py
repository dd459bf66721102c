"""Shared pieces of the benchmarks: timing, machine facts, robots, markdown helpers.

Imported by the section modules (``paper``, ``peers``, ``random_pairs``, ``scaling``) that
``bench/run_all.py`` runs in one process. Importing this module sets the thread variables
(before numpy loads) and makes ``tocontrol_ros`` importable from the source tree when it is
not installed.
"""

import os

# Before numpy is imported: BLAS threads make the small dense solves far slower.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import datetime  # noqa: E402
import importlib.metadata  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import site  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
try:
    import tocontrol_ros  # noqa: F401
except ImportError:  # not installed: use the source tree
    sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from tocontrol_ros.core.examples import PAPER_START, PAPER_TARGET  # noqa: E402

#: The paper's task (Section 5): end-effector start and target (m).
START, TARGET = PAPER_START, PAPER_TARGET
#: Warm re-solves move the target by 5 cm along x.
MOVED_TARGET = (2.25, 1.5)
#: The multistart that finds the best basin of the paper's example (the solver's default).
MULTI = {"starts": 16, "candidates": 3}
#: Two solutions are in the same basin when their T agree to this (relative).
SAME_T = 1e-6
PANDA_LOCKED = {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}


# --------------------------------------------------------------------------- timing
@dataclass
class Timing:
    """Wall times of one case (s), the warm-up run apart."""

    name: str
    times: list = field(default_factory=list)
    warmup: float = float("nan")
    note: str = ""
    ok: bool = True

    @property
    def median(self):
        return statistics.median(self.times) if self.times else float("nan")

    @property
    def min(self):
        return min(self.times) if self.times else float("nan")

    @property
    def max(self):
        return max(self.times) if self.times else float("nan")


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def measure(name, fn, runs, budget, check=None, warmup=True):
    """One warm-up run (unless ``warmup`` is False), then ``runs`` timed runs.

    Fewer runs (at least 3, or ``runs`` if smaller) when they would exceed ``budget`` s.
    Returns the :class:`Timing` and the output of the last run.
    """
    rec = Timing(name)
    if warmup:
        rec.warmup, out = timed(fn)
        per = rec.warmup
    else:
        dt, out = timed(fn)
        rec.times.append(dt)
        per = dt
    n = runs if per * runs <= budget else max(min(3, runs), int(budget / max(per, 1e-9)))
    for _ in range(n - len(rec.times)):
        dt, out = timed(fn)
        rec.times.append(dt)
        if check is not None and not check(out):
            rec.ok = False
    if check is not None and not check(out):
        rec.ok = False
    if n < runs:
        rec.note = f"{n} runs (budget {budget:g} s)"
    return rec, out


def fmt_ms(seconds):
    if seconds is None or not np.isfinite(seconds):
        return "—"
    return f"{seconds * 1e3:.1f}" if seconds < 10 else f"{seconds * 1e3:.0f}"


def fmt_s(seconds, digits=2):
    if seconds is None or not np.isfinite(seconds):
        return "—"
    return f"{seconds:.{digits}f}"


def fmt_t(T):
    return f"{T:.6f}" if T is not None and np.isfinite(T) else "—"


def table(header, rows):
    """Markdown table lines from a header list and rows of cells."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return out


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


# ---------------------------------------------------------------------- machine facts
def _version(dist):
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def load_text():
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def cpu_ticks():
    """``(steal, total)`` CPU ticks of the machine since boot (Linux ``/proc/stat``), or None.

    Steal is the time the hypervisor ran something else while this virtual machine wanted
    the CPU: on this project's VM it drifts between a few and tens of percent, and the
    timings with it.
    """
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n")[0].split()[1:]]
    except (OSError, ValueError):
        return None
    return (fields[7] if len(fields) > 7 else 0), sum(fields[:8])


def steal_text(before, after):
    """Steal between two :func:`cpu_ticks` readings, in percent of all CPU time."""
    if before is None or after is None or after[1] <= before[1]:
        return "unknown"
    return f"{100 * (after[0] - before[0]) / (after[1] - before[1]):.0f} %"


def speed_probe(runs: int = 5) -> str:
    """A fixed workload timed on this machine now: how fast it is, apart from our code.

    The figures of ``BENCHMARKS.md`` are wall times on shared virtual machines whose speed
    differs between sessions (the same commit's Panda plan took 0.75 s on one and 2.1 s on
    another, the interpreter's own loop 0.3 s against 0.9 s); each section records this
    probe beside its figures, so that two sections (or two runs) can be compared. Medians
    over ``runs`` of: a pure-Python loop (5e5 additions) and one IPOPT solve of a fixed
    NLP through CasADi (the chained Rosenbrock function in 200 variables from x = -1.2,
    exact Hessian, built once): the interpreter, and the compiled solver stack the planner
    spends its time in.
    """
    import casadi as ca

    x = ca.SX.sym("x", 200)
    f = ca.sum1(100 * (x[1:] - x[:-1] ** 2) ** 2 + (1 - x[:-1]) ** 2)
    solver = ca.nlpsol("probe", "ipopt", {"x": x, "f": f},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})

    def loop():
        total = 0
        for i in range(500_000):
            total += i
        return total

    py = statistics.median(timed(loop)[0] for _ in range(runs))
    nlp = statistics.median(timed(lambda: solver(x0=-1.2))[0] for _ in range(runs))
    return f"Python loop {1e3 * py:.0f} ms, IPOPT probe {1e3 * nlp:.0f} ms"


def machine_info():
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    try:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain",
                                "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()
        commit = f"{commit}{' + uncommitted changes' if dirty else ''}" if commit else "—"
    except OSError:
        commit = "—"
    import tocontrol_ros

    return {
        "CPU": cpu,
        "cores (usable)": f"{os.cpu_count()} ({usable})",
        "OS": platform.platform(),
        "Python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": _version("scipy"),
        "casadi": _version("casadi"),
        "toppra": _version("toppra"),
        "example-robot-data": _version("example-robot-data"),
        "C compiler": os.environ.get("CC") or "gcc (system)",
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
        "package": str(Path(tocontrol_ros.__file__).resolve().parent),
        "commit": commit,
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


# ----------------------------------------------------------------------------- robots
def paper_model():
    from tocontrol_ros.core.robot.model import default_urdf_path, load_robot

    return load_robot(str(default_urdf_path()))


def example_robot_data_dir():
    """``share/example-robot-data/robots`` of the cmeel wheel, wherever site-packages is."""
    dirs = list(sys.path) + site.getsitepackages() + [site.getusersitepackages()]
    for d in dirs:
        if not d:
            continue
        robots = Path(d) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
        if robots.is_dir():
            return robots
    return None


def panda_urdf():
    robots = example_robot_data_dir()
    if robots is None:
        return None
    path = robots / "panda_description" / "urdf" / "panda.urdf"
    return path if path.is_file() else None


def planar_arm_urdf(n, length=1.0, mass=1.0, damping=0.1, effort_per_link=10.0):
    """A planar arm of ``n`` equal uniform rods, horizontal plane (gravity does no work).

    Joint ``i`` (1-based) carries ``n - i + 1`` links and gets ``effort_per_link`` times that
    many N m; continuous joints, viscous friction ``damping`` N m s/rad, tool at the tip.
    """
    inertia = mass * length ** 2 / 12
    parts = [f'<?xml version="1.0"?>\n<robot name="planar_{n}r">', '  <link name="base_link"/>']
    parent = "base_link"
    for i in range(1, n + 1):
        offset = 0.0 if i == 1 else length
        parts += [
            f'  <joint name="joint{i}" type="continuous">',
            f'    <parent link="{parent}"/><child link="link{i}"/>',
            f'    <origin xyz="{offset} 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>',
            f'    <limit effort="{effort_per_link * (n - i + 1):g}" velocity="100.0"/>',
            f'    <dynamics damping="{damping:g}" friction="0.0"/>',
            "  </joint>",
            f'  <link name="link{i}"><inertial><origin xyz="{length / 2} 0 0" rpy="0 0 0"/>'
            f'<mass value="{mass:g}"/><inertia ixx="0" ixy="0" ixz="0" iyy="{inertia!r}" '
            f'iyz="0" izz="{inertia!r}"/></inertial></link>',
        ]
        parent = f"link{i}"
    parts += [
        '  <joint name="tool_joint" type="fixed">',
        f'    <parent link="{parent}"/><child link="tool"/>',
        f'    <origin xyz="{length} 0 0" rpy="0 0 0"/>',
        "  </joint>",
        '  <link name="tool"/>',
        "</robot>",
    ]
    return "\n".join(parts)


# -------------------------------------------------------------------- first-ever cost
FIRST_RUN_CODE = r"""
import json, sys, time
t0 = time.perf_counter()
from tocontrol_ros.core.robot.model import default_urdf_path, load_robot
from tocontrol_ros.core.types.problem import Problem, point
from tocontrol_ros.core.planning.solver import SolverOptions, plan
t1 = time.perf_counter()
model = load_robot(str(default_urdf_path()))
start, target, k = json.loads(sys.argv[1])
pr = Problem(model, point(start), point(target), k=k)
t2 = time.perf_counter()
opts = SolverOptions(starts=1, candidates=1, verify=False)
r1 = plan(pr, opts)
t3 = time.perf_counter()
r2 = plan(pr, opts)
t4 = time.perf_counter()
# Long sources got a quick build; their optimised builds finish before the process ends
# (else the next process would start them again).
from tocontrol_ros.core.robot import compiled
compiled.wait_for_builds()
t5 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "model": t2 - t1, "first_plan": t3 - t2,
                  "second_plan": t4 - t3, "ok": bool(r1.success and r2.success),
                  "background": t5 - t4}))
"""


def first_run_costs(k=4.0):
    """The paper's arm in a new process with an empty cache, then again on the filled one."""
    import tocontrol_ros

    env = dict(os.environ)
    pkg_parent = str(Path(tocontrol_ros.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([pkg_parent] + ([env["PYTHONPATH"]]
                                                        if env.get("PYTHONPATH") else []))
    out = {}
    with tempfile.TemporaryDirectory(prefix="tocontrol-bench-cache-") as cache:
        env["TOCONTROL_CACHE"] = cache
        for label in ("empty cache", "cache filled"):
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", FIRST_RUN_CODE,
                                   json.dumps([START, TARGET, k])], env=env,
                                  capture_output=True, text=True, timeout=600)
            wall = time.perf_counter() - t0
            if proc.returncode != 0:
                out[label] = {"error": " ".join(proc.stderr.strip().splitlines()[-1:])}
                continue
            data = json.loads(proc.stdout.strip().splitlines()[-1])
            data["process"] = wall
            out[label] = data
    return out


@dataclass
class Section:
    """One part of the report: markdown lines and the verdicts it contributes."""

    title: str
    lines: list
    targets: list = field(default_factory=list)  # (target, verdict) pairs
    seconds: float = float("nan")
    steal: str = "unknown"  # CPU steal during the section (see cpu_ticks)
    speed: str = "unknown"  # speed_probe() just before the section

    def print(self) -> None:
        """The section as markdown on stdout (a script run alone), its verdicts after it."""
        print(f"## {self.title}\n")
        print("\n".join(self.lines))
        for target, verdict in self.targets:
            print(f"- {target}: {verdict}")
