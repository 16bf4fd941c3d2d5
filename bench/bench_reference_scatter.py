"""The FEM–DEM reference's own error on a problem beyond the triaxial specimen: what another,
equally valid, FEM–DEM run differs from the pipeline's by, in the columns FEM–ML is judged in.

A surrogate's error against the reference means something only where it is larger than the
reference's own. Side by side, on the problem's first load path:

* the base: the run the pipeline makes (the problem's `dem_newton.tolerance`, the config's packing);
* the same at tighter Newton tolerances (--tolerances): how far the base is from a better solve;
* the same on packings of other seeds (--other-packings N: seeds seed+1 ... seed+N, the weak
  zone's packing too) at the base's tolerance: another realisation of the same material.

    .venv/bin/python bench/bench_reference_scatter.py --problem biaxial --tolerances 0.01 --other-packings 1
    .venv/bin/python bench/bench_reference_scatter.py --problem footing --tolerances 0.01 0.005 --other-packings 2
    .venv/bin/python bench/bench_reference_scatter.py --configfile config/tiny.yaml --spheres 100 \\
        --tolerances 0.02 0.01 --segments '[[9, 0.045]]'        # the tiny biaxial test, up to its peak

Printed and written after every run (the record, --out, default {output_dir}/bench/reference_scatter.json):
a row per run in the columns of the problems' surrogate tables (``analysis/problem_surrogate.py``:
force up to and after the base's peak and volumetric strain in % of their peaks, stress MAE inside
and outside the band or under the footing, band inclination and onset against the base's, DEM
work in % of the base's, wall time), plus its Newton iterations and cut-backs. A run that stops in
Newton is a row with its error. Runs and packings go to reference_scatter_runs/ beside the record
and are reused when they exist (delete to rerun).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pandas as pd

from granular_multiscale.analysis.problem_surrogate import comparison_table
from granular_multiscale.data import read_run
from granular_multiscale.dem.rve import RVESpec, prepare_packing
from granular_multiscale.drivers.fem_dem import run_fem_dem
from granular_multiscale.fem.newton import ConvergenceError

from common import bench_config, bench_parser, run_folder


def packing(config: dict, folder: Path, seed_offset: int, friction: float, name: str) -> str:
    """A packing of the config's RVE with seed seed + `seed_offset` and `friction` restored after
    consolidation (made once, then reused)."""
    file = folder / f"packing_{config['dem']['n_spheres']}_{name}{f'_seed+{seed_offset}' if seed_offset else ''}.yade.gz"
    if not file.exists():
        spec = RVESpec.from_config(config, config["seed"] + seed_offset)
        spec.friction = float(friction)
        prepare_packing(spec, file)
    return str(file)


def reference_run(config: dict, problem: str, path: str, tolerance: float, seed_offset: int, folder: Path,
                  workers: int):
    """The FEM–DEM run of `problem` at Newton `tolerance` on the packings of seed + `seed_offset`."""
    file = folder / f"{problem}_tol_{tolerance:g}{f'_seed+{seed_offset}' if seed_offset else ''}.h5"
    if file.is_file():
        return read_run(file)
    config[problem]["dem_newton"]["tolerance"] = tolerance
    strong = packing(config, folder, seed_offset, config["dem"]["friction"], "strong")
    weak = None
    if problem == "biaxial" and config["biaxial"].get("weak_zone"):
        weak = packing(config, folder, seed_offset, config["biaxial"]["weak_zone"]["dem_friction"], "weak")
    return run_fem_dem(config, path, [strong], file, None, workers, problem=problem, weak_packing=weak)


def main(argv=None) -> list[dict]:
    parser = bench_parser("reference_scatter", __doc__)
    parser.add_argument("--problem", choices=["biaxial", "footing"], default="biaxial")
    parser.add_argument("--spheres", type=int, default=None, help="spheres per RVE (default: dem.n_spheres)")
    parser.add_argument("--tolerances", type=float, nargs="*", default=[0.01],
                        help="tighter Newton tolerances than the problem's dem_newton.tolerance")
    parser.add_argument("--other-packings", type=int, default=0,
                        help="runs at the base's tolerance on packings of seeds seed+1, ..., seed+N")
    parser.add_argument("--segments", type=json.loads, default=None,
                        help="replace the path's segments, JSON: '[[9, 0.045]]' stops before the tiny biaxial peak")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    folder = run_folder(args)
    folder.mkdir(parents=True, exist_ok=True)
    config = bench_config(args.configfile, {"dem.n_spheres": args.spheres} if args.spheres else None)
    problem = args.problem
    path = list(config[problem]["load_paths"])[0]
    if args.segments is not None:
        config[problem]["load_paths"][path]["segments"] = args.segments
    base_tolerance = float(config[problem]["dem_newton"]["tolerance"])
    measurement = parser.measurement(args, problem=problem, section=config[problem])
    cases = ([(base_tolerance, 0)] + [(base_tolerance, k) for k in range(1, args.other_packings + 1)]
             + [(tol, 0) for tol in sorted(args.tolerances, reverse=True) if tol != base_tolerance])
    runs, failed, rows = {}, [], []
    for tolerance, offset in cases:
        label = f"tolerance {tolerance:g}" + (f", packing seed +{offset}" if offset else "")
        try:
            runs[label] = reference_run(config, problem, path, tolerance, offset, folder, args.workers)
        except ConvergenceError as error:
            failed.append({"run": label, "error": str(error)[:500]})
        if not runs:  # the base itself did not finish: nothing to compare with
            rows = failed
            measurement.finish({"problem": problem, "base": None, "rows": rows}, args.out)
            break
        base = next(iter(runs.values()))
        table = comparison_table(base, runs)
        table["Newton iterations"] = [int(run["newton_iterations"].sum()) for run in runs.values()]
        table["cut-backs"] = [int(run["cutbacks"].sum()) for run in runs.values()]
        table = table.drop(columns=[c for c in table if "spread" in c])  # FEM–DEM runs have no ensemble
        rows = table.to_dict("records") + failed
        with pd.option_context("display.width", 250, "display.max_columns", 30, "display.max_colwidth", 14):
            print(table.set_index("run").T.to_string(float_format=lambda v: f"{v:.3g}"), flush=True)
        measurement.finish({"problem": problem, "base": next(iter(runs)), "rows": rows}, args.out)
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
