"""Strain-driven material-point runs without the FEM solver, in the run-file contract.

Each point follows a prescribed strain history (a triaxial-like path with a per-point
lateral ratio and small shears), and a material-point set answers stress and tangent.
Tests, benchmarks and examples use it to make a history-dependent dataset in a fraction of
a second, from a material whose truth is known (the elastoplastic model).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..history import HIST, history_from_sequence
from ..materials.base import MaterialPointSet
from ..paths import LoadPath
from ..tensors import COMP, TCOMP, tangent_to_upper


def triaxial_strain_paths(load_path: LoadPath, n_points: int, seed: int = 0,
                          lateral_ratio=(0.3, 0.45), shear: float = 0.05) -> np.ndarray:
    """[steps+1, n_points, 6] tensorial strains: ε33 = −axial strain (compression positive
    axial strain), ε11 = ε22 = r·axial with r drawn per point in `lateral_ratio`, and shears
    a fraction (drawn per point in ±`shear`) of the axial strain."""
    rng = np.random.default_rng(seed)
    axial = load_path.axial_strain()[:, None]
    ratio = rng.uniform(*lateral_ratio, size=(1, n_points))
    shears = rng.uniform(-shear, shear, size=(1, n_points, 3))
    strain = np.zeros((axial.shape[0], n_points, 6))
    strain[..., 0] = ratio * axial * rng.uniform(0.9, 1.1, size=(1, n_points))
    strain[..., 1] = ratio * axial
    strain[..., 2] = -axial
    strain[..., 3:] = shears * axial[..., None]
    return strain


def material_point_run(material: MaterialPointSet, strain: np.ndarray, load_path: LoadPath | None = None) -> xr.Dataset:
    """Drive `material` through strain[steps+1, n, 6] (step 0 = fresh state) and record the response."""
    n_steps = strain.shape[0]
    stress = np.empty_like(strain)
    tangent = np.empty(strain.shape[:2] + (21,))
    for k in range(n_steps):
        s, D = material.evaluate(strain[k])
        material.commit()
        stress[k], tangent[k] = s, tangent_to_upper(D)
    ds = xr.Dataset(
        {
            "strain": (("step", "gp", "comp"), strain, {"units": "1"}),
            "stress": (("step", "gp", "comp"), stress, {"units": "Pa"}),
            "tangent": (("step", "gp", "tcomp"), tangent, {"units": "Pa"}),
            "history": (("step", "gp", "hist"), history_from_sequence(strain), {"units": "1"}),
            "gp_position": (("gp", "xyz"), np.zeros((strain.shape[1], 3)), {"units": "m"}),
        },
        coords={"step": np.arange(n_steps), "gp": np.arange(strain.shape[1]), "comp": list(COMP),
                "tcomp": list(TCOMP), "hist": list(HIST), "xyz": ["x", "y", "z"]},
        attrs={"method": getattr(material, "method", "material"), "title": "strain-driven material-point run"},
    )
    if load_path is not None:
        ds["axial_strain"] = ("step", load_path.axial_strain())
        ds["phase"] = ("step", load_path.phase())
    return ds
