"""Compile CasADi functions to C shared libraries, cached on disk.

The shooting solver spends its time in one function (an RK4 step of the canonical system and
its Jacobian). CasADi's virtual machine runs it about ten times slower than the same graph
compiled to C, so it is generated, compiled once with the system C compiler and cached under
``$TOCONTROL_CACHE`` (default ``~/.cache/tocontrol_ros``), keyed by a hash of the generated
source: only the first run for a given model pays for the compiler (about 10 s for the
paper's arm). Without a C compiler, or with ``TOCONTROL_COMPILE=0``, the virtual machine is
used: slower, same results.

Long sources are built in two tiers: gcc spends most of its time optimising long
straight-line code (register allocation), so a source above :data:`QUICK_SOURCE` bytes is
first compiled without optimisation (``-O0``, several times faster to build, slower to run)
and returned at once, while the optimised library is built in a background thread at low
priority. :func:`generation` counts the optimised libraries that have landed in the cache
since the process started; a :class:`~tocontrol_ros.core.planning.solver.Planner` made after that
loads them (the cache holds both). ``TOCONTROL_COMPILE_TIERS=0`` builds the optimised
library at once instead. :func:`add_listener` reports every build as it starts and ends.
A library is built by one process at a time: another process that misses it meanwhile (the
planner's workers, a batch's) waits for that build's lock and loads it (:func:`_process_lock`).

:func:`compile_owned` keeps the functions of one owner (a model) for its lifetime: its
symbolic functions are built once, a later call returns the loaded library, or the optimised
one once it has landed, without generating the source again.
"""

from __future__ import annotations

import errno
import functools
import glob
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

try:  # POSIX: the builds' lock across processes (_process_lock)
    import fcntl
except ImportError:  # pragma: no cover - not on Linux
    fcntl = None

__all__ = ["compile_function", "compile_functions", "cache_dir", "c_name", "generation",
           "pending_builds", "wait_for_builds", "add_listener", "remove_listener",
           "parallel_builds", "in_cache", "compile_owned", "bind_buffers", "BufferedFunction"]

#: -march=native (vector units) makes the RK4 step with its Jacobian markedly faster than
#: portable -O1. Such a library only runs on the CPU it was built for, so the cache key
#: includes the CPU's identity. :data:`SAME_BITS` (in every set of flags) makes every
#: optimisation level round alike, so that the quick build, the optimised one and the
#: portable fallback give the same bits (same request, same plan, whichever library had
#: landed; a test compares them): ``-ffp-contract=off``, no fused multiply-add; and
#: ``-fno-tree-vectorize``, no vectorised blocks: gcc 12's basic-block vectorizer with
#: -march=native (AVX-512 here) changed the last bit of 12-32 entries of the Panda's
#: Hermite-Simpson Hessian (``direct_asm_hess``) against -O0, so a first plan made while the
#: optimised library was still building differed from the same plan made after (a 0.16 %
#: longer T on one case of bench/warm_resolve.py, another start winning on another); it
#: costs nothing measurable on that function (93 against 96 us a call).
SAME_BITS = ("-ffp-contract=off", "-fno-tree-vectorize")
CFLAGS = ("-O2", "-march=native", *SAME_BITS, "-shared", "-fPIC")
#: gcc's -O2 time grows much faster than linearly with the size of these straight-line
#: functions (minutes for a planar 6R), so sources above this many bytes get
#: :data:`LARGE_CFLAGS`.
LARGE_SOURCE = 1_000_000
LARGE_CFLAGS = ("-O1", "-march=native", *SAME_BITS, "-shared", "-fPIC")
#: Used when the compiler rejects -march=native.
PORTABLE_CFLAGS = ("-O1", *SAME_BITS, "-shared", "-fPIC")
#: Sources above this many bytes get a quick unoptimised build first (see the module's
#: docstring); below it gcc is fast enough to optimise at once.
QUICK_SOURCE = 200_000
QUICK_CFLAGS = ("-O0", "-march=native", *SAME_BITS, "-shared", "-fPIC")
#: Niceness of the background builds: a solve running meanwhile keeps its core.
BACKGROUND_NICE = 10
#: Seconds between requests for a library's build lock that the kernel refused as a
#: deadlock between processes (:func:`_process_lock`: a false one, seen per process).
LOCK_RETRY = 0.05
#: Background builds run one at a time per cache directory (gcc takes up to a GB on the
#: longest sources); a process has one cache unless ``TOCONTROL_CACHE`` changes (tests).
_background_slots: dict[Path, threading.Semaphore] = {}

