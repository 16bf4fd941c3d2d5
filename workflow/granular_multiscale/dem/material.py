"""FEM–DEM material-point set: one YADE RVE per Gauss point.

``DemMaterialPointSet.evaluate(strain)`` sends each Gauss point's strain increment from its
last converged state to the RVE hosts (``worker.py``), which impose it on the periodic cell
and return the Love–Weber stress and the contact-stiffness tangent of
``utils.getStressAndTangent``; ``commit()`` makes the last trial the converged state.

What is imposed
---------------
The **symmetric strain increment only**, ``velGrad = Δε/(N dt)`` over N DEM steps with
``N = clamp(ceil(max|Δεij| / (strain_rate·dt)), min_steps, max_steps)``. The FEM solver is a
small-strain formulation whose Gauss points carry the symmetric strain; the skew part of
∇u is a rigid rotation that, in a small-strain formulation, must not change the stress, while
spinning a periodic cell would rotate its contact network and return a rotated stress.

Conventions (checked by ``tests/test_dem_material.py`` against the RVE itself)
------------------------------------------------------------------------------
* YADE's ``getStress``/``getStressAndTangent`` stress is tension positive (a consolidated
  packing gives −p), like the project's.
* A positive ``Cell.velGrad`` diagonal stretches the cell: strains are tension positive.
* The 6×6 tangent (Voigt 11,22,33,23,13,12) acts on the *engineering* strain increment,
  ``Δσ ≈ D · [Δε11, Δε22, Δε33, 2Δε23, 2Δε13, 2Δε12]``, as ``tensors.py`` expects. It is the
  contact-stiffness (Kruyt–Rothenburg) tangent: it ignores sliding and rearrangement, so it is
  stiffer than the RVE's actual response; Newton converges linearly with it.

Cost
----
Rollback is a ``fork`` of the host (see ``worker.py``), so a trial costs its DEM steps plus a
few ms per host. ``step_info()`` reports per load step: ``dem_time`` (YADE stepping, mean over
hosts), ``imbalance_time`` (slowest host minus mean), ``overhead_time`` (everything else inside
the material calls: fork, transfer, Python, snapshots), ``dem_cpu_time`` (CPU seconds of YADE
stepping summed over hosts: what the stepping costs on an idle machine), ``particle_steps``,
``trials``.

Heartbeat
---------
A trial with a large strain increment keeps the RVE hosts busy for minutes. While
:meth:`DemMaterialPointSet.evaluate` waits for them, it logs a line every ``heartbeat_interval``
seconds (class attribute, default :data:`HEARTBEAT_INTERVAL` = 30 s; set it on an instance to
change it, ``math.inf`` for none) with the RVEs stepped out of those to step, the DEM steps run
out of those planned and the elapsed time, and one more line when the trial is done. The hosts
publish these counts in shared memory (``executors.py``, ``worker.py``): nothing is asked of
them, and the numbers they compute are those of a run without heartbeat.

Checkpoints
-----------
``get_state()`` is small: the converged strains/stresses, the committed strain increments since
the last *snapshot*, and the snapshot file names. Every ``snapshot_interval`` committed steps
the hosts serialise their scenes and load them back (YADE scene strings; written to
``snapshot_dir`` when the run keeps checkpoints). A scene loaded from a string continues
with round-off-level differences from the live one (the collider rebuilds its lists), so this
re-load happens whether or not files are kept: the numbers of a run depend on
``snapshot_interval`` but not on whether it is checkpointed or resumed. ``set_state()`` loads
the newest snapshot (or the packings) and replays the committed increments, re-loading at the
same steps. YADE runs one thread per host, so the replay is bit-for-bit the original.
"""

from __future__ import annotations

import hashlib
import logging
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .. import integrity
from ..materials.base import MaterialPointError, MaterialPointSet
from .executors import HEARTBEAT_INTERVAL, Progress, format_progress, make_executor

STATE_FORMAT = "dem-material-state-v1"
SETTINGS_KEYS = ("strain_rate", "min_steps", "max_steps", "damping")


def packing_assignment(n_points: int, n_packings: int, seed: int) -> np.ndarray:
    """Which packing each Gauss point starts from: all the first one, or a seeded random pick."""
    if n_packings <= 1:
        return np.zeros(n_points, dtype=int)
    return np.random.default_rng(seed).integers(0, n_packings, n_points)


