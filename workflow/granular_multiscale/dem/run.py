"""FEM–DEM runs and RVE preparation as called by the rule scripts (no Snakemake here).

    prepare_rves(config, packing_paths, summary_path, threads, logger)
    run_fem_dem(config, path_name, packing_paths, output, checkpoint, n_workers, logger)
"""

from __future__ import annotations

import copy
import json
import logging
import math
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from .rve import RVESpec, prepare_packing

NEWTON_OVERRIDES = ("tolerance", "max_iterations", "max_cutbacks", "line_search", "tangent_repair", "acceleration",
                    "anderson_depth", "predictor")


def dem_newton_config(config: dict) -> dict:
    """The config a FEM–DEM run uses: ``newton`` with the overrides of ``dem.newton``."""
    cfg = copy.deepcopy(config)
    for key in NEWTON_OVERRIDES:
        if key in cfg["dem"].get("newton", {}):
            cfg["newton"][key] = cfg["dem"]["newton"][key]
    return cfg


def packing_seeds(config: dict) -> list[int]:
    return [int(config["seed"]) + k for k in range(int(config["dem"]["n_packings"]))]


def inertial_number(config: dict) -> float:
    """I = strain_rate · mean diameter · sqrt(density / p0) of the imposed increments."""
    dem = config["dem"]
    d_mean = 0.5 * (dem["diameter_min"] + dem["diameter_max"])
    return dem["strain_rate"] * d_mean * math.sqrt(dem["density"] / config["specimen"]["confining_pressure"])


def _write_json(path: Path, payload) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=1))


def prepare_rves(config: dict, packing_paths: list[str], summary_path: str, threads: int = 1,
                 logger: logging.Logger | None = None) -> dict:
    """Consolidate ``dem.n_packings`` packings (seeds seed, seed+1, ...) in parallel YADE processes."""
    logger = logger or logging.getLogger("granular_multiscale.dem")
    seeds = packing_seeds(config)
    if len(packing_paths) != len(seeds):
        raise ValueError(f"{len(packing_paths)} packing files for dem.n_packings = {len(seeds)}")
    specs = [RVESpec.from_config(config, seed) for seed in seeds]
    for spec, path in zip(specs, packing_paths):
        logger.info("packing %s: %d spheres, seed %d, cell %.4f m, consolidating to %.0f Pa with μ = 0",
                    path, spec.n_spheres, spec.seed, spec.cell_size(), spec.pressure)
    with ThreadPoolExecutor(max(1, min(threads, len(specs)))) as pool:
        summaries = list(pool.map(prepare_packing, specs, packing_paths))
    for s in summaries:
        sv = np.asarray(s["stress_voigt"])
        logger.info(
            "packing %s: %d steps, %.1f s (%.2f µs per particle-step); stress [%s] Pa (max deviation %.2f %% of p); "
            "porosity %.4f, void ratio %.4f, coordination %.2f (mechanical %.2f), unbalanced %.1e",
            s["packing"], s["steps"], s["wall_time"], 1e6 * s["particle_step_time"],
            ", ".join(f"{v:.0f}" for v in sv), 100 * s["stress_error"], s["porosity"], s["void_ratio"],
            s["coordination_number"], s["mechanical_coordination_number"], s["unbalanced_force"],
        )
    summary = {
        "n_packings": len(summaries),
        "n_spheres": int(config["dem"]["n_spheres"]),
        "confining_pressure": float(config["specimen"]["confining_pressure"]),
        "mean": {k: float(np.mean([s[k] for s in summaries])) for k in (
            "porosity", "void_ratio", "coordination_number", "mechanical_coordination_number", "wall_time", "steps")},
        "packings": summaries,
    }
    _write_json(Path(summary_path), summary)
    return summary


