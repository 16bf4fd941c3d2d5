"""Load paths: axial-strain schedules of the triaxial test, as data.

A path is a list of segments ``[steps, target]``: the axial strain goes linearly from
where the previous segment ended to ``target`` in ``steps`` equal increments. Axial
strain is *compression positive* (the strain tensor itself is tension positive, so
ε33 = −axial strain on a uniform specimen). Step 0 is the consolidated initial state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class LoadPathError(ValueError):
    """A load path in the config is malformed; the message names the config key."""


@dataclass(frozen=True)
class LoadPath:
    name: str
    segments: tuple[tuple[int, float], ...]

    @classmethod
    def from_config(cls, name: str, entry: dict) -> "LoadPath":
        key = f"load_paths.{name}.segments"
        segments = entry.get("segments") if isinstance(entry, dict) else None
        if not segments:
            raise LoadPathError(f"config key '{key}': a path needs at least one segment [steps, target]")
        parsed = []
        for k, seg in enumerate(segments):
            if not (isinstance(seg, (list, tuple)) and len(seg) == 2):
                raise LoadPathError(f"config key '{key}[{k}]': expected [steps, target], got {seg!r}")
            steps, target = seg
            if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
                raise LoadPathError(f"config key '{key}[{k}]': steps must be a positive integer, got {steps!r}")
            if not isinstance(target, (int, float)) or not np.isfinite(target):
                raise LoadPathError(f"config key '{key}[{k}]': target must be a finite number, got {target!r}")
            parsed.append((int(steps), float(target)))
        return cls(name, tuple(parsed))

    @property
    def n_steps(self) -> int:
        return sum(s for s, _ in self.segments)

    def axial_strain(self) -> np.ndarray:
        """Axial strain at steps 0..n_steps (compression positive), step 0 = 0."""
        values = [0.0]
        for steps, target in self.segments:
            start = values[-1]
            values.extend(start + (target - start) * np.arange(1, steps + 1) / steps)
        return np.asarray(values)

    def increments(self) -> np.ndarray:
        """Axial strain increment of steps 1..n_steps."""
        return np.diff(self.axial_strain())

    def phase(self) -> np.ndarray:
        """Label per step 0..n_steps: 'initial', 'loading', 'unloading' or 'reloading'.

        Reloading is loading that comes after an unloading."""
        labels = ["initial"]
        unloaded = False
        for d in self.increments():
            if d < 0:
                unloaded = True
                labels.append("unloading")
            else:
                labels.append("reloading" if unloaded else "loading")
        return np.asarray(labels)

    def phase_cycle(self) -> np.ndarray:
        """Like :meth:`phase`, with the unload–reload cycle numbered: 'initial', 'loading',
        'unloading 1', 'reloading 1', 'unloading 2', ... (see :func:`number_cycles`)."""
        return number_cycles(self.phase())

    def reversal_steps(self) -> list[int]:
        """Steps at which the loading direction changes (first step of the new direction)."""
        sign = np.sign(self.increments())
        return [k + 1 for k in range(1, len(sign)) if sign[k] != sign[k - 1] and sign[k] != 0]


def number_cycles(phases) -> np.ndarray:
    """Per-step phase labels of :meth:`LoadPath.phase` (or a run file's ``phase`` variable) with
    the unload–reload cycle numbered: the k-th run of 'unloading' steps becomes 'unloading k',
    and the 'reloading' steps after it 'reloading k'; 'initial' and 'loading' stay as they are."""
    labels, cycle, previous = [], 0, None
    for phase in map(str, phases):
        if phase not in ("initial", "loading", "unloading", "reloading"):
            raise ValueError(f"unknown load phase {phase!r} (expected initial, loading, unloading or reloading)")
        if phase == "unloading" and previous != "unloading":
            cycle += 1
        labels.append(f"{phase} {cycle}" if phase in ("unloading", "reloading") else phase)
        previous = phase
    return np.asarray(labels)


def load_paths_from_config(config: dict, problem: str = "triaxial") -> dict[str, LoadPath]:
    """The load paths of a problem: the triaxial specimen's ``load_paths``, or those of the
    problem's section (``biaxial.load_paths``, ``footing.load_paths``)."""
    if problem == "triaxial":
        entries, key = config["load_paths"], "load_paths"
    else:
        entries, key = config[problem]["load_paths"], f"{problem}.load_paths"
    paths = {}
    for name, entry in entries.items():
        try:
            paths[name] = LoadPath.from_config(name, entry)
        except LoadPathError as error:
            raise LoadPathError(str(error).replace("'load_paths.", f"'{key}.", 1)) from None
    return paths
