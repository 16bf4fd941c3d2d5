"""Adaptive FEM–DEM–ML at the paper mesh: 5×5×10 hexahedra (2000 Gauss points), Path2, 1000-sphere
RVEs where the surrogate is unsure, on this machine (target: under 30 minutes).

The networks are material models, independent of the mesh: the bench takes those of a finished
default-scale run (trained on 400-sphere RVE data), with the settings of the config that trained
them, and the paper's RVE, which the `rve` rule of config/paper.yaml prepares (about a minute):

    .venv/bin/snakemake -j2 --configfile config/paper.yaml -- results/paper/rve/packing_0.yade.gz
    .venv/bin/python bench/bench_adaptive_paper.py --threshold 0.02

What it does, in one process, side by side:

1. FEM–ML of the path at the paper mesh (seconds): the surrogate everywhere, with its ensemble
   spread at every Gauss point and step;
2. from that run, for each of --predict thresholds, the points whose FEM–ML spread reaches it and
   the first step they do: what the adaptive run would promote if its solution stayed FEM–ML's
   (a forecast of its DEM work, printed before the run starts);
3. the adaptive run at --threshold (``drivers.adaptive.run_adaptive``, written and checkpointed
   in ``adaptive_paper_runs/`` beside the record: a killed bench resumes where it was), its wall
   time, promotions, DEM share of the point-steps and DEM particle-steps (trials, replays);
4. the adaptive run against FEM–ML: top force (max over the path, % of FEM–ML's peak) and stress at
   the DEM points. With --reference (a FEM–DEM run of the same mesh and path) both against it.

No FEM–DEM run exists at this scale here (about 10 CPU-hours per path, README "Scales"); the DEM
share is quoted in point-steps, and in particle-steps against the FEM–DEM estimate scaled from
--default-fem-dem (the default-scale FEM–DEM run of the same path: particle-steps per RVE sphere).
The numbers are printed and written to the record (--out, default results/bench/adaptive_paper.json).

    .venv/bin/python bench/bench_adaptive_paper.py [--configfile FILE ...] [--models FOLDER] [--packing FILE]
        [--threshold 0.02] [--variant anchor_fraction=0.02,correction=kernel]
        [--predict 0.05 0.03 0.02 0.015 0.01] [--path path2] [--workers 2]
        [--elements 5 5 10] [--default-fem-dem FILE] [--reference FILE] [--out FILE] [--forecast-only]

--configfile: the config that trained the networks (default config/config.yaml); --models: their
folder (default: the models of that config's output_dir); --packing: default the first packing
of config/paper.yaml's output_dir; --default-fem-dem: default the config's FEM–DEM run of --path.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np

from granular_multiscale.config import CONFIG_DIR, load_config, validate_config
from granular_multiscale.data import read_run
from granular_multiscale.drivers.adaptive import run_adaptive
from granular_multiscale.drivers.fem_ml import run_fem_ml
from granular_multiscale.plan import Layout

from common import bench_parser, parse_variant, pipeline_models, require_files, run_folder, top_force_error_pct, variant_name


def promotion_forecast(fem_ml, thresholds) -> list[dict]:
    """Per threshold: the points whose FEM–ML relative spread reaches it at some step, and the
    point-steps from the first such step on (DEM share of the point-steps if the run promoted
    exactly there), from a FEM–ML run's ``stress_spread_relative(step, gp)``."""
    spread = fem_ml["stress_spread_relative"].values[1:]  # steps 1..n (step 0 is the packing's state)
    n_steps, n_points = spread.shape
    rows = []
    for t in thresholds:
        hit = spread >= t
        promoted = hit.any(axis=0)
        first = np.where(promoted, hit.argmax(axis=0), n_steps)
        rows.append({"threshold": float(t), "promoted": int(promoted.sum()),
                     "median_first_step": float(np.median(first[promoted]) + 1) if promoted.any() else float("nan"),
                     "dem_point_fraction": float((n_steps - first).sum() / (n_steps * n_points))})
    return rows


