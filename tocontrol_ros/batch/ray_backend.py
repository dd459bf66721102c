"""The ``batch`` backend on a Ray cluster (``--ray auto|local|ADDRESS``).

Ray is an optional dependency (``pip install tocontrol_ros[ray]``): this module imports it
only when a :class:`RayBackend` is made, and nothing else in the package imports this module
at import time. Each task is a Ray task running
:func:`tocontrol_ros.batch.worker.run_task`; a Ray worker process builds the model on its
first task and keeps it (once per worker). The robot goes to the cluster once, with
``ray.put``. Ray does not retry a task whose worker died (``max_retries=0``): the runner
does, so that attempts are counted (and journaled) the same way for every backend.

``local`` starts a private cluster from this process, without the dashboard, with every
Ray process listening on and talking to loopback (``127.0.0.1``) only: Ray binds its gRPC
servers to all interfaces and advertises the machine's outward address unless it runs as a
single-machine Ray (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, read when ``ray`` is first
imported, and inherited by the processes it starts); ``auto`` joins the cluster that
``ray start`` started on this machine; anything else is an address (``HOST:PORT`` or
``ray://HOST:PORT``).
"""

from __future__ import annotations

import os
import sys

from tocontrol_ros.batch.tasks import RobotSpec, Task
from tocontrol_ros.batch.worker import run_task

__all__ = ["RayBackend", "RayUnavailableError"]

#: Tasks queued per CPU of the cluster: one running, one waiting, so that a worker that
#: finishes starts its next task without a round trip to this process.
QUEUE_PER_CPU = 2
#: Environment under which Ray keeps a local cluster on loopback (see the module docstring).
LOCAL_ONLY_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
#: Memory of the private cluster's object store (bytes): results are a few kB each.
LOCAL_OBJECT_STORE = 100 * 1024 * 1024


class RayUnavailableError(RuntimeError):
    """Ray is not installed, or the cluster cannot be reached."""


class RayBackend:
    """Runs tasks on a Ray cluster.

    Parameters
    ----------
    robot : RobotSpec
    address : str
        ``"local"``, ``"auto"`` or a cluster address.
    workers : int, optional
        ``local``: the cluster's CPUs (default: all of this machine's). Elsewhere: at most
        this many tasks at once (default: the cluster's CPUs).
    fn : callable (robot, task) -> dict, optional
        The work of one task (default :func:`~tocontrol_ros.batch.worker.run_task`; the
        memory's build passes its own); a module-level function, so that workers import it.
    """

    def __init__(self, robot: RobotSpec, address: str, workers: int | None = None,
                 fn=run_task) -> None:
        if address == "local":
            if "ray" in sys.modules and any(os.environ.get(k) != v
                                            for k, v in LOCAL_ONLY_ENV.items()):
                raise RayUnavailableError(
                    "--ray local: ray was imported before the loopback-only settings "
                    f"{LOCAL_ONLY_ENV} were made; set them in the environment")
            os.environ.update(LOCAL_ONLY_ENV)
        try:
            import ray
        except ImportError:
            raise RayUnavailableError(
                "--ray needs Ray: pip install 'tocontrol_ros[ray]' (or pip install ray)"
            ) from None
        self._ray = ray
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False,
                     object_store_memory=LOCAL_OBJECT_STORE, log_to_driver=False,
                     configure_logging=False)
            self.node_ip = ray.util.get_node_ip_address()
            if self.node_ip != "127.0.0.1":  # checked, not assumed: the setting is Ray's
                ray.shutdown()
                raise RayUnavailableError(f"--ray local: Ray chose node address "
                                          f"{self.node_ip}, not 127.0.0.1")
        else:
            try:
                ray.init(address=address, log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise RayUnavailableError(f"--ray {address}: {exc}") from None
            self.node_ip = ray.util.get_node_ip_address()
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.cpus = min(cpus, workers) if workers and address != "local" else cpus
        self.capacity = QUEUE_PER_CPU * self.cpus
        self._remote = ray.remote(num_cpus=1, max_retries=0)(fn)
        self._robot = ray.put(robot)
        self._refs: dict = {}

    def submit(self, task: Task) -> None:
        """Queue `task` on the cluster."""
        self._refs[self._remote.remote(self._robot, task)] = task

    def poll(self, timeout: float) -> list:
        """Finished tasks (waits up to `timeout` s for the first)."""
        ray = self._ray
        if not self._refs:
            return []
        ready, rest = ray.wait(list(self._refs), num_returns=1, timeout=timeout)
        if ready and rest:
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        out = []
        for ref in ready:
            task = self._refs.pop(ref)
            try:
                out.append((task, ray.get(ref), None))
            except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
                    ray.exceptions.RayTaskError, ray.exceptions.TaskCancelledError) as exc:
                out.append((task, None, f"{type(exc).__name__}: {str(exc).splitlines()[0]}"))
        return out

    def stop(self, tasks) -> None:
        """Cancel `tasks`, killing the workers that run them (they do not come back)."""
        keys = {t.key for t in tasks}
        for ref, task in list(self._refs.items()):
            if task.key in keys:
                self._ray.cancel(ref, force=True)
                del self._refs[ref]

    def close(self, abandon: bool = False) -> None:
        """Cancel what is left when abandoning; disconnect (a private cluster stops)."""
        if abandon:
            for ref in self._refs:
                self._ray.cancel(ref, force=True)
        self._refs.clear()
        self._ray.shutdown()
