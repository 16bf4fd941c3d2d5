"""Any problem with the analytic elastoplastic model at every Gauss point (the fast reference
that stands in for FEM–DEM in tests and in ``config/elastoplastic.yaml``)."""

from __future__ import annotations

import logging

import xarray as xr

from ..data import write_run
from .problems import analytic_material, problem_and_path


def run_fem_reference(config: dict, path_name: str, output: str, logger: logging.Logger | None = None,
                      problem: str = "triaxial") -> xr.Dataset:
    """One elastoplastic reference run of a load path of `problem` (validated config), written in the data contract."""
    logger = logger or logging.getLogger("granular_multiscale.drivers.reference")
    bvp, load_path = problem_and_path(config, problem, path_name)
    logger.info(
        "%s: mesh %s elements (%d Gauss points, %s), p0 = %.0f Pa, path %s with %d steps",
        problem, "x".join(map(str, bvp.mesh_elements)), bvp.n_gauss_points, bvp.ops.element,
        bvp.confining_pressure, path_name, load_path.n_steps,
    )
    with analytic_material("elastoplastic", bvp, config) as material:
        ds = bvp.run(material, load_path, logger=logger)
    write_run(ds, output, config)
    logger.info("wrote %s", output)
    return ds
