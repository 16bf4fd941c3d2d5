"""The triaxial test with the analytic elastoplastic model at every Gauss point (the fast
reference that stands in for FEM–DEM in tests and in ``config/elastoplastic.yaml``)."""

from __future__ import annotations

import logging

import xarray as xr

from ..data import write_run
from ..fem.triaxial import TriaxialProblem
from ..materials import make_material
from ..paths import load_paths_from_config


def run_fem_reference(config: dict, path_name: str, output: str, logger: logging.Logger | None = None) -> xr.Dataset:
    """One elastoplastic reference run of a load path (validated config), written in the data contract."""
    logger = logger or logging.getLogger("granular_multiscale.drivers.reference")
    problem = TriaxialProblem.from_config(config)
    load_path = load_paths_from_config(config)[path_name]
    logger.info(
        "mesh %s elements (%d Gauss points), %s platens, p0 = %.0f Pa, path %s with %d steps",
        "x".join(map(str, problem.elements)), problem.n_gauss_points, problem.platen,
        problem.confining_pressure, path_name, load_path.n_steps,
    )
    with make_material("elastoplastic", problem.n_material_points, config) as material:
        ds = problem.run(material, load_path, logger=logger)
    write_run(ds, output, config)
    logger.info("wrote %s", output)
    return ds