def main(argv=None) -> dict:
    parser = bench_parser("adaptive_paper", __doc__)
    parser.add_argument("--models", default=None, help="folder with nn_sigma.pt and nn_tangent.pt "
                        "(default: those of the config's output_dir)")
    parser.add_argument("--packing", default=None, help="RVE packing (1000 spheres; default: config/paper.yaml's first)")
    parser.add_argument("--threshold", type=float, default=0.02, help="threshold of the adaptive run")
    parser.add_argument("--variant", default="", help="other adaptive settings, key=value,... (e.g. "
                        "anchor_fraction=0.02,correction=kernel; the rest from the config)")
    parser.add_argument("--predict", type=float, nargs="*", default=[0.05, 0.03, 0.02, 0.015, 0.01],
                        help="thresholds whose promotions the FEM–ML run forecasts")
    parser.add_argument("--path", default="path2")
    parser.add_argument("--workers", type=int, default=2, help="RVE worker processes")
    parser.add_argument("--elements", type=int, nargs=3, default=[5, 5, 10])
    parser.add_argument("--default-fem-dem", default=None, help="default-scale FEM–DEM run of the same path: scales "
                        "the FEM–DEM particle-step estimate (default: the config's FEM–DEM run of --path)")
    parser.add_argument("--reference", default=None, help="FEM–DEM run of this mesh and path, if one exists")
    parser.add_argument("--forecast-only", action="store_true", help="stop after the FEM–ML run and its forecast")
    args = parser.parse_args(argv)

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    logger = logging.getLogger("bench_adaptive_paper")
    logging.getLogger("granular_multiscale").setLevel(logging.WARNING)  # the run's own log: this bench's logger
    config = args.config
    layout = Layout(config["output_dir"])
    packing = args.packing or Layout(load_config(CONFIG_DIR / "paper.yaml")["output_dir"]).packings(1)[0]
    default_fem_dem = args.default_fem_dem or layout.run("fem_dem", args.path)
    paper = dict(config, specimen=dict(config["specimen"], elements=list(args.elements)),
                 adaptive={**config["adaptive"], **parse_variant(args.variant)})
    paper["adaptive"].pop("threshold")
    paper = validate_config(paper)
    sigma, tangent_model = pipeline_models(config, args.models)
    require_files(sigma, tangent_model, packing, hint="see the docstring of bench/bench_adaptive_paper.py for the "
                                                      "commands that make it")
    tangent = config["surrogate"]["tangent"]
    runs = run_folder(args)
    runs.mkdir(parents=True, exist_ok=True)
    measurement = parser.measurement(args)

    t0 = time.perf_counter()
    fem_ml = run_fem_ml(paper, args.path, sigma, tangent_model, tangent, progress=False)
    fem_ml_wall = time.perf_counter() - t0
    n_points, n_steps = fem_ml.sizes["gp"], fem_ml.sizes["step"] - 1
    print(f"FEM–ML {args.path}, mesh {'x'.join(map(str, args.elements))} ({n_points} Gauss points, {n_steps} steps): "
          f"{fem_ml_wall:.1f} s")
    forecast = promotion_forecast(fem_ml, sorted(set(args.predict) | {args.threshold}, reverse=True))
    print("forecast from FEM–ML's spread (points that reach the threshold, median first step, DEM share of point-steps):")
    for row in forecast:
        print(f"  threshold {row['threshold']:<6g} {row['promoted']:5d} points, first at step {row['median_first_step']:5.1f}, "
              f"{100 * row['dem_point_fraction']:5.1f} % of point-steps")
    if args.forecast_only:
        figures = {"gauss_points": int(n_points), "steps": int(n_steps), "fem_ml_wall_s": fem_ml_wall,
                   "forecast": forecast}
        measurement.finish(figures, args.out)
        print(f"wrote {args.out}")
        return figures

    t0 = time.perf_counter()
    name = f"{args.path}_{variant_name({**parse_variant(args.variant), 'threshold': args.threshold})}"
    run = run_adaptive(paper, args.path, args.threshold, [packing], sigma, tangent_model, tangent,
                       output=runs / f"{name}.h5", checkpoint=runs / f"{name}.ckpt", n_workers=args.workers,
                       logger=logger)
    wall = time.perf_counter() - t0
    dem_points = run["point_mode"].values[1:].astype(bool)
    stress_diff = np.linalg.norm(run["stress"].values[1:] - fem_ml["stress"].values[1:], axis=-1)
    result = {
        "gauss_points": int(n_points), "steps": int(n_steps), "threshold": args.threshold, "variant": args.variant,
        "anchors": int(run.attrs["adaptive_anchors"]), "correction": run.attrs["adaptive_correction"],
        "fem_ml_wall_s": fem_ml_wall, "adaptive_wall_s": wall, "adaptive_solver_s": float(run.attrs["time_run_s"]),
        "dem_points_final": int(run.attrs["dem_points_final"]),
        "promoted": int(run["promotions"].sum()),
        "dem_point_fraction": float(run.attrs["dem_point_fraction"]),
        "dem_particle_steps": float(run.attrs["dem_particle_steps"]),
        "dem_trial_particle_steps": float(run.attrs["dem_trial_particle_steps"]),
        "dem_replay_particle_steps": float(run.attrs["dem_replay_particle_steps"]),
        "newton_iterations": int(run["newton_iterations"].sum()),
        "top_force_vs_fem_ml_pct_of_peak": top_force_error_pct(fem_ml, run),
        "stress_diff_at_dem_points_kpa": float(stress_diff[dem_points].mean() / 1e3) if dem_points.any() else 0.0,
        "forecast": forecast,
    }
    if Path(default_fem_dem).is_file():
        default = read_run(default_fem_dem)
        per_sphere = float(default.attrs["dem_particle_steps"]) / (default.sizes["gp"] * int(config["dem"]["n_spheres"]))
        estimate = per_sphere * n_points * int(run.attrs["dem_n_spheres"])
        result["fem_dem_particle_steps_estimate"] = estimate
        result["dem_particle_share_of_estimate"] = result["dem_particle_steps"] / estimate
    if args.reference:
        reference = read_run(args.reference)
        result["top_force_vs_reference_pct_of_peak"] = top_force_error_pct(reference, run)
        result["fem_ml_top_force_vs_reference_pct_of_peak"] = top_force_error_pct(reference, fem_ml)

    print(f"adaptive FEM–DEM–ML {args.path} at threshold {args.threshold:g}: {wall:.0f} s wall "
          f"(goal: under 30 min), {result['dem_points_final']} of {n_points} points in DEM at the end "
          f"({result['anchors']} anchors, {result['promoted']} promoted), "
          f"{100 * result['dem_point_fraction']:.2f} % of point-steps in DEM")
    print(f"  DEM particle-steps {result['dem_particle_steps']:.3g} (trials {result['dem_trial_particle_steps']:.3g}, "
          f"replays {result['dem_replay_particle_steps']:.3g})" + (
              f", {100 * result['dem_particle_share_of_estimate']:.1f} % of the FEM–DEM estimate "
              f"{result['fem_dem_particle_steps_estimate']:.3g}" if "fem_dem_particle_steps_estimate" in result else ""))
    print(f"  against FEM–ML: top force {result['top_force_vs_fem_ml_pct_of_peak']:.2f} % of the peak (max over the "
          f"path), stress at the DEM points {result['stress_diff_at_dem_points_kpa']:.2f} kPa (mean)")
    if args.reference:
        print(f"  against FEM–DEM: top force {result['top_force_vs_reference_pct_of_peak']:.2f} % (FEM–ML "
              f"{result['fem_ml_top_force_vs_reference_pct_of_peak']:.2f} %)")
    print(f"load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    measurement.finish(result, args.out)
    print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    main()
