"""One FEM–ML run: the same triaxial FEM solver with the surrogate material at every Gauss point.

The run file is that of any other run (data contract, ``granular_multiscale.data``); its
``method`` attribute says which networks and tangent sat at the Gauss points
(``fem_ml_nn``, ``fem_ml_autodiff``, ``fem_ml_nohist_nn``...), and the per-step variables
``out_of_range_points``/``out_of_range_excess`` count inputs outside the training range.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path

import torch
import xarray as xr

from ..fem.newton import ConvergenceError
from ..fem.triaxial import TriaxialProblem
from ..paths import load_paths_from_config
from ..surrogate.material import SurrogateMaterial


def fem_ml_config(config: dict) -> dict:
    """The config a FEM–ML run uses: ``newton`` with the overrides of ``surrogate.newton``."""
    cfg = copy.deepcopy(config)
    cfg["newton"].update(config["surrogate"].get("newton", {}))
    return cfg


def run_fem_ml(
    config: dict,
    path_name: str,
    sigma_model: str | Path,
    tangent_model: str | Path | None,
    tangent: str,
    logger: logging.Logger | None = None,
    progress: bool = True,
    checkpoint: str | Path | None = None,
    allow_partial: bool = False,
) -> xr.Dataset:
    """FEM–ML run of load path `path_name` (validated config); returns the run Dataset.

    A step that does not converge raises ConvergenceError; with `allow_partial` (the runs that
    only compare the two tangents' Newton iterations) the converged steps are returned instead,
    marked ``completed = 0`` with ``stopped_at_step`` and ``stop_reason``."""
    logger = logger or logging.getLogger("granular_multiscale.fem_ml")
    paths = load_paths_from_config(config)
    if path_name not in paths:
        raise KeyError(f"unknown load path {path_name!r}; config key 'load_paths' defines {sorted(paths)}")
    config = fem_ml_config(config)
    torch.set_num_threads(int(config["surrogate"]["torch_threads"]))
    problem = TriaxialProblem.from_config(config)
    material = SurrogateMaterial.from_files(
        problem.n_gauss_points,
        sigma_model,
        tangent_model,
        tangent=tangent,
        out_of_range_tolerance=float(config["surrogate"]["out_of_range_tolerance"]),
        logger=logger,
        anchor_initial_state=bool(config["surrogate"]["anchor_initial_state"]),
    )
    logger.info(
        "FEM–ML %s: %d Gauss points, %s, tangent %s, NNσ %s%s; Newton tolerance %g, %d iterations",
        path_name, problem.n_gauss_points, "with history" if material.use_history else "NO history variables",
        tangent, sigma_model, f", ND {tangent_model}" if tangent == "nn" else "",
        config["newton"]["tolerance"], config["newton"]["max_iterations"],
    )
    with material:
        try:
            ds = problem.run(material, paths[path_name], method=material.method, checkpoint=checkpoint,
                             logger=logger, progress=progress)
            ds.attrs["completed"] = 1
        except ConvergenceError as error:
            if not allow_partial or error.partial is None:
                raise
            ds = error.partial
            ds.attrs["completed"] = 0
            logger.error("FEM–ML %s with the %s tangent stopped: %s; keeping the converged steps 0..%d "
                         "(attribute completed = 0)", path_name, tangent, error, ds.sizes["step"] - 1)
    ds.attrs.update(
        {
            "surrogate_tangent": tangent,
            "surrogate_use_history": int(material.use_history),
            "surrogate_sigma_model": str(sigma_model),
            "surrogate_tangent_model": str(tangent_model) if tangent == "nn" else "",
            "surrogate_features": ",".join(material.feature_names),
            "surrogate_anchor_initial_state": int(material.anchor_initial_state),
        }
    )
    n_out = int(ds["out_of_range_points"].max()) if "out_of_range_points" in ds else 0
    if n_out:
        steps = int((ds["out_of_range_points"] > 0).sum())
        logger.warning("FEM–ML %s: inputs outside the training range at %d steps (at most %d Gauss points)",
                       path_name, steps, n_out)
    return ds
