"""Isotropic linear elastic material-point set (solver tests, closed-form checks).

    σ = σ0 + D (ε)         D = isotropic Voigt stiffness on the engineering strain

σ0 is the initial stress (the consolidated specimen passes −p0·I), so at zero strain the
points are in the initial state. The model has no history: commit only remembers the
last trial for symmetry with the other sets.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..tensors import engineering, isotropic_elastic_tangent
from .base import MaterialPointSet


def initial_stress_array(initial_stress, n_points: int) -> np.ndarray:
    """None, [6] or [n, 6] -> [n, 6] (zero by default)."""
    if initial_stress is None:
        return np.zeros((n_points, 6))
    sigma0 = np.asarray(initial_stress, dtype=float)
    if sigma0.shape == (6,):
        return np.broadcast_to(sigma0, (n_points, 6)).copy()
    if sigma0.shape == (n_points, 6):
        return sigma0.copy()
    raise ValueError(f"initial_stress must be [6] or [{n_points}, 6], got shape {sigma0.shape}")


class LinearElastic(MaterialPointSet):
    method = "linear_elastic"

    def __init__(self, n_points: int, youngs_modulus: float, poisson_ratio: float, initial_stress=None):
        super().__init__(n_points)
        if not youngs_modulus > 0:
            raise ValueError(f"linear_elastic.youngs_modulus must be > 0, got {youngs_modulus}")
        if not 0 <= poisson_ratio < 0.5:
            raise ValueError(f"linear_elastic.poisson_ratio must be in [0, 0.5), got {poisson_ratio}")
        self.youngs_modulus = float(youngs_modulus)
        self.poisson_ratio = float(poisson_ratio)
        self.stiffness = isotropic_elastic_tangent(youngs_modulus, poisson_ratio)
        self.initial_stress = initial_stress_array(initial_stress, self.n_points)
        self._converged_strain = np.zeros((self.n_points, 6))
        self._trial_strain = self._converged_strain.copy()

    @classmethod
    def from_config(cls, n_points: int, config: dict, initial_stress=None) -> "LinearElastic":
        section = config["linear_elastic"]
        return cls(n_points, section["youngs_modulus"], section["poisson_ratio"], initial_stress=initial_stress)

    def evaluate(self, strain, need_tangent: bool = True):
        strain = self._check_strain(strain)
        self._trial_strain = strain.copy()
        stress = self.initial_stress + engineering(strain) @ self.stiffness.T
        tangent = np.broadcast_to(self.stiffness, (self.n_points, 6, 6)).copy() if need_tangent else None
        return stress, tangent

    def commit(self, strain=None) -> None:
        self._trial_at(strain, self._trial_strain)
        self._converged_strain = self._trial_strain.copy()

    def get_state(self) -> dict[str, Any]:
        return {"strain": self._converged_strain.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        self._converged_strain = np.array(state["strain"], dtype=float)
        self._trial_strain = self._converged_strain.copy()
