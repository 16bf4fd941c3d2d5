"""One FEM–ML run: the same FEM solver, on any problem, with the surrogate material at every Gauss point.

The run file is that of any other run (data contract, ``granular_multiscale.data``); its
``method`` attribute says which networks and tangent sat at the Gauss points
(``fem_ml_nn``, ``fem_ml_autodiff``, ``fem_ml_nohist_nn``...), and the per-step variables
``out_of_range_points``/``out_of_range_excess`` count inputs outside the training range.

The ensemble's uncertainty (``surrogate.ensemble_size`` K networks per model) is added after the
solver returns, from what the material set recorded at each commit (:func:`spread_variables`):
``stress_spread(step, gp, comp)``, the std over the K members of NNσ at the converged strain
(Pa), and ``stress_spread_relative(step, gp)`` = ‖stress_spread‖ / max(‖stress‖, √3·p0), the
floor being the norm of the consolidated stress −p0·1. Attribute ``ensemble_size``; with K = 1
both variables are 0. Under ``specimen.uniform_field`` the material set has one point (the
problem's ``n_material_points``), whose spread stands for every Gauss point.

A specimen at another confining pressure than the networks' training RVEs (``surrogate.other_pressure``,
:func:`at_specimen_pressure`): ``offset`` runs the networks as they are, anchored to their training
data's fresh state; ``isotropic_prestrain`` first takes them along an isotropic strain to the
specimen's pressure (:class:`~granular_multiscale.materials.wrappers.IsotropicPrestrain`). The solver
sees a material-point set either way. Networks that take the consolidation pressure as an input
(history variable ``p0``, trained on RVEs prepared at several pressures) need neither: they are
given the specimen's.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from pathlib import Path

import numpy as np
import torch
import xarray as xr

from ..config import reference_newton_config
from ..data import tangent_variables
from ..fem.newton import ConvergenceError
from ..materials.base import MaterialPointSet
from ..materials.wrappers import IsotropicPrestrain, ZonedSurrogate
from ..surrogate.material import SurrogateMaterial, relative_spread, spread_floor
from ..tensors import TCOMP36
from .problems import problem_and_path


#: whose Newton settings a FEM–ML run is solved with (:func:`fem_ml_config`)
SOLVERS = ("fem_ml", "reference")


def fem_ml_config(config: dict, solver: str = "fem_ml", problem: str = "triaxial") -> dict:
    """The config a FEM–ML run uses: ``newton`` with the overrides of ``surrogate.newton``; with
    solver ``reference``, the Newton settings the reference run of `problem` is solved with
    (:func:`~granular_multiscale.config.reference_newton_config`: FEM–DEM's tolerance, predictor and
    acceleration), so that FEM–ML and its reference differ in the material only."""
    if solver not in SOLVERS:
        raise ValueError(f"FEM–ML solver settings must be one of {SOLVERS}, got {solver!r}")
    if solver == "reference":
        return reference_newton_config(config, problem)
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
    problem: str = "triaxial",
    weak_zone_models: dict | None = None,
    solver: str = "fem_ml",
) -> xr.Dataset:
    """FEM–ML run of load path `path_name` of `problem` (validated config); returns the run Dataset.

    A step that does not converge raises ConvergenceError; with `allow_partial` (the runs that
    only compare the two tangents' Newton iterations) the converged steps are returned instead,
    marked ``completed = 0`` with ``stopped_at_step`` and ``stop_reason``. A weak zone of the problem
    gets the networks of `weak_zone_models` ({"sigma": file, "tangent": file}, trained on RVEs of
    the weak packing); without them it gets the specimen's networks (a warning says so). `solver`
    (:data:`SOLVERS`): FEM–ML's own Newton settings, or those of the problem's reference run
    (attribute ``newton_settings_of``)."""
    logger = logger or logging.getLogger("granular_multiscale.fem_ml")
    config = fem_ml_config(config, solver, problem)
    bvp, load_path = problem_and_path(config, problem, path_name)
    material = problem_surrogate_material(config, bvp, sigma_model, tangent_model, tangent, weak_zone_models, logger)
    logger.info(
        "FEM–ML %s %s: %d Gauss points (%d material points), %s, tangent %s, NNσ %s%s (ensemble of %d); "
        "Newton tolerance %g, %d iterations",
        problem, path_name, bvp.n_gauss_points, material.n_points, "with history" if material.use_history else "NO history variables",
        tangent, sigma_model, f", ND {tangent_model}" if tangent == "nn" else "", material.ensemble_size,
        config["newton"]["tolerance"], config["newton"]["max_iterations"],
    )
    with material:
        ds = run_keeping_partial(bvp, material, load_path, checkpoint, logger, progress, allow_partial,
                                 f"FEM–ML {problem} {path_name} with the {tangent} tangent")
    ds = ds.assign(spread_variables(material, ds))
    ds.attrs.update(surrogate_attributes(material, sigma_model, tangent_model))
    ds.attrs["newton_settings_of"] = solver
    if isinstance(material, ZonedSurrogate):
        ds.attrs["surrogate_weak_zone_sigma_model"] = str(weak_zone_models["sigma"])
    n_out = int(ds["out_of_range_points"].max()) if "out_of_range_points" in ds else 0
    if n_out:
        steps = int((ds["out_of_range_points"] > 0).sum())
        logger.warning("FEM–ML %s: inputs outside the training range at %d steps (at most %d Gauss points)",
                       path_name, steps, n_out)
    return ds


def weak_zone_models_of(inputs) -> dict | None:
    """The weak zone's {"sigma", "tangent"} model files among a rule's named inputs (Plan.fem_ml_models:
    weak_sigma, and weak_tangent where the run is solved with ND), or None where the problem has none."""
    if "weak_sigma" not in inputs.keys():
        return None
    return {"sigma": inputs.weak_sigma, "tangent": inputs.get("weak_tangent")}


def problem_surrogate_material(config: dict, bvp, sigma_model, tangent_model, tangent: str,
                               weak_zone_models: dict | None = None,
                               logger: logging.Logger | None = None) -> MaterialPointSet:
    """The networks at the material points of the problem `bvp` (config as :func:`fem_ml_config`
    makes it): a weak zone gets the networks of `weak_zone_models` ({"sigma": file, "tangent": file},
    trained on RVEs of the weak packing); without them it gets the specimen's (a warning says so)."""
    logger = logger or logging.getLogger("granular_multiscale.fem_ml")
    zones = bvp.zones()
    if zones.any() and weak_zone_models:
        logger.info("%s: the %d points of the weak zone get its own networks (NNσ %s)", bvp.name, int(zones.sum()),
                    weak_zone_models["sigma"])
        return ZonedSurrogate(
            [surrogate_material(config, int((zones == k).sum()), models["sigma"], models["tangent"], tangent, logger)
             for k, models in enumerate(({"sigma": sigma_model, "tangent": tangent_model}, weak_zone_models))],
            zones)
    if zones.any():
        logger.warning("%s: no networks of the weak zone (surrogate.weak_zone_sources); its %d points get the "
                       "specimen's", bvp.name, int(zones.sum()))
    return surrogate_material(config, bvp.n_material_points, sigma_model, tangent_model, tangent, logger)


#: the variables of a reference run that the networks driven along its strains keep: its kinematics
DRIVEN_KEEPS = ("strain", "history", "gp_position", "node_position", "element_vertices", "displacement",
                "load_displacement", "volumetric_strain", "phase", "axial_strain", "lateral_strain",
                "settlement_ratio")
#: attributes of the reference that describe how it was solved, not the problem: not kept
DRIVEN_DROPS = ("method", "config", "completed", "material_points", "dem_", "time_", "total_", "newton_", "tangent_")


def run_along_reference(config: dict, reference: xr.Dataset, sigma_model, tangent_model, tangent: str,
                        problem: str, weak_zone_models: dict | None = None,
                        logger: logging.Logger | None = None) -> xr.Dataset:
    """FEM–ML's material (:func:`problem_surrogate_material`: the same networks, weak zone and
    pressure handling as :func:`run_fem_ml`) driven along the strain histories of the `reference` run
    of `problem`, one commit per load step, with no FEM.

    FEM–ML's error holds the material's error and that of the field it converges to (a band that
    forms earlier or elsewhere); this run holds the material's alone. Its file is the reference's
    kinematics (:data:`DRIVEN_KEEPS`: strains, displacements, volumetric strain, the load measure)
    with the networks' stress, tangent and ensemble spread, and the forces those stresses carry in
    virtual work (``load_force_in_virtual_work``: every point weighed by how much a load of the
    boundary strains it): measured against the reference like any run, its force error is the
    material's share of FEM–ML's, in the measure of the force goals. Method
    ``fem_ml_driven_<tangent>``; no Newton iterations, no DEM."""
    logger = logger or logging.getLogger("granular_multiscale.fem_ml")
    config = fem_ml_config(config)
    bvp, _ = problem_and_path(config, problem, str(reference.attrs.get("load_path", "")))
    if bvp.uniform_field or reference.sizes["gp"] != bvp.n_gauss_points or not np.allclose(
            reference["gp_position"].values, bvp.gp_positions, atol=1e-9):
        raise ValueError(f"the reference run of {problem} ({reference.sizes['gp']} Gauss points) is not on the "
                         f"mesh of the config's '{problem}' section ({bvp.n_gauss_points} points"
                         f"{', uniform_field' if bvp.uniform_field else ''})")
    material = problem_surrogate_material(config, bvp, sigma_model, tangent_model, tangent, weak_zone_models, logger)
    strain = reference["strain"].transpose("step", "gp", "comp").values
    n_steps = strain.shape[0]
    stress, tangents, wall = np.empty_like(strain), [], np.empty(n_steps)
    load_force = np.empty(n_steps)
    with material:
        for step in range(n_steps):
            t0 = time.perf_counter()
            stress[step], D = material.evaluate(strain[step])
            material.commit(strain[step])
            tangents.append(D)
            load_force[step] = bvp.load_force_in_virtual_work(stress[step])
            wall[step] = time.perf_counter() - t0
    observed = [bvp.force_observables(force) for force in load_force]  # top_force, footing_pressure
    forces = {"load_force": load_force, **{name: np.array([o[name] for o in observed]) for name in observed[0]}}
    tangent_vars, tangent_attrs = tangent_variables(tangents, "along the reference's strains, no FEM")
    kept = reference[[name for name in DRIVEN_KEEPS if name in reference]]
    ds = kept.assign({
        "stress": (("step", "gp", "comp"), stress, {"units": "Pa", "description": "Cauchy stress of the networks "
                                                    "at the reference's strain, tension positive"}),
        **{name: (dims, values, {"units": units, "description": description})
           for name, (dims, values, units, description) in tangent_vars.items()},
        **{name: ("step", values, {**reference[name].attrs, "description": reference[name].attrs.get("description", name)
                                   + "; of the networks' stresses in virtual work (they are not in equilibrium)"})
           for name, values in forces.items()},
        "newton_iterations": ("step", np.zeros(n_steps, dtype=np.int64), {"description": "no FEM: 0"}),
        "cutbacks": ("step", np.zeros(n_steps, dtype=np.int64), {"description": "no FEM: 0"}),
        "wall_time": ("step", wall, {"units": "s", "description": "wall time of the step"}),
    })
    if "tangent_full" in ds:
        ds = ds.assign_coords(tcomp36=list(TCOMP36))
    ds = ds.assign(spread_variables(material, ds))
    ds.attrs = {key: value for key, value in reference.attrs.items() if not key.startswith(DRIVEN_DROPS)}
    ds.attrs.update({**tangent_attrs, **surrogate_attributes(material, sigma_model, tangent_model),
                     "method": f"fem_ml_driven_{tangent}", "driven_along": str(reference.attrs.get("method", "")),
                     "material_points": int(material.n_points), "completed": 1, "dem_particle_steps": 0.0,
                     "time_run_s": float(wall.sum())})
    if isinstance(material, ZonedSurrogate):
        ds.attrs["surrogate_weak_zone_sigma_model"] = str(weak_zone_models["sigma"])
    logger.info("%s: the networks along the %d steps of the reference's strains (%s), no FEM: %.2f s", problem,
                n_steps - 1, ds.attrs["driven_along"], wall.sum())
    return ds


OTHER_PRESSURE = ("offset", "isotropic_prestrain")


def surrogate_material(config: dict, n_points: int, sigma_model, tangent_model, tangent: str,
                       logger: logging.Logger | None = None) -> MaterialPointSet:
    """The networks of the model files as a material-point set, with the `surrogate` settings of the
    config, at the specimen's confining pressure (:func:`at_specimen_pressure`)."""
    torch.set_num_threads(int(config["surrogate"]["torch_threads"]))
    material = SurrogateMaterial.from_files(
        n_points,
        sigma_model,
        tangent_model,
        tangent=tangent,
        out_of_range_tolerance=float(config["surrogate"]["out_of_range_tolerance"]),
        logger=logger,
        anchor_initial_state=bool(config["surrogate"]["anchor_initial_state"]),
        consolidation_pressure=float(config["specimen"]["confining_pressure"]),  # for networks that take p0
    )
    return at_specimen_pressure(material, float(config["specimen"]["confining_pressure"]),
                                config["surrogate"]["other_pressure"], logger)


def at_specimen_pressure(material: SurrogateMaterial, pressure: float, other_pressure: str,
                         logger: logging.Logger | None = None) -> MaterialPointSet:
    """The networks for a specimen confined at `pressure` (Pa). At the pressure they were trained at
    (``SurrogateModel.training_pressure``; a model file that does not know it is taken to have been
    trained at `pressure`, with a warning) they are returned as they are. At another one,
    `other_pressure` (config ``surrogate.other_pressure``) decides: ``offset`` leaves them anchored
    to their training data's fresh state, ``isotropic_prestrain`` wraps them in
    :class:`IsotropicPrestrain` (an isotropic strain to `pressure`, then −pressure·1 at zero strain).
    Networks that take p0 (history variable ``p0``) are given `pressure` as it, at any pressure."""
    logger = logger or logging.getLogger("granular_multiscale.fem_ml")
    if other_pressure not in OTHER_PRESSURE:
        raise ValueError(f"config key 'surrogate.other_pressure' must be one of {OTHER_PRESSURE}, got {other_pressure!r}")
    if material.sigma_model.takes_pressure:
        material.set_consolidation_pressure(pressure)
        logger.info("networks that take the consolidation pressure p0: %g Pa, the specimen's", pressure)
        return material
    trained = material.sigma_model.training_pressure
    if trained is None:
        logger.warning("the NNσ model file records no confining pressure of its training RVEs (trained before it "
                       "was recorded, or from sources that record none or differ): taken to be the specimen's, %g Pa",
                       pressure)
        trained = pressure
    if math.isclose(trained, pressure, rel_tol=1e-9):
        return material
    if other_pressure == "offset":
        logger.warning("networks trained at a confining pressure of %g Pa on a specimen at %g Pa, "
                       "surrogate.other_pressure 'offset': the Gauss points start from the training data's "
                       "consolidated stress", trained, pressure)
        return material
    logger.info("networks trained at a confining pressure of %g Pa on a specimen at %g Pa: isotropic prestrain",
                trained, pressure)
    return IsotropicPrestrain(material, pressure, logger=logger)


def surrogate_attributes(material: MaterialPointSet, sigma_model, tangent_model) -> dict:
    """Run-file attributes that say which networks sat at the Gauss points (and, prestrained to
    another pressure, how far and with what stress offset)."""
    attributes = {
        "ensemble_size": material.ensemble_size,
        "surrogate_tangent": material.tangent,
        "surrogate_use_history": int(material.use_history),
        "surrogate_sigma_model": str(sigma_model),
        "surrogate_tangent_model": str(tangent_model) if material.tangent == "nn" else "",
        "surrogate_features": ",".join(material.feature_names),
        "surrogate_anchor_initial_state": int(material.anchor_initial_state),
    }
    trained = material.sigma_model.training_pressure
    if trained is not None:
        attributes["surrogate_training_pressure_Pa"] = trained
    if getattr(material, "consolidation_pressure", None) is not None:
        attributes["surrogate_consolidation_pressure_Pa"] = material.consolidation_pressure
    if isinstance(material, IsotropicPrestrain):
        attributes.update({"surrogate_prestrain_pressure_Pa": material.pressure,
                           "surrogate_prestrain": float(material.prestrain[:, 0].mean()),
                           "surrogate_prestrain_offset_Pa": material.offset_norm})
    return attributes


def commits_of_steps(ds: xr.Dataset, commits: int) -> np.ndarray:
    """[steps] the number of commits a material set had made at the end of each load step of the run
    `ds`, which made `commits` in all: 1 + ``cutbacks`` per load step (one per accepted sub-step).
    A run that stopped early may have committed sub-steps of its failing step after the last
    recorded step; a complete run must account for every commit."""
    ends = np.cumsum(ds["cutbacks"].values + 1)
    complete = int(ds.attrs.get("completed", 1)) == 1
    if commits < ends[-1] or (complete and commits != ends[-1]):
        raise RuntimeError(f"the material set recorded {commits} committed states, the run's "
                           f"{ds.sizes['step']} load steps and {int(ds['cutbacks'].sum())} cutbacks make {ends[-1]}")
    return ends


def run_keeping_partial(problem, material, load_path, checkpoint, logger, progress: bool, allow_partial: bool,
                        what: str) -> xr.Dataset:
    """``problem.run`` with attr ``completed`` = 1; a step that does not converge raises, or with
    ``allow_partial`` returns the converged steps (``completed`` = 0, the error logged)."""
    try:
        ds = problem.run(material, load_path, method=material.method, checkpoint=checkpoint, logger=logger,
                         progress=progress)
        ds.attrs["completed"] = 1
    except ConvergenceError as error:
        if not allow_partial or error.partial is None:
            raise
        ds = error.partial
        ds.attrs["completed"] = 0
        logger.error("%s stopped: %s; keeping the converged steps 0..%d (attribute completed = 0)", what, error,
                     ds.sizes["step"] - 1)
    return ds


def spread_variables(material: SurrogateMaterial, ds: xr.Dataset) -> dict[str, xr.Variable]:
    """The ensemble spread the material set recorded, one entry per load step of the run `ds`.

    The set records one spread per commit; load step s ended with commit cumsum(1 + cutbacks)[s]
    (:func:`commits_of_steps`)."""
    recorded = material.stress_spread
    spread = recorded[commits_of_steps(ds, recorded.shape[0]) - 1]
    n_gp = ds.sizes["gp"]
    if spread.shape[1] != n_gp:  # uniform field: the one material point stands for every Gauss point
        spread = np.broadcast_to(spread, (spread.shape[0], n_gp, 6)).copy()
    stress = ds["stress"].transpose("step", "gp", "comp").values
    p0 = float(ds.attrs["confining_pressure_Pa"])
    k = material.ensemble_size
    members = f"{k} ensemble members of NNσ" + (" (one network: no spread, 0)" if k == 1 else "")
    return {
        "stress_spread": xr.Variable(("step", "gp", "comp"), spread, {
            "units": "Pa", "ensemble_size": k,
            "description": f"standard deviation (population, divided by K) over the {members} of each stress "
                           "component at the converged strain, each member anchored to the fresh state"}),
        "stress_spread_relative": xr.Variable(("step", "gp"), relative_spread(spread, stress, p0), {
            "units": "1", "ensemble_size": k, "floor_Pa": spread_floor(p0),
            "description": "||stress_spread|| / max(||stress||, sqrt(3) * confining pressure), tensor norms; "
                           "the floor is the norm of the consolidated stress -p0*1"}),
    }
