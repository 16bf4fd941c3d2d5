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

Heartbeat
---------
A large strain increment keeps the hosts busy for minutes before any answers. While
``call_all`` waits, it calls ``heartbeat(progress)`` every ``interval`` seconds (default
:data:`HEARTBEAT_INTERVAL`; the default heartbeat logs a line to ``granular_multiscale.dem``),
and once more when all hosts have answered if it beat at least once, so that a step that never
finishes keeps saying so instead of hanging silently. :class:`Progress` is read from the
progress block each host publishes (``worker.py``): a few shared-memory words the driver polls
between waits on the sockets, so the hosts are never asked anything and compute exactly what
they compute without a heartbeat. The Dask executor gets the same words from an ``async``
method of each actor, which the worker runs on its event loop beside the busy ``call``; if that
query fails, a beat still reports the elapsed time and the hosts that answered.
"""

from __future__ import annotations

import logging
import math
import mmap
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Callable

import numpy as np

from ..materials.base import MaterialPointError
from .worker import PLANNED, PROGRESS_BYTES, RVES_DONE, RVES_TOTAL, STEPS_DONE, STEPS_PLANNED
from .yade_env import child_env

#: seconds between two heartbeats of a call_all that is still waiting for its hosts
HEARTBEAT_INTERVAL = 30.0
_log = logging.getLogger("granular_multiscale.dem")


class HostError(MaterialPointError):
    """An RVE host reported an error or died."""


@dataclass
class Progress:
    """What the hosts of one ``call_all`` have published so far (summed over the hosts called)."""

    command: str
    elapsed: float  # seconds since the messages went out
    hosts: int  # hosts called
    replied: int  # hosts that answered
    rves_done: int  # RVEs stepped to the end of their increment
    rves_total: int  # RVEs with an increment to step (hosts that have not started yet count 0)
    steps_done: int  # DEM steps run (each RVE: its N steps + one at rest)
    steps_planned: int | None  # DEM steps to run; None until every host called has published its plan
    finished: bool = False  # the last beat of a call, once every host has answered
    known: bool = True  # False: the hosts' progress could not be read (Dask), only elapsed/replied hold


def sum_progress(command: str, elapsed: float, blocks: list, replied: int, finished: bool = False) -> Progress:
    """A :class:`Progress` from the progress words of the hosts called (None: not readable)."""
    known = [b for b in blocks if b is not None]
    planned = len(known) == len(blocks) and all(b[PLANNED] for b in known)
    return Progress(
        command, elapsed, len(blocks), replied,
        rves_done=int(sum(b[RVES_DONE] for b in known)),
        rves_total=int(sum(b[RVES_TOTAL] for b in known)),
        steps_done=int(sum(b[STEPS_DONE] for b in known)),
        steps_planned=int(sum(b[STEPS_PLANNED] for b in known)) if planned else None,
        finished=finished, known=len(known) == len(blocks),
    )


def format_progress(p: Progress, what: str | None = None) -> str:
    """One heartbeat line, e.g. ``DEM trial running: 3/16 RVEs, 41,230/128,000 DEM steps, 2/4
    hosts answered, 61.0 s``; ``what`` replaces ``DEM trial``."""
    head = f"{what or 'DEM ' + p.command} {'done' if p.finished else 'running'}"
    if not p.known:
        return f"{head}: {p.replied}/{p.hosts} hosts answered, {p.elapsed:.1f} s (host progress not readable)"
    if p.steps_planned is None and not p.rves_total:  # a command that steps no RVE (snapshot, load)
        return f"{head}: {p.replied}/{p.hosts} hosts answered, {p.elapsed:.1f} s"
    planned = "?" if p.steps_planned is None else f"{p.steps_planned:,}"
    return (f"{head}: {p.rves_done}/{p.rves_total} RVEs, {p.steps_done:,}/{planned} DEM steps, "
            f"{p.replied}/{p.hosts} hosts answered, {p.elapsed:.1f} s")


def log_progress(p: Progress) -> None:
    """The default heartbeat."""
    _log.info("%s", format_progress(p))


Heartbeat = Callable[[Progress], None]


class _Beats:
    """When a waiting call_all beats: every ``interval`` s (``math.inf``: never), and once at the
    end if it beat at all."""

    def __init__(self, heartbeat: Heartbeat | None, interval: float | None, first: float | None = None):
        self.heartbeat = heartbeat or log_progress
        self.interval = HEARTBEAT_INTERVAL if interval is None else float(interval)
        self.t0 = time.monotonic()
        self.next = self.t0 + (self.interval if first is None else float(first))
        self.count = 0

    def timeout(self) -> float | None:
        """How long the caller may wait before the next beat is due (None: for ever)."""
        if math.isinf(self.next):
            return None
        return max(0.0, self.next - time.monotonic())

    def due(self) -> bool:
        return time.monotonic() >= self.next

    def beat(self, progress: Callable[[float], Progress]) -> None:
        now = time.monotonic()
        # the next beat one interval after this one (a slow beat does not make a burst of them)
        self.next = now + self.interval
        self.count += 1
        self._call(progress, now - self.t0)

    def close(self, progress: Callable[[float], Progress]) -> None:
        if self.count:
            self._call(progress, time.monotonic() - self.t0)

    def _call(self, progress: Callable[[float], Progress], elapsed: float) -> None:
        # a failing heartbeat must not leave the hosts' answers unread (the next call would read
        # them as its own): report it and go on waiting
        try:
            self.heartbeat(progress(elapsed))
        except Exception:
            _log.exception("DEM heartbeat failed (the DEM call goes on)")


def new_progress_block() -> tuple[int, np.ndarray]:
    """A zeroed progress block for one host: a file descriptor to hand it, and the driver's view.

    An anonymous memory file (Linux ``memfd``; elsewhere an unlinked temporary file) mapped
    shared on both sides: no name to clean up, nothing written to disk, and it goes away with
    the last mapping. The caller closes the descriptor once the host has it."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("rve-host-progress")
    else:
        with tempfile.TemporaryFile() as f:
            fd = os.dup(f.fileno())
    os.ftruncate(fd, PROGRESS_BYTES)  # zero-filled
    return fd, np.frombuffer(mmap.mmap(fd, PROGRESS_BYTES), dtype=np.int64)


