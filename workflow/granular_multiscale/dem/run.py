"""RVE preparation as called by the rule script (no Snakemake here), and DEM-stage facts of a config.

    prepare_rves(config, packing_paths, summary_path, threads, logger)

The FEM–DEM run itself composes the solver with the DEM material-point set, one layer up:
``granular_multiscale.drivers.fem_dem``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from .rve import RVESpec, prepare_packing

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
