"""Where RVE hosts run: a local process pool, or workers of a Dask distributed cluster.

Both executors hold ``n_slots`` RVE hosts (``worker.py``); the material-point set sends one
message per host and gathers the answers (``call_all``), so only strain increments go out
and stresses/tangents come back while the scenes stay resident in the hosts.

* :class:`LocalExecutor` starts the hosts as child processes of this one.
* :class:`DaskExecutor` places one Dask *actor* per host on the cluster's workers; each actor
  starts the same host process next to itself (``executor: dask``, ``dask_scheduler``: an
  address such as ``tcp://10.0.0.5:8786`` or empty for a ``LocalCluster`` of ``n_slots``
  single-threaded worker processes). For clusters under SLURM/PBS, start the scheduler and
  workers with ``dask-jobqueue`` and pass the scheduler address. Snapshot files (checkpoints)
  are written by the hosts: put the checkpoint folder on a file system all workers share.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from multiprocessing.connection import Connection, wait

from ..materials.base import MaterialPointError
from .yade_env import child_env


class HostError(MaterialPointError):
    """An RVE host reported an error or died."""


def spawn_host() -> tuple[subprocess.Popen, Connection]:
    """Start one RVE host process; returns the process and the driver's end of its socket."""
    ours, theirs = socket.socketpair()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "granular_multiscale.dem.worker", str(theirs.fileno())],
            pass_fds=[theirs.fileno()],
            env=child_env(),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,  # YADE greets on stdout
            start_new_session=True,  # its own process group: closing can end the whole lineage
        )
    finally:
        theirs.close()
    return proc, Connection(ours.detach())


def _unwrap(reply, who: str):
    status, payload = reply
    if status != "ok":
        raise HostError(f"{who}: {payload}")
    return payload


def stop_host(proc: subprocess.Popen, conn: Connection | None, timeout: float = 10.0) -> None:
    """Ask a host to close; end its process group if it does not."""
    try:
        if conn is not None and not conn.closed:
            try:
                conn.send(("close", None))
                if conn.poll(timeout):
                    conn.recv()
            except (OSError, EOFError):
                pass
            conn.close()
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()


class LocalExecutor:
    """``n_slots`` RVE host processes on this machine."""

    kind = "local"

    def __init__(self, n_slots: int):
        if n_slots < 1:
            raise ValueError(f"the local executor needs at least one worker, got {n_slots}")
        self.hosts = [spawn_host() for _ in range(n_slots)]
        self.n_slots = n_slots
        self.labels = [f"local worker {i} (pid {p.pid})" for i, (p, _) in enumerate(self.hosts)]

    def call_all(self, messages: list) -> list:
        """Send message i to host i (None: skip), then gather every answer."""
        pending = {}
        for i, ((proc, conn), msg) in enumerate(zip(self.hosts, messages)):
            if msg is None:
                continue
            try:
                conn.send(msg)
            except OSError as e:
                raise HostError(f"{self.labels[i]} is gone ({e}); exit code {proc.poll()}") from None
            pending[conn] = i
        replies: list = [None] * len(messages)
        errors = []
        while pending:
            for conn in wait(list(pending)):
                i = pending.pop(conn)
                try:
                    replies[i] = _unwrap(conn.recv(), self.labels[i])
                except (EOFError, OSError):
                    errors.append(f"{self.labels[i]} died (exit code {self.hosts[i][0].poll()})")
                except HostError as e:
                    errors.append(str(e))
        if errors:
            raise HostError("\n".join(errors))
        return replies

    def close(self) -> None:
        for proc, conn in self.hosts:
            stop_host(proc, conn)
        self.hosts = []


class HostActor:
    """Dask actor: owns one RVE host process on the worker it was placed on."""

    def __init__(self):
        self.proc, self.conn = spawn_host()

    def call(self, msg):
        self.conn.send(msg)
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            return ("error", f"RVE host died on {socket.gethostname()} (exit code {self.proc.poll()})")

    def close(self):
        stop_host(self.proc, self.conn)
        return True


class DaskExecutor:
    """``n_slots`` RVE hosts, one per Dask actor, spread over the workers of a cluster."""

    kind = "dask"

    def __init__(self, n_slots: int, scheduler: str | None = None, client=None):
        from distributed import Client, LocalCluster

        self._own_cluster = None
        if client is None:
            if scheduler:
                client = Client(scheduler)
            else:
                self._own_cluster = LocalCluster(
                    n_workers=n_slots, threads_per_worker=1, processes=True, dashboard_address=None
                )
                client = Client(self._own_cluster)
            self._own_client = True
        else:
            self._own_client = False
        self.client = client
        workers = sorted(client.scheduler_info()["workers"])
        if not workers:
            raise HostError(f"the Dask cluster at {scheduler or 'LocalCluster'} has no workers")
        futures = [
            client.submit(HostActor, actor=True, workers=[workers[i % len(workers)]], allow_other_workers=False, pure=False)
            for i in range(n_slots)
        ]
        self.actors = [f.result() for f in futures]
        self._futures = futures  # keep the actors alive
        self.n_slots = n_slots
        self.labels = [f"Dask actor {i} on {workers[i % len(workers)]}" for i in range(n_slots)]

    def call_all(self, messages: list) -> list:
        pending = [(i, self.actors[i].call(m)) for i, m in enumerate(messages) if m is not None]
        replies: list = [None] * len(messages)
        errors = []
        for i, fut in pending:
            try:
                replies[i] = _unwrap(fut.result(), self.labels[i])
            except HostError as e:
                errors.append(str(e))
            except Exception as e:  # worker lost, comm error
                errors.append(f"{self.labels[i]}: {type(e).__name__}: {e}")
        if errors:
            raise HostError("\n".join(errors))
        return replies

    def close(self) -> None:
        try:
            for f in [a.close() for a in self.actors]:
                f.result()
        except Exception:
            pass
        self.actors, self._futures = [], []
        if self._own_client:
            self.client.close()
        if self._own_cluster is not None:
            self._own_cluster.close()


def make_executor(kind: str, n_slots: int, scheduler: str | None = None, client=None):
    if kind == "local":
        return LocalExecutor(n_slots)
    if kind == "dask":
        return DaskExecutor(n_slots, scheduler=scheduler, client=client)
    raise ValueError(f"config key 'dem.executor': unknown executor {kind!r} (local or dask)")
