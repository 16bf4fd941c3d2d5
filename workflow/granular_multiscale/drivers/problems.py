"""What every driver does first: the problem a run is on, its load path, and the material zones
of the problem turned into material sets (a weak zone of the biaxial specimen).

    problem, load_path = problem_and_path(config, "biaxial", "biaxial")
    material = analytic_material("elastoplastic", problem, config)       # Zoned where a weak zone is
    packings, assignment = dem_packings(problem, config, packing_paths, weak_packing)

Zone 1 (weak) is, for DEM RVEs, the packing restored to the interparticle friction
``weak_zone.dem_friction`` (rule ``rve_weak``); for the analytic model, its friction and
strengths scaled by ``weak_zone.elastoplastic_strength``.
"""

from __future__ import annotations

import copy

import numpy as np

from ..dem.material import assignment_seed, packing_assignment
from ..fem import make_problem
from ..materials import make_material
from ..materials.wrappers import Zoned
from ..paths import LoadPath, load_paths_from_config

#: the analytic model's parameters a weak zone scales
WEAK_SCALED = ("friction", "initial_hardening", "saturated_hardening", "softening")


def problem_and_path(config: dict, problem_name: str, path_name: str):
    """(problem, load path) of a run; unknown names and paths that do not fit raise errors naming the key."""
    problem = make_problem(config, problem_name)
    paths = load_paths_from_config(config, problem_name)
    if path_name not in paths:
        key = "load_paths" if problem_name == "triaxial" else f"{problem_name}.load_paths"
        raise KeyError(f"unknown load path {path_name!r} of problem {problem_name!r}; config key '{key}' defines "
                       f"{sorted(paths)}")
    load_path: LoadPath = paths[path_name]
    problem.check_load_path(load_path)
    return problem, load_path


def check_problems(config: dict) -> None:
    """Build every problem of ``problems`` and check each of its load paths: a setting that does
    not fit (a weak zone outside the mesh, a footing wider than its domain, a path that pulls)
    raises an error naming the config key before any rule runs."""
    for name in config["problems"]:
        for path in config[name]["load_paths"]:
            problem_and_path(config, name, path)


def weak_zone(config: dict, problem) -> dict | None:
    """The weak-zone settings of the problem's config section, where the problem has one with points in it."""
    if not problem.zones().any():
        return None
    return config[problem.config_section]["weak_zone"]


def analytic_material(kind: str, problem, config: dict):
    """The analytic material set `kind` at the problem's material points; a weak zone gets the
    elastoplastic model with its strengths scaled (``weak_zone.elastoplastic_strength``)."""
    n = problem.n_material_points
    zone = weak_zone(config, problem)
    if zone is None:
        return make_material(kind, n, config)
    if kind != "elastoplastic":
        raise ValueError(f"config key '{problem.config_section}.weak_zone': a weak zone needs the elastoplastic "
                         f"model or DEM RVEs, not {kind!r}")
    zones = problem.zones()
    weak = copy.deepcopy(config)
    factor = float(zone["elastoplastic_strength"])
    for key in WEAK_SCALED:
        if key in weak["elastoplastic"]:
            weak["elastoplastic"][key] = factor * float(weak["elastoplastic"][key])
    return Zoned([make_material(kind, int((zones == 0).sum()), config),
                  make_material(kind, int((zones == 1).sum()), weak)], zones)


def dem_packings(problem, config: dict, packing_paths: list[str], weak_packing: str | None = None):
    """(packing files, assignment) of the problem's RVEs: the configured packings drawn as
    ``dem.n_packings`` and ``dem.assignment_seed`` say, and the weak packing in the weak zone."""
    n = problem.n_material_points
    zones = problem.zones()
    assignment = packing_assignment(n, len(packing_paths), assignment_seed(config))
    if not zones.any():
        return list(packing_paths), assignment
    if weak_packing is None:
        raise ValueError(f"config key '{problem.config_section}.weak_zone': the weak zone's RVEs need the weak "
                         "packing (rule rve_weak: {output_dir}/rve/packing_weak.yade.gz)")
    assignment = np.where(zones == 1, len(packing_paths), assignment)
    return [*packing_paths, weak_packing], assignment