_meta_lock = threading.Lock()
_target_locks: dict[Path, threading.Lock] = {}
_done = threading.Condition()
_pending: set[Path] = set()  # optimised libraries queued or being built
_generations: dict[Path, int] = {}  # optimised libraries landed, per cache directory
_listeners: list[Callable[[str, str, dict], None]] = []
_deferred = threading.local()  # .pool, .futures inside parallel_builds()


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
    return _found_compiler(os.environ.get("CC"), os.environ.get("PATH"))


@functools.lru_cache(maxsize=8)
def _found_compiler(cc: str | None, path: str | None) -> str | None:
    """``cc``, else gcc or cc on ``path``: looked up once per environment.

    A search of the ``PATH`` costs 0.2-0.4 ms, and every call of a compiled function's
    owner asks.
    """
    return cc or shutil.which("gcc", path=path) or shutil.which("cc", path=path)


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


# ------------------------------------------------------------------ build progress
def add_listener(listener: Callable[[str, str, dict], None]) -> None:
    """Call ``listener(event, name, info)`` on every build from now on (any thread).

    ``event`` is ``"compiling"`` or ``"compiled"`` (a build the caller waits for),
    ``"optimising"`` or ``"optimised"`` (a background build); ``name`` is the library's;
    ``info`` holds ``bytes`` (the C source's size), ``flags`` and, when it ended,
    ``seconds`` and ``ok``.
    """
    with _meta_lock:
        _listeners.append(listener)


def remove_listener(listener: Callable[[str, str, dict], None]) -> None:
    """Stop calling ``listener`` (no error when it was not registered)."""
    with _meta_lock:
        if listener in _listeners:
            _listeners.remove(listener)


def _notify(event: str, name: str, info: dict) -> None:
    with _meta_lock:
        listeners = list(_listeners)
    for listener in listeners:
        try:
            listener(event, name, info)
        except Exception:  # noqa: BLE001  (a reporting bug must not fail a build)
            pass


def generation() -> int:
    """How many optimised libraries the background builds have put in the cache so far.

    The cache of :func:`cache_dir` now: builds into another cache (a test's private one)
    neither count nor keep :func:`pending_builds` and :func:`wait_for_builds` waiting.
    """
    with _done:
        return _generations.get(cache_dir(), 0)


def pending_builds() -> int:
    """Background builds queued or running, into the cache of :func:`cache_dir`."""
    here = cache_dir()
    with _done:
        return _pending_into(here)


def _pending_into(cache: Path) -> int:
    """Pending builds whose library goes into ``cache`` (call holding ``_done``)."""
    return sum(1 for target in _pending if target.parent == cache)


def wait_for_builds(timeout: float | None = None) -> bool:
    """Wait until no background build into the cache of :func:`cache_dir` is left.

    Returns False when ``timeout`` (s) passed first.
    """
    here = cache_dir()
    with _done:
        return _done.wait_for(lambda: not _pending_into(here), timeout)


def in_cache(prefix: str) -> bool:
    """Whether the cache holds a library whose name starts with ``prefix``.

    A cheap hint (no source generated, no hash) that a model was compiled before.
    """
    return any(cache_dir().glob(f"{glob.escape(prefix)}*.so"))


# ------------------------------------------------------------------------- builds
def _target_lock(target: Path) -> threading.Lock:
    with _meta_lock:
        return _target_locks.setdefault(target, threading.Lock())


