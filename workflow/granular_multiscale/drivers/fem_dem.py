"""FEM–DEM: the FEM solver of any problem with a YADE RVE at every Gauss point, as called by the
rule scripts, benches and studies (no Snakemake here).

    run_fem_dem(config, path_name, packing_paths, output, checkpoint, n_workers, logger,
                problem="triaxial", weak_packing=None)

A problem with a weak zone (``biaxial.weak_zone``) gives the RVEs inside it the weak packing
(``drivers/problems.py``).
"""

from __future__ import annotations

import logging
import shutil
import time

from .. import checkpoint as checkpoints
from ..config import NEWTON_OVERRIDES, dem_newton_config  # noqa: F401  (the drivers' and tests' names)
from ..data import write_run
from ..dem.material import DemMaterialPointSet
from ..dem.run import inertial_number
from .problems import dem_packings, problem_and_path


def run_fem_dem(config: dict, path_name: str, packing_paths: list[str], output: str,
                checkpoint: str | None, n_workers: int, logger: logging.Logger | None = None,
                dask_client=None, problem: str = "triaxial", weak_packing: str | None = None):
    """One FEM–DEM run of a load path of `problem`, written in the data contract; returns the Dataset."""
    logger = logger or logging.getLogger("granular_multiscale.dem")
    cfg = dem_newton_config(config, problem)
    bvp, load_path = problem_and_path(cfg, problem, path_name)
    packings, assignment = dem_packings(bvp, cfg, packing_paths, weak_packing)
    dem = cfg["dem"]
    checkpoint, scenes_dir = checkpoints.checkpoint_and_scenes(checkpoint)
    logger.info(
        "FEM–DEM %s %s: %d steps, mesh %s of %s (%d Gauss points = RVEs of %d spheres%s), %s executor with %d "
        "workers; strain rate %.3g /s (inertial number %.1e), steps per increment %d..%d; Newton tolerance %.1e, "
        "%d iterations, %d cutbacks",
        problem, path_name, load_path.n_steps, "x".join(map(str, bvp.mesh_elements)), bvp.ops.element,
        bvp.n_material_points, dem["n_spheres"],
        f", {int(bvp.zones().sum())} in the weak zone" if bvp.zones().any() else "", dem["executor"], n_workers,
        dem["strain_rate"], inertial_number(cfg), dem["min_steps"], dem["max_steps"], cfg["newton"]["tolerance"],
        cfg["newton"]["max_iterations"], cfg["newton"]["max_cutbacks"],
    )
    t0 = time.perf_counter()
    with DemMaterialPointSet.from_config(cfg, bvp.n_material_points, packings, n_workers=n_workers,
                                         snapshot_dir=scenes_dir, logger=logger, dask_client=dask_client,
                                         assignment=assignment) as material:
        t_ready = time.perf_counter()
        ds = bvp.run(material, load_path, method="dem", checkpoint=checkpoint, logger=logger, progress=True)
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