def run_fem_dem(config: dict, path_name: str, packing_paths: list[str], output: str,
                checkpoint: str | None, n_workers: int, logger: logging.Logger | None = None,
                dask_client=None):
    """One FEM–DEM run of a load path, written in the data contract; returns the Dataset."""
    from ..data import write_run
    from ..fem.triaxial import TriaxialProblem
    from ..paths import load_paths_from_config
    from .material import DemMaterialPointSet

    logger = logger or logging.getLogger("granular_multiscale.dem")
    cfg = dem_newton_config(config)
    problem = TriaxialProblem.from_config(cfg)
    load_path = load_paths_from_config(cfg)[path_name]
    dem = cfg["dem"]
    scenes_dir = None
    if checkpoint:
        checkpoint = Path(checkpoint)
        scenes_dir = checkpoint.with_name(checkpoint.name + ".scenes")
        if not checkpoint.exists() and scenes_dir.exists():
            shutil.rmtree(scenes_dir)  # snapshots of an older, finished or abandoned run
    logger.info(
        "FEM–DEM %s: %d steps, mesh %s (%d Gauss points = RVEs of %d spheres), %s executor with %d workers; "
        "strain rate %.3g /s (inertial number %.1e), steps per increment %d..%d; Newton tolerance %.1e, "
        "%d iterations, %d cutbacks",
        path_name, load_path.n_steps, "x".join(map(str, problem.mesh_elements)), problem.n_material_points,
        dem["n_spheres"], dem["executor"], n_workers, dem["strain_rate"], inertial_number(cfg),
        dem["min_steps"], dem["max_steps"], cfg["newton"]["tolerance"], cfg["newton"]["max_iterations"],
        cfg["newton"]["max_cutbacks"],
    )
    t0 = time.perf_counter()
    with DemMaterialPointSet.from_config(cfg, problem.n_material_points, packing_paths, n_workers=n_workers,
                                         snapshot_dir=scenes_dir, logger=logger, dask_client=dask_client) as material:
        t_ready = time.perf_counter()
        ds = problem.run(material, load_path, method="dem", checkpoint=checkpoint, logger=logger, progress=True)
    # Totals from the per-step records, so a resumed run counts the steps before its checkpoint
    # too (the material set itself only saw the steps after the resume).
    split = {k: float(ds[k].values.sum()) for k in (
        "dem_time", "dem_cpu_time", "imbalance_time", "overhead_time", "material_time", "snapshot_time",
        "particle_steps", "trials")}
    wall = float(ds.attrs["time_run_s"])  # load-step loop across resumes
    logger.info("RVE workers started and packings loaded in %.1f s%s", t_ready - t0,
                f"; resume took {ds.attrs['time_resume_s']:.1f} s" if ds.attrs["time_resume_s"] else "")
    fem_other = max(wall - split["material_time"], 0.0)
    not_dem = 1.0 - split["dem_time"] / wall if wall > 0 else float("nan")
    ds.attrs.update({
        "dem_time_s": split["dem_time"],
        "dem_cpu_time_s": split["dem_cpu_time"],
        "dem_imbalance_time_s": split["imbalance_time"],
        "dem_overhead_time_s": split["overhead_time"],
        "dem_snapshot_time_s": split["snapshot_time"],
        "dem_particle_steps": split["particle_steps"],
        "dem_trials": split["trials"],
        "dem_wall_time_s": wall,
        "dem_startup_time_s": t_ready - t0,
        "dem_share_not_stepping": not_dem,
        "dem_n_workers": n_workers,
        "dem_executor": dem["executor"],
        "dem_strain_rate": dem["strain_rate"],
        "dem_inertial_number": inertial_number(cfg),
    })
    logger.info(
        "time split: wall %.1f s = DEM stepping %.1f s (%.1f %%) + worker imbalance %.1f s + rollback/transfer/Python "
        "%.1f s (%.1f %%, of which snapshots %.1f s) + FEM and the rest %.1f s; not DEM stepping: %.1f %%; "
        "%.3g particle-steps (%.2f µs of CPU each), %d RVE trials",
        wall, split["dem_time"], 100 * split["dem_time"] / wall, split["imbalance_time"], split["overhead_time"],
        100 * split["overhead_time"] / wall, split["snapshot_time"], fem_other, 100 * not_dem, split["particle_steps"],
        1e6 * split["dem_cpu_time"] / max(split["particle_steps"], 1), split["trials"],
    )
    write_run(ds, output, config)
    if scenes_dir is not None and scenes_dir.exists():
        shutil.rmtree(scenes_dir)
    logger.info("wrote %s", output)
    return ds