@contextmanager
def _process_lock(target: Path) -> Iterator[None]:
    """Held while ``target`` is built, across processes (``lockf`` on ``<target>.lock``).

    The planner's workers and a caller's own processes share one cache: without it each
    process that misses a library compiles it (the same source, at once: three gcc runs of
    one library were seen in a benchmark's main process and its two workers). With it the
    others wait and find it built. Where ``fcntl`` is missing, no lock (the builds stay
    correct: a library lands by an atomic rename). A POSIX record lock, not ``flock``: it
    belongs to this process, so a worker forked while a build holds it does not keep it
    (the threads of one process are kept apart by :func:`_target_lock`).

    The kernel's deadlock detection sees locks per process, not per thread: process A
    building library 1 on one thread and waiting for library 2 on another, while process B
    builds 2 and waits for 1, is refused with ``EDEADLK`` although each build ends and
    lets the other go on (no build holds one library's lock while it waits for another's).
    Seen with three planner nodes warming up on one new cache (a warm-up thread killed by
    the error). Such a refusal is waited out: the request is made again every
    :data:`LOCK_RETRY` seconds until it is granted.
    """
    if fcntl is None:
        yield
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.with_name(target.name + ".lock"), "a") as handle:
        while True:
            try:
                fcntl.lockf(handle, fcntl.LOCK_EX)
                break
            except OSError as exc:
                if exc.errno != errno.EDEADLK:
                    raise
                time.sleep(LOCK_RETRY)
        try:
            yield
        finally:
            fcntl.lockf(handle, fcntl.LOCK_UN)


def _target(name: str, source: bytes, cflags: Sequence[str]) -> Path:
    digest = hashlib.sha256(source + " ".join(cflags).encode() + _cpu_tag()
                            ).hexdigest()[:20]
    return cache_dir() / f"{name}_{digest}.so"


def _gcc(cc: str, name: str, tmp: str, cflags: Sequence[str], target: Path,
         event: str, background: bool = False) -> str:
    """Compile ``tmp/name.c`` into ``target``; returns "" or the compiler's complaint."""
    size = Path(tmp, f"{name}.c").stat().st_size
    done = "compiled" if event == "compiling" else "optimised"
    _notify(event, name, {"bytes": size, "flags": " ".join(cflags)})
    t0 = time.perf_counter()
    partial = Path(tmp, f"{name}.so")
    # `nice` as a command: preexec_fn is unsafe in a process with threads.
    nice = ["nice", "-n", str(BACKGROUND_NICE)] if background and shutil.which("nice") else []
    for flags in (cflags, PORTABLE_CFLAGS):
        proc = subprocess.run([*nice, cc, *flags, f"{name}.c", "-o", str(partial), "-lm"],
                              cwd=tmp, capture_output=True, text=True)
        if proc.returncode == 0:
            break
    else:
        _notify(done, name, {"bytes": size, "flags": " ".join(cflags), "ok": False,
                             "seconds": time.perf_counter() - t0})
        return proc.stderr[-300:] or f"exit status {proc.returncode}"
    staged = target.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
    shutil.copyfile(partial, staged)
    os.replace(staged, target)  # atomic: parallel processes never see half a file
    _notify(done, name, {"bytes": size, "flags": " ".join(cflags), "ok": True,
                         "seconds": time.perf_counter() - t0})
    return ""


def _optimise(cc: str, name: str, source: bytes, cflags: Sequence[str],
              target: Path) -> None:
    """Background thread: build the optimised library, then count it in."""
    ok = False
    with _meta_lock:
        slot = _background_slots.setdefault(target.parent, threading.Semaphore(1))
    try:
        with slot, _target_lock(target), _process_lock(target):
            if target.is_file():
                ok = True
            else:
                with tempfile.TemporaryDirectory() as tmp:
                    Path(tmp, f"{name}.c").write_bytes(source)
                    ok = not _gcc(cc, name, tmp, cflags, target, "optimising",
                                  background=True)
    finally:
        with _done:
            _pending.discard(target)
            if ok:
                _generations[target.parent] = _generations.get(target.parent, 0) + 1
            _done.notify_all()


