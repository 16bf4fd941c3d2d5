"""FEM–ML against FEM–DEM on the same mesh and load path: seconds per load step and the ratio,
printed side by side, with the DEM cost per particle-step and the coupling overhead share.

    .venv/bin/python bench/bench_fem_ml_vs_dem.py                      # tiny scale, first 12 steps of Path2
    .venv/bin/python bench/bench_fem_ml_vs_dem.py --configfile config/config.yaml   # 2×2×4, 128 RVEs of 400 spheres (long)
    .venv/bin/python bench/bench_fem_ml_vs_dem.py --steps 57 --workers 2 --models results/tiny/models

The scale is the config's (--configfile, default config/tiny.yaml). Both runs use the solver
settings of the pipeline: FEM–DEM the ``newton`` section with the ``dem.newton`` overrides,
FEM–ML the ``newton`` section (plus --ml-newton overrides). The RVE packing is the pipeline's
(``<output_dir>/rve/packing_0.yade.gz``) when it exists, otherwise one is consolidated here (YADE,
kept in ``fem_ml_vs_dem_runs/`` beside the record) and its time reported separately. The
networks are the pipeline's (``--models``: nn_sigma.pt, nn_tangent.pt) or, without it, trained
here on the elastoplastic reference of Path1 on the same mesh (paper architecture; a forward
pass costs the same whatever the weights, but the Newton iterations depend on them: say which
in a report).

Printed, and written to the record (--out, default {output_dir}/bench/fem_ml_vs_dem.json): per
run (``fem_dem``; ``fem_ml``; ``fem_ml_at_dem_tolerance``) seconds per load step, Newton
iterations and evaluations per step, cutbacks, start-up and whole-run seconds; the ratios; the
DEM cost per particle-step and its time split (``dem``); FEM–ML's top-force and volumetric-strain
errors against FEM–DEM on these steps, in % of FEM–DEM's peak; with --compare-models, the same
for FEM–ML with each other folder's networks (``fem_ml_compared``), against the same FEM–DEM run.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import yaml

from granular_multiscale.config import validate_config
from granular_multiscale.fem.newton import ConvergenceError
from granular_multiscale.fem.triaxial import TriaxialProblem
from granular_multiscale.paths import LoadPath, load_paths_from_config
from granular_multiscale.plan import Layout

from common import bench_parser, curve_error_pct, run_folder, surrogate_models, top_force_error_pct


def first_steps(path: LoadPath, n: int) -> LoadPath:
    """The first n steps of a path, as one-step segments (the same axial strains)."""
    axial = path.axial_strain()[1 : n + 1]
    return LoadPath(f"{path.name}_first{n}", tuple((1, float(a)) for a in axial))


def per_step(ds) -> dict:
    steps = slice(1, None)  # step 0 is the consolidated state
    return {
        "steps": ds.sizes["step"] - 1,
        "s_per_step": float(ds.wall_time.values[steps].mean()),
        "iterations": float(ds.newton_iterations.values[steps].mean()),
        "evaluations": float(ds.material_evaluations.values[steps].mean()),
        "cutbacks": int(ds.cutbacks.values.sum()),
        "total_s": float(ds.wall_time.values.sum()),
    }


def run_fem_dem(config, path, packing, workers, logger):
    from granular_multiscale.dem.material import DemMaterialPointSet
    from granular_multiscale.drivers.fem_dem import dem_newton_config

    cfg = dem_newton_config(config)
    problem = TriaxialProblem.from_config(cfg)
    t0 = time.perf_counter()
    with DemMaterialPointSet.from_config(cfg, problem.n_material_points, [packing], n_workers=workers,
                                         logger=logger) as material:
        start = time.perf_counter() - t0
        ds = problem.run(material, path, method="dem", logger=logger, progress=True)
        split = material.time_split()
    return problem, ds, split, start, cfg["newton"]


def run_fem_ml(config, path, sigma, tangent, logger, verbose: bool, label: str = "FEM–ML") -> dict:
    """FEM–ML on the config's mesh along `path`: per_step figures, start-up and the run (``run``)."""
    from granular_multiscale.drivers.fem_ml import surrogate_material

    problem = TriaxialProblem.from_config(config)
    t0 = time.perf_counter()
    # the pipeline's factory (its surrogate settings: anchoring, surrogate.other_pressure at another
    # confining pressure, p0 for networks that take it), with ND's tangent, which the --ml-newton
    # default is tuned for
    with surrogate_material(config, problem.n_gauss_points, sigma, tangent, "nn", logger) as material:
        start = time.perf_counter() - t0
        try:
            ds = problem.run(material, path, logger=logger, progress=verbose)
        except ConvergenceError as error:
            print(f"{label} stopped: {error}; timing the steps it converged")
            ds = error.partial
            ds.attrs["completed"] = 0  # compared with FEM–DEM on the steps it reached
    return {**per_step(ds), "start": start, "run": ds}


