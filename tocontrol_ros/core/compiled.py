"""Compile CasADi functions to C shared libraries, cached on disk.

The shooting solver spends its time in one function (an RK4 step of the canonical system and
its Jacobian). CasADi's virtual machine runs it about ten times slower than the same graph
compiled to C, so it is generated, compiled once with the system C compiler and cached under
``$TOCONTROL_CACHE`` (default ``~/.cache/tocontrol_ros``), keyed by a hash of the generated
source: only the first run for a given model pays for the compiler (about 10 s for the
paper's arm). Without a C compiler, or with ``TOCONTROL_COMPILE=0``, the virtual machine is
used: slower, same results.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

import casadi as ca

__all__ = ["compile_function", "compile_functions", "cache_dir", "c_name"]

#: -march=native (vector units, fused multiply-add) makes the RK4 step with its Jacobian
#: markedly faster than portable -O1. Such a library only runs on the CPU it was built for,
#: so the cache key includes the CPU's identity.
CFLAGS = ("-O2", "-march=native", "-shared", "-fPIC")
#: gcc's -O2 time grows much faster than linearly with the size of these straight-line
#: functions (minutes for a planar 6R), so sources above this many bytes get
#: :data:`LARGE_CFLAGS`.
LARGE_SOURCE = 1_000_000
LARGE_CFLAGS = ("-O1", "-march=native", "-shared", "-fPIC")
#: Used when the compiler rejects -march=native.
PORTABLE_CFLAGS = ("-O1", "-shared", "-fPIC")
_lock = threading.Lock()


def c_name(name: str) -> str:
    """``name`` as part of a C identifier (generated function names)."""
    return re.sub(r"\W", "_", name)


def cache_dir() -> Path:
    """Directory of the compiled functions (created on demand)."""
    root = os.environ.get("TOCONTROL_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "tocontrol_ros")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _compiler() -> str | None:
    if os.environ.get("TOCONTROL_COMPILE", "1") == "0":
        return None
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


@functools.cache
def _cpu_tag() -> bytes:
    """The machine and CPU (model and feature flags) that -march=native compiles for."""
    tag = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags", "Features"))]
        tag += "".join(sorted(set(lines)))
    except OSError:
        tag += platform.processor()
    return tag.encode()


def _build(cc: str, name: str, tmp: str) -> tuple[Path | None, str]:
    """Compile ``tmp/name.c`` into the cache (unless there already), keyed by its source."""
    source = Path(tmp, f"{name}.c").read_bytes()
    cflags = CFLAGS if len(source) <= LARGE_SOURCE else LARGE_CFLAGS
    digest = hashlib.sha256(source + " ".join(cflags).encode() + _cpu_tag()
                            ).hexdigest()[:20]
    target = cache_dir() / f"{name}_{digest}.so"
    how = "cached"
    with _lock:
        if not target.is_file():
            how = "compiled"
            partial = Path(tmp, f"{name}.so")
            for flags in (cflags, PORTABLE_CFLAGS):
                proc = subprocess.run([cc, *flags, f"{name}.c", "-o", str(partial), "-lm"],
                                      cwd=tmp, capture_output=True, text=True)
                if proc.returncode == 0:
                    break
            else:
                return None, f"virtual machine (compiler failed: {proc.stderr[-300:]})"
            staged = target.with_suffix(f".{os.getpid()}.tmp")
            shutil.copyfile(partial, staged)
            os.replace(staged, target)  # atomic: parallel processes never see half a file
    return target, how


def compile_function(fun: ca.Function) -> tuple[ca.Function, str]:
    """Return a compiled equivalent of ``fun`` (or ``fun`` itself when no compiler).

    Parameters
    ----------
    fun : casadi.Function
        An SX function.

    Returns
    -------
    function : casadi.Function
        Same signature as ``fun``.
    how : str
        ``"cached"``, ``"compiled"`` or ``"virtual machine (reason)"``.
    """
    cc = _compiler()
    if cc is None:
        return fun, "virtual machine (no C compiler or TOCONTROL_COMPILE=0)"
    name = fun.name()
    with tempfile.TemporaryDirectory() as tmp:
        cwd = os.getcwd()
        try:
            os.chdir(tmp)
            fun.generate(f"{name}.c")
        finally:
            os.chdir(cwd)
        target, how = _build(cc, name, tmp)
    if target is None:
        return fun, how
    return ca.external(name, str(target)), how


def compile_functions(name: str, funs: Sequence[ca.Function]
                      ) -> tuple[list[ca.Function], str]:
    """Compile several functions into one library (shared dependencies generated once).

    Parameters
    ----------
    name : str
        Name of the library (a C identifier); the cache key is a hash of the source.
    funs : sequence of casadi.Function
        SX or MX functions with distinct names.

    Returns
    -------
    functions : list of casadi.Function
        Compiled equivalents in the order of ``funs`` (``funs`` themselves when no
        compiler).
    how : str
        ``"cached"``, ``"compiled"`` or ``"virtual machine (reason)"``.
    """
    cc = _compiler()
    if cc is None:
        return list(funs), "virtual machine (no C compiler or TOCONTROL_COMPILE=0)"
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator(f"{name}.c")
        for fun in funs:
            gen.add(fun)
        gen.generate(tmp + os.sep)
        target, how = _build(cc, name, tmp)
    if target is None:
        return list(funs), how
    return [ca.external(fun.name(), str(target)) for fun in funs], how
