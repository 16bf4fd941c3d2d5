"""Uniform-field FEM–DEM of one RVE: the reference the RVE-procedure study compares the direct
tests (``studies.direct_triaxial``) with. Every Gauss point holds the same RVE, so the run is one
RVE driven by the FEM solver's Newton iterations."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from ..dem.material import SETTINGS_KEYS, DemMaterialPointSet
from ..drivers.fem_dem import dem_newton_config
from ..fem.triaxial import TriaxialProblem
from ..paths import load_paths_from_config


def run_fem_dem_uniform(packing: str | Path, config: dict, snapshot_interval: int | None = None,
                        logger=None) -> dict:
    """Uniform-field FEM–DEM of one RVE (as :func:`run_fem_dem` with specimen.uniform_field):
    returns per step the one point's converged strain and stress, q, εv, axial strain, Newton
    iterations and material evaluations, the committed strain increments (``dstrain``, what a
    replay needs to be exact) and the wall time."""
    logger = logger or logging.getLogger("granular_multiscale.studies.uniform_fem_dem")
    cfg = dem_newton_config(config)
    problem = TriaxialProblem.from_config(cfg)
    path = load_paths_from_config(cfg)["mono"]
    interval = cfg["dem"]["snapshot_interval"] if snapshot_interval is None else int(snapshot_interval)
    t0 = time.perf_counter()
    with DemMaterialPointSet(problem.n_material_points, [packing], {k: cfg["dem"][k] for k in SETTINGS_KEYS},
                             n_workers=1, snapshot_interval=interval, logger=logger) as material:
        ds = problem.run(material, path, method="dem", logger=logger, progress=False)
        dstrain = np.array(material.replay).reshape(-1, 6)
    stress = ds["stress"].values.mean(axis=1)  # uniform: every Gauss point holds the one RVE's stress
    strain = ds["strain"].values.mean(axis=1)
    return {
        "axial_strain": ds["axial_strain"].values.tolist(),
        "volumetric_strain": ds["volumetric_strain"].values.tolist(),
        "q": (0.5 * (stress[:, 0] + stress[:, 1]) - stress[:, 2]).tolist(),
        "stress": stress.tolist(),
        "strain": strain.tolist(),
        "dstrain": dstrain.tolist(),
        "newton_iterations": ds["newton_iterations"].values.tolist(),
        "material_evaluations": ds["material_evaluations"].values.tolist(),
        "cutbacks": ds["cutbacks"].values.tolist(),
        "wall_time": time.perf_counter() - t0,
        "snapshot_interval": interval,
        "settings": {k: cfg["dem"][k] for k in SETTINGS_KEYS},
        "tolerance": cfg["newton"]["tolerance"],
    }
