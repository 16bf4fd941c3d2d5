"""RVE paths: material points driven along designed strain histories, with no FEM and no Newton.

    run_rve_paths(config, set_name, packing_paths, output, checkpoint, n_workers, logger)

One trajectory of ``dem.strain_paths`` per material point; at every step one ``evaluate`` (the
designed strain; for the stress-controlled families, triaxial, plane_strain and isotropic_triaxial,
the strains they do not impose are solved from the last converged stress and tangent) and one
``commit``. The points are those of the reference material (``reference_material``): YADE RVEs of
a :class:`DemMaterialPointSet`, or the analytic elastoplastic model (the fast stand-in of the tests
and ``config/elastoplastic.yaml``). The file follows the data contract with one ``gp`` per
trajectory (``data.RVE_PATHS_VARIABLES``).

A set with ``consolidation_pressure`` g drives packings consolidated at g·p0 (rule rve_pressure):
its families' stress targets, its contact-loss criterion and its file's ``confining_pressure``
are g·p0 (:func:`at_consolidation_pressure`).

Contact loss (``rve_paths.contact_loss``): an RVE whose mean stress p = −tr σ/3 falls below
``min_mean_stress_fraction`` × the confining pressure, or whose contact-stiffness tangent is not
positive definite, has lost its contact network. It is reported in the log (trajectory, family,
step) and in the file (``valid`` False from that step on, ``lost_contact_step``, stress and
tangent NaN from that step on) and is still driven, so the other RVEs see no difference.

Checkpoint: after every step, {signature, step, records, DEM state, elapsed} is pickled
atomically; a run started again resumes after the last step done (the DEM set replays its
committed increments, bit for bit), one under another signature is set aside with a warning.
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import xarray as xr

from .. import checkpoint as checkpoints, integrity
from ..data import RVE_PATHS_VARIABLES, write_run
from ..dem.material import DemMaterialPointSet
from ..dem.strain_paths import (StrainPaths, isotropic_triaxial_rows, lateral_servo, mixed_control,
                                plane_strain_rows, set_definition, set_section, strain_paths_from_config)
from ..materials import make_material
from ..history import HIST, history_from_sequence
from ..tensors import COMP, TCOMP, tangent_to_upper

CHECKPOINT_FORMAT = "rve-paths-checkpoint-v1"


def contact_lost(stress: np.ndarray, tangent: np.ndarray, pressure: float,
                 criterion: dict) -> tuple[np.ndarray, list[str]]:
    """[n] True where an RVE has lost its contact network, and why (one text per point)."""
    p = -stress[:, :3].sum(axis=1) / 3.0
    eig = np.linalg.eigvalsh(0.5 * (tangent + np.swapaxes(tangent, 1, 2)))
    low_p = p < criterion["min_mean_stress_fraction"] * pressure
    not_pd = eig[:, 0] <= criterion["min_tangent_eigenvalue_fraction"] * np.maximum(eig[:, -1], 0.0)
    reasons = [
        f"mean stress {p[i]:.4g} Pa < {criterion['min_mean_stress_fraction']:g} x {pressure:g} Pa" if low_p[i] else
        f"tangent not positive definite (eigenvalues {eig[i, 0]:.3g} .. {eig[i, -1]:.3g} Pa)"
        for i in range(len(p))
    ]
    return low_p | not_pd, reasons


def at_consolidation_pressure(config: dict, set_name: str) -> dict:
    """The config set `set_name` is driven with: its RVEs were consolidated at g·p0 (the set's
    ``consolidation_pressure`` g), and so are the stresses its families target, its contact-loss
    criterion and the pressure its file records (history variable p0 of the networks)."""
    fraction = float(set_definition(config, set_name).get("consolidation_pressure", 1.0))
    if fraction == 1.0:
        return config
    config = copy.deepcopy(config)
    config["specimen"]["confining_pressure"] = fraction * float(config["specimen"]["confining_pressure"])
    return config


def _signature(config: dict, set_name: str, paths: StrainPaths, material) -> dict:
    return {
        "format": CHECKPOINT_FORMAT,
        "set": set_name,
        "definition": set_definition(config, set_name),
        "rve_paths": set_section(config, set_name),
        "seed": config["seed"],
        "confining_pressure": config["specimen"]["confining_pressure"],
        "strain_sha256": hashlib.sha256(np.ascontiguousarray(paths.strain).tobytes()).hexdigest(),
        "material": material.checkpoint_key(),
    }


def run_rve_paths(config: dict, set_name: str, packing_paths: list[str], output: str | Path,
                  checkpoint: str | Path | None, n_workers: int, logger: logging.Logger | None = None,
                  dask_client=None) -> xr.Dataset:
    """Drive the set ``rve_paths.sets.<set_name>`` and write it to ``output``; returns the Dataset."""
    logger = logger or logging.getLogger("granular_multiscale.drivers.rve_paths")
    config = at_consolidation_pressure(config, set_name)
    paths = strain_paths_from_config(config, set_name)
    n_traj, n_steps = paths.n_trajectories, paths.n_steps
    pressure = float(config["specimen"]["confining_pressure"])
    criterion = set_section(config, set_name)["contact_loss"]
    checkpoint, scenes_dir = checkpoints.checkpoint_and_scenes(checkpoint)
    counts = ", ".join(f"{(paths.family == f).sum()} {f}" for f in dict.fromkeys(paths.family))
    logger.info("RVE paths %s: %d trajectories (%s) x %d steps = %d RVE evaluations of %d spheres, largest "
                "increment %.3g, %s executor with %d workers", set_name, n_traj, counts, n_steps, n_traj * n_steps,
                config["dem"]["n_spheres"], paths.largest_increment(), config["dem"]["executor"], n_workers)
    t0 = time.perf_counter()
    if config["reference_material"] == "dem":
        material = DemMaterialPointSet.from_config(config, n_traj, packing_paths, n_workers=n_workers,
                                                   snapshot_dir=scenes_dir, logger=logger, dask_client=dask_client)
    else:
        material = make_material(config["reference_material"], n_traj, config)
    with material:
        startup = time.perf_counter() - t0
        signature = _signature(config, set_name, paths, material)
        stress0, tangent0 = _initial_response(material)
        records = {"strain": [np.zeros((n_traj, 6))], "stress": [stress0], "tangent": [tangent0],
                   "particle_steps": [0.0], "dem_time": [0.0], "dem_cpu_time": [0.0], "wall_time": [0.0]}
        lost = np.full(n_traj, -1)
        first, elapsed_before = 1, 0.0
        saved = checkpoints.resume(checkpoint, signature, material, logger)
        if saved is not None:
            records, lost, elapsed_before = saved["records"], saved["lost"], saved["elapsed"]
            first = saved["step"] + 1
            logger.info("resuming from checkpoint %s after step %d (%.1f s of steps done)", checkpoint,
                        saved["step"], elapsed_before)
        if first == 1:
            _report_contact_loss(records["stress"][0], records["tangent"][0], 0, lost, paths, pressure, criterion,
                                 logger)
        t_run = time.perf_counter()
        servo = paths.family == "triaxial"
        lateral_stress = -pressure * np.array([p.get("lateral_stress_fraction", 1.0) for p in paths.parameters])
        plane = np.flatnonzero(paths.family == "plane_strain")
        isotropic = np.flatnonzero(paths.family == "isotropic_triaxial")
        for step in range(first, n_steps + 1):
            t_step = time.perf_counter()
            strain = paths.strain[:, step].copy()
            # stress-controlled families: the strains they do not impose come from the last converged
            # response (mixed control)
            if servo.any():
                strain[servo] = lateral_servo(
                    records["strain"][-1][servo], records["stress"][-1][servo], records["tangent"][-1][servo],
                    paths.strain[servo, step, 2] - paths.strain[servo, step - 1, 2], lateral_stress[servo],
                    largest=3.0 * paths.increment)
            if plane.size:
                strain[plane] = _mixed_control_step(paths, plane, step, records, [
                    plane_strain_rows(paths.parameters[t], step, pressure,
                                      records["stress"][min(paths.parameters[t]["compression_steps"], step - 1)][t])
                    for t in plane])
            if isotropic.size:
                strain[isotropic] = _mixed_control_step(paths, isotropic, step, records, [
                    isotropic_triaxial_rows(paths.parameters[t], step, pressure) for t in isotropic])
            stress, tangent = material.evaluate(strain)
            material.commit()
            records["strain"].append(strain)
            info = material.step_info()
            wall = time.perf_counter() - t_step
            for key, value in (("stress", stress), ("tangent", tangent),
                               ("particle_steps", info.get("particle_steps", 0.0)),  # 0 for an analytic model
                               ("dem_time", info.get("dem_time", 0.0)), ("dem_cpu_time", info.get("dem_cpu_time", 0.0)),
                               ("wall_time", wall)):
                records[key].append(value)
            _report_contact_loss(stress, tangent, step, lost, paths, pressure, criterion, logger)
            elapsed = elapsed_before + time.perf_counter() - t_run
            if checkpoint is not None:
                checkpoints.save(checkpoint, {"signature": signature, "step": step, "records": records, "lost": lost,
                                              "material_state": material.get_state(), "elapsed": elapsed})
            logger.info("step %3d/%d  %.3g particle-steps  %.2f s  (%.0f s so far, about %.0f s to go)  "
                        "lost contact: %d",
                        step, n_steps, info.get("particle_steps", 0.0), wall, elapsed, elapsed / step * (n_steps - step),
                        int((lost >= 0).sum()))
        wall_total = elapsed_before + time.perf_counter() - t_run
    ds = _dataset(paths, records, lost, config)
    ds.attrs.update({"rve_paths_wall_time_s": wall_total, "dem_startup_time_s": startup,
                     "dem_n_workers": n_workers, "dem_executor": config["dem"]["executor"]})
    particle_steps, cpu = ds.attrs["dem_particle_steps"], ds.attrs["dem_cpu_time_s"]
    logger.info("RVE paths %s: %d RVE evaluations, %.3g particle-steps (%.2f µs of CPU each), wall %.1f s (DEM "
                "stepping %.1f s), start-up %.1f s; %d of %d trajectories lost contact", set_name, n_traj * n_steps,
                particle_steps, 1e6 * cpu / max(particle_steps, 1.0), wall_total, ds.attrs["dem_time_s"], startup,
                int((lost >= 0).sum()), n_traj)
    write_run(ds, output, config, required=RVE_PATHS_VARIABLES)
    if checkpoint is not None:
        integrity.forget(checkpoint)
    if scenes_dir is not None and scenes_dir.exists():
        shutil.rmtree(scenes_dir)
    logger.info("wrote %s", output)
    return ds


def _mixed_control_step(paths: StrainPaths, points: np.ndarray, step: int, records: dict,
                        rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """The strains of the trajectories ``points`` at ``step`` under their conditions ``rows`` (one
    (weights, stress rows, targets) per point, as :func:`plane_strain_rows` gives them), solved with
    the last converged stress and tangent."""
    weights, stress_rows, targets = (np.stack(r) for r in zip(*rows))
    designed_increment = paths.strain[points, step] - paths.strain[points, step - 1]
    # a stress target moves the free strains by a few designed increments at most; the isotropic
    # phase has no designed increment, and its steps must fit under the clip too: 4·p0 in ten steps is
    # 1.7e-3 a step for the elastoplastic model (tested), under 3·increment at the default 1e-3
    largest = 3.0 * max(paths.increment, float(np.abs(designed_increment).max()))
    return mixed_control(records["strain"][-1][points], records["stress"][-1][points], records["tangent"][-1][points],
                         designed_increment, weights, stress_rows, targets, largest)


def _initial_response(material) -> tuple[np.ndarray, np.ndarray]:
    """Stress and tangent of the consolidated state: the DEM set holds them from loading its
    packings; an analytic set answers a trial at zero strain (repeatable, nothing committed)."""
    if hasattr(material, "conv_stress"):
        return material.conv_stress.copy(), material.conv_tangent.copy()
    stress, tangent = material.evaluate(np.zeros((material.n_points, 6)))
    return stress, tangent


def _report_contact_loss(stress, tangent, step, lost, paths, pressure, criterion, logger) -> None:
    """Mark (in ``lost``) and warn about the RVEs that lose their contact network at this step."""
    now, reasons = contact_lost(stress, tangent, pressure, criterion)
    for t in np.flatnonzero(now & (lost < 0)):
        lost[t] = step
        logger.warning("RVE paths: trajectory %d (%s) lost its contact network at step %d: %s; its stress and "
                       "tangent are NaN from this step on (still driven)", t, paths.family[t], step, reasons[t])


def _dataset(paths: StrainPaths, records: dict, lost: np.ndarray, config: dict) -> xr.Dataset:
    n_steps = paths.n_steps
    step = np.arange(n_steps + 1)
    valid = (lost[None, :] < 0) | (step[:, None] < lost[None, :])
    stress = np.where(valid[..., None], np.asarray(records["stress"]), np.nan)
    tangent = np.where(valid[..., None], tangent_to_upper(np.asarray(records["tangent"])), np.nan)
    strain = np.asarray(records["strain"])  # [step, trajectory, 6]: what the RVEs got (servo included)
    totals = {k: float(np.sum(records[k])) for k in ("particle_steps", "dem_time", "dem_cpu_time")}
    per_step = {k: np.asarray(records[k], dtype=float) for k in ("particle_steps", "dem_time", "wall_time")}
    sgc, sgt = ("step", "gp", "comp"), ("step", "gp", "tcomp")
    return xr.Dataset(
        {
            "strain": (sgc, strain, {"units": "1", "long_name": "total strain the RVE got (tensorial shear): the "
                                                               "designed one; the strains a stress-controlled "
                                                               "trajectory does not impose from its servo"}),
            "stress": (sgc, stress, {"units": "Pa", "long_name": "RVE stress, tension positive; NaN once lost"}),
            "tangent": (sgt, tangent, {"units": "Pa", "long_name": "upper triangle of the contact-stiffness tangent "
                                                                   "dσ/d(engineering ε); NaN once lost"}),
            "history": (("step", "gp", "hist"), history_from_sequence(strain), {"units": "1", "long_name": "φ1–φ3, ψ1, ψ2"}),
            "family": (("gp",), paths.family.astype(str), {"long_name": "strain-path family of the trajectory"}),
            "valid": (("step", "gp"), valid, {"long_name": "the RVE still has its contact network"}),
            "lost_contact_step": (("gp",), lost.astype(int), {"long_name": "first step without it, -1 = never"}),
            "particle_steps": (("step",), per_step["particle_steps"], {"units": "1"}),
            "dem_time": (("step",), per_step["dem_time"], {"units": "s", "long_name": "YADE stepping, mean over hosts"}),
            "wall_time": (("step",), per_step["wall_time"], {"units": "s"}),
        },
        coords={"step": step, "gp": np.arange(paths.n_trajectories), "comp": list(COMP), "tcomp": list(TCOMP),
                "hist": list(HIST)},
        attrs={
            "method": "rve_paths",
            "rve_paths_set": paths.name,
            "n_trajectories": paths.n_trajectories,
            "n_steps": n_steps,
            "rve_evaluations": paths.n_trajectories * n_steps,
            "largest_increment": paths.largest_increment(),
            "n_lost_contact": int((lost >= 0).sum()),
            "dem_particle_steps": totals["particle_steps"],
            "dem_time_s": totals["dem_time"],
            "dem_cpu_time_s": totals["dem_cpu_time"],
            "trajectory_parameters": json.dumps(list(paths.parameters)),
            "strain_units": "1 (small strain, tension positive, tensorial shear)",
            "stress_units": "Pa (tension positive)",
            "confining_pressure": float(config["specimen"]["confining_pressure"]),
        },
    )