def _tiers() -> bool:
    return os.environ.get("TOCONTROL_COMPILE_TIERS", "1") != "0"


def _paths(name: str, source: bytes, cflags: Sequence[str] | None = None
           ) -> tuple[tuple[str, ...], Path, Path | None]:
    """The optimised library's flags and path, and the quick build's path (or None)."""
    if cflags is None:
        cflags = CFLAGS if len(source) <= LARGE_SOURCE else LARGE_CFLAGS
    quick = _tiers() and len(source) > QUICK_SOURCE
    return tuple(cflags), _target(name, source, cflags), \
        _target(name, source, QUICK_CFLAGS) if quick else None


def _build(cc: str, name: str, tmp: str, cflags: Sequence[str] | None = None
           ) -> tuple[Path | None, str]:
    """Compile ``tmp/name.c`` into the cache (unless there already), keyed by its source.

    A long source without its optimised library in the cache gets the quick build, and the
    optimised one is started in the background (see the module's docstring).
    """
    source = Path(tmp, f"{name}.c").read_bytes()
    cflags, target, quick_target = _paths(name, source, cflags)
    if target.is_file():
        return target, "cached"
    quick = quick_target is not None
    if quick:
        with _done:
            start = target not in _pending
            _pending.add(target)
        if start:
            threading.Thread(target=_optimise, args=(cc, name, source, cflags, target),
                             name=f"optimise {name}", daemon=True).start()
        target, cflags = quick_target, QUICK_CFLAGS
    how = "cached (quick build)" if quick else "cached"
    with _target_lock(target), _process_lock(target):
        if not target.is_file():
            why = _gcc(cc, name, tmp, cflags, target, "compiling")
            if why:
                return None, f"virtual machine (compiler failed: {why})"
            how = "compiled (quick build)" if quick else "compiled"
    return target, how


@contextmanager
def parallel_builds(jobs: int | None = None, wait: bool = True) -> Iterator[None]:
    """In this thread, :func:`compile_function` and :func:`compile_functions` only start builds.

    Inside the block they generate the C source, start its build on one of ``jobs``
    threads (default: the usable cores) and return the functions uncompiled, with ``how``
    ``"deferred"``; the block ends when every build has ended. Made for a throw-away pass
    over everything a model needs: the next pass finds it all in the cache, having used
    every core for the compiler (each build still has its two tiers). With ``wait`` False
    the block ends at once and the builds go on: :func:`compile_owned` waits for its own
    build on the next call, so that what is needed first can be used while the rest builds.
    """
    if getattr(_deferred, "pool", None) is not None:
        yield  # nested: the outer block waits
        return
    if jobs is None:
        jobs = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
            else (os.cpu_count() or 1)
    futures: list[Future] = []
    pool = ThreadPoolExecutor(max_workers=max(1, jobs), thread_name_prefix="compile")
    _deferred.pool, _deferred.futures = pool, futures
    try:
        yield
    finally:
        _deferred.pool = _deferred.futures = None
        pool.shutdown(wait=wait)
        if wait:
            for future in futures:
                future.result()


def _build_owned(cc: str, name: str, tmp: tempfile.TemporaryDirectory,
                 cflags: Sequence[str] | None = None) -> None:
    """A deferred build: :func:`_build` in a pool thread, which then removes ``tmp``."""
    with tmp:
        _build(cc, name, tmp.name, cflags)