def spawn_host() -> tuple[subprocess.Popen, Connection, np.ndarray]:
    """Start one RVE host process; returns the process, the driver's end of its socket and the
    host's progress block (``worker.py``)."""
    ours, theirs = socket.socketpair()
    progress_fd, progress = new_progress_block()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "granular_multiscale.dem.worker", str(theirs.fileno()), str(progress_fd)],
            pass_fds=[theirs.fileno(), progress_fd],
            env=child_env(),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,  # YADE greets on stdout
            start_new_session=True,  # its own process group: closing can end the whole lineage
        )
    finally:
        theirs.close()
        os.close(progress_fd)
    return proc, Connection(ours.detach()), progress


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
        spawned = [spawn_host() for _ in range(n_slots)]
        self.hosts = [(proc, conn) for proc, conn, _ in spawned]
        self.progress_blocks = [block for _, _, block in spawned]
        self.n_slots = n_slots
        self.labels = [f"local worker {i} (pid {p.pid})" for i, (p, _) in enumerate(self.hosts)]

    def call_all(self, messages: list, heartbeat: Heartbeat | None = None, interval: float | None = None,
                 first: float | None = None) -> list:
        """Send message i to host i (None: skip), then gather every answer; while waiting, call
        ``heartbeat(Progress)`` every ``interval`` s, the first time after ``first`` s (default
        ``interval``: a caller making many short calls keeps its own clock; module docstring)."""
        pending = {}
        called = []
        for i, ((proc, conn), msg) in enumerate(zip(self.hosts, messages)):
            if msg is None:
                continue
            # zeroed before the message goes: the host is idle until it reads it, so every word
            # read after this belongs to this command
            self.progress_blocks[i][:] = 0
            try:
                conn.send(msg)
            except OSError as e:
                raise HostError(f"{self.labels[i]} is gone ({e}); exit code {proc.poll()}") from None
            pending[conn] = i
            called.append(i)
        command = next((m[0] for m in messages if m is not None), "call")
        beats = _Beats(heartbeat, interval, first)

        def progress(elapsed: float, finished: bool = False) -> Progress:
            return sum_progress(command, elapsed, [self.progress_blocks[i] for i in called],
                                len(called) - len(pending), finished)

        replies: list = [None] * len(messages)
        errors = []
        while pending:
            for conn in wait(list(pending), timeout=beats.timeout()):
                i = pending.pop(conn)
                try:
                    replies[i] = _unwrap(conn.recv(), self.labels[i])
                except (EOFError, OSError):
                    errors.append(f"{self.labels[i]} died (exit code {self.hosts[i][0].poll()})")
                except HostError as e:
                    errors.append(str(e))
            if pending and beats.due():
                beats.beat(progress)
        beats.close(lambda elapsed: progress(elapsed, finished=True))
        if errors:
            raise HostError("\n".join(errors))
        return replies

    def close(self) -> None:
        for proc, conn in self.hosts:
            stop_host(proc, conn)
        self.hosts = []
        self.progress_blocks = []


