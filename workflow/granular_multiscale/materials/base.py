"""The one interface between the FEM solver and whatever sits at its Gauss points.

A material-point set holds ``n_points`` material points, each with a *converged* state
(that of the last committed load step). The solver's Newton loop calls

    stress, tangent = points.evaluate(strain)     # trial, any number of times per step
    points.commit(strain)                          # the state at the accepted strain becomes converged

``evaluate`` is a pure function of the converged state and the trial strain: calling it
twice with the same strain gives the same answer, and a rejected step (cutback) simply
evaluates again from the same converged state. ``get_state``/``set_state`` serialise the
converged state for checkpoints.

Conventions (see ``tensors``): strain [n, 6] total small strain with tensorial shear,
stress [n, 6] in Pa, tension positive, tangent [n, 6, 6] Voigt stiffness acting on the
engineering strain. At zero strain and fresh state the stress is the initial stress of the
specimen (isotropic −p0 for the consolidated triaxial specimen).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np


class MaterialPointError(RuntimeError):
    """A material point failed (non-finite response, dead worker, ...); names the Gauss points."""


class MaterialPointSet(ABC):
    #: short name written to the output files' ``method`` attribute
    method: str = "material"

    def __init__(self, n_points: int):
        if n_points < 1:
            raise ValueError(f"a material-point set needs at least one point, got {n_points}")
        self.n_points = int(n_points)

    @abstractmethod
    def evaluate(self, strain: np.ndarray, need_tangent: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Trial response at total strain [n, 6]: stress [n, 6] and tangent [n, 6, 6] (or None)."""

    @abstractmethod
    def commit(self, strain: np.ndarray | None = None) -> None:
        """Accept the state at trial strain `strain` [n, 6] as the converged state of every point.

        The solver passes the strain it accepted, which need not be the last one evaluated (a
        line search may keep an earlier step length): a set whose last evaluation was at another
        strain evaluates there again first (:meth:`_trial_at`). None: the last evaluated trial."""

    @abstractmethod
    def get_state(self) -> dict[str, Any]:
        """Converged state, picklable, for checkpoints."""

    @abstractmethod
    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a converged state returned by :meth:`get_state`."""

    def checkpoint_key(self) -> dict:
        """What the converged state depends on beyond the points' strains (JSON-serialisable; e.g.
        DEM packings and settings). A checkpoint written under another key is not resumed."""
        return {}

    def _trial_at(self, strain: np.ndarray | None, last_strain: np.ndarray | None, need_tangent: bool = False) -> None:
        """Make the pending trial the one at `strain`: evaluate again unless `last_strain` (the
        strain of the last evaluation, None if none) is exactly it. Called by ``commit``."""
        if strain is None:
            return
        strain = np.asarray(strain, dtype=float)
        if last_strain is None or not np.array_equal(strain, last_strain):
            self.evaluate(strain, need_tangent=need_tangent)

    def step_info(self) -> dict[str, float]:
        """Per-step diagnostics the solver records after each commit (e.g. DEM time split)."""
        return {}

    def close(self) -> None:
        """Release workers or files; the set is unusable afterwards."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _check_strain(self, strain: np.ndarray) -> np.ndarray:
        strain = np.asarray(strain, dtype=float)
        if strain.shape != (self.n_points, 6):
            raise ValueError(f"{type(self).__name__}: strain must be [{self.n_points}, 6], got {strain.shape}")
        bad = np.flatnonzero(~np.isfinite(strain).all(axis=1))
        if bad.size:
            raise MaterialPointError(f"non-finite trial strain at Gauss points {bad[:10].tolist()}")
        return strain

    @staticmethod
    def _check_response(stress: np.ndarray, tangent: np.ndarray | None, who: str) -> None:
        bad = ~np.isfinite(stress).all(axis=1)
        if tangent is not None:
            bad |= ~np.isfinite(tangent).all(axis=(1, 2))
        idx = np.flatnonzero(bad)
        if idx.size:
            raise MaterialPointError(f"{who}: non-finite stress or tangent at Gauss points {idx[:10].tolist()}")
