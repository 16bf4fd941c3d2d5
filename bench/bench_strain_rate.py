"""The RVE strain rate (`dem.strain_rate`): FEM–DEM runs of one load path at several rates, side
by side, against the slowest.

    .venv/bin/python bench/bench_strain_rate.py                         # Path2, default scale, 2.5 and 5 /s
    .venv/bin/python bench/bench_strain_rate.py --configfile config/tiny.yaml --rates 1.25 2.5 5
    .venv/bin/python bench/bench_strain_rate.py --runs a.h5 b.h5 --out docs/measured/strain_rate.json

Each rate's run uses the configured packing (prepared into strain_rate_runs/ beside the record
when missing) and everything else of the config; ``--runs`` compares finished run files of one
path instead of running (their rates are read from them). Written per rate, slowest first: its
inertial number, DEM evaluations per load step, particle-steps (and their ratio to the slowest
rate's), wall time, and its difference to the slowest rate's run: the largest top-force and
volumetric-strain differences over the path (% of the peak) and the stress MAE over all Gauss
points and steps (kPa). A rate is a setting of the material's definition, so the surrogate is
trained on and compared with runs at the same rate; what this measures is how much the RVE's
response moves when the rate changes, beside the reference's Newton tolerance error
(docs/why_defaults.md)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from granular_multiscale.data import read_run
from granular_multiscale.dem.rve import RVESpec, prepare_packing
from granular_multiscale.drivers.fem_dem import run_fem_dem

from common import bench_parser, curve_error_pct, run_folder


def compare(runs: dict[float, object]) -> list[dict]:
    """One row per rate: its cost and its differences to the slowest rate's run."""
    slowest = runs[min(runs)]
    steps = slowest.sizes["step"] - 1
    rows = []
    for rate, run in sorted(runs.items()):
        a = run.attrs
        rows.append({
            "strain_rate": rate, "inertial_number": float(a["dem_inertial_number"]),
            "evaluations_per_step": float(a["total_material_evaluations"]) / steps,
            "particle_steps": float(a["dem_particle_steps"]),
            "particle_steps_ratio": float(a["dem_particle_steps"]) / float(slowest.attrs["dem_particle_steps"]),
            "wall_s": float(a["time_run_s"]), "against": min(runs),
            "top_force_diff_pct": curve_error_pct(slowest, run, "top_force")["all"],
            "volumetric_strain_diff_pct": curve_error_pct(slowest, run, "volumetric_strain")["all"],
            "stress_mae_kpa": float(np.abs(run["stress"].values - slowest["stress"].values).mean() / 1e3),
        })
    return rows


def main(argv=None) -> None:
    parser = bench_parser("strain_rate", __doc__)
    parser.add_argument("--path", default=None, help="the load path (default: the validation path)")
    parser.add_argument("--rates", type=float, nargs="+", default=[2.5, 5.0])
    parser.add_argument("--runs", type=Path, nargs="+", default=None, help="compare these run files instead of running")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    config = args.config
    measurement = parser.measurement(args)
    if args.runs:
        runs = {}
        for file in args.runs:
            run = read_run(file)
            runs[float(run.attrs["dem_strain_rate"])] = run
        paths = {str(run.attrs["load_path"]) for run in runs.values()}
        if len(paths) != 1 or len(runs) != len(args.runs):
            raise SystemExit(f"--runs must be runs of one load path at distinct rates; got paths {sorted(paths)}, "
                             f"rates {sorted(runs)}")
    else:
        path = args.path or config["validation_path"]
        work = run_folder(args)
        work.mkdir(parents=True, exist_ok=True)
        packing = work / f"packing_{config['dem']['n_spheres']}_seed{config['seed']}.yade.gz"
        if not packing.exists():
            prepare_packing(RVESpec.from_config(config, config["seed"]), packing)
        runs = {}
        for rate in sorted(args.rates):
            config["dem"]["strain_rate"] = rate
            started = time.perf_counter()
            runs[rate] = run_fem_dem(config, path, [str(packing)], str(work / f"{path}_rate{rate:g}.h5"), None,
                                     config["dem"]["n_workers"])
            logging.info("rate %g /s: %.0f s", rate, time.perf_counter() - started)
    rows = compare(runs)
    for row in rows:
        print(", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    measurement.finish({"rows": rows}, args.out)  # --runs, if given, is in the record's settings
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