def _defer(cc: str, name: str, write: Callable[[str], None],
           cflags: Sequence[str] | None = None) -> tuple[Path, Path | None, Future] | None:
    """Inside :func:`parallel_builds`: write the source into a new directory, start its build.

    Returns the paths the build will fill (optimised, quick or None) and the build's
    future, or None outside.
    """
    pool = getattr(_deferred, "pool", None)
    if pool is None:
        return None
    tmp = tempfile.TemporaryDirectory()
    write(tmp.name)
    _, target, quick = _paths(name, Path(tmp.name, f"{name}.c").read_bytes(), cflags)
    future = pool.submit(_build_owned, cc, name, tmp, cflags)
    _deferred.futures.append(future)
    return target, quick, future


def _generate_one(fun: ca.Function, tmp: str) -> None:
    # The same source as fun.generate(), written into ``tmp`` by its path: Function.generate
    # writes into the working directory, and changing it from one thread made another
    # thread's generated file land in the caller's directory.
    _generate_many(fun.name(), [fun], tmp)


def _generate_many(name: str, funs: Sequence[ca.Function], tmp: str) -> None:
    gen = ca.CodeGenerator(f"{name}.c")
    for fun in funs:
        gen.add(fun)
    gen.generate(tmp + os.sep)


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
        ``"cached"``, ``"compiled"`` (either with `` (quick build)`` when the optimised
        library is still being built), ``"deferred"`` (inside :func:`parallel_builds`: not
        compiled yet) or ``"virtual machine (reason)"``.
    """
    cc = _compiler()
    if cc is None:
        return fun, "virtual machine (no C compiler or TOCONTROL_COMPILE=0)"
    name = fun.name()
    if _defer(cc, name, lambda tmp: _generate_one(fun, tmp)) is not None:
        return fun, "deferred"
    with tempfile.TemporaryDirectory() as tmp:
        _generate_one(fun, tmp)
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
        As for :func:`compile_function`.
    """
    cc = _compiler()
    if cc is None:
        return list(funs), "virtual machine (no C compiler or TOCONTROL_COMPILE=0)"
    if _defer(cc, name, lambda tmp: _generate_many(name, funs, tmp)) is not None:
        return list(funs), "deferred"
    with tempfile.TemporaryDirectory() as tmp:
        _generate_many(name, funs, tmp)
        target, how = _build(cc, name, tmp)
    if target is None:
        return list(funs), how
    return [ca.external(fun.name(), str(target)) for fun in funs], how


# ------------------------------------------------------------------ owned functions
@dataclass
class _Owned:
    """One owner's library: its symbolic functions, and what was loaded for them."""

    funs: list
    lock: threading.Lock = field(default_factory=threading.Lock)
    #: (optimised, quick or None) libraries of the source, once it was generated.
    paths: tuple[Path, Path | None] | None = None
    #: The build started inside :func:`parallel_builds`, until it ended.
    build: Future | None = None
    loaded: Path | None = None
    compiled: list | None = None
    how: str = ""