class HostActor:
    """Dask actor: owns one RVE host process on the worker it was placed on."""

    def __init__(self):
        self.proc, self.conn, self.block = spawn_host()

    def call(self, msg):
        self.block[:] = 0  # see LocalExecutor.call_all
        self.conn.send(msg)
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            return ("error", f"RVE host died on {socket.gethostname()} (exit code {self.proc.poll()})")

    async def progress(self) -> list[int]:
        """The host's progress words. ``async``: the Dask worker runs it on its event loop, so it
        answers while ``call`` still blocks the actor's thread."""
        return self.block.tolist()

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

    def _progress_blocks(self, slots: list[int]) -> list:
        """The progress words of the actors in ``slots`` (None where the query failed)."""
        futures = []
        for i in slots:
            try:
                futures.append(self.actors[i].progress())
            except Exception:
                futures.append(None)
        out = []
        for f in futures:
            try:
                out.append(None if f is None else f.result(timeout=5))
            except Exception:  # an old actor without progress(), a slow or lost worker: beat without it
                out.append(None)
        return out

    def call_all(self, messages: list, heartbeat: Heartbeat | None = None, interval: float | None = None,
                 first: float | None = None) -> list:
        """As :meth:`LocalExecutor.call_all`; the heartbeat's progress comes from the actors."""
        pending = [(i, self.actors[i].call(m)) for i, m in enumerate(messages) if m is not None]
        called = [i for i, _ in pending]
        command = next((m[0] for m in messages if m is not None), "call")
        beats = _Beats(heartbeat, interval, first)
        waiting = set(called)

        def progress(elapsed: float, finished: bool = False) -> Progress:
            return sum_progress(command, elapsed, self._progress_blocks(called), len(called) - len(waiting), finished)

        replies: list = [None] * len(messages)
        errors = []
        for i, fut in pending:
            while not fut.done():
                timeout = beats.timeout()
                try:  # wait for this answer, but not past the next beat
                    fut.result(timeout=None if timeout is None else max(timeout, 0.01))
                except TimeoutError:
                    pass
                except Exception:  # a failed call: reported by the result() below
                    break
                if not fut.done() and beats.due():
                    waiting.difference_update(j for j, f in pending if f.done())
                    beats.beat(progress)
            waiting.discard(i)
            try:
                replies[i] = _unwrap(fut.result(), self.labels[i])
            except HostError as e:
                errors.append(str(e))
            except Exception as e:  # worker lost, comm error
                errors.append(f"{self.labels[i]}: {type(e).__name__}: {e}")
        beats.close(lambda elapsed: progress(elapsed, finished=True))
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