def main(argv=None) -> dict:
    parser = bench_parser("fem_ml_vs_dem", __doc__, configfile=["config/tiny.yaml"])
    parser.add_argument("--steps", type=int, default=12, help="first N load steps of the validation path (57 = all)")
    parser.add_argument("--workers", type=int, default=2, help="RVE worker processes of FEM–DEM")
    parser.add_argument("--packing", help="a consolidated packing (default: the pipeline's, else made here)")
    parser.add_argument("--models", help="folder with nn_sigma.pt and nn_tangent.pt (default: train here)")
    parser.add_argument("--compare-models", nargs="*", default=[], metavar="LABEL=DIR",
                        help="more model folders, each run as FEM–ML on the same mesh and path beside the first and "
                             "recorded under its label (e.g. networks that take the consolidation pressure p0 beside "
                             "the prestrained default)")
    parser.add_argument("--ml-newton", nargs="*", default=["acceleration=anderson"],
                        help="newton overrides for FEM–ML, key=value (default: acceleration=anderson)")
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    logger = logging.getLogger("bench")

    import torch

    config = args.config
    measurement = parser.measurement(args)
    torch.set_num_threads(int(config["surrogate"]["torch_threads"]))
    full_path = load_paths_from_config(config)[config["validation_path"]]
    path = first_steps(full_path, min(args.steps, full_path.n_steps))

    # -- the RVE packing
    packing = Path(args.packing or Layout(config["output_dir"]).packings(1)[0])
    packing_note = f"pipeline packing {packing}"
    if not packing.exists():
        from granular_multiscale.dem.rve import RVESpec, prepare_packing

        # cached between bench runs
        packing = run_folder(args) / f"packing_{config['dem']['n_spheres']}_seed{config['seed']}.yade.gz"
        packing_note = f"bench packing {packing}"
        if not packing.exists():
            packing.parent.mkdir(parents=True, exist_ok=True)
            t0 = time.perf_counter()
            prepare_packing(RVESpec.from_config(config, config["seed"]), packing)
            packing_note += f", consolidated here in {time.perf_counter() - t0:.0f} s"

    # -- FEM–DEM
    problem, dem_ds, split, dem_start, dem_newton = run_fem_dem(config, path, packing, args.workers, logger)
    dem = per_step(dem_ds)

    # -- FEM–ML on the same mesh and path: the pipeline's Newton settings, and FEM–DEM's tolerance
    overrides = {k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in args.ml_newton)}
    ml_config = validate_config({**config, "newton": {**config["newton"], **overrides}})
    sigma = tangent = models_note = None
    ml, ml_runs = {}, {}
    for label, newton in (("FEM–ML", ml_config["newton"]),
                          ("FEM–ML tol", {**ml_config["newton"], "tolerance": dem_newton["tolerance"]})):
        cfg = validate_config({**ml_config, "newton": newton})
        ml_problem = TriaxialProblem.from_config(cfg)
        if sigma is None:
            sigma, tangent, models_note = surrogate_models(cfg, args.models, ml_problem, logger)
        run = run_fem_ml(cfg, path, sigma, tangent, logger, args.verbose, label)
        ml_runs[label] = run.pop("run")
        ml[label] = run
    ml_ds = ml_runs["FEM–ML"]
    compared = {}
    for entry in args.compare_models:
        label, _, folder = entry.rpartition("=")
        other_sigma, other_tangent, note = surrogate_models(ml_config, folder, ml_problem, logger)
        compared[label or folder] = run_fem_ml(ml_config, path, other_sigma, other_tangent, logger, args.verbose,
                                               label or folder)
        compared[label or folder]["networks"] = note

    # -- report
    n_gp = problem.n_gauss_points
    print(f"output_dir {config['output_dir']}: mesh {'x'.join(map(str, problem.mesh_elements))}, {n_gp} Gauss points, "
          f"RVEs of {config['dem']['n_spheres']} spheres, first {path.n_steps} steps of {full_path.name}")
    print(f"  {packing_note}; FEM–ML networks: {models_note}")
    print(f"  Newton: FEM–DEM tolerance {dem_newton['tolerance']:.0e}, {dem_newton['max_iterations']} iterations; "
          f"FEM–ML tolerance {ml_config['newton']['tolerance']:.0e}, acceleration {ml_config['newton']['acceleration']}")
    a, b = ml["FEM–ML"], ml["FEM–ML tol"]
    print(f"  {'':26s}{'FEM–DEM':>12s}{'FEM–ML':>12s}{'ratio':>8s}{'FEM–ML at':>14s}{'ratio':>8s}")
    print(f"  {'':26s}{'':12s}{'':12s}{'':8s}{'DEM tolerance':>14s}")
    print(f"  {'seconds per load step':26s}{dem['s_per_step']:12.3f}{a['s_per_step']:12.4f}"
          f"{dem['s_per_step'] / a['s_per_step']:7.0f}x{b['s_per_step']:14.4f}{dem['s_per_step'] / b['s_per_step']:7.0f}x")
    print(f"  {'Newton iterations / step':26s}{dem['iterations']:12.2f}{a['iterations']:12.2f}{'':8s}{b['iterations']:14.2f}")
    print(f"  {'evaluations / step':26s}{dem['evaluations']:12.2f}{a['evaluations']:12.2f}{'':8s}{b['evaluations']:14.2f}")
    print(f"  {'cutbacks':26s}{dem['cutbacks']:12d}{a['cutbacks']:12d}{'':8s}{b['cutbacks']:14d}")
    print(f"  {'start-up (s)':26s}{dem_start:12.2f}{a['start']:12.3f}{'':8s}{b['start']:14.3f}")
    print(f"  {'whole run (s)':26s}{dem['total_s']:12.1f}{a['total_s']:12.2f}"
          f"{dem['total_s'] / a['total_s']:7.0f}x{b['total_s']:14.2f}{dem['total_s'] / b['total_s']:7.0f}x")
    particle_steps = split["particle_steps"]
    dem_cost = {"particle_steps": particle_steps, "workers": args.workers}
    if particle_steps:
        dem_cost.update({"cpu_us_per_particle_step": 1e6 * split["dem_cpu_time"] / particle_steps,
                         "material_s": split["material_time"],
                         "stepping_share": split["dem_time"] / split["material_time"],
                         "imbalance_share": split["imbalance_time"] / split["material_time"],
                         "coupling_overhead_share": split["overhead_time"] / split["material_time"],
                         "fem_outside_the_material_share": 1 - split["material_time"] / dem["total_s"]})
        print(f"  DEM: {dem_cost['cpu_us_per_particle_step']:.2f} µs CPU per particle-step "
              f"({particle_steps:.3g} particle-steps, {args.workers} workers); of the time inside the DEM material "
              f"{split['material_time']:.1f} s: stepping {dem_cost['stepping_share']:.0%}, "
              f"imbalance {dem_cost['imbalance_share']:.0%}, coupling overhead "
              f"(fork, transfer, Python) {dem_cost['coupling_overhead_share']:.0%}; "
              f"the FEM outside the material {dem_cost['fem_outside_the_material_share']:.0%} of the run")
    top = top_force_error_pct(dem_ds, ml_ds)
    volumetric = curve_error_pct(dem_ds, ml_ds, "volumetric_strain")["all"]
    print(f"  (FEM–ML vs FEM–DEM on these steps: top force max difference {top:.1f} %, volumetric strain "
          f"{volumetric:.1f} % of the peak — only meaningful with networks trained on this DEM)")
    for label, run in compared.items():
        ds = run.pop("run")
        run.update(top_force_error_pct=top_force_error_pct(dem_ds, ds),
                   volumetric_strain_error_pct=curve_error_pct(dem_ds, ds, "volumetric_strain")["all"])
        print(f"  FEM–ML with {label} ({run['networks']}): top force {run['top_force_error_pct']:.1f} %, volumetric strain "
              f"{run['volumetric_strain_error_pct']:.1f} % of the peak, {run['s_per_step']:.4f} s per load step, "
              f"{run['cutbacks']} cutbacks")
    figures = {"mesh": "x".join(map(str, problem.mesh_elements)), "gauss_points": n_gp,
               "n_spheres": config["dem"]["n_spheres"], "steps": path.n_steps, "path": full_path.name,
               "packing": packing_note, "networks": models_note,
               "fem_dem": {**dem, "start": dem_start, "newton_tolerance": dem_newton["tolerance"]},
               "fem_ml": a, "fem_ml_at_dem_tolerance": b,
               "ratio_s_per_step": dem["s_per_step"] / a["s_per_step"],
               "ratio_s_per_step_at_dem_tolerance": dem["s_per_step"] / b["s_per_step"],
               "ratio_whole_run": dem["total_s"] / a["total_s"],
               "dem": dem_cost, "fem_ml_top_force_error_pct": top, "fem_ml_volumetric_strain_error_pct": volumetric,
               "fem_ml_compared": compared}
    measurement.finish(figures, args.out)
    print(f"wrote {args.out}")
    return figures


if __name__ == "__main__":
    main()