def assignment_seed(config: dict) -> int:
    """The seed of the packing assignment of a validated config: ``dem.assignment_seed``, or the
    config's ``seed`` where that is null."""
    seed = config["dem"].get("assignment_seed")
    return int(config["seed"] if seed is None else seed)


class DemMaterialPointSet(MaterialPointSet):
    method = "dem"
    #: load a point's scene only when it is first stepped (the hosts keep the packing's string)
    lazy_scenes = False
    #: seconds between two progress lines of a trial still running (module docstring)
    heartbeat_interval: float = HEARTBEAT_INTERVAL
    #: the first trial of this load step or its last heartbeat (time.monotonic); None before the first trial
    _last_beat: float | None = None

    def __init__(
        self,
        n_points: int,
        packings: Sequence[str | Path],
        settings: dict,
        *,
        assignment: Sequence[int] | None = None,
        executor: str = "local",
        n_workers: int = 1,
        dask_scheduler: str | None = None,
        dask_client=None,
        snapshot_dir: str | Path | None = None,
        snapshot_interval: int = 10,
        logger: logging.Logger | None = None,
    ):
        super().__init__(n_points)
        self.log = logger or logging.getLogger("granular_multiscale.dem")
        missing = [k for k in SETTINGS_KEYS if k not in settings]
        if missing:
            raise ValueError(f"DEM settings lack {missing} (config section 'dem')")
        self.settings = {k: settings[k] for k in SETTINGS_KEYS}
        self.packing_paths = [Path(p) for p in packings]
        if not self.packing_paths:
            raise ValueError("DemMaterialPointSet needs at least one packing file")
        self._packings = {}
        self.packing_sha256 = []
        for i, p in enumerate(self.packing_paths):
            try:
                data = p.read_bytes()
            except FileNotFoundError:
                raise FileNotFoundError(f"RVE packing {p} not found (run the 'rve' rule first)") from None
            sha256 = hashlib.sha256(data).hexdigest()
            if integrity.recorded(p) not in (None, sha256):  # YADE would say only "gzip error"
                integrity.verify(p, "RVE packing")
            self._packings[i] = {"name": p.name, "data": data}
            self.packing_sha256.append(sha256)
        self.assignment = (
            np.zeros(n_points, dtype=int) if assignment is None else np.asarray(assignment, dtype=int)
        )
        if self.assignment.shape != (n_points,) or self.assignment.min() < 0 or self.assignment.max() >= len(self.packing_paths):
            raise ValueError(f"packing assignment must give one of {len(self.packing_paths)} packings per Gauss point")
        self.snapshot_dir = Path(snapshot_dir) if snapshot_dir else None
        self.snapshot_interval = int(snapshot_interval)
        n_slots = max(1, min(int(n_workers), n_points))
        self.slots = self._make_slots(n_points, n_slots)
        t0 = time.perf_counter()
        self.executor = make_executor(executor, n_slots, scheduler=dask_scheduler, client=dask_client)
        try:
            self._load_packings()
            self.initial_stress = self.conv_stress.copy()
        except BaseException:
            self.executor.close()
            raise
        self.log.info(
            "DEM material: %d RVEs (%s spheres) on %d %s workers, ready in %.1f s",
            n_points, sorted(set(self.n_spheres.tolist())), n_slots, self.executor.kind, time.perf_counter() - t0,
        )
        self._reset_step_counters()
        self.totals = {k: 0.0 for k in self._step}
        self._last_step_info: dict[str, float] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_config(
        cls,
        config: dict,
        n_points: int,
        packings: Sequence[str | Path],
        n_workers: int | None = None,
        snapshot_dir: str | Path | None = None,
        logger: logging.Logger | None = None,
        dask_client=None,
        assignment: Sequence[int] | None = None,
    ) -> "DemMaterialPointSet":
        """The set of a validated config; ``assignment`` (which of ``packings`` each point starts
        from) defaults to a random pick among them with ``dem.assignment_seed``."""
        dem = config["dem"]
        workers = n_workers if n_workers is not None else dem["n_workers"]
        if assignment is None:
            assignment = packing_assignment(n_points, len(packings), assignment_seed(config))
        return cls(
            n_points,
            packings,
            {k: dem[k] for k in SETTINGS_KEYS},
            assignment=assignment,
            executor=dem["executor"],
            n_workers=workers,
            dask_scheduler=dem["dask_scheduler"] or None,
            dask_client=dask_client,
            snapshot_dir=snapshot_dir,
            snapshot_interval=dem["snapshot_interval"],
            logger=logger,
        )

    @staticmethod
    def _make_slots(n_points: int, n_slots: int) -> list[np.ndarray]:
        """The Gauss points of each host, interleaved: point i on host i mod n_slots. The busy points
        cluster in space (a shear band, the soil under a footing) and so in the element order; an
        RVE's answer does not depend on its host."""
        return [np.arange(j, n_points, n_slots) for j in range(n_slots)]

    def _slot_messages(self, cmd: str, per_point: dict[str, np.ndarray] | None = None, common: dict | None = None):
        msgs = []
        for idx in self.slots:
            args = dict(common or {})
            for key, arr in (per_point or {}).items():
                args[key] = arr[idx]
            msgs.append((cmd, args))
        return msgs

    def _adopt(self, replies: list[dict]) -> None:
        stress = np.empty((self.n_points, 6))
        tangent = np.empty((self.n_points, 6, 6))
        n_spheres = np.empty(self.n_points, dtype=int)
        for idx, r in zip(self.slots, replies):
            stress[idx], tangent[idx], n_spheres[idx] = r["stress"], r["tangent"], r["n_spheres"]
        self._check_response(stress, tangent, "DEM RVEs")
        self.conv_stress, self.conv_tangent, self.n_spheres = stress, tangent, n_spheres

    def _load_packings(self) -> None:
        msgs = []
        for idx in self.slots:
            keys = sorted(set(self.assignment[idx].tolist()))
            msgs.append(("load_packings", {
                "gps": idx.tolist(),
                "which": self.assignment[idx].tolist(),
                "packings": {k: self._packings[k] for k in keys},
                "settings": self.settings,
                "lazy": self.lazy_scenes,
            }))
        self._adopt(self.executor.call_all(msgs))
        self.conv_strain = np.zeros((self.n_points, 6))
        self.commits = 0
        self.replay: list[np.ndarray] = []
        self.base: dict | None = None
        self._trial = None

    # ------------------------------------------------------------------ accounting
    def _reset_step_counters(self) -> None:
        self._step = {
            "dem_time": 0.0, "dem_cpu_time": 0.0, "imbalance_time": 0.0, "overhead_time": 0.0, "material_time": 0.0,
            "snapshot_time": 0.0, "particle_steps": 0.0, "trials": 0.0, "dem_steps_max": 0.0,
        }

    def _account(self, wall: float, replies: list[dict] | None) -> None:
        s = self._step
        s["material_time"] += wall
        if not replies:
            s["overhead_time"] += wall
            return
        dem = np.array([r["dem_time"] for r in replies])
        s["dem_time"] += dem.mean()
        s["dem_cpu_time"] += sum(r["dem_cpu_time"] for r in replies)
        s["imbalance_time"] += dem.max() - dem.mean()
        s["overhead_time"] += wall - dem.max()
        s["particle_steps"] += sum(r["particle_steps"] for r in replies)
        s["dem_steps_max"] = max(s["dem_steps_max"], max(int(np.max(r["steps"], initial=0)) for r in replies))
        s["trials"] += 1

    # ------------------------------------------------------------------ interface
    def evaluate(self, strain: np.ndarray, need_tangent: bool = True):
        strain = self._check_strain(strain)
        if self._trial is not None and np.array_equal(strain, self._trial["strain"]):
            t = self._trial
            return t["stress"].copy(), (t["tangent"].copy() if need_tangent else None)
        dstrain = strain - self.conv_strain
        t0 = time.perf_counter()
        # the heartbeat's clock runs over the whole load step: its trials may each be shorter
        # than the interval while the step takes minutes
        if self._last_beat is None:
            self._last_beat = time.monotonic()
        replies = self.executor.call_all(self._slot_messages("trial", {"dstrain": dstrain}),
                                         heartbeat=self._heartbeat, interval=self.heartbeat_interval,
                                         first=max(0.0, self._last_beat + self.heartbeat_interval - time.monotonic()))
        wall = time.perf_counter() - t0
        self._account(wall, replies)
        stress = np.empty((self.n_points, 6))
        tangent = np.empty((self.n_points, 6, 6))
        for idx, r in zip(self.slots, replies):
            stress[idx], tangent[idx] = r["stress"], r["tangent"]
        self._check_response(stress, tangent, "DEM RVEs")
        self._trial = {"strain": strain.copy(), "dstrain": dstrain, "stress": stress, "tangent": tangent}
        return stress.copy(), (tangent.copy() if need_tangent else None)

    def _heartbeat(self, progress: Progress) -> None:
        """Log how far the running trial is (``trials`` counts the trials of this load step so far)."""
        self._last_beat = time.monotonic()
        self.log.info("%s", format_progress(progress, f"DEM trial {int(self._step['trials']) + 1} of this load step"))

    def commit(self, strain=None) -> None:
        self._trial_at(strain, None if self._trial is None else self._trial["strain"])
        t0 = time.perf_counter()
        if self._trial is not None:
            self.executor.call_all(self._slot_messages("commit"))
            t = self._trial
            self.conv_strain, self.conv_stress, self.conv_tangent = t["strain"], t["stress"], t["tangent"]
            self._last_beat = None  # the next load step's clock starts at its first trial
            self.replay.append(t["dstrain"])
            self._trial = None
        else:  # nothing evaluated since the last commit: the step changed nothing
            self.replay.append(np.zeros((self.n_points, 6)))
        self._close_commit(t0)

    def _close_commit(self, t0: float) -> None:
        """The end of every commit: count it, snapshot when due, close the step's accounting."""
        self.commits += 1
        self._account(time.perf_counter() - t0, None)
        if self._snapshot_due(self.commits):
            self._snapshot()
        self._last_step_info = dict(self._step)
        for k, v in self._step.items():
            self.totals[k] = max(self.totals[k], v) if k == "dem_steps_max" else self.totals[k] + v
        self._reset_step_counters()

    def rollback(self) -> None:
        """Drop a pending trial (the hosts go back to the converged state)."""
        self.executor.call_all(self._slot_messages("rollback"))
        self._trial = None

    def _snapshot_due(self, step: int) -> bool:
        return self.snapshot_interval > 0 and step % self.snapshot_interval == 0

    def _snapshot(self, write: bool = True) -> None:
        """Serialise and re-load every scene; with a snapshot_dir (and ``write``) keep the files
        as the new base of the checkpoint state."""
        t0 = time.perf_counter()
        files = [None] * len(self.slots)
        if write and self.snapshot_dir is not None:
            self.snapshot_dir.mkdir(parents=True, exist_ok=True)
            files = [str(self.snapshot_dir / f"commit{self.commits:05d}_slot{j}.pkl") for j in range(len(self.slots))]
        self.executor.call_all([("snapshot", {"path": f}) for f in files])
        if files[0] is not None:
            for f in files:  # before the checkpoint that refers to them is written
                integrity.record(f)
            old = self.base
            self.base = {"step": self.commits, "files": files}
            self.replay = []
            # keep the previous set too: the checkpoint on disk may still point to it
            if old is not None:
                for f in sorted(self.snapshot_dir.glob("commit*_slot*.pkl")):
                    if int(f.name[6:11]) < old["step"]:
                        integrity.forget(f)
        wall = time.perf_counter() - t0
        self._step["snapshot_time"] += wall
        self._step["overhead_time"] += wall
        self._step["material_time"] += wall

    def checkpoint_key(self) -> dict:
        """A checkpoint resumes only with the same packings (by content), assignment and DEM settings."""
        return {
            "packing_sha256": list(self.packing_sha256),
            "assignment": self.assignment.tolist(),
            "settings": dict(self.settings),
            "snapshot_interval": self.snapshot_interval,
        }

    def _identity(self) -> dict[str, Any]:
        """What a saved state must share with this set to be restored (see :meth:`_check_state`)."""
        return {
            "n_points": self.n_points,
            "packing_sha256": list(self.packing_sha256),
            "assignment": self.assignment.copy(),
            "settings": dict(self.settings),
            "snapshot_interval": self.snapshot_interval,
        }

    def _check_state(self, state: dict[str, Any], fmt: str) -> None:
        """Refuse (ValueError) a state of another format, point count, packings or DEM settings."""
        if not isinstance(state, dict) or state.get("format") != fmt:
            raise ValueError(f"not a {fmt} state (format {state.get('format') if isinstance(state, dict) else type(state)})")
        if state["n_points"] != self.n_points:
            raise ValueError(f"checkpoint has {state['n_points']} Gauss points, this run {self.n_points}")
        for i, (old, new) in enumerate(zip(state["packing_sha256"], self.packing_sha256)):
            if old != new:
                raise ValueError(f"RVE packing {self.packing_paths[i]} changed since the checkpoint was written")
        if len(state["packing_sha256"]) != len(self.packing_sha256) or not np.array_equal(state["assignment"], self.assignment):
            raise ValueError("the checkpoint uses a different set of packings (dem.n_packings or seed changed)")
        if state["settings"] != self.settings:
            raise ValueError(f"DEM settings changed since the checkpoint: {state['settings']} -> {self.settings}")

    def get_state(self) -> dict[str, Any]:
        if self._trial is not None:
            self.log.debug("get_state with a pending trial: the converged state is saved")
        return {
            **self._identity(),
            "format": STATE_FORMAT,
            "commits": self.commits,
            "base": None if self.base is None else {"step": self.base["step"], "files": list(self.base["files"])},
            "replay": np.array(self.replay).reshape(len(self.replay), self.n_points, 6),
            "converged_strain": self.conv_strain.copy(),
            "converged_stress": self.conv_stress.copy(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        self._check_state(state, STATE_FORMAT)
        t0 = time.perf_counter()
        self.executor.call_all(self._slot_messages("rollback"))
        self._trial = None
        base = state["base"]
        if base is None:
            self._load_packings()
        else:
            missing = [f for f in base["files"] if not Path(f).exists()]
            if missing:
                raise FileNotFoundError(f"checkpoint snapshot files missing: {missing}")
            for f in base["files"]:  # a truncated snapshot would fail inside the RVE hosts, unnamed
                integrity.verify(f, "RVE snapshot")
            msgs = [("load_snapshot", {"gps": idx.tolist(), "files": base["files"], "settings": self.settings}) for idx in self.slots]
            self._adopt(self.executor.call_all(msgs))
        replay = np.asarray(state["replay"]).reshape(-1, self.n_points, 6)
        self.snapshot_interval = int(state["snapshot_interval"])
        first = 0 if base is None else base["step"]
        for k, dstrain in enumerate(replay):
            replies = self.executor.call_all(self._slot_messages("replay", {"dstrain": dstrain}))
            for idx, r in zip(self.slots, replies):
                self.conv_stress[idx], self.conv_tangent[idx] = r["stress"], r["tangent"]
            if self._snapshot_due(first + k + 1):
                self._snapshot(write=False)  # the original run re-loaded here too
        self._reset_step_counters()
        self.commits = int(state["commits"])
        self.base = None if base is None else {"step": base["step"], "files": list(base["files"])}
        self.replay = [d for d in replay]
        self.conv_strain = np.asarray(state["converged_strain"], dtype=float).copy()
        diff = np.abs(self.conv_stress - np.asarray(state["converged_stress"])).max()
        if diff != 0.0:
            self.log.warning("DEM resume: replayed stresses differ from the checkpoint by up to %.3g Pa", diff)
        self.log.info(
            "DEM material resumed after %d commits (%s + %d replayed commits) in %.1f s",
            self.commits, "packings" if base is None else f"snapshot after commit {base['step']}", len(replay),
            time.perf_counter() - t0,
        )

    def step_info(self) -> dict[str, float]:
        return dict(self._last_step_info)

    def time_split(self) -> dict[str, float]:
        """Totals over all committed steps (same keys as ``step_info``)."""
        return dict(self.totals)

    def resident_scenes(self) -> int:
        """How many RVE scenes the hosts hold loaded (all of them, unless ``lazy_scenes``)."""
        if self._trial is not None:
            raise MaterialPointError("resident_scenes needs the converged state: commit or rollback first")
        return sum(r["loaded"] for r in self.executor.call_all([("resident", {})] * len(self.slots)))

    def scene_strings(self) -> dict[int, bytes]:
        """Converged YADE scene string of every Gauss point (diagnostics; costs a serialisation)."""
        pending = self._trial is not None
        if pending:
            raise MaterialPointError("scene_strings needs the converged state: commit or rollback first")
        out = {}
        for r in self.executor.call_all([("scene_strings", {})] * len(self.slots)):
            out.update(r)
        return out

    def close(self) -> None:
        ex, self.executor = getattr(self, "executor", None), None
        if ex is not None:
            ex.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
