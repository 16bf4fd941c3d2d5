"""One workflow at a time per output directory.

Snakemake's own lock lives in the working directory (``.snakemake/``), so two clones, or two
working directories, writing one ``output_dir`` would not see each other: the second would
rebuild files under the first. This lock lives in the output directory itself:
``<output_dir>/.workflow.lock`` holds the holder's pid, host, process start time, working
directory and start date. The Snakefile takes it before the first job (``onstart``) and gives
it back when the run ends (``onsuccess``/``onerror``).

A lock whose holder is gone (same host, pid not running, or running but started at another
time: a reused pid) is stale: it is taken over with a warning. A lock held from another host
cannot be checked from here; it stops the workflow, and the message says how to remove it.
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

LOCK_NAME = ".workflow.lock"


class OutputLockedError(RuntimeError):
    """Another workflow writes this output directory; the message names it."""


def lock_file(out: str | Path) -> Path:
    return Path(out) / LOCK_NAME


def _start_time(pid: int) -> str | None:
    """The process's start time in clock ticks since boot (/proc/<pid>/stat field 22), or None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]  # fields after the command name, which may hold spaces


def _me() -> dict:
    pid = os.getpid()
    return {"pid": pid, "host": socket.gethostname(), "process_start": _start_time(pid), "cwd": os.getcwd(),
            "started": time.strftime("%Y-%m-%d %H:%M:%S %Z")}


def read_holder(out: str | Path) -> dict | None:
    """The lock's holder as recorded, {} for an unreadable lock file, None without a lock."""
    try:
        return json.loads(lock_file(out).read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {}


def is_alive(holder: dict) -> bool | None:
    """True/False for a holder on this host; None when it cannot be told (another host)."""
    if holder.get("host") != socket.gethostname():
        return None
    pid = holder.get("pid")
    if not isinstance(pid, int):
        return False
    start = _start_time(pid)
    return start is not None and start == holder.get("process_start")


def describe(out: str | Path, holder: dict) -> str:
    return (f"output directory {out} is in use by another workflow: pid {holder.get('pid')} on host "
            f"{holder.get('host')}, started {holder.get('started')}, from {holder.get('cwd')}")


def held_by_other(out: str | Path) -> dict | None:
    """The holder of ``out``'s lock if it is another process that may still run, else None."""
    holder = read_holder(out)
    if not holder or holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
        return None
    return None if is_alive(holder) is False else holder


def acquire(out: str | Path, warn=print) -> None:
    """Take ``out``'s lock, or raise :class:`OutputLockedError` naming its holder. A stale lock
    is taken over (``warn`` says whose it was); so is an unreadable one."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    me = json.dumps(_me())
    for _ in range(2):
        try:
            fd = os.open(lock_file(out), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            holder = read_holder(out)
            if holder is None:
                continue  # released meanwhile
            if holder and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
                return
            alive = is_alive(holder) if holder else False
            if alive is not False:
                how = ("wait for it to finish" if alive else
                       f"if it no longer runs on {holder.get('host')}, remove {lock_file(out)}")
                raise OutputLockedError(f"{describe(out, holder)}; {how}") from None
            warn(f"taking over the stale lock of {out}: its holder (pid {holder.get('pid')}, started "
                 f"{holder.get('started')}, from {holder.get('cwd')}) no longer runs" if holder else
                 f"taking over the unreadable lock file {lock_file(out)}")
            lock_file(out).unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as f:
            f.write(me)
        return
    raise OutputLockedError(f"could not take the lock {lock_file(out)}: another workflow took it meanwhile")


def release(out: str | Path) -> None:
    """Remove ``out``'s lock if this process holds it."""
    holder = read_holder(out)
    if holder and holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
        lock_file(out).unlink(missing_ok=True)
