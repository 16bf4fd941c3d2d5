"""RVE host: a process that keeps the YADE scenes of a group of Gauss points resident.

Started as ``python -m granular_multiscale.dem.worker FD`` (see ``executors.spawn_host``); it
talks to its driver over the socket ``FD`` with ``multiprocessing.connection`` messages
``(command, arguments)`` and answers ``("ok", result)`` or ``("error", text)``.

Rollback by ``fork``
--------------------
Every Newton trial of a load step must start from the converged state of the previous step.
Serialising and re-loading a scene costs ~25 + 25 ms for 400 spheres (plus a full collider
sort), more than the DEM increment itself. A single-threaded process can instead be
*forked*: the child gets a copy-on-write image of every resident scene for ~5 ms per host
(not per RVE) and only pays for the memory pages it touches. So:

* the **holder** process owns the converged scenes and never steps them;
* a **trial** forks a child that imposes the strain increments, answers the driver and
  waits;
* another trial in the same step: the child exits and the holder forks a fresh one;
* ``commit``: the child tells the holder to exit and becomes the holder itself.

Only one process of the lineage reads the driver's socket at a time. A small root process
(a child subreaper) reaps whatever exits. YADE runs with one thread, so a trial computed in
a child is bit-for-bit the trial a replay computes in the holder (checkpoint resume).

Deformation imposed on an RVE: the *symmetric* strain increment Δε (the FEM passes small
strains; the rigid-body spin of a Gauss point does not change its stress in a small-strain
formulation, and rotating the cell would rotate the returned stress), as the constant
velocity gradient ``velGrad = Δε / (N dt)`` over N DEM steps,
N = clamp(ceil(max|Δεij| / (strain_rate · dt)), min_steps, max_steps); afterwards
``velGrad = 0``. A zero increment returns the converged state without stepping.

Snapshots: ``snapshot`` serialises every scene (to a file, or not) and re-loads it; ``reload``
does the same to some scenes only (the DEM subset's replay, ``subset.py``).

Progress
--------
A large increment keeps a host busy for minutes before it answers. So that the driver can say
how far it is without asking (a message would wait behind the trial), the host publishes its
progress in a small shared-memory block (``python -m granular_multiscale.dem.worker FD
PROGRESS_FD``: a file of :data:`PROGRESS_BYTES` the driver created and maps too): the int64
words :data:`PROGRESS_FIELDS`, written by plain stores while ``impose`` runs (every
:data:`PROGRESS_CHUNK` DEM steps). The block is shared with every forked trial child, since a
``MAP_SHARED`` mapping survives ``fork``. The driver zeroes it before each command; the host never
reads it, so it cannot change what the DEM computes.
"""

from __future__ import annotations

import math
import mmap
import os
import pickle
import sys
import time
import traceback
from multiprocessing.connection import Connection

import numpy as np

PR_SET_CHILD_SUBREAPER = 36

#: the int64 words of the progress block (module docstring): RVEs stepped so far and to step in
#: this command, DEM steps run so far and planned (each RVE: its N steps + the one at rest), and
#: ``planned`` = 1 once ``steps_planned`` is known
PROGRESS_FIELDS = ("rves_done", "rves_total", "steps_done", "steps_planned", "planned")
RVES_DONE, RVES_TOTAL, STEPS_DONE, STEPS_PLANNED, PLANNED = range(len(PROGRESS_FIELDS))
PROGRESS_BYTES = 8 * len(PROGRESS_FIELDS)
#: DEM steps between two updates of ``steps_done``: a store per 64 steps of ~100 µs costs nothing
PROGRESS_CHUNK = 64


def map_progress(fd: int) -> np.ndarray:
    """The progress block in the file ``fd`` (shared mapping) as an int64 array of PROGRESS_FIELDS."""
    return np.frombuffer(mmap.mmap(fd, PROGRESS_BYTES), dtype=np.int64)