#: owner -> {key: _Owned}; an entry lives as long as its owner.
_owned: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def compile_owned(owner: object, key: object, name: str,
                  build: Callable[[], Sequence[ca.Function]],
                  cflags: Sequence[str] | None = None) -> tuple[list[ca.Function], str]:
    """:func:`compile_functions` of ``build()`` for one owner, its graphs built once.

    Parameters
    ----------
    owner : object
        What the functions belong to (a model; held weakly): they live as long as it does.
    key : hashable
        Which of the owner's libraries.
    name : str
        Name of the library (a C identifier).
    build : callable
        Returns the symbolic functions; called on the first use of ``(owner, key)`` only.
    cflags : sequence of str, optional
        Flags of the optimised library (default: by the source's size, as for all).

    Returns
    -------
    functions, how
        As for :func:`compile_functions`. A later call returns the same compiled functions,
        or loads the optimised library once it has landed after a quick build; inside
        :func:`parallel_builds` the build is started and the next call outside the block
        loads it, without generating the source again in either case.
    """
    with _meta_lock:
        entries = _owned.setdefault(owner, {})
        entry = entries.get(key)
        if entry is None:
            entry = entries[key] = _Owned(funs=[])
    with entry.lock:
        if entry.build is None and entry.paths is not None and \
                entry.loaded == entry.paths[0] and \
                os.environ.get("TOCONTROL_COMPILE", "1") != "0":
            # The optimised library is loaded: nothing replaces it. No compiler lookup and
            # no file check: a replan's quick motion asks about 13 times (0.5-1 ms of it).
            return entry.compiled, entry.how
        if not entry.funs:
            entry.funs = list(build())
        funs = entry.funs
        cc = _compiler()
        if cc is None:
            return list(funs), "virtual machine (no C compiler or TOCONTROL_COMPILE=0)"
        if entry.build is not None:
            entry.build.result()  # started without waiting (parallel_builds(wait=False))
            entry.build = None
        if entry.paths is not None:
            optimised, quick = entry.paths
            for path, how in ((optimised, "cached"), (quick, "cached (quick build)")):
                if path is None or not path.is_file():
                    continue
                if entry.loaded != path:
                    entry.compiled = [ca.external(f.name(), str(path)) for f in funs]
                    entry.loaded, entry.how = path, how
                return entry.compiled, entry.how
        deferred = _defer(cc, name, lambda tmp: _generate_many(name, funs, tmp), cflags)
        if deferred is not None:
            entry.paths, entry.build = deferred[:2], deferred[2]
            return list(funs), "deferred"
        with tempfile.TemporaryDirectory() as tmp:
            _generate_many(name, funs, tmp)
            target, how = _build(cc, name, tmp, cflags)
            source = Path(tmp, f"{name}.c").read_bytes()
        entry.paths = _paths(name, source, cflags)[1:]
        if target is None:
            return list(funs), how
        entry.compiled = [ca.external(f.name(), str(target)) for f in funs]
        entry.loaded, entry.how = target, how
        return entry.compiled, how


# ------------------------------------------------------------------ buffered calls
def bind_buffers(fun: ca.Function, ins, outs) -> tuple:
    """An evaluation buffer of ``fun`` reading ``ins`` and writing ``outs`` (numpy arrays)."""
    buf, evaluate = fun.buffer()
    for i, arr in enumerate(ins):
        buf.set_arg(i, memoryview(arr))
    for i, arr in enumerate(outs):
        buf.set_res(i, memoryview(arr))
    return buf, evaluate, ins, outs


class BufferedFunction:
    """Call a CasADi function with dense inputs and outputs through numpy buffers.

    A plain call converts every argument to and from CasADi's ``DM`` (tens of microseconds
    a call); this binds fixed numpy arrays once and only copies values in and out.

    Parameters
    ----------
    fun : casadi.Function
        Every input and output dense.

    Notes
    -----
    Calls are serialised by a lock (the buffers are shared).
    """

    def __init__(self, fun: ca.Function) -> None:
        def layout(sparsity):
            if not sparsity.is_dense():
                raise ValueError(f"{fun.name()}: sparse input or output")
            return sparsity.size2(), sparsity.size1()  # column-major: (cols, rows) in C order

        ins = [np.zeros(layout(fun.sparsity_in(i))) for i in range(fun.n_in())]
        outs = [np.zeros(layout(fun.sparsity_out(i))) for i in range(fun.n_out())]
        self._shapes = [fun.size_out(i) for i in range(fun.n_out())]
        self._buf, self._evaluate, self._ins, self._outs = bind_buffers(fun, ins, outs)
        self._lock = threading.Lock()

    def __call__(self, *args) -> list[np.ndarray]:
        """Outputs as arrays of the function's shapes, (rows, cols); column vectors 1-D."""
        with self._lock:
            for buf, arg in zip(self._ins, args, strict=True):
                arr = np.asarray(arg, dtype=float)
                buf[:] = arr.T if arr.ndim == 2 else arr.reshape(buf.shape)
            self._evaluate()
            return [out[0].copy() if cols == 1 else out.T.copy()
                    for out, (_, cols) in zip(self._outs, self._shapes, strict=True)]
