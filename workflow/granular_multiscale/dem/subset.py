"""YADE RVEs at every Gauss point, of which only an *active* subset follows the strain.

    dem = DemSubsetMaterialPointSet.from_config(config, n_points, packings, n_workers=2)
    dem.evaluate(strain)     # trials for the active points only; the others stay consolidated
    dem.commit(strain)       # commits the active RVEs and records EVERY point's converged strain
    dem.activate(points)     # replay: bring inactive RVEs to the last converged state

What the adaptive FEM–DEM–ML set (``adaptive/``) runs its DEM points on. Every point has an RVE
from its packing, as in FEM–DEM (:class:`DemMaterialPointSet`, whose hosts, executors, accounting
and settings this class shares), but a host loads a point's scene only when the point is first
stepped (``lazy_scenes``: until then it answers with its packing's response, computed once per
packing), so memory and start-up are those of the DEM points, not of the mesh (2000 scenes of
1000 spheres at the paper mesh). Only the active points are driven:
a trial sends their strain increments from their converged state and a zero increment (no DEM
step) for the others, and a host without an active point is not called at all. The hosts hold
the points interleaved (point i on host i mod n_hosts), so that a spatial cluster of active
points is shared out among them.

Replay (:meth:`activate`)
-------------------------
The set records the converged strain ε_k of every point at every commit k, active or not. To
activate points after c commits, each of them replays its history: for k = 1..c the increment
ε_k − ε_{k−1} is imposed and accepted in the holder process (the hosts' ``replay`` command,
batched over all points activated together, a zero increment for the rest), and after every k
that is a multiple of ``snapshot_interval`` their scenes are serialised and re-loaded (``reload``),
as FEM–DEM re-loads every scene after such a commit. A scene's state is a function of its own
increments and of that schedule alone (YADE runs one thread, and a trial computed in a forked
child is bit for bit the replay in the holder), so an activated RVE is bit for bit the RVE that
followed the same converged strains from step 0, in this set or in a FEM–DEM run with the same
``snapshot_interval``. Scenes that are not active are never re-loaded: they stay the packing's.

The replay costs one DEM increment per past commit and point, accounted separately from the
trials (``replay_particle_steps``, ``replay_dem_time``, ``replay_time`` in :meth:`step_info`,
``activated``: points activated since the last commit).

What the RVEs answered (:meth:`dem_responses`)
----------------------------------------------
Besides the strains, the set keeps every converged DEM answer: per commit and point the RVE's
stress and tangent where the point was active at that commit, from the replay of its past
commits when it was activated (the answers a promoted point's RVE gives along its whole history)
and from the trials the solver accepted since. Where an RVE was not at a commit's converged
state (a point never activated, or one activated later that has not replayed it yet) the entry
is NaN. These are DEM trajectories like those of the RVE-path sets: what the active-learning
round of the adaptive runs trains on (``drivers/adaptive.py``).

Checkpoints
-----------
No snapshot files: the state is the strain record, the active mask and the commit count (at the
paper scale 60 commits × 2000 points × 6 strains, 6 MB). :meth:`set_state` re-loads the packings
and activates the active points again — a replay of all their committed increments, one DEM
increment per commit instead of the Newton trials that found them — and ends, by the argument
above, bit for bit in the state of the uninterrupted run.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .material import DemMaterialPointSet

SUBSET_STATE_FORMAT = "dem-subset-state-v1"


class DemSubsetMaterialPointSet(DemMaterialPointSet):
    method = "dem_subset"
    lazy_scenes = True

    def __init__(self, n_points: int, packings, settings: dict, **kwargs):
        if kwargs.get("snapshot_dir") is not None:
            raise ValueError("a DEM subset keeps no snapshot files (it resumes by replay): pass snapshot_dir=None")
        super().__init__(n_points, packings, settings, **kwargs)
        self.active = np.zeros(self.n_points, dtype=bool)
        self.strain_record: list[np.ndarray] = [np.zeros((self.n_points, 6))]  # [0]: before the first commit
        self._start_response_record(0)

    def _start_response_record(self, commits: int) -> None:
        """The DEM answers known after a (re)load of the packings: the consolidated state at commit 0
        for every point, NaN at the `commits` commits after it (filled by replays and commits)."""
        self.stress_record = [self.conv_stress.copy()] + [np.full((self.n_points, 6), np.nan) for _ in range(commits)]
        self.tangent_record = [self.conv_tangent.copy()] + [np.full((self.n_points, 6, 6), np.nan)
                                                             for _ in range(commits)]

    def dem_responses(self) -> dict[str, np.ndarray]:
        """The converged DEM answers so far (module docstring): ``strain`` [commits + 1, n, 6] (every
        point's converged strain), ``stress`` [.., n, 6] and ``tangent`` [.., n, 6, 6] (NaN where the
        point's RVE was not at that state) and ``known`` [.., n] where they are not NaN."""
        stress = np.asarray(self.stress_record)
        return {"strain": np.asarray(self.strain_record), "stress": stress, "tangent": np.asarray(self.tangent_record),
                "known": np.isfinite(stress).all(axis=-1)}

    def _reset_step_counters(self) -> None:
        super()._reset_step_counters()
        self._step.update({"replay_particle_steps": 0.0, "replay_dem_time": 0.0, "replay_time": 0.0,
                           "activated": 0.0})

    def _hosts(self, mask: np.ndarray) -> list[bool]:
        """Per host: does it hold a point of `mask`?"""
        return [bool(mask[idx].any()) for idx in self.slots]

    def _call(self, hosts: list[bool], cmd: str, per_point: dict[str, np.ndarray] | None = None,
              per_host: list[dict] | None = None) -> list:
        """Send `cmd` to the hosts marked in `hosts` (the others get nothing and answer None)."""
        msgs = []
        for j, (idx, wanted) in enumerate(zip(self.slots, hosts)):
            args = dict(per_host[j]) if per_host else {}
            args.update({key: arr[idx] for key, arr in (per_point or {}).items()})
            msgs.append((cmd, args) if wanted else None)
        return self.executor.call_all(msgs) if any(hosts) else [None] * len(self.slots)

    # ------------------------------------------------------------------ interface
    def evaluate(self, strain: np.ndarray, need_tangent: bool = True):
        strain = self._check_strain(strain)
        t = self._trial
        if t is not None and np.array_equal(strain, t["strain"]):
            return t["stress"].copy(), (t["tangent"].copy() if need_tangent else None)
        dstrain = np.where(self.active[:, None], strain - self.conv_strain, 0.0)
        stress, tangent = self.conv_stress.copy(), self.conv_tangent.copy()
        hosts = self._hosts(self.active)
        if any(hosts):
            t0 = time.perf_counter()
            replies = self._call(hosts, "trial", {"dstrain": dstrain})
            self._account(time.perf_counter() - t0, [r for r in replies if r is not None])
            for idx, r in zip(self.slots, replies):
                if r is not None:
                    stress[idx], tangent[idx] = r["stress"], r["tangent"]
            self._check_response(stress, tangent, "DEM RVEs")
        self._trial = {"strain": strain.copy(), "dstrain": dstrain, "stress": stress, "tangent": tangent,
                       "hosts": hosts}
        return stress.copy(), (tangent.copy() if need_tangent else None)

    def commit(self, strain=None) -> None:
        if strain is None:
            if self._trial is None:
                raise RuntimeError(f"{type(self).__name__}.commit() needs the accepted strain or an evaluation")
            strain = self._trial["strain"]
        strain = self._check_strain(strain)
        self._trial_at(strain, None if self._trial is None else self._trial["strain"])
        t0 = time.perf_counter()
        t, self._trial = self._trial, None
        self._call(t["hosts"], "commit")
        self.conv_strain = np.where(self.active[:, None], t["strain"], self.conv_strain)
        self.conv_stress, self.conv_tangent = t["stress"], t["tangent"]
        self.strain_record.append(strain.copy())
        self.stress_record.append(np.where(self.active[:, None], self.conv_stress, np.nan))
        self.tangent_record.append(np.where(self.active[:, None, None], self.conv_tangent, np.nan))
        self._close_commit(t0)

    def rollback(self) -> None:
        self._call(self._hosts(self.active), "rollback")
        self._trial = None

    def activate(self, points) -> int:
        """Make `points` active (those already active are left alone): replay their converged strain
        history from the packing up to the last commit (module docstring). Drops a pending trial.
        Returns how many points were activated."""
        new = np.zeros(self.n_points, dtype=bool)
        new[np.asarray(points, dtype=int)] = True
        new &= ~self.active
        if not new.any():
            return 0
        t0 = time.perf_counter()
        if self._trial is not None:
            self.rollback()
        record = np.asarray(self.strain_record)
        hosts = self._hosts(new)
        particle_steps = dem_time = 0.0
        for k in range(1, len(record)):
            dstrain = np.where(new[:, None], record[k] - record[k - 1], 0.0)
            replies = self._call(hosts, "replay", {"dstrain": dstrain})
            for idx, r in zip(self.slots, replies):
                if r is not None:
                    mine = new[idx]
                    self.conv_stress[idx[mine]] = r["stress"][mine]
                    self.conv_tangent[idx[mine]] = r["tangent"][mine]
                    self.stress_record[k][idx[mine]] = r["stress"][mine]
                    self.tangent_record[k][idx[mine]] = r["tangent"][mine]
                    particle_steps += r["particle_steps"]
                    dem_time += r["dem_time"]
            if self._snapshot_due(k):
                self._reload(new)
        self._check_response(self.conv_stress, self.conv_tangent, "DEM RVEs (replay)")
        self.active |= new
        self.conv_strain[new] = record[-1][new]
        s = self._step
        s["replay_particle_steps"] += particle_steps
        s["replay_dem_time"] += dem_time
        s["replay_time"] += time.perf_counter() - t0
        s["activated"] += float(new.sum())
        return int(new.sum())

    def _reload(self, mask: np.ndarray) -> None:
        """Serialise and re-load the scenes of the points in `mask` (only)."""
        self._call(self._hosts(mask), "reload", per_host=[{"gps": idx[mask[idx]].tolist()} for idx in self.slots])

    def _snapshot(self, write: bool = True) -> None:
        """After every snapshot_interval-th commit: re-load the active scenes, as FEM–DEM re-loads all."""
        t0 = time.perf_counter()
        self._reload(self.active)
        wall = time.perf_counter() - t0
        for key in ("snapshot_time", "overhead_time", "material_time"):
            self._step[key] += wall

    # ------------------------------------------------------------------ checkpoints
    def get_state(self) -> dict[str, Any]:
        return {
            **self._identity(),
            "format": SUBSET_STATE_FORMAT,
            "commits": self.commits,
            "active": self.active.copy(),
            "strain_record": np.asarray(self.strain_record),
            "converged_stress": self.conv_stress.copy(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        self._check_state(state, SUBSET_STATE_FORMAT)
        record = np.asarray(state["strain_record"], dtype=float)
        if record.shape != (int(state["commits"]) + 1, self.n_points, 6):
            raise ValueError(f"DEM subset state of {state['commits']} commits holds a strain record of shape "
                             f"{record.shape}")
        t0 = time.perf_counter()
        self.rollback()
        self._load_packings()
        self.active = np.zeros(self.n_points, dtype=bool)
        self.strain_record = list(record)
        self.commits = int(state["commits"])
        self._start_response_record(self.commits)  # the replay below fills in what the active RVEs answered
        self.activate(np.flatnonzero(state["active"]))
        self._reset_step_counters()
        diff = np.abs(self.conv_stress - np.asarray(state["converged_stress"]))[self.active]
        if diff.size and diff.max() != 0.0:
            self.log.warning("DEM subset resume: replayed stresses differ from the checkpoint by up to %.3g Pa",
                             diff.max())
        self.log.info("DEM subset resumed after %d commits: %d active RVEs replayed in %.1f s", self.commits,
                      int(self.active.sum()), time.perf_counter() - t0)
