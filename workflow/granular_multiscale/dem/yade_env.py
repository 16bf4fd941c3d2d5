"""Start YADE the same way in every process that runs it.

YADE is imported only in processes dedicated to it (RVE preparation, RVE hosts):
``from yade import *`` and YADE's start-up rebind module globals, print to stdout and read
``OMP_NUM_THREADS`` once. One OpenMP thread per process keeps every DEM step bit-for-bit
reproducible and lets the process be forked safely (a single-threaded process is the only
kind ``fork`` copies faithfully).
"""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys

from .. import vtk_order

ENV_THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def child_env() -> dict:
    """Environment for a process that will import YADE."""
    env = dict(os.environ)
    env.update(ENV_THREADS)
    return env


def import_yade():
    """Import YADE with one thread; returns the ``Omega`` singleton. Call once per process."""
    os.environ.update(ENV_THREADS)
    # YADE puts Debian's VTK 9.1 in the global symbol scope; pip's VTK modules loaded after it
    # bind to that copy and crash. If VTK is partly loaded already, load all of it first.
    vtk_order.before_yade_import()
    import yade  # noqa: F401  (side effects: plugin registration)
    from yade.wrapper import Omega

    omega = Omega()
    if omega.numThreads != 1:
        raise RuntimeError(
            f"YADE runs with {omega.numThreads} threads; set OMP_NUM_THREADS=1 before importing it"
        )
    _remove_at_exit(os.path.dirname(omega.tmpFilename()))
    return omega


def _remove_at_exit(yade_temp_dir: str) -> None:
    """YADE makes a /tmp/yade-XXXXXX folder when imported and removes it only when its own launcher
    exits, never when a Python process imported it: every RVE host of every run would leave one.
    The process that imported YADE removes it when it exits; its forked children share the folder
    and leave it to it (they end with os._exit, which runs no exit handler; the pid check covers
    one that would not)."""
    owner = os.getpid()

    def remove():
        if os.getpid() == owner:
            shutil.rmtree(yade_temp_dir, ignore_errors=True)

    atexit.register(remove)


def run_module(module: str, args: list[str], timeout: float | None = None) -> subprocess.CompletedProcess:
    """Run ``python -m module args`` with the YADE environment; raise with its stderr on failure."""
    cmd = [sys.executable, "-m", module, *args]
    out = subprocess.run(cmd, env=child_env(), capture_output=True, text=True, timeout=timeout)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {out.returncode}):\n{out.stderr[-4000:]}")
    return out