def steps_for_increment(dstrain: np.ndarray, dt: float, strain_rate: float, min_steps: int, max_steps: int) -> int:
    """DEM steps that impose a Voigt strain increment at (at most) the given strain rate."""
    emax = float(np.abs(dstrain).max())
    if emax == 0.0:
        return 0
    n = math.ceil(emax / (strain_rate * dt))
    return int(min(max(n, min_steps), max_steps))


class Host:
    """The YADE side: one scene per Gauss point of this host (lives in holder/trial processes)."""

    def __init__(self, progress: np.ndarray | None = None):
        from .yade_env import import_yade

        self.O = import_yade()
        from yade import utils
        from yade.minieigenHP import Matrix3

        self.utils, self.Matrix3 = utils, Matrix3
        self.gps: list[int] = []
        self.scene_ids: list[int] = []
        self.settings: dict = {}
        self.stress = np.zeros((0, 6))
        self.tangent = np.zeros((0, 6, 6))
        self.n_spheres: list[int] = []
        # scenes not loaded yet (load_packings with lazy=True): local index -> packing scene string
        self.pending: dict[int, bytes] = {}
        # where impose() publishes its progress (a private array when nobody reads it)
        self.progress = np.zeros(len(PROGRESS_FIELDS), dtype=np.int64) if progress is None else progress

    # ---- set-up -------------------------------------------------------------------
    def _scene(self, k: int) -> None:
        """Make scene k the current one; a scene loaded on demand (``lazy``) is loaded now."""
        self.O.switchToScene(self.scene_ids[k])
        blob = self.pending.pop(k, None)
        if blob is not None:
            self.O.stringToScene(blob)
            self._apply_settings()

    def _ensure_scenes(self, n: int) -> None:
        O = self.O
        if not self.scene_ids:
            self.scene_ids.append(O.thisScene)
        while len(self.scene_ids) < n:
            self.scene_ids.append(O.addScene())

    def _apply_settings(self) -> None:
        damping = self.settings.get("damping")
        for e in self.O.engines:
            if type(e).__name__ == "NewtonIntegrator" and damping is not None:
                e.damping = float(damping)

    def _respond(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        from .rve import stress_and_tangent

        return stress_and_tangent(self.utils)

    def load(self, gps: list[int], scenes: list[bytes], settings: dict, lazy: bool = False) -> dict:
        """Load one scene per Gauss point (YADE scene strings) and compute their response.

        ``lazy``: keep the strings and load a scene when it is first stepped (:meth:`_scene`); the
        response of each distinct string is computed once, in the first scene that uses it, which
        is then loaded again on demand like the others. A scene is a function of its string, so
        loading it later gives the same bits; memory and load time are those of the scenes stepped."""
        self.gps = list(gps)
        self.settings = dict(settings)
        self._ensure_scenes(len(gps))
        self.stress = np.zeros((len(gps), 6))
        self.tangent = np.zeros((len(gps), 6, 6))
        self.n_spheres = []
        self.pending = {}
        responses: dict[bytes, tuple] = {}
        for k, blob in enumerate(scenes):
            if lazy and blob in responses:
                self.stress[k], self.tangent[k], n = responses[blob]
                self.n_spheres.append(n)
                continue
            self.pending[k] = blob
            self._scene(k)
            if not self.O.periodic:
                raise RuntimeError(f"the RVE of Gauss point {gps[k]} is not a periodic cell")
            self.stress[k], self.tangent[k] = self._respond(k)
            self.n_spheres.append(len(self.O.bodies))
            if lazy:
                responses[blob] = (self.stress[k], self.tangent[k], self.n_spheres[-1])
        if lazy:
            self.pending = dict(enumerate(scenes))
        return self.converged()

    def load_packings(self, gps: list[int], which: list, packings: dict, settings: dict, lazy: bool = False) -> dict:
        """``packings``: {key: {"name": file name, "data": file bytes}} of packings saved by ``rve``;
        ``which[k]``: the packing key of ``gps[k]``. Each packing is read once and copied into
        its scenes through one scene string, so every RVE starts from the same bits whatever
        host it lives on. ``lazy``: see :meth:`load`."""
        import tempfile

        self._ensure_scenes(max(len(gps), 1))
        strings = {}
        for key, item in packings.items():
            with tempfile.TemporaryDirectory() as tmp:
                path = os.path.join(tmp, os.path.basename(item["name"]))
                with open(path, "wb") as f:
                    f.write(item["data"])
                self._scene(0)
                self.O.load(path)
                strings[key] = self.O.sceneToString()
        return self.load(gps, [strings[w] for w in which], settings, lazy)

    def load_snapshot(self, gps: list[int], files: list[str], settings: dict) -> dict:
        """Load the scenes of ``gps`` from snapshot files written by :meth:`snapshot`."""
        wanted, found = set(gps), {}
        for path in files:
            with open(path, "rb") as f:
                content = pickle.load(f)
            found.update({gp: blob for gp, blob in content["scenes"].items() if gp in wanted})
        missing = sorted(wanted - set(found))
        if missing:
            raise FileNotFoundError(f"snapshot files {files} hold no scene for Gauss points {missing[:10]}")
        return self.load(gps, [found[gp] for gp in gps], settings)

    def converged(self) -> dict:
        return {"gps": self.gps, "stress": self.stress.copy(), "tangent": self.tangent.copy(), "n_spheres": list(self.n_spheres)}

    # ---- DEM ----------------------------------------------------------------------
    def impose(self, dstrain: np.ndarray) -> dict:
        """Impose one strain increment per scene (from its current state); mutates the scenes.

        Publishes its progress in ``self.progress`` (module docstring) as it goes."""
        from .rve import voigt_to_matrix3

        O, cfg, progress = self.O, self.settings, self.progress
        dstrain = np.asarray(dstrain, dtype=float).reshape(len(self.gps), 6)
        stress, tangent = self.stress.copy(), self.tangent.copy()
        steps = np.zeros(len(self.gps), dtype=np.int64)
        dem_time = cpu_time = 0.0
        particle_steps = 0
        # a zero increment: no DEM step (and a scene loaded on demand stays unloaded)
        stepped = [k for k in range(len(self.gps)) if dstrain[k].any()]
        progress[RVES_TOTAL] = len(stepped)
        # The plan first, so that the driver can show "steps done of planned" from the start. N
        # depends on the scene's dt only, which nothing changes before the scene is stepped below;
        # a scene loaded on demand is loaded here instead of a few RVEs later, from the same string.
        for k in stepped:
            self._scene(k)
            steps[k] = steps_for_increment(dstrain[k], O.dt, cfg["strain_rate"], cfg["min_steps"], cfg["max_steps"])
        progress[STEPS_PLANNED] = int(steps.sum()) + len(stepped)
        progress[PLANNED] = 1
        steps_done = 0
        for k in stepped:
            self._scene(k)
            n = int(steps[k])
            O.cell.velGrad = voigt_to_matrix3(dstrain[k] / (n * O.dt), self.Matrix3)
            t0, c0 = time.perf_counter(), time.process_time()
            step = O.step
            # the same n calls of O.step as one loop, in chunks between which the count is published
            for first in range(0, n, PROGRESS_CHUNK):
                for _ in range(min(PROGRESS_CHUNK, n - first)):
                    step()
                progress[STEPS_DONE] = steps_done + min(first + PROGRESS_CHUNK, n)
            # Forces are computed before particles move within a step: one more step at rest
            # makes the contact forces (hence the stress) those of the fully deformed cell.
            O.cell.velGrad = self.Matrix3.Zero
            step()
            dem_time += time.perf_counter() - t0
            cpu_time += time.process_time() - c0
            steps_done += n + 1
            progress[STEPS_DONE] = steps_done
            particle_steps += (n + 1) * self.n_spheres[k]
            stress[k], tangent[k] = self._respond(k)
            if not (np.isfinite(stress[k]).all() and np.isfinite(tangent[k]).all()):
                raise FloatingPointError(f"non-finite stress or tangent in the RVE of Gauss point {self.gps[k]}")
            progress[RVES_DONE] += 1
        return {"stress": stress, "tangent": tangent, "steps": steps, "dem_time": dem_time, "dem_cpu_time": cpu_time,
                "particle_steps": particle_steps}

    def accept(self, result: dict) -> None:
        self.stress, self.tangent = result["stress"], result["tangent"]

    # ---- snapshots (checkpoints) ------------------------------------------------------
    def snapshot(self, path: str | None) -> dict:
        """Serialise every scene, write them to ``path`` (pickled {gp: scene string}; None: no
        file) and re-load them, so that a run resumed from this file and this run continue
        from bit-identical states."""
        t0 = time.perf_counter()
        blobs = {}
        for k, gp in enumerate(self.gps):
            if k in self.pending:  # never stepped: its packing's string, re-loaded on demand
                blobs[gp] = self.pending[k]
                continue
            self._scene(k)
            blobs[gp] = self.O.sceneToString()
        if path is not None:
            tmp = f"{path}.tmp{os.getpid()}"
            with open(tmp, "wb") as f:
                pickle.dump({"gps": self.gps, "scenes": blobs}, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        for k, gp in enumerate(self.gps):
            if k not in self.pending:
                self._reload_scene(k, blobs[gp])
        return {"time": time.perf_counter() - t0, "bytes": int(sum(len(b) for b in blobs.values()))}

    def reload(self, gps: list[int]) -> dict:
        """Serialise and re-load the scenes of ``gps`` only (what :meth:`snapshot` does to every
        scene, without a file): the others are left as they are."""
        t0 = time.perf_counter()
        for gp in gps:
            k = self.gps.index(gp)
            self._scene(k)
            self._reload_scene(k, self.O.sceneToString())
        return {"time": time.perf_counter() - t0}

    def _reload_scene(self, k: int, blob: bytes) -> None:
        self._scene(k)
        self.O.stringToScene(blob)
        self._apply_settings()

    def scene_strings(self) -> dict:
        out = {}
        for k, gp in enumerate(self.gps):
            self._scene(k)
            out[gp] = self.O.sceneToString()
        return out


# ------------------------------------------------------------------------ process lineage


def _send_verdict(fd: int, verdict) -> None:
    """Child -> holder, once: write the pickled verdict and close the pipe."""
    data = memoryview(pickle.dumps(verdict))
    try:
        while data:
            data = data[os.write(fd, data):]
    finally:
        os.close(fd)


def _read_verdict(fd: int):
    """Holder: block until the child writes its verdict and closes (None if it died silently)."""
    chunks = []
    try:
        while chunk := os.read(fd, 1 << 16):
            chunks.append(chunk)
    finally:
        os.close(fd)
    return pickle.loads(b"".join(chunks)) if chunks else None


def _handle_common(host: Host, cmd: str, args: dict):
    """Commands a holder answers in place."""
    if cmd == "load_packings":
        return host.load_packings(args["gps"], args["which"], args["packings"], args["settings"],
                                  bool(args.get("lazy", False)))
    if cmd == "load_snapshot":
        return host.load_snapshot(args["gps"], args["files"], args["settings"])
    if cmd == "replay":
        result = host.impose(args["dstrain"])
        host.accept(result)
        return result
    if cmd == "snapshot":
        return host.snapshot(args["path"])
    if cmd == "reload":
        return host.reload(args["gps"])
    if cmd == "scene_strings":
        return host.scene_strings()
    if cmd == "converged":
        return host.converged()
    if cmd == "resident":
        return {"loaded": len(host.gps) - len(host.pending), "points": len(host.gps)}
    if cmd == "ping":
        return {"pid": os.getpid()}
    raise ValueError(f"unknown command {cmd!r}")


def _trial_child(conn: Connection, host: Host, args: dict, verdict_fd: int) -> None:
    """Run in a forked child: compute the trial, answer, then wait for the driver's verdict.

    Returns only after ``commit`` (this process is then the holder); exits otherwise, also when
    the driver is gone (then the holder learns it from the closed pipe and leaves too)."""
    try:
        _trial_child_body(conn, host, args, verdict_fd)
    except (OSError, EOFError):  # driver gone
        os._exit(0)


def _trial_child_body(conn: Connection, host: Host, args: dict, verdict_fd: int) -> None:
    try:
        result = host.impose(args["dstrain"])
    except Exception:
        conn.send(("error", traceback.format_exc()))
        _send_verdict(verdict_fd, ("failed", None))
        os._exit(0)
    conn.send(("ok", result))
    while True:
        try:
            cmd, a = conn.recv()
        except (EOFError, OSError):
            _send_verdict(verdict_fd, ("close", None))
            os._exit(0)
        if cmd == "trial":
            _send_verdict(verdict_fd, ("retry", a))
            os._exit(0)
        if cmd == "rollback":
            _send_verdict(verdict_fd, ("rollback", None))
            os._exit(0)
        if cmd == "commit":
            host.accept(result)
            _send_verdict(verdict_fd, ("commit", None))
            conn.send(("ok", None))
            return
        if cmd == "close":
            _send_verdict(verdict_fd, ("close", None))
            conn.send(("ok", None))
            os._exit(0)
        if cmd == "ping":
            conn.send(("ok", {"pid": os.getpid()}))
            continue
        conn.send(("error", f"command {cmd!r} is not allowed while a trial is pending (commit or rollback first)"))


def _trial(conn: Connection, host: Host, args: dict) -> bool:
    """In the holder: fork trial children until one is committed (then this process exits)
    or the driver rolls back (returns True: still the holder). Returns False in the child that
    became the holder (it continues the serve loop)."""
    while True:
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(r)
            _trial_child(conn, host, args, w)
            return False
        os.close(w)
        verdict = _read_verdict(r)
        if verdict is None:  # the child died without a word (or the driver is gone)
            os.waitpid(pid, 0)
            try:
                conn.send(("error", f"DEM trial process {pid} of Gauss points {host.gps[:5]}... died"))
            except OSError:
                os._exit(0)
            return True
        kind, payload = verdict
        if kind == "commit":
            os._exit(0)
        os.waitpid(pid, 0)
        if kind == "retry":
            args = payload
            continue
        if kind == "rollback":
            try:
                conn.send(("ok", None))
            except OSError:
                os._exit(0)
            return True
        if kind == "failed":
            return True
        os._exit(0)  # close


def serve(conn: Connection, progress: np.ndarray | None = None) -> None:
    """Holder loop (also continued by a trial child after commit); leaves when the driver is gone."""
    try:
        _serve(conn, progress)
    except (OSError, EOFError):
        pass
    os._exit(0)


def _serve(conn: Connection, progress: np.ndarray | None = None) -> None:
    host = Host(progress)
    while True:
        try:
            cmd, args = conn.recv()
        except (EOFError, OSError):
            os._exit(0)
        if cmd == "trial":
            _trial(conn, host, args)
            continue
        if cmd in ("commit", "rollback"):  # no trial pending: nothing to accept or undo
            conn.send(("ok", None))
            continue
        if cmd == "close":
            conn.send(("ok", None))
            os._exit(0)
        try:
            conn.send(("ok", _handle_common(host, cmd, args)))
        except Exception:
            conn.send(("error", traceback.format_exc()))


def main(argv: list[str]) -> None:
    fd = int(argv[0])
    progress = None
    if len(argv) > 1:  # the driver's progress block (module docstring)
        progress_fd = int(argv[1])
        progress = map_progress(progress_fd)
        os.close(progress_fd)  # the mapping stays
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    except Exception:  # not Linux: exited holders are then reaped by init
        pass
    from .yade_env import import_yade

    import_yade()  # before the first fork: every descendant shares the loaded libraries
    conn = Connection(fd)
    pid = os.fork()
    if pid == 0:
        sys.stdout.flush()
        serve(conn, progress)
        os._exit(0)
    conn.close()
    # root: reap the lineage until nothing is left
    while True:
        try:
            os.wait()
        except ChildProcessError:
            break
        except InterruptedError:
            continue


if __name__ == "__main__":
    main(sys.argv[1:])
